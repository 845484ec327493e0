"""Load benchmark of the studio server: 1, 8 and 32 concurrent clients for 60 s each (issue 12).

Starts ``posturemap serve`` (the procedural sample clips with a saved map, as
``bench/server_fuzz.py`` does) twice, side by side in the same run: with the engine pool
(:data:`posturemap.web.studio.POOL_SIZE` engines, the default) and with one engine
(``POSTUREMAP_ENGINES=1``: every transition waits for the one before, as the former global
lock did). Each client keeps one connection open and posts seeded random transitions
(``upm``, ``spline``, ``auto``; random clips, lengths, alpha) back to back. Reports per setting
the throughput (requests per second), latency p50 and p99 (ms) and errors (non-200
answers), and the p50 ratio to the single-client p50.

    python bench/load.py --seconds 60 --doc docs/server-load.md
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import platform
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import server_fuzz  # noqa: E402

CLIENTS = (1, 8, 32)
METHODS = ("upm", "spline", "auto")


def _client(server, seed: int, stop: float, out: list, errors: list):
    rng = np.random.default_rng(seed)
    conn = http.client.HTTPConnection(server.host, server.port, timeout=60)
    while time.perf_counter() < stop:
        a, b = (str(x) for x in rng.choice(server_fuzz.CLIPS, 2))
        body = json.dumps({"a": a, "b": b, "length": int(rng.integers(5, 40)), "alpha": float(rng.random()),
                           "method": str(rng.choice(METHODS))})
        t0 = time.perf_counter()
        try:
            conn.request("POST", "/api/transition", body, {"Content-Type": "application/json"})
            resp = conn.getresponse()
            resp.read()
            status = resp.status
        except (OSError, http.client.HTTPException):
            status = 0
            conn.close()
            conn = http.client.HTTPConnection(server.host, server.port, timeout=60)
        t1 = time.perf_counter()
        if t1 <= stop:
            out.append(t1 - t0)
            if status != 200:
                errors.append(status)
    conn.close()


def measure(server, clients: int, seconds: float, seed: int) -> dict:
    latencies: list[float] = []
    errors: list[int] = []
    stop = time.perf_counter() + seconds
    threads = [threading.Thread(target=_client, args=(server, seed * 1000 + k, stop, latencies, errors))
               for k in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    lat = np.array(latencies) * 1000
    return {"clients": clients, "requests": len(lat), "throughput_rps": round(len(lat) / seconds, 1),
            "p50_ms": round(float(np.percentile(lat, 50)), 2), "p99_ms": round(float(np.percentile(lat, 99)), 2),
            "errors": len(errors)}


def run(seconds: float, seed: int) -> dict:
    results = {}
    for label, engines in (("pool", None), ("one engine", "1")):
        env_before = os.environ.get("POSTUREMAP_ENGINES")
        if engines:
            os.environ["POSTUREMAP_ENGINES"] = engines
        try:
            with tempfile.TemporaryDirectory(prefix="posturemap-load-") as tmp, server_fuzz.Server(Path(tmp)) as server:
                for _ in range(50):  # warm up (compiled kernels, caches)
                    server_fuzz.json_post(server, "/api/transition", {"a": "walk", "b": "run"})
                rows = [measure(server, c, seconds, seed) for c in CLIENTS]
                problems = server.problems()
        finally:
            if env_before is None:
                os.environ.pop("POSTUREMAP_ENGINES", None)
            else:
                os.environ["POSTUREMAP_ENGINES"] = env_before
        base = rows[0]["p50_ms"]
        for r in rows:
            r["p50_ratio"] = round(r["p50_ms"] / base, 2)
        results[label] = {"rows": rows, "log_problems": problems[:3]}
    return results


def markdown(results: dict, seconds: float) -> str:
    from posturemap.web.studio import POOL_SIZE

    lines = ["# Studio server under load", "",
             f"`python bench/load.py --seconds {seconds:g}`: `posturemap serve` on the procedural sample clips",
             "(3 clips, 21 joints) with a saved map; each client keeps one connection and posts random",
             "transitions (`upm`, `spline`, `auto`; lengths 5-39) back to back for "
             f"{seconds:g} s per row. Machine: {os.cpu_count()} cores, Python {platform.python_version()}, "
             "**shared with other engineers' test runs** while measured, so absolute figures are noisy; "
             "both settings ran in the same run, one after the other.", "",
             f"`pool`: {POOL_SIZE} engines (the default); `one engine`: `POSTUREMAP_ENGINES=1`, every transition "
             "waits for the previous one (the former global lock).", "",
             "| setting | clients | requests | throughput (req/s) | p50 (ms) | p99 (ms) | p50 / 1-client p50 | errors |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for label, res in results.items():
        for r in res["rows"]:
            lines.append(f"| {label} | {r['clients']} | {r['requests']} | {r['throughput_rps']} | {r['p50_ms']} | "
                         f"{r['p99_ms']} | {r['p50_ratio']} | {r['errors']} |")
    lines += ["", "Log problems (tracebacks, internal errors): "
              + ("none" if not any(r["log_problems"] for r in results.values()) else "see JSON"), ""]
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--doc", default=None, help="write a Markdown table here (e.g. docs/server-load.md)")
    args = ap.parse_args()
    results = run(args.seconds, args.seed)
    print(json.dumps(results))
    if args.doc:
        Path(args.doc).write_text(markdown(results, args.seconds))


if __name__ == "__main__":
    main()
