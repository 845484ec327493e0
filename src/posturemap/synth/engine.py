"""The transition engine: prepared clips, one transition per call, one implementation per method.

The transition fills ``length`` frames between the end of clip A (frame ``a_end``, time 0)
and the start of clip B (frame ``b_start``, time ``length + 1``).

Every frame is split into a *trajectory* (root horizontal position, heading about the up
axis) and a *posture* (root height, root tilt, local rotations). Rotations are handled as
rotation vectors ``log(ref^-1 q)`` relative to a per-joint reference rotation (the key's,
or B's first), a space without sign flips or seams for the short arcs of a transition.
The interpolating methods are each a linear map from the seam values to the in-between frames
(``damped``'s weighs each column by its motion's time scale at the seams); retrieval replays
real motion:

``auto`` (default)
    ``retrieval`` at every gap length (the spline took gaps under 0.25 s until held-out gaps of
    1-7 frames at 30 fps, 2-14 at 60 and 4-28 at 120 showed retrieval ahead there too, both with
    the foot lock, in L2P but on CMU at 4 frames (4% behind) and in L2Q but on LaFAN1 at 60 fps
    at 4-6 frames (2% behind); against the spline without the lock (as the bench runs it) the
    lock's cost on the shortest gaps leaves its L2P behind on CMU at 5 frames (3%) and on LaFAN1
    at 60 fps at 0.1-0.17 s (4-19%); the name stays the default's, whatever ``posturemap bench``
    finds best).
``retrieval``
    Real motion from the map's motion library, found through the map's index, replayed between
    the seams with smooth seam corrections and its planted feet kept planted, falling back by
    confidence to ``damped`` (its root, where B stays where it is, on the seams' own path, the
    spline's; ``spline`` on gaps under 0.6 s, where the upper body fades into it;
    :mod:`posturemap.synth.retrieval`). ``alpha`` weighs the match at A's
    end (0: continue A's motion) against the match at B's start (1: arrive in B's motion).
``upm`` (paper)
    Key posture from the four class maps: per class, the neuron nearest the ``alpha``-blend of
    A's last and B's first posture (an O(n) scan). A clamped cubic B-spline passes through A's
    end (value and velocity), the key at frame ``key_at`` and B's start (value and velocity).
``upm-path``
    As ``upm``, with each class key the neuron at fraction ``alpha`` of the way along the
    shortest path between the two postures' winners in the map graph.
``upm-valid``
    Keys every ``KEY_SPACING_S`` seconds, each estimated from the blend of the seam postures and
    the fading seam velocities and projected into the map's valid region (within ``ACCEPT`` * R of
    a neuron); one clamped B-spline through all of them (see :meth:`posturemap.synth.keys.MapKeys.valid_keys`).
``spline``
    The same cubic (Hermite) spline without a key: matches values and velocities at both ends.
``slerp``
    SLERP of every rotation and LERP of the root, from A's end to B's start (no velocities).
``damped``
    The straight line (SLERP/LERP) plus what each seam's velocity adds to it, carried on past
    its seam for as long as that motion keeps a velocity (its time scale over A's last and B's
    first 0.3 s: ``1 / omega`` of a wave, held within 0.05-0.33 s; the root's horizontal
    position 0.05 s; a joint turning toward the other seam's pose faster than the straight
    line, that part until it gets there, within 0.35 of the gap), then let go
    (:func:`posturemap.synth.bases.damped_frames`, :func:`_damped_frames`); a joint that swings
    back and forth at both seams (a waving hand) swings on through the gap in phase with both
    (:mod:`posturemap.synth.periodic`). The retrieval's fallback on gaps from 0.6 s, where the
    cubic overshoots.
``inertialize``
    B's start, extrapolated backwards with its velocity, plus an offset that decays with a
    quintic from A's end (value, velocity, acceleration) to zero (Bollo 2016).

Foot locking (:mod:`posturemap.synth.feet`, on by default) pins planted feet. Root alignment
(default) turns and moves B to continue A (:mod:`posturemap.synth.trajectory`). Parameters,
defaults and their checks: :mod:`posturemap.synth.request`; the bases of the interpolating
methods: :mod:`posturemap.synth.bases`; the key postures: :mod:`posturemap.synth.keys`.
"""

from __future__ import annotations

import copy
from functools import lru_cache

import numpy as np

from ..core import glitches, kernels, quat
from ..core.joints import ancestors, arm_chains, key_joints, leg_chains, leg_length, leg_toes
from ..core.skeleton import chain_world
from ..core.motion import Motion, concatenate, root_index, same_fps, up_axis
from ..errors import UserError
from ..learn.features import TWO_PI, root_global, upright_rest
from .bases import (DAMPED_GAP_SHARE, DAMPED_PEAK, DAMPED_REACH_SHARE, DAMPED_SAMPLES, DAMPED_STEP_S, DAMPED_TAU_MAX_S,
                    DAMPED_TAU_S, VELOCITY_HORIZON_S, damped_frames, damped_reach, damped_time_scales, hermite_basis,
                    inertialize_basis, key_spline_basis, keys_spline_basis, linear_basis, reach_parts)
from . import hinges, retrieval
from .feet import FLOOR_S, lock_feet
from .keys import MapKeys
from .library import MotionLibrary, own_frames, own_library
from .periodic import PERIODIC_MIN_SAMPLES, continued
from .request import KEYED, METHODS, RequestError, TransitionRequest, describe, frame_index
from .splice import spliced
from .trajectory import (Track, aligned, alignment, bend_fit, carry_chain, make_track, placement, put_root,
                         rotate_about_up, seam_path, seam_view, through_seams)

# TransitionEngine.warm_up: gaps (seconds) short enough for retrieval's spline fallback and
# upper body, of a second (the upper body from travelling frames), and long (the legs in step).
WARM_UP_GAPS_S = (0.2, 1.0, 2.0)
# Retrieval searches the clips' own motion beside the gap besides the library: at most this many
# seconds of A up to its end and of B from its start (the frames nearest the gap; a capture of
# several minutes is not searched whole for every transition). See _own_retriever.
OWN_SECONDS = 60.0
OWN_FRAMES = 1800  # ... and at most this many frames a side (60 s at 30 fps, 15 s at 120): the search takes every one
# A seam reads this many seconds of its clip beside it without their glitch steps (TransitionEngine.
# _seam_view; damped's context is a third of a second), and the last SEAM_VIEWS_KEPT such tracks
# are kept (each holds the clip's rotations once more).
SEAM_WINDOW_S = 0.5
SEAM_VIEWS_KEPT = 2


class TransitionEngine:
    """Keeps a map and prepared clips in memory; one transition per call (for a game loop).

    >>> engine = TransitionEngine(model)              # doctest: +SKIP
    >>> engine.add("walk", walk); engine.add("run", run)
    >>> rots, pos = engine.generate("walk", "run", alpha=0.3)
    >>> rots, pos = engine.generate("walk", "run", TransitionRequest(length=30, method="spline"))

    Clips are split into trajectory and posture once (:meth:`add`); :meth:`generate` then
    only reads seam frames, finds the key and evaluates a precomputed spline basis, writing
    into buffers reused between calls of the same length. One engine serves one call at a
    time; :meth:`fork` gives another that shares the clips and the map.

    ``own_seconds`` (default :data:`OWN_SECONDS`, at most :data:`OWN_FRAMES` frames): how much of
    A's motion up to its end and of B's from its start retrieval searches besides the map's
    library (the clips' own motion),
    where B stays where it is (``align=False``: a gap in a take) or where the map has no
    library; set it to 0 to replay the library only.
    """

    def __init__(self, model=None, skeleton=None):
        self.model = model
        if model is not None:
            if not hasattr(model, "require_fitted"):
                raise TypeError(f"model must be a PostureMap (or None), got {type(model).__name__}")
            model.require_fitted()
            skeleton = model.skeleton_
        self.skeleton = skeleton
        self.tracks: dict[str, Track] = {}
        self.last: dict = {}
        self._root = self._up = None
        self._buffers: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._chain = np.zeros(0, dtype=np.int64)
        self._rest = None
        self._legs = []
        self._retriever = None
        # id(track) -> (track, the hinges, each knee's and elbow's bend about them in each frame)
        self._limb_bends: dict[int, tuple] = {}
        # (id(track), seam frame, whether B's) -> (track, the track as that seam reads it), for
        # seams beside a glitch step (see _seam_view).
        self._seam_views: dict[tuple, tuple] = {}
        self._steadied = None  # the joints whose glitch steps are taken out (all below the root)
        self._learned: dict[int, tuple] = {}  # id(track) -> (track, its rotations as a map learns them)
        self._over: dict[int, tuple] = {}  # id(track) -> (track, its steps over the glitch bound, counted)
        # Without a motion library: (id(A), id(B)[, A's end, B's start: a gap in a take]) -> (A, B,
        # the hinges found in their frames, see _clip_limbs).
        self._clip_limbs: dict[tuple, tuple] = {}
        # The clips' own motion (see _own_retriever): retrievers per seam pair, (id(A), id(B), the
        # pieces searched) -> (A, B, retriever); each clip's per-frame key joints and
        # ankles, id(track) -> (track, keys, own_frames); the key joints without a library; the
        # retriever the others copy without a library.
        self._own: dict[tuple, tuple] = {}
        self._own_frames: dict[int, tuple] = {}
        self._own_keys = None
        self._own_base = None
        self.own_seconds = OWN_SECONDS  # see the class docstring and _own_retriever
        self.keys = None
        if model is not None:
            space = model.space_
            self._root, self._up, self._rest = space.root, space.up, space.rest
            self._chain = np.array(ancestors(skeleton.parents, self._root), dtype=np.int64)
            self.keys = MapKeys(model, skeleton.num_joints, self._up)

    # -- clips --------------------------------------------------------------------------------
    def add(self, name: str, motion: Motion) -> Track:
        """Prepare a clip under ``name`` (same skeleton as the map, if any; at least one frame,
        every value finite)."""
        if not isinstance(motion, Motion):
            raise TypeError(f"add needs a Motion (posturemap.io.bvh.read gives one), got {type(motion).__name__}")
        motion.check_usable(name)
        motion = motion.unit()  # rotations of length 1 exactly: the new frames are made of them
        if self.skeleton is None:
            self.skeleton = motion.skeleton
        whose = "the map's" if self.model is not None else "the other clips'"
        if not motion.skeleton.same_as(self.skeleton):
            raise UserError(name, f"skeleton differs from {whose} ({motion.skeleton.difference(self.skeleton, whose)})")
        why = motion.skeleton.body_mismatch(self.skeleton, whose)
        if why:
            raise UserError(name, why)
        if self._root is None:
            self._root, self._up = root_index(motion), up_axis(motion)
        self._chain = np.array(ancestors(self.skeleton.parents, self._root), dtype=np.int64)
        self._steadied = glitches.steadied_joints(self.skeleton, self._root)
        space = self.model.space_ if self.model is not None else None
        if self._rest is None:
            self._rest = upright_rest(root_global(motion, self._root)[0], self._up)
        if not self._legs:
            self._legs = leg_chains(self.skeleton)
            self._leg_length = leg_length(self.skeleton, self._legs)
            self._toes = leg_toes(self.skeleton, self._legs)
        tr = make_track(motion, self._root, self._up, self._rest, space)
        self.tracks[name] = tr
        return tr

    @property
    def up(self) -> int:
        """The up axis (0, 1 or 2) of the clips."""
        return int(self._up)

    def placement(self, b: str, turn: float, shift: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
        """How :meth:`continuation` places clip ``b`` (turned by ``turn`` radians about up, moved by
        ``shift``), as one joint's local change ``(joint, q (4,), t (3,))``: that joint's local
        rotation ``r`` and translation ``p`` become ``q r`` and ``q p + t`` on each of B's frames
        (:func:`posturemap.synth.trajectory.placement`: the joint above the root that carries
        root motion, else the root)."""
        track = self._track("b", b)
        return placement(track, self._chain, self._root, self._up, turn, shift, self._carrier(track))

    def _carry_chain(self, ta: Track, tb: Track, req: TransitionRequest, out_r, out_p, a_carrier: int,
                     b_carrier: int) -> None:
        """:func:`posturemap.synth.trajectory.carry_chain` on the new frames, compiled where the
        retrieval's kernels are loaded (on LaFAN1's rig at 1 s, 6 us median; 0.14 ms in numpy)."""
        dtheta, shift = float(self.last["dtheta"]), np.asarray(self.last["shift"], dtype=np.float64)
        jit = retrieval._compiled()
        if jit is None:
            carry_chain(ta, tb, req.a_end, req.b_start, out_r, out_p, self._chain, self._root, self._up, dtheta,
                        shift, a_carrier, b_carrier)
            return
        length = len(out_r)
        bump, solve = bend_fit(length, ta.motion.fps, bent=a_carrier >= 0)
        a_end, b_start = req.a_end, req.b_start
        jit.carry_chain(out_r, out_p, self._chain, b_carrier, self._root, ta.motion.rotations, ta.motion.positions,
                        ta.gpos, max(a_end - 1, 0), a_end, tb.motion.rotations, tb.motion.positions, tb.gpos, b_start,
                        min(b_start + 1, len(tb.gpos) - 1), self._up, dtheta, shift, hermite_basis(length), bump,
                        solve)

    def _carrier(self, track: Track) -> int:
        """Which joint of the root's chain carries ``track``'s root motion (:attr:`Track.carrier`);
        a single frame shows none, so it takes the rig's, as the first clip of several frames added
        shows it (a pose to reach on a root-motion rig is placed with its root bone)."""
        if len(track.gpos) > 1:
            return track.carrier
        return next((t.carrier for t in self.tracks.values() if len(t.gpos) > 1), -1)

    def fork(self) -> TransitionEngine:
        """Another engine for another thread: its own buffers and caches, the same clips, map and
        motion library (shared, read-only). A clip added to one engine afterwards is not in the
        other."""
        _forget_gone_clips(self)  # a clip replaced since its last transition is not copied
        shared = {id(self.model): self.model, **{id(t): t for t in self.tracks.values()}, id(self._own): {},
                  id(self._seam_views): {}, id(self._learned): {}, id(self._over): {},
                  id(self._own_frames): {}, id(self._own_base): None}
        library = getattr(self.model, "library_", None)
        if library is not None:  # a retriever built before the copy keeps it
            shared[id(library)] = library
        if self._retriever is not None:  # and its rows of the library's frames (read only)
            for name in ("_mats", "_index_w"):
                value = getattr(self._retriever, name, None)
                if value is not None:
                    shared[id(value)] = value
        return copy.deepcopy(self, shared)

    def continuation(self, b: str, b_start: int, align: bool = True, *, turn: float | None = None,
                     shift: np.ndarray | None = None) -> Motion:
        """B's frames from ``b_start`` on, placed to continue A: turned by ``turn`` radians about
        the up axis and moved by ``shift`` (default: as the last :meth:`generate` placed them);
        without ``align``, as they are."""
        track = self._track("b", b)
        b_start = frame_index("b_start", b_start, len(track.gpos), f"clip B {b!r}")
        if not align:
            return track.motion[b_start:]
        if (turn is None or shift is None) and "dtheta" not in self.last:
            raise RequestError("turn", "no transition made yet to take B's place from: give turn and shift")
        turn = self.last["dtheta"] if turn is None else turn
        shift = self.last["shift"] if shift is None else shift
        return aligned(track, b_start, turn, shift, self._chain, self._root, self._up, self._carrier(track))

    def warm_up(self, methods=("auto",)) -> int:
        """Prepare for a game loop: switch to the compiled kernels (:func:`posturemap.core.kernels.compiled`;
        numba's, loaded from its disk cache, or compiled on a fresh install) and run now what a
        process's first transitions would pay for (each kernel's first call, the bases of common
        lengths). Call it once after :meth:`add`, in a loading screen. Without it transitions run
        the numpy kernels (unless something else switched), several times slower; and after
        ``kernels.compiled()`` alone the first few calls take 10-500 ms each instead of about one.

        ``methods``: the methods (or one method's name) the caller will ask for (those needing a
        map are skipped without one); ``auto`` is ``retrieval``, which brings its fallbacks
        (``spline``, ``damped``) with it. The transitions run between the first and the last clip added, from their ends and their
        middles, at gaps of :data:`WARM_UP_GAPS_S` seconds, both placing B after A and keeping
        B where it is (matches of every confidence, as these clips give them); then, with a
        motion library, what runs at one confidence only (every part retrieved; a splice), run
        directly; and every clip's knees and elbows measured against the library's hinges (each
        clip's first transition would pay for it). Returns the number of transitions run;
        :attr:`last` and the frames earlier calls returned are left as they were. Raises
        :class:`RequestError` when no clip has been added."""
        if not self.tracks:
            raise RequestError("a", "no clips to warm up with (add one first)")
        methods = (methods,) if isinstance(methods, str) else tuple(methods)
        kernels.compiled()
        names = list(self.tracks)
        a, b = names[0], names[-1]
        na, nb = len(self.tracks[a].gpos), len(self.tracks[b].gpos)
        fps = self.tracks[a].motion.fps
        runnable = [m for m in methods if self.model is not None or m not in KEYED]
        seams = sorted({(na - 1, 0), (na // 2, nb // 2)})
        lengths = [max(1, round(gap * fps) - 1) for gap in WARM_UP_GAPS_S]
        # Frames returned by earlier calls stay as they were: the warm-up writes into buffers of
        # its own, and keeps those of lengths no call has asked for yet.
        last, count, buffers = self.last, 0, self._buffers
        self._buffers = {}
        try:
            for method in runnable:
                for length in lengths:
                    for a_end, b_start in seams:
                        for align in (True, False):
                            self.generate(a, b, method=method, length=length, a_end=a_end, b_start=b_start,
                                          align=align)
                            count += 1
            if self._retriever is not None:
                # What runs only at one confidence, whichever the schedule's matches had: every
                # part retrieved (the open columns) and a splice (when both halves fit at all).
                ta, tb = self.tracks[a], self.tracks[b]
                for length in lengths:
                    _open_columns(self, ta, tb, na - 1, 0, length)
                    spliced(self._retriever, ta, tb, na - 1, 0, length, 0.5)
                # The table that finds a take in the library (made once per library, about 30 ms
                # for bandai1's): asked of every in-betweening whose B starts past A's end.
                rt = self._retriever
                rt.lib.take_clips(rt.part_joints[1], ta.rots[na - 1], tb.rots[0], 2)
                # Each clip's knees and elbows about the library's hinges (a clip's first
                # transition would pay for it: about 35 us for a bandai1 clip, compiled).
                limbs = _library_limbs(self, rt.lib)
                if len(limbs[3]):
                    for track in self.tracks.values():
                        _limb_bends(self, track, limbs)
            for track in self.tracks.values():  # where a seam may meet a glitch step (about 1 ms a
                _over_bound(self, track)        # 1,000 frames; a clip's first transition would pay)
        finally:
            self.last = last
            self._buffers = {**self._buffers, **buffers}
        return count

    def _track(self, field: str, name: str) -> Track:
        """The prepared clip ``name``; a :class:`RequestError` on ``field`` if there is none."""
        track = self.tracks.get(name) if isinstance(name, str) else None
        if track is None:
            raise RequestError(field, f"no clip named {name!r} (add it first)" if isinstance(name, str)
                               else f"a clip name must be text, got {describe(name)}")
        return track

    def alignment(self, a: Track, b: Track, a_end: int, b_start: int, length: int) -> tuple[float, np.ndarray]:
        """Turn (radians about up) and translation (3,) that make B continue A."""
        return alignment(a, b, a_end, b_start, length, self._up)

    # -- transitions ----------------------------------------------------------------------------
    def generate(self, a: str, b: str, request: TransitionRequest | None = None, **fields):
        """The in-between frames: local rotations (length, J, 4) and positions (length, J, 3).

        ``request`` (default: the defaults of :class:`TransitionRequest`), with any of its
        fields given as keywords on top (``length=30, method="spline"``). ``foot_lock`` keeps
        planted feet still (:mod:`posturemap.synth.feet`). Raises :class:`RequestError` for a
        field out of range or a method that needs a map the engine lacks.

        Also sets ``self.last`` (the method that ran, key posture, chosen neurons, alignment, and
        for retrieval the source segments and confidence) for inspection. The returned arrays
        are buffers reused by the next call with the same ``length``.
        """
        ta, tb = self._track("a", a), self._track("b", b)
        if not same_fps(ta.motion.fps, tb.motion.fps):
            raise RequestError("b", f"clip {b!r} is at {tb.motion.fps:g} fps, {a!r} at {ta.motion.fps:g} fps: "
                                    "resample one clip to the other's rate first (posturemap.resample)")
        req = TransitionRequest.of(request, **fields).resolved(len(ta.gpos), len(tb.gpos))
        if req.keyed and self.model is None:
            raise RequestError("method", f"method {req.method!r} needs a posture map")
        ta, tb = self._seam_view(ta, req.a_end, False), self._seam_view(tb, req.b_start, True)
        out_r, out_p = _RUN[req.method](self, ta, tb, a, b, req)
        self.last.setdefault("method", req.method)  # auto names the method it chose
        b_carrier = self._carrier(tb)
        if req.align and b_carrier >= 0:
            # B's chain carries root motion (a game rig's root bone): B is placed with it, and
            # the new frames take it there.
            self._carry_chain(ta, tb, req, out_r, out_p, self._carrier(ta), b_carrier)
        return out_r, out_p

    def _seam_view(self, track: Track, frame: int, forward: bool) -> Track:
        """``track`` as its seam at ``frame`` reads it (:func:`posturemap.synth.trajectory.seam_view`):
        itself unless a glitch step lies within :data:`SEAM_WINDOW_S` of the seam on its side
        (after it with ``forward``, B's; before it, A's). The last few are kept
        (:data:`SEAM_VIEWS_KEPT`: a slider's new alpha reads the same seams)."""
        span = max(2, round(SEAM_WINDOW_S * track.motion.fps))
        lo, hi = glitches.seam_frames(len(track.gpos), frame, forward, span)
        over = _over_bound(self, track)
        if over[hi - 1] == over[lo]:  # no step there turns a joint as far as a glitch: nearly every seam
            return track
        key = (id(track), frame, forward)
        kept = self._seam_views.get(key)
        if kept is not None and kept[0] is track:
            return kept[1]
        view = seam_view(track, frame, forward, span, self._steadied)
        if view is not track:
            while len(self._seam_views) >= SEAM_VIEWS_KEPT:
                self._seam_views.pop(next(iter(self._seam_views)))
            self._seam_views[key] = (track, view)
        return view

    def _lock_feet(self, ta: Track, tb: Track, req: TransitionRequest, out_r, out_p, dtheta, shift, contacts=None):
        """Pin the planted feet of the new frames (:func:`posturemap.synth.feet.lock_feet`), with
        A's last two frames and B's first two (B placed by ``dtheta``, ``shift``) as context, and
        the toes' floor from A's last and B's first ``FLOOR_S`` seconds, and the map's motion
        library's toe clearance (:attr:`~posturemap.synth.library.MotionLibrary.clearance`, where
        it has one); returns the lock weights."""
        a_end, b_start, up = req.a_end, req.b_start, self._up
        # A's frames a_end - 1, a_end and B's b_start, b_start + 1 (repeated at a clip's end):
        # slices where they can be; the ankles and the toes of those frames.
        ia = slice(a_end - 1, a_end + 1) if a_end > 0 else [0, 0]
        ib = slice(b_start, b_start + 2) if b_start + 1 < len(tb.feet) else [b_start, b_start]
        a_feet, a_toes = ta.feet[ia], ta.toes[ia]
        b_feet = rotate_about_up(tb.feet[ib], dtheta, up) + shift
        b_toes = rotate_about_up(tb.toes[ib], dtheta, up) + shift
        # The toes' floor: their lowest over A's last FLOOR_S seconds and B's first (B's heights
        # moved with B): a stance in any gait, so a held foot's toe under it is lifted out.
        na, nb = round(FLOOR_S * ta.motion.fps) + 1, round(FLOOR_S * tb.motion.fps) + 1
        end_a, start_b = slice(max(a_end + 1 - na, 0), a_end + 1), slice(b_start, b_start + nb)
        rise = shift[up].item()
        toe_floor = min(ta.toes[end_a, :, up].min().item(), tb.toes[start_b, :, up].min().item() + rise)
        # Whether a foot is planted at a seam: against that clip's own floor, its lowest ankle there.
        seam_floors = (ta.feet[end_a, :, up].min().item(), tb.feet[start_b, :, up].min().item() + rise)
        library = getattr(self.model, "library_", None)
        return lock_feet(self.skeleton, self._legs, out_r, out_p, self._fk, self._up, a_feet, b_feet,
                         ta.motion.fps, contacts, self._leg_length, toe_floor, self._toes, seam_floors,
                         None if library is None else library.clearance, a_toes, b_toes)

    def _fk(self, rots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations and positions of the new frames (compiled FK, output buffers)."""
        out_p = self._buffers[len(rots)][1]
        grot, gpos = np.empty(rots.shape), np.empty(out_p.shape)
        kernels.fk(self.skeleton.parents, rots, out_p, grot, gpos)
        return grot, gpos

    def _out(self, length: int) -> tuple[np.ndarray, np.ndarray]:
        """The output buffers of ``length`` frames (reused between calls)."""
        j = self.skeleton.num_joints
        out = self._buffers.get(length) or (np.empty((length, j, 4)), np.empty((length, j, 3)))
        self._buffers[length] = out
        return out


# -- the methods ------------------------------------------------------------------------------
def _auto(eng: TransitionEngine, ta: Track, tb: Track, a: str, b: str, req: TransitionRequest):
    """The default: ``retrieval`` at every gap length (``eng.last["method"]`` says so)."""
    out = _retrieval(eng, ta, tb, a, b, req.replace(method="retrieval"))
    eng.last["method"] = "retrieval"
    return out


def _unbend_limbs(eng: TransitionEngine, ta: Track, tb: Track, a_end: int, b_start: int, out_r: np.ndarray,
                  out_p: np.ndarray, own: MotionLibrary | None = None, legs_only: bool = False) -> None:
    """No knee or elbow of the new frames bent further back, or folded further forward, than the
    motion library's go or the frames the output keeps of A (to ``a_end``) and of B (from
    ``b_start``), whichever goes further (:mod:`posturemap.synth.hinges`; the limbs' hinges
    found once per library, each clip's bends about them once per clip). Without a library,
    the hinges are found in ``own`` (the clips' own motion the transition searched,
    :func:`_own_retriever`), and without that in the frames the output keeps of A and B
    (:func:`_clip_limbs`).

    The clips' own bound keeps real motion real where the library's hinges are not its legs'
    (an unrelated library, another rig's knees): there the clips' knees go "backward" by the
    library's hinge, and their bound is as far back (and forward) as they go. Only the kept
    frames count: a gap in a take (A and B one clip) is never read, however its knees bend.
    ``legs_only``: the knees alone (an interpolating method's, before its foot lock: the lock
    touches the legs only, and the rest of the baseline stays as it is)."""
    lib = getattr(eng.model, "library_", None)
    if lib is None or not len(lib):
        lib = own
    limbs = (_clip_limbs(eng, ta, tb, a_end, b_start) if lib is None or not len(lib)
             else _library_limbs(eng, lib))
    joints, bounds, hinge, least, most = limbs
    if not len(least):
        return
    a_bends, b_bends = _limb_bends(eng, ta, limbs), _limb_bends(eng, tb, limbs)
    least, most = np.minimum(least, a_bends[0][a_end]), np.maximum(most, a_bends[2][a_end])
    if b_start < len(b_bends[1]):
        least, most = np.minimum(least, b_bends[1][b_start]), np.maximum(most, b_bends[3][b_start])
    if legs_only:  # the limbs whose shin is a leg's
        shins = {c[1] for c in eng._legs}
        keep = np.array([int(j) in shins for j in joints[bounds[:, 1] - 1]], dtype=bool)
        bounds, hinge, least, most = bounds[keep], hinge[keep], least[keep], most[keep]
    hinges.unbend((joints, bounds, hinge, least, most), out_r, out_p, hinges.UNBEND_ACCEL / ta.motion.fps**2)


def _clip_limbs(eng: TransitionEngine, ta: Track, tb: Track, a_end: int, b_start: int) -> tuple:
    """The knees' and elbows' hinges and bounds (:func:`_library_limbs`) found in the clips' real
    motion, where there is no motion library to find them in: between two clips their whole
    frames, once per pair (a slider's new seams cost nothing: about 1 ms a call otherwise); in
    a gap in a take (A is B) the frames the output keeps of it (to ``a_end``, from ``b_start``:
    never the gap's own), once per pair of seams. The last few are kept."""
    ta, tb = ta.base or ta, tb.base or tb  # kept for the clips (a seam's view reads the same frames)
    same = ta is tb
    key = (id(ta), id(tb)) + ((a_end, b_start) if same else ())
    kept = eng._clip_limbs.get(key)
    if kept is None or kept[0] is not ta or kept[1] is not tb:
        _forget_gone_clips(eng)  # a new pair: the clips replaced or dropped since go
        sk = eng.skeleton
        parts = ([(ta.motion, slice(0, a_end + 1)), (tb.motion, slice(b_start, None))] if same
                 else [(ta.motion, slice(None)), (tb.motion, slice(None))])
        rots = np.concatenate([m.rotations[s] for m, s in parts])
        positions = np.concatenate([np.broadcast_to(m.positions, m.rotations.shape[:-1] + (3,))[s] for m, s in parts])
        kept = (ta, tb, hinges.packed(hinges.find(sk.parents, leg_chains(sk) + arm_chains(sk), rots, positions),
                                      sk.parents))
        if len(eng._clip_limbs) >= 8:  # the oldest goes
            eng._clip_limbs.pop(next(iter(eng._clip_limbs)))
        eng._clip_limbs[key] = kept
    return kept[2]


def _library_limbs(eng: TransitionEngine, lib: MotionLibrary) -> tuple:
    """The knees' and elbows' hinges and bounds in ``lib`` (:func:`posturemap.synth.hinges.packed`
    of :func:`~posturemap.synth.hinges.find`), once per library."""
    sk = eng.skeleton
    return lib.derived("hinges", lambda: hinges.packed(hinges.find(
        sk.parents, leg_chains(sk) + arm_chains(sk), lib.rots, sk.offsets), sk.parents))


def _limb_bends(eng: TransitionEngine, track: Track, limbs: tuple) -> tuple[np.ndarray, ...]:
    """How far back each knee and elbow of ``limbs`` (:func:`posturemap.synth.hinges.packed`)
    goes in ``track``'s frames up to each frame and from each frame on, and how far forward:
    (N, limbs) each, the running minimum of :func:`posturemap.synth.hinges.bend_frames` from the
    clip's first frame and from its last, then the running maximum likewise. Once per clip and
    limbs (a clip's first transition, or :meth:`TransitionEngine.warm_up`), so a transition
    reads four rows, whatever the clip's length."""
    track = track.base or track  # kept per clip (a seam's view bends its knees as the clip does)
    kept = eng._limb_bends.get(id(track))
    if kept is None or kept[0] is not track or kept[1] is not limbs:
        _forget_gone_clips(eng)  # a clip's first transition: the clips replaced or dropped since go
        bends = hinges.bend_frames(limbs[:3], track.motion.rotations, track.motion.positions)
        kept = track, limbs, (np.minimum.accumulate(bends, axis=0), np.minimum.accumulate(bends[::-1], axis=0)[::-1],
                              np.maximum.accumulate(bends, axis=0), np.maximum.accumulate(bends[::-1], axis=0)[::-1])
        eng._limb_bends[id(track)] = kept
    return kept[2]


def _forget_gone_clips(eng: TransitionEngine) -> None:
    """Drop the knees' and elbows' own bounds the engine keeps of clips no longer among its
    tracks (replaced under their name, or dropped): a server that replaces its clips would
    otherwise keep every one, and a fork would copy them."""
    live = {id(t): t for t in eng.tracks.values()}
    eng._seam_views = {k: v for k, v in eng._seam_views.items() if live.get(k[0]) is v[0]}
    eng._learned = {k: v for k, v in eng._learned.items() if live.get(k) is v[0]}
    eng._over = {k: v for k, v in eng._over.items() if live.get(k) is v[0]}
    eng._limb_bends = {k: v for k, v in eng._limb_bends.items() if live.get(k) is v[0]}
    eng._own = {k: v for k, v in eng._own.items() if live.get(k[0]) is v[0] and live.get(k[1]) is v[1]}
    eng._own_frames = {k: v for k, v in eng._own_frames.items() if live.get(k) is v[0]}
    eng._clip_limbs = {k: v for k, v in eng._clip_limbs.items() if live.get(id(v[0])) is v[0]
                       and live.get(id(v[1])) is v[1]}


def _interpolated(eng: TransitionEngine, ta: Track, tb: Track, a: str, b: str, req: TransitionRequest,
                  swing_joints: np.ndarray | None = None):
    """The interpolating methods: seam values (and keys) through the method's basis.

    ``swing_joints``: for ``damped``, the joints (indices) whose swings may be continued (all
    by default; retrieval's fallback passes the parts it falls back for)."""
    up, root, length, a_end, b_start = eng._up, eng._root, req.length, req.a_end, req.b_start
    # Seam frames: A at a_end-2..a_end, B at b_start..b_start+1 (clamped inside the clips).
    ia = [max(a_end - 2, 0), max(a_end - 1, 0), a_end]
    ib = [b_start, min(b_start + 1, len(tb.gpos) - 1)]
    if req.align:
        dtheta, shift = eng.alignment(ta, tb, a_end, b_start, length)
    else:
        dtheta, shift = 0.0, np.zeros(3)
    # The keys, if any; the reference rotation per joint is the key's for keyed joints,
    # otherwise B's first frame.
    ref = tb.rots[b_start].copy()
    keys = _KEYS[req.method](eng, ta, tb, req) if req.method in _KEYS else None
    if keys is not None:
        ref[eng.model.space_.joints] = keys["key"][0]

    # Rows: A[a_end-2], A[a_end-1], A[a_end], B[b0], B[b0+1], then the context samples a method
    # asks for (damped: A's last and B's first frames every DAMPED_STEP_S seconds, and where
    # the clips are too short for the swing's fit at that step, its own closer samples).
    step = max(1, round(ta.motion.fps * DAMPED_STEP_S))
    ca, cb, fa, fb, fine = _NONE, _NONE, _NONE, _NONE, step
    if req.method in _CONTEXT:
        ca, cb = _context_frames(a_end, b_start, len(tb.gpos), step)
        fine = _swing_step(a_end, b_start, len(tb.gpos), step)
        if fine != step:
            fa, fb = _context_frames(a_end, b_start, len(tb.gpos), fine, DAMPED_SAMPLES * step // fine)
    rows = _seam_rows(eng, ta, tb, np.concatenate([ia, ca, fa]), np.concatenate([ib, cb, fb]), a_end, ref, dtheta,
                      shift)
    n_a = len(ia) + len(ca) + len(fa)
    seam = rows if n_a == len(ia) else rows[[0, 1, 2, n_a, n_a + 1]]
    rows_a, rows_b = rows[len(ia): len(ia) + len(ca)], rows[n_a + len(ib): n_a + len(ib) + len(cb)]
    swing_rows = (rows_a, rows_b, step) if fine == step else (rows[n_a - len(fa): n_a], rows[len(rows) - len(fb):],
                                                              fine)
    context = (rows_a, rows_b, step, swing_joints, swing_rows)
    s0 = 3 * eng.skeleton.num_joints
    # Inputs of the bases: pA, vA, pB, vB, and the fifth row (aA or a key) per method.
    inputs = np.empty((5, seam.shape[1]))
    inputs[0] = seam[2]
    np.subtract(seam[2], seam[1], out=inputs[1])
    inputs[2] = seam[3]
    np.subtract(seam[4], seam[3], out=inputs[3])
    frames = _FRAMES[req.method](eng, seam, inputs, ref, req, ta.motion.fps, keys, context)

    out_r, out_p = eng._out(length)
    j_count = eng.skeleton.num_joints
    kernels.exp_relative(frames[:, :s0].reshape(length, j_count, 3), ref, out_r)
    out_p[:] = frames[:, s0 + 4:].reshape(length, j_count, 3)
    # Contiguous copies: a compiled kernel given another memory layout than its other callers
    # compiles (or loads) a second version on that call, a hitch of 10-40 ms.
    kernels.compose_root(eng._chain, root, up, out_r, out_p, np.ascontiguousarray(frames[:, s0: s0 + 3]),
                         np.ascontiguousarray(frames[:, s0 + 3]))
    eng.last = {"key": None if keys is None else keys["key"], "neurons": None if keys is None else keys["neurons"],
                "dtheta": dtheta, "shift": shift}
    if req.foot_lock and eng._legs:
        # The lock bends a knee in its own plane: one the interpolation bent backward would be
        # bent on backward and swung round through straight (the spline between two sideways
        # walks, 102 degrees in a frame at a knee); unbent first, as auto's and retrieval's are.
        _unbend_limbs(eng, ta, tb, a_end, b_start, out_r, out_p, legs_only=True)
        eng.last["planted"] = eng._lock_feet(ta, tb, req, out_r, out_p, dtheta, shift)
    return out_r, out_p


_NONE = np.zeros(0, dtype=np.int64)
_CONTEXT = ("damped",)  # the methods that read more of the clips than the seams


def _context_frames(a_end: int, b_start: int, b_len: int, step: int,
                    count: int = DAMPED_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``count`` of A's frames every ``step`` up to ``a_end`` and of B's from
    ``b_start`` (as far as the clips go), in time order."""
    ca = a_end - step * np.arange(min(count, a_end // step + 1))[::-1]
    cb = b_start + step * np.arange(min(count, (b_len - 1 - b_start) // step + 1))
    return ca, cb


def _swing_step(a_end: int, b_start: int, b_len: int, step: int) -> int:
    """The step (frames) between the samples the swing's fit reads (:func:`_continue_swings`):
    ``damped``'s ``step`` where each clip gives :data:`PERIODIC_MIN_SAMPLES` samples at it,
    otherwise the longest that does, down to every frame (``step`` itself where not even that
    does). At 60 fps and above, ``step`` is 2 frames and more, and a context of 10 frames each
    side (the protocol's) gives 5 samples or fewer at it."""
    room = min(a_end, b_len - 1 - b_start) // (PERIODIC_MIN_SAMPLES - 1)
    return step if room < 1 else min(step, room)


def _seam_rows(eng: TransitionEngine, ta: Track, tb: Track, ia, ib, a_end: int, ref: np.ndarray, dtheta: float,
               shift: np.ndarray) -> np.ndarray:
    """Frames ``ia`` of A and ``ib`` of B as rows of the interpolating methods' columns:
    rotation vectors about ``ref`` (J x 3), the root's position (3; B's turned by ``dtheta`` and
    moved by ``shift``), its heading (1; B's unwrapped to A's at ``a_end``) and the local
    translations (J x 3)."""
    j_count, up = eng.skeleton.num_joints, eng._up
    n_a = len(ia)
    turns = TWO_PI * round((ta.heading[a_end] - tb.heading[ib[0]] - dtheta) / TWO_PI)
    out = np.empty((n_a + len(ib), 3 * j_count + 4 + 3 * j_count))
    if kernels.backend() == "numba":  # the steps below in one call (some twenty numpy calls otherwise)
        kernels.compiled().seam_rows(ta.rots, ta.motion.positions, ta.gpos, ta.heading, np.asarray(ia, np.int64),
                                     tb.rots, tb.motion.positions, tb.gpos, tb.heading, np.asarray(ib, np.int64), ref,
                                     float(dtheta), np.asarray(shift, dtype=float), float(turns), up, out)
        return out
    b_head = tb.heading[ib] + dtheta
    b_head += turns
    kernels.log_relative(np.concatenate([ta.rots[ia], tb.rots[ib]]), ref,
                         out[:, : 3 * j_count].reshape(len(out), j_count, 3))
    s0 = 3 * j_count
    out[:n_a, s0: s0 + 3] = ta.gpos[ia]
    out[:n_a, s0 + 3] = ta.heading[ia]
    out[:n_a, s0 + 4:] = ta.motion.positions[ia].reshape(n_a, -1)
    out[n_a:, s0: s0 + 3] = rotate_about_up(tb.gpos[ib], dtheta, up) + shift
    out[n_a:, s0 + 3] = b_head
    out[n_a:, s0 + 4:] = tb.motion.positions[ib].reshape(len(ib), -1)
    _unwrap_seam_rows(out[:, :s0].reshape(len(out), j_count, 3), np.asarray(ia), np.asarray(ib))
    return out


def _unwrap_seam_rows(rotvec: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> None:
    """Each row's rotation vectors (N, J, 3; A's frames ``ia``, then B's ``ib``) expressed near
    those of the row before it in time, from A's last frame back and from B's first on
    (:func:`posturemap.core.quat.near_turn`), in place; the last of A and the first of B keep
    the short arc about the reference.

    A joint half a turn from the reference (an arm raised at A's end, hanging at B's start, its
    twist the other way) has its short arcs on either side of that half turn from one frame to
    the next: their difference, the seam's velocity, was nearly a whole turn, and ``spline``,
    ``inertialize`` and ``damped`` swung the arm round at up to 120 degrees a frame.
    """
    for frames, first, order in ((ia, 0, np.argsort(-ia, kind="stable")), (ib, len(ia), np.argsort(ib, kind="stable"))):
        for i in range(1, len(frames)):
            r, p = first + order[i], first + order[i - 1]
            rotvec[r] = quat.near_turn(rotvec[r], rotvec[p])


@lru_cache(maxsize=16)
def _column_groups(j_count: int) -> np.ndarray:
    """Where each quantity of :func:`_seam_rows` begins: a joint's rotation vector, each
    coordinate of the root's position, its heading, a joint's translation (as
    ``np.add.reduceat`` takes them)."""
    s0 = 3 * j_count
    out = np.concatenate([np.arange(0, s0, 3), [s0, s0 + 1, s0 + 2, s0 + 3],
                          np.arange(s0 + 4, 2 * s0 + 4, 3)]).astype(np.intp)
    out.setflags(write=False)
    return out


# Keys of the key-posture methods: the key (rotations of the feature joints, root height), the
# neuron per class, and what the method's frames need besides.
def _paper_key(eng, ta, tb, req, path=False):
    key_vec, chosen = eng.keys.key_features(ta.features[req.a_end], tb.features[req.b_start], req.alpha, path=path)
    return {"key": eng.keys.decode_key(key_vec), "neurons": chosen}


def _path_key(eng, ta, tb, req):
    return _paper_key(eng, ta, tb, req, path=True)


def _valid_key(eng, ta, tb, req):
    times, key_vecs, main, chosen = eng.keys.valid_keys(ta, tb, req.a_end, req.b_start, req.length, req.key_at,
                                                        req.alpha)
    key_rots, key_heights = eng.keys.decode_keys(key_vecs)
    return {"key": (key_rots[main], float(key_heights[main])), "neurons": chosen, "times": times,
            "rots": key_rots, "heights": key_heights}


# The frames (length, columns) of each interpolating method from the seam rows and its inputs.
def _slerp_frames(eng, seam, inputs, ref, req, fps, keys, context):
    return linear_basis(req.length) @ inputs[[0, 2]]


def _inertialize_frames(eng, seam, inputs, ref, req, fps, keys, context):
    inputs[4] = seam[2] - 2.0 * seam[1] + seam[0]
    return inertialize_basis(req.length) @ inputs


def _spline_frames(eng, seam, inputs, ref, req, fps, keys, context):
    return hermite_basis(req.length) @ inputs[:4]


def _damped_frames(eng, seam, inputs, ref, req, fps, keys, context):
    """Each column's seam velocities carried for its motion's own time scale
    (:func:`posturemap.synth.bases.damped_time_scales` of A's last and B's first
    ``DAMPED_SAMPLES`` frames, ``DAMPED_STEP_S`` apart, together: over the six splits of
    ``docs/retrieval.md`` each seam's own scale, from its 0.3 s alone, scored 0.693x SLERP's L2Q
    at 45 frames against 0.688x, and lost more on waves), except the root's horizontal position,
    whose velocity is let go as soon as possible (``DAMPED_TAU_S``): carried longer, a root
    travelling at a seam (a run slowing down, a step) moves off the line to B's place and must
    come back (over the six splits of ``docs/retrieval.md``, adapting it too cost about 2% L2P).
    The root's height keeps its own, with the legs that carry it. No time constant exceeds
    ``DAMPED_GAP_SHARE`` of the gap, so that each seam's carried velocity turns (at 1.6 tau)
    before the gap's middle, except where a joint's rotation heads for the other seam's pose
    faster than the straight line: that part of its velocity is carried until it gets there
    (:func:`posturemap.synth.bases.reach_parts`, at most ``DAMPED_REACH_SHARE`` of the gap), as
    a hand raised to where B holds it goes on rising instead of crawling along the straight
    line (``docs/retrieval.md``, "A reach is carried to its end")."""
    rows_a, rows_b, step, swing_joints, swing_rows = context
    j_count = eng.skeleton.num_joints
    starts, fixed = _column_groups(j_count), _fixed_columns(j_count, eng._up)
    longest = max(DAMPED_TAU_S * fps, min(DAMPED_TAU_MAX_S * fps, DAMPED_GAP_SHARE * (req.length + 1)))
    reach_max = DAMPED_REACH_SHARE * (req.length + 1)
    if kernels.backend() == "numba":  # the same steps compiled (a few hundred numpy calls otherwise)
        out = np.empty((req.length, inputs.shape[1]))
        kernels.compiled().damped_columns(inputs, req.length, rows_a, rows_b, float(step), starts, fixed,
                                          DAMPED_TAU_S * fps, longest, 3 * j_count, reach_max, DAMPED_PEAK, out)
    else:
        scale = np.where(fixed, 0.0, damped_time_scales((rows_a, rows_b), step, starts))
        out = damped_frames(inputs, req.length, scale, DAMPED_TAU_S * fps, longest,
                            reach_parts(inputs, starts, 3 * j_count, req.length + 1.0, reach_max))
    _continue_swings(out, inputs, *swing_rows, req.length, fps, j_count, swing_joints)
    return out


def _continue_swings(out, inputs, rows_a, rows_b, step, length, fps, j_count, joints=None):
    """Blend into ``out`` (in place) the rotations of ``joints`` (indices; all by default) that
    swing back and forth at both seams, continued in phase through the gap
    (:func:`posturemap.synth.periodic.continued`; rotations only: the root's travel and the
    translations keep ``damped``'s). Over the six splits of ``docs/retrieval.md`` and Bandai's
    dataset-2 this took the default's waves from 0.90 to 0.79x SLERP's L2Q at 30 frames (0.96
    to 0.84x at 45); bows, pointing arms, walks and runs moved by under 0.01, raised hands with
    both arms lost 0.03-0.05 at 30 frames."""
    if joints is None:
        cols = slice(0, 3 * j_count)
        count = j_count
    else:
        cols = (3 * np.asarray(joints)[:, None] + np.arange(3)).ravel()
        count = len(joints)
        if not count:
            return
    rows = np.concatenate([rows_a[:, cols], rows_b[:, cols]])
    frames, weights = continued(rows, _sample_times(len(rows_a), len(rows_b), step, length), inputs[:4, cols], length,
                                fps, _column_groups(count)[:count], DAMPED_TAU_S * fps)
    if frames is not None:
        out[:, cols] += weights * (frames - out[:, cols])


@lru_cache(maxsize=64)
def _sample_times(n_a: int, n_b: int, step: int, length: int) -> np.ndarray:
    """The times (frames; A's seam at 0, B's at ``length + 1``) of ``n_a`` samples of A up to its
    seam and ``n_b`` of B from its seam, ``step`` apart (:func:`_context_frames`)."""
    out = np.concatenate([-step * np.arange(n_a - 1, -1, -1.0), length + 1.0 + step * np.arange(n_b, dtype=float)])
    out.setflags(write=False)
    return out


@lru_cache(maxsize=16)
def _fixed_columns(j_count: int, up: int) -> np.ndarray:
    """The columns of :func:`_seam_rows` whose ``damped`` time constant stays the shortest: the
    root's horizontal position."""
    out = np.zeros(6 * j_count + 4, dtype=bool)
    out[3 * j_count: 3 * j_count + 3] = np.arange(3) != up
    out.setflags(write=False)
    return out


def _key_frames(eng, seam, inputs, ref, req, fps, keys, context):
    """One clamped B-spline through the key for every column: keyed columns (feature joints'
    rotations, 0 about the key, and the root height) take the key's value, the others the
    Hermite curve's own value there, which leaves them on that curve."""
    inputs[4] = hermite_basis(req.length)[req.key_at - 1] @ inputs[:4]
    kcols = eng.keys.keyed_columns()
    inputs[4, kcols[:-1]] = 0.0
    inputs[4, kcols[-1]] = keys["key"][1]
    return key_spline_basis(req.length, req.key_at) @ inputs


def _valid_frames(eng, seam, inputs, ref, req, fps, keys, context):
    """Keys at several times: keyed columns take the keys' values (rotation vectors about the
    main key); the free columns (trajectory, joints outside the map) take the same kind of
    estimate: the straight line plus the damped seam velocities."""
    times, length = keys["times"], req.length
    kcols = eng.keys.keyed_columns()
    warp = times / (length + 1.0)
    ga, gb = damped_reach(times, length + 1.0, VELOCITY_HORIZON_S * fps)
    keyrows = (inputs[0] + warp[:, None] * (inputs[2] - inputs[0])
               + ((1 - warp) * ga)[:, None] * inputs[1] - (warp * gb)[:, None] * inputs[3])
    jk = eng.model.space_.joints
    krot = np.empty((len(times), len(jk), 3))
    kernels.log_relative(keys["rots"], ref[jk], krot)
    keyrows[:, kcols[:-1]] = krot.reshape(len(times), -1)
    keyrows[:, kcols[-1]] = keys["heights"]
    return keys_spline_basis(length, tuple(times)) @ np.concatenate([inputs[:4], keyrows])


def _open_columns(eng: TransitionEngine, ta: Track, tb: Track, a_end: int, b_start: int, length: int):
    """What a fully retrieved transition leaves open, as ``spline`` makes it: the rotations of
    the joints above the root (L, J, 4; only those set) and the local translations (L, J, 3),
    each a cubic Hermite from A's last frame and rate to B's first. A reference joint that carries
    a clip's trajectory (four Bandai clips; a game rig's root bone) keeps its speed through the
    seams: LERPed, it turned back at once where B's stands elsewhere (run into walk: 12 cm per
    frame squared at A's seam, against at most 0.01 along A)."""
    basis = hermite_basis(length)
    chain = eng._chain
    a_prev, b_next = max(a_end - 1, 0), min(b_start + 1, len(tb.gpos) - 1)
    jit = retrieval._compiled()
    if jit is not None:  # the steps below in one call (the matrix products as sums: within 1e-13)
        rots = np.empty((length, eng.skeleton.num_joints, 4)) if len(chain) else np.empty((0, 0, 4))
        pos = np.empty((length, eng.skeleton.num_joints, 3))
        jit.open_columns(chain, ta.rots, tb.rots, a_prev, a_end, b_start, b_next, ta.motion.positions,
                         tb.motion.positions, basis, rots, pos)
        return (rots if len(chain) else None), pos
    rots = None
    if len(chain):
        ref = tb.rots[b_start, chain]
        seam = np.empty((4, len(chain), 3))
        kernels.log_relative(np.stack([ta.rots[a_prev, chain], ta.rots[a_end, chain], ref, tb.rots[b_next, chain]]),
                             ref, seam)
        seam[0] = quat.near_turn(seam[0], seam[1])  # A's rate, not a whole turn (_unwrap_seam_rows)
        rots = np.empty((length, eng.skeleton.num_joints, 4))
        part = np.empty((length, len(chain), 4))
        kernels.exp_relative(through_seams(seam, length), ref, part)
        rots[:, chain] = part
    return rots, through_seams(np.stack([ta.motion.positions[a_prev], ta.motion.positions[a_end],
                                         tb.motion.positions[b_start], tb.motion.positions[b_next]]), length)


def _retrieval(eng: TransitionEngine, ta: Track, tb: Track, a: str, b: str, req: TransitionRequest):
    """``method="retrieval"`` (:mod:`posturemap.synth.retrieval`), with its fallback blended by confidence."""
    length, a_end, b_start, align = req.length, req.a_end, req.b_start, req.align
    lib = getattr(eng.model, "library_", None)
    res = rt = found = None
    if lib is not None and len(lib):
        if eng._retriever is None or eng._retriever.lib is not lib:
            eng._retriever = retrieval.Retriever(eng, lib)
        rt = eng._retriever
        # Between clips (B placed to continue A): A's continuation into B's arrival, when no
        # single segment fits both seams. In in-betweening (B fixed) the single segment, matched
        # to the gap's displacement at both ends, stays: on the benchmark the splice there moved
        # L2Q by +0.3% to +1.6% (held-out contents at 15 and 30 frames) for no less skate.
        # One search ranks the candidates for the single segment and both halves of the splice.
        shared = {"alphas": (0.0, 1.0)} if align else {}
        # A library that holds the take being in-betweened (a map trained on it) would replay the
        # frames this transition replaces: that clip is left out (its kept frames are the clips'
        # own motion, below). Between clips (B placed to continue A) nothing is replaced.
        skip = (lib.take_clips(rt.part_joints[1], _learned_rows(eng, ta)[a_end], _learned_rows(eng, tb)[b_start],
                               b_start - a_end) if not align and b_start > a_end + 1 else None)
        found = retrieval.match(rt, ta, tb, a_end, b_start, length, req.alpha, align, shared=shared, skip=skip)
    # The clips' own motion (A's up to its end, B's from its start) searched as well where B
    # stays where it is (a gap in a take), or where no library is; its match is taken where it
    # costs no more than the library's and, between clips, carries the legs fully confident (else
    # the library's splice of A's continuation into B's arrival is the better bet), or where there
    # is no library match. See _own_retriever.
    own = _own_retriever(eng, ta, tb, a, b, a_end, b_start, length) if not align or rt is None else None
    if own is not None:
        own_shared = {"alphas": (0.0, 1.0)} if align else {}
        mine = retrieval.match(own, ta, tb, a_end, b_start, length, req.alpha, align, shared=own_shared)
        if mine is not None and (found is None or (mine.cost <= found.cost
                                                   and (not align or mine.confidence[0] >= 1.0))):
            rt, found, shared = own, mine, own_shared
    if found is not None:
        if align and found.confidence[0] < 1.0:
            res = spliced(rt, ta, tb, a_end, b_start, length, req.alpha, shared, beat=found.confidence[0])
        if res is None:
            res = retrieval.replay(rt, found, skip_unconfident=True)
    # The fallback where confidence is short of full; otherwise a cubic Hermite gives what the
    # retrieved parts leave open (joints above the root, local translations).
    fallback = retrieval.fallback_method(length, ta.motion.fps)
    if res is not None and min(res.confidence) >= 1.0:
        # Every part retrieved: only the joints above the root and the local translations are
        # left open, made as the spline method makes them (its other columns would be
        # overwritten), without running the whole method.
        rots_fb, pos_fb = _open_columns(eng, ta, tb, a_end, b_start, length)
        fb_last = None  # B's place and the report come from the retrieval alone
    else:
        # damped continues the swings of the parts it falls back for only (and of the joints
        # above the root, which always come from it): where the legs are replayed, the arms'
        # rhythm is not to be taken from legs the replay replaces.
        swing = None
        if fallback == "damped" and res is not None and max(res.confidence) >= 1.0 > min(res.confidence):
            swing = np.concatenate([rt.open_joints] + [j for c, j in zip(res.confidence, rt.part_joints) if c < 1.0])
        rots_fb, pos_fb = _interpolated(eng, ta, tb, a, b, req.replace(method=fallback, foot_lock=False),
                                        swing_joints=swing)
        rots_fb, pos_fb = rots_fb.copy(), pos_fb.copy()
        fb_last = eng.last
        if not align and fallback == "damped":
            _on_seam_path(eng, ta, tb, a_end, b_start, rots_fb, pos_fb)
    out_r, out_p = eng._out(length)
    if res is None or max(res.confidence) <= 0.0:
        out_r[:], out_p[:] = rots_fb, pos_fb
        eng.last = {**fb_last, "retrieval": None if res is None else res.info}
        dtheta, shift, contacts = fb_last["dtheta"], fb_last["shift"], None
    else:
        out_r[:] = res.rots
        for j in eng._chain.tolist():  # one joint at a time: basic indexing, no gather and scatter
            out_r[:, j] = rots_fb[:, j]
        out_p[:] = pos_fb
        went = None  # the retrieved root's turn from the fallback's at the last frame, the way round it went
        if res.confidence[0] > 0.0:  # a part with confidence 0 was not replayed: the fallback's
            heading = res.heading
            if res.confidence[0] < 1.0:
                heading, went = _blend_root(eng, rots_fb, out_r, heading, res.confidence[0], align)
            kernels.compose_root(eng._chain, eng._root, eng._up, out_r, out_p, res.gpos, heading)
        upper_fb = rots_fb
        if res.confidence[0] > 0.0 and res.confidence[1] < 1.0 and len(rt.upper_tops):
            upper_fb = _fallback_chest(eng, rots_fb, out_r, rt.upper_tops, align)
        for mask, c in ((rt.lower_mask, res.confidence[0]), (rt.upper_mask, res.confidence[1])):
            fb = upper_fb if mask is rt.upper_mask else rots_fb
            if c <= 0.0:
                out_r[:, mask] = fb[:, mask]
            elif c < 1.0:  # no flip where the two pass a half turn apart (kernels.slerp_track)
                # On the arc that goes on through the frames, every joint moving to whichever of
                # the two the confidence is nearer where the arc goes past a half turn round.
                if mask is rt.lower_mask:  # but the root, blended already (_blend_root)
                    mask = rt.legs_mask
                part = out_r[:, mask]
                kernels.slerp_track(fb[:, mask], part, c, part, np.ones(part.shape[1], dtype=bool))
                out_r[:, mask] = part
        if 0.0 < res.confidence[0] < 1.0:
            r = eng._root
            out_p[:, r] = pos_fb[:, r] + res.confidence[0] * (out_p[:, r] - pos_fb[:, r])
        dtheta, shift = res.dtheta, res.shift
        if res.confidence[0] <= 0.0:
            dtheta, shift = fb_last["dtheta"], fb_last["shift"]
        elif res.confidence[0] < 1.0 and align:  # B's place blended like the trajectory
            c = res.confidence[0]
            g0 = tb.gpos[b_start]
            end_fb = rotate_about_up(g0, fb_last["dtheta"], eng._up) + fb_last["shift"]
            end = rotate_about_up(g0, dtheta, eng._up) + shift
            res_dtheta = dtheta
            dtheta = fb_last["dtheta"] + c * _turn_round(dtheta - fb_last["dtheta"], went)
            shift = end_fb + c * (end - end_fb) - rotate_about_up(g0, dtheta, eng._up)
            _meet_b_velocity(eng, tb, b_start, out_r, out_p, c, res_dtheta, fb_last["dtheta"], dtheta)
        # The retrieved segment's planted feet wherever its legs count and lie within
        # CONTACTS_WITHIN degrees of the seams: a leg blended with the fallback glides, and the
        # lock's own detection (low and slow) finds no contact in it. Held-out dashes at 45 frames
        # (their legs 16-20 degrees away, 0.3-0.4 confident under the ramp of that time) skated
        # 9.1 cm/s with the segment's contacts from a confidence of 0.5 only, 4.8 so (truth 2.9).
        # Farther, the blended leg moves more like the interpolation, whose feet the lock finds
        # and holds itself: LaFAN1 in-betweening at 24 fps and 1.5 s skated 1.51 cm/s with the
        # segment's contacts at every distance, 1.41 so (truth 1.02; docs/retrieval.md).
        contacts = (res.contacts if res.confidence[0] > 0.0 and res.distance[0] < retrieval.CONTACTS_WITHIN
                    else None)
        eng.last = {"key": None, "neurons": None, "dtheta": dtheta, "shift": shift, "retrieval": res.info}
        # The head steadied (retrieval.HEAD_GAZE): half its turn in the world the fallback's.
        head = rt.head_chain
        if not align and fb_last is not None and res.confidence[1] > 0.0 and len(head) > 1:
            kernels.turn_toward(head, out_r, rots_fb, retrieval.HEAD_GAZE)
    _unbend_limbs(eng, ta, tb, a_end, b_start, out_r, out_p, None if own is None else own.lib)
    if req.foot_lock and eng._legs:
        eng.last["planted"] = eng._lock_feet(ta, tb, req, out_r, out_p, dtheta, shift, contacts)
    return out_r, out_p


def _fallback_chest(eng: TransitionEngine, rots_fb: np.ndarray, out_r: np.ndarray, tops: np.ndarray,
                    align: bool) -> np.ndarray:
    """``rots_fb`` (the fallback's frames) with the upper body's top joints ``tops`` (the spine's
    first, :func:`posturemap.core.joints.upper_tops`) put over the root of ``out_r`` (the
    retrieved legs' pelvis) so that in the world the chest is the fallback's turned about the up
    axis with the pelvis (:func:`posturemap.core.kernels.chest_turned`): in full between clips
    (``align``), beyond :data:`~posturemap.synth.retrieval.CHEST_FREE_DEG` where B stays where
    it is; a copy.

    Where the upper body is (in part) the fallback's and the legs are retrieved (gaps under 0.6
    s by :func:`posturemap.synth.retrieval.upper_weight`, or an upper body far from the
    library), the fallback's spine rotations were made for the fallback's pelvis. Copied as
    local rotations onto a retrieved pelvis, which tilts, rocks and swings about the up axis
    with its own steps, the chest took all of that too and moved off the seams' course. Now it
    keeps the fallback's lean; its heading turns with the pelvis (the swing-twist twist of the
    rotation from the fallback's pelvis to the retrieved one, theta). Where B stays where it is,
    both pelvises start at A's and end at B's (up to whole turns), and a walking pelvis swings
    about a chest that holds its course: the chest turns by ``theta - free tanh(sin(theta) /
    free)`` only (``free`` = 15 degrees: a few degrees of swing hardly turn it, a real turn
    carries it all but 15 degrees; the sine, theta within 15% up to 60 degrees, makes a half
    turn either way the same turn, so the chest never jumps where the pelvises face apart).
    Between clips the fallback's B is placed by its own alignment, the retrieved one's by the
    retrieved motion; the two pelvises end apart, and a chest held back had to catch up: 14-18
    of 100 of the bench's transitions between clips then had a joint accelerating over 1.5x as
    fast as the real frames do (0-2 with the full turn), their jerk 20% higher. At the seams
    both pelvises are the clips', so nothing changes there.

    Held out (the bench's protocol but windows cut per length, so not ``docs/results.md``'s
    figures; retrieval + foot lock, L2Q / L2P; as local rotations -> turning in full (code
    ``511d30a``) -> held within 15 degrees): held-out styles at 45 frames 0.4482 / 1.198 ->
    0.4454 / 1.189 -> 0.4413 / 1.186; held-out contents 0.6168 / 2.087 -> 0.6163 / 2.084 ->
    0.6156 / 2.083; CMU 01_01 at 120 fps, 15 frames 0.0790 / 0.506 -> 0.0781 / 0.449 -> 0.0779 /
    0.446 (the spline 0.0874 / 0.478), 60 frames 0.2828 / 2.529 -> 0.2793 / 2.456 -> 0.2763 /
    2.439; LaFAN1 at 60 fps, 30 frames 0.2929 / 1.197 -> 0.2921 / 1.191 -> 0.2897 / 1.187. The
    skate unchanged (the legs are untouched). 10 degrees gives nearly as much; 20 and 30 within
    0.0003, and no turn at all (the fallback chest's heading kept in the world whatever the
    pelvis does) within 0.001. Where the pelvises turn a half turn apart (a gap between two
    moments of a take that face opposite ways, the retrieved heading counted round otherwise than
    the fallback's), the first version's ``free tanh(theta / free)`` flipped the chest by 30
    degrees in one frame (CMU 01_01, 30 frames from its frame 2242 back to 1842: 38 degrees
    against 9 a frame); with the sine, 8.4 (8.3 turning in full).
    """
    out = rots_fb.copy()
    free = 0.0 if align else float(np.radians(retrieval.CHEST_FREE_DEG))
    kernels.chest_turned(np.append(eng._chain, eng._root), eng._up, rots_fb, out_r, tops, free, out)
    return out


def _own_retriever(eng: TransitionEngine, ta: Track, tb: Track, a: str, b: str, a_end: int, b_start: int,
                   length: int):
    """A retriever over the clips' own motion: A's frames up to ``a_end`` and B's from
    ``b_start`` (each at most ``eng.own_seconds`` long and :data:`OWN_FRAMES` frames, nearest
    the gap), as :func:`posturemap.synth.library.own_library` makes them, searched whole and
    matched on the map's library's feature scales, so that its match and the library's compare
    by cost. None without a map, with ``own_seconds`` 0, for clips at two frame rates, or where
    neither side holds a segment of the gap's shortest warp.

    A performer's own motion continues their motion best: in-betweening a gap in a take (the
    same clip as A and B), the take's other steps and gestures are the same person's, style
    and speed, where the library holds other performances. Only frames the output keeps are
    read, so a gap's own frames (the ones being replaced) never are. Kept per seam pair and the
    pieces it uses (the last few), for the next call on the same seams (a slider's); each clip's
    per-frame key joints and ankles once per clip."""
    if eng.model is None or eng.own_seconds <= 0 or not same_fps(ta.motion.fps, tb.motion.fps):
        return None
    ta, tb = ta.base or ta, tb.base or tb  # the clips' frames as given, kept per clip (not a seam's view)
    span = max(min(int(eng.own_seconds * ta.motion.fps), OWN_FRAMES), 2)
    shortest = max(1, round(min(retrieval.WARPS) * (length + 1.0)))  # a segment's fewest frames, less one
    sides = [p for p in ((a, ta, max(0, a_end + 1 - span), a_end + 1),
                         (b, tb, b_start, min(len(tb.gpos), b_start + span))) if p[3] - p[2] > shortest]
    if not sides:
        return None
    # The pieces a gap of this length can use (a short piece holds no segment of a long gap).
    key = (id(ta), id(tb)) + tuple((p[0] == a, p[2], p[3]) for p in sides)
    kept = eng._own.get(key)
    if kept is not None and kept[0] is ta and kept[1] is tb:
        return kept[2]
    lib = getattr(eng.model, "library_", None)
    lib = lib if lib is not None and len(lib) else None
    if lib is not None:
        lower, upper = lib.lower, lib.upper
    else:
        if eng._own_keys is None:
            eng._own_keys = key_joints(eng.skeleton)
        lower, upper = eng._own_keys
    pieces = [(name, track, lo, hi, _own_frames(eng, track, np.concatenate([lower, upper])))
              for name, track, lo, hi in sides]
    own_lib = own_library(pieces, eng._up, eng._leg_length, lower, upper, None if lib is None else lib.scale)
    base = eng._retriever if lib is not None and eng._retriever is not None else eng._own_base
    own = retrieval.Retriever(eng, own_lib, whole=True) if base is None else base.over(own_lib, whole=True)
    if lib is None:
        eng._own_base = own
    if len(eng._own) >= 8:  # the oldest goes
        eng._own.pop(next(iter(eng._own)))
    eng._own[key] = (ta, tb, own)
    return own


def _learned_rows(eng: TransitionEngine, track: Track) -> np.ndarray:
    """``track``'s rotations as a map learns them (:func:`posturemap.core.glitches.steadied`, as
    :meth:`posturemap.learn.model.PostureMap.fit` reads a clip): its own where it has no glitch
    step, which is nearly every clip; kept per clip. What a library that holds the clip holds."""
    track = track.base or track
    kept = eng._learned.get(id(track))
    if kept is None or kept[0] is not track:
        kept = eng._learned[id(track)] = (track, glitches.steadied(track.rots, track.motion.fps, eng._steadied))
    return kept[1]


def _over_bound(eng: TransitionEngine, track: Track) -> np.ndarray:
    """How many of ``track``'s steps up to each frame turn a joint below the root further than a
    glitch's bound (:func:`posturemap.core.glitches.over_bound`): (F,), 0 at frame 0; once per
    clip, so that a seam tells in two reads whether any step beside it can be a glitch."""
    track = track.base or track
    kept = eng._over.get(id(track))
    if kept is None or kept[0] is not track:
        over = glitches.over_bound(track.motion.rotations, track.motion.fps, eng._steadied).any(axis=1)
        kept = eng._over[id(track)] = (track, np.concatenate([[0], np.cumsum(over)]))
    return kept[1]


def _own_frames(eng: TransitionEngine, track: Track, keys: np.ndarray) -> dict:
    """:func:`posturemap.synth.library.own_frames` of ``track``, once per clip."""
    track = track.base or track
    kept = eng._own_frames.get(id(track))
    if kept is None or kept[0] is not track or not np.array_equal(kept[1], keys):
        _forget_gone_clips(eng)
        kept = (track, keys, own_frames(track, keys, [c[2] for c in eng._legs], eng._up))
        eng._own_frames[id(track)] = kept
    return kept[2]


def _on_seam_path(eng: TransitionEngine, ta: Track, tb: Track, a_end: int, b_start: int, rots, pos) -> None:
    """The fallback's root over the floor on the seams' own path
    (:func:`posturemap.synth.trajectory.seam_path`: the ``spline`` method's; over gaps longer than
    2 s, each seam's velocity averaged over its own last or first second), its height as the
    fallback makes it, where B stays where it is and the fallback is ``damped``.

    ``damped`` carries each seam's velocity for 0.05 s only, then runs straight: where the legs
    are not retrieved in full (other performers' motion, a turn the library lacks) the body cut
    the corner of a curving path and missed a change of pace. On LaFAN1's segments (subject 5,
    the map of subjects 1-4) the default's L2P at 1 / 1.5 s went 0.679 / 0.756x SLERP's ->
    0.612 / 0.621x at 60 fps; CMU 01_01 at 1 / 1.5 s 0.605 / 0.698x -> 0.583 / 0.679x; the six
    bandai1 splits' mean at 1 / 1.5 s 0.565 / 0.640x -> 0.559 / 0.635x (every split lower or
    level within 0.2%; held-out contents at 1.5 s 0.736 -> 0.727x). At 0.5 s the fallback is
    the spline itself.
    """
    path = seam_path(ta, tb, a_end, b_start, len(pos), eng._up)
    flat = [i for i in range(3) if i != eng._up]
    r, chain = eng._root, eng._chain
    if not len(chain):
        pos[:, r, flat] = path[:, flat]
        return
    # The joints above the root take the same course (a root bone keeps to the body; on LaFAN1 at
    # 2 s it strayed 28 cm from it in the median on damped's own, and erred 21 cm): their spline's.
    gq, gp = chain_world(chain.tolist() + [r], rots, pos)
    gp[:, flat] = path[:, flat]
    chain_r, chain_p = _open_columns(eng, ta, tb, a_end, b_start, len(pos))
    for j in chain.tolist():
        rots[:, j], pos[:, j] = chain_r[:, j], chain_p[:, j]
    put_root(chain, r, rots, pos, gq, gp)


def _blend_root(eng: TransitionEngine, rots_fb, out_r, heading, c: float, align: bool) -> tuple[np.ndarray, float]:
    """The root of legs ``c`` confident (0 < c < 1): the retrieved one (its tilt in
    ``out_r[:, root]``, its heading ``heading`` (L,)) blended with the fallback's (``rots_fb``)
    as a turn about the up axis and a tilt (:func:`posturemap.core.kernels.blend_root`; the
    tilt replaced in ``out_r``). Returns the blended headings (L,) (for
    :func:`posturemap.core.kernels.compose_root`) and the retrieved root's lead at the last
    frame, the way round it went (for :func:`_turn_round`).

    Blended as one rotation, on the arc that goes on from frame to frame
    (:func:`posturemap.core.kernels.slerp_track`), two roots whose headings drift a whole turn
    apart (a retrieved run circling while the fallback's runs straight) end nearly the identity
    apart on that arc, where its axis swings round from frame to frame: ``c`` of a whole turn
    about a swinging axis turned the hips 75 and 179 degrees in two frames (150 frames between
    a dash and a run, the legs 0.55 confident). A turn about the up axis is one angle, and
    blends on round without an axis to lose.
    """
    out = np.empty(len(heading))
    tilt = np.ascontiguousarray(out_r[:, eng._root])
    went = kernels.blend_root(eng._chain, eng._root, eng._up, eng._rest, rots_fb, tilt,
                              np.ascontiguousarray(heading, dtype=float), float(c), bool(align), out)
    out_r[:, eng._root] = tilt
    return out, float(went)


def _turn_round(turn: float, went: float | None) -> float:
    """The turn about the up axis from the fallback's placement of B to the retrieved one
    (``turn``, modulo a whole turn) the way round that the blend of their roots went: the short
    way, unless the retrieved root's heading went on round past a half turn from the
    fallback's (``went``, its lead at the last frame, from :func:`_blend_root`).

    B is placed by the blend of the two placements; turned the short way while the blended
    root had gone round the other way, B stood ``(1 - c)`` of a whole turn off the last new
    frame: on LaFAN1 (a walk into a stumble, the legs 0.92 confident) the hips turned 37 degrees
    in one frame into B.
    """
    short = turn - TWO_PI * round(turn / TWO_PI)
    if went is None:
        return short
    return short + TWO_PI * round((went - short) / TWO_PI)


def _meet_b_velocity(eng: TransitionEngine, tb: Track, b_start: int, out_r, out_p, c: float, turn_res: float,
                     turn_fb: float, turn: float) -> None:
    """The root of a trajectory blended between the retrieved one and the fallback's (legs
    ``c`` confident) leaves the gap at B's own velocity where B is placed.

    Each ends at B's velocity turned as it places B (``turn_res``, ``turn_fb``); their blend ends
    at the blend of those two vectors, which is shorter and turned otherwise than B's velocity
    turned by the blended ``turn`` where the two placements turn B far apart (LaFAN1: sidesteps
    into a jog, 46 cm/s into 306 cm/s at B's first frame). The difference is added over B's
    velocity offset curve (:func:`posturemap.synth.retrieval.offset_curves`: from nothing
    ``blend_frames`` before B's seam to its whole at the seam), in the frame of the root's parent.
    """
    up = eng._up
    v_b = tb.gpos[min(b_start + 1, len(tb.gpos) - 1)] - tb.gpos[b_start]
    miss = rotate_about_up(v_b, float(turn), up) - c * rotate_about_up(v_b, float(turn_res), up) \
        - (1.0 - c) * rotate_about_up(v_b, float(turn_fb), up)
    length = len(out_p)
    curve = retrieval._hermite_offsets_cached(length, retrieval.blend_frames(tb.motion.fps))[3]
    offset = curve[:, None] * miss[None]
    if len(eng._chain):  # the root's translation is in its parent's frame
        offset = quat.mul_vec(quat.inv(chain_world(eng._chain, out_r, out_p)[0]), offset)
    out_p[:, eng._root] += offset


_KEYS = {"upm": _paper_key, "upm-path": _path_key, "upm-valid": _valid_key}
_FRAMES = {"upm": _key_frames, "upm-path": _key_frames, "upm-valid": _valid_frames, "spline": _spline_frames,
           "damped": _damped_frames, "slerp": _slerp_frames, "inertialize": _inertialize_frames}
_RUN = {"auto": _auto, "retrieval": _retrieval, **{m: _interpolated for m in _FRAMES}}
assert set(_RUN) == set(METHODS), "every method of the request's catalogue has one implementation"


def transition(a: Motion, b: Motion, model=None, request: TransitionRequest | None = None, *,
               report: dict | None = None, **fields) -> Motion:
    """A[:a_end+1], then ``length`` new frames, then B[b_start:] (moved to continue A).

    Parameters
    ----------
    a, b : Motion with one skeleton (and the map's, when ``model`` is given)
    model : PostureMap or None; needed for the :data:`~posturemap.synth.request.KEYED` methods (``auto``, ``retrieval``,
        ``upm``...)
    request : a :class:`TransitionRequest` (default: its defaults), and/or its fields as
        keywords: ``length`` (20), ``alpha`` (0.5), ``method`` (``"auto"``),
        ``key_at``, ``a_end`` (A's last frame), ``b_start`` (0), ``align`` (True),
        ``foot_lock`` (True); see :class:`TransitionRequest` for their meaning
    report : a dict to fill with what was done: ``method`` (the one used, for ``auto``) and,
        for retrieval, ``retrieval`` (per body part: source clip and frames, warp, costs, match
        distance in degrees, confidence, and for a splice the second segment under ``then``;
        None when nothing fitted and the fallback was used)

    Returns
    -------
    Motion with ``a_end + 1 + length + len(b) - b_start`` frames, A's skeleton and fps.
    """
    req = TransitionRequest.of(request, **fields)
    engine = TransitionEngine(model, a.skeleton if model is None else None)
    engine.add("a", a)
    engine.add("b", b)
    req = req.resolved(len(a), len(b))
    rots, pos = engine.generate("a", "b", req)
    if report is not None:
        report["method"] = engine.last["method"]
        if "retrieval" in engine.last:
            report["retrieval"] = engine.last["retrieval"]
    mid = Motion(a.skeleton, rots.copy(), pos.copy(), a.fps)
    b_part = engine.continuation("b", req.b_start, req.align)
    return concatenate([a[: req.a_end + 1], mid, Motion(a.skeleton, b_part.rotations, b_part.positions, a.fps)])
