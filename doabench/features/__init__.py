"""Feature extraction: SRP-PHAT maps, GCC-PHAT, spectrograms (offline and streaming).

``functional`` holds the pure torch functions; the classes precompute tables once. Conventions and
shapes: docs/features.md. :class:`ObservationPlan` (``plan``) is the one pipeline from a
recording to per-frame observations; ``kinds`` the registered observation kinds and their names;
``spec`` the :class:`ObservationSpec` a tracker declares (what it reads).

The names are loaded on first use (PEP 562): ``kinds`` and the plan's spaces need no torch, so
``import doabench.features.kinds`` (the dataset schema, the environment) does not import it.
"""
from __future__ import annotations

import importlib
from typing import Any

# public name -> the submodule that defines it
_EXPORTS = {
    "FeatureExtractor": "transforms",
    "SRPPHAT": "transforms",
    "GCCPHAT": "transforms",
    "Spectrogram": "transforms",
    "StreamingFeatureExtractor": "streaming",
    "ObservationPlan": "plan",
    "ObservationSpec": "spec",
    "STFTContext": "context",
    "FeatureKind": "kinds",
    "FrameContext": "kinds",
    "register_feature_kind": "kinds",
    "OBSERVATION_KINDS": "kinds",
    "stft_frames": "functional",
    "gcc_phat": "functional",
    "srp_phat": "functional",
    "normalize_maps": "functional",
    "map_maxima": "functional",
    "map_argmax_directions": "functional",
    "spectrogram_features": "functional",
    "zero_silent": "functional",
}

__all__ = ["functional", *_EXPORTS]


def __getattr__(name: str) -> Any:
    if name == "functional":
        return importlib.import_module(f"{__name__}.functional")
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
