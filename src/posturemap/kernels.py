"""Compiled kernels for the per-transition hot path (numba, cached on disk).

The same maths as :mod:`posturemap.quat` (which stays the readable, tested reference; the
tests cross-check these kernels against it), written as loops so that one transition costs
a few microseconds instead of hundreds of numpy dispatches. Quaternions are (w, x, y, z).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

_OPTS = dict(cache=True, nogil=True, fastmath=False)


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


@nb.njit(cache=True, nogil=True, fastmath={"nsz", "arcp", "contract", "reassoc"})
def nearest(W, x, period):
    """Index of the row of ``W (n, d)`` nearest ``x (d,)``; ``period`` per dimension (inf: linear)."""
    best = np.inf
    best_i = 0
    for i in range(W.shape[0]):
        acc = 0.0
        for k in range(W.shape[1]):
            d = abs(W[i, k] - x[k])
            d = min(d, period[k] - d)
            acc += d * d
        if acc < best:
            best = acc
            best_i = i
    return best_i
