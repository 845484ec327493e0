"""Scoring of rebuilt windows: accuracy, foot skate, naturalness, validity, jerk, per content."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import metrics
from ..core import quat
from ..core.motion import Motion
from ..core.skeleton import fk
from .protocol import N_FUTURE, N_PAST

NATURAL_FRAMES = 10  # naturalness compares at most this many evenly spaced frames of a window
NATURAL_STRIDE_S = 0.1  # reference windows start every 0.1 s


@dataclass
class Context:
    """What scoring needs besides the motions (skeleton, frames, training statistics).

    feet : indices of the foot joints; floor : (K,) their planted heights (a low percentile
    of their training heights, clip unit); std : (J, 3) L2P statistics; index : KD-tree of
    training postures (None: no pose validity, reported as None); skate_height : H of the skate
    measure (clip unit); cm : centimetres per clip unit (every figure in cm is the clip's figure
    times ``cm``).
    """

    skeleton: object
    space: object
    root: int
    up: int
    fps: float
    feet: np.ndarray
    floor: np.ndarray
    std: np.ndarray
    index: object
    skate_height: float = 2.5
    cm: float = 1.0


def global_windows(rots: np.ndarray, pos: np.ndarray, parents) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations (N, T, J, 4) and positions (N, T, J, 3) of local windows."""
    return fk(parents, rots, pos)


def window_features(ctx: Context, rots: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Active posture features (N*T, D) of local frames (N, T, J, ...)."""
    n = rots.shape[0] * rots.shape[1]
    j = rots.shape[2]
    m = Motion(ctx.skeleton, rots.reshape(n, j, 4), pos.reshape(n, j, 3), ctx.fps)
    return ctx.space.encode(m)[:, ctx.space.active]


def skate_scores(ctx: Context, gpos: np.ndarray, steps: slice) -> tuple[np.ndarray, float]:
    """Foot skate of windows of global positions (N, T, J, 3), in cm/s.

    Returns ``(per_window, contact)``: the height-weighted skate (:func:`metrics.weighted_skate`;
    ground = the lowest foot joint over all T frames, no per-joint offset; averaged over
    ``steps``) per window (N,), and the older
    contact-based skate over the frames that ``steps`` spans (one mean over all contact steps).
    """
    feet = gpos[:, :, ctx.feet]
    per = metrics.weighted_skate(feet, ctx.fps, ctx.up, ctx.skate_height, None, steps) * ctx.cm
    span = feet[:, steps.start: steps.stop + 1]
    contacts = metrics.foot_contacts(span, ctx.fps, ctx.up, ctx.floor, metrics.CONTACT_HEIGHT / ctx.cm,
                                     metrics.CONTACT_SPEED / ctx.cm)
    return per, metrics.foot_skate(span, ctx.fps, ctx.up, contacts)[0] * ctx.cm


def penetration(ctx: Context, gpos: np.ndarray, length: int) -> np.ndarray:
    """Floor penetration of windows of global positions (N, N_PAST + L + N_FUTURE, J, 3) per
    window (N,), in the clip's unit (:func:`metrics.floor_penetration`: the floor is the lowest
    foot joint in the context frames, the depth averaged over the gap's)."""
    context = np.ones(gpos.shape[1], dtype=bool)
    context[N_PAST: N_PAST + length] = False
    return metrics.floor_penetration(gpos[:, :, ctx.feet], ctx.up, context, slice(N_PAST, N_PAST + length))


def foot_float(ctx: Context, gpos: np.ndarray, length: int) -> np.ndarray:
    """Feet off the floor in windows of global positions (N, N_PAST + L + N_FUTURE, J, 3), per
    window (N,), in the clip's unit (:func:`metrics.foot_float`: how far the lowest foot joint
    rises in the gap above the highest it reaches in the context frames)."""
    context = np.ones(gpos.shape[1], dtype=bool)
    context[N_PAST: N_PAST + length] = False
    return metrics.foot_float(gpos[:, :, ctx.feet], ctx.up, context, slice(N_PAST, N_PAST + length))


def natural_frames(length: int) -> np.ndarray:
    """Indices of the (at most :data:`NATURAL_FRAMES`) evenly spaced frames naturalness compares."""
    return np.unique(np.round(np.linspace(0, length - 1, min(length, NATURAL_FRAMES))).astype(np.int64))


def natural_reference(ctx: Context, clips: list[Motion]) -> dict:
    """Per-frame pose and velocity features of the reference clips, z-scored.

    Returns ``{"frames": [(F_c - 1, D) per clip, row f - 1 = frame f], "mean", "std"}``;
    mean and std (D,) over all reference frames (a constant feature is divided by 1).
    """
    feats = []
    for m in clips:
        g_r, g_p = fk(ctx.skeleton.parents, m.rotations, m.positions)
        feats.append(metrics.motion_features(g_p, g_r, ctx.root, ctx.up, ctx.fps))
    allf = np.concatenate(feats)
    mean, std = allf.mean(0), allf.std(0)
    std = np.where(std < 1e-9 * max(float(std.max()), 1e-300), 1.0, std)
    return {"frames": [(f - mean) / std for f in feats], "mean": mean, "std": std}


def naturalness_fn(ctx: Context, ref: dict, windows, length: int):
    """A function: rebuilt windows -> naturalness, for the ``windows`` at one length.

    The function takes local rotations (K * N, L + 1, J, 4) and positions (K * N, L + 1, J, 3):
    the last past-context frame and the L rebuilt frames of the N windows, for K methods in a
    row (any K >= 1, so one pass over the reference serves every method). It returns (K * N,):
    the distance (root mean square over z-scored features) from each window's L rebuilt frames
    (pose and velocity, :func:`metrics.motion_features`, at :func:`natural_frames`) to the
    nearest real window of L frames of the reference clips, which start every
    :data:`NATURAL_STRIDE_S` seconds; reference windows that overlap the window's own frames
    in its own clip are left out, so the truth is never its own neighbour.
    """
    idx = natural_frames(length)
    stride = max(1, round(NATURAL_STRIDE_S * ctx.fps))
    descs, owner = [], []
    for c, f in enumerate(ref["frames"]):
        starts = np.arange(1, len(f) - length + 2, stride)  # first frame f0 >= 1 (needs f0 - 1)
        if len(starts):
            descs.append(f[(starts - 1)[:, None] + idx[None]].reshape(len(starts), -1))
            owner.append(np.stack([np.full(len(starts), c), starts], 1))
    refs, owner = np.concatenate(descs), np.concatenate(owner)
    refs_sq = (refs * refs).sum(1)
    span = N_PAST + length + N_FUTURE
    wc = np.array([c for c, _ in windows])[:, None]
    ws = np.array([s for _, s in windows])[:, None]
    exclude = (owner[None, :, 0] == wc) & (owner[None, :, 1] < ws + span) & (owner[None, :, 1] + length > ws)

    def score(rots: np.ndarray, pos: np.ndarray) -> np.ndarray:
        g_r, g_p = global_windows(rots, pos, ctx.skeleton.parents)
        f = (metrics.motion_features(g_p, g_r, ctx.root, ctx.up, ctx.fps) - ref["mean"]) / ref["std"]
        k = len(f) // len(windows)
        return metrics.nearest_window_distance(f[:, idx].reshape(len(f), -1), refs, np.tile(exclude, (k, 1)),
                                               refs_sq)

    return score


def rebuilt_frames(truth: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """The last past-context frame of windows ``truth (N, 20 + L, J, ...)`` followed by the
    rebuilt frames ``pred (N, L, J, ...)``: (N, L + 1, J, ...), what naturalness reads."""
    return np.concatenate([truth[:, N_PAST - 1: N_PAST], pred], axis=1)


def truth_globals(ctx: Context, truth_r, truth_p) -> tuple:
    """Global rotations and positions of true windows (N, T, J, ...), and the same in the
    window frame (:func:`metrics.normalize_windows`): what :func:`score_inbetween` needs of the
    truth, to compute once per length."""
    tg_r, tg_p = global_windows(truth_r, truth_p, ctx.skeleton.parents)
    t_pos, t_rot = metrics.normalize_windows(tg_p, tg_r, ctx.root, ctx.up, N_PAST - 1)
    return tg_r, tg_p, t_pos, t_rot


def score_inbetween(ctx: Context, truth_r, truth_p, pred_r, pred_p, length: int,
                    accuracy_only: bool = False, natural=None, truth_g: tuple | None = None) -> dict:
    """Every metric for windows (N, 20 + L, J, ...) of truth and rebuilt frames (N, L, J, ...).

    ``accuracy_only``: only L2Q, L2P and the foot skate (skips the pose-validity queries, the slow
    part).
    ``natural``: the naturalness of each window (N,) (:func:`naturalness_fn`), or None.
    ``truth_g``: :func:`truth_globals` of the truth when already known.
    Per-window values of L2Q, L2P, MPJPE, skate (and naturalness) go to ``per_window``.
    """
    sl = slice(N_PAST, N_PAST + length)
    full_r, full_p = truth_r.copy(), truth_p.copy()
    full_r[:, sl], full_p[:, sl] = pred_r, pred_p
    tg_r, tg_p, t_pos, t_rot = truth_g or truth_globals(ctx, truth_r, truth_p)
    pg_r, pg_p = global_windows(full_r, full_p, ctx.skeleton.parents)
    p_pos, p_rot = metrics.normalize_windows(pg_p, pg_r, ctx.root, ctx.up, N_PAST - 1, tg_p, tg_r)
    skate, contact = skate_scores(ctx, pg_p, slice(N_PAST - 1, N_PAST + length))
    if accuracy_only:
        return {"l2q": metrics.l2q(p_rot[:, sl], t_rot[:, sl]),
                "l2p": metrics.l2p(p_pos[:, sl], t_pos[:, sl], ctx.std), "skate": float(skate.mean())}
    t_q = quat.unroll(t_rot[:, sl], axis=1)
    p_q = metrics.align_signs(p_rot[:, sl], t_q)
    n = len(truth_r)
    root_err = np.linalg.norm(pg_p[:, sl, ctx.root] - tg_p[:, sl, ctx.root], axis=-1)
    rel_p = pg_p[:, sl] - pg_p[:, sl, ctx.root: ctx.root + 1]
    rel_t = tg_p[:, sl] - tg_p[:, sl, ctx.root: ctx.root + 1]
    valid = None if ctx.index is None else metrics.pose_validity(window_features(ctx, pred_r, pred_p), ctx.index)
    per_window = {
        "l2q": [metrics.l2q(p_rot[i: i + 1, sl], t_rot[i: i + 1, sl]) for i in range(n)],
        "l2p": [metrics.l2p(p_pos[i: i + 1, sl], t_pos[i: i + 1, sl], ctx.std) for i in range(n)],
        "mpjpe_cm": (np.linalg.norm(pg_p[:, sl] - tg_p[:, sl], axis=-1).mean(axis=(1, 2)) * ctx.cm).tolist(),
        "skate": skate.tolist(),
        "penetration_cm": (penetration(ctx, pg_p, length) * ctx.cm).tolist(),
        "float_cm": (foot_float(ctx, pg_p, length) * ctx.cm).tolist(),
    }
    out = {
        "l2q": metrics.l2q(p_rot[:, sl], t_rot[:, sl]),
        "l2p": metrics.l2p(p_pos[:, sl], t_pos[:, sl], ctx.std),
        "npss": metrics.npss(p_q.reshape(n, length, -1), t_q.reshape(n, length, -1)),
        "mpjpe_cm": metrics.mpjpe(pg_p[:, sl], tg_p[:, sl]) * ctx.cm,
        "root_error_cm": float(root_err.mean()) * ctx.cm,
        "pose_error_cm": metrics.mpjpe(rel_p, rel_t) * ctx.cm,
        "skate": float(skate.mean()),
        "contact_skate": contact,
        "penetration_cm": float(np.mean(per_window["penetration_cm"])),
        "float_cm": float(np.mean(per_window["float_cm"])),
        "validity": None if valid is None else float(valid.mean()),
        "validity_p95": None if valid is None else float(np.percentile(valid, 95)),
        "jerk": metrics.jerk(pg_p[:, N_PAST - 3: N_PAST + length + 3], ctx.fps) * ctx.cm,
        "per_window": per_window,
    }
    if natural is not None:
        out["naturalness"] = float(np.mean(natural))
        per_window["naturalness"] = np.asarray(natural).tolist()
    return out


def paired_difference(a: list[float], b: list[float], seed: int, resamples: int = 2000) -> dict:
    """Mean of ``a - b`` over windows, its 95% bootstrap interval, the share of windows with
    a < b, and the ratio of the means (``mean a / mean b``)."""
    d = np.asarray(a) - np.asarray(b)
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, len(d), (resamples, len(d)))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    mb = float(np.mean(b))
    return {"mean": float(d.mean()), "ci95": [float(lo), float(hi)], "share_better": float(np.mean(d < 0)),
            "ratio": float(np.mean(a)) / mb if mb else None}


def score_truth(ctx: Context, truth_r, truth_p, length: int, natural=None) -> dict:
    """The realism figures of the true frames themselves (reference row); ``natural`` as in
    :func:`score_inbetween`."""
    sl = slice(N_PAST, N_PAST + length)
    _, tg_p = global_windows(truth_r, truth_p, ctx.skeleton.parents)
    skate, contact = skate_scores(ctx, tg_p, slice(N_PAST - 1, N_PAST + length))
    valid = (None if ctx.index is None
             else metrics.pose_validity(window_features(ctx, truth_r[:, sl], truth_p[:, sl]), ctx.index))
    pen = penetration(ctx, tg_p, length) * ctx.cm
    up = foot_float(ctx, tg_p, length) * ctx.cm
    out = {"skate": float(skate.mean()), "contact_skate": contact, "penetration_cm": float(pen.mean()),
           "float_cm": float(up.mean()),
           "validity": None if valid is None else float(valid.mean()),
           "validity_p95": None if valid is None else float(np.percentile(valid, 95)),
           "jerk": metrics.jerk(tg_p[:, N_PAST - 3: N_PAST + length + 3], ctx.fps) * ctx.cm,
           "per_window": {"skate": skate.tolist(), "penetration_cm": pen.tolist(), "float_cm": up.tolist()}}
    if natural is not None:
        out["naturalness"] = float(np.mean(natural))
        out["per_window"]["naturalness"] = np.asarray(natural).tolist()
    return out


PER_CONTENT_KEYS = ("l2q", "l2p", "mpjpe_cm", "skate", "naturalness")


def per_content(res: dict, contents: list[str]) -> dict:
    """Means of the per-window figures (:data:`PER_CONTENT_KEYS`) over the windows of each
    motion type: ``{content: {"windows": n, "methods": {m: {L: {k: v}}}, "truth": {L: {k: v}}}}``.

    res : the in-betweening results (``methods`` and ``truth`` with ``per_window`` lists);
    contents : the content of each window, in window order.
    """
    labels = np.array(contents)
    out = {}

    def means(per_window, mask):
        return {k: float(np.mean(np.asarray(v)[mask])) for k, v in per_window.items() if k in PER_CONTENT_KEYS}

    for c in sorted(set(contents)):
        mask = labels == c
        out[c] = {"windows": int(mask.sum()),
                  "methods": {m: {n: means(v["per_window"], mask) for n, v in per.items()}
                              for m, per in res["methods"].items()},
                  "truth": {n: means(v["per_window"], mask) for n, v in res["truth"].items()}}
    return out
