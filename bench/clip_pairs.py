"""Transitions between every two clips of a folder, any rig and frame rate: joint pops and feet under the floor.

The bench's hold-outs and ``transition_feet.py`` measure Bandai's clips at 30 fps. An independent
evaluation joins clips of other rigs at other rates (CMU-rig walks at 30, 60 and 120 fps found the
foot lock's knees popping and, at 120 fps, toes 7-18 cm under the floor). This script joins every
ordered pair of a folder's clips (A to its end, B from its start, placed to continue A; or ``--pairs``
seeded draws of seams), at each gap length in seconds, and measures per method:

- **pops**: each transition's largest joint acceleration (second difference of the global
  positions) over A's last two frames, the new frames and B's first three, over the larger of the
  two clips' own largest; the transitions where it exceeds 1.5 and 3, and the largest;
- **under the floor**: how far the lowest foot joint goes in the new frames under the lowest foot
  joint of A's last and B's first 0.5 s (the floor the two clips stand on), in cm: the mean, the
  transitions deeper than 5 cm, the deepest.

Methods: the default (``auto`` + foot lock), the default without the lock, SLERP + foot lock and
SLERP. The map (with its motion library) is ``--map``'s, or trained on ``--train``'s clips (default
parameters, ``--seed``), or on the folder's own clips. Nothing is copied: the clips are read where
they are.

Usage::

    python bench/clip_pairs.py --clips DIR [--map MAP | --train DIR] [--seconds 0.5,1] [--pairs N]
                               [--json PATH] [--doc PATH] [--seed S]
"""

from __future__ import annotations

import datetime
import itertools
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from transition_speed import machine, machine_line, report_parser, save_outputs  # noqa: E402

METHODS = (("auto", True), ("auto", False), ("slerp", True), ("slerp", False))
POP = (1.5, 3.0)  # a transition pops where its largest joint acceleration is this many times the clips'
DEEP_CM = 5.0  # a foot deeper than this under the clips' floor is counted
FLOOR_S = 0.5  # the floor: the lowest foot joint of A's last and B's first this many seconds


def label(method: str, feet: bool) -> str:
    return method + ("+feet" if feet else "")


def largest_acceleration(motion) -> float:
    """The largest second difference of any joint's global position over the clip's frames."""
    g = motion.global_positions()
    return float(np.linalg.norm(np.diff(g, 2, axis=0), axis=-1).max()) if len(g) > 2 else 0.0


def measure_pair(engine, a: str, b: str, clip_a, clip_b, a_end: int, b_start: int, length: int, own: float,
                 feet, up: int, cm: float) -> dict:
    """Each method's pop ratio and depth under the floor (cm) of one transition: ``{label: (ratio, depth)}``."""
    from posturemap.core.motion import Motion, concatenate

    span = max(1, round(FLOOR_S * clip_a.fps))
    floor = min(clip_a.global_positions()[max(0, a_end + 1 - span): a_end + 1][:, feet, up].min(),
                clip_b.global_positions()[b_start: b_start + span][:, feet, up].min())
    out = {}
    for m, f in METHODS:
        rots, pos = engine.generate(a, b, length=length, a_end=a_end, b_start=b_start, method=m, foot_lock=f)
        new = Motion(clip_a.skeleton, rots.copy(), pos.copy(), clip_a.fps)
        joined = concatenate([clip_a[max(0, a_end - 1): a_end + 1], new, engine.continuation(b, b_start)[:3]])
        ratio = largest_acceleration(joined) / max(own, 1e-12)
        depth = max(0.0, floor - float(new.global_positions()[:, feet, up].min())) * cm
        out[label(m, f)] = (ratio, depth)
    return out


def summary(rows: list) -> dict:
    ratios = np.array([r for r, _ in rows])
    depths = np.array([d for _, d in rows])
    return {"pairs": len(rows), "pops": int((ratios > POP[0]).sum()), "big_pops": int((ratios > POP[1]).sum()),
            "largest": float(ratios.max()), "depth_mean_cm": float(depths.mean()),
            "deep": int((depths > DEEP_CM).sum()), "deepest_cm": float(depths.max())}


def run(clips_dir: Path, map_path=None, train_dir=None, seconds=(0.5, 1.0), pairs: int | None = None,
        seed: int = 0, log=print) -> dict:
    from posturemap.core import kernels
    from posturemap.core.joints import foot_joints
    from posturemap.core.motion import up_axis
    from posturemap.evaluate.protocol import unit_cm
    from posturemap.io import bvh
    from posturemap.learn.model import PostureMap
    from posturemap.synth.engine import TransitionEngine

    kernels.compiled()
    files = sorted(Path(clips_dir).glob("*.bvh"))
    if len(files) < 2:
        raise FileNotFoundError(f"{clips_dir}: fewer than two .bvh clips")
    clips = {f.stem: bvh.read(f) for f in files}
    first = next(iter(clips.values()))
    t0 = time.perf_counter()
    if map_path:
        model = PostureMap.load(map_path)
        trained_on = str(map_path)
    else:
        source = sorted(Path(train_dir).glob("*.bvh")) if train_dir else files
        model = PostureMap(seed=seed).fit([bvh.read(f) for f in source], [f.stem for f in source])
        trained_on = f"{len(source)} clips of {train_dir or clips_dir}"
        log(f"map and library of {len(source)} clips in {time.perf_counter() - t0:.0f} s")
    engine = TransitionEngine(model)
    for n, m in clips.items():
        engine.add(n, m)
    feet = foot_joints(first.skeleton.names)
    up, fps, cm = up_axis(first), float(first.fps), unit_cm(first)[0]
    own = {n: largest_acceleration(m) for n, m in clips.items()}
    rng = np.random.default_rng(seed)
    ordered = list(itertools.permutations(clips, 2))
    if pairs is None:
        draws = [(a, b, len(clips[a]) - 1, 0) for a, b in ordered]
    else:
        draws = []
        for _ in range(pairs):
            a, b = ordered[int(rng.integers(len(ordered)))]
            draws.append((a, b, int(rng.integers(len(clips[a]))), int(rng.integers(len(clips[b])))))
    result = {"date": datetime.date.today().isoformat(), "machine": machine(), "seed": seed,
              "clips": len(clips), "folder": str(clips_dir), "map": trained_on, "fps": fps,
              "joints": first.skeleton.num_joints, "transitions": len(draws), "seams": "ends" if pairs is None
              else "seeded", "lengths": {}}
    for s in seconds:
        length = max(1, round(s * fps))
        rows = {label(m, f): [] for m, f in METHODS}
        worst = []
        for a, b, a_end, b_start in draws:
            got = measure_pair(engine, a, b, clips[a], clips[b], a_end, b_start, length, max(own[a], own[b]),
                               feet, up, cm)
            for k, v in got.items():
                rows[k].append(v)
            worst.append((got["auto+feet"][0], got["auto+feet"][1], a, b, a_end, b_start))
        worst.sort(key=lambda w: -w[0])
        result["lengths"][str(length)] = {"seconds": s, "methods": {k: summary(v) for k, v in rows.items()},
                                          "worst": [list(w) for w in worst[:5]]}
        log(f"{s} s ({length} frames): " + ", ".join(f"{k} {summary(v)['pops']} pops, {summary(v)['deep']} deep"
                                                    for k, v in rows.items()))
    return result


def markdown(result: dict, command: str) -> str:
    seams = ("A's last frame into B's first" if result["seams"] == "ends"
             else "seams drawn at random in both clips")
    lines = [f"{result['transitions']} transitions between the {result['clips']} clips of `{result['folder']}` "
             f"({result['joints']} joints, {result['fps']:g} fps; {seams}, B placed to continue A); map and "
             f"library: {result['map']}. Pops: transitions whose largest joint acceleration is over "
             f"{POP[0]:g}x (and {POP[1]:g}x) the two clips' own largest. Under the floor: the lowest foot joint of "
             f"the new frames under the lowest of A's last and B's first {FLOOR_S:g} s, in cm.", ""]
    for length, row in result["lengths"].items():
        lines += [f"**{row['seconds']:g} s ({length} frames)**", "",
                  f"| method | pops > {POP[0]:g}x | > {POP[1]:g}x | largest | under the floor, mean cm | "
                  f"> {DEEP_CM:g} cm | deepest cm |", "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
        for k, s in row["methods"].items():
            lines.append(f"| {k} | {s['pops']} | {s['big_pops']} | {s['largest']:.2f}x | {s['depth_mean_cm']:.2f} | "
                         f"{s['deep']} | {s['deepest_cm']:.1f} |")
        lines.append("")
    lines.append(machine_line(result, command))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = report_parser(__doc__.split("\n")[0], data=False)
    p.add_argument("--clips", required=True, help="folder of .bvh clips (one rig and rate) to join")
    p.add_argument("--map", default=None, help="map file (with its motion library) to use")
    p.add_argument("--train", default=None, help="folder of .bvh clips to train the map on (default: --clips)")
    p.add_argument("--seconds", default="0.5,1", help="gap lengths in seconds, comma-separated (0.5,1)")
    p.add_argument("--pairs", type=int, default=None, help="seeded draws of pairs and seams instead of every "
                                                           "ordered pair joined at A's end and B's start")
    args = p.parse_args(argv)
    seconds = tuple(float(s) for s in args.seconds.split(","))
    result = run(Path(args.clips), args.map, args.train, seconds, args.pairs, args.seed)
    md = markdown(result, "python bench/clip_pairs.py " + " ".join(argv if argv is not None else sys.argv[1:]))
    print(md)
    save_outputs(result, md, args.json, args.doc, "Transitions between any clips: joint pops and feet under the "
                 "floor", __doc__)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
