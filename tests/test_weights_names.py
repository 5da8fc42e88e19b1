"""Shipped weights by name (docs/models.md, "Weights by name"): names resolve to the files whose
SHA-256 the training records hold, the default follows the stated rule on the committed results,
bad names and files are refused in one line before any work, and every view prints the name."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from doabench.cli.main import main
from doabench.errors import ConfigError, DoabenchError
from doabench.results.default_weights import choose, headline, judge
from doabench.trackers.registry import canonical_tracker, make_tracker
from doabench_baselines import catalog as C
from doabench_baselines import weights as W

from conftest import ROOT

RUN = ["run", "--task", "sim-demo", "--episodes", "1", "--quiet", "--no-frames"]


def test_every_name_resolves_to_the_file_whose_hash_its_training_record_holds() -> None:
    entries = C.all_named()
    assert {(e.tracker, e.name) for e in entries} >= {("cross3d:16x32", "paper"), ("cross3d:16x32", "moving"),
                                                      ("cross3d:8x16", "moving"), ("gcc-cnn1d", "paper")}
    manifest = W.read_manifest(W.SHIPPED_DIR)
    assert sorted(e.file for e in entries) == sorted(manifest), "every shipped file has a name, and only those"
    for e in entries:
        digest = W.sha256_file(e.path)
        assert digest == manifest[e.file] == e.sha256
        exported = (ROOT / "training-runs" / str(e.run) / "exported.txt").read_text()
        assert f"sha256 {digest}" in exported and e.file in exported, e.run
        model, _, res = e.tracker.partition(":")
        tracker = make_tracker(e.tracker, weights=e.name)
        assert tracker.weights_hash() == digest and tracker.weights_name == e.name
        assert W.read_metadata(e.path)["training"]["task"] == e.task


def test_the_catalog_is_what_the_rule_gives_on_the_committed_results() -> None:
    out = subprocess.run([sys.executable, str(ROOT / "scripts" / "weights_catalog.py"), "--check"],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    defaults = C.read_catalog()["defaults"]
    # today's results: the moving-talker weights keep up (lag <= 0.3 s) and the paper ones do not;
    # of the two that keep up, the longer-trained ones score lower on sim-grid, sim-walk and sim-turn
    assert defaults["cross3d:16x32"] == "moving-long" and defaults["cross3d"] == "cross3d:16x32"
    assert defaults["gcc-cnn1d"] == "paper"


def _results(tracker: str, sha: str, task: str, rmsae: float, lag: float | None, complete: bool = True) -> dict:
    return {"task": {"id": task, "episodes_run": 10 if complete else 5, "episodes_total": 10},
            "tracker": {"id": tracker, "weights_hash": sha, "options": {}},
            "features": {"delays": "nearest"},
            "summary": {"rmsae_all": rmsae, "rmsae_nonsilent": rmsae / 2, "lag_s": lag}}


def test_the_rule_picks_the_lowest_mean_among_the_weights_that_keep_up() -> None:
    runs = [
        # "slow": best on average but lags 0.8 s on sim-walk -> not eligible
        _results("m:8x8", "s" * 64, "sim-grid", 5.0, None), _results("m:8x8", "s" * 64, "sim-walk", 9.0, 0.8),
        _results("m:8x8", "s" * 64, "sim-turn", 9.0, 0.25),
        # "fast" and "steady" keep up; "steady" has the lower mean (10 vs 11)
        _results("m:8x8", "f" * 64, "sim-grid", 9.0, None), _results("m:8x8", "f" * 64, "sim-walk", 12.0, 0.1),
        _results("m:8x8", "f" * 64, "sim-turn", 12.0, 0.3),
        _results("m:8x8", "t" * 64, "sim-grid", 8.0, None), _results("m:8x8", "t" * 64, "sim-walk", 11.0, 0.2),
        _results("m:8x8", "t" * 64, "sim-turn", 11.0, 0.2),
        # "partial": only a partial run of sim-turn -> not eligible
        _results("m:8x8", "p" * 64, "sim-grid", 1.0, None), _results("m:8x8", "p" * 64, "sim-walk", 1.0, 0.1),
        _results("m:8x8", "p" * 64, "sim-turn", 1.0, 0.1, complete=False),
        # another tracker's run with the same hash does not count
        _results("other:8x8", "t" * 64, "sim-grid", 0.1, None),
    ]
    names = {"slow": "s", "fast": "f", "steady": "t", "partial": "p"}
    figures = {n: headline(runs, "m:8x8", c * 64) for n, c in names.items()}
    assert figures["steady"]["sim-grid"]["rmsae_all"] == 8.0
    chosen, verdicts = choose(figures, plain="slow")
    assert chosen == "steady"
    why = {v.name: v.reason for v in verdicts}
    assert "lags 0.80 s on sim-walk" in why["slow"] and "no complete run of sim-turn" in why["partial"]
    assert judge("steady", figures["steady"]).score == pytest.approx(10.0)
    # nothing eligible: the plain weights
    assert choose({"slow": figures["slow"]}, plain="slow")[0] == "slow"
    # an undefined lag (the tracker does not follow) is not eligible either
    no_lag = {**figures["steady"], "sim-turn": {**figures["steady"]["sim-turn"], "lag_s": None}}
    assert not judge("x", no_lag).eligible


def test_names_and_paths_name_one_configuration() -> None:
    by_default = make_tracker("cross3d")
    by_name = make_tracker("cross3d", weights="moving-long")
    by_path = make_tracker("cross3d:16x32", weights=str(W.SHIPPED_DIR / "cross3d-16x32-moving-long.safetensors"))
    assert by_default.weights_hash() == by_name.weights_hash() == by_path.weights_hash()
    for t, text, opts in ((by_default, "cross3d", {}), (by_name, "cross3d", {"weights": "moving-long"}),
                          (by_path, "cross3d:16x32", {"weights": str(by_path.options["weights"])})):
        assert canonical_tracker(text, opts, t) == ("cross3d:16x32", {"weights": "moving-long"})
    paper = make_tracker("cross3d", weights="paper")
    # the plain weights leave no option: their committed results keep their file names
    assert canonical_tracker("cross3d", {"weights": "paper"}, paper) == ("cross3d:16x32", {})
    assert make_tracker("cross3d", weights="default").weights_hash() == by_default.weights_hash()


def test_a_tracker_says_whether_it_loaded_its_default_and_canonical_ids_build_no_second_one(
        tmp_path: Path, monkeypatch) -> None:
    """Whether the loaded file is the default is the instance's answer (the same SHA-256 as the
    default the catalog names, wherever the file was read from); canonical_tracker reads it from the
    instance it is given and builds no other tracker, for the baselines as for a plug-in."""
    from doabench.trackers import registry

    default = make_tracker("cross3d")
    copy = tmp_path / "copy.safetensors"
    shutil.copy(W.SHIPPED_DIR / "cross3d-16x32-moving-long.safetensors", copy)
    by_copy = make_tracker("cross3d:16x32", weights=str(copy))
    assert default.loads_default_weights and by_copy.loads_default_weights
    assert not make_tracker("cross3d", weights="paper").loads_default_weights
    assert not make_tracker("cross3d:16x32", weights="random").loads_default_weights
    plugin = tmp_path / "plug"
    plugin.mkdir()
    (plugin / "own_default.bin").write_bytes(b"the plug-in's default weights")
    (plugin / "weighted_mod.py").write_text(
        "import hashlib\nfrom pathlib import Path\n\nimport doabench\n\n"
        "DEFAULT = Path(__file__).with_name('own_default.bin')\n\n\n"
        "def sha(path):\n    return hashlib.sha256(Path(path).read_bytes()).hexdigest()\n\n\n"
        "class Weighted(doabench.Tracker):\n"
        "    def __init__(self, spec=None, weights=None):\n"
        "        super().__init__(spec, weights=weights)\n"
        "        self.path = Path(weights) if weights else DEFAULT\n\n"
        "    def weights_hash(self):\n        return sha(self.path)\n\n"
        "    @property\n    def loads_default_weights(self):\n        return sha(self.path) == sha(DEFAULT)\n")
    monkeypatch.syspath_prepend(str(plugin))
    plug_copy, other = tmp_path / "plug-copy.bin", tmp_path / "other.bin"
    plug_copy.write_bytes((plugin / "own_default.bin").read_bytes())
    other.write_bytes(b"other weights")
    instances = {str(path): make_tracker("weighted_mod:Weighted", weights=str(path)) for path in (plug_copy, other)}

    def no_second_tracker(*args, **kwargs):
        raise AssertionError("canonical_tracker built a second tracker")

    monkeypatch.setattr(registry, "make_tracker", no_second_tracker)
    assert canonical_tracker("cross3d:16x32", {"weights": str(copy)}, by_copy) == ("cross3d:16x32", {"weights": "moving-long"})
    assert canonical_tracker("weighted_mod:Weighted", {"weights": str(plug_copy)}, instances[str(plug_copy)]) == (
        "weighted_mod:Weighted", {})
    assert canonical_tracker("weighted_mod:Weighted", {"weights": str(other)}, instances[str(other)]) == (
        "weighted_mod:Weighted", {"weights": str(other)})


def test_an_unknown_name_lists_the_names_and_a_name_of_another_tracker_says_whose() -> None:
    with pytest.raises(ConfigError) as exc:
        make_tracker("cross3d:16x32", weights="movng")
    text = str(exc.value)
    names = sorted(e.name for e in C.all_named() if e.tracker == "cross3d:16x32")
    assert {"moving", "paper"} <= set(names)
    assert "\n" not in text and f"its weights names are default, {', '.join(names)} (" in text
    with pytest.raises(ConfigError) as exc:
        make_tracker("cross3d:4x8", weights="moving")
    assert "names weights of cross3d:16x32, cross3d:32x64, cross3d:8x16" in str(exc.value)


def test_a_file_for_another_resolution_is_refused_before_any_work(tmp_path: Path, capsys) -> None:
    out = tmp_path / "r"
    code = main([*RUN, "--tracker", "cross3d:8x16", "--tracker-opt",
                 f"weights={W.SHIPPED_DIR / 'cross3d-16x32-moving.safetensors'}", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "16x32" in err and "8x16" in err
    assert not out.exists()


def test_a_renamed_or_missing_shipped_file_is_refused(tmp_path: Path, monkeypatch) -> None:
    folder = tmp_path / "weights"
    folder.mkdir()
    for name in ("cross3d-16x32.safetensors", "SHA256SUMS", C.CATALOG_NAME):
        shutil.copy(W.SHIPPED_DIR / name, folder / name)
    monkeypatch.setattr(W, "SHIPPED_DIR", folder)
    assert make_tracker("cross3d:16x32", weights="paper").weights_name == "paper"
    with pytest.raises(DoabenchError, match="cross3d-16x32-moving.safetensors does not exist"):
        make_tracker("cross3d:16x32", weights="moving")  # named in the catalog, missing on disk
    (folder / "cross3d-16x32.safetensors").rename(folder / "cross3d-16x32-old.safetensors")
    with pytest.raises(DoabenchError, match="does not exist"):
        make_tracker("cross3d:16x32", weights="paper")
    with pytest.raises(DoabenchError, match="not listed in"):
        make_tracker("cross3d:16x32", weights=str(folder / "cross3d-16x32-old.safetensors"))


def test_run_uses_the_default_says_which_and_records_the_name(tmp_path: Path, capsys) -> None:
    out = tmp_path / "r"
    assert main([*RUN, "--tracker", "cross3d", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "weights: moving-long (sha256 9ffcfd2dc814" in captured.err
    assert "tracker cross3d:16x32 (weights=moving-long)" in captured.out
    (path,) = out.glob("*.json")
    data = json.loads(path.read_text())
    assert path.name == "sim-demo__cross3d_16x32__moving-long.json"  # named by its weights, default or not
    assert data["tracker"]["weights_name"] == "moving-long"
    assert data["tracker"]["options"] == {"weights": "moving-long"}
    assert main([*RUN, "--tracker", "cross3d", "--tracker-opt", "weights=paper", "--out", str(out)]) == 0
    plain = json.loads((out / "sim-demo__cross3d_16x32__paper.json").read_text())
    assert plain["tracker"]["weights_name"] == "paper" and plain["tracker"]["options"] == {}


def test_views_print_the_name_of_committed_results_made_before_names_existed() -> None:
    from doabench.results.labels import run_label
    from doabench.results.schema import load_results
    from doabench.reporting.leaderboard import reproduce_command

    raw = json.loads((ROOT / "results" / "sim-grid__cross3d_16x32__paper.json").read_text())
    assert "weights_name" not in raw["tracker"]  # read through the upgrade of its older schema
    paper = load_results(ROOT / "results" / "sim-grid__cross3d_16x32__paper.json")
    moving = load_results(ROOT / "results" / "sim-grid__cross3d_16x32__moving.json")
    assert run_label(paper) == "cross3d:16x32 (weights=paper)"
    assert run_label(moving) == "cross3d:16x32 (weights=moving)"
    # reproducible by name, whatever the default is now
    assert "--tracker-opt weights=paper" in reproduce_command(paper)
    assert re.search(r"--tracker-opt weights=moving( |$)", reproduce_command(moving))


def test_results_written_before_names_existed_are_named_by_the_catalog() -> None:
    """Reading a results file builds no tracker: a file written before results recorded
    ``tracker.weights_name`` is named, by the upgrade of its schema, from a table of the weights
    that shipped then, which is what the catalog calls them."""
    from doabench.results.upgrade import NAMES_BEFORE_RECORDING

    catalog = {(e.tracker, e.sha256): e.name for e in C.all_named()}
    assert NAMES_BEFORE_RECORDING and all(catalog.get(key) == name for key, name in NAMES_BEFORE_RECORDING.items())
    for path in sorted((ROOT / "results").glob("*.json")):
        tracker = json.loads(path.read_text()).get("tracker") or {}
        if tracker.get("weights_hash") and "weights_name" not in tracker:
            assert (tracker["id"], tracker["weights_hash"]) in NAMES_BEFORE_RECORDING, path.name


def test_list_weights_shows_each_name_its_default_and_figures(capsys) -> None:
    assert main(["list", "weights"]) == 0
    text = capsys.readouterr().out
    line = next(ln for ln in text.splitlines() if ln.startswith("cross3d:16x32") and " moving-long" in ln)
    assert "moving-long *" in line and "sim-train-moving" in line and "17.09, lag 0.10 s" in line
    moving = next(ln for ln in text.splitlines() if ln.startswith("cross3d:16x32") and " moving " in ln)
    assert "*" not in moving and "18.51, lag 0.15 s" in moving
    assert any(ln.startswith("cross3d:16x32") and "paper " in ln and "*" not in ln for ln in text.splitlines())


def test_list_weights_says_for_every_figure_whether_and_why_it_has_a_lag(capsys) -> None:
    """Every figure cell has the lag or says why not, in one wording: a committed run older than the
    lag measurement is "lag not measured", never a bare number beside rows that have a lag."""
    assert main(["list", "weights"]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    header = lines[0].split()
    tasks = [c for c in header if c.startswith("sim-")]
    cell = re.compile(r"^-$|^\d+\.\d\d, (lag \d+\.\d\d s|lag not measured|no lag \((still scenes|not following|"
                      r"no speech)\)|no lag)$")
    rows = [ln for ln in lines[1:] if not ln.startswith("*")]
    for row in rows:
        cells = re.split(r"\s{2,}", row.strip())
        figures = cells[3:3 + len(tasks)]
        assert len(figures) == len(tasks) and all(cell.match(c) for c in figures), row
    paper = next(ln for ln in rows if ln.startswith("cross3d:16x32") and " paper " in ln)
    assert "10.71, lag not measured" in paper and "25.65, lag 0.80 s" in paper
    assert "lag not measured: the committed run predates the lag measurement" in lines[-1]


def test_lag_wordings_follow_the_notes_of_the_runs() -> None:
    from doabench.cli.weights_text import figure_text, lag_legend

    still = {"rmsae_all": 9.5, "lag_s": None, "lag_note": "static source (truth moves below 1 deg/s): no defined lag"}
    stuck = {"rmsae_all": 50.0, "lag_s": None, "lag_note": "not following the talker (RMSAE at ...): no defined lag"}
    old = {"rmsae_all": 10.7, "lag_s": None, "lag_note": "not measured: the run predates the lag measurement"}
    assert figure_text(still) == "9.50, no lag (still scenes)"
    assert figure_text(stuck) == "50.00, no lag (not following)"
    assert figure_text(old) == "10.70, lag not measured"
    assert figure_text({"rmsae_all": 11.0, "lag_s": 0.25}) == "11.00, lag 0.25 s"
    assert figure_text(None) == "-"
    legend = lag_legend([still, old, {"rmsae_all": 1.0, "lag_s": 0.1}])
    assert "no lag (still scenes): the talker does not move" in legend and "lag not measured" in legend
    assert "not following" not in legend


def test_describe_prints_a_summary_of_the_weights_and_json_the_record(capsys) -> None:
    """``describe --tracker`` is a summary of a few lines: the weights by name, the task they trained
    on, the exported epoch, precision, validation and headline figures, the SHA-256; ``--json`` is the
    whole record as before."""
    assert main(["describe", "--tracker", "cross3d:16x32"]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert len(lines) < 30 and not text.lstrip().startswith("{"), text
    assert lines[0] == "cross3d:16x32, weights moving-long (the default of cross3d:16x32)"
    digest = make_tracker("cross3d:16x32").weights_hash()
    fields = {ln[2:16].strip(): ln[17:] for ln in lines if ln.startswith("  ") and not ln.startswith("    ")}
    assert fields["sha256"] == digest
    assert fields["trained on"].startswith("sim-train-moving v1 (recipe paper") and "fine-tuned from moving" in fields["trained on"]
    assert fields["epochs"].startswith("epoch 24 ") and "best by validation RMSAE" in fields["epochs"]
    assert fields["precision"].startswith("bf16")
    assert "25.13 deg all frames" in fields["validation"] and "10.13 deg voice-active" in fields["validation"]
    walk = next(ln for ln in lines if ln.split()[:1] == ["sim-walk"])
    assert "17.09" in walk and "lag 0.10 s" in walk and "720 episodes" in walk
    assert lines[-1] == "The whole record: doabench describe --tracker cross3d:16x32 --json"
    assert main(["describe", "--tracker", "cross3d:16x32", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["weights_name"] == "moving-long" and record["weights_hash"] == digest
    assert record["training"]["epochs_completed"] == 24


def test_describe_summarises_every_kind_of_input_and_refuses_bad_ones_in_one_line(tmp_path: Path, capsys) -> None:
    """Named weights with a run older than the lag, another weights file (its training record, no
    figures), random weights, a classical tracker and a task: each a summary; bad input one line, exit 2."""
    assert main(["describe", "--tracker", "cross3d:16x32", "--tracker-opt", "weights=paper"]) == 0
    paper = capsys.readouterr().out
    assert "weights paper" in paper.splitlines()[0] and "default" not in paper.splitlines()[0]
    assert next(ln for ln in paper.splitlines() if ln.split()[:1] == ["sim-grid"]).split()[4:7] == \
        ["lag", "not", "measured"]
    assert "lag not measured: the committed run predates the lag measurement" in paper

    mine = tmp_path / "mine.safetensors"
    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    shipped = W.SHIPPED_DIR / "cross3d-4x8.safetensors"
    with safe_open(str(shipped), framework="pt") as f:
        meta = f.metadata()
    state = load_file(str(shipped))
    first = sorted(state)[0]
    state[first] = state[first] * 0.5
    save_file(state, str(mine), metadata=meta)
    assert main(["describe", "--tracker", "cross3d:4x8", "--tracker-opt", f"weights={mine}"]) == 0
    other = capsys.readouterr().out
    assert other.splitlines()[0] == f"cross3d:4x8, weights mine.safetensors (sha256 {W.sha256_file(mine)[:12]})"
    assert "sim-train v3" in other and "not a shipped weights file" in other

    assert main(["describe", "--tracker", "cross3d:32x64", "--tracker-opt", "weights=random"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "cross3d:32x64, untrained (random weights)"
    assert main(["describe", "--tracker", "srp-kalman"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "srp-kalman:16x32, no learned weights"
    assert main(["describe", "--task", "sim-walk"]) == 0
    task = capsys.readouterr().out
    assert task.splitlines()[0].startswith("sim-walk v1 (simulated") and "720: 12 cells" in task
    assert main(["describe", "--task", "sim-walk", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["episodes"] == 720

    for argv in (["describe", "--tracker", "cross3d:4x8", "--tracker-opt", "weights=nope"],
                 ["describe", "--tracker", "cross3d:4x8", "--tracker-opt", f"weights={tmp_path / 'missing.safetensors'}"],
                 ["describe", "--task", "sim-nope"], ["describe"]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
