"""Motion transitions on real motion capture: what the issue "Motion transitions" must show.

Real clips come from Bandai-Namco dataset 1 (``bandai_files``; skipped with a reason when the
data folder is absent): one PostureMap is trained once per module on five clips (walk, run,
bow, dance, walk-back; about a second). Kernels and spline bases are checked on seeded random
data against the numpy reference in :mod:`posturemap.core.quat`. The CLI runs in-process.
"""

from __future__ import annotations

import contextlib
import math
import os

import numpy as np
import pytest

from posturemap.io import bvh
from posturemap import cli
from posturemap.core import kernels, quat
from posturemap.errors import UserError
from posturemap.learn.features import root_global, upright_rest, wrap_diff
from posturemap.learn.model import PostureMap
from posturemap.core.motion import Motion, concatenate, root_index, up_axis
from posturemap.core.skeleton import chain_world, fk
from posturemap.synth.bases import (DAMPED_PEAK, DAMPED_SAMPLES, DAMPED_TAU_S, damped_frames, damped_time_scales,
                                   hermite_basis, inertialize_basis, key_spline_basis, keys_spline_basis,
                                   linear_basis, reach_parts)
from posturemap.synth import periodic, trajectory
from posturemap.synth.rest import at_rest
from posturemap.synth.engine import TransitionEngine, transition
from posturemap.synth.keys import ACCEPT
from posturemap.synth.request import KEY_POSTURE, KEYED, METHODS, RequestError, TransitionRequest
from rigkit import topped, under_node

UP = 1  # Bandai dataset 1 is Y up (data README): the checks below use the known axis
WALK, RUN, BOW, DANCE, BACK = ("walk_normal_001", "run_normal_001", "bow_normal_001",
                               "dance-short_normal_001", "walk-back_normal_001")
CLIPS = (WALK, RUN, BOW, DANCE, BACK)
LEFT = "walk-left_normal_001"  # read where needed, not part of the map
PAIRS = [(WALK, RUN), (BOW, DANCE), (RUN, BACK)]
NEURON_KEYS = ("upm", "upm-path")  # keys made of map neurons (upm-valid projects estimates)
WINDOW = 10  # clip frames beside a seam that the seam is compared with


# -- fixtures ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def paths(bandai_paths):
    return bandai_paths(CLIPS + (LEFT,))


@pytest.fixture(scope="module")
def clips(paths):
    return {n: bvh.read(paths[n]) for n in CLIPS}


@pytest.fixture(scope="module")
def model(clips):
    return PostureMap(seed=0).fit([clips[n] for n in CLIPS], list(CLIPS))


@pytest.fixture(scope="module")
def euler_model(clips):
    names = [WALK, RUN, BOW, BACK]
    return PostureMap(seed=0, features="euler").fit([clips[n] for n in names], names)


@pytest.fixture(scope="module")
def map_file(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("map") / "map.npz"
    model.save(str(path))
    return str(path)


# -- helpers ------------------------------------------------------------------------------
def up_vec() -> np.ndarray:
    v = np.zeros(3)
    v[UP] = 1.0
    return v


def root_state(m: Motion, rest=None):
    """Root (Hips) global position (F, 3), heading about up (F,) and tilt (F, 4), via quat.py.

    The heading is measured on the upright body (``rest``: the engine's, from the map or the
    first clip; by default the clip's own), as the library defines it.
    """
    grot, gpos = root_global(m, m.skeleton.index("Hips"))
    if rest is None:
        rest = upright_rest(grot, UP)
    head_q, tilt = quat.heading_tilt(grot, up_vec(), rest)
    return gpos, 2.0 * np.arctan2(head_q[..., 1 + UP], head_q[..., 0]), tilt


def wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def about_up(v: np.ndarray, angle: float) -> np.ndarray:
    """Vectors (..., 3) turned by ``angle`` about the up axis (quat.py reference)."""
    q = quat.from_axis_angle(up_vec(), np.float64(angle))
    return quat.mul_vec(np.broadcast_to(q, v.shape[:-1] + (4,)), v)


def horizontal(v: np.ndarray) -> np.ndarray:
    out = np.array(v, dtype=float, copy=True)
    out[..., UP] = 0.0
    return out


def key_vector(model, key) -> np.ndarray:
    """Full posture vector (D,) of a decoded key ``(rotations (K, 4), height)``."""
    rots, height = key
    return model.space_.encode_parts(rots[None], np.array([height]))[0]


def seam_cases(clips, seed: int, count: int):
    """Named pairs at their natural seams plus seeded random pairs, seams and lengths.

    Each case is (A, B, a_end, b_start, length) with ``WINDOW`` clip frames on both sides.
    """
    cases = [(a, b, len(clips[a]) - 1, 0, length) for a, b in PAIRS for length in (10, 20)]
    rng = np.random.default_rng(seed)
    names = list(CLIPS)
    for _ in range(count):
        a, b = rng.choice(names, 2, replace=False)
        a_end = int(rng.integers(WINDOW + 2, len(clips[a])))
        b_start = int(rng.integers(0, len(clips[b]) - WINDOW - 2))
        cases.append((str(a), str(b), a_end, b_start, int(rng.choice([10, 20, 30]))))
    return cases


def around_seams(out: Motion, a_end: int, length: int) -> tuple[Motion, int, int]:
    """Frames from ``WINDOW + 1`` before A's last to ``WINDOW + 1`` after B's first.

    Returns the slice and the indices (in it) of A's last frame and B's first frame.
    """
    lo = a_end - WINDOW - 1
    hi = a_end + 1 + length + WINDOW + 2
    return out[lo:hi], WINDOW + 1, WINDOW + 2 + length


def seam_ratios(part: Motion, i0: int, i1: int) -> dict[str, float]:
    """How much each seam stands out from its surroundings (1 = as rough as the roughest frame there).

    ``step`` is the largest distance any joint moves between two frames (global positions,
    cm); ``acc`` the largest change of a joint's per-frame displacement (velocity change).
    Each seam (A's last -> first new frame; last new frame -> B's first) is compared with the
    ``WINDOW`` clip frames on its side and with the in-between frames.
    """
    g = part.global_positions()
    step = np.linalg.norm(np.diff(g, axis=0), axis=-1).max(axis=-1)           # step[i]: frame i -> i+1
    acc = np.linalg.norm(g[2:] - 2 * g[1:-1] + g[:-2], axis=-1).max(axis=-1)  # acc[i]: at frame i+1
    inner_step = step[i0 + 1: i1 - 1].max()
    inner_acc = acc[i0 + 1: i1 - 2].max()
    return {
        "step_a": step[i0] / max(step[i0 - WINDOW: i0].max(), inner_step),
        "step_b": step[i1 - 1] / max(step[i1: i1 + WINDOW].max(), inner_step),
        "acc_a": acc[i0 - 1: i0 + 1].max() / max(acc[i0 - WINDOW - 1: i0 - 1].max(), inner_acc),
        "acc_b": acc[i1 - 2: i1].max() / max(acc[i1: i1 + WINDOW].max(), inner_acc),
    }


def run_cli(argv, capsys) -> tuple[int, str, str]:
    try:
        code = cli.main(argv)
    except SystemExit as e:  # argparse errors
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


# -- the data itself ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def every_clip(bandai_files):
    return {p.stem.removeprefix("dataset-1_"): bvh.read(p) for p in bandai_files}


def test_up_axis_of_every_bandai_clip_is_y(every_clip, model):
    # Bandai's joint_Root mostly stays at the origin while Hips walks away: a joint spread that
    # includes joint_Root measures the distance walked, not the body (walk_normal_001: 425 cm
    # along Z against a body height of 138 cm along Y).
    found = {n: up_axis(m) for n, m in every_clip.items()}
    wrong = {n: "XYZ"[u] for n, u in found.items() if u != UP}
    assert not wrong, f"{len(wrong)} of {len(found)} clips get a wrong up axis: {wrong}"
    assert model.space_.up == UP


def test_root_of_every_bandai_clip_is_hips(every_clip):
    # One skeleton, one root: in four clips joint_Root moves too (run_normal_001: 200 cm along
    # Z, with Hips moving on top of it), yet Hips is still what turns and tilts the body.
    found = {n: m.skeleton.names[root_index(m)] for n, m in every_clip.items()}
    wrong = {n: r for n, r in found.items() if r != "Hips"}
    assert not wrong, f"{len(wrong)} of {len(found)} clips get another root: {wrong}"


def test_mapless_alignment_turns_b_to_a_heading(clips, paths):
    # run_normal_001 and walk-back_normal_001 are clips whose joint_Root moves; walk-left
    # faces about 80 degrees away from them. Aligned, B must face A's heading plus the carried
    # turning, with or without a map.
    left = bvh.read(paths[LEFT])
    for name in (RUN, BACK):
        a = clips[name]
        out = transition(a, left, None, length=20, method="spline")
        i0, i1 = len(a) - 1, len(a) + 20
        rest = upright_rest(root_global(a, a.skeleton.index("Hips"))[0], UP)
        _, head_o, _ = root_state(out, rest)
        _, head_a, _ = root_state(a, rest)
        _, head_b, _ = root_state(left, rest)
        carried = 0.5 * ((head_a[i0] - head_a[i0 - 1]) + (head_b[1] - head_b[0])) * 21
        assert abs(wrap(head_o[i1] - head_o[i0] - carried)) < 1e-6, (
            f"{name} -> walk-left: B faces {np.degrees(wrap(head_o[i1] - head_o[i0])):.0f} deg from A")


# -- output layout --------------------------------------------------------------------------
@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("a_end, b_start, length, key_at", [
    (None, 0, 20, None), (50, 5, 7, 1), (0, 23, 45, 45), (120, 10, 2, 2),
])
def test_frame_count_and_clip_parts(clips, model, method, a_end, b_start, length, key_at):
    a, b = clips[WALK], clips[RUN]
    out = transition(a, b, model, length=length, key_at=key_at, a_end=a_end, b_start=b_start, method=method)
    last = len(a) - 1 if a_end is None else a_end
    assert len(out) == last + 1 + length + len(b) - b_start
    assert out.skeleton is a.skeleton and out.fps == a.fps
    # A's part is A's frames, untouched.
    assert np.array_equal(out.rotations[: last + 1], a.rotations[: last + 1])
    assert np.array_equal(out.positions[: last + 1], a.positions[: last + 1])
    # The new frames are what the engine makes for the same arguments.
    engine = TransitionEngine(model)
    engine.add("a", a)
    engine.add("b", b)
    rots, pos = engine.generate("a", "b", length=length, key_at=key_at, alpha=0.5, a_end=a_end, b_start=b_start,
                                method=method)
    np.testing.assert_array_equal(out.rotations[last + 1: last + 1 + length], rots)
    np.testing.assert_array_equal(out.positions[last + 1: last + 1 + length], pos)
    np.testing.assert_allclose(np.linalg.norm(rots, axis=-1), 1.0, atol=1e-9)
    assert np.all(np.isfinite(pos))
    # B's part is B moved rigidly: every joint below the root turned by dtheta about up and
    # shifted (global positions and rotations), local rotations below the root untouched.
    tail = out[last + 1 + length:]
    dtheta, shift = engine.last["dtheta"], engine.last["shift"]
    sk = a.skeleton
    hips = sk.index("Hips")
    below = np.array([j for j in range(sk.num_joints) if hips in ancestors_and_self(sk.parents, j)])
    g_tail, g_b = tail.global_positions(), b[b_start:].global_positions()
    np.testing.assert_allclose(g_tail[:, below], about_up(g_b[:, below], dtheta) + shift, atol=1e-6)
    turn = quat.from_axis_angle(up_vec(), np.float64(dtheta))
    grot_tail = fk(sk.parents, tail.rotations, tail.positions)[0]
    grot_b = fk(sk.parents, b.rotations[b_start:], b.positions[b_start:])[0]
    assert quat.angle_between(grot_tail[:, below], quat.mul(np.broadcast_to(turn, grot_b[:, below].shape),
                                                             grot_b[:, below])).max() < 1e-6
    others = below[below != hips]
    assert np.array_equal(tail.rotations[:, others], b.rotations[b_start:, others])
    # Continuity at both seams: no joint jumps further than it moves elsewhere around them
    # (the clip frames beside the seam and the new frames). The finer bounds are in
    # test_seams_are_continuous_in_position_and_velocity.
    g = out.global_positions()
    step = np.linalg.norm(np.diff(g, axis=0), axis=-1).max(axis=-1)  # step[i]: frame i -> i+1
    lo, hi = max(last - WINDOW, 0), min(last + length + WINDOW + 1, len(out) - 1)
    for seam in (last, last + length):  # A's last -> first new; last new -> B's first
        others_steps = np.delete(step[lo:hi], seam - lo)
        assert step[seam] <= 3.0 * max(others_steps.max(), 1e-9) + 1.0, (method, seam, step[seam], others_steps.max())


def ancestors_and_self(parents, j) -> set[int]:
    out = {j}
    while parents[j] >= 0:
        j = int(parents[j])
        out.add(j)
    return out


@pytest.mark.parametrize("length", [1, 2, 3])
@pytest.mark.parametrize("method", KEYED)
def test_default_key_at_works_for_short_transitions(clips, model, method, length):
    # key_at defaults to max(1, length // 2): length // 2 is 0 (outside 1..length) for length 1.
    a, b = clips[RUN], clips[BACK]
    out = transition(a, b, model, length=length, method=method)
    assert len(out) == len(a) + length + len(b)
    explicit = transition(a, b, model, length=length, key_at=max(1, length // 2), method=method)
    np.testing.assert_array_equal(out.rotations, explicit.rotations)
    np.testing.assert_array_equal(out.positions, explicit.positions)
    if method in KEY_POSTURE:  # and that frame is the key posture
        engine = TransitionEngine(model)
        engine.add("a", a)
        engine.add("b", b)
        engine.generate("a", "b", length=length, method=method, foot_lock=False)
        plain = transition(a, b, model, length=length, method=method, foot_lock=False)
        at = len(a) + max(1, length // 2) - 1
        assert_frame_is_key(plain[at], model, engine.last["key"], engine.last["neurons"], method, f"length {length}")


# -- the key posture ------------------------------------------------------------------------
def assert_frame_is_key(frame: Motion, model, key, neurons, method, where=""):
    """The one-frame motion ``frame`` shows the decoded ``key`` = (rotations (K, 4), height)."""
    space = model.space_
    key_rots, key_height = key
    # Local rotations of the feature joints below the root are the key's.
    err = quat.angle_between(frame.rotations[0, space.joints[1:]], key_rots[1:])
    assert err.max() < 1e-6, f"{where}: key joints off by {np.degrees(err.max()):.3g} deg"
    # The root's global rotation is the key's tilt turned about the up axis only, and its
    # height is the key's. (A key's tilt, an average of tilts, may itself turn a little about
    # up; that part then reads as heading, so compare rotations rather than decompositions.)
    grot, gpos = root_global(frame, space.root)
    turn = quat.mul(grot[0], quat.inv(key_rots[0]))
    assert np.abs(np.delete(turn[1:], UP)).max() < 1e-7, f"{where}: root tilt is not the key's"
    assert gpos[0, UP] == pytest.approx(key_height, abs=1e-6)
    if method in NEURON_KEYS:  # the key is made of the chosen neurons, class by class
        x = space.fill.copy()
        for c, k in enumerate(neurons):
            x[space.class_dims[c]] = model.maps_[c].weights_[k]
        rots, height = space.decode(x)
        assert quat.angle_between(rots, key_rots).max() < 1e-6
        assert float(height) == pytest.approx(key_height, abs=1e-9)


@pytest.mark.parametrize("method", KEY_POSTURE)
def test_frame_at_key_at_is_the_key_posture(clips, model, method):
    space = model.space_
    for (a, b), (a_end, b_start, length, key_at, alpha) in zip(
            PAIRS + [(WALK, RUN)], [(None, 0, 20, 10, 0.5), (100, 40, 12, 3, 0.2),
                                    (20, 5, 30, 30, 0.8), (150, 0, 9, 1, 1.0)]):
        engine = TransitionEngine(model)
        engine.add("a", clips[a])
        engine.add("b", clips[b])
        engine.generate("a", "b", length=length, key_at=key_at, alpha=alpha, a_end=a_end, b_start=b_start, method=method)
        out = transition(clips[a], clips[b], model, length=length, key_at=key_at, alpha=alpha, foot_lock=False,
                         a_end=a_end, b_start=b_start, method=method)
        last = len(clips[a]) - 1 if a_end is None else a_end
        where = f"{a}[..{last}] -> {b}[{b_start}..], key at {key_at} of {length}"
        assert_frame_is_key(out[last + 1 + key_at - 1], model, engine.last["key"], engine.last["neurons"],
                            method, where)
        # The posture vector of that frame is the key's, but for the root tilt (see above).
        x = model.encode(out[last + key_at])[0]
        key_x = key_vector(model, engine.last["key"])
        rest = space.active.copy()
        rest[:3] = False
        np.testing.assert_allclose(wrap_diff(x, key_x, space.circular)[rest], 0.0, atol=1e-6)
        # The neighbours are not the key: the spline passes through it, it does not stop there.
        if 1 < key_at < length:
            before = out[last + key_at - 1].rotations[0, space.joints[1:]]
            assert quat.angle_between(before, engine.last["key"][0][1:]).max() > 1e-4


@pytest.mark.parametrize("features", ["quat", "euler"])
def test_upm_key_is_the_neuron_nearest_the_alpha_blend(clips, model, euler_model, features):
    # Brute force with numpy: per class, the neuron of that class's map nearest the blend
    # xa + alpha (xb - xa) of the seam postures (circular dimensions blended the short way
    # round and wrapped, for Euler features); the engine's key must be that neuron's weights.
    mdl = model if features == "quat" else euler_model
    space = mdl.space_
    circ = space.circular
    names = [WALK, RUN, BOW, BACK]
    engine = TransitionEngine(mdl)
    for n in names:
        engine.add(n, clips[n])
    rng = np.random.default_rng(21)
    checked = 0
    for a, b in [(WALK, RUN), (BOW, BACK), (RUN, BOW), (BACK, WALK)]:
        for alpha in (0.0, 0.25, 0.5, 0.8, 1.0):
            a_end, b_start = int(rng.integers(len(clips[a]))), int(rng.integers(len(clips[b])))
            xa, xb = mdl.encode(clips[a][a_end])[0], mdl.encode(clips[b][b_start])[0]
            blend = xa + alpha * wrap_diff(xb, xa, circ)
            blend = np.where(circ, np.mod(blend, 2 * np.pi), blend)
            expected_key = space.fill.copy()
            expected = []
            for c, m in enumerate(mdl.maps_):
                dims = space.class_dims[c]
                d = np.linalg.norm(wrap_diff(m.weights_, blend[dims], circ[dims]), axis=1)
                k = int(np.argmin(d))
                assert np.sort(d)[1] - d[k] > 1e-9  # no tie: the nearest neuron is unambiguous
                expected.append(k)
                expected_key[dims] = m.weights_[k]
            key, chosen = engine.keys.key_features(xa, xb, alpha)
            assert list(chosen) == expected, (features, a, b, alpha)
            np.testing.assert_array_equal(key, expected_key)
            engine.generate(a, b, alpha=alpha, a_end=a_end, b_start=b_start, method="upm")
            assert list(engine.last["neurons"]) == expected, (features, a, b, alpha)
            np.testing.assert_allclose(key_vector(mdl, engine.last["key"])[space.active & ~circ],
                                       expected_key[space.active & ~circ], atol=1e-9)
            checked += 1
    assert checked == 20


@pytest.mark.parametrize("method", NEURON_KEYS)
@pytest.mark.parametrize("alpha", [0.0, 0.3, 0.5, 1.0])
def test_each_partial_key_is_a_map_neuron(clips, model, method, alpha):
    engine = TransitionEngine(model)
    for a, b in PAIRS:
        engine.add(a, clips[a])
        engine.add(b, clips[b])
        engine.generate(a, b, alpha=alpha, method=method)
        neurons = engine.last["neurons"]
        assert len(neurons) == len(model.maps_) == 4
        x = key_vector(model, engine.last["key"])
        for c, k in enumerate(neurons):
            assert 0 <= k < model.maps_[c].n_neurons
            np.testing.assert_allclose(x[model.space_.class_dims[c]], model.maps_[c].weights_[k], atol=1e-9)


def test_upm_path_keys_lie_on_the_shortest_map_path(clips, model):
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    space = model.space_
    engine = TransitionEngine(model)
    rng = np.random.default_rng(9)
    checked = 0
    for a, b in PAIRS + [(DANCE, WALK), (BACK, BOW)]:
        engine.add(a, clips[a])
        engine.add(b, clips[b])
        a_end, b_start = int(rng.integers(len(clips[a]))), int(rng.integers(len(clips[b])))
        xa, xb = model.encode(clips[a][a_end])[0], model.encode(clips[b][b_start])[0]
        chosen = {}
        for alpha in (0.0, 0.5, 1.0):
            engine.generate(a, b, alpha=alpha, a_end=a_end, b_start=b_start, method="upm-path")
            chosen[alpha] = engine.last["neurons"]
        for c, m in enumerate(model.maps_):
            dims = space.class_dims[c]
            circ = space.circular[dims]
            w = m.weights_
            wa = int(np.argmin(np.linalg.norm(wrap_diff(w, xa[dims], circ), axis=1)))
            wb = int(np.argmin(np.linalg.norm(wrap_diff(w, xb[dims], circ), axis=1)))
            e = m.edges_
            lengths = np.linalg.norm(wrap_diff(w[e[:, 0]], w[e[:, 1]], circ), axis=1)
            graph = csr_matrix((np.maximum(lengths, 1e-12), (e[:, 0], e[:, 1])), shape=(len(w), len(w)))
            da, db = dijkstra(graph, directed=False, indices=[wa, wb])
            if wa == wb or not np.isfinite(da[wb]):
                continue
            assert chosen[0.0][c] == wa and chosen[1.0][c] == wb, f"{a}->{b} class {c}"
            k = chosen[0.5][c]
            assert da[k] + db[k] == pytest.approx(da[wb], rel=1e-9), f"{a}->{b} class {c}: key off the path"
            checked += 1
    assert checked >= 10


def test_upm_path_graph_memory_grows_with_edges_not_edges_times_neurons(clips, model):
    # The path graph needs one length per edge, O(E * D) memory (under 1 MB here). Measuring
    # each edge's first neuron against every neuron builds an E x n x D array: 180 MB for this
    # small map, gigabytes and about 10 s per transition() call on the map of all bandai1.
    import tracemalloc

    engine = TransitionEngine(model)
    engine.add("a", clips[WALK])
    engine.add("b", clips[RUN])
    engine.generate("a", "b", method="upm")  # imports and compiled kernels out of the way
    tracemalloc.start()
    try:
        engine.generate("a", "b", method="upm-path")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    sizes = [(m.n_neurons, len(m.edges_), m.weights_.shape[1]) for m in model.maps_]
    assert peak < 20e6, f"first upm-path call peaks at {peak / 1e6:.0f} MB; (neurons, edges, dims): {sizes}"


@pytest.mark.parametrize("alpha", [0.0, 0.5, 1.0])
def test_upm_valid_keys_lie_in_the_maps_valid_region(clips, model, alpha):
    # upm-valid keys are estimates projected into the valid region: within ACCEPT * R of their
    # nearest neuron (reported in last["neurons"]), class by class.
    space = model.space_
    engine = TransitionEngine(model)
    rng = np.random.default_rng(4)
    for a, b in PAIRS + [(DANCE, BOW)]:
        engine.add(a, clips[a])
        engine.add(b, clips[b])
        a_end = int(rng.integers(1, len(clips[a])))
        engine.generate(a, b, alpha=alpha, a_end=a_end, method="upm-valid")
        x = key_vector(model, engine.last["key"])
        for c, k in enumerate(engine.last["neurons"]):
            m = model.maps_[c]
            part = x[space.class_dims[c]]
            d = np.linalg.norm(wrap_diff(m.weights_, part, space.circular[space.class_dims[c]]), axis=1)
            assert k == int(np.argmin(d))
            assert d[k] <= ACCEPT * m.radius_ * (1 + 1e-9), f"{a}->{b} class {c}: {d[k]:.3f} > {ACCEPT} R"


@pytest.mark.parametrize("method", KEY_POSTURE)
def test_alpha_0_keys_lie_nearer_a_than_alpha_1_keys(clips, model, method):
    space = model.space_
    circ = space.circular
    rng = np.random.default_rng(7)
    pairs = PAIRS + [(DANCE, WALK), (BACK, BOW), (WALK, DANCE)]
    engine = TransitionEngine(model)
    for n in CLIPS:
        engine.add(n, clips[n])

    def dist(x, y):  # feature distance per class, summed
        d = wrap_diff(x, y, circ)
        return sum(np.linalg.norm(d[dims]) for dims in space.class_dims)

    for a, b in pairs:
        a_end = int(rng.integers(0, len(clips[a])))
        b_start = int(rng.integers(0, len(clips[b])))
        xa = model.encode(clips[a][a_end])[0]
        xb = model.encode(clips[b][b_start])[0]
        keys = {}
        for alpha in (0.0, 1.0):
            engine.generate(a, b, alpha=alpha, a_end=a_end, b_start=b_start, method=method)
            keys[alpha] = key_vector(model, engine.last["key"])
        assert dist(keys[0.0], xa) < dist(keys[1.0], xa), f"{a}[{a_end}] -> {b}[{b_start}]"
        assert dist(keys[1.0], xb) < dist(keys[0.0], xb), f"{a}[{a_end}] -> {b}[{b_start}]"


# -- smoothness -----------------------------------------------------------------------------
@pytest.mark.parametrize("method", METHODS)
def test_no_joint_turns_more_than_90_degrees_between_frames(clips, model, method):
    engine_cases = seam_cases(clips, seed=11, count=8)
    for a, b, a_end, b_start, length in engine_cases:
        out = transition(clips[a], clips[b], model, length=length, a_end=a_end, b_start=b_start,
                         alpha=0.5, method=method)
        rots = out.rotations[a_end: a_end + length + 2]  # A's last, the new frames, B's first
        turn = quat.angle_between(rots[1:], rots[:-1])
        worst = np.unravel_index(np.argmax(turn), turn.shape)
        assert turn.max() < np.pi / 2, (
            f"{a}[..{a_end}] -> {b}[{b_start}..], {length} frames: {out.skeleton.names[worst[1]]} "
            f"turns {np.degrees(turn.max()):.0f} deg after frame {worst[0]}")


# Seam bounds. A transition has to move between two different postures, often faster or slower
# than either clip near the seam (bow -> dance: the dance starts at rest while the arms must
# travel), so the clips alone cannot bound it. A seam is continuous when it stands out from
# neither side: the step across it (C0) is at most 1.5x the largest step of the 10 clip frames
# beside it or of the new frames, and the change of velocity across it (C1) at most 2x the
# largest such change there. A pop or a velocity kink is exactly one step or acceleration that
# stands out. Measured on these cases: steps <= 1.04x, velocity changes <= 1.7x (upm-valid); a
# hard cut gives 7x to 41x (test_seam_bound_catches_a_hard_cut). slerp matches no velocities by
# design (its velocity changes reach 25x to 42x here), so only its C0 is checked.
STEP_BOUND = 1.5
ACC_BOUND = 2.0


@pytest.mark.parametrize("method", METHODS)
def test_seams_are_continuous_in_position_and_velocity(clips, model, method):
    for a, b, a_end, b_start, length in seam_cases(clips, seed=3, count=10):
        out = transition(clips[a], clips[b], model, length=length, a_end=a_end, b_start=b_start,
                         method=method)
        r = seam_ratios(*around_seams(out, a_end, length))
        where = f"{a}[..{a_end}] -> {b}[{b_start}..], {length} frames: " + \
            ", ".join(f"{k} {v:.2f}" for k, v in r.items())
        assert r["step_a"] <= STEP_BOUND and r["step_b"] <= STEP_BOUND, where
        if method != "slerp":
            assert r["acc_a"] <= ACC_BOUND and r["acc_b"] <= ACC_BOUND, where


def test_seam_bound_catches_a_hard_cut(clips, model):
    # The same measure on A followed directly by (aligned) B must flag the cut.
    flagged = 0
    for a, b in PAIRS:
        ta = clips[a]
        out = transition(ta, clips[b], model, length=20, method="spline")
        b_part = out[len(ta) + 20:]
        cut = concatenate([ta, b_part])
        g = cut[len(ta) - WINDOW - 1: len(ta) + WINDOW + 1].global_positions()
        step = np.linalg.norm(np.diff(g, axis=0), axis=-1).max(axis=-1)
        flagged += step[WINDOW] > STEP_BOUND * max(step[:WINDOW].max(), step[WINDOW + 1:].max())
    assert flagged == len(PAIRS)


# -- root alignment ----------------------------------------------------------------------------
def test_no_align_keeps_b_exactly(clips, model):
    for method in METHODS:
        for (a, b), (a_end, b_start) in zip(PAIRS, [(None, 0), (60, 300), (10, 7)]):
            out = transition(clips[a], clips[b], model, length=15, a_end=a_end, b_start=b_start,
                             align=False, method=method)
            last = len(clips[a]) - 1 if a_end is None else a_end
            tail = out[last + 16:]
            assert np.array_equal(tail.rotations, clips[b].rotations[b_start:]), (method, a, b)
            assert np.array_equal(tail.positions, clips[b].positions[b_start:]), (method, a, b)


@pytest.mark.parametrize("a, b, a_end, b_start, length", [
    (WALK, RUN, None, 0, 20), (RUN, BACK, 15, 5, 12), (WALK, RUN, 120, 4, 10),
    (DANCE, WALK, 700, 30, 25), (BACK, DANCE, 20, 400, 8),
])
def test_alignment_makes_b_continue_a(clips, a, b, a_end, b_start, length, model):
    ca, cb = clips[a], clips[b]
    out = transition(ca, cb, model, length=length, a_end=a_end, b_start=b_start, method="spline")
    i0 = len(ca) - 1 if a_end is None else a_end
    i1 = i0 + 1 + length
    d = length + 1.0
    rest = model.space_.rest
    pos_o, head_o, tilt_o = root_state(out, rest)
    pos_a, head_a, _ = root_state(ca, rest)
    pos_b, head_b, tilt_b = root_state(cb, rest)
    n_b = len(cb) - b_start

    # B is moved rigidly: one turn about up and one shift for all of its frames.
    dtheta = wrap(head_o[i1] - head_b[b_start])
    np.testing.assert_allclose(wrap(head_o[i1:] - head_b[b_start:] - dtheta), 0.0, atol=1e-9)
    turned = about_up(pos_b[b_start:], dtheta)
    shift = pos_o[i1] - turned[0]
    assert abs(shift[UP]) < 1e-9, "alignment must not move B up or down"
    np.testing.assert_allclose(pos_o[i1:], turned + shift, atol=1e-6)
    assert np.max(quat.angle_between(tilt_o[i1:], tilt_b[b_start:])) < 1e-6
    below = list(range(cb.skeleton.index("Hips") + 1, cb.skeleton.num_joints))
    assert np.array_equal(out.rotations[i1:, below], cb.rotations[b_start:, below])
    assert len(out) - i1 == n_b

    # B starts where A's root gets to, moving at the mean of the two seam velocities (B's
    # turned with it), and faces A's last heading advanced by the mean turning rate.
    v_a = horizontal(pos_a[i0] - pos_a[i0 - 1])
    v_b = about_up(horizontal(pos_b[b_start + 1] - pos_b[b_start]), dtheta)
    np.testing.assert_allclose(horizontal(pos_o[i1] - pos_o[i0]), 0.5 * (v_a + v_b) * d, atol=1e-6)
    w_a = head_a[i0] - head_a[i0 - 1]
    w_b = head_b[b_start + 1] - head_b[b_start]
    assert abs(wrap(head_o[i1] - head_o[i0] - 0.5 * (w_a + w_b) * d)) < 1e-6


def ground_offset(g: np.ndarray) -> np.ndarray:
    """Horizontal distance (F,) from joint_Root to the point of the floor under Hips."""
    d = g[:, 0] - g[:, 1]
    d[:, UP] = 0.0
    return np.linalg.norm(d, axis=1)


@pytest.mark.parametrize("method", ["auto", "slerp", "damped"])
def test_a_root_bone_that_carries_root_motion_is_placed_with_the_body(clips, model, method):
    # run_normal_001's and walk-back_normal_001's joint_Root run with the body, 0-6 cm from the
    # floor under Hips (root motion, as a game rig's root bone): B is placed with it, and the new
    # frames take it there, smoothly and near the body.
    ca, cb = clips[RUN], clips[BACK]
    engine = TransitionEngine(model)
    assert engine.add("run", ca).carrier == 0 and engine.add("back", cb).carrier == 0
    assert engine.add("walk", clips[WALK]).carrier == -1
    a_end, b_start, length = 15, 5, 20
    i1 = a_end + 1 + length
    out = transition(ca, cb, model, length=length, a_end=a_end, b_start=b_start, method=method)
    g = out.global_positions()
    # The body is where it is when the same motion is carried by Hips alone under a fixed node.
    still = np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3)
    ref = transition(under_node(ca, *still), under_node(cb, *still), model, length=length, a_end=a_end,
                     b_start=b_start, method=method).global_positions()
    assert np.abs(g[:, 1:] - ref[:, 1:]).max() < 1e-5
    # B as recorded below its root bone: placed whole.
    hips = ca.skeleton.index("Hips")
    assert np.abs(np.abs(np.sum(out.rotations[i1:, hips] * cb.rotations[b_start:, hips], axis=-1)) - 1).max() < 1e-9
    assert np.abs(out.positions[i1:, hips] - cb.positions[b_start:, hips]).max() < 1e-6
    np.testing.assert_allclose(ground_offset(g)[i1:], ground_offset(cb.global_positions())[b_start:], atol=1e-6)
    # Through the gap the root bone keeps near the body (before, B's stayed where B was recorded,
    # metres off; a plain cubic from seam to seam strays 32 cm here) and moves more smoothly
    # than the pelvis over the floor.
    seams = max(ground_offset(g)[a_end], ground_offset(g)[i1])
    assert ground_offset(g)[a_end + 1: i1].max() < seams + 12.0
    floor = g[:, 1].copy()
    floor[:, UP] = 0.0
    acc = lambda p: np.linalg.norm(np.diff(p, 2, axis=0), axis=1)
    assert acc(g[:, 0]).max() <= acc(floor).max()
    # It turns from A's heading to B's placed one evenly: no frame takes a fifth of the way.
    turn = out.rotations[:, 0]
    step = quat.angle_between(turn[1:], turn[:-1])
    assert step.max() <= quat.angle_between(turn[a_end], turn[i1]) / 5 + 1e-9


def test_in_betweening_that_falls_back_keeps_a_root_bone_on_the_bodys_course(clips, model, monkeypatch):
    # The legs not retrieved at all (confidence forced to 0): in in-betweening the fallback's root
    # runs on the seams' path, and walk-back_normal_001's joint_Root, which carries its root
    # motion, takes the spline's course with it instead of damped's straight one.
    from posturemap.synth import retrieval

    back = clips[BACK]
    # joint_Root bowed 20 cm sideways over the clip and turning up to 0.3 rad with it (Hips under
    # it where it was): a curved course.
    rots, pos = back.rotations.copy(), back.positions.copy()
    arc = np.sin(np.pi * np.arange(len(back)) / (len(back) - 1))
    gq, gp = quat.mul(rots[:, 0], rots[:, 1]), pos[:, 0] + quat.mul_vec(rots[:, 0], pos[:, 1])
    rots[:, 0] = quat.mul(quat.from_axis_angle(up_vec(), 0.3 * arc), rots[:, 0])
    pos[:, 0, 0] += 20.0 * arc
    inv = quat.inv(rots[:, 0])
    rots[:, 1], pos[:, 1] = quat.mul(inv, gq), quat.mul_vec(inv, gp - pos[:, 0])
    back = Motion(back.skeleton, rots, pos, back.fps)
    monkeypatch.setattr(retrieval, "confidences", lambda *a, **k: [0.0, 0.0])
    kw = dict(length=20, a_end=5, b_start=26, align=False, foot_lock=False)
    engine = TransitionEngine(model)
    engine.add("back", back)
    rots, pos = (x.copy() for x in engine.generate("back", "back", method="retrieval", **kw))
    assert engine.last["retrieval"]["confidence"] == 0.0
    spline_r, spline_p = (x.copy() for x in engine.generate("back", "back", method="spline", **kw))
    np.testing.assert_allclose(pos[:, 0], spline_p[:, 0], rtol=0, atol=1e-9)
    same_rotation = np.abs(np.sum(rots[:, 0] * spline_r[:, 0], axis=-1))
    np.testing.assert_allclose(same_rotation, 1.0, rtol=0, atol=1e-12)
    damped_r, damped_p = engine.generate("back", "back", method="damped", **kw)
    assert np.abs(damped_p[:, 0] - spline_p[:, 0]).max() > 1.0  # a course of its own
    # The body keeps the fallback's turn: only its place over the floor moves with the root.
    hips = back.skeleton.index("Hips")
    body = fk(back.skeleton.parents, rots, pos)[0][:, hips]
    fallback = fk(back.skeleton.parents, damped_r, damped_p)[0][:, hips]
    np.testing.assert_allclose(np.abs(np.sum(body * fallback, axis=-1)), 1.0, rtol=0, atol=1e-9)
    out = concatenate([back[:6], Motion(back.skeleton, rots, pos, back.fps), back[26:]])
    off = ground_offset(out.global_positions()) - ground_offset(back.global_positions())
    assert np.abs(off[6:26]).max() < 5.0  # off the body by what the clip's own bone is, within 5 cm


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("align", [True, False])
@pytest.mark.parametrize("method", ["spline", "damped", "retrieval", "retrieval-confident"])
def test_a_root_bone_half_a_turn_from_b_turns_on_without_spinning(clips, model, compiled, align, method,
                                                                   monkeypatch):
    # walk-back_normal_001's joint_Root (it carries the clip's root motion) turning steadily
    # about up (0.6 rad/s) through half a turn from where B's is put, the body held under it
    # where it was, A's last frame just past the half turn: its rate at A's seam is its own
    # step, not nearly a whole turn (the short arcs of A's last two frames point opposite ways),
    # and it turns on the way it turned, in even steps, onto B. In-betweening (B where it is)
    # and a transition (B placed with its root bone; the half turn is taken from where it is
    # placed, which A's root bone does not move: the body under it stays). Retrieval fully
    # confident leaves the root bone to a cubic of its own (engine._open_columns).
    from posturemap.synth import retrieval

    if method == "retrieval-confident":
        monkeypatch.setattr(retrieval, "confidences", lambda *a, **k: [1.0, 1.0])
        method = "retrieval"
    back = clips[BACK]
    length, a_end = 12, 10
    b_start = a_end + length + 1

    def turning(base):
        rots, pos = back.rotations.copy(), back.positions.copy()
        gq, gp = quat.mul(rots[:, 0], rots[:, 1]), pos[:, 0] + quat.mul_vec(rots[:, 0], pos[:, 1])
        angle = base + np.pi + 0.01 + 0.02 * (np.arange(len(back)) - a_end)
        angle[b_start:] = 0.0
        rots[:, 0] = quat.mul(quat.from_axis_angle(up_vec(), angle), rots[:, 0])
        inv = quat.inv(rots[:, 0])
        rots[:, 1], pos[:, 1] = quat.mul(inv, gq), quat.mul_vec(inv, gp - pos[:, 0])
        engine = TransitionEngine(model)
        assert engine.add("back", Motion(back.skeleton, rots, pos, back.fps)).carrier == 0
        with contextlib.nullcontext() if compiled else kernels.numpy_backend():
            r, _ = engine.generate("back", "back", length=length, a_end=a_end, b_start=b_start, align=align,
                                   method=method, foot_lock=False)
            placed = engine.continuation("back", b_start, align=align).rotations[:2, 0]
        return np.concatenate([rots[a_end - 1: a_end + 1, 0], r[:, 0], placed])

    first = turning(0.0)
    base = quat.log(quat.mul(first[-2], quat.inv(back.rotations[b_start, 0])))[UP]  # where B's was put
    turn = turning(base)
    np.testing.assert_allclose(np.abs(np.sum(turn[-2:] * first[-2:], axis=-1)), 1.0, atol=1e-9)
    steps = quat.angle_between(turn[1:], turn[:-1])
    assert steps.max() < 3 * np.pi / length, np.degrees(steps)
    about_up = quat.log(quat.mul(turn[1:], quat.inv(turn[:-1])))[:, UP]
    assert np.all(about_up > -1e-3), np.degrees(about_up)


@pytest.mark.parametrize("compiled", [True, False])
def test_b_is_placed_the_way_round_a_blended_root_went(clips, model, compiled, monkeypatch):
    # The legs half confident: the root is the blend of the retrieved one and the fallback's,
    # on the arc that goes on through the frames, and B is placed by the blend of their
    # placements. Here the fallback's root makes a whole extra turn about up through the gap (it
    # ends where it would have), so the two roots pass a half turn apart and the blend goes on
    # round: B must be placed the way round it went, half a turn from where the short way
    # would put it. Placed the short way (as before), the root turned about a half turn in the
    # one frame into B (on LaFAN1, a walk into a stumble, 37 degrees).
    from posturemap.synth import engine as engine_module, retrieval

    monkeypatch.setattr(retrieval, "confidences", lambda *a, **k: [0.5, 0.5])
    interpolated = engine_module._interpolated

    def spinning(eng, *args, **kw):
        rots, pos = interpolated(eng, *args, **kw)
        rots, chain = rots.copy(), eng._chain.tolist()
        spin = quat.from_axis_angle(up_vec(), 2 * np.pi * np.arange(1, len(rots) + 1) / len(rots))
        parent = chain_world(chain, rots, pos)[0] if chain else np.array([1.0, 0.0, 0.0, 0.0])
        world = quat.mul(parent, rots[:, eng._root])
        rots[:, eng._root] = quat.mul(quat.inv(parent), quat.mul(spin, world))
        return rots, pos

    monkeypatch.setattr(engine_module, "_interpolated", spinning)
    walk, length, a_end, b_start = clips[WALK], 12, 40, 70
    engine = TransitionEngine(model)
    engine.add("walk", walk)
    with contextlib.nullcontext() if compiled else kernels.numpy_backend():
        r, p = engine.generate("walk", "walk", length=length, a_end=a_end, b_start=b_start, method="retrieval",
                               foot_lock=False)
        placed = engine.continuation("walk", b_start)
    assert engine.last["retrieval"]["confidence"] == 0.5  # the blend ran
    chain = engine._chain.tolist() + [engine._root]
    world = np.concatenate([chain_world(chain, r, p)[0], chain_world(chain, placed.rotations[:2], placed.positions[:2])[0]])
    steps = quat.angle_between(world[1:], world[:-1])
    # The gap turns the body some 15 degrees a frame (half the fallback's 30); into B no more.
    assert steps[-2] < 1.5 * steps[:-2].max() + 0.05, np.degrees(steps)


@pytest.mark.parametrize("with_map", [True, False])
def test_an_interpolating_methods_foot_lock_straightens_a_knee_bent_backward_first(bandai_paths, model, with_map):
    # Between two sideways walks the spline bends a knee about 34 degrees backward; the foot
    # lock bends a knee in its own plane, so it bent that one on backward and swung it round
    # through straight: 102 degrees in a frame (inertialization's 77), where the unlocked spline
    # turns it 19. The knees are now turned onto their bound first, as the default's are: by
    # the library's hinges, or without a map by the clips' own (their kept frames).
    from posturemap.core.joints import leg_chains

    paths = bandai_paths(("walk-right_active_001", "walk-right_tired_001"))
    a, b = (bvh.read(paths[n]) for n in ("walk-right_active_001", "walk-right_tired_001"))
    legs = [j for chain in leg_chains(a.skeleton) for j in chain]
    n = 66
    for method in ("spline", "inertialize"):
        steps = {}
        for lock in (False, True):
            out = transition(a, b, model if with_map else None, length=30, method=method, a_end=n, foot_lock=lock)
            q = out.rotations[n: n + 32, legs]
            steps[lock] = np.degrees(quat.angle_between(q[1:], q[:-1])).max()
        assert steps[False] < 30.0 and steps[True] < steps[False] + 15.0, (method, steps)


@pytest.mark.parametrize("length, method", [(20, "retrieval"), (20, "auto"), (5, "auto"), (20, "damped"),
                                            (5, "spline")])
def test_no_new_knee_bends_backward_past_the_librarys(clips, model, length, method, monkeypatch):
    # The interpolation under the default (retrieval's fallback: the spline on short gaps)
    # made to bend the left knee 40 degrees backward in the middle of the gap, as damped did
    # carrying a dash's knee on past straight: retrieval and auto turn it forward onto the
    # library's bound (its knees never go past straight by more than a hair), in its plane,
    # the turn fading in before and out after it, the hip turning the leg so the ankle keeps
    # its line from it, and change nothing else; the interpolating methods themselves are left
    # as they are.
    from posturemap.synth import engine as engine_module, hinges, retrieval
    from posturemap.core.joints import leg_chains

    monkeypatch.setattr(retrieval, "confidences", lambda *a, **k: [0.0, 0.0])
    interpolated = engine_module._interpolated
    sk = model.skeleton_
    thigh, shin, ankle = leg_chains(sk)[0]
    lib = model.library_
    (path, hinge, least, _), _ = hinges.find(sk.parents, leg_chains(sk), lib.rots, sk.offsets)
    assert np.degrees(least) > -1.0
    made = {}

    def bent_back(eng, *args, **kw):
        rots, pos = interpolated(eng, *args, **kw)
        rots = rots.copy()
        t, sh = hinges.leg_vectors(rots, pos, path)
        bend = hinges.signed_bends(t, sh, hinge)
        mid = slice(len(rots) // 3, 2 * len(rots) // 3 + 1)
        # About the hinge (in the shin's parent's frame), back to 40 degrees past straight.
        axis = np.broadcast_to(hinge, (len(bend[mid]), 3))
        rots[mid, shin] = quat.mul(quat.from_axis_angle(axis, bend[mid] + np.radians(40.0)), rots[mid, shin])
        made["rots"], made["pos"] = rots.copy(), pos.copy()
        return rots, pos

    monkeypatch.setattr(engine_module, "_interpolated", bent_back)
    for m in ("damped", "spline"):
        monkeypatch.setitem(engine_module._RUN, m, bent_back)
    engine = TransitionEngine(model)
    engine.add("walk", clips[WALK])
    r, p = engine.generate("walk", "walk", length=length, a_end=40, b_start=40 + length + 12, method=method,
                           foot_lock=False)
    t, sh = hinges.leg_vectors(made["rots"], made["pos"], path)
    made_bend = hinges.signed_bends(t, sh, hinge)
    assert made_bend.min() < np.radians(-35.0)  # the knee was bent backward
    t, sh = hinges.leg_vectors(r, p, path)
    bend = hinges.signed_bends(t, sh, hinge)
    back = made_bend < least
    if method in ("damped", "spline"):
        np.testing.assert_array_equal(r, made["rots"])
        return
    # Forward only, none past the bound, each frame's knee accelerating within the bound
    # (UNBEND_ACCEL) or the made motion's own, larger there: a knee thrown 40 degrees back in a
    # frame is held on the bound through it rather than pushed off it, and the turn fades in
    # before the bound where the motion nears it steadily.
    assert bend.min() >= least - 1e-7
    assert np.all(bend >= made_bend - 1e-9)
    turned = bend - made_bend > 1e-9
    assert turned[back].all()
    if length == 20:
        accel = hinges.UNBEND_ACCEL / clips[WALK].fps ** 2
        assert np.all(np.abs(np.diff(bend, 2)) <= np.maximum(accel, np.abs(np.diff(made_bend, 2))) * 1.002)
    others = np.ones(sk.num_joints, dtype=bool)
    others[[thigh, shin]] = False
    np.testing.assert_array_equal(r[:, others], made["rots"][:, others])
    # The hip turned the straightened leg onto the line from the hip to where the ankle was.
    _, made_g = fk(sk.parents, made["rots"], made["pos"])
    _, g = fk(sk.parents, r, p)
    reach0, reach = made_g[turned, ankle] - made_g[turned, thigh], g[turned, ankle] - g[turned, thigh]
    np.testing.assert_allclose(np.cross(reach, reach0 / np.linalg.norm(reach0, axis=-1, keepdims=True)), 0.0,
                               atol=1e-6)
    assert np.all(np.sum(reach * reach0, axis=-1) > 0.0)


def test_a_root_bone_under_a_fixed_node_is_placed_and_the_node_stays(clips):
    # A conversion node (a quarter turn about X, off the origin) above the moving joint_Root: the
    # node stays where it is, and joint_Root and the body go where they go without it.
    node = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.array(-np.pi / 2)), np.array([30.0, 5.0, -20.0])
    ca, cb = clips[RUN], clips[BACK]
    ta, tb = topped(ca, *node), topped(cb, *node)
    model = PostureMap(seed=0).fit([ca, cb], ["run", "back"])
    topped_model = PostureMap(seed=0).fit([ta, tb], ["run", "back"])
    for method in ("spline", "auto"):
        kw = dict(length=20, a_end=15, b_start=5, method=method)
        ref = transition(ca, cb, model, **kw).global_positions()
        out = transition(ta, tb, topped_model, **kw)
        np.testing.assert_allclose(out.rotations[:, 0], np.broadcast_to(node[0], (len(out), 4)), rtol=0, atol=1e-12)
        np.testing.assert_allclose(out.positions[:, 0], np.broadcast_to(node[1], (len(out), 3)), rtol=0, atol=1e-9)
        assert np.abs(out.global_positions()[:, 1:] - ref).max() < 1e-4, method
    engine = TransitionEngine(topped_model)
    engine.add("a", ta)
    engine.add("b", tb)
    engine.generate("a", "b", length=20, a_end=15, b_start=5)
    joint, q, t = engine.placement("b", engine.last["dtheta"], engine.last["shift"])
    assert joint == 1  # joint_Root, under the node
    rots, pos = tb.rotations[5:].copy(), tb.positions[5:].copy()
    rots[:, 1], pos[:, 1] = quat.mul(q, rots[:, 1]), quat.mul_vec(q, pos[:, 1]) + t
    shown = Motion(tb.skeleton, rots, pos, tb.fps).global_positions()
    assert np.abs(shown - engine.continuation("b", 5).global_positions()).max() < 1e-6


def test_a_single_frame_b_on_a_root_motion_rig_is_placed_with_its_root_bone(clips, model):
    # One frame shows no root motion: it takes the rig's, which the run shows (a pose to reach).
    ca, pose = clips[RUN], clips[BACK][5:6]
    engine = TransitionEngine(model)
    assert engine.add("pose", pose).carrier == -1
    out = transition(ca, pose, model, length=20, a_end=15)
    g = out.global_positions()
    assert ground_offset(g)[-1] == pytest.approx(ground_offset(pose.global_positions())[0], abs=1e-6)
    assert ground_offset(g)[16:-1].max() < 15.0  # it stayed at B's recorded place, 200 cm off


def test_a_node_stored_at_float32_is_fixed(clips):
    walk = clips[WALK]
    rots = walk.rotations.copy()
    rots[:, 0] = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), np.array(2.0)).astype(np.float32)
    assert np.sum(rots[0, 0] ** 2) < 1.0 - 1e-8  # shorter than a unit at double precision
    engine = TransitionEngine()
    assert engine.add("walk", Motion(walk.skeleton, rots, walk.positions, walk.fps)).carrier == -1


def test_a_fixed_reference_node_stays_put_and_placement_says_how_b_moved(clips, model):
    # walk_normal_001's joint_Root stays at the origin: B's stays where it is, and the root is
    # placed under it. engine.placement gives that as one joint's change (the studio page's),
    # also under a node that is turned and moved (a Z-up file's conversion node).
    turned = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.array(-np.pi / 2)), np.array([30.0, 5.0, -20.0])
    for b, moves in ((clips[WALK], False), (under_node(clips[WALK], *turned), False), (clips[BACK], True)):
        engine = TransitionEngine(model)
        engine.add("a", clips[RUN])
        engine.add("b", b)
        engine.generate("a", "b", length=20, a_end=15, b_start=5, method="spline")
        placed = engine.continuation("b", 5)
        if not moves:
            assert np.array_equal(placed.rotations[:, 0], b.rotations[5:, 0])
            assert np.array_equal(placed.positions[:, 0], b.positions[5:, 0])
        joint, q, t = engine.placement("b", engine.last["dtheta"], engine.last["shift"])
        assert joint == (0 if moves else b.skeleton.index("Hips"))
        rots, pos = b.rotations[5:].copy(), b.positions[5:].copy()
        rots[:, joint], pos[:, joint] = quat.mul(q, rots[:, joint]), quat.mul_vec(q, pos[:, joint]) + t
        shown = Motion(b.skeleton, rots, pos, b.fps).global_positions()
        assert np.abs(shown - placed.global_positions()).max() < 1e-6


def test_the_seams_path_follows_a_curving_walk():
    # A root walking a circle of 1.5 m radius at 1.5 m/s (30 fps), swaying 3 cm from side to
    # side at the step's rate: over a 1.5 s gap the seams' path (the fallback's root where B
    # stays) keeps to the arc within 10 cm, where the straight line between the seams, which
    # damped's root follows after its first 0.05 s, cuts 40 cm into it.
    from types import SimpleNamespace

    fps, radius, speed = 30.0, 150.0, 150.0
    t = np.arange(200) / fps
    angle = speed * t / radius
    arc = np.stack([radius * np.sin(angle), np.zeros_like(t), radius * (1.0 - np.cos(angle))], axis=1)
    side = np.stack([-np.sin(angle), np.zeros_like(t), np.cos(angle)], axis=1)
    gpos = arc + 3.0 * np.sin(2 * np.pi * 1.8 * t)[:, None] * side
    track = SimpleNamespace(gpos=gpos, motion=SimpleNamespace(fps=fps))
    a_end, length = 60, 44
    b_start = a_end + length + 1
    path = trajectory.seam_path(track, track, a_end, b_start, length, UP)
    assert np.all(path[:, UP] == 0.0)
    s = np.linspace(0.0, 1.0, length + 2)[1:-1, None]
    chord = (1.0 - s) * gpos[a_end] + s * gpos[b_start]
    gap = slice(a_end + 1, b_start)
    off = lambda p: np.linalg.norm((p - arc[gap])[:, [0, 2]], axis=1).max()
    assert off(chord) > 35.0
    assert off(path) < 10.0


def test_the_seams_path_over_a_long_gap_carries_a_sway_briefly_and_a_walk_on():
    # Over a gap longer than SEAM_HERMITE_S a seam's velocity is its average over its last
    # (first) second, the two frames' own fading within SEAM_FADE_S: a performer swaying 3 cm
    # from side to side in place stays within a few cm of their place through a 5 s gap, where
    # the cubic through the seams' two-frame velocities swings 15 cm and more away; a steady
    # straight walk stays on its line; the first and last new frames move on with the seams' step.
    from types import SimpleNamespace

    fps = 30.0
    t = np.arange(400) / fps
    sway = np.zeros((len(t), 3))
    sway[:, 2] = 3.0 * np.sin(2 * np.pi * 1.8 * t)
    a_end = 100
    for length in (149, 174):  # 5 and 5.8 s, A's last and B's first frame swaying at full speed
        b_start = a_end + length + 1
        track = SimpleNamespace(gpos=sway, motion=SimpleNamespace(fps=fps))
        path = trajectory.seam_path(track, track, a_end, b_start, length, UP)
        cubic = trajectory.through_seams(sway[[a_end - 1, a_end, b_start, b_start + 1]], length)
        assert np.abs(cubic[:, 2]).max() > 15.0
        assert np.abs(path[:, [0, 2]]).max() < 5.0
        # The seams' own step carried into the first and last new frames (slowing: it fades).
        for first, seam in (((path[0] - sway[a_end]), sway[a_end] - sway[a_end - 1]),
                            ((sway[b_start] - path[-1]), sway[b_start + 1] - sway[b_start])):
            assert abs(seam[2]) > 1.0 and 0.5 < first[2] / seam[2] <= 1.0 and first[0] == 0.0
    # Sides with less than SEAM_AVERAGE_S of their own frames (the bench's 10 context frames)
    # keep their last step's velocity: the cubic.
    short = SimpleNamespace(gpos=sway[:10 + 150 + 10], motion=SimpleNamespace(fps=fps))
    path = trajectory.seam_path(short, short, 9, 160, 150, UP)
    np.testing.assert_allclose(path[:, [0, 2]], trajectory.through_seams(sway[[8, 9, 160, 161]], 150)[:, [0, 2]],
                               atol=1e-12)
    # At 0.4 fps a second is under a frame: a side with no frame before its seam (A's first
    # frame) or none after it (B's last) keeps its step, and no frame beyond the clip is read.
    coarse = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0], [50, 0, 50]])
    track = SimpleNamespace(gpos=coarse, motion=SimpleNamespace(fps=0.4))
    for a, b in ((0, 2), (3, 5)):
        np.testing.assert_allclose(trajectory.seam_path(track, track, a, b, 1, UP)[:, [0, 2]], trajectory.through_seams(
            coarse[[max(a - 1, 0), a, b, min(b + 1, 5)]], 1)[:, [0, 2]], atol=1e-12)
    walk = np.stack([120.0 * t, np.zeros_like(t), 40.0 * t], axis=1)
    track = SimpleNamespace(gpos=walk, motion=SimpleNamespace(fps=fps))
    path = trajectory.seam_path(track, track, a_end, a_end + 150, 149, UP)
    np.testing.assert_allclose(path, walk[a_end + 1:a_end + 150] * [1, 0, 1], atol=1e-9)
    # Up to SEAM_HERMITE_S, the cubic itself.
    length = int(trajectory.SEAM_HERMITE_S * fps) - 1
    path = trajectory.seam_path(track, track, a_end, a_end + length + 1, length, UP)
    np.testing.assert_array_equal(path[:, [0, 2]], trajectory.through_seams(
        walk[[a_end - 1, a_end, a_end + length + 1, a_end + length + 2]], length)[:, [0, 2]])


def test_alignment_faces_b_the_way_a_walks(clips, model):
    # Walk and run both go straight ahead. Aligned, the runner keeps the walker's direction of
    # travel (within 15 degrees) and starts about 21 frames of travel ahead of the walker;
    # without alignment it runs where it was captured, 300+ cm from the walk's end.
    a, b = clips[WALK], clips[RUN]
    i0, i1 = len(a) - 1, len(a) + 20
    for align in (True, False):
        out = transition(a, b, model, length=20, align=align, method="spline")
        pos, _, _ = root_state(out)
        travel_a = horizontal(pos[i0] - pos[i0 - 10]) / 10
        travel_b = horizontal(pos[i1 + 10] - pos[i1]) / 10
        cos = travel_a @ travel_b / (np.linalg.norm(travel_a) * np.linalg.norm(travel_b))
        gap = np.linalg.norm(horizontal(pos[i1] - pos[i0]))
        if align:
            assert cos > math.cos(math.radians(15))
            speeds = sorted([np.linalg.norm(travel_a), np.linalg.norm(travel_b)])
            assert 21 * 0.8 * speeds[0] < gap < 21 * 1.2 * speeds[1]
        else:
            assert gap > 300.0


def test_alignment_faces_a_heading_even_when_a_ends_bent(clips, model):
    # Facing measured physically: the horizontal direction of the hip line (left thigh joint
    # minus right). Ending a bow upright or at its deepest bend, the aligned walk must face
    # where the bowing body faces (10 degrees allowed for the carried turning and for the hip
    # line's own sway; the walk's first frames turn by under 1 degree per frame).
    bow, walk = clips[BOW], clips[WALK]
    sk = bow.skeleton
    left, right, head = sk.index("UpperLeg_L"), sk.index("UpperLeg_R"), sk.index("Head")

    def facing(m):
        g = m.global_positions()
        v = g[:, left] - g[:, right]
        return np.degrees(np.arctan2(v[:, (UP + 2) % 3], v[:, (UP + 1) % 3])), g

    _, g_bow = facing(bow)
    deepest = int(np.argmin(g_bow[:, head, UP]))  # the head lowest: the deepest bend
    assert 20 < deepest < len(bow) - 20
    for mdl in (None, model):
        for a_end in (0, deepest, len(bow) - 1):
            out = transition(bow, walk, mdl, length=20, a_end=a_end, method="spline")
            f, _ = facing(out[[a_end, a_end + 21]])
            turn = (f[1] - f[0] + 180) % 360 - 180
            assert abs(turn) < 10, (f"bow ending at frame {a_end} ({'map' if mdl else 'no map'}): "
                                    f"the walk faces {turn:.0f} deg away")


# -- every method, arguments, errors -------------------------------------------------------------
@pytest.mark.parametrize("method", METHODS)
def test_every_method_runs_with_finite_output(clips, model, method):
    for a, b in PAIRS:
        outs = []
        for alpha in (0.0, 0.5, 1.0):
            out = transition(clips[a], clips[b], model, alpha=alpha, method=method)
            assert len(out) == len(clips[a]) + 20 + len(clips[b])
            assert np.all(np.isfinite(out.rotations)) and np.all(np.isfinite(out.positions))
            np.testing.assert_allclose(np.linalg.norm(out.rotations, axis=-1), 1.0, atol=1e-9)
            assert np.array_equal(out.rotations[: len(clips[a])], clips[a].rotations)
            outs.append(out.rotations[len(clips[a]): len(clips[a]) + 20])
        # alpha steers the methods that have a key (or a retrieval seam weighting), nothing else.
        if method in KEY_POSTURE:
            assert not np.allclose(outs[0], outs[2]), (method, a, b)
        elif method not in KEYED:
            assert np.array_equal(outs[0], outs[1]) and np.array_equal(outs[0], outs[2]), (method, a, b)


@pytest.mark.parametrize("method", sorted(set(METHODS) - set(KEYED)))
def test_methods_without_a_key_need_no_map(clips, model, method):
    a, b = clips[WALK], clips[RUN]
    out = transition(a, b, None, method=method, foot_lock=False)
    assert len(out) == len(a) + 20 + len(b)
    new = out[len(a): len(a) + 20]
    # Joints below the root: slerp goes from A's last to B's first frame along the shortest arc;
    # spline and inertialize start from A's last frame and end in B's first.
    sk = a.skeleton
    joints = [j for j in range(sk.num_joints) if sk.parents[j] >= 0 and j != sk.index("Hips")
              and sk.index("Hips") in ancestors_and_self(sk.parents, j)]
    # Without a map, the same joints below the root as with one (the map's upright rest pose
    # only changes how the root is split into heading and tilt).
    with_map = transition(a, b, model, method=method, foot_lock=False)
    np.testing.assert_allclose(np.abs(quat.dot(with_map.rotations[:, joints], out.rotations[:, joints])), 1.0,
                               atol=1e-12)
    np.testing.assert_allclose(with_map.positions[:, joints], out.positions[:, joints], atol=1e-9)
    u = np.arange(1, 21) / 21.0
    qa = np.broadcast_to(a.rotations[-1, joints], (20, len(joints), 4))
    qb = np.broadcast_to(b.rotations[0, joints], (20, len(joints), 4))
    if method == "slerp":
        expected = quat.slerp(qa, qb, np.broadcast_to(u[:, None], (20, len(joints))))
        got = new.rotations[:, joints]
        np.testing.assert_allclose(got * np.sign(quat.dot(got, expected))[..., None], expected, atol=1e-9)
        np.testing.assert_allclose(new.positions[:, joints],  # local translations: straight lines
                                   a.positions[-1, joints] + u[:, None, None] * (b.positions[0, joints]
                                                                                - a.positions[-1, joints]),
                                   atol=1e-9)
    else:
        first = quat.angle_between(new.rotations[0, joints], a.rotations[-1, joints]).max()
        last = quat.angle_between(new.rotations[-1, joints], b.rotations[0, joints]).max()
        whole = quat.angle_between(a.rotations[-1, joints], b.rotations[0, joints]).max()
        assert first < 0.5 * whole and last < 0.5 * whole, (first, last, whole)


@pytest.mark.parametrize("method", KEYED)
def test_keyed_methods_without_a_map_raise(clips, method):
    with pytest.raises(UserError) as e:
        transition(clips[WALK], clips[RUN], None, method=method)
    assert e.value.field == "method" and method in str(e.value)
    engine = TransitionEngine(skeleton=clips[WALK].skeleton)
    engine.add("a", clips[WALK])
    engine.add("b", clips[RUN])
    with pytest.raises(UserError, match="needs a posture map"):
        engine.generate("a", "b", method=method)


@pytest.mark.parametrize("kwargs, field", [
    ({"a_end": 195}, "a_end"), ({"a_end": -1}, "a_end"),
    ({"b_start": 24}, "b_start"), ({"b_start": -3}, "b_start"),
    ({"key_at": 0}, "key_at"), ({"key_at": 21}, "key_at"),
    ({"length": 5, "key_at": 6}, "key_at"),
    ({"alpha": -0.01}, "alpha"), ({"alpha": 1.5}, "alpha"), ({"alpha": float("nan")}, "alpha"),
    ({"alpha": "0.5"}, "alpha"), ({"alpha": True}, "alpha"), ({"length": 2.5}, "length"),
    ({"align": 1}, "align"), ({"foot_lock": None}, "foot_lock"),
    ({"method": "cubic"}, "method"), ({"length": 0}, "length"), ({"length": 10 ** 309}, "length"),
])
def test_argument_errors_name_the_field(clips, model, kwargs, field):
    assert (len(clips[WALK]), len(clips[RUN])) == (195, 24)  # the values above rely on these
    with pytest.raises(RequestError) as e:
        transition(clips[WALK], clips[RUN], model, **kwargs)
    assert e.value.field == field and str(e.value).startswith(field + ":")
    # The engine and a request object refuse it the same way, with the same words.
    with pytest.raises(RequestError) as e2:
        TransitionRequest(**kwargs).resolved(195, 24)
    assert str(e2.value) == str(e.value)


def test_one_set_of_defaults_for_the_api_the_engine_and_a_request(clips, model):
    # transition() with no options, the engine with no options and an explicit default request
    # make the same frames: one place holds the defaults.
    a, b = clips[WALK], clips[RUN]
    out = transition(a, b, model)
    engine = TransitionEngine(model)
    engine.add("a", a)
    engine.add("b", b)
    rots, pos = engine.generate("a", "b")
    req = TransitionRequest().resolved(len(a), len(b))
    assert (req.length, req.alpha, req.method, req.key_at, req.a_end, req.b_start, req.align, req.foot_lock) == \
        (20, 0.5, "auto", 10, len(a) - 1, 0, True, True)
    np.testing.assert_array_equal(out.rotations[len(a): len(a) + 20], rots)
    rots2, _ = engine.generate("a", "b", req)
    np.testing.assert_array_equal(rots2, out.rotations[len(a): len(a) + 20])


def test_different_skeletons_raise(clips, model, sample_clips):
    other = sample_clips["walk"]
    with pytest.raises(UserError, match="skeleton differs"):
        transition(clips[WALK], other, None, method="spline")
    with pytest.raises(UserError, match="skeleton differs"):
        transition(clips[WALK], other, model)
    with pytest.raises(UserError, match="skeleton differs from the map's"):
        transition(other, sample_clips["run"], model)  # both alike, but not the map's skeleton
    with pytest.raises(UserError, match="b: skeleton differs from the other clips'"):
        transition(clips[WALK], other, None, method="slerp")  # no map: B against A
    engine = TransitionEngine(model)
    with pytest.raises(UserError, match="skeleton differs"):
        engine.add("x", other)
    assert "x" not in engine.tracks


# -- the reusable engine ------------------------------------------------------------------------
def test_engine_reuses_buffers_and_matches_the_functional_api(clips, model):
    engine = TransitionEngine(model)
    for n in CLIPS:
        engine.add(n, clips[n])
    rng = np.random.default_rng(5)
    first = None
    for i, (a, b) in enumerate(PAIRS * 2):
        method = METHODS[i % len(METHODS)]
        a_end = int(rng.integers(1, len(clips[a])))
        b_start = int(rng.integers(0, len(clips[b]) - 1))
        alpha = float(rng.random())
        rots, pos = engine.generate(a, b, length=20, key_at=7, alpha=alpha, a_end=a_end, b_start=b_start, method=method, foot_lock=False)
        if first is None:
            first = (rots, pos)
        assert rots is first[0] and pos is first[1], "a call of the same length must reuse the buffers"
        out = transition(clips[a], clips[b], model, length=20, key_at=7, alpha=alpha, foot_lock=False, a_end=a_end,
                         b_start=b_start, method=method)
        np.testing.assert_array_equal(out.rotations[a_end + 1: a_end + 21], rots)
        np.testing.assert_array_equal(out.positions[a_end + 1: a_end + 21], pos)
        b_part = engine.continuation(b, b_start)
        np.testing.assert_array_equal(out.rotations[a_end + 21:], b_part.rotations)
    # Another length has its own buffers; the first ones stay.
    short = engine.generate(WALK, RUN, length=10)
    assert short[0] is not first[0] and short[0].shape[0] == 10
    assert engine.generate(RUN, WALK, length=20)[0] is first[0]


# -- compiled kernels against the numpy reference (quat.py) ----------------------------------------
def random_quats(rng, shape) -> np.ndarray:
    q = quat.normalize(rng.normal(size=tuple(shape) + (4,)))
    return q * np.where(rng.random(tuple(shape) + (1,)) < 0.5, -1.0, 1.0)  # both hemispheres


def test_log_and_exp_relative_match_quat():
    rng = np.random.default_rng(0)
    n, j = 64, 9
    ref = random_quats(rng, (j,))
    q = random_quats(rng, (n, j))
    # Cases near the identity relative to ref (the series branch) and near 180 degrees.
    tiny = quat.exp(rng.normal(size=(4, j, 3)) * 1e-10)
    axis = quat.normalize(rng.normal(size=(4, j, 3)))
    near_pi = quat.exp(axis * (np.pi - 1e-6))
    q = np.concatenate([q, quat.mul(ref, tiny), -quat.mul(ref, near_pi)])
    out = np.empty(q.shape[:-1] + (3,))
    kernels.log_relative(q, ref, out)
    expected = quat.log(quat.mul(quat.inv(ref), q))
    np.testing.assert_allclose(out[:n + 4], expected[:n + 4], atol=1e-12)
    # At 180 degrees both signs of the axis are the same rotation: compare rotations there.
    assert np.all(quat.angle_between(quat.exp(out[n + 4:]), quat.exp(expected[n + 4:])) < 1e-6)
    assert np.all(np.linalg.norm(out, axis=-1) <= np.pi + 1e-12)

    r = np.concatenate([rng.normal(size=(n, j, 3)), rng.normal(size=(4, j, 3)) * 1e-10])
    back = np.empty(r.shape[:-1] + (4,))
    kernels.exp_relative(r, ref, back)
    np.testing.assert_allclose(back, quat.mul(ref, quat.exp(r)), atol=1e-12)
    # Round trip: exp(log(q)) is q (up to sign).
    again = np.empty(q.shape)
    kernels.exp_relative(out, ref, again)
    assert np.all(quat.angle_between(again, q) < 1e-6)


@pytest.mark.parametrize("up", [0, 1, 2])
@pytest.mark.parametrize("chain_len", [0, 1, 2])
def test_compose_root_matches_forward_kinematics(up, chain_len):
    rng = np.random.default_rng(10 * up + chain_len)
    n = 50
    root = chain_len
    parents = np.array([-1] + list(range(chain_len + 1)))  # ancestors, root, one child
    j_count = len(parents)
    rots = random_quats(rng, (n, j_count))
    positions = rng.normal(scale=50.0, size=(n, j_count, 3))
    tilt = rots[:, root].copy()
    gpos = rng.normal(scale=100.0, size=(n, 3))
    heading = rng.uniform(-4 * np.pi, 4 * np.pi, size=n)
    chain = np.arange(chain_len, dtype=np.int64)
    r_in, p_in = rots.copy(), positions.copy()
    kernels.compose_root(chain, root, up, rots, positions, gpos, heading)
    # Only the root's own rotation and translation change.
    others = [j for j in range(j_count) if j != root]
    assert np.array_equal(rots[:, others], r_in[:, others])
    assert np.array_equal(positions[:, others], p_in[:, others])
    grot, g = fk(parents, rots, positions)
    axis = np.zeros(3)
    axis[up] = 1.0
    expected = quat.mul(quat.from_axis_angle(axis, heading), tilt)
    assert np.all(quat.angle_between(grot[:, root], expected) < 1e-7)
    np.testing.assert_allclose(g[:, root], gpos, atol=1e-9)


def test_nearest_matches_a_numpy_scan():
    rng = np.random.default_rng(2)
    for trial in range(20):
        n, dims = int(rng.integers(1, 300)), int(rng.integers(1, 20))
        period = np.where(rng.random(dims) < 0.5, 2 * np.pi, np.inf)
        w = np.where(np.isinf(period), rng.normal(size=(n, dims)), rng.uniform(0, 2 * np.pi, size=(n, dims)))
        x = np.where(np.isinf(period), rng.normal(size=dims), rng.uniform(0, 2 * np.pi, size=dims))
        d = np.abs(w - x)
        d = np.where(np.isinf(period), d, np.minimum(d, 2 * np.pi - d))
        assert kernels.nearest(w, x, period) == int(np.argmin((d ** 2).sum(axis=1))), trial
    # Wrap-around counts: 359 degrees is nearest 1 degree, not 180.
    w = np.radians([[180.0], [359.0]])
    assert kernels.nearest(w, np.radians([1.0]), np.array([2 * np.pi])) == 1


# -- spline bases: boundary conditions, checked numerically --------------------------------------
def fitted(basis: np.ndarray, inputs: np.ndarray, t: np.ndarray, degree: int):
    """Polynomial of ``degree`` through the frames ``basis @ inputs`` at times ``t`` (exact fit)."""
    y = basis @ inputs
    poly = np.polynomial.Polynomial.fit(t, y, degree)
    assert np.max(np.abs(poly(t) - y)) < 1e-9 * max(1.0, np.abs(y).max()), "not a polynomial of that degree"
    return poly


@pytest.mark.parametrize("length", [5, 20, 45])
def test_hermite_basis_matches_values_and_velocities(length):
    rng = np.random.default_rng(length)
    p_a, v_a, p_b, v_b = rng.normal(size=4) * [10, 1, 10, 1]
    t = np.arange(1, length + 1, dtype=float)
    poly = fitted(hermite_basis(length), np.array([p_a, v_a, p_b, v_b]), t, 3)
    d = length + 1.0
    np.testing.assert_allclose([poly(0), poly.deriv()(0), poly(d), poly.deriv()(d)], [p_a, v_a, p_b, v_b],
                               atol=1e-8)


@pytest.mark.parametrize("length, key_at", [(20, 10), (15, 4), (30, 25), (20, 1), (20, 20), (1, 1)])
def test_key_spline_basis_passes_through_the_key(length, key_at):
    rng = np.random.default_rng(100 * length + key_at)
    inputs = rng.normal(size=5) * [10, 1, 10, 1, 10]  # pA, vA, pB, vB, key
    basis = key_spline_basis(length, key_at)
    assert basis.shape == (length, 5) and not basis.flags.writeable
    frames = basis @ inputs
    assert frames[key_at - 1] == pytest.approx(inputs[4], abs=1e-9)
    d = length + 1.0
    if key_at >= 4 and length - key_at + 1 >= 4:  # enough frames to recover both cubic pieces
        t = np.arange(1, length + 1, dtype=float)
        left = fitted(basis[:key_at], inputs, t[:key_at], 3)
        right = fitted(basis[key_at - 1:], inputs, t[key_at - 1:], 3)
        np.testing.assert_allclose([left(0), left.deriv()(0), right(d), right.deriv()(d)], inputs[:4], atol=1e-8)
        # Twice continuously differentiable through the key.
        for k in (1, 2):
            assert left.deriv(k)(key_at) == pytest.approx(right.deriv(k)(key_at), abs=1e-8)
    # A key on the Hermite curve gives that same curve (what the engine relies on for the
    # joints without a key).
    herm = hermite_basis(length) @ inputs[:4]
    on_curve = np.append(inputs[:4], herm[key_at - 1])
    np.testing.assert_allclose(basis @ on_curve, herm, atol=1e-9)


@pytest.mark.parametrize("length", [8, 20, 40])
def test_inertialize_basis_decays_from_a_to_b(length):
    rng = np.random.default_rng(length)
    p_a, v_a, p_b, v_b, a_a = rng.normal(size=5) * [10, 1, 10, 1, 0.2]
    t = np.arange(1, length + 1, dtype=float)
    poly = fitted(inertialize_basis(length), np.array([p_a, v_a, p_b, v_b, a_a]), t, 5)
    d = length + 1.0
    np.testing.assert_allclose([poly(0), poly.deriv()(0), poly.deriv(2)(0)], [p_a, v_a, a_a], atol=1e-7)
    np.testing.assert_allclose([poly(d), poly.deriv()(d), poly.deriv(2)(d)], [p_b, v_b, 0.0], atol=1e-7)


@pytest.mark.parametrize("length", [1, 7, 20])
def test_linear_basis_goes_straight(length):
    p_a, p_b = -3.0, 11.0
    t = np.arange(1, length + 1) / (length + 1.0)
    np.testing.assert_allclose(linear_basis(length) @ [p_a, p_b], p_a + (p_b - p_a) * t, atol=1e-12)


def damped_curve(length: int, tau: float, seams) -> np.ndarray:
    """``damped``'s frames (length,) of one column with seams ``[pA, vA, pB, vB]`` and time
    constant ``tau`` (frames)."""
    return damped_frames(np.asarray(seams, dtype=float).reshape(4, 1), length, np.array([tau]), tau, tau)[:, 0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_damped_keeps_the_seam_velocities_and_fades_onto_the_line(seed):
    # A long gap and a slow fade, so that frame differences are close to derivatives.
    length, tau = 599, 20.0
    d = length + 1.0
    rng = np.random.default_rng(seed)
    p_a, v_a, p_b, v_b = rng.normal(size=4) * [10, 1, 10, 1]
    slope = (p_b - p_a) / d
    curve = damped_curve(length, tau, [p_a, v_a, p_b, v_b])
    assert curve.shape == (length,)
    y = np.concatenate([[p_a], curve, [p_b]])
    step = np.diff(y)
    # Each seam keeps its own velocity, without a kink: the velocity changes over the first
    # frames by far less than the residual velocity per tau (what t * exp(-t / tau) would
    # change it by: 2 (v - slope) / tau).
    assert step[0] == pytest.approx(v_a, abs=0.01 * abs(v_a - slope))
    assert step[-1] == pytest.approx(v_b, abs=0.01 * abs(v_b - slope))
    assert abs(step[1] - step[0]) < 0.25 * 2 * abs(v_a - slope) / tau
    assert abs(step[-1] - step[-2]) < 0.25 * 2 * abs(v_b - slope) / tau
    # Away from the seams it is the straight line (within 1e-3 of the residual velocity's reach).
    t = np.arange(1, length + 1)
    mid = (t > 12 * tau) & (t < d - 12 * tau)
    line = linear_basis(length) @ [p_a, p_b]
    reach = tau * max(abs(v_a - slope), abs(v_b - slope))
    assert np.abs((curve - line)[mid]).max() < 1e-3 * reach
    # Near them it is not: the seam velocity carries the curve off the line.
    assert np.abs((curve - line)[t < 3 * tau]).max() > 0.5 * tau * abs(v_a - slope)


@pytest.mark.parametrize("length", [2, 4, 7])
def test_damped_lets_go_of_a_seams_velocity_before_the_other_seam(length):
    # The engine's shortest tau at 30 fps (1.5 frames), short gaps: what A's velocity adds is
    # weighed by 1 - smoothstep(t/d), so it is gone at B's start, with no slope there, however
    # short the gap; B's side likewise at A's end.
    tau, d = 1.5, length + 1.0
    t = np.arange(1, length + 1)
    g = t * (1 + t / tau) * np.exp(-t / tau)
    to_b = (t / d) ** 2 * (3 - 2 * t / d)
    from_a = damped_curve(length, tau, [0.0, 1.0, 0.0, 0.0])  # A's velocity alone, pA = pB = 0
    np.testing.assert_allclose(from_a, (1 - to_b) * g, atol=1e-12)
    from_b = damped_curve(length, tau, [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(from_b, -to_b * g[::-1], atol=1e-12)
    # The last frame carries less of A's velocity than one frame's worth of it over the gap.
    assert from_a[-1] <= g.max() / d + 1e-12


@pytest.mark.parametrize("phase", [0.0, 1.0, 2.5])
def test_damped_time_scales_measure_one_over_the_frequency(phase):
    # Ten samples a frame apart: a wave whose period fits in them (omega = 0.7 / frame) gets
    # 1 / omega whatever its phase (the finite differences' 1 / (2 sin(omega / 2)), within 6%:
    # nine steps are not a whole number of periods);
    # a still column 0; a steady drift inf; constant acceleration |v| / |a| (RMS).
    k = np.arange(DAMPED_SAMPLES, dtype=float)
    omega = 0.7
    wave = np.stack([np.sin(omega * k + phase), 2 * np.cos(omega * k + phase), 0 * k], axis=1)
    rows = np.concatenate([wave, np.ones((len(k), 1)), np.stack([3 * k], axis=1), np.stack([k * k], axis=1)], axis=1)
    starts = np.array([0, 3, 4, 5])
    scales = damped_time_scales([rows], 1, starts)
    assert scales.shape == (6,)
    np.testing.assert_allclose(scales[:3], 1 / (2 * np.sin(omega / 2)), rtol=0.06)
    assert scales[3] == 0.0 and scales[4] == np.inf
    v = np.diff(k * k)
    assert scales[5] == pytest.approx(np.sqrt(np.mean(v * v)) / 2.0)
    # Samples `step` frames apart measure in frames, not in samples.
    np.testing.assert_allclose(damped_time_scales([rows], 4, starts)[:3], 4 * scales[:3])
    assert not damped_time_scales([rows[:2]], 1, starts).any()
    # Two seams' samples together: their energies add (a still seam leaves the other's scale;
    # a seam of two samples adds nothing).
    still = np.zeros_like(rows)
    np.testing.assert_allclose(damped_time_scales([rows, still], 1, starts), scales)
    np.testing.assert_allclose(damped_time_scales([rows[:2], rows], 1, starts), scales)
    twice = damped_time_scales([rows, 2 * rows], 1, starts)
    np.testing.assert_allclose(twice, scales)  # a scaled copy: the same ratio


@pytest.mark.parametrize("length", [3, 20, 45])
def test_damped_frames_are_the_formula_per_column(length):
    # Each column its own time constant; the formula of the docstring written out here.
    rng = np.random.default_rng(length)
    inputs = rng.normal(size=(4, 7))
    tau = np.linspace(1.0, 5.0, 7)
    d = length + 1.0
    t = np.arange(1, length + 1)[:, None]
    w = t / d
    smooth = w * w * (3 - 2 * w)
    g = lambda x: x * (1 + x / tau) * np.exp(-x / tau)  # noqa: E731
    p_a, v_a, p_b, v_b = inputs
    slope = (p_b - p_a) / d
    expected = p_a + w * (p_b - p_a) + (1 - smooth) * g(t) * (v_a - slope) - smooth * g(d - t) * (v_b - slope)
    np.testing.assert_allclose(damped_frames(inputs, length, tau, 1.0, 5.0), expected, atol=1e-12)
    # Time scales outside [tau_min, tau_max] are held at its ends.
    np.testing.assert_allclose(damped_frames(inputs, length, np.zeros(7), 2.5, 2.5),
                               damped_frames(inputs, length, np.full(7, np.inf), 2.5, 2.5), atol=1e-12)
    np.testing.assert_allclose(damped_frames(inputs, length, np.full(7, 9.0), 1.0, 5.0),
                               damped_frames(inputs, length, np.full(7, 5.0), 1.0, 5.0), atol=1e-12)


def test_damped_carries_a_slow_swing_further_than_a_fast_one(clips):
    # One elbow swings about a fixed axis, passing A's end with the same angular velocity, once
    # slowly (period 2 s) and once fast (0.4 s, a wave); the rest of the body is the walk's. The
    # slow swing's velocity is carried for its own time scale (the 0.33 s cap), the wave's for
    # about 0.06 s: four frames into the gap, the slow one is much further along and near its
    # truth, the wave short of its velocity's reach.
    m = clips[WALK]
    j = m.skeleton.names.index("LowerArm_R")
    a_end, length = 40, 20
    fps = m.fps
    tau_s = (np.arange(len(m)) - a_end) / fps
    axis = np.array([1.0, 0.0, 0.0])
    speed = 3.0  # rad / s at A's end
    eng = TransitionEngine()
    angles = {}
    for name, period in (("slow", 2.0), ("fast", 0.4)):
        omega = 2 * np.pi / period
        theta = speed / omega * np.sin(omega * tau_s)
        rots = m.rotations.copy()
        rots[:, j] = quat.from_axis_angle(axis, theta)
        eng.add(name, Motion(m.skeleton, rots, m.positions.copy(), fps))
        r, _ = eng.generate(name, name, length=length, a_end=a_end, b_start=a_end + length + 1, align=False,
                            method="damped", foot_lock=False)
        angles[name] = 2 * np.arctan2(r[:, j, 1:] @ axis, r[:, j, 0]), theta[a_end + 1: a_end + length + 1]
    reach = speed * 4 / fps  # the velocity carried four frames unchanged
    slow, truth_slow = angles["slow"][0][3], angles["slow"][1][3]
    fast = angles["fast"][0][3]
    assert slow > 0.8 * reach and abs(slow - truth_slow) < 0.2 * reach
    assert fast < 0.6 * reach and slow > 1.5 * fast


def test_damped_lets_the_roots_travel_go_at_once_and_keeps_its_height_with_the_legs(clips):
    # A run slowing into a walk-back, in-betweened (B fixed): the root's horizontal position is
    # the fixed-tau curve (DAMPED_TAU_S: a travelling root's velocity carried longer leaves the
    # line to B's place), its height not (it takes the motion's time scale, as the legs do).
    a, b = clips[RUN], clips[BACK]
    eng = TransitionEngine()
    eng.add("a", a)
    eng.add("b", b)
    a_end, b_start, length = 20, 2, 30
    r, p = eng.generate("a", "b", length=length, a_end=a_end, b_start=b_start, align=False, method="damped",
                        foot_lock=False)
    root = root_index(a)
    got = fk(a.skeleton.parents, r, p)[1][:, root]
    ga, gb = fk(a.skeleton.parents, a.rotations, a.positions)[1][:, root], \
        fk(b.skeleton.parents, b.rotations, b.positions)[1][:, root]
    inputs = np.stack([ga[a_end], ga[a_end] - ga[a_end - 1], gb[b_start], gb[b_start + 1] - gb[b_start]])
    tau = DAMPED_TAU_S * a.fps
    fixed = damped_frames(inputs, length, np.zeros(3), tau, tau)
    flat = [k for k in range(3) if k != UP]
    np.testing.assert_allclose(got[:, flat], fixed[:, flat], atol=1e-6 * np.abs(fixed).max())
    assert np.abs(got[:, UP] - fixed[:, UP]).max() > 0.1  # cm: the height's own time scale


@pytest.mark.parametrize("length", [1, 7, 20, 45])
def test_damped_keeps_a_steady_motion_on_the_line(length):
    # Seam velocities equal to the line's slope (a root walking at a steady speed): the line itself.
    p_a, p_b = -3.0, 11.0
    v = (p_b - p_a) / (length + 1.0)
    np.testing.assert_allclose(damped_curve(length, 3.0, [p_a, v, p_b, v]), linear_basis(length) @ [p_a, p_b],
                               atol=1e-12)


def test_reach_parts_carry_a_seam_velocity_to_the_other_seam():
    # One joint (3 columns) from 0 to B's value (2, 0, 0) over a 45-frame gap (d = 46): A's
    # velocity along the path at 0.1 a frame, faster than the line's 2 / 46, gets the time
    # constant whose carried offset g(t) 0.1 peaks at the distance to go (2), and only its part
    # along the path (less the line's slope) is carried so: the sideways 0.3 keeps the column's
    # own. B's velocity across the path: none. A second joint (1 column): A's velocity heading
    # away, none; B's arriving from A's side, its own. Only whole groups within the first
    # ``columns`` columns take part; ``longest`` caps the time constant.
    d = 46.0
    starts = np.array([0, 3, 4])
    inputs = np.zeros((4, 7))
    inputs[2, 0] = 2.0
    inputs[1, 0:3] = [0.1, 0.3, 0.0]
    inputs[3, 0:3] = [0.0, 0.3, 0.0]
    inputs[2, 3], inputs[1, 3], inputs[3, 3] = -1.0, 0.5, -0.25
    tau_a, tau_b, part_a, part_b = reach_parts(inputs, starts, 4, d, 1e9)
    np.testing.assert_allclose(tau_a[:3], 2.0 / (DAMPED_PEAK * 0.1))
    np.testing.assert_allclose(part_a[:3], [0.1 - 2.0 / d, 0.0, 0.0])
    assert not tau_b[:3].any() and not part_b[:3].any()
    assert tau_a[3] == 0.0 and part_a[3] == 0.0
    assert tau_b[3] == pytest.approx(1.0 / (DAMPED_PEAK * 0.25)) and part_b[3] == pytest.approx(-(0.25 - 1.0 / d))
    assert not np.concatenate([tau_a[4:], tau_b[4:], part_a[4:], part_b[4:]]).any()
    t = np.linspace(0.0, 10 * tau_a[0], 200001)
    g = t * (1 + t / tau_a[0]) * np.exp(-t / tau_a[0])
    assert 0.1 * g.max() == pytest.approx(2.0, rel=1e-6)
    np.testing.assert_allclose(reach_parts(inputs, starts, 4, d, 5.0)[0][:3], 5.0)  # capped
    assert not reach_parts(inputs, starts, 3, d, 1e9)[1].any()  # the second group left out
    assert not reach_parts(inputs, starts, 2, d, 1e9)[0].any()  # no whole group
    # Slower along the path than the line: nothing to carry. And no jump where a seam's speed
    # crosses the line's: just above it, the frames are within 1e-6 of just below it.
    frames = {}
    for k, speed in (("below", 2.0 / d - 1e-7), ("above", 2.0 / d + 1e-7)):
        inputs[1, 0:3] = [speed, 0.0, 0.0]
        reach = reach_parts(inputs, starts, 4, d, 0.35 * d)
        assert (reach[0][0] > 0) == (k == "above")
        frames[k] = damped_frames(inputs, 45, np.full(7, 1.5), 1.5, 10.0, reach)
    np.testing.assert_allclose(frames["above"], frames["below"], atol=1e-6)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("backwards", [False, True])
def test_damped_carries_a_raised_arm_to_where_b_holds_it(clips, backwards, compiled):
    # A still body raising its right arm by 80 degrees over a second (a minimum-jerk reach),
    # the gap (1.5 s) beginning a quarter of the way into it: damped carries the seam's velocity
    # on toward where B holds the arm, and errs 0.72x SLERP's; carried for the motion's own time
    # scale (short: the arm is accelerating) it crawled along the straight line at 0.95x SLERP's
    # error. Backwards, the arm is held at A and lowered from B's seam on: B's velocity is
    # carried back alike. The compiled kernels and numpy's alike.
    m = clips[WALK]
    length, a_end, n = 45, 40, 150
    j = m.skeleton.names.index("UpperArm_R")
    s = np.clip((np.arange(n) - (a_end - 8)) / 30.0, 0.0, 1.0)
    theta = 1.4 * (10 * s**3 - 15 * s**4 + 6 * s**5)
    if backwards:
        theta = theta[::-1]
        a_end = n - 1 - (a_end + length + 1)
    rots = np.repeat(m.rotations[:1], n, axis=0)
    rots[:, j] = quat.mul(rots[:, j], quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), theta))
    eng = TransitionEngine()
    eng.add("reach", Motion(m.skeleton, rots, np.repeat(m.positions[:1], n, axis=0), m.fps))
    truth = theta[a_end + 1: a_end + length + 1]
    err = {}
    for method in ("damped", "slerp"):
        with contextlib.nullcontext() if compiled else kernels.numpy_backend():
            r, _ = eng.generate("reach", "reach", length=length, a_end=a_end, b_start=a_end + length + 1,
                                align=False, method=method, foot_lock=False)
        err[method] = np.sqrt(np.mean((quat.angle_between(r[:, j], m.rotations[0, j]) - truth) ** 2))
    assert err["damped"] < 0.8 * err["slerp"], err


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("method", ["spline", "inertialize", "damped"])
def test_a_joint_half_a_turn_from_b_goes_round_without_spinning(clips, compiled, method):
    # A still body whose right upper arm turns steadily (0.6 rad/s) through half a turn from
    # where B holds it, A's last frame just past the half turn: the short arcs of A's last two
    # frames about B's point nearly opposite ways. Their difference was taken for A's velocity,
    # nearly a whole turn a frame, and the arm spun round at up to 120 degrees a frame (a wave
    # into a hanging arm, bandai1, bench pair byebye_proud -> bye_old). The arm now goes on the
    # way it turned, at about its own rate or the half turn's over the gap, and lands on B.
    m = clips[WALK]
    length, a_end, n = 30, 40, 90
    j = m.skeleton.names.index("UpperArm_R")
    theta = np.pi + 0.01 + 0.02 * (np.arange(n) - a_end)
    theta[a_end + length + 1:] = 0.0
    rots = np.repeat(m.rotations[:1], n, axis=0)
    rots[:, j] = quat.mul(rots[:, j], quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), theta))
    eng = TransitionEngine()
    eng.add("turn", Motion(m.skeleton, rots, np.repeat(m.positions[:1], n, axis=0), m.fps))
    with contextlib.nullcontext() if compiled else kernels.numpy_backend():
        r, _ = eng.generate("turn", "turn", length=length, a_end=a_end, b_start=a_end + length + 1,
                            align=False, method=method, foot_lock=False)
    arm = np.concatenate([rots[a_end - 1: a_end + 1, j], r[:, j], rots[a_end + length + 1: a_end + length + 3, j]])
    steps = quat.angle_between(arm[1:], arm[:-1])
    # At most three times the half turn's even step over the gap (6 degrees a frame): 18 degrees.
    assert steps.max() < 3 * (np.pi - 0.01) / length, np.degrees(steps)
    # The way A turned (about +z): no frame turns back against it.
    about_z = quat.log(quat.mul(arm[1:], quat.inv(arm[:-1])))[:, 2]
    assert np.all(about_z > -1e-3), np.degrees(about_z)


# -- waves continued through the gap (periodic) -------------------------------------------------
def seam_samples(curve, length: int, step: int = 1, n: int = DAMPED_SAMPLES):
    """``curve(t)`` (t in frames, (T,) -> (T, C)) sampled as the engine samples the clips for
    ``damped`` (``n`` of A up to its seam at 0, ``n`` of B from its seam at ``length + 1``,
    ``step`` apart), the seam rows ``pA, vA, pB, vB`` and the truth of the gap's frames."""
    d = length + 1.0
    times = np.concatenate([-step * np.arange(n - 1, -1, -1.0), d + step * np.arange(n, dtype=float)])
    inputs = np.stack([curve(np.array([0.0]))[0], (curve(np.array([0.0])) - curve(np.array([-1.0])))[0],
                       curve(np.array([d]))[0], (curve(np.array([d + 1.0])) - curve(np.array([d])))[0]])
    return curve(times), times, inputs, curve(np.arange(1.0, length + 1.0))


def wave(period: float, amplitude: float = 0.5):
    """Three columns (one joint) swinging with ``period`` frames, each in its own phase, over a
    slow drift."""
    phases = np.array([0.4, 2.0, 3.5])
    return lambda t: amplitude * np.sin(2 * np.pi * t[:, None] / period + phases) + 0.002 * t[:, None]


@pytest.mark.parametrize("length, period", [(30, 15.0), (45, 18.0), (45, 10.0), (90, 12.0)])
def test_a_wave_is_continued_in_phase_through_the_gap(length, period):
    # A hand waving at both seams (periods 0.33-0.6 s at 30 fps: it turns back within each
    # seam's 0.3 s) is played on through the gap in phase with both: within 5% of its amplitude,
    # where the damped curve alone (the motion's own time scale, back to the line between the
    # seams) misses by a third of it and more. On the 3 s gap, the frequencies that put both
    # seams in phase with one swing more or less lie close: only the fit's peaks judged between
    # the grid's frequencies tell them apart.
    rows, times, inputs, truth = seam_samples(wave(period), length)
    starts = np.array([0])
    tau = DAMPED_TAU_S * 30.0
    frames, weights = periodic.continued(rows, times, inputs, length, 30.0, starts, tau)
    np.testing.assert_allclose(weights, 1.0)
    assert np.abs(frames - truth).max() < 0.05 * 0.5
    scale = damped_time_scales([rows[:DAMPED_SAMPLES], rows[DAMPED_SAMPLES:]], 1, starts)
    alone = damped_frames(inputs, length, scale, tau, 0.25 * (length + 1))
    assert np.sqrt(np.mean((alone - truth) ** 2)) > 0.33 * 0.5


def test_smooth_or_stopping_motions_are_not_continued():
    # A cosine fits half a swing to an arm raised at A's seam and lowered at B's (straight on at
    # both), to a bow's smooth dip, and to a wave at A's seam that has stopped at B's: none of
    # them is continued, so ``damped`` stays what it was for them.
    length, starts = 30, np.array([0])
    d = length + 1.0
    raised = lambda t: np.where(t <= 0, -0.08 * t, 0.08 * (t - d))[:, None] * [1.0, 0.5, -0.2]
    bow = lambda t: (0.6 * np.exp(-((t - d / 2) / 12.0) ** 2))[:, None] * [1.0, -0.3, 0.1]
    stops = lambda t: np.where(t <= 0, 0.4 * np.sin(2 * np.pi * t / 12.0), 0.1)[:, None] * [1.0, 0.7, 0.2]
    for name, curve in (("raised", raised), ("bow", bow), ("stops", stops)):
        rows, times, inputs, _ = seam_samples(curve, length)
        swing = periodic.swinging(rows[times <= 0], rows[times > 0], starts)
        frames, weights = periodic.continued(rows, times, inputs, length, 30.0, starts, 1.5)
        assert frames is None and not weights.any() and swing[0] == 0.0, name
    # A wave seen in fewer than PERIODIC_MIN_SAMPLES samples of one clip is not continued either.
    rows, times, inputs, _ = seam_samples(wave(12.0), length, n=periodic.PERIODIC_MIN_SAMPLES - 1)
    assert periodic.continued(rows, times, inputs, length, 30.0, starts, 1.5)[0] is None
    rows, times, inputs, _ = seam_samples(wave(12.0), length, n=periodic.PERIODIC_MIN_SAMPLES)
    assert periodic.continued(rows, times, inputs, length, 30.0, starts, 1.5)[0] is not None
    # The same gates pass a motion that turns back at one seam and keeps moving at the other.
    turns = lambda t: np.where(t <= 0, 0.4 * np.sin(2 * np.pi * t / 12.0), 0.15 * (t - d))[:, None] * [1.0, 0.7, 0.2]
    rows, times, _, _ = seam_samples(turns, length)
    assert periodic.swinging(rows[times <= 0], rows[times > 0], starts)[0] == 1.0


def elbow_wave_errors(m: Motion, length: int, a_end: int = 40) -> dict:
    """RMS error (radians) of the right elbow's angle in ``damped`` and ``slerp`` in-betweens of
    ``m`` with that elbow waving (period 0.5 s) over its own frames."""
    j = m.skeleton.names.index("LowerArm_R")
    axis = np.array([1.0, 0.0, 0.0])
    theta = 0.6 * np.sin(2 * np.pi * (np.arange(len(m)) - a_end) / (0.5 * m.fps) + 0.7)
    rots = m.rotations.copy()
    rots[:, j] = quat.from_axis_angle(axis, theta)
    eng = TransitionEngine()
    eng.add("wave", Motion(m.skeleton, rots, m.positions.copy(), m.fps))
    truth = theta[a_end + 1: a_end + length + 1]
    err = {}
    for method in ("damped", "slerp"):
        r, _ = eng.generate("wave", "wave", length=length, a_end=a_end, b_start=a_end + length + 1, align=False,
                            method=method, foot_lock=False)
        got = 2 * np.arctan2(r[:, j, 1:] @ axis, r[:, j, 0])
        err[method] = np.sqrt(np.mean((got - truth) ** 2))
    return err


def test_damped_waves_an_elbow_on_through_the_gap(clips):
    # Standing still (the walk's first frame held) with one elbow waving, in-betweened within
    # the clip over 1.5 s: damped's elbow follows the wave, its error a fifth of SLERP's (which
    # holds the line between the seams).
    m = clips[WALK]
    still = Motion(m.skeleton, np.repeat(m.rotations[:1], 150, axis=0), np.repeat(m.positions[:1], 150, axis=0), m.fps)
    err = elbow_wave_errors(still, 45)
    assert err["damped"] < 0.2 * err["slerp"], err


def test_damped_waves_on_at_60_fps_from_ten_context_frames(clips):
    # The protocol's 10 context frames each side at 60 fps: 5 samples each at damped's step of
    # 1/30 s, fewer than the swing's fit needs; it takes every frame instead (engine._swing_step),
    # and the elbow waving over a still body follows the wave through a 1 s gap (about SLERP's
    # error where it was not continued).
    m = clips[WALK]
    fps, length, a_end, period = 60.0, 59, 9, 0.5
    n = a_end + 1 + length + 10
    j = m.skeleton.names.index("LowerArm_R")
    axis = np.array([1.0, 0.0, 0.0])
    theta = 0.6 * np.sin(2 * np.pi * (np.arange(n) - a_end) / (period * fps) + 0.7)
    rots = np.repeat(m.rotations[:1], n, axis=0)
    rots[:, j] = quat.from_axis_angle(axis, theta)
    eng = TransitionEngine()
    eng.add("wave", Motion(m.skeleton, rots, np.repeat(m.positions[:1], n, axis=0), fps))
    err = {}
    for method in ("damped", "slerp"):
        r, _ = eng.generate("wave", "wave", length=length, a_end=a_end, b_start=a_end + length + 1, align=False,
                            method=method, foot_lock=False)
        got = 2 * np.arctan2(r[:, j, 1:] @ axis, r[:, j, 0])
        err[method] = np.sqrt(np.mean((got - theta[a_end + 1: a_end + length + 1]) ** 2))
    assert err["damped"] < 0.2 * err["slerp"], err


def test_damped_continues_only_the_joints_it_is_given(clips):
    # Retrieval's fallback passes the joints of the parts it falls back for: a waving elbow left
    # out keeps damped's curve; given (or all joints by default), it swings on.
    from posturemap.synth import engine as E

    m = clips[WALK]
    j = m.skeleton.names.index("LowerArm_R")
    theta = 0.6 * np.sin(2 * np.pi * (np.arange(150) - 40) / (0.5 * m.fps) + 0.7)
    rots = np.repeat(m.rotations[:1], 150, axis=0)
    rots[:, j] = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), theta)
    eng = TransitionEngine()
    track = eng.add("wave", Motion(m.skeleton, rots, np.repeat(m.positions[:1], 150, axis=0), m.fps))
    req = TransitionRequest(method="damped", length=45, a_end=40, b_start=86, align=False,
                            foot_lock=False).resolved(150, 150)
    out = {}
    for name, joints in (("all", None), ("with", np.array([0, j])), ("without", np.array([0, j - 1]))):
        out[name] = E._interpolated(eng, track, track, "wave", "wave", req, swing_joints=joints)[0][:, j].copy()
    np.testing.assert_allclose(out["with"], out["all"], atol=1e-12)
    truth = rots[41:86, j]
    assert quat.angle_between(out["with"], truth).max() < 0.05
    assert quat.angle_between(out["without"], truth).max() > 0.3


def test_damped_leaves_a_joint_out_of_rhythm_with_the_rest(clips, monkeypatch):
    # The same elbow waving over the walk: the legs and arms swing at the walk's pace, which the
    # shared frequency follows; the elbow's own rhythm is far from it, so it is not continued at
    # the walk's (at that frequency its error is 1.16x SLERP's) and keeps damped's curve (1.05x:
    # a seam velocity carried briefly, then the line).
    err = elbow_wave_errors(clips[WALK], 45)
    monkeypatch.setattr(periodic, "PERIODIC_OWN", 1e9)  # every joint at the shared frequency
    shared = elbow_wave_errors(clips[WALK], 45)
    assert err["damped"] < 0.95 * shared["damped"] and err["damped"] < 1.1 * err["slerp"], (err, shared)


# -- euler features -----------------------------------------------------------------------------
@pytest.mark.parametrize("method", KEYED)
def test_euler_features_work_for_transitions(clips, euler_model, method):
    space = euler_model.space_
    assert space.mode == "euler" and space.circular.any()
    for (a, b), (a_end, b_start, key_at, alpha) in zip([(WALK, RUN), (BOW, BACK), (RUN, WALK)],
                                                        [(None, 0, 10, 0.5), (70, 3, 4, 0.2), (12, 100, 15, 0.9)]):
        engine = TransitionEngine(euler_model)
        engine.add("a", clips[a])
        engine.add("b", clips[b])
        engine.generate("a", "b", length=20, key_at=key_at, alpha=alpha, a_end=a_end, b_start=b_start, method=method)
        out = transition(clips[a], clips[b], euler_model, length=20, key_at=key_at, alpha=alpha, foot_lock=False,
                         a_end=a_end, b_start=b_start, method=method)
        last = len(clips[a]) - 1 if a_end is None else a_end
        assert len(out) == last + 21 + len(clips[b]) - b_start
        assert np.all(np.isfinite(out.rotations))
        rots = out.rotations[last: last + 22]
        assert quat.angle_between(rots[1:], rots[:-1]).max() < np.pi / 2
        if method not in KEY_POSTURE:  # retrieval: real motion found through the euler maps
            assert set(engine.last["retrieval"]["parts"]) == {"lower", "upper"}
            continue
        assert_frame_is_key(out[last + key_at], euler_model, engine.last["key"], engine.last["neurons"],
                            method, f"{a} -> {b}")


# -- command line ---------------------------------------------------------------------------------
def header_layout(path) -> list[str]:
    """Joint and channel lines of a BVH file's hierarchy, whitespace normalised."""
    with open(path, encoding="utf-8") as f:
        header = f.read().split("MOTION")[0]
    keep = ("ROOT", "JOINT", "CHANNELS", "End")
    return [" ".join(line.split()) for line in header.splitlines() if line.strip().startswith(keep)]


def test_cli_transition_with_map(paths, clips, map_file, tmp_path, capsys):
    out = tmp_path / "walk_to_run.bvh"
    code, stdout, err = run_cli(["transition", str(paths[WALK]), str(paths[RUN]), "-o", str(out),
                                 "--map", map_file, "--a-end", "120", "--b-start", "3", "--length", "12",
                                 "--key-at", "4", "--alpha", "0.3"], capsys)
    assert code == 0, err
    result = bvh.read(out)
    a = clips[WALK]
    assert len(result) == 121 + 12 + len(clips[RUN]) - 3
    assert result.skeleton.same_as(a.skeleton)  # names, hierarchy, channel layout
    assert header_layout(out) == header_layout(paths[WALK])  # the same, read from the text
    np.testing.assert_allclose(result.skeleton.offsets, a.skeleton.offsets)
    assert result.fps == pytest.approx(a.fps)
    assert [(j, list(o)) for j, o in result.skeleton.end_sites] == [(j, list(o)) for j, o in a.skeleton.end_sites]
    # A's frames are written unchanged (to the text's precision); the same as the library's.
    np.testing.assert_allclose(result[:121].global_positions(), a[:121].global_positions(), atol=1e-4)
    model = PostureMap.load(map_file)
    expected = transition(a, clips[RUN], model, length=12, key_at=4, alpha=0.3, a_end=120, b_start=3)
    np.testing.assert_allclose(result.global_positions(), expected.global_positions(), atol=1e-3)
    assert str(out) in stdout


@pytest.mark.parametrize("extra", [[], ["--method", "slerp", "--no-align"], ["--method", "upm-path", "--length", "1"]])
def test_cli_transition_without_map(paths, clips, tmp_path, capsys, extra):
    out = tmp_path / "run_to_back.bvh"
    code, _, err = run_cli(["transition", str(paths[RUN]), str(paths[BACK]), "-o", str(out)] + extra, capsys)
    assert code == 0, err
    result = bvh.read(out)
    length = int(extra[extra.index("--length") + 1]) if "--length" in extra else 20
    assert len(result) == len(clips[RUN]) + length + len(clips[BACK])
    assert result.skeleton.same_as(clips[RUN].skeleton)
    if "--no-align" in extra:
        np.testing.assert_allclose(result[len(clips[RUN]) + 20:].global_positions(),
                                   clips[BACK].global_positions(), atol=1e-4)


@pytest.mark.parametrize("case", ["a-end", "b-start", "skeleton", "missing-a", "missing-b", "folder", "map"])
def test_cli_transition_errors(paths, sample_clips, map_file, tmp_path, capsys, case):
    a, b = str(paths[RUN]), str(paths[BACK])
    out = tmp_path / "out.bvh"
    extra, expect = [], None
    if case == "a-end":
        extra, expect = ["--a-end", "24"], "--a-end"
    elif case == "b-start":
        extra, expect = ["--b-start", "31", "--method", "spline"], "--b-start"
    elif case == "skeleton":
        b = str(tmp_path / "sample.bvh")
        bvh.write(b, sample_clips["walk"])
        expect = "skeleton differs"
    elif case == "missing-a":
        a = str(tmp_path / "nope.bvh")
        expect = a
    elif case == "missing-b":
        b = str(tmp_path / "nope.bvh")
        expect = b
    elif case == "folder":
        out = tmp_path / "missing" / "out.bvh"
        expect = "output folder"
    elif case == "map":
        extra, expect = ["--map", str(tmp_path / "no-map.npz")], "no-map.npz"
    before = set(os.listdir(tmp_path))
    code, _, err = run_cli(["transition", a, b, "-o", str(out)] + extra, capsys)
    assert code == 2
    assert err.startswith("posturemap: error: ") and err.endswith("\n") and err.count("\n") == 1, err
    assert expect in err
    assert not out.exists()
    assert set(os.listdir(tmp_path)) == before, "no partial or temporary file may be left"


@pytest.mark.parametrize("times, length", [((10.0,), 20), ((5.0, 10.0, 15.5), 20), ((1.0,), 3), ((45.0,), 45)])
def test_keys_spline_basis_matches_scipy(times, length):
    # The numpy clamped spline must be scipy's make_interp_spline(k=3) with end slopes.
    from scipy.interpolate import make_interp_spline

    rng = np.random.default_rng(len(times) + length)
    basis = keys_spline_basis(length, times)
    knots = np.concatenate([[0.0], times, [length + 1.0]])
    t = np.arange(1, length + 1, dtype=float)
    for _ in range(5):
        inp = rng.normal(size=4 + len(times))  # pA, vA, pB, vB, keys
        y = np.concatenate([[inp[0]], inp[4:], [inp[2]]])
        ref = make_interp_spline(knots, y, k=3, bc_type=([(1, inp[1])], [(1, inp[3])]))(t)
        np.testing.assert_allclose(basis @ inp, ref, atol=1e-12)


def test_fk_kernel_matches_skeleton_fk(clips):
    m = clips[WALK][:30]
    grot, gpos = np.empty(m.rotations.shape), np.empty(m.positions.shape)
    kernels.fk(m.skeleton.parents, m.rotations, m.positions, grot, gpos)
    ref_r, ref_p = fk(m.skeleton.parents, m.rotations, m.positions)
    np.testing.assert_allclose(grot, ref_r, atol=1e-12)
    np.testing.assert_allclose(gpos, ref_p, atol=1e-9)


def test_engine_reads_replaced_map_weights(clips, model):
    # The one-call key kernel works on a flattened copy of the maps; replacing a map's weights
    # (as the benchmark's fixed-key stand-ins do before every call) must reach the next key.
    import copy

    own = copy.deepcopy(model)
    engine = TransitionEngine(own)
    engine.add(WALK, clips[WALK])
    xa, xb = own.encode(clips[WALK][10])[0], own.encode(clips[WALK][40])[0]
    key1, _ = engine.keys.key_features(xa, xb, 0.5)
    for c, m in enumerate(own.maps_):
        m.weights_ = np.ascontiguousarray(m.weights_[:1] + 0.25)  # one neuron, moved
    key2, chosen = engine.keys.key_features(xa, xb, 0.5)
    assert chosen == [0] * len(own.maps_)
    for c, m in enumerate(own.maps_):
        assert np.allclose(key2[own.space_.class_dims[c]], m.weights_[0])
    assert not np.allclose(key1, key2)
