"""Knees and elbows bend one way (posturemap.synth.hinges)."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from posturemap.core import quat
from posturemap.core.skeleton import fk
from posturemap.core import kernels
from posturemap.synth.hinges import REACH_FULL, REACH_NONE, bend_frames, find, leg_vectors, packed, signed_bends, unbend
from posturemap.synth import rest
from posturemap.synth.rest import at_rest

X = np.array([1.0, 0.0, 0.0])


def leg(flex: np.ndarray, twist: bool = False, rng=None):
    """Local rotations and translations (N, J, 3/4) of a leg hanging along -Y from a hip (below
    a pelvis, the root) with a small random turn: the knee bent ``flex`` radians about X
    (positive: the shin back under the hip, as a knee bends; negative: backward), with a twist
    joint inside the thigh (turned about the thigh's own axis) when ``twist``."""
    rng = np.random.default_rng(0) if rng is None else rng
    n = len(flex)
    if twist:  # pelvis > hip > twist > knee > ankle > toe
        parents = np.array([-1, 0, 1, 2, 3, 4])
        offsets = [[0.0, 0.0, 0.0], [0.1, -0.1, 0.0], [0.0, -0.5, 0.0], [0.0, -0.5, 0.0], [0.0, -1.0, 0.0],
                   [0.0, -0.1, 0.2]]
    else:  # pelvis > hip > knee > ankle > toe
        parents = np.array([-1, 0, 1, 2, 3])
        offsets = [[0.0, 0.0, 0.0], [0.1, -0.1, 0.0], [0.0, -1.0, 0.0], [0.0, -1.0, 0.0], [0.0, -0.1, 0.2]]
    j = len(parents)
    rots = np.tile(quat.identity(), (n, j, 1))
    rots[:, 1] = quat.exp(rng.normal(scale=0.2, size=(n, 3)))  # the hip (thigh) turned anyhow
    if twist:
        rots[:, 2] = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), rng.normal(scale=0.5, size=n))
        rots[:, 3] = quat.from_axis_angle(X, flex)
        chain = (1, 3, 4)
    else:
        rots[:, 2] = quat.from_axis_angle(X, flex)
        chain = (1, 2, 3)
    pos = np.broadcast_to(np.array(offsets), (n, j, 3)).copy()
    return parents, chain, rots, pos


def two_legs(flex_l: np.ndarray, flex_r: np.ndarray, twist: bool = False, rng=None):
    """:func:`leg` twice under one pelvis (the right hip to the other side): ``parents``, the two
    chains, rotations and translations."""
    rng = np.random.default_rng(0) if rng is None else rng
    parents, chain, rots, pos = leg(flex_l, twist, rng)
    p2, c2, r2, q2 = leg(flex_r, twist, rng)
    j = len(parents)
    parents = np.concatenate([parents, np.where(p2[1:] == 0, 0, p2[1:] + j - 1)])
    rots, pos = np.concatenate([rots, r2[:, 1:]], axis=1), np.concatenate([pos, q2[:, 1:]], axis=1)
    pos[:, j, 0] *= -1.0
    return parents, [chain, tuple(c + j - 1 for c in c2)], rots, pos


def bends_of(parents, chain, rots, pos):
    """The knee's bend (radians, unsigned) from the joints' global positions."""
    _, gp = fk(parents, rots, pos)
    t, s = gp[:, chain[1]] - gp[:, chain[0]], gp[:, chain[2]] - gp[:, chain[1]]
    return np.arccos(np.clip(np.sum(t * s, -1) / np.linalg.norm(t, axis=-1) / np.linalg.norm(s, axis=-1), -1, 1))


@pytest.mark.parametrize("twist", [False, True])
def test_hinges_tell_forward_from_backward_and_how_far_back_the_library_goes(twist):
    rng = np.random.default_rng(1)
    flex = np.radians(rng.uniform(0.0, 90.0, 400))
    flex[:3] = np.radians([-2.0, -1.0, -0.5])  # the library's few knees a hair past straight
    parents, chain, rots, pos = leg(flex, twist, rng)
    (path, hinge, least, most), = find(parents, [chain], rots, pos[0])
    t, s = leg_vectors(rots, pos, path)
    signed = signed_bends(t, s, hinge)
    np.testing.assert_allclose(np.abs(signed), bends_of(parents, chain, rots, pos), atol=1e-9)
    np.testing.assert_allclose(signed, flex, atol=1e-9)  # forward positive, backward negative
    assert least == pytest.approx(np.percentile(flex, 0.1))
    assert np.radians(-2.0) < least < np.radians(-0.5)
    assert most == pytest.approx(np.percentile(flex, 99.9))  # and how far forward
    assert np.radians(89.0) < most < np.radians(90.0)
    # A library whose knees never bend has no hinge to tell them apart: no bound.
    parents, chain, rots, pos = leg(np.zeros(50), twist, rng)
    assert find(parents, [chain], rots, pos[0]) == [None]


def library_knees(rng, twist: bool = False) -> list:
    """:func:`find` over a seeded library of 300 knees bent 0..90 degrees: the bound at straight."""
    parents, chain, lib_rots, lib_pos = leg(np.radians(rng.uniform(0.0, 90.0, 300)), twist, rng)
    return find(parents, [chain], lib_rots, lib_pos[0])


def knees_and_leg(seed: int, flex: np.ndarray, twist: bool = False):
    """:func:`library_knees` and a :func:`leg` bent ``flex`` (radians) per frame, from one
    seeded generator: ``(knees, parents, chain, rots, pos)``."""
    rng = np.random.default_rng(seed)
    knees = library_knees(rng, twist)
    return (knees,) + leg(flex, twist, rng)


def backend(compiled: bool):
    """The compiled kernels (from here on in this process) or numpy's, for the block."""
    if compiled:
        kernels.compiled()
        return contextlib.nullcontext()
    return kernels.numpy_backend()


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("twist", [False, True])
def test_unbend_turns_a_knee_bent_backward_forward_in_its_plane_onto_the_bound(twist, compiled):
    flex = np.radians([30.0, 5.0, 0.0, -3.0, -40.0, -57.0, -10.0, 20.0])
    knees, parents, chain, rots, pos = knees_and_leg(2, flex, twist)
    (path, hinge, least, _), = knees
    assert least == 0.0
    before = rots.copy()
    _, gp0 = fk(parents, rots, pos)
    with backend(compiled):
        assert unbend(packed(knees, parents), rots, pos) == 4  # the four bent backward
    back = flex < 0.0
    np.testing.assert_array_equal(rots[~back], before[~back])  # the others exactly as they were
    hip, shin, ankle = chain
    changed = np.flatnonzero(np.any(rots != before, axis=-1).any(axis=0))
    assert list(changed) == [hip, shin]  # the shin turns, and the hip (a twist joint keeps its own)
    t, s = leg_vectors(rots, pos, path)
    np.testing.assert_allclose(signed_bends(t, s, hinge)[back], 0.0, atol=1e-7)  # straight: the bound
    _, gp = fk(parents, rots, pos)
    # In its own plane: the knee and the ankle stay in the plane of hip, knee and the old ankle.
    at, knee = gp0[back, hip], gp0[back, shin]
    normal = np.cross(gp0[back, ankle] - at, knee - at)
    for j in (shin, ankle):
        np.testing.assert_allclose(np.sum((gp[back, j] - at) * normal, axis=-1), 0.0, atol=1e-9)
    # The straight leg points where the bent-back one reached: the ankle on its old line from the
    # hip (turning the shin alone raised it: a spline's toe 46 cm up, then down in a frame).
    line = (gp0[back, ankle] - at) / np.linalg.norm(gp0[back, ankle] - at, axis=-1, keepdims=True)
    reach = gp[back, ankle] - at
    np.testing.assert_allclose(reach, line * np.sum(reach * line, axis=-1, keepdims=True), atol=1e-9)
    assert np.all(np.linalg.norm(gp[back, shin] - knee, axis=-1) > 1e-3)  # the thigh turned


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("twist", [False, True])
def test_unbend_brings_a_knee_swinging_backward_to_rest_on_the_bound_within_the_acceleration(twist, compiled):
    # A knee swinging back through straight at a steady 2 degrees a frame, 24 degrees past the
    # bound, and forward again. Turned onto the bound from the frame it passes it, its bend
    # stops dead and sets off again (the rate jumps by 2 degrees a frame: a CMU-rig walk at
    # 120 fps kinked a toe's path so, 3.35x the clips' own largest acceleration). Bounded, the
    # turn fades in before the bound and out after it: the knee slows onto the bound, rests on
    # it through the reversal, and sets off again within the bound on its acceleration. (The
    # turn's own acceleration bounded instead, the knee bounced off the bound at the reversal,
    # 3.7 degrees a frame squared, and never rested on it: a cold review.)
    accel = 0.005  # radians per frame squared: 7 frames to stop from 2 degrees a frame
    flex = np.radians(np.r_[np.linspace(40.0, -24.0, 33), np.linspace(-22.0, 40.0, 32)])
    knees, parents, chain, rots, pos = knees_and_leg(3, flex, twist)
    (path, hinge, least, _), = knees
    assert least == 0.0
    limits = packed(knees, parents)
    before, hard = rots.copy(), rots.copy()
    with backend(compiled):
        assert unbend(limits, hard, pos) == np.count_nonzero(flex < 0.0)
        n = unbend(limits, rots, pos, accel)
    bends = np.unwrap(signed_bends(*leg_vectors(rots, pos, path), hinge))
    hard_bends = signed_bends(*leg_vectors(hard, pos, path), hinge)
    assert bends.min() >= least - 1e-9  # never past the bound
    assert np.abs(np.diff(hard_bends, 2)).max() > 5 * accel  # the jump in rate it mends
    assert np.abs(np.diff(bends, 2)).max() <= accel * (1 + 1e-3)
    np.testing.assert_allclose(bends[flex < np.radians(-6.0)], 0.0, atol=1e-9)  # at rest on the bound
    # It turns knees within the bound too (the fade), and only forward, near the bound: the
    # first and last frames, bent 20 degrees and more, are left exactly as they were.
    assert n > np.count_nonzero(flex < 0.0)
    assert (bends - flex).min() > -1e-9
    turned = bends - flex > 1e-9
    np.testing.assert_array_equal(rots[flex > np.radians(20.0)], before[flex > np.radians(20.0)])
    assert turned[(flex > 0.0) & (flex < np.radians(5.0))].all()
    # Turned forward, the leg still reaches along the motion's line from the hip (the hip turned
    # with it), into the fade too.
    _, gp0 = fk(parents, before, pos)
    _, gp = fk(parents, rots, pos)
    hip, _, ankle = chain
    line = gp0[turned, ankle] - gp0[turned, hip]
    line /= np.linalg.norm(line, axis=-1, keepdims=True)
    reach = gp[turned, ankle] - gp[turned, hip]
    np.testing.assert_allclose(reach, line * np.sum(reach * line, axis=-1, keepdims=True), atol=1e-9)


@pytest.mark.parametrize("compiled", [False, True])
def test_unbend_holds_a_knee_on_the_bound_through_a_quick_reversal_past_it(compiled):
    # A knee swinging back past straight at 20 degrees a frame and straight back (a V, 30
    # degrees past the bound at its tip). Where the knee could follow the motion's own
    # acceleration past the bound too, the V's tip let it touch the bound and bounce off it (a
    # second cold review). Past the bound the bound is accel: wherever the motion is past it,
    # the knee accelerates within accel and turns back without a bounce. At 20 degrees a frame
    # it needs 50 degrees to stop within 4 a frame squared, so it turns back short of the
    # bound: smooth, not on it.
    accel = np.radians(4.0)
    flex = np.radians(np.r_[np.full(3, 60.0), np.arange(60.0, -30.1, -20.0), np.arange(-10.0, 60.1, 20.0),
                            np.full(3, 60.0)])
    knees, parents, chain, rots, pos = knees_and_leg(4, flex)
    (path, hinge, least, _), = knees
    hard = rots.copy()
    with backend(compiled):
        unbend(packed(knees, parents), hard, pos)
        unbend(packed(knees, parents), rots, pos, accel)
    bends = signed_bends(*leg_vectors(rots, pos, path), hinge)
    hard_bends = signed_bends(*leg_vectors(hard, pos, path), hinge)
    past = flex < least
    near = past[:-2] | past[1:-1] | past[2:]  # the second differences that touch a frame past the bound
    assert bends.min() >= least - 1e-9
    assert np.abs(np.diff(hard_bends, 2))[near].max() > 4 * accel
    assert np.abs(np.diff(bends, 2))[near].max() <= accel * 1.002
    assert np.all(np.diff(bends[:np.argmin(bends) + 1]) <= 1e-9)  # down, then up: no bounce
    assert np.all(np.diff(bends[np.argmin(bends):]) >= -1e-9)


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("twist", [False, True])
def test_unbend_reads_a_knee_folded_forward_past_a_half_turn_as_forward(twist, compiled):
    # An interpolated knee folding on past 180 degrees reads -179 frame by frame (the bend's
    # angle wraps): not a knee bent backward. Snapped onto the backward bound, it turned 176
    # degrees in a frame and back (a Bandai in-betweening, walk into dash, the default method).
    # Read over the frames, it goes on forward: folded further than the library's knees, it is
    # turned back onto their forward bound, frame after frame alike; a knee bent backward after
    # it is still turned onto the backward one, the knees within both left.
    knees, parents, chain, rots, pos = knees_and_leg(
        12, np.radians([160.0, 172.0, 178.0, 183.0, 190.0, 184.0, 176.0, 150.0, 60.0, 5.0, -20.0]), twist)
    (path, hinge, least, most), = knees
    t, s = leg_vectors(rots, pos, path)
    assert np.all(signed_bends(t, s, hinge)[3:6] < np.radians(-160.0))  # frame by frame: "backward"
    before = rots.copy()
    with backend(compiled):
        assert unbend(packed(knees, parents), rots, pos) == 9  # the eight folded, the last
    np.testing.assert_array_equal(rots[8:10], before[8:10])
    t, s = leg_vectors(rots, pos, path)
    bends = signed_bends(t, s, hinge)
    np.testing.assert_allclose(bends[:8], most, atol=1e-7)
    assert bends[-1] == pytest.approx(least, abs=1e-7)
    # The folded knees turn in their own plane, their hips as they were (an ankle near the hip
    # has no steady line from it to keep); only the shin's rotation changes.
    hip, shin, ankle = chain
    changed = np.flatnonzero(np.any(rots[:8] != before[:8], axis=-1).any(axis=0))
    assert list(changed) == [shin]
    _, gp0 = fk(parents, before, pos)
    _, gp = fk(parents, rots, pos)
    normal = np.cross(gp0[:8, ankle] - gp0[:8, hip], gp0[:8, shin] - gp0[:8, hip])
    np.testing.assert_allclose(np.sum((gp[:8, ankle] - gp0[:8, hip]) * normal, axis=-1), 0.0, atol=1e-9)


@pytest.mark.parametrize("compiled", [False, True])
def test_unbend_holds_a_knee_to_the_librarys_own_bound_and_skips_legs_without_a_hinge(compiled):
    rng = np.random.default_rng(3)
    flex = np.radians(rng.uniform(0.0, 80.0, 1000))
    flex[:5] = np.radians(-4.0)  # the library's knees go 4 degrees past straight at most
    parents, chain, lib_rots, lib_pos = leg(flex, rng=rng)
    knees = find(parents, [chain], lib_rots, lib_pos[0])
    least = knees[0][2]
    assert least == pytest.approx(np.radians(-4.0))
    parents, chain, rots, pos = leg(np.radians([-3.0, -20.0]), rng=rng)
    with backend(compiled):
        assert unbend(packed(knees, parents), rots, pos) == 1
    t, s = leg_vectors(rots, pos, knees[0][0])
    np.testing.assert_allclose(signed_bends(t, s, knees[0][1]), np.radians([-3.0, -4.0]), atol=1e-7)
    before = rots.copy()
    with backend(compiled):
        assert unbend(packed([None], parents), rots, pos) == 0
    np.testing.assert_array_equal(rots, before)


@pytest.mark.parametrize("compiled", [False, True])
def test_unbend_leaves_a_knee_bent_sideways_as_its_plane_turns_through_the_hinges_normal(compiled):
    # A blend bent a knee 11 degrees sideways, its plane turning past the hinge's normal and
    # back: signed by its plane's normal alone it read -11 degrees in two frames and was
    # straightened there (a 9-10 degree kick each way). About the hinge it reads about as much
    # as it bends backward, and the knee turns that much at most, frame after frame alike.
    rng = np.random.default_rng(5)
    knees = library_knees(rng)
    (path, hinge, least, _), = knees
    assert least == 0.0
    turn = np.radians(np.linspace(80.0, 100.0, 11))  # the plane's normal from the hinge (X) toward -Z and past
    axis = np.stack([np.cos(turn), np.zeros_like(turn), -np.sin(turn)], axis=-1)
    parents, chain, rots, pos = leg(np.zeros(len(turn)), rng=rng)
    rots[:, chain[1]] = quat.from_axis_angle(axis, np.full(len(turn), np.radians(11.0)))
    t, s = leg_vectors(rots, pos, path)
    bends = signed_bends(t, s, hinge)
    assert (bends < 0).sum() == 5 and np.abs(bends).max() < np.radians(2.0)
    before = rots.copy()
    _, gp0 = fk(parents, rots, pos)
    with backend(compiled):
        assert unbend(packed(knees, parents), rots, pos) == 5
    turned = np.degrees(quat.angle_between(rots[:, chain[1]], before[:, chain[1]]))
    np.testing.assert_allclose(turned, np.degrees(np.maximum(-bends, 0.0)), atol=1e-6)
    t, s = leg_vectors(rots, pos, path)
    np.testing.assert_allclose(np.minimum(signed_bends(t, s, hinge), 0.0), 0.0, atol=1e-9)
    assert bends_of(parents, chain, rots, pos).min() > np.radians(10.0)  # still bent sideways
    _, gp = fk(parents, rots, pos)
    reach0, reach = gp0[:, chain[2]] - gp0[:, chain[0]], gp[:, chain[2]] - gp[:, chain[0]]
    np.testing.assert_allclose(np.cross(reach, reach0), 0.0, atol=1e-9)  # the ankle on its line
    assert np.all(np.sum(reach * reach0, axis=-1) > 0.0)


@pytest.mark.parametrize("compiled", [False, True])
def test_unbend_leaves_the_hip_of_a_leg_folded_back_onto_itself(compiled):
    # The ankle at the hip has no line from it to keep: the knee straightens, the hip stays; a
    # leg folded back nearly so turns its hip part of the way, and as the fold passes a half
    # turn the hip does not swing round with the ankle's line (a spline's thigh turned 157
    # degrees in a frame so).
    rng = np.random.default_rng(6)
    knees = library_knees(rng)
    # The leg's thigh and shin are 1 long each: the ankle 2 cos(bend / 2) from the hip.
    full, none = (2.0 * np.degrees(np.arccos(r)) for r in (REACH_FULL, REACH_NONE))  # 120, 151 degrees
    flex = -np.radians([180.0 - 1e-6, 30.0, full - 5.0, 0.5 * (full + none), none + 3.0, 170.0, 178.0, 182.0,
                        190.0])
    parents, chain, rots, pos = leg(flex, rng=rng)
    rots[:, 1] = rots[0, 1]  # one thigh for all (the knee alone moves from frame to frame)
    before = rots.copy()
    with backend(compiled):
        assert unbend(packed(knees, parents), rots, pos) == len(flex)
    assert np.all(np.isfinite(rots))
    hip = chain[0]
    turn = quat.angle_between(rots[:, hip], before[:, hip])
    still = [0, 4, 5, 6, 7, 8]  # folded (past 151 degrees): the hip as it was
    np.testing.assert_array_equal(rots[still, hip], before[still, hip])
    assert np.all(turn[1:4] > np.radians(5.0))  # bent back 30 .. 136 degrees: the hip turns
    t, s = leg_vectors(rots, pos, knees[0][0])
    np.testing.assert_allclose(signed_bends(t, s, knees[0][1]), 0.0, atol=1e-7)
    # The whole way onto the ankle's line up to 120 degrees back, a share of it between.
    _, gp0 = fk(parents, before, pos)
    _, gp = fk(parents, rots, pos)
    line = gp0[:, chain[2]] - gp0[:, chain[0]]
    leg_dir = gp[:, chain[2]] - gp[:, chain[0]]
    off = np.degrees(np.arccos(np.clip(np.sum(line * leg_dir, -1) / np.linalg.norm(line, axis=-1)
                                       / np.linalg.norm(leg_dir, axis=-1), -1.0, 1.0)))
    assert np.all(off[1:3] < 1e-4) and off[3] > 5.0


def hinged_legs_and_frames(seed: int, twist: bool):
    """Two legs' hinges found in a seeded library of knees bent -3..90 degrees, packed with a
    leg without a hinge between them and the second leg's bounds at -10 and 40 degrees, and 40 seeded
    frames of knees bent -60..60 degrees with translations that vary per frame: (chains,
    limits, rots, pos)."""
    rng = np.random.default_rng(seed)
    parents, chains, lib_rots, lib_pos = two_legs(np.radians(rng.uniform(-3.0, 90.0, 500)),
                                                  np.radians(rng.uniform(-3.0, 90.0, 500)), twist, rng)
    left, right = find(parents, chains, lib_rots, lib_pos[0])
    limits = packed([left, None, (right[0], right[1], np.radians(-10.0), np.radians(40.0))], parents)
    _, _, rots, pos = two_legs(np.radians(rng.uniform(-60.0, 60.0, 40)), np.radians(rng.uniform(-60.0, 60.0, 40)),
                               twist, rng)
    pos += rng.normal(scale=0.01, size=pos.shape)
    return chains, limits, rots, pos


@pytest.mark.parametrize("twist", [False, True])
def test_bend_frames_is_the_same_compiled(twist):
    # Each frame's knee bends (forward and backward, a leg without a hinge left out by packed):
    # the compiled kernel reads what the numpy reference reads, per-frame translations or one set.
    _, limits, rots, pos = hinged_legs_and_frames(5, twist)
    legs = limits[:3]
    kernels.compiled()
    for offsets in (pos, pos[0]):
        with kernels.numpy_backend():
            want = bend_frames(legs, rots, offsets)
        got = bend_frames(legs, rots, offsets)
        assert want.shape == (40, 2) and want.min() < 0.0 < want.max()
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert bend_frames(legs, rots[:0], pos[:0]).shape == (0, 2)


@pytest.mark.parametrize("accel", [None, 0.05, 0.5])
@pytest.mark.parametrize("twist", [False, True])
def test_unbend_is_the_same_compiled(twist, accel):
    # Two legs (the second with another bound, a leg without a hinge between them): the compiled
    # kernel turns the same knees and hips by the same rotations as the numpy reference, the
    # turns bounded in acceleration or not.
    chains, limits, rots, pos = hinged_legs_and_frames(4, twist)
    assert limits[1][:, 3].tolist() == [chains[0][0], chains[1][0]]  # each hip its own leg's
    outs = []
    for compiled in (False, True):
        r = rots.copy()
        if compiled:
            n = kernels.compiled().unbend_limbs(r, pos, *limits, REACH_NONE, REACH_FULL,
                                                np.inf if accel is None else accel, rest.REST_PASSES,
                                                rest.REST_PLAIN, rest.REST_RELAX, rest.REST_EXACT)
        else:
            with kernels.numpy_backend():
                n = unbend(limits, r, pos, accel)
        outs.append((n, r))
    assert outs[0][0] == outs[1][0] > 0
    for hip in (chains[0][0], chains[1][0]):  # the hips turned
        assert not np.array_equal(outs[0][1][:, hip], rots[:, hip])
    np.testing.assert_allclose(outs[1][1], outs[0][1], rtol=0, atol=1e-12)


def test_a_share_of_the_hips_turn_is_the_same_compiled():
    # unbend turns a hip part of the way for a knee folded back past 120 degrees: the compiled
    # share of a turn is quat.exp(share * quat.log(q)), either sign of q, tiny turns too.
    rng = np.random.default_rng(10)
    q = quat.exp(rng.normal(scale=1.2, size=(60, 3)))
    q[:10] = quat.exp(rng.normal(scale=1e-9, size=(10, 3)))
    q *= np.where(rng.random((60, 1)) < 0.5, -1.0, 1.0)
    share = rng.uniform(0.0, 1.0, 60)
    want = quat.exp(share[:, None] * quat.log(q))
    got = np.array([kernels.compiled()._turn_share(*row, s) for row, s in zip(q.tolist(), share.tolist())])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert np.all(quat.angle_between(got, np.broadcast_to(quat.identity(), got.shape))[10:]
                  < quat.angle_between(q, np.broadcast_to(quat.identity(), q.shape))[10:] + 1e-12)


@pytest.mark.parametrize("compiled", [False, True])
def test_unbend_leaves_a_frame_it_cannot_measure(compiled):
    # A NaN in a frame's leg (a translation) or in the bound: nothing turned there, as numpy's
    # `bends < least` leaves it; no NaN written into the hip.
    knees, parents, chain, rots, pos = knees_and_leg(9, np.radians([-20.0, -30.0]))
    pos[0, chain[2], 1] = np.nan
    before = rots.copy()
    with backend(compiled):
        assert unbend(packed(knees, parents), rots, pos) == 1
    np.testing.assert_array_equal(rots[0], before[0])
    assert np.all(np.isfinite(rots))
    path, hinge, *_ = knees[0]
    limits = packed([(path, hinge, np.nan, np.nan)], parents)
    with backend(compiled):
        assert unbend(limits, rots, pos) == 0
    assert np.all(np.isfinite(rots))


def test_the_shortest_arc_is_the_same_compiled():
    # The compiled unbend's turn of the hip (numba_kernels._between) is quat.between's, for
    # vectors apart, near, the same and opposite (either perpendicular axis).
    rng = np.random.default_rng(7)
    a = rng.normal(size=(40, 3))
    b = rng.normal(size=(40, 3))
    b[:10] = a[:10] + rng.normal(scale=1e-3, size=(10, 3))
    b[10:15] = a[10:15]
    b[15:20] = -a[15:20]
    a[20], b[20] = [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]  # opposite along X: the other axis
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b /= np.linalg.norm(b, axis=-1, keepdims=True)
    want = quat.between(a, b)
    arc = kernels.compiled()._between
    got = np.array([arc(*x, *y) for x, y in zip(a, b)])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(quat.mul_vec(got, a), b, atol=1e-9)


@pytest.mark.parametrize("compiled", [False, True])
def test_unbend_leaves_a_hip_that_would_move_more_than_its_leg(compiled):
    # A rig without thigh joints: both shins hang from the pelvis, the root, which is each leg's
    # "thigh". Turning it to keep one ankle's line would turn the whole body: the knees
    # straighten, the pelvis stays.
    rng = np.random.default_rng(8)
    parents = np.array([-1, 0, 1, 0, 3])  # pelvis > knee_L > ankle_L, pelvis > knee_R > ankle_R
    offsets = np.array([[0.0, 1.0, 0.0], [0.1, -1.0, 0.0], [0.0, -1.0, 0.0], [-0.1, -1.0, 0.0], [0.0, -1.0, 0.0]])
    chains = [(0, 1, 2), (0, 3, 4)]

    def frames(flex_l, flex_r):
        rots = np.tile(quat.identity(), (len(flex_l), len(parents), 1))
        rots[:, 0] = quat.exp(rng.normal(scale=0.2, size=(len(flex_l), 3)))
        rots[:, 1], rots[:, 3] = quat.from_axis_angle(X, flex_l), quat.from_axis_angle(X, flex_r)
        return rots, np.broadcast_to(offsets, rots.shape[:2] + (3,)).copy()

    lib_rots, _ = frames(np.radians(rng.uniform(0.0, 90.0, 300)), np.radians(rng.uniform(0.0, 90.0, 300)))
    knees = find(parents, chains, lib_rots, offsets)
    limits = packed(knees, parents)
    assert limits[1][:, 3].tolist() == [-1, -1]
    rots, pos = frames(np.radians([-20.0, 10.0, -40.0]), np.radians([5.0, -30.0, -10.0]))
    before = rots.copy()
    with backend(compiled):
        assert unbend(limits, rots, pos) == 4
    np.testing.assert_array_equal(rots[:, 0], before[:, 0])  # the pelvis as it was
    for (path, hinge, *_), flex_back in zip(knees, ([True, False, True], [False, True, True])):
        t, s = leg_vectors(rots, pos, path)
        bends = signed_bends(t, s, hinge)
        np.testing.assert_allclose(bends[flex_back], 0.0, atol=1e-7)


def test_packed_turns_only_a_hip_that_moves_its_own_leg():
    rng = np.random.default_rng(10)

    def hips(parents, chains, rots, pos):
        return packed(find(parents, chains, rots, pos[0]), parents)[1][:, 3].tolist()

    flex = np.radians(rng.uniform(0.0, 90.0, 100))
    # A hip joint of its own below the pelvis, and a leaf beside the leg (a twist helper): turned.
    parents, chain, rots, pos = leg(flex, rng=rng)
    assert hips(parents, [chain], rots, pos) == [chain[0]]
    parents = np.append(parents, chain[0])
    rots = np.concatenate([rots, rots[:, :1] * 0 + quat.identity()], axis=1)
    pos = np.concatenate([pos, pos[:, -1:]], axis=1)
    assert hips(parents, [chain], rots, pos) == [chain[0]]
    # The hip the skeleton's root (nothing beside the leg): not turned.
    parents, chain, rots, pos = leg(flex, rng=rng)
    assert hips(parents[1:] - 1, [tuple(c - 1 for c in chain)], rots[:, 1:], pos[:, 1:]) == [-1]
    # Two shins under a pelvis that is not the root, only one knee ever bent (the other leg has
    # no hinge): the pelvis carries the other leg, not turned.
    parents = np.array([-1, 0, 1, 2, 1, 4])  # root > pelvis > knee_L > ankle_L, pelvis > knee_R > ankle_R
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.1, -1.0, 0.0], [0.0, -1.0, 0.0], [0.0, -1.0, 0.0],
                        [0.0, -1.0, 0.0]])  # the right leg straight, its knee never bent
    rots = np.tile(quat.identity(), (len(flex), 6, 1))
    rots[:, 2] = quat.from_axis_angle(X, flex)
    knees = find(parents, [(1, 2, 3), (1, 4, 5)], rots, offsets)
    assert knees[1] is None
    assert packed(knees, parents)[1][:, 3].tolist() == [-1]
