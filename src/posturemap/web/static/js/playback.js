// Playback: the playhead (state.time), play and pause, the timeline (scrub bar), the HUD, and
// the render loop: one requestAnimationFrame callback that advances the playhead and draws when
// something changed.
import * as THREE from 'three';
import { $, COLOR, clamp, escapeHtml, fitCanvas, methodName } from './common.js';
import { drawPlot, ui } from './panels.js';
import { changeScale, followPoint, measureFrame, renderAt, renderScene, settled } from './scene.js';
import { state } from './state.js';
import { studio, timePaint } from './studio.js';

const orange = new THREE.Color(COLOR.t);
const tmp = new THREE.Vector3();   // scratch

// ---- the playhead ------------------------------------------------------------------------
export function setPlaying(on) {
  state.playing = on && !!state.result;
  $('play-icon').innerHTML = state.playing ? '<path d="M7 5h4v14H7zM13 5h4v14h-4z"/>' : '<path d="M8 5v14l11-7z"/>';
  $('play').setAttribute('aria-label', state.playing ? 'Pause' : 'Play');
  state.needsRender = true;
}

export function setFrame(f) {
  if (!state.result) return;
  state.time = clamp(f, 0, state.result.frames - 1) / state.result.fps;
  state.needsRender = true;
}

export function currentFrame() {
  const { result } = state;
  return result ? clamp(Math.round(state.time * result.fps), 0, result.frames - 1) : 0;
}

// A new result: put the playhead where the edit shows (what `kind` of input changed it), unless playing.
export function placePlayhead(res, params, kind) {
  const [t0, t1] = res.transition;
  if (!state.playing) {
    let f = Math.round(state.time * res.fps);
    if (kind === 'a_end') f = res.seams[0];
    else if (kind === 'b_start') f = res.seams[1];
    else if (kind !== 'scrub' && (f < t0 - 1 || f > t1 + 1 || kind === 'init' || kind === 'clip')) {
      f = t0 + Math.floor(((res.key ? res.key.index : Math.ceil(params.length / 2)) - 1) / 2);
    }
    state.time = clamp(f, 0, res.frames - 1) / res.fps;
  } else {
    state.time = Math.min(state.time, (res.frames - 1) / res.fps);
  }
}

// ---- the render loop ---------------------------------------------------------------------
export function tick(now) {
  requestAnimationFrame(tick);
  const dt = Math.min((now - state.lastTick) / 1000, 0.1);
  state.lastTick = now;
  measureFrame(now);
  const { result } = state;
  if (state.playing && result) {
    const dur = (result.frames - 1) / result.fps;
    state.time += dt * state.speed;
    if (state.time > dur) state.time = 0;
    state.needsRender = true;
  }
  if (!state.main) return;
  if (state.needsRender) {   // a change: drawn now (at reduced resolution when frames are slow)
    state.needsRender = false;
    renderAt(changeScale(now), draw);
  } else if (settled(now)) {
    renderAt(1, draw);
  }
}

function draw() {
  const started = performance.now();
  const { main, cmp, result, cmpResult } = state;
  if (result) {
    main.setTime(state.time);
    if (cmpResult) cmp.setTime(state.time);
    const f = state.time * result.fps;
    const [t0, t1] = result.transition;
    const dist = f < t0 ? t0 - f : f > t1 ? f - t1 : 0;
    main.tint(orange, 0.8 * clamp(1 - dist / 3, 0, 1));
    if (ui.follow.checked) followPoint(main.rootWorld(tmp));
  }
  for (const ch of [main, cmp]) {
    if (!ch.blob) continue;
    ch.blob.visible = ch.group.visible && ch.clip !== null;
    if (ch.blob.visible) ch.blob.position.copy(ch.rootWorld(tmp)).setY(0.002);
  }
  renderScene();
  studio.renders++;
  studio.frame = currentFrame();
  studio.time = state.time;
  const rendered = performance.now();
  drawHud();
  drawTimeline();
  drawPlot();
  if (state.pendingTiming !== null) {
    const t = state.pendingTiming;
    state.pendingTiming = null;
    t.frame = started;
    t.rendered = rendered;
    t.drawn = performance.now();
    timePaint(t);
  }
}

function drawHud() {
  const { result } = state;
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

// ---- timeline (scrub bar) -----------------------------------------------------------------
export const timeline = $('timeline');
const PAD = 10;

export function drawTimeline() {
  const [ctx, w, h] = fitCanvas(timeline);
  ctx.clearRect(0, 0, w, h);
  const y = h / 2 - 5, bh = 10;
  roundRect(ctx, PAD, y, w - 2 * PAD, bh, 5, '#0f141b');
  const { result } = state;
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
  const px = x(state.time * result.fps);
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

// The playhead to the frame under the pointer (a pointer event over the timeline).
export function scrubTo(ev) {
  if (!state.result) return;
  const r = timeline.getBoundingClientRect();
  const u = clamp((ev.clientX - r.left - PAD) / (r.width - 2 * PAD), 0, 1);
  setFrame(Math.round(u * (state.result.frames - 1)));
}
