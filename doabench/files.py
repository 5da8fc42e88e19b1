"""Every file doabench writes goes through one rule (:func:`atomic_path`, :func:`resolve_output`).

* A regular file, or a path that does not exist yet, is written **atomically**: a temporary file
  in the target's folder, fsynced, renamed over the target, the folder fsynced. A crash, Ctrl-C,
  SIGTERM or power cut leaves the old file or the new one, never a half-written one.
* ``-`` (standard output), a FIFO, a character device (``/dev/null``, a terminal) and
  ``/dev/stdout``, ``/dev/fd/N``, ``/proc/self/fd/N`` are **written through**: the content goes
  into the stream (opened for appending), without a temporary file beside it and without a rename,
  so ``--out /dev/stdout`` and ``--out -`` pipe and the device node is never replaced.
* A **symbolic link** is followed: its target is written atomically (or through, when it is a
  stream), the link itself is kept. A link that loops, or whose target's folder does not exist,
  is refused; so is a path that names a folder, a block device or a socket.
* A failure to write (full disk, read-only file system, permission denied, quota) is one
  :class:`~doabench.errors.OutputError` naming the path and the reason; the temporary file is
  removed and an earlier file at the path is left as it was.

:func:`exclusive_lock` is the lock file two processes writing the same output take (``doabench
run``'s journal, ``make-dataset``'s parts, ``train``'s run folder): an ``flock`` the kernel
releases when its process dies (so a lock left by a killed process is stale and taken over), with
the owner's pid in the file for the other process's error message.
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
import stat
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from doabench.errors import DoabenchError, InputError, OutputError

#: What ``--out`` takes for standard output.
STDOUT = "-"

# OSError numbers that mean "this output cannot be written here" (not a bug, not a missing input).
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG,
                          errno.EIO, errno.ENXIO, errno.ETXTBSY})
_DESCRIPTOR = re.compile(r"^/(proc/(self|\d+)|dev)/fd/\d+$")
# Libraries that report a failed write in their own exception type, with the errno in the text:
# HDF5 (``errno = 28``), Rust's safetensors (``os error 28``).
_TEXT_ERRNO = re.compile(r"(?:errno = |os error |\[Errno )(\d+)")


def file_stem(text: object, fallback: str = "") -> str:
    """``text`` as a file name part that is safe on every filesystem: runs of characters other than
    letters, digits, ``.``, ``+`` and ``-`` become ``_`` (``cross3d:16x32`` -> ``cross3d_16x32``,
    ``file:data.h5`` -> ``file_data.h5``); ``fallback`` where nothing is left."""
    return re.sub(r"[^A-Za-z0-9.+-]+", "_", str(text)).strip("_") or fallback


def current_umask() -> int:
    """The process umask (read without changing it where /proc allows, else set and restored)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def apply_umask(path: str | Path, folder: bool = False) -> None:
    """Give ``path`` the mode a plain ``open()``/``mkdir()`` would have: 0666 (0777 for a folder)
    less the umask. ``tempfile`` creates 0600 files and 0700 folders whatever the umask."""
    os.chmod(path, (0o777 if folder else 0o666) & ~current_umask())


def fsync_file(path: str | Path) -> None:
    """Flush ``path``'s content to the disk."""
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def fsync_dir(folder: str | Path) -> None:
    """Flush ``folder``'s entries (a rename into it) to the disk, where the platform allows."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# -- the output rule ----------------------------------------------------------------------------
def write_error_reason(exc: BaseException) -> str | None:
    """The reason (``No space left on device``) when ``exc`` says an output cannot be written here
    (full disk, read-only file system, permission, quota), else None. HDF5 and safetensors report
    the errno only in their message (``errno = 28``, ``os error 28``)."""
    if isinstance(exc, DoabenchError):  # already a message for the user
        return None
    code = exc.errno if isinstance(exc, OSError) else None
    if code is None and isinstance(exc, Exception):
        found = _TEXT_ERRNO.search(str(exc))
        code = int(found.group(1)) if found else None
    return os.strerror(code) if code in WRITE_ERRNOS else None


def output_error(path: str | Path, exc: Exception) -> OutputError:
    """The one-line error of an output that could not be written."""
    reason = (write_error_reason(exc) or getattr(exc, "strerror", None) or " ".join(str(exc).split())
              or type(exc).__name__)
    return OutputError(f"cannot write {os.fspath(path)}: {reason}")


def reserve_space(folder: str | Path, nbytes: int, path: str | Path) -> None:
    """Refuse now, with one OutputError naming ``path``, a write of ``nbytes`` that ``folder``'s
    file system or the user's quota cannot hold: the bytes are allocated in a probe file and
    given back. For HDF5, whose library crashes the process on a full disk instead of raising."""
    if nbytes <= 0:
        return
    try:
        fd, name = tempfile.mkstemp(prefix=".doabench-space.", dir=folder)
    except OSError as exc:
        raise output_error(path, exc) from None
    try:
        try:
            os.posix_fallocate(fd, 0, int(nbytes))
        except OSError as exc:
            if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
                raise
            st = os.statvfs(folder)  # no fallocate here: the free space is the best estimate
            if st.f_bavail * st.f_frsize < nbytes:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)) from None
    except OSError as exc:
        raise OutputError(f"cannot write {os.fspath(path)}: {write_error_reason(exc) or exc.strerror} "
                          f"(it needs about {nbytes / 1e6:.1f} MB)") from None
    finally:
        os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(name)


@dataclass(frozen=True)
class Output:
    """How the output named ``given`` is written (see the module docstring)."""

    given: str
    path: Path | None  # where the bytes go (a link's target); None for standard output
    stream: bool       # written through: no temporary file beside it, no rename

    @property
    def stdout(self) -> bool:
        return self.path is None


def _through_descriptor(path: Path) -> bool:
    """True when ``path`` is, or links through, an open file descriptor (``/dev/stdout``,
    ``/dev/fd/N``, ``/proc/self/fd/N``): writing it means writing that descriptor's file."""
    text = str(path)
    for _ in range(40):  # the kernel's own limit on a chain of links
        if _DESCRIPTOR.match(os.path.normpath(os.path.abspath(text))):
            return True
        if not os.path.islink(text):
            return False
        try:
            text = os.path.join(os.path.dirname(text), os.readlink(text))
        except OSError:
            return False
    return False


def resolve_output(path: str | os.PathLike) -> Output:
    """Apply the output rule to ``path``: what is written where, or a one-line OutputError for a
    path doabench never writes (a folder, a block device, a socket, a broken or looping link)."""
    text = os.fspath(path)
    if text == STDOUT:
        return Output(text, None, True)
    p = Path(text)
    if _through_descriptor(p):
        return Output(text, p, True)
    if p.is_symlink():
        try:
            target = Path(os.path.realpath(p, strict=True))
        except FileNotFoundError:  # a dangling link: its target is created, as a shell's > does
            target = Path(os.path.realpath(p))
            if not target.parent.is_dir():
                raise OutputError(f"cannot write {text}: it is a symbolic link to {target}, whose folder does not "
                                  "exist (the link is never replaced)") from None
        except OSError as exc:
            raise OutputError(f"cannot write {text}: it is a symbolic link that cannot be followed "
                              f"({exc.strerror or exc}); the link is never replaced") from None
        p = target
    try:
        mode = p.stat().st_mode
    except OSError:  # a new file; a parent that is not a folder is reported by the write itself
        return Output(text, p, False)
    if stat.S_ISREG(mode):
        return Output(text, p, False)
    if stat.S_ISFIFO(mode) or stat.S_ISCHR(mode):
        return Output(text, p, True)
    kind = ("a folder" if stat.S_ISDIR(mode) else "a block device" if stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    hint = "; give a file name" if stat.S_ISDIR(mode) else ""
    raise OutputError(f"cannot write {text}: it is {kind} (doabench writes regular files, FIFOs, character "
                      f"devices and - for standard output){hint}")


def writes_to_stdout(path: str | os.PathLike | None) -> bool:
    """True when writing ``path`` sends the bytes to this process's standard output (``-``,
    ``/dev/stdout``, a FIFO or terminal that is the same file): the command then prints its own
    messages on standard error, so they do not mix with the data."""
    if path is None:
        return False
    text = os.fspath(path)
    if text == STDOUT:
        return True
    try:
        here, out = os.stat(text), os.fstat(1)
    except (OSError, ValueError):
        return False
    if _through_descriptor(Path(text)) or stat.S_ISFIFO(here.st_mode) or stat.S_ISCHR(here.st_mode):
        return (here.st_dev, here.st_ino) == (out.st_dev, out.st_ino)
    return False


def _copy_into(out: Output, source: Path) -> None:
    """Write the finished temporary file ``source`` through into the stream ``out``."""
    try:
        if out.path is None:  # standard output
            if sys.__stdout__ is not None:
                sys.__stdout__.flush()
            with open(1, "ab", closefd=False) as dst, open(source, "rb") as src:
                shutil.copyfileobj(src, dst, 1 << 20)
        else:
            # Appending: a terminal or pipe ignores it, and a file behind /dev/stdout keeps what
            # the shell (>>) or this process put there before.
            with open(out.path, "ab") as dst, open(source, "rb") as src:
                shutil.copyfileobj(src, dst, 1 << 20)
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise output_error(out.given, exc) from None


@contextlib.contextmanager
def _stream_path(out: Output, suffix: str | None, reserve: int = 0) -> Iterator[Path]:
    # The writers (HDF5, matplotlib, pandas, safetensors) want a seekable file by name: the output
    # is assembled in the temporary folder ($TMPDIR), then copied into the stream as one piece.
    name = "stdout" if out.path is None else out.path.name
    fd, tmp_name = tempfile.mkstemp(prefix=f"doabench-{name}.", suffix=suffix or Path(name).suffix or ".tmp")
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        reserve_space(tmp.parent, reserve, f"{out.given} (its temporary copy {tmp})")
        try:
            yield tmp
        except Exception as exc:
            if write_error_reason(exc):
                raise output_error(f"{out.given} (its temporary copy {tmp})", exc) from None
            raise
        _copy_into(out, tmp)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None, tmp: str | Path | None = None,
                reserve: int = 0) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s content into; the one helper for every file
    doabench writes (the rule is the module docstring's).

    For a regular or new file the temporary file is in the target's folder (the link's target's,
    for a symbolic link); on success it is fsynced, replaces the target atomically and the folder
    is fsynced. It is a fresh ``.<name>.XXXX<suffix>`` (mode as a plain ``open()`` gives), or
    ``tmp``'s name when the caller needs a name it recognises later (a stale one is removed first).
    For a stream it is in ``$TMPDIR`` and is copied into the stream at the end. It never outlives
    the block. Writing fails with one OutputError naming ``path`` and the reason. ``reserve``: the
    bytes the file will need at most, checked free (:func:`reserve_space`) before the block runs."""
    out = resolve_output(path)
    if out.stream:
        with _stream_path(out, suffix, reserve) as through:
            yield through
        return
    target = out.path
    assert target is not None, "standard output is a stream"
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        if tmp is None:
            fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or target.suffix or ".tmp",
                                        dir=target.parent)
            os.close(fd)
            tmp_path = Path(name)
        else:
            tmp_path = target.parent / Path(tmp).name  # beside the target, so the rename stays in its file system
            tmp_path.unlink(missing_ok=True)
    except OSError as exc:
        raise output_error(path, exc) from None
    try:
        reserve_space(target.parent, reserve, path)
        try:
            yield tmp_path
        except Exception as exc:
            if write_error_reason(exc):
                raise output_error(path, exc) from None
            raise
        try:
            if tmp_path.exists():
                if tmp is None:
                    apply_umask(tmp_path)
                fsync_file(tmp_path)
            os.replace(tmp_path, target)
        except OSError as exc:
            raise output_error(path, exc) from None
        fsync_dir(target.parent)
    finally:
        with contextlib.suppress(OSError):
            tmp_path.unlink()


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def to_json(obj: Any, indent: int | None = 2) -> str:
    return json.dumps(obj, indent=indent, default=_default, allow_nan=True)


def write_json(path: str | Path, obj: Any) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(to_json(obj) + "\n")
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def append_line(path: str | Path, line: str) -> None:
    """Append one line to a journal (``line`` without its newline). A failed write (full disk) is
    cut off again, so the journal ends with whole lines and the next run can resume from it."""
    path = Path(path)
    try:
        with open(path, "ab") as f:
            start = f.tell()
            try:
                f.write(line.encode() + b"\n")
                f.flush()
            except OSError:
                with contextlib.suppress(OSError):
                    f.truncate(start)
                raise
    except OSError as exc:
        raise output_error(path, exc) from None


# -- locks --------------------------------------------------------------------------------------
def _lock_owner(fd: int) -> tuple[int | None, str]:
    """The pid recorded in a lock file and its description for a message."""
    with contextlib.suppress(OSError, ValueError, TypeError):
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
        if isinstance(info, dict) and info.get("pid"):
            pid = int(info["pid"])
            return pid, f"pid {pid}" + (f", since {info['started']}" if info.get("started") else "")
    return None, "pid unknown"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


@contextlib.contextmanager
def exclusive_lock(path: str | Path, what: str) -> Iterator[None]:
    """Hold the lock file ``path`` while this process writes ``what``; a second process gets a
    one-line InputError naming the owner's pid. The ``flock`` is released by the kernel when the
    process dies, so a lock file left by a killed process is stale and is simply taken over; the
    file is removed when the block ends."""
    import datetime as _dt
    import fcntl

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise output_error(path, exc) from None
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise output_error(path, exc) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            _, owner = _lock_owner(fd)
            os.close(fd)
            raise InputError(f"another doabench process ({owner}) is writing {what}; wait for it or stop it "
                             f"(lock file {path})") from None
        except OSError as exc:
            if exc.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS):
                os.close(fd)
                raise output_error(path, exc) from None
            # A file system without flock (some network mounts): the pid in the file decides.
            pid, owner = _lock_owner(fd)
            if pid is not None and pid != os.getpid() and _alive(pid):
                os.close(fd)
                raise InputError(f"another doabench process ({owner}) is writing {what}; wait for it or stop it "
                                 f"(lock file {path})") from None
        # The owner may have finished and removed the file between our open and our lock: then
        # this lock is on a file no one else sees, and the path's (new) file is the one to take.
        try:
            here, there = os.fstat(fd), os.stat(path)
            current = (here.st_dev, here.st_ino) == (there.st_dev, there.st_ino)
        except OSError:
            current = False
        if current:
            break
        os.close(fd)
    try:
        with contextlib.suppress(OSError):  # the pid is for messages; a full disk must not stop the lock
            record = {"pid": os.getpid(), "started": _dt.datetime.now().isoformat(timespec="seconds"),
                      "command": " ".join(sys.argv)}
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(record) + "\n").encode(), 0)
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)  # before the unlock: a process that opened it meanwhile sees it is gone
        os.close(fd)
