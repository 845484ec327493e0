"""glTF 2.0 export (posturemap.io.gltf): the container against the specification, the Khronos
glTF-Validator, and three.js's GLTFLoader in the real browser.

The walk -> run transition on Bandai clips (as ``posturemap transition`` without ``--map``
makes it) is written as ``.glb`` (with the three parts as separate animations too) and as
``.gltf``; both must pass the validator with 0 errors and 0 warnings (its one information, the
skin no mesh uses, is expected: the file carries a skeleton and its animation, no mesh), and
three.js must load them with one track per channel, the motion's duration, and every joint's
world position at three frames (in A, in the transition, in B) equal to the BVH's forward
kinematics, in metres, within 0.1 mm.

The validator needs ``node`` and ``npm ci`` (``make web``); the browser test /usr/bin/chromium
(skipped with the reason when it is missing, like the other browser tests).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import struct
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest

from posturemap.io import bvh, gltf
from posturemap import cli
from posturemap.core import quat
from posturemap.errors import UserError
from posturemap.learn.model import PostureMap
from posturemap.core.motion import Motion, up_axis
from posturemap.core.skeleton import fk
from posturemap.synth.engine import transition

from pagekit import CHROMIUM, VENDOR, page_results, vendored  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
VALIDATE = REPO / "tests" / "js" / "validate_gltf.cjs"
ORIGIN = "http://gltf.test"
LENGTH = 20


@pytest.fixture(scope="module")
def walk_run(bandai_paths):
    """(result Motion, parts, A's frame count) of walk -> run on Bandai clips."""
    paths = bandai_paths(["walk_normal_001", "run_normal_001"])
    a, b = bvh.read(paths["walk_normal_001"]), bvh.read(paths["run_normal_001"])
    model = PostureMap(seed=0).fit([a, b], ["walk", "run"])
    out = transition(a, b, model, length=LENGTH, alpha=0.5)
    n = len(a)
    parts = [("A", 0, n), ("transition", n, n + LENGTH), ("B", n + LENGTH, len(out))]
    return out, parts


@pytest.fixture(scope="module")
def files(walk_run, tmp_path_factory):
    out, parts = walk_run
    folder = tmp_path_factory.mktemp("gltf")
    written = {"walk_run.glb": folder / "walk_run.glb", "walk_run.gltf": folder / "walk_run.gltf"}
    gltf.write(written["walk_run.glb"], out, parts=parts, split=True, name="walk_to_run")
    gltf.write(written["walk_run.gltf"], out, parts=parts, name="walk_to_run")
    return written


def expected_world_positions(m: Motion, scale: float, turn: np.ndarray) -> np.ndarray:
    """The BVH's forward kinematics (F, J, 3), in metres, turned to Y up."""
    return quat.mul_vec(turn, m.global_positions() * scale)


# -- the container and its content, against the specification ---------------------------------
def test_glb_layout_follows_the_spec(files, walk_run):
    data = files["walk_run.glb"].read_bytes()
    magic, version, length = struct.unpack_from("<III", data)
    assert (magic, version, length) == (0x46546C67, 2, len(data))  # 'glTF', 2, whole file
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_len % 4 == 0
    text = data[20: 20 + json_len]
    assert text == text.rstrip(b" ") + b" " * (len(text) - len(text.rstrip(b" ")))  # space padding
    bin_len, bin_type = struct.unpack_from("<II", data, 20 + json_len)
    assert bin_type == 0x004E4942 and bin_len % 4 == 0 and 28 + json_len + bin_len == len(data)
    doc, binary = gltf.read_glb(data)
    assert doc["asset"]["version"] == "2.0"
    assert doc["buffers"] == [{"byteLength": doc["buffers"][0]["byteLength"]}]  # no uri: the BIN chunk
    assert 0 <= bin_len - doc["buffers"][0]["byteLength"] < 4
    for view in doc["bufferViews"]:
        assert view["byteOffset"] % 4 == 0 and view["byteOffset"] + view["byteLength"] <= len(binary)
    # A broken header is refused.
    with pytest.raises(ValueError):
        gltf.read_glb(data[:-4])


def test_gltf_text_holds_the_same_document(files):
    doc_b, binary = gltf.read_glb(files["walk_run.glb"].read_bytes())
    doc_t = json.loads(files["walk_run.gltf"].read_text("utf-8"))
    uri = doc_t["buffers"][0].pop("uri")
    assert uri.startswith("data:application/octet-stream;base64,")
    import base64
    assert base64.b64decode(uri.split(",", 1)[1]) == binary[: doc_b["buffers"][0]["byteLength"]]
    assert doc_t["nodes"] == doc_b["nodes"]
    assert len(doc_t["animations"]) == 1 and len(doc_b["animations"]) == 4  # whole + A, transition, B


def test_content_is_the_motion_in_metres_y_up(files, walk_run):
    out, parts = walk_run
    doc, binary = gltf.read_glb(files["walk_run.glb"].read_bytes())
    sk = out.skeleton
    extras = doc["asset"]["extras"]
    assert extras["source_unit"] == "cm" and extras["metres_per_unit"] == 0.01
    assert extras["source_up_axis"] == "Y" and extras["fps"] == out.fps
    assert [(p["name"], p["first_frame"], p["frames"]) for p in extras["parts"]] == \
        [(n, s, e - s) for n, s, e in parts]
    assert [n["name"] for n in doc["nodes"][: sk.num_joints]] == list(sk.names)
    assert len(doc["nodes"]) == sk.num_joints + len(sk.end_sites)
    assert doc["skins"][0]["joints"] == list(range(len(doc["nodes"])))
    # Every joint's world position at every frame, from the file alone.
    world = gltf.world_positions(doc, binary)
    expected = expected_world_positions(out, 0.01, quat.identity())
    assert np.abs(world[:, : sk.num_joints] - expected).max() < 1e-5  # float32 in metres: 10 um
    # End Sites sit at their offsets from their joints.
    grot, gpos = out.global_transforms()
    for k, (j, offset) in enumerate(sk.end_sites):
        tip = (gpos[:, j] + quat.mul_vec(grot[:, j], np.broadcast_to(offset, gpos[:, j].shape))) * 0.01
        assert np.abs(world[:, sk.num_joints + k] - tip).max() < 1e-5
    # Times: one key per frame, k / fps seconds; the parts' animations restart at 0 on their frames.
    anims = doc["animations"]
    assert [a["name"] for a in anims] == ["walk_to_run", "A", "transition", "B"]
    times = gltf.accessor_array(doc, binary, anims[0]["samplers"][0]["input"])[:, 0]
    np.testing.assert_allclose(times, np.arange(len(out)) / out.fps, rtol=1e-6)
    for anim, (_, start, stop) in zip(anims[1:], parts):
        part = gltf.world_positions(doc, binary, anims.index(anim))
        np.testing.assert_allclose(part, world[start:stop], atol=1e-9)
    # Inverse bind matrices undo the rest pose (the nodes' own transforms): IBM x world = identity.
    ibm = gltf.accessor_array(doc, binary, doc["skins"][0]["inverseBindMatrices"]).reshape(-1, 4, 4)
    parents = np.full(len(doc["nodes"]), -1)
    for i, node in enumerate(doc["nodes"]):
        for c in node.get("children", []):
            parents[c] = i
    rest_r = np.array([np.array(n.get("rotation", [0, 0, 0, 1]))[[3, 0, 1, 2]] for n in doc["nodes"]])
    rest_p = np.array([n.get("translation", [0, 0, 0]) for n in doc["nodes"]])
    grot, gpos = fk(parents, rest_r, rest_p)
    world_rest = np.zeros((len(doc["nodes"]), 4, 4))
    world_rest[:, :3, :3], world_rest[:, :3, 3], world_rest[:, 3, 3] = quat.to_matrix(grot), gpos, 1.0
    product = ibm.transpose(0, 2, 1) @ world_rest  # stored column-major
    np.testing.assert_allclose(product, np.broadcast_to(np.eye(4), product.shape), atol=1e-5)
    assert np.abs(gpos).max() > 0.5  # a real rest pose, not all at the origin


def z_up(m: Motion) -> Motion:
    """The same motion in a Z-up world: (x, y, z) -> (x, -z, y), turned at the top joints."""
    turn = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.pi / 2)  # y -> z
    rots, pos = m.rotations.copy(), m.positions.copy()
    tops = np.flatnonzero(m.skeleton.parents < 0)
    rots[:, tops] = quat.mul(turn, rots[:, tops])
    pos[:, tops] = quat.mul_vec(turn, pos[:, tops])
    return Motion(m.skeleton, rots, pos, m.fps)


def test_z_up_clip_is_turned_to_y_up(sample_clips):
    walk = sample_clips["walk"]
    turned = z_up(walk)
    assert up_axis(walk) == 1 and up_axis(turned) == 2  # it really is Z-up now
    docs = [gltf.read_glb(gltf.dumps(m, name="walk")) for m in (walk, turned)]
    assert docs[1][0]["asset"]["extras"]["source_up_axis"] == "Z"
    worlds = [gltf.world_positions(doc, binary) for doc, binary in docs]
    np.testing.assert_allclose(worlds[1], worlds[0], atol=1e-5)
    scale = docs[0][0]["asset"]["extras"]["metres_per_unit"]
    np.testing.assert_allclose(worlds[0][:, : walk.skeleton.num_joints], walk.global_positions() * scale, atol=1e-5)
    assert worlds[0][..., 1].min() > -0.05 and worlds[0][..., 1].max() > 1.2  # on the floor, upright, in metres


def test_unknown_unit_takes_a_body_height_and_an_explicit_scale_wins(sample_clips):
    walk = sample_clips["walk"]
    unit, s = gltf.guess_scale(walk)
    odd = Motion(dataclasses.replace(walk.skeleton, offsets=walk.skeleton.offsets * 0.15),
                 walk.rotations, walk.positions * 0.15, walk.fps)
    unit_odd, s_odd = gltf.guess_scale(odd)
    assert unit_odd == "unknown"
    from posturemap.core.motion import body_height
    assert body_height(odd) * s_odd == pytest.approx(gltf.ASSUMED_HEIGHT_M)
    doc, _ = gltf.build(walk, metres_per_unit=0.5)
    assert doc["asset"]["extras"]["metres_per_unit"] == 0.5 and unit in gltf.METRES_PER
    with pytest.raises(ValueError, match="metres_per_unit"):
        gltf.build(walk, metres_per_unit=-1.0)
    with pytest.raises(ValueError, match="tile"):
        gltf.build(walk, parts=[("A", 0, 10), ("B", 11, len(walk))])


def test_quaternions_stay_in_one_hemisphere(sample_clips):
    walk = sample_clips["walk"]
    flipped = walk.rotations * np.where(np.arange(len(walk)) % 2, -1.0, 1.0)[:, None, None]
    doc, binary = gltf.build(Motion(walk.skeleton, flipped, walk.positions, walk.fps))
    for ch, sampler in zip(doc["animations"][0]["channels"], doc["animations"][0]["samplers"]):
        if ch["target"]["path"] == "rotation":
            q = gltf.accessor_array(doc, binary, sampler["output"]).astype(float)
            assert np.all(np.sum(q[1:] * q[:-1], axis=-1) > 0)  # LINEAR keys never take the long way
            np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-6)


# -- the command line ---------------------------------------------------------------------------
def test_cli_writes_glb_and_gltf_by_suffix(sample_clips, tmp_path, capsys):
    a, b = tmp_path / "walk.bvh", tmp_path / "run.bvh"
    bvh.write(a, sample_clips["walk"])
    bvh.write(b, sample_clips["run"])
    assert cli.main(["transition", str(a), str(b), "-o", str(tmp_path / "t.glb"), "--length", "12",
                     "--split-animations"]) == 0
    assert "t.glb" in capsys.readouterr().out
    doc, binary = gltf.read_glb((tmp_path / "t.glb").read_bytes())
    assert [x["name"] for x in doc["animations"]] == ["walk_to_run", "A", "transition", "B"]
    n_a = len(sample_clips["walk"])
    assert [(p["first_frame"], p["frames"]) for p in doc["asset"]["extras"]["parts"]] == \
        [(0, n_a), (n_a, 12), (n_a + 12, len(sample_clips["run"]))]
    # The same transition as BVH: the glTF's frames are its frames, in metres.
    assert cli.main(["transition", str(a), str(b), "-o", str(tmp_path / "t.bvh"), "--length", "12"]) == 0
    m = bvh.read(tmp_path / "t.bvh")
    scale = doc["asset"]["extras"]["metres_per_unit"]
    world = gltf.world_positions(doc, binary)[:, : m.skeleton.num_joints]
    assert np.abs(world - m.global_positions() * scale).max() < 1e-5 + 1e-6 * scale * 1e3
    assert cli.main(["transition", str(a), str(b), "-o", str(tmp_path / "t.gltf"), "--length", "12"]) == 0
    assert json.loads((tmp_path / "t.gltf").read_text())["asset"]["version"] == "2.0"


def test_cli_glb_errors_are_one_line(sample_clips, tmp_path, capsys):
    a = tmp_path / "walk.bvh"
    bvh.write(a, sample_clips["walk"])
    assert cli.main(["transition", str(a), str(a), "-o", str(tmp_path / "missing" / "t.glb")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("posturemap: error: ") and "output folder does not exist" in err and err.count("\n") == 1
    assert cli.main(["transition", str(a), str(a), "-o", str(tmp_path / "t.bvh"), "--split-animations"]) == 2
    err = capsys.readouterr().err
    assert "--split-animations" in err and ".glb" in err and err.count("\n") == 1
    assert not (tmp_path / "t.bvh").exists()


# -- the Khronos glTF-Validator -----------------------------------------------------------------
def validate(paths: list[Path]) -> list[dict]:
    node = shutil.which("node")
    if node is None:
        pytest.fail("node not found: the glTF-Validator runs on Node (apt-get install nodejs npm; .ci/run does)")
    if not (REPO / "node_modules" / "gltf-validator").is_dir():
        pytest.fail("node_modules/gltf-validator missing: run `make web` (npm ci installs it)")
    proc = subprocess.run([node, str(VALIDATE), *map(str, paths)], capture_output=True, text=True,
                          cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return [json.loads(line) for line in proc.stdout.splitlines()]


def test_khronos_validator_finds_no_error_or_warning(files, sample_clips, tmp_path):
    z_file = tmp_path / "wave_z_up.glb"
    gltf.write(z_file, z_up(sample_clips["wave"]), name="wave")
    reports = validate([files["walk_run.glb"], files["walk_run.gltf"], z_file])
    for path, report in zip([files["walk_run.glb"], files["walk_run.gltf"], z_file], reports):
        issues = report["issues"]
        assert (issues["numErrors"], issues["numWarnings"]) == (0, 0), (path.name, issues["messages"])
        # The one expected note: the skin is not used by a mesh (there is none).
        assert [(m["code"], m["pointer"]) for m in issues["messages"]] == [("UNUSED_OBJECT", "/skins/0")]
        assert report["info"]["hasSkins"] and report["info"]["hasDefaultScene"]
    assert [r["info"]["animationCount"] for r in reports] == [4, 1, 1]
    # The validator does catch a broken file: a non-unit rotation key.
    doc, binary = gltf.build(sample_clips["wave"])
    raw = bytearray(binary)
    rot = next(s["output"] for c, s in zip(doc["animations"][0]["channels"], doc["animations"][0]["samplers"])
               if c["target"]["path"] == "rotation")
    acc = doc["accessors"][rot]
    at = doc["bufferViews"][acc["bufferView"]]["byteOffset"] + acc.get("byteOffset", 0)
    raw[at: at + 16] = struct.pack("<4f", 0.5, 0.5, 0.5, 0.9)
    bad = tmp_path / "bad.glb"
    bad.write_bytes(gltf.glb_bytes(doc, bytes(raw)))
    assert validate([bad])[0]["issues"]["numErrors"] >= 1


# -- three.js GLTFLoader in headless Chromium ---------------------------------------------------
PAGE = """<!doctype html><meta charset="utf-8"><title>GLTFLoader</title>
<script type="importmap">{"imports": {"three": "/vendor/three.module.js", "three/addons/": "/vendor/addons/"}}</script>
<script type="module">
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
const spec = %s;
const out = {};
for (const file of spec.files) {
  const data = await (await fetch('/files/' + file)).arrayBuffer();
  const gltf = await new GLTFLoader().parseAsync(data, '');
  const clip = gltf.animations[0];
  const mixer = new THREE.AnimationMixer(gltf.scene);
  mixer.clipAction(clip).play();
  const positions = [];
  for (const f of spec.frames) {
    mixer.setTime(f / spec.fps);
    gltf.scene.updateMatrixWorld(true);
    positions.push(spec.joints.map((name) => gltf.scene.getObjectByName(name).getWorldPosition(new THREE.Vector3()).toArray()));
  }
  let bones = 0;
  gltf.scene.traverse((o) => { if (o.isBone) bones += 1; });
  out[file] = {
    animations: gltf.animations.map((a) => ({ name: a.name, tracks: a.tracks.length, duration: a.duration,
      keys: [...new Set(a.tracks.map((t) => t.times.length))],
      kinds: [...new Set(a.tracks.map((t) => t.name.split('.').pop()))].sort() })),
    positions, bones,
  };
}
window.__results = out;
</script>"""


def test_three_js_gltfloader_loads_the_motion(files, walk_run):
    if not os.path.exists(CHROMIUM):
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium; .ci/run does)")
    if not (VENDOR / "addons" / "loaders" / "GLTFLoader.js").is_file():
        pytest.fail(f"{VENDOR} has no GLTFLoader: run `make web`")
    out, parts = walk_run
    sk = out.skeleton
    n_a = parts[0][2]
    frames = [n_a - 5, n_a + LENGTH // 2, n_a + LENGTH + 7]  # in A, in the transition, in B
    spec = {"files": list(files), "frames": frames, "fps": out.fps, "joints": list(sk.names)}
    served = vendored()
    served.update({f"/files/{name}": path.read_bytes() for name, path in files.items()})
    served["/"] = (PAGE % json.dumps(spec)).encode()
    results = page_results(ORIGIN, served, "GLTFLoader")

    rotating = sum(any(c.endswith("rotation") for c in ch) for ch in sk.channels)
    moving = sum(sk.has_position(j) for j in range(sk.num_joints))
    expected = expected_world_positions(out[frames], 0.01, quat.identity())
    for name, r in results.items():
        whole = r["animations"][0]
        assert whole["name"] == "walk_to_run"
        assert whole["tracks"] == rotating + moving
        assert whole["kinds"] == ["position", "quaternion"]
        assert whole["keys"] == [len(out)]
        assert whole["duration"] == pytest.approx((len(out) - 1) / out.fps, rel=1e-6)
        assert r["bones"] == sk.num_joints + len(sk.end_sites)
        got = np.array(r["positions"])
        error_mm = np.abs(got - expected).max() * 1e3
        assert error_mm < 0.1, f"{name}: world positions differ by up to {error_mm:.4f} mm"
    parts_loaded = results["walk_run.glb"]["animations"][1:]
    assert [(a["name"], a["keys"]) for a in parts_loaded] == [(n, [e - s]) for n, s, e in parts]
    assert len(results["walk_run.gltf"]["animations"]) == 1


# -- the studio's export ------------------------------------------------------------------------
def test_studio_export_formats(sample_clips):
    pytest.importorskip("starlette", reason="the web extra (pip install 'posturemap[web]') is not installed")
    with warnings.catch_warnings():  # starlette 1.x prefers httpx2 for its test client; httpx still works
        warnings.simplefilter("ignore")
        from starlette.testclient import TestClient

    from posturemap.web.server import create_app

    model = PostureMap(seed=0, epochs=2).fit(list(sample_clips.values()))
    body = {"a": "wave", "b": "walk", "a_end": 40, "b_start": 10, "length": 8, "method": "spline"}
    with TestClient(create_app(sample_clips, model), raise_server_exceptions=False) as c:
        as_bvh = bvh.loads(c.post("/api/export", json=body).content)  # no format: BVH as before
        r = c.post("/api/export", json=dict(body, format="glb"))
        assert r.status_code == 200 and r.headers["content-type"] == "model/gltf-binary"
        assert r.headers["content-disposition"] == 'attachment; filename="wave_to_walk_spline.glb"'
        doc, binary = gltf.read_glb(r.content)
        assert [a["name"] for a in doc["animations"]] == ["wave_to_walk", "A", "transition", "B"]
        assert [(p["first_frame"], p["frames"]) for p in doc["asset"]["extras"]["parts"]] == \
            [(0, 41), (41, 8), (49, len(sample_clips["walk"]) - 10)]
        scale = doc["asset"]["extras"]["metres_per_unit"]
        world = gltf.world_positions(doc, binary)[:, : as_bvh.skeleton.num_joints]
        assert np.abs(world - as_bvh.global_positions() * scale).max() < 2e-5  # BVH text keeps 9 digits
        g = c.get("/api/export", params={**{k: str(v) for k, v in body.items()}, "format": "gltf"})
        assert g.status_code == 200 and g.headers["content-type"] == "model/gltf+json"
        assert json.loads(g.content)["nodes"] == doc["nodes"]
        for bad in ("fbx", 3, None):
            r = c.post("/api/export", json=dict(body, format=bad))
            if bad is None:
                assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
            else:
                assert r.status_code == 422 and r.json()["field"] == "format", r.text
        assert c.post("/api/transition", json=dict(body, format="glb")).status_code == 422  # export only


def test_two_top_joints_give_no_skin_and_still_the_motion(sample_clips, tmp_path):
    walk = sample_clips["walk"]
    parents = walk.skeleton.parents.copy()
    parents[5] = -1  # the left shoulder becomes a second top joint (its channels are then global)
    m = Motion(dataclasses.replace(walk.skeleton, parents=parents), walk.rotations, walk.positions, walk.fps)
    doc, binary = gltf.read_glb(gltf.dumps(m, metres_per_unit=0.01, up=1))
    assert "skins" not in doc  # a skin needs one common root
    assert doc["scenes"][0]["nodes"] == [0, 5]
    world = gltf.world_positions(doc, binary)[:, : len(parents)]
    assert np.abs(world - m.global_positions() * 0.01).max() < 1e-5


def test_write_checks_the_name_and_the_folder(sample_clips, tmp_path):
    walk = sample_clips["walk"]
    with pytest.raises(UserError, match=r"\.glb or \.gltf"):
        gltf.write(tmp_path / "walk.fbx", walk)
    with pytest.raises(UserError, match="cannot write") as info:
        gltf.write(tmp_path / "missing" / "walk.glb", walk)
    assert str(tmp_path / "missing" / "walk.glb") in str(info.value)
    assert list(tmp_path.iterdir()) == []
