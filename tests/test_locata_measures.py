"""LOCATA's tracking measures (doabench.locata.measures) against values worked out by hand.

Stamps are 0.1 s apart unless a test says otherwise; angles are given in degrees and converted.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from doabench.locata.measures import (OSPA_ORDERS, assign, ospa_key, recording_measures, score_stamps,
                                      task_averages, voice_periods)

C = 30.0  # the OSPA cut-off, degrees
R = np.radians


def _times(n: int) -> np.ndarray:
    return np.arange(n) * 0.1


def _measures(truth_az_deg, vad, est_az_deg, mode="official", truth_inc_deg=None, est_inc_deg=None, names=None):
    """recording_measures on degree lists: truth ``(S, T)``, estimates ``(K, T)`` (NaN: none)."""
    truth = np.atleast_2d(np.asarray(truth_az_deg, float))
    est = np.atleast_2d(np.asarray(est_az_deg, float))
    t_inc = np.full_like(truth, 90.0) if truth_inc_deg is None else np.atleast_2d(np.asarray(truth_inc_deg, float))
    e_inc = np.full_like(est, np.nan) if est_inc_deg is None else np.atleast_2d(np.asarray(est_inc_deg, float))
    vad = np.atleast_2d(np.asarray(vad, bool))
    return recording_measures(_times(truth.shape[1]), R(truth), R(t_inc), vad, R(est), R(e_inc), mode, names)


def _where(vad, values):
    """``values`` where ``vad`` is 1, NaN elsewhere."""
    return np.where(np.asarray(vad, bool), np.asarray(values, float), np.nan)


# -- periods -------------------------------------------------------------------------------------
def test_voice_periods_official_pair_starts_and_ends_in_order():
    vad = [0, 1, 1, 0, 0, 1, 1]
    assert voice_periods(vad, "official") == voice_periods(vad, "corrected") == [(1, 2), (5, 6)]
    # A run active at the first stamp has no start: the one start (5) is paired with the first end (2).
    early = [1, 1, 1, 0, 0, 1, 1, 1, 0, 0]
    assert voice_periods(early, "official") == [(5, 2)]
    assert voice_periods(early, "corrected") == [(0, 2), (5, 7)]
    assert voice_periods([1, 1, 1], "official") == [] and voice_periods([1, 1, 1], "corrected") == [(0, 2)]
    assert voice_periods([0, 0], "official") == voice_periods([], "corrected") == []


# -- a perfect submission ------------------------------------------------------------------------
@pytest.mark.parametrize("mode", ["official", "corrected"])
def test_a_perfect_track_scores_no_error_full_detection_and_no_swap(mode):
    vad = [0, 0, 1, 1, 1, 1, 0, 0, 1, 1]
    truth = np.linspace(-170, 170, 10)
    m = _measures(truth, vad, _where(vad, truth), mode, truth_inc_deg=np.full(10, 75.0),
                  est_inc_deg=_where(vad, np.full(10, 75.0)))
    s = m.sources["source1"]
    assert s.az_error_deg == s.az_error_ungated_deg == s.inc_error_deg == [0.0, 0.0]
    assert s.pd == [1.0, 1.0] and s.latency_s == 0.0 and s.swaps == 0
    assert s.swap_rate == s.frag_rate == 0.0
    assert m.far == m.far_vap == 0.0 and m.mota == [0.0]
    assert m.ospa_deg == {ospa_key(p): 0.0 for p in OSPA_ORDERS}
    assert s.periods_s == [(0.2, pytest.approx(0.5)), (pytest.approx(0.8), pytest.approx(0.9))]


# -- misses, latency and fragmentation -----------------------------------------------------------
def test_a_gap_fragments_the_track_and_official_latency_is_the_first_missed_stamps_time():
    vad = [0, 1, 1, 1, 1, 1, 0]
    est = [np.nan, 10, 10, np.nan, 10, 10, np.nan]  # detected, detected, missed, detected, detected
    for mode in ("official", "corrected"):
        s = _measures(np.full(7, 10.0), vad, est, mode).sources["source1"]
        assert s.pd == [pytest.approx(4 / 5)]
        # one missed -> detected step within the period (0.4 s long)
        assert s.frag_rate == pytest.approx(1 / 0.4) and s.swap_rate == 0.0
    # As released: the first missed stamp is the period's 3rd, so the recording's 3rd stamp: 0.2 s.
    assert _measures(np.full(7, 10.0), vad, est, "official").sources["source1"].latency_s == pytest.approx(0.2)
    # The paper: detected at the period's first stamp.
    assert _measures(np.full(7, 10.0), vad, est, "corrected").sources["source1"].latency_s == 0.0


def test_a_late_track_has_latency_from_its_periods_start_when_corrected():
    vad = [0, 1, 1, 1, 1, 1, 0]
    est = [np.nan, np.nan, np.nan, 10, 10, 10, np.nan]
    corrected = _measures(np.full(7, 10.0), vad, est, "corrected").sources["source1"]
    official = _measures(np.full(7, 10.0), vad, est, "official").sources["source1"]
    assert corrected.latency_s == pytest.approx(0.2)  # from 0.1 s to the first detection at 0.3 s
    assert official.latency_s == 0.0  # as released: the first miss is the period's first stamp -> t_1 - t_1
    assert corrected.pd == official.pd == [pytest.approx(3 / 5)]
    assert corrected.frag_rate == pytest.approx(1 / 0.4)
    never = _measures(np.full(7, 10.0), vad, np.full(7, np.nan), "corrected")
    assert math.isnan(never.sources["source1"].latency_s) and never.sources["source1"].pd == [0.0]
    assert never.mota == [5.0]  # five missed stamps, nothing else


def test_a_track_beyond_the_gate_misses_the_source_and_is_false():
    vad = [0, 1, 1, 0]
    m = _measures(np.zeros(4), vad, [np.nan, 40.0, 40.0, np.nan])
    s = m.sources["source1"]
    assert s.pd == [0.0] and math.isnan(s.az_error_deg[0])
    assert s.az_error_ungated_deg == [pytest.approx(40.0)]  # the ungated error still sees it
    assert m.far == pytest.approx(2 / 0.3) and m.mota == [4.0]  # 2 false + 2 missed


# -- false tracks and OSPA -----------------------------------------------------------------------
def test_a_second_track_is_false_and_raises_ospa_and_the_ungated_error():
    vad = [0, 0, 1, 1, 1, 0]
    tracks = [np.zeros(6), np.full(6, 90.0)]  # one on the source, one 90 degrees off; both always active
    m = _measures(np.zeros(6), vad, tracks)
    s = m.sources["source1"]
    # False: 2 at each of the three silent stamps, 1 (the far track) at each active one.
    assert m.far == pytest.approx(9 / 0.5) and m.far_vap == pytest.approx(3 / 0.2)
    assert m.mota == [9.0] and s.pd == [1.0] and s.az_error_deg == [0.0]
    assert s.az_error_ungated_deg == [pytest.approx(45.0)]  # (0 + 90) / 2 at every stamp
    for p in OSPA_ORDERS:  # 3 stamps of tracks only (c), 3 of one matched and one extra track
        expected = (3 * C + 3 * ((C ** p * 1 + 0.0) / 2) ** (1 / p)) / 6
        assert m.ospa_deg[ospa_key(p)] == pytest.approx(expected)
    assert m.ospa_deg["1"] == pytest.approx(22.5) and m.ospa_deg["2"] == pytest.approx(15 + 7.5 * math.sqrt(2))


@pytest.mark.parametrize("p", OSPA_ORDERS)
def test_ospa_with_more_tracks_than_sources(p):
    scores = score_stamps(R([[0.0]]), R([[90.0]]), [[1]], R([[10.0], [20.0], [50.0]]), np.full((3, 1), np.nan))
    # the best pair costs 10^p, two tracks are extra
    assert scores.ospa[OSPA_ORDERS.index(p), 0] == pytest.approx(((2 * C ** p + 10.0 ** p) / 3) ** (1 / p))
    assert scores.false[0] == 2 and scores.assigned[0, 0] == 0


@pytest.mark.parametrize("p", OSPA_ORDERS)
def test_ospa_with_more_sources_than_tracks(p):
    scores = score_stamps(R([[0.0], [100.0]]), R([[90.0], [90.0]]), [[1], [1]], R([[10.0]]), np.full((1, 1), np.nan))
    assert scores.ospa[OSPA_ORDERS.index(p), 0] == pytest.approx(((C ** p + 10.0 ** p) / 2) ** (1 / p))
    assert scores.missed[:, 0].tolist() == [False, True] and scores.false[0] == 0


def test_ospa_values_for_each_order_written_out():
    more_tracks = score_stamps(R([[0.0]]), R([[90.0]]), [[1]], R([[10.0], [20.0], [50.0]]), np.full((3, 1), np.nan))
    more_sources = score_stamps(R([[0.0], [100.0]]), R([[90.0], [90.0]]), [[1], [1]], R([[10.0]]),
                                np.full((1, 1), np.nan))
    # p = 1: (30 + 30 + 10) / 3 and (30 + 10) / 2; p = 2: sqrt((900 + 900 + 100) / 3), sqrt((900 + 100) / 2)
    assert more_tracks.ospa[[0, 2], 0] == pytest.approx([70 / 3, math.sqrt(1900 / 3)])
    assert more_sources.ospa[[0, 2], 0] == pytest.approx([20.0, math.sqrt(500)])
    # an inactive track costs the cut-off in the matrix but is neither extra nor false
    one = score_stamps(R([[0.0]]), R([[90.0]]), [[1]], R([[12.0], [np.nan]]), np.full((2, 1), np.nan))
    assert one.ospa[:, 0] == pytest.approx([12.0] * 4) and one.false[0] == 0
    nothing = score_stamps(R([[0.0]]), R([[90.0]]), [[0]], R([[np.nan]]), np.full((1, 1), np.nan))
    assert np.isnan(nothing.ospa[:, 0]).all()
    only_source = score_stamps(R([[0.0]]), R([[90.0]]), [[1]], R([[np.nan]]), np.full((1, 1), np.nan))
    assert only_source.ospa[:, 0] == pytest.approx([C] * 4) and only_source.missed[0, 0]


# -- swaps ---------------------------------------------------------------------------------------
def test_two_tracks_that_swap_sources_count_one_swap_each():
    vad = [[0, 1, 1, 1, 1, 1, 1], [0, 1, 1, 1, 1, 1, 1]]
    a, b = 0.0, 90.0
    track_1 = [np.nan, a, a, a, b, b, b]  # on source 1, then on source 2
    track_2 = [np.nan, b, b, b, a, a, a]
    m = _measures([np.full(7, a), np.full(7, b)], vad, [track_1, track_2], names=["s1", "s2"])
    for name in ("s1", "s2"):
        s = m.sources[name]
        assert s.swaps == 1 and s.pd == [1.0] and s.az_error_deg == [0.0]
        assert s.swap_rate == pytest.approx(1 / 0.5) and s.frag_rate == pytest.approx(1 / 0.5)
        assert math.isnan(s.az_error_ungated_deg[0])  # defined for single-source recordings only
    assert m.mota == [0.5, 0.5]  # (0 false + 0 missed + 1 swap) / 2 sources
    assert m.stamps.swaps[:, 4].tolist() == [True, True] and m.stamps.swaps.sum() == 2


def test_a_source_reacquired_by_the_same_track_after_a_gap_is_no_swap():
    vad = [0, 1, 1, 1, 1, 0]
    m = _measures(np.zeros(6), vad, [[np.nan, 0, np.nan, np.nan, 0, np.nan], [np.nan, np.nan, np.nan, 0, np.nan, np.nan]])
    s = m.sources["source1"]
    # track 1, gap, track 2 (a swap), track 1 (a swap back)
    assert s.swaps == 2 and m.stamps.assigned[0].tolist() == [-1, 0, -1, 1, 0, -1]
    assert s.frag_rate == pytest.approx((1 + 2) / 0.3)  # one missed -> detected step and two swaps


# -- the two modes -------------------------------------------------------------------------------
def test_a_voice_run_at_the_first_stamp_official_against_corrected():
    vad = [1, 1, 1, 0, 0, 1, 1, 1, 0, 0]
    est = _where(vad, np.full(10, 5.0))  # 5 degrees off the source at 0 whenever it is active
    official = _measures(np.zeros(10), vad, est, "official").sources["source1"]
    corrected = _measures(np.zeros(10), vad, est, "corrected").sources["source1"]
    # As released: one period, from the second run's start (0.5 s) to the first run's end (0.2 s): no stamps.
    assert official.periods_s == [(0.5, pytest.approx(0.2))]
    assert math.isnan(official.az_error_deg[0]) and math.isnan(official.pd[0])
    assert official.latency_s == 0.0 and official.swap_rate == official.frag_rate == 0.0
    assert corrected.periods_s == [(0.0, pytest.approx(0.2)), (0.5, pytest.approx(0.7))]
    assert corrected.az_error_deg == [pytest.approx(5.0)] * 2 and corrected.pd == [1.0, 1.0]
    assert corrected.latency_s == 0.0


def test_a_recording_without_a_voice_period_gives_nan_with_a_warning():
    with pytest.warns(UserWarning, match="no voice-active period"):
        m = _measures(np.zeros(4), [1, 1, 1, 1], np.zeros(4), "official")
    s = m.sources["source1"]
    assert s.pd == [] and math.isnan(s.latency_s) and math.isnan(s.swap_rate) and math.isnan(m.far_vap)
    assert m.far == 0.0 and m.ospa_deg["1"] == 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _measures(np.zeros(4), [1, 1, 1, 1], np.zeros(4), "corrected").sources["source1"].pd == [1.0]


def test_official_misses_count_silent_sources_corrected_only_active_ones():
    vad = [[0, 1, 1], [0, 0, 0]]  # the second source never speaks
    track = [[np.nan, 0.0, 0.0]]
    with pytest.warns(UserWarning, match="source s2 has no voice-active period"):
        official = _measures([np.zeros(3), np.full(3, 120.0)], vad, track, "official", names=["s1", "s2"])
    with pytest.warns(UserWarning):
        corrected = _measures([np.zeros(3), np.full(3, 120.0)], vad, track, "corrected", names=["s1", "s2"])
    assert official.stamps.missed[1].tolist() == [False, True, True]
    assert not corrected.stamps.missed[1].any()
    assert official.mota == [0.0, 1.0] and corrected.mota == [0.0, 0.0]  # (0 + 2 missed + 0) / 2 sources


def test_the_ungated_inclination_error_holds_the_azimuth_distance_as_released():
    vad = [0, 1, 1, 0]
    kwargs = dict(truth_inc_deg=np.full(4, 80.0), est_inc_deg=_where(vad, np.full(4, 70.0)))
    official = _measures(np.zeros(4), vad, _where(vad, np.full(4, 4.0)), "official", **kwargs).sources["source1"]
    corrected = _measures(np.zeros(4), vad, _where(vad, np.full(4, 4.0)), "corrected", **kwargs).sources["source1"]
    assert official.inc_error_deg == corrected.inc_error_deg == [pytest.approx(10.0)]
    assert official.inc_error_ungated_deg == [pytest.approx(4.0)]  # the azimuth distance
    assert corrected.inc_error_ungated_deg == [pytest.approx(10.0)]


# -- angles --------------------------------------------------------------------------------------
def test_azimuth_errors_wrap_across_180_degrees():
    vad = [0, 1, 1, 0]
    m = _measures([0, 179.0, -179.5, 0], vad, [np.nan, -179.0, 179.5, np.nan])
    s = m.sources["source1"]
    assert s.az_error_deg == [pytest.approx(1.5)] and s.az_error_ungated_deg == [pytest.approx(1.5)]
    assert s.pd == [1.0] and m.ospa_deg["1"] == pytest.approx(1.5)


# -- the assignment and the task averages ----------------------------------------------------------
def test_the_assignment_takes_as_many_pairs_as_the_gate_allows():
    rows, cols = assign(np.array([[1.0, 2.0], [1.5, np.inf]]))
    assert sorted(zip(rows.tolist(), cols.tolist())) == [(0, 1), (1, 0)]  # two pairs beat the cheapest one
    rows, cols = assign(np.array([[1.0, np.inf], [np.inf, np.inf]]))
    assert (rows.tolist(), cols.tolist()) == ([0], [0])
    assert assign(np.full((2, 3), np.inf))[0].size == 0


def test_task_averages_pool_periods_and_stamps_and_average_recordings():
    a = _measures(np.zeros(8), [0, 1, 1, 0, 0, 1, 1, 0], _where([0, 1, 1, 0, 0, 1, 1, 0], [0, 1, 1, 0, 0, 3, 3, 0]))
    b = _measures(np.zeros(4), [0, 1, 1, 0], [5.0, 8.0, 8.0, np.nan])
    assert a.sources["source1"].az_error_deg == [pytest.approx(1.0), pytest.approx(3.0)]
    avg = task_averages([a, b])
    assert avg["az_error_deg"] == pytest.approx((1 + 3 + 8) / 3)  # pooled, not (2 + 8) / 2
    assert avg["far"] == pytest.approx((0 + 1 / 0.3) / 2) and avg["pd"] == 1.0
    # OSPA over every defined stamp: a's four at 1, 1, 3, 3; b's three at 30 (track only), 8, 8
    assert avg["ospa_deg"]["1"] == pytest.approx((1 + 1 + 3 + 3 + 30 + 8 + 8) / 7)
    assert avg["swaps"] == 0 and avg["latency_s"] == 0.0


# -- SRP-DNN's protocol and a run's track on the stamps ---------------------------------------------
def test_srp_dnn_protocol_scores_correct_stamps_only():
    from doabench.locata.srpdnn import recording_mean, srp_dnn_scores

    truth = np.zeros(5)
    est = R([10.0, 40.0, np.nan, -20.0, 80.0])  # the last stamp is silent: not scored
    got = srp_dnn_scores(truth, R(np.full(5, 90.0)), [1, 1, 1, 1, 0], est, R([95.0, 90, 90, 87.0, 90]))
    assert got["accuracy"] == pytest.approx(2 / 4)  # 10 and -20 are within 30 degrees; 40 and none are not
    assert got["az_mae_deg"] == pytest.approx(15.0) and got["az_rmse_deg"] == pytest.approx(math.sqrt(250.0))
    assert got["inc_mae_deg"] == pytest.approx(4.0) and got["inc_rmse_deg"] == pytest.approx(math.sqrt(17.0))
    silent = srp_dnn_scores(truth, truth, np.zeros(5), est, est)
    assert all(math.isnan(v) for v in silent.values())
    assert recording_mean([got, silent, {"accuracy": 1.0}])["accuracy"] == pytest.approx(0.75)


def test_a_stamp_takes_the_latest_frame_that_has_ended():
    from doabench.locata.stamps import locata_angles
    from doabench.locata.tracks import frame_ends, stamp_track

    # +y is LOCATA's azimuth 0, +x is -90 degrees; inclination from +z
    az, inc = locata_angles(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 2.0]]))
    assert np.degrees(az[:2]) == pytest.approx([0.0, -90.0]) and np.degrees(inc) == pytest.approx([90, 90, 0])
    ends = frame_ends(0.5, np.array([0.25, 0.75]), window=8000, fs=16000)  # windows of 0.5 s
    assert ends == pytest.approx([1.0, 1.5])
    az, _ = stamp_track(np.array([0.9, 1.0, 1.2, 1.5, 3.0]), ends, np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    assert np.isnan(az[0]) and np.degrees(az[1:]) == pytest.approx([0.0, 0.0, -90.0, -90.0])
