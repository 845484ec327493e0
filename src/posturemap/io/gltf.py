"""glTF 2.0 export of a motion: the skeleton as a node hierarchy with a skin, and its animation.

What a file holds (``.glb``: the binary container; ``.gltf``: JSON with the buffer inline as a
base64 ``data:`` URI, one self-contained file):

- one node per joint, named as in the BVH, children under their parent, the rest pose as the
  nodes' own transforms (BVH offsets, no rotation), plus one leaf node per End Site
  (``<joint>_end``); a ``skin`` lists them all as joints (inverse bind matrices of that rest
  pose), so three.js, Blender, Godot and Unity import a skeleton of bones;
- one animation over the whole motion (LINEAR samplers, one key per frame, times ``k / fps``
  seconds): a ``rotation`` channel for every joint with rotation channels in the BVH and a
  ``translation`` channel for every joint with position channels; optionally (``parts`` and
  ``split``) one more animation per part (A's frames, the transition, B's frames), each
  starting at time 0 and sharing the whole animation's data;
- metres and +Y up, as glTF requires: lengths are multiplied by ``metres_per_unit`` (from the
  unit guessed from the body height unless given), and a clip whose up axis is X or Z is
  turned onto +Y at its top joints (Z-up: ``(x, y, z) -> (x, z, -y)``). ``asset.extras``
  records the source unit, the scale, the source up axis, the frame rate and the parts.

The layout follows the glTF 2.0 specification (section 4.4, GLB: a 12-byte header, a JSON chunk
padded with spaces and a BIN chunk padded with zeros, each to 4 bytes); the tests run the
Khronos glTF-Validator on the output and load it with three.js's ``GLTFLoader``.
"""

from __future__ import annotations

import base64
import json
import os
import struct

import numpy as np

from ..core import quat
from ..errors import UserError
from ..core.motion import AXES, Motion, body_height, length_unit, up_axis
from ..core.skeleton import fk

SUFFIXES = (".glb", ".gltf")
METRES_PER = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254}
ASSUMED_HEIGHT_M = 1.7  # body height assumed when the unit cannot be guessed (CMU's 1/0.45 inch)
_FLOAT = 5126  # componentType FLOAT
_GLB_MAGIC, _JSON_CHUNK, _BIN_CHUNK = 0x46546C67, 0x4E4F534A, 0x004E4942


def up_rotation(up: int) -> np.ndarray:
    """Quaternion (4,) turning the axis ``up`` (0, 1, 2 for X, Y, Z) onto +Y."""
    half = np.sqrt(0.5)
    return {0: np.array([half, 0.0, 0.0, half]),  # +90 degrees about Z: x -> y
            1: np.array([1.0, 0.0, 0.0, 0.0]),
            2: np.array([half, -half, 0.0, 0.0])}[up]  # -90 degrees about X: z -> y


def guess_scale(motion: Motion) -> tuple[str, float]:
    """The clip's length unit (:func:`posturemap.core.motion.length_unit`) and metres per unit.

    An unknown unit takes the scale that makes the body :data:`ASSUMED_HEIGHT_M` tall.
    """
    height = body_height(motion)
    unit = length_unit(motion, height)
    if unit in METRES_PER:
        return unit, METRES_PER[unit]
    return unit, ASSUMED_HEIGHT_M / height if height > 0 else 1.0


def transition_parts(a_frames: int, length: int, frames: int) -> list[tuple[str, int, int]]:
    """The parts of a transition result for :func:`build`: ``A`` (its first ``a_frames``
    frames), ``transition`` (the next ``length``) and ``B`` (the rest, up to ``frames``)."""
    return [("A", 0, a_frames), ("transition", a_frames, a_frames + length), ("B", a_frames + length, frames)]


def _check_parts(parts, frames: int) -> list[tuple[str, int, int]]:
    """``parts`` as (name, start, stop) frame ranges that tile 0..frames; raises ValueError."""
    out, at = [], 0
    for name, start, stop in parts:
        if start != at or not start < stop <= frames or not str(name):
            raise ValueError(f"parts must tile frames 0..{frames} in order, got {list(parts)}")
        out.append((str(name), int(start), int(stop)))
        at = stop
    if at != frames:
        raise ValueError(f"parts must tile frames 0..{frames} in order, got {list(parts)}")
    return out


class _Buffer:
    """The binary buffer, its buffer views and accessors as they are added."""

    def __init__(self):
        self.chunks: list[bytes] = []
        self.size = 0
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def view(self, data: np.ndarray) -> int:
        """Append float32 ``data`` as a new buffer view (4-byte aligned); returns its index."""
        raw = np.ascontiguousarray(data, dtype="<f4").tobytes()
        self.views.append({"buffer": 0, "byteOffset": self.size, "byteLength": len(raw)})
        self.chunks.append(raw)
        self.size += len(raw)
        return len(self.views) - 1

    def accessor(self, view: int, kind: str, count: int, first: int = 0, values=None) -> int:
        """An accessor of ``count`` elements of ``kind`` from element ``first`` of ``view``;
        ``values`` (count, n) gives its min and max."""
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[kind]
        acc = {"bufferView": view, "componentType": _FLOAT, "count": int(count), "type": kind}
        if first:
            acc["byteOffset"] = 4 * width * first
        if values is not None:
            v = np.asarray(values, dtype="<f4").reshape(count, width)
            acc["min"], acc["max"] = v.min(axis=0).tolist(), v.max(axis=0).tolist()
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def data(self) -> bytes:
        return b"".join(self.chunks)


def build(motion: Motion, parts=None, split: bool = False, name: str = "motion",
          metres_per_unit: float | None = None, up: int | None = None) -> tuple[dict, bytes]:
    """The glTF JSON document (a dict) and its binary buffer for ``motion``.

    Parameters
    ----------
    motion : the clip (any up axis, any unit)
    parts : list of (name, start, stop) frame ranges tiling the motion in order, or None;
        recorded in ``asset.extras`` and, with ``split``, one animation each
    split : also write one animation per part (each starting at time 0)
    name : name of the scene, the top node's skin and the whole animation
    metres_per_unit : scale to metres (default: :func:`guess_scale`)
    up : the clip's up axis 0, 1, 2 (default: read from the data, :func:`posturemap.core.motion.up_axis`)
    """
    sk = motion.skeleton
    frames = motion.num_frames
    parts = _check_parts(parts, frames) if parts else None
    if split and not parts:
        raise ValueError("split needs parts")
    unit, guessed = guess_scale(motion)
    scale = float(guessed if metres_per_unit is None else metres_per_unit)
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"metres_per_unit must be a positive number, got {metres_per_unit!r}")
    up = up_axis(motion) if up is None else int(up)
    turn = up_rotation(up)

    # Local transforms in metres, Y up: the top joints (no parent) carry the turn.
    rots = motion.rotations.copy()
    pos = motion.positions * scale
    offsets = sk.offsets * scale
    tops = np.flatnonzero(sk.parents < 0)
    rots[:, tops] = quat.mul(turn, rots[:, tops])
    pos[:, tops] = quat.mul_vec(turn, pos[:, tops])
    rots = quat.unroll(quat.normalize(rots), axis=0)  # one hemisphere from key to key
    rest_rot = np.broadcast_to(quat.identity(), (sk.num_joints, 4)).copy()
    rest_rot[tops] = turn
    rest_pos = offsets.copy()
    rest_pos[tops] = quat.mul_vec(turn, offsets[tops])

    # Nodes: joints first (node j is joint j), then End Sites.
    nodes = []
    for j in range(sk.num_joints):
        node = {"name": sk.names[j]}
        if np.any(rest_pos[j] != 0):
            node["translation"] = rest_pos[j].tolist()
        if np.any(rest_rot[j] != quat.identity()):
            node["rotation"] = rest_rot[j][[1, 2, 3, 0]].tolist()
        nodes.append(node)
    for j, offset in sk.end_sites:
        node = {"name": f"{sk.names[j]}_end"}
        if np.any(offset != 0):
            node["translation"] = (np.asarray(offset, dtype=float) * scale).tolist()
        nodes.append(node)
    end_parents = [j for j, _ in sk.end_sites]
    for child, parent in [(j, int(p)) for j, p in enumerate(sk.parents) if p >= 0] + \
            [(sk.num_joints + k, j) for k, j in enumerate(end_parents)]:
        nodes[parent].setdefault("children", []).append(child)

    buf = _Buffer()
    # Inverse bind matrices of the rest pose (column-major 4x4), one per skin joint.
    all_parents = np.concatenate([sk.parents, end_parents]).astype(np.int64)
    all_rot = np.concatenate([rest_rot, np.broadcast_to(quat.identity(), (len(end_parents), 4))])
    all_pos = np.concatenate([rest_pos, np.array([o for _, o in sk.end_sites]).reshape(-1, 3) * scale])
    grot, gpos = fk(all_parents, all_rot, all_pos)
    world = np.zeros((len(nodes), 4, 4))
    world[:, :3, :3] = quat.to_matrix(grot)
    world[:, :3, 3] = gpos
    world[:, 3, 3] = 1.0
    ibm = np.linalg.inv(world).transpose(0, 2, 1).reshape(len(nodes), 16)  # column-major
    skins = []
    if len(tops) == 1:  # a skin's joints need one common root
        skins.append({"name": name, "joints": list(range(len(nodes))), "skeleton": int(tops[0]),
                      "inverseBindMatrices": buf.accessor(buf.view(ibm), "MAT4", len(nodes))})

    times = np.arange(frames, dtype=np.float64) / motion.fps
    time_view = buf.view(times)
    series = []  # (node, path, view, kind)
    for j in range(sk.num_joints):
        if any(c.endswith("rotation") for c in sk.channels[j]):
            series.append((j, "rotation", buf.view(rots[:, j][:, [1, 2, 3, 0]]), "VEC4"))
        if sk.has_position(j):
            series.append((j, "translation", buf.view(pos[:, j]), "VEC3"))

    def animation(label: str, start: int, stop: int) -> dict:
        count = stop - start
        t_acc = buf.accessor(time_view, "SCALAR", count, 0, times[:count])
        samplers, channels = [], []
        for node, path, view, kind in series:
            samplers.append({"input": t_acc, "output": buf.accessor(view, kind, count, start),
                             "interpolation": "LINEAR"})
            channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})
        return {"name": label, "samplers": samplers, "channels": channels}

    animations = [animation(name, 0, frames)]
    if split:
        animations += [animation(label, start, stop) for label, start, stop in parts]

    from .. import __version__
    extras = {"source_unit": unit, "metres_per_unit": scale, "source_up_axis": AXES[up],
              "fps": float(motion.fps), "frames": frames}
    if parts:
        extras["parts"] = [{"name": label, "first_frame": start, "frames": stop - start,
                            "start_seconds": start / motion.fps} for label, start, stop in parts]
    doc = {
        "asset": {"version": "2.0", "generator": f"posturemap {__version__}", "extras": extras},
        "scene": 0,
        "scenes": [{"name": name, "nodes": [int(t) for t in tops]}],
        "nodes": nodes,
        "skins": skins,
        "animations": animations,
        "accessors": buf.accessors,
        "bufferViews": buf.views,
        "buffers": [{"byteLength": buf.size}],
    }
    if not skins:
        del doc["skins"]
    return doc, buf.data()


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def glb_bytes(doc: dict, data: bytes) -> bytes:
    """The binary glTF container: header, JSON chunk (space-padded), BIN chunk (zero-padded)."""
    text = _pad(json.dumps(doc, separators=(",", ":")).encode("utf-8"), b" ")
    binary = _pad(data, b"\0")
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<III", _GLB_MAGIC, 2, total) + struct.pack("<II", len(text), _JSON_CHUNK) + text
            + struct.pack("<II", len(binary), _BIN_CHUNK) + binary)


def gltf_text(doc: dict, data: bytes) -> str:
    """The JSON glTF with the buffer inline as a base64 data URI (one self-contained file)."""
    doc = dict(doc, buffers=[{"byteLength": len(data),
                              "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}])
    return json.dumps(doc, indent=1)


def dumps(motion: Motion, binary: bool = True, **options) -> bytes:
    """The file's bytes: ``.glb`` (``binary``) or ``.gltf``; ``options`` as for :func:`build`.

    A motion with NaN or infinite values raises :class:`~posturemap.io.bvh.BVHError` (nothing to write).
    """
    from .bvh import check_finite

    check_finite(motion)
    doc, data = build(motion, **options)
    return glb_bytes(doc, data) if binary else gltf_text(doc, data).encode("utf-8")


def is_gltf_path(path) -> bool:
    """Whether ``path`` ends in ``.glb`` or ``.gltf`` (any case)."""
    return os.fspath(path).lower().endswith(SUFFIXES)


def write(path, motion: Motion, **options) -> None:
    """Write ``motion`` as glTF to ``path`` atomically: ``.glb`` binary, ``.gltf`` JSON.

    ``options`` as for :func:`build`. A folder that cannot be written raises :class:`UserError`
    naming the file; an existing file stays as it was.
    """
    from .bvh import write_bytes_atomic

    path = os.fspath(path)
    if not is_gltf_path(path):
        raise UserError(path, "a glTF file name must end in .glb or .gltf")
    from .bvh import check_finite

    check_finite(motion, path)
    data = dumps(motion, binary=path.lower().endswith(".glb"), **options)
    try:
        write_bytes_atomic(path, data)
    except OSError as e:
        raise UserError(path, f"cannot write file ({e.strerror or e})") from None


def read_glb(data: bytes) -> tuple[dict, bytes]:
    """The JSON document and BIN chunk of a ``.glb`` (checks the header and chunk layout).

    For tests and tools; raises ValueError on anything that is not a well-formed GLB.
    """
    if len(data) < 20:
        raise ValueError("too short for a GLB header")
    magic, version, total = struct.unpack_from("<III", data, 0)
    if magic != _GLB_MAGIC or version != 2 or total != len(data):
        raise ValueError(f"bad GLB header (magic {magic:#x}, version {version}, length {total} of {len(data)})")
    length, kind = struct.unpack_from("<II", data, 12)
    if kind != _JSON_CHUNK or length % 4 or 20 + length > total:
        raise ValueError("first chunk is not a 4-byte aligned JSON chunk")
    doc = json.loads(data[20: 20 + length].decode("utf-8"))
    binary = b""
    at = 20 + length
    if at < total:
        length, kind = struct.unpack_from("<II", data, at)
        if kind != _BIN_CHUNK or length % 4 or at + 8 + length != total:
            raise ValueError("second chunk is not a 4-byte aligned BIN chunk ending the file")
        binary = data[at + 8: at + 8 + length]
    return doc, binary


def accessor_array(doc: dict, binary: bytes, index: int) -> np.ndarray:
    """The float values (count, n) of accessor ``index`` (tightly packed float32 views only)."""
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc["type"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.frombuffer(binary, dtype="<f4", count=acc["count"] * width, offset=start).reshape(acc["count"], width)


def world_positions(doc: dict, binary: bytes, animation: int = 0) -> np.ndarray:
    """World positions (K, nodes, 3) at the K keys of ``animation``, from the file alone.

    The nodes' own transforms, the animation's keys written over them (every sampler must
    share the first one's key times, as :func:`build` writes them), forward kinematics down
    the node tree. For tests and tools; ``doc`` and ``binary`` as from :func:`read_glb`.
    """
    nodes = doc["nodes"]
    count = len(nodes)
    parents = np.full(count, -1)
    for i, node in enumerate(nodes):
        for c in node.get("children", []):
            parents[c] = i
    if np.any(parents >= np.arange(count)):
        raise ValueError("nodes must come after their parents")
    anim = doc["animations"][animation]
    frames = doc["accessors"][anim["samplers"][0]["input"]]["count"]
    rots = np.zeros((frames, count, 4))
    pos = np.zeros((frames, count, 3))
    for i, node in enumerate(nodes):
        rots[:, i] = np.array(node.get("rotation", [0, 0, 0, 1]))[[3, 0, 1, 2]]
        pos[:, i] = node.get("translation", [0, 0, 0])
    for ch in anim["channels"]:
        values = accessor_array(doc, binary, anim["samplers"][ch["sampler"]]["output"]).astype(float)
        node, path = ch["target"]["node"], ch["target"]["path"]
        if path == "rotation":
            rots[:, node] = values[:, [3, 0, 1, 2]]
        else:
            pos[:, node] = values
    return fk(parents, rots, pos)[1]
