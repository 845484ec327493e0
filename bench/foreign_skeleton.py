"""Generalisation: the benchmark's hold-outs again, with every clip rewritten as another rig's.

The independent evaluation runs posturemap on clips of other skeletons and frame rates. This
script asks whether what the bench measures on Bandai's own format holds when only the format
changes: each clip of the style and content hold-outs (training and test side) is rewritten,
in memory, as

- **another naming**: Mixamo's (``mixamorig:Hips``, ``mixamorig:LeftUpLeg``, ``mixamorig:LeftLeg``,
  ``mixamorig:LeftFoot``, ...), so every joint is found by other names;
- **metres** instead of centimetres;
- **Z up** instead of Y up (the whole body turned by 90 degrees about X at the top joint);
- **60 fps** instead of 30 (every other frame SLERPed between two recorded ones);
- **three channels** (rotations only) on every joint below the hips;

then the map and its motion library are trained on the rewritten training side and the same
windows are in-betweened, at the same durations (15, 30, 45 frames at 30 fps are 30, 60, 90 at
60 fps; the 10 context frames on each side and the 40-frame stride of the protocol are frames,
so they cover half the time and give about twice the windows). Printed next to each other:
L2Q, L2P and foot skate of SLERP, the spline, inertialization and the default (``auto`` + foot
lock), each as a ratio to SLERP, and the truth's skate; and the default's time for one
in-between of 1 s in each format (median and p99 over the windows, in-process, after one
untimed call per window: at 60 fps the gap and the library hold twice the frames).

Nothing is written to disk but the report (Bandai's licence: the data stays where it is).

Usage::

    python bench/foreign_skeleton.py [--data DIR] [--doc PATH] [--json PATH] [--seed S]
"""

from __future__ import annotations

import dataclasses
import datetime
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from transition_speed import _stats, machine, machine_line, report_main  # noqa: E402

HOLDOUTS = ("style", "content")
METHODS = ("slerp", "spline", "inertialize", "auto+feet")
FPS_FACTOR = 2
TIMED_S = 1.0  # the gap (seconds, (length + 1) / fps) whose in-between is timed
TIMED_WINDOWS = 200  # at most this many windows timed per format
MIXAMO = {"joint_Root": "Reference", "Hips": "Hips", "Spine": "Spine", "Chest": "Spine2", "Neck": "Neck",
          "Head": "Head", "Shoulder_L": "LeftShoulder", "UpperArm_L": "LeftArm", "LowerArm_L": "LeftForeArm",
          "Hand_L": "LeftHand", "Shoulder_R": "RightShoulder", "UpperArm_R": "RightArm",
          "LowerArm_R": "RightForeArm", "Hand_R": "RightHand", "UpperLeg_L": "LeftUpLeg", "LowerLeg_L": "LeftLeg",
          "Foot_L": "LeftFoot", "Toes_L": "LeftToeBase", "UpperLeg_R": "RightUpLeg", "LowerLeg_R": "RightLeg",
          "Foot_R": "RightFoot", "Toes_R": "RightToeBase"}


def rewritten(m, factor: int = FPS_FACTOR):
    """A Bandai clip as the other rig: Mixamo names, metres, Z up, ``factor`` x the frame rate,
    rotation channels only below the hips (their translations: the skeleton's offsets)."""
    from posturemap.core import quat
    from posturemap.core.motion import Motion

    from posturemap.core.joints import ancestors

    sk = m.skeleton
    hips = sk.index("Hips")
    keep_pos = set(ancestors(sk.parents, hips)) | {hips}
    channels = tuple(c if j in keep_pos else tuple(x for x in c if x.endswith("rotation"))
                     for j, c in enumerate(sk.channels))
    sk2 = dataclasses.replace(sk, names=tuple("mixamorig:" + MIXAMO[n] for n in sk.names), offsets=sk.offsets / 100.0,
                              channels=channels, end_sites=tuple((j, o / 100.0) for j, o in sk.end_sites))
    turn = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.pi / 2)  # Y up -> Z up
    rots, pos = m.rotations.copy(), m.positions / 100.0
    rots[:, 0] = quat.mul(turn, rots[:, 0])
    pos[:, 0] = quat.mul_vec(turn, pos[:, 0])
    t = np.arange((len(m) - 1) * factor + 1) / factor
    i0 = np.floor(t).astype(np.int64)
    i1 = np.minimum(i0 + 1, len(m) - 1)
    f = t - i0
    rots = quat.slerp(rots[i0], rots[i1], f[:, None])
    pos = pos[i0] + f[:, None, None] * (pos[i1] - pos[i0])
    for j in range(sk.num_joints):
        if j not in keep_pos:
            pos[:, j] = sk2.offsets[j]
    return Motion(sk2, rots, pos, m.fps * factor)


def rewritten_split(split):
    """The hold-out with every clip :func:`rewritten` and the lengths scaled to the new rate."""
    from posturemap.evaluate.protocol import unit_cm

    test = [rewritten(m) for m in split.test]
    cm, unit = unit_cm(test[0])
    return dataclasses.replace(split, train=[rewritten(m) for m in split.train], test=test,
                               lengths=tuple(FPS_FACTOR * n for n in split.lengths), cm=cm, unit=unit)


def inbetween(split, settings, seed: int, lengths, log=print) -> dict:
    """L2Q, L2P, skate per method and length, and the truth's skate (the bench's scoring)."""
    from posturemap.evaluate import protocol, runner, scoring

    t0 = time.perf_counter()
    state = runner.prepare(split, settings, seed, log=lambda *a: None)
    windows = protocol.make_windows(state, settings, seed)
    ctx, test = state["ctx"], state["test"]
    engines = runner.empty_engines(state)
    out = {"windows": len(windows), "fps": float(test[0].fps), "unit": split.unit,
           "joints": len(ctx.skeleton.names), "up": "XYZ"[ctx.up], "lengths": {}}
    for length in lengths:
        truth_r, truth_p, preds = runner.predict_windows(engines, METHODS, test, windows, length)
        tg = scoring.truth_globals(ctx, truth_r, truth_p)
        row = {"truth_skate": scoring.score_truth(ctx, truth_r, truth_p, length)["skate"]}
        for m in METHODS:
            sc = scoring.score_inbetween(ctx, truth_r, truth_p, *preds[m], length, truth_g=tg)
            row[m] = {k: sc[k] for k in ("l2q", "l2p", "skate")}
        out["lengths"][str(length)] = row
    out["time"] = time_default(engines, test, windows, round(TIMED_S * out["fps"]) - 1)
    log(f"  {split.name} at {out['fps']:.4g} fps ({split.unit}): {len(windows)} windows in "
        f"{time.perf_counter() - t0:.0f} s")
    return out


def time_default(engines, test, windows, length: int) -> dict:
    """Median and p99 (us, :func:`transition_speed._stats`) of one default in-between (``auto`` + foot lock) of ``length``
    frames from the protocol's context of up to :data:`TIMED_WINDOWS` windows, each timed on its
    second call (the first loads what it needs)."""
    from posturemap.evaluate import runner
    from posturemap.evaluate.protocol import N_FUTURE, N_PAST

    eng, base, feet = runner.engine_call(engines, "auto+feet")
    span = N_PAST + length + N_FUTURE
    times = []
    for c, s in windows[:TIMED_WINDOWS]:
        if s + span > len(test[c]):
            continue
        past, future = test[c][s: s + N_PAST], test[c][s + N_PAST + length: s + span]
        with runner.clips_in(engines, {"_past": past, "_future": future}):
            for timed in (False, True):
                t0 = time.perf_counter_ns()
                eng.generate("_past", "_future", length=length, a_end=len(past) - 1, b_start=0, align=False,
                             method=base, foot_lock=feet)
                if timed:
                    times.append(time.perf_counter_ns() - t0)
    return {"length": length, **_stats(times)}


def run(data_dir: Path, seed: int = 0, log=print) -> dict:
    from posturemap.core import kernels
    from posturemap.evaluate.protocol import Settings, load_split

    kernels.compiled()
    settings = dataclasses.replace(Settings.full(), som_epochs=0.25)
    result = {"holdouts": {}, "date": datetime.date.today().isoformat(), "machine": machine()}
    for name in HOLDOUTS:
        split = load_split(name, data_dir, settings)
        other = rewritten_split(split)
        result["holdouts"][name] = {"bandai": inbetween(split, settings, seed, split.lengths[1:], log),
                                    "rewritten": inbetween(other, settings, seed, other.lengths[1:], log)}
    return result


def markdown(result: dict, command: str) -> str:
    lines = []
    for name, both in result["holdouts"].items():
        b, r = both["bandai"], both["rewritten"]
        lines += [f"**{name.capitalize()} hold-out**: Bandai's format ({b['joints']} joints, {b['fps']:.4g} fps, "
                  f"{b['unit']}, {b['up']} up, {b['windows']} windows) against the rewritten clips "
                  f"({r['fps']:.4g} fps, {r['unit']}, {r['up']} up, {r['windows']} windows). Ratios to SLERP; "
                  "skate in cm/s with the truth's.", "",
                  "| duration | format | " + " | ".join(f"{m} L2Q / L2P" for m in METHODS[1:])
                  + " | SLERP L2Q / L2P | skate: default / truth |",
                  "| --- | --- | " + " | ".join("---:" for _ in METHODS[1:]) + " | ---: | ---: |"]
        for (lb, rb), (lr, rr) in zip(b["lengths"].items(), r["lengths"].items()):
            for label, length, row in (("Bandai", lb, rb), ("rewritten", lr, rr)):
                sl = row["slerp"]
                cells = [f"{row[m]['l2q'] / sl['l2q']:.2f}x / {row[m]['l2p'] / sl['l2p']:.2f}x" for m in METHODS[1:]]
                lines.append(f"| {int(length) / (b['fps'] if label == 'Bandai' else r['fps']):.2f} s | {label} "
                             f"({length} frames) | " + " | ".join(cells)
                             + f" | {sl['l2q']:.3f} / {sl['l2p']:.3f} | {row['auto+feet']['skate']:.2f} / "
                             f"{row['truth_skate']:.2f} |")
        lines.append("")
        tb, tr = b["time"], r["time"]
        lines += [f"Time of one default in-between of {(tb['length'] + 1) / b['fps']:.2f} s (in-process, median / "
                  f"p99 over {tb['calls']} and {tr['calls']} windows): Bandai's format ({tb['length']} frames) "
                  f"{tb['median_us'] / 1e3:.2f} / {tb['p99_us'] / 1e3:.2f} ms, rewritten ({tr['length']} frames) "
                  f"{tr['median_us'] / 1e3:.2f} / {tr['p99_us'] / 1e3:.2f} ms.", ""]
    lines.append(machine_line(result, command))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    return report_main(__doc__, "Another rig: the hold-outs rewritten", "python bench/foreign_skeleton.py", run, markdown, argv)


if __name__ == "__main__":
    raise SystemExit(main())
