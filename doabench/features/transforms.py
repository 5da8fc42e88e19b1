"""Stateful feature transforms: precompute the delay/steering tables once, then map audio to features.

Thin ``torch.nn.Module`` wrappers over :mod:`doabench.features.functional` (the torchaudio
functional/transforms split). Their tables are buffers: ``.to(device)`` moves them, and a
transform called on an input on another device moves itself there first (as the tables were
copied lazily before), so CPU-built extractors still accept CUDA audio.

* :class:`SRPPHAT` -> ``(batch, frames, n_theta, n_phi)`` maps
* :class:`GCCPHAT` -> ``(batch, frames, n_pairs, 2 * max_lag + 1)``
* :class:`Spectrogram` -> ``(batch, frames, 2 * n_mics, window // 2)``
* :class:`FeatureExtractor` -> a dict of several of them on one frame grid, silent frames zeroed.
"""
from __future__ import annotations

from typing import Iterable, Mapping, Sequence

import numpy as np
import torch
from numpy.typing import ArrayLike

from doabench.geometry import resolution_text
from doabench.arrays import MicArray, get_array
from doabench.errors import ConfigError, FeatureKindError, InputError
from doabench.features import functional as F
from doabench.features.context import STFTContext
from doabench.features.configs import DEFAULT_RESOLUTION, DELAY_MODES
from doabench.features.kinds import (
    EXTRACTOR_KINDS,
    DelayMode,
    FeatureKind,
    FrameContext,
    call_kind,
    feature_kind,
    frame_shape_of,
    observation_kinds,
    own_frame_kinds,
)
from doabench.framing import FrameSpec, frame_vad
from doabench.geometry import SPEED_OF_SOUND, as_grid, grid_unit_vectors

# Precompute the exact-mode steering table only below this size; above it the table is rebuilt
# per grid block on every call (cheap next to the beamformer product for many frames).
_STEER_CACHE_BYTES = 256 << 20


def as_resolution(resolution: str | Sequence[int]) -> tuple[int, int]:
    """``(n_theta, n_phi)`` from a pair or a ``"16x32"`` string."""
    return as_grid(resolution)


def prepare_audio(audio: np.ndarray | torch.Tensor, n_mics: int, min_samples: int = 0) -> tuple[torch.Tensor, bool]:
    """Validate audio and return ``((batch, n_mics, samples) float32 tensor, was_batched)``.

    Accepts ``(n_mics, samples)`` or ``(batch, n_mics, samples)``, numpy or torch (device kept).
    """
    if isinstance(audio, np.ndarray):
        if not (np.issubdtype(audio.dtype, np.number) or audio.dtype == bool):
            raise InputError(f"audio has non-numeric dtype {audio.dtype}")
        x = torch.from_numpy(np.ascontiguousarray(audio))
    elif isinstance(audio, torch.Tensor):
        x = audio
    else:
        raise InputError(f"audio must be a numpy array or torch tensor, got {type(audio).__name__}")
    if x.is_complex():
        raise InputError("audio must be real-valued, got complex samples")
    batched = x.ndim == 3
    if x.ndim == 2:
        x = x.unsqueeze(0)
    elif x.ndim != 3:
        raise InputError(f"audio must be (n_mics, samples) or (batch, n_mics, samples), got shape {tuple(x.shape)}")
    if x.shape[1] != n_mics:
        raise InputError(f"audio has {x.shape[1]} channels but the array has {n_mics} microphones")
    x = x.to(torch.float32)
    if not bool(torch.isfinite(x).all()):
        raise InputError("audio contains NaN or infinite samples")
    if x.shape[-1] < min_samples:
        raise InputError(f"recording has {x.shape[-1]} samples, shorter than one {min_samples}-sample window")
    return x, batched


def prepare_vad(
    sample_vad: ArrayLike | torch.Tensor | None, batch: int, samples: int, batched: bool, device: torch.device
) -> torch.Tensor | None:
    """Validate a per-sample VAD; returns ``(batch, samples)`` bool on ``device`` or None."""
    if sample_vad is None:
        return None
    v = torch.as_tensor(np.asarray(sample_vad) if not isinstance(sample_vad, torch.Tensor) else sample_vad)
    if not batched and v.ndim == 1:
        v = v.unsqueeze(0)
    if tuple(v.shape) != (batch, samples):
        want = (batch, samples) if batched else (samples,)
        raise InputError(f"sample VAD has shape {tuple(v.shape)}, expected {want} to match the audio")
    return (v != 0).to(device)


def checked_output(kind: FeatureKind, value: object, shape: tuple[int, ...]) -> torch.Tensor:
    """What a plug-in kind's ``compute`` returned, checked against what it declares: a real tensor
    of ``shape`` (batch, frames, then its frame shape), finite, as float32. Anything else is a
    one-line :class:`FeatureKindError` naming the kind; nothing is cast that would change its
    meaning (complex values are refused, not cut to their real part)."""
    name = kind.name
    if not isinstance(value, torch.Tensor):
        raise FeatureKindError(f"feature kind {name!r} returned {type(value).__name__}; expected a float32 torch "
                               f"tensor of shape {shape}")
    if value.is_complex() or value.dtype == torch.bool:
        raise FeatureKindError(f"feature kind {name!r} returned {str(value.dtype).replace('torch.', '')} values; "
                               "a kind's frames are real float32")
    if tuple(value.shape) != shape:
        raise FeatureKindError(f"feature kind {name!r} returned shape {tuple(value.shape)}; it declares "
                               f"{shape[2:]} a frame, so {shape} was expected")
    value = value.to(torch.float32)
    bad = ~torch.isfinite(value)
    if bool(bad.any()):
        frame = int(bad.reshape(shape[0], shape[1], -1).any(-1).any(0).int().argmax())
        raise FeatureKindError(f"feature kind {name!r} returned NaN or infinite values ({int(bad.sum())} of "
                               f"{value.numel()}, the first in frame {frame} of the block)")
    return value


class _Transform(torch.nn.Module):
    """A feature transform whose tables are buffers (never trained: no parameters)."""

    def follow(self, device: torch.device) -> "_Transform":
        """Move the tables to ``device`` when an input arrives there; returns ``self``."""
        buffer = next(self.buffers(), None)
        if buffer is not None and buffer.device != torch.device(device):
            self.to(device)
        return self


class Spectrogram(_Transform):
    """Magnitude/phase spectrogram features (:func:`functional.spectrogram_features`; ``phase``:
    ``absolute``, or ``relative`` to the first microphone's).

    ``forward(audio (batch, n_mics, samples), vad (batch, frames) | None)`` (call the module) ->
    ``(batch, frames, 2 * n_mics, window // 2)`` float32, silent frames zeroed.
    """

    def __init__(self, frame_spec: FrameSpec = FrameSpec(), phase: str = "absolute") -> None:
        super().__init__()
        if phase not in F.SPECTROGRAM_PHASES:
            raise ConfigError(f"spectrogram phase must be one of {', '.join(F.SPECTROGRAM_PHASES)}, got {phase!r}")
        self.frame_spec, self.phase = frame_spec, phase

    def from_spectra(self, X: torch.Tensor, vad: torch.Tensor | None = None) -> torch.Tensor:
        return F.zero_silent(F.spectrogram_features(X, self.phase), vad)

    def forward(self, audio: torch.Tensor, vad: torch.Tensor | None = None) -> torch.Tensor:
        X = F.stft_frames(audio, self.frame_spec.window, self.frame_spec.hop)
        return self.from_spectra(X, vad)


class GCCPHAT(_Transform):
    """GCC-PHAT of every unique mic pair, lags ``-max_lag..max_lag`` with ``max_lag = array.max_lag(fs)``.

    ``forward(audio (batch, n_mics, samples), vad (batch, frames) | None)`` (call the module) ->
    ``(batch, frames, n_pairs, 2 * max_lag + 1)`` float32, silent frames zeroed.
    """

    pairs: torch.Tensor  # buffers (register_buffer), declared for the type checker
    index: torch.Tensor

    def __init__(self, array: MicArray | str, frame_spec: FrameSpec = FrameSpec(), c: float = SPEED_OF_SOUND) -> None:
        super().__init__()
        self.array = get_array(array)
        self.frame_spec = frame_spec
        self.c = float(c)
        self.max_lag = self.array.max_lag(frame_spec.fs, c)
        if 2 * self.max_lag + 1 > frame_spec.window:
            raise ConfigError(
                f"array {self.array.name!r} needs lags up to {self.max_lag} samples, too many for a "
                f"{frame_spec.window}-sample window"
            )
        pairs = torch.from_numpy(self.array.pairs)
        self.register_buffer("pairs", pairs, persistent=False)  # (n_pairs, 2) mic indices
        self.register_buffer("index", F.gram_lag_index(pairs, self.array.n_mics, self.max_lag), persistent=False)

    @property
    def n_lags(self) -> int:
        return 2 * self.max_lag + 1

    def from_phat(self, W: torch.Tensor) -> torch.Tensor:
        """Unmasked GCC from whitened spectra ``(batch, frames, n_mics, n_bins)``."""
        self.follow(W.device)
        return F.gcc_from_phat(W, self.pairs, self.max_lag, self.frame_spec.window, self.index)

    def forward(self, audio: torch.Tensor, vad: torch.Tensor | None = None) -> torch.Tensor:
        X = F.stft_frames(audio, self.frame_spec.window, self.frame_spec.hop)
        return F.zero_silent(self.from_phat(F.phat(X)), vad)


class SRPPHAT(_Transform):
    """SRP-PHAT maps on the equiangular grid of ``resolution = (n_theta, n_phi)``.

    ``mode="nearest"`` (the paper) rounds pair delays to whole samples and looks them up in the
    GCC; ``mode="exact"`` evaluates fractional delays exactly (PHAT beamformer). With
    ``normalize=True`` (default) maps have their mean removed and are divided by their maximum.

    ``forward(audio (batch, n_mics, samples), vad (batch, frames) | None)`` (call the module) ->
    ``(batch, frames, n_theta, n_phi)`` float32, silent frames zeroed.
    """

    tau: torch.Tensor  # buffers (register_buffer), declared for the type checker
    index: torch.Tensor | None
    steer: torch.Tensor | None

    def __init__(
        self,
        array: MicArray | str,
        resolution: str | Sequence[int] = DEFAULT_RESOLUTION,
        frame_spec: FrameSpec = FrameSpec(),
        mode: DelayMode = "nearest",
        normalize: bool = True,
        c: float = SPEED_OF_SOUND,
    ) -> None:
        if mode not in DELAY_MODES:
            raise ConfigError(f"unknown delay mode {mode!r}: use one of {', '.join(DELAY_MODES)}")
        super().__init__()
        self.array = get_array(array)
        self.resolution = as_resolution(resolution)
        self.frame_spec = frame_spec
        self.mode = mode
        self.normalize = normalize
        self.planar = bool(self.array.planar)
        self.gcc = GCCPHAT(self.array, frame_spec, c)
        n_theta, n_phi = self.resolution
        tau = F.grid_delays(self.array.positions, n_theta, n_phi, frame_spec.fs, self.planar, c)
        self.register_buffer("tau", torch.from_numpy(tau), persistent=False)  # (n_mics, n_grid) samples, float64
        index: torch.Tensor | None = None
        steer: torch.Tensor | None = None
        if mode == "nearest":
            index = torch.from_numpy(F.nearest_lag_index(tau, self.array.pairs, self.gcc.max_lag))
        else:
            nbytes = F.n_bins(frame_spec.window) * tau.size * 8
            if nbytes <= _STEER_CACHE_BYTES:
                steer = F.steering(self.tau, frame_spec.window)
        self.register_buffer("index", index, persistent=False)  # None in exact mode
        self.register_buffer("steer", steer, persistent=False)  # None unless cached

    @property
    def grid_directions(self) -> np.ndarray:
        """Unit vectors of the map cells, ``(n_theta, n_phi, 3)`` float64 (the maps' last two axes)."""
        return grid_unit_vectors(*self.resolution, planar=self.planar)

    def raw_from_phat(self, W: torch.Tensor, gcc: torch.Tensor | None = None) -> torch.Tensor:
        """Raw maps from whitened spectra; ``gcc`` (this array's full GCC) is reused if given."""
        n_theta, n_phi = self.resolution
        self.follow(W.device)
        if self.mode == "exact":
            return F.srp_exact_from_phat(W, self.tau, self.frame_spec.window, n_theta, n_phi, self.steer)
        if gcc is None:
            gcc = self.gcc.from_phat(W)
        assert self.index is not None  # built for the nearest mode
        return F.srp_from_gcc(gcc, self.index, n_theta, n_phi)

    def forward(self, audio: torch.Tensor, vad: torch.Tensor | None = None) -> torch.Tensor:
        X = F.stft_frames(audio, self.frame_spec.window, self.frame_spec.hop)
        maps = self.raw_from_phat(F.phat(X))
        if self.normalize:
            maps = F.normalize_maps(maps)
        return F.zero_silent(maps, vad)


class FeatureExtractor(_Transform):
    """Every feature a tracker may read, on one frame grid.

    ``forward(audio, sample_vad=None)`` (call the extractor): ``audio`` ``(batch, n_mics, samples)`` (or
    ``(n_mics, samples)``, then outputs have no batch axis), tensor or ndarray; ``sample_vad``
    ``(batch, samples)`` bool/0-1 or None (all active). Returns a dict with the requested
    ``kinds`` among

    * ``srp``: ``(B, T, n_theta, n_phi)`` normalised maps
    * ``srp_max``: ``(B, T, 2)`` normalised elevation/azimuth of each map's maximum
    * ``gcc``: ``(B, T, n_pairs, 2 * max_lag + 1)``
    * ``spectrogram``: ``(B, T_s, 2 * n_mics, K_s // 2)`` on ``spectrogram_frame_spec``'s grid
    * ``spectrogram_ipd``: the same, the phases relative to the first microphone's

    and any plug-in kind (:func:`~doabench.features.kinds.register_feature_kind`), each computed by
    its kind's ``compute`` from the pass's shared :class:`~doabench.features.context.STFTContext`
    (one STFT per frame grid), after the built-ins,

    plus ``vad`` ``(B, T)`` bool (frame active when > 2/3 of its samples are). Features of silent
    frames are zero. When kinds on their own frames (``own_frames``: the spectrogram) have a grid of
    their own, ``spectrogram_vad`` ``(B, T_s)`` is added for it. All features are float32.
    """

    def __init__(
        self,
        array: MicArray | str,
        kinds: Iterable[str] = EXTRACTOR_KINDS,
        resolution: str | Sequence[int] = DEFAULT_RESOLUTION,
        mode: DelayMode = "nearest",
        frame_spec: FrameSpec = FrameSpec(),
        spectrogram_frame_spec: FrameSpec | None = None,
        c: float = SPEED_OF_SOUND,
    ) -> None:
        super().__init__()
        kinds = (kinds,) if isinstance(kinds, str) else tuple(kinds)
        known = set(observation_kinds())
        computed = [k for k in kinds if k in known and feature_kind(k).compute is not None]
        unknown = [k for k in kinds if k not in computed]
        if unknown or not kinds:
            raise ConfigError(f"unknown feature kind(s) {unknown or kinds!r}: use some of "
                              f"{', '.join(EXTRACTOR_KINDS)} or a registered plug-in kind")
        builtin = tuple(k for k in EXTRACTOR_KINDS if k in computed)
        self.kinds = builtin + tuple(dict.fromkeys(k for k in computed if k not in EXTRACTOR_KINDS))
        self.array = get_array(array)
        self.frame_spec = frame_spec
        spec_fs = spectrogram_frame_spec or frame_spec
        if spec_fs.fs != frame_spec.fs:
            raise ConfigError(f"spectrogram sample rate {spec_fs.fs} differs from the features' {frame_spec.fs}")
        self.spectrogram_frame_spec = spec_fs
        self.mode = mode
        self.resolution = as_resolution(resolution)
        self.c = float(c)
        stages = {stage for k in self.kinds for stage in feature_kind(k).stages}
        self.srp = SRPPHAT(self.array, self.resolution, frame_spec, mode, True, c) if "srp" in stages else None
        self.gcc = self.srp.gcc if self.srp else GCCPHAT(self.array, frame_spec, c) if "gcc" in stages else None
        own = own_frame_kinds(self.kinds) if spec_fs != frame_spec else ()
        #: the kinds on the main frames, and those on their own (the second) frame grid
        self.main_kinds = tuple(k for k in self.kinds if k not in own)
        self.own_grid_kinds = own
        self._shapes: dict[str, tuple[int, ...]] | None = None
        self.feature_shapes()  # every kind's frame shape, checked before any audio is read

    # -- description ---------------------------------------------------------------------------
    @property
    def separate_spectrogram_grid(self) -> bool:
        """True when some kinds (the spectrogram) are framed differently from the other features."""
        return bool(self.own_grid_kinds)

    @property
    def min_samples(self) -> int:
        """Shortest recording that yields at least one frame of every requested kind."""
        windows = [self.frame_spec.window] if self.main_kinds else []
        if self.own_grid_kinds:
            windows.append(self.spectrogram_frame_spec.window)
        return max(windows)

    def frame_context(self) -> FrameContext:
        """What the per-frame shapes and axes of the kinds depend on."""
        return FrameContext(self.array, self.frame_spec, self.resolution, self.spectrogram_frame_spec)

    def feature_shapes(self) -> dict[str, tuple[int, ...]]:
        """Per-frame shape of each output key (without batch and frame axes), as each kind declares
        it (checked by :func:`~doabench.features.kinds.frame_shape_of`)."""
        if self._shapes is None:
            context = self.frame_context()
            shapes = {k: frame_shape_of(feature_kind(k), context) for k in self.kinds}
            shapes["vad"] = ()
            if self.separate_spectrogram_grid:
                shapes["spectrogram_vad"] = ()
            self._shapes = shapes
        return dict(self._shapes)

    # -- computation ---------------------------------------------------------------------------
    def _frame_vad(
        self, vad: torch.Tensor | None, spec: FrameSpec, batch: int, samples: int, device: torch.device
    ) -> torch.Tensor:
        if vad is None:
            return torch.ones((batch, spec.n_frames(samples)), dtype=torch.bool, device=device)
        return frame_vad(vad, spec.window, spec.hop)

    def _compute_kinds(self, kinds: tuple[str, ...], x: torch.Tensor, vad: torch.Tensor,
                       spec: FrameSpec) -> dict[str, torch.Tensor]:
        """``kinds`` from one shared STFT context of ``x`` on ``spec``, silent frames zeroed. A
        plug-in kind's output is checked against its declaration (:func:`checked_output`)."""
        stft = STFTContext(x, vad, spec, self.array, self.gcc, self.srp)
        out: dict[str, torch.Tensor] = {}
        for k in kinds:
            kind = feature_kind(k)
            assert kind.compute is not None  # the constructor keeps computed kinds only
            if k in EXTRACTOR_KINDS:
                out[k] = F.zero_silent(kind.compute(stft), vad)
            else:
                shape = tuple(vad.shape) + self.feature_shapes()[k]
                out[k] = F.zero_silent(checked_output(kind, call_kind(kind, "compute()", kind.compute, stft), shape), vad)
        return out

    def compute(
        self, x: torch.Tensor, sample_vad: torch.Tensor | None, main: bool = True, separate: bool = True
    ) -> dict[str, torch.Tensor]:
        """Features of validated audio ``(batch, n_mics, samples)`` float32 and VAD
        ``(batch, samples)`` bool or None (no checks; see :meth:`forward`).

        ``main=False`` skips everything on ``frame_spec``'s grid (``vad`` included) and
        ``separate=False`` skips the kinds on their own grid (used by the streaming extractor).
        """
        B, _, S = x.shape
        out: dict[str, torch.Tensor] = {}
        if main:
            vad = self._frame_vad(sample_vad, self.frame_spec, B, S, x.device)
            if self.main_kinds:
                out.update(self._compute_kinds(self.main_kinds, x, vad, self.frame_spec))
            out["vad"] = vad
        if separate and self.own_grid_kinds:
            spec = self.spectrogram_frame_spec
            vad_s = self._frame_vad(sample_vad, spec, B, S, x.device)
            out.update(self._compute_kinds(self.own_grid_kinds, x, vad_s, spec))
            out["spectrogram_vad"] = vad_s
        return {k: out[k] for k in self.feature_shapes() if k in out}

    def forward(
        self, audio: np.ndarray | torch.Tensor, sample_vad: ArrayLike | torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        x, batched = prepare_audio(audio, self.array.n_mics, self.min_samples)
        vad = prepare_vad(sample_vad, x.shape[0], x.shape[-1], batched, x.device)
        out = self.compute(x, vad)
        return out if batched else {k: v[0] for k, v in out.items()}

    def empty(self, batch: int, device: torch.device | str | None = None) -> dict[str, torch.Tensor]:
        """Zero-frame outputs ``(batch, 0, ...)`` with the right trailing shapes and dtypes."""
        return {
            k: torch.zeros((batch, 0) + s, dtype=torch.bool if k.endswith("vad") else torch.float32, device=device)
            for k, s in self.feature_shapes().items()
        }

    def describe(self) -> Mapping[str, object]:
        """Settings as JSON-serialisable data."""
        d: dict[str, object] = {
            "kinds": list(self.kinds),
            "frame": self.frame_spec.to_dict(),
            "array": self.array.to_dict(),
            "c": self.c,
        }
        if self.srp is not None:
            d.update(resolution=resolution_text(self.resolution), delays=self.mode)
        if self.gcc is not None:
            d["max_lag"] = self.gcc.max_lag
        if own_frame_kinds(self.kinds):  # the frames they would take, even when they are the main ones
            d["spectrogram_frame"] = self.spectrogram_frame_spec.to_dict()
        return d
