"""posturemap.core.quat cross-checked against scipy.spatial.transform.Rotation.

scipy stores quaternions (x, y, z, w); posturemap (w, x, y, z). Uppercase scipy Euler orders
are intrinsic, as in BVH and posturemap.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from posturemap.core import quat

TAIT_BRYAN = [o for o in quat.EULER_ORDERS if o[0] != o[2]]
PROPER = [o for o in quat.EULER_ORDERS if o[0] == o[2]]


# --- helpers ----------------------------------------------------------------------------------

def to_scipy(q: np.ndarray) -> Rotation:
    """posturemap (w, x, y, z) -> scipy Rotation (stored x, y, z, w)."""
    return Rotation.from_quat(np.asarray(q).reshape(-1, 4)[:, [1, 2, 3, 0]])


def from_scipy(r: Rotation) -> np.ndarray:
    """scipy Rotation -> posturemap (w, x, y, z)."""
    return r.as_quat()[..., [3, 0, 1, 2]]


def random_quats(rng, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def assert_same_rotation(a, b, atol=1e-12):
    """Equal as rotations: equal up to the quaternion sign, element by element."""
    a, b = np.asarray(a), np.asarray(b)
    err = np.minimum(np.abs(a - b).max(axis=-1), np.abs(a + b).max(axis=-1))
    assert err.max() <= atol, f"largest difference up to sign {err.max():.3g} > {atol:g}"


def wrap_diff(a, b):
    """a - b wrapped into (-pi, pi]."""
    return np.pi - (np.pi - (a - b)) % (2 * np.pi)


@pytest.fixture
def rng():
    return np.random.default_rng(20240601)


# --- identity, normalize, inv, mul, mul_vec, dot, angle_between, from_axis_angle ------------

def test_identity_shapes_and_value():
    assert quat.identity().shape == (4,)
    assert quat.identity(5).shape == (5, 4)
    assert quat.identity((2, 3)).shape == (2, 3, 4)
    assert np.array_equal(quat.identity((2, 3))[1, 2], [1.0, 0.0, 0.0, 0.0])
    assert np.allclose(to_scipy(quat.identity(3)).as_matrix(), np.eye(3))


def test_normalize(rng):
    q = rng.normal(size=(50, 4)) * rng.uniform(0.1, 10.0, size=(50, 1))
    n = quat.normalize(q)
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-15)
    assert np.allclose(n * np.linalg.norm(q, axis=-1, keepdims=True), q)
    zero = quat.normalize(np.zeros(4))
    assert np.all(np.isfinite(zero))


def test_inv_matches_scipy_and_cancels(rng):
    q = random_quats(rng, 200)
    assert_same_rotation(quat.inv(q), from_scipy(to_scipy(q).inv()))
    assert_same_rotation(quat.mul(q, quat.inv(q)), quat.identity(200))


def test_mul_matches_scipy_composition(rng):
    a, b = random_quats(rng, 300), random_quats(rng, 300)
    # scipy: (ra * rb) applies rb first, then ra, as the Hamilton product a * b.
    assert_same_rotation(quat.mul(a, b), from_scipy(to_scipy(a) * to_scipy(b)))


def test_mul_broadcasts(rng):
    a, b = random_quats(rng, 5)[:, None], random_quats(rng, 3)[None]
    ab = quat.mul(a, b)
    assert ab.shape == (5, 3, 4)
    assert_same_rotation(ab[4, 2], quat.mul(a[4, 0], b[0, 2]))


def test_mul_is_sign_covariant(rng):
    a, b = random_quats(rng, 50), random_quats(rng, 50)
    assert np.allclose(quat.mul(-a, b), -quat.mul(a, b))
    assert np.allclose(quat.mul(-a, -b), quat.mul(a, b))


def test_mul_vec_matches_scipy_apply(rng):
    q = random_quats(rng, 300)
    v = rng.normal(size=(300, 3)) * 50.0
    expected = to_scipy(q).apply(v)
    assert np.allclose(quat.mul_vec(q, v), expected, atol=1e-12)
    assert np.allclose(quat.mul_vec(-q, v), expected, atol=1e-12)  # both signs, one rotation


def test_mul_vec_batched_over_two_axes(rng):
    q = random_quats(rng, 12).reshape(3, 4, 4)
    v = rng.normal(size=(3, 4, 3))
    out = quat.mul_vec(q, v)
    assert out.shape == (3, 4, 3)
    assert np.allclose(out.reshape(-1, 3), to_scipy(q).apply(v.reshape(-1, 3)), atol=1e-12)


def test_dot_and_angle_between_match_scipy(rng):
    a, b = random_quats(rng, 300), random_quats(rng, 300)
    assert np.allclose(quat.dot(a, b), np.einsum("ij,ij->i", a, b))
    expected = (to_scipy(a).inv() * to_scipy(b)).magnitude()
    assert np.allclose(quat.angle_between(a, b), expected, atol=1e-7)  # arccos near 1: ~1e-8
    assert np.allclose(quat.angle_between(a, -b), expected, atol=1e-7)
    assert np.all(quat.angle_between(a, a) < 1e-7)


def test_from_axis_angle_matches_scipy_rotvec(rng):
    axis = rng.normal(size=(200, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = rng.uniform(-2 * np.pi, 2 * np.pi, 200)
    q = quat.from_axis_angle(axis, angle)
    assert_same_rotation(q, from_scipy(Rotation.from_rotvec(axis * angle[:, None])))
    assert np.allclose(np.linalg.norm(q, axis=-1), 1.0)


# --- Euler ------------------------------------------------------------------------------------

@pytest.mark.parametrize("order", quat.EULER_ORDERS)
def test_from_euler_matches_scipy(order, rng):
    angles = rng.uniform(-np.pi, np.pi, size=(500, 3))
    q = quat.from_euler(angles, order)
    assert_same_rotation(q, from_scipy(Rotation.from_euler(order, angles)))
    assert np.allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)


@pytest.mark.parametrize("order", quat.EULER_ORDERS)
def test_from_euler_batched_and_single(order, rng):
    angles = rng.uniform(-np.pi, np.pi, size=(4, 5, 3))
    q = quat.from_euler(angles, order)
    assert q.shape == (4, 5, 4)
    assert np.allclose(q[3, 1], quat.from_euler(angles[3, 1], order))
    assert quat.from_euler(angles[0, 0], order).shape == (4,)


def test_from_euler_order_is_intrinsic():
    # ZXY intrinsic = Rz * Rx * Ry: Ry acts first on column vectors.
    q = quat.from_euler(np.radians([90.0, 90.0, 0.0]), "ZXY")
    # Rx(90) takes +Y to +Z; Rz(90) leaves +Z alone.
    assert np.allclose(quat.mul_vec(q, np.array([0.0, 1.0, 0.0])), [0.0, 0.0, 1.0], atol=1e-15)
    q = quat.from_euler(np.radians([0.0, 90.0, 90.0]), "ZXY")
    # Ry(90) takes +X to -Z; Rx(90) takes -Z to +Y.
    assert np.allclose(quat.mul_vec(q, np.array([1.0, 0.0, 0.0])), [0.0, 1.0, 0.0], atol=1e-15)


@pytest.mark.parametrize("order", quat.EULER_ORDERS)
def test_to_euler_matches_scipy_both_signs(order, rng):
    q = random_quats(rng, 500)
    expected = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler(order)
    for sign in (1.0, -1.0):
        angles = quat.to_euler(sign * q, order)
        assert np.abs(wrap_diff(angles, expected)).max() < 1e-9
        assert_same_rotation(quat.from_euler(angles, order), q)


@pytest.mark.parametrize("order", quat.EULER_ORDERS)
def test_to_euler_ranges(order, rng):
    angles = quat.to_euler(random_quats(rng, 2000), order)
    assert np.all(angles > -np.pi) and np.all(angles <= np.pi)
    if order in TAIT_BRYAN:
        assert np.all(np.abs(angles[:, 1]) <= np.pi / 2 + 1e-12)
    else:
        assert np.all(angles[:, 1] >= -1e-12) and np.all(angles[:, 1] <= np.pi + 1e-12)


@pytest.mark.parametrize("order", quat.EULER_ORDERS)
def test_euler_near_plus_minus_180(order, rng):
    near = np.array([np.pi, -np.pi, np.pi - 1e-9, -np.pi + 1e-9, np.pi - 1e-6])
    angles = rng.uniform(-np.pi, np.pi, size=(len(near) ** 2, 3))
    angles[:, 0] = np.repeat(near, len(near))
    angles[:, 2] = np.tile(near, len(near))
    angles[:, 1] = rng.uniform(-1.2, 1.2, len(angles)) + (0.0 if order in TAIT_BRYAN else 1.6)
    q = quat.from_euler(angles, order)
    assert_same_rotation(q, from_scipy(Rotation.from_euler(order, angles)))
    back = quat.to_euler(q, order)
    assert np.all(back > -np.pi) and np.all(back <= np.pi)
    assert_same_rotation(quat.from_euler(back, order), q)
    # Away from gimbal lock the triple is unique up to 2 pi.
    assert np.abs(wrap_diff(back, angles)).max() < 1e-8


@pytest.mark.parametrize("order", quat.EULER_ORDERS)
def test_euler_gimbal_lock(order, rng):
    locks = [np.pi / 2, -np.pi / 2] if order in TAIT_BRYAN else [0.0, np.pi]
    for middle in locks:
        angles = rng.uniform(-np.pi, np.pi, size=(200, 3))
        angles[:, 1] = middle
        q = quat.from_euler(angles, order)
        assert_same_rotation(q, from_scipy(Rotation.from_euler(order, angles)))
        back = quat.to_euler(q, order)
        assert np.all(np.isfinite(back))
        # The third angle is set to zero, as documented (and as scipy does).
        assert np.abs(back[:, 2]).max() < 1e-12
        assert_same_rotation(quat.from_euler(back, order), q, atol=1e-9)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # scipy warns about gimbal lock
            expected = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler(order)
        assert_same_rotation(quat.from_euler(expected, order), quat.from_euler(back, order), atol=1e-9)


@pytest.mark.parametrize("order", ["ZXY", "ZYZ"])
def test_euler_gimbal_lock_zeroes_third_angle_as_documented(order):
    angles = np.array([[0.3, np.pi / 2 if order == "ZXY" else 0.0, 0.5]])
    back = quat.to_euler(quat.from_euler(angles, order), order)
    assert abs(back[0, 2]) < 1e-12 and np.isclose(back[0, 0], 0.8)


@pytest.mark.parametrize("order", TAIT_BRYAN + PROPER[:1])
def test_euler_just_off_gimbal_lock(order, rng):
    # Within 1e-7 rad of the lock to_euler treats the rotation as locked (like scipy), which
    # costs up to about twice the distance in accuracy; farther off it is exact again.
    middle = np.pi / 2 if order in TAIT_BRYAN else 0.0
    for delta, atol in ((1e-9, 1e-8), (1e-8, 1e-7), (1e-6, 1e-12), (1e-4, 1e-12)):
        angles = rng.uniform(-np.pi, np.pi, size=(200, 3))
        angles[:, 1] = middle - delta if order in TAIT_BRYAN else middle + delta
        q = quat.from_euler(angles, order)
        back = quat.to_euler(q, order)
        err = np.abs(quat.to_matrix(quat.from_euler(back, order)) - quat.to_matrix(q)).max()
        assert err < atol, (delta, err)


# --- matrices ---------------------------------------------------------------------------------

def test_to_matrix_matches_scipy_both_signs(rng):
    q = random_quats(rng, 300)
    expected = to_scipy(q).as_matrix()
    assert np.allclose(quat.to_matrix(q), expected, atol=1e-14)
    assert np.allclose(quat.to_matrix(-q), expected, atol=1e-14)
    assert quat.to_matrix(q.reshape(3, 100, 4)).shape == (3, 100, 3, 3)


def test_from_matrix_matches_scipy(rng):
    q = random_quats(rng, 300)
    m = to_scipy(q).as_matrix()
    back = quat.from_matrix(m)
    assert_same_rotation(back, q)
    assert np.all(back[:, 0] >= 0)
    assert np.allclose(np.linalg.norm(back, axis=-1), 1.0)
    assert np.allclose(quat.to_matrix(back), m, atol=1e-14)


def test_from_matrix_every_branch_and_half_turns(rng):
    axes = rng.normal(size=(40, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    special = np.concatenate([
        np.eye(3) * np.pi,                # half turns about X, Y, Z: w = 0, largest x, y or z
        axes * np.pi,                     # half turns about random axes
        axes * (np.pi - 1e-7),            # nearly half turns
        axes * 1e-9,                      # nearly identity
        np.zeros((1, 3)),                 # identity
    ])
    r = Rotation.from_rotvec(special)
    back = quat.from_matrix(r.as_matrix())
    assert_same_rotation(back, from_scipy(r), atol=1e-12)
    assert np.allclose(quat.to_matrix(back), r.as_matrix(), atol=1e-14)


def test_from_matrix_batched_two_axes(rng):
    q = random_quats(rng, 12).reshape(3, 4, 4)
    back = quat.from_matrix(quat.to_matrix(q))
    assert back.shape == (3, 4, 4)
    assert_same_rotation(back, q)


# --- log / exp --------------------------------------------------------------------------------

def test_log_matches_scipy_rotvec_both_signs(rng):
    q = random_quats(rng, 500)
    expected = to_scipy(q).as_rotvec()
    assert np.allclose(quat.log(q), expected, atol=1e-12)
    assert np.allclose(quat.log(-q), expected, atol=1e-12)
    assert np.all(np.linalg.norm(quat.log(q), axis=-1) <= np.pi + 1e-12)


def test_exp_matches_scipy_from_rotvec(rng):
    r = rng.normal(size=(500, 3))
    assert_same_rotation(quat.exp(r), from_scipy(Rotation.from_rotvec(r)))
    assert np.allclose(np.linalg.norm(quat.exp(r), axis=-1), 1.0)


@pytest.mark.parametrize("angle", [0.0, 1e-300, 1e-15, 1e-12, 1e-9, 1e-8, 1.0000001e-8, 1e-7, 1e-4, 1.0])
def test_log_exp_round_trip_small_angles(angle, rng):
    axis = rng.normal(size=(50, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    r = axis * angle
    q = quat.exp(r)
    assert np.allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)
    back = quat.log(q)
    assert np.all(np.isfinite(back))
    assert np.allclose(back, r, rtol=1e-9, atol=1e-300)
    assert np.allclose(quat.log(-q), r, rtol=1e-9, atol=1e-300)


@pytest.mark.parametrize("delta", [0.0, 1e-12, 1e-8, 1e-4])
def test_log_exp_round_trip_near_pi(delta, rng):
    axis = rng.normal(size=(50, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    r = axis * (np.pi - delta)
    q = quat.exp(r)
    back = quat.log(q)
    assert_same_rotation(quat.exp(back), q)
    assert np.allclose(np.linalg.norm(back, axis=-1), np.pi - delta, atol=1e-12)
    if delta > 0:  # unique below pi; at pi, r and -r are the same rotation
        assert np.allclose(back, r, atol=1e-10)
        assert np.allclose(quat.log(-q), r, atol=1e-10)


def test_exp_log_round_trip_batched(rng):
    q = random_quats(rng, 24).reshape(2, 3, 4, 4)
    assert_same_rotation(quat.exp(quat.log(q)), q)
    assert quat.log(q).shape == (2, 3, 4, 3)


# --- slerp ------------------------------------------------------------------------------------

def test_slerp_endpoints(rng):
    a, b = random_quats(rng, 100), random_quats(rng, 100)
    assert_same_rotation(quat.slerp(a, b, np.zeros(100)), a)
    assert_same_rotation(quat.slerp(a, b, np.ones(100)), b)
    assert np.allclose(quat.slerp(a, b, 0.0), a, atol=1e-12)  # t = 0 keeps a's sign


def test_slerp_midpoint_matches_scipy_short_arc(rng):
    a, b = random_quats(rng, 100), random_quats(rng, 100)
    b[:50] *= -1  # half the pairs on opposite hemispheres: slerp must take the short arc
    mid = quat.slerp(a, b, 0.5)
    for i in range(100):
        key = Rotation.from_quat(np.stack([a[i], b[i]])[:, [1, 2, 3, 0]])
        expected = from_scipy(Slerp([0.0, 1.0], key)([0.5]))[0]
        assert_same_rotation(mid[i], expected, atol=1e-12)
    half = quat.angle_between(a, b) / 2
    assert np.allclose(quat.angle_between(a, mid), half, atol=1e-7)
    assert np.allclose(quat.angle_between(mid, b), half, atol=1e-7)


def test_slerp_constant_speed(rng):
    a, b = random_quats(rng, 1)[0], random_quats(rng, 1)[0]
    t = np.linspace(0.0, 1.0, 11)
    path = quat.slerp(np.broadcast_to(a, (11, 4)), np.broadcast_to(b, (11, 4)), t)
    assert np.allclose(quat.angle_between(a[None], path), t * quat.angle_between(a, b), atol=1e-7)


def test_slerp_batched_over_two_leading_axes(rng):
    a = random_quats(rng, 20).reshape(4, 5, 4)
    b = random_quats(rng, 20).reshape(4, 5, 4)
    t = rng.uniform(0, 1, size=(4, 5))
    out = quat.slerp(a, b, t)
    assert out.shape == (4, 5, 4)
    for i in range(4):
        for j in range(5):
            key = Rotation.from_quat(np.stack([a[i, j], b[i, j]])[:, [1, 2, 3, 0]])
            expected = from_scipy(Slerp([0.0, 1.0], key)([t[i, j]]))[0]
            assert_same_rotation(out[i, j], expected, atol=1e-12)
    # a scalar t broadcasts too
    assert_same_rotation(quat.slerp(a, b, 0.25)[2, 3], quat.slerp(a[2, 3], b[2, 3], 0.25))


def test_slerp_nearly_equal_inputs_stay_finite(rng):
    a = random_quats(rng, 10)
    b = quat.normalize(a + 1e-9 * rng.normal(size=a.shape))
    out = quat.slerp(a, b, 0.3)
    assert np.all(np.isfinite(out))
    assert np.allclose(np.linalg.norm(out, axis=-1), 1.0)
    assert_same_rotation(quat.slerp(a, a, 0.7), a)
    assert_same_rotation(quat.slerp(a, -a, 0.7), a)


def test_slerp_does_not_mutate_inputs(rng):
    a, b = random_quats(rng, 30), random_quats(rng, 30)
    b[::2] *= -1  # negative dot products: the branch that flips b internally
    t = rng.uniform(0, 1, 30)
    a0, b0, t0 = a.copy(), b.copy(), t.copy()
    quat.slerp(a, b, t)
    assert np.array_equal(a, a0) and np.array_equal(b, b0) and np.array_equal(t, t0)


# --- unroll -----------------------------------------------------------------------------------

@pytest.mark.parametrize("axis", [0, 1])
def test_unroll(axis, rng):
    # A smooth path with random sign flips, two sequences side by side along the other axis.
    steps = np.cumsum(rng.normal(scale=0.2, size=(60, 2, 3)), axis=0)
    q = quat.exp(steps)
    flipped = q * np.where(rng.uniform(size=(60, 2, 1)) < 0.5, -1.0, 1.0)
    if axis == 1:
        flipped = np.swapaxes(flipped, 0, 1)
    before = flipped.copy()
    out = quat.unroll(flipped, axis=axis)
    assert np.array_equal(flipped, before)  # input untouched
    assert out.shape == flipped.shape
    seq = np.moveaxis(out, axis, 0)
    assert np.all(np.sum(seq[1:] * seq[:-1], axis=-1) >= 0)
    assert np.allclose(np.abs(np.sum(out * flipped, axis=-1)), 1.0)  # same rotations
    assert np.array_equal(np.moveaxis(out, axis, 0)[0], np.moveaxis(flipped, axis, 0)[0])
    assert np.sum(np.sum(np.moveaxis(flipped, axis, 0)[1:] * np.moveaxis(flipped, axis, 0)[:-1], -1) < 0) > 0


# --- swing / twist, heading / tilt ------------------------------------------------------------

@pytest.mark.parametrize("axis", [np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                                  np.array([2.0, -1.0, 0.5]) / np.linalg.norm([2.0, -1.0, 0.5])])
def test_swing_twist(axis, rng):
    q = random_quats(rng, 300)
    q0 = q.copy()
    swing, twist = quat.swing_twist(q, axis)
    assert np.array_equal(q, q0)
    assert_same_rotation(quat.mul(swing, twist), q)
    # twist turns about `axis` only: its vector part is parallel to the axis
    assert np.allclose(np.cross(twist[:, 1:], axis), 0.0, atol=1e-12)
    # swing does not turn about `axis`: its vector part is perpendicular to the axis
    assert np.allclose(swing[:, 1:] @ axis, 0.0, atol=1e-12)
    assert np.allclose(np.linalg.norm(swing, axis=-1), 1.0)
    assert np.allclose(np.linalg.norm(twist, axis=-1), 1.0)


def test_swing_twist_recovers_known_parts(rng):
    axis = np.array([0.0, 0.0, 1.0])
    angle = rng.uniform(-3.0, 3.0, 100)
    twist = quat.from_axis_angle(axis, angle)
    tilt_axis = np.stack([np.cos(angle * 2), np.sin(angle * 2), np.zeros(100)], -1)
    swing = quat.from_axis_angle(tilt_axis, rng.uniform(-1.5, 1.5, 100))
    s, t = quat.swing_twist(quat.mul(swing, twist), axis)
    assert_same_rotation(t, twist)
    assert_same_rotation(s, swing)


def test_swing_twist_degenerate_half_turn_perpendicular():
    # A half turn about an axis perpendicular to the twist axis has no twist at all.
    q = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.pi)
    swing, twist = quat.swing_twist(q, np.array([0.0, 1.0, 0.0]))
    assert np.all(np.isfinite(swing)) and np.all(np.isfinite(twist))
    assert_same_rotation(twist, quat.identity())
    assert_same_rotation(quat.mul(swing, twist), q)


@pytest.mark.parametrize("up", [1, 2])
def test_heading_twist(up, rng):
    up_v = np.eye(3)[up]
    q = random_quats(rng, 300)
    heading, tilt = quat.heading_twist(q, up_v)
    assert_same_rotation(quat.mul(heading, tilt), q)
    # heading is a pure turn about up: no tilt, it keeps the up axis where it is
    assert np.allclose(np.cross(heading[:, 1:], up_v), 0.0, atol=1e-12)
    assert np.allclose(quat.mul_vec(heading, np.broadcast_to(up_v, (300, 3))), up_v, atol=1e-12)
    # tilt has no turn about up
    assert np.allclose(tilt[:, 1:] @ up_v, 0.0, atol=1e-12)


def test_heading_twist_of_pure_yaw_and_known_parts(rng):
    up = np.array([0.0, 1.0, 0.0])
    yaw = quat.from_axis_angle(up, rng.uniform(-3.1, 3.1, 50))
    heading, tilt = quat.heading_twist(yaw, up)
    assert_same_rotation(heading, yaw)
    assert_same_rotation(tilt, quat.identity(50))
    # q = heading * tilt with a tilt about a horizontal axis: both parts come back
    tilt_true = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), rng.uniform(-1.0, 1.0, 50))
    h, t = quat.heading_twist(quat.mul(yaw, tilt_true), up)
    assert_same_rotation(h, yaw)
    assert_same_rotation(t, tilt_true)


# --- purity -----------------------------------------------------------------------------------

def test_functions_do_not_mutate_inputs(rng):
    q = random_quats(rng, 20)
    q[::3] *= -1
    p = random_quats(rng, 20)
    v = rng.normal(size=(20, 3))
    m = quat.to_matrix(random_quats(rng, 20))
    axis = np.array([0.0, 1.0, 0.0])
    calls = [
        (quat.normalize, (q * 3.0,)), (quat.inv, (q,)), (quat.mul, (q, p)), (quat.mul_vec, (q, v)),
        (quat.from_axis_angle, (v / np.linalg.norm(v, axis=-1, keepdims=True), v[:, 0])),
        (quat.from_euler, (v, "ZXY")), (quat.to_euler, (q, "YXZ")), (quat.to_matrix, (q,)),
        (quat.from_matrix, (m,)), (quat.log, (q,)), (quat.exp, (v,)), (quat.dot, (q, p)),
        (quat.angle_between, (q, p)), (quat.slerp, (q, p, v[:, 0] % 1.0)), (quat.unroll, (q,)),
        (quat.swing_twist, (q, axis)), (quat.heading_twist, (q, axis)),
    ]
    for fn, args in calls:
        before = [np.array(a, copy=True) if isinstance(a, np.ndarray) else a for a in args]
        fn(*args)
        for a, b in zip(args, before):
            if isinstance(a, np.ndarray):
                assert np.array_equal(a, b), f"{fn.__name__} modified its input"


def test_between_takes_a_onto_b(rng):
    a = rng.normal(size=(200, 3))
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b = rng.normal(size=(200, 3))
    b /= np.linalg.norm(b, axis=-1, keepdims=True)
    b[0] = -a[0]  # opposite vectors: a half turn
    b[1] = a[1]  # equal vectors: identity
    q = quat.between(a, b)
    np.testing.assert_allclose(quat.mul_vec(q, a), b, atol=1e-12)
    np.testing.assert_allclose(np.abs(q[1, 0]), 1.0, atol=1e-12)


def test_heading_tilt_ignores_a_bend_of_an_upright_body(rng):
    # A root whose rest pose lies along X (as Bandai's Hips): rest turns X onto Y (up).
    up = np.array([0.0, 1.0, 0.0])
    rest = quat.between(np.array([1.0, 0.0, 0.0]), up)
    yaw = quat.from_axis_angle(up, np.float64(0.7))
    for bend in (0.0, 0.4, 1.0):  # bend forward about the body's own right axis
        pose = quat.mul(quat.mul(yaw, quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.float64(bend))), rest)
        heading, tilt = quat.heading_tilt(pose, up, rest)
        assert abs(abs(quat.dot(heading, yaw)) - 1.0) < 1e-12, bend
        assert abs(abs(quat.dot(quat.mul(heading, tilt), pose)) - 1.0) < 1e-12
    # heading_twist on the raw rotation lets the bend leak into the heading: the reason for rest.
    bent = quat.mul(quat.mul(yaw, quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.float64(1.0))), rest)
    assert quat.angle_between(quat.heading_twist(bent, up)[0], yaw) > 0.1
