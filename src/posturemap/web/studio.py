"""The studio's state: clips, the posture map (trained in the background if none was given), a pool
of transition engines, and the answers of the API (clips and transitions as three.js tracks,
exports). Request bodies become a :class:`~posturemap.synth.request.TransitionRequest` here;
:mod:`posturemap.web.server` routes requests to these methods.
"""

from __future__ import annotations

import os
import queue
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.motion import (Motion, at_one_rate, body_height, concatenate, length_unit, resampled_note, root_index,
                           up_axis)
from ..errors import UserError
from ..io import bvh
from ..synth.engine import TransitionEngine
from ..synth.request import FIELDS as REQUEST_FIELDS
from ..synth.request import (DEFAULT_ALPHA, DEFAULT_LENGTH, DEFAULT_METHOD, KEYED, METHODS, RequestError,
                             TransitionRequest, describe)
from .guards import MAX_BODY, ApiError

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
    """Clips, the posture map and a pool of transition engines (forks sharing the clips and map)
    that serve the requests.

    Parameters
    ----------
    clips : dict of name to Motion, one skeleton (the first clip's); a clip at another frame rate
        than the first's is resampled to it (a note through ``log``)
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
                raise UserError(name, f"skeleton differs from {first_name} ({m.skeleton.difference(self.skeleton, 'its')}; "
                                      "the studio needs one skeleton)")
        # One rate, the first clip's (a transition's A and B share one, and so do a map's clips).
        motions, changed = at_one_rate(list(self.clips.values()), names=self.names)
        for i in changed:
            self.log(resampled_note(self.names[i], self.clips[self.names[i]].fps, first.fps))
        self.clips = dict(zip(self.names, motions, strict=True))
        if model is not None:
            model.check_skeleton(self.skeleton, first_name)
        self.bones = bone_names(self.skeleton.names)
        self.rest = first.positions[0].copy()
        self.root, self.up = root_index(first), up_axis(first)
        for name, m in self.clips.items():  # the rig turned to another up axis passes the skeleton's check
            up = up_axis(m) if m is not first else self.up
            if up != self.up:
                self.log(f"posturemap: warning: {name}: the body stands along {'XYZ'[up]}, {first_name}'s along "
                         f"{'XYZ'[self.up]}: transitions with it may not line up (lying on the floor, or of "
                         "another up axis?)")
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
        # Load the kernels of every method the page offers now rather than on the first
        # requests; with a motion library, also the retrieval's matrices, which the pool's
        # engines share.
        engine.warm_up(METHODS)
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
        ``align``; only ``with_b``, else None) and the alignment ``(joint, up axis, turn, shift,
        q, t)`` (:meth:`~posturemap.synth.engine.TransitionEngine.placement`).
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
            joint, q, t = engine.placement(p.b, turn, shift)
            up = engine.up
        finally:
            pool.put(engine)
        return rots, pos, last, keyed_joints, b_part, (joint, up, turn, shift, q, t)

    def generate(self, p: Params):
        """The whole result as one Motion: A[0..a_end], the new frames, then B's part."""
        rots, pos, _, _, b_part, _ = self._new_frames(p, with_b=True)
        a = self.clips[p.a]
        return concatenate([a[: p.request.a_end + 1], Motion(a.skeleton, rots, pos, a.fps),
                            Motion(a.skeleton, b_part.rotations, b_part.positions, a.fps)])

    def transition(self, p: Params) -> dict:
        """The answer to ``POST /api/transition``: the new frames as tracks, plus how to join them.

        The result is A's frames 0..a_end, the ``inbetween`` frames, then B's frames b_start..
        with ``alignment`` applied: B turned by ``turn`` radians about the up axis, then moved by
        ``shift``, which on each of B's frames premultiplies the local rotation of the joint
        ``alignment.joint`` by ``rotation`` and turns its local translation by it, then adds
        ``translation``. Clip frames come
        from ``GET /api/clip/{name}``, so an answer stays small however long the clips are.
        """
        rots, pos, last, keyed_joints, _, (joint, up, turn, shift, q, t) = self._new_frames(p)
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
            **({"retrieval": last["retrieval"], "method_used": last["method"]}
               if "retrieval" in last else {}),
            "source": {"a": [0, p.request.a_end], "b": [p.request.b_start, len(self.clips[p.b]) - 1]},
            "alignment": {"joint": self.bones[joint], "up": up, "turn": round(turn, 9),
                          "shift": np.round(shift, 6).tolist(), "rotation": np.round(q[[1, 2, 3, 0]], 9).tolist(),
                          "translation": np.round(t, 6).tolist()},
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


