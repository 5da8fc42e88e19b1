"""What the trainer needs from a learned tracker (implemented by the classes in ``baselines/``).

doabench never imports a model package: ``doabench train --tracker cross3d:8x16`` builds the
tracker with :func:`doabench.make_tracker` and trains it through this small protocol::

    tracker.features        # observation keys it reads, e.g. ("srp", "srp_max")
    tracker.resolution      # (n_theta, n_phi) of the SRP maps, or None
    tracker.frame_spec      # FrameSpec of its features (window, hop, fs)
    tracker.network         # the torch.nn.Module being trained
    tracker.network_input(features)   # dict of (B, T, ...) tensors -> the network's input tensor
    tracker.network(x)      # -> (B, T, 3) direction vectors (not necessarily unit length)
    tracker.save_weights(path, metadata)   # safetensors file; metadata["training"] is the
                                           # training record (see doabench.training.export)

Optional (read through :func:`training_observations` and :func:`training_defaults`, nowhere else):

* ``tracker.observation_spec``: what it reads, as one :class:`~doabench.features.spec.ObservationSpec`
  (every :class:`doabench.Tracker` declares it: its features, resolution, frames, the SRP delays of
  its weights, its spectrogram's own frames); a trainable network that is not a Tracker reads its
  ``features`` on nearest delays;
* ``tracker.training_defaults`` (dict) with recipe overrides the paper gives for that model, e.g.
  ``{"t60": (0.0, 0.3)}`` for its spectrogram models (section V-A: the baselines' spectrogram
  trackers declare it).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Mapping, Protocol, Sequence, runtime_checkable

import torch

from doabench.errors import ConfigError
from doabench.features.spec import ObservationSpec
from doabench.framing import FrameSpec

REQUIRED_ATTRIBUTES = ("network", "network_input", "save_weights", "features", "frame_spec")


@runtime_checkable
class TrainableTracker(Protocol):
    """A tracker with a trainable network (see the module docstring)."""

    features: Sequence[str]

    @property
    def resolution(self) -> tuple[int, int] | None: ...

    @property
    def frame_spec(self) -> FrameSpec: ...

    @property
    def network(self) -> torch.nn.Module: ...

    def network_input(self, features: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """Features ``{kind: (B, T, ...)}`` (plus ``vad`` ``(B, T)``) -> the network's input."""
        ...

    def save_weights(self, path: Any, metadata: Mapping[str, Any]) -> Any:
        """Write the network's weights and ``metadata`` (JSON-able) to ``path``."""
        ...


def check_trainable(tracker: Any, name: str) -> TrainableTracker:
    """Return ``tracker`` if it implements the protocol, else raise a one-line ConfigError."""
    missing = [a for a in REQUIRED_ATTRIBUTES if not hasattr(tracker, a)]
    network = None if missing else tracker.network
    if missing or not isinstance(network, torch.nn.Module):
        raise ConfigError(f"tracker {name!r} is not a learned tracker (it has no trainable network); "
                          "`doabench train` needs one such as cross3d:8x16 or gcc-cnn1d")
    if not any(p.requires_grad for p in network.parameters()):
        raise ConfigError(f"tracker {name!r} has no trainable parameters")
    return tracker


def training_observations(tracker: Any, frame_spec: FrameSpec) -> ObservationSpec:
    """What a learned tracker trains on, as one value: the :attr:`~doabench.Tracker.observation_spec`
    it declares, on the run's ``frame_spec``."""
    declared = getattr(tracker, "observation_spec", None)
    if not isinstance(declared, ObservationSpec):
        declared = ObservationSpec.of(tuple(tracker.features), tracker.resolution, frame_spec)
    return replace(declared, frame_spec=frame_spec)


def training_defaults(tracker: Any) -> dict[str, Any]:
    """Recipe overrides the tracker declares (``training_defaults``), else none."""
    own = getattr(tracker, "training_defaults", None)
    return dict(own) if isinstance(own, Mapping) else {}
