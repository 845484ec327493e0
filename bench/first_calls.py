"""The first transitions of a fresh process: what ``TransitionEngine.warm_up`` buys a game loop.

A game or a tool loads its map and clips, then transitions from the first frame on. Each run
here is a fresh interpreter (``subprocess``) that loads a map of every bandai1 clip (with its
motion library), prepares every clip in a :class:`posturemap.synth.engine.TransitionEngine`,
prepares it one of three ways, then times 120 default transitions (``auto`` + foot lock,
30 frames, seeded draws of two different clips, seams and alpha; the same draws in every run):

- ``numpy``: nothing more (the engine runs the numpy kernels, as ``import posturemap`` leaves
  them);
- ``compiled()``: ``kernels.compiled()`` (numba's kernels from its disk cache; each loads on
  its first call);
- ``warm_up()``: ``engine.warm_up()``.

Reported per way, the median over the runs (interleaved round by round, after one untimed round
that fills the disk caches): the preparation's time, the first call, the slowest and the sum of
the first 10 calls, and the median and p99 of calls 21-120 (pooled over the runs).

Usage::

    python bench/first_calls.py [--data DIR] [--map MAP] [--rounds 5] [--json PATH] [--doc PATH] [--seed S]
"""

from __future__ import annotations

import datetime
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from transition_speed import default_data_dir, machine, machine_line, report_parser, save_outputs  # noqa: E402

MODES = ("numpy", "compiled()", "warm_up()")
CALLS = 120
LENGTH = 30
STEADY = 20  # calls before the steady state

_CHILD = """
import json, sys, time
from pathlib import Path
import numpy as np
sys.path.insert(0, {bench!r})
from transition_speed import _draws
from posturemap.core import kernels
from posturemap.io import bvh
from posturemap.learn.model import PostureMap
from posturemap.synth.engine import TransitionEngine
mode, map_path, data, seed = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
files = sorted(Path(data, "bandai1").glob("*.bvh"))
names = [f.stem for f in files]
engine = TransitionEngine(PostureMap.load(map_path))
for n, f in zip(names, files):
    engine.add(n, bvh.read(f))
t0 = time.perf_counter_ns()
if mode == "compiled()":
    kernels.compiled()
elif mode == "warm_up()":
    engine.warm_up()
prep = time.perf_counter_ns() - t0
ns = []
lengths = [len(engine.tracks[n].gpos) for n in names]
for a, b, a_end, b_start, alpha in _draws(np.random.default_rng(seed), lengths, {calls}):
    t0 = time.perf_counter_ns()
    engine.generate(names[a], names[b], length={length}, alpha=alpha, a_end=a_end, b_start=b_start)
    ns.append(time.perf_counter_ns() - t0)
print(json.dumps({{"backend": kernels.backend(), "prep_ns": prep, "ns": ns}}))
"""


def child(mode: str, map_path: str, data: Path, seed: int) -> dict:
    code = _CHILD.format(bench=str(Path(__file__).resolve().parent), calls=CALLS, length=LENGTH)
    proc = subprocess.run([sys.executable, "-c", code, mode, map_path, str(data), str(seed)], capture_output=True,
                          text=True, timeout=900)
    if proc.returncode != 0:
        raise RuntimeError(f"{mode}: {proc.stderr.strip().splitlines()[-1:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run(data: Path, map_path: str | None, rounds: int, seed: int, log=print) -> dict:
    from posturemap.core import kernels
    from posturemap.io import bvh
    from posturemap.learn.model import PostureMap

    with tempfile.TemporaryDirectory() as tmp:
        if map_path is None:
            kernels.compiled()
            files = sorted(Path(data, "bandai1").glob("*.bvh"))
            log(f"training a map of {len(files)} clips")
            map_path = str(Path(tmp) / "bandai1.npz")
            PostureMap(seed=seed).fit([bvh.read(f) for f in files], [f.stem for f in files]).save(map_path)
        for mode in MODES:  # untimed: fills numba's and the OS's caches
            child(mode, map_path, data, seed)
        runs = {m: [] for m in MODES}
        for r in range(rounds):
            for mode in MODES:
                runs[mode].append(child(mode, map_path, data, seed))
            log(f"round {r + 1}/{rounds}")
    out = {"date": datetime.date.today().isoformat(), "machine": machine(), "rounds": rounds, "calls": CALLS,
           "length": LENGTH, "modes": {}}
    for mode, rs in runs.items():
        ms = [np.asarray(r["ns"], dtype=float) / 1e6 for r in rs]
        steady = np.concatenate([m[STEADY:] for m in ms])
        out["modes"][mode] = {
            "backend": rs[0]["backend"],
            "prep_ms": float(np.median([r["prep_ns"] / 1e6 for r in rs])),
            "first_ms": float(np.median([m[0] for m in ms])),
            "first10_max_ms": float(np.median([m[:10].max() for m in ms])),
            "first10_sum_ms": float(np.median([m[:10].sum() for m in ms])),
            "steady_median_ms": float(np.median(steady)),
            "steady_p99_ms": float(np.percentile(steady, 99)),
        }
    return out


def markdown(result: dict, command: str) -> str:
    rows = ["| preparation | kernels | preparation ms | first call ms | first 10 calls: slowest / sum ms | "
            f"calls {STEADY + 1}-{result['calls']}: median / p99 ms |",
            "|---|---|---:|---:|---:|---:|"]
    for mode, r in result["modes"].items():
        rows.append(f"| `{mode}` | {r['backend']} | {r['prep_ms']:.0f} | {r['first_ms']:.1f} | "
                    f"{r['first10_max_ms']:.1f} / {r['first10_sum_ms']:.0f} | "
                    f"{r['steady_median_ms']:.2f} / {r['steady_p99_ms']:.2f} |")
    return (f"{result['rounds']} fresh processes per way, {result['calls']} default transitions of "
            f"{result['length']} frames each.\n\n" + "\n".join(rows) + "\n\n" + machine_line(result, command) + "\n")


def main(argv=None) -> int:
    p = report_parser(__doc__.split("\n")[0])
    p.add_argument("--map", default=None, help="a map of bandai1 with its library (default: trained here)")
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args(argv)
    data = Path(args.data) if args.data else default_data_dir()
    result = run(data, args.map, args.rounds, args.seed)
    md = markdown(result, f"python bench/first_calls.py --rounds {args.rounds} --seed {args.seed}")
    print(md)
    save_outputs(result, md, args.json, args.doc, "First calls", __doc__)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
