"""Compiled replay of retrieved segments (numba; cached on disk): see
:func:`posturemap.synth.retrieval.replay_rotations`, whose numpy path is the reference it is tested
against. Loaded only in processes that already use numba (training, the studio, benchmarks).
Quaternions are (w, x, y, z) tuples inside; nothing is allocated per frame."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..core.numba_kernels import _mul

_OPTS = dict(cache=True, nogil=True, fastmath=False)


@nb.njit(**_OPTS)
def _log_rel(p, q):
    """log(p q^-1) as a rotation vector (short arc); p, q 4-tuples."""
    w, x, y, z = _mul(p[0], p[1], p[2], p[3], q[0], -q[1], -q[2], -q[3])
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    k = 2.0 * math.atan2(s, w) / s if s > 1e-8 else 2.0 + s * s / 3.0
    return x * k, y * k, z * k


@nb.njit(**_OPTS)
def _sample(rots, i0, i1, f, j):
    """Normalised lerp of library rotations i0 and i1 (sign-aligned) of joint j, a 4-tuple."""
    a0, a1, a2, a3 = float(rots[i0, j, 0]), float(rots[i0, j, 1]), float(rots[i0, j, 2]), float(rots[i0, j, 3])
    b0, b1, b2, b3 = float(rots[i1, j, 0]), float(rots[i1, j, 1]), float(rots[i1, j, 2]), float(rots[i1, j, 3])
    if a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 < 0.0:
        b0, b1, b2, b3 = -b0, -b1, -b2, -b3
    q0, q1, q2, q3 = a0 + f * (b0 - a0), a1 + f * (b1 - a1), a2 + f * (b2 - a2), a3 + f * (b3 - a3)
    n = max(math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3), 1e-12)
    return q0 / n, q1 / n, q2 / n, q3 / n


@nb.njit(**_OPTS)
def _row(a):
    return a[0], a[1], a[2], a[3]


@nb.njit(**_OPTS)
def replay(rots, i0, i1, f, joints, a2, b2, curves, out):
    """Segments sampled at (i0, i1, f) (K, T), seam-corrected and averaged into out (L, M, 4).

    rots (N, J, 4) library rotations; joints (M,); a2/b2 (2, M, 4) A at a_end-1, a_end and B
    at b_start, b_start+1; curves (4, L) offset curves, L = T - 4.
    """
    n_k, n_t = i0.shape
    n_l = curves.shape[1]
    n_m = joints.shape[0]
    ref = np.empty((n_l, n_m, 4))
    acc = np.zeros((n_l, n_m, 4))
    for k in range(n_k):
        for m in range(n_m):
            j = joints[m]
            s_m1 = _sample(rots, i0[k, 0], i1[k, 0], f[k, 0], j)
            s_0 = _sample(rots, i0[k, 1], i1[k, 1], f[k, 1], j)
            s_d = _sample(rots, i0[k, n_t - 2], i1[k, n_t - 2], f[k, n_t - 2], j)
            s_d1 = _sample(rots, i0[k, n_t - 1], i1[k, n_t - 1], f[k, n_t - 1], j)
            a_0, a_1, b_0, b_1 = _row(a2[0, m]), _row(a2[1, m]), _row(b2[0, m]), _row(b2[1, m])
            ra = _log_rel(a_1, s_0)
            va1, va2 = _log_rel(a_1, a_0), _log_rel(s_0, s_m1)
            rb = _log_rel(b_0, s_d)
            vb1, vb2 = _log_rel(b_1, b_0), _log_rel(s_d1, s_d)
            for t in range(n_l):
                c0, c1, c2, c3 = curves[0, t], curves[1, t], curves[2, t], curves[3, t]
                ox = c0 * ra[0] + c1 * (va1[0] - va2[0]) + c2 * rb[0] + c3 * (vb1[0] - vb2[0])
                oy = c0 * ra[1] + c1 * (va1[1] - va2[1]) + c2 * rb[1] + c3 * (vb1[1] - vb2[1])
                oz = c0 * ra[2] + c1 * (va1[2] - va2[2]) + c2 * rb[2] + c3 * (vb1[2] - vb2[2])
                ang = math.sqrt(ox * ox + oy * oy + oz * oz)
                h = math.sin(0.5 * ang) / ang if ang > 1e-8 else 0.5 - ang * ang / 48.0
                s = _sample(rots, i0[k, t + 2], i1[k, t + 2], f[k, t + 2], j)
                q = _mul(math.cos(0.5 * ang), ox * h, oy * h, oz * h, s[0], s[1], s[2], s[3])
                if k == 0:
                    for c in range(4):
                        ref[t, m, c] = q[c]
                sign = 1.0
                if q[0] * ref[t, m, 0] + q[1] * ref[t, m, 1] + q[2] * ref[t, m, 2] + q[3] * ref[t, m, 3] < 0.0:
                    sign = -1.0
                for c in range(4):
                    acc[t, m, c] += sign * q[c]
    for t in range(n_l):
        for m in range(n_m):
            n = max(math.sqrt(acc[t, m, 0] ** 2 + acc[t, m, 1] ** 2 + acc[t, m, 2] ** 2 + acc[t, m, 3] ** 2), 1e-12)
            for c in range(4):
                out[t, m, c] = acc[t, m, c] / n


@nb.njit(**_OPTS)
def seam_costs(pm, vm, frames, vframes, p, v, rate, out):
    """out[i] = |pm[frames[i]] - p|^2 + |rate[i] vm[vframes[i]] - v|^2 (float32 rows, float64 sums)."""
    for i in range(frames.shape[0]):
        f, g, r = frames[i], vframes[i], rate[i]
        c = 0.0
        for d in range(pm.shape[1]):
            x = pm[f, d] - p[d]
            c += x * x
        for d in range(vm.shape[1]):
            x = r * vm[g, d] - v[d]
            c += x * x
        out[i] = c
