"""What the trainer needs from a learned tracker (implemented by the classes in ``baselines/``).

doabench never imports a model package: ``doabench train --tracker cross3d:8x16`` builds the
tracker with :func:`doabench.make_tracker` and trains it through this small protocol::

    tracker.observation_spec    # what it reads, one ObservationSpec (kinds with their settings, frames)
    tracker.features        # its kinds' names, e.g. ("srp", "srp_max") (a doabench.Tracker derives
    tracker.resolution      # these three from observation_spec: the SRP grid or None,
    tracker.frame_spec      # and the frames)
    tracker.network         # the torch.nn.Module being trained
    tracker.network_input(features)   # dict of (B, T, ...) tensors -> the network's input tensor
    tracker.network(x)      # -> (B, T, 3) direction vectors (not necessarily unit length)
    tracker.save_weights(path, metadata)   # safetensors file; metadata["training"] is the
                                           # training record (see doabench.training.export)

``tracker.observation_spec`` is read through :func:`training_observations` and nowhere else: the
trainer computes, and the weights file records, exactly that value. A network reading a kind of
its own registers the kind (:func:`doabench.features.register_feature_kind`), so that its spec
can name it, even when the Trainer is given its own feature function.

Optional (read through :func:`training_defaults`, nowhere else):

* ``tracker.training_defaults`` (dict) with recipe overrides the paper gives for that model, e.g.
  ``{"t60": (0.0, 0.3)}`` for its spectrogram models (section V-A: the baselines' spectrogram
  trackers declare it).
"""
from __future__ import annotations

from typing import Any, Mapping, Protocol, Sequence, runtime_checkable

import torch

from doabench.errors import ConfigError
from doabench.features.spec import ObservationSpec
from doabench.trackers.base import observations_of
from doabench.framing import FrameSpec

REQUIRED_ATTRIBUTES = ("network", "network_input", "save_weights", "observation_spec", "features", "frame_spec")


@runtime_checkable
class TrainableTracker(Protocol):
    """A tracker with a trainable network (see the module docstring)."""

    observation_spec: ObservationSpec

    @property
    def features(self) -> Sequence[str]: ...

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


def training_observations(tracker: Any) -> ObservationSpec:
    """What a learned tracker trains on, as one value: the :attr:`~doabench.Tracker.observation_spec`
    it declares, as it is; a one-line ConfigError when it declares none."""
    return observations_of(tracker)


def training_defaults(tracker: Any) -> dict[str, Any]:
    """Recipe overrides the tracker declares (``training_defaults``), else none."""
    own = getattr(tracker, "training_defaults", None)
    return dict(own) if isinstance(own, Mapping) else {}
