"""Motion: a skeleton plus per-frame local rotations and translations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from . import quat
from .skeleton import Skeleton, fk

AXES = "XYZ"
# The frame rates a clip may have (frames per second): a frame time from 0.1 ms to 10 s, as the
# BVH reader accepts; beyond, a gap's frame counts (seconds times fps) are meaningless or huge.
MIN_FPS, MAX_FPS = 0.1, 10000.0
# How far a rotation's length may be from 1 (the kernels compose and invert rotations as unit
# quaternions, so a longer one grows through every joint and frame it passes into): float32
# rotations from a game engine are within 1e-6; a rotation scaled by 1.01 is not a rotation.
QUAT_NORM_TOL = 1e-3


@dataclass(frozen=True, eq=False)
class Motion:
    """A clip as plain arrays.

    Attributes
    ----------
    skeleton : Skeleton with J joints
    rotations : ndarray, shape (F, J, 4), local rotations (w, x, y, z)
    positions : ndarray, shape (F, J, 3), local translations in the clip's own length unit
        (the bone offset for joints without position channels)
    fps : float, frames per second, from :data:`MIN_FPS` to :data:`MAX_FPS`
    source : ndarray (F, C) or None; for a motion read from a BVH file, the file's own channel
        values per frame (NaN rows for frames that did not come from a file). The BVH writer
        writes them back for every joint whose pose is unchanged, so that a file read and
        written keeps its own numbers (angles past +-180 degrees included); slicing and
        :func:`concatenate` keep them with their frames

    Rotations and translations of any real dtype (float32 from a game engine, say) are stored
    as float64, the kernels' type; complex or non-numeric arrays raise ``ValueError``.
    """

    skeleton: Skeleton
    rotations: np.ndarray
    positions: np.ndarray
    fps: float
    source: np.ndarray | None = None

    def __post_init__(self):
        # The kernels take float64: other real dtypes (float32 from a game engine, integers) are
        # converted here, once; complex or non-numeric arrays are refused.
        for name in ("rotations", "positions"):
            given = getattr(self, name)
            a = np.asarray(given)
            if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
                raise ValueError(f"{name} must be real numbers, got dtype {a.dtype}")
            a = a.astype(np.float64, copy=False)
            if a is not given:
                object.__setattr__(self, name, a)
        j = self.skeleton.num_joints
        if self.rotations.ndim != 3 or self.rotations.shape[1:] != (j, 4):
            raise ValueError(f"rotations must be (F, {j}, 4), got {self.rotations.shape}")
        if self.positions.shape != self.rotations.shape[:2] + (3,):
            raise ValueError(f"positions must be (F, {j}, 3), got {self.positions.shape}")
        if not MIN_FPS <= self.fps <= MAX_FPS:
            raise ValueError(f"fps must be from {MIN_FPS:g} to {MAX_FPS:g}, got {self.fps}")
        if self.source is not None and (self.source.ndim != 2 or len(self.source) != len(self.rotations)):
            raise ValueError(f"source must be (F, C) with F = {len(self.rotations)}, got {self.source.shape}")

    def check_usable(self, where: str) -> None:
        """Raise :class:`~posturemap.errors.UserError` on ``where`` unless the clip has frames,
        every rotation and translation is finite (what a map or a transition can read: a NaN at a
        seam would run through every new frame) and every rotation is a unit quaternion within
        :data:`QUAT_NORM_TOL` (:meth:`unit` makes them exact)."""
        if not len(self):
            raise UserError(where, "the clip has no frames")
        for name, a in (("rotation", self.rotations), ("translation", self.positions)):
            if not np.isfinite(a).all():
                f, j = (int(k) for k in np.argwhere(~np.isfinite(a))[0][:2])
                raise UserError(where, f"NaN or infinite {name} (frame {f}, joint {self.skeleton.names[j]!r})")
        if not _lengths_within(self.rotations, QUAT_NORM_TOL):
            off = np.abs(np.linalg.norm(self.rotations, axis=-1) - 1.0)
            f, j = (int(k) for k in np.unravel_index(off.argmax(), off.shape))
            size = float(np.linalg.norm(self.rotations[f, j]))
            raise UserError(where, f"rotation of length {size:.6g} is not a unit quaternion (frame {f}, joint "
                                   f"{self.skeleton.names[j]!r}; rotations are (w, x, y, z) of length 1)")

    def unit(self) -> "Motion":
        """This clip, or a copy whose rotations are scaled to length 1 where any is not within
        1e-12 (within :data:`QUAT_NORM_TOL`, as :meth:`check_usable` lets through): what the
        engine keeps (and so a map's motion library), so that new frames are rotations of length
        1 too."""
        if _lengths_within(self.rotations, 1e-12):
            return self
        return Motion(self.skeleton, quat.normalize(self.rotations), self.positions.copy(), self.fps,
                      None if self.source is None else self.source.copy())

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    def __len__(self) -> int:
        return self.num_frames

    def __getitem__(self, index) -> "Motion":
        """Frames by slice or index array; always returns a Motion (copies the arrays). A frame
        number outside the clip raises ``IndexError`` (so that iterating a Motion ends)."""
        if isinstance(index, (int, np.integer)):
            if not -self.num_frames <= index < self.num_frames:
                raise IndexError(f"frame {index} is outside the clip ({self.num_frames} frames)")
            index = slice(index, index + 1 if index != -1 else None)
        source = None if self.source is None else self.source[index].copy()
        return Motion(self.skeleton, self.rotations[index].copy(), self.positions[index].copy(), self.fps, source)

    def global_transforms(self) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations (F, J, 4) and positions (F, J, 3) of every joint."""
        return fk(self.skeleton.parents, self.rotations, self.positions)

    def global_positions(self) -> np.ndarray:
        """Global joint positions, shape (F, J, 3), in the clip's length unit."""
        return self.global_transforms()[1]


def _lengths_within(q: np.ndarray, tol: float) -> bool:
    """Whether every quaternion of ``q`` (..., 4) has a length within ``tol`` of 1 (from the
    squared lengths: a third of the time of the lengths)."""
    squared = np.einsum("...i,...i->...", q, q)
    return bool(((squared >= (1.0 - tol) ** 2) & (squared <= (1.0 + tol) ** 2)).all())


FPS_RTOL = 1e-3  # relative: frame times written with 4-7 digits (0.0333, 0.033333) are one rate


def same_fps(a: float, b: float) -> bool:
    """Whether two frame rates are the same rate (within :data:`FPS_RTOL`, relative)."""
    return abs(float(a) - float(b)) <= FPS_RTOL * max(abs(float(a)), abs(float(b)))


def concatenate(motions: list[Motion]) -> Motion:
    """Frames of ``motions`` one after another (same skeleton and fps required)."""
    first = motions[0]
    for m in motions[1:]:
        if not m.skeleton.same_as(first.skeleton):
            raise ValueError("cannot concatenate motions with different skeletons")
        if not same_fps(m.fps, first.fps):
            raise ValueError(f"cannot concatenate motions at {first.fps} and {m.fps} fps")
    source = None
    with_source = [m.source for m in motions if m.source is not None]
    if with_source and all(s.shape[1] == with_source[0].shape[1] for s in with_source):
        width = with_source[0].shape[1]
        source = np.concatenate([m.source if m.source is not None else np.full((len(m), width), np.nan)
                                 for m in motions])
    return Motion(first.skeleton, np.concatenate([m.rotations for m in motions]),
                  np.concatenate([m.positions for m in motions]), first.fps, source)


MAX_RESAMPLED_BYTES = 512 << 20  # a resampled motion's rotations and translations (float64); making them
#                                   takes about 3.5 times as much at its peak (about 1.8 GiB here)


def resample(motion: Motion, fps: float) -> Motion:
    """``motion`` at another frame rate, over the same time: frame ``k`` at ``k / fps`` seconds
    (the first at 0; as many as make the clip's duration to the nearest frame, a last one past
    the end taken at the end), each joint's rotation SLERPed and its translation LERPed between
    the two recorded frames around it. Clips used together share one rate (a transition's A and
    B, a map's training clips): this makes one clip the other's.

    Raises ValueError for a rate outside [0.1, 10000] (a BVH frame time of 10 s to 0.1 ms, what
    the reader takes), for a motion with no frame, and before allocating anything, for a result
    whose rotations and translations would take more than :data:`MAX_RESAMPLED_BYTES` (512 MiB:
    a 22-joint clip of 435,000 frames, an hour at 120 fps; 1,000 frames at 0.1 fps made 10,000
    fps would be 100 million); :class:`~posturemap.errors.UserError` for a NaN or infinite
    rotation or translation.
    """
    fps = float(fps)
    if not (np.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise ValueError(f"fps must be a number in [{MIN_FPS:g}, {MAX_FPS:g}], got {fps:g}")
    if motion.num_frames == 0:
        raise ValueError("a motion with no frame has no rate to change")
    motion.check_usable("motion")  # a NaN would pass into every frame it is interpolated into
    if same_fps(fps, motion.fps):
        return Motion(motion.skeleton, motion.rotations.copy(), motion.positions.copy(), motion.fps,
                      None if motion.source is None else motion.source.copy())
    last = motion.num_frames - 1
    n = int(np.floor(last * fps / motion.fps + 0.5)) + 1
    size = n * motion.skeleton.num_joints * 7 * 8
    if size > MAX_RESAMPLED_BYTES:
        raise ValueError(f"{motion.num_frames} frames at {motion.fps:g} fps make {n} at {fps:g} fps, "
                         f"{size / 2**20:,.0f} MiB: over {MAX_RESAMPLED_BYTES / 2**20:g} MiB")
    u = np.minimum(np.arange(n) * (motion.fps / fps), last)  # in the clip's frames
    i0 = np.minimum(np.floor(u).astype(np.int64), max(last - 1, 0))
    i1 = np.minimum(i0 + 1, last)
    f = u - i0
    rots = quat.slerp(motion.rotations[i0], motion.rotations[i1],
                      np.broadcast_to(f[:, None], (n, motion.skeleton.num_joints)))
    pos = motion.positions[i0] + f[:, None, None] * (motion.positions[i1] - motion.positions[i0])
    return Motion(motion.skeleton, rots, pos, fps)


def at_one_rate(motions: list[Motion], fps: float | None = None,
                names: list[str] | None = None) -> tuple[list[Motion], list[int]]:
    """``motions`` at one frame rate, ``fps`` (default the first motion's): each at another rate
    resampled to it (:func:`resample`), the others (and any of no frames) as they are. Returns the
    motions and the indices of those resampled. A clip too large to resample raises
    :class:`~posturemap.errors.UserError` naming it by ``names`` (default ``clip i``).

    The command line and the studio take clips of mixed rates this way (each resampled one named
    in a note); the API's :meth:`~posturemap.learn.model.PostureMap.fit` and a transition's A and
    B need one rate and say so.
    """
    motions = list(motions)
    if not motions:
        return [], []
    fps = float(motions[0].fps if fps is None else fps)
    if not (np.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise ValueError(f"fps must be a number in [{MIN_FPS:g}, {MAX_FPS:g}], got {fps:g}")
    changed = [i for i, m in enumerate(motions) if m.num_frames and not same_fps(m.fps, fps)]
    for i in changed:
        try:
            motions[i] = resample(motions[i], fps)
        except ValueError as e:
            raise UserError(f"clip {i}" if names is None else names[i], str(e)) from None
    return motions, changed


def resampled_note(name: str, was: float, now: float) -> str:
    """The note the command line and the studio give for a clip :func:`at_one_rate` resampled."""
    return f"posturemap: note: {name}: {was:g} fps, resampled to {now:g} fps (the first clip's rate)"


def resampled_name(name: str, fps: float) -> str:
    """A resampled clip's name in a map's library and a transition's report, whose frames it
    counts at the new rate ``fps``."""
    return f"{name} (at {fps:g} fps)"


def root_index(motion_or_skeleton) -> int:
    """The joint that carries the trajectory (the pelvis): decided from the skeleton.

    Where legs are found (:func:`posturemap.core.joints.leg_chains`: by name, else in the
    hierarchy), the joint they hang from, or its nearest ancestor with position channels, if its
    subtree holds at least half the joints: ``Hips`` for Bandai (its ``joint_Root`` above it is
    a reference node, fixed in most clips and sliding in a few) and for CMU, ``pelvis`` for Unreal's mannequin (whose
    ``root`` also holds the IK targets ``ik_foot_root`` and ``ik_hand_root`` beside the body).
    Otherwise the deepest joint with position channels whose subtree holds at least 90% of the
    joints; joint 0 for a skeleton with a single moving root. Motion of the joints above it is
    kept: features and alignment use the root's *global* transform through them.
    """
    from .joints import legs_root, named_hands_and_head, subtree_mask

    sk = getattr(motion_or_skeleton, "skeleton", motion_or_skeleton)
    j_count = sk.num_joints
    size = np.ones(j_count, dtype=np.int64)
    for j in range(j_count - 1, 0, -1):
        if sk.parents[j] >= 0:
            size[sk.parents[j]] += size[j]
    j = legs_root(sk)
    while j >= 0 and not sk.has_position(j):
        j = int(sk.parents[j])
    if j >= 0 and size[j] >= 0.5 * j_count:
        # ... holding the body's hands and head too, where some are named (a pelvis that holds
        # the legs alone, beside the spine, is not the body's root)
        below = subtree_mask(sk.parents, j)
        if all(not named or below[named].any() for named in named_hands_and_head(sk)):
            return int(j)
    depth = sk.depth()
    best = 0
    for j in range(j_count):
        if sk.has_position(j) and size[j] >= 0.9 * j_count and depth[j] >= depth[best]:
            best = j
    return int(best)


def _body_positions(motion: Motion, sample: int) -> np.ndarray:
    """Global positions (S, K, 3) of the root and its descendants at up to ``sample`` frames."""
    frames = np.unique(np.linspace(0, motion.num_frames - 1, min(sample, motion.num_frames)).astype(int))
    gpos = motion[frames].global_positions()
    root = root_index(motion)
    parents = motion.skeleton.parents
    keep = np.zeros(motion.skeleton.num_joints, dtype=bool)
    keep[root] = True
    for j in range(root + 1, len(parents)):
        keep[j] = parents[j] >= 0 and keep[parents[j]]
    return gpos[:, keep]


def _up_and_height(motion: Motion, sample: int) -> tuple[int, float]:
    """Up axis and body height from one forward-kinematics pass (see :func:`up_axis`)."""
    spread = np.median(np.ptp(_body_positions(motion, sample), axis=1), axis=0)
    up = int(np.argmax(spread))
    return up, float(spread[up])


def up_axis(motion: Motion, sample: int = 32) -> int:
    """Index (0=X, 1=Y, 2=Z) of the world's up axis, read from the data.

    The body is taller than it is wide or deep: the axis along which the root and its
    descendants spread most (median over up to ``sample`` frames spread over the clip).
    """
    return _up_and_height(motion, sample)[0]


def shared_up_axis(motions, sample: int = 32) -> tuple[int, list[int]]:
    """The up axis of a set of clips of one rig, and each clip's own (:func:`up_axis`).

    The axis most of their frames stand along (the first clip's on a tie): one clip mostly lying
    on the floor (a fall, a crawl) reads as another axis and must not set the set's."""
    axes = [up_axis(m, sample) for m in motions]
    frames = np.zeros(3)
    for m, a in zip(motions, axes):
        frames[a] += m.num_frames
    best = frames.max()
    return next(a for a in axes if frames[a] == best), axes


def body_height(motion: Motion, sample: int = 32) -> float:
    """Median extent of the body (root and descendants) along the up axis, in the clip's unit."""
    return _up_and_height(motion, sample)[1]


def length_unit(motion: Motion, height: float | None = None) -> str:
    """The clip's length unit guessed from the body height: "m", "cm", "mm", "inch" or "unknown".

    A guess for display only: posturemap never rescales a clip. CMU's BVH conversions use
    the ASF unit (1/0.45 inch; a body about 24-30 units tall) and come out "unknown".
    ``height`` is :func:`body_height` when already known.
    """
    h = body_height(motion) if height is None else height
    for unit, lo, hi in (("m", 0.8, 2.5), ("cm", 80.0, 250.0), ("mm", 800.0, 2500.0), ("inch", 32.0, 80.0)):
        if lo <= h <= hi:
            return unit
    return "unknown"


def summary(motion: Motion) -> str:
    """A short human-readable description of a clip."""
    sk = motion.skeleton
    up, height = _up_and_height(motion, 32)
    return (f"{motion.num_frames} frames at {motion.fps:g} fps ({motion.num_frames / motion.fps:.2f} s), "
            f"{sk.num_joints} joints, {sum(len(c) for c in sk.channels)} channels, "
            f"up axis {AXES[up]}, body height {height:.3g} "
            f"({length_unit(motion, height)}; top joint to lowest, under the actor's height), "
            f"root joint {sk.names[root_index(motion)]!r}")


def up_vector(axis: int) -> np.ndarray:
    v = np.zeros(3)
    v[axis] = 1.0
    return v
