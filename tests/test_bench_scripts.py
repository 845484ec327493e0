"""The bench scripts' own logic: the rig rewrite of bench/foreign_skeleton.py keeps the motion, and
bench/transition_speed.py still drives the public API it times (one call each, no timing asserted)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from posturemap.core import quat
from posturemap.core.joints import key_joints, leg_chains
from posturemap.core.motion import up_axis
from posturemap.io import bvh

BENCH = Path(__file__).resolve().parents[1] / "bench"


def _module(name: str = "foreign_skeleton"):
    spec = importlib.util.spec_from_file_location(name, BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_rewritten_rig_moves_as_the_original(bandai_paths, tmp_path):
    mod = _module()
    name = "walk_normal_001"
    m = bvh.read(bandai_paths([name])[name])
    r = mod.rewritten(m)
    assert r.fps == 2 * m.fps and len(r) == 2 * len(m) - 1
    # Every recorded frame: the same global joint positions, in metres, turned into Z up.
    turn = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.pi / 2)
    want = quat.mul_vec(turn, m.global_positions()) / 100.0
    got = r.global_positions()[::2]
    assert np.abs(got - want).max() < 1e-6  # metres: a micrometre
    assert up_axis(r) == 2 and up_axis(m) == 1
    # The in-between frames lie between their neighbours (SLERP, not a copy of either).
    mid = r.global_positions()[1::2]
    assert np.all(np.abs(mid - 0.5 * (got[:-1] + got[1:])).max(axis=(1, 2)) < 0.02)
    assert np.abs(mid - got[:-1]).max() > 0.005
    # Another naming, found by name all the same; rotation channels only below the hips; and
    # the file round-trips.
    assert all(n.startswith("mixamorig:") for n in r.skeleton.names)
    assert len(leg_chains(r.skeleton)) == 2 and len(key_joints(r.skeleton)[0]) == 4
    hips = r.skeleton.index("mixamorig:Hips")
    assert all(len(c) == 3 for c in r.skeleton.channels[hips + 1:])
    bvh.write(tmp_path / "r.bvh", r)
    back = bvh.read(tmp_path / "r.bvh")
    assert np.abs(back.global_positions() - r.global_positions()).max() < 1e-4


def test_the_transition_speed_script_drives_the_engine_and_the_functional_api(bandai_paths, monkeypatch):
    from posturemap.learn.model import PostureMap
    from posturemap.synth.engine import TransitionEngine

    monkeypatch.syspath_prepend(str(BENCH))
    mod = _module("transition_speed")
    names = ["walk_normal_001", "run_normal_001"]
    paths = bandai_paths(names)
    clips = [bvh.read(paths[n]) for n in names]
    model = PostureMap(seed=0).fit(clips, names)
    engine = TransitionEngine(model)
    for n, m in zip(names, clips):
        engine.add(n, m)
    lengths = [len(m) for m in clips]
    methods = ("slerp", "auto")
    rng = np.random.default_rng(0)
    out = mod.bench_engine(engine, names, lengths, methods, 2, 1, rng, None)
    assert set(out) == set(methods) and all(out[m]["median_us"] > 0 for m in methods)
    out = mod.bench_functional(model, clips, lengths, methods, 2, rng, None)
    assert set(out) == set(methods) and all(out[m]["median_us"] > 0 for m in methods)


def test_the_other_dataset_sample_takes_the_same_number_from_every_cell(tmp_path):
    mod = _module("other_dataset")
    for content, style, count in (("walk", "active", 5), ("walk", "elderly", 1), ("wave-left-hand", "active", 4)):
        for i in range(1, count + 1):
            (tmp_path / f"dataset-2_{content}_{style}_{i:03d}.bvh").write_text("")
    (tmp_path / "dataset-1_walk_normal_001.bvh").write_text("")  # another dataset's name: ignored
    (tmp_path / "dataset-2_walk_active_001.json").write_text("")  # not a BVH file: ignored
    picked = mod.sample_files(tmp_path, 2, seed=0)
    cells = [(c, s) for _, c, s in picked]
    assert cells.count(("walk", "active")) == 2 and cells.count(("wave-left-hand", "active")) == 2
    assert cells.count(("walk", "elderly")) == 1  # a cell smaller than asked gives what it has
    assert all(p.name.startswith("dataset-2_") and p.suffix == ".bvh" for p, _, _ in picked)
    assert all(p.stem.split("_")[1] == c and p.stem.split("_")[2] == s for p, c, s in picked)
    # Seeded: the same seed draws the same files; over seeds the draws differ.
    assert mod.sample_files(tmp_path, 2, seed=0) == picked
    draws = {tuple(p.name for p, _, _ in mod.sample_files(tmp_path, 2, seed=s)) for s in range(8)}
    assert len(draws) > 1


def test_the_lafan1_segments_are_split_by_performer_without_their_mirror_images(tmp_path):
    mod = _module("lafan1_segments")
    for name in ("walk1_subject1_walk_filtered", "walk1_subject1_walk_mirror_filtered",
                 "obstacles1_subject2_walk10_filtered", "jumps1_subject5_big_filtered",
                 "fallAndGetUp1_subject5_walk2_mirror_filtered", "pushAndStumble1_subject5_stumble_filtered",
                 "dataset-2_walk_active_001"):
        (tmp_path / f"{name}.bvh").write_text("")
    (tmp_path / "walk1_subject1_walk_filtered.json").write_text("")  # not a BVH file
    found = [(p.stem, s, k) for p, s, k in mod.segment_files(tmp_path)]
    assert found == [("jumps1_subject5_big_filtered", "subject5", "jumps: big"),
                     ("obstacles1_subject2_walk10_filtered", "subject2", "obstacles: walk"),
                     ("pushAndStumble1_subject5_stumble_filtered", "subject5", "pushAndStumble: stumble"),
                     ("walk1_subject1_walk_filtered", "subject1", "walk: walk")]


def test_the_transition_feet_script_measures_skate_against_the_real_clips(bandai_paths, monkeypatch):
    from posturemap.core.joints import leg_chains, leg_toes
    from posturemap.learn.model import PostureMap
    from posturemap.synth.engine import TransitionEngine

    monkeypatch.syspath_prepend(str(BENCH))
    mod = _module("transition_feet")
    names = ["walk_normal_001", "run_normal_001", "bow_normal_001"]
    paths = bandai_paths(names)
    clips = [bvh.read(paths[n]) for n in names]
    engine = TransitionEngine(PostureMap(seed=0).fit(clips, names))
    for n, m in zip(names, clips):
        engine.add(n, m)
    # A body standing still has no skate; a walk has some.
    sk = clips[0].skeleton
    chains = leg_chains(sk)
    feet = np.array([c[2] for c in chains] + leg_toes(sk, chains).tolist())
    walk = clips[0]
    still = mod.skate_of(walk.rotations[[40] * 10], walk.positions[[40] * 10], sk, feet, walk.fps, 1, 20.0, 1.0)
    moving = mod.skate_of(walk.rotations[40:50], walk.positions[40:50], sk, feet, walk.fps, 1, 20.0, 1.0)
    assert still == 0.0 and moving > 1.0
    out = mod.measure(engine, names, clips, (30,), 12, np.random.default_rng(0), 1.0)["30"]
    assert set(out) == {mod.label(m, f) for m, f in mod.METHODS} | {"real clips"}
    # SLERP glides the feet between two stances; the default plants them, as the real clips do.
    assert out["auto+feet"]["mean"] < 0.5 * out["slerp"]["mean"]
    assert out["real clips"]["mean"] < 0.5 * out["slerp"]["mean"]
    assert all(s["median"] <= s["p90"] <= s["p99"] <= s["max"] for s in out.values())


def test_the_numbered_rig_keeps_the_motion_and_reads_as_the_named_one(bandai_paths):
    mod = _module("numbered_names")
    name = "walk_normal_001"
    m = bvh.read(bandai_paths([name])[name])
    n = mod.numbered(m)
    assert n.skeleton.names[:3] == ("J00", "J01", "J02") and len(set(n.skeleton.names)) == m.skeleton.num_joints
    assert np.array_equal(n.rotations, m.rotations) and np.array_equal(n.global_positions(), m.global_positions())
    named, numbered = mod.found(m.skeleton), mod.found(n.skeleton)
    assert numbered == named and numbered["legs"] and numbered["arms"] and numbered["head"] >= 0
    report = mod.markdown({"holdouts": {"style": {
        "lengths": {"5": {"windows": 3, "differ": 1, "rotation": 0.5, "position_cm": 2.0}},
        "rigs": {"named": named, "numbered": numbered}, "joints": m.skeleton.num_joints,
        "names": list(m.skeleton.names)}}, "machine": {"cpu": "x", "cpus": 1, "python": "3"}, "date": "d"}, "c")
    assert "legs UpperLeg_L > LowerLeg_L > Foot_L; UpperLeg_R > LowerLeg_R > Foot_R" in report
    assert "| 5 | 3 | 1 | 0.5 | 2 |" in report


def test_the_clip_pairs_script_counts_pops_and_feet_under_the_floor(bandai_paths, tmp_path, monkeypatch):
    from posturemap.core.motion import Motion

    monkeypatch.syspath_prepend(str(BENCH))
    mod = _module("clip_pairs")
    names = ["walk_normal_001", "run_normal_001", "bow_normal_001"]
    paths = bandai_paths(names)
    walk = bvh.read(paths["walk_normal_001"])
    # A body held still does not accelerate; one frame carried 10 cm off does, that much twice over.
    still = Motion(walk.skeleton, walk.rotations[[5] * 8], walk.positions[[5] * 8], walk.fps)
    assert mod.largest_acceleration(still) == 0.0
    jump = Motion(walk.skeleton, still.rotations.copy(), still.positions.copy(), walk.fps)
    jump.positions[4, 0, 0] += 10.0
    assert abs(mod.largest_acceleration(jump) - 20.0) < 1e-9
    for n, p in paths.items():  # the clips are read where they are: links in a folder of their own
        (tmp_path / f"{n}.bvh").symlink_to(p)
    result = mod.run(tmp_path, seconds=(0.5,), log=lambda *a: None)
    row = result["lengths"]["15"]["methods"]
    assert set(row) == {mod.label(m, f) for m, f in mod.METHODS}
    assert all(s["pairs"] == 6 and s["largest"] >= 0.0 and s["deepest_cm"] >= s["depth_mean_cm"] >= 0.0
               for s in row.values())
    # SLERP leaves A's velocity at once and meets B's at once: its joints jerk at both seams; the
    # default continues A's motion into B's.
    assert row["slerp"]["pops"] > row["auto+feet"]["pops"]
    assert "| auto+feet |" in mod.markdown(result, "python bench/clip_pairs.py")
