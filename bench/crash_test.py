"""Crash test: ``kill -9`` the CLI at random points while it makes and writes a transition.

Each round starts ``posturemap transition walk.bvh run.bvh -o out.bvh`` over an existing
``out.bvh`` (the *old* file, a different transition) and kills it with SIGKILL after a
seeded random delay drawn over the run's measured duration, weighted towards its end where
the write happens. Afterwards ``out.bvh`` must be byte for byte either the old file or the
new complete one (never partial). A killed process cannot clean up, so a ``.tmp-*`` file may
remain after a kill that hit the write; those are counted and removed. Then two normal errors
(a corrupt map, an unreadable clip) must leave no temporary file at all.

    python bench/crash_test.py --kills 200 --seed 0

Prints one JSON line: kills, how many left the old or the new file, partial files (must be
0), temp files left by kills and by normal errors (must be 0).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from posturemap.io import bvh
from posturemap import sample
from posturemap.io.fileio import TEMP_PREFIX


def _cmd(folder: Path, length: int, *extra) -> list[str]:
    return [sys.executable, "-m", "posturemap.cli", "transition", str(folder / "walk.bvh"),
            str(folder / "run.bvh"), "-o", str(folder / "out.bvh"), "--method", "spline",
            "--length", str(length), *extra]


def _temps(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if p.name.startswith(TEMP_PREFIX)]


def run(folder: Path, kills: int = 20, seed: int = 0) -> dict:
    """Run the crash test in ``folder``; returns the counts (see the module docstring)."""
    folder = Path(folder)
    clips = sample.clips()
    for name in ("walk", "run"):
        bvh.write(folder / f"{name}.bvh", clips[name])
    out = folder / "out.bvh"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    subprocess.run(_cmd(folder, 5), check=True, capture_output=True, env=env)
    old = out.read_bytes()
    t0 = time.perf_counter()
    subprocess.run(_cmd(folder, 20), check=True, capture_output=True, env=env)
    duration = time.perf_counter() - t0
    new = out.read_bytes()
    assert new != old
    rng = np.random.default_rng(seed)
    counts = {"kills": 0, "old": 0, "new": 0, "partial": 0, "kill_temps": 0}
    for _ in range(kills):
        out.write_bytes(old)
        delay = duration * (0.3 + 0.8 * float(rng.beta(3, 1)))  # mostly late: where the write is
        proc = subprocess.Popen(_cmd(folder, 20), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        counts["kills"] += 1
        data = out.read_bytes()
        counts["old" if data == old else "new" if data == new else "partial"] += 1
        left = _temps(folder)
        counts["kill_temps"] += len(left)
        for p in left:
            p.unlink()
    # Normal errors: nothing left behind.
    (folder / "bad.npz").write_bytes(b"PK\x03\x04 not a map")
    (folder / "bad.bvh").write_text("HIERARCHY\nROOT r\n{\n")
    subprocess.run(_cmd(folder, 20, "--map", str(folder / "bad.npz")), capture_output=True, env=env)
    subprocess.run([sys.executable, "-m", "posturemap.cli", "transition", str(folder / "bad.bvh"),
                    str(folder / "run.bvh"), "-o", str(folder / "out.bvh")], capture_output=True, env=env)
    counts["error_temps"] = len(_temps(folder))
    counts["run_seconds"] = round(duration, 3)
    return counts


def main():
    import tempfile

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="posturemap-crash-") as tmp:
        print(json.dumps(run(Path(tmp), args.kills, args.seed)))


if __name__ == "__main__":
    main()
