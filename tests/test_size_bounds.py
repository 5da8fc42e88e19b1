"""Every size that comes from input is bounded before anything of that size is allocated, with one
line saying the size and the limit (docs/guarantees.md, "Sizes from input"): a WAV header's sample
rate (the resampling filter's length), an array file's microphone count (pair distances), a
frame's window and rate. A plug-in tracker's grid and a plug-in kind's frame shape are checked in
tests/test_plugin_outputs.py, the simulators' memory in tests/test_memory_budget.py."""
from __future__ import annotations

import json
import resource
from pathlib import Path

import numpy as np
import pytest

from doabench.cli.main import main


def _one_line(capsys) -> str:
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


@pytest.fixture
def small_address_space():
    """A 6 GiB address-space limit while a check runs: an allocation of the size the input claims
    (1.5 GiB of filter taps, 8.9 GiB of pair distances) would fail with MemoryError instead."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = 6 << 30
    if hard != resource.RLIM_INFINITY and hard < limit:
        pytest.skip("the address space is limited below 6 GiB already")
    in_use = int(Path("/proc/self/statm").read_text().split()[0]) * resource.getpagesize() \
        if Path("/proc/self/statm").exists() else 0
    resource.setrlimit(resource.RLIMIT_AS, (in_use + limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def test_a_wav_claiming_a_huge_sample_rate_is_refused_before_its_filter(tmp_path, capsys, small_address_space):
    """``track --resample`` on a WAV whose header claims 10,000,019 Hz: 16 kHz from it would take a
    200-million-tap filter (1.5 GiB); the factor is bounded first."""
    import soundfile as sf

    wav = tmp_path / "odd.wav"
    sf.write(wav, np.zeros((40000, 12), np.float32), 10_000_019, subtype="FLOAT")
    assert main(["track", str(wav), "--tracker", "srp-max:4x8", "--resample", "--out", str(tmp_path / "t.csv")]) == 2
    err = _one_line(capsys)
    assert str(wav) in err and "10000019 Hz" in err and "outside 1 to 768000 Hz" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["odd.wav"]


def test_resampling_factors_are_bounded():
    """Common rates pass (44.1 and 48 kHz, 44,056 Hz of NTSC video); a pair of rates whose factors
    exceed the limit is refused with the filter length it would take and the limit's."""
    from doabench.errors import InputError
    from doabench.resampling import MAX_RESAMPLE_FACTOR, rational_factors

    assert rational_factors(44100, 16000) == (160, 441) and rational_factors(44056, 16000) == (2000, 5507)
    assert rational_factors(768000, 16000) == (1, 48)
    with pytest.raises(InputError, match=r"resampling 767999 Hz to 16000 Hz takes the factors 16000/767999, a "
                                         r"filter of 15359981 taps; the limit is a factor of 65536 \(1310721 taps\)"):
        rational_factors(767_999, 16000)
    assert MAX_RESAMPLE_FACTOR == 65536


def test_an_array_file_of_20000_microphones_is_refused_before_its_distances(tmp_path, capsys, small_address_space):
    """Pair distances grow with the square of the count: 20,000 microphones asked for 8.9 GiB."""
    import soundfile as sf

    rng = np.random.default_rng(0)
    big = tmp_path / "big.json"
    big.write_text(json.dumps({"name": "big", "positions": rng.uniform(-1, 1, (20000, 3)).round(6).tolist()}))
    wav = tmp_path / "rec.wav"
    sf.write(wav, np.zeros((8000, 2), np.float32), 16000, subtype="FLOAT")
    assert main(["features", str(wav), "--array", str(big), "--kind", "gcc", "--out", str(tmp_path / "f.npy")]) == 2
    err = _one_line(capsys)
    assert f"array file {big}: 20000 microphones, more than the limit of 1024" in err, err
    # the same from Python: a MicArray of too many positions, before any distance is computed
    from doabench.arrays import MicArray
    from doabench.errors import ConfigError

    with pytest.raises(ConfigError, match="20000 microphones, more than the limit of 1024"):
        MicArray("big", rng.uniform(-1, 1, (20000, 3)))
    huge = tmp_path / "huge.json"  # a file larger than any array: refused before it is read
    with open(huge, "wb") as fh:
        fh.truncate(64 << 20)
    assert main(["features", str(wav), "--array", str(huge), "--kind", "gcc", "--out", str(tmp_path / "f.npy")]) == 2
    assert f"array file {huge} holds 67108864 bytes, more than the limit of 4194304" in _one_line(capsys)


@pytest.mark.parametrize("argv, message", [
    (["--window", "100000000"], "a window of 100000000 samples, more than the limit of 1048576"),
    (["--fs", "10000000"], "a sample rate of 10000000 Hz, more than the limit of 768000 Hz"),
])
def test_frame_settings_are_bounded(argv, message, tmp_path, capsys):
    import soundfile as sf

    wav = tmp_path / "rec.wav"
    sf.write(wav, np.zeros((8000, 12), np.float32), 16000, subtype="FLOAT")
    assert main(["features", str(wav), *argv, "--out", str(tmp_path / "f.npy")]) == 2
    assert message in _one_line(capsys)
