"""Map file validation (issue 12): each crafted file of the issue is refused with one line and exit 2.

The reproducers go through ``posturemap inspect`` / ``transition --map`` in-process
(``cli.main``) and check the error contract: exit code 2, one line ``posturemap: error:
<file>: <what>`` on stderr, no traceback, no output file. ``serve --map`` loads through the
same ``PostureMap.load``.
"""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

from posturemap.io import bvh
from posturemap import cli, sample
from posturemap.io.mapfile import MAX_ARRAY_BYTES, MapFileError
from posturemap.learn.model import PostureMap
from clikit import assert_refused, run  # noqa: E402,F401


@pytest.fixture(scope="module")
def clips():
    return sample.clips()


@pytest.fixture(scope="module")
def map_bytes(clips, tmp_path_factory):
    path = tmp_path_factory.mktemp("map") / "good.npz"
    PostureMap(seed=3).fit(list(clips.values()), list(clips)).save(str(path))
    return path.read_bytes()


@pytest.fixture(scope="module")
def clip_files(clips, tmp_path_factory):
    folder = tmp_path_factory.mktemp("bvh")
    for name in ("walk", "run"):
        bvh.write(folder / f"{name}.bvh", clips[name])
    return folder / "walk.bvh", folder / "run.bvh"


def members(raw: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(raw), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def meta_of(raw: bytes) -> dict:
    return json.loads(bytes(members(raw)["meta"]).decode())


def build(raw: bytes, meta_dict: dict | None = None, **arrays) -> bytes:
    """The map ``raw`` with its metadata and some arrays replaced (an uncompressed npz)."""
    out = members(raw)
    if meta_dict is not None:
        out["meta"] = np.frombuffer(json.dumps(meta_dict).encode(), dtype=np.uint8)
    out.update(arrays)
    buf = io.BytesIO()
    np.savez(buf, **out)
    return buf.getvalue()


def with_meta_text(raw: bytes, text: str) -> bytes:
    return build(raw, None, meta=np.frombuffer(text.encode(), dtype=np.uint8))




def inspect_refuses(capsys, tmp_path, data: bytes, *words) -> str:
    path = tmp_path / "crafted.npz"
    path.write_bytes(data)
    return assert_refused(capsys, path, "inspect", path, words=words)


# -- the reproducers of issue 12 -------------------------------------------------------------
def test_issue12_meta_up_3(map_bytes, tmp_path, capsys):
    meta = meta_of(map_bytes)
    meta["space"]["up"] = 3
    inspect_refuses(capsys, tmp_path, build(map_bytes, meta), "space.up")


def test_issue12_meta_up_3_in_serve(map_bytes, tmp_path, clip_files, capsys):
    meta = meta_of(map_bytes)
    meta["space"]["up"] = 3
    path = tmp_path / "up3.npz"
    path.write_bytes(build(map_bytes, meta))
    assert_refused(capsys, path, "serve", clip_files[0], "--map", path, "--port", "0", words=["space.up"])


@pytest.mark.parametrize("text", ["1e999", "-1e999", "1" * 400, "1e308"])
def test_issue12_meta_huge_or_infinite_numbers(map_bytes, tmp_path, capsys, text):
    raw = json.dumps(meta_of(map_bytes))
    for field in ('"height_scale": ', '"fps": '):
        i = raw.index(field) + len(field)
        j = min(raw.index(c, i) for c in ",}" if c in raw[i:])
        crafted = raw[:i] + text + raw[j:]
        inspect_refuses(capsys, tmp_path, with_meta_text(map_bytes, crafted))


def test_issue12_meta_seed_with_thousands_of_digits(map_bytes, tmp_path, capsys):
    raw = json.dumps(meta_of(map_bytes)).replace('"seed": 3', '"seed": ' + "9" * 5000)
    inspect_refuses(capsys, tmp_path, with_meta_text(map_bytes, raw), "corrupt metadata")


def test_issue12_meta_deeply_nested(map_bytes, tmp_path, capsys):
    raw = json.dumps(meta_of(map_bytes))
    crafted = raw[:-1] + ', "deep": ' + "[" * 100_000 + "]" * 100_000 + "}"
    inspect_refuses(capsys, tmp_path, with_meta_text(map_bytes, crafted), "corrupt metadata")


@pytest.mark.parametrize("field, value", [("info", [1, 2]), ("info", "x"), ("quality", [1]),
                                          ("quality", {"body": "good"}), ("quality", {"body": {"neurons": None}})])
def test_issue12_info_or_quality_of_the_wrong_type(map_bytes, tmp_path, capsys, field, value):
    meta = meta_of(map_bytes)
    if field == "info":
        meta["info"] = value
    else:
        meta["info"]["quality"] = value
    inspect_refuses(capsys, tmp_path, build(map_bytes, meta), "info")


def test_issue12_zero_period(map_bytes, tmp_path, capsys):
    period = members(map_bytes)["c1_period"]
    inspect_refuses(capsys, tmp_path, build(map_bytes, c1_period=np.zeros_like(period)), "period")


def _npy_with_header(shape, dtype="<f8", body=b"") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue() + body


def _replace_member(raw: bytes, name: str, data: bytes, compress=zipfile.ZIP_STORED) -> bytes:
    src = zipfile.ZipFile(io.BytesIO(raw))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compress) as z:
        for info in src.infolist():
            z.writestr(info.filename, data if info.filename == name else src.read(info.filename))
    return buf.getvalue()


def test_issue12_npy_header_declaring_a_huge_shape(map_bytes, tmp_path, capsys):
    data = _npy_with_header((10 ** 12, 10 ** 9), body=b"\0" * 64)
    inspect_refuses(capsys, tmp_path, _replace_member(map_bytes, "c0_weights.npy", data), "c0_weights", "declares")


def test_issue12_six_gib_zero_entry_refused_from_its_header(map_bytes, tmp_path, capsys):
    # The crafted member declares 6 GiB of zeros; its header is refused before any data is read
    # (the archive holds only a few KiB of its deflated zeros here, the check does not need more).
    shape = (6 << 30) // 8
    assert shape * 8 > MAX_ARRAY_BYTES
    data = _npy_with_header((shape,), "<i8", body=b"\0" * 4096)
    crafted = _replace_member(map_bytes, "c2_hits.npy", data, zipfile.ZIP_DEFLATED)
    msg = inspect_refuses(capsys, tmp_path, crafted, "c2_hits", "declares")
    assert str(6 << 30) in msg


@pytest.mark.parametrize("fill", [np.nan, 0.0])
def test_issue12_nan_or_zero_weights_refused_by_transition(map_bytes, tmp_path, clip_files, capsys, fill):
    a = members(map_bytes)
    path = tmp_path / "weights.npz"
    path.write_bytes(build(map_bytes, c1_weights=np.full_like(a["c1_weights"], fill)))
    out = tmp_path / "out.bvh"
    assert_refused(capsys, path, "transition", *clip_files, "--map", path, "-o", out, "--method", "upm",
                   words=["weights"])
    assert not out.exists()


# -- more checks ------------------------------------------------------------------------------
def test_good_map_still_loads_and_transitions(map_bytes, tmp_path, clip_files, capsys):
    path = tmp_path / "good.npz"
    path.write_bytes(map_bytes)
    out = tmp_path / "out.bvh"
    code, _, err = run(capsys, "transition", *clip_files, "--map", path, "-o", out, "--method", "upm")
    assert code == 0, err
    assert np.all(np.isfinite(bvh.read(out).rotations))


def test_single_neuron_class_with_zero_weights_is_not_degenerate(map_bytes, tmp_path):
    # One neuron at the origin is a legitimate map of a class that never moves.
    a = members(map_bytes)
    d = a["c3_weights"].shape[1]
    path = tmp_path / "one.npz"
    path.write_bytes(build(map_bytes, c3_weights=np.zeros((1, d)), c3_edges=np.zeros((0, 2), np.int64),
                           c3_hits=np.ones(1, np.int64), c3_witness=np.zeros(1, np.int64)))
    assert PostureMap.load(path).maps_[3].n_neurons == 1


def test_loaded_arrays_are_writable(map_bytes, tmp_path):
    path = tmp_path / "good.npz"
    path.write_bytes(map_bytes)
    m = PostureMap.load(path)
    assert m.maps_[0].weights_.flags.writeable


@pytest.mark.parametrize("name, value, words", [
    ("library_rots", "nan", ["library_rots", "NaN"]),
    ("library_win", "object", ["library_win", "dtype"]),
    ("library_pose", "shape", ["library pose"]),
    ("c0_hits", "complex", ["c0_hits", "dtype"]),
    ("space_reference", "unnormalised", ["space_reference"]),
])
def test_arrays_checked(map_bytes, tmp_path, capsys, name, value, words):
    a = members(map_bytes)[name]
    if value == "nan":
        b = a.copy()
        b.flat[7] = np.nan
    elif value == "object":
        b = np.array([None] * len(a), dtype=object)
    elif value == "shape":
        b = a[:, :-1]
    elif value == "complex":
        b = a.astype(complex)
    else:
        b = a * 2
    if value == "object":  # np.savez would pickle it; store the header and bytes by hand
        crafted = _replace_member(map_bytes, f"{name}.npy", _npy_with_header((len(a),), "|O", b"\0" * 8 * len(a)))
    else:
        crafted = build(map_bytes, **{name: b})
    inspect_refuses(capsys, tmp_path, crafted, *words)


def test_header_shape_must_match_stored_bytes(map_bytes, tmp_path, capsys):
    w = members(map_bytes)["c0_weights"]
    buf = io.BytesIO()
    np.lib.format.write_array(buf, w)
    data = buf.getvalue()[:-16]  # two values short
    inspect_refuses(capsys, tmp_path, _replace_member(map_bytes, "c0_weights.npy", data), "c0_weights")


@pytest.mark.parametrize("mutate", [
    lambda m: m["skeleton"].__setitem__("parents", [5] + m["skeleton"]["parents"][1:]),
    lambda m: m["skeleton"]["offsets"][2].__setitem__(1, None),
    lambda m: m["skeleton"]["channels"].__setitem__(0, ["Wrotation"]),
    lambda m: m["space"].__setitem__("joints", [10 ** 6]),
    lambda m: m["space"].__setitem__("orders", 5),
    lambda m: m["params"].__setitem__("epochs", True),
    lambda m: m.__setitem__("radius", [1, 2, 3]),
    lambda m: m["library"].__setitem__("up", 3),
    lambda m: m["library"].__setitem__("frames", 10 ** 30),
    lambda m: m.__setitem__("classes", ["a", "b", "c", "d"]),
])
def test_meta_fields_checked(map_bytes, tmp_path, capsys, mutate):
    meta = meta_of(map_bytes)
    mutate(meta)
    inspect_refuses(capsys, tmp_path, build(map_bytes, meta), "corrupt map file")


def test_fifo_named_like_a_map_is_refused_at_once(tmp_path, capsys):
    import os

    fifo = tmp_path / "x.npz"
    os.mkfifo(fifo)
    assert_refused(capsys, fifo, "inspect", fifo, words=["not a regular file"])


def test_map_error_class_is_still_exported_from_model():
    from posturemap.learn import model

    assert model.MapFileError is MapFileError


def test_zip_bomb_member_is_refused_before_inflating(map_bytes, tmp_path, capsys):
    # 64 MiB of zeros deflate to about 64 KiB: consistent header, refused by its ratio.
    n = (64 << 20) // 8
    data = _npy_with_header((n,), "<i8", body=b"\0" * (n * 8))
    crafted = _replace_member(map_bytes, "c1_hits.npy", data, zipfile.ZIP_DEFLATED)
    assert len(crafted) < 1 << 20
    inspect_refuses(capsys, tmp_path, crafted, "c1_hits", "zip bomb")


def test_more_neurons_than_the_cap_refused_from_the_header(map_bytes, tmp_path, capsys, monkeypatch):
    from posturemap.io import mapfile

    monkeypatch.setattr(mapfile, "MAX_NEURONS", 50)  # the sample map's classes have more
    inspect_refuses(capsys, tmp_path, map_bytes, "weights", "does not fit the metadata")


def test_a_map_whose_library_has_other_legs_is_named_so_not_corrupt(map_bytes, tmp_path, capsys):
    # A map trained by an earlier version on a rig that names no leg holds the feet of no leg;
    # this version finds the hierarchy's legs there. Such a file is sound: the one line says
    # why it is refused and what to do, and does not call it corrupt.
    contacts = members(map_bytes)["library_contacts"]
    assert contacts.shape[1] == 2
    err = inspect_refuses(capsys, tmp_path, build(map_bytes, library_contacts=contacts[:, :0]),
                          "its motion library holds the feet of 0 legs, where this version finds 2",
                          "train the map again")
    assert "corrupt" not in err
    # The same width in a file whose other arrays do not fit is still corrupt.
    inspect_refuses(capsys, tmp_path, build(map_bytes, library_contacts=contacts[:-1]), "corrupt map file", "contacts")
