"""The CUDA paths against the CPU: the builtin simulator's torch path, the SRP-PHAT features,
Cross3D inference, `doabench run --device cuda` and training on a GPU.

CI and the CPU machines have no GPU, so every test here skips there (the reason says so);
benchmarks/gpu_check.sh runs them on a lent GPU. Tolerances are float32's: the GPU sums in
another order (cuFFT, cuDNN), so results agree to rounding, not bit for bit (on an H200 the
simulations differed by up to 1.02e-4 relative; a tail noise drawn by CUDA's generator gave 0.5)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import doabench
from doabench.acoustics import native
from doabench.acoustics.room import Room
from doabench.acoustics.scenes import SceneDistribution, sample_scene
from doabench.acoustics.simulators import get_simulator

pytestmark = [pytest.mark.cuda,
              pytest.mark.skipif(not torch.cuda.is_available(),
                                 reason="needs a CUDA device (none here; benchmarks/gpu_check.sh runs these on a GPU)")]

FS = 16000


def _relative(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(np.asarray(b)))


def _angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


def test_builtin_simulation_on_cuda_equals_the_cpu_torch_path():
    room = Room((5.2, 4.1, 2.9), 0.6, (0.9, 0.6, 0.75, 1.0, 0.55, 0.8))
    src = np.linspace([1.0, 1.1, 1.2], [2.6, 3.2, 1.7], 12)
    mics = doabench.get_array("nao").positions + np.array([3.9, 2.5, 1.3])
    x = np.random.default_rng(0).standard_normal(3 * FS)
    with native.disabled("the CUDA comparison is with the same torch path on the CPU"):
        y_cpu = get_simulator("builtin").simulate(room, src, mics, x, FS, seed=5)
    y_gpu = get_simulator("builtin", device="cuda").simulate(room, src, mics, x, FS, seed=5)
    assert y_gpu.shape == y_cpu.shape and np.all(np.isfinite(y_gpu))
    assert _relative(y_gpu, y_cpu) < 5e-4


def test_moving_turning_array_simulates_alike_on_cuda():
    """Per-point microphones (sim-turn's moving, turning array) on the GPU."""
    dist = SceneDistribution(p_static=0.0, walk_p=1.0, array_motion_p=1.0, array_speed=(0.1, 0.3),
                             duration_s=4.0, n_points=32)
    scene = sample_scene(dist, 7)
    assert scene.moving_array
    x = np.random.default_rng(1).standard_normal(int(dist.duration_s * FS))
    with native.disabled("the CUDA comparison is with the same torch path on the CPU"):
        y_cpu = get_simulator("builtin").simulate(scene.room, scene.trajectory, scene.mic_room_positions, x, FS, seed=3)
    y_gpu = get_simulator("builtin", device="cuda").simulate(scene.room, scene.trajectory, scene.mic_room_positions,
                                                             x, FS, seed=3)
    assert _relative(y_gpu, y_cpu) < 5e-4


@pytest.mark.parametrize("delays", ["nearest", "exact"])
def test_srp_phat_maps_on_cuda_equal_the_cpu(delays):
    array = doabench.get_array("nao")
    tracker = doabench.make_tracker("srp-max:16x32")
    plan = tracker.observation_spec.with_delays(delays).plan(array)
    audio = np.random.default_rng(2).standard_normal((len(array.positions), 2 * FS)).astype(np.float32)
    cpu = plan.observations(audio, None, device="cpu")
    gpu = plan.observations(audio, None, device="cuda")
    assert cpu.keys() == gpu.keys()
    assert _relative(gpu["srp"], cpu["srp"]) < 1e-4


def test_cross3d_on_cuda_tracks_as_on_the_cpu():
    """`doabench run --device cuda` scores the episode the CPU scores (features and network on the GPU)."""
    cpu = doabench.run("cross3d:16x32", "sim-demo", episodes=1, device="cpu", progress=False)
    gpu = doabench.run("cross3d:16x32", "sim-demo", episodes=1, device="cuda", progress=False)
    assert gpu["environment"]["device"] == "cuda" and gpu["environment"]["gpu"]
    diff = _angles_deg(np.asarray(gpu["frames"][0]["estimates"]), np.asarray(cpu["frames"][0]["estimates"]))
    assert np.median(diff) < 0.05 and np.mean(diff > 1.0) < 0.02
    assert gpu["summary"]["rmsae_all"] == pytest.approx(cpu["summary"]["rmsae_all"], abs=0.1)


def test_a_learned_tracker_is_made_on_cuda():
    tracker = doabench.make_tracker("cross3d:4x8", device="cuda")
    assert next(tracker.model.parameters()).device.type == "cuda"


def test_train_on_cuda_end_to_end(tmp_path):
    """Builtin simulator, features, model and bf16 autocast on CUDA, with and without data workers."""
    from doabench.cli.main import main as cli
    from doabench.corpora.fixture import write_librispeech_layout
    from doabench.training.checkpoint import load_checkpoint

    corpus = write_librispeech_layout(tmp_path / "LibriSpeech")
    for workers in ("0", "2"):
        out = tmp_path / f"run-{workers}"
        rc = cli(["train", "--tracker", "cross3d:4x8", "--tracker-opt", "weights=random", "--device", "cuda",
                  "--workers", workers, "--epochs", "1", "--epoch-size", "4", "--val-trajectories", "2",
                  "--no-compile", "--librispeech", str(corpus), "--cache-root", str(tmp_path / "cache"),
                  "--out", str(out), "--quiet"])
        assert rc == 0
        state = load_checkpoint(out / "checkpoint.safetensors")
        assert state["device"].startswith("cuda") and state["precision"] == "bf16" and state["epoch"] == 1
