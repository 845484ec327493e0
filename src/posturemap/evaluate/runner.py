"""The bench's run: train on each hold-out, rebuild the windows, score, write the report."""

from __future__ import annotations

import dataclasses
import os
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from . import metrics
from ..io.bvh import write_bytes_atomic
from ..learn.features import CLASSES
from ..core.joints import foot_joints, leg_chains, leg_length
from ..core.motion import Motion
from ..core.skeleton import fk
from ..synth.engine import TransitionEngine
from . import report
from .baselines import centred, engine_call, fixed_key_model, set_key, som_model
from .protocol import (CMU_FILE, CROSS_LENGTH, DEFAULT_SPEC, FLOOR_PERCENTILE, METHODS, N_FUTURE, N_PAST, OWN,
                       SPLIT_METHODS, STATS_STRIDE, STATS_WINDOW, STRIDE, SWEEP_FRACTIONS, SWEEP_LENGTHS,
                       TEST_CONTENTS, TEST_STYLES, VARIANTS, WHOLE_CLIP, Settings, Split, _log, load_own, load_split,
                       make_windows, method_spec, random_pairs, window_starts)
from .scoring import (NATURAL_FRAMES, NATURAL_STRIDE_S, Context, foot_float, global_windows, natural_reference,
                      naturalness_fn, paired_difference, per_content, rebuilt_frames, score_inbetween,
                      score_truth, skate_scores, truth_globals, window_features)
from .report import jsonable
from .speed import latency, run_bench_script, training_speed

def prepare(split: Split, settings: Settings, seed: int, log=_log, full: bool = True) -> dict:
    """Train the maps on a hold-out's training side; returns the shared state of the run.

    ``full=False``: the posture map alone, no classic SOM and no pose-validity index (what
    :func:`run_split` scores needs neither; ``state["som"]`` is then None).
    """
    from ..learn.model import PostureMap

    train, test = split.train, split.test
    log(f"{split.name} hold-out: {len(train)} training clips ({sum(map(len, train))} frames), "
        f"{len(test)} test clips ({sum(map(len, test))} frames)")
    t0 = time.perf_counter()
    model = PostureMap(seed=seed).fit(train, list(split.train_names))
    upm_seconds = time.perf_counter() - t0
    space = model.space_
    log(f"upm: {sum(model.neuron_counts())} neurons {model.neuron_counts()} in {upm_seconds:.1f} s "
        f"(root {model.skeleton_.names[space.root]}, up axis {'XYZ'[space.up]})")
    x_train = np.concatenate([space.encode(m) for m in train])
    som, som_info = None, None
    if full:
        log(f"som: MiniSom per class, {settings.som_epochs} epoch(s)")
        som, som_info = som_model(model, space.split(x_train), settings.som_epochs, seed, log)

    sk = model.skeleton_
    # Every score is of the test clips (speeds, jerk, the naturalness' reference windows), whose
    # rate may differ from the map's: a map serves clips at another rate.
    root, up, fps = space.root, space.up, float(test[0].fps)
    feet = foot_joints(sk.names)
    # L2P statistics: training windows of 50 frames every 20, in the window frame (LaFAN1).
    wins_r, wins_p = [], []
    for m in train:
        for s in window_starts(len(m), STATS_WINDOW, STATS_STRIDE):
            wins_r.append(m.rotations[s: s + STATS_WINDOW])
            wins_p.append(m.positions[s: s + STATS_WINDOW])
    g_r, g_p = fk(sk.parents, np.stack(wins_r), np.stack(wins_p))
    n_pos, _ = metrics.normalize_windows(g_p, g_r, root, up, N_PAST - 1)
    _, std = metrics.position_stats(n_pos)
    heights = np.concatenate([m.global_positions()[:, feet, up] for m in train])
    floor = np.percentile(heights, FLOOR_PERCENTILE, axis=0)
    skate_height = metrics.SKATE_HEIGHT_LEGS * leg_length(sk, leg_chains(sk))
    ctx = Context(sk, space, root, up, fps, feet, floor, std,
                  metrics.build_posture_index(x_train[:, space.active]) if full else None, skate_height, split.cm)
    return {"split": split, "train_files": split.train_names, "test_files": split.test_names,
            "train": train, "test": test, "model": model, "som": som, "som_info": som_info,
            "upm_seconds": upm_seconds, "ctx": ctx, "x_train": x_train, "stats_windows": len(wins_r)}


def make_engines(state: dict) -> dict:
    """One engine per key source, each holding every test clip (names = clip indices).

    The whole clips serve the latency and the diagnostics (which read the truth on purpose);
    in-betweening and cross-clip transitions use :func:`empty_engines`.
    """
    model = state["model"]
    engines = {"upm": TransitionEngine(model), "som": TransitionEngine(state["som"]),
               "fixed": TransitionEngine(fixed_key_model(model))}
    for e in engines.values():
        for c, m in enumerate(state["test"]):
            e.add(str(c), m)
    return engines


def empty_engines(state: dict) -> dict:
    """Engines of the map and of the SOM that hold no clip: a method can only see the clips
    put in for one call (:func:`clips_in`), whatever it looks at besides the map."""
    return {"upm": TransitionEngine(state["model"]), "som": TransitionEngine(state["som"])}


@contextmanager
def clips_in(engines: dict, clips: dict):
    """Inside the block, every engine of ``engines`` holds ``clips`` (name -> Motion); after it,
    they are gone again."""
    try:
        for e in engines.values():
            for name, m in clips.items():
                e.add(name, m)
        yield
    finally:
        for e in engines.values():
            for name in clips:
                e.tracks.pop(name, None)


def _generate(engines, method, clip, length, a_end, b_start, **kw):
    """``method`` between frames ``a_end`` and ``b_start`` of one whole clip (diagnostics)."""
    eng, base, feet = engine_call(engines, method)
    r, p = eng.generate(clip, clip, length=length, a_end=a_end, b_start=b_start, align=False, method=base,
                        foot_lock=feet, **kw)
    return r.copy(), p.copy()


def generate_from_context(engines: dict, methods, past: Motion, future: Motion, length: int) -> dict:
    """Each method's ``length`` frames between the past context (A) and the future context (B).

    engines : from :func:`empty_engines`; while the methods run they hold these two clips only
    (``align=False``), so no method can see a frame of the gap or another test clip.
    Returns ``{method: (rotations (L, J, 4), positions (L, J, 3))}``, new arrays.
    """
    out = {}
    with clips_in(engines, {"_past": past, "_future": future}):
        for m in methods:
            eng, base, feet = engine_call(engines, m)
            r, p = eng.generate("_past", "_future", length=length, a_end=len(past) - 1, b_start=0, align=False,
                                method=base, foot_lock=feet)
            out[m] = (r.copy(), p.copy())
    return out


def predict_windows(engines: dict, methods, test: list, windows, length: int):
    """The truth and each method's rebuilt gap of every window ``(clip, start)`` of ``test``.

    Returns ``(truth_r, truth_p, preds)``: the windows' rotations (W, span, J, 4) and positions
    (W, span, J, 3) over ``N_PAST + length + N_FUTURE`` frames, and ``{method: (rotations
    (W, length, J, 4), positions (W, length, J, 3))}`` made from the context alone
    (:func:`generate_from_context`; ``zero-velocity`` holds the last past frame).
    """
    span = N_PAST + length + N_FUTURE
    truth_r = np.stack([test[c].rotations[s: s + span] for c, s in windows])
    truth_p = np.stack([test[c].positions[s: s + span] for c, s in windows])
    preds = {m: (np.empty((len(windows), length) + truth_r.shape[2:]),
                 np.empty((len(windows), length) + truth_p.shape[2:])) for m in methods}
    generated = [m for m in methods if m != "zero-velocity"]
    for i, (c, s) in enumerate(windows):
        past, future = test[c][s: s + N_PAST], test[c][s + N_PAST + length: s + span]
        if "zero-velocity" in preds:
            preds["zero-velocity"][0][i], preds["zero-velocity"][1][i] = past.rotations[-1], past.positions[-1]
        for m, (r, p) in generate_from_context(engines, generated, past, future, length).items():
            preds[m][0][i], preds[m][1][i] = r, p
    return truth_r, truth_p, preds


def predict_whole_clip(model, test: list, windows, length: int) -> tuple[dict, dict]:
    """The default's rebuilt gap of every window given the whole clip as context (:data:`WHOLE_CLIP`):
    A is the test clip up to the window's last past frame, B the clip from its first future
    frame (``align=False``); neither holds a frame of the gap. Returns ``({label: (rotations
    (W, length, J, 4), positions (W, length, J, 3))}, {label: the share of windows whose
    retrieval replayed the clips' own motion})``."""
    eng = TransitionEngine(model)
    base, feet = method_spec(DEFAULT_SPEC)
    preds, own, default = {}, {}, eng.own_seconds
    for label, seconds in WHOLE_CLIP.items():
        eng.own_seconds = default if seconds is None else seconds
        r_out, p_out, count = None, None, 0
        for i, (c, s) in enumerate(windows):
            eng.add("_past", test[c][: s + N_PAST])
            eng.add("_future", test[c][s + N_PAST + length:])
            r, p = eng.generate("_past", "_future", length=length, a_end=s + N_PAST - 1, b_start=0, align=False,
                                method=base, foot_lock=feet)
            if r_out is None:
                r_out, p_out = np.empty((len(windows),) + r.shape), np.empty((len(windows),) + p.shape)
            r_out[i], p_out[i] = r, p
            count += bool((eng.last.get("retrieval") or {}).get("own"))
        eng.tracks.clear()
        preds[label], own[label] = (r_out, p_out), count / max(len(windows), 1)
    return preds, own


def _score_whole_clip(out: dict, n: int, model, ctx, test: list, windows, length: int, truth_r, truth_p,
                      **score) -> None:
    """:func:`predict_whole_clip` of ``windows`` at ``length`` scored against the truth into ``out``
    (``{"methods": {label: {n: scores}}, "own_share": {label: {n: share}}}``); ``score``: the
    keywords of :func:`score_inbetween`."""
    whole, own = predict_whole_clip(model, test, windows, length)
    for v, (r, p) in whole.items():
        out["methods"][v][n] = score_inbetween(ctx, truth_r, truth_p, r, p, length, **score)
        out["own_share"][v][n] = own[v]


def run_inbetween(state: dict, windows, settings: Settings, seed: int, log=_log,
                  diagnostics: bool = False) -> tuple[dict, dict, dict]:
    """Scores per method and length, the truth's, per content, the diagnostics; plus curves
    for a plot. Returns ``(inbetween, diagnostics, example)`` (diagnostics empty unless asked).
    """
    ctx, engines = state["ctx"], empty_engines(state)
    test, lengths = state["test"], state["split"].lengths
    res = {"windows": len(windows), "lengths": list(lengths), "methods": {m: {} for m in METHODS},
           "criteria_lengths": None if state["split"].criteria is None else list(state["split"].criteria),
           "truth": {}, "default_method": DEFAULT_SPEC, "vs_slerp": {m: {} for m in METHODS},
           "window_list": [[state["test_files"][c], s] for c, s in windows],
           "whole_clip": {"methods": {v: {} for v in WHOLE_CLIP}, "own_share": {v: {} for v in WHOLE_CLIP}}}
    diag = {"key_distance": {}, "key_distance_by_class": {}, "variants": {v: {} for v in VARIANTS},
            "sweep": {}} if diagnostics else {}
    example = {}
    ref = natural_reference(ctx, test)
    # The example plotted: a window of 30 frames at 30 fps (as long at a user's own clips' rate),
    # or the length nearest that.
    shown = 30 if state["split"].criteria is None else state["split"].criteria[1]
    shown = min(lengths, key=lambda n: (abs(n - shown), n))
    for length in lengths:
        t0 = time.perf_counter()
        truth_r, truth_p, preds = predict_windows(engines, METHODS, test, windows, length)
        sl = slice(N_PAST, N_PAST + length)
        nat = naturalness_fn(ctx, ref, windows, length)(
            np.concatenate([rebuilt_frames(truth_r, preds[m][0]) for m in METHODS] + [truth_r[:, N_PAST - 1: sl.stop]]),
            np.concatenate([rebuilt_frames(truth_p, preds[m][1]) for m in METHODS] + [truth_p[:, N_PAST - 1: sl.stop]]))
        nat = nat.reshape(len(METHODS) + 1, len(windows))
        n = str(length)
        truth_g = truth_globals(ctx, truth_r, truth_p)
        for k, m in enumerate(METHODS):
            res["methods"][m][n] = score_inbetween(ctx, truth_r, truth_p, *preds[m], length, natural=nat[k],
                                                   truth_g=truth_g)
        res["truth"][n] = score_truth(ctx, truth_r, truth_p, length, natural=nat[-1])
        _score_whole_clip(res["whole_clip"], n, state["model"], ctx, test, windows, length, truth_r, truth_p,
                          truth_g=truth_g)
        for m in METHODS:
            res["vs_slerp"][m][n] = {
                k: paired_difference(res["methods"][m][n]["per_window"][k],
                                     res["methods"]["slerp"][n]["per_window"][k], seed)
                for k in ("l2q", "l2p")}
        if diagnostics:
            run_diagnostics(state, windows, settings, seed, length, truth_r, truth_p, preds, diag)
        if length == shown:  # plot a walking window when there is one
            names = [state["test_files"][c] for c, _ in windows]
            e = next((i for i, nm in enumerate(names) if "_walk_" in nm), 0)
            example = {m: np.concatenate([truth_r[e, :N_PAST], preds[m][0][e], truth_r[e, N_PAST + length:]])
                       for m in METHODS}
            example["truth"] = truth_r[e]
            example["positions"] = {m: np.concatenate([truth_p[e, :N_PAST], preds[m][1][e], truth_p[e, N_PAST + length:]])
                                    for m in METHODS}
            example["positions"]["truth"] = truth_p[e]
            example["parents"], example["up"] = ctx.skeleton.parents, ctx.up
            example["feet"], example["fps"] = ctx.feet, ctx.fps
            example["window"] = windows[e]
            example["clip"] = names[e]
            example["joints"] = list(ctx.skeleton.names)
        r = res["methods"]
        log(f"  in-betweening L={length}: {len(windows)} windows in {time.perf_counter() - t0:.1f} s; "
            + ", ".join(f"{m} L2Q {r[m][n]['l2q']:.3f}" for m in METHODS))
    contents = [state["split"].contents[c] for c, _ in windows]
    res["per_content"] = per_content(res, contents)
    res["whole_clip"]["per_content"] = per_content({**res["whole_clip"], "truth": res["truth"]}, contents)
    return res, diag, example


def run_diagnostics(state, windows, settings, seed, length, truth_r, truth_p, preds, diag):
    """Key distances and stand-in keys of the keyed methods at one length, into ``diag``.

    These read the truth on purpose (the oracle key): they explain the keyed methods' errors,
    they are not methods. ``preds`` holds the methods' frames (``upm``, ``slerp`` are used).
    """
    from ..learn.model import PostureMap

    ctx, engines, test = state["ctx"], state["engines"], state["test"]
    space = state["model"].space_
    fixed, upm, act = engines["fixed"].model, engines["upm"], space.active
    vpreds = {v: (np.empty_like(preds["slerp"][0]), np.empty_like(preds["slerp"][1])) for v in VARIANTS}
    key_at = length // 2
    kd = {k: [] for k in ("a_to_true", "b_to_true", "blend_to_true", "upm_key_to_true",
                          "upm_path_key_to_true", "som_key_to_true", "nearest_neuron_to_true",
                          "upm_key_to_blend")}
    kdc = {cls: {"blend": [], "upm_key": [], "nearest_neuron": []} for cls in CLASSES}
    for i, (c, s) in enumerate(windows):
        name = str(c)
        a_end, b_start = s + N_PAST - 1, s + N_PAST + length
        feats = upm.tracks[name].features
        xa, xb, xt = feats[a_end], feats[b_start], feats[a_end + key_at]
        blend = xa + 0.5 * (xb - xa)
        k_upm, _ = upm.keys.key_features(xa, xb, 0.5)
        k_path, _ = upm.keys.key_features(xa, xb, 0.5, path=True)
        k_som, _ = engines["som"].keys.key_features(xa, xb, 0.5)
        k_near = space.merge([m.weights_[m.predict(xt[d][None])[0]]
                              for m, d in zip(state["model"].maps_, space.class_dims)])
        for key, v in (("a_to_true", xa), ("b_to_true", xb), ("blend_to_true", blend),
                       ("upm_key_to_true", k_upm), ("upm_path_key_to_true", k_path),
                       ("som_key_to_true", k_som), ("nearest_neuron_to_true", k_near)):
            kd[key].append(float(np.linalg.norm((v - xt)[act])))
        kd["upm_key_to_blend"].append(float(np.linalg.norm((k_upm - blend)[act])))
        for cls, d in zip(CLASSES, space.class_dims):
            for key, v in (("blend", blend), ("upm_key", k_upm), ("nearest_neuron", k_near)):
                kdc[cls][key].append(float(np.linalg.norm((v - xt)[d])))
        set_key(fixed, blend)
        vpreds["blend-key"][0][i], vpreds["blend-key"][1][i] = _generate(engines, "blend-key", name, length,
                                                                         a_end, b_start)
        set_key(fixed, xt)
        vpreds["oracle-key"][0][i], vpreds["oracle-key"][1][i] = _generate(engines, "oracle-key", name,
                                                                           length, a_end, b_start)
        # A map learned from this clip's context alone (the frames outside the gap), as
        # `posturemap transition` does without --map: the clip's own style, no truth.
        own = PostureMap(seed=seed).fit([centred(test[c][: a_end + 1], ctx.root, ctx.up),
                                         centred(test[c][b_start:], ctx.root, ctx.up)])
        eng = TransitionEngine(own)
        eng.add(name, test[c])
        r, p = eng.generate(name, name, length=length, a_end=a_end, b_start=b_start, align=False, method="upm")
        vpreds["self-map-key"][0][i], vpreds["self-map-key"][1][i] = r, p
        # Zero angular velocity at the seams: the window with the two frames before A's end
        # and the one after B's start given the seam frame's rotations (positions kept).
        seg_r = test[c].rotations[s: s + N_PAST + length + N_FUTURE].copy()
        a_w, b_w = N_PAST - 1, N_PAST + length
        seg_r[a_w - 2: a_w] = seg_r[a_w]
        seg_r[b_w + 1] = seg_r[b_w]
        fixed_eng = engines["fixed"]
        fixed_eng.add("v0", Motion(ctx.skeleton, seg_r, test[c].positions[s: s + N_PAST + length + N_FUTURE],
                                   ctx.fps))
        r, p = fixed_eng.generate("v0", "v0", length=length, a_end=a_w, b_start=b_w, align=False, method="spline")
        vpreds["spline-v0"][0][i], vpreds["spline-v0"][1][i] = r, p
        set_key(fixed, blend)
        r, p = fixed_eng.generate("v0", "v0", length=length, a_end=a_w, b_start=b_w, align=False, method="upm")
        vpreds["blend-key-v0"][0][i], vpreds["blend-key-v0"][1][i] = r, p
        # upm's frames with the root joint's translation of slerp (LERP root).
        vpreds["upm-lerp-root"][0][i] = preds["upm"][0][i]
        vpreds["upm-lerp-root"][1][i] = preds["upm"][1][i]
        vpreds["upm-lerp-root"][1][i, :, ctx.root] = preds["slerp"][1][i, :, ctx.root]
    n = str(length)
    for v in VARIANTS:
        diag["variants"][v][n] = score_inbetween(ctx, truth_r, truth_p, *vpreds[v], length)
    diag["key_distance"][n] = {k: float(np.mean(v)) for k, v in kd.items()}
    diag["key_distance_by_class"][n] = {cls: {k: float(np.mean(v)) for k, v in kv.items()}
                                        for cls, kv in kdc.items()}
    if settings.sweep and length in SWEEP_LENGTHS:
        diag["sweep"][n] = sweep(state, windows, truth_r, truth_p, length)


def sweep(state, windows, truth_r, truth_p, length) -> dict:
    """upm's L2Q and L2P for alpha at 1/4, 1/2, 3/4 and key_at at a quarter, the default
    (``length // 2``) and three quarters of the length."""
    out = {}
    engines, ctx = state["engines"], state["ctx"]
    key_ats = sorted({max(1, round(SWEEP_FRACTIONS[0] * length)), max(1, length // 2),
                      min(length, round(SWEEP_FRACTIONS[-1] * length))})
    for fa in SWEEP_FRACTIONS:
        for key_at in key_ats:
            pr = np.empty((len(windows), length) + truth_r.shape[2:])
            pp = np.empty((len(windows), length) + truth_p.shape[2:])
            for i, (c, s) in enumerate(windows):
                pr[i], pp[i] = _generate(engines, "upm", str(c), length, s + N_PAST - 1, s + N_PAST + length,
                                         alpha=fa, key_at=key_at)
            sc = score_inbetween(ctx, truth_r, truth_p, pr, pp, length, accuracy_only=True)
            out[f"alpha={fa:g},key_at={key_at}"] = {"alpha": fa, "key_at": key_at,
                                                    "l2q": sc["l2q"], "l2p": sc["l2p"]}
    return out


def run_cross(state: dict, settings: Settings, seed: int, log=_log) -> dict:
    """Foot skate, validity and jerk of transitions between two different test clips."""
    t0 = time.perf_counter()
    ctx, engines, test = state["ctx"], empty_engines(state), state["test"]
    pairs = random_pairs([len(m) for m in test], settings.pairs, seed + 1)
    length = CROSS_LENGTH
    upm = engines["upm"]
    seqs = {m: [] for m in METHODS}
    reference = []
    for a, b, a_end, b_start in pairs:
        with clips_in(engines, {"a": test[a], "b": test[b]}):  # these two clips only
            ta, tb = upm.tracks["a"], upm.tracks["b"]
            dtheta, shift = upm.alignment(ta, tb, a_end, b_start, length)
            b_part = upm.continuation("b", b_start, turn=dtheta, shift=shift)[:N_FUTURE]  # the reference's
            a_part = test[a][a_end - N_PAST + 1: a_end + 1]
            for m in METHODS:
                if m == "zero-velocity":
                    r = np.repeat(a_part.rotations[-1:], length, axis=0)
                    p = np.repeat(a_part.positions[-1:], length, axis=0)
                    placed = b_part
                else:
                    eng, base, feet = engine_call(engines, m)
                    r, p = eng.generate("a", "b", length=length, a_end=a_end, b_start=b_start, align=True,
                                        method=base, foot_lock=feet)
                    # B where this method put it (retrieval carries its own placement of B).
                    placed = eng.continuation("b", b_start)[:N_FUTURE]
                seqs[m].append((np.concatenate([a_part.rotations, r, placed.rotations]),
                                np.concatenate([a_part.positions, p, placed.positions])))
        reference.append((a_part, b_part))
    out = {"pairs": len(pairs), "length": length, "align": True, "methods": {}}
    sl = slice(N_PAST, N_PAST + length)
    steps = slice(N_PAST - 1, N_PAST + length)
    parents = ctx.skeleton.parents
    peak, jolt = {}, {}  # per method, per pair: the largest step and acceleration of any joint through the new frames
    for m in METHODS:
        rots = np.stack([s[0] for s in seqs[m]])
        pos = np.stack([s[1] for s in seqs[m]])
        _, gp = global_windows(rots, pos, parents)
        skate, contact = skate_scores(ctx, gp, steps)
        valid = metrics.pose_validity(window_features(ctx, rots[:, sl], pos[:, sl]), ctx.index)
        up = foot_float(ctx, gp, length) * ctx.cm
        peak[m] = metrics.largest_step(gp, slice(N_PAST - 1, N_PAST + length + 1))  # the seams' steps too
        jolt[m] = metrics.largest_acceleration(gp, slice(N_PAST - 2, N_PAST + length + 2))  # and the seams' frames
        out["methods"][m] = {"skate": float(skate.mean()), "contact_skate": contact,
                             "float_cm": float(up.mean()), "floats_over_10cm": int(np.sum(up > 10.0)),
                             "validity": float(valid.mean()),
                             "validity_p95": float(np.percentile(valid, 95)),
                             "jerk": metrics.jerk(gp[:, N_PAST - 3: N_PAST + length + 3], ctx.fps) * ctx.cm}
    # Reference: the real frames on both sides of the seams (10 of A, 10 of B, separately).
    real = [(np.stack([p.rotations for p in parts]), np.stack([p.positions for p in parts]))
            for parts in zip(*reference)]
    skates, contacts, jerks, valids, real_peak, real_jolt = [], [], [], [], [], []
    for rots, pos in real:
        _, gp = global_windows(rots, pos, parents)
        skate, contact = skate_scores(ctx, gp, slice(0, gp.shape[1] - 1))
        real_peak.append(metrics.largest_step(gp, slice(None)))
        real_jolt.append(metrics.largest_acceleration(gp, slice(None)))
        skates.append(skate.mean())
        contacts.append(contact)
        jerks.append(metrics.jerk(gp, ctx.fps) * ctx.cm)
        valids.append(metrics.pose_validity(window_features(ctx, rots, pos), ctx.index))
    v = np.concatenate(valids)
    # A transition's largest step over the largest of its own real frames (A's last 10, B's first
    # 10), or a brisk walking swing's (metrics.POP_FLOOR_LEGS) where those stand
    # (a standing pair whose B stands elsewhere needs a step): above 1 where the new frames move
    # some joint faster than either.
    # Likewise the largest acceleration (a limb set off or stopped at once), over a walking
    # ankle's (metrics.POP_ACCEL_LEGS) at least.
    leg = ctx.skate_height / metrics.SKATE_HEIGHT_LEGS
    for name, found, real_max, floor in (("step", peak, real_peak, metrics.POP_FLOOR_LEGS * leg / ctx.fps),
                                         ("accel", jolt, real_jolt, metrics.POP_ACCEL_LEGS * leg / ctx.fps**2)):
        own = np.maximum(np.maximum(real_max[0], real_max[1]), floor)
        for m in METHODS:
            ratio = found[m] / np.maximum(own, 1e-12)
            out["methods"][m].update({f"{name}_ratio": float(ratio.mean()),
                                      f"{name}s_over_1_5": int(np.sum(ratio > 1.5))})
    out["reference"] = {"skate": float(np.mean(skates)), "contact_skate": float(np.mean(contacts)),
                        "validity": float(v.mean()), "validity_p95": float(np.percentile(v, 95)),
                        "jerk": float(np.mean(jerks))}
    out["pair_list"] = [{"a": state["test_files"][a], "b": state["test_files"][b],
                         "a_end": a_end, "b_start": b_start} for a, b, a_end, b_start in pairs]
    log(f"  cross-clip: {len(pairs)} pairs in {time.perf_counter() - t0:.1f} s")
    return out


def run_holdout(name: str, data_dir: Path, settings: Settings, seed: int, log=_log,
                split: Split | None = None) -> tuple[dict, dict, dict, dict]:
    """One hold-out end to end: read, train on its training side, in-betweening, cross-clip.
    ``split``: the hold-out's clips when given (a user's own: :func:`protocol.load_own`), else
    read by :func:`load_split`.

    Returns ``(results, diagnostics, example, state)`` (diagnostics for the style hold-out
    when ``settings.diagnostics``; ``state`` for the speed figures; it holds the engines of
    :func:`make_engines` when the diagnostics ran).
    """
    split = split or load_split(name, data_dir, settings)
    state = prepare(split, settings, seed, log)
    diagnostics = settings.diagnostics and name == "style"
    if diagnostics:
        state["engines"] = make_engines(state)
    windows = make_windows(state, settings, seed)
    log(f"  in-betweening: {len(windows)} windows from {len(state['test'])} test clips")
    inb, diag, example = run_inbetween(state, windows, settings, seed, log, diagnostics=diagnostics)
    cross = run_cross(state, settings, seed, log) if len(state["test"]) >= 2 and settings.pairs else None
    model, ctx = state["model"], state["ctx"]
    out = {
        "split": {"rule": split.rule, "test_clips": len(split.test), "test_frames": int(sum(map(len, split.test))),
                  "train_clips_all": split.train_clips_all, "train_clips": len(split.train),
                  "train_frames": int(sum(map(len, split.train))), "fps": ctx.fps,
                  "joints": ctx.skeleton.num_joints, "unit": split.unit, "cm_per_unit": split.cm,
                  "test_files": list(split.test_names), "train_files": list(split.train_names)},
        "map": {"neurons": model.neuron_counts(), "radius": [m.radius_ for m in model.maps_],
                "train_seconds": state["upm_seconds"], "som": state["som_info"]},
        "feet": {"joints": [ctx.skeleton.names[j] for j in ctx.feet], "floor_cm": (ctx.floor * ctx.cm).tolist(),
                 "floor_percentile": FLOOR_PERCENTILE, "skate_height_cm": ctx.skate_height * ctx.cm,
                 "leg_length_cm": ctx.skate_height / metrics.SKATE_HEIGHT_LEGS * ctx.cm},
        "inbetween": inb, "cross_clip": cross,
    }
    return out, diag, example, state


def run_split(name: str, data_dir: Path, settings: Settings, seed: int, log=_log) -> dict:
    """One split of :data:`MORE_SPLITS`: in-betweening accuracy (L2Q, L2P) and foot skate of the
    main methods (:data:`SPLIT_METHODS`) and the truth's skate, at :data:`SPLIT_LENGTHS`, with
    the protocol of the hold-outs (the map and everything else from the split's training side)."""
    split = load_split(name, data_dir, settings)
    state = prepare(split, settings, seed, log, full=False)
    windows = make_windows(state, settings, seed)
    ctx, test = state["ctx"], state["test"]
    engines = {"upm": TransitionEngine(state["model"])}
    out = {"rule": split.rule, "train_clips": len(split.train), "train_clips_all": split.train_clips_all,
           "test_clips": len(split.test), "windows": len(windows), "lengths": list(split.lengths),
           "train_files": list(split.train_names), "test_files": list(split.test_names),
           "methods": {m: {} for m in SPLIT_METHODS}, "truth": {},
           "whole_clip": {"methods": {v: {} for v in WHOLE_CLIP}, "own_share": {v: {} for v in WHOLE_CLIP}}}
    t0 = time.perf_counter()
    for length in split.lengths:
        truth_r, truth_p, preds = predict_windows(engines, SPLIT_METHODS, test, windows, length)
        n, steps = str(length), slice(N_PAST - 1, N_PAST + length)
        truth_g = truth_globals(ctx, truth_r, truth_p)
        for m in SPLIT_METHODS:
            out["methods"][m][n] = score_inbetween(ctx, truth_r, truth_p, *preds[m], length, accuracy_only=True,
                                                   truth_g=truth_g)
        _score_whole_clip(out["whole_clip"], n, state["model"], ctx, test, windows, length, truth_r, truth_p,
                          accuracy_only=True, truth_g=truth_g)
        out["truth"][n] = {"skate": float(skate_scores(ctx, truth_g[1], steps)[0].mean())}
    log(f"  {name}: {len(windows)} windows from {len(test)} test clips in {time.perf_counter() - t0:.1f} s; "
        + ", ".join(f"{m} L2Q at 30 {out['methods'][m]['30']['l2q']:.3f}" for m in SPLIT_METHODS
                    if "30" in out["methods"][m]))
    return out


def run(data_dir, out, seed: int = 0, settings: Settings | None = None, log=_log, splits: dict | None = None,
        command: str | None = None) -> dict:
    """Run the benchmark; writes results.md, results.json and PNG plots into ``out``.

    ``splits`` (name -> :class:`Split`): run these hold-outs instead of ``settings.holdouts``
    (``data_dir`` then unused; a user's own clips, :func:`protocol.load_own`); ``command``: the
    command line's arguments that chose them, for the report.
    Returns the results dict (the content of results.json).
    """
    settings = settings or Settings.full()
    t_start = time.perf_counter()
    data_dir, out = Path(data_dir or "."), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    np.random.seed(seed)  # third-party code that draws from numpy's global generator
    import platform

    code = code_version()  # at the start: the code that runs, whatever changes meanwhile

    sections = {}
    clock = time.perf_counter()

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        sections[name] = now - clock
        clock = now

    holdouts, examples, diag, speed_state = {}, {}, {}, None
    for name in (splits or settings.holdouts):
        holdouts[name], d, examples[name], state = run_holdout(name, data_dir, settings, seed, log,
                                                               (splits or {}).get(name))
        diag = diag or d
        if speed_state is None or name == "style":
            speed_state = state
        lap(f"{name} hold-out")
    more = {}
    for name in () if splits else settings.more_splits:
        log(f"split {name}")
        more[name] = run_split(name, data_dir, settings, seed, log)
        lap(f"split {name}")
    log("speed: latency")
    if "engines" not in speed_state:
        speed_state["engines"] = make_engines(speed_state)
    speed = {"latency": latency(speed_state, settings.latency_calls, seed), "training": [], "bench": {},
             "holdout": speed_state["split"].name}
    log("speed: training")
    speed["training"] = training_speed(speed_state, seed)
    speed_state = state = None
    lap("speed: latency and training")
    for name in ("transition_speed", "train_speed", "bvh_load"):
        if settings.bench_scripts and not splits:
            log(f"speed: bench/{name}.py")
            speed["bench"][name] = run_bench_script(name, data_dir, settings, seed, log)
        else:
            speed["bench"][name] = {"status": "skipped", "reason": "they measure bandai1, not the clips given"
                                    if splits else "--quick skips the bench/ scripts" if settings.quick
                                    else "this run left the bench/ scripts out (Settings.bench_scripts=False)"}
        lap(f"bench/{name}.py")
    results = {
        "config": {"seed": seed, **dataclasses.asdict(settings), "command": command, "n_past": N_PAST,
                   "n_future": N_FUTURE,
                   "stride": STRIDE, "cross_length": CROSS_LENGTH, "natural_frames": NATURAL_FRAMES,
                   "natural_stride_s": NATURAL_STRIDE_S, "skate_height_legs": metrics.SKATE_HEIGHT_LEGS,
                   "test_styles": list(TEST_STYLES), "test_contents": list(TEST_CONTENTS)},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "code": code},
        "holdouts": holdouts, "more_splits": more, "diagnostics": diag, "speed": speed,
        "section_seconds": sections,
    }
    results["plots"] = report.plot(results, examples, out) if settings.plots else []
    results["wall_seconds"] = time.perf_counter() - t_start
    results = round_per_window(jsonable(results))
    text, md = report.dumps(results), report.markdown(results)  # both made before either is written
    write_bytes_atomic(out / "results.json", text.encode())
    write_bytes_atomic(out / "results.md", md.encode())
    log(f"wrote {out / 'results.md'}, {out / 'results.json'} and {len(results['plots'])} plots "
        f"in {results['wall_seconds']:.0f} s")
    return results


def round_per_window(x, digits: int = 5):
    """``x`` with every list under a ``per_window`` key rounded to ``digits`` significant digits
    (the window-by-window figures are for inspection; every mean and interval is computed from
    the full values before). Keeps results.json to about a megabyte."""
    if isinstance(x, dict):
        return {k: ({m: [None if v is None else float(f"{v:.{digits}g}") for v in vals] for m, vals in v.items()}
                    if k == "per_window" else round_per_window(v, digits)) for k, v in x.items()}
    if isinstance(x, list):
        return [round_per_window(v, digits) for v in x]
    return x


def code_version() -> str | None:
    """``git describe --always --dirty`` of the repository holding this file, or None."""
    import subprocess

    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=Path(__file__).resolve().parent,
                             capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def default_data_dir() -> Path:
    """``$POSTUREMAP_DATA`` or ``../shared/data`` next to the repository."""
    env = os.environ.get("POSTUREMAP_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[4] / "shared" / "data"


def run_own(train_inputs, test_inputs, out, seed: int = 0, quick: bool = False, lengths=None, log=_log) -> dict:
    """Every method on a user's own clips (:func:`protocol.load_own`: the map and its library from
    ``train_inputs``, gaps in ``test_inputs``), scored as the bench's hold-outs are; writes
    results.md, results.json and the plots into ``out`` as :func:`run` does (no Bandai split, no
    ``bench/`` script). ``quick``: 8 seeded windows, 10 cross-clip pairs, a quarter of a MiniSom
    epoch, 100 latency calls (every training clip is used)."""
    import sys

    split = load_own(train_inputs, test_inputs, lengths, log=lambda s: print(s, file=sys.stderr))
    base = Settings.quick_run() if quick else Settings.full()
    settings = dataclasses.replace(base, holdouts=(OWN,), more_splits=(), train_stride=1, bench_scripts=False,
                                   diagnostics=False, sweep=False)
    results = run(None, out, seed=seed, settings=settings, log=log, splits={OWN: split},
                  command=" ".join(["--train", *map(str, train_inputs), "--test", *map(str, test_inputs)]
                                   + ([] if lengths is None else ["--lengths", ",".join(map(str, lengths))])))
    return results


def run_cli(args) -> int:
    """Entry point of ``posturemap bench`` (``args.quick``, ``args.data``, ``args.out``, ``args.seed``;
    ``args.train``, ``args.test`` and ``args.lengths`` for a user's own clips: :func:`run_own`)."""
    from ..errors import UserError

    if getattr(args, "train", None):
        run_own(args.train, args.test, args.out, seed=args.seed, quick=args.quick, lengths=args.lengths)
        return 0

    data = Path(args.data) if args.data else default_data_dir()
    if not (data / "bandai1").is_dir():
        raise UserError(str(data), "no bandai1/ folder of BVH clips here (set --data or POSTUREMAP_DATA)")
    if not (data / CMU_FILE).is_file():
        raise UserError(str(data), f"no {CMU_FILE.as_posix()} here (the 120 fps hold-out; "
                                   "set --data or POSTUREMAP_DATA)")
    settings = Settings.quick_run() if args.quick else Settings.full()
    run(data, args.out, seed=args.seed, settings=settings)
    return 0
