"""BVH loading speed: posturemap against other Python BVH readers, side by side.

File sets: every ``bandai1/*.bvh`` (174 short clips, 22 joints with 6 channels each) and
``cmu/01_01.bvh`` (one long clip, 2752 frames at 120 fps). Readers:

- ``posturemap``: ``posturemap.io.bvh.read`` (hierarchy, frames and Euler-to-quaternion).
- ``bvhio``: ``bvhio.readAsBvh``, its fastest full read (``readAsHierarchy`` does more work
  on top of it and is about ten times slower).
- ``pybvh``: ``pybvh.read_bvh_file(path, world_up="+y")``; the explicit up axis skips its
  auto-detection, which makes it a little faster than the default (both data sets are Y up).

Each run reads every file of a set once with each reader, readers interleaved file by file;
the table gives the median over ``--repeat`` runs of the set's total. Files a reader cannot
read are left out of its total and its ratio is taken against posturemap on the same files.
Before timing, one untimed pass per reader loads imports and compiled code; the ``cold``
column is a separate fresh interpreter that imports the reader and reads the set once.

Usage::

    python bench/bvh_load.py [--data DIR] [--repeat 5] [--json PATH] [--no-cold]
"""

from __future__ import annotations

import argparse
import gc
import importlib.metadata
import json
import os
import platform
import statistics
import subprocess
import sys
import time
import warnings
from pathlib import Path

GOAL_RATIO = 2.0  # the issue: posturemap at least 2x faster than the fastest other reader

_READER_CODE = {
    "posturemap": ("from posturemap.io import bvh; from posturemap.core import kernels; kernels.compiled()", "bvh.read"),
    "bvhio": ("import bvhio", "bvhio.readAsBvh"),
    "pybvh": ("import pybvh, functools; "
              "_read = functools.partial(pybvh.read_bvh_file, world_up='+y')", "_read"),
}
_DISTRIBUTIONS = {"posturemap": "posturemap", "bvhio": "bvhio", "pybvh": "pybvh"}


def default_data_dir() -> Path:
    """``$POSTUREMAP_DATA`` or ``../shared/data`` next to the repository."""
    env = os.environ.get("POSTUREMAP_DATA")
    return Path(env) if env else Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def file_sets(data_dir: Path) -> dict[str, list[Path]]:
    """The benchmark's file sets that exist under ``data_dir`` (name -> sorted files)."""
    sets = {"bandai1": sorted((data_dir / "bandai1").glob("*.bvh")),
            "cmu/01_01": [p for p in [data_dir / "cmu" / "01_01.bvh"] if p.is_file()]}
    return {name: files for name, files in sets.items() if files}


def load_readers() -> dict:
    """Reader name -> callable(path); readers that fail to import are left out."""
    readers = {}
    for name, (setup, call) in _READER_CODE.items():
        scope: dict = {}
        try:
            exec(setup, scope)  # noqa: S102 - fixed code above, not user input
        except ImportError:
            continue
        readers[name] = eval(call, scope)  # noqa: S307 - fixed code above
    return readers


def _version(name: str) -> str:
    try:
        return importlib.metadata.version(_DISTRIBUTIONS[name])
    except importlib.metadata.PackageNotFoundError:
        return "?"


def _error_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text[:200]}"


def _timed(read, path: Path) -> float:
    t0 = time.perf_counter()
    read(str(path))
    return time.perf_counter() - t0


def cold_seconds(reader: str, files: list[Path]) -> float | None:
    """Wall time in a fresh interpreter: import the reader, read every file once."""
    setup, call = _READER_CODE[reader]
    code = (f"import time, warnings, sys\nwarnings.simplefilter('ignore')\n"
            f"t0 = time.perf_counter()\n{setup}\n_f = {call}\n"
            f"for p in sys.argv[1:]:\n    try:\n        _f(p)\n    except Exception:\n        pass\n"
            f"print(time.perf_counter() - t0)")
    proc = subprocess.run([sys.executable, "-c", code, *map(str, files)],
                          capture_output=True, text=True, timeout=600)
    try:
        return float(proc.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return None


def run(data_dir, repeat: int = 5, cold: bool = True) -> dict:
    """Time every reader on every file set; returns a JSON-ready dict (see :func:`markdown`)."""
    data_dir = Path(data_dir)
    sets = file_sets(data_dir)
    if not sets:
        raise FileNotFoundError(f"no BVH file sets (bandai1/, cmu/01_01.bvh) under {data_dir}")
    readers = load_readers()
    result = {"data_dir": str(data_dir), "repeat": repeat, "goal_ratio": GOAL_RATIO,
              "python": platform.python_version(), "machine": platform.machine(),
              "cpus": os.cpu_count(),
              "readers": {name: {"version": _version(name), "api": _READER_CODE[name][1]}
                          for name in readers},
              "sets": []}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pybvh warns about up-axis guesses; not our concern
        for set_name, files in sets.items():
            result["sets"].append(_run_set(set_name, files, readers, repeat, cold))
    result["goal_met"] = all(r["meets_goal"] for s in result["sets"] for r in s["readers"]
                             if r["meets_goal"] is not None)
    return result


def _run_set(set_name: str, files: list[Path], readers: dict, repeat: int, cold: bool) -> dict:
    # Untimed pass: finds the files each reader can read, warms imports and compiled code.
    failures = {name: {} for name in readers}
    for path in files:
        for name, read in readers.items():
            try:
                read(str(path))
            except Exception as e:  # noqa: BLE001 - a foreign reader may raise anything
                failures[name][path.name] = _error_line(e)
    ok = {name: [p for p in files if p.name not in failures[name]] for name in readers}
    # per_file[name][path] = list of times over runs
    per_file = {name: {p: [] for p in ok[name]} for name in readers}
    for _ in range(repeat):
        gc.collect()
        for path in files:
            for name, read in readers.items():
                if path in per_file[name]:
                    per_file[name][path].append(_timed(read, path))

    def median_total(name, subset):
        return statistics.median(sum(per_file[name][p][r] for p in subset) for r in range(repeat))

    rows = []
    for name in readers:
        subset = ok[name]
        row = {"reader": name, "files": len(files), "files_read": len(subset),
               "median_s": median_total(name, subset) if subset else None,
               "ratio_vs_posturemap": None, "meets_goal": None,
               "cold_s": cold_seconds(name, files) if cold else None,
               "failures": failures[name], "failure_summary": _failure_summary(failures[name], len(files))}
        if subset and "posturemap" in readers and name != "posturemap":
            common = [p for p in subset if p in per_file["posturemap"]]
            if common:
                row["ratio_vs_posturemap"] = median_total(name, common) / median_total("posturemap", common)
                row["meets_goal"] = row["ratio_vs_posturemap"] >= GOAL_RATIO
        elif name == "posturemap" and subset:
            row["ratio_vs_posturemap"] = 1.0
        rows.append(row)
    return {"set": set_name, "files": len(files), "readers": rows}


def _failure_summary(failures: dict, total: int) -> str:
    if not failures:
        return ""
    first_file, first_error = next(iter(failures.items()))
    kinds = {e.split(":")[0] for e in failures.values()}
    return (f"cannot read {len(failures)} of {total} files ({', '.join(sorted(kinds))}), "
            f"e.g. {first_file}: {first_error}")


def markdown(result: dict) -> str:
    """The result as a Markdown table plus one line per reader that cannot read some files."""
    out = [f"BVH loading, median of {result['repeat']} runs "
           f"(Python {result['python']}, {result['cpus']} CPUs); ratio = reader time / posturemap "
           f"time on the same files (goal: >= {result['goal_ratio']:g} for every other reader).",
           "",
           "| file set | reader | version | files read | median s | ratio vs posturemap | cold s |",
           "|---|---|---|---|---|---|---|"]
    notes = []
    for s in result["sets"]:
        for r in s["readers"]:
            version = result["readers"][r["reader"]]["version"]
            median = f"{r['median_s']:.4f}" if r["median_s"] is not None else "-"
            ratio = f"{r['ratio_vs_posturemap']:.2f}x" if r["ratio_vs_posturemap"] is not None else "n/a"
            cold = f"{r['cold_s']:.3f}" if r["cold_s"] is not None else "-"
            out.append(f"| {s['set']} | {r['reader']} | {version} | {r['files_read']}/{r['files']} "
                       f"| {median} | {ratio} | {cold} |")
            if r["failure_summary"]:
                notes.append(f"- {r['reader']} on {s['set']}: {r['failure_summary']}")
    out.append("")
    out.extend(notes)
    out.append(f"Goal met: {'yes' if result['goal_met'] else 'NO'}")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default=None, help="data folder (default: $POSTUREMAP_DATA or ../shared/data)")
    p.add_argument("--repeat", type=int, default=5, help="timed runs per reader and set (default 5)")
    p.add_argument("--json", default=None, help="also write the result as JSON to this path")
    p.add_argument("--no-cold", action="store_true", help="skip the fresh-interpreter timings")
    args = p.parse_args(argv)
    if args.repeat < 1:
        p.error("--repeat must be at least 1")
    result = run(args.data or default_data_dir(), args.repeat, cold=not args.no_cold)
    print(markdown(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
