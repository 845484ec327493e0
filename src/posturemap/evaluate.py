"""``posturemap bench``: in-betweening accuracy, realism and speed of every method, on hold-outs.

Protocol (DESIGN.md, "Evaluation protocol"; LaFAN1 benchmark of Harvey et al. 2020)
---------------------------------------------------------------------------------------
Three hold-outs (:data:`HOLDOUTS`), each evaluated separately; for each, the posture map (and
whatever a method keeps from the training clips, e.g. a motion library), the classic SOM, the
L2P statistics, the feet's planted heights and the pose-validity index are built from that
hold-out's training side only:

- ``style``: Bandai-Namco dataset-1 (``bandai1/dataset-1_{content}_{style}_{id}.bvh``); test =
  every clip of the styles :data:`TEST_STYLES` (angry, old, proud; 33 clips, every content),
  training = the other 141 clips. Unseen performers' styles of known motion types.
- ``content``: test = every clip of the contents :data:`TEST_CONTENTS` (dash, walk-back,
  byebye: fast locomotion, walking backwards, a waving gesture; 45 clips, every style),
  training = the other contents (129 clips). Whole motion types absent from the library.
- ``cmu``: CMU subject 1, trial 1 (``cmu/01_01.bvh``, 120 fps, its own skeleton and unit):
  training = the first half of its frames, test = the second half; lengths
  :data:`CMU_LENGTHS`, the same frame counts as at 30 fps and the same durations (x 4).

``--quick`` (:meth:`Settings.quick_run`, about 20 s on 2 idle cores): every fourth training
clip (sorted by name), 8 seeded random test windows per hold-out, 10 cross-clip pairs, a
quarter of a MiniSom epoch, 100 latency calls, no diagnostics, no sweep and no ``bench/``
scripts; every method, metric and hold-out still runs.

In-betweening: from each test clip, windows of 10 + max(L) + 10 frames start every 40 frames
(LaFAN1: ``while start + window < frames``); for a transition length L the window's first 10 +
L + 10 frames are used (as LaFAN1 does): 10 past-context frames, L frames to rebuild, 10
future-context frames. Every method sees the context only: the engine gets the 10 past frames
as clip A and the 10 future frames as clip B (``a_end`` = A's last frame, ``b_start`` = 0,
``align=False``: the truth's root trajectory is the reference), so no method can read a frame
of the gap. Methods (:data:`METHODS`):

- ``zero-velocity``: holds the last past-context frame (local rotations and root position);
- every method of :data:`posturemap.transition.METHODS` (new ones join automatically), through
  :class:`TransitionEngine` on a map fitted on the hold-out's training clips; ``+feet``
  (:data:`FEET`) variants for ``upm-valid`` and the default method;
- ``som``: ``upm`` with the key taken from a classic fixed-grid SOM (MiniSom) per bone class,
  with about the neuron count of the UPM class map (:func:`som_grid`), trained on the same
  features; the key is the SOM neuron nearest the alpha-blend, then the same B-spline.

Metrics (:mod:`posturemap.metrics`) on the rebuilt frames, per method and length, overall and
per motion type (content): L2Q, L2P, NPSS (LaFAN1), MPJPE, root position error and
root-relative joint position error (cm); foot skate, the standard height-weighted measure
(:func:`posturemap.metrics.weighted_skate`, cm/s, H = 2.5 cm per 80 cm of leg, ground = the
lowest foot joint over the window, over the L + 1 frame steps from the last past-context
frame to the first future-context frame; no contact detection), with the older contact-based
measure as a secondary column (``contact_skate``); naturalness (:func:`naturalness_fn`: each
rebuilt window's distance to its nearest real window of the same length among the test clips,
which no library has seen, leaving out windows that overlap its own frames; z-scored pose and
velocity features in the character's frame); pose validity (distance to the nearest training
posture in the map's feature space) and jerk (cm/s^3). Beside each realism figure, the truth's.
Every method against slerp, window by window, with a bootstrap interval.

Cross-clip transitions (hold-outs with two or more test clips): seeded random pairs of two
different test clips, random ``a_end`` and ``b_start``, ``length`` 20 (the paper's),
``align=True``. No ground truth: foot skate, validity and jerk, next to the same figures on the
real frames around the seams.

Diagnostics for the keyed methods (style hold-out, full run): distance of the key posture to
the true posture at ``key_at`` (next to the alpha-blend's, A's and B's and the nearest
neuron's), overall and per bone class; stand-ins (:data:`VARIANTS`) through the same spline;
a sweep of ``alpha`` and ``key_at``.

Speed (on the style hold-out's map): per-method latency of :meth:`TransitionEngine.generate`
(median, p99), UPM training against MiniSom at equal neuron count (samples/s), and the scripts
in the repository's ``bench/`` folder when present (BVH loading against other readers, ...).
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
from .feet import leg_chains, leg_length
from .motion import Motion, length_unit
from .skeleton import fk
from .transition import DEFAULT_METHOD, TransitionEngine, aligned
from .transition import METHODS as ENGINE_METHODS

HOLDOUTS = ("style", "content", "cmu")
TEST_STYLES = ("angry", "old", "proud")
TEST_CONTENTS = ("dash", "walk-back", "byebye")
LENGTHS = (5, 15, 30, 45)
CMU_FILE = Path("cmu") / "01_01.bvh"
CMU_LENGTHS = (5, 15, 20, 30, 45, 60, 120, 180)  # 5-45 frames, and 20-180: the 30 fps durations
N_PAST = 10
N_FUTURE = 10
STRIDE = 40
STATS_WINDOW, STATS_STRIDE = 50, 20  # LaFAN1 get_train_stats
CROSS_LENGTH = 20
_BASELINES = ("slerp", "inertialize", "spline")
FEET = "+feet"  # suffix: the method with foot locking (posturemap.feet)
DEFAULT_SPEC = DEFAULT_METHOD + FEET  # what `posturemap transition` does by default
# Every method of the engine (new ones join automatically), foot-locked variants, and the
# two built here.
_FOOT_LOCKED = tuple(m + FEET for m in dict.fromkeys(("upm-valid", DEFAULT_METHOD)) if m in ENGINE_METHODS)
METHODS = (("zero-velocity",) + tuple(m for m in _BASELINES if m in ENGINE_METHODS)
           + tuple(m for m in ENGINE_METHODS if m not in _BASELINES) + _FOOT_LOCKED + ("som",))


def method_spec(m: str) -> tuple[str, bool]:
    """Engine method and foot locking of a method name of this benchmark."""
    return (m[: -len(FEET)], True) if m.endswith(FEET) else (m, False)


VARIANTS = ("blend-key", "oracle-key", "self-map-key", "spline-v0", "blend-key-v0", "upm-lerp-root")
SWEEP_LENGTHS = (15, 30, 45)
SWEEP_FRACTIONS = (0.25, 0.5, 0.75)
FOOT_PATTERN = re.compile(r"foot|toe|ankle|heel", re.IGNORECASE)
FLOOR_PERCENTILE = 5.0
NATURAL_FRAMES = 10  # naturalness compares at most this many evenly spaced frames of a window
NATURAL_STRIDE_S = 0.1  # reference windows start every 0.1 s
UNIT_CM = {"m": 100.0, "cm": 1.0, "mm": 0.1, "inch": 2.54}
ASF_UNIT_CM = 2.54 / 0.45  # CMU's BVH conversions keep the ASF unit, 1/0.45 inch
QUALITY_KEYS = ("holdouts", "diagnostics")

_NAME = re.compile(r"^dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_(?P<id>\d+)$")


@dataclass(frozen=True)
class Settings:
    """How much of the benchmark to run (see :meth:`full` and :meth:`quick_run`).

    holdouts : which hold-outs of :data:`HOLDOUTS` to run
    train_stride : use every n-th training clip (sorted by name; Bandai hold-outs)
    max_windows : at most this many test windows per hold-out (a seeded random subset), None for all
    pairs : number of random cross-clip pairs
    som_epochs : passes of MiniSom over the training features (a fraction: that share of one pass)
    latency_calls : timed generate calls per method
    bench_scripts : run the scripts of ``bench/`` (slow)
    diagnostics : key distances and stand-in keys of the keyed methods (style hold-out)
    sweep : also score ``upm`` over a grid of ``alpha`` and ``key_at`` (with diagnostics)
    plots : write the PNG plots
    """

    quick: bool = False
    holdouts: tuple = HOLDOUTS
    train_stride: int = 1
    max_windows: int | None = None
    pairs: int = 100
    som_epochs: float = 4
    latency_calls: int = 2000
    bench_scripts: bool = True
    diagnostics: bool = True
    sweep: bool = True
    plots: bool = True

    @classmethod
    def full(cls) -> Settings:
        return cls()

    @classmethod
    def quick_run(cls) -> Settings:
        return cls(quick=True, train_stride=4, max_windows=8, pairs=10, som_epochs=0.25, latency_calls=100,
                   bench_scripts=False, diagnostics=False, sweep=False)


# -- data ---------------------------------------------------------------------------------
def parse_name(path: str | Path) -> dict | None:
    """``{"content", "style", "id"}`` of a Bandai file name, or None for another name."""
    m = _NAME.match(Path(path).stem)
    return m.groupdict() if m else None


def split_files(files: list[Path], test_styles=TEST_STYLES, test_contents=()) -> tuple[list[Path], list[Path]]:
    """(train, test): test = files whose style is in ``test_styles`` or whose content is in
    ``test_contents``; others (and any file whose name does not follow the Bandai pattern)
    are training files. Both sorted."""
    train, test = [], []
    for f in sorted(files):
        info = parse_name(f)
        held = info is not None and (info["style"] in test_styles or info["content"] in test_contents)
        (test if held else train).append(f)
    return train, test


@dataclass
class Split:
    """One hold-out: training and test motions and how to measure them.

    train, test : lists of Motion (one skeleton); train_names, test_names : their names
    contents : motion type of each test clip (per-content tables)
    lengths : transition lengths (frames); rule : the split in words
    cm : centimetres per unit of the clips; unit : how that unit was found
    train_clips_all : training clips before ``Settings.train_stride``
    """

    name: str
    rule: str
    train: list
    train_names: list
    test: list
    test_names: list
    contents: list
    lengths: tuple
    cm: float
    unit: str
    train_clips_all: int


def unit_cm(motion: Motion) -> tuple[float, str]:
    """Centimetres per unit of a clip, and how it was found (:func:`posturemap.motion.length_unit`;
    a clip of unknown unit is taken to be in CMU's ASF unit, 1/0.45 inch)."""
    u = length_unit(motion)
    if u in UNIT_CM:
        return UNIT_CM[u], u
    return ASF_UNIT_CM, "ASF unit (1/0.45 inch, assumed for a body of unknown unit, as CMU's)"


def load_split(name: str, data_dir: Path, settings: Settings) -> Split:
    """Read the clips of one hold-out of :data:`HOLDOUTS` (see the module doc)."""
    from . import bvh

    data_dir = Path(data_dir)
    if name == "cmu":
        path = data_dir / CMU_FILE
        m = bvh.read(path)
        half = len(m) // 2
        cm, unit = unit_cm(m)
        return Split(name, f"{CMU_FILE.name}: training = frames 0-{half - 1}, test = frames {half}-{len(m) - 1}",
                     [m[:half]], [f"{CMU_FILE.name}[0:{half}]"], [m[half:]], [f"{CMU_FILE.name}[{half}:{len(m)}]"],
                     [CMU_FILE.stem], CMU_LENGTHS, cm, unit, 1)
    if name not in ("style", "content"):
        raise ValueError(f"unknown hold-out {name!r}; valid: {', '.join(HOLDOUTS)}")
    files = sorted((data_dir / "bandai1").glob("*.bvh"))
    if not files:
        raise FileNotFoundError(str(data_dir / "bandai1"))
    if name == "style":
        train_f, test_f = split_files(files, TEST_STYLES)
        rule = f"test = every clip of the styles {', '.join(TEST_STYLES)}; training = the other styles"
    else:
        train_f, test_f = split_files(files, (), TEST_CONTENTS)
        rule = (f"test = every clip of the contents (motion types) {', '.join(TEST_CONTENTS)}; "
                "training = the other contents, every style")
    used = train_f[:: settings.train_stride]
    train, test = [bvh.read(f) for f in used], [bvh.read(f) for f in test_f]
    cm, unit = unit_cm(test[0])
    contents = [(parse_name(f) or {"content": "other"})["content"] for f in test_f]
    return Split(name, rule, train, [f.name for f in used], test, [f.name for f in test_f], contents,
                 LENGTHS, cm, unit, len(train_f))


def window_starts(num_frames: int, window: int, stride: int = STRIDE) -> list[int]:
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
    samples, ``round(epochs * n)`` updates in seeded random order.
    """
    from minisom import MiniSom

    rows, cols = som_grid(n_neurons)
    som = MiniSom(rows, cols, x.shape[1], sigma=max(rows, cols) / 4.0, learning_rate=0.5,
                  decay_function="linear_decay_to_zero", sigma_decay_function="linear_decay_to_one",
                  neighborhood_function="gaussian", random_seed=seed)
    som.random_weights_init(x)
    som.train(x, max(1, round(epochs * len(x))), random_order=True)
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
    """What scoring needs besides the motions (skeleton, frames, training statistics).

    feet : indices of the foot joints; floor : (K,) their planted heights (a low percentile
    of their training heights, clip unit); std : (J, 3) L2P statistics; index : KD-tree of
    training postures; skate_height : H of the skate measure (clip unit); cm : centimetres
    per clip unit (every figure in cm is the clip's figure times ``cm``).
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
    ground from all T frames, averaged over ``steps``) per window (N,), and the older
    contact-based skate over the frames that ``steps`` spans (one mean over all contact steps).
    """
    feet = gpos[:, :, ctx.feet]
    per = metrics.weighted_skate(feet, ctx.fps, ctx.up, ctx.skate_height, ctx.floor, steps) * ctx.cm
    span = feet[:, steps.start: steps.stop + 1]
    contacts = metrics.foot_contacts(span, ctx.fps, ctx.up, ctx.floor, metrics.CONTACT_HEIGHT / ctx.cm,
                                     metrics.CONTACT_SPEED / ctx.cm)
    return per, metrics.foot_skate(span, ctx.fps, ctx.up, contacts)[0] * ctx.cm


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

    ``accuracy_only``: only L2Q and L2P (skips the pose-validity queries, the slow part).
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
    if accuracy_only:
        return {"l2q": metrics.l2q(p_rot[:, sl], t_rot[:, sl]),
                "l2p": metrics.l2p(p_pos[:, sl], t_pos[:, sl], ctx.std)}
    t_q = quat.unroll(t_rot[:, sl], axis=1)
    p_q = metrics.align_signs(p_rot[:, sl], t_q)
    n = len(truth_r)
    root_err = np.linalg.norm(pg_p[:, sl, ctx.root] - tg_p[:, sl, ctx.root], axis=-1)
    rel_p = pg_p[:, sl] - pg_p[:, sl, ctx.root: ctx.root + 1]
    rel_t = tg_p[:, sl] - tg_p[:, sl, ctx.root: ctx.root + 1]
    skate, contact = skate_scores(ctx, pg_p, slice(N_PAST - 1, N_PAST + length))
    valid = metrics.pose_validity(window_features(ctx, pred_r, pred_p), ctx.index)
    per_window = {
        "l2q": [metrics.l2q(p_rot[i: i + 1, sl], t_rot[i: i + 1, sl]) for i in range(n)],
        "l2p": [metrics.l2p(p_pos[i: i + 1, sl], t_pos[i: i + 1, sl], ctx.std) for i in range(n)],
        "mpjpe_cm": (np.linalg.norm(pg_p[:, sl] - tg_p[:, sl], axis=-1).mean(axis=(1, 2)) * ctx.cm).tolist(),
        "skate": skate.tolist(),
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
        "validity": float(valid.mean()),
        "validity_p95": float(np.percentile(valid, 95)),
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
    valid = metrics.pose_validity(window_features(ctx, truth_r[:, sl], truth_p[:, sl]), ctx.index)
    out = {"skate": float(skate.mean()), "contact_skate": contact, "validity": float(valid.mean()),
           "validity_p95": float(np.percentile(valid, 95)),
           "jerk": metrics.jerk(tg_p[:, N_PAST - 3: N_PAST + length + 3], ctx.fps) * ctx.cm,
           "per_window": {"skate": skate.tolist()}}
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


# -- the run -------------------------------------------------------------------------------
def _log(msg: str):
    print(msg, flush=True)


def prepare(split: Split, settings: Settings, seed: int, log=_log) -> dict:
    """Train the maps on a hold-out's training side; returns the shared state of the run."""
    from .model import PostureMap

    train, test = split.train, split.test
    log(f"{split.name} hold-out: {len(train)} training clips ({sum(map(len, train))} frames), "
        f"{len(test)} test clips ({sum(map(len, test))} frames)")
    t0 = time.perf_counter()
    model = PostureMap(seed=seed).fit(train, list(split.train_names))
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
    skate_height = metrics.SKATE_HEIGHT_LEGS * leg_length(sk, leg_chains(sk))
    ctx = Context(sk, space, root, up, fps, feet, floor, std,
                  metrics.build_posture_index(x_train[:, space.active]), skate_height, split.cm)
    return {"split": split, "train_files": split.train_names, "test_files": split.test_names,
            "train": train, "test": test, "model": model, "som": som, "som_info": som_info,
            "upm_seconds": upm_seconds, "ctx": ctx, "x_train": x_train, "stats_windows": len(wins_r)}


def make_windows(state: dict, settings: Settings, seed: int) -> list[tuple[int, int]]:
    """(test clip index, first frame) of every window used, in a fixed order."""
    window = N_PAST + max(state["split"].lengths) + N_FUTURE
    wins = [(c, s) for c, m in enumerate(state["test"]) for s in window_starts(len(m), window)]
    if settings.max_windows is not None and len(wins) > settings.max_windows:
        rng = np.random.default_rng(seed)
        keep = np.sort(rng.choice(len(wins), settings.max_windows, replace=False))
        wins = [wins[i] for i in keep]
    return wins


def make_engines(state: dict) -> dict:
    """One engine per key source, each holding every test clip (names = clip indices).

    The whole clips serve the cross-clip transitions, the latency and the diagnostics (which
    read the truth on purpose); in-betweening gives the methods the context frames only.
    """
    model = state["model"]
    engines = {"upm": TransitionEngine(model), "som": TransitionEngine(state["som"]),
               "fixed": TransitionEngine(fixed_key_model(model))}
    for e in engines.values():
        for c, m in enumerate(state["test"]):
            e.add(str(c), m)
    return engines


def _engine_call(engines, method: str) -> tuple[TransitionEngine, str, bool]:
    """(engine, engine method, foot lock) of a benchmark method or stand-in key."""
    if method == "som":
        return engines["som"], "upm", False
    if method in VARIANTS:
        return engines["fixed"], "upm", False
    base, feet = method_spec(method)
    return engines["upm"], base, feet


def _generate(engines, method, clip, length, a_end, b_start, **kw):
    """``method`` between frames ``a_end`` and ``b_start`` of one whole clip (diagnostics)."""
    eng, base, feet = _engine_call(engines, method)
    r, p = eng.generate(clip, clip, length, a_end=a_end, b_start=b_start, align=False, method=base,
                        foot_lock=feet, **kw)
    return r.copy(), p.copy()


def generate_from_context(engines, method: str, past: Motion, future: Motion, length: int):
    """``method``'s ``length`` frames between the past context (A) and the future context (B).

    The engine sees only these frames (as two clips; ``align=False``): no frame of the gap.
    Returns local rotations (L, J, 4) and positions (L, J, 3), new arrays.
    """
    eng, base, feet = _engine_call(engines, method)
    eng.add("_past", past)
    eng.add("_future", future)
    try:
        r, p = eng.generate("_past", "_future", length, a_end=len(past) - 1, b_start=0, align=False,
                            method=base, foot_lock=feet)
        return r.copy(), p.copy()
    finally:
        del eng.tracks["_past"], eng.tracks["_future"]


def run_inbetween(state: dict, windows, settings: Settings, seed: int, log=_log,
                  diagnostics: bool = False) -> tuple[dict, dict, dict]:
    """Scores per method and length, the truth's, per content, the diagnostics; plus curves
    for a plot. Returns ``(inbetween, diagnostics, example)`` (diagnostics empty unless asked).
    """
    ctx, engines = state["ctx"], state["engines"]
    test, lengths = state["test"], state["split"].lengths
    res = {"windows": len(windows), "lengths": list(lengths), "methods": {m: {} for m in METHODS},
           "truth": {}, "default_method": DEFAULT_SPEC, "vs_slerp": {m: {} for m in METHODS},
           "window_list": [[state["test_files"][c], s] for c, s in windows]}
    diag = {"key_distance": {}, "key_distance_by_class": {}, "variants": {v: {} for v in VARIANTS},
            "sweep": {}} if diagnostics else {}
    example = {}
    ref = natural_reference(ctx, test)
    for length in lengths:
        t0 = time.perf_counter()
        span = N_PAST + length + N_FUTURE
        truth_r = np.stack([test[c].rotations[s: s + span] for c, s in windows])
        truth_p = np.stack([test[c].positions[s: s + span] for c, s in windows])
        preds = {m: (np.empty((len(windows), length) + truth_r.shape[2:]),
                     np.empty((len(windows), length) + truth_p.shape[2:])) for m in METHODS}
        for i, (c, s) in enumerate(windows):
            past, future = test[c][s: s + N_PAST], test[c][s + N_PAST + length: s + span]
            for m in METHODS:
                if m == "zero-velocity":
                    preds[m][0][i], preds[m][1][i] = past.rotations[-1], past.positions[-1]
                else:
                    preds[m][0][i], preds[m][1][i] = generate_from_context(engines, m, past, future, length)
        sl = slice(N_PAST, N_PAST + length)
        nat = naturalness_fn(ctx, ref, windows, length)(
            np.concatenate([rebuilt_frames(truth_r, preds[m][0]) for m in METHODS] + [truth_r[:, N_PAST - 1: sl.stop]]),
            np.concatenate([rebuilt_frames(truth_p, preds[m][1]) for m in METHODS] + [truth_p[:, N_PAST - 1: sl.stop]]))
        nat = nat.reshape(len(METHODS) + 1, len(windows))
        n = str(length)
        truth_g = truth_globals(ctx, truth_r, truth_p)
        for k, m in enumerate(METHODS):
            res["methods"][m][n] = score_inbetween(ctx, truth_r, truth_p, *preds[m], length, natural=nat[k],
                                                   truth_g=truth_g)
        res["truth"][n] = score_truth(ctx, truth_r, truth_p, length, natural=nat[-1])
        for m in METHODS:
            res["vs_slerp"][m][n] = {
                k: paired_difference(res["methods"][m][n]["per_window"][k],
                                     res["methods"]["slerp"][n]["per_window"][k], seed)
                for k in ("l2q", "l2p")}
        if diagnostics:
            run_diagnostics(state, windows, settings, seed, length, truth_r, truth_p, preds, diag)
        if length == 30:  # plot a walking window when there is one
            names = [state["test_files"][c] for c, _ in windows]
            e = next((i for i, nm in enumerate(names) if "_walk_" in nm), 0)
            example = {m: np.concatenate([truth_r[e, :N_PAST], preds[m][0][e], truth_r[e, N_PAST + length:]])
                       for m in METHODS}
            example["truth"] = truth_r[e]
            example["window"] = windows[e]
            example["clip"] = names[e]
            example["joints"] = list(ctx.skeleton.names)
        r = res["methods"]
        log(f"  in-betweening L={length}: {len(windows)} windows in {time.perf_counter() - t0:.1f} s; "
            + ", ".join(f"{m} L2Q {r[m][n]['l2q']:.3f}" for m in METHODS))
    res["per_content"] = per_content(res, [state["split"].contents[c] for c, _ in windows])
    return res, diag, example


def run_diagnostics(state, windows, settings, seed, length, truth_r, truth_p, preds, diag):
    """Key distances and stand-in keys of the keyed methods at one length, into ``diag``.

    These read the truth on purpose (the oracle key): they explain the keyed methods' errors,
    they are not methods. ``preds`` holds the methods' frames (``upm``, ``slerp`` are used).
    """
    from .model import PostureMap

    ctx, engines, test = state["ctx"], state["engines"], state["test"]
    space = state["model"].space_
    fixed, upm, act = engines["fixed"].model, engines["upm"], space.active
    vpreds = {v: (np.empty_like(preds["slerp"][0]), np.empty_like(preds["slerp"][1])) for v in VARIANTS}
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
        set_key(fixed, blend)
        vpreds["blend-key"][0][i], vpreds["blend-key"][1][i] = _generate(engines, "blend-key", name, length,
                                                                         a_end, b_start)
        set_key(fixed, xt)
        vpreds["oracle-key"][0][i], vpreds["oracle-key"][1][i] = _generate(engines, "oracle-key", name,
                                                                           length, a_end, b_start)
        # A map learned from this clip's context alone (the frames outside the gap), as
        # `posturemap transition` does without --map: the clip's own style, no truth.
        own = PostureMap(seed=seed).fit([centred(test[c][: a_end + 1], ctx.root, ctx.up),
                                         centred(test[c][b_start:], ctx.root, ctx.up)])
        eng = TransitionEngine(own)
        eng.add(name, test[c])
        r, p = eng.generate(name, name, length, a_end=a_end, b_start=b_start, align=False, method="upm")
        vpreds["self-map-key"][0][i], vpreds["self-map-key"][1][i] = r, p
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
        vpreds["spline-v0"][0][i], vpreds["spline-v0"][1][i] = r, p
        set_key(fixed, blend)
        r, p = fixed_eng.generate("v0", "v0", length, a_end=a_w, b_start=b_w, align=False, method="upm")
        vpreds["blend-key-v0"][0][i], vpreds["blend-key-v0"][1][i] = r, p
        # upm's frames with the root joint's translation of slerp (LERP root).
        vpreds["upm-lerp-root"][0][i] = preds["upm"][0][i]
        vpreds["upm-lerp-root"][1][i] = preds["upm"][1][i]
        vpreds["upm-lerp-root"][1][i, :, ctx.root] = preds["slerp"][1][i, :, ctx.root]
    n = str(length)
    for v in VARIANTS:
        diag["variants"][v][n] = score_inbetween(ctx, truth_r, truth_p, *vpreds[v], length)
    diag["key_distance"][n] = {k: float(np.mean(v)) for k, v in kd.items()}
    diag["key_distance_by_class"][n] = {cls: {k: float(np.mean(v)) for k, v in kv.items()}
                                        for cls, kv in kdc.items()}
    if settings.sweep and length in SWEEP_LENGTHS:
        diag["sweep"][n] = sweep(state, windows, truth_r, truth_p, length)


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
    """``count`` seeded (a, b, a_end, b_start) with a != b (unless there is one clip only), 10
    real frames on both sides."""
    rng = np.random.default_rng(seed)
    ok = [i for i, n in enumerate(lengths) if n >= N_PAST + N_FUTURE]
    pairs = []
    while len(pairs) < count:
        a, b = rng.choice(ok, 2, replace=len(ok) < 2)
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
                eng, base, feet = _engine_call(engines, m)
                r, p = eng.generate(str(a), str(b), length, a_end=a_end, b_start=b_start, align=True,
                                    method=base, foot_lock=feet)
            seqs[m].append((np.concatenate([a_part.rotations, r, b_part.rotations]),
                            np.concatenate([a_part.positions, p, b_part.positions])))
        reference.append((a_part, b_part))
    out = {"pairs": len(pairs), "length": length, "align": True, "methods": {}}
    sl = slice(N_PAST, N_PAST + length)
    steps = slice(N_PAST - 1, N_PAST + length)
    parents = ctx.skeleton.parents
    for m in METHODS:
        rots = np.stack([s[0] for s in seqs[m]])
        pos = np.stack([s[1] for s in seqs[m]])
        _, gp = global_windows(rots, pos, parents)
        skate, contact = skate_scores(ctx, gp, steps)
        valid = metrics.pose_validity(window_features(ctx, rots[:, sl], pos[:, sl]), ctx.index)
        out["methods"][m] = {"skate": float(skate.mean()), "contact_skate": contact, "validity": float(valid.mean()),
                             "validity_p95": float(np.percentile(valid, 95)),
                             "jerk": metrics.jerk(gp[:, N_PAST - 3: N_PAST + length + 3], ctx.fps) * ctx.cm}
    # Reference: the real frames on both sides of the seams (10 of A, 10 of B, separately).
    real = [(np.stack([p.rotations for p in parts]), np.stack([p.positions for p in parts]))
            for parts in zip(*reference)]
    skates, contacts, jerks, valids = [], [], [], []
    for rots, pos in real:
        _, gp = global_windows(rots, pos, parents)
        skate, contact = skate_scores(ctx, gp, slice(0, gp.shape[1] - 1))
        skates.append(skate.mean())
        contacts.append(contact)
        jerks.append(metrics.jerk(gp, ctx.fps) * ctx.cm)
        valids.append(metrics.pose_validity(window_features(ctx, rots, pos), ctx.index))
    v = np.concatenate(valids)
    out["reference"] = {"skate": float(np.mean(skates)), "contact_skate": float(np.mean(contacts)),
                        "validity": float(v.mean()), "validity_p95": float(np.percentile(v, 95)),
                        "jerk": float(np.mean(jerks))}
    out["pair_list"] = [{"a": state["test_files"][a], "b": state["test_files"][b],
                         "a_end": a_end, "b_start": b_start} for a, b, a_end, b_start in pairs]
    log(f"  cross-clip: {len(pairs)} pairs in {time.perf_counter() - t0:.1f} s")
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
        eng, meth, feet = _engine_call(engines, m)
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


def run_holdout(name: str, data_dir: Path, settings: Settings, seed: int, log=_log) -> tuple[dict, dict, dict, dict]:
    """One hold-out end to end: read, train on its training side, in-betweening, cross-clip.

    Returns ``(results, diagnostics, example, state)`` (diagnostics for the style hold-out
    when ``settings.diagnostics``; ``state`` for the speed figures).
    """
    split = load_split(name, data_dir, settings)
    state = prepare(split, settings, seed, log)
    state["engines"] = make_engines(state)
    windows = make_windows(state, settings, seed)
    log(f"  in-betweening: {len(windows)} windows from {len(state['test'])} test clips")
    inb, diag, example = run_inbetween(state, windows, settings, seed, log,
                                       diagnostics=settings.diagnostics and name == "style")
    cross = run_cross(state, settings, seed, log) if len(state["test"]) >= 2 and settings.pairs else None
    model, ctx = state["model"], state["ctx"]
    out = {
        "split": {"rule": split.rule, "test_clips": len(split.test), "test_frames": int(sum(map(len, split.test))),
                  "train_clips_all": split.train_clips_all, "train_clips": len(split.train),
                  "train_frames": int(sum(map(len, split.train))), "fps": ctx.fps,
                  "joints": ctx.skeleton.num_joints, "unit": split.unit, "cm_per_unit": split.cm,
                  "test_files": list(split.test_names), "train_files": list(split.train_names)},
        "map": {"neurons": model.neuron_counts(), "radius": [m.radius_ for m in model.maps_],
                "train_seconds": state["upm_seconds"], "som": state["som_info"]},
        "feet": {"joints": [ctx.skeleton.names[j] for j in ctx.feet], "floor_cm": (ctx.floor * ctx.cm).tolist(),
                 "floor_percentile": FLOOR_PERCENTILE, "skate_height_cm": ctx.skate_height * ctx.cm,
                 "leg_length_cm": ctx.skate_height / metrics.SKATE_HEIGHT_LEGS * ctx.cm},
        "inbetween": inb, "cross_clip": cross,
    }
    return out, diag, example, state


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

    code = code_version()  # at the start: the code that runs, whatever changes meanwhile

    sections = {}
    clock = time.perf_counter()

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        sections[name] = now - clock
        clock = now

    holdouts, examples, diag, speed_state = {}, {}, {}, None
    for name in settings.holdouts:
        holdouts[name], d, examples[name], state = run_holdout(name, data_dir, settings, seed, log)
        diag = diag or d
        if speed_state is None or name == "style":
            speed_state = state
        lap(f"{name} hold-out")
    log("speed: latency")
    speed = {"latency": latency(speed_state, settings.latency_calls, seed), "training": [], "bench": {},
             "holdout": speed_state["split"].name}
    log("speed: training")
    speed["training"] = training_speed(speed_state, seed)
    speed_state = state = None
    lap("speed: latency and training")
    for name in ("transition_speed", "train_speed", "bvh_load"):
        if settings.bench_scripts:
            log(f"speed: bench/{name}.py")
            speed["bench"][name] = run_bench_script(name, data_dir, settings, seed, log)
        else:
            speed["bench"][name] = {"status": "skipped", "reason": "--quick skips the bench/ scripts"}
        lap(f"bench/{name}.py")
    results = {
        "config": {"seed": seed, **dataclasses.asdict(settings), "n_past": N_PAST, "n_future": N_FUTURE,
                   "stride": STRIDE, "cross_length": CROSS_LENGTH, "natural_frames": NATURAL_FRAMES,
                   "natural_stride_s": NATURAL_STRIDE_S, "skate_height_legs": metrics.SKATE_HEIGHT_LEGS,
                   "test_styles": list(TEST_STYLES), "test_contents": list(TEST_CONTENTS)},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "code": code},
        "holdouts": holdouts, "diagnostics": diag, "speed": speed, "section_seconds": sections,
    }
    results["plots"] = report.plot(results, examples, out) if settings.plots else []
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
    if not (data / CMU_FILE).is_file():
        raise UserError(str(data), f"no {CMU_FILE.as_posix()} here (the 120 fps hold-out; set --data or POSTUREMAP_DATA)")
    settings = Settings.quick_run() if args.quick else Settings.full()
    run(data, args.out, seed=args.seed, settings=settings)
    return 0
