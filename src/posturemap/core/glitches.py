"""Glitches in recorded rotations: a joint that turns further in one frame than any joint can,
and back, or on.

Motion capture solved onto a rig now and then flips a joint whose bone gives the solver little
to hold (a thumb, a toe: half a turn about the bone, for a few frames to a third of a second)
or starts a clip with a reference pose (CMU's 01_01, whose first frame has its arms 65-136
degrees from the second). The frames are as recorded and are written as they are; but every
method that reads a seam's velocity reads such a step as one, and carried it through the gap:
a toe spun at 146-180 degrees a frame between two Xia clips, where SLERP turns it 2.

A step is a glitch where a joint turns further than :func:`glitch_turn` in one frame and the
step is as far from what both the frame before it and the one after it predict (each side's own
velocity carried one frame on; at a clip's end, the one side there): a flip or a spike misses
both, a real start or stop only the still side's. The bound is one rate at every frame rate, 47
rad/s (a quarter turn a frame at 30 fps, 22.5 degrees at 120), at most 135 degrees a frame: the
fastest joint of 174 Bandai clips turns 35 rad/s (a punching forearm), of Motiondataset-2's
2,902 clips 25, of LaFAN1's 142 takes 37, and none of them has a glitch step (nor bandai1
resampled down to 10 fps). A fast swing turns far in a frame, but as the frames around it say.

:func:`steadied` (what the maps learn) takes out the glitch steps whose wrong side it can tell:
a short piece at either end of the clip (a first frame in a reference pose), a piece between two
glitch steps that then leads on with none (a flipped run, a one-frame spike), and keeps each
stretch in the state most of its frames hold. :func:`seam_window` (what a transition reads
beside a seam, :func:`posturemap.synth.trajectory.seam_view`) takes out every glitch step among
the frames on the seam's side, walking away from the seam, whose frame stays as given: a gap in
a take is never read, and the new frames start from A's frame and land on B's as given. The
frames written are the clips' own.
"""

from __future__ import annotations

import numpy as np

from . import quat
from .joints import ancestors
from .motion import Motion, root_index

# A step is a glitch when it and both its prediction errors are over GLITCH_RATE / fps radians
# (a quarter turn at 30 fps, 45 degrees at 60, 22.5 at 120), and at most GLITCH_TURN_MOST (135
# degrees at 15 fps and below, where a frame is long enough for a real joint to turn that far).
GLITCH_RATE = 15.0 * np.pi
GLITCH_TURN_MOST = 0.75 * np.pi
# A piece at either end of a clip is taken for a glitch (a reference pose, a flip the clip
# starts or ends in) up to this long (s; at least one frame): a clip that ends half a turn
# from where it was a second before may mean it.
GLITCH_END_S = 0.1
# ... beside a piece with no glitch step at least this long (s): a short clip cannot say which
# side of its step is the clip's own, nor can the clean frames beside a marker dropout.
GLITCH_STEADY_S = 1.0


def glitch_turn(fps: float) -> float:
    """The largest turn (radians) a joint's rotation may make in one frame at ``fps`` before
    the step can be a glitch: :data:`GLITCH_RATE` over ``fps``, at most :data:`GLITCH_TURN_MOST`."""
    return min(GLITCH_RATE / float(fps), GLITCH_TURN_MOST)


def over_bound(rotations: np.ndarray, fps: float, joints=None) -> np.ndarray:
    """Which steps of local rotations ``rotations (F, J, 4)`` turn a joint (of ``joints``, all by
    default) further than :func:`glitch_turn`: (F-1, J) booleans. Only these can be glitch steps,
    of the clip or of any stretch of it."""
    q = np.asarray(rotations, dtype=float)
    out = quat.angle_between(q[:-1], q[1:]) > glitch_turn(fps)
    if joints is not None:
        out[:, np.setdiff1d(np.arange(out.shape[1]), joints)] = False
    return out


def glitch_steps(rotations: np.ndarray, fps: float, joints=None) -> np.ndarray:
    """Which steps of local rotations ``rotations (F, J, 4)`` (unit) are glitches: (F-1, J)
    booleans, step ``t`` from frame ``t`` to ``t + 1`` (see the module's docstring); of
    ``joints`` only, where given. A clip of fewer than three frames has none (one step says
    nothing of what is usual)."""
    q = np.asarray(rotations, dtype=float)
    n = len(q)
    out = np.zeros((max(n - 1, 0),) + q.shape[1:2], dtype=bool)
    if n < 3:
        return out
    limit = glitch_turn(fps)
    big = over_bound(q, fps, joints)
    if not big.any():
        return out
    # Step t predicted by the step before it (frame t+1 as t times t-1's step) and by the one
    # after it (frame t as t+1 times t+2's step back).
    ahead = np.full(big.shape, np.inf)
    ahead[1:] = quat.angle_between(quat.mul(q[1:-1], quat.mul(quat.inv(q[:-2]), q[1:-1])), q[2:])
    back = np.full(big.shape, np.inf)
    back[:-1] = quat.angle_between(quat.mul(q[1:-1], quat.mul(quat.inv(q[2:]), q[1:-1])), q[:-2])
    # Both sides must miss it (a real start or stop misses one: the still side's); at either
    # end of the clip the one side there is.
    ahead[0] = back[0]
    back[-1] = ahead[-1]
    out[:] = big & (ahead > limit) & (back > limit)
    return out


def steadied(rotations: np.ndarray, fps: float, joints=None) -> np.ndarray:
    """``rotations (F, J, 4)`` with their glitch steps (:func:`glitch_steps`) taken out where the
    wrong side can be told: the same array where none is, otherwise a copy. Per joint: a piece
    of at most :data:`GLITCH_END_S` at either end of the clip, beside a piece of at least
    :data:`GLITCH_STEADY_S` with no glitch step, is turned (as a whole: one rotation, its own frame-to-frame turns kept) to
    continue that piece (a first frame in a reference pose; not clean frames beside a dropout
    of random steps); then, in time order, each piece that a glitch step begins and another
    ends is turned to continue the frame before it (from the joint's own side or the parent's,
    whichever leads into the next piece the closer), and kept
    so only where it then leads into the next with no glitch (a flipped run turned back, a
    one-frame spike levelled); last, each stretch between the glitch steps left, where fewer
    than half its frames are as given, is turned as a whole onto its longest turned piece as
    given (the clip's own state is the one it holds most). Any other step is left as it is:
    neither side says it is the wrong one. ``joints``: the joints (indices) to steady, all by
    default."""
    glitches = glitch_steps(rotations, fps, joints)
    joints = np.nonzero(glitches.any(axis=0))[0]
    if not len(joints):
        return rotations
    out = np.array(rotations, dtype=float)
    limit = glitch_turn(fps)
    end = max(1, round(GLITCH_END_S * fps))
    steady = max(end + 1, round(GLITCH_STEADY_S * fps))
    n = len(out)
    for j in joints:
        cuts = [int(t) + 1 for t in np.nonzero(glitches[:, j])[0]]  # each a piece's first frame
        q = out[:, j]
        first, last = cuts[0], cuts[-1]
        beside = (cuts[1] if len(cuts) > 1 else n) - first  # the piece an end's piece would continue
        if first <= end and beside >= steady:
            q[:first] = _continued(q, 0, first, first, first - 1, False)
        beside = last - (cuts[-2] if len(cuts) > 1 else 0)
        if n - last <= end and beside >= steady:
            q[last:] = _continued(q, last, n, last - 1, last, False)
        for k in range(len(cuts) - 1):  # the pieces between two glitch steps
            s, e = cuts[k], cuts[k + 1]
            if _angle(q[s - 1], q[s]) <= limit:
                continue  # turned back with the piece before it
            turned = [_continued(q, s, e, s - 1, s, left) for left in (False, True)]
            step = [_angle(t[-1], q[e]) for t in turned]
            best = int(np.argmin(step))
            if step[best] <= limit:
                q[s:e] = turned[best]
        _most_as_given(q, rotations[:, j], cuts, limit)
    return out


def _most_as_given(q: np.ndarray, given: np.ndarray, cuts: list[int], limit: float) -> None:
    """Turn one joint's steadied rotations ``q (F, 4)`` (in place), each stretch between the
    glitch steps left as a whole, so that its longest turned piece is as given, where fewer
    than half of the stretch's frames are."""
    left = [c for c in cuts if _angle(q[c - 1], q[c]) > limit]
    bounds = [0] + cuts + [len(q)]
    for s, e in zip([0] + left, left + [len(q)]):
        same = np.all(q[s:e] == given[s:e], axis=-1)
        if 2 * int(same.sum()) >= e - s:
            continue
        pieces = [(b - a, a) for a, b in zip(bounds[:-1], bounds[1:]) if s <= a < e and not same[a - s]]
        _, a = max(pieces)
        turn = quat.mul(given[a], quat.inv(q[a]))
        q[s:e] = quat.normalize(quat.mul(turn, q[s:e]))
        q[a] = given[a]


def seam_frames(num_frames: int, frame: int, forward: bool, span: int) -> tuple[int, int]:
    """``(lo, hi)``: the frames ``lo:hi`` a seam at ``frame`` reads on its side of a clip of
    ``num_frames``: the seam and up to ``span`` after it with ``forward`` (B's start), else up to
    ``span`` before it and the seam (A's end)."""
    return (frame, min(num_frames, frame + span + 1)) if forward else (max(0, frame - span), frame + 1)


def seam_window(rotations: np.ndarray, fps: float, frame: int, forward: bool, span: int,
                joints=None) -> tuple[int, np.ndarray] | None:
    """The frames a transition reads beside its seam at ``frame`` with the glitch steps among them
    taken out, walking away from the seam: ``(first, rows)``, the rotations of frames ``first``
    to ``first + len(rows)`` (those after the seam up to ``span`` on, with ``forward``: B's
    start; else those before it up to ``span`` back: A's end); None where no glitch step lies
    among them (:func:`glitch_steps`, read on those frames alone, so that a gap in a take is
    never read). The seam frame is as given; past each glitch step the frames are turned as a
    whole (one rotation, from the joint's own side or the parent's, whichever continues the
    motion's velocity on the seam's side the better; the joint's own where no frame there tells,
    or both continue it alike: a solver flips a joint about its bone) to continue the frame on
    the seam's side with no step. ``joints`` as :func:`steadied` takes them."""
    lo, hi = seam_frames(len(rotations), frame, forward, span)
    q = rotations[lo:hi]
    glitches = glitch_steps(q, fps, joints)
    if not glitches.any():
        return None
    rows = np.array(q, dtype=float)
    m = len(rows)
    for j in np.nonzero(glitches.any(axis=0))[0]:
        r = rows[:, j]
        steps = np.nonzero(glitches[:, j])[0]
        for t in (steps if forward else steps[::-1]):
            near, far = (t, t + 1) if forward else (t + 1, t)
            piece = slice(far, m) if forward else slice(0, far + 1)
            s, e = piece.indices(m)[:2]
            # From the joint's own side first (a solver's flip about the bone), then the parent's.
            turned = [_continued(r, s, e, near, far, left) for left in (False, True)]
            # The velocity on the seam's side, carried on across the step: the better continuation
            # (the joint's own side where that cannot tell, or both continue it alike).
            before = near - 1 if forward else near + 1
            if 0 <= before < m:
                guess = quat.mul(r[near], quat.mul(quat.inv(r[before]), r[near]))
                nxt = far + 1 if forward else far - 1
                if 0 <= nxt < m:
                    miss = [_angle(guess, t[nxt - s]) for t in turned]
                    r[s:e] = turned[int(np.argmin(miss))]  # a tie: the first, the joint's own side
                    continue
            r[s:e] = turned[0]
    return lo, rows


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


def steady_motion(motion: Motion) -> Motion:
    """``motion`` with the rotations of its joints below the root :func:`steadied`
    (:func:`steadied_joints`), as the maps and a motion library learn a clip: the same object
    where it has no glitch step, otherwise a copy (the translations as they are; without the
    file's own channel values, which are the glitches' numbers)."""
    rots = steadied(motion.rotations, motion.fps, steadied_joints(motion.skeleton, root_index(motion)))
    if rots is motion.rotations:
        return motion
    return Motion(motion.skeleton, rots, motion.positions.copy(), motion.fps, None)


def changed_joint(motion: Motion, frame: int, steady: Motion | None = None) -> tuple[int, float] | None:
    """Where :func:`steady_motion` moves frame ``frame`` of ``motion`` by more than the glitch
    bound (:func:`glitch_turn`): ``(joint, angle in radians)`` of the joint it moves the most, or
    None. ``steady``: ``steady_motion(motion)`` where already made (two seams of one take)."""
    rots = (steady if steady is not None else steady_motion(motion)).rotations
    if rots is motion.rotations:
        return None
    moved = quat.angle_between(rots[frame], motion.rotations[frame])
    j = int(np.argmax(moved))
    return (j, float(moved[j])) if moved[j] > glitch_turn(motion.fps) else None


def steadied_joints(skeleton, root: int) -> np.ndarray:
    """The joints whose glitch steps are taken out: all but the root and its ancestors, which
    carry the trajectory (a half turn of the root in a frame is a turn, as far as any frame
    can tell)."""
    out = np.ones(skeleton.num_joints, dtype=bool)
    out[ancestors(skeleton.parents, root) + [root]] = False
    return np.nonzero(out)[0]
