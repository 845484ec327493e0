"""Metrics against hand-computed cases (and LaFAN1's own formulas where they apply)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from posturemap.evaluate import metrics
from posturemap.core import quat

S2 = math.sqrt(0.5)


def test_align_signs_flips_only_the_other_hemisphere_and_leaves_input():
    q = np.array([[-1.0, 0, 0, 0], [S2, 0, 0, S2]])
    ref = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    before = q.copy()
    out = metrics.align_signs(q, ref)
    np.testing.assert_array_equal(out, [[1.0, 0, 0, 0], [S2, 0, 0, S2]])
    np.testing.assert_array_equal(q, before)


def test_l2q_hand_case():
    # One window, two frames, two joints; truth is the identity everywhere.
    true = np.zeros((1, 2, 2, 4))
    true[..., 0] = 1.0
    pred = true.copy()
    pred[0, 0, 0] = [-1.0, 0, 0, 0]      # same rotation, other sign: costs nothing
    pred[0, 0, 1] = [S2, 0, 0, S2]       # 90 degrees about z: |q - 1|^2 = 2 - sqrt(2)
    expected = math.sqrt(2 - math.sqrt(2)) / 2  # frame 0 and frame 1 (0) averaged
    assert metrics.l2q(pred, true) == pytest.approx(expected, abs=1e-12)
    assert metrics.l2q(true, true) == 0.0


def test_normalize_windows_centres_and_turns_to_the_reference_facing():
    # Root (joint 0) at x = 10 then 20 (height 5); it faces +90 degrees about y at frame 0.
    gpos = np.zeros((1, 2, 2, 3))
    gpos[0, :, 0] = [[10.0, 5.0, 0.0], [20.0, 5.0, 0.0]]
    gpos[0, :, 1] = [[10.0, 5.0, 1.0], [20.0, 5.0, 1.0]]
    grot = np.zeros((1, 2, 2, 4))
    grot[..., 0] = 1.0
    grot[0, 0, 0] = [S2, 0, S2, 0]
    pos, rot = metrics.normalize_windows(gpos, grot, root=0, up=1, frame=0)
    # Mean horizontal root position (15, _, 0) to the origin, then -90 degrees about y:
    # (x, z) -> (-z, x): (-5, 0) -> (0, -5); (-5, 1) -> (-1, -5).
    np.testing.assert_allclose(pos[0, 0, 0], [0.0, 5.0, -5.0], atol=1e-12)
    np.testing.assert_allclose(pos[0, 1, 0], [0.0, 5.0, 5.0], atol=1e-12)
    np.testing.assert_allclose(pos[0, 0, 1], [-1.0, 5.0, -5.0], atol=1e-12)
    np.testing.assert_allclose(rot[0, 0, 0], [1.0, 0, 0, 0], atol=1e-12)
    # A prediction put in the truth's frame moves exactly as the truth does.
    shifted = gpos + np.array([0.0, 0.0, 3.0])
    p2, _ = metrics.normalize_windows(shifted, grot, 0, 1, 0, ref_pos=gpos, ref_rot=grot)
    np.testing.assert_allclose(p2 - pos, np.broadcast_to([-3.0, 0.0, 0.0], pos.shape), atol=1e-12)


def test_position_stats_and_l2p_hand_case():
    x = np.zeros((1, 2, 1, 3))
    x[0, 1, 0] = [2.0, 4.0, 6.0]
    mean, std = metrics.position_stats(x)
    np.testing.assert_allclose(mean, [[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(std, [[1.0, 2.0, 3.0]])
    # Two joints; joint 1's y never varies in training (std 0) and never differs.
    std = np.array([[2.0, 1.0, 1.0], [1.0, 0.0, 1.0]])
    true = np.zeros((1, 2, 2, 3))
    pred = true.copy()
    pred[0, 0, 0] = [2.0, 0.0, 0.0]  # (2 / 2) -> 1
    pred[0, 1, 1] = [0.0, 0.0, 3.0]  # 3 / 1 -> 3
    assert metrics.l2p(pred, true, std) == pytest.approx(2.0)


def test_mpjpe_hand_case():
    true = np.zeros((2, 1, 3))
    pred = np.array([[[3.0, 4.0, 0.0]], [[0.0, 0.0, 0.0]]])
    assert metrics.mpjpe(pred, true) == pytest.approx(2.5)


def _lafan1_fast_npss(gt_seq, pred_seq):
    """LaFAN1 benchmarks.fast_npss, restated (features with nonzero power only)."""
    gt_power = np.square(np.real(np.fft.fft(gt_seq, axis=1)))
    pred_power = np.square(np.real(np.fft.fft(pred_seq, axis=1)))
    gt_total, pred_total = gt_power.sum(axis=1), pred_power.sum(axis=1)
    cdf_gt = np.cumsum(gt_power / gt_total[:, None, :], axis=1)
    cdf_pred = np.cumsum(pred_power / pred_total[:, None, :], axis=1)
    emd = np.linalg.norm(cdf_pred - cdf_gt, ord=1, axis=1)
    return np.average(emd, weights=gt_total)


def test_npss_hand_case_and_zero_power_feature():
    # true [1, 0]: FFT [1, 1], power [1, 1] -> cdf [.5, 1]; pred [1, 1]: FFT [2, 0] -> cdf [1, 1].
    true = np.array([[[1.0, 0.0], [0.0, 0.0]]])  # (N=1, T=2, D=2); feature 1 has no power
    pred = np.array([[[1.0, 5.0], [1.0, -5.0]]])
    assert metrics.npss(pred, true) == pytest.approx(0.5)
    assert metrics.npss(true, true) == 0.0


def test_npss_matches_lafan1_formula():
    rng = np.random.default_rng(3)
    true = rng.normal(size=(4, 15, 6))
    pred = true + 0.3 * rng.normal(size=true.shape)
    assert metrics.npss(pred, true) == pytest.approx(_lafan1_fast_npss(true, pred), rel=1e-12)


def test_foot_contacts_and_skate_hand_case():
    fps, up = 10.0, 1
    # One foot joint, 5 frames: x steps 0.5, 0.5, 10 cm; last frame lifted 5 cm.
    pos = np.zeros((5, 1, 3))
    pos[:, 0, 0] = [0.0, 0.5, 1.0, 11.0, 11.0]
    pos[4, 0, 1] = 5.0
    np.testing.assert_allclose(metrics.horizontal_speed(pos, fps, up)[:, 0], [5.0, 5.0, 100.0, 0.0])
    contacts = metrics.foot_contacts(pos, fps, up, floor=np.array([0.0]))
    # steps: slow+low, slow+low, too fast (100 >= 50 cm/s), ends 5 cm up (>= 3 cm)
    np.testing.assert_array_equal(contacts[:, 0], [True, True, False, False])
    skate, n = metrics.foot_skate(pos, fps, up, contacts)
    assert (skate, n) == (pytest.approx(5.0), 2)
    # With no contact at all the skate is 0 over 0 steps.
    assert metrics.foot_skate(pos, fps, up, np.zeros_like(contacts)) == (0.0, 0)


def test_pose_validity_hand_case():
    index = metrics.build_posture_index(np.array([[0.0, 0.0], [3.0, 4.0]]))
    d = metrics.pose_validity(np.array([[0.0, 1.0], [3.0, 0.0], [3.0, 4.0]]), index)
    np.testing.assert_allclose(d, [1.0, 3.0, 0.0])


def test_jerk_of_a_cubic():
    # x = t^3 (t in frames) at 2 fps: x(s) = 8 s^3 cm, third derivative 48 cm/s^3 everywhere.
    pos = np.zeros((6, 2, 3))
    pos[:, 0, 0] = np.arange(6.0) ** 3
    assert metrics.jerk(pos, 2.0) == pytest.approx(24.0)  # joint 1 is still: (48 + 0) / 2
    assert metrics.jerk(pos[:, :1], 2.0) == pytest.approx(48.0)


def test_l2q_is_invariant_to_a_common_turn():
    rng = np.random.default_rng(0)
    a = quat.normalize(rng.normal(size=(2, 3, 4, 4)))
    b = quat.normalize(rng.normal(size=(2, 3, 4, 4)))
    turn = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), 0.7)
    assert metrics.l2q(quat.mul(turn, a), quat.mul(turn, b)) == pytest.approx(metrics.l2q(a, b), rel=1e-12)


def test_weighted_skate_hand_case_counts_a_foot_sliding_above_the_contact_height():
    fps, up, H = 10.0, 1, 2.5
    # Two foot joints over 3 frames: joint 0 planted at height 0 (the ground), joint 1 sliding
    # 10 cm per frame (100 cm/s) at 2 cm, then at 5 cm (2 H: weight 0).
    pos = np.zeros((3, 2, 3))
    pos[:, 1, 0] = [0.0, 10.0, 20.0]
    pos[:, 1, 1] = [2.0, 2.0, 5.0]
    w0 = 2.0 - 2.0 ** (2.0 / H)                        # step 0: mean height 2 cm
    w1 = max(0.0, 2.0 - 2.0 ** (3.5 / H))              # step 1: mean height 3.5 cm -> 0
    got = metrics.weighted_skate(pos[None], fps, up, H)
    assert got.shape == (1,)
    assert got[0] == pytest.approx((w0 * 100.0 + w1 * 100.0) / 4)  # mean over 2 steps x 2 joints
    assert metrics.weighted_skate(pos[None], fps, up, H, steps=slice(0, 1))[0] == pytest.approx(w0 * 100.0 / 2)
    # The contact-based measure never sees that foot (too fast to be a contact).
    contacts = metrics.foot_contacts(pos, fps, up, floor=np.zeros(2))
    assert not contacts[:, 1].any()
    # Offsets: joint 1 planted 2 cm higher than joint 0 (as an ankle above a toe) slides on the ground.
    off = metrics.weighted_skate(pos[None, :2], fps, up, H, offset=np.array([0.0, 2.0]), steps=slice(0, 1))
    assert off[0] == pytest.approx(100.0 / 2)
    # The ground is per window: the same window lifted 50 cm scores the same.
    lifted = pos + np.array([0.0, 50.0, 0.0])
    assert metrics.weighted_skate(np.stack([pos, lifted]), fps, up, H).tolist() == pytest.approx([got[0]] * 2)


def test_floor_penetration_keeps_the_contexts_floor():
    up = 1
    # Two foot joints over 5 frames; frames 0 and 4 are context, the floor their lowest joint (1 cm).
    pos = np.zeros((5, 2, 3))
    pos[:, 0, up] = [1.0, 0.0, -2.0, 1.0, 3.0]  # through the floor by 1 and 3 cm in the gap
    pos[:, 1, up] = [4.0, 2.0, 0.5, -1.0, 4.0]  # the deeper joint counts in each frame
    context = np.array([True, False, False, False, True])
    got = metrics.floor_penetration(pos[None], up, context, slice(1, 4))
    assert got.shape == (1,)
    assert got[0] == pytest.approx((1.0 + 3.0 + 2.0) / 3)
    # Above the floor: nothing, however low the context's feet; the floor moves with the window.
    high = pos.copy()
    high[1:4, :, up] = 1.5
    lifted = pos + np.array([0.0, 50.0, 0.0])
    assert metrics.floor_penetration(np.stack([high, lifted]), up, context, slice(1, 4)).tolist() == \
        pytest.approx([0.0, got[0]])
    # The window's own lowest foot is no floor: a skate measure that takes it sees no penetration.
    assert metrics.floor_penetration(pos[None], up, np.ones(5, dtype=bool), slice(1, 4))[0] == 0.0


def test_foot_float_measures_both_feet_above_what_the_context_shows():
    up = 1
    # Two foot joints over 6 frames; frames 0 and 5 are context. In the context the lower joint
    # reaches 3 cm at most (a flight); in the gap both rise, the lower to 20 cm at frame 2.
    pos = np.zeros((6, 2, 3))
    pos[:, 0, up] = [0.0, 8.0, 20.0, 30.0, 1.0, 3.0]
    pos[:, 1, up] = [5.0, 12.0, 25.0, 2.0, 9.0, 40.0]  # frame 3: this foot is down, the other up
    context = np.array([True, False, False, False, False, True])
    got = metrics.foot_float(pos[None], up, context, slice(1, 5))
    assert got.shape == (1,)
    assert got[0] == pytest.approx(20.0 - 3.0)
    # One foot down in every gap frame: nothing, however high the other swings.
    down = pos.copy()
    down[1:5, 1, up] = 0.5
    assert metrics.foot_float(down[None], up, context, slice(1, 5))[0] == 0.0
    # Moved up or down as a whole, the window scores the same (the context says where the floor is).
    assert metrics.foot_float((pos + np.array([0.0, 50.0, 0.0]))[None], up, context, slice(1, 5))[0] == \
        pytest.approx(got[0])
    # The height-weighted skate of the same gap falls as its feet rise: it cannot see this.
    fps, height = 30.0, 5.0
    moving = pos.copy()
    moving[:, :, 0] = np.arange(6)[:, None] * 3.0  # both feet sliding 3 cm a frame
    grounded = moving.copy()
    grounded[1:5, :, up] = 0.0
    assert metrics.weighted_skate(moving[None], fps, up, height)[0] < metrics.weighted_skate(grounded[None], fps, up,
                                                                                               height)[0]


def test_bench_penetration_takes_the_floor_from_the_context_frames_only():
    from types import SimpleNamespace

    from posturemap.evaluate.protocol import N_FUTURE, N_PAST
    from posturemap.evaluate.scoring import penetration

    length, up = 4, 1
    gpos = np.zeros((1, N_PAST + length + N_FUTURE, 3, 3))
    gpos[..., up] = 5.0
    gpos[0, 2, 1, up] = 1.0  # the lowest foot in the context (a past frame): the floor
    gpos[0, N_PAST + length + 3, 2, up] = 2.0  # a future frame, higher
    gpos[0, N_PAST + 1, 2, up] = -1.0  # 2 under the floor in the gap's second frame
    gpos[0, N_PAST + 3, 1, up] = 0.5  # 0.5 under it in the last
    gpos[0, 0, 0, up] = -9.0  # not a foot joint
    got = penetration(SimpleNamespace(feet=[1, 2], up=up), gpos, length)
    assert got.tolist() == pytest.approx([(2.0 + 0.5) / length])


def _turned(gpos, grot, angle, shift):
    turn = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), angle)
    return quat.mul_vec(turn, gpos) + shift, quat.mul(turn, grot)


def test_motion_features_are_pose_and_velocity_in_the_characters_frame():
    rng = np.random.default_rng(5)
    gpos = rng.normal(size=(4, 3, 3))
    grot = quat.normalize(rng.normal(size=(4, 3, 4)))
    f = metrics.motion_features(gpos, grot, root=0, up=1, fps=30.0)
    assert f.shape == (3, 6 * 3 + 1)
    # Invariant to a turn about up and a move on (and above) the floor... except the root height.
    p2, r2 = _turned(gpos, grot, 1.1, np.array([5.0, 0.0, -3.0]))
    np.testing.assert_allclose(metrics.motion_features(p2, r2, 0, 1, 30.0), f, atol=1e-12)
    # A root facing along +z (identity rotation) moving 1 unit per frame along x at 30 fps.
    pos = np.zeros((2, 1, 3))
    pos[1, 0, 0] = 1.0
    pos[:, 0, 1] = 0.9
    rot = np.zeros((2, 1, 4))
    rot[..., 0] = 1.0
    np.testing.assert_allclose(metrics.motion_features(pos, rot, 0, 1, 30.0)[0], [0, 0, 0, 0.9, 30.0, 0, 0])


def test_nearest_window_distance_hand_case_with_exclusion():
    ref = np.array([[0.0, 0.0], [3.0, 4.0], [1.0, 1.0]])
    q = np.array([[3.0, 4.0], [0.0, 0.0]])
    np.testing.assert_allclose(metrics.nearest_window_distance(q, ref), [0.0, 0.0], atol=1e-7)
    exclude = np.array([[False, True, True], [True, True, False]])
    # query 0 may only use ref 0 (distance 5, RMS over 2 features); query 1 only ref 2 (sqrt 2).
    np.testing.assert_allclose(metrics.nearest_window_distance(q, ref, exclude),
                               [5.0 / math.sqrt(2), 1.0], atol=1e-12)


def test_largest_step_finds_the_one_joint_thrown_across():
    # Two windows of 6 frames, 3 joints walking at 1 unit a frame; in the second, joint 2 jumps
    # 5 units between frames 3 and 4. Only the steps inside ``frames`` count.
    t = np.arange(6, dtype=float)
    pos = np.zeros((2, 6, 3, 3))
    pos[..., 0] = t[None, :, None]
    pos[1, 4:, 2, 2] += 5.0
    np.testing.assert_allclose(metrics.largest_step(pos, slice(None)), [1.0, np.hypot(1.0, 5.0)])
    np.testing.assert_allclose(metrics.largest_step(pos, slice(0, 4)), [1.0, 1.0])  # the jump is frame 3 -> 4
    np.testing.assert_allclose(metrics.largest_step(pos, slice(3, 5)), [1.0, np.hypot(1.0, 5.0)])


def test_largest_acceleration_finds_the_limb_set_off_at_once():
    # Two windows of 8 frames, 3 joints walking at 1 unit a frame (no acceleration); in the second,
    # joint 1 sets off sideways at frame 4 at 2 units a frame: its second difference is 2 at
    # frame 4 only (frames 3, 4, 5 at 0, 0, 2). Only frames with both neighbours in ``frames`` count.
    t = np.arange(8, dtype=float)
    pos = np.zeros((2, 8, 3, 3))
    pos[..., 0] = t[None, :, None]
    pos[1, :, 1, 2] = 2.0 * np.maximum(t - 4.0, 0.0)
    np.testing.assert_allclose(metrics.largest_acceleration(pos, slice(None)), [0.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(metrics.largest_acceleration(pos, slice(0, 5)), [0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(metrics.largest_acceleration(pos, slice(3, 6)), [0.0, 2.0], atol=1e-12)
