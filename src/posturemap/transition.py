"""Motion transitions: key posture from the maps, B-spline in-between, root alignment.

The transition fills ``length`` frames between the end of clip A (frame ``a_end``, time 0)
and the start of clip B (frame ``b_start``, time ``length + 1``).

Every frame is split into a *trajectory* (root horizontal position, heading about the up
axis) and a *posture* (root height, root tilt, local rotations). Rotations are handled as
rotation vectors ``log(ref^-1 q)`` relative to a per-joint reference rotation (the key's,
or B's first), a space without sign flips or seams for the short arcs of a transition.
The interpolating methods are each a fixed linear map from the seam values to the in-between
frames; retrieval replays real motion:

``auto`` (default)
    ``spline`` for gaps shorter than ``AUTO_SHORT_S`` seconds (too short for a step, where
    matching the seam velocities is what counts), ``retrieval`` otherwise.
``retrieval``
    Real motion from the map's motion library, found through the map's index, replayed between
    the seams with smooth seam corrections and its planted feet kept planted, falling back to
    ``upm-valid`` by confidence (:mod:`posturemap.retrieval`). ``alpha`` weighs the match at A's
    end (0: continue A's motion) against the match at B's start (1: arrive in B's motion).
``upm`` (paper)
    Key posture from the four class maps: per class, the neuron nearest the ``alpha``-blend of
    A's last and B's first posture (an O(n) scan). A clamped cubic B-spline passes through A's
    end (value and velocity), the key at frame ``key_at`` and B's start (value and velocity).
``upm-path``
    As ``upm``, with each class key the neuron at fraction ``alpha`` of the way along the
    shortest path between the two postures' winners in the map graph.
``upm-valid``
    Keys every ``KEY_SPACING_S`` seconds, each estimated from the blend of the seam postures and
    the fading seam velocities and projected into the map's valid region (within ``ACCEPT`` * R of
    a neuron); one clamped B-spline through all of them (see :meth:`TransitionEngine.valid_keys`).
``spline``
    The same cubic (Hermite) spline without a key: matches values and velocities at both ends.
``slerp``
    SLERP of every rotation and LERP of the root, from A's end to B's start (no velocities).
``inertialize``
    B's start, extrapolated backwards with its velocity, plus an offset that decays with a
    quintic from A's end (value, velocity, acceleration) to zero (Bollo 2016).

Foot locking (:mod:`posturemap.feet`, on by default in :func:`transition`) pins planted feet.

Root alignment (default): B is turned about the up axis and moved so that it continues A:
its start lies where A's root, moving at the mean of the two clips' seam velocities, gets to
in ``length + 1`` frames, facing A's heading advanced by the mean turning rate.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from functools import lru_cache

import numpy as np

from . import kernels, quat
from .errors import UserError
from .feet import leg_chains, leg_length, lock_feet
from .features import TWO_PI, root_global, upright_rest
from .motion import Motion, concatenate, root_index, up_axis, up_vector

METHODS = ("auto", "retrieval", "upm", "upm-path", "upm-valid", "spline", "slerp", "inertialize")
KEYED = ("auto", "retrieval", "upm", "upm-path", "upm-valid")  # need a map; alpha steers them
KEY_POSTURE = ("upm", "upm-path", "upm-valid")  # interpolate through key postures (key_at)
DEFAULT_METHOD = "auto"  # chosen by `posturemap bench`: see the README
AUTO_SHORT_S = 0.25  # auto: gaps shorter than this (seconds) use `spline`, longer ones `retrieval`
# upm-valid (see TransitionEngine.valid_keys and the README's evaluation section):
KEY_SPACING_S = 0.2  # at most this many seconds between keys
VELOCITY_HORIZON_S = 0.1  # time constant (s) over which the seam velocities fade from the keys
ACCEPT = 1.5  # estimates within ACCEPT * R of a neuron count as valid, others are pulled onto
#              that sphere. On bandai1, 99% of unseen real postures lie within 2.8 R of a map trained
#              without them, most within 1.5 R; 1.5 is the benchmark's trade-off: larger keeps more
#              accuracy, smaller more validity (2.0 is less valid than SLERP at 5-15 frames)


# -- bases: the in-between frames as linear maps of the seam values ------------------------
def key_spline_basis(length: int, key_at: int) -> np.ndarray:
    """Clamped cubic B-spline through (0: pA, vA), (key_at: key), (length+1: pB, vB).

    Returns the matrix (length, 5) mapping ``[pA, vA, pB, vB, key]`` to frames 1..length.
    """
    return keys_spline_basis(length, (float(key_at),))


@lru_cache(maxsize=256)
def keys_spline_basis(length: int, times: tuple[float, ...]) -> np.ndarray:
    """Clamped cubic B-spline through A's end, keys at ``times`` (0 < t < length+1), B's start.

    Returns the matrix (length, 4 + K) mapping ``[pA, vA, pB, vB, key_1..key_K]`` to frames
    1..length; the curve has value and velocity ``pA, vA`` at 0 and ``pB, vB`` at length+1.
    """
    k = len(times)
    knots = np.concatenate([[0.0], times, [length + 1.0]])
    spline = clamped_spline_matrix(knots, np.arange(1, length + 1, dtype=float))  # (L, k+4)
    # Its inputs are [y_0 (pA), y_1..y_k (keys), y_k+1 (pB), slope_0 (vA), slope_end (vB)].
    out = spline[:, [0, k + 2, k + 1, k + 3] + list(range(1, k + 1))]
    out.setflags(write=False)
    return out


def clamped_spline_matrix(knots: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The C2 cubic spline through values at ``knots`` (n+1,) with given end slopes, as a matrix.

    Returns (len(t), n+3) mapping ``[y_0..y_n, slope_0, slope_n]`` to the curve at ``t``.
    The interior slopes solve the usual tridiagonal C2 system; between knots the curve is
    the cubic Hermite of the two values and slopes. (Same curve as scipy's
    ``make_interp_spline(k=3)`` with first-derivative end conditions, without its import.)
    """
    n = len(knots) - 1
    h = np.diff(knots)
    # Slopes m (n+1,) = S @ [y, s0, sn].
    a = np.zeros((n + 1, n + 1))
    rhs = np.zeros((n + 1, n + 3))
    a[0, 0] = a[n, n] = 1.0
    rhs[0, n + 1] = rhs[n, n + 2] = 1.0
    for i in range(1, n):
        a[i, i - 1], a[i, i], a[i, i + 1] = 1 / h[i - 1], 2 / h[i - 1] + 2 / h[i], 1 / h[i]
        rhs[i, i - 1] -= 3 / h[i - 1] ** 2
        rhs[i, i] += 3 / h[i - 1] ** 2 - 3 / h[i] ** 2
        rhs[i, i + 1] += 3 / h[i] ** 2
    slopes = np.linalg.solve(a, rhs)
    seg = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, n - 1)
    hs = h[seg]
    s = (t - knots[seg]) / hs
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, (s**3 - 2 * s**2 + s) * hs
    h01, h11 = -2 * s**3 + 3 * s**2, (s**3 - s**2) * hs
    out = h10[:, None] * slopes[seg] + h11[:, None] * slopes[seg + 1]
    rows = np.arange(len(t))
    out[rows, seg] += h00
    out[rows, seg + 1] += h01
    return out


def damped_reach(times: np.ndarray, d: float, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """How far (in frames of velocity) each side's seam velocity carries at ``times``.

    A's continuation after ``t`` frames and B's before ``d - t`` frames, each
    ``t * exp(-t / tau)``: the full velocity near the seam, an offset that peaks at ``tau``
    frames and then fades back onto the blend path.
    """
    if tau <= 0:
        return np.zeros_like(times), np.zeros_like(times)
    return times * np.exp(-times / tau), (d - times) * np.exp(-(d - times) / tau)


@lru_cache(maxsize=256)
def key_times(length: int, key_at: int, spacing: float) -> tuple[float, ...]:
    """Key times for ``upm-valid``: ``key_at`` plus evenly spread keys, gaps at most ``spacing``."""
    d = length + 1.0
    times = []
    for lo, hi in ((0.0, float(key_at)), (float(key_at), d)):
        pieces = max(1, int(np.ceil((hi - lo) / spacing - 1e-9)))
        times.extend(lo + (hi - lo) * k / pieces for k in range(1, pieces))
        if hi < d:
            times.append(hi)
    return tuple(times)


@lru_cache(maxsize=256)
def hermite_basis(length: int) -> np.ndarray:
    """Cubic Hermite from (pA, vA) at 0 to (pB, vB) at length+1: matrix (length, 4)."""
    d = length + 1.0
    s = np.arange(1, length + 1) / d
    out = np.stack([2 * s**3 - 3 * s**2 + 1, (s**3 - 2 * s**2 + s) * d,
                    -2 * s**3 + 3 * s**2, (s**3 - s**2) * d], axis=1)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=256)
def linear_basis(length: int) -> np.ndarray:
    """Straight line from pA at 0 to pB at length+1: matrix (length, 2)."""
    s = np.arange(1, length + 1) / (length + 1.0)
    out = np.stack([1 - s, s], axis=1)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=256)
def inertialize_basis(length: int) -> np.ndarray:
    """B's start extrapolated back with vB, plus a quintic offset decay: matrix (length, 5).

    Maps ``[pA, vA, pB, vB, aA]``; the offset ``x0 = pA - (pB - vB d)``, ``v0 = vA - vB``,
    ``a0 = aA`` decays to zero value, velocity and acceleration at ``d = length + 1``.
    """
    d = length + 1.0
    t = np.arange(1, length + 1, dtype=float)
    # Offset polynomial x(t) = A t^5 + B t^4 + C t^3 + a0/2 t^2 + v0 t + x0, per unit x0, v0, a0.
    def poly(x0, v0, a0):
        a = -(a0 * d**2 + 6 * v0 * d + 12 * x0) / (2 * d**5)
        b = (3 * a0 * d**2 + 16 * v0 * d + 30 * x0) / (2 * d**4)
        c = -(3 * a0 * d**2 + 12 * v0 * d + 20 * x0) / (2 * d**3)
        return a * t**5 + b * t**4 + c * t**3 + 0.5 * a0 * t**2 + v0 * t + x0
    px, pv, pa = poly(1, 0, 0), poly(0, 1, 0), poly(0, 0, 1)
    # target(t) = pB - vB (d - t); x0 = pA - pB + vB d; v0 = vA - vB.
    out = np.stack([px, pv, 1 - px, -(d - t) + d * px - pv, pa], axis=1)
    out.setflags(write=False)
    return out


# -- per-clip decomposition ---------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Track:
    """A clip split into trajectory and posture, computed once per clip.

    Attributes
    ----------
    motion : the clip
    gpos : (F, 3) global root position
    heading : (F,) root heading about the up axis, radians, continuous over time
    rots : (F, J, 4) local rotations, with the root's replaced by its tilt
    features : (F, D) posture vectors for a map, or None
    feet : (F, n_legs, 3) global ankle positions (for foot locking)
    """

    motion: Motion
    gpos: np.ndarray
    heading: np.ndarray
    rots: np.ndarray
    features: np.ndarray | None
    feet: np.ndarray


def heading_of(q: np.ndarray, up: int) -> np.ndarray:
    """Angle (radians) of rotations ``q (..., 4)`` about the up axis (they must be pure turns)."""
    return 2.0 * np.arctan2(q[..., 1 + up], q[..., 0])


def rotate_about_up(v: np.ndarray, angle: float, up: int) -> np.ndarray:
    """Vectors ``v (..., 3)`` turned by ``angle`` (radians, right-handed) about the up axis."""
    a, b = (up + 1) % 3, (up + 2) % 3
    c, s = math.cos(angle), math.sin(angle)
    m = np.zeros((3, 3))
    m[up, up] = 1.0
    m[a, a], m[a, b], m[b, a], m[b, b] = c, -s, s, c
    return v @ m.T


def make_track(motion: Motion, root: int, up: int, rest: np.ndarray, space=None) -> Track:
    """Split a clip into trajectory and posture (see :class:`Track`)."""
    grot, gpos = root_global(motion, root)
    head_q, tilt = quat.heading_tilt(grot, up_vector(up), rest)
    heading = np.unwrap(heading_of(head_q, up))
    rots = motion.rotations.copy()
    rots[:, root] = tilt
    feats = space.encode(motion) if space is not None else None
    ankles = [c[2] for c in leg_chains(motion.skeleton)]
    feet = np.zeros((len(motion), 0, 3))
    if ankles:
        grot_all, gpos_all = np.empty(motion.rotations.shape), np.empty(motion.positions.shape)
        kernels.fk(motion.skeleton.parents, motion.rotations, motion.positions, grot_all, gpos_all)
        feet = gpos_all[:, ankles]
    return Track(motion, gpos, heading, rots, feats, feet)


def _ancestors(parents: np.ndarray, root: int) -> list[int]:
    chain = []
    j = parents[root]
    while j >= 0:
        chain.append(int(j))
        j = parents[j]
    return chain[::-1]


# -- the engine -----------------------------------------------------------------------------
class TransitionEngine:
    """Keeps a map and prepared clips in memory; one transition per call (for a game loop).

    >>> engine = TransitionEngine(model)              # doctest: +SKIP
    >>> engine.add("walk", walk); engine.add("run", run)
    >>> rots, pos = engine.generate("walk", "run", alpha=0.3)

    Clips are split into trajectory and posture once (:meth:`add`); :meth:`generate` then
    only reads seam frames, finds the key and evaluates a precomputed spline basis, writing
    into buffers reused between calls of the same length.
    """

    def __init__(self, model=None, skeleton=None):
        self.model = model
        if model is not None:
            skeleton = model.skeleton_
        self.skeleton = skeleton
        self.tracks: dict[str, Track] = {}
        self._root = self._up = None
        self._buffers: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._chain = np.zeros(0, dtype=np.int64)
        self._rest = None
        self._legs = []
        if model is not None:
            space = model.space_
            self._root, self._up, self._rest = space.root, space.up, space.rest
            self._chain = np.array(_ancestors(skeleton.parents, self._root), dtype=np.int64)
            self._circular = space.circular if space.circular.any() else None
            self._dim_index = np.concatenate(space.class_dims).astype(np.int64)
            self._dim_off = np.concatenate([[0], np.cumsum([len(d) for d in space.class_dims])]).astype(np.int64)
            self._flat_of = None
            self._paths = [None] * len(model.maps_)

    def add(self, name: str, motion: Motion) -> Track:
        """Prepare a clip under ``name`` (same skeleton as the map, if any)."""
        if self.skeleton is None:
            self.skeleton = motion.skeleton
        if not motion.skeleton.same_as(self.skeleton):
            raise UserError(name, "skeleton differs from the other clips (joints, hierarchy or channels)")
        if self._root is None:
            self._root, self._up = root_index(motion), up_axis(motion)
        self._chain = np.array(_ancestors(self.skeleton.parents, self._root), dtype=np.int64)
        space = self.model.space_ if self.model is not None else None
        if self._rest is None:
            self._rest = upright_rest(root_global(motion, self._root)[0], self._up)
        if not self._legs:
            self._legs = leg_chains(self.skeleton)
            self._leg_length = leg_length(self.skeleton, self._legs)
        tr = make_track(motion, self._root, self._up, self._rest, space)
        self.tracks[name] = tr
        return tr

    # -- key posture ------------------------------------------------------------------------
    def key_features(self, xa: np.ndarray, xb: np.ndarray, alpha: float, path: bool = False):
        """Key posture vector (D,) and the chosen neuron per class, between ``xa`` and ``xb``."""
        space = self.model.space_
        if self._circular is None and not path:
            maps = self.model.maps_
            if self._flat_of is None or any(w is not m.weights_ for w, m in zip(self._flat_of, maps)):
                self._flatten_maps()
            key = space.fill.copy()
            chosen = np.empty(len(self.model.maps_), dtype=np.int64)
            kernels.key_from_blend(self._wflat, self._woff, self._wn, self._dim_index, self._dim_off,
                                   xa + alpha * (xb - xa), key, chosen)
            return key, chosen.tolist()
        if self._circular is None:
            blend = xa + alpha * (xb - xa)
        else:
            circ = self._circular
            blend = xa + alpha * np.where(circ, np.mod(xb - xa + np.pi, TWO_PI) - np.pi, xb - xa)
            blend = np.where(circ, np.mod(blend, TWO_PI), blend)
        key = space.fill.copy()
        chosen = []
        for c, m in enumerate(self.model.maps_):
            dims = space.class_dims[c]
            if path:
                k = self._path_neuron(c, xa[dims], xb[dims], alpha)
            else:
                k = self._nearest(c, blend[dims])
            chosen.append(k)
            key[dims] = m.weights_[k]
        return key, chosen

    def valid_keys(self, ta: Track, tb: Track, a_end: int, b_start: int, length: int, key_at: int,
                   alpha: float) -> tuple[np.ndarray, np.ndarray, int, list[int]]:
        """Keys of ``upm-valid``: times (K,), key vectors (K, D), index of the key at ``key_at``,
        and the neuron per class nearest that key.

        Each key starts from an estimate of the posture at its time: the blend of A's last and
        B's first posture, at a fraction that runs linearly from 0 to ``alpha`` at ``key_at`` and
        on to 1 at B, plus each side's seam velocity carried over ``t * exp(-t / tau)`` frames
        (``tau`` = ``VELOCITY_HORIZON_S``: the velocity near the seam, fading back onto the blend;
        :func:`damped_reach`). Per class, the estimate is then projected into the map's
        valid region (the postures within ``ACCEPT`` * R of a neuron): kept if it lies that
        close to its nearest neuron, otherwise moved onto that neuron's sphere.
        """
        space = self.model.space_
        fps = ta.motion.fps
        d = length + 1.0
        times = np.array(key_times(length, key_at, KEY_SPACING_S * fps))
        main = int(np.argmin(np.abs(times - key_at)))
        warp = np.where(times <= key_at, alpha * times / key_at, alpha + (1 - alpha) * (times - key_at) / (d - key_at))
        xa, xb = ta.features[a_end], tb.features[b_start]
        fa, fb = ta.features[max(a_end - 1, 0)], tb.features[min(b_start + 1, len(tb.features) - 1)]
        if self._circular is None:
            delta, va, vb = xb - xa, xa - fa, fb - xb
        else:
            circ = self._circular
            delta = np.where(circ, np.mod(xb - xa + np.pi, TWO_PI) - np.pi, xb - xa)
            va = np.where(circ, np.mod(xa - fa + np.pi, TWO_PI) - np.pi, xa - fa)
            vb = np.where(circ, np.mod(fb - xb + np.pi, TWO_PI) - np.pi, fb - xb)
        ga, gb = damped_reach(times, d, VELOCITY_HORIZON_S * fps)
        est = xa + warp[:, None] * delta + ((1 - warp) * ga)[:, None] * va - (warp * gb)[:, None] * vb
        keys = np.broadcast_to(space.fill, est.shape).copy()
        chosen = []
        idx = np.empty(len(times), dtype=np.int64)
        for c, m in enumerate(self.model.maps_):
            dims = space.class_dims[c]
            x = np.ascontiguousarray(est[:, dims])
            kernels.project_to_map(m.weights_, x, m.period_, ACCEPT * m.radius_, x, idx)
            keys[:, dims] = x
            chosen.append(int(idx[main]))
        return times, keys, main, chosen

    def _flatten_maps(self):
        """All class maps in one flat array, for the one-call key of the Euclidean case.

        Rebuilt when a map's weights array is replaced (the engine reads the model live).
        """
        maps = self.model.maps_
        self._wflat = np.concatenate([m.weights_.ravel() for m in maps])
        self._woff = np.concatenate([[0], np.cumsum([m.weights_.size for m in maps])[:-1]]).astype(np.int64)
        self._wn = np.array([m.n_neurons for m in maps], dtype=np.int64)
        self._flat_of = [m.weights_ for m in maps]  # the arrays themselves: an id() can be reused

    def _nearest(self, c: int, x: np.ndarray) -> int:
        m = self.model.maps_[c]
        return kernels.nearest(m.weights_, x, m.period_)

    def _path_neuron(self, c: int, xa: np.ndarray, xb: np.ndarray, alpha: float) -> int:
        """Neuron at fraction ``alpha`` of the shortest graph path from A's winner to B's."""
        from scipy.sparse import csr_matrix
        from scipy.sparse.csgraph import dijkstra

        m = self.model.maps_[c]
        wa, wb = self._nearest(c, xa), self._nearest(c, xb)
        if wa == wb or len(m.edges_) == 0:
            return wa if alpha < 0.5 else wb
        if self._paths[c] is None:
            e = m.edges_
            diff = np.abs(m.weights_[e[:, 0]] - m.weights_[e[:, 1]])
            diff = np.minimum(diff, m.period_ - diff)
            d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
            n = m.n_neurons
            self._paths[c] = csr_matrix((np.maximum(d, 1e-12), (e[:, 0], e[:, 1])), shape=(n, n))
        dist, pred = dijkstra(self._paths[c], directed=False, indices=wa, return_predecessors=True)
        if not np.isfinite(dist[wb]):  # B's winner not reachable: fall back to the blend key
            blend = xa + alpha * (xb - xa)
            return self._nearest(c, np.where(np.isinf(m.period_), blend, np.mod(blend, TWO_PI)))
        path = [wb]
        while path[-1] != wa:
            path.append(int(pred[path[-1]]))
        path = path[::-1]
        target = alpha * dist[wb]
        return min(path, key=lambda k: abs(dist[k] - target))

    # -- transition ---------------------------------------------------------------------------
    def alignment(self, a: Track, b: Track, a_end: int, b_start: int, length: int) -> tuple[float, np.ndarray]:
        """Turn (radians about up) and translation (3,) that make B continue A."""
        up = self._up
        h1, h2 = (up + 1) % 3, (up + 2) % 3
        d = length + 1.0
        a0, b1 = max(a_end - 1, 0), min(b_start + 1, len(b.gpos) - 1)
        pa, pa0, pb, pb1 = a.gpos[a_end], a.gpos[a0], b.gpos[b_start], b.gpos[b1]
        wa = a.heading[a_end] - a.heading[a0]
        wb = b.heading[b1] - b.heading[b_start]
        dtheta = float(a.heading[a_end] + 0.5 * (wa + wb) * d - b.heading[b_start])
        c, s = math.cos(dtheta), math.sin(dtheta)
        # B's seam velocity and start, turned by dtheta in the horizontal plane (h1, h2).
        vb1, vb2 = pb1[h1] - pb[h1], pb1[h2] - pb[h2]
        vb1, vb2 = c * vb1 - s * vb2, s * vb1 + c * vb2
        sb1, sb2 = c * pb[h1] - s * pb[h2], s * pb[h1] + c * pb[h2]
        shift = np.zeros(3)
        shift[h1] = pa[h1] + 0.5 * (pa[h1] - pa0[h1] + vb1) * d - sb1
        shift[h2] = pa[h2] + 0.5 * (pa[h2] - pa0[h2] + vb2) * d - sb2
        return dtheta, shift

    def generate(self, a: str, b: str, length: int = 20, key_at: int | None = None, alpha: float = 0.5,
                 a_end: int | None = None, b_start: int = 0, align: bool = True, method: str = DEFAULT_METHOD,
                 foot_lock: bool = True):
        """The in-between frames: local rotations (length, J, 4) and positions (length, J, 3).

        ``foot_lock`` keeps planted feet still (:mod:`posturemap.feet`; costs a forward
        kinematics pass, about a millisecond).

        Also sets ``self.last`` (key posture, chosen neurons, alignment) for inspection.
        The returned arrays are buffers reused by the next call with the same ``length``.
        """
        ta, tb = self.tracks[a], self.tracks[b]
        a_end = len(ta.gpos) - 1 if a_end is None else a_end
        key_at = max(1, length // 2) if key_at is None else key_at
        check_args(len(ta.gpos), len(tb.gpos), length, key_at, alpha, a_end, b_start, method)
        if method in KEYED and self.model is None:
            raise UserError("--method", f"method {method!r} needs a posture map")
        if method == "auto":
            method = "spline" if (length + 1) / ta.motion.fps < AUTO_SHORT_S else "retrieval"
            out = self.generate(a, b, length, key_at, alpha, a_end, b_start, align, method, foot_lock)
            self.last["method"] = method
            return out
        if method == "retrieval":
            return self._retrieval(ta, tb, a, b, length, key_at, alpha, a_end, b_start, align, foot_lock)
        up, root = self._up, self._root

        # Seam frames: A at a_end-2..a_end, B at b_start..b_start+1 (clamped inside the clips).
        ia = [max(a_end - 2, 0), max(a_end - 1, 0), a_end]
        ib = [b_start, min(b_start + 1, len(tb.gpos) - 1)]
        if align:
            dtheta, shift = self.alignment(ta, tb, a_end, b_start, length)
        else:
            dtheta, shift = 0.0, np.zeros(3)
        b_head = tb.heading[ib] + dtheta
        b_head += TWO_PI * round((ta.heading[a_end] - b_head[0]) / TWO_PI)
        b_pos = rotate_about_up(tb.gpos[ib], dtheta, up) + shift

        rots_a, rots_b = ta.rots[ia], tb.rots[ib]
        j_count = self.skeleton.num_joints
        space = self.model.space_ if self.model is not None else None
        key = chosen = None
        # Reference rotation per joint: the key's for keyed joints, otherwise B's first frame.
        ref = rots_b[0].copy()
        if method == "upm-valid":
            times, key_vecs, main, chosen = self.valid_keys(ta, tb, a_end, b_start, length, key_at, alpha)
            key_rots, key_heights = self._decode_keys(key_vecs)
            key = (key_rots[main], float(key_heights[main]))
            ref[space.joints] = key[0]
        elif method in KEYED:
            key_vec, chosen = self.key_features(ta.features[a_end], tb.features[b_start], alpha,
                                                path=method == "upm-path")
            key = self._decode_key(key_vec)
            ref[space.joints] = key[0]
        # Seam values as one row each: rotation vectors about ref, then root position,
        # heading and local translations. Rows: A[a_end-2], A[a_end-1], A[a_end], B[b0], B[b0+1].
        seam = np.empty((5, 3 * j_count + 4 + 3 * j_count))
        kernels.log_relative(np.concatenate([rots_a, rots_b]), ref, seam[:, : 3 * j_count].reshape(5, j_count, 3))
        s0 = 3 * j_count
        seam[:3, s0: s0 + 3] = ta.gpos[ia]
        seam[:3, s0 + 3] = ta.heading[ia]
        seam[:3, s0 + 4:] = ta.motion.positions[ia].reshape(3, -1)
        seam[3:, s0: s0 + 3] = b_pos
        seam[3:, s0 + 3] = b_head
        seam[3:, s0 + 4:] = tb.motion.positions[ib].reshape(2, -1)
        # Inputs of the bases: pA, vA, pB, vB, aA (per-frame differences at the seams).
        inputs = np.empty((5, seam.shape[1]))
        inputs[0] = seam[2]
        np.subtract(seam[2], seam[1], out=inputs[1])
        inputs[2] = seam[3]
        np.subtract(seam[4], seam[3], out=inputs[3])
        if method == "slerp":
            frames = linear_basis(length) @ inputs[[0, 2]]
        elif method == "inertialize":
            inputs[4] = seam[2] - 2.0 * seam[1] + seam[0]
            frames = inertialize_basis(length) @ inputs
        elif method == "spline":
            frames = hermite_basis(length) @ inputs[:4]
        elif method == "upm-valid":
            # Keys at several times: keyed columns take the keys' values (rotation vectors about
            # the main key); the free columns (trajectory, joints outside the map) take the same
            # kind of estimate: the straight line plus the damped seam velocities.
            kcols = self._keyed_columns()
            warp = times / (length + 1.0)
            ga, gb = damped_reach(times, length + 1.0, VELOCITY_HORIZON_S * ta.motion.fps)
            keyrows = (inputs[0] + warp[:, None] * (inputs[2] - inputs[0])
                       + ((1 - warp) * ga)[:, None] * inputs[1] - (warp * gb)[:, None] * inputs[3])
            jk = space.joints
            krot = np.empty((len(times), len(jk), 3))
            kernels.log_relative(key_rots, ref[jk], krot)
            keyrows[:, kcols[:-1]] = krot.reshape(len(times), -1)
            keyrows[:, kcols[-1]] = key_heights
            frames = keys_spline_basis(length, tuple(times)) @ np.concatenate([inputs[:4], keyrows])
        else:
            # One clamped B-spline through the key for every column: keyed columns (feature
            # joints' rotations, 0 about the key, and the root height) take the key's value,
            # the others the Hermite curve's own value there, which leaves them on that curve.
            inputs[4] = hermite_basis(length)[key_at - 1] @ inputs[:4]
            kcols = self._keyed_columns()
            inputs[4, kcols[:-1]] = 0.0
            inputs[4, kcols[-1]] = key[1]
            frames = key_spline_basis(length, key_at) @ inputs

        out_r, out_p = self._buffers.get(length) or (np.empty((length, j_count, 4)), np.empty((length, j_count, 3)))
        self._buffers[length] = (out_r, out_p)
        kernels.exp_relative(frames[:, :s0].reshape(length, j_count, 3), ref, out_r)
        out_p[:] = frames[:, s0 + 4:].reshape(length, j_count, 3)
        kernels.compose_root(self._chain, root, up, out_r, out_p, frames[:, s0: s0 + 3], frames[:, s0 + 3])
        if foot_lock and self._legs:
            b_feet = rotate_about_up(tb.feet[ib], dtheta, up) + shift
            lock_feet(self.skeleton, self._legs, out_r, out_p, self._fk, up, ta.feet[ia[1:]], b_feet,
                      ta.motion.fps, body=self._leg_length)
        self.last = {"key": key, "neurons": chosen, "dtheta": dtheta, "shift": shift}
        return out_r, out_p

    def _retrieval(self, ta, tb, a, b, length, key_at, alpha, a_end, b_start, align, foot_lock):
        """``method="retrieval"`` (:mod:`posturemap.retrieval`), with its fallback blended by confidence."""
        from . import retrieval

        lib = getattr(self.model, "library_", None)
        res = None
        if lib is not None and len(lib):
            if getattr(self, "_retriever", None) is None or self._retriever.lib is not lib:
                self._retriever = retrieval.Retriever(self, lib)
            res = retrieval.retrieve(self._retriever, ta, tb, a_end, b_start, length, alpha, align,
                                     skip_unconfident=True)
        # The fallback where confidence is short of full; otherwise SLERP/LERP gives what the
        # retrieved parts leave open (joints above the root, local translations).
        fallback = retrieval.fallback_method(length, ta.motion.fps)
        base = fallback if res is None or min(res.confidence) < 1.0 else "slerp"
        rots_fb, pos_fb = self.generate(a, b, length, key_at, alpha, a_end, b_start, align, base, False)
        rots_fb, pos_fb = rots_fb.copy(), pos_fb.copy()
        fb_last = self.last
        out_r, out_p = self._buffers.get(length) or (np.empty((length, self.skeleton.num_joints, 4)),
                                                     np.empty((length, self.skeleton.num_joints, 3)))
        self._buffers[length] = (out_r, out_p)
        if res is None or max(res.confidence) <= 0.0:
            out_r[:], out_p[:] = rots_fb, pos_fb
            self.last = {**fb_last, "retrieval": None if res is None else res.info}
            dtheta, shift, contacts = fb_last["dtheta"], fb_last["shift"], None
        else:
            rt = self._retriever
            out_r[:] = res.rots
            out_r[:, self._chain] = rots_fb[:, self._chain]
            out_p[:] = pos_fb
            if res.confidence[0] > 0.0:  # a part with confidence 0 was not replayed: the fallback's
                kernels.compose_root(self._chain, self._root, self._up, out_r, out_p, res.gpos, res.heading)
            for mask, c in ((rt.lower_mask, res.confidence[0]), (rt.upper_mask, res.confidence[1])):
                if c <= 0.0:
                    out_r[:, mask] = rots_fb[:, mask]
                elif c < 1.0:
                    fb_part, part = rots_fb[:, mask].reshape(-1, 4), out_r[:, mask].reshape(-1, 4)
                    kernels.slerp(fb_part, part, c, part)
                    out_r[:, mask] = part.reshape(length, -1, 4)
            if 0.0 < res.confidence[0] < 1.0:
                r = self._root
                out_p[:, r] = pos_fb[:, r] + res.confidence[0] * (out_p[:, r] - pos_fb[:, r])
            dtheta, shift = res.dtheta, res.shift
            if res.confidence[0] <= 0.0:
                dtheta, shift = fb_last["dtheta"], fb_last["shift"]
            elif res.confidence[0] < 1.0 and align:  # B's place blended like the trajectory
                c = res.confidence[0]
                g0 = tb.gpos[b_start]
                end_fb = rotate_about_up(g0, fb_last["dtheta"], self._up) + fb_last["shift"]
                end = rotate_about_up(g0, dtheta, self._up) + shift
                turn = dtheta - fb_last["dtheta"]
                dtheta = fb_last["dtheta"] + c * (turn - TWO_PI * round(turn / TWO_PI))
                shift = end_fb + c * (end - end_fb) - rotate_about_up(g0, dtheta, self._up)
            contacts = res.contacts if res.confidence[0] >= 0.5 else None
            self.last = {"key": None, "neurons": None, "dtheta": dtheta, "shift": shift, "retrieval": res.info}
        if foot_lock and self._legs:
            ib = [b_start, min(b_start + 1, len(tb.gpos) - 1)]
            ia = [max(a_end - 1, 0), a_end]
            b_feet = rotate_about_up(tb.feet[ib], dtheta, self._up) + shift
            self.last["planted"] = lock_feet(self.skeleton, self._legs, out_r, out_p, self._fk, self._up,
                                             ta.feet[ia], b_feet, ta.motion.fps, contacts, self._leg_length)
        return out_r, out_p

    def _fk(self, rots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations and positions of the new frames (compiled FK, output buffers)."""
        out_p = self._buffers[len(rots)][1]
        grot, gpos = np.empty(rots.shape), np.empty(out_p.shape)
        kernels.fk(self.skeleton.parents, rots, out_p, grot, gpos)
        return grot, gpos

    def _decode_key(self, key_vec: np.ndarray) -> tuple[np.ndarray, float]:
        """Rotations (K, 4) of the feature joints (root tilt first) and root height of a key."""
        rots, heights = self._decode_keys(key_vec[None])
        return rots[0], float(heights[0])

    def _decode_keys(self, key_vecs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (N, K, 4) of the feature joints and root heights (N,) of key vectors (N, D)."""
        space = self.model.space_
        if space.mode != "logmap":
            return space.decode(key_vecs)
        k = len(space.joints)
        rots = np.empty((len(key_vecs), k, 4))
        kernels.exp_relative(np.ascontiguousarray(key_vecs[:, : 3 * k]).reshape(-1, k, 3), space.reference, rots)
        return rots, key_vecs[:, -1] * space.height_scale

    def _keyed_columns(self) -> np.ndarray:
        if not hasattr(self, "_kcols"):
            j_count = self.skeleton.num_joints
            joints = self.model.space_.joints
            rot_cols = (3 * joints[:, None] + np.arange(3)).ravel()
            self._kcols = np.concatenate([rot_cols, [3 * j_count + self._up]])
        return self._kcols


def check_args(len_a: int, len_b: int, length: int, key_at: int, alpha: float, a_end: int,
               b_start: int, method: str):
    """Validate transition arguments; raises :class:`UserError` naming the option."""
    if method not in METHODS:
        raise UserError("--method", f"unknown method {method!r} (choose from {', '.join(METHODS)})")
    if not 1 <= length <= 10_000:
        raise UserError("--length", f"must be between 1 and 10000 frames, got {length}")
    if method in KEYED and not 1 <= key_at <= length:
        raise UserError("--key-at", f"must be between 1 and the length {length}, got {key_at}")
    if not 0.0 <= alpha <= 1.0:
        raise UserError("--alpha", f"must be between 0 and 1, got {alpha}")
    if not 0 <= a_end < len_a:
        raise UserError("--a-end", f"frame {a_end} is outside clip A (frames 0..{len_a - 1})")
    if not 0 <= b_start < len_b:
        raise UserError("--b-start", f"frame {b_start} is outside clip B (frames 0..{len_b - 1})")


def aligned(track: Track, engine: TransitionEngine, start: int, dtheta: float, shift: np.ndarray) -> Motion:
    """Frames ``start:`` of a clip, turned by ``dtheta`` about up and moved by ``shift``."""
    m = track.motion
    up = engine._up
    rots = track.rots[start:].copy()
    positions = m.positions[start:].copy()
    gpos = rotate_about_up(track.gpos[start:], dtheta, up) + shift
    kernels.compose_root(engine._chain, engine._root, up, rots, positions, gpos, track.heading[start:] + dtheta)
    return Motion(m.skeleton, rots, positions, m.fps)


def transition(a: Motion, b: Motion, model=None, length: int = 20, key_at: int | None = None,
               alpha: float = 0.5, a_end: int | None = None, b_start: int = 0, align: bool = True,
               method: str = DEFAULT_METHOD, foot_lock: bool = True, report: dict | None = None) -> Motion:
    """A[:a_end+1], then ``length`` new frames, then B[b_start:] (moved to continue A).

    Parameters
    ----------
    a, b : Motion with one skeleton (and the map's, when ``model`` is given)
    model : PostureMap or None; needed for ``upm`` and ``upm-path``
    length : number of in-between frames (paper: 20)
    key_at : position of the key among the in-between frames, 1..length (default
        max(1, length // 2); the paper puts it at the 10th of 20)
    alpha : control parameter in [0, 1]: 0 keys near A's posture, 1 near B's
    a_end : last frame of A used (default: A's last frame)
    b_start : first frame of B used
    align : move and turn B to continue A; False leaves B's root exactly where it is
    method : one of :data:`METHODS`
    foot_lock : keep planted feet still in the new frames (:mod:`posturemap.feet`)
    report : a dict to fill with what was done: ``method`` (the one used, for ``auto``) and,
        for retrieval, ``retrieval`` (source clip and frames per body part, match cost in map
        radii, confidence; None when nothing fitted and the fallback was used)

    Returns
    -------
    Motion with ``a_end + 1 + length + len(b) - b_start`` frames, A's skeleton and fps.
    """
    engine = TransitionEngine(model, a.skeleton if model is None else None)
    engine.add("a", a)
    engine.add("b", b)
    rots, pos = engine.generate("a", "b", length, key_at, alpha, a_end, b_start, align, method, foot_lock)
    if report is not None:
        report["method"] = engine.last.get("method", method)
        if "retrieval" in engine.last:
            report["retrieval"] = engine.last["retrieval"]
    a_end = len(a) - 1 if a_end is None else a_end
    mid = Motion(a.skeleton, rots.copy(), pos.copy(), a.fps)
    if align:
        b_part = aligned(engine.tracks["b"], engine, b_start, engine.last["dtheta"], engine.last["shift"])
    else:
        b_part = b[b_start:]
    return concatenate([a[: a_end + 1], mid, Motion(a.skeleton, b_part.rotations, b_part.positions, a.fps)])
