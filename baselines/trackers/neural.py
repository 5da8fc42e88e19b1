"""What every learned tracker shares: its weights, its network, running it frame by frame or over
an episode, and turning the network's output into a direction.

The jobs around it live in their own modules: which weights it runs, by name or by default, and
whether they are shipped or its default (:mod:`~doabench_baselines.catalog`: the tracker asks it
and works none of that out itself), reading, verifying and describing the weights file
(:class:`~doabench_baselines.weights.WeightsFile`), the device (:mod:`..device`), the hold rule
(:class:`~doabench_baselines.hold.SilenceHold`), streaming (:mod:`..streaming`). Each model is a
subclass in a module of its own (:mod:`.cross3d`, :mod:`.max_cnn1d`, :mod:`.gcc_cnn1d`,
:mod:`.spec_cnn2d`, :mod:`.seldnet`).
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Mapping

import numpy as np

import doabench
from doabench.errors import ConfigError, TrackerError

from .. import catalog
from ..device import torch_device
from ..hold import SilenceHold, parse_hold
from ..weights import make_metadata, parse_resolution, resolution_text, save_weights

# torch and the model modules are imported where a tracker is built or run, not at import time:
# doabench loads these modules to list the registered trackers (`doabench list trackers`), which
# then needs no torch (0.6 s instead of 3 s here).
if TYPE_CHECKING:
    import torch
    from torch import nn

_INITIAL_DIRECTION = np.array([1.0, 0.0, 0.0])  # until the network gives a usable direction
_RANDOM = ("random", "none", "false", "")  # weights=random (or none/false) forces random init


class NeuralTracker(doabench.Tracker):
    """A learned tracker: its weights file, its network, frame-by-frame and whole-episode runs."""

    causal: ClassVar[bool] = True
    #: 2: causal models hold their estimate in long silences (``hold=auto``, :attr:`hold_frames`)
    version: ClassVar[str] = "2"
    #: model id used in weight files (the registry id)
    model_name: ClassVar[str] = ""
    #: whether the model is tied to an SRP map resolution (part of the weight file name)
    uses_resolution: ClassVar[bool] = False
    #: what the network reads when no weights say it (random weights: ``weights=random``); a
    #: tracker with weights reads its weights' own spec (the weights file's ``observations``)
    observation_spec = doabench.ObservationSpec.of(("srp",))

    @property
    def resolution_in_id(self) -> bool:  # type: ignore[override]
        """``cross3d`` and ``cross3d:16x32`` are one model: the id names the map resolution."""
        return self.uses_resolution

    def __init__(self, spec: str | None = None, weights: str | None = None, device: str = "cpu",
                 seed: int = 0, resolution: str | None = None, array: str | None = None,
                 hold: str | int = "auto") -> None:
        super().__init__(spec)
        if not self.uses_resolution and (spec or resolution):
            raise ConfigError(f"tracker {self.model_name!r} takes no map resolution (got {spec or resolution!r})")
        self.options = {"weights": weights, "device": device, "seed": seed, "resolution": resolution, "array": array,
                        "hold": hold}
        self._hold_option = parse_hold(hold)
        self.device = torch_device(str(device))
        #: weights=random given on purpose: running the untrained model is then allowed (and marked)
        self.allow_untrained = weights is not None and str(weights).lower() in _RANDOM
        res_text = resolution or spec
        asked = parse_resolution(res_text) if self.uses_resolution and res_text else None
        self.weights_file = None if self.allow_untrained else catalog.find_weights(
            self.model_name, asked or (self._default_resolution() if self.uses_resolution else None), weights)
        self._resolution = self._pick_resolution(asked)
        if self.weights_file is not None and self.uses_resolution:
            # Re-check now that the resolution is settled (a weight file for other maps is an error).
            self.weights_file.check(resolution=self._resolution)
        self._array = self._pick_array(array)
        #: what it reads: the spec its weights were trained on, as the weights entry carries it
        #: (the class's on this resolution for random weights)
        self.observation_spec = self._own_observations()
        import torch

        from ..streaming import StreamingRunner

        with torch.random.fork_rng(devices=[]):  # reproducible random init, global RNG untouched
            torch.manual_seed(int(seed))
            self.model = self.build_model()
        if self.weights_file is not None:
            self.weights_file.load_into(self.model, self.model_name, self.observation_spec)
        elif not self.allow_untrained:
            warnings.warn(f"{self.model_name}: no trained weights{self._for_resolution()}; using a randomly "
                          "initialised model (describe() reports trained: false; runs refuse it). Pass "
                          "weights=FILE, or weights=random to run it untrained on purpose.", stacklevel=3)
        self.model = self.model.to(self.device).eval()
        self._runner = StreamingRunner(self.model) if self.causal else None
        self._last = _INITIAL_DIRECTION.copy()
        hold_frames = self.hold_frames
        self._hold = SilenceHold(hold_frames) if hold_frames is not None else None

    # -- construction helpers ---------------------------------------------------------------------
    def build_model(self) -> nn.Module:
        raise NotImplementedError

    def _for_resolution(self) -> str:
        return f" for {resolution_text(self._resolution)} maps" if self.uses_resolution and self._resolution else ""

    def _default_resolution(self) -> tuple[int, int] | None:
        return None

    def _own_observations(self) -> doabench.ObservationSpec:
        declared = type(self).observation_spec
        if self.weights_file is None:
            return doabench.ObservationSpec.of(declared.kind_names, self._resolution, declared.frames)
        stored = self.weights_file.observations
        if stored.kind_names != declared.kind_names:
            raise ConfigError(f"weights file {self.weights_file.path.name} was trained on {stored}, not on the kinds "
                              f"{self.model_name} reads ({', '.join(declared.kind_names)})")
        return stored

    def _pick_resolution(self, asked: tuple[int, int] | None) -> tuple[int, int] | None:
        """The map resolution: the one asked for, else the weights' own, else the model's default."""
        if not self.uses_resolution:
            return None
        if asked is not None:
            return asked
        if self.weights_file is not None and self.weights_file.resolution is not None:
            return self.weights_file.resolution
        return self._default_resolution()

    def _pick_array(self, array: str | None) -> doabench.MicArray:
        trained = self.weights_file.array if self.weights_file is not None else None
        if trained is not None:
            if array is not None:
                self.weights_file.check_array(doabench.get_array(array), f"weights file {self.weights_file.path.name}")
            return trained
        return doabench.get_array(array or "nao")

    # -- what the environment needs -----------------------------------------------------------------
    @property
    def trained_array(self) -> doabench.MicArray:
        """The array the weights were trained for (the ``array`` option, else the weights' own)."""
        return self._array

    @property
    def receptive_field_frames(self) -> int | None:
        return getattr(self.model, "receptive_field", None)

    @property
    def hold_frames(self) -> int | None:
        """Silent frames after which the output holds (None: never; offline models never hold;
        :mod:`doabench_baselines.hold` says why). ``auto``: half the receptive field (16x32: 18
        frames, 3.5 s; holding after 6-21 frames scored 13.0-13.2 deg on the sim-train v2
        validation set against 18.2 deg without: docs/results.md)."""
        if not self.causal or self._hold_option == 0:
            return None
        if self._hold_option is None:  # auto
            rf = self.receptive_field_frames
            return None if rf is None else max(1, rf // 2)
        return self._hold_option

    @property
    def trained(self) -> bool:
        return self.weights_file is not None

    def weights_hash(self) -> str | None:
        return self.weights_file.sha256 if self.weights_file is not None else None

    @property
    def weights_name(self) -> str | None:
        """The catalog name of the weights in use (``paper``, ``moving``): the shipped file of this
        tracker with the same SHA-256, wherever it was read from; None for other files and random weights."""
        return catalog.name_of(self.model_name, self._resolution, self.weights_hash())

    @property
    def plain_weights_name(self) -> str | None:
        """The name of this tracker's plain weights (``<model>[-<res>].safetensors``): a run with
        them carries no weights option (:func:`doabench.trackers.registry.canonical_tracker`)."""
        return catalog.plain_name(self.model_name, self._resolution)

    @property
    def loads_default_weights(self) -> bool:
        """Whether the file it loaded is the one it runs without a weights option (the same SHA-256)."""
        return catalog.is_default(self.model_name, self._resolution, self.weights_hash())

    @classmethod
    def shipped_weights(cls) -> list[dict[str, Any]]:
        """The catalog's entries of this model (every resolution), default first per tracker id."""
        return catalog.listing(cls.model_name)

    def parameter_count(self) -> int:
        from ..layers import count_parameters

        return count_parameters(self.model)

    def describe(self) -> dict[str, Any]:
        from ..layers import receptive_field_seconds

        d = super().describe()
        rf = self.receptive_field_frames
        fs = self.frame_spec
        weights = self.weights_file.describe() if self.weights_file is not None else {
            "weights": None, "training": None, "trained_features": None}
        d.update(
            model=self.model_name,
            trained=self.trained,
            weights=weights["weights"],
            device=str(self.device),
            array=self._array.name,
            receptive_field_s=None if rf is None else round(receptive_field_seconds(rf, fs.window, fs.hop, fs.fs), 3),
            training=weights["training"],
            trained_features=weights["trained_features"],
            hold_frames=self.hold_frames,
        )
        return d

    @property
    def trained_delays(self) -> str | None:
        """The SRP delay mode of the maps its weights were trained on (its weights' spec), or None
        for random weights and a network that reads no map."""
        return self.observation_spec.delays if self.weights_file is not None else None

    def save_weights(self, path: str | Path, metadata: Mapping[str, Any] | None = None) -> Path:
        """Write the network to a weight file (training protocol: ``save_weights(path, metadata)``).

        The file's metadata is built here (model, resolution, array positions, the observations the
        network reads, parameter count, version, date); from ``metadata`` it takes ``training`` (the
        recipe summary), ``observations`` (the stored :class:`~doabench.ObservationSpec` it was
        trained on, whose delays are kept; else :attr:`observation_spec` on
        ``feature_settings.delays`` from trainers older than that, default ``nearest``) and
        ``array`` (the training array's name or file, whose positions are recorded), and keeps its
        other keys as they are. The keys built here win over the caller's.
        """
        extra = dict(metadata or {})
        training = extra.pop("training", None)
        trained_on = extra.pop("observations", None)
        legacy = (extra.get("feature_settings") or {}).get("delays", extra.pop("delay_mode", None))
        own = self.observation_spec.only(self.network_features)
        delays = (doabench.ObservationSpec.from_dict(trained_on).delays if trained_on else legacy) or own.delays
        observations = own.with_delays(delays)
        array = self._array
        if isinstance(extra.get("array"), str):
            array = doabench.get_array(extra["array"])
            self.check_array_fits(array)
        config = {"resolution": resolution_text(self._resolution)} if self.uses_resolution else {}
        meta = make_metadata(self.model_name, self.model, array=array, observations=observations.to_dict(),
                             model_config=config, training=training)
        for key, value in extra.items():
            meta.setdefault(key, value)
        return save_weights(path, self.model, meta)

    # -- training protocol (doabench.training) -----------------------------------------------------
    @property
    def network(self) -> nn.Module:
        """The torch module that is trained: ``network(x)`` -> ``(batch, frames, 3)``."""
        return self.model

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """Batched features ``{kind: (batch, frames, ...)}`` -> the network's input tensor."""
        raise NotImplementedError

    def warm_start_from(self, source: doabench.Tracker) -> None:
        """Start this tracker's network from the trained weights of ``source`` (training protocol,
        ``doabench train --warm-start``): the same model reading the same observations on the same
        frames, at this resolution or, where the model can carry weights over (:meth:`adapt_weights`),
        another. Anything else is refused in one line before training starts."""
        name = f"--warm-start {source.name}"
        if not isinstance(source, NeuralTracker) or source.model_name != self.model_name:
            raise ConfigError(f"{name}: a warm start needs weights of {self.model_name!r}, not of another tracker")
        if not source.trained:
            raise ConfigError(f"{name}: the tracker has no trained weights to start from (weights=random)")
        mine, theirs = self.observation_spec, source.observation_spec
        # the grid may differ (adapt_weights carries the weights over); nothing else may
        if theirs.with_grid(mine.resolution) != mine.with_grid(mine.resolution):
            raise ConfigError(f"{name}: its weights read other observations ({theirs}) than {self.name} trains on "
                              f"({mine})")
        if source.trained_array.positions.shape != self.trained_array.positions.shape or not np.allclose(
                source.trained_array.positions, self.trained_array.positions):
            raise ConfigError(f"{name}: its weights were trained on the {source.trained_array.name} array, "
                              f"this run trains on {self.trained_array.name}")
        state = {k: v.detach().clone() for k, v in source.network.state_dict().items()}
        if source.resolution != self.resolution:
            state = self.adapt_weights(state, source.resolution)
        self.load_network_state(state, name)

    def adapt_weights(self, state: dict[str, torch.Tensor], resolution: tuple[int, int] | None) -> dict[str, torch.Tensor]:
        """``state``, weights of this model for ``resolution`` maps, made to fit this tracker's maps
        (a warm start); models that cannot do this refuse it."""
        raise ConfigError(f"{self.model_name}: weights for {resolution_text(resolution) if resolution else 'no'} maps "
                          f"cannot start a model for {resolution_text(self.resolution) if self.resolution else 'no'} maps")

    def load_network_state(self, state: Mapping[str, torch.Tensor], where: str) -> None:
        """Load ``state`` into the network; a tensor of another shape is one line naming it."""
        own = self.network.state_dict()
        wrong = [k for k in own if k not in state or tuple(state[k].shape) != tuple(own[k].shape)]
        if wrong or set(state) - set(own):
            raise ConfigError(f"{where}: its weights do not fit {self.name} "
                              f"({wrong[0] if wrong else sorted(set(state) - set(own))[0]})")
        self.network.load_state_dict(state)

    # -- running --------------------------------------------------------------------------------------
    def reset(self, array: doabench.MicArray, **context: Any) -> None:
        frame_spec = context.get("frame_spec")
        if frame_spec is not None and (frame_spec.window, frame_spec.hop, frame_spec.fs) != (
                self.frame_spec.window, self.frame_spec.hop, self.frame_spec.fs):
            raise ConfigError(f"tracker {self.name!r} needs frames {self.frame_spec.to_dict()}, "
                              f"the environment gives {frame_spec.to_dict()}")
        if self.weights_file is not None:
            self.weights_file.check_array(array, f"tracker {self.name!r}: weights file {self.weights_file.path.name}")
        self.check_array_fits(array)
        if self._runner is not None:
            self._runner.reset()
        self._last = _INITIAL_DIRECTION.copy()
        if self._hold is not None:
            self._hold.reset()

    def check_array_fits(self, array: doabench.MicArray) -> None:
        """Raise ConfigError when the episode's array cannot feed the model's input layer."""

    @property
    def network_features(self) -> tuple[str, ...]:
        """The observation kinds the network reads: those of the class's ``observation_spec`` (an
        instance may read more for what it does after the network, e.g. Cross3D's ``refine`` reads
        ``audio``)."""
        return type(self).observation_spec.kind_names

    def frame_input(self, observation: Mapping[str, np.ndarray]) -> torch.Tensor:
        """One observation -> the model's input frame ``(1, *frame_shape)``: the episode path
        with one frame, so both paths build identical inputs."""
        x = self.network_input({k: self._tensor(observation[k])[None, None] for k in self.network_features})
        return x[:, :, 0]  # drop the time axis (axis 2 in every model)

    def episode_input(self, episode: Mapping[str, np.ndarray]) -> torch.Tensor:
        """A whole episode ``{kind: (frames, ...)}`` -> the network's input with batch 1."""
        return self.network_input({k: self._tensor(episode[k])[None] for k in self.network_features})

    @property
    def refines(self) -> bool:
        """Whether :meth:`refine` changes the network's directions (False here: it does not)."""
        return False

    def refine(self, directions: np.ndarray, observations: Mapping[str, np.ndarray]) -> np.ndarray:
        """The network's directions ``(frames, 3)`` after any post-processing of the model's own, before
        the hold rule; ``observations``: ``{kind: (frames, ...)}`` of the same frames. Called only
        where :attr:`refines`; none here."""
        return directions

    def step(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        if self._runner is None:
            return super().step(observation)  # offline model: the base class says to use track()
        y = self._runner.step(self.frame_input(observation))[0]
        direction = self.direction_from_output(y.detach().double().cpu().numpy())
        if self.refines:  # one frame as a batch of one
            direction = self.refine(direction[None], {k: np.asarray(v)[None] for k, v in observation.items()})[0]
        if self._hold is None:
            return direction
        return self._hold.step(direction, bool(np.asarray(observation.get("vad", True))))

    def track(self, episode: Mapping[str, np.ndarray]) -> np.ndarray:
        import torch

        from ..streaming import stream_episode

        n = len(episode["vad"])
        if n == 0:
            return np.zeros((0, 3))
        x = self.episode_input(episode)
        if self.causal:
            y = stream_episode(self.model, x)
        else:
            with torch.inference_mode():
                y = self.model(x)
        self._last = _INITIAL_DIRECTION.copy()
        directions = np.stack([self.direction_from_output(v) for v in y[0].to("cpu", torch.float64).numpy()])
        if self.refines:
            directions = self.refine(directions, episode)
        return directions if self._hold is None else self._hold.episode(directions, episode["vad"])

    def direction_from_output(self, y: np.ndarray) -> np.ndarray:
        """Normalise the network output; keep the previous direction if it is (near) zero. A NaN or
        infinite output is an error (broken weights or inputs), never silently held."""
        y = np.asarray(y, dtype=np.float64)
        if not np.all(np.isfinite(y)):
            raise TrackerError(
                f"tracker {self.name!r}: the network output {y} is not finite (damaged weights or inputs?)")
        scale = float(np.max(np.abs(y))) if y.size else 0.0
        if scale > 0:
            u = y / scale  # scaled first: the norm of huge outputs does not overflow
            norm = float(np.linalg.norm(u)) * scale
            if norm > 1e-6:
                self._last = u / np.linalg.norm(u)
        return self._last.copy()

    def _tensor(self, a: np.ndarray) -> torch.Tensor:
        import torch

        return torch.as_tensor(np.asarray(a, dtype=np.float32), device=self.device)
