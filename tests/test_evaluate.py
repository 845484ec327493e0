"""The benchmark (`posturemap bench`): protocol helpers, and one quick run of every hold-out."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from posturemap import evaluate
from posturemap.core import joints
from posturemap.core.motion import resample
from posturemap.core.skeleton import fk
from posturemap.learn.features import root_global
from posturemap.synth.engine import TransitionEngine
from posturemap.synth.trajectory import rotate_about_up
from posturemap.evaluate import report
from posturemap.evaluate.scoring import skate_scores
from posturemap.evaluate import LENGTHS, METHODS, N_FUTURE, N_PAST, VARIANTS, Settings

TINY = Settings(quick=True, holdouts=("cmu",), max_windows=3, pairs=0, som_epochs=0.1, latency_calls=5,
                bench_scripts=False, diagnostics=False, sweep=False, plots=False)
TINY_STYLE = dataclasses.replace(TINY, holdouts=("style",), train_stride=10)


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


def test_split_holds_out_whole_contents():
    names = ["dataset-1_walk_angry_001.bvh", "dataset-1_walk-back_normal_001.bvh", "dataset-1_dash_old_002.bvh",
             "dataset-1_byebye_proud_001.bvh", "dataset-1_bye_proud_001.bvh", "other.bvh"]
    train, test = evaluate.split_files([Path(n) for n in names], (), evaluate.TEST_CONTENTS)
    assert [p.name for p in test] == ["dataset-1_byebye_proud_001.bvh", "dataset-1_dash_old_002.bvh",
                                      "dataset-1_walk-back_normal_001.bvh"]
    assert [p.name for p in train] == ["dataset-1_bye_proud_001.bvh", "dataset-1_walk_angry_001.bvh", "other.bvh"]


def test_window_starts_follow_lafan1():
    assert evaluate.window_starts(65, 65) == []          # needs start + 65 < frames
    assert evaluate.window_starts(66, 65) == [0]
    assert evaluate.window_starts(146, 65) == [0, 40, 80]
    assert evaluate.window_starts(145, 65) == [0, 40]
    assert evaluate.window_starts(300, 200, 40) == [0, 40, 80]


def test_som_grid():
    assert evaluate.som_grid(12) == (3, 4)
    assert evaluate.som_grid(1089) == (33, 33)
    r, c = evaluate.som_grid(1061)  # prime: nearest square-ish grid, not 1 x 1061
    assert r == 33 and 1061 <= r * c < 1061 + r
    assert len(evaluate.grid_edges(3, 4)) == 3 * 3 + 2 * 4


def test_foot_joints_and_centred(sample_clips):
    names = ("Hips", "UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L", "LeftToeBase", "Hand_R")
    assert joints.foot_joints(names).tolist() == [3, 4, 5]
    walk = sample_clips["walk"]
    c = evaluate.centred(walk, 0, 1)
    assert np.all(c.positions[:, 0, [0, 2]] == 0.0)
    np.testing.assert_array_equal(c.positions[:, 0, 1], walk.positions[:, 0, 1])
    np.testing.assert_array_equal(c.rotations, walk.rotations)
    assert not np.all(walk.positions[:, 0, [0, 2]] == 0.0)  # the input is left alone


def test_key_model_stands_in_for_the_maps_only(sample_clips):
    from posturemap.learn.model import PostureMap

    model = PostureMap(seed=0).fit([sample_clips["walk"]])
    km = evaluate.fixed_key_model(model)
    assert [m.n_neurons for m in km.maps_] == [1] * len(model.maps_)
    assert km.space_ is model.space_ and (km.radius, km.seed) == (model.radius, model.seed)  # the rest: the map's
    with pytest.raises(AttributeError):
        _ = km.no_such_attribute


def test_methods_cover_the_engine_and_todays_default():
    from posturemap.synth.request import METHODS as ENGINE

    assert set(ENGINE) <= set(METHODS)
    assert {"zero-velocity", "som", "upm-valid" + evaluate.FEET, evaluate.DEFAULT_SPEC} <= set(METHODS)
    assert len(set(METHODS)) == len(METHODS)
    assert evaluate.method_spec("upm-valid+feet") == ("upm-valid", True)
    assert evaluate.method_spec("slerp") == ("slerp", False)


def test_per_content_means_the_windows_of_each_content():
    res = {"methods": {"m": {"5": {"per_window": {"l2q": [1.0, 2.0, 4.0], "skate": [0.0, 3.0, 6.0],
                                                  "npss": [9.0, 9.0, 9.0]}}}},
           "truth": {"5": {"per_window": {"skate": [1.0, 1.0, 4.0]}}}}
    out = evaluate.per_content(res, ["walk", "dash", "walk"])
    assert out["walk"]["windows"] == 2 and out["dash"]["windows"] == 1
    assert out["walk"]["methods"]["m"]["5"] == {"l2q": 2.5, "skate": 3.0}  # npss is not per content
    assert out["dash"]["truth"]["5"] == {"skate": 1.0}


def test_round_per_window_rounds_only_the_window_lists():
    x = {"a": {"per_window": {"l2q": [0.123456789, 12345.678, None]}, "l2q": 0.123456789},
         "b": [{"per_window": {"skate": [1 / 3]}}]}
    assert evaluate.round_per_window(x) == {"a": {"per_window": {"l2q": [0.12346, 12346.0, None]}, "l2q": 0.123456789},
                                            "b": [{"per_window": {"skate": [0.33333]}}]}


def test_dumps_keeps_number_lists_on_one_line_and_the_content():
    x = {"a": [1, -2.5, 1e-05, None], "b": ["x", "y"], "c": {"d": [[1, 2], [3, 4]]}}
    text = report.dumps(x)
    assert json.loads(text) == x
    assert '"a": [1, -2.5, 1e-05, null]' in text and '[1, 2]' in text and '"x",\n' in text


def _inb(ratios_q, ratios_p, skate, truth_skate, lengths=LENGTHS):
    """A synthetic in-betweening result: slerp at 1.0, spline and inertialize at 0.9, method m."""
    def row(q, p, s):
        return {str(n): {"l2q": q[i], "l2p": p[i], "skate": s[i]} for i, n in enumerate(lengths)}
    k = len(lengths)
    return {"lengths": list(lengths), "windows": 1,
            "truth": {str(n): {"skate": t} for n, t in zip(lengths, truth_skate)},
            "methods": {"slerp": row([1.0] * k, [1.0] * k, [9.0] * k), "spline": row([0.9] * k, [0.9] * k, [9.0] * k),
                        "inertialize": row([0.9] * k, [0.9] * k, [9.0] * k), "m": row(ratios_q, ratios_p, skate)}}


def test_acceptance_criteria_hand_cases():
    good = report.acceptance(_inb([0.5] * 4, [0.6] * 4, [1.0, 1.2, 1.4, 1.5], [1.0] * 4))["m"]
    assert good["skate"] == (True, pytest.approx(1.5))
    assert good["l2q"] == (True, 0.5) and good["l2p"] == (True, 0.6)
    assert good["goal"] == (True, 0.6)
    assert good["beats_baselines"] == (True, pytest.approx(0.6 / 0.9))
    # 1% worse than slerp at 5 frames, skate 1.6x the truth's at 45 (5 frames do not count for skate),
    # L2P 0.75x slerp at 45: not the goal; worse than spline at 30.
    bad = report.acceptance(_inb([1.01, 0.5, 0.95, 0.5], [0.5, 0.5, 0.5, 0.75], [9.0, 1.0, 1.0, 1.6], [1.0] * 4))["m"]
    assert bad["skate"] == (False, pytest.approx(1.6))
    assert bad["l2q"] == (False, pytest.approx(1.01)) and bad["l2p"][0]
    assert bad["goal"] == (False, pytest.approx(0.95))
    assert bad["beats_baselines"] == (False, pytest.approx(0.95 / 0.9))


def test_the_engine_sees_the_context_frames_only(sample_clips):
    from posturemap.learn.model import PostureMap
    from posturemap.synth.engine import TransitionEngine

    walk = sample_clips["walk"]
    seen = []

    class Spy(TransitionEngine):
        def generate(self, a, b, *args, **kw):
            seen.append((sorted(self.tracks), len(self.tracks[a].gpos), len(self.tracks[b].gpos), kw["a_end"],
                         kw["b_start"], kw["align"]))
            return super().generate(a, b, *args, **kw)

    model = PostureMap(seed=0).fit([walk])
    engines = {"upm": Spy(model), "som": Spy(model)}
    past, future = walk[20: 20 + N_PAST], walk[45: 45 + N_FUTURE]
    out = evaluate.generate_from_context(engines, ["upm-valid+feet", "som"], past, future, 15)
    assert seen == [(["_future", "_past"], N_PAST, N_FUTURE, N_PAST - 1, 0, False)] * 2
    assert engines["upm"].tracks == {} and engines["som"].tracks == {}  # the context clips do not stay behind
    # The frames are what a fresh engine holding only the two context clips makes (both engines
    # here hold the same map; "som" runs upm on its engine's map, "upm-valid+feet" locks the feet).
    for name, method, feet in (("upm-valid+feet", "upm-valid", True), ("som", "upm", False)):
        ref = TransitionEngine(model)
        ref.add("a", past)
        ref.add("b", future)
        r, p = ref.generate("a", "b", length=15, a_end=N_PAST - 1, b_start=0, align=False, method=method,
                            foot_lock=feet)
        np.testing.assert_array_equal(out[name][0], r)
        np.testing.assert_array_equal(out[name][1], p)


def test_every_window_is_rebuilt_from_its_own_context(sample_clips):
    from posturemap.learn.model import PostureMap

    walk = sample_clips["walk"]
    model = PostureMap(seed=0).fit([walk])
    engines = {"upm": TransitionEngine(model)}
    windows = [(0, 5), (0, 40)]
    length = 12
    truth_r, truth_p, preds = evaluate.predict_windows(engines, ["zero-velocity", "spline", "upm-valid"], [walk],
                                                       windows, length)
    span = N_PAST + length + N_FUTURE
    assert set(preds) == {"zero-velocity", "spline", "upm-valid"}
    for i, (_, s) in enumerate(windows):
        np.testing.assert_array_equal(truth_r[i], walk.rotations[s: s + span])
        np.testing.assert_array_equal(truth_p[i], walk.positions[s: s + span])
        # zero-velocity holds the last context frame; the others are what the window's context makes.
        assert np.all(preds["zero-velocity"][0][i] == walk.rotations[s + N_PAST - 1])
        made = evaluate.generate_from_context(engines, ["spline", "upm-valid"], walk[s: s + N_PAST],
                                              walk[s + N_PAST + length: s + span], length)
        for m in ("spline", "upm-valid"):
            np.testing.assert_array_equal(preds[m][0][i], made[m][0])
            np.testing.assert_array_equal(preds[m][1][i], made[m][1])
    assert not np.allclose(preds["spline"][0][0], preds["spline"][0][1])  # each window its own


def test_a_gap_in_a_take_is_rebuilt_from_the_clip_but_the_gap(sample_clips):
    from posturemap.learn.model import PostureMap
    from posturemap.core.motion import Motion

    walk = sample_clips["walk"]
    model = PostureMap(seed=0).fit([sample_clips["run"]])  # a library without the walk
    windows, length = [(0, 5), (0, 40)], 12
    preds, own = evaluate.predict_whole_clip(model, [walk], windows, length)
    assert set(preds) == set(own) == set(evaluate.WHOLE_CLIP)
    default, library_only = evaluate.WHOLE_CLIP
    assert own[library_only] == 0.0 and 0.0 < own[default] <= 1.0  # the walk's own steps replayed
    # The frames of a window's gap are never read: garbled, they change nothing in it (the
    # quaternions' signs, chosen continuous through a clip, within rounding).
    rng = np.random.default_rng(0)
    for i, (_, s) in enumerate(windows):
        rots = walk.rotations.copy()
        q = rng.normal(size=rots[s + N_PAST: s + N_PAST + length].shape)
        rots[s + N_PAST: s + N_PAST + length] = q / np.linalg.norm(q, axis=-1, keepdims=True)
        garbled = Motion(walk.skeleton, rots, walk.positions, walk.fps)
        again, _ = evaluate.predict_whole_clip(model, [garbled], [windows[i]], length)
        for label in preds:
            assert np.all(np.abs(np.sum(preds[label][0][i] * again[label][0][0], axis=-1)) > 1 - 1e-12), label
            np.testing.assert_allclose(preds[label][1][i], again[label][1][0], rtol=0, atol=1e-9)
    # Each window is what an engine holding the clip before and after its gap makes.
    for i, (_, s) in enumerate(windows):
        for label, seconds in evaluate.WHOLE_CLIP.items():
            eng = TransitionEngine(model)
            if seconds is not None:
                eng.own_seconds = seconds
            eng.add("a", walk[: s + N_PAST])
            eng.add("b", walk[s + N_PAST + length:])
            r, p = eng.generate("a", "b", length=length, a_end=s + N_PAST - 1, b_start=0, align=False)
            np.testing.assert_array_equal(preds[label][0][i], r)
            np.testing.assert_array_equal(preds[label][1][i], p)


def test_whole_clip_ratios_divide_by_slerp_and_the_truth_and_average_the_splits():
    def per(l2q, skate):
        return {str(n): {"l2q": l2q * n, "l2p": 2 * l2q * n, "skate": skate} for n in report.SKATE_LENGTHS}

    def split(a, truth_skate):
        return {"methods": {"slerp": per(1.0, 8.0)}, "truth": {str(n): {"skate": truth_skate} for n in report.SKATE_LENGTHS},
                "default_method": "auto+feet", "whole_clip": {"methods": {"auto+feet": per(a, 2.0)}}}

    results = {"holdouts": {"style": {"inbetween": split(0.5, 4.0)}, "cmu": {"inbetween": split(9.0, 1.0)}},
               "more_splits": {"styles-2": split(0.3, 1.0)}}
    ratios = report.whole_clip_ratios(results)
    assert set(ratios) == {"style", "styles-2", "mean"}  # Bandai splits only: not CMU
    assert ratios["style"]["30"] == pytest.approx({"l2q": 0.5, "l2p": 0.5, "skate": 0.5})
    assert ratios["mean"]["45"] == pytest.approx({"l2q": 0.4, "l2p": 0.4, "skate": 1.25})
    del results["more_splits"]["styles-2"]["whole_clip"]  # results of code without it
    assert report.whole_clip_ratios(results) is None


# -- on real data -------------------------------------------------------------------------------
# The checks below run on a smaller run than `posturemap bench --quick` (a third of its training
# clips, 3 windows, 2 pairs, no plots: a few seconds); the slow set runs them on the real quick
# run too, plots included.
SMALL = dataclasses.replace(Settings.quick_run(), train_stride=12, max_windows=3, pairs=2, latency_calls=10,
                            plots=False)


@pytest.fixture(scope="module", params=[pytest.param(SMALL, id="small"),
                                        pytest.param(Settings.quick_run(), id="quick", marks=pytest.mark.slow)])
def quick(request, data_dir, bandai_files, cmu_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    results = evaluate.run(data_dir, out, seed=0, settings=request.param, log=lambda m: None)
    return results, out, request.param


def _finite_numbers(d):
    if isinstance(d, dict):
        for v in d.values():
            yield from _finite_numbers(v)
    elif isinstance(d, list):
        for v in d:
            yield from _finite_numbers(v)
    elif isinstance(d, (int, float)) and not isinstance(d, bool):
        yield d


def test_quick_run_writes_every_file(quick):
    results, out, settings = quick
    names = ["results.md", "results.json"] + [f"results_{h}.png" for h in evaluate.HOLDOUTS] + \
        ["results_style_joint_angle.png", "results_style_filmstrip.png"]
    if not settings.plots:
        names = names[:2]
        assert not results.get("plots") and not list(out.glob("*.png"))
    for name in names:
        assert (out / name).stat().st_size > 0, name
    assert set(names[2:]) <= set(results.get("plots") or [])
    for png in results.get("plots") or []:
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((out / "results.json").read_text()) == json.loads(json.dumps(results))
    md = (out / "results.md").read_text()
    assert report.markdown(json.loads((out / "results.json").read_text())) == md  # rebuilt from the JSON alone
    for m in METHODS:
        assert md.count(f"| {m} |") >= 3 * len(report.METRIC_TITLES), m  # every table of every hold-out
    for name in evaluate.HOLDOUTS:
        title = report.HOLDOUT_TITLES[name]
        assert f"## {title}" in md and f"**{title}**" in md  # a section and an acceptance table
    assert "| truth |" in md and "L=180" in md and "angry, old, proud" in md and "dash, walk-back, byebye" in md
    assert "## More splits of bandai1" in md and "**Every Bandai split**" in md
    for name in evaluate.MORE_SPLITS:
        assert f"### {name}: " in md and f"| {name} | {evaluate.DEFAULT_SPEC} |" in md


def test_quick_run_has_every_hold_out_method_length_and_finite_metrics(quick):
    results, _, settings = quick
    holds = results["holdouts"]
    assert list(holds) == list(evaluate.HOLDOUTS)
    keys = {"l2q", "l2p", "npss", "mpjpe_cm", "skate", "contact_skate", "penetration_cm", "float_cm", "naturalness",
            "validity", "jerk"}
    for name, hold in holds.items():
        inb = hold["inbetween"]
        lengths = evaluate.CMU_LENGTHS if name == "cmu" else LENGTHS
        assert inb["lengths"] == list(lengths) and inb["windows"] == settings.max_windows
        assert set(inb["methods"]) == set(METHODS)
        for m, per_length in inb["methods"].items():
            assert set(per_length) == {str(n) for n in lengths}, (name, m)
            for n, scores in per_length.items():
                assert keys <= set(scores), (name, m, n)
                assert all(math.isfinite(v) for v in _finite_numbers(scores)), (name, m, n)
                assert len(scores["per_window"]["naturalness"]) == inb["windows"]
        for n in map(str, lengths):
            t = inb["truth"][n]
            assert {"skate", "penetration_cm", "float_cm", "naturalness", "validity", "jerk"} <= set(t)
            assert t["naturalness"] > 0  # the truth is never compared with its own frames
            assert all(inb["methods"][m][n]["l2q"] > 0 and inb["methods"][m][n]["mpjpe_cm"] > 0
                       for m in METHODS)
        # per content: the windows of every content add up; the means match the overall figure
        pc = inb["per_content"]
        assert sum(c["windows"] for c in pc.values()) == inb["windows"]
        m, n = "slerp", "30"
        overall = sum(c["windows"] * c["methods"][m][n]["l2q"] for c in pc.values()) / inb["windows"]
        assert overall == pytest.approx(inb["methods"][m][n]["l2q"], rel=1e-9)
    assert set(holds["content"]["inbetween"]["per_content"]) <= set(evaluate.TEST_CONTENTS)
    cross = holds["style"]["cross_clip"]
    assert cross["pairs"] == settings.pairs and set(cross["methods"]) == set(METHODS)
    assert all(p["a"] != p["b"] for p in cross["pair_list"])
    assert all(math.isfinite(v) for v in _finite_numbers(cross["methods"]))
    assert all(v["float_cm"] >= 0 and 0 <= v["floats_over_10cm"] <= cross["pairs"] for v in cross["methods"].values())
    assert all(v["step_ratio"] > 0 and 0 <= v["steps_over_1_5"] <= cross["pairs"] for v in cross["methods"].values())
    assert all(v["accel_ratio"] > 0 and 0 <= v["accels_over_1_5"] <= cross["pairs"] for v in cross["methods"].values())
    # Holding A's last pose and then jumping to B's first moves joints across in one frame:
    # the largest step and acceleration of every transition are far over the real frames' own.
    zero = cross["methods"]["zero-velocity"]
    assert zero["step_ratio"] > 1.5 and zero["accel_ratio"] > 1.5 and zero["accels_over_1_5"] == cross["pairs"]
    for name, hold in holds.items():  # a gap in a take: the default with the whole clip as context
        inb = hold["inbetween"]
        wc, lengths = inb["whole_clip"], [str(n) for n in inb["lengths"]]
        assert set(wc["methods"]) == set(evaluate.WHOLE_CLIP)
        for label, per_length in wc["methods"].items():
            assert set(per_length) == set(lengths)
            assert all(math.isfinite(v) for v in _finite_numbers(per_length)), (name, label)
            assert all(0.0 <= wc["own_share"][label][n] <= 1.0 for n in lengths)
        assert sum(c["windows"] for c in wc["per_content"].values()) == inb["windows"]
    assert holds["cmu"]["cross_clip"] is None  # one test clip
    assert set(results["speed"]["latency"]) == set(METHODS) - {"zero-velocity"}
    assert all(v["median_us"] > 0 for v in results["speed"]["latency"].values())


def test_quick_run_splits(quick):
    results, _, _ = quick
    holds = results["holdouts"]
    style, content, cmu = (holds[h]["split"] for h in evaluate.HOLDOUTS)
    assert {evaluate.parse_name(n)["style"] for n in style["test_files"]} == set(evaluate.TEST_STYLES)
    assert all(evaluate.parse_name(n)["style"] not in evaluate.TEST_STYLES for n in style["train_files"])
    assert {evaluate.parse_name(n)["content"] for n in content["test_files"]} == set(evaluate.TEST_CONTENTS)
    assert all(evaluate.parse_name(n)["content"] not in evaluate.TEST_CONTENTS for n in content["train_files"])
    for s in (style, content):
        assert not set(s["train_files"]) & set(s["test_files"])
        assert s["fps"] == pytest.approx(30.0, rel=1e-4) and s["cm_per_unit"] == 1.0
    assert cmu["fps"] == pytest.approx(120.0, rel=1e-4)
    assert cmu["train_frames"] + cmu["test_frames"] == 2752 and abs(cmu["train_frames"] - cmu["test_frames"]) <= 1
    assert cmu["cm_per_unit"] == pytest.approx(2.54 / 0.45)
    # Feet by name on both skeletons; the skate height follows the leg length (2.5 cm on an 80 cm leg).
    assert holds["style"]["feet"]["joints"] == ["Foot_L", "Toes_L", "Foot_R", "Toes_R"]
    assert holds["cmu"]["feet"]["joints"] == ["LeftFoot", "LeftToeBase", "RightFoot", "RightToeBase"]
    for h in holds.values():
        assert h["feet"]["skate_height_cm"] == pytest.approx(2.5 * h["feet"]["leg_length_cm"] / 80.0)


def test_quick_run_more_splits(quick):
    results, _, settings = quick
    splits = results["more_splits"]
    assert list(splits) == list(evaluate.MORE_SPLITS)
    for name, sp in splits.items():
        styles, contents = evaluate.MORE_SPLITS[name]
        test = [evaluate.parse_name(n) for n in sp["test_files"]]
        train = [evaluate.parse_name(n) for n in sp["train_files"]]
        held = {t["style"] for t in test} if styles else {t["content"] for t in test}
        assert held == set(styles or contents), name  # whole styles or whole motion types held out
        assert all(t["style"] not in styles and t["content"] not in contents for t in train), name
        assert not set(sp["train_files"]) & set(sp["test_files"])
        assert sp["windows"] == settings.max_windows and sp["lengths"] == list(evaluate.SPLIT_LENGTHS)
        assert list(sp["methods"]) == list(evaluate.SPLIT_METHODS)
        for m, per_length in sp["methods"].items():
            assert set(per_length) == {str(n) for n in evaluate.SPLIT_LENGTHS}
            for scores in per_length.values():
                assert {"l2q", "l2p", "skate"} <= set(scores)
                assert all(math.isfinite(v) and v > 0 for v in scores.values()), (name, m)
        assert all(t["skate"] > 0 for t in sp["truth"].values())
        for label, per_length in sp["whole_clip"]["methods"].items():
            assert set(per_length) == {str(n) for n in evaluate.SPLIT_LENGTHS}
            assert all(math.isfinite(v) and v > 0 for scores in per_length.values() for v in scores.values())
        # slerp glides the feet where the default steps: never less skate than the truth's here
        assert all(sp["methods"]["slerp"][n]["skate"] > sp["truth"][n]["skate"] for n in ("30", "45"))


def test_split_ratios_divide_by_slerp_and_the_truth_and_average_the_splits():
    def per(l2q, l2p, skate):
        return {str(n): {"l2q": l2q * n, "l2p": l2p * n, "skate": skate} for n in report.SKATE_LENGTHS}

    def split(a, truth_skate):
        return {"methods": {"slerp": per(1.0, 2.0, 8.0), "auto+feet": per(a, 1.0, 2.0)},
                "truth": {str(n): {"skate": truth_skate} for n in report.SKATE_LENGTHS}}

    results = {"holdouts": {"style": {"inbetween": split(0.5, 4.0)}, "cmu": {"inbetween": split(9.0, 1.0)}},
               "more_splits": {"styles-2": split(0.7, 1.0)}}
    ratios = report.split_ratios(results)
    assert set(ratios) == {"style", "styles-2", "mean"}  # Bandai splits only: not CMU
    assert ratios["style"]["auto+feet"]["30"] == pytest.approx({"l2q": 0.5, "l2p": 0.5, "skate": 0.5})
    assert ratios["styles-2"]["auto+feet"]["45"] == pytest.approx({"l2q": 0.7, "l2p": 0.5, "skate": 2.0})
    assert ratios["mean"]["auto+feet"]["15"] == pytest.approx({"l2q": 0.6, "l2p": 0.5, "skate": 1.25})
    assert ratios["mean"]["slerp"]["30"]["l2q"] == 1.0


@pytest.fixture(scope="module")
def tiny_state(data_dir, bandai_files):
    split = evaluate.load_split("style", data_dir, TINY_STYLE)
    state = evaluate.prepare(split, TINY_STYLE, 0, log=lambda m: None)
    state["engines"] = evaluate.make_engines(state)  # the diagnostics read whole clips
    return state


def test_the_scores_take_the_test_clips_frame_rate(data_dir, tiny_state):
    # The same held-out motion at 60 fps, scored with the map of 30 fps clips: its skate is in
    # centimetres per second of its own rate (it was halved when the scores took the map's).
    split = evaluate.load_split("style", data_dir, TINY_STYLE)
    fast = dataclasses.replace(split, test=[resample(m, 2 * m.fps) for m in split.test])
    state = evaluate.prepare(fast, TINY_STYLE, 0, log=lambda m: None, full=False)
    slow_ctx, ctx = tiny_state["ctx"], state["ctx"]
    assert ctx.fps == 2 * slow_ctx.fps == 2 * tiny_state["test"][0].fps
    length = 15
    skates = []
    for c, factor in ((slow_ctx, 1), (ctx, 2)):
        # The same stretch of motion: the gap's first frame at the same time at both rates.
        span = N_PAST + factor * (length + 1) - 1 + N_FUTURE
        starts = [(i, factor * 20 + (factor - 1) * N_PAST) for i in range(len(split.test))]
        clips = tiny_state["test"] if factor == 1 else state["test"]
        tr = np.stack([clips[i].rotations[s: s + span] for i, s in starts])
        tp = np.stack([clips[i].positions[s: s + span] for i, s in starts])
        _, g_p = evaluate.global_windows(tr, tp, c.skeleton.parents)
        skates.append(skate_scores(c, g_p, slice(N_PAST, N_PAST + factor * (length + 1) - 1))[0].mean())
    assert skates[1] == pytest.approx(skates[0], rel=0.1) and skates[0] > 0.5


def test_truth_as_prediction_scores_zero_error(tiny_state):
    state = tiny_state
    ctx = state["ctx"]
    windows = evaluate.make_windows(state, TINY_STYLE, 0)
    length = 15
    span = N_PAST + length + N_FUTURE
    tr = np.stack([state["test"][c].rotations[s: s + span] for c, s in windows])
    tp = np.stack([state["test"][c].positions[s: s + span] for c, s in windows])
    sl = slice(N_PAST, N_PAST + length)
    natural = evaluate.naturalness_fn(ctx, evaluate.natural_reference(ctx, state["test"]), windows, length)
    got = evaluate.score_inbetween(ctx, tr, tp, tr[:, sl], tp[:, sl], length,
                                   natural=natural(*(evaluate.rebuilt_frames(t, t[:, sl]) for t in (tr, tp))))
    for k in ("l2q", "l2p", "npss", "mpjpe_cm", "root_error_cm", "pose_error_cm"):
        assert got[k] == pytest.approx(0.0, abs=1e-9), k
    seam_on = slice(N_PAST - 1, sl.stop)  # the last past frame and the gap
    ref = evaluate.score_truth(ctx, tr, tp, length, natural=natural(tr[:, seam_on], tp[:, seam_on]))
    for k in ("skate", "contact_skate", "validity", "jerk", "naturalness"):
        assert got[k] == pytest.approx(ref[k], rel=1e-12), k
    # A perturbed prediction is not free.
    bad_r = tr[:, sl][:, ::-1]
    bad = evaluate.score_inbetween(ctx, tr, tp, bad_r, tp[:, sl], length,
                                   natural=natural(evaluate.rebuilt_frames(tr, bad_r),
                                                   evaluate.rebuilt_frames(tp, tp[:, sl])))
    assert bad["l2q"] > 0.01 and bad["l2p"] > 0.01 and bad["naturalness"] > got["naturalness"]
    # One call scores several methods' windows in a row, each as if alone.
    both = natural(np.concatenate([tr[:, seam_on], evaluate.rebuilt_frames(tr, bad_r)]),
                   np.concatenate([tp[:, seam_on], tp[:, seam_on]]))
    np.testing.assert_allclose(both, got["per_window"]["naturalness"] + bad["per_window"]["naturalness"])
    # Without a pose-validity index (a report that does not show validity), the same scores and
    # validity None.
    bare = dataclasses.replace(ctx, index=None)
    quick = evaluate.score_inbetween(bare, tr, tp, bad_r, tp[:, sl], length)
    assert quick["validity"] is None and quick["validity_p95"] is None
    for k in ("l2q", "l2p", "npss", "mpjpe_cm", "skate", "jerk"):
        assert quick[k] == bad[k], k
    assert evaluate.score_truth(bare, tr, tp, length)["validity"] is None
    assert evaluate.score_truth(bare, tr, tp, length)["skate"] == ref["skate"]


def test_naturalness_finds_a_copy_of_real_motion_and_ignores_the_windows_own_frames(tiny_state):
    state, length = tiny_state, 15
    ctx = state["ctx"]
    ref = evaluate.natural_reference(ctx, state["test"])
    stride = round(evaluate.NATURAL_STRIDE_S * ctx.fps)
    s1 = 1 + 4 * stride - N_PAST  # clip 1's gap starts at a reference window's first frame
    clip = state["test"][1]
    gap = slice(s1 + N_PAST - 1, s1 + N_PAST + length)  # the last past frame and the gap
    r, p = clip.rotations[None, gap], clip.positions[None, gap]
    own = evaluate.naturalness_fn(ctx, ref, [(1, s1)], length)(r, p)  # its own frames are left out
    other = evaluate.naturalness_fn(ctx, ref, [(0, 0)], length)(r, p)  # said to come from clip 0
    assert other[0] == pytest.approx(0.0, abs=1e-6)
    assert own[0] > 0.01


def test_diagnostics_oracle_key_beats_holding_the_last_frame(tiny_state):
    settings = dataclasses.replace(TINY_STYLE, diagnostics=True)
    windows = evaluate.make_windows(tiny_state, settings, 0)
    inb, diag, _ = evaluate.run_inbetween(tiny_state, windows, settings, 0, log=lambda m: None, diagnostics=True)
    assert set(diag["variants"]) == set(VARIANTS)
    for n in map(str, LENGTHS):
        assert set(diag["variants"]["oracle-key"]) == {str(k) for k in LENGTHS}
        # The true posture as key must beat holding the last frame.
        assert diag["variants"]["oracle-key"][n]["l2q"] < inb["methods"]["zero-velocity"][n]["l2q"]
        assert diag["key_distance"][n]["upm_key_to_true"] > 0


@pytest.mark.slow  # seconds of waiting or a second full run: `make test-slow`
def test_same_seed_same_numbers(data_dir, cmu_file, tmp_path):
    a = evaluate.run(data_dir, tmp_path / "a", seed=3, settings=TINY, log=lambda m: None)
    b = evaluate.run(data_dir, tmp_path / "b", seed=3, settings=TINY, log=lambda m: None)
    for key in evaluate.QUALITY_KEYS:
        assert a[key].keys() == b[key].keys(), key
    for name, hold in a["holdouts"].items():
        for key in ("split", "inbetween", "cross_clip"):
            assert hold[key] == b["holdouts"][name][key], (name, key)
        assert hold["map"]["neurons"] == b["holdouts"][name]["map"]["neurons"]
    assert len(a["holdouts"]["cmu"]["inbetween"]["window_list"]) == TINY.max_windows


def test_the_seed_picks_the_windows(tiny_state):
    a, b = (evaluate.make_windows(tiny_state, TINY_STYLE, seed) for seed in (3, 4))
    assert a != b and len(a) == len(b) == TINY_STYLE.max_windows
    assert a == evaluate.make_windows(tiny_state, TINY_STYLE, 3)


def test_cross_clip_sequences_put_b_where_each_method_placed_it(tiny_state, monkeypatch):
    # Retrieval places B itself (its own turn and shift in engine.last); the cross-clip scores
    # must join each method's new frames to B as that method placed it. Captured: the stacked
    # sequences scored per method; B's root after the new frames must equal the placement the
    # engine reported for that pair (a bug placed B by the interpolating alignment for every
    # method, a jump at B's seam for retrieval).
    from posturemap.evaluate import runner

    seen, placed = [], []
    real_generate = TransitionEngine.generate

    def spy_generate(self, a, b, request=None, **kw):
        out = real_generate(self, a, b, request, **kw)
        placed.append((kw.get("method"), kw.get("foot_lock"), float(self.last["dtheta"]), np.array(self.last["shift"])))
        return out

    def spy_windows(rots, pos, parents):
        seen.append((rots, pos))
        return real_windows(rots, pos, parents)

    real_windows = runner.global_windows
    monkeypatch.setattr(TransitionEngine, "generate", spy_generate)
    monkeypatch.setattr(runner, "global_windows", spy_windows)
    settings = dataclasses.replace(TINY_STYLE, pairs=3)
    out = runner.run_cross(tiny_state, settings, 0, log=lambda m: None)
    methods = list(out["methods"])
    root = tiny_state["ctx"].root
    k = methods.index("auto")
    rots, pos = seen[k]  # (pairs, N_PAST + length + N_FUTURE, J, ...)
    autos = [p[2:] for p in placed if p[:2] == ("auto", False)]  # the method "auto" (no foot lock)
    assert len(autos) == len(out["pair_list"]) == 3
    length, up = out["length"], tiny_state["ctx"].up
    for i, (pair, (turn, shift)) in enumerate(zip(out["pair_list"], autos)):
        b = next(m for m, f in zip(tiny_state["test"], tiny_state["test_files"]) if f == pair["b"])
        expect = rotate_about_up(root_global(b, root)[1][pair["b_start"]], turn, up) + shift
        got = fk(b.skeleton.parents, rots[i], pos[i])[1][N_PAST + length, root]
        np.testing.assert_allclose(got, expect, atol=1e-6)


# -- a user's own clips: `posturemap bench --train ... --test ...` -------------------------------
def _own_folders(tmp_path, bandai_paths):
    """A training folder of walks and a run; two test folders (named for what they hold) of a
    backward walk and a wave, none of them in training: symbolic links to the data, not copies."""
    groups = {"train": ["walk_normal_001", "walk_happy_001", "run_normal_001"],
              "backwards": ["walk-back_normal_001"], "waves": ["bye_normal_001"]}
    paths = bandai_paths([n for names in groups.values() for n in names])
    folders = {}
    for group, names in groups.items():
        folders[group] = tmp_path / group
        folders[group].mkdir()
        for n in names:
            (folders[group] / paths[n].name).symlink_to(paths[n])
    return folders


def test_own_clips_are_benched_as_the_hold_outs_are(tmp_path, bandai_paths, capsys):
    from clikit import run

    from posturemap.evaluate import runner
    from posturemap.evaluate.scoring import score_inbetween

    f = _own_folders(tmp_path, bandai_paths)
    out = tmp_path / "out"
    code, _, err = run(capsys, "bench", "--train", f["train"], "--test", f["backwards"], f["waves"], "--quick",
                       "--lengths", "5,30", "--out", out)
    assert code == 0, err
    results = json.loads((out / "results.json").read_text())
    assert list(results["holdouts"]) == ["own"] and results["more_splits"] == {}
    hold = results["holdouts"]["own"]
    inb = hold["inbetween"]
    assert hold["split"]["train_files"] == sorted(str(p) for p in f["train"].iterdir())
    assert hold["split"]["test_files"] == [str(p) for k in ("backwards", "waves") for p in f[k].iterdir()]
    assert inb["lengths"] == [5, 30] and inb["criteria_lengths"] == [15, 30, 45]
    # The windows are the test clips' (the quick run's seeded 8 of them), grouped by the folder they came from.
    split = evaluate.load_own([str(f["train"])], [str(f["backwards"]), str(f["waves"])], (5, 30))
    every = [(c, s) for c, m in enumerate(split.test) for s in evaluate.window_starts(len(m), N_PAST + 30 + N_FUTURE)]
    assert inb["windows"] == min(8, len(every)) == len(inb["window_list"])
    windows = [(hold["split"]["test_files"].index(n), s) for n, s in inb["window_list"]]
    assert set(windows) <= set(every)
    assert split.contents == [str(f["backwards"]), str(f["waves"])]  # the folders as given
    assert set(inb["per_content"]) == {split.contents[c] for c, _ in windows}
    # SLERP's L2Q at 30 frames, scored again from the same windows of the same clips.
    state = runner.prepare(split, Settings.quick_run(), 0, log=lambda m: None, full=False)
    tr, tp, preds = runner.predict_windows(runner.empty_engines(state), ["slerp"], state["test"], windows, 30)
    again = score_inbetween(state["ctx"], tr, tp, *preds["slerp"], 30, accuracy_only=True)["l2q"]
    assert inb["methods"]["slerp"]["30"]["l2q"] == pytest.approx(again, rel=1e-9)
    md = (out / "results.md").read_text()
    assert f"--train {f['train']} --test {f['backwards']} {f['waves']} --lengths 5,30 --quick" in md
    assert "## Your clips (library from --train, gaps in --test)" in md
    # The criteria's 15 and 45 frames did not run: the skate's checks 30 alone, the goal's 30 alone.
    assert "skate <= 1.5x truth at 30 |" in md and "goal: L2Q, L2P <= 0.7x slerp at 30 |" in md
    assert "not the clips given" in md  # the bench/ scripts measure bandai1: said, not run


def test_own_clips_at_60_fps_take_the_bench_gaps_durations(tmp_path, bandai_paths):
    from posturemap.io import bvh

    f = _own_folders(tmp_path, bandai_paths)
    fast = tmp_path / "fast"
    fast.mkdir()
    for p in f["waves"].iterdir():
        bvh.write(fast / p.name, resample(bvh.read(p), 60.0))
    split = evaluate.load_own([str(f["train"])], [str(fast)])
    assert split.lengths == (10, 30, 60, 90) and split.criteria == (30, 60, 90)  # 5, 15, 30, 45 at 30 fps
    assert split.test[0].fps == pytest.approx(60.0, rel=1e-5) and split.train[0].fps == pytest.approx(30.0, rel=1e-5)
    assert split.contents == [str(fast)]
    inb = {"lengths": [10, 30, 60, 90], "criteria_lengths": [30, 60, 90]}
    assert report.criteria_lengths(inb) == ([30, 60, 90], [60, 90])
    assert report.criteria_lengths({"lengths": [5, 15, 30, 45]}) == ([15, 30, 45], [30, 45])  # the bench's own


def test_own_clips_refused_with_one_line(tmp_path, bandai_paths, capsys, cmu_file):
    from clikit import assert_refused

    from posturemap import cli
    from posturemap.io import bvh

    f = _own_folders(tmp_path, bandai_paths)
    out = tmp_path / "out"
    assert_refused(capsys, "--test", "bench", "--train", f["train"], "--out", out, words=["give both"])
    assert_refused(capsys, "--lengths", "bench", "--lengths", "5,30", "--out", out, words=["only with"])
    assert_refused(capsys, cmu_file, "bench", "--train", f["train"], "--test", cmu_file, "--out", out,
                   words=["skeleton differs"])
    clip = next(f["backwards"].iterdir())
    assert_refused(capsys, clip, "bench", "--train", f["train"], "--test", clip, "--lengths", "9000", "--out", out,
                   words=["no test clip is longer than one window of 9020 frames"])
    with pytest.raises(SystemExit) as exc:  # argparse's refusal
        cli.main(["bench", "--train", str(f["train"]), "--test", str(clip), "--lengths", "0,5"])
    assert exc.value.code == 2
    assert capsys.readouterr().err == ("posturemap: error: --lengths: must be comma-separated whole numbers from 1 "
                                       "to 10000, got '0,5'\n")
    assert_refused(capsys, clip, "bench", "--train", f["train"], "--test", clip, "--out", clip,
                   words=["is a file"])
    assert_refused(capsys, "--data", "bench", "--train", f["train"], "--test", clip, "--data", tmp_path, "--out", out)
    one = tmp_path / "one"  # a clip of one frame beside a valid one: refused by name, not a traceback
    one.mkdir()
    bvh.write(one / "still.bvh", bvh.read(clip)[:1])
    assert_refused(capsys, one / "still.bvh", "bench", "--train", f["train"], "--test", f["waves"], one, "--out", out,
                   words=["2 frames at least"])
    assert not out.exists()  # nothing written


def test_own_clips_given_for_training_and_testing_are_named(tmp_path, bandai_paths):
    f = _own_folders(tmp_path, bandai_paths)
    said = []
    clip = next(f["train"].iterdir())
    evaluate.load_own([str(f["train"])], [str(clip)], (5,), log=said.append)
    assert len(said) == 1 and said[0].startswith(f"posturemap: warning: {clip}: given for training and for testing")
    said.clear()
    evaluate.load_own([str(f["train"])], [str(f["waves"])], (5,), log=said.append)
    assert said == []


def test_a_reference_without_error_leaves_its_ratios_out():
    # SLERP over a held pose makes no error, nor NPSS over a one-frame gap: no ratio to it, not a
    # division by zero (a user's own clips can be so).
    inb = _inb([0.5] * 4, [0.6] * 4, [1.0, 1.2, 1.4, 1.5], [1.0] * 4)
    inb["methods"]["slerp"]["30"]["l2q"] = 0.0
    inb["truth"]["15"]["skate"] = 0.0
    acc = report.acceptance(inb)["m"]
    assert acc["l2q"] == (True, 0.5)  # the other lengths' ratio
    assert acc["skate"] == (True, pytest.approx(1.5))  # 30 and 45 frames' (15's truth is 0)
    assert report._over(1.0, 0.0, 3, "x") == "-" and report._over(1.0, 4.0, 2, "x") == "0.25x"
