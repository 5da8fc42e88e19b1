"""gymnasium.make_vec with the doabench environments (issue 15): the async mode (fork on Linux)
must not hang after torch work in the parent; spawn works too. Run in subprocesses with a
timeout, so a hang fails the test instead of stopping the suite."""
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
