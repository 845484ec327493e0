"""Bases of the interpolating methods: the in-between frames as linear maps of the seam values.

Every ``*_basis`` function returns a read-only matrix (cached per length) that maps rows of seam
values (``pA, vA, pB, vB`` and, per basis, a key or A's acceleration) to the ``length`` new
frames at times ``1..length``; A's end is at time 0 and B's start at ``length + 1``. ``damped``
is such a map per column once its time constants are known: :func:`damped_frames` applies it,
the time constants taken from the clips' motion at the seams (:func:`damped_time_scales`) and,
for the part of a seam velocity that heads for the other seam's pose faster than the straight
line, from the distance to go (:func:`reach_parts`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

VELOCITY_HORIZON_S = 0.1  # upm-valid: time constant (s) over which a seam velocity fades from the keys
DAMPED_TAU_S = 0.05  # damped: the seam velocities' shortest time constant (s; see damped_frames) ...
DAMPED_TAU_MAX_S = 0.33  # ... and the longest (see damped_time_scales; a reach's may be longer), ...
DAMPED_GAP_SHARE = 0.25  # ... nor more than this share of the gap (the offset peaks before its middle)
DAMPED_STEP_S = 1 / 30  # damped: the time scales are measured on samples this far apart ...
DAMPED_SAMPLES = 10  # ... this many of each clip at its seam (0.3 s each, both seams together)
DAMPED_REACH_SHARE = 0.35  # damped: a reach's time constant at most this share of the gap (see reach_parts)
# The peak of damped's carried offset g(t) = t (1 + t / tau) exp(-t / tau), in units of tau:
# at t = phi tau (phi the golden ratio), g = phi (1 + phi) exp(-phi) tau = 0.8399 tau.
_PHI = (1.0 + 5.0 ** 0.5) / 2.0
DAMPED_PEAK = _PHI * (1.0 + _PHI) * float(np.exp(-_PHI))


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


def damped_weights(length: int, tau: np.ndarray, tau_b: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """How much of A's and B's residual seam velocity each frame carries: (length, C) each, for
    time constants ``tau`` (C,) in frames, B's ``tau_b`` when it has its own (see
    :func:`damped_frames`)."""
    tau_b = tau if tau_b is None else tau_b
    d = length + 1.0
    t = np.arange(1, length + 1, dtype=float)[:, None]
    w = t / d
    u = d - t
    to_b = w * w * (3 - 2 * w)  # smoothstep: 0 and 1 with no slope at the seams
    near_a = (1 - to_b) * t * (1 + t / tau) * np.exp(-t / tau)
    near_b = to_b * u * (1 + u / tau_b) * np.exp(-u / tau_b)
    return near_a, near_b


def reach_parts(inputs: np.ndarray, starts: np.ndarray, columns: int, d: float,
                longest: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What carries each seam's velocity on to the other seam's pose: ``(tau_a, tau_b, part_a,
    part_b)``, (C,) each, for the rows ``pA, vA, pB, vB`` of ``inputs`` and a gap of ``d``
    frames between the seams (see :func:`damped_frames`).

    Per group of columns (a joint's rotation vector; each begins at ``starts``, as
    ``np.add.reduceat`` reads them) among the first ``columns``, with ``D = pB - pA``: where A's
    velocity along the path, ``s = D . vA / |D|``, is faster than the straight line's
    ``|D| / d``, the time constant ``|D| / (DAMPED_PEAK s)`` (at most ``longest``; the carried
    offset ``g(t) s`` peaks at ``DAMPED_PEAK tau s``, about the distance to go) and the part of
    ``vA - D / d`` along the path, ``(s / |D| - 1 / d) D``, which it carries; the velocity across
    the path keeps the column's own time constant. B's alike, where the velocity it arrives
    with comes from A's side faster than the line. 0 elsewhere (a velocity heading away or
    slower than the line, a still joint, the other columns), and at the threshold the part is 0,
    so the frames do not jump as a seam's speed crosses it.

    A hand rising at A's seam to where it is held at B's goes on rising until it gets there, as a
    reach does, instead of carrying its velocity for its own short time scale (the acceleration
    of a hand that starts to rise is high) and then crawling along the straight line.
    """
    n_c = inputs.shape[1]
    out = np.zeros((4, n_c))
    bounds = np.append(starts, n_c)
    groups = np.flatnonzero(bounds[1:] <= columns)
    if not len(groups):
        return out[0], out[1], out[2], out[3]
    first, last = bounds[groups], bounds[groups + 1]
    end = last[-1]
    diff = inputs[2, :end] - inputs[0, :end]
    dd = np.add.reduceat(diff * diff, first)
    for k, v in enumerate((inputs[1, :end], inputs[3, :end])):
        along = np.add.reduceat(diff * v, first)
        reach = (dd > 0) & (along * d > dd)
        with np.errstate(divide="ignore", invalid="ignore"):
            tau = np.where(reach, np.minimum(dd / (DAMPED_PEAK * along), longest), 0.0)
            share = np.where(reach, along / dd - 1.0 / d, 0.0)
        out[k, :end] = np.repeat(tau, last - first)
        out[2 + k, :end] = np.repeat(share, last - first) * diff
    return out[0], out[1], out[2], out[3]


def damped_frames(inputs: np.ndarray, length: int, scale: np.ndarray, tau_min: float, tau_max: float,
                  reach: tuple[np.ndarray, ...] | None = None) -> np.ndarray:
    """The straight line from pA to pB plus each seam's velocity beyond it, fading: the frames
    (length, C) from the rows ``pA, vA, pB, vB`` of ``inputs`` (4 or more, C), each column's
    time constant ``tau`` its ``scale`` (frames, :func:`damped_time_scales`) held within
    ``[tau_min, tau_max]``.

    With ``w = t / d`` (``d = length + 1``), the line's slope ``s = (pB - pA) / d`` and the
    smoothstep ``S(w) = w^2 (3 - 2 w)``, the frame at ``t`` is ``pA + w (pB - pA) + (1 - S(w))
    g(t) (vA - s) - S(w) g(d - t) (vB - s)``, ``g(t) = t (1 + t / tau) exp(-t / tau)``. ``g`` has
    slope 1 and no curvature at 0, so each seam keeps its own velocity; ``S`` is 0 and 1 with no
    slope at the seams, so neither seam's term reaches the other seam's value or velocity, on
    short gaps too, and the weights add no acceleration at the seams. ``g``'s slope is 0 at
    ``1.6 tau`` frames, and the offset fades back onto the straight line (SLERP/LERP) by
    ``8 tau``. A motion that turns back (a wave) is not carried on past its seam, one that keeps
    going (a raised arm) for as long as its time scale says, and one at a steady speed (a
    walking root) stays on the line. ``reach``: :func:`reach_parts`, the part of each seam's
    velocity that heads for the other seam's pose faster than the line, carried with its own
    longer time constant (not below the column's), the bounds notwithstanding.
    """
    p_a, v_a, p_b, v_b = inputs[:4]
    tau = np.clip(scale, tau_min, tau_max)
    near_a, near_b = damped_weights(length, tau)
    d = length + 1.0
    slope = (p_b - p_a) / d
    w = (np.arange(1, length + 1) / d)[:, None]
    out = p_a + w * (p_b - p_a) + near_a * (v_a - slope) - near_b * (v_b - slope)
    if reach is not None:
        tau_a, tau_b, part_a, part_b = reach
        far_a, far_b = damped_weights(length, np.maximum(tau, tau_a), np.maximum(tau, tau_b))
        out += (far_a - near_a) * part_a - (far_b - near_b) * part_b
    return out


def damped_time_scales(samples, step: int, starts: np.ndarray) -> np.ndarray:
    """The time scale (frames) of the motion in ``samples``: a sequence of arrays (n, C), each
    in time order, ``step`` frames apart (the engine gives A's last and B's first); per group of
    columns (each begins at ``starts``, as ``np.add.reduceat`` reads them) ``sqrt(mean |v|^2 /
    mean |a|^2)`` of their velocity and acceleration, each array's means added, repeated over
    the group's columns.

    For a sinusoid of angular frequency ``omega`` sampled over its period this is ``1 / omega``
    whatever its phase: the time a velocity keeps pointing one way (a quarter period is
    ``1.57 / omega``), which is when :func:`damped_frames`'s offset peaks (``1.6 tau``). Over
    less than a period it is how long the velocity there would last at its acceleration there
    (long where the motion is at full speed, short where it turns): the two seams' samples
    together see more of it than either. A group that does not move gets 0, one that moves
    without accelerating ``inf``; an array of fewer than 3 samples adds nothing.
    """
    n_c = samples[0].shape[1]
    ev, ea = np.zeros(len(starts)), np.zeros(len(starts))
    for rows in samples:
        if len(rows) < 3:
            continue
        v = np.diff(rows, axis=0) / step
        a = np.diff(v, axis=0) / step
        ev += np.add.reduceat(np.mean(v * v, axis=0), starts)
        ea += np.add.reduceat(np.mean(a * a, axis=0), starts)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(ea > 0, np.sqrt(ev / ea), np.where(ev > 0, np.inf, 0.0))
    return np.repeat(scale, np.diff(np.append(starts, n_c)))


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

