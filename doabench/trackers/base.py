"""The public tracker API.

A tracker turns per-frame features into one direction estimate per frame. Subclass
:class:`Tracker`, declare what it reads as one :class:`~doabench.ObservationSpec`
(``observation_spec``: a class attribute, or an instance attribute set in ``__init__`` where it
depends on the tracker's options or weights), implement :meth:`reset` and :meth:`step` (causal) or
:meth:`track` (offline, whole episode), and register it::

    import numpy as np
    import doabench

    @doabench.register_tracker("my-tracker")
    class MyTracker(doabench.Tracker):
        observation_spec = doabench.ObservationSpec.of(("srp",), "16x32")  # what it reads
        causal = True

        def reset(self, array, **context):   # context: see ResetContext
            self.grid = ...

        def step(self, observation):
            srp = observation["srp"]          # (n_theta, n_phi), float32
            ...
            return np.array([x, y, z])        # unit vector, array frame

A frame where the tracker finds no source (a silence, a detection below its threshold) returns
three NaNs: ``doabench.NO_SOURCE`` (``np.full(3, np.nan)``; a row of NaNs in the ``(frames, 3)``
output of :meth:`Tracker.track`). Any other output must be a finite, non-zero vector ``(3,)``; the
runner refuses anything else in one line. A "no source" frame counts a fixed 90 degree error in the
frame metrics, and on LOCATA tasks the stamps that take it have no active track
(docs/adding-a-tracker.md, "Saying no source").

Observations are dicts of numpy arrays for one frame, with the keys of the kinds its
``observation_spec`` lists (:attr:`Tracker.features`) plus ``vad`` (1 if the frame is voice-active, else 0):

* ``srp``: ``(n_theta, n_phi)`` SRP-PHAT map, mean removed, divided by its maximum, zero in silent frames
* ``srp_max``: ``(2,)`` normalised elevation and azimuth of the map maximum in ``[0, 1]``
* ``gcc``: ``(n_pairs, 2 * max_lag + 1)`` GCC-PHAT for lags ``-max_lag..max_lag``
* ``spectrogram``: ``(2 * n_mics, window // 2)`` magnitudes (each frame divided by its maximum)
  then phases / pi, DC bin dropped

Options from the command line (``--tracker name:16x32`` and ``--tracker-opt key=value``) arrive as
keyword arguments of the constructor: the part after the colon is passed as ``spec``.
"""
from __future__ import annotations

from typing import Any, ClassVar, Mapping, TypedDict

import numpy as np

from doabench.errors import ConfigError
from doabench.geometry import resolution_text
from doabench.arrays import MicArray
from doabench.features.spec import ObservationSpec
from doabench.framing import FrameSpec

#: What a tracker reads from its ``observation_spec`` (read-only views of it): a subclass that
#: assigns one of them a value of its own is refused (:meth:`Tracker.__init_subclass__`).
SPEC_VIEWS = ("features", "resolution", "frame_spec", "spectrogram_frame_spec")


class ResetContext(TypedDict, total=False):
    """The keyword arguments of :meth:`Tracker.reset` besides the array. Every key is optional:
    ``doabench run`` passes both, ``doabench track`` (a user's recording) only ``frame_spec``.
    A tracker should accept and ignore keys it does not know (``**context``).

    A tracker is told what a deployed tracker would know: the array (``reset``'s first argument),
    these keys and the observations. Nothing about the episode's scene (room, source trajectory,
    array position, T60, SNR, speech), its truth or its seed reaches a tracker; the runner reads
    them from the environment after the episode has been scored."""

    frame_spec: FrameSpec    # frames of the observations that follow (window, hop, fs)
    task: str                # id of the task the episode comes from


def observations_of(tracker: "Tracker") -> ObservationSpec:
    """What ``tracker`` reads: its ``observation_spec``, as the runner, ``track``, the trainer and
    the export read it; a one-line ConfigError naming the tracker when it declares none or one out
    of bounds (a plug-in's property may build it only when asked)."""
    try:
        declared = tracker.observation_spec
    except ConfigError as exc:
        raise ConfigError(f"tracker {tracker.name!r}: {exc}") from None
    if not isinstance(declared, ObservationSpec):
        raise ConfigError(f"tracker {tracker.name!r}: observation_spec must be a doabench.ObservationSpec, "
                          f"got {type(declared).__name__}")
    return declared


def resolve_delays(tracker: "Tracker", requested: str | None) -> tuple[str, str | None]:
    """The SRP delay mode a run uses and, when it is not the one the tracker was trained on, that
    trained mode: ``requested`` None (no ``--delays``) takes the trained mode (else the delays of
    the tracker's ``observation_spec``, ``nearest`` where it reads no map); an explicit request
    wins, on purpose, and the results say so."""
    trained = tracker.trained_delays
    if requested is None:
        return trained or observations_of(tracker).delays or "nearest", None
    return requested, trained if trained not in (None, requested) else None


class Tracker:
    """Base class of every tracker. See the module docstring for the contract."""

    #: registry id, set by :func:`doabench.register_tracker` (or by the subclass); an instance of a
    #: class loaded by its path gets the id it was made from (not a ClassVar for that reason)
    name: str = ""
    #: bump when the tracker's outputs change for the same input and weights
    version: ClassVar[str] = "1"
    #: causal trackers are run frame by frame with :meth:`step`; others with :meth:`track`
    causal: ClassVar[bool] = True
    #: what it reads, as one value: its kinds (``srp``, ``srp_max``, ``gcc``, ``spectrogram``,
    #: ``audio`` or a plug-in's), each with its settings, on its frames. The environment, the
    #: trainer, ``doabench track``, results and the ONNX export take exactly this value (unless a
    #: user asks for other delays on purpose). A subclass sets it as a class attribute, or as an
    #: instance attribute in ``__init__`` where it depends on options or weights (a learned tracker
    #: takes its weights' own).
    observation_spec: ObservationSpec = ObservationSpec.of(("srp",))
    #: the spec after the colon (``name:16x32``) is the SRP map resolution, so the canonical id
    #: names the resolution the tracker runs at (``name`` alone is ``name:16x32``):
    #: :func:`doabench.trackers.registry.canonical_tracker`
    resolution_in_id: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        declared = cls.__dict__.get("observation_spec")
        if declared is not None and not isinstance(declared, (ObservationSpec, property)):
            raise ConfigError(f"tracker class {cls.__name__}: observation_spec must be a doabench.ObservationSpec "
                              f"(ObservationSpec.of(kinds, resolution, frame_spec) builds one)")
        own = [name for name in SPEC_VIEWS if name in cls.__dict__ and not isinstance(cls.__dict__[name], property)]
        if own:
            raise ConfigError(f"tracker class {cls.__name__} sets {', '.join(own)}: declare what it reads as one "
                              "observation_spec = doabench.ObservationSpec.of(kinds, resolution, frame_spec); "
                              f"{', '.join(own)} are read from it")

    def __init__(self, spec: str | None = None, **options: Any) -> None:
        self.spec = spec
        self.options = dict(options)

    # -- what the environment needs to know (views of observation_spec) -----------------------
    @property
    def features(self) -> tuple[str, ...]:
        """The observation keys it reads: the names of its ``observation_spec``'s kinds."""
        return observations_of(self).kind_names

    @property
    def resolution(self) -> tuple[int, int] | None:
        """``(n_theta, n_phi)`` of the SRP maps it reads (its ``observation_spec``'s grid), or None
        if it reads no map."""
        return observations_of(self).resolution

    @property
    def frame_spec(self) -> FrameSpec:
        """Window, hop and sample rate of the observations it reads (its ``observation_spec``'s)."""
        return observations_of(self).frames

    @property
    def trained_delays(self) -> str | None:
        """The SRP delay mode (``nearest``, ``exact``) its weights were trained on, or None when
        it was trained on none (a classical tracker, random weights): a run uses this mode unless
        the user asks for another on purpose (:func:`resolve_delays`)."""
        return None

    @property
    def receptive_field_frames(self) -> int | None:
        """How many past frames one estimate depends on (None: unbounded, e.g. a Kalman filter)."""
        return 1

    def weights_hash(self) -> str | None:
        """SHA-256 of the weights file it loaded, if any."""
        return None

    @property
    def weights_name(self) -> str | None:
        """The short name of the shipped weights it runs (``paper``, ``moving``), if it ships named
        weights and runs one of them (``--tracker-opt weights=NAME`` selects it)."""
        return None

    @property
    def plain_weights_name(self) -> str | None:
        """The name of the weights that a run leaves unnamed in its options (a tracker's first,
        plain weights: results made with them always carried no weights option); None: none."""
        return None

    @property
    def loads_default_weights(self) -> bool:
        """Whether the weights file it loaded is the one it loads without a weights option (the same
        SHA-256, wherever the file was read from): a run given that file by path then carries no
        weights option (:func:`doabench.trackers.registry.canonical_tracker`). False for a tracker
        without weights."""
        return False

    @classmethod
    def shipped_weights(cls) -> list[dict[str, Any]]:
        """Every shipped weights file of this tracker, for ``doabench list weights``: dicts with
        ``tracker`` (canonical id), ``name``, ``default`` (bool: what runs without a weights option),
        ``file``, ``sha256``, ``task`` (trained on), ``run`` (its training run's folder name, or None)
        and ``headline`` (``{task: {"rmsae_all", "rmsae_nonsilent", "lag_s", "episodes"}}``, with
        ``lag_note`` saying why where ``lag_s`` is None)."""
        return []

    def parameter_count(self) -> int:
        """Trainable parameters (0 for classical trackers)."""
        return 0

    def describe(self) -> dict[str, Any]:
        """What ``doabench describe`` prints."""
        return {
            "name": self.name,
            "version": self.version,
            "spec": self.spec,
            "causal": self.causal,
            "features": list(self.features),
            "resolution": resolution_text(self.resolution),
            "resolution_in_id": bool(self.resolution_in_id),
            "parameters": self.parameter_count(),
            "receptive_field_frames": self.receptive_field_frames,
            "frame": self.frame_spec.to_dict(),
            "weights_hash": self.weights_hash(),
            "weights_name": self.weights_name,
        }

    # -- the work -------------------------------------------------------------------------------
    def reset(self, array: MicArray, **context: Any) -> None:
        """Start a new episode recorded with ``array``. Called before the first step.

        ``context``: the keys of :class:`ResetContext` that the caller knows (``frame_spec``,
        ``task``), each optional. Nothing about the episode's scene or truth is passed."""

    def step(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """One frame in, one direction ``(3,)`` out (causal trackers), or ``doabench.NO_SOURCE``
        (three NaNs) when it finds no source in the frame."""
        raise NotImplementedError(f"tracker {self.name!r} is offline-only: use track()")

    def track(self, episode: Mapping[str, np.ndarray]) -> np.ndarray:
        """Whole episode in (each value ``(frames, ...)``), directions ``(frames, 3)`` out (a row of
        three NaNs for a frame without a source).

        The default runs :meth:`step` frame by frame, so causal trackers need not override it.
        """
        n = len(episode["vad"])
        return np.stack([self.step({k: v[t] for k, v in episode.items()}) for t in range(n)]) if n else np.zeros((0, 3))
