// Constants and small helpers the studio's modules share. Nothing here changes.
export const $ = (id) => document.getElementById(id);

export const COLOR = {
  a: '#5b8def', t: '#ff8a3d', b: '#3ecf8e', cmp: '#38bdf8', ghost: '#b794f6', main: '#dfe4ea',
  bg: '#0d1117', line: '#263041', muted: '#8b97a8', text: '#e6ebf2',
};

const METHOD_NAMES = {
  upm: 'UPM key (paper)', 'upm-path': 'UPM key on map path', 'upm-valid': 'UPM key, validated',
  retrieval: 'Retrieved real motion', auto: 'Auto (by gap and match)',
  spline: 'Spline, no key', slerp: 'SLERP / LERP', damped: 'SLERP + fading seam velocities',
  inertialize: 'Inertialization',
};
export const methodName = (m) => METHOD_NAMES[m] || m;
export const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));

export function escapeHtml(s) {
  return String(s).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' }[c]));
}

// A 2D canvas sized to its box at the device's pixel ratio: [context, CSS width, CSS height].
export function fitCanvas(c) {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(c.clientWidth * dpr)), h = Math.max(1, Math.round(c.clientHeight * dpr));
  if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
  const ctx = c.getContext('2d');
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  return [ctx, c.clientWidth, c.clientHeight];
}
