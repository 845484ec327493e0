"""Motion library: the training clips kept for retrieval, with matching features and an index.

The posture maps say which postures are real; the library keeps the real *motion* behind
them, so that a transition can replay a real segment instead of interpolating (motion graphs,
Kovar et al. 2002; motion matching, Clavet 2016 and Holden et al. 2020).

Per library frame (all training clips, one after another; ``clip_start`` marks the clips):

- ``rots (N, J, 4)`` local rotations, the root's replaced by its tilt (as in a transition
  :class:`~posturemap.synth.engine.Track`), float32;
- ``gpos (N, 3)`` the root's global position and ``heading (N,)`` its turn about the up axis
  (radians, continuous within a clip): the root trajectory;
- ``contacts (N, legs)`` planted feet (low and slow ankles, thresholds of :mod:`posturemap.synth.feet`);
- matching features, each in the frame's own heading frame (so they do not depend on where the
  character stands or faces): ``pose (N, K, 3)`` key joints (ankles, knees, wrists, head)
  relative to the root, their velocities ``vel (N, K, 3)`` (per second, backward difference)
  and the root's velocity, turning rate and height, ``root (N, 5)``;
- ``win (N,)``: each frame's winning neuron in the index class map (the ``global`` class:
  thighs, upper arms, clavicles). Its inverted index (neuron -> frames, CSR) is the search's
  first stage, as an IVF index of a nearest-neighbour library is.

And for the whole library, ``toe_counts``: its toes' heights above the floor by speed
(:func:`posturemap.synth.feet.toe_height_counts`, summed over the clips; saved as
``toe_step_counts``), from which :attr:`MotionLibrary.clearance` says how high its swinging toes
keep (the foot lock lifts a swinging toe that hangs lower; None for a skeleton without toes or a
map file written before them: its counts, by central differences, are not read).

Every clip is also searched played backwards (``reverse``, on by default): time-reversed real
motion, the same postures and contacts travelled the other way, so that a library of forward
walks also holds backward walks. The reversed copies are made in memory when the library is
built or loaded; the map file holds the recorded clips only.

Bytes per frame are reported by :meth:`MotionLibrary.nbytes_per_frame`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.joints import CONTACT_HEIGHT, CONTACT_SPEED, key_joints, leg_chains, leg_length, leg_toes
from ..core import kernels
from ..core.skeleton import Skeleton, fk
from .feet import CLEAR_BINS, CLEAR_HEIGHTS, clearance_curve, slower_step, toe_height_counts

INDEX_CLASS = 1  # the map whose winners index the library ("global": thighs, upper arms)
FLOOR_PERCENTILE = 5.0  # a clip's floor under each ankle: this percentile of its heights
ARRAYS = ("clip_start", "rots", "gpos", "heading", "contacts", "pose", "vel", "root", "win")


def heading_frame(v: np.ndarray, heading: np.ndarray, up: int) -> np.ndarray:
    """Vectors ``v (F, ..., 3)`` turned by ``-heading (F,)`` about the up axis (into the body's frame)."""
    a, b = (up + 1) % 3, (up + 2) % 3
    c, s = np.cos(heading), np.sin(heading)
    shape = (len(heading),) + (1,) * (v.ndim - 2)
    c, s = c.reshape(shape), s.reshape(shape)
    out = v.copy()
    out[..., a] = c * v[..., a] + s * v[..., b]
    out[..., b] = -s * v[..., a] + c * v[..., b]
    return out


def clip_features(gpos_all: np.ndarray, root_pos: np.ndarray, heading: np.ndarray, joints: np.ndarray,
                  up: int, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Matching features of one clip: ``pose (F, K, 3)``, ``vel (F, K, 3)``, ``root (F, 5)``.

    gpos_all : (F, J, 3) global joint positions; root_pos : (F, 3); heading : (F,) radians;
    joints : (K,) key joints. ``pose`` is the key joints relative to the root in the heading
    frame; ``vel`` its backward difference per second (the first frame takes the forward one);
    ``root`` the root's velocity in the heading frame (3, per second), its turning rate
    (rad/s) and its height (the up coordinate).
    """
    rel = gpos_all[:, joints] - root_pos[:, None]
    pose = heading_frame(rel, heading, up)
    vel, root = motion_features(pose, root_pos, heading, up, fps)
    return pose, vel, root


def motion_features(pose: np.ndarray, root_pos: np.ndarray, heading: np.ndarray, up: int,
                    fps: float, starts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The velocity features of :func:`clip_features` from a clip's ``pose`` (F, K, 3), root
    positions (F, 3) and headings (F,): ``vel (F, K, 3)`` and ``root (F, 5)``. ``starts``
    (C + 1,), when given, splits the frames into clips (no difference across a boundary)."""
    f = len(pose)
    starts = np.array([0, f]) if starts is None else np.asarray(starts)
    first = np.zeros(f, dtype=bool)
    first[starts[:-1][np.diff(starts) > 0]] = True
    prev = np.arange(f) - 1
    # A clip's first frame takes the forward difference (negated), a one-frame clip none.
    prev[first] = np.minimum(np.flatnonzero(first) + 1, np.repeat(starts[1:], np.diff(starts))[first] - 1)
    sign = np.where(first, -1.0, 1.0)
    vel = (pose - pose[prev]) * (sign * fps)[:, None, None]
    rv = heading_frame((root_pos - root_pos[prev]) * (sign * fps)[:, None], heading, up)
    turn = (heading - heading[prev]) * sign * fps
    root = np.concatenate([rv, turn[:, None], root_pos[:, up: up + 1]], axis=1)
    return vel, root


def clip_contacts(ankles: np.ndarray, up: int, fps: float, leg: float) -> np.ndarray:
    """Planted feet (F, legs) of one clip from its global ankle positions (F, legs, 3).

    A foot is planted while its ankle is within :data:`posturemap.core.joints.CONTACT_HEIGHT` leg
    lengths of the clip's floor under it and moves slower than ``CONTACT_SPEED`` leg lengths
    per second horizontally (the same thresholds as the foot lock).
    """
    if ankles.shape[1] == 0 or len(ankles) == 0:
        return np.zeros(ankles.shape[:2], dtype=bool)
    flat = np.ones(3)
    flat[up] = 0.0
    return planted(ankles[..., up], slower_step(ankles * flat) * fps, leg)


def planted(heights: np.ndarray, speeds: np.ndarray, leg: float) -> np.ndarray:
    """:func:`clip_contacts` from the ankles' heights and horizontal speeds (F, legs): within
    ``CONTACT_HEIGHT`` leg lengths of the clip's floor (the :data:`FLOOR_PERCENTILE` th percentile
    of each ankle's heights) and slower than ``CONTACT_SPEED`` leg lengths per second."""
    floor = low_percentile(heights, FLOOR_PERCENTILE)
    return (heights < floor + CONTACT_HEIGHT * leg) & (speeds < CONTACT_SPEED * leg)


def low_percentile(x: np.ndarray, q: float) -> np.ndarray:
    """``np.percentile(x, q, axis=0)`` of finite ``x`` (its linear method), the same values to the
    bit, from a partial sort of the two rows it reads: a few microseconds on a piece of a clip, where
    ``np.percentile``'s general machinery takes about 25 (an in-betweening call builds the
    contacts of two pieces of its clips' own motion, :func:`own_library`)."""
    n = len(x)
    if n == 0:
        return np.percentile(x, q, axis=0)  # its own warning and NaNs
    at = (n - 1) * (q / 100.0)  # numpy's virtual index and interpolation, step by step
    lo = math.floor(at)
    if at >= n - 1:
        return np.partition(x, n - 1, axis=0)[n - 1]
    part = np.partition(x, (lo, lo + 1), axis=0)
    a, b = part[lo], part[lo + 1]
    t = at - lo
    diff = b - a
    return b - diff * (1.0 - t) if t >= 0.5 else a + diff * t


class EarlierLegs(ValueError):
    """A sound library whose feet are not the legs this version finds in the skeleton: a map
    trained by an earlier version on a rig that names no leg (it found none; the hierarchy's
    are found now, :func:`posturemap.core.joints.structural_legs`). ``PostureMap.load`` says so
    without calling the file corrupt."""

    sound_file = True


@dataclass(frozen=True, eq=False)
class MotionLibrary:
    """Real motion for retrieval (see the module docstring for the arrays).

    Build it with :func:`build_library`; the arrays are plain and saved in the map file.
    ``reference_scale``: the feature scales to match with (:attr:`scale`), another library's,
    so that the costs of searches over both compare (:func:`own_library`); None: this
    library's own (:func:`feature_scales`). ``clip_first``: each recorded clip's first frame
    in the clip it was cut from (:meth:`source_frames` counts from there); empty: 0 for each.
    """

    fps: float
    up: int
    leg: float
    clip_start: np.ndarray
    rots: np.ndarray
    gpos: np.ndarray
    heading: np.ndarray
    contacts: np.ndarray
    pose: np.ndarray
    vel: np.ndarray
    root: np.ndarray
    win: np.ndarray
    clip_names: tuple[str, ...] = ()
    lower: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    upper: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    reverse: bool = True
    toe_counts: np.ndarray | None = None
    reference_scale: np.ndarray | None = None
    clip_first: tuple[int, ...] = ()
    recorded: int = field(init=False)
    clip_of: np.ndarray = field(init=False)
    clip_end: np.ndarray = field(init=False)
    scale: np.ndarray = field(init=False)
    index_ptr: np.ndarray = field(init=False)
    index_frames: np.ndarray = field(init=False)
    _derived: dict = field(init=False, repr=False)  # see derived

    def __post_init__(self):
        object.__setattr__(self, "_derived", {})
        object.__setattr__(self, "recorded", len(self.rots))
        if self.reverse and len(self.rots):
            self._add_reversed()
        n = len(self.rots)
        clip_of = np.repeat(np.arange(len(self.clip_start) - 1), np.diff(self.clip_start))
        object.__setattr__(self, "clip_of", clip_of)
        object.__setattr__(self, "clip_end", self.clip_start[1:][clip_of] if n else np.zeros(0, np.int64))
        object.__setattr__(self, "scale", feature_scales(self) if self.reference_scale is None
                           else np.asarray(self.reference_scale, dtype=np.float64))
        order = np.argsort(self.win, kind="stable")
        ptr = np.zeros(int(self.win.max()) + 2 if n else 1, dtype=np.int64)
        np.add.at(ptr, self.win + 1, 1)
        object.__setattr__(self, "index_ptr", np.cumsum(ptr))
        object.__setattr__(self, "index_frames", order.astype(np.int64))

    def _add_reversed(self):
        """Append every clip played backwards (in memory only; the file holds the recorded clips).

        Time-reversed real motion: the same postures, contacts and paths, travelled the other
        way (a forward walk becomes a backward walk). Velocity features are recomputed."""
        starts = self.clip_start
        clip = np.repeat(np.arange(len(starts) - 1), np.diff(starts))
        order = starts[clip] + starts[clip + 1] - 1 - np.arange(len(clip))  # each clip back to front
        rev = {k: getattr(self, k)[order] for k in ("rots", "gpos", "heading", "contacts", "pose", "win")}
        v, r = motion_features(rev["pose"].astype(np.float64), rev["gpos"], rev["heading"], self.up, self.fps,
                               starts)
        rev["vel"], rev["root"] = v.astype(self.vel.dtype), r.astype(self.root.dtype)
        for k, v in rev.items():
            object.__setattr__(self, k, np.concatenate([getattr(self, k), v]))
        object.__setattr__(self, "clip_start", np.concatenate([starts, starts[-1] + starts[1:]]))
        object.__setattr__(self, "clip_names", tuple(self.clip_names)
                           + tuple(f"{n} (reversed)" for n in self.clip_names))

    def __len__(self) -> int:
        return len(self.rots)

    def derived(self, key, build):
        """A value computed from this library's arrays alone, once per library: ``build()`` on the
        first call with ``key``, the same object after. The search's rows of every frame
        (:attr:`posturemap.synth.retrieval.Retriever.lists`) are one: every engine serving this
        library shares them, so that a new engine (each :func:`posturemap.synth.engine.transition`
        call makes one) does not rebuild them (about 50 ms for bandai1). Threads that ask at once
        may both build; one result is kept."""
        value = self._derived.get(key)
        if value is None:
            value = self._derived.setdefault(key, build())
        return value

    @property
    def clearance(self) -> np.ndarray | None:
        """The least height of the library's swinging toes by speed (leg lengths, at
        :func:`posturemap.synth.feet.clearance_speeds`: :func:`~posturemap.synth.feet.clearance_curve`
        of ``toe_counts``), or None without toe counts."""
        if self.toe_counts is None:
            return None
        return self.derived("clearance", lambda: clearance_curve(self.toe_counts))

    @property
    def num_clips(self) -> int:
        return len(self.clip_start) - 1

    def nbytes_per_frame(self) -> float:
        """Stored bytes per recorded library frame (all per-frame arrays; the map file holds
        these, uncompressed; the reversed copies exist in memory only)."""
        return sum(getattr(self, k)[0].nbytes for k in ARRAYS if k != "clip_start") if len(self) else 0.0

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays to save (names without prefix): the recorded clips only."""
        n = self.recorded
        out = {k: getattr(self, k)[:n] for k in ARRAYS if k != "clip_start"}
        out["clip_start"] = self.clip_start[: self.num_recorded_clips + 1]
        out["lower"], out["upper"] = self.lower, self.upper
        if self.toe_counts is not None:
            out["toe_step_counts"] = self.toe_counts
        return out

    def joined(self, other: "MotionLibrary") -> "MotionLibrary":
        """This library's recorded clips followed by ``other``'s (one skeleton, fps and up axis):
        one index over both, their reversed copies made again."""
        a, b = self.arrays(), other.arrays()
        per_frame = [k for k in ARRAYS if k != "clip_start"]
        starts = np.concatenate([a["clip_start"], a["clip_start"][-1] + b["clip_start"][1:]])
        names = (tuple(self.clip_names[: self.num_recorded_clips])
                 + tuple(other.clip_names[: other.num_recorded_clips]))
        counts = (None if self.toe_counts is None or other.toe_counts is None
                  else self.toe_counts + other.toe_counts)
        return MotionLibrary(self.fps, self.up, self.leg, starts, clip_names=names, lower=self.lower,
                             upper=self.upper, reverse=self.reverse, toe_counts=counts,
                             **{k: np.concatenate([a[k], b[k]]) for k in per_frame})

    def source_frames(self, s: int, e: int) -> tuple[str, int, int]:
        """The recorded clip and its frame numbers of library frames ``s..e`` (one clip):
        ``(name, first, last)``, with ``first > last`` for a clip played backwards."""
        c = int(self.clip_of[s])
        first, last = s - int(self.clip_start[c]), e - int(self.clip_start[c])
        n_rec = self.num_recorded_clips
        if c < n_rec:
            return self.clip_names[c], first + self._first(c), last + self._first(c)
        n = int(self.clip_start[c + 1] - self.clip_start[c])
        rec = c - n_rec
        return self.clip_names[rec], n - 1 - first + self._first(rec), n - 1 - last + self._first(rec)

    def _first(self, c: int) -> int:
        return int(self.clip_first[c]) if c < len(self.clip_first) else 0

    def take_clips(self, joints: np.ndarray, a_rots: np.ndarray, b_rots: np.ndarray, gap: int) -> np.ndarray:
        """The clips of this library that are a take being in-betweened: those holding its frame
        ``a_rots`` (J, 4: a track's rotations, compared at ``joints``, as float32 as the library
        keeps them) and, ``gap`` frames later, its frame ``b_rots``; each recorded clip with its
        reversed copy. Their frames between would be the very frames the transition replaces
        (a map trained on the take). Empty where none. Found through a table of every recorded
        frame's rotations, made once per library."""
        table = self.derived(("frame table", tuple(int(j) for j in joints)), lambda: self._frame_table(joints))
        a = np.ascontiguousarray(a_rots[joints], dtype=np.float32)
        b = np.ascontiguousarray(b_rots[joints], dtype=np.float32)
        out = []
        for i in table.get(hash(a.tobytes()), ()):
            j = i + gap
            if (j < self.clip_end[i] and np.array_equal(self.rots[i, joints], a)
                    and np.array_equal(self.rots[j, joints], b)):
                c = int(self.clip_of[i])
                out += [c, c + self.num_recorded_clips] if self.reverse else [c]
        return np.unique(np.array(out, dtype=np.int64))

    def _frame_table(self, joints: np.ndarray) -> dict:
        """Each recorded frame's index under the hash of its rotations at ``joints``."""
        rows = np.ascontiguousarray(self.rots[: self.recorded][:, joints])
        table: dict[int, list[int]] = {}
        for i, row in enumerate(rows):
            table.setdefault(hash(row.tobytes()), []).append(i)
        return table

    def library_frame(self, name: str, frame: int) -> int:
        """The library index of frame ``frame`` (as recorded, counted in the clip it was cut from:
        ``clip_first``) of the recorded clip ``name`` (the first of that name that holds it);
        ValueError where none does."""
        for c in range(self.num_recorded_clips):
            first = self._first(c)
            if self.clip_names[c] == name and first <= frame < first + self.clip_start[c + 1] - self.clip_start[c]:
                return int(self.clip_start[c]) + frame - first
        raise ValueError(f"no recorded clip {name!r} holds frame {frame}")

    @property
    def num_recorded_clips(self) -> int:
        return (len(self.clip_start) - 1) // (2 if self.reverse else 1)

    def meta(self) -> dict:
        return {"fps": self.fps, "up": self.up, "leg": self.leg, "frames": self.recorded, "reverse": self.reverse,
                "clips": list(self.clip_names[: self.num_recorded_clips]),
                "bytes_per_frame": round(self.nbytes_per_frame(), 1)}

    @classmethod
    def from_parts(cls, meta: dict, arrays: dict, sk: Skeleton, n_neurons: int) -> "MotionLibrary":
        """A library from saved arrays, each checked (dtype, shape, finite, ranges); raises ValueError."""
        missing = [f"metadata '{k}'" for k in ("frames", "fps", "leg", "up") if k not in meta]
        missing += [f"array 'library_{k}'" for k in ARRAYS + ("lower", "upper") if k not in arrays]
        if missing:
            raise ValueError(f"library lacks {', '.join(missing)}")
        n = int(meta["frames"])
        j = sk.num_joints
        legs = len(leg_chains(sk))
        fps, leg, up = float(meta["fps"]), float(meta["leg"]), int(meta["up"])
        if not (np.isfinite(fps) and fps > 0 and np.isfinite(leg) and leg > 0 and up in (0, 1, 2) and n >= 1):
            raise ValueError("library metadata out of range")
        lower, upper = (np.asarray(arrays[k], dtype=np.int64) for k in ("lower", "upper"))
        k = len(lower) + len(upper)
        if lower.ndim != 1 or upper.ndim != 1 or np.any(lower < 0) or np.any(lower >= j) \
                or np.any(upper < 0) or np.any(upper >= j):
            raise ValueError("library key joints do not fit the skeleton")
        held = np.shape(arrays["contacts"])
        if len(held) == 2 and held[0] == n and held[1] != legs:
            raise EarlierLegs(f"its motion library holds the feet of {held[1]} legs, where this version finds "
                              f"{legs} in the skeleton (found by name, else in the hierarchy; a map trained by an "
                              "earlier version found legs by name only): train the map again")
        shapes = {"rots": (n, j, 4), "gpos": (n, 3), "heading": (n,), "contacts": (n, legs),
                  "pose": (n, k, 3), "vel": (n, k, 3), "root": (n, 5), "win": (n,)}
        out = {}
        for name, shape in shapes.items():
            a = arrays[name]
            if a.shape != shape:
                raise ValueError(f"library {name} has shape {a.shape}, expected {shape}")
            if name not in ("contacts", "win") and (a.dtype.kind != "f" or not np.all(np.isfinite(a))):
                raise ValueError(f"library {name} is not finite floating point")
            out[name] = a
        if out["contacts"].dtype.kind not in "biu":
            raise ValueError("library contacts are not booleans")
        q = out["rots"].reshape(-1, 4)
        if np.any(np.abs(np.einsum("ij,ij->i", q, q) - 1.0) > 2e-3):  # |q|^2 within 1e-3 of 1
            raise ValueError("library rotations are not unit quaternions")
        out["contacts"] = out["contacts"].astype(bool)
        if out["win"].dtype.kind not in "iu" or out["win"].min() < 0 or out["win"].max() >= n_neurons:
            raise ValueError("library index refers to neurons the map does not have")
        out["win"] = out["win"].astype(np.int32)
        starts = np.asarray(arrays["clip_start"], dtype=np.int64)
        if starts.ndim != 1 or len(starts) < 2 or starts[0] != 0 or starts[-1] != n or np.any(np.diff(starts) < 1):
            raise ValueError("library clip boundaries are inconsistent")
        names = tuple(str(c) for c in meta.get("clips", []))[: len(starts) - 1]
        names += tuple(f"clip {i}" for i in range(len(names), len(starts) - 1))
        reverse = meta.get("reverse", True)
        if not isinstance(reverse, bool):
            raise ValueError("library 'reverse' is not true or false")
        # Absent from map files written before it; a file's older ``toe_counts`` (speeds by central
        # differences, not each frame's shorter step) is not read: such a map keeps the rule.
        counts = arrays.get("toe_step_counts")
        if counts is not None:
            shape = (len(CLEAR_BINS) - 1, len(CLEAR_HEIGHTS) - 1)
            if counts.shape != shape:
                raise ValueError(f"library toe_step_counts has shape {counts.shape}, expected {shape}")
            if counts.dtype.kind not in "iuf" or not np.all(np.isfinite(counts)) or np.any(counts < 0) \
                    or np.any(counts != np.round(counts)):
                raise ValueError("library toe_step_counts are not counts")
            counts = counts.astype(np.float64)
        return cls(fps, up, leg, starts, clip_names=names, lower=lower, upper=upper, reverse=reverse,
                   toe_counts=counts, **out)


def feature_scales(lib: MotionLibrary) -> np.ndarray:
    """One scale per feature block, so that each block weighs alike (Holden et al. 2020).

    Returns (7,): lower pose, lower velocity, upper pose, upper velocity (the mean standard
    deviation of their coordinates over the library, 1 where a block is empty), then the
    root's velocity, turning rate and height (their standard deviations, at least 1e-6).
    """
    kl = len(lib.lower)

    def spread(x):
        return float(np.mean(np.std(x.reshape(len(x), -1), axis=0))) if x.size else 1.0

    s = np.array([spread(lib.pose[:, :kl]), spread(lib.vel[:, :kl]), spread(lib.pose[:, kl:]),
                  spread(lib.vel[:, kl:])])
    root = [float(np.mean(np.std(lib.root[:, :3], axis=0))), float(np.std(lib.root[:, 3])),
            float(np.std(lib.root[:, 4]))] if len(lib) else [1.0] * 3
    return np.concatenate([np.where(s > 1e-9, s, 1.0), np.maximum(root, 1e-6)])


def build_library(tracks, model, names=None, reverse: bool = True) -> MotionLibrary:
    """A library of the clips behind ``tracks`` (:class:`~posturemap.synth.engine.Track`, one skeleton).

    ``model`` (a fitted :class:`~posturemap.learn.model.PostureMap`) gives the index class map whose
    winners index the frames. ``reverse``: also search every clip played backwards.
    """
    sk = tracks[0].motion.skeleton
    up = model.space_.up
    fps = float(tracks[0].motion.fps)
    lower, upper = key_joints(sk)
    joints = np.concatenate([lower, upper])
    chains = leg_chains(sk)
    leg = leg_length(sk, chains)
    toes = leg_toes(sk, chains)
    has_toes = bool(len(chains)) and all(t != c[2] for t, c in zip(toes, chains))
    counts = None
    parts = {k: [] for k in ("rots", "gpos", "heading", "contacts", "pose", "vel", "root")}
    for tr in tracks:
        m = tr.motion
        _, gp = fk(sk.parents, m.rotations, m.positions)
        pose, vel, root = clip_features(gp, tr.gpos, tr.heading, joints, up, m.fps)
        parts["rots"].append(tr.rots.astype(np.float32))
        parts["gpos"].append(tr.gpos)
        parts["heading"].append(tr.heading)
        parts["contacts"].append(clip_contacts(gp[:, [c[2] for c in chains]], up, m.fps, leg))
        if has_toes:
            clip_counts = toe_height_counts(gp[:, toes], up, m.fps, leg)
            counts = clip_counts if counts is None else counts + clip_counts
        parts["pose"].append(pose.astype(np.float32))
        parts["vel"].append(vel.astype(np.float32))
        parts["root"].append(root.astype(np.float32))
    arrays = {k: np.concatenate(v) for k, v in parts.items()}
    feats = np.concatenate([tr.features for tr in tracks])
    cmap = model.maps_[INDEX_CLASS]
    win = cmap.predict(feats[:, model.space_.class_dims[INDEX_CLASS]]).astype(np.int32)
    starts = np.concatenate([[0], np.cumsum([len(tr.gpos) for tr in tracks])]).astype(np.int64)
    names = tuple(names) if names is not None else tuple(f"clip {i}" for i in range(len(tracks)))
    return MotionLibrary(fps, up, leg, starts, clip_names=names, lower=lower, upper=upper, win=win,
                         reverse=reverse, toe_counts=counts, **arrays)


def own_frames(track, keys: np.ndarray, ankles: list[int], up: int) -> dict[str, np.ndarray]:
    """What a library of a clip's own motion reads of each frame of a
    :class:`~posturemap.synth.engine.Track`, computed once per clip for :func:`own_library` to
    slice: ``pose`` (F, K, 3), the key joints ``keys`` about the root in its heading frame, as
    :func:`clip_features` has them, their velocity ``vel`` and ``root`` (F, 5) as
    :func:`motion_features` has them over the whole clip (backward differences), the root's
    velocity in the world ``root_world`` (F, 3), the ankles' heights ``heights`` (F, legs) and
    their places over the floor ``flat`` (F, legs, 3; the up coordinate 0)."""
    m = track.motion
    grot, gp = np.empty(m.rotations.shape), np.empty(m.positions.shape)
    kernels.fk(m.skeleton.parents, m.rotations, m.positions, grot, gp)
    pose = heading_frame(gp[:, keys] - track.gpos[:, None], track.heading, up)
    vel, root = motion_features(pose, track.gpos, track.heading, up, m.fps)
    flat = np.ones(3)
    flat[up] = 0.0
    feet = gp[:, ankles]
    return {"pose": pose, "vel": vel, "root": root,
            "root_world": np.concatenate([track.gpos[1:2] - track.gpos[:1], np.diff(track.gpos, axis=0)]) * m.fps,
            "heights": feet[..., up], "flat": feet * flat}


def _piece(frames: dict, lo: int, hi: int, heading: np.ndarray, up: int, fps: float, leg: float):
    """Frames ``lo .. hi - 1`` of :func:`own_frames`' arrays as a clip of their own: the features
    of :func:`clip_features` and the contacts of :func:`clip_contacts` computed on those frames
    alone (the first frame's velocities the step to the next, as a clip's first frame's; the
    floor and the ankles' speeds from the piece's frames): ``(pose, vel, root, contacts)``."""
    pose, vel, root = frames["pose"][lo:hi], frames["vel"][lo:hi].copy(), frames["root"][lo:hi].copy()
    if hi - lo < 2:  # one frame: no motion
        vel[:] = 0.0
        root[:, :4] = 0.0
    elif lo > 0:  # the frame before is not the piece's: the step to the next frame (as a clip's first frame)
        vel[0] = frames["vel"][lo + 1]
        root[0, :3] = heading_frame(frames["root_world"][lo + 1][None], heading[lo: lo + 1], up)[0]
        root[0, 3] = frames["root"][lo + 1, 3]
    h = frames["heights"][lo:hi]
    if h.shape[1] == 0:
        return pose, vel, root, np.zeros(h.shape, dtype=bool)
    return pose, vel, root, planted(h, slower_step(frames["flat"][lo:hi]) * fps, leg)


def own_library(pieces, up: int, leg: float, lower: np.ndarray, upper: np.ndarray,
                reference_scale: np.ndarray | None = None) -> MotionLibrary:
    """The clips' own motion as a library: ``pieces`` ``[(name, track, first, stop, frames)]``, the
    frames ``first .. stop - 1`` of each :class:`~posturemap.synth.engine.Track` (one skeleton and
    frame rate) with :func:`own_frames`' arrays of its whole clip (key joints ``lower`` then
    ``upper``), as recorded (no reversed copies), matched on ``reference_scale`` (the map's
    library's :attr:`MotionLibrary.scale`; None: their own). A piece's velocities, contacts and
    floor are computed from its own frames only (as :func:`build_library` computes a clip's):
    a piece that ends at A's last frame or starts at B's first knows nothing of the frames
    between. The frames are not indexed (``win`` 0): a search takes every one
    (:class:`~posturemap.synth.retrieval.Retriever` with ``whole``);
    :meth:`MotionLibrary.source_frames` counts each piece's frames in its clip.
    """
    fps = float(pieces[0][1].motion.fps)
    parts = {k: [] for k in ("rots", "gpos", "heading", "contacts", "pose", "vel", "root")}
    for _, tr, lo, hi, frames in pieces:
        pose, vel, root, contacts = _piece(frames, lo, hi, tr.heading, up, fps, leg)
        for k, v in (("rots", tr.rots[lo:hi]), ("pose", pose), ("vel", vel), ("root", root)):
            parts[k].append(v.astype(np.float32))
        parts["gpos"].append(tr.gpos[lo:hi])
        parts["heading"].append(tr.heading[lo:hi])
        parts["contacts"].append(contacts)
    arrays = {k: np.concatenate(v) for k, v in parts.items()}
    starts = np.concatenate([[0], np.cumsum([p[3] - p[2] for p in pieces])]).astype(np.int64)
    return MotionLibrary(fps, up, leg, starts, clip_names=tuple(p[0] for p in pieces), lower=lower, upper=upper,
                         win=np.zeros(int(starts[-1]), dtype=np.int32), reverse=False,
                         reference_scale=reference_scale, clip_first=tuple(int(p[2]) for p in pieces), **arrays)
