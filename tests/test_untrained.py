"""A learned tracker without trained weights refuses to run unless weights=random is
given on purpose; such runs are marked untrained in the results and on the leaderboards. Building
the model (describe, docs, training from scratch) still works."""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest

import doabench
from doabench.cli.main import main
from doabench.errors import ConfigError

from conftest import QUICK_SCENE

UNTRAINED = "cross3d:12x24"  # no shipped weights for 12x24 maps


def _one_line_error(capsys, command: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"doabench {command}: error:") and "\n" not in err, err
    return err


def test_run_refuses_an_untrained_model_and_writes_nothing(tmp_path: Path, capsys) -> None:
    out = tmp_path / "results"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["run", "--tracker", UNTRAINED, "--task", "sim-demo", "--episodes", "1", "--quiet",
                     "--out", str(out)]) == 2
    err = _one_line_error(capsys, "run")
    assert "no trained weights for 12x24 maps" in err and "--tracker-opt weights=random" in err
    assert not out.exists()  # no results file, no journal, no folder


def test_track_refuses_an_untrained_model(tmp_path: Path, capsys) -> None:
    import numpy as np
    import soundfile as sf

    wav = tmp_path / "rec.wav"
    sf.write(wav, np.zeros((16000, 12), np.float32), 16000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["track", str(wav), "--array", "nao", "--tracker", UNTRAINED, "--out", str(tmp_path / "d.csv")]) == 2
    assert "no trained weights" in _one_line_error(capsys, "track")
    assert not (tmp_path / "d.csv").exists()


def test_python_api_refuses_and_names_the_keyword() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ConfigError, match=r"tracker_options=\{'weights'"):
            doabench.run(tracker=UNTRAINED, task="sim-demo", episodes=1, progress=False)
        tracker = doabench.make_tracker(UNTRAINED)  # building it is fine (describe, training from scratch)
    assert tracker.describe()["trained"] is False


def test_describe_still_shows_an_untrained_model(capsys) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["describe", "--tracker", UNTRAINED]) == 0
    assert "12x24" in capsys.readouterr().out


def test_explicit_random_runs_and_is_marked_untrained(tmp_path: Path) -> None:
    from doabench.reporting.leaderboard import build_leaderboards
    from doabench.results.writer import write_results

    results = doabench.run(tracker="cross3d:4x8", task="sim-demo", episodes=1, progress=False,
                           tracker_options={"weights": "random"}, scene_overrides=QUICK_SCENE)
    assert results["tracker"]["trained"] is False and results["tracker"]["untrained"] is True
    json_path, _ = write_results(results, tmp_path / "results")
    assert json.loads(json_path.read_text())["tracker"]["untrained"] is True
    files = build_leaderboards(tmp_path / "results")
    page = files["sim-demo.md"]
    # the run's scene overrides are part of its identity, so the row names them too
    assert "`cross3d:4x8 (weights=random) [scene_overrides=" in page and "**(untrained)**" in page
    assert "UNTRAINED (random weights)" in page
    assert ",untrained," in files["sim-demo.csv"]
    # A trained model's run is not marked.
    trained = doabench.run(tracker="cross3d:4x8", task="sim-demo", episodes=1, progress=False,
                           scene_overrides=QUICK_SCENE)
    assert trained["tracker"]["trained"] is True and "untrained" not in trained["tracker"]


def test_cli_refusal_is_the_only_line_on_stderr(tmp_path: Path, capsys) -> None:
    """The learned tracker warns Python callers that it fell back to random weights; on the
    command line the refusal says it, so no warning may print above it (warnings not silenced)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["run", "--tracker", UNTRAINED, "--task", "sim-demo", "--episodes", "1", "--quiet",
                     "--out", str(tmp_path / "results")]) == 2
        assert main(["export", "--tracker", UNTRAINED, "--out", str(tmp_path / "m.onnx")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith("doabench run: error:") and err[1].startswith(
        "doabench export: error:"), err
    assert not caught, [str(w.message) for w in caught]  # none was raised either
    assert not (tmp_path / "m.onnx").exists()


def test_cli_prints_a_warning_as_one_line(tmp_path: Path, capsys) -> None:
    """A warning raised while a command runs (here by a tracker plugin as it is built) prints as
    ``doabench COMMAND: warning: ...`` on one line, without Python's file, line and source line."""
    import numpy as np

    @doabench.register_tracker("toy-warning-test")
    class Warns(doabench.Tracker):
        observation_spec = doabench.ObservationSpec.of(("srp",))

        def __init__(self, **options) -> None:
            super().__init__(**options)
            warnings.warn("toy tracker: this is\na warning", UserWarning)

        def step(self, observation):
            return np.array([0.0, 0.0, 1.0])

    shown_before = warnings.showwarning
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert main(["run", "--tracker", "toy-warning-test", "--task", "sim-demo", "--episodes", "1", "--quiet",
                     "--no-frames", "--out", str(tmp_path / "results")]) == 0
    assert warnings.showwarning is shown_before  # Python's own format again after main()
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["doabench run: warning: toy tracker: this is a warning"], err
