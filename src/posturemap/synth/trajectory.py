"""The trajectory side of a transition: clips split into trajectory and posture, and B's alignment.

Every frame is split into a *trajectory* (root horizontal position, heading about the up
axis) and a *posture* (root height, root tilt, local rotations). Root alignment turns B about
the up axis and moves it so that it continues A: its start lies where A's root, moving at the
mean of the two clips' seam velocities, gets to in ``length + 1`` frames, facing A's heading
advanced by the mean turning rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from ..core import kernels, quat
from ..core.glitches import seam_window
from ..core.joints import ancestors, leg_chains, leg_toes
from ..core.motion import Motion, up_vector
from ..core.skeleton import chain_world
from ..learn.features import root_global
from .bases import hermite_basis


@dataclass(frozen=True, eq=False)
class Track:
    """A clip split into trajectory and posture, computed once per clip.

    Attributes
    ----------
    motion : the clip
    gpos : (F, 3) global root position
    heading : (F,) root heading about the up axis, radians, continuous over time
    rots : (F, J, 4) local rotations, with the root's replaced by its tilt
    features : (F, D) posture vectors for a map, or None
    feet : (F, n_legs, 3) global ankle positions (for foot locking)
    toes : (F, n_legs, 3) global positions of each leg's toe (:func:`posturemap.core.joints.leg_toes`:
        its ankle where it has none), for the foot lock's floor and its planted toes at the seams
    carrier : where in the root's chain (its ancestors, top first) the highest joint that moves in
        the clip is (:func:`chain_carrier`), -1 where none does: that joint carries the clip's root
        motion and is placed with the body, where fixed ones stay put
    base : None, or for a track that reads the frames beside a seam without their glitch steps
        (:func:`seam_view`), the clip's own track: what is kept per clip is kept for that one
    """

    motion: Motion
    gpos: np.ndarray
    heading: np.ndarray
    rots: np.ndarray
    features: np.ndarray | None
    feet: np.ndarray
    toes: np.ndarray
    carrier: int = -1
    base: "Track | None" = None


def heading_of(q: np.ndarray, up: int) -> np.ndarray:
    """Angle (radians) of rotations ``q (..., 4)`` about the up axis (they must be pure turns)."""
    return 2.0 * np.arctan2(q[..., 1 + up], q[..., 0])


def rotate_about_up(v: np.ndarray, angle, up: int) -> np.ndarray:
    """Vectors ``v (..., 3)`` turned by ``angle`` (radians, right-handed) about the up axis; an
    array of angles broadcasts over the leading axes."""
    a, b = (up + 1) % 3, (up + 2) % 3
    if isinstance(angle, float):  # a Python or numpy float64: math's cos, without a ufunc call (numpy's
        # values here; within an ulp where numpy has its own SIMD cos)
        c, s = math.cos(angle), math.sin(angle)
    else:
        c, s = np.cos(angle), np.sin(angle)
    out = np.array(v, dtype=float)
    va, vb = v[..., a], v[..., b]
    out[..., a] = c * va - s * vb
    out[..., b] = s * va + c * vb
    return out


# A joint above the root is fixed when it turns by under CHAIN_TURN radians and moves by under
# CHAIN_SHIFT times the skeleton's longest bone over the clip (a BVH's six decimals are far below).
CHAIN_TURN = 1e-4
CHAIN_SHIFT = 1e-4
# The bend of a carried root bone's path (:func:`carry_chain`): two terms, one more per
# BEND_PIECE_S seconds of gap. On LaFAN1's 4 s transitions (subject 5, 40 seeded pairs) the bone
# strayed from the floor under the hips by 25 cm in the median and 90 at most with two terms
# alone, 13 and 42 so (at 1 s, 7.4 and 6.9 cm in the median, 17 at most either way).
BEND_PIECE_S = 1.0


def chain_carrier(motion: Motion, chain) -> int:
    """Where in ``chain`` (the root's ancestors, top first) the highest joint that turns or moves
    over the clip is; -1 where none does (or the clip has a single frame: nothing to tell by).

    Such a joint carries root motion, as a game rig's root bone does (and four bandai1 clips'
    ``joint_Root``, and LaFAN1's segments' ``SimulationBone``): B is placed with it, and the new
    frames take it there (:func:`carry_chain`). A fixed one is a reference node (the other 170
    bandai1 clips' ``joint_Root``, or a file's conversion node above a root bone), a place in
    the world that stays where it is.
    """
    if len(motion) < 2:
        return -1
    bone = float(np.linalg.norm(motion.skeleton.offsets, axis=1).max(initial=0.0))
    for k, j in enumerate(np.asarray(chain, dtype=np.int64).tolist()):
        q, p = motion.rotations[:, j], motion.positions[:, j]
        # |cos| of half the turn from the first frame (norms divided out: a float32 node is fixed)
        cos_half = np.abs(np.sum(q * q[:1], axis=-1)) / (np.linalg.norm(q, axis=-1) * np.linalg.norm(q[0]))
        if cos_half.min() < math.cos(0.5 * CHAIN_TURN) or np.abs(p - p[:1]).max() > CHAIN_SHIFT * max(bone, 1e-9):
            return k
    return -1


def through_seams(rows: np.ndarray, length: int) -> np.ndarray:
    """The cubic Hermite (length, ...) through the new frames from A's last value and rate to B's
    first: ``rows`` (4, ...) hold A's frame before its last, its last, B's first and the one after
    (``spline``'s rows; :func:`posturemap.synth.bases.hermite_basis`)."""
    rates = np.stack([rows[1], rows[1] - rows[0], rows[2], rows[3] - rows[2]])
    return np.tensordot(hermite_basis(length), rates, axes=1)


#: Gaps up to this long (seconds, A's last kept frame to B's first) take each seam's velocity as
#: its last (first) two frames give it in :func:`seam_path`; longer ones, the velocity averaged
#: over up to :data:`SEAM_AVERAGE_S` more of the seam's own frames, the two frames' remainder
#: fading within :data:`SEAM_FADE_S`.
SEAM_HERMITE_S = 2.0
SEAM_AVERAGE_S = 1.0
SEAM_FADE_S = 0.25


def seam_path(ta: Track, tb: Track, a_end: int, b_start: int, length: int, up: int) -> np.ndarray:
    """The root's place over the floor through ``length`` new frames between A's frame ``a_end``
    and B's ``b_start`` where B stays where it is (in-betweening): (length, 3), the up
    coordinate 0. A cubic Hermite from A's last place and velocity (its last two frames) to B's
    first (its first two), as the ``spline`` method's root runs (up to :data:`SEAM_HERMITE_S`;
    longer gaps below).

    Measured against a trajectory smoothed as motion matching's is (a line fitted to each seam's
    last or first 0.25 s, its place and velocity joined by the cubic, each seam's sway off its
    line fading across the gap): as an estimate of the truth's hips over the floor on LaFAN1
    (subject 5, 1 / 2 s gaps) it erred 4.4 / 11.4 cm on average, this one 2.9 / 9.1, and the
    bench's six bandai1 splits and CMU agreed.

    Over a gap longer than :data:`SEAM_HERMITE_S` the cubic carries a seam's velocity for the whole
    gap, a sway or a last step included: a performer standing between two sways was sent 8 cm off
    their place, on average, by the cubic of a 5 s gap. There each seam's velocity is its average
    over its last (first) frames, a longer span the longer the gap (up to :data:`SEAM_AVERAGE_S` at
    a gap of ``SEAM_HERMITE_S + SEAM_AVERAGE_S``; the same cubic at ``SEAM_HERMITE_S``), and what
    the two frames' velocity adds to it fades within :data:`SEAM_FADE_S` of the seam (its place and
    velocity kept there). A side with less than ``SEAM_AVERAGE_S`` of its own frames keeps its two
    frames' velocity (an average over part of a stride is no steadier than its last step).
    In-betweening one take with no map (the CLI's ``transition --no-align`` without ``--map``), the
    default's MPJPE against the truth went, at 3 / 4 / 5 s (30 fps), on Motiondataset-2 (120 seeded
    takes, those long enough: 47 / 36 / 15) 9.49 / 9.44 / 9.29 -> 8.68 / 8.55 / 5.70 cm (SLERP's
    16.35 / 16.90 / 5.33); on bandai1 at 3.3 s (33 takes) 9.22 -> 8.42 (SLERP's 8.54). With a
    library (the bench's six bandai1 splits, the test clip's frames before and after the gap as
    context, 3 / 4 s) L2P moved by +0.4% / +0.1% on average (-0.3% to +1.1% a split), L2Q by under
    0.1%: on walks the last step's velocity and the average agree. The bench's 10-frame context is
    under a second: unchanged. Gaps up to 2 s are unchanged.
    """
    flat = [i for i in range(3) if i != up]
    a_prev, b_next = max(a_end - 1, 0), min(b_start + 1, len(tb.gpos) - 1)
    rows = np.stack([ta.gpos[a_prev], ta.gpos[a_end], tb.gpos[b_start], tb.gpos[b_next]])
    fps = ta.motion.fps
    d = length + 1.0
    over = d - SEAM_HERMITE_S * fps
    out = np.zeros((length, 3))
    if over <= 0.0:
        out[:, flat] = through_seams(rows, length)[:, flat]
        return out
    # A side with less than SEAM_AVERAGE_S of its own frames keeps its two frames' velocity: an
    # average over part of a stride is no steadier than its last step.
    whole = max(1, round(SEAM_AVERAGE_S * fps))  # a frame at least, at any frame rate
    span = max(1, min(round(over), whole))
    rates = np.stack([rows[1] - rows[0], rows[3] - rows[2]])  # the two frames' velocities
    mean = rates.copy()
    if a_end >= whole:
        mean[0] = (rows[1] - ta.gpos[a_end - span]) / span
    if len(tb.gpos) - 1 - b_start >= whole:
        mean[1] = (tb.gpos[b_start + span] - rows[2]) / span
    path = through_seams(np.stack([rows[1] - mean[0], rows[1], rows[2], rows[2] + mean[1]]), length)
    fade = SEAM_FADE_S * fps  # under the gap: SEAM_HERMITE_S is longer
    t = np.arange(1, length + 1, dtype=float)
    s_a = np.clip(t / fade, 0.0, 1.0)
    s_b = np.clip((t - (d - fade)) / fade, 0.0, 1.0)
    path += np.outer(fade * (s_a ** 3 - 2.0 * s_a ** 2 + s_a), rates[0] - mean[0])  # Hermite's h10, h11
    path += np.outer(fade * (s_b ** 3 - s_b ** 2), rates[1] - mean[1])
    out[:, flat] = path[:, flat]
    return out


def seam_view(track: Track, frame: int, forward: bool, span: int, joints) -> Track:
    """``track`` as a transition reads it beside its seam at ``frame``: where a glitch step lies
    among the ``span`` frames the seam reads (after it with ``forward``, B's start; before it,
    A's end; :func:`posturemap.core.glitches.seam_window`), a track whose rotations there (of
    ``joints``) continue the seam frame without it, the seam frame as given; otherwise
    ``track`` itself. The rest of the track (the trajectory, the feet, the posture vectors)
    is the clip's own, and so is every frame outside those."""
    found = seam_window(track.motion.rotations, track.motion.fps, frame, forward, span, joints)
    if found is None:
        return track
    lo, rows = found
    hi = lo + len(rows)
    motion_rots, rots = track.motion.rotations.copy(), track.rots.copy()
    motion_rots[lo:hi, joints] = rots[lo:hi, joints] = rows[:, joints]
    motion = Motion(track.motion.skeleton, motion_rots, track.motion.positions, track.motion.fps)
    return replace(track, motion=motion, rots=rots, base=track.base or track)


def make_track(motion: Motion, root: int, up: int, rest: np.ndarray, space=None) -> Track:
    """Split a clip into trajectory and posture (see :class:`Track`)."""
    grot, gpos = root_global(motion, root)
    head_q, tilt = quat.heading_tilt(grot, up_vector(up), rest)
    heading = np.unwrap(heading_of(head_q, up))
    rots = motion.rotations.copy()
    rots[:, root] = tilt
    feats = space.encode(motion) if space is not None else None
    chains = leg_chains(motion.skeleton)
    feet = toes = np.zeros((len(motion), 0, 3))
    if chains:
        grot_all, gpos_all = np.empty(motion.rotations.shape), np.empty(motion.positions.shape)
        kernels.fk(motion.skeleton.parents, motion.rotations, motion.positions, grot_all, gpos_all)
        feet = gpos_all[:, [c[2] for c in chains]]
        toes = gpos_all[:, leg_toes(motion.skeleton, chains)]
    carrier = chain_carrier(motion, ancestors(motion.skeleton.parents, root))
    return Track(motion, gpos, heading, rots, feats, feet, toes, carrier)


def alignment(a: Track, b: Track, a_end: int, b_start: int, length: int, up: int) -> tuple[float, np.ndarray]:
    """Turn (radians about up) and translation (3,) that make B continue A."""
    h1, h2 = (up + 1) % 3, (up + 2) % 3
    d = length + 1.0
    a0, b1 = max(a_end - 1, 0), min(b_start + 1, len(b.gpos) - 1)
    pa, pa0, pb, pb1 = a.gpos[a_end], a.gpos[a0], b.gpos[b_start], b.gpos[b1]
    wa = a.heading[a_end] - a.heading[a0]
    wb = b.heading[b1] - b.heading[b_start]
    dtheta = float(a.heading[a_end] + 0.5 * (wa + wb) * d - b.heading[b_start])
    c, s = math.cos(dtheta), math.sin(dtheta)
    # B's seam velocity and start, turned by dtheta in the horizontal plane (h1, h2).
    vb1, vb2 = pb1[h1] - pb[h1], pb1[h2] - pb[h2]
    vb1, vb2 = c * vb1 - s * vb2, s * vb1 + c * vb2
    sb1, sb2 = c * pb[h1] - s * pb[h2], s * pb[h1] + c * pb[h2]
    shift = np.zeros(3)
    shift[h1] = pa[h1] + 0.5 * (pa[h1] - pa0[h1] + vb1) * d - sb1
    shift[h2] = pa[h2] + 0.5 * (pa[h2] - pa0[h2] + vb2) * d - sb2
    return dtheta, shift


def aligned(track: Track, start: int, dtheta: float, shift: np.ndarray, chain: np.ndarray, root: int,
            up: int, carrier: int | None = None) -> Motion:
    """Frames ``start:`` of a clip, turned by ``dtheta`` about up and moved by ``shift``.

    ``chain`` holds the root's ancestors (top first), whose rotations carry the heading. The
    joint of the chain that carries root motion (``carrier``, default the clip's own
    :attr:`Track.carrier`) is turned and moved with the body, under the fixed ones above it;
    where none does (a reference node) the chain stays where it is and the root is placed
    under it.
    """
    m = track.motion
    rots = track.rots[start:].copy()
    positions = m.positions[start:].copy()
    k = track.carrier if carrier is None else carrier
    if k >= 0 and len(chain):
        j = int(chain[k])
        q, t = _seen_from(chain[:k], m, up, dtheta, shift)
        rots[:, j] = quat.mul(q, rots[:, j])
        positions[:, j] = quat.mul_vec(q, positions[:, j]) + t
    gpos = rotate_about_up(track.gpos[start:], dtheta, up) + shift
    kernels.compose_root(chain, root, up, rots, positions, gpos, track.heading[start:] + dtheta)
    return Motion(m.skeleton, rots, positions, m.fps)


def _seen_from(fixed, motion: Motion, up: int, dtheta: float, shift) -> tuple[np.ndarray, np.ndarray]:
    """The turn by ``dtheta`` about up and the move by ``shift`` of the world, as a change
    ``(q, t)`` of the local rotation and translation of a joint whose ancestors are the fixed
    joints ``fixed`` (top first; none: the world's own)."""
    turn = quat.from_axis_angle(up_vector(up), np.array(float(dtheta)))
    shift = np.asarray(shift, dtype=float)
    if not len(fixed):
        return turn, shift.copy()
    cq, cp = chain_world(fixed, motion.rotations[:1], motion.positions[:1])
    cq_inv = quat.inv(cq[0])
    return quat.mul(cq_inv, quat.mul(turn, cq[0])), quat.mul_vec(cq_inv, quat.mul_vec(turn, cp[0]) + shift - cp[0])


def placement(track: Track, chain, root: int, up: int, dtheta: float, shift,
              carrier: int | None = None) -> tuple[int, np.ndarray, np.ndarray]:
    """How :func:`aligned` places the clip, as one joint's local change: ``(joint, q (4,), t (3,))``
    with ``joint``'s local rotation ``r`` and translation ``p`` becoming ``q r`` and ``q p + t``
    on every frame (the joints below it as they are).

    That joint is the one of the chain that carries root motion (``carrier``, default the clip's
    own), or the root where none does (or there is no chain); ``q`` and ``t`` are the turn by
    ``dtheta`` about up and the move by ``shift``, seen from the fixed joints above it.
    """
    k = track.carrier if carrier is None else carrier
    if k >= 0 and len(chain):
        return int(chain[k]), *_seen_from(chain[:k], track.motion, up, dtheta, shift)
    return int(root), *_seen_from(chain, track.motion, up, dtheta, shift)


@lru_cache(maxsize=64)
def _bend_fit(length: int, terms: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`carry_chain`'s bump, ``s^2 (1-s)^2`` times Legendre polynomials of degree under
    ``terms`` at the new frames' times ``s``, and its least-squares solver (read-only)."""
    s = np.arange(1, length + 1) / (length + 1.0)
    if terms:
        bump = (s * s * (1.0 - s) ** 2)[:, None] * np.polynomial.legendre.legvander(2.0 * s - 1.0, terms - 1)
        solve = np.linalg.pinv(bump)
    else:
        bump, solve = np.zeros((length, 0)), np.zeros((0, length))
    bump.setflags(write=False)
    solve.setflags(write=False)
    return bump, solve


def bend_fit(length: int, fps: float, bent: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """:func:`carry_chain`'s bump over ``length`` new frames at ``fps`` (two terms, one more per
    :data:`BEND_PIECE_S` seconds of gap) and its least-squares solver (read-only); not ``bent``,
    empty ones (no terms: the compiled carry then bends nothing)."""
    return _bend_fit(int(length), 2 + int((length + 1.0) / (BEND_PIECE_S * fps)) if bent else 0)


def carry_chain(ta: Track, tb: Track, a_end: int, b_start: int, rots: np.ndarray, positions: np.ndarray, chain,
                root: int, up: int, dtheta: float, shift, a_carrier: int, b_carrier: int) -> None:
    """The joint of the root's chain that carries B's root motion (``b_carrier``, at least 0:
    :attr:`Track.carrier`) through new frames ``rots (L, J, 4)``, ``positions (L, J, 3)`` (in
    place), where B is placed to continue A (turned by ``dtheta`` about up, moved by ``shift``)
    and so is that joint.

    It runs from A's last frame to B's first, placed: a cubic Hermite in the world from their
    turns, places and rates, as the ``spline`` method's. From a clip whose chain carries root
    motion too (``a_carrier`` at least 0), its path is bent as the body's bends; from a fixed one
    it starts away from the body. The bend is the body's ground point's departure from its own
    Hermite between the seams, fitted by ``s^2 (1-s)^2`` times polynomials in the gap's time
    ``s`` (two terms, one more per :data:`BEND_PIECE_S` seconds): a smooth bump that keeps the
    seams' places and rates and leaves out the body's sway from step to step (a root bone moves
    smoothly). The fixed joints above it keep theirs, and the root its global turn and place:
    its local ones are made again under the new chain.
    """
    k = int(b_carrier)
    j, fixed, upto = int(chain[k]), chain[:k], chain[: k + 1]
    a_prev, b_next = max(a_end - 1, 0), min(b_start + 1, len(tb.gpos) - 1)
    shift = np.asarray(shift, dtype=float)
    gq, gp = chain_world(list(chain) + [root], rots, positions)
    ia, ib = [a_prev, a_end], [b_start, b_next]
    aq, ap = chain_world(upto, ta.motion.rotations[ia], ta.motion.positions[ia])
    bq, bp = chain_world(upto, tb.motion.rotations[ib], tb.motion.positions[ib])
    bq = quat.mul(quat.from_axis_angle(up_vector(up), np.array(float(dtheta))), bq)
    bp = rotate_about_up(bp, float(dtheta), up) + shift
    seam_q, length = np.concatenate([aq, bq]), len(rots)
    logs = quat.log(quat.mul(quat.inv(seam_q[2]), seam_q))
    logs[0] = quat.near_turn(logs[0], logs[1])  # A's rate, not a whole turn, where A is half a turn from B
    new_q = quat.mul(seam_q[2], quat.exp(through_seams(logs, length)))
    new_p = through_seams(np.concatenate([ap, bp]), length)
    if a_carrier >= 0:
        ground = np.concatenate([ta.gpos[ia], rotate_about_up(tb.gpos[ib], float(dtheta), up) + shift])
        bend = gp - through_seams(ground, length)
        bend[:, up] = 0.0
        bump, solve = bend_fit(length, ta.motion.fps)
        new_p += bump @ (solve @ bend)
    if len(fixed):  # into the frame of the fixed joints above it
        fq, fp = chain_world(fixed, rots, positions)
        fq_inv = quat.inv(fq)
        new_q, new_p = quat.mul(fq_inv, new_q), quat.mul_vec(fq_inv, new_p - fp)
    rots[:, j], positions[:, j] = new_q, new_p
    put_root(chain, root, rots, positions, gq, gp)


def put_root(chain, root: int, rots: np.ndarray, positions: np.ndarray, gq: np.ndarray, gp: np.ndarray) -> None:
    """The root's local rotation and translation (in place) that put it at global ``gq`` (N, 4),
    ``gp`` (N, 3) under its ancestors ``chain`` (top first, at least one) as they now are."""
    cq, cp = chain_world(chain, rots, positions)
    cq_inv = quat.inv(cq)
    rots[:, root], positions[:, root] = quat.mul(cq_inv, gq), quat.mul_vec(cq_inv, gp - cp)
