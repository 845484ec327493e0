"""Posture vectors: the paper's DOF vector, the four bone classes, and the exact inverse.

A posture excludes what a transition must not copy from another clip: the root's horizontal
position and its heading (rotation about the up axis). What stays:

- every joint's local rotation (joints above the root, such as Bandai's fixed
  ``joint_Root``, belong to the trajectory and are left out),
- the root's *tilt* (its global rotation with the heading removed) and its height.

Two modes:

``euler``
    The paper's DOF vector: each rotation as Euler angles in the joint's own channel order,
    bounded to [0, 2*pi); distances and updates are taken on the circle (359 and 1 degrees
    are 2 degrees apart). Gimbal lock and the circle's seam remain, as in the paper.
``logmap`` (default)
    Each rotation as the rotation vector ``log(ref^-1 * q)`` relative to the joint's mean
    rotation over the training data: no seam within 180 degrees of the mean, no gimbal lock,
    and Euclidean distance equals the geodesic angle.

The root height is divided by the leg length, so one unit of height weighs like one radian.
Dimensions that never change in the training data (the paper's redundant DOFs, such as a
joint that never moves) are dropped; the inverse puts their constant value back.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field

import numpy as np

from ..core import quat
from ..core.joints import SHORT_BONE, Limbs, ancestors, subtree_mask
from ..core.skeleton import chain_world
from ..errors import UserError
from ..core.motion import Motion, root_index, shared_up_axis, up_vector

CLASSES = ("body", "global", "medium", "detail")
MODES = ("euler", "logmap")
TWO_PI = 2.0 * np.pi

# Name rules, tried in order; a name is lower-cased and stripped of prefixes such as
# "mixamorig:" and of side markers before matching. Covers Bandai, CMU, LaFAN1 and Mixamo.
_NAME_RULES = [
    ("detail", r"hand|wrist|finger|thumb|index|middle|ring|pinky|little|toe|foot|ankle|heel"),
    ("medium", r"forearm|lowerarm|elbow|lowerleg|shin|calf|knee|neck|head|^leg$|^farm$"),  # OptiTrack's LFArm
    ("global", r"clavicle|collar|shoulder|shldr|upperarm|^arm$|^uarm$|thigh|upleg|upperleg|^hip$"),  # Daz, OptiTrack
    ("body", r"hips|pelvis|root|spine|chest|torso|back|abdomen|waist|hipjoint|^body$"),
]


def _clean(name: str) -> str:
    """Lower-case joint name without namespace, side marker, separators or trailing digits."""
    n = name.split(":")[-1]
    n = re.sub(r"^(joint_|Bip\d*_?|mixamorig_?)", "", n, flags=re.I)
    n = re.sub(r"^(Left|Right|left|right|L|R)(?=[A-Z_])|[_.\s]?(Left|Right|left|right)$|[_.\s][LRlr]$",
               "", n)
    return re.sub(r"\d+$", "", re.sub(r"[_.\s]", "", n.lower()))


def assign_classes(motion_or_skeleton, root: int | None = None) -> np.ndarray:
    """Bone class index (0 body, 1 global, 2 medium, 3 detail) per joint, shape (J,).

    Names decide where they can (see ``_NAME_RULES``); a joint no rule knows is placed from
    the hierarchy: the root and the chain to the joint with the most descendants are body,
    the others global, medium and detail by their distance from the body. A rig none of whose
    names a rule knows (``J00``, ``J01``..., another language) is read by its limbs instead,
    as the names would place them (:func:`_limb_classes`: thigh, shin, foot; upper arm,
    forearm, hand; the neck and head medium). Never fails.
    """
    sk = getattr(motion_or_skeleton, "skeleton", motion_or_skeleton)
    parents = sk.parents
    j_count = sk.num_joints
    root = 0 if root is None else root
    # Hierarchy fallback.
    desc = np.zeros(j_count, dtype=np.int64)
    for j in range(j_count - 1, 0, -1):
        if parents[j] >= 0:
            desc[parents[j]] += desc[j] + 1
    body = np.zeros(j_count, dtype=bool)
    j = root
    while j >= 0:  # the root and its ancestors
        body[j] = True
        j = parents[j]
    children = [[] for _ in range(j_count)]  # one pass: linear time in joints
    for c in range(j_count):
        if parents[c] >= 0:
            children[parents[c]].append(c)
    # Follow the spine: from the root, the child with the most descendants, up to the first
    # joint where three or more chains part (the chest: neck and two arms).
    j = root
    while True:
        kids = children[j]
        if not kids or (j != root and len(kids) >= 3):
            break
        j = max(kids, key=lambda c: desc[c])
        body[j] = True
    fallback = np.zeros(j_count, dtype=np.int64)
    steps = np.zeros(j_count, dtype=np.int64)
    for c in range(j_count):
        if body[c]:
            continue
        p = parents[c]
        steps[c] = 1 if p < 0 or body[p] else steps[p] + 1
        fallback[c] = min(int(steps[c]), 3)
    named = [next((cls for cls, pattern in _NAME_RULES if re.search(pattern, _clean(n))), None) for n in sk.names]
    if not any(named):
        _limb_classes(sk, body, children, fallback)
    out = fallback.copy()
    for c, cls in enumerate(named):
        if cls is not None:
            out[c] = CLASSES.index(cls)
    out[root] = 0
    return out


def _limb_classes(sk, body: np.ndarray, children: list, fallback: np.ndarray) -> None:
    """The classes of a rig none of whose names a rule knows (``J00``, ``J01``..., another
    language), from its limbs (:class:`posturemap.core.joints.Limbs`), in place in ``fallback``:
    two alike chains from one body joint (legs, arms) global down to their upper joint (a
    clavicle above it too; a hip joint at the pelvis's place above a thigh, CMU's ``LHipJoint``,
    body), medium from the middle joint (knee, elbow), detail from the end (ankle, wrist) down,
    as the names place them; another chain from a body joint where limbs leave (the chest's neck
    and head) medium. The chains do not overlap: near-linear in the joints. A rig with some
    names keeps the plain distance rule for the joints no rule knows."""
    limbs = Limbs(sk.parents, sk.offsets)
    thighs = {leg[0] for leg in limbs.legs()}
    end = np.zeros(len(fallback), dtype=bool)
    for p in np.flatnonzero(body).tolist():
        paths = [limbs.path(c) for c in children[p] if not body[c]]
        paired = {i for pair in limbs.pairs(paths) for i in pair}
        for i, path in enumerate(paths):
            if i not in paired:
                if paired:
                    fallback[path] = 2
                continue
            upper, middle, last = limbs.joints3(path)
            at, hip = 1, SHORT_BONE * limbs.reach(path)
            for j in path:
                at = 2 if j == middle else (3 if j == last else at)
                # A hip joint at the pelvis's place above a thigh is the pelvis's (CMU's LHipJoint).
                fallback[j] = 0 if at == 1 and j != upper and upper in thighs and limbs.bone[j] <= hip else at
            end[last] = True
    for c in range(len(fallback)):  # parents come first: below an ankle or a wrist, detail
        p = sk.parents[c]
        if p >= 0 and end[p]:
            end[c] = True
            fallback[c] = 3


def load_class_overrides(path: str, names: tuple[str, ...]) -> dict[str, str]:
    """Read a JSON object ``{"JointName": "body"|"global"|"medium"|"detail", ...}``."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except OSError as e:
        raise UserError(path, f"cannot read class file ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise UserError(path, f"not valid JSON ({e.msg} at line {e.lineno})") from None
    if not isinstance(data, dict):
        raise UserError(path, 'expected a JSON object {"joint": "class", ...}')
    for k, v in data.items():
        if k not in names:
            raise UserError(path, f"unknown joint {k!r}")
        if v not in CLASSES:
            raise UserError(path, f"class of {k!r} must be one of {', '.join(CLASSES)}, got {v!r}")
    return data


@dataclass(frozen=True, eq=False)
class FeatureSpace:
    """How postures become vectors for one skeleton; fitted on training motions.

    The full vector has three entries per joint below the root (the root's tilt first)
    followed by the root height; ``active`` keeps the dimensions that vary.

    Attributes
    ----------
    mode : "euler" or "logmap"
    root : index of the joint that carries the trajectory
    up : up axis index (0, 1, 2)
    height_scale : length that counts as one unit of root height (leg length)
    joints : ndarray (K,), joints whose rotations are features, root first
    orders : tuple of str, Euler order per entry of ``joints`` (euler mode)
    reference : ndarray (K, 4), reference rotations (logmap mode; identity in euler mode)
    joint_class : ndarray (J,), class index per joint
    fill : ndarray (3K + 1,), value of every full dimension (used for dropped ones)
    active : ndarray (3K + 1,), bool, dimensions kept
    rest : ndarray (4,), the root's upright orientation (see :func:`upright_rest`)
    """

    mode: str
    root: int
    up: int
    height_scale: float
    joints: np.ndarray
    orders: tuple[str, ...]
    reference: np.ndarray
    joint_class: np.ndarray
    fill: np.ndarray
    active: np.ndarray
    rest: np.ndarray = field(default_factory=lambda: quat.identity())
    class_dims: tuple = field(init=False)

    def __post_init__(self):
        dim_class = np.concatenate([np.repeat(self.joint_class[self.joints], 3), [0]])
        dims = tuple(np.flatnonzero(self.active & (dim_class == c)) for c in range(len(CLASSES)))
        object.__setattr__(self, "class_dims", dims)

    @property
    def circular(self) -> np.ndarray:
        """Bool per full dimension: an angle measured on the circle (euler mode)."""
        c = np.zeros(self.active.shape, dtype=bool)
        if self.mode == "euler":
            c[:-1] = True
        return c

    # -- encoding -------------------------------------------------------------------------
    def root_frames(self, motion: Motion) -> tuple[np.ndarray, np.ndarray]:
        """Global root rotation (F, 4) and position (F, 3) via the root's ancestors."""
        return root_global(motion, self.root)

    def encode(self, motion: Motion) -> np.ndarray:
        """Full posture vectors, shape (F, 3K + 1)."""
        grot, gpos = self.root_frames(motion)
        _, tilt = quat.heading_tilt(grot, up_vector(self.up), self.rest)
        rots = motion.rotations[:, self.joints].copy()
        rots[:, 0] = tilt
        return self.encode_parts(rots, gpos[:, self.up])

    def encode_parts(self, rots: np.ndarray, height: np.ndarray) -> np.ndarray:
        """Full vectors from rotations (F, K, 4) of ``joints`` (root tilt first) and heights (F,)."""
        if self.mode == "euler":
            ang = np.empty(rots.shape[:-1] + (3,))
            for order in set(self.orders):
                idx = [k for k, o in enumerate(self.orders) if o == order]
                ang[:, idx] = quat.to_euler(rots[:, idx], order)
            rot_part = wrap_angle(ang)
        else:
            rot_part = quat.log(quat.mul(quat.inv(self.reference), rots))
        return np.concatenate([rot_part.reshape(len(rots), -1), (height / self.height_scale)[:, None]], axis=1)

    def split(self, x: np.ndarray) -> list[np.ndarray]:
        """Per-class active parts of full vectors (..., 3K + 1): a list of 4 arrays."""
        return [x[..., d] for d in self.class_dims]

    def merge(self, parts: list[np.ndarray]) -> np.ndarray:
        """Inverse of :meth:`split`: full vectors with dropped dimensions at their constant."""
        lead = parts[0].shape[:-1]
        x = np.broadcast_to(self.fill, lead + self.fill.shape).copy()
        for d, p in zip(self.class_dims, parts):
            x[..., d] = p
        return x

    def decode(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (F, K, 4) of ``joints`` (root tilt first) and root heights (F,)."""
        k = len(self.joints)
        rot_part = x[..., : 3 * k].reshape(x.shape[:-1] + (k, 3))
        if self.mode == "euler":
            rots = np.empty(rot_part.shape[:-1] + (4,))
            for order in set(self.orders):
                idx = [i for i, o in enumerate(self.orders) if o == order]
                rots[..., idx, :] = quat.from_euler(rot_part[..., idx, :], order)
        else:
            rots = quat.mul(self.reference, quat.exp(rot_part))
        return rots, x[..., -1] * self.height_scale

    # -- metadata -------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "mode": self.mode, "root": self.root, "up": self.up, "height_scale": self.height_scale,
            "joints": self.joints.tolist(), "orders": list(self.orders),
            "joint_class": self.joint_class.tolist(),
        }

    def arrays(self) -> dict[str, np.ndarray]:
        return {"reference": self.reference, "fill": self.fill, "active": self.active, "rest": self.rest}

    @classmethod
    def from_parts(cls, meta: dict, arrays: dict) -> "FeatureSpace":
        return cls(meta["mode"], int(meta["root"]), int(meta["up"]), float(meta["height_scale"]),
                   np.asarray(meta["joints"], dtype=np.int64), tuple(meta["orders"]),
                   np.asarray(arrays["reference"], dtype=float), np.asarray(meta["joint_class"], dtype=np.int64),
                   np.asarray(arrays["fill"], dtype=float), np.asarray(arrays["active"], dtype=bool),
                   np.asarray(arrays.get("rest", quat.identity()), dtype=float).reshape(4))


def root_global(motion: Motion, root: int) -> tuple[np.ndarray, np.ndarray]:
    """Global rotation (F, 4) and position (F, 3) of joint ``root`` through its ancestors."""
    rot, pos = chain_world(ancestors(motion.skeleton.parents, root) + [root], motion.rotations, motion.positions)
    return rot.copy(), pos.copy()


def upright_rest(grot: np.ndarray, up: int) -> np.ndarray:
    """The root's upright orientation (4,) from its global rotations (F, 4).

    The root's own axis that points up on average, ``u = mean(grot^-1 up)``, and the
    shortest turn taking ``u`` onto the world's up axis: for Bandai's Hips (bones along X) a
    quarter turn about Z, for a Y-up Hips the identity. Headings are measured on
    ``grot * rest^-1`` (see :func:`posturemap.core.quat.heading_tilt`).
    """
    upv = up_vector(up)
    u = quat.mul_vec(quat.inv(grot), np.broadcast_to(upv, grot.shape[:-1] + (3,))).mean(axis=0)
    norm = np.linalg.norm(u)
    if norm < 1e-9:
        return quat.identity()
    return quat.between(u / norm, upv)


def leg_length(motion: Motion, root: int, up: int) -> float:
    """Height of the root above the lowest joint in the first frame (a leg length)."""
    gpos = motion[0].global_positions()[0]
    h = gpos[root, up] - gpos[:, up].min()
    return float(h) if h > 1e-9 else 1.0


def fit_space(motions: list[Motion], mode: str = "logmap", classes: dict[str, str] | None = None,
              tol: float = 1e-6) -> FeatureSpace:
    """Fit a :class:`FeatureSpace` to training motions (all with one skeleton).

    ``classes`` overrides the automatic bone classes for the joints it names.
    """
    if mode not in MODES:
        raise UserError("--features", f"unknown feature mode {mode!r} (choose from {', '.join(MODES)})")
    first = motions[0]
    sk = first.skeleton
    root = root_index(first)
    up = shared_up_axis(motions)[0]
    jc = assign_classes(sk, root)
    for name, cls in (classes or {}).items():
        jc[sk.index(name)] = CLASSES.index(cls)
    below = np.flatnonzero(subtree_mask(sk.parents, root))
    joints = np.array([root] + [j for j in below if j != root], dtype=np.int64)
    orders = tuple(sk.rotation_order(int(j)) or "ZXY" for j in joints)
    k = len(joints)
    rest = upright_rest(np.concatenate([root_global(m, root)[0] for m in motions]), up)
    provisional = FeatureSpace(mode, root, up, leg_length(first, root, up), joints, orders,
                               quat.identity((k,)), jc, np.zeros(3 * k + 1), np.ones(3 * k + 1, bool), rest)
    if mode == "logmap":
        rots = np.concatenate([_feature_rotations(provisional, m) for m in motions])
        provisional = FeatureSpace(mode, root, up, provisional.height_scale, joints, orders,
                                   mean_rotation(rots), jc, provisional.fill, provisional.active, rest)
    x = np.concatenate([provisional.encode(m) for m in motions])
    circ = provisional.circular
    spread = np.where(circ, circular_range(x), np.ptp(x, axis=0))
    active = spread > tol
    active[-1] = True  # the root height always counts
    fill = np.where(circ, circular_mean(x), x.mean(axis=0))
    return FeatureSpace(mode, root, up, provisional.height_scale, joints, orders,
                        provisional.reference, jc, fill, active, rest)


def _feature_rotations(space: FeatureSpace, motion: Motion) -> np.ndarray:
    grot, _ = space.root_frames(motion)
    _, tilt = quat.heading_tilt(grot, up_vector(space.up), space.rest)
    rots = motion.rotations[:, space.joints].copy()
    rots[:, 0] = tilt
    return rots


def mean_rotation(q: np.ndarray) -> np.ndarray:
    """Mean of unit quaternions (N, K, 4) per K: principal eigenvector (Markley et al. 2007)."""
    m = np.einsum("nki,nkj->kij", q, q)
    _, vecs = np.linalg.eigh(m)
    mean = vecs[..., -1]
    return mean * np.where(mean[..., :1] < 0, -1.0, 1.0)


def wrap_angle(x: np.ndarray) -> np.ndarray:
    """Angles in [0, 2*pi). (np.mod alone returns 2*pi for tiny negative angles.)"""
    m = np.mod(x, TWO_PI)
    return np.where(m >= TWO_PI, 0.0, m)


def circular_mean(x: np.ndarray) -> np.ndarray:
    """Mean angle in [0, 2*pi) over axis 0."""
    return wrap_angle(np.arctan2(np.sin(x).mean(0), np.cos(x).mean(0)))


def circular_range(x: np.ndarray) -> np.ndarray:
    """Largest deviation from the circular mean over axis 0 (radians, 0 for a constant)."""
    d = np.mod(x - circular_mean(x) + np.pi, TWO_PI) - np.pi
    return np.abs(d).max(axis=0)


def wrap_diff(a: np.ndarray, b: np.ndarray, circular: np.ndarray) -> np.ndarray:
    """``a - b`` with circular dimensions wrapped into [-pi, pi)."""
    d = a - b
    return np.where(circular, np.mod(d + np.pi, TWO_PI) - np.pi, d)
