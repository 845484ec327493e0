"""Glitches in recorded rotations: a joint that turns further in one frame than any joint can,
and back, or on.

Motion capture solved onto a rig now and then flips a joint whose bone gives the solver little
to hold (a thumb, a toe: half a turn about the bone, for a few frames to a third of a second)
or starts a clip with a reference pose (CMU's 01_01, whose first frame has its arms 65-136
degrees from the second). The frames are as recorded and are written as they are; but every
method that reads a seam's velocity reads such a step as one, and carried it through the gap:
a toe spun at 146-180 degrees a frame between two Xia clips, where SLERP turns it 2.

A step is a glitch where a joint turns further than :func:`glitch_turn` in one frame and the
step is as far from what the frame before it or the one after it predicts (each side's own
velocity carried one frame on): the joint would reverse, start or stop within the frame at a
speed no joint reaches. The bound is a quarter of a turn at 30 fps and below, the same rate
above: 47 rad/s, where the fastest joint of 174 Bandai clips turns 35 rad/s (a punching
forearm), of Motiondataset-2's 2,902 clips 25, of LaFAN1's 142 takes 37 (and one foot's
64-degree step at 60 fps, a glitch by this rule). A fast swing turns far in a frame, but as the
frames around it say.

:func:`steadied` takes out the glitch steps it can tell the wrong side of: a piece of frames
that one glitch step begins and another ends is turned as a whole (one constant rotation, so
that its own frame-to-frame turns are kept) to continue the frame before it, where it then
leads into the frame after it with no glitch (a flipped run turned back, a one-frame spike
levelled); a piece of at most :data:`GLITCH_END_S` at either end of the clip is turned to
continue its neighbour (a first frame in a reference pose takes the second frame's pose). A
lone step between two long pieces is left. The maps and the motion library are learned from
steadied clips; a transition reads each clip from its seam frame as given, the frames beside it
steadied and turned to follow it (:func:`posturemap.synth.trajectory.anchored`), and writes
the clips' own frames as they are given.
"""

from __future__ import annotations

import numpy as np

from . import quat
from .motion import Motion

# A step is a glitch when it and its prediction error are both over this at 30 fps or under,
# and over this times 30 / fps above (45 degrees at 60 fps, 22.5 at 120): the same 47 rad/s.
GLITCH_TURN = 0.5 * np.pi
GLITCH_FPS = 30.0
# A piece at either end of a clip is taken for a glitch (a reference pose, a flip the clip
# starts or ends in) up to this long (s; at least one frame): a clip that ends half a turn
# from where it was a second before may mean it.
GLITCH_END_S = 0.1


def glitch_turn(fps: float) -> float:
    """The largest turn (radians) a joint's rotation may make in one frame at ``fps`` before
    the step can be a glitch (:data:`GLITCH_TURN`, scaled down above :data:`GLITCH_FPS`)."""
    return GLITCH_TURN * min(1.0, GLITCH_FPS / float(fps))


def glitch_steps(rotations: np.ndarray, fps: float) -> np.ndarray:
    """Which steps of local rotations ``rotations (F, J, 4)`` (unit) are glitches: (F-1, J)
    booleans, step ``t`` from frame ``t`` to ``t + 1`` (see the module's docstring). A clip of
    fewer than three frames has none (one step says nothing of what is usual)."""
    q = np.asarray(rotations, dtype=float)
    n = len(q)
    out = np.zeros((max(n - 1, 0),) + q.shape[1:2], dtype=bool)
    if n < 3:
        return out
    limit = glitch_turn(fps)
    step = quat.angle_between(q[:-1], q[1:])
    big = step > limit
    if not big.any():
        return out
    # Step t predicted by the step before it (frame t+1 as t times t-1's step) and by the one
    # after it (frame t as t+1 times t+2's step back).
    ahead = np.full(step.shape, np.inf)
    ahead[1:] = quat.angle_between(quat.mul(q[1:-1], quat.mul(quat.inv(q[:-2]), q[1:-1])), q[2:])
    back = np.full(step.shape, np.inf)
    back[:-1] = quat.angle_between(quat.mul(q[1:-1], quat.mul(quat.inv(q[2:]), q[1:-1])), q[:-2])
    # At either end only one side predicts: there that side must say so; elsewhere either.
    ahead[0] = back[0]
    back[-1] = ahead[-1]
    out[:] = big & ((ahead > limit) | (back > limit))
    return out


def steadied(rotations: np.ndarray, fps: float, joints=None) -> np.ndarray:
    """``rotations (F, J, 4)`` with their glitch steps (:func:`glitch_steps`) taken out where a
    piece of frames between them can be turned back: the same array where none is, otherwise a
    copy. Per joint, in time order, each piece that a glitch step begins and another ends is
    turned as a whole (one rotation from the left or from the right, whichever leads into the
    next piece the closer; its own frame-to-frame turns kept) to continue the frame before it,
    and kept so only where its last frame then leads into the next with no glitch (a flipped run
    turned back, a one-frame spike levelled); then a piece at either end of the clip, up to
    :data:`GLITCH_END_S` long and shorter than the piece beside it, whose step into it is
    still a glitch, is turned to lead into that piece (a first frame in a reference pose).
    Any other step is left as it is: neither side says it is the wrong one. ``joints``: the
    joints (indices) to steady, all by default."""
    glitches = glitch_steps(rotations, fps)
    if joints is not None:
        glitches[:, np.setdiff1d(np.arange(glitches.shape[1]), joints)] = False
    joints = np.nonzero(glitches.any(axis=0))[0]
    if not len(joints):
        return rotations
    out = np.array(rotations, dtype=float)
    limit = glitch_turn(fps)
    end = max(1, round(GLITCH_END_S * fps))
    n = len(out)
    for j in joints:
        cuts = [int(t) + 1 for t in np.nonzero(glitches[:, j])[0]]  # each a piece's first frame
        q = out[:, j]
        for k in range(len(cuts) - 1):  # the pieces between two glitch steps
            s, e = cuts[k], cuts[k + 1]
            if _angle(q[s - 1], q[s]) <= limit:
                continue  # turned back with the piece before it
            # Turned in the parent's frame (from the left) or in the joint's own (from the
            # right: a flip about the bone), whichever leads into the next piece the closer.
            turned = [_continued(q, s, e, s - 1, s, left) for left in (True, False)]
            step = [_angle(t[-1], q[e]) for t in turned]
            best = int(np.argmin(step))
            if step[best] <= limit:
                q[s:e] = turned[best]
        first, last = cuts[0], cuts[-1]
        after_first = cuts[1] if len(cuts) > 1 else n
        if first <= end and first < after_first - first and _angle(q[first - 1], q[first]) > limit:
            q[:first] = _continued(q, 0, first, first, first - 1, True)
        before_last = cuts[-2] if len(cuts) > 1 else 0
        if n - last <= end and n - last < last - before_last and _angle(q[last - 1], q[last]) > limit:
            q[last:] = _continued(q, last, n, last - 1, last, True)
    return out


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(quat.angle_between(a, b))


def _continued(q: np.ndarray, s: int, e: int, fixed: int, own: int, left: bool) -> np.ndarray:
    """Frames ``s:e`` of one joint's rotations ``q (F, 4)`` turned by one rotation (from the left,
    or from the right) so that frame ``own`` (one of them) equals frame ``fixed`` (beside them),
    in the same hemisphere; a new array."""
    if left:
        piece = quat.mul(quat.mul(q[fixed], quat.inv(q[own])), q[s:e])
    else:
        piece = quat.mul(q[s:e], quat.mul(quat.inv(q[own]), q[fixed]))
    piece = quat.normalize(piece)
    return -piece if np.dot(piece[own - s], q[fixed]) < 0.0 else piece


def steady_motion(motion: Motion, joints=None) -> Motion:
    """``motion`` with its rotations :func:`steadied`: the same object where it has no glitch
    step, otherwise a copy (the translations as they are; without the file's own channel
    values, which are the glitches' numbers); ``joints`` as :func:`steadied` takes them."""
    rots = steadied(motion.rotations, motion.fps, joints)
    if rots is motion.rotations:
        return motion
    return Motion(motion.skeleton, rots, motion.positions.copy(), motion.fps, None)


def changed_joint(motion: Motion, frame: int, joints=None) -> tuple[int, float] | None:
    """Where :func:`steadied` moves frame ``frame`` of ``motion`` by more than the glitch bound
    (:func:`glitch_turn`): ``(joint, angle in radians)`` of the joint it moves the most, or None.
    ``joints`` as :func:`steadied` takes them."""
    rots = steadied(motion.rotations, motion.fps, joints)
    if rots is motion.rotations:
        return None
    moved = quat.angle_between(rots[frame], motion.rotations[frame])
    j = int(np.argmax(moved))
    return (j, float(moved[j])) if moved[j] > glitch_turn(motion.fps) else None
