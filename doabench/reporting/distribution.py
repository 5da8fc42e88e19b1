"""Is a task in a learned tracker's training distribution?

A learned tracker's score on a task drawn from the distribution it was trained on (the same
simulator, array and scene family) measures how well it fits that distribution, not how it
generalises; a leaderboard says which of the two a row is, the way MTEB's leaderboard flags
zero-shot models. The rule, from the results file alone (the tracker's training record names its
training task) and the task specs:

* both tasks are simulated (recordings such as LOCATA are never in a simulated training set),
* by the same room simulator (``builtin``, ``pyroomacoustics``, ...) for the same array,
* and every scene feature of the test task that changes the geometry of the problem (a walking
  talker, a turned array, a moving or turning array) also occurs in the training scenes.

T60, SNR, pauses and a quiet noise source vary within a family and do not count: the paper's
training distribution covers T60 0.2-1.3 s and SNR 5-30 dB, and its test grid is read as in
distribution.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

IN, OUT = "in", "out"

#: scene features that make another family: (name shown, test on the scene parameters)
FAMILY_FEATURES = (
    ("walking talkers", lambda s: _positive(s.get("walk_p"))),
    ("turned arrays", lambda s: any(_nonzero(s.get(k)) for k in ("array_yaw", "array_pitch", "array_roll"))),
    ("moving or turning arrays", lambda s: _positive(s.get("array_motion_p")) or _positive(s.get("array_turn_p"))),
)


def _positive(x: Any) -> bool:
    try:
        return x is not None and float(x) > 0
    except (TypeError, ValueError):
        return False


def _nonzero(x: Any) -> bool:
    if x is None:
        return False
    values = x if isinstance(x, (list, tuple)) else [x]
    try:
        return any(float(v) != 0 for v in values)
    except (TypeError, ValueError):
        return False


@dataclass(frozen=True)
class Verdict:
    """``status`` is ``in`` or ``out``; ``training`` the training task (``sim-train v1``); ``why``
    says what differs (empty when in distribution)."""

    status: str
    training: str
    why: str = ""

    @property
    def text(self) -> str:
        if self.status == IN:
            return f"in its training distribution ({self.training}: same simulator and scene family)"
        return f"zero-shot: not in its training distribution ({self.training}; {self.why})"


def scene_features(scene: Mapping[str, Any]) -> set[str]:
    """The family features (:data:`FAMILY_FEATURES`) of a scene parameter table."""
    return {name for name, present in FAMILY_FEATURES if present(scene)}


def _spec(task_id: str):
    """The registered task ``task_id`` (None for another: a results file's ids resolve nothing)."""
    from doabench.results.identity import recorded_task_spec

    return recorded_task_spec(task_id)


def _simulator(spec: Any, source: Mapping[str, Any] | None = None) -> str:
    if source and source.get("simulator"):
        return str(source["simulator"])
    params = dict(getattr(spec, "params", {}) or {})
    return str((params.get("simulator") or {}).get("backend") or "builtin")


def training_distribution(results: Mapping[str, Any]) -> Verdict | None:
    """Whether the run's task is in its tracker's training distribution; None for a tracker without
    a training record (classical trackers, untrained or foreign weights)."""
    tracker = results.get("tracker") or {}
    training = tracker.get("training")
    if not isinstance(training, Mapping) or not training.get("task"):
        return None
    train_id = str(training["task"])
    version = training.get("task_version")
    name = f"{train_id} v{version}" if version is not None else train_id
    task = results.get("task") or {}
    train_spec, test_spec = _spec(train_id), _spec(str(task.get("id")))
    if train_spec is None:
        return Verdict(OUT, name, f"its training task {train_id} is not registered here, so no match is claimed")
    test_kind = task.get("kind") or getattr(test_spec, "kind", None)
    if test_kind != "simulated" or train_spec.kind != "simulated":
        what = "recorded audio" if test_kind == "locata" else f"task kind {test_kind}"
        return Verdict(OUT, name, f"this task is {what}, the training data {train_spec.kind}")
    source = task.get("source") or {}
    sim_test, sim_train = _simulator(test_spec, source), _simulator(train_spec)
    if sim_test != sim_train:
        return Verdict(OUT, name, f"simulator {sim_test} here, {sim_train} in training")
    array_test = getattr(test_spec, "array", None) or tracker.get("array")
    if array_test and array_test != train_spec.array:
        return Verdict(OUT, name, f"array {array_test} here, {train_spec.array} in training")
    scene = dict((dict(getattr(test_spec, "params", {}) or {}).get("scene") or {}))
    scene.update(source.get("scene_overrides") or {})
    new = scene_features(scene) - scene_features(dict(train_spec.params.get("scene") or {}))
    if new:
        return Verdict(OUT, name, ", ".join(sorted(new)) + " here, none in training")
    return Verdict(IN, name)
