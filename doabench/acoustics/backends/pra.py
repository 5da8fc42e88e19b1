"""``pyroomacoustics``: the same model through ``pyroomacoustics.ShoeBox`` (its image sources and
fractional delays, doabench's diffuse tail); the trusted reference and fallback."""
from __future__ import annotations

import contextlib
import importlib.util
import math

import numpy as np
import torch

from doabench.acoustics import compute
from doabench.acoustics import rir_model
from doabench.acoustics.backends.base import TorchBackend
from doabench.acoustics.room import Room
from doabench.errors import DependencyError


_PRA_WALLS = ("west", "east", "south", "north", "floor", "ceiling")  # = x0, x1, y0, y1, z0, z1


class PyroomacousticsSimulator(TorchBackend):
    """The same model through pyroomacoustics' ShoeBox image sources.

    Pinned settings (restored afterwards): ``frac_delay_length = 33`` (the builtin's sinc width, +-16),
    ``sinc_lut_granularity = 20``, ``rir_hpf_enable = False``, ``c = 343``; no air absorption, no
    ray tracing, no randomised ISM; ``max_order`` = the highest reflection order among the images
    that reach Tdiff. Its RIRs are shifted back by its ``frac_delay_length // 2`` global delay and
    scaled by ``1 / (4 pi)`` (pyroomacoustics uses ``1 / r``), cut at Tdiff, and the builtin's
    shared diffuse tail (:func:`doabench.acoustics.rir_model.shared_tail`, fitted to these early parts)
    is added from there, so builtin and pyroomacoustics differ only in their image sources.
    """

    name = "pyroomacoustics"
    SOURCES_PER_ROOM = 8  # bounds pyroomacoustics' image arrays

    def __init__(self, device: str | torch.device | None = None) -> None:
        if importlib.util.find_spec("pyroomacoustics") is None:
            raise DependencyError("pyroomacoustics is not installed: pip install pyroomacoustics==0.10.1")
        self.device = compute.resolve_device(device)

    def settings(self) -> dict:
        from doabench.geometry import SPEED_OF_SOUND

        return {
            "frac_delay_length": 2 * rir_model.SINC_HALF + 1,
            "sinc_lut_granularity": 20,
            "rir_hpf_enable": False,
            "c": SPEED_OF_SOUND,
        }

    def versions(self) -> dict[str, str]:
        import pyroomacoustics as pra

        out = {"backend": self.name, "pyroomacoustics": pra.__version__, "torch": torch.__version__,
               "tail": rir_model.TAIL_MODEL}
        out.update({k: str(v) for k, v in self.settings().items()})
        return out

    @contextlib.contextmanager
    def _constants(self):
        import pyroomacoustics as pra

        old = {k: pra.constants.get(k) for k in self.settings()}
        try:
            for k, v in self.settings().items():
                pra.constants.set(k, v)
            yield pra
        finally:
            for k, v in old.items():
                pra.constants.set(k, v)

    def max_order(self, room: Room, layout: rir_model.RirLayout, fs: int) -> int:
        """Reflection order that includes every image arriving before the end of the ISM part."""
        if room.t60 == 0:
            return 0
        from doabench.geometry import SPEED_OF_SOUND

        horizon = (layout.n_early + rir_model.SINC_HALF) / fs * SPEED_OF_SOUND
        return int(rir_model.enumerate_images(room, horizon).order.max())

    def early_part(self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, layout) -> np.ndarray:
        """pyroomacoustics' image-source responses ``(S, M, n_early)`` float32 (our conventions)."""
        return self.render(room, sources, mics, fs, layout.n_early, self.max_order(room, layout, fs))

    def render(self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, n_out: int, order: int) -> np.ndarray:
        """pyroomacoustics' image-source responses ``(S, M, n_out)`` float32 to reflection order
        ``order``, in doabench's conventions (arrival at ``r / c``, amplitude ``1 / (4 pi r)``),
        from ``sources`` ``(S, 3)`` to ``mics`` ``(M, 3)`` or ``(S, M, 3)``; walls absorb
        ``1 - beta**2`` of the energy with doabench's reflection coefficients ``beta``."""
        S, M = len(sources), mics.shape[-2]
        early = np.zeros((S, M, n_out), dtype=np.float32)
        beta = room.reflection_coefficients()
        # A moving array (mics (S, M, 3)): one room per point, each with that point's microphones.
        per_room = 1 if mics.ndim == 3 else self.SOURCES_PER_ROOM
        with self._constants() as pra:
            shift = pra.constants.get("frac_delay_length") // 2
            materials = {w: pra.Material(energy_absorption=float(1 - b**2)) for w, b in zip(_PRA_WALLS, beta)}
            for s0 in range(0, S, per_room):  # pyroomacoustics' API is per source
                chunk = sources[s0 : s0 + per_room]
                room_mics = mics[s0] if mics.ndim == 3 else mics
                shoebox = pra.ShoeBox(
                    list(room.dims), fs=fs, materials=materials, max_order=order,
                    air_absorption=False, ray_tracing=False, use_rand_ism=False,
                )
                for p in chunk:
                    shoebox.add_source(list(p))
                shoebox.add_microphone_array(np.asarray(room_mics, dtype=np.float64).T)
                shoebox.compute_rir()
                for m in range(M):
                    for k in range(len(chunk)):
                        h = np.asarray(shoebox.rir[m][k][shift : shift + n_out])
                        early[s0 + k, m, : len(h)] = h / (4 * math.pi)
        return early

    def rirs_parts(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator, width: int | None = None
    ) -> rir_model.RirParts | None:
        src = torch.tensor(sources, device=self.device)
        mic = torch.tensor(mics, device=self.device)
        delays = rir_model.direct_delays(src, mic, fs)
        layout = rir_model.rir_layout(room, float(delays.max()), fs)
        width = layout.n_early if width is None else max(int(width), layout.n_early)
        early = torch.zeros(len(sources), mics.shape[-2], width, dtype=torch.float32, device=self.device)
        early[..., : layout.n_early] = torch.as_tensor(self.early_part(room, sources, mics, fs, layout), device=self.device)
        levels = None
        if room.t60 > 0 and layout.n_taps > layout.n_diff:
            levels = rir_model.tail_level(early[..., : layout.n_early], room, fs, layout, delays)
        return rir_model.RirParts(early, rir_model.shared_tail(levels, room, fs, layout, generator), layout)
