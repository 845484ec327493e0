"""UPM training speed: samples/s against MiniSom at equal neuron count, full-set time, scaling.

Three measurements, all on the posture vectors of bandai1 (174 clips, 31,914 frames; default
``logmap`` features):

1. **Samples/s at equal neuron count.** The ``global`` class (upper arms, clavicles, thighs:
   18 dimensions). The UPM radius is searched (secant steps on log R against log neurons,
   full training each step) until the map has ``--neurons`` (1000) +- 3%; MiniSom then gets the
   most square grid of the same size (e.g. 32 x 31), sigma = side / 4, learning rate 0.5,
   weights initialised on samples, and the same number of sample presentations as the UPM
   (epochs x samples = 4 x 31,914) through ``train_random``. Rates are presentations per
   second. Two UPM figures: the Algorithm 1 epochs alone (timed to the last epoch's progress
   callback, which is what MiniSom's ``train_random`` does) and the whole ``fit()`` (plus the
   final graph, hit counts and quality figures). Runs are interleaved; medians over
   ``--repeat`` (3).
2. **All of bandai1 with defaults.** ``PostureMap().fit`` on every clip (the four class maps,
   radius ``auto``), clips already loaded; and ``posturemap train <bandai1> -o MAP`` as a
   subprocess (interpreter start, BVH loading, training, saving).
3. **Scaling.** 10k, 100k and 1M frames: the first 10k frames of bandai1; for the larger sizes
   bandai1 repeated clip by clip with seeded Gaussian jitter (sigma 0.01 per dimension) on
   every copy. The four class maps are trained with defaults (as ``PostureMap.fit`` does:
   radius ``auto`` per class, four threads at most). Each size runs in its own process,
   which reports its training time and peak resident memory (``getrusage(RUSAGE_SELF)``,
   before and after training).

numba compiles the kernels on first use (cached on disk): every measurement warms up first.

Usage::

    python bench/train_speed.py [--quick] [--data DIR] [--repeat 3] [--sizes 10000,100000,1000000]
                                [--no-full] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))

from posturemap.io import bvh
from posturemap.learn import features
from posturemap.learn.features import CLASSES
from posturemap.learn.model import PostureMap
from posturemap.learn.upm import UniformPostureMap

GOAL_RATIO = 10.0  # UPM samples/s at least 10x MiniSom's
GOAL_FULL_SECONDS = 10.0  # all of bandai1 with defaults
JITTER = 0.01


def default_data_dir() -> Path:
    """``$POSTUREMAP_DATA`` or ``../shared/data`` next to the repository."""
    env = os.environ.get("POSTUREMAP_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


def load_bandai(data_dir: Path):
    files = sorted((data_dir / "bandai1").glob("*.bvh"))
    if not files:
        raise SystemExit(f"train_speed: no bandai1 clips under {data_dir} (set --data or POSTUREMAP_DATA)")
    return files, [bvh.read(f) for f in files]


def posture_vectors(motions, mode="logmap"):
    """Feature space, full vectors (n, D) and clip labels (n,)."""
    space = features.fit_space(motions, mode)
    x = np.concatenate([space.encode(m) for m in motions])
    seq = np.concatenate([np.full(len(m), i) for i, m in enumerate(motions)])
    return space, x, seq


# -- 1. samples/s ----------------------------------------------------------------------------
def timed_upm(X, seq, radius, seed=0):
    """Fit once; returns (map, seconds to the end of the last epoch, seconds for the whole fit)."""
    marks = []
    m = UniformPostureMap(radius=radius, seed=seed)
    t0 = time.perf_counter()
    m.fit(X, seq, progress=lambda e, n, err: marks.append(time.perf_counter()))
    t1 = time.perf_counter()
    return m, marks[-1] - t0, t1 - t0


def radius_for(X, seq, target, tol=0.03, max_steps=10):
    """Radius whose map has ``target`` neurons +- ``tol`` (secant on log-log); (radius, neurons, steps)."""
    from posturemap.learn.upm import auto_radius

    r = auto_radius(X, np.full(X.shape[1], np.inf))
    pts = []
    for step in range(1, max_steps + 1):
        n = UniformPostureMap(radius=r).fit(X, seq).n_neurons
        pts.append((np.log(r), np.log(n)))
        if abs(n - target) <= tol * target:
            return r, n, step
        if len(pts) == 1:
            slope = -2.0  # first guess: neurons ~ R^-2
        else:
            (a0, b0), (a1, b1) = pts[-2], pts[-1]
            slope = (b1 - b0) / (a1 - a0) if a1 != a0 and b1 != b0 else -2.0
            slope = min(slope, -0.5)
        r = float(np.exp(np.log(r) + (np.log(target) - np.log(n)) / slope))
    return r, n, max_steps


def grid_shape(n):
    rows = max(1, round(np.sqrt(n)))
    return rows, max(1, round(n / rows))


def timed_minisom(X, rows, cols, iterations, seed=0):
    from minisom import MiniSom

    som = MiniSom(rows, cols, X.shape[1], sigma=max(rows, cols) / 4.0, learning_rate=0.5, random_seed=seed)
    som.random_weights_init(X)
    t0 = time.perf_counter()
    som.train_random(X, iterations)
    return time.perf_counter() - t0


def speed(x, seq, space, target=1000, repeat=3, log=print):
    X = np.ascontiguousarray(space.split(x)[CLASSES.index("global")])
    UniformPostureMap(radius=1.0).fit(X[:500], seq[:500])  # warm-up (compiled kernels)
    timed_minisom(X[:500], 4, 4, 100)
    t0 = time.perf_counter()
    radius, neurons, steps = radius_for(X, seq, target)
    log(f"  radius {radius:.4f} -> {neurons} neurons ({steps} fits, {time.perf_counter() - t0:.1f} s)")
    rows, cols = grid_shape(neurons)
    epochs = UniformPostureMap().epochs
    presentations = epochs * len(X)
    upm_train, upm_fit, som = [], [], []
    for r in range(repeat):
        m, t_train, t_fit = timed_upm(X, seq, radius)
        t_som = timed_minisom(X, rows, cols, presentations, seed=r)
        upm_train.append(t_train)
        upm_fit.append(t_fit)
        som.append(t_som)
        log(f"  repeat {r + 1}: UPM epochs {t_train:.2f} s, fit {t_fit:.2f} s; MiniSom {t_som:.2f} s")
    med = {k: statistics.median(v) for k, v in (("upm_train", upm_train), ("upm_fit", upm_fit), ("som", som))}
    return {
        "class": "global", "dims": int(X.shape[1]), "samples": len(X), "presentations": presentations,
        "radius": radius, "upm_neurons": int(m.n_neurons), "som_grid": [rows, cols], "som_neurons": rows * cols,
        "seconds": {k: v for k, v in (("upm_train", upm_train), ("upm_fit", upm_fit), ("som", som))},
        "median_seconds": med,
        "samples_per_s": {k: presentations / v for k, v in med.items()},
        "ratio_train": med["som"] / med["upm_train"], "ratio_fit": med["som"] / med["upm_fit"],
    }


# -- 2. all of bandai1 -----------------------------------------------------------------------
def full_training(files, motions, repeat=2, cli_runs=2, log=print):
    PostureMap(epochs=1).fit([m[:200] for m in motions[:4]])  # warm-up
    fits = []
    for r in range(repeat):
        t0 = time.perf_counter()
        pm = PostureMap().fit(motions)
        fits.append(time.perf_counter() - t0)
        log(f"  PostureMap().fit: {fits[-1]:.2f} s, neurons {pm.neuron_counts()}")
    clis = []
    folder = files[0].parent
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bandai1.npz"
        cmd = [sys.executable, "-m", "posturemap.cli", "train", str(folder), "-o", str(out)]
        for _ in range(cli_runs):
            t0 = time.perf_counter()
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
            clis.append(time.perf_counter() - t0)
            if proc.returncode != 0:
                raise RuntimeError(f"posturemap train failed: {proc.stderr.strip()}")
            log(f"  posturemap train: {clis[-1]:.2f} s ({proc.stdout.strip()})")
    return {"clips": len(motions), "frames": int(sum(len(m) for m in motions)),
            "neurons": pm.neuron_counts(), "radius": [m.radius_ for m in pm.maps_],
            "fit_seconds": fits, "fit_median": statistics.median(fits),
            "cli_seconds": clis, "cli_median": statistics.median(clis),
            "cli_command": "posturemap train " + str(folder) + " -o bandai1.npz"}


# -- 3. scaling ------------------------------------------------------------------------------
def scaled_data(x, seq, frames, seed=0):
    """``frames`` rows: bandai1 itself when it is long enough, else copies with jitter."""
    if frames <= len(x):
        return x[:frames].copy(), seq[:frames].copy()
    rng = np.random.default_rng(seed)
    idx = np.arange(frames) % len(x)
    copy = np.arange(frames) // len(x)
    big = x[idx]
    big += rng.normal(0.0, JITTER, big.shape)
    return big, seq[idx] + copy * (seq.max() + 1)


def train_four(space, x, seq):
    """The four class maps with defaults, as PostureMap.fit trains them (threads)."""
    parts = space.split(x)
    maps = [UniformPostureMap(seed=c) for c in range(len(CLASSES))]
    with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
        list(pool.map(lambda c: maps[c].fit(parts[c], seq), range(len(CLASSES))))
    return maps


def scale_child(frames, data_dir):
    """Runs in a fresh process: one size, prints one JSON line."""
    _, motions = load_bandai(data_dir)
    space, x, seq = posture_vectors(motions)
    del motions
    UniformPostureMap(radius=1.0).fit(x[:300, :5])  # warm-up
    xs, ss = scaled_data(x, seq, frames)
    del x
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    maps = train_four(space, xs, ss)
    seconds = time.perf_counter() - t0
    rss_after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"frames": frames, "seconds": seconds, "neurons": [m.n_neurons for m in maps],
                      "radius": [m.radius_ for m in maps], "data_mb": xs.nbytes / 2 ** 20,
                      "peak_rss_mb_before_training": rss_before / 1024, "peak_rss_mb": rss_after / 1024}))


def scaling(sizes, data_dir, log=print):
    rows = []
    for frames in sizes:
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--scale-child", str(frames),
                               "--data", str(data_dir)], capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise RuntimeError(f"scaling run for {frames} frames failed:\n{proc.stderr}")
        row = json.loads(proc.stdout.strip().splitlines()[-1])
        row["process_seconds"] = time.perf_counter() - t0
        rows.append(row)
        log(f"  {frames:>9,} frames: {row['seconds']:.1f} s, neurons {row['neurons']}, "
            f"peak RSS {row['peak_rss_mb']:.0f} MB")
    return rows


# -- report ----------------------------------------------------------------------------------
def markdown(report: dict) -> str:
    s = report["speed"]
    sps = s["samples_per_s"]
    out = [(f"### Training samples/s at equal neuron count (bandai1 `global` class, {s['dims']} dims, "
           f"{s['samples']:,} samples x {s['presentations'] // s['samples']} = {s['presentations']:,} presentations; "
           f"median of {len(s['seconds']['som'])})"), "",
           "| map | neurons | median s | samples/s | UPM / MiniSom |", "|---|---:|---:|---:|---:|",
           (f"| UPM, Algorithm 1 epochs (R = {s['radius']:.4f}) | {s['upm_neurons']} | "
           f"{s['median_seconds']['upm_train']:.2f} | {sps['upm_train']:,.0f} | **{s['ratio_train']:.1f}x** |"),
           (f"| UPM, whole `fit()` (+ final graph, quality) | {s['upm_neurons']} | "
           f"{s['median_seconds']['upm_fit']:.2f} | {sps['upm_fit']:,.0f} | {s['ratio_fit']:.1f}x |"),
           (f"| MiniSom `train_random` ({s['som_grid'][0]}x{s['som_grid'][1]}, sigma "
           f"{max(s['som_grid']) / 4:g}) | {s['som_neurons']} | {s['median_seconds']['som']:.2f} | "
           f"{sps['som']:,.0f} | 1.0x |"), "",
           (f"Goal: UPM >= {GOAL_RATIO:g}x MiniSom: {'met' if s['ratio_train'] >= GOAL_RATIO else 'NOT met'} "
           f"({s['ratio_train']:.1f}x epochs only, {s['ratio_fit']:.1f}x whole fit).")]
    f = report.get("full")
    if f:
        out += ["", f"### All of bandai1 with defaults ({f['clips']} clips, {f['frames']:,} frames)", "",
                "| what | runs (s) | median s |", "|---|---|---:|",
                (f"| `PostureMap().fit(clips)` (loaded clips) | {', '.join(f'{v:.2f}' for v in f['fit_seconds'])} | "
                f"{f['fit_median']:.2f} |"),
                (f"| `{f['cli_command']}` (subprocess, wall) | {', '.join(f'{v:.2f}' for v in f['cli_seconds'])} | "
                f"{f['cli_median']:.2f} |"), "",
                (f"Neurons per class (body, global, medium, detail): {', '.join(map(str, f['neurons']))}; radius "
                f"auto: {', '.join(f'{r:.3f}' for r in f['radius'])}. Goal: under {GOAL_FULL_SECONDS:g} s: "
                f"{'met' if f['cli_median'] < GOAL_FULL_SECONDS else 'NOT met'}.")]
    rows = report.get("scaling")
    if rows:
        out += ["", "### Scaling: four class maps with defaults (own process per size)", "",
                ("| frames | data | train s | frames/s | neurons (body, global, medium, detail) | "
                "peak RSS before training | peak RSS |"), "|---:|---|---:|---:|---|---:|---:|"]
        for r in rows:
            kind = "bandai1 (first frames)" if r["frames"] <= report.get("bandai_frames", 0) else \
                f"bandai1 x {r['frames'] / report.get('bandai_frames', 1):.1f}, jitter {JITTER}"
            out.append(f"| {r['frames']:,} | {kind} | {r['seconds']:.1f} | {r['frames'] / r['seconds']:,.0f} | "
                       f"{', '.join(map(str, r['neurons']))} | {r['peak_rss_mb_before_training']:.0f} MB | "
                       f"{r['peak_rss_mb']:.0f} MB |")
    return "\n".join(out)


def run(data: str | os.PathLike | None = None, quick: bool = False, repeat: int = 3, neurons: int = 1000,
        sizes=None, full: bool = True, log=print) -> dict:
    """All three measurements; returns a JSON-ready dict."""
    data_dir = Path(data) if data else default_data_dir()
    t_start = time.perf_counter()
    files, motions = load_bandai(data_dir)
    space, x, seq = posture_vectors(motions)
    report = {"date": time.strftime("%Y-%m-%d %H:%M"), "machine": {
        "cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(),
        "load_average_at_start": os.getloadavg()}, "bandai_frames": len(x), "quick": quick}
    if quick:
        keep = np.isin(seq, np.unique(seq)[::4])  # every 4th clip
        x_speed, seq_speed = x[keep], seq[keep]
        repeat = 1
        sizes = sizes or (10_000, 30_000)
    else:
        x_speed, seq_speed = x, seq
        sizes = sizes or (10_000, 100_000, 1_000_000)
    log(f"1. samples/s, UPM vs MiniSom at ~{neurons} neurons ({len(x_speed):,} samples)")
    report["speed"] = speed(x_speed, seq_speed, space, neurons, repeat, log)
    if full:
        log("2. all of bandai1 with defaults")
        report["full"] = full_training(files, motions, repeat=1 if quick else 2, cli_runs=1 if quick else 2, log=log)
    log("3. scaling")
    report["scaling"] = scaling(sizes, data_dir, log)
    report["machine"]["load_average_at_end"] = os.getloadavg()
    report["total_seconds"] = time.perf_counter() - t_start
    return report


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default=None, help="data folder (default: $POSTUREMAP_DATA or ../shared/data)")
    p.add_argument("--quick", action="store_true", help="a fast variant (about a minute)")
    p.add_argument("--repeat", type=int, default=3, help="repeats of the samples/s comparison (3)")
    p.add_argument("--neurons", type=int, default=1000, help="neuron count of both maps (1000)")
    p.add_argument("--sizes", default=None,
                   help="frame counts of the scaling runs, comma-separated (10000,100000,1000000; "
                        "--quick: 10000,30000)")
    p.add_argument("--no-full", action="store_true", help="skip the all-of-bandai1 timings")
    p.add_argument("--json", default=None, metavar="PATH", help="also write the results as JSON")
    p.add_argument("--scale-child", type=int, default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    data_dir = Path(args.data) if args.data else default_data_dir()
    if args.scale_child:
        scale_child(args.scale_child, data_dir)
        return 0
    sizes = tuple(int(v) for v in args.sizes.split(",") if v.strip()) if args.sizes else None
    report = run(data_dir, args.quick, args.repeat, args.neurons, sizes, not args.no_full,
                 log=lambda s: print(s, file=sys.stderr))
    print(markdown(report))
    print(f"\n(total {report['total_seconds']:.0f} s; load average {report['machine']['load_average_at_start']} "
          f"at start, {report['machine']['load_average_at_end']} at end)")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
