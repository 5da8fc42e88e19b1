"""One scoring rule everywhere: `doabench.metrics.score_frames` (invalid truth left out, planar
arrays folded, silent frames in the all-frames RMSAE only) behind `run`, `track --truth` and the
scripts; `simulate --task T --episode N` + `track --truth --vad truth` reproduces `run`'s numbers."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from doabench.cli.main import main
from doabench.errors import ConfigError
from doabench.framing import frame_vad, samples_from_frame_vad
from doabench.metrics import score_episode, score_frames

ROOT = Path(__file__).resolve().parents[1]


def test_score_frames_leaves_out_invalid_truth_and_folds_planar_arrays():
    truth = np.array([[0.6, 0.0, -0.8], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    est = np.array([[0.6, 0.0, 0.8], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    vad = np.array([True, False, True])
    valid = np.array([True, True, False])
    folded = score_frames(est, truth, vad, valid, planar=True)
    assert folded.keep.tolist() == [True, True, False] and folded.n_invalid == 1
    assert folded.errors == pytest.approx([0.0, 0.0], abs=1e-6)
    assert folded.vad.tolist() == [True, False]
    plain = score_frames(est, truth, vad, valid, planar=False)
    assert plain.errors[0] == pytest.approx(np.degrees(np.arccos(0.36 - 0.64)), abs=1e-6)
    m = score_episode(est, truth, vad, valid, planar=False, times=np.arange(3) * 0.192)
    assert m["frames_scored"] == 2 and m["frames_invalid"] == 1
    assert m["rmsae_all"] == pytest.approx(plain.errors[0] / np.sqrt(2))
    assert m["rmsae_nonsilent"] == pytest.approx(plain.errors[0])
    assert m["lag_s"] is None and "lag_note" in m


def test_a_per_frame_vad_becomes_per_sample_activity_exactly():
    rng = np.random.default_rng(0)
    n = 4096 + 3072 * 40
    frames = rng.random(41) < 0.5
    assert np.array_equal(frame_vad(samples_from_frame_vad(frames, n, 4096, 3072), 4096, 3072), frames)
    with pytest.raises(ConfigError, match="frame VAD values"):
        samples_from_frame_vad(frames[:-1], n, 4096, 3072)
    # half-window hops: an inactive frame between two active ones would read as active
    with pytest.raises(ConfigError, match="overlap too much"):
        samples_from_frame_vad(np.array([True, False, True]), 4096 * 2, 4096, 2048)


def test_simulate_and_track_with_the_truth_vad_reproduce_run(tmp_path, capsys):
    """Episode 1 of sim-demo (10 s, embedded speech): `doabench run` and `doabench simulate
    --episode 1` + `doabench track --truth --vad truth` give the same estimates and scores."""
    scene, runs = tmp_path / "scene", tmp_path / "runs"
    assert main(["run", "--tracker", "srp-max:8x16", "--task", "sim-demo", "--episodes", "2", "--out", str(runs),
                 "--quiet"]) == 0
    results = json.loads((runs / "sim-demo__srp-max_8x16.json").read_text())
    row, frames = results["episodes"][1], results["frames"][1]
    assert row["episode"] == 1
    assert main(["simulate", "--task", "sim-demo", "--episode", "1", "--out", str(scene)]) == 0
    capsys.readouterr()
    doa = tmp_path / "doa.csv"
    assert main(["track", str(scene / "audio.wav"), "--tracker", "srp-max:8x16", "--truth", str(scene / "truth.csv"),
                 "--vad", "truth", "--out", str(doa)]) == 0
    printed = capsys.readouterr().out
    table = pd.read_csv(doa)
    assert table.vad.tolist() == [int(v) for v in frames["vad"]]
    assert np.allclose(table[["x", "y", "z"]].to_numpy(), frames["estimates"], atol=2e-4)  # the CSV keeps 4 decimals
    assert f"RMSAE {row['rmsae_all']:.2f} deg all frames, {row['rmsae_nonsilent']:.2f} deg non-silent" in printed
    assert f"MAE {row['mae']:.2f}, median {row['median']:.2f}" in printed
    lag = "-" if row["lag_s"] is None else f"{row['lag_s']:.2f} s"
    assert f"lag {lag}" in printed
    # the WebRTC VAD (track's default) is another VAD: other features, other silent frames
    assert main(["track", str(scene / "audio.wav"), "--tracker", "srp-max:8x16", "--truth", str(scene / "truth.csv"),
                 "--out", str(tmp_path / "webrtc.csv")]) == 0
    assert pd.read_csv(tmp_path / "webrtc.csv").vad.tolist() != table.vad.tolist()


def test_track_scores_a_planar_array_against_the_folded_truth(tmp_path, capsys):
    ring = [[0.05 * np.cos(a), 0.05 * np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)]
    array = tmp_path / "ring6.json"
    array.write_text(json.dumps({"name": "ring6", "positions": ring}))
    scene = tmp_path / "scene"
    assert main(["simulate", "--t60", "0.3", "--snr", "20", "--seed", "2", "--duration", "3", "--array", str(array),
                 "--out", str(scene)]) == 0
    doa = tmp_path / "doa.csv"
    assert main(["track", str(scene / "audio.wav"), "--array", str(array), "--tracker", "srp-max:8x16",
                 "--truth", str(scene / "truth.csv"), "--vad", "truth", "--out", str(doa)]) == 0
    printed = capsys.readouterr().out
    assert "planar array: scored against mirror-folded truth" in printed
    est, truth = pd.read_csv(doa), pd.read_csv(scene / "truth.csv")
    xyz = ["x", "y", "z"]
    scored = score_frames(est[xyz].to_numpy(), truth[xyz].to_numpy(), truth.vad.to_numpy(bool), planar=True)
    assert f"RMSAE {scored.summary()['rmsae_all']:.2f} deg all frames" in printed
    assert np.allclose(est.error_deg, scored.errors, atol=0.05)


def test_vad_truth_needs_a_truth_table(tmp_path, capsys):
    rec = tmp_path / "r.wav"
    import soundfile as sf

    sf.write(rec, np.zeros((16000, 12), np.float32), 16000, subtype="FLOAT")
    assert main(["track", str(rec), "--vad", "truth", "--out", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--vad truth" in err and "\n" not in err and "Traceback" not in err


def test_compare_scores_results_frames_as_run_does(tmp_path, capsys):
    """`doabench compare --silence` splits a results file's per-frame error as `doabench run` scored
    it, on a planar array file with invalid frames (through doabench.metrics.score_frames): its
    voice-active row is the run's non-silent RMSAE and its rows after the first voice the
    all-frames one."""
    truth = np.array([[0.6, 0.0, -0.8], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    est = np.array([[0.6, 0.0, 0.8], [0.0, 0.8, 0.6], [0.0, 0.0, 1.0], [0.0, 0.6, 0.8]])
    vad, valid = [True, True, True, False], [True, True, False, True]
    m = score_frames(est, truth, np.array(vad), np.array(valid), planar=True).summary()
    results = {"schema": "doabench.results/1", "tracker": {"id": "t"}, "task": {"id": "x", "version": 1},
               "scoring": {"planar_fold": True}, "episodes": [{"episode": 0, "seed": 1}],
               "frames": [{"times": [0.1, 0.3, 0.5, 0.7], "estimates": est.tolist(), "truth": truth.tolist(),
                           "vad": vad, "valid": valid}]}
    path = tmp_path / "r.json"
    path.write_text(json.dumps(results))
    assert main(["compare", str(path), "--silence"]) == 0
    rows = {line.split("|")[1].strip(): line.split("|")[2:5] for line in capsys.readouterr().out.splitlines()
            if line.startswith("| ") and line.count("|") == 5}
    assert float(rows["0 (voice-active)"][1]) == pytest.approx(m["rmsae_nonsilent"], abs=0.005)
    # the first frame is voice-active, so every scored frame (3 of 4: one has invalid truth) comes after it
    assert rows["before the first voice"][0].strip() == "0"
    after = rows["after the first voice (all but the row above)"]
    assert int(after[0]) == 3 and float(after[1]) == pytest.approx(m["rmsae_all"], abs=0.005)


def test_the_environment_reward_folds_a_planar_array_as_the_scores_do():
    """Gymnasium users scoring by the reward get what `run` scores: for a planar array the mirror
    image of the truth costs nothing."""
    from dataclasses import replace

    from conftest import QUICK_SCENE
    from doabench.envs.env import DoaEnv

    env = DoaEnv("sim-demo", features=("srp",), resolution=(4, 8), scene_overrides=QUICK_SCENE)
    env.reset(options={"episode": 0})
    while not env.step(np.array([1.0, 0.0, 0.0]))[2]:  # the truth is told once the episode is over
        pass
    truth = env.episode_truth()["directions"]
    env.reset(options={"episode": 0})
    mirror = truth[0] * np.array([1.0, 1.0, -1.0])
    if abs(truth[0][2]) < 1e-3:
        pytest.skip("the truth lies in the array plane: its mirror image is itself")
    _, reward, *_ = env.step(mirror)
    assert reward < -1e-3  # the NAO head is not planar: the mirror image is an error
    env.reset(options={"episode": 0})
    env.array = replace(env.array, planar=True)  # the same geometry, scored as a planar array's
    _, reward, *_ = env.step(mirror)
    assert reward == pytest.approx(0.0, abs=1e-9)
    est = np.tile(mirror, (len(truth), 1))
    env.reset(options={"episode": 0})
    errors = env.score_offline(est)
    expected = score_frames(est, truth, np.ones(len(truth), bool), planar=True).errors
    assert np.allclose(np.degrees(errors), expected, atol=1e-9)
