"""The clips' own motion (issue "Transitions that move like real people"): retrieval searches A's
frames up to its end and B's from its start besides the map's library, and replays the better
match; a gap in a take (A and B the same clip) is filled from the take's other frames, never from
the frames it replaces.
"""

from __future__ import annotations

import numpy as np
import pytest

from posturemap.core import quat
from posturemap.core.joints import part_masks
from posturemap.core.motion import Motion
from posturemap.core.skeleton import fk
from posturemap.io import bvh
from posturemap.learn.model import PostureMap
from posturemap.synth import engine as engine_module
from posturemap.synth import retrieval
from posturemap.synth.engine import TransitionEngine, transition

LIBRARY = ("walk_normal_001", "walk_happy_001", "run_normal_001", "walk-left_normal_001")
TAKES = ("walk-back_old_001", "byebye_happy_001", "walk-back_proud_001", "punch_normal_001", "run_happy_001")
A_END, LENGTH = 100, 30
B_START = A_END + LENGTH + 1


@pytest.fixture(scope="module")
def paths(bandai_paths):
    return bandai_paths(LIBRARY + TAKES)


@pytest.fixture(scope="module")
def clips(paths):
    return {n: bvh.read(p) for n, p in paths.items()}


@pytest.fixture(scope="module")
def model(clips):
    return PostureMap(seed=0).fit([clips[n] for n in LIBRARY], list(LIBRARY))


def garbled(m: Motion, lo: int, hi: int, seed: int = 0) -> Motion:
    """``m`` with frames ``lo .. hi - 1`` replaced by random rotations and moved up to a few metres."""
    rng = np.random.default_rng(seed)
    rots, pos = m.rotations.copy(), m.positions.copy()
    q = rng.normal(size=rots[lo:hi].shape)
    rots[lo:hi] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    pos[lo:hi] += rng.normal(scale=100.0, size=pos[lo:hi].shape)
    return Motion(m.skeleton, rots, pos, m.fps)


def outside_the_gap(info: dict, a_end: int, b_start: int) -> bool:
    """Every replayed segment (both parts, both halves of a splice) lies in A's frames up to its
    end or in B's from its start."""
    segments = [p for p in info["parts"].values()] + [p["then"] for p in info["parts"].values() if "then" in p]
    return all(max(p["frames"]) <= a_end or min(p["frames"]) >= b_start for p in segments)


@pytest.mark.parametrize("name, a_end", [("walk-back_old_001", A_END), ("byebye_happy_001", 110),
                                          ("punch_normal_001", 112), ("run_happy_001", 70)])
def test_a_gap_in_a_take_is_filled_from_the_take_never_from_the_frames_it_replaces(model, clips, name, a_end):
    # No backward walk, wave or punch in the library. Garbled, the gap's frames would also bend
    # its knees and elbows backward, which loosened their bound when it counted the whole clip.
    take = clips[name]
    b_start = a_end + LENGTH + 1
    made = []
    for clip in (take, garbled(take, a_end + 1, b_start)):
        report = {}
        out = transition(clip, clip, model, length=LENGTH, a_end=a_end, b_start=b_start, align=False, report=report)
        made.append((out, report["retrieval"]))
    (out, info), (out_garbled, info_garbled) = made
    assert info["own"] and outside_the_gap(info, a_end, b_start)
    assert info == info_garbled
    # The same rotations (the clip's quaternion signs, chosen continuous through the gap, may
    # differ: within rounding) and the same places.
    new = slice(a_end + 1, b_start)
    assert np.all(np.abs(np.sum(out.rotations[new] * out_garbled.rotations[new], axis=-1)) > 1 - 1e-12)
    np.testing.assert_allclose(out.positions, out_garbled.positions, rtol=0, atol=1e-9)
    # Not the truth replayed: the gap's own frames were never there to replay.
    truth = take.global_positions()[new]
    assert np.linalg.norm(out.global_positions()[new] - truth, axis=-1).mean() > 0.1


def test_own_frames_are_the_takes_frames_up_to_the_seam_correction(model, clips, monkeypatch):
    monkeypatch.setattr(retrieval, "WARPS", (1.0,))  # no time warp: whole frames of the take
    monkeypatch.setattr(retrieval, "UPPER_LIFT", 0.0)  # each part's rotations as its own segment has them
    eng = TransitionEngine(model)
    tr = eng.add("take", clips["walk-back_old_001"])
    own = engine_module._own_retriever(eng, tr, tr, "take", "take", A_END, B_START, LENGTH)
    assert own.whole and own.lib.clip_names == ("take", "take") and own.lib.clip_first == (0, B_START)
    res = retrieval.retrieve(own, tr, tr, A_END, B_START, LENGTH, 0.5, False, top_k=1, blend=12.0)
    d = LENGTH + 1
    curves = retrieval.offset_curves(np.arange(1, d), d, 12.0)
    middle = np.flatnonzero((curves[1] == 0) & (curves[3] == 0))
    assert len(middle) > 0 and res.info["own"]
    for part, mask in (("lower", own.lower_mask), ("upper", own.upper_mask)):
        first, last = res.info["parts"][part]["frames"]
        assert last - first == d and (last <= A_END or first >= B_START)
        src = tr.rots[first - 1: last + 2][:, mask]  # t = -1 .. d + 1, the take's own frames

        def rel(p, q):
            return quat.log(quat.mul(p, quat.inv(q)))

        a2, b2 = tr.rots[[A_END - 1, A_END]][:, mask], tr.rots[[B_START, B_START + 1]][:, mask]
        turn = curves[0, middle, None, None] * rel(a2[1], src[1]) + curves[2, middle, None, None] * rel(b2[0], src[-2])
        expected = quat.mul(quat.exp(turn), src[2:-2][middle])
        assert np.allclose(quat.angle_between(res.rots[middle][:, mask], expected), 0.0, atol=1e-5), part


def test_the_cheaper_match_of_library_and_own_motion_is_replayed(model, clips):
    take = clips["walk-back_old_001"]
    eng = TransitionEngine(model)
    tr = eng.add("take", take)
    kw = dict(length=LENGTH, a_end=A_END, b_start=B_START, align=False, method="retrieval")
    eng.generate("take", "take", **kw)
    own_info = eng.last["retrieval"]
    library = retrieval.match(eng._retriever, tr, tr, A_END, B_START, LENGTH, 0.5, False)
    assert own_info["own"] and own_info["parts"]["lower"]["cost"] + own_info["parts"]["upper"]["cost"] <= library.cost


def test_a_library_that_holds_the_take_is_searched_without_it(model, clips):
    # A map trained on the take itself (a capture session, then a gap filled in one of its
    # takes) holds the gap's own frames, at no cost: that clip (and its reversed copy) is left
    # out, and the take's kept frames are searched as its own motion. Garbled gap frames (a
    # marker dropout) in the map's copy are not replayed either.
    take = clips["walk-back_old_001"]
    for clip in (take, garbled(take, A_END + 1, B_START)):
        knows = PostureMap(seed=0).fit([clip, clips["walk_normal_001"]], ["take", "walk"])
        lib = knows.library_
        eng = TransitionEngine(knows)
        tr = eng.add("take", take)
        rt = retrieval.Retriever(eng, lib)
        # The take (its gap whole or garbled) and its reversed copy: its frames at A's end and B's start.
        assert list(lib.take_clips(rt.part_joints[1], tr.rots[A_END], tr.rots[B_START], B_START - A_END)) == [0, 2]
        eng.generate("take", "take", length=LENGTH, a_end=A_END, b_start=B_START, align=False, method="retrieval")
        info = eng.last["retrieval"]
        for p in info["parts"].values():
            if p["clip"] == "take":  # the library's copy or the take's own frames: never its gap
                assert max(p["frames"]) <= A_END or min(p["frames"]) >= B_START, p
    # Between clips (B placed to continue A) nothing is replaced: the library's take may serve,
    # at no cost (its frames there are a real transition from A's end to B's start).
    eng.generate("take", "take", length=LENGTH, a_end=A_END, b_start=B_START, align=True, method="retrieval")
    assert eng.last["retrieval"]["parts"]["lower"]["frames"] == [A_END, B_START]


def test_a_standing_wave_goes_on_from_the_performers_own_waving(model, clips):
    # No wave in the library, and the body stands: the library's match is interpolated (a
    # standing gesture); the take's own waving plays on, nearer the truth.
    wave = clips["byebye_happy_001"]
    a_end = len(wave) // 2
    b_start = a_end + LENGTH + 1
    eng = TransitionEngine(model)
    eng.add("wave", wave)
    kw = dict(length=LENGTH, a_end=a_end, b_start=b_start, align=False)
    upper = part_masks(wave.skeleton, eng._root)[1]
    errors = {}
    for seconds in (engine_module.OWN_SECONDS, 0.0):
        eng.own_seconds = seconds
        r, p = eng.generate("wave", "wave", **kw)
        info = eng.last["retrieval"]
        grot = fk(wave.skeleton.parents, r, p)[0]
        truth = fk(wave.skeleton.parents, wave.rotations[a_end + 1: b_start], wave.positions[a_end + 1: b_start])[0]
        errors[seconds] = float(np.mean(quat.angle_between(grot[:, upper], truth[:, upper])))
        if seconds:
            assert info["own"] and info.get("standing") and info["parts"]["upper"]["confidence"] > 0.5
        else:
            assert info["confidence"] == 0.0 and info.get("standing")
    assert errors[engine_module.OWN_SECONDS] < 0.8 * errors[0.0], errors


def test_own_motion_is_searched_within_own_seconds_of_the_seams(model, clips):
    eng = TransitionEngine(model)
    tr = eng.add("take", clips["walk-back_proud_001"])
    eng.own_seconds = 1.5
    eng.generate("take", "take", length=LENGTH, a_end=A_END, b_start=B_START, align=False)
    info = eng.last["retrieval"]
    span = int(1.5 * tr.motion.fps)
    assert info["own"]
    for p in info["parts"].values():
        assert A_END + 1 - span <= min(p["frames"]) and max(p["frames"]) <= A_END \
            or B_START <= min(p["frames"]) and max(p["frames"]) < B_START + span, p
    own = engine_module._own_retriever(eng, tr, tr, "take", "take", A_END, B_START, LENGTH)
    assert len(own.lib) == 2 * span
    eng.own_seconds = 0.5  # 15 frames a side: no segment of a 31-frame gap fits
    assert engine_module._own_retriever(eng, tr, tr, "take", "take", A_END, B_START, LENGTH) is None


def test_own_motion_is_searched_within_own_frames_of_the_seams(model, clips, monkeypatch):
    # However long own_seconds is, at most OWN_FRAMES a side (every frame is a candidate).
    monkeypatch.setattr(engine_module, "OWN_FRAMES", 50)
    eng = TransitionEngine(model)
    tr = eng.add("take", clips["walk-back_proud_001"])
    own = engine_module._own_retriever(eng, tr, tr, "take", "take", A_END, B_START, LENGTH)
    assert len(own.lib) == 100 and own.lib.clip_first == (A_END + 1 - 50, B_START)


def test_a_gap_of_another_length_on_the_same_seams_searches_its_own_pieces(model, clips):
    # B's 24 frames from its start hold a segment of a 21-frame gap, not of a 41-frame one: the
    # search kept for the longer gap must not serve the shorter (a length slider).
    wave = clips["byebye_happy_001"]
    a_end, b_start = 100, len(wave) - 24
    eng, fresh = TransitionEngine(model), TransitionEngine(model)
    eng.add("w", wave)
    fresh.add("w", wave)
    kw = dict(a_end=a_end, b_start=b_start, align=False)
    eng.generate("w", "w", length=40, **kw)
    r, p = eng.generate("w", "w", length=20, **kw)
    r2, p2 = fresh.generate("w", "w", length=20, **kw)
    assert eng.last["retrieval"] == fresh.last["retrieval"]
    assert np.array_equal(r, r2) and np.array_equal(p, p2)


def test_a_replaced_clip_and_a_fork_search_their_own_clips(model, clips):
    kw = dict(length=LENGTH, a_end=A_END, b_start=B_START, align=False)
    eng = TransitionEngine(model)
    eng.add("take", clips["walk-back_old_001"])
    eng.generate("take", "take", **kw)
    eng.add("take", clips["walk-back_proud_001"])  # replaced under the same name
    r, p = (x.copy() for x in eng.generate("take", "take", **kw))
    fresh = TransitionEngine(model)
    fresh.add("take", clips["walk-back_proud_001"])
    r2, p2 = fresh.generate("take", "take", **kw)
    assert np.array_equal(r, r2) and np.array_equal(p, p2)
    assert len(eng._own) == 1  # the replaced clip's own motion let go
    child = eng.fork()
    assert child._own == {} and child._own is not eng._own
    r3, p3 = child.generate("take", "take", **kw)
    assert np.array_equal(r, r3) and np.array_equal(p, p3)


def test_the_command_line_without_a_map_fills_a_gap_from_the_takes_kept_frames(clips, tmp_path, capsys):
    from posturemap import cli

    take = clips["walk-back_old_001"]
    made = []
    for name, clip in (("take", Motion(take.skeleton, take.rotations, take.positions, take.fps)),
                       ("garbled", garbled(take, A_END + 1, B_START))):
        path, out = tmp_path / f"{name}.bvh", tmp_path / f"{name}_out.bvh"
        bvh.write(path, clip)
        assert cli.main(["transition", str(path), str(path), "-o", str(out), "--a-end", str(A_END),
                         "--b-start", str(B_START), "--length", str(LENGTH), "--no-align"]) == 0
        text = capsys.readouterr().out
        assert "the clips' own motion" in text and f"lower: {path} frames " in text, text
        made.append(bvh.read(out))
    # A length other than the gap's makes the take shorter: a warning says so (the default, 20).
    path = tmp_path / "take.bvh"
    assert cli.main(["transition", str(path), str(path), "-o", str(tmp_path / "short.bvh"), "--a-end", str(A_END),
                     "--b-start", str(B_START), "--no-align"]) == 0
    err = capsys.readouterr().err
    assert (f"posturemap: warning: {path}: A and B are one take and --length 20 is not the {LENGTH} frames between "
            f"--a-end and --b-start: the take comes out {LENGTH - 20} frames shorter") in err, err
    # Within the BVH text's six decimals (the written rotations of the gap differ, their signs with them).
    np.testing.assert_allclose(made[0].global_positions(), made[1].global_positions(), rtol=0, atol=1e-4)


def test_a_piece_of_a_clip_is_computed_from_its_own_frames_as_a_clip_of_them_would_be(model, clips):
    # own_library slices what own_frames computes once per clip; each piece must be what the
    # library's own code makes of the piece's frames as a clip of their own (velocities at its
    # first frame toward the next, its own floor and ankle speeds), so that nothing outside it
    # is read.
    from posturemap.core.joints import leg_chains
    from posturemap.synth.library import clip_contacts, clip_features, own_frames, own_library

    eng = TransitionEngine(model)
    tr = eng.add("take", clips["walk-back_old_001"])
    lib = model.library_
    keys = np.concatenate([lib.lower, lib.upper])
    ankles = [c[2] for c in leg_chains(tr.motion.skeleton)]
    frames = own_frames(tr, keys, ankles, 1)
    for lo, hi in ((0, 101), (131, 282), (57, 60), (140, 141)):
        own = own_library([("take", tr, lo, hi, frames)], 1, lib.leg, lib.lower, lib.upper, lib.scale)
        piece = tr.motion[lo:hi]
        gp = fk(piece.skeleton.parents, piece.rotations, piece.positions)[1]
        pose, vel, root = clip_features(gp, tr.gpos[lo:hi], tr.heading[lo:hi], keys, 1, piece.fps)
        np.testing.assert_allclose(own.pose, pose.astype(np.float32), rtol=1e-6, atol=1e-4)
        np.testing.assert_allclose(own.vel, vel.astype(np.float32), rtol=1e-6, atol=1e-3)
        np.testing.assert_allclose(own.root, root.astype(np.float32), rtol=1e-6, atol=1e-3)
        assert np.array_equal(own.contacts, clip_contacts(gp[:, ankles], 1, piece.fps, lib.leg)), (lo, hi)
        assert np.array_equal(own.rots, tr.rots[lo:hi].astype(np.float32)) and np.array_equal(own.scale, lib.scale)
        assert own.source_frames(0, hi - lo - 1) == ("take", lo, hi - 1) and own.library_frame("take", hi - 1) == hi - lo - 1
    # Two pieces of one clip (A's and B's): each frame found in the piece that holds it.
    both = own_library([("take", tr, 0, 101, frames), ("take", tr, 131, 282, frames)], 1, lib.leg, lib.lower, lib.upper)
    assert both.library_frame("take", 100) == 100 and both.library_frame("take", 131) == 101
    assert both.source_frames(101, 110) == ("take", 131, 140)
    with pytest.raises(ValueError):
        both.library_frame("take", 115)  # in the gap: in neither piece


def test_a_pieces_floor_is_numpys_percentile_to_the_bit():
    # The contacts of a piece (and of a library clip) stand on the 5th percentile of its ankle
    # heights; low_percentile is np.percentile's linear method from a partial sort: the same
    # bits on any length, at quantiles landing between rows, on a row and at either end, ties included.
    from posturemap.synth.library import FLOOR_PERCENTILE, low_percentile
    rng = np.random.default_rng(3)
    checked = 0
    for n in list(range(1, 70)) + [121, 600, 2001]:
        for q in (FLOOR_PERCENTILE, 0.0, 0.1, 25.0, 50.0, 62.5, 99.9, 100.0):
            for ties in (False, True):
                x = rng.normal(size=(n, 2)) * 40.0
                x = np.round(x) if ties else x
                want = np.percentile(x, q, axis=0)
                got = low_percentile(x, q)
                assert got.shape == want.shape and np.array_equal(got, want), (n, q, got, want)
                checked += 1
    assert checked == 72 * 8 * 2


def test_without_a_map_an_interpolating_methods_lock_reads_no_frame_of_the_gap(clips):
    # Without a map, the knees' hinges that straighten a knee bent backward before the foot lock
    # come from the clips (engine._clip_limbs); in a gap in a take, only from the frames the
    # output keeps: the gap garbled (a marker dropout), the same hinges and bounds to the bit,
    # and the same output within 1e-5 (a track's heading, about the facing it estimates from its
    # whole clip, moves by about 0.001 radians with the gap garbled: not this lock's reading).
    take = clips["walk-back_old_001"]
    outs, limbs = [], []
    for clip in (take, garbled(take, A_END + 1, B_START)):
        eng = TransitionEngine(None, take.skeleton)
        eng.add("take", clip)
        r, p = eng.generate("take", "take", length=LENGTH, a_end=A_END, b_start=B_START, align=False,
                            method="spline", foot_lock=True)
        outs.append((r.copy(), p.copy()))
        (found,) = eng._clip_limbs.values()
        limbs.append(found[2])
    assert len(limbs[0][0]) > 0  # hinges were found
    for x, y in zip(*limbs):
        np.testing.assert_array_equal(x, y)
    for x, y in zip(*outs):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-5)
    # Read from the whole take instead, the garbled gap moves the hinges.
    from posturemap.core.joints import arm_chains, leg_chains
    from posturemap.synth import hinges
    sk = take.skeleton
    whole = [hinges.find(sk.parents, leg_chains(sk) + arm_chains(sk), m.rotations, m.positions)
             for m in (take, garbled(take, A_END + 1, B_START))]
    assert any(not np.allclose(u[1], v[1]) for u, v in zip(*whole) if u is not None and v is not None)
