"""The studio page in a real browser: headless Chromium (the system's /usr/bin/chromium) driven by
Playwright, against the real server (uvicorn in a thread) serving real Bandai clips.

Skipped, with the reason, only when /usr/bin/chromium is missing (CI installs it) or the Bandai
data is absent. ``POSTUREMAP_UPDATE_DOCS=1`` (``make studio-docs``) also writes the screenshot to
docs/studio.png. The latency figures come from bench/studio_latency.py.
"""

from __future__ import annotations

import http.client
import io
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np
import pytest

from posturemap.core import quat
from posturemap.io import bvh
from posturemap.learn.model import PostureMap
from posturemap.synth.request import DEFAULT_METHOD, KEYED
from posturemap.web.server import create_app, running
from posturemap.web.studio import LOOPBACK_HOSTS
from rigkit import under_node

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
CLIPS = ("walk_normal_001", "run_normal_001", "bow_normal_001", "bye_normal_001")
DOCS = Path(__file__).resolve().parent.parent / "docs"
UPDATE_DOCS = os.environ.get("POSTUREMAP_UPDATE_DOCS") == "1"
MOVES = 50

if not os.path.exists(CHROMIUM):
    pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium; .ci/run does)",
                allow_module_level=True)

from playwright.sync_api import sync_playwright


# -- fixtures -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def clips(bandai_paths):
    return {n: bvh.read(p) for n, p in bandai_paths(CLIPS).items()}


@pytest.fixture(scope="module")
def base_url(clips):
    """The real server on a free localhost port, with a small map trained here."""
    # bow first: the map takes its root joint from its first clip (its up axis from most frames), and
    # posturemap.core.motion reads walk_normal_001 as Z-up (it walks far from the origin, where Bandai's
    # joint_Root stays) and run_normal_001's root as joint_Root (which carries its trajectory).
    order = ["bow_normal_001"] + [n for n in clips if n != "bow_normal_001"]
    model = PostureMap(seed=0).fit([clips[n] for n in order], order)
    assert model.space_.up == 1 and model.skeleton_.names[model.space_.root] == "Hips"
    with running(create_app(clips, model, allowed_hosts=LOOPBACK_HOSTS)) as url:
        yield url


@pytest.fixture(scope="module")
def browser():
    with sync_playwright() as p:
        # Playwright gives each launch a fresh temporary profile (its own --user-data-dir).
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


class Page:
    """A fresh page on the studio that records console errors and page exceptions."""

    def __init__(self, browser, url, query="", **ctx):
        self.context = browser.new_context(viewport={"width": 1440, "height": 900}, accept_downloads=True, **ctx)
        self.page = self.context.new_page()
        self.errors: list[str] = []
        self.page.on("console", lambda m: m.type == "error" and self.errors.append(m.text))
        self.page.on("pageerror", lambda e: self.errors.append(f"pageerror: {e}"))
        self.browser_version = browser.version
        self.page.goto(url + "/" + query)
        self.wait("window.__studio && window.__studio.state === 'ready'", 60)

    def js(self, expr):
        return self.page.evaluate(expr)

    def wait(self, expr, timeout=20.0):
        """Poll a JS expression (the page's CSP forbids Playwright's eval-based wait_for_function)."""
        deadline = time.monotonic() + timeout
        while True:
            value = self.page.evaluate(expr)
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out waiting for {expr}; errors: {self.errors}")
            time.sleep(0.02)

    def wait_requests_settled(self):
        """Wait until the shown result reflects the current controls."""
        self.wait("(() => { const s = __studio, p = s.params, v = (id) => document.getElementById(id);"
                  " return p && p.a === v('clip-a').value && p.b === v('clip-b').value"
                  " && p.alpha === Number(v('alpha').value) && p.method === v('method').value"
                  " && p.length === Number(v('length').value) && p.key_at === Number(v('key-at').value)"
                  " && p.a_end === Number(v('a-end').value) && p.b_start === Number(v('b-start').value); })()")

    def choose(self, a, b, **ranges):
        """Pick clips A and B, then set range inputs by id (``a_end=60`` sets ``#a-end``), in
        order, as a user would; waits until the shown result reflects them."""
        self.page.select_option("#clip-a", a)
        self.page.select_option("#clip-b", b)
        for name, value in ranges.items():
            set_range(self, "#" + name.replace("_", "-"), value)
        self.wait_requests_settled()

    def close(self):
        self.context.close()


@pytest.fixture
def studio(browser, base_url):
    p = Page(browser, base_url)
    yield p
    p.close()


def set_range(page, sel, value):
    """Set a range input as a user would (value, then an input event)."""
    page.js(f"(() => {{ const e = document.querySelector('{sel}'); e.value = '{value}';"
            " e.dispatchEvent(new Event('input', {bubbles: true})); })()")


def canvas_stats(png: bytes):
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).reshape(-1, 3)
    colors = len(np.unique(img, axis=0))
    background = np.array([13, 17, 23])
    far = np.abs(img.astype(int) - background).sum(axis=1) > 40
    return colors, float(far.mean())


# -- tests --------------------------------------------------------------------------------------------
def test_page_loads_without_console_errors_and_draws(studio, clips):
    s = studio.js("({state: __studio.state, frames: __studio.frameCount, result: __studio.result,"
                  " renders: __studio.renders, clips: [...document.querySelectorAll('#clip-a option')].map(o => o.value)})")
    assert s["state"] == "ready" and s["renders"] > 0
    assert s["clips"] == list(CLIPS)
    # --disable-gpu: software WebGL (SwiftShader), which the page detects and draws lighter.
    assert studio.js("__studio.profile") == "lite"
    a, b = s["result"]["a"], s["result"]["b"]
    assert (a, b) == ("walk_normal_001", "run_normal_001")
    assert s["frames"] == len(clips[a]) + 20 + len(clips[b])
    studio.page.wait_for_timeout(300)
    colors, covered = canvas_stats(studio.page.locator("#view").screenshot())
    assert colors > 500, f"3D view looks blank: {colors} colours"
    assert covered > 0.05, f"3D view looks blank: {covered:.1%} of pixels differ from the background"
    # Scrub bar: a click at the middle moves the playhead there; play advances it, pause stops it.
    box = studio.page.locator("#timeline").bounding_box()
    studio.page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    middle = studio.wait(f"Math.abs(__studio.frame - {(s['frames'] - 1) / 2}) <= 3 && __studio.frame")
    studio.page.click("#play")
    studio.wait(f"__studio.frame !== {middle}")
    studio.page.click("#play")
    assert studio.js("__studio.frame") != middle
    assert studio.errors == []


def test_picking_clips_and_alpha_change_the_key_posture(studio, clips):
    # Mid-clip seams: both clips start and end standing still, where every alpha gives one key.
    # With the foot lock on (it may move the legs at the key's frame), the ghost shows the key.
    studio.page.select_option("#method", "upm-valid")
    assert studio.page.is_checked("#foot-lock")
    studio.choose("bow_normal_001", "bye_normal_001", a_end=60, b_start=40)
    s = studio.js("__studio.result")
    assert (s["a"], s["b"]) == ("bow_normal_001", "bye_normal_001")
    assert studio.js("__studio.frameCount") == 61 + 20 + len(clips["bye_normal_001"]) - 40
    keys, shown = {}, {}
    for alpha in ("0.05", "0.95"):
        set_range(studio, "#alpha", alpha)
        studio.wait_requests_settled()
        studio.wait("__studio.latencies.length > 0 && __studio.renders > 0")
        keys[alpha] = np.array(studio.js("__studio.keyPosture.quaternions"))
        shown[alpha] = np.array(studio.js("__studio.displayedKey()"))
        assert studio.js("__studio.keyPosture.frame") == studio.js("__studio.result.key_frame")
    assert keys["0.05"].shape == keys["0.95"].shape and keys["0.05"].shape[1] == 4
    assert np.abs(keys["0.05"] - keys["0.95"]).max() > 1e-2, "alpha did not change the key posture"
    assert np.abs(shown["0.05"] - shown["0.95"]).max() > 1e-2, "the ghost skeleton did not move"
    # The ghost shows the key: its bones carry the key's rotations (joints below the root).
    bones = studio.js("__studio.keyPosture.bones")
    names = studio.js("[...document.querySelectorAll('#plot-joint option')].map(o => o.textContent)")
    for bone, q in list(zip(bones, keys["0.95"]))[1:]:
        got = shown["0.95"][names.index(bone)]
        assert abs(float(np.dot(got, q))) == pytest.approx(1.0, abs=1e-3), bone
    assert studio.errors == []


def test_export_downloads_the_shown_result(studio, clips):
    page = studio.page
    studio.choose("run_normal_001", "walk_normal_001", a_end=15, b_start=30, length=24)
    expected = 16 + 24 + len(clips["walk_normal_001"]) - 30
    assert studio.js("__studio.frameCount") == expected
    with page.expect_download() as info:
        page.click("#export")
    download = info.value
    assert download.suggested_filename == f"run_normal_001_to_walk_normal_001_{DEFAULT_METHOD}.bvh"
    m = bvh.loads(Path(download.path()).read_bytes())
    assert len(m) == expected
    assert m.skeleton.same_as(clips["run_normal_001"].skeleton)
    # The page puts the result together from the clips' frames, the new frames and B's alignment;
    # what it draws is what the file holds (every joint, the reference node above Hips too).
    exported = m.global_positions()
    for f in (0, 15, 16, 27, 39, 40, 41, expected - 1):
        drawn = np.array(studio.js(f"__studio.jointPositions({f})"))
        assert np.abs(drawn - exported[f]).max() < 0.05, f"frame {f}"
    assert studio.errors == []


def test_the_page_draws_b_placed_under_a_turned_node_as_the_export_holds_it(browser, clips):
    # joint_Root held a quarter turn about X and off the origin (a Z-up file's conversion node),
    # Hips carrying the motion, but in run_normal_001, whose joint_Root moves (root motion): the
    # page applies the placement the server names, on Hips or on joint_Root, as the export does.
    node = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.array(-np.pi / 2)), np.array([30.0, 5.0, -20.0])
    held = {n: (m if n == "run_normal_001" else under_node(m, *node)) for n, m in clips.items()}
    order = ["bow_normal_001"] + [n for n in held if n != "bow_normal_001"]
    model = PostureMap(seed=0).fit([held[n] for n in order], order)
    with running(create_app(held, model, allowed_hosts=LOOPBACK_HOSTS)) as url:
        studio = Page(browser, url)
        try:
            for a, b in (("run_normal_001", "walk_normal_001"), ("walk_normal_001", "run_normal_001")):
                studio.choose(a, b, a_end=15, b_start=3, length=24)
                with studio.page.expect_download() as info:
                    studio.page.click("#export")
                exported = bvh.loads(Path(info.value.path()).read_bytes()).global_positions()
                for f in range(len(exported)):
                    drawn = np.array(studio.js(f"__studio.jointPositions({f})"))
                    assert np.abs(drawn - exported[f]).max() < 0.05, (a, b, f)
            assert studio.errors == []
        finally:
            studio.close()


def test_traversal_and_malformed_requests_get_4xx(studio, base_url):
    req = studio.page.request
    for path in ("/static/..%2f..%2f..%2fetc%2fpasswd", "/static/%2e%2e/%2e%2e/%2e%2e/etc/passwd"):
        r = req.get(base_url + path)
        assert r.status == 404 and "root:" not in r.text()
    host, port = base_url.removeprefix("http://").split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=10)
    conn.putrequest("GET", "/static/../../../../etc/passwd")  # sent as is, not normalised
    conn.endheaders()
    resp = conn.getresponse()
    assert resp.status == 404 and b"root:" not in resp.read()
    conn.close()
    r = req.post(base_url + "/api/transition", data=b"{not json", headers={"Content-Type": "application/json"})
    assert r.status == 400 and "not valid JSON" in r.json()["error"]
    r = req.post(base_url + "/api/transition", data=json.dumps({"a": "walk_normal_001", "b": "nope"}),
                 headers={"Content-Type": "application/json"})
    assert r.status == 404 and "unknown clip" in r.json()["error"]
    r = req.post(base_url + "/api/transition", data=json.dumps({"a": "walk_normal_001", "b": "bow_normal_001",
                                                                "alpha": 7}),
                 headers={"Content-Type": "application/json"})
    assert r.status == 422 and "alpha" in r.json()["error"]


@pytest.mark.slow  # seconds of waiting or a second full run: `make test-slow`
def test_slider_moves_update_one_by_one(studio, clips):
    """50 alpha moves: one request and one timed update each; the keyless comparison is reused.

    (The latency figures come from bench/studio_latency.py; here only what must hold.)
    """
    page = studio.page
    studio.wait_requests_settled()
    assert studio.js("__studio.compare") == "spline"
    posts = []
    page.on("request", lambda r: r.method == "POST" and r.url.endswith("/api/transition")
            and posts.append(json.loads(r.post_data)["method"]))
    page.focus("#alpha")
    before = studio.js("__studio.latencies.length")
    for i in range(MOVES):
        page.keyboard.press("ArrowRight" if (i // 10) % 2 == 0 else "ArrowLeft")
        studio.js(f"__studio.latencyCount({before + i + 1})")
    studio.wait_requests_settled()
    lat = studio.js(f"__studio.latencies.slice({before})")
    steps = studio.js(f"__studio.timings.slice({before})")
    assert len(lat) == MOVES and len(steps) == MOVES
    order = ("input", "sent", "received", "applied", "frame", "rendered", "drawn", "painted")
    for t, total in zip(steps, lat):
        assert [t[k] for k in order] == sorted(t[k] for k in order), t
        assert t["painted"] == pytest.approx(total)
    # Only the keyed method is asked again: spline's result does not depend on alpha.
    assert posts == [DEFAULT_METHOD] * MOVES
    assert studio.js("__studio.params.alpha") == pytest.approx(0.6)  # 10 right, 10 left, ..., 10 right
    print(f"\n{MOVES} alpha moves (keyboard): median {statistics.median(lat):.1f} ms to the painted frame")
    assert studio.errors == []


@pytest.mark.slow  # seconds of waiting or a second full run: `make test-slow`
def test_screenshot(browser, base_url, tmp_path):
    """The studio mid-transition (the default method: real motion retrieved, its source in the
    panel) with a comparison overlay, drawn with the render profile a GPU gets (antialiasing,
    shadow maps; forced here, on software WebGL)."""
    studio = Page(browser, base_url, "?render=full")
    assert studio.js("__studio.profile") == "full"
    page = studio.page
    page.select_option("#compare", "slerp")
    studio.choose("walk_normal_001", "bow_normal_001", a_end=150, length=30, key_at=20, alpha=0.6)
    studio.wait("__studio.compare === 'slerp'")
    t0 = studio.js("__studio.result.transition[0]")
    page.evaluate(f"__studio.setFrame({t0 + 2})")
    studio.wait(f"__studio.frame === {t0 + 2}")
    page.evaluate("__studio.setView(90, 13, 4.4)")
    page.wait_for_timeout(500)
    studio.wait("__studio.renderScale === 1")  # redrawn at full resolution once still
    page.wait_for_timeout(700)
    assert studio.js("__studio.result.retrieval.parts.lower.clip") in CLIPS
    assert page.locator("#retrieval-info").is_visible()
    out = DOCS / "studio.png" if UPDATE_DOCS else tmp_path / "studio.png"
    page.screenshot(path=str(out))
    colors, covered = canvas_stats(out.read_bytes())
    assert colors > 1000 and covered > 0.2
    assert studio.errors == []
    studio.close()


def test_page_without_a_map_uses_keyless_methods(browser, sample_clips):
    """With no posture map (``train=False``) the page falls back to a keyless method."""
    with running(create_app(sample_clips, train=False, allowed_hosts=LOOPBACK_HOSTS)) as url:
        p = Page(browser, url)
        r = p.js("({result: __studio.result, map: __studio.map.state,"
                 " disabled: [...document.querySelectorAll('#method option:disabled')].map(o => o.value)})")
        assert r["map"] == "none" and r["result"]["method"] == "spline" and r["result"]["key_frame"] is None
        assert (r["result"]["a"], r["result"]["b"]) == ("walk", "run")
        assert set(r["disabled"]) == set(KEYED)
        assert p.js("__studio.keyPosture") is None and p.errors == []
        p.close()


def test_retrieval_shows_its_source_and_confidence(studio, clips):
    # The default (auto) replays real library motion for a 20-frame gap: the panel names the
    # clip and frames of each body part and how confident the match is; alpha still steers it.
    studio.choose("walk_normal_001", "run_normal_001", a_end=60, b_start=10)
    r = studio.js("__studio.result.retrieval")
    assert set(r["parts"]) == {"lower", "upper"}
    text = studio.page.inner_text("#retrieval-info")
    for part, p in r["parts"].items():
        assert p["clip"] in clips and f"{part}: {p['clip']} {p['frames'][0]}–{p['frames'][1]}" in text
        assert f"confidence {round(100 * p['confidence'])}%" in text
    costs = []
    for alpha in ("0", "1"):
        set_range(studio, "#alpha", alpha)
        studio.wait_requests_settled()
        costs.append(studio.js("__studio.result.retrieval.parts.lower"))
    assert costs[0]["cost_a"] <= costs[1]["cost_a"] and costs[0]["cost_b"] >= costs[1]["cost_b"]
    studio.page.select_option("#method", "slerp")
    studio.wait_requests_settled()
    assert studio.page.locator("#retrieval-info").is_hidden()
    assert studio.errors == []


def test_export_as_glb_downloads_the_shown_result(studio, clips):
    from posturemap.io import gltf

    page = studio.page
    studio.choose("run_normal_001", "walk_normal_001", a_end=15, b_start=30, length=24)
    expected = 16 + 24 + len(clips["walk_normal_001"]) - 30
    page.select_option("#export-format", "glb")
    with page.expect_download() as info:
        page.click("#export")
    download = info.value
    assert download.suggested_filename == f"run_normal_001_to_walk_normal_001_{DEFAULT_METHOD}.glb"
    doc, binary = gltf.read_glb(Path(download.path()).read_bytes())
    assert doc["asset"]["extras"]["frames"] == expected and doc["asset"]["extras"]["metres_per_unit"] == 0.01
    times = gltf.accessor_array(doc, binary, doc["animations"][0]["samplers"][0]["input"])
    assert len(times) == expected
    world = gltf.world_positions(doc, binary)  # metres; Bandai is Y-up like glTF
    assert world.shape[0] == expected
    # What the page draws (centimetres) is what the file holds, every joint from Hips down.
    for f in (0, 15, 16, 27, 39, 40, 41, expected - 1):
        drawn = np.array(studio.js(f"__studio.jointPositions({f})"))
        assert np.abs(drawn[1:] * 0.01 - world[f, 1: len(drawn)]).max() < 5e-4, f"frame {f}"
    assert studio.errors == []
