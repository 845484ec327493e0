"""Retrieval transitions: replay real library motion between A's end and B's start.

A transition fills the frames ``t = 1 .. L`` between A's end (``t = 0``) and B's start
(``t = d = L + 1``). For each body part (``lower``: root and legs, carrying the trajectory;
``upper``: spine, arms and head) it:

1. **searches** the motion library (:mod:`posturemap.synth.library`) for segments ``[s, e]`` of one
   clip whose start continues A (key joint positions and velocities in the heading frame, the
   root's velocity, turning rate and height) and whose end arrives in B, over time warps
   ``(e - s) / d`` of :data:`WARPS` (velocities compared at the warped speed); in
   in-betweening (B fixed, ``align=False``) also matching the root's displacement and turn
   over the gap. Candidates come through the posture map: the frames whose winning neuron
   (``global`` class) is among those nearest A's and B's postures (an inverted index, as
   IVF), then an exact re-rank of every candidate. On gaps of a second and more, while the
   body travels at a seam, the upper body's candidates there come from frames where it travels too
   (:meth:`Retriever.travelling`: arms that match at the seams but belong to a bow or a wave
   do not swing over walking legs). ``alpha`` weighs the two seams:
   ``2 (1 - alpha) cost_A + 2 alpha cost_B``: 0 picks motion that continues A, 1 motion that
   arrives in B;
2. **replays** the best :data:`TOP_K` segments (:func:`segments_averaged`: more on long gaps,
   where the legs keep only those in step with the best, :meth:`Retriever.in_step`, and the
   upper body weighs those in step with the legs twice, :meth:`Retriever.upper_in_step`),
   resampled to ``d`` frames, turned and moved to
   continue A, and averages them (per joint; the trajectory after turning each);
3. **removes the seam errors** with smooth offsets (:func:`offset_curves`): the value offsets
   at A and B carried from one into the other over the whole gap (a constant offset, such as
   another style's posture, stays constant), the velocity offsets fading from each seam over
   :data:`BLEND_S` seconds, so rotations, root height and trajectory meet A and B with
   continuous position and velocity; in in-betweening the root lands exactly on B; in
   transitions B takes the segment's end as its place (``last["dtheta"]``, ``last["shift"]``);
   where the legs are replayed, the upper body's top joint turns :data:`UPPER_LIFT` of the way
   from the legs' pelvis to its own segments' (:func:`lift_upper`: each part was recorded over
   its own pelvis; legs blended toward the fallback by a partial confidence are blended after
   it, so the chest then hangs from a pelvis the lift did not see);
4. **plants the feet** that are planted in the retrieved segment: two-bone IK holds them where
   they touch down (A's or B's spot at a seam), the correction carried smoothly through the
   swing (:func:`posturemap.synth.feet.lock_feet` with the segment's contacts);
5. **falls back** by confidence (:func:`confidences`): the match distance, the RMS difference of
   the part's joint rotations between the segment and A / B at the seams (degrees per joint, the
   larger seam), over 12-24 degrees for the legs between clips and 8-48 in in-betweening
   (``align=False``), times how much the root moves at the seams or, in in-betweening, must
   travel across the gap (:func:`still_weight`: standing gestures are interpolated); full up to
   twice the legs' full distance, none above 48 degrees, for the upper body, which follows the
   legs and, on short gaps,
   fades with :func:`upper_weight` (there the arms come from the fallback, which matches the
   seams' velocities); where a part's confidence is 0 it is the interpolating fallback
   (:func:`fallback_method`), at 1 the retrieved motion, in between a per-joint SLERP of the two.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ..core import kernels, quat
from ..learn.features import wrap_diff
from ..core.joints import ancestors, head_joint, part_masks, upper_tops
from .trajectory import rotate_about_up
from .library import INDEX_CLASS, MotionLibrary, clip_features, heading_frame, motion_features

WARPS = (0.75, 0.85, 0.93, 1.0, 1.08, 1.18, 1.33)  # segment duration / gap duration
TOP_K = 16  # segments averaged per part, on gaps up to TOP_K_RAMP_S[0] seconds ...
TOP_K_LONG = 24  # ... and from TOP_K_RAMP_S[1] seconds on (see segments_averaged)
TOP_K_RAMP_S = (1.1, 1.5)
# Seconds over which a seam's velocity offset fades (value offsets span the gap); see blend_frames.
BLEND_S = 0.33
BUDGET = 1536  # frames gathered per seam from the index (the neurons nearest the seam posture), ...
GATHER_NEURONS = 256  # at most this many of the nearest neurons are visited
PREFILTER = 32  # of those, the best matches at natural speed that become segment ends, ...
# ... and TOP_K, TOP_K_LONG where match takes them (segments_averaged): each counts frames or
# segments of a library at this frame rate and grows with a faster library's rate
# (moments_scale; a search called with no k keeps TOP_K).
LIBRARY_FPS = 30.0
# The legs' match distance (RMS degrees per joint): full confidence below, none above; in
# in-betweening (B fixed: align False) and between clips (align True). See confidences.
CONF_RANGE = {False: (8.0, 48.0), True: (12.0, 24.0)}
UPPER_CONF_RANGE = {False: (16.0, 48.0), True: (24.0, 48.0)}  # the upper body's, likewise
# In in-betweening the head's orientation in the world goes this far from the retrieved one toward
# the fallback's: a person steadies the head where they look, which the seams tell better than
# another performance does (docs/retrieval.md, "The head steadied").
HEAD_GAZE = 0.5
UPPER_FOLLOWS = 0.5  # the upper body is retrieved in full while the legs' confidence is at least this
# The upper body's match distance (degrees) over which the clips' own motion keeps a standing
# gesture (a bow, a wave) confident where the body stands at the seams (see confidences).
OWN_STANDING_RANGE = (8.0, 24.0)
# The foot lock holds the retrieved segment's planted feet where its legs lie within this match
# distance (degrees; between clips, the end of their ramp); beyond, it finds them itself.
CONTACTS_WITHIN = 24.0
FALLBACK = "damped"
FALLBACK_SHORT = ("spline", 0.6)  # gaps shorter than this many seconds fall back to this method
W_VEL = 1.0  # weight of velocities against positions in the match
W_ROOT = (1.0, 1.0, 0.5)  # root velocity, turning rate, height
W_DISP = 1.0  # root displacement and turn over the gap (in-betweening)
W_WARP = 2.0  # prefer the natural speed: W_WARP * log(warp)^2
DISP_SCALE = 0.25  # leg lengths of displacement error that cost as much as one feature std
STILL_SPEED = (0.2, 0.5)  # leg lengths / s (16-40 cm/s on Bandai): see still_weight
STEP_SPEED = (0.5, 1.0)  # leg lengths / s of the legs' key joints about the root: stepping in place
# On gaps from UPPER_TRAVEL_S seconds, while the root travels at a seam (from STILL_SPEED[1]), the
# upper body's candidates there come from frames whose root travels at least UPPER_TRAVEL times as
# fast (see Retriever.travelling).
UPPER_TRAVEL = 0.5
UPPER_TRAVEL_S = 1.0
# On gaps from TOP_K_RAMP_S[1] seconds the legs average only the segments whose feet are planted
# as the best segment's are in at least this share of the gap's frames (see Retriever.in_step);
# on gaps from UPPER_IN_STEP_S seconds the upper body's segments whose own feet step so with the
# legs' best weigh UPPER_IN_STEP_WEIGHT times as much as the others in its average (see
# Retriever.upper_in_step).
IN_STEP = 0.8
UPPER_IN_STEP_WEIGHT = 2.0
UPPER_IN_STEP_S = 1.5  # see Retriever.upper_in_step for 1 s
UPPER_RAMP_S = (0.25, FALLBACK_SHORT[1])  # gap seconds: the upper body the fallback's up to the first (see upper_weight)
# The upper body and the legs come from different segments, each with its own pelvis. The upper
# body's top joints (the spine's first) are turned this fraction of the way from the legs'
# pelvis to the upper segments' own, in the heading frame (see lift_upper): 0 keeps them
# relative to the legs' pelvis, 1 keeps the chest as its own segments carried it.
UPPER_LIFT = 0.5
# Where the upper body is the fallback's over retrieved legs and B stays where it is, the chest
# turns with the pelvis about the up axis by theta - free tanh(sin(theta) / free), free this many
# degrees: it holds its course while the pelvis swings with the steps, and follows a real turn
# (engine._fallback_chest; between clips it turns in full).
CHEST_FREE_DEG = 15.0
# In-betweening, a segment's path bends with its heading's correction (see bend_paths) in full
# where that removes at least BEND_GATE[1] of its miss at B, not at all below BEND_GATE[0].
BEND_GATE = (0.3, 0.7)


def fallback_method(length: int, fps: float) -> str:
    """The interpolating method a part falls back to: on gaps under ``FALLBACK_SHORT[1]`` seconds
    the seam velocities matter most (``spline``); on longer ones they are carried for as long as
    the motion at each seam keeps its velocity and let go (``damped``), where the cubic would
    carry a wave or a step on past its seam.

    ``damped`` replaced ``upm-valid`` (whose keys, real postures from the map, are no better a
    guess of a motion the library lacks than the straight line): on data the library never saw
    (a seeded sample of Bandai's second dataset, 140 clips, with a library of all of bandai1;
    windows sized per length) the default's L2Q went from 0.627 / 0.716x SLERP's to 0.621 / 0.712x
    at 30 / 45 frames with a fixed 0.05 s time constant, and to 0.584 / 0.700x once each seam's
    came from its motion (raised hands 0.93-0.97x -> 0.68-0.82x, waves at 45 frames
    0.96-0.98x -> 0.94-1.02x); over the bench's six Bandai splits from 0.642 / 0.711x to 0.630 /
    0.701x, then 0.614 / 0.693x (see ``docs/retrieval.md``, "Confidence and fallback")."""
    return FALLBACK_SHORT[0] if (length + 1) / fps < FALLBACK_SHORT[1] else FALLBACK


@dataclass
class Seams:
    """One seam as the search sees it: ``pose``/``vel`` (K, 3) key joints in the heading frame
    and their velocity (per second; A's end backward, B's start forward), ``root`` (5,) the
    root's velocity (3), turning rate and height. ``vectors`` caches its rows per body part."""

    pose: np.ndarray
    vel: np.ndarray
    root: np.ndarray
    vectors: dict = field(default_factory=dict)


class Retriever:
    """Search and synthesis over one library for one engine (skeleton, root, up)."""

    def __init__(self, engine, library: MotionLibrary, whole: bool = False):
        self.engine = engine
        self.lib = library
        # Every frame is a candidate, not only those the index files under the seams' neurons:
        # the clips' own motion (library.own_library), at most engine.OWN_FRAMES a side.
        self.whole = bool(whole)
        sk = engine.skeleton
        self.lower_mask, self.upper_mask = part_masks(sk, engine._root)
        self.part_joints = (np.flatnonzero(self.lower_mask), np.flatnonzero(self.upper_mask))
        self.open_joints = np.flatnonzero(~(self.lower_mask | self.upper_mask))  # above the root
        self.legs_mask = self.lower_mask.copy()  # the lower body but its root (engine._blend_root's)
        self.legs_mask[engine._root] = False
        self.upper_tops = upper_tops(sk.parents, engine._root, self.lower_mask, self.upper_mask)  # see lift_upper
        # The head and its ancestors, top first, where the upper body holds a head (see HEAD_GAZE).
        head = head_joint(sk)
        self.head_chain = (np.array(ancestors(sk.parents, head) + [head], dtype=np.int64)
                           if head >= 0 and self.upper_mask[head] else np.zeros(0, dtype=np.int64))
        # The library's own key joints: its features were computed for them when it was built.
        self.keys = np.concatenate([library.lower, library.upper]).astype(np.int64)
        self.kl = len(library.lower)
        space = engine.model.space_
        self.space = space
        cmap = engine.model.maps_[INDEX_CLASS]
        self.cmap = cmap
        dim_joint = np.concatenate([np.repeat(space.joints, 3), [space.root]])
        self.part_dims = [np.flatnonzero(space.active & m[dim_joint]) for m in (self.lower_mask, self.upper_mask)]
        # Columns of the index map's vectors that belong to each part (all, if a part has none).
        index_dims = space.class_dims[INDEX_CLASS]
        self.index_cols = []
        for dims in self.part_dims:
            cols = np.flatnonzero(np.isin(index_dims, dims))
            self.index_cols.append(cols if len(cols) else np.arange(len(index_dims)))
        self._mats = None
        self._index_w = None
        self._plan = None  # see _scale_plan
        self._dims_of = {}  # see seam_distances
        self._speed = None  # see travelling
        self._logmap = space.mode == "logmap" and not space.circular.any()  # seam_distances' compiled case

    def over(self, library: MotionLibrary, whole: bool = False) -> "Retriever":
        """This retriever's engine, joints and map over another ``library`` (of the same key
        joints): what depends on the library alone is made anew, the rest shared (building a
        retriever takes about 0.4 ms; the clips' own motion needs one per seam pair)."""
        if not (np.array_equal(library.lower, self.lib.lower) and np.array_equal(library.upper, self.lib.upper)):
            return Retriever(self.engine, library, whole)
        out = copy.copy(self)
        out.lib, out.whole = library, bool(whole)
        out._mats = out._speed = None
        if not np.array_equal(library.scale, self.lib.scale):
            out._plan = None
        return out

    # -- seams ----------------------------------------------------------------------------
    def seams(self, track, frames: list[int], which: int) -> Seams:
        """The seam at ``frames[which]`` of two consecutive frames ``frames`` of a track (A's end:
        ``which = 1``, velocity backward; B's start: ``which = 0``, forward)."""
        eng = self.engine
        sk = eng.skeleton
        rots = track.motion.rotations[frames]
        pos = track.motion.positions[frames].copy()
        grot, gp = np.empty(rots.shape), np.empty(pos.shape)
        kernels.fk(sk.parents, rots, pos, grot, gp)
        # Key joints relative to the clip's own root, in its own heading frame.
        p, v, r = clip_features(gp, track.gpos[frames], track.heading[frames], self.keys, eng._up,
                                track.motion.fps)
        return Seams(p[which], v[which], r[which])

    def seam_pair(self, ta, ia: list[int], tb, ib: list[int]) -> tuple[Seams, Seams]:
        """A's end seam (``seams(ta, ia, 1)``) and B's start seam (``seams(tb, ib, 0)``) in one go:
        one forward kinematics and one feature pass over the four frames (the same values); where
        numba is in use, one compiled call that also makes both seams' :meth:`query_vectors`."""
        if ta.motion.fps != tb.motion.fps:
            return self.seams(ta, ia, 1), self.seams(tb, ib, 0)
        eng = self.engine
        if _compiled() is not None:  # the steps below and both seams' rows of both parts, in one call
            k = len(self.keys)
            pose, vel, root = np.empty((2, k, 3)), np.empty((2, k, 3)), np.empty((2, 5))
            rows = [(np.empty((2, len(plan[0])), np.float32), np.empty((2, len(plan[3])), np.float32))
                    for plan in self._scale_plans()]
            _compiled().seam_rows(eng.skeleton.parents, ta.motion.rotations, ta.motion.positions, tb.motion.rotations,
                                  tb.motion.positions, np.array(ia), np.array(ib), ta.gpos, ta.heading, tb.gpos,
                                  tb.heading, self.keys, eng._up, float(ta.motion.fps), *self._plan[0], *self._plan[1],
                                  pose, vel, root, *rows[0], *rows[1])
            qa, qb = Seams(pose[0], vel[0], root[0]), Seams(pose[1], vel[1], root[1])
            for p, (pr, vr) in enumerate(rows):
                qa.vectors[p], qb.vectors[p] = (pr[0], vr[0]), (pr[1], vr[1])
            return qa, qb
        rots = np.concatenate([ta.motion.rotations[ia], tb.motion.rotations[ib]])
        pos = np.concatenate([ta.motion.positions[ia], tb.motion.positions[ib]])
        grot, gp = np.empty(rots.shape), np.empty(pos.shape)
        kernels.fk(eng.skeleton.parents, rots, pos, grot, gp)
        root_pos = np.concatenate([ta.gpos[ia], tb.gpos[ib]])
        heading = np.concatenate([ta.heading[ia], tb.heading[ib]])
        pose = heading_frame(gp[:, self.keys] - root_pos[:, None], heading, eng._up)
        vel, root = motion_features(pose, root_pos, heading, eng._up, ta.motion.fps, np.array([0, 2, 4]))
        return Seams(pose[1], vel[1], root[1]), Seams(pose[2], vel[2], root[2])

    def seam_distance(self, part: int, s: int, e: int, xa: np.ndarray, xb: np.ndarray) -> float:
        """Match distance in degrees: the larger, over the two seams, of the RMS joint-rotation
        difference between the segment's end posture and A's end / B's start over the part's
        joints (posture features; the root height counts in leg lengths as one radian)."""
        return self.seam_distances([(part, s, e)], xa, xb)[0]

    def seam_distances(self, segments, xa: np.ndarray, xb: np.ndarray) -> list[float]:
        """:meth:`seam_distance` of several segments ``[(part, s, e), ...]``, encoded in one go."""
        lib, space = self.lib, self.space
        frames = [f for _, s, e in segments for f in (s, e)]
        if self._logmap and _compiled() is not None:
            parts = tuple(p for p, _, _ in segments)
            if parts not in self._dims_of:  # the parts' dimensions, one after another, and where each starts
                dims = [self.part_dims[p] for p in parts]
                self._dims_of[parts] = (np.concatenate(dims).astype(np.int64),
                                        np.cumsum([0] + [len(d) for d in dims]).astype(np.int64))
            out = np.empty(len(segments))
            _compiled().seam_distances(lib.rots, lib.gpos, np.array(frames, dtype=np.int64), space.joints,
                                       space.reference, space.up, float(space.height_scale), xa, xb,
                                       *self._dims_of[parts], out)
            return out.tolist()
        rots = lib.rots[frames][:, space.joints].astype(np.float64)
        if space.mode == "logmap":  # space.encode_parts, with the hot kernel for the rotations
            x = np.empty((len(frames), 3 * len(space.joints) + 1))
            kernels.log_relative(rots, space.reference, x[:, :-1].reshape(len(frames), -1, 3))
            x[:, -1] = lib.gpos[frames, space.up] / space.height_scale
        else:
            x = space.encode_parts(rots, lib.gpos[frames, space.up])
        circ = space.circular
        out = []
        for i, (part, _, _) in enumerate(segments):
            dims = self.part_dims[part]
            d = max(np.linalg.norm(wrap_diff(x[2 * i], xa, circ)[dims]),
                    np.linalg.norm(wrap_diff(x[2 * i + 1], xb, circ)[dims]))
            out.append(float(np.degrees(d / math.sqrt(max(len(dims), 1) / 3.0))))
        return out

    @property
    def root_speed(self) -> np.ndarray:
        """Every library frame's horizontal root speed (N,), in leg lengths per second."""
        if self._speed is None:
            self._speed = horizontal_speed(self.lib.root, self.lib.up) / self.lib.leg
        return self._speed

    def travelling(self, frames: np.ndarray, q: Seams) -> np.ndarray:
        """Which of library ``frames`` (a boolean mask) may give the upper body at the seam
        ``q``: all of them while the root at ``q`` moves slower than ``STILL_SPEED[1]`` leg
        lengths per second; while it travels at ``v``, those whose root travels at least
        :data:`UPPER_TRAVEL` ``v`` (all of them if none does).

        The upper body is matched on its own joints (wrists and head relative to the root), so
        without this a walking seam's arms could come from a bow or a wave whose arms happen to
        be where the walker's are, and which then bows or waves in the middle of the gap over
        walking legs. Over six hold-outs of bandai1 (the bench's protocol), 26 of 54 retrieved
        windows of 3 s mixed walking legs with such arms on the split holding out the styles
        chimpira, musical and sad, and lost to SLERP's arms there; with this rule that split's
        L2Q at 4 s fell from 1.054x SLERP's to 0.973x, the six splits' from 0.919x to 0.898x
        (3 s: 0.860x -> 0.848x, 2 s: 0.775x -> 0.771x; 1 and 1.5 s within 0.2% on average,
        -1.8% to +2.3% per split: the split without forward walks loses at 1.5 s, whose walkers'
        arms the library's standing clips matched better than its sideways and backward walks;
        the skate unchanged). Half a second is too short for the arms to bow or wave: there it
        cost 0.9% L2Q, so it applies on gaps from :data:`UPPER_TRAVEL_S` (:meth:`upper_frames`).
        """
        v = float(horizontal_speed(q.root, self.lib.up)) / self.lib.leg
        if v < STILL_SPEED[1]:
            return np.ones(len(frames), dtype=bool)
        ok = self.root_speed[frames] >= UPPER_TRAVEL * v
        return ok if ok.any() else np.ones(len(frames), dtype=bool)

    def upper_frames(self, sa: np.ndarray, sb: np.ndarray, qa: Seams, qb: Seams, d: float, fps: float):
        """The gathered starts ``sa`` and ends ``sb`` the upper body's search may use on a gap of
        ``d`` frames at ``fps``: on gaps from :data:`UPPER_TRAVEL_S` seconds, those
        :meth:`travelling` at A's end (``qa``) and at B's start (``qb``); all on shorter ones."""
        if d / fps < UPPER_TRAVEL_S:
            return sa, sb
        return sa[self.travelling(sa, qa)], sb[self.travelling(sb, qb)]

    def in_step(self, s: np.ndarray, e: np.ndarray, d: float) -> np.ndarray:
        """Which of the legs' segments ``[s, e]`` (K,), best first, step in time with the best one
        over a gap of ``d`` frames (a boolean mask, the best always in): those whose feet, sampled
        at the gap's frames as the replay samples them, are planted or in the air as the best
        segment's are in at least :data:`IN_STEP` of the frames and feet (all of them on a rig
        without legs).

        On long gaps the seams decide less of the middle, and the best segments that agree at
        both seams walk their middle in different phases: their average swings its feet lower
        and slides them, while the foot lock holds the best segment's contacts. :func:`match`
        keeps only the segments in step on gaps from ``TOP_K_RAMP_S[1]`` seconds (where 24 are
        averaged). Over the six Bandai splits (windows of 10 + L + 10 frames at stride 40), the
        default's skate over the truth's at 2 / 3 / 4 s went from 0.83 / 0.86 / 1.01 on average
        (1.34 / 1.44 / 1.78 on the worst split) to 0.76 / 0.71 / 0.70 (1.24 / 1.13 / 1.14), its
        jerk from 4,931 / 3,773 / 3,136 to 5,242 / 4,364 / 4,030 cm/s^3 (the truth's 8,074 /
        7,235 / 6,805: the average of many segments is smoother than real motion), for L2Q
        0.771 / 0.848 / 0.898x SLERP's -> 0.772 / 0.855 / 0.911x; at 1.5 s the skate 0.80 ->
        0.77 (1.17 -> 1.13), L2Q 0.721 -> 0.722x; CMU 01_01 at 1.5 s (120 fps) L2Q 0.739 -> 0.726x.
        Averaging the best 8 regardless of their step took the skate less far (0.77 / 0.78 /
        0.89) for about the same L2Q (0.775 / 0.854 / 0.904x); 90% in step, further (0.74 /
        0.65 / 0.66) for more (0.776 / 0.861 / 0.920x).
        """
        keep = np.ones(len(s), dtype=bool)
        if len(s) < 2 or self.lib.contacts.shape[1] == 0:
            return keep
        c = self.gap_contacts(s, e, d)
        keep[1:] = (c[1:] == c[:1]).mean(axis=(1, 2)) >= IN_STEP
        return keep

    def upper_in_step(self, legs: tuple, upper: tuple, d: float) -> np.ndarray:
        """Which of the upper body's segments ``upper[0..1]`` (K,) step in time with the legs'
        best segment ``legs[0][0]``, ``legs[1][0]`` over a gap of ``d`` frames: their own clip's
        feet planted or in the air as the legs' are in at least :data:`IN_STEP` of the frames
        and feet (:meth:`in_step`'s measure). A boolean mask (none on a rig without legs).

        An arm swings in step with the legs of its own clip (each arm forward with the other
        leg), so an upper segment whose feet step as the legs' do swings its arms in the legs'
        phase; a standing clip's feet, planted throughout, agree with a walk's only while the
        walking feet are planted (about 60-70% of the frames), under the bound. :func:`match`
        weighs these :data:`UPPER_IN_STEP_WEIGHT` times as much as the others in the upper
        body's average on gaps from :data:`UPPER_IN_STEP_S` seconds. Over the six Bandai splits
        (windows of 10 + L + 10 frames at stride 40), L2Q over SLERP's at 1.5 / 2 s 0.717 /
        0.768 -> 0.711 / 0.760, lower on every split at both (the held-out styles 0.681 -> 0.669
        at 1.5 s), L2P 0.674 -> 0.672; CMU 01_01 at 1.5 s 0.711 -> 0.715 (weighing them 3 or 5
        times: Bandai 0.708 / 0.706, CMU 0.719 / 0.727). From 1 s: at 1.0 and 1.37 s every
        Bandai split and CMU lower too (the six splits' mean 0.641 -> 0.638 and 0.691 -> 0.687),
        but a 30-frame transition took 772 instead of 681 us (median, 400 seeded draws between
        two clips, alternated), half of it this check (about 45 us); from 0.5 s, CMU at 0.76 s
        lost 1.1%. Keeping only these (no weight for the others) gained most on the
        held-out styles (0.629 at 1.5 s) but averaged two or three segments where few were in
        step, and lost up to 0.97 L2Q in a window (CMU 0.753)."""
        if len(upper[0]) == 0 or self.lib.contacts.shape[1] == 0:
            return np.zeros(len(upper[0]), dtype=bool)
        ref = self.gap_contacts(legs[0][:1], legs[1][:1], d)
        return (self.gap_contacts(upper[0], upper[1], d) == ref).mean(axis=(1, 2)) >= IN_STEP

    def gap_contacts(self, s: np.ndarray, e: np.ndarray, d: float) -> np.ndarray:
        """The planted feet (K, L, legs) of segments ``[s, e]`` (K,) at the gap's frames t = 1 ..
        d - 1 of a gap of ``d`` frames, each the nearest recorded frame of the sample, as the
        replay takes its contacts."""
        i0, _, f = segment_times(self.lib, s, e, d)
        return self.lib.contacts[np.rint(i0[:, 2:-2] + f[:, 2:-2]).astype(np.int64)]

    # -- search ---------------------------------------------------------------------------
    def gather(self, x: np.ndarray, part: int | None = None) -> np.ndarray:
        """Library frames whose index neuron is among those nearest the posture ``x`` (D,).

        Neurons are visited nearest first until :attr:`budget` frames are gathered; with
        ``part``, nearness counts only the index map's dimensions of that body part's joints
        (the thighs for the legs, the clavicles and upper arms for the upper body). With
        ``whole``, every frame.
        """
        lib, cmap = self.lib, self.cmap
        if self.whole:
            return np.arange(len(lib), dtype=np.int64)
        if _compiled() is not None:
            cols = self.index_cols[part] if part is not None else np.arange(cmap.weights_.shape[1])
            return _compiled().gather(cmap.weights_, cols, x[self.space.class_dims[INDEX_CLASS][cols]],
                                      cmap.period_[cols], lib.index_ptr, lib.index_frames, GATHER_NEURONS,
                                      self.budget)
        cols = self.index_cols[part] if part is not None else slice(None)
        q = x[self.space.class_dims[INDEX_CLASS]][cols]
        w = cmap.weights_[:, cols]
        if np.isfinite(cmap.period_).any():  # euler features: angles on the circle
            diff = np.abs(w - q)
            diff = np.minimum(diff, cmap.period_[cols] - diff)
            d2 = np.einsum("ij,ij->i", diff, diff)
        else:
            d2 = np.einsum("ij,ij->i", w - q, w - q)
        n_take = min(len(w), GATHER_NEURONS)
        near = np.argpartition(d2, n_take - 1)[:n_take] if n_take < len(w) else np.arange(len(w))
        near = near[np.argsort(d2[near])]
        near = near[near < len(lib.index_ptr) - 1]  # neurons past the last indexed one hold no frame
        start = lib.index_ptr[near]
        count = lib.index_ptr[near + 1] - start
        cum = np.cumsum(count)
        stop = min(int(np.searchsorted(cum, self.budget)) + 1, len(near))
        if stop == 0 or cum[stop - 1] == 0:
            return np.zeros(0, dtype=np.int64)
        start, count, total = start[:stop], count[:stop], int(cum[stop - 1])
        # The CSR rows of the chosen neurons, one after another, without a Python loop.
        offset = np.repeat(start - (cum[:stop] - count), count)
        return lib.index_frames[offset + np.arange(total)]

    def gather_seams(self, xa: np.ndarray, xb: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """``[(gather(xa, 0), gather(xb, 0)), (gather(xa, 1), gather(xb, 1))]``: where numba is in
        use, in one pass over the index map's neurons."""
        if _compiled() is None or self.whole:
            return [(self.gather(xa, p), self.gather(xb, p)) for p in (0, 1)]
        cmap, lib = self.cmap, self.lib
        if self._index_w is None or self._index_w[0] is not cmap.weights_:
            # Per part: the map's columns, their features' dimensions and periods.
            dims = self.space.class_dims[INDEX_CLASS]
            self._index_w = (cmap.weights_,) + tuple((np.ascontiguousarray(cmap.weights_[:, c]), dims[c],
                                                      cmap.period_[c]) for c in self.index_cols)
        (w0, d0, period0), (w1, d1, period1) = self._index_w[1:]
        a0, b0, a1, b1 = _compiled().gather_seams(w0, w1, xa[d0], xa[d1], xb[d0], xb[d1], period0, period1,
                                                  lib.index_ptr, lib.index_frames, GATHER_NEURONS, self.budget)
        return [(a0, b0), (a1, b1)]

    def candidates(self, sa: np.ndarray, sb: np.ndarray, d: float, fps: float):
        """Candidate segments ``(s, e)`` (M,) from gathered starts ``sa`` and ends ``sb``."""
        lib = self.lib
        ratio = lib.fps / fps
        ns = np.unique(np.maximum(1, np.round(np.array(WARPS) * d * ratio)).astype(np.int64))
        s1 = np.repeat(sa, len(ns))
        e1 = s1 + np.tile(ns, len(sa))
        e2 = np.repeat(sb, len(ns))
        s2 = e2 - np.tile(ns, len(sb))
        s = np.concatenate([s1, s2])
        e = np.concatenate([e1, e2])
        ok = (s >= 0) & (e < len(lib))
        s, e = s[ok], e[ok]
        ok = lib.clip_of[s] == lib.clip_of[e]
        return s[ok], e[ok]  # may repeat a segment found from both seams: see search

    @property
    def lists(self):
        """The inverted index's lists with their frames' rows (as faiss's IVF-Flat lists hold their
        vectors), built on first use: per part ``(P, V, Vn)`` (N, D) float32, the rows of
        :meth:`_matrices` in the order of ``lib.index_frames`` (a neuron's frames one after
        another), ``Vn`` the velocities of each frame's next frame (a segment's end is matched
        with them); and ``pos_of`` (N,), each frame's row. The compiled search reads these:
        the frames gathered from a neuron are one stretch of memory, not scattered rows (its
        prefilter 91 -> 55 us a body part, the whole transition about 35 us faster, paired).
        They replace :attr:`matrices` there (built only for the numpy steps): 288 bytes a frame
        instead of 188 (Bandai). They depend on the library alone and are kept with it
        (:meth:`~posturemap.synth.library.MotionLibrary.derived`): every engine serving it shares
        them."""
        return self.lib.derived(("search lists", W_VEL, W_ROOT), self._build_lists)

    def _build_lists(self):
        lib = self.lib
        order = lib.index_frames  # a permutation of the frames (argsort of their neurons)
        nxt = np.minimum(np.arange(len(lib)) + 1, lib.clip_end - 1)[order]
        pos_of = np.empty(len(lib), dtype=np.int64)
        pos_of[order] = np.arange(len(lib))
        rows = []
        for part in (0, 1):
            P, V = self.matrices[part] if self._mats is not None else self.rows(part, lib.pose, lib.vel, lib.root)
            rows.append(tuple(np.ascontiguousarray(x) for x in (P[order], V[order], V[nxt])))
            for x in rows[-1]:
                x.setflags(write=False)
        return rows, pos_of

    @property
    def matrices(self):
        """:meth:`_matrices`, built on first use."""
        if self._mats is None:
            self._mats = self._matrices()
        return self._mats

    def _matrices(self):
        """Per part, the weighted matching features of every library frame as two matrices:
        ``P`` (N, Dp) positions (and the root's height) and ``V`` (N, Dv) velocities (and the
        root's velocity and turning rate), so that a seam costs ``|P - p|^2 + |warp V - v|^2``."""
        lib = self.lib
        return [self.rows(part, lib.pose, lib.vel, lib.root) for part in (0, 1)]

    def rows(self, part: int, pose, vel, root) -> tuple[np.ndarray, np.ndarray]:
        """Frames' features (``pose``, ``vel`` (N, K, 3), ``root`` (N, 5)) as the weighted rows
        ``P`` (N, Dp) and ``V`` (N, Dv) of ``part``, float32 (see :meth:`_matrices`)."""
        n = len(pose)
        return self._scaled(part, np.concatenate([pose.reshape(n, -1), vel.reshape(n, -1), root], axis=1))

    def query_vectors(self, part: int, q: Seams) -> tuple[np.ndarray, np.ndarray]:
        """The seam ``q`` as the rows of :meth:`_matrices` (p, v), float32 (kept on the seam;
        both parts from one gather of the seam's features)."""
        if part not in q.vectors:
            flat = np.concatenate([q.pose.ravel(), q.vel.ravel(), q.root])[None]
            for p in (0, 1):
                pr, vr = self._scaled(p, flat)
                q.vectors[p] = (pr[0], vr[0])
        return q.vectors[part]

    def _scaled(self, part: int, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Frames' flat features ``[pose (K*3), vel (K*3), root (5)]`` (N, 6K+5) as ``part``'s
        rows ``P``, ``V`` (float32): the part's key joints' positions divided by their spread
        (and, for the legs, the root's height), their velocities likewise with weight ``W_VEL``
        (and the root's velocity and turning rate), weighted by ``W_ROOT``."""
        pidx, pdiv, pmul, vidx, vmul = self._scale_plans()[part]
        return (np.ascontiguousarray(flat[:, pidx] / pdiv * pmul, dtype=np.float32),
                np.ascontiguousarray(flat[:, vidx] * vmul, dtype=np.float32))

    def _scale_plans(self) -> list:
        """:meth:`_scale_plan` of both parts, made on first use."""
        if self._plan is None:
            self._plan = [self._scale_plan(p) for p in (0, 1)]
        return self._plan

    def _scale_plan(self, part: int):
        """Where :meth:`_scaled` reads each of ``part``'s columns and how it scales them:
        ``P = flat[:, pidx] / pdiv * pmul``, ``V = flat[:, vidx] * vmul``."""
        lib, kl, n_keys = self.lib, self.kl, len(self.keys)
        keys = range(0, kl) if part == 0 else range(kl, n_keys)
        pidx = [3 * k + c for k in keys for c in range(3)]
        vidx = [3 * n_keys + i for i in pidx]
        pdiv, pmul = [lib.scale[2 * part]] * len(pidx), [1.0] * len(pidx)
        vmul = [math.sqrt(W_VEL) / lib.scale[2 * part + 1]] * len(vidx)
        if part == 0:
            w = np.sqrt(np.array(W_ROOT)) / lib.scale[4:7]
            root = 6 * n_keys
            pidx.append(root + 4)
            pdiv.append(1.0)
            pmul.append(w[2])
            vidx += [root, root + 1, root + 2, root + 3]
            vmul += [w[0]] * 3 + [w[1]]
        return (np.array(pidx), np.array(pdiv, dtype=np.float64), np.array(pmul, dtype=np.float64), np.array(vidx),
                np.array(vmul, dtype=np.float64))

    def costs(self, part: int, s, e, qa: Seams, qb: Seams, d: float, fps: float, alpha: float,
              disp=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Match costs of segments ``(s, e)`` for ``part`` (0 lower, 1 upper): (total, at A, at B).

        Velocities of the library are compared at the speed they are replayed at: times the
        warp ``(e - s) / lib.fps`` over ``d / fps`` (a segment longer than the gap plays faster).
        """
        ca, cb = self.pair_costs(part, s, e, qa, qb, d, fps)
        return self.total(part, s, e, ca, cb, d, fps, alpha, disp), ca, cb

    def pair_costs(self, part: int, s, e, qa: Seams, qb: Seams, d: float, fps: float):
        """The seam costs of :meth:`costs` alone: at A (``s`` against ``qa``) and at B (``e``
        against ``qb``), velocities at the replayed speed."""
        pm, vm = self.matrices[part]
        rate = self.warp(s, e, d, fps)
        nxt = np.minimum(e + 1, self.lib.clip_end[e] - 1)
        return (seam_costs(pm, vm, s, s, *self.query_vectors(part, qa), rate),
                seam_costs(pm, vm, e, nxt, *self.query_vectors(part, qb), rate))

    def warp(self, s, e, d: float, fps: float) -> np.ndarray:
        """Segments' warps: source duration over gap duration."""
        return ((e - s) / self.lib.fps) / (d / fps)

    def total(self, part: int, s, e, ca, cb, d: float, fps: float, alpha: float, disp=None) -> np.ndarray:
        """The cost ranked at ``alpha``: seam costs ``ca``, ``cb`` weighted by alpha, the warp's
        penalty and (in-betweening, legs) the root displacement's error."""
        total = 2 * (1 - alpha) * ca + 2 * alpha * cb + W_WARP * np.log(self.warp(s, e, d, fps)) ** 2
        if disp is not None and part == 0:
            total = total + W_DISP * self.displacement_cost(s, e, disp)
        return total

    def displacement_cost(self, s, e, disp) -> np.ndarray:
        """Squared error of the root's displacement and turn over ``[s, e]`` against ``disp``.

        ``disp`` = (dx, dz, dtheta): the gap's displacement in A's heading frame and turn.
        """
        lib = self.lib
        up = lib.up
        a, b = (up + 1) % 3, (up + 2) % 3
        delta = lib.gpos[e] - lib.gpos[s]
        h = lib.heading[s]
        c, sn = np.cos(h), np.sin(h)
        dx = c * delta[:, a] + sn * delta[:, b]
        dz = -sn * delta[:, a] + c * delta[:, b]
        turn = lib.heading[e] - lib.heading[s]
        scale = DISP_SCALE * lib.leg
        return ((dx - disp[0]) ** 2 + (dz - disp[1]) ** 2) / scale**2 + (turn - disp[2]) ** 2 / 0.25**2

    @property
    def budget(self) -> int:
        """How many frames :meth:`gather` collects per seam: :data:`BUDGET` at
        :data:`LIBRARY_FPS`, in proportion to a faster library's frame rate, so that they hold
        as many moments of motion. With 1,536 at 60 fps (half the moments), bandai1's
        hold-outs rewritten at 60 fps (docs/another-rig.md) scored L2Q 0.644 / 0.729x SLERP's
        on held-out styles at 1 / 1.5 s where Bandai's own 30 fps scored 0.56 / 0.64x; with
        3,072 (and :func:`segments_averaged` in proportion too) 0.561 / 0.632x. A slower
        library keeps 1,536 (:func:`moments_scale`)."""
        return max(1, round(BUDGET * moments_scale(self.lib.fps)))

    @property
    def keep(self) -> int:
        """How many gathered frames per seam the prefilter keeps: :data:`PREFILTER` at
        :data:`LIBRARY_FPS`, in proportion to a faster library's frame rate (neighbouring
        frames at a higher rate are near copies of each other: at 120 fps, 96 frames held a
        quarter of the moments, and CMU's 1.5 s gaps lost 4-5% L2Q against 128 to 384;
        :func:`moments_scale`)."""
        return max(1, round(PREFILTER * moments_scale(self.lib.fps)))

    def prefilter(self, part: int, frames: np.ndarray, q: Seams, end: bool, keep: int) -> np.ndarray:
        """The ``keep`` frames of ``frames`` that best match the seam ``q`` at natural speed.

        ``end``: match as a segment's last frame (velocity towards the next frame).
        """
        if len(frames) <= keep:
            return frames
        pm, vm = self.matrices[part]
        fv = np.minimum(frames + 1, self.lib.clip_end[frames] - 1) if end else frames
        c = seam_costs(pm, vm, frames, fv, *self.query_vectors(part, q), np.ones(len(frames)))
        return frames[np.argpartition(c, keep - 1)[:keep]]

    def search(self, part, qa, qb, sa, sb, d, fps, alpha, disp=None, k=None, exhaustive=False):
        """The ``k`` best segments of ``part`` from gathered start and end frames ``sa``, ``sb``.

        Returns arrays ``s, e, total, cost_a, cost_b`` (best first), or None when no segment
        fits. ``exhaustive``: every start frame of the library with every warp (the exact
        search the index is measured against).
        """
        return self.search_alphas(part, qa, qb, sa, sb, d, fps, (alpha,), disp, k, exhaustive)[0]

    def search_alphas(self, part, qa, qb, sa, sb, d, fps, alphas, disp=None, k=None, exhaustive=False):
        """:meth:`search` for several ``alphas`` at once: one list entry per alpha, the same as
        searching for each alone (the candidates and their seam costs do not depend on alpha;
        only the ranking does), at the cost of one search."""
        k = _top_k(k)
        alphas = tuple(float(a) for a in alphas)
        if part == 1 and not exhaustive:
            sa, sb = self.upper_frames(sa, sb, qa, qb, d, fps)
        if not exhaustive and _compiled() is not None:
            return self._search_compiled(part, qa, qb, sa, sb, d, fps, alphas, disp, k)
        return self._search_numpy(part, qa, qb, sa, sb, d, fps, alphas, disp, k, exhaustive)

    def search_parts(self, qa, qb, gathered, d, fps, alphas, disp=None, k=None, exhaustive=False):
        """:meth:`search_alphas` of both body parts (``gathered`` = ``[(sa, sb)]`` per part; ``disp``
        for the lower body only): ``[per alpha]`` per part. Where numba is in use, one compiled call
        (:func:`posturemap.synth.retrieval_numba.search_parts`)."""
        if exhaustive or _compiled() is None:
            return [self.search_alphas(p, qa, qb, *gathered[p], d, fps, alphas, disp if p == 0 else None, k,
                                       exhaustive) for p in (0, 1)]
        k = _top_k(k)
        rows, pos_of = self.lists
        (sa0, sb0), (sa1, sb1) = gathered
        sa1, sb1 = self.upper_frames(sa1, sb1, qa, qb, d, fps)
        found = _compiled().search_parts(
            *rows[0], *rows[1], pos_of, self.lib.clip_of, sa0, sb0, sa1, sb1, *self.query_vectors(0, qa),
            *self.query_vectors(0, qb), *self.query_vectors(1, qa), *self.query_vectors(1, qb),
            *self._kernel_terms(d, fps, alphas, disp), k)
        return [_ranked(*(x[p] for x in found)) for p in (0, 1)]

    def _search_numpy(self, part, qa, qb, sa, sb, d, fps, alphas, disp, k, exhaustive=False):
        """:meth:`search_alphas` in numpy steps (the reference of :meth:`_search_compiled`)."""
        if exhaustive:
            s, e = self.candidates(np.arange(len(self.lib)), np.zeros(0, np.int64), d, fps)
            if part == 1 and d / fps >= UPPER_TRAVEL_S:  # upper_frames' rule, per segment: either end
                keep = self.travelling(s, qa) | self.travelling(e, qb)
                s, e = s[keep], e[keep]
        else:
            s, e = self.candidates(self.prefilter(part, sa, qa, False, self.keep),
                                   self.prefilter(part, sb, qb, True, self.keep), d, fps)
        if len(s) == 0:
            return [None] * len(alphas)
        out = []
        ca, cb = self.pair_costs(part, s, e, qa, qb, d, fps)
        for alpha in alphas:
            total = self.total(part, s, e, ca, cb, d, fps, alpha, disp)
            # The k best distinct segments (a segment can come from both seams' frames, twice).
            m = min(2 * k, len(s))
            best = np.argpartition(total, m - 1)[:m] if m < len(s) else np.arange(len(s))
            best = best[np.lexsort((e[best], s[best], total[best]))]
            keep = np.ones(len(best), dtype=bool)
            keep[1:] = (s[best][1:] != s[best][:-1]) | (e[best][1:] != e[best][:-1])
            best = best[keep][:k]
            out.append((s[best], e[best], total[best], ca[best], cb[best]))
        return out

    def _search_compiled(self, part, qa, qb, sa, sb, d, fps, alphas, disp, k):
        """:meth:`search_alphas` in one compiled call (:func:`posturemap.synth.retrieval_numba.search`)."""
        rows, pos_of = self.lists
        return _ranked(*_compiled().search(
            *rows[part], pos_of, self.lib.clip_of, np.asarray(sa, dtype=np.int64), np.asarray(sb, dtype=np.int64),
            *self.query_vectors(part, qa), *self.query_vectors(part, qb),
            *self._kernel_terms(d, fps, alphas, disp if part == 0 else None), k))

    def _kernel_terms(self, d, fps, alphas, disp):
        """The arguments both compiled searches take after the seams' rows: the durations, warp
        penalties and speed factors, the prefilter's size, the alphas, and the displacement term
        (whether, the library's root path, the gap's ``disp``, its scale and weight)."""
        lib = self.lib
        return (*_warp_terms(float(d), float(lib.fps), float(fps), WARPS, W_WARP), self.keep,
                np.array(alphas, dtype=np.float64), disp is not None, lib.gpos, lib.heading, lib.up,
                np.array(disp if disp is not None else (0.0, 0.0, 0.0), dtype=np.float64), DISP_SCALE * lib.leg,
                W_DISP)


def segments_averaged(length: int, fps: float, lib_fps: float = LIBRARY_FPS) -> int:
    """How many best segments each body part averages on a gap of ``length`` frames:
    :data:`TOP_K` up to ``TOP_K_RAMP_S[0]`` seconds (from A's last kept frame to B's first,
    ``(length + 1) / fps``), :data:`TOP_K_LONG` from ``TOP_K_RAMP_S[1]`` on, linear in between;
    for a library faster than :data:`LIBRARY_FPS`, in proportion to its rate (segments that
    start a frame apart at 60 fps are near copies: as many of them hold half the moments;
    :func:`moments_scale`).

    The longer the gap, the less its seams decide its middle, and there the mean of more real
    segments is the better estimate (a smaller expected error, as for any average of
    plausible futures). Over the six Bandai splits (the bench's protocol), 24 instead of 16 at
    45 frames (1.53 s): L2Q against SLERP's 0.728x -> 0.722x (five splits lower, one the same),
    L2P 0.685x -> 0.683x; at 60 / 90 frames 0.780 / 0.867x -> 0.775 / 0.860x; the skate 2%
    higher at 45 frames (2.09 -> 2.14 cm/s, the truth's 1.6-4.2), 2-4% at 60-90. Weighting the
    segments by their cost instead was worse (docs/retrieval.md). Gaps up to 1.1 s (33 frames
    at 30 fps) keep 16: no change there, nor in the time of the 30-frame transition.
    """
    lo, hi = TOP_K_RAMP_S
    u = min(max(((length + 1) / float(fps) - lo) / (hi - lo), 0.0), 1.0)
    return max(1, int(round((TOP_K + u * (TOP_K_LONG - TOP_K)) * moments_scale(lib_fps))))


def moments_scale(lib_fps: float) -> float:
    """The factor on the search's counts of frames and segments (:data:`BUDGET`,
    :data:`PREFILTER`, :data:`TOP_K`, :data:`TOP_K_LONG`, the splice's halves) for a library
    at ``lib_fps``: its rate over :data:`LIBRARY_FPS`, so that a faster library's counts hold
    as many moments of motion, and never under 1, so that a slower one's hold more (at the
    cost of a 30 fps search). Bandai's hold-outs resampled to 24 fps (library and clips), L2Q
    against SLERP's at 1 / 1.5 s: held-out styles 0.558 / 0.652x with the counts in proportion,
    0.545 / 0.638x with 30 fps's; held-out contents 0.641 / 0.715x and 0.639 / 0.703x (L2P
    0.532 / 0.617x -> 0.521 / 0.604x and 0.660 / 0.724x -> 0.661 / 0.715x)."""
    return max(float(lib_fps), LIBRARY_FPS) / LIBRARY_FPS


def _top_k(k: int | None) -> int:
    """How many best segments a search keeps (:data:`TOP_K` by default); at least 1."""
    k = TOP_K if k is None else int(k)
    if k < 1:
        raise ValueError(f"top_k must be at least 1, got {k}")
    return k


def _ranked(s, e, total, ca, cb, count) -> list:
    """A compiled search's rows (A, k) and counts (A,) as one entry per alpha: ``(s, e, total,
    cost_a, cost_b)`` of its best segments, or None where none fits."""
    return [(s[r, :n], e[r, :n], total[r, :n], ca[r, :n], cb[r, :n]) if n else None
            for r, n in enumerate(count.tolist())]


@lru_cache(maxsize=256)
def _warp_terms(d: float, lib_fps: float, fps: float, warps: tuple, w_warp: float):
    """The segment durations (W,) of a gap of ``d`` frames (as :meth:`Retriever.candidates` makes
    them from ``warps``), their warp penalties and speed factors (as :meth:`Retriever.costs`)."""
    ns = np.unique(np.maximum(1, np.round(np.array(warps) * d * (lib_fps / fps))).astype(np.int64))
    rho = (ns / lib_fps) / (d / fps)
    out = (ns, w_warp * np.log(rho) ** 2, rho)
    for a in out:
        a.setflags(write=False)
    return out


def horizontal_speed(root: np.ndarray, up: int) -> np.ndarray:
    """The root's horizontal speed (per second) of root feature rows ``root`` (..., 5): the
    length of their velocity (the first three columns) without the ``up`` axis."""
    return np.hypot(root[..., (up + 1) % 3], root[..., (up + 2) % 3])


def still_weight(qa: Seams, qb: Seams, leg: float, up: int, travel: float = 0.0, lower: int = 0) -> float:
    """How much the character moves: 0 when the root stands still at both seams (its horizontal
    speed at the faster seam below ``STILL_SPEED[0]`` leg lengths per second) and has nowhere to
    go, 1 from ``STILL_SPEED[1]``.

    ``travel``: the horizontal speed (scene units per second) the gap itself asks for, in
    in-betweening the root's distance from A's end to B's start over the gap's duration (0 in
    transitions, where B takes the segment's place). The faster of the seams and the gap counts:
    a character standing at both seams who must cross two metres in between walks there.

    ``lower``: the legs' key joints (the first rows of the seams' ``vel``, about the root in its
    heading frame). Where they step faster than ``STEP_SPEED`` leg lengths per second at a seam,
    the legs step about a root that stays: a clip "in place", as game assets often are (a walk
    whose root never leaves its spot). The weight is then that of the step: 1 from
    ``STEP_SPEED[1]``. A bow's or a wave's feet stay put, and the root's speed alone decides. In
    in-betweening of six bandai1 walks and runs made in place (their hips held over one spot; a
    map of eleven travelling walks and runs, 40 windows of 30 frames), the default's error in
    the joints' global rotations fell from 1.06 (interpolated, confidence 0) to 0.75, SLERP's
    1.14; the bench's splits moved within -0.2% to +0.4% L2Q at 45 frames (CMU 01_01 at 60 frames
    0.519 -> 0.526x SLERP's, LaFAN1's other performers at 1 / 1.5 s 0.713 / 0.790 -> 0.715 /
    0.792x: more of their standing frames shuffle the feet).

    Standing gestures (bows, waves, pointing) are left to interpolation: on the benchmark's
    held-out styles, retrieved standing motion of other styles shuffled the feet and was less
    accurate than SLERP (L2Q at 30 frames: bows 0.255 against 0.175), while with this weight it
    is as accurate (0.168) and locomotion is unchanged. Before the gap's travel counted, a
    1.5 s gap of CMU 01_01 that stops, walks and stops again was interpolated too, and its feet
    glided over the floor at 27-29 cm/s (the truth's 3).
    """
    lo, hi = STILL_SPEED
    speed = max(max(float(horizontal_speed(q.root, up)) for q in (qa, qb)), travel) / leg
    weight = min(max((speed - lo) / (hi - lo), 0.0), 1.0) if hi > lo else 1.0
    if lower and weight < 1.0:  # legs stepping about a root that stays (a clip "in place")
        steps = max(float(horizontal_speed(q.vel[:lower], up).max()) for q in (qa, qb)) / leg
        lo, hi = STEP_SPEED
        weight = max(weight, min(max((steps - lo) / (hi - lo), 0.0), 1.0))
    return weight


def confidences(distance, still: float, upper: float, both: bool = True, *, align: bool,
                own: bool = False) -> list[float]:
    """The confidence (0..1) of each body part of a match, from its match distances (degrees,
    :meth:`Retriever.seam_distances`), :func:`still_weight` and :func:`upper_weight`.

    The legs: full below ``CONF_RANGE[align][0]`` of match distance, none above
    ``CONF_RANGE[align][1]``, linear in between, times ``still``. The upper body (``both``: one
    segment matched at both seams) over ``UPPER_CONF_RANGE[align]`` (full up to twice the legs'
    full distance), and following the legs that carry it: in full while their confidence is at
    least :data:`UPPER_FOLLOWS`, less below (a library that cannot make the step does not lend
    its arms either), times ``upper``. Another style's arms lie far from the library's at the
    seams, but much of that distance is posture, which the seam correction carries through the
    gap (:func:`offset_curves`). For the halves of a splice (``both`` False: each matched at one
    seam, between clips) both parts keep the legs' range, times ``still`` (and ``upper`` for
    the upper body).

    In in-betweening (``align`` False: B fixed, both seams from one performance) the ramps are
    wide, 8-48 degrees for the legs and 16-48 for the upper body: a typical match (12-20 degrees
    on Bandai's held-out clips, 11-17 on LaFAN1's other performers) is 0.7-0.9 confident, and
    ``damped``, the fallback, takes the rest. Real motion from another performance and the
    interpolation of this performance's own seams err in different ways, and their blend errs
    less than either where neither is sure; full confidence is kept for a segment that nearly
    continues the seams. Between clips (``align`` True) the ramps stay 12-24 and 24-48 degrees:
    there the fallback interpolates between two different motions, a weaker guess than real
    motion, and the wide ramps gave mixed results. The measurements (every Bandai split, LaFAN1,
    CMU, a library far from the clips, the ramps tried and not kept) are in
    ``docs/retrieval.md``, "Wide ramps in in-betweening".

    ``own``: the segments are the clips' own motion (:func:`posturemap.synth.library.own_library`).
    Where the body stands at the seams (``still`` under 1, 0 at a bow or a wave), another
    performance's arms are held back with the legs, but the performer's own wave goes on as
    they waved it: the upper body keeps the confidence of its match distance over
    :data:`OWN_STANDING_RANGE` (the legs' ramp without ``still`` in place of ``lower``) where that
    is the higher.
    """
    def ramp(x, lo, hi):
        return min(max((hi - x) / (hi - lo), 0.0), 1.0)

    lo, hi = CONF_RANGE[bool(align)]
    legs = ramp(distance[0], lo, hi)
    lower = legs * still
    if both:
        arms = ramp(distance[1], *UPPER_CONF_RANGE[bool(align)]) * min(lower / UPPER_FOLLOWS, 1.0) * upper
        if own:  # the performer's own gesture goes on where the body stands (see OWN_STANDING_RANGE)
            arms = max(arms, ramp(distance[1], *OWN_STANDING_RANGE) * min(legs / UPPER_FOLLOWS, 1.0) * upper)
        return [lower, arms]
    return [lower, ramp(distance[1], lo, hi) * still * upper]


def upper_weight(length: int, fps: float) -> float:
    """How much of the upper body is retrieved on a gap of ``length`` frames: 0 up to
    ``UPPER_RAMP_S[0]`` seconds (the fallback's there, the spline's), 1 from
    ``UPPER_RAMP_S[1]`` (where the fallback turns from the spline to ``damped``), linear in
    between, where the arms are a per-joint SLERP of the spline and the retrieved motion.

    On short gaps the arms' swing is predicted by the seams' velocities better than by another
    performance's swing; the legs stay retrieved (their planted feet are the point). Held-out
    (the bench's protocol; L2Q / L2P, before -> after): CMU 01_01 at 120 fps, 30 frames (0.26 s)
    0.161 / 1.213 -> 0.147 / 1.007 (the spline: 0.154 / 0.953), 45 frames 0.278 / 2.217 ->
    0.255 / 1.955 (0.279 / 2.017), 60 frames 0.371 / 3.070 -> 0.350 / 2.884; Bandai's held-out
    styles at 8-15 frames at 30 fps 1-2% lower both ways, held-out contents within 1%; foot
    skate unchanged. Ramping the legs too lowered L2Q and L2P further but let the feet slide
    (held-out styles, 8 frames: skate 4.5 -> 6.5 cm/s, the truth's 3.8).
    """
    lo, hi = UPPER_RAMP_S
    seconds = (length + 1) / float(fps)
    return min(max((seconds - lo) / (hi - lo), 0.0), 1.0) if hi > lo else float(seconds >= lo)


def blend_frames(fps: float) -> float:
    """Frames over which a seam's velocity offset fades (:func:`offset_curves`): :data:`BLEND_S`
    seconds, in in-betweening (B fixed) and in transitions (B placed to continue A) alike.

    In in-betweening, over six hold-outs (the bench's two and four more splits of bandai1 by
    style and by motion type), L2Q at 30 and 45 frames averaged 0.718x SLERP's with 0.67 s,
    0.696x with 0.33 s, 0.699x with 0.2 s: the real motion takes over sooner. Transitions kept
    0.67 s until the bench measured feet off the floor: a seam's velocity offset carried that
    long continues the leg's swing where the segment's foot is planted (a foot that has just
    landed at A's end, its knee and hip still turning, rose 10 cm over the next 0.3 s while the
    other foot swung: both feet in the air in a walk), and the foot lock holds a planted foot
    over the floor but keeps its height. Between two held-out clips (100 pairs at 20 frames,
    held-out contents / styles), with 0.67 s -> 0.33 s: feet off the floor 1.50 / 2.45 ->
    1.09 / 1.69 cm on average, over 10 cm in 1 / 3 -> 0 / 0 pairs; pose validity 1.37 / 1.17 ->
    1.28 / 1.12 (the real frames' 1.20 / 1.04); jerk 18,300 / 15,500 -> 17,700 / 15,300 cm/s^3
    (real 19,300 / 12,700); the foot skate 1.59 / 1.82 -> 1.84 / 2.01 cm/s (real 3.0 / 3.6: a
    foot nearer the floor weighs more in it). 0.25 and 0.2 s lowered the float a little more for
    more jerk.
    """
    return BLEND_S * float(fps)


def offset_curves(t: np.ndarray, d: float, blend: float) -> np.ndarray:
    """Seam offset curves (4, len(t)) at times ``t`` of a gap from 0 (A's end) to ``d`` (B's start).

    Rows: A's value offset, falling from 1 at ``t = 0`` to 0 at ``t = d`` (``1 - smoothstep(t / d)``);
    A's velocity offset, the cubic Hermite ``h10`` over ``blend`` frames (at most ``d``: value 0
    and slope 1 at ``t = 0``, value and slope 0 from ``t = blend`` on); B's value and velocity
    offsets, their mirror images into ``t = d``. Adding them to a curve moves its ends onto A and
    B, value and velocity; what differs between the curve and the seams in value is carried from
    A's offset into B's over the whole gap (a constant offset, such as another style's posture,
    stays constant), what differs in velocity only near its seam.

    The first version let the value offsets fade as the velocity offsets did then (0.67 s), so that
    the middle of a long gap was the library's motion unchanged, posture and all: a retrieved arm
    swing of another style went back to that style's posture in the middle of the gap. Over six
    hold-outs (see :func:`blend_frames`), with the confidences of :func:`confidences`, L2Q at 30
    and 45 frames averaged 0.773x SLERP's that way, 0.696x now.
    """
    blend = min(float(blend), d)
    t = np.asarray(t, dtype=float)
    out = np.zeros((4, len(t)))
    for row, tau, sign in ((0, t, 1.0), (2, d - t, -1.0)):
        w = np.clip(tau / d, 0.0, 1.0)
        out[row] = 2 * w**3 - 3 * w**2 + 1
        u = np.clip(tau / blend, 0.0, 1.0)
        out[row + 1] = sign * blend * (u**3 - 2 * u**2 + u)
    return out


def hermite_offsets(length: int, blend: float) -> np.ndarray:
    """:func:`offset_curves` at the new frames ``t = 1 .. length`` of a gap ``d = length + 1``."""
    return offset_curves(np.arange(1, length + 1), length + 1.0, blend)


@lru_cache(maxsize=64)
def _hermite_offsets_cached(length: int, blend: float) -> np.ndarray:
    """:func:`hermite_offsets`, kept per (length, blend) and read-only."""
    out = hermite_offsets(length, blend)
    out.setflags(write=False)
    return out


def segment_times(lib: MotionLibrary, s: np.ndarray, e: np.ndarray, d: float):
    """Where library segments ``[s, e]`` (K,) are sampled at output times ``t = -1 .. d + 1``.

    Returns ``(i0, i1, f)``, each (K, T) with ``T = d + 3``: the library frames on both sides
    of each sample and the fraction between them. A time before the clip's start or after its
    end (the samples one frame outside a segment at a clip's edge, which only give the seams'
    velocities) is extrapolated from the clip's first or last two frames: held on the edge
    frame, the segment read as still there, and the seam correction added A's whole velocity
    to the segment's own (a walk backwards continued from its clip's first frame, in a map of
    two clips: the root's step jumped from 3.1 to 5.5 cm a frame at A's seam). The numpy steps
    of :func:`replay` (its compiled call runs :func:`posturemap.synth.retrieval_numba.segment_times`).
    """
    t = _sample_times(d)
    u = s[:, None] + t[None] * ((e - s) / d)[:, None]
    lo = lib.clip_start[lib.clip_of[s]][:, None]
    hi = (lib.clip_end[s] - 1)[:, None]
    i0 = np.minimum(np.maximum(np.floor(u).astype(np.int64), lo), np.maximum(hi - 1, lo))
    return i0, np.minimum(i0 + 1, hi), u - i0


@lru_cache(maxsize=64)
def _sample_times(d: float) -> np.ndarray:
    """The output times ``-1 .. d + 1`` of :func:`segment_times`, kept per ``d`` and read-only."""
    t = np.arange(-1, d + 2, dtype=float)
    t.setflags(write=False)
    return t


def sample_trajectory(lib: MotionLibrary, i0, i1, f) -> tuple[np.ndarray, np.ndarray]:
    """Root positions (K, T, 3) and headings (K, T) at the samples of :func:`segment_times`."""
    gpos = lib.gpos[i0] + f[..., None] * (lib.gpos[i1] - lib.gpos[i0])
    return gpos, lib.heading[i0] + f * (lib.heading[i1] - lib.heading[i0])


def sample_rotations(lib: MotionLibrary, i0, i1, f, joints: np.ndarray) -> np.ndarray:
    """Rotations (K, T, M, 4) of ``joints`` (M,) at the samples: lerp of neighbours, not normalised
    (:func:`average_rotations` normalises their sum, so the mean weighs each segment by its
    lerp's length: halfway between two neighbouring frames of bandai1, 1 - 5e-6 for the median
    pair, 1 - 2e-3 at the 99th percentile)."""
    q0 = lib.rots[i0][:, :, joints].astype(np.float64)
    q1 = lib.rots[i1][:, :, joints].astype(np.float64)
    q1 = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0, -q1, q1)
    return q0 + f[..., None, None] * (q1 - q0)


def replay_rotations(lib: MotionLibrary, i0, i1, f, joints, a2, b2, curves,
                     frames: tuple[int, int] | None = None, out: np.ndarray | None = None,
                     weights: np.ndarray | None = None) -> np.ndarray:
    """The new frames' rotations (L, M, 4) of ``joints``: the segments sampled and averaged
    (:func:`average_rotations`), the average's seams corrected (:func:`offset_rotations`).
    ``frames``: ``(lo, hi)``, only the new frames ``lo <= t < hi``; the others are the identity.
    ``out``: the whole skeleton's frames (L, J, 4), whose columns ``joints`` are written (and
    returned); ``a2`` and ``b2`` are then A's and B's rows of every joint (2, J, 4).

    Averaging first and correcting the average costs one exponential per frame and joint instead
    of one per segment. Correcting each segment, then averaging, differs from it in
    the second order (the product of the seam offsets and the segments' spread): on the bench's
    hold-outs L2Q, L2P and skate moved by at most 0.001 (0.1%), cross-clip jerk by -0.5%.

    The numpy steps of :func:`replay` (its compiled call runs
    :func:`posturemap.synth.retrieval_numba.replay`).
    """
    length = curves.shape[1]
    lo, hi = (0, length) if frames is None else (max(int(frames[0]), 0), min(int(frames[1]), length))
    cols = np.arange(len(joints)) if out is None else joints
    if out is None:
        out = np.empty((length, len(joints), 4))
    part = offset_rotations(average_rotations(sample_rotations(lib, i0, i1, f, joints), weights)[None],
                            a2[:, cols], b2[:, cols], curves)[0]
    part[:lo] = part[max(hi, lo):] = (1.0, 0.0, 0.0, 0.0)
    out[:, cols] = part
    return out


def lift_upper(lib: MotionLibrary, i0, i1, f, root: int, tops: np.ndarray, a2, b2, curves, weight: float,
               frames: tuple[int, int] | None, out: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Turn the upper body's top joints ``tops`` (children of ``root``) in ``out`` (L, J, 4),
    whose legs (the root's tilt included) are replayed, toward the upper segments' own pelvis.

    The upper segments (sampled at ``(i0, i1, f)``) were recorded over their own pelvis; their
    spine's rotation is relative to it. Over the legs' pelvis, which rocks and tilts with other
    steps, the chest would carry both motions. Their root is replayed as their other joints are
    (averaged with the segments' ``weights``, seam-corrected to A's and B's from ``a2``/``b2``
    (2, J, 4)), and each top joint is turned by ``weight`` of the rotation from the legs' root
    to it (short arc): 1 keeps the chest's orientation in the heading frame as its segments
    carried it, 0 leaves it relative to the legs' pelvis. Both roots are seam-corrected to A's
    and B's, so the turn starts from nothing at A and returns to nothing at B. Only the new
    frames of ``frames`` ``(lo, hi)`` (all if None). Returns ``out``. The numpy steps of the
    compiled :func:`posturemap.synth.retrieval_numba.lift_upper`.

    Over the six Bandai splits (see docs/retrieval.md) 0.5 gave the lowest L2Q and L2P of 0, 0.5
    and 1 at 15, 30 and 45 frames, and lost on none (1 lost on one)."""
    length = curves.shape[1]
    lo, hi = (0, length) if frames is None else (max(int(frames[0]), 0), min(int(frames[1]), length))
    if hi <= lo or len(tops) == 0:
        return out
    own = replay_rotations(lib, i0, i1, f, np.array([root]), a2[:, [root]], b2[:, [root]], curves,
                           weights=weights)[lo:hi, 0]
    turn = quat.mul(quat.inv(out[lo:hi, root]), own)
    turn *= np.where(turn[:, :1] < 0, -1.0, 1.0)  # short arc
    turn = quat.exp(weight * quat.log(turn))
    out[lo:hi, tops] = quat.normalize(quat.mul(turn[:, None], out[lo:hi, tops]))
    return out


def seam_costs(pm, vm, frames, vframes, p, v, rate) -> np.ndarray:
    """Seam match costs (M,): ``|pm[frames] - p|^2 + |rate * vm[vframes] - v|^2`` per row.

    pm, vm : (N, Dp), (N, Dv) float32 feature rows (:meth:`Retriever._matrices`); p, v the
    seam's rows; rate (M,) the speed factor of each candidate. Compiled where numba is in use.
    """
    if _compiled() is not None:
        out = np.empty(len(frames))
        _compiled().seam_costs(pm, vm, frames, vframes, p, v, np.asarray(rate, dtype=np.float64), out)
        return out
    dp = pm[frames] - p
    dv = vm[vframes] * np.asarray(rate, dtype=np.float32)[:, None] - v
    return np.einsum("ij,ij->i", dp, dp, dtype=np.float64) + np.einsum("ij,ij->i", dv, dv, dtype=np.float64)


def _compiled():
    """The compiled retrieval kernels once this process uses numba (:func:`posturemap.core.kernels.compiled`:
    training, the studio, benchmarks), else None (a single CLI transition stays in numpy)."""
    if kernels.backend() != "numba":
        return None
    if not _loaded:  # an import statement per call would cost a microsecond each, dozens a transition
        from . import retrieval_numba

        _loaded.append(retrieval_numba)
    return _loaded[0]


_loaded: list = []  # [retrieval_numba] once _compiled() has loaded it


def offset_rotations(src: np.ndarray, a2: np.ndarray, b2: np.ndarray, curves: np.ndarray) -> np.ndarray:
    """Rotations of the new frames: ``exp(o(t)) * src(t)`` with seam offsets ``o`` (see module doc).

    src : (K, T, J, 4) sampled segment at t = -1 .. d + 1; a2 : (2, J, 4) A at a_end-1, a_end;
    b2 : (2, J, 4) B at b_start, b_start+1; curves : (4, L) from :func:`hermite_offsets`.
    Returns (K, L, J, 4).
    """
    def rel(p, q):  # log(p q^-1), (..., 3)
        return quat.log(quat.mul(p, quat.inv(q)))

    r_a = rel(a2[1], src[:, 1])
    v_a = rel(a2[1], a2[0]) - rel(src[:, 1], src[:, 0])
    r_b = rel(b2[0], src[:, -2])
    v_b = rel(b2[1], b2[0]) - rel(src[:, -1], src[:, -2])
    c = curves[:, None, :, None, None]  # (4, 1, L, 1, 1)
    o = c[0] * r_a[:, None] + c[1] * v_a[:, None] + c[2] * r_b[:, None] + c[3] * v_b[:, None]
    return quat.mul(quat.exp(o), src[:, 2:-2])


def offset_values(src: np.ndarray, a2: np.ndarray, b2: np.ndarray, curves: np.ndarray) -> np.ndarray:
    """Values (K, L, ...) of a channel sampled at t = -1 .. d + 1, with seam offsets (value, velocity)."""
    r_a = a2[1] - src[:, 1]
    v_a = (a2[1] - a2[0]) - (src[:, 1] - src[:, 0])
    r_b = b2[0] - src[:, -2]
    v_b = (b2[1] - b2[0]) - (src[:, -1] - src[:, -2])
    shape = (4, 1, curves.shape[1]) + (1,) * (src.ndim - 2)
    c = curves.reshape(shape)
    return src[:, 2:-2] + c[0] * r_a[:, None] + c[1] * v_a[:, None] + c[2] * r_b[:, None] + c[3] * v_b[:, None]


def average_rotations(q: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Mean of K segments' rotations ``q`` (K, T, ..., 4) at each of their T samples: the
    normalised sum, each segment weighed by ``weights`` (K,) if given (the rotations need not
    be unit length), each segment's sign kept from sample to sample and set at the first sample
    by the first segment's (then given the first segment's sign at each sample).

    Aligned to the first segment sample by sample instead, a segment whose joint passed a half
    turn from the first's changed sign in the middle of the gap, and the mean with it (an arm
    turned 107 degrees in a frame, averaging six segments between a wave and a run). Where no
    segment does, the signs are those of that sample-by-sample alignment."""
    if len(q) == 1:
        return quat.normalize(q[0])
    flips = np.sum(q[:, 1:] * q[:, :-1], axis=-1) < 0.0  # a segment's own sign changes
    par = np.concatenate([np.ones((len(q), 1) + flips.shape[2:]),
                          np.where(np.cumsum(flips, axis=1) % 2 == 1, -1.0, 1.0)], axis=1)
    side = np.where(np.sum(q[:, :1] * q[:1, :1], axis=-1) < 0.0, -1.0, 1.0)  # at the first sample
    sign = (side * par * par[:1])[..., None]
    if weights is not None:
        sign = sign * np.asarray(weights, dtype=float).reshape((len(q),) + (1,) * (q.ndim - 1))
    return quat.normalize(np.sum(q * sign, axis=0))


def root_trajectory(lib: MotionLibrary, i0, i1, f, ta, tb, ia: list[int], ib: list[int], align: bool, up: int,
                    curves: np.ndarray):
    """The root path of the lower body's segments sampled at (i0, i1, f) (K, T): each turned and
    moved to continue A (frames ``ia`` of track ``ta``), its seams corrected towards A and B
    (frames ``ib`` of ``tb``; with ``align`` B moves to where the segments end; ``curves`` (4, L)
    the offsets, whose value rows span the gap: in in-betweening the path lands on B), averaged.

    Returns positions (L, 3), headings (L,), B's turn and shift (3,). The numpy steps of
    :func:`replay` (its compiled call runs :func:`posturemap.synth.retrieval_numba.trajectory`).
    """
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    length = curves.shape[1]
    a_end, b_start = ia[1], ib[0]
    gp, hd = sample_trajectory(lib, i0, i1, f)
    theta0 = ta.heading[a_end] - hd[:, 1]
    traj = np.empty(hd.shape + (3,))
    rel = rotate_about_up(gp - gp[:, 1:2], theta0[:, None], up)
    traj[..., 0] = rel[..., a_] + ta.gpos[a_end, a_]
    traj[..., 1] = rel[..., b_] + ta.gpos[a_end, b_]
    traj[..., 2] = hd + theta0[:, None]
    a2 = np.stack([[ta.gpos[i, a_], ta.gpos[i, b_], ta.heading[i]] for i in ia])
    if align:
        end = traj[:, -2].mean(axis=0)
        dtheta = float(end[2] - tb.heading[b_start])
        turned = rotate_about_up(tb.gpos[ib], dtheta, up)
        shift = np.zeros(3)
        shift[a_], shift[b_] = end[0] - turned[0, a_], end[1] - turned[0, b_]
    else:
        dtheta, shift = 0.0, np.zeros(3)
    b_pos = rotate_about_up(tb.gpos[ib], dtheta, up) + shift
    b_head = tb.heading[ib] + dtheta
    b_head += 2 * math.pi * np.round((traj[:, -2, 2].mean() - b_head[0]) / (2 * math.pi))
    b2 = np.stack([b_pos[:, a_], b_pos[:, b_], b_head], axis=1)
    if not align:
        bend_paths(traj, a2, b2, curves)
    tr = offset_values(traj, a2, b2, curves).mean(axis=0)
    height = offset_values(gp[..., up], ta.gpos[ia, up], tb.gpos[ib, up], curves).mean(axis=0)
    gpos = np.empty((length, 3))
    gpos[:, a_], gpos[:, b_], gpos[:, up] = tr[:, 0], tr[:, 1], height
    return gpos, tr[:, 2], dtheta, shift


def bend_paths(traj: np.ndarray, a2: np.ndarray, b2: np.ndarray, curves: np.ndarray) -> None:
    """In-betweening: bend each segment's path (K, T, 3: horizontal a, b and heading, sampled at
    t = -1 .. d + 1, continuing A) with the turn its heading must make to arrive in B's, as far as
    that brings the path's end nearer B (in place).

    Each step of the path is turned by the heading's seam correction at that time (the same
    offsets, :func:`offset_values`, that then correct the heading itself), so a segment walking
    straight into a gap that turns walks an arc, and the value offsets that follow (which move
    every frame toward the line from A's miss to B's) are left a smaller miss to carry. Per
    segment, the bent path is taken by the fraction ``lam`` in [0, 1] of the way from the path
    as it was that brings its end nearest B's place (``lam = ((B - P0) . (P1 - P0)) / |P1 - P0|^2``,
    P0 the end before, P1 after bending), and that only as far as it mends the miss: in full
    where it removes at least ``BEND_GATE[1]`` of the distance from P0 to B, not at all below
    ``BEND_GATE[0]``, linearly between. A walk that turns is mended almost whole; a heading that
    differs from B's by the way a style holds its hips, or a stride's sway, is not a turn, and
    bending for it only trades one miss for another. The heading column is not changed.

    On Bandai's Motiondataset-2 (walks that turn, which bandai1 lacks; a library of all of
    bandai1, windows per length) L2P of walking turns at 45 frames went from 0.73-0.75x SLERP's to
    0.47-0.50x (0.44-0.45x without the gate), the whole sample from 0.713 to 0.614x; CMU 01_01 at
    1.5 s 0.757 -> 0.723x. Over the six Bandai splits (no turning walks) L2P moved by at most
    +0.001 at 15-45 frames (without the gate +0.003 / +0.008 at 30 / 45) and from 0.917 to 0.921x
    at 4 s; L2Q did not move (see ``docs/retrieval.md``).
    """
    hc = offset_values(traj[..., 2], a2[:, 2], b2[:, 2], curves)  # (K, L) corrected headings
    n_k, n_t = traj.shape[:2]
    dh = np.empty((n_k, n_t))
    dh[:, 2:-2] = hc - traj[:, 2:-2, 2]
    dh[:, :2] = (a2[1, 2] - traj[:, 1, 2])[:, None]
    dh[:, -2:] = (b2[0, 2] - traj[:, -2, 2])[:, None]
    turn = 0.5 * (dh[:, 1:] + dh[:, :-1])  # (K, T - 1): the turn of each step
    step_a, step_b = np.diff(traj[..., 0], axis=1), np.diff(traj[..., 1], axis=1)
    c, s = np.cos(turn), np.sin(turn)
    bent = np.empty((n_k, n_t, 2))
    bent[:, 1] = traj[:, 1, :2]
    bent[:, 0, 0] = traj[:, 1, 0] - (c[:, 0] * step_a[:, 0] - s[:, 0] * step_b[:, 0])
    bent[:, 0, 1] = traj[:, 1, 1] - (s[:, 0] * step_a[:, 0] + c[:, 0] * step_b[:, 0])
    bent[:, 2:, 0] = traj[:, 1:2, 0] + np.cumsum(c[:, 1:] * step_a[:, 1:] - s[:, 1:] * step_b[:, 1:], axis=1)
    bent[:, 2:, 1] = traj[:, 1:2, 1] + np.cumsum(s[:, 1:] * step_a[:, 1:] + c[:, 1:] * step_b[:, 1:], axis=1)
    p0 = traj[:, -2, :2]
    dp = bent[:, -2] - p0
    miss = b2[0, :2] - p0
    lam = np.clip((miss * dp).sum(axis=-1) / np.maximum((dp * dp).sum(axis=-1), 1e-12), 0.0, 1.0)
    mended = 1.0 - np.hypot(*(miss - lam[:, None] * dp).T) / np.maximum(np.hypot(*miss.T), 1e-12)
    lo, hi = BEND_GATE
    lam *= np.clip((mended - lo) / (hi - lo), 0.0, 1.0)
    traj[..., :2] += lam[:, None, None] * (bent - traj[..., :2])


class Result:
    """What one retrieval transition made: frames, B's alignment, contacts and the report; per
    body part the confidence and the match distance (degrees, unrounded: the report rounds it)."""

    def __init__(self, rots, gpos, heading, dtheta, shift, contacts, info, confidence, distance):
        self.rots, self.gpos, self.heading = rots, gpos, heading
        self.dtheta, self.shift = dtheta, shift
        self.contacts, self.info, self.confidence, self.distance = contacts, info, confidence, distance


@dataclass
class Match:
    """What the search found for one transition, before anything is replayed: per body part
    the best segments ``found[p] = (s, e, total, cost_a, cost_b)``, the match distance (degrees)
    and ``confidence`` (:func:`confidences`), and the transition it was made for; :attr:`info` is
    the report. ``weights[p]``: each segment's weight in the part's average (K,), or None for
    equal weights (:meth:`Retriever.upper_in_step`)."""

    ta: object
    tb: object
    ia: list
    ib: list
    length: int
    align: bool
    found: list
    distance: list
    confidence: list
    lib: MotionLibrary
    weights: list = field(default_factory=lambda: [None, None])
    still: float = 1.0  # still_weight: 0 where the body stands at both seams (a standing gesture)
    own: bool = False  # the segments are the clips' own motion (a Retriever with ``whole``)
    _info: dict | None = field(default=None, repr=False)

    @property
    def cost(self) -> float:
        """The best segment's cost of each body part, summed: what a search over the clips' own
        motion is weighed against the library's by (both on the library's feature scales)."""
        return sum(float(f[2][0]) for f in self.found)

    @property
    def info(self) -> dict:
        """Per body part the best segment's source clip and frames, warp, costs, match distance
        and confidence, and how many segments are blended; the overall confidence. Made on
        first use (a transition reports one of the matches it weighs)."""
        if self._info is None:
            lib = self.lib
            seconds = (self.length + 1.0) / float(self.ta.motion.fps)
            parts = {}
            for p, (s, e, total, ca, cb) in enumerate(self.found):
                s0, e0 = s.item(0), e.item(0)  # Python numbers: rounding numpy's is slow
                clip, first, last = lib.source_frames(s0, e0)
                parts["lower" if p == 0 else "upper"] = {
                    "clip": clip, "frames": [first, last], "reversed": first > last,
                    "warp": round((e0 - s0) / float(lib.fps) / seconds, 3),
                    "cost": round(total.item(0), 4), "cost_a": round(ca.item(0), 4), "cost_b": round(cb.item(0), 4),
                    "distance": round(float(self.distance[p]), 3), "confidence": round(float(self.confidence[p]), 3),
                    "blended": len(s)}
            self._info = {"parts": parts, "confidence": round(min(self.confidence), 3)}
            if self.own:  # the clips' own frames: A's up to its end, B's from its start
                self._info["own"] = True
            if self.still <= 0.0:  # why the legs are interpolated (and, but for own motion, the arms)
                self._info["standing"] = True
        return self._info


def match(rt: Retriever, ta, tb, a_end: int, b_start: int, length: int, alpha: float, align: bool,
          exhaustive: bool = False, top_k: int | None = None, seam: str = "both",
          shared: dict | None = None, skip: np.ndarray | None = None) -> Match | None:
    """The search of :func:`retrieve` and the confidences, without replaying; None when no
    segment fits at all.

    ``seam``: the seams whose match distance sets the confidence: ``"both"`` (the larger of
    the two), ``"a"`` (A's end only) or ``"b"`` (B's start only), for the two halves of a
    splice (:mod:`posturemap.synth.splice`; ``alpha`` 0 and 1 rank them by that seam alone).
    ``top_k``: the segments kept per part (default :func:`segments_averaged` of the gap).
    ``shared``: a dict kept by the caller between calls: for calls on the same transition
    (tracks, seams, ``length``, ``align``, ``exhaustive``, ``top_k``) the seams' features, the
    frames gathered for them, their :func:`still_weight` and the searches are made once; a call
    on another transition starts afresh. With ``shared["alphas"]`` set, the first call ranks
    the candidates for all of those alphas in its one search (as
    :meth:`Retriever.search_alphas`), and later calls for those alphas search no more.
    ``skip``: library clips left out of the search (:meth:`MotionLibrary.take_clips`: the take
    being in-betweened, where nothing is spliced; not with ``exhaustive``).
    """
    lib = rt.lib
    fps = float(ta.motion.fps)
    d = length + 1.0
    top_k = segments_averaged(length, fps, lib.fps) if top_k is None else top_k
    ia = [max(a_end - 1, 0), a_end]
    ib = [b_start, min(b_start + 1, len(tb.gpos) - 1)]
    xa, xb = ta.features[a_end], tb.features[b_start]
    shared = {} if shared is None else shared
    skip = np.zeros(0, np.int64) if skip is None else np.asarray(skip, dtype=np.int64)
    key = (id(ta), id(tb), a_end, b_start, length, bool(align), bool(exhaustive), top_k, tuple(skip.tolist()))
    if shared.get("key") != key:  # another transition: nothing kept applies to it
        for name in ("seams", "found"):
            shared.pop(name, None)
        shared["key"] = key
    if "seams" in shared:
        qa, qb, gathered, still, disp = shared["seams"]
    else:
        qa, qb = rt.seam_pair(ta, ia, tb, ib)
        none = np.zeros(0, np.int64)
        gathered = [(none, none)] * 2 if exhaustive else rt.gather_seams(xa, xb)
        if len(skip) and not exhaustive:  # a segment lies in one clip: none of these clips' then
            kept = np.ones(lib.num_clips, dtype=bool)
            kept[skip[(skip >= 0) & (skip < len(kept))]] = False  # as np.isin: others match no clip
            gathered = [tuple(f[kept[lib.clip_of[f]]] for f in pair) for pair in gathered]
        # In-betweening: B's place is fixed, so the gap's displacement ranks the segments and its
        # speed says whether the character must travel (still_weight).
        disp = None if align else _displacement(ta, tb, a_end, b_start, rt.engine._up)
        travel = 0.0 if disp is None else math.hypot(*disp[:2]) * fps / d
        still = still_weight(qa, qb, lib.leg, rt.engine._up, travel, rt.kl)
        shared["seams"] = (qa, qb, gathered, still, disp)
    searched = shared.setdefault("found", {})
    if float(alpha) not in searched:
        alphas = tuple(a for a in dict.fromkeys((float(alpha),) + tuple(float(a) for a in shared.get("alphas", ())))
                       if a not in searched)
        per_part = rt.search_parts(qa, qb, gathered, d, fps, alphas, disp, top_k, exhaustive)
        for i, a in enumerate(alphas):
            searched[a] = [per_part[0][i], per_part[1][i]]
    found = searched[float(alpha)]
    if found[0] is None or found[1] is None:
        return None
    weights = [None, None]
    if seam == "both" and (length + 1) / fps >= UPPER_IN_STEP_S:
        legs, upper = found
        if (length + 1) / fps >= TOP_K_RAMP_S[1]:  # a new tuple: `shared` keeps the search's
            keep = rt.in_step(legs[0], legs[1], d)
            legs = tuple(x[keep] for x in legs)
        weights[1] = np.where(rt.upper_in_step(legs, upper, d), UPPER_IN_STEP_WEIGHT, 1.0)
        found = [legs, upper]
    if seam == "a":  # the segment's start against A's end on both sides of the measure
        dist = rt.seam_distances([(p, found[p][0][0], found[p][0][0]) for p in (0, 1)], xa, xa)
    elif seam == "b":
        dist = rt.seam_distances([(p, found[p][1][0], found[p][1][0]) for p in (0, 1)], xb, xb)
    else:
        dist = rt.seam_distances([(p, found[p][0][0], found[p][1][0]) for p in (0, 1)], xa, xb)
    conf = confidences(dist, still, upper_weight(length, fps), seam == "both", align=align, own=rt.whole)
    return Match(ta, tb, ia, ib, length, align, found, dist, conf, lib, weights, still, rt.whole)


def _displacement(ta, tb, a_end: int, b_start: int, up: int) -> tuple[float, float, float]:
    """The gap's root displacement in A's heading frame and its turn (in-betweening: B fixed)."""
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    delta = tb.gpos[b_start] - ta.gpos[a_end]
    h = ta.heading[a_end]
    c, s = math.cos(h), math.sin(h)
    turn = tb.heading[b_start] - ta.heading[a_end]
    turn -= 2 * math.pi * round(turn / (2 * math.pi))
    return c * delta[a_] + s * delta[b_], -s * delta[a_] + c * delta[b_], turn


def replay(rt: Retriever, m: Match, blend: float | None = None, skip_unconfident: bool = False,
           frames: tuple[int, int] | None = None) -> Result:
    """The frames of a :class:`Match`: each part's best segments replayed, seam-corrected and
    averaged, the lower body's root trajectory and planted feet (see :func:`retrieve`).
    ``frames``: ``(lo, hi)``, the rotations of the new frames ``lo <= t < hi`` only (the others
    are the identity; the trajectory and contacts are whole). Where the legs are replayed, the
    upper body's top joints are lifted toward its own segments' pelvis (:func:`lift_upper`).
    Where numba is in use, each body part is one compiled call (:func:`_replay_part`)."""
    lib, eng = rt.lib, rt.engine
    up = eng._up
    ta, tb, ia, ib, length = m.ta, m.tb, m.ia, m.ib, m.length
    fps = float(ta.motion.fps)
    d = length + 1.0
    curves = _hermite_offsets_cached(length, blend_frames(fps) if blend is None else float(blend))
    out = np.empty((length, eng.skeleton.num_joints, 4))
    out[:, rt.open_joints] = (1.0, 0.0, 0.0, 0.0)  # above the root: the caller's
    jit = _compiled()
    if jit is None:
        a_rots, b_rots = ta.rots[ia], tb.rots[ib]
    gpos = heading = dtheta = shift = contacts = None
    legs = False  # whether the legs (and the root's tilt) are in `out`: the upper body is lifted over them
    for p, (s, e, _, _, _) in enumerate(m.found):
        joints = rt.part_joints[p]
        if skip_unconfident and m.confidence[p] <= 0.0:
            out[:, joints] = (1.0, 0.0, 0.0, 0.0)
            continue
        lift = p == 1 and legs
        legs |= p == 0
        if jit is not None:  # the steps below in one call
            root = _replay_part(jit, m, p, s, e, joints, curves, frames, out, up,
                                (eng._root, rt.upper_tops) if lift else None)
            if root is not None:
                gpos, heading, dtheta, shift, contacts = root
            continue
        i0, i1, f = segment_times(lib, s, e, d)
        replay_rotations(lib, i0, i1, f, joints, a_rots, b_rots, curves, frames, out=out, weights=m.weights[p])
        if lift:
            lift_upper(lib, i0, i1, f, eng._root, rt.upper_tops, a_rots, b_rots, curves, UPPER_LIFT, frames, out,
                       m.weights[p])
        if p == 0:
            gpos, heading, dtheta, shift = root_trajectory(lib, i0, i1, f, ta, tb, ia, ib, m.align, up, curves)
            # The nearest recorded frame of the first segment (its samples lie inside its clip).
            contacts = lib.contacts[np.round(i0[0, 2:-2] + f[0, 2:-2]).astype(np.int64)]
    return Result(out, gpos, heading, dtheta, shift, contacts, m.info, m.confidence, m.distance)


_NO_TOPS = np.zeros(0, dtype=np.int64)


def _replay_part(jit, m: Match, p: int, s, e, joints, curves, frames, out, up: int, lift: tuple | None = None):
    """Part ``p`` of :func:`replay` in one compiled call (:func:`posturemap.synth.retrieval_numba.replay_part`:
    segment times, replay into ``out``, and for the lower body the root path and contacts; with
    ``lift`` ``(root, tops)``, :func:`lift_upper` of the joints ``tops``); for the lower body
    ``(gpos, heading, dtheta, shift, contacts)``, else None."""
    lib, ta, tb, length = m.lib, m.ta, m.tb, m.length
    d = length + 1.0
    lo, hi = (0, length) if frames is None else (max(int(frames[0]), 0), min(int(frames[1]), length))
    n_legs, kind = lib.contacts.shape[1], lib.contacts.dtype
    if p == 0:
        root = (np.empty((length, 3)), np.empty(length), np.empty(3), np.empty((length, n_legs), dtype=kind))
    else:  # no root: nothing is written into these
        root = (np.empty((0, 3)), np.empty(0), np.empty(3), np.empty((0, n_legs), dtype=kind))
    dtheta = jit.replay_part(lib.rots, lib.clip_start, lib.clip_of, lib.clip_end, s, e, d, _sample_times(d), joints,
                             joints, ta.rots, tb.rots, np.array(m.ia), np.array(m.ib), curves, lo, hi, out, p == 0,
                             lib.gpos, lib.heading, lib.contacts, ta.gpos, ta.heading, tb.gpos, tb.heading, m.align,
                             up, *root, *((-1, _NO_TOPS) if lift is None else lift), UPPER_LIFT,
                             np.ones(len(s)) if m.weights[p] is None else m.weights[p], *BEND_GATE)
    if p != 0:
        return None
    gpos, heading, shift, contacts = root
    return gpos, heading, float(dtheta), shift, contacts


def retrieve(rt: Retriever, ta, tb, a_end: int, b_start: int, length: int, alpha: float, align: bool,
             exhaustive: bool = False, top_k: int | None = None, blend: float | None = None,
             skip_unconfident: bool = False, seam: str = "both", shared: dict | None = None) -> Result | None:
    """One retrieval transition (see the module docstring): :func:`match`, then :func:`replay`;
    None when no segment fits at all.

    Returns the new frames' local rotations with the root's *tilt* (L, J, 4), the root
    trajectory (positions (L, 3), headings (L,)), B's turn and shift, the planted feet of the
    retrieved lower body (L, legs) and the report (source clips, frames, costs, confidence).

    ``skip_unconfident``: a part whose confidence is 0 (the caller replaces it by the fallback)
    is not replayed: its joints' rotations are left as the identity, and for the lower body the
    trajectory, B's turn and shift and the contacts are None. The report is the same.
    ``seam`` and ``shared``: as for :func:`match`.
    """
    m = match(rt, ta, tb, a_end, b_start, length, alpha, align, exhaustive, top_k, seam, shared)
    return None if m is None else replay(rt, m, blend, skip_unconfident)
