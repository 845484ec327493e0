"""Key postures from the maps: the paper's key (``upm``), its graph-path variant and ``upm-valid``.

A key is a posture vector (the map's feature space) built from the neurons of the four class
maps; every neuron is a real posture, so a key is a posture the map has seen (or, for
``upm-valid``, one within ``ACCEPT`` map radii of such a posture). :class:`MapKeys` holds what
the searches reuse between calls (the maps flattened for one compiled call, the graphs).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..core import kernels
from ..learn.features import TWO_PI
from .bases import VELOCITY_HORIZON_S, damped_reach
from .trajectory import Track

# upm-valid (see MapKeys.valid_keys and the README's evaluation section):
KEY_SPACING_S = 0.2  # at most this many seconds between keys
ACCEPT = 1.5  # estimates within ACCEPT * R of a neuron count as valid, others are pulled onto
#              that sphere. On bandai1, 99% of unseen real postures lie within 2.8 R of a map trained
#              without them, most within 1.5 R; 1.5 is the benchmark's trade-off: larger keeps more
#              accuracy, smaller more validity (2.0 is less valid than SLERP at 5-15 frames)



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


class MapKeys:
    """The key postures of a trained :class:`~posturemap.learn.model.PostureMap`.

    It reads the model live: replacing a map's weights array (e.g. a new epoch in the studio)
    rebuilds the flattened copy on the next call.
    """

    def __init__(self, model, num_joints: int, up: int):
        self.model = model
        self.num_joints, self.up = num_joints, up
        space = model.space_
        self._circular = space.circular if space.circular.any() else None
        self._dim_index = np.concatenate(space.class_dims).astype(np.int64)
        self._dim_off = np.concatenate([[0], np.cumsum([len(d) for d in space.class_dims])]).astype(np.int64)
        self._flat_of = None
        self._paths = [None] * len(model.maps_)
        self._kcols = None

    @property
    def space(self):
        """The model's feature space."""
        return self.model.space_

    @property
    def maps(self):
        """The model's class maps (read live)."""
        return self.model.maps_

    def key_features(self, xa: np.ndarray, xb: np.ndarray, alpha: float, path: bool = False):
        """Key posture vector (D,) and the chosen neuron per class, between ``xa`` and ``xb``."""
        space = self.space
        if self._circular is None and not path:
            maps = self.maps
            if self._flat_of is None or any(w is not m.weights_ for w, m in zip(self._flat_of, maps)):
                self._flatten_maps()
            key = space.fill.copy()
            chosen = np.empty(len(self.maps), dtype=np.int64)
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
        for c, m in enumerate(self.maps):
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
        space = self.space
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
        for c, m in enumerate(self.maps):
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
        maps = self.maps
        self._wflat = np.concatenate([m.weights_.ravel() for m in maps])
        self._woff = np.concatenate([[0], np.cumsum([m.weights_.size for m in maps])[:-1]]).astype(np.int64)
        self._wn = np.array([m.n_neurons for m in maps], dtype=np.int64)
        self._flat_of = [m.weights_ for m in maps]  # the arrays themselves: an id() can be reused

    def _nearest(self, c: int, x: np.ndarray) -> int:
        m = self.maps[c]
        return kernels.nearest(m.weights_, x, m.period_)

    def _path_neuron(self, c: int, xa: np.ndarray, xb: np.ndarray, alpha: float) -> int:
        """Neuron at fraction ``alpha`` of the shortest graph path from A's winner to B's."""
        from scipy.sparse import csr_matrix
        from scipy.sparse.csgraph import dijkstra

        m = self.maps[c]
        wa, wb = self._nearest(c, xa), self._nearest(c, xb)
        if wa == wb or len(m.edges_) == 0:
            return wa if alpha < 0.5 else wb
        if self._paths[c] is None or self._paths[c][0] is not m.weights_ or self._paths[c][1] is not m.edges_:
            e = m.edges_
            diff = np.abs(m.weights_[e[:, 0]] - m.weights_[e[:, 1]])
            diff = np.minimum(diff, m.period_ - diff)
            d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
            n = m.n_neurons
            # Kept with the arrays it was built from: a map that grows (partial_fit) rebuilds it.
            self._paths[c] = (m.weights_, m.edges_, csr_matrix((np.maximum(d, 1e-12), (e[:, 0], e[:, 1])),
                                                               shape=(n, n)))
        dist, pred = dijkstra(self._paths[c][2], directed=False, indices=wa, return_predecessors=True)
        if not np.isfinite(dist[wb]):  # B's winner not reachable: fall back to the blend key
            blend = xa + alpha * (xb - xa)
            return self._nearest(c, np.where(np.isinf(m.period_), blend, np.mod(blend, TWO_PI)))
        path = [wb]
        while path[-1] != wa:
            path.append(int(pred[path[-1]]))
        path = path[::-1]
        target = alpha * dist[wb]
        return min(path, key=lambda k: abs(dist[k] - target))

    def decode_key(self, key_vec: np.ndarray) -> tuple[np.ndarray, float]:
        """Rotations (K, 4) of the feature joints (root tilt first) and root height of a key."""
        rots, heights = self.decode_keys(key_vec[None])
        return rots[0], float(heights[0])

    def decode_keys(self, key_vecs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (N, K, 4) of the feature joints and root heights (N,) of key vectors (N, D)."""
        space = self.space
        if space.mode != "logmap":
            return space.decode(key_vecs)
        k = len(space.joints)
        rots = np.empty((len(key_vecs), k, 4))
        kernels.exp_relative(np.ascontiguousarray(key_vecs[:, : 3 * k]).reshape(-1, k, 3), space.reference, rots)
        return rots, key_vecs[:, -1] * space.height_scale

    def keyed_columns(self) -> np.ndarray:
        """Columns of the engine's seam rows that a key sets: the feature joints' rotation
        vectors, then the root height."""
        if self._kcols is None:
            rot_cols = (3 * self.space.joints[:, None] + np.arange(3)).ravel()
            self._kcols = np.concatenate([rot_cols, [3 * self.num_joints + self.up]])
        return self._kcols

