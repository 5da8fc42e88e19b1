"""The observation kinds: registered objects, and the names every layer derives from them.

Each kind is a :class:`FeatureKind` (lhotse's feature extractors and torchaudio's transforms are
the models): its name, the shape and Gymnasium bounds of one frame, where a dataset file keeps it
and in what precision, what its axes hold, which frames it is computed on, and how it computes
itself from the shared STFT context of one extractor pass
(:class:`~doabench.features.context.STFTContext`: the spectra, their PHAT whitening, the GCC and
the SRP maps, each computed once for every kind that reads it). The built-in kinds (srp, srp_max,
gcc, spectrogram, spectrogram_ipd, audio) are declared here like a plug-in's, which is registered with
:func:`register_feature_kind` or declared in the ``doabench.feature_kinds`` entry-point group
(docs/extending.md). The environment, make-dataset, ``track``, ``features``, the trainer and the
plots all read kinds through :class:`~doabench.features.plan.ObservationPlan` and
:class:`~doabench.features.FeatureExtractor`, which ask this registry.

Kept apart from :mod:`doabench.features.plan` (which computes them) so that the transforms, the
dataset schema and the environment can read the kinds without importing torch or the plan, and
without an import cycle (the plan imports the transforms, the transforms import this module). The
built-in kinds' ``compute`` only read the context's stages, so this module needs no torch.

Each kind declares its config class (``config``, :mod:`doabench.features.configs`): the settings
an observation of it carries (a map kind's grid and delays, the spectrogram's own frames).

Names: an item of a kind on the SRP grid (``on_grid``: srp, srp_max, a plug-in map) carries its
grid, ``srp:16x32`` / ``srp_max:16x32``; the other kinds are named by the kind alone (``gcc``,
``spectrogram``, ``audio``). In a dataset file an item ``srp:16x32`` lies at ``features/srp_16x32``,
``gcc`` at ``features/gcc`` and ``audio`` (the raw recording) at ``audio`` (docs/hdf5-schema.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Literal, NamedTuple, Sequence

import numpy as np

from doabench.errors import ConfigError, DoabenchError, FeatureKindError, one_line
from doabench.features.configs import FramesConfig, KindConfig, MapConfig
from doabench.framing import FrameSpec
from doabench.geometry import grid_angles, parse_resolution, resolution_text
from doabench.plugins import Registry

#: Where the dataset file keeps computed features (the raw ``audio`` lies beside them).
FEATURES_GROUP = "features"
DelayMode = Literal["nearest", "exact"]
#: Entry-point group of feature kinds added by other packages (``name = "package.module:KIND"``).
ENTRY_POINT_GROUP = "doabench.feature_kinds"
#: The most values one frame of a kind may hold (2**26: 256 MiB as float32, a 1024-microphone GCC
#: at 16 kHz holds 50 million): a kind declaring more is refused before anything of that size is
#: allocated (an observation space holds two arrays of one frame's size).
MAX_FRAME_VALUES = 1 << 26
#: The shared stages that need tables built once per extractor (pair lags, grid delays): a kind
#: whose ``compute`` reads ``context.gcc`` declares ``"gcc"``, one reading ``context.maps`` ``"srp"``.
STAGES = ("gcc", "srp")


class FrameContext(NamedTuple):
    """What the shape of one frame of a kind may depend on."""

    array: Any                   # the MicArray
    frame_spec: FrameSpec        # the observations' frames
    resolution: tuple[int, int]  # the SRP grid (n_theta, n_phi)
    spectrogram_frame_spec: FrameSpec | None = None  # the spectrogram's own frames, when it has them


@dataclass(frozen=True)
class FeatureKind:
    """One observation kind.

    ``frame_shape(context)``: the shape of one frame (no batch or frame axis). ``low``/``high``:
    the bounds of its Gymnasium box (float32). ``compute(stft)``: the kind from the shared
    :class:`~doabench.features.context.STFTContext` of one extractor pass, ``(batch, frames,
    *frame_shape)`` float32 on the context's frames; the features of silent frames are zeroed after
    it. ``stages``: the shared stages among :data:`STAGES` that ``compute`` reads (their tables are
    built once per extractor). ``own_frames``: computed on the observations' second frame grid
    (``ObservationSpec.spectrogram_frame_spec``) when one is given, as the paper's spectrogram models
    are; otherwise on the main frames. ``on_grid``: computed on an SRP grid, so its name carries the
    grid (``srp:16x32``). ``framed``: the recording's own samples, framed, not computed (no
    ``compute``). ``half``: make-dataset's ``--float16`` stores it in half precision.
    ``requestable``: make-dataset ``--features`` may ask for it. ``comes_with``: the kinds a dataset
    stores beside it on the same grid (srp_max with every srp map). ``config``: its config class
    (:mod:`doabench.features.configs`): :class:`MapConfig` for a kind on the grid,
    :class:`FramesConfig` for one with ``own_frames``, :class:`KindConfig` (no settings) otherwise.
    ``axes(context)``: what the axes of one frame hold, for the sidecar of ``doabench features``
    (``{"axes": [...], ...}``; None: ``description`` alone says it).
    """

    name: str
    frame_shape: Callable[[FrameContext], tuple[int, ...]]
    low: float = float("-inf")
    high: float = float("inf")
    compute: Callable[[Any], Any] | None = None
    stages: tuple[str, ...] = ()
    own_frames: bool = False
    on_grid: bool = False
    framed: bool = False
    half: bool = False
    requestable: bool = True
    comes_with: tuple[str, ...] = ()
    config: type[KindConfig] = KindConfig
    axes: Callable[[FrameContext], dict[str, Any]] | None = None
    description: str = ""

    def storage_path(self, resolution: str | None = None) -> str:
        """Where an item of this kind lies in a dataset episode group (``resolution`` as ``16x32``)."""
        if self.on_grid:
            return f"{FEATURES_GROUP}/{self.name}_{resolution}"
        return self.name if self.framed else f"{FEATURES_GROUP}/{self.name}"

    def frames(self, context: FrameContext) -> FrameSpec:
        """The frames this kind is computed on in ``context``."""
        return (context.spectrogram_frame_spec or context.frame_spec) if self.own_frames else context.frame_spec


def call_kind(kind: FeatureKind, what: str, fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)``, one of ``kind``'s own functions (``compute``, ``frame_shape``, ``axes``); an
    exception it raises becomes a one-line :class:`FeatureKindError` naming the kind, as a
    tracker's does (doabench's own errors pass through)."""
    try:
        return fn(*args)
    except DoabenchError:
        raise
    except Exception as exc:
        raise FeatureKindError(f"feature kind {kind.name!r} raised in {what}: {one_line(exc)}") from None


def frame_shape_of(kind: FeatureKind, context: FrameContext) -> tuple[int, ...]:
    """The shape of one frame of ``kind`` in ``context``, checked: whole sizes of at least 1, at
    most :data:`MAX_FRAME_VALUES` values in all; else a one-line error naming the kind."""
    declared = call_kind(kind, "frame_shape()", kind.frame_shape, context)
    try:
        dims = tuple(declared)
        ok = all(isinstance(d, (int, np.integer)) and not isinstance(d, bool) and d >= 1 for d in dims)
    except TypeError:
        ok = False
    if not ok:
        raise FeatureKindError(f"feature kind {kind.name!r} declares the frame shape {declared!r}; expected a "
                               "tuple of whole sizes of at least 1")
    shape = tuple(int(d) for d in dims)
    values = math.prod(shape)
    if values > MAX_FRAME_VALUES:
        raise ConfigError(f"feature kind {kind.name!r}: one frame of shape {shape} holds {values} values, more "
                          f"than the limit of {MAX_FRAME_VALUES}")
    return shape


def _gcc_shape(c: FrameContext) -> tuple[int, ...]:
    return (len(c.array.pairs), 2 * c.array.max_lag(c.frame_spec.fs) + 1)


def _spectrogram_shape(c: FrameContext) -> tuple[int, ...]:
    return (2 * c.array.n_mics, (c.spectrogram_frame_spec or c.frame_spec).window // 2)


def _map_axes(c: FrameContext) -> dict[str, Any]:
    elevation, azimuth = grid_angles(*c.resolution, planar=bool(c.array.planar))
    return {"elevations_deg": np.degrees(elevation).round(6).tolist(),
            "azimuths_deg": np.degrees(azimuth).round(6).tolist()}


def _srp_axes(c: FrameContext) -> dict[str, Any]:
    return {"axes": ["frame", "elevation", "azimuth"], **_map_axes(c),
            "normalization": "each map minus its mean, divided by its maximum"}


def _srp_max_axes(c: FrameContext) -> dict[str, Any]:
    return {"axes": ["frame", "channel"], **_map_axes(c),
            "channels": ["elevation / elevation span", "(azimuth + 180) / 360"]}


def _gcc_axes(c: FrameContext) -> dict[str, Any]:
    max_lag = c.array.max_lag(c.frame_spec.fs)
    return {"axes": ["frame", "pair", "lag"], "pairs": c.array.pairs.tolist(),
            "lags": list(range(-max_lag, max_lag + 1))}


def _spectrogram_axes(c: FrameContext, phases: str = "phase/pi of mics 1..M") -> dict[str, Any]:
    spec = c.spectrogram_frame_spec or c.frame_spec
    return {"axes": ["frame", "channel", "frequency"],
            "channels": f"magnitude of mics 1..M (each divided by its maximum), then {phases}",
            "frequencies_hz": (np.arange(1, spec.window // 2 + 1) * spec.fs / spec.window).tolist()}


def _spectrogram_ipd_axes(c: FrameContext) -> dict[str, Any]:
    return _spectrogram_axes(c, "(phase of mic m - phase of mic 1)/pi for m = 1..M, wrapped to (-1, 1]")


BUILTIN_KINDS: tuple[FeatureKind, ...] = (
    # mean removed and divided by the maximum: the maximum is 1, the minimum has no bound
    FeatureKind("srp", lambda c: tuple(c.resolution), high=1.0, compute=lambda stft: stft.maps, stages=("srp",),
                on_grid=True, half=True, comes_with=("srp_max",), config=MapConfig, axes=_srp_axes, description="SRP-PHAT map on the equiangular grid"),
    FeatureKind("srp_max", lambda c: (2,), low=0.0, high=1.0, compute=lambda stft: stft.map_maxima,
                stages=("srp",), on_grid=True, requestable=False, config=MapConfig, axes=_srp_max_axes,
                description="normalised elevation and azimuth of the map's maximum"),
    # PHAT-weighted: a mean of unit phasors, so |R| <= 1
    FeatureKind("gcc", _gcc_shape, low=-1.0, high=1.0, compute=lambda stft: stft.gcc, stages=("gcc",), half=True,
                axes=_gcc_axes, description="GCC-PHAT of every mic pair"),
    FeatureKind("spectrogram", _spectrogram_shape, low=-1.0, high=1.0, compute=lambda stft: stft.spectrogram,
                own_frames=True, half=True, config=FramesConfig, axes=_spectrogram_axes, description="magnitude and phase spectrogram"),
    # the phases relative to the first microphone's: a plane wave's are -2 pi f tau, whatever the source
    FeatureKind("spectrogram_ipd", _spectrogram_shape, low=-1.0, high=1.0, compute=lambda stft: stft.spectrogram_ipd,
                own_frames=True, half=True, config=FramesConfig, axes=_spectrogram_ipd_axes,
                description="magnitude spectrogram and phase differences to the first microphone"),
    FeatureKind("audio", lambda c: (c.array.n_mics, c.frame_spec.window), framed=True,
                description="the recording's samples, framed"),
)

#: The built-in kinds an environment observation may hold, in the order error messages list them
#: (:func:`observation_kinds` adds the plug-ins').
OBSERVATION_KINDS = tuple(k.name for k in BUILTIN_KINDS)
#: The built-in kinds :class:`~doabench.features.FeatureExtractor` computes together, in its output order.
EXTRACTOR_KINDS = tuple(k.name for k in BUILTIN_KINDS if not k.framed)
#: The built-in kinds that are the recording's own samples, framed, not computed by the extractor
#: (whether any kind is: ``feature_kind(name).framed``).
FRAMED_KINDS = tuple(k.name for k in BUILTIN_KINDS if k.framed)
#: What ``make-dataset --features`` requests, in the files' canonical order; an ``srp`` request
#: stores its ``srp_max`` too, so srp_max is not requested on its own.
DATASET_KINDS = tuple(k.name for k in BUILTIN_KINDS if k.requestable)


def _check_plugin_kind(name: str, kind: Any) -> FeatureKind:
    if not isinstance(kind, FeatureKind):
        raise ConfigError(f"a feature kind must be a doabench FeatureKind, got {type(kind).__name__}")
    if name != kind.name:
        raise ConfigError(f"feature kind {kind.name!r} cannot be registered as {name!r}")
    if kind.name in OBSERVATION_KINDS or ":" in kind.name or not kind.name.isidentifier():
        raise ConfigError(f"feature kind name {kind.name!r} is taken or not a plain identifier")
    if kind.compute is None or kind.framed:
        raise ConfigError(f"feature kind {kind.name!r}: a plug-in kind brings compute() and is not framed")
    check_config_class(kind)
    unknown = sorted(set(kind.stages) - set(STAGES))
    if unknown:
        raise ConfigError(f"feature kind {kind.name!r} reads unknown stage(s) {unknown}; the shared stages with "
                          f"tables are {', '.join(STAGES)}")
    return kind


def check_config_class(kind: FeatureKind) -> None:
    """A one-line ConfigError unless ``kind.config`` fits the kind: a :class:`MapConfig` (its grid and
    delays) for a kind on the grid, a :class:`FramesConfig` for one with ``own_frames``."""
    config = kind.config
    if not (isinstance(config, type) and issubclass(config, KindConfig)):
        raise ConfigError(f"feature kind {kind.name!r}: config must be a KindConfig class, got {config!r}")
    if kind.on_grid != issubclass(config, MapConfig) or kind.own_frames != issubclass(config, FramesConfig):
        raise ConfigError(f"feature kind {kind.name!r}: a kind on the SRP grid (on_grid) takes MapConfig, one on "
                          f"its own frames (own_frames) FramesConfig, and no other kind either; got {config.__name__}")


#: Every feature kind: the built-ins (computed by doabench), then plug-ins from the
#: ``doabench.feature_kinds`` group or :func:`register_feature_kind` (:mod:`doabench.plugins`).
FEATURE_KINDS: Registry[FeatureKind] = Registry("feature kind", ENTRY_POINT_GROUP, _check_plugin_kind,
                                                builtins={k.name: k for k in BUILTIN_KINDS})


def register_feature_kind(kind: FeatureKind) -> FeatureKind:
    """Add a plug-in kind (it must bring ``compute``); returns it. A built-in name cannot be taken."""
    if not isinstance(kind, FeatureKind):
        raise ConfigError(f"a feature kind must be a doabench FeatureKind, got {type(kind).__name__}")
    return FEATURE_KINDS.register(kind.name, kind)


def feature_kind(name: str) -> FeatureKind:
    """The registered kind ``name`` (a declared plug-in is loaded on first use), else a ConfigError
    naming the nearest kind."""
    return FEATURE_KINDS.get(name)


def observation_kinds() -> tuple[str, ...]:
    """Every kind an observation may hold: the built-ins, then the registered and declared plug-ins."""
    return OBSERVATION_KINDS + tuple(sorted(set(FEATURE_KINDS.names()) - set(OBSERVATION_KINDS)))


def map_kinds(kinds: Iterable[str]) -> tuple[str, ...]:
    """The kinds among ``kinds`` computed on the SRP grid (built-in or plug-in)."""
    return tuple(k for k in kinds if feature_kind(k).on_grid)


def own_frame_kinds(kinds: Iterable[str]) -> tuple[str, ...]:
    """The kinds among ``kinds`` computed on the observations' second frame grid when one is given."""
    return tuple(k for k in kinds if feature_kind(k).own_frames)


def check_kinds(kinds: Iterable[str]) -> tuple[str, ...]:
    """``kinds`` as a tuple, or the environment's ConfigError naming the unknown ones (plug-in kinds
    registered or declared count as known)."""
    kinds = tuple(kinds)
    unknown = sorted(set(kinds) - set(observation_kinds()))
    if unknown:
        raise ConfigError(f"unknown feature kind(s) {unknown}; choose from {', '.join(observation_kinds())}")
    return kinds


def item_name(kind: str, resolution: Sequence[int] | str | None = None) -> str:
    """Canonical name of ``kind`` on the grid ``resolution``: ``srp:16x32``, ``gcc``, ...

    ``resolution`` None leaves a map kind's name bare (``srp``: a reader resolves it to the only
    stored grid); kinds off the grid ignore it.
    """
    found = FEATURE_KINDS.find(kind) if resolution else None  # other keys (vad) pass as they are
    if found is not None and found[1].on_grid:
        return f"{kind}:{resolution if isinstance(resolution, str) else resolution_text(resolution)}"
    return kind


def item_names(kinds: Iterable[str], resolution: Sequence[int] | str | None = None) -> list[str]:
    """:func:`item_name` of each kind, in order."""
    return [item_name(k, resolution) for k in kinds]


def parse_item_name(name: str) -> tuple[str, tuple[int, int] | None]:
    """``"srp:16x32"`` -> ``("srp", (16, 32))``, ``"gcc"`` -> ``("gcc", None)``, ``"srp"`` -> ``("srp", None)``.

    The resolution is parsed by :func:`doabench.geometry.parse_resolution` (its errors); an unknown
    kind, or a resolution on a kind without a grid, is a ConfigError.
    """
    kind, sep, res = str(name).partition(":")
    check_kinds([kind])
    if not sep:
        return kind, None
    if not feature_kind(kind).on_grid:
        raise ConfigError(f"feature {kind!r} takes no resolution, got {name!r}")
    return kind, parse_resolution(res)


def storage_path(name: str) -> str:
    """Path of item ``name`` inside a dataset episode group: ``srp:16x32`` -> ``features/srp_16x32``,
    ``gcc`` -> ``features/gcc``, ``audio`` -> ``audio``."""
    kind, _, res = str(name).partition(":")
    return feature_kind(kind).storage_path(res)
