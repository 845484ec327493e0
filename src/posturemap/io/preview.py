"""Filmstrip pictures of motions (PNG, matplotlib's Agg renderer: the ``preview`` extra).

:func:`filmstrip` draws consecutive segments of motion (e.g. A's last frames, the transition,
B's first frames), each in its own colour, in two views:

- **side**: stick figures of every ``every``-th frame, left to right in time, each placed
  relative to its own centre (so postures stay readable however far the body travels), seen
  along the horizontal axis across the main direction of travel;
- **top**: the real ground plan: the path of the body's centre, the figures' feet, and
  footprints where a foot is planted.

Foot contacts (low and slow ankles, with :mod:`posturemap.synth.feet`'s thresholds in leg lengths)
are marked with filled dots in both views. Inputs are plain arrays of global joint positions;
:func:`transition_filmstrip` builds the segments of a transition result; :func:`filmstrip_rows`
stacks side views (e.g. the truth and each method on one window). matplotlib is imported
on first use only (``pip install 'posturemap[preview]'``).
"""

from __future__ import annotations

import io
import os

import numpy as np

from ..errors import UserError, require_extra
from ..core.joints import CONTACT_HEIGHT, CONTACT_SPEED, leg_chains
from ..core.motion import Motion

COLOURS = {"A": "#7a8491", "transition": "#e8590c", "B": "#1c7ed6", "context": "#7a8491", "truth": "#212529"}
OTHER_COLOURS = ("#2b8a3e", "#862e9c", "#c92a2a", "#495057")


def foot_contacts(feet: np.ndarray, fps: float, up: int, leg: float) -> np.ndarray:
    """Planted feet: bool (F, K) for foot positions ``feet (F, K, 3)``.

    A foot is planted when it is within ``CONTACT_HEIGHT`` leg lengths of its lowest height in
    these frames and moves slower than ``CONTACT_SPEED`` leg lengths per second (horizontally).
    ``leg`` is the leg length in the positions' unit.
    """
    if feet.shape[1] == 0 or len(feet) < 2:
        return np.zeros(feet.shape[:2], dtype=bool)
    h = feet[..., up]
    low = h < h.min(axis=0) + CONTACT_HEIGHT * leg
    flat = np.delete(feet, up, axis=-1)
    step = np.linalg.norm(np.diff(flat, axis=0), axis=-1) * fps  # (F-1, K)
    speed = np.concatenate([step[:1], 0.5 * (step[1:] + step[:-1]), step[-1:]])  # per frame
    return low & (speed < CONTACT_SPEED * leg)


def _leg_length(positions: np.ndarray, parents: np.ndarray, feet) -> float:
    """Median shin + thigh length (ankle to its parent to its grandparent) of ``feet``; 0 if none."""
    lengths = []
    for j in feet:
        shin = parents[j]
        thigh = parents[shin] if shin >= 0 else -1
        if thigh >= 0:
            lengths.append(np.linalg.norm(positions[:, j] - positions[:, shin], axis=-1)
                           + np.linalg.norm(positions[:, shin] - positions[:, thigh], axis=-1))
    return float(np.median(lengths)) if lengths else 0.0


def _rigid_bones(positions: np.ndarray, parents: np.ndarray) -> list[tuple[int, int]]:
    """(joint, parent) pairs whose distance stays the same over the frames (within 1%): the
    skeleton's bones, without links to reference nodes that slide under the body (Bandai's
    ``joint_Root``)."""
    out = []
    for j, p in enumerate(parents):
        if p >= 0:
            d = np.linalg.norm(positions[:, j] - positions[:, p], axis=-1)
            if np.ptp(d) <= 0.01 * max(float(d.mean()), 1e-12):
                out.append((j, int(p)))
    return out


def _horizontal_axes(points: np.ndarray, up: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (3,) ``(along, across)`` of the ground plane: ``along`` the main direction
    of the points' spread (travel, for a moving body), ``across`` perpendicular to it."""
    h = [a for a in range(3) if a != up]
    flat = points.reshape(-1, 3)[:, h]
    flat = flat - flat.mean(axis=0)
    cov = flat.T @ flat
    vals, vecs = np.linalg.eigh(cov)
    main = vecs[:, int(np.argmax(vals))]
    along, across = np.zeros(3), np.zeros(3)
    along[h] = main
    across[h] = [-main[1], main[0]]
    return along, across


def filmstrip(segments, path, parents, up: int = 1, fps: float = 30.0, feet=(), every: int | None = None,
              title: str | None = None, unit: str = "", width_px: int = 1200) -> None:
    """Write a filmstrip PNG of consecutive motion segments to ``path`` (atomically): the side
    view above, the top view below.

    Parameters
    ----------
    segments : sequence of ``(label, positions, colour)``; ``positions`` (F_k, J, 3) global joint
        positions of consecutive frames (one skeleton), ``colour`` any matplotlib colour or None
        (:data:`COLOURS` by label, else :data:`OTHER_COLOURS` in turn, one colour per label)
    path : PNG file to write
    parents : (J,) parent index per joint, -1 for roots (bones are drawn joint to parent)
    up : up axis 0, 1, 2 of the positions
    fps : frames per second (foot speeds, the time axis label)
    feet : joint indices of the feet, for contact marks (empty: none)
    every : draw every ``every``-th frame in the side view (default: about 18 figures in all)
    title : text above the picture
    unit : the positions' length unit, for the axis labels
    width_px : picture width in pixels (the height follows from the views' extents)
    """
    require_extra("preview", "matplotlib", what="--preview")
    strip = _prepare(segments, parents, up, fps, feet, every)
    plan = np.stack([strip["body_pos"] @ strip["along"], strip["body_pos"] @ strip["across"]], axis=-1)
    plan_w, plan_h = np.ptp(plan.reshape(-1, 2), axis=0) + 0.1 * strip["height"]
    inner = 0.92 * width_px
    side_px = _side_px(strip, inner)
    top_px = float(np.clip(inner * plan_h / plan_w, 110, 320))
    fig, (side, top) = _figure(width_px, [side_px, top_px], 120)
    _draw_side(side, strip)
    side.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False, ncol=len(strip["segs"]))
    _draw_top(top, strip, unit)
    _save(fig, path, title)


def filmstrip_rows(rows, path, parents, up: int = 1, fps: float = 30.0, feet=(), every: int | None = None,
                   title: str | None = None, width_px: int = 1200) -> None:
    """Side-view filmstrips stacked in one PNG, one row per motion (e.g. the truth, then one row
    per method on the same window): the same frames drawn at the same places in every row.

    ``rows`` is a sequence of ``(row_title, segments)``, ``segments`` as for :func:`filmstrip`;
    ``every`` defaults to about 18 figures for the longest row. Other parameters as for
    :func:`filmstrip`.
    """
    require_extra("preview", "matplotlib", what="--preview")
    rows = list(rows)
    if not rows:
        raise ValueError("rows must hold at least one (title, segments)")
    longest = max(sum(len(np.asarray(p)) for _, p, _ in segs) for _, segs in rows)
    every = every or max(1, int(np.ceil(longest / 18)))
    palette = _palette(*(segs for _, segs in rows))
    strips = [(row_title, _prepare(segs, parents, up, fps, feet, every, palette)) for row_title, segs in rows]
    inner = 0.92 * width_px
    fig, axes = _figure(width_px, [_side_px(s, inner) for _, s in strips], 60)
    for ax, (row_title, strip) in zip(np.atleast_1d(axes), strips):
        _draw_side(ax, strip, f"{row_title}: " if row_title else "")
        ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), fontsize=7, frameon=False,
                  ncol=len(strip["segs"]))
    _save(fig, path, title)


def _palette(*segment_lists) -> dict[str, str]:
    """A colour per segment label: :data:`COLOURS` by label, other labels :data:`OTHER_COLOURS`
    in turn (the same label always the same colour)."""
    out = dict(COLOURS)
    k = 0
    for segs in segment_lists:
        for label, _, _ in segs:
            if str(label) not in out:
                out[str(label)] = OTHER_COLOURS[k % len(OTHER_COLOURS)]
                k += 1
    return out


def _prepare(segments, parents, up: int, fps: float, feet, every: int | None, palette: dict | None = None) -> dict:
    """What both views need: segments with colours, bones, body joints, axes, contacts."""
    segs = [(str(label), np.asarray(pos, dtype=float), colour) for label, pos, colour in segments]
    if not segs or any(p.ndim != 3 or p.shape[-1] != 3 or len(p) == 0 for _, p, _ in segs):
        raise ValueError("segments must be (label, positions (F, J, 3) with F >= 1, colour)")
    parents = np.asarray(parents)
    feet = list(feet)
    palette = palette or _palette(segs)
    segs = [(label, pos, colour or palette[label]) for label, pos, colour in segs]
    allpos = np.concatenate([p for _, p, _ in segs])
    total = len(allpos)
    bones = _rigid_bones(allpos, parents)
    body = sorted({j for bone in bones for j in bone}) or list(range(len(parents)))
    body_pos = allpos[:, body]
    along, across = _horizontal_axes(body_pos, up)
    height = float(np.median(np.ptp(body_pos[..., up], axis=1))) or 1.0
    leg = _leg_length(allpos, parents, feet) or 0.5 * height
    return {"segs": segs, "allpos": allpos, "body": body, "body_pos": body_pos, "bones": bones,
            "along": along, "across": across, "height": height, "up": up, "fps": fps, "feet": feet,
            "every": every or max(1, int(np.ceil(total / 18))), "spacing": 0.55 * height,
            "floor": float(body_pos[..., up].min()),
            "contacts": foot_contacts(allpos[:, feet], fps, up, leg) if feet else np.zeros((total, 0), dtype=bool)}


def _side_px(strip: dict, inner: float) -> float:
    """Height in pixels of a side view ``inner`` pixels wide (equal aspect), within bounds."""
    side_w = (len(strip["allpos"]) / strip["every"]) * strip["spacing"] + strip["height"]
    return float(np.clip(inner * 1.25 * strip["height"] / side_w, 110, 320))


def _shown(strip: dict):
    """Per segment: (label, positions, colour, its frame numbers, the frames drawn)."""
    start, every = 0, strip["every"]
    for label, pos, colour in strip["segs"]:
        frames = np.arange(start, start + len(pos))
        yield label, pos, colour, frames, frames[(frames % every == 0) | (frames == frames[-1])]
        start += len(pos)


def _draw_side(ax, strip: dict, prefix: str = "") -> None:
    """Stick figures left to right in time, each about its own centre; dots on planted feet."""
    from matplotlib.collections import LineCollection

    allpos, along, up, every = strip["allpos"], strip["along"], strip["up"], strip["every"]
    for label, pos, colour, _, shown in _shown(strip):
        lines, dots = [], []
        for f in shown:
            p = allpos[f]
            x = p @ along - (p[strip["body"]] @ along).mean() + (f / every) * strip["spacing"]
            y = p[:, up] - strip["floor"]
            lines.extend([[(x[j], y[j]), (x[k], y[k])] for j, k in strip["bones"]])
            dots.extend((x[j], y[j]) for i, j in enumerate(strip["feet"]) if strip["contacts"][f, i])
        ax.add_collection(LineCollection(lines, colors=colour, linewidths=1.3, label=f"{label} ({len(pos)} frames)"))
        if dots:
            ax.scatter(*np.array(dots).T, s=14, color=colour, edgecolors="black", linewidths=0.5, zorder=3)
    ax.autoscale_view()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_yticks([])
    ax.set_xticks([])
    ax.set_title(f"{prefix}side view, every {every} frames ({every / strip['fps']:.2f} s) left to right; "
                 f"dots: planted feet", fontsize=9, loc="left")


def _draw_top(ax, strip: dict, unit: str) -> None:
    """The ground plan: path of the body's centre, the drawn figures faintly, footprints."""
    from matplotlib.collections import LineCollection

    allpos, along, across = strip["allpos"], strip["along"], strip["across"]
    for _, pos, colour, frames, shown in _shown(strip):
        centre = pos[:, strip["body"]].mean(axis=1)
        ax.plot(centre @ along, centre @ across, color=colour, linewidth=2)
        for i, j in enumerate(strip["feet"]):
            planted = strip["contacts"][frames, i]
            ax.scatter(pos[planted, j] @ along, pos[planted, j] @ across, s=10, color=colour,
                       edgecolors="black", linewidths=0.4, zorder=3)
        lines = [[(allpos[f, j] @ along, allpos[f, j] @ across), (allpos[f, k] @ along, allpos[f, k] @ across)]
                 for f in shown for j, k in strip["bones"]]
        ax.add_collection(LineCollection(lines, colors=colour, linewidths=0.6, alpha=0.45))
    ax.autoscale_view()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("top view: path of the body's centre, feet, footprints", fontsize=9, loc="left")
    ax.tick_params(labelsize=7)
    if unit:
        ax.set_xlabel(unit, fontsize=8)


def _figure(width_px: int, heights_px: list[float], margin_px: float):
    """A matplotlib Figure (Agg canvas, no pyplot) with one axes row per height."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_px / 100, (sum(heights_px) + margin_px + 40 * len(heights_px)) / 100), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(heights_px), 1, gridspec_kw={"height_ratios": heights_px}, squeeze=False)[:, 0]
    for ax in axes:
        for spine in ("top", "right"):
            ax.spines[spine].set_visible(False)
    return fig, axes


def _save(fig, path, title: str | None) -> None:
    """Render ``fig`` to PNG and write it to ``path`` atomically (one-line error if it cannot)."""
    from .bvh import write_bytes_atomic

    if title:
        fig.suptitle(title, fontsize=10, x=0.01, ha="left")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    try:
        write_bytes_atomic(path, buf.getvalue())
    except OSError as e:
        raise UserError(os.fspath(path), f"cannot write file ({e.strerror or e})") from None


def transition_filmstrip(result: Motion, a_frames: int, length: int, path, up: int = 1, context: int | None = None,
                         title: str | None = None, unit: str = "") -> None:
    """Filmstrip of a transition result: A's last ``context`` frames, the ``length`` new frames,
    B's first ``context`` frames (default context: one second, at most what each part has).

    ``result`` holds A's ``a_frames`` frames, then the new frames, then B's (as
    :func:`posturemap.synth.engine.transition` returns it).
    """
    context = int(round(result.fps)) if context is None else context
    t0, t1 = a_frames, a_frames + length
    if not (0 < t0 < t1 < len(result)):
        raise ValueError(f"a_frames {a_frames} and length {length} do not fit a result of {len(result)} frames")
    gpos = result.global_positions()
    sk = result.skeleton
    chains = leg_chains(sk)
    segments = [("A", gpos[max(0, t0 - context): t0], None), ("transition", gpos[t0:t1], None),
                ("B", gpos[t1: t1 + context], None)]
    filmstrip(segments, path, sk.parents, up=up, fps=result.fps, feet=[c[2] for c in chains], title=title,
              unit=unit)


__all__ = ["COLOURS", "CONTACT_HEIGHT", "CONTACT_SPEED", "filmstrip", "filmstrip_rows", "foot_contacts",
           "transition_filmstrip"]
