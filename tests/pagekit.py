"""Run a three.js module page in headless Chromium over a fake origin, for the loader tests."""

from __future__ import annotations

import time
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
VENDOR = Path(__file__).resolve().parent.parent / "src" / "posturemap" / "web" / "static" / "vendor"


def vendored() -> dict[str, bytes]:
    """The vendored three.js modules, by the path the pages import them from (``/vendor/...``)."""
    return {"/vendor/" + str(p.relative_to(VENDOR)): p.read_bytes() for p in VENDOR.rglob("*.js")}


def page_results(origin: str, served: dict[str, bytes], what: str, timeout: float = 60.0):
    """Open ``origin + "/"`` with every request answered from ``served`` (path -> bytes, 404
    otherwise), wait for the page's ``window.__results`` and return it; fails on a page error,
    a console error or after ``timeout`` seconds (``what`` names the loader in the message)."""
    from playwright.sync_api import sync_playwright

    def serve(route):
        path = route.request.url.removeprefix(origin).split("?")[0]
        body = served.get(path)
        if body is None:
            return route.fulfill(status=404, body="not found")
        kind = "text/html" if path == "/" else "text/javascript" if path.endswith(".js") else "application/octet-stream"
        route.fulfill(status=200, body=body, content_type=kind)

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page()
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.on("console", lambda m: m.type == "error" and errors.append(m.text))
        page.route(f"{origin}/**", serve)
        page.goto(origin + "/")
        deadline = time.monotonic() + timeout
        while not page.evaluate("!!window.__results") and not errors:
            assert time.monotonic() < deadline, f"{what} did not finish"
            time.sleep(0.05)
        results = page.evaluate("window.__results")
        browser.close()
    assert errors == [], errors
    return results
