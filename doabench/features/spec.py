"""What a tracker reads, as one value: :class:`ObservationSpec` (kinds, SRP grid, frames, delays).

A tracker declares it (:attr:`doabench.Tracker.observation_spec`); the environment
(:func:`doabench.runner.loop.make_env_for`), the trainer, ``doabench track`` and the ONNX export
take that value instead of reassembling it from the tracker's attributes, so a tracker is
evaluated on the observations it was trained on. A run that asks for other delays on purpose says
so in its results (``features.trained_delays``).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Mapping, Sequence, cast

from doabench.errors import ConfigError
from doabench.features.kinds import DEFAULT_RESOLUTION, DELAY_MODES, check_kinds, own_frame_kinds
from doabench.geometry import resolution_text
from doabench.framing import FrameSpec
from doabench.geometry import as_grid

if TYPE_CHECKING:  # the plan imports torch lazily, but the spec needs none of it
    from doabench.arrays import MicArray
    from doabench.features.plan import ObservationPlan


@dataclass(frozen=True)
class ObservationSpec:
    """The observations a tracker reads.

    ``kinds``: observation kinds (``srp``, ``srp_max``, ``gcc``, ``spectrogram``, ``audio`` or a
    plug-in's); ``resolution``: the SRP grid ``(n_theta, n_phi)``; ``frame_spec``: window, hop and
    sample rate; ``delays``: the SRP delay mode (``nearest``, the paper's, or ``exact``);
    ``spectrogram_frame_spec``: the second frame grid, of the kinds declared ``own_frames`` (the
    spectrogram), when it differs (None: the same).
    """

    kinds: tuple[str, ...]
    resolution: tuple[int, int] = DEFAULT_RESOLUTION
    frame_spec: FrameSpec = FrameSpec()
    delays: str = "nearest"
    spectrogram_frame_spec: FrameSpec | None = None

    def __post_init__(self) -> None:
        kinds = (self.kinds,) if isinstance(self.kinds, str) else tuple(self.kinds)
        object.__setattr__(self, "kinds", check_kinds(kinds))
        resolution = self.resolution  # the constructor also takes "16x32" or any sequence of sizes
        object.__setattr__(self, "resolution", as_grid(resolution))
        if self.delays not in DELAY_MODES:
            raise ConfigError(f"unknown delay mode {self.delays!r}: use one of {', '.join(DELAY_MODES)}")
        if not isinstance(self.frame_spec, FrameSpec) or not (
                self.spectrogram_frame_spec is None or isinstance(self.spectrogram_frame_spec, FrameSpec)):
            raise ConfigError("frame_spec and spectrogram_frame_spec must be doabench.FrameSpec values")
        if self.spectrogram_frame_spec == self.frame_spec:
            object.__setattr__(self, "spectrogram_frame_spec", None)  # one grid: said one way

    @classmethod
    def of(cls, kinds: Sequence[str], resolution: Sequence[int] | str | None = None,
           frame_spec: FrameSpec | None = None, delays: str | None = None,
           spectrogram_frame_spec: FrameSpec | None = None) -> "ObservationSpec":
        """A spec with the defaults for what is None (the 16x32 grid, the paper's frames, nearest delays)."""
        # __post_init__ turns a "16x32" string or a sequence of sizes into the (n_theta, n_phi) tuple
        grid = cast("tuple[int, int]", resolution or DEFAULT_RESOLUTION)
        return cls(tuple(kinds), grid, frame_spec or FrameSpec(), delays or "nearest", spectrogram_frame_spec)

    def with_delays(self, delays: str | None) -> "ObservationSpec":
        """The same observations on ``delays`` (a run that asks for other delays on purpose); None
        keeps the spec's own."""
        return self if delays is None else replace(self, delays=delays)

    @property
    def separate_spectrogram_grid(self) -> bool:
        """True when some kinds (``own_frames``: the spectrogram) are framed on a grid of their own."""
        return self.spectrogram_frame_spec is not None and bool(own_frame_kinds(self.kinds))

    def plan(self, array: "MicArray | str") -> "ObservationPlan":
        """The :class:`~doabench.features.plan.ObservationPlan` computing these observations for ``array``."""
        from doabench.features.plan import ObservationPlan

        return ObservationPlan(self.kinds, array, self.frame_spec, (self.resolution,), self.delays,
                               self.spectrogram_frame_spec)

    def env_options(self) -> dict[str, Any]:
        """The :class:`~doabench.envs.DoaEnv` keywords that give these observations."""
        return {"features": self.kinds, "resolution": self.resolution, "delays": self.delays,
                "frame_spec": self.frame_spec, "spectrogram_frame_spec": self.spectrogram_frame_spec}

    def to_dict(self) -> dict[str, Any]:
        """The one stored form of the spec (a results file's ``features``, a weights file's
        ``observations``, an ONNX file's ``doabench_observations``); :meth:`from_dict` reads it back."""
        d: dict[str, Any] = {"kinds": list(self.kinds), "resolution": resolution_text(self.resolution),
                             "delays": self.delays, "frame": self.frame_spec.to_dict()}
        if self.spectrogram_frame_spec is not None:
            d["spectrogram_frame"] = self.spectrogram_frame_spec.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "ObservationSpec":
        """The spec :meth:`to_dict` wrote (other keys beside it, such as a results file's
        ``trained_delays``, are ignored); a one-line ConfigError naming what is missing or wrong."""
        try:
            frame = _frame_spec(d["frame"])
            spectrogram = _frame_spec(d["spectrogram_frame"]) if d.get("spectrogram_frame") else None
            return cls(tuple(d["kinds"]), d["resolution"], frame, str(d.get("delays") or "nearest"), spectrogram)
        except (KeyError, TypeError) as exc:
            raise ConfigError(f"not a stored observation spec (kinds, resolution, delays, frame): missing or "
                              f"malformed {exc}") from None


def _frame_spec(d: Mapping[str, Any]) -> FrameSpec:
    return FrameSpec(int(d["window"]), int(d["hop"]), int(d["fs"]))
