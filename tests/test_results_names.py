"""Results files never silently replace a different configuration: tracker options
and exact delays name the file by a configuration hash; a file of the same name with another
configuration (weights, task version) is refused unless --overwrite."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from doabench.cli.main import main
from doabench.errors import InputError
from doabench.results.schema import load_results
from doabench.results.upgrade import upgrade_results
from doabench.results.writer import config_suffix, results_stem, write_results

from conftest import ROOT

RUN = ["run", "--task", "sim-demo", "--episodes", "1", "--quiet", "--no-frames"]


def _run(out: Path, *extra: str) -> int:
    return main([*RUN, "--out", str(out), *extra])


def test_default_configuration_keeps_the_plain_name_and_options_get_a_hash() -> None:
    assert results_stem("sim-demo", "srp-max:32x64") == "sim-demo__srp-max_32x64"
    a = results_stem("sim-demo", "srp-kalman", {"alpha": 0.2})
    b = results_stem("sim-demo", "srp-kalman", {"alpha": 0.7})
    assert a != b and a.startswith("sim-demo__srp-kalman__") and len(a) == len("sim-demo__srp-kalman__") + 8
    assert results_stem("sim-demo", "srp-max", delays="exact") != results_stem("sim-demo", "srp-max")
    # A weights file is named by its content: the same path with other content is another name.
    w1 = config_suffix({"weights": "w.safetensors"}, weights_hash="aa" * 32)
    w2 = config_suffix({"weights": "w.safetensors"}, weights_hash="bb" * 32)
    assert w1 != w2 and config_suffix({"weights": "elsewhere/w.safetensors"}, weights_hash="aa" * 32) == w1


def test_two_option_values_write_two_files(tmp_path: Path, capsys) -> None:
    out = tmp_path / "r"
    assert _run(out, "--tracker", "srp-kalman:4x8", "--tracker-opt", "alpha=0.2") == 0
    assert _run(out, "--tracker", "srp-kalman:4x8", "--tracker-opt", "alpha=0.7") == 0
    files = sorted(p.name for p in out.glob("*.json"))
    assert len(files) == 2, files
    alphas = sorted(json.loads((out / f).read_text())["tracker"]["options"]["alpha"] for f in files)
    assert alphas == [0.2, 0.7]
    # Both show up as distinct rows on the leaderboard.
    from doabench.reporting.leaderboard import build_leaderboards

    page = build_leaderboards(out)["sim-demo.md"]
    assert "`srp-kalman:4x8 (alpha=0.2)`" in page and "`srp-kalman:4x8 (alpha=0.7)`" in page


def test_a_different_configuration_under_the_same_name_is_refused(tmp_path: Path, capsys) -> None:
    out = tmp_path / "r"
    assert _run(out, "--tracker", "srp-max:4x8") == 0
    path = out / "sim-demo__srp-max_4x8.json"
    data = json.loads(path.read_text())
    data["task"]["version"] = -1  # as if written for another task version
    path.write_text(json.dumps(data))
    capsys.readouterr()
    assert _run(out, "--tracker", "srp-max:4x8") == 2
    err = capsys.readouterr().err.strip()
    assert "holds a different configuration" in err and "task_version -1 -> " in err and "\n" not in err
    assert json.loads(path.read_text())["task"]["version"] == -1  # untouched
    assert not list(out.glob(".*"))  # no journal or lock left behind
    assert _run(out, "--tracker", "srp-max:4x8", "--overwrite") == 0
    assert json.loads(path.read_text())["task"]["version"] != -1
    # The same configuration is simply rerun and replaced.
    assert _run(out, "--tracker", "srp-max:4x8") == 0


def test_python_writer_refuses_another_configuration(tmp_path: Path) -> None:
    results = load_results(ROOT / "results" / "sim-demo__srp-max_16x32.json")
    json_path, _ = write_results(results, tmp_path)
    assert json_path.name == "sim-demo__srp-max_16x32.json"
    write_results(results, tmp_path)  # same configuration: fine
    other = json.loads(json.dumps(results))
    other["tracker"]["weights_hash"] = "c" * 64
    with pytest.raises(InputError, match="different configuration"):
        write_results(other, tmp_path)
    write_results(other, tmp_path, overwrite=True)


def test_committed_results_carry_the_names_their_configuration_gives() -> None:
    from doabench.results.writer import results_path

    for path in sorted((ROOT / "results").glob("*.json")):
        assert results_path(load_results(path), path.parent).name == path.name


# -- task options are part of a run's identity ---------------------------------------------------------
def test_a_run_on_another_simulator_is_another_configuration(tmp_path: Path, capsys) -> None:
    """--backend changes the episodes: the second run must not replace the first, the leaderboard
    shows two rows, the file says which options it ran with and its reproduce line repeats them."""
    from doabench.reporting.leaderboard import build_leaderboards, reproduce_command

    out = tmp_path / "bk"
    assert _run(out, "--tracker", "srp-max:4x8", "--backend", "pyroomacoustics") == 0
    assert _run(out, "--tracker", "srp-max:4x8") == 0
    files = sorted(out.glob("*.json"))
    assert [p.name for p in files][0] == "sim-demo__srp-max_4x8.json" and len(files) == 2, files
    other = json.loads(files[1].read_text())
    assert other["task"]["options"] == {"backend": "pyroomacoustics"}
    assert json.loads(files[0].read_text())["task"]["options"] == {}
    assert "--backend pyroomacoustics" in reproduce_command(other)
    page = build_leaderboards(out)["sim-demo.md"]
    assert "`srp-max:4x8`" in page and "`srp-max:4x8 [backend=pyroomacoustics]`" in page
    assert "superseded" not in page.lower()


def test_task_options_name_the_file_only_where_they_differ_from_the_task() -> None:
    from doabench.envs.registry import get_task_spec
    from doabench.envs.sources import task_identity

    demo = get_task_spec("sim-demo")
    assert task_identity(demo, {"librispeech": "/somewhere", "backend": "builtin", "device": "cpu"}) == {}
    assert task_identity(demo, {"backend": "pyroomacoustics"}) == {"backend": "pyroomacoustics"}
    assert task_identity(demo, {"scene_overrides": {"duration_s": 3}}) == {"scene_overrides": {"duration_s": 3}}
    # A task rendered by its own simulator: that simulator (or builtin, which stands for it) is its default.
    pra = get_task_spec("sim-walk-pra")
    assert task_identity(pra, {"backend": "pyroomacoustics"}) == task_identity(pra, {"backend": "builtin"}) == {}
    # LOCATA: the split and the VAD change the episodes and the scoring; the corpus root does not.
    locata = get_task_spec("locata-3")
    assert task_identity(locata, {"locata_root": "/data", "split": "dev", "vad": "webrtc"}) == {}
    assert task_identity(locata, {"split": "eval", "vad": "corpus"}) == {"split": "eval", "vad": "corpus"}
    plain = results_stem("locata-3", "srp-max:16x32")
    assert results_stem("locata-3", "srp-max:16x32", task_options={}) == plain
    assert len({plain, results_stem("locata-3", "srp-max:16x32", task_options={"vad": "corpus"}),
                results_stem("locata-3", "srp-max:16x32", task_options={"split": "eval"})}) == 3


def test_a_file_written_before_task_options_were_recorded_reads_them_from_its_source() -> None:
    """The upgrade from doabench.results/1 reads the task options back from ``task.source``."""
    from doabench.results.writer import results_configuration, results_task_options

    data = json.loads((ROOT / "results" / "sim-demo__srp-max_16x32.json").read_text())
    assert data["schema"] == "doabench.results/1" and "options" not in data["task"]
    assert upgrade_results(data)["task"]["options"] == {}
    data["task"]["source"] = {**data["task"]["source"], "simulator": "pyroomacoustics"}
    upgraded = upgrade_results(data)
    assert upgraded["task"]["options"] == {"backend": "pyroomacoustics"} == results_task_options(upgraded)
    assert results_configuration(upgraded)["task_options"] == {"backend": "pyroomacoustics"}


def test_compare_refuses_runs_of_other_task_options(tmp_path: Path, capsys) -> None:
    out = tmp_path / "bk"
    assert _run(out, "--tracker", "srp-max:4x8", "--backend", "pyroomacoustics") == 0
    assert _run(out, "--tracker", "srp-max:4x8") == 0
    a, b = sorted(out.glob("*.json"))
    capsys.readouterr()
    assert main(["compare", str(a), str(b)]) == 2
    err = capsys.readouterr().err.strip()
    assert "different task options" in err and len(err.splitlines()) == 1


def test_a_plug_in_trackers_reproduce_line_uses_the_id_that_was_typed() -> None:
    from doabench.reporting.leaderboard import reproduce_command

    data = json.loads((ROOT / "results" / "sim-demo__srp-max_16x32.json").read_text())
    data["tracker"] = {**data["tracker"], "id": "fixed-front", "name": "fixed-front",
                       "given_id": "my_trackers.fixed:FixedFront"}
    assert "--tracker my_trackers.fixed:FixedFront " in reproduce_command(data)
    data["tracker"] = {**data["tracker"], "id": "srp-max:16x32", "name": "srp-max", "given_id": "srp-max"}
    assert "--tracker srp-max:16x32 " in reproduce_command(data)


PLUG_IN = '''
import numpy as np
import doabench


class EmaTracker(doabench.Tracker):
    """Holds an average of the SRP peak; its spec is the map resolution, not in its id."""
    causal = True

    def __init__(self, spec=None, alpha=0.5, **options):
        super().__init__(spec, **options)
        self.alpha = float(alpha)
        self.observation_spec = doabench.ObservationSpec.of(("srp",), self.spec or "16x32")

    def reset(self, array, **context):
        from doabench.geometry import grid_unit_vectors
        self.grid = grid_unit_vectors(*self.resolution, planar=array.planar).reshape(-1, 3)
        self.last = np.array([1.0, 0.0, 0.0])

    def step(self, observation):
        srp = observation["srp"].ravel()
        if observation["vad"] and srp.any():
            self.last = self.alpha * self.last + (1 - self.alpha) * self.grid[np.argmax(srp)]
        return self.last / np.linalg.norm(self.last)
'''


def test_a_plug_in_trackers_spec_is_part_of_its_identity(tmp_path: Path, monkeypatch, capsys) -> None:
    """``module:Class:8x16`` and ``module:Class:4x8`` (and an option) into one folder: three files,
    each named by the whole tracker text, and three leaderboard rows whose labels carry the spec;
    the leaderboard is read without the plug-in importable."""
    import sys

    from doabench.reporting.leaderboard import build_leaderboards
    from doabench.results.labels import run_label

    (tmp_path / "ema_plugin.py").write_text(PLUG_IN)
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "r"
    assert _run(out, "--tracker", "ema_plugin:EmaTracker:8x16") == 0
    assert _run(out, "--tracker", "ema_plugin:EmaTracker:4x8") == 0
    assert _run(out, "--tracker", "ema_plugin:EmaTracker:4x8", "--tracker-opt", "alpha=0.2") == 0
    files = sorted(p.name for p in out.glob("*.json"))
    assert len(files) == 3, files
    assert "sim-demo__ema_plugin_EmaTracker_8x16.json" in files and "sim-demo__ema_plugin_EmaTracker_4x8.json" in files
    labels = sorted(run_label(json.loads((out / f).read_text())) for f in files)
    assert labels == ["ema_plugin:EmaTracker:4x8", "ema_plugin:EmaTracker:4x8 (alpha=0.2)",
                      "ema_plugin:EmaTracker:8x16"]
    monkeypatch.delitem(sys.modules, "ema_plugin")
    (tmp_path / "ema_plugin.py").unlink()  # reading results imports nothing they name
    page = build_leaderboards(out)["sim-demo.md"]
    for label in labels:
        assert f"`{label}`" in page
    assert "ema_plugin" not in sys.modules


# -- shipped weights name the file; `doabench migrate` brings older names to it ----------------------
def test_shipped_weights_name_the_file_and_other_options_hash_after_them() -> None:
    h = "ab" * 32
    assert results_stem("sim-walk", "cross3d:16x32", {}, weights_hash=h, weights_name="paper") == \
        "sim-walk__cross3d_16x32__paper"
    named = results_stem("sim-walk", "cross3d:16x32", {"weights": "moving-long"}, weights_hash=h,
                         weights_name="moving-long")
    assert named == "sim-walk__cross3d_16x32__moving-long"
    refined = results_stem("sim-walk", "cross3d:16x32", {"weights": "moving-long", "refine": "64x128"},
                           weights_hash=h, weights_name="moving-long")
    assert refined.startswith(named + "__") and len(refined) == len(named) + 10
    # a file that is not shipped weights is named by its content's hash, as before
    assert results_stem("sim-walk", "cross3d:16x32", {"weights": "w.safetensors"}, weights_hash=h).startswith(
        "sim-walk__cross3d_16x32__") and "paper" not in results_stem("sim-walk", "cross3d:16x32",
                                                                      {"weights": "w.safetensors"}, weights_hash=h)


def _old_named_copy(folder: Path) -> tuple[Path, str]:
    """A committed results file of shipped weights under a name of the older naming (its hash)."""
    source = ROOT / "results" / "sim-pauses__cross3d_16x32__paper-v3.json"
    folder.mkdir()
    old = folder / "sim-pauses__cross3d_16x32__650e03d8.json"
    old.write_bytes(source.read_bytes())
    old.with_suffix(".csv").write_text("episode\n")
    return old, source.name


def test_migrate_renames_older_names_with_their_csv_and_is_idempotent(tmp_path: Path, capsys) -> None:
    old, new_name = _old_named_copy(tmp_path / "r")
    assert main(["migrate", str(old.parent), "--dry-run"]) == 0
    assert f"{old.name} -> {new_name}" in capsys.readouterr().out and old.exists()
    assert main(["migrate", str(old.parent)]) == 0
    assert not old.exists() and (old.parent / new_name).exists()
    assert (old.parent / new_name).with_suffix(".csv").read_text() == "episode\n"
    capsys.readouterr()
    assert main(["migrate", str(old.parent)]) == 0
    assert "and has its current name" in capsys.readouterr().out


def test_migrate_refuses_two_files_of_one_configuration_and_foreign_files(tmp_path: Path, capsys) -> None:
    old, new_name = _old_named_copy(tmp_path / "r")
    (old.parent / new_name).write_bytes(old.read_bytes())
    assert main(["migrate", str(old.parent)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "same configuration" in err and old.exists()
    (old.parent / new_name).unlink()
    (old.parent / "notes.json").write_text("[1, 2]")
    assert main(["migrate", str(old.parent)]) == 2
    assert "notes.json" in capsys.readouterr().err and old.exists()
    assert main(["migrate", str(tmp_path / "missing")]) == 2
