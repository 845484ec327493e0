"""The report of ``posturemap bench``: results.md and the PNG plots, from the results dict.

Everything comes from the dict :func:`posturemap.evaluate.run` writes to results.json, so the
report can be rebuilt from that file alone.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from . import metrics
from .features import CLASSES


def plot(results: dict, example: dict, out: Path) -> list[str]:
    """PNG plots: L2Q and L2P against length per method; one joint's angle through a window.

    ``example`` (from :func:`posturemap.evaluate.run_inbetween`, may be empty): per method and
    ``truth`` the local rotations (F, J, 4) of one window at 30 frames, with ``clip``, ``window``
    and the skeleton's ``joints``. Returns the names of the files written into ``out``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    inb = results["inbetween"]
    methods, lengths = list(inb["methods"]), results["config"]["lengths"]
    for metric, label in (("l2q", "L2Q (global quaternions)"), ("l2p", "L2P (normalised global positions)")):
        fig, ax = plt.subplots(figsize=(6, 4), dpi=110)
        for m in methods:
            ax.plot(lengths, [inb["methods"][m][str(n)][metric] for n in lengths], marker="o", label=m)
        ax.set_xlabel("transition length (frames)")
        ax.set_ylabel(label)
        ax.set_xticks(lengths)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title(f"In-betweening error, {inb['windows']} held-out windows")
        fig.tight_layout()
        path = out / f"results_{metric}.png"
        fig.savefig(path)
        plt.close(fig)
        written.append(path.name)
    if example:
        names = example["joints"]
        joint = next((j for j, n in enumerate(names) if re.search(r"lowerleg|knee|shin", n, re.IGNORECASE)), 1)
        _, s = example["window"]
        fig, ax = plt.subplots(figsize=(7, 4), dpi=110)
        t = np.arange(len(example["truth"])) - (results["config"]["n_past"] - 1)
        for m in ["truth"] + methods:
            ang = np.degrees(2 * np.arccos(np.clip(np.abs(example[m][:, joint, 0]), 0, 1)))
            ax.plot(t, ang, lw=2.5 if m == "truth" else 1.2, color="k" if m == "truth" else None,
                    ls="-" if m == "truth" else "--", label=m)
        ax.axvspan(1, 30, color="0.9")
        ax.set_xlabel("frame (0 = last past-context frame; grey: the 30 rebuilt frames)")
        ax.set_ylabel(f"{names[joint]} rotation angle (deg)")
        ax.set_title(f"{example['clip']}, frames {s}..{s + len(t) - 1}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        fig.tight_layout()
        path = out / "results_joint_angle.png"
        fig.savefig(path)
        plt.close(fig)
        written.append(path.name)
    return written


def _fmt(v, digits=3):
    if v is None:
        return "-"
    if isinstance(v, float):
        if abs(v) >= 1000:
            return f"{v:,.0f}"
        return f"{v:.{digits}f}"
    return str(v)


def _table(rows: list[str], header: list[str], body: list[list]) -> None:
    rows.append("| " + " | ".join(header) + " |")
    rows.append("|" + "---|" * len(header))
    for b in body:
        rows.append("| " + " | ".join(_fmt(v) for v in b) + " |")
    rows.append("")


METRIC_TITLES = {
    "l2q": "L2Q (global quaternions, LaFAN1; lower is better)",
    "l2p": "L2P (global positions normalised as LaFAN1; lower is better)",
    "npss": "NPSS (global quaternions; lower is better)",
    "mpjpe_cm": "MPJPE (cm)",
    "root_error_cm": "Root position error (cm)",
    "pose_error_cm": "Root-relative joint position error (cm)",
    "foot_skate": "Foot skate (cm/s, horizontal foot speed in contact; truth row for reference)",
    "foot_slide_truth_contacts": "Foot slide where the truth's feet are planted (cm/s)",
    "validity": "Pose validity (mean distance to the nearest training posture, feature units; truth row for reference)",
    "jerk": "Jerk (cm/s^3; truth row for reference)",
}


def markdown(results: dict) -> str:
    """results.md from the results dict (as in results.json: the report can be redone from it)."""
    r = []
    cfg = results["config"]
    inb = results["inbetween"]
    methods, lengths = list(inb["methods"]), cfg["lengths"]
    r.append("# posturemap bench: results\n")
    r.append(f"Run: `posturemap bench{' --quick' if cfg['quick'] else ''} --seed {cfg['seed']}` on "
             f"{results['machine']['cpus']} CPUs, Python {results['machine']['python']}, code "
             f"`{results['machine']['code']}`; "
             f"wall time **{results['wall_seconds']:.0f} s** ("
             + ", ".join(f"{k} {v:.0f} s" for k, v in results["section_seconds"].items()) + ").\n")
    sp = results["split"]
    r.append("## Protocol\n")
    r.append("- Data: Bandai-Namco dataset-1 (`bandai1/`, 30 fps, cm, Y up).")
    used = f" (every {cfg['train_stride']}. one used)" if cfg["train_stride"] > 1 else ""
    r.append(f"- Split: test = every clip of the styles {', '.join(sp['test_styles'])} "
             f"({sp['test_clips']} clips, {sp['test_frames']} frames); training = the other "
             f"{sp['train_clips_all']} clips{used}: "
             f"{sp['train_clips']} clips, {sp['train_frames']} frames. No test clip is seen in training "
             f"(map, SOM, L2P statistics, floor heights, validity index).")
    r.append(f"- In-betweening: windows of {cfg['n_past']} past + L + {cfg['n_future']} future frames starting "
             f"every {cfg['stride']} frames "
             f"(65-frame windows truncated per L, as LaFAN1), {inb['windows']} windows; "
             f"L = {', '.join(map(str, lengths))}. Engine: same clip as A and B, `a_end` = last past frame, "
             f"`b_start` = first future frame, `align=False`, `alpha=0.5`, `key_at=L//2`.")
    r.append("- L2Q, L2P, NPSS as in LaFAN1 (window frame: root centred, turned to face a fixed direction "
             "at the last past frame; L2P divides by per-coordinate std of training windows of 50 frames, "
             "stride 20; signs of quaternions made consistent with the truth).")
    r.append(f"- Foot skate: joints {', '.join(results['feet']['joints'])}; contact when a joint is below its "
             f"floor height + {metrics.CONTACT_HEIGHT:g} cm at both ends of a frame step and moves "
             f"horizontally slower than {metrics.CONTACT_SPEED:g} cm/s; floor = "
             f"{results['feet']['floor_percentile']:g}th percentile "
             f"of its height in training ({', '.join(f'{v:.1f}' for v in results['feet']['floor_cm'])} cm). "
             "Measured over the L+1 steps from the last past frame to the first future frame.")
    r.append("- Pose validity: distance (KD-tree) from each rebuilt posture to the nearest training posture "
             "in the map's feature space (logmap radians, root height in leg lengths).")
    r.append("- Jerk: every third difference of global positions that touches a rebuilt frame.\n")
    r.append("## In-betweening (held-out clips)\n")
    for metric, title in METRIC_TITLES.items():
        r.append(f"### {title}\n")
        body = [[m] + [inb["methods"][m][str(n)][metric] for n in lengths] for m in methods]
        if metric in inb["truth"][str(lengths[0])]:
            body.append(["truth"] + [inb["truth"][str(n)][metric] for n in lengths])
        _table(r, ["method"] + [f"L={n}" for n in lengths], body)
    # the goal
    dm = inb["default_method"]
    r.append(f"### The issue's goal: default method ({dm}) against SLERP/LERP\n")
    body = []
    for n in lengths:
        u, s = inb["methods"][dm][str(n)], inb["methods"]["slerp"][str(n)]
        pd = inb["vs_slerp"][dm][str(n)]
        body.append([f"L={n}", "yes" if u["l2q"] < s["l2q"] else "NO", "yes" if u["l2p"] < s["l2p"] else "NO",
                     "yes" if u["foot_skate"] <= s["foot_skate"] else "NO",
                     "yes" if u["validity"] <= s["validity"] else "NO"]
                    + [f"{pd[k]['mean']:+.3f} [{pd[k]['ci95'][0]:+.3f}, {pd[k]['ci95'][1]:+.3f}], "
                       f"{100 * pd[k]['share_better']:.0f}%" for k in ("l2q", "l2p")])
    _table(r, ["length", "L2Q better", "L2P better", "skate no worse", "validity at least as good",
               f"L2Q {dm} - slerp [95% CI], windows better", f"L2P {dm} - slerp [95% CI], windows better"], body)
    r.append("Every method against slerp, window by window: mean difference of L2Q and L2P "
             "(negative = better than slerp) and the share of windows where it is better:\n")
    def cell(m, n, k):
        v = inb["vs_slerp"][m][str(n)][k]
        return f"{v['mean']:+.3f} ({100 * v['share_better']:.0f}%)"

    _table(r, ["method"] + [f"L={n} L2Q" for n in lengths] + [f"L={n} L2P" for n in lengths],
           [[m] + [cell(m, n, k) for k in ("l2q", "l2p") for n in lengths] for m in methods if m != "slerp"])
    cc = results["cross_clip"]
    r.append(f"## Transitions between different clips ({cc['pairs']} seeded random pairs of test clips, "
             f"length {cc['length']}, align=True)\n")
    body = [[m] + [cc["methods"][m][k] for k in ("foot_skate", "contact_fraction", "validity", "validity_p95", "jerk")]
            for m in methods]
    body.append(["real frames at the seams"] + [cc["reference"][k] for k in
                                                ("foot_skate", "contact_fraction", "validity", "validity_p95", "jerk")])
    _table(r, ["method", "foot skate cm/s", "contact fraction", "validity", "validity p95", "jerk cm/s^3"], body)
    d = results["diagnostics"]
    r.append("## Diagnostics (keyed methods)\n")
    r.append("Distance in the map's feature space from candidate postures to the true posture at `key_at` "
             "(mean over windows):\n")
    keys = list(next(iter(d["key_distance"].values())))
    _table(r, ["L"] + keys, [[n] + [d["key_distance"][str(n)][k] for k in keys] for n in lengths])
    r.append("Per bone class (distance over that class's dimensions; the map's radius per class: "
             + ", ".join(f"{c} {v:.3f}" for c, v in zip(CLASSES, results["map"]["radius"])) + "):\n")
    _table(r, ["L", "class", "blend to true", "upm key to true", "nearest neuron to true"],
           [[n, cls, v["blend"], v["upm_key"], v["nearest_neuron"]]
            for n in lengths for cls, v in d["key_distance_by_class"][str(n)].items()])
    r.append("The same spline with stand-in keys: `blend-key` = the alpha-blend itself (no map), "
             "`oracle-key` = the true posture at `key_at` (an upper bound for any key), `self-map-key` = "
             "the key from a map learned from the window's clip alone, without the missing frames (as "
             "`posturemap transition` does without `--map`):\n")
    r.append("Stand-ins that test the spline itself: `spline-v0` = the keyless spline with zero angular velocity "
             "at both seams (root translation keeps its velocity), `blend-key-v0` = `blend-key` with zero "
             "angular seam velocity, `upm-lerp-root` = `upm`'s frames with the root translation of `slerp` "
             "(LERP). The `self-map-key` map and the stand-in keys use no frame of the gap.\n")
    for metric in ("l2q", "l2p", "root_error_cm", "pose_error_cm", "foot_skate", "validity"):
        body = [[v] + [d["variants"][v][str(n)][metric] for n in lengths] for v in d["variants"]]
        refs = ("spline", "upm") + ((dm,) if dm != "upm" else ()) + ("slerp",)
        body += [[m] + [inb["methods"][m][str(n)][metric] for n in lengths] for m in refs]
        r.append(f"{metric}:\n")
        _table(r, ["key"] + [f"L={n}" for n in lengths], body)
    if d["sweep"]:
        r.append("upm with other `alpha` and `key_at` (L2Q / L2P):\n")
        body = []
        for n, rows in d["sweep"].items():
            for v in rows.values():
                body.append([n, v["alpha"], v["key_at"], v["l2q"], v["l2p"]])
        _table(r, ["L", "alpha", "key_at", "L2Q", "L2P"], body)
    r.append("## Speed\n")
    spd = results["speed"]
    r.append(f"Transition latency, `TransitionEngine.generate`, length {cfg['cross_length']}, {cfg['latency_calls']} "
             "cross-clip calls per method (microseconds):\n")
    _table(r, ["method", "median us", "p99 us", "neurons per class"],
           [[m, v["median_us"], v["p99_us"], "/".join(map(str, v["neurons"]))] for m, v in spd["latency"].items()])
    r.append("Training, per bone class, same features, same epochs as configured, UPM on one thread "
             "against MiniSom at (about) the UPM's neuron count:\n")
    _table(r, ["class", "samples", "dims", "UPM neurons", "UPM epochs", "UPM s", "UPM samples/s",
               "SOM neurons", "SOM epochs", "SOM s", "SOM samples/s"],
           [[t["class"], t["samples"], t["dims"], t["upm_neurons"], t["upm_epochs"], t["upm_seconds"],
             t["upm_samples_per_s"], t["som_neurons"], t["som_epochs"], t["som_seconds"], t["som_samples_per_s"]]
            for t in spd["training"]])
    for name, b in spd["bench"].items():
        r.append(f"### bench/{name}.py\n")
        if b["status"] == "ok":
            r.append((b.get("markdown") or "```\n" + json.dumps(b["result"], indent=1)[:3000] + "\n```") + "\n")
        else:
            r.append(f"Not run: {b['status']} ({b['reason']}).\n")
    return "\n".join(r) + "\n"
