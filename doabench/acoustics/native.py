"""The compiled image-source kernel (``image_sources.c``): built on first use, loaded with ctypes.

The builtin engine's per-image work is one fused loop in C when a C compiler is available
(``cc``, ``gcc`` or ``clang``, or ``$CC``), and the torch path of :func:`rir.render_images`
otherwise. Both approximate the same model (the kernel rounds arrivals to 1/128 sample, the
torch path interpolates between 1/8-sample phases); they agree to about 1e-2 of the peak sample
(tested), and each is bitwise reproducible on its own. ``doabench`` records which one ran in the simulator's
provenance (:func:`kernel_name`).

Why not a library: numba is not one of doabench's dependencies, and ``torch.compile`` (inductor)
needs seconds to minutes of compilation per process and shape and cannot fuse the scattered
additions. The kernel is 80 lines of C without Python headers, so any C compiler builds it in
well under a second; the shared object is cached per source, compiler and CPU under
``$DOABENCH_CACHE`` (default ``$XDG_CACHE_HOME/doabench`` or ``~/.cache/doabench``) and written
atomically (several worker processes may build it at once).

Loading a shared object runs its code, so one is loaded only from a **private** folder: a folder
(not a symbolic link) that the current user owns and that neither group nor others may write,
holding a regular file (not a link) of that user's without group or other write bits. The cache
folder is created so (mode 0700). A cached file that fails the check is built again in place; a
cache folder that fails it (or that cannot be created or written) is not used at all: the kernel
is built afresh in a new private temporary folder (``tempfile.mkdtemp``), loaded from there and
the folder removed. No file that another user could have placed is ever loaded.

``DOABENCH_NATIVE=0`` turns the kernel off (the torch path runs).
"""
from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import platform
import shutil
import stat
import subprocess
import tempfile
import threading
from importlib import resources
from pathlib import Path
from typing import Iterator

import numpy as np

SOURCE = "image_sources.c"
KERNEL_VERSION = 5  # doabench_image_kernel_version() of the source
FLAGS = ["-O3", "-march=native", "-ffp-contract=off", "-fno-math-errno", "-shared", "-fPIC"]
_HALF, _OVER = 16, 128  # SINC_HALF and KERNEL_PHASES (rir.py) as compiled into the C source
_TAPS = 32  # samples per image in the C source (2 * SINC_HALF)
_BLOCK = 64  # DB_BLOCK

_lock = threading.Lock()
_state: dict = {}  # "lib": ctypes.CDLL or None, "why": reason when None


def _cache_dir() -> Path:
    if os.environ.get("DOABENCH_CACHE"):
        return Path(os.environ["DOABENCH_CACHE"]) / "native"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "doabench" / "native"


def _compiler() -> str | None:
    for name in [os.environ.get("CC"), "cc", "gcc", "clang"]:
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def _cpu_signature() -> str:
    """What -march=native depends on: the CPU's feature flags (Linux) or its name."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("flags", "Features")):
                return line
    except OSError:
        pass
    return platform.machine() + platform.processor()


def _private(path: Path, kind: int) -> bool:
    """``path`` is a ``kind`` (``stat.S_IFDIR`` or ``stat.S_IFREG``), not a symbolic link, owned by
    the current user, with no group or other write bit."""
    try:
        st = os.lstat(path)
    except OSError:
        return False
    return stat.S_IFMT(st.st_mode) == kind and st.st_uid == os.getuid() and not st.st_mode & 0o022


def _private_folder(folder: Path) -> bool:
    """Create ``folder`` (mode 0700) if it is missing; whether it is private (:func:`_private`)."""
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        folder.mkdir(mode=0o700)
    except FileExistsError:
        pass
    except OSError:  # a read-only or unusable cache location
        return False
    return _private(folder, stat.S_IFDIR)


def _build(cc: str, source: bytes, target: Path) -> None:
    """Compile into ``target``'s folder (a private one), then rename into place: the file is the
    current user's, mode 0700."""
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        src = Path(tmp) / SOURCE
        src.write_bytes(source)
        obj = Path(tmp) / target.name
        subprocess.run([cc, *FLAGS, "-o", str(obj), str(src), "-lm"], check=True,
                       capture_output=True, timeout=120)
        os.chmod(obj, 0o700)
        os.replace(obj, target)  # atomic: concurrent builders write the same bytes


def _cached(cc: str, source: bytes, target: Path) -> ctypes.CDLL | None:
    """The kernel from the private cache folder of ``target``: loaded when the file there passes
    :func:`_private`, else built there first; None when that folder cannot be used."""
    if not _private_folder(target.parent):
        return None
    try:
        if not _private(target, stat.S_IFREG):  # missing, or not a file only this user can change
            _build(cc, source, target)
        try:
            return ctypes.CDLL(str(target))
        except OSError:  # a damaged cache file (e.g. cut short by a crash): build it again, once
            _build(cc, source, target)
            return ctypes.CDLL(str(target))
    except OSError:  # a cache folder this user may not write after all (read-only, full): build elsewhere
        return None


def _fresh(cc: str, source: bytes, name: str) -> ctypes.CDLL:
    """The kernel built afresh in a new private temporary folder, loaded, the folder removed."""
    folder = Path(tempfile.mkdtemp(prefix="doabench-native-"))
    try:
        target = folder / name
        _build(cc, source, target)
        return ctypes.CDLL(str(target))
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _load():
    if os.environ.get("DOABENCH_NATIVE", "1") == "0":
        return None, "turned off by DOABENCH_NATIVE=0"
    cc = _compiler()
    if cc is None:
        return None, "no C compiler found (cc, gcc, clang or $CC)"
    source = resources.files("doabench.acoustics").joinpath(SOURCE).read_bytes()
    try:
        version = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"{cc} --version failed: {exc}"
    key = hashlib.sha256(b"\0".join([source, version.encode(), " ".join(FLAGS).encode(),
                                     _cpu_signature().encode()])).hexdigest()[:20]
    name = f"image_sources-{key}.so"
    try:
        lib = _cached(cc, source, _cache_dir() / name) or _fresh(cc, source, name)
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"building {SOURCE} failed: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
    if lib.doabench_image_kernel_version() != KERNEL_VERSION:
        return None, "stale kernel"
    i64, f32, ptr = ctypes.c_int64, ctypes.c_float, ctypes.c_void_p
    lib.doabench_render_images.restype = ctypes.c_int
    lib.doabench_render_images.argtypes = [i64, i64, i64, ptr, ptr, ptr, ptr, ptr, f32, f32, ptr, ptr, i64,
                                           i64, ptr, i64]
    return lib, ""


def library():
    """The loaded kernel library, or None (the reason in :func:`unavailable_reason`)."""
    with _lock:
        if "lib" not in _state:
            _state["lib"], _state["why"] = _load()
        return _state["lib"]


@contextlib.contextmanager
def disabled(reason: str = "turned off for this block") -> Iterator[None]:
    """Run the block on the torch path, as ``DOABENCH_NATIVE=0`` does, then restore the kernel that
    was loaded (to compare the two paths in one process)."""
    library()
    with _lock:
        saved = dict(_state)
        _state.update(lib=None, why=reason)
    try:
        yield
    finally:
        with _lock:
            _state.clear()
            _state.update(saved)


def reload() -> None:
    """Forget the loaded kernel, so that the next use reads ``DOABENCH_NATIVE`` and builds or loads
    the kernel again."""
    with _lock:
        _state.clear()


def unavailable_reason() -> str:
    library()
    return _state["why"]


def kernel_name() -> str:
    """``"c"`` when the compiled kernel runs on CPU, else ``"torch"`` (for provenance)."""
    return "c" if library() is not None else "torch"


def tap_table(windowed_sinc, half: int, over: int) -> np.ndarray:
    """``(over, 2 half)`` float32: row ``ph`` holds ``windowed_sinc(n - (half - 1) - ph / over)``,
    the taps of an image arriving ``ph / over`` samples after an integer sample time."""
    if (half, over) != (_HALF, _OVER):
        raise ValueError(f"the C kernel is built for SINC_HALF {_HALF} and {_OVER} phases")
    n = np.arange(_TAPS)[None, :]
    ph = np.arange(over)[:, None]
    return np.ascontiguousarray(windowed_sinc(n - (half - 1) - ph / over, half), dtype=np.float32)


def render(lib, src: np.ndarray, mic: np.ndarray, sign: np.ndarray, offset: np.ndarray, gain: np.ndarray,
           reach2: float, scale: float, table: np.ndarray, out: np.ndarray, n_out: int) -> None:
    """Call the kernel. Arrays float32 C-contiguous: ``src`` (P, 3), ``mic`` (M, 3) shared by every
    point or (P, M, 3) per point (a moving array), ``sign`` and ``offset`` (I, 3), ``gain`` (I,),
    ``table`` (:func:`tap_table`); ``out`` (P, M, stride) with contiguous rows (its first ``n_out``
    samples per row are written)."""
    per_point = mic.ndim == 3
    P, M, I = src.shape[0], mic.shape[-2], gain.shape[0]
    if per_point and mic.shape[0] != P:
        raise ValueError("per-point microphones must have one (M, 3) set per source point")
    arrays = (src, mic, sign, offset, gain, table)
    # Real checks, not asserts (python -O strips those): a wrong layout would write out of bounds.
    if not all(a.dtype == np.float32 and a.flags.c_contiguous for a in arrays):
        raise ValueError("image kernel inputs must be C-contiguous float32 arrays")
    if (src.shape[1:], mic.shape[-1:], sign.shape, offset.shape, table.shape) != (
            (3,), (3,), (I, 3), (I, 3), (_OVER, _TAPS)):
        raise ValueError("image kernel inputs have the wrong shapes")
    if not (out.dtype == np.float32 and out.ndim == 3 and out.shape[:2] == (P, M) and out.shape[2] >= n_out >= 0
            and out.strides == (M * out.shape[2] * 4, out.shape[2] * 4, 4)):
        raise ValueError("image kernel output must be float32 (P, M, >= n_out) with contiguous rows")
    work = np.empty(4 * (I + _BLOCK), dtype=np.float32)
    lib.doabench_render_images(P, M, I, *(a.ctypes.data for a in arrays[:5]), float(reach2), float(scale),
                               table.ctypes.data, out.ctypes.data, n_out, out.shape[2], work.ctypes.data,
                               3 * M if per_point else 0)
