"""The splice of A's continuation into B's arrival (posturemap.synth.splice)."""

from __future__ import annotations

import contextlib
from types import SimpleNamespace

import numpy as np
import pytest

from posturemap.core import quat
from posturemap.synth.splice import SPLICE_WIDTH, splice, splice_blend, splice_weights
from posturemap.synth.trajectory import rotate_about_up

UP = 1


@pytest.mark.parametrize("length", [5, 20, 45])
def test_splice_weights_run_from_a_to_b_and_alpha_moves_the_blend(length):
    w = {alpha: splice_weights(length, alpha) for alpha in (0.0, 0.25, 0.5, 0.75, 1.0)}
    for alpha, x in w.items():
        assert np.all(np.diff(x) >= 0) and np.all((0 <= x) & (x <= 1))
    # alpha 0.5: the blend sits in the middle, symmetric about it.
    np.testing.assert_allclose(w[0.5], 1 - w[0.5][::-1], atol=1e-12)
    # A larger alpha blends earlier: B's weight never smaller, somewhere larger.
    alphas = sorted(w)
    for lo, hi in zip(alphas, alphas[1:]):
        assert np.all(w[hi] >= w[lo] - 1e-12) and np.any(w[hi] > w[lo])
    # The blend is as wide as fits around its centre: the whole gap at alpha 0.5 (no frame holds 0
    # or 1), half of it at alpha 0 and 1 (frames outside hold 0 or 1).
    t = np.arange(1, length + 1) / (length + 1.0)
    assert splice_blend(0.5) == (0.5, SPLICE_WIDTH) == (0.5, 1.0)
    assert np.all((w[0.5] > 0) & (w[0.5] < 1))
    for alpha, centre in ((0.0, 0.75), (1.0, 0.25)):
        assert splice_blend(alpha) == (centre, 0.5)
        inside = np.abs(t - centre) < 0.25
        assert np.all(np.isin(w[alpha][~inside], (0.0, 1.0)))


def _result(rng, length, joints, start, velocity, turn_rate, dtheta, shift, contacts):
    t = np.arange(1, length + 1)[:, None]
    # Poses that move (5 degrees a frame at most about each axis) from a turn of at most 40
    # degrees: the two halves stay within a half turn of each other.
    rots = quat.exp(np.radians(20.0) * rng.uniform(-1, 1, (1, joints, 3))
                    + np.cumsum(np.radians(5.0) / len(t) * rng.uniform(-1, 1, (length, joints, 3)), axis=0))
    return SimpleNamespace(rots=rots * np.where(rng.random((length, joints, 1)) < 0.3, -1.0, 1.0),
                           gpos=start + t * velocity, heading=0.3 + turn_rate * t[:, 0],
                           dtheta=dtheta, shift=np.asarray(shift, dtype=float), contacts=contacts)


def test_splice_in_transition_mode_integrates_a_smooth_path_and_places_b_at_its_end():
    rng = np.random.default_rng(0)
    length, joints = 20, 5
    a_pos, a_heading = np.array([1.0, 90.0, 2.0]), 0.3
    v1, v2 = np.array([3.0, 0.0, 0.0]), np.array([0.0, 0.0, -2.0])
    on1 = np.zeros((length, 2), bool)
    on2 = np.ones((length, 2), bool)
    first = _result(rng, length, joints, a_pos, v1, 0.01, 0.0, [0, 0, 0], on1)
    second = _result(rng, length, joints, a_pos, v2, -0.02, 0.7, [5.0, 0.0, -3.0], on2)
    b_pos = np.array([40.0, 90.0, 7.0])
    w = splice_weights(length, 0.5)
    rots, gpos, heading, dtheta, shift, contacts = splice(first, second, w, a_pos, a_heading, b_pos, UP)
    # Poses: SLERP by the weight, frame by frame (the same rotations; signs kept continuous).
    assert quat.angle_between(rots, quat.slerp(first.rots, second.rots, w[:, None])).max() < 1e-7
    assert np.all(np.sum(rots[1:] * rots[:-1], axis=-1)[w[1:] >= 1.0] >= 0.0)
    # Path: the turning rate is the blend of the two; the velocity the blend of the two, each
    # in its own heading's frame, turned to the path's heading: it starts as A's continuation
    # and ends as B's arrival, with no jump anywhere.
    np.testing.assert_allclose(np.diff(np.concatenate([[a_heading], heading])), (1 - w) * 0.01 + w * -0.02,
                               atol=1e-12)
    vel = np.diff(np.concatenate([a_pos[None], gpos]), axis=0)
    expect = (1 - w)[:, None] * rotate_about_up(np.broadcast_to(v1, (length, 3)), heading - first.heading, UP) \
        + w[:, None] * rotate_about_up(np.broadcast_to(v2, (length, 3)), heading - second.heading, UP)
    np.testing.assert_allclose(np.delete(vel, UP, axis=1), np.delete(expect, UP, axis=1), atol=1e-12)
    # B lies relative to the path's end as `second` put it relative to its own end, turned by
    # the difference of the end headings.
    turn = heading[-1] - second.heading[-1]
    mine = rotate_about_up(b_pos, dtheta, UP) + shift - gpos[-1]
    theirs = rotate_about_up(b_pos, second.dtheta, UP) + second.shift - second.gpos[-1]
    np.testing.assert_allclose(mine, rotate_about_up(theirs, turn, UP), atol=1e-9)
    assert dtheta == pytest.approx(second.dtheta + turn)
    # Planted feet from the segment that dominates each frame.
    np.testing.assert_array_equal(contacts, np.where((w < 0.5)[:, None], on1, on2))


def test_splice_headings_stay_continuous_when_the_segments_drift_apart():
    # The second segment turns a whole circle over the gap while the first goes straight: the
    # blended heading must change by the blend of the two rates each frame, never by a jump.
    rng = np.random.default_rng(2)
    length = 20
    a_pos = np.zeros(3)
    on = np.zeros((length, 2), bool)
    first = _result(rng, length, 3, a_pos, np.array([2.0, 0, 0]), 0.0, 0.0, [0, 0, 0], on)
    second = _result(rng, length, 3, a_pos, np.array([2.0, 0, 0]), 2 * np.pi / length, 0.0, [0, 0, 0], on)
    w = splice_weights(length, 0.5)
    _, _, heading, _, _, _ = splice(first, second, w, a_pos, 0.3, np.zeros(3), UP)
    steps = np.diff(np.concatenate([[0.3], heading]))
    np.testing.assert_allclose(steps, w * 2 * np.pi / length, atol=1e-12)


@pytest.mark.parametrize("compiled", [True, False])
def test_the_spliced_path_goes_where_it_faces_and_arrives_at_b_as_placed(compiled):
    # Both halves start at A's root (as replays are aligned) and walk where they face (each
    # frame's step along its own heading), the first turning left, the second right, so the
    # blended heading ends some 20 degrees off the second's: the spliced path must walk where
    # its own heading faces too, and its last step must be B's arrival turned as B is placed.
    # Blending the two steps as they lay in the world, the body went sideways into B (LaFAN1,
    # a jump into a jog, 90 frames at 60 fps: the hips arrived at 6.7 cm a frame across B's
    # 7.6 forward, the knee's velocity turned some 120 degrees in one frame).
    from posturemap.core import kernels

    length, forward = 30, np.array([0.0, 0.0, 1.0])

    def walking(start, h0, rate, speed, dtheta):
        heading = h0 + rate * np.arange(1, length + 1)
        steps = rotate_about_up(np.broadcast_to(forward * speed, (length, 3)), heading, UP)
        return SimpleNamespace(rots=np.broadcast_to(np.array([1.0, 0, 0, 0]), (length, 2, 4)).copy(),
                               gpos=start + np.cumsum(steps, axis=0), heading=heading, dtheta=dtheta,
                               shift=np.array([3.0, 0.0, -4.0]), contacts=np.zeros((length, 2), bool))

    a_pos, a_heading = np.array([0.0, 90.0, 0.0]), 0.2
    first = walking(a_pos, a_heading, 0.02, 4.0, 0.0)
    second = walking(a_pos, a_heading, -0.03, 6.0, 0.4)
    w = splice_weights(length, 1.0)  # B's arrival alone over the last half
    assert w[-1] == 1.0
    with contextlib.nullcontext() if compiled else kernels.numpy_backend():
        _, gpos, heading, dtheta, shift, _ = splice(first, second, w, a_pos, a_heading, np.array([7.0, 90.0, 2.0]), UP)
    vel = np.diff(np.concatenate([a_pos[None], gpos]), axis=0)
    speed = (1 - w) * 4.0 + w * 6.0
    np.testing.assert_allclose(vel, rotate_about_up(forward * speed[:, None], heading, UP), atol=1e-9)
    turn = dtheta - second.dtheta  # B is placed turned by this from where `second` put it
    assert abs(turn) > 0.3
    np.testing.assert_allclose(vel[-1], rotate_about_up(second.gpos[-1] - second.gpos[-2], turn, UP), atol=1e-9)


def arc_blend(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The blend of tracks a and b (L, J, 4) by w (L,; rising from 0 to 1) on the arc that goes
    on from frame to frame, from its definition: a turned by the fraction w of a^-1 b, whose
    sign is the short arc's at the first frame with 0 < w < 1 and then follows on from frame to
    frame (its rotation angle grows past a half turn where the halves pass one)."""
    rel = quat.mul(quat.inv(a), b)
    out = np.where((w >= 1.0)[:, None, None], b, a)
    blend = np.flatnonzero((w > 0.0) & (w < 1.0))
    for k, t in enumerate(blend):
        if k == 0:
            rel[t] *= np.where(rel[t, :, :1] < 0.0, -1.0, 1.0)
        else:
            rel[t] *= np.where(np.sum(rel[t] * rel[blend[k - 1]], axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
        v = rel[t, :, 1:]
        s = np.linalg.norm(v, axis=-1, keepdims=True)
        half = np.arctan2(s, rel[t, :, :1])  # in [0, pi]: the whole angle up to a full turn
        axis = v / np.maximum(s, 1e-300)
        out[t] = quat.mul(a[t], np.concatenate([np.cos(w[t] * half), np.sin(w[t] * half) * axis], axis=-1))
    return out


@pytest.mark.parametrize("compiled", [False, True])
def test_splice_rotations_go_on_round_where_the_halves_pass_a_half_turn_apart(compiled):
    # Between a walk and a wave the two halves' arms passed through a half turn from each other
    # in the blend; the short arc flipped to the other side there and the arm turned 180
    # degrees in one frame. The blend goes on round on the arc it was on.
    from posturemap.core import kernels
    from posturemap.synth import retrieval_numba
    from posturemap.synth.splice import splice_rotations

    rng = np.random.default_rng(8)
    length, joints = 30, 4
    a = quat.exp(np.cumsum(rng.normal(scale=0.03, size=(length, joints, 3)), axis=0))
    axes = rng.normal(size=(joints, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angle = np.radians(np.linspace(150.0, 210.0, length))  # a half turn apart mid-gap
    b = quat.mul(a, quat.exp(angle[:, None, None] * axes[None]))
    b *= np.where(rng.random((length, joints, 1)) < 0.5, -1.0, 1.0)  # stored signs anyhow
    w = splice_weights(length, 0.5)
    if compiled:
        got = np.empty(a.shape)
        retrieval_numba.splice_rotations(a, b, w, got)
    else:
        with kernels.numpy_backend():
            got = splice_rotations(a, b, w)
    want = quat.mul(a, quat.exp(w[:, None, None] * angle[:, None, None] * axes[None]))
    np.testing.assert_allclose(np.abs(np.sum(got * want, axis=-1)), 1.0, atol=1e-9)
    steps = quat.angle_between(got[1:], got[:-1])
    assert steps.max() < np.radians(20.0)  # the blend's own pace, no jump
    # The short arc, frame by frame, turned the joints about 180 degrees in a frame there.
    short = quat.slerp(a, b, w[:, None])
    assert quat.angle_between(short[1:], short[:-1]).max() > np.radians(150.0)


@pytest.mark.parametrize("alpha", [0.0, 0.5, 1.0])
def test_compiled_splice_rotations_match_the_numpy_reference(alpha):
    from posturemap.core import kernels
    from posturemap.synth import retrieval_numba
    from posturemap.synth.splice import splice_rotations

    rng = np.random.default_rng(21)
    length, joints = 24, 6
    # Smooth motions whose quaternions flip hemisphere now and then (as stored rotations may).
    a = quat.exp(np.cumsum(rng.normal(scale=0.2, size=(length, joints, 3)), axis=0))
    b = quat.exp(np.cumsum(rng.normal(scale=0.2, size=(length, joints, 3)), axis=0))
    b *= np.where(rng.random((length, joints, 1)) < 0.3, -1.0, 1.0)
    nan = splice_weights(length, 0.5)
    nan[length // 2] = np.nan  # a weight that is no number: B's frame, as the compiled kernel has it
    for w in (splice_weights(length, alpha), np.sort(np.clip(rng.normal(0.5, 0.6, length), 0.0, 1.0)), nan):
        got = np.empty(a.shape)
        retrieval_numba.splice_rotations(a, b, w, got)
        with kernels.numpy_backend():
            ref = splice_rotations(a, b, w)
        np.testing.assert_allclose(got, ref, atol=1e-12)
        if np.isnan(w).any():  # that frame is B's, and every number is one
            k = length // 2
            assert np.all(np.isfinite(got)) and quat.angle_between(got[k], b[k]).max() < 1e-6
            continue
        # The SLERP on the arc that goes on from frame to frame (some of these halves pass a half
        # turn apart, where the short arc would flip): a's frame turned by the fraction w of the
        # relative rotation a^-1 b, its sign kept from frame to frame (the short arc at the first).
        assert quat.angle_between(got, arc_blend(a, b, w)).max() < 1e-6
        # ... with B's frames following on in sign from the frame before (no flips to undo).
        tail = np.flatnonzero(w >= 1.0)
        tail = tail[tail > 0]
        assert np.all(np.sum(got[tail] * got[tail - 1], axis=-1) > 0.0)


def test_compiled_splice_matches_the_numpy_steps():
    # splice() runs one compiled call (rotations, path, B's place, contacts); the numpy steps are
    # the reference, also where the second half's headings lie whole turns from the first's.
    from posturemap.core import kernels
    from posturemap.synth import retrieval

    assert retrieval._compiled() is not None
    rng = np.random.default_rng(23)
    length, joints = 21, 5
    for alpha, up, turns in ((0.0, 1, 0), (0.5, 2, 1), (1.0, 1, -2), (0.3, 1, 0.5)):
        halves = []
        for h in range(2):
            halves.append(SimpleNamespace(
                rots=quat.exp(np.cumsum(rng.normal(scale=0.2, size=(length, joints, 3)), axis=0)),
                gpos=np.cumsum(rng.normal(size=(length, 3)), axis=0),
                heading=np.cumsum(rng.normal(scale=0.1, size=length)) + 2 * np.pi * turns * h,
                dtheta=float(rng.normal()), shift=rng.normal(size=3), contacts=rng.random((length, 2)) < 0.5))
        w = splice_weights(length, alpha)
        args = (halves[0], halves[1], w, rng.normal(size=3), float(rng.normal()), rng.normal(size=3), up)
        got = splice(*args)
        with kernels.numpy_backend():
            ref = splice(*args)
        np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-12)  # rotations
        for x, y in zip(got[1:5], ref[1:5]):  # path, headings, B's turn and shift
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(got[5], ref[5])  # planted feet of the dominant half
        assert np.any(got[5] != halves[0].contacts) and np.any(got[5] != halves[1].contacts)


def test_compiled_splice_path_matches_the_numpy_reference():
    from posturemap.core import kernels
    from posturemap.synth import retrieval_numba
    from posturemap.synth.splice import splice_path

    rng = np.random.default_rng(22)
    length = 19
    g1, g2 = (np.cumsum(rng.normal(size=(length, 3)), axis=0) for _ in range(2))
    h1, h2 = (np.cumsum(rng.normal(scale=0.1, size=length)) for _ in range(2))
    a_pos, a_heading = rng.normal(size=3), 0.3
    for w, up, turn2 in ((splice_weights(length, 0.2), 1, 0.0), (rng.random(length), 2, -2 * np.pi)):
        got = np.empty((length, 3)), np.empty(length)
        retrieval_numba.splice_path(g1, h1, g2, h2, turn2, w, a_pos, a_heading, up, *got)
        with kernels.numpy_backend():
            ref = splice_path(g1, h1, g2, h2, turn2, w, a_pos, a_heading, up)
        for x, y in zip(got, ref):
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-12)
        gpos, heading = got
        # Where one segment alone plays, the path moves as that segment does; the height is blended.
        only1 = np.flatnonzero(w == 0.0)
        only1 = only1[only1 > 0]
        np.testing.assert_allclose(np.diff(gpos, axis=0)[only1 - 1][:, [i for i in range(3) if i != up]],
                                   np.diff(g1, axis=0)[only1 - 1][:, [i for i in range(3) if i != up]], atol=1e-12)
        np.testing.assert_allclose(gpos[:, up], (1 - w) * g1[:, up] + w * g2[:, up], atol=1e-12)
        np.testing.assert_allclose(heading[0], a_heading + (1 - w[0]) * (h1[0] - a_heading)
                                   + w[0] * (h2[0] + turn2 - a_heading), atol=1e-12)
