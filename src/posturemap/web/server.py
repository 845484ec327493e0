"""Local web server of the transition studio (``posturemap serve``).

A small pool of :class:`~posturemap.synth.engine.TransitionEngine` (:meth:`TransitionEngine.fork
<posturemap.synth.engine.TransitionEngine.fork>`) holds every clip and the posture map in
memory; the page asks for transitions as its sliders move and gets three.js-ready tracks back.

Endpoints (JSON unless noted; every error is ``{"error": message, "field": name or null}``):

``GET /``                    the studio page (``static/index.html``)
``GET /static/...``          the page's own files, from one fixed folder
``GET /api/status``          posture map state: ``loading``, ``training`` (with progress), ``ready``
                             or ``error``
``GET /api/clips``           the skeleton (names, parents, rest translations, end sites, up axis)
                             and the clips (name, frames, fps), the methods and the limits
``GET /api/clip/{name}``     one clip's frames as tracks
``POST /api/transition``     body ``{a, b, a_end, b_start, length, key_at, alpha, method, align,
                             foot_lock}``: the result is A[0..a_end], ``length`` new frames, then
                             B[b_start..] (turned and moved to continue A unless ``align`` is
                             false). The answer carries the new frames as tracks (``inbetween``),
                             the ``alignment`` to apply to B's frames, the segments, the seams and
                             the key posture; the clips' own frames come from ``/api/clip``
``POST /api/export``         the same body plus ``format``: ``bvh`` (default; ``text/plain``), ``glb``
``GET /api/export?a=..``     (``model/gltf-binary``) or ``gltf`` (``model/gltf+json``); answers the
                             result as an attachment, the body fields as query parameters for GET

Tracks follow three.js: one ``<bone>.quaternion`` track per joint with local rotations in the
order (x, y, z, w), and a ``<bone>.position`` track for each joint whose local translation moves
(the others keep their rest translation from ``/api/clips``); ``times`` in seconds is shared.
Bone names are the joint names made safe for three.js's ``PropertyBinding`` (``bones`` in the
skeleton). Positions are in the clips' own length unit.

``alignment`` is ``{joint, up, turn, shift, rotation, translation}``: B is turned by ``turn``
radians about the axis ``up`` (0, 1, 2 for x, y, z), then moved by ``shift``. On each of B's
frames that is one joint's change: the local rotation of ``joint`` is premultiplied by
``rotation`` (x, y, z, w) and its local translation turned by it, then ``translation`` is added.
``joint`` is the top of the root joint's chain where that chain moves in B (it carries root
motion, as a game rig's root bone does; ``rotation`` is then the turn and ``translation`` the
shift), and the root joint otherwise (a fixed reference node above it stays where it is). The
export holds the same frames.

Bad input never gives a 500: invalid JSON (or not UTF-8, or an object naming a member twice) is
400, an unknown clip 404, a body over
:data:`~posturemap.web.guards.MAX_BODY` bytes 413, a body not sent within :data:`~posturemap.web.guards.BODY_TIMEOUT` seconds 408, a POST
whose ``Content-Type`` is not ``application/json`` 415, headers over :data:`~posturemap.web.guards.MAX_HEADER_BYTES`
431, wrong types or values out of range 422,
and a keyed method asked for while the map is still training 503.

Cross-site requests are refused with 403: a request whose ``Origin`` is not the server's own
(``http://<Host>``), and a request to ``/api/`` that the browser marks ``Sec-Fetch-Site:
cross-site`` or ``same-site`` (a page elsewhere cannot make the studio work or read its
exports). Requests without these headers (curl, scripts) are served. A foreign ``Host``
header is refused with 400 when bound to this machine (DNS rebinding).

The server (:func:`server_for`) closes a connection whose request headers are not complete within
:data:`~posturemap.web.guards.HEADER_TIMEOUT` seconds and an idle keep-alive connection after
:data:`~posturemap.web.guards.KEEP_ALIVE_TIMEOUT`; a client that disconnects mid-request is dropped quietly.
The routes are here; the studio's state and its answers are in :mod:`posturemap.web.studio`,
the checks on every request in :mod:`posturemap.web.guards`. Requests run concurrently: each transition takes an engine from a small pool
(:data:`~posturemap.web.studio.POOL_SIZE` copies sharing the clips' tracks and the map, each with its own output
buffers), so no lock is held while one is computed.
"""

from __future__ import annotations

import contextlib
import socket
import sys
import threading
import time
import traceback
from pathlib import Path

from ..core.motion import Motion
from ..errors import UserError
from .guards import (KEEP_ALIVE_TIMEOUT, MAX_HEADER_BYTES, ApiError, Disconnected, Guard, page_policy,
                     query_params, read_json, timed_h11)
from .studio import LOOPBACK_HOSTS, Studio, export_format, load_clips

try:  # the "web" extra
    from starlette.applications import Starlette
    from starlette.exceptions import HTTPException
    from starlette.middleware import Middleware
    from starlette.requests import ClientDisconnect
    from starlette.responses import FileResponse, JSONResponse, Response
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles
except ImportError:  # pragma: no cover - reported by run_cli / create_app
    Starlette = None
_NEEDS_WEB = "needs the web extra: pip install 'posturemap[web]' (in a checkout: pip install -e '.[web]')"

STATIC_DIR = Path(__file__).resolve().parent / "static"
VENDOR_FILES = ("three.module.js", "three.core.js", "addons/controls/OrbitControls.js")


def create_app(clips: dict[str, Motion], model=None, *, train: bool = True, epochs: int = 4, seed: int = 0,
               allowed_hosts=None, log=None):
    """The studio as an ASGI app (Starlette), for ``uvicorn`` or a test client.

    Parameters
    ----------
    clips : dict of name to Motion (one skeleton)
    model : PostureMap or None (None: learn one in a background thread when ``train``)
    train, epochs, seed : see :class:`Studio`
    allowed_hosts : Host header names to accept (None: any); ``run_cli`` passes the loopback
        names when bound to this machine only
    log : function taking one line of text, or None

    The :class:`Studio` is ``app.state.studio``.
    """
    if Starlette is None:
        raise UserError("serve", _NEEDS_WEB)
    studio = Studio(clips, model, train=train, epochs=epochs, seed=seed, log=log)
    from starlette.concurrency import run_in_threadpool

    async def index(request):
        if not (STATIC_DIR / "index.html").is_file():
            raise ApiError(404, "the studio page is missing from this installation")
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})

    async def status(request):
        return JSONResponse(studio.status())

    async def clips_list(request):
        return JSONResponse(studio.clips_payload())

    async def clip_one(request):
        return JSONResponse(await run_in_threadpool(studio.clip_payload, request.path_params["name"]))

    async def transition(request):
        p = studio.params(await read_json(request))
        return JSONResponse(await run_in_threadpool(studio.transition, p))

    async def export(request):
        raw = query_params(request.query_params) if request.method == "GET" else await read_json(request)
        fmt = export_format(raw)
        data, name, media = await run_in_threadpool(studio.export, studio.params(raw), fmt)
        return Response(data, media_type=media,
                        headers={"Content-Disposition": f'attachment; filename="{name}"',
                                 "Cache-Control": "no-store"})

    async def api_error(request, exc: ApiError):
        return JSONResponse({"error": exc.message, "field": exc.field}, exc.status)

    async def http_error(request, exc: HTTPException):
        return JSONResponse({"error": exc.detail, "field": None}, exc.status_code, headers=exc.headers)

    async def disconnected(request, exc: Exception):
        return Response(status_code=400)  # the client is gone: nothing to log, nobody reads this

    async def server_error(request, exc: Exception):
        if isinstance(exc, (Disconnected, ClientDisconnect)):
            return await disconnected(request, exc)
        studio.log("posturemap: internal error:\n" + "".join(traceback.format_exception(exc)).rstrip())
        return JSONResponse({"error": f"internal error ({type(exc).__name__})", "field": None}, 500)

    routes = [
        Route("/", index, methods=["GET", "HEAD"]),
        Route("/api/status", status, methods=["GET"]),
        Route("/api/clips", clips_list, methods=["GET"]),
        Route("/api/clip/{name:path}", clip_one, methods=["GET"]),
        Route("/api/transition", transition, methods=["POST"]),
        Route("/api/export", export, methods=["GET", "POST"]),
        Mount("/static", app=StaticFiles(directory=STATIC_DIR, check_dir=False), name="static"),
    ]
    app = Starlette(routes=routes, middleware=[Middleware(Guard, allowed_hosts=allowed_hosts,
                                                             policy=page_policy(STATIC_DIR / "index.html"))],
                    exception_handlers={ApiError: api_error, HTTPException: http_error, Disconnected: disconnected,
                                        ClientDisconnect: disconnected, Exception: server_error})
    app.state.studio = studio
    return app



# -- command line -------------------------------------------------------------------------
def _listen(host: str, port: int) -> socket.socket:
    if not 0 <= port <= 65535:
        raise UserError("--port", f"must be between 0 and 65535, got {port}")
    try:
        info = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as e:
        raise UserError("--host", f"cannot resolve {host!r} ({e.strerror})") from None
    family, kind, proto, _, addr = info[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        # Answers go out at once: without TCP_NODELAY (which asyncio sets only on sockets made
        # with proto IPPROTO_TCP) a small answer can wait 40 ms for the client's delayed ACK.
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.bind(addr)
        sock.listen(128)
    except OSError as e:
        sock.close()
        raise UserError(f"{host}:{port}", f"cannot listen ({e.strerror or e})") from None
    sock.set_inheritable(True)
    return sock


def server_for(app):
    """A uvicorn server for ``app`` with the studio's limits: header and keep-alive timeouts,
    h11's buffer for an incomplete request head at :data:`~posturemap.web.guards.MAX_HEADER_BYTES` (``Guard`` checks
    the size of a complete one), no access log."""
    import uvicorn

    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off", http=timed_h11(),
                            timeout_keep_alive=KEEP_ALIVE_TIMEOUT, h11_max_incomplete_event_size=MAX_HEADER_BYTES)
    return uvicorn.Server(config)


@contextlib.contextmanager
def running(app, host: str = "127.0.0.1", port: int = 0):
    """Serve ``app`` with uvicorn in a background thread; yields the base URL (``http://host:port``).

    For tests, benchmarks and notebooks; port 0 takes a free port. The server stops on exit.
    """
    sock = _listen(host, port)
    srv = server_for(app)
    thread = threading.Thread(target=srv.run, kwargs={"sockets": [sock]}, daemon=True, name="posturemap-serve")
    thread.start()
    deadline = time.monotonic() + 20
    while not srv.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            sock.close()
            raise RuntimeError(f"the studio server did not start on {host}:{port}")
        time.sleep(0.01)
    try:
        shown = f"[{host}]" if ":" in host else host
        yield f"http://{shown}:{sock.getsockname()[1]}"
    finally:
        srv.should_exit = True
        thread.join(10)
        sock.close()


def run_cli(args) -> int:
    """``posturemap serve``: load the clips, the map (or learn one in the background) and serve."""
    if Starlette is None:
        raise UserError("serve", _NEEDS_WEB)
    import uvicorn

    def log(line: str):
        sys.stderr.write(line + "\n")
        sys.stderr.flush()

    missing = [f for f in VENDOR_FILES if not (STATIC_DIR / "vendor" / f).is_file()]
    if missing:
        log(f"posturemap: warning: {STATIC_DIR / 'vendor'} lacks three.js ({', '.join(missing)}); "
            "run `make web` in the repository (the page cannot draw without it)")
    from ..core import kernels
    kernels.compiled()  # many transitions (and maybe training) ahead: compiled kernels pay off
    clips = load_clips(args.inputs, log)
    model = None
    if args.map:
        from ..learn.model import PostureMap
        model = PostureMap.load(args.map)
        model.check_skeleton(next(iter(clips.values())).skeleton, next(iter(clips)))
    sock = _listen(args.host, args.port)
    local = args.host in LOOPBACK_HOSTS
    app = create_app(clips, model, allowed_hosts=LOOPBACK_HOSTS if local else None, log=log)
    port = sock.getsockname()[1]
    shown = f"[{args.host}]" if ":" in args.host else args.host
    frames = sum(len(m) for m in app.state.studio.clips.values())  # as served (resampled to one rate)
    print(f"posturemap studio: {len(clips)} clips ({frames} frames), "
          f"map {'from ' + args.map if args.map else 'learning in the background'}", flush=True)
    if not local:
        log(f"posturemap: warning: listening on {args.host}: other machines can reach the studio")
    print(f"open http://{shown}:{port}/  (Ctrl+C to stop)", flush=True)
    server = server_for(app)
    try:
        server.run(sockets=[sock])
    finally:
        sock.close()
    return 0


__all__ = ["STATIC_DIR", "create_app", "run_cli", "running", "server_for"]
