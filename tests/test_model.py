"""PostureMap: fit, map files (save/load, corrupt files), and the train/inspect commands."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from clikit import assert_refused
from posturemap.io import bvh
from posturemap import cli, sample
from posturemap.core import quat
from posturemap.errors import UserError
from posturemap.learn.features import CLASSES
from posturemap.learn.model import FORMAT, VERSION, MapFileError, PostureMap
from posturemap.core.motion import Motion
from posturemap.synth.engine import TransitionEngine
from posturemap.core.skeleton import Skeleton



# -- helpers ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def clips():
    return sample.clips()


@pytest.fixture(scope="module")
def fitted(clips):
    return PostureMap(seed=3).fit(list(clips.values()), list(clips))


@pytest.fixture
def saved(fitted, tmp_path):
    path = tmp_path / "map.npz"
    fitted.save(str(path))
    return path


@pytest.fixture(scope="module")
def bvh_dir(clips, tmp_path_factory):
    """The sample clips written as BVH files (train input)."""
    folder = tmp_path_factory.mktemp("clips")
    for name, m in clips.items():
        bvh.write(str(folder / f"{name}.bvh"), m)
    return folder


def map_arrays(path):
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def rewrite(path, arrays, **changes):
    """Save ``arrays`` with ``changes`` as an npz at ``path`` (uncompressed, like a foreign tool)."""
    out = dict(arrays)
    out.update(changes)
    np.savez(path, **out)
    return path


def meta_bytes(meta: dict) -> np.ndarray:
    return np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)


def expect_map_error(path, *words):
    with pytest.raises(MapFileError) as info:
        PostureMap.load(str(path))
    msg = str(info.value)
    assert msg.startswith(f"{path}: "), msg
    assert isinstance(info.value, UserError)
    for w in words:
        assert w in msg, msg
    return msg


def renamed_skeleton_clip(m):
    """The same motion on a skeleton with one joint renamed: a different skeleton."""
    sk = m.skeleton
    names = tuple("Skull" if n == "Head" else n for n in sk.names)
    return type(m)(Skeleton(names, sk.parents, sk.offsets, sk.channels, sk.end_sites), m.rotations,
                   m.positions, m.fps)


def run_cli(*args, cwd=None):
    """``posturemap ARGS`` in a fresh interpreter: (exit code, stdout, stderr lines)."""
    proc = subprocess.run([sys.executable, "-m", "posturemap.cli", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, timeout=120, check=False)
    return proc.returncode, proc.stdout, proc.stderr.splitlines()


class _Trap:
    """Unpickling this object would create ``path``: proof that a map load never unpickles."""

    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


# -- fit -------------------------------------------------------------------------------------
def test_fit_sample(fitted, clips):
    assert len(fitted.maps_) == 4
    counts = fitted.neuron_counts()
    assert all(c >= 1 for c in counts)
    frames = sum(len(m) for m in clips.values())
    assert fitted.info_["frames"] == frames and fitted.info_["clips"] == 3
    x = np.concatenate([fitted.encode(m) for m in clips.values()])
    for c, m in enumerate(fitted.maps_):
        part = fitted.space_.split(x)[c]
        assert m.weights_.shape[1] == part.shape[1] == len(fitted.space_.class_dims[c])
        assert m.hits_.sum() == frames
        assert m.invalid_fraction(part) == 0.0
        assert fitted.info_["quality"][CLASSES[c]]["neurons"] == counts[c]
    assert fitted.maps_[0].seed == 3 and fitted.maps_[3].seed == 6  # one seed per class


def test_fit_is_deterministic(clips):
    a = PostureMap(seed=1).fit(list(clips.values()))
    b = PostureMap(seed=1).fit(list(clips.values()))
    for ma, mb in zip(a.maps_, b.maps_):
        np.testing.assert_array_equal(ma.weights_, mb.weights_)
        np.testing.assert_array_equal(ma.edges_, mb.edges_)


def test_fit_and_partial_fit_take_one_motion_as_a_list_of_it(clips):
    # One Motion where a list is expected is the list of it (iterating it frame by frame had
    # never ended): the same maps as from [motion], and partial_fit grows them alike.
    walk, run = clips["walk"], clips["run"]
    one, listed = PostureMap(seed=1).fit(walk), PostureMap(seed=1).fit([walk])
    assert one.info_["clips"] == 1
    one.partial_fit(run)
    listed.partial_fit([run])
    assert one.info_["clips"] == listed.info_["clips"] == 2
    for ma, mb in zip(one.maps_, listed.maps_):
        np.testing.assert_array_equal(ma.weights_, mb.weights_)


def test_fit_euler_mode_is_circular(clips):
    pm = PostureMap(features="euler", radius=0.2).fit(list(clips.values()))
    assert pm.space_.mode == "euler"
    body = pm.maps_[0]
    assert np.isinf(body.period_[-1])  # root height (last body dimension) is linear
    assert np.all(body.period_[:-1] == 2 * np.pi)
    for m in pm.maps_:
        assert m.radius_ == 0.2


def test_mixed_skeletons_name_the_file(clips):
    odd = renamed_skeleton_clip(clips["run"])
    with pytest.raises(UserError) as info:
        PostureMap().fit([clips["walk"], odd], ["walk.bvh", "odd.bvh"])
    assert str(info.value).startswith("odd.bvh: skeleton differs from walk.bvh")


def test_mixed_skeletons_sample_and_bandai(clips, bandai_files):
    bandai = bvh.read(bandai_files[0])
    with pytest.raises(UserError, match="skeleton differs") as info:
        PostureMap().fit([clips["walk"], bandai], ["walk.bvh", str(bandai_files[0])])
    assert str(info.value).startswith(str(bandai_files[0]))


def test_fit_without_motions():
    with pytest.raises(ValueError, match="no training motions"):
        PostureMap().fit([])


def test_fit_on_a_few_bandai_clips(bandai_files):
    motions = [bvh.read(f) for f in bandai_files[:3]]
    pm = PostureMap(epochs=2).fit(motions)
    assert pm.skeleton_.names[0] == "joint_Root"
    assert pm.describe()["skeleton"]["root"] == "Hips"
    for q in pm.info_["quality"].values():
        assert q["invalid_neurons"] == 0.0 and q["neurons"] >= 1


def test_single_joint_skeleton_map(tmp_path):
    """A skeleton with one joint: three classes are empty; fit, save and load still work."""
    rng = np.random.default_rng(0)
    sk = Skeleton(("thing",), np.array([-1]), np.zeros((1, 3)),
                  (("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),))
    rots = quat.from_euler(rng.normal(0, 0.3, (40, 1, 3)), "ZXY")
    pos = rng.normal(0, 1, (40, 1, 3)) + [0, 90, 0]
    pm = PostureMap().fit([Motion(sk, rots, pos, 30.0)])
    assert [m.weights_.shape[1] for m in pm.maps_][1:] == [0, 0, 0]
    pm.save(str(tmp_path / "one.npz"))
    check_same_map(pm, PostureMap.load(str(tmp_path / "one.npz")))


# -- save / load -----------------------------------------------------------------------------
def check_same_map(a, b):
    assert a.neuron_counts() == b.neuron_counts()
    for ma, mb in zip(a.maps_, b.maps_):
        for attr in ("weights_", "edges_", "hits_", "witness_", "period_"):
            np.testing.assert_array_equal(getattr(ma, attr), getattr(mb, attr), err_msg=attr)
        assert ma.radius_ == mb.radius_
        assert ma.weights_.dtype == np.float64 and mb.edges_.dtype == np.int64
    sa, sb = a.space_, b.space_
    for attr in ("mode", "root", "up", "height_scale", "orders"):
        assert getattr(sa, attr) == getattr(sb, attr), attr
    for attr in ("joints", "reference", "joint_class", "fill", "active"):
        np.testing.assert_array_equal(getattr(sa, attr), getattr(sb, attr), err_msg=attr)
    for d1, d2 in zip(sa.class_dims, sb.class_dims):
        np.testing.assert_array_equal(d1, d2)
    ka, kb = a.skeleton_, b.skeleton_
    assert ka.same_as(kb) and ka.names == kb.names and ka.euler_style == kb.euler_style
    np.testing.assert_array_equal(ka.offsets, kb.offsets)
    assert [(j, o.tolist()) for j, o in ka.end_sites] == [(j, o.tolist()) for j, o in kb.end_sites]
    assert a.describe() == b.describe()
    assert json.loads(json.dumps(b.describe())) == b.describe()  # JSON-ready


@pytest.mark.parametrize("mode", ["logmap", "euler"])
def test_save_load_equal(clips, tmp_path, mode):
    pm = PostureMap(features=mode, seed=2).fit(list(clips.values()), list(clips))
    path = tmp_path / "m.npz"
    pm.save(str(path))
    back = PostureMap.load(str(path))
    check_same_map(pm, back)
    walk = clips["walk"]
    np.testing.assert_array_equal(back.encode(walk), pm.encode(walk))
    x = pm.space_.split(pm.encode(walk))
    for c in range(4):
        np.testing.assert_array_equal(back.maps_[c].predict(x[c]), pm.maps_[c].predict(x[c]))
    assert (back.radius, back.epochs, back.seed, back.features) == (pm.radius, pm.epochs, pm.seed, mode)
    assert back.info_ == json.loads(json.dumps(pm.info_))


def test_load_accepts_pathlike(saved, fitted):
    check_same_map(fitted, PostureMap.load(saved))


def test_map_file_has_no_pickles(saved):
    with np.load(saved, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    assert all(a.dtype != object for a in arrays.values())
    meta = json.loads(bytes(arrays["meta"]).decode("utf-8"))
    assert meta["format"] == FORMAT and meta["version"] == VERSION
    assert set(meta["assignment"].values()) <= set(CLASSES)


def test_save_is_atomic(fitted, saved, tmp_path, monkeypatch):
    before = saved.read_bytes()

    def fail(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(UserError, match=r"map\.npz: cannot write file \(No space left on device\)"):
        fitted.save(str(saved))
    with pytest.raises(UserError, match=r"new\.npz: cannot write file"):
        fitted.save(str(tmp_path / "new.npz"))
    monkeypatch.undo()
    assert saved.read_bytes() == before  # the old map is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.npz"]  # no temporary left, no new.npz


# -- corrupt map files -----------------------------------------------------------------------
def test_missing_file(tmp_path):
    expect_map_error(tmp_path / "none.npz", "no such map file")


def test_empty_file(tmp_path):
    p = tmp_path / "empty.npz"
    p.write_bytes(b"")
    expect_map_error(p, "not a posturemap map file")


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.02])
def test_truncated_file(saved, keep):
    raw = saved.read_bytes()
    saved.write_bytes(raw[: int(len(raw) * keep)])
    expect_map_error(saved, "not a posturemap map file")


def test_random_bytes(tmp_path):
    p = tmp_path / "random.npz"
    p.write_bytes(np.random.default_rng(0).bytes(4096))
    expect_map_error(p, "not a posturemap map file")


def test_random_bytes_message_gives_no_pickle_advice(tmp_path):
    # Fix: in PostureMap.load, before np.load: `if not zipfile.is_zipfile(path): raise
    # MapFileError(path, "not a posturemap map file (not an .npz archive)")`.
    p = tmp_path / "random.npz"
    p.write_bytes(np.random.default_rng(0).bytes(4096))
    msg = expect_map_error(p, "not a posturemap map file")
    assert "pickle" not in msg


def test_damaged_compressed_member(saved):
    # Flipping bytes inside a member's deflate stream gives zlib.error from np.load, which
    # PostureMap.load does not catch (traceback in `posturemap inspect`). Fix: add zlib.error
    # to the except tuple around np.load (import zlib).
    raw = bytearray(saved.read_bytes())
    with zipfile.ZipFile(io.BytesIO(bytes(raw))) as z:
        info = z.getinfo("c0_weights.npy")
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    for i in range(start + 20, start + 120):
        raw[i] ^= 0xA5
    saved.write_bytes(bytes(raw))
    expect_map_error(saved)


def test_damaged_member_crc(saved):
    """Damage that inflates but fails the CRC check is reported."""
    arrays = map_arrays(saved)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:  # uncompressed: bytes are data
        for k, v in arrays.items():
            b = io.BytesIO()
            np.lib.format.write_array(b, v)
            z.writestr(f"{k}.npy", b.getvalue())
    raw = bytearray(buf.getvalue())
    with zipfile.ZipFile(io.BytesIO(bytes(raw))) as z:
        info = z.getinfo("c1_weights.npy")
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    raw[start + info.file_size - 3] ^= 0xFF
    saved.write_bytes(bytes(raw))
    expect_map_error(saved, "not a posturemap map file")


def test_foreign_npz(tmp_path):
    p = tmp_path / "foreign.npz"
    np.savez(p, weights=np.zeros((3, 2)), labels=np.arange(3))
    expect_map_error(p, "no 'meta' entry")


def test_plain_npy_file(tmp_path):
    # np.load returns an ndarray for a .npy: `with` fails with TypeError (traceback in the CLI).
    p = tmp_path / "array.npy"
    np.save(p, np.zeros((3, 3)))
    expect_map_error(p)


@pytest.mark.parametrize("meta, words", [
    ({"format": "something-else", "version": 1}, ["foreign format"]),
    ({"version": 1}, ["foreign format"]),
    ({"format": FORMAT, "version": 99}, ["version 99", f"reads {VERSION}"]),
    ({"format": FORMAT}, ["version None"]),
    ([1, 2, 3], ["foreign format"]),
])
def test_meta_wrong_format_or_version(saved, meta, words):
    rewrite(saved, map_arrays(saved), meta=meta_bytes(meta))
    expect_map_error(saved, *words)


def test_meta_not_json(saved):
    rewrite(saved, map_arrays(saved), meta=np.frombuffer(b"\xff\xfe{not json", dtype=np.uint8))
    expect_map_error(saved, "corrupt metadata")


def test_meta_missing_keys(saved):
    rewrite(saved, map_arrays(saved), meta=meta_bytes({"format": FORMAT, "version": VERSION}))
    expect_map_error(saved, "corrupt map file")


def test_object_array_is_never_unpickled(saved, tmp_path):
    trap = tmp_path / "unpickled"
    arrays = map_arrays(saved)
    obj = np.empty(1, dtype=object)
    obj[0] = _Trap(str(trap))
    rewrite(saved, arrays, c0_hits=obj)
    expect_map_error(saved)
    assert not trap.exists()
    # An object array as the meta entry too.
    rewrite(saved, arrays, meta=obj)
    expect_map_error(saved)
    assert not trap.exists()


@pytest.mark.parametrize("change", [
    lambda a: {"c0_weights": a["c0_weights"][:, :-1]},
    lambda a: {"c2_weights": a["c2_weights"].ravel()},
    lambda a: {"c1_weights": np.zeros((0, a["c1_weights"].shape[1]))},
    lambda a: {"c3_weights": np.full_like(a["c3_weights"], np.nan)},
    lambda a: {"c0_edges": np.array([[0, len(a["c0_weights"]) + 5]])},
    lambda a: {"c0_edges": np.array([0, 1, 2])},
    lambda a: {"c1_period": np.ones(1)},
    lambda a: {"space_fill": a["space_fill"][:-2]},
    lambda a: {"space_reference": a["space_reference"][:, :3]},
])
def test_corrupt_arrays(saved, change):
    arrays = map_arrays(saved)
    rewrite(saved, arrays, **change(arrays))
    expect_map_error(saved, "corrupt map file")


def test_missing_array(saved):
    arrays = map_arrays(saved)
    del arrays["c2_edges"]
    rewrite(saved, arrays)
    expect_map_error(saved, "corrupt map file", "c2_edges")


# -- CLI: train / inspect --------------------------------------------------------------------
def test_cli_train_and_inspect(bvh_dir, tmp_path, capsys):
    out = tmp_path / "walkrun.npz"
    files = [str(bvh_dir / f"{n}.bvh") for n in ("walk", "run", "wave")]
    assert cli.main(["train", *files, "-o", str(out), "--seed", "1", "--epochs", "3"]) == 0
    summary = capsys.readouterr().out
    assert out.is_file()
    pm = PostureMap.load(str(out))
    assert summary.startswith(f"{out}: 3 clips, 240 frames, {sum(pm.neuron_counts())} neurons")
    assert f"body {pm.neuron_counts()[0]}" in summary
    assert pm.epochs == 3 and pm.seed == 1
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".tmp")]

    assert cli.main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"{out}: posture map, features logmap")
    for c, n in zip(CLASSES, pm.neuron_counts()):
        assert any(line.split()[:2] == [c, str(n)] for line in text.splitlines()), c
    assert "UpperArm_L" in text
    legs = [line for line in text.splitlines() if line.split()[:1] == ["legs"]]
    assert legs == ["  legs    UpperLeg_L > LowerLeg_L > Foot_L > Toes_L; UpperLeg_R > LowerLeg_R > Foot_R > Toes_R"]

    assert cli.main(["inspect", str(out), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert set(d) >= {"skeleton", "features", "params", "classes", "training", "assignment"}
    assert [d["classes"][c]["neurons"] for c in CLASSES] == pm.neuron_counts()
    assert d["training"]["frames"] == 240 and d["training"]["clips"] == 3
    assert d["skeleton"] == {"joints": 21, "root": "Hips", "up": "Y"}
    assert d["params"]["epochs"] == 3
    assert all(d["classes"][c]["invalid_neurons"] == 0.0 for c in CLASSES)
    assert sorted(n for names in d["assignment"].values() for n in names) == sorted(pm.skeleton_.names)


def test_cli_train_folder_radius_features_classes(bvh_dir, tmp_path, capsys):
    classes = tmp_path / "classes.json"
    classes.write_text(json.dumps({"Neck": "body"}))
    out = tmp_path / "m.npz"
    code = cli.main(["train", str(bvh_dir), "-o", str(out), "--radius", "0.3", "--features", "euler",
                     "--neighborhood", "0", "--classes", str(classes)])
    assert code == 0
    pm = PostureMap.load(str(out))
    assert pm.space_.mode == "euler" and pm.neighborhood == 0
    assert [m.radius_ for m in pm.maps_] == [0.3] * 4
    assert "Neck" in pm.describe()["assignment"]["body"]
    assert "3 clips" in capsys.readouterr().out


def test_cli_same_result_as_library(bvh_dir, tmp_path, capsys):
    out = tmp_path / "m.npz"
    assert cli.main(["train", str(bvh_dir), "-o", str(out)]) == 0
    files = sorted(bvh_dir.glob("*.bvh"))
    lib = PostureMap().fit([bvh.read(f) for f in files])
    for a, b in zip(PostureMap.load(str(out)).maps_, lib.maps_):
        np.testing.assert_allclose(a.weights_, b.weights_, rtol=0, atol=1e-9)


def check_one_error_line(code, err, *words):
    assert code == 2
    assert len(err) == 1, err
    assert err[0].startswith("posturemap: error: ")
    for w in words:
        assert w in err[0], err[0]


def run_cli_here(capsys, *args):
    """``posturemap ARGS`` in this process: (exit code, stdout, stderr lines)."""
    try:
        code = cli.main([str(a) for a in args])
    except SystemExit as e:  # argparse errors
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err.splitlines()


# In this process in the quick set; each case in a fresh interpreter (as users run it) in the slow set.
@pytest.mark.parametrize("fresh", [pytest.param(False, id="in-process"),
                                   pytest.param(True, id="fresh-process", marks=pytest.mark.slow)])
def test_cli_errors(bvh_dir, tmp_path, saved, capsys, fresh):
    walk = bvh_dir / "walk.bvh"
    out = tmp_path / "out.npz"
    empty = tmp_path / "empty"
    empty.mkdir()
    bad_json = tmp_path / "bad.json"
    bad_json.write_text("{nope")
    unknown = tmp_path / "unknown.json"
    unknown.write_text('{"Tail": "detail"}')
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(saved.read_bytes()[:300])
    odd = tmp_path / "odd.bvh"
    bvh.write(str(odd), renamed_skeleton_clip(sample.clips()["run"]))
    cases = [
        (["train", tmp_path / "missing.bvh", "-o", out], [str(tmp_path / "missing.bvh"), "no such file"]),
        (["train", empty, "-o", out], [str(empty), "no .bvh files"]),
        (["train", walk, odd, "-o", out], [str(odd), "skeleton differs"]),
        (["inspect", corrupt], [str(corrupt), "not a posturemap map file"]),
        (["inspect", tmp_path / "none.npz"], [str(tmp_path / "none.npz"), "no such map file"]),
        (["train", walk, "--radius", "-1", "-o", out], ["--radius", "-1"]),
        (["train", walk, "--radius", "0", "-o", out], ["--radius"]),
        (["train", walk, "--classes", bad_json, "-o", out], [str(bad_json), "not valid JSON"]),
        (["train", walk, "--classes", unknown, "-o", out], [str(unknown), "unknown joint 'Tail'"]),
        (["train", walk, "--epochs", "0", "-o", out], ["--epochs"]),
        (["train", walk, "--features", "quat", "-o", out], ["--features"]),
        # Past the bounds a map cannot be computed or written: an infinite radius went into the
        # file's JSON as Infinity (unreadable), 1e200 overflowed when squared, a neighbourhood
        # past int64 broke the compiled kernel, a negative seed reached numpy (tracebacks).
        (["train", walk, "--radius", "inf", "-o", out], ["--radius", "up to 1e+06"]),
        (["train", walk, "--radius", "1e200", "-o", out], ["--radius"]),
        (["train", walk, "--neighborhood", "99999999999999999999999", "-o", out], ["--neighborhood"]),
        (["train", walk, "--epochs", "10001", "-o", out], ["--epochs", "from 1 to 10000"]),
        (["train", walk, "--seed", "-1", "-o", out], ["--seed", "from 0 to 4294967295"]),
        (["bench", "--seed", "-1", "--out", tmp_path / "bench"], ["--seed"]),
    ]
    for args, words in cases:
        code, stdout, err = run_cli(*args) if fresh else run_cli_here(capsys, *args)
        check_one_error_line(code, err, *words)
        assert stdout == ""
        assert not out.exists(), args  # nothing written when training fails
    assert not (tmp_path / "bench").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".tmp")]


@pytest.mark.parametrize("params", [dict(radius=float("inf")), dict(radius=1e200), dict(epochs=10**9),
                                    dict(neighborhood=10**23), dict(seed=-1)])
def test_parameters_past_their_bounds_are_refused(clips, params):
    # The same bounds in the API: a map that cannot be computed or written is refused before
    # training (a radius of inf was trained and saved, and the file could not be read back).
    with pytest.raises(ValueError, match="radius|epochs|neighborhood|seed"):
        PostureMap(**params).fit([clips["walk"]])


def test_cli_mixed_with_bandai(bvh_dir, bandai_files, tmp_path):
    out = tmp_path / "out.npz"
    code, _, err = run_cli("train", bvh_dir / "walk.bvh", bandai_files[0], "-o", out)
    check_one_error_line(code, err, str(bandai_files[0]), "skeleton differs")
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_cli_failed_training_keeps_existing_map(bvh_dir, tmp_path, saved):
    before = saved.read_bytes()
    odd = tmp_path / "odd.bvh"
    bvh.write(str(odd), renamed_skeleton_clip(sample.clips()["walk"]))
    code, _, err = run_cli("train", bvh_dir / "walk.bvh", odd, "-o", saved)
    check_one_error_line(code, err, str(odd))
    assert saved.read_bytes() == before


@pytest.mark.parametrize("rate", ["2", "0", "nan"])
def test_cli_bad_learning_rate(bvh_dir, tmp_path, rate):
    # Fix: in cli.build_parser, `--learning-rate` with a type that accepts only 0 < v < 1
    # (raise argparse.ArgumentTypeError(f"must be between 0 and 1 (exclusive), got {text!r}")).
    code, _, err = run_cli("train", bvh_dir / "walk.bvh", "--learning-rate", rate, "-o", tmp_path / "m.npz")
    check_one_error_line(code, err, "--learning-rate")


def test_cli_output_folder_checked_before_training(bvh_dir, tmp_path):
    # Fix: in cli._cmd_train call _check_output(args.output) first, before bvh.read_inputs.
    out = tmp_path / "no" / "such" / "map.npz"
    code, _, err = run_cli("train", bvh_dir / "walk.bvh", "-o", out)
    check_one_error_line(code, err, str(out), "output folder does not exist")


def test_cli_never_writes_over_its_inputs(bvh_dir, tmp_path, saved, capsys):
    # `train clip.bvh -o clip.bvh` replaced the clip with a map (exit 0), and `transition A B -o A`
    # replaced A: an output that is one of the command's inputs is refused, the input untouched.
    clip = tmp_path / "walk.bvh"
    clip.write_bytes((bvh_dir / "walk.bvh").read_bytes())
    other = bvh_dir / "run.bvh"
    before = clip.read_bytes()
    link = tmp_path / "alias.bvh"
    link.symlink_to(clip)  # the same file by another name
    for args, path, words in [
        (["train", clip, "-o", clip], clip, ["must end in .npz"]),
        (["train", clip, "-o", tmp_path / "map"], tmp_path / "map", ["must end in .npz"]),
        (["transition", clip, other, "-o", clip], clip, ["is an input", str(clip)]),
        (["transition", other, clip, "-o", link], link, ["is an input", str(clip)]),
        (["transition", clip, other, "--map", saved, "-o", clip], clip, ["is an input"]),
        (["resample", clip, "--fps", "60", "-o", link], link, ["is an input"]),
    ]:
        assert_refused(capsys, path, *args, words=words)
        assert clip.read_bytes() == before, args
    assert not (tmp_path / "map").exists()
    # An input read again as another input is no output: the command still runs.
    assert cli.main(["transition", str(clip), str(clip), "-o", str(tmp_path / "out.bvh")]) == 0
    capsys.readouterr()


def test_predict_and_score_follow_the_class_maps(sample_clips):
    # predict: per frame and class, the nearest neuron, checked by brute force on the class's
    # posture vectors; score: minus the mean distance to it in radii, averaged over classes.
    walk, run = sample_clips["walk"], sample_clips["run"]
    model = PostureMap(seed=0, library=False).fit([walk])
    win = model.predict(run)
    parts = model.space_.split(model.encode(run))
    assert win.shape == (len(run), len(model.maps_))
    per_class = []
    for c, (m, x) in enumerate(zip(model.maps_, parts)):
        d = m.distances(x)
        np.testing.assert_array_equal(win[:, c], np.argmin(d, axis=1))
        per_class.append(d.min(axis=1).mean() / m.radius_)
    assert model.score(run) == pytest.approx(-np.mean(per_class))
    assert model.score([walk]) > model.score(run)  # its own data is covered better
    assert model.score(walk) == model.score([walk])


def test_partial_fit_grows_the_maps_and_the_library(sample_clips):
    walk, run = sample_clips["walk"], sample_clips["run"]
    model = PostureMap(seed=0).fit([walk], ["walk"])
    before = model.score(run)
    neurons = model.neuron_counts()
    frames = len(model.library_)
    model.partial_fit([run], ["run"])
    assert model.score(run) > before  # the new motion is now covered
    assert all(n1 >= n0 for n0, n1 in zip(neurons, model.neuron_counts()))
    assert sum(model.neuron_counts()) > sum(neurons)
    assert model.info_["clips"] == 2 and model.info_["frames"] == len(walk) + len(run)
    # The library holds both clips (recorded and reversed), the new one indexed by the grown map.
    lib = model.library_
    assert len(lib) == frames + 2 * len(run)
    assert lib.clip_names[:2] == ("walk", "run")
    s = int(lib.clip_start[1])
    others = np.arange(run.skeleton.num_joints) != model.space_.root  # the root's is its tilt there
    np.testing.assert_allclose(lib.rots[s: s + len(run)][:, others], run.rotations[:, others], atol=1e-6)
    idx = model.space_.class_dims[1]
    win = model.maps_[1].predict(model.encode(run)[:, idx])
    np.testing.assert_array_equal(lib.win[s: s + len(run)], win)
    # Its toe counts are both clips' (the new clip's added to the first library's).
    alone = PostureMap(seed=0).fit([run], ["run"]).library_.toe_counts
    np.testing.assert_array_equal(lib.toe_counts, PostureMap(seed=0).fit([walk], ["walk"]).library_.toe_counts + alone)
    # Another fps or skeleton is refused, naming the clip.
    with pytest.raises(UserError, match="fps"):
        model.partial_fit([Motion(run.skeleton, run.rotations, run.positions, run.fps * 2)], ["fast"])


def test_a_grown_map_saves_loads_and_keys_on_its_new_graph(sample_clips, tmp_path):
    # partial_fit leaves witness -1 on neurons no new sample moved: the file keeps it and loads;
    # an engine built before the growth finds path keys on the grown graph (not the old one).
    walk, run, wave = sample_clips["walk"], sample_clips["run"], sample_clips["wave"]
    model = PostureMap(seed=0).fit([walk], ["walk"])
    engine = TransitionEngine(model)
    engine.add("w", walk)
    engine.add("r", run)
    engine.generate("w", "r", length=10, method="upm-path")  # the graph of the first map is cached
    model.partial_fit([run, wave], ["run", "wave"])
    assert any((m.witness_ < 0).any() for m in model.maps_)
    path = tmp_path / "grown.npz"
    model.save(str(path))
    back = PostureMap.load(str(path))
    assert back.neuron_counts() == model.neuron_counts()
    np.testing.assert_array_equal(back.predict(run), model.predict(run))
    assert back.library_.clip_names[:3] == ("walk", "run", "wave")
    r, _ = engine.generate("w", "r", length=10, method="upm-path")
    fresh = TransitionEngine(model)
    fresh.add("w", walk)
    fresh.add("r", run)
    np.testing.assert_array_equal(r, fresh.generate("w", "r", length=10, method="upm-path")[0])
    with pytest.raises(ValueError, match="names"):
        model.partial_fit([run, wave], ["one name"])
