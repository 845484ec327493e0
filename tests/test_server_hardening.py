"""The studio server under hostile input (issue 12), against a running ``posturemap serve``.

The server runs as the real command in a subprocess (``bench/server_fuzz.py`` starts it); its
log must stay free of tracebacks. The long mode (10^4 random requests) is
``python bench/server_fuzz.py``; here a few hundred. Timeouts are checked in-process with
short limits (the real ones are 10 s).
"""

from __future__ import annotations

import http.client
import json
import socket
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from posturemap.web import server as web
from posturemap.web import guards
from posturemap.web.studio import POOL_SIZE

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
import server_fuzz  # noqa: E402

sys.path.pop(0)


@pytest.fixture(scope="module")
def srv(tmp_path_factory):
    with server_fuzz.Server(tmp_path_factory.mktemp("serve")) as s:
        yield s
    assert s.problems() == []


def test_issue12_alpha_with_309_digits_is_422(srv):
    huge = "9" * 309
    body = ('{"a": "walk", "b": "run", "alpha": ' + huge + "}").encode()
    for path in ("/api/transition", "/api/export"):
        status, raw = server_fuzz.request(srv, "POST", path, body, {"Content-Type": "application/json"})
        assert status == 422, raw
        msg = json.loads(raw)["error"]
        assert msg.startswith("alpha:") and "309-digit" in msg
    status, _ = server_fuzz.request(srv, "GET", f"/api/export?a=walk&b=run&alpha={huge}")
    assert status == 422


def test_a_body_in_utf16_or_naming_a_member_twice_is_400(srv):
    plain = '{"a": "walk", "b": "run", "length": 10}'
    twice = '{"a": "walk", "b": "run", "length": 10, "length": 20}'
    headers = {"Content-Type": "application/json"}
    status, _ = server_fuzz.request(srv, "POST", "/api/transition", plain.encode(), headers)
    assert status == 200  # the same request in UTF-8, once
    status, raw = server_fuzz.request(srv, "POST", "/api/transition", plain.encode("utf-16"), headers)
    assert status == 400 and "not valid JSON" in json.loads(raw)["error"]
    status, raw = server_fuzz.request(srv, "POST", "/api/transition", twice.encode(), headers)
    assert status == 400 and "'length' given twice" in json.loads(raw)["error"]
    # A byte order mark before UTF-8 is skipped (RFC 8259 allows it); a lone surrogate escaped
    # in a member's name was a 500 (its error message could not be encoded), now 400.
    status, _ = server_fuzz.request(srv, "POST", "/api/transition", b"\xef\xbb\xbf" + plain.encode(), headers)
    assert status == 200
    lone = '{"a": "walk", "b": "run", "length": 10, "\\ud800": 1}'
    status, raw = server_fuzz.request(srv, "POST", "/api/transition", lone.encode(), headers)
    assert status == 400 and "not valid JSON" in json.loads(raw)["error"]
    # A pair of surrogates escaped is one character (an emoji): valid JSON, judged as a request.
    paired = '{"a": "walk", "b": "run", "length": 10, "\\ud83d\\ude00": 1}'
    status, raw = server_fuzz.request(srv, "POST", "/api/transition", paired.encode(), headers)
    assert 400 <= status < 500 and "not valid JSON" not in json.loads(raw)["error"], (status, raw)


def test_every_docstring_is_text():
    # help() and pydoc encode docstrings: one that spelled a lone surrogate as an escape in a
    # plain string (read_json's "\ud800") held the surrogate itself, and help() raised.
    import importlib
    import inspect
    import pkgutil

    import posturemap

    seen = 0
    for info in pkgutil.walk_packages(posturemap.__path__, "posturemap."):
        module = importlib.import_module(info.name)
        for obj in [module] + [v for _, v in inspect.getmembers(module) if getattr(v, "__module__", None) == info.name]:
            doc = inspect.getdoc(obj)
            if doc:
                doc.encode("utf-8")
                seen += 1
    assert seen > 300


def test_issue12_malformed_requests_get_4xx_and_no_traceback(srv):
    result = server_fuzz.malformed(srv)
    assert result["cross_origin_post"] == 403
    assert result["cross_origin_export_get"] == 403
    assert result["cross_site_no_origin_export"] == 403
    assert result["form_post"] == 415 and result["text_plain_post"] == 415
    assert 400 <= result["huge_header"] < 500
    assert result["bad_request_line"] == 400
    assert all(s < 500 for s in result.values()), result
    time.sleep(0.3)
    assert srv.problems() == []


@pytest.mark.slow  # seconds of waiting or a second full run: `make test-slow`
def test_issue12_client_disconnect_mid_body_is_quiet(srv):
    before = len(srv.log)
    for _ in range(3):
        server_fuzz._disconnect_mid_body(srv)
    time.sleep(0.3)
    assert srv.problems() == []
    assert all("error" not in line.lower() for line in srv.log[before:]), srv.log[before:]


def test_same_origin_and_plain_clients_are_served(srv):
    own = f"http://127.0.0.1:{srv.port}"
    assert server_fuzz.json_post(srv, "/api/transition", {"a": "walk", "b": "run"}, Origin=own)[0] == 200
    assert server_fuzz.json_post(srv, "/api/transition", {"a": "walk", "b": "run"})[0] == 200
    status, text = server_fuzz.request(srv, "GET", "/api/export?a=walk&b=run&method=spline",
                                       headers={"Sec-Fetch-Site": "same-origin"})
    assert status == 200 and text.startswith(b"HIERARCHY")
    # Another site may link to the page (a navigation), not use the API.
    assert server_fuzz.request(srv, "GET", "/", headers={"Sec-Fetch-Site": "cross-site"})[0] == 200


def test_issue12_seeded_random_requests_never_5xx(srv):
    result = server_fuzz.fuzz(srv, 300, seed=0)
    assert result["5xx_or_errors"] == 0, result
    assert result["log_problems"] == []
    statuses = {int(k) for k in result["statuses"]}
    assert {200, 403, 415, 422} <= statuses  # the mix reaches the work, the guards and the validation


@pytest.mark.slow  # seconds of waiting or a second full run: `make test-slow`
def test_issue12_trickling_client_does_not_block_others(srv):
    result = server_fuzz.trickle_does_not_block(srv, 2.0)
    statuses = [s for _, s in result["latencies"]]
    assert len(statuses) >= 3 and set(statuses) == {200}


# -- in-process: timeouts and concurrency (short limits) --------------------------------------
@pytest.fixture(scope="module")
def app(sample_clips):
    from posturemap.learn.model import PostureMap

    model = PostureMap(seed=0).fit(list(sample_clips.values()), list(sample_clips))
    return web.create_app(sample_clips, model)


def test_issue12_header_timeout_closes_a_trickling_connection(app, monkeypatch):
    monkeypatch.setattr(guards, "HEADER_TIMEOUT", 0.5)
    with web.running(app) as base:
        port = int(base.rsplit(":", 1)[1])
        s = socket.create_connection(("127.0.0.1", port), timeout=5)
        s.sendall(b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # never finishes its headers
        t0 = time.monotonic()
        assert s.recv(1024) == b""  # closed by the server
        assert time.monotonic() - t0 < 4
        s.close()
        # A complete request on a fresh connection is still answered.
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
        conn.request("GET", "/api/status")
        assert conn.getresponse().status == 200
        conn.close()


def test_issue12_body_timeout_is_408(app, monkeypatch):
    monkeypatch.setattr(guards, "BODY_TIMEOUT", 0.5)
    with web.running(app) as base:
        port = int(base.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
            s.sendall(b"POST /api/transition HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                      b"Content-Length: 100\r\n\r\n{")
            reply = s.recv(4096)
        assert reply.startswith(b"HTTP/1.1 408")


def test_engine_pool_shares_clips_and_keeps_buffers_apart(app):
    studio = app.state.studio
    engines = []
    while True:
        try:
            engines.append(studio._pool.get_nowait())
        except Exception:  # noqa: BLE001 - queue.Empty
            break
    for e in engines:
        studio._pool.put(e)
    assert len(engines) == POOL_SIZE >= 2
    shared = studio.engine.tracks  # the same prepared clips (each engine its own list of them)
    assert all(e.model is studio.engine.model and e.tracks.keys() == shared.keys()
               and all(e.tracks[n] is t for n, t in shared.items()) for e in engines)
    assert len({id(e) for e in engines}) == len(engines)


def test_concurrent_requests_give_the_sequential_answers(app):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from starlette.testclient import TestClient
    bodies = [{"a": a, "b": b, "length": n, "alpha": al, "method": m}
              for a, b, n, al, m in [("walk", "run", 20, 0.2, "upm"), ("run", "wave", 20, 0.8, "upm"),
                                     ("wave", "walk", 33, 0.5, "spline"), ("walk", "wave", 20, 0.5, "upm")]]
    with TestClient(app) as client:
        expected = [client.post("/api/transition", json=b).json()["inbetween"] for b in bodies]
        results = [[None] * len(bodies) for _ in range(6)]

        def worker(k):
            for i in np.random.default_rng(k).permutation(len(bodies)):
                results[k][i] = client.post("/api/transition", json=bodies[i]).json()["inbetween"]

        threads = [threading.Thread(target=worker, args=(k,)) for k in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    for got in results:
        assert got == expected
