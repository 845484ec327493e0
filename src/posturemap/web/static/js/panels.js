// The panels around the 3D view: the controls (element references, the parameters they set,
// their read-outs, filling the selects), the result's labels and retrieval source, the map
// status pill, the joint angle plot and the message line.
import { $, COLOR, clamp, fitCanvas, methodName } from './common.js';
import { state } from './state.js';

// ---- controls ----------------------------------------------------------------------------
export const ui = {
  clipA: $('clip-a'), clipB: $('clip-b'), aEnd: $('a-end'), bStart: $('b-start'), method: $('method'),
  alpha: $('alpha'), length: $('length'), keyAt: $('key-at'), align: $('align'), footLock: $('foot-lock'),
  compare: $('compare'),
  ghost: $('ghost'), follow: $('follow'), speed: $('speed'), plotJoint: $('plot-joint'),
};

function clipInfo(name) { return state.info.clips.find((c) => c.name === name); }

export function currentParams() {
  return {
    a: ui.clipA.value, b: ui.clipB.value,
    a_end: Number(ui.aEnd.value), b_start: Number(ui.bStart.value),
    length: Number(ui.length.value), key_at: Number(ui.keyAt.value),
    alpha: Number(ui.alpha.value), method: ui.method.value, align: ui.align.checked,
    foot_lock: ui.footLock.checked,
  };
}

export function showOutputs() {
  const p = currentParams();
  $('a-end-out').textContent = `${p.a_end} / ${clipInfo(p.a).frames - 1}`;
  $('b-start-out').textContent = `${p.b_start} / ${clipInfo(p.b).frames - 1}`;
  $('alpha-out').textContent = p.alpha.toFixed(2);
  $('length-out').textContent = `${p.length} frames`;
  $('key-at-out').textContent = `${p.key_at} of ${p.length}`;
  const keyed = state.info.keyed.includes(p.method);
  ui.alpha.disabled = !keyed;
  ui.keyAt.disabled = !keyed;
}

export function setClipRanges(resetA, resetB) {
  const a = clipInfo(ui.clipA.value), b = clipInfo(ui.clipB.value);
  ui.aEnd.max = String(a.frames - 1);
  if (resetA || Number(ui.aEnd.value) > a.frames - 1) ui.aEnd.value = String(a.frames - 1);
  ui.bStart.max = String(b.frames - 1);
  if (resetB || Number(ui.bStart.value) > b.frames - 1) ui.bStart.value = '0';
  ui.keyAt.max = ui.length.value;
  if (resetA && resetB) ui.keyAt.value = String(Math.max(1, Math.floor(Number(ui.length.value) / 2)));
}

// A new length: the key keeps its place in proportion and stays within the transition.
export function fitKeyAt() {
  const len = Number(ui.length.value), old = Number(ui.keyAt.max) || len;
  const k = clamp(Math.round(Number(ui.keyAt.value) * len / old), 1, len);
  ui.keyAt.max = String(len);
  ui.keyAt.value = String(k);
}

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

// The controls for the served clips and methods (GET /api/clips), with the first view's choices.
export function fillControls(info) {
  const skel = info.skeleton;
  const names = info.clips.map((c) => c.name);
  $('clip-count').textContent = `${names.length} clips · ${skel.names.length} joints`;
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
}

// ---- the result's labels -----------------------------------------------------------------
// Legends, the result line and the retrieval source of a newly shown result.
export function showLabels(res, cres, params) {
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
}

// Which real motion a retrieval transition replayed, and how well it matched (one line per part;
// a splice names the segment continuing A, then the one arriving in B).
const source = (p) => `${p.clip} ${p.frames[0]}–${p.frames[1]}` + (p.reversed ? ' (played backwards)' : '')
  + ` · match ${p.distance.toFixed(1)}°`;

function showRetrieval(res) {
  const el = $('retrieval-info');
  const r = res.retrieval;
  el.hidden = r === undefined;
  if (r === undefined) return;
  el.textContent = !r ? 'No real motion fits (library or the clips\' own frames): interpolated (fallback).'
    : (r.own ? 'The clips\' own motion (A up to its end, B from its start):\n' : '')
      + Object.entries(r.parts).map(([part, p]) => `${part}: ${source(p)}`
        + (p.then ? ` → then ${source(p.then)}` : '')
        + ` · confidence ${Math.round(100 * p.confidence)}%`).join('\n');
}

// ---- map status --------------------------------------------------------------------------
// The pill in the top bar for a GET /api/status answer.
export function showMapStatus(s) {
  const pill = $('map-status');
  pill.className = `pill ${s.state}`;
  if (s.state === 'training' || s.state === 'loading') {
    $('map-text').textContent = `Training posture map · ${Math.round(100 * s.progress)}% · ${s.neurons} neurons`;
    $('map-bar').style.width = `${Math.round(100 * s.progress)}%`;
  } else if (s.state === 'ready') {
    $('map-text').textContent = `Posture map ready · ${s.neurons.toLocaleString('en')} neurons`;
  } else {
    $('map-text').textContent = s.state === 'none' ? 'No posture map · keyless methods only' : 'Posture map failed';
    if (s.message) { pill.title = s.message; note(s.message, 'error'); }
  }
}

// No map (not trained, or training failed): the methods with a key cannot be chosen.
export function disableKeyedMethods() {
  for (const sel of [ui.method, ui.compare]) {
    for (const o of sel.options) o.disabled = state.info.keyed.includes(o.value);
    if (state.info.keyed.includes(sel.value)) sel.value = sel === ui.method ? 'spline' : '';
  }
}

// ---- joint angle plot --------------------------------------------------------------------
const plot = $('plot');

function angleSeries(res, j) {
  const v = res.tracks[j].values, n = res.frames, out = new Float32Array(n);
  for (let f = 0; f < n; f++) out[f] = 2 * Math.acos(Math.min(1, Math.abs(v[4 * f + 3]))) * 180 / Math.PI;
  return out;
}

export function drawPlot() {
  const [ctx, w, h] = fitCanvas(plot);
  ctx.clearRect(0, 0, w, h);
  const { result, cmpResult } = state;
  if (!result) return;
  const j = Number(ui.plotJoint.value) || 0;
  const cacheKey = `${state.applied}:${j}`;
  if (state.plotCache.key !== cacheKey) {
    state.plotCache = { key: cacheKey, main: angleSeries(result, j), cmp: cmpResult ? angleSeries(cmpResult, j) : null };
  }
  const { main: s, cmp: c } = state.plotCache;
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
  const px = x(state.time * result.fps);
  ctx.strokeStyle = 'rgba(255,255,255,0.7)'; ctx.lineWidth = 1;
  ctx.beginPath(); ctx.moveTo(px, T); ctx.lineTo(px, h - B); ctx.stroke();
}

// ---- messages ----------------------------------------------------------------------------
export function note(text, kind = 'error') {
  const m = $('message');
  m.textContent = text;
  m.className = `message ${kind === 'info' ? 'info' : ''}`;
  m.hidden = false;
  clearTimeout(state.messageTimer);
  if (kind !== 'info') state.messageTimer = setTimeout(() => { m.hidden = true; }, 6000);
}

export function hideMessage() { $('message').hidden = true; }
