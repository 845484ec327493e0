"""Clips that cannot be mixed are refused with a clear error; clips that can are not.

Another unit (metres against centimetres), another frame rate, a clip name the engine lacks, a
map that was never fitted: each is one line naming what is wrong, never garbage nor a traceback.
"""

from __future__ import annotations

import dataclasses
import os
import sys

import numpy as np
import pytest

from clikit import assert_refused, run
from posturemap import cli
from posturemap.errors import UserError
from posturemap.io import bvh
from posturemap.learn.model import PostureMap
from posturemap.synth.engine import TransitionEngine, transition
from posturemap.synth.request import RequestError


def scaled(m, factor: float):
    """The clip in another unit: every offset and translation times ``factor``."""
    sk = dataclasses.replace(m.skeleton, offsets=m.skeleton.offsets * factor)
    return dataclasses.replace(m, skeleton=sk, positions=m.positions * factor)


@pytest.fixture(scope="module")
def walk_map(sample_clips):
    return PostureMap(seed=0, library=False).fit([sample_clips["walk"], sample_clips["run"]], ["walk", "run"])


def test_a_clip_in_another_unit_is_refused_everywhere(sample_clips, walk_map, tmp_path, capsys):
    walk, run_ = sample_clips["walk"], sample_clips["run"]
    metres = scaled(run_, 0.01)
    assert "0.01 times as long" in metres.skeleton.body_mismatch(walk.skeleton)
    # The API: training, a map's engine, an engine without a map.
    with pytest.raises(Exception, match="0.01 times as long as walk's"):
        PostureMap(seed=0, library=False).fit([walk, metres], ["walk", "metres"])
    with pytest.raises(Exception, match="as long as the map's"):
        TransitionEngine(walk_map).add("m", metres)
    with pytest.raises(Exception, match="as long as the other clips'"):
        transition(walk, metres, method="spline")
    # The command line: one line, exit 2.
    a, b, m = tmp_path / "walk.bvh", tmp_path / "metres.bvh", tmp_path / "map.npz"
    bvh.write(a, walk)
    bvh.write(b, metres)
    walk_map.save(str(m))
    assert_refused(capsys, b, "transition", a, b, "--method", "spline", "-o", tmp_path / "out.bvh",
                   words=("0.01 times as long", "another unit"))
    assert_refused(capsys, b, "transition", b, b, "--map", m, "-o", tmp_path / "out.bvh", words=("the map's",))
    assert_refused(capsys, b, "train", a, b, "-o", tmp_path / "m2.npz", words=("one unit",))
    assert not (tmp_path / "out.bvh").exists() and not (tmp_path / "m2.npz").exists()


def test_a_smaller_body_of_the_same_rig_is_not_another_unit(sample_clips, walk_map):
    walk, run_ = sample_clips["walk"], sample_clips["run"]
    small = scaled(run_, 0.8)
    assert small.skeleton.body_mismatch(walk.skeleton) is None
    out = transition(walk, small, walk_map, length=10, method="auto")
    assert np.isfinite(out.positions).all() and len(out) == len(walk) + 10 + len(small)


def test_frame_rates_within_a_thousandth_are_one_rate(sample_clips, walk_map):
    walk, run_ = sample_clips["walk"], sample_clips["run"]
    # A frame time written with six digits (1/30 as 0.033333) is still 30 fps.
    near = dataclasses.replace(run_, fps=1 / 0.033333)
    assert len(transition(walk, near, walk_map, length=10)) == len(walk) + 10 + len(near)
    double = dataclasses.replace(run_, fps=2 * run_.fps)
    with pytest.raises(Exception, match="fps"):
        transition(walk, double, walk_map, length=10)
    eng = TransitionEngine(walk_map)
    eng.add("walk", walk)
    eng.add("double", double)
    with pytest.raises(RequestError, match="resample"):
        eng.generate("walk", "double", length=10)
    # Training refuses clips at two rates, as growing a map does.
    with pytest.raises(Exception, match="one frame rate"):
        PostureMap(seed=0, library=False).fit([walk, double], ["walk", "double"])


def test_the_engine_and_the_map_name_what_is_missing(sample_clips, walk_map):
    walk = sample_clips["walk"]
    eng = TransitionEngine(walk_map)
    eng.add("walk", walk)
    with pytest.raises(RequestError, match="no clip named 'zzz'") as e:
        eng.generate("walk", "zzz", length=10)
    assert e.value.field == "b"
    with pytest.raises(RequestError, match="must be text"):
        eng.generate(3, "walk", length=10)
    with pytest.raises(RequestError, match="no transition made yet"):
        eng.continuation("walk", 0)
    eng.generate("walk", "walk", length=10)
    assert len(eng.continuation("walk", 0)) == len(walk)
    with pytest.raises(ValueError, match="not fitted"):
        TransitionEngine(PostureMap())
    with pytest.raises(ValueError, match="not fitted"):
        PostureMap().save("never.npz")
    for use in (PostureMap().score, PostureMap().predict, PostureMap().encode):
        with pytest.raises(ValueError, match="not fitted"):
            use(walk)
    with pytest.raises(TypeError, match="model must be a PostureMap"):
        TransitionEngine("map.npz")
    with pytest.raises(TypeError, match="add needs a Motion"):
        TransitionEngine().add("walk", walk.rotations)
    assert not os.path.exists("never.npz")
    with pytest.raises(TypeError, match="Motion objects"):
        PostureMap().fit(["walk.bvh"])


def test_a_clip_of_no_frames_or_with_nan_is_refused_by_name(sample_clips, walk_map, tmp_path):
    # A clip of no frames crashed deep inside (a reshape, an index out of range); a NaN at a seam
    # ran through every new frame of the transition, silently.
    walk, run_ = sample_clips["walk"], sample_clips["run"]
    rots = walk.rotations.copy()
    rots[-1, 2, 1] = np.nan
    broken = dataclasses.replace(walk, rotations=rots)
    # A rotation that is not of length 1 grew through the inverses and products of every new
    # frame: B scaled by 1.1 gave rotations of length 1e8 under the foot lock, silently.
    scale = np.where(np.arange(len(walk)) == 4, 1.1, 1.0)[:, None, None]
    longer = dataclasses.replace(walk, rotations=walk.rotations * scale)
    zero = walk.rotations.copy()
    zero[2, 3] = 0.0
    for clip, words in ((walk[:0], "the clip has no frames"), (broken, r"NaN or infinite rotation \(frame"),
                        (longer, r"rotation of length 1.1 is not a unit quaternion \(frame 4, joint"),
                        (dataclasses.replace(walk, rotations=zero), r"rotation of length 0 is not a unit quaternion "
                                                                   r"\(frame 2, joint '" + walk.skeleton.names[3])):
        with pytest.raises(UserError, match=f"^a: {words}"):
            transition(clip, run_, walk_map)
        with pytest.raises(UserError, match=f"^b: {words}"):
            transition(run_, clip, method="spline")
        with pytest.raises(UserError, match=f"^odd: {words}"):
            PostureMap(seed=0, library=False).fit([run_, clip], ["run", "odd"])
        with pytest.raises(UserError, match=f"^odd: {words}"):
            PostureMap(seed=0, library=False).fit([run_], ["run"]).partial_fit([clip], ["odd"])
        for use in (walk_map.predict, walk_map.score):
            with pytest.raises(UserError, match=f"^motion: {words}"):
                use(clip)
    with pytest.raises(bvh.BVHError, match="no frames; nothing written"):
        bvh.write(tmp_path / "empty.bvh", walk[:0])
    assert not (tmp_path / "empty.bvh").exists()


def test_rotations_nearly_of_length_one_make_rotations_of_length_one(sample_clips, walk_map):
    # float32 rotations from a game engine, or rounded ones, are off by a little: accepted, and
    # the engine keeps them scaled to length 1, so that the new frames are rotations too.
    walk, run_ = sample_clips["walk"], sample_clips["run"]
    rng = np.random.default_rng(0)
    near = [dataclasses.replace(m, rotations=m.rotations * (1 + rng.uniform(-9e-4, 9e-4, m.rotations.shape[:2] + (1,))))
            for m in (walk, run_)]
    for method in ("auto", "slerp", "spline"):
        for foot_lock in (True, False):
            out = transition(*near, walk_map, method=method, foot_lock=foot_lock, length=12, a_end=30)
            length = np.linalg.norm(out.rotations[31:43], axis=-1)
            assert np.abs(length - 1).max() < 1e-12, (method, foot_lock)
            exact = transition(walk, run_, walk_map, method=method, foot_lock=foot_lock, length=12, a_end=30)
            assert np.allclose(out.rotations[31:], exact.rotations[31:], atol=1e-5)
    assert near[0].unit() is not near[0] and walk.unit() is walk  # a copy only where one is off


def test_the_api_checks_what_it_is_given(sample_clips, walk_map, tmp_path):
    walk, run_ = sample_clips["walk"], sample_clips["run"]
    with pytest.raises(TypeError, match="request must be a TransitionRequest, got dict"):
        transition(walk, run_, walk_map, {"length": 5})
    eng = TransitionEngine(walk_map)
    eng.add("walk", walk)
    eng.add("run", run_)
    eng.generate("walk", "run", length=10)
    for frame in (len(run_), -1):  # a slice would give no frames, or the last one
        with pytest.raises(RequestError, match=f"frame {frame} is outside clip B 'run'"):
            eng.continuation("run", frame)
        with pytest.raises(RequestError, match="outside clip B"):
            eng.continuation("run", frame, align=False)
    # The frames a call returned stay as they were through a warm-up (it runs transitions of
    # the same lengths into buffers of its own), and one method may be named alone.
    rots, pos = eng.generate("walk", "run", length=29, method="spline")
    kept = rots.copy(), pos.copy()
    assert eng.warm_up("spline") == 3 * 2 * 2
    assert np.array_equal(rots, kept[0]) and np.array_equal(pos, kept[1])
    # A map written into a missing folder: one error naming the file, nothing left.
    with pytest.raises(UserError, match=r"map\.npz: cannot write file"):
        walk_map.save(str(tmp_path / "missing" / "map.npz"))
    assert list(tmp_path.iterdir()) == []


def test_a_reader_that_stops_early_is_no_error(walk_map, tmp_path, monkeypatch, capsys):
    m = tmp_path / "map.npz"
    walk_map.save(str(m))

    class Closed:
        def write(self, _):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            pass

    monkeypatch.setattr(sys, "stdout", Closed())
    code = cli.main(["inspect", str(m)])
    assert code == 141
    assert capsys.readouterr().err == ""
    monkeypatch.undo()
    code, out, err = run(capsys, "inspect", m)
    assert code == 0 and "posture map" in out and err == ""


def test_inspect_names_the_legs_or_says_there_are_none(sample_clips, tmp_path, capsys):
    from rigkit import bare

    walk = sample_clips["walk"]
    files = {name: tmp_path / f"{name}.bvh" for name in ("named", "bare", "unalike")}
    for name, clip in (("named", walk), ("bare", bare(walk)), ("unalike", bare(walk, unalike=True))):
        bvh.write(files[name], clip)
    legs = {}
    for name, path in files.items():
        code, out, _ = run(capsys, "inspect", path)
        assert code == 0
        legs[name] = [line for line in out.splitlines() if line.split()[:1] == ["legs"]]
    assert legs["named"] == ["  legs    UpperLeg_L > LowerLeg_L > Foot_L > Toes_L; "
                             "UpperLeg_R > LowerLeg_R > Foot_R > Toes_R"]
    # Named J00, J01...: the same legs, from the hierarchy (two like chains beside the spine).
    joint = {n: f"J{j:02d}" for j, n in enumerate(walk.skeleton.names)}
    assert legs["bare"] == ["  legs    " + "; ".join(" > ".join(joint[n] for n in (f"UpperLeg_{s}", f"LowerLeg_{s}",
                                                                                f"Foot_{s}", f"Toes_{s}"))
                                                    for s in "LR")]
    assert legs["unalike"][0].startswith("  legs    none found by name") and "no foot lock" in legs["unalike"][0]
