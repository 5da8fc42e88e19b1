"""Weight files: safetensors (tensors only, loading never executes code) plus JSON metadata.

The metadata, stored as JSON under the ``doabench`` key of the safetensors header, records what
the weights were trained for, and loading checks it against what the caller is about to use::

    {"format": "doabench-weights/2", "model": "cross3d", "model_config": {"resolution": "16x32"},
     "array": {"name": "nao", "positions": [[x, y, z], ...]},
     "observations": {...what the network reads: doabench.ObservationSpec.to_dict()...},
     "training": {...free-form recipe summary...}, "parameters": 1693988,
     "doabench_version": "0.1.0", "date": "2026-01-01T00:00:00+00:00"}

Metadata of an older format is read as the current one (``doabench.upgrade_weights_metadata``;
``doabench migrate FILE`` writes such a file's upgraded copy), so every check below reads the
stored spec back with ``ObservationSpec.from_dict``.

Shipped weights are the files of ``baselines/weights/`` (:data:`SHIPPED_DIR`); which of them a
tracker runs, by name or by default, is :mod:`.catalog`'s answer, which builds on this module and
which this module never imports. ``baselines/weights/SHA256SUMS`` (``sha256sum`` format) lists the
SHA-256 of every shipped file; a shipped file is loaded only when it matches, and
:func:`save_weights` into that folder updates the list. Every loaded tensor must be finite and of
a plausible magnitude (at most ``MAX_ABS_WEIGHT``).
"""
from __future__ import annotations

import datetime
import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

import doabench
from doabench.errors import ConfigError, DoabenchError, InputError, NotFoundError
from doabench.trackers import parse_resolution, resolution_text  # noqa: F401  (the trackers import both from here)

if TYPE_CHECKING:  # torch is imported where tensors are handled: `doabench list trackers` needs none
    import torch
    from torch import nn

FORMAT = "doabench-weights/2"
METADATA_KEY = "doabench"
SHIPPED_DIR = Path(__file__).resolve().parent / "weights"
#: largest microphone displacement (m) between the weights' array and the one in use
ARRAY_TOLERANCE_M = 0.005
#: the SHA-256 list of the shipped weight files, in SHIPPED_DIR
MANIFEST_NAME = "SHA256SUMS"
#: no trained weight is anywhere near this (the shipped ones stay below 1); larger means a broken file
MAX_ABS_WEIGHT = 1e6


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of a file (the shipped-weights manifest and the trackers' ``weights_hash``).
    Written here rather than imported: this package uses doabench's public API only, and file
    hashing is not part of it."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()




def make_metadata(
    model_name: str,
    model: nn.Module,
    *,
    array: "doabench.MicArray",
    observations: Mapping[str, Any],
    model_config: Mapping[str, Any] | None = None,
    training: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The metadata dict of a weight file (see the module docstring). ``observations``: what the
    network reads, as ``doabench.ObservationSpec.to_dict()`` writes it (the one stored form that
    results and ONNX files hold too)."""
    return {
        "format": FORMAT,
        "model": model_name,
        "model_config": dict(model_config or {}),
        "array": {"name": array.name, "positions": np.asarray(array.positions, dtype=float).round(6).tolist()},
        "observations": dict(observations),
        "training": dict(training or {}),
        "parameters": sum(p.numel() for p in model.parameters()),
        "doabench_version": doabench.__version__,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }


def save_weights(path: str | Path, model: nn.Module, metadata: Mapping[str, Any]) -> Path:
    """Write ``model``'s state dict (parameters and buffers, float tensors on CPU) and metadata."""
    from safetensors.torch import save_file

    path = Path(path)
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in model.state_dict().items()}
    # doabench's output rule: atomic for a file (a crash never leaves a half-written weight file
    # under the real name), written through for a stream, a symbolic link's target kept a link.
    with doabench.atomic_path(path, suffix=".safetensors") as tmp:
        save_file(tensors, str(tmp), metadata=header_metadata(metadata))
    if _is_shipped(path):
        update_manifest(path)
    return path


def header_metadata(metadata: Mapping[str, Any]) -> dict[str, str]:
    """The safetensors header entries of a weights file with ``metadata``: the metadata as JSON
    under :data:`METADATA_KEY`, and the model's name beside it."""
    return {METADATA_KEY: json.dumps(dict(metadata), sort_keys=True), "model": str(metadata.get("model"))}


def _is_shipped(path: str | Path) -> bool:
    """A file of the shipped folder: named in it (a link there included), or a link to a file in it."""
    here = Path(SHIPPED_DIR).resolve()
    path = Path(path)
    return path.absolute().parent.resolve() == here or path.resolve().parent == here


def read_manifest(folder: str | Path | None = None) -> dict[str, str]:
    """``{file name: sha256}`` of the shipped weight files (empty when there is no manifest)."""
    path = Path(folder or SHIPPED_DIR) / MANIFEST_NAME
    if not path.is_file():
        return {}
    out = {}
    for line in path.read_text().splitlines():
        digest, sep, name = line.strip().partition("  ")
        if sep and len(digest) == 64:
            out[name.lstrip("*")] = digest.lower()
    return out


def update_manifest(path: str | Path) -> None:
    """Record the SHA-256 of ``path`` (a shipped weight file) in its folder's manifest."""
    path = Path(path)
    entries = read_manifest(path.parent)
    entries[path.name] = sha256_file(path)
    text = "".join(f"{digest}  {name}\n" for name, digest in sorted(entries.items()))
    with doabench.atomic_path(path.parent / MANIFEST_NAME) as tmp:
        tmp.write_text(text)


def verify_shipped(path: str | Path) -> None:
    """A shipped weight file must match its SHA-256 in the manifest (flipped bytes, a truncated or
    replaced file are refused), however it is reached: by its name in the shipped folder, which
    must then be a regular file there and not a link out of it, or through a link elsewhere to
    such a file."""
    path = Path(path)
    folder = Path(SHIPPED_DIR)
    if path.absolute().parent.resolve() == folder.resolve():  # named in the shipped folder
        if path.is_symlink():
            raise InputError(f"weights file {path} is a symbolic link; shipped weights are regular files in {folder}")
        name = path.name
    else:  # a link elsewhere to a shipped file
        name = path.resolve().name
    if not path.is_file():
        raise NotFoundError(f"weights file {path} does not exist") if not path.exists() else InputError(
            f"weights file {path} is not a regular file")
    want = read_manifest(folder).get(name)
    if want is None:
        raise InputError(f"weights file {path} is not listed in {folder / MANIFEST_NAME}; shipped weights "
                         "are loaded only when their SHA-256 is recorded there")
    have = sha256_file(path)
    if have != want:
        raise InputError(f"weights file {path} is damaged: its SHA-256 {have[:12]}... does not match "
                         f"{want[:12]}... in {MANIFEST_NAME}; reinstall it")


def check_tensors(state: Mapping[str, torch.Tensor], path: str | Path) -> None:
    """Every floating-point tensor must be finite and at most MAX_ABS_WEIGHT in magnitude."""
    for name, t in state.items():
        if not t.is_floating_point() or t.numel() == 0:
            continue
        if not bool(t.isfinite().all()):
            raise InputError(f"weights file {Path(path).name}: tensor {name!r} holds NaN or infinite values; "
                             "the file is damaged")
        worst = float(t.abs().max())
        if worst > MAX_ABS_WEIGHT:
            raise InputError(f"weights file {Path(path).name}: tensor {name!r} holds a value of magnitude "
                             f"{worst:.3g} (more than {MAX_ABS_WEIGHT:g}); the file is damaged")


#: the metadata key of a `doabench train` checkpoint (doabench.training.checkpoint, which this
#: package may not import): such a file holds a whole run state, not a model's weights
CHECKPOINT_KEY = "doabench_state"
CHECKPOINT_NAME = "checkpoint.safetensors"


def training_run_hint(path: str | Path, tracker: str | None = None) -> str:
    """The one-line error for a training run folder or its checkpoint given as weights: export it."""
    path = Path(path)
    run = path if path.is_dir() else path.parent
    name = f"{run.resolve().name or 'model'}.safetensors"
    return (f"weights={path} is a `doabench train` {'run folder' if path.is_dir() else 'checkpoint'}, not a "
            f"weights file; export it first with `doabench train --tracker {tracker or 'ID'} --out {run} --export "
            f"{name}` and pass --tracker-opt weights={name}")


def _checkpoint_tracker(path: Path) -> str | None:
    """The tracker id a training checkpoint records (None when unreadable)."""
    from safetensors import safe_open

    try:
        with safe_open(str(path), framework="pt", device="cpu") as f:
            return json.loads((f.metadata() or {})[CHECKPOINT_KEY]).get("tracker")
    except Exception:  # any damage: the hint goes without the id
        return None


def _open(path: str | Path):
    from safetensors import safe_open

    path = Path(path)
    if path.is_dir():
        checkpoint = path / CHECKPOINT_NAME
        if checkpoint.is_file():
            raise InputError(training_run_hint(path, _checkpoint_tracker(checkpoint)))
        raise InputError(f"weights file {path} is a folder; give a .safetensors weights file")
    if not path.is_file():
        if path.exists():  # a FIFO, a device (/dev/zero), a socket
            raise InputError(f"weights file {path} is not a regular file; give a .safetensors weights file")
        raise NotFoundError(f"weights file {path} does not exist")
    try:
        return safe_open(str(path), framework="pt", device="cpu")
    except Exception as exc:  # any parse failure is the user's file
        raise InputError(f"weights file {path}: not a safetensors file ({type(exc).__name__}: {exc})") from None


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The doabench metadata of a weight file in the current format (an older format read as it,
    ``doabench.upgrade_weights_metadata``); InputError if it has none or it cannot be read."""
    with _open(path) as f:
        header = f.metadata() or {}
    raw = header.get(METADATA_KEY)
    if raw is None and CHECKPOINT_KEY in header:
        raise InputError(training_run_hint(path, _checkpoint_tracker(Path(path))))
    if raw is None:
        raise InputError(f"weights file {path}: no doabench metadata (was it written by save_weights, or exported "
                         "with `doabench train --out RUN --export FILE`?)")
    try:
        meta = json.loads(raw)
    except json.JSONDecodeError:
        raise InputError(f"weights file {path}: metadata is not valid JSON") from None
    try:
        return doabench.upgrade_weights_metadata(meta)
    except InputError as exc:
        raise InputError(f"weights file {path}: {exc}") from None


def check_metadata(
    meta: Mapping[str, Any],
    path: str | Path,
    *,
    model_name: str | None = None,
    resolution: tuple[int, int] | None = None,
    array: "doabench.MicArray | None" = None,
    frame_spec: "doabench.FrameSpec | None" = None,
    delay_mode: str | None = None,
    observations: "doabench.ObservationSpec | None" = None,
) -> None:
    """Raise ConfigError naming the first thing the weights were not trained for. What they read
    is their stored spec (``ObservationSpec.from_dict`` of ``observations``), compared whole with
    ``observations`` (a tracker's ``observation_spec``) or in part: its grid with ``resolution``,
    its frames with ``frame_spec``, its SRP delays with ``delay_mode``."""
    where = f"weights file {Path(path).name}"
    if model_name is not None and meta.get("model") != model_name:
        raise ConfigError(f"{where} holds a {meta.get('model')!r} model, not {model_name!r}")
    if array is not None:
        check_array(meta, array, where)
    if resolution is observations is frame_spec is delay_mode is None:
        return
    stored = stored_observations(meta, where)
    if observations is not None and stored != observations:
        raise ConfigError(f"{where} was trained on the observations {stored.to_dict()}, not {observations.to_dict()}")
    if resolution is not None and stored.resolution != tuple(resolution):
        had = resolution_text(stored.resolution) if stored.resolution else "no"
        raise ConfigError(f"{where} was trained on {had} maps, not {resolution_text(resolution)}")
    if frame_spec is not None and stored.frame_spec != frame_spec:
        raise ConfigError(f"{where} was trained with frames {stored.frame_spec.to_dict()}, not {frame_spec.to_dict()}")
    if delay_mode is not None and stored.delays not in (None, delay_mode):
        raise ConfigError(f"{where} was trained with {stored.delays!r} SRP delays, not {delay_mode!r}")


def stored_observations(meta: Mapping[str, Any], where: str) -> doabench.ObservationSpec:
    """The spec a weights file's metadata stores (``ObservationSpec.from_dict``); a one-line
    InputError naming ``where`` when it holds none it can read."""
    stored = meta.get("observations")
    if not isinstance(stored, Mapping):
        raise InputError(f"{where}: its metadata stores no observations")
    try:
        return doabench.ObservationSpec.from_dict(stored)
    except DoabenchError as exc:
        raise InputError(f"{where}: its stored observations cannot be read ({exc})") from None


def check_array(meta: Mapping[str, Any], array: "doabench.MicArray", where: str) -> None:
    """The array in use must have the trained array's microphones within ARRAY_TOLERANCE_M."""
    trained = np.asarray(meta.get("array", {}).get("positions", []), dtype=float)
    name = meta.get("array", {}).get("name")
    pos = np.asarray(array.positions, dtype=float)
    if trained.shape != pos.shape:
        raise ConfigError(f"{where} was trained for array {name!r} with {len(trained)} microphones; "
                          f"array {array.name!r} has {len(pos)}")
    worst = float(np.abs(trained - pos).max()) if pos.size else 0.0
    if worst > ARRAY_TOLERANCE_M:
        raise ConfigError(f"{where} was trained for array {name!r}; array {array.name!r} differs by up to "
                          f"{worst * 1000:.1f} mm (tolerance {ARRAY_TOLERANCE_M * 1000:.0f} mm)")


def load_weights(path: str | Path, **expect: Any) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Read a weight file and check its metadata (keywords as :func:`check_metadata`).

    Returns ``(state_dict, metadata)``; tensors are on the CPU.
    """
    if _is_shipped(path):
        verify_shipped(path)
    meta = read_metadata(path)
    check_metadata(meta, path, **expect)
    try:
        with _open(path) as f:
            state = {k: f.get_tensor(k) for k in f.keys()}
    except DoabenchError:
        raise
    except Exception as exc:  # a damaged tensor section
        raise InputError(f"weights file {path}: unreadable tensors ({type(exc).__name__}: {exc})") from None
    check_tensors(state, path)
    return state, meta


def load_into(model: nn.Module, state: Mapping[str, torch.Tensor], path: str | Path) -> None:
    """``model.load_state_dict`` with key and shape mismatches reported as ConfigError."""
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    extra = sorted(set(state) - set(own))
    if missing or extra:
        raise ConfigError(f"weights file {Path(path).name} does not fit the model: "
                          f"missing {missing[:3]}, unexpected {extra[:3]}")
    for k, v in own.items():
        if tuple(state[k].shape) != tuple(v.shape):
            raise ConfigError(f"weights file {Path(path).name}: {k} has shape {tuple(state[k].shape)}, "
                              f"the model needs {tuple(v.shape)}")
    model.load_state_dict(dict(state))


class WeightsFile:
    """One weights file of one model: read, verified (SHA-256 of shipped files, metadata, finite
    tensors) and described, as one value.

    :meth:`read` reads the metadata only; :meth:`load_into` reads and checks the tensors. The
    metadata says what the weights were trained for: the frames (:attr:`frame_spec`), the SRP
    grid (:attr:`resolution`), the array (:attr:`array`), the SRP delays (:attr:`delay_mode`).
    """

    def __init__(self, path: str | Path, metadata: Mapping[str, Any]) -> None:
        self.path = Path(path)
        self.metadata = dict(metadata)
        self._sha256: str | None = None

    @classmethod
    def read(cls, path: str | Path, model_name: str | None = None) -> WeightsFile:
        """The weights file at ``path`` with its metadata (the tensors are read by :meth:`load_into`);
        with ``model_name``, the file must hold a model of that name (a ConfigError otherwise).
        Finding a file by its catalog name or by default is :func:`.catalog.find_weights`."""
        found = cls(path, read_metadata(path))
        if model_name is not None:
            found.check(model_name=model_name)
        return found

    def check(self, **expect: Any) -> None:
        """:func:`check_metadata` of this file (a ConfigError naming the first mismatch)."""
        check_metadata(self.metadata, self.path, **expect)

    def check_array(self, array: doabench.MicArray, where: str) -> None:
        """The array in use must be the trained one (:func:`check_array`)."""
        check_array(self.metadata, array, where)

    @property
    def sha256(self) -> str:
        if self._sha256 is None:
            self._sha256 = sha256_file(self.path)
        return self._sha256

    @property
    def frame_spec(self) -> doabench.FrameSpec:
        """The frames the weights were trained on (their observations')."""
        return self.observations.frame_spec

    @property
    def resolution(self) -> tuple[int, int] | None:
        """The SRP grid of the observations the weights were trained on."""
        return self.observations.resolution

    @property
    def array(self) -> doabench.MicArray | None:
        """The array the weights were trained for (None when the file does not record it)."""
        entry = self.metadata.get("array")
        return doabench.MicArray(entry["name"], np.asarray(entry["positions"], dtype=float)) if entry else None

    @property
    def observations(self) -> doabench.ObservationSpec:
        """What the network was trained to read: the file's stored ``ObservationSpec``."""
        return stored_observations(self.metadata, f"weights file {self.path.name}")

    @property
    def delay_mode(self) -> str:
        """The SRP delay mode of the maps the weights were trained on (``nearest`` for a network
        that reads no map)."""
        return self.observations.delays or "nearest"

    def load_into(self, model: nn.Module, model_name: str, observations: doabench.ObservationSpec | None = None) -> None:
        """Read the tensors (checked: shipped hash, metadata, finite values, keys and shapes) into
        ``model``; with ``observations`` (the tracker's ``observation_spec``), the weights must have
        been trained on them."""
        state, _ = load_weights(self.path, model_name=model_name, observations=observations)
        load_into(model, state, self.path)
        self._sha256 = sha256_file(self.path)

    def describe(self) -> dict[str, Any]:
        """What ``describe()`` reports of the weights: the file, the training summary and the
        observations they were trained on (``trained_features``, their stored spec)."""
        return {"weights": str(self.path), "training": self.metadata.get("training"),
                "trained_features": self.observations.to_dict()}
