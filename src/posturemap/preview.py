"""Filmstrip pictures of motions (PNG, matplotlib's Agg renderer: the ``preview`` extra).

:func:`filmstrip` draws consecutive segments of motion (e.g. A's last frames, the transition,
B's first frames), each in its own colour, in two views:

- **side**: stick figures of every ``every``-th frame, left to right in time, each placed
  relative to its own centre (so postures stay readable however far the body travels), seen
  along the horizontal axis across the main direction of travel;
- **top**: the real ground plan: the path of the body's centre, the figures' feet, and
  footprints where a foot is planted.

Foot contacts (low and slow ankles, with :mod:`posturemap.feet`'s thresholds in leg lengths)
are marked with filled dots in both views. Inputs are plain arrays of global joint positions;
:func:`transition_filmstrip` builds the segments of a transition result. matplotlib is imported
on first use only (``pip install 'posturemap[preview]'``).
"""

from __future__ import annotations

import io
import os

import numpy as np

from .errors import UserError, require_extra
from .feet import CONTACT_HEIGHT, CONTACT_SPEED, leg_chains
from .motion import Motion

COLOURS = {"A": "#7a8491", "transition": "#e8590c", "B": "#1c7ed6"}
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
    """Write a filmstrip PNG of consecutive motion segments to ``path`` (atomically).

    Parameters
    ----------
    segments : sequence of ``(label, positions, colour)``; ``positions`` (F_k, J, 3) global joint
        positions of consecutive frames (one skeleton), ``colour`` any matplotlib colour or None
        (:data:`COLOURS` by label, else :data:`OTHER_COLOURS` in turn)
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
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    segs = [(str(label), np.asarray(pos, dtype=float), colour) for label, pos, colour in segments]
    if not segs or any(p.ndim != 3 or p.shape[-1] != 3 or len(p) == 0 for _, p, _ in segs):
        raise ValueError("segments must be (label, positions (F, J, 3) with F >= 1, colour)")
    parents = np.asarray(parents)
    feet = list(feet)
    others = iter(OTHER_COLOURS * 4)
    segs = [(label, pos, colour or COLOURS.get(label) or next(others)) for label, pos, colour in segs]
    allpos = np.concatenate([p for _, p, _ in segs])
    total = len(allpos)
    every = every or max(1, int(np.ceil(total / 18)))
    bones = _rigid_bones(allpos, parents)
    body = sorted({j for bone in bones for j in bone}) or list(range(len(parents)))
    allpos_body = allpos[:, body]
    along, across = _horizontal_axes(allpos_body, up)
    height = float(np.median(np.ptp(allpos_body[..., up], axis=1))) or 1.0
    leg = _leg_length(allpos, parents, feet) or 0.5 * height
    contacts = foot_contacts(allpos[:, feet], fps, up, leg) if feet else np.zeros((total, 0), dtype=bool)

    spacing = 0.55 * height
    # Panel heights from the views' extents (equal aspect), within sensible bounds.
    plan = np.stack([allpos_body @ along, allpos_body @ across], axis=-1).reshape(-1, 2)
    plan_w, plan_h = np.ptp(plan, axis=0) + 0.1 * height
    side_w = (total / every) * spacing + height
    inner = 0.92 * width_px
    side_px = float(np.clip(inner * 1.25 * height / side_w, 110, 320))
    top_px = float(np.clip(inner * plan_h / plan_w, 110, 320))
    fig = Figure(figsize=(width_px / 100, (side_px + top_px + 120) / 100), dpi=100)
    FigureCanvasAgg(fig)
    side, top = fig.subplots(2, 1, gridspec_kw={"height_ratios": [side_px, top_px]})
    start = 0
    floor = float(allpos_body[..., up].min())
    for label, pos, colour in segs:
        frames = np.arange(start, start + len(pos))
        shown = frames[(frames % every == 0) | (frames == frames[-1])]
        lines, dots = [], []
        for f in shown:
            p = allpos[f]
            x = p @ along - (p[body] @ along).mean() + (f / every) * spacing
            y = p[:, up] - floor
            lines.extend([[(x[j], y[j]), (x[k], y[k])] for j, k in bones])
            dots.extend((x[j], y[j]) for i, j in enumerate(feet) if contacts[f, i])
        side.add_collection(LineCollection(lines, colors=colour, linewidths=1.3, label=f"{label} ({len(pos)} frames)"))
        if dots:
            side.scatter(*np.array(dots).T, s=14, color=colour, edgecolors="black", linewidths=0.5, zorder=3)
        # Top: the path of the body's centre, every shown figure's feet, footprints.
        centre = pos[:, body].mean(axis=1)
        top.plot(centre @ along, centre @ across, color=colour, linewidth=2)
        for i, j in enumerate(feet):
            planted = contacts[frames, i]
            top.scatter(pos[planted, j] @ along, pos[planted, j] @ across, s=10, color=colour,
                        edgecolors="black", linewidths=0.4, zorder=3)
        top_lines = [[(allpos[f, j] @ along, allpos[f, j] @ across), (allpos[f, k] @ along, allpos[f, k] @ across)]
                     for f in shown for j, k in bones]
        top.add_collection(LineCollection(top_lines, colors=colour, linewidths=0.6, alpha=0.45))
        start += len(pos)
    side.autoscale_view()
    side.set_aspect("equal", adjustable="datalim")
    side.set_yticks([])
    side.set_xticks([])
    side.set_title(f"side view, every {every} frames ({every / fps:.2f} s) left to right; "
                   f"dots: planted feet", fontsize=9, loc="left")
    side.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False, ncol=len(segs))
    top.autoscale_view()
    top.set_aspect("equal", adjustable="datalim")
    top.set_title("top view: path of the body's centre, feet, footprints", fontsize=9, loc="left")
    top.tick_params(labelsize=7)
    if unit:
        top.set_xlabel(unit, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10, x=0.01, ha="left")
    for ax in (side, top):
        for spine in ("top", "right"):
            ax.spines[spine].set_visible(False)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    from .bvh import write_bytes_atomic

    try:
        write_bytes_atomic(path, buf.getvalue())
    except OSError as e:
        raise UserError(os.fspath(path), f"cannot write file ({e.strerror or e})") from None


def transition_filmstrip(result: Motion, a_frames: int, length: int, path, up: int = 1, context: int | None = None,
                         title: str | None = None, unit: str = "") -> None:
    """Filmstrip of a transition result: A's last ``context`` frames, the ``length`` new frames,
    B's first ``context`` frames (default context: one second, at most what each part has).

    ``result`` holds A's ``a_frames`` frames, then the new frames, then B's (as
    :func:`posturemap.transition.transition` returns it).
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


__all__ = ["COLOURS", "CONTACT_HEIGHT", "CONTACT_SPEED", "filmstrip", "foot_contacts", "transition_filmstrip"]
