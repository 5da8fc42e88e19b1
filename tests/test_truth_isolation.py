"""A tracker sees only what a deployed tracker would: the array, the frame spec, the task id and the
observations. A tracker that searches everything it is given for truth (the scene, the source
trajectory, the array position, directions, T60/SNR, seeds) and uses whatever it finds scores no
better than the SRP-PHAT argmax it otherwise is."""
from __future__ import annotations

import dataclasses
import types
from typing import Any, Iterator

import gymnasium
import numpy as np
import pytest

import doabench
from doabench.envs.env import DoaEnv
from doabench.geometry import great_circle_error
from doabench.runner import run_task
from doabench.trackers.base import ResetContext
from doabench.trackers.srp import SrpMaxTracker

from conftest import QUICK_SCENE

RESOLUTION = (8, 16)
EPISODES = 2
ALLOWED_CONTEXT = {"frame_spec", "task"}
RESET_INFO = {"episode", "n_frames", "frame_times"}
STEP_INFO = {"frame", "truth", "vad", "error_rad", "time_s", "no_source"}  # the frame just scored
# Names under which an episode's truth or scene would be found.
TRUTH_WORDS = {"metadata", "scene", "room", "dims", "t60", "snr", "snr_db", "seed", "speech", "trajectory",
               "trajectory_params", "position", "source_position", "truth", "direction", "directions", "doa",
               "azimuth", "elevation", "sample_directions", "duration_s", "start", "end", "array_rotation",
               "rotation", "pose", "array_pose", "yaw", "pitch", "roll", "walk", "recording"}


def walk(obj: Any, path: str = "", seen: set[int] | None = None, depth: int = 0) -> Iterator[tuple[str, Any]]:
    """Every ``(path, value)`` reachable from ``obj``: mapping items, sequence items and the
    attributes (properties included) of any object, recursively."""
    seen = set() if seen is None else seen
    if depth > 12 or id(obj) in seen:
        return
    yield path, obj
    if isinstance(obj, (str, bytes, int, float, complex, bool, type(None), np.generic, np.ndarray, type,
                        types.ModuleType, types.FunctionType, types.BuiltinFunctionType, types.MethodType)):
        return
    seen.add(id(obj))
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from walk(v, f"{path}.{k}", seen, depth + 1)
        return
    if isinstance(obj, (list, tuple, set, frozenset)):
        for i, v in enumerate(obj):
            yield from walk(v, f"{path}[{i}]", seen, depth + 1)
        return
    names = {f.name for f in dataclasses.fields(obj)} if dataclasses.is_dataclass(obj) else set()
    names |= {n for n in dir(obj) if not n.startswith("__")}
    for name in sorted(names):
        try:
            value = getattr(obj, name)
        except Exception:
            continue
        if callable(value) and not isinstance(value, (np.ndarray, dict, list, tuple)):
            continue
        yield from walk(value, f"{path}.{name}", seen, depth + 1)


def truth_like(obj: Any) -> dict[str, Any]:
    """The values reachable from ``obj`` whose name says truth or scene, by their path."""
    found = {}
    for path, value in walk(obj):
        last = path.rsplit(".", 1)[-1].split("[")[0].lower()
        if last in TRUTH_WORDS and value is not None:
            found[path] = value
    return found


def _vectors(found: dict[str, Any], name: str) -> list[np.ndarray]:
    out = []
    for path, value in found.items():
        if path.rsplit(".", 1)[-1].split("[")[0].lower() == name:
            try:
                a = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                continue
            if a.ndim >= 1 and a.shape[-1] == 3 and np.all(np.isfinite(a)):
                out.append(a)
    return out


class TruthSeeker(SrpMaxTracker):
    """srp-max that looks for the truth in everything it is given and uses what it finds.

    Reset: the array, every context keyword and every attribute reachable from them. Step: the
    observation. A truth direction (``truth``/``direction(s)``/``doa``), or a source trajectory
    with the array position (the room-frame geometry, as a scene description carries it), becomes
    the estimate; without either it is srp-max exactly."""

    name = "truth-seeker"

    def __init__(self, spec: str | None = "8x16", **options: Any) -> None:
        super().__init__(spec, **options)

    def reset(self, array: doabench.MicArray, **context: Any) -> None:
        super().reset(array, **context)
        self.context_keys = set(context)
        self.found = truth_like({"array": array, **context})
        self.frame_spec_seen = context.get("frame_spec") or self.frame_spec
        self.found_in_steps: dict[str, Any] = {}
        self.t = 0
        self.cheated = 0

    def _cheat(self, found: dict[str, Any]) -> np.ndarray | None:
        for name in ("truth", "direction", "directions", "doa", "sample_directions"):
            for a in _vectors(found, name):
                return a if a.ndim == 1 else a[min(self.t, len(a) - 1)]
        trajectories = [a for a in _vectors(found, "trajectory") if a.ndim == 2]
        positions = [a for a in _vectors(found, "position") if a.ndim == 1]
        if trajectories and positions:
            traj, pos = trajectories[0], positions[0]
            durations = [float(v) for p, v in found.items() if p.endswith("duration_s")]
            fs = self.frame_spec_seen
            centre = (self.t * fs.hop + fs.window / 2) / fs.fs
            i = int(centre / durations[0] * len(traj)) if durations else len(traj) // 2
            d = traj[min(max(i, 0), len(traj) - 1)] - pos
            return d if np.any(d) else None
        return None

    def step(self, observation):
        estimate = super().step(observation)
        in_step = truth_like({"observation": observation})
        self.found_in_steps.update(in_step)
        cheat = self._cheat({**self.found, **in_step})
        self.t += 1
        if cheat is not None:
            self.cheated += 1
            return cheat
        return estimate


def test_the_truth_seeker_finds_and_uses_a_leaked_scene():
    """The detector has teeth: handed an episode's metadata, as `doabench run` once did, it tracks
    the source almost perfectly."""
    env = DoaEnv("sim-demo", features=("srp",), resolution=RESOLUTION, scene_overrides=QUICK_SCENE)
    obs, info = env.reset(options={"episode": 0})
    leaked = env.load_episode(0)[0].metadata
    cheat, honest = TruthSeeker(), SrpMaxTracker("8x16")
    cheat.reset(env.episode_array, frame_spec=env.frame_spec, task="sim-demo", metadata=leaked)
    honest.reset(env.episode_array, frame_spec=env.frame_spec)
    errors: dict[str, list[float]] = {"cheat": [], "honest": []}
    terminated = False
    while not terminated:
        c, h = cheat.step(obs), honest.step(obs)
        obs, reward, terminated, _, step_info = env.step(c)
        errors["cheat"].append(-reward)
        errors["honest"].append(float(great_circle_error(h, step_info["truth"])))
    rmsae = {k: float(np.degrees(np.sqrt(np.mean(np.square(v))))) for k, v in errors.items()}
    assert cheat.cheated == len(errors["cheat"])
    assert rmsae["cheat"] < 5.0 and rmsae["cheat"] < rmsae["honest"] / 2, rmsae


class _ContextRecorder(doabench.Tracker):
    name = "context-recorder"
    observation_spec = doabench.ObservationSpec.of(("srp",), (4, 8))
    contexts: list[dict[str, Any]] = []

    def reset(self, array, **context):
        type(self).contexts.append(dict(context))

    def step(self, observation):
        return np.array([1.0, 0.0, 0.0])


def test_reset_context_is_exactly_the_allowed_keys():
    _ContextRecorder.contexts = []
    run_task(_ContextRecorder(), "sim-demo", episodes=1, progress=False, scene_overrides=QUICK_SCENE)
    (context,) = _ContextRecorder.contexts
    assert set(context) == ALLOWED_CONTEXT == set(ResetContext.__annotations__)
    assert context["task"] == "sim-demo" and isinstance(context["frame_spec"], doabench.FrameSpec)


def test_truth_seeker_run_by_the_runner_scores_no_better_than_srp_max():
    cheat = TruthSeeker()
    seeker = run_task(cheat, "sim-demo", episodes=EPISODES, progress=False, scene_overrides=QUICK_SCENE)
    assert cheat.context_keys == ALLOWED_CONTEXT
    assert cheat.found == {} and cheat.found_in_steps == {}
    assert cheat.cheated == 0
    srp = run_task("srp-max:8x16", "sim-demo", episodes=EPISODES, progress=False, scene_overrides=QUICK_SCENE)
    for key in ("rmsae_all", "rmsae_nonsilent"):
        assert seeker["summary"][key] >= srp["summary"][key] - 1e-9, (key, seeker["summary"][key],
                                                                      srp["summary"][key])
    # The metadata still reaches the results after the episode: the per-episode scene columns.
    assert len(seeker["episodes"]) == EPISODES
    for row in seeker["episodes"]:
        assert row["task"] == "sim-demo" and None not in (row["t60"], row["snr"], row["seed"])


def test_environment_info_holds_no_truth_before_the_frame_is_scored():
    env = gymnasium.make("doabench/sim-demo-v2", features=("srp", "srp_max", "gcc"), resolution=(4, 8),
                         scene_overrides=QUICK_SCENE)
    obs, info = env.reset(options={"episode": 1})
    assert set(info) == RESET_INFO and truth_like(info) == {} and truth_like(obs) == {}
    with pytest.raises(RuntimeError, match="once the episode is over"):
        env.unwrapped.episode_metadata()
    with pytest.raises(RuntimeError, match="once the episode is over"):
        env.unwrapped.episode_truth()
    with pytest.raises(RuntimeError, match="once the episode is over"):
        _ = env.unwrapped.current_episode
    t, terminated = 0, False
    while not terminated:
        obs, _, terminated, _, info = env.step(np.array([0.0, 0.0, 1.0], np.float32))
        assert set(info) == STEP_INFO and info["frame"] == t  # the truth of the frame just scored only
        assert truth_like(obs) == {}
        t += 1
    meta = env.unwrapped.episode_metadata()
    assert meta["scene"]["trajectory"] and meta["episode_index"] == 1 and "seed" in meta
    assert env.unwrapped.episode_truth()["directions"].shape == (t, 3)


def test_offline_path_scores_then_reveals():
    env = DoaEnv("sim-demo", features=("srp",), resolution=(4, 8), scene_overrides=QUICK_SCENE)
    _, info = env.reset(options={"episode": 0})
    assert not env.episode_over
    errors = env.score_offline(np.tile([0.0, 0.0, 1.0], (info["n_frames"], 1)))
    assert errors.shape == (info["n_frames"],) and env.episode_over
    assert env.episode_metadata()["episode_index"] == 0
    with pytest.raises(gymnasium.error.ResetNeeded):
        env.step(np.array([0.0, 0.0, 1.0]))


def test_vector_env_infos_hold_no_truth_before_scoring():
    envs = gymnasium.make_vec("doabench/sim-demo-v2", num_envs=2, vectorization_mode="sync", features=("srp",),
                              resolution=(4, 8), scene_overrides=QUICK_SCENE)
    try:
        obs, info = envs.reset(options={"episode": 0})
        assert {k for k in info if not k.startswith("_")} == RESET_INFO and truth_like(info) == {}
        obs, _, _, _, info = envs.step(np.tile([1.0, 0.0, 0.0], (2, 1)).astype(np.float32))
        assert {k for k in info if not k.startswith("_")} == STEP_INFO and (info["frame"] == 0).all()
        assert truth_like(obs) == {}
    finally:
        envs.close()


def test_a_recordings_own_array_reaches_the_tracker_without_its_file(tmp_path):
    """LOCATA episodes carry their measured array, read from a file beside the recording's truth:
    the tracker gets the positions, not the path."""
    from fixtures.locata import write_fixture

    root = tmp_path / "locata"
    write_fixture(root, tasks=(1,), duration_s=2.0, simulator="freefield", seed=1)
    cheat = TruthSeeker()
    run_task(cheat, "locata-1", episodes=1, progress=False, locata_root=str(root))
    assert cheat.context_keys == ALLOWED_CONTEXT and cheat.found == {} and cheat.cheated == 0
    env = DoaEnv("locata-1", features=("srp",), resolution=(4, 8), locata_root=str(root))
    env.reset(options={"episode": 0})
    strings = [v for _, v in walk({"array": env.episode_array, "frame_spec": env.frame_spec, "task": "locata-1"})
               if isinstance(v, str)]
    assert strings and not any(str(root) in v or str(tmp_path) in v for v in strings), strings
    assert env.load_episode(0)[0].array.source.startswith(str(root))  # the file is where the truth is
