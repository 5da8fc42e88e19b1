#!/usr/bin/env python3
"""Where the compiled image-source kernel spends its time on one slow scene.

Scene 1001 of the benchmark's distribution (moving source; 5.8 x 6.8 x 2.8 m, T60 1.21 s): the
kernel's CPU time with one microphone and with all twelve, so the per-point gathering of the
images within reach (paid once per point) separates from the per-microphone work.

    .venv/bin/python benchmarks/profile_image_kernel.py
"""
from __future__ import annotations

import time

import numpy as np
import torch

from doabench.acoustics import rir as engine
from doabench.acoustics import rir_model
from doabench.acoustics.scenes import SceneDistribution, sample_scene
from doabench.arrays import get_array
from doabench.geometry import SPEED_OF_SOUND

FS = 16000


def main() -> int:
    torch.set_num_threads(1)
    array = get_array("nao")
    scene = sample_scene(SceneDistribution(p_static=0.0), 1001, None, array)
    src = torch.tensor(np.asarray(scene.trajectory))
    mics = torch.tensor(np.asarray(array.positions) + np.asarray(scene.array_position))
    layout, _ = rir_model.plan(scene.room, src, mics, FS)
    images = rir_model.enumerate_images(scene.room, (layout.n_early + rir_model.SINC_HALF) / FS * SPEED_OF_SOUND)
    dims = "x".join(f"{d:.1f}" for d in scene.room.dims)
    print(f"room {dims} m, T60 {scene.room.t60:.2f} s, {len(images)} images, {len(src)} points, "
          f"rows of {layout.n_early} samples, kernel {engine.image_kernel('cpu')}")
    per_mic = {}
    for m in (1, len(mics)):
        out = torch.empty(len(src), m, layout.n_early)
        engine.render_images(images, src, mics[:m], FS, layout.n_early, out=out)  # warm-up (build, caches)
        t0 = time.process_time()
        for _ in range(3):
            engine.render_images(images, src, mics[:m], FS, layout.n_early, out=out)
        per_mic[m] = (time.process_time() - t0) / 3
        print(f"{m:2d} microphone(s): {per_mic[m]:.4f} CPU-s")
    slope = (per_mic[len(mics)] - per_mic[1]) / (len(mics) - 1)
    print(f"per microphone {slope:.4f} s, per-point gathering about {per_mic[1] - slope:.4f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
