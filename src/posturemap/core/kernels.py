"""Kernels of the hot paths: numpy first, numba-compiled where a process gains from it.

``import posturemap`` does not import numba (importing it costs about half a second, more
than a whole command-line transition needs). The per-transition kernels below are plain numpy
until :func:`compiled` is called; from then on the same names run the numba versions of
:mod:`posturemap.core.numba_kernels` (compiled once, cached on disk), which cost microseconds
instead of a few hundred numpy dispatches. :func:`compiled` is called by whatever runs many
transitions or trains a map: UPM training (the training kernels below are only compiled:
``kernels.upm_epoch`` and the like load them), the studio server, the benchmarks, the demo.
A single ``posturemap transition`` with ``--map`` stays in numpy.

Both versions compute the same maths (the tests cross-check them and :mod:`posturemap.core.quat`);
callers use the module attribute (``kernels.fk(...)``), never a name imported from it, so that
they follow the switch. Quaternions are (w, x, y, z); every kernel writes into ``out`` arrays
given by the caller.
"""

from __future__ import annotations

import contextlib
import threading
import types

import numpy as np

from . import quat
from .skeleton import chain_world
from .skeleton import fk as _fk_reference

FADE_SPAN = np.radians(90.0)  # slerp_track's fade columns: from a half turn round, toward an end over this

# Per-transition kernels with a numpy version here and a compiled one in numba_kernels.
HOT = ("log_relative", "exp_relative", "compose_root", "fk", "nearest",
       "project_to_map", "key_from_blend", "slerp", "slerp_track", "turn_toward", "blend_root", "chest_turned")
# Training kernels: compiled only (a numpy UPM epoch would be hundreds of times slower).
COMPILED_ONLY = ("upm_epoch", "two_nearest", "nearest_sample_dist", "sqdist", "move")

_loaded: list = []  # [numba_kernels] once compiled() has run
_lock = threading.Lock()
_CHUNK = 1 << 22  # elements of one (rows, neurons, dims) difference block in _nearest_rows


def compiled() -> types.ModuleType:
    """Load the numba kernels and switch this module's hot kernels to them; returns that module.

    The first call imports numba and loads (or, on a new machine, compiles) the cached
    kernels: about half a second. Later calls return at once.
    """
    if not _loaded:
        with _lock:
            if not _loaded:
                from . import numba_kernels
                globals().update({name: getattr(numba_kernels, name) for name in HOT})
                _loaded.append(numba_kernels)
    return _loaded[0]


def backend() -> str:
    """``"numba"`` once :func:`compiled` has run, else ``"numpy"``."""
    return "numba" if _loaded else "numpy"


@contextlib.contextmanager
def numpy_backend():
    """Run the block with the numpy kernels (BVH parsing included), then restore the backend.

    For tests and comparisons; not for use while another thread runs kernels.
    """
    with _lock:
        saved = list(_loaded)
        _loaded.clear()
        globals().update(vars(NUMPY))
    try:
        yield
    finally:
        with _lock:
            _loaded[:] = saved
            if saved:
                globals().update({name: getattr(saved[0], name) for name in HOT})


def __getattr__(name: str):
    if name in COMPILED_ONLY:
        return getattr(compiled(), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# -- numpy versions -------------------------------------------------------------------------
def log_relative(q, ref, out):
    """``out[n, j] = log(ref[j]^-1 q[n, j])`` on the short arc; q (N, J, 4), ref (J, 4), out (N, J, 3)."""
    out[...] = quat.log(quat.mul(quat.inv(ref), q))


def exp_relative(r, ref, out):
    """``out[n, j] = ref[j] exp(r[n, j])``; r (N, J, 3), ref (J, 4), out (N, J, 4)."""
    out[...] = quat.mul(ref, quat.exp(r))


def compose_root(chain, root, up, rots, positions, gpos, heading):
    """Turn tilt + heading + global position into the root's local rotation and position.

    ``rots (N, J, 4)``: ``rots[:, root]`` holds the tilt on entry; ``gpos (N, 3)`` the root's
    global position, ``heading (N,)`` its turn about axis ``up`` (radians). ``chain`` lists the
    root's ancestors from the top (empty for most skeletons). Writes ``rots[:, root]`` and
    ``positions[:, root]``; nothing else changes.
    """
    axis = np.zeros(3)
    axis[up] = 1.0
    g = quat.mul(quat.from_axis_angle(axis, np.asarray(heading, dtype=float)), rots[:, root])
    p = np.asarray(gpos, dtype=float)
    if len(chain):
        prot, ppos = chain_world(chain, rots, positions)
        g = quat.mul(quat.inv(prot), g)
        p = quat.mul_vec(quat.inv(prot), p - ppos)
    rots[:, root] = g
    positions[:, root] = p


def slerp(a, b, t, out):
    """``out[i]`` = :func:`posturemap.core.quat.slerp` from ``a[i]`` to ``b[i]`` (M, 4) at the fraction ``t``."""
    out[...] = quat.slerp(a, b, t)


def slerp_track(a, b, t, out, fade):
    """``out[n, m]`` = the SLERP from ``a[n, m]`` to ``b[n, m]`` (N, M, 4; N frames) at the
    fraction ``t`` (one for every frame, or (N,) one per frame), on the arc that goes on from
    frame to frame: the short arc at frame 0, then each frame's relative rotation ``a^-1 b`` in
    the hemisphere of the frame before's.

    Two tracks that pass through a half turn from each other (a retrieved arm and the fallback's)
    had their short arc flip to the other side of it from one frame to the next, and a blend of
    them jumped by up to a half turn in a frame; on this arc it goes on round.

    On the columns ``fade`` (M,) bool, where the arc has gone on past a half turn round, the
    fraction moves to the nearer end (0 below a half, else 1) over the next :data:`FADE_SPAN`
    (a smoothstep; all the way from three quarters of a turn round): for a fraction that stays
    (a confidence), tracks that passed a half turn apart and came back together from the other
    side ended nearly a whole turn round on the arc, and the blend a third of that from both
    (an arm 123 degrees in a frame into B's first); where the arc wound on past a whole turn,
    its axis turned over (the hips 179 degrees in a frame). Up to a half turn round they are
    blended as the other columns are.

    Returns the last frame's relative rotation on that arc (M, 4): its scalar part is negative
    where the arc ends more than a half turn round (the caller that places something at the
    arc's end, B after a blended root, needs to know which way round it went). N must be >= 1.
    """
    t = np.broadcast_to(np.asarray(t, dtype=np.float64), (len(a),))[:, None, None]
    rel = quat.mul(quat.inv(a), b)
    flips = np.sum(rel[1:] * rel[:-1], axis=-1) < 0.0
    sign = np.where(rel[:1, :, 0] < 0.0, -1.0, 1.0) * np.concatenate(
        [np.ones((1,) + flips.shape[1:]), np.where(np.cumsum(flips, axis=0) % 2 == 1, -1.0, 1.0)])
    theta = np.arccos(np.clip(sign * rel[..., 0], -1.0, 1.0))[..., None]
    fade = np.asarray(fade, dtype=bool)
    if fade.any():
        near = np.clip((2.0 * theta - np.pi) / FADE_SPAN, 0.0, 1.0)
        t = np.where(fade[:, None], t + (np.where(t >= 0.5, 1.0, 0.0) - t) * near * near * (3.0 - 2.0 * near), t)
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-6
    safe = np.where(small, 1.0, sin_theta)
    wa = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(small, t, np.sin(t * theta) / safe) * sign[..., None]
    out[...] = quat.normalize(wa * a + wb * b)
    return sign[-1][:, None] * rel[-1]


def blend_root(chain, root, up, rest, rots_fb, tilt, heading, c, align, out):
    """The root blended at the fraction ``c`` from the fallback's to the retrieved one, as a
    turn about the up axis and a tilt.

    ``rots_fb (N, J, 4)``: the fallback's frames (the root's global rotation is that of its
    ancestors ``chain``, top first, and its own); ``tilt (N, 4)``: the retrieved root's tilt,
    replaced by the blend of the two tilts (the short arc; a tilt stays within a quarter turn of
    upright); ``heading (N,)``: the retrieved root's turn about axis ``up`` (radians, as
    :func:`compose_root` takes it); ``rest (4,)``: the root's upright orientation (headings are
    measured on ``g * rest^-1``, :func:`posturemap.core.quat.heading_tilt`). ``out (N,)``: the
    blended headings, the fallback's plus ``c`` of the retrieved one's lead over it, the short
    way at the first frame, then on round through the frames as the two go (counted in whole
    turns as ``heading`` is, so that they run on from frame to frame as it does). Where B stays where
    it is (not ``align``), the whole turns of the lead at the last frame are taken off it over
    the frames (a smoothstep): both roots end on B's heading, and the blend would end ``c`` of
    them off it.

    Returns the lead at the last frame, the way round it went (whole turns kept).
    """
    g = rots_fb[:, root]
    for j in chain[::-1]:
        g = quat.mul(rots_fb[:, j], g)
    axis = np.zeros(3)
    axis[up] = 1.0
    turn, tilt_fb = quat.heading_tilt(g, axis, rest)
    h_fb = 2.0 * np.arctan2(turn[:, 1 + up], turn[:, 0])
    two_pi = 2.0 * np.pi
    lead = heading - h_fb
    lead[0] -= two_pi * np.rint(lead[0] / two_pi)
    lead[1:] -= two_pi * np.cumsum(np.rint(np.diff(lead) / two_pi))
    went = float(lead[-1])
    base = heading - lead  # the fallback's heading, counted round as the retrieved one's
    turns = np.rint(went / two_pi)
    if turns != 0.0 and not align:
        u = np.arange(1, len(lead) + 1) / len(lead)
        lead -= two_pi * turns * (u * u * (3.0 - 2.0 * u))
    tilt[...] = quat.slerp(tilt_fb, tilt, c)
    out[...] = base + c * lead
    return went


def turn_toward(chain, rots, other, t):
    """The last joint of ``chain`` (joint indices, top first, the top without a parent) turned in
    place in ``rots (N, J, 4)`` so that its global rotation goes the fraction ``t`` of the short
    arc from its own toward its global rotation in ``other (N, J, 4)``; its ancestors stay, the
    joints under it follow."""
    j = chain[-1]
    up_own, up_other = rots[:, chain[0]], other[:, chain[0]]
    for c in chain[1:-1]:
        up_own, up_other = quat.mul(up_own, rots[:, c]), quat.mul(up_other, other[:, c])
    own = quat.mul(up_own, rots[:, j])
    rots[:, j] = quat.mul(quat.inv(up_own), quat.slerp(own, quat.mul(up_other, other[:, j]), t))


def chest_turned(chain, up, other, rots, joints, free, out):
    """``out[:, joints]``: the joints ``joints`` of ``other (N, J, 4)`` (children of the last joint
    of ``chain``) put under the chain of ``rots (N, J, 4)`` so that they differ in the world from
    ``other``'s only by a turn about axis ``up`` (0, 1, 2): of the turn between the two chains'
    last joints (the swing-twist twist of the rotation from ``other``'s to ``rots``'s, of angle
    theta in [-pi, pi)) what lies beyond ``free`` radians, smoothly, ``theta - free
    tanh(sin(theta) / free)`` (all of it with ``free`` 0; the sine makes a half turn either way
    the same turn). ``chain`` top first, the top without a parent. Nothing else of ``out (N, J,
    4)`` is written."""
    w_other, w_rots = other[:, chain[0]], rots[:, chain[0]]
    for c in chain[1:]:
        w_other, w_rots = quat.mul(w_other, other[:, c]), quat.mul(w_rots, rots[:, c])
    d = quat.mul(w_rots, quat.inv(w_other))
    theta = 2.0 * np.arctan2(d[:, 1 + up], d[:, 0])
    theta = (theta + np.pi) % (2.0 * np.pi) - np.pi
    half = 0.5 * (theta - free * np.tanh(np.sin(theta) / free)) if free > 0.0 else 0.5 * theta
    turn = np.zeros((len(d), 4))
    turn[:, 0], turn[:, 1 + up] = np.cos(half), np.sin(half)
    onto = quat.mul(quat.inv(w_rots), quat.mul(turn, w_other))
    out[:, joints] = quat.normalize(quat.mul(onto[:, None], other[:, joints]))


def fk(parents, rots, positions, grot, gpos):
    """Forward kinematics of (N, J) local rotations/translations into ``grot``/``gpos``.

    Same as :func:`posturemap.core.skeleton.fk` (parents before children, -1 for roots).
    """
    grot[...], gpos[...] = _fk_reference(parents, rots, positions)


def _nearest_rows(W, X, period) -> np.ndarray:
    """Index (m,) of the row of ``W (n, d)`` nearest each row of ``X (m, d)`` (circular where
    ``period`` is finite); ties go to the lower index, as in the compiled scan."""
    per_row = max(1, W.size)
    out = np.empty(len(X), dtype=np.int64)
    circular = bool(np.isfinite(period).any())
    for s in range(0, len(X), max(1, _CHUNK // per_row)):
        d = np.abs(W[None] - X[s: s + max(1, _CHUNK // per_row), None])
        if circular:
            d = np.minimum(d, period - d)
        out[s: s + len(d)] = np.argmin(np.einsum("mnd,mnd->mn", d, d), axis=1)
    return out


def nearest(W, x, period) -> int:
    """Index of the row of ``W (n, d)`` nearest ``x (d,)``; ``period`` (d,) per dimension (inf: linear)."""
    return int(_nearest_rows(W, x[None], period)[0])


def _wrap_difference(d, period):
    """Differences ``d (..., d)`` wrapped into [-p/2, p/2) where ``period`` is finite."""
    circ = np.isfinite(period)
    if not circ.any():
        return d
    p = np.where(circ, period, 1.0)
    return np.where(circ, d - p * np.floor(d / p + 0.5), d)


def project_to_map(W, X, period, limit, out, idx):
    """Project each row of ``X (m, d)`` into the union of balls of radius ``limit`` around the
    rows of ``W``: kept where within ``limit`` of its nearest row, else moved onto that ball's
    surface. Writes the results into ``out (m, d)`` (which may be ``X``) and the nearest rows
    into ``idx (m,)``. Periodic dimensions (finite ``period``) are wrapped into [0, period).
    """
    k = _nearest_rows(W, X, period)
    diff = _wrap_difference(X - W[k], period)
    dist = np.sqrt(np.einsum("md,md->m", diff, diff))
    scale = np.where(dist <= limit, 1.0, limit / np.maximum(dist, 1e-300))
    v = W[k] + diff * scale[:, None]
    circ = np.isfinite(period)
    if circ.any():
        p = np.where(circ, period, 1.0)
        wrapped = v - p * np.floor(v / p)
        v = np.where(circ, np.where(wrapped >= p, 0.0, wrapped), v)
    out[...] = v
    idx[...] = k


def key_from_blend(weights, offsets, counts, dim_index, dim_offsets, blend, key, chosen):
    """The paper's key for all bone classes at once (Euclidean maps).

    Class ``c`` has ``counts[c]`` neurons stored row-major in ``weights`` from ``offsets[c]``,
    over the feature dimensions ``dim_index[dim_offsets[c]:dim_offsets[c + 1]]``. For each class
    the neuron nearest ``blend`` (full feature vector) is found, its index written to
    ``chosen[c]`` and its weights into those dimensions of ``key``.
    """
    for c in range(len(counts)):
        dims = dim_index[dim_offsets[c]: dim_offsets[c + 1]]
        w = weights[offsets[c]: offsets[c] + counts[c] * len(dims)].reshape(counts[c], len(dims))
        best = int(_nearest_rows(w, blend[dims][None], np.full(len(dims), np.inf))[0])
        chosen[c] = best
        key[dims] = w[best]


NUMPY = types.SimpleNamespace(**{name: globals()[name] for name in HOT})
"""The numpy versions, whichever backend is active (for tests and comparisons)."""
