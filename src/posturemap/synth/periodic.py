"""An oscillation continued through a gap: where a joint swings back and forth at both seams (a
waving hand), the fallback ``damped`` plays the swing on through the gap in phase with both.

``damped`` (:mod:`posturemap.synth.bases`) carries each seam's velocity for the motion's own
time scale and returns to the straight line between the seams: for a wave that line lies wherever
the two seams' phases put it, and the swing stops. A wave, though, keeps its rhythm. From A's
last and B's first samples (the ones ``damped`` reads) :func:`continued` fits one frequency
shared by the swinging joints and, per column, ``c0 + c1 t / d + a cos(w t) + b sin(w t)`` by
least squares over both seams' samples together, so that the phase has to agree with both ends;
the seams' residual values and velocities are then taken off with ``damped``'s shortest time
constant, so the result starts and ends on the seams exactly.

A joint is continued only where the samples show a swing (:func:`swinging`: it turns back at a
seam and moves at both), where the sinusoid explains its samples much better than a cubic (as
many parameters) does (:data:`PERIODIC_GATE`), and where the shared frequency is its own
(:data:`PERIODIC_OWN`). A bow, a pointing arm, an arm raised at one seam and lowered at the
other, or a root turning are smooth over 0.3 s at each seam and stay ``damped``'s; a hand that
turns back two or three times in the same 0.6 s is continued; an elbow waving over walking legs
keeps ``damped``'s too, rather than the walk's rhythm.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..core import kernels
from .bases import damped_frames

PERIODIC_MIN_S = 0.3  # the shortest period (s) looked for ...
PERIODIC_MAX_S = 1.5  # ... and the longest
PERIODIC_GRID = 8  # frequency steps per 1 / (the time the samples span): an eighth of a cycle of drift over the samples
PERIODIC_GATE = (0.25, 0.5)  # a joint's residual, sinusoid over cubic: continued in full under the first, not above the second
PERIODIC_TURN = (0.6, 0.9)  # a joint's net travel over its path at a seam: turning back under the first, straight on above the second
PERIODIC_BALANCE = (0.05, 0.2)  # the quieter seam's speed^2 over the busier one's: none under the first, full above the second
PERIODIC_PEAKS = 3  # the highest peaks of the frequency grid's fit refined
PERIODIC_OWN = 2.0  # a joint whose own best frequency leaves a residual this many times smaller keeps its own rhythm: not continued
PERIODIC_MIN_RMS = np.radians(1.0)  # a joint a cubic fits within this (RMS, radians) has no swing worth continuing
PERIODIC_MIN_SAMPLES = 6  # each seam's samples needed (fewer cannot show a swing)


def frequencies(span: float, fps: float) -> np.ndarray:
    """The angular frequencies (radians per frame) tried for samples spanning ``span`` frames:
    periods from :data:`PERIODIC_MIN_S` to :data:`PERIODIC_MAX_S`, evenly spaced in frequency
    by ``1 / (PERIODIC_GRID * span)`` cycles per frame (two fits that far apart in frequency
    drift by an eighth of a cycle over the samples)."""
    return _grid(float(span), float(fps), PERIODIC_GRID, PERIODIC_MIN_S, PERIODIC_MAX_S)


@lru_cache(maxsize=64)
def _grid(span: float, fps: float, steps: int, shortest: float, longest: float) -> np.ndarray:
    lo, hi = 1.0 / (longest * fps), 1.0 / (shortest * fps)
    out = 2 * np.pi * np.linspace(lo, hi, max(int(np.ceil((hi - lo) * steps * span)) + 1, 2))
    out.setflags(write=False)
    return out


def _design(times: np.ndarray, omega, d: float) -> np.ndarray:
    """``[1, t / d, cos(w t), sin(w t)]`` at ``times`` for each ``omega``: (W, n, 4)."""
    wt = np.multiply.outer(np.atleast_1d(omega), times)
    out = np.empty(wt.shape + (4,))
    out[..., 0] = 1.0
    out[..., 1] = times / d
    out[..., 2] = np.cos(wt)
    out[..., 3] = np.sin(wt)
    return out


def _explained(rows: np.ndarray, times: np.ndarray, omega: float, d: float) -> float:
    """How much of ``rows`` (summed over columns) the fit at ``omega`` explains."""
    x = _design(times, omega, d)[0]
    return float(np.trace(np.linalg.solve(x.T @ x + 1e-9 * np.eye(4), x.T @ (rows @ (rows.T @ x)))))


def _peak(omegas: np.ndarray, explained: np.ndarray, exact, peaks: int) -> float:
    """The frequency that explains the most: each local maximum of ``explained`` on the grid
    moved to its parabola's vertex through its neighbours, the ``peaks`` highest
    by the parabolas evaluated ``exact``-ly, the best of them (or of the grid) kept. Peaks of
    aliases (frequencies that put both seams in phase with a different number of swings
    between) stand close in height; judged at grid points, the one that falls nearest a grid
    point would win."""
    inner = np.flatnonzero((explained[1:-1] >= explained[:-2]) & (explained[1:-1] >= explained[2:])) + 1
    best, best_val = omegas[int(np.argmax(explained))], float(explained.max())
    if not len(inner):
        return best
    y0, y1, y2 = explained[inner - 1], explained[inner], explained[inner + 1]
    curve = y0 - 2 * y1 + y2
    shift = np.where(curve < 0, 0.5 * (y0 - y2) / np.where(curve < 0, curve, -1.0), 0.0)
    step = omegas[1] - omegas[0]
    height = y1 - 0.25 * (y0 - y2) * shift
    for i in np.argsort(-height, kind="stable")[:peaks]:
        om = omegas[inner[i]] + shift[i] * step
        val = exact(om)
        if val > best_val:
            best, best_val = om, val
    return best


def _ramp(x, lo: float, hi: float):
    """0 at ``lo``, 1 at ``hi``, linear in between (either way round)."""
    return np.clip((x - lo) / (hi - lo), 0.0, 1.0)


def swinging(side_a: np.ndarray, side_b: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Per joint (groups of columns at ``starts``), how far the samples of each seam (``side_a``
    and ``side_b``, (n, C) each in time order) show a swing to continue, 0 to 1: at least one
    seam's must turn back (its net travel well under its path: :data:`PERIODIC_TURN`), and
    both must move (the quieter seam's mean squared speed a share of the busier one's:
    :data:`PERIODIC_BALANCE`). An arm raised at A's seam and lowered at B's travels straight
    on at both, though a cosine fits it as half a swing; an arm that waves at A's seam and
    rests at B's has stopped waving."""
    straight = np.ones(len(starts))
    energy = []
    for side in (side_a, side_b):
        step = np.diff(side, axis=0)
        path = np.sqrt(np.add.reduceat(step * step, starts, axis=1)).sum(axis=0)
        net = side[-1] - side[0]
        net = np.sqrt(np.add.reduceat(net * net, starts))
        straight = np.minimum(straight, np.where(path > 1e-12, net / np.maximum(path, 1e-12), 1.0))
        energy.append(np.add.reduceat(np.mean(step * step, axis=0), starts))
    quiet, busy = np.minimum(*energy), np.maximum(*energy)
    share = np.where(busy > 1e-12, quiet / np.maximum(busy, 1e-12), 0.0)
    return _ramp(straight, *PERIODIC_TURN[::-1]) * _ramp(share, *PERIODIC_BALANCE)


def continued(rows: np.ndarray, times: np.ndarray, inputs: np.ndarray, length: int, fps: float, starts: np.ndarray,
              tau: float) -> tuple[np.ndarray, np.ndarray]:
    """The swing of the columns of ``rows`` continued through a gap of ``length`` frames, and
    how much of it to take per column: ``(frames (length, C), weights (C,))``, the frames None
    where no joint swings (:func:`swinging`) or either clip gives fewer than
    :data:`PERIODIC_MIN_SAMPLES` samples.

    ``rows`` (n, C) are samples at ``times`` (n,; frames, A's seam at 0 and B's at ``length +
    1``) of both clips; ``inputs`` the seam rows ``pA, vA, pB, vB`` (4 or more, C) as for
    :func:`posturemap.synth.bases.damped_frames`; ``starts`` where each joint's columns begin
    (as ``np.add.reduceat`` reads them); ``tau`` the time constant (frames) over which the seams'
    residuals are let go.

    One angular frequency from :func:`frequencies` is shared by the columns: the one whose fit
    explains most of the swinging joints' samples (a wave's shoulder, elbow and wrist swing
    together; pooled, they tell the phase apart better than each alone: over the six splits of
    ``docs/retrieval.md`` each joint's own frequency scored 0.602x SLERP's L2Q at 30 frames
    against 0.595x), judged between the grid's points at its highest peaks (:func:`_peak`).
    Each joint's weight is :func:`swinging`'s, times how much better the sinusoid fits its
    samples than a cubic does (:data:`PERIODIC_GATE`), and 0 where its own best frequency on
    the grid leaves a residual :data:`PERIODIC_OWN` times smaller than the shared one's, or
    where a cubic fits its samples within :data:`PERIODIC_MIN_RMS` (nothing to gain; when no
    joint is left, the frequency search is skipped).
    """
    if min(np.count_nonzero(times <= 0), np.count_nonzero(times > 0)) < PERIODIC_MIN_SAMPLES:
        return None, np.zeros(rows.shape[1])
    if kernels.backend() == "numba":  # the same steps compiled (some fifty numpy calls otherwise)
        frames, weights = np.empty((length, rows.shape[1])), np.empty(rows.shape[1])
        omegas = frequencies(float(times.max() - times.min()), fps)
        # C order always: one compiled version (a fancy-indexed selection of columns comes in
        # Fortran order, and a second version costs a 10-40 ms load on its first call).
        rows, inputs = np.ascontiguousarray(rows), np.ascontiguousarray(inputs)
        found = kernels.compiled().swing_columns(rows, times, inputs, length, omegas, starts, float(tau),
                                                 PERIODIC_GATE, PERIODIC_TURN, PERIODIC_BALANCE, PERIODIC_PEAKS,
                                                 PERIODIC_OWN, PERIODIC_MIN_RMS, frames, weights)
        return (frames if found else None), weights
    swing = swinging(rows[times <= 0], rows[times > 0], starts)
    if not swing.any():
        return None, np.zeros(rows.shape[1])
    d = length + 1.0
    n = len(times)
    sizes = np.diff(np.append(starts, rows.shape[1]))
    # A cubic through each joint's samples: a joint it fits within PERIODIC_MIN_RMS has no swing
    # worth continuing; the others are judged against it below.
    s = (times - 0.5 * d) / d
    cubic = np.stack([np.ones(n), s, s * s, s * s * s], axis=1)
    fit = cubic @ np.linalg.lstsq(cubic, rows, rcond=None)[0]
    res_cubic_j = np.add.reduceat(np.sum((rows - fit) ** 2, axis=0), starts)
    swing = np.where(res_cubic_j > n * sizes * PERIODIC_MIN_RMS ** 2, swing, 0.0)
    if not swing.any():
        return None, np.zeros(rows.shape[1])
    omegas = frequencies(float(times.max() - times.min()), fps)
    x = _design(times, omegas, d)  # (W, n, 4)
    xt = x.transpose(0, 2, 1)
    xtx = xt @ x + 1e-9 * np.eye(4)
    # The frequency that explains the most of the swinging joints: trace(inv(X'X) X'G X), G = Y Y'.
    swung = rows[:, np.repeat(swing > 0, sizes)]
    xgx = xt @ (swung @ (swung.T @ x))
    explained = np.trace(np.linalg.solve(xtx, xgx), axis1=1, axis2=2)
    omega = _peak(omegas, explained, lambda om: _explained(swung, times, om, d), PERIODIC_PEAKS)
    xb = _design(times, omega, d)[0]
    xty = xb.T @ rows  # (4, C)
    coef = np.linalg.solve(xb.T @ xb + 1e-9 * np.eye(4), xty)
    res_wave = np.sum((rows - xb @ coef) ** 2, axis=0)
    res_wave_j = np.add.reduceat(res_wave, starts)
    lo, hi = PERIODIC_GATE
    moving = swing > 0  # (and so res_cubic_j > 0)
    ratio = np.where(moving, res_wave_j / np.where(moving, res_cubic_j, 1.0), np.inf)
    # Each joint's own best frequency on the grid: one whose swing that frequency fits far
    # better than the shared one keeps another rhythm (an elbow waving over walking legs).
    xty_all = xt @ rows  # (W, 4, C)
    own = np.einsum("wac,wac->wc", np.linalg.solve(xtx, xty_all), xty_all)
    own_res = np.maximum(np.add.reduceat(np.sum(rows * rows, axis=0), starts)
                         - np.add.reduceat(own, starts, axis=1).max(axis=0), 0.0)
    in_rhythm = res_wave_j <= PERIODIC_OWN * np.maximum(own_res, 1e-300)
    weight = _ramp(ratio, hi, lo) * swing * in_rhythm
    weights = np.repeat(weight, sizes)

    t = np.arange(1, length + 1, dtype=float)
    frames = _design(t, omega, d)[0] @ coef
    # The fit at A's last two frames and B's first two, as the seam rows measure the clips.
    at = _design(np.array([-1.0, 0.0, d, d + 1.0]), omega, d)[0] @ coef
    residual = np.stack([inputs[0] - at[1], inputs[1] - (at[1] - at[0]), inputs[2] - at[2], inputs[3] - (at[3] - at[2])])
    frames += damped_frames(residual, length, np.zeros(rows.shape[1]), tau, tau)
    return frames, weights

