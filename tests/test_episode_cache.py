"""DOABENCH_EPISODE_CACHE: several trackers, one simulation per episode, same numbers."""
from __future__ import annotations

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
