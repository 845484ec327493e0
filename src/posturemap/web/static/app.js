// posturemap transition studio: asks the local server for transitions as the controls move and
// plays them with three.js (Bone / Skeleton, AnimationClip with <bone>.quaternion and
// <bone>.position tracks, AnimationMixer). No CDN: three.js is vendored next to this file.
//
// This entry wires the modules in js/ (docs/studio-page.md): the DOM events to their
// handlers, the test hook's actions, and the start. Everything that changes is in js/state.js.
import * as THREE from 'three';
import { createCharacters } from './js/character.js';
import { $ } from './js/common.js';
import { drawPlot, fillControls, fitKeyAt, note, setClipRanges, showOutputs, ui } from './js/panels.js';
import { currentFrame, drawTimeline, scrubTo, setFrame, setPlaying, tick, timeline } from './js/playback.js';
import { exportResult, fetchClips, pollStatus, request } from './js/requests.js';
import { controls, fitWorld, resize, scene, setView, world } from './js/scene.js';
import { state } from './js/state.js';
import { setPhase, studio } from './js/studio.js';

// ---- the test hook's actions (window.__studio, js/studio.js) -------------------------------
Object.assign(studio, {
  setFrame: (f) => { setFrame(f); },
  // The main character's joint positions at frame f as drawn, in the clips' space and unit.
  jointPositions: (f) => {
    setFrame(f);
    state.main.setTime(state.time);
    scene.updateMatrixWorld(true);
    return state.main.bones.map((b) => world.worldToLocal(b.getWorldPosition(new THREE.Vector3())).toArray());
  },
  play: (on) => setPlaying(on),
  // Camera around its target: azimuth from +Z and elevation in degrees, distance in metres.
  setView,
});

// ---- events --------------------------------------------------------------------------------
timeline.addEventListener('pointerdown', (ev) => {
  timeline.setPointerCapture(ev.pointerId);
  setPlaying(false);
  scrubTo(ev);
});
timeline.addEventListener('pointermove', (ev) => { if (timeline.hasPointerCapture(ev.pointerId)) scrubTo(ev); });

// The controls, once they hold the served clips and methods.
function listen() {
  ui.clipA.addEventListener('change', () => { setClipRanges(true, false); request('clip'); });
  ui.clipB.addEventListener('change', () => { setClipRanges(false, true); request('clip'); });
  ui.aEnd.addEventListener('input', () => request('a_end'));
  ui.bStart.addEventListener('input', () => request('b_start'));
  ui.alpha.addEventListener('input', () => request('alpha'));
  ui.keyAt.addEventListener('input', () => request('key_at'));
  ui.length.addEventListener('input', () => { fitKeyAt(); request('length'); });
  ui.method.addEventListener('change', () => request('method'));
  ui.align.addEventListener('change', () => request('align'));
  ui.footLock.addEventListener('change', () => request('foot_lock'));
  ui.compare.addEventListener('change', () => request('compare'));
  ui.ghost.addEventListener('change', () => {
    state.ghost.group.visible = !!(state.result && state.result.key) && ui.ghost.checked;
    $('legend-ghost-item').hidden = !state.ghost.group.visible;
    state.needsRender = true;
  });
  ui.follow.addEventListener('change', () => { state.needsRender = true; });
  ui.speed.addEventListener('change', () => { state.speed = Number(ui.speed.value); });
  ui.plotJoint.addEventListener('change', () => drawPlot());
  $('play').addEventListener('click', () => setPlaying(!state.playing));
  $('export').addEventListener('click', exportResult);
}

window.addEventListener('keydown', (ev) => {
  const t = ev.target;
  if (t instanceof HTMLSelectElement || t instanceof HTMLButtonElement
    || (t instanceof HTMLInputElement && t.type !== 'checkbox' && t.type !== 'range')) return;
  if (ev.code === 'Space') { ev.preventDefault(); setPlaying(!state.playing); }
  else if ((ev.code === 'ArrowLeft' || ev.code === 'ArrowRight') && !(t instanceof HTMLInputElement)) {
    ev.preventDefault();
    setPlaying(false);
    setFrame(currentFrame() + (ev.code === 'ArrowRight' ? 1 : -1));
  }
});

controls.addEventListener('change', () => { if (!state.drawing) state.needsRender = true; });
new ResizeObserver(() => { resize(); drawTimeline(); drawPlot(); }).observe(document.body);

// ---- start ---------------------------------------------------------------------------------
async function init() {
  state.info = await fetchClips();
  fitWorld(state.info.skeleton);
  Object.assign(state, createCharacters(state.info.skeleton));
  fillControls(state.info);
  listen();
  showOutputs();
  pollStatus();
}

resize();
requestAnimationFrame(tick);
init().catch((e) => {
  setPhase('error');
  studio.errors.push(String(e.message || e));
  note(`The studio could not start: ${e.message || e}`);
  console.error(e);
});
