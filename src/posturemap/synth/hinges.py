"""Knees and elbows bend one way, and only so far: no new frame bends one backward past what the
motion library's do, nor folds one further forward than they do.

Interpolation and extrapolation work on each joint's rotation alone and know nothing of a
knee's hinge, and retrieval's seam offsets add a rotation to a knee whatever its bend: where A's
knee is nearly straight and the retrieved segment's starts bent, the offset that takes one to
the other, carried on over frames where the segment straightens its knee, bends it backward.
Between two held-out dashes (Bandai, the content hold-out's library, 20 frames) ``damped``, the
retrieval's fallback there, carried A's knee velocity on past straight and bent a knee 57
degrees backward; in in-betweening over held-out styles at 1.5 s, 7 of 100 random windows bent
a knee more than 5 degrees backward (up to 16), and the foot lock, which bends the knee in its
plane, bent one further back and then swung it round through 138 degrees in a frame as the
motion's passed straight. Bandai's 26,000 training frames bend no knee backward by more than
0.3 degrees; LaFAN1's by none. Elbows less often: one window of 100 in each of those, one
elbow 28 degrees backward (the library's elbows: 2.4 degrees at most).

The library gives each leg and arm its hinge (:func:`find`: the knee's or elbow's bending
planes' normals summed in the frame of the shin's or forearm's parent, the bent frames weighing
the most) and how far back it goes (the 0.1st percentile of the bends about the hinge, 0 at
most). :func:`unbend` turns each knee and elbow of the new frames that goes further back about
its hinge to that bound: it locks straight, as a real one does, and the hip turns the straight
leg onto the line from the hip to where the ankle was, so the ankle keeps the motion's line, a
little further out. The knee slows onto the bound within ``UNBEND_ACCEL`` instead of stopping
dead on it, rests on it while the motion would take it past, and leaves it as gently
(:func:`faded`); frames far from it are left exactly as they are. (Turning the
shin alone left the thigh where the bent-back leg had it: between two held-out dashes (10
frames) the spline, retrieval's fallback there, matching B's knee flexing 35 degrees a frame
from straight, carried the knee 49 degrees backward, and the straightened leg raised the toe to
46 cm; it came down 15 cm into B's first frame, an acceleration 2.1x the clips' largest. With
the hip turned the toe keeps the spline's path: the largest acceleration there 0.91x, the knee's
at B's seam.)

Nor does extrapolation know how far a knee folds: ``damped``, carrying a walk's swinging shins
on through 45 frames into a run, folded a knee 179 degrees, the heel through the thigh (Bandai's
knees fold 128-141 degrees in 999 frames of 1,000, its elbows 142); over a 5 s fallback between
two dashes the ankle came within 2 cm of the hip, and the foot lock's IK, with no steady line
from hip to ankle to aim along, turned that thigh 72 and 109 degrees in two frames. The library
gives each leg how far forward it goes too (the ``100 - LEAST_PERCENTILE``-th percentile), and
:func:`unbend` turns a knee folded past that bound back onto it about the hinge, its hip left as
it is (the ankle near the hip has no steady line to keep). Below, "leg", "thigh", "shin" and
"knee" stand for an arm's upper arm, forearm and elbow too. The engine does this to
``retrieval``'s and ``auto``'s frames before the foot lock
(:func:`posturemap.synth.engine.TransitionEngine.generate`), and to any method's knees before its
foot lock, which bends a knee in its own plane (a knee bent backward would be bent on backward);
otherwise the interpolating methods, the baselines, stay as they are.
"""

from __future__ import annotations

import numpy as np

from ..core import kernels, quat
from ..core.joints import subtree_mask
from . import rest

LEAST_PERCENTILE = 0.1  # of the library's signed knee bends: the furthest back a new frame's knee may go
#                         (100 less it: the furthest forward)
HINGE_MIN = 1e-3  # the normals' mean length (in squared leg-bone lengths) under which a leg has no hinge
# The hip-to-ankle distance, in leg lengths (thigh plus shin), from which unbend turns the hip the
# whole way onto the ankle's line, and under which it leaves the hip as it is (a fraction between).
REACH_FULL, REACH_NONE = 0.5, 0.25
UNBEND_ACCEL = 60.0  # radians per second^2: a knee unbend turns slows onto its bound and leaves it within
#                      this (faded; pops between CMU-rig walks at 120 fps and 0.5 / 1 s: 6 / 11 turned at
#                      once, 5 / 5 at 135, the lock's KNEE_ACCEL, 4 / 2 at 60 and at 30)


def leg_path(parents, thigh: int, shin: int, ankle: int) -> tuple[list[int], list[int]]:
    """The joints below ``thigh`` down to ``shin`` and below ``shin`` down to ``ankle`` (each
    list top first, ending with its last joint): a bone may be several joints (twist joints)."""
    def below(top, bottom):
        path = [bottom]
        while parents[path[-1]] != top:
            path.append(int(parents[path[-1]]))
        return path[::-1]
    return below(thigh, shin), below(shin, ankle)


def leg_vectors(rots: np.ndarray, offsets: np.ndarray, path: tuple[list[int], list[int]]):
    """The thigh's vector (hip to knee) and the shin's (knee to ankle), (N, 3) each, in the
    frame of the shin's parent (the thigh's, or a twist joint's inside the thigh: the frame the
    knee's own rotation turns the shin in), from local rotations ``rots`` (N, J, 4) and
    translations ``offsets`` (N, J, 3) or (J, 3)."""
    thigh, shin, _ = _leg_frame(rots, offsets, path)
    return thigh, shin


def _leg_frame(rots: np.ndarray, offsets: np.ndarray, path: tuple[list[int], list[int]]):
    """:func:`leg_vectors` and the rotation (N, 4) from the frame of the shin's parent to the
    thigh's own (the identity without twist joints)."""
    to_shin, to_ankle = path
    n = len(rots)
    offsets = np.broadcast_to(offsets, (n,) + offsets.shape[-2:])
    q = np.broadcast_to(quat.identity(), (n, 4))
    p = np.zeros((n, 3))
    parent = q
    for j in to_shin:
        p = p + quat.mul_vec(q, offsets[:, j])
        parent, q = q, quat.mul(q, rots[:, j])
    thigh = p
    for k, j in enumerate(to_ankle):
        p = p + quat.mul_vec(q, offsets[:, j])
        if k + 1 < len(to_ankle):  # the ankle's own rotation moves nothing above it
            q = quat.mul(q, rots[:, j])
    back = quat.inv(parent)
    return quat.mul_vec(back, thigh), quat.mul_vec(back, p - thigh), parent


def signed_bends(thigh: np.ndarray, shin: np.ndarray, hinge: np.ndarray) -> np.ndarray:
    """Each frame's knee bend about its hinge (radians, 0 straight, negative backward): the
    angle the shin turns through about ``hinge`` onto the thigh's line, both seen along it
    (projected onto the plane normal to it). A knee bent in the hinge's plane reads its whole
    bend, forward or backward; one bent sideways reads the part of it about the hinge, which
    goes through 0 as the knee's plane turns through sideways. (The sign of the bend by its plane's normal alone
    jumped there: a blend of two segments bent a LaFAN1 knee 11 degrees sideways, its plane
    turning past the hinge's normal and back over three frames, and :func:`unbend` straightened
    it in two of them, a 9-10 degree kick each way.)"""
    across = np.sum(np.cross(shin, thigh) * hinge, axis=-1)
    along = np.sum(thigh * shin, axis=-1) - np.sum(thigh * hinge, axis=-1) * np.sum(shin * hinge, axis=-1)
    return np.arctan2(across, along)


def find(parents, chains, rots: np.ndarray, offsets: np.ndarray) -> list:
    """Per leg of ``chains`` ((thigh, shin, ankle) each): ``(path, hinge (3,), least, most)``,
    the leg's joints (:func:`leg_path`), its hinge in the frame of the shin's parent (unit), the
    furthest back its knee goes in ``rots`` (N, J, 4; a bend about the hinge in radians, 0 at
    most: the ``LEAST_PERCENTILE``-th percentile) and the furthest forward (0 at least: the
    ``100 - LEAST_PERCENTILE``-th); None for a leg whose knees never bend (no hinge to tell
    backward from forward)."""
    out = []
    for thigh, shin, ankle in chains:
        path = leg_path(parents, thigh, shin, ankle)
        t, s = leg_vectors(rots, offsets, path)
        normal = np.cross(s, t).sum(axis=0)
        size = float(np.mean(np.linalg.norm(t, axis=-1) * np.linalg.norm(s, axis=-1))) if len(t) else 0.0
        if not len(t) or np.linalg.norm(normal) <= HINGE_MIN * size * len(t):
            out.append(None)
            continue
        hinge = normal / np.linalg.norm(normal)
        least, most = np.percentile(signed_bends(t, s, hinge), [LEAST_PERCENTILE, 100.0 - LEAST_PERCENTILE])
        out.append((path, hinge, min(0.0, float(least)), max(0.0, float(most))))
    return out


def packed(knees: list, parents) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`find`' legs that have a hinge as arrays for :func:`unbend`: ``joints`` (every
    leg's joints below the thigh down to the ankle, in turn), ``bounds`` (K, 4) each leg's
    ``[first, shin's end, last]`` in ``joints`` (its shin is ``joints[mid - 1]``) and its thigh
    (the joint above ``joints[first]`` in ``parents``: the hip, whose rotation turns the leg;
    -1 where turning it would move more than this leg: the skeleton's root, or a joint with
    another child that has children of its own, as a rig without thigh joints has its pelvis
    above the spine and the other leg; a leaf beside the leg, a twist helper's, turns with it),
    ``hinge`` (K, 3), ``least`` (K,) and ``most`` (K,)."""
    legs = [k for k in knees if k is not None]
    joints, bounds = [], []
    for (to_shin, to_ankle), *_ in legs:
        bounds.append([len(joints), len(joints) + len(to_shin), len(joints) + len(to_shin) + len(to_ankle),
                       int(parents[to_shin[0]])])
        joints += list(to_shin) + list(to_ankle)
    parents = np.asarray(parents, dtype=np.int64)
    has_kids = np.zeros(len(parents), dtype=bool)
    has_kids[parents[parents >= 0]] = True
    for leg in bounds:
        first, top = leg[0], leg[3]
        beside = subtree_mask(parents, top) & ~subtree_mask(parents, joints[first])
        beside[top] = False
        if parents[top] < 0 or (beside & has_kids).any():
            leg[3] = -1
    return (np.array(joints, dtype=np.int64), np.array(bounds, dtype=np.int64).reshape(-1, 4),
            np.array([k[1] for k in legs], dtype=np.float64).reshape(-1, 3),
            np.array([k[2] for k in legs], dtype=np.float64), np.array([k[3] for k in legs], dtype=np.float64))


def bend_frames(legs: tuple, rots: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Each leg's knee's signed bend (radians) against its hinge in each of the frames ``rots``
    (N, J, 4; local translations ``positions``): (N, legs); ``legs`` the first three of
    :func:`packed`'s arrays. Its minimum over some frames is how far back the knee goes in them.
    Where this process uses numba, one compiled call
    (:func:`posturemap.core.numba_kernels.limb_bends`; about 35 us for a bandai1 clip's four
    limbs, where numpy takes about 0.6 ms)."""
    joints, bounds, hinge_rows = legs
    out = np.zeros((len(rots), len(bounds)))
    if kernels.backend() == "numba" and len(rots):
        positions = np.broadcast_to(positions, rots.shape[:-1] + (3,))
        kernels.compiled().limb_bends(np.ascontiguousarray(rots, dtype=np.float64),
                                      np.ascontiguousarray(positions, dtype=np.float64), joints, bounds,
                                      np.ascontiguousarray(hinge_rows, dtype=np.float64), out)
        return out
    for k, ((first, mid, last, _), hinge) in enumerate(zip(bounds.tolist(), hinge_rows)):
        if len(rots):
            t, s = leg_vectors(rots, positions, (joints[first:mid].tolist(), joints[mid:last].tolist()))
            out[:, k] = signed_bends(t, s, hinge)
    return out


def unbend(limits: tuple, rots: np.ndarray, positions: np.ndarray, accel: float | None = None) -> int:
    """Each knee of the frames ``rots`` (N, J, 4; local translations ``positions`` (N, J, 3))
    folded further forward than its leg's bound (``limits``: :func:`packed` of :func:`find`;
    :func:`signed_bends`) turned back about the hinge onto it, the hip left as it is; each bent
    about its hinge further back than its leg's backward bound turned forward onto that: the
    shin's local rotation turned about the hinge, in the frame of the shin's parent, by as much
    as it is past the bound (a knee bent in the hinge's plane turns in its own plane; one bent
    sideways keeps its sideways part); then the thigh's local rotation turned by the shortest
    arc that takes the ankle back onto its line from the hip (the straightened leg points where
    the bent-back one reached; the ankle's own rotation is kept; where :func:`packed` gives the
    leg a thigh that moves only it). A knee folded back so far that the ankle comes within
    ``REACH_FULL`` leg lengths of the hip (bent back about 120 degrees) has its hip turned only
    part of the way, none within ``REACH_NONE`` (about 150 degrees): the ankle's line from the
    hip swings round as the ankle passes the hip, and the hip with it (a spline over 3.3 s
    folded a knee back through a half turn, and its straightened thigh turned 157 degrees in a
    frame). The bends are read continuously from frame to frame (unwrapped, starting from the
    first frame's in (-pi, pi]): a knee folded forward past a half turn, or bent sideways past
    a quarter turn, reads about pi on one frame and about -pi on the next, which is not a knee
    bent backward (read frame by frame, one interpolated knee folded forward past 180 degrees
    was snapped straight and back, a 176-degree turn in a frame each way). A knee spun through
    a whole turn (a baseline's, over seconds) reads its later bends a whole turn off, and is
    held on a bound from there on (straightened after a backward spin, folded as far as the
    library's after a forward one, up to the gap's end, however far that is from B's first
    frame); reading it afresh once near straight gave pops wherever that
    switched the reading (47 degrees in a frame in a spline over 3.3 s).

    ``accel`` (radians per frame squared; the engine's: ``UNBEND_ACCEL`` over the frame rate
    squared): the change of each leg's bends is :func:`faded`'s, so that the knee's own second
    differences stay within ``accel``, or within the motion's own where those are larger and
    the knee within its range: it slows onto the bound a few frames before it, rests on it, and
    leaves it as gently. Turned
    onto the bound from the frame it passed it, a knee swinging backward stopped dead, and its
    rate jumped: between CMU-rig walks at 120 fps (docs/clip-pairs.md) a toe's path kinked,
    3.35x the clips' own largest acceleration. (Bounding the turn's acceleration instead of the
    knee's, a knee on the bound through a quick reversal was pushed off it, 14-49 degrees
    forward past the motion, and snapped back: a cold review. Letting the knee follow the
    motion's own acceleration past the bound too, it bounced off the bound at a quick reversal:
    a second one.) A knee swinging onto the bound faster than ``accel`` can stop it in the room
    it has turns back short of the bound, smoothly. ``None``: onto the bound at once, every
    frame within it left exactly as it is.

    In place; returns how many knees (frames times legs) it turned. Where this process uses
    numba, one compiled call (:func:`posturemap.core.numba_kernels.unbend_limbs`)."""
    joints, bounds, hinge_rows, leasts, mosts = limits
    if kernels.backend() == "numba":
        return int(kernels.compiled().unbend_limbs(rots, positions, joints, bounds, hinge_rows, leasts, mosts,
                                                   REACH_NONE, REACH_FULL, np.inf if accel is None else accel,
                                                   rest.REST_PASSES, rest.REST_PLAIN, rest.REST_RELAX,
                                                   rest.REST_EXACT))
    turned = 0
    for (first, mid, last, top), hinge, least, most in zip(bounds.tolist(), hinge_rows, leasts.tolist(),
                                                         mosts.tolist()):
        path = (joints[first:mid].tolist(), joints[mid:last].tolist())
        t, s, frame = _leg_frame(rots, positions, path)
        bends = signed_bends(t, s, hinge)
        ok = np.isfinite(bends)
        bends[ok] = np.unwrap(bends[ok])  # continuous over the frames it can measure (see above)
        # The change of each frame's bend that keeps it within both bounds (NaN, a bend or a
        # bound: any), and the least one: 0 within them, onto the bound past either.
        with np.errstate(invalid="ignore"):
            lo, hi = least - bends, most - bends
        lo[np.isnan(lo)], hi[np.isnan(hi)] = -np.inf, np.inf
        if not (lo > 0.0).any() and not (hi < 0.0).any():
            continue
        change = np.clip(0.0, lo, hi) if accel is None else faded(bends, lo, hi, 0.5 * (least + most), accel)
        change[~ok] = 0.0
        past = np.flatnonzero(change)
        shin = path[0][-1]
        # The shin turns about the hinge (a turn about +hinge lowers the bend): a knee bent
        # backward toward the thigh's line (never past it: that bound is at most 0), a folded
        # one back.
        turn = quat.from_axis_angle(np.broadcast_to(hinge, (len(past), 3)), -change[past])
        rots[past, shin] = quat.mul(turn, rots[past, shin])
        turned += len(past)
        # Only a knee turned forward turns its hip (a folded leg's ankle near the hip has no
        # steady line from it), and only a hip that moves this leg alone (packed).
        backward = change[past] > 0.0
        back, turn = past[backward], turn[backward]
        if top < 0 or not len(back):
            continue
        # The hip turns the leg so that the ankle, now further from it, is on the old line:
        # hip-to-ankle before and after, in the thigh's frame.
        t, s, frame = t[back], s[back], frame[back]
        reach, straight = quat.mul_vec(frame, t + s), quat.mul_vec(frame, t + quat.mul_vec(turn, s))
        near, far = np.linalg.norm(reach, axis=-1), np.linalg.norm(straight, axis=-1)
        # A leg folded back onto itself (the ankle at the hip) has no line: its hip stays.
        share = (near / (np.linalg.norm(t, axis=-1) + np.linalg.norm(s, axis=-1)) - REACH_NONE) / (REACH_FULL
                                                                                                 - REACH_NONE)
        some = share > 0.0
        onto = quat.between(straight[some] / far[some, None], reach[some] / near[some, None])
        part = share[some] < 1.0
        onto[part] = quat.exp(share[some][part, None] * quat.log(onto[part]))
        rots[back[some], top] = quat.mul(rots[back[some], top], onto)
    return turned


def faded(bends: np.ndarray, lo: np.ndarray, hi: np.ndarray, middle: float, accel: float) -> np.ndarray:
    """The change (L,) of each frame's knee bend ``bends`` (L,; unwrapped, NaN where not
    measured) that keeps it within both bounds (each frame's change within ``lo`` and ``hi``,
    the bounds less the bend), set off and brought to rest within ``accel`` (radians per frame
    squared): the change is moved as little as :func:`posturemap.synth.rest.rest_bounded` finds
    so that the knee's own second differences (its bend plus the change) stay within ``accel``,
    or within the motion's own where that is larger and the three frames are within the range
    (none where one is not measured): a knee swinging onto the bound slows onto it, rests on it
    while the motion would take it past (through a reversal there too), and follows the motion
    where it is within the range. Each frame is turned toward the
    ``middle`` of the range only (a knee nearer the backward bound forward: not wound up the
    other way first), no further than a change from rest at either seam reaches (a knee already
    past the bound in the first new frame is turned onto it there at once, the clip below). Where
    no such change is found (the bounds and the box leave none), the change onto the bound at
    once (as ``accel`` None does). Turns under 1e-12 radians are none."""
    n = len(bends)
    hard = np.clip(0.0, lo, hi)
    own = np.zeros(n + 2)  # the motion's second differences, at the new frames with two new neighbours
    bound = np.full(n + 2, accel)
    if n >= 3:
        own[2:n] = bends[:-2] - 2.0 * bends[1:-1] + bends[2:]
        # The knee may follow the motion's own acceleration where all three frames are within the
        # range (a reversal past the bound is no swing of the held knee's: there accel, so it
        # rests on the bound instead of bouncing off it); none where a frame is not measured.
        inside = (lo <= 0.0) & (hi >= 0.0)
        bound[2:n] = np.where(inside[:-2] & inside[1:-1] & inside[2:], np.maximum(accel, np.abs(own[2:n])), accel)
    unmeasured = ~np.isfinite(own)
    own[unmeasured], bound[unmeasured] = 0.0, np.inf
    with np.errstate(invalid="ignore"):
        below, above = bends < middle, bends > middle
    low, high = np.where(below, np.maximum(lo, 0.0), lo), np.where(above, np.minimum(hi, 0.0), hi)

    def reach(most):  # the furthest a change from rest at either seam goes, its second differences at most `most`
        return np.minimum(np.cumsum(np.cumsum(most))[:n], np.cumsum(np.cumsum(most[::-1]))[:n][::-1])

    low, high = np.minimum(low, reach(bound - own)), np.maximum(high, -reach(bound + own))
    change = rest.rest_bounded(hard, accel, low, high, own, bound)
    slack = 2e-3 * np.abs(change) + 1e-9
    if (np.any(np.abs(rest.at_rest(change) + own) > bound * 1.002) or np.any(change < low - slack)
            or np.any(change > high + slack)):
        return hard
    change = np.clip(change, lo, hi)
    change[np.abs(change) < 1e-12] = 0.0
    return change
