"""The benchmark (`posturemap bench`): protocol helpers, and one quick run on bandai1."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from posturemap import evaluate, report
from posturemap.evaluate import LENGTHS, METHODS, N_PAST, VARIANTS, Settings

TINY = Settings(quick=True, train_stride=10, max_windows=4, pairs=3, som_epochs=1, latency_calls=5,
                bench_scripts=False, sweep=False, plots=False)


# -- protocol helpers (no data needed) ---------------------------------------------------------
def test_split_holds_out_whole_styles():
    names = ["dataset-1_walk_angry_001.bvh", "dataset-1_walk_normal_001.bvh", "dataset-1_walk-back_old_001.bvh",
             "dataset-1_bow_not-confident_001.bvh", "dataset-1_run_proud_002.bvh", "other.bvh"]
    train, test = evaluate.split_files([Path(n) for n in names])
    assert [p.name for p in test] == ["dataset-1_run_proud_002.bvh", "dataset-1_walk-back_old_001.bvh",
                                      "dataset-1_walk_angry_001.bvh"]
    assert [p.name for p in train] == ["dataset-1_bow_not-confident_001.bvh", "dataset-1_walk_normal_001.bvh",
                                       "other.bvh"]
    assert evaluate.parse_name("dataset-1_walk-left_not-confident_003.bvh") == {
        "content": "walk-left", "style": "not-confident", "id": "003"}


def test_window_starts_follow_lafan1():
    assert evaluate.window_starts(65) == []          # needs start + 65 < frames
    assert evaluate.window_starts(66) == [0]
    assert evaluate.window_starts(146) == [0, 40, 80]
    assert evaluate.window_starts(145) == [0, 40]


def test_som_grid():
    assert evaluate.som_grid(12) == (3, 4)
    assert evaluate.som_grid(1089) == (33, 33)
    r, c = evaluate.som_grid(1061)  # prime: nearest square-ish grid, not 1 x 1061
    assert r == 33 and 1061 <= r * c < 1061 + r
    assert len(evaluate.grid_edges(3, 4)) == 3 * 3 + 2 * 4


def test_foot_joints_and_centred(sample_clips):
    names = ("Hips", "UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L", "LeftToeBase", "Hand_R")
    assert evaluate.foot_joints(names).tolist() == [3, 4, 5]
    walk = sample_clips["walk"]
    c = evaluate.centred(walk, 0, 1)
    assert np.all(c.positions[:, 0, [0, 2]] == 0.0)
    np.testing.assert_array_equal(c.positions[:, 0, 1], walk.positions[:, 0, 1])
    np.testing.assert_array_equal(c.rotations, walk.rotations)
    assert not np.all(walk.positions[:, 0, [0, 2]] == 0.0)  # the input is left alone


# -- on bandai1 ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def quick(data_dir, bandai_files, tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    results = evaluate.run(data_dir, out, seed=0, settings=Settings.quick_run(), log=lambda m: None)
    return results, out


def _finite_numbers(d):
    if isinstance(d, dict):
        for v in d.values():
            yield from _finite_numbers(v)
    elif isinstance(d, (int, float)) and not isinstance(d, bool):
        yield d


def test_quick_run_writes_every_file(quick):
    results, out = quick
    for name in ("results.md", "results.json", "results_l2q.png", "results_l2p.png", "results_joint_angle.png"):
        assert (out / name).stat().st_size > 0, name
    for png in results["plots"]:
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((out / "results.json").read_text()) == json.loads(json.dumps(results))
    md = (out / "results.md").read_text()
    assert report.markdown(json.loads((out / "results.json").read_text())) == md  # rebuilt from the JSON alone
    for m in METHODS:
        assert f"| {m} |" in md
    assert "| truth |" in md and "L=45" in md and "angry, old, proud" in md


def test_quick_run_has_every_method_length_and_finite_metrics(quick):
    results, _ = quick
    inb = results["inbetween"]
    assert inb["windows"] == Settings.quick_run().max_windows
    keys = {"l2q", "l2p", "npss", "mpjpe_cm", "foot_skate", "validity", "jerk"}
    for group in (inb["methods"], results["diagnostics"]["variants"]):
        for m, per_length in group.items():
            assert set(per_length) == {str(n) for n in LENGTHS}, m
            for n, scores in per_length.items():
                assert keys <= set(scores), (m, n)
                assert all(math.isfinite(v) for v in _finite_numbers(scores)), (m, n, scores)
    assert set(inb["methods"]) == set(METHODS)
    assert set(results["diagnostics"]["variants"]) == set(VARIANTS)
    cross = results["cross_clip"]
    assert cross["pairs"] == Settings.quick_run().pairs
    assert set(cross["methods"]) == set(METHODS)
    assert all(p["a"] != p["b"] for p in cross["pair_list"])
    assert all(math.isfinite(v) for v in _finite_numbers(cross["methods"]))
    assert set(results["speed"]["latency"]) == set(METHODS) - {"zero-velocity"}
    assert all(v["median_us"] > 0 for v in results["speed"]["latency"].values())


def test_quick_run_split_and_sanity(quick):
    results, _ = quick
    split = results["split"]
    test_styles = {evaluate.parse_name(n)["style"] for n in split["test_files"]}
    assert test_styles == set(evaluate.TEST_STYLES)
    assert not set(split["train_files"]) & set(split["test_files"])
    assert all(evaluate.parse_name(n)["style"] not in evaluate.TEST_STYLES for n in split["train_files"])
    inb, var = results["inbetween"]["methods"], results["diagnostics"]["variants"]
    for n in map(str, LENGTHS):
        # The true posture as key must beat holding the last frame; errors are positive.
        assert var["oracle-key"][n]["l2q"] < inb["zero-velocity"][n]["l2q"]
        assert all(inb[m][n]["l2q"] > 0 and inb[m][n]["mpjpe_cm"] > 0 for m in METHODS)


@pytest.fixture(scope="module")
def tiny_state(data_dir, bandai_files):
    state = evaluate.prepare(data_dir, TINY, 0, log=lambda m: None)
    state["engines"] = evaluate.make_engines(state)
    return state


def test_truth_as_prediction_scores_zero_error(tiny_state):
    state = tiny_state
    ctx = state["ctx"]
    windows = evaluate.make_windows(state, TINY, 0)
    length = 15
    span = N_PAST + length + 10
    tr = np.stack([state["test"][c].rotations[s: s + span] for c, s in windows])
    tp = np.stack([state["test"][c].positions[s: s + span] for c, s in windows])
    sl = slice(N_PAST, N_PAST + length)
    got = evaluate.score_inbetween(ctx, tr, tp, tr[:, sl], tp[:, sl], length)
    for k in ("l2q", "l2p", "npss", "mpjpe_cm", "root_error_cm", "pose_error_cm"):
        assert got[k] == pytest.approx(0.0, abs=1e-9), k
    ref = evaluate.score_truth(ctx, tr, tp, length)
    for k in ("foot_skate", "validity", "jerk"):
        assert got[k] == pytest.approx(ref[k], rel=1e-12), k
    # A perturbed prediction is not free.
    bad = evaluate.score_inbetween(ctx, tr, tp, tr[:, sl][:, ::-1], tp[:, sl], length)
    assert bad["l2q"] > 0.01 and bad["l2p"] > 0.01


def test_same_seed_same_numbers(data_dir, bandai_files, tmp_path):
    a = evaluate.run(data_dir, tmp_path / "a", seed=3, settings=TINY, log=lambda m: None)
    b = evaluate.run(data_dir, tmp_path / "b", seed=3, settings=TINY, log=lambda m: None)
    for key in evaluate.QUALITY_KEYS:
        assert a[key] == b[key], key
    assert a["map"]["neurons"] == b["map"]["neurons"]
    c = evaluate.run(data_dir, tmp_path / "c", seed=4, settings=dataclasses.replace(TINY), log=lambda m: None)
    assert c["cross_clip"]["pair_list"] != a["cross_clip"]["pair_list"]
