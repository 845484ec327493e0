"""Compiled retrieval (numba; cached on disk): the gather, the search (with prefetch hints for
the library rows it reads scattered), the seams, the replay of retrieved segments and the splice;
each against the numpy steps of :mod:`posturemap.synth.retrieval` and
:mod:`posturemap.synth.splice`, the references it is tested against. Loaded only in processes
that already use numba (training, the studio, benchmarks). Quaternions are (w, x, y, z) tuples
inside; nothing is allocated per frame."""

from __future__ import annotations

import math

import llvmlite.binding
import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ..core.numba_kernels import _FAST, _mul, _near_turn, _rotate, exp_relative, fk, log_relative, slerp_track

_OPTS = dict(cache=True, nogil=True, fastmath=False)

# LLVM's prefetch hint; its name carries the pointer type: LLVM 14 (numba 0.59-0.60) wants
# "p0i8", later ones "p0" (and rename it where they still print typed pointers). Checked with
# numba 0.59.1 (LLVM 14), 0.61.2 (LLVM 15) and 0.68.1 (LLVM 22).
_PREFETCH = "llvm.prefetch.p0" if llvmlite.binding.llvm_version_info >= (15,) else "llvm.prefetch.p0i8"
AHEAD = 16  # how many rows ahead the search's scattered reads are prefetched


@intrinsic
def _prefetch(typingctx, arr, index):
    """Hint the CPU to bring the cache line of ``arr[index]`` (``index`` a tuple, one integer per
    dimension) into its caches (a read, kept in every level: LLVM's ``llvm.prefetch``); no
    effect on any value. The search reads library rows scattered over tens of megabytes: most
    reads miss the caches, and a row fetched while the previous ones are costed is there when
    its turn comes."""
    if not (isinstance(arr, types.Array) and isinstance(index, types.BaseTuple) and len(index) == arr.ndim
            and all(isinstance(t, types.Integer) for t in index)):
        return None  # not an array with one integer per dimension: no such signature
    sig = types.void(arr, index)

    def codegen(context, builder, signature, args):
        aryty, idxty = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = [context.cast(builder, x, t, types.intp)
               for x, t in zip(cgutils.unpack_tuple(builder, args[1], len(idxty)), idxty)]
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, idx, wraparound=False)
        i8p, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            _PREFETCH)
        builder.call(fn, [builder.bitcast(ptr, i8p), i32(0), i32(3), i32(1)])  # read, keep, data
        return context.get_dummy_value()

    return sig, codegen


@nb.njit(**_OPTS)
def _prefetch_row(arr, i):
    """:func:`_prefetch` of row ``i`` of ``arr`` (2-D): its first and last elements' lines (a
    row may straddle two)."""
    _prefetch(arr, (i, 0))
    _prefetch(arr, (i, arr.shape[1] - 1))


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
    """Lerp of library rotations i0 and i1 (sign-aligned) of joint j, a 4-tuple; not normalised
    (:func:`_mean_track` normalises the segments' sum)."""
    a0, a1, a2, a3 = float(rots[i0, j, 0]), float(rots[i0, j, 1]), float(rots[i0, j, 2]), float(rots[i0, j, 3])
    b0, b1, b2, b3 = float(rots[i1, j, 0]), float(rots[i1, j, 1]), float(rots[i1, j, 2]), float(rots[i1, j, 3])
    if a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 < 0.0:
        b0, b1, b2, b3 = -b0, -b1, -b2, -b3
    return a0 + f * (b0 - a0), a1 + f * (b1 - a1), a2 + f * (b2 - a2), a3 + f * (b3 - a3)


@nb.njit(**_OPTS)
def _row(a):
    return a[0], a[1], a[2], a[3]


@nb.njit(**_OPTS)
def _mean_track(rots, i0, i1, f, joints, wts, out):
    """The segments' mean rotation of each joint of ``joints`` (M,) at every sample, into out
    (T, M, 4): the normalised sum of the K samples ``_sample(rots, i0[k, u], i1[k, u], f[k, u], j)``,
    each weighed by ``wts[k]``, each segment's sign kept from sample to sample and set at the
    first sample by the first segment's (:func:`posturemap.synth.retrieval.average_rotations`,
    the reference). Segment by segment, sample by sample: each library frame read once for all
    the joints."""
    n_k, n_t, n_m = i0.shape[0], i0.shape[1], joints.shape[0]
    par0 = np.empty((n_t, n_m))  # the first segment's own sign changes, to its first sample
    first = np.empty((n_m, 4))
    prev = np.empty((n_m, 4))
    par, side = np.empty(n_m), np.empty(n_m)
    for k in range(n_k):
        g = wts[k]
        for u in range(n_t):
            a, b, w = i0[k, u], i1[k, u], f[k, u]
            for m in range(n_m):
                q0, q1, q2, q3 = _sample(rots, a, b, w, joints[m])
                if u == 0:
                    par[m] = 1.0
                    if k == 0:
                        first[m, 0], first[m, 1], first[m, 2], first[m, 3] = q0, q1, q2, q3
                        side[m] = 1.0
                    else:
                        d = q0 * first[m, 0] + q1 * first[m, 1] + q2 * first[m, 2] + q3 * first[m, 3]
                        side[m] = -1.0 if d < 0.0 else 1.0
                elif q0 * prev[m, 0] + q1 * prev[m, 1] + q2 * prev[m, 2] + q3 * prev[m, 3] < 0.0:
                    par[m] = -par[m]
                prev[m, 0], prev[m, 1], prev[m, 2], prev[m, 3] = q0, q1, q2, q3
                if k == 0:
                    par0[u, m] = par[m]
                    out[u, m, 0], out[u, m, 1], out[u, m, 2], out[u, m, 3] = g * q0, g * q1, g * q2, g * q3
                    continue
                h = g * (side[m] * par[m] * par0[u, m])
                out[u, m, 0], out[u, m, 1], out[u, m, 2], out[u, m, 3] = (
                    out[u, m, 0] + h * q0, out[u, m, 1] + h * q1, out[u, m, 2] + h * q2, out[u, m, 3] + h * q3)
    for u in range(n_t):
        for m in range(n_m):
            a0, a1, a2, a3 = out[u, m, 0], out[u, m, 1], out[u, m, 2], out[u, m, 3]
            n = max(math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3), 1e-12)
            out[u, m, 0], out[u, m, 1], out[u, m, 2], out[u, m, 3] = a0 / n, a1 / n, a2 / n, a3 / n


@nb.njit(**_OPTS)
def replay(rots, i0, i1, f, joints, cols, a2, b2, curves, lo, hi, out, wts):
    """Segments sampled at (i0, i1, f) (K, T), averaged (each weighed by ``wts`` (K,)), and the
    average seam-corrected into the columns ``cols`` (M,) of out (L, C, 4), for the new frames
    ``lo <= t < hi`` (the others are set to the identity).

    rots (N, J, 4) library rotations, of which the joints ``joints`` (M,) are replayed; a2/b2
    (2, C, 4) A at a_end-1, a_end and B at b_start, b_start+1, read at ``cols``; curves (4, L)
    offset curves, L = T - 4. One exponential per frame and joint, whatever K.
    """
    n_t = i0.shape[1]
    n_l = curves.shape[1]
    n_m = joints.shape[0]
    for t in range(n_l):
        if t < lo or t >= hi:
            for m in range(n_m):
                col = cols[m]
                out[t, col, 0], out[t, col, 1], out[t, col, 2], out[t, col, 3] = 1.0, 0.0, 0.0, 0.0
    means = np.empty((n_t, n_m, 4))  # every sample's: each segment's sign follows on through them
    _mean_track(rots, i0, i1, f, joints, wts, means)
    seam = np.empty((4, n_m, 4))  # the mean at t = -1, 0, d, d + 1
    for r, u in enumerate((0, 1, n_t - 2, n_t - 1)):
        seam[r] = means[u]
    # Per joint, the seam offsets: A's value and velocity, B's value and velocity.
    off = np.empty((n_m, 4, 3))
    for m in range(n_m):
        s_m1, s_0, s_d, s_d1 = _row(seam[0, m]), _row(seam[1, m]), _row(seam[2, m]), _row(seam[3, m])
        j = cols[m]
        a_0, a_1, b_0, b_1 = _row(a2[0, j]), _row(a2[1, j]), _row(b2[0, j]), _row(b2[1, j])
        ra = _log_rel(a_1, s_0)
        va1, va2 = _log_rel(a_1, a_0), _log_rel(s_0, s_m1)
        rb = _log_rel(b_0, s_d)
        vb1, vb2 = _log_rel(b_1, b_0), _log_rel(s_d1, s_d)
        for c in range(3):
            off[m, 0, c], off[m, 1, c] = ra[c], va1[c] - va2[c]
            off[m, 2, c], off[m, 3, c] = rb[c], vb1[c] - vb2[c]
    for t in range(lo, hi):
        mean = means[t + 2]
        c0, c1, c2, c3 = curves[0, t], curves[1, t], curves[2, t], curves[3, t]
        for m in range(n_m):
            ox = c0 * off[m, 0, 0] + c1 * off[m, 1, 0] + c2 * off[m, 2, 0] + c3 * off[m, 3, 0]
            oy = c0 * off[m, 0, 1] + c1 * off[m, 1, 1] + c2 * off[m, 2, 1] + c3 * off[m, 3, 1]
            oz = c0 * off[m, 0, 2] + c1 * off[m, 1, 2] + c2 * off[m, 2, 2] + c3 * off[m, 3, 2]
            ang = math.sqrt(ox * ox + oy * oy + oz * oz)
            h = math.sin(0.5 * ang) / ang if ang > 1e-8 else 0.5 - ang * ang / 48.0
            col = cols[m]
            out[t, col, 0], out[t, col, 1], out[t, col, 2], out[t, col, 3] = _mul(
                math.cos(0.5 * ang), ox * h, oy * h, oz * h, mean[m, 0], mean[m, 1], mean[m, 2], mean[m, 3])


@nb.njit(**_OPTS)
def lift_upper(rots, i0, i1, f, root, tops, a2, b2, curves, lo, hi, weight, out, wts):
    """:func:`posturemap.synth.retrieval.lift_upper`: the upper body's segments' own root
    (``root``'s column of rots at the samples ``(i0, i1, f)``, averaged (weighed by ``wts``) and
    seam-corrected as :func:`replay` does, A's and B's from ``a2``/``b2`` (2, J, 4)), and the
    turn of ``weight`` of the way from the legs' root in ``out`` to it applied to the joints
    ``tops`` of ``out`` (L, J, 4), new frames ``lo <= t < hi``."""
    n_l = curves.shape[1]
    lo, hi = max(lo, 0), min(hi, n_l)
    own = np.empty((n_l, 1, 4))
    a_r, b_r = np.empty((2, 1, 4)), np.empty((2, 1, 4))
    for r in range(2):
        for c in range(4):
            a_r[r, 0, c], b_r[r, 0, c] = a2[r, root, c], b2[r, root, c]
    joints, cols = np.full(1, root, dtype=np.int64), np.zeros(1, dtype=np.int64)
    replay(rots, i0, i1, f, joints, cols, a_r, b_r, curves, lo, hi, own, wts)
    for t in range(lo, hi):
        # the legs' root to the upper body's own: out[t, root]^-1 own[t], short arc, scaled
        w, x, y, z = _mul(out[t, root, 0], -out[t, root, 1], -out[t, root, 2], -out[t, root, 3],
                          own[t, 0, 0], own[t, 0, 1], own[t, 0, 2], own[t, 0, 3])
        if w < 0.0:
            w, x, y, z = -w, -x, -y, -z
        s = math.sqrt(x * x + y * y + z * z)
        half = weight * math.atan2(s, w)
        k = math.sin(half) / s if s > 1e-12 else weight
        c0, c1, c2, c3 = math.cos(half), x * k, y * k, z * k
        for m in range(tops.shape[0]):
            j = tops[m]
            q0, q1, q2, q3 = _mul(c0, c1, c2, c3, out[t, j, 0], out[t, j, 1], out[t, j, 2], out[t, j, 3])
            n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
            out[t, j, 0], out[t, j, 1], out[t, j, 2], out[t, j, 3] = q0 / n, q1 / n, q2 / n, q3 / n


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


# The search's seam costs: the sums of seam_costs, vectorised over the features (fast-math lets
# the compiler reorder a sum: within about 1e-15 of seam_costs' sequential sums, relative).
@nb.njit(cache=True, nogil=True, fastmath=_FAST)
def _pos_cost(pm, f, p):
    """The position part of a seam cost: ``|pm[f] - p|^2`` (float32 differences, float64 sum)."""
    c = 0.0
    for d in range(pm.shape[1]):
        x = pm[f, d] - p[d]
        c += x * x
    return c


@nb.njit(cache=True, nogil=True, fastmath=_FAST)
def _vel_cost(vm, g, v, r):
    """The velocity part of a seam cost: ``|r vm[g] - v|^2``."""
    c = 0.0
    for d in range(vm.shape[1]):
        x = r * vm[g, d] - v[d]
        c += x * x
    return c


@nb.njit(**_OPTS)
def _seam_costs(pm, vm, rows, g_rows, p, v, rates, out):
    """``out[i]`` = the seam cost of :func:`seam_costs` of ``rows[i]`` (velocity row ``g_rows[i]``);
    the rows :data:`AHEAD` further on are prefetched meanwhile."""
    n = rows.shape[0]
    for i in range(n):
        if i + AHEAD < n:
            _prefetch_row(pm, rows[i + AHEAD])
            _prefetch_row(vm, g_rows[i + AHEAD])
        out[i] = _pos_cost(pm, rows[i], p) + _vel_cost(vm, g_rows[i], v, rates[i])


@nb.njit(**_OPTS)
def _pos_costs(pm, rows, p, out):
    """The position part of :func:`_seam_costs` of each row."""
    for i in range(rows.shape[0]):
        out[i] = _pos_cost(pm, rows[i], p)


@nb.njit(**_OPTS)
def _vel_costs(vm, g_rows, v, rates, init, out):
    """:func:`_seam_costs` of rows whose position part is known (``init``, from :func:`_pos_costs`;
    the same bits as computing it again)."""
    for i in range(g_rows.shape[0]):
        out[i] = init[i] + _vel_cost(vm, g_rows[i], v, rates[i])


@nb.njit(**_OPTS)
def _first_smallest(c, work, n_w, need, out, n_out):
    """The ``need`` smallest of ``c[work[:n_w]]`` by (value, index), appended to ``out`` from
    ``n_out`` (a selection: for the few values the buckets leave)."""
    for r in range(need):
        best = r
        for i in range(r + 1, n_w):
            if c[work[i]] < c[work[best]] or (c[work[i]] == c[work[best]] and work[i] < work[best]):
                best = i
        work[r], work[best] = work[best], work[r]
        out[n_out + r] = work[r]


@nb.njit(**_OPTS)
def _buckets(c, work, n_w, n_b, bucket, count):
    """Spread ``c[work[i]]`` (``c[i]`` when ``work`` is None), ``i < n_w``, over ``n_b`` buckets
    between their min and max: each one's bucket into ``bucket``, the buckets' sizes into
    ``count``; 1 when done, 0 when all the values are equal, -1 when their range is not finite
    (an infinite or NaN value: no buckets either way)."""
    lo = hi = c[0] if work is None else c[work[0]]
    for i in range(1, n_w):
        x = c[i] if work is None else c[work[i]]
        lo, hi = min(lo, x), max(hi, x)
    if not hi - lo < np.inf:
        return -1
    if not hi > lo:
        return 0
    scale = n_b / (hi - lo)
    count[:] = 0
    for i in range(n_w):
        x = ((c[i] if work is None else c[work[i]]) - lo) * scale  # monotone in the value: equal values share a bucket
        b = np.int64(x) if x < n_b else n_b - 1
        bucket[i] = b
        count[b] += 1
    return 1


@nb.njit(**_OPTS)
def _smallest(c, keep):
    """Indices (keep,) of the ``keep`` smallest values of ``c`` (all of them if fewer), in no
    particular order: ``np.argpartition``'s set where the values are distinct; of values equal
    to the largest kept one, the first ones (the smallest by value, then index).

    Bucket selection: the values spread over 64 buckets between their min and max; the buckets
    below the one holding the ``keep``-th value are kept whole, that one is split again, and
    the last few are picked one by one. Each value's bucket is computed once per level (kept in
    a byte) and the first level reads ``c`` in order: on the search's 1,560 costs 9.1 -> 6.5 us
    and the gather's 1,281 neuron distances 7.6 -> 5.3 us against the previous bucket passes
    (which recomputed each bucket; they were faster than the one-pass max-heap before them, itself
    faster than ``np.partition`` and a pass).
    """
    n = c.shape[0]
    if n <= keep:
        return np.arange(n)
    n_b = 64
    out = np.empty(keep, dtype=np.int64)
    work = np.empty(n, dtype=np.int64)
    bucket = np.empty(n, dtype=np.uint8)
    count = np.empty(n_b, dtype=np.int64)
    n_out, n_w, need = 0, n, keep
    first = True  # the first level: work is 0..n-1, read c directly
    while n_w > 16:
        spread = _buckets(c, None if first else work, n_w, n_b, bucket, count)
        if spread == 0:  # all equal: the first ones
            for i in range(need):
                out[n_out + i] = i if first else work[i]
            return out
        if spread < 0:  # a range that is not finite: pick one by one
            break
        cut, below = 0, 0
        while below + count[cut] < need:
            below += count[cut]
            cut += 1
        m = 0
        for i in range(n_w):
            b = bucket[i]
            j = i if first else work[i]
            if b < cut:
                out[n_out] = j
                n_out += 1
            elif b == cut:
                work[m] = j
                m += 1
        first = False
        if m == n_w:  # no progress (a range too narrow to split): pick one by one
            break
        n_w, need = m, need - below
        if need == n_w:
            out[n_out:] = work[:n_w]
            return out
    if first:  # work was never filled: every index is still in
        for i in range(n):
            work[i] = i
    _first_smallest(c, work, n_w, need, out, n_out)
    return out


@nb.njit(**_OPTS)
def _prefilter(P, V, pos_of, frames, p, v, keep):
    """:meth:`posturemap.synth.retrieval.Retriever.prefilter`: the ``keep`` frames that match best at
    natural speed; ``P``, ``V`` the rows in index order (``pos_of`` a frame's row; for a seam at a
    segment's end ``V`` holds each frame's next frame's velocities)."""
    if frames.shape[0] <= keep:
        return frames
    n = frames.shape[0]
    c = np.empty(n)
    for i in range(n):
        if i + 2 * AHEAD < n:  # frames lie anywhere in the library: their rows' places too
            _prefetch(pos_of, (frames[i + 2 * AHEAD],))
        if i + AHEAD < n:
            r = pos_of[frames[i + AHEAD]]
            _prefetch_row(P, r)
            _prefetch_row(V, r)
        q = pos_of[frames[i]]
        c[i] = _pos_cost(P, q, p) + _vel_cost(V, q, v, 1.0)
    return frames[_smallest(c, keep)]


@nb.njit(**_OPTS)
def _best(total, cs, ce, k, out):
    """The ``k`` best distinct segments (indices into ``total``, ``cs``, ``ce``) written to ``out``,
    best first, ordered by (total, start, end); returns how many (fewer when less fit).

    One pass with a sorted buffer of ``k``: most candidates cost one comparison with the
    buffer's worst. A segment found from both seams has the same total twice and counts once.
    """
    n = 0
    for i in range(total.shape[0]):
        key = (total[i], cs[i], ce[i])
        if n == k:
            j = out[k - 1]
            if key >= (total[j], cs[j], ce[j]):
                continue
        dup = False
        for q in range(n):
            if cs[out[q]] == cs[i] and ce[out[q]] == ce[i]:
                dup = True
                break
        if dup:
            continue
        pos = n if n < k else k - 1
        while pos > 0:
            j = out[pos - 1]
            if key < (total[j], cs[j], ce[j]):
                out[pos] = j
                pos -= 1
            else:
                break
        out[pos] = i
        if n < k:
            n += 1
    return n


@nb.njit(**_OPTS)
def search(P, V, Vn, pos_of, clip_of, sa, sb, pa, va, pb, vb, ns, penalty, rates, keep, alphas,
           use_disp, gpos, heading, up, disp, disp_scale, w_disp, k):
    """:meth:`posturemap.synth.retrieval.Retriever.search_alphas` after the gather, in one call.

    The part's rows come in the inverted index's order (:attr:`posturemap.synth.retrieval.Retriever.lists`):
    ``P``, ``V`` and ``Vn`` (the next frame's velocities) at row ``pos_of[frame]``, so that the
    prefilter reads each gathered neuron's frames from one stretch of memory.

    Prefilters the gathered starts ``sa`` and ends ``sb`` to ``keep`` frames each, makes the
    candidate segments (every prefiltered start and end with every duration ``ns`` (W,), inside
    one clip), costs them once (``penalty`` (W,) the warp term and ``rates`` (W,) the speed
    factor of each duration; with ``use_disp`` the root displacement term against ``disp``
    (3,)) and ranks them for every alpha of ``alphas`` (A,): ``(s, e, total, cost_a, cost_b)``
    (A, k) and the count (A,) of each row's ``k`` best distinct segments, best first, ties
    ordered by start, then end (count 0 when no segment fits).
    """
    n_lib = clip_of.shape[0]
    fa = _prefilter(P, V, pos_of, sa, pa, va, keep)
    fb = _prefilter(P, Vn, pos_of, sb, pb, vb, keep)
    n_w = ns.shape[0]
    cap = (fa.shape[0] + fb.shape[0]) * n_w
    cs = np.empty(cap, dtype=np.int64)
    ce = np.empty(cap, dtype=np.int64)
    cw = np.empty(cap, dtype=np.int64)
    # The position part of a prefiltered frame's seam cost is the same at every warp: once each.
    pos_a, pos_b = np.empty(fa.shape[0]), np.empty(fb.shape[0])
    _pos_costs(P, pos_of[fa], pa, pos_a)
    _pos_costs(P, pos_of[fb], pb, pos_b)
    known = np.empty(cap)
    m = 0
    for i in range(fa.shape[0]):
        for w in range(n_w):
            s, e = fa[i], fa[i] + ns[w]
            if s >= 0 and e < n_lib and clip_of[s] == clip_of[e]:
                cs[m], ce[m], cw[m], known[m] = s, e, w, pos_a[i]
                m += 1
    m_a = m  # candidates from A's frames, then from B's
    for i in range(fb.shape[0]):
        for w in range(n_w):
            s, e = fb[i] - ns[w], fb[i]
            if s >= 0 and e < n_lib and clip_of[s] == clip_of[e]:
                cs[m], ce[m], cw[m], known[m] = s, e, w, pos_b[i]
                m += 1
    ca = np.empty(m)
    cb = np.empty(m)
    base = np.empty(m)
    moved = np.zeros(m)
    rate = np.empty(m)
    qs, qe = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)  # the segments' rows
    for i in range(m):
        if i + AHEAD < m:
            _prefetch(pos_of, (cs[i + AHEAD],))
            _prefetch(pos_of, (ce[i + AHEAD],))
        rate[i] = rates[cw[i]]
        qs[i], qe[i] = pos_of[cs[i]], pos_of[ce[i]]
    _vel_costs(V, qs[:m_a], va, rate[:m_a], known[:m_a], ca[:m_a])
    _seam_costs(P, V, qs[m_a:], qs[m_a:], pa, va, rate[m_a:], ca[m_a:])
    _seam_costs(P, Vn, qe[:m_a], qe[:m_a], pb, vb, rate[:m_a], cb[:m_a])
    _vel_costs(Vn, qe[m_a:], vb, rate[m_a:], known[m_a:m], cb[m_a:])
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    for i in range(m):  # what does not depend on alpha: the warp and displacement terms
        s, e = cs[i], ce[i]
        base[i] = penalty[cw[i]]
        if use_disp:
            da, db = gpos[e, a_] - gpos[s, a_], gpos[e, b_] - gpos[s, b_]
            c, sn = math.cos(heading[s]), math.sin(heading[s])
            dx = c * da + sn * db
            dz = -sn * da + c * db
            turn = heading[e] - heading[s]
            moved[i] = w_disp * (((dx - disp[0]) ** 2 + (dz - disp[1]) ** 2) / disp_scale ** 2
                                 + (turn - disp[2]) ** 2 / 0.25 ** 2)
    n_a = alphas.shape[0]
    out_s, out_e = np.zeros((n_a, k), dtype=np.int64), np.zeros((n_a, k), dtype=np.int64)
    out_t, out_ca, out_cb = np.zeros((n_a, k)), np.zeros((n_a, k)), np.zeros((n_a, k))
    count = np.zeros(n_a, dtype=np.int64)
    total = np.empty(m)
    sel = np.empty(k, dtype=np.int64)
    for r in range(n_a):
        alpha = alphas[r]
        for i in range(m):
            total[i] = 2 * (1 - alpha) * ca[i] + 2 * alpha * cb[i] + base[i]
            if use_disp:
                total[i] += moved[i]
        n_k = _best(total, cs, ce, k, sel)
        count[r] = n_k
        for i in range(n_k):
            b = sel[i]
            out_s[r, i], out_e[r, i], out_t[r, i], out_ca[r, i], out_cb[r, i] = cs[b], ce[b], total[b], ca[b], cb[b]
    return out_s, out_e, out_t, out_ca, out_cb, count


@nb.njit(**_OPTS)
def search_parts(P0, V0, Vn0, P1, V1, Vn1, pos_of, clip_of, sa0, sb0, sa1, sb1, pa0, va0, pb0, vb0, pa1, va1, pb1,
                 vb1, ns, penalty, rates, keep, alphas, use_disp, gpos, heading, up, disp, disp_scale, w_disp, k):
    """:func:`search` of both body parts in one call (the lower body's rows ``P0``, ``V0``,
    ``Vn0``, gathered frames ``sa0``, ``sb0`` and seam rows ``pa0``... with the displacement term
    when ``use_disp``; the upper body's without): ``(s, e, total, cost_a, cost_b)`` (2, A, k)
    and the counts (2, A), part first."""
    r0 = search(P0, V0, Vn0, pos_of, clip_of, sa0, sb0, pa0, va0, pb0, vb0, ns, penalty, rates, keep, alphas,
                use_disp, gpos, heading, up, disp, disp_scale, w_disp, k)
    r1 = search(P1, V1, Vn1, pos_of, clip_of, sa1, sb1, pa1, va1, pb1, vb1, ns, penalty, rates, keep, alphas,
                False, gpos, heading, up, disp, disp_scale, w_disp, k)
    n_a = alphas.shape[0]
    s, e = np.empty((2, n_a, k), dtype=np.int64), np.empty((2, n_a, k), dtype=np.int64)
    total, ca, cb = np.empty((2, n_a, k)), np.empty((2, n_a, k)), np.empty((2, n_a, k))
    count = np.empty((2, n_a), dtype=np.int64)
    s[0], e[0], total[0], ca[0], cb[0], count[0] = r0
    s[1], e[1], total[1], ca[1], cb[1], count[1] = r1
    return s, e, total, ca, cb, count


@nb.njit(**_OPTS)
def _sqdist(weights, i, cols, q, period):
    """Squared distance of neuron ``i`` to ``q`` over the columns ``cols`` (circular where
    ``period`` is finite; ``min(d, inf - d)`` leaves the others as they are)."""
    acc = 0.0
    for j in range(cols.shape[0]):
        diff = abs(weights[i, cols[j]] - q[j])
        diff = min(diff, period[j] - diff)
        acc += diff * diff
    return acc


@nb.njit(**_OPTS)
def _frames_of_nearest(d2, index_ptr, index_frames, n_take, budget):
    """The library frames of the neurons nearest first (squared distances ``d2``) until
    ``budget`` frames are gathered (see :func:`gather`)."""
    n = d2.shape[0]
    n_indexed = index_ptr.shape[0] - 1  # neurons past the last indexed one hold no frame
    # Usually a few dozen neurons hold the budget: sort the nearest 64 first, all n_take if short.
    for take in (min(64, n_take), n_take):
        near = np.sort(_smallest(d2, take)) if take < n else np.arange(n)
        near = near[np.argsort(d2[near], kind="mergesort")]  # nearest first, ties by neuron
        chosen = np.empty(near.shape[0], dtype=np.int64)
        n_c = 0
        total = 0
        for i in range(near.shape[0]):
            k = near[i]
            if k >= n_indexed:
                continue
            chosen[n_c] = k
            n_c += 1
            total += index_ptr[k + 1] - index_ptr[k]
            if total >= budget:
                break
        if total >= budget or take >= min(n, n_take):
            break
    out = np.empty(total, dtype=np.int64)
    m = 0
    for i in range(n_c):
        k = chosen[i]
        for f in range(index_ptr[k], index_ptr[k + 1]):
            out[m] = index_frames[f]
            m += 1
    return out


@nb.njit(**_OPTS)
def gather(weights, cols, q, period, index_ptr, index_frames, n_take, budget):
    """:meth:`posturemap.synth.retrieval.Retriever.gather` in one call: the library frames of the
    neurons nearest ``q`` (over the columns ``cols`` of ``weights``; circular where ``period``
    (len(cols),) is finite), nearest first, until ``budget`` frames are gathered."""
    d2 = np.empty(weights.shape[0])
    for i in range(weights.shape[0]):
        d2[i] = _sqdist(weights, i, cols, q, period)
    return _frames_of_nearest(d2, index_ptr, index_frames, n_take, budget)


@nb.njit(cache=True, nogil=True, fastmath=_FAST)
def _sqdists(w, q, period, circular, out):
    """``out[i]`` = squared distance of row ``w[i]`` to ``q`` (circular where ``period`` is finite,
    when ``circular``); vectorised over the columns."""
    for i in range(w.shape[0]):
        acc = 0.0
        if circular:
            for j in range(w.shape[1]):
                diff = abs(w[i, j] - q[j])
                diff = min(diff, period[j] - diff)
                acc += diff * diff
        else:
            for j in range(w.shape[1]):
                diff = w[i, j] - q[j]
                acc += diff * diff
        out[i] = acc


@nb.njit(**_OPTS)
def gather_seams(w0, w1, qa0, qa1, qb0, qb1, period0, period1, index_ptr, index_frames, n_take, budget):
    """:func:`gather` of both seams (``qa*``, ``qb*``) for both body parts, whose columns of the
    index map are ``w0`` and ``w1`` (N, D0/D1, contiguous): ``(a0, b0, a1, b1)``."""
    n = w0.shape[0]
    d2 = np.empty((4, n))
    circular = False
    for j in range(period0.shape[0]):
        circular |= period0[j] < np.inf
    for j in range(period1.shape[0]):
        circular |= period1[j] < np.inf
    _sqdists(w0, qa0, period0, circular, d2[0])
    _sqdists(w0, qb0, period0, circular, d2[1])
    _sqdists(w1, qa1, period1, circular, d2[2])
    _sqdists(w1, qb1, period1, circular, d2[3])
    return (_frames_of_nearest(d2[0], index_ptr, index_frames, n_take, budget),
            _frames_of_nearest(d2[1], index_ptr, index_frames, n_take, budget),
            _frames_of_nearest(d2[2], index_ptr, index_frames, n_take, budget),
            _frames_of_nearest(d2[3], index_ptr, index_frames, n_take, budget))


@nb.njit(**_OPTS)
def seam_features(gp, root_pos, heading, keys, up, fps, pose, vel, root):
    """The matching features of :func:`posturemap.synth.library.clip_features` at A's end and B's start.

    gp (4, J, 3) global joint positions, root_pos (4, 3), heading (4,) of the frames A[a_end-1],
    A[a_end], B[b_start], B[b_start+1]; keys (K,) key joints. Writes ``pose``/``vel`` (2, K, 3)
    and ``root`` (2, 5) of A's end (row 0; velocity backward) and B's start (row 1; forward).
    """
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    rel = np.empty((4, keys.shape[0], 3))
    for f in range(4):
        c, s = math.cos(heading[f]), math.sin(heading[f])
        for k in range(keys.shape[0]):
            va = gp[f, keys[k], a_] - root_pos[f, a_]
            vb = gp[f, keys[k], b_] - root_pos[f, b_]
            rel[f, k, a_] = c * va + s * vb
            rel[f, k, b_] = -s * va + c * vb
            rel[f, k, up] = gp[f, keys[k], up] - root_pos[f, up]
    for row in range(2):
        f, prev = (1, 0) if row == 0 else (2, 3)
        rate = fps if row == 0 else -1.0 * fps  # B's first frame: the forward difference, negated
        for k in range(keys.shape[0]):
            for x in range(3):
                pose[row, k, x] = rel[f, k, x]
                vel[row, k, x] = (rel[f, k, x] - rel[prev, k, x]) * rate
        da = (root_pos[f, a_] - root_pos[prev, a_]) * rate
        db = (root_pos[f, b_] - root_pos[prev, b_]) * rate
        c, s = math.cos(heading[f]), math.sin(heading[f])
        root[row, a_] = c * da + s * db
        root[row, b_] = -s * da + c * db
        root[row, up] = (root_pos[f, up] - root_pos[prev, up]) * rate
        root[row, 3] = (heading[f] - heading[prev]) * (1.0 if row == 0 else -1.0) * fps
        root[row, 4] = root_pos[f, up]


@nb.njit(**_OPTS)
def _scale_rows(flat, pidx, pdiv, pmul, vidx, vmul, p_out, v_out):
    """:meth:`posturemap.synth.retrieval.Retriever._scaled` of the rows of ``flat``, into ``p_out``
    and ``v_out`` (float32)."""
    for r in range(flat.shape[0]):
        for j in range(pidx.shape[0]):
            p_out[r, j] = np.float32(flat[r, pidx[j]] / pdiv[j] * pmul[j])
        for j in range(vidx.shape[0]):
            v_out[r, j] = np.float32(flat[r, vidx[j]] * vmul[j])


@nb.njit(**_OPTS)
def seam_rows(parents, a_rots, a_pos, b_rots, b_pos, ia, ib, a_gpos, a_heading, b_gpos, b_heading, keys, up, fps,
              pidx0, pdiv0, pmul0, vidx0, vmul0, pidx1, pdiv1, pmul1, vidx1, vmul1, pose, vel, root, p0, v0, p1, v1):
    """:meth:`posturemap.synth.retrieval.Retriever.seam_pair` in one call: the frames ``ia`` (2,) of
    A and ``ib`` of B through forward kinematics and :func:`seam_features` into ``pose``, ``vel``
    (2, K, 3) and ``root`` (2, 5), and both seams' rows of both parts (``_scaled`` with each
    part's plan) into ``p0``, ``v0`` and ``p1``, ``v1`` (2, D), row 0 A's end, row 1 B's start."""
    n_j = parents.shape[0]
    rots, pos = np.empty((4, n_j, 4)), np.empty((4, n_j, 3))
    root_pos, heading = np.empty((4, 3)), np.empty(4)
    for r in range(2):
        rots[r], pos[r], root_pos[r], heading[r] = a_rots[ia[r]], a_pos[ia[r]], a_gpos[ia[r]], a_heading[ia[r]]
        rots[r + 2], pos[r + 2] = b_rots[ib[r]], b_pos[ib[r]]
        root_pos[r + 2], heading[r + 2] = b_gpos[ib[r]], b_heading[ib[r]]
    grot, gp = np.empty((4, n_j, 4)), np.empty((4, n_j, 3))
    fk(parents, rots, pos, grot, gp)
    seam_features(gp, root_pos, heading, keys, up, fps, pose, vel, root)
    n_k = keys.shape[0]
    flat = np.empty((2, 6 * n_k + 5))
    for r in range(2):
        for k in range(n_k):
            for x in range(3):
                flat[r, 3 * k + x] = pose[r, k, x]
                flat[r, 3 * (n_k + k) + x] = vel[r, k, x]
        for x in range(5):
            flat[r, 6 * n_k + x] = root[r, x]
    _scale_rows(flat, pidx0, pdiv0, pmul0, vidx0, vmul0, p0, v0)
    _scale_rows(flat, pidx1, pdiv1, pmul1, vidx1, vmul1, p1, v1)


@nb.njit(**_OPTS)
def _seam_misses(src, k, ch, a0, a1, b0, b1, n_l):
    """Segment ``k``'s misses in channel ``ch`` of src (K, T, C) sampled at t = -1 .. d + 1 against
    A's values ``a0, a1`` and B's ``b0, b1``: value and velocity at A, value and velocity at B
    (:func:`posturemap.synth.retrieval.offset_values`'s ``r_a, v_a, r_b, v_b``)."""
    r_a = a1 - src[k, 1, ch]
    v_a = (a1 - a0) - (src[k, 1, ch] - src[k, 0, ch])
    r_b = b0 - src[k, n_l + 2, ch]
    v_b = (b1 - b0) - (src[k, n_l + 3, ch] - src[k, n_l + 2, ch])
    return r_a, v_a, r_b, v_b


@nb.njit(**_OPTS)
def _offset_mean(src, a0, a1, b0, b1, curves, out, ch):
    """Channel ``ch`` of :func:`posturemap.synth.retrieval.offset_values` averaged over the segments:
    src (K, T, C) sampled at t = -1 .. d + 1, seam values a0, a1 (A) and b0, b1 (B) (K-independent),
    curves (4, L); writes out[:, ch] (L, ...)."""
    n_k = src.shape[0]
    n_l = curves.shape[1]
    for t in range(n_l):
        out[t] = 0.0
    for k in range(n_k):
        r_a, v_a, r_b, v_b = _seam_misses(src, k, ch, a0, a1, b0, b1, n_l)
        for t in range(n_l):
            out[t] += (src[k, t + 2, ch] + curves[0, t] * r_a + curves[1, t] * v_a + curves[2, t] * r_b
                       + curves[3, t] * v_b)
    for t in range(n_l):
        out[t] /= n_k


@nb.njit(**_OPTS)
def _bend_paths(traj, a_h0, a_h1, b_a, b_b, b_h0, b_h1, curves, gate_lo, gate_hi):
    """:func:`posturemap.synth.retrieval.bend_paths` on traj (K, T, 4: a, b, heading, height) in place:
    A's headings ``a_h0, a_h1``, B's place ``b_a, b_b`` and headings ``b_h0, b_h1``, the gate
    ``BEND_GATE`` as ``gate_lo, gate_hi``."""
    n_k, n_t = traj.shape[0], traj.shape[1]
    n_l = curves.shape[1]
    dh = np.empty(n_t)
    bent = np.empty((n_t, 2))
    for k in range(n_k):
        r_a, v_a, r_b, v_b = _seam_misses(traj, k, 2, a_h0, a_h1, b_h0, b_h1, n_l)
        for t in range(n_l):
            dh[t + 2] = curves[0, t] * r_a + curves[1, t] * v_a + curves[2, t] * r_b + curves[3, t] * v_b
        dh[0] = dh[1] = r_a
        dh[n_t - 2] = dh[n_t - 1] = r_b
        bent[1, 0], bent[1, 1] = traj[k, 1, 0], traj[k, 1, 1]
        for t in range(n_t - 1):
            turn = 0.5 * (dh[t + 1] + dh[t])
            c, s = math.cos(turn), math.sin(turn)
            sa = traj[k, t + 1, 0] - traj[k, t, 0]
            sb = traj[k, t + 1, 1] - traj[k, t, 1]
            ra, rb = c * sa - s * sb, s * sa + c * sb
            if t == 0:
                bent[0, 0], bent[0, 1] = traj[k, 1, 0] - ra, traj[k, 1, 1] - rb
            else:
                bent[t + 1, 0], bent[t + 1, 1] = bent[t, 0] + ra, bent[t, 1] + rb
        p0a, p0b = traj[k, n_t - 2, 0], traj[k, n_t - 2, 1]
        da, db = bent[n_t - 2, 0] - p0a, bent[n_t - 2, 1] - p0b
        ma, mb = b_a - p0a, b_b - p0b
        lam = (ma * da + mb * db) / max(da * da + db * db, 1e-12)
        lam = min(max(lam, 0.0), 1.0)
        mended = 1.0 - math.hypot(ma - lam * da, mb - lam * db) / max(math.hypot(ma, mb), 1e-12)
        lam *= min(max((mended - gate_lo) / (gate_hi - gate_lo), 0.0), 1.0)
        for t in range(n_t):
            traj[k, t, 0] += lam * (bent[t, 0] - traj[k, t, 0])
            traj[k, t, 1] += lam * (bent[t, 1] - traj[k, t, 1])


@nb.njit(**_OPTS)
def trajectory(lib_gpos, lib_heading, i0, i1, f, a_pos, a_head, b_pos_in, b_head_in, align, up, curves, gpos,
               heading, shift, gate_lo, gate_hi):
    """The root trajectory of the lower body's segments (see :func:`posturemap.synth.retrieval.retrieve`):
    each segment's root path sampled at (i0, i1, f) (K, T), turned and moved to continue A
    (``a_pos`` (2, 3), ``a_head`` (2,): A at a_end-1, a_end), its seams corrected towards A and B
    (B at b_start, b_start+1 moved by the returned turn and ``shift``, when ``align`` to where
    the segments end), averaged. Writes ``gpos`` (L, 3), ``heading`` (L,) and ``shift`` (3,);
    returns B's turn ``dtheta``. ``curves`` (4, L) are the seam offsets (their value rows span the
    gap, so the horizontal path lands on B in in-betweening, where each path is first bent by
    :func:`_bend_paths` with the gate ``gate_lo, gate_hi``)."""
    n_k, n_t = i0.shape
    n_l = curves.shape[1]
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    traj = np.empty((n_k, n_t, 4))  # horizontal a_, b_, heading, height
    for k in range(n_k):
        g1a = lib_gpos[i0[k, 1], a_] + f[k, 1] * (lib_gpos[i1[k, 1], a_] - lib_gpos[i0[k, 1], a_])
        g1b = lib_gpos[i0[k, 1], b_] + f[k, 1] * (lib_gpos[i1[k, 1], b_] - lib_gpos[i0[k, 1], b_])
        h1 = lib_heading[i0[k, 1]] + f[k, 1] * (lib_heading[i1[k, 1]] - lib_heading[i0[k, 1]])
        theta0 = a_head[1] - h1
        c, s = math.cos(theta0), math.sin(theta0)
        for t in range(n_t):
            j0, j1, u = i0[k, t], i1[k, t], f[k, t]
            va = lib_gpos[j0, a_] + u * (lib_gpos[j1, a_] - lib_gpos[j0, a_]) - g1a
            vb = lib_gpos[j0, b_] + u * (lib_gpos[j1, b_] - lib_gpos[j0, b_]) - g1b
            traj[k, t, 0] = (c * va - s * vb) + a_pos[1, a_]
            traj[k, t, 1] = (s * va + c * vb) + a_pos[1, b_]
            traj[k, t, 2] = lib_heading[j0] + u * (lib_heading[j1] - lib_heading[j0]) + theta0
            traj[k, t, 3] = lib_gpos[j0, up] + u * (lib_gpos[j1, up] - lib_gpos[j0, up])
    end = np.zeros(3)
    for k in range(n_k):
        for x in range(3):
            end[x] += traj[k, n_t - 2, x]
    for x in range(3):
        end[x] /= n_k
    shift[:] = 0.0
    dtheta = 0.0
    if align:
        dtheta = end[2] - b_head_in[0]
        c, s = math.cos(dtheta), math.sin(dtheta)
        shift[a_] = end[0] - (c * b_pos_in[0, a_] - s * b_pos_in[0, b_])
        shift[b_] = end[1] - (s * b_pos_in[0, a_] + c * b_pos_in[0, b_])
    c, s = math.cos(dtheta), math.sin(dtheta)
    b_pos = np.empty((2, 3))
    b_head = np.empty(2)
    for i in range(2):
        b_pos[i, a_] = (c * b_pos_in[i, a_] - s * b_pos_in[i, b_]) + shift[a_]
        b_pos[i, b_] = (s * b_pos_in[i, a_] + c * b_pos_in[i, b_]) + shift[b_]
        b_head[i] = b_head_in[i] + dtheta
    turns = np.rint((end[2] - b_head[0]) / (2 * math.pi))
    for i in range(2):
        b_head[i] += 2 * math.pi * turns
    if not align:
        _bend_paths(traj, a_head[0], a_head[1], b_pos[0, a_], b_pos[0, b_], b_head[0], b_head[1], curves, gate_lo,
                    gate_hi)
    out = np.empty(n_l)
    _offset_mean(traj, a_pos[0, a_], a_pos[1, a_], b_pos[0, a_], b_pos[1, a_], curves, out, 0)
    gpos[:, a_] = out
    _offset_mean(traj, a_pos[0, b_], a_pos[1, b_], b_pos[0, b_], b_pos[1, b_], curves, out, 1)
    gpos[:, b_] = out
    _offset_mean(traj, a_head[0], a_head[1], b_head[0], b_head[1], curves, out, 2)
    heading[:] = out
    _offset_mean(traj, a_pos[0, up], a_pos[1, up], b_pos_in[0, up], b_pos_in[1, up], curves, out, 3)
    gpos[:, up] = out
    return dtheta


@nb.njit(**_OPTS)
def seam_distances(rots, gpos, frames, joints, reference, up, height_scale, xa, xb, dims, dim_ptr, out):
    """:meth:`posturemap.synth.retrieval.Retriever.seam_distances` for a map in logmap mode (no circular
    dimension): segment ``i`` starts at library frame ``frames[2 i]`` and ends at ``frames[2 i + 1]``
    and counts the feature dimensions ``dims[dim_ptr[i]:dim_ptr[i + 1]]``; ``out[i]`` in degrees."""
    n_j = joints.shape[0]
    x = np.empty((frames.shape[0], 3 * n_j + 1))
    for r in range(frames.shape[0]):
        f = frames[r]
        for m in range(n_j):
            j = joints[m]
            w, a, b, c = _mul(reference[m, 0], -reference[m, 1], -reference[m, 2], -reference[m, 3],
                              float(rots[f, j, 0]), float(rots[f, j, 1]), float(rots[f, j, 2]), float(rots[f, j, 3]))
            if w < 0.0:
                w, a, b, c = -w, -a, -b, -c
            s = math.sqrt(a * a + b * b + c * c)
            k = 2.0 * math.atan2(s, w) / s if s > 1e-8 else 2.0 + s * s / 3.0
            x[r, 3 * m], x[r, 3 * m + 1], x[r, 3 * m + 2] = a * k, b * k, c * k
        x[r, 3 * n_j] = gpos[f, up] / height_scale
    for i in range(out.shape[0]):
        da = 0.0
        db = 0.0
        for q in range(dim_ptr[i], dim_ptr[i + 1]):
            d = dims[q]
            da += (x[2 * i, d] - xa[d]) ** 2
            db += (x[2 * i + 1, d] - xb[d]) ** 2
        n = max(dim_ptr[i + 1] - dim_ptr[i], 1)
        out[i] = max(math.sqrt(da), math.sqrt(db)) / math.sqrt(n / 3.0) * (180.0 / math.pi)


@nb.njit(**_OPTS)
def segment_times(clip_start, clip_of, clip_end, s, e, d, t, i0, i1, f):
    """:func:`posturemap.synth.retrieval.segment_times` into ``i0``, ``i1``, ``f`` (K, T) at times ``t`` (T,)."""
    for k in range(s.shape[0]):
        lo = clip_start[clip_of[s[k]]]
        hi = clip_end[s[k]] - 1
        step = (e[k] - s[k]) / d
        for j in range(t.shape[0]):
            u = s[k] + t[j] * step  # outside the clip: extrapolated from its two edge frames
            a = min(max(np.int64(math.floor(u)), lo), max(hi - 1, lo))
            i0[k, j] = a
            i1[k, j] = min(a + 1, hi)
            f[k, j] = u - a


@nb.njit(**_OPTS)
def replay_part(rots, clip_start, clip_of, clip_end, s, e, d, t, joints, cols, a_rots, b_rots, ia, ib, curves, lo,
                hi, out, root, lib_gpos, lib_heading, lib_contacts, a_gpos, a_heading, b_gpos, b_heading, align, up,
                gpos, heading, shift, contacts, lift_root, tops, lift, wts, gate_lo, gate_hi):
    """One body part of :func:`posturemap.synth.retrieval.replay` in one call: the segments
    ``[s, e]`` (K,) sampled at the times ``t`` (:func:`segment_times`), averaged and
    seam-corrected into the columns ``cols`` of ``out`` (:func:`replay`; A's rows ``ia`` (2,)
    of ``a_rots``, B's rows ``ib`` of ``b_rots``); with ``root``, also the root trajectory
    (:func:`trajectory`, from the tracks' ``a_gpos``/``a_heading`` and ``b_gpos``/``b_heading``
    at the same rows, into ``gpos``, ``heading``, ``shift``; returns B's turn) and the planted
    feet of the first segment's nearest recorded frames (into ``contacts`` (L, legs)).
    With ``lift_root`` >= 0 (the upper body, the legs already in ``out``), the joints ``tops``
    turned by :func:`lift_upper` (``lift`` its weight). ``wts`` (K,): each segment's weight in
    the average; ``gate_lo, gate_hi``: the path's bend (:func:`trajectory`). Returns 0.0 without
    ``root``."""
    n_k, n_t = s.shape[0], t.shape[0]
    i0, i1, f = np.empty((n_k, n_t), dtype=np.int64), np.empty((n_k, n_t), dtype=np.int64), np.empty((n_k, n_t))
    segment_times(clip_start, clip_of, clip_end, s, e, d, t, i0, i1, f)
    n_c = a_rots.shape[1]
    a2, b2 = np.empty((2, n_c, 4)), np.empty((2, n_c, 4))
    for r in range(2):
        a2[r] = a_rots[ia[r]]
        b2[r] = b_rots[ib[r]]
    replay(rots, i0, i1, f, joints, cols, a2, b2, curves, lo, hi, out, wts)
    if lift_root >= 0:
        lift_upper(rots, i0, i1, f, lift_root, tops, a2, b2, curves, lo, hi, lift, out, wts)
    if not root:
        return 0.0
    a_pos, a_head, b_pos, b_head = np.empty((2, 3)), np.empty(2), np.empty((2, 3)), np.empty(2)
    for r in range(2):
        a_pos[r] = a_gpos[ia[r]]
        b_pos[r] = b_gpos[ib[r]]
        a_head[r] = a_heading[ia[r]]
        b_head[r] = b_heading[ib[r]]
    dtheta = trajectory(lib_gpos, lib_heading, i0, i1, f, a_pos, a_head, b_pos, b_head, align, up, curves, gpos,
                        heading, shift, gate_lo, gate_hi)
    for u in range(contacts.shape[0]):
        contacts[u] = lib_contacts[np.int64(np.rint(i0[0, u + 2] + f[0, u + 2]))]
    return dtheta


@nb.njit(**_OPTS)
def splice_rotations(a, b, w, out):
    """:func:`posturemap.synth.splice.splice_rotations` in one call: per frame ``t`` of a (L, J, 4)
    and b, ``a[t]`` where ``w[t] <= 0``, the SLERP at ``w[t]`` between (on the arc that goes on
    from frame to frame, :func:`~posturemap.core.numba_kernels.slerp_track`), ``b[t]`` where
    ``w[t] >= 1``, each joint's sign in the hemisphere of the frame before."""
    n_l, n_j = a.shape[0], a.shape[1]
    lo, hi = n_l, 0
    for t in range(n_l):
        if 0.0 < w[t] < 1.0:
            lo, hi = min(lo, t), t + 1
    if lo < hi:  # one stretch: w rises
        slerp_track(a[lo:hi], b[lo:hi], w[lo:hi], out[lo:hi], np.zeros(n_j, dtype=np.bool_))
    for t in range(n_l):
        if w[t] <= 0.0:
            out[t] = a[t]
        elif w[t] < 1.0:
            continue
        else:
            out[t] = b[t]
            if t > 0:
                for j in range(n_j):
                    if (b[t, j, 0] * out[t - 1, j, 0] + b[t, j, 1] * out[t - 1, j, 1]
                            + b[t, j, 2] * out[t - 1, j, 2] + b[t, j, 3] * out[t - 1, j, 3]) < 0.0:
                        for c in range(4):
                            out[t, j, c] = -b[t, j, c]


@nb.njit(**_OPTS)
def splice_path(g1, h1, g2, h2, turn2, w, a_pos, a_heading, up, gpos, heading):
    """The spliced root path of :func:`posturemap.synth.splice.splice` into ``gpos`` (L, 3) and
    ``heading`` (L,): the turning rates of ``first`` (``h1``) and of ``second`` (``h2 + turn2``)
    blended by ``w`` (L,) and integrated from A's heading; their horizontal velocities (``g1``,
    ``g2``) in their own headings' frames blended so, turned to the path's heading and
    integrated from A's root (``a_pos``); the height blended as it is."""
    n_l = w.shape[0]
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    acc_a, acc_b = 0.0, 0.0
    acc_h = 0.0
    for t in range(n_l):
        u = 1.0 - w[t]
        q1 = a_heading if t == 0 else h1[t - 1]
        q2 = a_heading if t == 0 else h2[t - 1] + turn2
        acc_h += u * (h1[t] - q1) + w[t] * ((h2[t] + turn2) - q2)
        heading[t] = a_heading + acc_h
        d1a = g1[t, a_] - (a_pos[a_] if t == 0 else g1[t - 1, a_])
        d1b = g1[t, b_] - (a_pos[b_] if t == 0 else g1[t - 1, b_])
        d2a = g2[t, a_] - (a_pos[a_] if t == 0 else g2[t - 1, a_])
        d2b = g2[t, b_] - (a_pos[b_] if t == 0 else g2[t - 1, b_])
        c1, s1 = math.cos(heading[t] - h1[t]), math.sin(heading[t] - h1[t])
        c2, s2 = math.cos(heading[t] - (h2[t] + turn2)), math.sin(heading[t] - (h2[t] + turn2))
        acc_a += u * (c1 * d1a - s1 * d1b) + w[t] * (c2 * d2a - s2 * d2b)
        acc_b += u * (s1 * d1a + c1 * d1b) + w[t] * (s2 * d2a + c2 * d2b)
        gpos[t, a_] = a_pos[a_] + acc_a
        gpos[t, b_] = a_pos[b_] + acc_b
        gpos[t, up] = u * g1[t, up] + w[t] * g2[t, up]


@nb.njit(**_OPTS)
def _turned(v, c, s, up):
    """:func:`posturemap.synth.trajectory.rotate_about_up` of one vector (3,) by the turn of cosine
    ``c`` and sine ``s``."""
    a_, b_ = (up + 1) % 3, (up + 2) % 3
    out = v.copy()
    out[a_] = c * v[a_] - s * v[b_]
    out[b_] = s * v[a_] + c * v[b_]
    return out


@nb.njit(**_OPTS)
def splice(a_rots, b_rots, w, g1, h1, g2, h2, a_pos, a_heading, b_pos, b_dtheta, b_shift, c1, c2, up, rots, gpos,
           heading, shift, contacts):
    """:func:`posturemap.synth.splice.splice` in one call: the rotations (:func:`splice_rotations`)
    and root path (:func:`splice_path`) of ``first`` (``a_rots``, ``g1``, ``h1``, contacts ``c1``)
    blended into ``second`` (``b_rots``, ``g2``, ``h2``, ``c2``; it placed B by ``b_dtheta``,
    ``b_shift``) by ``w``; B (``b_pos``, as it lies in its clip) carried to the path's end.
    Writes ``rots``, ``gpos``, ``heading``, ``shift`` and ``contacts``; returns B's turn."""
    splice_rotations(a_rots, b_rots, w, rots)
    turn2 = 2 * math.pi * np.rint((h1[0] - h2[0]) / (2 * math.pi))
    splice_path(g1, h1, g2, h2, turn2, w, a_pos, a_heading, up, gpos, heading)
    n_l = w.shape[0]
    turn = heading[n_l - 1] - (h2[n_l - 1] + turn2)
    b_placed = _turned(b_pos, math.cos(b_dtheta), math.sin(b_dtheta), up) + b_shift
    end = gpos[n_l - 1] + _turned(b_placed - g2[n_l - 1], math.cos(turn), math.sin(turn), up)
    dtheta = b_dtheta + turn
    shift[:] = end - _turned(b_pos, math.cos(dtheta), math.sin(dtheta), up)
    for t in range(n_l):
        contacts[t] = c1[t] if w[t] < 0.5 else c2[t]
    return dtheta


@nb.njit(**_OPTS)
def _replay_half(rots, clip_start, clip_of, clip_end, s0, e0, s1, e1, skip_upper, d, t, joints0, joints1,
                 open_joints, a_rots, b_rots, ia, ib, curves, lo, hi, lib_gpos, lib_heading, lib_contacts, a_gpos,
                 a_heading, b_gpos, b_heading, up, out, gpos, heading, shift, contacts, lift_root, tops, lift):
    """One half of a splice as :func:`posturemap.synth.retrieval.replay` makes it with
    ``skip_unconfident`` and its legs confident (B placed to continue A): the rotations of the new
    frames ``lo <= t < hi`` into ``out`` (the identity elsewhere, in the open joints and in a
    skipped upper body), the lower body's segments ``[s0, e0]`` with the root path and contacts,
    the upper body's ``[s1, e1]`` (its ``tops`` turned by :func:`lift_upper` with ``lift_root``
    and ``lift``, as :func:`replay_part` does); returns B's turn."""
    for u in range(out.shape[0]):
        for j in range(open_joints.shape[0]):
            out[u, open_joints[j], 0] = 1.0
            for c in range(1, 4):
                out[u, open_joints[j], c] = 0.0
    dtheta = replay_part(rots, clip_start, clip_of, clip_end, s0, e0, d, t, joints0, joints0, a_rots, b_rots, ia, ib,
                         curves, lo, hi, out, True, lib_gpos, lib_heading, lib_contacts, a_gpos, a_heading, b_gpos,
                         b_heading, True, up, gpos, heading, shift, contacts, -1, tops, lift, np.ones(s0.shape[0]),
                         0.0, 1.0)  # B placed where the legs end: no path to bend (the gate is unused)
    if skip_upper:
        for u in range(out.shape[0]):
            for j in range(joints1.shape[0]):
                out[u, joints1[j], 0] = 1.0
                for c in range(1, 4):
                    out[u, joints1[j], c] = 0.0
    else:
        replay_part(rots, clip_start, clip_of, clip_end, s1, e1, d, t, joints1, joints1, a_rots, b_rots, ia, ib,
                    curves, lo, hi, out, False, lib_gpos, lib_heading, lib_contacts, a_gpos, a_heading, b_gpos,
                    b_heading, True, up, gpos[:0], heading[:0], shift, contacts[:0],
                    lift_root, tops, lift, np.ones(s1.shape[0]), 0.0, 1.0)
    return dtheta


@nb.njit(**_OPTS)
def spliced(rots, clip_start, clip_of, clip_end, s_a0, e_a0, s_a1, e_a1, s_b0, e_b0, s_b1, e_b1, skip_upper, d, t,
            joints0, joints1, open_joints, a_rots, b_rots, ia, ib, curves, frames, lib_gpos, lib_heading,
            lib_contacts, a_gpos, a_heading, b_gpos, b_heading, up, w, out, gpos, heading, shift, contacts,
            lift_root, tops, lift):
    """:func:`posturemap.synth.splice.spliced` after the search, in one call: both halves replayed
    (:func:`_replay_half`: the segments ``[s_a0, e_a0]`` (lower body) and ``[s_a1, e_a1]`` (upper)
    of the half continuing A, ``s_b*``, ``e_b*`` of the half arriving in B; ``skip_upper`` (2,)
    a half's upper body left out, ``frames`` (2, 2) the new frames each half shows; both halves'
    legs are replayed; ``lift_root``, ``tops``, ``lift`` as for :func:`replay_part`), then
    spliced by the weights ``w`` (:func:`splice`) into ``out``
    (L, J, 4), ``gpos``, ``heading``, ``shift`` and ``contacts``; returns B's turn."""
    n_l, n_j = out.shape[0], out.shape[1]
    rot = np.empty((2, n_l, n_j, 4))
    g, h = np.empty((2, n_l, 3)), np.empty((2, n_l))
    sh = np.empty((2, 3))
    con = np.empty((2, n_l, contacts.shape[1]), dtype=contacts.dtype)
    _replay_half(rots, clip_start, clip_of, clip_end, s_a0, e_a0, s_a1, e_a1, skip_upper[0], d, t, joints0, joints1,
                 open_joints, a_rots, b_rots, ia, ib, curves, max(frames[0, 0], 0), min(frames[0, 1], n_l), lib_gpos,
                 lib_heading, lib_contacts, a_gpos, a_heading, b_gpos, b_heading, up, rot[0], g[0], h[0],
                 sh[0], con[0], lift_root, tops, lift)
    turn_b = _replay_half(rots, clip_start, clip_of, clip_end, s_b0, e_b0, s_b1, e_b1, skip_upper[1], d, t, joints0,
                          joints1, open_joints, a_rots, b_rots, ia, ib, curves, max(frames[1, 0], 0),
                          min(frames[1, 1], n_l), lib_gpos, lib_heading, lib_contacts, a_gpos, a_heading, b_gpos,
                          b_heading, up, rot[1], g[1], h[1], sh[1], con[1], lift_root, tops, lift)
    a_pos, b_pos = np.empty(3), np.empty(3)  # in float64, whatever the tracks' type (as splice() has them)
    for c in range(3):
        a_pos[c], b_pos[c] = a_gpos[ia[1], c], b_gpos[ib[0], c]
    return splice(rot[0], rot[1], w, g[0], h[0], g[1], h[1], a_pos, np.float64(a_heading[ia[1]]), b_pos, turn_b,
                  sh[1], con[0], con[1], up, out, gpos, heading, shift, contacts)


@nb.njit(**_OPTS)
def open_columns(chain, a_rots, b_rots, a_prev, a_end, b_start, b_next, a_positions, b_positions, basis, rots, pos):
    """What a fully retrieved transition leaves open, as the spline method makes it
    (:func:`posturemap.synth.engine._open_columns`): the rotations of the joints ``chain`` above the
    root into their columns of ``rots`` (L, J, 4), and every joint's local translation into
    ``pos`` (L, J, 3), each the cubic Hermite ``basis`` (L, 4) from A's frame ``a_end`` (its rate
    from ``a_prev``) to B's ``b_start`` (its rate to ``b_next``): rotations as rotation vectors
    about B's, translations as they are."""
    n_l, n_c = basis.shape[0], chain.shape[0]
    if n_c:
        q, ref = np.empty((4, n_c, 4)), np.empty((n_c, 4))
        for m in range(n_c):
            ref[m] = b_rots[b_start, chain[m]]
            q[0, m], q[1, m] = a_rots[a_prev, chain[m]], a_rots[a_end, chain[m]]
            q[2, m], q[3, m] = ref[m], b_rots[b_next, chain[m]]
        seam = np.empty((4, n_c, 3))
        log_relative(q, ref, seam)
        for m in range(n_c):  # A's rate, not a whole turn (engine._unwrap_seam_rows)
            seam[0, m, 0], seam[0, m, 1], seam[0, m, 2] = _near_turn(seam[0, m, 0], seam[0, m, 1], seam[0, m, 2],
                                                                     seam[1, m, 0], seam[1, m, 1], seam[1, m, 2])
        lin = np.empty((n_l, n_c, 3))
        for t in range(n_l):
            for m in range(n_c):
                for c in range(3):
                    lin[t, m, c] = (basis[t, 0] * seam[1, m, c] + basis[t, 1] * (seam[1, m, c] - seam[0, m, c])
                                    + basis[t, 2] * seam[2, m, c] + basis[t, 3] * (seam[3, m, c] - seam[2, m, c]))
        part = np.empty((n_l, n_c, 4))
        exp_relative(lin, ref, part)
        for t in range(n_l):
            for m in range(n_c):
                rots[t, chain[m]] = part[t, m]
    for t in range(n_l):
        for j in range(pos.shape[1]):
            for c in range(3):
                pa, pb = a_positions[a_end, j, c], b_positions[b_start, j, c]
                pos[t, j, c] = (basis[t, 0] * pa + basis[t, 1] * (pa - a_positions[a_prev, j, c]) + basis[t, 2] * pb
                                + basis[t, 3] * (b_positions[b_next, j, c] - pb))


@nb.njit(**_OPTS)
def _chain_world(rots, positions, f, chain, upto):
    """Global rotation (w, x, y, z) and position of ``chain[upto - 1]`` at frame ``f`` of local
    ``rots``/``positions`` (``chain`` top first, its top without a parent; ``upto`` at least 1)."""
    j = chain[0]
    w, x, y, z = rots[f, j, 0], rots[f, j, 1], rots[f, j, 2], rots[f, j, 3]
    px, py, pz = positions[f, j, 0], positions[f, j, 1], positions[f, j, 2]
    for m in range(1, upto):
        c = chain[m]
        dx, dy, dz = _rotate(w, x, y, z, positions[f, c, 0], positions[f, c, 1], positions[f, c, 2])
        px, py, pz = px + dx, py + dy, pz + dz
        w, x, y, z = _mul(w, x, y, z, rots[f, c, 0], rots[f, c, 1], rots[f, c, 2], rots[f, c, 3])
    return w, x, y, z, px, py, pz


@nb.njit(**_OPTS)
def _seam_carrier(rots, positions, f, chain, upto, turn, shift, sq, sp, row):
    """The carrier's world at frame ``f`` into row ``row`` of ``sq`` (4, 1, 4) and ``sp`` (4, 3),
    turned by the quaternion ``turn`` (4,) and moved by ``shift`` (3,)."""
    w, x, y, z, px, py, pz = _chain_world(rots, positions, f, chain, upto)
    w, x, y, z = _mul(turn[0], turn[1], turn[2], turn[3], w, x, y, z)
    px, py, pz = _rotate(turn[0], turn[1], turn[2], turn[3], px, py, pz)
    sq[row, 0, 0], sq[row, 0, 1], sq[row, 0, 2], sq[row, 0, 3] = w, x, y, z
    sp[row, 0], sp[row, 1], sp[row, 2] = px + shift[0], py + shift[1], pz + shift[2]


@nb.njit(**_OPTS)
def carry_chain(rots, positions, chain, k, root, a_rots, a_positions, a_gpos, a_prev, a_end, b_rots, b_positions,
                b_gpos, b_start, b_next, up, dtheta, shift, basis, bump, solve):
    """:func:`posturemap.synth.trajectory.carry_chain` in one call (its numpy steps the
    reference): the joint ``chain[k]`` from A's frame ``a_end`` (rate from ``a_prev``) to B's
    ``b_start`` (rate to ``b_next``), B's turned by ``dtheta`` about axis ``up`` and moved by
    ``shift``, a cubic Hermite ``basis`` (L, 4) in the world, bent by ``bump`` (L, T) times
    ``solve`` (T, L) applied to the root's ground path's departure from its own Hermite (no bend
    where T is 0), under the fixed joints ``chain[:k]``; the root's local turn and place made
    again so that its global ones stay."""
    n_l, n_c = basis.shape[0], chain.shape[0]
    j = chain[k]
    gq, gp = np.empty((n_l, 4)), np.empty((n_l, 3))
    for t in range(n_l):
        w, x, y, z, px, py, pz = _chain_world(rots, positions, t, chain, n_c)
        dx, dy, dz = _rotate(w, x, y, z, positions[t, root, 0], positions[t, root, 1], positions[t, root, 2])
        gp[t, 0], gp[t, 1], gp[t, 2] = px + dx, py + dy, pz + dz
        gq[t, 0], gq[t, 1], gq[t, 2], gq[t, 3] = _mul(w, x, y, z, rots[t, root, 0], rots[t, root, 1],
                                                      rots[t, root, 2], rots[t, root, 3])
    still, none = np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3)
    turn = np.zeros(4)
    turn[0] = math.cos(0.5 * dtheta)
    turn[1 + up] = math.sin(0.5 * dtheta)
    sq, sp = np.empty((4, 1, 4)), np.empty((4, 3))
    _seam_carrier(a_rots, a_positions, a_prev, chain, k + 1, still, none, sq, sp, 0)
    _seam_carrier(a_rots, a_positions, a_end, chain, k + 1, still, none, sq, sp, 1)
    _seam_carrier(b_rots, b_positions, b_start, chain, k + 1, turn, shift, sq, sp, 2)
    _seam_carrier(b_rots, b_positions, b_next, chain, k + 1, turn, shift, sq, sp, 3)
    ref = sq[2].copy()
    logs = np.empty((4, 1, 3))
    log_relative(sq, ref, logs)
    logs[0, 0, 0], logs[0, 0, 1], logs[0, 0, 2] = _near_turn(logs[0, 0, 0], logs[0, 0, 1], logs[0, 0, 2],
                                                              logs[1, 0, 0], logs[1, 0, 1], logs[1, 0, 2])
    lin, new_p = np.empty((n_l, 1, 3)), np.empty((n_l, 3))
    for t in range(n_l):
        for c in range(3):
            lin[t, 0, c] = (basis[t, 0] * logs[1, 0, c] + basis[t, 1] * (logs[1, 0, c] - logs[0, 0, c])
                            + basis[t, 2] * logs[2, 0, c] + basis[t, 3] * (logs[3, 0, c] - logs[2, 0, c]))
            new_p[t, c] = (basis[t, 0] * sp[1, c] + basis[t, 1] * (sp[1, c] - sp[0, c]) + basis[t, 2] * sp[2, c]
                           + basis[t, 3] * (sp[3, c] - sp[2, c]))
    new_q = np.empty((n_l, 1, 4))
    exp_relative(lin, ref, new_q)
    n_b = bump.shape[1]
    if n_b:
        ground = np.empty((4, 3))
        for c in range(3):
            ground[0, c], ground[1, c] = a_gpos[a_prev, c], a_gpos[a_end, c]
        for row, f in ((2, b_start), (3, b_next)):
            vx, vy, vz = _rotate(turn[0], turn[1], turn[2], turn[3], b_gpos[f, 0], b_gpos[f, 1], b_gpos[f, 2])
            ground[row, 0], ground[row, 1], ground[row, 2] = vx + shift[0], vy + shift[1], vz + shift[2]
        bend = np.zeros((n_l, 3))
        for t in range(n_l):
            for c in range(3):
                if c != up:
                    bend[t, c] = gp[t, c] - (basis[t, 0] * ground[1, c] + basis[t, 1] * (ground[1, c] - ground[0, c])
                                             + basis[t, 2] * ground[2, c] + basis[t, 3] * (ground[3, c] - ground[2, c]))
        coef = np.zeros((n_b, 3))
        for i in range(n_b):
            for t in range(n_l):
                for c in range(3):
                    coef[i, c] += solve[i, t] * bend[t, c]
        for t in range(n_l):
            for i in range(n_b):
                for c in range(3):
                    new_p[t, c] += bump[t, i] * coef[i, c]
    for t in range(n_l):
        w, x, y, z = new_q[t, 0, 0], new_q[t, 0, 1], new_q[t, 0, 2], new_q[t, 0, 3]
        px, py, pz = new_p[t, 0], new_p[t, 1], new_p[t, 2]
        if k > 0:  # into the frame of the fixed joints above it
            fw, fx, fy, fz, fpx, fpy, fpz = _chain_world(rots, positions, t, chain, k)
            w, x, y, z = _mul(fw, -fx, -fy, -fz, w, x, y, z)
            px, py, pz = _rotate(fw, -fx, -fy, -fz, px - fpx, py - fpy, pz - fpz)
        rots[t, j, 0], rots[t, j, 1], rots[t, j, 2], rots[t, j, 3] = w, x, y, z
        positions[t, j, 0], positions[t, j, 1], positions[t, j, 2] = px, py, pz
        cw, cx, cy, cz, cpx, cpy, cpz = _chain_world(rots, positions, t, chain, n_c)
        rots[t, root, 0], rots[t, root, 1], rots[t, root, 2], rots[t, root, 3] = _mul(
            cw, -cx, -cy, -cz, gq[t, 0], gq[t, 1], gq[t, 2], gq[t, 3])
        positions[t, root, 0], positions[t, root, 1], positions[t, root, 2] = _rotate(
            cw, -cx, -cy, -cz, gp[t, 0] - cpx, gp[t, 1] - cpy, gp[t, 2] - cpz)
