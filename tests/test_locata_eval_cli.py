"""``doabench locata-eval`` on the LOCATA fixture: a perfect submission, one written the way other
tools write them, the truth it writes, and every bad input refused with one line, exit code 2 and
nothing written."""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from doabench.cli.main import main
from doabench.locata import find_recordings
from doabench.locata.stamps import stamp_truth
from doabench.locata.submission import recording_folder, required_calendar, track_text
from fixtures.locata import FS_CORPUS, write_fixture


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("locata-eval")
    recs = write_fixture(root, tasks=(1, 3), duration_s=3.0, simulator="freefield", seed=1)
    return root, {r.task: r for r in recs}


def _perfect(root: Path, out: Path, tasks=(1, 3)) -> Path:
    """A submission whose one track is the truth wherever the source is voice-active."""
    for task in tasks:
        rec = find_recordings(root, "dev", task, "benchmark2")[0]
        truth = stamp_truth(rec)
        az = np.full(len(truth.required_times), np.nan)
        inc = az.copy()
        az[truth.valid] = np.where(truth.vad[0], truth.azimuth[0], np.nan)
        inc[truth.valid] = np.where(truth.vad[0], truth.inclination[0], np.nan)
        folder = recording_folder(out, task, 1, "benchmark2")
        folder.mkdir(parents=True)
        (folder / "source_1.txt").write_text(track_text(required_calendar(rec.required_time_file), az, inc))
        (folder / "telapsed.txt").write_text("0.5\n")
    return out


def _eval(root: Path, submission: Path, out: Path, *extra: str) -> int:
    return main(["locata-eval", "--locata-root", str(root), "--submission", str(submission), "--out", str(out),
                 *extra])


def test_a_perfect_submission_scores_no_error_full_detection_and_no_swap(corpus, tmp_path, capsys):
    root, _ = corpus
    sub = _perfect(root, tmp_path / "sub")
    assert _eval(root, sub, tmp_path / "r.json", "--markdown", str(tmp_path / "r.md")) == 0
    captured = capsys.readouterr()
    data = json.loads((tmp_path / "r.json").read_text())
    assert data["schema"] == "doabench.locata-eval/1" and data["measures"] == "official"
    one = data["recordings"][0]
    assert (one["task"], one["recording"], one["array"]) == (1, 1, "benchmark2")
    source = one["sources"]["loudspeaker1"]
    assert len(source["pd"]) >= 1 and set(source["pd"]) == {1.0}
    assert max(source["az_error_deg"] + source["az_error_ungated_deg"] + source["inc_error_deg"]) < 1e-5
    assert source["swaps"] == 0 and source["swap_rate"] == 0.0 and source["latency_s"] == 0.0
    assert one["far"] == 0.0 and one["far_vap"] == 0.0 and one["mota"] == [0.0]
    assert set(one["ospa_deg"]) == {"1", "1.5", "2", "5"} and max(one["ospa_deg"].values()) < 1e-5
    assert data["tasks"]["1"]["benchmark2"]["pd"] == 1.0 and data["tasks"]["1"]["benchmark2"]["recordings"] == [1]
    # Task 3's talker is active at the first stamp: as released that run has no period (NaN, a warning).
    talker = data["recordings"][1]["sources"]["talker1"]
    assert talker["pd"] == [] and talker["latency_s"] is None and data["tasks"]["3"]["benchmark2"]["pd"] is None
    assert "task 3 recording 1 benchmark2: source talker1 has no voice-active period" in captured.err
    assert "| 1 | benchmark2 | 1 |" in captured.out and "2 recordings scored (official measures)" in captured.out
    assert (tmp_path / "r.md").read_text().startswith("<!-- written by doabench locata-eval -->")
    # Corrected, the run is taken as it is.
    assert _eval(root, sub, tmp_path / "c.json", "--measures", "corrected", "--tasks", "3") == 0
    corrected = json.loads((tmp_path / "c.json").read_text())
    assert [r["task"] for r in corrected["recordings"]] == [3]
    assert set(corrected["recordings"][0]["sources"]["talker1"]["pd"]) == {1.0}
    # An earlier locata-eval output is replaced.
    assert _eval(root, sub, tmp_path / "c.json", "--tasks", "1") == 0


def test_the_truth_written_is_the_scored_stamps_in_locatas_convention(corpus, tmp_path):
    root, recs = corpus
    sub = _perfect(root, tmp_path / "sub", tasks=(3,))
    assert _eval(root, sub, tmp_path / "r.json", "--truth-out", str(tmp_path / "truth")) == 0
    path = tmp_path / "truth" / "task3" / "recording1" / "benchmark2" / "truth_talker1.csv"
    lines = path.read_text().splitlines()
    assert lines[0] == "time_s,azimuth,inclination,vad"
    table = np.array([[float(x) for x in line.split(",")] for line in lines[1:]])
    rec = find_recordings(root, "dev", 3, "benchmark2")[0]
    assert len(table) == int(stamp_truth(rec).valid.sum())  # the valid stamps only
    t, az, inc, vad = table.T
    d = recs[3].motion.directions(t)  # the simulated truth, array frame
    expected_az = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - np.pi / 2)))  # from +y
    assert np.abs(np.angle(np.exp(1j * (az - expected_az)))).max() < 1e-4
    assert np.abs(inc - np.arccos(d[:, 2])).max() < 1e-4
    # the corpus VAD at the array sample nearest each stamp (the array audio starts at 0 s, 48 kHz)
    corpus_vad = np.loadtxt(rec.vad_file("talker1"), skiprows=1)
    nearest = np.clip(np.rint(t * FS_CORPUS).astype(int), 0, len(corpus_vad) - 1)
    assert np.array_equal(vad, corpus_vad[nearest])


def test_a_submission_written_by_another_tool_scores_the_same(corpus, tmp_path):
    """Other tools (the challenge's MATLAB framework) write more columns, CRLF line ends, rows only
    where they have an estimate, and ``NaN`` spelled their way."""
    root, _ = corpus
    ours = _perfect(root, tmp_path / "ours", tasks=(1,))
    theirs = tmp_path / "theirs" / "task1" / "recording1" / "benchmark2"
    theirs.mkdir(parents=True)
    rows = (ours / "task1" / "recording1" / "benchmark2" / "source_1.txt").read_text().splitlines()
    out = ["year\tmonth\tday\thour\tminute\tsecond\tx\ty\tz\tazimuth\televation\tradius"]
    for k, row in enumerate(rows[1:]):
        f = row.split("\t")
        if f[6] == "NaN" and k % 2:
            continue  # a row left out: no estimate there either
        out.append("\t".join(f[:6] + ["0.1", "0.2", "nan", f[6], f[7], "1.5"]))
    (theirs / "source_1.txt").write_text("\r\n".join(out) + "\r\n")
    (theirs / "telapsed.txt").write_text("12.5\r\n")
    assert _eval(root, ours, tmp_path / "a.json") == 0
    assert _eval(root, tmp_path / "theirs", tmp_path / "b.json") == 0
    a, b = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "b.json"))
    assert a["recordings"] == b["recordings"] and a["tasks"] == b["tasks"]


def _edit_line(path: Path, number: int, edit) -> None:
    lines = path.read_text().splitlines()
    lines[number - 1] = edit(lines[number - 1])
    path.write_text("\n".join(lines) + "\n")


def _shift_second(line: str, by: float) -> str:
    f = line.split("\t")
    f[5] = f"{float(f[5]) + by:.6f}"
    return "\t".join(f)


def _degrees(path: Path) -> None:
    lines = path.read_text().splitlines()
    out = [lines[0]]
    for line in lines[1:]:
        f = line.split("\t")
        f[6] = f[6] if f[6] == "NaN" else f"{math.degrees(float(f[6])):.6f}"
        out.append("\t".join(f))
    path.write_text("\n".join(out) + "\n")


def _first_estimate_line(path: Path) -> int:
    return next(n for n, line in enumerate(path.read_text().splitlines(), 1) if n > 1 and "NaN" not in line)


BAD = {
    "no tracks": (lambda f: (f / "source_1.txt").unlink(), "no tracks for this recording"),
    "missing columns": (lambda f: _edit_line(f / "source_1.txt", 10, lambda s: s.rsplit("\t", 1)[0]),
                        "source_1.txt line 10: 7 fields, the header has 8"),
    "no azimuth column": (lambda f: _edit_line(f / "source_1.txt", 1, lambda s: s.replace("azimuth", "azimut")),
                          "source_1.txt line 1: the header lacks column(s) azimuth"),
    "time not a required stamp": (lambda f: _edit_line(f / "source_1.txt", 12, lambda s: _shift_second(s, 0.001)),
                                  "source_1.txt line 12: time"),
    "a stamp twice": (lambda f: _edit_line(f / "source_1.txt", 13, lambda s: s + "\n" + s),
                      "source_1.txt line 14: a second row for the stamp"),
    "degrees as radians": (lambda f: _degrees(f / "source_1.txt"), "is outside [-2pi, 2pi]"),
    "track numbers with a hole": (lambda f: shutil.copy(f / "source_1.txt", f / "source_3.txt"),
                                  "source_2.txt is missing"),
    "not a number": (lambda f: _edit_line(f / "source_1.txt", 20, lambda s: s.rsplit("\t", 1)[0] + "\tabc"),
                     "source_1.txt line 20: 'abc' is not a number"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_is_one_line_exit_2_and_nothing_written(corpus, tmp_path, capsys, case):
    root, _ = corpus
    sub = _perfect(root, tmp_path / "sub", tasks=(1,))
    folder = recording_folder(sub, 1, 1, "benchmark2")
    if case == "degrees as radians":
        expected_line = _first_estimate_line(folder / "source_1.txt")
    edit, message = BAD[case]
    edit(folder)
    capsys.readouterr()
    code = _eval(root, sub, tmp_path / "r.json", "--truth-out", str(tmp_path / "truth"), "--markdown",
                 str(tmp_path / "r.md"))
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith("doabench locata-eval: error:") and message in err, err
    if case == "degrees as radians":
        assert f"source_1.txt line {expected_line}: azimuth" in err
    assert not (tmp_path / "r.json").exists() and not (tmp_path / "r.md").exists()
    assert not (tmp_path / "truth").exists()


def test_an_out_file_locata_eval_did_not_write_is_never_replaced(corpus, tmp_path, capsys):
    root, _ = corpus
    sub = _perfect(root, tmp_path / "sub", tasks=(1,))
    for name, text in (("notes.json", '{"mine": 1}\n'), ("notes.txt", "my notes\n")):
        (tmp_path / name).write_text(text)
        assert _eval(root, sub, tmp_path / name) == 2
        assert "was not written by doabench locata-eval" in capsys.readouterr().err
        assert (tmp_path / name).read_text() == text
    (tmp_path / "table.md").write_text("# mine\n")
    assert _eval(root, sub, tmp_path / "r.json", "--markdown", str(tmp_path / "table.md")) == 2
    assert not (tmp_path / "r.json").exists() and (tmp_path / "table.md").read_text() == "# mine\n"
    foreign = tmp_path / "truth" / "task1" / "recording1" / "benchmark2" / "truth_loudspeaker1.csv"
    foreign.parent.mkdir(parents=True)
    foreign.write_text("a,b\n")
    assert _eval(root, sub, tmp_path / "r.json", "--truth-out", str(tmp_path / "truth")) == 2
    assert not (tmp_path / "r.json").exists() and foreign.read_text() == "a,b\n"


def test_a_submission_without_the_task_or_array_is_refused(corpus, tmp_path, capsys):
    root, _ = corpus
    sub = _perfect(root, tmp_path / "sub", tasks=(1,))
    assert _eval(root, sub, tmp_path / "r.json", "--tasks", "3") == 2
    assert "no tracks for task 3" in capsys.readouterr().err
    assert _eval(root, sub, tmp_path / "r.json", "--arrays", "eigenmike") == 2
    assert "eigenmike" in capsys.readouterr().err
    assert _eval(root, tmp_path / "nowhere", tmp_path / "r.json") == 2
    assert "is not a folder" in capsys.readouterr().err
    assert not (tmp_path / "r.json").exists()


# -- every LOCATA run reports the measures and writes its submission --------------------------------
def test_a_locata_run_reports_the_measures_and_writes_the_submission_locata_eval_scores(corpus, tmp_path, capsys):
    root, _ = corpus
    sub, runs = tmp_path / "sub", tmp_path / "runs"
    assert main(["run", "--tracker", "srp-max:8x16", "--task", "locata-1", "--locata-root", str(root), "--quiet",
                 "--out", str(runs), "--locata-submission", str(sub)]) == 0
    assert "wrote the LOCATA submission of 1 recording(s)" in capsys.readouterr().out
    results = json.loads((runs / "locata-1__srp-max_8x16.json").read_text())
    block = results["locata"]
    assert {"recordings", "official", "corrected", "srp_dnn"} <= set(block)
    assert block["srp_dnn"]["accuracy"] > 0.9 and block["official"]["pd"] > 0.9
    lines = (sub / "task1" / "recording1" / "benchmark2" / "source_1.txt").read_text().splitlines()
    rec = find_recordings(root, "dev", 1, "benchmark2")[0]
    assert len(lines) == len(rec.required_time_file.read_text().splitlines())  # one row per required stamp
    assert lines[1].endswith("\tNaN\tNaN")  # before the first frame has ended
    for mode in ("official", "corrected"):
        assert _eval(root, sub, tmp_path / f"{mode}.json", "--measures", mode) == 0
        scored = json.loads((tmp_path / f"{mode}.json").read_text())
        ours, theirs = block["recordings"][0][mode], scored["recordings"][0]
        assert ours["far"] == pytest.approx(theirs["far"])
        for key in ("az_error_deg", "az_error_ungated_deg", "pd"):
            mine = ours["sources"]["loudspeaker1"][key]
            assert mine == pytest.approx(theirs["sources"]["loudspeaker1"][key], abs=1e-6)
        assert block[mode]["ospa_deg"]["1"] == pytest.approx(scored["tasks"]["1"]["benchmark2"]["ospa_deg"]["1"])
    # the leaderboards show them beside the frame metrics
    from doabench.reporting.leaderboard import build_leaderboards

    pages = build_leaderboards(str(runs))
    row = (f"| `srp-max:8x16` | {block['official']['az_error_ungated_deg']:.2f} | "
           f"{block['corrected']['az_error_ungated_deg']:.2f} | {block['corrected']['pd']:.3f} |")
    assert "### LOCATA challenge measures" in pages["locata-1.md"] and row in pages["locata-1.md"]
    assert "## LOCATA challenge measures of the best runs" in pages["summary.md"]


def test_locata_submission_is_refused_without_frames_or_off_locata(corpus, tmp_path, capsys):
    root, _ = corpus
    base = ["run", "--tracker", "srp-max:4x8", "--quiet", "--out", str(tmp_path / "runs"), "--locata-submission",
            str(tmp_path / "sub")]
    assert main([*base, "--task", "locata-1", "--locata-root", str(root), "--no-frames"]) == 2
    assert "leave out --no-frames" in capsys.readouterr().err
    assert main([*base, "--task", "sim-demo"]) == 2
    assert "applies to LOCATA tasks" in capsys.readouterr().err
    assert not (tmp_path / "sub").exists() and not (tmp_path / "runs").exists()
