"""Localisation and tracking metrics.

Definitions (all angles reported in degrees):

* frame error ``e_t``: great-circle angle between estimate and truth, ``atan2(|u x v|, u . v)``;
* ``rmsae_all`` = sqrt(mean_t e_t^2) over all frames; ``rmsae_nonsilent`` over voice-active frames
  only (the paper's two numbers: Fig. 6 excludes silent frames, Fig. 8 and Table II include them);
* ``mae``, ``median``, ``p90``: mean, median and 90th percentile of ``e_t`` (non-silent frames);
* ``within_5`` ... ``within_30``: share of non-silent frames with ``e_t`` at most 5/10/20/30 degrees;
* ``azimuth_mae``: mean wrapped azimuth error ``|wrap(az_est - az_true)|`` over voice-active frames,
  the LOCATA challenge's azimuth metric.

Which frames are scored, and how (:func:`score_frames`, the one place every score goes through:
``doabench run``, ``doabench track --truth``, the trainer's validation and the scripts): frames
whose truth is invalid (LOCATA ``valid_flag = 0``) are left out; for a planar array estimate and
truth are both mirror-folded onto the upper half-space (the array cannot tell a direction from its
mirror image); every remaining frame counts in ``rmsae_all`` and the voice-active ones in the
non-silent metrics.

Frames where the tracker said "no source" (three NaNs, ``doabench.NO_SOURCE``) have no estimate.
They stay in every pool and count the fixed error ``NO_SOURCE_ERROR_DEG`` (90 degrees, the mean
error of a direction drawn at random on the sphere), great-circle and azimuth alike, so saying
"no source" never scores better than a guess and every tracker's RMSAE pools the same frames;
the runner reports how many frames had no estimate (``no_estimate`` in the rows and the summary).
The lag leaves them out (they follow no path). A tracker that never says "no source" scores
exactly as before.

Aggregation over episodes comes in two labelled flavours: ``pooled`` (all frames of all episodes
in one pool, the paper's way) and ``episode_mean`` (the mean of per-episode values).

Tracking lag (beyond the paper): the delay ``tau`` of the truth, 0 to 2 s in steps of 0.05 s,
that minimises the RMSAE between the estimates and the truth delayed by ``tau``
(``truth(t - tau)``, interpolated between frames along the great circle's chord and normalised),
over the voice-active frames at least 2 s into the episode (the same frames for every ``tau``).
A tracker that follows the talker's path late by half a second has a lag of 0.5 s. A static or
nearly static source (median angular speed of the truth over those frames below 1 deg/s) has no
defined lag: every delay fits alike, and the lag is reported as None with the reason. Each
episode keeps its curve of summed squared errors per delay (``lag_sse``, ``lag_frames``), so the
pooled lag is the delay minimising the pooled curve over the episodes whose truth moves.

A lag is a property of estimates that follow the talker; a tracker that points one way (an
untrained network, a stuck tracker) fits some delay best by chance, often the end of the range.
So the lag is defined only when both hold for the pooled curve:

* the best delay is below the end of the search range (2 s), and
* the RMSAE at the best delay is below ``FOLLOW_RATIO`` (0.9) times that of the best constant
  direction over the same frames (per episode, ``lag_const_sse``: the smallest summed squared
  error one fixed direction, the spherical mean of the truth, reaches at any candidate delay).

A tracker with one fixed direction per episode can never pass the second test: its curve is
nowhere below ``lag_const_sse``. Otherwise the lag is None with the reason. Curves written before
``lag_const_sse`` was recorded are checked by the first test only.

RMSAE by angular speed: the voice-active frames split by the angular speed of the truth seen from
the array (central differences of the frame truth) into the bands of ``SPEED_BANDS``; each
episode keeps the summed squared errors and frame counts per band, pooled exactly.

The package, one job a module (each name is importable from ``doabench.metrics``):

* :mod:`~doabench.metrics.scoring`: frame errors, the summary metrics and :func:`score_frames`,
  the one rule of which frames are scored;
* :mod:`~doabench.metrics.motion`: the tracking lag and the RMSAE by angular speed;
* :mod:`~doabench.metrics.episode`: :func:`score_episode`, every per-episode metric of a row;
* :mod:`~doabench.metrics.bootstrap`: the one bootstrap (resampling counts, strata, percentile
  intervals) and a results file's 95 % intervals;
* :mod:`~doabench.metrics.pooled`: statistics pooled over episodes from their per-episode sums
  (:class:`Metric`), as the leaderboards and ``doabench compare`` compute them;
* :mod:`~doabench.metrics.paired`: the paired bootstrap difference of two runs on the same
  episodes (``doabench compare``).
"""
from __future__ import annotations

from doabench.metrics.bootstrap import (MIN_INTERVAL_EPISODES, MIN_STRATUM, bootstrap_ci, bootstrap_ci_from_sums,
                                        bootstrap_counts, bootstrap_strata, defined_interval, percentile_interval)
from doabench.metrics.episode import score_episode
from doabench.metrics.motion import (FOLLOW_RATIO, KARCHER_STEPS, LAG_MAX_S, LAG_STEP_S, SPEED_BANDS,
                                     STATIC_SPEED_DEG_S, best_constant_sse, delayed_truth, follows, lag_curve,
                                     lag_from_curves, lag_grid, motion_metrics, moves, pooled_const_sse,
                                     pooled_speed_bands, speed_band_sums)
from doabench.metrics.paired import PairedDifference, paired_difference, weighted_quantile
from doabench.metrics.pooled import Metric, group_by, pooled_from_rows, pooled_rms, row_sums, summary_metrics
from doabench.metrics.scoring import (THRESHOLDS_DEG, ScoredFrames, aggregate, azimuth_errors_deg, episode_metrics,
                                      error_summary, frame_errors_deg, rms, rms_from_sums, score_frames,
                                      squared_error_sums)

__all__ = [
    "FOLLOW_RATIO", "KARCHER_STEPS", "LAG_MAX_S", "LAG_STEP_S", "MIN_INTERVAL_EPISODES", "MIN_STRATUM", "SPEED_BANDS",
    "STATIC_SPEED_DEG_S", "THRESHOLDS_DEG",
    "Metric", "PairedDifference", "ScoredFrames",
    "aggregate", "azimuth_errors_deg", "best_constant_sse", "bootstrap_ci", "bootstrap_ci_from_sums",
    "bootstrap_counts", "bootstrap_strata", "defined_interval", "delayed_truth", "episode_metrics", "error_summary",
    "follows", "frame_errors_deg", "group_by", "lag_curve", "lag_from_curves", "lag_grid", "motion_metrics", "moves",
    "paired_difference", "percentile_interval", "pooled_const_sse", "pooled_from_rows", "pooled_rms", "pooled_speed_bands", "rms",
    "rms_from_sums", "row_sums", "score_episode", "score_frames", "speed_band_sums", "squared_error_sums",
    "summary_metrics", "weighted_quantile",
]
