"""Metrics against hand-computed values."""
import math

import numpy as np
import pytest
import torch

from doabench.geometry import angles_to_unit, great_circle_error
from doabench.metrics import aggregate, azimuth_errors_deg, bootstrap_ci, episode_metrics, frame_errors_deg


def _rot_z(deg):
    a = math.radians(deg)
    return np.array([math.cos(a), math.sin(a), 0.0])


def test_rmsae_all_and_nonsilent_by_hand():
    truth = np.tile([1.0, 0.0, 0.0], (4, 1))
    est = np.stack([_rot_z(d) for d in (0, 10, 20, 90)])
    vad = np.array([1, 1, 0, 1], bool)
    m = episode_metrics(est, truth, vad)
    assert m["rmsae_all"] == pytest.approx(math.sqrt((0 + 100 + 400 + 8100) / 4), rel=1e-9)
    assert m["rmsae_nonsilent"] == pytest.approx(math.sqrt((0 + 100 + 8100) / 3), rel=1e-9)
    assert m["mae"] == pytest.approx(100 / 3)
    assert m["mae_all"] == pytest.approx(120 / 4)
    assert m["median"] == pytest.approx(10)
    assert m["within_5"] == pytest.approx(1 / 3)
    assert m["within_10"] == pytest.approx(2 / 3)
    assert m["within_30"] == pytest.approx(2 / 3)
    assert m["azimuth_mae"] == pytest.approx(100 / 3)
    assert (m["n_frames"], m["n_nonsilent"]) == (4, 3)


def test_great_circle_has_no_floor_for_tiny_errors():
    u = np.array([0.0, 0.0, 1.0])
    for eps in (1e-9, 1e-7, 1e-4):
        v = np.array([math.sin(eps), 0.0, math.cos(eps)])
        assert great_circle_error(u, v) == pytest.approx(eps, rel=1e-6)
    # float32 torch too: arccos of a clamped float32 dot would give 0 or ~3e-4 rad here
    import torch

    e = great_circle_error(torch.tensor(u, dtype=torch.float32), torch.tensor([1e-5, 0.0, 1.0], dtype=torch.float32))
    assert float(e) == pytest.approx(1e-5, rel=1e-3)


def test_antipodal_and_unnormalised_inputs():
    assert frame_errors_deg(np.array([[2.0, 0, 0]]), np.array([[-1.0, 0, 0]]))[0] == pytest.approx(180)
    assert frame_errors_deg(np.array([[0, 5.0, 0]]), np.array([[1.0, 0, 0]]))[0] == pytest.approx(90)


def test_azimuth_error_wraps():
    e = angles_to_unit(np.array([math.pi / 2]), np.array([math.radians(179)]))
    t = angles_to_unit(np.array([math.pi / 2]), np.array([math.radians(-179)]))
    assert azimuth_errors_deg(e, t)[0] == pytest.approx(2.0)


def test_pooled_versus_episode_mean():
    # episode A: errors 10 (1 frame); episode B: errors 0, 0, 0 (3 frames)
    per_frame = [(np.array([10.0]), np.array([10.0]), np.array([True])),
                 (np.zeros(3), np.zeros(3), np.ones(3, bool))]
    rows = [{"rmsae_all": 10.0, "rmsae_nonsilent": 10.0}, {"rmsae_all": 0.0, "rmsae_nonsilent": 0.0}]
    agg = aggregate(per_frame, rows)
    assert agg["pooled"]["rmsae_all"] == pytest.approx(math.sqrt(100 / 4))
    assert agg["episode_mean"]["rmsae_all"] == pytest.approx(5.0)


def test_silent_only_episode_gives_nan_not_crash():
    m = episode_metrics(np.tile([1.0, 0, 0], (3, 1)), np.tile([0, 1.0, 0], (3, 1)), np.zeros(3, bool))
    assert m["rmsae_all"] == pytest.approx(90)
    assert math.isnan(m["rmsae_nonsilent"])


def test_bootstrap_ci_brackets_the_estimate_and_collapses_for_equal_episodes():
    rng = np.random.default_rng(0)
    per = [(rng.normal(0, 10, 50), np.ones(50, bool)) for _ in range(20)]
    pooled = math.sqrt(np.mean(np.concatenate([e for e, _ in per]) ** 2))
    lo, hi = bootstrap_ci(per, "rmsae_all")
    assert lo < pooled < hi
    same = [(np.full(10, 3.0), np.ones(10, bool))] * 5
    lo, hi = bootstrap_ci(same, "rmsae_nonsilent")
    assert lo == pytest.approx(3.0) and hi == pytest.approx(3.0)


def test_pooled_from_rows_equals_pooling_the_frames():
    from doabench.metrics import error_summary, pooled_from_rows

    rng = np.random.default_rng(1)
    per_frame, rows = [], []
    for n in (50, 80, 20):
        e = np.abs(rng.normal(0, 10, n))
        v = rng.random(n) > 0.3
        per_frame.append((e, e, v))
        rows.append(error_summary(e, v))
    pooled = aggregate(per_frame, rows)["pooled"]
    from_rows = pooled_from_rows(rows)
    assert from_rows["rmsae_all"] == pytest.approx(pooled["rmsae_all"])
    assert from_rows["rmsae_nonsilent"] == pytest.approx(pooled["rmsae_nonsilent"])
    assert bootstrap_ci([(e, v) for e, _, v in per_frame], "rmsae_all") == pytest.approx(from_rows["rmsae_all_ci95"])


@pytest.mark.parametrize("scale", [1e200, 1e-200, 1e300])
def test_huge_or_tiny_direction_is_scored_as_the_direction_it_is(scale):
    """[1e200, 0, 0] is the x axis: its norm overflows, so a naive normalisation made it [0, 0, 0]
    and scored 0 deg against any truth."""
    from doabench.geometry import normalize, robust_norm

    truth = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    est = np.array([[scale, 0.0, 0.0], [scale, 0.0, 0.0]])
    np.testing.assert_allclose(frame_errors_deg(est, truth), [90.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(normalize(est), [[1, 0, 0], [1, 0, 0]])
    np.testing.assert_allclose(normalize(np.array([scale, scale, 0.0])), [2 ** -0.5, 2 ** -0.5, 0])
    assert robust_norm(np.array([3 * scale, 4 * scale, 0.0])) == pytest.approx(5 * scale)
    m = episode_metrics(est, truth, np.ones(2, bool))
    assert m["rmsae_all"] == pytest.approx(np.sqrt(90.0 ** 2 / 2))
    assert m["azimuth_mae"] == pytest.approx(45.0)
    t = normalize(torch.tensor([[scale, 0.0, 0.0]], dtype=torch.float64))
    torch.testing.assert_close(t, torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64))


def test_one_bootstrap_serves_results_files_and_compare() -> None:
    """A results file's interval is the one-stratum case of compare's stratified bootstrap: the
    same draws, the same numbers; the paired bootstrap draws with the same resampler and takes the
    same percentile interval, and no module of compare resamples or takes percentiles of its own."""
    import inspect

    import doabench.metrics.paired as paired
    import doabench.reporting.compare as cmp
    import doabench.reporting.compare_report as report
    import doabench.reporting.pairing as pairing
    import doabench.reporting.silence as silence
    from doabench.metrics import bootstrap_ci_from_sums, bootstrap_counts, percentile_interval

    assert paired.bootstrap_counts is bootstrap_counts and paired.percentile_interval is percentile_interval
    for module in (cmp, report, pairing, silence):
        source = inspect.getsource(module)
        assert "default_rng" not in source and "percentile(" not in source and "def _rms" not in source, module
    rng = np.random.default_rng(2)
    n = rng.integers(40, 120, 30).astype(float)
    sq = rng.uniform(3.0, 30.0, 30) ** 2 * n
    counts = bootstrap_counts([np.arange(30)], 30, 1000, seed=0)
    assert counts.shape == (1000, 30) and np.all(counts.sum(1) == 30)
    expected = np.percentile(np.sqrt(counts @ sq / (counts @ n)), [2.5, 97.5])
    assert bootstrap_ci_from_sums(sq, n) == pytest.approx(tuple(expected), rel=1e-12)
    # stratified: each stratum keeps its own size in every resample
    strata = [np.arange(0, 10), np.arange(10, 30)]
    split = bootstrap_counts(strata, 30, 500, seed=3)
    assert np.all(split[:, :10].sum(1) == 10) and np.all(split[:, 10:].sum(1) == 20)


def _arc_truth(n_frames: int, period_s: float, deg_per_s: float) -> np.ndarray:
    from doabench.geometry import angles_to_unit

    az = np.radians(deg_per_s * np.arange(n_frames) * period_s)
    return angles_to_unit(np.full(n_frames, np.pi / 2), az)


@pytest.mark.parametrize("delay_s", [0.0, 0.5, 1.25])
def test_a_tracker_that_outputs_the_truth_late_is_measured_at_that_lag(delay_s):
    from doabench.metrics import delayed_truth, motion_metrics

    period = 0.192  # the paper's hop
    truth = _arc_truth(150, period, 20.0)
    late = delayed_truth(truth, np.array([delay_s / period]))[0]
    late = np.where(np.isnan(late), truth[:1], late)
    m = motion_metrics(late, truth, np.ones(150, bool), period)
    assert m["lag_s"] == pytest.approx(delay_s)
    assert m["lag_sse"][int(round(delay_s / 0.05))] == pytest.approx(0.0, abs=1e-12)
    # every frame moves at 20 deg/s: all in the 15-30 band, with the error of a delay of delay_s
    bands = m["speed_bands"]
    assert bands["15-30"][1] == 150 and bands["<5"][1] == bands["5-15"][1] == bands[">30"][1] == 0
    assert np.sqrt(bands["15-30"][0] / 150) <= 20.0 * delay_s + 1e-6


def test_a_static_source_has_no_defined_lag_and_pooling_skips_it():
    from doabench.metrics import lag_from_curves, motion_metrics

    period = 0.192
    still = np.repeat(_arc_truth(1, period, 0.0), 100, axis=0)
    m = motion_metrics(still, still, np.ones(100, bool), period)
    assert m["lag_s"] is None and "static" in m["lag_note"]
    truth = _arc_truth(100, period, 30.0)
    moving = motion_metrics(truth, truth, np.ones(100, bool), period)
    assert lag_from_curves([m, moving]) == (0.0, "")
    silent = motion_metrics(truth, truth, np.zeros(100, bool), period)
    assert silent["lag_s"] is None and "voice-active" in silent["lag_note"]


def _walk() -> tuple[np.ndarray, float]:
    """A talker walking 150 deg along the horizon at 10 deg/s for 15 s, frames every 0.192 s."""
    period = 0.192
    return _arc_truth(80, period, 10.0), period


@pytest.mark.parametrize("where", ["start", "middle", "end", "off the path"])
def test_a_tracker_that_points_one_way_has_no_defined_lag(where):
    """One fixed direction fits some delay best by chance (the end of the range when it points
    where the talker started); it does not follow the talker, so it has no lag, and the note says why."""
    from doabench.metrics import motion_metrics

    truth, period = _walk()
    fixed = {"start": truth[0], "middle": truth[40], "end": truth[-1],
             "off the path": angles_to_unit(np.radians(45.0), np.radians(30.0))}[where]
    m = motion_metrics(np.tile(fixed, (len(truth), 1)), truth, np.ones(len(truth), bool), period)
    assert m["lag_s"] is None, m
    assert "not following the talker" in m["lag_note"] and m["lag_note"].endswith("no defined lag")
    if where == "start":  # the truth of 2 s ago is nearest to where it points
        assert "end of the 2 s search range" in m["lag_note"]
    # its curve is nowhere below the best constant direction's error
    assert min(m["lag_sse"]) >= 0.999 * m["lag_const_sse"] > 0


def test_a_follower_keeps_its_lag_and_fixed_episodes_pool_to_none():
    """A noisy tracker 0.5 s late still measures 0.5 s; three episodes of fixed directions pool to
    no lag, in an episode's row and in the run's summary alike."""
    from doabench.metrics import delayed_truth, lag_from_curves, motion_metrics
    from doabench.runner.summary import lag_summary

    truth, period = _walk()
    late = delayed_truth(truth, np.array([0.5 / period]))[0]
    late = np.where(np.isnan(late), truth[:1], late)
    noisy = late + np.radians(1.0) * np.random.default_rng(0).standard_normal(late.shape)
    follower = motion_metrics(noisy / np.linalg.norm(noisy, axis=1, keepdims=True), truth,
                              np.ones(len(truth), bool), period)
    assert follower["lag_s"] == pytest.approx(0.5) and "lag_note" not in follower
    rows = [motion_metrics(np.tile(truth[i], (len(truth), 1)), truth, np.ones(len(truth), bool), period)
            for i in (0, 40, 79)]
    lag, note = lag_from_curves(rows)
    assert lag is None and "not following the talker" in note
    summary = lag_summary(rows)
    assert summary["lag_s"] is None and "not following the talker" in summary["lag_note"]


def test_the_best_constant_direction_is_the_spherical_mean():
    """``lag_const_sse`` is the smallest error a fixed direction reaches: no direction of a fine
    grid does better, and the spherical mean of an arc is its midpoint."""
    from doabench.geometry import grid_unit_vectors
    from doabench.metrics import best_constant_sse

    truth, _ = _walk()
    best = best_constant_sse(truth[None])[0]
    grid = grid_unit_vectors(90, 180).reshape(-1, 3)
    errors = np.degrees(great_circle_error(truth[None, :, :], grid[:, None, :]))  # (grid, frames)
    assert np.square(errors).sum(1).min() >= 0.999 * best
    midpoint = np.square(frame_errors_deg(np.tile(truth[40] + truth[39], (80, 1)), truth)).sum()
    assert best == pytest.approx(midpoint, rel=1e-3)


def test_curves_written_before_the_constant_direction_are_checked_by_the_range_only():
    """Older results rows have no ``lag_const_sse``: their lag is the curve's minimum unless that
    is the end of the search range."""
    from doabench.metrics import LAG_MAX_S, LAG_STEP_S, lag_from_curves, lag_grid

    d = len(lag_grid(LAG_MAX_S, LAG_STEP_S))
    inside = {"lag_sse": [(k - 10) ** 2 + 1.0 for k in range(d)], "lag_frames": 8, "lag_speed": 20.0}
    at_end = {"lag_sse": [float(d - k) for k in range(d)], "lag_frames": 8, "lag_speed": 20.0}
    assert lag_from_curves([inside]) == (pytest.approx(0.5), "")
    lag, note = lag_from_curves([at_end])
    assert lag is None and "end of the 2 s search range" in note
