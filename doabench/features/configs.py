"""The settings of one observation kind, as small frozen values that round-trip.

Each :class:`~doabench.features.kinds.FeatureKind` declares its config class (``config``), as
lhotse's feature extractors declare theirs: a map kind on the SRP grid takes :class:`MapConfig`
(grid and delay mode), the spectrogram :class:`FramesConfig` (its own frames, or the main ones),
gcc and audio :class:`NoConfig`. A plug-in kind brings any of these or a subclass of
:class:`KindConfig` of its own.

Every config has three forms that read each other back: the value, its stored form
(:meth:`KindConfig.to_dict`, written into results, weights and ONNX files inside
:meth:`ObservationSpec.to_dict <doabench.features.spec.ObservationSpec.to_dict>`) and its text
form (``grid=16x32, delays=nearest``; :meth:`KindConfig.text`, :meth:`KindConfig.parse`).
:meth:`KindConfig.of_flat` builds one from the flat description older files and keyword
arguments give (a resolution, a delay mode, the spectrogram's frames).

Needs neither torch nor the registry, so :mod:`doabench.features.kinds` imports it.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any, Mapping, NamedTuple, Sequence, TypeVar

from doabench.errors import ConfigError
from doabench.framing import FrameSpec
from doabench.geometry import as_grid, resolution_text

#: The SRP grid when nothing asks for another one.
DEFAULT_RESOLUTION = (16, 32)
#: The SRP delay modes: pair delays rounded to whole samples (the paper's) or exact fractional ones.
DELAY_MODES = ("nearest", "exact")

C = TypeVar("C", bound="KindConfig")


class FlatDescription(NamedTuple):
    """The flat description of observations (``DoaEnv``'s keywords, older stored forms): what
    :meth:`KindConfig.of_flat` builds each kind's config from. None: the default."""

    resolution: Sequence[int] | str | None = None
    delays: str | None = None
    spectrogram_frame_spec: FrameSpec | None = None


@dataclass(frozen=True)
class KindConfig:
    """The settings of a kind; this base class holds none (it is the config of gcc and audio).

    A subclass is a frozen dataclass whose fields are strings, whole numbers, grids or
    :class:`~doabench.FrameSpec` values; it overrides :meth:`field_to_stored` /
    :meth:`field_from_stored` (and the text pair) for a field of another type.
    """

    # -- the stored form -------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The stored form: ``{field: JSON value}``; :meth:`from_dict` reads it back."""
        return {f.name: self.field_to_stored(f.name, getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_dict(cls: type[C], d: Mapping[str, Any]) -> C:
        """The config :meth:`to_dict` wrote, every field of it; a one-line ConfigError otherwise."""
        return cls._build(d, partial=False)

    @classmethod
    def _build(cls: type[C], d: Mapping[str, Any], partial: bool) -> C:
        names = [f.name for f in fields(cls)]
        if not isinstance(d, Mapping):
            raise ConfigError(f"{cls.__name__}: expected {{{', '.join(names)}}}, got {d!r}")
        unknown, missing = sorted(set(d) - set(names)), [] if partial else [n for n in names if n not in d]
        if unknown or missing:
            raise ConfigError(f"{cls.__name__} takes {', '.join(names) or 'no settings'}; "
                              f"{'unknown: ' + ', '.join(unknown) if unknown else 'missing: ' + ', '.join(missing)}")
        return cls(**{k: cls.field_from_stored(k, v) for k, v in d.items()})

    @classmethod
    def field_to_stored(cls, name: str, value: Any) -> Any:
        return value

    @classmethod
    def field_from_stored(cls, name: str, value: Any) -> Any:
        return value

    # -- the text form ---------------------------------------------------------------------------
    def text(self) -> str:
        """``grid=16x32, delays=nearest`` (empty for no settings); :meth:`parse` reads it back."""
        return ", ".join(f"{f.name}={self.field_to_text(f.name, getattr(self, f.name))}" for f in fields(self))

    @classmethod
    def parse(cls: type[C], text: str) -> C:
        """The config :meth:`text` wrote (a field left out takes its default); a one-line
        ConfigError otherwise."""
        values: dict[str, str] = {}
        for part in (p.strip() for p in text.split(",")):
            if not part:
                continue
            key, sep, value = part.partition("=")
            if not sep:
                raise ConfigError(f"{cls.__name__}: {part!r} is not KEY=VALUE")
            values[key.strip()] = value.strip()
        return cls._build({k: cls.field_from_text(k, v) for k, v in values.items()}, partial=True)

    @classmethod
    def field_to_text(cls, name: str, value: Any) -> str:
        return str(cls.field_to_stored(name, value))

    @classmethod
    def field_from_text(cls, name: str, text: str) -> Any:
        return text

    # -- the flat description --------------------------------------------------------------------
    @classmethod
    def of_flat(cls: type[C], flat: FlatDescription) -> C:
        """This kind's config from the flat description (the base class: no settings)."""
        return cls()

    def with_delays(self: C, delays: str) -> C:
        """The same settings on another SRP delay mode (unchanged where the kind has none)."""
        return self


#: The config of a kind with no settings (gcc, audio).
NoConfig = KindConfig


@dataclass(frozen=True)
class MapConfig(KindConfig):
    """A kind on the SRP grid (srp, srp_max, a plug-in map): ``grid`` ``(n_theta, n_phi)`` (given
    as ``16x32`` or two sizes) and the pair ``delays`` (``nearest``, the paper's, or ``exact``)."""

    grid: tuple[int, int] = DEFAULT_RESOLUTION
    delays: str = "nearest"

    def __post_init__(self) -> None:
        object.__setattr__(self, "grid", as_grid(self.grid))
        if self.delays not in DELAY_MODES:
            raise ConfigError(f"unknown delay mode {self.delays!r}: use one of {', '.join(DELAY_MODES)}")

    @classmethod
    def field_to_stored(cls, name: str, value: Any) -> Any:
        return resolution_text(value) if name == "grid" else value

    @classmethod
    def of_flat(cls, flat: FlatDescription) -> "MapConfig":
        return cls(as_grid(flat.resolution or DEFAULT_RESOLUTION), flat.delays or "nearest")

    def with_delays(self, delays: str) -> "MapConfig":
        return replace(self, delays=delays)


@dataclass(frozen=True)
class FramesConfig(KindConfig):
    """A kind that may be framed on its own grid (the spectrogram, as the paper's spectrogram
    models read it): ``frames``, or None for the observations' main frames. Text form:
    ``frames=512/384@16000`` (window/hop@fs)."""

    frames: FrameSpec | None = None

    def __post_init__(self) -> None:
        if self.frames is not None and not isinstance(self.frames, FrameSpec):
            raise ConfigError(f"frames must be a doabench.FrameSpec or None, got {self.frames!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"frames": None if self.frames is None else self.frames.to_dict()}

    @classmethod
    def field_from_stored(cls, name: str, value: Any) -> Any:
        return None if value is None else frame_spec_from_dict(value)

    def text(self) -> str:
        return "" if self.frames is None else f"frames={frames_text(self.frames)}"

    @classmethod
    def field_from_text(cls, name: str, text: str) -> Any:
        return parse_frames_text(text).to_dict()

    @classmethod
    def of_flat(cls, flat: FlatDescription) -> "FramesConfig":
        return cls(flat.spectrogram_frame_spec)


def frame_spec_from_dict(d: Any) -> FrameSpec:
    """The :class:`~doabench.FrameSpec` of ``{"window", "hop", "fs"}``; a one-line ConfigError otherwise."""
    try:
        if set(d) != {"window", "hop", "fs"}:
            raise KeyError(sorted(d))
        return FrameSpec(int(d["window"]), int(d["hop"]), int(d["fs"]))
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f"frames must be {{window, hop, fs}} in whole samples and Hz, got {d!r}") from None


def frames_text(frames: FrameSpec) -> str:
    """``4096/3072@16000``: window/hop@fs."""
    return f"{frames.window}/{frames.hop}@{frames.fs}"


def parse_frames_text(text: str) -> FrameSpec:
    """The frames :func:`frames_text` wrote; a one-line ConfigError otherwise."""
    sizes, _, fs = text.strip().partition("@")
    window, _, hop = sizes.partition("/")
    try:
        return FrameSpec(int(window), int(hop), int(fs))
    except ValueError:
        raise ConfigError(f"frames {text!r} are not WINDOW/HOP@FS, e.g. 4096/3072@16000") from None
