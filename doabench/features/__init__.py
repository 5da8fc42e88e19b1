"""Feature extraction: SRP-PHAT maps, GCC-PHAT, spectrograms (offline and streaming).

``functional`` holds the pure torch functions; the classes precompute tables once. Conventions and
shapes: docs/features.md.
"""
from doabench.features import functional
from doabench.features.functional import (
    gcc_phat,
    map_argmax_directions,
    map_maxima,
    normalize_maps,
    spectrogram_features,
    srp_phat,
    stft_frames,
    zero_silent,
)
from doabench.features.streaming import StreamingFeatureExtractor
from doabench.features.transforms import (
    GCCPHAT,
    KINDS,
    SRPPHAT,
    FeatureExtractor,
    Spectrogram,
)

__all__ = [
    "functional",
    "FeatureExtractor",
    "StreamingFeatureExtractor",
    "SRPPHAT",
    "GCCPHAT",
    "Spectrogram",
    "KINDS",
    "stft_frames",
    "gcc_phat",
    "srp_phat",
    "normalize_maps",
    "map_maxima",
    "map_argmax_directions",
    "spectrogram_features",
    "zero_silent",
]
