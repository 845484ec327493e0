"""``posturemap bench``: in-betweening accuracy, cross-clip realism and speed of every method.

Protocol (DESIGN.md, "Evaluation protocol"; LaFAN1 benchmark of Harvey et al. 2020)
---------------------------------------------------------------------------------------
Data: the Bandai-Namco dataset-1 clips ``bandai1/dataset-1_{content}_{style}_{id}.bvh``.

Split: the clips of the styles in :data:`TEST_STYLES` (angry, old, proud: 33 of the 174 clips,
every content in those styles) are the held-out test clips; the other 141 clips are the
training clips. The posture map, the classic SOM, the L2P statistics, the floor heights of
the feet and the pose-validity index are built from training clips only, so no test clip (not
even another take of the same style) is ever seen in training.

``--quick`` (:meth:`Settings.quick_run`, under a minute on 2 cores): every third training clip
(sorted by name), 32 seeded random test windows, 20 cross-clip pairs, one MiniSom epoch, 200
latency calls, no ``bench/`` scripts; every method and diagnostic still runs. The full run
(seed 0) took 466 s on 2 busy cores, 294 s of it in ``bench/train_speed.py``.

In-betweening: from each test clip, windows of 65 frames start every 40 frames (LaFAN1:
``while start + 65 < frames``); for a transition length L in 5, 15, 30, 45 the window's first
10 + L + 10 frames are used (as LaFAN1 does): 10 past-context frames, L frames to rebuild, 10
future-context frames. Every method sees the context only: the engine gets the whole clip as
both A and B with ``a_end`` = the last past-context frame, ``b_start`` = the first
future-context frame and ``align=False`` (the truth's root trajectory is the reference).
Methods (:data:`METHODS`):

- ``zero-velocity``: holds the last past-context frame (local rotations and root position);
- ``slerp``, ``inertialize``, ``spline``, ``upm``, ``upm-path`` and any other method of
  :data:`posturemap.transition.METHODS`: :class:`TransitionEngine`;
- ``som``: ``upm`` with the key taken from a classic fixed-grid SOM (MiniSom) per bone class,
  with about the neuron count of the UPM class map (:func:`som_grid`), trained on the same
  features; the key is the SOM neuron nearest the alpha-blend, then the same B-spline.

Metrics (:mod:`posturemap.metrics`) on the rebuilt frames: L2Q, L2P (LaFAN1), NPSS, MPJPE
(cm), root position error (cm) and the root-relative joint position error (cm), foot skate
(cm/s, over the L + 1 frame steps from the last past-context frame to the first
future-context frame; contacts from the motion itself, plus the slide of the feet where the
truth's feet are planted), pose validity (distance to the nearest training posture in the
map's feature space; compare with the truth row) and jerk (cm/s^3, every third difference
that touches a rebuilt frame).

Cross-clip transitions: seeded random pairs of two different test clips, random ``a_end`` and
``b_start``, ``length`` 20 (the paper's), ``align=True``. No ground truth: foot skate,
validity and jerk, next to the same figures on the real frames around the seams.

Diagnostics for the keyed methods: distance of the key posture to the true posture at
``key_at`` (next to the alpha-blend's, A's and B's and the nearest neuron's), overall and per
bone class; stand-ins (:data:`VARIANTS`) through the same spline: the plain alpha-blend as
key (not snapped to a neuron), the true posture as key (an oracle), the key of a map learned
from the window's own clip without the gap, the keyless spline and the blend key with zero
angular seam velocity, and ``upm`` with a LERP root; a sweep of ``alpha`` and ``key_at``; and
every method's per-window difference from slerp with a bootstrap interval.

Speed: per-method latency of :meth:`TransitionEngine.generate` (median, p99), UPM training
against MiniSom at equal neuron count (samples/s), and the scripts in the repository's
``bench/`` folder when present (BVH loading against other readers, ...).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import inspect
import json
import math
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import metrics, quat, report
from .bvh import write_bytes_atomic
from .features import CLASSES
from .motion import Motion
from .skeleton import fk
from .transition import DEFAULT_METHOD, TransitionEngine, aligned
from .transition import METHODS as ENGINE_METHODS

TEST_STYLES = ("angry", "old", "proud")
LENGTHS = (5, 15, 30, 45)
N_PAST = 10
N_FUTURE = 10
STRIDE = 40
WINDOW = N_PAST + max(LENGTHS) + N_FUTURE
STATS_WINDOW, STATS_STRIDE = 50, 20  # LaFAN1 get_train_stats
CROSS_LENGTH = 20
_BASELINES = ("slerp", "inertialize", "spline")
# Every method of the engine (new ones join automatically), plus the two built here.
FEET = "+feet"  # suffix: the method with foot locking (posturemap.feet)
DEFAULT_SPEC = DEFAULT_METHOD + FEET  # what `posturemap transition` does by default
METHODS = (("zero-velocity",) + tuple(m for m in _BASELINES if m in ENGINE_METHODS)
           + tuple(m for m in ENGINE_METHODS if m not in _BASELINES) + (DEFAULT_SPEC, "som"))


def method_spec(m: str) -> tuple[str, bool]:
    """Engine method and foot locking of a method name of this benchmark."""
    return (m[: -len(FEET)], True) if m.endswith(FEET) else (m, False)
VARIANTS = ("blend-key", "oracle-key", "self-map-key", "spline-v0", "blend-key-v0", "upm-lerp-root")
SWEEP_LENGTHS = (15, 30, 45)
SWEEP_FRACTIONS = (0.25, 0.5, 0.75)
FOOT_PATTERN = re.compile(r"foot|toe|ankle|heel", re.IGNORECASE)
FLOOR_PERCENTILE = 5.0
QUALITY_KEYS = ("inbetween", "cross_clip", "diagnostics")

_NAME = re.compile(r"^dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_(?P<id>\d+)$")


@dataclass(frozen=True)
class Settings:
    """How much of the benchmark to run (see :meth:`full` and :meth:`quick`).

    train_stride : use every n-th training clip (sorted by name)
    max_windows : at most this many test windows (a seeded random subset), None for all
    pairs : number of random cross-clip pairs
    som_epochs : passes of MiniSom over the training features
    latency_calls : timed generate calls per method
    bench_scripts : run the scripts of ``bench/`` (slow)
    sweep : also score ``upm`` over a grid of ``alpha`` and ``key_at``
    plots : write the PNG plots
    """

    quick: bool = False
    train_stride: int = 1
    max_windows: int | None = None
    pairs: int = 100
    som_epochs: int = 4
    latency_calls: int = 2000
    bench_scripts: bool = True
    sweep: bool = True
    plots: bool = True

    @classmethod
    def full(cls) -> Settings:
        return cls()

    @classmethod
    def quick_run(cls) -> Settings:
        return cls(quick=True, train_stride=3, max_windows=32, pairs=20, som_epochs=1,
                   latency_calls=200, bench_scripts=False)


# -- data ---------------------------------------------------------------------------------
def parse_name(path: str | Path) -> dict | None:
    """``{"content", "style", "id"}`` of a Bandai file name, or None for another name."""
    m = _NAME.match(Path(path).stem)
    return m.groupdict() if m else None


def split_files(files: list[Path], test_styles=TEST_STYLES) -> tuple[list[Path], list[Path]]:
    """(train, test): test = files whose style is in ``test_styles``; others (and any file
    whose name does not follow the Bandai pattern) are training files. Both sorted."""
    train, test = [], []
    for f in sorted(files):
        info = parse_name(f)
        (test if info and info["style"] in test_styles else train).append(f)
    return train, test


def window_starts(num_frames: int, window: int = WINDOW, stride: int = STRIDE) -> list[int]:
    """First frames of the windows of one clip (LaFAN1: ``while start + window < frames``)."""
    return list(range(0, max(num_frames - window, 0), stride))


def foot_joints(names) -> np.ndarray:
    """Indices of the joints named like feet, ankles, toes or heels."""
    return np.array([j for j, n in enumerate(names) if FOOT_PATTERN.search(n)], dtype=np.int64)


# -- the classic SOM key --------------------------------------------------------------------
def som_grid(n: int) -> tuple[int, int]:
    """Rows and columns of a SOM grid with about ``n`` neurons, as square as possible.

    Exactly ``n`` when ``n`` has a divisor between sqrt(n)/2 and sqrt(n); otherwise
    ``round(sqrt n)`` rows and enough columns (at most one row's worth more than ``n``).
    """
    root = math.isqrt(n)
    for r in range(root, max(1, math.ceil(root / 2)) - 1, -1):
        if r > 0 and n % r == 0 and r >= root / 2:
            return r, n // r
    r = max(1, round(math.sqrt(n)))
    return r, math.ceil(n / r)


@dataclass
class KeyTable:
    """A stand-in for one class map: the attributes :class:`TransitionEngine` reads."""

    weights_: np.ndarray
    period_: np.ndarray
    edges_: np.ndarray

    @property
    def n_neurons(self) -> int:
        return len(self.weights_)

    def distances(self, X) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        return np.linalg.norm(X[:, None, :] - self.weights_[None], axis=-1)


@dataclass
class KeyModel:
    """A stand-in for :class:`PostureMap` with other key tables (same skeleton and features)."""

    skeleton_: object
    space_: object
    maps_: list


def grid_edges(rows: int, cols: int) -> np.ndarray:
    """4-neighbour edges (E, 2) of a rows x cols grid, neurons numbered row by row."""
    idx = np.arange(rows * cols).reshape(rows, cols)
    e = [np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1), np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1)]
    return np.concatenate(e).astype(np.int64)


def train_som(x: np.ndarray, n_neurons: int, epochs: int, seed: int):
    """A MiniSom with about ``n_neurons`` neurons trained on ``x (n, d)``; returns (som, rows, cols).

    Classic settings: Gaussian neighbourhood from sigma = max(rows, cols) / 4 decreasing
    linearly to 1, learning rate 0.5 decreasing linearly to 0, weights started at random
    samples, ``epochs * n`` updates in seeded random order.
    """
    from minisom import MiniSom

    rows, cols = som_grid(n_neurons)
    som = MiniSom(rows, cols, x.shape[1], sigma=max(rows, cols) / 4.0, learning_rate=0.5,
                  decay_function="linear_decay_to_zero", sigma_decay_function="linear_decay_to_one",
                  neighborhood_function="gaussian", random_seed=seed)
    som.random_weights_init(x)
    som.train(x, epochs * len(x), random_order=True)
    return som, rows, cols


def som_model(model, parts: list[np.ndarray], epochs: int, seed: int, log=print):
    """A :class:`KeyModel` whose class maps are classic SOMs trained on the same class features.

    Returns ``(model, info)`` with per-class neuron counts and training seconds.
    """
    maps, info = [], []
    for c, (m, x) in enumerate(zip(model.maps_, parts)):
        t0 = time.perf_counter()
        som, rows, cols = train_som(x, m.n_neurons, epochs, seed + c)
        seconds = time.perf_counter() - t0
        w = np.ascontiguousarray(som.get_weights().reshape(rows * cols, -1), dtype=np.float64)
        maps.append(KeyTable(w, np.full(w.shape[1], np.inf), grid_edges(rows, cols)))
        info.append({"class": CLASSES[c], "grid": [rows, cols], "neurons": rows * cols,
                     "upm_neurons": m.n_neurons, "samples": len(x), "epochs": epochs,
                     "seconds": seconds, "samples_per_s": epochs * len(x) / seconds})
        log(f"  som {CLASSES[c]}: {rows}x{cols} grid ({rows * cols} neurons, UPM {m.n_neurons}), "
            f"{seconds:.1f} s")
    return KeyModel(model.skeleton_, model.space_, maps), info


def fixed_key_model(model) -> KeyModel:
    """A :class:`KeyModel` with one neuron per class, set before each call (diagnostic keys)."""
    space = model.space_
    maps = [KeyTable(np.zeros((1, len(d))), np.full(len(d), np.inf), np.zeros((0, 2), np.int64))
            for d in space.class_dims]
    return KeyModel(model.skeleton_, space, maps)


def centred(motion: Motion, root: int, up: int) -> Motion:
    """``motion`` with the root's horizontal translation set to 0 in every frame.

    Postures exclude the horizontal position, so a map learned from it is the same; but
    :func:`posturemap.motion.up_axis` measures the spread of all joints, including a fixed
    top joint at the origin (Bandai's ``joint_Root``), and takes the walking direction for up
    once the character is far from the origin. Centring keeps it right.
    """
    pos = motion.positions.copy()
    pos[:, root, [a for a in range(3) if a != up]] = 0.0
    return Motion(motion.skeleton, motion.rotations, pos, motion.fps)


def set_key(key_model: KeyModel, x: np.ndarray):
    """Make ``x`` (full feature vector) the only neuron of every class of ``key_model``."""
    for m, d in zip(key_model.maps_, key_model.space_.class_dims):
        m.weights_ = np.ascontiguousarray(x[d][None], dtype=np.float64)


# -- scoring ------------------------------------------------------------------------------
@dataclass
class Context:
    """What scoring needs besides the motions (skeleton, frames, training statistics)."""

    skeleton: object
    space: object
    root: int
    up: int
    fps: float
    feet: np.ndarray
    floor: np.ndarray
    std: np.ndarray
    index: object


def global_windows(rots: np.ndarray, pos: np.ndarray, parents) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations (N, T, J, 4) and positions (N, T, J, 3) of local windows."""
    return fk(parents, rots, pos)


def window_features(ctx: Context, rots: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Active posture features (N*T, D) of local frames (N, T, J, ...)."""
    n = rots.shape[0] * rots.shape[1]
    j = rots.shape[2]
    m = Motion(ctx.skeleton, rots.reshape(n, j, 4), pos.reshape(n, j, 3), ctx.fps)
    return ctx.space.encode(m)[:, ctx.space.active]


def feet_scores(ctx: Context, gpos: np.ndarray, truth_contacts: np.ndarray | None = None) -> dict:
    """Foot skate of windows of global positions (N, T, J, 3) over all their T-1 steps."""
    feet = gpos[:, :, ctx.feet]
    contacts = metrics.foot_contacts(feet, ctx.fps, ctx.up, ctx.floor)
    skate, n = metrics.foot_skate(feet, ctx.fps, ctx.up, contacts)
    out = {"foot_skate": skate, "contact_fraction": n / contacts.size}
    if truth_contacts is not None:
        out["foot_slide_truth_contacts"] = metrics.foot_skate(feet, ctx.fps, ctx.up, truth_contacts)[0]
    return out


def score_inbetween(ctx: Context, truth_r, truth_p, pred_r, pred_p, length: int,
                    accuracy_only: bool = False) -> dict:
    """Every metric for windows (N, 20 + L, J, ...) of truth and rebuilt frames (N, L, J, ...).

    ``accuracy_only``: only L2Q and L2P (skips the pose-validity queries, the slow part).
    """
    sl = slice(N_PAST, N_PAST + length)
    full_r, full_p = truth_r.copy(), truth_p.copy()
    full_r[:, sl], full_p[:, sl] = pred_r, pred_p
    parents = ctx.skeleton.parents
    tg_r, tg_p = global_windows(truth_r, truth_p, parents)
    pg_r, pg_p = global_windows(full_r, full_p, parents)
    t_pos, t_rot = metrics.normalize_windows(tg_p, tg_r, ctx.root, ctx.up, N_PAST - 1)
    p_pos, p_rot = metrics.normalize_windows(pg_p, pg_r, ctx.root, ctx.up, N_PAST - 1, tg_p, tg_r)
    if accuracy_only:
        return {"l2q": metrics.l2q(p_rot[:, sl], t_rot[:, sl]),
                "l2p": metrics.l2p(p_pos[:, sl], t_pos[:, sl], ctx.std)}
    t_q = quat.unroll(t_rot[:, sl], axis=1)
    p_q = metrics.align_signs(p_rot[:, sl], t_q)
    n = len(truth_r)
    root_err = np.linalg.norm(pg_p[:, sl, ctx.root] - tg_p[:, sl, ctx.root], axis=-1)
    rel_p = pg_p[:, sl] - pg_p[:, sl, ctx.root: ctx.root + 1]
    rel_t = tg_p[:, sl] - tg_p[:, sl, ctx.root: ctx.root + 1]
    seam = slice(N_PAST - 1, N_PAST + length + 1)
    t_contacts = metrics.foot_contacts(tg_p[:, seam][:, :, ctx.feet], ctx.fps, ctx.up, ctx.floor)
    valid = metrics.pose_validity(window_features(ctx, pred_r, pred_p), ctx.index)
    out = {
        "l2q": metrics.l2q(p_rot[:, sl], t_rot[:, sl]),
        "l2p": metrics.l2p(p_pos[:, sl], t_pos[:, sl], ctx.std),
        "npss": metrics.npss(p_q.reshape(n, length, -1), t_q.reshape(n, length, -1)),
        "mpjpe_cm": metrics.mpjpe(pg_p[:, sl], tg_p[:, sl]),
        "root_error_cm": float(root_err.mean()),
        "pose_error_cm": metrics.mpjpe(rel_p, rel_t),
        **feet_scores(ctx, pg_p[:, seam], t_contacts),
        "validity": float(valid.mean()),
        "validity_p95": float(np.percentile(valid, 95)),
        "jerk": metrics.jerk(pg_p[:, N_PAST - 3: N_PAST + length + 3], ctx.fps),
        "per_window": {
            "l2q": [metrics.l2q(p_rot[i: i + 1, sl], t_rot[i: i + 1, sl]) for i in range(n)],
            "l2p": [metrics.l2p(p_pos[i: i + 1, sl], t_pos[i: i + 1, sl], ctx.std) for i in range(n)],
        },
    }
    return out


def paired_difference(a: list[float], b: list[float], seed: int, resamples: int = 2000) -> dict:
    """Mean of ``a - b`` over windows, its 95% bootstrap interval and the share of windows with a < b."""
    d = np.asarray(a) - np.asarray(b)
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, len(d), (resamples, len(d)))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return {"mean": float(d.mean()), "ci95": [float(lo), float(hi)], "share_better": float(np.mean(d < 0))}


def score_truth(ctx: Context, truth_r, truth_p, length: int) -> dict:
    """The realism figures of the true frames themselves (reference row)."""
    sl = slice(N_PAST, N_PAST + length)
    seam = slice(N_PAST - 1, N_PAST + length + 1)
    _, tg_p = global_windows(truth_r, truth_p, ctx.skeleton.parents)
    valid = metrics.pose_validity(window_features(ctx, truth_r[:, sl], truth_p[:, sl]), ctx.index)
    return {**feet_scores(ctx, tg_p[:, seam]), "validity": float(valid.mean()),
            "validity_p95": float(np.percentile(valid, 95)),
            "jerk": metrics.jerk(tg_p[:, N_PAST - 3: N_PAST + length + 3], ctx.fps)}


# -- the run -------------------------------------------------------------------------------
def _log(msg: str):
    print(msg, flush=True)


def prepare(data_dir: Path, settings: Settings, seed: int, log=_log) -> dict:
    """Read the clips, split them, train the maps; returns the shared state of the run."""
    from . import bvh
    from .model import PostureMap

    files = sorted((Path(data_dir) / "bandai1").glob("*.bvh"))
    if not files:
        raise FileNotFoundError(str(Path(data_dir) / "bandai1"))
    train_files, test_files = split_files(files)
    train_files = train_files[:: settings.train_stride]
    t0 = time.perf_counter()
    train = [bvh.read(f) for f in train_files]
    test = [bvh.read(f) for f in test_files]
    log(f"data: {len(train_files)} training clips ({sum(map(len, train))} frames), "
        f"{len(test_files)} test clips ({sum(map(len, test))} frames) in {time.perf_counter() - t0:.1f} s")
    t0 = time.perf_counter()
    model = PostureMap(seed=seed).fit(train, [f.name for f in train_files])
    upm_seconds = time.perf_counter() - t0
    space = model.space_
    log(f"upm: {sum(model.neuron_counts())} neurons {model.neuron_counts()} in {upm_seconds:.1f} s "
        f"(root {model.skeleton_.names[space.root]}, up axis {'XYZ'[space.up]})")
    x_train = np.concatenate([space.encode(m) for m in train])
    parts = space.split(x_train)
    log(f"som: MiniSom per class, {settings.som_epochs} epoch(s)")
    som, som_info = som_model(model, parts, settings.som_epochs, seed, log)

    sk = model.skeleton_
    root, up, fps = space.root, space.up, float(train[0].fps)
    feet = foot_joints(sk.names)
    # L2P statistics: training windows of 50 frames every 20, in the window frame (LaFAN1).
    wins_r, wins_p = [], []
    for m in train:
        for s in window_starts(len(m), STATS_WINDOW, STATS_STRIDE):
            wins_r.append(m.rotations[s: s + STATS_WINDOW])
            wins_p.append(m.positions[s: s + STATS_WINDOW])
    g_r, g_p = fk(sk.parents, np.stack(wins_r), np.stack(wins_p))
    n_pos, _ = metrics.normalize_windows(g_p, g_r, root, up, N_PAST - 1)
    _, std = metrics.position_stats(n_pos)
    heights = np.concatenate([m.global_positions()[:, feet, up] for m in train])
    floor = np.percentile(heights, FLOOR_PERCENTILE, axis=0)
    ctx = Context(sk, space, root, up, fps, feet, floor, std,
                  metrics.build_posture_index(x_train[:, space.active]))
    return {"train_files": train_files, "test_files": test_files, "train": train, "test": test,
            "model": model, "som": som, "som_info": som_info, "upm_seconds": upm_seconds,
            "ctx": ctx, "x_train": x_train, "stats_windows": len(wins_r)}


def make_windows(state: dict, settings: Settings, seed: int) -> list[tuple[int, int]]:
    """(test clip index, first frame) of every window used, in a fixed order."""
    wins = [(c, s) for c, m in enumerate(state["test"]) for s in window_starts(len(m))]
    if settings.max_windows is not None and len(wins) > settings.max_windows:
        rng = np.random.default_rng(seed)
        keep = np.sort(rng.choice(len(wins), settings.max_windows, replace=False))
        wins = [wins[i] for i in keep]
    return wins


def make_engines(state: dict) -> dict:
    """One engine per key source, each holding every test clip (names = clip indices)."""
    model = state["model"]
    engines = {"upm": TransitionEngine(model), "som": TransitionEngine(state["som"]),
               "fixed": TransitionEngine(fixed_key_model(model))}
    for e in engines.values():
        for c, m in enumerate(state["test"]):
            e.add(str(c), m)
    return engines


def _generate(engines, method, clip, length, a_end, b_start, **kw):
    if method == "som":
        r, p = engines["som"].generate(clip, clip, length, a_end=a_end, b_start=b_start, align=False,
                                       method="upm", **kw)
    elif method in VARIANTS:
        r, p = engines["fixed"].generate(clip, clip, length, a_end=a_end, b_start=b_start, align=False,
                                         method="upm", **kw)
    else:
        base, feet = method_spec(method)
        r, p = engines["upm"].generate(clip, clip, length, a_end=a_end, b_start=b_start, align=False,
                                       method=base, foot_lock=feet, **kw)
    return r.copy(), p.copy()


def run_inbetween(state: dict, windows, settings: Settings, seed: int, log=_log) -> tuple[dict, dict, dict]:
    """Scores per method and length, the truth's, the diagnostics; plus curves for a plot.

    Returns ``(inbetween, diagnostics, example)``.
    """
    from .model import PostureMap

    ctx, engines = state["ctx"], state["engines"]
    test, space = state["test"], state["model"].space_
    fixed = engines["fixed"].model
    upm = engines["upm"]
    act = space.active
    res = {"windows": len(windows), "lengths": list(LENGTHS), "methods": {m: {} for m in METHODS},
           "truth": {}, "default_method": DEFAULT_SPEC, "vs_slerp": {m: {} for m in METHODS}}
    diag = {"key_distance": {}, "key_distance_by_class": {}, "variants": {v: {} for v in VARIANTS},
            "sweep": {}}
    example = {}
    for length in LENGTHS:
        t0 = time.perf_counter()
        span = N_PAST + length + N_FUTURE
        truth_r = np.stack([test[c].rotations[s: s + span] for c, s in windows])
        truth_p = np.stack([test[c].positions[s: s + span] for c, s in windows])
        preds = {m: (np.empty((len(windows), length) + truth_r.shape[2:]),
                     np.empty((len(windows), length) + truth_p.shape[2:])) for m in METHODS + VARIANTS}
        key_at = length // 2
        kd = {k: [] for k in ("a_to_true", "b_to_true", "blend_to_true", "upm_key_to_true",
                              "upm_path_key_to_true", "som_key_to_true", "nearest_neuron_to_true",
                              "upm_key_to_blend")}
        kdc = {cls: {"blend": [], "upm_key": [], "nearest_neuron": []} for cls in CLASSES}
        for i, (c, s) in enumerate(windows):
            name = str(c)
            a_end, b_start = s + N_PAST - 1, s + N_PAST + length
            feats = upm.tracks[name].features
            xa, xb, xt = feats[a_end], feats[b_start], feats[a_end + key_at]
            blend = xa + 0.5 * (xb - xa)
            k_upm, _ = upm.key_features(xa, xb, 0.5)
            k_path, _ = upm.key_features(xa, xb, 0.5, path=True)
            k_som, _ = engines["som"].key_features(xa, xb, 0.5)
            k_near = space.merge([m.weights_[m.predict(xt[d][None])[0]]
                                  for m, d in zip(state["model"].maps_, space.class_dims)])
            for key, v in (("a_to_true", xa), ("b_to_true", xb), ("blend_to_true", blend),
                           ("upm_key_to_true", k_upm), ("upm_path_key_to_true", k_path),
                           ("som_key_to_true", k_som), ("nearest_neuron_to_true", k_near)):
                kd[key].append(float(np.linalg.norm((v - xt)[act])))
            kd["upm_key_to_blend"].append(float(np.linalg.norm((k_upm - blend)[act])))
            for cls, d in zip(CLASSES, space.class_dims):
                for key, v in (("blend", blend), ("upm_key", k_upm), ("nearest_neuron", k_near)):
                    kdc[cls][key].append(float(np.linalg.norm((v - xt)[d])))
            for m in METHODS:
                if m == "zero-velocity":
                    preds[m][0][i] = test[c].rotations[a_end]
                    preds[m][1][i] = test[c].positions[a_end]
                else:
                    preds[m][0][i], preds[m][1][i] = _generate(engines, m, name, length, a_end, b_start)
            set_key(fixed, blend)
            preds["blend-key"][0][i], preds["blend-key"][1][i] = _generate(engines, "blend-key", name, length,
                                                                           a_end, b_start)
            set_key(fixed, xt)
            preds["oracle-key"][0][i], preds["oracle-key"][1][i] = _generate(engines, "oracle-key", name,
                                                                             length, a_end, b_start)
            # A map learned from this clip's context alone (the frames outside the gap), as
            # `posturemap transition` does without --map: the clip's own style, no truth.
            own = PostureMap(seed=seed).fit([centred(test[c][: a_end + 1], ctx.root, ctx.up),
                                             centred(test[c][b_start:], ctx.root, ctx.up)])
            eng = TransitionEngine(own)
            eng.add(name, test[c])
            r, p = eng.generate(name, name, length, a_end=a_end, b_start=b_start, align=False, method="upm")
            preds["self-map-key"][0][i], preds["self-map-key"][1][i] = r, p
            # Zero angular velocity at the seams: the window with the two frames before A's end
            # and the one after B's start given the seam frame's rotations (positions kept).
            seg_r = test[c].rotations[s: s + N_PAST + length + N_FUTURE].copy()
            a_w, b_w = N_PAST - 1, N_PAST + length
            seg_r[a_w - 2: a_w] = seg_r[a_w]
            seg_r[b_w + 1] = seg_r[b_w]
            fixed_eng = engines["fixed"]
            fixed_eng.add("v0", Motion(ctx.skeleton, seg_r, test[c].positions[s: s + N_PAST + length + N_FUTURE],
                                       ctx.fps))
            r, p = fixed_eng.generate("v0", "v0", length, a_end=a_w, b_start=b_w, align=False, method="spline")
            preds["spline-v0"][0][i], preds["spline-v0"][1][i] = r, p
            set_key(fixed, blend)
            r, p = fixed_eng.generate("v0", "v0", length, a_end=a_w, b_start=b_w, align=False, method="upm")
            preds["blend-key-v0"][0][i], preds["blend-key-v0"][1][i] = r, p
            # upm's frames with the root joint's translation of slerp (LERP root).
            preds["upm-lerp-root"][0][i] = preds["upm"][0][i]
            preds["upm-lerp-root"][1][i] = preds["upm"][1][i]
            preds["upm-lerp-root"][1][i, :, ctx.root] = preds["slerp"][1][i, :, ctx.root]
        for m in METHODS:
            res["methods"][m][str(length)] = score_inbetween(ctx, truth_r, truth_p, *preds[m], length)
        for v in VARIANTS:
            diag["variants"][v][str(length)] = score_inbetween(ctx, truth_r, truth_p, *preds[v], length)
        res["truth"][str(length)] = score_truth(ctx, truth_r, truth_p, length)
        for m in METHODS:
            res["vs_slerp"][m][str(length)] = {
                k: paired_difference(res["methods"][m][str(length)]["per_window"][k],
                                     res["methods"]["slerp"][str(length)]["per_window"][k], seed)
                for k in ("l2q", "l2p")}
        diag["key_distance"][str(length)] = {k: float(np.mean(v)) for k, v in kd.items()}
        diag["key_distance_by_class"][str(length)] = {cls: {k: float(np.mean(v)) for k, v in kv.items()}
                                                      for cls, kv in kdc.items()}
        if settings.sweep and length in SWEEP_LENGTHS:
            diag["sweep"][str(length)] = sweep(state, windows, truth_r, truth_p, length)
        if length == 30:  # plot a walking window when there is one
            names = [state["test_files"][c].name for c, _ in windows]
            e = next((i for i, nm in enumerate(names) if "_walk_" in nm), 0)
            example = {m: np.concatenate([truth_r[e, :N_PAST], preds[m][0][e], truth_r[e, N_PAST + length:]])
                       for m in METHODS}
            example["truth"] = truth_r[e]
            example["window"] = windows[e]
            example["clip"] = names[e]
            example["joints"] = list(state["ctx"].skeleton.names)
        r = res["methods"]
        log(f"in-betweening L={length}: {len(windows)} windows in {time.perf_counter() - t0:.1f} s; "
            + ", ".join(f"{m} L2Q {r[m][str(length)]['l2q']:.3f}" for m in METHODS))
    return res, diag, example


def sweep(state, windows, truth_r, truth_p, length) -> dict:
    """upm's L2Q and L2P for alpha at 1/4, 1/2, 3/4 and key_at at a quarter, the default
    (``length // 2``) and three quarters of the length."""
    out = {}
    engines, ctx = state["engines"], state["ctx"]
    key_ats = sorted({max(1, round(SWEEP_FRACTIONS[0] * length)), max(1, length // 2),
                      min(length, round(SWEEP_FRACTIONS[-1] * length))})
    for fa in SWEEP_FRACTIONS:
        for key_at in key_ats:
            pr = np.empty((len(windows), length) + truth_r.shape[2:])
            pp = np.empty((len(windows), length) + truth_p.shape[2:])
            for i, (c, s) in enumerate(windows):
                pr[i], pp[i] = _generate(engines, "upm", str(c), length, s + N_PAST - 1, s + N_PAST + length,
                                         alpha=fa, key_at=key_at)
            sc = score_inbetween(ctx, truth_r, truth_p, pr, pp, length, accuracy_only=True)
            out[f"alpha={fa:g},key_at={key_at}"] = {"alpha": fa, "key_at": key_at,
                                                    "l2q": sc["l2q"], "l2p": sc["l2p"]}
    return out


def random_pairs(lengths: list[int], count: int, seed: int, length: int = CROSS_LENGTH) -> list[tuple]:
    """``count`` seeded (a, b, a_end, b_start) with a != b, 10 real frames on both sides."""
    rng = np.random.default_rng(seed)
    ok = [i for i, n in enumerate(lengths) if n >= N_PAST + N_FUTURE]
    pairs = []
    while len(pairs) < count:
        a, b = rng.choice(ok, 2, replace=False)
        a_end = int(rng.integers(N_PAST - 1, lengths[a]))
        b_start = int(rng.integers(0, lengths[b] - N_FUTURE + 1))
        pairs.append((int(a), int(b), a_end, b_start))
    return pairs


def run_cross(state: dict, settings: Settings, seed: int, log=_log) -> dict:
    """Foot skate, validity and jerk of transitions between two different test clips."""
    t0 = time.perf_counter()
    ctx, engines, test = state["ctx"], state["engines"], state["test"]
    pairs = random_pairs([len(m) for m in test], settings.pairs, seed + 1)
    length = CROSS_LENGTH
    upm = engines["upm"]
    seqs = {m: [] for m in METHODS}
    reference = []
    for a, b, a_end, b_start in pairs:
        ta, tb = upm.tracks[str(a)], upm.tracks[str(b)]
        dtheta, shift = upm.alignment(ta, tb, a_end, b_start, length)
        b_part = aligned(tb, upm, b_start, dtheta, shift)[:N_FUTURE]
        a_part = test[a][a_end - N_PAST + 1: a_end + 1]
        for m in METHODS:
            if m == "zero-velocity":
                r = np.repeat(a_part.rotations[-1:], length, axis=0)
                p = np.repeat(a_part.positions[-1:], length, axis=0)
            else:
                eng = engines["som"] if m == "som" else upm
                base, feet = method_spec("upm" if m == "som" else m)
                r, p = eng.generate(str(a), str(b), length, a_end=a_end, b_start=b_start, align=True,
                                    method=base, foot_lock=feet)
            seqs[m].append((np.concatenate([a_part.rotations, r, b_part.rotations]),
                            np.concatenate([a_part.positions, p, b_part.positions])))
        reference.append((a_part, b_part))
    out = {"pairs": len(pairs), "length": length, "align": True, "methods": {}}
    sl = slice(N_PAST, N_PAST + length)
    seam = slice(N_PAST - 1, N_PAST + length + 1)
    parents = ctx.skeleton.parents
    for m in METHODS:
        rots = np.stack([s[0] for s in seqs[m]])
        pos = np.stack([s[1] for s in seqs[m]])
        _, gp = global_windows(rots, pos, parents)
        valid = metrics.pose_validity(window_features(ctx, rots[:, sl], pos[:, sl]), ctx.index)
        out["methods"][m] = {**feet_scores(ctx, gp[:, seam]), "validity": float(valid.mean()),
                             "validity_p95": float(np.percentile(valid, 95)),
                             "jerk": metrics.jerk(gp[:, N_PAST - 3: N_PAST + length + 3], ctx.fps)}
    # Reference: the real frames on both sides of the seams (10 of A, 10 of B, separately).
    real = [(np.stack([p.rotations for p in parts]), np.stack([p.positions for p in parts]))
            for parts in zip(*reference)]
    feet_out, jerks, valids = [], [], []
    for rots, pos in real:
        _, gp = global_windows(rots, pos, parents)
        feet_out.append(feet_scores(ctx, gp))
        jerks.append(metrics.jerk(gp, ctx.fps))
        valids.append(metrics.pose_validity(window_features(ctx, rots, pos), ctx.index))
    v = np.concatenate(valids)
    out["reference"] = {"foot_skate": float(np.mean([f["foot_skate"] for f in feet_out])),
                        "contact_fraction": float(np.mean([f["contact_fraction"] for f in feet_out])),
                        "validity": float(v.mean()), "validity_p95": float(np.percentile(v, 95)),
                        "jerk": float(np.mean(jerks))}
    out["pair_list"] = [{"a": state["test_files"][a].name, "b": state["test_files"][b].name,
                         "a_end": a_end, "b_start": b_start} for a, b, a_end, b_start in pairs]
    log(f"cross-clip: {len(pairs)} pairs in {time.perf_counter() - t0:.1f} s")
    return out


# -- speed ---------------------------------------------------------------------------------
def latency(state: dict, calls: int, seed: int) -> dict:
    """Median and p99 (microseconds) of single generate calls per method (cross-clip, L=20)."""
    engines, test = state["engines"], state["test"]
    pairs = random_pairs([len(m) for m in test], calls, seed + 2)
    out = {}
    for m in METHODS:
        if m == "zero-velocity":
            continue
        eng = engines["som"] if m == "som" else engines["upm"]
        meth, feet = method_spec("upm" if m == "som" else m)
        for a, b, a_end, b_start in pairs[:20]:  # warm-up: compiled kernels, caches
            eng.generate(str(a), str(b), CROSS_LENGTH, a_end=a_end, b_start=b_start, method=meth, foot_lock=feet)
        times = np.empty(len(pairs))
        for i, (a, b, a_end, b_start) in enumerate(pairs):
            t0 = time.perf_counter_ns()
            eng.generate(str(a), str(b), CROSS_LENGTH, a_end=a_end, b_start=b_start, method=meth, foot_lock=feet)
            times[i] = time.perf_counter_ns() - t0
        out[m] = {"median_us": float(np.median(times)) / 1e3, "p99_us": float(np.percentile(times, 99)) / 1e3,
                  "calls": len(pairs), "neurons": [int(t.n_neurons) for t in eng.model.maps_]}
    return out


def training_speed(state: dict, seed: int) -> list[dict]:
    """Per class: UPM (one thread) against MiniSom on the same features and neuron count."""
    from .upm import UniformPostureMap

    model, parts = state["model"], state["model"].space_.split(state["x_train"])
    seq = np.concatenate([np.full(len(m), i) for i, m in enumerate(state["train"])])
    rows = []
    for c, info in enumerate(state["som_info"]):
        m = model.maps_[c]
        upm = UniformPostureMap(model.radius, model.neighborhood, model.learning_rate, model.epochs,
                                seed + c, m.period_)
        t0 = time.perf_counter()
        upm.fit(parts[c], seq)
        sec = time.perf_counter() - t0
        rows.append({"class": CLASSES[c], "samples": len(parts[c]), "dims": int(parts[c].shape[1]),
                     "upm_neurons": upm.n_neurons, "upm_epochs": int(model.epochs), "upm_seconds": sec,
                     "upm_samples_per_s": model.epochs * len(parts[c]) / sec,
                     "som_neurons": info["neurons"], "som_epochs": info["epochs"],
                     "som_seconds": info["seconds"], "som_samples_per_s": info["samples_per_s"]})
    return rows


def bench_dir() -> Path:
    """The repository's ``bench/`` folder (next to ``src/``)."""
    return Path(__file__).resolve().parents[2] / "bench"


def run_bench_script(name: str, data_dir: Path, settings: Settings, seed: int, log=_log) -> dict:
    """Import ``bench/<name>.py`` by path and call its ``run``; never raises.

    Arguments are passed by name when ``run`` takes them: ``data_dir``/``data``, ``repeat``
    (3), ``quick``, ``seed``. Returns ``{"status": "ok", "result": ..., "markdown": ...}`` or
    ``{"status": "absent"|"failed", "reason": ...}``.
    """
    path = bench_dir() / f"{name}.py"
    if not path.is_file():
        return {"status": "absent", "reason": f"{path} not found"}
    t0 = time.perf_counter()
    try:
        spec = importlib.util.spec_from_file_location(f"posturemap_bench_{name}", path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        params = inspect.signature(mod.run).parameters
        offer = {"data_dir": data_dir, "data": data_dir, "repeat": 3, "quick": settings.quick, "seed": seed}
        kwargs = {k: v for k, v in offer.items() if k in params}
        result = mod.run(**kwargs)
        md = mod.markdown(result) if hasattr(mod, "markdown") else None
    except Exception as e:  # noqa: BLE001 - another team's script: report, do not crash
        log(f"bench/{name}.py failed: {type(e).__name__}: {e}")
        return {"status": "failed", "reason": f"{type(e).__name__}: {' '.join(str(e).split())[:300]}"}
    log(f"bench/{name}.py: {time.perf_counter() - t0:.1f} s")
    return {"status": "ok", "seconds": time.perf_counter() - t0, "result": _jsonable(result), "markdown": md}


def _jsonable(x):
    """A JSON-ready copy: numpy scalars and arrays to Python, Paths to str, tuple keys joined."""
    if isinstance(x, dict):
        return {(k if isinstance(k, str) else "/".join(map(str, k)) if isinstance(k, tuple) else str(k)):
                _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def run(data_dir, out, seed: int = 0, settings: Settings | None = None, log=_log) -> dict:
    """Run the benchmark; writes results.md, results.json and PNG plots into ``out``.

    Returns the results dict (the content of results.json).
    """
    settings = settings or Settings.full()
    t_start = time.perf_counter()
    data_dir, out = Path(data_dir), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    np.random.seed(seed)  # third-party code that draws from numpy's global generator
    import platform

    sections = {}
    clock = time.perf_counter()

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        sections[name] = now - clock
        clock = now

    state = prepare(data_dir, settings, seed, log)
    state["engines"] = make_engines(state)
    windows = make_windows(state, settings, seed)
    lap("data and training")
    log(f"in-betweening: {len(windows)} windows from {len(state['test'])} test clips")
    inb, diag, example = run_inbetween(state, windows, settings, seed, log)
    lap("in-betweening and diagnostics")
    cross = run_cross(state, settings, seed, log)
    lap("cross-clip")
    log("speed: latency")
    speed = {"latency": latency(state, settings.latency_calls, seed), "training": [], "bench": {}}
    log("speed: training")
    speed["training"] = training_speed(state, seed)
    lap("speed: latency and training")
    for name in ("transition_speed", "train_speed", "bvh_load"):
        if settings.bench_scripts:
            log(f"speed: bench/{name}.py")
            speed["bench"][name] = run_bench_script(name, data_dir, settings, seed, log)
        else:
            speed["bench"][name] = {"status": "skipped", "reason": "--quick skips the bench/ scripts"}
        lap(f"bench/{name}.py")
    model = state["model"]
    ctx = state["ctx"]
    results = {
        "config": {"seed": seed, **dataclasses.asdict(settings), "lengths": list(LENGTHS), "n_past": N_PAST,
                   "n_future": N_FUTURE, "stride": STRIDE, "cross_length": CROSS_LENGTH},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "code": code_version()},
        "split": {"rule": f"test = styles {', '.join(TEST_STYLES)}; train = the other styles",
                  "test_styles": list(TEST_STYLES), "test_clips": len(state["test_files"]),
                  "test_frames": int(sum(map(len, state["test"]))),
                  "train_clips_all": len(split_files(sorted((data_dir / "bandai1").glob("*.bvh")))[0]),
                  "train_clips": len(state["train_files"]), "train_frames": int(sum(map(len, state["train"]))),
                  "test_files": [f.name for f in state["test_files"]],
                  "train_files": [f.name for f in state["train_files"]]},
        "map": {"neurons": model.neuron_counts(), "radius": [m.radius_ for m in model.maps_],
                "train_seconds": state["upm_seconds"],
                "som": state["som_info"]},
        "feet": {"joints": [ctx.skeleton.names[j] for j in ctx.feet], "floor_cm": ctx.floor.tolist(),
                 "floor_percentile": FLOOR_PERCENTILE},
        "inbetween": inb, "cross_clip": cross, "diagnostics": diag, "speed": speed,
        "section_seconds": sections,
    }
    results["plots"] = report.plot(results, example, out) if settings.plots else []
    results["wall_seconds"] = time.perf_counter() - t_start
    results = _jsonable(results)
    write_bytes_atomic(out / "results.json", (json.dumps(results, indent=1) + "\n").encode())
    write_bytes_atomic(out / "results.md", report.markdown(results).encode())
    log(f"wrote {out / 'results.md'}, {out / 'results.json'} and {len(results['plots'])} plots "
        f"in {results['wall_seconds']:.0f} s")
    return results


def code_version() -> str | None:
    """``git describe --always --dirty`` of the repository holding this file, or None."""
    import subprocess

    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=Path(__file__).resolve().parent,
                             capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def default_data_dir() -> Path:
    """``$POSTUREMAP_DATA`` or ``../shared/data`` next to the repository."""
    env = os.environ.get("POSTUREMAP_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[3] / "shared" / "data"


def run_cli(args) -> int:
    """Entry point of ``posturemap bench`` (``args.quick``, ``args.data``, ``args.out``, ``args.seed``)."""
    from .errors import UserError

    data = Path(args.data) if args.data else default_data_dir()
    if not (data / "bandai1").is_dir():
        raise UserError(str(data), "no bandai1/ folder of BVH clips here (set --data or POSTUREMAP_DATA)")
    settings = Settings.quick_run() if args.quick else Settings.full()
    run(data, args.out, seed=args.seed, settings=settings)
    return 0
