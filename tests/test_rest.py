"""rest.rest_bounded: a change of the new frames that sets off from rest and comes to rest within
a bound on its second differences, moved as little as it must; compiled, the same."""

from __future__ import annotations

import numpy as np
import pytest

from posturemap.core import kernels
from posturemap.synth import feet, rest
from posturemap.synth.rest import at_rest


def least_squares_at_rest(change, accel, lo=None, hi=None):
    """The nearest change whose second differences (at_rest) are within accel (and its values
    within ``lo`` and ``hi``, where given): scipy's SLSQP."""
    from scipy.optimize import Bounds, minimize

    n = len(change)
    d = np.array([at_rest(e) for e in np.eye(n)]).T  # (n + 2, n): the second differences' matrix
    bound = [{"type": "ineq", "fun": lambda x, s=s: accel - s * (d @ x), "jac": lambda x, s=s: -s * d}
             for s in (1.0, -1.0)]
    box = None if lo is None else Bounds(lo, hi)
    res = minimize(lambda x: 0.5 * ((x - change) ** 2).sum(), np.zeros(n), jac=lambda x: x - change,
                   method="SLSQP", constraints=bound, bounds=box, options={"maxiter": 500, "ftol": 1e-14})
    assert res.success
    return res.x


def steep_changes():
    """Changes a lock makes of a knee's bend, too steep for the bound (0.15): a ramp onto a plateau
    (the sweeps before rest_bounded left 2.75x the bound: the first frame held at it, its
    neighbour's own second difference within it, nothing moved on), a step at the last frame,
    a bump, and seeded smooth walks, 1.5 radians at most."""
    rng = np.random.default_rng(7)
    out = [np.array([0.0, 0.75] + [1.5] * 10), np.r_[np.zeros(8), 0.9], 1.5 * np.exp(-0.5 * ((np.arange(30) - 12) / 1.5) ** 2)]
    for n in (8, 20, 60):  # a bend changes by less than pi: these by 1.5 radians at most
        walk = np.convolve(np.cumsum(rng.normal(size=n)), np.ones(5) / 5, mode="same")
        out.append(walk * 1.5 / np.abs(walk).max())
    return out


def test_rest_bounded_brings_every_second_difference_within_the_bound_seams_included():
    accel = 0.15
    for change in steep_changes():
        assert np.abs(at_rest(change)).max() > 2 * accel
        got = rest.rest_bounded(change, accel)
        assert np.abs(at_rest(got)).max() <= accel * (1 + 1e-4)
        # As little as it must: as near the change as the least squares projection onto the bound,
        # within 20 % (0 is within the bound too, but not near).
        best = least_squares_at_rest(change, accel)
        assert np.linalg.norm(got - change) <= 1.2 * np.linalg.norm(best - change) + 1e-9
    # A change within the bound is left as it is.
    calm = 0.3 * np.sin(np.linspace(0.0, np.pi, 40)) ** 2
    assert np.abs(at_rest(calm)).max() < accel
    np.testing.assert_array_equal(rest.rest_bounded(calm, accel), calm)


def test_rest_bounded_keeps_within_its_box_and_scales_what_the_sweeps_leave(monkeypatch):
    accel = 0.15
    change = np.r_[np.zeros(6), np.full(8, 1.2), np.zeros(10)]  # a block: the projection rings below 0 beside it
    assert rest.rest_bounded(change, accel).min() < -0.01
    got = rest.rest_bounded(change, accel, np.zeros(len(change)), np.full(len(change), 2.0))
    assert got.min() >= 0.0 and np.abs(at_rest(got)).max() <= accel * (1 + 1e-4)
    # Two sweeps leave the plateau far over the bound: projected onto it instead, as near the
    # change as the least squares projection (SLSQP's) within 5 %, within the box; with two
    # iterations of that too, scaled toward 0 onto it.
    monkeypatch.setattr(rest, "REST_PASSES", 2)
    few = rest.rest_bounded(change, accel)
    assert np.abs(at_rest(few)).max() <= accel * (1 + 1e-4)
    best = least_squares_at_rest(change, accel)
    assert np.linalg.norm(few - change) <= 1.05 * np.linalg.norm(best - change)
    boxed = rest.rest_bounded(change, accel, np.zeros(len(change)), np.full(len(change), 2.0))
    assert boxed.min() >= 0.0 and np.abs(at_rest(boxed)).max() <= accel * (1 + 1e-4)
    monkeypatch.setattr(rest, "REST_EXACT", 2)
    few = rest.rest_bounded(change, accel)
    assert np.abs(at_rest(few)).max() == pytest.approx(accel)
    assert 0.0 < np.abs(few).max() < np.abs(change).max()  # less than the sweeps took it, not 0


def test_rest_bounded_projects_a_change_over_many_frames_the_sweeps_cannot_bring_within_the_bound():
    # A knee's change over 90 frames at 120 fps (the bound per frame squared a sixteenth of 30
    # fps's): 1.5 radians for 0.3 s in the middle, within a box that holds a nearly straight
    # leg's bend at 0 near B. The sweeps need thousands of passes for it; what they left was
    # scaled down toward 0, to a seventh of what the bound allows (a lock lifting a toe out of
    # the floor while the hips rose out of a crouch put the ankle 21 cm under it). Now projected:
    # as near the change as the least squares projection (SLSQP's), within the bound and the box.
    n, accel = 90, feet.KNEE_ACCEL / 120.0**2
    t = np.arange(n)
    change = 1.5 * np.exp(-0.5 * ((t - 45) / 12.0) ** 8)
    lo, hi = np.full(n, -1.0), np.full(n, 3.0)
    lo[-12:] = -1e-3  # a straight leg near B: its bend cannot go below straight
    got = rest.rest_bounded(change, accel, lo, hi)
    assert np.abs(at_rest(got)).max() <= accel * (1 + 1e-4)
    assert np.all(got >= lo) and np.all(got <= hi)
    best = least_squares_at_rest(change, accel, lo, hi)
    assert np.linalg.norm(got - change) <= 1.01 * np.linalg.norm(best - change)
    assert got.max() > 0.9 * change.max()
    # The compiled projection, the same.
    assert (kernels.compiled()._REST_RHO, kernels.compiled()._REST_OVER) == (rest.REST_RHO, rest.REST_OVER)
    same = change.copy()
    kernels.compiled()._rest_bounded(same, accel, rest.REST_PASSES, rest.REST_PLAIN, rest.REST_RELAX,
                                     rest.REST_EXACT, lo, hi, np.zeros(n + 2), np.full(n + 2, accel))
    np.testing.assert_allclose(same, got, rtol=0, atol=1e-9)


def test_rest_bounded_is_the_same_compiled(monkeypatch):
    nk = kernels.compiled()
    for change in steep_changes() + [np.array([0.4]), np.array([0.3, -0.3])]:
        got = change.copy()
        nk._rest_bounded(got, 0.15, rest.REST_PASSES, rest.REST_PLAIN, rest.REST_RELAX, rest.REST_EXACT,
                         np.full(len(got), -np.inf), np.full(len(got), np.inf), np.zeros(len(got) + 2),
                         np.full(len(got) + 2, 0.15))
        np.testing.assert_allclose(got, rest.rest_bounded(change, 0.15), rtol=0, atol=1e-12)
        # Within a box too, projected where the sweeps cannot reach it (the two Cholesky factors,
        # LAPACK's and the kernel's, round apart), and scaled where that cannot either.
        lo, hi = np.minimum(change, 0.0) - 0.01, np.maximum(change, 0.0) + 0.01
        for passes, exact in ((rest.REST_PASSES, rest.REST_EXACT), (3, rest.REST_EXACT), (3, 2)):
            got = change.copy()
            nk._rest_bounded(got, 0.15, passes, rest.REST_PLAIN, rest.REST_RELAX, exact, lo, hi, np.zeros(len(got) + 2),
                             np.full(len(got) + 2, 0.15))
            monkeypatch.setattr(rest, "REST_PASSES", passes)
            monkeypatch.setattr(rest, "REST_EXACT", exact)
            want = rest.rest_bounded(change, 0.15, lo, hi)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 if passes > 3 else 1e-9)


def knee_held_at_straight(frames: int, seed: int = 3):
    """A knee's bend (radians) swinging back past straight and forward again, quickly (a seeded
    smooth walk plus a 40 degree backward bump over six frames), and the change that holds it
    at straight (0 where it is bent forward): ``(bend, hard, lo, own)``, ``own`` the bend's
    second differences at the new frames with two new neighbours (rest_bounded's)."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)
    bend = np.radians(20.0 + 5.0 * np.sin(t / 5.0 + rng.uniform(0.0, 6.0)))
    bend -= np.radians(60.0) * np.where(np.abs(t - frames // 2) < 3, np.cos(np.pi * (t - frames // 2) / 6.0) ** 2, 0.0)
    lo = -bend
    hard = np.maximum(lo, 0.0)
    own = np.zeros(frames + 2)
    own[2:frames] = np.diff(bend, 2)
    return bend, hard, lo, own


def test_rest_bounded_bounds_the_sum_with_the_motions_own_second_differences():
    # Bounding the change alone, a knee held on a bound that the motion swings across quickly
    # is pushed off it: the change cannot follow the motion's own acceleration there, and the
    # knee bent 14 degrees forward here (25-32 in a cold review's bumps). Given the motion's own
    # second differences, the sum is bounded instead, by accel or by the motion's own where
    # that is larger: the knee rests on the bound, follows the motion off it, and slows onto it.
    accel = 60.0 / 30.0**2
    bend, hard, lo, own = knee_held_at_straight(40)
    assert np.abs(own).max() > 3 * accel  # the bump's own acceleration
    alone = rest.rest_bounded(hard, accel, lo, np.full(40, np.inf))
    summed = rest.rest_bounded(hard, accel, lo, np.full(40, np.inf), own)
    bound = np.maximum(accel, np.abs(own))
    assert np.all(np.abs(at_rest(summed) + own) <= bound * (1 + 1e-4))
    assert np.all(summed >= lo - 1e-12)
    knee_alone, knee = bend + alone, bend + summed
    held = hard > 0.0
    assert np.degrees(knee_alone[held]).max() > 10.0  # pushed far off the bound
    assert np.degrees(knee[held]).max() < 2.0
    # Compiled, the same.
    got = hard.copy()
    kernels.compiled()._rest_bounded(got, accel, rest.REST_PASSES, rest.REST_PLAIN, rest.REST_RELAX, rest.REST_EXACT,
                                     lo, np.full(40, np.inf), own, np.maximum(accel, np.abs(own)))
    np.testing.assert_allclose(got, summed, rtol=0, atol=1e-12)
