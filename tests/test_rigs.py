"""Rigs from other tools: a game rig's IK targets beside the body, toes below a mid-foot joint,
skeletons built in another joint order than a file's."""

from __future__ import annotations

import numpy as np

from posturemap.core import kernels
from posturemap.core.joints import key_joints, leg_chains, leg_toes
from posturemap.core.motion import Motion, root_index, up_axis
from posturemap.core.skeleton import Skeleton
from posturemap.io import bvh


def with_ik_targets(m: Motion) -> Motion:
    """``m`` as Unreal's mannequin lays it out: a ``root`` at the origin above the hips, and
    beside the body the IK targets ``ik_foot_root > ik_foot_l/r`` and ``ik_hand_root >
    ik_hand_gun > ik_hand_l/r``, left where they are (as exported from a rig that does not
    animate them)."""
    sk = m.skeleton
    extra = [("ik_foot_root", 0), ("ik_foot_l", 1), ("ik_foot_r", 1), ("ik_hand_root", 0), ("ik_hand_gun", 4),
             ("ik_hand_l", 5), ("ik_hand_r", 5)]
    names = ("root",) + tuple(n for n, _ in extra) + sk.names
    shift = 1 + len(extra)
    parents = np.array([-1] + [p for _, p in extra] + [p + shift if p >= 0 else 0 for p in sk.parents])
    offsets = np.vstack([np.zeros((shift, 3)), sk.offsets])
    offsets[1:shift] = [[0, 0, 0], [10, 5, 0], [-10, 5, 0], [0, 0, 0], [0, 100, 30], [20, 0, 0], [-20, 0, 0]]
    pos6 = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
    channels = (pos6,) + (pos6,) * len(extra) + sk.channels
    ends = tuple((j + shift, o) for j, o in sk.end_sites)
    out = Skeleton(names, parents, offsets, channels, ends)
    f = len(m)
    rots = np.concatenate([np.tile([1.0, 0, 0, 0], (f, shift, 1)), m.rotations], axis=1)
    pos = np.concatenate([np.broadcast_to(offsets[:shift], (f, shift, 3)), m.positions], axis=1)
    return Motion(out, rots, pos.copy(), m.fps)


def test_a_game_rigs_ik_targets_are_not_the_body(sample_clips):
    # The IK targets under the root put the hips' subtree under 90% of the joints, and the body
    # walks away from them: the root is still the hips, the up axis still Y, the hands the hands.
    m = sample_clips["walk"]
    ue = with_ik_targets(m)
    sk = ue.skeleton
    hips = sk.names.index("Hips")
    assert root_index(ue) == hips and root_index(m) == 0
    assert up_axis(ue) == up_axis(m) == 1
    lower, upper = key_joints(sk)
    assert sorted(sk.names[j] for j in upper) == ["Hand_L", "Hand_R", "Head"]
    assert [sk.names[j] for j in lower] == [m.skeleton.names[j] for j in key_joints(m.skeleton)[0]]
    # The hips' offset (where a recording starts) and the targets are not bones: another take
    # with them elsewhere is the same rig.
    other = Skeleton(sk.names, sk.parents, sk.offsets * np.where(np.arange(sk.num_joints)[:, None] <= hips, 3.0, 1.0),
                     sk.channels, sk.end_sites)
    assert sk.body_mismatch(other) is None
    metres = Skeleton(sk.names, sk.parents, sk.offsets / 100.0, sk.channels, sk.end_sites)
    assert "another unit" in sk.body_mismatch(metres)


def test_the_toe_is_the_toe_not_the_middle_of_the_foot():
    # Daz: lFoot > lMetatarsals > lToe > the toes; Mixamo: LeftToeBase > LeftToe_End.
    names = ("hip", "lThigh", "lShin", "lFoot", "lMetatarsals", "lToe", "lBigToe", "lSmallToe1",
             "rThigh", "rShin", "rFoot", "RightToeBase", "RightToe_End")
    parents = np.array([-1, 0, 1, 2, 3, 4, 5, 5, 0, 8, 9, 10, 11])
    offsets = np.array([[0, 90, 0], [10, 0, 0], [0, -42, 0], [0, -42, 0], [0, -3, 5], [0, -3, 5], [2, 0, 3],
                        [-2, 0, 3], [-10, 0, 0], [0, -42, 0], [0, -42, 0], [0, -6, 10], [0, 0, 5]], dtype=float)
    sk = Skeleton(names, parents, offsets, (("Xrotation",),) * len(names))
    assert [sk.names[j] for j in leg_toes(sk)] == ["lToe", "RightToeBase"]
    assert [sk.names[c[2]] for c in leg_chains(sk)] == ["lFoot", "rFoot"]


def test_a_skeleton_in_another_joint_order_is_written_as_it_moves(sample_clips, tmp_path):
    # Parents come before children, but not depth first (both thighs, then both shins...), with
    # six channels on some joints and three on others: the file's MOTION lines follow its
    # hierarchy, and it reads back as the same motion.
    m = sample_clips["walk"]
    sk = m.skeleton
    order = [0] + [j for j in range(1, sk.num_joints) if sk.parents[j] == 0]
    while len(order) < sk.num_joints:
        order += [j for j in range(sk.num_joints) if j not in order and sk.parents[j] in order]
    new_of = {j: i for i, j in enumerate(order)}
    assert order != sorted(order)
    shuffled = Skeleton(tuple(sk.names[j] for j in order),
                        np.array([new_of[int(sk.parents[j])] if sk.parents[j] >= 0 else -1 for j in order]),
                        sk.offsets[order], tuple(sk.channels[j] for j in order),
                        tuple((new_of[j], o) for j, o in sk.end_sites))
    moved = Motion(shuffled, m.rotations[:, order], m.positions[:, order], m.fps)
    path = tmp_path / "shuffled.bvh"
    bvh.write(path, moved)
    back = bvh.read(path)
    g = moved.global_positions()
    gb = back.global_positions()
    names = list(back.skeleton.names)
    np.testing.assert_allclose(gb[:, [names.index(n) for n in shuffled.names]], g, atol=1e-4)


def two_legs(names_left, names_right, above=("Reference", "Hips"), upper=("Spine", "Head")):
    """A skeleton: ``above`` in a chain (the first and last with position channels), the two legs
    and ``upper`` (a chain) hanging from its last joint, each joint 10 units below (legs) or above
    (spine) its parent."""
    names = list(above) + list(names_left) + list(names_right) + list(upper)
    parents, offsets = [], []
    for i, _ in enumerate(above):
        parents.append(i - 1)
        offsets.append([0.0, 90.0 if i else 0.0, 0.0])
    hip = len(above) - 1
    for chain, side in ((names_left, 1.0), (names_right, -1.0)):
        for k, _ in enumerate(chain):
            parents.append(hip if k == 0 else len(parents) - 1)
            offsets.append([10.0 * side, 0.0, 0.0] if k == 0 else [0.0, -10.0, 0.0])
    for k, _ in enumerate(upper):
        parents.append(hip if k == 0 else len(parents) - 1)
        offsets.append([0.0, 10.0, 0.0])
    pos6 = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
    return Skeleton(tuple(names), np.array(parents), np.array(offsets),
                    tuple(pos6 if p < 0 or n == above[-1] else ("Zrotation", "Xrotation", "Yrotation")
                          for n, p in zip(names, parents)))


def test_legs_whose_bones_differ_by_a_number_only_keep_their_thigh():
    # L_Leg1 > L_Leg2 > L_Foot: merging the numbered segments would give both legs the hips as
    # their thigh; the plain parent and grandparent instead.
    sk = two_legs(("L_Leg1", "L_Leg2", "L_Foot"), ("R_Leg1", "R_Leg2", "R_Foot"))
    assert [tuple(sk.names[j] for j in c) for c in leg_chains(sk)] == [("L_Leg1", "L_Leg2", "L_Foot"),
                                                                      ("R_Leg1", "R_Leg2", "R_Foot")]


def test_a_roll_joint_named_like_a_foot_is_passed_through_to_the_ankle():
    sk = two_legs(("LeftUpLeg", "LeftLeg", "LeftFootRoll", "LeftFoot", "LeftToeBase"),
                  ("RightUpLeg", "RightLeg", "RightFootRoll", "RightFoot", "RightToeBase"))
    assert [tuple(sk.names[j] for j in c) for c in leg_chains(sk)] == [("LeftUpLeg", "LeftLeg", "LeftFoot"),
                                                                      ("RightUpLeg", "RightLeg", "RightFoot")]
    assert [sk.names[j] for j in leg_toes(sk)] == ["LeftToeBase", "RightToeBase"]


def test_the_root_holds_the_head_and_hands_too():
    # Legs under a pelvis that holds half the joints, the spine beside it under the top joint:
    # the pelvis is not the body's root.
    sk = two_legs(("LeftUpLeg", "LeftUpLegTwist", "LeftLeg", "LeftLegTwist", "LeftFoot", "LeftToeBase"),
                  ("RightUpLeg", "RightUpLegTwist", "RightLeg", "RightLegTwist", "RightFoot", "RightToeBase"),
                  above=("Root", "Pelvis"), upper=())
    spine = ("Spine", "Chest", "Neck", "Head")
    names = sk.names + spine
    parents = np.concatenate([sk.parents, [0, len(sk.names), len(sk.names) + 1, len(sk.names) + 2]])
    offsets = np.vstack([sk.offsets, [[0, 100, 0], [0, 10, 0], [0, 20, 0], [0, 10, 0]]])
    full = Skeleton(names, parents, offsets, sk.channels + (("Zrotation", "Xrotation", "Yrotation"),) * 4)
    assert full.names[root_index(full)] == "Root"
    assert sk.names[root_index(sk)] == "Pelvis"  # no head or hands named elsewhere: the legs' joint
    _, upper = key_joints(full)
    assert [full.names[j] for j in upper] == ["Head"]


def test_offsets_near_the_float_limit_are_refused_in_one_line(sample_clips):
    # A bone of 1e308 units: its length overflows; said as such (no numpy warning on stderr),
    # naming whichever skeleton holds it.
    import warnings

    sk = sample_clips["walk"].skeleton
    offsets = sk.offsets.copy()
    offsets[sk.names.index("Spine")] = 1e308
    huge = Skeleton(sk.names, sk.parents, offsets, sk.channels, sk.end_sites)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert huge.body_mismatch(sk) == "its bone offsets are too large to be lengths"
        assert sk.body_mismatch(huge, "A's") == "A's bone offsets are too large to be lengths"
        assert sk.body_mismatch(sk) is None


def rigify_like(face: bool = False, neck_segments: int = 2) -> Skeleton:
    """Blender Rigify's deform bones as a BVH export names them: the hands are named, the head
    is not (``DEF-spine.006``, the top of the neck chain), breast bones beside the neck."""
    joints = [("DEF-spine", -1, (0, 95, 0))]

    def add(name, parent, offset):
        joints.append((name, [n for n, _, _ in joints].index(parent), offset))

    for side, x in (("L", 9), ("R", -9)):
        add(f"DEF-thigh.{side}", "DEF-spine", (x, 0, 0))
        add(f"DEF-shin.{side}", f"DEF-thigh.{side}", (0, -43, 0))
        add(f"DEF-foot.{side}", f"DEF-shin.{side}", (0, -43, 0))
        add(f"DEF-toe.{side}", f"DEF-foot.{side}", (0, -6, 10))
    add("DEF-spine.001", "DEF-spine", (0, 12, 0))
    add("DEF-spine.002", "DEF-spine.001", (0, 12, 0))
    add("DEF-spine.003", "DEF-spine.002", (0, 12, 0))
    for side, x in (("L", 1), ("R", -1)):
        add(f"DEF-breast.{side}", "DEF-spine.003", (x * 9, 0, 8))
        add(f"DEF-shoulder.{side}", "DEF-spine.003", (x * 3, 10, 0))
        add(f"DEF-upper_arm.{side}", f"DEF-shoulder.{side}", (x * 15, 0, 0))
        add(f"DEF-forearm.{side}", f"DEF-upper_arm.{side}", (x * 28, 0, 0))
        add(f"DEF-hand.{side}", f"DEF-forearm.{side}", (x * 25, 0, 0))
        add(f"DEF-f_index.01.{side}", f"DEF-hand.{side}", (x * 8, 0, 0))
    neck = [f"DEF-spine.{4 + i:03d}" if neck_segments == 2 else f"DEF-neck.{i:03d}"
            for i in range(neck_segments)] + ["DEF-spine.006"]
    for parent, name in zip(["DEF-spine.003"] + neck, neck):
        add(name, parent, (0, 8, 0))
    if face:
        for name in ("DEF-jaw", "DEF-eye.L", "DEF-eye.R"):
            add(name, "DEF-spine.006", (0, 5, 6))
    names = tuple(n for n, _, _ in joints)
    parents = np.array([p for _, p, _ in joints])
    offsets = np.array([o for _, _, o in joints], dtype=float)
    channels = (("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),) \
        + (("Zrotation", "Xrotation", "Yrotation"),) * (len(names) - 1)
    return Skeleton(names, parents, offsets, channels)


def test_a_rig_that_does_not_name_its_head_matches_the_top_of_its_neck():
    # Rigify's head is DEF-spine.006: the arms meet at DEF-spine.003, whose other children are
    # the breast bones and the neck chain; the neck chain's top is the head, with or without
    # face joints below it, however many neck segments there are.
    for face, segments in ((False, 2), (True, 2), (False, 40)):
        sk = rigify_like(face, segments)
        lower, upper = key_joints(sk)
        assert [sk.names[j] for j in upper] == ["DEF-hand.L", "DEF-hand.R", "DEF-spine.006"], (face, segments)
        assert sorted(sk.names[j] for j in lower) == ["DEF-foot.L", "DEF-foot.R", "DEF-shin.L", "DEF-shin.R"]
    # A named head is taken as before, and hands that do not meet (one hand only) add no head.
    sk = rigify_like()
    named = Skeleton(tuple("Head" if n == "DEF-spine.005" else n for n in sk.names), sk.parents, sk.offsets,
                     sk.channels)
    assert named.names[key_joints(named)[1][-1]] == "Head"
    one_hand = Skeleton(tuple("DEF-palm.R" if n == "DEF-hand.R" else n for n in sk.names), sk.parents, sk.offsets,
                        sk.channels)
    assert [one_hand.names[j] for j in key_joints(one_hand)[1]] == ["DEF-hand.L"]


def test_the_upper_bodys_top_is_the_spine_not_a_hip_joint(cmu_file, sample_clips):
    # The joints retrieval turns toward the upper segments' own pelvis (retrieval.lift_upper):
    # CMU's LHipJoint / RHipJoint hang from the hips above the thighs, outside the legs' subtree
    # (so in the upper mask), but turning them would move the legs.
    from posturemap.core.joints import part_masks, upper_tops
    for sk, expected in ((bvh.read(cmu_file).skeleton, ["LowerBack"]), (sample_clips["walk"].skeleton, ["Spine"])):
        root = root_index(sk)
        lower, upper = part_masks(sk, root)
        assert [sk.names[j] for j in upper_tops(sk.parents, root, lower, upper)] == expected
    sk = bvh.read(cmu_file).skeleton
    lower, upper = part_masks(sk, root_index(sk))
    assert upper[sk.index("LHipJoint")] and upper[sk.index("RHipJoint")]


def test_arm_chains_find_upper_arm_forearm_and_hand_past_twist_joints(cmu_file, sample_clips):
    # The elbows held to how far back the library's go (synth.hinges) need each arm's chain.
    from posturemap.core.joints import arm_chains

    def chains(sk):
        return [tuple(sk.names[j] for j in c) for c in arm_chains(sk)]

    assert chains(bvh.read(cmu_file).skeleton) == [("LeftArm", "LeftForeArm", "LeftHand"),
                                                   ("RightArm", "RightForeArm", "RightHand")]
    assert chains(sample_clips["walk"].skeleton) == [("UpperArm_L", "LowerArm_L", "Hand_L"),
                                                     ("UpperArm_R", "LowerArm_R", "Hand_R")]
    # Not a game rig's IK targets beside the body (ik_hand_root > ik_hand_gun > ik_hand_l).
    assert chains(with_ik_targets(sample_clips["walk"]).skeleton) == [("UpperArm_L", "LowerArm_L", "Hand_L"),
                                                                      ("UpperArm_R", "LowerArm_R", "Hand_R")]
    # SMPL names the wrist and a hand below it: the wrist ends the arm.
    legs = ("L_Hip", "L_Knee", "L_Ankle"), ("R_Hip", "R_Knee", "R_Ankle")
    sk = two_legs(*legs, upper=("Spine", "L_Shoulder", "L_Elbow", "L_Wrist", "L_Hand"))
    assert chains(sk) == [("L_Shoulder", "L_Elbow", "L_Wrist")]
    # A roll joint inside the forearm is passed through.
    sk = two_legs(*legs, upper=("Spine", "LeftArm", "LeftForeArm", "LeftForeArmRoll", "LeftHand", "LeftHandIndex1"))
    assert chains(sk) == [("LeftArm", "LeftForeArm", "LeftHand")]


def test_a_rig_whose_offsets_are_all_zero_still_makes_finite_transitions(sample_clips):
    # Every joint at the root's place (offsets zeroed: a rig exported without its rest pose):
    # speeds and distances divided by the legs' length divided by zero (a traceback, or NaN
    # frames from the foot lock). The legs have no length, so the scale is the one of a rig without legs.
    import posturemap
    from posturemap.core.joints import leg_length

    m = sample_clips["walk"]
    sk = m.skeleton
    flat = Skeleton(sk.names, sk.parents, np.zeros_like(sk.offsets), sk.channels, sk.end_sites)
    pos = m.positions.copy()
    pos[:, 1:] = 0.0
    z = Motion(flat, m.rotations.copy(), pos, m.fps)
    assert leg_chains(flat) and leg_length(flat) == 1.0
    model = posturemap.PostureMap(seed=0).fit([z])
    for method in posturemap.METHODS:
        for align in (True, False):
            out = posturemap.transition(z, z, model, length=15, a_end=20, b_start=40, method=method, align=align)
            assert np.isfinite(out.rotations).all() and np.isfinite(out.positions).all(), (method, align)
    # The numpy foot lock too, and a leg that cannot bend is left as it is: the same frames as without the lock.
    with kernels.numpy_backend(), np.errstate(all="raise"):
        locked = posturemap.transition(z, z, model, length=15, a_end=20, b_start=40, method="slerp")
        free = posturemap.transition(z, z, model, length=15, a_end=20, b_start=40, method="slerp", foot_lock=False)
    np.testing.assert_allclose(locked.rotations, free.rotations, atol=1e-12)


def test_legs_are_read_from_the_hierarchy_where_no_name_says_so(bandai_files, cmu_file, sample_clips):
    # Named J00, J01...: no leg was found, so nothing was locked and retrieval's lower body was the
    # root alone (a cold evaluation measured 28-91 cm/s of foot skate where the named rig gives
    # 1-6). The hierarchy's legs are the names' legs on each rig here, a hip joint above the
    # thigh (CMU's LHipJoint) and the toes below the ankle left out.
    from posturemap.core.joints import structural_legs
    from rigkit import bare

    for sk in (bvh.read(bandai_files[0]).skeleton, bvh.read(cmu_file).skeleton, sample_clips["walk"].skeleton):
        assert structural_legs(sk.parents, sk.offsets) == sorted(leg_chains(sk)) != []
    walk = sample_clips["walk"]
    assert leg_chains(bare(walk).skeleton) == leg_chains(walk.skeleton)
    # Legs that are not alike are no pair; and the arms, alike, hang from the chest, where the
    # neck is no bigger than they are: they are not taken for legs.
    assert leg_chains(bare(walk, unalike=True).skeleton) == []
    # Hands with fingers end the arms' chains at the fork: the arms are still found, the hand
    # is the hand (not a fingertip), and the legs stay the legs.
    from posturemap.core.joints import arm_chains, structural_arms

    sk = bare(walk).skeleton
    names, parents, offsets = list(sk.names), list(sk.parents), list(sk.offsets)
    for hand in (walk.skeleton.names.index("Hand_L"), walk.skeleton.names.index("Hand_R")):
        for finger in range(3):
            for segment in range(2):
                parents.append(hand if segment == 0 else len(names) - 1)
                offsets.append(np.array([2.0 + finger, 1.0, 0.0]) if segment == 0 else np.array([2.5, 0.0, 0.0]))
                names.append(f"J{len(names):02d}")
    fingered = Skeleton(tuple(names), np.array(parents), np.array(offsets), tuple(sk.channels) + (sk.channels[-1],) * (
        len(names) - sk.num_joints), sk.end_sites, sk.euler_style)
    assert leg_chains(fingered) == leg_chains(walk.skeleton)
    assert arm_chains(fingered) == structural_arms(fingered, leg_chains(fingered)) == arm_chains(walk.skeleton)


def test_a_rig_named_j00_j01_makes_the_named_rigs_transitions(sample_clips):
    # The bone classes and the legs read from the hierarchy are the names' (a thigh and an upper
    # arm global, a shin and a forearm medium, a foot and a hand detail, the neck and head
    # medium), so that a rig in another language, or numbered, moves as the named one does.
    from posturemap.learn.features import assign_classes
    from posturemap.learn.model import PostureMap
    from posturemap.synth.engine import transition
    from rigkit import bare

    from posturemap.core.joints import arm_chains, head_joint, structural_arms

    walk, run_ = sample_clips["walk"], sample_clips["run"]
    sk, numbered_sk = walk.skeleton, bare(walk).skeleton
    root = root_index(walk)
    assert (assign_classes(numbered_sk, root) == assign_classes(sk, root)).all()
    # The arms (their elbows bend one way), the hands and the head retrieval matches: the names'.
    assert structural_arms(sk, leg_chains(sk)) == arm_chains(numbered_sk) == arm_chains(sk) != []
    assert [k.tolist() for k in key_joints(numbered_sk)] == [k.tolist() for k in key_joints(sk)]
    assert head_joint(numbered_sk) == head_joint(sk) == sk.names.index("Head")
    named = PostureMap(seed=0).fit([walk, run_])
    numbered = PostureMap(seed=0).fit([bare(walk), bare(run_)])
    for method, align in (("auto", True), ("auto", False), ("spline", True)):
        x = transition(walk, run_, named, method=method, align=align, length=20, a_end=40, b_start=10)
        y = transition(bare(walk), bare(run_), numbered, method=method, align=align, length=20, a_end=40, b_start=10)
        assert np.array_equal(x.rotations, y.rotations) and np.array_equal(x.positions, y.positions), (method, align)


def _numbered_rig(joints):
    """A skeleton from ``(name, parent name or None, offset)`` rows, its joints then renamed J00,
    J01... (no name rule knows them); returns it and each original name's index."""
    names = [n for n, _, _ in joints]
    index = {n: i for i, n in enumerate(names)}
    parents = np.array([-1 if p is None else index[p] for _, p, _ in joints])
    offsets = np.array([o for _, _, o in joints], dtype=float)
    channels = tuple(("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation") if p is None
                     else ("Zrotation", "Xrotation", "Yrotation") for _, p, _ in joints)
    return Skeleton(tuple(f"J{j:02d}" for j in range(len(names))), parents, offsets, channels), index


def _human(pelvis_beside_spine=False, twist=False, skirt=0, face=0, heel=False):
    top = "Pelvis" if pelvis_beside_spine else "Hips"
    rows = [("Hips", None, (0, 90, 0))] + ([("Pelvis", "Hips", (0, 0, 0))] if pelvis_beside_spine else [])
    rows += [("Spine", "Hips", (0, 10, 0)), ("Chest", "Spine", (0, 25, 0)), ("Neck", "Chest", (0, 15, 0)),
             ("Head", "Neck", (0, 10, 0))]
    rows += [(f"Face{i}", "Head", (i - 3.5, 5, 8)) for i in range(face)]
    for s, x in (("L", 1), ("R", -1)):
        rows += [(f"Shoulder{s}", "Chest", (x * 4, 8, 0)), (f"UpperArm{s}", f"Shoulder{s}", (x * 14, 0, 0)),
                 (f"ForeArm{s}", f"UpperArm{s}", (x * 28, 0, 0)), (f"Hand{s}", f"ForeArm{s}", (x * 25, 0, 0))]
        rows += [(f"Thigh{s}", top, (x * 9, 0, 0))]
        shin_parent = f"Thigh{s}"
        if twist:  # a roll helper at the thigh's place, another at the shin's: both in their parent's bone
            rows += [(f"ThighTwist{s}", f"Thigh{s}", (0, 0, 0))]
            shin_parent = f"ThighTwist{s}"
        rows += [(f"Shin{s}", shin_parent, (0, -42, 0))]
        foot_parent = f"Shin{s}"
        if twist:
            rows += [(f"ShinTwist{s}", f"Shin{s}", (0, 0, 0))]
            foot_parent = f"ShinTwist{s}"
        rows += [(f"Foot{s}", foot_parent, (0, -40, 0)), (f"Toe{s}", f"Foot{s}", (0, -5, 12)),
                 (f"ToeEnd{s}", f"Toe{s}", (0, 0, 4))]
        if heel:  # the foot forks: a heel chain beside the toes
            rows += [(f"Heel{s}", f"Foot{s}", (0, -4, -5)), (f"HeelEnd{s}", f"Heel{s}", (0, 0, -2))]
    for i in range(skirt):  # cloth chains round the hips, shorter than the legs
        rows += [(f"Skirt{i}a", "Hips", (8 * np.cos(i), -5, 8 * np.sin(i))), (f"Skirt{i}b", f"Skirt{i}a", (0, -12, 0)),
                 (f"Skirt{i}c", f"Skirt{i}b", (0, -12, 0))]
    return _numbered_rig(rows)


def test_the_hierarchys_legs_and_arms_past_helpers_skirts_faces_and_a_pelvis_beside_the_spine(cmu_file):
    # Found by a cold review: twist helpers at their parent's place made the toes an ankle, a
    # skirt's chains or a big face were taken for legs or made the arms legs, legs hanging from
    # a pelvis beside the spine were missed, and CMU's clavicle (longer than its forearm) was read
    # as its upper arm.
    from posturemap.core.joints import structural_arms, structural_legs

    for kind in ({}, {"twist": True}, {"skirt": 4}, {"face": 8}, {"pelvis_beside_spine": True},
                 {"pelvis_beside_spine": True, "face": 8}, {"heel": True}):
        sk, at = _human(**kind)
        legs = structural_legs(sk.parents, sk.offsets)
        assert legs == [(at[f"Thigh{s}"], at[f"Shin{s}"], at[f"Foot{s}"]) for s in "LR"], kind
        assert leg_chains(sk) == legs
        arms = [(at[f"UpperArm{s}"], at[f"ForeArm{s}"], at[f"Hand{s}"]) for s in "LR"]
        assert structural_arms(sk, legs) == arms, kind
    cmu = bvh.read(cmu_file).skeleton
    numbered = Skeleton(tuple(f"J{j:02d}" for j in range(cmu.num_joints)), cmu.parents, cmu.offsets, cmu.channels)
    from posturemap.core.joints import arm_chains

    assert arm_chains(numbered) == arm_chains(cmu) == [tuple(cmu.names.index(n) for n in (f"{s}Arm", f"{s}ForeArm",
                                                                                         f"{s}Hand"))
                                                        for s in ("Left", "Right")]
    assert [k.tolist() for k in key_joints(numbered)] == [k.tolist() for k in key_joints(cmu)]
    # Its bone classes too: a hip joint at the pelvis's place above each thigh (LHipJoint) is the
    # pelvis's, as its name makes it; the rest as a human's limbs.
    from posturemap.learn.features import assign_classes

    root = root_index(cmu)
    assert root_index(numbered) == root
    assert assign_classes(numbered, root).tolist() == assign_classes(cmu, root).tolist()
