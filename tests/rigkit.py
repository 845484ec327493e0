"""Rigs built from real clips for the tests: the same world poses under another chain of joints
above the root (a reference node turned and moved, a conversion node on top)."""

from __future__ import annotations

import numpy as np

from posturemap.core import quat
from posturemap.core.motion import Motion
from posturemap.core.skeleton import Skeleton


def under_node(m: Motion, q0, p0) -> Motion:
    """The clip with its joint_Root held at rotation ``q0`` and translation ``p0`` (a reference
    node, or a file's conversion node) and Hips carrying the motion: every joint from Hips down
    where it was."""
    rots, pos = m.rotations.copy(), m.positions.copy()
    gq, gp = quat.mul(rots[:, 0], rots[:, 1]), pos[:, 0] + quat.mul_vec(rots[:, 0], pos[:, 1])
    rots[:, 0], pos[:, 0] = q0, p0
    inv = quat.inv(rots[:, 0])
    rots[:, 1], pos[:, 1] = quat.mul(inv, gq), quat.mul_vec(inv, gp - pos[:, 0])
    return Motion(m.skeleton, rots, pos, m.fps)


def topped(m: Motion, q0, p0) -> Motion:
    """The clip under a new fixed top joint ``Top`` at rotation ``q0``, translation ``p0`` (a
    file's conversion node above its root bone): every other joint where it was."""
    sk = m.skeleton
    parents = np.concatenate([[-1], np.where(sk.parents >= 0, sk.parents + 1, 0)])
    top = Skeleton(("Top",) + tuple(sk.names), parents, np.concatenate([np.zeros((1, 3)), sk.offsets]),
                   (sk.channels[0],) + tuple(sk.channels), tuple((j + 1, o) for j, o in sk.end_sites), sk.euler_style)
    q = np.broadcast_to(q0, (len(m), 4))
    rots = np.concatenate([q[:, None], m.rotations], axis=1)
    pos = np.concatenate([np.broadcast_to(p0, (len(m), 3))[:, None], m.positions], axis=1)
    rots[:, 1], pos[:, 1] = quat.mul(quat.inv(q), m.rotations[:, 0]), quat.mul_vec(quat.inv(q), m.positions[:, 0] - p0)
    return Motion(top, rots, pos, m.fps)


def bare(m: Motion, unalike: bool = False) -> Motion:
    """The clip with joints named ``J00``, ``J01``...: no leg found by name, the hierarchy's
    (:func:`posturemap.core.joints.structural_legs`). ``unalike``: the left shin and foot bones
    also 1.6 times as long, so that the two legs are not alike and none is found at all."""
    sk = m.skeleton
    offsets, pos = sk.offsets.copy(), m.positions.copy()
    if unalike:
        for name in ("LowerLeg_L", "Foot_L"):
            j = sk.names.index(name)
            offsets[j] *= 1.6
            pos[:, j] *= 1.6
    renamed = Skeleton(tuple(f"J{j:02d}" for j in range(sk.num_joints)), sk.parents, offsets, sk.channels,
                       sk.end_sites, sk.euler_style)
    return Motion(renamed, m.rotations, pos, m.fps)
