"""Changes that set off from rest and come to rest: a change of the new frames' values (a knee's
bend) moved as little as it can be so that it accelerates at most a bound, within a box.

The foot lock's turn of a knee (:func:`posturemap.synth.feet.knee_bounded`) and the turn that
holds a knee or elbow within the library's range (:func:`posturemap.synth.hinges.unbend`) are
each such a change: made frame by frame they jump where the goal jumps or where a bend passes a
bound, and a jump in a joint's angle, or in its rate, is a pop the eye sees. Both ask the same
of it: 0 in the two clip frames on either side of the new ones (the clips' motion is kept), and
every second difference, A's last frame's and B's first included, at most the bound (for the
lock, the turn's own; for ``unbend``, the knee's: the turn's plus the motion's, ``own``, each
within its own ``bound``).
:func:`rest_bounded` finds it by projections onto each bound, and where they stop short by the
least squares projection (:func:`rest_projected`). The compiled twins are
:func:`posturemap.core.numba_kernels._rest_bounded` and ``_rest_projected``.
"""

from __future__ import annotations

import numpy as np

REST_PASSES = 200  # rest_bounded's sweeps at most
REST_PLAIN = 20  # the sweeps that project onto each bound before they over-relax
REST_RELAX = 1.9  # then each projection goes this far (below 2: the sweeps still converge)
REST_EXACT = 500  # where the sweeps stop short, iterations at most of the exact projection (rest_projected)
REST_RHO = 0.3  # ... its ADMM penalty, over the bound
REST_OVER = 1.6  # ... and its over-relaxation


def at_rest(change: np.ndarray) -> np.ndarray:
    """The second differences (L + 2,) of a change of the new frames (L,), 0 in the clips' two
    frames on either side: at A's last frame, at each new frame and at B's first."""
    return np.diff(np.concatenate([[0.0, 0.0], change, [0.0, 0.0]]), 2)


def rest_bounded(change: np.ndarray, accel: float, lo: np.ndarray | None = None,
                 hi: np.ndarray | None = None, own: np.ndarray | None = None,
                 bound: np.ndarray | None = None) -> np.ndarray:
    """``change`` (L,) moved as little as the sweeps find so that, 0 in the two frames before it
    and the two after it (the clips' frames beside the new ones), every second difference is at
    most ``accel``: the one at each new frame, and at A's last frame and B's first (there the
    first and the last value themselves); each value within ``lo`` and ``hi`` (L,) where given
    (``change`` must be). A change of the new frames that sets off from rest and comes to
    rest within a bound on its acceleration.

    ``own`` (L + 2,): the second differences (as :func:`at_rest` gives them) of the motion the
    change is added to, where it is the sum that is bounded: each second difference of the
    change plus the motion's own within ``accel``, or within the motion's own size where that
    is larger (the change may follow the motion's own acceleration, never exceed it; 0 is
    always within), or within ``bound`` (L + 2,) where given: :func:`posturemap.synth.hinges.faded`'s,
    the motion's own only where the knee is within its range, ``accel`` where it is past it.

    Each bound is a slab in the values it touches (one, two or three of them); a sweep projects
    the values onto the slabs they break (Kaczmarz's projections onto convex sets: a point
    within every bound near the nearest one, not that one), the second differences three frames
    apart at once (they share no value), then onto ``[lo, hi]``, and after ``REST_PLAIN``
    sweeps over-relaxed by ``REST_RELAX`` (still converging: a relaxation below 2), for at most
    ``REST_PASSES`` sweeps. Of 817 knee changes the lock made between seeded pairs of bandai1's
    clips and of LaFAN1's subject 5 (its own map of subjects 1-4; 30 and 60 fps), the 282 that
    broke the bound ended within 1.0001 of it after at most 44 sweeps, and moved at most 1.16x
    as far as the least squares projection onto the bound (median 1.00; scipy's SLSQP, for the
    comparison). The sweeps before these moved only the frame over the bound, a quarter of its
    excess, and stalled where a seam's frame was held at the bound: they left 39 of the 282
    over it, one at 3.8x, and moved 1.2x as far (median).

    A sweep moves a value by its neighbours' excess only: a change over many frames needs
    sweeps as the square of its frames. Where ``REST_PASSES`` sweeps leave the change over the
    bound (a whole 0.3 s plateau at 120 fps, where the bound per frame squared is a sixteenth of
    30 fps's; a change far beyond a knee's, 14 radians over 20 frames at 30 fps, needs some 500),
    the least squares projection onto the bound and the box is found instead
    (:func:`rest_projected`, at most ``REST_EXACT`` iterations; some 230 there). Before it, what
    the sweeps left was scaled down toward 0: a lock at 120 fps that lifted a toe out of the
    floor while the hips rose out of a crouch had its knee's change cut to a seventh, and the
    ankle, put along the hip-goal line at the distance of that bend, went 21 cm under the floor.
    What is left over the bound after that (only a change the iterations cannot bring within
    it) is scaled down toward 0 until it is within it: a smaller change, within every bound
    where the box holds 0 (the bounds are convex and symmetric about it). Where it does not
    (:func:`~posturemap.synth.hinges.unbend`'s, at a knee past the library's bound) the scaled
    change can leave the box, and the caller clips it back: the box is the harder bound there.

    The box: :func:`~posturemap.synth.feet.knee_bounded` clips the bend to [0, pi]; the
    projection rings below 0 beside a block of positive change (by up to 1.3 times the bound),
    and a nearly straight leg's bend, clipped there, broke the bound again (1.67x; a cold
    review).
    """
    n = len(change)
    c = np.zeros(n + 4)  # the clips' two frames on either side, 0
    c[2:-2] = change
    free = np.zeros(n + 4)
    free[2:-2] = 1.0
    centres = np.arange(1, n + 3)  # every second difference bounded: A's last frame to B's first
    norm2 = free[centres - 1] + 4.0 * free[centres] + free[centres + 1]
    low = np.full(n + 4, -np.inf) if lo is None else np.concatenate([[0.0, 0.0], lo, [0.0, 0.0]])
    high = np.full(n + 4, np.inf) if hi is None else np.concatenate([[0.0, 0.0], hi, [0.0, 0.0]])
    own = np.zeros(n + 2) if own is None else own
    bound = np.maximum(accel, np.abs(own)) if bound is None else bound

    def size(x):  # each second difference's size, the motion's own added (x padded with the clips' 0)
        return np.abs(x[:-2] - 2.0 * x[1:-1] + x[2:] + own)

    for sweep in range(REST_PASSES):
        if np.all(size(c) - bound <= bound * 1e-4):
            break
        relax = 1.0 if sweep < REST_PLAIN else REST_RELAX
        for first in range(3):
            m = centres[first::3]
            second = c[m - 1] - 2.0 * c[m] + c[m + 1] + own[m - 1]
            f = relax * np.sign(second) * np.maximum(np.abs(second) - bound[m - 1], 0.0) / norm2[m - 1]
            c[m - 1] -= f * free[m - 1]
            c[m] += 2.0 * f * free[m]
            c[m + 1] -= f * free[m + 1]
            c = np.clip(c, low, high)
    if n and not np.all(size(c) - bound <= bound * 1e-4):
        c[2:-2] = rest_projected(change, accel, low[2:-2], high[2:-2], own, bound)
        now = size(c)
        past = now - bound > bound * 1e-4
        if past.any():  # scaled toward 0 (within every bound: |s + own| <= |s| + |own|) until within
            ours = np.abs(own[past])
            c *= max(np.min((bound[past] - ours) / (now[past] - ours)), 0.0)
    return c[2:-2]


def rest_projected(change: np.ndarray, accel: float, lo: np.ndarray, hi: np.ndarray,
                   own: np.ndarray | None = None, bound: np.ndarray | None = None) -> np.ndarray:
    """The least squares projection of ``change`` (L,) onto :func:`rest_bounded`'s bound (every
    second difference at most ``accel``, the clips' two frames on either side 0; with ``own``,
    the sum's, as there) and the box
    ``[lo, hi]`` (L,), by ADMM (the alternating direction method of multipliers): each iteration
    one solve of ``(1 + r) I + r D'D`` (pentadiagonal, factored once; ``D`` the second
    differences, ``r = REST_RHO / accel``), then the second differences clipped onto the bound
    and the values onto the box (both over-relaxed by ``REST_OVER``). Stops where every second
    difference is within 1.001 of the bound, every value within the box and no value moved by
    more than a thousandth of the bound in the last iteration, at most ``REST_EXACT``
    iterations; the values are clipped onto the box (the caller scales what is still over the
    bound). The numpy steps of the compiled
    :func:`posturemap.core.numba_kernels._rest_projected`.

    Stopped where the values move by under a thousandth of the bound from one iteration to the
    next as well: stopped as soon as they were within it, the projection of a 1.2 radian block
    over 8 frames moved 1.07x as far as the least squares one (SLSQP's); so, within 1.0015x of
    it over the seven changes of ``tests/test_rest.py``, in 21-246 iterations, and 253 on a 0.3 s
    plateau at 120 fps (with the penalty at 1 over the bound and no over-relaxation: 500, the
    cap, and still 1.01x over the bound there; a cold review). Compiled, 0.3 / 0.4 / 0.8 ms for
    60 / 90 / 180 frames, after the sweeps that stopped short (0.8 / 1.1 / 2.2 ms)."""
    from scipy.linalg import cho_solve_banded, cholesky_banded

    n = len(change)
    rho = REST_RHO / accel
    band = np.zeros((3, n))  # upper form: the diagonal last
    band[0, 2:], band[1, 1:], band[2] = rho, -4.0 * rho, 1.0 + 7.0 * rho
    factor = cholesky_banded(band)

    def spread(z):  # D' z
        return z[:-2] - 2.0 * z[1:-1] + z[2:]

    own = np.zeros(n + 2) if own is None else own
    bound = np.maximum(accel, np.abs(own)) if bound is None else bound
    least, most = -bound - own, bound - own  # each second difference of the change (own: rest_bounded)
    y = np.clip(at_rest(change), least, most)
    w = np.clip(change, lo, hi)
    u, v = np.zeros(n + 2), np.zeros(n)
    c = change
    for _ in range(REST_EXACT):
        before = c
        c = cho_solve_banded((factor, False), change + rho * spread(y - u) + rho * (w - v))
        dc = at_rest(c)
        dc_r = REST_OVER * dc + (1.0 - REST_OVER) * y  # over-relaxed
        c_r = REST_OVER * c + (1.0 - REST_OVER) * w
        y = np.clip(dc_r + u, least, most)
        w = np.clip(c_r + v, lo, hi)
        u += dc_r - y
        v += c_r - w
        if (np.all(np.abs(dc + own) <= bound * 1.001) and np.all(c >= lo - 1e-12) and np.all(c <= hi + 1e-12)
                and np.abs(c - before).max() <= accel * 1e-3):
            break
    return np.clip(c, lo, hi)
