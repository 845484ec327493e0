// posturemap transition studio: asks the local server for transitions as the controls move and
// plays them with three.js (Bone / Skeleton, AnimationClip with <bone>.quaternion and
// <bone>.position tracks, AnimationMixer). No CDN: three.js is vendored next to this file.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const $ = (id) => document.getElementById(id);

const COLOR = {
  a: '#5b8def', t: '#ff8a3d', b: '#3ecf8e', cmp: '#38bdf8', ghost: '#b794f6', main: '#dfe4ea',
  bg: '#0d1117', line: '#263041', muted: '#8b97a8', text: '#e6ebf2',
};
const METHOD_NAMES = {
  upm: 'UPM key (paper)', 'upm-path': 'UPM key on map path', 'upm-valid': 'UPM key, validated',
  retrieval: 'Retrieved real motion', auto: 'Auto (by gap and match)',
  spline: 'Spline, no key', slerp: 'SLERP / LERP', inertialize: 'Inertialization',
};
const methodName = (m) => METHOD_NAMES[m] || m;
const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));

// ---- test and debugging hook -------------------------------------------------------------
const studio = {
  state: 'loading',          // loading | training | ready | error
  map: null,                 // last /api/status answer
  params: null,              // parameters of the shown result
  frameCount: 0,             // frames of the shown result (A part + transition + B part)
  frame: 0,                  // frame under the playhead
  keyPosture: null,          // {frame, joints, bones, quaternions (x, y, z, w)} of the shown key
  result: null,              // summary of the shown result (segments, seams, key frame, method)
  compare: null,             // method of the overlaid comparison, or null
  latencies: [],             // ms from a control's input event to the next frame after the new pose is drawn
  timings: [],               // the same updates split up: ms after the input event at each step
  errors: [],                // messages shown to the user
  requests: 0,               // transition requests sent
  renders: 0,
  renderScale: 1,            // fraction of the full resolution of the last frame drawn
  profile: null,             // render profile: 'full' (GPU) or 'lite' (software WebGL)
  displayedKey: () => (ghost ? ghost.pose() : null),   // the ghost skeleton's bone quaternions
  // A promise resolved once `latencies` holds n entries (a driver waits without polling the page).
  latencyCount: (n) => new Promise((resolve) => {
    const check = () => { if (studio.latencies.length >= n) resolve(n); else latencyWaiters.push(check); };
    check();
  }),
  setFrame: (f) => { setFrame(f); },
  // The main character's joint positions at frame f as drawn, in the clips' space and unit.
  jointPositions: (f) => {
    setFrame(f);
    main.setTime(time);
    scene.updateMatrixWorld(true);
    return main.bones.map((b) => world.worldToLocal(b.getWorldPosition(new THREE.Vector3())).toArray());
  },
  play: (on) => setPlaying(on),
  // Camera around its target: azimuth from +Z and elevation in degrees, distance in metres.
  setView: (azimuth, elevation, distance) => {
    const a = THREE.MathUtils.degToRad(azimuth), e = THREE.MathUtils.degToRad(elevation);
    camera.position.copy(controls.target).add(new THREE.Vector3(
      distance * Math.cos(e) * Math.sin(a), distance * Math.sin(e), distance * Math.cos(e) * Math.cos(a)));
    controls.update();
    needsRender = true;
  },
};
const latencyWaiters = [];
window.__studio = studio;

// ---- scene ---------------------------------------------------------------------------------
// Two render profiles. "full" (a GPU): antialiasing and shadow maps. "lite" (software WebGL such
// as SwiftShader or llvmpipe, which the browser reports as a major performance caveat): neither,
// and a soft disc under each character instead of a shadow map; a frame costs about a third.
// ?render=full or ?render=lite in the address overrides the choice.
function softwareWebGL() {
  const c = document.createElement('canvas');
  const gl = c.getContext('webgl2', { failIfMajorPerformanceCaveat: true });
  if (!gl) return true;
  const dbg = gl.getExtension('WEBGL_debug_renderer_info');
  const name = dbg ? String(gl.getParameter(dbg.UNMASKED_RENDERER_WEBGL)) : '';
  gl.getExtension('WEBGL_lose_context')?.loseContext();
  return /swiftshader|llvmpipe|softpipe|software|basic render/i.test(name);
}
const asked = new URLSearchParams(location.search).get('render');
const PROFILE = asked === 'full' || asked === 'lite' ? asked : softwareWebGL() ? 'lite' : 'full';
const FULL = PROFILE === 'full';
studio.profile = PROFILE;

const canvas = $('view');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: FULL });
renderer.shadowMap.enabled = FULL;
renderer.shadowMap.type = THREE.PCFShadowMap;
renderer.toneMapping = THREE.ACESFilmicToneMapping;
renderer.toneMappingExposure = 1.05;

const scene = new THREE.Scene();
scene.background = new THREE.Color(COLOR.bg);
scene.fog = new THREE.Fog(COLOR.bg, 7, 26);

const camera = new THREE.PerspectiveCamera(38, 1, 0.05, 200);
camera.position.set(2.3, 1.45, 3.0);
const controls = new OrbitControls(camera, canvas);
controls.target.set(0, 0.85, 0);
controls.enableDamping = false;
controls.maxPolarAngle = Math.PI * 0.495;
controls.minDistance = 0.8;
controls.maxDistance = 30;

scene.add(new THREE.HemisphereLight(0xdfe8f5, 0x202633, 1.6));
const sun = new THREE.DirectionalLight(0xffffff, 2.4);
sun.position.set(2.5, 5, 3);
sun.castShadow = FULL;
sun.shadow.mapSize.set(1024, 1024);
Object.assign(sun.shadow.camera, { left: -3, right: 3, top: 3, bottom: -3, near: 0.5, far: 14 });
sun.shadow.bias = -0.0005;
sun.shadow.radius = 3;
scene.add(sun, sun.target);
const rim = new THREE.DirectionalLight(0x88aaff, 0.6);
rim.position.set(-3, 2.5, -4);
scene.add(rim);

// Ground: a 1 m grid with 25 cm subdivisions computed in the fragment shader (anti-aliased with
// screen-space derivatives; a tiled texture costs several times more to sample in software).
function groundMaterial() {
  const m = new THREE.MeshLambertMaterial({ color: '#151c26' });
  const glsl = (hex) => `vec3(${new THREE.Color(hex).toArray().map((x) => x.toFixed(5)).join(', ')})`;  // linear
  m.onBeforeCompile = (sh) => {
    sh.vertexShader = sh.vertexShader
      .replace('#include <common>', '#include <common>\nvarying vec2 vGround;')
      .replace('#include <begin_vertex>', '#include <begin_vertex>\nvGround = (modelMatrix * vec4(position, 1.0)).xz;');
    sh.fragmentShader = sh.fragmentShader
      .replace('#include <common>', `#include <common>
varying vec2 vGround;
float gridLine(vec2 p, float width) {
  vec2 d = abs(fract(p - 0.5) - 0.5) / max(fwidth(p) * width, 1e-5);
  return 1.0 - min(min(d.x, d.y), 1.0);
}`)
      .replace('#include <color_fragment>', `#include <color_fragment>
vec2 fine = vGround * 4.0;
float near = 1.0 - clamp(length(fwidth(fine)) - 0.3, 0.0, 1.0);
diffuseColor.rgb = mix(diffuseColor.rgb, ${glsl('#1f2836')}, gridLine(fine, 1.0) * near);
diffuseColor.rgb = mix(diffuseColor.rgb, ${glsl('#2e3a4d')}, gridLine(vGround, 1.5));`);
  };
  return m;
}
const ground = new THREE.Mesh(new THREE.PlaneGeometry(200, 200), groundMaterial());
ground.rotation.x = -Math.PI / 2;
ground.receiveShadow = FULL;
scene.add(ground);

// In the lite profile: a soft dark disc on the ground under a character's root.
function blobShadow() {
  const c = document.createElement('canvas');
  c.width = c.height = 64;
  const g = c.getContext('2d');
  const grad = g.createRadialGradient(32, 32, 0, 32, 32, 32);
  grad.addColorStop(0, 'rgba(0,0,0,0.55)');
  grad.addColorStop(0.55, 'rgba(0,0,0,0.3)');
  grad.addColorStop(1, 'rgba(0,0,0,0)');
  g.fillStyle = grad;
  g.fillRect(0, 0, 64, 64);
  const mesh = new THREE.Mesh(new THREE.PlaneGeometry(0.9, 0.9), new THREE.MeshBasicMaterial({
    map: new THREE.CanvasTexture(c), transparent: true, depthWrite: false, fog: false,
    polygonOffset: true, polygonOffsetFactor: -2, polygonOffsetUnits: -2,
  }));
  mesh.rotation.x = -Math.PI / 2;
  mesh.renderOrder = 1;
  mesh.visible = false;
  scene.add(mesh);
  return mesh;
}

// Clip space (the clips' own unit and up axis) inside a group scaled to metres.
const world = new THREE.Group();
scene.add(world);

// ---- characters --------------------------------------------------------------------------
class Character {
  // A three.js skeleton of the served joints with shaded capsules between joints.
  constructor(skel, { color, opacity = 1, thickness = 1, shadows = true, emissive = 0x000000 }) {
    this.skel = skel;
    this.group = new THREE.Group();
    this.bones = skel.bones.map((name, j) => {
      const b = new THREE.Bone();
      b.name = name;
      b.position.fromArray(skel.rest[j]);
      return b;
    });
    skel.parents.forEach((p, j) => (p >= 0 ? this.bones[p] : this.group).add(this.bones[j]));
    this.skeleton = new THREE.Skeleton(this.bones);
    this.baseColor = new THREE.Color(color);
    this.material = new THREE.MeshStandardMaterial({
      color, roughness: 0.48, metalness: 0.06, emissive, emissiveIntensity: 0.35,
      transparent: opacity < 1, opacity, depthWrite: opacity >= 1,
    });
    const H = skel.height;
    const below = belowRoot(skel);
    const v = new THREE.Vector3();
    for (let j = 0; j < this.bones.length; j++) {
      const p = skel.parents[j];
      if (p >= 0 && below[p] && below[j]) this.link(this.bones[p], v.fromArray(skel.rest[j]), skel.names[j], H, thickness);
      if (below[j]) this.joint(this.bones[j], H, thickness, skel.names[j]);
    }
    for (const [j, off] of skel.end_sites) {
      if (!below[j]) continue;
      if (/head/i.test(skel.names[j])) this.head(this.bones[j], v.fromArray(off), H, thickness);
      else this.link(this.bones[j], v.fromArray(off), skel.names[j], H, thickness);
    }
    this.group.traverse((o) => { if (o.isMesh) { o.castShadow = shadows; o.receiveShadow = false; } });
    this.mixer = new THREE.AnimationMixer(this.group);
    this.clip = null;
    this.blob = null;          // disc under the root in the lite profile
    this.action = null;
    this.duration = 0;
  }

  link(parent, offset, name, H, k) {
    const len = offset.length();
    if (len < 1e-3 * H) return;
    const torso = /spine|chest|hips|pelvis|torso|abdomen/i.test(name);
    const r = k * (torso ? 0.05 * H : clamp(0.1 * len, 0.011 * H, 0.027 * H));
    const geo = new THREE.CapsuleGeometry(r, Math.max(len - r, 1e-3), 4, 12);
    geo.translate(0, len / 2, 0);
    const mesh = new THREE.Mesh(geo, this.material);
    mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), offset.clone().normalize());
    parent.add(mesh);
  }

  joint(bone, H, k, name) {
    const r = k * (/hand|foot|toe|wrist|ankle/i.test(name) ? 0.016 : 0.021) * H;
    bone.add(new THREE.Mesh(new THREE.SphereGeometry(r, 14, 10), this.material));
  }

  head(bone, offset, H, k) {
    const r = k * Math.max(0.058 * H, 0.45 * offset.length());
    const mesh = new THREE.Mesh(new THREE.SphereGeometry(r, 24, 16), this.material);
    mesh.position.copy(offset).multiplyScalar(0.55);
    mesh.scale.set(0.9, 1.1, 0.98);
    bone.add(mesh);
  }

  setClip(clip) {
    if (this.action) {
      this.action.stop();
      this.mixer.uncacheAction(this.clip);
      this.mixer.uncacheClip(this.clip);
    }
    this.clip = clip;
    this.duration = clip ? clip.duration : 0;
    this.action = clip ? this.mixer.clipAction(clip) : null;
    if (this.action) this.action.play();
  }

  setTime(t) {
    if (this.action) this.mixer.setTime(clamp(t, 0, Math.max(this.duration - 1e-6, 0)));
  }

  tint(color, amount) {
    this.material.color.copy(this.baseColor).lerp(color, amount);
  }

  pose() {
    return this.bones.map((b) => [b.quaternion.x, b.quaternion.y, b.quaternion.z, b.quaternion.w]);
  }

  rootWorld(target) {
    return this.bones[this.skel.root].getWorldPosition(target);
  }
}

function belowRoot(skel) {
  // Joints at or below the root joint (the ones drawn): above it sit static helpers such as joint_Root.
  const below = skel.parents.map(() => false);
  skel.parents.forEach((p, j) => { below[j] = j === skel.root || (p >= 0 && below[p]); });
  return below;
}

// The root's path on the ground, coloured by segment (A, transition, B): a flat ribbon.
class Trail {
  constructor() {
    this.material = new THREE.MeshBasicMaterial({
      vertexColors: true, transparent: true, opacity: 0.8, depthWrite: false, side: THREE.DoubleSide,
      polygonOffset: true, polygonOffsetFactor: -4, polygonOffsetUnits: -4,
    });
    this.mesh = new THREE.Mesh(new THREE.BufferGeometry(), this.material);
    this.mesh.renderOrder = 1;
    this.mesh.frustumCulled = false;
  }

  update(res, skel) {
    // World positions of the root joint: its chain of ancestors composed from the tracks.
    const n = res.frames, up = skel.up;
    const chain = [];
    for (let j = skel.root; j >= 0; j = skel.parents[j]) chain.unshift(j);
    const byName = new Map(res.tracks.map((t) => [t.name, t.values]));
    const parts = chain.map((j) => ({
      pos: byName.get(`${skel.bones[j]}.position`), quat: byName.get(`${skel.bones[j]}.quaternion`), rest: skel.rest[j],
    }));
    const m = new THREE.Matrix4(), local = new THREE.Matrix4(), p = new THREE.Vector3(), q = new THREE.Quaternion();
    const one = new THREE.Vector3(1, 1, 1);
    const pts = [];
    for (let f = 0; f < n; f++) {
      m.identity();
      for (const c of parts) {
        if (c.pos) p.set(c.pos[3 * f], c.pos[3 * f + 1], c.pos[3 * f + 2]); else p.fromArray(c.rest);
        if (c.quat) q.set(c.quat[4 * f], c.quat[4 * f + 1], c.quat[4 * f + 2], c.quat[4 * f + 3]); else q.identity();
        m.multiply(local.compose(p, q, one));
      }
      const v = new THREE.Vector3().setFromMatrixPosition(m);
      v.setComponent(up, 0.004 * skel.height);
      pts.push(v);
    }
    const w = 0.028 * skel.height;
    const pos = new Float32Array(n * 2 * 3), col = new Float32Array(n * 2 * 3), idx = [];
    const [t0, t1] = res.transition;
    const ca = new THREE.Color(COLOR.a), ct = new THREE.Color(COLOR.t), cb = new THREE.Color(COLOR.b);
    const upv = new THREE.Vector3().setComponent(up, 1), d = new THREE.Vector3(), side = new THREE.Vector3();
    for (let f = 0; f < n; f++) {
      d.subVectors(pts[Math.min(f + 1, n - 1)], pts[Math.max(f - 1, 0)]);
      side.crossVectors(d, upv);
      if (side.lengthSq() < 1e-12) side.set(0, 0, 0); else side.normalize().multiplyScalar(w / 2);
      pts[f].clone().add(side).toArray(pos, 6 * f);
      pts[f].clone().sub(side).toArray(pos, 6 * f + 3);
      const c = f < t0 ? ca : f <= t1 ? ct : cb;
      c.toArray(col, 6 * f);
      c.toArray(col, 6 * f + 3);
      if (f < n - 1) idx.push(2 * f, 2 * f + 1, 2 * f + 2, 2 * f + 1, 2 * f + 3, 2 * f + 2);
    }
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(pos, 3));
    g.setAttribute('color', new THREE.BufferAttribute(col, 3));
    g.setIndex(idx);
    this.mesh.geometry.dispose();
    this.mesh.geometry = g;
  }
}

function makeClip(res, name) {
  const times = Float32Array.from(res.times);
  const tracks = res.tracks.map((t) => (t.type === 'quaternion'
    ? new THREE.QuaternionKeyframeTrack(t.name, times, t.values)
    : new THREE.VectorKeyframeTrack(t.name, times, t.values)));
  return new THREE.AnimationClip(name, res.duration, tracks);
}

// ---- clip frames and the whole result ------------------------------------------------------
// A transition answer carries only the new frames; the clips' frames are fetched once per clip
// (GET /api/clip/<name>) and the result is put together here: A's frames 0..a_end, the new
// frames, then B's frames from b_start with the alignment applied to one joint.
const clipFrames = new Map();   // name -> Promise of {frames, quat: [Float32Array per bone], pos: Map}

function framesOf(payload) {
  // Tracks as typed arrays: quat[j] (4 per frame, x y z w), pos.get(j) (3 per frame) for moving joints.
  const index = new Map(info.skeleton.bones.map((b, j) => [b, j]));
  const quat = new Array(info.skeleton.bones.length), pos = new Map();
  for (const t of payload.tracks) {
    const dot = t.name.lastIndexOf('.');
    const j = index.get(t.name.slice(0, dot));
    if (t.type === 'quaternion') quat[j] = Float32Array.from(t.values);
    else pos.set(j, Float32Array.from(t.values));
  }
  return { frames: payload.frames, quat, pos };
}

function clipFramesOf(name) {
  if (!clipFrames.has(name)) {
    const p = fetch(`/api/clip/${encodeURIComponent(name)}`).then(async (r) => {
      if (!r.ok) {
        let msg = `HTTP ${r.status}`;
        try { msg = (await r.json()).error || msg; } catch { /* not JSON */ }
        throw new Error(`clip ${name}: ${msg}`);
      }
      return framesOf(await r.json());
    });
    p.catch(() => clipFrames.delete(name));   // a failed fetch is tried again next time
    clipFrames.set(name, p);
  }
  return clipFrames.get(name);
}

function assemble(res, ca, cb) {
  // The whole result as tracks (same shape as a clip payload, typed arrays for values).
  const skel = info.skeleton, J = skel.bones.length;
  const nb = res.inbetween.frames, na = res.params.a_end + 1, b0 = res.params.b_start;
  const n = res.frames, nB = n - na - nb;
  const mid = framesOf(res.inbetween);
  const al = res.alignment, top = skel.bones.indexOf(al.joint);
  const turn = new THREE.Quaternion().setFromAxisAngle(new THREE.Vector3().setComponent(al.up, 1), al.turn);
  const shift = new THREE.Vector3().fromArray(al.shift);
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

// ---- state -------------------------------------------------------------------------------
let info = null;          // /api/clips
let main = null, cmp = null, ghost = null, trail = null;
let result = null, cmpResult = null;
let time = 0, playing = false, speed = 1;
let needsRender = true;
let pendingTiming = null;  // steps of the update waiting to be drawn (see studio.timings)
const orange = new THREE.Color(COLOR.t);
const tmp = new THREE.Vector3();

const ui = {
  clipA: $('clip-a'), clipB: $('clip-b'), aEnd: $('a-end'), bStart: $('b-start'), method: $('method'),
  alpha: $('alpha'), length: $('length'), keyAt: $('key-at'), align: $('align'), footLock: $('foot-lock'),
  compare: $('compare'),
  ghost: $('ghost'), follow: $('follow'), speed: $('speed'), plotJoint: $('plot-joint'),
};

function clipInfo(name) { return info.clips.find((c) => c.name === name); }

function currentParams() {
  return {
    a: ui.clipA.value, b: ui.clipB.value,
    a_end: Number(ui.aEnd.value), b_start: Number(ui.bStart.value),
    length: Number(ui.length.value), key_at: Number(ui.keyAt.value),
    alpha: Number(ui.alpha.value), method: ui.method.value, align: ui.align.checked,
    foot_lock: ui.footLock.checked,
  };
}

function showOutputs() {
  const p = currentParams();
  $('a-end-out').textContent = `${p.a_end} / ${clipInfo(p.a).frames - 1}`;
  $('b-start-out').textContent = `${p.b_start} / ${clipInfo(p.b).frames - 1}`;
  $('alpha-out').textContent = p.alpha.toFixed(2);
  $('length-out').textContent = `${p.length} frames`;
  $('key-at-out').textContent = `${p.key_at} of ${p.length}`;
  const keyed = info.keyed.includes(p.method);
  ui.alpha.disabled = !keyed;
  ui.keyAt.disabled = !keyed;
}

// ---- requests: one in flight, the latest parameters next, stale answers dropped ------------
let inflight = false, dirty = false, seq = 0, applied = 0, pendingInput = null, focus = 'init';

function request(kind) {
  if (pendingInput === null) pendingInput = performance.now();
  focus = kind;
  showOutputs();
  if (inflight) { dirty = true; return; }
  send();
}

let shownCmp = { key: null, res: null };   // the comparison on screen and its inputs

function resultKey(params, method) {
  // What a result depends on: every parameter, less alpha and the key position for a keyless method.
  const keyed = info.keyed.includes(method);
  return JSON.stringify({ ...params, method, alpha: keyed ? params.alpha : null, key_at: keyed ? params.key_at : null });
}

async function postJSON(url, body) {
  const r = await fetch(url, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
  let data = null;
  try { data = await r.json(); } catch { data = { error: `HTTP ${r.status}` }; }
  if (!r.ok) { const e = new Error(data.error || `HTTP ${r.status}`); e.status = r.status; throw e; }
  return data;
}

async function send() {
  inflight = true;
  dirty = false;
  const mine = ++seq;
  const params = currentParams();
  const started = pendingInput;
  const kind = focus;
  pendingInput = null;
  const sentAt = performance.now();
  const cmpMethod = ui.compare.value && ui.compare.value !== params.method ? ui.compare.value : null;
  studio.requests++;
  // The comparison is asked for again only when its own inputs changed (a method without a key
  // ignores alpha and the key position).
  const cmpKey = cmpMethod ? resultKey(params, cmpMethod) : null;
  const cmpKept = cmpKey !== null && shownCmp.key === cmpKey ? shownCmp.res : null;
  try {
    const clips = Promise.all([clipFramesOf(params.a), clipFramesOf(params.b)]);
    const jobs = [postJSON('/api/transition', params), clips];
    if (cmpMethod && !cmpKept) jobs.push(postJSON('/api/transition', { ...params, method: cmpMethod }).catch((e) => e));
    const [answer, [ca, cb], cmpAnswer] = await Promise.all(jobs);
    if (mine < applied) return;   // an answer to older parameters
    applied = mine;
    const receivedAt = performance.now();
    const res = assemble(answer, ca, cb);
    const cmpError = cmpAnswer instanceof Error ? cmpAnswer : null;
    let cres = cmpKept;
    if (cmpAnswer && !cmpError) cres = assemble(cmpAnswer, ca, cb);
    shownCmp = { key: cres ? cmpKey : null, res: cres };
    apply(res, cres, params, kind);
    if (started !== null) {
      pendingTiming = { input: started, sent: sentAt, received: receivedAt, applied: performance.now() };
    }
    if (cmpError) note(`Compare (${methodName(cmpMethod)}): ${cmpError.message}`, 'info');
    else hideMessage();
  } catch (e) {
    if (e.status === 503) {
      note(e.message.replace(/^method: /, ''), 'info');
      waitForMap = true;
    } else {
      note(e.message, 'error');
      studio.errors.push(e.message);
    }
  } finally {
    inflight = false;
    if (dirty) send();
  }
}

function apply(res, cres, params, kind) {
  result = res;
  main.setClip(makeClip(res, `${res.a} → ${res.b} (${res.method})`));
  if (cres !== cmpResult) cmp.setClip(cres ? makeClip(cres, `${cres.a} → ${cres.b} (${cres.method})`) : null);
  cmpResult = cres;
  cmp.group.visible = !!cres;
  if (res.key) {
    ghost.setClip(main.clip);
    ghost.setTime(res.key.frame / res.fps);
  } else {
    ghost.setClip(null);
  }
  ghost.group.visible = !!res.key && ui.ghost.checked;
  trail.update(res, info.skeleton);

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
  if (studio.map && studio.map.state !== 'training' && studio.map.state !== 'loading') studio.state = 'ready';

  // Put the playhead where the edit shows, unless playing.
  const [t0, t1] = res.transition;
  if (!playing) {
    let f = Math.round(time * res.fps);
    if (kind === 'a_end') f = res.seams[0];
    else if (kind === 'b_start') f = res.seams[1];
    else if (kind !== 'scrub' && (f < t0 - 1 || f > t1 + 1 || kind === 'init' || kind === 'clip')) {
      f = t0 + Math.floor(((res.key ? res.key.index : Math.ceil(params.length / 2)) - 1) / 2);
    }
    time = clamp(f, 0, res.frames - 1) / res.fps;
  } else {
    time = Math.min(time, (res.frames - 1) / res.fps);
  }
  $('legend-main').textContent = methodName(res.method);
  $('legend-cmp').textContent = cres ? methodName(cres.method) : '';
  $('legend-cmp-item').hidden = !cres;
  $('legend-ghost-item').hidden = !res.key || !ui.ghost.checked;
  $('plot-main').textContent = methodName(res.method);
  $('plot-cmp').textContent = cres ? methodName(cres.method) : '';
  $('plot-cmp-item').hidden = !cres;
  const d = (res.frames / res.fps).toFixed(2);
  $('result-info').textContent = `${res.frames} frames (${d} s): A 0–${res.seams[0]}, `
    + `${params.length} new frames, B from its frame ${params.b_start}`
    + (res.key ? ` · key neurons ${res.key.neurons.join(', ')}` : '');
  showRetrieval(res);
  drawTimeline();
  drawPlot();
  needsRender = true;
}

let waitForMap = false;

// Which real motion a retrieval transition replayed, and how well it matched (one line per part).
function showRetrieval(res) {
  const el = $('retrieval-info');
  const r = res.retrieval;
  el.hidden = r === undefined;
  if (r === undefined) return;
  el.textContent = !r ? 'No library motion fits: interpolated (fallback).'
    : Object.entries(r.parts).map(([part, p]) => `${part}: ${p.clip} ${p.frames[0]}–${p.frames[1]}`
      + (p.reversed ? ' (played backwards)' : '')
      + ` · match ${p.distance.toFixed(1)}° · confidence ${Math.round(100 * p.confidence)}%`).join('\n');
}

// ---- playback ----------------------------------------------------------------------------
function setPlaying(on) {
  playing = on && !!result;
  $('play-icon').innerHTML = playing ? '<path d="M7 5h4v14H7zM13 5h4v14h-4z"/>' : '<path d="M8 5v14l11-7z"/>';
  $('play').setAttribute('aria-label', playing ? 'Pause' : 'Play');
  needsRender = true;
}

function setFrame(f) {
  if (!result) return;
  time = clamp(f, 0, result.frames - 1) / result.fps;
  needsRender = true;
}

function currentFrame() {
  return result ? clamp(Math.round(time * result.fps), 0, result.frames - 1) : 0;
}

// Resolution: in the lite profile, or when a full-resolution frame takes over SLOW_FRAME_MS (a
// weak GPU), frames drawn while something changes use half the pixels, and the view is redrawn
// at full resolution once things have been still for SETTLE_MS.
const quality = { scale: 1, slow: !FULL, lastChange: 0, refined: true, renderedAt: null, renderedScale: 1 };
const SLOW_FRAME_MS = 40, SETTLE_MS = 800;

function setScale(s) {
  if (s === quality.scale) return;
  quality.scale = s;
  sizeView();   // the caller draws next
}

let last = performance.now();
function tick(now) {
  requestAnimationFrame(tick);
  const dt = Math.min((now - last) / 1000, 0.1);
  last = now;
  if (quality.renderedAt !== null) {   // the previous frame's cost shows in this callback's delay
    if (quality.renderedScale === 1) quality.slow = !FULL || now - quality.renderedAt > SLOW_FRAME_MS;
    quality.renderedAt = null;
  }
  if (playing && result) {
    const dur = (result.frames - 1) / result.fps;
    time += dt * speed;
    if (time > dur) time = 0;
    needsRender = true;
  }
  if (!main) return;
  if (needsRender) redraw(now);
  else if (!quality.refined && now - quality.lastChange > SETTLE_MS) render(1);
}

// Draw after a change (at half resolution in the lite profile or when full frames are slow).
function redraw(now) {
  needsRender = false;
  quality.lastChange = now;
  render(quality.slow ? 0.5 : 1);
}

function render(scale) {
  setScale(scale);
  quality.refined = scale === 1;
  draw();
  quality.renderedAt = performance.now();
  quality.renderedScale = scale;
  studio.renderScale = scale;
}

function draw() {
  const started = performance.now();
  if (result) {
    main.setTime(time);
    if (cmpResult) cmp.setTime(time);
    const f = time * result.fps;
    const [t0, t1] = result.transition;
    const dist = f < t0 ? t0 - f : f > t1 ? f - t1 : 0;
    main.tint(orange, 0.8 * clamp(1 - dist / 3, 0, 1));
    if (ui.follow.checked) follow();
  }
  for (const ch of [main, cmp]) {
    if (!ch.blob) continue;
    ch.blob.visible = ch.group.visible && ch.clip !== null;
    if (ch.blob.visible) ch.blob.position.copy(ch.rootWorld(tmp)).setY(0.002);
  }
  sun.target.position.copy(controls.target).setY(0);
  sun.position.copy(sun.target.position).add(tmp.set(2.5, 5, 3));
  drawing = true;
  controls.update();
  drawing = false;
  renderer.render(scene, camera);
  studio.renders++;
  studio.frame = currentFrame();
  studio.time = time;
  const rendered = performance.now();
  drawHud();
  drawTimeline();
  drawPlot();
  if (pendingTiming !== null) {
    // The pose is submitted; the update counts as shown at the next frame (after the browser
    // has painted this one): requestAnimationFrame, then a task.
    const t = pendingTiming;
    pendingTiming = null;
    t.frame = started;
    t.rendered = rendered;
    t.drawn = performance.now();
    requestAnimationFrame(() => {
      const ch = new MessageChannel();
      ch.port1.onmessage = () => {
        t.painted = performance.now();
        studio.timings.push(Object.fromEntries(Object.entries(t).map(([k, v]) => [k, v - t.input])));
        studio.latencies.push(t.painted - t.input);
        for (const w of latencyWaiters.splice(0)) w();
      };
      ch.port2.postMessage(null);
    });
  }
}

function follow() {
  main.rootWorld(tmp);
  const dx = tmp.x - controls.target.x, dz = tmp.z - controls.target.z;
  controls.target.x += dx; controls.target.z += dz;
  camera.position.x += dx; camera.position.z += dz;
}

function drawHud() {
  if (!result) { $('hud').textContent = ''; return; }
  const f = currentFrame();
  const [t0, t1] = result.transition;
  let seg, src;
  if (f < t0) { seg = '<span class="seg-a">Clip A</span>'; src = `${result.a} #${f}`; }
  else if (f <= t1) {
    const k = f - t0 + 1;
    seg = `<span class="seg-t">Transition ${k}/${t1 - t0 + 1}</span>`
      + (result.key && f === result.key.frame ? ' · <b>key</b>' : '');
    src = methodName(result.method);
  } else {
    seg = '<span class="seg-b">Clip B</span>';
    src = `${result.b} #${result.source.b[0] + f - t1 - 1}`;
  }
  $('hud').innerHTML = `<b>Frame ${f}</b> / ${result.frames - 1}<br>${seg}<br><span class="muted">${escapeHtml(src)}</span>`;
  $('frame-out').textContent = `${f} / ${result.frames - 1}`;
}

function escapeHtml(s) {
  return String(s).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' }[c]));
}

// ---- timeline (scrub bar) -----------------------------------------------------------------
const timeline = $('timeline');

function fitCanvas(c) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(c.clientWidth * dpr)), h = Math.max(1, Math.round(c.clientHeight * dpr));
  if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
  const ctx = c.getContext('2d');
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  return [ctx, c.clientWidth, c.clientHeight];
}

const PAD = 10;
function drawTimeline() {
  const [ctx, w, h] = fitCanvas(timeline);
  ctx.clearRect(0, 0, w, h);
  const y = h / 2 - 5, bh = 10;
  roundRect(ctx, PAD, y, w - 2 * PAD, bh, 5, '#0f141b');
  if (!result) return;
  const n = result.frames, x = (f) => PAD + (w - 2 * PAD) * (f / Math.max(n - 1, 1));
  const [t0, t1] = result.transition;
  ctx.globalAlpha = 0.85;
  roundRect(ctx, x(0), y, x(t0 - 0.5) - x(0), bh, 5, COLOR.a);
  roundRect(ctx, x(t1 + 0.5), y, x(n - 1) - x(t1 + 0.5), bh, 5, COLOR.b);
  ctx.globalAlpha = 1;
  ctx.fillStyle = COLOR.t;
  ctx.shadowColor = COLOR.t; ctx.shadowBlur = 8;
  ctx.fillRect(x(t0 - 0.5), y - 3, Math.max(x(t1 + 0.5) - x(t0 - 0.5), 2), bh + 6);
  ctx.shadowBlur = 0;
  if (result.key) {
    const kx = x(result.key.frame), ky = y + bh / 2;
    ctx.fillStyle = COLOR.ghost; ctx.strokeStyle = '#0d1117'; ctx.lineWidth = 1.5;
    ctx.beginPath(); ctx.moveTo(kx, ky - 8); ctx.lineTo(kx + 6, ky); ctx.lineTo(kx, ky + 8); ctx.lineTo(kx - 6, ky); ctx.closePath();
    ctx.fill(); ctx.stroke();
  }
  const px = x(time * result.fps);
  ctx.fillStyle = '#ffffff';
  ctx.fillRect(px - 1, 3, 2, y + bh + 3 - 3);
  ctx.beginPath(); ctx.arc(px, 5, 4, 0, Math.PI * 2); ctx.fill();
  ctx.fillStyle = COLOR.muted; ctx.font = '10px system-ui, sans-serif'; ctx.textBaseline = 'bottom';
  ctx.textAlign = 'left'; ctx.fillText('0', PAD, h);
  ctx.textAlign = 'right'; ctx.fillText(String(n - 1), w - PAD, h);
  ctx.textAlign = 'center'; ctx.fillStyle = COLOR.t; ctx.fillText(`${t0}–${t1}`, (x(t0) + x(t1)) / 2, h);
}

function roundRect(ctx, x, y, w, h, r, fill) {
  if (w <= 0) return;
  r = Math.min(r, w / 2, h / 2);
  ctx.beginPath();
  ctx.roundRect(x, y, w, h, r);
  ctx.fillStyle = fill;
  ctx.fill();
}

function scrubTo(ev) {
  if (!result) return;
  const r = timeline.getBoundingClientRect();
  const u = clamp((ev.clientX - r.left - PAD) / (r.width - 2 * PAD), 0, 1);
  setFrame(Math.round(u * (result.frames - 1)));
}
timeline.addEventListener('pointerdown', (ev) => {
  timeline.setPointerCapture(ev.pointerId);
  setPlaying(false);
  scrubTo(ev);
});
timeline.addEventListener('pointermove', (ev) => { if (timeline.hasPointerCapture(ev.pointerId)) scrubTo(ev); });

// ---- joint angle plot --------------------------------------------------------------------
const plot = $('plot');

function angleSeries(res, j) {
  const v = res.tracks[j].values, n = res.frames, out = new Float32Array(n);
  for (let f = 0; f < n; f++) out[f] = 2 * Math.acos(Math.min(1, Math.abs(v[4 * f + 3]))) * 180 / Math.PI;
  return out;
}

let plotCache = { key: null };
function drawPlot() {
  const [ctx, w, h] = fitCanvas(plot);
  ctx.clearRect(0, 0, w, h);
  if (!result) return;
  const j = Number(ui.plotJoint.value) || 0;
  const cacheKey = `${applied}:${j}`;
  if (plotCache.key !== cacheKey) {
    plotCache = { key: cacheKey, main: angleSeries(result, j), cmp: cmpResult ? angleSeries(cmpResult, j) : null };
  }
  const { main: s, cmp: c } = plotCache;
  let lo = Infinity, hi = -Infinity;
  for (const arr of [s, c]) if (arr) for (const a of arr) { lo = Math.min(lo, a); hi = Math.max(hi, a); }
  const span = Math.max(hi - lo, 5);
  lo -= span * 0.1; hi += span * 0.1;
  const L = 38, R = 10, T = 8, B = 18;
  const n = result.frames;
  const x = (f) => L + (w - L - R) * (f / Math.max(n - 1, 1));
  const y = (a) => T + (h - T - B) * (1 - (a - lo) / (hi - lo));
  const [t0, t1] = result.transition;
  ctx.fillStyle = 'rgba(255, 138, 61, 0.13)';
  ctx.fillRect(x(t0 - 0.5), T, x(t1 + 0.5) - x(t0 - 0.5), h - T - B);
  ctx.strokeStyle = COLOR.line; ctx.lineWidth = 1; ctx.fillStyle = COLOR.muted;
  ctx.font = '10px system-ui, sans-serif'; ctx.textAlign = 'right'; ctx.textBaseline = 'middle';
  for (let i = 0; i <= 3; i++) {
    const a = lo + (hi - lo) * i / 3, yy = Math.round(y(a)) + 0.5;
    ctx.beginPath(); ctx.moveTo(L, yy); ctx.lineTo(w - R, yy); ctx.stroke();
    ctx.fillText(`${a.toFixed(0)}°`, L - 6, yy);
  }
  ctx.textAlign = 'center'; ctx.textBaseline = 'top';
  for (const f of [0, t0, t1, n - 1]) ctx.fillText(String(f), x(f), h - B + 4);
  if (result.key) {
    ctx.strokeStyle = COLOR.ghost; ctx.setLineDash([4, 3]);
    ctx.beginPath(); ctx.moveTo(x(result.key.frame), T); ctx.lineTo(x(result.key.frame), h - B); ctx.stroke();
    ctx.setLineDash([]);
  }
  const line = (arr, color, width) => {
    ctx.strokeStyle = color; ctx.lineWidth = width; ctx.lineJoin = 'round';
    ctx.beginPath();
    for (let f = 0; f < arr.length; f++) { if (f) ctx.lineTo(x(f), y(arr[f])); else ctx.moveTo(x(f), y(arr[f])); }
    ctx.stroke();
  };
  if (c) line(c, COLOR.cmp, 1.6);
  line(s, COLOR.text, 1.6);
  ctx.strokeStyle = COLOR.t; ctx.lineWidth = 2.2;
  ctx.beginPath();
  for (let f = Math.max(t0 - 1, 0); f <= Math.min(t1 + 1, n - 1); f++) {
    if (f === Math.max(t0 - 1, 0)) ctx.moveTo(x(f), y(s[f])); else ctx.lineTo(x(f), y(s[f]));
  }
  ctx.stroke();
  const px = x(time * result.fps);
  ctx.strokeStyle = 'rgba(255,255,255,0.7)'; ctx.lineWidth = 1;
  ctx.beginPath(); ctx.moveTo(px, T); ctx.lineTo(px, h - B); ctx.stroke();
}

// ---- messages ----------------------------------------------------------------------------
let messageTimer = null;
function note(text, kind = 'error') {
  const m = $('message');
  m.textContent = text;
  m.className = `message ${kind === 'info' ? 'info' : ''}`;
  m.hidden = false;
  clearTimeout(messageTimer);
  if (kind !== 'info') messageTimer = setTimeout(() => { m.hidden = true; }, 6000);
}
function hideMessage() { $('message').hidden = true; }

// ---- map status --------------------------------------------------------------------------
async function pollStatus() {
  let s;
  try {
    s = await (await fetch('/api/status')).json();
  } catch (e) {
    setTimeout(pollStatus, 1000);
    return;
  }
  studio.map = s;
  const pill = $('map-status');
  pill.className = `pill ${s.state}`;
  if (s.state === 'training' || s.state === 'loading') {
    $('map-text').textContent = `Training posture map · ${Math.round(100 * s.progress)}% · ${s.neurons} neurons`;
    $('map-bar').style.width = `${Math.round(100 * s.progress)}%`;
    if (studio.state !== 'error') studio.state = 'training';
    setTimeout(pollStatus, 400);
    return;
  }
  if (s.state === 'ready') {
    $('map-text').textContent = `Posture map ready · ${s.neurons.toLocaleString('en')} neurons`;
    if (result) studio.state = 'ready';
    if (waitForMap || !result) { waitForMap = false; request('init'); }
  } else {
    // No map (not trained, or training failed): the methods without a key still work.
    $('map-text').textContent = s.state === 'none' ? 'No posture map · keyless methods only' : 'Posture map failed';
    if (s.message) { pill.title = s.message; note(s.message, 'error'); }
    for (const sel of [ui.method, ui.compare]) {
      for (const o of sel.options) o.disabled = info.keyed.includes(o.value);
      if (info.keyed.includes(sel.value)) sel.value = sel === ui.method ? 'spline' : '';
    }
    if (result) studio.state = 'ready';
    if (waitForMap || !result) { waitForMap = false; request('init'); }
  }
}

// ---- setup -------------------------------------------------------------------------------
function fillSelect(sel, items, value) {
  sel.replaceChildren(...items.map(([v, label]) => {
    const o = document.createElement('option');
    o.value = v; o.textContent = label;
    return o;
  }));
  if (value !== undefined) sel.value = value;
}

function pick(names, patterns, fallback) {
  for (const re of patterns) { const n = names.find((x) => re.test(x)); if (n) return n; }
  return fallback;
}

function resize() {
  sizeView();
  needsRender = true;
}

function sizeView() {
  const vp = $('viewport');
  const w = vp.clientWidth, h = vp.clientHeight;
  renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2) * quality.scale);
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(h, 1);
  camera.updateProjectionMatrix();
}

async function init() {
  const r = await fetch('/api/clips');
  if (!r.ok) throw new Error(`cannot list the clips (HTTP ${r.status})`);
  info = await r.json();
  const skel = info.skeleton;
  const names = info.clips.map((c) => c.name);
  $('clip-count').textContent = `${names.length} clips · ${skel.names.length} joints`;

  // Clip units to metres, clip up axis to three.js's +Y.
  world.scale.setScalar(1.7 / (skel.height || 1.7));
  if (skel.up === 2) world.rotation.x = -Math.PI / 2;
  else if (skel.up === 0) world.rotation.z = Math.PI / 2;

  main = new Character(skel, { color: COLOR.main });
  cmp = new Character(skel, { color: COLOR.cmp, thickness: 0.82, emissive: 0x0a3040 });
  ghost = new Character(skel, { color: COLOR.ghost, opacity: 0.42, thickness: 1.04, shadows: false, emissive: 0x6a3fc0 });
  ghost.group.renderOrder = 2;
  trail = new Trail();
  world.add(main.group, cmp.group, ghost.group, trail.mesh);
  cmp.group.visible = false;
  ghost.group.visible = false;
  if (!FULL) { main.blob = blobShadow(); cmp.blob = blobShadow(); }

  // Labels without the prefix every clip name shares (e.g. "dataset-1_").
  let prefix = names.length > 1 ? names.reduce((p, n) => { while (!n.startsWith(p)) p = p.slice(0, -1); return p; }) : '';
  prefix = prefix.slice(0, Math.max(prefix.search(/[_\-. ][^_\-. ]*$/) + 1, 0));
  const clipItems = info.clips.map((c) => [c.name, `${c.name.slice(prefix.length)}  (${c.frames} frames)`]);
  const a = pick(names, [/_walk_normal/, /^walk/, /walk/], names[0]);
  const b = pick(names.filter((n) => n !== a), [/_run_normal/, /^run/, /run/], names[1 % names.length]);
  fillSelect(ui.clipA, clipItems, a);
  fillSelect(ui.clipB, clipItems, b);
  fillSelect(ui.method, info.methods.map((m) => [m, methodName(m)]), info.default_method);
  fillSelect(ui.compare, [['', 'None'], ...info.methods.map((m) => [m, methodName(m)])],
    info.methods.includes('spline') ? 'spline' : '');
  fillSelect(ui.plotJoint, skel.names.map((n, j) => [String(j), n]),
    String(Math.max(0, skel.names.findIndex((n) => /lowerleg_l|leftleg|leftknee|l_?knee|lknee/i.test(n)))));
  ui.length.max = String(Math.min(info.limits.length[1], 120));
  ui.length.value = String(info.defaults.length);
  setClipRanges(true, true);

  ui.clipA.addEventListener('change', () => { setClipRanges(true, false); request('clip'); });
  ui.clipB.addEventListener('change', () => { setClipRanges(false, true); request('clip'); });
  ui.aEnd.addEventListener('input', () => request('a_end'));
  ui.bStart.addEventListener('input', () => request('b_start'));
  ui.alpha.addEventListener('input', () => request('alpha'));
  ui.keyAt.addEventListener('input', () => request('key_at'));
  ui.length.addEventListener('input', () => {
    const len = Number(ui.length.value), old = Number(ui.keyAt.max) || len;
    const k = clamp(Math.round(Number(ui.keyAt.value) * len / old), 1, len);
    ui.keyAt.max = String(len);
    ui.keyAt.value = String(k);
    request('length');
  });
  ui.method.addEventListener('change', () => request('method'));
  ui.align.addEventListener('change', () => request('align'));
  ui.footLock.addEventListener('change', () => request('foot_lock'));
  ui.compare.addEventListener('change', () => request('compare'));
  ui.ghost.addEventListener('change', () => {
    ghost.group.visible = !!(result && result.key) && ui.ghost.checked;
    $('legend-ghost-item').hidden = !ghost.group.visible;
    needsRender = true;
  });
  ui.follow.addEventListener('change', () => { needsRender = true; });
  ui.speed.addEventListener('change', () => { speed = Number(ui.speed.value); });
  ui.plotJoint.addEventListener('change', () => drawPlot());
  $('play').addEventListener('click', () => setPlaying(!playing));
  $('export').addEventListener('click', exportResult);
  showOutputs();
  pollStatus();
}

function setClipRanges(resetA, resetB) {
  const a = clipInfo(ui.clipA.value), b = clipInfo(ui.clipB.value);
  ui.aEnd.max = String(a.frames - 1);
  if (resetA || Number(ui.aEnd.value) > a.frames - 1) ui.aEnd.value = String(a.frames - 1);
  ui.bStart.max = String(b.frames - 1);
  if (resetB || Number(ui.bStart.value) > b.frames - 1) ui.bStart.value = '0';
  ui.keyAt.max = ui.length.value;
  if (resetA && resetB) ui.keyAt.value = String(Math.max(1, Math.floor(Number(ui.length.value) / 2)));
}

async function exportResult() {
  const btn = $('export');
  const format = $('export-format').value;
  btn.disabled = true;
  try {
    const r = await fetch('/api/export', {
      method: 'POST', headers: { 'Content-Type': 'application/json' },
      body: JSON.stringify({ ...currentParams(), format }),
    });
    if (!r.ok) {
      let msg = `HTTP ${r.status}`;
      try { msg = (await r.json()).error || msg; } catch { /* not JSON */ }
      throw new Error(msg);
    }
    const name = (/filename="([^"]+)"/.exec(r.headers.get('Content-Disposition') || '') || [])[1] || `transition.${format}`;
    const url = URL.createObjectURL(await r.blob());
    const link = document.createElement('a');
    link.href = url;
    link.download = name;
    document.body.append(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(url), 30000);
  } catch (e) {
    note(`Export failed: ${e.message}`);
    studio.errors.push(e.message);
  } finally {
    btn.disabled = false;
  }
}

window.addEventListener('keydown', (ev) => {
  const t = ev.target;
  if (t instanceof HTMLSelectElement || t instanceof HTMLButtonElement
    || (t instanceof HTMLInputElement && t.type !== 'checkbox' && t.type !== 'range')) return;
  if (ev.code === 'Space') { ev.preventDefault(); setPlaying(!playing); }
  else if ((ev.code === 'ArrowLeft' || ev.code === 'ArrowRight') && !(t instanceof HTMLInputElement)) {
    ev.preventDefault();
    setPlaying(false);
    setFrame(currentFrame() + (ev.code === 'ArrowRight' ? 1 : -1));
  }
});

let drawing = false;
controls.addEventListener('change', () => { if (!drawing) needsRender = true; });
new ResizeObserver(() => { resize(); drawTimeline(); drawPlot(); }).observe(document.body);
resize();
requestAnimationFrame(tick);
init().catch((e) => {
  studio.state = 'error';
  studio.errors.push(String(e.message || e));
  note(`The studio could not start: ${e.message || e}`);
  console.error(e);
});
