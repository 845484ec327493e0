"""Start-up cost of the command line: wall time of fresh processes, side by side in one run.

Every command runs in a fresh interpreter (``subprocess``, output discarded), the commands
interleaved round by round (so load on a shared machine hits all alike) after one untimed round
that fills the on-disk caches. Reported: median, p90 and max wall time per command and the
ratio of its median to the median of ``python -c pass`` measured in the same run (the floor of
any Python command on this machine), plus ``python -c "import numpy"`` (the floor of any command
that touches an array).

Commands (``python -m posturemap.cli`` is what the ``posturemap`` script runs):

- ``--help`` and ``--version``;
- ``transition A B -o OUT --map MAP --length 30`` with A, B = Bandai ``walk_normal_001`` and
  ``run_normal_001`` and a map of all bandai1 clips (``--map``, or trained once here with the
  defaults), written as ``.bvh`` and as ``.glb``;
- with ``--baseline SRC``: the same ``--help`` and ``.bvh`` transition with another checkout's
  ``src`` folder first on ``PYTHONPATH`` (e.g. the commit before numba became lazy).

Goals (issue "Fit where animators and engine developers work"): ``--help`` within 0.2 s and the
30-frame transition within 0.35 s, on the 2-core machine.

Usage::

    python bench/startup.py [--data DIR] [--map MAP] [--rounds 15] [--baseline SRC] [--json PATH] [--doc PATH]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GOALS_S = {"posturemap --help": 0.2, "posturemap transition -> .bvh": 0.35}
PAIR = ("walk_normal_001", "run_normal_001")
LENGTH = 30


def default_data_dir() -> Path:
    """``$POSTUREMAP_DATA`` or ``../shared/data`` next to the repository."""
    env = os.environ.get("POSTUREMAP_DATA")
    return Path(env) if env else Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def wall(cmd: list[str], env: dict | None = None) -> float:
    """Seconds from start to exit of ``cmd`` (must exit 0)."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    elapsed = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr.decode()[-500:]}")
    return elapsed


def commands(data: Path, map_path: Path, out: Path, baseline: Path | None) -> dict[str, tuple[list[str], dict | None]]:
    py = sys.executable
    a, b = (str(data / "bandai1" / f"dataset-1_{n}.bvh") for n in PAIR)
    cli = [py, "-m", "posturemap.cli"]
    trans = ["transition", a, b, "--map", str(map_path), "--length", str(LENGTH), "-o"]
    cmds = {
        "python -c pass": ([py, "-c", "pass"], None),
        "python -c 'import numpy'": ([py, "-c", "import numpy"], None),
        "posturemap --help": (cli + ["--help"], None),
        "posturemap --version": (cli + ["--version"], None),
        "posturemap transition -> .bvh": (cli + trans + [str(out / "t.bvh")], None),
        "posturemap transition -> .glb": (cli + trans + [str(out / "t.glb")], None),
    }
    if baseline is not None:
        env = dict(os.environ, PYTHONPATH=str(baseline))
        cmds["baseline --help"] = (cli + ["--help"], env)
        cmds["baseline transition -> .bvh"] = (cli + trans + [str(out / "base.bvh")], env)
    return cmds


def run(data: Path, map_path: Path | None, rounds: int, baseline: Path | None, log=print) -> dict:
    with tempfile.TemporaryDirectory(prefix="posturemap-startup-") as tmp:
        tmp = Path(tmp)
        if map_path is None:
            map_path = tmp / "bandai1.npz"
            log(f"training a map of {data / 'bandai1'} (defaults) ...")
            subprocess.run([sys.executable, "-m", "posturemap.cli", "train", str(data / "bandai1"), "-o",
                            str(map_path)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        cmds = commands(data, map_path, tmp, baseline)
        for cmd, env in cmds.values():  # untimed: caches, page cache
            wall(cmd, env)
        times: dict[str, list[float]] = {name: [] for name in cmds}
        names = list(cmds)
        for r in range(rounds):
            k = r % len(names)
            for name in names[k:] + names[:k]:
                times[name].append(wall(*cmds[name]))
    ref = statistics.median(times["python -c pass"])
    rows = {}
    for name, xs in times.items():
        xs = sorted(xs)
        med = statistics.median(xs)
        p90 = xs[min(len(xs) - 1, int(round(0.9 * (len(xs) - 1))))]
        goal = GOALS_S.get(name)
        rows[name] = {"median_s": med, "p90_s": p90, "max_s": xs[-1], "ratio_to_python": med / ref,
                      "goal_s": goal, "meets_goal": None if goal is None else med <= goal, "runs": len(xs)}
    return {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                        "system": f"{platform.system()} {platform.release()}"},
            "rounds": rounds, "length": LENGTH, "pair": PAIR, "rows": rows,
            "baseline": str(baseline) if baseline else None}


def markdown(result: dict) -> str:
    lines = ["| command | median | p90 | max | median / `python -c pass` | goal |",
             "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for name, r in result["rows"].items():
        goal = "" if r["goal_s"] is None else f"{r['goal_s']:.2f} s {'met' if r['meets_goal'] else 'MISSED'}"
        lines.append(f"| `{name}` | {r['median_s'] * 1e3:.0f} ms | {r['p90_s'] * 1e3:.0f} ms | "
                     f"{r['max_s'] * 1e3:.0f} ms | {r['ratio_to_python']:.1f}x | {goal} |")
    m = result["machine"]
    lines.append("")
    lines.append(f"{result['rounds']} rounds of fresh processes, interleaved; {m['cpus']} CPUs, Python "
                 f"{m['python']}, {m['system']}; {result['date']}. Transition: Bandai {result['pair'][0]} -> "
                 f"{result['pair'][1]}, {result['length']} frames, map of all bandai1 clips.")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=default_data_dir(), help="data folder holding bandai1/")
    p.add_argument("--map", type=Path, default=None, help="map of bandai1 (default: train one, about 6 s)")
    p.add_argument("--rounds", type=int, default=15, help="timed runs per command (15)")
    p.add_argument("--baseline", type=Path, default=None, help="another checkout's src/ to compare with")
    p.add_argument("--json", type=Path, default=None, help="also write the results as JSON")
    p.add_argument("--doc", type=Path, default=None,
                   help="write the Markdown table into this file (between its table markers, if any)")
    args = p.parse_args(argv)
    if not (args.data / "bandai1").is_dir():
        sys.stderr.write(f"startup.py: error: {args.data / 'bandai1'}: no such folder (set --data or POSTUREMAP_DATA)\n")
        return 2
    result = run(args.data, args.map, args.rounds, args.baseline, log=lambda s: sys.stderr.write(s + "\n"))
    table = markdown(result)
    print(table)
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    if args.doc:
        begin, end = "<!-- startup table -->\n", "<!-- /startup table -->"
        text = args.doc.read_text(encoding="utf-8") if args.doc.is_file() else ""
        if begin in text and end in text:  # keep the prose around the table
            text = text[: text.index(begin) + len(begin)] + table + text[text.index(end):]
        else:
            text = begin + table + end + "\n"
        args.doc.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
