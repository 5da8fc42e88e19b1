"""Tracker classes of the neural models, built on doabench's public plugin API only.

Registered ids (``--tracker ID[:SPEC]`` with ``--tracker-opt key=value``):

* ``cross3d[:RES]``  – Cross3D on SRP maps (``srp``, ``srp_max``); RES defaults to the highest
  resolution with shipped weights, else 8x16.
* ``gcc-cnn1d``      – 1D CNN on GCC-PHAT (``gcc``); option ``array`` (default ``nao``).
* ``max-cnn1d[:RES]``– 1D CNN on the map maxima (``srp_max``); RES defaults to 64x128.
* ``spec-cnn2d``     – causal 2D CNN on spectrograms (``spectrogram``, K = 4096).
* ``seldnet``        – SELDnet DOA replica on spectrograms (K = 512), offline (``track``).

Common options: ``weights=FILE`` (default: the shipped file if any, else random initialisation;
``weights=random`` forces it), ``device=cpu|cuda[:N]``, ``seed=N`` (random initialisation),
``hold=auto|off|N`` (causal models: see :meth:`NeuralTracker.hold_frames`).
Untrained trackers say ``trained: false`` in :meth:`describe`. They can be built (``describe``,
docs, training from scratch), but ``doabench run``/``track``/``doabench.run`` refuse them unless
``weights=random`` was given explicitly (:attr:`NeuralTracker.allow_untrained`).

Causal trackers run one frame per :meth:`step` through a :class:`StreamingRunner`; their
:meth:`track` streams the episode in chunks and gives the same directions.
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Mapping

import numpy as np

import doabench
from doabench.errors import ConfigError, TrackerError

from . import catalog
from .weights import (check_array, check_metadata, load_into, load_weights, make_metadata, parse_resolution,
                      read_metadata, resolution_text, save_weights, sha256_file)

# torch and the model modules are imported where a tracker is built or run, not at import time:
# doabench loads this module to list the registered trackers (`doabench list trackers`), which
# then needs no torch (0.6 s instead of 3 s here).
if TYPE_CHECKING:
    import torch
    from torch import nn

_INITIAL_DIRECTION = np.array([1.0, 0.0, 0.0])  # until the network gives a usable direction
_RANDOM = ("random", "none", "false", "")  # weights=random (or none/false) forces random init
_TRACK_CHUNK = 64  # frames per forward pass in track(): bounds memory on long episodes


_NEVER_VOICED = 1 << 62  # silent-run count before the first voice-active frame


def _parse_hold(value: str | int) -> int | None:
    """``hold`` option: None for auto, 0 for off, else a positive frame count."""
    text = str(value).strip().lower()
    if text == "auto":
        return None
    if text in ("off", "none", "false", "0", "no"):
        return 0
    try:
        frames = int(text)
    except ValueError:
        frames = -1
    if frames < 1:
        raise ConfigError(f"hold must be auto, off or a number of frames >= 1, got {value!r}")
    return frames


def _device(text: str) -> torch.device:
    import torch

    try:
        device = torch.device(text)
    except (RuntimeError, TypeError):
        raise ConfigError(f"unknown device {text!r}: use cpu or cuda[:N]") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {text!r} requested but CUDA is not available; use device=cpu")
    if device.type not in ("cpu", "cuda"):
        raise ConfigError(f"unsupported device {text!r}: use cpu or cuda[:N]")
    return device


class NeuralTracker(doabench.Tracker):
    """Shared machinery: weights, device, describe, streaming, direction normalisation."""

    causal: ClassVar[bool] = True
    #: 2: causal models hold their estimate in long silences (``hold=auto``, :attr:`hold_frames`)
    version: ClassVar[str] = "2"
    #: model id used in weight files (the registry id)
    model_name: ClassVar[str] = ""
    #: whether the model is tied to an SRP map resolution (part of the weight file name)
    uses_resolution: ClassVar[bool] = False
    default_frame_spec: ClassVar[doabench.FrameSpec] = doabench.FrameSpec()

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
        self._hold_option = _parse_hold(hold)
        self.device = _device(str(device))
        #: weights=random given on purpose: running the untrained model is then allowed (and marked)
        self.allow_untrained = weights is not None and str(weights).lower() in _RANDOM
        self._weights_path, self._meta = self._find_weights(weights, resolution or spec)
        meta = self._meta or {}
        self._resolution = self._pick_resolution(resolution or spec, meta)
        if self._meta is not None and self.uses_resolution:
            # Re-check now that the resolution is settled (a weight file for other maps is an error).
            check_metadata(self._meta, self._weights_path, resolution=self._resolution)
        self._array = self._pick_array(array, meta)
        feats = meta.get("features", {})
        self._frame_spec = (doabench.FrameSpec(feats["window"], feats["hop"], feats["fs"])
                            if self._meta is not None else self.default_frame_spec)
        import torch

        from .streaming import StreamingRunner

        with torch.random.fork_rng(devices=[]):  # reproducible random init, global RNG untouched
            torch.manual_seed(int(seed))
            self.model = self.build_model()
        if self._meta is not None:
            state, _ = load_weights(self._weights_path, model_name=self.model_name, frame_spec=self._frame_spec)
            load_into(self.model, state, self._weights_path)
            self._hash = sha256_file(self._weights_path)
        else:
            self._hash = None
            if not self.allow_untrained:
                warnings.warn(f"{self.model_name}: no trained weights{self._for_resolution()}; using a randomly "
                              "initialised model (describe() reports trained: false; runs refuse it). Pass "
                              "weights=FILE, or weights=random to run it untrained on purpose.", stacklevel=3)
        self.model = self.model.to(self.device).eval()
        self._runner = StreamingRunner(self.model) if self.causal else None
        self._last = _INITIAL_DIRECTION.copy()
        self._silent_run, self._held = _NEVER_VOICED, None

    # -- construction helpers ---------------------------------------------------------------------
    def build_model(self) -> nn.Module:
        raise NotImplementedError

    def _for_resolution(self) -> str:
        return f" for {resolution_text(self._resolution)} maps" if self.uses_resolution and self._resolution else ""

    def _default_resolution(self) -> tuple[int, int] | None:
        return None

    def _find_weights(self, weights: str | None, res_text: str | None) -> tuple[Path | None, dict | None]:
        """The weights file and its metadata: ``random``: none; a name of the catalog (``moving``,
        ``default``; :mod:`.catalog`) or nothing: that shipped file of this tracker's resolution; else
        a file path, whose own metadata then settles the resolution."""
        if weights is not None and str(weights).lower() in _RANDOM:
            return None, None
        res = None
        if self.uses_resolution:
            res = parse_resolution(res_text) if res_text else self._default_resolution()
        path = catalog.resolve(self.model_name, res, weights)
        if path is None and weights is not None:
            path = Path(str(weights)).expanduser()
        if path is None:
            return None, None
        meta = read_metadata(path)
        check_metadata(meta, path, model_name=self.model_name)
        return path, meta

    def _pick_resolution(self, res_text: str | None, meta: Mapping[str, Any]) -> tuple[int, int] | None:
        if not self.uses_resolution:
            return None
        if res_text:
            return parse_resolution(res_text)
        if meta.get("resolution"):
            return parse_resolution(meta["resolution"])
        return self._default_resolution()

    def _pick_array(self, array: str | None, meta: Mapping[str, Any]) -> doabench.MicArray:
        if meta.get("array"):
            trained = doabench.MicArray(meta["array"]["name"], np.asarray(meta["array"]["positions"], dtype=float))
            if array is not None:
                check_array(meta, doabench.get_array(array), f"weights file {self._weights_path.name}")
            return trained
        return doabench.get_array(array or "nao")

    # -- what the environment needs -----------------------------------------------------------------
    @property
    def resolution(self) -> tuple[int, int] | None:
        return self._resolution

    @property
    def frame_spec(self) -> doabench.FrameSpec:
        return self._frame_spec

    @property
    def trained_array(self) -> doabench.MicArray:
        """The array the weights were trained for (the ``array`` option, else the weights' own)."""
        return self._array

    @property
    def receptive_field_frames(self) -> int | None:
        return getattr(self.model, "receptive_field", None)

    @property
    def hold_frames(self) -> int | None:
        """Silent frames after which the output holds (None: never; offline models never hold).

        A causal model sees only its receptive field (Cross3D 16x32: 37 frames, 7.2 s). Once a
        silence fills it the input holds no trace of the talker and the output wanders (on the
        sim-train v2 validation set, cross3d:16x32 erred by 7-14 deg up to 30 silent frames and
        by 56-87 deg beyond). So after ``hold`` consecutive voice-inactive frames the tracker
        repeats its last estimate from before that point until someone speaks again; before the
        first voice-active frame there is nothing to hold and the model's output is returned.
        ``auto``: half the receptive field (16x32: 18 frames, 3.5 s; holding after 6-21 frames
        scored 13.0-13.2 deg on that validation set against 18.2 deg without: docs/results.md).
        """
        if not self.causal or self._hold_option == 0:
            return None
        if self._hold_option is None:  # auto
            rf = self.receptive_field_frames
            return None if rf is None else max(1, rf // 2)
        return self._hold_option

    @property
    def trained(self) -> bool:
        return self._meta is not None

    def weights_hash(self) -> str | None:
        return self._hash

    @property
    def weights_name(self) -> str | None:
        """The catalog name of the weights in use (``paper``, ``moving``): the shipped file of this
        tracker with the same SHA-256, wherever it was read from; None for other files and random weights."""
        return catalog.name_of(self.model_name, self._resolution, self._hash)

    @property
    def plain_weights_name(self) -> str | None:
        """The name of this tracker's plain weights (``<model>[-<res>].safetensors``): a run with
        them carries no weights option (:func:`doabench.trackers.registry.canonical_tracker`)."""
        return catalog.plain_name(self.model_name, self._resolution)

    @classmethod
    def shipped_weights(cls) -> list[dict[str, Any]]:
        """The catalog's entries of this model (every resolution), default first per tracker id."""
        out = []
        for e in catalog.all_named():
            if e.tracker.partition(":")[0] != cls.model_name:
                continue
            res = parse_resolution(e.tracker.partition(":")[2]) if ":" in e.tracker else None
            out.append({"tracker": e.tracker, "name": e.name, "default": catalog.default_name(cls.model_name, res) == e.name,
                        "file": e.file, "sha256": e.sha256, "task": e.task, "headline": dict(e.headline)})
        return sorted(out, key=lambda d: (d["tracker"], not d["default"], d["name"]))

    @classmethod
    def named_weights(cls, spec: str | None) -> dict[str, str]:
        """``{sha256: name}`` of the shipped weights of this tracker at ``spec`` (its resolution),
        for reading a name back from a results file's hash."""
        res = parse_resolution(spec) if cls.uses_resolution and spec else None
        return {e.sha256: name for name, e in catalog.named_weights(cls.model_name, res).items() if e.sha256}

    def parameter_count(self) -> int:
        from .layers import count_parameters

        return count_parameters(self.model)

    def describe(self) -> dict[str, Any]:
        from .layers import receptive_field_seconds

        d = super().describe()
        rf = self.receptive_field_frames
        fs = self.frame_spec
        d.update(
            model=self.model_name,
            trained=self.trained,
            weights=None if self._weights_path is None else str(self._weights_path),
            device=str(self.device),
            array=self._array.name,
            receptive_field_s=None if rf is None else round(receptive_field_seconds(rf, fs.window, fs.hop, fs.fs), 3),
            training=(self._meta or {}).get("training"),
            trained_features=(self._meta or {}).get("features"),
            hold_frames=self.hold_frames,
        )
        return d

    @property
    def trained_delays(self) -> str | None:
        """The SRP delay mode of the maps its weights were trained on (their metadata), or None
        for random weights."""
        if self._meta is None:
            return None
        return (self._meta.get("features") or {}).get("delay_mode") or "nearest"

    def save_weights(self, path: str | Path, metadata: Mapping[str, Any] | None = None) -> Path:
        """Write the network to a weight file (training protocol: ``save_weights(path, metadata)``).

        The file's metadata is built here (model, resolution, array positions, frames, feature
        kinds, parameter count, version, date); from ``metadata`` it takes ``training`` (the recipe
        summary), ``feature_settings.delays`` (SRP delay mode, default ``nearest``) and ``array``
        (the training array's name or file, whose positions are recorded), and keeps its other
        keys as they are. The keys built here win over the caller's.
        """
        extra = dict(metadata or {})
        training = extra.pop("training", None)
        delays = (extra.get("feature_settings") or {}).get("delays", extra.pop("delay_mode", "nearest"))
        array = self._array
        if isinstance(extra.get("array"), str):
            array = doabench.get_array(extra["array"])
            self.check_array_fits(array)
        config = {"resolution": resolution_text(self._resolution)} if self.uses_resolution else {}
        meta = make_metadata(self.model_name, self.model, array=array, frame_spec=self.frame_spec,
                             features=self.features, resolution=self._resolution, delay_mode=delays,
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

    # -- running --------------------------------------------------------------------------------------
    def reset(self, array: doabench.MicArray, **context: Any) -> None:
        frame_spec = context.get("frame_spec")
        if frame_spec is not None and (frame_spec.window, frame_spec.hop, frame_spec.fs) != (
                self.frame_spec.window, self.frame_spec.hop, self.frame_spec.fs):
            raise ConfigError(f"tracker {self.name!r} needs frames {self.frame_spec.to_dict()}, "
                              f"the environment gives {frame_spec.to_dict()}")
        if self._meta is not None:
            check_array(self._meta, array, f"tracker {self.name!r}: weights file {self._weights_path.name}")
        self.check_array_fits(array)
        if self._runner is not None:
            self._runner.reset()
        self._last = _INITIAL_DIRECTION.copy()
        self._silent_run, self._held = _NEVER_VOICED, None

    def check_array_fits(self, array: doabench.MicArray) -> None:
        """Raise ConfigError when the episode's array cannot feed the model's input layer."""

    def frame_input(self, observation: Mapping[str, np.ndarray]) -> torch.Tensor:
        """One observation -> the model's input frame ``(1, *frame_shape)``: the episode path
        with one frame, so both paths build identical inputs."""
        x = self.network_input({k: self._tensor(observation[k])[None, None] for k in self.features})
        return x[:, :, 0]  # drop the time axis (axis 2 in every model)

    def episode_input(self, episode: Mapping[str, np.ndarray]) -> torch.Tensor:
        """A whole episode ``{kind: (frames, ...)}`` -> the network's input with batch 1."""
        return self.network_input({k: self._tensor(episode[k])[None] for k in self.features})

    def step(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        if self._runner is None:
            return super().step(observation)  # offline model: the base class says to use track()
        y = self._runner.step(self.frame_input(observation))[0]
        direction = self.direction_from_output(y.detach().double().cpu().numpy())
        hold = self.hold_frames
        if hold is None:
            return direction
        if bool(np.asarray(observation.get("vad", True))):
            self._silent_run = 0
        elif self._silent_run < _NEVER_VOICED:
            self._silent_run += 1
        if self._silent_run >= _NEVER_VOICED:  # no voice yet: nothing to hold
            return direction
        if self._silent_run < hold:  # voice within the last `hold` frames
            self._held = direction
            return direction
        return self._held.copy()

    def track(self, episode: Mapping[str, np.ndarray]) -> np.ndarray:
        import torch

        n = len(episode["vad"])
        if n == 0:
            return np.zeros((0, 3))
        x = self.episode_input(episode)
        with torch.inference_mode():
            if self.causal:
                state, parts = self.model.init_state(), []
                for chunk in torch.split(x, _TRACK_CHUNK, dim=2):
                    y, state = self.model.stream_chunk(chunk, state)
                    parts.append(y)
                y = torch.cat(parts, dim=1)
            else:
                y = self.model(x)
        self._last = _INITIAL_DIRECTION.copy()
        directions = np.stack([self.direction_from_output(v) for v in y[0].to("cpu", torch.float64).numpy()])
        hold = self.hold_frames
        return directions if hold is None else doabench.hold_in_silences(directions, np.asarray(episode["vad"], bool), hold)

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


@doabench.register_tracker("cross3d")
class Cross3DTracker(NeuralTracker):
    """Cross3D (paper IV-B) on SRP-PHAT maps and their maxima; spec = map resolution."""

    model_name = "cross3d"
    features = ("srp", "srp_max")
    uses_resolution = True

    def _default_resolution(self) -> tuple[int, int]:
        """The catalog's default resolution for ``cross3d`` (its default rule), else 8x16."""
        return catalog.default_resolution(self.model_name) or (8, 16)

    def build_model(self) -> nn.Module:
        from .cross3d import Cross3D

        return Cross3D(*self._resolution)

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        srp = features["srp"]  # (B, T, n_theta, n_phi)
        if tuple(srp.shape[2:]) != self._resolution:
            raise ConfigError(f"tracker {self.name!r} expects {resolution_text(self._resolution)} maps, "
                              f"got {'x'.join(map(str, srp.shape[2:]))}")
        from .cross3d import cross3d_input

        x = cross3d_input(srp, features["srp_max"])  # (B, T, 3, n_theta, n_phi)
        return x.transpose(1, 2)


@doabench.register_tracker("max-cnn1d")
class MaxCnn1dTracker(NeuralTracker):
    """1D CNN over the normalised coordinates of each map's maximum (paper V-A); spec = resolution."""

    model_name = "max-cnn1d"
    features = ("srp_max",)
    uses_resolution = True

    def _default_resolution(self) -> tuple[int, int]:
        return (64, 128)

    def build_model(self) -> nn.Module:
        from .cnn1d import CausalCnn1d

        return CausalCnn1d(2)

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return features["srp_max"].transpose(1, 2)  # (B, T, 2) -> (B, 2, T)


def _n_lags(array: doabench.MicArray, fs: int) -> int:
    return 2 * array.max_lag(fs) + 1


@doabench.register_tracker("gcc-cnn1d")
class GccCnn1dTracker(NeuralTracker):
    """1D CNN over the GCC-PHAT values within the physical lag range (paper V-A)."""

    model_name = "gcc-cnn1d"
    features = ("gcc",)

    def build_model(self) -> nn.Module:
        from .cnn1d import CausalCnn1d

        self._gcc_shape = (len(self._array.pairs), _n_lags(self._array, self.frame_spec.fs))
        return CausalCnn1d(self._gcc_shape[0] * self._gcc_shape[1])

    def check_array_fits(self, array: doabench.MicArray) -> None:
        shape = (len(array.pairs), _n_lags(array, self.frame_spec.fs))
        if shape != self._gcc_shape:
            raise ConfigError(f"tracker {self.name!r} was built for array {self._array.name!r} "
                              f"({self._gcc_shape[0]} pairs x {self._gcc_shape[1]} lags); array {array.name!r} "
                              f"gives {shape[0]} x {shape[1]}: pass --tracker-opt array=NAME_OR_FILE")

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        gcc = features["gcc"]  # (B, T, n_pairs, n_lags)
        if tuple(gcc.shape[2:]) != self._gcc_shape:
            raise ConfigError(f"tracker {self.name!r} expects gcc of shape {self._gcc_shape}, "
                              f"got {tuple(gcc.shape[2:])}")
        return gcc.flatten(2).transpose(1, 2)  # (B, n_pairs * n_lags, T), pair-major


class _SpectrogramTracker(NeuralTracker):
    features = ("spectrogram",)

    def _spec_shape(self) -> tuple[int, int]:
        return (2 * self._array.n_mics, self.frame_spec.window // 2)

    def check_array_fits(self, array: doabench.MicArray) -> None:
        if 2 * array.n_mics != self._spec_shape()[0]:
            raise ConfigError(f"tracker {self.name!r} was built for {self._array.n_mics} microphones "
                              f"(array {self._array.name!r}); array {array.name!r} has {array.n_mics}: "
                              "pass --tracker-opt array=NAME_OR_FILE")

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        s = features["spectrogram"]  # (B, T, 2 n_mics, bins)
        if tuple(s.shape[2:]) != self._spec_shape():
            raise ConfigError(f"tracker {self.name!r} expects spectrograms of shape {self._spec_shape()}, "
                              f"got {tuple(s.shape[2:])}")
        return s.transpose(1, 2)  # (B, 2 n_mics, T, bins)


@doabench.register_tracker("spec-cnn2d")
class SpecCnn2dTracker(_SpectrogramTracker):
    """Causal 2D CNN over magnitude and phase spectrograms, K = 4096 (paper V-A)."""

    model_name = "spec-cnn2d"

    def build_model(self) -> nn.Module:
        from .cnn2d import SpecCnn2d

        channels, bins = self._spec_shape()
        return SpecCnn2d(channels, bins)


@doabench.register_tracker("seldnet")
class SeldnetTracker(_SpectrogramTracker):
    """SELDnet DOA-branch replica (paper V-A): offline, bidirectional GRUs, K = 512 windows.

    Frames: 512-sample windows with doabench's 3/4-window hop (384 samples, 24 ms), so its
    estimates are on a finer time grid than the K = 4096 models; the scores compare each tracker
    with the truth of its own frames.
    """

    model_name = "seldnet"
    causal = False
    default_frame_spec = doabench.FrameSpec(window=512)

    def build_model(self) -> nn.Module:
        from .seldnet import Seldnet

        channels, bins = self._spec_shape()
        return Seldnet(channels, bins)
