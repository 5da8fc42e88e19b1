"""Task specs: versioned descriptions of a benchmark task, kept as TOML files.

A spec file (``tasks/<id>.toml``)::

    id = "sim-demo"
    version = 0            # bump whenever a change can move a score
    kind = "simulated"     # which episode source builds the episodes (see doabench.envs.sources)
    description = "..."
    array = "nao"          # built-in array name or a JSON/YAML array file (relative: to this file's folder)
    episodes = 3
    base_seed = 1000
    [frames]               # optional, defaults: window 4096, hop 3/4 window, fs 16000
    window = 4096
    [speech]               # kind-specific sections are kept verbatim in ``params``
    corpus = "embedded"
    [scene]
    t60 = [0.2, 0.5]

A file may also define a *grid*: ``[grid]`` with ``t60 = [...]`` and ``snr = [...]`` plus
``cell_id = "sim-t60-{t60}-snr-{snr}"`` and ``episodes_per_cell``. It then registers one task per
cell (fixed T60 and SNR) and the grid task itself, whose episodes are the cells' episodes in order.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

from doabench.errors import ConfigError
from doabench.framing import FrameSpec

try:
    import tomllib  # type: ignore[import-not-found, unused-ignore]  # mypy checks as Python 3.10, which has none
except ModuleNotFoundError:  # Python 3.10: the same parser, published as tomli (a dependency there)
    import tomli as tomllib

REQUIRED = ("id", "version", "kind")


@dataclass(frozen=True)
class TaskSpec:
    """A registered task. ``params`` holds the kind-specific sections (scene, speech, grid...)."""

    id: str
    version: int
    kind: str
    description: str = ""
    array: str = "nao"
    episodes: int = 1
    base_seed: int = 0
    frames: FrameSpec = field(default_factory=FrameSpec)
    params: Mapping[str, Any] = field(default_factory=dict)
    source_file: str = ""

    @property
    def gym_id(self) -> str:
        return f"doabench/{self.id}-v{self.version}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "version": self.version,
            "kind": self.kind,
            "description": self.description,
            "array": self.array,
            "episodes": self.episodes,
            "base_seed": self.base_seed,
            "frames": self.frames.to_dict(),
            "params": _plain(self.params),
        }


def is_training_task(task: TaskSpec | Mapping[str, Any]) -> bool:
    """Whether ``task`` (a spec, or the dict of one a dataset file records) is a training task:
    its speech is drawn from a LibriSpeech training subset (``train-clean-100``, as ``sim-train``
    and its variants). Every other task (the simulated test tasks on ``test-other``, ``sim-demo``,
    LOCATA's recordings) is a benchmark task, one that scores trackers."""
    params = task.params if isinstance(task, TaskSpec) else task.get("params", {})
    speech = dict((params or {}).get("speech") or {})
    return speech.get("corpus") == "librispeech" and str(speech.get("subset", "")).startswith("train")


def _plain(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    return obj


def format_number(x: float) -> str:
    """0.9 -> "0.9", 0.0 -> "0", 5.0 -> "5": the form task ids use."""
    return f"{float(x):g}"


def spec_from_dict(data: Mapping[str, Any], source: str = "<dict>") -> list[TaskSpec]:
    """Build the task(s) a spec mapping defines (a grid file yields its cells and itself)."""
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ConfigError(f"task spec {source}: missing {', '.join(missing)}")
    try:
        frames = FrameSpec(**dict(data.get("frames", {})))
    except TypeError as exc:
        raise ConfigError(f"task spec {source}: bad [frames] section: {exc}") from None
    known = {"id", "version", "kind", "description", "array", "episodes", "base_seed", "frames"}
    params = {k: v for k, v in data.items() if k not in known}
    try:
        base = TaskSpec(
            id=str(data["id"]),
            version=int(data["version"]),
            kind=str(data["kind"]),
            description=str(data.get("description", "")),
            array=str(data.get("array", "nao")),
            episodes=int(data.get("episodes", 1)),
            base_seed=int(data.get("base_seed", 0)),
            frames=frames,
            params=params,
            source_file=source,
        )
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"task spec {source}: {exc}") from None
    for key in ("episodes", "version", "base_seed"):
        value = data.get(key, 0)
        if isinstance(value, bool) or not isinstance(value, int) and not (isinstance(value, float) and value.is_integer()):
            raise ConfigError(f"task spec {source}: {key} must be an integer, got {value!r}")
    if base.episodes < 1:
        raise ConfigError(f"task spec {source}: episodes must be at least 1, got {base.episodes}")
    if "grid" not in params:
        return [base]
    return _expand_grid(base, source)


def _expand_grid(base: TaskSpec, source: str) -> list[TaskSpec]:
    grid = dict(base.params["grid"])
    try:
        t60s = [float(v) for v in grid["t60"]]
        snrs = [float(v) for v in grid["snr"]]
        per_cell = int(grid["episodes_per_cell"])
        pattern = str(grid.get("cell_id", "sim-t60-{t60}-snr-{snr}"))
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"task spec {source}: [grid] needs t60, snr and episodes_per_cell ({exc})") from None
    if per_cell < 1:
        raise ConfigError(f"task spec {source}: [grid] episodes_per_cell must be at least 1, got {per_cell}")
    cells = []
    params_wo_grid = {k: v for k, v in base.params.items() if k != "grid"}
    for index, (t60, snr) in enumerate((t, s) for t in t60s for s in snrs):
        scene = dict(params_wo_grid.get("scene", {}), t60=[t60, t60], snr=[snr, snr])
        cell_id = pattern.format(t60=format_number(t60), snr=format_number(snr))
        cells.append(replace(
            base, id=cell_id, episodes=per_cell,
            description=f"{base.description} Cell T60 = {format_number(t60)} s, SNR = {format_number(snr)} dB.".strip(),
            params={**params_wo_grid, "scene": scene, "cell": {"index": index, "t60": t60, "snr": snr, "grid": base.id}},
        ))
    grid_task = replace(base, episodes=per_cell * len(cells),
                        params={**base.params, "cells": [c.id for c in cells]})
    return cells + [grid_task]


ARRAY_FILE_SUFFIXES = (".json", ".yaml", ".yml")


def is_array_path(value: str) -> bool:
    """Whether a spec's ``array`` names a file rather than a built-in array: it has a JSON/YAML
    suffix or a folder in it (a bare name such as ``nao`` is always the built-in one)."""
    return Path(value).suffix.lower() in ARRAY_FILE_SUFFIXES or "/" in value or "\\" in value


def resolve_array_path(value: Any, folder: str | Path) -> Any:
    """A relative array file of a spec file, made absolute against the spec file's ``folder``,
    so a task loads the same array from any working directory; names and absolute paths as given."""
    if not isinstance(value, str) or not is_array_path(value):
        return value
    path = Path(value).expanduser()
    return value if path.is_absolute() else str((Path(folder) / path).resolve())


def load_spec_file(path: str | Path) -> list[TaskSpec]:
    """Parse one TOML spec file into its task(s). A relative ``array`` file is read from the spec
    file's folder, not from the working directory."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"task spec {path} does not exist") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"task spec {path}: invalid TOML ({exc})") from None
    if "array" in data:
        data["array"] = resolve_array_path(data["array"], path.resolve().parent)
    return spec_from_dict(data, str(path))
