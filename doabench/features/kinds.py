"""The observation kinds and their names: the one list every layer derives its own from.

Kept apart from :mod:`doabench.features.plan` (which computes them) so that the transforms, the
dataset schema and the environment can read the lists without importing torch or the plan, and
without an import cycle (the plan imports the transforms, the transforms import these lists).

Names: an srp or srp_max item carries its grid, ``srp:16x32`` / ``srp_max:16x32``; the other
kinds are named by the kind alone (``gcc``, ``spectrogram``, ``audio``). In a dataset file an item
``srp:16x32`` lies at ``features/srp_16x32``, ``gcc`` at ``features/gcc`` and ``audio`` (the raw
recording) at ``audio`` (docs/hdf5-schema.md).
"""
from __future__ import annotations

from typing import Iterable, Sequence

from doabench.errors import ConfigError
from doabench.geometry import parse_resolution

#: Every kind an environment observation may hold, in the order error messages list them.
OBSERVATION_KINDS = ("srp", "srp_max", "gcc", "spectrogram", "audio")
#: The kinds :class:`~doabench.features.FeatureExtractor` computes, in its output order.
EXTRACTOR_KINDS = ("srp", "srp_max", "gcc", "spectrogram")
#: Kinds that are the recording's own samples, framed, not computed by the extractor.
FRAMED_KINDS = tuple(k for k in OBSERVATION_KINDS if k not in EXTRACTOR_KINDS)
#: Kinds computed on an SRP grid: their names carry the grid's resolution.
MAP_KINDS = ("srp", "srp_max")
#: Maps that a dataset's ``--float16`` stores as half precision (srp_max and audio stay float32:
#: srp_max holds two normalised angles, audio the recording itself).
HALF_KINDS = ("srp", "gcc", "spectrogram")
#: What ``make-dataset --features`` requests, in the files' canonical order; an ``srp`` request
#: stores its ``srp_max`` too, so srp_max is not requested on its own.
DATASET_KINDS = tuple(k for k in OBSERVATION_KINDS if k != "srp_max")
#: The SRP grid when nothing asks for another one.
DEFAULT_RESOLUTION = (16, 32)
#: Where the dataset file keeps computed features (the raw ``audio`` lies beside them).
FEATURES_GROUP = "features"


def check_kinds(kinds: Iterable[str]) -> tuple[str, ...]:
    """``kinds`` as a tuple, or the environment's ConfigError naming the unknown ones."""
    kinds = tuple(kinds)
    unknown = sorted(set(kinds) - set(OBSERVATION_KINDS))
    if unknown:
        raise ConfigError(f"unknown feature kind(s) {unknown}; choose from {', '.join(OBSERVATION_KINDS)}")
    return kinds


def resolution_text(resolution: Sequence[int]) -> str:
    """``(16, 32)`` -> ``"16x32"``."""
    return f"{resolution[0]}x{resolution[1]}"


def item_name(kind: str, resolution: Sequence[int] | str | None = None) -> str:
    """Canonical name of ``kind`` on the grid ``resolution``: ``srp:16x32``, ``gcc``, ...

    ``resolution`` None leaves an srp name bare (``srp``: a reader resolves it to the only stored
    grid); the other kinds ignore it.
    """
    if kind in MAP_KINDS and resolution:
        return f"{kind}:{resolution if isinstance(resolution, str) else resolution_text(resolution)}"
    return kind


def item_names(kinds: Iterable[str], resolution: Sequence[int] | str | None = None) -> list[str]:
    """:func:`item_name` of each kind, in order."""
    return [item_name(k, resolution) for k in kinds]


def parse_item_name(name: str) -> tuple[str, tuple[int, int] | None]:
    """``"srp:16x32"`` -> ``("srp", (16, 32))``, ``"gcc"`` -> ``("gcc", None)``, ``"srp"`` -> ``("srp", None)``.

    The resolution is parsed by :func:`doabench.geometry.parse_resolution` (its errors); a kind
    outside :data:`OBSERVATION_KINDS`, or a resolution on a kind without a grid, is a ConfigError.
    """
    kind, sep, res = str(name).partition(":")
    check_kinds([kind])
    if not sep:
        return kind, None
    if kind not in MAP_KINDS:
        raise ConfigError(f"feature {kind!r} takes no resolution, got {name!r}")
    return kind, parse_resolution(res)


def storage_path(name: str) -> str:
    """Path of item ``name`` inside a dataset episode group: ``srp:16x32`` -> ``features/srp_16x32``,
    ``gcc`` -> ``features/gcc``, ``audio`` -> ``audio``."""
    kind, _, res = str(name).partition(":")
    if kind in MAP_KINDS:
        return f"{FEATURES_GROUP}/{kind}_{res}"
    return kind if kind in FRAMED_KINDS else f"{FEATURES_GROUP}/{kind}"  # raw samples, not a feature
