"""Generalisation: a library of all of bandai1, gaps in clips of Bandai's second dataset.

The independent evaluation runs posturemap on clips it never saw, of other contents and
styles. The bench's hold-outs split one dataset; this script takes a second one. Bandai Namco
Research's Motiondataset-2 (2,902 clips, the same 22-joint skeleton at 30 fps, CC BY-NC 4.0,
https://github.com/BandaiNamcoResearchInc/Bandai-Namco-Research-Motiondataset) has ten
contents: walk, walk-turn-left, walk-turn-right, run, wave-both-hands, wave-left-hand,
wave-right-hand, raise-up-both-hands, raise-up-left-hand, raise-up-right-hand. bandai1 has
walks and runs but no walking turns, waves in its own way (byebye, bye) and no raised hands.
Its seven styles are active, elderly, exhausted, feminine, masculine, normal and youthful.

The map and its motion library are trained on every clip of bandai1 (the bench's settings and
seed). The test clips are drawn with the seed from a directory of dataset-2's BVH files, the
same number from each (content, style) cell (``--per-cell``, 2 by default: 140 clips), and
in-betweened as the bench does (10 past and 10 future frames of context, windows every 40
frames, the gap's length 5 to 45 frames). Printed next to each other: L2Q, L2P, NPSS and MPJPE
of SLERP, the spline, inertialization, ``damped``, the paper's ``upm``, the previous default
(``upm-valid`` + foot lock) and the default (``auto`` + foot lock), the default's and SLERP's
foot skate with the truth's, and the default per content; in a last column the default again
given the whole clip but the gap as context (a gap in a take: A the clip up to the last past
frame, B from the first future frame), where it also replays the clip's own motion.

Nothing is copied: the clips are read where they are (Bandai's licence).

Usage::

    python bench/other_dataset.py --other DIR [--data DIR] [--per-cell N] [--doc PATH] [--json PATH] [--seed S]
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
from transition_speed import default_data_dir, machine, machine_line, report_parser, save_outputs  # noqa: E402

METHODS = ("slerp", "spline", "inertialize", "damped", "upm", "upm-valid+feet", "auto+feet")
DEFAULT = "auto+feet"
# The default again with the whole test clip but the gap as context (a gap in a take: A the clip
# up to the last past frame, B from the first future frame; posturemap.evaluate.predict_whole_clip).
WHOLE = "auto+feet, whole clip"
LENGTHS = (5, 15, 30, 45)
PER_CONTENT = (30, 45)  # lengths of the per-content table
NAME = re.compile(r"^dataset-2_(?P<content>[^_]+)_(?P<style>[^_]+)_(?P<id>\d+)$")


def sample_files(directory: Path, per_cell: int, seed: int) -> list[tuple[Path, str, str]]:
    """``per_cell`` files of each (content, style) cell of ``directory``, drawn with ``seed``:
    ``(path, content, style)`` sorted by name. Files not named as dataset-2's are ignored."""
    cells: dict[tuple[str, str], list[Path]] = {}
    for f in sorted(Path(directory).glob("*.bvh")):
        m = NAME.match(f.stem)
        if m:
            cells.setdefault((m["content"], m["style"]), []).append(f)
    rng = np.random.default_rng(seed)
    out = []
    for (content, style), files in sorted(cells.items()):
        pick = rng.choice(len(files), size=min(per_cell, len(files)), replace=False)
        out += [(files[i], content, style) for i in sorted(pick)]
    return sorted(out)


def load(data_dir: Path, other: Path, per_cell: int, seed: int):
    """The split: training = every clip of bandai1, test = :func:`sample_files` of ``other``."""
    from posturemap.evaluate.protocol import Split, unit_cm
    from posturemap.io import bvh

    train_f = sorted((Path(data_dir) / "bandai1").glob("*.bvh"))
    if not train_f:
        raise FileNotFoundError(str(Path(data_dir) / "bandai1"))
    picked = sample_files(other, per_cell, seed)
    if not picked:
        raise FileNotFoundError(f"{other}: no dataset-2_<content>_<style>_<id>.bvh file")
    train = [bvh.read(f) for f in train_f]
    test = [bvh.read(f) for f, _, _ in picked]
    cm, unit = unit_cm(test[0])
    return Split("dataset-2", f"training = every clip of bandai1; test = {per_cell} clips per content and style of "
                 f"{Path(other).name}", train, [f.name for f in train_f], test, [f.name for f, _, _ in picked],
                 [c for _, c, _ in picked], LENGTHS, cm, unit, len(train_f))


def run(data_dir: Path, other: Path, per_cell: int = 2, seed: int = 0, log=print) -> dict:
    from posturemap.core import kernels
    from posturemap.evaluate import protocol, runner

    kernels.compiled()
    settings = dataclasses.replace(protocol.Settings.full(), som_epochs=0.25)
    split = load(data_dir, other, per_cell, seed)
    t0 = time.perf_counter()
    state = runner.prepare(split, settings, seed, log=lambda *a: None)
    windows = protocol.make_windows(state, settings, seed)
    test = state["test"]
    kinds = np.array([split.contents[c] for c, _ in windows])
    result = {"date": datetime.date.today().isoformat(), "machine": machine(), "seed": seed,
              "per_cell": per_cell, "clips": len(test), "train_clips": len(split.train), "windows": len(windows),
              "contents": {k: int((kinds == k).sum()) for k in sorted(set(kinds))},
              "lengths": scored_lengths(state, windows, kinds, LENGTHS, PER_CONTENT)}
    log(f"dataset-2: {len(test)} clips, {len(windows)} windows in {time.perf_counter() - t0:.0f} s")
    return result


def scored_lengths(state: dict, windows, kinds: np.ndarray, lengths, per_content) -> dict:
    """Each length's scores (``{str(length): row}``) of :data:`METHODS` on ``windows`` of
    ``state`` (:func:`posturemap.evaluate.runner.prepare`): L2Q, L2P, NPSS, MPJPE and skate per
    method and the truth's skate; at the lengths in ``per_content`` also per motion (``kinds``,
    one per window): SLERP's, the spline's, ``damped``'s and the default's accuracy and skate."""
    from posturemap.evaluate import runner, scoring

    ctx, test = state["ctx"], state["test"]
    engines = runner.empty_engines(state)
    out = {}
    for length in lengths:
        truth_r, truth_p, preds = runner.predict_windows(engines, METHODS, test, windows, length)
        preds[WHOLE] = runner.predict_whole_clip(state["model"], test, windows, length)[0][DEFAULT]
        tg = scoring.truth_globals(ctx, truth_r, truth_p)
        row = {"truth_skate": scoring.score_truth(ctx, truth_r, truth_p, length)["skate"]}
        for m in METHODS + (WHOLE,):
            sc = scoring.score_inbetween(ctx, truth_r, truth_p, *preds[m], length, truth_g=tg)
            row[m] = {k: sc[k] for k in ("l2q", "l2p", "npss", "mpjpe_cm", "skate")}
        if length in per_content:
            row["per_content"] = {}
            for k in sorted(set(kinds)):
                ix = np.flatnonzero(kinds == k)
                tk = tuple(x[ix] for x in tg)
                cell = {m: scoring.score_inbetween(ctx, truth_r[ix], truth_p[ix], preds[m][0][ix], preds[m][1][ix],
                                                   length, accuracy_only=True, truth_g=tk)
                        for m in ("slerp", "spline", "damped", DEFAULT, WHOLE)}
                cell["truth_skate"] = scoring.score_truth(ctx, truth_r[ix], truth_p[ix], length)["skate"]
                row["per_content"][k] = cell
        out[str(length)] = row
    return out


def score_tables(scores: dict, contents: dict, kind: str = "content") -> list[str]:
    """Markdown lines of :func:`scored_lengths`' ``scores``: L2Q, L2P, NPSS and MPJPE as ratios to
    SLERP's, the skate beside the truth's, and per ``kind`` (``contents``: windows of each); the
    default with the whole clip as context (:data:`WHOLE`) in a last column where scored."""
    lines = []
    methods = METHODS + ((WHOLE,) if all(WHOLE in row for row in scores.values()) else ())
    for key, label in (("l2q", "L2Q"), ("l2p", "L2P"), ("npss", "NPSS"), ("mpjpe_cm", "MPJPE (cm)")):
        lines += [f"**{label}**", "", "| frames | " + " | ".join(methods) + " |",
                  "| ---: | " + " | ".join("---:" for _ in methods) + " |"]
        for length, row in scores.items():
            sl = row["slerp"][key]
            cells = [f"{sl:.3f}"] + [f"{row[m][key] / sl:.2f}x" for m in methods[1:]]
            lines.append(f"| {length} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["**Foot skate** (cm/s, height-weighted foot speed over the gap, no contact detection)", "",
              "| frames | " + " | ".join(methods) + " | truth |", "| ---: | " + " | ".join("---:" for _ in methods)
              + " | ---: |"]
    for length, row in scores.items():
        lines.append(f"| {length} | " + " | ".join(f"{row[m]['skate']:.2f}" for m in methods)
                     + f" | {row['truth_skate']:.2f} |")
    lines.append("")
    for length, row in scores.items():
        if "per_content" not in row:
            continue
        whole = all(WHOLE in cell for cell in row["per_content"].values())
        shown = ("spline", "damped", DEFAULT) + ((WHOLE,) if whole else ())
        lines += [f"**Per {kind} at {length} frames** (L2Q / L2P as ratios to SLERP; skate in cm/s)", "",
                  f"| {kind} | windows | SLERP L2Q | spline | damped | default | "
                  + ("default, whole clip | " if whole else "") + "default skate / truth |",
                  "| --- | ---: | ---: | ---: | ---: | ---: | " + ("---: | " if whole else "") + "---: |"]
        for k, cell in row["per_content"].items():
            sl = cell["slerp"]
            ratio = [f"{cell[m]['l2q'] / sl['l2q']:.2f}x / {cell[m]['l2p'] / sl['l2p']:.2f}x" for m in shown]
            lines.append(f"| {k} | {contents[k]} | {sl['l2q']:.3f} | " + " | ".join(ratio)
                         + f" | {cell[DEFAULT]['skate']:.2f} / {cell['truth_skate']:.2f} |")
        lines.append("")
    return lines


def markdown(result: dict, command: str) -> str:
    lines = [f"{result['clips']} test clips ({result['per_cell']} per content and style, seed {result['seed']}; a clip "
             f"shorter than a window gives none), {result['windows']} windows; library: the {result['train_clips']} "
             "clips of bandai1. "
             "Ratios to SLERP (lower is better); SLERP's own value in its column.", ""]
    lines += score_tables(result["lengths"], result["contents"])
    lines.append(machine_line(result, command))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = report_parser(__doc__.split("\n")[0])
    p.add_argument("--other", required=True, help="directory of Motiondataset-2's BVH files")
    p.add_argument("--per-cell", type=int, default=2)
    args = p.parse_args(argv)
    result = run(Path(args.data) if args.data else default_data_dir(), Path(args.other), args.per_cell, args.seed)
    md = markdown(result, f"python bench/other_dataset.py --other DIR --per-cell {args.per_cell} --seed {args.seed}")
    print(md)
    save_outputs(result, md, args.json, args.doc, "Another dataset: bandai1's library, Motiondataset-2's gaps",
                 __doc__)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
