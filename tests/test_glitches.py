"""Glitch steps in recorded rotations (core/glitches.py) and what the engine makes of them."""

from __future__ import annotations

import numpy as np
import pytest

from posturemap.core import glitches, quat
from posturemap.core.glitches import glitch_steps, glitch_turn, steadied
from posturemap.core.motion import Motion
from posturemap.io import bvh
from posturemap.learn.model import PostureMap
from posturemap.synth.engine import TransitionEngine

FPS = 30.0
N = 120


def swinging(seed: int = 0, n: int = N, fps: float = FPS) -> np.ndarray:
    """(n, 4, 4) local rotations: four joints swinging about random axes, the fastest at 30
    rad/s at its peak (57 degrees a frame at 30 fps, near the fastest Bandai joint's 35)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fps
    axes = rng.normal(size=(4, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    amp = np.array([0.3, 0.8, 1.2, 1.0])
    omega = np.array([4.0, 9.0, 25.0, 2.0])  # peak rates 1.2, 7.2, 30, 2 rad/s
    phase = rng.uniform(0, 2 * np.pi, 4)
    base = quat.exp(rng.normal(scale=0.5, size=(4, 3)))
    angle = amp * np.sin(omega * t[:, None] + phase)
    return quat.mul(quat.exp(axes * angle[..., None]), base)


def half_turn(axis=(1.0, 0.0, 0.0)) -> np.ndarray:
    return quat.from_axis_angle(np.asarray(axis, dtype=float), np.array(np.pi))


def test_real_swings_have_no_glitch_and_come_back_as_they_are():
    q = swinging()
    assert not glitch_steps(q, FPS).any()
    assert steadied(q, FPS) is q
    # A joint turning 80 degrees a frame at a steady rate (a fast spin) is not a glitch: the
    # frames around each step say it.
    spin = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), np.radians(80.0) * np.arange(20))[:, None]
    assert not glitch_steps(spin, FPS).any()


def test_a_flipped_run_is_two_glitch_steps_and_is_turned_back():
    q = swinging(1)
    bad = q.copy()
    bad[40:50, 1] = quat.mul(half_turn(), q[40:50, 1])  # half a turn, as a solver flips a toe
    g = glitch_steps(bad, FPS)
    assert {tuple(x) for x in np.argwhere(g)} == {(39, 1), (49, 1)}
    out = steadied(bad, FPS)
    assert out is not bad
    others = np.ones(4, dtype=bool)
    others[1] = False
    assert np.array_equal(out[:, others], bad[:, others])  # the other joints untouched
    assert np.array_equal(out[:40, 1], bad[:40, 1]) and np.array_equal(out[50:, 1], bad[50:, 1])
    # The run continues the frame before it with no step, keeps its own frame-to-frame turns,
    # and leads into the frame after it within the step of the frames around it.
    assert quat.angle_between(out[39, 1], out[40, 1]) < 1e-6
    np.testing.assert_allclose(quat.angle_between(out[40:50, 1][1:], out[40:50, 1][:-1]),
                               quat.angle_between(q[40:50, 1][1:], q[40:50, 1][:-1]), atol=1e-7)
    own = quat.angle_between(q[38:52, 1][1:], q[38:52, 1][:-1]).max()
    assert quat.angle_between(out[49, 1], out[50, 1]) <= 2.0 * own + 1e-9
    assert not glitch_steps(out, FPS).any()


def test_a_one_frame_spike_is_levelled():
    q = swinging(2)
    bad = q.copy()
    bad[60, 2] = quat.mul(quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(2.0)), q[60, 2])
    assert {tuple(x) for x in np.argwhere(glitch_steps(bad, FPS))} == {(59, 2), (60, 2)}
    out = steadied(bad, FPS)
    assert quat.angle_between(out[60, 2], bad[59, 2]) < 1e-6
    mask = np.ones(out.shape[:2], dtype=bool)
    mask[60, 2] = False
    assert np.array_equal(out[mask], bad[mask])


def test_a_first_frame_in_a_reference_pose_takes_the_second_frames_pose():
    q = swinging(3)
    bad = q.copy()
    # Arms out: 100 and 110 degrees from the second frame's pose.
    bad[0, [0, 3]] = quat.mul(quat.exp(np.array([[0.0, 0.0, 1.75], [1.92, 0.0, 0.0]])), q[1, [0, 3]])
    assert {tuple(x) for x in np.argwhere(glitch_steps(bad, FPS))} == {(0, 0), (0, 3)}
    out = steadied(bad, FPS)
    np.testing.assert_allclose(quat.angle_between(out[0, [0, 3]], bad[1, [0, 3]]), 0.0, atol=1e-6)
    assert np.array_equal(out[1:], bad[1:]) and np.array_equal(out[0, [1, 2]], bad[0, [1, 2]])


def test_the_bound_is_a_rate_a_30_degree_spike_is_a_glitch_at_120_fps_only():
    assert glitch_turn(30.0) == pytest.approx(np.pi / 2)
    assert glitch_turn(120.0) == pytest.approx(np.pi / 8)
    assert glitch_turn(20.0) == pytest.approx(0.75 * np.pi)  # a constant rate, at most 135 degrees
    assert glitch_turn(10.0) == pytest.approx(0.75 * np.pi)
    for fps, expected in ((120.0, True), (30.0, False)):
        q = swinging(4, fps=fps)
        bad = q.copy()
        bad[50, 0] = quat.mul(quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), np.radians(30.0)), q[50, 0])
        assert glitch_steps(bad, fps)[49, 0] == expected, fps


def test_a_lone_step_between_two_long_pieces_is_left():
    # A joint that turns 120 degrees in a frame and stays: either side could be the wrong one.
    q = swinging(5)
    bad = q.copy()
    bad[60:, 1] = quat.mul(quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(120.0)), q[60:, 1])
    assert glitch_steps(bad, FPS)[59, 1]
    assert np.array_equal(steadied(bad, FPS), bad)


def test_short_clips_have_no_glitch():
    q = swinging(6)[:2].copy()
    q[1, 0] = quat.mul(half_turn(), q[1, 0])
    assert not glitch_steps(q, FPS).any() and not glitch_steps(q[:1], FPS).any()


def test_a_real_start_or_stop_is_no_glitch():
    # A joint swinging fast stops dead (or starts from rest): the still side predicts the step
    # badly, the moving side well. Only a step both sides miss is a glitch; with either, a
    # forearm stopping at 30 degrees a frame at 120 fps was one.
    fps = 120.0
    angle = np.concatenate([np.zeros(20), np.radians(30.0) * np.arange(1, 21), np.full(20, np.radians(600.0))])
    q = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), angle)[:, None]
    assert not glitch_steps(q, fps).any()
    assert not glitch_steps(q[::-1].copy(), fps).any()
    # Bandai's dance at 15 fps: an upper arm swinging 93 degrees a frame onto a stop is real.
    slow = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.radians([0.0, 0.0, 0.0, 93.0, 186.0, 186.0, 186.0]))
    assert not glitch_steps(slow[:, None], 15.0).any()


def test_a_flip_at_the_start_and_one_later_are_both_turned_back():
    # Frame 0 flipped and frames 40-49: the end's piece is turned first, so that the clean
    # stretch between is not turned onto the first flip (all of frames 0-49 were left flipped).
    q = swinging(7)
    bad = q.copy()
    for frames in (slice(0, 1), slice(40, 50)):
        bad[frames, 1] = quat.mul(half_turn(), q[frames, 1])
    out = steadied(bad, FPS)
    off = quat.angle_between(out[:, 1], q[:, 1])
    step = quat.angle_between(q[1:, 1], q[:-1, 1])
    # Each turned piece continues its neighbour with no step: off the clean frames by one step.
    assert off[1:40].max() < 1e-6 and off[50:].max() < 1e-6, np.degrees(off[:52])
    assert off[0] <= step[0] + 1e-6 and off[40:50].max() <= step[39] + 1e-6, np.degrees(off[:52])
    assert not glitch_steps(out, FPS).any()


def test_a_clip_mostly_flipped_stays_as_it_mostly_is():
    # Frame 0 as the other clips hold the toe, frames 1-60 flipped, 61-89 not, 90-119 flipped
    # again (Xia's sexy_01_001): steadied onto the state most of its frames are in.
    q = swinging(8)
    bad = q.copy()
    for frames in (slice(1, 61), slice(90, N)):
        bad[frames, 2] = quat.mul(half_turn((0.0, 1.0, 0.0)), q[frames, 2])
    out = steadied(bad, FPS)
    kept = np.all(out[:, 2] == bad[:, 2], axis=-1)
    assert kept.sum() >= N / 2 and kept[1:61].all() and kept[90:].all()
    assert not glitch_steps(out, FPS).any()


def test_a_seam_window_keeps_the_seam_and_its_motion_past_a_flip():
    # A's last 30 frames, a toe flipped in the first 20 of them, from the parent's side or the
    # joint's own: the seam frame is as given, and the frames before it continue it at the
    # joint's own velocity (the flip undone from the same side it was made: told by which
    # continues the seam side's velocity the better, here a joint swinging at up to 7 rad/s).
    q = swinging(9)
    flips = (lambda r: quat.mul(half_turn(), r), lambda r: quat.mul(r, half_turn()))
    for flip in flips:
        bad = q.copy()
        bad[:70, 1] = flip(q[:70, 1])
        first, rows = glitches.seam_window(bad, FPS, 89, False, 29)
        assert first == 60 and np.array_equal(rows[-1], bad[89])
        steps = quat.angle_between(rows[1:, 1], rows[:-1, 1])
        own = quat.angle_between(q[61:90, 1], q[60:89, 1])
        np.testing.assert_allclose(np.delete(steps, 9), np.delete(own, 9), atol=1e-6)
        assert steps[9] < 1e-6  # the flip's step, now none
        # Past the flip, the clean frames turned by one rotation from the side the flip was
        # made on: the joint's motion there as the clean frames' (the other side's turn would
        # spin its axis by the half turn).
        left = quat.mul(rows[:10, 1], quat.inv(q[60:70, 1]))
        right = quat.mul(quat.inv(q[60:70, 1]), rows[:10, 1])
        kept = left if flip is flips[0] else right
        assert quat.angle_between(kept, kept[:1]).max() < 1e-6
    assert glitches.seam_window(q, FPS, 89, False, 29) is None


def test_a_flip_about_the_bone_right_after_the_seam_is_undone_on_the_joints_own_side():
    # B's frame 1 on flipped half a turn about the bone (q F, as a solver flips a toe): no frame
    # on the seam's side tells the velocity, and the turn back is made from the joint's own
    # side, so its motion past the seam is the clean frames' (from the parent's side the bone's
    # bend came out mirrored, 11.5 degrees off within ten frames in the median of 1,410 cases).
    q = swinging(11)
    bad = q.copy()
    bad[1:, 2] = quat.mul(q[1:, 2], half_turn())
    first, rows = glitches.seam_window(bad, FPS, 0, True, 15)
    assert first == 0 and np.array_equal(rows[0], bad[0])
    right = quat.mul(quat.inv(q[1:16, 2]), rows[1:, 2])
    assert quat.angle_between(right, right[:1]).max() < 1e-6


def test_a_clip_keeps_the_state_most_of_its_frames_hold():
    # Frames 20-89 of 120 flipped: the run is turned onto the frames before it, then the joint
    # as a whole back onto the run as given (70 frames against 50): the state the clip holds most.
    q = swinging(12)
    bad = q.copy()
    bad[20:90, 1] = quat.mul(half_turn(), q[20:90, 1])
    out = steadied(bad, FPS)
    assert quat.angle_between(out[20:90, 1], bad[20:90, 1]).max() < 1e-6
    step = quat.angle_between(q[1:, 1], q[:-1, 1]).max()
    assert quat.angle_between(out[:20, 1], bad[:20, 1]).max() > np.radians(170)  # turned over
    assert quat.angle_between(out[90:, 1], bad[90:, 1]).max() > np.radians(170)
    assert not glitch_steps(out, FPS).any() and step < np.radians(20)


def test_clean_frames_before_a_dropout_are_not_turned_onto_it():
    # A marker dropout from frame 2 (random rotations for 0.5 s, five frames of it steady): the
    # first two frames are no end's glitch (the frames beside them are no steady second), and
    # stay as given (they were turned onto the dropout's first frame, 120 degrees off).
    rng = np.random.default_rng(13)
    q = swinging(13)
    bad = q.copy()
    bad[2:7, 0] = quat.mul(quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), np.array(2.1)), q[2:7, 0])
    bad[7:17, 0] = quat.exp(rng.normal(scale=2.0, size=(10, 3)))
    assert glitch_steps(bad, FPS)[1, 0] and not glitch_steps(bad, FPS)[2:6, 0].any()
    out = steadied(bad, FPS)
    assert np.array_equal(out[:2, 0], bad[:2, 0])


# -- the engine ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def walks(bandai_paths):
    names = ("walk_normal_001", "run_normal_001", "walk-back_normal_001")
    return [bvh.read(p) for p in bandai_paths(names).values()]


@pytest.fixture(scope="module")
def walk_map(walks):
    return PostureMap(seed=0).fit(walks)


def flipped_first_frame(m: Motion, joint: int) -> Motion:
    """``m`` with frame 0's ``joint`` turned half a turn about its bone (a solver's flip)."""
    rots = m.rotations.copy()
    rots[0, joint] = quat.mul(rots[0, joint], half_turn())
    return Motion(m.skeleton, rots, m.positions.copy(), m.fps)


@pytest.mark.parametrize("method", ["auto", "retrieval", "damped", "spline", "inertialize", "upm-valid"])
def test_a_flip_in_bs_first_frame_does_not_spin_the_gap(walks, walk_map, method):
    a, b = walks[0], walks[2]
    toe = a.skeleton.names.index("Toes_R")
    bad = flipped_first_frame(b, toe)
    turns, length = {}, 30
    for name, clip in (("clean", b), ("flipped", bad)):
        eng = TransitionEngine(walk_map)
        eng.add("a", a)
        eng.add("b", clip)
        r, _ = eng.generate("a", "b", length=length, a_end=60, b_start=0, method=method)
        # The new frames, then B's first as given.
        toes = np.concatenate([r[:, toe], clip.rotations[:1, toe]])
        turns[name] = np.degrees(quat.angle_between(toes[1:], toes[:-1])).max()
    # Read as a velocity, the flip spun the toe at 61-172 degrees a frame. Now the toe moves as
    # it does into B unflipped, turned over by the half turn across the gap (at most 1.5 times
    # SLERP's even step: the spline 9 degrees a frame, SLERP 6), and lands on B's frame as
    # given. upm-valid's key is a map neuron, a toe as the library holds it: the half turn is
    # made between the key and B (38 degrees a frame at most).
    bound = 45.0 if method == "upm-valid" else turns["clean"] + 1.5 * 180.0 / (length + 1) + 1.0
    assert turns["flipped"] <= bound, turns
    # B's frames are written as given, the flip included.
    assert np.array_equal(eng.continuation("b", 0, align=False).rotations, bad.rotations)


def test_a_map_learns_no_flipped_toe(walks):
    walk = walks[0]
    toe = walk.skeleton.names.index("Toes_R")
    rots = walk.rotations.copy()
    rots[100:110, toe] = quat.mul(rots[100:110, toe], half_turn())
    bad = Motion(walk.skeleton, rots, walk.positions.copy(), walk.fps)
    model = PostureMap(seed=0).fit([bad])
    lib = model.library_
    assert lib.clip_start[1] == len(bad)  # the clip as recorded first (then played backward)
    kept = lib.rots[: len(bad), toe].astype(np.float64)
    own = quat.angle_between(walk.rotations[1:, toe], walk.rotations[:-1, toe]).max()
    # The flip as given is two half-turn steps; in the library the toe steps as the walk's own.
    assert quat.angle_between(kept[1:], kept[:-1]).max() <= own + np.radians(0.5)
    # And the maps learn the steadied clip, neuron for neuron.
    steady = Motion(walk.skeleton, steadied(rots, walk.fps), walk.positions.copy(), walk.fps)
    clean = PostureMap(seed=0).fit([steady])
    for m, c in zip(model.maps_, clean.maps_):
        assert np.array_equal(m.weights_, c.weights_)


@pytest.mark.parametrize("method", ["auto", "damped", "spline"])
def test_a_short_clip_is_read_from_its_seam_as_given(walks, walk_map, method):
    # Ten frames of a walk whose toe is flipped in the first eight (a cut through a flipped
    # run): ten frames cannot say which side of the flip is the clip's own. A first version
    # took the last two for a flip the clip ends in, turned them over, and turned the gap back
    # onto A's last frame as given afterwards: damped's gap turned the toe 3.5 degrees a frame
    # where the clean frames turn it 0.1 (on Xia's clips at 120 fps, L2Q 0.19 -> 0.64 in one
    # window). Read from A's last frame as given, the frames before it follow it, turned back,
    # and the toe moves as it does from the clean ten.
    walk = walks[0]
    toe = walk.skeleton.names.index("Toes_R")
    rots = walk.rotations[40:50].copy()
    rots[:8, toe] = quat.mul(half_turn((0.0, 1.0, 0.0)), rots[:8, toe])
    flipped = Motion(walk.skeleton, rots, walk.positions[40:50].copy(), walk.fps)
    assert glitch_steps(flipped.rotations, flipped.fps)[7, toe]
    turns = {}
    for name, a in (("clean", walk[40:50]), ("flipped", flipped)):
        eng = TransitionEngine(walk_map)
        eng.add("a", a)
        eng.add("b", walk[80:])
        r, _ = eng.generate("a", "b", length=30, a_end=9, b_start=0, align=False, method=method)
        toes = np.concatenate([a.rotations[-1:, toe], r[:, toe]])
        turns[name] = np.degrees(quat.angle_between(toes[1:], toes[:-1])).max()
    assert turns["flipped"] <= turns["clean"] + 1.0, turns


@pytest.mark.parametrize("method", ["auto", "damped"])
def test_a_gap_in_a_take_is_never_read_glitches_or_not(walks, walk_map, method):
    # Two takes alike but in the gap: in one the toe's flip, begun before A's end, ends inside
    # the gap; in the other it turns back slowly there. Steadying the whole take read the gap's
    # frames (its outputs differed by up to 59 degrees); a seam reads its own side only.
    walk = walks[0]
    toe = walk.skeleton.names.index("Toes_R")
    a_end, b_start = 40, 71
    outs = []
    for ease in (False, True):
        rots = walk.rotations.copy()
        rots[20:56, toe] = quat.mul(half_turn(), rots[20:56, toe])
        if ease:
            back = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.linspace(np.pi, 0.0, 16)[1:])
            rots[41:56, toe] = quat.mul(back, walk.rotations[41:56, toe])
        eng = TransitionEngine(walk_map)
        eng.add("take", Motion(walk.skeleton, rots, walk.positions.copy(), walk.fps))
        r, p = eng.generate("take", "take", length=b_start - a_end - 1, a_end=a_end, b_start=b_start, align=False,
                            method=method)
        outs.append((r.copy(), p.copy()))
    assert np.array_equal(outs[0][0], outs[1][0]) and np.array_equal(outs[0][1], outs[1][1])


def test_a_take_in_the_library_is_found_past_a_glitch_at_its_seam(walks):
    # A map trained on the take being in-betweened leaves the take out (its gap's frames would
    # come back). The library holds the take steadied; its seam frame, in a flipped run, is
    # compared as the map learned it, not as given.
    from posturemap.synth.engine import _learned_rows

    walk = walks[0]
    hand = walk.skeleton.names.index("Hand_R")
    rots = walk.rotations.copy()
    rots[30:45, hand] = quat.mul(half_turn(), rots[30:45, hand])
    take = Motion(walk.skeleton, rots, walk.positions.copy(), walk.fps)
    model = PostureMap(seed=0).fit([take, walks[1]])
    eng = TransitionEngine(model)
    track = eng.add("take", take)
    lib = model.library_
    joints = np.arange(1, walk.skeleton.num_joints)
    a_end, b_start = 40, 80
    learned = _learned_rows(eng, track)
    found = lib.take_clips(joints, learned[a_end], learned[b_start], b_start - a_end)
    assert list(found) == [0, lib.num_recorded_clips]  # the take, and its copy played backward
    assert not len(lib.take_clips(joints, track.rots[a_end], track.rots[b_start], b_start - a_end))
