// Everything the studio changes while it runs, in one object. The other modules keep constants,
// three.js resources made once (scene.js) and scratch vectors; whatever a later event depends on
// lives here. Who writes each field is named beside it; any module may read.
export const state = {
  // -- from the server ---------------------------------------------------------------------
  info: null,               // GET /api/clips: skeleton, clips, methods, keyed, limits, defaults (app.js)
  map: null,                // last GET /api/status answer (requests.js; the hook's `map` mirrors it)
  phase: 'loading',         // loading | training | ready | error (the hook's `state` mirrors it)
  clipFrames: new Map(),    // clip name -> Promise of its frames {frames, quat, pos} (requests.js)

  // -- characters: three.js objects made once the skeleton is known (app.js) ---------------
  main: null,               // Character playing the result
  cmp: null,                // Character playing the comparison method's result
  ghost: null,              // Character holding the key posture
  trail: null,              // Trail: the root's path on the ground

  // -- the shown result (result.js) ---------------------------------------------------------
  result: null,             // the whole result: the answer plus times and tracks of every frame
  cmpResult: null,          // the comparison's whole result, or null
  shownCmp: { key: null, res: null },   // the comparison on screen and the inputs it came from

  // -- requests: one in flight, the latest parameters next, stale answers dropped (requests.js)
  inflight: false,          // a transition request is on its way
  dirty: false,             // the controls changed while it was: send again when it is back
  seq: 0,                   // number of the last request sent
  applied: 0,               // number of the request whose answer is shown
  pendingInput: null,       // performance.now() of the first input event not yet sent, or null
  focus: 'init',            // what the last input changed (a_end, b_start, alpha, clip, ...)
  waitForMap: false,        // a keyed method was refused while the map trained: ask again when ready

  // -- playback (playback.js) ---------------------------------------------------------------
  time: 0,                  // playhead, seconds into the result
  playing: false,
  speed: 1,                 // playback speed factor (the speed select)
  lastTick: performance.now(),   // timestamp of the previous animation frame

  // -- drawing --------------------------------------------------------------------------------
  needsRender: true,        // something changed: draw at the next animation frame (any module)
  drawing: false,           // inside draw(): the camera controls' own change event is ours (scene.js)
  // Resolution (scene.js): the pixel ratio factor now, whether full frames are slow (scene.js
  // starts it true in the lite profile only), when the view last changed, whether the last frame
  // was at full resolution, and when and at which scale the last frame was drawn (its cost shows
  // at the next animation frame).
  quality: { scale: 1, slow: true, lastChange: 0, refined: true, renderedAt: null, renderedScale: 1 },
  plotCache: { key: null }, // joint angle series of the shown results (panels.js)
  pendingTiming: null,      // steps of the update waiting to be drawn (studio.js, see the hook's timings)
  latencyWaiters: [],       // callbacks of the hook's latencyCount() waiting for more latencies (studio.js)

  // -- messages (panels.js) -------------------------------------------------------------------
  messageTimer: null,       // hides an error message after a while
};
