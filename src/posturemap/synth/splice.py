"""Splicing two real motions in a gap: A's continuation, blended into B's arrival.

Retrieval looks for library segments that both continue A and arrive in B. Between different
clips (a bow and a walk, a run and a wave) there is rarely one: the best segments match
neither seam well, the confidence drops and interpolation takes over, and interpolated feet
slide. But every motion has real continuations, and every motion real approaches. The splice
plays a segment that continues A (matched at A's end only), blends into a segment that arrives
in B (matched at B's start only) over the middle of the gap, and plays that one into B: a
motion-graph transition (Kovar, Gleicher and Pighin 2002) inside the gap, both ends real.

- Poses are blended by SLERP with a smoothstep weight, centred by ``alpha`` (0: the blend comes
  late, A's motion carries on longer; 1: it comes early, B's motion starts sooner), so alpha keeps
  its meaning, and as wide as fits in the gap around that centre (:func:`splice_blend`: the
  whole gap at alpha 0.5, half of it at 0 and 1).
- The root's turning rate and its horizontal velocity in the heading's frame are blended and
  integrated from A's end, so the path has no kink and the body goes where it faces, and B is
  placed where the path arrives, as the second segment placed it relative to its own end. (In in-betweening, B fixed, the engine keeps the single segment.)
- Planted feet come from the segment that dominates each frame.
- Confidence per body part: the smaller of the two halves' confidences, each measured at its
  own seam. The engine uses the splice in transitions (B placed to continue A) when its legs
  are more confident than the single segment's (:meth:`TransitionEngine.generate
  <posturemap.synth.engine.TransitionEngine.generate>`, ``retrieval``); in in-betweening the
  single segment, matched to the gap at both ends, stays.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core import kernels
from . import retrieval
from .retrieval import Result, _compiled, _hermite_offsets_cached, _sample_times, blend_frames, match, replay
from .trajectory import rotate_about_up

SPLICE_WIDTH = 1.0  # the largest fraction of the gap over which A's continuation blends into B's arrival
# Segments averaged per half (the single segment averages retrieval.TOP_K = 16): on the bench's
# cross-clip pairs, 16 per half skated 4.37 / 4.38 cm/s (held-out styles / contents; the real
# frames 3.65 / 3.02) with jerk 16,200 / 20,400 cm/s^3, 8 per half 4.08 / 4.26 with 17,300 /
# 21,600 (real 12,700 / 19,300), in half the replay's time (the foot lock of that time). Since
# the blend spans the whole gap at alpha 0.5, each half replays every frame there. On the same
# seeded draws of bench/retrieval_speed.py's kind (prof runs alternated, this shared machine's
# spread about 5%), 8 per half took 0.95-0.97 ms a transition, 6 0.93-0.99 (the code with the
# half-gap blend and 8 per half: 0.92-1.03); skate 3.94 / 3.82 and 3.92 / 3.88 cm/s, jerk
# 15,200 / 19,300 and 15,400 / 19,300 cm/s^3. 4 per half (0.92-0.93 ms, 3.80 / 3.75 cm/s,
# 16,000 / 20,200) made B's seam rougher: in a run-to-backward-walk transition its acceleration
# stood out 2.25x from the frames around it (the seam test's bound is 2; 6 and 8 pass).
HALF_TOP_K = 6
# A splice is not kept where its lowest foot stays this many leg lengths above both seams' lowest
# foot for FLOAT_S seconds or more (see floats).
FLOAT = 0.1
FLOAT_S = 0.15


def splice_blend(alpha: float, widest: float = SPLICE_WIDTH) -> tuple[float, float]:
    """The blend's centre and width as fractions of the gap: centred at ``0.75 - 0.5 * alpha``,
    as wide as fits in the gap around it (up to ``widest``): the whole gap at alpha 0.5, half of
    it at alpha 0 and 1.

    On the bench's cross-clip pairs (alpha 0.5), blending over the whole gap instead of half of
    it took the jerk from 17,500 to 15,200 cm/s^3 on held-out styles and from 22,000 to 19,300 on
    contents (the real frames 12,700 and 19,300) for the same foot skate (3.97 / 3.77 -> 3.94 /
    3.82 cm/s): two real motions blended over 0.33 s bent the knees faster than either does."""
    centre = 0.75 - 0.5 * float(alpha)
    return centre, min(float(widest), 2.0 * min(centre, 1.0 - centre))


def splice_weights(length: int, alpha: float, widest: float = SPLICE_WIDTH) -> np.ndarray:
    """Weight (length,) of B's arrival at the new frames: 0 before the blend, a smoothstep over
    the blend (:func:`splice_blend`), 1 after. A larger alpha never lowers it."""
    t = np.arange(1, length + 1) / (length + 1.0)
    centre, width = splice_blend(alpha, widest)
    # np.clip's values, without its overhead
    u = np.minimum(np.maximum((t - centre) / max(width, 1e-9) + 0.5, 0.0), 1.0)
    return u * u * (3.0 - 2.0 * u)


def splice(first, second, w: np.ndarray, a_pos: np.ndarray, a_heading: float, b_pos: np.ndarray, up: int):
    """Blend ``first`` (continues A) into ``second`` (arrives in B), two retrieval results of a
    transition (B placed to continue A).

    ``w`` (L,) the weight of ``second`` per new frame (:func:`splice_weights`); ``a_pos`` (3,)
    and ``a_heading`` A's root at its last frame; ``b_pos`` (3,) B's root at its first frame
    as it lies in its clip. Returns ``(rots, gpos, heading, dtheta, shift, contacts)`` in the
    form of a :class:`~posturemap.synth.retrieval.Result`'s fields. Where numba is in use, one
    compiled call (:func:`posturemap.synth.retrieval_numba.splice`).
    """
    w = np.asarray(w, dtype=np.float64)
    jit = _compiled()
    if jit is not None:  # the steps below in one call
        rots, gpos, heading = np.empty(first.rots.shape), np.empty((len(w), 3)), np.empty(len(w))
        shift, contacts = np.empty(3), np.empty(first.contacts.shape, dtype=first.contacts.dtype)
        dtheta = jit.splice(first.rots, second.rots, w, first.gpos, first.heading, second.gpos, second.heading,
                            np.asarray(a_pos, dtype=np.float64), float(a_heading), np.asarray(b_pos, dtype=np.float64),
                            float(second.dtheta), np.asarray(second.shift, dtype=np.float64), first.contacts,
                            second.contacts, up, rots, gpos, heading, shift, contacts)
        return rots, gpos, heading, float(dtheta), shift, contacts
    rots = splice_rotations(first.rots, second.rots, w)
    # One turn of 2 pi for the whole second segment (its headings are continuous): frame by
    # frame the two may drift more than pi apart.
    turn2 = 2 * np.pi * round(float(first.heading[0] - second.heading[0]) / (2 * np.pi))
    gpos, heading = splice_path(first.gpos, first.heading, second.gpos, second.heading, turn2, w, a_pos,
                                a_heading, up)
    # B where `second` put it relative to its own last frame, carried to the path's end.
    turn = float(heading[-1] - (second.heading[-1] + turn2))
    b_placed = rotate_about_up(b_pos, second.dtheta, up) + second.shift
    end = gpos[-1] + rotate_about_up(b_placed - second.gpos[-1], turn, up)
    dtheta = float(second.dtheta + turn)
    shift = end - rotate_about_up(b_pos, dtheta, up)
    contacts = np.where((w < 0.5)[:, None], first.contacts, second.contacts)
    return rots, gpos, heading, dtheta, shift, contacts


def splice_path(g1, h1, g2, h2, turn2: float, w: np.ndarray, a_pos: np.ndarray, a_heading: float, up: int):
    """The spliced root path: positions (L, 3) and headings (L,). The turning rates of the first
    segment (``h1`` (L,)) and of the second (``h2 + turn2``) are blended by ``w`` (L,) and
    integrated from A's heading (``a_heading``); each segment's horizontal velocity (``g1``,
    ``g2`` (L, 3)), taken in its own heading's frame, is blended so and turned to the path's
    heading, and integrated from A's root (``a_pos``): the path has no kink, and the body goes
    where it faces as each segment does (where the path has turned away from the second
    segment, it arrives at B's velocity turned as B is placed). The height is blended as it is.
    The numpy steps of :func:`splice` (its compiled call runs
    :func:`posturemap.synth.retrieval_numba.splice_path`)."""
    w = np.asarray(w, dtype=np.float64)
    a_pos = np.asarray(a_pos, dtype=np.float64)
    h2 = h2 + turn2
    heading = a_heading + np.cumsum((1 - w) * np.diff(np.concatenate([[a_heading], h1]))
                                    + w * np.diff(np.concatenate([[a_heading], h2])))
    vel = (1 - w)[:, None] * rotate_about_up(np.diff(np.concatenate([a_pos[None], g1]), axis=0), heading - h1, up) \
        + w[:, None] * rotate_about_up(np.diff(np.concatenate([a_pos[None], g2]), axis=0), heading - h2, up)
    gpos = a_pos + np.cumsum(vel, axis=0)
    gpos[:, up] = (1 - w) * g1[:, up] + w * g2[:, up]
    return gpos, heading


def splice_rotations(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Frames (L, J, 4) of A's continuation ``a`` blended into B's arrival ``b`` by the weights
    ``w`` (L,; 0 before the blend, rising, 1 after it): ``a[t]`` where ``w[t] <= 0``, the
    SLERP at ``w[t]`` in between, ``b[t]`` where ``w[t] >= 1``, each joint's sign in the
    hemisphere of the frame before (so each may hold only the frames it shows: :func:`spliced`
    replays no more). The SLERP is on the arc that goes on from frame to frame
    (:func:`posturemap.core.kernels.slerp_track`: the short arc at the blend's first frame):
    where the two halves pass through a half turn from each other, the short arc flipped to
    the other side in a frame (an arm turned 180 degrees in one frame between a walk and a
    wave). The numpy steps of :func:`splice` (its compiled call runs
    :func:`posturemap.synth.retrieval_numba.splice_rotations`)."""
    w = np.asarray(w, dtype=np.float64)
    out = np.empty(a.shape)
    blend = np.flatnonzero((w > 0.0) & (w < 1.0))
    if len(blend):
        lo, hi = int(blend[0]), int(blend[-1]) + 1  # one stretch: w rises
        kernels.slerp_track(a[lo:hi], b[lo:hi], w[lo:hi], out[lo:hi], np.zeros(a.shape[1], dtype=bool))
    for t, wt in enumerate(w.tolist()):
        if wt <= 0.0:
            out[t] = a[t]
        elif not 0.0 < wt < 1.0:  # B (from 1 on, or NaN), each joint in the hemisphere of the frame before
            out[t] = b[t] if t == 0 else np.where((np.sum(b[t] * out[t - 1], axis=-1) < 0.0)[:, None], -b[t], b[t])
    return out


def halves(rt, ta, tb, a_end: int, b_start: int, length: int, shared: dict | None = None):
    """The two halves of a splice as :class:`~posturemap.synth.retrieval.Match` es: the best
    segments continuing A (matched at A's end, ``alpha`` 0) and arriving in B (at B's start,
    ``alpha`` 1), :data:`HALF_TOP_K` of each (times
    :func:`~posturemap.synth.retrieval.moments_scale` of the library's frame rate); None
    for a half that finds no segment. ``shared``: as for :func:`~posturemap.synth.retrieval.match`."""
    shared = {} if shared is None else shared
    keep = max(1, round(HALF_TOP_K * retrieval.moments_scale(rt.lib.fps)))
    out = []
    for alpha, seam in ((0.0, "a"), (1.0, "b")):
        m = match(rt, ta, tb, a_end, b_start, length, alpha, True, seam=seam, shared=shared)
        if m is not None:  # a new list: the search's own stays whole in `shared`
            m = dataclasses.replace(m, found=[tuple(x[:keep] for x in f) for f in m.found], _info=None)
        out.append(m)
    return out[0], out[1]


def spliced(rt, ta, tb, a_end: int, b_start: int, length: int, alpha: float,
            shared: dict | None = None, beat: float | None = None) -> Result | None:
    """The splice of the best segment continuing A into the best segment arriving in B, in a
    transition (B placed to continue A), as a :class:`~posturemap.synth.retrieval.Result`;
    None when the library has no segment, or when either half's legs have no confidence (the
    trajectory needs both). ``shared``: as for :func:`~posturemap.synth.retrieval.match` (the
    seams searched once for both halves; with ``shared["alphas"]`` holding 0 and 1, no search
    at all after the single segment's). ``beat``: a leg confidence to beat; None, without
    replaying anything, when the splice's is not higher."""
    first, second = halves(rt, ta, tb, a_end, b_start, length, shared)
    if first is None or second is None:
        return None
    conf = [min(c1, c2) for c1, c2 in zip(first.confidence, second.confidence)]
    if conf[0] <= 0.0 or (beat is not None and conf[0] <= beat):
        return None
    up = rt.engine.up
    w = splice_weights(length, alpha)
    # Each half's rotations only where the splice uses them (w rises from 0 to 1).
    first_frames = (0, length - int(np.count_nonzero(w >= 1.0)))
    second_frames = (int(np.count_nonzero(w <= 0.0)), length)
    jit = _compiled()
    if jit is not None:  # the replays and the splice below in one call
        rots, gpos, heading, dtheta, shift, contacts = _spliced_compiled(jit, rt, first, second, w,
                                                                         (first_frames, second_frames))
    else:
        rots, gpos, heading, dtheta, shift, contacts = splice(
            replay(rt, first, skip_unconfident=True, frames=first_frames),
            replay(rt, second, skip_unconfident=True, frames=second_frames), w, ta.gpos[a_end],
            float(ta.heading[a_end]), tb.gpos[b_start], up)
    if floats(rt.engine, ta, tb, a_end, b_start, rots, gpos):
        return None
    # Per body part: the segment continuing A, with the one arriving in B under "then"; the
    # part's confidence is the splice's.
    parts = {part: {**entry, "confidence": round(c, 3), "then": second.info["parts"][part]}
             for (part, entry), c in zip(first.info["parts"].items(), conf)}
    centre, width = splice_blend(alpha)
    info = {"parts": parts, "confidence": round(min(conf), 3),
            "splice": {"centre": round(centre, 3), "width": round(width, 3)}}
    if first.own:  # the clips' own motion (a Retriever with ``whole``)
        info["own"] = True
    # The match distance the report gives: the half continuing A's.
    return Result(rots, gpos, heading, dtheta, shift, contacts, info, conf, first.distance)


def floats(eng, ta, tb, a_end: int, b_start: int, rots: np.ndarray, gpos: np.ndarray) -> bool:
    """Whether a splice (its rotations ``rots`` (L, J, 4), the root's tilt in its own column, and
    root path ``gpos`` (L, 3)) lifts both feet off the floor: its lowest ankle or toe at least
    :data:`FLOAT` leg lengths above the higher of A's and B's lowest at their seams, for
    :data:`FLOAT_S` seconds or more on end.

    Each half is a real motion corrected toward the other seam's pose, and SLERPing the legs of
    two gaits in different phases can fold both knees at once: a dash into a walk (Bandai, the
    map of all 174 clips, 20 frames) held both feet 37 cm up for 12 frames, the hips at standing
    height. On the bench's 300 cross-clip pairs of the held-out contents (styles) such floats,
    the lowest foot over 10 cm above the real frames' around the gap, came from 14 (7) splices
    and 2 (1) single segments; with this check 2 (3) and 3 (1). A run's flight, a few frames
    with both feet up, stays under the duration. The height-weighted skate rewards a foot in
    the air: on the bench's pairs it rose from 1.47 to 1.59 cm/s (styles 1.68 -> 1.82; the real
    frames' 3.0 / 3.6), pose validity and jerk came closer to the real frames' (docs/retrieval.md,
    "Splicing").
    """
    legs = eng._legs
    if not legs:
        return False
    up, root = eng._up, eng._root
    feet = np.unique(np.array([c[2] for c in legs] + list(eng._toes), dtype=np.int64))
    seam = max(min(ta.feet[a_end, :, up].min(), ta.toes[a_end, :, up].min()),
               min(tb.feet[b_start, :, up].min(), tb.toes[b_start, :, up].min()))
    pos = np.repeat(ta.motion.positions[a_end:a_end + 1], len(rots), axis=0)
    grot, gp = np.empty(rots.shape), np.empty(pos.shape)
    kernels.fk(eng.skeleton.parents, rots, pos, grot, gp)
    # The root's place is the path's; the joints above it are the identity in a replay.
    low = gpos[:, up] + gp[:, feet, up].min(axis=1) - gp[:, root, up]
    high = low > seam + FLOAT * eng._leg_length
    longest = run = 0
    for h in high.tolist():
        run = run + 1 if h else 0
        longest = max(longest, run)
    return longest >= max(2, round(FLOAT_S * ta.motion.fps))


def _spliced_compiled(jit, rt, first, second, w: np.ndarray, frames):
    """:func:`splice` of the :func:`~posturemap.synth.retrieval.replay` of ``first`` and of
    ``second`` (each with ``skip_unconfident`` and only its ``frames``; both with confident legs)
    in one compiled call (:func:`posturemap.synth.retrieval_numba.spliced`): the same values."""
    lib, ta, tb, length = rt.lib, first.ta, first.tb, first.length
    d = length + 1.0
    (s_a0, e_a0, *_), (s_a1, e_a1, *_) = first.found
    (s_b0, e_b0, *_), (s_b1, e_b1, *_) = second.found
    rots = np.empty((length, rt.engine.skeleton.num_joints, 4))
    gpos, heading, shift = np.empty((length, 3)), np.empty(length), np.empty(3)
    contacts = np.empty((length, lib.contacts.shape[1]), dtype=lib.contacts.dtype)
    dtheta = jit.spliced(lib.rots, lib.clip_start, lib.clip_of, lib.clip_end, s_a0, e_a0, s_a1, e_a1, s_b0, e_b0, s_b1,
                         e_b1, np.array([first.confidence[1] <= 0.0, second.confidence[1] <= 0.0]), d,
                         _sample_times(d), rt.part_joints[0], rt.part_joints[1], rt.open_joints, ta.rots, tb.rots,
                         np.array(first.ia), np.array(first.ib),
                         _hermite_offsets_cached(length, blend_frames(ta.motion.fps)),
                         np.array(frames, dtype=np.int64), lib.gpos, lib.heading, lib.contacts, ta.gpos, ta.heading,
                         tb.gpos, tb.heading, rt.engine._up, w, rots, gpos, heading,
                         shift, contacts, rt.engine._root, rt.upper_tops, retrieval.UPPER_LIFT)
    return rots, gpos, heading, float(dtheta), shift, contacts
