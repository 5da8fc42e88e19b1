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

``DOABENCH_NATIVE=0`` turns the kernel off (the torch path runs).
"""
from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import platform
import shutil
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


def _build(cc: str, source: bytes, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        src = Path(tmp) / SOURCE
        src.write_bytes(source)
        obj = Path(tmp) / target.name
        subprocess.run([cc, *FLAGS, "-o", str(obj), str(src), "-lm"], check=True,
                       capture_output=True, timeout=120)
        os.replace(obj, target)  # atomic: concurrent builders write the same bytes


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
    target = _cache_dir() / f"image_sources-{key}.so"
    try:
        if not target.exists():
            try:
                _build(cc, source, target)
            except PermissionError:  # a read-only cache folder (e.g. a locked-down home): a private temp one
                target = Path(tempfile.gettempdir()) / f"doabench-native-{os.getuid()}" / target.name
                if not target.exists():
                    _build(cc, source, target)
        try:
            lib = ctypes.CDLL(str(target))
        except OSError:  # a damaged cache file (e.g. cut short by a crash): build it again, once
            target.unlink(missing_ok=True)
            _build(cc, source, target)
            lib = ctypes.CDLL(str(target))
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
