// The test and debugging hook, window.__studio: what the page shows, for the browser tests and
// bench/studio_latency.py. The studio writes it and never reads it back (its own state is in
// state.js). Its actions (setFrame, jointPositions, play, setView) are attached by app.js, which
// can reach the modules they drive; `time` appears with the first frame drawn.
import { state } from './state.js';

export const studio = {
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
  displayedKey: () => (state.ghost ? state.ghost.pose() : null),   // the ghost skeleton's bone quaternions
  // A promise resolved once `latencies` holds n entries (a driver waits without polling the page).
  latencyCount: (n) => new Promise((resolve) => {
    const check = () => { if (studio.latencies.length >= n) resolve(n); else state.latencyWaiters.push(check); };
    check();
  }),
};
window.__studio = studio;

// The studio's phase (state.phase), shown in the hook's `state`.
export function setPhase(phase) {
  state.phase = phase;
  studio.state = phase;
}

// An update's pose is submitted (t holds its steps so far): it counts as shown at the next
// frame, after the browser has painted this one (requestAnimationFrame, then a task).
export function timePaint(t) {
  requestAnimationFrame(() => {
    const ch = new MessageChannel();
    ch.port1.onmessage = () => {
      t.painted = performance.now();
      studio.timings.push(Object.fromEntries(Object.entries(t).map(([k, v]) => [k, v - t.input])));
      studio.latencies.push(t.painted - t.input);
      for (const w of state.latencyWaiters.splice(0)) w();
    };
    ch.port2.postMessage(null);
  });
}
