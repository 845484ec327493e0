"""Read and write BVH motion capture files.

Reading gives a :class:`~posturemap.motion.Motion`; writing reproduces the hierarchy and the
channel layout (any rotation order per joint, 3- or 6-channel joints, End Sites). Joints with
position channels take their translation from the channels (the OFFSET is kept for writing
back); the others use their OFFSET. Numbers are parsed in one vectorised pass.

Every problem with a file raises :class:`BVHError` naming the file, the line and what is wrong.
"""

from __future__ import annotations

import dataclasses
import io
import os
import tempfile

import numpy as np

from . import quat
from .errors import UserError
from .motion import Motion
from .skeleton import POSITION_CHANNELS, ROTATION_CHANNELS, Skeleton

MAX_JOINTS = 10_000
MAX_VALUES = 500_000_000  # frames * channels; beyond this a file is not motion capture


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
    if isinstance(raw, bytes):
        if b"\x00" in raw[:65536]:
            raise BVHError(path, None, "binary data, not a BVH text file")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")
    else:
        text = raw
    if not text.strip():
        raise BVHError(path, None, "empty file")
    lines = text.splitlines()
    skeleton, motion_line = _parse_hierarchy(lines, path)
    values, fps = _parse_motion(lines, motion_line, skeleton, path)
    rotations, positions = _channels_to_pose(skeleton, values)
    if _has_unwrapped_angles(skeleton, values):
        skeleton = dataclasses.replace(skeleton, euler_style="continuous")
    return Motion(skeleton, rotations, positions, fps)


def _has_unwrapped_angles(sk: Skeleton, values: np.ndarray) -> bool:
    """True when some rotation channel leaves [-180, 180] degrees (a continuous exporter)."""
    cols = [c for rc in _layout(sk)[1] for c in rc]
    return bool(cols) and bool(np.any(np.abs(values[:, cols]) > 180.0 + 1e-9))


def _parse_hierarchy(lines: list[str], path: str) -> tuple[Skeleton, int]:
    """Parse HIERARCHY up to MOTION; returns the skeleton and the MOTION line index."""
    names, parents, offsets, channels, end_sites = [], [], [], [], []
    stack: list[int] = []  # open joints; -2 marks an open End Site
    pending = None  # joint (or End Site) declared, waiting for its "{"
    seen_hierarchy = False
    i = 0
    while i < len(lines):
        tokens = lines[i].split()
        lineno = i + 1
        i += 1
        if not tokens:
            continue
        key = tokens[0].upper()
        if key == "HIERARCHY":
            seen_hierarchy = True
        elif key == "MOTION":
            if stack or pending is not None:
                raise BVHError(path, lineno, "MOTION before the hierarchy's braces are closed")
            if not names:
                raise BVHError(path, lineno, "no joints before MOTION")
            sk = Skeleton(tuple(names), np.array(parents), np.array(offsets),
                          tuple(channels), tuple(end_sites))
            return sk, i - 1
        elif not seen_hierarchy:
            raise BVHError(path, lineno, f"expected HIERARCHY, found {tokens[0][:40]!r}")
        elif key in ("ROOT", "JOINT"):
            if pending is not None:
                raise BVHError(path, lineno, "expected '{' after a joint name")
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
            if pending is not None or not stack or stack[-1] == -2:
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
        raise BVHError(path, None, "no HIERARCHY section (not a BVH file?)")
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


def _parse_motion(lines: list[str], motion_line: int, sk: Skeleton, path: str) -> tuple[np.ndarray, float]:
    """Frames as an array (F, C) of channel values in file order, and the fps."""
    i = motion_line + 1
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        raise BVHError(path, motion_line + 1, "MOTION without a frame count")
    frames_txt = _header_value(lines[i], ("frames:", "frames", "numframes:"), path, i + 1)
    try:
        num_frames = int(float(frames_txt))
    except ValueError:
        raise BVHError(path, i + 1, f"frame count {frames_txt[:40]!r} is not a number") from None
    num_channels = sum(len(c) for c in sk.channels)
    if num_frames < 1 or num_frames * max(num_channels, 1) > MAX_VALUES:
        raise BVHError(path, i + 1, f"absurd frame count {num_frames}")
    i += 1
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        raise BVHError(path, i, "missing 'Frame Time:'")
    ft_txt = _header_value(lines[i], ("frame time:", "frametime:", "frame time", "frametime"), path, i + 1)
    try:
        frame_time = float(ft_txt)
    except ValueError:
        raise BVHError(path, i + 1, f"frame time {ft_txt[:40]!r} is not a number") from None
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise BVHError(path, i + 1, f"frame time must be a positive number, got {ft_txt[:40]!r}")
    first = i + 1
    body = lines[first:]
    while body and not body[-1].strip():
        body.pop()
    if len(body) < num_frames:
        raise BVHError(path, first + len(body),
                       f"truncated: {len(body)} frame lines but 'Frames: {num_frames}'")
    if len(body) > num_frames:
        raise BVHError(path, first + num_frames + 1,
                       f"{len(body) - num_frames} frame lines beyond 'Frames: {num_frames}'")
    tokens = " ".join(body).split()
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        values = None
    if values is None or values.size != num_frames * num_channels:
        _locate_bad_line(body, first, num_channels, path)
    values = values.reshape(num_frames, num_channels)
    bad = ~np.isfinite(values)
    if bad.any():
        f = int(np.argmax(bad.any(axis=1)))
        raise BVHError(path, first + f + 1, "NaN or infinite value in frame data")
    return values, 1.0 / frame_time


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


def _channels_to_pose(sk: Skeleton, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    num_frames = values.shape[0]
    pos_cols, rot_cols = _layout(sk)
    positions = np.broadcast_to(sk.offsets, (num_frames, sk.num_joints, 3)).copy()
    has = pos_cols >= 0
    jj, aa = np.nonzero(has)
    positions[:, jj, aa] = values[:, pos_cols[jj, aa]]
    rotations = np.zeros((num_frames, sk.num_joints, 4))
    rotations[..., 0] = 1.0
    # Group joints by Euler order: one vectorised conversion per order.
    by_order: dict[str, list[int]] = {}
    for j in range(sk.num_joints):
        if rot_cols[j]:
            by_order.setdefault(sk.rotation_order(j), []).append(j)
    for order, joints in by_order.items():
        cols = np.array([rot_cols[j] for j in joints])
        rotations[:, joints] = quat.from_euler(np.radians(values[:, cols]), order)
    return rotations, positions


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
