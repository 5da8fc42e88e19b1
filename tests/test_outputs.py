"""The output rule and failed writes: a regular or new file is replaced atomically, a stream (``-``,
a FIFO, a character device) is written through, a symbolic link is followed and kept; a full disk,
a read-only folder, a refused permission or a quota is one line (exit 2) naming the path and the
reason, with no partial file and an earlier good file intact, and journals stay resumable.

The full-disk cases run for real on a small tmpfs where the tests may mount one (root), else skip
with the reason; the other reasons are injected as the OSError the system would raise."""
from __future__ import annotations

import ast
import contextlib
import errno
import json
import os
import stat
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from doabench.cli.main import main
from doabench.errors import OutputError
from doabench.files import atomic_path, resolve_output, write_text

from conftest import ROOT, tiny_task_toml

RUN = ["--tracker", "srp-max:4x8", "--task", "sim-demo", "--episodes", "2", "--quiet"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """Two seconds of noise on the NAO array's 12 channels: enough frames for `doabench track`."""
    path = tmp_path_factory.mktemp("rec") / "rec.wav"
    sf.write(str(path), np.random.default_rng(0).standard_normal((32000, 12)).astype(np.float32) * 0.1, 16000)
    return path


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _no_debris(folder: Path) -> None:
    left = [p.name for p in folder.iterdir() if p.name.startswith(".") or p.name.endswith((".tmp", ".partial"))]
    assert not left, f"temporary files left in {folder}: {left}"


@contextlib.contextmanager
def small_tmpfs(folder: Path, size: str):
    """A tmpfs of ``size`` mounted at ``folder`` (skips without root or where mounting is refused)."""
    if os.geteuid() != 0:
        pytest.skip("a real full disk needs a small tmpfs, and mounting one needs root")
    folder.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)], capture_output=True,
                          text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip() or done.returncode})")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def remount(folder: Path, options: str) -> None:
    subprocess.run(["mount", "-o", f"remount,{options}", str(folder)], check=True)


def fill(folder: Path) -> None:
    """Use up every free byte of ``folder``'s file system."""
    with open(folder / "filler", "wb", buffering=0) as f:
        with contextlib.suppress(OSError):
            while True:
                f.write(b"\0" * 512)


# -- the rule --------------------------------------------------------------------------------------
def test_resolve_output_classifies_every_kind_of_path(tmp_path):
    regular = tmp_path / "a.csv"
    regular.write_text("x")
    assert resolve_output(regular) == resolve_output(regular)  # a plain value
    assert not resolve_output(regular).stream and resolve_output(regular).path == regular
    assert not resolve_output(tmp_path / "new.csv").stream
    assert resolve_output("-").stream and resolve_output("-").stdout
    os.mkfifo(tmp_path / "fifo")
    assert resolve_output(tmp_path / "fifo").stream
    assert resolve_output("/dev/null").stream and resolve_output("/dev/stdout").stream
    (tmp_path / "link.csv").symlink_to("a.csv")
    assert resolve_output(tmp_path / "link.csv").path == regular.resolve()
    (tmp_path / "new-link.csv").symlink_to("b.csv")  # dangling, in an existing folder: the target is made
    assert resolve_output(tmp_path / "new-link.csv").path == (tmp_path / "b.csv").resolve()
    (tmp_path / "lost.csv").symlink_to("missing/c.csv")
    (tmp_path / "loop.csv").symlink_to("loop.csv")
    for refused, why in ((tmp_path, "is a folder"), (tmp_path / "lost.csv", "whose folder does not exist"),
                         (tmp_path / "loop.csv", "cannot be followed")):
        with pytest.raises(OutputError, match=why):
            resolve_output(refused)


def test_a_symlink_is_followed_and_kept(tmp_path, recording, capsys):
    target = tmp_path / "real.csv"
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to("real.csv")
    assert main(["track", str(recording), "--out", str(link)]) == 0
    assert link.is_symlink() and os.readlink(link) == "real.csv"
    assert target.read_text().startswith("time_s,")
    # a dangling link into an existing folder: its target is created, the link stays
    (tmp_path / "to-new.csv").symlink_to("made.csv")
    assert main(["track", str(recording), "--out", str(tmp_path / "to-new.csv")]) == 0
    assert (tmp_path / "to-new.csv").is_symlink() and (tmp_path / "made.csv").read_text().startswith("time_s,")
    # a link into a folder that does not exist is refused, and left as it is
    (tmp_path / "lost.csv").symlink_to("nowhere/x.csv")
    capsys.readouterr()
    assert main(["track", str(recording), "--out", str(tmp_path / "lost.csv")]) == 2
    assert "symbolic link" in _one_line(capsys.readouterr().err)
    assert (tmp_path / "lost.csv").is_symlink() and not (tmp_path / "nowhere").exists()
    _no_debris(tmp_path)


def test_a_fifo_and_a_character_device_are_written_through(tmp_path, recording, capsys):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    received: list[bytes] = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()))
    reader.start()
    assert main(["track", str(recording), "--out", str(fifo)]) == 0
    reader.join(30)
    assert stat.S_ISFIFO(fifo.lstat().st_mode)  # still the FIFO, not a file renamed over it
    assert received and received[0].decode().startswith("time_s,") and len(received[0].splitlines()) == 11
    before = os.stat("/dev/null")
    assert main(["track", str(recording), "--out", "/dev/null"]) == 0
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and (after.st_ino, after.st_rdev) == (before.st_ino, before.st_rdev)
    assert not list(Path("/dev").glob(".null.*"))
    _no_debris(tmp_path)


@pytest.mark.parametrize("out", ["-", "/dev/stdout"])
def test_out_to_standard_output_pipes_the_data_and_keeps_messages_apart(out, recording):
    done = subprocess.run([sys.executable, "-m", "doabench", "track", str(recording), "--out", out],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("time_s,elevation_deg") and len(lines) == 11  # the CSV alone
    assert "wrote" in done.stderr  # the command's own message went to stderr


def test_dev_full_is_a_one_line_error_and_stays_a_device(recording, capsys):
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full on this system")
    assert main(["track", str(recording), "--out", "/dev/full"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "/dev/full" in line and "No space left on device" in line
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)


def test_streams_and_symlinks_for_other_writers(tmp_path):
    """The helper itself, as HDF5, matplotlib, numpy and JSON writers use it."""
    os.mkfifo(tmp_path / "fifo")
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append((tmp_path / "fifo").read_bytes()))
    reader.start()
    with atomic_path(tmp_path / "fifo", suffix=".npy") as tmp:
        np.save(tmp, np.arange(5))
    reader.join(30)
    assert got[0].startswith(b"\x93NUMPY")
    (tmp_path / "data.json").write_text("{}")
    (tmp_path / "link.json").symlink_to("data.json")
    write_text(tmp_path / "link.json", '{"a": 1}\n')
    assert (tmp_path / "link.json").is_symlink() and json.loads((tmp_path / "data.json").read_text()) == {"a": 1}


def test_folder_outputs_refuse_streams_and_follow_links(tmp_path, capsys):
    assert main(["run", *RUN, "--out", "-"]) == 2
    assert "folder" in _one_line(capsys.readouterr().err) and not Path("-").exists()
    real = tmp_path / "real"
    real.mkdir()
    (tmp_path / "results").symlink_to("real")
    assert main(["run", *RUN, "--out", str(tmp_path / "results")]) == 0
    assert (tmp_path / "results").is_symlink() and list(real.glob("*.json"))


_WRITE_CALLS = {"to_csv", "savefig", "save_file", "savez", "save", "write_text", "write_bytes", "export",
                "write"}


def _writes_outside_the_helper(path: Path) -> list[str]:
    """Calls that write a file by name (``open(p, "w")``, ``x.to_csv(p)``, ``h5py.File(p, "w")``,
    ``p.write_text(...)``, ``save_file(t, p)``, ...) where no argument is a name bound by
    ``atomic_path(...) as NAME`` (or by a ``with open(NAME...) as fh`` inside it), nor an
    in-memory ``io.BytesIO()`` buffer."""
    tree = ast.parse(path.read_text(encoding="utf-8"))

    def called(node: ast.AST) -> str:
        func = node.func if isinstance(node, ast.Call) else None
        return getattr(func, "attr", getattr(func, "id", "")) if func is not None else ""

    def names(node: ast.AST) -> set[str]:
        return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}

    bound = {t.id for node in ast.walk(tree) if isinstance(node, ast.Assign) and called(node.value) == "BytesIO"
             for t in node.targets if isinstance(t, ast.Name)}
    withs = [item for node in ast.walk(tree) if isinstance(node, (ast.With, ast.AsyncWith)) for item in node.items
             if isinstance(item.optional_vars, ast.Name) and isinstance(item.context_expr, ast.Call)]
    bound |= {item.optional_vars.id for item in withs if called(item.context_expr) == "atomic_path"}
    for _ in range(3):  # `with open(tmp, "wb") as fh` inside the block: fh is the temporary file too
        bound |= {item.optional_vars.id for item in withs if names(item.context_expr) & bound}

    def ok(node: ast.Call) -> bool:
        return any(names(arg) & bound for arg in [*node.args, *(k.value for k in node.keywords)])

    bad = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = called(node)
        mode = next((a.value for a in node.args[1:2] if isinstance(a, ast.Constant)), None)
        mode = next((k.value.value for k in node.keywords if k.arg == "mode" and isinstance(k.value, ast.Constant)),
                    mode)
        if name in ("write_text", "write_bytes"):  # Path(...).write_text: the receiver is the file
            if isinstance(node.func, ast.Attribute) and not names(node.func.value) & bound:
                bad.append(f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{node.lineno}")
            continue
        writes = ((name in ("open", "File") and isinstance(mode, str) and any(c in mode for c in "wax+"))
                  or (name in ("to_csv", "savefig", "save_file", "savez", "save") and node.args))
        if writes and not ok(node):
            bad.append(f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{node.lineno}")
    return bad


# Writers that are not outputs of a command: the file system's own protocols, each with a reason.
_ALLOWED = {
    "files.py",      # the helper itself
    "download.py",   # a resumable download appends to its own .part file, renamed when its checksum matches
    "native.py",     # the compiled kernel cache: written by the C compiler, renamed into place
}


def test_the_writer_check_sees_a_write_by_name(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("import io\nfrom doabench.files import atomic_path\n"
                      "def f(df, fig, path):\n"
                      "    df.to_csv(path)\n"                       # 4: bypasses the rule
                      "    with atomic_path(path) as tmp:\n"
                      "        fig.savefig(tmp)\n"
                      "        with open(tmp, 'w') as fh:\n"
                      "            fh.write('x')\n"
                      "    open(path, 'a').write('x')\n"            # 9: bypasses the rule
                      "    buf = io.BytesIO()\n"
                      "    fig.savefig(buf)\n"
                      "    path.write_text('x')\n")                 # 12: bypasses the rule
    assert sorted(int(h.rsplit(":", 1)[1]) for h in _writes_outside_the_helper(module)) == [4, 9, 12]


def test_every_writer_goes_through_the_output_rule():
    sources = sorted([*(ROOT / "doabench").rglob("*.py"), *(ROOT / "baselines").glob("*.py")])
    bad = [hit for path in sources if path.name not in _ALLOWED for hit in _writes_outside_the_helper(path)]
    assert not bad, f"files written without doabench.files.atomic_path: {bad}"


# -- failed writes -----------------------------------------------------------------------------------
def test_full_disk_track_keeps_the_earlier_file(tmp_path, recording, capsys):
    with small_tmpfs(tmp_path / "disk", "64k") as disk:
        good = disk / "o.csv"
        good.write_text("an earlier good file\n")
        fill(disk)
        assert main(["track", str(recording), "--out", str(good)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert str(good) in line and "No space left on device" in line
        assert good.read_text() == "an earlier good file\n"
        assert sorted(p.name for p in disk.iterdir()) == ["filler", "o.csv"]


def _scores(results: dict) -> tuple:
    """What a run computes, without its timings."""
    rows = [{k: v for k, v in row.items() if k != "tracker_s"} for row in results["episodes"]]
    return results["summary"], rows, results["frames"]


def test_full_disk_run_stops_cleanly_and_resumes_to_the_same_result(tmp_path, capsys):
    assert main(["run", *RUN, "--episodes", "4", "--out", str(tmp_path / "straight")]) == 0
    straight = json.loads(next((tmp_path / "straight").glob("*.json")).read_text())
    with small_tmpfs(tmp_path / "disk", "32k") as disk:
        out = disk / "r"
        capsys.readouterr()
        assert main(["run", *RUN, "--episodes", "4", "--out", str(out)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert str(out) in line and "No space left on device" in line
        journal = next(out.glob(".*.partial.jsonl"))
        for text in journal.read_text().splitlines():  # whole lines only: resumable
            json.loads(text)
        assert not list(out.glob("*.json")) and not list(out.glob("*.lock"))
        remount(disk, "size=2m")
        assert main(["run", *RUN, "--episodes", "4", "--out", str(out)]) == 0
        resumed = json.loads(next(out.glob("*.json")).read_text())
        assert _scores(resumed) == _scores(straight)
        _no_debris(out)


TASK_TOML = tiny_task_toml("out-tiny-test", episodes=3, base_seed=31)


def _episodes(path: Path) -> list:
    from doabench.datasets import DatasetFile
    from doabench.datasets.layout import read_episode

    with DatasetFile(path) as f:
        return [read_episode(f.file["episodes"][f"{i:06d}"]) for i in f.indices]


def test_full_disk_make_dataset_is_one_line_and_resumes(tmp_path):
    """HDF5 crashes the process when the disk fills under it: the parts are built in memory and
    the assembly's space is reserved first, so the command stops with one line instead."""
    (tmp_path / "tasks").mkdir()
    (tmp_path / "tasks" / "out-tiny-test.toml").write_text(TASK_TOML)
    env = dict(os.environ, DOABENCH_TASK_PATH=str(tmp_path / "tasks"), PYTHONPATH=str(ROOT))

    def make(out: Path) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "doabench", "make-dataset", "--task", "out-tiny-test",
                               "--features", "srp:4x8,audio", "--out", str(out), "--quiet"], env=env,
                              capture_output=True, text=True, timeout=600)

    assert make(tmp_path / "straight.h5").returncode == 0
    with small_tmpfs(tmp_path / "disk", "64k") as disk:
        out = disk / "d.h5"
        for size in ("64k", "1m"):  # a part does not fit; then the parts fit but the assembly does not
            remount(disk, f"size={size}")
            done = make(out)
            assert done.returncode == 2, done.stderr
            line = _one_line(done.stderr)
            assert "No space left on device" in line and str(disk) in line
            assert not out.exists() and not list(disk.rglob("*.tmp")) and not list(disk.glob("*.partial"))
        remount(disk, "size=8m")
        done = make(out)
        assert done.returncode == 0, done.stderr
        assert "from an earlier run" in done.stdout
        a, b = _episodes(tmp_path / "straight.h5"), _episodes(out)
        assert len(a) == len(b) == 3
        for x, y in zip(a, b):
            assert x.arrays.keys() == y.arrays.keys()
            assert all(np.array_equal(x.arrays[k], y.arrays[k]) for k in x.arrays)


def test_full_disk_checkpoint_keeps_the_previous_one(tmp_path):
    import torch

    from doabench.training import checkpoint as ckpt

    state = {"epoch": 1, "model": {"w": torch.ones(3)}, "best_model": None,
             "optimizer": {"state": {}, "param_groups": [{"lr": 0.1, "params": [0]}]},
             "rng": ckpt.rng_state(), "recipe": {}, "tracker": "t", "task": "x", "history": [], "best": 1.0,
             "compute_s": 0.0, "trajectories_seen": 0}
    with small_tmpfs(tmp_path / "disk", "256k") as disk:
        path = disk / ckpt.LATEST
        ckpt.save_checkpoint(path, state)
        fill(disk)
        bigger = dict(state, epoch=2, model={"w": torch.ones(200_000)})
        with pytest.raises(OutputError, match="No space left on device"):
            ckpt.save_checkpoint(path, bigger)
        assert ckpt.load_checkpoint(path)["epoch"] == 1
        assert sorted(p.name for p in disk.iterdir()) == [ckpt.LATEST, "filler"]


def test_read_only_folder_is_one_line_and_the_file_stays(tmp_path, recording, capsys):
    with small_tmpfs(tmp_path / "disk", "1m") as disk:
        good = disk / "o.csv"
        good.write_text("kept\n")
        remount(disk, "ro")
        assert main(["track", str(recording), "--out", str(good)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert str(good) in line and "read-only file system" in line
        assert good.read_text() == "kept\n"
        # past the early check (as when the folder turns read-only during the work): the write itself
        with pytest.raises(OutputError, match="Read-only file system"):
            write_text(good, "new\n")
        assert good.read_text() == "kept\n"


@pytest.mark.parametrize("code", [errno.EACCES, errno.EDQUOT, errno.EROFS, errno.ENOSPC])
def test_injected_write_errors_are_one_line_and_leave_no_partial_file(code, tmp_path, recording, capsys,
                                                                     monkeypatch):
    """Permission denied and a quota cannot be made real as root: the writer raises what the
    system would, at the rename (after the data was written) and inside the writer."""
    import pandas as pd

    import doabench.files as files

    good = tmp_path / "o.csv"
    good.write_text("kept\n")

    def refuse(*args, **kwargs):
        raise OSError(code, os.strerror(code))

    with monkeypatch.context() as m:
        m.setattr(files.os, "replace", refuse)
        assert main(["track", str(recording), "--out", str(good)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert str(good) in line and os.strerror(code) in line
    with monkeypatch.context() as m:
        m.setattr(pd.DataFrame, "to_csv", refuse)
        assert main(["track", str(recording), "--out", str(good)]) == 2
    assert os.strerror(code) in _one_line(capsys.readouterr().err)
    assert good.read_text() == "kept\n"
    _no_debris(tmp_path)


def test_injected_journal_write_error_keeps_the_journal_resumable(tmp_path, capsys, monkeypatch):
    """A quota hit while journalling an episode: the cut line is removed, the next run resumes."""
    import doabench.runner.journal as journal

    calls = []
    original = journal.append_line

    def quota_on_second(path, line):
        calls.append(path)
        if len(calls) == 2:
            with open(path, "a") as f:  # what a write cut by the quota leaves: part of the line
                f.write(line[: len(line) // 2])
            raise OutputError(f"cannot write {path}: {os.strerror(errno.EDQUOT)}")
        original(path, line)

    monkeypatch.setattr(journal, "append_line", quota_on_second)
    assert main(["run", *RUN, "--out", str(tmp_path)]) == 2
    assert "Disk quota exceeded" in _one_line(capsys.readouterr().err)
    monkeypatch.setattr(journal, "append_line", original)
    assert main(["run", *RUN, "--out", str(tmp_path)]) == 0
    assert len(json.loads(next(tmp_path.glob("*.json")).read_text())["episodes"]) == 2
    _no_debris(tmp_path)


def test_append_line_cuts_a_failed_line_off(tmp_path, monkeypatch):
    from doabench.files import append_line

    path = tmp_path / "j.jsonl"
    append_line(path, '{"a": 1}')

    class Full:
        def __init__(self, f):
            self.f = f

        def __getattr__(self, name):
            return getattr(self.f, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, data):
            self.f.write(data[:3])  # the kernel took three bytes, then the disk was full
            self.f.flush()
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    real_open = open
    monkeypatch.setattr("builtins.open", lambda *a, **k: Full(real_open(*a, **k)))
    with pytest.raises(OutputError, match="No space left on device"):
        append_line(path, '{"b": 2}')
    monkeypatch.undo()
    assert path.read_text() == '{"a": 1}\n'



def test_a_float_wav_written_in_another_second_has_the_same_bytes(tmp_path):
    """libsndfile stamps float WAVs with the time of writing (the PEAK chunk); doabench's writer
    zeroes the stamp, so a seeded simulation gives the same file whenever it is written."""
    import time

    from doabench.recording import float_wav_bytes

    audio = np.random.default_rng(0).standard_normal((3, 800)).astype(np.float32) * 0.1
    first = float_wav_bytes(audio, 16000)
    time.sleep(1.1)
    assert float_wav_bytes(audio, 16000) == first
    assert b"PEAK" in first[:200]  # the chunk is kept, only its stamp is fixed
    (tmp_path / "a.wav").write_bytes(first)
    data, fs = sf.read(tmp_path / "a.wav", dtype="float32", always_2d=True)
    assert fs == 16000 and np.array_equal(data.T, audio)
