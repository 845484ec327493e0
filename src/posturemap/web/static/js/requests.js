// Talking to the server: the clip list, the map status, clip frames, transitions and exports.
// Transitions: one request in flight, the latest parameters next, stale answers dropped; the
// comparison method is asked again only when its own inputs changed.
import { $, methodName } from './common.js';
import {
  currentParams, disableKeyedMethods, hideMessage, note, showMapStatus, showOutputs, ui,
} from './panels.js';
import { assemble, framesOf, showResult } from './result.js';
import { state } from './state.js';
import { setPhase, studio } from './studio.js';

// GET /api/clips: the skeleton, the clips, the methods and the limits.
export async function fetchClips() {
  const r = await fetch('/api/clips');
  if (!r.ok) throw new Error(`cannot list the clips (HTTP ${r.status})`);
  return r.json();
}

// ---- transitions -------------------------------------------------------------------------
// A control changed (`kind` names it): show its value now, ask for the result at once or, with
// a request in flight, once it is back.
export function request(kind) {
  if (state.pendingInput === null) state.pendingInput = performance.now();
  state.focus = kind;
  showOutputs();
  if (state.inflight) { state.dirty = true; return; }
  send();
}

function resultKey(params, method) {
  // What a result depends on: every parameter, less alpha and the key position for a keyless method.
  const keyed = state.info.keyed.includes(method);
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
  state.inflight = true;
  state.dirty = false;
  const mine = ++state.seq;
  const params = currentParams();
  const started = state.pendingInput;
  const kind = state.focus;
  state.pendingInput = null;
  const sentAt = performance.now();
  const cmpMethod = ui.compare.value && ui.compare.value !== params.method ? ui.compare.value : null;
  studio.requests++;
  // The comparison is asked for again only when its own inputs changed (a method without a key
  // ignores alpha and the key position).
  const cmpKey = cmpMethod ? resultKey(params, cmpMethod) : null;
  const cmpKept = cmpKey !== null && state.shownCmp.key === cmpKey ? state.shownCmp.res : null;
  try {
    const clips = Promise.all([clipFramesOf(params.a), clipFramesOf(params.b)]);
    const jobs = [postJSON('/api/transition', params), clips];
    if (cmpMethod && !cmpKept) jobs.push(postJSON('/api/transition', { ...params, method: cmpMethod }).catch((e) => e));
    const [answer, [ca, cb], cmpAnswer] = await Promise.all(jobs);
    if (mine < state.applied) return;   // an answer to older parameters
    state.applied = mine;
    const receivedAt = performance.now();
    const res = assemble(answer, ca, cb);
    const cmpError = cmpAnswer instanceof Error ? cmpAnswer : null;
    let cres = cmpKept;
    if (cmpAnswer && !cmpError) cres = assemble(cmpAnswer, ca, cb);
    state.shownCmp = { key: cres ? cmpKey : null, res: cres };
    showResult(res, cres, params, kind);
    if (started !== null) {
      state.pendingTiming = { input: started, sent: sentAt, received: receivedAt, applied: performance.now() };
    }
    if (cmpError) note(`Compare (${methodName(cmpMethod)}): ${cmpError.message}`, 'info');
    else hideMessage();
  } catch (e) {
    if (e.status === 503) {
      note(e.message.replace(/^method: /, ''), 'info');
      state.waitForMap = true;
    } else {
      note(e.message, 'error');
      studio.errors.push(e.message);
    }
  } finally {
    state.inflight = false;
    if (state.dirty) send();
  }
}

// A clip's frames (GET /api/clip/<name>), fetched once: a Promise of {frames, quat, pos}.
function clipFramesOf(name) {
  const cache = state.clipFrames;
  if (!cache.has(name)) {
    const p = fetch(`/api/clip/${encodeURIComponent(name)}`).then(async (r) => {
      if (!r.ok) {
        let msg = `HTTP ${r.status}`;
        try { msg = (await r.json()).error || msg; } catch { /* not JSON */ }
        throw new Error(`clip ${name}: ${msg}`);
      }
      return framesOf(await r.json());
    });
    p.catch(() => cache.delete(name));   // a failed fetch is tried again next time
    cache.set(name, p);
  }
  return cache.get(name);
}

// ---- map status --------------------------------------------------------------------------
// GET /api/status until the map is trained (or known absent), then the first result.
export async function pollStatus() {
  let s;
  try {
    s = await (await fetch('/api/status')).json();
  } catch (e) {
    setTimeout(pollStatus, 1000);
    return;
  }
  state.map = s;
  studio.map = s;
  showMapStatus(s);
  if (s.state === 'training' || s.state === 'loading') {
    if (state.phase !== 'error') setPhase('training');
    setTimeout(pollStatus, 400);
    return;
  }
  // No map (not trained, or training failed): the methods without a key still work.
  if (s.state !== 'ready') disableKeyedMethods();
  if (state.result) setPhase('ready');
  if (state.waitForMap || !state.result) { state.waitForMap = false; request('init'); }
}

// ---- export ------------------------------------------------------------------------------
// POST /api/export with the current controls: the result downloads as a file.
export async function exportResult() {
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
