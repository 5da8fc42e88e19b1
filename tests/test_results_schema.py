"""The results JSON Schema: shipped in the package, committed files and freshly written
ones follow it, and a broken file fails it. (conftest validates every file tests write.)"""
from __future__ import annotations

import copy
import json
import shutil
import subprocess
from pathlib import Path

import pytest

jsonschema = pytest.importorskip("jsonschema", reason="jsonschema is in the test extra")

from doabench.results.schema import results_schema, validate_results  # noqa: E402
from doabench.results.upgrade import upgrade_results  # noqa: E402

from conftest import QUICK_SCENE, ROOT  # noqa: E402


def test_schema_is_shipped_and_valid() -> None:
    from importlib import resources

    assert resources.files("doabench.results").joinpath("schemas", "results-2.schema.json").is_file()
    schema = results_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["properties"]["schema"] == {"const": "doabench.results/2"}
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert '"doabench.results" = ["schemas/*.json"]' in pyproject  # in the wheel too


@pytest.mark.parametrize("path", sorted((ROOT / "results").glob("*.json")), ids=lambda p: p.name)
def test_committed_results_follow_the_schema(path: Path) -> None:
    """Committed files of an older schema follow the current one once upgraded."""
    validate_results(upgrade_results(json.loads(path.read_text())))


def test_a_fresh_run_follows_the_schema_and_breakage_is_caught(tmp_path: Path) -> None:
    import doabench
    from doabench.results.writer import write_results

    results = doabench.run(tracker="srp-max:4x8", task="sim-demo", episodes=1, progress=False,
                           scene_overrides=QUICK_SCENE)
    validate_results(results)
    json_path, _ = write_results(results, tmp_path)  # validated by conftest on the way
    validate_results(json.loads(json_path.read_text()))
    for breakage in (lambda r: r.pop("summary"), lambda r: r["task"].update(version=1.5),
                     lambda r: r.pop("observations"), lambda r: r.update(trained_delays="sideways"), lambda r: r["episodes"][0].pop("n_frames")):
        bad = copy.deepcopy(results)
        breakage(bad)
        with pytest.raises(jsonschema.ValidationError):
            validate_results(bad)
        with pytest.raises(jsonschema.ValidationError):
            write_results(bad, tmp_path / "bad")  # the test hook refuses to write it


def test_every_field_of_the_schema_is_documented() -> None:
    page = (ROOT / "docs" / "results-format.md").read_text()
    schema = results_schema()
    for key in schema["properties"]:
        assert f"`{key}`" in page, key
    for section in ("task", "tracker", "environment", "summary", "scoring"):
        for key in schema["properties"][section].get("properties", {}):
            assert f"`{section}.{key}`" in page, f"{section}.{key}"


def test_the_best_constant_directions_error_is_optional_and_typed() -> None:
    """Episode rows carry ``lag_const_sse`` (the lag's evidence that the estimates follow the
    talker) since it was recorded; rows written before it still validate, a wrong type does not."""
    old = upgrade_results(json.loads((ROOT / "results" / "sim-demo__srp-max_16x32.json").read_text()))
    assert all("lag_const_sse" not in row for row in old["episodes"])
    validate_results(old)
    new = copy.deepcopy(old)
    new["episodes"][0]["lag_const_sse"] = 1234.5
    validate_results(new)
    new["episodes"][0]["lag_const_sse"] = "large"
    with pytest.raises(jsonschema.ValidationError):
        validate_results(new)


@pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(), reason="needs git and a git checkout")
def test_results_record_the_commit_of_the_checkout_they_ran_from() -> None:
    """A results file names the commit it was made with (the checkout doabench is imported from)."""
    from doabench.provenance import git_commit

    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True)
    recorded = git_commit()
    assert recorded["commit"] == head.stdout.strip() and isinstance(recorded["dirty"], bool)
