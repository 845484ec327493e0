"""Local web server of the transition studio (``posturemap serve``).

One :class:`~posturemap.synth.engine.TransitionEngine` holds every clip and the posture map in
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

``alignment`` is ``{joint, up, turn, shift}``: on each of B's frames the joint ``joint`` (the top
of the root joint's chain) is turned by ``turn`` radians about the axis ``up`` (0, 1, 2 for x, y,
z): its rotation is premultiplied by that turn and its translation turned, then ``shift`` is
added to the translation. The export writes the same change into the root joint instead; the
world pose of every joint from the root down is the same.

Bad input never gives a 500: invalid JSON is 400, an unknown clip 404, a body over
:data:`MAX_BODY` bytes 413, a body not sent within :data:`BODY_TIMEOUT` seconds 408, a POST
whose ``Content-Type`` is not ``application/json`` 415, headers over :data:`MAX_HEADER_BYTES`
431, wrong types or values out of range 422,
and a keyed method asked for while the map is still training 503.

Cross-site requests are refused with 403: a request whose ``Origin`` is not the server's own
(``http://<Host>``), and a request to ``/api/`` that the browser marks ``Sec-Fetch-Site:
cross-site`` or ``same-site`` (a page elsewhere cannot make the studio work or read its
exports). Requests without these headers (curl, scripts) are served. A foreign ``Host``
header is refused with 400 when bound to this machine (DNS rebinding).

The server (:func:`server_for`) closes a connection whose request headers are not complete within
:data:`HEADER_TIMEOUT` seconds and an idle keep-alive connection after
:data:`KEEP_ALIVE_TIMEOUT`; a client that disconnects mid-request is dropped quietly.
Requests run concurrently: each transition takes an engine from a small pool
(:data:`POOL_SIZE` copies sharing the clips' tracks and the map, each with its own output
buffers), so no lock is held while one is computed.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import hashlib
import json
import os
import queue
import re
import socket
import sys
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io import bvh
from ..errors import UserError
from ..core.motion import Motion, body_height, concatenate, length_unit, root_index, up_axis
from ..synth.engine import TransitionEngine
from ..synth.request import FIELDS as REQUEST_FIELDS
from ..synth.request import (DEFAULT_ALPHA, DEFAULT_LENGTH, DEFAULT_METHOD, KEYED, METHODS, RequestError,
                             TransitionRequest, describe)

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

STATIC_DIR = Path(__file__).resolve().parent / "static"
VENDOR_FILES = ("three.module.js", "three.core.js", "addons/controls/OrbitControls.js")
MAX_BODY = 64 * 1024          # bytes of a request body
BODY_TIMEOUT = 10.0           # seconds to receive a request body
HEADER_TIMEOUT = 10.0         # seconds to receive a request's headers
KEEP_ALIVE_TIMEOUT = 5        # seconds an idle keep-alive connection stays open
MAX_HEADER_BYTES = 16 * 1024  # request headers (431 beyond)


def _pool_size() -> int:
    """Transition engines working at once: ``$POSTUREMAP_ENGINES`` (1..64) or 2..4 by cores."""
    text = os.environ.get("POSTUREMAP_ENGINES", "")
    if text.strip().isdigit() and 1 <= int(text) <= 64:
        return int(text)
    return max(2, min(4, os.cpu_count() or 1))


POOL_SIZE = _pool_size()
MAX_LENGTH = 600              # in-between frames (20 s at 30 fps)
FIELDS = ("a", "b") + REQUEST_FIELDS
EXPORT_FORMATS = {"bvh": "text/plain; charset=utf-8", "glb": "model/gltf-binary", "gltf": "model/gltf+json"}
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
_RESERVED = re.compile(r"[\[\]\.:/]")


class ApiError(Exception):
    """A request the server refuses: HTTP status, message and the field at fault (if any)."""

    def __init__(self, status: int, message: str, field: str | None = None):
        super().__init__(message)
        self.status, self.message, self.field = status, message, field


@dataclass(frozen=True)
class Params:
    """A validated transition request: the clips' names and the resolved request (frame indices
    into the source clips, defaults filled in)."""

    a: str
    b: str
    request: TransitionRequest


def bone_names(names: tuple[str, ...]) -> list[str]:
    """Joint names made safe and unique for three.js track names (``PropertyBinding``)."""
    out, seen = [], set()
    for i, n in enumerate(names):
        b = _RESERVED.sub("", re.sub(r"\s", "_", n)) or f"joint{i}"
        base, k = b, 2
        while b in seen:
            b, k = f"{base}_{k}", k + 1
        seen.add(b)
        out.append(b)
    return out


# -- the studio state ---------------------------------------------------------------------
class Studio:
    """Clips, the posture map and one transition engine shared by all requests.

    Parameters
    ----------
    clips : dict of name to Motion, one skeleton (the first clip's) and, for transitions
        between two clips, one frame rate
    model : PostureMap or None; None learns one from the clips in a background thread
        (when ``train``), so the page loads at once
    train : learn a map when ``model`` is None (False: only the methods without a key)
    epochs, seed : training parameters of that map
    log : function taking one line of text (progress in the terminal), or None
    """

    def __init__(self, clips: dict[str, Motion], model=None, train: bool = True, epochs: int = 4,
                 seed: int = 0, log=None):
        if not clips:
            raise UserError("serve", "no clips to serve")
        self.log = log or (lambda line: None)
        self.clips = dict(clips)
        self.names = list(self.clips)          # listing order
        first_name, first = next(iter(self.clips.items()))
        self.skeleton = first.skeleton
        for name, m in self.clips.items():
            if not m.skeleton.same_as(self.skeleton):
                raise UserError(name, f"skeleton differs from {first_name} (the studio needs one skeleton)")
        if model is not None:
            model.check_skeleton(self.skeleton, first_name)
        self.bones = bone_names(self.skeleton.names)
        self.rest = first.positions[0].copy()
        self.root, self.up = root_index(first), up_axis(first)
        self.height = body_height(first)
        self.unit = length_unit(first, self.height)
        if model is not None and (model.space_.up, model.space_.root) != (self.up, self.root):
            self.log(f"posturemap: warning: the map takes root {self.skeleton.names[model.space_.root]!r} and "
                     f"up {'XYZ'[model.space_.up]} but the clips read as root {self.skeleton.names[self.root]!r}, "
                     f"up {'XYZ'[self.up]}: transitions may not line up")
        self._lock = threading.Lock()  # guards the status and the swap of engines, not the work
        self.engine = self._engine(model)
        self._pool = self._make_pool(self.engine)
        self._status = {"state": "ready" if model is not None else ("loading" if train else "none"),
                        "progress": 1.0 if model is not None else 0.0, "epochs": epochs, "classes": {},
                        "neurons": sum(model.neuron_counts()) if model is not None else 0,
                        "seconds": None, "message": ""}
        self._started = time.perf_counter()
        if model is None and train:
            self._thread = threading.Thread(target=self._train, args=(epochs, seed), daemon=True,
                                            name="posturemap-train")
            self._thread.start()

    def _engine(self, model) -> TransitionEngine:
        engine = TransitionEngine(model, None if model is not None else self.skeleton)
        for name, m in self.clips.items():
            engine.add(name, m)
        name = next(iter(self.clips))
        # Compile the kernels now rather than on the first request.
        engine.generate(name, name, length=2, method=KEYED[0] if model is not None else "spline")
        return engine

    @staticmethod
    def _make_pool(engine: TransitionEngine) -> queue.SimpleQueue:
        """:data:`POOL_SIZE` engines: ``engine`` and copies that share its tracks and map.

        An engine reuses its output buffers between calls, so one engine serves one request at
        a time; the copies have their own buffers and caches, the clips and the map are shared
        (read-only).
        """
        pool = queue.SimpleQueue()
        pool.put(engine)
        for _ in range(POOL_SIZE - 1):
            pool.put(engine.fork())
        return pool

    # -- training ---------------------------------------------------------------------------
    def _train(self, epochs: int, seed: int):
        from ..learn.model import PostureMap

        frames = sum(len(m) for m in self.clips.values())
        self._set_status(state="training", message=f"learning a posture map from {len(self.clips)} clips "
                                                   f"({frames} frames)")
        self.log(f"training posture map: {len(self.clips)} clips, {frames} frames, {epochs} epochs")
        shown = [0]

        def progress(cls: str, epoch: int, total: int, neurons: int):
            with self._lock:
                classes = self._status["classes"]
                classes[cls] = {"epoch": epoch, "neurons": neurons}
                self._status["progress"] = round(min(sum(c["epoch"] for c in classes.values()) / (4.0 * total), 1.0), 4)
                self._status["neurons"] = sum(c["neurons"] for c in classes.values())
                epoch_done = min(c["epoch"] for c in classes.values()) if len(classes) == 4 else 0
                parts = ", ".join(f"{c} {v['neurons']}" for c, v in sorted(classes.items()))
            if epoch_done > shown[0]:
                shown[0] = epoch_done
                self.log(f"training posture map: epoch {epoch_done}/{total}  neurons: {parts}")

        try:
            model = PostureMap(epochs=epochs, seed=seed).fit(list(self.clips.values()), list(self.clips),
                                                              progress=progress)
            engine = self._engine(model)
            pool = self._make_pool(engine)
        except Exception as e:  # noqa: BLE001 - reported on the page and in the terminal
            self._set_status(state="error", message=f"training failed: {e}")
            self.log(f"posturemap: error: training the posture map failed: {e}")
            return
        seconds = round(time.perf_counter() - self._started, 2)
        with self._lock:
            self.engine, self._pool = engine, pool
            self._status.update(state="ready", progress=1.0, neurons=sum(model.neuron_counts()),
                                seconds=seconds, message="")
        self.log(f"posture map ready: {sum(model.neuron_counts())} neurons "
                 f"({', '.join(str(n) for n in model.neuron_counts())}) in {seconds:.1f} s")

    def _set_status(self, **kw):
        with self._lock:
            self._status.update(kw)

    def status(self) -> dict:
        with self._lock:
            s = dict(self._status)
            s["classes"] = {k: dict(v) for k, v in s["classes"].items()}
        s["methods"] = {m: (m not in KEYED or s["state"] == "ready") for m in METHODS}
        return s

    def wait_ready(self, timeout: float = 60.0) -> dict:
        """Block until the map is trained (or failed); returns the status (for tests and scripts)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            s = self.status()
            if s["state"] in ("ready", "error", "none"):
                return s
            time.sleep(0.02)
        return self.status()

    # -- descriptions -------------------------------------------------------------------------
    def clips_payload(self) -> dict:
        sk = self.skeleton
        return {
            "skeleton": {
                "names": list(sk.names), "bones": self.bones, "parents": sk.parents.tolist(),
                "rest": np.round(self.rest, 6).tolist(),
                "end_sites": [[int(j), np.round(o, 6).tolist()] for j, o in sk.end_sites],
                "up": int(self.up), "root": int(self.root), "height": round(self.height, 4),
                "unit": self.unit,
            },
            "clips": [{"name": n, "frames": len(self.clips[n]), "fps": float(self.clips[n].fps),
                       "duration": round(len(self.clips[n]) / self.clips[n].fps, 6)} for n in self.names],
            "methods": list(METHODS), "keyed": list(KEYED), "default_method": DEFAULT_METHOD,
            "defaults": {"length": DEFAULT_LENGTH, "alpha": DEFAULT_ALPHA, "align": True, "foot_lock": True},
            "limits": {"length": [1, MAX_LENGTH], "body_bytes": MAX_BODY},
            "status": self.status(),
        }

    def clip_payload(self, name: str) -> dict:
        m = self._clip(name, "name")
        return {"name": name, "frames": len(m), "fps": float(m.fps),
                **self.tracks(m.rotations, m.positions, m.fps)}

    def tracks(self, rotations: np.ndarray, positions: np.ndarray, fps: float) -> dict:
        """three.js tracks of local rotations (F, J, 4) (w, x, y, z) and translations (F, J, 3)."""
        n = len(rotations)
        q = rotations[..., [1, 2, 3, 0]]
        # One hemisphere per joint over time (three.js slerps the short way anyway; plots need it).
        dots = np.einsum("fjc,fjc->fj", q[1:], q[:-1])
        sign = np.cumprod(np.where(dots < 0, -1.0, 1.0), axis=0)
        q = q.copy()
        q[1:] *= sign[..., None]
        qv = np.round(q, 6).transpose(1, 0, 2).reshape(len(self.bones), -1).tolist()
        moving = np.flatnonzero(np.any(np.abs(positions - self.rest) > 1e-6, axis=(0, 2)))
        pv = np.round(positions[:, moving], 4).transpose(1, 0, 2).reshape(len(moving), -1).tolist()
        tracks = [{"name": f"{b}.quaternion", "type": "quaternion", "values": v} for b, v in zip(self.bones, qv)]
        tracks += [{"name": f"{self.bones[j]}.position", "type": "vector", "values": v} for j, v in zip(moving, pv)]
        return {"fps": float(fps), "frames": n, "duration": round(max(n - 1, 0) / fps, 6),
                "times": (np.arange(n) / fps).tolist(), "tracks": tracks}

    # -- requests -----------------------------------------------------------------------------
    def _clip(self, name, field: str) -> Motion:
        if not isinstance(name, str):
            raise ApiError(422, f"{field}: must be a clip name (a string), got {describe(name)}", field)
        if name not in self.clips:
            shown = name if len(name) <= 80 else name[:77] + "..."
            raise ApiError(404, f"{field}: unknown clip {shown!r} (GET /api/clips lists them)", field)
        return self.clips[name]

    def params(self, raw: dict) -> Params:
        """Validate a request body (a dict from JSON); raises :class:`ApiError`."""
        if not isinstance(raw, dict):
            raise ApiError(422, f"body must be a JSON object, got {describe(raw)}")
        unknown = sorted(str(k) for k in raw if k not in FIELDS)
        if unknown:
            shown = ", ".join(repr(k[:40]) for k in unknown[:5])
            raise ApiError(422, f"unknown field {shown} (fields: {', '.join(FIELDS)})", unknown[0][:40])
        for f in ("a", "b"):
            if f not in raw:
                raise ApiError(422, f"{f}: missing (name of clip {f.upper()})", f)
        ma, mb = self._clip(raw["a"], "a"), self._clip(raw["b"], "b")
        if abs(ma.fps - mb.fps) > 1e-6 * ma.fps:
            raise ApiError(422, f"clips {raw['a']!r} ({ma.fps:g} fps) and {raw['b']!r} ({mb.fps:g} fps) "
                                f"have different frame rates", "b")
        try:
            req = TransitionRequest.from_fields(raw).resolved(len(ma), len(mb), max_length=MAX_LENGTH,
                                                              names=(raw["a"], raw["b"]))
        except RequestError as e:
            raise ApiError(422, f"{e.field}: {e.what}", e.field) from None
        return Params(raw["a"], raw["b"], req)

    def _new_frames(self, p: Params, with_b: bool = False):
        """The in-between frames and how B continues A.

        Returns rotations (L, J, 4) and positions (L, J, 3) of the new frames, the engine's
        ``last``, the map's keyed joints (or None), B's part (a Motion, turned and moved when
        ``align``; only ``with_b``, else None) and the alignment ``(top joint, up axis, turn,
        shift)``.
        """
        with self._lock:
            pool = self._pool
            s = dict(self._status)
        engine = pool.get()  # blocks only while all POOL_SIZE engines are busy
        try:
            req = p.request
            if req.keyed and engine.model is None:
                if s["state"] == "training":
                    raise ApiError(503, f"method: {req.method!r} needs the posture map, still training "
                                        f"({100 * s['progress']:.0f}%); try again in a moment", "method")
                raise ApiError(503, f"method: {req.method!r} needs a posture map and none is available"
                                    + (f" ({s['message']})" if s["message"] else ""), "method")
            try:
                rots, pos = engine.generate(p.a, p.b, req)
            except RequestError as e:
                raise ApiError(422, f"{e.field}: {e.what}", e.field) from None
            rots, pos = rots.copy(), pos.copy()
            last = dict(engine.last)
            keyed_joints = engine.model.space_.joints.copy() if engine.model is not None else None
            if req.align:
                turn, shift = float(last["dtheta"]), np.asarray(last["shift"], dtype=np.float64)
            else:
                turn, shift = 0.0, np.zeros(3)
            b_part = engine.continuation(p.b, req.b_start, req.align) if with_b else None
            top = engine.alignment_joint
            up = engine.up
        finally:
            pool.put(engine)
        return rots, pos, last, keyed_joints, b_part, (top, up, turn, shift)

    def generate(self, p: Params):
        """The whole result as one Motion: A[0..a_end], the new frames, then B's part."""
        rots, pos, _, _, b_part, _ = self._new_frames(p, with_b=True)
        a = self.clips[p.a]
        return concatenate([a[: p.request.a_end + 1], Motion(a.skeleton, rots, pos, a.fps),
                            Motion(a.skeleton, b_part.rotations, b_part.positions, a.fps)])

    def transition(self, p: Params) -> dict:
        """The answer to ``POST /api/transition``: the new frames as tracks, plus how to join them.

        The result is A's frames 0..a_end, the ``inbetween`` frames, then B's frames b_start..
        with ``alignment`` applied: the joint ``alignment.joint`` (the top of the root's chain)
        turned by ``turn`` radians about the up axis, then moved by ``shift``. Clip frames come
        from ``GET /api/clip/{name}``, so an answer stays small however long the clips are.
        """
        rots, pos, last, keyed_joints, _, (top, up, turn, shift) = self._new_frames(p)
        t0, t1 = p.request.a_end + 1, p.request.a_end + p.request.length
        fps = float(self.clips[p.a].fps)
        frames = p.request.a_end + 1 + p.request.length + len(self.clips[p.b]) - p.request.b_start
        key = None
        if last.get("key") is not None:
            krots, height = last["key"]
            key = {"frame": p.request.a_end + p.request.key_at, "index": p.request.key_at,
                   "joints": [self.skeleton.names[j] for j in keyed_joints],
                   "bones": [self.bones[j] for j in keyed_joints],
                   "quaternions": np.round(krots[:, [1, 2, 3, 0]], 6).tolist(),
                   "root_height": round(float(height), 4),
                   "neurons": [int(k) for k in last["neurons"]]}
        return {
            "a": p.a, "b": p.b, "method": p.request.method,
            "params": {"a_end": p.request.a_end, "b_start": p.request.b_start, "length": p.request.length, "key_at": p.request.key_at,
                       "alpha": p.request.alpha, "align": p.request.align, "foot_lock": p.request.foot_lock},
            "fps": fps, "frames": frames, "duration": round((frames - 1) / fps, 6),
            "segments": {"a": [0, p.request.a_end], "transition": [t0, t1], "b": [t1 + 1, frames - 1]},
            "transition": [t0, t1],
            "seams": [p.request.a_end, t1 + 1],
            "key_frame": key["frame"] if key else None,
            "key": key,
            **({"retrieval": last["retrieval"], "method_used": last.get("method", p.request.method)}
               if "retrieval" in last else {}),
            "source": {"a": [0, p.request.a_end], "b": [p.request.b_start, len(self.clips[p.b]) - 1]},
            "alignment": {"joint": self.bones[top], "up": up, "turn": round(turn, 9),
                          "shift": np.round(shift, 6).tolist()},
            "inbetween": self.tracks(rots, pos, fps),
        }

    def export(self, p: Params, fmt: str = "bvh") -> tuple[bytes, str, str]:
        """The result as a file: its bytes, a file name and a media type.

        ``fmt`` is one of :data:`EXPORT_FORMATS`: ``bvh`` (the clips' skeleton and channels),
        ``glb`` or ``gltf`` (glTF 2.0 in metres, Y up: the whole result as one animation, then
        A's part, the transition and B's part as three more; see :mod:`posturemap.io.gltf`).
        A result the writers refuse (non-finite values) is a 422.
        """
        out = self.generate(p)
        stem = re.sub(r"[^A-Za-z0-9._-]+", "_", f"{p.a}_to_{p.b}_{p.request.method}")[:120]
        try:
            if fmt == "bvh":
                return bvh.dumps(out).encode("utf-8"), stem + ".bvh", EXPORT_FORMATS[fmt]
            from ..io import gltf

            parts = gltf.transition_parts(p.request.a_end + 1, p.request.length, len(out))
            data = gltf.dumps(out, binary=fmt == "glb", parts=parts, split=True, up=self.up,
                              name=re.sub(r"[^A-Za-z0-9._-]+", "_", f"{p.a}_to_{p.b}")[:120])
        except UserError as e:  # the writers refuse non-finite values
            raise ApiError(422, e.what) from None
        return data, f"{stem}.{fmt}", EXPORT_FORMATS[fmt]


def export_format(raw) -> str:
    """Take the export's ``format`` field out of a request body (default ``bvh``); raises
    :class:`ApiError` (422) for anything but a name in :data:`EXPORT_FORMATS`."""
    fmt = raw.pop("format", None) if isinstance(raw, dict) else None
    if fmt is None:
        return "bvh"
    if not isinstance(fmt, str) or fmt not in EXPORT_FORMATS:
        got = repr(fmt[:40]) if isinstance(fmt, str) else describe(fmt)
        raise ApiError(422, f"format: unknown export format {got} (choose from {', '.join(EXPORT_FORMATS)})",
                       "format")
    return fmt


def query_params(query) -> dict:
    """Request fields from a query string (numbers and booleans parsed from text)."""
    raw = {}
    for k, v in query.multi_items():
        if k in raw:
            raise ApiError(422, f"{k[:40]}: given more than once", k[:40])
        if k in ("a_end", "b_start", "length", "key_at"):
            if not re.fullmatch(r"[+-]?\d{1,12}", v.strip()):
                raise ApiError(422, f"{k}: must be a whole number, got {v[:40]!r}", k)
            raw[k] = int(v)
        elif k == "alpha":
            try:
                raw[k] = float(v)
            except ValueError:
                raise ApiError(422, f"alpha: must be a number between 0 and 1, got {v[:40]!r}", k) from None
        elif k == "align":
            if v.lower() not in ("true", "false", "1", "0"):
                raise ApiError(422, f"align: must be true or false, got {v[:40]!r}", k)
            raw[k] = v.lower() in ("true", "1")
        else:
            raw[k] = v
    return raw


def _reject_constant(name: str):
    raise ValueError(f"{name} is not a JSON number")


class Disconnected(Exception):
    """The client went away before its request was read (answered quietly: nobody listens)."""


def _is_json(content_type: str) -> bool:
    return content_type.split(";", 1)[0].strip().lower() == "application/json"


async def read_json(request) -> object:
    """The request body as JSON.

    415 unless ``Content-Type: application/json`` (a cross-site form cannot send that without
    the browser asking first), 413 over :data:`MAX_BODY` bytes, 408 when the body takes longer
    than :data:`BODY_TIMEOUT` seconds, 400 when not valid JSON; :class:`Disconnected` when the
    client leaves.
    """
    if not _is_json(request.headers.get("content-type", "")):
        raise ApiError(415, "send the body as JSON with 'Content-Type: application/json'")
    try:
        async with asyncio.timeout(BODY_TIMEOUT):
            body = await _read_body(request)
    except TimeoutError:
        raise ApiError(408, f"request body not received within {BODY_TIMEOUT:g} s") from None
    except ClientDisconnect:
        raise Disconnected from None
    if not body.strip():
        raise ApiError(400, "empty body: send a JSON object")
    try:
        return json.loads(bytes(body), parse_constant=_reject_constant)
    except RecursionError:
        raise ApiError(400, "body is not valid JSON (nested too deeply)") from None
    except (ValueError, UnicodeDecodeError) as e:
        raise ApiError(400, f"body is not valid JSON ({str(e)[:120]})") from None


async def _read_body(request) -> bytearray:
    """The body, at most :data:`MAX_BODY` bytes (413 beyond, from the header or while streaming)."""
    declared = request.headers.get("content-length")
    if declared is not None:
        if not declared.strip().isdigit():
            raise ApiError(400, "bad Content-Length header")
        if int(declared) > MAX_BODY:
            raise ApiError(413, f"request body too large ({int(declared)} bytes; at most {MAX_BODY})")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY:
            raise ApiError(413, f"request body too large (at most {MAX_BODY} bytes)")
    return body


# -- the application ----------------------------------------------------------------------
def _page_policy() -> str:
    """Content-Security-Policy of the page: own files only, plus the page's inline import map."""
    hashes = ""
    index = STATIC_DIR / "index.html"
    if index.is_file():
        for block in re.findall(r'<script type="importmap">(.*?)</script>', index.read_text("utf-8"), re.DOTALL):
            digest = base64.b64encode(hashlib.sha256(block.encode("utf-8")).digest()).decode()
            hashes += f" 'sha256-{digest}'"
    return ("default-src 'self'; script-src 'self'" + hashes + "; style-src 'self'; "
            "img-src 'self' data: blob:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
            "form-action 'none'; frame-ancestors 'none'")


def cross_site(headers: dict, path: str) -> str | None:
    """Why a request must be refused as cross-site, or None (see the module docstring).

    ``headers`` maps lower-case header names to values (bytes). A browser sends ``Origin``
    on every POST and on cross-origin fetches; it must be this server's own origin
    (``http://`` or ``https://`` plus the ``Host`` header). ``Sec-Fetch-Site`` covers requests
    without ``Origin`` (an ``<img>`` or ``<script>`` pointing at ``/api/export``): other sites
    may link to the page, not use the API.
    """
    origin = headers.get(b"origin")
    if origin is not None:
        host = headers.get(b"host", b"").decode("latin-1").lower()
        if origin.decode("latin-1").lower() not in (f"http://{host}", f"https://{host}"):
            return f"cross-origin request from {origin.decode('latin-1')[:80]!r} refused"
    site = headers.get(b"sec-fetch-site", b"").lower()
    if path.startswith("/api/") and site in (b"cross-site", b"same-site"):
        return f"cross-site request ({site.decode('latin-1')}) to the API refused"
    return None


class _Guard:
    """ASGI middleware: refuses foreign Host headers (DNS rebinding) and cross-site requests
    (:func:`cross_site`), and adds security headers."""

    def __init__(self, app, allowed_hosts=None):
        self.app = app
        self.allowed = None if allowed_hosts is None else {h.lower() for h in allowed_hosts}
        self.headers = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer"),
                        (b"x-frame-options", b"DENY"),
                        (b"content-security-policy", _page_policy().encode())]

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        if sum(len(k) + len(v) + 4 for k, v in scope["headers"]) > MAX_HEADER_BYTES:
            resp = JSONResponse({"error": f"request headers larger than {MAX_HEADER_BYTES} bytes", "field": None}, 431)
            return await resp(scope, receive, send)
        headers = dict(scope["headers"])
        refused = cross_site(headers, scope.get("path", ""))
        if refused:
            return await JSONResponse({"error": refused, "field": None}, 403)(scope, receive, send)
        if self.allowed is not None:
            host = headers.get(b"host", b"").decode("latin-1").lower()
            name = host[1:].split("]")[0] if host.startswith("[") else host.rsplit(":", 1)[0]
            if name not in self.allowed:
                resp = JSONResponse({"error": f"unexpected Host header {host[:80]!r}", "field": None}, 400)
                return await resp(scope, receive, send)
        extra = self.headers

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                message = dict(message)
                message["headers"] = list(message.get("headers", [])) + extra
            await send(message)

        return await self.app(scope, receive, send_with_headers)


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
        raise UserError("serve", "needs the web extra: pip install 'posturemap[web]'")
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
    app = Starlette(routes=routes, middleware=[Middleware(_Guard, allowed_hosts=allowed_hosts)],
                    exception_handlers={ApiError: api_error, HTTPException: http_error, Disconnected: disconnected,
                                        ClientDisconnect: disconnected, Exception: server_error})
    app.state.studio = studio
    return app


# -- command line -------------------------------------------------------------------------
def load_clips(inputs: list[str], log=None) -> dict[str, Motion]:
    """Clips by name from BVH files and folders (default: the bundled sample).

    Names are the file names without ``.bvh`` (made unique). Clips whose skeleton differs from
    the first one's are left out with a note through ``log``.
    """
    log = log or (lambda line: None)
    if not inputs:
        from .. import sample
        return sample.clips()

    out: dict[str, Motion] = {}
    first = None
    for path, m in bvh.read_inputs(inputs):
        if first is None:
            first = (path, m.skeleton)
        elif not m.skeleton.same_as(first[1]):
            log(f"posturemap: note: {path}: left out, its skeleton differs from {first[0]}")
            continue
        name = base = Path(path).stem
        k = 2
        while name in out:
            name, k = f"{base}-{k}", k + 1
        out[name] = m
    return out


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


def _timed_h11():
    """uvicorn's h11 protocol with a deadline for each request's headers (a trickling client is cut off)."""
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class TimedH11Protocol(H11Protocol):
        _header_timer = None

        def connection_made(self, transport):
            super().connection_made(transport)
            self._arm()

        def _arm(self):
            if self._header_timer is None:
                self._header_timer = self.loop.call_later(HEADER_TIMEOUT, self._headers_too_slow)

        def _disarm(self):
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _headers_too_slow(self):
            self._header_timer = None
            if not self.transport.is_closing():
                self.transport.close()

        def data_received(self, data: bytes) -> None:
            cycle = self.cycle
            if cycle is None or cycle.response_complete:
                self._arm()  # bytes of a new request: its headers must come in time
            super().data_received(data)
            if self.cycle is not cycle:  # a request's headers were parsed
                self._disarm()

        def connection_lost(self, exc):
            self._disarm()
            super().connection_lost(exc)

    return TimedH11Protocol


def server_for(app):
    """A uvicorn server for ``app`` with the studio's limits: header and keep-alive timeouts,
    h11's buffer for an incomplete request head at :data:`MAX_HEADER_BYTES` (``_Guard`` checks
    the size of a complete one), no access log."""
    import uvicorn

    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off", http=_timed_h11(),
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
        raise UserError("serve", "needs the web extra: pip install 'posturemap[web]'")
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
    frames = sum(len(m) for m in clips.values())
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


__all__ = [
    "MAX_BODY",
    "MAX_LENGTH",
    "ApiError",
    "Params",
    "Studio",
    "bone_names",
    "create_app",
    "cross_site",
    "load_clips",
    "run_cli",
    "running",
    "server_for",
]
