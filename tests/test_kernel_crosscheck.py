"""Every numba kernel against a plain numpy (or Python) reference, on seeded random input.

One test per compiled function (helpers included: a wrong ``_mul`` would hide in every kernel
that uses it), each comparing the compiled result with a reference written here or taken from
:mod:`posturemap.core.quat`, :mod:`posturemap.core.skeleton`, scipy or the numpy path of the
same module. Each test is registered with :func:`crosschecks`; ``test_every_kernel_is_crosschecked``
lists the compiled functions of the kernel modules (and of any other module that mentions
``njit``) and fails when one has no registered cross-check, so a new kernel cannot slip through.
"""

from __future__ import annotations

import importlib
import itertools
import re
import types
from pathlib import Path

import numba
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from posturemap.core import kernels, quat
from posturemap.core.skeleton import fk as fk_reference
from posturemap.io import bvh
from posturemap.synth import retrieval
from posturemap.synth.bases import hermite_basis

NK = kernels.compiled()  # posturemap.core.numba_kernels
from posturemap.synth import retrieval_numba as RN  # noqa: E402 - needs numba loaded first

BVH_KERNELS = bvh._fast_kernels()  # the BVH reader's two kernels, compiled once numba is in use
SRC = Path(__file__).resolve().parent.parent / "src" / "posturemap"

CHECKED: set[str] = set()  # "module:function" names with a cross-check below


def crosschecks(*names):
    """Register the decorated test as the cross-check of the compiled functions ``names``."""
    CHECKED.update(names)
    return lambda test: test


def random_quats(rng, shape) -> np.ndarray:
    """Unit quaternions (shape..., 4) with random signs (both hemispheres)."""
    q = quat.normalize(rng.normal(size=tuple(shape) + (4,)))
    return q * np.where(rng.random(tuple(shape) + (1,)) < 0.5, -1.0, 1.0)


def same_rotation(a, b, atol=1e-12):
    """Quaternions equal up to sign (q and -q are one rotation)."""
    d = np.abs(np.sum(np.asarray(a) * np.asarray(b), axis=-1))
    np.testing.assert_allclose(d, 1.0, atol=atol)


def wrapped(d, period):
    """Differences wrapped into [-p/2, p/2) where ``period`` is finite."""
    p = np.where(np.isfinite(period), period, 1.0)
    return np.where(np.isfinite(period), d - p * np.floor(d / p + 0.5), d)


def periodic_sqdist(x, W, period):
    """Squared distances (n,) from ``x (d,)`` to the rows of ``W (n, d)``: per dimension
    min(|d|, p - |d|) where the period p is finite."""
    d = np.abs(W - x)
    d = np.where(np.isfinite(period), np.minimum(d, period - d), d)
    return (d * d).sum(-1)


def mixed_data(rng, n, d, circular_fraction=0.5, scale=1.0):
    """Rows (n, d) and a period (d,): 2 pi on about ``circular_fraction`` of the dims, else inf."""
    period = np.where(rng.random(d) < circular_fraction, 2 * np.pi, np.inf)
    rows = np.where(np.isinf(period), rng.normal(scale=scale, size=(n, d)), rng.uniform(0, 2 * np.pi, (n, d)))
    return rows, period


# -- quaternion helpers ---------------------------------------------------------------------
@crosschecks("numba_kernels:_mul", "numba_kernels:_rotate")
def test_mul_and_rotate_match_quat():
    rng = np.random.default_rng(101)
    a, b = random_quats(rng, (50,)), random_quats(rng, (50,))
    a[0] *= 3.0  # not unit: the product is still bilinear
    v = rng.normal(scale=20.0, size=(50, 3))
    for i in range(50):
        np.testing.assert_allclose(NK._mul(*a[i], *b[i]), quat.mul(a[i], b[i]), atol=1e-15, rtol=1e-14)
        if i:
            np.testing.assert_allclose(NK._rotate(*a[i], *v[i]), quat.mul_vec(a[i], v[i]), atol=1e-12)
            np.testing.assert_allclose(NK._rotate(*a[i], *v[i]), Rotation.from_quat(np.roll(a[i], -1)).apply(v[i]),
                                       atol=1e-12)


@crosschecks("retrieval_numba:_log_rel", "retrieval_numba:_row")
def test_log_rel_is_the_short_arc_log_of_p_times_q_inverse():
    rng = np.random.default_rng(102)
    p, q = random_quats(rng, (60,)), random_quats(rng, (60,))
    q[0] = p[0]  # zero
    q[1] = quat.mul(quat.exp(np.array([1e-10, -2e-10, 0.0])), p[1])  # the series branch
    q[2] = -p[2]  # same rotation, other sign
    for i in range(60):
        assert RN._row(p[i]) == tuple(p[i])
        got = np.array(RN._log_rel(RN._row(p[i]), RN._row(q[i])))
        rel = quat.mul(p[i], quat.inv(q[i]))
        rel = rel if rel[0] >= 0 else -rel
        np.testing.assert_allclose(got, Rotation.from_quat(np.roll(rel, -1)).as_rotvec(), atol=1e-12)
        assert np.linalg.norm(got) <= np.pi + 1e-12
    assert np.abs(RN._log_rel(RN._row(p[2]), RN._row(q[2]))).max() < 1e-12


@crosschecks("retrieval_numba:_sample")
def test_sample_is_the_sign_aligned_lerp():
    rng = np.random.default_rng(103)
    rots = random_quats(rng, (30, 4)).astype(np.float32)  # the library stores float32
    for _ in range(40):
        i0, i1, j = int(rng.integers(30)), int(rng.integers(30)), int(rng.integers(4))
        f = float(rng.random())
        a, b = rots[i0, j].astype(np.float64), rots[i1, j].astype(np.float64)
        b = -b if a @ b < 0 else b
        ref = a + f * (b - a)  # not normalised: the mean of the segments' samples normalises
        # 1e-7: numba's float() of a float32 stays float32, so b - a is rounded to float32
        # (the numpy path subtracts in float64); float32 rows carry no more than that anyway.
        np.testing.assert_allclose(RN._sample(rots, i0, i1, f, j), ref, atol=1e-7)


# -- per-transition kernels -----------------------------------------------------------------
@crosschecks("numba_kernels:log_relative", "numba_kernels:exp_relative")
def test_log_relative_and_exp_relative_match_scipy():
    rng = np.random.default_rng(104)
    n, j = 30, 6
    ref, q = random_quats(rng, (j,)), random_quats(rng, (n, j))
    q[0] = quat.mul(ref, quat.exp(rng.normal(size=(j, 3)) * 1e-10))  # the series branch
    q[1] = -ref  # zero rotation on the other sign
    out = np.empty((n, j, 3))
    NK.log_relative(q, ref, out)
    rel = quat.mul(quat.inv(ref), q)
    rel = np.where(rel[..., :1] < 0, -rel, rel)
    expected = Rotation.from_quat(np.roll(rel, -1, axis=-1).reshape(-1, 4)).as_rotvec().reshape(n, j, 3)
    np.testing.assert_allclose(out, expected, atol=1e-12)
    assert np.abs(out[1]).max() < 1e-12

    r = rng.normal(scale=1.5, size=(n, j, 3))
    r[0] = rng.normal(size=(j, 3)) * 1e-10  # the series branch
    back = np.empty((n, j, 4))
    NK.exp_relative(r, ref, back)
    expected = quat.mul(ref, np.roll(Rotation.from_rotvec(r.reshape(-1, 3)).as_quat().reshape(n, j, 4), 1, axis=-1))
    same_rotation(back, expected)
    np.testing.assert_allclose(back[..., 0] * expected[..., 0] >= 0, True)  # the same sign as ref * exp(r)
    np.testing.assert_allclose(back, expected, atol=1e-12)


@crosschecks("numba_kernels:fk")
def test_fk_matches_the_reference_forward_kinematics():
    rng = np.random.default_rng(105)
    parents = np.array([-1, 0, 1, 2, 1, 4, 0, 6, -1, 8])  # two roots
    n = 12
    rots, positions = random_quats(rng, (n, len(parents))), rng.normal(scale=30.0, size=(n, len(parents), 3))
    grot, gpos = np.empty((n, len(parents), 4)), np.empty((n, len(parents), 3))
    NK.fk(parents, rots, positions, grot, gpos)
    ref_rot, ref_pos = fk_reference(parents, rots, positions)
    np.testing.assert_allclose(grot, ref_rot, atol=1e-12)
    np.testing.assert_allclose(gpos, ref_pos, atol=1e-10)
    # Joint 5 by hand: 0 -> 1 -> 4 -> 5 with rotation matrices.
    m = Rotation.from_quat(np.roll(rots[:, 0], -1, axis=-1))
    p = positions[:, 0].copy()
    for c in (1, 4, 5):
        p = p + m.apply(positions[:, c])
        m = m * Rotation.from_quat(np.roll(rots[:, c], -1, axis=-1))
    np.testing.assert_allclose(gpos[:, 5], p, atol=1e-10)


@pytest.mark.parametrize("chain_len", [0, 3])
@crosschecks("numba_kernels:compose_root")
def test_compose_root_puts_the_root_at_its_global_pose(chain_len):
    # The defining property: after compose_root, forward kinematics through the root's
    # ancestors gives the root the global rotation heading * tilt and the global position gpos.
    rng = np.random.default_rng(106 + chain_len)
    n, up = 15, 1
    parents = np.array(list(range(-1, chain_len)) + [chain_len])  # chain 0..chain_len-1, root, child
    root = chain_len
    rots = random_quats(rng, (n, len(parents)))
    positions = rng.normal(scale=40.0, size=(n, len(parents), 3))
    gpos, heading = rng.normal(scale=100.0, size=(n, 3)), rng.uniform(-7, 7, n)
    tilt = rots[:, root].copy()
    r, p = rots.copy(), positions.copy()
    NK.compose_root(np.arange(chain_len, dtype=np.int64), root, up, r, p, gpos, heading)
    grot, g = fk_reference(parents, r, p)
    turn = Rotation.from_rotvec(np.outer(heading, np.eye(3)[up]))
    want = turn * Rotation.from_quat(np.roll(tilt, -1, axis=-1))
    same_rotation(grot[:, root], np.roll(want.as_quat(), 1, axis=-1), atol=1e-12)
    np.testing.assert_allclose(g[:, root], gpos, atol=1e-9)
    others = np.arange(len(parents)) != root
    np.testing.assert_array_equal(r[:, others], rots[:, others])  # nothing else changes
    np.testing.assert_array_equal(p[:, others], positions[:, others])


@pytest.mark.parametrize("circular", [False, True])
@crosschecks("numba_kernels:nearest", "numba_kernels:_nearest_row")
def test_nearest_kernels_match_a_brute_force_scan(circular):
    rng = np.random.default_rng(107 + circular)
    W, period = mixed_data(rng, 200, 9, 0.5 if circular else 0.0)
    X, _ = mixed_data(np.random.default_rng(7), 40, 9, 0.0, scale=1.5)
    X = np.where(np.isinf(period), X, np.mod(X * 3.0, 2 * np.pi))
    W[17] = W[5]  # a tie: the lower index wins
    X[0] = W[5]
    truth = np.array([np.argmin(periodic_sqdist(x, W, period)) for x in X])
    assert truth[0] == 5
    got = [NK.nearest(W, x, period) for x in X]
    assert got == truth.tolist()
    linear = [NK._nearest_row(W, x, period, False) for x in X]
    if not circular:
        assert linear == truth.tolist()
    else:  # the periodic metric matters here: a linear scan picks other rows
        assert linear != truth.tolist()
        assert [NK._nearest_row(W, x, period, True) for x in X] == truth.tolist()


@pytest.mark.parametrize("circular", [False, True])
@crosschecks("numba_kernels:project_to_map")
def test_project_to_map_matches_a_numpy_projection(circular):
    rng = np.random.default_rng(109 + circular)
    W, period = mixed_data(rng, 80, 6, 0.5 if circular else 0.0)
    X = np.where(np.isinf(period), rng.normal(scale=2.0, size=(50, 6)), rng.uniform(-1, 7.5, (50, 6)))
    k = np.array([np.argmin(periodic_sqdist(x, W, period)) for x in X])
    diff = wrapped(X - W[k], period)
    dist = np.linalg.norm(diff, axis=1)
    limit = float(np.median(dist))
    expected = W[k] + diff * np.minimum(1.0, limit / dist)[:, None]
    expected = np.where(np.isfinite(period), np.mod(expected, np.where(np.isfinite(period), period, 1.0)), expected)
    out, idx = np.empty_like(X), np.empty(len(X), dtype=np.int64)
    NK.project_to_map(W, X, period, limit, out, idx)
    assert idx.tolist() == k.tolist()
    np.testing.assert_allclose(out, expected, atol=1e-12)
    moved = dist > limit
    assert moved.any() and (~moved).any()
    np.testing.assert_allclose(np.linalg.norm(wrapped(out - W[k], period), axis=1),
                               np.minimum(dist, limit), atol=1e-12)
    if circular:
        assert np.all((out[:, np.isfinite(period)] >= 0) & (out[:, np.isfinite(period)] < 2 * np.pi))


@crosschecks("numba_kernels:key_from_blend")
def test_key_from_blend_takes_the_nearest_neuron_of_each_class():
    rng = np.random.default_rng(111)
    dims = [np.array([6, 0, 3]), np.array([1, 2, 7]), np.array([5]), np.array([4, 8])]
    maps = [rng.normal(size=(int(rng.integers(3, 60)), len(d))) for d in dims]
    weights = np.concatenate([w.ravel() for w in maps])
    offsets = np.concatenate([[0], np.cumsum([w.size for w in maps])[:-1]]).astype(np.int64)
    counts = np.array([len(w) for w in maps], dtype=np.int64)
    dim_index = np.concatenate(dims).astype(np.int64)
    dim_offsets = np.concatenate([[0], np.cumsum([len(d) for d in dims])]).astype(np.int64)
    for trial in range(20):
        blend = rng.normal(size=9)
        key, chosen = np.full(10, np.nan), np.empty(len(dims), dtype=np.int64)
        NK.key_from_blend(weights, offsets, counts, dim_index, dim_offsets, blend, key, chosen)
        for c, d in enumerate(dims):
            best = int(np.argmin(np.linalg.norm(maps[c] - blend[d], axis=1)))
            assert chosen[c] == best, (trial, c)
            np.testing.assert_array_equal(key[d], maps[c][best])
        assert np.isnan(key[9])  # dimensions of no class are left alone


# -- UPM training ---------------------------------------------------------------------------
@crosschecks("numba_kernels:sqdist")
def test_sqdist_matches_numpy():
    rng = np.random.default_rng(112)
    W, period = mixed_data(rng, 50, 7)
    x = np.where(np.isinf(period), rng.normal(size=7), rng.uniform(0, 2 * np.pi, 7))
    out = np.full(50, -1.0)
    NK.sqdist(x, W, 40, period, out)  # only the first n rows
    np.testing.assert_allclose(out[:40], periodic_sqdist(x, W[:40], period), rtol=1e-12)
    assert np.all(out[40:] == -1.0)


def move_reference(w, x, gain, period):
    d = wrapped(x - w, period)
    v = w + gain * d
    p = np.where(np.isfinite(period), period, 1.0)
    v = np.where(np.isfinite(period), v - p * np.floor(v / p), v)
    return np.where(np.isfinite(period) & (v >= p), 0.0, v)


@crosschecks("numba_kernels:move")
def test_move_steps_towards_the_sample_across_the_wrap():
    rng = np.random.default_rng(113)
    for _ in range(30):
        w, period = mixed_data(rng, 1, 8)
        w = w[0]
        x = np.where(np.isinf(period), rng.normal(size=8), rng.uniform(0, 2 * np.pi, 8))
        gain = float(rng.uniform(0, 1))
        expected = move_reference(w, x, gain, period)
        got = w.copy()
        NK.move(got, x, gain, period)
        np.testing.assert_allclose(got, expected, atol=1e-12)
    # Across the wrap: from 0.1 towards 2 pi - 0.1 is a step down through 0.
    got = np.array([0.1])
    NK.move(got, np.array([2 * np.pi - 0.1]), 0.75, np.array([2 * np.pi]))
    np.testing.assert_allclose(got, [2 * np.pi - 0.05], atol=1e-12)


def upm_epoch_reference(X, order, start, W, n, witness, edges_of, n_graph, period, r2, eta0, step0, total, hops,
                        win, second):
    """A plain Python UPM epoch (the paper's online rule), written without the kernel's buffers."""
    cap = len(W)
    step = step0
    for s in range(start, len(order)):
        if n >= cap:
            return s, n, step - step0
        i = order[s]
        x = X[i]
        eta = eta0 * max(0.0, 1.0 - step / total)
        step += 1
        if n == 0:
            W[0], witness[0], win[i], second[i], n = x, i, 0, -1, 1
            continue
        dist = periodic_sqdist(x, W[:n], period)
        ranked = np.argsort(dist, kind="stable")
        b = int(ranked[0])
        if dist[b] > r2:  # a new neuron at the sample
            W[n], witness[n], win[i], second[i] = x, i, n, b
            n += 1
            continue
        win[i], second[i] = b, (int(ranked[1]) if n > 1 else -1)
        W[b] = move_reference(W[b], x, eta, period)
        witness[b] = i
        if hops > 0 and b < n_graph:
            seen, frontier = {b}, [b]
            for h in range(1, hops + 1):  # neighbours h edges away, moved less the farther
                nxt = []
                for u in frontier:
                    for v in (edges_of.get(u, ()) if u < n_graph else ()):
                        if v not in seen:
                            seen.add(v)
                            nxt.append(v)
                            if dist[v] <= r2:
                                W[v] = move_reference(W[v], x, eta * (1.0 - h / (hops + 1.0)), period)
                                witness[v] = i
                frontier = nxt
    return len(order), n, step - step0


@pytest.mark.parametrize("cap, hops, circular", [(60, 2, False), (60, 1, True), (12, 2, True), (60, 0, False)])
@crosschecks("numba_kernels:upm_epoch")
def test_upm_epoch_matches_a_plain_python_epoch(cap, hops, circular):
    from posturemap.learn.upm import graph_csr

    rng = np.random.default_rng(114 + cap + hops + circular)
    d = 5
    X, period = mixed_data(rng, 120, d, 0.6 if circular else 0.0)
    n0 = 8
    W0 = np.zeros((cap, d))
    W0[:n0] = X[rng.choice(len(X), n0, replace=False)] + rng.normal(scale=0.1, size=(n0, d))
    W0[:n0] = np.where(np.isfinite(period), np.mod(W0[:n0], 2 * np.pi), W0[:n0])
    edges = np.array([(a, b) for a in range(n0) for b in range(a + 1, n0) if rng.random() < 0.4])
    ptr, idx = graph_csr(edges, n0)
    edges_of = {u: idx[ptr[u]: ptr[u + 1]].tolist() for u in range(n0)}
    # A radius that both adds neurons and moves existing ones.
    r2 = float(np.quantile([periodic_sqdist(x, W0[:n0], period).min() for x in X], 0.7))
    order = rng.permutation(len(X))
    args = dict(start=3, n=n0, period=period, r2=r2, eta0=0.5, step0=7, total=500.0, hops=hops)

    W, witness = W0.copy(), np.full(cap, -1, dtype=np.int64)
    win, second = np.full(len(X), -9, dtype=np.int64), np.full(len(X), -9, dtype=np.int64)
    got = NK.upm_epoch(X, order, args["start"], W, args["n"], witness, ptr, idx, period, r2, 0.5, 7, 500.0, hops,
                       win, second, np.empty(cap), np.full(cap, -1, dtype=np.int64), np.empty(cap, dtype=np.int64),
                       np.empty(cap, dtype=np.int64))
    W_ref, witness_ref = W0.copy(), np.full(cap, -1, dtype=np.int64)
    win_ref, second_ref = np.full(len(X), -9, dtype=np.int64), np.full(len(X), -9, dtype=np.int64)
    expected = upm_epoch_reference(X, order, 3, W_ref, n0, witness_ref, edges_of, n0, period, r2, 0.5, 7, 500.0,
                                   hops, win_ref, second_ref)
    assert tuple(got) == expected
    np.testing.assert_allclose(W, W_ref, atol=1e-12)
    np.testing.assert_array_equal(witness, witness_ref)
    np.testing.assert_array_equal(win, win_ref)
    np.testing.assert_array_equal(second, second_ref)
    assert expected[1] > n0  # neurons were added
    if cap == 12:
        assert expected[0] < len(order)  # stopped early: the weight array is full
    elif hops:
        moved_neighbours = [v for v in range(n0) if not np.allclose(W[v], W0[v]) and witness[v] >= 0]
        assert len(moved_neighbours) >= 2


@crosschecks("numba_kernels:two_nearest", "numba_kernels:_two_smallest")
def test_two_nearest_matches_numpy():
    rng = np.random.default_rng(115)
    X, period = mixed_data(rng, 70, 6)
    W, _ = mixed_data(rng, 30, 6)
    W = np.where(np.isinf(period), W, np.mod(W, 2 * np.pi))
    for n in (1, 25):
        win, second, err = np.empty(70, dtype=np.int64), np.empty(70, dtype=np.int64), np.empty(70)
        NK.two_nearest(X, W, n, period, win, second, err)
        dist = np.array([periodic_sqdist(x, W[:n], period) for x in X])
        ranked = np.argsort(dist, axis=1, kind="stable")
        np.testing.assert_array_equal(win, ranked[:, 0])
        np.testing.assert_array_equal(second, ranked[:, 1] if n > 1 else -1)
        np.testing.assert_allclose(err, np.sqrt(dist.min(1)), rtol=1e-12)


@crosschecks("numba_kernels:nearest_sample_dist")
def test_nearest_sample_dist_matches_numpy():
    rng = np.random.default_rng(116)
    X, period = mixed_data(rng, 90, 5)
    W, _ = mixed_data(rng, 25, 5)
    W = np.where(np.isinf(period), W, np.mod(W, 2 * np.pi))
    hint = rng.integers(-1, 90, 25)  # -1: no hint
    got = NK.nearest_sample_dist(W, X, period, hint)
    expected = np.array([np.sqrt(periodic_sqdist(w, X, period).min()) for w in W])
    np.testing.assert_allclose(got, expected, rtol=1e-12)


# -- retrieval --------------------------------------------------------------------------------
@pytest.mark.parametrize("k", [1, 4])
@crosschecks("retrieval_numba:replay", "retrieval_numba:_mean_track")
def test_replay_matches_the_numpy_retrieval_path(k):
    rng = np.random.default_rng(117 + k)
    n_lib, j, length = 200, 6, 9
    lib = types.SimpleNamespace(rots=random_quats(rng, (n_lib, j)).astype(np.float32))
    t = length + 4  # samples at -1 .. d + 1 of a gap d = length + 1
    i0 = rng.integers(0, n_lib - 1, (k, t))
    i1 = np.minimum(i0 + 1, n_lib - 1)
    f = rng.random((k, t))
    joints = np.array([0, 2, 3, 5])
    a2, b2 = random_quats(rng, (2, len(joints))), random_quats(rng, (2, len(joints)))
    curves = retrieval.hermite_offsets(length, 4.0)
    # The segments averaged, then the average's seams corrected.
    expected = retrieval.offset_rotations(retrieval.average_rotations(
        retrieval.sample_rotations(lib, i0, i1, f, joints))[None], a2, b2, curves)[0]
    out = np.empty((length, len(joints), 4))
    RN.replay(lib.rots, i0, i1, f, joints, np.arange(len(joints)), a2, b2, curves, 0, length, out, np.ones(k))
    same_rotation(out, expected, atol=1e-12)
    assert quat.angle_between(out, expected).max() < 1e-6  # float32 rounding (see _sample's test)
    # Weighed segments: the weighted mean, as numpy makes it (equal weights of any size: the same).
    wts = rng.uniform(0.5, 3.0, k)
    weighted = retrieval.offset_rotations(retrieval.average_rotations(
        retrieval.sample_rotations(lib, i0, i1, f, joints), wts)[None], a2, b2, curves)[0]
    got = np.empty_like(out)
    RN.replay(lib.rots, i0, i1, f, joints, np.arange(len(joints)), a2, b2, curves, 0, length, got, wts)
    same_rotation(got, weighted, atol=1e-12)
    RN.replay(lib.rots, i0, i1, f, joints, np.arange(len(joints)), a2, b2, curves, 0, length, got, np.full(k, 3.0))
    same_rotation(got, out, atol=1e-12)
    if k > 1:  # unequal weights move the mean
        assert quat.angle_between(weighted, expected).max() > 1e-3
    # A range of frames: the numpy path (whole replay, the rest set to the identity) agrees.
    lo, hi = 2, length - 3
    RN.replay(lib.rots, i0, i1, f, joints, np.arange(len(joints)), a2, b2, curves, lo, hi, out, np.ones(k))
    same_rotation(out[lo:hi], expected[lo:hi], atol=1e-12)
    with kernels.numpy_backend():
        ref = retrieval.replay_rotations(lib, i0, i1, f, joints, a2, b2, curves, frames=(lo, hi))
    np.testing.assert_array_equal(ref[:lo], np.tile([1.0, 0.0, 0.0, 0.0], (lo, len(joints), 1)))
    np.testing.assert_array_equal(out[:lo], ref[:lo])
    np.testing.assert_array_equal(out[hi:], ref[hi:])


@crosschecks("retrieval_numba:lift_upper")
def test_lift_upper_matches_numpy():
    rng = np.random.default_rng(123)
    n_lib, j, length, k = 200, 6, 11, 3
    lib = types.SimpleNamespace(rots=random_quats(rng, (n_lib, j)).astype(np.float32))
    t = length + 4
    i0 = rng.integers(0, n_lib - 1, (k, t))
    i1, f = np.minimum(i0 + 1, n_lib - 1), rng.random((k, t))
    a2, b2 = random_quats(rng, (2, j)), random_quats(rng, (2, j))
    curves = retrieval.hermite_offsets(length, 4.0)
    root, tops = 1, np.array([2, 4])
    wts = np.array([2.0, 1.0, 1.0])  # the segments' weights in the average
    base = random_quats(rng, (length, j))
    for weight, frames in ((0.5, None), (1.0, (3, 8)), (0.0, None)):
        lo, hi = (0, length) if frames is None else frames
        got, ref = base.copy(), base.copy()
        RN.lift_upper(lib.rots, i0, i1, f, root, tops, a2, b2, curves, lo, hi, weight, got, wts)
        retrieval.lift_upper(lib, i0, i1, f, root, tops, a2, b2, curves, weight, frames, ref, wts)
        same_rotation(got, ref, atol=1e-12)
        # Only the top joints of the new frames in range move; none at weight 0.
        others = [c for c in range(j) if c not in tops]
        np.testing.assert_array_equal(got[:, others], base[:, others])
        np.testing.assert_array_equal(got[:lo], base[:lo])
        np.testing.assert_array_equal(got[hi:], base[hi:])
        assert (quat.angle_between(got[lo:hi, tops], base[lo:hi, tops]) > 1e-6).all() == (weight > 0)
    # Where the legs' root is exactly the upper segments' own (the turn is the identity: the
    # division-free branch), nothing turns and nothing is NaN, whatever the weight.
    own = np.empty((length, 1, 4))
    RN.replay(lib.rots, i0, i1, f, np.array([root]), np.zeros(1, dtype=np.int64), a2[:, [root]], b2[:, [root]],
              curves, 0, length, own, wts)
    legs = base.copy()
    legs[:, root] = own[:, 0]
    ref_legs = base.copy()
    ref_legs[:, root] = retrieval.replay_rotations(lib, i0, i1, f, np.array([root]), a2[:, [root]], b2[:, [root]],
                                                   curves, weights=wts)[:, 0]
    for weight in (0.5, 1.0):
        got, ref = legs.copy(), ref_legs.copy()
        RN.lift_upper(lib.rots, i0, i1, f, root, tops, a2, b2, curves, 0, length, weight, got, wts)
        retrieval.lift_upper(lib, i0, i1, f, root, tops, a2, b2, curves, weight, None, ref, wts)
        np.testing.assert_allclose(got, legs, atol=1e-12)
        np.testing.assert_allclose(ref, ref_legs, atol=1e-12)


@crosschecks("retrieval_numba:seam_costs")
def test_seam_costs_match_numpy():
    rng = np.random.default_rng(118)
    pm, vm = rng.normal(size=(300, 7)).astype(np.float32), rng.normal(size=(300, 4)).astype(np.float32)
    frames, vframes = rng.integers(0, 300, 120), rng.integers(0, 300, 120)
    p, v = rng.normal(size=7).astype(np.float32), rng.normal(size=4).astype(np.float32)
    rate = rng.uniform(0.5, 2.0, 120)
    out = np.empty(120)
    RN.seam_costs(pm, vm, frames, vframes, p, v, rate, out)
    pm64, vm64 = pm.astype(np.float64), vm.astype(np.float64)
    expected = (((pm64[frames] - p) ** 2).sum(1)
                + ((rate[:, None] * vm64[vframes] - v.astype(np.float64)) ** 2).sum(1))
    np.testing.assert_allclose(out, expected, rtol=1e-6)


# -- BVH reading --------------------------------------------------------------------------------
def _format_number(rng) -> str:
    kind = int(rng.integers(6))
    x = float(rng.normal(scale=10.0 ** int(rng.integers(-3, 4))))
    if kind == 0:
        return f"{x:.6f}"
    if kind == 1:
        return repr(x)  # up to 17 digits
    if kind == 2:
        return f"{x:.3e}".replace("e", "E" if rng.random() < 0.5 else "e")
    if kind == 3:
        return str(int(rng.integers(-500, 500))) + ("." if rng.random() < 0.3 else "")
    if kind == 4:
        return f"{x:.25f}"  # more than 18 digits: the kernel hands it to Python
    return ("+" if rng.random() < 0.5 else "-") + f"{abs(x):.4f}e{int(rng.integers(-40, 40))}"


def swing_cases(rng):
    """Seam samples of groups of 3 and 1 columns: a wave (two periods), a raised arm (straight
    on at both seams), a group still at B, a column swinging at a rhythm of its own, noise, a
    still group; samples 1 or 4 frames apart."""
    starts = np.array([0, 3, 6, 9, 10, 13], dtype=np.intp)
    for step, n_a, n_b, length in ((1, 10, 10, 30), (4, 10, 8, 180), (1, 6, 10, 45), (2, 10, 10, 12)):
        d = length + 1.0
        times = np.concatenate([-step * np.arange(n_a - 1, -1, -1.0), d + step * np.arange(n_b, dtype=float)])
        rows = rng.normal(scale=0.01, size=(len(times), 16))
        for c, phase in zip(range(3), (0.3, 1.9, 4.0)):
            rows[:, c] += 0.4 * np.sin(2 * np.pi * times / (9.0 * step) + phase)
        rows[:, 3:6] += np.where(times <= 0, -times, times - d)[:, None] * [0.05, -0.02, 0.01]
        rows[:, 6:9] += np.where(times <= 0, 0.3 * np.sin(times), 0.0)[:, None]
        rows[:, 9] += 0.3 * np.sin(2 * np.pi * times / (16.0 * step))
        rows[:, 13:16] = 0.5
        yield rows, times, rng.normal(size=(5, 16)), length, starts


@crosschecks("numba_kernels:swing_columns", "numba_kernels:_ramp", "numba_kernels:_swing_design",
             "numba_kernels:_solve4", "numba_kernels:_swing_explained", "numba_kernels:_swing_peak",
             "numba_kernels:_own_residuals", "numba_kernels:_cholesky4")
def test_swing_columns_are_the_numpy_continued_swing():
    from posturemap.synth import periodic

    rng = np.random.default_rng(113)
    fps, tau = 30.0, 1.5
    seen, vetoed = set(), 0
    for rows, times, inputs, length, starts in swing_cases(rng):
        with kernels.numpy_backend():
            expected, w_expected = periodic.continued(rows, times, inputs, length, fps, starts, tau)
        frames, weights = np.empty((length, 16)), np.empty(16)
        found = NK.swing_columns(rows, times, inputs, length, periodic.frequencies(float(np.ptp(times)), fps), starts,
                                 tau, periodic.PERIODIC_GATE, periodic.PERIODIC_TURN, periodic.PERIODIC_BALANCE,
                                 periodic.PERIODIC_PEAKS, periodic.PERIODIC_OWN, periodic.PERIODIC_MIN_RMS, frames,
                                 weights)
        assert found == (expected is not None)
        np.testing.assert_allclose(weights, w_expected, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(frames, expected, rtol=1e-9, atol=1e-9)
        seen.update(np.round(weights[[0, 3, 6, 13]], 6))
        saved, periodic.PERIODIC_OWN = periodic.PERIODIC_OWN, 1e9  # every joint at the shared frequency
        try:
            with kernels.numpy_backend():
                free = periodic.continued(rows, times, inputs, length, fps, starts, tau)[1]
        finally:
            periodic.PERIODIC_OWN = saved
        vetoed += np.any((weights == 0.0) & (free > 0.0))
    assert {0.0, 1.0} <= seen  # both gates' ends met
    assert vetoed  # a group out of rhythm with the shared frequency: continued only without that check
    a = rng.normal(size=(4, 4))
    a = a @ a.T + 0.1 * np.eye(4)
    b = rng.normal(size=(4, 7))
    np.testing.assert_allclose(NK._solve4(a, b), np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)
    assert [NK._ramp(x, 0.2, 0.6) for x in (0.0, 0.4, 1.0)] == pytest.approx([0.0, 0.5, 1.0])
    assert [NK._ramp(x, 0.6, 0.2) for x in (0.0, 0.4, 1.0)] == pytest.approx([1.0, 0.5, 0.0])
    t = np.concatenate([-4.0 * np.arange(9, -1, -1), 50.0 + 4.0 * np.arange(9), [90.0, 91.5, 93.0]])  # even runs
    x = np.empty((len(t), 4))
    NK._swing_design(t, 0.07, 50.0, x)
    np.testing.assert_allclose(x, periodic._design(t, 0.07, 50.0)[0], rtol=0, atol=1e-13)
    rows, times, _, length, _ = next(swing_cases(rng))
    omegas = periodic.frequencies(float(np.ptp(times)), fps)
    d = length + 1.0
    explained = np.array([periodic._explained(rows, times, om, d) for om in omegas])
    np.testing.assert_allclose([NK._swing_explained(rows @ rows.T, times, om, d) for om in omegas[::7]],
                               explained[::7], rtol=1e-10)
    for peaks in (0, 1, 3):
        assert NK._swing_peak(omegas, explained, rows @ rows.T, times, d, peaks) == pytest.approx(
            periodic._peak(omegas, explained, lambda om: periodic._explained(rows, times, om, d), peaks), rel=1e-12)


@crosschecks("numba_kernels:seam_rows", "numba_kernels:_unwrap_seam_rows", "numba_kernels:_near_turn")
def test_compiled_seam_rows_equal_the_engines_numpy_rows(sample_clips):
    # Two clips' seam and context frames as the interpolating methods' rows, B turned and moved
    # (a turn of more than a half circle, so the heading's unwrapping counts), both backends.
    # The second reference stands half a turn from A's last frame about random axes: some of the
    # joints' frames (of A's rows, about a quarter) fall on the other side of that half turn, and
    # are unwrapped.
    from posturemap.synth import engine as E

    eng = E.TransitionEngine(None, sample_clips["walk"].skeleton)
    ta, tb = eng.add("a", sample_clips["walk"]), eng.add("b", sample_clips["run"])
    ia, ib = np.array([40, 41, 42, 30, 33, 36, 39]), np.array([5, 6, 5, 8, 11])
    j_count = eng.skeleton.num_joints
    axes = np.random.default_rng(4).normal(size=(j_count, 3))
    half = quat.exp(np.pi * axes / np.linalg.norm(axes, axis=1, keepdims=True))
    s0 = 3 * j_count
    unwrapped = 0
    for ref in (tb.rots[5].copy(), quat.mul(ta.rots[42], half)):
        for dtheta, shift in ((0.3, np.array([10.0, 0.0, -4.0])), (-2.9, np.zeros(3)),
                              (3.5, np.array([0.0, 2.0, 1.0]))):
            fast = E._seam_rows(eng, ta, tb, ia, ib, 42, ref, dtheta, shift)
            with kernels.numpy_backend():
                slow = E._seam_rows(eng, ta, tb, ia, ib, 42, ref, dtheta, shift)
            np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)
            assert abs(fast[len(ia), s0 + 3] - ta.heading[42]) < np.pi  # B's heading unwrapped to A's
            # The same rotations as the short arcs, and A's frames 41 and 42 (one step) a step apart.
            np.testing.assert_allclose(quat.angle_between(quat.exp(fast[:, :s0].reshape(-1, j_count, 3)),
                                                          quat.mul(quat.inv(ref), np.concatenate([ta.rots[ia], tb.rots[ib]]))),
                                       0.0, atol=1e-6)
            rv = fast[:, :s0].reshape(-1, j_count, 3)
            step = np.linalg.norm(rv[2] - rv[1], axis=-1)
            assert step.max() < 2 * quat.angle_between(ta.rots[42], ta.rots[41]).max() + 1e-6
            plain = np.empty_like(rv)
            kernels.log_relative(np.concatenate([ta.rots[ia], tb.rots[ib]]), ref, plain)
            unwrapped += int(np.sum(np.abs(plain - rv).max(axis=-1) > 1.0))
    assert unwrapped > 0  # the half turn put some frames across it


def test_near_turn_is_the_same_rotation_nearest_the_neighbour():
    rng = np.random.default_rng(8)
    axes = rng.normal(size=(500, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angle = rng.uniform(np.pi - 0.19, np.pi, 500)
    v = axes * angle[:, None]
    # The neighbour: the same axis just beyond the half turn, whose short arc is the opposite vector.
    near_q = quat.exp(axes * (angle + 0.2)[:, None])
    near = quat.log(near_q)
    assert np.all(np.sum(near * v, axis=1) < 0)
    out = quat.near_turn(near, v)
    np.testing.assert_allclose(quat.angle_between(quat.exp(out), near_q), 0.0, atol=1e-6)  # arccos: 1e-8
    np.testing.assert_allclose(np.linalg.norm(out - v, axis=1), 0.2, atol=1e-9)
    np.testing.assert_allclose(quat.near_turn(v, v), v)  # already nearest: unchanged
    np.testing.assert_array_equal(quat.near_turn(np.zeros((3, 3)), v[:3]), 0.0)  # no axis: left as it is
    fast = np.array([NK._near_turn(*a, *b) for a, b in zip(near, v)])
    np.testing.assert_allclose(fast, out, rtol=0, atol=1e-12)


@crosschecks("numba_kernels:damped_columns", "numba_kernels:_group_energy", "numba_kernels:_damped_apply",
             "numba_kernels:_reach_group")
def test_damped_columns_are_the_bases_damped_frames():
    # Random seam inputs and context samples (a wave, a still group, a steady drift, noise),
    # groups of 3 and 1 columns, some columns fixed to the shortest time constant; samples
    # 1 or 4 frames apart; also a context of two samples (no time scale from that side). The
    # reach in the groups of the first 5, 8 or 10 columns (5 and 8 fall inside a group, which
    # is then left out), at most a third of the gap, so that some groups are capped; it must
    # change the frames somewhere.
    from posturemap.synth.bases import DAMPED_PEAK, damped_frames, damped_time_scales, reach_parts

    rng = np.random.default_rng(112)
    starts = np.array([0, 3, 6, 7, 10], dtype=np.intp)
    n_c = 13
    fixed = np.zeros(n_c, dtype=bool)
    fixed[[3, 5]] = True
    changed = {k: False for k in (0, 5, 8, 10)}
    for step, n_a, n_b, length in ((1, 10, 10, 30), (4, 10, 7, 45), (1, 2, 10, 5), (2, 10, 10, 1), (1, 2, 2, 8)):
        inputs = rng.normal(size=(5, n_c))
        rows = [rng.normal(scale=0.05, size=(n, n_c)) for n in (n_a, n_b)]
        k = np.arange(n_a)
        rows[0][:, 0:3] = np.sin(0.7 * k)[:, None] * [1.0, 2.0, -0.5]
        rows[0][:, 6] = 0.0  # still at A
        rows[1][:, 6] = 3.0 * np.arange(n_b)  # a steady drift at B: inf, held at tau_max
        tau_min = 1.5
        tau_max = max(tau_min, 0.25 * (length + 1))  # as the engine holds it
        scale = np.where(fixed, 0.0, damped_time_scales(rows, step, starts))
        plain = damped_frames(inputs, length, scale, tau_min, tau_max)
        for reach_columns in (0, 5, 8, 10):
            reach_max = (length + 1) / 3.0
            out = np.empty((length, n_c))
            NK.damped_columns(inputs, length, rows[0], rows[1], float(step), starts, fixed, tau_min, tau_max,
                              reach_columns, reach_max, DAMPED_PEAK, out)
            reach = reach_parts(inputs, starts, reach_columns, length + 1.0, reach_max)
            expected = damped_frames(inputs, length, scale, tau_min, tau_max, reach)
            np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-12)
            if reach_columns == 0:
                np.testing.assert_allclose(out, plain, atol=1e-12)
            changed[reach_columns] |= np.abs(out - plain).max() > 1e-3
        for g, c0 in enumerate(starts):
            c1 = starts[g + 1] if g + 1 < len(starts) else n_c
            ev, ea = NK._group_energy(rows[0], c0, c1, float(step))
            if n_a < 3:
                assert (ev, ea) == (0.0, 0.0)
            else:
                v = np.diff(rows[0][:, c0:c1], axis=0) / step
                a = np.diff(v, axis=0) / step
                assert ev == pytest.approx(np.mean(v * v, axis=0).sum(), rel=1e-12)
                assert ea == pytest.approx(np.mean(a * a, axis=0).sum(), rel=1e-12)
    assert changed == {0: False, 5: True, 8: True, 10: True}


@crosschecks("bvh:parse_frames")
def test_parse_frames_kernel_matches_python_float():
    rng = np.random.default_rng(119)
    frames, channels = 25, 9
    tokens = [[_format_number(rng) for _ in range(channels)] for _ in range(frames)]
    seps = [" ", "\t", "  "]
    ends = ["\n", "\r\n", "\r", "\n\n"]
    text = "".join(rng.choice(seps).join(row) + rng.choice(ends) for row in tokens)
    buf = np.frombuffer(text.encode("ascii"), dtype=np.uint8)
    out, slow = np.full(frames * channels, np.nan), np.empty((4096, 3), dtype=np.int64)
    status, num_slow = BVH_KERNELS.parse_frames(buf, frames, channels, out, slow)
    assert status == 0
    assert num_slow > 0  # some numbers took the slow path
    for k, start, end in slow[:num_slow]:
        out[k] = float(buf[start:end].tobytes())
    expected = np.array([float(t) for row in tokens for t in row])
    np.testing.assert_array_equal(out, expected)  # exact: correctly rounded, as float() is
    # What the kernel refuses, and with which status (the caller then uses the general parser).
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    body = [ln for ln in lines if ln.strip()]
    cases = {
        1: "\n".join(body[:3] + [" ".join(body[3].split()[:-1])] + body[4:]) + "\n",  # a short line
        2: "\n".join(body + body[:1]) + "\n",  # an extra line
        3: "\n".join(body[:2] + [body[2].replace(body[2].split()[0], "1x", 1)] + body[3:]) + "\n",  # a bad number
        5: "\n".join(body[:-1]) + "\n",  # a line missing
    }
    for want, case in cases.items():
        buf = np.frombuffer(case.encode("ascii"), dtype=np.uint8)
        status, _ = BVH_KERNELS.parse_frames(buf, frames, channels, np.empty(frames * channels), slow)
        assert status == want, (want, status)


@crosschecks("bvh:euler_to_quat")
def test_euler_to_quat_kernel_matches_scipy():
    rng = np.random.default_rng(120)
    orders = ["ZXY", "XYZ", "ZYX", "YXZ", "XZY", "YZX"]
    n_frames, n_joints = 40, len(orders)
    values = rng.uniform(-180, 180, size=(n_frames, 3 * n_joints + 2))
    values[:5] *= 7.0  # beyond +-180: reported
    cols = np.arange(2, 2 + 3 * n_joints).reshape(n_joints, 3)[rng.permutation(n_joints)]
    joints = np.arange(1, n_joints + 1)
    axes = np.array([["XYZ".index(c) for c in o] for o in orders])
    out = np.full((n_frames, n_joints + 2, 4), np.nan)
    assert BVH_KERNELS.euler_to_quat(values, joints, cols, axes, out)
    for n, order in enumerate(orders):
        expected = np.roll(Rotation.from_euler(order, values[:, cols[n]], degrees=True).as_quat(), 1, axis=-1)
        same_rotation(out[:, joints[n]], expected, atol=1e-12)
        np.testing.assert_allclose(out[:, joints[n]], quat.from_euler(np.radians(values[:, cols[n]]), order),
                                   atol=1e-12)
    assert np.isnan(out[:, 0]).all() and np.isnan(out[:, -1]).all()  # other joints untouched
    assert not BVH_KERNELS.euler_to_quat(values[5:], joints, cols, axes, out[5:])  # within [-180, 180]


# -- nothing compiled goes unchecked ---------------------------------------------------------
KERNEL_MODULES = {"numba_kernels": NK, "retrieval_numba": RN}


def compiled_functions() -> set[str]:
    """``module:function`` of every numba dispatcher defined in the kernel modules, plus the
    BVH reader's compiled kernels."""
    found = set()
    for short, module in KERNEL_MODULES.items():
        for name, obj in vars(module).items():
            if isinstance(obj, numba.core.registry.CPUDispatcher) and obj.py_func.__module__ == module.__name__:
                found.add(f"{short}:{name}")
    import dataclasses

    found |= {f"bvh:{f.name}" for f in dataclasses.fields(BVH_KERNELS)}
    return found


@crosschecks("retrieval_numba:carry_chain", "retrieval_numba:_chain_world", "retrieval_numba:_seam_carrier")
def test_compiled_carry_chain_matches_the_numpy_steps(bandai_paths):
    # A root bone that carries root motion (run_normal_001's and walk-back_normal_001's
    # joint_Root), on its own and under a fixed node turned and moved, bent with the body's path
    # or not, through random new frames at random seams, turns and shifts.
    from posturemap.core.joints import ancestors
    from posturemap.core.motion import root_index, up_axis
    from posturemap.learn.features import root_global, upright_rest
    from posturemap.synth import trajectory
    from rigkit import topped

    clips = [bvh.read(p) for p in bandai_paths(["run_normal_001", "walk-back_normal_001"]).values()]
    node = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.array(-np.pi / 2)), np.array([30.0, 5.0, -20.0])
    rng = np.random.default_rng(7)
    checked = 0
    for rig in (clips, [topped(m, *node) for m in clips]):
        root, up = root_index(rig[0]), up_axis(rig[0])
        chain = np.array(ancestors(rig[0].skeleton.parents, root), dtype=np.int64)
        rest = upright_rest(root_global(rig[0], root)[0], up)
        ta, tb = (trajectory.make_track(m, root, up, rest) for m in rig)
        assert ta.carrier == tb.carrier == len(chain) - 1
        for length, a_carrier in itertools.product((1, 7, 40), (-1, ta.carrier)):
            rots = random_quats(rng, (length, rig[0].skeleton.num_joints))
            pos = rng.normal(scale=30.0, size=(length, rig[0].skeleton.num_joints, 3))
            a_end, b_start = int(rng.integers(0, len(ta.gpos))), int(rng.integers(0, len(tb.gpos)))
            dtheta, shift = float(rng.uniform(-np.pi, np.pi)), rng.normal(scale=100.0, size=3)
            ref_r, ref_p, given = rots.copy(), pos.copy(), pos.copy()
            trajectory.carry_chain(ta, tb, a_end, b_start, ref_r, ref_p, chain, root, up, dtheta, shift, a_carrier,
                                   tb.carrier)
            bump, solve = trajectory.bend_fit(length, ta.motion.fps, bent=a_carrier >= 0)
            RN.carry_chain(rots, pos, chain, tb.carrier, root, ta.motion.rotations, ta.motion.positions, ta.gpos,
                           max(a_end - 1, 0), a_end, tb.motion.rotations, tb.motion.positions, tb.gpos, b_start,
                           min(b_start + 1, len(tb.gpos) - 1), up, dtheta, shift, hermite_basis(length), bump, solve)
            same_rotation(rots, ref_r, atol=1e-10)
            np.testing.assert_allclose(pos, ref_p, rtol=0, atol=1e-8)
            carrier = chain[tb.carrier]
            assert np.abs(pos[:, carrier] - given[:, carrier]).max() > 1.0  # the bone was carried
            checked += 1
    assert checked == 12


@crosschecks("retrieval_numba:_prefetch_row")
def test_prefetch_hints_change_nothing():
    # The prefetch hints (LLVM's llvm.prefetch, named for this LLVM's pointers) compile and are
    # only hints: every row, the last ones included, reads back as it was.
    @numba.njit
    def touch_and_sum(a, rows, idx):
        for r in rows:
            RN._prefetch_row(a, r)
        for i in idx:
            RN._prefetch(idx, (i,))
            RN._prefetch(a, (np.int32(i), np.int32(0)))  # narrower indices are widened
        acc = 0.0
        for r in rows:
            for j in range(a.shape[1]):
                acc += float(a[r, j])
        return acc

    rng = np.random.default_rng(31)
    for dtype in (np.float32, np.float64):
        a = rng.normal(size=(257, 13)).astype(dtype)
        before = a.copy()
        rows = np.array([0, 1, 128, 255, 256], dtype=np.int64)
        got = touch_and_sum(a, rows, np.arange(5, dtype=np.int64))
        np.testing.assert_array_equal(a, before)
        want = 0.0
        for r in rows:
            for x in before[r].astype(np.float64):
                want += float(x)
        assert got == want
    # The hints are there: the compiled code calls LLVM's prefetch.
    for ir_text in touch_and_sum.inspect_llvm().values():
        assert ir_text.count("call void @llvm.prefetch") >= 4


# Kernels whose cross-check against the numpy reference lives next to that reference: the test
# (file and name) that compares them. The guard checks that each named test exists.
ELSEWHERE = {
    "test_feet.py::test_compiled_foot_lock_matches_the_numpy_reference": (
        "numba_kernels:lock_legs", "numba_kernels:hinge_ik_frame", "numba_kernels:_angle",
        "numba_kernels:_axis_angle_in", "numba_kernels:_unit", "numba_kernels:_knee_hinge",
        "numba_kernels:_knee_axis", "numba_kernels:_knee_angles", "numba_kernels:_signed_bend"),
    "test_feet.py::test_foot_lock_lifts_a_toe_dragged_along_the_floor": ("numba_kernels:_toe_lift",),
    "test_feet.py::test_the_planted_test_of_a_seam_is_the_same_compiled": ("numba_kernels:_planted",),
    "test_feet.py::test_pace_passes_is_the_same_compiled": ("numba_kernels:_pace_passes", "numba_kernels:_pass_gap",
                                                         "numba_kernels:_pass_accel", "numba_kernels:_pass_second",
                                                         "numba_kernels:_step_high"),
    "test_feet.py::test_knee_bounded_is_the_same_compiled": ("numba_kernels:knee_bounded",),
    "test_rest.py::test_rest_bounded_projects_a_change_over_many_frames_the_sweeps_cannot_bring_within_the_bound": (
        "numba_kernels:_rest_projected",),
    "test_rest.py::test_rest_bounded_is_the_same_compiled": ("numba_kernels:_rest_bounded", "numba_kernels:_at",
                                                             "numba_kernels:_second_size", "numba_kernels:_within"),
    "test_hinges.py::test_unbend_is_the_same_compiled": ("numba_kernels:unbend_limbs", "numba_kernels:_faded"),
    "test_hinges.py::test_a_share_of_the_hips_turn_is_the_same_compiled": ("numba_kernels:_turn_share",),
    "test_hinges.py::test_bend_frames_is_the_same_compiled": ("numba_kernels:limb_bends", "numba_kernels:_limb_bend"),
    "test_hinges.py::test_the_shortest_arc_is_the_same_compiled": ("numba_kernels:_between",),
    "test_feet.py::test_a_toe_planted_at_a_seam_stays_put_after_a_short_run_there": ("numba_kernels:_from_seam",),
    "test_feet.py::test_stance_windows_give_each_moving_foot_its_own_part_of_the_gap_farthest_first": (
        "numba_kernels:_stance_windows",),
    "test_feet.py::test_a_twist_joint_inside_the_thigh_stays_inside_it": ("numba_kernels:_carried",),
    "test_feet.py::test_soft_limit_is_the_value_until_its_start_then_bends_onto_the_limit": (
        "numba_kernels:_soft_limit",),
    "test_kernels.py::test_slerp_agrees": ("numba_kernels:slerp", "numba_kernels:_slerp_signed"),
    "test_kernels.py::test_slerp_track_goes_on_round_a_half_turn": ("numba_kernels:slerp_track",),
    "test_kernels.py::test_turn_toward_agrees_and_turns_the_last_joint_only": ("numba_kernels:turn_toward",),
    "test_kernels.py::test_chest_turned_agrees_and_differs_from_the_other_by_the_turn_about_up_beyond_free": (
        "numba_kernels:chest_turned",),
    "test_kernels.py::test_blend_root_turns_about_up_and_tilts_on_the_short_arc": ("numba_kernels:blend_root",),
    "test_retrieval.py::test_compiled_search_matches_the_numpy_steps": (
        "retrieval_numba:search", "retrieval_numba:_best", "retrieval_numba:_prefilter", "retrieval_numba:_pos_cost",
        "retrieval_numba:_pos_costs", "retrieval_numba:_vel_cost", "retrieval_numba:_vel_costs",
        "retrieval_numba:_seam_costs", "retrieval_numba:_sqdist", "retrieval_numba:_sqdists"),
    "test_retrieval.py::test_compiled_selection_of_the_smallest": (
        "retrieval_numba:_smallest", "retrieval_numba:_first_smallest", "retrieval_numba:_buckets"),
    "test_splice.py::test_compiled_splice_rotations_match_the_numpy_reference": (
        "retrieval_numba:splice_rotations",),
    "test_splice.py::test_compiled_splice_path_matches_the_numpy_reference": ("retrieval_numba:splice_path",),
    "test_splice.py::test_compiled_splice_matches_the_numpy_steps": (
        "retrieval_numba:splice", "retrieval_numba:_turned"),
    "test_retrieval.py::test_compiled_replay_of_a_match_equals_the_numpy_steps": ("retrieval_numba:replay_part",),
    "test_retrieval.py::test_the_splice_replays_only_what_it_shows_and_equals_the_whole_replays": (
        "retrieval_numba:spliced", "retrieval_numba:_replay_half"),
    "test_retrieval.py::test_a_fully_confident_transition_takes_the_open_columns_from_spline": (
        "retrieval_numba:open_columns",),
    "test_retrieval.py::test_compiled_gather_matches_the_numpy_steps": (
        "retrieval_numba:gather", "retrieval_numba:_frames_of_nearest"),
    "test_retrieval.py::test_gathering_both_seams_at_once_equals_one_by_one": ("retrieval_numba:gather_seams",),
    "test_retrieval.py::test_searching_both_parts_at_once_equals_each_alone": ("retrieval_numba:search_parts",),
    "test_retrieval.py::test_batched_seams_and_distances_equal_the_single_ones": (
        "retrieval_numba:seam_features", "retrieval_numba:seam_distances", "retrieval_numba:seam_rows",
        "retrieval_numba:_scale_rows"),
    "test_retrieval.py::test_compiled_root_trajectory_matches_the_numpy_steps": (
        "retrieval_numba:trajectory", "retrieval_numba:_offset_mean", "retrieval_numba:_bend_paths",
        "retrieval_numba:_seam_misses"),
    "test_retrieval.py::test_compiled_segment_times_match_the_numpy_steps": ("retrieval_numba:segment_times",),
}


def test_cross_checks_elsewhere_exist():
    here = Path(__file__).resolve().parent
    for where in ELSEWHERE:
        file, name = where.split("::")
        assert f"def {name}(" in (here / file).read_text(encoding="utf-8"), where


def test_every_kernel_is_crosschecked():
    found = compiled_functions()
    assert len(found) >= 20
    checked = CHECKED | {k for names in ELSEWHERE.values() for k in names}
    missing = sorted(found - checked)
    assert not missing, f"compiled functions without a cross-check in {Path(__file__).name}: {missing}"
    stale = sorted(checked - found)
    assert not stale, f"cross-checks of functions that no longer exist: {stale}"


def test_no_other_module_compiles_kernels():
    # A kernel in a new module must be added to KERNEL_MODULES (and cross-checked).
    known = {SRC / "core" / "numba_kernels.py", SRC / "synth" / "retrieval_numba.py", SRC / "io" / "bvh.py"}
    users = {p for p in SRC.rglob("*.py") if re.search(r"\b(njit|numba\.jit|nb\.jit|vectorize)\b", p.read_text())}
    assert users - known == set(), f"modules compiling numba kernels not cross-checked here: {sorted(users - known)}"
    for path in known:
        importlib.import_module("posturemap." + ".".join(path.relative_to(SRC).with_suffix("").parts))
