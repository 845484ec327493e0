"""Skeleton: joint names, parents, offsets and the BVH channel layout; forward kinematics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import quat

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
BODY_RATIO = 1.5  # clips of one rig whose bones differ in size by more are another unit (Skeleton.body_mismatch)


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A joint hierarchy.

    Attributes
    ----------
    names : tuple of str, length J
    parents : ndarray, shape (J,), int; -1 for the root, parents come before children
    offsets : ndarray, shape (J, 3); rest translation of each joint in its parent's frame
    channels : tuple of tuple of str, length J; BVH channel names per joint in file order
    end_sites : tuple of (int, ndarray (3,)); End Site offsets, keyed by the joint they end
    euler_style : "wrapped" (angles written in [-180, 180], middle angle within 90 degrees) or
        "continuous" (angles continuous over time, as some exporters write); read from the file
        and reproduced when writing
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_sites: tuple[tuple[int, np.ndarray], ...] = ()
    euler_style: str = "wrapped"

    def __post_init__(self):
        parents = np.asarray(self.parents, dtype=np.int64)
        if parents.shape != (len(self.names),) or np.any(parents >= np.arange(len(parents))):
            raise ValueError("parents must have one entry per joint and come before children")
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", np.asarray(self.offsets, dtype=float).reshape(-1, 3))

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of the joint called ``name`` (ValueError if absent)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"no joint named {name!r}") from None

    def rotation_order(self, j: int) -> str:
        """Euler order of joint ``j`` as in its channels, e.g. ``"ZXY"`` ("" if none)."""
        return "".join(c[0] for c in self.channels[j] if c in ROTATION_CHANNELS)

    def has_position(self, j: int) -> bool:
        return any(c in POSITION_CHANNELS for c in self.channels[j])

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == j)]

    def depth(self) -> np.ndarray:
        """Number of ancestors of each joint, shape (J,)."""
        d = np.zeros(self.num_joints, dtype=np.int64)
        for j in range(1, self.num_joints):
            d[j] = d[self.parents[j]] + 1 if self.parents[j] >= 0 else 0
        return d

    def same_as(self, other: "Skeleton") -> bool:
        """True when both have the same joints, hierarchy and channel layout."""
        return (self.names == other.names and np.array_equal(self.parents, other.parents)
                and self.channels == other.channels)

    def difference(self, other: "Skeleton", whose: str = "the other's") -> str | None:
        """The first way this skeleton's joints, hierarchy or channels differ from ``other``'s, in
        words (``whose`` names the other), or None where :meth:`same_as` holds."""
        if self.num_joints != other.num_joints:
            return f"{self.num_joints} joints, {whose} {other.num_joints}"
        for j in range(self.num_joints):
            if self.names[j] != other.names[j]:
                return f"joint {j} is {self.names[j]!r}, {whose} {other.names[j]!r}"
        for j in range(self.num_joints):
            mine, theirs = (int(x.parents[j]) for x in (self, other))
            if mine != theirs:
                def parent(sk, p):
                    return repr(sk.names[p]) if p >= 0 else "no parent"
                return f"{self.names[j]!r} hangs from {parent(self, mine)}, {whose} from {parent(other, theirs)}"
        for j in range(self.num_joints):
            if self.channels[j] != other.channels[j]:
                return (f"{self.names[j]!r} has channels {' '.join(self.channels[j]) or 'none'}, {whose} "
                        f"{' '.join(other.channels[j]) or 'none'}")
        return None

    def body_mismatch(self, other: "Skeleton", whose: str = "the other skeleton's") -> str | None:
        """Why clips of this skeleton cannot be mixed with ``other``'s (``whose`` names it in the
        message) though they have the same joints: their bones (the offsets of the joints below the
        root, the hips of :func:`posturemap.core.motion.root_index`: the offsets above and at it are
        where a recording starts, or a game rig's IK targets, not bones) differ in size by more
        than :data:`BODY_RATIO` (another unit: metres against centimetres, inches), or point other
        ways in the rest pose (the rig's bones laid out for another up axis). None when they can. Bodies of one rig a little smaller or larger, or arms
        in a T against an A pose, pass. (A clip turned to another up axis by its root's rotation
        has the same offsets: not seen here.)"""
        if self.offsets.shape != other.offsets.shape:
            return "its joints differ"
        from .joints import subtree_mask
        from .motion import root_index

        root = root_index(self)
        bones = subtree_mask(self.parents, root)  # the joints below the root
        bones[root] = False
        a, b = self.offsets[bones], other.offsets[bones]
        with np.errstate(over="ignore", invalid="ignore"):  # offsets near the float limit: said below
            la, lb = np.linalg.norm(a, axis=-1), np.linalg.norm(b, axis=-1)
            total_a, total_b = la.sum(), lb.sum()
        if not np.isfinite(total_a):
            return "its bone offsets are too large to be lengths"
        if not np.isfinite(total_b):
            return f"{whose} bone offsets are too large to be lengths"
        if total_a <= 0 or total_b <= 0:
            return None  # no bone lengths to compare
        ratio = float(total_a / total_b)
        if not 1 / BODY_RATIO <= ratio <= BODY_RATIO:
            return f"its bones are {ratio:.3g} times as long as {whose} (another unit?)"
        both = (la > 0) & (lb > 0)
        w = np.minimum(la, lb)[both]
        if w.sum() > 0:
            cos = np.sum(a[both] * b[both], axis=-1) / (la[both] * lb[both])
            if float(np.sum(w * cos) / w.sum()) < 0.5:
                return f"its bones point other ways than {whose} in the rest pose (another up axis?)"
        return None

    def to_dict(self) -> dict:
        """Plain JSON-ready description (inverse: :meth:`from_dict`)."""
        return {
            "names": list(self.names),
            "parents": self.parents.tolist(),
            "offsets": self.offsets.tolist(),
            "channels": [list(c) for c in self.channels],
            "end_sites": [[j, np.asarray(o).tolist()] for j, o in self.end_sites],
            "euler_style": self.euler_style,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Skeleton":
        return cls(tuple(d["names"]), np.asarray(d["parents"]), np.asarray(d["offsets"]),
                   tuple(tuple(c) for c in d["channels"]),
                   tuple((int(j), np.asarray(o, dtype=float)) for j, o in d.get("end_sites", [])),
                   d.get("euler_style", "wrapped"))


def chain_world(chain, rots: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Global rotation and position (..., 4), (..., 3) of the last joint of ``chain`` (joint
    indices, top first, the top without a parent) from local ``rots (..., J, 4)`` and
    ``positions (..., J, 3)``."""
    q, p = rots[..., chain[0], :], positions[..., chain[0], :]
    for c in chain[1:]:
        p = p + quat.mul_vec(q, positions[..., c, :])
        q = quat.mul(q, rots[..., c, :])
    return q, p


def fk(parents: np.ndarray, rotations: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics for all frames at once.

    Parameters
    ----------
    parents : ndarray, shape (J,), parents before children, -1 for roots
    rotations : ndarray, shape (..., J, 4), local rotations (w, x, y, z)
    positions : ndarray, shape (..., J, 3), local translations (offsets or channel values)

    Returns
    -------
    global_rotations : ndarray, shape (..., J, 4)
    global_positions : ndarray, shape (..., J, 3)
    """
    grot = np.empty(rotations.shape)
    gpos = np.empty(positions.shape)
    for j, p in enumerate(parents):
        if p < 0:
            grot[..., j, :] = rotations[..., j, :]
            gpos[..., j, :] = positions[..., j, :]
        else:
            grot[..., j, :] = quat.mul(grot[..., p, :], rotations[..., j, :])
            gpos[..., j, :] = gpos[..., p, :] + quat.mul_vec(grot[..., p, :], positions[..., j, :])
    return grot, gpos
