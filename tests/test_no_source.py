"""A tracker may say "no source" for a frame: three NaNs (``doabench.NO_SOURCE``) from ``step()`` or
as a row of ``track()``. The runner and the environment take exactly that and refuse every other
non-finite output in one line; the frame metrics count such a frame at 90 degrees and the results
count them; a tracker that never says it scores as the committed results do; on LOCATA tasks such
a stamp has no active track (NaN in the submission, no false alarm)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import doabench
from doabench.cli.main import main
from doabench.envs.env import DoaEnv
from doabench.errors import InputError, TrackerError
from doabench.geometry import NO_SOURCE_ERROR_DEG, is_no_source
from doabench.metrics import aggregate, score_episode, score_frames
from doabench.runner import check_direction, check_directions, run_task

from conftest import QUICK_SCENE, ROOT


class _Silent(doabench.Tracker):
    """Says no source in every voice-inactive frame, else straight ahead."""

    name = "says-nothing-in-silence"

    def step(self, observation):
        return doabench.NO_SOURCE if not observation["vad"] else np.array([1.0, 0.0, 0.0])


class _Mute(doabench.Tracker):
    """Offline; says no source in every frame."""

    name = "mute"
    causal = False

    def track(self, episode):
        return np.full((len(episode["vad"]), 3), np.nan)


class _Returns(doabench.Tracker):
    name = "returns"

    def __init__(self, value):
        super().__init__()
        self.value = value

    def step(self, observation):
        return self.value


def test_no_source_is_three_read_only_nans():
    assert doabench.NO_SOURCE.shape == (3,) and np.isnan(doabench.NO_SOURCE).all()
    with pytest.raises(ValueError):
        doabench.NO_SOURCE[0] = 1.0
    assert bool(is_no_source(np.full(3, np.nan))) and not bool(is_no_source([np.nan, 0.0, 0.0]))
    np.testing.assert_array_equal(is_no_source(np.array([[np.nan] * 3, [1.0, 0, 0], [np.nan, 1, 0]])),
                                  [True, False, False])


@pytest.mark.parametrize("value", [np.full(3, np.nan), doabench.NO_SOURCE, [float("nan")] * 3,
                                   np.full(3, np.nan, np.float32)])
def test_three_nans_pass_the_check_as_no_source(value):
    out = check_direction(_Returns(value), value, 4)
    assert out.shape == (3,) and np.isnan(out).all() and out.flags.writeable


@pytest.mark.parametrize("value,message", [
    ([np.nan, 0.0, 0.0], "non-finite direction .* at frame 4 .*doabench.NO_SOURCE"),
    ([np.nan, np.nan, np.inf], "non-finite direction"),
    ([np.inf, 0.0, 0.0], "non-finite direction"),
    ([0.0, 0.0, 0.0], "zero vector at frame 4"),
    (np.full(2, np.nan), r"shape \(2,\) at frame 4"),
    (np.full(4, np.nan), r"shape \(4,\) at frame 4"),
    ("left", "returned str at frame 4"),
])
def test_every_other_non_unit_output_is_refused_in_one_line(value, message):
    with pytest.raises(TrackerError, match=message) as info:
        check_direction(_Returns(value), value, 4)
    assert "'returns'" in str(info.value) and "\n" not in str(info.value)


def test_offline_rows_of_nans_say_no_source_and_other_rows_are_refused():
    rows = np.array([[2.0, 0, 0], [np.nan] * 3, [0, 0, -3.0]])
    out = check_directions(_Mute(), rows, 3)
    np.testing.assert_array_equal(out[[0, 2]], [[1.0, 0, 0], [0, 0, -1.0]])
    assert np.isnan(out[1]).all()
    rows[2] = [np.nan, np.nan, 1.0]
    with pytest.raises(TrackerError, match="'mute'.*at frame 2 .*doabench.NO_SOURCE"):
        check_directions(_Mute(), rows, 3)


def test_the_environment_takes_no_source_as_an_action_scored_at_90_degrees():
    env = DoaEnv("sim-demo", features=("srp",), resolution=(4, 8), scene_overrides=QUICK_SCENE)
    _, info = env.reset(options={"episode": 0})
    _, reward, _, _, step_info = env.step(doabench.NO_SOURCE)
    assert reward == pytest.approx(-math.pi / 2) and step_info["no_source"] is True
    assert step_info["error_rad"] == pytest.approx(math.radians(NO_SOURCE_ERROR_DEG))
    _, _, _, _, step_info = env.step(np.array([1.0, 0.0, 0.0], np.float32))
    assert step_info["no_source"] is False
    with pytest.raises(InputError, match="three NaNs"):
        env.step(np.array([np.nan, 1.0, 0.0]))
    env.reset(options={"episode": 0})
    rows = np.tile([0.0, 1.0, 0.0], (info["n_frames"], 1))
    rows[::2] = np.nan
    errors = env.score_offline(rows)
    np.testing.assert_allclose(errors[::2], math.pi / 2)
    assert np.all(errors[1::2] < math.pi)


def test_no_source_frames_count_90_degrees_and_are_counted():
    t = 60
    truth = np.tile([0.0, 1.0, 0.0], (t, 1))
    est = truth.copy()
    est[::3] = np.nan
    vad = np.arange(t) >= 12
    m = score_episode(est, truth, vad, None, False, np.arange(t) * 0.192)
    n_none = len(range(0, t, 3))
    assert m["rmsae_all"] == pytest.approx(math.sqrt(n_none * 90.0 ** 2 / t))
    active_none = int(np.sum(vad[::3]))
    assert m["rmsae_nonsilent"] == pytest.approx(math.sqrt(active_none * 90.0 ** 2 / vad.sum()))
    assert m["azimuth_mae"] == pytest.approx(active_none * 90.0 / vad.sum())
    assert m["within_5"] == pytest.approx(1 - active_none / vad.sum())
    assert m["lag_frames"] == int(np.sum(vad & ~is_no_source(est) & (np.arange(t) >= 11)))
    assert np.isfinite(m["lag_sse"]).all()
    # a planar array folds the estimates it has and scores the others alike
    folded = score_frames(est, truth, vad, planar=True)
    np.testing.assert_allclose(folded.errors[::3], 90.0)


def test_a_run_counts_the_frames_without_an_estimate_and_stores_them_as_nan():
    res = run_task(_Silent(), "sim-demo", episodes=3, progress=False, scene_overrides=QUICK_SCENE, keep_frames=True)
    for row, frames in zip(res["episodes"], res["frames"]):
        silent = ~np.asarray(frames["vad"], bool)
        assert row.get("no_estimate", 0) == int(silent.sum()) and row.get("no_estimate_nonsilent", 0) == 0
        assert np.isnan(np.asarray(frames["estimates"], float)[silent]).all()
    assert "no_estimate" not in res["episodes"][0]  # an episode without such frames has no key
    assert all(res["episodes"][i]["no_estimate"] > 0 for i in (1, 2))
    none = res["summary"]["no_estimate"]
    pooled = res["summary"]["pooled"]
    assert none["frames"] == sum(r.get("no_estimate", 0) for r in res["episodes"]) and none["nonsilent_frames"] == 0
    assert none["share_all"] == pytest.approx(none["frames"] / pooled["n_frames"]) and none["share_nonsilent"] == 0
    assert none["error_deg"] == 90.0
    mute = run_task(_Mute(), "sim-demo", episodes=1, progress=False, scene_overrides=QUICK_SCENE)
    assert mute["summary"]["rmsae_all"] == pytest.approx(90.0) and mute["summary"]["rmsae_nonsilent"] == pytest.approx(90.0)
    assert mute["summary"]["no_estimate"]["share_all"] == 1.0 and mute["causal"] is False


def test_srp_max_silence_none_says_no_source_in_silences_only():
    """The same estimates on voice-active frames as the hold (same RMSAE there and lag), no source
    in every silent frame; the results pass the schema and the leaderboards' checks."""
    from doabench.results.schema import results_problem, summary_problem, validate_results

    hold, none = (run_task("srp-max:8x16", "sim-demo", episodes=[1, 2], progress=False, scene_overrides=QUICK_SCENE,
                           tracker_options=options) for options in ({}, {"silence": "none"}))
    assert none["tracker"]["options"] == {"silence": "none"} and "no_estimate" not in hold["summary"]
    assert not any("no_estimate" in row for row in hold["episodes"])
    for results in (hold, none):
        written = json.loads(json.dumps(results))  # as a results file reads back
        validate_results(written)
        assert summary_problem(written) is None and results_problem(written) is None
    for f_hold, f_none, row in zip(hold["frames"], none["frames"], none["episodes"]):
        silent = ~np.asarray(f_none["vad"], bool)
        est_hold, est_none = np.asarray(f_hold["estimates"], float), np.asarray(f_none["estimates"], float)
        np.testing.assert_array_equal(est_none[~silent], est_hold[~silent])
        assert np.isnan(est_none[silent]).all() and silent.any()
        assert row["no_estimate"] == int(silent.sum())
    assert none["summary"]["rmsae_nonsilent"] == pytest.approx(hold["summary"]["rmsae_nonsilent"], abs=1e-12)
    assert none["summary"]["rmsae_all"] > hold["summary"]["rmsae_all"]
    assert [r["lag_sse"] for r in none["episodes"]] == [r["lag_sse"] for r in hold["episodes"]]
    with pytest.raises(doabench.DoabenchError, match="silence must be one of hold, none"):
        doabench.make_tracker("srp-max", silence="off")


# -- a tracker that never says "no source" scores as it always did ---------------------------------
COMMITTED = ROOT / "results" / "sim-demo__srp-max_16x32.json"
METRICS = ("frames_scored", "frames_invalid", "rmsae_all", "rmsae_nonsilent", "mae_all", "mae", "median", "p90",
           "within_5", "within_10", "within_20", "within_30", "azimuth_mae", "n_frames", "n_nonsilent", "lag_s",
           "lag_sse", "lag_frames", "lag_speed", "speed_bands")


def test_committed_frames_score_exactly_as_committed():
    results = json.loads(COMMITTED.read_text())
    per_frame = []
    for row, f in zip(results["episodes"], results["frames"]):
        m = score_episode(np.asarray(f["estimates"]), np.asarray(f["truth"]), np.asarray(f["vad"]), f.get("valid"),
                          False, np.asarray(f["times"]))
        assert {k: m[k] for k in METRICS} == {k: row[k] for k in METRICS}
        assert "no_estimate" not in m and "no_estimate" not in row
        scored = score_frames(f["estimates"], f["truth"], f["vad"], f.get("valid"))
        per_frame.append((scored.errors, scored.az_errors, scored.vad))
    pooled = aggregate(per_frame, results["episodes"])["pooled"]
    assert pooled["rmsae_all"] == results["summary"]["rmsae_all"]
    assert pooled["rmsae_nonsilent"] == results["summary"]["rmsae_nonsilent"]


def test_a_run_of_a_tracker_that_never_says_it_gives_the_committed_numbers():
    committed = json.loads(COMMITTED.read_text())
    res = run_task("srp-max:16x32", "sim-demo", episodes=[0], progress=False)
    row, old = res["episodes"][0], committed["episodes"][0]
    assert {k: row[k] for k in METRICS} == {k: old[k] for k in METRICS}
    assert set(row) - set(old) <= {"lag_const_sse"}  # recorded since; no key for frames without an estimate
    assert "no_estimate" not in res["summary"] and "no_estimate" not in res["scoring"]
    np.testing.assert_array_equal(res["frames"][0]["estimates"], committed["frames"][0]["estimates"])


# -- LOCATA: a "no source" stamp has no active track -------------------------------------------------
@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    from fixtures.locata import write_fixture

    root = tmp_path_factory.mktemp("locata-no-source")
    write_fixture(root, tasks=(3,), duration_s=4.0, simulator="freefield", seed=1)
    return root


def _locata_run(root: Path, out: Path, silence: str) -> tuple[dict, Path]:
    sub, runs = out / f"sub-{silence}", out / f"runs-{silence}"
    assert main(["run", "--tracker", "srp-max:8x16", "--tracker-opt", f"silence={silence}", "--task", "locata-3",
                 "--locata-root", str(root), "--vad", "corpus", "--quiet", "--out", str(runs),
                 "--locata-submission", str(sub)]) == 0
    return json.loads(next(runs.glob("*.json")).read_text()), sub


def test_silence_none_leaves_no_false_track_at_silent_stamps(corpus, tmp_path):
    from doabench.locata import find_recordings
    from doabench.locata.measures import score_stamps
    from doabench.locata.stamps import stamp_truth
    from doabench.locata.submission import read_tracks, recording_folder
    from doabench.locata.tracks import frame_ends

    rec = find_recordings(corpus, "dev", 3, "benchmark2")[0]
    truth = stamp_truth(rec)
    silent_stamp = ~truth.vad[0].astype(bool)
    false_at, far, nan_rows = {}, {}, {}
    for silence in ("hold", "none"):
        results, sub = _locata_run(corpus, tmp_path, silence)
        frames = results["frames"][0]
        frame_spec = doabench.ObservationSpec.from_dict(results["observations"]).frame_spec
        window, fs = frame_spec.window, frame_spec.fs
        ends = frame_ends(results["locata"]["recordings"][0]["start_s"], frames["times"], window, fs)
        latest = np.searchsorted(ends, truth.times, side="right") - 1
        # the frames' truth VAD is the corpus VAD where the truth is valid (the maps' VAD there)
        valid = np.asarray(frames["valid"], bool)[np.maximum(latest, 0)] & (latest >= 0)
        frame_vad = np.asarray(frames["vad"], bool)[np.maximum(latest, 0)]
        frame_silent, frame_active = valid & ~frame_vad, valid & frame_vad
        tracks = read_tracks(recording_folder(sub, 3, 1, "benchmark2"), truth.required_times, truth.origin)
        az, inc = tracks.azimuth[:, truth.valid], tracks.inclination[:, truth.valid]
        nan_rows[silence] = np.isnan(az[0])
        scores = score_stamps(truth.azimuth, truth.inclination, truth.vad, az, inc)
        quiet = silent_stamp & frame_silent  # silent stamps whose latest frame is silent
        assert quiet.sum() > 5
        false_at[silence] = scores.false[quiet]
        far[silence] = results["locata"]["official"]["far"]
        if silence == "none":
            assert nan_rows["none"][frame_silent].all() and not nan_rows["none"][frame_active].any()
    assert (false_at["hold"] == 1).all()  # a held direction is a false track at every silent stamp
    assert (false_at["none"] == 0).all()  # no source: no track, no false alarm
    assert far["none"] < far["hold"]
    assert nan_rows["none"].sum() > nan_rows["hold"].sum()
