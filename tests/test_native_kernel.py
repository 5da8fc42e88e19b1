"""The compiled image-source kernel against an independent float64 evaluation and the torch path."""
from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from doabench.acoustics import native
from doabench.acoustics import compute
from doabench.acoustics import rir as engine
from doabench.acoustics import rir_model
from doabench.acoustics.room import Room
from doabench.acoustics.simulators import get_simulator
from doabench.geometry import SPEED_OF_SOUND

FS = 16000
WEIGHTS = (0.9, 0.6, 0.75, 1.0, 0.55, 0.8)

needs_kernel = pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None,
                                  reason="no C compiler on this machine")


def _scene(t60=0.5, n_points=5):
    room = Room((5.2, 4.1, 2.9), t60, WEIGHTS)
    src = np.linspace([1.0, 1.1, 1.2], [2.6, 3.2, 1.7], n_points)
    mics = np.array([[3.9, 2.5, 1.3], [3.95, 2.45, 1.35], [3.85, 2.55, 1.25]])
    return room, src, mics


def _render(images, src, mics, n_out, use_kernel: bool, out=None):
    lib = native.library()
    try:
        with contextlib.nullcontext() if use_kernel else native.disabled("test"):
            return engine.render_images(images, torch.tensor(src), torch.tensor(mics), FS, n_out, out=out)
    finally:
        assert native.library() is lib


def _reference(images, src, mics, n_out, exact: bool = False):
    """Image by image: gain / (4 pi d) times the windowed sinc (float64) centred on the arrival
    time rounded to 1/KERNEL_PHASES sample (the kernel's model). The arrival is computed in float32
    exactly as the kernel computes it (coordinates relative to the array centre), because
    rounding to the nearest phase turns a 1e-7 difference at a phase boundary into a whole phase."""
    over = engine.KERNEL_PHASES
    out = np.zeros((len(src), len(mics), n_out))
    s = np.arange(n_out)
    centre = mics.mean(0)
    f32 = np.float32
    offset, sign = (images.offset - centre).astype(f32), images.sign.astype(f32)
    scale = f32(FS / SPEED_OF_SOUND * over)
    for p, x in enumerate(src):
        pos = offset + sign * x.astype(f32)
        for m, y in enumerate(mics):
            diff = pos - (y - centre).astype(f32)
            d32 = np.sqrt(diff[:, 0] * diff[:, 0] + diff[:, 1] * diff[:, 1] + diff[:, 2] * diff[:, 2])
            d = np.linalg.norm(images.offset + images.sign * x - y, axis=1)
            arrival = d * FS / SPEED_OF_SOUND if exact else np.floor(d32 * scale + f32(0.5)).astype(np.float64) / over
            w = images.gain / (4 * math.pi * d)
            for wk, tk in zip(w, arrival):
                lo = int(np.floor(tk)) - rir_model.SINC_HALF - 1
                sl = slice(max(lo, 0), max(min(lo + 2 * rir_model.SINC_HALF + 4, n_out), 0))
                out[p, m, sl] += wk * engine.windowed_sinc(s[sl] - tk)
    return out


@needs_kernel
def test_kernel_builds_here():
    assert native.library() is not None, native.unavailable_reason()
    assert engine.image_kernel("cpu") == "c" and get_simulator("builtin").versions()["image_kernel"] == "c"


@needs_kernel
def test_kernel_matches_a_float64_evaluation_and_the_torch_path():
    room, src, mics = _scene(t60=0.3, n_points=2)
    images = rir_model.enumerate_images(room, 12.0)
    n_out = int(12.0 / SPEED_OF_SOUND * FS) - 40
    ref = _reference(images, src, mics, n_out)
    c = _render(images, src, mics, n_out, use_kernel=True).numpy()
    t = _render(images, src, mics, n_out, use_kernel=False).numpy()
    peak = np.abs(ref).max()
    # the same model and the same float32 arrivals: float32 rounding of amplitudes and taps
    assert np.abs(c - ref).max() <= 5e-6 * peak
    # Both approximate the windowed sinc at the exact arrival: the kernel's nearest 1/128-sample
    # phase and the torch path's linear interpolation between 1/8-sample phases each err by at
    # most 5.3e-3 and 6.4e-3 of an image's peak tap; over many images the errors partly cancel.
    exact = _reference(images, src, mics, n_out, exact=True)
    assert np.abs(c - exact).max() <= 6e-3 * peak and np.abs(t - exact).max() <= 6e-3 * peak
    assert np.abs(c - t).max() <= 1e-2 * peak and np.linalg.norm(c - t) <= 1e-2 * np.linalg.norm(c)


@needs_kernel
def test_kernel_is_bitwise_reproducible_and_leaves_padding_alone():
    room, src, mics = _scene()
    images = rir_model.enumerate_images(room, 20.0)
    n_out = 700
    a = torch.full((len(src), len(mics), n_out + 13), 7.0)
    b = torch.full((len(src), len(mics), n_out + 13), 7.0)
    _render(images, src, mics, n_out, use_kernel=True, out=a)
    _render(images, src, mics, n_out, use_kernel=True, out=b)
    assert torch.equal(a, b)
    assert torch.all(a[..., n_out:] == 7.0) and torch.all(a[..., :n_out] != 7.0)


@needs_kernel
def test_simulations_agree_between_kernel_and_torch_path():
    room, src, mics = _scene(t60=0.6, n_points=8)
    x = np.random.default_rng(0).standard_normal(8000)
    sim = get_simulator("builtin")
    y_c = sim.simulate(room, src, mics, x, FS, seed=5)
    with native.disabled("test"):
        assert sim.versions()["image_kernel"] == "torch"
        y_t = sim.simulate(room, src, mics, x, FS, seed=5)
    # two approximations of the same exact model (see the test above)
    assert np.linalg.norm(y_c - y_t) / np.linalg.norm(y_t) < 1e-2


@pytest.fixture
def reloaded_kernel():
    """The kernel loaded afresh in the test (which may change how), and again after it."""
    native.reload()
    yield
    native.reload()


def test_without_a_compiler_the_torch_path_runs(monkeypatch, reloaded_kernel):
    monkeypatch.setattr(native, "_compiler", lambda: None)
    assert native.library() is None and "no C compiler" in native.unavailable_reason()
    assert engine.image_kernel("cpu") == "torch"
    room, src, mics = _scene(t60=0.3, n_points=2)
    h = get_simulator("builtin").rirs(room, src, mics, FS, seed=1)
    assert h.shape[:2] == (2, 3) and np.all(np.isfinite(h))


def test_native_can_be_turned_off(monkeypatch, reloaded_kernel):
    monkeypatch.setenv("DOABENCH_NATIVE", "0")
    assert native.kernel_name() == "torch" and "DOABENCH_NATIVE" in native.unavailable_reason()


@needs_kernel
def test_a_failed_build_falls_back(monkeypatch, tmp_path, reloaded_kernel):
    monkeypatch.setenv("DOABENCH_CACHE", str(tmp_path))
    monkeypatch.setattr(native, "FLAGS", ["--no-such-flag-xyz", *native.FLAGS])
    assert native.library() is None and "failed" in native.unavailable_reason()
    assert not any(tmp_path.rglob("*.so"))  # nothing half-written left behind


@needs_kernel
def test_a_damaged_cached_kernel_is_rebuilt(tmp_path):
    """A cache file cut short (a crash while it was written by something else) is built again.
    In fresh processes: a process that has loaded the library gets the loaded copy back."""
    env = {**os.environ, "DOABENCH_CACHE": str(tmp_path)}
    code = "from doabench.acoustics import native; print(native.kernel_name(), native.unavailable_reason())"

    def kernel() -> str:
        return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                              timeout=120).stdout.strip()

    assert kernel() == "c"
    (so,) = tmp_path.rglob("*.so")
    so.write_bytes(so.read_bytes()[:100])
    assert kernel() == "c" and so.stat().st_size > 100


#: a shared object that says it is the kernel and, when loaded, writes the file its MARKER names
PLANTED_C = """
#include <stdio.h>
__attribute__((constructor)) static void planted(void) {
    FILE *f = fopen(MARKER, "w");
    if (f) { fputs("planted library loaded", f); fclose(f); }
}
long long doabench_image_kernel_version(void) { return 5; }
int doabench_render_images(void) { return 0; }
"""


def _kernel_file_name(tmp_path, monkeypatch) -> str:
    """The cache file name of the kernel on this machine (built once into a scratch cache)."""
    monkeypatch.setenv("DOABENCH_CACHE", str(tmp_path / "scratch"))
    native.reload()
    assert native.library() is not None, native.unavailable_reason()
    (so,) = (tmp_path / "scratch").rglob("*.so")
    native.reload()
    return so.name


def _plant(path, marker) -> None:
    """A library at ``path`` that writes ``marker`` when it is loaded."""
    path.parent.mkdir(parents=True, exist_ok=True)
    src = path.parent / "planted.c"
    src.write_text(f"#define MARKER {json.dumps(str(marker))}\n" + PLANTED_C)
    cc = shutil.which("cc") or shutil.which("gcc")
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(path), str(src)], check=True, capture_output=True)
    src.unlink()


@needs_kernel
def test_a_library_planted_in_the_temp_folder_is_never_loaded(monkeypatch, tmp_path, reloaded_kernel):
    """With a cache folder that cannot be written, the kernel is built in a new private temporary
    folder: a library waiting under a predictable temp path (``doabench-native-<uid>``, where an
    earlier doabench looked) is not loaded, and none is left behind."""
    name = _kernel_file_name(tmp_path, monkeypatch)
    temp, marker = tmp_path / "tmp", tmp_path / "PLANTED_LOADED"
    _plant(temp / f"doabench-native-{os.getuid()}" / name, marker)
    locked = tmp_path / "locked"
    build = native._build

    def refuse_locked(cc, source, target):  # what compiling into a read-only folder raises
        if locked in target.parents:
            raise PermissionError(13, "Permission denied", str(target.parent))
        return build(cc, source, target)

    monkeypatch.setenv("DOABENCH_CACHE", str(locked))
    monkeypatch.setattr(native, "_build", refuse_locked)
    monkeypatch.setattr(native.tempfile, "gettempdir", lambda: str(temp))
    assert native.library() is not None, native.unavailable_reason()
    assert native.kernel_name() == "c" and not marker.exists()
    assert sorted(p.name for p in temp.iterdir()) == [f"doabench-native-{os.getuid()}"]  # the fresh folder is gone


@pytest.mark.parametrize("how", ["folder writable by others", "file writable by others", "file is a link",
                                 "folder is a link", "file of another user"])
@needs_kernel
def test_a_cache_others_could_write_is_not_trusted(monkeypatch, tmp_path, reloaded_kernel, how):
    """A cached kernel is loaded only from a folder of the current user's that nobody else may
    write, and only when the file is that user's, not writable by others and not a link: otherwise
    it is built again (in place, in a private folder; afresh in a temporary one otherwise)."""
    if how == "file of another user" and os.getuid() != 0:
        pytest.skip("giving a file to another user needs root")
    name = _kernel_file_name(tmp_path, monkeypatch)
    cache, marker = tmp_path / "cache", tmp_path / "PLANTED_LOADED"
    folder = cache / "native"
    planted = (tmp_path / "elsewhere" / name) if how.endswith("link") else folder / name
    _plant(planted, marker)
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    if how == "folder writable by others":
        folder.chmod(0o777)
    elif how == "file writable by others":
        planted.chmod(0o666)
    elif how == "file is a link":
        (folder / name).symlink_to(planted)
    elif how == "folder is a link":
        folder.rmdir()
        folder.symlink_to(planted.parent, target_is_directory=True)
    else:
        os.chown(planted, 65534, 65534)
    monkeypatch.setenv("DOABENCH_CACHE", str(cache))
    assert native.library() is not None, native.unavailable_reason()
    assert native.kernel_name() == "c" and not marker.exists(), how


def test_largest_tap_errors_of_the_two_approximations():
    """docs/simulation.md quotes them: nearest of 128 phases (the kernel) 5.3e-3, linear between
    8 phases (the torch path) 6.4e-3 of the peak tap, against the windowed sinc at the exact time."""
    half = rir_model.SINC_HALF
    frac = np.linspace(0.0, 1.0, 4001)[:-1]
    n = np.arange(2 * half)[None, :] - (half - 1)
    exact = engine.windowed_sinc(n - frac[:, None])
    table = native.tap_table(engine.windowed_sinc, half, engine.KERNEL_PHASES).astype(np.float64)
    q = np.floor(frac * engine.KERNEL_PHASES + 0.5).astype(int)  # q == 128: the next sample's phase 0
    nearest = np.where((q < engine.KERNEL_PHASES)[:, None], table[np.minimum(q, engine.KERNEL_PHASES - 1)],
                       engine.windowed_sinc(n - 1.0))
    over = engine.OVERSAMPLE
    lo = np.floor(frac * over)
    a = (frac * over - lo)[:, None]
    linear = (1 - a) * engine.windowed_sinc(n - lo[:, None] / over) + a * engine.windowed_sinc(n - (lo[:, None] + 1) / over)
    assert np.abs(nearest - exact).max() == pytest.approx(5.3e-3, abs=0.1e-3)
    assert np.abs(linear - exact).max() == pytest.approx(6.4e-3, abs=0.1e-3)


def test_accelerator_work_sizes_give_the_same_simulation(monkeypatch):
    """Off the CPU the torch path and the FFT convolutions work in far larger pieces (fewer kernel
    launches). The pieces change only the order of float32 additions, so a simulation with the
    accelerator's sizes, run here on the CPU, must equal the CPU-sized one to rounding."""
    from doabench.acoustics import convolution

    assert compute.work_elements(torch.device("cpu"), 1, 2) == 1
    assert compute.work_elements(torch.device("cuda"), 1, 2) == 2  # a device object needs no GPU
    room, src, mics = _scene(t60=0.6, n_points=120)
    x = np.random.default_rng(1).standard_normal(48000)
    # with the CPU's sizes the early convolution runs in several chunks of points, with the
    # accelerator's in one
    layout, _ = rir_model.plan(room, torch.tensor(src), torch.tensor(mics), FS)
    row = len(mics) * convolution.trajectory_fft_size(len(x), len(src), layout.n_early)
    assert convolution._OLA_CHUNK_ELEMENTS // row < len(src) <= convolution._OLA_CHUNK_ELEMENTS_CUDA // row
    sim = get_simulator("builtin")
    with native.disabled("test"):  # the torch path, which CUDA runs
        cpu_sized = sim.simulate(room, src, mics, x, FS, seed=5)
        monkeypatch.setattr(engine, "work_elements", lambda device, cpu, accelerator: accelerator)
        accelerator_sized = sim.simulate(room, src, mics, x, FS, seed=5)
    assert np.linalg.norm(accelerator_sized - cpu_sized) / np.linalg.norm(cpu_sized) < 1e-5
