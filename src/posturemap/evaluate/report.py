"""The report of ``posturemap bench``: results.md and the PNG plots, from the results dict.

Everything comes from the dict :func:`posturemap.evaluate.run` writes to results.json, so the
report can be rebuilt from that file alone.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from . import metrics
from ..learn.features import CLASSES
from .protocol import N_PAST

HOLDOUT_TITLES = {
    "style": "Style hold-out (unseen styles of known motion types)",
    "content": "Content hold-out (motion types absent from the library)",
    "cmu": "CMU 01_01 at 120 fps (library from the first half, gaps in the second)",
    "own": "Your clips (library from --train, gaps in --test)",
}
PLOT_METRICS = (("l2q", "L2Q (global quaternions)"), ("l2p", "L2P (normalised global positions)"),
                ("skate", "foot skate (cm/s)"), ("naturalness", "naturalness (distance to nearest real window)"))
# The acceptance criteria (issue 11, "What must be shown").
SKATE_LENGTHS = (15, 30, 45)
SKATE_FACTOR = 1.5
GOAL_LENGTHS = (30, 45)
GOAL_FACTOR = 0.7


def plot(results: dict, examples: dict, out: Path) -> list[str]:
    """PNG plots per hold-out: L2Q, L2P, foot skate and naturalness against length (truth as a
    black line where it has a value); one joint's angle through a window at 30 frames (at 30 fps).

    ``examples`` (from :func:`posturemap.evaluate.run_inbetween`, per hold-out, may be empty):
    per method and ``truth`` the local rotations (F, J, 4) of one window at 30 frames, with
    ``clip``, ``window`` and the skeleton's ``joints``. Returns the names of the files written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    for name, hold in results["holdouts"].items():
        inb = hold["inbetween"]
        methods, lengths = list(inb["methods"]), inb["lengths"]
        fig, axes = plt.subplots(2, 2, figsize=(12.5, 7.5), dpi=100)
        for ax, (metric, label) in zip(axes.ravel(), PLOT_METRICS):
            for i, m in enumerate(methods):  # ten colours; then the same colours dashed, dotted
                ax.plot(lengths, [inb["methods"][m][str(n)].get(metric) for n in lengths], marker="o", ms=3,
                        lw=2.2 if m == inb["default_method"] else 1.1, ls=("-", "--", ":")[min(i // 10, 2)],
                        color=f"C{i % 10}", label=m)
            if metric in inb["truth"][str(lengths[0])]:
                ax.plot(lengths, [inb["truth"][str(n)][metric] for n in lengths], color="k", lw=2.5, ls="--",
                        label="truth")
            ax.set_xlabel("transition length (frames)")
            ax.set_ylabel(label)
            ax.set_xscale("log")
            ax.set_xticks(lengths)
            ax.set_xticklabels([str(n) for n in lengths])
            ax.minorticks_off()
            ax.grid(alpha=0.3)
        fig.legend(*axes[1, 0].get_legend_handles_labels(), loc="center right", fontsize=8)
        fig.suptitle(f"{HOLDOUT_TITLES.get(name, name)}: {inb['windows']} windows (thick: the default; "
                     "dashed black: the truth)", fontsize=10)
        fig.tight_layout(rect=(0, 0, 0.85, 1))
        path = out / f"results_{name}.png"
        fig.savefig(path)
        plt.close(fig)
        written.append(path.name)
        example = examples.get(name) or {}
        if example:
            written.append(_plot_example(plt, example, methods, results["config"]["n_past"], out,
                                         f"results_{name}_joint_angle.png"))
            if "positions" in example:
                written.append(_filmstrip_example(example, inb["default_method"], results["config"]["n_past"], out,
                                                  f"results_{name}_filmstrip.png", HOLDOUT_TITLES.get(name, name)))
    return written


FILMSTRIP_METHODS = ("slerp", "spline", "inertialize", "upm", "upm-valid+feet")


def _filmstrip_example(example: dict, default: str, n_past: int, out: Path, filename: str, title: str) -> str:
    """One window (30 frames at 30 fps, or the length nearest as long) as side-view filmstrips, one
    row each: the truth, the baselines and the default (:func:`posturemap.io.preview.filmstrip_rows`;
    the rebuilt frames in colour, the context grey)."""
    from ..io.preview import filmstrip_rows
    from ..core.skeleton import fk

    parents = np.asarray(example["parents"])
    rows = []
    for m in ("truth",) + tuple(x for x in FILMSTRIP_METHODS if x in example["positions"]) + (default,):
        local_r = example["truth"] if m == "truth" else example[m]
        _, g = fk(parents, local_r, example["positions"][m])
        gap = len(g) - 2 * n_past
        rows.append((m, [("context", g[:n_past], None), ("truth" if m == "truth" else "transition",
                                                         g[n_past: n_past + gap], None), ("context", g[n_past + gap:], None)]))
    _, s = example["window"]
    filmstrip_rows(rows, out / filename, parents, up=int(example["up"]), fps=float(example["fps"]),
                   feet=[int(j) for j in example["feet"]],
                   title=f"{title}: {example['clip']}, frames {s}..{s + len(example['truth']) - 1}; "
                         f"the {len(example['truth']) - 2 * n_past} rebuilt frames in colour")
    return filename


def _plot_example(plt, example: dict, methods: list[str], n_past: int, out: Path, filename: str) -> str:
    names = example["joints"]
    joint = next((j for j, n in enumerate(names) if re.search(r"lowerleg|knee|shin|leftleg", n, re.IGNORECASE)), 1)
    _, s = example["window"]
    fig, ax = plt.subplots(figsize=(7, 4), dpi=110)
    t = np.arange(len(example["truth"])) - (n_past - 1)
    for m in ["truth"] + methods:
        ang = np.degrees(2 * np.arccos(np.clip(np.abs(example[m][:, joint, 0]), 0, 1)))
        ax.plot(t, ang, lw=2.5 if m == "truth" else 1.2, color="k" if m == "truth" else None,
                ls="-" if m == "truth" else "--", label=m)
    gap = len(example["truth"]) - 2 * n_past
    ax.axvspan(1, gap, color="0.9")
    ax.set_xlabel(f"frame (0 = last past-context frame; grey: the {gap} rebuilt frames)")
    ax.set_ylabel(f"{names[joint]} rotation angle (deg)")
    ax.set_title(f"{example['clip']}, frames {s}..{s + len(t) - 1}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(out / filename)
    plt.close(fig)
    return filename


def _over(a, b, digits: int, suffix: str = "") -> str:
    """``a / b`` to ``digits`` decimals (then ``suffix``); ``-`` where ``b`` is 0 (a reference that
    makes no error: SLERP over a held pose, NPSS of a one-frame gap)."""
    return f"{a / b:.{digits}f}{suffix}" if b else "-"


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
    "skate": "Foot skate (cm/s, height-weighted horizontal foot speed, no contact detection; truth row for reference)",
    "naturalness": "Naturalness (distance to the nearest real window of unseen data, z-scored pose and velocity; "
                   "truth row for reference; lower is more natural)",
    "penetration_cm": "Floor penetration (cm: the deepest foot joint under the floor, the lowest foot joint in the "
                      "context frames, averaged over the gap's frames; truth row for reference)",
    "float_cm": "Feet off the floor (cm: per window, how far the lowest foot joint rises in the gap above the highest "
                "it reaches in the context frames, 0 where never; the height-weighted skate lowers for feet in the "
                "air, this shows them; truth row for reference)",
    "contact_skate": "Secondary: contact-based foot skate (cm/s over detected contact steps only; blind to a foot "
                     "sliding above the contact height)",
    "validity": "Pose validity (mean distance to the nearest training posture, feature units; truth row for reference)",
    "jerk": "Jerk (cm/s^3; truth row for reference)",
}


def criteria_lengths(inb: dict) -> tuple[list[int], list[int]]:
    """The lengths (frames) of one hold-out's criteria: the skate's (:data:`SKATE_LENGTHS`) and the
    goal's (:data:`GOAL_LENGTHS`), or, where the hold-out names them (``criteria_lengths``: its
    frames for 15, 30 and 45 at 30 fps, a user's own clips at another rate), those; only the
    lengths it ran."""
    own = inb.get("criteria_lengths")
    skate, goal = (SKATE_LENGTHS, GOAL_LENGTHS) if not own else (tuple(own), tuple(own[1:]))
    return [n for n in skate if n in inb["lengths"]], [n for n in goal if n in inb["lengths"]]


def acceptance(inb: dict) -> dict:
    """The issue's acceptance criteria per method, from one hold-out's in-betweening results.

    Returns ``{method: {criterion: (passed, worst ratio)}}`` with the criteria ``skate`` (skate
    at most 1.5x the truth's at 15, 30, 45 frames), ``l2q``/``l2p`` (no worse than slerp at any
    length), ``goal`` (L2Q and L2P at most 0.7x slerp's at 30 and 45) and ``beats_baselines``
    (L2Q and L2P below spline's and inertialize's at 30 and 45). A ratio is the method's figure
    divided by the reference's; the worst over the lengths (and metrics) is reported. A criterion
    none of whose lengths ran (a user's own ``--lengths``) is ``(None, None)``.
    """
    lengths = inb["lengths"]
    meth, truth = inb["methods"], inb["truth"]

    def worst(m, metric, ref, ns, factor=1.0):
        # A length where the reference makes no error (a held pose's SLERP, a truth that never
        # slides) says nothing about the ratio: left out.
        ratios = [meth[m][str(n)][metric] / ref[str(n)][metric] for n in ns if str(n) in ref and ref[str(n)][metric]]
        if not ratios:
            return None, None
        r = max(ratios)
        return r <= factor, r

    def joined(parts):  # several checks as one: passed if all did, the worst ratio; none ran: (None, None)
        parts = [p for p in parts if p[0] is not None]
        return (all(p[0] for p in parts), max(p[1] for p in parts)) if parts else (None, None)

    out = {}
    skate_ns, long_ns = criteria_lengths(inb)
    for m in meth:
        slerp = meth.get("slerp", {})
        row = {"skate": worst(m, "skate", truth, skate_ns, SKATE_FACTOR),
               "l2q": worst(m, "l2q", slerp, lengths), "l2p": worst(m, "l2p", slerp, lengths)}
        row["goal"] = joined([worst(m, k, slerp, long_ns, GOAL_FACTOR) for k in ("l2q", "l2p")])
        beats = [worst(m, k, meth[b], long_ns) for b in ("spline", "inertialize") if b in meth and b != m
                 for k in ("l2q", "l2p")]
        row["beats_baselines"] = joined(beats) if beats else (False, None)
        out[m] = row
    return out


def _acceptance_rows(r: list[str], name: str, inb: dict) -> None:
    acc = acceptance(inb)

    def cell(v):
        ok, ratio = v
        if ok is None and ratio is None:
            return "-"  # none of its lengths ran
        return ("yes" if ok else "NO") + (f" ({ratio:.2f})" if ratio is not None else "")

    skate_ns, long_ns = ("/".join(map(str, ns)) or "(none of these lengths)" for ns in criteria_lengths(inb))
    r.append(f"**{HOLDOUT_TITLES.get(name, name)}** ({inb['windows']} windows):\n")
    _table(r, ["method", f"skate <= {SKATE_FACTOR:g}x truth at {skate_ns}", "L2Q <= slerp, every L",
               "L2P <= slerp, every L", f"goal: L2Q, L2P <= {GOAL_FACTOR:g}x slerp at {long_ns}",
               f"L2Q, L2P < spline, inertialize at {long_ns}"],
           [[m] + [cell(v[k]) for k in ("skate", "l2q", "l2p", "goal", "beats_baselines")] for m, v in acc.items()])


def _series(per_length: dict, lengths, metric) -> str:
    return " ".join(_fmt(per_length[str(n)].get(metric)) for n in lengths)


def _holdout_section(r: list[str], name: str, hold: dict, cfg: dict) -> None:
    inb, sp, feet = hold["inbetween"], hold["split"], hold["feet"]
    methods, lengths = list(inb["methods"]), inb["lengths"]
    r.append(f"## {HOLDOUT_TITLES.get(name, name)}\n")
    used = f" (every {cfg['train_stride']}th used)" if cfg["train_stride"] > 1 and name != "cmu" else ""
    r.append(f"- Split: {sp['rule']}. Test: {sp['test_clips']} clips, {sp['test_frames']} frames; training: "
             f"{sp['train_clips_all']} clips{used}, {sp['train_clips']} clips, {sp['train_frames']} frames "
             f"(test clips at {sp['fps']:g} fps; {sp['joints']} joints, unit: {sp['unit']}, {sp['cm_per_unit']:.4g} cm). "
             "The map (and any library a method keeps), SOM, L2P statistics, planted foot heights and "
             "validity index see the training side only.")
    r.append(f"- Windows: {inb['windows']}, L = {', '.join(map(str, lengths))}.")
    r.append(f"- Feet: {', '.join(feet['joints'])}; planted heights "
             f"{', '.join(f'{v:.1f}' for v in feet['floor_cm'])} cm; skate H = {feet['skate_height_cm']:.2f} cm "
             f"({cfg['skate_height_legs']:.4f} x leg length {feet['leg_length_cm']:.1f} cm).\n")
    for metric, title in METRIC_TITLES.items():
        r.append(f"### {title}\n")
        body = [[m] + [inb["methods"][m][str(n)].get(metric) for n in lengths] for m in methods]
        if metric in inb["truth"][str(lengths[0])]:
            body.append(["truth"] + [inb["truth"][str(n)][metric] for n in lengths])
        _table(r, ["method"] + [f"L={n}" for n in lengths], body)
    r.append("### Every method against slerp, window by window\n")
    r.append("Ratio of the means (method / slerp), mean difference with its 95% bootstrap interval, share of "
             "windows where the method is better:\n")

    def cell(m, n, k):
        v = inb["vs_slerp"][m][str(n)][k]
        ratio = "-" if v.get("ratio") is None else f"{v['ratio']:.2f}"
        return f"{ratio}; {v['mean']:+.3f} [{v['ci95'][0]:+.3f}, {v['ci95'][1]:+.3f}]; {100 * v['share_better']:.0f}%"

    for k in ("l2q", "l2p"):
        _table(r, ["method"] + [f"{k.upper()} L={n}" for n in lengths],
               [[m] + [cell(m, n, k) for n in lengths] for m in methods if m != "slerp"])
    r.append("### Per motion type (content)\n")
    r.append("Each cell lists the values at L = " + ", ".join(map(str, lengths)) + ".\n")
    for content, pc in inb["per_content"].items():
        r.append(f"**{content}** ({pc['windows']} windows)\n")
        body = [[m] + [_series(pc["methods"][m], lengths, k) for k in ("l2q", "l2p", "mpjpe_cm", "skate",
                                                                        "naturalness")] for m in methods]
        body.append(["truth", "", "", "", _series(pc["truth"], lengths, "skate"),
                     _series(pc["truth"], lengths, "naturalness")])
        _table(r, ["method", "L2Q", "L2P", "MPJPE cm", "skate cm/s", "naturalness"], body)
    if inb.get("whole_clip"):
        _whole_clip_section(r, inb)
    cc = hold.get("cross_clip")
    if cc:
        r.append(f"### Transitions between different clips ({cc['pairs']} seeded random pairs of test clips, "
                 f"length {cc['length']}, align=True)\n")
        keys = ("skate", "float_cm", "floats_over_10cm", "contact_skate", "validity", "validity_p95", "jerk",
                "step_ratio", "steps_over_1_5", "accel_ratio", "accels_over_1_5")
        body = [[m] + [cc["methods"][m].get(k) for k in keys] for m in methods]
        body.append(["real frames at the seams"] + [cc["reference"].get(k) for k in keys])
        _table(r, ["method", "skate cm/s", "feet off the floor cm", "of them over 10 cm", "contact skate cm/s",
                   "validity", "validity p95", "jerk cm/s^3", "largest step / real's", "of them over 1.5x",
                   "largest acceleration / real's", "of them over 1.5x"], body)
        r.append("Feet off the floor: per transition, how far the lowest foot joint rises in the new frames above "
                 "the highest it reaches in the real frames around them (A's last 10, B's first 10), the mean; "
                 "then the number of transitions where that is over 10 cm. The height-weighted skate weighs a foot "
                 "by its closeness to the ground, so feet held in the air lower it; this column shows them. "
                 "Largest step: per transition, the largest distance any joint moves from one frame to the next "
                 "from A's last frame to B's first, over the largest in those real frames around them (or a brisk "
                 f"walking swing's, {metrics.POP_FLOOR_LEGS:g} leg lengths a second, where those stand), the mean; "
                 "then the number of transitions where that is over 1.5 (a pop: a foot thrown across, a limb "
                 "snapped, which the jerk averages away). Largest acceleration: likewise, of any joint at any frame "
                 "from A's last to B's first, over the largest in the real frames around them (or a walking ankle's "
                 f"99th percentile, {metrics.POP_ACCEL_LEGS:g} leg lengths a second squared, where those stand): a "
                 "limb set off or stopped at once, a knee snapped straight.\n")


def _whole_clip_section(r: list[str], inb: dict) -> None:
    """A gap in a take: the default given the whole clip as context, beside the protocol's."""
    wc, lengths, default = inb["whole_clip"], inb["lengths"], inb["default_method"]
    labels = list(wc["methods"])
    r.append("### A gap in a take: the whole clip as context\n")
    r.append(f"The same windows, but A is the test clip up to the last past frame and B the clip from the first "
             f"future frame: everything but the gap, where the protocol above gives {N_PAST} frames each (a gap "
             "in a take to fill, as `posturemap transition take.bvh take.bvh --a-end I --b-start J --length J-I-1 --no-align` "
             "gives it). The default also searches the clips' own motion beside the library "
             "(`TransitionEngine.own_seconds`; docs/retrieval.md, \"The clips' own motion\"); "
             f"\"{labels[-1]}\" does not. Ratios to slerp's (slerp reads the seams only: its figures are "
             "those above), slerp's own value in its row; the skate in cm/s.\n")
    body = []
    for k, title in (("l2q", "L2Q"), ("l2p", "L2P"), ("npss", "NPSS"), ("mpjpe_cm", "MPJPE cm")):
        ref = [inb["methods"]["slerp"][str(n)][k] for n in lengths]
        body.append([f"{title}: slerp"] + ref)
        body.append([f"{title}: {default}, {N_PAST} frames each side"]
                    + [_over(inb['methods'][default][str(n)][k], v, 3, "x") for n, v in zip(lengths, ref)])
        for label in labels[::-1]:
            body.append([f"{title}: {label}, whole clip"]
                        + [_over(wc['methods'][label][str(n)][k], v, 3, "x") for n, v in zip(lengths, ref)])
    for label in labels[::-1]:
        body.append([f"skate: {label}, whole clip"] + [wc["methods"][label][str(n)]["skate"] for n in lengths])
    body.append(["skate: truth"] + [inb["truth"][str(n)]["skate"] for n in lengths])
    body.append([f"windows replaying the clips' own motion ({labels[0]})"]
                + [f"{100 * wc['own_share'][labels[0]][str(n)]:.0f}%" for n in lengths])
    _table(r, ["measure"] + [f"L={n}" for n in lengths], body)
    if wc.get("per_content"):
        r.append(f"Per motion type, {labels[0]} with the whole clip: L2Q and L2P as ratios to slerp's at L = "
                 + ", ".join(map(str, lengths)) + ".\n")
        body = []
        for content, pc in wc["per_content"].items():
            sl = inb["per_content"][content]["methods"]["slerp"]
            body.append([content, pc["windows"]] + [" ".join(_over(pc['methods'][labels[0]][str(n)][k], sl[str(n)][k], 2)
                                                             for n in lengths) for k in ("l2q", "l2p")])
        _table(r, ["content", "windows", "L2Q / slerp", "L2P / slerp"], body)


def markdown(results: dict) -> str:
    """results.md from the results dict (as in results.json: the report can be redone from it)."""
    r = []
    cfg = results["config"]
    holds = results["holdouts"]
    r.append("# posturemap bench: results\n")
    scripts = "" if cfg["quick"] or cfg.get("bench_scripts", True) else " without the bench/ scripts"
    given = f" {cfg['command']}" if cfg.get("command") else ""
    r.append(f"Run: `posturemap bench{given}{' --quick' if cfg['quick'] else ''} --seed {cfg['seed']}`{scripts} on "
             f"{results['machine']['cpus']} CPUs (shared with other jobs), Python {results['machine']['python']}, "
             f"code `{results['machine']['code']}`; wall time **{results['wall_seconds']:.0f} s** ("
             + ", ".join(f"{k} {v:.0f} s" for k, v in results["section_seconds"].items()) + ").\n")
    r.append("## Summary: the issue's acceptance criteria, per hold-out\n")
    r.append(f"Ratios in brackets: the worst over the lengths (and over L2Q and L2P) of the method's figure "
             f"divided by the reference's (truth's skate, slerp's, spline's and inertialize's errors); `yes` when "
             f"the criterion holds. Skate: at most {SKATE_FACTOR:g}x the truth's at 15, 30, 45 frames. Goal: L2Q "
             f"and L2P at most {GOAL_FACTOR:g}x slerp's at 30 and 45 frames (at 30 fps; a hold-out of your own clips "
             "at another rate takes as long gaps).\n")
    for name, hold in holds.items():
        _acceptance_rows(r, name, hold["inbetween"])
    whole = [(name, hold["inbetween"]) for name, hold in holds.items()
             if hold["inbetween"].get("whole_clip") and criteria_lengths(hold["inbetween"])[1]]
    if whole:
        def goal_ratios(inb, k):  # the default with the whole clip, over slerp, at the goal's lengths
            wc, sl = inb["whole_clip"]["methods"][inb["default_method"]], inb["methods"]["slerp"]
            return " / ".join(_over(wc[str(n)][k], sl[str(n)][k], 3) for n in criteria_lengths(inb)[1])

        r.append(f"**A gap in a take** (the same windows with the whole clip as context instead of {N_PAST} frames "
                 "each side; see each hold-out's section): the default's L2Q and L2P as ratios to slerp's at the "
                 "goal's lengths: "
                 + "; ".join(f"{name} ({' / '.join(map(str, criteria_lengths(inb)[1]))} frames) L2Q "
                             f"{goal_ratios(inb, 'l2q')}, L2P {goal_ratios(inb, 'l2p')}" for name, inb in whole)
                 + ".\n")
    ratios = split_ratios(results) if results.get("more_splits") else None
    default = next(iter(holds.values()))["inbetween"]["default_method"]
    if ratios:
        mean = ratios["mean"][default]
        r.append(f"**Every Bandai split** (the style and content hold-outs and the {len(results['more_splits'])} "
                 f"of [More splits of bandai1](#more-splits-of-bandai1)): {default}'s mean ratio to slerp's L2Q "
                 + " / ".join(f"{mean[str(n)]['l2q']:.3f}" for n in SKATE_LENGTHS) + ", L2P "
                 + " / ".join(f"{mean[str(n)]['l2p']:.3f}" for n in SKATE_LENGTHS) + " at "
                 + " / ".join(str(n) for n in SKATE_LENGTHS) + " frames; its skate "
                 + " / ".join(f"{mean[str(n)]['skate']:.2f}" for n in SKATE_LENGTHS) + "x the truth's.\n")
    r.append("## Protocol\n")
    r.append("- Hold-outs: " + "; ".join(f"**{n}**: {h['split']['rule']}" for n, h in holds.items()) + ".")
    r.append(f"- In-betweening: windows of {cfg['n_past']} past + L + {cfg['n_future']} future frames starting "
             f"every {cfg['stride']} frames (windows of the longest L truncated per L, as LaFAN1). Every method sees "
             f"the context only: the {cfg['n_past']} past frames as clip A, the {cfg['n_future']} future frames as "
             "clip B, `align=False`, `alpha=0.5`, `key_at=L//2`; no method can read a frame of the gap.")
    r.append("- L2Q, L2P, NPSS as in LaFAN1 (window frame: root centred, turned to face a fixed direction "
             "at the last past frame; L2P divides by per-coordinate std of training windows of 50 frames, "
             "stride 20; signs of quaternions made consistent with the truth). MPJPE and all cm figures: the "
             "clip's unit times the hold-out's cm per unit.")
    pct = next(iter(holds.values()))["feet"]["floor_percentile"]
    r.append(f"- Foot skate (the standard measure): per window, the ground is the lowest height of any foot joint "
             f"(ankles and toes) over the window's frames; per joint and frame step, the horizontal speed times "
             f"`w = clip(2 - 2**(h / H), 0, 1)` with h the mean height above that ground at the step's two ends and "
             f"H = {cfg['skate_height_legs']:.5f} leg lengths (2.5 cm on Bandai's 80 cm leg); the mean over the "
             "L+1 steps from the last past frame to the first future frame and over the foot joints. No contact "
             "detection: a foot sliding near the ground always counts. A planted ankle sits well above a toe (7.5 cm "
             "on Bandai), so in effect the toes carry the measure (the truth's heel roll does not inflate its "
             "figure). The older contact-based measure (speed over steps where the joint is within "
             f"{metrics.CONTACT_HEIGHT:g} cm of its planted height, the {pct:g}th percentile of its height in "
             f"training, at both ends and slower than {metrics.CONTACT_SPEED:g} cm/s) is kept as a secondary "
             "table.")
    r.append("- Floor penetration: per window, the floor is the lowest foot joint in the context frames (the same "
             "for every method and the truth); per frame of the gap, the depth of the lowest foot joint under it "
             "(0 above it); the mean over the gap. The skate's ground is the window's own lowest foot, so a foot "
             "through the floor lowers it and makes every other foot count as higher: this measure shows it.")
    r.append(f"- Naturalness: per frame, joint positions relative to the root, the root's height and every joint's "
             f"velocity, all in the character's heading frame, z-scored over the reference frames; a window is "
             f"described by at most {cfg['natural_frames']} evenly spaced rebuilt frames; its naturalness is the "
             f"RMS distance to the nearest real window of the same length among the hold-out's test clips (data "
             f"no library was built from), starting every {cfg['natural_stride_s']:g} s, leaving out windows that "
             "overlap its own frames (so the truth row is the distance from real motion to other real motion).")
    r.append("- Pose validity: distance (KD-tree) from each rebuilt posture to the nearest training posture "
             "in the map's feature space (logmap radians, root height in leg lengths).")
    r.append("- Jerk: every third difference of global positions that touches a rebuilt frame.\n")
    for name, hold in holds.items():
        _holdout_section(r, name, hold, cfg)
    if ratios:
        _splits_section(r, results["more_splits"], ratios, default, whole_clip_ratios(results))
    if results.get("diagnostics"):
        _diagnostics_section(r, results)
    _speed_section(r, results)
    return "\n".join(r) + "\n"


def split_ratios(results: dict) -> dict:
    """Per Bandai split (the style and content hold-outs and every split of ``more_splits``), per
    method scored on all of them, per length of :data:`SKATE_LENGTHS`: ``{"l2q", "l2p"}`` as
    ratios to slerp's and ``skate`` as a ratio to the truth's. Also ``"mean"``: the mean of each
    ratio over the splits."""
    tables = {}
    for name, hold in results["holdouts"].items():
        if name in ("style", "content"):
            inb = hold["inbetween"]
            tables[name] = (inb["methods"], inb["truth"])
    for name, sp in results.get("more_splits", {}).items():
        tables[name] = (sp["methods"], sp["truth"])
    methods = [m for m in next(iter(results["more_splits"].values()))["methods"]
               if all(m in t[0] for t in tables.values())]
    out = {}
    for name, (meth, truth) in tables.items():
        out[name] = {m: {str(n): {"l2q": meth[m][str(n)]["l2q"] / meth["slerp"][str(n)]["l2q"],
                                  "l2p": meth[m][str(n)]["l2p"] / meth["slerp"][str(n)]["l2p"],
                                  "skate": meth[m][str(n)]["skate"] / truth[str(n)]["skate"]}
                         for n in SKATE_LENGTHS} for m in methods}
    out["mean"] = {m: {str(n): {k: float(np.mean([out[s][m][str(n)][k] for s in tables]))
                                for k in ("l2q", "l2p", "skate")} for n in SKATE_LENGTHS} for m in methods}
    return out


def whole_clip_ratios(results: dict) -> dict | None:
    """:func:`split_ratios` of the default with the whole clip as context (``whole_clip``), per
    Bandai split and their mean; None where a split lacks it (results of older code)."""
    tables = {name: hold["inbetween"] for name, hold in results["holdouts"].items() if name in ("style", "content")}
    tables.update(results.get("more_splits", {}))
    if not tables or any(t.get("whole_clip") is None for t in tables.values()):
        return None
    default = next(iter(results["holdouts"].values()))["inbetween"]["default_method"]
    def ratios(t, n):
        whole, slerp = t["whole_clip"]["methods"][default][n], t["methods"]["slerp"][n]
        return {"l2q": whole["l2q"] / slerp["l2q"], "l2p": whole["l2p"] / slerp["l2p"],
                "skate": whole["skate"] / t["truth"][n]["skate"]}

    out = {name: {str(n): ratios(t, str(n)) for n in SKATE_LENGTHS} for name, t in tables.items()}
    out["mean"] = {str(n): {k: float(np.mean([out[s][str(n)][k] for s in tables])) for k in ("l2q", "l2p", "skate")}
                   for n in SKATE_LENGTHS}
    return out


def _splits_section(r: list[str], splits: dict, ratios: dict, default: str, whole: dict | None = None) -> None:
    lengths = " / ".join(str(n) for n in SKATE_LENGTHS)
    r.append("## More splits of bandai1\n")
    r.append("The style and content hold-outs above are one split of bandai1 each, and the default's rules "
             "were developed on them. These splits hold out other whole styles or motion types, with the same "
             "protocol (the map and its library from the split's training side only, the windows of its test "
             "clips, the context alone), scored for the main methods' accuracy and foot skate: "
             + "; ".join(f"**{n}**: {sp['rule']} ({sp['windows']} windows)" for n, sp in splits.items()) + ".\n")
    r.append(f"Every Bandai split, at {lengths} frames: L2Q and L2P as ratios to slerp's, foot skate as a ratio "
             "to the truth's (lower is better; the mean of the ratios over the splits last).\n")
    body = []
    for name, per in ratios.items():
        for m, v in per.items():
            if m == "slerp":
                continue
            body.append([f"**{name}**" if name == "mean" else name, m]
                        + [" ".join(f"{v[str(n)][k]:.2f}" for n in SKATE_LENGTHS) for k in ("l2q", "l2p", "skate")])
    _table(r, ["split", "method", f"L2Q / slerp at {lengths}", f"L2P / slerp at {lengths}",
               f"skate / truth at {lengths}"], body)
    goal = [ratios["mean"][default][str(n)]["l2q"] for n in GOAL_LENGTHS]
    r.append(f"The default ({default}) over all {len(ratios) - 1} splits: L2Q "
             + " and ".join(f"{g:.3f}x" for g in goal) + f" slerp's at {' and '.join(map(str, GOAL_LENGTHS))} "
             f"frames (goal: {GOAL_FACTOR:g}x).\n")
    if whole:
        r.append(f"A gap in a take (the whole clip as context instead of {N_PAST} frames each side), every split: "
                 f"the default's L2Q and L2P as ratios to slerp's, its skate to the truth's, at {lengths} frames.\n")
        _table(r, ["split", f"L2Q / slerp at {lengths}", f"L2P / slerp at {lengths}", f"skate / truth at {lengths}"],
               [[f"**{name}**" if name == "mean" else name]
                + [" ".join(f"{v[str(n)][k]:.2f}" for n in SKATE_LENGTHS) for k in ("l2q", "l2p", "skate")]
                for name, v in whole.items()])
    for name, sp in splits.items():
        r.append(f"### {name}: {sp['rule']}\n")
        r.append(f"{sp['test_clips']} test clips, {sp['windows']} windows; {sp['train_clips']} training clips. "
                 f"Values at {lengths} frames.\n")
        body = [[m] + [" ".join(f"{sp['methods'][m][str(n)][k]:.3f}" for n in SKATE_LENGTHS) for k in ("l2q", "l2p")]
                + [" ".join(f"{sp['methods'][m][str(n)]['skate']:.2f}" for n in SKATE_LENGTHS)] for m in sp["methods"]]
        body.append(["truth", "-", "-", " ".join(f"{sp['truth'][str(n)]['skate']:.2f}" for n in SKATE_LENGTHS)])
        _table(r, ["method", "L2Q", "L2P", "foot skate cm/s"], body)


def _diagnostics_section(r: list[str], results: dict) -> None:
    d = results["diagnostics"]
    hold = results["holdouts"]["style"]
    inb = hold["inbetween"]
    lengths = inb["lengths"]
    dm = inb["default_method"]
    r.append("## Diagnostics (keyed methods, style hold-out)\n")
    r.append("Distance in the map's feature space from candidate postures to the true posture at `key_at` "
             "(mean over windows):\n")
    keys = list(next(iter(d["key_distance"].values())))
    _table(r, ["L"] + keys, [[n] + [d["key_distance"][str(n)][k] for k in keys] for n in lengths])
    r.append("Per bone class (distance over that class's dimensions; the map's radius per class: "
             + ", ".join(f"{c} {v:.3f}" for c, v in zip(CLASSES, hold["map"]["radius"])) + "):\n")
    _table(r, ["L", "class", "blend to true", "upm key to true", "nearest neuron to true"],
           [[n, cls, v["blend"], v["upm_key"], v["nearest_neuron"]]
            for n in lengths for cls, v in d["key_distance_by_class"][str(n)].items()])
    r.append("The same spline with stand-in keys (these read the whole clip on purpose: the oracle key is the "
             "truth): `blend-key` = the alpha-blend itself (no map), `oracle-key` = the true posture at `key_at` "
             "(an upper bound for any key), `self-map-key` = the key from a map learned from the window's clip "
             "alone, without the missing frames (as `posturemap transition` does without `--map`).\n")
    r.append("Stand-ins that test the spline itself: `spline-v0` = the keyless spline with zero angular velocity "
             "at both seams (root translation keeps its velocity), `blend-key-v0` = `blend-key` with zero "
             "angular seam velocity, `upm-lerp-root` = `upm`'s frames with the root translation of `slerp` "
             "(LERP).\n")
    for metric in ("l2q", "l2p", "root_error_cm", "pose_error_cm", "skate", "validity"):
        body = [[v] + [d["variants"][v][str(n)][metric] for n in lengths] for v in d["variants"]]
        refs = ("spline", "upm") + ((dm,) if dm != "upm" else ()) + ("slerp",)
        body += [[m] + [inb["methods"][m][str(n)][metric] for n in lengths] for m in refs if m in inb["methods"]]
        r.append(f"{metric}:\n")
        _table(r, ["key"] + [f"L={n}" for n in lengths], body)
    if d.get("sweep"):
        r.append("upm with other `alpha` and `key_at` (L2Q / L2P):\n")
        body = []
        for n, rows in d["sweep"].items():
            for v in rows.values():
                body.append([n, v["alpha"], v["key_at"], v["l2q"], v["l2p"]])
        _table(r, ["L", "alpha", "key_at", "L2Q", "L2P"], body)


def _speed_section(r: list[str], results: dict) -> None:
    cfg = results["config"]
    spd = results["speed"]
    r.append("## Speed\n")
    r.append(f"On the {spd['holdout']} hold-out's map; the machine was shared with other jobs. Transition latency, "
             f"`TransitionEngine.generate`, length {cfg['cross_length']}, {cfg['latency_calls']} "
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


_NUMBER_LIST = re.compile(r"\[(?:\s*(?:-?[0-9][0-9.eE+-]*|null)\s*,)*\s*(?:-?[0-9][0-9.eE+-]*|null)\s*\]")


def dumps(results: dict) -> str:
    """results.json's text: indented JSON with every list of numbers on one line."""
    text = json.dumps(results, indent=1)
    return _NUMBER_LIST.sub(lambda m: re.sub(r"\s+", "", m.group(0)).replace(",", ", "), text) + "\n"


def jsonable(x):
    """A JSON-ready copy: numpy scalars and arrays to Python, Paths to str, tuple keys joined."""
    if isinstance(x, dict):
        return {(k if isinstance(k, str) else "/".join(map(str, k)) if isinstance(k, tuple) else str(k)):
                jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
