"""Generalisation: a rig whose joint names say nothing, against the same rig named.

The independent evaluation runs posturemap on other skeletons, whose joints may be named in
another language, by number (``J00``, ``J01``...) or by a tool's own scheme that no name rule
knows. Where nothing is named like a foot, a hand or a head, posturemap reads the legs, the
arms, the head and the bone classes from the hierarchy (``joints.structural_legs``,
``joints.structural_arms``, ``features.assign_classes``). This script takes the bench's style,
content and CMU (120 fps, 31 joints, a hip joint above each thigh) hold-outs twice: as
recorded, and with every joint renamed ``J00``, ``J01``... in the same order (training and test
side); trains a map and its motion library on each training side; in-betweens the same windows
with the default (``auto`` + foot lock) at the bench's lengths; and prints, per hold-out and
length, how many windows differ between the two and by how much (rotations: quaternion
components; positions: centimetres), with the joints each rig is read to have (legs, arms,
matched joints, head, and whether the bone classes agree).

Nothing is written to disk but the report (Bandai's licence: the data stays where it is).

Usage::

    python bench/numbered_names.py [--data DIR] [--doc PATH] [--json PATH] [--seed S]
"""

from __future__ import annotations

import dataclasses
import datetime
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from transition_speed import machine, machine_line, report_main  # noqa: E402

HOLDOUTS = ("style", "content", "cmu")
TITLES = {"style": "Style", "content": "Content", "cmu": "CMU"}
METHOD = "auto+feet"


def numbered(m):
    """The clip with its joints named ``J00``, ``J01``... in the file's order (nothing else
    changed)."""
    from posturemap.core.motion import Motion
    from posturemap.core.skeleton import Skeleton

    sk = m.skeleton
    renamed = Skeleton(tuple(f"J{j:02d}" for j in range(sk.num_joints)), sk.parents, sk.offsets, sk.channels,
                       sk.end_sites, sk.euler_style)
    return Motion(renamed, m.rotations, m.positions, m.fps, m.source)


def found(sk) -> dict:
    """What the rig is read to have: legs and arms (joint indices), matched joints, head, classes."""
    from posturemap.core.joints import arm_chains, head_joint, key_joints, leg_chains
    from posturemap.core.motion import root_index
    from posturemap.learn.features import assign_classes

    lower, upper = key_joints(sk)
    return {"legs": [list(c) for c in leg_chains(sk)], "arms": [list(c) for c in arm_chains(sk)],
            "lower": lower.tolist(), "upper": upper.tolist(), "head": head_joint(sk),
            "classes": assign_classes(sk, root_index(sk)).tolist()}


def run(data_dir: Path, seed: int = 0, log=print) -> dict:
    from posturemap.core import kernels
    from posturemap.evaluate import protocol, runner

    kernels.compiled()
    settings = dataclasses.replace(protocol.Settings.full(), som_epochs=0.25)
    result = {"holdouts": {}, "date": datetime.date.today().isoformat(), "machine": machine()}
    for name in HOLDOUTS:
        split = protocol.load_split(name, data_dir, settings)
        other = dataclasses.replace(split, train=[numbered(m) for m in split.train],
                                    test=[numbered(m) for m in split.test])
        preds, windows, rigs = {}, None, {}
        for label, sp in (("named", split), ("numbered", other)):
            log(f"{name}: {label} rig")
            state = runner.prepare(sp, settings, seed, log=lambda *a: None, full=False)
            if windows is None:  # the same windows for both: the clips' lengths are the same
                windows = protocol.make_windows(state, settings, seed)
            rigs[label] = found(sp.train[0].skeleton)
            engines = runner.empty_engines(state)
            for length in split.lengths:
                preds[label, length] = runner.predict_windows(engines, (METHOD,), state["test"], windows, length)[2][
                    METHOD]
        rows = {}
        for length in split.lengths:
            (ra, pa), (rb, pb) = preds["named", length], preds["numbered", length]
            differ = (np.abs(ra - rb).max(axis=(1, 2, 3)) > 0) | (np.abs(pa - pb).max(axis=(1, 2, 3)) > 0)
            rows[str(length)] = {"windows": len(windows), "differ": int(differ.sum()),
                                 "rotation": float(np.abs(ra - rb).max()),
                                 "position_cm": float(np.abs(pa - pb).max() * split.cm)}
        result["holdouts"][name] = {"lengths": rows, "rigs": rigs, "joints": split.train[0].skeleton.num_joints,
                                    "names": list(split.train[0].skeleton.names)}
    return result


def markdown(result: dict, command: str) -> str:
    lines = []
    for name, r in result["holdouts"].items():
        named, num = r["rigs"]["named"], r["rigs"]["numbered"]
        same = [k for k in named if named[k] == num[k]]
        legs = "; ".join(" > ".join(r["names"][j] for j in c) for c in num["legs"]) or "none"
        arms = "; ".join(" > ".join(r["names"][j] for j in c) for c in num["arms"]) or "none"
        head = r["names"][num["head"]] if num["head"] >= 0 else "none"
        lines += [f"**{TITLES[name]} hold-out** ({r['joints']} joints). Read from the numbered rig's "
                  f"hierarchy: legs {legs}; arms {arms}; head {head} "
                  f"(the same as the names give: {', '.join(same) if same else 'nothing'}"
                  + (f"; differing: {', '.join(k for k in named if k not in same)}" if len(same) < len(named) else "")
                  + ").", "",
                  "| frames | windows | windows that differ | largest rotation difference "
                  "| largest position difference (cm) |",
                  "| ---: | ---: | ---: | ---: | ---: |"]
        for length, row in r["lengths"].items():
            lines.append(f"| {length} | {row['windows']} | {row['differ']} | {row['rotation']:.3g} | "
                         f"{row['position_cm']:.3g} |")
        lines.append("")
    lines.append(machine_line(result, command))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    return report_main(__doc__, "Joints named J00, J01...: the hold-outs read from the hierarchy",
                       "python bench/numbered_names.py", run, markdown, argv)


if __name__ == "__main__":
    raise SystemExit(main())
