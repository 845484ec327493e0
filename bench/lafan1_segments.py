"""Generalisation: other performers, another rig, 60 fps: LaFAN1's motion cut into segments.

The independent evaluation runs posturemap on clips of other contents, styles, skeletons and
frame rates. The bench's hold-outs split Bandai's dataset, ``other_dataset.py`` takes Bandai's
second one (the same rig), ``foreign_skeleton.py`` rewrites Bandai's clips as another rig's.
This script takes other people's motion on another rig: Ubisoft La Forge's LaFAN1 (Harvey et
al. 2020; five performers; CC BY-NC-ND 4.0), as a motion-matching course project published it
(https://github.com/karstm/motion-matching, ``data/mocap/lafan1_filtered_60fps``): 153 segments
cut from the takes (walks, jogs, runs, sidesteps, backward walks, stumbles, jumps, dance...),
filtered, resampled to 60 fps, each with a ``SimulationBone`` root on the
ground above the hips (23 joints, centimetres, Y up); and each segment mirrored, which this
script skips (``*_mirror_filtered.bvh``: mirror images are not other motion). These are not the
original takes, so the standard LaFAN1 benchmark (windows of subject 5's whole takes at 30 fps)
cannot be run from them, and its published figures are not comparable with these.

The map and its motion library are trained on every segment of subjects 1-4 (the bench's
settings and seed); gaps are made in subject 5's segments (``--test-subject``), as the bench
does (10 past and 10 future frames of context, windows every 40 frames, at the bench's
durations: 5, 15, 30 and 45 frames at 30 fps, that is 10, 30, 60 and 90 at 60). It runs at the
segments' own 60 fps and again with every segment resampled to 30 fps and to film's 24 fps
(``--fps``; the durations' frames rounded at 24: 4, 12, 24 and 36). Printed
next to each other: L2Q, L2P, NPSS and MPJPE of SLERP, the spline, inertialization, ``damped``,
the paper's ``upm``, the previous default (``upm-valid`` + foot lock) and the default (``auto``
+ foot lock), every method's foot skate with the truth's, and the default per motion (the
theme of the take and the segment's label); in a last column the default again given the whole
segment but the gap as context (a gap in a take), where it also replays the segment's own
motion.

Nothing is copied: the files are read where they are (the licence forbids sharing changes).

Usage::

    python bench/lafan1_segments.py --lafan DIR [--test-subject subject5] [--fps native,30,24] [--doc PATH] [--json PATH] [--seed S]
"""

from __future__ import annotations

import dataclasses
import datetime
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from other_dataset import scored_lengths, score_tables  # noqa: E402
from transition_speed import machine, machine_line, report_parser, save_outputs  # noqa: E402

LENGTHS = (5, 15, 30, 45)  # the bench's gaps, frames at 30 fps (as many times more at another rate)
PER_CONTENT = (30, 45)  # the per-motion tables' (1 and 1.5 s)
NAME = re.compile(r"^(?P<theme>[A-Za-z]+)(?P<take>\d+)_(?P<subject>subject\d+)_(?P<label>.+?)_filtered$")


def segment_files(directory: Path) -> list[tuple[Path, str, str]]:
    """The segments of ``directory``: ``(path, subject, motion)`` sorted by name, ``motion`` the
    take's theme and the segment's label without its number (``"walk: walk"``, ``"jumps: big"``).
    Mirrored copies (``*_mirror_filtered.bvh``) and files not named so are left out."""
    out = []
    for f in sorted(Path(directory).glob("*.bvh")):
        m = NAME.match(f.stem)
        if m is None or m["label"].endswith("_mirror"):
            continue
        out.append((f, m["subject"], f"{m['theme']}: {re.sub(r'[0-9]+$', '', m['label'])}"))
    return out


def load(directory: Path, test_subject: str, fps: float | None):
    """The split: training = every segment not of ``test_subject``, test = its segments, all at
    ``fps`` (None: as recorded)."""
    from posturemap.core.motion import resample
    from posturemap.evaluate.protocol import Split, unit_cm
    from posturemap.io import bvh

    files = segment_files(directory)
    train_f = [f for f, s, _ in files if s != test_subject]
    test = [(f, k) for f, s, k in files if s == test_subject]
    if not train_f or not test:
        raise FileNotFoundError(f"{directory}: no <theme><take>_<subject>_<label>_filtered.bvh files of "
                                f"{test_subject} and of other subjects")
    at = (lambda m: m) if fps is None else (lambda m: resample(m, fps))
    train = [at(bvh.read(f)) for f in train_f]
    test_m = [at(bvh.read(f)) for f, _ in test]
    rate = float(test_m[0].fps)
    lengths = tuple(round(n * rate / 30.0) for n in LENGTHS)
    cm, unit = unit_cm(test_m[0])
    return Split("lafan1-segments", f"training = the segments of the other subjects; test = {test_subject}'s",
                 train, [f.name for f in train_f], test_m, [f.name for f, _ in test], [k for _, k in test],
                 lengths, cm, unit, len(train))


def evaluate(split, seed: int, log=print) -> dict:
    """Every method's scores at each of the split's lengths, the truth's skate, the default per motion."""
    from posturemap.evaluate import protocol, runner

    settings = dataclasses.replace(protocol.Settings.full(), som_epochs=0.25)
    t0 = time.perf_counter()
    # The posture map alone: no method here uses the classic SOM (MiniSom takes many minutes over
    # 100,000 frames), and no pose-validity index (its nearest-neighbour queries in the postures'
    # dimensions take about a minute per method and length there; this report has no validity).
    state = runner.prepare(split, settings, seed, log=lambda *a: None, full=False)
    windows = protocol.make_windows(state, settings, seed)
    test = state["test"]
    kinds = np.array([split.contents[c] for c, _ in windows])
    rate = float(test[0].fps)
    lib = state["model"].library_
    out = {"fps": rate, "joints": len(state["ctx"].skeleton.names), "train_clips": len(split.train),
           "train_frames": int(sum(len(m) for m in split.train)), "clips": len(test), "windows": len(windows),
           "contents": {k: int((kinds == k).sum()) for k in sorted(set(kinds))},
           "clearance": None if lib.clearance is None else [round(float(x), 4) for x in lib.clearance],
           "lengths": scored_lengths(state, windows, kinds, split.lengths,
                                     {round(n * rate / 30.0) for n in PER_CONTENT})}
    log(f"lafan1 segments at {rate:.4g} fps: {len(test)} test segments, {len(windows)} windows in "
        f"{time.perf_counter() - t0:.0f} s")
    return out


def run(directory: Path, test_subject: str = "subject5", rates=(None, 30.0), seed: int = 0, log=print) -> dict:
    from posturemap.core import kernels

    kernels.compiled()
    result = {"date": datetime.date.today().isoformat(), "machine": machine(), "seed": seed,
              "test_subject": test_subject, "rates": []}
    for fps in rates:
        result["rates"].append(evaluate(load(directory, test_subject, fps), seed, log))
    return result


def markdown(result: dict, command: str) -> str:
    lines = []
    for res in result["rates"]:
        rate = res["fps"]
        lines += [f"## At {rate:.4g} fps", "",
                  f"{res['clips']} test segments of {result['test_subject']}, {res['windows']} windows; library: "
                  f"the other subjects' {res['train_clips']} segments ({res['train_frames']} frames; their toes' "
                  f"clearance by speed, leg lengths: {res['clearance']}). Gaps of "
                  + ", ".join(f"{length} frames ({int(length) / rate:.2f} s)" for length in res["lengths"])
                  + ". Ratios to SLERP (lower is better); SLERP's own value in its column.", ""]
        lines += score_tables(res["lengths"], res["contents"], "motion")
    lines.append(machine_line(result, command))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = report_parser(__doc__.split("\n")[0])
    p.add_argument("--lafan", required=True, help="directory of the segments' BVH files (lafan1_filtered_60fps)")
    p.add_argument("--test-subject", default="subject5", help="the performer whose segments get the gaps")
    p.add_argument("--fps", default="native,30,24", help="comma-separated rates: 'native' (as recorded) or fps")
    args = p.parse_args(argv)
    rates = tuple(None if r.strip() == "native" else float(r) for r in args.fps.split(","))
    result = run(Path(args.lafan), args.test_subject, rates, args.seed)
    md = markdown(result, f"python bench/lafan1_segments.py --lafan DIR --test-subject {args.test_subject} "
                          f"--fps {args.fps} --seed {args.seed}")
    print(md)
    save_outputs(result, md, args.json, args.doc, "Other performers on another rig: LaFAN1's segments", __doc__)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
