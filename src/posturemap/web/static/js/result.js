// The shown result. A transition answer carries only the new frames; the clips' frames are
// fetched once per clip (GET /api/clip/<name>, requests.js) and the result is put together here:
// A's frames 0..a_end, the new frames, then B's frames from b_start with the alignment applied
// to one joint. showResult() then puts it on the characters, the panels and the test hook.
import * as THREE from 'three';
import { makeClip } from './character.js';
import { drawPlot, showLabels, ui } from './panels.js';
import { drawTimeline, placePlayhead } from './playback.js';
import { state } from './state.js';
import { setPhase, studio } from './studio.js';

export function framesOf(payload) {
  // Tracks as typed arrays: quat[j] (4 per frame, x y z w), pos.get(j) (3 per frame) for moving joints.
  const index = new Map(state.info.skeleton.bones.map((b, j) => [b, j]));
  const quat = new Array(state.info.skeleton.bones.length), pos = new Map();
  for (const t of payload.tracks) {
    const dot = t.name.lastIndexOf('.');
    const j = index.get(t.name.slice(0, dot));
    if (t.type === 'quaternion') quat[j] = Float32Array.from(t.values);
    else pos.set(j, Float32Array.from(t.values));
  }
  return { frames: payload.frames, quat, pos };
}

export function assemble(res, ca, cb) {
  // The whole result as tracks (same shape as a clip payload, typed arrays for values).
  const skel = state.info.skeleton, J = skel.bones.length;
  const nb = res.inbetween.frames, na = res.params.a_end + 1, b0 = res.params.b_start;
  const n = res.frames, nB = n - na - nb;
  const mid = framesOf(res.inbetween);
  // B's placement is one joint's change (the root's, or a root bone's that carries root motion).
  const al = res.alignment, top = skel.bones.indexOf(al.joint);
  const turn = new THREE.Quaternion().fromArray(al.rotation);
  const shift = new THREE.Vector3().fromArray(al.translation);
  const q = new THREE.Quaternion(), v = new THREE.Vector3();
  const tracks = [];
  for (let j = 0; j < J; j++) {
    const out = new Float32Array(4 * n);
    out.set(ca.quat[j].subarray(0, 4 * na), 0);
    out.set(mid.quat[j], 4 * na);
    out.set(cb.quat[j].subarray(4 * b0, 4 * (b0 + nB)), 4 * (na + nb));
    if (j === top) {
      for (let f = na + nb; f < n; f++) q.fromArray(out, 4 * f).premultiply(turn).toArray(out, 4 * f);
    }
    tracks.push({ name: `${skel.bones[j]}.quaternion`, type: 'quaternion', values: out });
  }
  const moving = new Set([...ca.pos.keys(), ...cb.pos.keys(), ...mid.pos.keys(), top]);
  for (const j of [...moving].sort((x, y) => x - y)) {
    const out = new Float32Array(3 * n);
    const part = (src, from, count, at) => {
      if (src) out.set(src.subarray(3 * from, 3 * (from + count)), 3 * at);
      else for (let f = at; f < at + count; f++) out.set(skel.rest[j], 3 * f);
    };
    part(ca.pos.get(j), 0, na, 0);
    part(mid.pos.get(j), 0, nb, na);
    part(cb.pos.get(j), b0, nB, na + nb);
    if (j === top) {
      for (let f = na + nb; f < n; f++) v.fromArray(out, 3 * f).applyQuaternion(turn).add(shift).toArray(out, 3 * f);
    }
    tracks.push({ name: `${skel.bones[j]}.position`, type: 'vector', values: out });
  }
  const times = new Float32Array(n);
  for (let f = 0; f < n; f++) times[f] = f / res.fps;
  return { ...res, times, tracks };
}

// Show res (and the comparison cres, or null) made from params; `kind` names the input that
// asked for it (where the playhead goes).
export function showResult(res, cres, params, kind) {
  const { main, cmp, ghost } = state;
  state.result = res;
  main.setClip(makeClip(res, `${res.a} → ${res.b} (${res.method})`));
  if (cres !== state.cmpResult) cmp.setClip(cres ? makeClip(cres, `${cres.a} → ${cres.b} (${cres.method})`) : null);
  state.cmpResult = cres;
  cmp.group.visible = !!cres;
  if (res.key) {
    ghost.setClip(main.clip);
    ghost.setTime(res.key.frame / res.fps);  // placed where the result is at the key's frame
    ghost.setRotations(res.key.bones, res.key.quaternions);
  } else {
    ghost.setClip(null);
  }
  ghost.group.visible = !!res.key && ui.ghost.checked;
  state.trail.update(res, state.info.skeleton);

  studio.params = params;
  studio.frameCount = res.frames;
  studio.compare = cres ? cres.method : null;
  studio.keyPosture = res.key ? {
    frame: res.key.frame, joints: res.key.joints, bones: res.key.bones, quaternions: res.key.quaternions,
    root_height: res.key.root_height, neurons: res.key.neurons,
  } : null;
  studio.result = {
    a: res.a, b: res.b, method: res.method, frames: res.frames, fps: res.fps, segments: res.segments,
    seams: res.seams, transition: res.transition, key_frame: res.key_frame, retrieval: res.retrieval || null,
  };
  if (state.map && state.map.state !== 'training' && state.map.state !== 'loading') setPhase('ready');

  placePlayhead(res, params, kind);
  showLabels(res, cres, params);
  drawTimeline();
  drawPlot();
  state.needsRender = true;
}
