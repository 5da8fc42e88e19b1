"""Angle conventions shared by every part of doabench.

* Directions are unit vectors ``(x, y, z)`` in the **array frame**.
* ``elevation`` is the *inclination* from +z in radians, in ``[0, pi]`` (0 = straight up),
  as in the paper's maps (N_theta rows over ``[0, pi]``).
* ``azimuth`` is ``atan2(y, x)`` in ``[-pi, pi)``.
* ``u = (sin(el) cos(az), sin(el) sin(az), cos(el))``.

All functions accept numpy arrays or torch tensors with any leading shape and the angle/vector
axis last; they return the same kind of array they were given.
"""
from __future__ import annotations

import math
import sys
from typing import TYPE_CHECKING, Any, Sequence, TypeGuard, Union, overload

import numpy as np

if TYPE_CHECKING:
    import torch

# torch is imported lazily: commands that need no tensors (help, list, leaderboard) start in a
# fraction of the 1.4 s torch's import costs. A tensor can only exist once torch is imported, so
# "is this a tensor" never needs the import.
ArrayLike = Union[np.ndarray, "torch.Tensor"]


def is_tensor(x: object) -> TypeGuard[torch.Tensor]:
    """True when ``x`` is a torch tensor (without importing torch)."""
    torch_module = sys.modules.get("torch")
    return torch_module is not None and isinstance(x, torch_module.Tensor)

SPEED_OF_SOUND = 343.0  # m/s, the value the issues fix
# Bound of SRP grids: delay tables and maps grow with the grid (100000x100000 would allocate 37 GiB).
MAX_GRID_SIDE = 1024
MAX_GRID_POINTS = 256 * 512


def _lib(x: ArrayLike):
    return sys.modules["torch"] if is_tensor(x) else np


# The overloads say what the module docstring does: a function returns the kind of array it was given.
@overload
def angles_to_unit(elevation: torch.Tensor, azimuth: torch.Tensor) -> torch.Tensor: ...
@overload
def angles_to_unit(elevation: np.ndarray, azimuth: np.ndarray) -> np.ndarray: ...
def angles_to_unit(elevation: ArrayLike, azimuth: ArrayLike) -> ArrayLike:
    """(elevation, azimuth) in radians, shape ``(...)`` each -> unit vectors ``(..., 3)``."""
    lib = _lib(elevation)
    s = lib.sin(elevation)
    return lib.stack([s * lib.cos(azimuth), s * lib.sin(azimuth), lib.cos(elevation)], -1)


@overload
def unit_to_angles(u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]: ...
@overload
def unit_to_angles(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
def unit_to_angles(u: ArrayLike) -> tuple[ArrayLike, ArrayLike]:
    """Vectors ``(..., 3)`` (any norm > 0) -> (elevation, azimuth) in radians, each ``(...)``."""
    lib = _lib(u)
    u = _prescale(u)  # huge components would overflow rho
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    rho = lib.sqrt(x * x + y * y)
    elevation = lib.arctan2(rho, z) if lib is np else lib.atan2(rho, z)
    azimuth = lib.arctan2(y, x) if lib is np else lib.atan2(y, x)
    return elevation, azimuth


@overload
def _prescale(u: torch.Tensor) -> torch.Tensor: ...
@overload
def _prescale(u: np.ndarray) -> np.ndarray: ...
def _prescale(u: ArrayLike) -> ArrayLike:
    """``u`` divided by its largest absolute component along the last axis (rows that are all zero
    stay zero), so that squaring the components neither overflows (1e200) nor underflows (1e-200)."""
    if is_tensor(u):
        m = u.abs().amax(dim=-1, keepdim=True)
        return u / m.where(m > 0, 1.0)
    u = np.asarray(u)
    if not np.issubdtype(u.dtype, np.floating):
        u = u.astype(np.float64)
    m = np.max(np.abs(u), axis=-1, keepdims=True)
    with np.errstate(invalid="ignore"):
        return u / np.where(m > 0, m, 1)


@overload
def robust_norm(u: torch.Tensor) -> torch.Tensor: ...
@overload
def robust_norm(u: np.ndarray) -> np.ndarray: ...
def robust_norm(u: ArrayLike) -> ArrayLike:
    """Euclidean norm over the last axis without overflow or underflow: ``max|u_i| * |u / max|u_i||``."""
    if is_tensor(u):
        m = u.abs().amax(dim=-1)
        return m * _prescale(u).norm(dim=-1)
    u = np.asarray(u)
    if not np.issubdtype(u.dtype, np.floating):
        u = u.astype(np.float64)
    m = np.max(np.abs(u), axis=-1)
    with np.errstate(over="ignore"):
        return m * np.linalg.norm(_prescale(u), axis=-1)


@overload
def normalize(u: torch.Tensor, eps: float = ...) -> torch.Tensor: ...
@overload
def normalize(u: np.ndarray, eps: float = ...) -> np.ndarray: ...
def normalize(u: ArrayLike, eps: float = 1e-12) -> ArrayLike:
    """Scale vectors ``(..., 3)`` to unit norm.

    Each vector is first divided by its largest absolute component, so a valid direction with huge
    (``[1e200, 0, 0]``) or tiny components is normalised to the direction it is instead of
    overflowing to ``inf`` (and then to a zero vector). All-zero vectors stay zero.
    """
    v = _prescale(u)
    if is_tensor(v):
        return v / v.norm(dim=-1, keepdim=True).clamp_min(eps)
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), eps)


@overload
def great_circle_error(u: torch.Tensor, v: ArrayLike) -> torch.Tensor: ...
@overload
def great_circle_error(u: ArrayLike, v: torch.Tensor) -> torch.Tensor: ...
@overload
def great_circle_error(u: np.ndarray, v: np.ndarray) -> np.ndarray: ...
def great_circle_error(u: ArrayLike, v: ArrayLike) -> ArrayLike:
    """Angle in radians between directions ``(..., 3)`` (need not be unit norm).

    atan2(|u x v|, u . v) is accurate for small and large angles alike; arccos of a clamped dot
    product would put a floor of about 1e-4 rad under small float32 errors.
    """
    if is_tensor(u) or is_tensor(v):
        import torch

        u = torch.as_tensor(u)
        v = torch.as_tensor(v, dtype=u.dtype, device=u.device)
        u, v = _prescale(u), _prescale(v)
        return torch.atan2(torch.linalg.cross(u, v, dim=-1).norm(dim=-1), (u * v).sum(-1))
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    u, v = _prescale(u), _prescale(v)  # no overflow in the cross and dot products of huge vectors
    return np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))


def fold_to_upper(directions: np.ndarray) -> np.ndarray:
    """Mirror directions below the array plane onto it (z -> |z|): what a planar array scores against."""
    d = np.array(directions, dtype=np.float64, copy=True)
    d[..., 2] = np.abs(d[..., 2])
    return d


@overload
def wrap_angle(a: torch.Tensor) -> torch.Tensor: ...
@overload
def wrap_angle(a: np.ndarray) -> np.ndarray: ...
def wrap_angle(a: ArrayLike) -> ArrayLike:
    """Wrap radians to ``[-pi, pi)``."""
    return (a + math.pi) % (2 * math.pi) - math.pi


@overload
def resolution_text(resolution: Sequence[int]) -> str: ...
@overload
def resolution_text(resolution: None) -> None: ...
def resolution_text(resolution: Sequence[int] | None) -> str | None:
    """``(16, 32)`` -> ``"16x32"`` (the inverse of :func:`parse_resolution`); None stays None."""
    return None if resolution is None else f"{int(resolution[0])}x{int(resolution[1])}"


def parse_resolution(text: str) -> tuple[int, int]:
    """``"16x32"`` -> ``(16, 32)`` (N_theta, N_phi). Raises ConfigError on anything else."""
    from doabench.errors import ConfigError

    try:
        a, b = text.lower().split("x")
        n_theta, n_phi = int(a), int(b)
    except ValueError:
        raise ConfigError(f"resolution {text!r} is not of the form N_THETAxN_PHI, e.g. 16x32") from None
    return check_grid(n_theta, n_phi, repr(text))


def as_grid(resolution: Any) -> tuple[int, int]:
    """An SRP grid written ``"16x32"`` or as two whole sizes (a tracker's declared ``resolution``),
    bounded by :func:`check_grid`; else one line."""
    from doabench.errors import ConfigError

    if isinstance(resolution, str):
        return parse_resolution(resolution)
    try:
        n_theta, n_phi = (int(v) for v in resolution)
    except (TypeError, ValueError):
        raise ConfigError(f"resolution must be (n_theta, n_phi) or 'NxM', got {resolution!r}") from None
    return check_grid(n_theta, n_phi)


def check_grid(n_theta: int, n_phi: int, text: str | None = None) -> tuple[int, int]:
    """``(n_theta, n_phi)`` when it is an SRP grid doabench computes (at least 2 and at most
    :data:`MAX_GRID_SIDE` per side, at most :data:`MAX_GRID_POINTS` points), else a one-line
    ConfigError saying the size and the limit, before anything of its size is allocated. ``text``:
    how the grid was written (default ``NxM``)."""
    from doabench.errors import ConfigError

    text = text or f"{n_theta}x{n_phi}"
    if n_theta < 2 or n_phi < 2:
        raise ConfigError(f"resolution {text}: both N_theta and N_phi must be at least 2")
    if n_theta > MAX_GRID_SIDE or n_phi > MAX_GRID_SIDE or n_theta * n_phi > MAX_GRID_POINTS:
        raise ConfigError(f"resolution {text} is too fine: at most {MAX_GRID_SIDE} per side and "
                          f"{MAX_GRID_POINTS} grid points (e.g. 256x512), got {n_theta * n_phi}")
    return int(n_theta), int(n_phi)


def grid_angles(n_theta: int, n_phi: int, planar: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The equiangular SRP grid.

    Elevations: ``n_theta`` values over ``[0, pi]`` with both ends included (``[0, pi/2]`` for
    planar arrays). Azimuths: ``n_phi`` values over ``[-pi, pi)`` (``-pi + 2 pi j / n_phi``).
    Returns ``(elevations (n_theta,), azimuths (n_phi,))`` in radians, float64.
    """
    top = math.pi / 2 if planar else math.pi
    elevations = np.linspace(0.0, top, n_theta)
    azimuths = -math.pi + 2 * math.pi * np.arange(n_phi) / n_phi
    return elevations, azimuths


def grid_unit_vectors(n_theta: int, n_phi: int, planar: bool = False) -> np.ndarray:
    """Unit vectors of every grid point, shape ``(n_theta, n_phi, 3)``, float64."""
    el, az = grid_angles(n_theta, n_phi, planar)
    return angles_to_unit(el[:, None] + 0 * az[None, :], az[None, :] + 0 * el[:, None])


def grid_spacing_deg(n_theta: int, n_phi: int, planar: bool = False) -> tuple[float, float]:
    """(elevation step, azimuth step) in degrees."""
    top = 90.0 if planar else 180.0
    return top / (n_theta - 1), 360.0 / n_phi


def angular_speed_deg(directions: np.ndarray, period_s: float | np.ndarray) -> np.ndarray:
    """Angular speed in deg/s ``(T,)`` of unit ``directions`` ``(T, 3)`` sampled every ``period_s``
    seconds (or at times ``(T,)``): central differences of the great-circle angle between
    neighbours, one-sided at the ends; zeros for fewer than two samples."""
    d = np.asarray(directions, np.float64)
    if len(d) < 2:
        return np.zeros(len(d))
    dt = np.diff(np.asarray(period_s, np.float64)) if np.ndim(period_s) else float(period_s)
    step = np.degrees(great_circle_error(d[1:], d[:-1])) / dt
    out = np.empty(len(d))
    out[0], out[-1] = step[0], step[-1]
    out[1:-1] = 0.5 * (step[1:] + step[:-1])
    return out


# -- "no source": a frame without a direction ---------------------------------------------------
#: What a tracker returns for a frame where it reports no source: three NaNs, as the LOCATA
#: submission format writes a stamp without an estimate. Read-only; ``np.full(3, np.nan)`` is the same.
NO_SOURCE: np.ndarray = np.full(3, np.nan)
NO_SOURCE.flags.writeable = False
#: The error in degrees that every frame score counts for a frame without an estimate, great-circle
#: and azimuth alike: the mean error of a direction drawn at random (uniformly on the sphere), so
#: saying "no source" never scores better than a guess (doabench.metrics).
NO_SOURCE_ERROR_DEG = 90.0


def is_no_source(directions: ArrayLike) -> np.ndarray:
    """bool ``(...)``: which vectors ``(..., 3)`` say "no source" (every component NaN: :data:`NO_SOURCE`)."""
    return np.asarray(np.all(np.isnan(np.asarray(directions, np.float64)), axis=-1))
