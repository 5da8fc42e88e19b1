"""Older file formats read as the current ones: the steps from each results schema and weights
format to the next, as pure functions of the loaded data.

Results files (``doabench.results/N``, JSON) and weights metadata (``doabench-weights/N``, the JSON
under the ``doabench`` key of a safetensors header) are read through :func:`upgrade_results` and
:func:`upgrade_weights_metadata`: a file of an older version goes through every step from its
version to the current one, in memory, and every reader sees the current form only.
``doabench migrate`` writes the upgraded form back (:mod:`doabench.results.migrate`).

Upgrading reads data and nothing else: it imports nothing a file names and loads no plug-in. The
stored observation spec of an older file becomes the current one through
``ObservationSpec.of(...).to_dict()``, so it is the form a new run writes.

``doabench.results/1`` -> ``/2`` (:func:`results_v1_to_v2`):

* ``features`` (kinds, resolution, delays, frame) becomes ``observations``, the run's
  ``ObservationSpec`` as ``to_dict()`` writes it; ``features.trained_delays`` becomes the
  top-level ``trained_delays``;
* ``tracker.trained_features`` (a learned tracker's weights' ``features`` block: kinds, frames,
  delay mode) becomes the stored spec of the observations the weights were trained on;
* ``tracker.id``: a bare id of a tracker whose spec is its map resolution (``cross3d``, written
  before ids were canonical) gets the resolution it ran at (``cross3d:16x32``), ``given_id``
  keeping the bare id;
* ``tracker.weights_name``: where absent, the name :data:`NAMES_BEFORE_RECORDING` gives the
  weights' SHA-256 (files of shipped weights written before the name was recorded), else null;
* ``task.options``: where absent, the task options read back from ``task.source``
  (:func:`doabench.envs.sources.recorded_identity`);
* a ``*_ci95`` interval of the summary or a cell that its episodes do not back (a file written
  before that rule: an interval of no width) becomes null
  (:func:`doabench.results.intervals.drop_undefined_intervals`).

``doabench-weights/1`` -> ``/2`` (:func:`weights_v1_to_v2`): ``observations`` is the stored spec
(read from the ``features`` and ``resolution`` blocks where the file has none; the 16x32 grid
where the model reads no map); the ``features`` and ``resolution`` blocks are dropped, the map
resolution of a model that reads maps is ``model_config.resolution``.
"""
from __future__ import annotations

import copy
from typing import Any, Callable, Mapping

from doabench.envs.sources import recorded_identity
from doabench.errors import DoabenchError, InputError
from doabench.features.configs import frame_spec_from_dict
from doabench.features.kinds import BUILTIN_KINDS
from doabench.features.spec import ObservationSpec
from doabench.framing import FrameSpec
from doabench.results.identity import recorded_task_spec
from doabench.results.intervals import drop_undefined_intervals

RESULTS_PREFIX = "doabench.results/"
#: the results schema new runs write
RESULTS_SCHEMA = "doabench.results/2"
WEIGHTS_PREFIX = "doabench-weights/"
#: the weights metadata format new weights files hold
WEIGHTS_FORMAT = "doabench-weights/2"

#: The names of the weights that shipped before results files recorded ``tracker.weights_name``,
#: by canonical tracker id and SHA-256 (their names in ``baselines/weights/catalog.json``).
NAMES_BEFORE_RECORDING: dict[tuple[str, str], str] = {
    ("cross3d:16x32", "8d1eef915b2a8edcce9090c8d4b6b73e182fb3517add31c12b24dfd7799c0a4c"): "paper",
    ("cross3d:16x32", "8ce3ea54bcd7cef2fff9bbe32e0ded4137d780bcf86fe6adc67c1340722be8cb"): "moving",
    ("cross3d:16x32", "68ad5339d4e56fef1963f31bc3bfc19633011ede09174f9d809a67fd81975124"): "paper-v3",
    ("cross3d:8x16", "6a2a5ef6fb3bba7899a08cea325f48df674a86b9b92df5310e00009239a798d1"): "paper",
    ("cross3d:8x16", "fe8c0ebdf1de4776a3de4862f404ed94ab09c72ea058fd849c65c7053679da2d"): "moving",
    ("cross3d:4x8", "f7b287c60ff0498a910a1c06cad1d82c5f1d756f9d2e259c5645b0c59f527997"): "paper",
    ("gcc-cnn1d", "16f53834efc3d28ddbd609285b79ce48516205c2acb207afd45856bd0153e94a"): "paper",
    ("max-cnn1d:64x128", "cf1d9a2d1df2181bc6854198c17922edb7116eddbee50e6b6fca9c83fa16507a"): "paper",
    ("seldnet", "6c2f53a8bf7b1d4c377bc7b6bc4afa11df793bc0a0a45641cfa929a4e2e358e4"): "paper",
    ("spec-cnn2d", "b5a8266e795d01c44b6bd370424d2dca4961fcae1b6d84ccbe8470e9bf003946"): "paper",
}


class UpgradeError(InputError):
    """An older file whose content its upgrade cannot read (a malformed stored block)."""


def _frame(d: Any) -> FrameSpec:
    """The frames of an older block that holds ``window``, ``hop`` and ``fs`` among other keys."""
    return frame_spec_from_dict({key: d[key] for key in ("window", "hop", "fs")})


def _spec_dict(kinds: Any, resolution: Any, frame: FrameSpec, delays: Any,
               spectrogram_frame: FrameSpec | None = None) -> dict[str, Any]:
    """The stored form of the spec an older file describes in its own way. doabench's own kinds are
    configured by ``ObservationSpec.of``; another name (a plug-in's kind: none could be on the grid
    then) is stored as a kind without settings and never looked up, since reading a file must not
    load the plug-in it names."""
    if isinstance(kinds, str) or not isinstance(kinds, (list, tuple)):
        raise TypeError(f"kinds {kinds!r} is not a list")
    names = [str(k) for k in kinds]
    builtin = {kind.name for kind in BUILTIN_KINDS}
    spec = ObservationSpec.of(tuple(n for n in names if n in builtin), resolution or None, frame, delays or None,
                              spectrogram_frame).to_dict()
    configured = {stored["kind"]: stored for stored in spec["kinds"]}
    return {**spec, "kinds": [configured.get(name, {"kind": name}) for name in names]}


# -- results --------------------------------------------------------------------------------------
def _canonical_v1_id(tracker: Mapping[str, Any]) -> str:
    """The canonical id of a ``/1`` file's tracker: its id, with the map resolution it ran at
    where the id is bare and the tracker's spec is its resolution."""
    text = str(tracker.get("id") or tracker.get("name"))
    resolution = tracker.get("resolution")
    in_id = tracker.get("resolution_in_id", resolution is not None)
    return f"{text}:{resolution}" if ":" not in text and in_id and resolution else text


def results_v1_to_v2(data: Mapping[str, Any]) -> dict[str, Any]:
    """A ``doabench.results/1`` dictionary as ``doabench.results/2`` (see the module docstring);
    ``data`` itself is left as it is. An UpgradeError names a ``features`` block it cannot read."""
    out = copy.deepcopy(dict(data))
    features = out.pop("features", None)
    if isinstance(features, Mapping):
        try:
            out["observations"] = _spec_dict(features.get("kinds"), features.get("resolution"),
                                             _frame(features["frame"]), features.get("delays"))
        except (KeyError, TypeError, ValueError, DoabenchError) as exc:
            raise UpgradeError(f"its features block cannot be read ({exc})") from None
        if features.get("trained_delays") is not None:
            out["trained_delays"] = str(features["trained_delays"])
    tracker = out.get("tracker")
    if isinstance(tracker, dict):
        trained = tracker.get("trained_features")
        if isinstance(trained, Mapping):
            try:
                tracker["trained_features"] = _spec_dict(trained.get("kinds"), tracker.get("resolution"),
                                                         _frame(trained), trained.get("delay_mode"))
            except (KeyError, TypeError, ValueError, DoabenchError) as exc:
                raise UpgradeError(f"its tracker.trained_features cannot be read ({exc})") from None
        canonical = _canonical_v1_id(tracker)
        if canonical != tracker.get("id") and tracker.get("id") and "given_id" not in tracker:
            tracker["given_id"] = str(tracker["id"])  # the alias the run was given, as /2 files keep it
        tracker["id"] = canonical
        if "weights_name" not in tracker:
            digest = tracker.get("weights_hash")
            tracker["weights_name"] = NAMES_BEFORE_RECORDING.get((tracker["id"], str(digest))) if digest else None
    task = out.get("task")
    if isinstance(task, dict) and not isinstance(task.get("options"), Mapping):
        task["options"] = _recorded_task_options(task)
    drop_undefined_intervals(out)
    out["schema"] = "doabench.results/2"
    return out


def _recorded_task_options(task: Mapping[str, Any]) -> dict[str, Any]:
    """The task options of a run recorded before results held them, read back from its
    ``task.source`` (a task id registered here by its spec; another by its source alone)."""
    spec = recorded_task_spec(str(task.get("id")))  # None: a task not registered here; its source alone says it
    source = task.get("source")
    return dict(recorded_identity(spec, str(task.get("kind")), source if isinstance(source, Mapping) else {}))


#: each results schema's step to the next, by the version it reads
RESULTS_STEPS: dict[str, Callable[[Mapping[str, Any]], dict[str, Any]]] = {
    "doabench.results/1": results_v1_to_v2,
}


def results_version(data: Any) -> str | None:
    """The ``schema`` of a loaded results file, None for anything that does not name one."""
    found = data.get("schema") if isinstance(data, Mapping) else None
    return found if isinstance(found, str) and found.startswith(RESULTS_PREFIX) else None


def upgrade_results(data: Any) -> Any:
    """``data`` (a loaded results file) in the current schema: a file of an older schema through
    each step to the current one (a new dictionary), anything else as it is (no results file, a
    schema this doabench does not know: :func:`doabench.results.schema.results_problem` says
    which). An UpgradeError (one line) for an older file whose content a step cannot read."""
    version = results_version(data)
    while version in RESULTS_STEPS:
        try:
            data = RESULTS_STEPS[version](data)
        except UpgradeError as exc:
            raise UpgradeError(f"a {version} results file that cannot be read as {RESULTS_SCHEMA}: {exc}") from None
        version = results_version(data)
    return data


# -- weights --------------------------------------------------------------------------------------
def weights_v1_to_v2(meta: Mapping[str, Any]) -> dict[str, Any]:
    """``doabench-weights/1`` metadata as ``doabench-weights/2`` (see the module docstring); ``meta``
    itself is left as it is. An UpgradeError names what it cannot read."""
    out = copy.deepcopy(dict(meta))
    features = out.pop("features", None) or {}
    resolution = out.pop("resolution", None)
    stored = out.get("observations")
    try:
        if isinstance(stored, Mapping) and stored:
            second = stored.get("spectrogram_frame")
            out["observations"] = _spec_dict(stored.get("kinds"), stored.get("resolution"), _frame(stored["frame"]),
                                             stored.get("delays"), _frame(second) if second else None)
        else:
            out["observations"] = _spec_dict(features.get("kinds") or [], resolution, _frame(features),
                                             features.get("delay_mode"))
    except (KeyError, TypeError, ValueError, AttributeError, DoabenchError) as exc:
        raise UpgradeError(f"its stored observations cannot be read ({exc})") from None
    config = out.get("model_config")
    config = dict(config) if isinstance(config, Mapping) else {}
    if resolution and "resolution" not in config:
        config["resolution"] = str(resolution)
    out["model_config"] = config
    out["format"] = "doabench-weights/2"
    return out


#: each weights format's step to the next, by the version it reads
WEIGHTS_STEPS: dict[str, Callable[[Mapping[str, Any]], dict[str, Any]]] = {
    "doabench-weights/1": weights_v1_to_v2,
}


def upgrade_weights_metadata(meta: Mapping[str, Any]) -> dict[str, Any]:
    """Weights metadata in the current format: an older format through each step to the current
    one. An UpgradeError (one line) for an unknown format or content a step cannot read."""
    found = meta.get("format") if isinstance(meta, Mapping) else meta
    while found in WEIGHTS_STEPS:
        try:
            meta = WEIGHTS_STEPS[found](meta)
        except UpgradeError as exc:
            raise UpgradeError(f"{found} metadata that cannot be read as {WEIGHTS_FORMAT}: {exc}") from None
        found = meta.get("format")
    if found != WEIGHTS_FORMAT:
        raise UpgradeError(f"unknown metadata format {found!r}; this doabench reads {WEIGHTS_FORMAT} and older")
    return dict(meta)
