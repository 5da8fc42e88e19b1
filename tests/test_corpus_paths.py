"""One rule for where a corpus is: ``--librispeech`` / ``--locata-root``, the Python keyword (a
task's run-time option) and ``DOABENCH_LIBRISPEECH`` / ``DOABENCH_LOCATA`` resolve through
:func:`doabench.corpora.paths.corpus_root` (explicit path first, then the environment), so the same
path gives the same result whichever way it is given."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from doabench.cli.main import main
from doabench.corpora.paths import LIBRISPEECH_ENV, LOCATA_ENV, corpus_root

from conftest import ROOT

CLIPS = ROOT / "doabench" / "data" / "speech"


@pytest.fixture
def official_root(tmp_path) -> Path:
    """A LibriSpeech root laid out as the official one, with several subsets."""
    root = tmp_path / "LibriSpeech"
    for n, subset in enumerate(("dev-clean", "test-clean", "train-clean-100")):
        for speaker in range(2):
            chapter = root / subset / str(100 + 10 * n + speaker) / str(1000 + speaker)
            chapter.mkdir(parents=True)
            for utt in range(2):
                shutil.copy(CLIPS / f"clip{1 + (speaker * 2 + utt) % 6}.flac",
                            chapter / f"{100 + 10 * n + speaker}-{1000 + speaker}-{utt:04d}.flac")
    return root


def test_precedence_flag_then_environment(monkeypatch, tmp_path):
    monkeypatch.delenv(LIBRISPEECH_ENV, raising=False)
    monkeypatch.delenv(LOCATA_ENV, raising=False)
    assert corpus_root("librispeech") is None and corpus_root("locata", "") is None
    monkeypatch.setenv(LIBRISPEECH_ENV, "/from/env")
    monkeypatch.setenv(LOCATA_ENV, "/locata/env")
    assert corpus_root("librispeech") == "/from/env"
    assert corpus_root("librispeech", "") == "/from/env"  # an empty flag is not given
    assert corpus_root("librispeech", tmp_path) == str(tmp_path)  # the flag or keyword wins
    assert corpus_root("locata") == "/locata/env" and corpus_root("locata", "/given") == "/given"


def _simulate(out: Path, *extra: str) -> dict:
    assert main(["simulate", "--duration", "1", "--seed", "2", "--out", str(out), *extra]) == 0
    return json.loads((out / "scene.json").read_text())["scene"]


def test_simulate_treats_the_flag_and_the_environment_alike(official_root, tmp_path, monkeypatch, capsys):
    """The official root (several subsets) picks test-clean, given by flag or by environment."""
    monkeypatch.delenv(LIBRISPEECH_ENV, raising=False)
    by_flag = _simulate(tmp_path / "flag", "--librispeech", str(official_root))
    monkeypatch.setenv(LIBRISPEECH_ENV, str(official_root))
    by_env = _simulate(tmp_path / "env")
    assert by_flag["speech"]["subset"] == by_env["speech"]["subset"] == "test-clean"
    assert by_flag["speech"] == by_env["speech"]
    assert (tmp_path / "flag" / "audio.wav").read_bytes() == (tmp_path / "env" / "audio.wav").read_bytes()
    # the flag wins over the environment, and --subset applies whichever way the root came
    monkeypatch.setenv(LIBRISPEECH_ENV, str(tmp_path / "nowhere"))
    assert _simulate(tmp_path / "both", "--librispeech", str(official_root))["speech"] == by_flag["speech"]
    monkeypatch.setenv(LIBRISPEECH_ENV, str(official_root))
    assert _simulate(tmp_path / "sub", "--subset", "dev-clean")["speech"]["subset"] == "dev-clean"


def test_a_librispeech_path_that_is_a_file_says_so(tmp_path, monkeypatch, capsys):
    """A file given as the corpus (an archive not yet unpacked) is "not a folder", by flag or by
    environment alike, not "does not exist"."""
    archive = tmp_path / "test-clean.tar.gz"
    archive.write_bytes(b"\x1f\x8b not unpacked")
    monkeypatch.delenv(LIBRISPEECH_ENV, raising=False)
    assert main(["simulate", "--duration", "1", "--out", str(tmp_path / "a"), "--librispeech", str(archive)]) == 2
    monkeypatch.setenv(LIBRISPEECH_ENV, str(archive))
    assert main(["simulate", "--duration", "1", "--out", str(tmp_path / "b"), "--subset", "test-clean"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 2 and "Traceback" not in "".join(errors), errors
    for err in errors:
        assert f"LibriSpeech path {archive} is not a folder" in err and "does not exist" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["test-clean.tar.gz"]


def test_a_task_finds_librispeech_by_keyword_or_environment(official_root, monkeypatch):
    from doabench.envs.sources import make_speech_source

    speech = {"corpus": "librispeech", "subset": "test-clean"}
    monkeypatch.delenv(LIBRISPEECH_ENV, raising=False)
    by_keyword = make_speech_source(speech, str(official_root))
    monkeypatch.setenv(LIBRISPEECH_ENV, str(official_root))
    by_env = make_speech_source(speech, None)
    assert (by_keyword.root, by_keyword.subset) == (by_env.root, by_env.subset)
    assert by_keyword.chapters == by_env.chapters


def test_locata_flag_and_environment_give_the_same_run(tmp_path, monkeypatch, capsys):
    from fixtures.locata import write_fixture

    root = tmp_path / "locata"
    write_fixture(root, tasks=(1,), duration_s=2.0, simulator="builtin", t60=0.2, seed=5)
    args = ["run", "--tracker", "srp-max:4x8", "--task", "locata-1", "--quiet", "--no-frames"]
    monkeypatch.delenv(LOCATA_ENV, raising=False)
    assert main([*args, "--locata-root", str(root), "--out", str(tmp_path / "flag")]) == 0
    monkeypatch.setenv(LOCATA_ENV, str(root))
    assert main([*args, "--out", str(tmp_path / "env")]) == 0
    a, b = (json.loads(next((tmp_path / d).glob("*.json")).read_text()) for d in ("flag", "env"))
    assert a["summary"] == b["summary"]
    assert [r["rmsae_all"] for r in a["episodes"]] == [r["rmsae_all"] for r in b["episodes"]]
