"""`doabench track` on a user's recording: output format, truth agreement and input errors."""
from pathlib import Path

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
    assert list(est.columns) == ["time_s", "elevation_deg", "azimuth_deg", "x", "y", "z", "vad"]
    assert set(est.vad) <= {0, 1} and est.vad.sum() > 0
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


def test_track_refuses_an_output_that_is_an_input(scene_dir, tmp_path, capsys):
    import shutil

    rec = tmp_path / "in.wav"
    shutil.copy(scene_dir / "audio.wav", rec)
    before = rec.read_bytes()
    assert main(["track", str(rec), "--out", str(rec)]) == 2
    assert main(["track", str(rec), "--out", str(tmp_path / "x.csv"), "--plot", str(rec)]) == 2
    assert rec.read_bytes() == before and not (tmp_path / "x.csv").exists()
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 2


def test_track_bad_outputs_are_refused_before_the_work(scene_dir, tmp_path, capsys, monkeypatch):
    import os

    rec = str(scene_dir / "audio.wav")
    folder = tmp_path / "adir"
    folder.mkdir()
    (tmp_path / "afile").write_text("x")
    calls = []
    import doabench.cli.track as track_cli

    monkeypatch.setattr(track_cli, "track_recording", lambda *a, **k: calls.append(1))
    cases = [["--out", str(folder)], ["--out", str(tmp_path / "afile" / "x.csv")],
             ["--out", str(tmp_path / "o.csv"), "--plot", str(tmp_path / "x.xyz")]]
    for extra in cases:
        assert main(["track", rec, *extra]) == 2, extra
        err = capsys.readouterr().err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    real_access = os.access
    locked = tmp_path / "locked"
    locked.mkdir()
    monkeypatch.setattr(os, "access", lambda p, mode, **k: False if Path(p) == locked else real_access(p, mode, **k))
    assert main(["track", rec, "--out", str(locked / "o.csv")]) == 2
    assert calls == [] and not (tmp_path / "o.csv").exists() and not list(locked.iterdir())


def test_digital_silence_warns_and_the_csv_has_a_vad_column(tmp_path, capsys):
    rec = tmp_path / "silence.wav"
    sf.write(rec, np.zeros((16000 * 2, 12), np.float32), 16000, subtype="FLOAT")
    out = tmp_path / "s.csv"
    for vad in ("webrtc", "none"):
        assert main(["track", str(rec), "--vad", vad, "--out", str(out)]) == 0
        assert "warning" in capsys.readouterr().err
        est = pd.read_csv(out)
        assert "vad" in est.columns and len(est) > 0 and (est.vad == 0).all()


def test_features_zero_sample_rate_is_refused(scene_dir, tmp_path, capsys):
    out = tmp_path / "f.npy"
    assert main(["features", str(scene_dir / "audio.wav"), "--fs", "0", "--resample", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_track_scores_against_the_truth_that_simulate_writes(scene_dir, tmp_path, capsys):
    csv, png = tmp_path / "doa.csv", tmp_path / "doa.png"
    assert main(["track", str(scene_dir / "audio.wav"), "--tracker", "srp-max:32x64", "--truth",
                 str(scene_dir / "truth.csv"), "--out", str(csv), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "RMSAE" in out and "non-silent" in out
    est = pd.read_csv(csv)
    assert est.columns[-1] == "error_deg"
    truth = pd.read_csv(scene_dir / "truth.csv")
    cos = np.sum(est[["x", "y", "z"]].to_numpy() * truth[["x", "y", "z"]].to_numpy(), 1)
    assert np.allclose(est.error_deg, np.degrees(np.arccos(np.clip(cos, -1, 1))), atol=0.3)  # CSV keeps 4 decimals
    rmsae_printed = float(out.split("RMSAE ", 1)[1].split()[0])
    assert rmsae_printed == pytest.approx(float(np.sqrt(np.mean(est.error_deg ** 2))), abs=0.05)
    assert png.stat().st_size > 1000
    # A truth table on another frame grid is a one-line error, before anything is written.
    bad = tmp_path / "short.csv"
    truth.iloc[:-2].to_csv(bad, index=False)
    assert main(["track", str(scene_dir / "audio.wav"), "--truth", str(bad), "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "frames but the tracker produced" in err and "\n" not in err
    assert not (tmp_path / "x.csv").exists()
