// The characters: a three.js skeleton of the served joints drawn as capsules (Character; the
// result, the comparison and the key posture's ghost are three of them), the root's path on the
// ground (Trail), and the AnimationClip a result's tracks make.
import * as THREE from 'three';
import { COLOR, clamp } from './common.js';
import { FULL, blobShadow, world } from './scene.js';

export class Character {
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

  // The named bones turned to these local rotations (x, y, z, w), over the clip's pose at its time:
  // the ghost shows the key posture itself, not the result's frame (which the foot lock may change).
  setRotations(names, quaternions) {
    names.forEach((name, i) => {
      const j = this.skel.bones.indexOf(name);
      if (j >= 0) this.bones[j].quaternion.fromArray(quaternions[i]);
    });
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
export class Trail {
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

export function makeClip(res, name) {
  const times = Float32Array.from(res.times);
  const tracks = res.tracks.map((t) => (t.type === 'quaternion'
    ? new THREE.QuaternionKeyframeTrack(t.name, times, t.values)
    : new THREE.VectorKeyframeTrack(t.name, times, t.values)));
  return new THREE.AnimationClip(name, res.duration, tracks);
}

// The result's character, the comparison's (thinner, blue) and the key posture's ghost
// (translucent), with the trail, in the clip-space group; hidden until there is something to show.
export function createCharacters(skel) {
  const main = new Character(skel, { color: COLOR.main });
  const cmp = new Character(skel, { color: COLOR.cmp, thickness: 0.82, emissive: 0x0a3040 });
  const ghost = new Character(skel, { color: COLOR.ghost, opacity: 0.42, thickness: 1.04, shadows: false, emissive: 0x6a3fc0 });
  ghost.group.renderOrder = 2;
  const trail = new Trail();
  world.add(main.group, cmp.group, ghost.group, trail.mesh);
  cmp.group.visible = false;
  ghost.group.visible = false;
  if (!FULL) { main.blob = blobShadow(); cmp.blob = blobShadow(); }
  return { main, cmp, ghost, trail };
}
