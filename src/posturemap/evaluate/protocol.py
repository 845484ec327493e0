"""The bench's protocol: hold-outs and their splits, windows, methods, settings.

See :mod:`posturemap.evaluate` for the protocol in words.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.motion import Motion, length_unit
from ..synth.request import DEFAULT_METHOD
from ..synth.request import METHODS as ENGINE_METHODS

HOLDOUTS = ("style", "content", "cmu")
OWN = "own"  # the hold-out of a user's own clips (`posturemap bench --train ... --test ...`: load_own)
OWN_LENGTHS_30 = (5, 15, 30, 45)  # its default gaps: the bench's, frames at 30 fps (as long at the test clips' rate)
TEST_STYLES = ("angry", "old", "proud")
TEST_CONTENTS = ("dash", "walk-back", "byebye")
# More splits of bandai1, each holding out other whole styles or motion types (every clip of
# them): the default's choices are checked on these too, since one split can flatter a rule
# tuned on it. Scored for the main methods' accuracy and skate only (see runner.run_split).
MORE_SPLITS = {"styles-2": (("childish", "giant", "tired"), ()),
               "styles-3": (("chimpira", "musical", "sad"), ()),
               "contents-2": ((), ("walk-left", "run", "bye")),
               "contents-3": ((), ("walk", "guide"))}
SPLIT_LENGTHS = (15, 30, 45)
LENGTHS = (5, 15, 30, 45)
CMU_FILE = Path("cmu") / "01_01.bvh"
CMU_LENGTHS = (5, 15, 20, 30, 45, 60, 120, 180)  # 5-45 frames, and 20-180: the 30 fps durations
N_PAST = 10
N_FUTURE = 10
STRIDE = 40
STATS_WINDOW, STATS_STRIDE = 50, 20  # LaFAN1 get_train_stats
CROSS_LENGTH = 20
_BASELINES = ("slerp", "inertialize", "spline")
FEET = "+feet"  # suffix: the method with foot locking (posturemap.synth.feet)
DEFAULT_SPEC = DEFAULT_METHOD + FEET  # what `posturemap transition` does by default
# Every method of the engine (new ones join automatically), foot-locked variants, and the
# two built here.
_FOOT_LOCKED = tuple(m + FEET for m in dict.fromkeys(("upm-valid", DEFAULT_METHOD)) if m in ENGINE_METHODS)
METHODS = (("zero-velocity",) + tuple(m for m in _BASELINES if m in ENGINE_METHODS)
           + tuple(m for m in ENGINE_METHODS if m not in _BASELINES) + _FOOT_LOCKED + ("som",))


def method_spec(m: str) -> tuple[str, bool]:
    """Engine method and foot locking of a method name of this benchmark."""
    return (m[: -len(FEET)], True) if m.endswith(FEET) else (m, False)


# In-betweening of a gap in a take: A is the test clip up to the last past frame and B the clip
# from the first future frame (the whole clip but the gap, where the protocol above gives 10 frames
# each). The default as it runs (the clips' own motion searched beside the library) and with the
# library only (TransitionEngine.own_seconds = 0): label -> own_seconds (None: the engine's default).
WHOLE_CLIP = {DEFAULT_SPEC: None, DEFAULT_SPEC + ", library only": 0.0}
VARIANTS = ("blend-key", "oracle-key", "self-map-key", "spline-v0", "blend-key-v0", "upm-lerp-root")
SWEEP_LENGTHS = (15, 30, 45)
SWEEP_FRACTIONS = (0.25, 0.5, 0.75)
FLOOR_PERCENTILE = 5.0
# The methods scored on MORE_SPLITS: the baselines, the previous default and the default.
SPLIT_METHODS = tuple(m for m in ("slerp", "spline", "inertialize", "upm-valid" + FEET, DEFAULT_SPEC)
                      if m in METHODS)
UNIT_CM = {"m": 100.0, "cm": 1.0, "mm": 0.1, "inch": 2.54}
ASF_UNIT_CM = 2.54 / 0.45  # CMU's BVH conversions keep the ASF unit, 1/0.45 inch
QUALITY_KEYS = ("holdouts", "diagnostics")

_NAME = re.compile(r"^dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_(?P<id>\d+)$")


@dataclass(frozen=True)
class Settings:
    """How much of the benchmark to run (see :meth:`full` and :meth:`quick_run`).

    holdouts : which hold-outs of :data:`HOLDOUTS` to run
    more_splits : which splits of :data:`MORE_SPLITS` to score besides (the main methods' accuracy)
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
    more_splits: tuple = tuple(MORE_SPLITS)
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
    criteria : the lengths (frames) the acceptance criteria take for the bench's 15, 30 and 45
        frames at 30 fps (None: those frame counts themselves)
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
    criteria: tuple | None = None


def unit_cm(motion: Motion) -> tuple[float, str]:
    """Centimetres per unit of a clip, and how it was found (:func:`posturemap.core.motion.length_unit`;
    a clip of unknown unit is taken to be in CMU's ASF unit, 1/0.45 inch)."""
    u = length_unit(motion)
    if u in UNIT_CM:
        return UNIT_CM[u], u
    return ASF_UNIT_CM, "ASF unit (1/0.45 inch, assumed for a body of unknown unit, as CMU's)"


def load_split(name: str, data_dir: Path, settings: Settings) -> Split:
    """Read the clips of one hold-out of :data:`HOLDOUTS` or one split of :data:`MORE_SPLITS`
    (see the module doc)."""
    from ..io import bvh

    data_dir = Path(data_dir)
    if name == "cmu":
        path = data_dir / CMU_FILE
        m = bvh.read(path)
        half = len(m) // 2
        cm, unit = unit_cm(m)
        return Split(name, f"{CMU_FILE.name}: training = frames 0-{half - 1}, test = frames {half}-{len(m) - 1}",
                     [m[:half]], [f"{CMU_FILE.name}[0:{half}]"], [m[half:]], [f"{CMU_FILE.name}[{half}:{len(m)}]"],
                     [CMU_FILE.stem], CMU_LENGTHS, cm, unit, 1)
    splits = {"style": (TEST_STYLES, ()), "content": ((), TEST_CONTENTS), **MORE_SPLITS}
    if name not in splits:
        raise ValueError(f"unknown hold-out {name!r}; valid: {', '.join(HOLDOUTS + tuple(MORE_SPLITS))}")
    files = sorted((data_dir / "bandai1").glob("*.bvh"))
    if not files:
        raise FileNotFoundError(str(data_dir / "bandai1"))
    styles, contents = splits[name]
    train_f, test_f = split_files(files, styles, contents)
    if styles:
        rule = f"test = every clip of the styles {', '.join(styles)}; training = the other styles"
    else:
        rule = (f"test = every clip of the contents (motion types) {', '.join(contents)}; "
                "training = the other contents, every style")
    used = train_f[:: settings.train_stride]
    train, test = [bvh.read(f) for f in used], [bvh.read(f) for f in test_f]
    cm, unit = unit_cm(test[0])
    kinds = [(parse_name(f) or {"content": "other"})["content"] for f in test_f]
    return Split(name, rule, train, [f.name for f in used], test, [f.name for f in test_f], kinds,
                 LENGTHS if name in HOLDOUTS else SPLIT_LENGTHS, cm, unit, len(train_f))


def _as_long(frames_30, fps: float) -> tuple:
    """Frame counts at 30 fps as long at ``fps`` (at least one frame each), in their order."""
    return tuple(max(1, round(n * fps / 30.0)) for n in frames_30)


def own_lengths(fps: float) -> tuple:
    """The bench's gaps, :data:`OWN_LENGTHS_30` frames at 30 fps, as long at ``fps`` (at least one frame)."""
    return tuple(sorted(set(_as_long(OWN_LENGTHS_30, fps))))


def load_own(train_inputs: list[str], test_inputs: list[str], lengths=None, log=None) -> Split:
    """The hold-out of a user's own clips: the library from ``train_inputs``, gaps in
    ``test_inputs`` (BVH files or folders of them; :func:`posturemap.io.bvh.read_inputs`).

    Every clip must have the first training clip's skeleton. Test clips at another rate than
    the first test clip's are resampled to it, training clips to the first training clip's (a map
    serves clips at another rate). ``lengths``: the gaps in frames at the test clips' rate
    (default :func:`own_lengths`). The per-motion tables group the test clips by the input each
    came from (a folder as given, a file's stem); clips are named by their paths as given.
    Raises :class:`~posturemap.errors.UserError` naming the file for a clip of another skeleton,
    a test clip of fewer than two frames, a test set with no clip long enough for one window, or
    a training set with no clip long enough for the L2P statistics' windows. A clip given both
    for training and for testing is named in a warning (its gaps are in the library).
    """
    import os

    from ..core.motion import at_one_rate, resampled_note
    from ..errors import UserError
    from ..io import bvh

    def read(inputs):
        groups = []
        for item in inputs:
            clips = bvh.read_inputs([item])
            label = (os.path.normpath(item) if os.path.normpath(item) != "." else os.path.basename(os.getcwd())
                     ) if os.path.isdir(item) else Path(item).stem
            groups += [(path, m, label) for path, m in clips]
        motions, changed = at_one_rate([m for _, m, _ in groups], names=[p for p, _, _ in groups])
        for i in changed:
            (log or _log)(resampled_note(groups[i][0], groups[i][1].fps, motions[0].fps))
        return [p for p, _, _ in groups], motions, [k for _, _, k in groups]

    train_paths, train, _ = read(train_inputs)
    test_paths, test, kinds = read(test_inputs)
    both = {os.path.realpath(p) for p in train_paths} & {os.path.realpath(p) for p in test_paths}
    for path in test_paths:
        if os.path.realpath(path) in both:
            (log or _log)(f"posturemap: warning: {path}: given for training and for testing: its gaps are in the "
                          "library, and the scores flatter every method that reads it")
    for path, m in zip(test_paths, test):
        if len(m) < 2:
            raise UserError(path, f"a test clip needs 2 frames at least (it has {len(m)})")
    first = train[0].skeleton
    for path, m in zip(train_paths + test_paths, train + test):
        if not m.skeleton.same_as(first):
            whose = f"{train_paths[0]}'s"
            raise UserError(path, f"skeleton differs from {whose} ({m.skeleton.difference(first, whose)})")
    fps = float(test[0].fps)
    lengths = own_lengths(fps) if lengths is None else tuple(sorted(set(int(n) for n in lengths)))
    window = N_PAST + max(lengths) + N_FUTURE
    if not any(len(m) > window for m in test):
        raise UserError(test_paths[0], f"no test clip is longer than one window of {window} frames "
                                       f"({N_PAST} before the gap, {max(lengths)} in it, {N_FUTURE} after): "
                                       "give longer clips or shorter --lengths")
    if not any(len(m) > STATS_WINDOW for m in train):
        raise UserError(train_paths[0], f"no training clip is longer than {STATS_WINDOW} frames (the windows "
                                        "L2P's statistics are taken over)")
    cm, unit = unit_cm(test[0])
    criteria = _as_long((15, 30, 45), fps)
    rule = (f"training = {len(train)} clips of {', '.join(train_inputs)}; "
            f"test = {len(test)} clips of {', '.join(test_inputs)}")
    return Split(OWN, rule, train, list(train_paths), test, list(test_paths), kinds, lengths, cm, unit, len(train),
                 criteria)


def window_starts(num_frames: int, window: int, stride: int = STRIDE) -> list[int]:
    """First frames of the windows of one clip (LaFAN1: ``while start + window < frames``)."""
    return list(range(0, max(num_frames - window, 0), stride))


def make_windows(state: dict, settings: Settings, seed: int) -> list[tuple[int, int]]:
    """(test clip index, first frame) of every window used, in a fixed order."""
    window = N_PAST + max(state["split"].lengths) + N_FUTURE
    wins = [(c, s) for c, m in enumerate(state["test"]) for s in window_starts(len(m), window)]
    if settings.max_windows is not None and len(wins) > settings.max_windows:
        rng = np.random.default_rng(seed)
        keep = np.sort(rng.choice(len(wins), settings.max_windows, replace=False))
        wins = [wins[i] for i in keep]
    return wins


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


def _log(msg: str):
    print(msg, flush=True)
