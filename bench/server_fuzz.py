"""Hostile and random requests against a running ``posturemap serve`` (issue 12).

Starts the real command (``posturemap serve`` on the procedural sample clips with a saved map,
port 0) in a subprocess, then sends:

- the malformed requests of the issue (a 309-digit ``alpha``, a client that disconnects
  mid-body, headers trickled byte by byte, cross-origin POSTs and GETs, a form POST, a huge
  header block, a bad request line);
- ``n`` seeded random requests: random methods, paths, query strings, JSON bodies with
  random fields and values (huge integers, NaN spellings, nesting, wrong types), random bytes,
  random content types and Origins.

Every answer must be below 500, and the server's log must hold no traceback and no
"internal error". ``python bench/server_fuzz.py --requests 10000 --seed 0`` prints one JSON
line with the counts; the tests run a few hundred (tests/test_server_hardening.py).
"""

from __future__ import annotations

import argparse
import http.client
import json
import re
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np

CLIPS = ("walk", "run", "wave")
FIELDS = ("a", "b", "a_end", "b_start", "length", "key_at", "alpha", "method", "align", "foot_lock")
VALUES = [None, True, False, 0, -1, 1, 2, 5, 89, 90, 2 ** 31, 2 ** 64, -2 ** 63, 10 ** 308, int("9" * 309),
          0.5, -0.0, 1e-300, 1e308, 3.7, "", "walk", "run", "wave", "upm", "spline", "auto", "retrieval",
          "x" * 300, "\u0000", "\ud7ff", [], [1], {}, {"a": 1}, "../..", "%2e%2e", "NaN", "1e400",
          [[[[[]]]]], "walk\u202e"]
PATHS = ["/", "/api/status", "/api/clips", "/api/clip/walk", "/api/clip/nope", "/api/clip/..%2f..%2fetc",
         "/api/transition", "/api/export", "/static/app.js", "/static/../../etc/passwd", "/static/%00",
         "/api/nothing", "//api//export", "/api/clip/" + "x" * 500]
ORIGINS = [None] * 12 + ["http://evil.example", "null", "http://127.0.0.1:1", "https://attacker.test"]
CTYPES = ["application/json", "application/json", "application/json; charset=utf-8", "text/plain",
          "application/x-www-form-urlencoded", "multipart/form-data; boundary=x", None, "application/JSON"]


# -- the server ------------------------------------------------------------------------------
class Server:
    """``posturemap serve`` in a subprocess: ``base`` URL, ``host:port``, and its stderr log lines."""

    def __init__(self, folder: Path):
        from posturemap.io import bvh
        from posturemap import sample
        from posturemap.learn.model import PostureMap

        folder = Path(folder)
        clips = sample.clips()
        for name in CLIPS:
            bvh.write(folder / f"{name}.bvh", clips[name])
        map_path = folder / "map.npz"
        PostureMap(seed=0).fit([clips[n] for n in CLIPS], list(CLIPS)).save(str(map_path))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "posturemap.cli", "serve", *(str(folder / f"{n}.bvh") for n in CLIPS),
             "--map", str(map_path), "--port", "0"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.log: list[str] = []
        threading.Thread(target=self._collect, daemon=True).start()
        deadline = time.monotonic() + 120
        port = None
        while port is None and time.monotonic() < deadline:
            line = self.proc.stdout.readline()
            if not line and self.proc.poll() is not None:
                raise RuntimeError("posturemap serve ended: " + "\n".join(self.log))
            m = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
            port = int(m.group(1)) if m else None
        self.host, self.port = "127.0.0.1", port
        self.base = f"http://127.0.0.1:{port}"

    def _collect(self):
        for line in self.proc.stderr:
            self.log.append(line.rstrip("\n"))

    def problems(self) -> list[str]:
        """Log lines that show a traceback or an internal error."""
        return [line for line in self.log if "Traceback" in line or "internal error" in line
                or "Exception" in line]

    def close(self):
        self.proc.terminate()
        try:
            self.proc.wait(20)
        finally:
            self.proc.stdout.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def request(server: Server, method: str, path: str, body: bytes | None = None, headers: dict | None = None,
            timeout: float = 30.0) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection(server.host, server.port, timeout=timeout)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        resp = conn.getresponse()
        return resp.status, resp.read()
    finally:
        conn.close()


def json_post(server, path, obj, **headers):
    return request(server, "POST", path, json.dumps(obj).encode(),
                   {"Content-Type": "application/json", **headers})


# -- malformed requests of the issue -----------------------------------------------------------
def malformed(server: Server) -> dict[str, int]:
    """Each named malformed request and its status (a socket-level case: 0 when closed quietly)."""
    huge = "9" * 309
    body = ('{"a": "walk", "b": "run", "alpha": ' + huge + "}").encode()
    out = {
        "alpha_309_digits_transition": request(server, "POST", "/api/transition", body,
                                               {"Content-Type": "application/json"})[0],
        "alpha_309_digits_export": request(server, "POST", "/api/export", body,
                                           {"Content-Type": "application/json"})[0],
        "alpha_309_digits_export_get": request(server, "GET", f"/api/export?a=walk&b=run&alpha={huge}")[0],
        "cross_origin_post": json_post(server, "/api/transition", {"a": "walk", "b": "run"},
                                       Origin="http://evil.example")[0],
        "cross_origin_export_get": request(server, "GET", "/api/export?a=walk&b=run",
                                           headers={"Origin": "http://evil.example"})[0],
        "cross_site_no_origin_export": request(server, "GET", "/api/export?a=walk&b=run",
                                               headers={"Sec-Fetch-Site": "cross-site"})[0],
        "form_post": request(server, "POST", "/api/transition", b"a=walk&b=run",
                             {"Content-Type": "application/x-www-form-urlencoded"})[0],
        "text_plain_post": request(server, "POST", "/api/export", b'{"a": "walk", "b": "run"}',
                                   {"Content-Type": "text/plain"})[0],
        "huge_header": request(server, "GET", "/api/status", headers={"X-Pad": "x" * 40000})[0],
    }
    out["disconnect_mid_body"] = _disconnect_mid_body(server)
    out["bad_request_line"] = _raw(server, b"GARBAGE\r\n\r\n")
    return out


def _raw(server: Server, data: bytes) -> int:
    with socket.create_connection((server.host, server.port), timeout=10) as s:
        s.sendall(data)
        reply = s.recv(4096)
    m = re.match(rb"HTTP/1\.[01] (\d{3})", reply)
    return int(m.group(1)) if m else 0


def _disconnect_mid_body(server: Server) -> int:
    s = socket.create_connection((server.host, server.port), timeout=10)
    s.sendall(b"POST /api/transition HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
              b"Content-Length: 1000\r\n\r\n{\"a\": \"wa")
    time.sleep(0.2)
    s.close()
    time.sleep(0.2)
    return 0


def trickle_does_not_block(server: Server, seconds: float = 3.0) -> dict:
    """A client trickles a request's headers a byte at a time; others must still be served.

    Returns the other clients' latencies and whether the trickler was cut off (closed by the
    server before it finished; only when ``seconds`` exceeds the header timeout).
    """
    s = socket.create_connection((server.host, server.port), timeout=30)
    stop = threading.Event()
    closed = []

    def trickle():
        data = b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 10000
        try:
            for b in data:
                if stop.is_set():
                    return
                s.send(bytes([b]))
                time.sleep(0.05)
        except OSError:
            closed.append(True)

    t = threading.Thread(target=trickle, daemon=True)
    t.start()
    latencies = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t0 = time.perf_counter()
        status, _ = json_post(server, "/api/transition", {"a": "walk", "b": "run", "method": "spline"})
        latencies.append((time.perf_counter() - t0, status))
    stop.set()
    t.join(5)
    s.close()
    return {"latencies": latencies, "trickler_closed": bool(closed)}


# -- random requests ---------------------------------------------------------------------------
def random_request(rng: np.random.Generator) -> tuple[str, str, bytes | None, dict]:
    """One seeded random request: (method, path, body, headers)."""
    kind = int(rng.integers(0, 5))
    headers = {}
    origin = ORIGINS[int(rng.integers(len(ORIGINS)))]
    if origin:
        headers["Origin"] = origin
    if kind <= 1:  # JSON body with random fields and values
        body_obj = {str(rng.choice(FIELDS + ("", "__proto__", "pad"))): VALUES[int(rng.integers(len(VALUES)))]
                    for _ in range(int(rng.integers(0, 8)))}
        if rng.random() < 0.7:
            body_obj.update(a=str(rng.choice(CLIPS)), b=str(rng.choice(CLIPS)))
        if rng.random() < 0.1:
            body_obj = [body_obj] if rng.random() < 0.5 else VALUES[int(rng.integers(len(VALUES)))]
        body = json.dumps(body_obj).encode()
        ctype = CTYPES[int(rng.integers(len(CTYPES)))]
        if ctype:
            headers["Content-Type"] = ctype
        return "POST", str(rng.choice(["/api/transition", "/api/export"])), body, headers
    if kind == 2:  # random bytes as JSON
        body = rng.bytes(int(rng.integers(0, 400)))
        headers["Content-Type"] = "application/json"
        return "POST", str(rng.choice(["/api/transition", "/api/export"])), body, headers
    if kind == 3:  # export query strings
        vals = ["1", "-5", "x", "0.5", "walk", "run", "", "%00", "1e9", "9" * 309, "nan", "inf", "true", "1" * 20]
        q = "&".join(f"{rng.choice(FIELDS + ('zz',))}={rng.choice(vals)}" for _ in range(int(rng.integers(0, 7))))
        return "GET", f"/api/export?{q}", None, headers
    method = str(rng.choice(["GET", "HEAD", "POST", "PUT", "DELETE", "OPTIONS", "PATCH"]))
    body = rng.bytes(int(rng.integers(0, 50))) if method in ("POST", "PUT", "PATCH") else None
    return method, str(rng.choice(PATHS)), body, headers


def fuzz(server: Server, n: int, seed: int = 0) -> dict:
    """``n`` seeded random requests; returns status counts, 5xx answers and log problems."""
    rng = np.random.default_rng(seed)
    statuses = Counter()
    server_errors = []
    for i in range(n):
        method, path, body, headers = random_request(rng)
        try:
            status, _ = request(server, method, path, body, headers)
        except (OSError, http.client.HTTPException) as e:
            status = f"connection error {type(e).__name__}"
        statuses[status] += 1
        if not isinstance(status, int) or status >= 500:
            server_errors.append((i, method, path[:80], status))
    return {"requests": n, "statuses": dict(sorted((str(k), v) for k, v in statuses.items())),
            "5xx_or_errors": len(server_errors), "first_errors": server_errors[:5],
            "log_problems": server.problems()[:5]}


def main():
    import tempfile

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--requests", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="posturemap-serverfuzz-") as tmp, Server(Path(tmp)) as server:
        t0 = time.perf_counter()
        result = {"malformed": malformed(server)}
        result.update(fuzz(server, args.requests, args.seed))
        trickle = trickle_does_not_block(server, 12.0)
        lat = [t for t, _ in trickle["latencies"]]
        result["trickle"] = {"others_served": len(lat), "others_p50_ms": round(1000 * float(np.median(lat)), 2),
                             "others_max_ms": round(1000 * max(lat), 2),
                             "trickler_closed_by_server": trickle["trickler_closed"]}
        result["seconds"] = round(time.perf_counter() - t0, 1)
        result["log_problems"] = server.problems()[:5]
    print(json.dumps(result))


if __name__ == "__main__":
    main()
