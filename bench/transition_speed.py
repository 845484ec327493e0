"""Transition latency: one 20-frame transition, every method side by side.

Three measurements, all on Bandai-Namco dataset 1 (``<data>/bandai1``):

- **engine**: a :class:`posturemap.synth.engine.TransitionEngine` holding a map trained on all
  clips (``PostureMap().fit``, default parameters) and every clip prepared once; one call of
  ``generate`` (key posture, spline, root alignment: the in-between frames' local rotations and
  positions) is timed with ``time.perf_counter_ns``. Clip pairs, seam frames (``a_end``,
  ``b_start``) and ``alpha`` are drawn with a seeded RNG; every method gets the same draws, the
  methods interleaved call by call (so drift hits all alike). Warm-up calls first (compiled
  kernels, spline bases, upm-path's graph: its cost is the "first call" column). The garbage
  collector stays on: the p99 includes what a game loop would see.
- **transition()**: the functional API, which builds an engine and prepares both clips per call
  and also copies the clips' frames into the output motion.
- **CLI**: wall time of ``posturemap transition A B -o OUT [--map MAP]`` in a fresh process,
  start-up included (median of 5 after one untimed run that fills the on-disk caches).

Goal (issue "Motion transitions"): ``upm`` median < 100 us and p99 < 300 us in-process; CLI
< 1 s. The paper needed about one second for 20 frames.

Usage::

    python bench/transition_speed.py [--quick] [--data DIR] [--json PATH] [--doc PATH] [--seed S]
"""

from __future__ import annotations

import argparse
import datetime
import gc
import importlib.metadata
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

LENGTH = 20
GOAL_MEDIAN_US = 100.0
GOAL_P99_US = 300.0
GOAL_CLI_S = 1.0
CLI_PAIR = ("walk_normal_001", "run_normal_001")
REPO = Path(__file__).resolve().parent.parent


def default_data_dir() -> Path:
    """``$POSTUREMAP_DATA`` or ``../shared/data`` next to the repository."""
    env = os.environ.get("POSTUREMAP_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def machine() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass

    def version(dist):
        try:
            return importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            return "?"

    return {"cpu": cpu, "cpus": os.cpu_count(), "python": platform.python_version(),
            "system": f"{platform.system()} {platform.release()}",
            "numpy": np.__version__, "numba": version("numba"), "scipy": version("scipy"),
            "posturemap": version("posturemap")}


def _stats(ns: list[int]) -> dict:
    us = np.asarray(ns, dtype=float) / 1e3
    return {"calls": len(us), "median_us": float(np.median(us)), "p99_us": float(np.percentile(us, 99)),
            "mean_us": float(us.mean()), "min_us": float(us.min()), "max_us": float(us.max())}


def _draws(rng: np.random.Generator, lengths: list[int], count: int) -> list[tuple]:
    """(a, b, a_end, b_start, alpha) per call: two different clips, seams anywhere in them."""
    out = []
    n = len(lengths)
    for _ in range(count):
        a = int(rng.integers(n))
        b = (a + int(rng.integers(1, n))) % n
        out.append((a, b, int(rng.integers(lengths[a])), int(rng.integers(lengths[b])), float(rng.random())))
    return out


def bench_engine(engine, names, lengths, methods, calls, warmup, rng, log) -> dict:
    """Median/p99 of ``engine.generate`` per method over the same seeded draws."""
    first_ms = {}
    for m in methods:  # the very first call: compiled kernels loaded, bases and graphs built
        a, b, a_end, b_start, alpha = _draws(rng, lengths, 1)[0]
        t0 = time.perf_counter_ns()
        engine.generate(names[a], names[b], length=LENGTH, alpha=alpha, a_end=a_end,
                        b_start=b_start, method=m, foot_lock=False)
        first_ms[m] = (time.perf_counter_ns() - t0) / 1e6
    for a, b, a_end, b_start, alpha in _draws(rng, lengths, warmup):
        for m in methods:
            engine.generate(names[a], names[b], length=LENGTH, alpha=alpha, a_end=a_end,
                        b_start=b_start, method=m, foot_lock=False)
    times = {m: [] for m in methods}
    cpu_times = {m: [] for m in methods}
    clock, cpu_clock = time.perf_counter_ns, time.thread_time_ns
    gc.collect()
    for i, (a, b, a_end, b_start, alpha) in enumerate(_draws(rng, lengths, calls)):
        na, nb = names[a], names[b]
        k = i % len(methods)
        for m in methods[k:] + methods[:k]:  # rotate the order: no method always runs first
            c0 = cpu_clock()
            t0 = clock()
            engine.generate(na, nb, length=LENGTH, alpha=alpha, a_end=a_end,
                        b_start=b_start, method=m, foot_lock=False)
            t1 = clock()
            cpu_times[m].append(cpu_clock() - c0)
            times[m].append(t1 - t0)
        if log and (i + 1) % max(1, calls // 4) == 0:
            log(f"  engine: {i + 1}/{calls} calls per method")
    # Back to back: one method over all the draws, as a game calling its transition method
    # (the interleaved runs above start every call with the other methods' data in the caches).
    b2b = {m: [] for m in methods}
    draws = _draws(rng, lengths, calls)
    for m in methods:
        for a, b, a_end, b_start, alpha in draws:
            t0 = clock()
            engine.generate(names[a], names[b], length=LENGTH, alpha=alpha, a_end=a_end,
                        b_start=b_start, method=m, foot_lock=False)
            b2b[m].append(clock() - t0)
    out = {}
    for m in methods:
        cpu = _stats(cpu_times[m])
        seq = _stats(b2b[m])
        out[m] = {**_stats(times[m]), "first_call_ms": first_ms[m],
                  "cpu_median_us": cpu["median_us"], "cpu_p99_us": cpu["p99_us"],
                  "b2b_median_us": seq["median_us"], "b2b_p99_us": seq["p99_us"]}
    return out


def bench_functional(model, clips, lengths, methods, calls, rng, log) -> dict:
    """Median/p99 of ``transition(A, B, model, ...)`` per method (an engine per call)."""
    from posturemap.synth.engine import transition

    out = {}
    for m in methods:
        n = calls
        draws = _draws(rng, lengths, n + 2)
        for a, b, a_end, b_start, alpha in draws[:2]:  # warm-up
            transition(clips[a], clips[b], model, length=LENGTH, alpha=alpha, a_end=a_end, b_start=b_start,
                       align=True, method=m, foot_lock=False)
        times = []
        for a, b, a_end, b_start, alpha in draws[2:]:
            t0 = time.perf_counter_ns()
            transition(clips[a], clips[b], model, length=LENGTH, alpha=alpha, a_end=a_end, b_start=b_start,
                       align=True, method=m, foot_lock=False)
            times.append(time.perf_counter_ns() - t0)
        out[m] = _stats(times)
        if log:
            log(f"  transition(): {m} {out[m]['median_us']:.0f} us median over {n} calls")
    return out


def _cli_command() -> list[str]:
    script = Path(sys.executable).parent / "posturemap"
    if script.exists():
        return [str(script)]
    found = shutil.which("posturemap")
    return [found] if found else [sys.executable, "-m", "posturemap.cli"]


def bench_cli(path_a: Path, path_b: Path, map_path: str | None, runs: int, workdir: str) -> dict:
    """Wall time (s) of the transition command in a fresh process, start-up included."""
    out = os.path.join(workdir, "cli_out.bvh")
    cmd = _cli_command() + ["transition", str(path_a), str(path_b), "-o", out]
    if map_path:
        cmd += ["--map", map_path]
    times = []
    for i in range(runs + 1):
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
        dt = time.perf_counter() - t0
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed: {proc.stderr.strip()}")
        if i > 0:  # the first run fills the on-disk caches (numba, bytecode)
            times.append(dt)
    shown = ["posturemap"] + cmd[len(_cli_command()):]
    shown = [os.path.basename(c) if c.endswith((".bvh", ".npz")) else c for c in shown]
    return {"command": " ".join(shown), "runs": runs, "median_s": statistics.median(times),
            "min_s": min(times), "max_s": max(times)}


def run(data_dir, quick: bool = False, seed: int = 0, log=print) -> dict:
    """Run the benchmark; returns a JSON-ready dict (see :func:`markdown`)."""
    from posturemap.io import bvh
    from posturemap.learn.model import PostureMap
    from posturemap.synth.engine import TransitionEngine
    from posturemap.synth.request import METHODS

    data_dir = Path(data_dir)
    files = sorted((data_dir / "bandai1").glob("*.bvh"))
    if not files:
        raise FileNotFoundError(f"no BVH files in {data_dir / 'bandai1'}")
    if quick:  # every 6th clip, plus the CLI pair
        files = sorted(set(files[::6]) | {p for p in files if any(n in p.name for n in CLI_PAIR)})
    calls, warmup, fcalls, cli_runs = (200, 20, 40, 3) if quick else (2000, 100, 200, 5)
    rng = np.random.default_rng(seed)
    log = log or (lambda *_: None)
    load_before = os.getloadavg()

    t0 = time.perf_counter()
    clips = [bvh.read(p) for p in files]
    names = [p.stem.removeprefix("dataset-1_") for p in files]
    lengths = [len(c) for c in clips]
    read_s = time.perf_counter() - t0
    log(f"read {len(clips)} clips, {sum(lengths)} frames in {read_s:.1f} s")
    t0 = time.perf_counter()
    model = PostureMap().fit(clips, names)
    fit_s = time.perf_counter() - t0
    log(f"map trained in {fit_s:.1f} s: neurons {model.neuron_counts()}")
    engine = TransitionEngine(model)
    t0 = time.perf_counter()
    for n, c in zip(names, clips):
        engine.add(n, c)
    prep_s = time.perf_counter() - t0

    methods = list(METHODS)
    engine_rows = bench_engine(engine, names, lengths, methods, calls, warmup, rng, log)
    functional_rows = bench_functional(model, clips, lengths, methods, fcalls, rng, log)
    for rows in (engine_rows, functional_rows):
        base = rows["upm"]["median_us"]
        for r in rows.values():
            r["ratio_to_upm"] = r["median_us"] / base

    with tempfile.TemporaryDirectory(prefix="posturemap-bench-") as tmp:
        map_path = os.path.join(tmp, "bandai1.npz")
        model.save(map_path)
        by_name = dict(zip(names, files))
        pa, pb = by_name[CLI_PAIR[0]], by_name[CLI_PAIR[1]]
        cli = {"with_map": bench_cli(pa, pb, map_path, cli_runs, tmp),
               "without_map": bench_cli(pa, pb, None, cli_runs, tmp)}
    log(f"CLI: {cli['with_map']['median_s']:.2f} s with --map, {cli['without_map']['median_s']:.2f} s without")

    upm = engine_rows["upm"]
    return {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "data": {"dir": str(data_dir), "clips": len(clips), "frames": int(sum(lengths)), "fps": clips[0].fps},
        "quick": quick, "seed": seed, "length": LENGTH,
        "load_average": {"before": [round(x, 2) for x in load_before],
                         "after": [round(x, 2) for x in os.getloadavg()]},
        "map": {"neurons": model.neuron_counts(), "train_s": fit_s, "read_s": read_s, "prepare_s": prep_s},
        "engine": engine_rows,
        "functional": functional_rows,
        "cli": cli,
        "goals": {"median_us": GOAL_MEDIAN_US, "p99_us": GOAL_P99_US, "cli_s": GOAL_CLI_S,
                  "upm_median_met": upm["median_us"] < GOAL_MEDIAN_US,
                  "upm_p99_met": upm["p99_us"] < GOAL_P99_US,
                  "upm_b2b_median_met": upm["b2b_median_us"] < GOAL_MEDIAN_US,
                  "upm_b2b_p99_met": upm["b2b_p99_us"] < GOAL_P99_US,
                  "cli_met": all(c["median_s"] < GOAL_CLI_S for c in cli.values())},
    }


def markdown(result: dict, command: str | None = None) -> str:
    """The result as Markdown: machine, in-process table, CLI table, goals."""
    mc, d, mp = result["machine"], result["data"], result["map"]
    eng, fun = result["engine"], result["functional"]
    load = result["load_average"]
    lines = [
        (f"One {result['length']}-frame transition, {mc['cpu']} ({mc['cpus']} cores), Python {mc['python']}, "
         f"numpy {mc['numpy']}, numba {mc['numba']}, scipy {mc['scipy']}; {result['date']}; load average "
         f"(1 min) {load['before'][0]:.2f} before, {load['after'][0]:.2f} after."),
        (f"Map trained on {d['clips']} clips of bandai1 ({d['frames']} frames) in {mp['train_s']:.1f} s; "
         f"neurons per class (body, global, medium, detail): {', '.join(map(str, mp['neurons']))}."),
        "",
        ("| method | engine median µs | engine p99 µs | × upm | engine CPU median / p99 µs "
         "| back to back median / p99 µs | first call ms "
         "| transition() median µs | transition() p99 µs | × upm |"),
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for m, r in eng.items():
        f = fun[m]
        lines.append(f"| {m} | {r['median_us']:.1f} | {r['p99_us']:.1f} | {r['ratio_to_upm']:.2f} "
                     f"| {r['cpu_median_us']:.1f} / {r['cpu_p99_us']:.1f} "
                     f"| {r['b2b_median_us']:.1f} / {r['b2b_p99_us']:.1f} | {r['first_call_ms']:.1f} "
                     f"| {f['median_us']:.0f} | {f['p99_us']:.0f} | {f['ratio_to_upm']:.2f} |")
    calls = next(iter(eng.values()))["calls"]
    fcalls = next(iter(fun.values()))["calls"]
    lines += [
        "",
        (f"Engine: {calls} calls per method (same seeded clip pairs, seams and alpha for every method), "
         "after warm-up; wall time, and the calling thread's CPU time (which leaves out time the "
         "process waited for a core: on a busy machine the wall p99 mostly measures that). "
         "\"First call\" is the very first call (kernels loaded from the cache, bases and graphs built). "
         "\"Back to back\": the same draws, one method after the other in turn, as a game that always "
         "calls its one transition method (the interleaved columns start every call with the other "
         "methods' data in the caches). "
         f"transition(): {fcalls} calls per method, an engine per call."),
        "",
        "| CLI (fresh process, start-up included) | median s | min s | max s |",
        "|---|---:|---:|---:|",
    ]
    for c in result["cli"].values():
        lines.append(f"| `{c['command']}` | {c['median_s']:.2f} | {c['min_s']:.2f} | {c['max_s']:.2f} |")
    g = result["goals"]
    up = eng["upm"]
    lines += [
        "",
        (f"Goals: upm median {up['median_us']:.1f} µs interleaved, {up['b2b_median_us']:.1f} µs back to back "
         f"< {g['median_us']:.0f} µs: {'met' if g['upm_median_met'] else 'NOT met'} interleaved, "
         f"{'met' if g['upm_b2b_median_met'] else 'NOT met'} back to back; p99 {up['p99_us']:.1f} µs < {g['p99_us']:.0f} µs: "
         f"{'met' if g['upm_p99_met'] else 'NOT met'}; CLI < {g['cli_s']:.0f} s: "
         f"{'met' if g['cli_met'] else 'NOT met'}. The paper: about 1 s for 20 frames."),
    ]
    busy = max(load["before"][0], load["after"][0])
    if busy > 0.5 * (mc["cpus"] or 1):
        lines += ["", (f"Note: the machine was busy (load average up to {busy:.1f} on {mc['cpus']} cores): "
                       "wall times include waiting for a core, most visibly the p99 and the CLI runs; the "
                       "CPU-time column is closer to what an idle machine gives.")]
    if command:
        lines += ["", f"Command: `{command}`"]
    return "\n".join(lines) + "\n"


def report_parser(description: str, data: bool = True) -> argparse.ArgumentParser:
    """The options of the quality reports (``foreign_skeleton.py``, ``other_dataset.py``):
    ``--data`` (unless ``data`` is False: a report on clips of its own, ``clip_pairs.py``),
    ``--json``, ``--doc`` and ``--seed``; a script adds its own."""
    p = argparse.ArgumentParser(description=description)
    if data:
        p.add_argument("--data", default=None, help="data folder holding bandai1/ (default: $POSTUREMAP_DATA or "
                                                    "../shared/data)")
    p.add_argument("--json", default=None, metavar="PATH", help="also write the result as JSON")
    p.add_argument("--doc", default=None, metavar="PATH", help="Markdown file to write")
    p.add_argument("--seed", type=int, default=0, help="random seed (0)")
    return p


def report_main(doc: str, title: str, command: str, run, markdown, argv=None) -> int:
    """The ``main`` of a quality report that takes :func:`report_parser`'s options only: ``run(data,
    seed)``, then ``markdown(result, command)`` printed and saved (:func:`save_outputs`)."""
    args = report_parser(doc.split("\n")[0]).parse_args(argv)
    result = run(Path(args.data) if args.data else default_data_dir(), args.seed)
    md = markdown(result, command)
    print(md)
    save_outputs(result, md, args.json, args.doc, title, doc)
    return 0


def machine_line(result: dict, command: str) -> str:
    """The report's last line: the machine (``result["machine"]``, :func:`machine`), the command
    and the date."""
    m = result["machine"]
    return f"Machine: {m['cpu']}, {m['cpus']} CPUs, Python {m['python']}; `{command}` ({result['date']})."


def write_text(path, text: str) -> None:
    """``text`` into ``path``, whole or not at all: a temporary file beside it, flushed to disk,
    then renamed over it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def save_outputs(result: dict, md: str, json_path, doc_path, title: str, doc: str) -> None:
    """A bench script's ``--json`` (the result) and ``--doc`` (``# title``, the script's docstring up
    to its usage, then the report ``md``), each when asked for."""
    if json_path:
        write_text(json_path, json.dumps(result, indent=1) + "\n")
    if doc_path:
        write_text(doc_path, f"# {title}\n\n" + doc.split("\n\n", 1)[1].split("Usage::")[0] + md)


def write_doc(path: Path, result: dict, command: str) -> None:
    write_text(path, "# Transition speed\n\n"
               "Latency of one transition (`bench/transition_speed.py`; the method is described in its "
               "docstring).\n\n" + markdown(result, command))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer clips and calls (about 30 s)")
    p.add_argument("--data", default=None, help="data folder (default: $POSTUREMAP_DATA or ../shared/data)")
    p.add_argument("--json", metavar="PATH", help="also write the result as JSON")
    p.add_argument("--doc", metavar="PATH", default=None,
                   help="Markdown file to write (default: docs/transition-benchmarks.md for a full run, "
                        "none for --quick)")
    p.add_argument("--seed", type=int, default=0, help="random seed (0)")
    args = p.parse_args(argv)
    data = Path(args.data) if args.data else default_data_dir()
    result = run(data, quick=args.quick, seed=args.seed, log=lambda s: print(s, file=sys.stderr))
    command = "python bench/transition_speed.py" + (" " + " ".join(argv if argv is not None else sys.argv[1:])
                                                    if (argv if argv is not None else sys.argv[1:]) else "")
    print(markdown(result, command))
    if args.json:
        write_text(args.json, json.dumps(result, indent=2))
    doc = args.doc or (None if args.quick else str(REPO / "docs" / "transition-benchmarks.md"))
    if doc:
        write_doc(Path(doc), result, command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
