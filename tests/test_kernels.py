"""The two kernel backends (numpy, numba) against each other, and a start-up without numba.

``posturemap.core.kernels`` runs numpy until something calls ``kernels.compiled()``; every hot
kernel must give the same answer either way. ``import posturemap`` and one command-line
transition with ``--map`` must not import numba at all (a structural check, in a fresh
process: the timing is ``bench/startup.py``'s job).
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from posturemap.io import bvh
from posturemap.core import kernels, quat
from posturemap.learn.model import PostureMap
from posturemap.synth.engine import transition
from posturemap.synth.request import METHODS


def random_quats(rng, shape) -> np.ndarray:
    q = quat.normalize(rng.normal(size=tuple(shape) + (4,)))
    return q * np.where(rng.random(tuple(shape) + (1,)) < 0.5, -1.0, 1.0)


@pytest.fixture(scope="module")
def jit():
    return kernels.compiled()


def test_backend_switch_and_restore(jit):
    assert kernels.backend() == "numba" and kernels.fk is jit.fk
    with kernels.numpy_backend():
        assert kernels.backend() == "numpy"
        assert kernels.fk is kernels.NUMPY.fk and kernels.nearest is kernels.NUMPY.nearest
        assert bvh._fast_kernels() is None  # the BVH reader follows the backend
    assert kernels.backend() == "numba" and kernels.fk is jit.fk
    assert bvh._fast_kernels() is not None
    assert kernels.upm_epoch is jit.upm_epoch  # training kernels: compiled only


def test_log_exp_and_fk_agree(jit):
    rng = np.random.default_rng(0)
    n, j = 40, 7
    ref = random_quats(rng, (j,))
    q = random_quats(rng, (n, j))
    q[0] = quat.mul(ref, quat.exp(rng.normal(size=(j, 3)) * 1e-10))  # the series branch
    outs = []
    for impl in (kernels.NUMPY, jit):
        out = np.empty((n, j, 3))
        impl.log_relative(q, ref, out)
        back = np.empty((n, j, 4))
        impl.exp_relative(out, ref, back)
        outs.append((out, back))
    np.testing.assert_allclose(outs[0][0], outs[1][0], atol=1e-12)
    np.testing.assert_allclose(outs[0][1], outs[1][1], atol=1e-12)
    assert np.all(quat.angle_between(outs[0][1], q) < 1e-7)  # exp(log(q)) is q

    parents = np.array([-1, 0, 1, 1, 3, 0, 5])
    positions = rng.normal(scale=10.0, size=(n, j, 3))
    results = []
    for impl in (kernels.NUMPY, jit):
        grot, gpos = np.empty((n, j, 4)), np.empty((n, j, 3))
        impl.fk(parents, q, positions, grot, gpos)
        results.append((grot, gpos))
    np.testing.assert_allclose(results[0][0], results[1][0], atol=1e-12)
    np.testing.assert_allclose(results[0][1], results[1][1], atol=1e-10)
    # Joint 4's global position by hand: root, then 1, 3, 4 down the chain.
    g = positions[:, 0]
    r = q[:, 0]
    for c in (1, 3, 4):
        g = g + quat.mul_vec(r, positions[:, c])
        r = quat.mul(r, q[:, c])
    np.testing.assert_allclose(results[0][1][:, 4], g, atol=1e-10)


@pytest.mark.parametrize("chain_len", [0, 2])
@pytest.mark.parametrize("up", [1, 2])
def test_compose_root_agrees(jit, up, chain_len):
    rng = np.random.default_rng(3 + up + 10 * chain_len)
    n, root = 30, chain_len
    j_count = chain_len + 2
    rots = random_quats(rng, (n, j_count))
    positions = rng.normal(scale=50.0, size=(n, j_count, 3))
    gpos = rng.normal(scale=100.0, size=(n, 3))
    heading = rng.uniform(-7, 7, size=n)
    chain = np.arange(chain_len, dtype=np.int64)
    out = []
    for impl in (kernels.NUMPY, jit):
        r, p = rots.copy(), positions.copy()
        impl.compose_root(chain, root, up, r, p, gpos, heading)
        out.append((r, p))
    assert np.all(quat.angle_between(out[0][0], out[1][0]) < 1e-7)
    np.testing.assert_allclose(out[0][1], out[1][1], atol=1e-9)
    assert not np.allclose(out[0][0][:, root], rots[:, root])  # it did change the root


@pytest.mark.parametrize("circular", [False, True])
def test_nearest_and_projection_agree(jit, circular):
    rng = np.random.default_rng(5 + circular)
    n, d, m = 300, 12, 25
    period = np.where(rng.random(d) < 0.5, 2 * np.pi, np.inf) if circular else np.full(d, np.inf)
    w = np.where(np.isinf(period), rng.normal(size=(n, d)), rng.uniform(0, 2 * np.pi, size=(n, d)))
    x = np.where(np.isinf(period), rng.normal(scale=1.5, size=(m, d)), rng.uniform(0, 2 * np.pi, size=(m, d)))
    # A brute-force scan as the oracle.
    diff = np.abs(w[None] - x[:, None])
    diff = np.where(np.isinf(period), diff, np.minimum(diff, 2 * np.pi - diff))
    truth = np.argmin((diff ** 2).sum(-1), axis=1)
    for impl in (kernels.NUMPY, jit):
        assert [impl.nearest(w, xi, period) for xi in x] == truth.tolist()
    limit = float(np.median(np.sqrt((diff ** 2).sum(-1).min(1))))  # half the rows kept
    projected = []
    for impl in (kernels.NUMPY, jit):
        out, idx = x.copy(), np.empty(m, dtype=np.int64)
        impl.project_to_map(w, out, period, limit, out, idx)  # in place, as synth/keys.py calls it
        assert idx.tolist() == truth.tolist()
        projected.append(out)
    np.testing.assert_allclose(projected[0], projected[1], atol=1e-12)
    moved = np.linalg.norm(projected[0] - x, axis=1) > 1e-9
    assert moved.any() and (~moved).any()  # some kept, some pulled onto a sphere


def test_key_from_blend_agrees(jit):
    rng = np.random.default_rng(8)
    dims = [np.array([0, 3, 4]), np.array([1, 2]), np.array([5])]
    maps = [rng.normal(size=(int(rng.integers(5, 40)), len(d))) for d in dims]
    weights = np.concatenate([w.ravel() for w in maps])
    offsets = np.concatenate([[0], np.cumsum([w.size for w in maps])[:-1]]).astype(np.int64)
    counts = np.array([len(w) for w in maps], dtype=np.int64)
    dim_index = np.concatenate(dims).astype(np.int64)
    dim_offsets = np.concatenate([[0], np.cumsum([len(d) for d in dims])]).astype(np.int64)
    blend = rng.normal(size=6)
    keys = []
    for impl in (kernels.NUMPY, jit):
        key, chosen = np.full(6, np.nan), np.empty(3, dtype=np.int64)
        impl.key_from_blend(weights, offsets, counts, dim_index, dim_offsets, blend, key, chosen)
        for c, d in enumerate(dims):
            assert chosen[c] == np.argmin(((maps[c] - blend[d]) ** 2).sum(1))
            np.testing.assert_array_equal(key[d], maps[c][chosen[c]])
        keys.append(key)
    np.testing.assert_array_equal(keys[0], keys[1])


@pytest.mark.parametrize("t", [0.0, 0.3, 0.75, 1.0])
def test_slerp_agrees(jit, t):
    rng = np.random.default_rng(9)
    a = random_quats(rng, (200,))
    b = quat.mul(a, quat.exp(rng.normal(scale=1.0, size=(200, 3))))
    b *= np.where(rng.random((200, 1)) < 0.5, -1.0, 1.0)  # both hemispheres: the short arc
    b[:20] = a[:20] * np.where(rng.random((20, 1)) < 0.5, -1.0, 1.0)  # the same rotation
    b[20:40] = quat.mul(a[20:40], quat.exp(rng.normal(scale=1e-8, size=(20, 3))))  # nearly
    outs = []
    for impl in (kernels.NUMPY, jit):
        out = np.empty_like(a)
        impl.slerp(a, b, t, out)
        outs.append(out)
    np.testing.assert_allclose(outs[1], outs[0], atol=1e-12)
    # The short arc from a to b, at the fraction t of the angle.
    whole = quat.angle_between(a, b)
    np.testing.assert_allclose(quat.angle_between(a, outs[1]), t * whole, atol=1e-6)
    np.testing.assert_allclose(quat.angle_between(outs[1], b), (1 - t) * whole, atol=1e-6)


@pytest.mark.parametrize("t", [0.0, 0.33, 0.75, 1.0])
def test_slerp_track_goes_on_round_a_half_turn(jit, t):
    # Track b turns steadily away from track a (3 degrees a frame, 60 frames) through a half turn
    # at frame 40, about a random axis per column, with random signs: the short arc of each frame
    # is slerp's until the half turn, then it flips to the other side and a blend jumped by up to
    # a half turn in a frame. slerp_track stays on the arc it was on: the same as slerp before
    # the half turn, then going on round (its angle from a grows on past 180 degrees), never a
    # step larger than the track's own.
    rng = np.random.default_rng(5)
    n, m = 60, 12
    a = random_quats(rng, (n, m))
    axes = rng.normal(size=(m, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angle = np.radians(60.0 + 3.0 * np.arange(n))  # 180 degrees at frame 40
    b = quat.mul(a, quat.exp(angle[:, None, None] * axes[None]))
    b *= np.where(rng.random((n, m, 1)) < 0.5, -1.0, 1.0)
    outs, ends = [], []
    for impl in (kernels.NUMPY, jit):
        out = np.empty_like(a)
        ends.append(impl.slerp_track(a, b, t, out, np.zeros(m, dtype=bool)))
        outs.append(out)
    np.testing.assert_allclose(outs[1], outs[0], atol=1e-12)
    out = outs[1]
    # It returns the last frame's relative rotation on the arc, its sign included: 237 degrees
    # round (a scalar part below 0), not the short arc's -123.
    for end in ends:
        np.testing.assert_allclose(end, quat.exp(angle[-1] * axes), atol=1e-9)
    assert np.all(ends[1][:, 0] < 0.0)
    short = np.empty_like(a)
    kernels.NUMPY.slerp(a.reshape(-1, 4), b.reshape(-1, 4), t, short.reshape(-1, 4))
    same = np.abs(np.sum(out * short, axis=-1))
    np.testing.assert_allclose(same[:40], 1.0, atol=1e-9)  # the short arc up to the half turn
    # Everywhere, beyond the half turn too: the fraction t of b's whole turn from a, on round.
    want = quat.mul(a, quat.exp(t * angle[:, None, None] * axes[None]))
    np.testing.assert_allclose(np.abs(np.sum(out * want, axis=-1)), 1.0, atol=1e-9)
    steps = quat.angle_between(quat.mul(quat.inv(a[1:]), out[1:]), quat.mul(quat.inv(a[:-1]), out[:-1]))
    assert steps.max() <= np.radians(3.0) * t + 1e-6  # t of b's own step from a, never a jump


@pytest.mark.parametrize("align", [True, False])
@pytest.mark.parametrize("c", [0.0, 0.55, 1.0])
def test_blend_root_turns_about_up_and_tilts_on_the_short_arc(jit, c, align):
    # The fallback's root (under a turned ancestor, Bandai's rest a quarter turn about Z) turns
    # about the up axis and tilts; the retrieved one leads it by 0.3 rad at the first frame,
    # round past a whole turn by the last (a segment circling), with tilts of its own. The blend
    # is the fallback's heading plus c of the lead, on round (no axis to swing where the two
    # come back together), and the short arc between the tilts; where B stays put, the lead's
    # whole turn at the last frame is taken off over the frames.
    rng = np.random.default_rng(23)
    n, up = 50, 1
    rest = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.pi / 2)
    yaw = lambda h: quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), h)  # noqa: E731
    def tilted(scale):  # small turns about horizontal axes: no twist about up
        v = rng.normal(scale=scale, size=(n, 3))
        v[:, up] = 0.0
        return quat.exp(v)
    h_fb = np.cumsum(rng.normal(scale=0.05, size=n)) + 3.0  # across the +-pi seam of atan2
    g_fb = quat.mul(quat.mul(yaw(h_fb), tilted(0.1)), rest)
    rots = np.tile(quat.identity(), (n, 3, 1))
    rots[:, 0] = random_quats(rng, (n,))  # the root's ancestor
    rots[:, 1] = quat.mul(quat.inv(rots[:, 0]), g_fb) * np.where(rng.random((n, 1)) < 0.5, -1.0, 1.0)
    u = np.arange(1, n + 1) / n
    lead = 0.3 + (2.0 * np.pi * 1.04 - 0.3) * u * u * (3.0 - 2.0 * u)
    heading = h_fb + lead + 2.0 * np.pi * 3  # the retrieved track counts whole turns of its own
    tilt_ret = quat.mul(tilted(0.1), rest) * np.where(rng.random((n, 1)) < 0.5, -1.0, 1.0)
    outs = []
    for impl in (kernels.NUMPY, jit):
        tilt, out = tilt_ret.copy(), np.empty(n)
        went = impl.blend_root(np.array([0]), 1, up, rest, rots, tilt, heading, c, align, out)
        outs.append((tilt, out, went))
    np.testing.assert_allclose(outs[1][0], outs[0][0], atol=1e-12)
    np.testing.assert_allclose(outs[1][1], outs[0][1], atol=1e-12)
    assert abs(outs[1][2] - outs[0][2]) < 1e-12
    tilt, out, went = outs[1]
    assert went == pytest.approx(lead[-1], abs=1e-9)  # on round, past the whole turn
    taken = 0.0 if align else 2.0 * np.pi * u * u * (3.0 - 2.0 * u)
    np.testing.assert_allclose(out, h_fb + 6.0 * np.pi + c * (lead - taken), atol=1e-9)  # counted round as heading
    tilt_fb = quat.mul(quat.inv(yaw(h_fb)), g_fb)
    np.testing.assert_allclose(quat.angle_between(tilt, quat.slerp(tilt_fb, tilt_ret, c)), 0.0, atol=1e-7)
    if c == 0.0:  # the fallback's own root, rebuilt
        np.testing.assert_allclose(quat.angle_between(quat.mul(yaw(out), tilt), g_fb), 0.0, atol=1e-7)
    blended = quat.mul(yaw(out), tilt)
    steps = quat.angle_between(blended[1:], blended[:-1])
    assert steps.max() < np.abs(np.diff(h_fb)).max() + c * np.diff(lead - taken).max() + 0.5  # never a jump


@pytest.mark.parametrize("t", [0.33, 0.59])
def test_slerp_track_fade_columns_meet_an_end_when_the_arc_winds_and_never_turn_over(jit, t):
    # Track b turns away from track a through a half turn and on, round to within 9 degrees of
    # a whole turn (back next to a from the other side), then 15 degrees past it. On the arc
    # that goes on, a blend at a fraction that stays ends a third of a whole turn from both (an
    # arm 123 degrees in a frame into B's first) and turns over where the arc passes the whole
    # turn; the fade columns are that arc up to a half turn round, then their fraction moves
    # to the nearer end, all the way from three quarters of a turn.
    assert jit._FADE_SPAN == kernels.FADE_SPAN == np.radians(90.0)
    rng = np.random.default_rng(15)
    n, m = 80, 6
    a = quat.exp(np.cumsum(rng.normal(scale=0.01, size=(n, m, 3)), axis=0))
    axes = rng.normal(size=(m, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angle = np.radians(np.linspace(2.0, 375.0, n))
    b = quat.mul(a, quat.exp(angle[:, None, None] * axes[None]))
    b *= np.where(rng.random((n, m, 1)) < 0.5, -1.0, 1.0)
    fade = np.arange(m) % 2 == 0  # half the columns
    outs, ends = [], []
    for impl in (kernels.NUMPY, jit):
        out = np.empty_like(a)
        ends.append(impl.slerp_track(a, b, t, out, fade))
        outs.append(out)
    np.testing.assert_allclose(outs[1], outs[0], atol=1e-12)
    np.testing.assert_allclose(ends[1], ends[0], atol=1e-12)
    out = outs[1]
    on_round = quat.mul(a, quat.exp(t * angle[:, None, None] * axes[None]))  # t of the arc's angle
    same = np.abs(np.sum(out * on_round, axis=-1))
    # Up to a half turn round, every column is on the arc that goes on ...
    np.testing.assert_allclose(same[angle <= np.pi], 1.0, atol=1e-9)
    # ... past it the other columns stay on it (and turn over at the whole turn) ...
    np.testing.assert_allclose(same[angle < 2.0 * np.pi - 1e-3][:, ~fade], 1.0, atol=1e-9)
    assert quat.angle_between(out[1:, ~fade], out[:-1, ~fade]).max() > np.radians(30.0)
    # ... and the fade columns reach the nearer end by three quarters of a turn, and stay there.
    end = a if t < 0.5 else b
    late = angle >= 1.5 * np.pi
    assert quat.angle_between(out[late][:, fade], end[late][:, fade]).max() < 1e-6
    steps = quat.angle_between(out[1:, fade], out[:-1, fade])
    assert steps.max() < 3.0 * np.radians(373.0 / (n - 1))  # three times the tracks' relative turn a frame


@pytest.mark.parametrize("t", [0.0, 0.5, 1.0])
def test_turn_toward_agrees_and_turns_the_last_joint_only(jit, t):
    rng = np.random.default_rng(11)
    n, j_count = 40, 7
    rots, other = random_quats(rng, (n, j_count)), random_quats(rng, (n, j_count))
    chain = np.array([0, 2, 3, 5], dtype=np.int64)  # joint 5 under 3 under 2 under 0
    outs = []
    for impl in (kernels.NUMPY, jit):
        r = rots.copy()
        impl.turn_toward(chain, r, other, t)
        outs.append(r)
    assert np.all(quat.angle_between(outs[0], outs[1]) < 1e-6)
    for j in range(j_count - 2):  # the ancestors and every other joint stay, to the bit
        np.testing.assert_array_equal(outs[1][:, j], rots[:, j])
    np.testing.assert_array_equal(outs[1][:, 6], rots[:, 6])

    def world(r):
        g = r[:, chain[0]]
        for c in chain[1:]:
            g = quat.mul(g, r[:, c])
        return g

    own, goal, got = world(rots), world(other), world(outs[1])
    whole = quat.angle_between(own, goal)
    assert whole.min() > 0.1
    np.testing.assert_allclose(quat.angle_between(own, got), t * whole, atol=1e-6)
    np.testing.assert_allclose(quat.angle_between(got, goal), (1 - t) * whole, atol=1e-6)


@pytest.mark.parametrize("up", [0, 1, 2])
@pytest.mark.parametrize("above", [[0], []])
@pytest.mark.parametrize("free", [0.0, 0.7, np.pi])
def test_chest_turned_agrees_and_differs_from_the_other_by_the_turn_about_up_beyond_free(jit, up, above, free):
    rng = np.random.default_rng(12)
    n, j_count = 40, 7
    other, rots = random_quats(rng, (n, j_count)), random_quats(rng, (n, j_count))
    # 3 and 5 under the root 2, itself under 0 (Bandai's joint_Root) or a top joint (CMU's Hips)
    chain, joints = np.array(above + [2], dtype=np.int64), np.array([3, 5], dtype=np.int64)
    outs = []
    for impl in (kernels.NUMPY, jit):
        out = np.zeros((n, j_count, 4))
        impl.chest_turned(chain, up, other, rots, joints, free, out)
        outs.append(out)
    assert np.all(quat.angle_between(outs[0][:, joints], outs[1][:, joints]) < 1e-6)
    others = np.setdiff1d(np.arange(j_count), joints)
    assert not outs[0][:, others].any() and not outs[1][:, others].any()  # nothing else written

    def world(r):
        return quat.mul(r[:, 0], r[:, 2]) if above else r[:, 2]

    axis = np.zeros(3)
    axis[up] = 1.0
    swing, twist = quat.swing_twist(quat.mul(world(rots), quat.inv(world(other))), axis)
    assert np.median(quat.angle_between(swing, quat.identity())) > 0.5  # the chains differ by more than a turn
    theta = 2.0 * np.arctan2(twist[:, 1:] @ axis, twist[:, 0])  # the chains' turn about up, in [-pi, pi)
    theta = (theta + np.pi) % (2.0 * np.pi) - np.pi
    beyond = theta - free * np.tanh(np.sin(theta) / free) if free > 0.0 else theta  # the turn beyond free
    if free > 0.0:
        assert np.abs(beyond - theta).max() > 0.1  # free holds some of the turn back
    turn = quat.from_axis_angle(np.broadcast_to(axis, (n, 3)), beyond)
    for j in joints:
        moved = quat.mul(quat.mul(world(rots), outs[1][:, j]), quat.inv(quat.mul(world(other), other[:, j])))
        np.testing.assert_allclose(quat.angle_between(moved, turn), 0.0, atol=1e-6)


def test_chest_turned_turns_a_half_turn_either_way_alike(jit):
    # Pelvises a half turn apart about up, just short of it either way, are one turn: the chest
    # must come out the same (a bound on theta itself jumped by twice the bound there).
    free = np.radians(15.0)
    eps = 1e-6
    for impl in (kernels.NUMPY, jit):
        worlds = []
        for theta in (np.pi - eps, -np.pi + eps):
            other = np.zeros((1, 2, 4))
            other[..., 0] = 1.0  # the pelvis and the chest as they are
            rots = other.copy()
            rots[0, 0] = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), np.array(theta))
            out = other.copy()
            impl.chest_turned(np.array([0], dtype=np.int64), 1, other, rots, np.array([1], dtype=np.int64), free, out)
            worlds.append(quat.mul(rots[0, 0], out[0, 1]))
        assert quat.angle_between(worlds[0], worlds[1]) < 1e-4
        assert quat.angle_between(worlds[0], quat.identity()) > np.pi - 1e-3  # turned with the pelvis, all of it


@pytest.mark.parametrize("method", METHODS)
def test_transitions_agree_across_backends(sample_clips, method):
    a, b = sample_clips["walk"], sample_clips["run"]
    model = PostureMap(seed=0, epochs=2).fit([a, b])
    fast = transition(a, b, model, length=12, alpha=0.3, method=method)
    with kernels.numpy_backend():
        slow = transition(a, b, model, length=12, alpha=0.3, method=method)
    np.testing.assert_allclose(slow.positions, fast.positions, atol=1e-8)
    np.testing.assert_allclose(np.abs(quat.dot(slow.rotations, fast.rotations)), 1.0, atol=1e-12)


def _modules_after(code: str) -> dict:
    """Run ``code`` in a fresh interpreter; returns which heavy modules it imported."""
    probe = textwrap.dedent(code) + textwrap.dedent("""
        import json, sys
        print(json.dumps({m: m in sys.modules for m in ("numpy", "numba", "scipy", "matplotlib", "starlette")}))
    """)
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_import_posturemap_does_not_import_numba():
    loaded = _modules_after("import posturemap\nposturemap.PostureMap, posturemap.transition")
    assert loaded == {"numpy": True, "numba": False, "scipy": False, "matplotlib": False, "starlette": False}
    # The package itself loads its modules on first use; the names are the same objects.
    loaded = _modules_after("import posturemap")
    assert not any(loaded.values()), loaded
    import posturemap
    from posturemap import transition as imported_name
    from posturemap.learn.model import PostureMap as model_class

    assert posturemap.PostureMap is model_class
    assert posturemap.transition is transition is imported_name  # the function, not the module
    assert callable(posturemap.transition) and "transition" in dir(posturemap)


@pytest.mark.parametrize("flag", ["--help", "--version"])
def test_help_and_version_import_no_numpy(flag):
    loaded = _modules_after(f"""
        from posturemap import cli
        try:
            cli.main([{flag!r}])
        except SystemExit as e:
            assert e.code == 0
    """)
    assert not any(loaded.values()), loaded


def test_cli_transition_with_a_map_runs_without_numba(sample_clips, tmp_path):
    a, b = tmp_path / "walk.bvh", tmp_path / "run.bvh"
    bvh.write(a, sample_clips["walk"])
    bvh.write(b, sample_clips["run"])
    model = PostureMap(seed=0, epochs=2).fit([bvh.read(a), bvh.read(b)])
    model.save(tmp_path / "map.npz")
    out = tmp_path / "out.bvh"
    loaded = _modules_after(f"""
        from posturemap import cli
        assert cli.main(["transition", {str(a)!r}, {str(b)!r}, "-o",
                        {str(out)!r}, "--map", {str(tmp_path / "map.npz")!r}, "--length", "15"]) == 0
    """)
    assert loaded["numba"] is False and loaded["matplotlib"] is False
    # The numpy run in that process wrote what the compiled kernels make here.
    expected = transition(bvh.read(a), bvh.read(b), model, length=15)
    got = bvh.read(out)
    assert len(got) == len(expected)
    assert np.all(quat.angle_between(got.rotations, expected.rotations) < 1e-6)
    np.testing.assert_allclose(got.positions, expected.positions, atol=1e-5)
