"""Environments and `doabench run`: Gymnasium compliance, determinism, plugins, sanity scores."""
import json

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import doabench
from doabench.cli.main import main
from doabench.envs.env import DoaEnv
from doabench.errors import TrackerError
from doabench.runner import run_task

from conftest import QUICK_SCENE, ROOT, TINY_SCENE


def _sim_tasks():
    return [t for t, s in doabench.available_tasks().items() if s.kind == "simulated"]


@pytest.mark.parametrize("task_id", _sim_tasks())
def test_check_env_passes_for_every_simulated_task(task_id, librispeech_root):
    env = gymnasium.make(doabench.get_task_spec(task_id).gym_id, features=("srp", "srp_max", "gcc"),
                         resolution=(4, 8), librispeech=str(librispeech_root), scene_overrides=TINY_SCENE,
                         cache_size=8)
    check_env(env.unwrapped, skip_render_check=True)


def test_reset_with_seed_is_deterministic_and_truth_comes_after_the_step():
    env = gymnasium.make("doabench/sim-demo-v2", features=("srp", "gcc"), resolution=(8, 16),
                         scene_overrides=QUICK_SCENE)
    obs1, info1 = env.reset(seed=7)
    obs2, info2 = env.reset(seed=7)
    assert info1["episode"] == info2["episode"]
    for k in obs1:
        np.testing.assert_array_equal(obs1[k], obs2[k])
    assert "truth" not in info1
    _, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0, 0.0], np.float32))
    assert info["truth"].shape == (3,) and reward == pytest.approx(-info["error_rad"])
    # a second environment renders the same episode bit for bit
    other = DoaEnv("sim-demo", features=("srp",), resolution=(8, 16), scene_overrides=QUICK_SCENE)
    o, _ = other.reset(options={"episode": info1["episode"]})
    np.testing.assert_array_equal(o["srp"], obs1["srp"])


def test_episode_streams_one_frame_per_step_until_terminated():
    env = DoaEnv("sim-demo", features=("srp",), resolution=(4, 8), scene_overrides=QUICK_SCENE)
    obs, info = env.reset(options={"episode": 0})
    n = info["n_frames"]
    assert n == 1 + (3 * 16000 - 4096) // 3072
    steps, terminated = 0, False
    while not terminated:
        obs, _, terminated, _, _ = env.step(np.array([0.0, 0.0, 1.0]))
        steps += 1
    assert steps == n
    with pytest.raises(gymnasium.error.ResetNeeded):
        env.step(np.array([0.0, 0.0, 1.0]))


class _NaNTracker(doabench.Tracker):
    name = "nan-tracker"

    def step(self, observation):
        return np.array([np.nan, 0.0, 0.0])


class _WrongShapeTracker(doabench.Tracker):
    name = "wrong-shape"

    def step(self, observation):
        return np.zeros(2)


@pytest.mark.parametrize("tracker,message", [(_NaNTracker(), "nan-tracker.*non-finite"),
                                             (_WrongShapeTracker(), r"wrong-shape.*shape \(2,\)")])
def test_misbehaving_tracker_is_stopped_with_its_name(tracker, message):
    with pytest.raises(TrackerError, match=message):
        run_task(tracker, "sim-demo", episodes=1, progress=False, scene_overrides=QUICK_SCENE)


def test_docs_example_tracker_runs_from_outside_the_package(tmp_path, monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(ROOT / "docs" / "examples"))
    code = main(["run", "--tracker", "centroid_tracker:CentroidTracker", "--tracker-opt", "top=3",
                 "--task", "sim-demo", "--episodes", "1", "--out", str(tmp_path), "--quiet"])
    assert code == 0, capsys.readouterr().err
    results = json.loads(next(tmp_path.glob("*.json")).read_text())
    assert results["tracker"]["name"] == "srp-centroid"
    assert results["summary"]["rmsae_nonsilent"] < 60
    assert {"rmsae_all", "rmsae_nonsilent"} <= set(results["summary"])
    assert results["environment"]["git"]["commit"] is None or len(results["environment"]["git"]["commit"]) == 40
    assert not list(tmp_path.glob(".*partial*"))  # the resume file is gone after success
    csv = next(tmp_path.glob("*.csv")).read_text().splitlines()
    assert len(csv) == 2 and "rmsae_all" in csv[0]


def test_run_resumes_from_partial_file(tmp_path):
    partial = tmp_path / "p.jsonl"
    seen = []
    first = run_task("srp-max:4x8", "sim-demo", episodes=2, progress=lambda i, r: seen.append(i),
                     partial_path=partial, scene_overrides=QUICK_SCENE)
    assert seen == [0, 1]
    seen.clear()
    again = run_task("srp-max:4x8", "sim-demo", episodes=2, progress=lambda i, r: seen.append(i),
                     partial_path=partial, scene_overrides=QUICK_SCENE)
    assert seen == []  # both episodes came from the partial file
    assert again["summary"]["rmsae_all"] == first["summary"]["rmsae_all"]


def test_bad_ids_exit_nonzero_without_results(tmp_path, capsys):
    assert main(["run", "--tracker", "srp-max", "--task", "sim-t60-0.9-snr-55", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "unknown task" in err and "sim-t60-0.9-snr-5" in err
    assert not any(tmp_path.iterdir())


def test_srp_max_sanity_bound_on_low_reverb_cell(librispeech_root):
    """srp-max at 32x64 on sim-t60-0.3-snr-30 (two 20 s episodes): RMSAE on non-silent frames < 15 deg."""
    res = run_task("srp-max:32x64", "sim-t60-0.3-snr-30", episodes=2, progress=False,
                   librispeech=str(librispeech_root))
    assert res["summary"]["rmsae_nonsilent"] < 15.0, res["summary"]


@pytest.fixture(scope="module")
def locata_fixture(tmp_path_factory):
    from fixtures.locata import write_fixture

    root = tmp_path_factory.mktemp("locata")
    write_fixture(root, tasks=(1, 3, 5), duration_s=2.0, simulator="freefield", seed=1)
    return root


@pytest.mark.parametrize("task_id", [t for t, s in doabench.available_tasks().items() if s.kind == "locata"])
def test_check_env_passes_for_every_locata_task(task_id, locata_fixture):
    env = gymnasium.make(doabench.get_task_spec(task_id).gym_id, features=("srp", "srp_max"), resolution=(4, 8),
                         locata_root=str(locata_fixture))
    check_env(env.unwrapped, skip_render_check=True)


class _HugeTracker(doabench.Tracker):
    name = "huge"

    def __init__(self, scale):
        super().__init__()
        self.scale = scale

    def step(self, observation):
        return np.array([self.scale, 0.0, 0.0])


def test_a_huge_direction_scores_as_the_direction_it_is():
    """[1e200, 0, 0] used to overflow to a zero vector and score 0 deg (ranking first)."""
    unit = run_task(_HugeTracker(1.0), "sim-demo", episodes=1, progress=False, scene_overrides=QUICK_SCENE)
    huge = run_task(_HugeTracker(1e200), "sim-demo", episodes=1, progress=False, scene_overrides=QUICK_SCENE)
    assert unit["summary"]["rmsae_all"] > 1.0
    assert huge["summary"]["rmsae_all"] == pytest.approx(unit["summary"]["rmsae_all"])


def test_a_zero_direction_is_refused():
    with pytest.raises(TrackerError, match="huge"):
        run_task(_HugeTracker(0.0), "sim-demo", episodes=1, progress=False, scene_overrides=QUICK_SCENE)


def _one_line_error(capsys):
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err


def test_bad_run_inputs_are_one_line_errors_checked_first(tmp_path, monkeypatch, capsys):
    plugin = tmp_path / "plugins"
    plugin.mkdir()
    (plugin / "broken_mod.py").write_text("raise RuntimeError('boom at import')\n")
    (plugin / "raising_mod.py").write_text(
        "import doabench\n\n\nclass Mid(doabench.Tracker):\n    name = 'mid'\n\n"
        "    def step(self, observation):\n        raise ZeroDivisionError('mid-episode')\n")
    monkeypatch.syspath_prepend(str(plugin))
    afile = tmp_path / "afile"
    afile.write_text("x")
    base = ["run", "--task", "sim-demo", "--episodes", "1", "--quiet"]
    out = tmp_path / "out"
    for tracker, where in (("srp-max:100000x100000", out), ("broken_mod:X", out), ("raising_mod:Mid", out),
                           ("srp-max:4x8", afile), ("srp-max:4x8", afile / "sub")):
        assert main(base + ["--tracker", tracker, "--out", str(where)]) == 2, tracker
        err = _one_line_error(capsys)
        if "mod" in tracker:
            assert tracker.split(":")[1].lower() in err.lower() or "broken_mod" in err
    assert afile.read_text() == "x"
    assert not out.exists()  # no results, journal or folder left behind


def test_run_and_sweep_use_one_torch_thread_unless_told(tmp_path, monkeypatch, capsys):
    import torch

    before = torch.get_num_threads()
    try:
        for command in (["run", "--tracker", "srp-max:4x8", "--task", "sim-demo"],
                        ["sweep", "--trackers", "srp-max:4x8", "--tasks", "sim-demo"]):
            torch.set_num_threads(2)
            assert main(command + ["--threads", "0", "--out", str(tmp_path / "out")]) == 2
            assert "--threads must be at least 1" in _one_line_error(capsys) and not (tmp_path / "out").exists()
        # train keeps its own default (None: the trainer chooses) and refuses the same bad values
        assert main(["train", "--tracker", "cross3d:4x8", "--threads", "-1", "--out", str(tmp_path / "out")]) == 2
        assert "--threads must be at least 1" in _one_line_error(capsys) and not (tmp_path / "out").exists()
        torch.set_num_threads(2)
        assert main(["run", "--tracker", "srp-max:4x8", "--task", "sim-demo", "--episodes", "1", "--quiet",
                     "--out", str(tmp_path / "out")]) == 0
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_a_grid_too_fine_is_refused_before_allocating():
    from doabench.errors import ConfigError
    from doabench.geometry import parse_resolution

    with pytest.raises(ConfigError):
        parse_resolution("100000x100000")
    assert parse_resolution("64x128") == (64, 128)


def _stop_after_first(i, record):
    raise KeyboardInterrupt


def test_resume_repairs_a_cut_line_and_adds_up_wall_time(tmp_path):
    import time

    partial = tmp_path / ".p.partial.jsonl"
    with pytest.raises(KeyboardInterrupt):
        run_task("srp-max:4x8", "sim-demo", episodes=2, progress=_stop_after_first, partial_path=partial,
                 scene_overrides=QUICK_SCENE)
    lines = partial.read_text().splitlines()
    assert len(lines) == 2
    first_wall = json.loads(lines[1])["wall_s"]
    assert first_wall > 0
    partial.write_text(lines[0] + "\n" + lines[1] + "\n" + lines[1][: len(lines[1]) // 2])  # a crash cut a line
    seen = []
    start = time.perf_counter()
    res = run_task("srp-max:4x8", "sim-demo", episodes=2, progress=lambda i, r: seen.append(i), partial_path=partial,
                   scene_overrides=QUICK_SCENE)
    second = time.perf_counter() - start
    assert seen == [1]
    for line in partial.read_text().splitlines():
        json.loads(line)  # the fragment is gone; the new episode's line stands on its own
    assert len(partial.read_text().splitlines()) == 3
    assert first_wall < res["wall_time_s"] <= first_wall + second
    assert not (tmp_path / ".p.lock").exists()


def test_garbage_journal_header_is_a_one_line_error(tmp_path, capsys):
    from doabench.results.writer import results_stem

    partial = tmp_path / f".{results_stem('sim-demo', 'srp-max:4x8')}.partial.jsonl"
    partial.write_text("\x00garbage{\n")
    args = ["run", "--tracker", "srp-max:4x8", "--task", "sim-demo", "--episodes", "1", "--out", str(tmp_path),
            "--quiet"]
    assert main(args) == 2
    _one_line_error(capsys)
    assert partial.read_text() == "\x00garbage{\n" and not list(tmp_path.glob("*.json"))


def test_two_runs_with_the_same_out_are_refused(tmp_path, capsys):
    from doabench.results.writer import results_stem
    from doabench.runner import run_lock

    partial = tmp_path / f".{results_stem('sim-demo', 'srp-max:4x8')}.partial.jsonl"
    args = ["run", "--tracker", "srp-max:4x8", "--task", "sim-demo", "--episodes", "1", "--out", str(tmp_path),
            "--quiet"]
    with run_lock(partial):  # as if another `doabench run` were running
        assert main(args) == 2
        _one_line_error(capsys)
        assert not list(tmp_path.glob("*.json")) and not partial.exists()
    with pytest.raises(doabench.DoabenchError):
        with run_lock(partial):
            run_task("srp-max:4x8", "sim-demo", episodes=1, progress=False, partial_path=partial,
                     scene_overrides=QUICK_SCENE)


def test_a_learned_tracker_runs_on_the_delays_it_was_trained_on_unless_asked(tmp_path):
    import doabench
    from doabench.results.identity import results_delays
    from doabench.trackers.base import resolve_delays

    tracker = doabench.make_tracker("cross3d:4x8")
    assert tracker.trained_delays == "nearest"
    assert resolve_delays(tracker, None) == ("nearest", None)
    assert resolve_delays(tracker, "exact") == ("exact", "nearest")  # on purpose: recorded
    assert resolve_delays(doabench.make_tracker("srp-max:4x8"), None) == ("nearest", None)
    quick = {"duration_s": 3.0, "n_points": 12}
    default = doabench.run(tracker="cross3d:4x8", task="sim-demo", episodes=1, progress=False, scene_overrides=quick)
    assert results_delays(default) == "nearest" and "trained_delays" not in default
    other = doabench.run(tracker="cross3d:4x8", task="sim-demo", episodes=1, progress=False, scene_overrides=quick,
                         delays="exact")
    assert results_delays(other) == "exact" and other["trained_delays"] == "nearest"
