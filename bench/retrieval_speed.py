"""Retrieval transitions: latency, scaling with the library, in-betweening, and the index against its peers.

All on Bandai-Namco dataset 1 (``<data>/bandai1``), a map (with its motion library) trained on
every clip with default parameters, every clip prepared once in a
:class:`posturemap.synth.engine.TransitionEngine`:

- **latency**: one 30-frame transition between two different clips (seeded draws of clips,
  seams and alpha; B moved to continue A), ``retrieval`` with its foot lock next to the
  previous default (``upm-valid`` + foot lock) and SLERP, interleaved call by call; median and
  p99 of ``time.perf_counter_ns`` after warm-up calls;
- **10x library**: the same calls with a library of ten copies of every clip, each copy's
  rotations jittered by a seeded random rotation of about 1 degree per joint and frame (the
  map is the same; the copies' frames are indexed through it), on a second engine interleaved
  call by call with the first, so that the 10x / 1x ratio does not depend on how busy the
  shared machine was in one part of the run or another;
- **in-betweening**: one 30-frame gap inside a clip (B the same clip, kept where it is; seeded
  draws of clips of at least 90 frames and of the gap's place), the default (``auto`` + foot
  lock) as it runs, searching the clips' own motion (A's frames before the gap, B's after it)
  beside the library, against the same with the library only (``own_seconds`` 0) and SLERP,
  interleaved call by call; each call's seams are new, so each builds its own-motion search
  (one built for a seam pair is kept for the next call on it, as a slider's);
- **index**: how the candidate frames are found, each followed by the same exact re-rank of
  the same cost (:meth:`posturemap.synth.retrieval.Retriever.search`), against the exhaustive search
  (every start frame of the library with every warp):
  ``upm`` (the map's inverted index, then the best frames at natural speed),
  ``faiss-flat`` (exact k nearest neighbours of the seam features, ``faiss.IndexFlatL2``) and
  ``faiss-hnsw`` (approximate, ``faiss.IndexHNSWFlat``, M = 32). Recall@1 is the share of
  queries whose best segment is the exhaustive search's; the cost ratio is the best cost found
  over the exhaustive best (1 = as good). Times are for the search of both body parts.

Goal (issue "Transitions that move like real people"): one 30-frame retrieval transition at
most 1 ms in-process; at 10x the library at most 2x that time.

Usage::

    python bench/retrieval_speed.py [--quick] [--data DIR] [--json PATH] [--doc PATH] [--seed S]
"""

from __future__ import annotations

import argparse
import copy
import datetime
import gc
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from transition_speed import _draws, _stats, default_data_dir, machine, save_outputs  # noqa: E402

LENGTH = 30
COPIES = 10
JITTER_DEG = 1.0
METHODS = (("retrieval", True), ("upm-valid", True), ("slerp", False))
GOAL_MS = 1.0


def jittered(motion, rng, degrees: float):
    """A copy of ``motion`` with every local rotation turned by a small random rotation."""
    from posturemap.core import quat
    from posturemap.core.motion import Motion

    axis = rng.normal(size=motion.rotations.shape[:-1] + (3,))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = np.radians(degrees) * rng.normal(size=motion.rotations.shape[:-1])
    rots = quat.mul(motion.rotations, quat.from_axis_angle(axis, angle))
    return Motion(motion.skeleton, rots, motion.positions.copy(), motion.fps)


def time_methods(engines: dict, names, lengths, calls, rng) -> dict:
    """Median/p99 (us) of ``engine.generate`` per engine (``{label: engine}``) and method,
    interleaved call by call (the order rotated from call to call), so that every engine and
    method meets the same phases of a shared machine: ``{label: {method: stats}}``."""
    draws = _draws(rng, lengths, calls + 20)
    runs = [(label, engine, m, feet) for label, engine in engines.items() for m, feet in METHODS]
    for a, b, a_end, b_start, alpha in draws[:20]:  # warm-up
        for _, engine, m, feet in runs:
            engine.generate(names[a], names[b], length=LENGTH, alpha=alpha, a_end=a_end, b_start=b_start,
                            method=m, foot_lock=feet)
    times = {(label, m): [] for label, _, m, _ in runs}
    gc.collect()
    for i, (a, b, a_end, b_start, alpha) in enumerate(draws[20:]):
        k = i % len(runs)
        for label, engine, m, feet in runs[k:] + runs[:k]:
            t0 = time.perf_counter_ns()
            engine.generate(names[a], names[b], length=LENGTH, alpha=alpha, a_end=a_end, b_start=b_start,
                            method=m, foot_lock=feet)
            times[label, m].append(time.perf_counter_ns() - t0)
    return {label: {m: _stats(times[label, m]) for m, _ in METHODS} for label in engines}


def time_inbetween(engine, names, lengths, calls, rng) -> dict:
    """Median/p99 (us) of one ``LENGTH``-frame gap inside a clip (``align=False``): the default as it
    runs, with the library only, and SLERP, interleaved call by call as :func:`time_methods`."""
    default = engine.own_seconds
    runs = (("default", "auto", True, default), ("default, library only", "auto", True, 0.0),
            ("slerp", "slerp", False, default))
    long = [i for i, n in enumerate(lengths) if n >= 3 * LENGTH]
    draws = []
    for _ in range(calls + 20):
        c = long[int(rng.integers(len(long)))]
        a_end = int(rng.integers(1, lengths[c] - LENGTH - 2))
        draws.append((names[c], a_end, float(rng.random())))
    times = {label: [] for label, *_ in runs}
    for i, (name, a_end, alpha) in enumerate(draws):
        k = i % len(runs)
        for label, m, feet, seconds in runs[k:] + runs[:k]:
            engine.own_seconds = seconds
            t0 = time.perf_counter_ns()
            engine.generate(name, name, length=LENGTH, alpha=alpha, a_end=a_end, b_start=a_end + LENGTH + 1,
                            align=False, method=m, foot_lock=feet)
            if i >= 20:  # the first 20: warm-up
                times[label].append(time.perf_counter_ns() - t0)
    engine.own_seconds = default
    return {label: _stats(t) for label, t in times.items()}


def seam_queries(rt, engine, names, lengths, count, rng):
    """Seeded cross-clip queries: (qa, qb, xa, xb, d, fps, alpha) for the search."""
    out = []
    for a, b, a_end, b_start, alpha in _draws(rng, lengths, count):
        ta, tb = engine.tracks[names[a]], engine.tracks[names[b]]
        a_end = max(a_end, 1)
        b_start = min(b_start, len(tb.gpos) - 2)
        qa = rt.seams(ta, [a_end - 1, a_end], 1)
        qb = rt.seams(tb, [b_start, b_start + 1], 0)
        out.append((qa, qb, ta.features[a_end], tb.features[b_start], LENGTH + 1.0, ta.motion.fps, alpha))
    return out


def compare_indexes(rt, queries, log=None) -> dict:
    """Recall@1, cost ratio and search time of each index against the exhaustive search."""
    import faiss

    faiss.omp_set_num_threads(1)
    lib = rt.lib
    mats = rt.matrices
    nxt = np.minimum(np.arange(len(lib)) + 1, lib.clip_end - 1)
    knn = {}
    for name in ("faiss-flat", "faiss-hnsw"):
        per_part = []
        for pm, vm in mats:
            pair = []
            for v in (vm, vm[nxt]):  # starts: velocity at the frame; ends: towards the next
                x = np.ascontiguousarray(np.concatenate([pm, v], axis=1), dtype=np.float32)
                index = faiss.IndexFlatL2(x.shape[1]) if name == "faiss-flat" else faiss.IndexHNSWFlat(x.shape[1], 32)
                index.add(x)
                pair.append(index)
            per_part.append(pair)
        knn[name] = per_part

    def best(part, q, qa, qb, xa, xb, d, fps, alpha, how):
        if how == "exhaustive":
            return rt.search(part, qa, qb, None, None, d, fps, alpha, None, 1, exhaustive=True)
        if how == "upm":
            return rt.search(part, qa, qb, rt.gather(xa, part), rt.gather(xb, part), d, fps, alpha, None, 1)
        frames = []
        for index, seam in zip(knn[how][part], (qa, qb)):
            p, v = rt.query_vectors(part, seam)
            _, idx = index.search(np.concatenate([p, v])[None], rt.keep)
            frames.append(idx[0][idx[0] >= 0].astype(np.int64))
        return rt.search(part, qa, qb, frames[0], frames[1], d, fps, alpha, None, 1)

    out = {}
    ref = None
    for how in ("exhaustive", "upm", "faiss-flat", "faiss-hnsw"):
        times, found = [], []
        for qa, qb, xa, xb, d, fps, alpha in queries:
            t0 = time.perf_counter_ns()
            res = [best(p, None, qa, qb, xa, xb, d, fps, alpha, how) for p in (0, 1)]
            times.append(time.perf_counter_ns() - t0)
            found.append([(int(r[0][0]), int(r[1][0]), float(r[2][0])) for r in res])
        if how == "exhaustive":
            ref = found
        hits = [f[p][:2] == r[p][:2] for f, r in zip(found, ref) for p in (0, 1)]
        ratio = [f[p][2] / max(r[p][2], 1e-12) for f, r in zip(found, ref) for p in (0, 1)]
        out[how] = {**_stats(times), "recall_at_1": float(np.mean(hits)), "cost_ratio_mean": float(np.mean(ratio)),
                    "cost_ratio_p90": float(np.percentile(ratio, 90))}
        if log:
            log(f"  index {how}: median {out[how]['median_us']:.0f} us, recall@1 {out[how]['recall_at_1']:.2f}, "
                f"cost ratio {out[how]['cost_ratio_mean']:.3f}")
    return out


def run(data_dir, quick: bool = False, seed: int = 0, log=print) -> dict:
    """Every measurement above; returns a JSON-ready dict."""
    from posturemap.io import bvh
    from posturemap.synth.library import build_library
    from posturemap.learn.model import PostureMap
    from posturemap.synth.retrieval import Retriever
    from posturemap.synth.engine import TransitionEngine

    files = sorted((Path(data_dir) / "bandai1").glob("*.bvh"))
    if quick:
        files = files[::6]
    clips = [bvh.read(f) for f in files]
    names = [f.stem for f in files]
    lengths = [len(m) for m in clips]
    t0 = time.perf_counter()
    model = PostureMap(seed=seed).fit(clips, names)
    fit_s = time.perf_counter() - t0
    lib = model.library_
    log(f"library: {len(lib)} frames of {lib.num_clips} clips, {lib.nbytes_per_frame():.0f} bytes per frame "
        f"(map and library fitted in {fit_s:.1f} s)")
    engine = TransitionEngine(model)
    for n, m in zip(names, clips):
        engine.add(n, m)
    calls = 100 if quick else 1000

    # Ten jittered copies of every clip, indexed through the same map (a copy of the model that
    # holds them as its library: the two engines are timed side by side).
    jrng = np.random.default_rng(seed + 1)
    copies = [jittered(m, jrng, JITTER_DEG) for _ in range(COPIES) for m in clips]
    t0 = time.perf_counter()
    builder = TransitionEngine(model)
    tracks = [builder.add(str(i), m) for i, m in enumerate(copies)]
    model_big = copy.copy(model)
    model_big.library_ = build_library(tracks, model, [f"{n} copy {k}" for k in range(COPIES) for n in names])
    big = model_big.library_
    build_s = time.perf_counter() - t0
    del tracks, builder
    engine_big = TransitionEngine(model_big)
    for n, m in zip(names, clips):
        engine_big.add(n, m)
    timed = time_methods({"1x": engine, "10x": engine_big}, names, lengths, calls, np.random.default_rng(seed))
    latency, latency_big = timed["1x"], timed["10x"]
    for m, s in latency.items():
        log(f"  {m}: median {s['median_us']:.0f} us, p99 {s['p99_us']:.0f} us")
    log(f"  10x library ({len(big)} frames, built in {build_s:.1f} s): retrieval median "
        f"{latency_big['retrieval']['median_us']:.0f} us")

    inbetween = time_inbetween(engine, names, lengths, calls, np.random.default_rng(seed + 3))
    for m, s in inbetween.items():
        log(f"  in-betweening, {m}: median {s['median_us']:.0f} us, p99 {s['p99_us']:.0f} us")

    rt = Retriever(engine, lib)
    queries = seam_queries(rt, engine, names, lengths, 40 if quick else 200, np.random.default_rng(seed + 2))
    indexes = compare_indexes(rt, queries, log)
    return {
        "date": datetime.date.today().isoformat(), "machine": machine(), "quick": quick, "seed": seed,
        "clips": len(clips), "library_frames": len(lib), "bytes_per_frame": lib.nbytes_per_frame(),
        "length": LENGTH, "calls": calls, "latency": latency,
        "library_10x": {"frames": len(big), "copies": COPIES, "jitter_deg": JITTER_DEG, "latency": latency_big,
                        "ratio": latency_big["retrieval"]["median_us"] / latency["retrieval"]["median_us"]},
        "inbetween": inbetween,
        "index": {"queries": len(queries), "results": indexes},
    }


def markdown(result: dict, command: str | None = None) -> str:
    """The result as Markdown tables."""
    lat, big = result["latency"], result["library_10x"]
    base = lat["slerp"]["median_us"]
    lines = [
        f"Library: {result['library_frames']} frames of {result['clips']} Bandai clips, "
        f"{result['bytes_per_frame']:.0f} bytes per frame. One {result['length']}-frame transition between "
        f"two different clips, {result['calls']} seeded calls per method and library, all interleaved.",
        "",
        "| method | median | p99 | median / SLERP | 10x library median | 10x p99 | 10x / 1x |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for m, s in lat.items():
        b = big["latency"][m]
        lines.append(f"| {m}{' + foot lock' if m != 'slerp' else ''} | {s['median_us'] / 1e3:.2f} ms | "
                     f"{s['p99_us'] / 1e3:.2f} ms | {s['median_us'] / base:.1f}x | {b['median_us'] / 1e3:.2f} ms | "
                     f"{b['p99_us'] / 1e3:.2f} ms | {b['median_us'] / s['median_us']:.2f}x |")
    lines += ["", f"The 10x library: {big['frames']} frames ({big['copies']} copies of every clip, rotations "
              f"jittered by about {big['jitter_deg']:g} degree).", ""]
    if "inbetween" in result:
        inb = result["inbetween"]
        lines += [f"In-betweening: one {result['length']}-frame gap inside a clip (B kept where it is), "
                  f"{result['calls']} seeded calls each, interleaved:", "",
                  "| method | median | p99 | median / SLERP |", "| --- | ---: | ---: | ---: |"]
        note = {"default": " (the clips' own motion searched too)"}
        for m, s in inb.items():
            lines.append(f"| {m}{note.get(m, '')} | "
                         f"{s['median_us'] / 1e3:.2f} ms | {s['p99_us'] / 1e3:.2f} ms | "
                         f"{s['median_us'] / inb['slerp']['median_us']:.1f}x |")
        lines.append("")
    lines += [f"Index against the exhaustive search ({result['index']['queries']} cross-clip queries, both body "
              "parts; the same exact re-rank after each):", "",
              "| index | search median | p99 | recall@1 | best cost / exhaustive (mean) | p90 |",
              "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for how, s in result["index"]["results"].items():
        lines.append(f"| {how} | {s['median_us'] / 1e3:.2f} ms | {s['p99_us'] / 1e3:.2f} ms | "
                     f"{s['recall_at_1']:.2f} | {s['cost_ratio_mean']:.3f} | {s['cost_ratio_p90']:.3f} |")
    m = result["machine"]
    lines += ["", f"Machine: {m['cpu']}, {m['cpus']} CPUs, Python {m['python']}, numpy {m['numpy']}"
              + (f"; `{command}`" if command else "") + f" ({result['date']})."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--data", default=None)
    p.add_argument("--json", default=None)
    p.add_argument("--doc", default=None)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    try:  # the index comparison needs faiss: say so before minutes of measuring, not after
        import faiss  # noqa: F401
    except ImportError:
        p.error("faiss is not installed: pip install -e '.[bench]' (faiss-cpu, for the index comparison)")
    result = run(Path(args.data) if args.data else default_data_dir(), args.quick, args.seed)
    md = markdown(result, "python bench/retrieval_speed.py" + (" --quick" if args.quick else ""))
    print(md)
    save_outputs(result, md, args.json, args.doc, "Retrieval speed", __doc__)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
