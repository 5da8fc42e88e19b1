"""``pyroomacoustics-full``: pyroomacoustics for the whole response, with no doabench tail.

The ``pyroomacoustics`` backend (:mod:`doabench.acoustics.backends.pra`) takes only the image
sources up to Tdiff from pyroomacoustics and adds doabench's diffuse tail, so it checks the image
sources alone. This backend renders the whole RIR, ``[0, Tmax)``, with pyroomacoustics' image
sources to the reflection order of ``pyroomacoustics.inverse_sabine``'s rule (the order whose
images fill a sphere of radius ``c t``; here ``t = Tmax``, where the RIR ends,
:meth:`PyroomacousticsFullSimulator.image_order`), so the late field is pyroomacoustics' image
sources too. What it shares with doabench: the room (walls absorb
``1 - beta**2`` of the energy, ``beta`` from Sabine's formula with the room's absorption weights,
which is ``inverse_sabine``'s absorption when the weights are equal), the pinned settings of the
``pyroomacoustics`` backend (33-tap fractional delay, ``c = 343``; but pyroomacoustics' own 10 Hz
high-pass filter is on here, see :meth:`PyroomacousticsFullSimulator.settings`), the RIR length
(Tmax, the 40 dB decay time, as every engine) and the moving-source convolution.

Cost: the order grows as ``c T60 / L``, the images as its cube; a 20 s, 156-point trajectory at
T60 0.9 s takes minutes (benchmarks/bench_simulation.py).
"""
from __future__ import annotations

import numpy as np
import torch

from doabench.acoustics import rir_model
from doabench.acoustics.backends.pra import PyroomacousticsSimulator
from doabench.acoustics.room import Room
from doabench.geometry import SPEED_OF_SOUND


class PyroomacousticsFullSimulator(PyroomacousticsSimulator):
    """pyroomacoustics' image sources for the whole RIR (module docstring); ``seed`` has no
    effect (the model draws nothing)."""

    name = "pyroomacoustics-full"
    # One source per pyroomacoustics room: at the orders a T60 needs (tens to hundreds) a room's
    # image arrays are tens of MB per source.
    SOURCES_PER_ROOM = 1

    def settings(self) -> dict:
        """The ``pyroomacoustics`` backend's pinned settings, with pyroomacoustics' own high-pass
        filter on (its defaults: 2nd-order Butterworth at 10 Hz, zero-phase): a long pure
        image-source response builds up a low-frequency offset (every image adds a positive pulse)
        that decays slower than the T60 and lengthened the measured T20 by about 25 %; the filter
        is pyroomacoustics' remedy. Zero-phase, so arrival times stay."""
        out = super().settings()
        out.update({"rir_hpf_enable": True, "rir_hpf_fc": 10.0,
                    "rir_hpf_kwargs": {"n": 2, "rp": 5.0, "rs": 60.0, "type": "butter"}})
        return out

    def versions(self) -> dict[str, str]:
        out = super().versions()
        out.update({
            "tail": "none: pyroomacoustics image sources for the whole RIR",
            "max_order": "pyroomacoustics inverse_sabine(Tmax, room dimensions)",
            "absorption": "1 - beta**2 per wall, beta from doabench's Sabine formula with the absorption weights",
            "tmax": "40 dB decay",
        })
        return out

    def image_order(self, room: Room) -> int:
        """The reflection order of pyroomacoustics' ``inverse_sabine`` rule for the kept response:
        the order whose images fill a sphere of radius ``c Tmax`` (0 for an anechoic room).

        ``inverse_sabine(T60, dims)`` gives the order for a radius of ``c T60`` (the 60 dB
        decay); the RIR ends at Tmax (40 dB), and images farther than ``c Tmax`` arrive after it,
        so the rule is applied to Tmax: the same RIR in ``[0, Tmax)`` from ``(2/3)**3``, about a
        third, of the images."""
        if room.t60 == 0:
            return 0
        import pyroomacoustics as pra

        dims = list(room.dims)
        try:
            _, order = pra.inverse_sabine(room.max_time(), dims, c=SPEED_OF_SOUND)
        except ValueError:  # its absorption check refuses so short a time in a very absorbing room
            _, order = pra.inverse_sabine(room.t60, dims, c=SPEED_OF_SOUND)  # a larger order: covers more
        return int(order)

    def rirs_parts(
        self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator, width: int | None = None
    ) -> rir_model.RirParts | None:
        return None  # complete RIRs only: there is no shared tail to convolve apart

    def rirs_tensor(self, room: Room, sources: np.ndarray, mics: np.ndarray, fs: int, generator) -> torch.Tensor:
        """RIRs ``(S, M, n_taps)`` float32 on the backend's device, ``n_taps = round(Tmax fs)``
        (longer only when a direct path arrives late)."""
        layout, _ = rir_model.plan(room, torch.tensor(sources), torch.tensor(mics), fs)
        h = self.render(room, sources, mics, fs, layout.n_taps, self.image_order(room))
        return torch.as_tensor(h, device=self.device)
