"""The numba-compiled kernels (cached on disk): UPM training and the per-transition hot path.

Imported only through :func:`posturemap.core.kernels.compiled` (``import posturemap`` does not load
numba). The same maths as :mod:`posturemap.core.kernels`' numpy versions and :mod:`posturemap.core.quat`
(the readable, tested references; the tests cross-check the two), written as loops so that one
transition costs a few microseconds instead of hundreds of numpy dispatches. Quaternions are
(w, x, y, z).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

_OPTS = dict(cache=True, nogil=True, fastmath=False)
# Fast-math without the no-NaN/no-inf assumptions: linear dimensions have period inf.
_FAST = {"nsz", "arcp", "contract", "reassoc"}


@nb.njit(**_OPTS)
def _mul(a0, a1, a2, a3, b0, b1, b2, b3):
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


@nb.njit(**_OPTS)
def _rotate(w, x, y, z, vx, vy, vz):
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx))


@nb.njit(**_OPTS)
def log_relative(q, ref, out):
    """``out[n, j] = log(ref[j]^-1 q[n, j])`` on the short arc; q (N, J, 4), out (N, J, 3)."""
    for n in range(q.shape[0]):
        for j in range(q.shape[1]):
            w, x, y, z = _mul(ref[j, 0], -ref[j, 1], -ref[j, 2], -ref[j, 3],
                              q[n, j, 0], q[n, j, 1], q[n, j, 2], q[n, j, 3])
            if w < 0.0:
                w, x, y, z = -w, -x, -y, -z
            s = math.sqrt(x * x + y * y + z * z)
            if s > 1e-8:
                k = 2.0 * math.atan2(s, w) / s
            else:
                k = 2.0 + s * s / 3.0
            out[n, j, 0] = x * k
            out[n, j, 1] = y * k
            out[n, j, 2] = z * k


@nb.njit(**_OPTS)
def exp_relative(r, ref, out):
    """``out[n, j] = ref[j] exp(r[n, j])``; r (N, J, 3), ref (J, 4), out (N, J, 4)."""
    for n in range(r.shape[0]):
        for j in range(r.shape[1]):
            a = math.sqrt(r[n, j, 0] ** 2 + r[n, j, 1] ** 2 + r[n, j, 2] ** 2)
            if a > 1e-8:
                k = math.sin(0.5 * a) / a
            else:
                k = 0.5 - a * a / 48.0
            w, x, y, z = _mul(ref[j, 0], ref[j, 1], ref[j, 2], ref[j, 3],
                              math.cos(0.5 * a), r[n, j, 0] * k, r[n, j, 1] * k, r[n, j, 2] * k)
            out[n, j, 0] = w
            out[n, j, 1] = x
            out[n, j, 2] = y
            out[n, j, 3] = z


@nb.njit(**_OPTS)
def compose_root(chain, root, up, rots, positions, gpos, heading):
    """Turn tilt + heading + global position into the root's local rotation and position.

    ``rots[n, root]`` holds the tilt on entry; ``chain`` lists the root's ancestors from the
    top (empty for most skeletons). Writes ``rots[n, root]`` and ``positions[n, root]``.
    """
    for n in range(rots.shape[0]):
        h = 0.5 * heading[n]
        hq = [math.cos(h), 0.0, 0.0, 0.0]
        hq[1 + up] = math.sin(h)
        g = _mul(hq[0], hq[1], hq[2], hq[3], rots[n, root, 0], rots[n, root, 1], rots[n, root, 2], rots[n, root, 3])
        px, py, pz = gpos[n, 0], gpos[n, 1], gpos[n, 2]
        if chain.shape[0] > 0:
            c0 = chain[0]
            p = (rots[n, c0, 0], rots[n, c0, 1], rots[n, c0, 2], rots[n, c0, 3])
            ox, oy, oz = positions[n, c0, 0], positions[n, c0, 1], positions[n, c0, 2]
            for i in range(1, chain.shape[0]):
                c = chain[i]
                dx, dy, dz = _rotate(p[0], p[1], p[2], p[3], positions[n, c, 0], positions[n, c, 1], positions[n, c, 2])
                ox, oy, oz = ox + dx, oy + dy, oz + dz
                p = _mul(p[0], p[1], p[2], p[3], rots[n, c, 0], rots[n, c, 1], rots[n, c, 2], rots[n, c, 3])
            g = _mul(p[0], -p[1], -p[2], -p[3], g[0], g[1], g[2], g[3])
            px, py, pz = _rotate(p[0], -p[1], -p[2], -p[3], px - ox, py - oy, pz - oz)
        rots[n, root, 0], rots[n, root, 1], rots[n, root, 2], rots[n, root, 3] = g
        positions[n, root, 0], positions[n, root, 1], positions[n, root, 2] = px, py, pz


@nb.njit(cache=True, nogil=True, fastmath=_FAST)
def _nearest_row(W, x, period, wrap):
    """Index of the row of ``W (n, d)`` nearest ``x (d,)``; with ``wrap``, dimensions wrap at
    ``period`` (inf: linear). Without it the inner loop is a plain squared distance, which
    LLVM vectorises (the branch on ``wrap`` is hoisted out of the loops)."""
    best = np.inf
    best_i = 0
    for i in range(W.shape[0]):
        acc = 0.0
        for k in range(W.shape[1]):
            d = abs(W[i, k] - x[k])
            if wrap:
                d = min(d, period[k] - d)
            acc += d * d
        if acc < best:
            best = acc
            best_i = i
    return best_i


@nb.njit(cache=True, nogil=True, fastmath=_FAST)
def nearest(W, x, period):
    """Index of the row of ``W (n, d)`` nearest ``x (d,)``; ``period`` per dimension (inf: linear)."""
    wrap = False
    for k in range(period.shape[0]):
        if period[k] < np.inf:
            wrap = True
    return _nearest_row(W, x, period, wrap)


# -- Uniform Posture Map training (see posturemap.learn.upm) ------------------------------------
@nb.njit(cache=True, fastmath=_FAST, nogil=True)
def sqdist(x, W, n, period, out):
    d_count = x.shape[0]
    for j in range(n):
        acc = 0.0
        for k in range(d_count):
            d = abs(x[k] - W[j, k])
            d = min(d, period[k] - d)
            acc += d * d
        out[j] = acc

@nb.njit(cache=True, nogil=True)
def move(w, x, gain, period):
    for k in range(x.shape[0]):
        d = x[k] - w[k]
        p = period[k]
        if p < np.inf:
            d -= p * np.floor(d / p + 0.5)
            v = w[k] + gain * d
            v -= p * np.floor(v / p)
            w[k] = v if v < p else 0.0  # [0, p): -1e-16 would round to p
        else:
            w[k] += gain * d

@nb.njit(cache=True, nogil=True)
def upm_epoch(X, order, start, W, n, witness, ptr, idx, period, r2, eta0, step0, total,
          hops, win, second, dist, stamp, queue, qhop):
    """Run samples ``order[start:]``; returns (next start, neuron count, steps done).

    Stops early (next start < len(order)) when the weight array is full.
    """
    cap = W.shape[0]
    n_graph = ptr.shape[0] - 1
    step = step0
    for s in range(start, order.shape[0]):
        if n >= cap:
            return s, n, step - step0
        i = order[s]
        x = X[i]
        eta = eta0 * max(0.0, 1.0 - step / total)
        step += 1
        if n == 0:
            W[0, :] = x
            witness[0] = i
            win[i] = 0
            second[i] = -1
            n = 1
            continue
        sqdist(x, W, n, period, dist)
        b, c = _two_smallest(dist, n)
        if dist[b] > r2:
            W[n, :] = x
            witness[n] = i
            win[i] = n
            second[i] = b
            n += 1
            continue
        win[i] = b
        second[i] = c
        move(W[b], x, eta, period)
        witness[b] = i
        if hops > 0 and b < n_graph:
            # Breadth-first walk over the graph up to `hops` edges from the winner.
            tag = step
            stamp[b] = tag
            head = 0
            tail = 0
            queue[tail] = b
            qhop[tail] = 0
            tail += 1
            while head < tail:
                u = queue[head]
                h = qhop[head]
                head += 1
                if h >= hops or u >= n_graph:
                    continue
                for e in range(ptr[u], ptr[u + 1]):
                    v = idx[e]
                    if stamp[v] == tag:
                        continue
                    stamp[v] = tag
                    queue[tail] = v
                    qhop[tail] = h + 1
                    tail += 1
                    if dist[v] <= r2:  # only neurons that x lies within R of
                        move(W[v], x, eta * (1.0 - (h + 1) / (hops + 1.0)), period)
                        witness[v] = i
    return order.shape[0], n, step - step0


@nb.njit(cache=True, nogil=True)
def _two_smallest(dist, n):
    """Indices of the smallest and second smallest of ``dist[:n]`` (second -1 when n == 1)."""
    b = 0
    c = -1
    for j in range(1, n):
        if dist[j] < dist[b]:
            c = b
            b = j
        elif c < 0 or dist[j] < dist[c]:
            c = j
    return b, c


@nb.njit(cache=True, nogil=True)
def two_nearest(X, W, n, period, win, second, err):
    dist = np.empty(n)
    for i in range(X.shape[0]):
        sqdist(X[i], W, n, period, dist)
        b, c = _two_smallest(dist, n)
        win[i] = b
        second[i] = c
        err[i] = math.sqrt(dist[b])

@nb.njit(cache=True, nogil=True)
def nearest_sample_dist(W, X, period, hint):
    """Distance from each neuron to its nearest sample (starting from a hint sample)."""
    out = np.empty(W.shape[0])
    d_count = W.shape[1]
    for j in range(W.shape[0]):
        best = np.inf
        h = hint[j]
        if h >= 0:
            acc = 0.0
            for k in range(d_count):
                d = abs(X[h, k] - W[j, k])
                d = min(d, period[k] - d)
                acc += d * d
            best = acc
        for i in range(X.shape[0]):
            acc = 0.0
            for k in range(d_count):
                d = abs(X[i, k] - W[j, k])
                d = min(d, period[k] - d)
                acc += d * d
                if acc >= best:
                    break
            if acc < best:
                best = acc
        out[j] = math.sqrt(best)
    return out



@nb.njit(cache=True, nogil=True, fastmath=_FAST)
def nearest_many(W, X, period, out):
    """``out[i]`` = index of the row of ``W (n, d)`` nearest ``X[i]`` (see :func:`nearest`)."""
    for i in range(X.shape[0]):
        out[i] = nearest(W, X[i], period)


@nb.njit(cache=True, nogil=True)
def project_to_map(W, X, period, limit, out, idx):
    """Project each row of ``X (m, d)`` into the union of balls of radius ``limit`` around the
    rows of ``W``: kept where within ``limit`` of its nearest row, else moved onto that ball's
    surface. Writes the results into ``out (m, d)`` and the nearest rows into ``idx (m,)``.
    Periodic dimensions (finite ``period``) are wrapped into [0, period).
    """
    d_count = X.shape[1]
    diff = np.empty(d_count)
    for i in range(X.shape[0]):
        k = nearest(W, X[i], period)
        idx[i] = k
        acc = 0.0
        for j in range(d_count):
            dj = X[i, j] - W[k, j]
            p = period[j]
            if p < np.inf:
                dj -= p * np.floor(dj / p + 0.5)
            diff[j] = dj
            acc += dj * dj
        dist = math.sqrt(acc)
        scale = 1.0 if dist <= limit else limit / dist
        for j in range(d_count):
            v = W[k, j] + diff[j] * scale
            p = period[j]
            if p < np.inf:
                v -= p * np.floor(v / p)
                if v >= p:
                    v = 0.0
            out[i, j] = v


@nb.njit(cache=True, nogil=True, fastmath=_FAST)
def key_from_blend(weights, offsets, counts, dim_index, dim_offsets, blend, key, chosen):
    """The paper's key for all bone classes at once (Euclidean maps).

    Class ``c`` has ``counts[c]`` neurons stored row-major in ``weights`` from ``offsets[c]``,
    over the feature dimensions ``dim_index[dim_offsets[c]:dim_offsets[c + 1]]``. For each class
    the neuron nearest ``blend`` (full feature vector) is found, its index written to
    ``chosen[c]`` and its weights into those dimensions of ``key``.
    """
    q = np.empty(dim_index.shape[0])
    for c in range(counts.shape[0]):
        d0, d1 = dim_offsets[c], dim_offsets[c + 1]
        d = d1 - d0
        for k in range(d):
            q[k] = blend[dim_index[d0 + k]]
        base = offsets[c]
        best = np.inf
        best_i = 0
        for i in range(counts[c]):
            w = weights[base + i * d: base + (i + 1) * d]
            acc = 0.0
            for k in range(d):
                diff = w[k] - q[k]
                acc += diff * diff
            if acc < best:
                best = acc
                best_i = i
        chosen[c] = best_i
        row = base + best_i * d
        for k in range(d):
            key[dim_index[d0 + k]] = weights[row + k]


@nb.njit(**_OPTS)
def fk(parents, rots, positions, grot, gpos):
    """Forward kinematics of (N, J) local rotations/translations into ``grot``/``gpos``.

    Same as :func:`posturemap.core.skeleton.fk` (parents before children, -1 for roots).
    """
    for n in range(rots.shape[0]):
        for j in range(parents.shape[0]):
            p = parents[j]
            if p < 0:
                for k in range(4):
                    grot[n, j, k] = rots[n, j, k]
                for k in range(3):
                    gpos[n, j, k] = positions[n, j, k]
            else:
                w, x, y, z = _mul(grot[n, p, 0], grot[n, p, 1], grot[n, p, 2], grot[n, p, 3],
                                  rots[n, j, 0], rots[n, j, 1], rots[n, j, 2], rots[n, j, 3])
                grot[n, j, 0], grot[n, j, 1], grot[n, j, 2], grot[n, j, 3] = w, x, y, z
                dx, dy, dz = _rotate(grot[n, p, 0], grot[n, p, 1], grot[n, p, 2], grot[n, p, 3],
                                     positions[n, j, 0], positions[n, j, 1], positions[n, j, 2])
                gpos[n, j, 0] = gpos[n, p, 0] + dx
                gpos[n, j, 1] = gpos[n, p, 1] + dy
                gpos[n, j, 2] = gpos[n, p, 2] + dz
