"""Frame rates: a clip resampled to another rate (API and command line), and what the command
line says about its options and outputs."""

from __future__ import annotations

import numpy as np
import pytest

import posturemap
from posturemap.core import quat
from posturemap.core.motion import Motion, at_one_rate, resample
from posturemap.io import bvh

from clikit import assert_refused, run


def test_resample_keeps_the_time_and_the_recorded_frames(sample_clips):
    m = sample_clips["walk"]
    duration = (len(m) - 1) / m.fps
    # Half the rate: every other recorded frame, exactly (an even number of frame steps).
    even = m[:(len(m) - 1) // 2 * 2 + 1]
    half = resample(even, m.fps / 2)
    assert half.fps == m.fps / 2 and len(half) == (len(even) - 1) // 2 + 1
    np.testing.assert_allclose(np.abs(np.sum(half.rotations * even.rotations[::2], axis=-1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(half.positions, even.positions[::2], atol=1e-12)
    # Twice the rate: the recorded frames on the even frames, the halfway SLERP and LERP between.
    double = resample(m, 2 * m.fps)
    assert len(double) == 2 * (len(m) - 1) + 1 and (len(double) - 1) / double.fps == pytest.approx(duration)
    np.testing.assert_allclose(double.positions[::2], m.positions, atol=1e-12)
    mid = quat.slerp(m.rotations[:-1], m.rotations[1:], np.full((len(m) - 1, m.skeleton.num_joints), 0.5))
    np.testing.assert_allclose(np.abs(np.sum(double.rotations[1::2] * mid, axis=-1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(double.positions[1::2], 0.5 * (m.positions[:-1] + m.positions[1:]), atol=1e-12)
    # There and back: the same motion, the same number of frames.
    back = resample(resample(m, 24.0), m.fps)
    assert len(back) == len(m)
    err = np.abs(back.global_positions() - m.global_positions()).max()
    assert err < 0.05 * np.ptp(m.global_positions()[..., 1]) and err > 0  # not the same samples, near them
    # A rate within 0.1% is the same rate: a copy.
    same = resample(m, m.fps * (1 + 1e-4))
    assert same.fps == m.fps and np.array_equal(same.rotations, m.rotations) and same.rotations is not m.rotations
    for bad in (0.0, -30.0, 0.05, float("nan"), float("inf"), 2e4):
        with pytest.raises(ValueError, match="fps"):
            resample(m, bad)
    assert posturemap.resample is resample


def test_resample_refuses_a_nan_as_the_other_entry_points_do(sample_clips):
    # A NaN would pass into every frame interpolated next to it: refused, naming frame and joint.
    m = sample_clips["walk"]
    bad = Motion(m.skeleton, m.rotations.copy(), m.positions.copy(), m.fps)
    bad.rotations[3, 2, 0] = np.nan
    with pytest.raises(posturemap.errors.UserError, match="NaN or infinite rotation .frame 3"):
        resample(bad, 60.0)


def test_resample_one_frame_and_the_last_frame(sample_clips):
    m = sample_clips["walk"]
    one = resample(m[:1], 60.0)
    assert len(one) == 1 and np.allclose(one.rotations, m.rotations[:1], atol=1e-12)
    # A duration that is not a whole number of new frames: the nearest count, the last one at the end.
    short = m[:8]  # 7 frame steps
    r = resample(short, short.fps * 0.55)  # 3.85 new steps: 4, the last clamped to the clip's end
    assert len(r) == 5
    np.testing.assert_allclose(r.positions[-1], short.positions[-1], atol=1e-12)


def test_resample_command(capsys, tmp_path, sample_clips):
    m = sample_clips["walk"]
    src = tmp_path / "walk.bvh"
    bvh.write(src, m)
    out = tmp_path / "walk60.bvh"
    code, stdout, err = run(capsys, "resample", src, "--fps", "60", "-o", out)
    assert code == 0, err
    r = bvh.read(out)
    assert r.fps == pytest.approx(60.0, rel=1e-6) and len(r) == 2 * (len(m) - 1) + 1
    assert f"{len(r)} frames at 60 fps" in stdout
    np.testing.assert_allclose(r.global_positions()[::2], bvh.read(src).global_positions(), atol=1e-3)
    assert option_refused(capsys, "resample", src, "--fps", "0", "-o", out).startswith(
        "posturemap: error: --fps: must be a frame rate in [0.1, 10000]")
    assert_refused(capsys, tmp_path / "w.txt", "resample", src, "--fps", "24", "-o", tmp_path / "w.txt",
                   words=[".bvh, .glb or .gltf"])
    assert not (tmp_path / "w.txt").exists()


def test_transition_refuses_an_unknown_output_format_and_says_when_no_legs_are_found(capsys, tmp_path,
                                                                                     sample_clips):
    a, b = tmp_path / "a.bvh", tmp_path / "b.bvh"
    bvh.write(a, sample_clips["walk"])
    bvh.write(b, sample_clips["run"])
    assert_refused(capsys, tmp_path / "t.txt", "transition", a, b, "-o", tmp_path / "t.txt", words=[".bvh, .glb"])
    assert not (tmp_path / "t.txt").exists()
    code, out, err = run(capsys, "transition", a, b, "-o", tmp_path / "t.bvh", "--method", "slerp")
    assert code == 0 and "foot lock" not in out
    # The same clips with joints no name finds a leg in: the hierarchy's legs are locked. With
    # the legs not alike either, the transition is made, and it says that nothing is locked.
    from rigkit import bare

    for unalike in (False, True):
        for path, clip in ((a, sample_clips["walk"]), (b, sample_clips["run"])):
            bvh.write(path, bare(clip, unalike))
        code, out, err = run(capsys, "transition", a, b, "-o", tmp_path / "u.bvh", "--method", "slerp")
        assert code == 0, err
        assert ("foot lock: off, no legs found by name" in out) == unalike, out
    code, out, _ = run(capsys, "transition", a, b, "-o", tmp_path / "v.bvh", "--method", "slerp", "--no-foot-lock")
    assert code == 0 and "foot lock" not in out


def option_refused(capsys, *argv) -> str:
    """The one line of an option refused by the parser (exit 2)."""
    with pytest.raises(SystemExit) as info:
        run(capsys, *argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err.strip()


def test_option_errors_name_the_option_first(capsys, tmp_path):
    # As a file's errors name the file: "posturemap: error: --length: ...", not argparse's "argument --length".
    line = option_refused(capsys, "transition", "a.bvh", "b.bvh", "-o", tmp_path / "t.bvh", "--length", "0")
    assert line == "posturemap: error: --length: must be a whole number of at least 1, got '0'"


def test_transition_and_train_take_clips_at_two_rates(capsys, tmp_path, sample_clips):
    # B at twice A's rate: the command line resamples B to A's rate (saying so) rather than
    # refusing it, from its frame --b-start on (--b-start counts B's own frames; none before it
    # is read: a frame between two of B's would blend in the one before).
    walk, run_ = sample_clips["walk"], sample_clips["run"]
    a, b = tmp_path / "walk.bvh", tmp_path / "run60.bvh"
    bvh.write(a, walk)
    bvh.write(b, resample(run_, 2 * run_.fps))
    b60 = bvh.read(b)
    out = tmp_path / "t.bvh"
    code, stdout, err = run(capsys, "transition", a, b, "-o", out, "--method", "slerp", "--length", "10",
                            "--b-start", "22", "--no-align")
    assert code == 0, err
    assert (f"{b}: {b60.fps:g} fps, its frames from 22 on resampled to A's {walk.fps:g} fps (its frame 22 is "
            "their first)") in stdout
    r, cut, b30 = bvh.read(out), resample(b60[22:], walk.fps), resample(b60, walk.fps)
    assert r.fps == pytest.approx(walk.fps, rel=1e-6) and len(r) == len(walk) + 10 + len(cut)
    np.testing.assert_allclose(r.global_positions()[len(walk) + 10:], cut.global_positions(), atol=1e-3)
    # B's frame 22 is at A's rate the frame halfway between 10 and 11 there: as the whole of B
    # resampled has it from its frame 11 (22 / 60 s), to within the BVH's decimals.
    np.testing.assert_allclose(cut.global_positions()[: len(cut) - 1], b30.global_positions()[11: 10 + len(cut)],
                               atol=1e-3)
    # B's frames before --b-start are never read: garbled, the output is the same.
    garbled = bvh.read(b)
    garbled.rotations[:22] = garbled.rotations[::-1][:22]
    garbled.positions[:22] += 100.0
    bvh.write(tmp_path / "g60.bvh", garbled)
    code, _, err = run(capsys, "transition", a, tmp_path / "g60.bvh", "-o", tmp_path / "g.bvh", "--method", "slerp",
                       "--length", "10", "--b-start", "22", "--no-align")
    assert code == 0, err
    np.testing.assert_allclose(bvh.read(tmp_path / "g.bvh").global_positions(), r.global_positions(), atol=1e-6)
    # Without --map, the report names B's frames by their count from --b-start at A's rate.
    code, stdout, err = run(capsys, "transition", a, b, "-o", out, "--length", "20", "--b-start", "4")
    assert code == 0, err
    assert f"{b} (at {walk.fps:g} fps) from its frame 4 frames " in stdout or "lower: " not in stdout, stdout
    assert f"{b} frames" not in stdout, stdout
    # B's own last frame is the last a --b-start can name.
    assert_refused(capsys, "--b-start", "transition", a, b, "-o", out, "--b-start", str(len(b60)),
                   words=[f"frame {len(b60)} is outside clip B (frames 0..{len(b60) - 1})"])
    # Training: every clip at the first one's rate, each resampled one named on stderr.
    code, stdout, err = run(capsys, "train", a, b, "-o", tmp_path / "m.npz", "--epochs", "1")
    assert code == 0, err
    assert f"posturemap: note: {b}: {b60.fps:g} fps, resampled to {walk.fps:g} fps (the first clip's rate)" in err
    m = posturemap.PostureMap.load(tmp_path / "m.npz")
    assert m.info_["fps"] == pytest.approx(walk.fps) and m.info_["frames"] == len(walk) + len(b30)
    # The library names the resampled clip with the rate its frames are counted at.
    assert m.library_.clip_names[:2] == (str(a), f"{b} (at {walk.fps:g} fps)")


def test_at_one_rate_resamples_only_the_clips_at_another_rate(sample_clips):
    walk, run_ = sample_clips["walk"], sample_clips["run"]
    fast = resample(run_, 2 * run_.fps)
    out, changed = at_one_rate([walk, fast, run_, walk[:0]])
    assert changed == [1] and out[0] is walk and out[2] is run_ and len(out[3]) == 0
    assert out[1].fps == walk.fps and len(out[1]) == len(run_)
    np.testing.assert_allclose(out[1].global_positions(), run_.global_positions(), atol=1e-9)
    out, changed = at_one_rate([walk, fast], fps=fast.fps)
    assert changed == [0] and out[1] is fast and out[0].fps == fast.fps
    assert at_one_rate([]) == ([], [])
    with pytest.raises(ValueError, match="fps must be a number"):  # the rate asked for, not a clip, at fault
        at_one_rate([walk, fast], fps=0.0)


def test_a_resample_too_large_to_hold_is_refused_before_allocating(capsys, tmp_path, sample_clips):
    # 0.1 fps made 10,000 fps: every frame becomes 100,000. Refused by size (512 MiB of result,
    # about 1.8 GiB at the peak of making it), naming the clip, rather than a MemoryError (or
    # the machine swapping).
    import dataclasses
    import tracemalloc

    walk = sample_clips["walk"]
    slow, fast = dataclasses.replace(walk, fps=0.1), dataclasses.replace(walk, fps=10000.0)
    tracemalloc.start()
    with pytest.raises(ValueError, match=r"make \d+ at 10000 fps, [\d,]+ MiB: over 512 MiB"):
        resample(slow, 10000.0)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 1 << 20
    with pytest.raises(posturemap.errors.UserError, match="^slow: "):
        at_one_rate([fast, slow], names=["fast", "slow"])
    a, b = tmp_path / "fast.bvh", tmp_path / "slow.bvh"
    bvh.write(a, fast)
    bvh.write(b, slow)
    assert_refused(capsys, b, "resample", b, "--fps", "10000", "-o", tmp_path / "o.bvh", words=["MiB"])
    assert_refused(capsys, b, "transition", a, b, "-o", tmp_path / "t.bvh", "--method", "slerp", words=["MiB"])
    assert_refused(capsys, b, "train", a, b, "-o", tmp_path / "m.npz", words=["MiB"])
    assert not any(p.name.startswith(("o.", "t.", "m.")) for p in tmp_path.iterdir())


def test_running_out_of_memory_is_one_error_line(capsys, tmp_path, sample_clips, monkeypatch):
    # Whatever runs out (a huge but valid input), the command line says so in one line, exit 2.
    a = tmp_path / "walk.bvh"
    bvh.write(a, sample_clips["walk"])

    def no_memory(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(bvh, "read", no_memory)
    line = assert_refused(capsys, "memory", "resample", a, "--fps", "60", "-o", tmp_path / "o.bvh")
    assert line == "posturemap: error: memory: not enough for this input"
    assert not (tmp_path / "o.bvh").exists()
