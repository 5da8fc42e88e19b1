"""One observation pipeline: recording audio -> per-frame observations, named, shaped and spaced.

An :class:`ObservationPlan` is an :class:`~doabench.features.spec.ObservationSpec` (the kinds, each
with its settings, on one frame grid) on one array, with one or more SRP grids. It owns

* the per-frame shape and the Gymnasium ``spaces.Box`` of each kind (what :class:`DoaEnv` declares);
* the extractor passes: one :class:`~doabench.features.FeatureExtractor` pass per SRP resolution,
  the kinds off the grid (gcc, spectrogram, ...) riding on the first one (they share its STFT);
* :meth:`ObservationPlan.compute`: audio ``(M, L)`` + sample VAD -> ``{name: (T, ...)}`` arrays;

so that the environment, ``make-dataset``, ``doabench track``, the ONNX example input and the
plots compute observations the same way. Names and dataset paths: :mod:`doabench.features.kinds`.

torch is imported only by :meth:`~ObservationPlan.compute` and the extractor builders: building a
plan to describe spaces (``gymnasium.make``) needs none.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Sequence, cast

import numpy as np
from gymnasium import spaces

from doabench.arrays import MicArray, get_array
from doabench.features.configs import DEFAULT_RESOLUTION
from doabench.features.kinds import DelayMode, FrameContext, feature_kind, frame_shape_of, item_name
from doabench.framing import FrameSpec, frame_signal
from doabench.geometry import as_grid

if TYPE_CHECKING:  # torch is imported lazily (see the module docstring)
    from doabench.features.streaming import StreamingFeatureExtractor
    from doabench.features.transforms import FeatureExtractor

#: What an extractor pass computes when a plan asks for framed audio only: the extractor still
#: validates the audio and frames the VAD (the observations' ``vad``), as every other plan's does.
VAD_ONLY_KINDS = ("srp_max",)


def framed_audio(audio: np.ndarray, frame_spec: FrameSpec) -> np.ndarray:
    """The ``audio`` observation: ``(M, L)`` samples -> ``(T, M, window)`` float32 frames.

    A strided view of ``audio`` (no copy); the environment copies each frame it hands out.
    """
    frames = frame_signal(np.asarray(audio, np.float32), frame_spec.window, frame_spec.hop)  # (M, T, K)
    return np.moveaxis(frames, 0, 1)


def _grid(resolution: str | Sequence[int]) -> tuple[int, int]:
    """``"16x32"`` as trackers may declare it, or ``(n_theta, n_phi)``, as a tuple, bounded before
    any space or table of its size is built (:func:`~doabench.features.spec.as_grid`)."""
    return as_grid(resolution)


class ObservationPlan:
    """The observations ``spec`` of recordings made with ``array`` (usually built by
    :meth:`ObservationSpec.plan <doabench.features.spec.ObservationSpec.plan>`).

    ``resolutions``: the SRP grids ``(n_theta, n_phi)`` or ``"16x32"`` the kinds on the grid are
    computed on (None: the spec's own grid); the other kinds are computed once. Spaces and
    :meth:`observations` describe the first grid.
    """

    # spec: an ObservationSpec (typed Any: doabench.features.spec imports this module to build plans)
    def __init__(self, spec: Any, array: MicArray | str,
                 resolutions: Sequence[str | Sequence[int]] | None = None) -> None:
        self.spec = spec
        self.kinds = spec.kind_names
        self.array = get_array(array)
        self.frame_spec = spec.frames
        grids = resolutions if resolutions else (spec.resolution or DEFAULT_RESOLUTION,)
        self.resolutions = tuple(_grid(r) for r in grids)
        self.delays = spec.delays or "nearest"
        self.spectrogram_frame_spec = spec.spectrogram_frame_spec
        self._extractors: dict[tuple[bytes, tuple[str, ...], tuple[int, int]], FeatureExtractor] = {}

    # -- description ------------------------------------------------------------------------------
    @property
    def resolution(self) -> tuple[int, int]:
        """The first SRP grid: the one of :meth:`spaces` and :meth:`observations`."""
        return self.resolutions[0]

    @property
    def extractor_kinds(self) -> tuple[str, ...]:
        """The kinds a FeatureExtractor computes (framed kinds are not); never empty."""
        return tuple(k for k in self.kinds if not feature_kind(k).framed) or VAD_ONLY_KINDS

    def names(self) -> list[str]:
        """Canonical name of every item :meth:`compute` returns for ``kinds``, in pass order."""
        out = [item_name(k, res) for ks, res in self.passes() for k in ks]
        return out + [k for k in self.kinds if feature_kind(k).framed]

    def passes(self) -> list[tuple[tuple[str, ...], tuple[int, int]]]:
        """``(kinds, resolution)`` of each extractor pass: every extractor kind on the first grid,
        then the kinds on the grid (srp, srp_max, a plug-in map) on each further grid."""
        first = self.extractor_kinds
        maps = tuple(k for k in first if feature_kind(k).on_grid)
        return [(first, self.resolution)] + ([(maps, r) for r in self.resolutions[1:]] if maps else [])

    def frame_context(self) -> FrameContext:
        """What the per-frame shapes depend on (the first grid)."""
        return FrameContext(self.array, self.frame_spec, self.resolution, self.spectrogram_frame_spec)

    def frame_shape(self, kind: str) -> tuple[int, ...]:
        """Per-frame shape of ``kind`` (without the frame axis) on the first grid."""
        return frame_shape_of(feature_kind(kind), self.frame_context())

    def space(self, kind: str) -> spaces.Box:
        """The Gymnasium box of one frame of ``kind`` (float32, the kind's bounds)."""
        k = feature_kind(kind)
        return spaces.Box(k.low, k.high, self.frame_shape(kind), np.float32)

    def observation_space(self) -> spaces.Dict:
        """``{kind: Box}`` for each of ``kinds`` plus ``vad``: ``Discrete(2)``."""
        space: dict[str, spaces.Space[Any]] = {k: self.space(k) for k in self.kinds}
        space["vad"] = spaces.Discrete(2)
        return spaces.Dict(space)

    # -- computation ------------------------------------------------------------------------------
    def extractor(self, array: MicArray | None = None, kinds: Sequence[str] | None = None,
                  resolution: Sequence[int] | None = None) -> FeatureExtractor:
        """The (cached) :class:`~doabench.features.FeatureExtractor` of one pass for ``array``
        (default: the plan's; a recording may bring its own measured geometry)."""
        from doabench.features.transforms import FeatureExtractor

        array = array or self.array
        kinds = self.extractor_kinds if kinds is None else tuple(kinds)
        grid = self.resolution if resolution is None else cast("tuple[int, int]", tuple(resolution))  # as _grid
        key = (array.positions.tobytes(), kinds, grid)
        if key not in self._extractors:
            # the delays are checked by the extractor (ConfigError) when it computes maps
            mode = cast(DelayMode, self.delays)
            self._extractors[key] = FeatureExtractor(array, kinds=kinds, resolution=grid, mode=mode,
                                                     frame_spec=self.frame_spec,
                                                     spectrogram_frame_spec=self.spectrogram_frame_spec)
        return self._extractors[key]

    def streaming_extractor(self, array: MicArray | None = None) -> StreamingFeatureExtractor:
        """A :class:`~doabench.features.StreamingFeatureExtractor` of the first pass (one grid)."""
        from doabench.features.streaming import StreamingFeatureExtractor

        return StreamingFeatureExtractor(array or self.array, kinds=self.extractor_kinds, resolution=self.resolution,
                                         mode=self.delays, frame_spec=self.frame_spec,
                                         spectrogram_frame_spec=self.spectrogram_frame_spec)

    def compute(self, audio: np.ndarray, sample_vad: np.ndarray | None, array: MicArray | None = None,
                device: str | None = None) -> dict[str, np.ndarray]:
        """Observations of one recording, ``{name: (T, ...)}`` numpy arrays keyed by :meth:`names`.

        ``audio``: ``(M, L)``; ``sample_vad``: ``(L,)`` bool/0-1, None for all active (features of
        silent frames are zero). Extractor outputs are float32 (``srp:RxC (T, R, C)``,
        ``srp_max:RxC (T, 2)``, ``gcc (T, P, lags)``, ``spectrogram (T, 2M, K/2)``), ``audio``
        is ``(T, M, window)`` float32 (a view of ``audio``), ``vad (T,)`` int64 is the first
        pass's frame VAD (and ``spectrogram_vad`` when the spectrogram has its own grid).
        """
        import torch

        x = torch.as_tensor(np.ascontiguousarray(audio), dtype=torch.float32, device=device)[None]
        vad = None if sample_vad is None else torch.as_tensor(np.asarray(sample_vad, bool), device=device)[None]
        out: dict[str, np.ndarray] = {}
        with torch.inference_mode():
            for kinds, res in self.passes():
                feats = self.extractor(array, kinds, res)(x, vad)
                for key, value in feats.items():
                    # the VADs are the same in every pass: the first one's is kept
                    out.setdefault(item_name(key, res), value[0].detach().cpu().numpy())
        for kind in self.kinds:
            if feature_kind(kind).framed:  # the recording's own samples (``audio``), framed
                out[kind] = framed_audio(audio, self.frame_spec)
        out["vad"] = out["vad"].astype(np.int64)
        return out

    def observations(self, audio: np.ndarray, sample_vad: np.ndarray | None, array: MicArray | None = None,
                     device: str | None = None) -> dict[str, np.ndarray]:
        """:meth:`compute` keyed by kind (``srp`` rather than ``srp:16x32``), as environments and
        trackers read them: ``{kind: (T, ...)}`` plus ``vad (T,)`` int64. One grid only."""
        if len(self.resolutions) > 1:
            raise ValueError("observations() describes one SRP grid; use compute() for several")  # a doabench bug
        return {name.partition(":")[0]: v for name, v in self.compute(audio, sample_vad, array, device).items()}
