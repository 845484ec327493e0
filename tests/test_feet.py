"""Foot-skate cleanup: leg detection, two-bone IK, lock runs, and the effect on transitions."""

from __future__ import annotations

import contextlib
import dataclasses

import numpy as np
import pytest

from posturemap.io import bvh
from posturemap.evaluate import metrics
from posturemap.core import quat
from posturemap.core.joints import key_joints, leg_chains, leg_length, leg_toes
from posturemap.core.motion import up_axis
from posturemap.synth import feet, rest
from posturemap.synth.rest import at_rest
from posturemap.synth.feet import (CLEAR_FADE_S, CLEAR_S, CLEAR_SPEED, FLOOR_S, MAX_DRIFT, STEP_S, TOE_CLEAR,
                                   clearance_lift, contact_runs, lock_weights_and_targets, soft_limit, swing_offsets,
                                   two_bone_ik)
from posturemap.core.skeleton import fk
from posturemap.synth import engine as engine_module
from posturemap.synth.engine import TransitionEngine
from posturemap.synth.trajectory import rotate_about_up


# The compiled foot lock against the numpy one, rotations: the IK's angles are arc cosines,
# which turn rounding differences of 1e-16 in a nearly straight leg (a spot out of reach) into
# about 1e-8.
IK_ATOL = 3e-8


def compiled_ik(rots, grot, gpos, chain, targets, hinge=feet.KNEE_HINGE):
    """The compiled lock's IK of each frame onto ``targets`` (L, 3), unbounded (the kernels
    ``lock_legs`` calls: the leg's hinge over all the frames, each frame's axis, the turn
    ``knee_bounded`` asks, ``hinge_ik_frame``), as :func:`feet.two_bone_ik` with ``hinge``:
    the thigh's and shin's new local rotations (L, 4) each."""
    from posturemap.core import kernels
    jit = kernels.compiled()
    thigh, shin, ankle = chain
    n = len(targets)
    h = jit._knee_hinge(grot, rots, gpos, thigh, shin, ankle, ankle, feet.HINGE_SURE, np.ones(n, dtype=bool))
    axes = np.array([jit._knee_axis(rots, grot, gpos, f, thigh, shin, ankle, hinge, *h) for f in range(n)])
    work = np.empty((4, n))
    jit.knee_bounded(np.ascontiguousarray(targets, dtype=float), gpos, axes, thigh, shin, ankle, 0.0,
                     feet.KNEE_THROUGH, 1e9, 1, 1, 1.0, 1, work, np.ones(n, dtype=bool))
    out = [jit.hinge_ik_frame(rots, grot, gpos, f, thigh, shin, ankle, *targets[f], *axes[f], work[0, f], 1e-5)
           for f in range(n)]
    return np.array([o[0] for o in out]), np.array([o[1] for o in out])


def lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, *args, **kw):
    """``feet.lock_feet`` on a copy of ``rots`` with the numpy code and with the compiled kernel:
    ``{"numpy": (rots, weights), "numba": (rots, weights)}``."""
    from posturemap.core import kernels

    out = {}
    for backend in ("numpy", "numba"):
        r = rots.copy()
        ctx = kernels.numpy_backend() if backend == "numpy" else contextlib.nullcontext()
        if backend == "numba":
            kernels.compiled()
        with ctx:
            w = feet.lock_feet(sk, chains, r, pos, lambda q: fk(sk.parents, q, pos), up, a_feet, b_feet, fps,
                               *args, **kw)
        out[backend] = (r, w)
    return out


def test_leg_chains_are_found_once_per_hierarchy(sample_clips):
    # An engine asks for each clip it prepares (transition() prepares two per call): the chains
    # of one hierarchy come from one search, and a caller that changes its list changes no
    # other caller's.
    from posturemap.core import joints

    sk = sample_clips["walk"].skeleton
    same = dataclasses.replace(sk, offsets=sk.offsets.copy())  # another skeleton object, the same joints
    first = leg_chains(sk)
    searches = joints._leg_chains_of.cache_info().misses
    first.append((0, 0, 0))
    assert leg_chains(same) == leg_chains(sk) == first[:2] and len(first[0]) == 3
    assert joints._leg_chains_of.cache_info().misses == searches
    renamed = dataclasses.replace(sk, names=tuple(n.replace("Foot", "Paw") for n in sk.names))
    assert leg_chains(renamed) == first[:2]  # another hierarchy is searched again: no ankle by name, the hierarchy's
    assert joints._leg_chains_of.cache_info().misses == searches + 1
    leg_chains(dataclasses.replace(sk, offsets=sk.offsets * 2.0))  # the hierarchy's legs depend on the bones
    assert joints._leg_chains_of.cache_info().misses == searches + 2


def test_leg_chains_by_name(sample_clips, bandai_files, cmu_file):
    sk = sample_clips["walk"].skeleton
    names = [tuple(sk.names[j] for j in c) for c in leg_chains(sk)]
    assert names == [("UpperLeg_L", "LowerLeg_L", "Foot_L"), ("UpperLeg_R", "LowerLeg_R", "Foot_R")]
    bandai = bvh.read(bandai_files[0]).skeleton
    assert [bandai.names[c[2]] for c in leg_chains(bandai)] == ["Foot_L", "Foot_R"]
    assert leg_length(bandai, leg_chains(bandai)) == pytest.approx(80.0, rel=0.05)  # centimetres
    cmu = bvh.read(cmu_file).skeleton
    assert [tuple(cmu.names[j] for j in c) for c in leg_chains(cmu)] == [
        ("LeftUpLeg", "LeftLeg", "LeftFoot"), ("RightUpLeg", "RightLeg", "RightFoot")]
    assert [bandai.names[j] for j in leg_toes(bandai)] == ["Toes_L", "Toes_R"]
    assert [cmu.names[j] for j in leg_toes(cmu)] == ["LeftToeBase", "RightToeBase"]
    # A leg whose ankle has no child: its toe is the ankle itself; of two children, the longer bone.
    from posturemap.core.skeleton import Skeleton
    bare = Skeleton(("Hips", "UpperLeg_L", "LowerLeg_L", "Foot_L", "UpperLeg_R", "LowerLeg_R", "Foot_R", "Heel_R",
                     "Toe_R"), np.array([-1, 0, 1, 2, 0, 4, 5, 6, 6]),
                    np.array([[0, 0, 0], [1, 0, 0], [0, -4, 0], [0, -4, 0], [-1, 0, 0], [0, -4, 0], [0, -4, 0],
                              [0, -1, -0.5], [0, -1, 1.5]], dtype=float), (("Xrotation",),) * 9)
    assert list(leg_toes(bare)) == [3, 8]
    # SMPL's names: L_Foot is the toe below L_Ankle, not a second leg (knee, ankle, foot).
    smpl = Skeleton(("Pelvis", "L_Hip", "L_Knee", "L_Ankle", "L_Foot", "R_Hip", "R_Knee", "R_Ankle", "R_Foot",
                     "Spine1", "L_Wrist", "L_Hand", "Head"), np.array([-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 9]),
                    np.array([[0, 0, 0], [1, -1, 0], [0, -4, 0], [0, -4, 0], [0, -1, 1], [-1, -1, 0], [0, -4, 0],
                              [0, -4, 0], [0, -1, 1], [0, 1, 0], [3, 2, 0], [1, 0, 0], [0, 2, 0]], dtype=float),
                    (("Xrotation",),) * 13)
    assert leg_chains(smpl) == [(1, 2, 3), (5, 6, 7)]
    assert list(leg_toes(smpl)) == [4, 8]
    lower, upper = key_joints(smpl)
    assert list(lower) == [3, 7, 2, 6] and list(upper) == [10, 12]


def chain_skeleton(names):
    """A one-leg skeleton: ``names`` from the root down, each joint one unit below its parent."""
    from posturemap.core.skeleton import Skeleton
    n = len(names)
    return Skeleton(tuple(names), np.arange(-1, n - 1), np.array([[0.0, 0.0, 0.0]] + [[0.0, -1.0, 0.0]] * (n - 1)),
                    (("Xrotation",),) * n)


@pytest.mark.parametrize("names, legs", [
    # MakeHuman: thigh and shin in two numbered segments each.
    (("root", "pelvis.L", "upperleg01.L", "upperleg02.L", "lowerleg01.L", "lowerleg02.L", "foot.L", "toe1-1.L"),
     [["upperleg01.L", "lowerleg01.L", "foot.L", "toe1-1.L"]]),
    # Rigify's deform bones: the second segment numbered .001.
    (("root", "DEF-pelvis.L", "DEF-thigh.L", "DEF-thigh.L.001", "DEF-shin.L", "DEF-shin.L.001", "DEF-foot.L",
      "DEF-toe.L"), [["DEF-thigh.L", "DEF-shin.L", "DEF-foot.L", "DEF-toe.L"]]),
    # Daz: a twist joint inside the thigh.
    (("hip", "pelvis", "lThighBend", "lThighTwist", "lShin", "lFoot", "lToe"),
     [["lThighBend", "lShin", "lFoot", "lToe"]]),
    # Numbered alike all the way to the root: the names do not tell the bones apart (the plain
    # parent and grandparent).
    (("Bone", "Bone1", "Bone2", "Bone3", "Foot"), [["Bone2", "Bone3", "Foot"]]),
    # A plain leg is what it was.
    (("Hips", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase"), [["LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase"]]),
])
def test_legs_pass_through_a_bone_split_in_segments(names, legs):
    from posturemap.core.joints import describe_legs
    sk = chain_skeleton(names)
    assert describe_legs(sk) == legs
    thigh, shin, ankle = leg_chains(sk)[0]
    # The leg's length runs through the segments: from the thigh's top to the shin's, and on to the ankle.
    assert leg_length(sk) == pytest.approx((shin - thigh) + (ankle - shin))


def with_thigh_twist(m, seed=0):
    """``m`` with a twist joint inside each thigh (Daz's ``lThighBend > lThighTwist > lShin``)
    and a second segment inside each shin (Rigify's ``DEF-shin.L > DEF-shin.L.001``): halfway
    down each bone, turning about it by a seeded random angle per frame that the joint below
    takes back, so every joint's global transform stays as it was."""
    from posturemap.core.motion import Motion
    from posturemap.core.skeleton import Skeleton
    sk = m.skeleton
    rng = np.random.default_rng(seed)
    names, parents, offsets, rots, pos = list(sk.names), list(sk.parents), list(sk.offsets), [], []
    new_of = {}
    order = []
    for j in range(sk.num_joints):
        if sk.names[j].startswith(("LowerLeg", "Foot")):
            order.append(("twist", j))
        order.append(("joint", j))
    out_names, out_parents, out_offsets, out_r, out_p = [], [], [], [], []
    for kind, j in order:
        p = int(sk.parents[j])
        if kind == "twist":
            bone = sk.offsets[j]
            angle = rng.uniform(-1.0, 1.0, len(m))
            q = quat.from_axis_angle(np.broadcast_to(bone / np.linalg.norm(bone), (len(m), 3)), angle)
            new_of[("twist", j)] = len(out_names)
            out_names.append(sk.names[p] + ("Twist" if sk.names[j].startswith("LowerLeg") else ".001"))
            out_parents.append(new_of[p])
            out_offsets.append(0.5 * bone)
            out_r.append(q)
            out_p.append(np.broadcast_to(0.5 * bone, (len(m), 3)))
            continue
        new_of[j] = len(out_names)
        out_names.append(sk.names[j])
        if ("twist", j) in new_of:
            out_parents.append(new_of[("twist", j)])
            out_offsets.append(0.5 * sk.offsets[j])
            out_r.append(quat.mul(quat.inv(out_r[new_of[("twist", j)]]), m.rotations[:, j]))
            out_p.append(np.broadcast_to(0.5 * sk.offsets[j], (len(m), 3)))
        else:
            out_parents.append(new_of[p] if p >= 0 else -1)
            out_offsets.append(sk.offsets[j])
            out_r.append(m.rotations[:, j])
            out_p.append(m.positions[:, j])
    ends = tuple((new_of[j], o) for j, o in sk.end_sites)
    twisted = Skeleton(tuple(out_names), np.array(out_parents), np.array(out_offsets),
                       tuple(sk.channels[0] if n.endswith(("Twist", ".001")) else sk.channels[sk.names.index(n)]
                             for n in out_names), ends)
    keep = np.array([new_of[j] for j in range(sk.num_joints)])  # the original joints' rows
    return Motion(twisted, np.stack(out_r, axis=1), np.stack(out_p, axis=1).copy(), m.fps), keep


def test_a_twist_joint_inside_the_thigh_stays_inside_it(sample_clips):
    # A twist joint between thigh and shin and a second segment of the shin are passed through:
    # the leg is the same leg, as long, with the thigh (and its subtree) in the lower body; the
    # foot lock moves the same joints to the same places as on the rig without them, keeps the
    # foot's global orientation, and leaves their own rotations alone (neither bone bends in the
    # middle).
    from posturemap.core.joints import describe_legs, part_masks
    m = sample_clips["walk"]
    tw, keep = with_thigh_twist(m)
    sk, tsk = m.skeleton, tw.skeleton
    assert np.allclose(fk(tsk.parents, tw.rotations, tw.positions)[1][:, keep],
                       fk(sk.parents, m.rotations, m.positions)[1], atol=1e-9)
    chains, t_chains = leg_chains(sk), leg_chains(tsk)
    assert [tuple(keep[list(c)]) for c in chains] == t_chains
    assert describe_legs(tsk) == [["UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L"],
                                  ["UpperLeg_R", "LowerLeg_R", "Foot_R", "Toes_R"]] == describe_legs(sk)
    assert leg_length(tsk, t_chains) == pytest.approx(leg_length(sk, chains), rel=1e-12)
    lower, upper = part_masks(tsk, 0)
    twists = [j for j, n in enumerate(tsk.names) if n.endswith(("Twist", ".001"))]
    assert len(twists) == 4 and lower[twists].all() and lower[[c[0] for c in t_chains]].all()
    assert np.array_equal(lower[keep], part_masks(sk, 0)[0])
    # The lock on both rigs: a held foot dragged towards a spot 0.1 leg lengths away.
    up, length = up_axis(m), 12
    frames = np.arange(20, 20 + length)
    leg = leg_length(sk, chains)
    side = (np.arange(3) == (up + 1) % 3).astype(float)
    contacts = np.ones((length, 2), dtype=bool)
    locked = {}
    for name, clip, ch in (("plain", m, chains), ("twist", tw, t_chains)):
        rots, pos = clip.rotations[frames].copy(), clip.positions[frames].copy()
        g = fk(clip.skeleton.parents, rots, pos)[1][:, [c[2] for c in ch]]
        a_feet = np.repeat(g[:1], 2, axis=0) + 0.1 * leg * side
        b_feet = a_feet + 0.2 * leg * side
        locked[name] = {b: fk(clip.skeleton.parents, r, pos) + (r,) for b, (r, _) in
                        lock_both(clip.skeleton, ch, rots, pos, up, a_feet, b_feet, m.fps, contacts).items()}
    for backend in ("numpy", "numba"):
        (g_r, g_p, _), (t_r, t_p, t_rots) = locked["plain"][backend], locked["twist"][backend]
        assert np.abs(g_p - fk(sk.parents, m.rotations[frames], m.positions[frames])[1]).max() > 0.05 * leg
        assert np.allclose(t_p[:, keep], g_p, atol=1e-6 * leg)
        assert np.allclose(np.abs(np.sum(t_r[:, keep] * g_r, axis=-1)), 1.0, atol=1e-9)
        assert np.array_equal(t_rots[:, twists], tw.rotations[frames][:, twists])
        for thigh, shin, ankle in t_chains:
            for top, bottom in ((thigh, shin), (shin, ankle)):
                mid = tsk.parents[bottom]
                assert mid != top  # a joint inside the bone
                upper_half, lower_half = t_p[:, mid] - t_p[:, top], t_p[:, bottom] - t_p[:, mid]
                cos = np.sum(upper_half * lower_half, axis=-1) / np.linalg.norm(upper_half, axis=-1) \
                    / np.linalg.norm(lower_half, axis=-1)
                assert np.all(cos > 1 - 1e-9)


def test_two_bone_ik_reaches_reachable_targets():
    rng = np.random.default_rng(0)
    n = 200
    # A chain hip (origin) -> knee -> ankle, bones of length 1 along -Y, random local rotations.
    parents = np.array([-1, 0, 1])
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, -1.0, 0.0]])
    local = quat.normalize(np.concatenate([rng.normal(size=(n, 2, 4)) * [1, 0.3, 0.3, 0.3] + [1, 0, 0, 0],
                                           np.tile(quat.identity(), (n, 1, 1))], axis=1))
    pos = np.broadcast_to(offsets, (n, 3, 3)).copy()
    grot, gpos = fk(parents, local, pos)
    # Targets within reach: a random point at distance 0.5..1.9 from the hip.
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    target = direction * rng.uniform(0.5, 1.9, size=(n, 1))
    a_lr, b_lr = two_bone_ik(gpos[:, 0], gpos[:, 1], gpos[:, 2], target, grot[:, 0], grot[:, 1],
                             local[:, 0], local[:, 1])
    new = local.copy()
    new[:, 0], new[:, 1] = a_lr, b_lr
    _, gpos2 = fk(parents, new, pos)
    np.testing.assert_allclose(gpos2[:, 2], target, atol=1e-6)
    # Bone lengths are kept (rotations only).
    np.testing.assert_allclose(np.linalg.norm(gpos2[:, 1] - gpos2[:, 0], axis=-1), 1.0, atol=1e-9)


def test_a_straight_knee_bends_about_the_legs_hinge_not_its_noise():
    # Hip -> knee -> ankle along -Y, bones of length 1: four frames with the knee bent forward
    # (+Z, 20 degrees at the hip), one straight but for a knee 0.1 mm to the side (+X). The
    # lock asks each ankle 0.4 closer to the hip. Bent about its own plane (hinge 0) the straight
    # leg's knee goes sideways; with the hinge, forward as in the other frames.
    parents = np.array([-1, 0, 1])
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, -1.0, 0.0]])
    bend = np.tile(quat.identity(), (5, 3, 1))
    bend[:4, 0] = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), -0.35)  # thigh forward
    bend[:4, 1] = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), 0.7)  # shin back under the hip
    bend[4, 0] = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), 1e-4)  # knee a hair to +X
    bend[4, 1] = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), -2e-4)
    pos = np.broadcast_to(offsets, (5, 3, 3)).copy()
    grot, gpos = fk(parents, bend, pos)
    target = gpos[:, 2] + 0.4 * (gpos[:, 0] - gpos[:, 2]) / np.linalg.norm(gpos[:, 0] - gpos[:, 2], axis=-1)[:, None]
    knees = {}
    for hinge in (0.0, 0.2):
        a_lr, b_lr = two_bone_ik(gpos[:, 0], gpos[:, 1], gpos[:, 2], target, grot[:, 0], grot[:, 1],
                                 bend[:, 0], bend[:, 1], hinge=hinge)
        new = bend.copy()
        new[:, 0], new[:, 1] = a_lr, b_lr
        _, moved = fk(parents, new, pos)
        np.testing.assert_allclose(moved[:, 2], target, atol=1e-6)  # the ankle reaches either way
        knees[hinge] = moved[4, 1]
    assert abs(knees[0.0][0]) > 0.3 and abs(knees[0.0][2]) < 0.01  # sideways
    assert knees[0.2][2] > 0.3 and abs(knees[0.2][0]) < 0.01  # forward, as the bent frames' knees


def test_a_knee_bent_across_the_hinge_stays_on_its_side():
    # A nearly straight knee bent 3 degrees in a plane 120 degrees from the hinge's (a clip whose
    # thigh is turned otherwise about its bone than the other frames'), or bent back 3 degrees in
    # the hinge's own plane: asked for its own ankle, the IK leaves the knee where it is, on its
    # own side. A first version bent a knee bent back in (or near) the hinge's plane forward
    # through straight, and flipped it across wherever the lock began holding a foot, or the
    # knee's plane turned across the edge of "near" (7.7 cm for a turn of a quarter of a degree,
    # 1 m legs; a cold review).
    parents = np.array([-1, 0, 1])
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, -1.0, 0.0]])
    bend = np.tile(quat.identity(), (6, 3, 1))
    bend[:4, 0] = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), -0.35)  # hinge: about X
    bend[:4, 1] = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), 0.7)
    side = np.array([np.cos(np.radians(120.0)), 0.0, np.sin(np.radians(120.0))])  # 120 degrees from X
    bend[4, 0] = quat.from_axis_angle(side, -0.026)
    bend[4, 1] = quat.from_axis_angle(side, 0.052)
    bend[5, 0] = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), 0.026)  # bent back, in the hinge's plane
    bend[5, 1] = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), -0.052)
    pos = np.broadcast_to(offsets, (6, 3, 3)).copy()
    grot, gpos = fk(parents, bend, pos)
    a_lr, b_lr = two_bone_ik(gpos[:, 0], gpos[:, 1], gpos[:, 2], gpos[:, 2].copy(), grot[:, 0], grot[:, 1],
                             bend[:, 0], bend[:, 1], hinge=0.2)
    new = bend.copy()
    new[:, 0], new[:, 1] = a_lr, b_lr
    _, moved = fk(parents, new, pos)
    np.testing.assert_allclose(moved[4:], gpos[4:], atol=1e-9)
    # The compiled IK, frame by frame about the same hinge, the same.
    th, sh = compiled_ik(bend, grot, gpos, (0, 1, 2), gpos[:, 2], hinge=0.2)
    np.testing.assert_allclose(np.abs(np.sum(th * a_lr, axis=-1)), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(sh * b_lr, axis=-1)), 1.0, atol=1e-9)


def test_the_legs_hinge_is_read_in_the_hips_frame_not_the_turning_thighs():
    # Hips -> thigh -> knee -> ankle along -Y: four frames with the knee bent forward (+Z), two of
    # them with the thigh turned a quarter turn about its own bone and the shin turned back (the
    # same positions: no joint shows the turn; CMU-rig clips differ in it), and a fifth straight
    # but for a knee 0.1 mm to the side (+X). The lock asks each ankle 0.4 closer to the hip. In
    # the thigh's own frame the turned frames' planes lie a quarter turn from the others', the
    # hinge half-way between, and the straight knee was bent 45 degrees sideways; in the hips'
    # frame every plane is the same, and it bends forward as the others.
    parents = np.array([-1, 0, 1, 2])
    offsets = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, -1.0, 0.0]])
    x, y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    bend = np.tile(quat.identity(), (5, 4, 1))
    bend[:4, 1] = quat.from_axis_angle(x, -0.35)  # thigh forward
    bend[:4, 2] = quat.from_axis_angle(x, 0.7)  # shin back under the hip
    turn = quat.from_axis_angle(y, np.pi / 2)  # about the thigh's bone
    for f in (1, 3):
        bend[f, 1] = quat.mul(bend[f, 1], turn)
        bend[f, 2] = quat.mul(quat.inv(turn), bend[f, 2])
    bend[4, 1] = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), 1e-4)  # knee a hair to +X
    bend[4, 2] = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), -2e-4)
    pos = np.broadcast_to(offsets, (5, 4, 3)).copy()
    grot, gpos = fk(parents, bend, pos)
    np.testing.assert_allclose(gpos[1], gpos[0], atol=1e-12)  # the turn shows in no position
    target = gpos[:, 3] + 0.4 * (gpos[:, 1] - gpos[:, 3]) / np.linalg.norm(gpos[:, 1] - gpos[:, 3], axis=-1)[:, None]
    a_lr, b_lr = two_bone_ik(gpos[:, 1], gpos[:, 2], gpos[:, 3], target, grot[:, 1], grot[:, 2],
                             bend[:, 1], bend[:, 2], hinge=0.2)
    new = bend.copy()
    new[:, 1], new[:, 2] = a_lr, b_lr
    _, moved = fk(parents, new, pos)
    np.testing.assert_allclose(moved[:, 3], target, atol=1e-6)
    knee = moved[4, 2] - moved[4, 1]
    assert knee[2] > 0.3 and abs(knee[0]) < 0.01  # forward, as the bent frames' knees
    th, sh = compiled_ik(bend, grot, gpos, (1, 2, 3), target, hinge=0.2)  # the compiled hinge and IK, the same
    np.testing.assert_allclose(np.abs(np.sum(th * a_lr, axis=-1)), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(sh * b_lr, axis=-1)), 1.0, atol=1e-9)


def test_signed_bend_takes_a_knee_bent_back_forward_through_straight_without_a_jump():
    # A knee bent back 7 degrees (about its axis): straightened while its ankle needs less bend
    # than that, bent forward once it needs KNEE_THROUGH times as much, and in between through
    # straight, never further back than it was; a knee bent forward gets what it needs.
    back = np.radians(7.0)
    need = np.linspace(0.0, 0.8, 801)
    got = feet.signed_bend(-back, need)
    np.testing.assert_allclose(got[need <= back], -need[need <= back])
    ahead = need >= feet.KNEE_THROUGH * back
    np.testing.assert_allclose(got[ahead], need[ahead])
    assert got.min() >= -back - 1e-12
    slope = (feet.KNEE_THROUGH + 1.0) / (feet.KNEE_THROUGH - 1.0)
    assert np.abs(np.diff(got)).max() <= slope * 0.001 * (1 + 1e-9)  # continuous in the need
    np.testing.assert_allclose(feet.signed_bend(np.radians(12.0), need), need)
    # ... and in the knee's own bend, through straight.
    bends = np.linspace(-0.2, 0.2, 401)
    assert np.abs(np.diff(feet.signed_bend(bends, 0.3))).max() < 0.01


def test_a_knee_bent_back_asked_to_bend_more_swings_forward_without_a_jump():
    # Hip -> knee -> ankle along -Y, bones of length 1: four frames bent forward (+Z) give the
    # hinge; then 40 frames of a knee bent back 7 degrees, their ankles' goals drawn toward the
    # hip so that the knee needs from 7 to 40 degrees of bend. The IK before, its hinge the plain
    # sum of the normals (the 40 frames bent back outweighed the 4 forward), bent this knee back
    # all the way to 40 degrees; with a hinge that pointed forward, it bent further back until
    # asked for twice its bend, then flipped forward in a frame (CMU-rig walks popped so). About
    # its axis, it passes through straight a frame at a time, ends bent forward, and reaches its
    # goals but for a few millimetres in between (0.6% of the leg).
    parents = np.array([-1, 0, 1])
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, -1.0, 0.0]])
    n = 44
    x = np.array([1.0, 0.0, 0.0])
    bend = np.tile(quat.identity(), (n, 3, 1))
    bend[:4, 0] = quat.from_axis_angle(x, -0.35)  # forward: the hinge about X
    bend[:4, 1] = quat.from_axis_angle(x, 0.7)
    back = np.radians(7.0)
    bend[4:, 0] = quat.from_axis_angle(x, back / 2)  # bent back, in the hinge's plane
    bend[4:, 1] = quat.from_axis_angle(x, -back)
    pos = np.broadcast_to(offsets, (n, 3, 3)).copy()
    grot, gpos = fk(parents, bend, pos)
    need = np.r_[np.full(4, 0.7), np.linspace(back, np.radians(40.0), n - 4)]
    reach = np.sqrt(2.0 + 2.0 * np.cos(need))
    line = (gpos[:, 2] - gpos[:, 0]) / np.linalg.norm(gpos[:, 2] - gpos[:, 0], axis=-1)[:, None]
    target = gpos[:, 0] + reach[:, None] * line
    a_lr, b_lr = two_bone_ik(gpos[:, 0], gpos[:, 1], gpos[:, 2], target, grot[:, 0], grot[:, 1], bend[:, 0],
                             bend[:, 1], hinge=feet.KNEE_HINGE)
    new = bend.copy()
    new[:, 0], new[:, 1] = a_lr, b_lr
    _, moved = fk(parents, new, pos)
    knee = moved[4:, 1]
    assert np.linalg.norm(np.diff(knee, axis=0), axis=-1).max() < 0.03  # a frame at a time: no jump
    assert knee[0, 2] < -0.05 and knee[-1, 2] > 0.3  # from behind the hip-ankle line to before it
    miss = np.linalg.norm(moved[:, 2] - target, axis=-1)
    assert miss.max() < 0.006 * 2.0 and miss[-10:].max() < 1e-9  # 6 mm of a 1 m leg at most
    th, sh = compiled_ik(bend, grot, gpos, (0, 1, 2), target)  # compiled, the same
    np.testing.assert_allclose(np.abs(np.sum(th * a_lr, axis=-1)), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(sh * b_lr, axis=-1)), 1.0, atol=1e-9)


def test_the_legs_hinge_of_knees_all_bent_back_turns_toward_the_toes():
    # Hip -> knee -> ankle -> toe, the knee bent back 7 degrees in every frame (the toes ahead,
    # +Z): the normals alone say the knee bends backward; the toes turn the hinge about, so that a
    # knee bent about it goes toward them, as a knee bends. Compiled, the same.
    parents = np.array([-1, 0, 1, 2])
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 0.2]])
    n = 6
    x = np.array([1.0, 0.0, 0.0])
    bend = np.tile(quat.identity(), (n, 4, 1))
    bend[:, 0] = quat.from_axis_angle(x, np.linspace(0.05, 0.07, n))  # bent back, the hip a little forward
    bend[:, 1] = quat.from_axis_angle(x, -np.radians(7.0) - np.linspace(0.0, 0.04, n))
    bend[:, 2] = quat.inv(quat.mul(bend[:, 0], bend[:, 1]))  # the foot flat, toes ahead
    pos = np.broadcast_to(offsets, (n, 4, 3)).copy()
    grot, gpos = fk(parents, bend, pos)
    assert (gpos[:, 3, 2] - gpos[:, 2, 2] > 0.19).all() and (gpos[:, 1, 2] < 0).all()
    args = (gpos[:, 0], gpos[:, 1], gpos[:, 2], grot[:, 0], bend[:, 0])
    back, ahead = feet.leg_hinge(*args), feet.leg_hinge(*args, toe=gpos[:, 3])
    np.testing.assert_allclose(ahead, -back, atol=1e-12)
    going = np.cross(ahead, gpos[:, 2] - gpos[:, 0])  # where a knee bent about it goes (the hips' frame is the world's)
    assert (going[:, 2] > 0).all()
    from posturemap.core import kernels
    jit = kernels.compiled()
    every = np.ones(n, dtype=bool)
    np.testing.assert_allclose(jit._knee_hinge(grot, bend, gpos, 0, 1, 2, 3, feet.HINGE_SURE, every), ahead, atol=1e-12)
    np.testing.assert_allclose(jit._knee_hinge(grot, bend, gpos, 0, 1, 2, 2, feet.HINGE_SURE, every), back, atol=1e-12)
    # A kneeling leg (bent 90 degrees, its toes behind the ankle) says which way its hinge points
    # itself: the toes do not turn it.
    kneel = bend.copy()
    kneel[:, 0] = quat.from_axis_angle(x, np.full(n, -np.pi / 2))  # the thigh forward, level
    kneel[:, 1] = quat.from_axis_angle(x, np.full(n, np.pi / 2))  # the shin down
    kneel[:, 2] = quat.from_axis_angle(x, np.full(n, np.pi))  # the foot turned back: toes behind
    grot, gpos = fk(parents, kneel, pos)
    assert (gpos[:, 3, 2] < gpos[:, 2, 2]).all()
    args = (gpos[:, 0], gpos[:, 1], gpos[:, 2], grot[:, 0], kneel[:, 0])
    np.testing.assert_allclose(feet.leg_hinge(*args, toe=gpos[:, 3]), feet.leg_hinge(*args), atol=1e-12)
    np.testing.assert_allclose(jit._knee_hinge(grot, kneel, gpos, 0, 1, 2, 3, feet.HINGE_SURE, every),
                               feet.leg_hinge(*args), atol=1e-12)


def test_a_knee_bent_far_back_reads_its_bend_about_the_hinge_without_a_flip():
    # A knee bent back 15 to 35 degrees in the hinge's plane (hip above ankle, bones of 1; the
    # hinge bends the knee toward +Z, the hips' frame the world's). The knee's own normal, against
    # the hinge, cancelled it at about 23 degrees, the axis flipped over and the bend read about
    # it jumped from -23 to +23 degrees (a cold review): now it reads -15 to -35 a step at a time.
    back = np.radians(np.linspace(15.0, 35.0, 201))
    n = len(back)
    a = np.zeros((n, 3))
    c = np.stack([np.zeros(n), -2.0 * np.cos(back / 2), np.zeros(n)], axis=-1)
    b = np.stack([np.zeros(n), -np.cos(back / 2), -np.sin(back / 2)], axis=-1)  # behind: bent back
    ident = np.tile(quat.identity(), (n, 1))
    axes = feet.knee_axes(a, b, c, ident, ident, np.array([-1.0, 0.0, 0.0]), feet.KNEE_HINGE)
    theta, _ = feet.knee_angles(a, b, c, axes)
    np.testing.assert_allclose(theta, -back, atol=1e-9)


def test_contact_runs():
    on = np.array([0, 1, 1, 0, 0, 1, 0, 1, 1, 1], dtype=bool)
    assert contact_runs(on) == [(1, 3), (5, 6), (7, 10)]
    assert contact_runs(np.zeros(4, bool)) == []


def test_lock_targets_from_a_and_b_and_nothing_in_the_air():
    length = 20
    h = np.full(length, 30.0)
    h[:5] = 0.5   # planted at the start (A's end)
    h[15:] = 0.5  # planted at the end (B's start)
    h[10:12] = 0.5  # a short touch in the middle
    horiz = np.zeros((length, 3))
    horiz[:, 0] = np.arange(length) * 2.0  # the free foot slides along x
    a_spot, b_spot = np.array([-1.0, 0, 0]), np.array([45.0, 0, 0])
    w, target, raised = lock_weights_and_targets(h, horiz, True, a_spot, True, b_spot, floor=0.0, height_tol=1.0)
    assert not raised.any()  # no run is planted all through: no step
    assert np.all(w[:5] == 1) and np.all(w[15:] == 1) and np.all(w[10:12] == 1)
    np.testing.assert_array_equal(target[:5], np.tile(a_spot, (5, 1)))
    np.testing.assert_array_equal(target[15:], np.tile(b_spot, (5, 1)))
    np.testing.assert_array_equal(target[10:12], np.tile(horiz[10], (2, 1)))  # the run's middle
    # In the air: no weight, the foot's own position (swing_offsets carries the corrections there).
    assert not w[5:10].any() and not w[12:15].any()
    np.testing.assert_array_equal(target[5:10], horiz[5:10])
    # Not planted at A's end: the run at A's end is not held (a spot of its own would jump at
    # A's seam); the others are as before.
    w2, t2, _ = lock_weights_and_targets(h, horiz, False, a_spot, True, b_spot, floor=0.0, height_tol=1.0)
    assert not w2[:5].any() and np.all(w2[10:12] == 1) and np.all(w2[15:] == 1)
    np.testing.assert_array_equal(t2[:5], horiz[:5])
    # Low all through, planted at B's start but not at A's end: not held on B's spot from A's
    # first new frame (which jumped the foot there); likewise planted at A's end only.
    low = np.full(length, 0.5)
    for a_on, b_on in ((False, True), (True, False)):
        w4, t4, _ = lock_weights_and_targets(low, horiz, a_on, a_spot, b_on, b_spot, floor=0.0, height_tol=1.0)
        assert not w4.any()
        np.testing.assert_array_equal(t4, horiz)
    # The retrieved segment's contacts are held so too.
    w5, _, _ = lock_weights_and_targets(h, horiz, False, a_spot, True, b_spot, 0.0, 1.0, on=np.ones(length, bool))
    assert not w5.any()
    # A fast low foot is swinging, not planted.
    w3, _, _ = lock_weights_and_targets(h, horiz, False, a_spot, False, b_spot, 0.0, 1.0,
                                        speed=np.full(length, 5.0), speed_tol=1.0)
    assert not w3.any()


def test_a_toe_planted_at_a_seam_is_held_while_the_new_frames_keep_it_low():
    # The foot is in the air at both seams (heel up), its toe planted at A's end: the frames from
    # A's end while the toe stays low, at most `most`, hold the ankle where the toe stays on A's
    # toe spot; a gap of SEAM_TOE_GAP frames is kept free before a run held already; B's side
    # likewise, back from B's start.
    length = 20
    h = np.full(length, 30.0)  # the ankle high: no run of its own
    horiz = np.zeros((length, 3))
    horiz[:, 0] = np.arange(length) * 2.0
    toe = np.tile([12.0, 0.0, 3.0], (length, 1))  # the toe's place about the ankle, turning a little
    toe[:, 2] += np.arange(length) * 0.1
    low = np.zeros(length, dtype=bool)
    low[:4] = low[-7:] = True
    a_toe, b_toe = np.array([10.0, 0.0, 3.0]), np.array([52.0, 0.0, 5.0])
    a_spot, b_spot = np.zeros(3), np.array([40.0, 0, 0])

    def lock(a_t, b_t, most, on=None):
        return lock_weights_and_targets(h, horiz, False, a_spot, False, b_spot, 0.0, 1.0, on=on, toe=toe,
                                        toe_seams=(a_t, a_toe, b_t, b_toe, low, most))[:2]

    w, target = lock(True, False, 6)
    np.testing.assert_array_equal(w, np.r_[np.ones(4), np.zeros(length - 4)])  # held while low
    np.testing.assert_allclose(target[:4] + toe[:4], np.tile(a_toe, (4, 1)))  # the toe on A's spot
    np.testing.assert_array_equal(target[4:], horiz[4:])
    w, _ = lock(True, True, 6)
    np.testing.assert_array_equal(w, np.r_[np.ones(4), np.zeros(length - 10), np.ones(6)])  # B's: at most 6
    w, target = lock(False, True, 2)
    np.testing.assert_array_equal(w, np.r_[np.zeros(length - 2), np.ones(2)])
    np.testing.assert_allclose(target[-2:] + toe[-2:], np.tile(b_toe, (2, 1)))
    # Low all through: each seam's toe held over (L - SEAM_TOE_GAP) // 2 frames at most, SEAM_TOE_GAP
    # frames between (held through, A's toe jumped to B's spot at B's seam).
    low[:] = True
    w, target = lock(True, True, length)
    half = (length - feet.SEAM_TOE_GAP) // 2
    np.testing.assert_array_equal(w, np.r_[np.ones(half), np.zeros(feet.SEAM_TOE_GAP), np.ones(half)])
    np.testing.assert_allclose(target[-half:] + toe[-half:], np.tile(b_toe, (half, 1)))
    # With a catch-up speed: each hold ends where its offset can pass on to the next held frame's
    # (B's to A's last held one; A's to nothing at B's seam) at that speed at most.
    catch = 3.0
    w, target, _ = lock_weights_and_targets(h, horiz, False, a_spot, False, b_spot, 0.0, 1.0, toe=toe,
                                            toe_seams=(True, a_toe, True, b_toe, low, length, catch))
    held = np.flatnonzero(w > 0)
    a_last = held[held < length // 2].max()
    b_first = held[held >= length // 2].min()
    assert a_last + 1 <= half and 0 < length - b_first < half  # B's shorter than without the catch
    offset = target - horiz
    assert np.linalg.norm(offset[a_last]) <= catch * (length - a_last)
    assert np.linalg.norm(offset[b_first] - offset[a_last]) <= catch * (b_first - a_last)
    # One frame more of B's hold would pass on faster than that.
    longer = np.linalg.norm(b_toe - toe[b_first - 1] - horiz[b_first - 1] - offset[a_last])
    assert longer > catch * (b_first - 1 - a_last)
    low[:] = False
    low[:4] = low[-7:] = True
    # A run of the segment's contacts from frame 3: A's toe held 3 - SEAM_TOE_GAP frames only.
    on = np.zeros(length, dtype=bool)
    on[3:8] = True
    w, _ = lock(True, False, 6, on)
    np.testing.assert_array_equal(w, np.r_[np.ones(3 - feet.SEAM_TOE_GAP), np.zeros(feet.SEAM_TOE_GAP), np.ones(5),
                                           np.zeros(length - 8)])
    # A foot held from A's end already keeps its own run; a toe not planted is not held.
    on[:] = False
    on[:5] = True
    w_run, t_run, _ = lock_weights_and_targets(h, horiz, True, a_spot, False, b_spot, 0.0, 1.0, on=on, toe=toe)
    w, target, _ = lock_weights_and_targets(h, horiz, True, a_spot, False, b_spot, 0.0, 1.0, on=on, toe=toe,
                                            toe_seams=(True, a_toe, False, b_toe, low, 6))
    np.testing.assert_array_equal(w, w_run)
    np.testing.assert_array_equal(target, t_run)
    w, _ = lock(False, False, 6)
    assert not w.any()


def test_a_held_foot_turns_about_its_toe():
    # Three runs: from A's spot, in the middle, onto B's spot. The toe's place about the ankle
    # turns (the foot yaws) and shortens (the heel rises) within each run: the target (the
    # ankle's) moves so that the toe stays where it was at the run's reference frame (A's end,
    # the run's middle, B's start), and the seams' spots are kept there.
    length = 24
    h = np.full(length, 30.0)
    runs = [(0, 6), (10, 15), (19, 24)]
    for a, b in runs:
        h[a:b] = 0.5
    horiz = np.zeros((length, 3))
    horiz[:, 0] = np.arange(length) * 2.0
    angle = np.linspace(0.0, 0.8, length)
    reach = np.linspace(15.0, 9.0, length)
    toe = np.stack([reach * np.cos(angle), np.zeros(length), reach * np.sin(angle)], axis=1)
    a_spot, b_spot = np.array([-1.0, 0, 0]), np.array([45.0, 0, 0])
    w0, t0, r0 = lock_weights_and_targets(h, horiz, True, a_spot, True, b_spot, 0.0, 1.0)
    w, t, r = lock_weights_and_targets(h, horiz, True, a_spot, True, b_spot, 0.0, 1.0, toe=toe)
    np.testing.assert_array_equal(w, w0)
    np.testing.assert_array_equal(r, r0)
    for (a, b), ref in zip(runs, (0, 12, length - 1)):
        np.testing.assert_allclose(t[a:b] + toe[a:b], np.tile(t0[ref] + toe[ref], (b - a, 1)), atol=1e-12)
    np.testing.assert_array_equal(t[0], a_spot)  # the seams' spots where the runs meet them
    np.testing.assert_array_equal(t[-1], b_spot)
    np.testing.assert_array_equal(t[6:10], horiz[6:10])  # in the air: untouched
    assert np.abs(t - t0).max() > 2.0  # the toe turned: the ankle moved under it
    # A run planted all through that steps from A's spot to B's: the toe's reference passes
    # from the run's first frame to its last as the step goes.
    ws, ts, _ = lock_weights_and_targets(np.zeros(length), horiz, True, a_spot, True, b_spot, 0.0, 1.0, step=6,
                                         toe=toe)
    _, ts0, _ = lock_weights_and_targets(np.zeros(length), horiz, True, a_spot, True, b_spot, 0.0, 1.0, step=6)
    k0 = (length - 6) // 2
    np.testing.assert_allclose(ts[:k0] + toe[:k0], np.tile(a_spot + toe[0], (k0, 1)), atol=1e-12)
    np.testing.assert_allclose(ts[k0 + 6:] + toe[k0 + 6:], np.tile(b_spot + toe[-1], (length - k0 - 6, 1)),
                               atol=1e-12)
    moved = np.linalg.norm(np.diff(ts + toe, axis=0), axis=1)
    # No jump: a smoothstep over the step's middle (1 - 2 STEP_LAG) of its 7 intervals.
    way = np.linalg.norm(b_spot + toe[-1] - a_spot - toe[0])
    assert moved.max() <= way * 1.5 / (7 * (1 - 2 * feet.STEP_LAG)) + 1e-9


def test_swing_offsets_carry_the_runs_corrections_smoothly():
    # Runs [3, 7) and [12, 16) of 20 frames hold corrections that drift; the frames around them get
    # a curve with the runs' values and rates at its ends, starting and ending at rest on 0 at A's
    # last frame (-1) and B's first (20).
    length = 20
    runs = [(3, 7), (12, 16)]
    offset = np.zeros((length, 2))
    offset[3:7] = np.array([4.0, -1.0]) + np.arange(4)[:, None] * [0.5, 0.25]
    offset[12:16] = np.array([-6.0, 2.0]) + np.arange(4)[:, None] * [-0.3, 0.0]
    in_runs = offset.copy()
    swing_offsets(offset, runs)
    for start, stop in runs:
        np.testing.assert_array_equal(offset[start:stop], in_runs[start:stop])  # runs untouched
    full = np.concatenate([np.zeros((2, 2)), offset, np.zeros((2, 2))])  # A's last 2 frames, B's first 2
    rate = np.diff(full, axis=0)
    # The rate changes little from one frame to the next anywhere (no jump in value or rate),
    # against a ramp over 3 frames that would step the rate by a third of the 6-unit run value.
    assert np.abs(np.diff(rate, axis=0)).max() < 1.5
    # Value and rate are both continued: runs on one straight line give that line between them.
    line = np.zeros((length, 2))
    for start, stop in runs:
        line[start:stop, 0] = 1.0 + 0.5 * np.arange(start, stop)
    swing_offsets(line, runs)
    np.testing.assert_allclose(line[7:12, 0], 1.0 + 0.5 * np.arange(7, 12), atol=1e-12)
    # Before the first run the offset rises from rest at 0; after the last it settles to 0.
    assert np.all(np.abs(offset[0]) < np.abs(offset[1])) and np.all(np.abs(offset[1]) < np.abs(offset[2]))
    assert np.all(np.abs(offset[-1]) < np.abs(offset[-2]))
    # No runs: nothing moves.
    empty = np.ones((length, 2))
    assert not swing_offsets(empty, []).any()


def test_soft_limit_is_the_value_until_its_start_then_bends_onto_the_limit():
    start, limit = 1.9, 2.0
    x = np.linspace(0.0, 4.0, 4001)
    out = soft_limit(x, start, limit)
    inside = x <= start
    np.testing.assert_array_equal(out[inside], x[inside])  # the value itself up to the start
    assert np.all(out < limit) and np.all(np.diff(out) >= 0)  # never the limit, never back
    slope = np.diff(out) / np.diff(x)
    assert np.abs(np.diff(slope)).max() < 0.01  # no kink where the soft part starts
    # Per element (the IK's start is the ankle's own distance where that is farther out), and
    # no bend where the limit is not above the start.
    np.testing.assert_array_equal(soft_limit(np.array([1.97, 1.5]), np.array([1.97, 2.0]), 2.0), [1.97, 1.5])
    assert soft_limit(np.array([1.99]), np.array([1.97]), 2.0)[0] < 1.99
    # The compiled scalar version gives the same values.
    from posturemap.core import kernels
    jit = kernels.compiled()
    for xs, st, lim in ((x[::50], start, limit), (np.array([1.5, 2.5]), 2.0, 2.0), (np.array([0.3]), 0.2, 0.4)):
        np.testing.assert_allclose([jit._soft_limit(v, st, lim) for v in xs], soft_limit(xs, st, lim), rtol=1e-12)


def standing(m, length):
    """``m``'s first leg standing still on its frame 30 for ``length`` frames: ``(sk, up, chains,
    leg, rots, pos)``, the chains that one leg's, ``leg`` its length, the frames' local
    rotations and translations (copies)."""
    sk, up = m.skeleton, up_axis(m)
    chains = leg_chains(sk)[:1]
    frames = np.full(length, 30)
    return sk, up, chains, leg_length(sk, chains), m.rotations[frames].copy(), m.positions[frames].copy()


def sliding_stance(m, length=20):
    """A run of ``length`` frames of ``m`` standing on one frame, its first leg's foot sliding
    sideways 0 to 0.6 leg lengths while its contacts say planted (the last frame not), A's end
    planted on the first frame's spot, B's far away: ``(sk, chains, rots, pos, up, a_feet,
    b_feet, contacts, g, leg, side)``, ``g`` the ankle's global positions before the slide."""
    sk, up, chains, leg, rots, pos = standing(m, length)
    g = fk(sk.parents, rots, pos)[1][:, chains[0][2]]
    side = (np.arange(3) == (up + 1) % 3).astype(float)
    pos[:, 0] -= np.linspace(0.0, 0.6 * leg, length)[:, None] * side
    a_feet = np.repeat(g[:1], 2, axis=0)[:, None]
    b_feet = a_feet + 5 * leg * side  # far away and not relevant (no run reaches B)
    contacts = np.ones((length, 1), dtype=bool)
    contacts[-1] = False
    return sk, chains, rots, pos, up, a_feet, b_feet, contacts, g, leg, side


def test_a_far_spot_drags_the_foot_of_a_run_too_short_to_step(sample_clips, monkeypatch):
    # A foot planted on a spot a growing distance from where the motion puts it, in a run too
    # short for a step (the step made longer than the run): held exactly while the spot is
    # within MAX_DRIFT[0] leg lengths, then moved ever less of the way, never more than
    # MAX_DRIFT[1]; the weight is the fraction of the way.
    monkeypatch.setattr(feet, "STEP_S", 10.0)
    m = sample_clips["walk"]
    length = 20
    sk, chains, rots, pos, up, a_feet, b_feet, contacts, g, leg, side = sliding_stance(m, length)
    for r, w in lock_both(sk, chains, rots, pos, up, a_feet, b_feet, m.fps, contacts).values():
        ankle = fk(sk.parents, r, pos)[1][:, chains[0][2]]
        moved = np.linalg.norm((ankle - g[:1]) * (1 - (np.arange(3) == up)), axis=-1) / leg
        slide = np.linspace(0.0, 0.6, length)[:-1]
        held = slide <= MAX_DRIFT[0]
        # The run lets go of its last frames so that the correction passes back to B's foot at
        # no more than feet.PASS_SPEED and feet.PASS_ACCEL (pace_passes): a prefix is kept.
        kept = w[:-1, 0] > 0
        n = int(kept.sum())
        most = max(MAX_DRIFT[1] * m.fps / feet.PASS_SPEED, np.sqrt(6.0 * MAX_DRIFT[1] * m.fps**2 / feet.PASS_ACCEL))
        assert kept[:n].all() and 0 < length - 1 - n <= np.ceil(most)
        dragged = ~held & kept
        assert np.all(w[:-1][held, 0] == 1) and np.all(moved[:-1][held] < 1e-6)
        assert np.all(np.diff(w[:-1][dragged, 0]) < 0) and dragged.sum() >= 5
        # Where the foot is dragged, the correction (slide less what is left of it) grows past the
        # first bound and stays under the second.
        correction = slide - moved[:-1]
        assert np.all(moved[:-1][dragged] > 0) and np.all(np.diff(correction[dragged]) > 0)
        assert np.all(correction[dragged] > MAX_DRIFT[0] - 1e-9) and np.all(correction < MAX_DRIFT[1])


def test_a_far_spot_makes_a_step_where_the_run_is_long_enough(sample_clips, monkeypatch):
    # The same sliding stance, in a run long enough for a step: the foot is not dragged but held
    # on A's spot, then steps (lifted) in the run's middle to where it lifts off, moved back
    # toward A's spot by MAX_DRIFT[0] leg lengths (what the lock holds without dragging). The
    # pass from there back to B's foot, in the one free frame at the pace alone, is widened by
    # the acceleration's bound: the run lets go of its last frames, no more than the bound asks,
    # and still lands the step.
    m = sample_clips["walk"]
    length = 20
    sk, chains, rots, pos, up, a_feet, b_feet, contacts, g, leg, side = sliding_stance(m, length)
    step = round(feet.STEP_S * m.fps)
    assert length - 1 >= step + 2
    k0 = (length - 1 - step) // 2
    flat = 1 - (np.arange(3) == up)
    lift_off = fk(sk.parents, rots, pos)[1][length - 2, chains[0][2]] * flat
    landing = lift_off + (g[0] * flat - lift_off) * MAX_DRIFT[0] * leg / np.linalg.norm(g[0] * flat - lift_off)
    most = int(np.ceil(np.sqrt(6.0 * MAX_DRIFT[0] * m.fps**2 / feet.PASS_ACCEL)))  # frames of the pass back
    for accel in (np.inf, feet.PASS_ACCEL):
        monkeypatch.setattr(feet, "PASS_ACCEL", accel)
        for r, w in lock_both(sk, chains, rots, pos, up, a_feet, b_feet, m.fps, contacts).values():
            ankle = fk(sk.parents, r, pos)[1][:, chains[0][2]]
            n = int(np.sum(w[:, 0] > 0))
            if np.isinf(accel):
                assert n == length - 1  # every spot within the drift: held all through, never dragged
            else:
                assert k0 + step < n < length - 1 and length - n <= most
            assert np.all(w[:n, 0] == 1) and not w[n:, 0].any()
            np.testing.assert_allclose(ankle[:k0] * flat, np.tile(g[0] * flat, (k0, 1)), atol=1e-6)
            # (The last two held frames' within 0.2% of a leg: the knee's change of bend comes to
            # rest at B's frame no faster than KNEE_ACCEL, knee_bounded, along the hip-ankle line.)
            tail = max(k0 + step, n - 2)
            np.testing.assert_allclose(ankle[k0 + step: tail] * flat, np.tile(landing, (tail - k0 - step, 1)),
                                       atol=1e-6)
            np.testing.assert_allclose(ankle[tail: n] * flat, np.tile(landing, (n - tail, 1)), atol=0.002 * leg)
            # On the ground before the step, off it in the step (after it, the toe's clearance of
            # the last frame's swing may lift the foot a little: not asserted).
            heights = ankle[:, up] - g[:, up]
            assert np.all(np.abs(heights[:k0]) < 1e-6)
            way = np.linalg.norm(landing - g[0] * flat) - feet.STAND_STEP * leg
            # (20 frames at 30 fps: no shorter than STEP_RISE_S, so the whole STEP_RISE.)
            assert heights[k0 + step // 2] > 0.5 * min(feet.STEP_LIFT * leg, feet.STEP_RISE * way)


def test_a_run_held_to_one_seam_steps_there_when_it_lands_far_and_lets_go_where_that_foot_moves():
    length, step = 20, 6
    h = np.zeros(length)
    horiz = np.zeros((length, 3))
    a_spot, b_spot = np.array([100.0, 0, 0]), np.array([30.0, 0, 0])
    on = np.zeros(length, bool)
    on[5:] = True  # lands on frame 5 at the origin and stays until B, where B's spot is 30 away
    w, target, raised = lock_weights_and_targets(h, horiz, False, a_spot, True, b_spot, 0.0, 1.0, on=on, step=step,
                                                 lift=4.0, reach=10.0)
    assert np.all(w[5:] == 1) and not w[:5].any()
    # Held where it lands moved 10 (the reach) toward B's spot, a step of `step` frames in the
    # run's middle, then B's spot; lifted (at most `lift`) in the step only.
    k0 = 5 + (15 - step) // 2
    np.testing.assert_array_equal(target[5:k0], np.tile([10.0, 0, 0], (k0 - 5, 1)))
    np.testing.assert_array_equal(target[k0 + step:], np.tile(b_spot, (length - k0 - step, 1)))
    travel = np.diff(target[k0 - 1: k0 + step + 1, 0])
    assert np.all(travel >= 0) and travel[step // 2] > 0  # on its way, rising and coming down in place
    assert np.all(raised[k0: k0 + step] > 0) and raised.max() <= 4.0 and not raised[:k0].any()
    # Within the reach, or without room for a step, B's spot all through, as before.
    for kw in ({"reach": 40.0}, {"reach": 10.0, "step": 14}):
        w2, t2, r2 = lock_weights_and_targets(h, horiz, False, a_spot, True, b_spot, 0.0, 1.0, on=on,
                                              **{"step": step, "lift": 4.0, **kw})
        np.testing.assert_array_equal(t2[5:], np.tile(b_spot, (15, 1)))
        assert not r2.any()
    # B's foot not planted: the run is held (on the middle of its frames) but for its last `step`
    # frames, where the foot goes to B's through the air; all of it without a step.
    w3, t3, _ = lock_weights_and_targets(h, horiz, False, a_spot, False, b_spot, 0.0, 1.0, on=on, step=step)
    assert np.all(w3[5: length - step] == 1) and not w3[length - step:].any()
    w4, _, _ = lock_weights_and_targets(h, horiz, False, a_spot, False, b_spot, 0.0, 1.0, on=on)
    assert not w4.any()
    # Two frames must stay held: a run of step + 1 frames is let go whole, one of step + 2 keeps two.
    for extra, kept in ((1, 0), (2, 2)):
        run = np.zeros(length, bool)
        run[length - step - extra:] = True
        w6, _, _ = lock_weights_and_targets(h, horiz, False, a_spot, False, b_spot, 0.0, 1.0, on=run, step=step)
        assert w6.sum() == kept and not w6[length - step:].any()
        w7, _, _ = lock_weights_and_targets(h, horiz, False, a_spot, False, b_spot, 0.0, 1.0, on=run[::-1], step=step)
        assert w7.sum() == kept and not w7[:step].any()
    # Likewise at A's end: a run from A's first new frame where A's foot moves is let go in its first frames.
    w5, _, _ = lock_weights_and_targets(h, horiz, False, a_spot, False, b_spot, 0.0, 1.0, on=~on, step=2)
    assert not w5[:2].any() and np.all(w5[2:5] == 1) and not w5[5:].any()


def test_a_seams_planted_foot_is_told_by_that_clips_floor_not_by_the_new_frames(sample_clips):
    # The new frames stand 3 contact heights lower than the seams (a blend, an interpolation):
    # measured against the lowest ankle of the new frames and the seams, a seam's planted foot
    # looked lifted and the run reaching it was let go at that seam; against the seam's own
    # floor it is held there. The other seam's foot is in the air: let go over its `step` frames.
    m = sample_clips["walk"]
    length = 20
    step = round(feet.STEP_S * m.fps)
    sk, up, chains, leg, rots, pos = standing(m, length)
    g = fk(sk.parents, rots, pos)[1][:, chains[0][2]]
    pos[:, 0, up] -= 3 * feet.CONTACT_HEIGHT * leg
    ground = np.repeat(g[:1], 2, axis=0)[:, None]
    lifted = ground + np.eye(3)[up] * leg
    contacts = np.ones((length, 1), dtype=bool)
    floors = (float(g[0, up]), float(g[0, up]))
    for a_feet, b_feet, planted in ((lifted, ground, slice(length - 3, length)), (ground, lifted, slice(0, 3))):
        free = slice(0, step) if planted.start else slice(length - step, length)
        for kw, held in (({}, False), ({"seam_floors": floors}, True)):
            out = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, m.fps, contacts, **kw)
            for r, w in out.values():
                assert not w[free, 0].any()  # the seam whose foot is in the air: let go
                assert np.all(w[planted, 0] == 1) if held else not w[planted, 0].any()
            np.testing.assert_allclose(out["numpy"][1], out["numba"][1], atol=1e-12)
            np.testing.assert_allclose(out["numpy"][0], out["numba"][0], atol=IK_ATOL)


def test_a_foot_planted_at_both_seams_farther_apart_than_a_step_is_not_held(sample_clips):
    # A standing pose carried along the floor (a body gliding over a standing segment), its
    # contacts planted all through, each seam's foot planted where the glide starts and ends.
    # Held on A's spot, then stepping to B's in the middle, the spot crossed the gliding foot
    # and the softly limited pull swapped sides: in-betweening a whole sidestep clip (5 m in
    # 150 frames), Foot_R moved 35 and 36 cm in two frames. Spots a step apart are held through
    # with one step, as before; spots farther apart than STEP_MOST legs are not held: the foot
    # goes as the motion takes it, compiled and numpy alike.
    m = sample_clips["walk"]
    length = 40
    contacts = np.ones((length, 1), dtype=bool)
    for way, held in ((0.5, True), (feet.STEP_MOST + 0.05, False), (3.0, False)):
        sk, up, chains, leg, rots, pos = standing(m, length)
        side = (np.arange(3) == (up + 1) % 3).astype(float)
        glide = np.linspace(0.0, way * leg, length + 2)
        pos[:, 0] += glide[1:-1, None] * side
        g = fk(sk.parents, rots, pos)[1][:, chains[0][2]]
        a_feet = np.stack([g[0] - glide[1] * side, g[0] - glide[1] * side])[:, None]
        b_feet = np.stack([g[-1] + (glide[-1] - glide[-2]) * side] * 2)[:, None]
        floors = (float(g[0, up]), float(g[0, up]))
        out = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, m.fps, contacts, seam_floors=floors)
        for r, w in out.values():
            assert w[:, 0].all() if held else not w[:, 0].any(), (way, w[:, 0])
            gr = fk(sk.parents, r, pos)[1][:, chains[0][2]]
            steps = np.linalg.norm(np.diff(gr, axis=0), axis=-1)
            if not held:  # the motion's own glide (its toe lifted clear of the floor), no jump
                assert steps.max() < 1.5 * way * leg / (length + 1), (way, steps.max() / (way * leg / (length + 1)))
        np.testing.assert_allclose(out["numpy"][1], out["numba"][1], atol=1e-12)
        np.testing.assert_allclose(out["numpy"][0], out["numba"][0], atol=IK_ATOL)


def test_the_compiled_lock_matches_numpy_on_runs_held_to_one_seam(sample_clips, monkeypatch):
    # Seeded random stances, sliding or not, with contacts given or detected, seam floors or
    # not, gaps of 1-25 frames at 1-60 fps (a step of 0-18 frames): the compiled lock makes the
    # numpy lock's weights and rotations, and the new rules (a run stepping off or onto a seam's
    # spot, a run let go at a seam, interpolated feet stepping in turn) are met on the way.
    m = sample_clips["walk"]
    sk, up = m.skeleton, up_axis(m)
    chains = leg_chains(sk)
    leg = leg_length(sk, chains)
    rng = np.random.default_rng(3)
    side = (np.arange(3) == (up + 1) % 3).astype(float)
    calls = {"_step": 0, "_toward": 0}
    for name in calls:
        f = getattr(feet, name)
        monkeypatch.setattr(feet, name, lambda *a, _f=f, _n=name: (calls.__setitem__(_n, calls[_n] + 1), _f(*a))[1])
    turns = []  # stance_windows' answers where feet stepped in turn
    windows = feet.stance_windows

    def counted(*args):
        w = windows(*args)
        if (w[:, 0] >= 0).any():
            turns.append(w)
        return w

    monkeypatch.setattr(feet, "stance_windows", counted)
    for _ in range(300):
        length = int(rng.integers(1, 26))
        fps = float(rng.choice([1.0, 10.0, 30.0, 60.0]))
        f0 = int(rng.integers(0, len(m) - length))
        frames = np.full(length, f0) if rng.random() < 0.5 else np.arange(f0, f0 + length)
        rots, pos = m.rotations[frames].copy(), m.positions[frames].copy()
        pos[:, 0] -= np.linspace(0.0, rng.uniform(0, 1.0) * leg, length)[:, None] * side
        g = fk(sk.parents, rots, pos)[1][:, [c[2] for c in chains]]
        a_feet = np.repeat(g[:1], 2, axis=0) + rng.normal(0, 0.3 * leg, (1, 2, 3)) * (rng.random() < 0.5)
        b_feet = np.repeat(g[-1:], 2, axis=0) + rng.normal(0, 0.3 * leg, (1, 2, 3)) * (rng.random() < 0.5)
        contacts = None
        if rng.random() < 0.6:
            contacts = np.zeros((length, len(chains)), bool)
            i, j = sorted(rng.integers(0, length + 1, 2))
            contacts[i:j] = True
            contacts[:j] |= rng.random() < 0.5
            contacts[i:] |= rng.random() < 0.5
        floors = None if rng.random() < 0.5 else tuple(rng.normal(g[..., up].min(), 0.1 * leg, 2))
        if contacts is None and rng.random() < 0.5:  # both feet planted at both seams: they step in turn
            a_feet, b_feet, floors = np.repeat(g[:1], 2, axis=0), np.repeat(g[-1:], 2, axis=0), None
        if length >= 14 and fps == 30.0 and rng.random() < 0.5:  # a run of exactly step + 1 or + 2 frames at a seam
            contacts = np.zeros((length, len(chains)), bool)
            n = round(feet.STEP_S * fps) + int(rng.integers(1, 3))
            contacts[:n] = rng.random() < 0.5
            contacts[length - n:] = rng.random() < 0.5
        out = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, contacts, seam_floors=floors)
        assert np.isfinite(out["numpy"][0]).all()
        np.testing.assert_allclose(out["numba"][1], out["numpy"][1], atol=1e-9)
        np.testing.assert_allclose(out["numba"][0], out["numpy"][0], atol=IK_ATOL)
    assert calls["_toward"] > 20 and calls["_step"] > calls["_toward"]
    assert len(turns) > 10 and sum(w[:, 1].min() > 0 for w in turns) > 5


def test_soft_ik_bends_the_knee_smoothly_near_full_reach():
    # A target pulled away from the hip past the leg's reach: the hard IK snaps the knee straight
    # (the knee's angle changes fastest just before), the soft one straightens it gradually.
    parents = np.array([-1, 0, 1])
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, -1.0, 0.0]])
    bend = quat.from_axis_angle(np.array([1.0, 0, 0]), 0.6)
    local = np.stack([quat.identity(), bend, quat.identity()])[None].repeat(200, axis=0)
    pos = np.broadcast_to(offsets, (200, 3, 3)).copy()
    grot, gpos = fk(parents, local, pos)
    dist = np.linalg.norm(gpos[0, 2]) + np.linspace(0.0, 0.3, 200)
    target = gpos[:, 2] / np.linalg.norm(gpos[:, 2], axis=-1, keepdims=True) * dist[:, None]
    knee = {}
    for soft in (0.0, 0.05):
        a_lr, b_lr = two_bone_ik(gpos[:, 0], gpos[:, 1], gpos[:, 2], target, grot[:, 0], grot[:, 1],
                                 local[:, 0], local[:, 1], soft=soft)
        knee[soft] = quat.angle_between(b_lr, quat.identity()[None])
    step = {soft: np.abs(np.diff(k)).max() for soft, k in knee.items()}
    assert step[0.05] < 0.5 * step[0.0], step
    assert knee[0.05].min() > 0  # never fully straight


@pytest.mark.parametrize("step, lift, shuffle", [(9, 8.0, 0.0), (9, 100.0, 0.0), (40, 8.0, 0.0), (0, 8.0, 0.0),
                                                  (9, 100.0, 4.0), (9, 8.0, 40.0)])
def test_a_foot_planted_all_through_steps_from_a_to_b(step, lift, shuffle):
    # Planted at A's end, all through the gap and at B's start, on two different spots: the foot
    # holds A's spot, steps (lifted on a squared sine no higher than `lift` and STEP_RISE of the way beyond
    # `shuffle`, easing off the floor and onto it; the target moving monotonically, in
    # the step's middle only: the foot rises and comes down in place) and holds B's spot; it never
    # jumps. A way shorter than `shuffle` slides: the same target, no lift.
    length = 20
    h = np.zeros(length)
    horiz = np.zeros((length, 3))
    a_spot, b_spot = np.array([0.0, 0, 0]), np.array([30.0, 0, 4.0])
    w, target, raised = lock_weights_and_targets(h, horiz, True, a_spot, True, b_spot, 0.0, 1.0, step=step, lift=lift,
                                                 shuffle=shuffle)
    assert np.all(w == 1)
    k = min(step, length - 2)
    k0 = (length - k) // 2
    np.testing.assert_array_equal(target[:k0], np.tile(a_spot, (k0, 1)))
    np.testing.assert_array_equal(target[k0 + k:], np.tile(b_spot, (length - k0 - k, 1)))
    along = (target - a_spot) @ (b_spot - a_spot) / np.sum((b_spot - a_spot) ** 2)
    assert np.all(np.diff(along) >= 0) and along[0] == 0 and along[-1] == 1
    dist = np.linalg.norm(b_spot - a_spot)
    # The largest move in one frame: a smoothstep over the middle (1 - 2 STEP_LAG) (k + 1) intervals
    # moves at most 1.5 / ((k + 1) (1 - 2 STEP_LAG)); the first and last STEP_LAG of the step stay.
    moves = np.linalg.norm(np.diff(target, axis=0), axis=1)
    assert moves.max() <= dist * 1.5 / ((k + 1) * (1 - 2 * feet.STEP_LAG)) + 1e-9
    u = np.arange(1, k + 1) / (k + 1.0)
    rising, landing = u <= feet.STEP_LAG, u >= 1 - feet.STEP_LAG
    np.testing.assert_array_equal(target[k0: k0 + k][rising], np.tile(a_spot, (rising.sum(), 1)))
    np.testing.assert_array_equal(target[k0: k0 + k][landing], np.tile(b_spot, (landing.sum(), 1)))
    if k >= 3:
        assert 0 < along[k0 + k // 2] < 1  # it does travel in the middle
    assert not raised[:k0].any() and not raised[k0 + k:].any()
    high = min(lift, feet.STEP_RISE * max(dist - shuffle, 0.0))
    if k and high > 0:
        assert raised.max() == pytest.approx(high, rel=0.05)
        assert np.all(raised[k0: k0 + k] > 0)
        rise = np.diff(np.r_[0.0, raised[k0: k0 + k], 0.0])  # from the last frame on the floor to the next
        assert abs(rise[0]) < 0.5 * np.abs(rise).max() and abs(rise[-1]) < 0.5 * np.abs(rise).max()
    else:
        assert not raised.any()


def test_stance_windows_give_each_moving_foot_its_own_part_of_the_gap_farthest_first():
    from posturemap.core import numba_kernels

    nan = np.nan
    # One foot to move (or none): the middle of its run, as any foot planted all through.
    for moves in ([nan, nan], [nan, 30.0], [1.0, 30.0], [30.0]):
        assert (feet.stance_windows(moves, 16, 9, 4.0) == -1).all()
    # Two: the farther first, each over its half (the step's frames at most, in the middle).
    w = feet.stance_windows([20.0, 30.0], 16, 9, 4.0)
    assert w.tolist() == [[8, 8], [0, 8]]
    assert feet.stance_windows([30.0, 30.0], 16, 9, 4.0).tolist() == [[0, 8], [8, 8]]  # a tie: the lower index
    assert feet.stance_windows([30.0, 20.0], 40, 9, 4.0).tolist() == [[5, 9], [25, 9]]  # long parts: the step
    # Three feet (a quadruped's three): parts of 3 frames, a step over each; in a gap too short
    # for that (parts of 1-2 frames), every foot keeps the middle of its run.
    assert feet.stance_windows([5.0, 6.0, 7.0], 9, 9, 4.0).tolist() == [[6, 3], [3, 3], [0, 3]]
    assert (feet.stance_windows([5.0, 6.0, 7.0], 8, 9, 4.0) == -1).all()
    rng = np.random.default_rng(5)
    for _ in range(300):
        n = int(rng.integers(1, 5))
        moves = np.where(rng.random(n) < 0.3, nan, rng.choice([3.0, 5.0, 8.0, 8.0, 20.0], n))
        length, step = int(rng.integers(1, 50)), int(rng.integers(0, 20))
        w = feet.stance_windows(moves, length, step, 4.0)
        np.testing.assert_array_equal(numba_kernels._stance_windows(moves, length, step, 4.0), w)
        steps = sorted((int(a), int(a + k)) for a, k in w if a >= 0)
        count = int(np.sum(moves > 4.0))
        assert len(steps) == (count if count >= 2 and length // count >= 3 else 0)
        assert all(b - a >= min(step, 1) for a, b in steps)  # no step of no frame unless asked for
        assert all(0 <= a <= b <= length for a, b in steps)
        assert all(b0 <= a1 for (_, b0), (a1, _) in zip(steps, steps[1:]))  # one foot after another


def test_a_quick_step_gives_up_its_lag_in_place_to_stay_within_the_bound():
    # A standing foot's step of 21 cm over its 5 frames of a short gap: rising and coming down in
    # place over STEP_LAG of them, the foot moved over 3 and set off at 5 cm a frame squared; with
    # the bound (3.6 a frame squared, a walking ankle's at 30 fps), the lag gives way and the foot
    # travels over all of them within it. A step with time to spare keeps the lag.
    first, last, accel = np.zeros(3), np.array([21.0, 0.0, 0.0]), 3.6
    assert feet.step_lag(9, 5.0, accel) == feet.STEP_LAG and feet.step_lag(5, 21.0, np.inf) == feet.STEP_LAG
    assert 0.0 <= feet.step_lag(5, 21.0, accel) < 0.25 * feet.STEP_LAG
    peaks = {}
    for bound in (np.inf, accel):
        spot, raised = np.empty((7, 3)), np.zeros(7)
        feet._step(spot, raised, first, last, 5, 8.0, (1, 5), 4.0, bound)  # frames 1-5 of 7
        path = np.concatenate([[first], spot, [last]])
        peaks[bound] = np.abs(np.diff(path[:, 0], 2)).max()
        np.testing.assert_allclose(spot[[0, -1]], [first, last])  # from A's spot to B's
    assert peaks[np.inf] > 1.4 * accel and peaks[accel] <= accel, peaks


def test_interpolated_feet_change_stance_by_stepping_one_after_another(sample_clips):
    # Both feet planted at A's end and at B's start on other spots, the interpolated legs gliding
    # between them a little above the floor (not planted by the lock's test in the middle): each
    # foot is held on A's spot, steps lifted in its own half of the gap, and is held on B's;
    # never both in the air. Before, the lock let both glide along the floor together.
    m = sample_clips["walk"]
    sk, up = m.skeleton, up_axis(m)
    chains = leg_chains(sk)
    leg = leg_length(sk, chains)
    length = 16
    rots, pos = m.rotations[np.full(length, 30)].copy(), m.positions[np.full(length, 30)].copy()
    side = (np.arange(3) == (up + 1) % 3).astype(float)
    flat = 1 - (np.arange(3) == up)
    t = np.linspace(0.0, 1.0, length)
    pos[:, 0] += (0.18 * leg * t[:, None]) * side + (0.06 * leg * np.sin(np.pi * t)[:, None]) * (1 - flat)
    g = fk(sk.parents, rots, pos)[1][:, [c[2] for c in chains]]
    a_feet, b_feet = np.repeat(g[:1], 2, axis=0), np.repeat(g[-1:], 2, axis=0)
    a_spot, b_spot = g[0] * flat, g[-1] * flat
    windows = feet.stance_windows([0.18 * leg] * 2, length, round(STEP_S * m.fps), feet.STAND_STEP * leg)
    assert windows.tolist() == [[0, 8], [8, 8]]
    out = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, m.fps)
    for r, w in out.values():
        ankles = fk(sk.parents, r, pos)[1][:, [c[2] for c in chains]]
        assert np.all(w == 1)
        for i, (k0, k) in enumerate(windows):  # held (a straight leg's soft reach: within 0.2% of a leg)
            np.testing.assert_allclose(ankles[:k0, i] * flat, np.tile(a_spot[i], (k0, 1)), atol=0.002 * leg)
            np.testing.assert_allclose(ankles[k0 + k:, i] * flat, np.tile(b_spot[i], (length - k0 - k, 1)),
                                       atol=0.002 * leg)
            lifted = ankles[k0: k0 + k, i, up] - g[k0: k0 + k, i, up]
            # (16 frames at 30 fps: no shorter than STEP_RISE_S, so the whole STEP_RISE.)
            assert lifted.min() > 0 and lifted.max() > 0.5 * feet.STEP_RISE * (0.18 - feet.STAND_STEP) * leg
    np.testing.assert_allclose(out["numba"][0], out["numpy"][0], atol=IK_ATOL)
    # A leg the motion lifts between the seams (a kick: the thigh turned 1.2 rad at mid-gap) is
    # left to the motion; the other still holds and steps (in the middle: it is alone now).
    kick = rots.copy()
    thigh = chains[0][0]
    turn = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), 1.2 * np.sin(np.pi * t))
    kick[:, thigh] = quat.mul(kick[:, thigh], turn)
    raised = fk(sk.parents, kick, pos)[1][:, chains[0][2], up]
    assert raised.max() - g[:, 0, up].min() > 2 * feet.STEP_LIFT * leg
    for r, w in lock_both(sk, chains, kick, pos, up, a_feet, b_feet, m.fps).values():
        assert np.all(w[4:12, 0] == 0) and np.all(w[:, 1] == 1)
    # With the legs' contacts given (a retrieved segment's), the feet do as the contacts say.
    on = np.ones((length, len(chains)), bool)
    on[4:12] = False
    r, _ = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, m.fps, on)["numpy"]
    ankles = fk(sk.parents, r, pos)[1][:, [c[2] for c in chains]]
    assert np.abs(ankles[4:12, :, up] - g[4:12, :, up]).max() < 0.03 * leg  # only the toes' clearance
    # Contacts that hold both feet all through (a retrieved segment standing in both clips): the
    # feet step one after another, in the same parts of the gap. Before, each stepped in the
    # middle of its run, both in the air at once: a hop (a bow into a wave, held-out styles).
    held = np.ones((length, len(chains)), bool)
    for r, w in lock_both(sk, chains, rots, pos, up, a_feet, b_feet, m.fps, held).values():
        lifted = fk(sk.parents, r, pos)[1][:, [c[2] for c in chains], up] - g[..., up]
        stepping = lifted > 0.01 * leg
        assert stepping.any(axis=0).all() and not (stepping[:, 0] & stepping[:, 1]).any()
        for i, (k0, k) in enumerate(windows):
            assert not stepping[:k0, i].any() and not stepping[k0 + k:, i].any()


def _pair_engine(bandai_files, a_name: str, b_name: str):
    """Bandai clips ``a_name`` and ``b_name`` as "a" and "b" of a map-less engine: (engine, a, b)."""
    by_name = {p.name: p for p in bandai_files}
    a = bvh.read(by_name[f"dataset-1_{a_name}.bvh"])
    b = bvh.read(by_name[f"dataset-1_{b_name}.bvh"])
    e = TransitionEngine(None, a.skeleton)
    e.add("a", a)
    e.add("b", b)
    return e, a, b


def test_a_short_gap_lifts_its_steps_by_its_share_of_step_rise_s(sample_clips):
    # Real feet hardly rise over a fifth of a second: a gap shorter than STEP_RISE_S lifts its
    # steps by STEP_RISE times its share of it (step_rise), in both the numpy code and the kernel;
    # from STEP_RISE_S on, by STEP_RISE. The two feet of the interpolated stance change above,
    # over 6 new frames at 30 fps (0.23 s from A's last frame to B's first) and over 16.
    fps = 30.0
    assert feet.step_rise(6, fps) == pytest.approx(feet.STEP_RISE * 7.0 / (fps * feet.STEP_RISE_S))
    assert feet.step_rise(16, fps) == feet.step_rise(100, fps) == feet.STEP_RISE
    assert feet.step_rise(0, fps) == feet.STEP_RISE
    assert feet.step_rise(24, 120.0) == pytest.approx(feet.STEP_RISE * 25.0 / (120.0 * feet.STEP_RISE_S))
    m = sample_clips["walk"]
    assert m.fps == fps
    sk, up = m.skeleton, up_axis(m)
    chains = leg_chains(sk)
    leg = leg_length(sk, chains)
    side = (np.arange(3) == (up + 1) % 3).astype(float)
    flat = 1 - (np.arange(3) == up)
    way = (0.18 - feet.STAND_STEP) * leg  # each foot's way beyond the shuffle
    peaks = {}
    for length in (6, 16):
        rots, pos = m.rotations[np.full(length, 30)].copy(), m.positions[np.full(length, 30)].copy()
        pos[:, 0] += 0.18 * leg * np.linspace(0.0, 1.0, length)[:, None] * side
        g = fk(sk.parents, rots, pos)[1][:, [c[2] for c in chains]]
        a_feet, b_feet = np.repeat(g[:1], 2, axis=0), np.repeat(g[-1:], 2, axis=0)
        out = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps)
        np.testing.assert_allclose(out["numba"][0], out["numpy"][0], atol=IK_ATOL)
        ankles = fk(sk.parents, out["numpy"][0], pos)[1][:, [c[2] for c in chains]]
        peaks[length] = (ankles[..., up] - g[..., up]).max(axis=0)
        # Well within the acceleration's bound here: the lift is the share's (a squared sine over
        # a few frames peaks between them: three quarters of it over two).
        high = feet.step_rise(length, fps) * way
        assert np.all(peaks[length] < 1.05 * high) and np.all(peaks[length] > 0.7 * high), (peaks, high)
    assert np.all(peaks[6] < 0.55 * peaks[16])


def test_foot_lock_never_jumps_a_planted_foot(bandai_files, monkeypatch):
    # Transitions from a bow to a walk, B placed to continue A: between two frames where a foot
    # is fully locked it moves at most as fast as the step's smoothstep allows (1.5 / (step + 1)
    # / (1 - 2 STEP_LAG) of the largest A-to-B distance the lock accepts, the foot travelling in
    # the step's middle only; the step is shorter where both feet step
    # in turn, each in half the gap). Without the step (STEP_S = 0, as before it existed) a foot
    # planted at both seams jumps from A's spot to B's in one frame.
    e, a, b = _pair_engine(bandai_files, "bow_normal_001", "walk_normal_001")
    ankles = [c[2] for c in e._legs]
    leg = leg_length(a.skeleton)
    bound = MAX_DRIFT[1] * leg * 1.5 / (min(round(STEP_S * a.fps), 20 // 2 - 2) + 1) / (1 - 2 * feet.STEP_LAG)

    def worst_held_move():
        rng = np.random.default_rng(3)
        worst = 0.0
        for _ in range(8):
            kw = dict(length=20, a_end=int(rng.integers(2, len(a))), b_start=int(rng.integers(0, len(b) - 2)),
                      method="spline", foot_lock=True)
            r, p = e.generate("a", "b", **kw)
            g = fk(e.skeleton.parents, r, p)[1][:, ankles]
            held = (e.last["planted"][1:] == 1) & (e.last["planted"][:-1] == 1)
            move = np.linalg.norm(np.diff(np.delete(g, 1, axis=-1), axis=0), axis=-1)[held]
            worst = max(worst, float(move.max(initial=0.0)))
        return worst

    assert worst_held_move() <= bound
    monkeypatch.setattr(feet, "STEP_S", 0.0)
    assert worst_held_move() > 3 * bound  # the jump the step replaces


@pytest.mark.parametrize("pair", [("walk_normal_001", "run_normal_001"), ("bow_normal_001", "walk_happy_001")])
def test_foot_lock_reduces_skate_and_touches_only_the_legs(bandai_files, pair):
    e, a, b = _pair_engine(bandai_files, *pair)
    ankles = [c[2] for c in e._legs]
    feet_joints = ankles + list(leg_toes(e.skeleton, e._legs))
    height = metrics.SKATE_HEIGHT_LEGS * leg_length(e.skeleton, e._legs)
    rng = np.random.default_rng(1)
    free_steps, locked_steps, free_heels, locked_heels = [], [], [], []
    for _ in range(12):  # seeded seams anywhere in the clips, with A's last 2 frames as context
        kw = dict(length=20, a_end=int(rng.integers(2, len(a))), b_start=int(rng.integers(0, len(b) - 2)),
                  method="spline")
        r0, p0 = (x.copy() for x in e.generate("a", "b", foot_lock=False, **kw))
        r1, p1 = (x.copy() for x in e.generate("a", "b", foot_lock=True, **kw))
        # The lock's input: the free motion with any knee bent backward straightened first
        # (the lock bends a knee in its own plane); that turns the shin and hip only.
        u0 = r0.copy()
        engine_module._unbend_limbs(e, e.tracks["a"], e.tracks["b"], kw["a_end"], kw["b_start"], u0, p0,
                                    legs_only=True)
        g0 = fk(e.skeleton.parents, u0, p0)[1][:, feet_joints]
        g1 = fk(e.skeleton.parents, r1, p1)[1][:, feet_joints]
        # Skate as the benchmark measures it: the feet's horizontal speed weighted by their
        # closeness to the floor, no contact detection (the toes, lowest, carry nearly all of it).
        free_steps.append(metrics.weighted_skate(g0, a.fps, 1, height))
        locked_steps.append(metrics.weighted_skate(g1, a.fps, 1, height))
        # The heels too: ankles low (within 4 cm of the floor, 11 cm for Bandai's ankles) and slow
        # (under 50 cm/s) in the free motion move slower locked. The foot turns about its toe,
        # so a held ankle moves as the foot rolls or turns over it (as the real clips' ankles
        # do: flat on the floor, 7.2 cm/s against the toes' 5.1).
        g0a, g1a = g0[:, :len(ankles)], g1[:, :len(ankles)]
        contacts = metrics.foot_contacts(g0a, a.fps, 1, np.full(len(ankles), 11.0), 4.0, 50.0)
        free_heels.append(metrics.horizontal_speed(g0a, a.fps, 1)[contacts])
        locked_heels.append(metrics.horizontal_speed(g1a, a.fps, 1)[contacts])
        # Only the legs change; the feet keep their global orientation through the lock.
        legs = sorted({j for c in e._legs for j in c})
        others = [j for j in range(a.skeleton.num_joints) if j not in legs]
        np.testing.assert_array_equal(r1[:, others], r0[:, others])
        np.testing.assert_array_equal(u0[:, others], r0[:, others])
        np.testing.assert_array_equal(p1, p0)
        q0, q1 = fk(e.skeleton.parents, u0, p0)[0], fk(e.skeleton.parents, r1, p1)[0]
        assert np.max(quat.angle_between(q0[:, ankles], q1[:, ankles])) < 1e-6
    free, locked = np.mean(free_steps), np.mean(locked_steps)
    # 0.61 and 0.54 (a foot held by its ankle, its toe sliding as it rolled: 0.62 and 0.71).
    assert locked < 0.7 * free, (free, locked)
    free, locked = np.concatenate(free_heels), np.concatenate(locked_heels)
    assert len(free) > 10
    # 0.86 and 0.68 (held by the ankle: 0.42 and 0.44; 0.79 and 0.68 before knees bent backward
    # were straightened ahead of the lock: a straightened leg has less reach left to hold a heel
    # with, and the walk-run pair's spline bends a knee back in some of these frames).
    assert locked.mean() < 0.9 * free.mean(), (free.mean(), locked.mean())


@pytest.mark.parametrize("given_contacts", [False, True])
def test_compiled_foot_lock_matches_the_numpy_reference(sample_clips, given_contacts):
    from posturemap.synth import feet
    from posturemap.core import kernels
    from posturemap.core.motion import up_axis

    jit = kernels.compiled()
    m = sample_clips["walk"]
    sk, up = m.skeleton, up_axis(m)
    chains = leg_chains(sk)
    ankles = [c[2] for c in chains]
    g_all = fk(sk.parents, m.rotations, m.positions)[1]
    rng = np.random.default_rng(7)
    length = 30
    toe_j = leg_toes(sk)
    weights_seen, moved_in_air, toe_held = [], [], 0
    for trial in range(20):
        start = int(rng.integers(2, len(m) - length - 2))
        axis = rng.normal(size=(length, sk.num_joints, 3))
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        if trial % 4 > 1:
            # The clip's frames turned a little at every joint; A's and B's feet from around them.
            frames = np.arange(start, start + length)
            angle = rng.normal(scale=0.05, size=(length, sk.num_joints))
            a_feet = g_all[start - 2: start, ankles] + rng.normal(scale=0.3, size=(2, len(ankles), 3))
            b_feet = g_all[start + length: start + length + 2, ankles] + rng.normal(scale=0.3, size=(2, len(ankles), 3))
            contacts = rng.random((length, len(chains))) < 0.7 if given_contacts else None
            # The toes of the same frames, A's planted in odd trials, B's in every third.
            a_toes = g_all[start - 2: start, toe_j] + rng.normal(scale=0.3, size=(2, len(toe_j), 3))
            b_toes = g_all[start + length: start + length + 2, toe_j] + rng.normal(scale=0.3, size=(2, len(toe_j), 3))
            if trial % 2:
                a_toes[0] = a_toes[1]
            if trial % 3 == 0:
                b_toes[1] = b_toes[0]
        else:
            # Standing on both feet all through, A's spot and B's a little apart: held on A's
            # spot, a step to B's in the middle (lifted), held on B's.
            frames = np.full(length, start)
            angle = rng.normal(scale=0.002, size=(length, sk.num_joints))
            a_feet = np.repeat(g_all[start: start + 1, ankles], 2, axis=0)
            b_feet = a_feet + rng.normal(scale=0.5, size=(1, len(ankles), 3)) * (np.arange(3) != up)
            contacts = np.ones((length, len(chains)), dtype=bool) if given_contacts else None
            if trial % 4 == 1:  # B's feet a third of a leg away: the run to B's spot is locked partly
                b_feet = b_feet + leg_length(sk, chains) / 3 * (np.arange(3) == (up + 1) % 3)
            a_toes = np.repeat(g_all[start: start + 1, toe_j], 2, axis=0)
            b_toes = a_toes + (b_feet - a_feet)
        # The toes' floor given (the context's) or not (found in the new frames), in turn.
        toe_floor = None if trial % 2 == 0 else float(g_all[start - 2: start + length + 2, toe_j, up].min())
        rots = quat.mul(m.rotations[frames], quat.from_axis_angle(axis, angle))
        pos = m.positions[frames].copy()

        def gpos_fn(r):
            return fk(sk.parents, r, pos)

        out = []
        kw = dict(toe_floor=toe_floor, a_toes=a_toes, b_toes=b_toes)
        for backend in ("numpy", "numba"):
            r = rots.copy()
            if backend == "numpy":
                with kernels.numpy_backend():
                    assert feet._compiled() is None
                    w = feet.lock_feet(sk, chains, r, pos, gpos_fn, up, a_feet, b_feet, m.fps, contacts, **kw)
                    no_toes = feet.lock_feet(sk, chains, rots.copy(), pos, gpos_fn, up, a_feet, b_feet, m.fps, contacts,
                                             toe_floor=toe_floor)
            else:
                assert feet._compiled() is jit
                w = feet.lock_feet(sk, chains, r, pos, gpos_fn, up, a_feet, b_feet, m.fps, contacts, **kw)
            out.append((r, w))
        (r_np, w_np), (r_nb, w_nb) = out
        toe_held += int(np.sum((w_np > 0) & (no_toes == 0)))
        np.testing.assert_allclose(w_nb, w_np, atol=1e-12)
        np.testing.assert_allclose(r_nb, r_np, atol=IK_ATOL)
        weights_seen.append(w_np)
        thighs = [c[0] for c in chains]
        moved_in_air.append((np.abs(r_np[:, thighs] - rots[:, thighs]).max(axis=-1) > 1e-9) & (w_np == 0))
    w = np.concatenate(weights_seen)
    # Not a vacuous comparison: feet were locked, partly locked (a far spot) and left free; with
    # the given contacts' many short runs, legs were also moved in the air between runs.
    assert np.sum(w == 1.0) > 20 and np.sum((w > 0) & (w < 1)) > 20 and np.sum(w == 0) > 20
    assert toe_held > 5  # frames held by a seam's planted toe alone (9 with the given contacts)
    if given_contacts:
        assert np.concatenate(moved_in_air).sum() > 20


def test_foot_lock_context_is_a_last_two_frames_and_b_first_two_at_the_clips_ends(bandai_files, monkeypatch):
    # The lock's context: A's frames a_end - 1 and a_end, B's b_start and b_start + 1 (as placed),
    # the clip's end frame repeated where there is no other; also at the first and last frames.
    # The toes' floor looks further: FLOOR_S seconds on each side.
    e, a, b = _pair_engine(bandai_files, "walk_normal_001", "run_normal_001")
    ta, tb = e.tracks["a"], e.tracks["b"]
    seen = []
    real = engine_module.lock_feet
    monkeypatch.setattr(engine_module, "lock_feet", lambda *args, **kw: seen.append(args) or real(*args, **kw))
    lower = []
    for a_end, b_start in ((0, len(b) - 1), (1, len(b) - 2), (len(a) - 1, 0), (40, 17)):
        e.generate("a", "b", length=12, a_end=a_end, b_start=b_start, method="slerp", foot_lock=True)
        a_feet, b_feet = seen[-1][6], seen[-1][7]
        np.testing.assert_array_equal(a_feet, ta.feet[[max(a_end - 1, 0), a_end]])
        ib = [b_start, min(b_start + 1, len(b) - 1)]
        placed = rotate_about_up(tb.feet[ib], e.last["dtheta"], e.up) + e.last["shift"]
        np.testing.assert_array_equal(b_feet, placed)
        # The toes' floor: their lowest over A's last FLOOR_S seconds and B's first, B's moved with B.
        g_a = fk(a.skeleton.parents, a.rotations, a.positions)[1][:, leg_toes(a.skeleton), e.up]
        g_b = fk(b.skeleton.parents, b.rotations, b.positions)[1][:, leg_toes(b.skeleton), e.up]
        na, nb = round(FLOOR_S * a.fps) + 1, round(FLOOR_S * b.fps) + 1
        toe_floor = min(g_a[max(a_end + 1 - na, 0): a_end + 1].min(),
                        g_b[b_start: b_start + nb].min() + e.last["shift"][e.up])
        lower.append(toe_floor < min(g_a[[max(a_end - 1, 0), a_end]].min(), g_b[ib].min() + e.last["shift"][e.up]))
        assert seen[-1][11] == pytest.approx(toe_floor, abs=1e-9)
        # The toes of the same frames, for the toes planted at the seams (B's placed as its ankles).
        toes_a = fk(a.skeleton.parents, a.rotations, a.positions)[1][:, leg_toes(a.skeleton)]
        toes_b = fk(b.skeleton.parents, b.rotations, b.positions)[1][:, leg_toes(b.skeleton)]
        np.testing.assert_allclose(seen[-1][15], toes_a[[max(a_end - 1, 0), a_end]], atol=1e-9)
        placed = rotate_about_up(toes_b[ib], e.last["dtheta"], e.up) + e.last["shift"]
        np.testing.assert_allclose(seen[-1][16], placed, atol=1e-9)
    assert any(lower)  # the longer context found a lower toe than the seams' two frames


def test_clearance_lift_raises_a_fast_toe_near_the_floor_smoothly_and_only_while_it_swings():
    fps, body, up, length = 30.0, 80.0, 1, 40
    r = round(CLEAR_S * fps)
    x = np.arange(length) * 2.0 * body / fps  # 2 leg lengths per second along x (on CLEAR_SPEED's ramp)
    toe = np.zeros((length, 3))
    toe[:, 0] = x
    toe[:, up] = 0.002 * body  # grazing the floor (0.16 cm above it)
    free = np.ones(length, dtype=bool)
    free[28:] = False  # held from frame 28 on
    lift = clearance_lift(toe, free, 0.0, up, body, fps)
    u = (2.0 - CLEAR_SPEED[0]) / (CLEAR_SPEED[1] - CLEAR_SPEED[0])
    assert 0.0 < u < 1.0
    need = TOE_CLEAR * body * u - 0.002 * body
    # At least the shortfall in every free frame past the seam's fade; nothing far into the held run.
    assert np.all(lift[r: 28] >= need - 1e-9)
    assert np.all(lift[28 + 2 * r + 1:] == 0)
    # Continuous: it falls over 2r + 1 frames into the held run, and rises from A's seam on a
    # smoothstep over CLEAR_FADE_S (its steepest slope 1.5 / fade of the lift): half of it in the
    # first new frame at 30 fps, all of it from the second.
    fade = max(2, round(CLEAR_FADE_S * fps))
    assert fade == 2
    assert np.max(np.abs(np.diff(lift[r:]))) <= need / (2 * r + 1) + 1e-9
    assert np.max(np.abs(np.diff(np.concatenate([[0.0], lift[:r + 1]])))) <= 1.5 * need / fade + 1e-9
    assert lift[0] == pytest.approx(0.5 * lift[1])
    assert lift[1] >= need - 1e-9
    # Slow, high enough or held: no lift.
    slow = toe.copy()
    slow[:, 0] = np.arange(length) * 0.2 * body / fps
    assert not clearance_lift(slow, free, 0.0, up, body, fps).any()
    high = toe.copy()
    high[:, up] = 1.01 * TOE_CLEAR * body
    assert not clearance_lift(high, free, 0.0, up, body, fps).any()
    assert not clearance_lift(toe, np.zeros(length, dtype=bool), 0.0, up, body, fps).any()
    # The floor counts: the same toe over a floor 5 cm lower is high enough.
    assert not clearance_lift(toe, free, -5.0, up, body, fps).any()
    # A held toe under the floor is lifted onto it (the floor only, no clearance), faded at the seams
    # over 2r + 1 frames (a planted leg is often straight: its knee bends by the lift's square root).
    held = np.zeros(length, dtype=bool)
    lift = clearance_lift(toe, held, 0.002 * body + 1.0, up, body, fps)
    np.testing.assert_allclose(lift[2 * r: length - 2 * r], 1.0)
    assert 0 < lift[0] < lift[r] < 1.0


def test_held_toes_under_the_floor_are_lifted_in_gaps_of_one_to_three_frames(sample_clips):
    # Both feet held, their toes 1 cm under the context's floor: the compiled lock does what the
    # numpy reference does, down to one frame (no speed there, the floor still counts), and lifts.
    m = sample_clips["walk"]
    sk, up = m.skeleton, up_axis(m)
    chains, toes = leg_chains(sk), leg_toes(sk)
    ankles = [c[2] for c in chains]
    for length in (1, 2, 3):
        rots, pos = m.rotations[np.full(length, 40)].copy(), m.positions[np.full(length, 40)].copy()
        g0 = fk(sk.parents, rots, pos)[1]
        floor = g0[:, toes, up].min() + 1.0
        a_feet = b_feet = np.repeat(g0[:1, ankles], 2, axis=0)
        contacts = np.ones((length, 2), dtype=bool)
        results = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, m.fps, contacts, toe_floor=floor, toes=toes)
        np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
        lifted = fk(sk.parents, results["numpy"][0], pos)[1][:, toes, up]
        assert np.all(lifted > g0[:, toes, up] + 1e-3), length


def test_toe_height_counts_give_the_least_height_real_toes_keep_at_each_speed():
    # One toe planted (height 0, still: it is the floor, and too slow to count), the other moving
    # at 1.2 leg lengths per second with heights spread evenly from 0.01 to 0.05 leg lengths: its
    # samples all fall in the 1.0-1.5 bin, whose 10th percentile is 0.014. Bins without samples
    # take the slower bin's height (0 below the first counted one). On a platform 0.3 legs up,
    # the floor under the toes rises with them: the same counts.
    body, fps, up, n = 0.9, 30.0, 1, 400
    toes = np.zeros((n, 2, 3))
    toes[:, 1, 0] = np.arange(n) * 1.2 * body / fps
    toes[:, 1, up] = np.linspace(0.01, 0.05, n) * body
    counts = feet.toe_height_counts(toes, up, fps, body)
    assert counts.shape == (len(feet.CLEAR_BINS) - 1, len(feet.CLEAR_HEIGHTS) - 1)
    assert counts.sum() == n and counts[2].sum() == n
    curve = feet.clearance_curve(counts)
    np.testing.assert_allclose(curve[2], 0.014, atol=1e-3)
    np.testing.assert_array_equal(curve[:2], 0.0)
    np.testing.assert_array_equal(curve[3:], curve[2])
    raised = toes.copy()
    raised[..., up] += 0.3 * body
    on_platform = feet.toe_height_counts(raised, up, fps, body)
    assert on_platform.sum() == n and np.abs(on_platform - counts).sum() <= 4  # rounding at bin edges only
    np.testing.assert_allclose(feet.clearance_curve(on_platform), curve, atol=1e-4)
    # The floor is the lowest toe within FLOOR_S: a toe that dips 0.01 legs under the planted one
    # for a moment lowers it there only, so its heights near the dip count from the dip.
    dipped = toes.copy()
    dipped[200, 1, up] = -0.01 * body
    near = feet.toe_height_counts(dipped, up, fps, body)
    assert near[2].sum() == n and not np.array_equal(near, counts)
    # Counts of several clips add up to the library's; too few samples in a bin count as none.
    np.testing.assert_array_equal(feet.clearance_curve(counts + counts), curve)
    few = np.zeros_like(counts)
    few[2, 10] = feet.CLEAR_MIN_SAMPLES - 1
    np.testing.assert_array_equal(feet.clearance_curve(few), 0.0)


def test_a_toe_lifting_off_counts_as_still_where_it_stands_at_any_frame_rate():
    # slower_step: each frame's shorter step, so a toe on the floor at lift-off or touch-down
    # moves 0 there (the central difference would give it half the swing's first step).
    x = np.zeros((8, 1, 3))
    x[4:, 0, 0] = np.arange(1, 5) * 0.1
    np.testing.assert_allclose(feet.slower_step(x)[:, 0], [0, 0, 0, 0, 0.1, 0.1, 0.1, 0.1])
    assert feet.slower_step(x[:1]).shape == (1, 1) and feet.slower_step(x[:1])[0, 0] == 0.0
    # A walk's toe: 0.4 s still on the floor, 0.4 s swinging at 1.2 leg lengths per second up
    # to 0.06 leg lengths, and so on. At 24 and at 60 fps no sample on the floor counts as
    # moving (the swing's count in the 1.0-1.5 bin, a few in slower bins where a swing starts
    # between two frames); by central differences the floor's samples at lift-off and touch-down
    # would count at half the swing's speed.
    body, up = 0.9, 1
    for fps in (24.0, 60.0):
        t = np.arange(round(4.0 * fps)) / fps
        phase = (t % 0.8) / 0.4  # < 1 standing, 1..2 swinging
        swing = np.clip(phase - 1.0, 0.0, 1.0)
        toes = np.zeros((len(t), 1, 3))
        toes[:, 0, 0] = 0.48 * body * (np.floor(t / 0.8) + swing)
        toes[:, 0, up] = 0.06 * body * np.sin(np.pi * swing)
        counts = feet.toe_height_counts(toes, up, fps, body)
        assert counts[:, 0].sum() == 0 and counts[2].sum() > counts.sum() / 2, fps
        central = np.linalg.norm(np.gradient(toes * [1, 0, 1], axis=0), axis=-1)[:, 0] * fps / body
        assert np.any((central >= feet.CLEAR_BINS[0]) & (toes[:, 0, up] == 0.0)), fps


def test_a_toe_lifting_off_asks_no_lift_where_it_still_stands():
    # A free toe on the floor for ten frames, then swinging off at 2 leg lengths per second
    # 0.05 leg lengths up (above what the rule asks at that speed): the lift measures each
    # frame's shorter step, so the last frame on the floor (still on one side) asks nothing and
    # nothing is lifted. By the central difference that frame would move at 1 leg length per
    # second on the floor, and be lifted.
    body, fps, up, n = 0.9, 24.0, 1, 20
    toe = np.zeros((n, 3))
    toe[10:, 0] = np.arange(1, n - 9) * 2.0 * body / fps
    toe[10:, up] = 0.05 * body
    free = np.ones(n, dtype=bool)
    np.testing.assert_array_equal(feet.clearance_lift(toe, free, 0.0, up, body, fps), 0.0)
    assert feet.clearance_need(np.array([1.0]), TOE_CLEAR)[0] > 0.0  # what the central difference would ask
    # The same toe dragged along the floor asks for its clearance from its first moving frame.
    dragged = toe.copy()
    dragged[:, up] = 0.0
    lift = feet.clearance_lift(dragged, free, 0.0, up, body, fps)
    assert lift[12:-3].min() > 0.02 * body


def test_clearance_need_is_the_rule_raised_by_the_library_curve():
    curve = np.array([0.004, 0.012, 0.017, 0.015, 0.025, 0.034])
    speeds = np.array([0.1, 0.375, 0.75, 1.25, 2.0, 3.25, 6.0, 9.0])
    rule = TOE_CLEAR * np.clip((speeds - CLEAR_SPEED[0]) / (CLEAR_SPEED[1] - CLEAR_SPEED[0]), 0.0, 1.0)
    np.testing.assert_allclose(feet.clearance_need(speeds, TOE_CLEAR), rule)
    need = feet.clearance_need(speeds, TOE_CLEAR, curve)
    at_knots = np.concatenate([[0.0], curve, [curve[-1]]])  # 0 below CLEAR_BINS[0], the fastest beyond
    np.testing.assert_allclose(need, np.maximum(rule, at_knots))
    assert need[2] == curve[1] > rule[2] and need[5] == rule[5] > curve[4]  # each wins somewhere
    np.testing.assert_array_equal(feet.clearance_need(speeds, 0.0, curve), 0.0)  # no toe joint: nothing


def gliding_left_toe(m, speed: float, length: int = 30):
    """One posture of ``m`` (the left toe down, the right up) held for ``length`` frames while the
    body glides forward at ``speed`` leg lengths per second: ``(sk, up, chains, toes, body, length,
    fps, rots, pos, step)``, ``step`` the root's move per frame."""
    sk, up = m.skeleton, up_axis(m)
    chains, toes = leg_chains(sk), leg_toes(sk)
    body = leg_length(sk, chains)
    g_all = fk(sk.parents, m.rotations, m.positions)[1]
    frame = int(np.argmax(g_all[:, toes[1], up] - g_all[:, toes[0], up]))  # left toe down, right up
    rots, pos = m.rotations[np.full(length, frame)].copy(), m.positions[np.full(length, frame)].copy()
    ahead = (np.arange(3) == (up + 2) % 3).astype(float)
    step = speed * body / m.fps * ahead
    pos[:, 0] += np.arange(length)[:, None] * step
    return sk, up, chains, toes, body, length, m.fps, rots, pos, step


def glide_context(sk, up, chains, toes, rots, pos, step):
    """A glide's global positions, its toes' floor (their lowest) and A's last two and B's first
    two ankle positions continuing the glide: ``(gpos, floor, a_feet, b_feet)``."""
    gpos0 = fk(sk.parents, rots, pos)[1]
    ankles = [c[2] for c in chains]
    a_feet = gpos0[0, ankles] - np.array([2.0, 1.0])[:, None, None] * step
    b_feet = gpos0[-1, ankles] + np.array([1.0, 2.0])[:, None, None] * step
    return gpos0, gpos0[:, toes, up].min(), a_feet, b_feet


def test_foot_lock_lifts_a_slow_dragged_toe_to_the_library_clearance(sample_clips):
    # The body glides at 0.75 leg lengths per second, the left toe on the floor: the fixed rule asks
    # for 0.0067 leg lengths there, a library whose toes keep 0.02 at that speed asks for that, and
    # the lock (compiled and numpy alike) lifts the toe to it.
    m = sample_clips["walk"]
    sk, up, chains, toes, body, length, fps, rots, pos, step = gliding_left_toe(m, 0.75)
    gpos0, floor, a_feet, b_feet = glide_context(sk, up, chains, toes, rots, pos, step)
    curve = np.full(len(feet.CLEAR_BINS) - 1, 0.02)
    rr = round(CLEAR_S * fps)
    mid = slice(2 * rr, length - 2 * rr)
    heights = {}
    for name, given in (("rule", None), ("library", curve)):
        results = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, body=body, toe_floor=floor, toes=toes,
                            clearance=given)
        np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
        heights[name] = fk(sk.parents, results["numpy"][0], pos)[1][mid, toes[0], up] - floor
    rule = TOE_CLEAR * (0.75 - CLEAR_SPEED[0]) / (CLEAR_SPEED[1] - CLEAR_SPEED[0])
    assert np.all(heights["rule"] >= rule * body * (1 - 1e-6)) and np.all(heights["rule"] < 0.012 * body)
    assert np.all(heights["library"] >= 0.02 * body * (1 - 1e-6))
    assert np.all(heights["library"] < 0.021 * body)  # lifted to it, not beyond


def test_the_planted_test_of_a_seam_is_the_same_compiled():
    # numba_kernels._planted (the lock's seam test of ankles and toes) against feet._planted, on
    # random seams near both thresholds.
    from posturemap.core import numba_kernels

    rng = np.random.default_rng(11)
    for _ in range(500):
        up = int(rng.integers(3))
        x = rng.normal(0.0, 1.0, (2, 3, 3))
        leg, seam = int(rng.integers(3)), int(rng.integers(2))
        floor, height_tol, speed_tol = rng.normal(), abs(rng.normal()), abs(rng.normal()) * 2
        want = feet._planted(x[seam, leg].copy(), x[1 - seam, leg].copy(), floor, up, height_tol, speed_tol)
        assert numba_kernels._planted(x, seam, 1 - seam, leg, up, floor, height_tol, speed_tol) == want


def test_a_toe_planted_at_as_end_stays_put_through_the_lock_compiled_and_numpy(sample_clips):
    # The body glides at 0.8 leg lengths per second (too fast for the ankle to count as planted),
    # the left toe low: at A's end that toe stood still. The lock holds it on its spot for
    # SEAM_TOE_S, then lets it go (its offset carried off through the air); without A's toes it
    # slid from the first frame. B's planted toe likewise at the other end; and a toe that rises
    # out of the contact height is let go there.
    m = sample_clips["walk"]
    sk, up, chains, toes, body, length, fps, rots, pos, step = gliding_left_toe(m, 0.8)
    gpos0, floor, a_feet, b_feet = glide_context(sk, up, chains, toes, rots, pos, step)
    a_toes = gpos0[0, toes] - np.array([2.0, 1.0])[:, None, None] * step
    b_toes = gpos0[-1, toes] + np.array([1.0, 2.0])[:, None, None] * step
    a_toes[0, 0] = a_toes[1, 0]  # the left toe still at A's end: planted
    most = round(feet.SEAM_TOE_S * fps)
    assert most == 6
    horizontal = np.arange(3) != up
    kw = dict(body=body, toe_floor=floor, toes=toes)
    results = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, a_toes=a_toes, b_toes=b_toes, **kw)
    np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
    np.testing.assert_array_equal(results["numba"][1], results["numpy"][1])
    r, w = results["numpy"]
    np.testing.assert_array_equal(w[:, 0], np.r_[np.ones(most), np.zeros(length - most)])
    assert not w[:, 1].any()
    g1 = fk(sk.parents, r, pos)[1]
    held = g1[:most, toes[0]][:, horizontal] - a_toes[1, 0][horizontal]
    assert np.abs(held).max() < 0.005 * body  # on A's spot (within the soft reach of a leg trailing behind)
    free = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, **kw)["numpy"][0]
    slid = fk(sk.parents, free, pos)[1][:most, toes[0]][:, horizontal] - a_toes[1, 0][horizontal]
    assert np.linalg.norm(slid[-1]) > (most - 0.5) * np.linalg.norm(step)
    # B's toe planted instead: held over B's last `most` frames on B's spot.
    b_still = b_toes.copy()
    b_still[1, 0] = b_still[0, 0]
    a_moving = gpos0[0, toes] - np.array([2.0, 1.0])[:, None, None] * step
    results = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, a_toes=a_moving, b_toes=b_still, **kw)
    np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
    r, w = results["numpy"]
    np.testing.assert_array_equal(w[:, 0], np.r_[np.zeros(length - most), np.ones(most)])
    g1 = fk(sk.parents, r, pos)[1]
    assert np.abs(g1[-most:, toes[0]][:, horizontal] - b_still[0, 0][horizontal]).max() < 0.005 * body
    # A gap of 8 frames: held over (8 - SEAM_TOE_GAP) // 2 = 3 frames.
    short = gliding_left_toe(m, 0.8, length=8)
    results = lock_both(sk, chains, short[7], short[8], up, a_feet, b_feet, fps, a_toes=a_toes, b_toes=b_toes, **kw)
    np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
    np.testing.assert_array_equal(results["numba"][1], results["numpy"][1])
    np.testing.assert_array_equal(results["numpy"][1][:, 0], np.r_[np.ones(3), np.zeros(5)])
    # The body rises out of the contact height from frame 3: the toe is held over frames 0-2 only.
    risen = pos.copy()
    risen[3:, 0, up] += 0.06 * body
    results = lock_both(sk, chains, rots, risen, up, a_feet, b_feet, fps, a_toes=a_toes, b_toes=b_toes, **kw)
    np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
    np.testing.assert_array_equal(results["numpy"][1][:, 0], np.r_[np.ones(3), np.zeros(length - 3)])


@pytest.mark.parametrize("seam", ["a", "b"])
def test_a_toe_planted_at_a_seam_stays_put_after_a_short_run_there(sample_clips, seam):
    # The glide above, but the left ankle stands still at the seam (A's end, or B's start) and the
    # given contacts hold it over the gap's first (last) one or two frames, no longer than the
    # lift's fade at the seam: the toe is then held where the run left it, up to SEAM_TOE_S more
    # frames, instead of being swept away low over the floor at once (its lift crammed into the
    # seam's fade bent a straight knee: bow into dance). Where the run leaves it, not the seam's
    # own toe spot, which is put 0.02 leg lengths aside here. A run of three frames is past the
    # fade: nothing is held after it. Compiled and numpy alike.
    m = sample_clips["walk"]
    sk, up, chains, toes, body, length, fps, rots, pos, step = gliding_left_toe(m, 0.8)
    gpos0, floor, a_feet, b_feet = glide_context(sk, up, chains, toes, rots, pos, step)
    a_toes = gpos0[0, toes] - np.array([2.0, 1.0])[:, None, None] * step
    b_toes = gpos0[-1, toes] + np.array([1.0, 2.0])[:, None, None] * step
    aside = 0.02 * body * (np.arange(3) == (up + 1) % 3)
    if seam == "a":
        a_feet[0, 0] = a_feet[1, 0]  # the left ankle still at A's end: planted
        a_toes[:, 0] = a_toes[1, 0] + aside  # and its toe, a little aside
    else:
        b_feet[1, 0] = b_feet[0, 0]
        b_toes[:, 0] = b_toes[0, 0] + aside
    most = round(feet.SEAM_TOE_S * fps)
    fade = feet._fade_frames(fps)
    assert fade == 2 and most == 6
    horizontal = np.arange(3) != up
    kw = dict(body=body, toe_floor=floor, toes=toes, a_toes=a_toes, b_toes=b_toes)
    for run in (1, 2, 3):
        contacts = np.zeros((length, len(chains)), dtype=bool)
        order = np.arange(length) if seam == "a" else np.arange(length)[::-1]  # frames from the seam on
        contacts[order[:run], 0] = True
        results = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, contacts, **kw)
        np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
        np.testing.assert_array_equal(results["numba"][1], results["numpy"][1])
        r, w = results["numpy"]
        held = run + most if run <= fade else run
        np.testing.assert_array_equal(w[order, 0] > 0, np.arange(length) < held, err_msg=f"run {run}")
        g1 = fk(sk.parents, r, pos)[1][order, toes[0]][:, horizontal]  # from the seam on
        left = g1[run - 1]  # where the run leaves the toe
        if run <= fade:  # the toe stays there
            assert np.abs(g1[run: held] - left).max() < 0.005 * body, run
            seam_spot = (a_toes[1, 0] if seam == "a" else b_toes[0, 0])[horizontal]
            assert np.linalg.norm(left - seam_spot) > 0.01 * body  # not the seam's own spot
        else:  # let go with the run, it moves off with the body (its offset carried off smoothly)
            assert np.linalg.norm(g1[run + most - 1] - left) > 2 * np.linalg.norm(step), run


def test_foot_lock_lifts_a_toe_dragged_along_the_floor(sample_clips):
    # One posture held while the whole body glides forward at 2.5 leg lengths per second, the left
    # toe on the floor: nothing is planted (too fast), and the lock lifts that toe clear of the
    # floor through the leg's IK, the foot keeping its orientation. The compiled kernel
    # (numba_kernels._toe_lift inside lock_legs) does what the numpy reference does.
    m = sample_clips["walk"]
    sk, up, chains, toes, body, length, fps, rots, pos, step = gliding_left_toe(m, 2.5)
    gpos0, floor, a_feet, b_feet = glide_context(sk, up, chains, toes, rots, pos, step)
    ankles = [c[2] for c in chains]
    results = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, body=body, toe_floor=floor, toes=toes)
    assert not results["numpy"][1].any() and not results["numba"][1].any()
    np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
    r = results["numpy"][0]
    grot1, gpos1 = fk(sk.parents, r, pos)
    u = min(1.0, (2.5 - CLEAR_SPEED[0]) / (CLEAR_SPEED[1] - CLEAR_SPEED[0]))
    rr = round(CLEAR_S * fps)
    mid = slice(2 * rr, length - 2 * rr)  # past the seams' fade
    assert np.all(gpos0[mid, toes[0], up] - floor < 0.2 * TOE_CLEAR * body)  # not clear before
    assert np.all(gpos0[:, toes[1], up] - floor > TOE_CLEAR * body)
    assert np.all(gpos1[mid, toes[0], up] - floor >= TOE_CLEAR * body * u * (1 - 1e-6))
    # The ankle rose as the toe did (the foot's global orientation kept), horizontally unmoved
    # but in the three frames at each seam: there the lift, fading in from A's frame and out to
    # B's, would bend the straight knee faster than KNEE_ACCEL from and to rest, and knee_bounded
    # keeps the ankle a little nearer the hip along its line (1.5 mm, nearly straight down).
    ankle = chains[0][2]
    np.testing.assert_allclose(gpos1[:, toes[0]] - gpos1[:, ankle], gpos0[:, toes[0]] - gpos0[:, ankle], atol=1e-6)
    horizontal = np.arange(3) != up
    np.testing.assert_allclose(gpos1[3:-3, ankle][:, horizontal], gpos0[3:-3, ankle][:, horizontal], atol=1e-6)
    np.testing.assert_allclose(gpos1[:, ankle][:, horizontal], gpos0[:, ankle][:, horizontal], atol=0.003 * body)
    # Only the left leg moved (the right toe is high already).
    moved = np.abs(r - rots).max(axis=(0, 2)) > 1e-12
    assert set(np.flatnonzero(moved)) == set(chains[0])
    # A foot without a toe joint (its "toe" the ankle) gets no clearance: an ankle swings low at
    # heel strike. But an ankle under the floor (the ankles' lowest in the context, here 1 cm
    # above the left one) is lifted onto it, and no higher where it is under it all along.
    for r, _ in lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, body=body, toe_floor=floor,
                          toes=np.array(ankles)).values():
        np.testing.assert_array_equal(r, rots)
    ankle_floor = gpos0[:, ankles[0], up].min() + 0.0125 * body
    results = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, body=body, toe_floor=ankle_floor,
                        toes=np.array(ankles))
    np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
    g1 = fk(sk.parents, results["numpy"][0], pos)[1]
    assert np.all(gpos0[:, ankles[0], up] < ankle_floor - 0.01 * body)
    assert np.all(g1[mid, ankles[0], up] >= ankle_floor - 1e-6)
    assert np.all(g1[mid, ankles[0], up] <= ankle_floor + 1e-6)
    np.testing.assert_allclose(g1[:, ankles[1]], gpos0[:, ankles[1]], atol=1e-9)  # above the floor: as it was
    # A swinging toe under the context's floor (here 1 cm below it) does not lower the floor: it is
    # lifted out of it, to the clearance above the floor. Nothing is held, so the context decides.
    raised_floor = floor + 0.0125 * body
    results = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, body=body, toe_floor=raised_floor, toes=toes)
    np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
    lifted = fk(sk.parents, results["numpy"][0], pos)[1][mid, toes[0], up]
    assert np.all(lifted - raised_floor >= TOE_CLEAR * body * u * (1 - 1e-6))
    # A held foot (the right, in the middle frames) whose toe is under the context's floor (here
    # 1 cm) is lifted onto it: a retrieved stance can put it there. Without a context, the held
    # foot's toe is where the floor is: it stays, and the left toe clears its height.
    contacts = np.zeros((length, 2), dtype=bool)
    contacts[5:25, 1] = True  # a run off the seams (one at a seam where the foot moves would be dropped)
    right_toe = gpos0[0, toes[1], up]
    held_floor = right_toe + 0.0125 * body
    for given, ground in ((held_floor, held_floor), (None, right_toe)):
        results = lock_both(sk, chains, rots, pos, up, a_feet, b_feet, fps, contacts, body=body, toe_floor=given,
                            toes=toes)
        np.testing.assert_allclose(results["numba"][0], results["numpy"][0], atol=IK_ATOL)
        # Held within frames 5-24, in one run; its dragged ends let go of a frame or two so that
        # the correction passes on from A's end and back to B's foot within PASS_ACCEL (pace_passes).
        held = np.flatnonzero(results["numpy"][1][:, 1] > 0)
        assert 5 <= held[0] <= 7 and 22 <= held[-1] < 25 and np.array_equal(held, np.arange(held[0], held[-1] + 1))
        assert not results["numpy"][1][:, 0].any()
        g1 = fk(sk.parents, results["numpy"][0], pos)[1]
        assert np.all(g1[mid, toes[0], up] - ground >= TOE_CLEAR * body * u * (1 - 1e-6))
        assert np.all(g1[5:25, toes[1], up] >= ground - 1e-6)
        # Lifted by the shortfall, no more, where the foot stands on its spot (the run's middle; the
        # body glides on, so its ends are dragged and the leg, near its reach, raises the foot; and
        # the swinging toe's clearance, from the free frames before the run, fades out over the
        # spot's first frame: 0.2 cm there).
        on_spot = results["numpy"][1][:, 1] == 1.0
        assert on_spot.sum() >= 2 and np.all(g1[on_spot, toes[1], up] <= ground + 0.003 * body)


def test_a_short_stretch_between_far_held_spots_is_widened_and_stepped():
    # Two held runs, frames 0-4 and 6-11: the first holds A's spot while the motion's foot drifts
    # 0.3 away from it, the second the foot's own spot; passed in the one free frame between
    # them, the correction jumped 0.15 a frame twice. At a pace of 0.05 a frame the stretch must
    # span the correction's change over it: the runs let go of their ends (the longer first),
    # each keeping its frame at the seam, and the freed frames lift the foot as a step does.
    length, pace, lift, shuffle = 12, 0.05, 0.08, 0.04
    held = np.ones(length, dtype=bool)
    held[5] = False
    weight = held.astype(float)
    offset = np.zeros((length, 3))
    offset[:5, 0] = np.linspace(0.0, 0.3, 5)
    raised = np.zeros(length)
    h = np.full(length, 0.1)  # the motion's ankle: level
    feet.pace_passes(held, weight, offset, raised, h, pace, lift, shuffle)
    runs = feet.contact_runs(held)
    assert len(runs) == 2 and runs[0][0] == 0 and runs[1][1] == length
    p, q = runs[0][1] - 1, runs[1][0]
    d = offset[p, 0]
    assert q - p >= d / pace and q - p - 1 < offset[p + 1, 0] / pace  # wide enough, no wider
    assert (p, q) == (3, 8)  # frames 4, 6 and 7 let go (the longer run first): 0.225 over 5 frames
    assert np.all(weight[~held] == 0) and np.all(weight[held] == 1)
    high = min(lift, feet.STEP_RISE * max(d - shuffle, 0.0))
    u = (np.arange(p + 1, q) - p) / (q - p)
    np.testing.assert_allclose(raised[p + 1: q], high * np.sin(np.pi * u) ** 2)
    assert np.all(raised[held] == 0)
    # Carried through the widened stretch, no frame passes over twice the pace (the Hermite's
    # peak, 1.5x its mean, and the run's own rate carried on); through the one frame, 0.15 a
    # frame.
    carried = feet.swing_offsets(offset.copy(), runs)[:, 0]
    assert np.abs(np.diff(carried)).max() <= 2 * pace
    narrow = np.ones(length, dtype=bool)
    narrow[5] = False
    assert np.abs(np.diff(feet.swing_offsets(offset.copy(), feet.contact_runs(narrow))[:, 0])).max() >= 0.15
    # A stretch the offset passes slowly enough is left as it is; where the motion lifts the
    # foot already (frame 5, by 0.1), the step adds only what it lacks.
    for pace2, hh in ((0.15, h), (pace, h + 0.1 * (np.arange(length) == 5))):
        held2, weight2, raised2 = narrow.copy(), narrow.astype(float), np.zeros(length)
        feet.pace_passes(held2, weight2, offset, raised2, hh, pace2, lift, shuffle)
        if pace2 == 0.15:  # 0.3 over two frames
            assert np.array_equal(held2, narrow) and not raised2.any()
        else:
            assert np.array_equal(held2, held)
            np.testing.assert_allclose(raised2, np.where(np.arange(length) == 5, max(raised[5] - 0.1, 0.0), raised))


def test_a_pass_accelerates_no_faster_than_the_bound_and_puts_the_foot_down_for_no_hop():
    # A foot held on its own spot (frames 0-11), then three frames on a spot 0.3 away (13-15, as a
    # splice's second segment puts it), then on that spot again up to B (17-39). The pace alone
    # (1 a frame) leaves the one free frame between the runs. Bounded by an acceleration of 0.01 a
    # frame squared, 0.3 needs sqrt(6 * 0.3 / 0.01) = 13.4 frames: the runs let go of their ends
    # (the longer first), which leaves the three frames between shorter than three (a foot put
    # down for a frame between two passes, a hop) and the first run one frame long. The three
    # frames go whole, the shortest as they came; the first run gets its frames back, and the
    # last gives up the frames the one pass from the first spot to the second needs, a step.
    length, pace, lift, shuffle, accel, least = 40, 1.0, 0.08, 0.04, 0.01, 3
    held = np.ones(length, dtype=bool)
    held[[12, 16]] = False
    weight = held.astype(float)
    offset = np.zeros((length, 3))
    offset[13:, 0] = 0.3
    raised = np.zeros(length)
    h = np.full(length, 0.1)  # the motion's ankle: level
    pace_only = [held.copy(), weight.copy(), raised.copy()]
    feet.pace_passes(pace_only[0], pace_only[1], offset, pace_only[2], h, pace, lift, shuffle)
    assert np.array_equal(pace_only[0], held) and not pace_only[2].any()
    feet.pace_passes(held, weight, offset, raised, h, pace, lift, shuffle, accel, least)
    runs = feet.contact_runs(held)
    assert runs == [(0, 12), (25, length)]
    p, q = 11, 25
    assert q - p >= np.sqrt(6.0 * 0.3 / accel) and q - p - 1 < np.sqrt(6.0 * 0.3 / accel)  # no wider than needed
    rise = raised[p + 1: q]
    top = int(np.argmax(rise))
    assert np.all(np.diff(rise[: top + 1]) > 0) and np.all(np.diff(rise[top:]) < 0)  # one step
    assert np.all(weight[~held] == 0) and np.all(weight[held] == 1) and np.all(raised[held] == 0)
    # Carried between the runs (no rate at their ends), the correction accelerates within the
    # bound; through the one free frames, fifteen times as fast.
    carried = feet.swing_offsets(offset.copy(), runs)[:, 0]
    narrow = feet.swing_offsets(offset.copy(), feet.contact_runs(pace_only[0]))[:, 0]
    assert np.abs(np.diff(carried, 2)).max() <= accel
    assert np.abs(np.diff(narrow, 2)).max() >= 15 * accel


def test_swing_offsets_carry_a_runs_rate_only_so_far():
    # A run (frames 0-9) whose correction grows 0.5 a frame (the motion under a held foot walks
    # on), then 40 free frames to a run holding 2.0 still. Carried 6 frames at most, the curve
    # leaves the run at its rate and is the smoothstep from 4.5 to 2.0 from frame 6 of the
    # stretch on; the Hermite over the whole stretch carries the rate on and bulges far beyond
    # both values.
    length, carry, rate = 60, 6, 0.5
    offset = np.zeros((length, 1))
    offset[:10, 0] = rate * np.arange(10)
    offset[50:, 0] = 2.0
    runs = [(0, 10), (50, length)]
    short = swing_offsets(offset.copy(), runs, carry)[:, 0]
    whole = swing_offsets(offset.copy(), runs)[:, 0]
    p, q, vp = 9, 50, offset[9, 0]
    u = (np.arange(p + carry, q) - p) / (q - p)
    np.testing.assert_allclose(short[p + carry: q], vp + (3 * u**2 - 2 * u**3) * (2.0 - vp), atol=1e-12)
    # The run's rate goes on from it (slowing at 4 rate / carry a frame squared), where the
    # smoothstep alone would set off from rest.
    assert short[p + 1] - short[p] > 0.6 * rate and short[p + 2] - short[p + 1] > 0
    assert short.max() <= vp + rate * carry * 4 / 27 + 1e-9  # the rate's term at its largest
    assert whole.max() > vp + 2.0
    # With no rate the window changes nothing: the smoothstep both ways.
    still = offset.copy()
    still[:10, 0] = vp
    np.testing.assert_allclose(swing_offsets(still.copy(), runs, carry), swing_offsets(still.copy(), runs), atol=1e-12)


@pytest.mark.parametrize("carry", [None, 2, 7])
def test_pass_accel_is_the_carried_curves_peak_acceleration(carry):
    # The curve swing_offsets lays between two runs, refined 40 times (the same curve on a finer
    # grid: the span, the window and the rates scaled), accelerates at most as pass_accel says,
    # and reaches it within the grid's error; with no rates, a smoothstep's 6 |way| / span^2.
    rng = np.random.default_rng(3)
    k = 40
    for _ in range(30):
        span = int(rng.integers(2, 20))
        vp, vq, rp, rq = (rng.normal(0.0, 1.0, 2) for _ in range(4))
        n = span * k
        offset = np.zeros((n + 3, 2))
        offset[0], offset[1] = vp - rp / k, vp  # the run before: frames 0-1, p = 1
        offset[n + 1], offset[n + 2] = vq, vq + rq / k  # the run after: q = n + 1
        fine = swing_offsets(offset, [(0, 2), (n + 1, n + 3)], None if carry is None else carry * k)
        found = np.linalg.norm(np.diff(fine, 2, axis=0), axis=-1).max() * k**2
        want = feet.pass_accel(vq - vp, rp, rq, span, carry)
        assert found <= want * (1 + 1e-9) and found >= 0.9 * want, (found, want)
    assert feet.pass_accel(np.array([0.3, 0.4]), np.zeros(2), np.zeros(2), 5, carry) == pytest.approx(6 * 0.5 / 25)


def test_a_foot_held_while_its_motion_moves_on_is_let_go_soon_enough_to_catch_it():
    # A foot held on its spot for frames 0-19 while the motion under it moves 0.3 a frame (the
    # correction grows as much), then free to B's seam at frame 30, where it must be back on the
    # motion (0). The offsets' gap alone (5.7 over 11 frames) passes a smoothstep within 0.3 a
    # frame squared, but leaving the run at rest the foot must also reach the motion's pace: the
    # run lets go of its end until the carried curve accelerates within the bound.
    length, accel, rate = 30, 0.3, 0.3
    held = np.zeros(length, dtype=bool)
    held[:20] = True
    weight = held.astype(float)
    offset = np.zeros((length, 2))
    offset[:20, 0] = rate * np.arange(20)
    raised = np.zeros(length)
    h = np.full(length, 0.1)
    p0, d0 = 19, offset[19, 0]
    assert 6 * d0 / (length - p0) ** 2 <= accel  # the old test: passes
    assert feet.pass_accel(-offset[19], offset[19] - offset[18], np.zeros(2), length - p0) > accel
    feet.pace_passes(held, weight, offset, raised, h, 100.0, 0.08, 0.04, accel, 1, 9)
    runs = feet.contact_runs(held)
    assert len(runs) == 1 and runs[0][0] == 0 and 1 < runs[0][1] < 20
    p = runs[0][1] - 1
    assert feet.pass_accel(-offset[p], offset[p] - offset[p - 1], np.zeros(2), length - p, 9) <= accel
    assert feet.pass_accel(-offset[p + 1], offset[p + 1] - offset[p], np.zeros(2), length - p - 1, 9) > accel
    carried = np.concatenate([feet.swing_offsets(offset.copy(), runs, 9), np.zeros((2, 2))])  # B's frames at 0
    assert np.linalg.norm(np.diff(carried, 2, axis=0), axis=-1).max() <= accel * (1 + 1e-9)


def test_a_widened_pass_lifts_the_foot_by_its_own_way_within_the_bound(monkeypatch):
    # The foot held on its spot (0) for frames 0-19 while the motion's foot walks on 0.3 a frame
    # (its correction grows as much), let go sooner (the run's rate counted): between the held
    # frame and B's (frame 30, on the motion's foot) the foot itself travels the motion's way
    # less what was held back, far more than the correction's gap alone. The step it makes is
    # lifted by that way (beyond the shuffle, the lift at most), a squared sine no
    # higher than lets it accelerate within the bound.
    length, accel, rate, lift, shuffle = 30, 0.3, 0.3, 4.0, 4.0
    monkeypatch.setattr(feet, "STEP_RISE", 1.0)  # the whole way beyond the shuffle: the bound binds
    foot = np.zeros((length + 2, 2))  # A's last frame, the new ones, B's first
    foot[:, 0] = -rate * np.arange(-1, length + 1)

    def widened(given, carry=15):
        held = np.zeros(length, dtype=bool)
        held[:20] = True
        offset = np.zeros((length, 2))
        offset[:20, 0] = rate * np.arange(20)
        raised = np.zeros(length)
        feet.pace_passes(held, held.astype(float), offset, raised, np.zeros(length), 100.0, lift, shuffle, accel,
                         1, carry, given)
        return feet.contact_runs(held)[0][1] - 1, offset, raised

    p, offset, raised = widened(foot)
    way = abs(foot[-1, 0] - (foot[p + 1, 0] + offset[p, 0]))  # from the held spot to the motion's foot at B
    assert way > 1.5 * abs(offset[p, 0])
    k = length - p - 1
    want = min(lift, way - shuffle, accel * (k + 1) ** 2 / (2 * np.pi**2))
    np.testing.assert_allclose(raised[p + 1:], want * np.sin(np.pi * np.arange(1, k + 1) / (k + 1)) ** 2)
    assert np.abs(np.diff(np.concatenate([[0.0], raised[p:], [0.0]]), 2)).max() <= accel * (1 + 1e-9)
    # Without the motion's foot: the correction's gap only, a lower step; unbounded, higher.
    assert widened(None)[2].max() < 0.7 * raised.max()
    assert feet.step_lift(k, way, lift, shuffle).max() > 1.1 * raised.max()
    # A stretch longer than the rate is carried follows the motion's own foot after that: the
    # gap's step only.
    p2, _, low = widened(foot, carry=length - p - 2)
    _, _, gap_only = widened(None, carry=length - p - 2)
    assert p2 == p and np.array_equal(low, gap_only)


def test_a_widened_pass_from_a_seam_sets_off_from_the_clips_own_foot():
    # A run held 30 off the motion's foot, let go from A's frame on at the pace (15 frames): the
    # step from A's seam travels from A's own foot (4 behind the new frames' still foot) to the
    # held spot, 34, and is lifted by that beyond the shuffle; from the first new frame's
    # foot it would be 30.
    length, lift, shuffle = 30, 100.0, 20.0

    def widened(a_foot, rise=None):
        held = np.zeros(length, dtype=bool)
        held[2:] = True
        offset = np.zeros((length, 2))
        offset[2:, 0] = 30.0
        raised = np.zeros(length)
        foot = np.zeros((length + 2, 2))
        foot[0, 0] = a_foot
        feet.pace_passes(held, held.astype(float), offset, raised, np.zeros(length), 2.0, lift, shuffle,
                         np.inf, 1, length + 1, foot, rise=rise)
        return np.flatnonzero(held)[0], raised

    q, raised = widened(-4.0)
    assert q == 14  # 30 at 2 a frame: 15 frames from A's
    np.testing.assert_allclose(raised[:q], feet.step_lift(q, 34.0, lift, shuffle), rtol=1e-12)
    np.testing.assert_allclose(widened(0.0)[1][:q], feet.step_lift(q, 30.0, lift, shuffle), rtol=1e-12)
    assert raised[:q].max() > 1.3 * widened(0.0)[1][:q].max()  # 14 high, not 10
    # The lock's share for its gap (step_rise), where given, instead of STEP_RISE: half as high.
    half = widened(-4.0, rise=0.5 * feet.STEP_RISE)[1]
    np.testing.assert_allclose(half[:q], feet.step_lift(q, 34.0, lift, shuffle, rise=0.5 * feet.STEP_RISE),
                               rtol=1e-12)
    np.testing.assert_allclose(half[:q], 0.5 * raised[:q], rtol=1e-12)


def rechecked_runs():
    """Two runs and B's seam: the stretch between the runs passes with the second run's rate
    (the offset moving on at the average pace, a gentle Hermite) and not without it (a
    smoothstep); the stretch to B's seam then shortens that run to its first frame, and its rate
    with it."""
    length, w = 16, 10.0
    held = np.zeros(length, dtype=bool)
    held[2:6] = held[10:14] = True
    offset = np.zeros((length, 2))
    offset[10:14, 0] = w + w / 5 * np.arange(4)
    # (rates 0 / w/5 over 5 frames: peak 0.16 w; 0 / 0: 0.24 w; bound 0.2 w; pace w / 4 a frame)
    return held, held.astype(float), offset, np.zeros(length), np.zeros(length), w / 4, 0.2 * w


def test_pace_passes_checks_a_stretch_again_when_the_next_one_shortens_its_run():
    held, weight, offset, raised, h, pace, accel = rechecked_runs()
    feet.pace_passes(held, weight, offset, raised, h, pace, 1.0, 0.5, accel)
    assert np.array_equal(np.flatnonzero(held), [2, 3, 4, 10])
    # Every stretch left passes: at the pace, and its carried curve within the bound.
    runs = feet.contact_runs(held)
    ends = [(-1, runs[0][0]), (runs[0][1] - 1, runs[1][0]), (runs[1][1] - 1, len(held))]
    for p, q in ends:
        way = (offset[q] if q < len(held) else 0.0) - (offset[p] if p >= 0 else 0.0)
        assert q - p >= np.linalg.norm(way) / pace
        if q - p >= 2:  # the held runs' rates: none left (one frame, or still frames)
            assert feet.pass_accel(way, np.zeros(2), np.zeros(2), q - p) <= accel


def test_pace_passes_is_the_same_compiled():
    # numba_kernels._pace_passes (and _pass_gap, _pass_accel) against feet.pace_passes on random runs,
    # corrections and heights, the ends' stretches (from A's frame -1 and to B's frame L) included.
    from posturemap.core import numba_kernels

    rng = np.random.default_rng(5)
    changed = dropped = 0
    for _ in range(400):
        length = int(rng.integers(1, 30))
        held = rng.random(length) < rng.uniform(0.3, 0.9)
        weight = held * rng.uniform(0.5, 1.0, length)
        offset = np.where(held[:, None], rng.normal(0.0, 0.2, (length, 2)), 0.0)
        raised = np.where(held, rng.uniform(0.0, 0.05, length), 0.0)
        up, ankle = 1, 0
        gpos = rng.normal(0.0, 0.05, (length, 1, 3))
        pace, lift, stand = float(rng.uniform(0.01, 0.2)), 0.08, 0.04
        # Half the cases without the acceleration bound and the shortest run (the pace alone).
        accel, least = ((float(rng.uniform(0.002, 0.05)), int(rng.integers(1, 5))) if rng.random() < 0.5
                        else (np.inf, 1))
        carry = int(rng.integers(1, 40))  # the runs' rates carried that far: shorter or longer than the stretches
        rise = float(rng.uniform(0.03, feet.STEP_RISE))  # the lock's share for a gap's length (step_rise)
        want = [held.copy(), weight.copy(), offset.copy(), raised.copy()]
        seams = rng.normal(0.0, 0.05, (2, 3))  # A's last and B's first ankle
        foot = np.concatenate([seams[:1], gpos[:, ankle], seams[1:]])[:, [(up + 1) % 3, (up + 2) % 3]]
        feet.pace_passes(*want, gpos[:, ankle, up].copy(), pace, lift, stand, accel, least, carry, foot,
                         rise=rise)
        got = [held.copy(), weight.copy(), offset.copy(), raised.copy()]
        numba_kernels._pace_passes(*got, gpos, ankle, up, *seams, pace, lift, stand, rise, accel, least, carry)
        for g, w in zip(got, want):
            np.testing.assert_allclose(g, w, rtol=0, atol=1e-12)
        changed += not np.array_equal(want[0], held)
        dropped += np.isfinite(accel) and len(feet.contact_runs(want[0])) < len(feet.contact_runs(held))
    assert changed > 100 and dropped > 20
    # A stretch checked again once the next one shortened its run.
    held, weight, offset, raised, h, pace, accel = rechecked_runs()
    want = [held.copy(), weight.copy(), offset.copy(), raised.copy()]
    feet.pace_passes(*want, h, pace, 1.0, 0.5, accel, 1, len(held))
    gpos = np.zeros((len(held), 1, 3))
    numba_kernels._pace_passes(held, weight, offset, raised, gpos, 0, 1, np.zeros(3), np.zeros(3), pace, 1.0, 0.5,
                               feet.STEP_RISE, accel, 1, len(held))
    assert np.array_equal(held, want[0]) and not held[5]
    np.testing.assert_allclose(raised, want[3], rtol=0, atol=1e-12)


# -- the knee's bend bounded ------------------------------------------------------------------
def straight_leg_lifted(n: int = 24, lift_at: int = 12, rng=None):
    """A nearly straight leg (thigh 45, shin 42 cm; the hip 0.3 % of its reach above the ankle),
    hip and ankle still, and the lock's goals: held on the spot, then from frame ``lift_at`` on
    a pass that lifts the ankle 6 cm at once (what a foot lifted from a straight leg did)."""
    a = np.tile([0.0, 90.0, 0.0], (n, 1))
    c = np.tile([0.0, 90.0 - 0.997 * 87.0, 0.0], (n, 1))
    # the knee in front, where thigh and shin meet
    h = 0.997 * 87.0
    x = (45.0**2 - 42.0**2 + h**2) / (2 * h)
    b = np.tile([np.sqrt(45.0**2 - x**2), 90.0 - x, 0.0], (n, 1))
    goal = c.copy()
    goal[lift_at:, 1] += 6.0 * np.minimum(1.0, (np.arange(n - lift_at) + 1) / 3.0)
    if rng is not None:
        goal += rng.normal(scale=1.5, size=goal.shape)
    return goal, a, b, c


def bends(goal, a, b, c):
    thigh, shin = np.linalg.norm(b[0] - a[0]), np.linalg.norm(c[0] - b[0])
    return (feet.bend_for_reach(np.linalg.norm(goal - a, axis=-1), thigh, shin, 0.0)
            - feet.bend_for_reach(np.linalg.norm(c - a, axis=-1), thigh, shin, 0.0))


def plane_axes(a, b, c, straight=(0.0, 0.0, 1.0)):
    """The knee's axes of a leg that bends in its own plane (the plane's normal; ``straight``
    where the leg is straight): :func:`feet.knee_axes` of a leg whose hinge is its plane's."""
    n = np.cross(c - a, b - a)
    size = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(size > 1e-12, n / np.maximum(size, 1e-300), np.asarray(straight))


def reached(turn, a, b, c, axes):
    """The hip-ankle distance a leg reaches with its knee turned ``turn`` about ``axes``."""
    theta0, psi = feet.knee_angles(a, b, c, axes)
    return feet.knee_reach(theta0 + turn, np.linalg.norm(b - a, axis=-1), np.linalg.norm(c - b, axis=-1), psi)


def test_knee_bounded_starts_a_lift_from_a_straight_leg_a_few_frames_early():
    # Lifting the ankle 6 cm over three frames bends the nearly straight knee by 35 degrees, 17
    # in the first frame: bounded, the change of the bend accelerates at most KNEE_ACCEL, 0 beside the
    # new frames, and the knee starts to bend before the lift (the held heel rising a little).
    fps = 30.0
    accel = feet.KNEE_ACCEL / fps**2
    goal, a, b, c = straight_leg_lifted()
    before = bends(goal, a, b, c)
    assert np.degrees(np.diff(before).max()) > 15.0
    axes = plane_axes(a, b, c)
    out, bent = feet.knee_bounded(goal, a, b, c, axes, 0.0, accel)
    after = np.concatenate([[0.0], out, [0.0]])
    # (The lift lasts to the last frame, whose change must come to rest at B's frame too.)
    assert np.abs(np.diff(after, 2)).max() <= accel * 1.001 and abs(after[-2]) <= accel * 1.001
    assert bent[:12].any() and after[12] > 0.0  # bending before the lift
    # Where the bound leaves the turn, it reaches the goal's distance.
    np.testing.assert_allclose(reached(out, a, b, c, axes)[~bent], np.linalg.norm(goal - a, axis=-1)[~bent],
                               atol=1e-9)
    # A bound that nothing exceeds leaves every turn as the goals ask.
    slow, none = feet.knee_bounded(goal, a, b, c, axes, 0.0, 10.0)
    assert not none.any()
    np.testing.assert_allclose(slow, before, atol=1e-9)


def test_knee_bounded_sets_a_knee_off_from_as_still_frames_within_the_bound():
    # The lift from the first new frame on: A's frames beside it have no change, so the first
    # frame's change is A's last frame's second difference, and it too stays within the bound
    # (unbounded there, the knee bent 17 degrees from rest in one frame). Likewise the last
    # frame's, at B's side.
    fps = 30.0
    accel = feet.KNEE_ACCEL / fps**2
    goal, a, b, c = straight_leg_lifted(lift_at=0)
    assert bends(goal, a, b, c)[0] > 2 * accel
    out, bent = feet.knee_bounded(goal, a, b, c, plane_axes(a, b, c), 0.0, accel)
    after = np.concatenate([[0.0, 0.0], out])  # A's last two frames, then the new ones
    assert bent[0] and abs(after[2]) <= accel * 1.001 and np.abs(np.diff(after, 2)[:-1]).max() <= accel * 1.001
    assert after[2 + 12] > 0.99 * bends(goal, a, b, c)[12]  # the lift itself reached a few frames on
    assert abs(after[-1]) <= accel * 1.001


def test_knee_bounded_keeps_a_straight_legs_bend_within_the_bound():
    # A straight leg (the knee's own bend 0) bent 0.52 radians in frames 2-11 of 36 at 60 fps:
    # bounded, the change rings below 0 beside the block, and a straight knee cannot bend back,
    # so its bend, clipped at straight, broke the bound (1.67x; a cold review). Within it now.
    n, accel = 36, feet.KNEE_ACCEL / 3600.0
    a = np.zeros((n, 3))
    b = np.tile([0.0, -1.0, 0.0], (n, 1))
    c = np.tile([0.0, -2.0, 0.0], (n, 1))
    goal = c.copy()
    goal[2:12, 1] = -np.sqrt(2.0 + 2.0 * np.cos(0.52))
    out, bent = feet.knee_bounded(goal, a, b, c, plane_axes(a, b, c), 0.0, accel)
    after = out  # the bend itself: the knee's own is 0
    assert bent.any() and after.min() >= 0.0
    assert np.abs(at_rest(after)).max() <= accel * 1.001


def test_knee_bounded_applies_the_iks_soft_reach():
    # A goal beyond the reach is where the IK's soft reach puts it (the IK then runs without it).
    goal, a, b, c = straight_leg_lifted()
    goal[:, 1] -= 3.0  # 3 cm beyond the ankle: out of reach
    axes = plane_axes(a, b, c)
    out, bent = feet.knee_bounded(goal, a, b, c, axes, feet.SOFT_REACH, 10.0)
    assert not bent.any()
    reach = np.linalg.norm(b[0] - a[0]) + np.linalg.norm(c[0] - b[0])
    own = np.linalg.norm(c - a, axis=-1)
    want = feet.soft_limit(np.linalg.norm(goal - a, axis=-1), np.maximum(own, (1 - feet.SOFT_REACH) * reach), reach)
    got = reached(out, a, b, c, axes)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert (got < reach).all()


@pytest.mark.parametrize("seed", range(6))
def test_knee_bounded_is_the_same_compiled(seed):
    from posturemap.core import kernels

    nk = kernels.compiled()
    rng = np.random.default_rng(seed)
    goal, a, b, c = straight_leg_lifted(n=int(rng.integers(4, 40)), lift_at=int(rng.integers(1, 4)), rng=rng)
    for soft, accel in ((0.0, feet.KNEE_ACCEL / 900.0), (feet.SOFT_REACH, feet.KNEE_ACCEL / 3600.0)):
        axes = plane_axes(a, b, c)
        want, bent = feet.knee_bounded(goal, a, b, c, axes, soft, accel)
        gpos = np.stack([a, b, c], axis=1)
        work, moves = np.empty((4, len(goal))), np.zeros(len(goal), dtype=bool)
        nk.knee_bounded(goal, gpos, axes, 0, 1, 2, soft, feet.KNEE_THROUGH, accel, rest.REST_PASSES, rest.REST_PLAIN,
                        rest.REST_RELAX, rest.REST_EXACT, work, moves)
        np.testing.assert_allclose(work[0], want, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(moves, bent)
