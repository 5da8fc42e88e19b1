"""Scene rendering: determinism, SNR, anechoic rooms, directional noise, truth convention, CLI."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import soundfile as sf

from doabench.acoustics.render import render_components, render_scene
from doabench.acoustics.scenes import SceneDistribution, sample_scene
from doabench.corpora.speech import EmbeddedSpeechSource
from doabench.acoustics.trajectories import segment_bounds
from doabench.cli.main import main as cli
from doabench.errors import ConfigError
from doabench.framing import frame_signal, frame_vad

SPEECH = EmbeddedSpeechSource()
# Small rooms and short signals keep every render around a second on one CPU core.
SMALL = SceneDistribution(room_min=(3.0, 3.0, 2.5), room_max=(5.0, 4.0, 3.0), t60=(0.3, 0.3), snr=(12.0, 12.0),
                          duration_s=3.0, n_points=24)


@pytest.fixture(scope="module")
def rendered():
    scene = sample_scene(SMALL, 11, SPEECH)
    return scene, render_components(scene, SPEECH, keep_direct=True)


def test_same_seed_same_backend_is_bitwise_identical(rendered):
    scene, r = rendered
    again = render_scene(sample_scene(SMALL, 11, SPEECH), SPEECH, simulator="builtin")
    assert again.audio.dtype == np.float32 and again.audio.shape == (12, 48000)
    assert np.array_equal(again.audio, r.episode.audio)
    assert np.array_equal(again.sample_directions, r.episode.sample_directions)
    meta = r.episode.metadata
    assert meta["backend"] == "builtin" and meta["backend_versions"]["backend"] == "builtin"
    assert meta["scene"] == scene.to_dict() and json.dumps(meta)


def test_snr_is_measured_on_direct_path_over_non_silent_frames(rendered):
    scene, r = rendered
    active = np.asarray(frame_vad(r.episode.sample_vad, 4096, 3072))
    assert active.sum() >= 5 and np.array_equal(active, r.active_frames)
    direct = frame_signal(r.direct, 4096, 3072)[:, active]  # (M, T_active, K)
    noise = frame_signal(r.noise, 4096, 3072)[:, active]
    snr = 10 * np.log10(np.mean(direct**2) / np.mean(noise**2))
    assert abs(snr - scene.snr_db) < 0.5
    # The mixture is exactly reverberant speech plus that noise.
    assert np.allclose(r.episode.audio, (r.reverberant + r.noise).astype(np.float32), atol=1e-7)


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_analytic_direct_power_matches_the_convolved_direct_path(seed):
    from doabench.acoustics.render import direct_path_power, reference_power
    from doabench.acoustics.backends.base import direct_path

    dist = SMALL.replace(room_min=(3.0, 3.0, 2.5), room_max=(9.0, 8.0, 5.0), duration_s=6.0, n_points=48)
    scene = sample_scene(dist, seed, SPEECH)
    chunk = SPEECH.load(scene.speech)
    sources, mics = np.array(scene.source_positions), np.array(scene.mic_room_positions)
    direct = direct_path(scene.room, sources, mics, chunk.signal, scene.fs)
    convolved, frames_a = reference_power(direct, chunk.vad)
    analytic, frames_b = direct_path_power(sources, mics, chunk.signal, chunk.vad, scene.fs)
    assert np.array_equal(frames_a, frames_b)
    assert abs(10 * np.log10(analytic / convolved)) < 0.1


def test_anechoic_scene_is_the_direct_path():
    scene = sample_scene(SMALL.replace(t60=(0.0, 0.0), snr=(30.0, 30.0), duration_s=1.5, n_points=12), 2, SPEECH)
    r = render_components(scene, SPEECH, keep_direct=True)
    assert scene.room.t60 == 0.0 and np.all(np.isfinite(r.episode.audio))
    err = np.abs(r.reverberant - r.direct).max()
    assert err < 1e-5 * np.abs(r.direct).max()


def test_directional_noise_is_added_when_enabled():
    dist = SMALL.replace(duration_s=1.5, n_points=12, directional_noise_p=1.0, directional_noise_snr=(10.0, 10.0),
                         directional_noise_kind="lowpass")
    scene = sample_scene(dist, 4, SPEECH)
    assert scene.directional_noise is not None and scene.directional_noise.snr_db == 10.0
    r = render_components(scene, SPEECH)
    assert r.directional is not None
    mix = (r.reverberant + r.noise + r.directional).astype(np.float32)
    assert np.allclose(r.episode.audio, mix, atol=1e-7)
    # Its SNR is measured at the microphones: reverberant speech (non-silent frames) vs. the noise.
    speech = frame_signal(r.reverberant, 4096, 3072)[:, r.active_frames]
    assert abs(10 * np.log10(np.mean(speech**2) / np.mean(r.directional**2)) - 10.0) < 0.01
    # The noise plays in the silences too (unlike the speech).
    silent = ~r.episode.sample_vad
    assert silent.any() and np.mean(r.directional[:, silent] ** 2) > 0


def test_render_errors():
    scene = sample_scene(SMALL, 0)  # no speech source
    with pytest.raises(ConfigError, match="without a speech source"):
        render_scene(scene, SPEECH)
    with pytest.raises(ConfigError, match="simulator"):
        render_scene(sample_scene(SMALL, 0, SPEECH), SPEECH, simulator=object())


def test_truth_segments_are_the_simulators():
    from doabench.acoustics import convolution

    assert convolution.segment_bounds is segment_bounds  # one rule cuts the audio and the truth
    for n, s in [(320000, 156), (48000, 24), (1001, 7), (5, 5)]:
        b = segment_bounds(n, s)
        assert b[0] == 0 and b[-1] == n and np.all(np.diff(b) >= n // s) and np.all(np.diff(b) <= n // s + 1)


def _srp_errors(static: bool) -> np.ndarray:
    from doabench.features import FeatureExtractor
    from doabench.geometry import grid_unit_vectors, great_circle_error

    dist = SceneDistribution(room_min=(4.0, 4.0, 2.5), room_max=(6.0, 5.0, 3.0), t60=(0.2, 0.2),
                             snr=(30.0, 30.0), duration_s=6.0, n_points=47, p_static=1.0 if static else 0.0,
                             min_array_distance=1.0)
    scene = sample_scene(dist, 5, SPEECH)
    ep = render_scene(scene, SPEECH)
    feats = FeatureExtractor(scene.array, kinds=("srp",), resolution=(32, 64))(ep.audio[None], ep.sample_vad[None])
    srp = np.asarray(feats["srp"][0])  # (T, 32, 64)
    vad = np.asarray(feats["vad"][0], dtype=bool)
    grid = grid_unit_vectors(32, 64)
    est = grid.reshape(-1, 3)[srp.reshape(len(srp), -1).argmax(-1)]
    from doabench.framing import FrameSpec

    truth = ep.frame_truth(FrameSpec())["directions"][: len(srp)]
    return np.degrees(great_circle_error(est[vad], truth[vad]))


@pytest.mark.parametrize("static", [True, False])
def test_srp_argmax_tracks_the_truth(static):
    errors = _srp_errors(static)
    assert len(errors) >= 5
    # Grid spacing of 32x64: 180/31 = 5.8 deg in elevation, 360/64 = 5.6 deg in azimuth.
    assert np.median(errors) < 5.6, errors


def test_cli_simulate_end_to_end(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DOABENCH_LIBRISPEECH", raising=False)
    out = tmp_path / "sim"
    rc = cli(["simulate", "--t60", "0.3", "--snr", "20", "--seed", "3", "--duration", "2", "--out", str(out)])
    assert rc == 0 and "embedded speech" in capsys.readouterr().out
    audio, fs = sf.read(str(out / "audio.wav"), dtype="float32")
    assert fs == 16000 and audio.shape == (32000, 12) and sf.info(str(out / "audio.wav")).subtype == "FLOAT"
    rows = list(csv.DictReader(open(out / "truth.csv")))
    assert len(rows) == 1 + (32000 - 4096) // 3072
    assert list(rows[0]) == ["time_s", "elevation_deg", "azimuth_deg", "x", "y", "z", "vad"]
    assert abs(float(rows[0]["time_s"]) - 2048 / 16000) < 1e-6 and rows[0]["vad"] in ("0", "1")
    info = json.loads((out / "scene.json").read_text())
    assert info["scene"]["room"]["t60"] == 0.3 and info["scene"]["snr_db"] == 20.0
    assert info["backend"] == "builtin" and info["backend_versions"] and len(info["scene"]["trajectory"]) == 16
    assert [p.name for p in tmp_path.iterdir()] == ["sim"]  # no temporary folder left behind
    # The output folder is never overwritten silently; bad values are one-line errors.
    assert cli(["simulate", "--t60", "0.3", "--snr", "20", "--duration", "2", "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert cli(["simulate", "--t60", "-1", "--duration", "1", "--out", str(tmp_path / "x")]) == 2
    assert "t60" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_cli_simulate_from_a_task(tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli(["simulate", "--task", "sim-demo", "--seed", "1", "--duration", "1.5", "--out", str(out)]) == 0
    info = json.loads((out / "scene.json").read_text())
    assert info["task"] == "sim-demo" and 0.2 <= info["scene"]["room"]["t60"] <= 0.6
    assert info["distribution"]["t60"] == [0.2, 0.6] and info["distribution"]["duration_s"] == 1.5
    capsys.readouterr()
    assert cli(["simulate", "--episode", "0", "--out", str(tmp_path / "x")]) == 2
    assert "--episode needs --task" in capsys.readouterr().err


def test_simulate_force_replaces_only_a_folder_simulate_wrote(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DOABENCH_LIBRISPEECH", raising=False)
    args = ["simulate", "--t60", "0.2", "--snr", "20", "--duration", "1", "--force", "--out"]
    user_file = tmp_path / "notes.txt"
    user_file.write_text("precious")
    assert cli(args + [str(user_file)]) == 2
    assert user_file.read_text() == "precious"
    other = tmp_path / "other"
    other.mkdir()
    (other / "thesis.tex").write_text("precious")
    assert cli(args + [str(other)]) == 2
    assert (other / "thesis.tex").read_text() == "precious" and len(list(other.iterdir())) == 1
    sim = tmp_path / "sim"
    assert cli(args + [str(sim)]) == 0
    first = (sim / "scene.json").read_text()
    assert cli(args[:-1] + ["--seed", "5", "--out", str(sim)]) == 0  # an earlier simulate's folder is replaced
    assert (sim / "scene.json").read_text() != first
    (sim / "extra.txt").write_text("mine")
    assert cli(args + [str(sim)]) == 2 and (sim / "extra.txt").exists()
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    capsys.readouterr()
    assert cli(args + ["."]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not list(work.iterdir()) and sorted(p.name for p in tmp_path.iterdir()) == [
        "notes.txt", "other", "sim", "work"]


def test_outputs_respect_the_umask(tmp_path, monkeypatch):
    import os
    import stat

    from doabench.files import write_json

    monkeypatch.delenv("DOABENCH_LIBRISPEECH", raising=False)
    old = os.umask(0o022)
    try:
        out = tmp_path / "sim"
        assert cli(["simulate", "--t60", "0.2", "--snr", "20", "--duration", "1", "--out", str(out)]) == 0
        assert stat.S_IMODE(out.stat().st_mode) == 0o755
        for name in ("audio.wav", "truth.csv", "scene.json"):
            assert stat.S_IMODE((out / name).stat().st_mode) == 0o644
        assert stat.S_IMODE(write_json(tmp_path / "r.json", {"a": 1}).stat().st_mode) == 0o644
        os.umask(0o077)
        assert stat.S_IMODE(write_json(tmp_path / "s.json", {"a": 1}).stat().st_mode) == 0o600
    finally:
        os.umask(old)
