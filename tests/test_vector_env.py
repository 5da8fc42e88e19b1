"""Vector environments: gymnasium.make_vec with the doabench environments (the async mode, fork on
Linux, must not hang after torch work in the parent; spawn works too), and doabench's make_vec,
which splits a task's episodes across sub-environments without repetition. Async runs are in
subprocesses with a timeout, so a hang fails the test instead of stopping the suite."""
from __future__ import annotations

import subprocess
import sys

import pytest

from conftest import ROOT

SCRIPT = """
import sys, numpy as np, torch, gymnasium as gym, doabench
torch.set_num_threads(2)
x = torch.randn(1500, 1500); float((x @ x).sum())   # torch work in the parent: its thread pool is live
gym_id = doabench.get_task_spec("sim-demo").gym_id
kwargs = dict(features=("srp",), resolution=(4, 8), scene_overrides={"duration_s": 1.5, "n_points": 12})
vector_kwargs = {"context": sys.argv[1]} if sys.argv[1] != "default" else None
envs = gym.make_vec(gym_id, num_envs=2, vectorization_mode="async", vector_kwargs=vector_kwargs, **kwargs)
obs, info = envs.reset(seed=0, options={"episode": 1})
assert obs["srp"].shape == (2, 4, 8), obs["srp"].shape
assert list(info["episode"]) == [1, 1]
obs, reward, terminated, truncated, info = envs.step(np.tile([1.0, 0.0, 0.0], (2, 1)))
assert reward.shape == (2,) and np.all(reward <= 0) and np.all(np.isfinite(reward))
assert info["error_rad"].shape == (2,)
envs.close()
print("ok")
"""


@pytest.mark.parametrize("context", ["default", "spawn"])
def test_async_vector_env_after_torch_work(context: str) -> None:
    try:
        proc = subprocess.run([sys.executable, "-c", SCRIPT, context], cwd=ROOT, capture_output=True, text=True,
                              timeout=240)
    except subprocess.TimeoutExpired:
        pytest.fail(f"make_vec(async, context={context}) hung after torch work in the parent")
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-3000:]


# -- splitting a task's episodes across sub-environments -------------------------------------------
def _four_episode_task():
    import uuid

    from doabench.envs.registry import register_task

    (spec,) = register_task({"id": f"vec-four-{uuid.uuid4().hex[:8]}", "version": 0, "kind": "simulated",
                             "array": "nao", "episodes": 4, "base_seed": 31, "speech": {"corpus": "embedded"},
                             "scene": {"duration_s": 1.5, "n_points": 12}})
    return spec


def _run_until_each_env_finished(envs, passes: int) -> list[tuple[int, int, int]]:
    """(sub-env, episode, repeat) of every episode the sub-environments started."""
    import numpy as np

    n = envs.num_envs
    obs, info = envs.reset(seed=0)
    started = [(k, int(info["episode"][k]), int(info["repeat"][k])) for k in range(n)]
    finished = np.zeros(n, int)
    for _ in range(1000):
        obs, reward, terminated, truncated, info = envs.step(np.tile([1.0, 0.0, 0.0], (n, 1)))
        for k in np.flatnonzero(info.get("_episode", np.zeros(n, bool))):
            started.append((int(k), int(info["episode"][k]), int(info["repeat"][k])))
        finished += terminated
        if finished.min() >= passes:
            return started
    raise AssertionError("the episodes never ended")


def test_vector_env_splits_a_task_without_repetition() -> None:
    from doabench.envs.vector import make_vec, split_episodes

    assert split_episodes(4, 2) == [[0, 2], [1, 3]] and split_episodes(5, 2) == [[0, 2, 4], [1, 3]]
    spec = _four_episode_task()
    envs = make_vec(spec.id, num_envs=2, vectorization_mode="sync", features=("srp",), resolution=(4, 8))
    try:
        assert [list(s) for s in envs.call("episode_share")] == [[0, 2], [1, 3]]
        started = _run_until_each_env_finished(envs, passes=2)
    finally:
        envs.close()
    first_pass = [episode for _, episode, repeat in started if repeat == 0]
    assert sorted(first_pass) == [0, 1, 2, 3]  # episodes 0-3, each exactly once
    assert {(k, e) for k, e, r in started if r == 0} == {(0, 0), (0, 2), (1, 1), (1, 3)}


def test_episode_share_is_checked() -> None:
    from doabench.envs.env import DoaEnv
    from doabench.errors import InputError

    spec = _four_episode_task()
    for bad in ([], [0, 0], [4], "x"):
        with pytest.raises(InputError):
            DoaEnv(spec.id, features=("srp",), resolution=(4, 8), episodes=bad)
    from doabench.envs.vector import make_vec

    with pytest.raises(InputError, match="5 sub-environments for 4 episodes"):
        make_vec(spec.id, num_envs=5, vectorization_mode="sync", features=("srp",), resolution=(4, 8))


SPLIT_SCRIPT = """
import sys, numpy as np, doabench
from doabench.envs.registry import register_task
from doabench.envs.vector import make_vec
(spec,) = register_task({"id": "vec-four-async", "version": 0, "kind": "simulated", "array": "nao", "episodes": 4,
                         "base_seed": 31, "speech": {"corpus": "embedded"}, "scene": {"duration_s": 1.5, "n_points": 12}})
vector_kwargs = {"context": sys.argv[1]} if sys.argv[1] != "default" else None
envs = make_vec(spec, num_envs=2, features=("srp",), resolution=(4, 8), vector_kwargs=vector_kwargs)
obs, info = envs.reset(seed=0)
seen = [int(e) for e in info["episode"]]
finished = np.zeros(2, int)
while finished.min() < 2:
    obs, reward, terminated, truncated, info = envs.step(np.tile([1.0, 0.0, 0.0], (2, 1)))
    seen += [int(info["episode"][k]) for k in np.flatnonzero(info.get("_episode", np.zeros(2, bool)))
             if info["repeat"][k] == 0]
    finished += terminated
envs.close()
assert sorted(seen) == [0, 1, 2, 3], seen
print("ok")
"""


@pytest.mark.parametrize("context", ["default", "spawn"])
def test_async_vector_env_splits_a_run_time_task(context: str) -> None:
    """Async workers (forked, or spawned: a fresh interpreter without the parent's run-time
    registrations) each run their share of a task registered at run time."""
    try:
        proc = subprocess.run([sys.executable, "-c", SPLIT_SCRIPT, context], cwd=ROOT, capture_output=True,
                              text=True, timeout=300)
    except subprocess.TimeoutExpired:
        pytest.fail(f"make_vec(async, context={context}) hung")
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-3000:]


def test_environment_doc_example_of_the_split_runs() -> None:
    """docs/environment.md's make_vec example runs as shown (with short scenes) and prints what
    its comments say."""
    text = (ROOT / "docs" / "environment.md").read_text()
    blocks = [b for b in text.split("```python\n")[1:] if "vector import make_vec" in b.split("```")[0]]
    assert len(blocks) == 1, "docs/environment.md should show one make_vec example"
    code = blocks[0].split("```")[0]
    fast = code.replace('resolution=(8, 16))', 'resolution=(8, 16), scene_overrides={"duration_s": 1.5, "n_points": 12})', 1)
    assert fast != code
    proc = subprocess.run([sys.executable, "-c", fast], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    shown = [line.split("# ", 1)[1].split(":")[0].strip() for line in code.splitlines()
             if line.startswith("print(") and "# " in line]
    assert proc.stdout.split("\n")[:2] == shown, (proc.stdout, shown)
