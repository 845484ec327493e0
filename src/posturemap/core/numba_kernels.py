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
_FADE_SPAN = float(np.radians(90.0))  # kernels.FADE_SPAN (slerp_track's fade columns; a test holds them equal)
_REST_RHO, _REST_OVER = 0.3, 1.6  # rest.REST_RHO and REST_OVER (a test holds them equal)


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
def _near_turn(x, y, z, nx, ny, nz):
    """:func:`posturemap.core.quat.near_turn` of one vector: ``(x, y, z)`` plus the whole turns
    about its axis that bring it nearest ``(nx, ny, nz)``."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle <= 1e-12:
        return x, y, z
    turns = np.round(((x * nx + y * ny + z * nz) / angle - angle) / (2.0 * math.pi))
    k = 2.0 * math.pi * turns / angle
    return x + k * x, y + k * y, z + k * z


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


# -- foot lock (see posturemap.synth.feet.lock_feet, the numpy reference) ----------------------------
@nb.njit(**_OPTS)
def _unit(x, y, z):
    n = max(math.sqrt(x * x + y * y + z * z), 1e-12)
    return x / n, y / n, z / n


@nb.njit(**_OPTS)
def _angle(ux, uy, uz, vx, vy, vz):
    """Angle between two vectors (radians), as :func:`posturemap.synth.feet.two_bone_ik` takes it."""
    ux, uy, uz = _unit(ux, uy, uz)
    vx, vy, vz = _unit(vx, vy, vz)
    return math.acos(min(max(ux * vx + uy * vy + uz * vz, -1.0), 1.0))


@nb.njit(**_OPTS)
def _axis_angle_in(q, ax, ay, az, angle):
    """The rotation by ``angle`` about the unit axis (ax, ay, az) given in world space,
    expressed in the local frame of the global rotation ``q`` (a 4-vector)."""
    x, y, z = _rotate(q[0], -q[1], -q[2], -q[3], ax, ay, az)
    h = 0.5 * angle
    s = math.sin(h)
    return math.cos(h), s * x, s * y, s * z


@nb.njit(**_OPTS)
def _soft_limit(x, start, limit):
    """:func:`posturemap.synth.feet.soft_limit` of one value."""
    room = limit - start
    if x > start and room > 0.0:
        return start + room * -math.expm1(-((x - start) / room))
    return x


@nb.njit(**_OPTS)
def _knee_axis(rots, grot, gpos, f, thigh, shin, ankle, weight, hx, hy, hz):
    """:func:`posturemap.synth.feet.knee_axes` of frame ``f``: the knee's plane's normal weighed
    by its sine squared and by its cosine to the hinge (0 from a right angle on), plus
    ``weight`` cubed times the leg's unit hinge (hx, hy, hz) in the hips' frame
    (:func:`_knee_hinge`), each times the leg's size, less the sum's part along the thigh; unit
    (0 for none)."""
    ax, ay, az = gpos[f, thigh, 0], gpos[f, thigh, 1], gpos[f, thigh, 2]
    ux, uy, uz = gpos[f, ankle, 0] - ax, gpos[f, ankle, 1] - ay, gpos[f, ankle, 2] - az
    vx, vy, vz = gpos[f, shin, 0] - ax, gpos[f, shin, 1] - ay, gpos[f, shin, 2] - az
    size = math.sqrt(ux * ux + uy * uy + uz * uz) * math.sqrt(vx * vx + vy * vy + vz * vz)
    fr = _mul(grot[f, thigh, 0], grot[f, thigh, 1], grot[f, thigh, 2], grot[f, thigh, 3],
              rots[f, thigh, 0], -rots[f, thigh, 1], -rots[f, thigh, 2], -rots[f, thigh, 3])
    wx, wy, wz = _rotate(fr[0], fr[1], fr[2], fr[3], hx, hy, hz)  # the hinge in the world
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    sine = length / max(size, 1e-300)
    ux, uy, uz = _unit(nx, ny, nz)
    k = sine * sine * max(ux * wx + uy * wy + uz * wz, 0.0)
    w = weight * weight * weight * size
    nx, ny, nz = nx * k + w * wx, ny * k + w * wy, nz * k + w * wz
    ex, ey, ez = _unit(vx, vy, vz)
    k = nx * ex + ny * ey + nz * ez
    nx, ny, nz = nx - k * ex, ny - k * ey, nz - k * ez
    if math.sqrt(nx * nx + ny * ny + nz * nz) <= 1e-12:
        return 0.0, 0.0, 0.0
    return _unit(nx, ny, nz)


@nb.njit(**_OPTS)
def _knee_angles(gpos, f, thigh, shin, ankle, ex, ey, ez):
    """:func:`posturemap.synth.feet.knee_angles` of frame ``f`` about the unit axis (ex, ey, ez):
    (bend, sideways part)."""
    tx, ty, tz = gpos[f, shin, 0] - gpos[f, thigh, 0], gpos[f, shin, 1] - gpos[f, thigh, 1], \
        gpos[f, shin, 2] - gpos[f, thigh, 2]
    sx, sy, sz = gpos[f, ankle, 0] - gpos[f, shin, 0], gpos[f, ankle, 1] - gpos[f, shin, 1], \
        gpos[f, ankle, 2] - gpos[f, shin, 2]
    across = (sy * tz - sz * ty) * ex + (sz * tx - sx * tz) * ey + (sx * ty - sy * tx) * ez
    se = sx * ex + sy * ey + sz * ez
    along = tx * sx + ty * sy + tz * sz - (tx * ex + ty * ey + tz * ez) * se
    shin_len = max(math.sqrt(sx * sx + sy * sy + sz * sz), 1e-300)
    return math.atan2(across, along), math.asin(min(max(se / shin_len, -1.0), 1.0))


@nb.njit(**_OPTS)
def _signed_bend(theta0, need, through):
    """:func:`posturemap.synth.feet.signed_bend` of one frame (``through``: ``KNEE_THROUGH``)."""
    back = max(-theta0, 0.0)
    if need <= back:
        return -need
    if need >= through * back:
        return need
    return -back + (through + 1.0) / (through - 1.0) * (need - back)


@nb.njit(**_OPTS)
def hinge_ik_frame(rots, grot, gpos, f, thigh, shin, ankle, tx, ty, tz, ex, ey, ez, turn, eps):
    """:func:`posturemap.synth.feet.hinge_ik` for frame ``f``: the knee's bend about the unit axis
    (ex, ey, ez) increased by ``turn``, the leg swung about the hip onto the line to the target
    (tx, ty, tz); the thigh's and shin's new local rotations (``lock_legs`` writes them, and the
    ankle's that keeps the foot's global rotation)."""
    ax, ay, az = gpos[f, thigh, 0], gpos[f, thigh, 1], gpos[f, thigh, 2]
    bx, by, bz = gpos[f, shin, 0], gpos[f, shin, 1], gpos[f, shin, 2]
    cx, cy, cz = gpos[f, ankle, 0], gpos[f, ankle, 1], gpos[f, ankle, 2]
    a_gr = (grot[f, thigh, 0], grot[f, thigh, 1], grot[f, thigh, 2], grot[f, thigh, 3])
    b_gr = (grot[f, shin, 0], grot[f, shin, 1], grot[f, shin, 2], grot[f, shin, 3])
    a_lr = (rots[f, thigh, 0], rots[f, thigh, 1], rots[f, thigh, 2], rots[f, thigh, 3])
    b_lr = (rots[f, shin, 0], rots[f, shin, 1], rots[f, shin, 2], rots[f, shin, 3])
    lab = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2 + (bz - az) ** 2)
    lcb = math.sqrt((cx - bx) ** 2 + (cy - by) ** 2 + (cz - bz) ** 2)
    if min(lab, lcb) <= eps:  # a thigh or shin of no length cannot bend: the leg as it is
        return a_lr, b_lr
    if ex == 0.0 and ey == 0.0 and ez == 0.0:  # no axis: a straight leg, no hinge
        turn = 0.0
    r1 = _axis_angle_in(b_gr, ex, ey, ez, -turn)
    h = -0.5 * turn
    s = math.sin(h)
    dx, dy, dz = _rotate(math.cos(h), s * ex, s * ey, s * ez, cx - bx, cy - by, cz - bz)
    cx, cy, cz = bx + dx, by + dy, bz + dz
    ux, uy, uz = cx - ax, cy - ay, cz - az
    vx, vy, vz = tx - ax, ty - ay, tz - az
    x1, y1, z1 = _unit(uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx)
    r2 = _axis_angle_in(a_gr, x1, y1, z1, _angle(ux, uy, uz, vx, vy, vz))
    th = _mul(a_lr[0], a_lr[1], a_lr[2], a_lr[3], r2[0], r2[1], r2[2], r2[3])
    sh = _mul(b_lr[0], b_lr[1], b_lr[2], b_lr[3], r1[0], r1[1], r1[2], r1[3])
    return th, sh


@nb.njit(**_OPTS)
def _limb_bend(rots, positions, f, joints, first, mid, last, hx, hy, hz):
    """Frame ``f``'s knee bend about the hinge ``(hx, hy, hz)`` of the leg ``joints[first:last]``
    (the shin ``joints[mid - 1]``; :func:`posturemap.synth.hinges.signed_bends` of
    :func:`~posturemap.synth.hinges.leg_vectors`), the rotation to the frame of the shin's parent
    (w, x, y, z), and the thigh's and the shin's vectors in that frame: (bend, parent, tx, ty,
    tz, sx, sy, sz)."""
    q = (1.0, 0.0, 0.0, 0.0)
    parent = q
    px, py, pz = 0.0, 0.0, 0.0
    tx, ty, tz = 0.0, 0.0, 0.0
    for i in range(first, last):
        j = joints[i]
        ox, oy, oz = _rotate(q[0], q[1], q[2], q[3], positions[f, j, 0], positions[f, j, 1], positions[f, j, 2])
        px, py, pz = px + ox, py + oy, pz + oz
        if i < mid:
            parent = q
        if i < last - 1:  # the ankle's own rotation moves nothing above it
            q = _mul(q[0], q[1], q[2], q[3], rots[f, j, 0], rots[f, j, 1], rots[f, j, 2], rots[f, j, 3])
        if i == mid - 1:
            tx, ty, tz = px, py, pz
    # Both in the frame of the shin's parent (hinges.leg_vectors).
    sx, sy, sz = _rotate(parent[0], -parent[1], -parent[2], -parent[3], px - tx, py - ty, pz - tz)
    tx, ty, tz = _rotate(parent[0], -parent[1], -parent[2], -parent[3], tx, ty, tz)
    # The bend about the hinge (hinges.signed_bends).
    across = (sy * tz - sz * ty) * hx + (sz * tx - sx * tz) * hy + (sx * ty - sy * tx) * hz
    along = tx * sx + ty * sy + tz * sz - (tx * hx + ty * hy + tz * hz) * (sx * hx + sy * hy + sz * hz)
    return math.atan2(across, along), parent, tx, ty, tz, sx, sy, sz


@nb.njit(**_OPTS)
def limb_bends(rots, positions, joints, bounds, hinges, out):
    """:func:`posturemap.synth.hinges.bend_frames` (the reference) into ``out`` (N, K): each
    frame's knee bend of each leg of ``bounds`` about its hinge, as :func:`unbend_limbs` reads
    it."""
    for k in range(bounds.shape[0]):
        hx, hy, hz = hinges[k, 0], hinges[k, 1], hinges[k, 2]
        for f in range(rots.shape[0]):
            out[f, k] = _limb_bend(rots, positions, f, joints, bounds[k, 0], bounds[k, 1], bounds[k, 2], hx, hy, hz)[0]


@nb.njit(**_OPTS)
def unbend_limbs(rots, positions, joints, bounds, hinges, leasts, mosts, reach_none, reach_full, accel, passes, plain,
                 relax, exact):
    """:func:`posturemap.synth.hinges.unbend` (the reference) in place: each leg of ``bounds``
    (K, 4; its joints in ``joints``, the shin ``joints[mid - 1]``, the thigh ``bounds[k, 3]``,
    -1 for none to turn) whose knee bends about ``hinges[k]`` (in the frame of the shin's
    parent) further back than ``leasts[k]`` turned about the hinge onto it, and its thigh turned
    to keep the ankle on its line from the hip (the whole way where the ankle is at least
    ``reach_full`` leg lengths from the hip, none within ``reach_none``, a share of the way
    between); one folded further forward than ``mosts[k]`` turned back onto that, its thigh
    left; the bends read unwrapped over the frames. The turn of each leg's frames set off and
    brought to rest within ``accel`` (radians per frame squared; ``inf``: none) by
    :func:`_rest_bounded` (``passes``, ``plain``, ``relax``, ``exact``: ``REST_PASSES``,
    ``REST_PLAIN``, ``REST_RELAX``, ``REST_EXACT``), the bounds kept; a knee turned forward
    turns its thigh. Returns how many knees it turned."""
    n = rots.shape[0]
    change, lo, hi, low, high, bends = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    measured = np.empty(n, dtype=np.bool_)
    turned = 0
    for k in range(bounds.shape[0]):
        first, mid, last, top = bounds[k, 0], bounds[k, 1], bounds[k, 2], bounds[k, 3]
        shin = joints[mid - 1]
        hx, hy, hz = hinges[k, 0], hinges[k, 1], hinges[k, 2]
        seen, prev, fix = False, 0.0, 0.0
        past = False
        for f in range(n):  # the change of each bend that keeps it within both bounds
            bend = _limb_bend(rots, positions, f, joints, first, mid, last, hx, hy, hz)[0]
            measured[f] = bend == bend
            lo[f], hi[f], change[f], bends[f] = -np.inf, np.inf, 0.0, bend
            if not measured[f]:  # NaN: left as it is, as numpy's, and not a step of the unwrapping
                continue
            if seen:  # unwrapped as np.unwrap does it over the measured frames: each step within a half turn
                step = bend - prev
                wrapped = (step + math.pi) % (2.0 * math.pi) - math.pi
                if wrapped == -math.pi and step > 0.0:
                    wrapped = math.pi
                if abs(step) >= math.pi:
                    fix += wrapped - step
            seen, prev = True, bend
            bend += fix
            bends[f] = bend
            if leasts[k] == leasts[k]:  # a NaN bound: none
                lo[f] = leasts[k] - bend
            if mosts[k] == mosts[k]:
                hi[f] = mosts[k] - bend
            change[f] = min(max(0.0, lo[f]), hi[f])
            past = past or change[f] != 0.0
        if not past:
            continue
        if accel < np.inf:  # set off and brought to rest within the bound (hinges.faded)
            _faded(bends, lo, hi, 0.5 * (leasts[k] + mosts[k]), accel, passes, plain, relax, exact, change, low,
                   high)
        for f in range(n):
            if not measured[f]:
                change[f] = 0.0
        for f in range(n):
            if change[f] == 0.0:
                continue
            bend, parent, tx, ty, tz, sx, sy, sz = _limb_bend(rots, positions, f, joints, first, mid, last, hx, hy, hz)
            # The shin turned about the hinge by the change (a turn about +hinge lowers the bend).
            half = -0.5 * change[f]
            c, sn = math.cos(half), math.sin(half)
            rots[f, shin, 0], rots[f, shin, 1], rots[f, shin, 2], rots[f, shin, 3] = _mul(
                c, sn * hx, sn * hy, sn * hz, rots[f, shin, 0], rots[f, shin, 1], rots[f, shin, 2], rots[f, shin, 3])
            turned += 1
            if change[f] < 0.0 or top < 0:  # a folded leg's hip stays; so does one that would move more than the leg
                continue
            # The hip-to-ankle line before and after the shin's turn, in the thigh's frame.
            nx, ny, nz = _rotate(c, sn * hx, sn * hy, sn * hz, sx, sy, sz)
            rx, ry, rz = _rotate(parent[0], parent[1], parent[2], parent[3], tx + sx, ty + sy, tz + sz)
            ux, uy, uz = _rotate(parent[0], parent[1], parent[2], parent[3], tx + nx, ty + ny, tz + nz)
            near, far = math.sqrt(rx * rx + ry * ry + rz * rz), math.sqrt(ux * ux + uy * uy + uz * uz)
            size = math.sqrt(tx * tx + ty * ty + tz * tz) + math.sqrt(sx * sx + sy * sy + sz * sz)
            share = (near / size - reach_none) / (reach_full - reach_none)
            if not share > 0.0:
                continue
            rx, ry, rz, ux, uy, uz = rx / near, ry / near, rz / near, ux / far, uy / far, uz / far
            a0, a1, a2, a3 = _between(ux, uy, uz, rx, ry, rz)
            if share < 1.0:  # a share of the turn (quat.exp of share times quat.log)
                a0, a1, a2, a3 = _turn_share(a0, a1, a2, a3, share)
            rots[f, top, 0], rots[f, top, 1], rots[f, top, 2], rots[f, top, 3] = _mul(
                rots[f, top, 0], rots[f, top, 1], rots[f, top, 2], rots[f, top, 3], a0, a1, a2, a3)
    return turned


@nb.njit(**_OPTS)
def _faded(bends, lo, hi, middle, accel, passes, plain, relax, exact, change, low, high):
    """:func:`posturemap.synth.hinges.faded` (the reference) into ``change`` (L,; on entry the
    change onto the bounds at once, ``lo`` and ``hi`` clipped to 0), ``low`` and ``high`` (L,)
    its scratch: the change moved as little as :func:`_rest_bounded` finds so that the knee's
    second differences stay within ``accel``, or the motion's own where larger and the three
    frames within the range (none where one is not measured), each frame turned toward
    ``middle`` only and no further than a change from rest at either seam reaches; the change
    at once where none is found; turns under 1e-12 radians none."""
    n = bends.shape[0]
    own, bound = np.zeros(n + 2), np.full(n + 2, accel)
    for m in range(2, n):  # the motion's second differences, at the new frames with two new neighbours
        second = bends[m - 2] - 2.0 * bends[m - 1] + bends[m]
        if not math.isfinite(second):  # a frame not measured: no bound there
            bound[m] = np.inf
            continue
        own[m] = second
        if lo[m - 2] <= 0.0 <= hi[m - 2] and lo[m - 1] <= 0.0 <= hi[m - 1] and lo[m] <= 0.0 <= hi[m]:
            bound[m] = max(accel, abs(second))  # within the range: the motion's own where larger
    for f in range(n):
        low[f], high[f] = lo[f], hi[f]
        if bends[f] < middle:
            low[f] = max(lo[f], 0.0)
        elif bends[f] > middle:
            high[f] = min(hi[f], 0.0)
    # The furthest a change from rest at either seam goes (each second difference within its bound).
    up_a, down_a, up_sum, down_sum = 0.0, 0.0, 0.0, 0.0
    for f in range(n):  # from A's side: the second differences up to frame f's
        up_sum += bound[f] - own[f]
        down_sum += bound[f] + own[f]
        up_a += up_sum
        down_a += down_sum
        low[f], high[f] = min(low[f], up_a), max(high[f], -down_a)
    up_b, down_b, up_sum, down_sum = 0.0, 0.0, 0.0, 0.0
    for f in range(n - 1, -1, -1):  # from B's side
        up_sum += bound[f + 2] - own[f + 2]
        down_sum += bound[f + 2] + own[f + 2]
        up_b += up_sum
        down_b += down_sum
        low[f], high[f] = min(low[f], up_b), max(high[f], -down_b)
    hard = change.copy()
    _rest_bounded(change, accel, passes, plain, relax, exact, low, high, own, bound)
    found = True
    for m in range(n + 2):
        found = found and _second_size(change, own, m) <= bound[m] * 1.002
    for f in range(n):
        slack = 2e-3 * abs(change[f]) + 1e-9
        found = found and low[f] - slack <= change[f] <= high[f] + slack
    for f in range(n):
        change[f] = min(max(change[f], lo[f]), hi[f]) if found else hard[f]
        if found and abs(change[f]) < 1e-12:
            change[f] = 0.0


@nb.njit(**_OPTS)
def _turn_share(w, x, y, z, share):
    """The unit rotation ``(w, x, y, z)`` scaled to ``share`` of its angle (short arc), as
    ``quat.exp(share * quat.log(q))``."""
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    angle = 2.0 * math.atan2(s, w)
    scale = angle / s if s > 1e-8 else 2.0 + s * s / 3.0
    rx, ry, rz = share * x * scale, share * y * scale, share * z * scale
    a = math.sqrt(rx * rx + ry * ry + rz * rz)
    k = math.sin(0.5 * a) / a if a > 1e-8 else 0.5 - a * a / 48.0
    return math.cos(0.5 * a), rx * k, ry * k, rz * k


@nb.njit(**_OPTS)
def _between(ax, ay, az, bx, by, bz):
    """:func:`posturemap.core.quat.between` of two unit vectors: the shortest-arc rotation."""
    d = ax * bx + ay * by + az * bz
    if d > -1.0 + 1e-12:
        w, x, y, z = 1.0 + d, ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    elif abs(ax) < 0.9:  # opposite: a half turn about a perpendicular, cross(a, X)
        w, x, y, z = 0.0, 0.0, az, -ay
    else:  # cross(a, Y)
        w, x, y, z = 0.0, -az, 0.0, ax
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    return w / norm, x / norm, y / norm, z / norm


@nb.njit(**_OPTS)
def _knee_hinge(grot, rots, gpos, thigh, shin, ankle, toe, sure, moves):
    """:func:`posturemap.synth.feet.leg_hinge` of the frames the lock moves (``moves`` (L,) bool):
    the leg's hinge in the hips' frame (the thigh's parent's; unit, 0 where the legs are
    straight), the knee's plane normals summed there, each weighed by its sine squared, and,
    where that sum is under ``sure`` (``HINGE_SURE``) of the legs' sizes, turned about where a
    knee bent about it goes away from the toes (``toe``: the toe joint; the ankle for none,
    which leaves it), so that it goes toward them."""
    sx, sy, sz = 0.0, 0.0, 0.0
    sizes = 0.0
    for t in range(gpos.shape[0]):
        if not moves[t]:
            continue
        ux, uy, uz = gpos[t, ankle, 0] - gpos[t, thigh, 0], gpos[t, ankle, 1] - gpos[t, thigh, 1], \
            gpos[t, ankle, 2] - gpos[t, thigh, 2]
        vx, vy, vz = gpos[t, shin, 0] - gpos[t, thigh, 0], gpos[t, shin, 1] - gpos[t, thigh, 1], \
            gpos[t, shin, 2] - gpos[t, thigh, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        size2 = (ux * ux + uy * uy + uz * uz) * (vx * vx + vy * vy + vz * vz)
        sizes += math.sqrt(size2)
        k = (nx * nx + ny * ny + nz * nz) / max(size2, 1e-300)
        q = _mul(grot[t, thigh, 0], grot[t, thigh, 1], grot[t, thigh, 2], grot[t, thigh, 3],
                 rots[t, thigh, 0], -rots[t, thigh, 1], -rots[t, thigh, 2], -rots[t, thigh, 3])
        x, y, z = _rotate(q[0], -q[1], -q[2], -q[3], nx * k, ny * k, nz * k)
        sx, sy, sz = sx + x, sy + y, sz + z
    hx, hy, hz = _unit(sx, sy, sz)
    if toe == ankle or math.sqrt(sx * sx + sy * sy + sz * sz) >= sure * sizes:
        return hx, hy, hz
    ahead = 0.0  # where a knee bent about the hinge goes, against the toes' way from the ankle
    for t in range(gpos.shape[0]):
        if not moves[t]:
            continue
        q = _mul(grot[t, thigh, 0], grot[t, thigh, 1], grot[t, thigh, 2], grot[t, thigh, 3],
                 rots[t, thigh, 0], -rots[t, thigh, 1], -rots[t, thigh, 2], -rots[t, thigh, 3])
        wx, wy, wz = _rotate(q[0], q[1], q[2], q[3], hx, hy, hz)
        ux, uy, uz = gpos[t, ankle, 0] - gpos[t, thigh, 0], gpos[t, ankle, 1] - gpos[t, thigh, 1], \
            gpos[t, ankle, 2] - gpos[t, thigh, 2]
        ahead += (wy * uz - wz * uy) * (gpos[t, toe, 0] - gpos[t, ankle, 0]) \
            + (wz * ux - wx * uz) * (gpos[t, toe, 1] - gpos[t, ankle, 1]) \
            + (wx * uy - wy * ux) * (gpos[t, toe, 2] - gpos[t, ankle, 2])
    if ahead < 0.0:
        return -hx, -hy, -hz
    return hx, hy, hz


@nb.njit(**_OPTS)
def _at(c, t):
    """``c[t]`` within ``c``, 0 outside it (the clips' frames beside the new ones)."""
    return c[t] if 0 <= t < c.shape[0] else 0.0


@nb.njit(**_OPTS)
def _second_size(c, own, m):
    """The size of second difference ``m`` of ``c`` (L,) with two 0 on either side, the motion's
    own (``own`` (L + 2,)) added: centre ``m`` is the frame ``m - 1`` (rest.rest_bounded)."""
    return abs(_at(c, m - 2) - 2.0 * _at(c, m - 1) + _at(c, m) + own[m])


@nb.njit(**_OPTS)
def _within(c, own, bound):
    """Whether every second difference of ``c`` (with the motion's ``own``) is within its
    ``bound`` (L + 2,), to a ten-thousandth (rest.rest_bounded)."""
    for m in range(c.shape[0] + 2):
        if _second_size(c, own, m) - bound[m] > bound[m] * 1e-4:
            return False
    return True


@nb.njit(**_OPTS)
def _rest_bounded(c, accel, passes, plain, relax, exact, lo, hi, own, bound):
    """:func:`posturemap.synth.rest.rest_bounded` in place on ``c`` (L,), each value within ``lo``
    and ``hi`` (L,), the motion's own second differences ``own`` (L + 2,; zeros for none) and the
    bound on each second difference of the sum ``bound`` (L + 2,; ``accel`` each for none): the
    same sweeps, in the same order (``passes``, ``plain``, ``relax``: ``REST_PASSES``,
    ``REST_PLAIN``, ``REST_RELAX``), where they stop short the same projection
    (:func:`_rest_projected`, ``exact``: ``REST_EXACT``), and the same scaling of what is left.
    Centre ``m`` of the second differences is the frame ``m - 2`` of ``c`` (-1: A's last frame,
    ``L``: B's first); values outside ``c`` are the clips', 0."""
    n = c.shape[0]
    first_c = c.copy()
    for sweep in range(passes):
        if _within(c, own, bound):
            break
        lam = 1.0 if sweep < plain else relax
        for first in range(3):
            for m in range(1 + first, n + 3, 3):
                second = _at(c, m - 3) - 2.0 * _at(c, m - 2) + _at(c, m - 1) + own[m - 1]
                excess = abs(second) - bound[m - 1]
                if excess <= 0.0:
                    continue
                norm2 = (1.0 if 0 <= m - 3 < n else 0.0) + (4.0 if 0 <= m - 2 < n else 0.0) \
                    + (1.0 if 0 <= m - 1 < n else 0.0)
                f = lam * (1.0 if second > 0.0 else -1.0) * excess / norm2
                for t, w in ((m - 3, -f), (m - 2, 2.0 * f), (m - 1, -f)):
                    if 0 <= t < n:
                        c[t] = min(max(c[t] + w, lo[t]), hi[t])
    if n == 0 or _within(c, own, bound):
        return
    _rest_projected(first_c, accel, lo, hi, own, bound, exact, c)
    scale = 1.0
    for m in range(n + 2):  # scaled toward 0 (within every bound) until within
        size, ours = _second_size(c, own, m), abs(own[m])
        if size - bound[m] > bound[m] * 1e-4:
            scale = max(min(scale, (bound[m] - ours) / (size - ours)), 0.0)
    if scale < 1.0:
        for t in range(n):
            c[t] *= scale


@nb.njit(**_OPTS)
def _rest_projected(change, accel, lo, hi, own, bound, iters, out):
    """:func:`posturemap.synth.rest.rest_projected` (the reference) into ``out`` (L,): the least
    squares projection of ``change`` onto the bound and the box by ADMM, the pentadiagonal
    ``(1 + r) I + r D'D`` factored here (Cholesky, its three bands); ``own`` (L + 2,) the motion's
    own second differences, ``bound`` (L + 2,) each one's bound (rest.rest_bounded)."""
    n = change.shape[0]
    rho = _REST_RHO / accel
    diag, sub1, sub2 = np.empty(n), np.zeros(n), np.zeros(n)  # L[i, i], L[i, i - 1], L[i, i - 2]
    for i in range(n):
        l2 = rho / diag[i - 2] if i >= 2 else 0.0
        l1 = (-4.0 * rho - (l2 * sub1[i - 1] if i >= 2 else 0.0)) / diag[i - 1] if i >= 1 else 0.0
        sub2[i], sub1[i] = l2, l1
        diag[i] = math.sqrt(1.0 + 7.0 * rho - l1 * l1 - l2 * l2)
    y, u = np.empty(n + 2), np.zeros(n + 2)
    w, v = np.empty(n), np.zeros(n)
    rhs, dc = np.empty(n), np.empty(n + 2)
    for m in range(n + 2):
        second = _at(change, m - 2) - 2.0 * _at(change, m - 1) + _at(change, m)
        y[m] = min(max(second, -bound[m] - own[m]), bound[m] - own[m])
    for t in range(n):
        w[t] = min(max(change[t], lo[t]), hi[t])
        out[t] = change[t]
    for _ in range(iters):
        for t in range(n):  # change + r D'(y - u) + r (w - v)
            rhs[t] = change[t] + rho * ((y[t] - u[t]) - 2.0 * (y[t + 1] - u[t + 1]) + (y[t + 2] - u[t + 2])) \
                + rho * (w[t] - v[t])
        for t in range(n):  # L x = rhs
            x = rhs[t]
            if t >= 1:
                x -= sub1[t] * rhs[t - 1]
            if t >= 2:
                x -= sub2[t] * rhs[t - 2]
            rhs[t] = x / diag[t]
        step = 0.0
        for t in range(n - 1, -1, -1):  # L' out = x
            x = rhs[t]
            if t + 1 < n:
                x -= sub1[t + 1] * out[t + 1]
            if t + 2 < n:
                x -= sub2[t + 2] * out[t + 2]
            step = max(step, abs(x / diag[t] - out[t]))
            out[t] = x / diag[t]
        inside = True
        for m in range(n + 2):
            dc[m] = _at(out, m - 2) - 2.0 * _at(out, m - 1) + _at(out, m)
            inside = inside and abs(dc[m] + own[m]) <= bound[m] * 1.001
            relaxed = _REST_OVER * dc[m] + (1.0 - _REST_OVER) * y[m]
            y_new = min(max(relaxed + u[m], -bound[m] - own[m]), bound[m] - own[m])
            u[m] += relaxed - y_new
            y[m] = y_new
        for t in range(n):
            relaxed = _REST_OVER * out[t] + (1.0 - _REST_OVER) * w[t]
            w_new = min(max(relaxed + v[t], lo[t]), hi[t])
            v[t] += relaxed - w_new
            w[t] = w_new
            inside = inside and lo[t] - 1e-12 <= out[t] <= hi[t] + 1e-12
        if inside and step <= accel * 1e-3:
            break
    for t in range(n):
        out[t] = min(max(out[t], lo[t]), hi[t])


@nb.njit(**_OPTS)
def knee_bounded(goals, gpos, axes, thigh_j, shin_j, ankle_j, soft, through, accel, passes, plain, relax, exact,
                 work, moves):
    """:func:`posturemap.synth.feet.knee_bounded`: ``work[0]`` (L,) the lock's bounded turn of the
    knee about its axis (``axes`` (L, 3), :func:`_knee_axis`) toward the ankle's ``goals`` (L, 3;
    the ankle itself where the lock leaves the leg); the hip, knee and ankle of ``gpos`` (L, J,
    3) at joints ``thigh_j``, ``shin_j``, ``ankle_j``; ``through``: ``KNEE_THROUGH``; ``work``
    (4, L) scratch; ``moves`` (L,) bool, the frames the lock moves, set where the bound moves one
    more."""
    n_l = goals.shape[0]
    for t in range(n_l):
        work[0, t] = 0.0
    for t in range(n_l):  # a rigid leg (feet.IK_EPS): nothing to bend
        thigh = math.sqrt((gpos[t, shin_j, 0] - gpos[t, thigh_j, 0]) ** 2 + (gpos[t, shin_j, 1] - gpos[t, thigh_j, 1]) ** 2
                          + (gpos[t, shin_j, 2] - gpos[t, thigh_j, 2]) ** 2)
        shin = math.sqrt((gpos[t, ankle_j, 0] - gpos[t, shin_j, 0]) ** 2 + (gpos[t, ankle_j, 1] - gpos[t, shin_j, 1]) ** 2
                         + (gpos[t, ankle_j, 2] - gpos[t, shin_j, 2]) ** 2)
        if min(thigh, shin) <= 1e-5:
            return
    # work[0]: the turn, bounded in place; work[1], work[2]: its bounds (the knee no further back
    # than the motion's, nor past pi); work[3]: the turn unbounded.
    for t in range(n_l):
        ax, ay, az = gpos[t, thigh_j, 0], gpos[t, thigh_j, 1], gpos[t, thigh_j, 2]
        thigh = math.sqrt((gpos[t, shin_j, 0] - ax) ** 2 + (gpos[t, shin_j, 1] - ay) ** 2 + (gpos[t, shin_j, 2] - az) ** 2)
        shin = math.sqrt((gpos[t, ankle_j, 0] - gpos[t, shin_j, 0]) ** 2 + (gpos[t, ankle_j, 1] - gpos[t, shin_j, 1]) ** 2
                         + (gpos[t, ankle_j, 2] - gpos[t, shin_j, 2]) ** 2)
        theta0, psi = _knee_angles(gpos, t, thigh_j, shin_j, ankle_j, axes[t, 0], axes[t, 1], axes[t, 2])
        lean = 2.0 * thigh * shin * math.cos(psi)
        full = math.sqrt(max(thigh * thigh + shin * shin + lean, 0.0))
        dist = math.sqrt((goals[t, 0] - ax) ** 2 + (goals[t, 1] - ay) ** 2 + (goals[t, 2] - az) ** 2)
        own = math.sqrt((gpos[t, ankle_j, 0] - ax) ** 2 + (gpos[t, ankle_j, 1] - ay) ** 2
                        + (gpos[t, ankle_j, 2] - az) ** 2)
        if soft > 0.0:
            dist = _soft_limit(dist, max(own, (1.0 - soft) * full), full)
        need = math.acos(min(max((dist * dist - thigh * thigh - shin * shin) / max(lean, 1e-300), -1.0), 1.0))
        work[0, t] = _signed_bend(theta0, need, through) - theta0
        work[1, t], work[2, t] = min(-theta0, 0.0), math.pi - theta0
        work[3, t] = work[0, t]
    _rest_bounded(work[0], accel, passes, plain, relax, exact, work[1], work[2], np.zeros(n_l + 2),
                  np.full(n_l + 2, accel))
    for t in range(n_l):
        if abs(work[0, t] - work[3, t]) > 1e-9:
            moves[t] = True


@nb.njit(**_OPTS)
def _toe_lift(gpos, toe, up, offset, raised, held, toe_floor, clear, clear_lo, clear_hi, curve_v, curve_h, r,
              fade_free, deficit, widest):
    """Add to ``raised`` (L,) the lift that keeps the toe out of the floor and a swinging toe clear
    of it (:func:`posturemap.synth.feet.clearance_lift`, the reference): the toe at ``gpos[:, toe]``
    moved by the ankle's ``offset`` (L, 2) and ``raised``; ``held`` (L,) the frames not free;
    ``curve_v``/``curve_h`` a library's clearance by speed (per frame / length unit; empty: none);
    ``fade_free`` the free frames' fade at the seams (frames); ``deficit`` (2, L) and ``widest``
    scratch: row 0 the free frames' deficits then lift, row 1 the held frames'."""
    n_l = gpos.shape[0]
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    any_deficit = False
    for t in range(n_l):
        deficit[0, t] = 0.0
        deficit[1, t] = 0.0
        need = 0.0  # a held foot's toe (or one frame, without a speed) needs the floor only
        if not held[t] and n_l > 1:
            v = np.inf  # the shorter of the frame's two steps (slower_step)
            for lo in (t - 1, t):
                if 0 <= lo and lo + 1 < n_l:
                    da = gpos[lo + 1, toe, a_] + offset[lo + 1, 0] - gpos[lo, toe, a_] - offset[lo, 0]
                    db = gpos[lo + 1, toe, b_] + offset[lo + 1, 1] - gpos[lo, toe, b_] - offset[lo, 1]
                    v = min(v, math.sqrt(da * da + db * db))
            need = clear * min(max((v - clear_lo) / (clear_hi - clear_lo), 0.0), 1.0)
            if clear > 0.0 and curve_v.shape[0] > 0:
                need = max(need, np.interp(v, curve_v, curve_h))
        short = need - (gpos[t, toe, up] + raised[t] - toe_floor)
        if short > 0.0:
            deficit[1 if held[t] else 0, t] = short
            any_deficit = True
    if not any_deficit:
        return
    width = 2 * r + 1
    for k in range(2):  # free frames: faded over fade_free frames at the seams; held: over 2r + 1
        fade = fade_free if k == 0 else 2.0 * r + 1.0
        for i in range(n_l + 2 * r):
            m = 0.0
            for f in range(i - 2 * r, i + 1):
                if 0 <= f < n_l:
                    m = max(m, deficit[k, f])
            widest[i] = m
        for t in range(n_l):  # widest holds what the row had: the row now takes its lift
            total = 0.0
            for i in range(t, t + width):
                total += widest[i]
            edge = min(min(t + 1, n_l - t) / fade, 1.0)
            deficit[k, t] = total / width * edge * edge * (3.0 - 2.0 * edge)
    for t in range(n_l):
        raised[t] += max(deficit[0, t], deficit[1, t])


@nb.njit(**_OPTS)
def _carried(g, grot, t, top, joint):
    """The new global rotation of ``joint`` (frame ``t``) below ``top``, whose new global rotation
    is ``g`` (a 4-tuple): the joints between keep their local rotations, so ``joint`` turns as
    ``top`` did: ``g grot[top]^-1 grot[joint]``."""
    g = _mul(g[0], g[1], g[2], g[3], grot[t, top, 0], -grot[t, top, 1], -grot[t, top, 2], -grot[t, top, 3])
    return _mul(g[0], g[1], g[2], g[3], grot[t, joint, 0], grot[t, joint, 1], grot[t, joint, 2], grot[t, joint, 3])


@nb.njit(**_OPTS)
def _planted(x, seam, near, leg, up, floor, height_tol, speed_tol):
    """:func:`posturemap.synth.feet._planted` of leg ``leg``'s joint in ``x`` (2, n, 3): frame
    ``seam`` within ``height_tol`` of ``floor``, moved less than ``speed_tol`` horizontally from frame
    ``near``."""
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    da, db = x[seam, leg, a_] - x[near, leg, a_], x[seam, leg, b_] - x[near, leg, b_]
    return x[seam, leg, up] < floor + height_tol and math.sqrt(da * da + db * db) < speed_tol


@nb.njit(**_OPTS)
def _pass_gap(offset, p, q, n_l):
    """How far the offset (L, 2) passes from frame ``p`` to ``q`` (0 at frames -1 and ``n_l``)."""
    pa = offset[p, 0] if p >= 0 else 0.0
    pb = offset[p, 1] if p >= 0 else 0.0
    qa = offset[q, 0] if q < n_l else 0.0
    qb = offset[q, 1] if q < n_l else 0.0
    return math.sqrt((qa - pa) ** 2 + (qb - pb) ** 2)


@nb.njit(**_OPTS)
def _pass_second(wa, wb, rpa, rpb, rqa, rqb, span, window, s, side):
    """The norm of the second derivative of :func:`posturemap.synth.feet.swing_offsets`' curve at
    ``s`` frames into a stretch of ``span`` (its rates' windows taken as just after ``s``, side 1,
    or just before, -1); 0 outside the stretch (``feet.pass_accel``)."""
    if not 0.0 < s + 0.5 * side < span:
        return 0.0
    k = (6.0 - 12.0 * s / span) / (span * span)
    oa, ob = wa * k, wb * k
    if s + 0.5 * side < window:
        k = (6.0 * s / window - 4.0) / window
        oa += rpa * k
        ob += rpb * k
    if s + 0.5 * side > span - window:
        k = (6.0 * (1.0 - (span - s) / window) - 2.0) / window
        oa += rqa * k
        ob += rqb * k
    return math.sqrt(oa * oa + ob * ob)


@nb.njit(**_OPTS)
def _pass_accel(offset, p, q, lo, hi, n_l, carry):
    """:func:`posturemap.synth.feet.pass_accel` of the pass from frame ``p`` (its run from ``lo``)
    to ``q`` (its run to ``hi``) of ``offset`` (L, 2): the runs' rates where they hold two frames,
    carried ``carry`` frames at most."""
    pa = offset[p, 0] if p >= 0 else 0.0
    pb = offset[p, 1] if p >= 0 else 0.0
    qa = offset[q, 0] if q < n_l else 0.0
    qb = offset[q, 1] if q < n_l else 0.0
    rpa = offset[p, 0] - offset[p - 1, 0] if p - 1 >= lo else 0.0
    rpb = offset[p, 1] - offset[p - 1, 1] if p - 1 >= lo else 0.0
    rqa = offset[q + 1, 0] - offset[q, 0] if q + 1 < hi else 0.0
    rqb = offset[q + 1, 1] - offset[q, 1] if q + 1 < hi else 0.0
    span = float(q - p)
    window = float(max(min(carry, q - p), 1))
    out = 0.0
    for s, side in ((0.0, 1), (span, -1), (window, -1), (window, 1), (span - window, -1), (span - window, 1)):
        out = max(out, _pass_second(qa - pa, qb - pb, rpa, rpb, rqa, rqb, span, window, s, side))
    return out


@nb.njit(**_OPTS)
def _step_high(k, way, lift, stand, rise, accel):
    """The height of :func:`posturemap.synth.feet.step_lift`'s squared sine over ``k`` frames."""
    return min(lift, rise * max(way - stand, 0.0), accel * (k + 1.0) ** 2 / (2.0 * math.pi**2))


@nb.njit(**_OPTS)
def _pace_passes(on, weight, offset, raised, gpos, ankle, up, a_foot, b_foot, pace, lift, stand, rise, accel, least,
                 carry):
    """:func:`posturemap.synth.feet.pace_passes` of one leg: ``on`` (L,) its held frames,
    ``weight``, ``offset`` (L, 2), ``raised`` in place; the ankle's height and way from ``gpos``,
    A's last frame's and B's first's ankle ``a_foot``, ``b_foot`` (3,)."""
    n_l = on.shape[0]
    if n_l == 0 or pace <= 0.0:
        return
    # The runs [start, stop) and their first lengths; the first stretches (p, q) between them.
    n_r = 0
    starts = np.empty(n_l, dtype=np.int64)
    stops = np.empty(n_l, dtype=np.int64)
    t = 0
    while t < n_l:
        if on[t]:
            s = t
            while t < n_l and on[t]:
                t += 1
            starts[n_r], stops[n_r] = s, t
            n_r += 1
        else:
            t += 1
    orig_starts = starts[:n_r].copy()
    orig_stops = stops[:n_r].copy()
    lengths = orig_stops - orig_starts
    given = weight.copy()
    first_p = np.empty(n_r + 1, dtype=np.int64)
    first_q = np.empty(n_r + 1, dtype=np.int64)
    for i in range(n_r + 1):
        first_p[i] = orig_stops[i - 1] - 1 if i > 0 else -1
        first_q[i] = orig_starts[i] if i < n_r else n_l
    keep = np.ones(n_r, dtype=np.bool_)
    while True:
        # From the runs as they came, less those let go whole (feet.pace_passes).
        for i in range(n_r):
            starts[i], stops[i] = orig_starts[i], orig_stops[i]
            for f in range(orig_starts[i], orig_stops[i]):
                on[f] = keep[i]
                weight[f] = given[f] if keep[i] else 0.0
        widened = True
        while widened:  # until no stretch widens (feet.pace_passes)
            widened = False
            prev = -1  # the run before the stretch (index), -1 for A's seam
            for i in range(n_r + 1):
                if i < n_r and not keep[i]:
                    continue
                p = stops[prev] - 1 if prev >= 0 else -1
                q = starts[i] if i < n_r else n_l
                while True:
                    d = _pass_gap(offset, p, q, n_l)
                    lo = starts[prev] if prev >= 0 else 0
                    hi = stops[i] if i < n_r else n_l
                    if q - p >= d / pace and (q - p < 2 or _pass_accel(offset, p, q, lo, hi, n_l, carry) <= accel):
                        break
                    left = p - starts[prev] if prev >= 0 else 0
                    right = stops[i] - 1 - q if i < n_r else 0
                    if left <= 0 and right <= 0:
                        break
                    widened = True
                    if left >= right:
                        on[p] = False
                        weight[p] = 0.0
                        p -= 1
                    else:
                        on[q] = False
                        weight[q] = 0.0
                        q += 1
                if prev >= 0:
                    stops[prev] = p + 1
                if i < n_r:
                    starts[i] = q
                prev = i
        short = -1  # the shortest as it came of the runs left too short, the first on a tie
        for i in range(n_r):
            if keep[i] and stops[i] - starts[i] < min(least, lengths[i]) and (short < 0 or lengths[i] < lengths[short]):
                short = i
        if short < 0:
            break
        keep[short] = False
    prev = -1
    for i in range(n_r + 1):
        if i < n_r and not keep[i]:
            continue
        p = stops[prev] - 1 if prev >= 0 else -1
        q = starts[i] if i < n_r else n_l
        prev = i
        same = False
        for k in range(n_r + 1):
            if first_p[k] == p and first_q[k] == q:
                same = True
        if same:
            continue
        # The foot's own way between the two held frames: the motion's, with the offsets', over
        # a stretch of carry frames at most (feet.pace_passes).
        d = _pass_gap(offset, p, q, n_l)
        if q - p <= carry:
            a_, b_ = (up + 1) % 3, (up + 2) % 3
            qa, qb = (gpos[q, ankle, a_], gpos[q, ankle, b_]) if q < n_l else (b_foot[a_], b_foot[b_])
            pa, pb = (gpos[p, ankle, a_], gpos[p, ankle, b_]) if p >= 0 else (a_foot[a_], a_foot[b_])
            wa, wb = qa - pa, qb - pb
            if q < n_l:
                wa, wb = wa + offset[q, 0], wb + offset[q, 1]
            if p >= 0:
                wa, wb = wa - offset[p, 0], wb - offset[p, 1]
            d = math.sqrt(wa * wa + wb * wb)
        high = _step_high(q - p - 1, d, lift, stand, rise, accel)
        hp = gpos[p, ankle, up] if p >= 0 else gpos[0, ankle, up]
        hq = gpos[q, ankle, up] if q < n_l else gpos[n_l - 1, ankle, up]
        base = min(hp, hq)
        for f in range(p + 1, q):
            u = (f - p) / float(q - p)
            raised[f] = max(raised[f], high * math.sin(math.pi * u) ** 2 - max(gpos[f, ankle, up] - base, 0.0))


@nb.njit(**_OPTS)
def _from_seam(i, side, n_l):
    """The new frame ``i`` frames from a seam: from A's end (side 0) or back from B's start (1)."""
    return i if side == 0 else n_l - 1 - i


@nb.njit(**_OPTS)
def _stance_windows(moves, length, step, least):
    """:func:`posturemap.synth.feet.stance_windows`: (n, 2) ``(k0, k)`` per leg, -1 for none."""
    n = moves.shape[0]
    out = np.full((n, 2), -1, dtype=np.int64)
    order = np.empty(n, dtype=np.int64)
    parts = 0
    for i in range(n):
        if moves[i] > least:  # NaN: not standing
            j = parts  # insertion by distance, farthest first, the lower index on a tie
            while j > 0 and moves[order[j - 1]] < moves[i]:
                order[j] = order[j - 1]
                j -= 1
            order[j] = i
            parts += 1
    if parts < 2 or length // parts < 3:
        return out
    for r in range(parts):
        lo, hi = r * length // parts, (r + 1) * length // parts
        k = max(0, min(step, hi - lo))
        out[order[r], 0] = lo + (hi - lo - k) // 2
        out[order[r], 1] = k
    return out


@nb.njit(**_OPTS)
def lock_legs(parents, legs, rots, grot, gpos, up, a_feet, b_feet, body, height_tol, speed_tol, contacts,
              drift_lo, drift_hi, eps, soft, hinge, step, lift, step_lag, toes, toe_floor, clear, clear_lo, clear_hi,
              curve_v, curve_h, clear_r, clear_fade, a_floor, b_floor, stand, rise, farthest, a_toes, b_toes, toe_most,
              toe_gap, toe_catch, pace, accel, least, carry, hinge_sure, knee_through, knee_accel, knee_passes,
              knee_plain, knee_relax, knee_exact, weights):
    """The whole of :func:`posturemap.synth.feet.lock_feet` after its forward kinematics, every leg.

    legs (n, 3) thigh, shin and ankle joints; rots (L, J, 4) local rotations, changed in place;
    grot/gpos (L, J, 4/3) their global rotations and positions; a_feet/b_feet (2, n, 3) ankle
    positions in A's last two and B's first two frames; contacts (L, n) planted frames, or an
    array with no rows to detect them from height and speed; drift_lo/drift_hi, eps, soft and
    hinge: ``MAX_DRIFT``, ``IK_EPS``, ``SOFT_REACH`` and ``KNEE_HINGE`` of
    :mod:`posturemap.synth.feet`; step (frames)
    and lift (length unit): the step between two spots of one run (A's and B's, or a seam's and
    where the foot lands or lifts off far from it) and the frames let go at a seam whose foot moves,
    step_lag the share of a step's frames at each end where the foot rises or comes down in place
    (``STEP_LAG``; less where the step would set the foot off faster than accel:
    ``posturemap.synth.feet.step_lag``); toes (n,) each leg's toe joint (the ankle: none) and toe_floor the toes'
    lowest in the context (inf: none; see :func:`posturemap.synth.feet.lock_feet` for the floor);
    clear (length unit), clear_lo/clear_hi (length unit per frame), curve_v/curve_h (length unit
    per frame / length unit: a library's clearance by speed, empty for none) and clear_r (frames):
    the swinging toe's clearance (``TOE_CLEAR``, ``CLEAR_SPEED``, ``CLEAR_S`` of
    :mod:`posturemap.synth.feet`, :func:`posturemap.synth.feet.clearance_lift`), clear_fade (frames)
    its fade at the seams (``CLEAR_FADE_S``); a_floor and
    b_floor: the floors of the seams' planted test (NaN: each leg's lowest ankle in its seam
    frames and the new frames); stand (length unit): ``STAND_STEP`` of a leg, from which
    feet planted at both seams (spots at most ``drift_hi`` legs apart) that contacts hold all
    through, or without contacts whose motion keeps the ankle under ``lift`` above its floor and
    within ``drift_lo`` legs of the line between them, step one after another
    (:func:`posturemap.synth.feet.stance_windows`), and beyond which a step lifts the foot (by
    rise times the rest of its way: ``posturemap.synth.feet.step_rise`` of the gap, ``lift`` at
    most); farthest (length unit): ``STEP_MOST`` of a leg, beyond which a run planted at both
    seams on spots that far apart is not held; weights (L, n) out.
    A run held on one seam's spot steps where the foot's other end lies farther than
    ``drift_lo * body`` (``lock_weights_and_targets``' reach). a_toes/b_toes (2, n, 3): the toes in
    A's last two and B's first two frames, or an array with no rows for none; a toe planted at a
    seam whose foot no run holds there (or a run of at most clear_fade frames, then from where it
    leaves the toe) stays on its spot while the new frames keep it low, at most
    toe_most frames and ``(L - toe_gap) // 2``, toe_gap frames free before a held one, and no
    longer than lets its offset pass on to the next held frame's at toe_catch per frame (length
    unit; ``SEAM_TOE_S``, ``SEAM_TOE_GAP``, ``SEAM_TOE_CATCH``; ``posturemap.synth.feet._hold_seam_toes``).
    pace (length unit per frame): the fastest a held foot's offset passes between two runs on
    average (``PASS_SPEED``), accel (per frame squared) its peak acceleration at most
    (``PASS_ACCEL``) and least (frames) the shortest run the widening leaves (``PASS_LEAST_S``;
    ``posturemap.synth.feet.pace_passes``); carry (frames): how long a run's rate is carried into
    the free frames at most (``CARRY_S``; ``posturemap.synth.feet.swing_offsets``). hinge_sure:
    ``HINGE_SURE`` (:func:`_knee_hinge`); knee_through: ``KNEE_THROUGH`` (:func:`_signed_bend`);
    knee_accel (radians per frame squared), knee_passes, knee_plain, knee_relax and knee_exact:
    the bound on the lock's turn of the knees about their
    axes, its sweeps and the projection where they stop short (``KNEE_ACCEL``, ``REST_PASSES``,
    ``REST_PLAIN``, ``REST_RELAX``, ``REST_EXACT``; :func:`knee_bounded`); the IK
    (:func:`hinge_ik_frame`) then turns each knee so and swings the leg onto its goal's line.
    """
    n_l, n_legs = rots.shape[0], legs.shape[0]
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    reach = drift_lo * body
    # Each leg's floor and whether it is planted at A's end and at B's start; the interpolated
    # legs planted at both (no contacts given) are held through and step once, one after another.
    floors = np.empty(n_legs)
    a_ons = np.empty(n_legs, dtype=np.bool_)
    b_ons = np.empty(n_legs, dtype=np.bool_)
    moves = np.full(n_legs, np.nan)
    for leg in range(n_legs):
        ankle = legs[leg, 2]
        floor = min(min(a_feet[0, leg, up], a_feet[1, leg, up]), min(b_feet[0, leg, up], b_feet[1, leg, up]))
        for t in range(n_l):
            floor = min(floor, gpos[t, ankle, up])
        fa = floor if math.isnan(a_floor) else a_floor
        fb = floor if math.isnan(b_floor) else b_floor
        a_ons[leg] = _planted(a_feet, 1, 0, leg, up, fa, height_tol, speed_tol)
        b_ons[leg] = _planted(b_feet, 0, 1, leg, up, fb, height_tol, speed_tol)
        floors[leg] = floor
        da, db = b_feet[0, leg, a_] - a_feet[1, leg, a_], b_feet[0, leg, b_] - a_feet[1, leg, b_]
        move = math.sqrt(da * da + db * db)
        if not (a_ons[leg] and b_ons[leg] and move <= drift_hi * body):  # one step's way at most
            continue
        if contacts.shape[0] > 0:  # a foot the retrieved segment holds all through
            if contacts[:, leg].all():
                moves[leg] = move
        else:
            # Only a foot the motion glides: under a step's lift, near the line between the spots.
            glides = n_l > 0
            dd = max(da * da + db * db, 1e-300)
            for t in range(n_l):
                pa, pb = gpos[t, ankle, a_] - a_feet[1, leg, a_], gpos[t, ankle, b_] - a_feet[1, leg, b_]
                u = min(max((pa * da + pb * db) / dd, 0.0), 1.0)
                if (gpos[t, ankle, up] >= floor + lift
                        or math.sqrt((pa - u * da) ** 2 + (pb - u * db) ** 2) > reach):
                    glides = False
                    break
            if glides:
                moves[leg] = move
    windows = _stance_windows(moves, n_l, step, stand)
    on_all = np.empty((n_legs, n_l), dtype=np.bool_)
    weight = np.empty(n_l)
    target = np.empty((n_l, 2))  # the horizontal coordinates (a_, b_) of each frame's spot
    offset_all = np.empty((n_legs, n_l, 2))  # the ankle's horizontal correction (posturemap.synth.feet.swing_offsets)
    raised_all = np.empty((n_legs, n_l))  # the step's lift, then also the swinging toe's
    deficit = np.empty((2, n_l))  # the toe's shortfall below its clearance: free frames, held frames
    widest = np.empty(n_l + 2 * clear_r)  # the largest deficit within clear_r of frame i - clear_r
    goals = np.empty((n_l, 3))  # the ankle's goals, every frame
    ik = np.empty(n_l, dtype=np.bool_)  # the frames the IK moves
    knee_work = np.empty((4, n_l))  # knee_bounded's scratch; row 0 the knee's turns
    axes = np.empty((n_l, 3))  # each frame's knee axis (_knee_axis)
    for leg in range(n_legs):
        on, offset, raised = on_all[leg], offset_all[leg], raised_all[leg]
        thigh, shin, ankle = legs[leg, 0], legs[leg, 1], legs[leg, 2]
        floor, a_on, b_on = floors[leg], a_ons[leg], b_ons[leg]
        if contacts.shape[0] > 0:
            for t in range(n_l):
                on[t] = contacts[t, leg]
        elif not math.isnan(moves[leg]):  # held through, one step
            on[:] = True
        else:
            pa, pb = a_feet[1, leg, a_], a_feet[1, leg, b_]
            for t in range(n_l):
                ha, hb = gpos[t, ankle, a_], gpos[t, ankle, b_]
                speed = math.sqrt((ha - pa) ** 2 + (hb - pb) ** 2)
                on[t] = gpos[t, ankle, up] < floor + height_tol and speed < speed_tol
                pa, pb = ha, hb
        # A run at a seam where that clip's foot is not planted would jump: let go there.
        first_stop = 0
        while first_stop < n_l and on[first_stop]:
            first_stop += 1
        if first_stop > 0 and not a_on:
            on[:step if 0 < step <= first_stop - 2 else first_stop] = False
        last_start = n_l
        while last_start > 0 and on[last_start - 1]:
            last_start -= 1
        if last_start < n_l and not b_on:
            on[n_l - step if 0 < step <= n_l - last_start - 2 else last_start:] = False
        # Lock weights and targets (posturemap.synth.feet.lock_weights_and_targets).
        for t in range(n_l):
            weight[t] = 0.0
            raised[t] = 0.0
            target[t, 0], target[t, 1] = gpos[t, ankle, a_], gpos[t, ankle, b_]
        t = 0
        while t < n_l:
            if not on[t]:
                t += 1
                continue
            start = t
            while t < n_l and on[t]:
                t += 1
            stop = t
            from_a = start == 0 and a_on
            to_b = stop == n_l and b_on
            n = stop - start
            k = max(0, min(step, n - 2))  # the first spot, the step over k frames in the middle, the last
            k0 = (n - k) // 2
            if from_a and to_b and windows[leg, 0] >= 0:  # a standing foot's own part of the gap
                k0, k = windows[leg, 0], windows[leg, 1]
            xa, xb = a_feet[1, leg, a_], a_feet[1, leg, b_]
            ya, yb = b_feet[0, leg, a_], b_feet[0, leg, b_]
            if from_a and to_b and math.sqrt((ya - xa) ** 2 + (yb - xb) ** 2) > farthest:
                on[start:stop] = False  # no step makes it: the motion's own foot, not held (feet.STEP_MOST)
                continue
            # A run on one seam's spot steps where the foot's other end lies beyond the drift.
            stepping = from_a and to_b
            if not stepping and 0 < step <= n - 2 and (from_a or to_b):
                f = stop - 1 if from_a else start
                ea, eb = gpos[f, ankle, a_], gpos[f, ankle, b_]
                far = (math.sqrt((ea - xa) ** 2 + (eb - xb) ** 2) if from_a
                       else math.sqrt((ya - ea) ** 2 + (yb - eb) ** 2))
                if from_a and far > reach:  # the lift-off moved toward A's spot by reach
                    ya, yb, stepping = ea + (xa - ea) * (reach / far), eb + (xb - eb) * (reach / far), True
                elif to_b and far > reach:  # the landing moved toward B's spot by reach
                    xa, xb, stepping = ea + (ya - ea) * (reach / far), eb + (yb - eb) * (reach / far), True
            way = math.sqrt((ya - xa) ** 2 + (yb - xb) ** 2)
            high = _step_high(k, way, lift, stand, rise, accel)
            lag = step_lag  # less where the step is too quick for it (feet.step_lag)
            if k > 0 and way > 0.0 and accel < np.inf:
                lag = min(max(0.5 * (1.0 - math.sqrt(6.0 * way / accel) / (k + 1.0)), 0.0), step_lag)
            mid = (start + stop - 1) // 2
            ma, mb = gpos[mid, ankle, a_], gpos[mid, ankle, b_]
            # The foot turns about its toe, held where it was at the spot's frame: the toe's place
            # about the ankle at a seam's run's first and last frames (its reference moves between
            # them as the spot does), or at the middle of a run on its own.
            toe = toes[leg]
            f0, f1 = (start, stop - 1) if from_a or to_b else (mid, mid)
            ra0, rb0 = gpos[f0, toe, a_] - gpos[f0, ankle, a_], gpos[f0, toe, b_] - gpos[f0, ankle, b_]
            ra1, rb1 = gpos[f1, toe, a_] - gpos[f1, ankle, a_], gpos[f1, toe, b_] - gpos[f1, ankle, b_]
            for u in range(start, stop):
                i = u - start
                if stepping:
                    if i >= k0 + k:
                        sa, sb, ref = ya, yb, 1.0
                    elif i < k0:
                        sa, sb, ref = xa, xb, 0.0
                    else:
                        uu = (i - k0 + 1) / (k + 1.0)
                        vv = min(max((uu - lag) / (1.0 - 2.0 * lag), 0.0), 1.0)
                        ss = vv * vv * (3.0 - 2.0 * vv)
                        sa, sb, ref = xa + ss * (ya - xa), xb + ss * (yb - xb), ss
                        raised[u] = high * math.sin(math.pi * uu) ** 2
                elif from_a:
                    sa, sb, ref = xa, xb, 0.0
                elif to_b:
                    sa, sb, ref = ya, yb, 1.0
                else:
                    sa, sb, ref = ma, mb, 0.0
                weight[u] = 1.0
                ta = gpos[u, toe, a_] - gpos[u, ankle, a_] - (ra0 + ref * (ra1 - ra0))
                tb = gpos[u, toe, b_] - gpos[u, ankle, b_] - (rb0 + ref * (rb1 - rb0))
                target[u, 0], target[u, 1] = sa - ta, sb - tb
        # A toe planted at a seam whose foot no run holds there stays on its spot while the new
        # frames keep it low (posturemap.synth.feet._hold_seam_toes): A's first, then B's.
        if a_toes.shape[0] == 2 and n_l > 0:
            toe = toes[leg]
            tf = toe_floor
            if tf == np.inf:
                tf = min(min(a_toes[0, leg, up], a_toes[1, leg, up]), min(b_toes[0, leg, up], b_toes[1, leg, up]))
            for side in range(2):
                if side == 0:
                    planted = _planted(a_toes, 1, 0, leg, up, tf, height_tol, speed_tol)
                    sa, sb = a_toes[1, leg, a_], a_toes[1, leg, b_]
                else:
                    planted = _planted(b_toes, 0, 1, leg, up, tf, height_tol, speed_tol)
                    sa, sb = b_toes[0, leg, a_], b_toes[0, leg, b_]
                if not planted:
                    continue
                n0 = 0  # the frames a run holds from the seam: the toe stays where the run leaves it
                while n0 < n_l and on[_from_seam(n0, side, n_l)]:
                    n0 += 1
                if n0 == n_l or n0 > clear_fade:  # after a longer run the lift is not cut short at the seam
                    continue
                if n0 > 0:
                    f = _from_seam(n0 - 1, side, n_l)
                    sa = target[f, 0] + gpos[f, toe, a_] - gpos[f, ankle, a_]
                    sb = target[f, 1] + gpos[f, toe, b_] - gpos[f, ankle, b_]
                n = n0
                while n < min(n0 + toe_most, (n_l - toe_gap) // 2):
                    f = _from_seam(n, side, n_l)
                    if on[f] or gpos[f, toe, up] >= tf + height_tol:
                        break
                    n += 1
                after = n_l  # the next frame held already (n_l: the other seam, where the offset is 0)
                for i in range(n0, n_l):
                    f = _from_seam(i, side, n_l)
                    if on[f]:
                        after = i
                        break
                n = min(n, max(after - toe_gap, n0))  # toe_gap frames free before it
                ga, gb = 0.0, 0.0
                if after < n_l:
                    f = _from_seam(after, side, n_l)
                    ga, gb = target[f, 0] - gpos[f, ankle, a_], target[f, 1] - gpos[f, ankle, b_]
                while n > n0:  # the offset passes on to that frame's at most toe_catch per frame
                    f = _from_seam(n - 1, side, n_l)
                    oa, ob = sa - gpos[f, toe, a_] - ga, sb - gpos[f, toe, b_] - gb
                    if math.sqrt(oa * oa + ob * ob) <= toe_catch * (after - n + 1):
                        break
                    n -= 1
                for i in range(n0, n):
                    f = _from_seam(i, side, n_l)
                    on[f] = True
                    weight[f] = 1.0
                    target[f, 0] = sa - (gpos[f, toe, a_] - gpos[f, ankle, a_])
                    target[f, 1] = sb - (gpos[f, toe, b_] - gpos[f, ankle, b_])
        # The runs' offsets, softly limited where the spot is far from the foot.
        for t in range(n_l):
            offset[t, 0] = target[t, 0] - gpos[t, ankle, a_]
            offset[t, 1] = target[t, 1] - gpos[t, ankle, b_]
            far = math.sqrt(offset[t, 0] ** 2 + offset[t, 1] ** 2) / body
            if on[t] and far > 0.0:
                scale = _soft_limit(far, drift_lo, drift_hi) / far
                weight[t] *= scale
                offset[t, 0] *= scale
                offset[t, 1] *= scale
                raised[t] *= scale
        # Stretches too short for the offset to pass at ``pace`` widened (feet.pace_passes).
        _pace_passes(on, weight, offset, raised, gpos, ankle, up, a_feet[1, leg], b_feet[0, leg], pace, lift, stand,
                     rise, accel, least, carry)
        # Carried through the frames between the runs: a smoothstep from the value at one run's
        # end (0 on frame -1) to the next one's start (0 on frame L), each end's rate carried
        # ``carry`` frames at most by the cubic Hermite's terms for it (feet.swing_offsets).
        prev, vp0, vp1, rp0, rp1 = -1, 0.0, 0.0, 0.0, 0.0
        t = 0
        while True:
            while t < n_l and not on[t]:
                t += 1
            q, vq0, vq1, rq0, rq1 = t, 0.0, 0.0, 0.0, 0.0
            stop = t
            while stop < n_l and on[stop]:
                stop += 1
            if q < n_l:
                vq0, vq1 = offset[q, 0], offset[q, 1]
                if stop - q >= 2:
                    rq0, rq1 = offset[q + 1, 0] - offset[q, 0], offset[q + 1, 1] - offset[q, 1]
            span = float(q - prev)
            window = float(max(min(carry, q - prev), 1))
            for f in range(prev + 1, q):
                sf = float(f - prev)
                u = sf / span
                ua = min(sf / window, 1.0)
                ub = max(1.0 - (span - sf) / window, 0.0)
                h01, h10, h11 = 3 * u**2 - 2 * u**3, window * ua * (1 - ua) ** 2, window * ub**2 * (ub - 1)
                offset[f, 0] = vp0 + h01 * (vq0 - vp0) + h10 * rp0 + h11 * rq0
                offset[f, 1] = vp1 + h01 * (vq1 - vp1) + h10 * rp1 + h11 * rq1
            if q >= n_l:
                break
            prev, vp0, vp1, rp0, rp1 = stop - 1, offset[stop - 1, 0], offset[stop - 1, 1], 0.0, 0.0
            if stop - q >= 2:
                rp0, rp1 = offset[stop - 1, 0] - offset[stop - 2, 0], offset[stop - 1, 1] - offset[stop - 2, 1]
            t = stop
        for t in range(n_l):
            weights[t, leg] = weight[t]
    # The toes' floor: the context's; without one, a held foot's lowest toe in the new frames, or
    # the new frames' lowest toe when no foot is held.
    if toe_floor == np.inf:
        for leg in range(n_legs):
            for t in range(n_l):
                if on_all[leg, t]:
                    toe_floor = min(toe_floor, gpos[t, toes[leg], up])
    if toe_floor == np.inf:
        for leg in range(n_legs):
            for t in range(n_l):
                toe_floor = min(toe_floor, gpos[t, toes[leg], up])
    for leg in range(n_legs):
        on, offset, raised = on_all[leg], offset_all[leg], raised_all[leg]
        thigh, shin, ankle = legs[leg, 0], legs[leg, 1], legs[leg, 2]
        # A foot without a toe joint: its ankle kept out of the floor, no clearance above it.
        _toe_lift(gpos, toes[leg], up, offset, raised, on, toe_floor, clear if toes[leg] != ankle else 0.0, clear_lo,
                  clear_hi, curve_v, curve_h, clear_r, clear_fade, deficit, widest)
        for t in range(n_l):
            ik[t] = not (offset[t, 0] == 0.0 and offset[t, 1] == 0.0 and raised[t] == 0.0)
            for c in range(3):
                goals[t, c] = gpos[t, ankle, c]
            if ik[t]:
                goals[t, a_] += offset[t, 0]
                goals[t, b_] += offset[t, 1]
                goals[t, up] += raised[t]
        if not ik.any():
            continue
        hx, hy, hz = _knee_hinge(grot, rots, gpos, thigh, shin, ankle, toes[leg], hinge_sure, ik)
        for t in range(n_l):
            axes[t, 0], axes[t, 1], axes[t, 2] = _knee_axis(rots, grot, gpos, t, thigh, shin, ankle, hinge, hx, hy, hz)
        knee_bounded(goals, gpos, axes, thigh, shin, ankle, soft, knee_through, knee_accel, knee_passes, knee_plain,
                     knee_relax, knee_exact, knee_work, ik)
        for t in range(n_l):
            if not ik[t]:
                continue
            th, sh = hinge_ik_frame(rots, grot, gpos, t, thigh, shin, ankle, goals[t, 0], goals[t, 1], goals[t, 2],
                                    axes[t, 0], axes[t, 1], axes[t, 2], knee_work[0, t], eps)
            # Keep the foot's global orientation: its parent chain turned (twist joints between
            # keep their local rotations and turn with the joint above).
            p = parents[thigh]
            sg = _mul(grot[t, p, 0], grot[t, p, 1], grot[t, p, 2], grot[t, p, 3], th[0], th[1], th[2], th[3])
            if parents[shin] != thigh:
                sg = _carried(sg, grot, t, thigh, parents[shin])
            sg = _mul(sg[0], sg[1], sg[2], sg[3], sh[0], sh[1], sh[2], sh[3])
            if parents[ankle] != shin:
                sg = _carried(sg, grot, t, shin, parents[ankle])
            ft = _mul(sg[0], -sg[1], -sg[2], -sg[3], grot[t, ankle, 0], grot[t, ankle, 1], grot[t, ankle, 2],
                      grot[t, ankle, 3])
            for c in range(4):
                rots[t, thigh, c] = th[c]
                rots[t, shin, c] = sh[c]
                rots[t, ankle, c] = ft[c]


@nb.njit(**_OPTS)
def _slerp_signed(a0, a1, a2, a3, b0, b1, b2, b3, d, sign, t):
    """The SLERP from ``a`` to ``sign * b`` at the fraction ``t``, ``d`` their dot product with
    that sign (the cosine of half the angle between them), normalised."""
    theta = math.acos(min(max(d, -1.0), 1.0))
    sin_theta = math.sin(theta)
    if sin_theta < 1e-6:
        wa, wb = 1.0 - t, t
    else:
        wa, wb = math.sin((1.0 - t) * theta) / sin_theta, math.sin(t * theta) / sin_theta
    wb *= sign
    q0, q1, q2, q3 = wa * a0 + wb * b0, wa * a1 + wb * b1, wa * a2 + wb * b2, wa * a3 + wb * b3
    n = max(math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3), 1e-12)
    return q0 / n, q1 / n, q2 / n, q3 / n


@nb.njit(**_OPTS)
def slerp(a, b, t, out):
    """``out[i]`` = spherical linear interpolation from ``a[i]`` to ``b[i]`` (M, 4) at the
    fraction ``t`` on the short arc (:func:`posturemap.core.quat.slerp`, the reference)."""
    for i in range(a.shape[0]):
        d = a[i, 0] * b[i, 0] + a[i, 1] * b[i, 1] + a[i, 2] * b[i, 2] + a[i, 3] * b[i, 3]
        sign = -1.0 if d < 0 else 1.0
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = _slerp_signed(a[i, 0], a[i, 1], a[i, 2], a[i, 3], b[i, 0],
                                                                   b[i, 1], b[i, 2], b[i, 3], abs(d), sign, t)


@nb.njit(**_OPTS)
def slerp_track(a, b, t, out, fade):
    """:func:`posturemap.core.kernels.slerp_track` (the reference): the SLERP from ``a[n, m]`` to
    ``b[n, m]`` (N, M, 4) at the fraction ``t`` (a number, or (N,) one per frame) on the arc
    that goes on from frame to frame, the columns ``fade`` (M,) with their fraction moving to
    the nearer end where the arc has gone on past a half turn round; returns the last frame's
    relative rotation on that arc (M, 4)."""
    ends = np.empty((a.shape[1], 4))
    w = np.empty(a.shape[0])
    w[:] = t
    for m in range(a.shape[1]):
        sign = 1.0
        p0, p1, p2, p3 = 0.0, 0.0, 0.0, 0.0
        for n in range(a.shape[0]):
            r0, r1, r2, r3 = _mul(a[n, m, 0], -a[n, m, 1], -a[n, m, 2], -a[n, m, 3],
                                  b[n, m, 0], b[n, m, 1], b[n, m, 2], b[n, m, 3])
            if n == 0:
                sign = -1.0 if r0 < 0.0 else 1.0
            elif r0 * p0 + r1 * p1 + r2 * p2 + r3 * p3 < 0.0:
                sign = -sign
            tt = w[n]
            if fade[m]:
                near = min(max((2.0 * math.acos(min(max(sign * r0, -1.0), 1.0)) - math.pi) / _FADE_SPAN, 0.0), 1.0)
                tt += ((1.0 if tt >= 0.5 else 0.0) - tt) * near * near * (3.0 - 2.0 * near)
            p0, p1, p2, p3 = r0, r1, r2, r3
            out[n, m, 0], out[n, m, 1], out[n, m, 2], out[n, m, 3] = _slerp_signed(
                a[n, m, 0], a[n, m, 1], a[n, m, 2], a[n, m, 3], b[n, m, 0], b[n, m, 1], b[n, m, 2], b[n, m, 3],
                sign * r0, sign, tt)
        ends[m, 0], ends[m, 1], ends[m, 2], ends[m, 3] = sign * p0, sign * p1, sign * p2, sign * p3
    return ends


@nb.njit(**_OPTS)
def blend_root(chain, root, up, rest, rots_fb, tilt, heading, c, align, out):
    """:func:`posturemap.core.kernels.blend_root` (the reference): the root blended at the
    fraction ``c`` from the fallback's (``rots_fb``) to the retrieved one (``tilt``, replaced by
    the blended tilt; ``heading``) as a turn about the up axis and a tilt, the blended headings
    into ``out``; returns the retrieved root's lead at the last frame, the way round it went."""
    two_pi = 2.0 * math.pi
    n = rots_fb.shape[0]
    lead = np.empty(n)
    prev = 0.0
    turns = 0.0
    for f in range(n):
        g0, g1, g2, g3 = rots_fb[f, root, 0], rots_fb[f, root, 1], rots_fb[f, root, 2], rots_fb[f, root, 3]
        for i in range(chain.shape[0] - 1, -1, -1):
            j = chain[i]
            g0, g1, g2, g3 = _mul(rots_fb[f, j, 0], rots_fb[f, j, 1], rots_fb[f, j, 2], rots_fb[f, j, 3],
                                  g0, g1, g2, g3)
        p = _mul(g0, g1, g2, g3, rest[0], -rest[1], -rest[2], -rest[3])
        h = 2.0 * math.atan2(p[1 + up], p[0])
        sh = -math.sin(0.5 * h)  # the heading's inverse, about axis up
        t0, t1, t2, t3 = _mul(math.cos(0.5 * h), sh if up == 0 else 0.0, sh if up == 1 else 0.0,
                              sh if up == 2 else 0.0, g0, g1, g2, g3)
        d = t0 * tilt[f, 0] + t1 * tilt[f, 1] + t2 * tilt[f, 2] + t3 * tilt[f, 3]
        sign = -1.0 if d < 0 else 1.0
        tilt[f, 0], tilt[f, 1], tilt[f, 2], tilt[f, 3] = _slerp_signed(t0, t1, t2, t3, tilt[f, 0], tilt[f, 1],
                                                                       tilt[f, 2], tilt[f, 3], abs(d), sign, c)
        raw = heading[f] - h
        if f == 0:
            raw -= two_pi * np.rint(raw / two_pi)
        else:
            turns += np.rint((raw - prev) / two_pi)
        prev = raw
        lead[f] = raw - two_pi * turns
    went = lead[n - 1]
    whole = np.rint(went / two_pi)
    for f in range(n):
        x = lead[f]
        if whole != 0.0 and not align:
            u = (f + 1.0) / n
            x -= two_pi * whole * (u * u * (3.0 - 2.0 * u))
        out[f] = (heading[f] - lead[f]) + c * x  # the fallback's heading counted round as heading is, plus c of x
    return went


@nb.njit(**_OPTS)
def turn_toward(chain, rots, other, t):
    """The last joint of ``chain`` (top first, the top without a parent) turned in place in
    ``rots (N, J, 4)`` so that its global rotation goes the fraction ``t`` of the short arc from
    its own toward its global rotation in ``other`` (:func:`posturemap.core.kernels.turn_toward`,
    the reference)."""
    j = chain[-1]
    k = chain.shape[0]
    one = np.empty((1, 4))
    two = np.empty((1, 4))
    for n in range(rots.shape[0]):
        c = chain[0]
        a = (rots[n, c, 0], rots[n, c, 1], rots[n, c, 2], rots[n, c, 3])
        b = (other[n, c, 0], other[n, c, 1], other[n, c, 2], other[n, c, 3])
        for i in range(1, k - 1):
            c = chain[i]
            a = _mul(a[0], a[1], a[2], a[3], rots[n, c, 0], rots[n, c, 1], rots[n, c, 2], rots[n, c, 3])
            b = _mul(b[0], b[1], b[2], b[3], other[n, c, 0], other[n, c, 1], other[n, c, 2], other[n, c, 3])
        own = _mul(a[0], a[1], a[2], a[3], rots[n, j, 0], rots[n, j, 1], rots[n, j, 2], rots[n, j, 3])
        goal = _mul(b[0], b[1], b[2], b[3], other[n, j, 0], other[n, j, 1], other[n, j, 2], other[n, j, 3])
        for i in range(4):
            one[0, i], two[0, i] = own[i], goal[i]
        slerp(one, two, t, one)
        q = _mul(a[0], -a[1], -a[2], -a[3], one[0, 0], one[0, 1], one[0, 2], one[0, 3])
        rots[n, j, 0], rots[n, j, 1], rots[n, j, 2], rots[n, j, 3] = q


@nb.njit(**_OPTS)
def chest_turned(chain, up, other, rots, joints, free, out):
    """``out[:, joints]``: ``other``'s joints under ``rots``'s chain, differing from ``other``'s in
    the world by what of the two chains' turn about ``up`` lies beyond ``free`` radians, smoothly
    (:func:`posturemap.core.kernels.chest_turned`, the reference)."""
    k = chain.shape[0]
    for n in range(rots.shape[0]):
        c = chain[0]
        a = (other[n, c, 0], other[n, c, 1], other[n, c, 2], other[n, c, 3])
        b = (rots[n, c, 0], rots[n, c, 1], rots[n, c, 2], rots[n, c, 3])
        for i in range(1, k):
            c = chain[i]
            a = _mul(a[0], a[1], a[2], a[3], other[n, c, 0], other[n, c, 1], other[n, c, 2], other[n, c, 3])
            b = _mul(b[0], b[1], b[2], b[3], rots[n, c, 0], rots[n, c, 1], rots[n, c, 2], rots[n, c, 3])
        d = _mul(b[0], b[1], b[2], b[3], a[0], -a[1], -a[2], -a[3])  # other's chain to rots's, in the world
        theta = 2.0 * np.arctan2(d[1 + up], d[0])  # its turn about up
        theta = (theta + np.pi) % (2.0 * np.pi) - np.pi
        half = 0.5 * (theta - free * np.tanh(np.sin(theta) / free)) if free > 0.0 else 0.5 * theta  # beyond free
        w, v = np.cos(half), np.sin(half)
        t1, t2, t3 = (v if up == 0 else 0.0), (v if up == 1 else 0.0), (v if up == 2 else 0.0)
        q = _mul(w, t1, t2, t3, a[0], a[1], a[2], a[3])  # the turn, then other's chain
        q = _mul(b[0], -b[1], -b[2], -b[3], q[0], q[1], q[2], q[3])  # under rots's chain
        for i in range(joints.shape[0]):
            j = joints[i]
            r = _mul(q[0], q[1], q[2], q[3], other[n, j, 0], other[n, j, 1], other[n, j, 2], other[n, j, 3])
            s = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3])
            out[n, j, 0], out[n, j, 1], out[n, j, 2], out[n, j, 3] = r[0] / s, r[1] / s, r[2] / s, r[3] / s


@nb.njit(**_OPTS)
def _group_energy(rows, c0, c1, step):
    """The mean squared velocity and acceleration of the columns ``c0:c1`` of ``rows`` (summed
    over the columns; 0, 0 with fewer than 3 samples): :func:`posturemap.synth.bases.damped_time_scales`'s."""
    n = rows.shape[0]
    ev, ea = 0.0, 0.0
    if n < 3:
        return ev, ea
    for c in range(c0, c1):
        sv, sa = 0.0, 0.0
        for k in range(n - 1):
            v = (rows[k + 1, c] - rows[k, c]) / step
            sv += v * v
        for k in range(n - 2):
            a = (rows[k + 2, c] - 2.0 * rows[k + 1, c] + rows[k, c]) / (step * step)
            sa += a * a
        ev += sv / (n - 1)
        ea += sa / (n - 2)
    return ev, ea


@nb.njit(**_OPTS)
def seam_rows(a_rots, a_pos, a_gpos, a_heading, ia, b_rots, b_pos, b_gpos, b_heading, ib, ref, dtheta, shift,
              turns, up, out):
    """:func:`posturemap.synth.engine._seam_rows` in one call: frames ``ia`` of A, then ``ib`` of
    B, as rows of ``out`` (N, 6J + 4): rotation vectors about ``ref`` (J, 4), the root's global
    position (B's turned by ``dtheta`` about axis ``up`` and moved by ``shift``), its heading
    (B's plus ``dtheta``, plus the whole ``turns`` that unwrap it to A's) and the local
    translations."""
    n_a, n_j = ia.shape[0], ref.shape[0]
    s0 = 3 * n_j
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    c, s = math.cos(dtheta), math.sin(dtheta)
    for r in range(out.shape[0]):
        on_a = r < n_a
        f = ia[r] if on_a else ib[r - n_a]
        rots = a_rots if on_a else b_rots
        pos = a_pos if on_a else b_pos
        for j in range(n_j):
            w, x, y, z = _mul(ref[j, 0], -ref[j, 1], -ref[j, 2], -ref[j, 3],
                              rots[f, j, 0], rots[f, j, 1], rots[f, j, 2], rots[f, j, 3])
            if w < 0.0:
                w, x, y, z = -w, -x, -y, -z
            n = math.sqrt(x * x + y * y + z * z)
            k = 2.0 * math.atan2(n, w) / n if n > 1e-8 else 2.0 + n * n / 3.0
            out[r, 3 * j] = x * k
            out[r, 3 * j + 1] = y * k
            out[r, 3 * j + 2] = z * k
            for d in range(3):
                out[r, s0 + 4 + 3 * j + d] = pos[f, j, d]
        if on_a:
            for d in range(3):
                out[r, s0 + d] = a_gpos[f, d]
            out[r, s0 + 3] = a_heading[f]
        else:
            va, vb = b_gpos[f, a_], b_gpos[f, b_]
            out[r, s0 + up] = b_gpos[f, up] + shift[up]
            out[r, s0 + a_] = c * va - s * vb + shift[a_]
            out[r, s0 + b_] = s * va + c * vb + shift[b_]
            out[r, s0 + 3] = (b_heading[f] + dtheta) + turns
    _unwrap_seam_rows(out, ia, ib, n_j)


@nb.njit(**_OPTS)
def _unwrap_seam_rows(out, ia, ib, n_j):
    """:func:`posturemap.synth.engine._unwrap_seam_rows` on the rotation vectors of ``out`` (N, 6J + 4)."""
    n_a = ia.shape[0]
    for side in range(2):
        frames = ia if side == 0 else ib
        first = 0 if side == 0 else n_a
        order = np.argsort(-frames if side == 0 else frames, kind="mergesort")
        for i in range(1, frames.shape[0]):
            r, p = first + order[i], first + order[i - 1]
            for j in range(n_j):
                c = 3 * j
                out[r, c], out[r, c + 1], out[r, c + 2] = _near_turn(out[r, c], out[r, c + 1], out[r, c + 2],
                                                                     out[p, c], out[p, c + 1], out[p, c + 2])


@nb.njit(**_OPTS)
def damped_columns(inputs, length, rows_a, rows_b, step, starts, fixed, tau_min, tau_max, reach_columns, reach_max,
                   peak, out):
    """``damped``'s frames (length, C) into ``out``: :func:`posturemap.synth.bases.damped_frames`
    of ``inputs`` (rows pA, vA, pB, vB), each column's time constant at both seams from
    :func:`posturemap.synth.bases.damped_time_scales` of ``rows_a`` and ``rows_b`` together
    (samples ``step`` frames apart, column groups beginning at ``starts``), 0 where ``fixed``,
    held within ``[tau_min, tau_max]``; in the groups of the first ``reach_columns`` columns,
    :func:`posturemap.synth.bases.reach_parts` (at most ``reach_max``; ``peak``:
    :data:`posturemap.synth.bases.DAMPED_PEAK`)."""
    n_c = inputs.shape[1]
    d = length + 1.0
    tau = np.empty(n_c)
    tau_a = np.empty(n_c)
    tau_b = np.empty(n_c)
    part_a = np.zeros(n_c)
    part_b = np.zeros(n_c)
    for g in range(starts.shape[0]):
        c0 = starts[g]
        c1 = starts[g + 1] if g + 1 < starts.shape[0] else n_c
        ev_a, ea_a = _group_energy(rows_a, c0, c1, step)
        ev_b, ea_b = _group_energy(rows_b, c0, c1, step)
        ev, ea = ev_a + ev_b, ea_a + ea_b
        if ea > 0.0:
            scale = math.sqrt(ev / ea)
        else:
            scale = math.inf if ev > 0.0 else 0.0
        for c in range(c0, c1):
            s = 0.0 if fixed[c] else scale
            tau[c] = min(max(s, tau_min), tau_max)
            tau_a[c] = tau[c]
            tau_b[c] = tau[c]
        if c1 <= reach_columns:
            _reach_group(inputs, 1, c0, c1, d, peak, reach_max, tau, tau_a, part_a)
            _reach_group(inputs, 3, c0, c1, d, peak, reach_max, tau, tau_b, part_b)
    _damped_apply(inputs, length, tau, out, tau_a, tau_b, part_a, part_b, min(reach_columns, n_c))


@nb.njit(**_OPTS)
def _reach_group(inputs, row, c0, c1, d, peak, reach_max, tau, tau_out, part_out):
    """:func:`posturemap.synth.bases.reach_parts` of one seam (its velocity in ``inputs[row]``)
    for the group of columns ``c0:c1``, into ``tau_out`` and ``part_out`` (left as they are where
    the seam's speed along the path is not faster than the straight line's)."""
    dd, along = 0.0, 0.0
    for c in range(c0, c1):
        diff = inputs[2, c] - inputs[0, c]
        dd += diff * diff
        along += diff * inputs[row, c]
    if dd > 0.0 and along * d > dd:
        t = min(dd / (peak * along), reach_max)
        share = along / dd - 1.0 / d
        for c in range(c0, c1):
            tau_out[c] = max(tau[c], t)
            part_out[c] = share * (inputs[2, c] - inputs[0, c])


@nb.njit(**_OPTS)
def _damped_apply(inputs, length, tau, out, tau_a, tau_b, part_a, part_b, columns):
    """:func:`posturemap.synth.bases.damped_frames` of ``inputs`` (rows pA, vA, pB, vB) with
    each column's time constant ``tau`` (C,; frames, already held within its bounds) into ``out``
    (length, C); over the first ``columns`` columns, the reach's parts of the seam velocities
    (``part_a``, ``part_b``) carried with their time constants ``tau_a``, ``tau_b`` instead
    (``damped_frames``'s ``reach``; ``columns`` 0: none)."""
    n_c = inputs.shape[1]
    d = length + 1.0
    for i in range(length):
        t = i + 1.0
        w = t / d
        u = d - t
        to_b = w * w * (3.0 - 2.0 * w)
        tc, near_a, near_b = -1.0, 0.0, 0.0
        for c in range(n_c):
            if tau[c] != tc:  # a group's columns share their weights
                tc = tau[c]
                near_a = (1.0 - to_b) * t * (1.0 + t / tc) * math.exp(-t / tc)
                near_b = to_b * u * (1.0 + u / tc) * math.exp(-u / tc)
            p_a, v_a, p_b, v_b = inputs[0, c], inputs[1, c], inputs[2, c], inputs[3, c]
            slope = (p_b - p_a) / d
            out[i, c] = p_a + w * (p_b - p_a) + near_a * (v_a - slope) - near_b * (v_b - slope)
        key_a, key_b, own_a, own_b, extra_a, extra_b = -1.0, -1.0, -1.0, -1.0, 0.0, 0.0
        for c in range(columns):
            if part_a[c] != 0.0:
                if tau_a[c] != key_a or tau[c] != own_a:  # a group's columns share their weights
                    key_a, own_a = tau_a[c], tau[c]
                    extra_a = (1.0 - to_b) * t * ((1.0 + t / key_a) * math.exp(-t / key_a)
                                                  - (1.0 + t / own_a) * math.exp(-t / own_a))
                out[i, c] += extra_a * part_a[c]
            if part_b[c] != 0.0:
                if tau_b[c] != key_b or tau[c] != own_b:
                    key_b, own_b = tau_b[c], tau[c]
                    extra_b = to_b * u * ((1.0 + u / key_b) * math.exp(-u / key_b)
                                          - (1.0 + u / own_b) * math.exp(-u / own_b))
                out[i, c] -= extra_b * part_b[c]


@nb.njit(**_OPTS)
def _ramp(x, lo, hi):
    """0 at ``lo``, 1 at ``hi``, linear in between (either way round)."""
    return min(max((x - lo) / (hi - lo), 0.0), 1.0)


@nb.njit(**_OPTS)
def _cholesky4(a):
    """The lower Cholesky factor of a symmetric positive definite 4 x 4 ``a``."""
    low = np.zeros((4, 4))
    for i in range(4):
        for j in range(i + 1):
            s = a[i, j]
            for k in range(j):
                s -= low[i, k] * low[j, k]
            if i == j:
                low[i, i] = math.sqrt(max(s, 1e-300))
            else:
                low[i, j] = s / low[j, j]
    return low


@nb.njit(**_OPTS)
def _solve4(a, b):
    """``a^-1 b`` for a symmetric positive definite 4 x 4 ``a`` and ``b`` (4, C), by Cholesky."""
    low = _cholesky4(a)
    out = np.empty_like(b)
    y = np.empty(4)
    for c in range(b.shape[1]):
        for i in range(4):
            s = b[i, c]
            for k in range(i):
                s -= low[i, k] * y[k]
            y[i] = s / low[i, i]
        for i in range(3, -1, -1):
            s = y[i]
            for k in range(i + 1, 4):
                s -= low[k, i] * out[k, c]
            out[i, c] = s / low[i, i]
    return out


@nb.njit(**_OPTS)
def _swing_design(times, omega, d, out):
    """``[1, t / d, cos(w t), sin(w t)]`` at ``times`` into ``out`` (n, 4). Where ``times`` step
    evenly (each seam's samples), the cosines and sines follow by the angle-addition formulas
    (a few calls of each per run of even steps instead of one per sample)."""
    last, c_step, s_step = math.nan, 1.0, 0.0
    for k in range(times.shape[0]):
        out[k, 0] = 1.0
        out[k, 1] = times[k] / d
        gap = times[k] - times[k - 1] if k > 0 else math.nan
        if gap == last:
            out[k, 2] = out[k - 1, 2] * c_step - out[k - 1, 3] * s_step
            out[k, 3] = out[k - 1, 3] * c_step + out[k - 1, 2] * s_step
        else:
            out[k, 2] = math.cos(omega * times[k])
            out[k, 3] = math.sin(omega * times[k])
            if k > 0:
                last, c_step, s_step = gap, math.cos(omega * gap), math.sin(omega * gap)


@nb.njit(**_OPTS)
def _swing_explained(gram, times, omega, d):
    """How much of the rows whose Gram matrix is ``gram`` the fit at ``omega`` explains."""
    n = times.shape[0]
    x = np.empty((n, 4))
    _swing_design(times, omega, d, x)
    gx = gram @ x
    xtx = x.T @ x
    for i in range(4):
        xtx[i, i] += 1e-9
    sol = _solve4(xtx, x.T @ gx)
    return sol[0, 0] + sol[1, 1] + sol[2, 2] + sol[3, 3]


@nb.njit(**_OPTS)
def _swing_peak(omegas, explained, gram, times, d, peaks):
    """:func:`posturemap.synth.periodic._peak`: the grid's best, or the best of its ``peaks``
    highest local maxima moved to their parabolas' vertices."""
    w_count = omegas.shape[0]
    top = 0
    for w in range(1, w_count):
        if explained[w] > explained[top]:
            top = w
    best, best_val = omegas[top], explained[top]
    inner = np.empty(w_count, dtype=np.int64)
    height = np.empty(w_count)
    shift = np.empty(w_count)
    m = 0
    for w in range(1, w_count - 1):
        y0, y1, y2 = explained[w - 1], explained[w], explained[w + 1]
        if y1 >= y0 and y1 >= y2:
            curve = y0 - 2.0 * y1 + y2
            sh = 0.5 * (y0 - y2) / curve if curve < 0.0 else 0.0
            inner[m] = w
            shift[m] = sh
            height[m] = y1 - 0.25 * (y0 - y2) * sh
            m += 1
    if m == 0:
        return best
    order = np.argsort(-height[:m], kind="mergesort")
    step = omegas[1] - omegas[0]
    for r in range(min(peaks, m)):
        i = order[r]
        om = omegas[inner[i]] + shift[i] * step
        val = _swing_explained(gram, times, om, d)
        if val > best_val:
            best, best_val = om, val
    return best


@nb.njit(**_OPTS)
def _own_residuals(rows, times, omegas, d, starts, candidate):
    """Per joint (groups at ``starts``) where ``candidate``, its least residual over the
    frequency grid (the sinusoid fitted to its columns alone); 0 elsewhere."""
    n, n_c = rows.shape
    n_g = starts.shape[0]
    best = np.zeros(n_g)
    energy = np.zeros(n_g)
    for g in range(n_g):
        if candidate[g]:
            for c in range(starts[g], starts[g + 1] if g + 1 < n_g else n_c):
                for k in range(n):
                    energy[g] += rows[k, c] * rows[k, c]
    x = np.empty((n, 4))
    xtx = np.empty((4, 4))
    xty = np.empty((4, 1))
    for w in range(omegas.shape[0]):
        _swing_design(times, omegas[w], d, x)
        for a in range(4):
            for b in range(4):
                s = 0.0
                for k in range(n):
                    s += x[k, a] * x[k, b]
                xtx[a, b] = s + (1e-9 if a == b else 0.0)
        low = _cholesky4(xtx)
        for g in range(n_g):
            if not candidate[g]:
                continue
            explained = 0.0
            for c in range(starts[g], starts[g + 1] if g + 1 < n_g else n_c):
                for a in range(4):
                    s = 0.0
                    for k in range(n):
                        s += x[k, a] * rows[k, c]
                    xty[a, 0] = s
                # x'y' inv(X'X) x'y = |L^-1 x'y|^2
                for i in range(4):
                    s = xty[i, 0]
                    for k in range(i):
                        s -= low[i, k] * xty[k, 0]
                    xty[i, 0] = s / low[i, i]
                    explained += xty[i, 0] * xty[i, 0]
            best[g] = max(best[g], explained)
    out = np.zeros(n_g)
    for g in range(n_g):
        if candidate[g]:
            out[g] = max(energy[g] - best[g], 0.0)
    return out


@nb.njit(**_OPTS)
def swing_columns(rows, times, inputs, length, omegas, starts, tau, gate, turn, balance, peaks, own, min_rms,
                  frames, weights):
    """:func:`posturemap.synth.periodic.continued` into ``frames`` (length, C) and ``weights``
    (C,); returns False (and leaves ``frames`` alone) where no joint swings."""
    n, n_c = rows.shape
    n_a = 0
    for k in range(n):
        if times[k] <= 0.0:
            n_a += 1
    n_g = starts.shape[0]
    swing = np.zeros(n_g)
    any_swing = False
    for g in range(n_g):
        c0 = starts[g]
        c1 = starts[g + 1] if g + 1 < n_g else n_c
        straight = 1.0
        energy = np.zeros(2)
        for side in range(2):
            k0, k1 = (0, n_a) if side == 0 else (n_a, n)
            path = 0.0
            for k in range(k0, k1 - 1):
                s = 0.0
                for c in range(c0, c1):
                    dv = rows[k + 1, c] - rows[k, c]
                    s += dv * dv
                path += math.sqrt(s)
                energy[side] += s
            if k1 - k0 > 1:
                energy[side] /= k1 - k0 - 1
            net = 0.0
            for c in range(c0, c1):
                dv = rows[k1 - 1, c] - rows[k0, c]
                net += dv * dv
            net = math.sqrt(net)
            straight = min(straight, net / path if path > 1e-12 else 1.0)
        quiet, busy = min(energy[0], energy[1]), max(energy[0], energy[1])
        share = quiet / busy if busy > 1e-12 else 0.0
        swing[g] = _ramp(straight, turn[1], turn[0]) * _ramp(share, balance[0], balance[1])
        if swing[g] > 0.0:
            any_swing = True
    for c in range(n_c):
        weights[c] = 0.0
    if not any_swing:
        return False
    d = length + 1.0
    # A cubic through each joint's samples: a joint it fits within ``min_rms`` has no swing worth
    # continuing; the others are judged against it below.
    cubic = np.empty((n, 4))
    for k in range(n):
        s = (times[k] - 0.5 * d) / d
        cubic[k, 0], cubic[k, 1], cubic[k, 2], cubic[k, 3] = 1.0, s, s * s, s * s * s
    cty = cubic.T @ rows
    ccoef = _solve4(cubic.T @ cubic, cty)
    res_cubic = np.zeros(n_g)
    any_swing = False
    for g in range(n_g):
        if swing[g] <= 0.0:
            continue
        c0 = starts[g]
        c1 = starts[g + 1] if g + 1 < n_g else n_c
        for c in range(c0, c1):
            for k in range(n):
                fc = 0.0
                for a in range(4):
                    fc += cubic[k, a] * ccoef[a, c]
                res_cubic[g] += (rows[k, c] - fc) ** 2
        if res_cubic[g] <= n * (c1 - c0) * min_rms * min_rms:
            swing[g] = 0.0
        else:
            any_swing = True
    if not any_swing:
        return False
    # The frequency that explains the most of the swinging joints: trace(inv(X'X) X'G X), G = Y Y'.
    gram = np.zeros((n, n))
    for k in range(n):
        for m in range(k, n):
            s = 0.0
            for g in range(n_g):
                if swing[g] > 0.0:
                    for c in range(starts[g], starts[g + 1] if g + 1 < n_g else n_c):
                        s += rows[k, c] * rows[m, c]
            gram[k, m] = s
            gram[m, k] = s
    x = np.empty((n, 4))
    _swing_design(times, 0.0, d, x)  # the columns 1 and t / d do not depend on the frequency
    gx = np.zeros((n, 4))
    for k in range(n):
        for m in range(n):
            gx[k, 0] += gram[k, m] * x[m, 0]
            gx[k, 1] += gram[k, m] * x[m, 1]
    xtx = np.zeros((4, 4))
    xgx = np.zeros((4, 4))
    for a in range(2):
        for b in range(2):
            for k in range(n):
                xtx[a, b] += x[k, a] * x[k, b]
                xgx[a, b] += x[k, a] * gx[k, b]
    xtx[0, 0] += 1e-9
    xtx[1, 1] += 1e-9
    explained = np.empty(omegas.shape[0])
    for w in range(omegas.shape[0]):
        _swing_design(times, omegas[w], d, x)
        for k in range(n):
            s2, s3 = 0.0, 0.0
            for m in range(n):
                s2 += gram[k, m] * x[m, 2]
                s3 += gram[k, m] * x[m, 3]
            gx[k, 2] = s2
            gx[k, 3] = s3
        for a in range(4):
            for b in range(2, 4):
                s, t = 0.0, 0.0
                for k in range(n):
                    s += x[k, a] * x[k, b]
                    t += x[k, a] * gx[k, b]
                xtx[a, b] = s
                xtx[b, a] = s
                xgx[a, b] = t
                xgx[b, a] = t
        xtx[2, 2] += 1e-9
        xtx[3, 3] += 1e-9
        sol = _solve4(xtx, xgx)
        explained[w] = sol[0, 0] + sol[1, 1] + sol[2, 2] + sol[3, 3]
    omega = _swing_peak(omegas, explained, gram, times, d, peaks)
    _swing_design(times, omega, d, x)
    xtx = x.T @ x
    for i in range(4):
        xtx[i, i] += 1e-9
    xty = x.T @ rows
    coef = _solve4(xtx, xty)
    shared_res = np.zeros(n_g)
    for g in range(n_g):
        if swing[g] <= 0.0:
            continue
        c0 = starts[g]
        c1 = starts[g + 1] if g + 1 < n_g else n_c
        res_wave = 0.0
        for c in range(c0, c1):
            for k in range(n):
                fw = 0.0
                for a in range(4):
                    fw += x[k, a] * coef[a, c]
                res_wave += (rows[k, c] - fw) ** 2
        wgt = _ramp(res_wave / res_cubic[g], gate[1], gate[0]) * swing[g]
        shared_res[g] = res_wave
        for c in range(c0, c1):
            weights[c] = wgt
    # A joint whose own best frequency fits it far better keeps its own rhythm: not continued.
    candidate = np.zeros(n_g, dtype=np.bool_)
    for g in range(n_g):
        candidate[g] = weights[starts[g]] > 0.0
    own_res = _own_residuals(rows, times, omegas, d, starts, candidate)
    for g in range(n_g):
        if candidate[g] and shared_res[g] > own * max(own_res[g], 1e-300):
            for c in range(starts[g], starts[g + 1] if g + 1 < n_g else n_c):
                weights[c] = 0.0
    # The fit through the gap; its residuals at A's last two frames and B's first two (as the
    # seam rows measure the clips: value and step) let go over ``tau``.
    ends = np.array([-1.0, 0.0, d, d + 1.0])
    at = np.empty((4, 4))
    _swing_design(ends, omega, d, at)
    fit = at @ coef
    res = np.empty((4, n_c))
    for c in range(n_c):
        res[0, c] = inputs[0, c] - fit[1, c]
        res[1, c] = inputs[1, c] - (fit[1, c] - fit[0, c])
        res[2, c] = inputs[2, c] - fit[2, c]
        res[3, c] = inputs[3, c] - (fit[3, c] - fit[2, c])
    taus, none = np.full(n_c, tau), np.zeros(n_c)
    _damped_apply(res, length, taus, frames, taus, taus, none, none, 0)
    for i in range(length):
        t = i + 1.0
        ct, st = math.cos(omega * t), math.sin(omega * t)
        for c in range(n_c):
            frames[i, c] += coef[0, c] + coef[1, c] * (t / d) + coef[2, c] * ct + coef[3, c] * st
    return True
