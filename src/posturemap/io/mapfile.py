"""The map file format and its validation: every byte is checked before it is trusted.

A map file is a ZIP archive of ``.npy`` members (``numpy.savez``), read here without
``numpy.load`` and never with pickles:

- ``meta``: UTF-8 JSON as a 1-D ``uint8`` array (format name, version, skeleton, feature
  space, class assignment, training parameters, radii, training summary and, when the map
  carries a motion library, ``library``);
- ``space_reference (K, 4)``, ``space_fill (3K + 1,)``, ``space_active (3K + 1,)`` and
  ``space_rest (4,)``: the feature space of the K keyed joints;
- per class ``c`` in 0..3: ``c{c}_weights (n, d)``, ``c{c}_edges (E, 2)``, ``c{c}_hits (n,)``,
  ``c{c}_witness (n,)``, ``c{c}_period (d,)``, where ``d`` is the number of the class's
  active dimensions;
- ``library_*``: the motion library's per-frame arrays, and its toes' height counts by speed
  (``library_toe_step_counts``, absent from files written before them, whose
  ``library_toe_counts`` measured speeds otherwise and is not read; shapes and values checked by
  :meth:`posturemap.synth.library.MotionLibrary.from_parts`).

:func:`read` checks, in this order and before the next step reads anything: the path is a
regular file of at most :data:`MAX_FILE_BYTES`; the archive has at most :data:`MAX_MEMBERS`
members, none inflating more than :data:`MAX_RATIO` times its stored size; each member's
``.npy`` header (read through :mod:`numpy.lib.format`) declares a plain numeric dtype (bool,
integer or float; no objects, no structures) and a shape whose size is within
:data:`MAX_ARRAY_BYTES` (:data:`MAX_META_BYTES` for ``meta``) and matches the member's size
in the archive; the metadata's every field (type, range, finite, lengths against the
skeleton); each array's shape against the metadata (class maps: at most :data:`MAX_NEURONS`
neurons), from its header, before its data is read; then the values: finite floats within
:data:`MAX_VALUE`, rotation features within :data:`MAX_ANGLE`, unit quaternions (the
library's are checked by ``from_parts``), indices within range, class weights not degenerate
(two or more neurons that all coincide). Any failure raises :class:`MapFileError` naming the
file and what is wrong.

Members the format does not name are not read. This is the only version so far
(:data:`VERSION` 1); an older or newer version is refused with a message saying which one
this posturemap reads.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
import zlib

import numpy as np

from ..errors import UserError
from ..learn.features import CLASSES
from .fileio import open_regular
from ..core.skeleton import POSITION_CHANNELS, ROTATION_CHANNELS

FORMAT = "posturemap-map"
VERSION = 1
MAX_FILE_BYTES = 4 << 30       # a map file on disk
MAX_MEMBERS = 256              # .npy members in the archive
MAX_META_BYTES = 16 << 20      # the JSON metadata
MAX_ARRAY_BYTES = 2 << 30      # one array, as declared by its header
MAX_TOTAL_BYTES = 4 << 30      # all arrays together
MAX_JOINTS = 10_000
MAX_NEURONS = 1_000_000        # per class map (a Bandai map has about 3,000)
MAX_EDGES = 50 * MAX_NEURONS
MAX_RATIO = 200                # uncompressed / compressed size of a member over 16 MiB (a zip bomb)
MAX_INT = 2 ** 53              # integers in the metadata (counts, seeds)
MAX_VALUE = 1e12               # any float in an array (positions in any unit, velocities)
MAX_ANGLE = 4 * math.pi        # rotation features (rotation vectors, Euler angles), radians
_DTYPE_KINDS = "biuf"          # bool, signed and unsigned integers, floats
_CHANNELS = set(POSITION_CHANNELS + ROTATION_CHANNELS)


class MapFileError(UserError):
    """A map file that cannot be used: corrupt, truncated, foreign or of another version."""

    def __init__(self, path, what):
        super().__init__(path, what)


class _Bad(Exception):
    """A metadata or array check failed (internal; becomes a MapFileError)."""


# -- reading ---------------------------------------------------------------------------------
def read(path: str | os.PathLike) -> tuple[dict, dict[str, np.ndarray]]:
    """The checked metadata and arrays of a map file (array names without ``.npy``).

    Raises :class:`MapFileError` for anything that is not a valid map file of this version.
    """
    path = os.fspath(path)
    if not os.path.lexists(path):
        raise MapFileError(path, "no such map file")
    try:
        f = open_regular(path, MAX_FILE_BYTES, "map file")
    except UserError as e:
        raise MapFileError(path, e.what) from None
    with f:
        if not zipfile.is_zipfile(f):
            raise MapFileError(path, "not a posturemap map file (not an .npz archive)")
        try:
            with zipfile.ZipFile(f) as z, np.errstate(all="ignore"):  # huge values fail the checks, quietly
                return _read_archive(z, path)
        except MapFileError:
            raise
        except _Bad as e:
            raise MapFileError(path, f"corrupt map file ({e})") from None
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, NotImplementedError,
                RuntimeError, KeyError) as e:
            raise MapFileError(path, f"not a posturemap map file (unreadable archive: {str(e)[:200]})") from None


def _read_archive(z: zipfile.ZipFile, path: str) -> tuple[dict, dict[str, np.ndarray]]:
    infos = z.infolist()
    if len(infos) > MAX_MEMBERS:
        raise MapFileError(path, f"not a posturemap map file ({len(infos)} members; at most {MAX_MEMBERS})")
    members = {}
    for info in infos:
        name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
        if name in members:
            raise MapFileError(path, f"not a posturemap map file (member {name[:60]!r} twice)")
        members[name] = info
    if "meta" not in members:
        raise MapFileError(path, "not a posturemap map file (no 'meta' entry)")
    raw = _read_npy(z, members["meta"], "meta", MAX_META_BYTES, lambda shape: len(shape) == 1, "u")
    meta = _parse_meta(raw, path)
    expected = check_meta(meta)
    arrays = {}
    total = 0
    for name, rule in expected.items():
        if name not in members:
            if rule.optional:
                continue
            raise _Bad(f"missing array {name!r}")
        a = _read_npy(z, members[name], name, MAX_ARRAY_BYTES, rule.shape_ok, rule.kinds)
        total += a.nbytes
        if total > MAX_TOTAL_BYTES:
            raise _Bad(f"arrays larger than {MAX_TOTAL_BYTES} bytes in all")
        arrays[name] = a
    for name, info in members.items():  # the library's arrays: generic checks here
        if name.startswith("library_") and name not in arrays and "library" in meta:
            a = _read_npy(z, info, name, MAX_ARRAY_BYTES, lambda shape: len(shape) <= 4, _DTYPE_KINDS)
            total += a.nbytes
            if total > MAX_TOTAL_BYTES:
                raise _Bad(f"arrays larger than {MAX_TOTAL_BYTES} bytes in all")
            arrays[name] = a
    check_arrays(meta, arrays)
    return meta, arrays


def _read_npy(z: zipfile.ZipFile, info: zipfile.ZipInfo, name: str, max_bytes: int, shape_ok,
              kinds: str) -> np.ndarray:
    """One ``.npy`` member, its header checked (dtype kind, shape, size) before its data is read."""
    if info.flag_bits & 0x1:
        raise _Bad(f"{name} is encrypted")
    if info.file_size > 16 << 20 and info.file_size > MAX_RATIO * max(info.compress_size, 1):
        raise _Bad(f"{name} inflates {info.file_size} bytes from {info.compress_size} (a zip bomb?)")
    with z.open(info) as f:
        try:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
            else:
                raise _Bad(f"{name} has .npy format version {version}")
        except _Bad:
            raise
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError):
            raise
        except Exception as e:  # noqa: BLE001 - numpy parses the header text with ast and tokenize, which
            # raise ValueError, SyntaxError, tokenize.TokenError, RecursionError... on hostile text
            raise _Bad(f"{name} has no valid .npy header ({type(e).__name__})") from None
        if dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None or dtype.kind not in kinds:
            raise _Bad(f"{name} has dtype {str(dtype)[:40]}, expected "
                       + {"u": "bytes (uint8)", "iu": "whole numbers", "f": "floats", "b": "booleans"}.get(kinds, "numbers"))
        if name == "meta" and dtype.itemsize != 1:
            raise _Bad("meta is not a byte array")
        if not all(isinstance(s, int) and s >= 0 for s in shape) or len(shape) > 8:
            raise _Bad(f"{name} declares shape {str(shape)[:60]}")
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > max_bytes:
            raise _Bad(f"{name} declares {nbytes} bytes (shape {shape}); at most {max_bytes}")
        if not shape_ok(shape):
            raise _Bad(f"{name} has shape {shape}, which does not fit the metadata")
        if f.tell() + nbytes != info.file_size:
            raise _Bad(f"{name}: the header's shape {shape} does not match the stored data "
                       f"({info.file_size - f.tell()} bytes for {nbytes})")
        out = np.empty(math.prod(shape), dtype=dtype)  # writable, as numpy.load gives
        got = f.readinto(memoryview(out).cast("B")) if nbytes else 0
        f.read(1)  # at the end of the member: the archive checks its CRC
    if got != nbytes:
        raise _Bad(f"{name} is truncated")
    return out.reshape(shape, order="F" if fortran else "C")


def _reject_constant(name: str):
    raise ValueError(f"{name} is not a JSON number")


def _parse_meta(raw: np.ndarray, path: str) -> dict:
    try:
        meta = json.loads(raw.tobytes().decode("utf-8"), parse_constant=_reject_constant)
    except RecursionError:
        raise MapFileError(path, "corrupt metadata (nested too deeply)") from None
    except (UnicodeDecodeError, ValueError):
        raise MapFileError(path, "corrupt metadata (not JSON)") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise MapFileError(path, "not a posturemap map file (foreign format)")
    if meta.get("version") != VERSION or isinstance(meta.get("version"), bool):
        shown = meta.get("version")
        shown = shown if isinstance(shown, (int, float, type(None))) and len(repr(shown)) < 30 else "unknown"
        raise MapFileError(path, f"map format version {shown!r}; this posturemap reads {VERSION}")
    return meta


# -- metadata --------------------------------------------------------------------------------
def _get(d: dict, key: str, where: str, default=...):
    if key not in d:
        if default is ...:
            raise _Bad(f"{where}{key} missing")
        return default
    return d[key]


def _int(d: dict, key: str, where: str, lo: int, hi: int, default=...) -> int:
    v = _get(d, key, where, default)
    if not (isinstance(v, int) and not isinstance(v, bool)) or not lo <= v <= hi:
        raise _Bad(f"{where}{key} must be a whole number in {lo}..{hi}, got {_shown(v)}")
    return v


def _num(d: dict, key: str, where: str, lo: float, hi: float = math.inf, default=...) -> float:
    v = _get(d, key, where, default)
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        raise _Bad(f"{where}{key} must be a number, got {_shown(v)}")
    if isinstance(v, int) and not -MAX_INT <= v <= MAX_INT:
        raise _Bad(f"{where}{key} out of range ({lo:g}..{hi:g})")
    if not (math.isfinite(v) and lo <= v <= hi):
        raise _Bad(f"{where}{key} must be a finite number in {lo:g}..{hi:g}, got {_shown(v)}")
    return float(v)


def _list(d: dict, key: str, where: str, n: int | None = None, lo: int = 0, hi: int = MAX_JOINTS,
          default=...) -> list:
    v = _get(d, key, where, default)
    if not isinstance(v, list):
        raise _Bad(f"{where}{key} must be a list, got {_shown(v)}")
    if n is not None and len(v) != n:
        raise _Bad(f"{where}{key} has {len(v)} entries, expected {n}")
    if not lo <= len(v) <= hi:
        raise _Bad(f"{where}{key} has {len(v)} entries, expected {lo}..{hi}")
    return v


def _ints(values: list, what: str, lo: int, hi: int) -> None:
    for v in values:
        if not (isinstance(v, int) and not isinstance(v, bool)) or not lo <= v <= hi:
            raise _Bad(f"{what} must hold whole numbers in {lo}..{hi}, got {_shown(v)}")


def _vector(v, what: str, n: int = 3) -> None:
    if not (isinstance(v, list) and len(v) == n and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and abs(x) <= 1e300 and math.isfinite(x)
            for x in v)):
        raise _Bad(f"{what} must be {n} finite numbers, got {_shown(v)}")


def _dict(d: dict, key: str, where: str, default=...) -> dict:
    v = _get(d, key, where, default)
    if not isinstance(v, dict):
        raise _Bad(f"{where}{key} must be an object, got {_shown(v)}")
    return v


def _choice(d: dict, key: str, where: str, choices: tuple, default=...):
    v = _get(d, key, where, default)
    if not isinstance(v, str) or v not in choices:
        raise _Bad(f"{where}{key} must be one of {', '.join(choices)}, got {_shown(v)}")
    return v


def _shown(v) -> str:
    if isinstance(v, (dict, list)):
        return "an object" if isinstance(v, dict) else "a list"
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) > 10 ** 15:
        return "a huge number"
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


class _Rule:
    """What one array must be: dtype kinds, a test of its declared shape, optional or not."""

    def __init__(self, kinds: str, shape, optional: bool = False, limit: int | None = None):
        self.kinds, self.optional = kinds, optional
        self.shape, self.limit = shape, limit  # limit: of the first axis when it is free

    def shape_ok(self, shape: tuple) -> bool:
        want = self.shape
        return (len(shape) == len(want) and all(w is None or s == w for s, w in zip(shape, want))
                and (self.limit is None or shape[0] <= self.limit))


def check_skeleton(sk: dict) -> int:
    """Check the skeleton's metadata; returns the number of joints J."""
    w = "skeleton."
    names = _list(sk, "names", w, lo=1)
    j = len(names)
    if not all(isinstance(n, str) and 0 < len(n) <= 1000 for n in names):
        raise _Bad("skeleton.names must be non-empty strings")
    parents = _list(sk, "parents", w, j)
    for i, p in enumerate(parents):
        if not (isinstance(p, int) and not isinstance(p, bool)) or not -1 <= p < i:
            raise _Bad(f"skeleton.parents[{i}] must be -1 or an earlier joint, got {_shown(p)}")
    for i, o in enumerate(_list(sk, "offsets", w, j)):
        _vector(o, f"skeleton.offsets[{i}]")
    for i, ch in enumerate(_list(sk, "channels", w, j)):
        if not (isinstance(ch, list) and len(ch) <= 6 and all(isinstance(c, str) and c in _CHANNELS for c in ch)
                and len(set(ch)) == len(ch) and sum(c in ROTATION_CHANNELS for c in ch) in (0, 3)):
            raise _Bad(f"skeleton.channels[{i}] is not a BVH channel list")
    for k, e in enumerate(_list(sk, "end_sites", w, hi=MAX_JOINTS, default=[])):
        if not (isinstance(e, list) and len(e) == 2):
            raise _Bad(f"skeleton.end_sites[{k}] must be [joint, offset]")
        _ints([e[0]], f"skeleton.end_sites[{k}]", 0, j - 1)
        _vector(e[1], f"skeleton.end_sites[{k}] offset")
    _choice(sk, "euler_style", w, ("wrapped", "continuous"), default="wrapped")
    return j


def check_meta(meta: dict) -> dict[str, _Rule]:
    """Check every metadata field (type, range, finite, lengths); returns the array rules.

    Raises ``_Bad`` naming the field. The rules say each array's dtype kinds and shape as
    the metadata implies them (``None`` for a free length).
    """
    j = check_skeleton(_dict(meta, "skeleton", ""))
    sp = _dict(meta, "space", "")
    w = "space."
    _choice(sp, "mode", w, ("logmap", "euler"))
    _int(sp, "root", w, 0, j - 1)
    _int(sp, "up", w, 0, 2)
    _num(sp, "height_scale", w, 1e-300, 1e300)
    joints = _list(sp, "joints", w, lo=1, hi=j)
    _ints(joints, "space.joints", 0, j - 1)
    k = len(joints)
    orders = _list(sp, "orders", w, k)
    if not all(isinstance(o, str) and len(o) == 3 and set(o) <= set("XYZ") and o[0] != o[1] != o[2]
               for o in orders):
        raise _Bad("space.orders must be Euler orders such as 'ZXY'")
    joint_class = _list(sp, "joint_class", w, j)
    _ints(joint_class, "space.joint_class", 0, len(CLASSES) - 1)
    if _get(meta, "classes", "") != list(CLASSES):
        raise _Bad(f"classes must be {list(CLASSES)}")
    assignment = _dict(meta, "assignment", "", default={})
    if not all(isinstance(v, str) for v in assignment.values()):
        raise _Bad("assignment must map joint names to class names")
    p = _dict(meta, "params", "")
    radius = _get(p, "radius", "params.")
    if radius != "auto":
        _num(p, "radius", "params.", 0.0, 1e300)
    _int(p, "neighborhood", "params.", 0, 10 ** 6)
    _num(p, "learning_rate", "params.", 0.0, 1.0)
    _int(p, "epochs", "params.", 1, 10 ** 6)
    _int(p, "seed", "params.", -MAX_INT, MAX_INT)
    _choice(p, "features", "params.", ("logmap", "euler"))
    radii = _list(meta, "radius", "", len(CLASSES))
    for c in range(len(CLASSES)):
        _num({"radius": radii[c]}, "radius", f"class {CLASSES[c]} ", 0.0, 1e300)
    _check_info(_dict(meta, "info", "", default={}))
    if "library" in meta:
        lib = _dict(meta, "library", "")
        _num(lib, "fps", "library.", 1e-3, 1e6)
        _num(lib, "leg", "library.", 1e-300, 1e300)
        _int(lib, "up", "library.", 0, 2)
        _int(lib, "frames", "library.", 1, MAX_INT)
        if not all(isinstance(c, str) for c in _list(lib, "clips", "library.", hi=10 ** 7, default=[])):
            raise _Bad("library.clips must be clip names")

    dim_class = np.concatenate([np.repeat(np.asarray(joint_class)[joints], 3), [0]])
    full = 3 * k + 1
    rules = {"space_reference": _Rule("f", (k, 4)), "space_fill": _Rule("f", (full,)),
             "space_active": _Rule("b", (full,)), "space_rest": _Rule("f", (4,), optional=True)}
    for c in range(len(CLASSES)):
        rules[f"c{c}_weights"] = _Rule("f", (None, None), limit=MAX_NEURONS)  # d checked with the mask
        rules[f"c{c}_edges"] = _Rule("iu", (None, 2), limit=MAX_EDGES)
        rules[f"c{c}_hits"] = _Rule("iu", (None,), limit=MAX_NEURONS)
        rules[f"c{c}_witness"] = _Rule("iu", (None,), limit=MAX_NEURONS)
        rules[f"c{c}_period"] = _Rule("f", (None,))
    meta["_dim_class"] = dim_class  # removed by check_arrays
    return rules


def _check_info(info: dict) -> None:
    """The training summary: scalars, and per class a table of finite numbers."""
    for key, v in info.items():
        if key == "quality":
            if not isinstance(v, dict):
                raise _Bad("info.quality must be an object")
            for cls, q in v.items():
                if cls not in CLASSES or not isinstance(q, dict):
                    raise _Bad(f"info.quality.{str(cls)[:40]} is not a class table")
                for name in q:
                    _num(q, name, f"info.quality.{cls}.", -1e300, 1e300)
        elif not (v is None or isinstance(v, (str, bool)) or (isinstance(v, (int, float))
                                                               and abs(v) <= 1e300 and math.isfinite(v))):
            raise _Bad(f"info.{str(key)[:40]} must be a plain value, got {_shown(v)}")


# -- arrays ----------------------------------------------------------------------------------
def _finite(a: np.ndarray, name: str) -> None:
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise _Bad(f"{name} has NaN or infinite values")


def check_arrays(meta: dict, arrays: dict[str, np.ndarray]) -> None:
    """Check the arrays' values and their shapes against each other (after :func:`check_meta`)."""
    dim_class = meta.pop("_dim_class")
    for name, a in arrays.items():
        if not name.endswith("_period"):  # periods are 2 pi or infinite
            _finite(a, name)
            if a.dtype.kind == "f" and a.size and np.abs(a).max() > MAX_VALUE:
                raise _Bad(f"{name} has values beyond {MAX_VALUE:g}")
    # Feature values: rotation parts are rotation vectors or Euler angles (radians), the last
    # dimension a height in leg lengths; beyond these bounds a decoded posture is not a rotation.
    bound = np.full(len(dim_class), MAX_ANGLE)
    bound[-1] = MAX_VALUE
    if np.any(np.abs(arrays["space_fill"]) > bound):
        raise _Bad(f"space_fill has rotation values beyond {MAX_ANGLE:.4g} radians")
    ref = arrays["space_reference"]
    if np.any(np.abs(np.linalg.norm(ref, axis=1) - 1.0) > 1e-3):
        raise _Bad("space_reference holds rotations that are not unit quaternions")
    if "space_rest" in arrays and abs(np.linalg.norm(arrays["space_rest"]) - 1.0) > 1e-3:
        raise _Bad("space_rest is not a unit quaternion")
    active = arrays["space_active"]
    if active.dtype.kind != "b":
        raise _Bad("space_active must be booleans")
    for c, cls in enumerate(CLASSES):
        dims = int(np.count_nonzero(active & (dim_class == c)))
        w = arrays[f"c{c}_weights"]
        n = len(w)
        if w.shape[1] != dims or n == 0:
            raise _Bad(f"class {cls} weights have shape {w.shape}, expected (n >= 1, {dims})")
        if np.any(np.abs(w) > bound[active & (dim_class == c)]):
            raise _Bad(f"class {cls} weights (c{c}_weights) have rotation values beyond {MAX_ANGLE:.4g} radians")
        if n >= 2 and np.all(w == w[0]):
            raise _Bad(f"class {cls} weights are degenerate (all {n} neurons coincide)")
        edges = arrays[f"c{c}_edges"]
        if edges.size and (edges.min() < 0 or edges.max() >= n):
            raise _Bad(f"class {cls} edges (c{c}_edges) do not fit its {n} neurons")
        for part, lowest in (("hits", 0), ("witness", -1)):  # witness -1: none among the latest data
            a = arrays[f"c{c}_{part}"]
            if a.shape != (n,) or (a.size and a.min() < lowest):
                raise _Bad(f"class {cls} {part} (c{c}_{part}) have shape {a.shape} or values below {lowest}; "
                           f"expected ({n},), at least {lowest}")
        period = arrays[f"c{c}_period"]
        if period.shape != (dims,):
            raise _Bad(f"class {cls} periods (c{c}_period) have shape {period.shape}, expected ({dims},)")
        if np.any(np.isnan(period)) or np.any(period <= 0):
            raise _Bad(f"class {cls} periods (c{c}_period) must be positive (or infinite)")
