"""Room impulse responses and simulator backends: behaviour against physics and the reference."""
from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
import torch
from scipy.signal import fftconvolve

from doabench.acoustics import compute
from doabench.acoustics import rir as engine
from doabench.acoustics import rir_model
from doabench.acoustics.room import SABINE_CONSTANT, Room, check_inside
from doabench.acoustics.backends.base import direct_path
from doabench.acoustics.convolution import convolve_trajectory
from doabench.acoustics.simulators import get_simulator
from doabench.acoustics.trajectories import segment_bounds
from doabench.errors import ConfigError, DependencyError, InputError, NotFoundError
from doabench.geometry import SPEED_OF_SOUND

FS = 16000
WEIGHTS = (0.9, 0.6, 0.75, 1.0, 0.55, 0.8)


@pytest.fixture(scope="module")
def builtin():
    return get_simulator("builtin")


def schroeder_t60(h: np.ndarray, fs: int = FS) -> float:
    """T60 from a line fitted to the Schroeder energy decay curve between -5 and -25 dB."""
    energy = np.cumsum(h[::-1].astype(np.float64) ** 2)[::-1]
    edc = 10 * np.log10(energy / energy[0])
    i5, i25 = int(np.argmax(edc <= -5)), int(np.argmax(edc <= -25))
    slope = np.polyfit(np.arange(i5, i25) / fs, edc[i5:i25], 1)[0]
    return -60.0 / slope


# ------------------------------------------------------------------------------------- Room


def test_reflection_coefficients_satisfy_sabine():
    room = Room((6.0, 4.0, 3.0), 0.6, WEIGHTS)
    beta = room.reflection_coefficients()
    alpha = 1 - beta**2
    assert np.allclose(SABINE_CONSTANT * room.volume / np.dot(room.wall_areas, alpha), 0.6)
    assert np.allclose(alpha / alpha.max(), np.array(WEIGHTS) / max(WEIGHTS))  # weights respected
    assert np.all(Room((6, 4, 3), 0.0).reflection_coefficients() == 0)
    assert room.diffuse_start() == pytest.approx(0.12) and room.max_time() == pytest.approx(0.4)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(dims=(5, -1, 3), t60=0.5), "dimensions"),
        (dict(dims=(5, 4, float("nan")), t60=0.5), "NaN"),
        (dict(dims=(5, 4), t60=0.5), "3 numbers"),
        (dict(dims=(5, 4, 3), t60=-0.1), "T60"),
        (dict(dims=(5, 4, 3), t60=float("inf")), "T60"),
        (dict(dims=(5, 4, 3), t60=0.5, abs_weights=(1, 1, 1, 1, 1, 1.5)), "(0, 1]"),
        (dict(dims=(5, 4, 3), t60=0.5, abs_weights=(1, 1, 1, 1, 1, 0)), "(0, 1]"),
        (dict(dims=(5, 4, 3), t60=0.5, abs_weights=(1, 1, 1)), "6 numbers"),
        (dict(dims=(10, 8, 6), t60=0.05), "unreachable"),
    ],
)
def test_room_rejects_bad_parameters(kwargs, words):
    with pytest.raises(ConfigError, match=None) as err:
        Room(**kwargs)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_check_inside_names_the_point():
    room = Room((4, 3, 2.5), 0.3)
    pts = np.array([[1, 1, 1], [2, 2, 2], [3.5, 1, 3.0]])
    with pytest.raises(ConfigError, match=r"array microphone 3 at \(3\.5, 1, 3\) is outside the 4x3x2\.5 m room"):
        check_inside(room, pts, "array microphone")
    with pytest.raises(ConfigError, match="source point 2 .* not finite"):
        check_inside(room, [[1, 1, 1], [np.nan, 1, 1]], "source point")
    assert room.contains(pts).tolist() == [True, True, False]


def test_simulators_reject_bad_geometry(builtin):
    room = Room((4, 3, 2.5), 0.3)
    mics = np.array([[2, 1.5, 1.2], [2.1, 1.5, 1.2], [2.2, 1.5, 1.2]])
    src = np.tile([[1.0, 1.0, 1.0]], (20, 1))
    src[16] = [5.0, 1.0, 1.0]
    with pytest.raises(ConfigError, match="source point 17 .* outside"):
        builtin.rirs(room, src, mics, FS)
    bad_mics = mics.copy()
    bad_mics[2, 2] = -0.1
    with pytest.raises(ConfigError, match="array microphone 3 .* outside"):
        builtin.rirs(room, src[:2], bad_mics, FS)
    with pytest.raises(ConfigError, match="source point 1 is at array microphone 2"):
        builtin.rirs(room, mics[1:2], mics, FS)
    with pytest.raises(ConfigError, match="sample rate"):
        builtin.rirs(room, src[:2], mics, 0)
    with pytest.raises(InputError, match="NaN"):
        builtin.simulate(room, src[:2], mics, np.array([0.0, np.nan]), FS)


# ------------------------------------------------------------------- builtin vs reference


def test_builtin_matches_pyroomacoustics():
    room = Room((4.3, 3.7, 2.8), 0.35, WEIGHTS)
    src = np.array([[1.1, 1.3, 1.4]])
    mics = np.array([[3.1, 2.6, 1.2], [3.0, 2.9, 1.0]])
    hb = get_simulator("builtin").rirs(room, src, mics, FS, seed=3)
    hp = get_simulator("pyroomacoustics").rirs(room, src, mics, FS, seed=3)
    assert hb.shape == hp.shape == (1, 2, round(room.max_time() * FS))
    n_diff = round(room.diffuse_start() * FS)
    early_b, early_p = hb[..., :n_diff], hp[..., :n_diff]
    assert np.linalg.norm(early_b - early_p) / np.linalg.norm(early_p) <= 0.10

    # Direct path and first-order reflections: arrival sample and amplitude.
    images = rir_model.enumerate_images(room, 30.0)
    checked = 0
    for m in range(2):
        pos = images.offset + images.sign * src[0]
        delays = np.linalg.norm(pos - mics[m], axis=1) / SPEED_OF_SOUND * FS
        for i in np.flatnonzero(images.order <= 1):
            others = np.delete(delays, i)
            if np.min(np.abs(others - delays[i])) < 4:  # overlapping arrivals: peaks not comparable
                continue
            lo, hi = int(delays[i]) - 2, int(delays[i]) + 3
            pb = lo + int(np.argmax(np.abs(hb[0, m, lo:hi])))
            pp = lo + int(np.argmax(np.abs(hp[0, m, lo:hi])))
            assert abs(pb - delays[i]) <= 1 and abs(pb - pp) <= 1
            assert hb[0, m, pb] == pytest.approx(hp[0, m, pp], rel=0.05)
            checked += 1
    assert checked >= 8


@pytest.mark.parametrize("t60", [0.2, 0.45, 0.8, 1.3])
def test_schroeder_decay_gives_the_target_t60(builtin, t60):
    room = Room((6.5, 5.0, 3.0), t60, WEIGHTS)
    src = np.array([[1.2, 1.5, 1.1]])
    mics = np.array([[4.8, 3.6, 1.3], [4.7, 3.5, 1.4]])
    h = builtin.rirs(room, src, mics, FS, seed=11)
    for m in range(2):
        assert schroeder_t60(h[0, m]) == pytest.approx(t60, rel=0.15)


def test_anechoic_is_only_the_direct_path(builtin):
    room = Room((5, 4, 3), 0.0)
    src = np.array([[1.0, 1.0, 1.5], [4.0, 3.0, 2.0]])
    mics = np.array([[2.5, 2.0, 1.2]])
    h = builtin.rirs(room, src, mics, FS, seed=0)
    for s in range(2):
        d = np.linalg.norm(src[s] - mics[0])
        tau = d / SPEED_OF_SOUND * FS
        n = np.arange(h.shape[-1])
        outside = np.abs(n - tau) >= rir_model.SINC_HALF + 1 / engine.KERNEL_PHASES  # arrival rounded to 1/128
        assert np.all(h[s, 0, outside] == 0)
        expected = engine.windowed_sinc(n - tau) / (4 * math.pi * d)
        assert np.max(np.abs(h[s, 0] - expected)) <= 0.01 * np.max(np.abs(expected))


def test_seeds_fix_the_tail_and_mics_get_independent_tails(builtin):
    room = Room((5, 4, 3), 0.5, WEIGHTS)
    src = np.array([[1.0, 1.2, 1.5]])
    mics = np.array([[3.5, 2.5, 1.2], [3.55, 2.5, 1.2]])
    a = builtin.rirs(room, src, mics, FS, seed=7)
    assert np.array_equal(a, builtin.rirs(room, src, mics, FS, seed=7))
    assert np.array_equal(a, builtin.rirs(room, src, mics, FS, seed=torch.Generator().manual_seed(7)))
    b = builtin.rirs(room, src, mics, FS, seed=8)
    n_diff = round(room.diffuse_start() * FS)
    assert np.array_equal(a[..., : n_diff - rir_model.SINC_HALF - 1], b[..., : n_diff - rir_model.SINC_HALF - 1])
    tail_a, tail_b = a[0, :, n_diff + 200 :], b[0, :, n_diff + 200 :]
    assert not np.allclose(tail_a, tail_b)
    corr = np.corrcoef(tail_a)[0, 1]  # diffuse field: independent noise per microphone
    assert abs(corr) < 0.1
    # the tail continues the early part's energy envelope
    k = rir_model.decay_rate(room.t60) / FS
    w = slice(n_diff // 2, n_diff)
    t_early = np.arange(n_diff)[w]
    early_level = np.mean(a[0, :, w] ** 2 * np.exp(k * t_early))
    t_tail = np.arange(n_diff, a.shape[-1])
    tail_level = np.mean(a[0, :, n_diff:] ** 2 * np.exp(k * t_tail))
    assert 0.5 < tail_level / early_level < 2.0


# ---------------------------------------------------------------------------- simulate()


def test_static_source_equals_convolution_with_its_rir(builtin):
    room = Room((4, 3.5, 2.6), 0.3, WEIGHTS)
    src = np.array([[1.0, 1.0, 1.3]])
    mics = np.array([[2.8, 2.2, 1.1], [2.9, 2.3, 1.2]])
    x = np.random.default_rng(0).standard_normal(6000).astype(np.float32)
    y = builtin.simulate(room, src, mics, x, FS, seed=5)
    h = builtin.rirs(room, src, mics, FS, seed=5)
    ref = np.stack([fftconvolve(x, h[0, m])[: len(x)] for m in range(2)])
    assert y.shape == (2, len(x)) and y.dtype == np.float32
    assert np.allclose(y, ref, atol=1e-5 * np.abs(ref).max())
    # identical trajectory points: one static source (same point, same RIRs up to the tail noise)
    anechoic = Room((4, 3.5, 2.6), 0.0)
    y_static = builtin.simulate(anechoic, src, mics, x, FS)
    y_traj = builtin.simulate(anechoic, np.repeat(src, 13, axis=0), mics, x, FS)
    assert np.allclose(y_traj, y_static, atol=1e-5 * np.abs(y_static).max())


def test_trajectory_segments_use_their_own_rir():
    rng = np.random.default_rng(1)
    S, M, N, L = 7, 3, 40, 103
    h = torch.as_tensor(rng.standard_normal((S, M, N)), dtype=torch.float32)
    x = torch.as_tensor(rng.standard_normal(L), dtype=torch.float32)
    b = segment_bounds(L, S)
    ref = np.zeros((M, L + N))
    for i in range(S):  # the definition, one segment at a time
        for m in range(M):
            seg = x[b[i] : b[i + 1]].numpy()
            ref[m, b[i] : b[i + 1] + N - 1] += np.convolve(seg, h[i, m].numpy())
    assert np.allclose(convolve_trajectory(h, x).numpy(), ref[:, :L], atol=1e-4)
    # more points than samples: points without a sample are ignored
    short = x[:5]
    b = segment_bounds(5, S)
    ref = np.zeros((M, 5 + N))
    for i in range(S):
        for m in range(M):
            if b[i + 1] > b[i]:
                ref[m, b[i] : b[i] + N] += short[b[i]].item() * h[i, m].numpy()
    assert np.allclose(convolve_trajectory(h, short).numpy(), ref[:, :5], atol=1e-5)
    assert segment_bounds(10, 3).tolist() == [0, 3, 6, 10]


def test_direct_path_matches_anechoic_simulation(builtin):
    room = Room((5, 4, 3), 0.0)
    src = np.linspace([1.0, 1.0, 1.0], [4.0, 3.0, 2.0], 9)
    mics = np.array([[2.5, 2.0, 1.2], [2.55, 2.0, 1.25]])
    x = np.random.default_rng(2).standard_normal(4000).astype(np.float32)
    y = builtin.simulate(room, src, mics, x, FS)
    d = direct_path(room, src, mics, x, FS)
    assert np.allclose(d, y, atol=1e-6 * np.abs(y).max())
    d_free = direct_path(None, src, mics, x, FS)
    assert np.array_equal(d, d_free)


# ----------------------------------------------------------------------------- backends


def test_unknown_simulator_lists_the_names():
    with pytest.raises(NotFoundError, match="builtin, gpurir, pyroomacoustics"):
        get_simulator("nope")


@pytest.mark.skipif(importlib.util.find_spec("gpuRIR") is not None, reason="gpuRIR is installed")
def test_gpurir_missing_says_how_to_install():
    with pytest.raises(DependencyError) as err:
        get_simulator("gpurir")
    msg = str(err.value)
    assert "not on PyPI" in msg and "CUDA" in msg and "github.com/DavidDiazGuerra/gpuRIR" in msg


def test_versions_are_strings():
    for name in ("builtin", "pyroomacoustics"):
        v = get_simulator(name).versions()
        assert v["backend"] == name and all(isinstance(x, str) for x in v.values())


def test_results_do_not_depend_on_chunking(builtin, monkeypatch):
    room = Room((4.5, 4.0, 2.7), 0.4, WEIGHTS)
    src = np.linspace([1.0, 1.0, 1.0], [3.5, 3.0, 2.0], 6)
    mics = np.array([[2.5, 2.0, 1.2], [2.55, 2.0, 1.25], [2.5, 2.05, 1.2]])
    ref = builtin.rirs(room, src, mics, FS, seed=4)
    monkeypatch.setattr(engine, "_CHUNK_ELEMENTS", 1)  # one point per chunk
    monkeypatch.setattr(engine, "_SLICE_ELEMENTS", 30)  # tiny image slices
    out = builtin.rirs(room, src, mics, FS, seed=4)
    assert np.allclose(out, ref, rtol=0, atol=1e-6 * np.abs(ref).max())


def test_simulation_leaves_global_settings_alone(builtin):
    import pyroomacoustics as pra

    threads = torch.get_num_threads()
    hpf = pra.constants.get("rir_hpf_enable")
    fdl = pra.constants.get("frac_delay_length")
    room = Room((4, 3.5, 2.6), 0.25)
    src, mics = np.array([[1.0, 1.0, 1.3]]), np.array([[2.8, 2.2, 1.1], [2.9, 2.3, 1.2]])
    builtin.simulate(room, src, mics, np.ones(100), FS, seed=0)
    get_simulator("pyroomacoustics").rirs(room, src, mics, FS, seed=0)
    assert torch.get_num_threads() == threads
    assert pra.constants.get("rir_hpf_enable") == hpf and pra.constants.get("frac_delay_length") == fdl


# ------------------------------------------------------------------ shared diffuse tail


def _moving_scene(t60=0.6, n_points=12):
    room = Room((6.5, 5.0, 3.0), t60, WEIGHTS)
    src = np.linspace([1.0, 1.2, 1.1], [2.5, 3.8, 1.6], n_points)
    mics = np.array([[4.8, 3.6, 1.3], [4.75, 3.55, 1.35], [4.85, 3.5, 1.25], [4.7, 3.65, 1.3]])
    return room, src, mics


def _parts(room, src, mics, seed):
    gen = compute.make_generator(seed)
    return engine.image_source_parts(room, torch.tensor(src), torch.tensor(mics), FS, gen)


@pytest.mark.parametrize("t60", [0.3, 0.6, 1.0])
def test_shared_tail_decays_at_the_target_t60(t60):
    room, src, mics = _moving_scene(t60)
    parts = _parts(room, src, mics, seed=21)
    assert parts.tail.shape == (len(mics), parts.layout.n_taps - parts.layout.n_diff)
    for m in range(len(mics)):
        # the tail spans 28 dB (Tdiff at -12 dB, Tmax at -40 dB): fit -5..-15 dB, where the
        # truncation's bend of the Schroeder curve is negligible
        h = parts.tail[m].numpy().astype(np.float64)
        edc = 10 * np.log10(np.cumsum(h[::-1] ** 2)[::-1] / np.sum(h**2))
        i5, i15 = int(np.argmax(edc <= -5)), int(np.argmax(edc <= -15))
        slope = np.polyfit(np.arange(i5, i15) / FS, edc[i5:i15], 1)[0]
        assert -60.0 / slope == pytest.approx(t60, rel=0.05)


def test_shared_tail_continues_the_early_energy_within_1_db(builtin):
    room, src, mics = _moving_scene(0.6)
    h = builtin.rirs(room, src, mics, FS, seed=5).astype(np.float64)
    n_diff = round(room.diffuse_start() * FS)
    k = rir_model.decay_rate(room.t60) / FS
    w = n_diff // 2
    before = np.arange(n_diff - w, n_diff)
    after = np.arange(n_diff, n_diff + w)
    e_before = np.mean(h[..., before] ** 2 * np.exp(k * before))  # decay-compensated, all points and mics
    e_after = np.mean(h[..., after] ** 2 * np.exp(k * after))
    assert abs(10 * np.log10(e_after / e_before)) <= 1.0
    # one tail for every point, independent per microphone
    assert np.array_equal(h[0, :, n_diff:], h[-1, :, n_diff:])
    assert abs(np.corrcoef(h[0, :2, n_diff + 200 :])[0, 1]) < 0.1


def test_early_part_and_direct_path_are_the_per_point_engines(builtin):
    room, src, mics = _moving_scene(0.5, n_points=5)
    h = builtin.rirs(room, src, mics, FS, seed=2)
    layout, delays = rir_model.plan(room, torch.tensor(src), torch.tensor(mics), FS)
    images = rir_model.enumerate_images(room, (layout.n_early + rir_model.SINC_HALF) / FS * SPEED_OF_SOUND)
    for s in range(len(src)):  # one point at a time, as a per-point engine renders it
        early = engine.render_images(images, torch.tensor(src[s : s + 1]), torch.tensor(mics), FS, layout.n_early)
        assert np.allclose(h[s, :, : layout.n_diff], early[0, :, : layout.n_diff].numpy(),
                           rtol=0, atol=1e-6 * float(early.abs().max()))
        # direct path: the peak sits at the geometric delay; inter-microphone lags agree
        d = delays[s].numpy()
        peaks = np.array([int(d[m]) - 2 + int(np.argmax(np.abs(h[s, m, int(d[m]) - 2 : int(d[m]) + 4])))
                          for m in range(len(mics))])
        assert np.all(np.abs(peaks - d) <= 1)
        assert np.all(np.abs((peaks - peaks[0]) - (d - d[0])) <= 1)


def test_moving_source_simulation_is_reproducible_and_equals_rir_convolution(builtin):
    room, src, mics = _moving_scene(0.45, n_points=9)
    x = np.random.default_rng(3).standard_normal(9000).astype(np.float32)
    y = builtin.simulate(room, src, mics, x, FS, seed=17)
    assert np.array_equal(y, builtin.simulate(room, src, mics, x, FS, seed=17))  # bitwise, same seed
    assert not np.array_equal(y, builtin.simulate(room, src, mics, x, FS, seed=18))
    h = builtin.rirs(room, src, mics, FS, seed=17)
    ref = convolve_trajectory(torch.as_tensor(h), torch.as_tensor(x)).numpy()
    assert np.allclose(y, ref, rtol=0, atol=1e-5 * np.abs(ref).max())
    # static source: the shared tail is the per-point tail (same draw), simulate = its convolution
    y1 = builtin.simulate(room, src[:1], mics, x, FS, seed=17)
    h1 = builtin.rirs(room, src[:1], mics, FS, seed=17)
    ref1 = np.stack([fftconvolve(x, h1[0, m])[: len(x)] for m in range(len(mics))])
    assert np.allclose(y1, ref1, rtol=0, atol=1e-5 * np.abs(ref1).max())


def test_pyroomacoustics_backend_uses_the_shared_tail():
    room = Room((4.0, 3.5, 2.6), 0.3, WEIGHTS)
    src = np.array([[1.0, 1.0, 1.3], [1.3, 1.2, 1.3]])
    mics = np.array([[2.8, 2.2, 1.1], [2.9, 2.3, 1.2]])
    pra_sim = get_simulator("pyroomacoustics")
    hp = pra_sim.rirs(room, src, mics, FS, seed=9)
    n_early = round(room.diffuse_start() * FS)
    assert np.array_equal(hp[0, :, n_early:], hp[1, :, n_early:])
    x = np.random.default_rng(4).standard_normal(3000).astype(np.float32)
    y = pra_sim.simulate(room, src, mics, x, FS, seed=9)
    ref = convolve_trajectory(torch.as_tensor(hp), torch.as_tensor(x)).numpy()
    assert np.allclose(y, ref, rtol=0, atol=1e-5 * np.abs(ref).max())


@pytest.mark.parametrize("n_samples,n_tail,start", [(50_000, 3_000, 700), (9_000, 20_000, 10), (300, 40, 299),
                                                   (40_000, 9_000, 0)])
def test_tail_convolution_is_the_direct_convolution(n_samples, n_tail, start):
    """The blocked overlap-add of the shared tail equals a plain convolution (float32 rounding),
    for tails shorter and longer than a block and outputs shorter than one."""
    from doabench.acoustics.convolution import add_tail_convolution_

    rng = np.random.default_rng(n_tail)
    x = rng.standard_normal(n_samples).astype(np.float32)
    tail = rng.standard_normal((2, n_tail)).astype(np.float32)
    base = rng.standard_normal((2, n_samples)).astype(np.float32)
    out = add_tail_convolution_(torch.tensor(base), torch.tensor(x), torch.tensor(tail), start).numpy()
    ref = base.astype(np.float64).copy()
    for m in range(2):
        ref[m, start:] += fftconvolve(x.astype(np.float64), tail[m].astype(np.float64))[: n_samples - start]
    assert np.abs(out - ref).max() <= 1e-5 * np.abs(ref).max()


def test_simulator_backends_are_plugins():
    from doabench.acoustics.backends.base import Simulator
    from doabench.acoustics.backends.builtin import BuiltinSimulator
    from doabench.acoustics.simulators import register_simulator, simulator_names

    assert {"builtin", "pyroomacoustics", "gpurir"} <= set(simulator_names())  # declared as entry points

    class Quiet(BuiltinSimulator):  # a third party's backend, registered at run time
        name = "quiet"

        def simulate(self, room, sources, mics, signal, fs, *, seed=None):
            return 0.5 * super().simulate(room, sources, mics, signal, fs, seed=seed)

    register_simulator("quiet", Quiet)
    quiet = get_simulator("quiet")
    assert isinstance(quiet, Simulator) and "quiet" in simulator_names()
    room = Room((5.0, 4.0, 3.0), 0.3, WEIGHTS)
    x = np.random.default_rng(0).standard_normal(4000).astype(np.float32)
    src, mics = np.array([[1.0, 1.0, 1.5]]), np.array([[3.0, 2.0, 1.5], [3.1, 2.0, 1.5]])
    loud = get_simulator("builtin").simulate(room, src, mics, x, FS, seed=3)
    assert np.allclose(quiet.simulate(room, src, mics, x, FS, seed=3), 0.5 * loud)
    with pytest.raises(NotFoundError, match="unknown simulator 'nope'"):
        get_simulator("nope")
