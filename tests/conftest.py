"""Shared fixtures: where the optional real data are (tests that need them skip without them, and
the session ends with one line that counts the skips by reason)."""
import os
from collections import Counter
from pathlib import Path
from typing import Any, Iterable

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_LIBRISPEECH = ROOT.parent / "shared" / "data" / "LibriSpeech"


def librispeech_location(environ: "os._Environ[str] | dict[str, str] | None" = None) -> tuple[Path | None, str]:
    """``(root, "")`` of the real LibriSpeech the tests use, or ``(None, why not)``: the folder
    ``DOABENCH_LIBRISPEECH`` names when it is set (as doabench itself reads it), else
    ``../shared/data/LibriSpeech``; either must hold the ``test-other`` subset."""
    environ = os.environ if environ is None else environ
    given = environ.get("DOABENCH_LIBRISPEECH") or ""
    root = Path(given).expanduser() if given else SHARED_LIBRISPEECH
    if (root / "test-other").is_dir():
        return root, ""
    where = f"DOABENCH_LIBRISPEECH={given}" if given else f"{SHARED_LIBRISPEECH} (or set DOABENCH_LIBRISPEECH)"
    return None, f"real LibriSpeech test-other subset not found at {where}"


#: the real LibriSpeech of this session (None: the tests that need it skip with ``LIBRISPEECH_MISSING``)
LIBRISPEECH, LIBRISPEECH_MISSING = librispeech_location()

# Short scenes keep environment tests fast; the scene rate of 156 points per 20 s is kept.
QUICK_SCENE = {"duration_s": 3.0, "n_points": 24}
# The shortest scenes that still give several frames, for checks run on every task.
TINY_SCENE = {"duration_s": 1.5, "n_points": 12}


def tiny_task_toml(task_id: str, episodes: int, base_seed: int, version: int = 1, extra_scene: str = "") -> str:
    """A task spec of 1 s scenes with the embedded speech: the smallest simulated task the dataset,
    scale-out, output and interrupt tests build on (``extra_scene``: more ``[scene]`` lines)."""
    return f"""
id = "{task_id}"
version = {version}
kind = "simulated"
episodes = {episodes}
base_seed = {base_seed}
[speech]
corpus = "embedded"
[scene]
duration_s = 1.0
n_points = 8
t60 = [0.2, 0.3]
room_max = [5.0, 5.0, 3.0]
{extra_scene}"""


@pytest.fixture
def librispeech_root() -> Path:
    if LIBRISPEECH is None:
        pytest.skip(LIBRISPEECH_MISSING)
    return LIBRISPEECH


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    """One intra-op thread: results do not depend on the machine's thread count, and test runs on
    a shared 2-core machine do not oversubscribe it."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(autouse=True)
def _validate_written_results(monkeypatch):
    """Every results file a test writes through doabench (``write_results``: ``doabench run``,
    ``doabench.results.writer``) is validated against the shipped JSON Schema first."""
    try:
        import jsonschema  # noqa: F401
    except ImportError:  # the test extra brings it; without it the schema tests skip
        yield
        return
    import doabench.results.writer as writer
    from doabench.results.schema import validate_results

    original = writer.write_json

    def checked(path, obj):
        if isinstance(obj, dict) and str(obj.get("schema", "")).startswith("doabench.results/"):
            validate_results(obj)
        return original(path, obj)

    monkeypatch.setattr(writer, "write_json", checked)
    yield


# The slow tests (several seconds each: subprocesses that are signalled or run the demo, Ray, mypy,
# the site in Chromium, git, spawned vector environments, full-length streaming), by node-id
# prefix. `make test` (the README's and CI's command) runs everything; `make test-fast` leaves
# these out for a quick loop while editing (`pytest -m "not slow"`).
SLOW_TESTS = (
    "tests/test_interrupts.py",
    "tests/test_scaleout.py",
    "tests/test_site_browser.py",
    "tests/test_quickstart.py",
    "tests/test_types.py",
    "tests/test_commit_run_state.py",
    "tests/test_train_queue.py",
    "tests/test_docs.py::test_generated_pages_are_current",
    "tests/test_docs.py::test_mkdocs",
    "tests/test_docs_figures.py::test_a_docs_figure_drawn_from_librispeech_",
    "tests/test_track.py::test_streamed_",
    "tests/test_outputs.py::test_full_disk_",
    "tests/test_outputs.py::test_out_to_standard_output_",
    "tests/test_vector_env.py::test_async_vector_env_",
    "tests/test_datasets.py::test_sigkill_mid_run_",
    "tests/test_datasets.py::test_two_shards_merged_",
    "tests/test_run.py::test_check_env_passes_for_every_simulated_task[sim-walk-pra",
    "tests/test_run.py::test_check_env_passes_for_every_simulated_task[sim-walk-torchrir",
    "tests/test_readme_commands.py::test_demo_writes_only_under_an_ignored_folder",
    "tests/test_extending.py",
    "tests/test_weights_names.py::test_the_catalog_is_what_the_rule_gives",
    # every committed results file and leaderboard, and every grid cell's environment: the quick loop
    # keeps a fresh run's schema check, the leaderboard tests on small folders, each task's own environment
    # and the T60 0 cells
    "tests/test_results_schema.py::test_committed_results_follow_the_schema",
    "tests/test_leaderboard.py::test_committed_leaderboards_match_committed_results",
    "tests/test_run.py::test_check_env_passes_for_every_simulated_task[sim-t60-0.",
    "tests/test_run.py::test_check_env_passes_for_every_simulated_task[sim-t60-1.",
    "tests/test_run.py::test_check_env_passes_for_every_simulated_task[sim-turn-t60-",
    "tests/test_run.py::test_check_env_passes_for_every_simulated_task[sim-walk-t60-",
    "tests/test_simulation_time.py::test_run_and_make_dataset_print_the_estimate_before_they_start",
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.nodeid.startswith(SLOW_TESTS):
            item.add_marker(pytest.mark.slow)


def skip_summary(reports: Iterable[Any]) -> str:
    """One line counting skipped tests by reason, most frequent first (empty when none skipped)."""
    reasons: Counter[str] = Counter()
    for report in reports:
        longrepr = getattr(report, "longrepr", None)
        reason = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr or "")
        reasons[" ".join(str(reason).removeprefix("Skipped: ").split()) or "no reason given"] += 1
    if not reasons:
        return ""
    n = sum(reasons.values())
    return (f"skipped {n} test{'s' if n != 1 else ''}: "
            + "; ".join(f"{count} {reason}" for reason, count in reasons.most_common()))


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    line = skip_summary(terminalreporter.stats.get("skipped", []))
    if line:
        terminalreporter.write_line(line)
