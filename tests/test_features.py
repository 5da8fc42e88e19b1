"""Feature extraction against physics and against independent reference computations."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import soundfile as sf
import torch

from doabench.arrays import MicArray, get_array
from doabench.cli.main import main as cli_main
from doabench.errors import ConfigError, InputError
from doabench.features import (
    GCCPHAT,
    SRPPHAT,
    FeatureExtractor,
    Spectrogram,
    StreamingFeatureExtractor,
    functional as F,
)
from doabench.framing import FrameSpec, frame_vad
from doabench.geometry import SPEED_OF_SOUND, grid_spacing_deg, great_circle_error, grid_unit_vectors
from fixtures.signals import plane_wave

FS = 16000
NAO = get_array("nao")


def random_directions(n: int, rng) -> np.ndarray:
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    # Make sure the poles, where azimuth means nothing, are exercised.
    u[0] = (0, 0, 1)
    u[1] = (0, 0, -1)
    u[2] = (0.05, 0.02, 1) / np.linalg.norm((0.05, 0.02, 1))
    return u


def cell_diagonal(n_theta: int, n_phi: int) -> float:
    """Angular size (rad) of a grid cell's diagonal at the equator, where cells are largest.

    "Within one cell" is measured as the great-circle distance between the map maximum and the
    true direction, which stays meaningful at the poles where azimuth indices do not.
    """
    return math.radians(math.hypot(*grid_spacing_deg(n_theta, n_phi)))


# Nearest mode rounds each pair delay to a whole sample: a delay error of up to 0.5 sample on the
# longest baseline (d_max fs / c = 5.64 samples on NAO) is a direction error of about
# 0.5 / 5.64 rad = 5.1 deg. Measured worst case over 2000 random directions (K = 4096): 9.4 deg at
# 16x32 (0.57 cell diagonal), 6.4 deg at 32x64 (0.79), 4.3 deg at 64x128 (1.07). Bound: the larger
# of one cell diagonal and that half-sample resolution.
NEAREST_FLOOR = 0.5 / (NAO.max_distance * FS / SPEED_OF_SOUND)


def peak_errors(audio: np.ndarray, truth: np.ndarray, res, mode: str, window: int) -> np.ndarray:
    X = F.stft_frames(torch.from_numpy(audio), window, window)
    maps = F.srp_phat(X, NAO.positions, *res, FS, mode=mode)[:, 0]
    return great_circle_error(F.map_argmax_directions(maps).double().numpy(), truth)


@pytest.fixture(scope="module")
def nao_waves():
    rng = np.random.default_rng(1234)
    u = random_directions(20, rng)
    return u, plane_wave(u, 4096, NAO.positions, rng), plane_wave(u, 512, NAO.positions, rng)


@pytest.mark.parametrize("res", [(16, 32), (32, 64), (64, 128)])
def test_exact_map_peak_within_one_cell(nao_waves, res):
    u, x4096, x512 = nao_waves
    # Exact maps cost ~ n_bins x n_grid to set up, seconds for fine grids at K = 4096; shorter
    # frames localise a noise plane wave as well.
    audio, window = (x4096, 4096) if res == (16, 32) else (x512, 512)
    err = peak_errors(audio, u, res, "exact", window)
    assert err.max() <= cell_diagonal(*res), np.degrees(err)


@pytest.mark.parametrize("res", [(16, 32), (32, 64), (64, 128)])
def test_nearest_map_peak_bound(nao_waves, res):
    u, x4096, _ = nao_waves
    err = peak_errors(x4096, u, res, "nearest", 4096)
    assert err.max() <= max(cell_diagonal(*res), NEAREST_FLOOR), np.degrees(err)


@pytest.mark.parametrize("res", [(4, 8), (8, 16), (16, 32), (32, 64), (64, 128), (5, 7), (2, 2)])
def test_any_resolution_shapes(res):
    x = torch.randn(2, NAO.n_mics, 256 + 192)
    X = F.stft_frames(x, 256, 192)
    for mode in ("nearest", "exact"):
        m = F.srp_phat(X, NAO.positions, *res, FS, mode=mode)
        assert m.shape == (2, 2) + res and m.dtype == torch.float32 and torch.isfinite(m).all()


@pytest.mark.parametrize("K", [64, 63])
def test_exact_equals_bruteforce_eq3(K):
    """Exact mode vs eq. (3) (PHAT beamformer) and eq. (4)-(5) (pair sum), float64 loops."""
    rng = np.random.default_rng(7)
    M, hop, n_theta, n_phi = 4, 48, 5, 6
    pos = rng.uniform(-0.05, 0.05, (M, 3))
    x = rng.standard_normal((2, M, K + hop))
    got = F.srp_phat(F.stft_frames(torch.from_numpy(x).float(), K, hop), pos, n_theta, n_phi, FS, mode="exact", window=K)

    win = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(K) / K)  # periodic Hann
    w = 2 * np.pi * np.arange(K // 2 + 1) / K
    a = np.full(K // 2 + 1, 2.0)  # multiplicity of each rfft bin in the full spectrum
    a[0] = 1.0
    if K % 2 == 0:
        a[-1] = 1.0  # Nyquist
    grid = grid_unit_vectors(n_theta, n_phi).reshape(-1, 3)
    ref3 = np.zeros((2, 2, len(grid)))
    ref45 = np.zeros_like(ref3)
    for b in range(2):
        for t in range(2):
            Xn = np.fft.rfft(x[b, :, t * hop : t * hop + K] * win, axis=-1)
            Wn = Xn / np.abs(Xn)  # G_n = 1 / |X_n|
            for g, u in enumerate(grid):
                tau = -(pos @ u) * FS / SPEED_OF_SOUND  # arrival delays, samples
                # eq. (3): steer to compensate the arrival delays, integrate |.|^2 over the whole
                # spectrum (rfft bins weighted by their multiplicity), then drop the n == m terms
                # and count each unordered pair once.
                Y = (Wn * np.exp(1j * w * tau[:, None])).sum(0)
                full = np.sum(a * np.abs(Y) ** 2) - np.sum(a * np.sum(np.abs(Wn) ** 2, 0))
                ref3[b, t, g] = full / 2 / K
                # eq. (4)-(5): sum over pairs of the GCC at the fractional pair delay.
                for n in range(M):
                    for m in range(n + 1, M):
                        phi = Wn[n] * np.conj(Wn[m])
                        ref45[b, t, g] += np.sum(a * np.real(phi * np.exp(1j * w * (tau[n] - tau[m])))) / K
    np.testing.assert_allclose(ref3, ref45, atol=1e-9)
    np.testing.assert_allclose(got.reshape(2, 2, -1).numpy(), ref3, atol=2e-5 * np.abs(ref3).max())


def test_gcc_equals_irfft_reference():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((1, 3, 256)).astype(np.float32)
    X = F.stft_frames(torch.from_numpy(x), 128, 64)
    pairs = np.array([[0, 1], [0, 2], [1, 2]])
    got = F.gcc_phat(X, pairs, 5).numpy()
    Xd = X.numpy().astype(np.complex128)
    Wd = Xd / np.abs(Xd)
    r = np.fft.irfft(Wd[:, :, pairs[:, 0]] * np.conj(Wd[:, :, pairs[:, 1]]), n=128, axis=-1)
    ref = np.concatenate([r[..., -5:], r[..., :6]], axis=-1)
    np.testing.assert_allclose(got, ref, atol=1e-6)
    # Many lags take the full-length irfft path; same numbers.
    big = F.gcc_phat(X, pairs, 63).numpy()
    ref = np.concatenate([r[..., -63:], r[..., :64]], axis=-1)
    np.testing.assert_allclose(big, ref, atol=1e-6)


def test_planar_array_upper_hemisphere():
    d = 0.04
    array = MicArray("square", np.array([[d, 0, 0], [0, d, 0], [-d, 0, 0], [0, -d, 0], [0.7 * d, 0.7 * d, 0]]), planar=True)
    rng = np.random.default_rng(9)
    u = np.array([[np.sin(0.6) * np.cos(2.0), np.sin(0.6) * np.sin(2.0), np.cos(0.6)]])
    x = torch.from_numpy(plane_wave(u, 2048, array.positions, rng))
    out = FeatureExtractor(array, kinds=("srp", "srp_max"), resolution=(10, 24), mode="exact", frame_spec=FrameSpec(2048))(x)
    el, az = out["srp_max"][0, 0].tolist()
    # Planar grids span elevations [0, pi/2]: srp_max's elevation is a fraction of pi/2.
    assert abs(el * math.pi / 2 - 0.6) <= math.radians(10) and abs(az * 2 * math.pi - math.pi - 2.0) <= math.radians(15)
    dirs = F.map_argmax_directions(out["srp"], planar=True)[0, 0].double().numpy()
    assert great_circle_error(dirs, u[0]) <= math.radians(math.hypot(10, 15))


@pytest.mark.parametrize("delay", [-3, 0, 2, 5])
def test_gcc_peaks_at_relative_delay(delay):
    rng = np.random.default_rng(5)
    s = rng.standard_normal(4096 + 32)
    # mic 0 hears s delayed by `delay` samples relative to mic 1: tau_0 - tau_1 = delay.
    x = np.stack([s[16 - delay : 16 - delay + 4096], s[16 : 16 + 4096]])[None].astype(np.float32)
    g = F.gcc_phat(F.stft_frames(torch.from_numpy(x), 4096, 3072), [[0, 1]], 8)
    assert int(g[0, 0, 0].argmax()) - 8 == delay


def test_nearest_equals_exact_for_integer_delays():
    d = SPEED_OF_SOUND / FS  # one sample of propagation
    # On the 3x4 grid every direction component is -1, 0 or 1, so all pair delays are integers.
    array = MicArray("integer", np.array([[0, 0, 0], [0, 0, 2 * d], [3 * d, 0, 0], [0, d, 0]]))
    tau = F.grid_delays(array.positions, 3, 4, FS)
    dtau = tau[array.pairs[:, 0]] - tau[array.pairs[:, 1]]
    assert np.allclose(dtau, np.rint(dtau), atol=1e-9) and np.abs(dtau).max() >= 2
    x = torch.randn(2, 4, 2048)
    X = F.stft_frames(x, 512, 384)
    near = F.srp_phat(X, array.positions, 3, 4, FS, mode="nearest")
    exact = F.srp_phat(X, array.positions, 3, 4, FS, mode="exact")
    assert near.abs().max() > 0.1
    torch.testing.assert_close(near, exact, atol=2e-5, rtol=0)
    # The transforms agree with the functions.
    spec = FrameSpec(512, 384, FS)
    torch.testing.assert_close(SRPPHAT(array, (3, 4), spec, "nearest", normalize=False)(x), near)
    torch.testing.assert_close(SRPPHAT(array, (3, 4), spec, "exact", normalize=False)(x), exact, atol=2e-5, rtol=0)


def test_exact_blocking_does_not_change_result(monkeypatch):
    x = torch.randn(3, NAO.n_mics, 256 + 2 * 192)
    X = F.stft_frames(x, 256, 192)
    whole = F.srp_phat(X, NAO.positions, 8, 16, FS, mode="exact")
    monkeypatch.setattr(F, "_EXACT_TILE_BYTES", 256)
    monkeypatch.setattr(F, "_EXACT_BLOCK_BYTES", 4096)
    monkeypatch.setattr(F, "_GCC_BLOCK_BYTES", 1)
    torch.testing.assert_close(F.srp_phat(X, NAO.positions, 8, 16, FS, mode="exact"), whole, atol=1e-5, rtol=0)
    near = F.srp_phat(X, NAO.positions, 8, 16, FS)
    monkeypatch.undo()
    torch.testing.assert_close(near, F.srp_phat(X, NAO.positions, 8, 16, FS), atol=1e-6, rtol=0)


def test_normalize_and_maxima():
    maps = torch.randn(2, 3, 4, 8)
    maps[0, 1] = 0.0
    maps[1, 2, 3, 5] = 100.0
    n = F.normalize_maps(maps)
    live = torch.ones(2, 3, dtype=torch.bool)
    live[0, 1] = False
    torch.testing.assert_close(n[live].mean((-2, -1)), torch.zeros(5), atol=1e-6, rtol=0)
    torch.testing.assert_close(n[live].amax((-2, -1)), torch.ones(5))
    assert (n[0, 1] == 0).all()
    mx = F.map_maxima(maps)
    assert mx.shape == (2, 3, 2)
    torch.testing.assert_close(mx[1, 2], torch.tensor([3 / 3, 5 / 8]))
    u = F.map_argmax_directions(maps)
    torch.testing.assert_close(u[1, 2], torch.as_tensor(grid_unit_vectors(4, 8)[3, 5], dtype=torch.float32))
    assert ((mx >= 0) & (mx <= 1)).all()


def test_spectrogram_normalisation():
    x = torch.randn(2, 3, 2000) * 7
    s = Spectrogram(FrameSpec(512))(x)
    assert s.shape == (2, F.stft_frames(x, 512, 384).shape[1], 6, 256)
    torch.testing.assert_close(s[:, :, :3].amax(-1), torch.ones(2, s.shape[1], 3))
    assert (s[:, :, :3] >= 0).all()
    assert (s[:, :, 3:] >= -1).all() and (s[:, :, 3:] <= 1).all()


def test_silent_frames_are_zero():
    rng = np.random.default_rng(0)
    spec = FrameSpec(1024, 768, FS)
    x = rng.standard_normal((1, NAO.n_mics, 1024 + 5 * 768)).astype(np.float32)
    vad = np.ones((1, x.shape[-1]), dtype=bool)
    vad[0, 768 : 768 + 600] = False  # frame 1 keeps 424/1024 < 2/3 active; frame 0 keeps 768/1024
    out = FeatureExtractor(NAO, frame_spec=spec)(x, vad)
    expected = frame_vad(torch.from_numpy(vad), 1024, 768)
    assert torch.equal(out["vad"], expected) and not expected[0, 1] and expected[0, 0]
    for key in ("srp", "srp_max", "gcc", "spectrogram"):
        v = out[key]
        assert (v[~expected] == 0).all(), key
        assert (v[expected].flatten(1).abs().amax(1) > 0).all(), key
    assert out["srp"].dtype == torch.float32 and out["vad"].dtype == torch.bool
    assert torch.equal(FeatureExtractor(NAO, frame_spec=spec)(x)["vad"], torch.ones_like(expected))


def test_batch_equals_single_calls():
    spec = FrameSpec(1024, 768, FS)
    x = torch.randn(3, NAO.n_mics, 1024 + 3 * 768)
    vad = torch.rand(3, x.shape[-1]) > 0.1
    for mode in ("nearest", "exact"):
        fe = FeatureExtractor(NAO, resolution=(8, 16), mode=mode, frame_spec=spec)
        batch = fe(x, vad)
        for b in range(3):
            single = fe(x[b], vad[b])  # unbatched in, unbatched out
            for k, v in batch.items():
                assert single[k].shape == v[b].shape
                torch.testing.assert_close(single[k], v[b], atol=1e-6, rtol=0)
        pair = fe(x[1:], vad[1:])
        for k in batch:
            torch.testing.assert_close(pair[k], batch[k][1:], atol=1e-6, rtol=0)


@pytest.mark.parametrize("separate", [False, True])
def test_streaming_equals_offline(separate):
    rng = np.random.default_rng(11)
    kw = dict(
        resolution=(8, 16),
        frame_spec=FrameSpec(1024, 768, FS),
        spectrogram_frame_spec=FrameSpec(256, 192, FS) if separate else None,
    )
    x = rng.standard_normal((2, NAO.n_mics, 9000)).astype(np.float32)
    vad = rng.random((2, 9000)) > 0.15
    offline = FeatureExtractor(NAO, **kw)(x, vad)
    stream = StreamingFeatureExtractor(NAO, **kw)
    for trial in range(2):
        stream.reset()
        parts, pos = [], 0
        while pos < x.shape[-1]:
            n = int(rng.choice([0, 1, 7, 300, 1024, 2500])) if trial == 0 else int(rng.integers(0, 4000))
            parts.append(stream.push(x[..., pos : pos + n], vad[:, pos : pos + n]))
            pos += n
        assert set(parts[0]) == set(offline)
        for k, v in offline.items():
            got = torch.cat([p[k] for p in parts], dim=1)
            assert got.shape == v.shape, k
            torch.testing.assert_close(got, v, atol=1e-6, rtol=0)
        # Only samples of incomplete frames are kept between pushes.
        assert stream.buffered_samples < 1024
    # Unbatched chunks give unbatched outputs.
    stream.reset()
    one = [stream.push(x[0, :, s : s + 1500], vad[0, s : s + 1500]) for s in range(0, 9000, 1500)]
    torch.testing.assert_close(torch.cat([p["srp"] for p in one]), offline["srp"][0], atol=1e-6, rtol=0)


def test_hop_longer_than_window_streams():
    kw = dict(kinds=("gcc",), frame_spec=FrameSpec(256, 400, FS))
    x = torch.randn(NAO.n_mics, 3000)
    offline = FeatureExtractor(NAO, **kw)(x)["gcc"]
    stream = StreamingFeatureExtractor(NAO, **kw)
    got = torch.cat([stream.push(x[:, s : s + 123])["gcc"] for s in range(0, 3000, 123)])
    torch.testing.assert_close(got, offline)


def test_transforms_agree_with_extractor():
    spec = FrameSpec(1024, 768, FS)
    x = torch.randn(2, NAO.n_mics, 4000)
    out = FeatureExtractor(NAO, resolution=(8, 16), frame_spec=spec)(x)
    torch.testing.assert_close(SRPPHAT(NAO, (8, 16), spec)(x), out["srp"])
    torch.testing.assert_close(GCCPHAT(NAO, spec)(x), out["gcc"])
    torch.testing.assert_close(Spectrogram(spec)(x), out["spectrogram"])
    assert out["gcc"].shape[-2:] == (66, 2 * NAO.max_lag(FS) + 1)
    assert out["srp_max"].shape == (2, out["srp"].shape[1], 2)


def test_input_errors():
    fe = FeatureExtractor(NAO, kinds=("srp",))
    with pytest.raises(InputError, match="channels"):
        fe(np.zeros((1, 11, 5000), np.float32))
    bad = np.zeros((12, 5000), np.float32)
    bad[3, 100] = np.nan
    with pytest.raises(InputError, match="NaN"):
        fe(bad)
    with pytest.raises(InputError, match="shorter than one"):
        fe(np.zeros((12, 4000), np.float32))
    with pytest.raises(InputError, match="VAD"):
        fe(np.zeros((12, 5000), np.float32), np.ones(4999, bool))
    with pytest.raises(ConfigError):
        FeatureExtractor(NAO, kinds=("srp", "mfcc"))
    with pytest.raises(ConfigError):
        FeatureExtractor(NAO, mode="linear")
    with pytest.raises(ConfigError):
        FeatureExtractor(NAO, resolution="16by32")
    with pytest.raises(InputError):
        StreamingFeatureExtractor(NAO).push(np.zeros((3, 100), np.float32))


# -- CLI ----------------------------------------------------------------------------------------
@pytest.fixture()
def wav(tmp_path):
    rng = np.random.default_rng(2)
    u = np.array([[0.6, 0.0, 0.8]])
    x = plane_wave(u, 16000, NAO.positions, rng)[0].T * 0.1  # (samples, 12)
    path = tmp_path / "rec.wav"
    sf.write(path, x, FS, subtype="FLOAT")
    return path, x


def run_cli(args, capsys):
    code = cli_main(["features", *map(str, args)])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_cli_srp(wav, tmp_path, capsys):
    path, _ = wav
    out = tmp_path / "maps.npy"
    code, _, err = run_cli([path, "--array", "nao", "--kind", "srp", "--resolution", "8x16", "--out", out], capsys)
    assert code == 0, err
    maps = np.load(out)
    meta = json.loads((tmp_path / "maps.json").read_text())
    assert maps.shape == (4, 8, 16) and maps.dtype == np.float32
    assert meta["shape"] == [4, 8, 16] and meta["resolution"] == "8x16" and meta["delays"] == "nearest"
    assert meta["elevations_deg"][0] == 0 and meta["elevations_deg"][-1] == 180 and meta["azimuths_deg"][0] == -180
    assert meta["frame_times_s"] == pytest.approx(FrameSpec().times(4).tolist())
    assert meta["array"]["name"] == "nao" and meta["frame"] == {"window": 4096, "hop": 3072, "fs": FS}
    # The source is at elevation 36.9 deg, azimuth 0: the maps peak next to it.
    row, col = np.unravel_index(maps[0].argmax(), maps[0].shape)
    assert abs(meta["elevations_deg"][row] - 36.87) <= 180 / 7 and abs(meta["azimuths_deg"][col]) <= 360 / 16
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp files left


def test_cli_other_kinds_and_resample(wav, tmp_path, capsys):
    path, x = wav
    code, _, err = run_cli([path, "--kind", "gcc", "--out", tmp_path / "g.npy"], capsys)
    assert code == 0, err
    assert np.load(tmp_path / "g.npy").shape == (4, 66, 13)
    assert json.loads((tmp_path / "g.json").read_text())["lags"] == list(range(-6, 7))
    code, _, err = run_cli([path, "--kind", "spectrogram", "--window", "512", "--out", tmp_path / "s.npy"], capsys)
    assert code == 0, err
    assert np.load(tmp_path / "s.npy").shape == (1 + (16000 - 512) // 384, 24, 256)
    p48 = tmp_path / "rec48.wav"
    sf.write(p48, np.repeat(x, 3, axis=0), 48000, subtype="FLOAT")
    code, _, err = run_cli([p48, "--out", tmp_path / "r.npy"], capsys)
    assert code == 2 and "--resample" in err and len(err.strip().splitlines()) == 1
    code, _, err = run_cli([p48, "--resample", "--delays", "exact", "--out", tmp_path / "r.npy"], capsys)
    assert code == 0, err
    meta = json.loads((tmp_path / "r.json").read_text())
    assert meta["resampled"] and meta["recording_fs"] == 48000 and np.load(tmp_path / "r.npy").shape == (4, 16, 32)


def test_cli_bad_inputs(wav, tmp_path, capsys):
    path, x = wav
    cases = {}
    sf.write(tmp_path / "four.wav", x[:, :4], FS, subtype="FLOAT")
    cases["channels"] = tmp_path / "four.wav"
    y = x.copy()
    y[100, 2] = np.inf
    sf.write(tmp_path / "inf.wav", y, FS, subtype="FLOAT")
    cases["infinite"] = tmp_path / "inf.wav"
    sf.write(tmp_path / "short.wav", x[:4000], FS, subtype="FLOAT")
    cases["shorter than one"] = tmp_path / "short.wav"
    (tmp_path / "junk.wav").write_bytes(b"not audio at all")
    cases["cannot read"] = tmp_path / "junk.wav"
    cases["does not exist"] = tmp_path / "missing.wav"
    for needle, rec in cases.items():
        out = tmp_path / "o.npy"
        code, _, err = run_cli([rec, "--out", out], capsys)
        assert code == 2, needle
        assert len(err.strip().splitlines()) == 1 and needle in err and "Traceback" not in err, err
        assert not out.exists()
    code, _, err = run_cli([path, "--resolution", "16", "--out", tmp_path / "o.npy"], capsys)
    assert code == 2 and "resolution" in err
    code, _, err = run_cli([path, "--array", tmp_path / "nope.json", "--out", tmp_path / "o.npy"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1


def test_srp_of_one_frame_equals_the_batched_maps():
    """srp_from_gcc gathers a single frame directly (the streaming case); the maps are those of the
    batched path."""
    srp = SRPPHAT(NAO, (32, 64))
    gcc = torch.randn(2, 4, len(NAO.pairs), 2 * srp.gcc.max_lag + 1)
    batched = F.srp_from_gcc(gcc, srp.index, 32, 64)
    one_by_one = torch.stack([torch.cat([F.srp_from_gcc(gcc[b:b + 1, t:t + 1], srp.index, 32, 64)
                                         for t in range(4)], dim=1)[0] for b in range(2)])
    torch.testing.assert_close(one_by_one, batched, rtol=1e-5, atol=1e-4)


def test_relative_phase_is_the_plane_wave_delay():
    """``phase="relative"``: a plane wave's phase at mic m minus mic 1's is -2 pi f tau_m (wrapped),
    whatever the source's own phase; the magnitudes are those of the absolute form."""
    rng = np.random.default_rng(3)
    u = random_directions(4, rng)
    K, n_bins = 1024, 513
    tau = -(u @ NAO.positions.T) * FS / SPEED_OF_SOUND  # (B, M) samples
    tau = tau - tau[:, :1]  # relative to the first mic
    k = np.arange(n_bins)
    source = rng.standard_normal((4, 1, n_bins)) + 1j * rng.standard_normal((4, 1, n_bins))
    X = torch.from_numpy(source * np.exp(-2j * np.pi * k * tau[..., None] / K))[:, None]  # (B, 1 frame, M, bins)
    rel = F.spectrogram_features(X, phase="relative")
    expected = np.angle(np.exp(-2j * np.pi * k[1:] * tau[..., None] / K)) / np.pi
    got = rel[:, 0, NAO.n_mics:].numpy()
    wrapped = np.abs((got - expected + 1) % 2 - 1)  # the same angle, +-1 being one point
    assert wrapped.max() < 1e-6
    assert np.abs(got[:, 0]).max() == 0  # the first mic against itself
    absolute = F.spectrogram_features(X)
    torch.testing.assert_close(rel[:, :, :NAO.n_mics], absolute[:, :, :NAO.n_mics])
    assert not torch.allclose(rel[:, :, NAO.n_mics:], absolute[:, :, NAO.n_mics:])


def test_relative_phase_of_a_recorded_plane_wave():
    """Through the STFT (Hann windows) a plane wave's relative phase matches -2 pi f tau at the low
    bins, where the delay is a small part of the window, and the transform says which phase it gives."""
    rng = np.random.default_rng(4)
    u = random_directions(4, rng)[3:]  # one random direction
    x = torch.from_numpy(plane_wave(u, 16 * 4096, NAO.positions, rng))
    s = Spectrogram(FrameSpec(4096, 3072, FS), phase="relative")(x)
    tau = -(u @ NAO.positions.T)[0] * FS / SPEED_OF_SOUND
    tau = tau - tau[0]
    bins = np.arange(1, 200)
    expected = np.angle(np.exp(-2j * np.pi * bins[None] * tau[:, None] / 4096)) / np.pi  # (M, bins)
    got = s[0, :, NAO.n_mics:, :199].numpy()  # (frames, M, bins)
    assert np.median(np.abs((got - expected[None] + 1) % 2 - 1)) < 0.01
    with pytest.raises(ConfigError, match="phase must be one of absolute, relative"):
        Spectrogram(FrameSpec(4096), phase="ipd")
    with pytest.raises(ConfigError, match="phase must be one of"):
        F.spectrogram_features(torch.zeros(1, 1, 2, 5, dtype=torch.complex64), phase="diff")
