"""BVH reader and writer, skeleton FK and Motion, against hand-computed numbers and scipy.

Sections follow the issue: (a) golden file with hand-computed FK, (b) real files against an
independent scipy FK, (c) round trips, (d) quirks, (e) units and axes, (f) Motion slicing and
concatenation, (g) atomic writing, (h) error messages, (i) the command line. Real-mocap tests
take the conftest fixtures and skip with a reason when ../shared/data is absent.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from posturemap.io import bvh
from posturemap import cli, sample
from posturemap.core import motion as motion_mod, quat
from posturemap.io.bvh import BVHError
from posturemap.errors import UserError
from posturemap.core.motion import Motion, concatenate
from posturemap.core.skeleton import Skeleton

# --- an independent reader and FK (no posturemap code) ----------------------------------------


@dataclasses.dataclass
class RawBVH:
    names: list
    parents: list
    offsets: np.ndarray  # (J, 3)
    channels: list  # per joint, as written
    end_sites: dict  # joint -> offset (3,)
    frames: int
    frame_time: float
    values: np.ndarray  # (F, C) raw channel values


def parse_raw(text: str) -> RawBVH:
    """A deliberately simple BVH parser for well-formed files, written for the tests."""
    lines = text.splitlines()
    names, parents, offsets, channels, end_sites = [], [], [], [], {}
    stack, in_end, i = [], False, 0
    while True:
        tok = lines[i].split()
        i += 1
        if not tok:
            continue
        key = tok[0].upper()
        if key in ("ROOT", "JOINT"):
            names.append(" ".join(tok[1:]))
            parents.append(stack[-1] if stack else -1)
            offsets.append(None)
            channels.append([])
            stack.append(len(names) - 1)
            i += 1  # "{"
        elif key == "END":
            in_end = True
            i += 1
        elif key == "OFFSET":
            off = np.array([float(t) for t in tok[1:4]])
            if in_end:
                end_sites[stack[-1]] = off
            else:
                offsets[stack[-1]] = off
        elif key == "CHANNELS":
            channels[stack[-1]] = tok[2:]
        elif key == "}":
            if in_end:
                in_end = False
            else:
                stack.pop()
        elif key == "MOTION":
            break
    frames = int(lines[i].split(":")[1])
    frame_time = float(lines[i + 1].split(":")[1])
    values = np.array(" ".join(lines[i + 2:]).split(), dtype=float).reshape(frames, -1)
    return RawBVH(names, parents, np.array(offsets), channels, end_sites, frames, frame_time, values)


def raw_columns(raw: RawBVH):
    """Per joint: {axis: column} for position channels, (order, [columns]) for rotations."""
    col, pos, rot = 0, [], []
    for chans in raw.channels:
        p, order, cols = {}, "", []
        for c in chans:
            if c.lower().endswith("position"):
                p["xyz".index(c[0].lower())] = col
            else:
                order += c[0].upper()
                cols.append(col)
            col += 1
        pos.append(p)
        rot.append((order, cols))
    return pos, rot


def scipy_fk(raw: RawBVH, frames) -> np.ndarray:
    """Global joint positions (len(frames), J, 3) from raw channel values with scipy matrices."""
    vals = raw.values[np.asarray(frames)]
    pos_cols, rot_cols = raw_columns(raw)
    n = len(vals)
    g_rot, g_pos = [], []
    for j, parent in enumerate(raw.parents):
        t = np.tile(raw.offsets[j], (n, 1))
        for axis, c in pos_cols[j].items():
            t[:, axis] = vals[:, c]
        order, cols = rot_cols[j]
        if order:
            r = Rotation.from_euler(order, vals[:, cols], degrees=True).as_matrix()
        else:
            r = np.tile(np.eye(3), (n, 1, 1))
        if parent < 0:
            g_rot.append(r)
            g_pos.append(t)
        else:
            g_rot.append(g_rot[parent] @ r)
            g_pos.append(g_pos[parent] + np.einsum("fij,fj->fi", g_rot[parent], t))
    return np.stack(g_pos, axis=1)


def same_up_to_sign(a, b) -> float:
    """Largest element difference between quaternion arrays, up to the sign of each."""
    return float(np.minimum(np.abs(a - b).max(-1), np.abs(a + b).max(-1)).max())


def angle_diff(a, b):
    """a - b in degrees, wrapped into [-180, 180)."""
    return (a - b + 180.0) % 360.0 - 180.0


def end_site_positions(m: Motion) -> dict:
    grot, gpos = m.global_transforms()
    return {j: gpos[:, j] + quat.mul_vec(grot[:, j], np.broadcast_to(o, gpos[:, j].shape))
            for j, o in m.skeleton.end_sites}


def without_kernels(monkeypatch):
    """Force the general numpy paths of the reader (as without numba)."""
    monkeypatch.setattr(bvh, "_fast_kernels", lambda: None)


# --- (a) golden file --------------------------------------------------------------------------

GOLDEN = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Chest
  {
    OFFSET 0 10 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    JOINT Arm
    {
      OFFSET 5 0 0
      CHANNELS 3 Yrotation Zrotation Xrotation
      End Site
      {
        OFFSET 4 0 0
      }
    }
  }
  JOINT Leg
  {
    OFFSET 0 -8 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 -6 0
    }
  }
}
MOTION
Frames: 4
Frame Time: 0.04
1 2 3 0 0 0 0 0 0 0 0 0 0 0 0
0 0 0 90 0 0 0 0 0 0 0 0 0 0 0
0 0 0 0 0 0 0 90 0 0 90 0 0 0 90
1 0 0 90 90 0 0 0 0 0 0 0 0 0 0
"""

# Hand-computed: Rz(90) takes x to y and y to -x; Ry(90) takes x to -z; Rx(90) takes y to z.
# Frame 3 turns the root by Rz(90) * Rx(90) (ZXY order: X acts first).
GOLDEN_JOINTS = {  # Hips, Chest, Arm, Leg
    0: [(1, 2, 3), (1, 12, 3), (6, 12, 3), (1, -6, 3)],
    1: [(0, 0, 0), (-10, 0, 0), (-10, 5, 0), (8, 0, 0)],
    2: [(0, 0, 0), (0, 10, 0), (0, 10, -5), (0, -8, 0)],
    3: [(1, 0, 0), (1, 0, 10), (1, 5, 10), (1, 0, -8)],
}
GOLDEN_ENDS = {  # end of Arm, end of Leg
    0: [(10, 12, 3), (1, -12, 3)],
    1: [(-10, 9, 0), (14, 0, 0)],
    2: [(0, 14, -5), (0, -8, -6)],
    3: [(1, 9, 10), (1, 0, -14)],
}


def line_of(text: str, needle: str, nth: int = 0) -> int:
    """1-based number of the nth line of text containing needle."""
    hits = [k + 1 for k, line in enumerate(text.splitlines()) if needle in line]
    return hits[nth]


def test_golden_structure():
    m = bvh.loads(GOLDEN, "golden.bvh")
    sk = m.skeleton
    assert sk.names == ("Hips", "Chest", "Arm", "Leg")
    assert sk.parents.tolist() == [-1, 0, 1, 0]
    assert [sk.rotation_order(j) for j in range(4)] == ["ZXY", "XYZ", "YZX", "ZYX"]
    assert sk.channels[0] == ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
    assert [j for j, _ in sk.end_sites] == [2, 3]
    assert np.allclose(dict(sk.end_sites)[2], [4, 0, 0])
    assert np.allclose(sk.offsets, [[0, 0, 0], [0, 10, 0], [5, 0, 0], [0, -8, 0]])
    assert m.num_frames == 4 and len(m) == 4
    assert m.fps == pytest.approx(25.0)
    assert m.rotations.shape == (4, 4, 4) and m.positions.shape == (4, 4, 3)


def test_golden_fk_by_hand():
    m = bvh.loads(GOLDEN, "golden.bvh")
    gpos = m.global_positions()
    ends = end_site_positions(m)
    for f in range(4):
        assert np.allclose(gpos[f], GOLDEN_JOINTS[f], atol=1e-12), f
        assert np.allclose(ends[2][f], GOLDEN_ENDS[f][0], atol=1e-12), f
        assert np.allclose(ends[3][f], GOLDEN_ENDS[f][1], atol=1e-12), f


def test_golden_local_values():
    m = bvh.loads(GOLDEN, "golden.bvh")
    s = np.sqrt(0.5)
    assert np.allclose(m.rotations[1, 0], [s, 0, 0, s])  # Zrotation 90 on Hips
    assert np.allclose(m.rotations[2, 1], [s, 0, s, 0])  # Yrotation 90 on Chest
    assert np.allclose(m.rotations[2, 2], [s, 0, 0, s])  # Zrotation 90 on Arm (YZX channels)
    assert np.allclose(m.rotations[2, 3], [s, s, 0, 0])  # Xrotation 90 on Leg (ZYX channels)
    assert np.allclose(m.positions[0, 0], [1, 2, 3])  # root from its channels
    assert np.allclose(m.positions[:, 1], [0, 10, 0])  # others from OFFSET
    assert np.allclose(np.linalg.norm(m.rotations, axis=-1), 1.0)


def test_golden_matches_independent_fk():
    raw = parse_raw(GOLDEN)
    m = bvh.loads(GOLDEN, "golden.bvh")
    assert np.allclose(m.global_positions(), scipy_fk(raw, range(4)), atol=1e-12)


def test_golden_round_trip_and_general_path_agree(monkeypatch):
    m = bvh.loads(GOLDEN, "golden.bvh")
    text = bvh.dumps(m)
    m2 = bvh.loads(text)
    assert m2.skeleton.same_as(m.skeleton)
    assert np.allclose(m2.global_positions(), m.global_positions(), atol=1e-9)
    without_kernels(monkeypatch)
    m3 = bvh.loads(GOLDEN, "golden.bvh")
    assert np.array_equal(m3.positions, m.positions)
    assert np.allclose(m3.rotations, m.rotations, atol=1e-15)


# --- real data: cache one read per file -------------------------------------------------------


@functools.lru_cache(maxsize=None)
def load_real(path: str):
    text = Path(path).read_text()
    return bvh.read(path), parse_raw(text)


@pytest.fixture(scope="module", params=[pytest.param(8, id="every-8th"),
                                        pytest.param(1, id="all", marks=pytest.mark.slow)])
def real_files(request, bandai_files, cmu_file) -> list[str]:
    """Every 8th Bandai clip (by name) and CMU in the quick set; every clip in the slow set."""
    return [str(p) for p in bandai_files[::request.param]] + [str(cmu_file)]


# --- (b) real files against the independent FK ------------------------------------------------


def test_real_files_fk_first_middle_last(real_files):
    bad = []
    for path in real_files:
        m, raw = load_real(path)
        assert m.num_frames == raw.frames
        frames = [0, raw.frames // 2, raw.frames - 1]
        expected = scipy_fk(raw, frames)
        got = m[np.array(frames)].global_positions()
        scale = max(1.0, np.abs(expected).max())
        err = np.abs(got - expected).max() / scale
        if not err < 1e-9:
            bad.append(f"{Path(path).name}: relative error {err:.3g}")
    assert not bad, bad


def test_real_files_structure_matches_raw(real_files):
    for path in real_files:
        m, raw = load_real(path)
        sk = m.skeleton
        assert list(sk.names) == raw.names
        assert sk.parents.tolist() == raw.parents
        assert [list(c) for c in sk.channels] == raw.channels
        assert np.array_equal(sk.offsets, raw.offsets)
        assert {j: tuple(o) for j, o in sk.end_sites} == {j: tuple(o) for j, o in raw.end_sites.items()}
        assert m.fps == pytest.approx(1.0 / raw.frame_time, rel=1e-12)
        assert np.all(np.isfinite(m.rotations)) and np.all(np.isfinite(m.positions))
        assert np.allclose(np.linalg.norm(m.rotations, axis=-1), 1.0, atol=1e-12)


def test_real_files_bone_lengths_constant(real_files):
    bad = []
    for path in real_files:
        m, raw = load_real(path)
        pos_cols, _ = raw_columns(raw)
        gpos = m.global_positions()
        checked = 0
        for j, parent in enumerate(raw.parents):
            cols = list(pos_cols[j].values())
            if parent < 0 or (cols and np.ptp(raw.values[:, cols], axis=0).max() > 0):
                continue  # a root, or a joint whose translation channels move
            length = np.linalg.norm(gpos[:, j] - gpos[:, parent], axis=-1)
            local = m.positions[0, j]
            if not np.allclose(length, np.linalg.norm(local), rtol=1e-6, atol=1e-9):
                bad.append(f"{Path(path).name}: {raw.names[j]} varies by {np.ptp(length):.3g}")
            checked += 1
        assert checked >= 15, f"{path}: only {checked} bones checked"
    assert not bad, bad[:10]


def test_real_files_fast_and_general_parser_agree(real_files, monkeypatch):
    picks = real_files[::40] + real_files[-1:]
    fast = [bvh.read(p) for p in picks]
    without_kernels(monkeypatch)
    for p, a in zip(picks, fast):
        b = bvh.read(p)
        assert np.array_equal(a.positions, b.positions), p
        assert np.allclose(a.rotations, b.rotations, atol=2e-15), p
        assert a.skeleton.euler_style == b.skeleton.euler_style


# --- (c) round trips --------------------------------------------------------------------------


def test_real_files_round_trip(real_files):
    bad = []
    for path in real_files:
        m, raw = load_real(path)
        text = bvh.dumps(m)
        m2 = bvh.loads(text, "round-trip")
        raw2 = parse_raw(text)
        name = Path(path).name
        # same hierarchy, channel layout, frame count and frame time
        assert raw2.names == raw.names and raw2.parents == raw.parents, name
        assert raw2.channels == raw.channels, name
        assert np.allclose(raw2.offsets, raw.offsets, rtol=1e-9, atol=0), name
        assert raw2.end_sites.keys() == raw.end_sites.keys(), name
        assert raw2.frames == raw.frames, name
        assert raw2.frame_time == pytest.approx(raw.frame_time, rel=1e-9), name
        assert m2.skeleton.same_as(m.skeleton) and m2.skeleton.euler_style == m.skeleton.euler_style
        pos_cols, rot_cols = raw_columns(raw)
        pc = [c for p in pos_cols for c in p.values()]
        rc = [c for _, cols in rot_cols for c in cols]
        a, b = raw.values, raw2.values
        # positions identical to 1e-6 relative
        if not np.allclose(b[:, pc], a[:, pc], rtol=1e-6, atol=1e-12):
            bad.append(f"{name}: position channels differ")
        # rotations identical modulo 360 degrees to 1e-6 relative (1e-6 degrees below 1 degree)
        tol = 1e-6 * np.maximum(np.abs(a[:, rc]), 1.0)
        if not np.all(np.abs(angle_diff(b[:, rc], a[:, rc])) <= tol):
            bad.append(f"{name}: rotation channels differ by up to "
                       f"{np.abs(angle_diff(b[:, rc], a[:, rc])).max():.3g} degrees")
        if same_up_to_sign(m2.rotations, m.rotations) > 1e-9:
            bad.append(f"{name}: quaternions differ beyond sign")
        if not np.allclose(m2.positions, m.positions, rtol=1e-6, atol=1e-12):
            bad.append(f"{name}: Motion.positions differ")
    assert not bad, bad[:10]


def test_bandai_has_both_plus_and_minus_180(bandai_files):
    # Why the round trip compares angles modulo 360: the files write the same angle both ways.
    found = set()
    for path in bandai_files:
        _, raw = load_real(str(path))
        found |= set(np.unique(raw.values[np.abs(np.abs(raw.values) - 180.0) < 1e-9]).tolist())
        if found >= {180.0, -180.0}:
            break
    assert found >= {180.0, -180.0}


def test_round_trip_of_sample_clips(sample_clips, tmp_path):
    for name, clip in sample_clips.items():
        path = tmp_path / f"{name}.bvh"
        bvh.write(path, clip)
        back = bvh.read(path)
        assert back.skeleton.same_as(clip.skeleton)
        assert back.num_frames == clip.num_frames
        assert back.fps == pytest.approx(clip.fps, rel=1e-8)
        assert same_up_to_sign(back.rotations, clip.rotations) < 1e-8
        assert np.allclose(back.positions, clip.positions, rtol=1e-8, atol=1e-9)
        assert np.allclose(back.global_positions(), clip.global_positions(), atol=1e-6)
        # and a second round trip reproduces the text exactly
        assert bvh.dumps(back) == bvh.dumps(bvh.loads(bvh.dumps(back)))


def test_read_inputs_files_and_folders(sample_clips, tmp_path):
    folder = tmp_path / "clips"
    folder.mkdir()
    for name in ("walk", "run"):
        bvh.write(folder / f"{name}.bvh", sample_clips[name])
    (folder / "notes.txt").write_text("not a clip")
    single = tmp_path / "wave.BVH"
    bvh.write(single, sample_clips["wave"])
    got = bvh.read_inputs([str(folder), str(single)])
    assert [Path(p).name for p, _ in got] == ["run.bvh", "walk.bvh", "wave.BVH"]  # a folder's files sorted
    assert [len(m) for _, m in got] == [len(sample_clips[n]) for n in ("run", "walk", "wave")]
    with pytest.raises(UserError, match="no such file or folder"):
        bvh.read_inputs([str(tmp_path / "missing")])
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(UserError, match="holds no .bvh files"):
        bvh.read_inputs([str(empty)])


def test_continuous_euler_style_survives_round_trip(cmu_file):
    m, raw = load_real(str(cmu_file))
    assert m.skeleton.euler_style == "continuous"
    assert np.abs(raw.values[:, 3:]).max() > 180.0  # the file leaves [-180, 180]
    back = parse_raw(bvh.dumps(m))
    steps = np.abs(np.diff(back.values[:, 3:], axis=0))
    assert steps.max() < 180.0  # continuous curves: no 360-degree jumps between frames


def test_wrapped_style_writes_within_180():
    m = bvh.loads(GOLDEN)
    assert m.skeleton.euler_style == "wrapped"
    text = GOLDEN.replace("1 0 0 90 90 0 0 0 0", "1 0 0 450 90 0 0 0 0")  # 450 = 90 + 360
    m2 = bvh.loads(text)
    assert m2.skeleton.euler_style == "continuous"
    assert same_up_to_sign(m2.rotations, m.rotations) < 1e-12
    values = parse_raw(bvh.dumps(m)).values
    assert np.abs(values[:, 3:]).max() <= 180.0


# --- (d) quirks -------------------------------------------------------------------------------

def golden_motion() -> Motion:
    return bvh.loads(GOLDEN, "golden.bvh")


def assert_same_motion(a: Motion, b: Motion):
    assert a.skeleton.same_as(b.skeleton)
    assert np.array_equal(a.skeleton.offsets, b.skeleton.offsets)
    assert [j for j, _ in a.skeleton.end_sites] == [j for j, _ in b.skeleton.end_sites]
    assert a.num_frames == b.num_frames
    assert a.fps == pytest.approx(b.fps, rel=1e-12)
    assert np.array_equal(a.positions, b.positions)
    assert np.allclose(a.rotations, b.rotations, atol=1e-15)


def _tabs(t):
    return "\n".join("\t".join(line.split()) for line in t.splitlines()) + "\n"


def _odd_layout(t):
    out = []
    for k, line in enumerate(t.splitlines()):
        out.append(" " * (k % 7) + "  ".join(line.split()) + " \t" * (k % 3))
        if k % 4 == 0:
            out.append("   \t ")
    return "\n".join(out) + "\n\n\n  \n"


QUIRKS = {
    "tabs": _tabs,
    "crlf": lambda t: t.replace("\n", "\r\n"),
    "cr only": lambda t: t.replace("\n", "\r"),
    "odd indentation and blank lines": _odd_layout,
    "no final newline": lambda t: t.rstrip("\n"),
    "blank lines among frames": lambda t: t.replace("\n0 0 0 90", "\n\n  \t\n0 0 0 90").replace(
        "Frame Time: 0.04\n", "Frame Time: 0.04\n\n"),
    "byte-order mark": lambda t: "\ufeff" + t,
    "lowercase keywords and channels": lambda t: re.sub(
        r"(HIERARCHY|ROOT|JOINT|End Site|OFFSET|CHANNELS|MOTION|[XYZ](?:position|rotation))",
        lambda m: m.group(1).lower(), t),
    "number spellings": lambda t: t.replace("0 0 0 90 0 0 0 0 0", "-0 +0.0 0. 9e1 .0 0e5 0 0 0")
                                   .replace("OFFSET 0 10 0", "OFFSET 0 1E1 -0"),
}

FRAME_HEADERS = [
    ("Frames: 4", "Frame Time: 0.04"),
    ("Frames:\t4", "Frame Time:\t0.04"),
    ("FRAMES: 4", "FRAME TIME: 0.04"),
    ("frames:4", "frame time:0.04"),
    ("Frames 4", "Frame Time 0.04"),
    ("NumFrames: 4", "FrameTime: 0.04"),
    ("Frames: 4", "FrameTime 0.04"),
    ("Frames: 4.0", "Frame Time: 4e-2"),
]


@pytest.mark.parametrize("quirk", sorted(QUIRKS))
def test_quirks_read_like_the_clean_file(quirk, monkeypatch):
    text = QUIRKS[quirk](GOLDEN)
    assert text != GOLDEN
    expected = golden_motion()
    for data in (text, text.encode("utf-8")):
        assert_same_motion(bvh.loads(data, "quirk.bvh"), expected)
    without_kernels(monkeypatch)
    assert_same_motion(bvh.loads(text.encode("utf-8"), "quirk.bvh"), expected)


@pytest.mark.parametrize("frames_line, time_line", FRAME_HEADERS)
def test_frame_header_spellings(frames_line, time_line):
    text = GOLDEN.replace("Frames: 4", frames_line).replace("Frame Time: 0.04", time_line)
    assert_same_motion(bvh.loads(text, "h.bvh"), golden_motion())


def test_latin1_and_utf8_joint_names(tmp_path):
    text = GOLDEN.replace("JOINT Arm", "JOINT Bras_gauche_\u00e9paule")
    for encoding in ("utf-8", "latin-1"):
        path = tmp_path / f"{encoding}.bvh"
        path.write_bytes(text.encode(encoding))
        m = bvh.read(path)
        assert m.skeleton.names[2] == "Bras_gauche_\u00e9paule"
        assert np.allclose(m.global_positions(), golden_motion().global_positions())


def test_bytes_like_inputs():
    expected = golden_motion()
    for data in (GOLDEN.encode(), bytearray(GOLDEN.encode()), memoryview(GOLDEN.encode())):
        assert_same_motion(bvh.loads(data, "g.bvh"), expected)


def test_joint_names_with_spaces_round_trip():
    text = GOLDEN.replace("JOINT Leg", "JOINT Left Upper Leg")
    m = bvh.loads(text)
    assert m.skeleton.names[3] == "Left Upper Leg"
    assert bvh.loads(bvh.dumps(m)).skeleton.names[3] == "Left Upper Leg"


def test_three_channel_root():
    text = GOLDEN.replace("CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
                          "CHANNELS 3 Zrotation Xrotation Yrotation").replace("OFFSET 0 0 0", "OFFSET 7 8 9", 1)
    lines = text.splitlines()
    first = line_of(text, "Frame Time")
    lines[first:] = [" ".join(line.split()[3:]) for line in lines[first:]]
    text = "\n".join(lines) + "\n"
    m = bvh.loads(text, "root3.bvh")
    assert not m.skeleton.has_position(0)
    assert np.allclose(m.positions[:, 0], [7, 8, 9])  # the root stays at its OFFSET
    expected = np.array([GOLDEN_JOINTS[f] for f in range(4)], dtype=float)
    expected -= np.array([[[1, 2, 3]], [[0, 0, 0]], [[0, 0, 0]], [[1, 0, 0]]])  # no root motion
    assert np.allclose(m.global_positions(), expected + [7, 8, 9], atol=1e-12)
    back = bvh.loads(bvh.dumps(m))
    assert back.skeleton.channels[0] == ("Zrotation", "Xrotation", "Yrotation")
    assert np.allclose(back.global_positions(), m.global_positions(), atol=1e-9)


def _chain_bvh(orders, values, position_channels=None):
    """A chain of joints, joint k with rotation order orders[k]; values (F, C) in file order."""
    out = ["HIERARCHY"]
    for k, order in enumerate(orders):
        pad = "  " * k
        chans = [f"{a}rotation" for a in order]
        if k == 0:
            chans = ["Xposition", "Yposition", "Zposition"] + chans
        elif position_channels and k in position_channels:
            chans = position_channels[k](chans)
        out += [f"{pad}{'ROOT' if k == 0 else 'JOINT'} j{k}", f"{pad}{{",
                f"{pad}  OFFSET {k + 1} {2 * k + 3} {-k}", f"{pad}  CHANNELS {len(chans)} {' '.join(chans)}"]
    k = len(orders)
    out += ["  " * k + "End Site", "  " * k + "{", "  " * k + "  OFFSET 1 2 3", "  " * k + "}"]
    out += ["  " * i + "}" for i in reversed(range(len(orders)))]
    out += ["MOTION", f"Frames: {len(values)}", "Frame Time: 0.01"]
    out += [" ".join(repr(float(v)) for v in row) for row in values]
    return "\n".join(out) + "\n"


TAIT_BRYAN = [o for o in quat.EULER_ORDERS if o[0] != o[2]]


def test_all_six_rotation_orders_against_scipy():
    rng = np.random.default_rng(6)
    orders = TAIT_BRYAN
    values = rng.uniform(-180, 180, size=(25, 3 + 3 * len(orders)))
    values[:, :3] = rng.normal(size=(25, 3)) * 10
    values[:3, 4] = [90.0, -90.0, 180.0]  # gimbal lock and half turns for the root
    text = _chain_bvh(orders, values)
    m = bvh.loads(text, "orders.bvh")
    assert [m.skeleton.rotation_order(j) for j in range(6)] == orders
    for j, order in enumerate(orders):
        expected = Rotation.from_euler(order, values[:, 3 + 3 * j: 6 + 3 * j], degrees=True)
        assert same_up_to_sign(m.rotations[:, j], expected.as_quat()[:, [3, 0, 1, 2]]) < 1e-14
    raw = parse_raw(text)
    assert np.allclose(m.global_positions(), scipy_fk(raw, range(25)), atol=1e-12)
    back = bvh.loads(bvh.dumps(m))
    assert same_up_to_sign(back.rotations, m.rotations) < 1e-8  # the writer keeps 9 digits


def test_rotation_first_and_partial_position_channels():
    rng = np.random.default_rng(7)
    swap = {1: lambda c: c + ["Xposition", "Yposition", "Zposition"],  # rotations first
            2: lambda c: ["Yposition"] + c}  # a single position channel
    values = rng.uniform(-90, 90, size=(10, 3 + 3 + 6 + 4))
    text = _chain_bvh(["ZXY", "XYZ", "YZX"], values, position_channels=swap)
    m = bvh.loads(text, "partial.bvh")
    assert np.allclose(m.positions[:, 1], values[:, 9:12])
    assert np.allclose(m.positions[:, 2, 1], values[:, 12])
    assert np.allclose(m.positions[:, 2, [0, 2]], [3, -2])  # from OFFSET "3 7 -2"
    assert np.allclose(m.global_positions(), scipy_fk(parse_raw(text), range(10)), atol=1e-12)
    back = bvh.loads(bvh.dumps(m))
    assert back.skeleton.channels == m.skeleton.channels
    assert np.allclose(back.positions, m.positions)


def test_number_formats_parse_exactly_like_python_float(monkeypatch):
    rng = np.random.default_rng(8)
    # (Magnitudes up to the reader's bound, bvh.MAX_ABS_VALUE; beyond it a value is refused, below.)
    values = np.concatenate([rng.normal(0, 100, 600), rng.normal(0, 1e-6, 300), rng.uniform(-1e7, 1e7, 300),
                             10.0 ** rng.uniform(-40, 9, 300) * rng.choice([-1, 1], 300),
                             [0.0, -0.0, 2.0 ** 29, 2.0 ** 29 + 1, 999999999.5, 1e9, -1e9, 5e-324]])
    formats = ["%.17g", "%.9g", "%.15g", "%.6f", "%e", "%.3E", "%+.4f", "%.0f", "%.12f", "%.20f", "%r"]
    tokens = []
    for k, v in enumerate(values):
        fmt = formats[k % len(formats)]
        tokens.append(repr(float(v)) if fmt == "%r" else fmt % v)
    tokens += ["1.", ".5", "-.25", "+7", "00012.50", "1e0", "1E+2", "-0", "0e999", "123456789.012345678901234",
               "0.000000000000000000000000001", "1.0000000000000000000001e9", "4.9e-324"]
    tokens = tokens[: len(tokens) // 3 * 3]
    rows = np.array(tokens, dtype=object).reshape(-1, 3)
    text = ("HIERARCHY\nROOT r\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n"
            " End Site\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\n"
            f"Frames: {len(rows)}\nFrame Time: 0.1\n" + "\n".join(" ".join(r) for r in rows) + "\n")
    expected = np.array([float(t) for t in rows.ravel()]).reshape(-1, 3)
    got = bvh.loads(text).positions[:, 0]
    assert np.array_equal(got, expected)
    assert np.array_equal(np.signbit(got), np.signbit(expected))
    without_kernels(monkeypatch)
    assert np.array_equal(bvh.loads(text).positions[:, 0], expected)


@pytest.mark.parametrize("token", ["1.0000001e9", "-9007199254740993", "1e22", "123456789012345678901234",
                                  "1.7976931348623157e308"])
def test_values_beyond_the_bound_are_refused_on_both_paths(token, monkeypatch):
    refused_on_both_paths(GOLDEN.replace("1 0 0 90 90 0", f"1 0 0 90 {token} 0"),
                          f"x.bvh:{_frame_line(3)}: value beyond +-1e+09 in frame data", monkeypatch)


def test_many_long_numbers_take_the_general_path_exactly():
    rng = np.random.default_rng(9)
    values = rng.normal(0, 100, size=(2000, 3))  # 6000 numbers of 17 digits: beyond the slow list
    text = ("HIERARCHY\nROOT r\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n"
            " End Site\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\n"
            f"Frames: {len(values)}\nFrame Time: 0.1\n" + "\n".join(" ".join(repr(float(v)) for v in r) for r in values))
    assert np.array_equal(bvh.loads(text).positions[:, 0], values)


# --- (e) units and axes -----------------------------------------------------------------------


def test_cmu_keeps_its_own_unit(cmu_file):
    m, raw = load_real(str(cmu_file))
    height = motion_mod.body_height(m)
    assert 10.0 < height < 60.0  # CMU BVH units: a body is a few tens tall, not metres or cm
    assert np.array_equal(m.positions[:, 0], raw.values[:, :3])  # root channels not rescaled
    assert np.array_equal(m.skeleton.offsets, raw.offsets)
    assert motion_mod.up_axis(m) == 1
    assert m.fps == pytest.approx(120.0, rel=1e-4)


def test_bandai_is_y_up_centimetres(bandai_files):
    # Independent of posturemap.core.motion: the body's extent (joints other than joint_Root, which
    # mostly stays at the origin while Hips travels) is largest along Y, in cm.
    for path in bandai_files:
        m, raw = load_real(str(path))
        assert raw.names[0] == "joint_Root" and raw.names[1] == "Hips"
        gpos = m.global_positions()[:, 1:]
        extent = np.median(np.ptp(gpos, axis=1), axis=0)
        assert int(np.argmax(extent)) == 1, path.name
        assert 100.0 < extent[1] < 220.0, path.name  # centimetres (crouching giants: ~120)
        assert m.fps == pytest.approx(30.0, rel=1e-4)
        if np.all(m.positions[:, 0] == 0.0):  # 4 clips move joint_Root too
            assert motion_mod.root_index(m) == m.skeleton.index("Hips")


def test_bandai_up_axis_and_unit_in_place(bandai_files):
    # Clips that stay in place: posturemap.core.motion agrees (Y up, centimetres).
    for path in [p for p in bandai_files if re.search(r"_(bow|bye|byebye|call|guide)_", p.name)]:
        m, _ = load_real(str(path))
        assert motion_mod.up_axis(m) == 1, path.name
        assert motion_mod.length_unit(m) == "cm", path.name


def test_bandai_up_axis_and_unit_every_clip(bandai_files):
    bad = []
    for path in bandai_files:
        m, _ = load_real(str(path))
        if motion_mod.up_axis(m) != 1 or motion_mod.length_unit(m) != "cm":
            bad.append(path.name)
    assert not bad, f"{len(bad)} clips: {bad[:5]}"


# --- (f) Motion slicing and concatenation -----------------------------------------------------


def test_motion_slicing(sample_clips):
    m = sample_clips["walk"]
    part = m[10:20]
    assert isinstance(part, Motion) and part.num_frames == 10
    assert np.array_equal(part.rotations, m.rotations[10:20])
    assert np.array_equal(part.positions, m.positions[10:20])
    assert part.fps == m.fps and part.skeleton is m.skeleton
    assert m[5].num_frames == 1 and np.array_equal(m[5].rotations[0], m.rotations[5])
    assert m[-1].num_frames == 1 and np.array_equal(m[-1].positions[0], m.positions[-1])
    assert m[-2].num_frames == 1 and np.array_equal(m[-2].positions[0], m.positions[-2])
    assert m[np.int64(3)].num_frames == 1
    picked = m[np.array([0, 2, 4])]
    assert picked.num_frames == 3 and np.array_equal(picked.rotations[2], m.rotations[4])
    assert m[::10].num_frames == len(range(0, m.num_frames, 10))
    part.positions[:] = 0.0  # a copy: the original is untouched
    assert not np.all(m.positions[10:20] == 0.0)
    # A frame number outside the clip raises IndexError, so iterating a Motion ends (a clip
    # given where a list is expected was iterated for ever: each index past the end gave an
    # empty Motion).
    for outside in (m.num_frames, -m.num_frames - 1, 10**6):
        with pytest.raises(IndexError, match="outside the clip"):
            m[outside]
    frames = list(m[:7])
    assert len(frames) == 7 and all(np.array_equal(f.rotations[0], m.rotations[i]) for i, f in enumerate(frames))


def test_motion_concatenate(sample_clips):
    m = sample_clips["walk"]
    whole = concatenate([m[:30], m[30:60], m[60:]])
    assert whole.num_frames == m.num_frames
    assert np.array_equal(whole.rotations, m.rotations) and np.array_equal(whole.positions, m.positions)
    both = concatenate([sample_clips["walk"], sample_clips["run"]])
    assert both.num_frames == sample_clips["walk"].num_frames + sample_clips["run"].num_frames


def test_concatenate_rejects_different_skeletons_and_fps(sample_clips):
    golden = bvh.loads(GOLDEN)
    with pytest.raises(ValueError, match="different skeletons"):
        concatenate([sample_clips["walk"], golden])
    other_fps = Motion(golden.skeleton, golden.rotations, golden.positions, 60.0)
    with pytest.raises(ValueError, match="fps"):
        concatenate([golden, other_fps])


def test_concatenate_real_skeletons_differ(bandai_files, cmu_file):
    a, _ = load_real(str(bandai_files[0]))
    b, _ = load_real(str(cmu_file))
    with pytest.raises(ValueError):
        concatenate([a[:5], b[:5]])
    c, _ = load_real(str(bandai_files[1]))
    assert concatenate([a[:5], c[:7]]).num_frames == 12


def test_motion_validates_shapes():
    g = bvh.loads(GOLDEN)
    with pytest.raises(ValueError):
        Motion(g.skeleton, g.rotations[:, :3], g.positions, 25.0)
    with pytest.raises(ValueError):
        Motion(g.skeleton, g.rotations, g.positions[:2], 25.0)
    # A frame rate outside the reader's range (frame times of 0.1 ms to 10 s) is refused where
    # the Motion is made: a gap's frame counts come from it (inf overflowed, 1e-9 Hz asked for
    # terabytes).
    for fps in (0.0, -30.0, float("nan"), float("inf"), 1e-9, 0.099, 10001.0):
        with pytest.raises(ValueError, match="fps must be from 0.1 to 10000"):
            Motion(g.skeleton, g.rotations, g.positions, fps)
    for fps in (0.1, 10000.0):
        assert Motion(g.skeleton, g.rotations, g.positions, fps).fps == fps
    from posturemap.synth.engine import transition

    # Other real dtypes become float64 (the kernels' type): float32 from a game engine gives
    # the same transition as float64; complex numbers are refused.
    for dtype in (np.float32, np.float16, np.int64, np.longdouble):
        m = Motion(g.skeleton, g.rotations.astype(dtype), g.positions.astype(dtype), 25.0)
        assert m.rotations.dtype == m.positions.dtype == np.float64
        assert np.array_equal(m.rotations, g.rotations.astype(dtype).astype(np.float64))
    m32 = Motion(g.skeleton, g.rotations.astype(np.float32), g.positions.astype(np.float32), 25.0)
    m64 = Motion(g.skeleton, m32.rotations.copy(), m32.positions.copy(), 25.0)
    r32, r64 = transition(m32, m32, length=6, method="spline"), transition(m64, m64, length=6, method="spline")
    assert np.array_equal(r32.rotations, r64.rotations) and np.array_equal(r32.positions, r64.positions)
    with pytest.raises(ValueError, match="rotations must be real numbers"):
        Motion(g.skeleton, g.rotations.astype(complex), g.positions, 25.0)
    with pytest.raises(ValueError, match="positions must be real numbers"):
        Motion(g.skeleton, g.rotations, g.positions.astype(object), 25.0)


def test_skeleton_difference_names_the_first_way_two_skeletons_differ(bandai_files, cmu_file):
    # What a "skeleton differs" error says: the joint count, a joint's name, its parent or its
    # channels, the first that differs; None for the same skeleton.
    sk = bvh.read(bandai_files[0]).skeleton
    assert sk.difference(sk) is None and sk.difference(bvh.read(bandai_files[1]).skeleton) is None
    cmu = bvh.read(cmu_file).skeleton
    assert sk.difference(cmu, "the map's") == f"{sk.num_joints} joints, the map's {cmu.num_joints}"
    names = list(sk.names)
    names[3] = "Torso"
    renamed = dataclasses.replace(sk, names=tuple(names))
    assert renamed.difference(sk) == f"joint 3 is 'Torso', the other's {sk.names[3]!r}"
    j = sk.names.index("Head")
    parents = sk.parents.copy()
    parents[j] = 0
    moved = dataclasses.replace(sk, parents=parents)
    assert moved.difference(sk, "its") == f"'Head' hangs from {sk.names[0]!r}, its from {sk.names[sk.parents[j]]!r}"
    channels = list(sk.channels)
    channels[j] = ("Zrotation", "Xrotation", "Yrotation")
    assert dataclasses.replace(sk, channels=tuple(channels)).difference(sk) == (
        f"'Head' has channels Zrotation Xrotation Yrotation, the other's {' '.join(sk.channels[j])}")
    # In the command line's error: one line naming the difference.
    with pytest.raises(UserError, match=r"skeleton differs from the map's \(22 joints, the map's 31\)"):
        from posturemap.learn.model import PostureMap
        PostureMap(seed=0).fit([bvh.read(cmu_file)[:60]]).encode(bvh.read(bandai_files[0]))
    from posturemap.web.studio import Studio

    with pytest.raises(UserError, match=r"^cmu: skeleton differs from walk \(31 joints, its 22; the studio needs one"):
        Studio({"walk": bvh.read(bandai_files[0]), "cmu": bvh.read(cmu_file)[:60]})


def test_skeleton_dict_round_trip():
    sk = bvh.loads(GOLDEN).skeleton
    back = Skeleton.from_dict(sk.to_dict())
    assert back.same_as(sk) and np.array_equal(back.offsets, sk.offsets)
    assert back.depth().tolist() == [0, 1, 2, 1]
    assert sk.children(0) == [1, 3]


# --- (g) atomic writing -----------------------------------------------------------------------


def _leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(".tmp-")]


def test_write_into_missing_folder_raises_and_leaves_nothing(tmp_path):
    target = tmp_path / "missing" / "out.bvh"
    with pytest.raises(BVHError, match="out.bvh"):
        bvh.write(target, golden_motion())
    assert not (tmp_path / "missing").exists()
    assert _leftovers(tmp_path) == []


def test_write_into_read_only_folder_raises_and_leaves_nothing(tmp_path, monkeypatch):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        # Root writes into a read-only folder anyway: refuse the temporary file as the kernel
        # does for anyone else (EACCES), so that the test runs (and checks the same) as root.
        import tempfile

        from posturemap.io import fileio

        def refused(*args, **kwargs):
            raise PermissionError(13, "Permission denied")

        monkeypatch.setattr(fileio, "tempfile", type("T", (), {"mkstemp": staticmethod(refused)}))
        assert tempfile.mkstemp is not refused
    try:
        with pytest.raises(BVHError, match=r"out\.bvh: cannot write file \(Permission denied\)"):
            bvh.write(folder / "out.bvh", golden_motion())
        assert list(folder.iterdir()) == []
    finally:
        folder.chmod(0o755)


def test_failed_rename_leaves_no_temp_file_and_keeps_old_file(tmp_path, monkeypatch):
    target = tmp_path / "out.bvh"
    target.write_text("old contents")

    def failing_replace(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(bvh.os, "replace", failing_replace)
    with pytest.raises(BVHError, match="No space left"):
        bvh.write(target, golden_motion())
    assert target.read_text() == "old contents"
    assert _leftovers(tmp_path) == []


def test_write_then_read(tmp_path):
    target = tmp_path / "out.bvh"
    bvh.write(str(target), golden_motion())
    assert_same_motion(bvh.read(target), golden_motion())
    assert _leftovers(tmp_path) == []


# --- (h) errors -------------------------------------------------------------------------------


def _frame_line(k: int) -> int:
    return line_of(GOLDEN, "Frame Time") + 1 + k


def _replace_line(text: str, lineno: int, new: str | None) -> str:
    lines = text.splitlines()
    if new is None:
        del lines[lineno - 1]
    else:
        lines[lineno - 1] = new
    return "\n".join(lines) + "\n"


GOLDEN_LINES = GOLDEN.splitlines()
ERRORS = {
    # name: (text, line or None, phrase)
    "empty": ("", None, "empty file"),
    "blank": ("  \n\n\t\n", None, "empty file"),
    "not bvh": ("hello world\n", 1, "expected HIERARCHY"),
    "truncated": (_replace_line(GOLDEN, _frame_line(3), None), _frame_line(2), "truncated"),
    "extra frame lines": (GOLDEN + "0 " * 15 + "\n", _frame_line(4), "beyond 'Frames: 4'"),
    "too few values": (_replace_line(GOLDEN, _frame_line(1), "0 0 0 90 0 0"), _frame_line(1),
                       "frame has 6 values, expected 15"),
    "too many values": (_replace_line(GOLDEN, _frame_line(2), GOLDEN_LINES[_frame_line(2) - 1] + " 1"),
                        _frame_line(2), "frame has 16 values, expected 15"),
    "compensating lines": (_replace_line(_replace_line(GOLDEN, _frame_line(0), GOLDEN_LINES[_frame_line(0) - 1]
                                                       + " 0"), _frame_line(1), "0 0 0 90 0 0 0 0 0 0 0 0 0 0"),
                           _frame_line(0), "frame has 16 values"),
    "non-numeric": (GOLDEN.replace("1 0 0 90 90 0", "1 0 0 90 abc 0"), _frame_line(3), "non-numeric value 'abc'"),
    "comma decimal": (GOLDEN.replace("1 2 3 0", "1,5 2 3 0"), _frame_line(0), "non-numeric value '1,5'"),
    "nan": (GOLDEN.replace("1 0 0 90 90 0", "1 0 0 90 nan 0"), _frame_line(3), "NaN or infinite"),
    # Finite but no pose: 1e50-1e308 ran through forward kinematics into numpy's overflow warnings
    # (many lines on stderr) and an error naming the output, or exit 0 with garbage.
    "huge value": (GOLDEN.replace("1 0 0 90 90 0", "1 0 0 90 1e50 0"), _frame_line(3), "beyond +-1e+09"),
    "huge offset": (GOLDEN.replace("OFFSET 5 0 0", "OFFSET 5e300 0 0"), 12, "has a value beyond +-1e+09"),
    "NaN": (GOLDEN.replace("1 2 3 0", "1 NaN 3 0"), _frame_line(0), "NaN or infinite"),
    "inf": (GOLDEN.replace("1 2 3 0", "1 inf 3 0"), _frame_line(0), "NaN or infinite"),
    "-inf": (GOLDEN.replace("1 2 3 0", "1 -inf 3 0"), _frame_line(0), "NaN or infinite"),
    "overflow": (GOLDEN.replace("1 2 3 0", "1 1e999 3 0"), _frame_line(0), "NaN or infinite"),
    "nan offset": (GOLDEN.replace("OFFSET 0 10 0", "OFFSET 0 nan 0"), 8, "NaN or infinite"),
    "bad offset": (GOLDEN.replace("OFFSET 0 10 0", "OFFSET 0 ten 0"), 8, "non-numeric"),
    "short offset": (GOLDEN.replace("OFFSET 0 10 0", "OFFSET 0 10"), 8, "OFFSET needs 3 numbers"),
    "missing MOTION": (GOLDEN.split("MOTION")[0], None, "missing MOTION section"),
    "missing close brace": (_replace_line(GOLDEN, line_of(GOLDEN, "}", 2), None), line_of(GOLDEN, "MOTION") - 1,
                            "braces are closed"),
    "unclosed and no MOTION": (GOLDEN.split("}\nMOTION")[0], None, "missing MOTION section (unbalanced braces)"),
    "extra close brace": (_replace_line(GOLDEN, line_of(GOLDEN, "MOTION"), "}\nMOTION"),
                          line_of(GOLDEN, "MOTION"), "unbalanced '}'"),
    "unclosed before MOTION": (GOLDEN.replace("}\nMOTION", "MOTION"), line_of(GOLDEN, "MOTION") - 1,
                               "braces are closed"),
    "unknown channel": (GOLDEN.replace("Yrotation Zrotation Xrotation", "Yrotation Wrotation Xrotation"), 13,
                        "unknown channel 'Wrotation'"),
    "channel count": (GOLDEN.replace("CHANNELS 3 Xrotation", "CHANNELS 4 Xrotation"), 9, "CHANNELS says 4"),
    "two rotations": (GOLDEN.replace("CHANNELS 3 Xrotation Yrotation Zrotation", "CHANNELS 2 Xrotation Yrotation"),
                      9, "2 rotation channels"),
    "duplicate channel": (GOLDEN.replace("Xrotation Yrotation Zrotation", "Xrotation Xrotation Zrotation"), 9,
                          "listed twice"),
    "absurd frames": (GOLDEN.replace("Frames: 4", "Frames: 999999999999"), line_of(GOLDEN, "Frames"),
                      "absurd frame count"),
    "zero frames": (GOLDEN.replace("Frames: 4", "Frames: 0"), line_of(GOLDEN, "Frames"), "absurd frame count"),
    "negative frames": (GOLDEN.replace("Frames: 4", "Frames: -4"), line_of(GOLDEN, "Frames"), "absurd frame count"),
    "infinite frames": (GOLDEN.replace("Frames: 4", "Frames: inf"), line_of(GOLDEN, "Frames"), "whole number"),
    "huge frames": (GOLDEN.replace("Frames: 4", "Frames: 1e400"), line_of(GOLDEN, "Frames"), "whole number"),
    "fractional frames": (GOLDEN.replace("Frames: 4", "Frames: 4.5"), line_of(GOLDEN, "Frames"), "whole number"),
    "text frames": (GOLDEN.replace("Frames: 4", "Frames: four"), line_of(GOLDEN, "Frames"), "not a number"),
    "missing frames line": (GOLDEN.replace("Frames: 4\n", ""), line_of(GOLDEN, "Frames"), "expected 'Frames:'"),
    "zero frame time": (GOLDEN.replace("Frame Time: 0.04", "Frame Time: 0"), line_of(GOLDEN, "Frame Time"),
                        "positive number"),
    "tiny frame time": (GOLDEN.replace("Frame Time: 0.04", "Frame Time: 1e-320"), line_of(GOLDEN, "Frame Time"),
                        "positive number"),
    "nan frame time": (GOLDEN.replace("Frame Time: 0.04", "Frame Time: nan"), line_of(GOLDEN, "Frame Time"),
                       "positive number"),
    "missing frame time": (GOLDEN.split("Frame Time")[0], line_of(GOLDEN, "Frames"), "missing 'Frame Time:'"),
    "joint outside root": (GOLDEN.replace("ROOT Hips", "JOINT Hips"), 2, "JOINT outside any ROOT"),
    "joint without name": (GOLDEN.replace("JOINT Chest", "JOINT"), 6, "without a name"),
    "joint name twice": (GOLDEN.replace("JOINT Leg", "JOINT Chest"), 20, "'Chest' is used twice (also on line 6)"),
    "offset before brace": (GOLDEN.replace("JOINT Chest\n  {\n", "JOINT Chest\n"), 7, "expected '{'"),
    "end site without offset": (GOLDEN.replace("        OFFSET 4 0 0\n", ""), 16, "End Site without OFFSET"),
    "joint without channels": (GOLDEN.replace("    CHANNELS 3 Xrotation Yrotation Zrotation\n", ""), 18,
                               "lacks OFFSET or CHANNELS"),
    "brace without joint": (GOLDEN.replace("HIERARCHY\n", "HIERARCHY\n{\n"), 2, "'{' without a joint"),
    "no joints": ("HIERARCHY\nMOTION\nFrames: 1\nFrame Time: 0.1\n\n", 2, "no joints"),
    "motion without frames": (GOLDEN.split("Frames")[0], line_of(GOLDEN, "MOTION"), "without a frame count"),
}


@pytest.mark.parametrize("case", sorted(ERRORS))
def test_error_messages(case, tmp_path):
    text, line, phrase = ERRORS[case]
    path = tmp_path / "bad_file.bvh"
    path.write_text(text)
    with pytest.raises(BVHError) as info:
        bvh.read(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path) + (f":{line}: " if line else ": ")), message
    assert phrase in message, message
    assert info.value.line == line
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("case", ["too few values", "non-numeric", "nan", "huge value", "truncated",
                                  "compensating lines"])
def test_error_messages_are_the_same_without_kernels(case, monkeypatch):
    text = ERRORS[case][0]
    with pytest.raises(BVHError) as fast:
        bvh.loads(text, "x.bvh")
    without_kernels(monkeypatch)
    with pytest.raises(BVHError) as general:
        bvh.loads(text, "x.bvh")
    assert str(fast.value) == str(general.value)


def refused_on_both_paths(text: str, expected: str, monkeypatch) -> None:
    """``bvh.loads(text, "x.bvh")`` raises ``expected`` with the compiled parser and without it."""
    with pytest.raises(BVHError, match=re.escape(expected)):
        bvh.loads(text, "x.bvh")
    without_kernels(monkeypatch)
    with pytest.raises(BVHError, match=re.escape(expected)):
        bvh.loads(text, "x.bvh")


def test_error_line_numbers_count_blank_lines(monkeypatch):
    text = GOLDEN.replace("Frame Time: 0.04\n", "Frame Time: 0.04\n\n\n").replace("1 0 0 90 90 0", "1 0 0 90 ? 0")
    refused_on_both_paths(text, f"x.bvh:{_frame_line(3) + 2}: non-numeric value '?'", monkeypatch)


def test_large_frame_count_with_short_body_allocates_little():
    import tracemalloc

    text = GOLDEN.replace("Frames: 4", "Frames: 30000000")  # 4.5e8 values claimed, 60 present
    tracemalloc.start()
    try:
        with pytest.raises(BVHError, match="truncated: 4 frame lines but 'Frames: 30000000'"):
            bvh.loads(text.encode(), "short.bvh")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50e6


def test_binary_garbage(tmp_path):
    path = tmp_path / "garbage.bvh"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)) * 4)
    with pytest.raises(BVHError, match=r"garbage\.bvh: binary data"):
        bvh.read(path)
    rng = np.random.default_rng(10)
    for k in range(20):  # random bytes without NUL: still one clean error
        data = bytes(rng.integers(1, 256, size=int(rng.integers(1, 3000)), dtype=np.uint8))
        with pytest.raises(BVHError) as info:
            bvh.loads(data, f"random{k}.bvh")
        assert str(info.value).startswith(f"random{k}.bvh")


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(BVHError, match=r"nope\.bvh: cannot read file \(No such file"):
        bvh.read(tmp_path / "nope.bvh")
    with pytest.raises(BVHError, match="cannot read file"):
        bvh.read(tmp_path)


def _deep_chain(n: int) -> str:
    head = ["HIERARCHY", "ROOT j0", "{", "OFFSET 0 0 0", "CHANNELS 6 Xposition Yposition Zposition "
            "Zrotation Xrotation Yrotation"]
    for k in range(1, n):
        head += [f"JOINT j{k}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
    head += ["End Site", "{", "OFFSET 0 1 0", "}"] + ["}"] * n
    head += ["MOTION", "Frames: 2", "Frame Time: 0.1", " ".join(["0"] * (3 * n + 3)),
             "1 2 3 " + " ".join(["0"] * (3 * n))]
    return "\n".join(head) + "\n"


def test_very_deep_nesting_parses_and_writes_without_recursion():
    n = 5000
    text = _deep_chain(n)
    m = bvh.loads(text, "deep.bvh")
    assert m.skeleton.num_joints == n
    assert len(text) > 4 * 65536  # as bytes, the header alone outgrows the first decoded prefix
    assert_same_motion(bvh.loads(text.encode(), "deep.bvh"), m)
    assert m.skeleton.depth()[-1] == n - 1
    gpos = m.global_positions()
    assert np.allclose(gpos[0, -1], [0, n - 1, 0])
    assert np.allclose(gpos[1, -1], [1, n + 1, 3])
    text = bvh.dumps(m)  # iterative writer: no RecursionError
    back = bvh.loads(text)
    assert back.skeleton.same_as(m.skeleton)


def test_too_many_joints_is_a_clean_error():
    with pytest.raises(BVHError, match="more than 10000 joints"):
        bvh.loads(_deep_chain(10_001), "huge.bvh")


def test_deeply_nested_braces_are_a_clean_error():
    with pytest.raises(BVHError, match="'{' without a joint"):
        bvh.loads("HIERARCHY\n" + "{\n" * 100_000, "braces.bvh")


# --- (i) the command line ---------------------------------------------------------------------


def test_cli_demo_writes_readable_bvh(tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli.main(["demo", "--out", str(out)]) == 0
    for name, clip in sample.clips().items():
        m = bvh.read(out / f"sample_{name}.bvh")
        assert m.num_frames == clip.num_frames and m.skeleton.same_as(clip.skeleton)
    files = sorted(out.glob("*.bvh"))
    for f in files:  # whatever else the demo writes must be readable BVH too
        assert np.all(np.isfinite(bvh.read(f).global_positions())), f
    assert "sample_walk.bvh" in capsys.readouterr().out


def test_cli_bad_file_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    # The only subcommand today is `demo`, which reads no user file: let it read --data so that
    # the CLI's error contract is exercised with a real BVHError from a real bad file.
    bad = tmp_path / "broken.bvh"
    bad.write_text(GOLDEN.replace("1 2 3 0", "1 x 3 0"))
    from posturemap import demo

    monkeypatch.setattr(demo, "run", lambda out, data=None, log=print: bvh.read(data))
    code = cli.main(["demo", "--out", str(tmp_path / "o"), "--data", str(bad)])
    captured = capsys.readouterr()
    assert code == 2
    lines = captured.err.splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("posturemap: error: ")
    assert str(bad) in lines[0] and "non-numeric" in lines[0]


def test_cli_missing_file_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    from posturemap import demo

    monkeypatch.setattr(demo, "run", lambda out, data=None, log=print: bvh.read(data))
    missing = tmp_path / "missing.bvh"
    assert cli.main(["demo", "--data", str(missing)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("posturemap: error: ") and str(missing) in err[0]


def test_cli_unknown_command_exits_2_with_one_line(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["no-such-command"])
    assert info.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("posturemap: error: ")

# Not tested here: `posturemap inspect`, `train`, `transition`, `bench`, `serve`. Their
# owners add their tests with the subcommands.
