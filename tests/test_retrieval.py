"""Retrieval transitions (issue "Transitions that move like real people"): what they must show.

A library is learned from Bandai clips of some styles and the transitions are made on clips of
*other* styles (the library never saw them): the retrieved frames are real library frames up
to the seam correction, planted feet stay put, B is reached exactly, an unrelated library falls
back to interpolation, results are deterministic, ``alpha`` trades the match at A against the
match at B monotonically, and the library survives the map file.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from posturemap.io import bvh
from posturemap import cli
from posturemap.core import kernels, quat
from posturemap.synth import retrieval, trajectory
from posturemap.core.joints import foot_joints, key_joints, leg_toes
from posturemap.learn.model import MapFileError, PostureMap
from posturemap.core.motion import Motion, concatenate
from posturemap.core.skeleton import fk
from posturemap.synth import engine as engine_module
from posturemap.synth.engine import TransitionEngine, transition
from posturemap.synth.request import RequestError

LIBRARY = ("walk_normal_001", "walk_happy_001", "walk_tired_001", "run_normal_001", "run_happy_001",
           "walk-left_normal_001", "walk-right_normal_001", "dash_normal_001")
HELD_OUT = ("walk_angry_001", "run_proud_001", "walk_old_001")
UNRELATED = ("bow_normal_001", "bow_happy_001")
UP = 1


@pytest.fixture(scope="module")
def clips(bandai_paths):
    paths = bandai_paths(LIBRARY + HELD_OUT + UNRELATED)
    return {n: bvh.read(p) for n, p in paths.items()}


@pytest.fixture(scope="module")
def model(clips):
    return PostureMap(seed=0).fit([clips[n] for n in LIBRARY], list(LIBRARY))


@pytest.fixture(scope="module")
def engine(model, clips):
    # The library's retrieval: the gaps below lie inside the held-out clips, whose own motion
    # (A's before the gap, B's after it) would be searched as well (tested on its own below).
    eng = TransitionEngine(model)
    eng.own_seconds = 0.0
    for n in HELD_OUT:
        eng.add(n, clips[n])
    return eng


def windows(clips, length, count, seed=0):
    """Seeded in-betweening windows (clip, a_end, b_start) inside the held-out clips."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        name = HELD_OUT[int(rng.integers(len(HELD_OUT)))]
        a_end = int(rng.integers(10, len(clips[name]) - length - 12))
        out.append((name, a_end, a_end + length + 1))
    return out


# -- the library ------------------------------------------------------------------------------
def test_library_holds_every_training_frame_once_each_way(model, clips):
    lib = model.library_
    n = sum(len(clips[c]) for c in LIBRARY)
    assert lib.recorded == n and len(lib) == 2 * n  # the recorded clips, then each played backwards
    assert list(np.diff(lib.clip_start)) == [len(clips[c]) for c in LIBRARY] * 2
    assert lib.clip_names == LIBRARY + tuple(f"{c} (reversed)" for c in LIBRARY)
    # The inverted index lists every frame exactly once, under its own winning neuron.
    assert np.array_equal(np.sort(lib.index_frames), np.arange(len(lib)))
    for k in (0, int(lib.win[len(lib) // 2]), int(lib.win.max())):
        frames = lib.index_frames[lib.index_ptr[k]: lib.index_ptr[k + 1]]
        assert np.all(lib.win[frames] == k)
    # The rotations are the clips' own (root: its tilt, the rest unchanged), then reversed.
    first = clips[LIBRARY[0]]
    f = len(first)
    joints = [j for j in range(first.skeleton.num_joints) if j != model.space_.root]
    assert np.allclose(lib.rots[:f, joints], first.rotations[:, joints], atol=1e-6)
    back = slice(n, n + f)
    assert np.array_equal(lib.rots[back], lib.rots[:f][::-1])
    assert np.array_equal(lib.contacts[back], lib.contacts[:f][::-1])
    # Played backwards, every velocity turns round: frame i of the reversed clip moves as
    # frame f - i of the recorded one, the other way.
    assert np.allclose(lib.vel[back][1:], -lib.vel[:f][::-1][:-1], atol=1e-3)
    assert np.allclose(lib.root[back][1:, 3], -lib.root[:f][::-1][:-1, 3], atol=1e-3)  # turning rate
    speed = np.linalg.norm(lib.root[:, :3], axis=1)  # the root's velocity: the same speed
    assert np.allclose(speed[back][1:], speed[:f][::-1][:-1], rtol=1e-3, atol=1e-3)
    assert 200 < lib.nbytes_per_frame() < 1000


def test_a_library_can_keep_to_the_recorded_direction(clips):
    fwd = PostureMap(seed=0, library="recorded").fit([clips[n] for n in LIBRARY[:2]], list(LIBRARY[:2]))
    assert len(fwd.library_) == fwd.library_.recorded == sum(len(clips[n]) for n in LIBRARY[:2])


def test_walking_feet_are_planted_about_half_the_time(model):
    lib = model.library_
    walk = slice(lib.clip_start[0], lib.clip_start[1])
    share = lib.contacts[walk].mean(axis=0)
    # A walk has each foot on the ground for about 60% of the cycle; a swinging foot is not.
    assert np.all((share > 0.35) & (share < 0.85)), share
    assert lib.contacts[walk].any(axis=1).mean() > 0.9  # double or single support, never flight


def test_the_library_counts_its_toes_heights_and_the_lock_takes_its_clearance(model, clips, engine, monkeypatch):
    # The library's toe counts are its recorded clips' (feet.toe_height_counts of each, summed:
    # the reversed copies move as fast at the same heights); its clearance is their curve, and
    # the engine's foot lock is given it.
    from posturemap.core.joints import leg_chains, leg_length
    from posturemap.core.motion import up_axis
    from posturemap.synth import engine as engine_module, feet

    lib = model.library_
    sk = clips[LIBRARY[0]].skeleton
    chains = leg_chains(sk)
    toes, body = leg_toes(sk, chains), leg_length(sk, chains)
    up = up_axis(clips[LIBRARY[0]])
    expected = sum(feet.toe_height_counts(fk(sk.parents, clips[c].rotations, clips[c].positions)[1][:, toes],
                                          up, clips[c].fps, body) for c in LIBRARY)
    np.testing.assert_array_equal(lib.toe_counts, expected)
    np.testing.assert_array_equal(lib.clearance, feet.clearance_curve(expected))
    assert np.all(lib.clearance > 0) and lib.clearance.max() < 0.1  # every bin counted, within the counts' range
    seen = []

    def spy(*args, **kw):
        seen.append(args[14] if len(args) > 14 else kw.get("clearance"))
        return feet.lock_feet(*args, **kw)

    monkeypatch.setattr(engine_module, "lock_feet", spy)
    name = HELD_OUT[0]
    engine.generate(name, name, length=25, a_end=30, b_start=56, align=False, method="auto", foot_lock=True)
    assert len(seen) == 1 and seen[0] is lib.clearance


@pytest.mark.parametrize("older", [None, "library_toe_counts"])
def test_a_map_file_without_toe_counts_loads_with_the_fixed_clearance(model, tmp_path, older):
    # Map files written before the library counted its toes load; the lock then keeps to TOE_CLEAR.
    # So do those whose counts measured the toes' speed by central differences (their member's
    # older name): such counts would read a lower curve than the lock's speeds ask of it.
    path = tmp_path / "old.npz"
    model.save(path)
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "library_toe_step_counts"}
        if older:
            arrays[older] = z["library_toe_step_counts"]
    np.savez(path, **arrays)
    back = PostureMap.load(path)
    assert back.library_.toe_counts is None and back.library_.clearance is None
    assert len(back.library_) == len(model.library_)


def test_key_joints_are_found_by_name(model):
    sk = model.skeleton_
    lower, upper = key_joints(sk)
    names = [sk.names[j] for j in np.concatenate([lower, upper])]
    assert {"Foot_L", "Foot_R", "LowerLeg_L", "LowerLeg_R", "Hand_L", "Hand_R", "Head"} <= set(names), names


# -- the replay -------------------------------------------------------------------------------
def test_retrieved_frames_are_real_library_frames_up_to_the_seam_correction(engine, clips, monkeypatch):
    monkeypatch.setattr(retrieval, "WARPS", (1.0,))  # no time warp: whole library frames
    # The upper body's top joints unturned (their lift over the legs' pelvis: the next test).
    monkeypatch.setattr(retrieval, "UPPER_LIFT", 0.0)
    lib = engine.model.library_
    rt = retrieval.Retriever(engine, lib)
    length = 45
    blend = 12.0
    checked_middle = 0
    for name, a_end, b_start in windows(clips, length, 6, seed=1):
        tr = engine.tracks[name]
        res = retrieval.retrieve(rt, tr, tr, a_end, b_start, length, 0.5, False, top_k=1, blend=blend)
        d = length + 1
        curves = retrieval.offset_curves(np.arange(1, length + 1), d, blend)
        for part, mask in (("lower", rt.lower_mask), ("upper", rt.upper_mask)):
            info = res.info["parts"][part]
            first, last = info["frames"]
            assert abs(last - first) == d and info["reversed"] == (last < first)
            step = -1 if info["reversed"] else 1
            frames = lib.library_frame(info["clip"], first) + step * np.arange(-1, d + 2)  # t = -1 .. d + 1
            src = quat.normalize(lib.rots[frames][:, mask].astype(float))
            a2, b2 = tr.rots[[a_end - 1, a_end]][:, mask], tr.rots[[b_start, b_start + 1]][:, mask]

            def rel(p, q):
                return quat.log(quat.mul(p, quat.inv(q)))

            seam = [rel(a2[1], src[1]), rel(a2[1], a2[0]) - rel(src[1], src[0]),
                    rel(b2[0], src[-2]), rel(b2[1], b2[0]) - rel(src[-1], src[-2])]
            # Each new frame is the library frame turned by the seam offsets, whose angle is at
            # most the sum of the four offsets' angles weighted by their curves.
            bound = sum(np.abs(curves[i])[:, None] * np.linalg.norm(seam[i], axis=-1)[None] for i in range(4))
            angle = quat.angle_between(res.rots[:, mask], src[2:-2])
            assert np.all(angle <= bound + 1e-5), (part, float((angle - bound).max()))
            # Where the velocity offsets have faded, the frame is the library frame turned by the
            # value offsets alone, carried from A's into B's: exp((1 - s) r_A + s r_B) * frame.
            middle = np.flatnonzero((curves[1] == 0) & (curves[3] == 0))
            turn = curves[0, middle, None, None] * seam[0] + curves[2, middle, None, None] * seam[2]
            expected = quat.mul(quat.exp(turn), src[2:-2][middle])
            assert np.allclose(quat.angle_between(res.rots[middle][:, mask], expected), 0.0, atol=1e-5)
            checked_middle += len(middle)
    assert checked_middle > 0


def _seam_corrected_middle(src, a2, b2, curves):
    """Frames ``src`` (t = -1 .. d + 1, (T, M, 4)) turned by the seam value offsets, carried from
    A's (a2) into B's (b2), where the velocity offsets have faded: (frames, the new frames' indices)."""
    def rel(p, q):
        return quat.log(quat.mul(p, quat.inv(q)))

    middle = np.flatnonzero((curves[1] == 0) & (curves[3] == 0))
    turn = curves[0, middle, None, None] * rel(a2[1], src[1]) + curves[2, middle, None, None] * rel(b2[0], src[-2])
    return quat.mul(quat.exp(turn), src[2:-2][middle]), middle


def test_the_upper_body_keeps_its_own_pelvis_orientation_by_the_lift(engine, clips, monkeypatch):
    # The upper segments were recorded over their own pelvis. At UPPER_LIFT 1 the spine's top, in
    # the heading frame (the legs' root tilt times its rotation), is the upper library frame's
    # (its own root tilt times its spine), each seam-corrected; at 0 it hangs from the legs'
    # pelvis as recorded; in between it turns that fraction of the way, about one axis.
    monkeypatch.setattr(retrieval, "WARPS", (1.0,))
    rt = retrieval.Retriever(engine, engine.model.library_)
    lib, root, tops = rt.lib, engine._root, rt.upper_tops
    assert [engine.skeleton.names[j] for j in tops] == ["Spine"]
    length, blend = 45, 12.0
    d = length + 1
    curves = retrieval.offset_curves(np.arange(1, length + 1), d, blend)
    checked = 0
    for name, a_end, b_start in windows(clips, length, 6, seed=3):
        tr = engine.tracks[name]
        res = {}
        for lift in (0.0, 0.5, 1.0):
            monkeypatch.setattr(retrieval, "UPPER_LIFT", lift)
            res[lift] = retrieval.retrieve(rt, tr, tr, a_end, b_start, length, 0.5, False, top_k=1, blend=blend)
        info = res[1.0].info["parts"]["upper"]
        first, last = info["frames"]
        step = -1 if info["reversed"] else 1
        frames = lib.library_frame(info["clip"], first) + step * np.arange(-1, d + 2)
        cols = np.concatenate([[root], tops])
        src = quat.normalize(lib.rots[frames][:, cols].astype(float))
        a2, b2 = tr.rots[[a_end - 1, a_end]][:, cols], tr.rots[[b_start, b_start + 1]][:, cols]
        own, middle = _seam_corrected_middle(src, a2, b2, curves)
        got = quat.mul(res[1.0].rots[middle][:, [root]], res[1.0].rots[middle][:, tops])
        assert np.allclose(quat.angle_between(got, quat.mul(own[:, :1], own[:, 1:])), 0.0, atol=1e-5)
        # The legs are the same whatever the lift; at 0.5 the top joints turn half of 1's turn.
        np.testing.assert_array_equal(res[0.0].rots[:, rt.lower_mask], res[1.0].rots[:, rt.lower_mask])
        full = quat.mul(res[1.0].rots[:, tops], quat.inv(res[0.0].rots[:, tops]))
        full *= np.where(full[..., :1] < 0, -1.0, 1.0)  # the short arc, as the lift turns
        half = quat.mul(res[0.5].rots[:, tops], quat.inv(res[0.0].rots[:, tops]))
        np.testing.assert_allclose(quat.angle_between(quat.exp(0.5 * quat.log(full)), half), 0.0, atol=1e-6)
        assert quat.angle_between(full, quat.identity(full.shape[:-1])).max() > 0.01  # the pelvises differ
        checked += len(middle)
    assert checked > 0


def test_planted_feet_stay_within_a_centimetre(engine, clips):
    # The held foot turns about its toe (the ankle rises and moves over it as the foot rolls):
    # the toe, where the foot meets the floor, is what stays put.
    sk = engine.skeleton
    toes = leg_toes(sk, engine._legs)
    held = 0
    for name, a_end, b_start in windows(clips, 30, 8, seed=2):
        rots, pos = engine.generate(name, name, length=30, a_end=a_end, b_start=b_start, align=False,
                                    method="retrieval", foot_lock=True)
        planted = engine.last["planted"]
        _, g = fk(sk.parents, rots, pos)
        for leg, toe in enumerate(toes):
            both = (planted[1:, leg] >= 1.0) & (planted[:-1, leg] >= 1.0)
            step = np.linalg.norm(np.diff(g[:, toe][:, [0, 2]], axis=0), axis=-1)
            assert np.all(step[both] < 1.0), (name, a_end, leg, step[both].max())
            held += int(both.sum())
    assert held > 40  # the feet were planted for a good part of these walks and runs


def test_partly_confident_legs_still_plant_the_segments_feet(engine, clips, monkeypatch):
    # Legs blended with the fallback (confidence 0.3) keep the retrieved segment's contacts: the
    # same feet are planted as with full confidence, and held within a centimetre.
    sk, ankles = engine.skeleton, [c[2] for c in engine._legs]
    name, a_end, b_start = "run_proud_001", 40, 71  # a run: blended with the fallback, its feet glide
    kw = dict(length=30, a_end=a_end, b_start=b_start, align=False, method="retrieval", foot_lock=True)
    engine.generate(name, name, **kw)
    assert engine.last["retrieval"]["parts"]["lower"]["distance"] < retrieval.CONTACTS_WITHIN
    full = engine.last["planted"] >= 1.0
    assert full.sum() > 10
    conf = retrieval.confidences
    monkeypatch.setattr(retrieval, "confidences", lambda *a, **k: [0.3 * c for c in conf(*a, **k)])
    rots, pos = engine.generate(name, name, **kw)
    assert engine.last["retrieval"]["parts"]["lower"]["confidence"] < 0.5
    planted = engine.last["planted"] >= 1.0
    assert planted.sum() >= 0.8 * full.sum()
    _, g = fk(sk.parents, rots, pos)
    for leg, ankle in enumerate(ankles):
        both = planted[1:, leg] & planted[:-1, leg]
        step = np.linalg.norm(np.diff(g[:, ankle][:, [0, 2]], axis=0), axis=-1)
        assert np.all(step[both] < 1.0), (leg, step[both].max())


def test_inbetweening_steadies_the_head_halfway_to_the_fallbacks(engine, clips, monkeypatch):
    # B fixed: the head's orientation in the world goes HEAD_GAZE of the way from the retrieved
    # one to the fallback's (damped, at 30 frames), its ancestors and every other joint as they
    # were; between clips it stays the retrieved one. (Confidences at 0.8 of the match's.)
    sk = engine.skeleton
    rt = retrieval.Retriever(engine, engine.model.library_)
    head = int(rt.head_chain[-1])
    assert sk.names[head] == "Head" and rt.upper_mask[head]
    name, a_end, b_start = "run_proud_001", 40, 71
    kw = dict(length=30, a_end=a_end, b_start=b_start, foot_lock=False)
    def world(r):
        return fk(sk.parents, r, np.zeros(r.shape[:-1] + (3,)))[0][:, head]
    out = {}
    conf = retrieval.confidences
    for gaze in (0.0, retrieval.HEAD_GAZE):
        monkeypatch.setattr(retrieval, "HEAD_GAZE", gaze)
        for align in (False, True):
            with monkeypatch.context() as m:  # between clips this match is full: make it partial
                m.setattr(retrieval, "confidences", lambda *a, **k: [0.8 * c for c in conf(*a, **k)])
                out[gaze, align] = engine.generate(name, name, method="retrieval", align=align, **kw)[0].copy()
            got = [engine.last["retrieval"]["parts"][p]["confidence"] for p in ("lower", "upper")]
            assert 0.0 < min(got) < 1.0 and got[1] > 0.0  # the fallback runs
    damped = engine.generate(name, name, method="damped", align=False, **kw)[0]
    np.testing.assert_array_equal(out[0.0, True], out[retrieval.HEAD_GAZE, True])
    own, steadied = out[0.0, False], out[retrieval.HEAD_GAZE, False]
    others = np.arange(sk.num_joints) != head
    np.testing.assert_array_equal(own[:, others], steadied[:, others])
    whole = quat.angle_between(world(own), world(damped))
    assert whole.max() > np.radians(3.0)
    np.testing.assert_allclose(quat.angle_between(world(own), world(steadied)), retrieval.HEAD_GAZE * whole,
                               atol=1e-6)
    np.testing.assert_allclose(quat.angle_between(world(steadied), world(damped)),
                               (1 - retrieval.HEAD_GAZE) * whole, atol=1e-6)


def test_the_upper_body_follows_the_legs_and_is_full_up_to_twice_their_distance():
    for align in (False, True):
        assert_the_confidences(align)


def assert_the_confidences(align):
    def conf(distance, still, upper, both=True):
        return retrieval.confidences(distance, still, upper, both, align=align)

    lo, hi = retrieval.CONF_RANGE[align]
    ulo, uhi = retrieval.UPPER_CONF_RANGE[align]
    # Another style's arms are far: much of it is posture, which the offsets carry.
    assert ulo == 2 * lo and uhi >= hi
    # Legs: by their match distance (full below CONF_RANGE[0], none above [1]), times still.
    assert conf([lo, 0.0], 1.0, 1.0) == [1.0, 1.0]
    assert conf([hi + 1, 0.0], 1.0, 1.0) == [0.0, 0.0]  # the arms follow: an unrelated library
    assert conf([0.0, 0.0], 0.0, 1.0) == [0.0, 0.0]  # standing still: interpolated
    legs = [conf([d, 0.0], 1.0, 1.0)[0] for d in np.linspace(lo - 2, hi + 2, 30)]
    assert legs[0] == 1.0 and legs[-1] == 0.0 and np.all(np.diff(legs) <= 0)
    # The upper body over UPPER_CONF_RANGE: at a distance the legs accept only in part, full.
    assert conf([ulo, 0.0], 1.0, 1.0)[0] < 1.0 and conf([0.0, ulo], 1.0, 1.0)[1] == 1.0
    ups = [conf([0.0, d], 1.0, 1.0)[1] for d in np.linspace(ulo - 2, uhi + 2, 30)]
    assert ups[0] == 1.0 and ups[-1] == 0.0 and np.all(np.diff(ups) <= 0) and 0 < ups[15] < 1
    # ... in full while the legs are at least UPPER_FOLLOWS confident, less below, times `upper`.
    half = hi - retrieval.UPPER_FOLLOWS * (hi - lo)  # the legs' distance at that confidence
    assert conf([half, 0.0], 1.0, 1.0)[1] == pytest.approx(1.0)
    quarter = conf([half, 0.0], 0.5, 0.5)
    assert quarter[0] == pytest.approx(0.5 * retrieval.UPPER_FOLLOWS) and quarter[1] == pytest.approx(0.25)
    # A splice's halves are matched at one seam each: both parts over the legs' range, times still.
    assert conf([0.0, hi + 1], 1.0, 1.0, both=False) == [1.0, 0.0]
    assert conf([0.0, 0.0], 1.0, 0.5, both=False) == [1.0, 0.5]
    if not align:  # in-betweening takes more of a far match, and less of a near one, than between clips
        near, far = retrieval.CONF_RANGE[True]
        assert retrieval.confidences([far, 0.0], 1.0, 1.0, align=True)[0] == 0.0
        assert conf([far, 0.0], 1.0, 1.0)[0] > 0.0
        assert retrieval.confidences([near, 0.0], 1.0, 1.0, align=True)[0] == 1.0
        assert conf([near, 0.0], 1.0, 1.0)[0] < 1.0


def test_offset_curves_put_the_ends_exactly_on_a_and_b():
    d, blend = 31.0, 9.0
    eps = 1e-6
    c = retrieval.offset_curves([0.0, eps, d - eps, d], d, blend)
    assert np.allclose(c[:, 0], [1, 0, 0, 0]) and np.allclose(c[:, 3], [0, 0, 1, 0])
    slope0, slope_d = (c[:, 1] - c[:, 0]) / eps, (c[:, 3] - c[:, 2]) / eps
    assert np.allclose(slope0, [0, 1, 0, 0], atol=1e-4) and np.allclose(slope_d, [0, 0, 0, 1], atol=1e-4)
    mid = retrieval.offset_curves(np.arange(blend, d - blend + 1), d, blend)
    assert np.all(mid[[1, 3]] == 0)  # the velocity offsets fade within blend frames of their seam
    # The value offsets carry A's into B's over the whole gap: they sum to 1 (a constant offset
    # stays constant), A's falls and B's rises throughout, B's the mirror image of A's.
    t = np.linspace(0.0, d, 50)
    c = retrieval.offset_curves(t, d, blend)
    assert np.allclose(c[0] + c[2], 1.0)
    assert np.all(np.diff(c[0]) < 0) and np.all(np.diff(c[2]) > 0)
    assert np.allclose(c[2], c[0][::-1])
    # At the new frames t = 1 .. d - 1, B's value offset never reaches 0 or 1 (A's and B's own frames do).
    rise = retrieval.hermite_offsets(int(d) - 1, blend)[2]
    assert rise[0] > 0 and rise[-1] < 1 and np.all(np.diff(rise) > 0)


def test_inbetweening_keeps_b_exactly_and_lands_the_root_on_it(model, clips):
    name = HELD_OUT[0]
    m = clips[name]
    a_end, length = 40, 30
    b_start = a_end + length + 1
    out = transition(m, m, model, length=length, a_end=a_end, b_start=b_start, align=False, method="retrieval")
    assert np.array_equal(out.rotations[b_start:], m.rotations[b_start:])
    assert np.array_equal(out.positions[b_start:], m.positions[b_start:])
    g = out.global_positions()[:, model.space_.root]
    step = np.linalg.norm(np.diff(g[a_end - 5: b_start + 6], axis=0), axis=-1)
    truth = np.linalg.norm(np.diff(m.global_positions()[a_end - 5: b_start + 6, model.space_.root], axis=0), axis=-1)
    assert step.max() < 1.5 * truth.max()  # no jump onto B: the root arrives at B's place


# -- confidence and fallback ------------------------------------------------------------------
def twisted(m: Motion) -> Motion:
    """``m`` with its thighs and shins twisted 90 degrees about their bones (Bandai's bones lie
    along their joints' x axes): legs still upright, in postures no walk or run comes near."""
    r = m.rotations.copy()
    for name in ("UpperLeg_L", "UpperLeg_R", "LowerLeg_L", "LowerLeg_R"):
        j = m.skeleton.index(name)
        r[:, j] = quat.mul(r[:, j], quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.pi / 2))
    return Motion(m.skeleton, r, m.positions, m.fps)


def test_an_unrelated_library_falls_back_to_interpolation(clips, monkeypatch):
    from posturemap.synth import engine as engine_module

    # In-betweening ramps the confidence over a wide range of match distances: a bow's legs for
    # a run's, 30 degrees apart, are still partly confident there ...
    bows = TransitionEngine(PostureMap(seed=0).fit([clips[n] for n in UNRELATED], list(UNRELATED)))
    bows.own_seconds = 0.0  # the library alone (the run's own motion would be searched too)
    bows.add("run", clips["run_proud_001"])
    bows.generate("run", "run", method="retrieval", length=30, a_end=40, b_start=71, align=False, foot_lock=False)
    legs = bows.last["retrieval"]["parts"]["lower"]
    assert retrieval.CONF_RANGE[True][1] < legs["distance"] < retrieval.CONF_RANGE[False][1]
    assert 0.0 < legs["confidence"] < 1.0
    # A bow's planted feet are not a run's: beyond CONTACTS_WITHIN the lock finds them itself.
    given = []
    lock = bows._lock_feet
    monkeypatch.setattr(bows, "_lock_feet", lambda *a: given.append(a[-1]) or lock(*a))
    bows.generate("run", "run", method="retrieval", length=30, a_end=40, b_start=71, align=False)
    assert legs["distance"] > retrieval.CONTACTS_WITHIN and given == [None]
    # ... and bows on twisted legs are beyond it.
    eng = TransitionEngine(PostureMap(seed=0).fit([twisted(clips[n]) for n in UNRELATED], list(UNRELATED)))
    eng.own_seconds = 0.0
    eng.add("run", clips["run_proud_001"])
    kw = dict(length=30, a_end=40, b_start=71, align=False, foot_lock=False)
    rots, pos = eng.generate("run", "run", method="retrieval", **kw)
    info = eng.last["retrieval"]
    assert info["confidence"] == 0.0 and info["parts"]["lower"]["distance"] > retrieval.CONF_RANGE[False][1]
    assert_the_fallback(eng, "run", rots.copy(), pos.copy(), kw)
    # Between clips the range is narrower: the bows themselves are too far for a run.
    kw = dict(length=30, a_end=40, b_start=71, foot_lock=False)
    rots, pos = (x.copy() for x in bows.generate("run", "run", method="retrieval", **kw))  # buffers
    info = bows.last["retrieval"]
    assert info["confidence"] == 0.0 and info["parts"]["lower"]["distance"] > retrieval.CONF_RANGE[True][1]
    fb_r, fb_p = bows.generate("run", "run", method="damped", **kw)
    assert fb_r is not rots
    fb_r, fb_p = fb_r.copy(), fb_p.copy()
    engine_module._unbend_limbs(bows, bows.tracks["run"], bows.tracks["run"], kw["a_end"], kw["b_start"], fb_r,
                                fb_p)  # as assert_the_fallback
    assert np.array_equal(rots, fb_r) and np.array_equal(pos, fb_p)


def assert_the_fallback(eng, name, rots, pos, kw):
    """``rots``/``pos``, made in ``name``'s gap with fields ``kw`` (B fixed, no foot lock), are the
    fallback's (``damped`` at this length), but for the root over the floor: B stays where it is,
    so the root runs on the seams' own path (the spline's); and its knees are held as retrieval
    holds them (no further back than the library's and the clip's own go: damped carries a
    straightening knee on past straight)."""
    from posturemap.synth import engine as engine_module

    assert retrieval.fallback_method(kw["length"], 30.0) == "damped"
    fb_r, fb_p = (x.copy() for x in eng.generate(name, name, **{**kw, "method": "damped"}))
    engine_module._unbend_limbs(eng, eng.tracks[name], eng.tracks[name], kw["a_end"], kw["b_start"], fb_r, fb_p)
    root, others = eng._root, np.arange(eng.skeleton.num_joints) != eng._root
    assert np.array_equal(rots, fb_r) and np.array_equal(pos[:, others], fb_p[:, others])
    track = eng.tracks[name]
    path = trajectory.seam_path(track, track, kw["a_end"], kw["b_start"], kw["length"], UP)
    np.testing.assert_allclose(pos[:, root, [0, 2]], path[:, [0, 2]], rtol=0, atol=1e-9)
    assert np.array_equal(pos[:, root, UP], fb_p[:, root, UP])
    assert np.abs(pos[:, root, [0, 2]] - fb_p[:, root, [0, 2]]).max() > 1e-3  # not damped's own path


@pytest.mark.parametrize("a, a_end, b, b_start, length", [
    ("walk-left_normal_001", 30, "dash_normal_001", 9, 60), ("walk_happy_001", 30, "dash_normal_001", 9, 60)])
def test_partly_confident_legs_leave_the_gap_at_bs_velocity(model, clips, a, a_end, b, b_start, length):
    # The legs a third confident (or less): the root's path is the blend of the retrieved one and
    # the fallback's, which place B turned far apart. Each ends at B's velocity turned its own way;
    # their blend, at a shorter one turned between, so the root jerked at B's seam by 2.8-3.5 cm
    # a frame (LaFAN1's sidesteps into a jog: 46 cm/s into 306 cm/s). Now the root leaves the gap
    # at B's own velocity, placed: the change at the seam within B's own first frames'.
    eng = TransitionEngine(model)
    eng.add("a", clips[a])
    eng.add("b", clips[b])
    r, p = eng.generate("a", "b", length=length, a_end=a_end, b_start=b_start, method="retrieval", foot_lock=False)
    assert 0.0 < eng.last["retrieval"]["parts"]["lower"]["confidence"] < 0.5
    out = concatenate([clips[a][: a_end + 1], Motion(clips[a].skeleton, r.copy(), p.copy(), clips[a].fps),
                       eng.continuation("b", b_start)])
    hips = out.global_positions()[:, clips[a].skeleton.index("Hips")]
    change = np.linalg.norm(np.diff(hips, 2, axis=0), axis=1)  # change[t]: the velocity's at frame t + 1
    seam = a_end + length  # the velocity's change at B's first frame
    assert change[seam] <= change[seam + 1: seam + 6].max()


@pytest.mark.parametrize("align, turns", [(False, 1.0), (True, 1.15)])
def test_partly_confident_legs_blend_a_root_that_spins_a_whole_turn_without_a_jump(model, clips, monkeypatch, align,
                                                                                     turns):
    # The retrieved root turns a whole turn more than the fallback's over the gap (a segment
    # running in a circle), the legs 0.55 confident. Blended as one rotation on the arc that goes
    # on, the two roots came back nearly together from the other side, where that arc's axis
    # swings round from frame to frame: 0.55 of a whole turn about a swinging axis turned the
    # hips 75 and 179 degrees in two frames (a dash into a run, 150 frames). Blended as a turn
    # about the up axis and a tilt, the hips turn at most by the clips' own steps plus 0.55 of
    # the spin's, in the gap and into B, and B is met: placed the way round the blend went
    # (between clips) or, where B stays put, with the whole turn taken off the blend.
    eng = TransitionEngine(model)
    a, a_end, b, b_start, length = "walk_angry_001", 30, "run_proud_001", 40, 45
    eng.add("a", clips[a])
    eng.add("b", clips[b] if align else clips[a])
    if not align:
        b, b_start = a, a_end + length + 1
    u = np.arange(1, length + 1) / (length + 1.0)
    spin = 2.0 * np.pi * turns * u * u * (3.0 - 2.0 * u)  # eased in and out
    conf = retrieval.confidences
    monkeypatch.setattr(retrieval, "confidences", lambda *x, **k: [0.55 * c for c in conf(*x, **k)])

    def spinning(make):
        def made(*x, **k):
            res = make(*x, **k)
            if res is not None and res.heading is not None:
                res.heading = res.heading + spin
                res.dtheta = res.dtheta + 2.0 * np.pi * turns
            return res
        return made

    monkeypatch.setattr(retrieval, "replay", spinning(retrieval.replay))
    monkeypatch.setattr(engine_module, "spliced", spinning(engine_module.spliced))
    r, p = eng.generate("a", "b", length=length, a_end=a_end, b_start=b_start, align=align, method="retrieval",
                        foot_lock=False)
    c = eng.last["retrieval"]["parts"]["lower"]["confidence"]
    assert 0.3 < c < 0.6
    hips = clips[a].skeleton.index("Hips")

    def steps(m):  # the hips' turn from frame to frame, degrees
        g = m.global_transforms()[0][:, hips]
        return np.degrees(2.0 * np.arccos(np.clip(np.abs(np.sum(g[1:] * g[:-1], axis=-1)), 0.0, 1.0)))

    own = max(steps(clips[a]).max(), steps(clips[b]).max())
    out = concatenate([clips[a][: a_end + 1], Motion(clips[a].skeleton, r.copy(), p.copy(), clips[a].fps),
                       eng.continuation("b", b_start, align)[:3]])
    turned = steps(out)[a_end - 1:]  # into the gap, through it and into B
    assert turned.max() <= own + c * np.degrees(np.diff(spin).max()) + 3.0, (turned.max(), own)


def test_a_related_library_is_confident_for_the_legs(engine, clips):
    # Walks and runs of other styles: the legs move alike (the arms carry more of the style).
    conf = []
    for name, a_end, b_start in windows(clips, 30, 8, seed=3):
        engine.generate(name, name, length=30, a_end=a_end, b_start=b_start, align=False, method="retrieval")
        conf.append(engine.last["retrieval"]["parts"]["lower"]["confidence"])
    assert np.median(conf) > 0.5, conf


def test_a_map_without_library_uses_the_fallback(clips):
    bare = PostureMap(seed=0, library=False).fit([clips[n] for n in LIBRARY[:2]], list(LIBRARY[:2]))
    assert bare.library_ is None
    eng = TransitionEngine(bare)
    eng.add("w", clips["walk_angry_001"])
    # Its own motion replays where A's frames before the gap and B's after it hold a segment ...
    eng.generate("w", "w", length=20, a_end=60, b_start=81, method="retrieval")
    assert eng.last["retrieval"]["own"]
    # ... not where too few of them are left (A's first 11 frames, B's last 11: a segment of the
    # shortest warp has 16), nor without it: there it is the fallback's motion, its knees and
    # elbows held to how far the clip's kept frames bend them (without a library: its left
    # elbow folds further than the walker's ever does in the second).
    from posturemap.synth import engine as engine_module

    turned = []
    for seconds, a_end in ((eng.own_seconds, 10), (0.0, 60)):
        eng.own_seconds = seconds
        b_start = len(clips["walk_angry_001"]) - 11 if seconds else a_end + 21
        kw = dict(length=20, a_end=a_end, b_start=b_start, foot_lock=False)
        r, _ = eng.generate("w", "w", method="retrieval", **kw)
        r = r.copy()
        assert eng.last["retrieval"] is None
        fb, fb_p = (x.copy() for x in eng.generate("w", "w", method=retrieval.fallback_method(20, 30.0), **kw))
        raw = fb.copy()
        engine_module._unbend_limbs(eng, eng.tracks["w"], eng.tracks["w"], a_end, b_start, fb, fb_p)
        assert np.array_equal(r, fb)
        turned.append(not np.array_equal(fb, raw))
    assert turned[1]


_LOADS_PROBE = """
import json, sys
import numpy as np
from numba.core.registry import CPUDispatcher
from posturemap.core import kernels
from posturemap.io import bvh
from posturemap.learn.model import PostureMap
from posturemap.synth import retrieval
from posturemap.synth.engine import TransitionEngine
kernels.compiled(), retrieval._compiled()
import posturemap.core.numba_kernels as nk, posturemap.synth.retrieval_numba as rn
kernels_ = {f"{m.__name__}.{k}": v for m in (nk, rn) for k, v in vars(m).items() if isinstance(v, CPUDispatcher)}
map_path, warm, *paths = sys.argv[1:]
eng = TransitionEngine(PostureMap.load(map_path))
for i, p in enumerate(paths):
    eng.add(str(i), bvh.read(p))
if warm == "1":
    eng.warm_up()
before = {k: len(d.signatures) for k, d in kernels_.items()}
rng = np.random.default_rng(0)
for _ in range(40):
    a, b = (str(int(i)) for i in rng.integers(len(paths), size=2))
    na, nb = len(eng.tracks[a].gpos), len(eng.tracks[b].gpos)
    eng.generate(a, b, length=int(rng.integers(3, 61)), alpha=float(rng.random()), a_end=int(rng.integers(na)),
                 b_start=int(rng.integers(nb)), align=bool(rng.integers(2)))
print(json.dumps(sorted(k for k, d in kernels_.items() if len(d.signatures) != before[k])))
"""


def test_warm_up_loads_every_kernel_the_default_calls(model, bandai_paths, tmp_path):
    """After ``warm_up``, 40 seeded default transitions (any length up to 2 s, seams, alpha, placed
    or in-betweening) of a fresh process load no compiled kernel (each load is a 10-500 ms
    hitch); without it they load several, so the probe sees them."""
    map_path = tmp_path / "lib.npz"
    model.save(map_path)
    paths = [str(p) for p in bandai_paths(HELD_OUT).values()]

    def loaded(warm: str) -> list:
        proc = subprocess.run([sys.executable, "-c", _LOADS_PROBE, str(map_path), warm, *paths],
                              capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout.strip().splitlines()[-1])

    assert loaded("1") == []
    cold = loaded("0")
    assert {"posturemap.synth.retrieval_numba.search_parts", "posturemap.synth.retrieval_numba.spliced",
            "posturemap.synth.retrieval_numba.open_columns", "posturemap.core.numba_kernels.lock_legs"} <= set(cold)


def test_engines_of_one_library_share_its_search_rows(model, clips):
    # Each transition() call makes an engine; the rows of the library's frames (18 MB for
    # bandai1, about 50 ms to build) are built once per library, not per engine.
    name = HELD_OUT[0]
    engines = [TransitionEngine(model) for _ in range(2)]
    for eng in engines:
        eng.add(name, clips[name])
        eng.generate(name, name, length=20, a_end=30, b_start=51, align=False, method="retrieval")
    first, second = (eng._retriever.lists for eng in engines)
    assert first is second and first[0][0][0].shape == (len(model.library_), first[0][0][0].shape[1])
    # Another library (what partial_fit makes) has its own.
    other = model._build_library([clips[n] for n in LIBRARY[:2]], list(LIBRARY[:2]))
    rt = retrieval.Retriever(engines[0], other)
    assert rt.lists is not first and len(rt.lists[1]) == len(other)


def test_a_fork_makes_the_same_transitions_with_its_own_buffers_and_clips(model, clips):
    # The studio serves each request from a fork (one per thread): the same frames, the clips
    # and the library's rows shared, the output buffers and the list of clips its own.
    parent = TransitionEngine(model)
    for n in HELD_OUT[:2]:
        parent.add(n, clips[n])
    args = dict(length=30, a_end=40, b_start=0, method="retrieval")
    rots, pos = parent.generate(*HELD_OUT[:2], **args)
    kept = rots.copy(), pos.copy()
    child = parent.fork()
    assert child.tracks[HELD_OUT[0]] is parent.tracks[HELD_OUT[0]]
    assert child._retriever.lists is parent._retriever.lists
    r2, p2 = child.generate(*HELD_OUT[:2], **args)
    assert r2 is not rots and np.array_equal(r2, kept[0]) and np.array_equal(p2, kept[1])
    child.generate(HELD_OUT[1], HELD_OUT[0], **args)  # the parent's frames stay as they were
    assert np.array_equal(rots, kept[0]) and np.array_equal(pos, kept[1])
    child.add(HELD_OUT[2], clips[HELD_OUT[2]])
    assert HELD_OUT[2] in child.tracks and HELD_OUT[2] not in parent.tracks


def test_a_replaced_clip_is_let_go_after_the_next_transition(model, clips):
    # The engine keeps each clip's knees' and elbows' bends (how far back they go) from its first
    # transition on; a clip replaced under its name (the studio's upload) is not kept by it, nor
    # are the clips before it.
    import gc
    import weakref

    eng = TransitionEngine(model)
    a, b = HELD_OUT[:2]
    eng.add(b, clips[b])
    gone = []
    for k in range(4):
        eng.add(a, clips[a][k:])  # a new clip under the same name
        gone.append(weakref.ref(eng.tracks[a]))
        eng.generate(a, b, length=20, a_end=40, b_start=0, method="auto", foot_lock=True)
    gc.collect()
    assert [ref() is None for ref in gone] == [True, True, True, False]
    # Nor does a fork copy one replaced since the last transition.
    eng.add(a, clips[a][5:])
    child = eng.fork()
    kept = list(child._limb_bends.values())
    assert len(kept) == 1 and kept[0][0] is child.tracks[b]  # B's, shared; not A's replaced one


def test_a_clips_knee_bounds_are_those_of_its_kept_frames_and_warm_up_makes_them(model, clips):
    # A transition reads how far back and how far forward each knee and elbow goes in A up to
    # its end and in B from its start: four rows of running minima and maxima, made once per
    # clip (in warm_up for the clips added).
    from posturemap.synth import engine as engine_module, hinges

    eng = TransitionEngine(model)
    for n in HELD_OUT[:3]:
        eng.add(n, clips[n])
    eng.warm_up()
    limbs = engine_module._library_limbs(eng, model.library_)
    assert len(limbs[3]) and len(eng._limb_bends) == 3
    for track in eng.tracks.values():
        first, last, first_max, last_max = engine_module._limb_bends(eng, track, limbs)
        bends = hinges.bend_frames(limbs[:3], track.motion.rotations, track.motion.positions)
        assert bends.min() < bends.max()
        for f in (0, 7, len(bends) // 2, len(bends) - 1):
            np.testing.assert_array_equal(first[f], bends[:f + 1].min(axis=0))
            np.testing.assert_array_equal(last[f], bends[f:].min(axis=0))
            np.testing.assert_array_equal(first_max[f], bends[:f + 1].max(axis=0))
            np.testing.assert_array_equal(last_max[f], bends[f:].max(axis=0))


def test_no_new_knee_folds_further_than_the_library_and_the_clips_kept_frames(engine):
    # damped, the retrieval's fallback, carries a walk's swinging shins on through 45 frames
    # into a run and folds a knee 179 degrees, the heel through the thigh (one of the library's
    # runs folds 118 at most); so did a 5 s fallback between two dashes, whose foot lock then
    # turned the folded leg's thigh 72 and 109 degrees in two frames. The limbs are held to the
    # furthest forward the library's knees and elbows go (or A's up to its end, B's from its
    # start), as to the furthest back: the knees past it turned back onto it, the turn fading in
    # and out over the frames around, the rest as they were.
    from posturemap.synth import engine as engine_module, hinges

    a, b, kw = "walk_angry_001", "run_proud_001", dict(length=45, a_end=10, b_start=71, foot_lock=False)
    rots, pos = (x.copy() for x in engine.generate(a, b, method="damped", **kw))
    limbs = engine_module._library_limbs(engine, engine.model.library_)
    _, _, _, least, most = limbs
    ta, tb = engine.tracks[a], engine.tracks[b]
    least = np.minimum(least, np.minimum(engine_module._limb_bends(engine, ta, limbs)[0][kw["a_end"]],
                                         engine_module._limb_bends(engine, tb, limbs)[1][kw["b_start"]]))
    most = np.maximum(most, np.maximum(engine_module._limb_bends(engine, ta, limbs)[2][kw["a_end"]],
                                       engine_module._limb_bends(engine, tb, limbs)[3][kw["b_start"]]))
    before = np.unwrap(hinges.bend_frames(limbs[:3], rots, pos), axis=0)  # as unbend reads them
    folded, back = before > most, before < least
    assert np.degrees(before - most).max() > 45.0 and folded.sum() > 10
    assert np.degrees(before).max() > 180.0  # folded past a half turn: reads -179 frame by frame
    held, hard = rots.copy(), rots.copy()
    engine_module._unbend_limbs(engine, ta, tb, kw["a_end"], kw["b_start"], held, pos)
    limits = (limbs[0], limbs[1], limbs[2], least, most)
    hinges.unbend(limits, hard, pos)  # onto the bounds at once, as before the fade
    after = np.unwrap(hinges.bend_frames(limbs[:3], held, pos), axis=0)
    assert np.all(after <= most + 1e-7) and np.all(after >= least - 1e-7)
    assert np.all(np.abs(after - before)[folded | back] > 1e-3)
    # Each frame turned toward the middle of its limb's range only, each knee accelerating within
    # the bound (or the damped motion's own, larger there); the frames it never reaches, as they were.
    assert np.all((after - before) * (before - 0.5 * (least + most)) <= 1e-9)
    accel = hinges.UNBEND_ACCEL / ta.motion.fps**2
    own = np.abs(np.diff(before, 2, axis=0))
    assert np.all(np.abs(np.diff(after, 2, axis=0)) <= np.maximum(accel, own) * 1.002)
    assert np.abs(np.diff(after, 2, axis=0)).max() < 0.5 * np.abs(np.diff(np.unwrap(
        hinges.bend_frames(limbs[:3], hard, pos), axis=0), 2, axis=0)).max()  # the corners at the bound gone
    untouched = np.all(after == before, axis=1)
    assert untouched.sum() > 5
    np.testing.assert_array_equal(held[untouched], rots[untouched])
    # The default there: retrieved legs, no knee past the bound either.
    out, out_p = engine.generate(a, b, method="auto", **kw)
    assert engine.last["method"] == "retrieval"
    assert np.all(hinges.bend_frames(limbs[:3], out, out_p) <= most + 1e-7)


def test_warm_up_needs_a_clip_and_leaves_the_last_transition(model, engine, clips):
    with pytest.raises(RequestError, match="add one first"):
        TransitionEngine(model).warm_up()
    name = HELD_OUT[0]
    engine.generate(name, name, length=20, a_end=30, b_start=51, align=False, method="retrieval")
    last = engine.last
    assert engine.warm_up(methods=("auto", "slerp")) == 2 * 3 * 2 * 2  # methods x gaps x seams x placings
    assert engine.last is last


# -- control ----------------------------------------------------------------------------------
def test_results_are_deterministic(model, clips, engine):
    args = dict(length=30, a_end=50, b_start=81, align=False, method="retrieval", foot_lock=True)
    r1, p1 = (x.copy() for x in engine.generate(HELD_OUT[1], HELD_OUT[1], **args))
    r2, p2 = engine.generate(HELD_OUT[1], HELD_OUT[1], **args)
    assert np.array_equal(r1, r2) and np.array_equal(p1, p2)
    fresh = TransitionEngine(PostureMap(seed=0).fit([clips[n] for n in LIBRARY], list(LIBRARY)))
    fresh.add(HELD_OUT[1], clips[HELD_OUT[1]])
    own = [x.copy() for x in fresh.generate(HELD_OUT[1], HELD_OUT[1], **args)]  # its own motion searched too
    assert fresh.last["retrieval"]["own"]
    fresh.own_seconds = 0.0  # the library alone, as `engine`'s
    r3, p3 = fresh.generate(HELD_OUT[1], HELD_OUT[1], **args)
    assert np.array_equal(r1, r3) and np.array_equal(p1, p3)
    again = TransitionEngine(fresh.model)
    again.add(HELD_OUT[1], clips[HELD_OUT[1]])
    for x, y in zip(own, again.generate(HELD_OUT[1], HELD_OUT[1], **args)):
        assert np.array_equal(x, y)


def test_alpha_trades_the_match_at_a_against_the_match_at_b(engine, clips):
    # alpha weighs the two seams of the one-segment search: 2 (1 - alpha) cost_A + 2 alpha
    # cost_B. For the chosen segment, the cost at A can only grow and the cost at B only fall as
    # alpha rises. (A splice moves its blend earlier as alpha rises: test_splice.py.)
    rng = np.random.default_rng(4)
    rt = retrieval.Retriever(engine, engine.model.library_)
    moved = 0
    for _ in range(6):
        a, b = rng.choice(HELD_OUT, 2, replace=False)
        a_end = int(rng.integers(20, len(clips[a]) - 1))
        b_start = int(rng.integers(0, len(clips[b]) - 20))
        costs = []
        for alpha in (0.0, 0.25, 0.5, 0.75, 1.0):
            res = retrieval.retrieve(rt, engine.tracks[a], engine.tracks[b], a_end, b_start, 24, alpha, True)
            p = res.info["parts"]["lower"]
            costs.append((p["cost_a"], p["cost_b"]))
        ca, cb = np.array(costs).T
        assert np.all(np.diff(ca) >= -1e-3) and np.all(np.diff(cb) <= 1e-3), costs
        moved += ca[-1] > ca[0] + 1e-3
    assert moved >= 3  # alpha did change the choice in most cases


# -- files, other frame rates, the command line ------------------------------------------------
def test_map_file_keeps_the_library(model, engine, tmp_path):
    path = tmp_path / "lib.npz"
    model.save(path)
    back = PostureMap.load(path)
    saved = back.library_.arrays()
    for k, v in model.library_.arrays().items():
        assert np.array_equal(saved[k], v), k
    for k in ("rots", "vel", "root", "index_frames", "clip_start"):  # the reversed half is rebuilt alike
        assert np.array_equal(getattr(back.library_, k), getattr(model.library_, k)), k
    eng = TransitionEngine(back)
    eng.own_seconds = engine.own_seconds  # the library's motion, as `engine`'s
    name = HELD_OUT[0]
    eng.add(name, engine.tracks[name].motion)
    args = dict(length=25, a_end=30, b_start=56, align=False, method="retrieval")
    r1 = engine.generate(name, name, **args)[0].copy()
    assert np.array_equal(r1, eng.generate(name, name, **args)[0])


@pytest.mark.parametrize("damage", ["nan", "shape", "clips", "index", "not-unit", "ints", "missing", "toe-counts",
                                    "toe-shape"])
def test_a_damaged_library_is_refused(model, tmp_path, damage):
    path = tmp_path / "lib.npz"
    model.save(path)
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    if damage == "nan":
        arrays["library_gpos"] = arrays["library_gpos"].copy()
        arrays["library_gpos"][3, 1] = np.nan
    elif damage == "shape":
        arrays["library_rots"] = arrays["library_rots"][:-1]
    elif damage == "clips":
        arrays["library_clip_start"] = arrays["library_clip_start"][::-1].copy()
    elif damage == "index":
        arrays["library_win"] = arrays["library_win"] + 100000
    elif damage == "not-unit":
        arrays["library_rots"] = arrays["library_rots"] * 2
    elif damage == "ints":
        arrays["library_pose"] = arrays["library_pose"].astype(np.int64)
    elif damage == "toe-counts":
        arrays["library_toe_step_counts"] = arrays["library_toe_step_counts"] - 0.5  # not whole, some negative
    elif damage == "toe-shape":
        arrays["library_toe_step_counts"] = arrays["library_toe_step_counts"][:, :-1]
    else:
        del arrays["library_rots"]
    np.savez(path, **arrays)
    with pytest.raises(MapFileError, match="library"):
        PostureMap.load(path)


def resample(m: Motion, factor: int) -> Motion:
    """``m`` at ``factor`` times its frame rate (SLERP of rotations, LERP of translations)."""
    t = np.arange((len(m) - 1) * factor + 1) / factor
    i0 = np.minimum(np.floor(t).astype(int), len(m) - 2)
    f = t - i0
    rots = quat.slerp(m.rotations[i0], m.rotations[i0 + 1], np.broadcast_to(f[:, None], (len(t), m.rotations.shape[1])))
    pos = m.positions[i0] + f[:, None, None] * (m.positions[i0 + 1] - m.positions[i0])
    return Motion(m.skeleton, rots, pos, m.fps * factor)


def test_a_clip_at_another_frame_rate_replays_the_library_at_its_speed(model, clips):
    fast = resample(clips["walk_angry_001"], 4)  # 120 fps against a 30 fps library
    eng = TransitionEngine(model)
    eng.own_seconds = 0.0  # the library's frames (the clip's own are at its rate)
    eng.add("w", fast)
    length = 119  # one second
    warps = []
    for a_end in (100, 250, 400):
        eng.generate("w", "w", length=length, a_end=a_end, b_start=a_end + length + 1, align=False, method="retrieval")
        info = eng.last["retrieval"]["parts"]["lower"]
        warps.append(info["warp"])
        frames = info["frames"][1] - info["frames"][0]
        assert abs(frames - 30 * info["warp"] * (length + 1) / 120) <= 1  # 30 library frames a second
    assert all(min(retrieval.WARPS) - 0.01 <= w <= max(retrieval.WARPS) + 0.01 for w in warps)


def test_the_search_holds_as_many_moments_at_any_frame_rate(model, clips):
    # A library recorded at 60 fps holds each moment of motion in two frames. The frames gathered
    # per seam and the segments averaged grow with its rate (Retriever.budget, segments_averaged;
    # a splice's halves too), so they hold as many moments (1/30 s apart) as the 30 fps library's:
    # the same one-second in-between at 60 fps searches as much motion. At 1,536 frames and 16
    # segments, as at 30 fps, they held about half as many. A library at 15 fps keeps the 30 fps
    # counts (retrieval.moments_scale).
    from posturemap.synth import splice

    def halved(m):
        return Motion(m.skeleton, m.rotations[::2], m.positions[::2], m.fps / 2)

    fast_lib = model._build_library([resample(clips[n], 2) for n in LIBRARY], list(LIBRARY))
    slow_lib = model._build_library([halved(clips[n]) for n in LIBRARY], list(LIBRARY))
    name, a_end, length = HELD_OUT[0], 40, 29  # one second at 30 fps
    counts = {}
    for factor, lib, clip in ((1, model.library_, clips[name]), (2, fast_lib, resample(clips[name], 2)),
                              (0.5, slow_lib, halved(clips[name]))):
        eng = TransitionEngine(model)
        track = eng.add(name, clip)
        rt = retrieval.Retriever(eng, lib)
        a, n = round(factor * a_end), round(factor * (length + 1)) - 1
        b = a + n + 1
        scale = max(factor, 1)

        def moments(frames):  # (clip, time in 30ths of a second)
            return len({(int(lib.clip_of[f]), round((f - int(lib.clip_start[lib.clip_of[f]])) * 30 / lib.fps))
                        for f in np.asarray(frames).tolist()})

        gathered = rt.gather_seams(track.features[a], track.features[b])
        assert rt.budget == scale * retrieval.BUDGET and rt.keep == scale * retrieval.PREFILTER
        found = retrieval.match(rt, track, track, a, b, n, 0.5, align=False).found
        assert len(found[1][0]) == scale * retrieval.TOP_K  # the upper body: all it kept
        halves = splice.halves(rt, track, track, a, b, n)
        assert all(len(h.found[p][0]) == scale * splice.HALF_TOP_K for h in halves for p in (0, 1))
        counts[factor] = [moments(x) for pair in gathered for x in pair] + [moments(found[1][0])]
    assert all(fast >= 0.8 * slow for slow, fast in zip(counts[1], counts[2])), counts
    # The slow library is smaller than a seam's gather (every frame once each way is gathered).
    assert counts[0.5][:4] == [min(retrieval.BUDGET, len(slow_lib))] * 4, counts


def test_cli_says_which_motion_was_replayed(model, clips, paths_for_cli, tmp_path, capsys):
    map_path = tmp_path / "map.npz"
    model.save(map_path)
    out = tmp_path / "out.bvh"
    a, b = paths_for_cli
    assert cli.main(["transition", str(a), str(b), "-o", str(out), "--map", str(map_path),
                     "--method", "retrieval", "--length", "30"]) == 0
    text = capsys.readouterr().out
    assert "lower: " in text and "upper: " in text and "confidence" in text and "match distance" in text
    assert any(n in text for n in LIBRARY)  # a recorded clip, or one played backwards
    assert len(bvh.read(out)) == len(clips[HELD_OUT[0]]) + 30 + len(clips[HELD_OUT[1]])


@pytest.fixture
def paths_for_cli(bandai_paths):
    p = bandai_paths(HELD_OUT[:2])
    return p[HELD_OUT[0]], p[HELD_OUT[1]]


def test_the_mean_of_segments_keeps_each_ones_sign_through_a_half_turn_from_the_first():
    # Two segments of a joint: the second turns steadily away from the first (120 -> 240
    # degrees about one axis), passing a half turn from it mid-gap; the library stores either
    # sign of each frame. Aligned to the first segment sample by sample, the second changed sign
    # there and the mean jumped 180 degrees (an arm 107 degrees in a frame between a wave and a
    # run); each segment's sign kept from sample to sample, the mean turns steadily: the first
    # turned half the second's angle, on round.
    from posturemap.synth import retrieval_numba

    rng = np.random.default_rng(4)
    t = 40
    first = quat.exp(np.cumsum(rng.normal(scale=0.02, size=(t, 3)), axis=0))
    axis = np.array([0.3, 0.9, -0.3]) / np.linalg.norm([0.3, 0.9, -0.3])
    angle = np.radians(np.linspace(120.0, 240.0, t))
    second = quat.mul(first, quat.exp(angle[:, None] * axis))
    rots = np.concatenate([first, second])[:, None] * np.where(rng.random((2 * t, 1, 1)) < 0.4, -1.0, 1.0)
    lib = SimpleNamespace(rots=rots.astype(np.float32))
    i0 = np.stack([np.arange(t), t + np.arange(t)])
    i1, f = i0.copy(), np.zeros(i0.shape)
    joints = np.array([0])
    samples = retrieval.sample_rotations(lib, i0, i1, f, joints)
    want = quat.mul(first, quat.exp(0.5 * angle[:, None] * axis))[:, None]
    got = retrieval.average_rotations(samples)
    compiled = np.empty((t, 1, 4))
    retrieval_numba._mean_track(lib.rots, i0, i1, f, joints, np.ones(2), compiled)
    for mean in (got, compiled):
        assert quat.angle_between(mean, want).max() < 1e-6
        assert quat.angle_between(mean[1:], mean[:-1]).max() < np.radians(6.0)  # the tracks' own pace
    np.testing.assert_allclose(compiled, got, atol=1e-12)
    # Where no segment passes a half turn from the first, the same signs as aligning each sample
    # to the first segment's (the mean before this rule, to the bit).
    near = quat.mul(first, quat.exp(np.radians(np.linspace(10.0, 90.0, t))[:, None] * axis))
    lib.rots = (np.concatenate([first, near])[:, None] * np.where(rng.random((2 * t, 1, 1)) < 0.4, -1.0, 1.0)
                ).astype(np.float32)
    q = retrieval.sample_rotations(lib, i0, i1, f, joints)
    aligned = quat.normalize(np.sum(q * np.where(np.sum(q * q[:1], axis=-1, keepdims=True) < 0, -1.0, 1.0), axis=0))
    np.testing.assert_array_equal(retrieval.average_rotations(q), aligned)
    # One sample: the first segment's sign, the same shape as the compiled mean's.
    one = retrieval.average_rotations(q[:, :1])
    assert one.shape == (1, 1, 4)
    np.testing.assert_array_equal(one, aligned[:1])


def test_compiled_replay_matches_the_numpy_reference(model):
    from posturemap.synth import retrieval_numba

    lib = model.library_
    rng = np.random.default_rng(5)
    length, k = 17, 5
    s = rng.integers(0, len(lib) - 40, k)
    s = np.array([v for v in s if lib.clip_end[v] - v > 40][:3])
    e = s + rng.integers(10, 30, len(s))
    i0, i1, f = retrieval.segment_times(lib, s, e, length + 1.0)
    joints = np.array([0, 1, 3, 7, 12])
    a2, b2 = (quat.normalize(rng.normal(size=(2, len(joints), 4))) for _ in range(2))
    curves = retrieval.hermite_offsets(length, 6.0)
    # The segments averaged, then the average's seams corrected.
    ref = retrieval.offset_rotations(retrieval.average_rotations(
        retrieval.sample_rotations(lib, i0, i1, f, joints))[None], a2, b2, curves)[0]
    out = np.empty_like(ref)
    retrieval_numba.replay(lib.rots, i0, i1, f, joints, np.arange(len(joints)), a2, b2, curves, 0, length, out,
                           np.ones(len(s)))
    assert np.allclose(np.abs(np.sum(out * ref, axis=-1)), 1.0, atol=1e-9)
    assert quat.angle_between(out, ref).max() < 1e-6
    # Only some frames (as the splice asks of each half): those rows the same, the rest identity.
    part = np.empty_like(ref)
    retrieval_numba.replay(lib.rots, i0, i1, f, joints, np.arange(len(joints)), a2, b2, curves, 4, 11, part,
                           np.ones(len(s)))
    np.testing.assert_array_equal(part[4:11], out[4:11])
    assert np.all(part[:4] == (1.0, 0.0, 0.0, 0.0)) and np.all(part[11:] == (1.0, 0.0, 0.0, 0.0))
    ref_part = retrieval.replay_rotations(lib, i0, i1, f, joints, a2, b2, curves, frames=(4, 11))  # numpy steps
    assert quat.angle_between(ref_part[4:11], part[4:11]).max() < 1e-6
    np.testing.assert_array_equal(ref_part[:4], part[:4])
    np.testing.assert_array_equal(ref_part[11:], part[11:])
    # Into the whole skeleton's frames (A's and B's rows of every joint): the columns of
    # `joints` as above, the others untouched; the numpy steps the same.
    n_j = lib.rots.shape[1]
    a_all, b_all = (quat.normalize(rng.normal(size=(2, n_j, 4))) for _ in range(2))
    a_all[:, joints], b_all[:, joints] = a2, b2
    for compiled in (True, False):
        full = np.full((length, n_j, 4), 7.0)
        if compiled:
            retrieval_numba.replay(lib.rots, i0, i1, f, joints, joints, a_all, b_all, curves, 4, 11, full, np.ones(len(s)))
        else:
            got = retrieval.replay_rotations(lib, i0, i1, f, joints, a_all, b_all, curves, frames=(4, 11), out=full)
            assert got is full
        assert quat.angle_between(full[:, joints][4:11], part[4:11]).max() < 1e-6
        assert np.all(full[:, joints][:4] == (1.0, 0.0, 0.0, 0.0))
        others = np.setdiff1d(np.arange(n_j), joints)
        assert np.all(full[:, others] == 7.0)


def test_compiled_seam_costs_match_numpy(model, monkeypatch):
    from posturemap.synth import retrieval_numba

    rng = np.random.default_rng(6)
    pm = rng.normal(size=(500, 7)).astype(np.float32)
    vm = rng.normal(size=(500, 5)).astype(np.float32)
    frames, vframes = rng.integers(0, 500, 300), rng.integers(0, 500, 300)
    p, v = rng.normal(size=7).astype(np.float32), rng.normal(size=5).astype(np.float32)
    rate = rng.uniform(0.7, 1.4, 300)
    out = np.empty(300)
    retrieval_numba.seam_costs(pm, vm, frames, vframes, p, v, rate, out)
    monkeypatch.setattr(retrieval, "_compiled", lambda: None)  # the numpy path
    ref = retrieval.seam_costs(pm, vm, frames, vframes, p, v, rate)
    plain = ((pm[frames] - p) ** 2).sum(1) + ((rate[:, None] * vm[vframes] - v) ** 2).sum(1)
    assert np.allclose(out, plain, rtol=1e-5) and np.allclose(ref, plain, rtol=1e-5)


def test_a_library_shorter_than_the_gap_falls_back(clips):
    short = clips["walk_normal_001"][:12]
    tiny = PostureMap(seed=0).fit([short, clips["run_normal_001"][:10]], ["short walk", "short run"])
    eng = TransitionEngine(tiny)
    eng.own_seconds = 0.0  # the library alone (the walk's own frames hold such segments)
    eng.add("w", clips["walk_angry_001"])
    r, p = eng.generate("w", "w", length=30, a_end=20, b_start=51, align=False, method="retrieval", foot_lock=True)
    assert eng.last["retrieval"] is None  # no clip holds a 23..41-frame segment
    assert np.all(np.isfinite(r)) and np.all(np.isfinite(p))


def test_inspect_describes_the_library(model, tmp_path, capsys):
    path = tmp_path / "m.npz"
    model.save(path)
    assert cli.main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    n = model.library_.recorded
    assert f"motion library: {n} frames of {len(LIBRARY)} clips at 30 fps, also played backwards" in out
    heights = " / ".join(f"{h:.3f}" for h in model.library_.clearance)
    assert f"swinging toes kept at least {heights} leg lengths above the floor at 0.375 / 0.75 / 1.25" in out
    assert cli.main(["inspect", str(path), "--json"]) == 0
    import json

    d = json.loads(capsys.readouterr().out)["library"]
    assert d["frames"] == n and d["clips"] == len(LIBRARY) and "Foot_L" in d["key_joints"]
    np.testing.assert_allclose(d["toe_clearance"]["heights"], model.library_.clearance, atol=5e-5)
    assert d["toe_clearance"]["speeds"] == [0.375, 0.75, 1.25, 2.0, 3.25, 6.0]


def test_auto_is_retrieval_at_every_gap_length(engine, clips, model):
    name = HELD_OUT[0]
    for length in (1, 5, 7, 30):  # 0.07 s to 1 s at 30 fps
        r1 = engine.generate(name, name, length=length, a_end=40, b_start=41 + length, align=False, method="auto",
                             foot_lock=True)[0].copy()
        assert engine.last["method"] == "retrieval"
        assert "lower" in engine.last["retrieval"]["parts"]
        r2 = engine.generate(name, name, length=length, a_end=40, b_start=41 + length, align=False,
                             method="retrieval", foot_lock=True)[0]
        assert engine.last["method"] == "retrieval"  # an explicit method is named too
        assert np.array_equal(r1, r2)
        spline = engine.generate(name, name, length=length, a_end=40, b_start=41 + length, align=False,
                                 method="spline", foot_lock=True)[0]
        assert not np.allclose(r1, spline)  # the legs are retrieved, not the spline's
    report = {}
    transition(clips[name], clips[name], model, length=5, a_end=40, b_start=46, align=False, report=report)
    assert report["method"] == "retrieval"


def test_standing_seams_are_left_to_interpolation(model, clips):
    leg = model.library_.leg
    still = retrieval.Seams(np.zeros((7, 3)), np.zeros((7, 3)), np.array([0.1 * leg, 0.0, 0.05 * leg, 0.0, 90.0]))
    moving = retrieval.Seams(np.zeros((7, 3)), np.zeros((7, 3)), np.array([0.0, 0.0, 1.2 * leg, 0.1, 90.0]))
    assert retrieval.still_weight(still, still, leg, 1) == 0.0
    assert retrieval.still_weight(still, moving, leg, 1) == 1.0  # one moving seam is enough
    half = retrieval.Seams(np.zeros((7, 3)), np.zeros((7, 3)), np.array([0.35 * leg, 0.0, 0.0, 0.0, 90.0]))
    assert retrieval.still_weight(half, still, leg, 1) == pytest.approx(0.5)
    # A bow (the feet stay put): the parts fall back to interpolation and say so.
    eng = TransitionEngine(model)
    eng.add("bow", clips["bow_happy_001"])
    kw = dict(length=30, a_end=20, b_start=51, align=False, foot_lock=False)
    r, p = (x.copy() for x in eng.generate("bow", "bow", method="retrieval", **kw))
    assert eng.last["retrieval"]["confidence"] == 0.0
    # The report says why (the command line's line too): not a loose match, a body standing.
    from posturemap.cli import describe_retrieval

    assert eng.last["retrieval"]["standing"] is True
    assert "stands still at both seams" in describe_retrieval(eng.last["retrieval"])
    assert_the_fallback(eng, "bow", r, p, kw)


def test_legs_stepping_in_place_are_not_a_standing_gesture(model, clips):
    """A clip "in place" (a game asset's walk whose root stays put): the root stands at both
    seams, but the legs step about it, faster than STEP_SPEED[1] leg lengths per second; the
    legs are retrieved, not left to interpolation as a bow's are."""
    leg, kl = model.library_.leg, 4
    root = np.array([0.05 * leg, 0.0, 0.05 * leg, 0.0, 90.0])
    stepping = np.zeros((7, 3))
    stepping[1] = (0.0, 0.3 * leg, 1.2 * leg)  # a foot swinging forward (its up speed does not count)
    still = retrieval.Seams(np.zeros((7, 3)), np.zeros((7, 3)), root)
    steps = retrieval.Seams(np.zeros((7, 3)), stepping, root)
    assert retrieval.still_weight(still, still, leg, 1, lower=kl) == 0.0
    assert retrieval.still_weight(still, steps, leg, 1, lower=kl) == 1.0
    assert retrieval.still_weight(still, steps, leg, 1) == 0.0  # the root's speed alone
    assert retrieval.still_weight(still, steps, leg, 1, lower=1) == 0.0  # a joint of the upper body moving
    half = retrieval.Seams(np.zeros((7, 3)), stepping * 0.625, root)  # 0.75 leg lengths a second
    assert retrieval.still_weight(half, still, leg, 1, lower=kl) == pytest.approx(0.5)
    # A held-out walk made "in place" (its hips held over one spot): the legs are retrieved.
    walk = clips[HELD_OUT[0]]
    hips = walk.skeleton.names.index("Hips")
    in_place = dataclasses.replace(walk, positions=walk.positions.copy())
    in_place.positions[:, :hips + 1, 0] = in_place.positions[:1, :hips + 1, 0]
    in_place.positions[:, :hips + 1, 2] = in_place.positions[:1, :hips + 1, 2]
    eng = TransitionEngine(model)
    eng.add("walk", in_place)
    eng.generate("walk", "walk", length=30, a_end=40, b_start=71, align=False, method="retrieval")
    assert eng.last["retrieval"]["parts"]["lower"]["confidence"] > 0.5
    assert "standing" not in eng.last["retrieval"]


def test_a_gap_that_must_travel_is_not_a_standing_gesture(model, clips):
    """Standing at both seams, but B is two metres away: the character must walk there, so the
    still weight follows the gap's speed and the legs are retrieved rather than gliding."""
    leg = model.library_.leg
    still = retrieval.Seams(np.zeros((7, 3)), np.zeros((7, 3)), np.array([0.1 * leg, 0.0, 0.05 * leg, 0.0, 90.0]))
    assert retrieval.still_weight(still, still, leg, 1, travel=0.1 * leg) == 0.0
    assert retrieval.still_weight(still, still, leg, 1, travel=0.35 * leg) == pytest.approx(0.5)
    assert retrieval.still_weight(still, still, leg, 1, travel=2.0 * leg) == 1.0
    bow = clips["bow_happy_001"]
    far = dataclasses.replace(bow, positions=bow.positions.copy())
    far.positions[:, 0, 0] += 200.0  # cm: B's place two metres along x
    eng = TransitionEngine(model)
    eng.add("bow", bow)
    eng.add("far", far)
    for align, expected in ((False, True), (True, False)):
        eng.generate("bow", "far", length=30, a_end=20, b_start=51, align=align, method="retrieval")
        assert (eng.last["retrieval"]["parts"]["lower"]["confidence"] > 0.0) == expected
    # In a transition B takes the segment's place, so nothing asks the bow to travel.


def test_long_gaps_average_more_segments(engine):
    # 16 segments up to 1.1 s of gap, 24 from 1.5 s, more in between and never fewer; in seconds,
    # so at any frame rate; what the report says was blended.
    avg = retrieval.segments_averaged
    assert [avg(n, 30.0) for n in (5, 20, 32)] == [retrieval.TOP_K] * 3
    assert [avg(n, 30.0) for n in (44, 60, 300)] == [retrieval.TOP_K_LONG] * 3
    counts = [avg(n, 30.0) for n in range(1, 60)]
    assert all(b >= a for a, b in zip(counts, counts[1:])) and retrieval.TOP_K < avg(39, 30.0) < retrieval.TOP_K_LONG
    assert avg(4 * 39 + 3, 120.0) == avg(39, 30.0)  # the same duration at 120 fps
    # A library at 60 fps: twice as many (segments a frame apart are near copies there).
    assert avg(59, 60.0, 60.0) == 2 * retrieval.TOP_K and avg(89, 60.0, 60.0) == 2 * retrieval.TOP_K_LONG
    name = HELD_OUT[0]
    for length, want in ((30, retrieval.TOP_K), (45, retrieval.TOP_K_LONG)):
        engine.generate(name, name, length=length, a_end=20, b_start=20 + length + 1, align=False, method="retrieval")
        parts = engine.last["retrieval"]["parts"]
        assert parts["upper"]["blended"] == want, (length, parts)
        # The legs: all of them on a short gap, those in step with the best from 1.5 s.
        assert parts["lower"]["blended"] == want if length == 30 else 1 <= parts["lower"]["blended"] <= want


def test_long_gaps_average_only_the_legs_in_step_with_the_best(engine, clips, monkeypatch):
    rt = retrieval.Retriever(engine, engine.model.library_)
    lib = rt.lib
    name, a_end = "walk_angry_001", 15
    tr = engine.tracks[name]
    fps = tr.motion.fps

    def legs(length):
        return retrieval.match(rt, tr, tr, a_end, a_end + length + 1, length, 0.5, False).found[0]

    length = 90  # 3 s: the best segments walk their middles in different phases
    with monkeypatch.context() as m:
        m.setattr(retrieval, "IN_STEP", 0.0)
        every = legs(length)
    kept = legs(length)
    assert len(every[0]) == retrieval.segments_averaged(length, fps) > len(kept[0]) >= 1
    # The kept ones, in rank order, are exactly those whose contacts at the gap's frames (the
    # nearest library frame of each) agree with the best's in at least IN_STEP of frames and feet.
    d = length + 1.0
    t = np.arange(1, length + 1)

    def contacts(s, e):
        u = np.clip(s + t * (e - s) / d, lib.clip_start[lib.clip_of[s]], lib.clip_end[s] - 1)
        return lib.contacts[np.rint(u).astype(np.int64)]  # the nearest frame, as the replay's contacts

    best = contacts(every[0][0], every[1][0])
    agree = [np.mean(contacts(s, e) == best) for s, e in zip(every[0], every[1])]
    want = [i for i, a in enumerate(agree) if a >= retrieval.IN_STEP]
    assert want[0] == 0 and any(np.isclose(a, retrieval.IN_STEP) for a in agree)  # the bound is exercised
    np.testing.assert_array_equal(kept[0], every[0][want])
    np.testing.assert_array_equal(kept[1], every[1][want])
    # The search kept in `shared` stays whole (a splice's halves rank it again).
    shared = {}
    retrieval.match(rt, tr, tr, a_end, a_end + length + 1, length, 0.5, False, shared=shared)
    np.testing.assert_array_equal(shared["found"][0.5][0][0], every[0])
    # From 1.5 s of gap ((length + 1) / fps) on; shorter gaps, and a splice's halves (matched at
    # one seam), keep every segment.
    calls = []
    step = rt.in_step
    monkeypatch.setattr(rt, "in_step", lambda *a: calls.append(a) or step(*a))
    for n in (43, 44, 45):
        legs(n)
    assert len(calls) == sum((n + 1) / fps >= retrieval.TOP_K_RAMP_S[1] for n in (43, 44, 45)) >= 1
    assert len(legs(30)[0]) == retrieval.TOP_K
    half = retrieval.match(rt, tr, tr, a_end, a_end + length + 1, length, 0.0, True, seam="a")
    assert len(half.found[0][0]) == retrieval.segments_averaged(length, fps)
    # A rig without legs has no contacts: nothing to keep in step.
    from types import SimpleNamespace

    legless = SimpleNamespace(lib=SimpleNamespace(contacts=np.zeros((len(lib), 0), dtype=bool)))
    assert retrieval.Retriever.in_step(legless, every[0], every[1], d).all()


def test_long_gaps_weigh_the_upper_body_in_step_with_the_legs_twice(engine, monkeypatch):
    rt = retrieval.Retriever(engine, engine.model.library_)
    lib = rt.lib
    name, a_end = "walk_angry_001", 30
    tr = engine.tracks[name]
    for length in (60, 30):  # 2 s; 1.03 s with the rule from 1 s (all the legs kept there)
        monkeypatch.setattr(retrieval, "UPPER_IN_STEP_S", 1.5 if length == 60 else 1.0)
        shared = {}
        m = retrieval.match(rt, tr, tr, a_end, a_end + length + 1, length, 0.5, False, shared=shared)
        legs, every = m.found[0], shared["found"][0.5][1]  # the upper body's search, whole
        assert len(legs[0]) < len(shared["found"][0.5][0][0]) if length == 60 else len(legs[0]) == retrieval.TOP_K
        d = length + 1.0
        t = np.arange(1, length + 1)

        def contacts(s, e):
            u = np.clip(s + t * (e - s) / d, lib.clip_start[lib.clip_of[s]], lib.clip_end[s] - 1)
            return lib.contacts[np.rint(u).astype(np.int64)]

        ref = contacts(legs[0][0], legs[1][0])
        agree = np.array([np.mean(contacts(s, e) == ref) for s, e in zip(every[0], every[1])])
        in_step = agree >= retrieval.IN_STEP
        assert 0 < in_step.sum() < len(in_step)  # some step with the legs, some do not
        # Every segment once, in rank order; those in step weigh twice in the average.
        for k in range(5):
            np.testing.assert_array_equal(m.found[1][k], every[k])
        np.testing.assert_array_equal(m.weights[1], np.where(in_step, 2.0, 1.0))
        assert m.weights[0] is None and m.info["parts"]["upper"]["blended"] == len(every[0])
        # The replay averages with those weights: as the same segments with the in-step ones
        # listed twice, and unlike equal weights.
        twice = np.concatenate([np.arange(len(in_step)), np.flatnonzero(in_step)])
        doubled = dataclasses.replace(m, found=[m.found[0], tuple(x[twice] for x in m.found[1])],
                                      weights=[None, None], _info=None)
        equal = dataclasses.replace(m, weights=[None, None], _info=None)
        got, ref_rots, flat = (retrieval.replay(rt, x).rots[:, rt.upper_mask] for x in (m, doubled, equal))
        assert quat.angle_between(got, ref_rots).max() < 1e-6
        assert quat.angle_between(got, flat).max() > 0.01  # the weights move the arms
        with monkeypatch.context() as mp:  # no compiled kernels: the numpy steps, the same frames
            mp.setattr(retrieval, "_compiled", lambda: None)
            assert quat.angle_between(retrieval.replay(rt, m).rots[:, rt.upper_mask], got).max() < 1e-6
    # Shorter gaps weigh every segment alike: by default from 1.5 s ((length + 1) / fps).
    monkeypatch.setattr(retrieval, "UPPER_IN_STEP_S", 1.5)
    seen = set()
    for length in (43, 44, 45):
        weighed = (length + 1) / tr.motion.fps >= 1.5
        m = retrieval.match(rt, tr, tr, a_end, a_end + length + 1, length, 0.5, False)
        assert (m.weights[1] is not None) == weighed and m.weights[0] is None
        seen.add(weighed)
    assert seen == {False, True}
    # A standing clip (feet planted throughout) agrees with walking feet only while they are
    # planted (60% here), under the bound; a rig without legs has nothing to step with.
    from types import SimpleNamespace

    n = 200
    walk = np.arange(100)
    feet = np.ones((n, 2), dtype=bool)
    feet[:100, 0], feet[:100, 1] = walk % 30 < 18, (walk + 15) % 30 < 18
    fake = SimpleNamespace(lib=SimpleNamespace(contacts=feet, clip_start=np.array([0, n]), clip_of=np.zeros(n, int),
                                               clip_end=np.full(n, n)))
    fake.gap_contacts = lambda s, e, d: retrieval.Retriever.gap_contacts(fake, s, e, d)
    walking = (np.array([0]), np.array([46]))
    upper = (np.array([0, 15, 100]), np.array([46, 61, 146]))  # itself, half a cycle later, standing
    step = retrieval.Retriever.upper_in_step
    assert step(fake, walking, upper, 46.0).tolist() == [True, False, False]
    legless = SimpleNamespace(lib=SimpleNamespace(contacts=np.zeros((n, 0), dtype=bool)))
    assert step(legless, walking, upper, 46.0).tolist() == [False, False, False]


def test_a_travelling_seam_takes_the_upper_body_only_from_travelling_frames(engine):
    rt = retrieval.Retriever(engine, engine.model.library_)
    lib, leg = rt.lib, rt.lib.leg
    speed = rt.root_speed
    a, b = [i for i in range(3) if i != lib.up]
    # The root's horizontal speed, as the path's own steps give it (inside the clips).
    step = np.linalg.norm(np.diff(lib.gpos[:, [a, b]], axis=0), axis=1) * lib.fps / leg
    inside = lib.clip_of[1:] == lib.clip_of[:-1]
    moving = inside & (speed[1:] > 0.5)
    assert np.median(np.abs(step[moving] - speed[1:][moving]) / speed[1:][moving]) < 0.05
    frames = np.arange(len(lib))

    def seam(v):  # a seam whose root moves at v leg lengths per second, partly sideways
        root = np.zeros(5)
        root[a], root[b] = 0.8 * v * leg, 0.6 * v * leg
        return retrieval.Seams(np.zeros((1, 3)), np.zeros((1, 3)), root)

    v = float(np.median(speed[speed > 1.0]))  # a walking speed of this library
    ok = rt.travelling(frames, seam(v))
    np.testing.assert_array_equal(ok, speed >= retrieval.UPPER_TRAVEL * v)
    assert 0 < ok.sum() < len(lib)  # the library's slow frames (starts, stops, turns) are left out
    # A seam that stands (slower than STILL_SPEED[1]) takes any frame; so does one faster than
    # anything in the library (then nothing would be left).
    assert rt.travelling(frames, seam(0.99 * retrieval.STILL_SPEED[1])).all()
    assert rt.travelling(frames, seam(1e3 * speed.max())).all()
    v = 1.01 * retrieval.STILL_SPEED[1]  # just travelling
    np.testing.assert_array_equal(rt.travelling(frames, seam(v)), speed >= retrieval.UPPER_TRAVEL * v)


@pytest.fixture(scope="module")
def walks_and_bows(clips):
    # Walks and standing motion (bows): an old man's bent back over walking legs is, in the arms
    # and head, close to a bow's first frames.
    names = ("walk_normal_001", "bow_normal_001", "bow_happy_001")
    eng = TransitionEngine(PostureMap(seed=0).fit([clips[n] for n in names], list(names)))
    eng.add("walk_old_001", clips["walk_old_001"])
    return eng


def test_walking_legs_do_not_take_a_bows_arms_on_long_gaps(walks_and_bows, monkeypatch):
    eng = walks_and_bows
    rt = retrieval.Retriever(eng, eng.model.library_)
    lib, tr = rt.lib, eng.tracks["walk_old_001"]
    length, a_end = 45, 80
    b_start = a_end + length + 1

    def upper(exhaustive=False):
        m = retrieval.match(rt, tr, tr, a_end, b_start, length, 0.5, False, exhaustive=exhaustive)
        s, e = m.found[1][0], m.found[1][1]
        return s, e, {lib.source_frames(int(i), int(j))[0] for i, j in zip(s, e)}

    def legs():
        return retrieval.match(rt, tr, tr, a_end, b_start, length, 0.5, False).found[0]

    with monkeypatch.context() as m:
        m.setattr(retrieval, "UPPER_TRAVEL", 0.0)  # any frame may give the arms
        assert any(n.startswith("bow") for n in upper()[2])
        legs_before = legs()
    for x, y in zip(legs(), legs_before):  # the legs' search is not touched
        np.testing.assert_array_equal(x, y)
    qa, qb = rt.seam_pair(tr, [a_end - 1, a_end], tr, [b_start, b_start + 1])
    for exhaustive in (False, True):
        s, e, names = upper(exhaustive)
        assert names == {"walk_normal_001"}, (exhaustive, names)
        # Every segment came in through a seam it travels at: its start at A's or its end at B's.
        assert np.all(rt.travelling(s, qa) | rt.travelling(e, qb))
    with monkeypatch.context() as m:  # the numpy steps (a process without numba) as well
        m.setattr(retrieval, "_compiled", lambda: None)
        assert upper()[2] == {"walk_normal_001"}
    # Both searches of both parts at once hand the rule the upper body's gathered frames, once,
    # and never the legs'.
    gathered = rt.gather_seams(tr.features[a_end], tr.features[b_start])
    assert not np.array_equal(gathered[0][0], gathered[1][0])
    rule = rt.upper_frames
    for jit in (True, False):
        calls = []
        with monkeypatch.context() as m:
            m.setattr(rt, "upper_frames", lambda sa, sb, *rest: calls.append((sa, sb)) or rule(sa, sb, *rest))
            if not jit:
                m.setattr(retrieval, "_compiled", lambda: None)
            rt.search_parts(qa, qb, gathered, length + 1.0, tr.motion.fps, (0.5,), None, 8)
        assert len(calls) == 1 and all(np.array_equal(x, y) for x, y in zip(calls[0], gathered[1])), jit
    # Each seam's own speed decides for its own frames: with B standing, B's gathered frames are
    # all kept and A's are thinned; the exhaustive search then keeps every segment (any end may
    # arrive at a standing B), as if there were no rule.
    still = retrieval.Seams(qb.pose, qb.vel, np.zeros(5))  # the upper body's rows do not read root
    sa, sb = rt.gather_seams(tr.features[a_end], tr.features[b_start])[1]
    fa, fb = rt.upper_frames(sa, sb, qa, still, length + 1.0, tr.motion.fps)
    assert len(fa) < len(sa) and np.array_equal(fb, sb)
    fb2, fa2 = rt.upper_frames(sb, sa, still, qa, length + 1.0, tr.motion.fps)
    assert np.array_equal(fb2, sb) and np.array_equal(fa2, fa)
    args = (1, qa, still, None, None, length + 1.0, tr.motion.fps, 0.5, None, 8)
    got = rt.search(*args, exhaustive=True)
    with monkeypatch.context() as m:
        m.setattr(retrieval, "UPPER_TRAVEL", 0.0)
        ref = rt.search(*args, exhaustive=True)
    for x, y in zip(got, ref):
        np.testing.assert_array_equal(x, y)
    # The rule leaves out some of the frames gathered for these seams on this gap, and none on a
    # gap shorter than UPPER_TRAVEL_S.
    gathered = rt.gather_seams(tr.features[a_end], tr.features[b_start])[1]
    fps = tr.motion.fps
    kept = rt.upper_frames(*gathered, qa, qb, length + 1.0, fps)
    assert sum(map(len, kept)) < sum(map(len, gathered))
    short = rt.upper_frames(*gathered, qa, qb, retrieval.UPPER_TRAVEL_S * fps - 1.0, fps)
    assert short[0] is gathered[0] and short[1] is gathered[1]


def test_the_search_matches_the_joints_the_library_was_built_for(engine):
    # The library's matching features were computed for its key joints when it was built (a map
    # trained by an older release, whose rule for a rig's key joints may differ): the search
    # takes those, not the ones the current rule would find for the skeleton.
    import copy

    lib = copy.copy(engine.model.library_)  # as built by a rule that listed the upper joints the other way round
    object.__setattr__(lib, "upper", lib.upper[::-1].copy())
    assert not np.array_equal(lib.upper, key_joints(engine.skeleton)[1])
    rt = retrieval.Retriever(engine, lib)
    np.testing.assert_array_equal(rt.keys, np.concatenate([lib.lower, lib.upper]))
    assert rt.kl == len(lib.lower) and lib.pose.shape[1] == len(rt.keys)


def test_the_prefilter_keeps_as_many_moments_at_any_frame_rate():
    from types import SimpleNamespace

    keep = retrieval.Retriever.keep.fget
    assert keep(SimpleNamespace(lib=SimpleNamespace(fps=retrieval.LIBRARY_FPS))) == retrieval.PREFILTER
    assert keep(SimpleNamespace(lib=SimpleNamespace(fps=4 * retrieval.LIBRARY_FPS))) == 4 * retrieval.PREFILTER
    assert keep(SimpleNamespace(lib=SimpleNamespace(fps=0.001))) == retrieval.PREFILTER  # never fewer than at 30


def test_the_upper_body_fades_into_the_spline_on_short_gaps():
    # The ramp runs from a quarter second to where the fallback stops being the spline.
    assert retrieval.UPPER_RAMP_S == (0.25, retrieval.FALLBACK_SHORT[1])
    lo, hi = retrieval.UPPER_RAMP_S
    assert retrieval.upper_weight(5, 30.0) == 0.0  # 0.2 s
    assert retrieval.upper_weight(29, 120.0) == 0.0  # 0.25 s at 120 fps: seconds count, not frames
    assert retrieval.upper_weight(16, 40.0) == pytest.approx((17 / 40 - lo) / (hi - lo))
    assert retrieval.upper_weight(17, 30.0) == 1.0 and retrieval.upper_weight(71, 120.0) == 1.0
    w = [retrieval.upper_weight(n, 60.0) for n in range(1, 60)]
    assert np.all(np.diff(w) >= 0) and 0 < w[30] < 1


def test_a_short_gap_takes_the_arms_from_the_spline_and_keeps_the_retrieved_legs(engine, monkeypatch):
    rt = retrieval.Retriever(engine, engine.model.library_)
    tr = engine.tracks[HELD_OUT[0]]
    # 12 frames (0.43 s): the upper body's confidence is its match's times the ramp's weight.
    ramped = retrieval.match(rt, tr, tr, 40, 53, 12, 0.5, False)
    with monkeypatch.context() as m:
        m.setattr(retrieval, "UPPER_RAMP_S", (0.0, 0.0))  # no ramp: weight 1 at any length
        flat = retrieval.match(rt, tr, tr, 40, 53, 12, 0.5, False)
    assert ramped.confidence[0] == flat.confidence[0] > 0
    assert flat.confidence[1] > 0
    assert ramped.confidence[1] == pytest.approx(flat.confidence[1] * retrieval.upper_weight(12, tr.motion.fps))
    # 6 frames (0.23 s): the arms and the spine below its first joint are the spline's, frame for
    # frame; the legs are retrieved.
    kw = dict(length=6, a_end=40, b_start=47, align=False, foot_lock=False)
    r = engine.generate(HELD_OUT[0], HELD_OUT[0], method="retrieval", **kw)[0].copy()
    assert engine.last["retrieval"]["parts"]["upper"]["confidence"] == 0.0
    assert engine.last["retrieval"]["parts"]["lower"]["confidence"] > 0.0
    spline = engine.generate(HELD_OUT[0], HELD_OUT[0], method="spline", **kw)[0].copy()  # a buffer, reused
    below = rt.upper_mask.copy()
    below[rt.upper_tops] = False
    assert below.any() and len(rt.upper_tops)
    np.testing.assert_array_equal(r[:, below], spline[:, below])
    assert not np.allclose(r[:, rt.lower_mask], spline[:, rt.lower_mask], atol=1e-3)
    # The spine's first joint: the spline's chest over the retrieved pelvis (engine._fallback_chest),
    # in the world the spline's chest turned about up by the pelvises' turn beyond CHEST_FREE_DEG
    # (smoothly: theta - free tanh(sin(theta) / free)), though the two pelvises differ by more (a tilt).
    up = np.zeros(3)
    up[engine._up] = 1.0
    pelvis = engine._chain.tolist() + [engine._root]  # the joints above the root, then the root

    def world(rots, joints):  # the last joint's rotation in the world, down the chain
        q = rots[:, joints[0]]
        for k in joints[1:]:
            q = quat.mul(q, rots[:, k])
        return q

    def tilt_between(a, b):  # the angle from b to a once any turn about up is taken out
        swing, _ = quat.swing_twist(quat.mul(a, quat.inv(b)), up)
        return 2 * np.arccos(np.clip(np.abs(swing[..., 0]), 0.0, 1.0))

    assert tilt_between(world(r, pelvis), world(spline, pelvis)).max() > np.radians(1.0)
    _, twist = quat.swing_twist(quat.mul(world(r, pelvis), quat.inv(world(spline, pelvis))), up)
    theta = 2.0 * np.arctan2(twist[:, 1:] @ up, twist[:, 0])
    theta = (theta + np.pi) % (2.0 * np.pi) - np.pi  # in [-pi, pi), whatever the sign of the quaternion
    assert np.abs(theta).max() > np.radians(0.5)  # the pelvises turn apart too
    for free in (retrieval.CHEST_FREE_DEG, 0.0):  # as made, then turning with the pelvis in full
        with monkeypatch.context() as m:
            m.setattr(retrieval, "CHEST_FREE_DEG", free)
            got = engine.generate(HELD_OUT[0], HELD_OUT[0], method="retrieval", **kw)[0].copy()
        np.testing.assert_array_equal(got[:, ~np.isin(np.arange(got.shape[1]), rt.upper_tops)],
                                      r[:, ~np.isin(np.arange(r.shape[1]), rt.upper_tops)])
        bound = np.radians(free)
        beyond = theta - bound * np.tanh(np.sin(theta) / bound) if bound > 0.0 else theta
        turn = quat.from_axis_angle(np.broadcast_to(up, (len(theta), 3)), beyond)
        for t in rt.upper_tops.tolist():
            chest = quat.mul(world(got, pelvis + [t]), quat.inv(world(spline, pelvis + [t])))
            np.testing.assert_allclose(quat.angle_between(chest, turn), 0.0, atol=1e-6)
            if free == 0.0:
                assert not np.allclose(got[:, t], r[:, t], atol=1e-4)  # the full turn is another chest
                assert not np.allclose(got[:, t], spline[:, t], atol=1e-3)  # not the spline's local rotation
    # Between clips (B placed by the retrieved motion, the fallback's B placed by its own) the
    # chest turns with the pelvis in full: the bound is not used there.
    between = dict(kw, align=True)
    outs = []
    for free in (retrieval.CHEST_FREE_DEG, 0.0):
        with monkeypatch.context() as m:
            m.setattr(retrieval, "CHEST_FREE_DEG", free)
            outs.append(engine.generate(HELD_OUT[0], HELD_OUT[0], method="retrieval", **between)[0].copy())
        assert engine.last["retrieval"]["parts"]["upper"]["confidence"] < 1.0
        assert engine.last["retrieval"]["parts"]["lower"]["confidence"] > 0.0
    np.testing.assert_array_equal(outs[0], outs[1])


def test_compiled_search_matches_the_numpy_steps(engine, clips):
    assert retrieval._compiled() is not None  # the suite runs with numba loaded
    rt = retrieval.Retriever(engine, engine.model.library_)
    rng = np.random.default_rng(8)
    checked = 0
    for i in range(12):
        na, nb = HELD_OUT[i % 3], HELD_OUT[(i + 1 + i // 6) % 3]
        ta, tb = engine.tracks[na], engine.tracks[nb]
        a_end, b_start = int(rng.integers(1, len(ta.gpos))), int(rng.integers(0, len(tb.gpos) - 1))
        qa, qb = rt.seams(ta, [a_end - 1, a_end], 1), rt.seams(tb, [b_start, b_start + 1], 0)
        d, alpha = float(rng.integers(6, 46)), (0.0, 0.5, 1.0, float(rng.random()))[i % 4]
        disp = (float(rng.normal(scale=30)), float(rng.normal(scale=30)), float(rng.normal())) if i % 2 else None
        for part in (0, 1):
            sa, sb = rt.gather(ta.features[a_end], part), rt.gather(tb.features[b_start], part)
            # One search ranked for several alphas (as a transition and its splice's halves ask).
            args = (part, qa, qb, sa, sb, d, 30.0, (alpha, 0.0, 1.0), disp, 8)
            for got, ref in zip(rt._search_compiled(*args), rt._search_numpy(*args)):
                assert (got is None) == (ref is None)
                if ref is None:
                    continue
                np.testing.assert_array_equal(got[0], ref[0])  # the same segments in the same order
                np.testing.assert_array_equal(got[1], ref[1])
                for g, r in zip(got[2:], ref[2:]):  # the costs (sums vectorised: to rounding)
                    np.testing.assert_allclose(g, r, rtol=1e-13)
                checked += len(ref[0])
            # Ranking for several alphas at once is ranking for each alone.
            for a, many in zip((alpha, 0.0, 1.0), rt.search_alphas(*args)):
                alone = rt.search(part, qa, qb, sa, sb, d, 30.0, a, disp, 8)
                for x, y in zip(many, alone):
                    np.testing.assert_array_equal(x, y)
    assert checked > 300
    # The numpy backend's search (numpy costs, float64 squares) finds the same best segments.
    with kernels.numpy_backend():
        assert retrieval._compiled() is None
        ref = rt.search(0, qa, qb, sa, sb, d, 30.0, alpha, None, 8)
    got = rt.search(0, qa, qb, sa, sb, d, 30.0, alpha, None, 8)
    np.testing.assert_array_equal(got[0][:3], ref[0][:3])
    np.testing.assert_allclose(got[2], ref[2], rtol=1e-5)


def test_compiled_selection_of_the_smallest():
    from posturemap.synth import retrieval_numba

    rng = np.random.default_rng(9)
    for n, keep in ((50, 7), (300, 192), (10, 20), (1, 1)):
        c = rng.normal(size=n)
        got = np.sort(retrieval_numba._smallest(c, keep))
        want = np.sort(np.argsort(c)[:keep])
        np.testing.assert_array_equal(got, want)
    c = np.array([3.0, 1.0, 2.0, 1.0, 2.0, 2.0, 0.0])  # ties at the cut: the first ones
    np.testing.assert_array_equal(np.sort(retrieval_numba._smallest(c, 4)), [1, 2, 3, 6])
    # Many ties, in every order of arrival: the kept set is the stable sort's first ones.
    for seed in range(20):
        c = np.random.default_rng(seed).integers(0, 6, size=200).astype(float)
        for keep in (1, 17, 64, 199):
            want = np.sort(np.argsort(c, kind="stable")[:keep])
            np.testing.assert_array_equal(np.sort(retrieval_numba._smallest(c, keep)), want)
    # The search's sizes, with heavy tails, all values equal, ranges too narrow for the buckets
    # (a few ulps, denormal) and a single outlier: always the stable sort's first ones.
    heavy = rng.exponential(size=1576) ** 6
    narrow = 1.0 + rng.integers(0, 5, 1281) * np.finfo(float).eps
    tiny = rng.integers(0, 9, 1576) * 5e-324
    outlier = np.concatenate([rng.random(1300), [1e300]])
    infinite = np.where(rng.random(1576) < 0.3, np.inf, rng.random(1576))  # a range that is not finite
    for c in (rng.random(1281), rng.chisquare(3, 1576), heavy, np.zeros(1576), narrow, tiny, outlier, infinite):
        for keep in (1, 64, 96, 700):
            want = np.sort(np.argsort(c, kind="stable")[:keep])
            np.testing.assert_array_equal(np.sort(retrieval_numba._smallest(c, keep)), want)


def test_compiled_ranking_keeps_the_best_distinct_segments():
    from posturemap.synth import retrieval_numba

    rng = np.random.default_rng(10)
    for n, k in ((400, 8), (30, 8), (5, 8), (1, 1)):
        cs = rng.integers(0, 20, n)
        ce = cs + rng.integers(1, 4, n)
        total = np.round(rng.random(n), 1)  # many ties: ordered by start, then end
        first = {}
        for t, s, e in zip(total, cs, ce):  # a repeated segment has one total (found from both seams)
            first.setdefault((s, e), t)
        total = np.array([first[(s, e)] for s, e in zip(cs, ce)])
        want = sorted((t, s, e) for (s, e), t in first.items())[:k]
        out = np.empty(k, dtype=np.int64)
        got = retrieval_numba._best(total, cs, ce, k, out)
        assert [(total[i], cs[i], ce[i]) for i in out[:got]] == want


@pytest.mark.parametrize("budget", [retrieval.BUDGET, 6000, 30000])  # 30000: more than 256 neurons hold
@pytest.mark.parametrize("circular", [False, True])
def test_compiled_gather_matches_the_numpy_steps(engine, monkeypatch, circular, budget):
    from types import SimpleNamespace

    from posturemap.synth.library import INDEX_CLASS

    rt = retrieval.Retriever(engine, engine.model.library_)
    rng = np.random.default_rng(10)
    dims = rt.space.class_dims[INDEX_CLASS]
    # A stand-in index map (angles on the circle, or not) over a stand-in inverted index with
    # empty neurons and neurons past the last indexed one.
    n_neurons, n_frames = 700, 20000
    period = np.full(len(dims), 2 * np.pi if circular else np.inf)
    weights = rng.uniform(0, 2 * np.pi, (n_neurons, len(dims)))
    win = rng.integers(0, n_neurons - 40, n_frames) ** 2 // (n_neurons - 40)  # uneven counts
    ptr = np.zeros(win.max() + 2, dtype=np.int64)
    np.add.at(ptr, win + 1, 1)
    rt.cmap = SimpleNamespace(weights_=weights, period_=period)
    rt.lib = SimpleNamespace(index_ptr=np.cumsum(ptr), index_frames=np.argsort(win, kind="stable").astype(np.int64),
                             fps=retrieval.LIBRARY_FPS)
    monkeypatch.setattr(retrieval, "BUDGET", budget)
    sizes = []
    for _ in range(10):
        x = rng.uniform(0, 2 * np.pi, dims.max() + 1)
        for part in (0, 1, None):
            got = rt.gather(x, part)
            with monkeypatch.context() as m:
                m.setattr(retrieval, "_compiled", lambda: None)  # the numpy steps
                ref = rt.gather(x, part)
            np.testing.assert_array_equal(got, ref)  # the same frames in the same order
            sizes.append(len(ref))
    if budget < 20000:
        assert min(sizes) >= budget
    else:  # the budget is out of reach: every one of the nearest GATHER_NEURONS neurons is visited
        assert max(sizes) < budget


def test_batched_seams_and_distances_equal_the_single_ones(engine):
    # seam_pair and seam_distances run compiled kernels here (numba is loaded); seams and
    # encode_parts are the numpy references.
    rt = retrieval.Retriever(engine, engine.model.library_)
    lib = rt.lib
    rng = np.random.default_rng(11)
    for i in range(20):
        ta, tb = engine.tracks[HELD_OUT[i % 3]], engine.tracks[HELD_OUT[(i + 1) % 3]]
        a_end, b_start = int(rng.integers(len(ta.gpos))), int(rng.integers(len(tb.gpos)))
        ia, ib = [max(a_end - 1, 0), a_end], [b_start, min(b_start + 1, len(tb.gpos) - 1)]
        pair = rt.seam_pair(ta, ia, tb, ib)
        for got, ref in zip(pair, (rt.seams(ta, ia, 1), rt.seams(tb, ib, 0))):
            for name in ("pose", "vel", "root"):
                np.testing.assert_array_equal(getattr(got, name), getattr(ref, name))
            for part in (0, 1):  # a seam's rows as the library's rows are made
                rows = rt.rows(part, got.pose[None], got.vel[None], got.root[None])
                for a, b in zip(rt.query_vectors(part, got), rows):
                    np.testing.assert_array_equal(a, b[0])
        segments = [(p, int(rng.integers(len(lib))), int(rng.integers(len(lib)))) for p in (0, 1, 1)]
        xa, xb = ta.features[a_end], tb.features[b_start]
        both = rt.seam_distances(segments, xa, xb)
        assert both == [rt.seam_distance(p, s, e, xa, xb) for p, s, e in segments]
        assert min(both) > 0
        for (p, s, e), got in zip(segments, both):  # the posture features of the map's encoding
            x = rt.space.encode_parts(lib.rots[[s, e]][:, rt.space.joints].astype(float), lib.gpos[[s, e], UP])
            dims = rt.part_dims[p]
            d = max(np.linalg.norm((x[0] - xa)[dims]), np.linalg.norm((x[1] - xb)[dims]))
            assert got == pytest.approx(np.degrees(d / np.sqrt(len(dims) / 3.0)), abs=1e-9)


def test_a_seams_query_rows_are_the_librarys_rows_of_its_features(engine):
    # query_vectors reads a seam's features by a precomputed plan; they must be the very rows
    # the library's frames get (rows), or the search would rank against shifted queries.
    rt = retrieval.Retriever(engine, engine.model.library_)
    for name in HELD_OUT:
        tr = engine.tracks[name]
        for a in (1, 30, len(tr.gpos) - 3):
            for q in rt.seam_pair(tr, [a - 1, a], tr, [a, a + 1]):
                for p in (0, 1):
                    rows = rt.rows(p, q.pose[None], q.vel[None], q.root[None])
                    for got, want in zip(rt.query_vectors(p, q), rows):
                        assert got.dtype == np.float32
                        np.testing.assert_array_equal(got, want[0])


@pytest.mark.parametrize("circular", [False, True])
def test_gathering_both_seams_at_once_equals_one_by_one(engine, circular):
    from types import SimpleNamespace

    rt = retrieval.Retriever(engine, engine.model.library_)
    rng = np.random.default_rng(12)
    if circular:  # a stand-in map: the legs' columns on the circle, the others not
        period = np.full(rt.cmap.weights_.shape[1], np.inf)
        period[rt.index_cols[0]] = 2 * np.pi
        period[rt.index_cols[1]] = np.inf
        rt.cmap = SimpleNamespace(weights_=np.mod(rt.cmap.weights_, 2 * np.pi), period_=period)
    for i in range(10):
        ta, tb = engine.tracks[HELD_OUT[i % 3]], engine.tracks[HELD_OUT[(i + 2) % 3]]
        xa, xb = ta.features[rng.integers(len(ta.gpos))], tb.features[rng.integers(len(tb.gpos))]
        both = rt.gather_seams(xa, xb)
        for part in (0, 1):
            np.testing.assert_array_equal(both[part][0], rt.gather(xa, part))
            np.testing.assert_array_equal(both[part][1], rt.gather(xb, part))
            assert len(both[part][0]) >= retrieval.BUDGET


def test_searching_both_parts_at_once_equals_each_alone(engine):
    # search_parts (one compiled call for both body parts) finds what search_alphas finds for
    # each part alone: the same segments, costs and counts, with and without the displacement.
    rt = retrieval.Retriever(engine, engine.model.library_)
    rng = np.random.default_rng(14)
    found = 0
    for i in range(8):
        ta, tb = engine.tracks[HELD_OUT[i % 3]], engine.tracks[HELD_OUT[(i + 1) % 3]]
        a_end, b_start = int(rng.integers(2, len(ta.gpos))), int(rng.integers(0, len(tb.gpos) - 2))
        qa, qb = rt.seam_pair(ta, [a_end - 1, a_end], tb, [b_start, b_start + 1])
        gathered = rt.gather_seams(ta.features[a_end], tb.features[b_start])
        d, alphas = float(rng.integers(6, 46)), (float(rng.random()), 0.0, 1.0)
        disp = (float(rng.normal(scale=30)), float(rng.normal(scale=30)), float(rng.normal())) if i % 2 else None
        both = rt.search_parts(qa, qb, gathered, d, 30.0, alphas, disp, 1 + i)
        for part in (0, 1):
            alone = rt.search_alphas(part, qa, qb, *gathered[part], d, 30.0, alphas, disp if part == 0 else None, 1 + i)
            for got, ref in zip(both[part], alone):
                assert (got is None) == (ref is None)
                if ref is not None:
                    for x, y in zip(got, ref):
                        np.testing.assert_array_equal(x, y)
                    found += len(ref[0])
    assert found > 100
    with pytest.raises(ValueError, match="top_k"):
        rt.search_parts(qa, qb, gathered, 31.0, 30.0, (0.5,), None, 0)


def _straight_path(length: int) -> np.ndarray:
    """One segment walking straight along the first horizontal axis at one unit a frame, heading
    0, sampled at t = -1 .. length + 2 (as :func:`retrieval.segment_times` samples)."""
    t = np.arange(-1, length + 3, dtype=float)
    return np.stack([t, np.zeros_like(t), np.zeros_like(t)], axis=1)[None].copy()


@pytest.mark.parametrize("length", [20, 45])
def test_a_straight_path_bends_into_a_gap_that_turns(length):
    d = length + 1.0
    traj = _straight_path(length)
    a2 = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    # B a quarter circle on (arc length d), facing and walking a quarter turn to the left.
    r = 2 * d / np.pi
    b2 = np.array([[r, r, np.pi / 2], [r, r + 1.0, np.pi / 2]])
    before = np.hypot(*(traj[0, -2, :2] - b2[0, :2]))
    curves = retrieval.hermite_offsets(length, 20.0)
    retrieval.bend_paths(traj, a2, b2, curves)
    after = np.hypot(*(traj[0, -2, :2] - b2[0, :2]))
    assert after < 0.25 * before
    # It starts where A is, with A's direction, and turns to the left all the way.
    np.testing.assert_allclose(traj[0, 1, :2], [0.0, 0.0], atol=1e-12)
    steps = np.diff(traj[0, 1:-1, :2], axis=0)
    angles = np.unwrap(np.arctan2(steps[:, 1], steps[:, 0]))
    assert abs(angles[0]) < 0.05 and np.all(np.diff(angles) > -1e-9) and angles[-1] > 1.2
    np.testing.assert_allclose(traj[0, :, 2], 0.0)  # the heading column is left to the offsets


def test_a_path_is_not_bent_away_from_b():
    # B ahead and a little to the right, but facing 45 degrees to the left (hips held turned, not
    # a turn of the walk): bending to the left would take the end away from B, so nothing moves.
    length = 30
    traj = _straight_path(length)
    before = traj.copy()
    a2 = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    b2 = np.array([[length + 1.0, -2.0, np.pi / 4], [length + 2.0, -2.0, np.pi / 4]])
    retrieval.bend_paths(traj, a2, b2, retrieval.hermite_offsets(length, 20.0))
    np.testing.assert_array_equal(traj, before)


def test_a_bend_that_mends_little_of_the_miss_is_not_taken(monkeypatch):
    # B a quarter turn to the left but ahead of the straight path's end and a little to the left:
    # the best fraction of the bend (about 1%) would mend almost none of the miss (the gate's
    # lower end is 30%), so the path stays; with the gate open, it moves.
    length = 30
    a2 = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    b2 = np.array([[length + 4.0, 2.0, np.pi / 2], [length + 4.0, 3.0, np.pi / 2]])
    curves = retrieval.hermite_offsets(length, 20.0)
    traj = _straight_path(length)
    retrieval.bend_paths(traj, a2, b2, curves)
    np.testing.assert_array_equal(traj, _straight_path(length))
    monkeypatch.setattr(retrieval, "BEND_GATE", (-1.0, 0.0))
    retrieval.bend_paths(traj, a2, b2, curves)
    assert 1e-3 < np.abs(traj - _straight_path(length)).max() < 1.0


def test_compiled_root_trajectory_matches_the_numpy_steps(engine):
    from posturemap.synth import retrieval_numba

    rt = retrieval.Retriever(engine, engine.model.library_)
    rng = np.random.default_rng(13)
    for i in range(12):
        ta, tb = engine.tracks[HELD_OUT[i % 3]], engine.tracks[HELD_OUT[(i + 1) % 3]]
        # B's headings a few turns off A's (a clip that turned on the spot): B's seam is taken
        # to the nearest equivalent heading.
        tb = dataclasses.replace(tb, heading=tb.heading + 2 * np.pi * (i % 3 - 1) * 2)
        a_end, b_start = int(rng.integers(1, len(ta.gpos))), int(rng.integers(0, len(tb.gpos) - 1))
        ia, ib = [a_end - 1, a_end], [b_start, b_start + 1]
        length = int(rng.integers(5, 46))
        qa, qb = rt.seam_pair(ta, ia, tb, ib)
        sa, sb = rt.gather_seams(ta.features[a_end], tb.features[b_start])[0]
        s, e = rt.search(0, qa, qb, sa, sb, length + 1.0, 30.0, 0.5, None, 1 + i % 8)[:2]
        i0, i1, f = retrieval.segment_times(rt.lib, s, e, length + 1.0)
        curves = retrieval.hermite_offsets(length, float(rng.uniform(5, 25)))
        align = bool(i % 2)
        gpos, heading, shift = np.empty((length, 3)), np.empty(length), np.empty(3)
        dtheta = retrieval_numba.trajectory(rt.lib.gpos, rt.lib.heading, i0, i1, f, ta.gpos[ia], ta.heading[ia],
                                            tb.gpos[ib], tb.heading[ib], align, UP, curves, gpos, heading,
                                            shift, *retrieval.BEND_GATE)
        got = gpos, heading, dtheta, shift
        ref = retrieval.root_trajectory(rt.lib, i0, i1, f, ta, tb, ia, ib, align, UP, curves)
        for g, r in zip(got, ref):  # positions, headings, B's turn and shift
            np.testing.assert_allclose(g, r, rtol=0, atol=1e-9)
        assert np.ptp(ref[0][:, 0]) > 1.0  # the root moves (not a trivial comparison)


def test_compiled_replay_of_a_match_equals_the_numpy_steps(engine, monkeypatch):
    # replay() runs each body part in one compiled call (segment times, replay, root path and
    # contacts); the numpy steps are the reference: the same rotations, path, turn, shift and
    # planted feet, for whole replays, some frames only, and a part left out.
    rt = retrieval.Retriever(engine, engine.model.library_)
    rng = np.random.default_rng(15)
    planted = moving = 0
    for i in range(10):
        ta, tb = engine.tracks[HELD_OUT[i % 3]], engine.tracks[HELD_OUT[(i + 1) % 3]]
        a_end, b_start = int(rng.integers(1, len(ta.gpos))), int(rng.integers(0, len(tb.gpos) - 1))
        length = int(rng.integers(5, 46))
        m = retrieval.match(rt, ta, tb, a_end, b_start, length, float(rng.random()), bool(i % 2))
        frames = None if i % 3 == 0 else (int(rng.integers(0, length)), int(rng.integers(length // 2, length + 3)))
        if i % 4 == 3:  # the upper body unconfident: not replayed
            m.confidence = [1.0, 0.0]
        elif i == 5:  # the legs unconfident
            m.confidence = [0.0, 1.0]
        got = retrieval.replay(rt, m, skip_unconfident=True, frames=frames)
        with monkeypatch.context() as mp:
            mp.setattr(retrieval, "_compiled", lambda: None)
            ref = retrieval.replay(rt, m, skip_unconfident=True, frames=frames)
        assert quat.angle_between(got.rots, ref.rots).max() < 1e-6
        if ref.gpos is None:  # the legs unconfident: no root either way
            assert got.gpos is None and got.contacts is None
            # and no legs' pelvis to lift the upper body over: its top joints as replayed
            with monkeypatch.context() as mp:
                mp.setattr(retrieval, "UPPER_LIFT", 0.0)
                unlifted = retrieval.replay(rt, m, skip_unconfident=True, frames=frames)
            np.testing.assert_array_equal(got.rots, unlifted.rots)
            continue
        np.testing.assert_allclose(got.gpos, ref.gpos, rtol=0, atol=1e-9)
        np.testing.assert_allclose(got.heading, ref.heading, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got.shift, ref.shift, rtol=0, atol=1e-9)
        assert abs(got.dtheta - ref.dtheta) < 1e-12
        np.testing.assert_array_equal(got.contacts, ref.contacts)
        planted += int(ref.contacts.any())
        moving += int(np.ptp(ref.gpos[:, 0]) > 5.0)
    assert planted >= 5 and moving >= 5  # feet planted, roots moving: not a trivial comparison


def test_compiled_segment_times_match_the_numpy_steps(model):
    from posturemap.synth import retrieval_numba

    lib = model.library_
    rng = np.random.default_rng(14)
    # Segments anywhere, also at a clip's first and last frames (the samples before and after the clip).
    s = np.concatenate([rng.integers(0, len(lib) - 50, 40), lib.clip_start[:-1][:5]])
    e = np.minimum(s + rng.integers(0, 45, len(s)), lib.clip_end[s] - 1)
    for d in (6.0, 21.0, 31.0, 46.0):
        t = np.arange(-1, d + 2, dtype=float)
        got = np.empty((len(s), len(t)), dtype=np.int64), np.empty((len(s), len(t)), dtype=np.int64), \
            np.empty((len(s), len(t)))
        retrieval_numba.segment_times(lib.clip_start, lib.clip_of, lib.clip_end, s, e, d, t, *got)
        ref = retrieval.segment_times(lib, s, e, d)
        for g, r in zip(got, ref):
            assert g.dtype == r.dtype
            np.testing.assert_array_equal(g, r)
        # Every sample is the lerp of two neighbouring frames of its clip at the time asked, also
        # one frame outside the clip (extrapolated from its two edge frames: the seams' velocity).
        np.testing.assert_allclose(ref[0] + ref[2], s[:, None] + t[None] * ((e - s) / d)[:, None], rtol=0, atol=1e-9)
        assert np.all(ref[1] - ref[0] == 1)
        assert np.all(ref[0] >= lib.clip_start[lib.clip_of[s]][:, None]) and np.all(ref[1] < lib.clip_end[s][:, None])
        assert np.any(ref[2] < 0.0) and np.any(ref[2] > 1.0)  # before a clip's start, after its end
        assert np.any(ref[2] == 0.0) and np.any((ref[2] > 0) & (ref[2] < 1))


def test_a_segment_at_its_clips_first_frame_keeps_as_velocity_at_the_seam(bandai_paths):
    # A map of two clips (the command line's without --map): a walk backwards continued by its own
    # clip's first frames. The sample before the clip's start was held on its first frame, the
    # segment read as still there, and the seam correction added A's whole velocity to the
    # segment's own: the root's step jumped from 3.1 to 5.5 cm a frame at A's seam.
    paths = bandai_paths(["walk-back_normal_001", "walk_normal_001"])
    a, b = bvh.read(paths["walk-back_normal_001"]), bvh.read(paths["walk_normal_001"])
    out = transition(a, b, PostureMap(seed=0).fit([a, b], ["a", "b"]), length=20, method="retrieval")
    hips = out.global_positions()[:, a.skeleton.index("Hips")][:, [0, 2]]
    step = np.linalg.norm(np.diff(hips, axis=0), axis=1)
    n = len(a)
    assert step[n - 2] > 2.5  # A walks backwards at 3 cm a frame
    assert abs(step[n - 1] - step[n - 2]) < 0.1 * step[n - 2], step[n - 3: n + 2]


def test_the_warps_are_read_per_call(engine, clips, monkeypatch):
    # The compiled search keeps the warp terms per gap: they must follow retrieval.WARPS.
    rt = retrieval.Retriever(engine, engine.model.library_)
    name, a_end, b_start = windows(clips, 45, 1, seed=3)[0]
    tr = engine.tracks[name]
    qa, qb = rt.seam_pair(tr, [a_end - 1, a_end], tr, [b_start, b_start + 1])
    sa, sb = rt.gather_seams(tr.features[a_end], tr.features[b_start])[0]
    s, e = rt.search(0, qa, qb, sa, sb, 46.0, 30.0, 0.5, None, 8)[:2]
    assert len(set(e - s)) > 1  # segments of several durations
    monkeypatch.setattr(retrieval, "WARPS", (1.0,))
    s, e = rt.search(0, qa, qb, sa, sb, 46.0, 30.0, 0.5, None, 8)[:2]
    assert set(e - s) == {46}


def test_a_splice_plants_the_feet_between_different_motions(engine, clips, monkeypatch):
    # Transitions between held-out walks and runs, B placed to continue A: where no single
    # library segment fits both seams, the engine splices A's continuation into B's arrival.
    # Against the same engine without the splice, the feet slide less (the standard
    # height-weighted skate of the new frames), and the report names both halves.
    from posturemap.core.joints import foot_joints, leg_length
    from posturemap.evaluate import metrics
    from posturemap.synth import engine as engine_module
    from posturemap.synth import splice as splice_module

    sk = engine.skeleton
    feet = foot_joints(sk.names)
    height = metrics.SKATE_HEIGHT_LEGS * leg_length(sk)
    rng = np.random.default_rng(9)
    pairs = []
    while len(pairs) < 12:
        a, b = rng.choice(HELD_OUT, 2, replace=False)
        pairs.append((a, b, int(rng.integers(20, len(clips[a]) - 1)), int(rng.integers(0, len(clips[b]) - 40))))

    def skates():
        out, used = [], 0
        for a, b, a_end, b_start in pairs:
            r, p = engine.generate(a, b, length=30, a_end=a_end, b_start=b_start, method="retrieval")
            info = engine.last["retrieval"]
            if info and "splice" in info:
                used += 1
                assert all("then" in part for part in info["parts"].values())
                # Each half averages its best HALF_TOP_K segments, where the single one averages TOP_K.
                assert all(part["blended"] == part["then"]["blended"] == splice_module.HALF_TOP_K
                           for part in info["parts"].values())
            elif info:
                assert all(part["blended"] == retrieval.TOP_K for part in info["parts"].values())
            g = fk(sk.parents, r, p)[1][:, feet]
            out.append(metrics.weighted_skate(g[None], 30.0, UP, height)[0])
        return np.mean(out), used

    # The feet the splice plants, measured under the fixed clearance: this small library's toes
    # (walks, runs, a dash) keep 1.5-6 cm above the floor from 0.5 leg lengths per second, and
    # its clearance lifts the sliding feet of both out of the measure's reach (last lines).
    library_class = type(engine.model.library_)
    clearance = library_class.clearance
    monkeypatch.setattr(library_class, "clearance", property(lambda self: None))
    with_splice, used = skates()
    monkeypatch.setattr(engine_module, "spliced", lambda *args, **kw: None)  # the engine's name for it
    without, _ = skates()
    assert used >= 4
    assert with_splice < 0.8 * without, (with_splice, without)
    monkeypatch.setattr(library_class, "clearance", clearance)
    lifted_without, _ = skates()
    monkeypatch.undo()
    lifted_with, _ = skates()
    assert max(lifted_with, lifted_without) < 0.5 * without, (lifted_with, lifted_without, without)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_a_fully_confident_transition_takes_the_open_columns_from_spline(model, clips, backend):
    # With every part retrieved at full confidence, the engine does not run a whole fallback:
    # it makes the joints above the root and the local translations alone, as cubic Hermites
    # from A's last frame and rate to B's first. They must be the spline method's. A library
    # clip (its own frames match exactly), whose joint above the root turns ever faster and
    # whose joints' translations drift ever faster, so that both columns move and their rates
    # differ at the two seams (a LERP, the slerp method's, then differs).
    walk = clips["walk_normal_001"]
    eng = TransitionEngine(model)
    top = int(eng._chain[0])
    assert len(eng._chain) == 1 and top != eng._root  # Bandai: a reference joint above the hips
    rots, pos = walk.rotations.copy(), walk.positions.copy()
    n = len(walk)
    frames = np.arange(n)
    rots[:, top] = quat.mul(quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), 1e-5 * frames**2), rots[:, top])
    others = np.flatnonzero(np.arange(walk.skeleton.num_joints) != eng._root)
    pos[:, others] += 1e-4 * (frames**2)[:, None, None]
    eng.add("walk", Motion(walk.skeleton, rots, pos, walk.fps))
    checked = 0
    with kernels.numpy_backend() if backend == "numpy" else contextlib.nullcontext():
        assert (retrieval._compiled() is None) == (backend == "numpy")
        checked = _open_columns_match_spline(eng, top, others)
    assert checked >= 22  # at least two gaps with B fixed and two with B moved


def _open_columns_match_spline(eng, top, others) -> int:
    checked = 0
    for (a_end, b_start, length), align in itertools.product(((40, 71, 30), (90, 136, 45), (150, 166, 15)),
                                                             (False, True)):
        kw = dict(length=length, a_end=a_end, b_start=b_start, align=align, foot_lock=False)
        r, p = (x.copy() for x in eng.generate("walk", "walk", method="retrieval", **kw))
        if eng.last["retrieval"]["confidence"] < 1.0:
            continue
        r_ref, p_ref = eng.generate("walk", "walk", method="spline", **kw)
        # The top moves, so with B placed it is placed with B, bent with the body's own path
        # (trajectory.carry_chain, test_transition): the open columns are the others there.
        cols = others[others != top] if align else others
        np.testing.assert_allclose(p[:, cols], p_ref[:, cols], rtol=0, atol=1e-9)
        if not align:
            gap = np.minimum(np.abs(r[:, top] - r_ref[:, top]), np.abs(r[:, top] + r_ref[:, top])).max()
            assert gap < 1e-12, gap  # the same quaternions (up to sign)
            assert quat.angle_between(r[0, top], r[-1, top]) > 0.01  # the column moves: a real check
        r_lin, p_lin = eng.generate("walk", "walk", method="slerp", **kw)
        assert np.abs(p[:, cols] - p_lin[:, cols]).max() > 0.01  # not the LERP
        checked += 1 + 10 * align
    return checked


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_a_reference_joint_that_carries_the_trajectory_keeps_its_speed_through_the_seams(model, clips, backend):
    # run_normal_001's joint_Root moves with the runner (8.7 cm a frame); walk_normal_001's stays
    # at the origin, behind where A ends. The open columns' joint_Root must leave A at A's speed
    # and reach B at rest, not turn back at A's seam. Nothing else drives joint_Root.
    from posturemap.synth import engine as engine_module
    run, walk = clips["run_normal_001"], clips["walk_normal_001"]
    eng = TransitionEngine(model)
    eng.add("run", run)
    eng.add("walk", walk)
    top = int(eng._chain[0])
    ta, tb = eng.tracks["run"], eng.tracks["walk"]
    a_end, b_start, length = 12, 162, 30
    with kernels.numpy_backend() if backend == "numpy" else contextlib.nullcontext():
        assert (retrieval._compiled() is None) == (backend == "numpy")
        _, pos = engine_module._open_columns(eng, ta, tb, a_end, b_start, length)
    path = np.concatenate([run.positions[a_end - 1: a_end + 1, top], pos[:, top], walk.positions[b_start:
                                                                                               b_start + 2, top]])
    acc = np.linalg.norm(np.diff(path, 2, axis=0), axis=-1)
    assert np.linalg.norm(np.diff(run.positions[:a_end + 1, top], 2, axis=0), axis=-1).max() < 0.05
    assert acc.max() < 3.0, acc.round(2)  # LERPed: 12.1 at A's seam
    np.testing.assert_allclose(pos[0, top] - run.positions[a_end, top],
                               run.positions[a_end, top] - run.positions[a_end - 1, top], atol=1.5)


def test_a_shared_dict_serves_one_transition_and_starts_afresh_for_another(engine):
    # The engine passes one dict to the single segment's match and to both halves of a splice;
    # a caller reusing it for another gap (length, B fixed or not, how many blended) must get
    # what a fresh call gets, not the first transition's segments.
    rt = retrieval.Retriever(engine, engine.model.library_)
    tr = engine.tracks[HELD_OUT[0]]
    shared = {"alphas": (0.0, 1.0)}
    first = retrieval.match(rt, tr, tr, 40, 71, 30, 0.5, True, shared=shared)
    searched = shared["found"]
    again = retrieval.match(rt, tr, tr, 40, 71, 30, 1.0, True, seam="b", shared=shared)
    assert shared["found"] is searched and set(searched) == {0.5, 0.0, 1.0}  # one search, three rankings
    assert again.found[0][0][0] == retrieval.match(rt, tr, tr, 40, 71, 30, 1.0, True, seam="b").found[0][0][0]
    for kw in ({"length": 15}, {"align": False}, {"top_k": 1}):
        args = {"length": 30, "align": True, "top_k": None, **kw}
        got = retrieval.match(rt, tr, tr, 40, 71, args["length"], 0.5, args["align"], top_k=args["top_k"],
                              shared=shared)
        fresh = retrieval.match(rt, tr, tr, 40, 71, args["length"], 0.5, args["align"], top_k=args["top_k"])
        for p in (0, 1):
            for x, y in zip(got.found[p], fresh.found[p]):
                np.testing.assert_array_equal(x, y)
        assert got.info == fresh.info
    assert first.info != got.info
    with pytest.raises(ValueError, match="top_k"):
        retrieval.match(rt, tr, tr, 40, 71, 30, 0.5, True, top_k=0)


def test_a_splice_that_lifts_both_feet_off_the_floor_is_not_kept(engine, clips, monkeypatch):
    # floats(): a held-out walk's own frames stand on the floor; raised by 0.15 leg lengths for
    # FLOAT_S they float, for a frame less they do not (a run's flight).
    from posturemap.synth import splice

    tr, a_end, length = engine.tracks["walk_angry_001"], 40, 30
    b_start = a_end + length + 1
    rots = tr.rots[a_end + 1: b_start].copy()
    rots[:, engine._chain] = (1.0, 0.0, 0.0, 0.0)  # as a replay leaves the joints above the root
    gpos = tr.gpos[a_end + 1: b_start].copy()
    assert not splice.floats(engine, tr, tr, a_end, b_start, rots, gpos)
    n = round(splice.FLOAT_S * tr.motion.fps)
    for frames, floating in ((n, True), (n - 1, False)):
        raised = gpos.copy()
        raised[5: 5 + frames, UP] += 0.15 * engine._leg_length
        assert splice.floats(engine, tr, tr, a_end, b_start, rots, raised) == floating
    # In a transition from a run into a dash, the splice of the segment that continues the run
    # and the one that arrives in the dash lifted both feet off the floor for longer than a
    # flight (the lowest foot up to 15 cm over both seams'): the single segment is taken
    # instead, its feet within 5 cm.
    sk, feet = engine.skeleton, foot_joints(engine.skeleton.names)
    a, a_end, b, b_start = "run_normal_001", 21, "dash_normal_001", 18
    eng = TransitionEngine(engine.model)
    for name in (a, b):
        eng.add(name, clips[name])
    seams = max(clips[a].global_positions()[a_end, feet, UP].min(), clips[b].global_positions()[b_start, feet, UP].min())
    lowest = {}
    for guard in (False, True):
        with monkeypatch.context() as m:
            if not guard:
                m.setattr(splice, "floats", lambda *args: False)
            r, p = eng.generate(a, b, length=20, a_end=a_end, b_start=b_start, method="retrieval")
            lowest[guard] = fk(sk.parents, r, p)[1][:, feet, UP].min(axis=1) - seams
            assert ("splice" in eng.last["retrieval"]) != guard
    assert lowest[False].max() > 10.0 and lowest[True].max() < 5.0, (lowest[False].max(), lowest[True].max())


def test_the_splice_replays_only_what_it_shows_and_equals_the_whole_replays(engine):
    # Each half of a splice replays only the frames its blend weight shows, both halves and the
    # splice in one compiled call: the result must be bit for bit the splice of the two halves
    # replayed step by step (replay, then splice), and the splice of the two whole replays (the
    # same rotations; the others are never read).
    from posturemap.synth import splice

    rt = retrieval.Retriever(engine, engine.model.library_)
    a, b = engine.tracks[HELD_OUT[0]], engine.tracks[HELD_OUT[1]]
    jit = retrieval._compiled()
    assert jit is not None
    done, skipped = 0, 0
    for length, alpha, a_end, b_start in ((30, 0.5, 60, 20), (20, 0.0, 90, 5), (45, 1.0, 120, 40), (1, 0.5, 70, 10),
                                          (5, 0.3, 80, 12)):
        got = splice.spliced(rt, a, b, a_end, b_start, length, alpha)
        first, second = splice.halves(rt, a, b, a_end, b_start, length)
        if min(first.confidence[0], second.confidence[0]) <= 0.0:
            assert got is None
            continue
        w = splice.splice_weights(length, alpha)
        shown = (0, int(np.flatnonzero(w < 1.0)[-1]) + 1), (int(np.flatnonzero(w > 0.0)[0]), length)
        place = (a.gpos[a_end], float(a.heading[a_end]), b.gpos[b_start], UP)
        steps = splice.splice(retrieval.replay(rt, first, skip_unconfident=True, frames=shown[0]),
                              retrieval.replay(rt, second, skip_unconfident=True, frames=shown[1]), w, *place)
        floating = splice.floats(engine, a, b, a_end, b_start, steps[0], steps[1])
        assert (got is None) == floating
        if floating:
            continue
        whole = splice.splice(retrieval.replay(rt, first, skip_unconfident=True),
                              retrieval.replay(rt, second, skip_unconfident=True), w, *place)
        for x, y in zip((got.rots, got.gpos, got.heading, got.dtheta, got.shift, got.contacts), steps):
            np.testing.assert_array_equal(x, y)
        gap = np.minimum(np.abs(got.rots - whole[0]), np.abs(got.rots + whole[0])).max()
        assert gap < 1e-12, gap  # the same quaternions (up to sign)
        np.testing.assert_array_equal(got.gpos, whole[1])
        # Without numba, spliced() runs those steps in numpy: the same frames, to rounding.
        with kernels.numpy_backend():
            plain = splice.spliced(rt, a, b, a_end, b_start, length, alpha)
            ref = splice.splice(retrieval.replay(rt, first, skip_unconfident=True, frames=shown[0]),
                                retrieval.replay(rt, second, skip_unconfident=True, frames=shown[1]), w, *place)
        for x, y in zip((plain.rots, plain.gpos, plain.heading, plain.dtheta, plain.shift, plain.contacts), ref):
            np.testing.assert_array_equal(x, y)
        gap = np.minimum(np.abs(got.rots - plain.rots), np.abs(got.rots + plain.rots)).max()
        assert gap < 1e-8, gap  # the numpy and compiled replays round differently
        np.testing.assert_allclose(got.gpos, plain.gpos, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(got.contacts, plain.contacts)
        skipped += sum(half.confidence[1] <= 0.0 for half in (first, second))  # an upper body left out
        done += 1
    assert done >= 3 and skipped >= 1


def test_a_segment_is_matched_at_the_speed_it_is_replayed_at(model, clips):
    """A segment of ``n`` library frames replayed over a gap of ``d`` frames plays ``n / d`` as
    fast as recorded, so its seam velocities are compared at that speed: a clip played 1.2x as
    fast (resampled, its rate kept) matches its own library frames best at warp 1.2 (the
    velocities once were divided by the warp, which made such a seam prefer warp 0.85)."""
    from posturemap.core.motion import resample

    name, speed, k, d = "walk_normal_001", 1.2, 50, 20.0
    src = clips[name]
    fast = resample(src, src.fps / speed)
    fast = Motion(fast.skeleton, fast.rotations, fast.positions, src.fps)  # 1.2x as fast
    eng = TransitionEngine(model)
    eng.add("fast", fast)
    rt = retrieval.Retriever(eng, model.library_)
    track = eng.tracks["fast"]
    qa = rt.seams(track, [k - 1, k], 1)  # the fast clip's frame k is the recording's frame 60
    s = model.library_.library_frame(name, round(k * speed))
    warps = (0.85, 1.0, speed, 1.33)
    e = np.array([s + round(w * d) for w in warps])
    for part in (0, 1):
        ca, _ = rt.pair_costs(part, np.full(len(e), s), e, qa, qa, d, src.fps)
        assert np.argmin(ca) == warps.index(speed), (part, ca)
        assert ca[warps.index(speed)] < 0.25 * ca[warps.index(0.85)], (part, ca)


def test_a_foot_passed_between_held_spots_sets_off_no_faster_than_a_walking_ankle(engine, clips, monkeypatch):
    # A tired walk into a happy one, 20 frames: at the pace alone (feet.PASS_SPEED) a held foot's
    # correction set off from rest in a few frames and came down on a run a frame or two long,
    # the largest acceleration of any joint 1.6 times the largest in A's last and B's first
    # frames (2.7 while a step lifted the foot by its whole way, before feet.STEP_RISE). Bounded by a walking ankle's acceleration (feet.PASS_ACCEL), with no run left
    # shorter than feet.PASS_LEAST_S, it is under theirs. (The knee's bound, feet.KNEE_ACCEL,
    # is off at the pace alone: it also softens that pass, to 1.25 times theirs.)
    from posturemap.synth import feet as feet_module

    a, a_end, b, b_start, length = "walk_tired_001", 205, "walk_happy_001", 176, 20
    eng = TransitionEngine(engine.model)
    for name in (a, b):
        eng.add(name, clips[name])
    sk = engine.skeleton

    def largest(g):
        return np.linalg.norm(np.diff(g, 2, axis=0), axis=-1).max()

    own = max(largest(clips[a].global_positions()[a_end - 10: a_end + 1]),
              largest(clips[b].global_positions()[b_start: b_start + 11]))
    peak = {}
    for bound in ("pace", "accel"):
        if bound == "pace":
            monkeypatch.setattr(feet_module, "PASS_ACCEL", np.inf)
            monkeypatch.setattr(feet_module, "PASS_LEAST_S", 0.0)
            monkeypatch.setattr(feet_module, "KNEE_ACCEL", np.inf)
        else:
            monkeypatch.undo()
        r, p = eng.generate(a, b, length=length, a_end=a_end, b_start=b_start, method="retrieval")
        g = np.concatenate([clips[a].global_positions()[a_end - 1: a_end + 1], fk(sk.parents, r, p)[1]])
        peak[bound] = largest(g)
    assert peak["pace"] > 1.5 * own and peak["accel"] < own, (peak, own)


def test_a_foot_passed_between_two_held_spots_is_not_snapped_across(engine, clips, monkeypatch):
    # A run into a tired walk, 8 frames: the splice of A's own continuation into B's arrival
    # holds one foot on A's spot for three frames and on B's for four, one frame apart, with
    # corrections of 14 and 17 cm. Passed in that frame, the foot moved 24 cm a frame twice,
    # where A's last and B's first frames step 16 cm at most; the runs now let go of their ends
    # so that it passes at a walking pace (feet.PASS_SPEED), lifted as a step.
    from posturemap.synth import feet as feet_module

    a, a_end, b, b_start, length = "run_happy_001", 91, "walk_tired_001", 117, 8
    eng = TransitionEngine(engine.model)
    for name in (a, b):
        eng.add(name, clips[name])
    sk, ft = engine.skeleton, foot_joints(engine.skeleton.names)
    inputs = np.concatenate([clips[a].global_positions()[a_end - 10: a_end + 1, ft],
                             clips[b].global_positions()[b_start: b_start + 11, ft]])
    steps = np.linalg.norm(np.diff(inputs, axis=0), axis=-1)
    own = max(steps[:10].max(), steps[11:].max())  # A's last and B's first steps (not across them)
    peak = {}
    for pace in (0.0, feet_module.PASS_SPEED):
        monkeypatch.setattr(feet_module, "PASS_SPEED", pace)
        r, p = eng.generate(a, b, length=length, a_end=a_end, b_start=b_start, method="retrieval")
        g = np.concatenate([clips[a].global_positions()[a_end: a_end + 1, ft], fk(sk.parents, r, p)[1][:, ft]])
        peak[pace] = np.linalg.norm(np.diff(g, axis=0), axis=-1).max()
    assert peak[0.0] > 1.4 * own and peak[feet_module.PASS_SPEED] < 1.1 * own, (peak, own)
