"""Ids are looked up once, where they are typed, and passed on as values: a sweep resolves each
task id and each tracker text once, however many runs they take part in."""
from __future__ import annotations

from collections import Counter

import pytest
from conftest import tiny_task_toml

import doabench
from doabench.envs import registry as task_registry
from doabench.trackers import registry as tracker_registry

TASKS = ("resolve-once-a", "resolve-once-b")
TRACKERS = ("srp-max:4x8", "srp-max:8x16")


@pytest.fixture(scope="module")
def tasks(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tasks")
    for n, task_id in enumerate(TASKS):
        (folder / f"{task_id}.toml").write_text(tiny_task_toml(task_id, 1, 100 + n))
        doabench.register_task(folder / f"{task_id}.toml")
    return TASKS


@pytest.fixture
def lookups(monkeypatch):
    """Every lookup of a typed task id (the task registry) and of a tracker id (the tracker
    registry), counted by the text looked up."""
    seen: Counter[str] = Counter()

    def counting(registry, method):
        real = getattr(registry, method)

        def wrapper(text, *args, **kwargs):
            seen[text] += 1
            return real(text, *args, **kwargs)
        monkeypatch.setattr(registry, method, wrapper)

    counting(task_registry.TASKS, "get")
    counting(tracker_registry.TRACKERS, "find")
    return seen


def test_a_sweep_resolves_each_task_id_and_each_tracker_text_once(tasks, lookups, tmp_path):
    from doabench.sweep import sweep

    result = sweep(",".join(TRACKERS), ",".join(tasks), tmp_path / "out", episodes=1, log=lambda m: None)
    assert [r.status for r in result.runs] == ["done"] * 4, [r.error for r in result.runs]
    assert {t: lookups[t] for t in tasks} == {t: 1 for t in tasks}
    assert lookups["srp-max"] == len(TRACKERS)  # one lookup of each tracker text's id
    assert sum(lookups.values()) == len(tasks) + len(TRACKERS), lookups


@pytest.mark.parametrize("argv, trackers", [
    (["run", "--tracker", TRACKERS[0], "--task", "{task}", "--episodes", "1", "--quiet", "--out", "{tmp}"], 1),
    (["make-dataset", "--task", "{task}", "--episodes", "1", "--features", "srp:4x8", "--quiet",
      "--out", "{tmp}/d.h5"], 0),
    (["describe", "--task", "{task}"], 0),
], ids=["run", "make-dataset", "describe"])
def test_a_command_resolves_its_task_id_and_tracker_text_once(argv, trackers, tasks, lookups, tmp_path):
    from doabench.cli.main import main

    assert main([a.format(task=tasks[0], tmp=tmp_path) for a in argv]) == 0
    assert lookups == Counter({tasks[0]: 1, **({"srp-max": trackers} if trackers else {})})


def test_a_run_spec_built_from_values_runs_without_a_lookup(tasks, lookups):
    """RunSpec carries the resolved task and canonical tracker (not part of its identity): running
    it, or building its tracker again in a worker, looks nothing up."""
    from doabench.runner import RunSpec

    task, ref = doabench.get_task_spec(tasks[1]), tracker_registry.tracker_ref("srp-max")
    lookups.clear()
    spec, instance = RunSpec.build(ref, task, {"resolution": "4x8"})
    assert spec.tracker == "srp-max:4x8" and spec.resolved_task() is task
    again = spec.make_tracker()
    assert type(again) is type(instance) and again.resolution == instance.resolution == (4, 8)
    assert spec == RunSpec.build("srp-max", tasks[1], {"resolution": "4x8"})[0]  # as from the typed ids
    lookups.clear()
    results = spec.execute(again, episodes=1, progress=False)
    assert results["task"]["id"] == tasks[1] and not lookups
