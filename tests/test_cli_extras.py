"""The command line beyond the core: filmstrip previews, optional extras that fail kindly, data
folders only from arguments or ``POSTUREMAP_DATA``, the demo's own output folders, the version.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import posturemap
from posturemap.io import bvh, preview
from posturemap import cli, demo, errors

REPO = Path(__file__).resolve().parent.parent


def png_pixels(path: Path) -> np.ndarray:
    """RGBA pixels (H, W, 4) of a PNG, read with matplotlib."""
    from matplotlib import image

    return image.imread(str(path))


# -- filmstrip ----------------------------------------------------------------------------------
def test_filmstrip_draws_each_segment_in_its_colour(sample_clips, tmp_path):
    walk = sample_clips["walk"]
    gpos = walk.global_positions()
    sk = walk.skeleton
    out = tmp_path / "strip.png"
    segments = [("A", gpos[:30], "#ff0000"), ("transition", gpos[30:50], "#00ff00"), ("B", gpos[50:80], "#0000ff")]
    feet = [sk.names.index(n) for n in sk.names if "Foot" in n]
    preview.filmstrip(segments, out, sk.parents, up=1, fps=walk.fps, feet=feet, title="test", unit="cm")
    px = png_pixels(out)
    assert px.shape[1] == 1200 and 300 < px.shape[0] < 900
    rgb = (px[..., :3] * 255).round().astype(int)
    counts = {c: int(np.all(rgb == v, axis=-1).sum()) for c, v in
              {"red": (255, 0, 0), "green": (0, 255, 0), "blue": (0, 0, 255)}.items()}
    assert all(n > 200 for n in counts.values()), counts  # every segment is drawn, in its colour
    # Left to right in time: A's red lies left of the transition's green, left of B's blue.
    cols = {c: np.flatnonzero(np.all(rgb == v, axis=-1).any(axis=0)).mean() for c, v in
            {"red": (255, 0, 0), "green": (0, 255, 0), "blue": (0, 0, 255)}.items()}
    assert cols["red"] < cols["green"] < cols["blue"], cols


def test_foot_contacts_low_and_slow():
    fps, leg = 30.0, 80.0
    t = np.arange(60) / fps
    planted = np.stack([np.full(60, 10.0), np.full(60, 2.0), np.zeros(60)], axis=-1)  # still, on the floor
    phase = 4 * np.pi * t  # a step every half second: lifts and speeds up, slows and lands
    swinging = np.stack([25 * (phase - np.sin(phase)) / np.pi, 2.0 + 15 * (1 - np.cos(phase)), np.zeros(60)], axis=-1)
    sliding = np.stack([200 * t, np.full(60, 2.0), np.zeros(60)], axis=-1)  # low but 2 m/s
    on = preview.foot_contacts(np.stack([planted, swinging, sliding], axis=1), fps, 1, leg)
    assert on[:, 0].all()
    assert not on[:, 2].any()
    lift = swinging[:, 1] - 2.0
    assert on[:, 1].any() and not on[lift > 10, 1].any()  # down between steps, never in the swing
    assert np.all(lift[on[:, 1]] < preview.CONTACT_HEIGHT * leg)


def test_filmstrip_rejects_bad_segments(tmp_path, sample_clips):
    sk = sample_clips["walk"].skeleton
    with pytest.raises(ValueError, match="segments"):
        preview.filmstrip([("A", np.zeros((0, sk.num_joints, 3)), None)], tmp_path / "x.png", sk.parents)
    assert not (tmp_path / "x.png").exists()


def test_cli_transition_preview(sample_clips, tmp_path, capsys):
    a, b = tmp_path / "walk.bvh", tmp_path / "run.bvh"
    bvh.write(a, sample_clips["walk"])
    bvh.write(b, sample_clips["run"])
    png = tmp_path / "t.png"
    assert cli.main(["transition", str(a), str(b), "-o", str(tmp_path / "t.glb"), "--preview", str(png),
                     "--method", "slerp", "--length", "10"]) == 0
    assert "filmstrip" in capsys.readouterr().out
    px = png_pixels(png)
    rgb = (px[..., :3] * 255).round().astype(int)
    for colour in (preview.COLOURS[k] for k in ("A", "transition", "B")):
        v = tuple(int(colour[i: i + 2], 16) for i in (1, 3, 5))
        assert np.all(rgb == v, axis=-1).sum() > 100, colour
    for bad, what in [(tmp_path / "t.jpg", "must end in .png"), (tmp_path / "no" / "t.png", "output folder")]:
        assert cli.main(["transition", str(a), str(b), "-o", str(tmp_path / "u.bvh"), "--preview", str(bad)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and what in err, err
        assert not (tmp_path / "u.bvh").exists()  # checked before anything is written


def z_up(m):
    """The clip turned from Y up to Z up by its top joint (the same rig, the same offsets)."""
    from posturemap.core import quat

    turn = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.pi / 2)
    rots, pos = m.rotations.copy(), m.positions.copy()
    rots[:, 0] = quat.mul(turn, rots[:, 0])
    pos[:, 0] = quat.mul_vec(turn, pos[:, 0])
    return dataclasses.replace(m, rotations=rots, positions=pos, source=None)


def test_cli_train_warns_of_a_clip_given_twice_or_standing_along_another_axis(sample_clips, tmp_path, capsys):
    # The map's up axis is the one most frames stand along, not the first clip's: a Z-up clip
    # first (or one lying on the floor) no longer sets it. Each odd clip gets one warning line.
    from posturemap.learn.model import PostureMap

    walk, run_ = sample_clips["walk"], sample_clips["run"]
    files = {}
    for name, clip in (("z", z_up(run_)), ("walk", walk), ("run", run_)):
        files[name] = tmp_path / f"{name}.bvh"
        bvh.write(files[name], clip)
    out = tmp_path / "map.npz"
    code = cli.main(["train", str(files["z"]), str(files["walk"]), str(files["run"]), str(files["walk"]),
                     "-o", str(out), "--epochs", "1"])
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("posturemap:")]
    assert code == 0
    assert err == [f"posturemap: warning: {files['walk']}: given twice: its frames count twice in the map",
                   f"posturemap: warning: {files['z']}: the body stands along Z, most clips' along Y (the map's "
                   "up axis): lying on the floor, or of another up axis?"], err
    assert PostureMap.load(str(out)).space_.up == 1
    assert cli.main(["train", str(files["walk"]), str(files["run"]), "-o", str(out), "--epochs", "1"]) == 0
    assert not [line for line in capsys.readouterr().err.splitlines() if line.startswith("posturemap:")]


def test_cli_transition_warns_of_a_clip_turned_to_another_up_axis(sample_clips, tmp_path, capsys):
    # The same rig turned from Y up to Z up passes the skeleton's check; the map's up axis then
    # turned B about the wrong axis, silently. It is read from the body's extent, which a clip
    # lying on the floor can mislead, so it warns (one line) rather than refuses.
    from posturemap.learn.model import PostureMap

    walk, run_ = sample_clips["walk"], sample_clips["run"]
    m = tmp_path / "map.npz"
    PostureMap(seed=0, library=False).fit([walk, run_]).save(str(m))
    for name, clips, warned in (("y", (walk, run_), False), ("z", (z_up(walk), z_up(run_)), True)):
        a, b = tmp_path / f"walk_{name}.bvh", tmp_path / f"run_{name}.bvh"
        bvh.write(a, clips[0])
        bvh.write(b, clips[1])
        assert cli.main(["transition", str(a), str(b), "-o", str(tmp_path / f"{name}.bvh"), "--map", str(m),
                         "--method", "slerp", "--length", "10"]) == 0
        err = capsys.readouterr().err
        assert err == (f"posturemap: warning: {a}: the body stands along Z, the map's clips along Y: the "
                       "transition may not line up (a map trained on clips of this orientation would)\n"
                       f"posturemap: warning: {b}: the body stands along Z, the map's clips along Y: the "
                       "transition may not line up (a map trained on clips of this orientation would)\n"
                       if warned else ""), err
    # A Y-up A and a Z-up B: only A was read, and B came out lying on the floor, silently. Now B
    # is named, against the map's axis, or without a map against A's.
    a, b = tmp_path / "walk_y.bvh", tmp_path / "run_z.bvh"
    for extra, whose in ((["--map", str(m)], "the map's clips along Y: the transition may not line up (a map "
                          "trained on clips of this orientation would)"),
                         ([], f"{a}'s along Y: the transition may not line up (lying on the floor, or of another "
                          "up axis?)")):
        assert cli.main(["transition", str(a), str(b), "-o", str(tmp_path / "mixed.bvh"), "--method", "slerp",
                         "--length", "10", *extra]) == 0
        assert capsys.readouterr().err == f"posturemap: warning: {b}: the body stands along Z, {whose}\n"
    # Without --map, auto's map of A and B stands along the axis most of their frames do: the
    # clip that differs from it is named, A or B (a 60-frame Y-up A before a 90-frame Z-up B:
    # the map is Z-up, and A is the odd one).
    a60, b90 = tmp_path / "run_y.bvh", tmp_path / "walk_z.bvh"
    bvh.write(a60, run_)
    bvh.write(b90, z_up(walk))
    assert len(run_) < len(walk)
    assert cli.main(["transition", str(a60), str(b90), "-o", str(tmp_path / "m2.bvh"), "--length", "10"]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("posturemap: warning")]
    assert err == [f"posturemap: warning: {a60}: the body stands along Y, {a60} and {b90} (most frames) along Z: "
                   "the transition may not line up (lying on the floor, or of another up axis?)"], err
    from posturemap.web.studio import Studio

    lines = []
    Studio({"walk": walk, "run": z_up(run_), "run_y": run_}, train=False, log=lines.append)
    assert lines == ["posturemap: warning: run: the body stands along Z, walk's along Y: transitions with it may "
                     "not line up (lying on the floor, or of another up axis?)"], lines


def test_cli_transition_warns_of_a_seam_frame_that_is_a_glitch(sample_clips, tmp_path, capsys):
    # CMU's 01_01 starts in a reference pose (its forearm 136 degrees from the second frame):
    # the new frames read B's motion without it and turn into frame 0 as given over the gap,
    # and the user is told how to leave it out (with --b-start 1, nothing to tell).
    from posturemap.core import quat
    from posturemap.core.motion import Motion

    walk, run_ = sample_clips["walk"], sample_clips["run"]
    rots = run_.rotations.copy()
    j = 5
    rots[0, j] = quat.mul(quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(2.4)), rots[1, j])
    a, b = tmp_path / "walk.bvh", tmp_path / "run.bvh"
    bvh.write(a, walk)
    bvh.write(b, Motion(run_.skeleton, rots, run_.positions, run_.fps))
    given = bvh.read(b)
    name = walk.skeleton.names[j]
    for start, warned in ((0, True), (1, False)):
        out = tmp_path / f"out{start}.bvh"
        assert cli.main(["transition", str(a), str(b), "-o", str(out), "--method", "spline", "--length", "10",
                         "--b-start", str(start)]) == 0
        err = capsys.readouterr().err
        assert err == (f"posturemap: warning: {b}: its frame 0 is a glitch at {name} (138 degrees off the frames "
                       "beside it: a reference pose or a flipped joint); the new frames turn into it over the gap "
                       "(--b-start 1 starts B after it)\n" if warned else ""), err
        written = bvh.read(out)
        k = len(walk) + 10
        assert quat.angle_between(written.rotations[k, j], given.rotations[start, j]) < 1e-6  # B as given
        # Into B's frame as given, in even steps (at most 19 degrees): the spline read the glitch
        # as B's velocity and swung the joint 110 degrees in the last step, 38-62 before it.
        steps = np.degrees(quat.angle_between(written.rotations[k - 10: k + 1, j][1:],
                                              written.rotations[k - 10: k + 1, j][:-1]))
        assert steps.max() < 30.0, steps


def test_cli_transition_reads_and_steadies_one_file_once_and_warns_of_both_seams(sample_clips, tmp_path, capsys,
                                                                                  monkeypatch):
    # A and B from one file (a loop from a take's end back to its start, a gap in a take): it
    # used to be read twice and steadied once for each seam's warning; now once each.
    from posturemap.core import glitches, quat
    from posturemap.core.motion import Motion

    run_ = sample_clips["run"]
    rots = run_.rotations.copy()
    j, last = 5, len(run_) - 1
    for f, beside in ((0, 1), (last, last - 1)):  # B's first frame and A's last, each a glitch
        rots[f, j] = quat.mul(quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(2.4)), rots[beside, j])
    take = tmp_path / "take.bvh"
    bvh.write(take, Motion(run_.skeleton, rots, run_.positions, run_.fps))
    reads, steadied = [], []
    real_read, real_steady = bvh.read, glitches.steady_motion
    monkeypatch.setattr(bvh, "read", lambda path: reads.append(path) or real_read(path))
    monkeypatch.setattr(glitches, "steady_motion", lambda m: steadied.append(m) or real_steady(m))
    out = tmp_path / "loop.bvh"
    assert cli.main(["transition", str(take), str(take), "-o", str(out), "--method", "spline", "--length", "10"]) == 0
    assert len(reads) == 1 and len(steadied) == 1
    err = capsys.readouterr().err
    name = run_.skeleton.names[j]
    assert f"{take}: its last frame is a glitch at {name}" in err, err
    assert f"{take}: its frame 0 is a glitch at {name}" in err, err
    monkeypatch.undo()
    assert len(bvh.read(str(out))) == 2 * len(run_) + 10


def test_cli_transition_writes_both_outputs_or_neither(sample_clips, tmp_path, capsys, monkeypatch):
    # The output was written before the filmstrip was drawn: a filmstrip that could not be
    # written (an immutable folder, a full disk) left the output behind with exit code 2.
    from posturemap.errors import UserError

    a, b = tmp_path / "walk.bvh", tmp_path / "run.bvh"
    bvh.write(a, sample_clips["walk"])
    bvh.write(b, sample_clips["run"])
    out, png = tmp_path / "u.bvh", tmp_path / "u.png"
    args = ["transition", str(a), str(b), "-o", str(out), "--preview", str(png), "--method", "slerp"]

    def refused(path, *rest, **kw):
        raise UserError(str(path), "cannot write file (Operation not permitted)")

    with monkeypatch.context() as m:
        m.setattr(preview, "_save", lambda fig, path, title: refused(path))
        assert cli.main(args) == 2
    assert "u.png: cannot write" in capsys.readouterr().err
    assert not out.exists() and not png.exists()
    with monkeypatch.context() as m:  # and the output refused after the filmstrip was drawn
        m.setattr(bvh, "write", refused)
        assert cli.main(args) == 2
    assert "u.bvh: cannot write" in capsys.readouterr().err
    assert not out.exists() and not png.exists()
    assert cli.main(args) == 0 and out.exists() and png.exists()


# -- optional extras ----------------------------------------------------------------------------
def hide_modules(monkeypatch, *names):
    """Make ``importlib.util.find_spec`` (and import) fail for ``names``, as if not installed."""
    real = importlib.util.find_spec

    def find_spec(name, *args, **kwargs):
        if name.split(".")[0] in names:
            return None
        return real(name, *args, **kwargs)

    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    for n in names:
        monkeypatch.setitem(sys.modules, n, None)  # import n -> ImportError


@pytest.mark.parametrize("argv, hidden, extra", [
    (["bench", "--quick", "--data", "."], ("minisom",), "bench"),
    (["serve"], ("uvicorn",), "web"),
    (["transition", "A.bvh", "B.bvh", "-o", "o.bvh", "--preview", "p.png"], ("matplotlib",), "preview"),
])
def test_missing_extra_is_one_line_naming_it(argv, hidden, extra, monkeypatch, capsys):
    hide_modules(monkeypatch, *hidden)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("posturemap: error: ")
    assert f"pip install 'posturemap[{extra}]'" in err and hidden[0] in err


def test_require_extra_passes_when_installed():
    errors.require_extra("preview", "numpy")  # installed: no error
    with pytest.raises(errors.UserError, match=r"needs no_such_module_x: pip install 'posturemap\[web\]'"):
        errors.require_extra("web", "numpy", "no_such_module_x")


def test_demo_without_matplotlib_says_so_and_goes_on(monkeypatch, tmp_path):
    hide_modules(monkeypatch, "matplotlib")
    lines = []
    written = demo.run(str(tmp_path / "d"), log=lines.append)
    assert not any(p.endswith(".png") for p in written.values())
    assert any("pip install 'posturemap[preview]'" in line for line in lines)
    assert sum(p.endswith(".glb") for p in written.values()) == 3


# -- data folders -------------------------------------------------------------------------------
def test_bench_data_only_from_argument_or_environment(monkeypatch, tmp_path, capsys):
    pytest.importorskip("minisom")
    monkeypatch.delenv("POSTUREMAP_DATA", raising=False)
    assert cli.main(["bench", "--quick"]) == 2
    err = capsys.readouterr().err
    assert "--data" in err and "POSTUREMAP_DATA" in err and err.count("\n") == 1
    monkeypatch.setenv("POSTUREMAP_DATA", str(tmp_path / "nowhere"))
    assert cli.main(["bench", "--quick"]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "nowhere") in err and "POSTUREMAP_DATA" in err
    assert cli.main(["bench", "--quick", "--data", str(tmp_path)]) == 2  # exists, but no bandai1/
    assert "bandai1" in capsys.readouterr().err


# -- the demo's folders and the version ---------------------------------------------------------
def test_demo_data_run_has_its_own_folder(tmp_path, monkeypatch, sample_clips, capsys):
    monkeypatch.chdir(tmp_path)
    data = tmp_path / "mydata"
    data.mkdir()
    for name, clip in sample_clips.items():
        bvh.write(data / f"x_{name}_1.bvh", clip)
    assert demo.default_out(None) == "out" and demo.default_out(str(data)) == "out-mydata"
    assert cli.main(["demo"]) == 0
    sample_map = (tmp_path / "out" / "map.npz").read_bytes()
    capsys.readouterr()
    assert cli.main(["demo", "--data", str(data)]) == 0
    text = capsys.readouterr().out
    assert (tmp_path / "out-mydata" / "map.npz").is_file()
    assert (tmp_path / "out" / "map.npz").read_bytes() == sample_map  # the sample run's map untouched
    assert sorted(p.name for p in (tmp_path / "out-mydata").glob("*.glb")) == \
        ["x_walk_1_to_x_run_1.glb"]
    # The demo ends with the next commands, which work as printed.
    serve_line = next(line for line in text.splitlines() if line.strip().startswith("posturemap serve"))
    assert f"--map out-mydata{os.sep}map.npz" in serve_line and str(data) in serve_line
    transition_line = next(line for line in text.splitlines()[::-1]
                           if line.strip().startswith("posturemap transition"))
    assert cli.main(transition_line.split()[1:]) == 0
    assert (tmp_path / "my_transition.glb").is_file()


def test_version_matches_the_package_metadata(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["--version"])
    assert info.value.code == 0
    meta = tomllib.loads((REPO / "pyproject.toml").read_text("utf-8"))
    assert capsys.readouterr().out.strip() == f"posturemap {meta['project']['version']}"
    assert posturemap.__version__ == meta["project"]["version"]



def test_filmstrip_rows_stack_one_side_view_per_motion(sample_clips, tmp_path):
    walk, run = sample_clips["walk"], sample_clips["run"]
    sk = walk.skeleton
    g_walk, g_run = walk.global_positions(), run.global_positions()
    rows = [("truth", [("context", g_walk[:10], "#888888"), ("gap", g_walk[10:30], "#ff0000")]),
            ("method", [("context", g_walk[:10], "#888888"), ("gap", g_run[:20], "#0000ff")])]
    out = tmp_path / "rows.png"
    preview.filmstrip_rows(rows, out, sk.parents, fps=walk.fps, title="one window")
    rgb = (png_pixels(out)[..., :3] * 255).round().astype(int)
    red = np.flatnonzero(np.all(rgb == (255, 0, 0), axis=-1).any(axis=1))
    blue = np.flatnonzero(np.all(rgb == (0, 0, 255), axis=-1).any(axis=1))
    assert len(red) > 20 and len(blue) > 20
    assert red.max() < blue.min()  # the truth's row above the method's
    with pytest.raises(ValueError):
        preview.filmstrip_rows([], out, sk.parents)


def test_transition_help_lists_every_method_with_its_summary(capsys):
    from posturemap import cli
    from posturemap.synth.request import METHOD_INFO

    with pytest.raises(SystemExit) as e:
        cli.main(["transition", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    lines = out[out.index("methods:"):].splitlines()[1:]
    assert [line.split()[0] for line in lines if line.strip()] == list(METHOD_INFO)
    for name, info in METHOD_INFO.items():
        assert info.summary.split()[0] in next(line for line in lines if line.split()[:1] == [name])
