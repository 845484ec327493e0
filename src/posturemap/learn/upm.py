"""The Uniform Posture Map: Algorithm 1 of Kim et al., a self-organising map that grows.

For each sample ``x`` (seeded shuffle per epoch):

1. distances ``D_i`` from ``x`` to every neuron;
2. if the nearest neuron is farther than the radius ``R``, a new neuron with weight ``x`` is
   inserted and nothing else changes;
3. otherwise the winner moves toward ``x`` by ``eta * (x - w)``, and so do its neighbours in
   the map graph within the current neighbourhood (``N`` hops, shrinking to 0), each with a
   gain falling with the hop count.

``eta`` falls linearly from ``learning_rate`` to 0 over all epochs; training ends there.
A neighbour only moves if ``x`` lies within ``R`` of it, so every neuron always lies within
``R`` of a training sample (the one that placed or last moved it): the map never holds a
posture that is not near a real one, the paper's guarantee.

The neighbour graph is the topology: competitive Hebbian edges (each sample joins its
nearest and second-nearest neuron; Martinetz and Schulten) plus edges between the winners of
consecutive frames. The edges seen in one epoch are the neighbourhood of the next; the
final graph is built from the trained weights.

Circular dimensions (angles, ``period`` 2*pi) measure distance and move on the circle.
The kernels are compiled with numba on first use (and cached on disk).
"""

from __future__ import annotations


import numpy as np

from .limits import MAX_EPOCHS, MAX_NEIGHBORHOOD, MAX_RADIUS

AUTO_SUBSAMPLE = 2000
AUTO_FACTOR = 3.0
MIN_EDGE_SUPPORT = 2


def _kernels():
    """The compiled training kernels (numba; compiled once and cached on disk)."""
    from ..core import kernels

    return {"epoch": kernels.upm_epoch, "two_nearest": kernels.two_nearest,
            "nearest_sample_dist": kernels.nearest_sample_dist, "sqdist": kernels.sqdist}


def graph_csr(edges: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Adjacency of an undirected edge list (E, 2) as CSR arrays (ptr (n+1,), idx (2E,))."""
    if len(edges) == 0:
        return np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    a = np.concatenate([edges[:, 0], edges[:, 1]])
    b = np.concatenate([edges[:, 1], edges[:, 0]])
    order = np.lexsort((b, a))
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(ptr, a + 1, 1)
    return np.cumsum(ptr), b[order].astype(np.int64)


def _pair_key(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    return np.minimum(a, b) * n + np.maximum(a, b)


def _unique_edges(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ok = (a >= 0) & (b >= 0) & (a != b)
    e = np.sort(np.stack([a[ok], b[ok]], axis=1), axis=1)
    return np.unique(e, axis=0) if len(e) else np.zeros((0, 2), dtype=np.int64)


def sequence_edges(win: np.ndarray, sequences: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Winner pairs of consecutive rows of the same sequence."""
    if sequences is None or len(win) < 2:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    same = sequences[1:] == sequences[:-1]
    return win[:-1][same], win[1:][same]


def auto_radius(X: np.ndarray, period: np.ndarray, seed: int = 0) -> float:
    """The data-driven radius used for ``radius='auto'``.

    ``AUTO_FACTOR`` (3) times the median distance from a sample to its nearest neighbour
    among ``AUTO_SUBSAMPLE`` (2000) seeded random samples: the map resolves the data at the
    scale of a 2000-posture sample, so it holds a comparable number of neurons (one to three
    thousand per class on the Bandai set) whatever the amount of data, and R follows the
    spread of the data: 10k frames of few motions give a finer radius than 32k frames of
    many. No tuning needed; pass a number to choose the resolution yourself.

    A sample's exact copies are no neighbours (a clip listed twice, a held pose, frames doubled
    to raise the frame rate would otherwise make the median 0 and the map hold every frame); with
    no two distinct samples the radius is 1e-6 (one neuron per distinct posture).
    """
    rng = np.random.default_rng(seed)
    m = min(len(X), AUTO_SUBSAMPLE)
    sub = X[rng.choice(len(X), m, replace=False)] if len(X) > m else X
    k = _kernels()
    d = np.empty(m)
    nn = np.empty(m)
    for i in range(m):
        k["sqdist"](sub[i], sub, m, period, d)
        d[d == 0.0] = np.inf  # itself and its exact copies
        nn[i] = d.min()
    nn = nn[np.isfinite(nn)]
    r = AUTO_FACTOR * float(np.sqrt(np.median(nn))) if len(nn) else 0.0
    return r if r > 0 else 1e-6


class UniformPostureMap:
    """A growing self-organising map that never holds an unreal sample (Algorithm 1).

    Parameters
    ----------
    radius : float or "auto"
        Maximum distance from a sample to its neuron, ``R``; see :func:`auto_radius`.
    neighborhood : int
        Initial neighbourhood in graph hops, ``N``; shrinks linearly to 0.
    learning_rate : float
        Initial gain ``eta`` (0 < eta < 1); falls linearly to 0 over all epochs.
    epochs : int
        Passes over the data.
    seed : int
        Seed of the per-epoch shuffle.
    period : array-like or None
        Per dimension, the period of a circular dimension (2*pi for an angle) or ``inf``.

    Attributes (after ``fit``)
    --------------------------
    weights_ : ndarray (n_neurons, D)
    edges_ : ndarray (E, 2), undirected neighbour graph
    hits_ : ndarray (n_neurons,), training samples each neuron wins
    quantization_error_, topographic_error_, invalid_fraction_ : float, on the training data
    radius_ : float, the radius used
    witness_ : ndarray (n_neurons,), index of a training sample within ``radius_`` of each neuron
    """

    def __init__(self, radius="auto", neighborhood=2, learning_rate=0.5, epochs=4, seed=0, period=None):
        self.radius = radius
        self.neighborhood = neighborhood
        self.learning_rate = learning_rate
        self.epochs = epochs
        self.seed = seed
        self.period = period

    # -- learning -------------------------------------------------------------------------
    def _check(self, X):
        X = np.ascontiguousarray(X, dtype=np.float64)
        if X.ndim != 2 or len(X) == 0:
            raise ValueError(f"X must be a non-empty 2-D array, got shape {X.shape}")
        if not np.all(np.isfinite(X)):
            raise ValueError("X has NaN or infinite values")
        if not 0 < self.learning_rate < 1:
            raise ValueError(f"learning_rate must be in (0, 1), got {self.learning_rate}")
        if not 1 <= int(self.epochs) <= MAX_EPOCHS or not 0 <= int(self.neighborhood) <= MAX_NEIGHBORHOOD:
            raise ValueError(f"epochs must be from 1 to {MAX_EPOCHS} and neighborhood from 0 to {MAX_NEIGHBORHOOD}, "
                             f"got {self.epochs!r} and {self.neighborhood!r}")
        if isinstance(self.seed, bool) or not (isinstance(self.seed, (int, np.integer)) and self.seed >= 0):
            raise ValueError(f"seed must be a whole number, not negative, got {self.seed!r}")
        return X

    def _period(self, d):
        if self.period is None:
            return np.full(d, np.inf)
        p = np.asarray(self.period, dtype=np.float64)
        if p.shape != (d,):
            raise ValueError(f"period must have {d} entries, got {p.shape}")
        return p

    def fit(self, X, sequences=None, progress=None):
        """Learn a new map from samples ``X (n, D)``; returns ``self``.

        ``sequences`` (n,) labels rows of one clip: consecutive rows with the same label are
        consecutive frames, joined in the graph. ``progress(epoch, n_neurons, error)`` is
        called after each epoch.
        """
        X = self._check(X)
        period = self._period(X.shape[1])
        if self.radius == "auto":
            r = auto_radius(X, period, self.seed)
        else:
            r = float(self.radius)
            if not 0 < r <= MAX_RADIUS:  # a larger radius squared overflows; inf is no resolution
                raise ValueError(f"radius must be a positive number up to {MAX_RADIUS:g} or 'auto', "
                                 f"got {self.radius!r}")
        self.radius_ = r
        self.period_ = period
        self.weights_ = np.zeros((0, X.shape[1]))
        self.witness_ = np.zeros(0, dtype=np.int64)
        self.edges_ = np.zeros((0, 2), dtype=np.int64)
        self._train(X, sequences, progress, witness_offset=0)
        self._X_ref = None
        return self

    def partial_fit(self, X, sequences=None, progress=None):
        """Grow an existing map with new samples (same radius); returns ``self``.

        Existing neurons adapt to the new data with the same schedule; samples farther than
        the radius from every neuron become new neurons. The graph and hit counts add to the
        old ones. ``witness_`` refers to the samples of this call for the neurons it placed or
        moved and is -1 for the others, which keep the validity their earlier data gave them;
        ``invalid_fraction_`` counts only the former.
        """
        if not hasattr(self, "weights_"):
            return self.fit(X, sequences, progress)
        X = self._check(X)
        if X.shape[1] != self.weights_.shape[1]:
            raise ValueError(f"X has {X.shape[1]} dimensions, the map {self.weights_.shape[1]}")
        old_edges, old_hits = self.edges_, self.hits_
        self._train(X, sequences, progress, witness_offset=None)
        self.edges_ = _unique_edges(np.concatenate([old_edges[:, 0], self.edges_[:, 0]]),
                                    np.concatenate([old_edges[:, 1], self.edges_[:, 1]]))
        self.hits_ = self.hits_ + np.pad(old_hits, (0, self.n_neurons - len(old_hits)))
        win, second, _ = self._two_nearest(X)
        self.topographic_error_ = self._topographic_error(win, second)
        far = self.neuron_sample_distance(X) > self.radius_ * (1 + 1e-9)
        self.invalid_fraction_ = float(np.mean(far & (self.witness_ >= 0)))
        return self

    def _train(self, X, sequences, progress, witness_offset):
        k = _kernels()
        n_samples, dim = X.shape
        period = self.period_
        seq = None if sequences is None else np.asarray(sequences)
        n = len(self.weights_)
        cap = max(64, 2 * n, min(n_samples, 1024) + n)
        W = np.zeros((cap, dim))
        W[:n] = self.weights_
        witness = np.full(cap, -1, dtype=np.int64)
        if witness_offset is not None:
            witness[:n] = self.witness_
        edges = self.edges_
        rng = np.random.default_rng(self.seed)
        r2 = self.radius_ ** 2
        epochs = int(self.epochs)
        total = float(epochs * n_samples)
        win = np.full(n_samples, -1, dtype=np.int64)
        second = np.full(n_samples, -1, dtype=np.int64)
        step = 0
        for e in range(epochs):
            hops = int(round(self.neighborhood * (1.0 - e / epochs)))
            ptr, idx = graph_csr(edges, n)
            order = rng.permutation(n_samples)
            start = 0
            while True:
                dist = np.empty(W.shape[0])
                stamp = np.full(W.shape[0], -1, dtype=np.int64)
                queue = np.empty(W.shape[0], dtype=np.int64)
                qhop = np.empty(W.shape[0], dtype=np.int64)
                start, n, done = k["epoch"](X, order, start, W, n, witness, ptr, idx, period, r2,
                                            float(self.learning_rate), step, total, hops, win, second,
                                            dist, stamp, queue, qhop)
                step += done
                if start >= n_samples:
                    break
                W = np.concatenate([W, np.zeros_like(W)])  # full: double the capacity
                witness = np.concatenate([witness, np.full(len(witness), -1, dtype=np.int64)])
            a1, b1 = sequence_edges(win, seq)
            edges = _unique_edges(np.concatenate([win, a1]), np.concatenate([second, b1]))
            if progress is not None:
                progress(e + 1, n, None)
        self.weights_ = W[:n].copy()
        self.witness_ = witness[:n].copy()
        self._finish(X, seq)

    def _finish(self, X, seq):
        """Final graph, hit counts and quantisation error from the trained weights.

        A Hebbian edge is kept when at least ``MIN_EDGE_SUPPORT`` samples have its two
        neurons as nearest and second nearest (one-off pairs are noise, as edge ageing in
        growing neural gas removes them); consecutive-frame edges are always kept.
        """
        win, second, err = self._two_nearest(X)
        a1, b1 = sequence_edges(win, seq)
        key = _pair_key(win, second, self.n_neurons)
        uniq, counts = np.unique(key[second >= 0], return_counts=True)
        strong = np.isin(key, uniq[counts >= MIN_EDGE_SUPPORT])
        self.edges_ = _unique_edges(np.concatenate([win[strong], a1]), np.concatenate([second[strong], b1]))
        self.hits_ = np.bincount(win, minlength=self.n_neurons)
        self.quantization_error_ = float(err.mean())
        self.topographic_error_ = self._topographic_error(win, second)
        self.invalid_fraction_ = self.invalid_fraction(X)

    def _two_nearest(self, X):
        X = np.ascontiguousarray(np.atleast_2d(X), dtype=np.float64)
        win = np.empty(len(X), dtype=np.int64)
        second = np.empty(len(X), dtype=np.int64)
        err = np.empty(len(X))
        _kernels()["two_nearest"](X, self.weights_, self.n_neurons, self.period_, win, second, err)
        return win, second, err

    # -- use ------------------------------------------------------------------------------
    @property
    def n_neurons(self) -> int:
        return len(self.weights_)

    def distances(self, X) -> np.ndarray:
        """Distances (n, n_neurons) from samples to neurons (on the circle where periodic)."""
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        d = np.abs(X[:, None, :] - self.weights_[None])
        d = np.minimum(d, self.period_ - d)
        return np.sqrt(np.einsum("ijk,ijk->ij", d, d))

    def predict(self, X) -> np.ndarray:
        """Index of the winning (nearest) neuron for each sample ``X (n, D)``."""
        return self._two_nearest(X)[0]

    def quantization_error(self, X) -> float:
        """Mean distance from each sample to its winner."""
        return float(self._two_nearest(X)[2].mean())

    def topographic_error(self, X) -> float:
        """Fraction of samples whose nearest and second-nearest neurons share no graph edge."""
        win, second, _ = self._two_nearest(X)
        return self._topographic_error(win, second)

    def _topographic_error(self, win, second) -> float:
        if self.n_neurons < 2:
            return 0.0
        edge_keys = _pair_key(self.edges_[:, 0], self.edges_[:, 1], self.n_neurons)
        return float(1.0 - np.isin(_pair_key(win, second, self.n_neurons), edge_keys).mean())

    def neuron_sample_distance(self, X) -> np.ndarray:
        """Distance from each neuron to its nearest sample of ``X`` (n_neurons,)."""
        X = np.ascontiguousarray(np.atleast_2d(X), dtype=np.float64)
        hint = self.witness_ if len(self.witness_) == self.n_neurons else np.full(self.n_neurons, -1)
        hint = np.where(hint < len(X), hint, -1)
        return _kernels()["nearest_sample_dist"](self.weights_, X, self.period_, hint.astype(np.int64))

    def invalid_fraction(self, X) -> float:
        """Fraction of neurons farther than the radius from every sample of ``X`` (must be 0)."""
        return float(np.mean(self.neuron_sample_distance(X) > self.radius_ * (1 + 1e-9)))
