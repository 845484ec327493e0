"""Feet in transitions between different clips: foot skate where no truth exists.

The bench's hold-outs in-between gaps cut out of real clips, where the truth's own skate is the
reference. A user's transition joins two different clips (B moved and turned to continue A),
and the feet of the two clips stand in different places: the retrieved segments, their splice
and the foot lock must carry the body from one stance to the other without sliding a foot
along the floor. This script measures that on seeded draws of two different clips of bandai1
(seams anywhere in them, ``alpha`` drawn too, as ``bench/retrieval_speed.py`` draws them), the
map and its motion library trained on every clip (default parameters, seed 0 or ``--seed``):

- the height-weighted foot skate (``posturemap.evaluate.metrics.weighted_skate``: each foot
  joint's horizontal speed weighted by its closeness to the window's lowest foot joint, no
  contact detection) over A's last frame, the new frames and B's first frame, in cm/s;
- per method: the default (``auto`` + foot lock), the previous default (``upm-valid`` + foot
  lock), SLERP, the spline and inertialization (without the lock, as the bench's baselines);
- next to them, the real motion's own skate: seeded windows of the same number of frames cut
  from the same clips (as many draws; a clip shorter than the window gives none);
- mean, median, p90, p99 and the largest over the draws: a foot that slides 30 cm in one
  transition of a hundred shows at the p99, not in the mean.

Nothing is copied: the clips are read where they are (Bandai's licence).

Usage::

    python bench/transition_feet.py [--quick] [--data DIR] [--json PATH] [--doc PATH] [--seed S]
"""

from __future__ import annotations

import datetime
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from transition_speed import _draws, default_data_dir, machine, machine_line, report_parser, save_outputs  # noqa: E402

METHODS = (("auto", True), ("upm-valid", True), ("slerp", False), ("spline", False), ("inertialize", False))
LENGTHS = (15, 30, 45)
DRAWS = 300


def label(method: str, feet: bool) -> str:
    return method + ("+feet" if feet else "")


def skate_of(motion_rots, motion_pos, sk, feet_joints, fps: float, up: int, height: float, cm: float) -> float:
    """The height-weighted skate (cm/s) of one stretch of frames (local rotations and translations)."""
    from posturemap.core.skeleton import fk
    from posturemap.evaluate import metrics

    _, g = fk(sk.parents, motion_rots, motion_pos)
    return float(metrics.weighted_skate(g[None, :, feet_joints], fps, up, height)[0]) * cm


def summary(values) -> dict:
    v = np.asarray(values, dtype=float)
    return {"mean": float(v.mean()), "median": float(np.median(v)), "p90": float(np.percentile(v, 90)),
            "p99": float(np.percentile(v, 99)), "max": float(v.max()), "count": int(len(v))}


def measure(engine, names, clips, lengths, draws: int, rng, cm: float) -> dict:
    """Per gap length, the skate summary of every method over the same seeded draws, and of the
    real clips' own windows of the same length: ``{length: {label: summary}}``."""
    from posturemap.core.joints import leg_chains, leg_length, leg_toes
    from posturemap.evaluate import metrics

    sk, up = engine.skeleton, engine._up
    chains = leg_chains(sk)
    feet_joints = np.array([c[2] for c in chains] + leg_toes(sk, chains).tolist())
    height = metrics.SKATE_HEIGHT_LEGS * leg_length(sk, chains)
    fps = clips[0].fps
    out = {}
    for length in lengths:
        row = {label(m, f): [] for m, f in METHODS}
        for a, b, a_end, b_start, alpha in _draws(rng, [len(m) for m in clips], draws):
            for m, f in METHODS:
                rots, pos = engine.generate(names[a], names[b], length=length, alpha=alpha, a_end=a_end,
                                            b_start=b_start, method=m, foot_lock=f)
                # A's last frame, the new frames, B's first (placed as the transition placed it).
                b_first = engine.continuation(names[b], b_start, True)[:1]
                r = np.concatenate([clips[a].rotations[a_end: a_end + 1], rots, b_first.rotations])
                p = np.concatenate([clips[a].positions[a_end: a_end + 1], pos, b_first.positions])
                row[label(m, f)].append(skate_of(r, p, sk, feet_joints, fps, up, height, cm))
        real = []
        for _ in range(draws):
            c = int(rng.integers(len(clips)))
            if len(clips[c]) < length + 2:
                continue
            s = int(rng.integers(len(clips[c]) - length - 1))
            m = clips[c]
            real.append(skate_of(m.rotations[s: s + length + 2], m.positions[s: s + length + 2], sk, feet_joints,
                                 fps, up, height, cm))
        out[str(length)] = {k: summary(v) for k, v in row.items()} | {"real clips": summary(real)}
    return out


def run(data_dir: Path, quick: bool = False, seed: int = 0, log=print) -> dict:
    from posturemap.core import kernels
    from posturemap.evaluate.protocol import unit_cm
    from posturemap.io import bvh
    from posturemap.learn.model import PostureMap
    from posturemap.synth.engine import TransitionEngine

    kernels.compiled()
    files = sorted((Path(data_dir) / "bandai1").glob("*.bvh"))
    if not files:
        raise FileNotFoundError(str(Path(data_dir) / "bandai1"))
    if quick:
        files = files[::12]
    names = [f.stem for f in files]
    clips = [bvh.read(f) for f in files]
    t0 = time.perf_counter()
    model = PostureMap(seed=seed).fit(clips, names)
    log(f"map and library of {len(clips)} clips in {time.perf_counter() - t0:.0f} s")
    engine = TransitionEngine(model)
    for n, m in zip(names, clips):
        engine.add(n, m)
    draws = 20 if quick else DRAWS
    lengths = (30,) if quick else LENGTHS
    t0 = time.perf_counter()
    rows = measure(engine, names, clips, lengths, draws, np.random.default_rng(seed), unit_cm(clips[0])[0])
    result = {"date": datetime.date.today().isoformat(), "machine": machine(), "seed": seed, "clips": len(clips),
              "draws": draws, "fps": clips[0].fps, "lengths": rows}
    log(f"{draws} draws per length in {time.perf_counter() - t0:.0f} s")
    return result


def markdown(result: dict, command: str) -> str:
    lines = [f"{result['draws']} seeded transitions per gap length between two different clips of the "
             f"{result['clips']} (B placed to continue A); map and library of every clip. Height-weighted foot "
             "skate in cm/s over A's last frame, the new frames and B's first; the real clips' row: seeded windows "
             "of the same number of frames cut from the clips themselves (as many draws; a clip shorter than the "
             "window gives none).", ""]
    for length, row in result["lengths"].items():
        seconds = int(length) / result["fps"]
        lines += [f"**{length} frames ({seconds:.2f} s)**", "", "| method | mean | median | p90 | p99 | max |",
                  "| --- | ---: | ---: | ---: | ---: | ---: |"]
        for k, s in row.items():
            lines.append(f"| {k} | {s['mean']:.2f} | {s['median']:.2f} | {s['p90']:.2f} | {s['p99']:.2f} | "
                         f"{s['max']:.2f} |")
        lines.append("")
    lines.append(machine_line(result, command))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = report_parser(__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="every twelfth clip, 20 draws, 30 frames only")
    args = p.parse_args(argv)
    result = run(Path(args.data) if args.data else default_data_dir(), args.quick, args.seed)
    md = markdown(result, "python bench/transition_feet.py" + (" --quick" if args.quick else "")
                  + (f" --seed {args.seed}" if args.seed else ""))
    print(md)
    save_outputs(result, md, args.json, args.doc, "Feet in transitions between clips", __doc__)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
