"""Transition outputs in a real consumer of BVH: three.js's BVHLoader in headless Chromium.

The issue "Motion transitions" asks for three outputs made with
:func:`posturemap.synth.engine.transition` on Bandai clips (walk -> run, bow -> dance-short,
run -> walk-back) and written with :func:`posturemap.io.bvh.write` to import in a real BVH reader.
They are loaded with the vendored ``BVHLoader`` (``make web``) in a page served through
Playwright's request routing (no server): each must give one track per joint and channel kind
with one key per frame, one bone per joint and End Site, the file's frame time, and rotations
equal to the ones posturemap wrote.

Skipped, with the reason, only when /usr/bin/chromium or the Bandai data is missing.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from posturemap.io import bvh
from posturemap.learn.model import PostureMap
from posturemap.synth.engine import transition

from pagekit import CHROMIUM, VENDOR, page_results, vendored  # noqa: E402
PAIRS = [("walk_normal_001", "run_normal_001"), ("bow_normal_001", "dance-short_normal_001"),
         ("run_normal_001", "walk-back_normal_001")]
ORIGIN = "http://consumer.test"

if not os.path.exists(CHROMIUM):
    pytest.skip(f"{CHROMIUM} not found: install Debian's chromium (apt-get install chromium; .ci/run does)",
                allow_module_level=True)

PAGE = """<!doctype html><meta charset="utf-8"><title>BVHLoader</title>
<script type="importmap">{"imports": {"three": "/vendor/three.module.js", "three/addons/": "/vendor/addons/"}}</script>
<script type="module">
import * as THREE from 'three';
import { BVHLoader } from 'three/addons/loaders/BVHLoader.js';
const names = %s;
const out = {};
const loader = new BVHLoader();
for (const name of names) {
  const text = await (await fetch('/bvh/' + name + '.bvh')).text();
  const { skeleton, clip } = loader.parse(text);
  const quats = clip.tracks.filter((t) => t.name.endsWith('.quaternion'));
  out[name] = {
    bones: skeleton.bones.length,
    named: skeleton.bones.filter((b) => b.name !== 'ENDSITE').map((b) => b.name),
    tracks: clip.tracks.length,
    keys: [...new Set(clip.tracks.map((t) => t.times.length))],
    values: clip.tracks.every((t) => t.values.length === t.times.length * t.getValueSize()),
    duration: clip.duration, dt: clip.tracks[0].times[1] - clip.tracks[0].times[0],
    quats: quats.map((t) => Array.from(t.values)),
    quatNames: quats.map((t) => t.name.slice(0, -'.quaternion'.length)),
  };
  // It plays: an AnimationMixer drives the skeleton through the clip.
  const root = new THREE.Group();
  root.add(skeleton.bones[0]);
  const mixer = new THREE.AnimationMixer(root);
  mixer.clipAction(clip).play();
  mixer.setTime(clip.duration / 2);
  out[name].played = skeleton.bones.every((b) => Number.isFinite(b.quaternion.w));
}
window.__results = out;
</script>"""


@pytest.fixture(scope="module")
def outputs(bandai_paths, tmp_path_factory):
    """The three transitions as BVH files: {name: (path, Motion written)}."""
    by_name = bandai_paths({n for pair in PAIRS for n in pair})
    folder = tmp_path_factory.mktemp("consumer")
    out = {}
    for a_name, b_name in PAIRS:
        a, b = bvh.read(by_name[a_name]), bvh.read(by_name[b_name])
        model = PostureMap(seed=0).fit([a, b], [a_name, b_name])  # as `posturemap transition` without --map
        m = transition(a, b, model, length=20, alpha=0.5)
        name = f"{a_name.split('_')[0]}-to-{b_name.split('_')[0]}"
        path = folder / f"{name}.bvh"
        bvh.write(path, m)
        assert len(m) == len(a) + 20 + len(b)
        out[name] = (path, m)
    return out


@pytest.fixture(scope="module")
def loaded(outputs):
    if not (VENDOR / "addons" / "loaders" / "BVHLoader.js").is_file():
        pytest.fail(f"{VENDOR} has no three.js: run `make web`")
    files = vendored()
    files.update({f"/bvh/{n}.bvh": path.read_bytes() for n, (path, _) in outputs.items()})
    files["/"] = (PAGE % json.dumps(list(outputs))).encode()
    return page_results(ORIGIN, files, "BVHLoader")


@pytest.mark.parametrize("name", [f"{a.split('_')[0]}-to-{b.split('_')[0]}" for a, b in PAIRS])
def test_three_js_bvhloader_imports_the_transition(outputs, loaded, name):
    _, m = outputs[name]
    r = loaded[name]
    sk = m.skeleton
    frames = len(m)
    assert r["bones"] == sk.num_joints + len(sk.end_sites)  # BVHLoader makes a bone per End Site too
    assert r["named"] == list(sk.names)
    assert r["tracks"] == 2 * sk.num_joints  # .position and .quaternion per joint
    assert r["keys"] == [frames], f"tracks have {r['keys']} keys, the file {frames} frames"
    assert r["values"] and r["played"]
    assert r["dt"] == pytest.approx(1.0 / m.fps, rel=1e-6)
    assert r["duration"] == pytest.approx((frames - 1) / m.fps, rel=1e-6)
    # three.js's rotations from the file's Euler angles are the ones posturemap wrote.
    assert r["quatNames"] == list(sk.names)
    q = np.array(r["quats"]).reshape(sk.num_joints, frames, 4)
    ref = m.rotations.transpose(1, 0, 2)[..., [1, 2, 3, 0]]
    dots = np.abs(np.sum(q * ref, axis=-1))
    assert dots.min() > 1 - 1e-5, f"largest rotation difference {np.degrees(2 * np.arccos(dots.min())):.3f} deg"
