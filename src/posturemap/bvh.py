"""Read and write BVH motion capture files.

Reading gives a :class:`~posturemap.motion.Motion`; writing reproduces the hierarchy and the
channel layout (any rotation order per joint, 3- or 6-channel joints, End Sites). Joints with
position channels take their translation from the channels (the OFFSET is kept for writing
back); the others use their OFFSET.

The frame data is read in one pass without per-line Python work: a numba kernel parses the
numbers straight from the bytes and another turns Euler angles into quaternions. Text the
kernel does not recognise (unusual whitespace or number syntax, a wrong line) goes through
the general numpy path, which is the reference for what is accepted and for the error
messages; numbers the kernel does parse come out bit-identical to Python's ``float``.

Every problem with a file raises :class:`BVHError` naming the file, the line and what is wrong.
"""

from __future__ import annotations

import dataclasses
import io
import os
import re
import tempfile

import numpy as np

from . import quat
from .errors import UserError
from .motion import Motion
from .skeleton import POSITION_CHANNELS, ROTATION_CHANNELS, Skeleton

MAX_JOINTS = 10_000
MAX_VALUES = 500_000_000  # frames * channels; beyond this a file is not motion capture

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
        with open(path, "rb") as f:
            raw = f.read()
    except OSError as e:
        raise BVHError(path, None, f"cannot read file ({e.strerror or e})") from None
    return loads(raw, path)


def loads(raw: bytes | str, path: str = "<string>") -> Motion:
    """Parse BVH text (bytes or str); ``path`` is only used in error messages."""
    text = _decode(raw, path)
    lines = _lines(text)
    skeleton, motion_lineno = _parse_hierarchy(lines, path)
    num_frames, fps, last_lineno, offset = _parse_motion_header(lines, motion_lineno, skeleton, path)
    ascii_raw = raw if isinstance(raw, bytes) and raw.isascii() else None
    values = _parse_frames(text, ascii_raw, offset, last_lineno, num_frames, skeleton, path)
    rotations, positions, unwrapped = _channels_to_pose(skeleton, values)
    if unwrapped:
        skeleton = dataclasses.replace(skeleton, euler_style="continuous")
    return Motion(skeleton, rotations, positions, fps)


def _decode(raw: bytes | str, path: str) -> str:
    """Text of a file: UTF-8 (a byte-order mark dropped), else Latin-1; binary data refused."""
    if isinstance(raw, str):
        return raw[1:] if raw.startswith("\ufeff") else raw
    if b"\x00" in raw[:65536]:
        raise BVHError(path, None, "binary data, not a BVH text file")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _lines(text: str):
    """Lazily yield ``(line number, line, offset after its line break)`` as splitlines() cuts."""
    start = 0
    lineno = 0
    for m in _LINE_BREAK.finditer(text):
        lineno += 1
        yield lineno, text[start:m.start()], m.end()
        start = m.end()
    if start < len(text):
        yield lineno + 1, text[start:], len(text)


def _has_unwrapped_angles(sk: Skeleton, values: np.ndarray) -> bool:
    """True when some rotation channel leaves [-180, 180] degrees (a continuous exporter)."""
    cols = [c for rc in _layout(sk)[1] for c in rc]
    return bool(cols) and bool(np.any(np.abs(values[:, cols]) > 180.0 + 1e-9))


def _parse_hierarchy(lines, path: str) -> tuple[Skeleton, int]:
    """Parse HIERARCHY up to MOTION; returns the skeleton and the MOTION line number."""
    names, parents, offsets, channels, end_sites = [], [], [], [], []
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
            names.append(" ".join(tokens[1:]))
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
    return v


def _channels(tokens: list[str], path: str, lineno: int) -> tuple[str, ...]:
    try:
        n = int(tokens[1])
    except (IndexError, ValueError):
        raise BVHError(path, lineno, "CHANNELS needs a count") from None
    names = tuple(tokens[2:])
    if n != len(names):
        raise BVHError(path, lineno, f"CHANNELS says {n} but lists {len(names)}")
    valid = {c.lower(): c for c in POSITION_CHANNELS + ROTATION_CHANNELS}
    out = []
    for c in names:
        if c.lower() not in valid:
            raise BVHError(path, lineno, f"unknown channel {c[:40]!r}")
        out.append(valid[c.lower()])
    if len(set(out)) != len(out):
        raise BVHError(path, lineno, "a channel is listed twice")
    rot = [c for c in out if c in ROTATION_CHANNELS]
    if len(rot) not in (0, 3):
        raise BVHError(path, lineno, f"{len(rot)} rotation channels; need 0 or 3")
    return tuple(out)


def _header_value(line: str, keys: tuple[str, ...], path: str, lineno: int) -> str:
    low = line.strip().lower()
    for k in keys:
        if low.startswith(k):
            return line.strip()[len(k):].strip()
    raise BVHError(path, lineno, f"expected '{keys[0].title()}', found {line.strip()[:40]!r}")


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
    if not (np.isfinite(frame_time) and frame_time > 0 and np.isfinite(1.0 / frame_time)):
        raise BVHError(path, lineno, f"frame time must be a positive number, got {ft_txt[:40]!r}")
    return num_frames, 1.0 / frame_time, lineno, offset


def _parse_frames(text: str, ascii_raw: bytes | None, offset: int, last_lineno: int,
                  num_frames: int, sk: Skeleton, path: str) -> np.ndarray:
    """Frame values (F, C) in file order from the text after the 'Frame Time' line.

    ``ascii_raw`` is the file's bytes when they are pure ASCII (then byte and character
    offsets agree and the kernel reads them without a copy); ``last_lineno`` is the line
    number of the 'Frame Time' line.
    """
    num_channels = sum(len(c) for c in sk.channels)
    kernels = _fast_kernels()
    if kernels is not None and num_channels > 0:
        if ascii_raw is not None:
            buf = np.frombuffer(ascii_raw, dtype=np.uint8, offset=offset)
        else:
            try:
                buf = np.frombuffer(text[offset:].encode("ascii"), dtype=np.uint8)
            except UnicodeEncodeError:
                buf = None
        if buf is not None:
            out = np.empty(num_frames * num_channels)
            if kernels.parse_frames(buf, num_frames, num_channels, out) == 0:
                return out.reshape(num_frames, num_channels)
    return _parse_frames_general(text[offset:], last_lineno, num_frames, num_channels, path)


def _parse_frames_general(body_text: str, last_lineno: int, num_frames: int, num_channels: int,
                          path: str) -> np.ndarray:
    """The reference frame parser (numpy): any whitespace, any number Python's float reads."""
    first = last_lineno  # frame line k (from 0) is line first + k + 1
    body = body_text.splitlines()
    while body and not body[-1].strip():
        body.pop()
    if len(body) < num_frames:
        raise BVHError(path, first + len(body),
                       f"truncated: {len(body)} frame lines but 'Frames: {num_frames}'")
    if len(body) > num_frames:
        raise BVHError(path, first + num_frames + 1,
                       f"{len(body) - num_frames} frame lines beyond 'Frames: {num_frames}'")
    rows = [line.split() for line in body]
    if any(len(r) != num_channels for r in rows):
        _locate_bad_line(body, first, num_channels, path)
    try:
        values = np.array(rows, dtype=np.float64).reshape(num_frames, num_channels)
    except ValueError:
        _locate_bad_line(body, first, num_channels, path)
    bad = ~np.isfinite(values)
    if bad.any():
        f = int(np.argmax(bad.any(axis=1)))
        raise BVHError(path, first + f + 1, "NaN or infinite value in frame data")
    return values


def _locate_bad_line(body: list[str], first: int, num_channels: int, path: str):
    """Slow path, only on error: find the first frame line that is wrong and say why."""
    for k, line in enumerate(body):
        tokens = line.split()
        if len(tokens) != num_channels:
            raise BVHError(path, first + k + 1,
                           f"frame has {len(tokens)} values, expected {num_channels}")
        for t in tokens:
            try:
                float(t)
            except ValueError:
                raise BVHError(path, first + k + 1, f"non-numeric value {t[:40]!r}") from None
    raise BVHError(path, first, "malformed frame data")


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
    rotations = np.zeros((num_frames, sk.num_joints, 4))
    rotations[..., 0] = 1.0
    joints = [j for j in range(sk.num_joints) if rot_cols[j]]
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

def _parse_frames_kernel(buf, num_frames, num_channels, out):
    """Parse frame lines of plain decimal numbers from ASCII bytes ``buf`` into ``out``.

    Returns 0 when ``buf`` holds exactly ``num_frames`` lines of ``num_channels`` numbers
    (then blank lines only) and ``out`` (size F * C) is filled; otherwise a code > 0 and the
    caller uses the general parser. Accepted: spaces, tabs, line breaks (LF, CRLF, CR) and
    numbers ``[+-]digits[.digits][(e|E)[+-]digits]`` with at most 18 digits, a mantissa (the
    digits as an integer) up to 2**53 and a decimal exponent within +-22. Such a number is an
    exact double times an exact power of ten, so one correctly rounded multiplication or
    division gives exactly Python's ``float`` (Clinger's fast path).
    """
    n = buf.size
    total = num_frames * num_channels
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
            elif on_line > 0 or line < num_frames:
                return 1  # short line, or a blank line among the frames
            continue
        if k >= total or on_line >= num_channels:
            return 2  # extra values or lines
        negative = c == 45
        if c == 45 or c == 43:
            i += 1
        # Digits before and after the point; leading zeros add nothing to the mantissa.
        mantissa = 0
        start = i
        while i < n and 48 <= buf[i] <= 57:
            mantissa = mantissa * 10 + (buf[i] - 48)
            i += 1
        digits = i - start
        exponent = 0
        if i < n and buf[i] == 46:
            i += 1
            start = i
            while i < n and 48 <= buf[i] <= 57:
                mantissa = mantissa * 10 + (buf[i] - 48)
                i += 1
            exponent = start - i
            digits += i - start
        if digits == 0:
            return 3
        if digits > 18 or mantissa > 9007199254740992:  # 2**53: beyond, float(mantissa) rounds
            return 3
        if i < n and (buf[i] == 101 or buf[i] == 69):
            i += 1
            e_negative = i < n and buf[i] == 45
            if i < n and (buf[i] == 45 or buf[i] == 43):
                i += 1
            e = 0
            e_digits = 0
            while i < n and 48 <= buf[i] <= 57:
                if e < 100000:
                    e = e * 10 + (buf[i] - 48)
                e_digits += 1
                i += 1
            if e_digits == 0:
                return 3
            exponent += -e if e_negative else e
        if i < n and not (buf[i] == 32 or buf[i] == 9 or buf[i] == 10 or buf[i] == 13):
            return 3
        v = float(mantissa)
        if mantissa != 0:
            if exponent < -22 or exponent > 22:
                return 4
            if exponent < 0:
                v = v / _POW10[-exponent]
            elif exponent > 0:
                v = v * _POW10[exponent]
        out[k] = -v if negative else v
        k += 1
        on_line += 1
    if on_line == num_channels:
        line += 1
    elif on_line > 0:
        return 1
    return 0 if line == num_frames and k == total else 5


def _euler_to_quat_kernel(values, joints, cols, axes, out):
    """Quaternions ``out[f, joints[n]]`` of intrinsic Euler angles in degrees.

    The angles of joint ``joints[n]`` are ``values[f, cols[n]]`` about the axes ``axes[n]``
    (0 = X, 1 = Y, 2 = Z), composed as :func:`quat.from_euler` does (bit-identical result).
    Returns True when some angle leaves [-180, 180] degrees (a continuous exporter).
    """
    half = np.pi / 360.0
    unwrapped = False
    for f in range(values.shape[0]):
        for n in range(joints.shape[0]):
            w, x, y, z = 1.0, 0.0, 0.0, 0.0
            for r in range(3):
                d = values[f, cols[n, r]]
                if abs(d) > 180.0 + 1e-9:
                    unwrapped = True
                if d == 0.0:
                    continue
                c, s = np.cos(d * half), np.sin(d * half)
                a = axes[n, r]
                if a == 0:
                    w, x, y, z = w * c - x * s, x * c + w * s, y * c + z * s, z * c - y * s
                elif a == 1:
                    w, x, y, z = w * c - y * s, x * c - z * s, y * c + w * s, z * c + x * s
                else:
                    w, x, y, z = w * c - z * s, x * c + y * s, y * c - x * s, z * c + w * s
            j = joints[n]
            out[f, j, 0], out[f, j, 1], out[f, j, 2], out[f, j, 3] = w, x, y, z
    return unwrapped


_POW10 = np.array([10.0 ** k for k in range(23)])  # exact doubles
_KERNELS: list = []  # [namespace or None] once _fast_kernels() has run


def _fast_kernels():
    """The compiled kernels (``parse_frames``, ``euler_to_quat``), or None without numba.

    numba is imported on first use only, so ``import posturemap`` stays light; compiled code
    is cached on disk, so only the very first read on a machine pays for compilation.
    """
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
    return values


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


def dumps(motion: Motion) -> str:
    """BVH text of ``motion`` with its skeleton's hierarchy and channel layout."""
    sk = motion.skeleton
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
    while todo:
        kind, j, depth = todo.pop()
        pad = "  " * depth
        if kind == "close":
            out.write(f"{pad}}}\n")
            continue
        head = "ROOT" if sk.parents[j] < 0 else "JOINT"
        out.write(f"{pad}{head} {sk.names[j]}\n{pad}{{\n")
        out.write(f"{pad}  OFFSET {' '.join(fmt.format(v) for v in sk.offsets[j])}\n")
        out.write(f"{pad}  CHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}\n")
        if j in ends:
            out.write(f"{pad}  End Site\n{pad}  {{\n{pad}    OFFSET "
                      f"{' '.join(fmt.format(v) for v in ends[j])}\n{pad}  }}\n")
        todo.append(("close", j, depth))
        todo.extend(("open", c, depth + 1) for c in reversed(children[j]))
    out.write(f"MOTION\nFrames: {motion.num_frames}\nFrame Time: {1.0 / motion.fps:.9g}\n")
    values = _pose_to_channels(motion)
    values[np.abs(values) < 1e-12] = 0.0
    np.savetxt(out, values, fmt="%.9g", delimiter=" ")
    return out.getvalue()


def write(path: str | os.PathLike, motion: Motion) -> None:
    """Write ``motion`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    write_bytes_atomic(path, dumps(motion).encode("utf-8"))


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file and rename: never a half-written file."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
