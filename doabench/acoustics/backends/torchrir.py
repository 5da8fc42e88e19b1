"""``torchrir``: the torchrir library (PyPI, Apache-2.0) as a whole, image sources and late field.

torchrir is a PyTorch image-source simulator for static and moving scenes on CPU or CUDA. This
backend uses its model throughout and shares only the room (dimensions, T60 and the Sabine
reflection coefficients), the RIR lengths and the moving-source convolution with doabench:

* **Image sources, ``[0, Tdiff)``**: torchrir's ISM over the image grid of
  ``torchrir.util.acoustics.estimate_image_counts_from_tmax(Tdiff)`` (every image index up to
  ``c Tdiff / L`` per axis, gpuRIR's rule), each image ``prod(beta) / r`` at delay ``r / c``,
  band-limited by torchrir's Hann-windowed sinc of ``frac_delay_length = 81`` taps (its default;
  tabulated with 20 phases per sample and interpolated). Amplitudes are divided by ``4 pi`` here
  (doabench's convention, ``1 / (4 pi r)``, as for pyroomacoustics).
* **Late field, ``[Tdiff, Tmax)``**: torchrir's own diffuse tail: Gaussian noise decaying at the
  T60 that torchrir computes back from the reflection coefficients by Sabine's formula (the asked
  T60, since the coefficients come from it by the same formula), its level set per trajectory point
  and microphone to the RMS of the last 10 ms of that point's image-source part, joined to it by a
  5 ms power-complementary crossfade. One noise carrier per microphone (seeded from ``seed``) is
  shared by all trajectory points, each point scaling it by its own level.
* **Reflection coefficients**: doabench's (:meth:`doabench.acoustics.room.Room.reflection_coefficients`,
  Sabine's formula with the room's absorption weights), passed to torchrir as ``beta``: torchrir's
  own ``t60`` argument gives six equal coefficients and would ignore the weights.
* **Tdiff and Tmax**: torchrir's ``attenuation_db_to_time_sabine`` at 12 and 40 dB (the times
  doabench and gpuRIR use). Tdiff moves later when a direct path arrives after it, so no direct
  sound is replaced by the tail.
* **Moving sources and microphones**: one torchrir ``DynamicScene`` frame per trajectory point (the
  array's pose at that point for a moving array); the per-point RIRs are convolved by doabench's
  shared overlap-add (:mod:`doabench.acoustics.convolution`).

Cost: every image is spread over 81 taps for every point and microphone, so the CPU is slow: a
20 s, 156-point sim-walk trajectory at T60 0.9 s took about 33 s on one loaded core (a whole
srp-max run of it on the builtin engine: 0.8 s); CUDA is what torchrir is for.

Reproducibility: the same seed gives the same audio on one device. torchrir draws its tail noise
with a generator on the simulation device, so CPU and CUDA renderings of one seed have the same
image-source part (to float32 rounding) but different tail noise.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from doabench.acoustics import compute
from doabench.acoustics import rir_model
from doabench.acoustics.backends.base import TorchBackend
from doabench.acoustics.room import DIFFUSE_START_DB, MAX_TIME_DB, Room
from doabench.errors import ConfigError, DependencyError
from doabench.geometry import SPEED_OF_SOUND

TORCHRIR_INSTALL = 'torchrir is not installed: pip install "doabench[torchrir]"'

FRAC_DELAY_LENGTH = 81  # torchrir's default fractional-delay length (taps), kept as its model
SINC_LUT_GRANULARITY = 20  # torchrir's default lookup-table phases per sample
# Bound on one image chunk's (points x microphones x images x taps) temporaries: torchrir's
# accumulation allocates about ten tensors of that size per chunk (int64 indices among them), 2 MB
# each at 256k elements. On CUDA larger chunks amortise the kernel launches.
_CHUNK_ELEMENTS = 1 << 18
_CHUNK_ELEMENTS_CUDA = 1 << 25  # about 3 GB of temporaries
_POINTS_PER_CALL = 32  # trajectory points per torchrir call on the CPU (more on CUDA)
_POINTS_PER_CALL_CUDA = 512


_MALLOC_WARMED: list[bool] = []


def _raise_malloc_threshold() -> None:
    """Allocate and free one 24 MB block, once per process.

    glibc's malloc gives blocks above its mmap threshold (128 kB at start) fresh mappings and
    trims the heap's free top beyond twice that threshold; the threshold rises to the size of the
    largest mapped block freed so far, up to 32 MB (the dynamic threshold of mallopt(3)). torchrir
    allocates its temporaries afresh for every image chunk, so until the threshold has risen each
    chunk page-faults its memory anew: a 16-point batch at T60 1.2 s took 34 s in a fresh process
    instead of 12 s, more than half of it in the kernel. Freeing a 24 MB block raises the threshold
    at once. Elsewhere than glibc it is one harmless allocation."""
    if not _MALLOC_WARMED:
        block = torch.empty(24 << 20, dtype=torch.uint8)
        del block
        _MALLOC_WARMED.append(True)


class TorchrirSimulator(TorchBackend):
    """torchrir's image sources and diffuse tail (module docstring), on ``device`` (CPU or CUDA).

    ``rirs`` returns ``(S, M, n_taps)`` float32 with ``n_taps = round(Tmax fs)`` (longer only when
    a direct path arrives late); ``simulate`` convolves them with doabench's trajectory overlap-add.
    """

    name = "torchrir"

    def __init__(self, device: str | torch.device | None = None) -> None:
        try:
            import torchrir
            import torchrir.config
            import torchrir.sim
            import torchrir.util.acoustics
        except ImportError:
            raise DependencyError(TORCHRIR_INSTALL) from None
        self._torchrir = torchrir
        self.device = compute.resolve_device(device)
        if self.device.type == "cpu":
            _raise_malloc_threshold()

    @staticmethod
    def library_version() -> str:
        from importlib import metadata

        try:
            return metadata.version("torchrir")
        except metadata.PackageNotFoundError:  # imported from a source tree
            return "unknown"

    def settings(self) -> dict[str, Any]:
        """The torchrir settings every simulation uses (recorded by :meth:`versions`)."""
        return {
            "frac_delay_length": FRAC_DELAY_LENGTH,
            "sinc_lut_granularity": SINC_LUT_GRANULARITY,
            "use_lut": True,
            "high_pass": None,
            "c": SPEED_OF_SOUND,
            "dtype": "float32",
        }

    def versions(self) -> dict[str, str]:
        out = {
            "backend": self.name,
            "torchrir": self.library_version(),
            "torch": torch.__version__,
            "device": str(self.device),
            "images": f"torchrir ISM, image grid estimate_image_counts_from_tmax(Tdiff), Tdiff at "
                      f"{DIFFUSE_START_DB:g} dB",
            "tail": "torchrir diffuse tail: one noise carrier per microphone, Sabine decay from beta, "
                    "level of the last 10 ms before Tdiff per point, 5 ms crossfade",
            "tmax": f"{MAX_TIME_DB:g} dB decay",
            "beta": "doabench Sabine reflection coefficients (absorption weights)",
            "amplitude": "1/(4 pi r) (torchrir's 1/r divided by 4 pi)",
        }
        out.update({k: str(v) for k, v in self.settings().items()})
        return out

    # ----------------------------------------------------------------------------------------

    def _lengths(self, room: Room, max_delay: float, fs: int) -> tuple[int | None, int]:
        """``(tdiff sample or None when anechoic, n_taps)`` for a batch whose latest direct path
        arrives ``max_delay`` samples after emission."""
        from torchrir.util.acoustics import attenuation_db_to_time_sabine

        direct_end = int(math.ceil(max_delay)) + FRAC_DELAY_LENGTH // 2 + 2  # the direct sinc's last tap
        if room.t60 == 0:
            return None, direct_end
        n_diff = int(round(attenuation_db_to_time_sabine(DIFFUSE_START_DB, room.t60) * fs))
        n_diff = max(n_diff, direct_end)  # a late direct path stays image-source
        n_taps = int(round(attenuation_db_to_time_sabine(MAX_TIME_DB, room.t60) * fs))
        return n_diff, max(n_taps, n_diff + 1)

    def rirs_tensor(self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator) -> torch.Tensor:
        """RIRs ``(S, M, n_taps)`` float32 on the backend's device from ``sources`` ``(S, 3)`` to
        ``mics`` ``(M, 3)`` or ``(S, M, 3)`` (validated room coordinates)."""
        from torchrir import DynamicScene, MicrophoneArray, Source
        from torchrir import Room as TorchrirRoom
        from torchrir.config import SimulationConfig
        from torchrir.sim import simulate
        from torchrir.util.acoustics import estimate_image_counts_from_tmax

        dev = self.device
        S, M = len(sources), mics.shape[-2]
        delays = rir_model.direct_delays(torch.tensor(sources), torch.tensor(mics), fs)
        n_diff, n_taps = self._lengths(room, float(delays.max()), fs)
        # One integer seed per call, drawn from the caller's generator: the same seed gives the same
        # tail noise (torchrir derives each microphone's carrier from it).
        seed = int(torch.randint(0, 2**62, (1,), generator=generator))
        dtype = torch.float32
        beta = torch.as_tensor(room.reflection_coefficients(), dtype=dtype, device=dev)
        t_room = TorchrirRoom.shoebox(list(room.dims), fs=float(fs), c=SPEED_OF_SOUND, beta=beta, device=dev, dtype=dtype)
        if n_diff is None:
            limits: dict[str, Any] = {"max_order": 0}
        else:
            counts = estimate_image_counts_from_tmax(n_diff / fs, torch.tensor(room.dims), c=SPEED_OF_SOUND)
            limits = {"nb_img": tuple(int(v) for v in counts), "tdiff": (n_diff - 0.5) / fs, "seed": seed}
        per_call = min(S, _POINTS_PER_CALL if dev.type == "cpu" else _POINTS_PER_CALL_CUDA)
        budget = compute.work_elements(dev, _CHUNK_ELEMENTS, _CHUNK_ELEMENTS_CUDA)
        image_chunk = int(min(2048, max(16, budget // (per_call * M * FRAC_DELAY_LENGTH))))
        config = SimulationConfig(
            **limits, nsample=n_taps, device=dev, dtype=dtype, frac_delay_length=FRAC_DELAY_LENGTH,
            sinc_lut_granularity=SINC_LUT_GRANULARITY, use_lut=True, image_chunk_size=image_chunk,
            accumulate_chunk_size=image_chunk,
        )
        src = torch.tensor(sources, dtype=dtype, device=dev)
        mic = torch.tensor(mics, dtype=dtype, device=dev)
        out = torch.empty(S, M, n_taps, dtype=torch.float32, device=dev)
        # Chunks of trajectory points bound memory; every chunk gets the same seed, and torchrir's
        # carrier depends only on it, so the result does not depend on the chunking.
        for p0 in range(0, S, per_call):
            p1 = min(S, p0 + per_call)
            src_traj = src[p0:p1, None, :]  # (T, 1, 3): one source, T frames
            mic_traj = mic[p0:p1] if mic.dim() == 3 else mic.expand(p1 - p0, M, 3)
            scene = DynamicScene(
                room=t_room,
                sources=Source.from_positions(src_traj[0], device=dev, dtype=dtype),
                mics=MicrophoneArray.from_positions(mic_traj[0], device=dev, dtype=dtype),
                src_traj=src_traj,
                mic_traj=mic_traj.contiguous(),
            )
            try:
                h = simulate(scene, config).rirs  # (T, 1, M, n_taps), amplitude 1 / r
            except ValueError as exc:  # torchrir's checks (e.g. no energy to set its tail level from)
                raise ConfigError(f"torchrir could not simulate this room: {exc}") from None
            out[p0:p1] = h[:, 0].to(torch.float32) / (4.0 * math.pi)
        return out
