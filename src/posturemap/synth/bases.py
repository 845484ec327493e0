"""Bases of the interpolating methods: the in-between frames as fixed linear maps of the seam values.

Every function returns a read-only matrix (cached per length) that maps rows of seam values
(``pA, vA, pB, vB`` and, per basis, a key or A's acceleration) to the ``length`` new frames at
times ``1..length``; A's end is at time 0 and B's start at ``length + 1``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

VELOCITY_HORIZON_S = 0.1  # upm-valid: time constant (s) over which a seam velocity fades from the keys
DAMPED_TAU_S = 0.05  # damped: the seam velocities' time constant (s; see damped_basis)


def key_spline_basis(length: int, key_at: int) -> np.ndarray:
    """Clamped cubic B-spline through (0: pA, vA), (key_at: key), (length+1: pB, vB).

    Returns the matrix (length, 5) mapping ``[pA, vA, pB, vB, key]`` to frames 1..length.
    """
    return keys_spline_basis(length, (float(key_at),))


@lru_cache(maxsize=256)
def keys_spline_basis(length: int, times: tuple[float, ...]) -> np.ndarray:
    """Clamped cubic B-spline through A's end, keys at ``times`` (0 < t < length+1), B's start.

    Returns the matrix (length, 4 + K) mapping ``[pA, vA, pB, vB, key_1..key_K]`` to frames
    1..length; the curve has value and velocity ``pA, vA`` at 0 and ``pB, vB`` at length+1.
    """
    k = len(times)
    knots = np.concatenate([[0.0], times, [length + 1.0]])
    spline = clamped_spline_matrix(knots, np.arange(1, length + 1, dtype=float))  # (L, k+4)
    # Its inputs are [y_0 (pA), y_1..y_k (keys), y_k+1 (pB), slope_0 (vA), slope_end (vB)].
    out = spline[:, [0, k + 2, k + 1, k + 3] + list(range(1, k + 1))]
    out.setflags(write=False)
    return out


def clamped_spline_matrix(knots: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The C2 cubic spline through values at ``knots`` (n+1,) with given end slopes, as a matrix.

    Returns (len(t), n+3) mapping ``[y_0..y_n, slope_0, slope_n]`` to the curve at ``t``.
    The interior slopes solve the usual tridiagonal C2 system; between knots the curve is
    the cubic Hermite of the two values and slopes. (Same curve as scipy's
    ``make_interp_spline(k=3)`` with first-derivative end conditions, without its import.)
    """
    n = len(knots) - 1
    h = np.diff(knots)
    # Slopes m (n+1,) = S @ [y, s0, sn].
    a = np.zeros((n + 1, n + 1))
    rhs = np.zeros((n + 1, n + 3))
    a[0, 0] = a[n, n] = 1.0
    rhs[0, n + 1] = rhs[n, n + 2] = 1.0
    for i in range(1, n):
        a[i, i - 1], a[i, i], a[i, i + 1] = 1 / h[i - 1], 2 / h[i - 1] + 2 / h[i], 1 / h[i]
        rhs[i, i - 1] -= 3 / h[i - 1] ** 2
        rhs[i, i] += 3 / h[i - 1] ** 2 - 3 / h[i] ** 2
        rhs[i, i + 1] += 3 / h[i] ** 2
    slopes = np.linalg.solve(a, rhs)
    seg = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, n - 1)
    hs = h[seg]
    s = (t - knots[seg]) / hs
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, (s**3 - 2 * s**2 + s) * hs
    h01, h11 = -2 * s**3 + 3 * s**2, (s**3 - s**2) * hs
    out = h10[:, None] * slopes[seg] + h11[:, None] * slopes[seg + 1]
    rows = np.arange(len(t))
    out[rows, seg] += h00
    out[rows, seg + 1] += h01
    return out


def damped_reach(times: np.ndarray, d: float, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """How far (in frames of velocity) each side's seam velocity carries at ``times``.

    A's continuation after ``t`` frames and B's before ``d - t`` frames, each
    ``t * exp(-t / tau)``: the full velocity near the seam, an offset that peaks at ``tau``
    frames and then fades back onto the blend path.
    """
    if tau <= 0:
        return np.zeros_like(times), np.zeros_like(times)
    return times * np.exp(-times / tau), (d - times) * np.exp(-(d - times) / tau)


@lru_cache(maxsize=256)
def damped_basis(length: int, tau: float) -> np.ndarray:
    """The straight line from pA to pB plus each seam's velocity beyond it, fading: (length, 4).

    Maps ``[pA, vA, pB, vB]``. With ``w = t / d`` (``d = length + 1``) and the line's slope
    ``s = (pB - pA) / d``, the frame at ``t`` is ``pA + w (pB - pA) + (1 - w) g(t) (vA - s) -
    w g(d - t) (vB - s)``, ``g(t) = t (1 + t / tau) exp(-t / tau)``. ``g`` has slope 1 and no
    curvature at 0, so each seam keeps its own velocity (the other seam's term reaches it only
    by ``(1 + d / tau) exp(-d / tau)``) and its acceleration there is only that of the weights
    ``1 - w`` and ``w`` (``2 (v - s) / d``), which bring the far seam's term to 0 at each seam on
    short gaps too. ``g``'s slope is 0 at ``1.6 tau`` frames, and the offset fades back onto the
    straight line (SLERP/LERP) by ``8 tau``. A motion that turns back (a wave) is not carried on
    past its seam, one that keeps going (a raised arm) for a few frames, and one at a steady
    speed (a walking root) stays on the line. At 30 fps the engine's ``tau`` (0.05 s) is 1.5
    frames: the first new frame carries about 0.8 of a seam's residual velocity, the next 0.3.
    """
    d = length + 1.0
    t = np.arange(1, length + 1, dtype=float)
    w = t / d
    u = d - t
    near_a = (1 - w) * t * (1 + t / tau) * np.exp(-t / tau)
    near_b = w * u * (1 + u / tau) * np.exp(-u / tau)
    out = np.stack([1 - w + (near_a - near_b) / d, near_a, w - (near_a - near_b) / d, -near_b], axis=1)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=256)
def hermite_basis(length: int) -> np.ndarray:
    """Cubic Hermite from (pA, vA) at 0 to (pB, vB) at length+1: matrix (length, 4)."""
    d = length + 1.0
    s = np.arange(1, length + 1) / d
    out = np.stack([2 * s**3 - 3 * s**2 + 1, (s**3 - 2 * s**2 + s) * d,
                    -2 * s**3 + 3 * s**2, (s**3 - s**2) * d], axis=1)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=256)
def linear_basis(length: int) -> np.ndarray:
    """Straight line from pA at 0 to pB at length+1: matrix (length, 2)."""
    s = np.arange(1, length + 1) / (length + 1.0)
    out = np.stack([1 - s, s], axis=1)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=256)
def inertialize_basis(length: int) -> np.ndarray:
    """B's start extrapolated back with vB, plus a quintic offset decay: matrix (length, 5).

    Maps ``[pA, vA, pB, vB, aA]``; the offset ``x0 = pA - (pB - vB d)``, ``v0 = vA - vB``,
    ``a0 = aA`` decays to zero value, velocity and acceleration at ``d = length + 1``.
    """
    d = length + 1.0
    t = np.arange(1, length + 1, dtype=float)
    # Offset polynomial x(t) = A t^5 + B t^4 + C t^3 + a0/2 t^2 + v0 t + x0, per unit x0, v0, a0.
    def poly(x0, v0, a0):
        a = -(a0 * d**2 + 6 * v0 * d + 12 * x0) / (2 * d**5)
        b = (3 * a0 * d**2 + 16 * v0 * d + 30 * x0) / (2 * d**4)
        c = -(3 * a0 * d**2 + 12 * v0 * d + 20 * x0) / (2 * d**3)
        return a * t**5 + b * t**4 + c * t**3 + 0.5 * a0 * t**2 + v0 * t + x0
    px, pv, pa = poly(1, 0, 0), poly(0, 1, 0), poly(0, 0, 1)
    # target(t) = pB - vB (d - t); x0 = pA - pB + vB d; v0 = vA - vB.
    out = np.stack([px, pv, 1 - px, -(d - t) + d * px - pv, pa], axis=1)
    out.setflags(write=False)
    return out

