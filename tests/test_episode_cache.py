"""DOABENCH_EPISODE_CACHE: several trackers, one simulation per episode, same numbers."""
from __future__ import annotations

import pytest

import doabench

QUICK = {"duration_s": 3.0, "n_points": 12}


def test_cached_episodes_score_exactly_as_rendered_ones(tmp_path, monkeypatch):
    fresh = doabench.run(tracker="srp-max:8x16", task="sim-demo", episodes=2, progress=False,
                         scene_overrides=QUICK)
    monkeypatch.setenv("DOABENCH_EPISODE_CACHE", str(tmp_path))
    first = doabench.run(tracker="srp-max:8x16", task="sim-demo", episodes=2, progress=False, scene_overrides=QUICK)
    files = sorted(tmp_path.glob("sim-demo-*.npz"))
    assert len(files) == 2
    stamps = [f.stat().st_mtime_ns for f in files]
    again = doabench.run(tracker="srp-kalman:8x16", task="sim-demo", episodes=2, progress=False, scene_overrides=QUICK)
    assert [f.stat().st_mtime_ns for f in files] == stamps  # read, not rendered again
    for a, b in ((fresh, first),):
        assert a["frames"][0]["estimates"] == b["frames"][0]["estimates"]
        assert a["summary"]["rmsae_all"] == b["summary"]["rmsae_all"]
    assert again["episodes"][1]["seed"] == fresh["episodes"][1]["seed"]
    # other scene overrides are other episodes: another key, never a stale file
    doabench.run(tracker="srp-max:8x16", task="sim-demo", episodes=1, progress=False,
                 scene_overrides={**QUICK, "duration_s": 2.0})
    assert len(list(tmp_path.glob("sim-demo-*.npz"))) == 3
    files[0].write_bytes(b"not an npz")  # a damaged file is rendered again
    repaired = doabench.run(tracker="srp-max:8x16", task="sim-demo", episodes=2, progress=False, scene_overrides=QUICK)
    assert repaired["summary"]["rmsae_all"] == fresh["summary"]["rmsae_all"]


HEAL_TASK = "test-cache-heals-tiny"


def _heal_task() -> str:
    if HEAL_TASK not in doabench.available_tasks():
        doabench.register_task({"id": HEAL_TASK, "version": 1, "kind": "simulated", "episodes": 1, "base_seed": 9,
                                "speech": {"corpus": "embedded"},
                                "scene": {"duration_s": 1.0, "n_points": 8, "t60": [0.2, 0.3]}})
    return HEAL_TASK


def _run(out, capsys) -> tuple[float, list[str]]:
    """``doabench run`` of the tiny task: its RMSAE and the lines it wrote on standard error."""
    import json

    from doabench.cli.main import main

    code = main(["run", "--tracker", "srp-max:4x8", "--task", _heal_task(), "--out", str(out), "--quiet",
                 "--replace"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 0, err
    results = json.loads(next(out.glob("*.json")).read_text())
    return results["summary"]["rmsae_all"], err


def test_a_damaged_or_changed_cached_episode_is_rendered_again(tmp_path, monkeypatch, capsys):
    """A flipped byte (once a BadZipFile on every later run) or changed audio in a valid file (once
    used silently, RMSAE 3.56 -> 14.39): the episode is rendered again with one warning line
    naming the file, the scores are the rendered episode's, and the file is whole again."""
    import numpy as np

    cache = tmp_path / "cache"
    monkeypatch.setenv("DOABENCH_EPISODE_CACHE", str(cache))
    rendered, err = _run(tmp_path / "r0", capsys)
    assert not err
    (path,) = cache.glob("*.npz")
    stamp = path.stat().st_mtime_ns
    assert _run(tmp_path / "r1", capsys) == (rendered, [])  # read, not rendered again
    assert path.stat().st_mtime_ns == stamp

    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte inside the audio
    path.write_bytes(bytes(data))
    rmsae, err = _run(tmp_path / "r2", capsys)
    assert rmsae == rendered and len(err) == 1, err
    assert "warning: episode cache:" in err[0] and path.name in err[0] and "rendered again" in err[0], err
    assert _run(tmp_path / "r3", capsys) == (rendered, [])  # stored afresh, whole

    with np.load(path) as z:  # a valid file whose audio was changed, its checksum kept
        arrays = {name: z[name] for name in z.files}
    arrays["audio"] = np.random.default_rng(0).normal(0, 0.1, arrays["audio"].shape).astype(np.float32)
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    rmsae, err = _run(tmp_path / "r4", capsys)
    assert rmsae == rendered and len(err) == 1 and "checksum does not match" in err[0], err

    # the checksum covers the name it is stored under: a valid file copied to another episode's
    # name is not that episode
    from doabench.runner import episode_cache

    episode_cache._load(path)  # whole again
    copied = path.with_name(path.name.replace(".npz", "1.npz"))
    copied.write_bytes(path.read_bytes())
    with pytest.raises(ValueError, match="checksum does not match"):
        episode_cache._load(copied)

def test_an_episode_cache_path_that_is_a_file_is_one_line(tmp_path, monkeypatch, capsys):
    from doabench.cli.main import main

    not_a_folder = tmp_path / "cache"
    not_a_folder.write_text("a file\n")
    monkeypatch.setenv("DOABENCH_EPISODE_CACHE", str(not_a_folder))
    code = main(["run", "--tracker", "srp-max:4x8", "--task", _heal_task(), "--out", str(tmp_path / "r"),
                 "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "Traceback" not in err, err
    assert f"the episode cache DOABENCH_EPISODE_CACHE={not_a_folder} is not a folder" in err
    assert not_a_folder.read_text() == "a file\n" and not (tmp_path / "r").exists()
