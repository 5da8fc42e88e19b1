"""`doabench track` on a user's recording: output format, truth agreement and input errors."""
import numpy as np
import pandas as pd
import pytest
import soundfile as sf

from doabench.cli.main import main


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene") / "s"
    assert main(["simulate", "--t60", "0.2", "--snr", "30", "--seed", "5", "--duration", "4", "--out", str(out)]) == 0
    return out


def test_track_writes_csv_close_to_truth_and_a_plot(scene_dir, tmp_path):
    csv, png = tmp_path / "doa.csv", tmp_path / "doa.png"
    assert main(["track", str(scene_dir / "audio.wav"), "--tracker", "srp-max:32x64", "--out", str(csv),
                 "--plot", str(png)]) == 0
    est = pd.read_csv(csv)
    assert list(est.columns) == ["time_s", "elevation_deg", "azimuth_deg", "x", "y", "z"]
    truth = pd.read_csv(scene_dir / "truth.csv")
    assert np.allclose(est.time_s, truth.time_s)
    active = truth.vad.to_numpy(bool)
    cos = np.sum(est[["x", "y", "z"]].to_numpy() * truth[["x", "y", "z"]].to_numpy(), 1)
    assert np.median(np.degrees(np.arccos(np.clip(cos[active], -1, 1)))) < 10
    assert png.stat().st_size > 1000


def test_track_input_errors_are_one_line(scene_dir, tmp_path, capsys):
    audio, fs = sf.read(scene_dir / "audio.wav")
    cases = {}
    sf.write(tmp_path / "ch4.wav", audio[:, :4], fs)
    cases["ch4.wav"] = "has 4 channels but array 'nao' has 12"
    sf.write(tmp_path / "fs8k.wav", audio[::2], fs // 2)
    cases["fs8k.wav"] = "pass --resample"
    bad = audio.copy()
    bad[100, 3] = np.nan
    sf.write(tmp_path / "nan.wav", bad, fs, subtype="FLOAT")
    cases["nan.wav"] = "NaN or infinite"
    sf.write(tmp_path / "short.wav", audio[:1000], fs)
    cases["short.wav"] = "shorter than one 4096-sample window"
    (tmp_path / "junk.wav").write_bytes(b"not audio at all")
    cases["junk.wav"] = "cannot read"
    cases["missing.wav"] = "does not exist"
    for name, message in cases.items():
        out = tmp_path / f"{name}.csv"
        assert main(["track", str(tmp_path / name), "--out", str(out)]) == 2, name
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()
    # with --resample the 8 kHz file is accepted
    assert main(["track", str(tmp_path / "fs8k.wav"), "--resample", "--out", str(tmp_path / "ok.csv")]) == 0


@pytest.mark.parametrize("tracker", ["music", "normmusic", "srp-pra"])
def test_pyroomacoustics_trackers_follow_the_truth(scene_dir, tmp_path, tracker):
    csv = tmp_path / "doa.csv"
    assert main(["track", str(scene_dir / "audio.wav"), "--tracker", tracker, "--out", str(csv)]) == 0
    est, truth = pd.read_csv(csv), pd.read_csv(scene_dir / "truth.csv")
    cos = np.sum(est[["x", "y", "z"]].to_numpy() * truth[["x", "y", "z"]].to_numpy(), 1)
    errors = np.degrees(np.arccos(np.clip(cos, -1, 1)))[truth.vad.to_numpy(bool)]
    assert np.median(errors) < 15, (tracker, np.median(errors))
