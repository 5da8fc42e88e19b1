"""Ground truth from tracked poses: interpolation to sample times and the array-frame transform.

* Positions are interpolated linearly in time between pose rows; before the first and after the
  last row the end values are held (such samples are marked invalid by the reader anyway).
* Rotations are interpolated element-wise linearly and then re-orthonormalised with the polar
  decomposition (``R = U V^T`` from the SVD, the nearest rotation in the Frobenius norm). For the
  small rotations between two ~120 Hz rows this equals slerp to well below 1e-6 rad.
* The source direction in the array frame is ``v = R^T (s - p)`` (LOCATA's definition, with
  ``R`` the local-to-world rotation and ``p`` the array's reference point), normalised.
* The recording's microphone geometry in the array frame is ``R^T (mic - p)`` per pose row; it is
  constant for a rigid array, and the time average is used (its spread is reported).
"""
from __future__ import annotations

import numpy as np

from doabench.geometry import normalize
from doabench.locata.tables import Pose

_CHUNK = 65536  # samples per SVD batch: bounds the temporary memory of long recordings


def interpolate_positions(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Linear interpolation of ``values (P, ...)`` given at ``times (P,)`` to ``at (N,)`` ->
    ``(N, ...)``; end values held outside ``[times[0], times[-1]]``."""
    flat = values.reshape(len(times), -1)
    if len(times) == 1:
        return np.broadcast_to(values[:1], (len(at),) + values.shape[1:]).copy()
    # searchsorted once, then one weighted sum for every column (np.interp would loop over them).
    i = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    w = np.clip((at - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)[:, None]
    out = flat[i] * (1.0 - w) + flat[i + 1] * w
    return out.reshape((len(at),) + values.shape[1:])


def orthonormalize(r: np.ndarray) -> np.ndarray:
    """Nearest proper rotations to ``r (N, 3, 3)`` (polar decomposition), ``(N, 3, 3)``."""
    out = np.empty_like(r)
    for s in range(0, len(r), _CHUNK):
        u, _, vt = np.linalg.svd(r[s:s + _CHUNK])
        q = u @ vt
        # A reflection (det -1) can only come from a corrupt table; flip it to the nearest rotation.
        neg = np.linalg.det(q) < 0
        if neg.any():
            u[neg, :, -1] *= -1
            q[neg] = u[neg] @ vt[neg]
        out[s:s + _CHUNK] = q
    return out


def interpolate_rotations(times: np.ndarray, rotations: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Rotations ``(P, 3, 3)`` at ``times`` -> ``(N, 3, 3)`` at ``at``: linear, then polar."""
    if len(times) == 1 or np.allclose(rotations, rotations[:1], atol=1e-12):
        return np.broadcast_to(orthonormalize(rotations[:1]), (len(at), 3, 3)).copy()
    return orthonormalize(interpolate_positions(times, rotations, at))


def array_frame_directions(array_pose: Pose, source_pose: Pose, at: np.ndarray) -> np.ndarray:
    """Unit vectors ``(N, 3)`` from the array to the source in the array frame at times ``at``:
    ``normalize(R(t)^T (s(t) - p(t)))``."""
    p = interpolate_positions(array_pose.times, array_pose.position, at)
    s = interpolate_positions(source_pose.times, source_pose.position, at)
    r = interpolate_rotations(array_pose.times, array_pose.rotation, at)
    v = np.einsum("nji,nj->ni", r, s - p)  # R^T (s - p) for every sample
    return normalize(v)


def local_mic_positions(array_pose: Pose) -> tuple[np.ndarray, float]:
    """Microphone positions in the array frame, ``((M, 3) time average, max spread in metres)``.

    Each row's world positions are mapped with ``R^T (mic - p)``; the spread is the largest
    distance of any row's microphone from its average (0 for a perfectly rigid table).
    """
    if array_pose.mics is None:
        raise ValueError("pose has no microphone columns")
    r = orthonormalize(array_pose.rotation)
    local = np.einsum("pji,pmj->pmi", r, array_pose.mics - array_pose.position[:, None, :])  # (P, M, 3)
    mean = local.mean(0)
    spread = float(np.linalg.norm(local - mean, axis=-1).max())
    return mean, spread


def coverage_mask(times: np.ndarray, at: np.ndarray, tolerance: float) -> np.ndarray:
    """``(N,)`` bool: ``at`` lies within ``[times[0] - tolerance, times[-1] + tolerance]``."""
    return (at >= times[0] - tolerance) & (at <= times[-1] + tolerance)


def required_mask(req_times: np.ndarray, valid: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: the valid flag of the required-time row nearest to each time in ``at``
    (every row stands for the half-way interval to its neighbours); False beyond half a step
    before the first row and after the last."""
    if len(req_times) == 1:
        return np.full(len(at), bool(valid[0]))
    step = float(np.median(np.diff(req_times)))
    i = np.clip(np.searchsorted(req_times, at), 1, len(req_times) - 1)
    nearest = np.where(at - req_times[i - 1] <= req_times[i] - at, i - 1, i)
    return valid[nearest] & coverage_mask(req_times, at, step / 2)
