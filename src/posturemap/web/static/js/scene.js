// The 3D view: renderer, camera and orbit controls, lights, ground, the group in clip space, and
// the render quality (profile and resolution). Made once, when the page loads.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { $, COLOR } from './common.js';
import { state } from './state.js';
import { studio } from './studio.js';

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
export const FULL = PROFILE === 'full';
studio.profile = PROFILE;
state.quality.slow = !FULL;

const canvas = $('view');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: FULL });
renderer.shadowMap.enabled = FULL;
renderer.shadowMap.type = THREE.PCFShadowMap;
renderer.toneMapping = THREE.ACESFilmicToneMapping;
renderer.toneMappingExposure = 1.05;

export const scene = new THREE.Scene();
scene.background = new THREE.Color(COLOR.bg);
scene.fog = new THREE.Fog(COLOR.bg, 7, 26);

export const camera = new THREE.PerspectiveCamera(38, 1, 0.05, 200);
camera.position.set(2.3, 1.45, 3.0);
export const controls = new OrbitControls(camera, canvas);
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
export function blobShadow() {
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
export const world = new THREE.Group();
scene.add(world);

// Clip units to metres, clip up axis to three.js's +Y.
export function fitWorld(skel) {
  world.scale.setScalar(1.7 / (skel.height || 1.7));
  if (skel.up === 2) world.rotation.x = -Math.PI / 2;
  else if (skel.up === 0) world.rotation.z = Math.PI / 2;
}

// Camera around its target: azimuth from +Z and elevation in degrees, distance in metres.
export function setView(azimuth, elevation, distance) {
  const a = THREE.MathUtils.degToRad(azimuth), e = THREE.MathUtils.degToRad(elevation);
  camera.position.copy(controls.target).add(new THREE.Vector3(
    distance * Math.cos(e) * Math.sin(a), distance * Math.sin(e), distance * Math.cos(e) * Math.cos(a)));
  controls.update();
  state.needsRender = true;
}

// The camera and its target move with the point p (world space) over the ground.
export function followPoint(p) {
  const dx = p.x - controls.target.x, dz = p.z - controls.target.z;
  controls.target.x += dx; controls.target.z += dz;
  camera.position.x += dx; camera.position.z += dz;
}

const sunOffset = new THREE.Vector3();   // scratch

// The sun (and its shadow camera) stays above the camera's target; then the controls update,
// without asking for another frame (state.drawing), and the scene is drawn.
export function renderScene() {
  sun.target.position.copy(controls.target).setY(0);
  sun.position.copy(sun.target.position).add(sunOffset.set(2.5, 5, 3));
  state.drawing = true;
  controls.update();
  state.drawing = false;
  renderer.render(scene, camera);
}

// -- resolution ------------------------------------------------------------------------------
// In the lite profile, or when a full-resolution frame takes over SLOW_FRAME_MS (a weak GPU),
// frames drawn while something changes use half the pixels, and the view is redrawn at full
// resolution once things have been still for SETTLE_MS.
const SLOW_FRAME_MS = 40, SETTLE_MS = 800;

function sizeView() {
  const vp = $('viewport');
  const w = vp.clientWidth, h = vp.clientHeight;
  renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2) * state.quality.scale);
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(h, 1);
  camera.updateProjectionMatrix();
}

export function resize() {
  sizeView();
  state.needsRender = true;
}

function setScale(s) {
  if (s === state.quality.scale) return;
  state.quality.scale = s;
  sizeView();   // the caller draws next
}

// At the start of an animation frame: the previous frame's cost shows in this callback's delay.
export function measureFrame(now) {
  const q = state.quality;
  if (q.renderedAt !== null) {
    if (q.renderedScale === 1) q.slow = !FULL || now - q.renderedAt > SLOW_FRAME_MS;
    q.renderedAt = null;
  }
}

// The scale to draw a change at (half resolution in the lite profile or when full frames are slow).
export function changeScale(now) {
  state.quality.lastChange = now;
  return state.quality.slow ? 0.5 : 1;
}

// Still for long enough after a reduced frame: time for one at full resolution.
export function settled(now) {
  return !state.quality.refined && now - state.quality.lastChange > SETTLE_MS;
}

// Draw a frame (draw() does the work) at a fraction of the full resolution.
export function renderAt(scale, draw) {
  setScale(scale);
  state.quality.refined = scale === 1;
  draw();
  state.quality.renderedAt = performance.now();
  state.quality.renderedScale = scale;
  studio.renderScale = scale;
}
