"""Read and write BVH motion capture files.

Reading gives a :class:`~posturemap.core.motion.Motion`; writing reproduces the hierarchy and the
channel layout (any rotation order per joint, 3- or 6-channel joints, End Sites). Joints with
position channels take their translation from the channels (the OFFSET is kept for writing
back); the others use their OFFSET.

The frame data is read in one pass without per-line Python work: only the header of a large
ASCII file is decoded, a numba kernel parses the numbers straight from the bytes and another
turns Euler angles into quaternions, once numba is loaded in the process
(:func:`posturemap.core.kernels.compiled`; until then, e.g. for the two files of one command-line
transition, the general numpy path reads everything). Text the kernel does not recognise (unusual whitespace or
number syntax, a wrong line) goes through the general numpy path, which is the reference for
what is accepted and for the error messages; numbers the kernel parses come out bit-identical
to Python's ``float``.

Every problem with a file raises :class:`BVHError` naming the file, the line and what is wrong.
"""

from __future__ import annotations

import dataclasses
import io
import os
import re

import numpy as np

from ..core import quat
from ..errors import UserError
from .fileio import read_regular, write_bytes_atomic  # noqa: F401 - write_bytes_atomic kept here for callers
from ..core.motion import MAX_FPS, MIN_FPS, Motion
from ..core.skeleton import POSITION_CHANNELS, ROTATION_CHANNELS, Skeleton

MAX_JOINTS = 10_000
MAX_DEPTH = MAX_JOINTS  # joints on one chain from a root (the parser keeps its own stack)
MAX_VALUES = 500_000_000  # frames * channels; beyond this a file is not motion capture
MAX_FILE_BYTES = 2 << 30  # 2 GiB: larger files are refused before reading
MAX_ABS_VALUE = 1e9  # a channel or offset value beyond this (in any unit) is not a pose: refused
MIN_FRAME_TIME, MAX_FRAME_TIME = 1.0 / MAX_FPS, 1.0 / MIN_FPS  # seconds: 10 kHz .. 0.1 Hz (core.motion)

_CHANNEL_NAMES = {c.lower(): c for c in POSITION_CHANNELS + ROTATION_CHANNELS}  # any case
# The line breaks of str.splitlines(), so that line numbers match what editors show.
_LINE_BREAK = re.compile("\r\n|[\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]")


class BVHError(UserError):
    """A malformed BVH file: the message names the file, the line and what is wrong."""

    def __init__(self, path, line, what):
        super().__init__(f"{path}" + (f":{line}" if line else ""), what)
        self.path, self.line = path, line


def read(path: str | os.PathLike) -> Motion:
    """Read a BVH file into a Motion (rotations from degrees to quaternions)."""
    path = os.fspath(path)
    try:
        raw = read_regular(path, MAX_FILE_BYTES, "BVH file")
    except UserError as e:
        raise BVHError(path, None, e.what) from None
    return loads(raw, path)


def read_inputs(inputs: list[str]) -> list[tuple[str, Motion]]:
    """Read BVH files and folders of them (a folder's ``.bvh`` files sorted by name).

    Returns ``(path, Motion)`` pairs; raises :class:`UserError` for a missing path or a folder
    without BVH files and :class:`BVHError` for a bad file.
    """
    paths = []
    for item in inputs:
        if os.path.isdir(item):
            found = sorted(os.path.join(item, f) for f in os.listdir(item) if f.lower().endswith(".bvh"))
            if not found:
                raise UserError(item, "folder holds no .bvh files")
            paths.extend(found)
        elif os.path.exists(item):
            paths.append(item)
        else:
            raise UserError(item, "no such file or folder")
    return [(p, read(p)) for p in paths]


def loads(raw: bytes | str, path: str = "<string>") -> Motion:
    """Parse BVH text (bytes or str); ``path`` is only used in error messages."""
    if isinstance(raw, (bytearray, memoryview)):
        raw = bytes(raw)
    if (b"\x00" if isinstance(raw, bytes) else "\x00") in raw[:65536]:
        raise BVHError(path, None, "binary data, not a BVH text file")
    header = _ascii_header(raw, path) if isinstance(raw, bytes) else None
    text = None
    if header is None:  # small, non-ASCII or str input: decode it all
        text = _decode(raw, path)
        lines = _lines(text)
        skeleton, motion_lineno = _parse_hierarchy(lines, path)
        header = (skeleton, *_parse_motion_header(lines, motion_lineno, skeleton, path))
    skeleton, num_frames, fps, last_lineno, offset = header
    values = _parse_frames(raw, text, offset, last_lineno, num_frames, skeleton, path)
    rotations, positions, unwrapped = _channels_to_pose(skeleton, values)
    if unwrapped:
        skeleton = dataclasses.replace(skeleton, euler_style="continuous")
    return Motion(skeleton, rotations, positions, fps, source=values)


class _NeedMore(Exception):
    """The header runs past the decoded prefix of the file (internal)."""


def _ascii_header(raw: bytes, path: str):
    """Parse the header from an ASCII prefix of ``raw``, without decoding the frame data.

    Returns ``(skeleton, frames, fps, frame-time line number, byte offset of the frames)``,
    or None when the file is small, has no LF line breaks or a non-ASCII header (then the
    caller decodes the whole file). The prefix ends at a line break, so its lines and line
    numbers are those of the whole file and errors read the same.
    """
    size = 1 << 16
    while size < len(raw):
        cut = raw.rfind(b"\n", 0, size) + 1
        head = raw[:cut]
        if cut and head.isascii():
            lines = _lines(head.decode("ascii"), complete=False)
            try:
                skeleton, motion_lineno = _parse_hierarchy(lines, path)
                return (skeleton, *_parse_motion_header(lines, motion_lineno, skeleton, path))
            except _NeedMore:
                pass
        elif cut:
            return None
        size *= 4
    return None


def _decode(raw: bytes | str, path: str) -> str:
    """Text of a file: UTF-8 (a byte-order mark dropped), else Latin-1."""
    if isinstance(raw, str):
        return raw[1:] if raw.startswith("\ufeff") else raw
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _lines(text: str, complete: bool = True):
    """Lazily yield ``(line number, line, offset after its line break)`` as splitlines() cuts.

    With ``complete=False`` the text is a prefix of the file: running out of it raises
    :class:`_NeedMore` instead of ending.
    """
    start = 0
    lineno = 0
    for m in _LINE_BREAK.finditer(text):
        lineno += 1
        yield lineno, text[start:m.start()], m.end()
        start = m.end()
    if not complete:
        raise _NeedMore
    if start < len(text):
        yield lineno + 1, text[start:], len(text)


def _has_unwrapped_angles(sk: Skeleton, values: np.ndarray) -> bool:
    """True when some rotation channel leaves [-180, 180] degrees (a continuous exporter)."""
    cols = [c for rc in _layout(sk)[1] for c in rc]
    return bool(cols) and bool(np.any(np.abs(values[:, cols]) > 180.0 + 1e-9))


def _parse_hierarchy(lines, path: str) -> tuple[Skeleton, int]:
    """Parse HIERARCHY up to MOTION; returns the skeleton and the MOTION line number."""
    names, parents, offsets, channels, end_sites = [], [], [], [], []
    named_at: dict[str, int] = {}  # joint name -> its line
    stack: list[int] = []  # open joints; -2 marks an open End Site
    pending = None  # joint (or End Site) declared, waiting for its "{"
    seen_hierarchy = seen_text = False
    for lineno, line, _ in lines:
        tokens = line.split()
        if not tokens:
            continue
        seen_text = True
        key = tokens[0].upper()
        if pending is not None and key != "{":
            raise BVHError(path, lineno, f"expected '{{', found {tokens[0][:40]!r}")
        if key == "HIERARCHY":
            seen_hierarchy = True
        elif key == "MOTION":
            if stack:
                raise BVHError(path, lineno, "MOTION before the hierarchy's braces are closed")
            if not names:
                raise BVHError(path, lineno, "no joints before MOTION")
            sk = Skeleton(tuple(names), np.array(parents), np.array(offsets),
                          tuple(channels), tuple(end_sites))
            return sk, lineno
        elif not seen_hierarchy:
            raise BVHError(path, lineno, f"expected HIERARCHY, found {tokens[0][:40]!r}")
        elif key in ("ROOT", "JOINT"):
            if key == "ROOT" and stack:
                raise BVHError(path, lineno, "ROOT inside another joint")
            if key == "JOINT" and not stack:
                raise BVHError(path, lineno, "JOINT outside any ROOT")
            if stack and stack[-1] == -2:
                raise BVHError(path, lineno, "JOINT inside an End Site")
            if len(tokens) < 2:
                raise BVHError(path, lineno, f"{tokens[0]} without a name")
            if len(names) >= MAX_JOINTS:
                raise BVHError(path, lineno, f"more than {MAX_JOINTS} joints")
            name = " ".join(tokens[1:])
            if name in named_at:  # joints are found and written by name: one name, one joint
                raise BVHError(path, lineno, f"joint name {name[:40]!r} is used twice (also on line {named_at[name]})")
            named_at[name] = lineno
            names.append(name)
            parents.append(stack[-1] if stack else -1)
            offsets.append(None)
            channels.append(None)
            pending = len(names) - 1
        elif key == "END":
            if not stack or stack[-1] == -2:
                raise BVHError(path, lineno, "End Site in the wrong place")
            end_sites.append([stack[-1], None])
            pending = -2
        elif key == "{":
            if pending is None:
                raise BVHError(path, lineno, "'{' without a joint")
            stack.append(pending)
            if pending != -2 and len(stack) > MAX_DEPTH:
                raise BVHError(path, lineno, f"hierarchy nested more than {MAX_DEPTH} levels deep")
            pending = None
            if len(tokens) > 1:
                raise BVHError(path, lineno, "unexpected text after '{'")
        elif key == "}":
            if not stack:
                raise BVHError(path, lineno, "unbalanced '}'")
            j = stack.pop()
            if j == -2:
                if end_sites[-1][1] is None:
                    raise BVHError(path, lineno, "End Site without OFFSET")
            elif offsets[j] is None or channels[j] is None:
                raise BVHError(path, lineno, f"joint {names[j]!r} lacks OFFSET or CHANNELS")
        elif key == "OFFSET":
            if not stack:
                raise BVHError(path, lineno, "OFFSET outside a joint")
            off = _numbers(tokens[1:], 3, path, lineno, "OFFSET")
            if stack[-1] == -2:
                end_sites[-1][1] = off
            else:
                offsets[stack[-1]] = off
        elif key == "CHANNELS":
            if not stack or stack[-1] == -2:
                raise BVHError(path, lineno, "CHANNELS outside a joint")
            channels[stack[-1]] = _channels(tokens, path, lineno)
        else:
            raise BVHError(path, lineno, f"unexpected {tokens[0][:40]!r} in HIERARCHY")
    if not seen_hierarchy:
        raise BVHError(path, None, "no HIERARCHY section (not a BVH file?)" if seen_text else "empty file")
    raise BVHError(path, None, "missing MOTION section" + (" (unbalanced braces)" if stack else ""))


def _numbers(tokens: list[str], n: int, path: str, lineno: int, what: str) -> np.ndarray:
    if len(tokens) != n:
        raise BVHError(path, lineno, f"{what} needs {n} numbers, found {len(tokens)}")
    try:
        v = np.array([float(t) for t in tokens])
    except ValueError:
        raise BVHError(path, lineno, f"{what} has a non-numeric value") from None
    if not np.all(np.isfinite(v)):
        raise BVHError(path, lineno, f"{what} has a NaN or infinite value")
    if np.any(np.abs(v) > MAX_ABS_VALUE):
        raise BVHError(path, lineno, f"{what} has a value beyond +-{MAX_ABS_VALUE:g}")
    return v


def _channels(tokens: list[str], path: str, lineno: int) -> tuple[str, ...]:
    try:
        n = int(tokens[1])
    except (IndexError, ValueError):
        raise BVHError(path, lineno, "CHANNELS needs a count") from None
    names = tuple(tokens[2:])
    if n != len(names):
        raise BVHError(path, lineno, f"CHANNELS says {n} but lists {len(names)}")
    out = []
    for c in names:
        if c.lower() not in _CHANNEL_NAMES:
            raise BVHError(path, lineno, f"unknown channel {c[:40]!r}")
        out.append(_CHANNEL_NAMES[c.lower()])
    if len(set(out)) != len(out):
        raise BVHError(path, lineno, "a channel is listed twice")
    rot = [c for c in out if c in ROTATION_CHANNELS]
    if len(rot) not in (0, 3):
        raise BVHError(path, lineno, f"{len(rot)} rotation channels; need 0 or 3")
    return tuple(out)


def _header_value(line: str, keys: tuple[str, ...], path: str, lineno: int) -> str:
    """The text after a header such as 'Frame Time:' (any case, any spaces or tabs)."""
    words = " ".join(line.split())
    low = words.lower()
    for k in keys:
        if low.startswith(k):
            return words[len(k):].strip()
    raise BVHError(path, lineno, f"expected '{keys[0].title()}', found {words[:40]!r}")


def _next_nonblank(lines):
    """The next ``(line number, line, offset)`` that is not blank, or None at the end."""
    for item in lines:
        if item[1].strip():
            return item
    return None


def _parse_motion_header(lines, motion_lineno: int, sk: Skeleton,
                         path: str) -> tuple[int, float, int, int]:
    """Read 'Frames:' and 'Frame Time:' after MOTION.

    Returns the frame count, the fps, the line number of the 'Frame Time' line and the text
    offset where the frame lines start.
    """
    item = _next_nonblank(lines)
    if item is None:
        raise BVHError(path, motion_lineno, "MOTION without a frame count")
    lineno, line, _ = item
    frames_txt = _header_value(line, ("frames:", "frames", "numframes:"), path, lineno)
    try:
        count = float(frames_txt)
    except ValueError:
        raise BVHError(path, lineno, f"frame count {frames_txt[:40]!r} is not a number") from None
    if not (np.isfinite(count) and count == int(count)):
        raise BVHError(path, lineno, f"frame count {frames_txt[:40]!r} is not a whole number")
    num_frames = int(count)
    num_channels = sum(len(c) for c in sk.channels)
    if num_frames < 1 or num_frames * max(num_channels, 1) > MAX_VALUES:
        raise BVHError(path, lineno, f"absurd frame count {num_frames}")
    item = _next_nonblank(lines)
    if item is None:
        raise BVHError(path, lineno, "missing 'Frame Time:'")
    lineno, line, offset = item
    ft_txt = _header_value(line, ("frame time:", "frametime:", "frame time", "frametime"), path, lineno)
    try:
        frame_time = float(ft_txt)
    except ValueError:
        raise BVHError(path, lineno, f"frame time {ft_txt[:40]!r} is not a number") from None
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise BVHError(path, lineno, f"frame time must be a positive number, got {ft_txt[:40]!r}")
    if not MIN_FRAME_TIME <= frame_time <= MAX_FRAME_TIME:
        raise BVHError(path, lineno, f"frame time {ft_txt[:40]} is out of range (must be a positive number from "
                                     f"{MIN_FRAME_TIME:g} to {MAX_FRAME_TIME:g} s: {1 / MAX_FRAME_TIME:g} to "
                                     f"{1 / MIN_FRAME_TIME:g} frames per second)")
    return num_frames, 1.0 / frame_time, lineno, offset


def _parse_frames(raw: bytes | str, text: str | None, offset: int, last_lineno: int,
                  num_frames: int, sk: Skeleton, path: str) -> np.ndarray:
    """Frame values (F, C) in file order from the text after the 'Frame Time' line.

    ``raw`` is the input as given; ``text`` its decoded text, or None when only the (ASCII)
    header was decoded, so that ``offset`` is a byte offset into ``raw`` too; ``last_lineno``
    is the line number of the 'Frame Time' line.
    """
    num_channels = sum(len(c) for c in sk.channels)
    kernels = _fast_kernels()
    if kernels is not None and num_channels > 0:
        values = _parse_frames_fast(kernels, raw, text, offset, num_frames, num_channels)
        if values is not None and np.all(np.abs(values) <= MAX_ABS_VALUE):
            return values  # (else the general parser says which line is out of range)
    if text is None:
        text = _decode(raw, path)
    return _parse_frames_general(text[offset:], last_lineno, num_frames, num_channels, path)


def _parse_frames_fast(kernels, raw: bytes | str, text: str | None, offset: int,
                       num_frames: int, num_channels: int) -> np.ndarray | None:
    """The kernel's parse, or None when the text needs the general parser."""
    if text is None or (isinstance(raw, bytes) and text.isascii() and len(text) == len(raw)):
        buf = np.frombuffer(raw, dtype=np.uint8, offset=offset)  # byte offset = text offset
    else:
        try:
            buf = np.frombuffer(text[offset:].encode("ascii"), dtype=np.uint8)
        except UnicodeEncodeError:
            return None
    if num_frames * num_channels > (buf.size + 1) // 2:
        return None  # too short for the count (a value takes 2 bytes): no huge allocation
    if buf[-1] not in _WHITESPACE:  # the kernel needs a whitespace at the end
        buf = np.concatenate([buf, np.array([10], dtype=np.uint8)])
    out = np.empty(num_frames * num_channels)
    slow = np.empty((_MAX_SLOW_TOKENS, 3), dtype=np.int64)
    status, num_slow = kernels.parse_frames(buf, num_frames, num_channels, out, slow)
    if status != 0:
        return None
    for k, start, end in slow[:num_slow]:  # numbers beyond the exact fast path: Python's float
        out[k] = float(buf[start:end].tobytes())
    if num_slow and not np.all(np.isfinite(out[slow[:num_slow, 0]])):
        return None  # 1e999 and the like: the general parser says where
    return out.reshape(num_frames, num_channels)


def _parse_frames_general(body_text: str, last_lineno: int, num_frames: int, num_channels: int,
                          path: str) -> np.ndarray:
    """The reference frame parser: any whitespace, any number Python's ``float`` reads.

    Blank lines among the frames are skipped; ``last_lineno`` is the line number of the
    'Frame Time' line (error messages give the file's own line numbers).
    """
    numbered = [(last_lineno + k + 1, line) for k, line in enumerate(body_text.splitlines())
                if line.strip()]
    if len(numbered) < num_frames:
        raise BVHError(path, numbered[-1][0] if numbered else last_lineno,
                       f"truncated: {len(numbered)} frame lines but 'Frames: {num_frames}'")
    if len(numbered) > num_frames:
        raise BVHError(path, numbered[num_frames][0],
                       f"{len(numbered) - num_frames} frame lines beyond 'Frames: {num_frames}'")
    rows = [line.split() for _, line in numbered]
    for (lineno, _), row in zip(numbered, rows):
        if len(row) != num_channels:
            raise BVHError(path, lineno, f"frame has {len(row)} values, expected {num_channels}")
    try:
        values = np.array(rows, dtype=np.float64).reshape(num_frames, num_channels)
    except ValueError:  # numpy is stricter than float() on a few spellings; say which token
        values = np.array([[_float(t, path, lineno) for t in row]
                           for (lineno, _), row in zip(numbered, rows)]).reshape(num_frames, num_channels)
    bad = ~np.isfinite(values)
    if bad.any():
        f = int(np.argmax(bad.any(axis=1)))
        raise BVHError(path, numbered[f][0], "NaN or infinite value in frame data")
    huge = np.abs(values) > MAX_ABS_VALUE
    if huge.any():
        f = int(np.argmax(huge.any(axis=1)))
        raise BVHError(path, numbered[f][0], f"value beyond +-{MAX_ABS_VALUE:g} in frame data")
    return values


def _float(token: str, path: str, lineno: int) -> float:
    try:
        return float(token)
    except ValueError:
        raise BVHError(path, lineno, f"non-numeric value {token[:40]!r}") from None


def _layout(sk: Skeleton):
    """Column indices: for each joint, position columns by axis (or -1) and rotation columns."""
    col = 0
    pos_cols = np.full((sk.num_joints, 3), -1, dtype=np.int64)
    rot_cols = []
    for j, chans in enumerate(sk.channels):
        rc = []
        for c in chans:
            if c in POSITION_CHANNELS:
                pos_cols[j, "XYZ".index(c[0])] = col
            else:
                rc.append(col)
            col += 1
        rot_cols.append(rc)
    return pos_cols, rot_cols


def _channels_to_pose(sk: Skeleton, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Local rotations (F, J, 4), translations (F, J, 3) and whether angles leave [-180, 180]."""
    num_frames = values.shape[0]
    pos_cols, rot_cols = _layout(sk)
    positions = np.broadcast_to(sk.offsets, (num_frames, sk.num_joints, 3)).copy()
    jj, aa = np.nonzero(pos_cols >= 0)
    positions[:, jj, aa] = values[:, pos_cols[jj, aa]]
    rotations = np.empty((num_frames, sk.num_joints, 4))
    joints = [j for j in range(sk.num_joints) if rot_cols[j]]
    rotations[:, [j for j in range(sk.num_joints) if not rot_cols[j]]] = quat.identity()
    if not joints:
        return rotations, positions, False
    kernels = _fast_kernels()
    if kernels is not None:
        axes = np.array([["XYZ".index(o) for o in sk.rotation_order(j)] for j in joints])
        cols = np.array([rot_cols[j] for j in joints])
        unwrapped = kernels.euler_to_quat(values, np.array(joints), cols, axes, rotations)
        return rotations, positions, bool(unwrapped)
    # Group joints by Euler order: one vectorised conversion per order.
    by_order: dict[str, list[int]] = {}
    for j in joints:
        by_order.setdefault(sk.rotation_order(j), []).append(j)
    for order, group in by_order.items():
        cols = np.array([rot_cols[j] for j in group])
        rotations[:, group] = quat.from_euler(np.radians(values[:, cols]), order)
    return rotations, positions, _has_unwrapped_angles(sk, values)


# --- Kernels: plain Python here, compiled with numba on first use (cached on disk) ----------

_WHITESPACE = (32, 9, 10, 13)  # space, tab, LF, CR: the separators the kernel accepts
_MAX_SLOW_TOKENS = 4096  # numbers the kernel hands to Python's float; more: general parser
_POW10 = np.array([10.0 ** k for k in range(23)])  # exact doubles
_SCALE_MUL = np.concatenate([np.ones(22), _POW10])  # index exponent + 22, exponent in [-22, 22]
_SCALE_DIV = np.concatenate([_POW10[:0:-1], np.ones(23)])


def _parse_frames_kernel(buf, num_frames, num_channels, out, slow):
    """Parse frame lines of decimal numbers from ASCII bytes ``buf`` into ``out`` (F * C).

    ``buf`` must end with a whitespace byte. Returns ``(status, num_slow)``: status 0 when
    ``buf`` holds exactly ``num_frames`` lines of ``num_channels`` numbers (blank lines are
    skipped), otherwise a code > 0 and the caller uses the general parser. Accepted: spaces,
    tabs, line breaks (LF, CRLF, CR) and numbers ``[+-]digits[.digits][(e|E)[+-]digits]``.
    A number with at most 18 digits, a mantissa (the digits as an integer) up to 2**53 and
    a decimal exponent within +-22 is an exact double times an exact power of ten, so one
    correctly rounded multiplication or division gives exactly Python's ``float``
    (Clinger's fast path); the others are listed in ``slow`` as (index, start, end) for the
    caller to convert (at most ``len(slow)``).
    """
    n = buf.size
    total = num_frames * num_channels
    num_slow = 0
    k = 0  # values written
    line = 0  # complete frame lines
    on_line = 0  # values on the current line
    i = 0
    while i < n:
        c = buf[i]
        if c == 32 or c == 9:
            i += 1
            continue
        if c == 10 or c == 13:
            i += 2 if c == 13 and i + 1 < n and buf[i + 1] == 10 else 1
            if on_line == num_channels:
                line += 1
                on_line = 0
            elif on_line > 0:
                return 1, num_slow  # a short line
            continue
        if k >= total or on_line >= num_channels:
            return 2, num_slow  # extra values or lines
        start = i
        sign = 1.0 - 2.0 * (c == 45)
        i += (c == 45) | (c == 43)
        # Digits, a point, digits (one loop); the whitespace at the end of buf stops it.
        mantissa = 0
        digits = 0
        exponent = 0  # minus the digits after the point
        point = False
        while True:
            d = np.int64(buf[i]) - 48
            if np.uint64(d) < 10:
                mantissa = mantissa * 10 + d
                digits += 1
                exponent -= point
            elif d == -2 and not point:  # "."
                point = True
            else:
                break
            i += 1
        if digits == 0:
            return 3, num_slow
        c = buf[i]
        if c == 101 or c == 69:  # "e" or "E"
            i += 1
            e_negative = buf[i] == 45
            i += (buf[i] == 45) | (buf[i] == 43)
            e = 0
            first = i
            d = np.int64(buf[i]) - 48
            while np.uint64(d) < 10:
                if e < 100000:
                    e = e * 10 + d
                i += 1
                d = np.int64(buf[i]) - 48
            if i == first:
                return 3, num_slow
            exponent += -e if e_negative else e
            c = buf[i]
        if not (c == 32 or c == 9 or c == 10 or c == 13):
            return 3, num_slow
        if mantissa == 0 and digits <= 18:
            exponent = 0
        if digits <= 18 and mantissa <= 9007199254740992 and -22 <= exponent <= 22:
            out[k] = sign * (float(mantissa) * _SCALE_MUL[exponent + 22] / _SCALE_DIV[exponent + 22])
        elif num_slow < slow.shape[0]:
            slow[num_slow, 0], slow[num_slow, 1], slow[num_slow, 2] = k, start, i
            num_slow += 1
        else:
            return 4, num_slow
        k += 1
        on_line += 1
    if on_line == num_channels:
        line += 1
    elif on_line > 0:
        return 1, num_slow
    return (0 if line == num_frames and k == total else 5), num_slow


# fdlibm's kernel coefficients: sin and cos on [-pi/4, pi/4] to within an ulp.
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


def _euler_to_quat_kernel(values, joints, cols, axes, out):
    """Quaternions ``out[f, joints[n]]`` of intrinsic Euler angles in degrees.

    The angles of joint ``joints[n]`` are ``values[f, cols[n]]`` about the axes ``axes[n]``
    (0 = X, 1 = Y, 2 = Z), composed as :func:`quat.from_euler` does. Works frame by frame
    with small buffers (no frame-sized temporaries). Returns True when some angle leaves
    [-180, 180] degrees (a continuous exporter).
    """
    num_joints = joints.shape[0]
    deg = np.empty(3 * num_joints)
    cos_half = np.empty(3 * num_joints)
    sin_half = np.empty(3 * num_joints)
    largest = 0.0
    for f in range(out.shape[0]):
        for n in range(num_joints):
            for r in range(3):
                d = values[f, cols[n, r]]
                largest = max(largest, abs(d))
                # Beyond 1e15 degrees reduce exactly first (a half-angle period is 720).
                deg[3 * n + r] = np.fmod(d, 720.0) if abs(d) > 1e15 else d
        # Half-angle cosines and sines in one branch-free (vectorised) loop: each angle is
        # reduced exactly in degrees to within 90 of a multiple of 180 (180 * quarter is an
        # integer below 2**53), then fdlibm's polynomials give the result within an ulp or two
        # of np.cos / np.sin.
        for p in range(deg.size):
            quarter = np.rint(deg[p] * (1.0 / 180.0))  # quarter turns of the half angle
            t = (deg[p] - 180.0 * quarter) * (np.pi / 360.0)  # |t| <= pi/4; exact subtraction
            tt = t * t
            sin_t = t + t * tt * (_S1 + tt * (_S2 + tt * (_S3 + tt * (_S4 + tt * (_S5 + tt * _S6)))))
            half_tt = 0.5 * tt
            one_minus = 1.0 - half_tt
            cos_t = one_minus + (((1.0 - one_minus) - half_tt) + tt * tt * (
                _C1 + tt * (_C2 + tt * (_C3 + tt * (_C4 + tt * (_C5 + tt * _C6))))))
            m = quarter - 4.0 * np.floor(quarter * 0.25)  # 0, 1, 2 or 3
            odd = m == 1.0 or m == 3.0
            sin_q = cos_t if odd else sin_t
            cos_q = sin_t if odd else cos_t
            cos_half[p] = -cos_q if (m == 1.0 or m == 2.0) else cos_q
            sin_half[p] = -sin_q if m >= 2.0 else sin_q
        for n in range(num_joints):
            w, x, y, z = 1.0, 0.0, 0.0, 0.0
            for r in range(3):
                c, s = cos_half[3 * n + r], sin_half[3 * n + r]
                a = axes[n, r]
                if a == 0:
                    w, x, y, z = w * c - x * s, x * c + w * s, y * c + z * s, z * c - y * s
                elif a == 1:
                    w, x, y, z = w * c - y * s, x * c - z * s, y * c + w * s, z * c + x * s
                else:
                    w, x, y, z = w * c - z * s, x * c + y * s, y * c - x * s, z * c + w * s
            j = joints[n]
            out[f, j, 0], out[f, j, 1], out[f, j, 2], out[f, j, 3] = w, x, y, z
    return largest > 180.0 + 1e-9


_KERNELS: list = []  # [namespace or None] once _fast_kernels() has run


def _fast_kernels():
    """The compiled kernels (see :class:`_Kernels`), or None to parse with numpy.

    Compiled only once something in this process has loaded numba through
    :func:`posturemap.core.kernels.compiled` (training, the studio, benchmarks; ``train`` and
    ``serve`` load it before reading): reading a few files with numpy (about 20 ms a MB) is
    faster than importing numba (about half a second). Compiled code is cached on disk, so
    only the very first read on a machine pays for compilation.
    """
    from ..core import kernels

    if kernels.backend() != "numba":
        return None
    if not _KERNELS:
        try:
            import numba
        except ImportError:  # pragma: no cover - numba is a dependency; numpy path as fallback
            _KERNELS.append(None)
        else:
            jit = numba.njit(cache=True, nogil=True)
            _KERNELS.append(_Kernels(jit(_parse_frames_kernel), jit(_euler_to_quat_kernel)))
    return _KERNELS[0]


@dataclasses.dataclass(frozen=True)
class _Kernels:
    parse_frames: object
    euler_to_quat: object


def _pose_to_channels(motion: Motion) -> np.ndarray:
    sk = motion.skeleton
    pos_cols, rot_cols = _layout(sk)
    num_channels = sum(len(c) for c in sk.channels)
    values = np.zeros((motion.num_frames, num_channels))
    jj, aa = np.nonzero(pos_cols >= 0)
    values[:, pos_cols[jj, aa]] = motion.positions[:, jj, aa]
    by_order: dict[str, list[int]] = {}
    for j in range(sk.num_joints):
        if rot_cols[j]:
            by_order.setdefault(sk.rotation_order(j), []).append(j)
    for order, joints in by_order.items():
        euler = quat.to_euler(motion.rotations[:, joints], order)
        if sk.euler_style == "continuous":
            euler = continuous_euler(euler, order)
        values[:, np.array([rot_cols[j] for j in joints])] = np.degrees(euler)
    if motion.source is not None and motion.source.shape == values.shape:
        values = _with_source_values(motion, values, pos_cols, rot_cols)
    return values


def _with_source_values(motion: Motion, values: np.ndarray, pos_cols, rot_cols) -> np.ndarray:
    """``values`` (F, C) with the file's own numbers wherever a joint's pose is unchanged.

    A joint's rotation channels of a frame take ``motion.source``'s triple when it encodes the
    frame's rotation (quaternion dot within 1e-12 of 1), a position channel its value when
    equal within 1e-9; the other (generated or changed) runs of frames are turned by whole
    360-degree steps, in continuous style, to continue from the frame before them (or, at the
    start, into the frame after them), so that no curve jumps where the file's did not.
    """
    sk = motion.skeleton
    src = motion.source
    known = np.all(np.isfinite(src), axis=1)
    if not known.any():
        return values
    filled = np.where(known[:, None], src, 0.0)
    src_rot, src_pos = _channels_to_pose(sk, filled)[:2]
    out = values.copy()
    jj, aa = np.nonzero(pos_cols >= 0)
    for j, a in zip(jj, aa):
        c = pos_cols[j, a]
        same = known & (np.abs(src[:, c] - motion.positions[:, j, a]) <= 1e-9 * (1.0 + np.abs(src[:, c])))
        out[same, c] = src[same, c]
    continuous = sk.euler_style == "continuous"
    for j, cols in enumerate(rot_cols):
        if not cols:
            continue
        dot = np.abs(np.einsum("fc,fc->f", src_rot[:, j], motion.rotations[:, j]))
        same = known & (dot >= 1.0 - 1e-12)
        cols = np.array(cols)
        out[np.ix_(same, cols)] = src[np.ix_(same, cols)]
        if continuous and same.any() and not same.all():
            _continue_runs(out, cols, same)
    return out


def _continue_runs(out: np.ndarray, cols: np.ndarray, fixed: np.ndarray) -> None:
    """Turn each run of rows not ``fixed`` by 360-degree steps (per column) to meet its neighbour."""
    f = len(fixed)
    edges = np.flatnonzero(np.diff(np.concatenate([[1], fixed.astype(np.int8), [1]])))
    for start, end in zip(edges[::2], edges[1::2]):  # rows start..end-1 are not fixed
        ref, at = (start - 1, start) if start > 0 else (end, end - 1)
        if ref >= f:
            continue
        step = 360.0 * np.round((out[ref, cols] - out[at, cols]) / 360.0)
        out[start:end, cols] += step


def continuous_euler(euler: np.ndarray, order: str) -> np.ndarray:
    """Euler angles (F, ..., 3) in radians made continuous over frames (axis 0).

    Each frame takes its triple's 360-degree turn nearest the previous frame, so angles may
    leave [-180, 180], as exporters that write continuous curves (CMU's) do. The equivalent
    second triple (Tait-Bryan middle angle past 90 degrees) is taken over only where it is
    less than half as far from the previous frame: at a gimbal-lock passage, where staying
    would jump.
    """
    if order[0] == order[2]:  # proper Euler: (a, b, c) ~ (a + pi, -b, c + pi)
        alt = euler * np.array([1.0, -1.0, 1.0]) + np.array([np.pi, 0.0, np.pi])
    else:  # Tait-Bryan: (a, b, c) ~ (a + pi, pi - b, c + pi)
        alt = np.stack([euler[..., 0] + np.pi, np.pi - euler[..., 1], euler[..., 2] + np.pi], -1)
    out = np.empty_like(euler)
    out[0] = euler[0]
    on_alt = np.zeros(euler.shape[1:-1], dtype=bool)
    two_pi = 2.0 * np.pi
    for f in range(1, len(euler)):
        prev = out[f - 1]
        a = euler[f] + two_pi * np.round((prev - euler[f]) / two_pi)
        b = alt[f] + two_pi * np.round((prev - alt[f]) / two_pi)
        da = np.sum((a - prev) ** 2, axis=-1)
        db = np.sum((b - prev) ** 2, axis=-1)
        on_alt = np.where(on_alt, ~(da < 0.25 * db), db < 0.25 * da)
        out[f] = np.where(on_alt[..., None], b, a)
    return out


def check_finite(motion: Motion, where: str = "output") -> None:
    """Raise :class:`BVHError` when ``motion`` has no frames or a NaN or infinite value (nothing
    to write: the reader refuses a file of no frames)."""
    if not len(motion):
        raise BVHError(where, None, "refusing to write a motion with no frames; nothing written")
    if not np.isfinite(motion.fps) or motion.fps <= 0:
        raise BVHError(where, None, f"refusing to write a motion with frame rate {motion.fps!r}")
    for name, a in (("rotation", motion.rotations), ("translation", motion.positions)):
        bad = ~np.isfinite(a)
        if bad.any():
            f, j = (int(k) for k in np.argwhere(bad)[0][:2])
            raise BVHError(where, None, f"refusing to write NaN or infinite values (frame {f}, "
                                        f"joint {motion.skeleton.names[j]!r}, {name}); nothing written")


_MAX_INDENT = 32  # indentation levels the writer shows; deeper joints share the last one


def dumps(motion: Motion) -> str:
    """BVH text of ``motion`` with its skeleton's hierarchy and channel layout.

    A motion with a NaN or infinite rotation, translation or frame rate raises
    :class:`BVHError` (a BVH file cannot hold it, and no reader would take it back).
    """
    sk = motion.skeleton
    check_finite(motion)
    out = io.StringIO()
    out.write("HIERARCHY\n")
    ends = {j: o for j, o in sk.end_sites}
    children = [[] for _ in range(sk.num_joints)]
    for j, p in enumerate(sk.parents):
        if p >= 0:
            children[p].append(j)
    fmt = "{:.9g}"
    # Iterative depth-first walk (no recursion limit): ("open", j) writes a joint, ("close", j) its brace.
    todo = [("open", j, 0) for j in reversed(range(sk.num_joints)) if sk.parents[j] < 0]
    order = []  # the joints as written: the MOTION lines give their channels in this order
    while todo:
        kind, j, depth = todo.pop()
        pad = "  " * min(depth, _MAX_INDENT)  # capped: a deep chain must not grow quadratically
        if kind == "close":
            out.write(f"{pad}}}\n")
            continue
        head = "ROOT" if sk.parents[j] < 0 else "JOINT"
        order.append(j)
        out.write(f"{pad}{head} {sk.names[j]}\n{pad}{{\n")
        out.write(f"{pad}  OFFSET {' '.join(fmt.format(v) for v in sk.offsets[j])}\n")
        out.write(f"{pad}  CHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}\n")
        if j in ends:
            out.write(f"{pad}  End Site\n{pad}  {{\n{pad}    OFFSET "
                      f"{' '.join(fmt.format(v) for v in ends[j])}\n{pad}  }}\n")
        todo.append(("close", j, depth))
        todo.extend(("open", c, depth + 1) for c in reversed(children[j]))
    out.write(f"MOTION\nFrames: {motion.num_frames}\nFrame Time: {1.0 / motion.fps:.9g}\n")
    values = _pose_to_channels(motion)  # the joints' channels in index order
    if order != sorted(order):  # a skeleton built in another order than depth first (a file's is not)
        start = np.concatenate([[0], np.cumsum([len(c) for c in sk.channels])])
        values = values[:, np.concatenate([np.arange(start[j], start[j + 1]) for j in order]).astype(np.int64)]
    values[np.abs(values) < 1e-12] = 0.0
    np.savetxt(out, values, fmt="%.9g", delimiter=" ")
    return out.getvalue()


def write(path: str | os.PathLike, motion: Motion) -> None:
    """Write ``motion`` to ``path`` atomically (temporary file in the same folder, then rename).

    A folder that is missing or not writable, a full disk and the like raise :class:`BVHError`
    naming the file; no temporary file is left behind and an existing file stays as it was.
    """
    path = os.fspath(path)
    check_finite(motion, path)
    data = dumps(motion).encode("utf-8")
    try:
        write_bytes_atomic(path, data)
    except OSError as e:
        raise BVHError(os.fspath(path), None, f"cannot write file ({e.strerror or e})") from None
