"""The studio's HTTP API (``posturemap serve``), through Starlette's test client.

Most tests use the procedural sample (always available) with a map trained once per module;
one checks every method on real Bandai clips (skipped with a reason without ../shared/data);
one starts the real command in a subprocess.
"""

from __future__ import annotations

import base64
import hashlib
import http.client
import json
import os
import re
import socket
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

with warnings.catch_warnings():  # starlette 1.x prefers httpx2 for its test client; httpx still works
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

from posturemap.io import bvh
from posturemap.core import quat
from posturemap.learn.model import PostureMap
from posturemap.core.motion import Motion, resample
from posturemap.synth.engine import transition
from posturemap.synth.request import DEFAULT_METHOD, KEYED, METHODS
from posturemap.web import server, studio
from posturemap.web.guards import MAX_BODY
from posturemap.web.server import create_app
from posturemap.web.studio import LOOPBACK_HOSTS, MAX_LENGTH
from rigkit import under_node


@pytest.fixture(scope="module")
def model(sample_clips):
    return PostureMap(seed=0).fit(list(sample_clips.values()), list(sample_clips))


@pytest.fixture(scope="module")
def client(sample_clips, model):
    with TestClient(create_app(sample_clips, model), raise_server_exceptions=False) as c:
        yield c


def post(client, body, url="/api/transition"):
    return client.post(url, json=body)


def expected_frames(a_len, b_len, a_end, length, b_start):
    return a_end + 1 + length + b_len - b_start


def local_arrays(payload, bones, rest):
    """Local rotations (F, J, 4) (w, x, y, z) and translations (F, J, 3) from a tracks payload."""
    n = payload["frames"]
    rots = np.empty((n, len(bones), 4))
    pos = np.repeat(np.asarray(rest, dtype=np.float64)[None], n, axis=0)
    for t in payload["tracks"]:
        bone, kind = t["name"].rsplit(".", 1)
        j = bones.index(bone)
        if kind == "quaternion":
            rots[:, j] = np.array(t["values"]).reshape(n, 4)[:, [3, 0, 1, 2]]
        else:
            pos[:, j] = np.array(t["values"]).reshape(n, 3)
    return rots, pos


def assemble(client, d, skeleton) -> Motion:
    """The whole result of a transition answer, put together as its docstring says (and the page does):
    A's frames 0..a_end, the in-between frames, B's frames b_start.. with the alignment applied."""
    sk = client.get("/api/clips").json()["skeleton"]
    bones, rest = sk["bones"], sk["rest"]
    ra, pa = local_arrays(client.get(f"/api/clip/{d['a']}").json(), bones, rest)
    rb, pb = local_arrays(client.get(f"/api/clip/{d['b']}").json(), bones, rest)
    rt, pt = local_arrays(d["inbetween"], bones, rest)
    a_end, b_start = d["params"]["a_end"], d["params"]["b_start"]
    rb, pb = rb[b_start:].copy(), pb[b_start:].copy()
    al = d["alignment"]
    turn = np.array(al["rotation"])[[3, 0, 1, 2]]
    top = bones.index(al["joint"])
    rb[:, top] = quat.mul(turn, rb[:, top])
    pb[:, top] = quat.mul_vec(turn, pb[:, top]) + np.array(al["translation"])
    rots = np.concatenate([ra[: a_end + 1], rt, rb])
    pos = np.concatenate([pa[: a_end + 1], pt, pb])
    assert len(rots) == d["frames"]
    return Motion(skeleton, rots, pos, d["fps"])


# -- listing ----------------------------------------------------------------------------------
def test_clips_lists_skeleton_clips_and_methods(client, sample_clips):
    r = client.get("/api/clips")
    assert r.status_code == 200
    d = r.json()
    assert [c["name"] for c in d["clips"]] == list(sample_clips)
    for c in d["clips"]:
        m = sample_clips[c["name"]]
        assert c["frames"] == len(m) and c["fps"] == pytest.approx(m.fps)
    sk = d["skeleton"]
    walk = sample_clips["walk"]
    assert sk["names"] == list(walk.skeleton.names)
    assert sk["parents"] == walk.skeleton.parents.tolist()
    assert np.allclose(sk["rest"], walk.positions[0], atol=1e-5)
    assert len(sk["end_sites"]) == len(walk.skeleton.end_sites)
    assert sk["up"] == 1 and sk["unit"] == "cm" and 150 < sk["height"] < 200
    assert d["methods"] == list(METHODS) and d["keyed"] == list(KEYED)
    assert d["limits"]["length"] == [1, MAX_LENGTH]
    assert d["status"]["state"] == "ready"


def test_one_clip_as_tracks(client, sample_clips):
    run = sample_clips["run"]
    d = client.get("/api/clip/run").json()
    assert d["frames"] == len(run) and len(d["times"]) == len(run)
    quats = {t["name"]: t["values"] for t in d["tracks"] if t["type"] == "quaternion"}
    hips = np.array(quats["Hips.quaternion"]).reshape(-1, 4)
    ref = run.rotations[:, 0, [1, 2, 3, 0]]
    assert np.allclose(np.abs(np.sum(hips * ref, axis=1)), 1.0, atol=1e-5)
    pos = {t["name"]: t["values"] for t in d["tracks"] if t["type"] == "vector"}
    assert list(pos) == ["Hips.position"]  # only the root's translation moves
    assert np.allclose(np.array(pos["Hips.position"]).reshape(-1, 3), run.positions[:, 0], atol=1e-3)
    r = client.get("/api/clip/nope")
    assert r.status_code == 404 and "unknown clip" in r.json()["error"]


def test_bone_names_are_safe_for_three_js():
    assert studio.bone_names(("Hips", "left arm", "a.b:c/d[0]", "a.b:c/d[0]", "...")) == \
        ["Hips", "left_arm", "abcd0", "abcd0_2", "joint4"]


# -- transitions ------------------------------------------------------------------------------
@pytest.mark.parametrize("method", METHODS)
def test_transition_shape_segments_and_key(client, sample_clips, method):
    walk, run = sample_clips["walk"], sample_clips["run"]
    body = {"a": "walk", "b": "run", "a_end": 70, "b_start": 5, "length": 16, "key_at": 6, "alpha": 0.3,
            "method": method, "align": True, "foot_lock": False}  # the key frame exactly as keyed
    r = post(client, body)
    assert r.status_code == 200, r.text
    d = r.json()
    n = expected_frames(len(walk), len(run), 70, 16, 5)
    assert d["frames"] == n
    assert d["fps"] == pytest.approx(30.0)
    assert d["duration"] == pytest.approx((n - 1) / 30.0)
    assert d["segments"] == {"a": [0, 70], "transition": [71, 86], "b": [87, n - 1]}
    assert d["transition"] == [71, 86] and d["seams"] == [70, 87]
    # Only the 16 new frames travel; the clips' frames come from /api/clip.
    new = d["inbetween"]
    assert new["frames"] == 16 and len(new["times"]) == 16 and new["times"][1] == pytest.approx(1 / 30.0)
    j = walk.skeleton.num_joints
    quats = [t for t in new["tracks"] if t["type"] == "quaternion"]
    assert [t["name"] for t in quats] == [f"{b}.quaternion" for b in walk.skeleton.names]
    assert all(len(t["values"]) == 4 * 16 for t in new["tracks"] if t["type"] == "quaternion")
    assert all(len(t["values"]) == 3 * 16 for t in new["tracks"] if t["type"] == "vector")
    q = np.array([t["values"] for t in quats]).reshape(j, 16, 4)
    assert np.allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-5)
    assert d["alignment"]["joint"] == "Hips" and d["alignment"]["up"] == 1
    if method in ("auto", "retrieval"):  # real motion replayed: which one, and how confidently
        parts = d["retrieval"]["parts"]
        assert set(parts) == {"lower", "upper"} and d["key"] is None
        assert all(p["clip"] in ("walk", "run", "wave") and 0 <= p["confidence"] <= 1 for p in parts.values())
        assert d["method_used"] == "retrieval"
    elif method in KEYED:
        key = d["key"]
        assert key["frame"] == d["key_frame"] == 70 + 6 and key["index"] == 6
        kq = np.array(key["quaternions"])
        assert kq.shape == (len(key["joints"]), 4) and np.allclose(np.linalg.norm(kq, axis=1), 1, atol=1e-5)
        assert len(key["neurons"]) == 4
        # The in-between frame at the key carries the key's rotations (joints below the root).
        names = list(walk.skeleton.names)
        for name, k in zip(key["joints"][1:], kq[1:]):
            got = q[names.index(name), key["index"] - 1]
            assert abs(np.dot(got, k)) == pytest.approx(1.0, abs=1e-4)
    else:
        assert d["key"] is None and d["key_frame"] is None and "retrieval" not in d


def test_transition_frames_match_the_library(client, sample_clips, model):
    walk, wave = sample_clips["walk"], sample_clips["wave"]
    body = {"a": "walk", "b": "wave", "a_end": 50, "b_start": 3, "length": 12, "key_at": 4, "alpha": 0.7}
    d = post(client, body).json()
    ref = transition(walk, wave, model, length=12, key_at=4, alpha=0.7, a_end=50, b_start=3)
    assert d["frames"] == len(ref)
    got = assemble(client, d, walk.skeleton)
    assert np.allclose(np.abs(np.sum(got.rotations * ref.rotations, axis=-1)), 1.0, atol=1e-5)
    assert np.allclose(got.positions[:, 0], ref.positions[:, 0], atol=1e-3)
    assert np.abs(got.global_positions() - ref.global_positions()).max() < 1e-3


def test_defaults_and_alpha_moves_the_key(client, sample_clips):
    d = post(client, {"a": "run", "b": "walk"}).json()
    run, walk = sample_clips["run"], sample_clips["walk"]
    assert d["params"] == {"a_end": len(run) - 1, "b_start": 0, "length": 20, "key_at": 10, "alpha": 0.5,
                           "align": True, "foot_lock": True}
    assert d["method"] == DEFAULT_METHOD and d["frames"] == len(run) + 20 + len(walk)
    keys = [np.array(post(client, {"a": "walk", "b": "wave", "alpha": a, "method": "upm-valid"}).json()["key"]["quaternions"])
            for a in (0.0, 1.0)]
    assert np.abs(keys[0] - keys[1]).max() > 1e-3


def test_length_one_and_no_align(client, sample_clips):
    d = post(client, {"a": "walk", "b": "run", "length": 1, "align": False, "method": "upm-valid"}).json()
    assert d["key"]["index"] == 1 and d["transition"] == [90, 90]
    run = sample_clips["run"]
    assert d["alignment"]["turn"] == 0 and d["alignment"]["shift"] == [0, 0, 0]
    hips = assemble(client, d, run.skeleton).positions[:, 0]
    assert np.allclose(hips[91:], run.positions[:, 0], atol=1e-3)  # B left where it is


# -- export -----------------------------------------------------------------------------------
def test_export_post_and_get_give_bvh(client, sample_clips):
    body = {"a": "wave", "b": "walk", "a_end": 40, "b_start": 10, "length": 8, "method": "spline"}
    r = post(client, body, "/api/export")
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/plain")
    assert r.headers["content-disposition"] == 'attachment; filename="wave_to_walk_spline.bvh"'
    m = bvh.loads(r.content)
    assert len(m) == 41 + 8 + len(sample_clips["walk"]) - 10
    assert m.skeleton.same_as(sample_clips["wave"].skeleton)
    g = client.get("/api/export", params={"a": "wave", "b": "walk", "a_end": "40", "b_start": "10",
                                          "length": "8", "method": "spline", "align": "true"})
    assert g.status_code == 200 and g.content == r.content
    assert client.get("/api/export?a=wave&b=walk&length=ten").status_code == 422
    assert client.get("/api/export?a=wave&b=walk&alpha=2").status_code == 422
    assert client.get("/api/export?a=wave&b=walk&a=run").status_code == 422
    # Both switches work from a query string: without the foot lock, as POST without it.
    body_free = {**body, "foot_lock": False}
    free = post(client, body_free, "/api/export")
    for flag in ("false", "0"):
        g = client.get("/api/export", params={"a": "wave", "b": "walk", "a_end": "40", "b_start": "10",
                                              "length": "8", "method": "spline", "foot_lock": flag})
        assert g.status_code == 200 and g.content == free.content
    bad = client.get("/api/export?a=wave&b=walk&foot_lock=maybe")
    assert bad.status_code == 422 and bad.json()["field"] == "foot_lock"


@pytest.fixture(scope="module")
def bandai(bandai_paths):
    return {n: bvh.read(p) for n, p in bandai_paths(["walk_normal_001", "run_normal_001", "bow_normal_001"]).items()}


def test_export_matches_transition_on_bandai(bandai):
    clips = bandai
    names = ["bow_normal_001", "walk_normal_001", "run_normal_001"]  # bow first: see the next test
    model = PostureMap(seed=0).fit([clips[n] for n in names], names)
    with TestClient(create_app(clips, model), raise_server_exceptions=False) as c:
        for method in METHODS:
            body = {"a": "bow_normal_001", "b": "walk_normal_001", "a_end": 100, "b_start": 20, "length": 24,
                    "alpha": 0.4, "method": method}
            d = post(c, body).json()
            n = 101 + 24 + len(clips["walk_normal_001"]) - 20
            assert d["frames"] == n, method
            r = post(c, body, "/api/export")
            m = bvh.loads(r.content)
            assert len(m) == n
            ref = transition(clips["bow_normal_001"], clips["walk_normal_001"], model, length=24, alpha=0.4,
                             a_end=100, b_start=20, method=method)
            assert np.allclose(m.global_positions(), ref.global_positions(), atol=1e-3)
            # The page's assembly: walk_normal_001's joint_Root stays at the origin (a reference
            # node), so B's placement goes on Hips under it; every joint lands where the export
            # puts it, joint_Root too.
            assert d["alignment"]["joint"] == "Hips"
            shown = assemble(c, d, m.skeleton).global_positions()
            assert np.abs(shown - ref.global_positions()).max() < 1e-2, method
        # run_normal_001's joint_Root runs with the body (root motion): B's placement goes on it.
        body = {"a": "walk_normal_001", "b": "run_normal_001", "a_end": 150, "b_start": 2, "length": 20}
        d = post(c, body).json()
        assert d["alignment"]["joint"] == "joint_Root"
        assert d["alignment"]["rotation"] == pytest.approx(
            [0, np.sin(d["alignment"]["turn"] / 2), 0, np.cos(d["alignment"]["turn"] / 2)], abs=1e-9)
        ref = transition(clips["walk_normal_001"], clips["run_normal_001"], model, length=20, a_end=150, b_start=2)
        shown = assemble(c, d, ref.skeleton).global_positions()
        assert np.abs(shown - ref.global_positions()).max() < 1e-2
        sk = c.get("/api/clips").json()["skeleton"]
        assert sk["up"] == 1 and sk["names"][sk["root"]] == "Hips"


def test_the_page_places_b_under_a_turned_node_as_the_export_does(bandai):
    # joint_Root fixed a quarter turn about X and off the origin (a Z-up file's conversion node):
    # B's placement, seen from the node, goes on Hips; run_normal_001 keeps its moving joint_Root,
    # which takes the placement itself. Every joint of the page's assembly lands where the export
    # puts it, B placed or not.
    node = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.array(-np.pi / 2)), np.array([30.0, 5.0, -20.0])
    clips = {n: (m if n == "run_normal_001" else under_node(m, *node)) for n, m in bandai.items()}
    model = PostureMap(seed=0).fit(list(clips.values()), list(clips))
    with TestClient(create_app(clips, model), raise_server_exceptions=False) as c:
        for a, b, joint in (("bow_normal_001", "walk_normal_001", "Hips"), ("walk_normal_001", "run_normal_001", "joint_Root"),
                            ("run_normal_001", "walk_normal_001", "Hips")):
            for align in (True, False):
                body = {"a": a, "b": b, "a_end": min(100, len(clips[a]) - 1), "b_start": 3, "length": 20, "align": align}
                d = post(c, body).json()
                assert d["alignment"]["joint"] == joint
                exported = bvh.loads(post(c, body, "/api/export").content)
                shown = assemble(c, d, exported.skeleton).global_positions()
                assert np.abs(shown - exported.global_positions()).max() < 1e-2, (a, b, align)


def test_server_trained_map_lines_clips_up_on_bandai(bandai):
    """The map learnt by the server takes Hips as root and Y as up whatever the clip order.

    (posturemap.core.motion reads walk_normal_001 as Z-up and run_normal_001's root as joint_Root; the
    studio puts first a clip read like the majority, since map and engine follow their first clip.)
    """
    app = create_app(bandai)
    studio = app.state.studio
    assert studio.wait_ready(60)["state"] == "ready"
    space = studio.engine.model.space_
    assert (space.root, space.up) == (1, 1) and studio.root == 1 and studio.up == 1
    with TestClient(app, raise_server_exceptions=False) as c:
        for a, b in [("walk_normal_001", "run_normal_001"), ("run_normal_001", "bow_normal_001")]:
            m = bvh.loads(post(c, {"a": a, "b": b, "length": 20}, "/api/export").content)
            hips = m.global_positions()[:, 1]
            speed = np.linalg.norm(np.diff(hips[:, [0, 2]], axis=0), axis=1)  # cm per frame
            n = len(bandai[a])
            seams = np.concatenate([speed[n - 3: n + 1], speed[n + 18: n + 22]])
            assert seams.max() < 1.5 * max(speed[: n - 1].max(), speed[n + 21:].max()) + 1, (a, b, seams)


# -- status and training ------------------------------------------------------------------------
def test_training_in_background_then_keyed_methods(sample_clips):
    app = create_app(sample_clips)
    with TestClient(app, raise_server_exceptions=False) as c:
        s = c.get("/api/status").json()
        assert s["state"] in ("loading", "training", "ready") and 0 <= s["progress"] <= 1
        # Keyless methods work at once; keyed ones answer 503 until the map is ready.
        assert post(c, {"a": "walk", "b": "run", "method": "slerp"}).status_code == 200
        r = post(c, {"a": "walk", "b": "run"})
        assert r.status_code in (200, 503)
        if r.status_code == 503:
            assert "training" in r.json()["error"]
        assert app.state.studio.wait_ready(60)["state"] == "ready"
        s = c.get("/api/status").json()
        assert s["state"] == "ready" and s["progress"] == 1.0 and s["neurons"] > 0
        assert set(s["classes"]) == {"body", "global", "medium", "detail"}
        assert post(c, {"a": "walk", "b": "run"}).status_code == 200


def test_no_map_keyed_method_is_503(sample_clips):
    with TestClient(create_app(sample_clips, train=False), raise_server_exceptions=False) as c:
        assert c.get("/api/status").json()["state"] == "none"
        r = post(c, {"a": "walk", "b": "run", "method": "upm"})
        assert r.status_code == 503 and "posture map" in r.json()["error"]
        assert post(c, {"a": "walk", "b": "run", "method": "inertialize"}).status_code == 200


def test_a_clip_at_another_rate_is_resampled_to_the_first_clips(sample_clips, model):
    # Before, transitions between the two answered 422 (different frame rates).
    walk, run_ = sample_clips["walk"], sample_clips["run"]
    lines = []
    app = create_app({"walk": walk, "run": resample(run_, 2 * run_.fps)}, model, log=lines.append)
    served = app.state.studio.clips["run"]
    assert served.fps == walk.fps and len(served) == len(run_)
    np.testing.assert_allclose(served.global_positions(), run_.global_positions(), atol=1e-9)
    assert [x for x in lines if "resampled" in x] == [
        f"posturemap: note: run: {2 * run_.fps:g} fps, resampled to {walk.fps:g} fps (the first clip's rate)"]
    with TestClient(app, raise_server_exceptions=False) as c:
        assert c.get("/api/clips").json()["clips"][1]["fps"] == pytest.approx(walk.fps)
        r = post(c, {"a": "walk", "b": "run", "length": 10, "b_start": 5})
        assert r.status_code == 200, r.text
        assert r.json()["frames"] == expected_frames(len(walk), len(run_), len(walk) - 1, 10, 5)


def test_mixed_skeletons_are_refused(sample_clips, cmu_file):
    with pytest.raises(ValueError, match="skeleton differs"):
        create_app({"walk": sample_clips["walk"], "cmu": bvh.read(cmu_file)}, train=False)


# -- bad input: 4xx with a message, never 500 -------------------------------------------------------
@pytest.mark.parametrize("path", [
    "/static/../../etc/passwd", "/static/..%2f..%2fetc%2fpasswd", "/static/%2e%2e/%2e%2e/etc/passwd",
    "/static/..%252f..%252fetc%252fpasswd", "/static/vendor/../../server.py", "/static/%2e%2e/server.py",
    "/static//etc/passwd", "/static/..\\..\\server.py", "/static/../__init__.py", "/../../etc/passwd",
])
def test_path_traversal_is_404(client, path):
    r = client.get(path)
    assert r.status_code == 404, (path, r.status_code)
    assert "root:" not in r.text and "import" not in r.text


def test_raw_traversal_requests_are_404(sample_clips, model):
    """The paths as sent on the wire (no client normalisation), against a real server."""
    with server.running(create_app(sample_clips, model)) as url:
        port = int(url.rsplit(":", 1)[1])
        for path in ("/static/../../../../etc/passwd", "/static/..%2F..%2F..%2F..%2Fetc%2Fpasswd",
                     "/static/%2e%2e/%2e%2e/%2e%2e/%2e%2e/etc/passwd", "/static/vendor/../../server.py"):
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
            conn.putrequest("GET", path, skip_accept_encoding=True)
            conn.endheaders()
            resp = conn.getresponse()
            text = resp.read().decode("utf-8", "replace")
            conn.close()
            assert 400 <= resp.status < 500, (path, resp.status)
            assert "root:" not in text and "import" not in text
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        conn.request("GET", "/static/app.js")
        assert conn.getresponse().status == 200
        conn.close()


def test_accepted_connections_send_at_once():
    """TCP_NODELAY on the studio's connections: a small answer does not wait for the client's
    delayed ACK (40 ms on Linux) behind Nagle's algorithm."""
    listener = server._listen("127.0.0.1", 0)
    try:
        with socket.create_connection(listener.getsockname()[:2], timeout=5):
            conn, _ = listener.accept()
            with conn:
                assert conn.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0
    finally:
        listener.close()


def test_page_and_security_headers(client):
    r = client.get("/")
    assert r.status_code == 200 and "text/html" in r.headers["content-type"]
    assert '<script type="importmap">' in r.text and "/static/vendor/three.module.js" in r.text
    assert "cdn" not in r.text.lower() and "https://" not in r.text
    csp = r.headers["content-security-policy"]
    block = re.search(r'<script type="importmap">(.*?)</script>', r.text, re.DOTALL).group(1)
    digest = base64.b64encode(hashlib.sha256(block.encode()).digest()).decode()
    assert f"'sha256-{digest}'" in csp and "default-src 'self'" in csp
    assert r.headers["x-content-type-options"] == "nosniff"
    for f in ("app.js", "style.css", "favicon.svg"):
        assert client.get(f"/static/{f}").status_code == 200


def test_page_modules_are_served_as_javascript(client):
    """Every module the page imports by a relative path (app.js, then js/*.js) is served as a
    JavaScript module (a browser refuses a module of another type), and every file in js/ is used."""
    seen, todo = set(), ["app.js"]
    while todo:
        path = todo.pop()
        r = client.get(f"/static/{path}")
        assert r.status_code == 200, path
        assert r.headers["content-type"].split(";")[0] in ("text/javascript", "application/javascript"), path
        seen.add(path)
        for spec in re.findall(r"""^\s*(?:import|export)\b[^'"]*?from\s+['"](\.{1,2}/[^'"]+)['"]""", r.text, re.M):
            target = os.path.normpath(os.path.join(os.path.dirname(path), spec))
            if target not in seen:
                todo.append(target)
    on_disk = {f"js/{p.name}" for p in (server.STATIC_DIR / "js").glob("*.js")}
    assert on_disk and on_disk <= seen, sorted(on_disk - seen)


def test_vendored_three_is_the_pinned_version(client):
    with open(os.path.join(os.path.dirname(__file__), "..", "package.json")) as f:
        pinned = json.load(f)["dependencies"]["three"]
    r = client.get("/static/vendor/three.core.js")
    assert r.status_code == 200, "run `make web` to vendor three.js"
    assert re.search(r"const REVISION = '(\d+)'", r.text).group(1) == pinned.split(".")[1]
    for f in ("three.module.js", "addons/controls/OrbitControls.js", "addons/loaders/BVHLoader.js"):
        assert client.get(f"/static/vendor/{f}").status_code == 200


def test_host_header_is_checked_when_bound_locally(sample_clips, model):
    with TestClient(create_app(sample_clips, model, allowed_hosts=LOOPBACK_HOSTS)) as c:
        assert c.get("/api/status").status_code == 400  # Host: testserver (DNS rebinding)
        for host in ("127.0.0.1:8000", "localhost", "[::1]:8000"):
            assert c.get("/api/status", headers={"host": host}).status_code == 200, host
        assert c.get("/api/status", headers={"host": "evil.example:8000"}).status_code == 400


def test_malformed_json_is_400(client):
    for raw in (b"{bad", b"", b"   ", b'{"a": "walk",}', b"\xff\xfe\x00", b'{"a": NaN}', b'{"alpha": Infinity}',
                b'{"a": "walk"} trailing'):
        r = client.post("/api/transition", content=raw, headers={"content-type": "application/json"})
        assert r.status_code == 400, raw[:20]
        assert r.json()["error"]
    r = client.post("/api/transition", content=b"[" * 30000 + b"]" * 30000,  # nested too deeply
                    headers={"content-type": "application/json"})
    assert r.status_code in (400, 422) and r.json()["error"]


def test_oversized_body_is_413(client):
    big = json.dumps({"a": "walk", "b": "run", "pad": "x" * (MAX_BODY + 10)})
    r = client.post("/api/transition", content=big, headers={"content-type": "application/json"})
    assert r.status_code == 413 and "too large" in r.json()["error"]

    def chunks():  # no Content-Length: the limit holds while streaming
        for _ in range(100):
            yield b" " * 1024

    r = client.post("/api/transition", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413
    r = client.post("/api/transition", content=b"{}", headers={"content-length": "abc",
                                                                "content-type": "application/json"})
    assert r.status_code in (400, 413)


@pytest.mark.parametrize("body, status, field, words", [
    ({"a": "nope", "b": "run"}, 404, "a", "unknown clip 'nope'"),
    ({"a": "walk", "b": "../../etc/passwd"}, 404, "b", "unknown clip"),
    ({"b": "run"}, 422, "a", "missing"),
    ({"a": "walk", "b": "run", "method": "magic"}, 422, "method", "unknown method 'magic'"),
    ({"a": "walk", "b": "run", "a_end": 90}, 422, "a_end", "frame 90 is outside clip A 'walk' (frames 0..89)"),
    ({"a": "walk", "b": "run", "a_end": -1}, 422, "a_end", "outside"),
    ({"a": "walk", "b": "run", "b_start": 60}, 422, "b_start", "outside clip B"),
    ({"a": "walk", "b": "run", "length": 0}, 422, "length", "between 1 and"),
    ({"a": "walk", "b": "run", "length": MAX_LENGTH + 1}, 422, "length", "between 1 and"),
    ({"a": "walk", "b": "run", "length": 10, "key_at": 11}, 422, "key_at", "between 1 and 10"),
    ({"a": "walk", "b": "run", "key_at": 0}, 422, "key_at", "between"),
    ({"a": "walk", "b": "run", "alpha": 1.5}, 422, "alpha", "between 0 and 1"),
    ({"a": "walk", "b": "run", "alpha": -0.01}, 422, "alpha", "between 0 and 1"),
    ({"a": "walk", "b": "run", "alpha": "0.5"}, 422, "alpha", "number"),
    ({"a": "walk", "b": "run", "alpha": True}, 422, "alpha", "number"),
    ({"a": "walk", "b": "run", "length": "20"}, 422, "length", "whole number"),
    ({"a": "walk", "b": "run", "length": 2.5}, 422, "length", "whole number"),
    ({"a": "walk", "b": "run", "a_end": True}, 422, "a_end", "whole number"),
    ({"a": "walk", "b": "run", "a_end": 1e300}, 422, "a_end", "outside"),
    ({"a": "walk", "b": "run", "align": "yes"}, 422, "align", "true or false"),
    ({"a": ["walk"], "b": "run"}, 422, "a", "clip name"),
    ({"a": "walk", "b": "run", "alhpa": 0.2}, 422, "alhpa", "unknown field"),
    ([1, 2, 3], 422, None, "JSON object"),
    ("walk", 422, None, "JSON object"),
])
def test_bad_requests_get_4xx_with_a_message(client, body, status, field, words):
    r = post(client, body)
    assert r.status_code == status, r.text
    d = r.json()
    assert words in d["error"] and d["field"] == field
    assert post(client, body, "/api/export").status_code == status


def test_float_frame_numbers_that_are_whole_are_accepted(client):
    assert post(client, {"a": "walk", "b": "run", "length": 12.0, "a_end": 30.0}).json()["frames"] == 31 + 12 + 60


def test_wrong_methods_and_routes(client):
    assert client.get("/api/transition").status_code == 405
    assert client.put("/api/export", content=b"{}").status_code == 405
    r = client.get("/api/nothing")
    assert r.status_code == 404 and r.json()["error"]


def test_random_garbage_never_gives_500(client):
    rng = np.random.default_rng(1234)
    values = [None, True, False, 0, -1, 1, 2**31, 2**64, -2**63, 0.5, -0.0, 1e-300, 1e308, 3.7, "", "walk", "run",
              "wave", "upm", "spline", "x" * 300, "\u0000", "\ud7ff", [], [1], {}, {"a": 1}, "../..", "%2e%2e",
              "NaN", "1e400"]
    fields = list(studio.FIELDS) + ["", "__proto__", "pad"]
    statuses = set()
    for i in range(400):
        kind = rng.integers(0, 4)
        if kind == 0:  # structured: random fields with random values
            body = {str(rng.choice(fields)): values[rng.integers(len(values))] for _ in range(rng.integers(0, 8))}
            if rng.random() < 0.7:
                body.update(a=str(rng.choice(["walk", "run", "wave"])), b=str(rng.choice(["walk", "run", "wave"])))
            r = client.post(str(rng.choice(["/api/transition", "/api/export"])), json=body)
        elif kind == 1:  # random bytes
            raw = rng.bytes(int(rng.integers(0, 300)))
            r = client.post("/api/transition", content=raw, headers={"content-type": "application/json"})
        elif kind == 2:  # query strings
            q = "&".join(f"{rng.choice(fields)}={rng.choice(['1', '-5', 'x', '0.5', 'walk', 'run', '', '%00', '1e9'])}"
                         for _ in range(rng.integers(0, 6)))
            r = client.get(f"/api/export?a=walk&b=run&{q}")
        else:  # paths
            seg = rng.choice(["..", "%2e%2e", "%2f", "static", "vendor", "api", "clip", "x", "%00", "app.js", "\\"],
                             size=int(rng.integers(1, 6)))
            r = client.get("/" + "/".join(seg))
        statuses.add(r.status_code)
        assert r.status_code < 500, (i, r.status_code, r.text[:200])
        if r.status_code >= 400:
            assert r.json()["error"]
    assert 200 in statuses and 422 in statuses and 404 in statuses and 400 in statuses


# -- the real command -------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_command_starts_and_answers(tmp_path):
    port = _free_port()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "posturemap.cli", "serve", "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = ""
        deadline = time.monotonic() + 60
        while "open http" not in line and time.monotonic() < deadline:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, proc.stderr.read()
        assert f"http://127.0.0.1:{port}/" in line
        state = None
        while time.monotonic() < deadline:
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
            conn.request("GET", "/api/status")
            state = json.loads(conn.getresponse().read())["state"]
            conn.close()
            if state == "ready":
                break
            time.sleep(0.1)
        assert state == "ready"
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        conn.request("POST", "/api/transition", body=json.dumps({"a": "walk", "b": "wave"}),
                     headers={"Content-Type": "application/json"})
        resp = conn.getresponse()
        assert resp.status == 200 and json.loads(resp.read())["frames"] == 90 + 20 + 90
        conn.close()
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    assert "training posture map" in err and "posture map ready" in err


def test_serve_command_errors_are_one_line(tmp_path):
    r = subprocess.run([sys.executable, "-m", "posturemap.cli", "serve", str(tmp_path / "missing.bvh")],
                       check=False, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].startswith("posturemap: error:")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        r = subprocess.run([sys.executable, "-m", "posturemap.cli", "serve", "--port", str(port)],
                           check=False, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "cannot listen" in r.stderr
