"""BVH bounds, special files and output sanity (issue 12): each reproducer is a named test.

Bad input must end in exit code 2 and one line ``posturemap: error: <file>...: <what>`` on
stderr (no traceback, no output file); the checks come before any allocation.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from posturemap.io import bvh
from posturemap import cli, sample
from posturemap.io.bvh import BVHError
from posturemap.core.motion import Motion
from clikit import assert_refused, run  # noqa: E402,F401


@pytest.fixture(scope="module")
def walk_text():
    return bvh.dumps(sample.clips()["walk"])




def with_frame_time(text: str, value: str) -> str:
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("Frame Time:"))
    lines[k] = f"Frame Time: {value}"
    return "\n".join(lines) + "\n"


def chain(n: int, frames: int = 2) -> str:
    """A chain of ``n`` joints, each the child of the previous one."""
    lines = ["HIERARCHY", "ROOT j0", "{", "OFFSET 0 0 0",
             "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
    for i in range(1, n):
        lines += [f"JOINT j{i}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
    lines += ["End Site", "{", "OFFSET 0 1 0", "}"] + ["}"] * n
    lines += ["MOTION", f"Frames: {frames}", "Frame Time: 0.0333333"]
    lines += [" ".join(["0"] * (3 + 3 * n))] * frames
    return "\n".join(lines) + "\n"


# -- reproducers -------------------------------------------------------------------------------
@pytest.mark.parametrize("value", ["100", "1000", "1e308", "1e-300", "0.00001"])
def test_issue12_frame_time_out_of_bounds(walk_text, tmp_path, capsys, value):
    path = tmp_path / "slow.bvh"
    path.write_text(with_frame_time(walk_text, value))
    out = tmp_path / "out.bvh"
    assert_refused(capsys, path, "transition", path, path, "-o", out, words=["frame time"])
    assert not out.exists()
    assert_refused(capsys, path, "inspect", path, words=["frame time"])


def test_frame_time_bounds_are_inclusive(walk_text):
    assert bvh.loads(with_frame_time(walk_text, "10")).fps == pytest.approx(0.1)
    assert bvh.loads(with_frame_time(walk_text, "0.0001")).fps == pytest.approx(10000)


def test_issue12_fifo_named_bvh_is_refused_at_once(tmp_path, capsys):
    fifo = tmp_path / "x.bvh"
    os.mkfifo(fifo)  # nobody writes: reading would block forever
    assert_refused(capsys, fifo, "inspect", fifo, words=["not a regular file", "FIFO"])


def test_issue12_symlink_to_dev_zero_is_refused(tmp_path, capsys):
    link = tmp_path / "zero.bvh"
    link.symlink_to("/dev/zero")
    assert_refused(capsys, link, "inspect", link, words=["not a regular file", "device"])


def test_issue12_folder_of_special_files(tmp_path, capsys):
    (tmp_path / "clips").mkdir()
    os.mkfifo(tmp_path / "clips" / "a.bvh")
    out = tmp_path / "m.npz"
    assert_refused(capsys, tmp_path / "clips" / "a.bvh", "train", tmp_path / "clips", "-o", out,
                   words=["not a regular file"])
    assert not out.exists()


def test_issue12_chain_of_9999_joints_reads_in_linear_time(tmp_path, capsys):
    # Bone classes were found with a scan of all joints per joint on the spine and an ancestor
    # walk per joint (quadratic: 13-24 s); now one pass each. The time itself is measured by
    # bench/fuzz_long.py (no timing asserts in unit tests): here the result must be right.
    from posturemap.core.joints import subtree_mask
    from posturemap.learn.features import assign_classes

    path = tmp_path / "chain.bvh"
    path.write_text(chain(9999))
    code, out, err = run(capsys, "inspect", path)
    assert code == 0, err
    assert "9999 joints" in out
    sk = bvh.read(path).skeleton
    assert subtree_mask(sk.parents, 0).all() and subtree_mask(sk.parents, 5000).sum() == 4999
    jc = assign_classes(sk, 0)
    assert jc[0] == 0 and jc.shape == (9999,)


def test_hierarchy_deeper_than_the_limit_is_refused(monkeypatch):
    monkeypatch.setattr(bvh, "MAX_DEPTH", 50)
    with pytest.raises(BVHError, match="nested more than 50 levels"):
        bvh.loads(chain(51))
    assert bvh.loads(chain(50)).skeleton.num_joints == 50


@pytest.mark.parametrize("frames", ["1000000", "3000000"])
def test_frame_count_beyond_the_file_is_refused_before_allocating(walk_text, frames):
    # The fast parser checks the count against the bytes left before allocating; the general
    # one then says how many frame lines there are.
    text = walk_text.replace(f"Frames: {sample.clips()['walk'].num_frames}", f"Frames: {frames}")
    with pytest.raises(BVHError, match=f"truncated: .* but 'Frames: {frames}'"):
        bvh.loads(text.encode())


def test_huge_file_refused_from_its_size(tmp_path, monkeypatch):
    path = tmp_path / "big.bvh"
    path.write_bytes(b"HIERARCHY\n" + b" " * 5000)
    monkeypatch.setattr(bvh, "MAX_FILE_BYTES", 4096)
    with pytest.raises(BVHError, match="too large"):
        bvh.read(path)


# -- output sanity -----------------------------------------------------------------------------
@pytest.mark.parametrize("where", ["rotations", "positions"])
def test_non_finite_motion_is_not_written(tmp_path, where):
    m = sample.clips()["walk"]
    arrays = {"rotations": m.rotations.copy(), "positions": m.positions.copy()}
    arrays[where][7, 3, 1] = np.nan
    bad = Motion(m.skeleton, arrays["rotations"], arrays["positions"], m.fps)
    out = tmp_path / "out.bvh"
    out.write_text("old")
    with pytest.raises(BVHError, match="refusing to write NaN") as info:
        bvh.write(out, bad)
    assert "frame 7" in str(info.value) and m.skeleton.names[3] in str(info.value)
    assert out.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bvh"]
    with pytest.raises(BVHError):
        bvh.dumps(bad)


# -- round trip: the file's own channel values ------------------------------------------------
def _frame_values(text: str) -> np.ndarray:
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("Frame Time"))
    return np.array([[float(x) for x in line.split()] for line in lines[k + 1:] if line.strip()])


@pytest.mark.parametrize("start", [0, 243, 2000])
def test_issue12_cmu_frames_written_with_the_files_own_values(cmu_file, start):
    # CMU angles pass +-180 degrees (continuous curves); written from a frame whose root angle
    # was beyond 180, the writer used to start at the principal value: 360 degrees away from
    # the file for every later frame.
    m = bvh.read(cmu_file)
    original = _frame_values(cmu_file.read_text())
    assert np.abs(original[start:, 3:6]).max() > 180  # the case the issue describes
    assert np.array_equal(_frame_values(bvh.dumps(m[start:])), original[start:])


def test_issue12_cmu_transition_keeps_a_and_continues_smoothly(cmu_file):
    from posturemap.synth.engine import transition

    m = bvh.read(cmu_file)
    original = _frame_values(cmu_file.read_text())
    a, b = m[:2100], m[2300:]
    out = transition(a, b, None, length=30, method="spline")
    values = _frame_values(bvh.dumps(out))
    assert np.array_equal(values[:2100], original[:2100])  # A unchanged: the file's numbers
    rot = [c for c in range(values.shape[1]) if c not in (0, 1, 2)]
    jump = np.abs(np.diff(values[:, rot], axis=0)).max(axis=0)
    file_jump = np.abs(np.diff(original[:, rot], axis=0)).max(axis=0)
    # No channel jumps by a turn where the file did not (the seams included).
    assert np.all(jump < np.maximum(file_jump, 90.0) + 1.0), (jump - file_jump).max()


def test_generated_run_between_file_frames_continues_by_whole_turns():
    from posturemap.io.bvh import _continue_runs

    out = np.array([[170.0], [179.0], [-170.0], [-160.0], [200.0]])  # rows 2-3 generated (wrapped)
    fixed = np.array([True, True, False, False, True])
    _continue_runs(out, np.array([0]), fixed)
    assert np.allclose(out[:, 0], [170, 179, 190, 200, 200])
    out = np.array([[-170.0], [190.0]])  # a generated first row meets the file's next one
    _continue_runs(out, np.array([0]), np.array([False, True]))
    assert np.allclose(out[:, 0], [190, 190])


def test_changed_joints_are_recomputed_not_copied(tmp_path):
    m = bvh.loads(bvh.dumps(sample.clips()["walk"]))
    assert m.source is not None
    rots = m.rotations.copy()
    rots[:, 0] = rots[::-1, 0]  # the root's rotation changed: its file values no longer apply
    changed = Motion(m.skeleton, rots, m.positions, m.fps, m.source)
    back = bvh.loads(bvh.dumps(changed))
    assert np.allclose(np.abs(np.einsum("fjc,fjc->fj", back.rotations, rots)), 1.0, atol=1e-7)


def test_gltf_writer_refuses_non_finite_motion_too(tmp_path):
    from posturemap.io import gltf

    m = sample.clips()["walk"]
    rots = m.rotations.copy()
    rots[3, 2, 0] = np.inf
    bad = Motion(m.skeleton, rots, m.positions, m.fps)
    with pytest.raises(BVHError, match="refusing to write NaN"):
        gltf.write(tmp_path / "out.glb", bad)
    assert list(tmp_path.iterdir()) == []
