"""Uniform Posture Map (Algorithm 1): insertion rule, updates, determinism, guarantee, quality."""

from __future__ import annotations

import numpy as np
import pytest

from posturemap.learn.upm import MIN_EDGE_SUPPORT, UniformPostureMap, auto_radius

TWO_PI = 2.0 * np.pi



# -- helpers ---------------------------------------------------------------------------------
def circ_diff(a, b, period):
    """``a - b`` wrapped into [-p/2, p/2) where the period is finite."""
    d = np.asarray(a, float) - np.asarray(b, float)
    finite = np.isfinite(period)
    p = np.where(finite, period, 1.0)
    return np.where(finite, d - p * np.floor(d / p + 0.5), d)


def brute_dist(X, W, period):
    d = np.abs(np.asarray(X, float)[:, None, :] - np.asarray(W, float)[None])
    d = np.minimum(d, period - d)
    return np.sqrt((d * d).sum(-1))


def moved(w, x, gain, period):
    """``w + gain * (x - w)``, on the circle (and back into [0, p)) where the period is finite."""
    v = w + gain * circ_diff(x, w, period)
    finite = np.isfinite(period)
    p = np.where(finite, period, 1.0)
    return np.where(finite, v - p * np.floor(v / p), v)


def reference_upm(X, radius, neighborhood, learning_rate, epochs, seed, period=None, sequences=None):
    """Algorithm 1 as documented in posturemap.learn.upm, in plain Python (the test oracle).

    Seeded shuffle per epoch; insert when the nearest neuron is farther than R; else move the
    winner by eta*(x - w) and graph neighbours within ``hops`` (and within R of x) by
    eta*(1 - h/(hops+1)); eta falls linearly to 0; the graph of epoch e is the Hebbian and
    consecutive-frame edges seen in epoch e-1.
    """
    X = np.asarray(X, float)
    n_samples, dim = X.shape
    period = np.full(dim, np.inf) if period is None else np.asarray(period, float)
    rng = np.random.default_rng(seed)
    W: list[np.ndarray] = []
    win = np.full(n_samples, -1)
    second = np.full(n_samples, -1)
    edges: set[tuple[int, int]] = set()
    total = float(epochs * n_samples)
    step = 0
    for e in range(epochs):
        hops = round(neighborhood * (1.0 - e / epochs))
        n_graph = len(W)
        adj = {i: set() for i in range(n_graph)}
        for a, b in edges:
            adj[a].add(b)
            adj[b].add(a)
        for i in rng.permutation(n_samples):
            x = X[i]
            eta = learning_rate * max(0.0, 1.0 - step / total)
            step += 1
            if not W:
                W.append(x.copy())
                win[i], second[i] = 0, -1
                continue
            d2 = brute_dist(x[None], np.array(W), period)[0] ** 2
            order = np.argsort(d2, kind="stable")
            b = int(order[0])
            c = int(order[1]) if len(W) > 1 else -1
            if d2[b] > radius ** 2:
                W.append(x.copy())
                win[i], second[i] = len(W) - 1, b
                continue
            win[i], second[i] = b, c
            W[b] = moved(W[b], x, eta, period)
            if hops > 0 and b < n_graph:
                depth = {b: 0}
                frontier = [b]
                while frontier:
                    nxt = []
                    for u in frontier:
                        if depth[u] >= hops:
                            continue
                        for v in sorted(adj[u]):
                            if v in depth:
                                continue
                            depth[v] = depth[u] + 1
                            nxt.append(v)
                            if d2[v] <= radius ** 2:
                                g = eta * (1.0 - depth[v] / (hops + 1.0))
                                W[v] = moved(W[v], x, g, period)
                    frontier = nxt
        pairs = list(zip(win, second))
        if sequences is not None:
            seq = np.asarray(sequences)
            pairs += [(win[k], win[k + 1]) for k in range(n_samples - 1) if seq[k] == seq[k + 1]]
        edges = {(min(a, b), max(a, b)) for a, b in pairs if a >= 0 and b >= 0 and a != b}
    return np.array(W)


def ring(n=1500, inner=1.0, outer=2.0, seed=0):
    """Uniform samples of the annulus inner <= |x| <= outer (2-D, seeded)."""
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.uniform(inner ** 2, outer ** 2, n))
    t = rng.uniform(0.0, TWO_PI, n)
    return np.c_[r * np.cos(t), r * np.sin(t)]


def c_shape(n=1500, seed=0):
    """A thick 'C': the ring with the sector |angle| < 60 degrees removed (opening to +x)."""
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.uniform(1.0, 4.0, n))
    t = rng.uniform(np.radians(60.0), np.radians(300.0), n)
    return np.c_[r * np.cos(t), r * np.sin(t)]


def fitted(weights, radius, edges=(), period=None):
    """A map with given weights (no training), for the query functions."""
    w = np.asarray(weights, float)
    m = UniformPostureMap(radius=radius, period=period)
    m.weights_ = w
    m.edges_ = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    m.period_ = np.full(w.shape[1], np.inf) if period is None else np.asarray(period, float)
    m.radius_ = radius
    m.witness_ = np.full(len(w), -1)
    return m


# -- Algorithm 1: hand-made cases ------------------------------------------------------------
def test_first_sample_becomes_first_neuron():
    m = UniformPostureMap(radius=1.0, epochs=1).fit([[0.25, -3.0]])
    np.testing.assert_array_equal(m.weights_, [[0.25, -3.0]])
    assert m.hits_.tolist() == [1] and len(m.edges_) == 0
    assert m.witness_.tolist() == [0]


def test_insertion_rule_step_by_step():
    """R=1: [0,0] -> first neuron; [0.5,0] moves it by eta*(x-w); [3,0] is a new neuron, exactly."""
    m = UniformPostureMap(radius=1.0, neighborhood=0, learning_rate=0.5, epochs=1)
    m.fit([[0.0, 0.0]])
    m.partial_fit([[0.5, 0.0]])  # one sample, one epoch: eta is the initial gain 0.5
    np.testing.assert_array_equal(m.weights_, [[0.25, 0.0]])
    m.partial_fit([[3.0, 0.0]])  # 2.75 > R: inserted, nothing else moves
    np.testing.assert_array_equal(m.weights_, [[0.25, 0.0], [3.0, 0.0]])
    m.partial_fit([[3.4, 0.3]])  # within R of neuron 1 only: it alone moves
    np.testing.assert_allclose(m.weights_, [[0.25, 0.0], [3.2, 0.15]], rtol=0, atol=1e-15)
    m.partial_fit([[1.25, 0.0]])  # exactly R from neuron 0: "farther than R" is false, so it moves
    np.testing.assert_allclose(m.weights_, [[0.75, 0.0], [3.2, 0.15]], rtol=0, atol=1e-15)
    assert m.n_neurons == 2


def test_insertion_changes_no_other_neuron():
    rng = np.random.default_rng(5)
    m = UniformPostureMap(radius=0.3, seed=1).fit(rng.uniform(0, 1, (400, 3)))
    before = m.weights_.copy()
    far = np.array([[5.0, 5.0, 5.0]])
    m.partial_fit(far)
    assert m.n_neurons == len(before) + 1
    np.testing.assert_array_equal(m.weights_[:-1], before)  # bit for bit
    np.testing.assert_array_equal(m.weights_[-1], far[0])


def test_fit_order_independent_case_by_hand():
    """Three far-apart clusters of identical samples: any order gives the same map.

    Each cluster's first sample places a neuron at exactly its value; the others coincide
    with it, so eta*(x - w) = 0.
    """
    X = np.repeat([[0.0, 0.0], [3.0, 0.0], [0.0, 3.0]], 4, axis=0)
    for seed in range(4):
        m = UniformPostureMap(radius=1.0, neighborhood=0, epochs=1, seed=seed).fit(X)
        assert sorted(map(tuple, m.weights_)) == [(0.0, 0.0), (0.0, 3.0), (3.0, 0.0)]
        assert m.hits_.tolist() == [4, 4, 4]
        assert m.quantization_error_ == 0.0


def test_two_samples_by_hand_each_order():
    """Samples a=[0], b=[0.6], R=1, eta0=0.5, one epoch: the second seen moves the neuron by
    eta(1) = 0.5 * (1 - 1/2) = 0.25 of the way."""
    X = np.array([[0.0], [0.6]])
    seen = set()
    for seed in range(12):
        w = UniformPostureMap(radius=1.0, neighborhood=0, learning_rate=0.5, epochs=1, seed=seed).fit(X).weights_
        assert w.shape == (1, 1)
        assert w[0, 0] == pytest.approx(0.15) or w[0, 0] == pytest.approx(0.45)
        seen.add(round(float(w[0, 0]), 6))
    assert seen == {0.15, 0.45}  # both orders occur over the seeds


def test_eta_falls_linearly_to_zero_over_epochs():
    """One sample, E epochs: the gains are eta0*(1 - k/E) for k = 0..E-1 (the last above 0)."""
    m = UniformPostureMap(radius=10.0, neighborhood=0, learning_rate=0.5, epochs=1).fit([[0.0]])
    m.epochs = 4
    m.partial_fit([[1.0]])
    w = 0.0
    for k in range(4):
        w += 0.5 * (1 - k / 4) * (1.0 - w)
    assert m.weights_[0, 0] == pytest.approx(w, abs=1e-15)


def test_neighbours_move_with_hop_gain_only_when_within_radius():
    # Two neurons at 0 and 1.5 joined by a consecutive-frame edge (and Hebbian support 2).
    m = UniformPostureMap(radius=1.0, neighborhood=0, learning_rate=0.5, epochs=1).fit(
        [[0.0], [1.5]], sequences=[0, 0])
    assert m.edges_.tolist() == [[0, 1]]
    w0 = {round(float(v), 9) for v in m.weights_[:, 0]}
    assert w0 == {0.0, 1.5}
    i0 = int(np.argmin(m.weights_[:, 0]))
    i1 = 1 - i0
    m.neighborhood = 1
    m.partial_fit([[0.7]])  # winner 0 (0.7 away), neighbour 1 is 0.8 <= R away: moves at half gain
    assert m.weights_[i0, 0] == pytest.approx(0.35, abs=1e-15)
    assert m.weights_[i1, 0] == pytest.approx(1.5 + 0.25 * (0.7 - 1.5), abs=1e-15)
    # A sample within R of the winner but farther than R from its neighbour: the neighbour stays.
    before = m.weights_[i1, 0]
    m.partial_fit([[-0.5]])
    assert m.weights_[i0, 0] == pytest.approx(0.35 + 0.5 * (-0.5 - 0.35), abs=1e-15)
    assert m.weights_[i1, 0] == before


def test_neighbourhood_zero_moves_winner_only():
    m = UniformPostureMap(radius=1.0, neighborhood=0, learning_rate=0.5, epochs=1).fit(
        [[0.0], [1.5]], sequences=[0, 0])
    before = m.weights_.copy()
    m.partial_fit([[0.7]])
    moved = np.flatnonzero(np.any(m.weights_ != before, axis=1))
    assert len(moved) == 1 and before[moved[0], 0] == 0.0


def test_circular_update_takes_short_way():
    """On the circle, a neuron at 350 degrees pulled toward 10 degrees passes through 0."""
    p = [TWO_PI]
    m = UniformPostureMap(radius=np.radians(30), neighborhood=0, learning_rate=0.5, epochs=1, period=p)
    m.fit([[np.radians(350.0)]])
    m.partial_fit([[np.radians(10.0)]])
    assert m.weights_[0, 0] == pytest.approx(0.0, abs=1e-12) or m.weights_[0, 0] == pytest.approx(TWO_PI, abs=1e-12)
    m.partial_fit([[np.radians(20.0)]])
    assert np.degrees(m.weights_[0, 0]) == pytest.approx(10.0, abs=1e-9)
    assert m.n_neurons == 1


def test_circular_weights_stay_below_two_pi():
    # move(): v = 0 + 0.5 * (-8.9e-16); v - p*floor(v/p) rounds to exactly 2*pi. Fix in
    # kernels.move: after wrapping, `if w[k] >= p: w[k] = 0.0`.
    m = UniformPostureMap(radius=1.0, neighborhood=0, epochs=1, period=[TWO_PI]).fit([[0.0]])
    m.partial_fit([[TWO_PI - 1e-15]])
    assert 0.0 <= m.weights_[0, 0] < TWO_PI


# -- Algorithm 1 against the plain-Python reference ------------------------------------------
@pytest.mark.parametrize("case", [
    {"n": 300, "d": 3, "radius": 0.35, "neighborhood": 0, "epochs": 3, "seed": 0},
    {"n": 300, "d": 2, "radius": 0.2, "neighborhood": 2, "epochs": 4, "seed": 1},
    {"n": 250, "d": 4, "radius": 0.6, "neighborhood": 3, "epochs": 2, "seed": 7, "sequences": True},
    {"n": 200, "d": 2, "radius": 0.5, "neighborhood": 2, "epochs": 3, "seed": 3, "circular": True},
])
def test_kernel_matches_reference(case):
    rng = np.random.default_rng(case["seed"] + 100)
    X = rng.uniform(0.0, 2.0, (case["n"], case["d"]))
    period = None
    if case.get("circular"):
        X = rng.uniform(0.0, TWO_PI, (case["n"], case["d"]))
        period = np.full(case["d"], TWO_PI)
    seq = np.repeat(np.arange(case["n"] // 50), 50)[: case["n"]] if case.get("sequences") else None
    if seq is not None:
        X = np.cumsum(rng.normal(0, 0.1, X.shape), axis=0)  # trajectories: consecutive frames close
    m = UniformPostureMap(radius=case["radius"], neighborhood=case["neighborhood"], learning_rate=0.5,
                          epochs=case["epochs"], seed=case["seed"], period=period).fit(X, sequences=seq)
    ref = reference_upm(X, case["radius"], case["neighborhood"], 0.5, case["epochs"], case["seed"], period, seq)
    assert m.n_neurons == len(ref)
    np.testing.assert_allclose(m.weights_, ref, rtol=0, atol=1e-10)


def test_final_graph_by_brute_force():
    rng = np.random.default_rng(11)
    X = np.cumsum(rng.normal(0, 0.05, (600, 2)), axis=0)
    seq = np.repeat(np.arange(6), 100)
    m = UniformPostureMap(radius=0.15, seed=0).fit(X, sequences=seq)
    D = brute_dist(X, m.weights_, m.period_)
    order = np.argsort(D, axis=1, kind="stable")
    win, second = order[:, 0], order[:, 1]
    pairs = {}
    for a, b in zip(win, second):
        key = (min(a, b), max(a, b))
        pairs[key] = pairs.get(key, 0) + 1
    want = {k for k, c in pairs.items() if c >= MIN_EDGE_SUPPORT}
    want |= {(min(win[k], win[k + 1]), max(win[k], win[k + 1])) for k in range(len(X) - 1)
             if seq[k] == seq[k + 1] and win[k] != win[k + 1]}
    assert {tuple(e) for e in m.edges_.tolist()} == want
    assert np.all(m.edges_[:, 0] < m.edges_[:, 1])
    np.testing.assert_array_equal(m.hits_, np.bincount(win, minlength=m.n_neurons))
    assert m.hits_.sum() == len(X)


# -- determinism -----------------------------------------------------------------------------
def test_same_seed_same_map_different_seed_different_map():
    rng = np.random.default_rng(2)
    X = rng.normal(size=(800, 5))
    seq = np.repeat(np.arange(8), 100)
    a = UniformPostureMap(radius=1.2, seed=4).fit(X, sequences=seq)
    b = UniformPostureMap(radius=1.2, seed=4).fit(X.copy(), sequences=seq)
    c = UniformPostureMap(radius=1.2, seed=5).fit(X, sequences=seq)
    np.testing.assert_array_equal(a.weights_, b.weights_)
    np.testing.assert_array_equal(a.edges_, b.edges_)
    np.testing.assert_array_equal(a.hits_, b.hits_)
    assert a.radius_ == b.radius_
    assert a.weights_.shape != c.weights_.shape or not np.array_equal(a.weights_, c.weights_)


def test_fit_does_not_mutate_input():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(200, 3))
    keep = X.copy()
    UniformPostureMap(radius=0.8).fit(X)
    np.testing.assert_array_equal(X, keep)


def test_refit_starts_from_scratch():
    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(200, 2)), rng.normal(size=(200, 2)) + 10
    m = UniformPostureMap(radius=0.8).fit(A)
    m.fit(B)
    fresh = UniformPostureMap(radius=0.8).fit(B)
    np.testing.assert_array_equal(m.weights_, fresh.weights_)


# -- the guarantee: no neuron away from the data ---------------------------------------------
@pytest.mark.parametrize("seed", range(4))
def test_no_invalid_neurons_random_data(seed):
    rng = np.random.default_rng(seed)
    n, d = rng.integers(200, 1200), rng.integers(1, 8)
    X = rng.normal(size=(n, d)) * rng.uniform(0.1, 3.0, d)
    radius = float(rng.uniform(0.2, 1.5))
    m = UniformPostureMap(radius=radius, neighborhood=int(rng.integers(0, 4)), epochs=int(rng.integers(1, 6)),
                          learning_rate=float(rng.uniform(0.05, 0.95)), seed=seed).fit(X)
    assert m.invalid_fraction_ == 0.0
    assert m.invalid_fraction(X) == 0.0
    near = brute_dist(m.weights_, X, m.period_).min(axis=1)
    assert near.max() <= m.radius_ * (1 + 1e-9)
    np.testing.assert_allclose(m.neuron_sample_distance(X), near, rtol=1e-9, atol=1e-12)
    # The witness of each neuron is a training sample within R of it.
    witness_dist = np.linalg.norm(m.weights_ - X[m.witness_], axis=1)
    assert witness_dist.max() <= m.radius_ * (1 + 1e-9)


@pytest.mark.parametrize("make", [ring, c_shape])
def test_no_invalid_neurons_nonconvex(make):
    X = make(seed=1)
    for radius in (0.15, 0.4):
        m = UniformPostureMap(radius=radius, neighborhood=3, seed=0).fit(X)
        assert m.invalid_fraction_ == 0.0
        assert np.linalg.norm(m.weights_ - X[m.witness_], axis=1).max() <= radius * (1 + 1e-9)


def test_no_invalid_neurons_circular():
    rng = np.random.default_rng(9)
    X = np.mod(np.c_[rng.normal(0.0, 0.4, 500), rng.normal(3.0, 0.4, 500)], TWO_PI)
    m = UniformPostureMap(radius=0.3, period=[TWO_PI, TWO_PI], seed=0).fit(X)
    assert m.invalid_fraction_ == 0.0
    near = brute_dist(m.weights_, X, np.full(2, TWO_PI)).min(axis=1)
    assert near.max() <= 0.3 * (1 + 1e-9)


@pytest.mark.parametrize("make", [ring, c_shape])
def test_paper_claim_no_neuron_in_the_hole(make):
    """Section 2: on non-convex data a SOM can place neurons outside the valid space; the UPM
    cannot. Every neuron lies within R of the data and none inside the hole."""
    from scipy.spatial import Delaunay

    X = make(seed=0)
    radius = 0.3
    # The data is genuinely non-convex: points of its convex hull lie far from every sample.
    hull = Delaunay(X)
    holes = np.array([[0.0, 0.0], [0.2, 0.1], [-0.25, -0.1]] + ([[0.6, 0.0]] if make is c_shape else []))
    assert np.all(hull.find_simplex(holes) >= 0)
    assert brute_dist(holes, X, np.full(2, np.inf)).min() > 0.6
    assert np.linalg.norm(X, axis=1).min() >= 1.0 - 1e-9
    for neighborhood in (0, 2, 4):
        m = UniformPostureMap(radius=radius, neighborhood=neighborhood, epochs=6, seed=0).fit(X)
        near = brute_dist(m.weights_, X, m.period_).min(axis=1)
        assert near.max() <= radius * (1 + 1e-9)  # no neuron farther than R from the data
        assert np.linalg.norm(m.weights_, axis=1).min() >= 1.0 - radius  # none deep in the inner disc
        assert brute_dist(holes, m.weights_, m.period_).min() > 0.6 - radius
        assert m.invalid_fraction_ == 0.0
        assert m.n_neurons > 20


def test_classic_som_does_leave_neurons_in_the_hole():
    """The control for the claim: a fixed-grid SOM on the same ring puts neurons in the hole."""
    minisom = pytest.importorskip("minisom")
    X = ring(seed=0)
    som = minisom.MiniSom(15, 15, 2, sigma=3.75, learning_rate=0.5, random_seed=0)
    som.random_weights_init(X)
    som.train_random(X, 10 * len(X))
    w = som.get_weights().reshape(-1, 2)
    near = brute_dist(w, X, np.full(2, np.inf)).min(axis=1)
    assert np.sum(near > 0.2) >= 1
    assert np.linalg.norm(w, axis=1).min() < 1.0 - 0.2


# -- partial_fit -----------------------------------------------------------------------------
def test_partial_fit_grows_map():
    rng = np.random.default_rng(4)
    A = rng.uniform(0, 1, (400, 2))
    B = rng.uniform(0, 1, (400, 2)) + [4.0, 0.0]  # far from everything A placed
    m = UniformPostureMap(radius=0.2, seed=0).fit(A)
    old = m.weights_.copy()
    m.partial_fit(B)
    assert m.n_neurons > len(old)
    np.testing.assert_array_equal(m.weights_[: len(old)], old)  # B is beyond R of all of them
    assert np.all(m.weights_[len(old):, 0] >= 4.0 - 1e-12)
    assert m.radius_ == 0.2
    both = np.concatenate([A, B])
    assert m.invalid_fraction(both) == 0.0
    assert brute_dist(B, m.weights_, m.period_).min(axis=1).max() <= 0.2


def test_partial_fit_near_data_moves_but_keeps_count_low():
    rng = np.random.default_rng(4)
    A = rng.uniform(0, 1, (400, 2))
    m = UniformPostureMap(radius=0.3, seed=0).fit(A)
    n = m.n_neurons
    old = m.weights_.copy()
    m.partial_fit(rng.uniform(0, 1, (400, 2)))
    assert m.n_neurons >= n  # neurons are never removed
    assert np.any(m.weights_[:n] != old)  # old neurons adapt to the new data
    assert m.n_neurons < n + 40


def test_partial_fit_without_fit_is_fit():
    X = np.random.default_rng(0).normal(size=(100, 2))
    a = UniformPostureMap(radius=0.5).partial_fit(X)
    b = UniformPostureMap(radius=0.5).fit(X)
    np.testing.assert_array_equal(a.weights_, b.weights_)


def test_partial_fit_dimension_mismatch():
    m = UniformPostureMap(radius=0.5).fit(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="3 dimensions, the map 2"):
        m.partial_fit(np.zeros((3, 3)))


def test_partial_fit_keeps_old_graph_hits_and_validity():
    # After partial_fit with data far from the old map, the old neurons lose every edge (the
    # graph is rebuilt from the new batch only), their hits drop to 0, witness_ becomes -1
    # and invalid_fraction_ reports them as invalid (0.5 here) although no neuron moved away
    # from its data. Fix: see the report (union old edges, add hits, count only neurons
    # placed/moved in this call as candidates for invalid_fraction_).
    rng = np.random.default_rng(0)
    A = rng.uniform(0, 1, (300, 2))
    B = A + [10.0, 0.0]
    m = UniformPostureMap(radius=0.2, seed=0).fit(A, sequences=np.zeros(300))
    n_old, old_edges, old_hits = m.n_neurons, m.edges_.copy(), m.hits_.copy()
    assert len(old_edges) > n_old
    m.partial_fit(B, sequences=np.zeros(300))
    assert m.invalid_fraction_ == 0.0
    kept = {tuple(e) for e in m.edges_.tolist()}
    assert {tuple(e) for e in old_edges.tolist()} <= kept
    assert m.hits_[:n_old].sum() == old_hits.sum()


# -- predict and quality ---------------------------------------------------------------------
@pytest.mark.parametrize("circular", [False, True])
def test_predict_is_brute_force_winner(circular):
    rng = np.random.default_rng(8)
    period = np.full(3, TWO_PI) if circular else None
    X = rng.uniform(0, TWO_PI, (500, 3))
    m = UniformPostureMap(radius=1.0, seed=0, period=period).fit(X)
    Q = rng.uniform(0, TWO_PI, (300, 3))
    D = brute_dist(Q, m.weights_, m.period_)
    np.testing.assert_array_equal(m.predict(Q), D.argmin(axis=1))
    np.testing.assert_allclose(m.distances(Q), D, rtol=1e-12, atol=1e-12)
    assert m.predict(Q[0]).shape == (1,)  # one sample as a 1-D vector
    np.testing.assert_array_equal(m.predict(m.weights_), np.arange(m.n_neurons))


def test_quantization_and_topographic_error_brute_force():
    X = ring(800, seed=3)
    m = UniformPostureMap(radius=0.25, seed=0).fit(X)
    D = brute_dist(X, m.weights_, m.period_)
    order = np.argsort(D, axis=1)
    qe = D.min(axis=1).mean()
    assert m.quantization_error_ == pytest.approx(qe, rel=1e-9)
    assert m.quantization_error(X) == pytest.approx(qe, rel=1e-9)
    assert 0.0 < qe <= m.radius_  # every sample within R of its winner (Algorithm 1)
    assert D.min(axis=1).max() <= m.radius_ * (1 + 1e-9)
    edges = {tuple(e) for e in m.edges_.tolist()}
    te = np.mean([(min(a, b), max(a, b)) not in edges for a, b in order[:, :2]])
    assert m.topographic_error_ == pytest.approx(te)
    assert m.topographic_error(X) == pytest.approx(te)
    assert 0.0 <= te < 0.5
    # On other data: a query set farther out has a larger error.
    assert m.quantization_error(X * 1.5) > qe


def test_quality_on_hand_made_map():
    m = fitted([[0.0, 0.0], [1.0, 0.0], [5.0, 0.0]], radius=1.0, edges=[[0, 1]])
    X = np.array([[0.1, 0.0], [0.9, 0.0], [4.0, 0.0]])
    assert m.quantization_error(X) == pytest.approx((0.1 + 0.1 + 1.0) / 3)
    # Sample 3's nearest pair (2, 1) has no edge: 1 of 3.
    assert m.topographic_error(X) == pytest.approx(1 / 3)
    assert m.neuron_sample_distance(X).tolist() == pytest.approx([0.1, 0.1, 1.0])
    assert m.invalid_fraction(X) == 0.0
    assert m.invalid_fraction(X[:2]) == pytest.approx(1 / 3)  # neuron 2 is 3.1 from those


def test_single_neuron_quality():
    m = UniformPostureMap(radius=5.0).fit(np.zeros((10, 2)))
    assert m.n_neurons == 1
    assert m.topographic_error_ == 0.0 and m.quantization_error_ == 0.0 and m.invalid_fraction_ == 0.0


# -- radius "auto" ---------------------------------------------------------------------------
def test_auto_radius_is_three_median_nearest_neighbour_distances():
    g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2) * 0.2
    assert auto_radius(g, np.full(2, np.inf)) == pytest.approx(3 * 0.2)
    m = UniformPostureMap().fit(g)
    assert m.radius_ == pytest.approx(0.6)
    assert m.invalid_fraction_ == 0.0
    assert auto_radius(np.zeros((5, 2)), np.full(2, np.inf)) > 0  # identical samples: tiny, positive
    assert 0 < auto_radius(np.zeros((1, 2)), np.full(2, np.inf)) < 1e-3  # one sample: finite
    # Exact copies are no neighbours: the grid listed twice, or every sample doubled (frames
    # doubled to raise the frame rate), keeps its radius instead of collapsing to nothing.
    assert auto_radius(np.concatenate([g, g]), np.full(2, np.inf)) == pytest.approx(3 * 0.2)
    assert auto_radius(np.repeat(g, 2, axis=0), np.full(2, np.inf)) == pytest.approx(3 * 0.2)


def test_auto_radius_scales_with_data():
    X = ring(1000, seed=2)
    r1 = auto_radius(X, np.full(2, np.inf))
    r2 = auto_radius(X * 10, np.full(2, np.inf))
    assert r2 == pytest.approx(10 * r1, rel=1e-9)
    m1 = UniformPostureMap(seed=0).fit(X)
    m2 = UniformPostureMap(seed=0).fit(X * 10)
    assert m1.n_neurons == m2.n_neurons


# -- errors ----------------------------------------------------------------------------------
@pytest.mark.parametrize("X, match", [
    (np.zeros(5), "non-empty 2-D"),
    (np.zeros((0, 3)), "non-empty 2-D"),
    (np.zeros((2, 3, 4)), "non-empty 2-D"),
    (np.array([[0.0, np.nan]]), "NaN or infinite"),
    (np.array([[0.0, np.inf]]), "NaN or infinite"),
])
def test_bad_samples(X, match):
    with pytest.raises(ValueError, match=match):
        UniformPostureMap(radius=1.0).fit(X)


@pytest.mark.parametrize("kwargs, match", [
    ({"learning_rate": 0.0}, "learning_rate must be in"),
    ({"learning_rate": 1.0}, "learning_rate must be in"),
    ({"learning_rate": -0.1}, "learning_rate must be in"),
    ({"learning_rate": float("nan")}, "learning_rate must be in"),
    ({"radius": 0.0}, "radius must be a positive number"),
    ({"radius": -1.0}, "radius must be a positive number"),
    ({"radius": float("nan")}, "radius must be a positive number"),
    ({"radius": float("inf")}, "radius must be a positive number up to 1e\\+06"),
    ({"epochs": 0}, "epochs must be from 1 to 10000"),
    ({"epochs": 10_001}, "epochs must be from 1 to 10000"),
    ({"neighborhood": -1}, "neighborhood from 0 to 1000000"),
    ({"seed": -1}, "seed must be a whole number, not negative"),
    ({"period": [TWO_PI]}, "period must have 2 entries"),
])
def test_bad_parameters(kwargs, match):
    params = {"radius": 1.0}
    params.update(kwargs)
    with pytest.raises(ValueError, match=match):
        UniformPostureMap(**params).fit(np.zeros((4, 2)))


def test_bad_radius_text():
    with pytest.raises(ValueError):
        UniformPostureMap(radius="big").fit(np.zeros((4, 2)))


def test_failed_fit_leaves_no_half_map():
    m = UniformPostureMap(radius=-1.0)
    with pytest.raises(ValueError):
        m.fit(np.zeros((4, 2)))
    assert not hasattr(m, "weights_")
