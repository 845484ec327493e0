"""Studio slider latency: from the alpha slider's input event to the new pose on screen.

``posturemap serve <data>/bandai1`` runs in its own process, as a user starts it (all 174 clips,
the posture map learnt in the background). The system's Chromium (headless, driven by
Playwright) opens the page at 1440x900 and waits for the map. Then the alpha slider moves, one
move at a time (each waits until the page has shown the previous one), in two ways:

- **drag**: the mouse holds the thumb and moves 4 px per step (about two slider steps), as an
  animator drags it; the browser delivers such moves with the animation frames;
- **keys**: arrow keys on the focused slider, one step per press.

The page measures every update itself (``window.__studio.latencies``): ``performance.now()``
from the slider's ``input`` event to the first task after the ``requestAnimationFrame`` that
follows the draw, i.e. once the browser has painted the new pose; ``window.__studio.timings``
splits it into steps.

The default view: clip A walk_normal_001 to clip B run_normal_001, method upm-valid with the
spline comparison overlaid, key ghost on, 20 in-between frames. Both render profiles, each way of
moving: 5 warm-up moves, then ``--moves`` measured ones:

- **lite**: what the page picks for software WebGL (no antialiasing, no shadow maps);
- **full**: ``?render=full``, what it picks with a GPU (antialiasing, shadow maps), forced here.

Goal (issue "Interactive transition studio"): a slider move updates the transition within
50 ms on localhost, median over 50 moves.

Usage::

    python bench/studio_latency.py [--moves 50] [--data DIR] [--json PATH] [--doc PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

GOAL_MS = 50.0
WARMUP = 5
DRAG_PX = 4        # mouse step of a drag: about two slider steps (alpha 0..1 by 0.01 over ~235 px)
PROTOCOLS = {"drag": "mouse drag of the thumb", "keys": "arrow keys"}
CONFIGS = (("lite", "drag"), ("lite", "keys"), ("full", "drag"), ("full", "keys"))
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
REPO = Path(__file__).resolve().parent.parent
STEPS = (  # (label, from, to) over window.__studio.timings
    ("request (server, network, JSON)", "sent", "received"),
    ("result assembled, three.js clips built", "received", "applied"),
    ("wait for the next animation frame", "applied", "frame"),
    ("pose drawn (render call)", "frame", "rendered"),
    ("timeline, plot and text drawn", "rendered", "drawn"),
    ("frame painted (rasterise, composite)", "drawn", "painted"),
)


def default_data_dir() -> Path:
    """``$POSTUREMAP_DATA`` or ``../shared/data`` next to the repository."""
    env = os.environ.get("POSTUREMAP_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


class Server:
    """``posturemap serve FOLDER --port 0`` in a subprocess; ``url`` once it listens."""

    def __init__(self, folder: Path, log):
        exe = Path(sys.executable).with_name("posturemap")
        cmd = [str(exe)] if exe.exists() else [sys.executable, "-c", "from posturemap.cli import main; main()"]
        self.proc = subprocess.Popen(cmd + ["serve", str(folder), "--port", "0"], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, bufsize=1)
        self.url = None
        found = threading.Event()

        def read():
            for line in self.proc.stdout:
                log("  serve: " + line.rstrip())
                m = re.search(r"open (http://\S+?)/? ", line)
                if m:
                    self.url = m.group(1)
                    found.set()
            found.set()

        threading.Thread(target=read, daemon=True).start()
        found.wait(120)
        if self.url is None:
            self.close()
            raise SystemExit("posturemap serve did not start (see its output above)")

    def close(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def _moves(page, protocol: str, count: int):
    """Yield after each slider move that changed alpha (the caller waits for its update)."""
    if protocol == "keys":
        page.focus("#alpha")
        for i in range(count):
            page.keyboard.press("ArrowRight" if (i // 10) % 2 == 0 else "ArrowLeft")
            yield
        return
    box = page.locator("#alpha").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2   # the thumb, at alpha 0.5
    page.mouse.move(x, y)
    page.mouse.down()
    done = i = 0
    while done < count:
        x += DRAG_PX if (i // 10) % 2 == 0 else -DRAG_PX
        i += 1
        before = page.evaluate("document.getElementById('alpha').value")
        page.mouse.move(x, y)
        if page.evaluate("document.getElementById('alpha').value") != before:
            done += 1
            yield
    page.mouse.up()


def measure(browser, url: str, profile: str, protocol: str, moves: int) -> dict:
    """Latencies (ms) and step medians of ``moves`` alpha-slider moves."""
    context = browser.new_context(viewport={"width": 1440, "height": 900})
    page = context.new_page()
    errors = []
    page.on("console", lambda m: m.type == "error" and errors.append(m.text))
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url + ("/?render=full" if profile == "full" else "/"))
    deadline = time.monotonic() + 300
    while not page.evaluate("window.__studio && window.__studio.state === 'ready'"):
        if time.monotonic() > deadline:
            raise SystemExit(f"the studio did not get ready: {errors}")
        time.sleep(0.1)
    page.wait_for_timeout(1000)  # the settled full-resolution redraw
    start = page.evaluate("__studio.latencies.length")
    for k, _ in enumerate(_moves(page, protocol, WARMUP + moves), 1):
        page.evaluate(f"Promise.race([__studio.latencyCount({start + k}), new Promise((_, no) => "
                      "setTimeout(() => no(new Error('no update within 10 s')), 10000))])")
    begin = start + WARMUP
    lat = page.evaluate(f"__studio.latencies.slice({begin})")
    timings = page.evaluate(f"__studio.timings.slice({begin})")
    info = page.evaluate("({profile: __studio.profile, result: __studio.result, compare: __studio.compare})")
    context.close()
    if errors:
        raise SystemExit(f"the page reported errors: {errors}")
    steps = {label: statistics.median(t[b] - t[a] for t in timings) for label, a, b in STEPS}
    lat_sorted = sorted(lat)
    return {"profile": info["profile"], "protocol": protocol, "moves": len(lat),
            "median_ms": statistics.median(lat), "p90_ms": lat_sorted[int(0.9 * (len(lat) - 1))],
            "min_ms": lat_sorted[0], "max_ms": lat_sorted[-1], "steps_ms": steps, "latencies_ms": lat,
            "method": info["result"]["method"], "compare": info["compare"], "frames": info["result"]["frames"]}


def run(data: Path, moves: int, log) -> dict:
    from playwright.sync_api import sync_playwright

    folder = data / "bandai1"
    if not folder.is_dir():
        raise SystemExit(f"{folder}: not found (set POSTUREMAP_DATA or --data)")
    if not os.path.exists(CHROMIUM):
        raise SystemExit(f"{CHROMIUM}: not found (apt-get install chromium)")
    server = Server(folder, log)
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            results = {}
            for profile, protocol in CONFIGS:
                log(f"measuring: {profile} profile, {PROTOCOLS[protocol]}, {WARMUP} + {moves} moves")
                results[f"{profile}, {protocol}"] = measure(browser, server.url, profile, protocol, moves)
            version = browser.version
            browser.close()
    finally:
        server.close()
    return {"date": time.strftime("%Y-%m-%d"), "goal_ms": GOAL_MS, "moves": moves, "chromium": version,
            "cpus": os.cpu_count(), "machine": platform.machine(), "load": round(os.getloadavg()[0], 2),
            "clips": len(list(folder.glob("*.bvh"))), "profiles": results}


def markdown(result: dict, command: str) -> str:
    rows = ["| render profile, moves | median | p90 | min | max | median / goal |",
            "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for name, r in result["profiles"].items():
        rows.append(f"| {name} | {r['median_ms']:.1f} ms | {r['p90_ms']:.1f} ms | {r['min_ms']:.1f} ms | "
                    f"{r['max_ms']:.1f} ms | {r['median_ms'] / result['goal_ms']:.2f} |")
    names = list(result["profiles"])
    steps = ["| step | " + " | ".join(names) + " |", "| --- |" + " ---: |" * len(names)]
    for label, _, _ in STEPS:
        steps.append(f"| {label} | " + " | ".join(f"{r['steps_ms'][label]:.1f}" for r in result["profiles"].values())
                     + " |")
    first = next(iter(result["profiles"].values()))
    return "\n".join([
        f"Alpha slider input to the new pose painted, {result['moves']} moves each "
        f"(goal: median under {result['goal_ms']:.0f} ms).", "", *rows, "",
        "Median of each step (ms):", "", *steps, "",
        f"Setup: `posturemap serve` on Bandai-Namco dataset 1 ({result['clips']} clips) in its own process and "
        f"headless Chromium {result['chromium']} with software WebGL (SwiftShader; this machine has no GPU), "
        f"page 1440x900, on one machine ({result['cpus']} cores, {result['machine']}, load average "
        f"{result['load']} at the end). Default view: {first['method']} with the {first['compare']} comparison "
        f"overlaid, {first['frames']} frames in all, 20 in-between. On its own the page picked the "
        f"`{first['profile']}` profile; `full` was forced with `?render=full`.",
        "", f"Command: `{command}` ({result['date']}).",
    ]) + "\n"


def write_doc(path: Path, result: dict, command: str) -> None:
    requests = [r["steps_ms"][STEPS[0][0]] for r in result["profiles"].values()]
    lo, hi = min(requests), max(requests)
    paint = {k: r["steps_ms"][STEPS[-1][0]] for k, r in result["profiles"].items()}
    extra = paint["full, drag"] - paint["lite, drag"]
    text = ("# Studio slider latency\n\n"
            "Measured by `bench/studio_latency.py` (its docstring describes the method).\n\n"
            + markdown(result, command) + "\n"
            f"Where the time goes: the request ({lo:.0f} to {hi:.0f} ms: the server computes the 20 new frames "
            "(the default method: retrieval, a few milliseconds) and sends only those; HTTP and JSON in the browser take the rest), then "
            "the browser's frame pipeline: the update waits for the next animation frame, and one more "
            "frame passes before it is on screen. A drag's mouse moves arrive with the animation frames, "
            "so the answer is back before the next frame starts; a key press arrives mid-frame and its "
            "update often waits for the frame after. The scene itself draws in about a millisecond of "
            "script. The `full` rows show what antialiasing and shadow maps cost a software rasteriser "
            f"(about {extra:.0f} ms more to paint a frame); the page uses them only when the browser has a GPU (not measured "
            "here: this machine has none).\n\n"
            "Re-measure with `make studio-docs`.\n")
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--moves", type=int, default=50, help="measured slider moves per configuration (50)")
    p.add_argument("--data", default=None, help="data folder (default: $POSTUREMAP_DATA or ../shared/data)")
    p.add_argument("--json", metavar="PATH", help="also write the result as JSON")
    p.add_argument("--doc", metavar="PATH", help="Markdown file to write (e.g. docs/web-latency.md)")
    args = p.parse_args(argv)
    data = Path(args.data) if args.data else default_data_dir()
    result = run(data, args.moves, log=lambda s: print(s, file=sys.stderr))
    given = argv if argv is not None else sys.argv[1:]
    command = "python bench/studio_latency.py" + ("" if not given else " " + " ".join(given))
    print(markdown(result, command))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2), encoding="utf-8")
    if args.doc:
        write_doc(Path(args.doc), result, command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
