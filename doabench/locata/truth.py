"""Ground truth from tracked poses: interpolation to sample times and the array-frame transform.

* Positions are interpolated linearly in time between pose rows; before the first and after the
  last row the end values are held (such samples are marked invalid by the reader anyway).
* Rotations: every pose row is first re-orthonormalised with the polar decomposition
  (``R = U V^T`` from the SVD, the nearest rotation in the Frobenius norm; the tables hold 6
  decimals), then rotations are interpolated by slerp: between rows ``i`` and ``i + 1`` the
  rotation turns about the fixed axis of ``R_i^T R_{i+1}`` at constant angular velocity,
  ``R(t) = R_i exp(w [omega_i]_x)`` with ``w`` the time fraction. This is the geodesic between the
  two rows (element-wise linear interpolation plus re-orthonormalisation agrees with it to second
  order for the small steps between ~120 Hz rows, but needs one SVD per sample). Rows are assumed
  less than 180 degrees apart.
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


def _log_map(d: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(K, 3)`` (axis times angle) of rotations ``d (K, 3, 3)`` (angles < pi)."""
    cos = np.clip((np.trace(d, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    vee = 0.5 * np.stack([d[:, 2, 1] - d[:, 1, 2], d[:, 0, 2] - d[:, 2, 0], d[:, 1, 0] - d[:, 0, 1]], -1)
    # |vee| = sin(angle); angle / sin(angle) -> 1 for small angles (its series avoids 0 / 0).
    sin = np.sin(angle)
    scale = np.where(angle > 1e-6, angle / np.where(angle > 1e-6, sin, 1.0), 1.0 + angle**2 / 6.0)
    return vee * scale[:, None]


def _exp_map(rv: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation vectors ``(N, 3)`` -> rotations ``(N, 3, 3)``."""
    angle = np.linalg.norm(rv, axis=-1)
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0 - angle**2 / 6.0, np.sin(angle) / safe)  # sin(t) / t
    b = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(angle)) / safe**2)  # (1 - cos t) / t^2
    x, y, z = rv[:, 0], rv[:, 1], rv[:, 2]
    k = np.zeros(rv.shape[:-1] + (3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 0], k[:, 1, 2], k[:, 2, 0], k[:, 2, 1] = -z, y, z, -x, -y, x
    return np.eye(3) + a[:, None, None] * k + b[:, None, None] * (k @ k)


def interpolate_rotations(times: np.ndarray, rotations: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Rotations ``(P, 3, 3)`` at ``times`` -> ``(N, 3, 3)`` at ``at`` by slerp between the
    (re-orthonormalised) rows; the end rows are held outside ``[times[0], times[-1]]``."""
    rows = orthonormalize(rotations)
    if len(times) == 1 or np.allclose(rows, rows[:1], atol=1e-12):
        return np.broadcast_to(rows[:1], (len(at), 3, 3)).copy()
    omega = _log_map(np.einsum("kji,kjl->kil", rows[:-1], rows[1:]))  # (P-1, 3): R_i^T R_{i+1}
    i = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    w = np.clip((at - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)
    return rows[i] @ _exp_map(omega[i] * w[:, None])


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
