"""Batch rotation math on numpy arrays.

Glossary (the one convention of the project):

- A quaternion is an array of shape ``(..., 4)`` ordered ``(w, x, y, z)``; unit length
  unless a function says otherwise. Leading axes are batch axes and broadcast.
- Angles are radians. Euler orders are strings of three axis letters such as ``"ZXY"``
  and mean *intrinsic* rotations as in BVH: ``from_euler(a, "ZXY")`` is
  ``Rz(a[..., 0]) * Rx(a[..., 1]) * Ry(a[..., 2])`` acting on column vectors.
- A rotation vector (``log`` / ``exp``) is ``axis * angle``, shape ``(..., 3)``.
- Matrices are ``(..., 3, 3)`` acting on column vectors.

Functions never modify their inputs.
"""

from __future__ import annotations

import numpy as np

_AXIS = {"X": 0, "Y": 1, "Z": 2}
EULER_ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX",
                "XYX", "XZX", "YXY", "YZY", "ZXZ", "ZYZ")


def identity(shape=()) -> np.ndarray:
    """Identity quaternions of the given batch ``shape``, result shape ``shape + (4,)``."""
    q = np.zeros(tuple(np.atleast_1d(shape)) + (4,) if shape != () else (4,))
    q[..., 0] = 1.0
    return q


def normalize(q: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Unit quaternions ``q / |q|``; shape ``(..., 4)``."""
    return q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), eps)


def inv(q: np.ndarray) -> np.ndarray:
    """Inverse (conjugate) of unit quaternions ``(..., 4)``."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``); shapes broadcast."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def mul_vec(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``."""
    # v + 2w (u x v) + 2 u x (u x v), written out: np.cross is slow on small arrays.
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return np.stack([vx + w * tx + (y * tz - z * ty),
                     vy + w * ty + (z * tx - x * tz),
                     vz + w * tz + (x * ty - y * tx)], axis=-1)


def from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Quaternions from unit ``axis (..., 3)`` and ``angle (...)`` in radians."""
    half = 0.5 * np.asarray(angle, dtype=float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def _axis_quat(axis: int, angle: np.ndarray) -> np.ndarray:
    half = 0.5 * angle
    q = np.zeros(angle.shape + (4,))
    q[..., 0] = np.cos(half)
    q[..., 1 + axis] = np.sin(half)
    return q


def from_euler(angles: np.ndarray, order: str) -> np.ndarray:
    """Quaternions from intrinsic Euler ``angles (..., 3)`` (radians) in ``order``.

    ``angles[..., i]`` is the angle about axis ``order[i]``; ``order`` is one of
    :data:`EULER_ORDERS`.
    """
    angles = np.asarray(angles, dtype=float)
    q = _axis_quat(_AXIS[order[0]], angles[..., 0])
    q = mul(q, _axis_quat(_AXIS[order[1]], angles[..., 1]))
    return mul(q, _axis_quat(_AXIS[order[2]], angles[..., 2]))


def to_euler(q: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles ``(..., 3)`` in radians of unit quaternions ``q (..., 4)``.

    Inverse of :func:`from_euler`. The middle angle lies in ``[-pi/2, pi/2]`` for
    Tait-Bryan orders and ``[0, pi]`` for proper Euler orders; the others in
    ``(-pi, pi]``. At gimbal lock the third angle is set to zero.
    Direct method of Bernardes and Viollet (2022).
    """
    q = np.asarray(q, dtype=float)
    # Intrinsic order "ABC" equals extrinsic "CBA": work extrinsic on the reversed order.
    i, j, k = (_AXIS[c] for c in order[::-1])
    symmetric = i == k
    if symmetric:
        k = 3 - i - j
    sign = (i - j) * (j - k) * (k - i) // 2
    w, v = q[..., 0], q[..., 1:]
    if symmetric:
        a, b, c, d = w, v[..., i], v[..., j], v[..., k] * sign
    else:
        a, b = w - v[..., j], v[..., i] + v[..., k] * sign
        c, d = v[..., j] + w, v[..., k] * sign - v[..., i]
    theta2 = 2.0 * np.arctan2(np.hypot(c, d), np.hypot(a, b))
    half_sum = np.arctan2(b, a)
    half_diff = np.arctan2(d, c)
    eps = 1e-7
    lock0 = np.abs(theta2) <= eps
    lock_pi = np.abs(theta2 - np.pi) <= eps
    # At gimbal lock only a sum (or difference) of the outer angles is known: the intrinsic
    # third angle (theta1 of the extrinsic form) is set to zero, as scipy does.
    theta1 = np.where(lock0 | lock_pi, 0.0, half_sum - half_diff)
    theta3 = np.where(lock0, 2.0 * half_sum, np.where(lock_pi, 2.0 * half_diff, half_sum + half_diff))
    if not symmetric:
        theta3 = theta3 * sign
        theta2 = theta2 - np.pi / 2
    out = np.stack([theta3, theta2, theta1], axis=-1)  # back to intrinsic order
    return np.pi - (np.pi - out) % (2 * np.pi)  # wrapped into (-pi, pi]


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1).reshape(q.shape[:-1] + (3, 3))


def from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` (w >= 0) of rotation matrices ``(..., 3, 3)``.

    Uses the numerically stable branch (largest of w, x, y, z) per element.
    """
    m = np.asarray(m, dtype=float)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    cand = np.stack([
        np.stack([1 + m00 + m11 + m22, m[..., 2, 1] - m[..., 1, 2],
                  m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1),
        np.stack([m[..., 2, 1] - m[..., 1, 2], 1 + m00 - m11 - m22,
                  m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]], -1),
        np.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0],
                  1 - m00 + m11 - m22, m[..., 1, 2] + m[..., 2, 1]], -1),
        np.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0],
                  m[..., 1, 2] + m[..., 2, 1], 1 - m00 - m11 + m22], -1),
    ], axis=-2)
    best = np.argmax(np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22,
                               1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1), axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    q = normalize(q)
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def log(q: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` (axis * angle, angle in [0, pi]) of unit quaternions."""
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    # angle / s -> 2 as s -> 0; the series keeps it exact for tiny rotations.
    scale = np.where(s > 1e-8, angle / np.maximum(s, 1e-300), 2.0 + s * s / 3.0)
    return v * scale[..., None]


def near_turn(v: np.ndarray, near: np.ndarray) -> np.ndarray:
    """Of the rotation vectors that make the same rotation as ``v (..., 3)`` (``v`` plus any
    whole turn about its axis), the one nearest ``near (..., 3)``.

    :func:`log` keeps the angle in [0, pi]; two frames on either side of a half turn from the
    reference get vectors of nearly opposite directions, and their difference (a velocity) is
    nearly a whole turn. Each expressed near its neighbour, they differ by the frames' own step.
    """
    angle = np.linalg.norm(v, axis=-1)
    unit = v / np.maximum(angle, 1e-12)[..., None]
    turns = np.where(angle > 1e-12, np.round((np.sum(unit * near, axis=-1) - angle) / (2.0 * np.pi)), 0.0)
    return v + (2.0 * np.pi * turns)[..., None] * unit  # no axis (under 1e-12): left as it is


def exp(r: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation vectors ``r (..., 3)`` (inverse of :func:`log`)."""
    angle = np.linalg.norm(r, axis=-1)
    half = 0.5 * angle
    # sin(half) / angle -> 1/2 as angle -> 0.
    scale = np.where(angle > 1e-8, np.sin(half) / np.maximum(angle, 1e-300), 0.5 - angle * angle / 48.0)
    return np.concatenate([np.cos(half)[..., None], r * scale[..., None]], axis=-1)


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Component dot product of quaternions, shape ``(...)``."""
    return np.sum(a * b, axis=-1)


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle in radians ``[0, pi]`` from ``a`` to ``b`` (unit quaternions)."""
    return 2.0 * np.arccos(np.clip(np.abs(dot(a, b)), 0.0, 1.0))


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation on the short arc; ``t`` broadcasts against ``(...)``.

    ``a``, ``b`` unit quaternions ``(..., 4)``; ``t`` an array of shape ``(...)``
    (0 gives ``a``, 1 gives ``b``).
    """
    t = np.asarray(t, dtype=float)[..., None]
    d = dot(a, b)[..., None]
    b = np.where(d < 0, -b, b)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-6
    safe = np.where(small, 1.0, sin_theta)
    wa = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(small, t, np.sin(t * theta) / safe)
    return normalize(wa * a + wb * b)


def unroll(q: np.ndarray, axis: int = 0) -> np.ndarray:
    """Flip signs along ``axis`` (time) so consecutive quaternions lie in one hemisphere."""
    q = np.moveaxis(np.asarray(q, dtype=float), axis, 0)
    flips = np.sum(q[1:] * q[:-1], axis=-1) < 0
    sign = np.concatenate([np.ones((1,) + flips.shape[1:]),
                           np.where(np.cumsum(flips, axis=0) % 2 == 1, -1.0, 1.0)], axis=0)
    return np.moveaxis(q * sign[..., None], 0, axis)


def swing_twist(q: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split ``q = swing * twist`` with ``twist`` a rotation about unit ``axis (3,)``.

    Returns ``(swing, twist)``, each ``(..., 4)``. ``twist`` is the rotation about ``axis``
    closest to ``q``; ``swing`` tilts ``axis`` without turning about it.
    """
    proj = q[..., 1:] @ axis
    twist = np.concatenate([q[..., :1], proj[..., None] * axis], axis=-1)
    norm = np.linalg.norm(twist, axis=-1, keepdims=True)
    twist = np.where(norm > 1e-12, twist / np.maximum(norm, 1e-300), identity())
    return mul(q, inv(twist)), twist


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc rotations (..., 4) taking unit vectors ``a`` onto ``b`` (..., 3)."""
    d = np.sum(a * b, axis=-1, keepdims=True)
    q = np.concatenate([1.0 + d, np.cross(a, b)], axis=-1)
    # Opposite vectors: any half turn about an axis perpendicular to a.
    perp = np.where(np.abs(a[..., :1]) < 0.9, np.cross(a, [1.0, 0.0, 0.0]), np.cross(a, [0.0, 1.0, 0.0]))
    q = np.where(d > -1.0 + 1e-12, q, np.concatenate([np.zeros_like(d), perp], axis=-1))
    return normalize(q)


def heading_tilt(q: np.ndarray, up: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split ``q = heading * tilt``, measuring the heading of ``q * rest^-1``.

    ``rest`` (4,) is the joint's upright orientation relative to the world (for Bandai's Hips
    a quarter turn about Z, since its bones run along X): the heading is then the turn about
    ``up`` of the upright body, and a forward bend stays in ``tilt`` instead of leaking into it.
    """
    heading, _ = heading_twist(mul(q, inv(rest)), up)
    return heading, mul(inv(heading), q)


def heading_twist(q: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split ``q = heading * tilt`` with ``heading`` a rotation about ``up``.

    Returns ``(heading, tilt)`` (each ``(..., 4)``); the order matches a character that first
    tilts in its own frame and is then turned about the world's up axis.
    """
    tilt_inv, heading_inv = swing_twist(inv(q), up)
    return inv(heading_inv), inv(tilt_inv)
