"""`doabench track` on a user's recording: output format, truth agreement and input errors."""
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import soundfile as sf

from doabench.cli.main import main


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene") / "s"
    assert main(["simulate", "--t60", "0.2", "--snr", "30", "--seed", "5", "--duration", "4", "--out", str(out)]) == 0
    return out


def test_track_writes_csv_close_to_truth_and_a_plot(scene_dir, tmp_path):
    csv, png = tmp_path / "doa.csv", tmp_path / "doa.png"
    assert main(["track", str(scene_dir / "audio.wav"), "--tracker", "srp-max:32x64", "--out", str(csv),
                 "--plot", str(png)]) == 0
    est = pd.read_csv(csv)
    assert list(est.columns) == ["time_s", "elevation_deg", "azimuth_deg", "x", "y", "z", "vad"]
    assert set(est.vad) <= {0, 1} and est.vad.sum() > 0
    truth = pd.read_csv(scene_dir / "truth.csv")
    assert np.allclose(est.time_s, truth.time_s)
    active = truth.vad.to_numpy(bool)
    cos = np.sum(est[["x", "y", "z"]].to_numpy() * truth[["x", "y", "z"]].to_numpy(), 1)
    assert np.median(np.degrees(np.arccos(np.clip(cos[active], -1, 1)))) < 10
    assert png.stat().st_size > 1000


def test_track_input_errors_are_one_line(scene_dir, tmp_path, capsys):
    audio, fs = sf.read(scene_dir / "audio.wav")
    cases = {}
    sf.write(tmp_path / "ch4.wav", audio[:, :4], fs)
    cases["ch4.wav"] = "has 4 channels but array 'nao' has 12"
    sf.write(tmp_path / "fs8k.wav", audio[::2], fs // 2)
    cases["fs8k.wav"] = "pass --resample"
    bad = audio.copy()
    bad[100, 3] = np.nan
    sf.write(tmp_path / "nan.wav", bad, fs, subtype="FLOAT")
    cases["nan.wav"] = "NaN or infinite"
    sf.write(tmp_path / "short.wav", audio[:1000], fs)
    cases["short.wav"] = "shorter than one 4096-sample window"
    (tmp_path / "junk.wav").write_bytes(b"not audio at all")
    cases["junk.wav"] = "cannot read"
    cases["missing.wav"] = "does not exist"
    for name, message in cases.items():
        out = tmp_path / f"{name}.csv"
        assert main(["track", str(tmp_path / name), "--out", str(out)]) == 2, name
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()
    # with --resample the 8 kHz file is accepted
    assert main(["track", str(tmp_path / "fs8k.wav"), "--resample", "--out", str(tmp_path / "ok.csv")]) == 0


@pytest.mark.parametrize("tracker", ["music", "normmusic", "srp-pra"])
def test_pyroomacoustics_trackers_follow_the_truth(scene_dir, tmp_path, tracker):
    csv = tmp_path / "doa.csv"
    assert main(["track", str(scene_dir / "audio.wav"), "--tracker", tracker, "--out", str(csv)]) == 0
    est, truth = pd.read_csv(csv), pd.read_csv(scene_dir / "truth.csv")
    cos = np.sum(est[["x", "y", "z"]].to_numpy() * truth[["x", "y", "z"]].to_numpy(), 1)
    errors = np.degrees(np.arccos(np.clip(cos, -1, 1)))[truth.vad.to_numpy(bool)]
    assert np.median(errors) < 15, (tracker, np.median(errors))


def test_track_refuses_an_output_that_is_an_input(scene_dir, tmp_path, capsys):
    import shutil

    rec = tmp_path / "in.wav"
    shutil.copy(scene_dir / "audio.wav", rec)
    before = rec.read_bytes()
    assert main(["track", str(rec), "--out", str(rec)]) == 2
    assert main(["track", str(rec), "--out", str(tmp_path / "x.csv"), "--plot", str(rec)]) == 2
    assert rec.read_bytes() == before and not (tmp_path / "x.csv").exists()
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 2


def test_track_bad_outputs_are_refused_before_the_work(scene_dir, tmp_path, capsys, monkeypatch):
    import os

    rec = str(scene_dir / "audio.wav")
    folder = tmp_path / "adir"
    folder.mkdir()
    (tmp_path / "afile").write_text("x")
    calls = []
    import doabench.runner.recordings as recordings

    monkeypatch.setattr(recordings, "track_recording", lambda *a, **k: calls.append(1))
    monkeypatch.setattr(recordings, "track_stream", lambda *a, **k: calls.append(1))
    cases = [["--out", str(folder)], ["--out", str(tmp_path / "afile" / "x.csv")],
             ["--out", str(tmp_path / "o.csv"), "--plot", str(tmp_path / "x.xyz")]]
    for extra in cases:
        assert main(["track", rec, *extra]) == 2, extra
        err = capsys.readouterr().err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    real_access = os.access
    locked = tmp_path / "locked"
    locked.mkdir()
    monkeypatch.setattr(os, "access", lambda p, mode, **k: False if Path(p) == locked else real_access(p, mode, **k))
    assert main(["track", rec, "--out", str(locked / "o.csv")]) == 2
    assert calls == [] and not (tmp_path / "o.csv").exists() and not list(locked.iterdir())


def test_digital_silence_warns_and_the_csv_has_a_vad_column(tmp_path, capsys):
    rec = tmp_path / "silence.wav"
    sf.write(rec, np.zeros((16000 * 2, 12), np.float32), 16000, subtype="FLOAT")
    out = tmp_path / "s.csv"
    for vad in ("webrtc", "none"):
        assert main(["track", str(rec), "--vad", vad, "--out", str(out)]) == 0
        assert "warning" in capsys.readouterr().err
        est = pd.read_csv(out)
        assert "vad" in est.columns and len(est) > 0 and (est.vad == 0).all()


def test_features_zero_sample_rate_is_refused(scene_dir, tmp_path, capsys):
    out = tmp_path / "f.npy"
    assert main(["features", str(scene_dir / "audio.wav"), "--fs", "0", "--resample", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_track_scores_against_the_truth_that_simulate_writes(scene_dir, tmp_path, capsys):
    csv, png = tmp_path / "doa.csv", tmp_path / "doa.png"
    assert main(["track", str(scene_dir / "audio.wav"), "--tracker", "srp-max:32x64", "--truth",
                 str(scene_dir / "truth.csv"), "--out", str(csv), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "RMSAE" in out and "non-silent" in out
    est = pd.read_csv(csv)
    assert est.columns[-1] == "error_deg"
    truth = pd.read_csv(scene_dir / "truth.csv")
    cos = np.sum(est[["x", "y", "z"]].to_numpy() * truth[["x", "y", "z"]].to_numpy(), 1)
    assert np.allclose(est.error_deg, np.degrees(np.arccos(np.clip(cos, -1, 1))), atol=0.3)  # CSV keeps 4 decimals
    rmsae_printed = float(out.split("RMSAE ", 1)[1].split()[0])
    assert rmsae_printed == pytest.approx(float(np.sqrt(np.mean(est.error_deg ** 2))), abs=0.05)
    assert png.stat().st_size > 1000
    # A truth table on another frame grid is a one-line error, before anything is written.
    bad = tmp_path / "short.csv"
    truth.iloc[:-2].to_csv(bad, index=False)
    assert main(["track", str(scene_dir / "audio.wav"), "--truth", str(bad), "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "frames but the tracker makes" in err and "\n" not in err
    assert not (tmp_path / "x.csv").exists()


def test_track_plot_title_names_the_weights(scene_dir, tmp_path, monkeypatch):
    """``--tracker cross3d:4x8`` alone names no weights: the title adds them by name; another file
    by its name and hash; a classical tracker has none to name."""
    import doabench.cli.track as track_cli

    titles = []
    monkeypatch.setattr(track_cli, "plot_track", lambda path, times, directions, vad, title, truth=None:
                        titles.append(title))
    assert main(["track", str(scene_dir / "audio.wav"), "--tracker", "cross3d:4x8", "--out", str(tmp_path / "a.csv"),
                 "--plot", str(tmp_path / "a.png")]) == 0
    assert titles == ["audio.wav: cross3d:4x8, weights paper"]
    other = {"weights_hash": "0123456789abcdef" * 4, "weights_name": None, "weights": "/x/mine.safetensors"}
    assert track_cli.plot_title("r.wav", "cross3d:4x8", other) == \
        "r.wav: cross3d:4x8, weights mine.safetensors (sha256 0123456789ab)"
    assert track_cli.plot_title("r.wav", "srp-max", {"weights_hash": None}) == "r.wav: srp-max"


def test_track_plot_keeps_its_legend_off_the_curves_and_names_the_polar_angle():
    from doabench.cli.track import track_figure
    from doabench.geometry import angles_to_unit
    from test_plot_styles import _assert_legends_clear_of_axes

    # Curves high on both panels (where a legend inside would sit), silent frames in the legend too.
    times = np.arange(100) * 0.192
    up = angles_to_unit(np.radians(np.full(100, 170.0)), np.radians(np.linspace(150, 179, 100)))
    vad = np.arange(100) % 7 != 0
    for truth in (None, up[::-1]):
        fig = track_figure(times, up, vad, "rec.wav: srp-max:16x32 with a long title", truth)
        _assert_legends_clear_of_axes(fig)
        azimuth, elevation = fig.axes
        assert "polar angle from zenith" in elevation.get_ylabel() and "azimuth" in azimuth.get_ylabel()
        assert elevation.get_ylim() == (0, 180)


# -- long recordings stream: block by block, same bytes as the offline computation --------------

def _bursty_recording(path, seconds: float, fs: int = 16000, channels: int = 12, seed: int = 3) -> None:
    """Noise with loud bursts (voice-active for the WebRTC VAD) and quiet gaps, written in blocks."""
    rng = np.random.default_rng(seed)
    total, block = int(seconds * fs), 7 * fs
    with sf.SoundFile(str(path), "w", fs, channels, subtype="PCM_16") as f:
        for start in range(0, total, block):
            n = min(block, total - start)
            t = (start + np.arange(n)) / fs
            gain = np.where((t % 3) < 1.7, 0.25, 0.003)[:, None]
            f.write((rng.standard_normal((n, channels)) * gain).clip(-1, 1).astype(np.float32))


def _offline_track_csv(rec, name: str, opts=(), resample: bool = False, vad: str = "webrtc") -> str:
    """What `doabench track` wrote before it streamed: the whole recording in memory."""
    from doabench.arrays import get_array
    from doabench.cli.track import track_table
    from doabench.runner.recordings import recording_vad, track_recording
    from doabench.recording import load_recording
    from doabench.trackers.registry import make_tracker, parse_options

    tracker = make_tracker(name, **parse_options(list(opts)))
    array = get_array("nao")
    audio, _ = load_recording(rec, array, tracker.frame_spec.fs, resample, min_samples=tracker.frame_spec.window)
    if not np.any(audio):
        sample_vad = np.zeros(audio.shape[-1], bool)
    else:
        sample_vad = recording_vad(audio, tracker.frame_spec.fs) if vad == "webrtc" else None
    out = track_recording(tracker, array, audio, sample_vad)
    return track_table(out).to_csv(index=False, float_format="%.4f")


def _offline_features_npy(rec, kind: str, resample: bool = False, extra=()) -> bytes:
    import io

    from doabench.arrays import get_array
    from doabench.features import FeatureExtractor
    from doabench.framing import FrameSpec
    from doabench.recording import load_recording

    array, spec = get_array("nao"), FrameSpec()
    audio, _ = load_recording(rec, array, spec.fs, resample, min_samples=spec.window)
    ex = FeatureExtractor(array, kinds=(kind,), resolution=(16, 32), mode="nearest", frame_spec=spec,
                          spectrogram_frame_spec=spec)
    buf = io.BytesIO()
    np.save(buf, ex(audio)[kind].numpy().astype(np.float32, copy=False))
    return buf.getvalue()


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("long") / "long.wav"
    _bursty_recording(path, 150)  # 2.5 minutes, 12 channels
    return path


def test_streamed_track_and_features_equal_the_offline_bytes(long_recording, tmp_path, monkeypatch, capsys):
    """A multi-minute recording, read in blocks (also an odd block size, not a multiple of the hop or
    of the VAD's 10 ms): the CSV and the .npy are byte-identical to the whole-recording computation."""
    import io

    import doabench.recording as recording

    expected_csv = _offline_track_csv(long_recording, "srp-max")
    expected_npy = _offline_features_npy(long_recording, "srp")
    assert 0 < pd.read_csv(io.StringIO(expected_csv)).vad.mean() < 1  # both kinds of frame
    for block in (recording.BLOCK_SAMPLES, 50_001):
        monkeypatch.setattr(recording, "BLOCK_SAMPLES", block)
        csv, npy = tmp_path / f"t{block}.csv", tmp_path / f"f{block}.npy"
        assert main(["track", str(long_recording), "--out", str(csv)]) == 0
        assert csv.read_text() == expected_csv, block
        assert main(["features", str(long_recording), "--kind", "srp", "--out", str(npy)]) == 0
        # SRP maps: torch reduces a block of frames in another order than the whole recording
        # (up to 2e-7 here); same header, shape and values within float32 rounding.
        got, want = npy.read_bytes(), expected_npy
        assert got[:128] == want[:128] and len(got) == len(want)
        np.testing.assert_allclose(np.load(npy), np.load(io.BytesIO(want)), atol=1e-6, rtol=0)
        assert np.load(npy).shape == (780, 16, 32)
        npy = tmp_path / f"g{block}.npy"  # GCC-PHAT: exactly the same bytes
        assert main(["features", str(long_recording), "--kind", "gcc", "--out", str(npy)]) == 0
        assert npy.read_bytes() == _offline_features_npy(long_recording, "gcc"), block


def test_streamed_track_other_trackers_vad_and_resampling_equal_offline(tmp_path, monkeypatch):
    """Raw-audio (music), non-causal (seldnet) and --resample (48 kHz input, streamed polyphase
    resampling) paths, and a mostly quiet recording whose VAD falls back to a milder mode."""
    import doabench.recording as recording

    monkeypatch.setattr(recording, "BLOCK_SAMPLES", 40_000)
    rec = tmp_path / "r.wav"
    _bursty_recording(rec, 20)
    rec48 = tmp_path / "r48.wav"
    _bursty_recording(rec48, 12, fs=48000)
    cases = [(rec, "music", [], []), (rec, "seldnet", ["weights=random"], []), (rec, "srp-max", [], ["--vad", "none"]),
             (rec48, "srp-max", [], ["--resample"])]
    for path, name, opts, extra in cases:
        csv = tmp_path / "o.csv"
        argv = ["track", str(path), "--tracker", name, "--out", str(csv), *extra]
        for o in opts:
            argv += ["--tracker-opt", o]
        assert main(argv) == 0, name
        want = _offline_track_csv(path, name, opts, resample="--resample" in extra,
                                  vad="none" if "none" in extra else "webrtc")
        assert csv.read_text() == want, (name, extra)
    npy = tmp_path / "s.npy"
    assert main(["features", str(rec48), "--kind", "spectrogram", "--resample", "--out", str(npy)]) == 0
    assert npy.read_bytes() == _offline_features_npy(rec48, "spectrogram", resample=True)


def test_streamed_vad_mode_fallback_and_resampler_equal_offline(tmp_path):
    from doabench.corpora.vad import webrtc_vad
    from doabench.recording import Recording, StreamingWebrtcVad, read_audio, resample

    rng = np.random.default_rng(0)
    fs = 16000
    x = rng.standard_normal(fs * 6 + 77).astype(np.float32) * 0.002
    x[fs:fs + 4000] *= 200  # mostly quiet: mode 3 keeps too little, the fallback decides
    audio = np.stack([x, 0.5 * x])
    ref, ref_mode = webrtc_vad(audio.mean(0) / float(np.max(np.abs(audio.mean(0)))), fs)
    for block in (160, 999, 50_000):
        v = StreamingWebrtcVad(fs, float(np.max(np.abs(audio.mean(0)))))
        for s in range(0, audio.shape[1], block):
            v.push(audio[:, s:s + block])
        d, mode = v.finish()
        assert mode == ref_mode and np.array_equal(v.sample_vad(d, 0, audio.shape[1]), ref), block
    for sr in (44100, 22050, 8000):
        p = tmp_path / f"{sr}.wav"
        sf.write(p, rng.standard_normal((int(sr * 2.1) + 5, 2)).astype(np.float32) * 0.1, sr, subtype="FLOAT")
        a, _ = read_audio(p)
        want = resample(a, sr, fs)
        for block in (1000, 16_384):
            r = Recording(p, 2, sr, a.shape[1], fs)
            assert r.samples == want.shape[1]
            assert np.array_equal(np.concatenate(list(r.blocks(block)), axis=1), want), (sr, block)
