"""What a tracker reads, as one value: :class:`ObservationSpec`, the frames plus a tuple of
configured kinds (:class:`ConfiguredKind`: a kind's name and its config, e.g.
``srp(grid=16x32, delays=nearest)``; :mod:`doabench.features.configs`).

A tracker declares it (:attr:`doabench.Tracker.observation_spec`); a learned tracker's named
weights carry it. The environment (:class:`~doabench.envs.DoaEnv`'s ``observations``), the
observation plan, make-dataset, the trainer, ``doabench track``, results files, weights files and
the ONNX export take and store that value whole (:meth:`ObservationSpec.to_dict`), so a tracker is
evaluated on the observations it was trained on. A run that asks for other delays on purpose says
so in its results (``features.trained_delays``).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Mapping, Sequence

from doabench.errors import ConfigError
from doabench.features.configs import (
    FlatDescription,
    FramesConfig,
    KindConfig,
    MapConfig,
    frame_spec_from_dict,
    frames_text,
    parse_frames_text,
)
from doabench.features.kinds import check_kinds, feature_kind
from doabench.framing import FrameSpec
from doabench.geometry import as_grid

if TYPE_CHECKING:  # the plan imports torch lazily, but the spec needs none of it
    from doabench.arrays import MicArray
    from doabench.features.plan import ObservationPlan


@dataclass(frozen=True)
class ConfiguredKind:
    """One observation kind with its settings: ``kind`` (a registered kind's name) and ``config``
    (an instance of the kind's declared config class). Text form ``srp(grid=16x32, delays=nearest)``,
    stored form ``{"kind": "srp", "grid": "16x32", "delays": "nearest"}``."""

    kind: str
    config: KindConfig = KindConfig()

    def __post_init__(self) -> None:
        check_kinds([self.kind])
        declared = feature_kind(self.kind).config
        if type(self.config) is not declared:
            raise ConfigError(f"feature kind {self.kind!r} takes a {declared.__name__}, "
                              f"got {type(self.config).__name__}")

    @classmethod
    def of(cls, kind: str, flat: FlatDescription = FlatDescription()) -> "ConfiguredKind":
        """``kind`` with its config built from the flat description (defaults where None)."""
        check_kinds([kind])
        return cls(kind, feature_kind(kind).config.of_flat(flat))

    def __str__(self) -> str:
        text = self.config.text()
        return f"{self.kind}({text})" if text else self.kind

    @classmethod
    def parse(cls, text: str) -> "ConfiguredKind":
        """The kind :meth:`__str__` wrote (``srp(grid=16x32)``; ``gcc`` or ``gcc()``: no settings)."""
        m = re.fullmatch(r"\s*([^\s()]+)\s*(?:\((.*)\))?\s*", text)
        if m is None:
            raise ConfigError(f"{text!r} is not KIND or KIND(KEY=VALUE, ...)")
        check_kinds([m.group(1)])
        return cls(m.group(1), feature_kind(m.group(1)).config.parse(m.group(2) or ""))

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **self.config.to_dict()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ConfiguredKind":
        if not isinstance(d, Mapping) or not isinstance(d.get("kind"), str):
            raise ConfigError(f"a stored kind is {{\"kind\": NAME, ...its settings}}, got {d!r}")
        check_kinds([d["kind"]])
        return cls(d["kind"], feature_kind(d["kind"]).config.from_dict({k: v for k, v in d.items() if k != "kind"}))


@dataclass(frozen=True)
class ObservationSpec:
    """The observations a tracker reads: ``frames`` (window, hop and sample rate) and ``kinds``,
    each a :class:`ConfiguredKind` (``srp``, ``srp_max``, ``gcc``, ``spectrogram``, ``audio`` or a
    plug-in's, with its settings).

    The kinds on the SRP grid share one grid and one delay mode (the plan computes them in one
    pass). Text form: ``srp(grid=16x32, delays=nearest)+srp_max(grid=16x32, delays=nearest) @
    4096/3072@16000`` (:meth:`parse` reads it back); stored form: :meth:`to_dict`. Build one from
    the flat description (kinds, resolution, frames, delays) with :meth:`of`.
    """

    frames: FrameSpec
    kinds: tuple[ConfiguredKind, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.frames, FrameSpec):
            raise ConfigError(f"frames must be a doabench.FrameSpec, got {self.frames!r}")
        kinds = tuple(self.kinds)
        if not all(isinstance(k, ConfiguredKind) for k in kinds):
            raise ConfigError("kinds must be ConfiguredKind values (ObservationSpec.of builds them from names)")
        names = [k.kind for k in kinds]
        if len(set(names)) != len(names):
            raise ConfigError(f"a kind appears twice in the observations: {', '.join(names)}")
        maps = {(k.config.grid, k.config.delays) for k in kinds if isinstance(k.config, MapConfig)}
        if len(maps) > 1:
            raise ConfigError(f"the kinds on the SRP grid must share one grid and delay mode, got "
                              f"{' and '.join(str(k) for k in kinds if isinstance(k.config, MapConfig))}")
        # one grid is said one way: frames equal to the main ones are the main ones (None)
        kinds = tuple(ConfiguredKind(k.kind, FramesConfig(None))
                      if isinstance(k.config, FramesConfig) and k.config.frames == self.frames else k for k in kinds)
        object.__setattr__(self, "kinds", kinds)

    @classmethod
    def of(cls, kinds: Sequence[str], resolution: Sequence[int] | str | None = None,
           frame_spec: FrameSpec | None = None, delays: str | None = None,
           spectrogram_frame_spec: FrameSpec | None = None) -> "ObservationSpec":
        """The spec of the flat description: each of ``kinds`` configured from ``resolution``,
        ``delays`` and ``spectrogram_frame_spec`` as its config class reads them (defaults where
        None: the 16x32 grid, nearest delays, the main frames), on ``frame_spec`` (the paper's when None)."""
        names = (kinds,) if isinstance(kinds, str) else tuple(kinds)
        check_kinds(names)
        flat = FlatDescription(resolution, delays, spectrogram_frame_spec)
        return cls(frame_spec or FrameSpec(), tuple(ConfiguredKind.of(k, flat) for k in names))

    # -- derived views ----------------------------------------------------------------------------
    @property
    def kind_names(self) -> tuple[str, ...]:
        """The kinds' names, in order (the observation keys)."""
        return tuple(k.kind for k in self.kinds)

    @property
    def frame_spec(self) -> FrameSpec:
        """The main frames (``frames``)."""
        return self.frames

    def _map(self) -> MapConfig | None:
        return next((k.config for k in self.kinds if isinstance(k.config, MapConfig)), None)

    @property
    def resolution(self) -> tuple[int, int] | None:
        """The grid of the kinds on the SRP grid, or None when none is."""
        config = self._map()
        return None if config is None else config.grid

    @property
    def delays(self) -> str | None:
        """The delay mode of the kinds on the SRP grid, or None when none is."""
        config = self._map()
        return None if config is None else config.delays

    @property
    def spectrogram_frame_spec(self) -> FrameSpec | None:
        """The frames of the kinds framed on a grid of their own (``own_frames``: the
        spectrogram), when they are not the main ones; else None."""
        return next((k.config.frames for k in self.kinds if isinstance(k.config, FramesConfig)
                     and k.config.frames is not None), None)

    @property
    def separate_spectrogram_grid(self) -> bool:
        """True when some kinds (``own_frames``: the spectrogram) are framed on a grid of their own."""
        return self.spectrogram_frame_spec is not None

    def with_delays(self, delays: str | None) -> "ObservationSpec":
        """The same observations on ``delays`` (a run that asks for other delays on purpose); None
        keeps the spec's own."""
        if delays is None:
            return self
        return ObservationSpec(self.frames, tuple(ConfiguredKind(k.kind, k.config.with_delays(delays))
                                                  for k in self.kinds))

    def only(self, names: Sequence[str]) -> "ObservationSpec":
        """The same observations restricted to the kinds named in ``names`` (in the spec's order)."""
        return ObservationSpec(self.frames, tuple(k for k in self.kinds if k.kind in names))

    def with_kinds(self, *kinds: ConfiguredKind) -> "ObservationSpec":
        """These observations and ``kinds`` besides (Cross3D's refine reads the recording too)."""
        return ObservationSpec(self.frames, self.kinds + tuple(kinds))

    def with_grid(self, grid: Sequence[int] | str | None) -> "ObservationSpec":
        """The same observations with the kinds on the SRP grid on ``grid`` (None: unchanged)."""
        if grid is None:
            return self
        return ObservationSpec(self.frames, tuple(
            ConfiguredKind(k.kind, replace(k.config, grid=as_grid(grid))) if isinstance(k.config, MapConfig) else k
            for k in self.kinds))

    def plan(self, array: "MicArray | str", resolutions: "Sequence[Sequence[int] | str] | None" = None
             ) -> "ObservationPlan":
        """The :class:`~doabench.features.plan.ObservationPlan` computing these observations for
        ``array`` (its map kinds on ``resolutions`` when given, else on the spec's grid)."""
        from doabench.features.plan import ObservationPlan

        return ObservationPlan(self, array, resolutions)

    # -- text and stored forms --------------------------------------------------------------------
    def __str__(self) -> str:
        return f"{'+'.join(str(k) for k in self.kinds)} @ {frames_text(self.frames)}"

    @classmethod
    def parse(cls, text: str) -> "ObservationSpec":
        """The spec :meth:`__str__` wrote; a one-line ConfigError otherwise."""
        kinds, sep, frames = str(text).rpartition(" @ ")
        if not sep:
            raise ConfigError(f"{text!r} is not KINDS @ WINDOW/HOP@FS, e.g. srp(grid=16x32)+srp_max(grid=16x32) "
                              "@ 4096/3072@16000")
        return cls(parse_frames_text(frames), tuple(ConfiguredKind.parse(k) for k in kinds.split("+") if k.strip()))

    def to_dict(self) -> dict[str, Any]:
        """The one stored form of the spec (a results file's ``features``, a weights file's
        ``observations``, an ONNX file's ``doabench_observations``)::

            {"frames": {"window": 4096, "hop": 3072, "fs": 16000},
             "kinds": [{"kind": "srp", "grid": "16x32", "delays": "nearest"}, ...]}

        :meth:`from_dict` reads it back."""
        return {"frames": self.frames.to_dict(), "kinds": [k.to_dict() for k in self.kinds]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ObservationSpec":
        """The spec :meth:`to_dict` wrote (other keys beside it, such as a results file's
        ``trained_delays``, are ignored); a one-line ConfigError otherwise."""
        if not isinstance(d, Mapping) or "frames" not in d or not isinstance(d.get("kinds"), (list, tuple)):
            raise ConfigError(f"not a stored observation spec ({{frames, kinds: [...]}}): {_short(d)}")
        return cls(frame_spec_from_dict(d["frames"]), tuple(ConfiguredKind.from_dict(k) for k in d["kinds"]))


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 120 else text[:117] + "..."
