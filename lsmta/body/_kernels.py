"""Compiled kernels of the body model: the skeleton's chain of transforms, every point's
skin distance (and its derivatives), and the silhouette term's search along each line of
sight, one pass over all points (numba, ``prange`` over points or lines).

They compute what the plain numpy code of :mod:`lsmta.body.skeleton`,
:mod:`lsmta.body.metaballs` and :mod:`lsmta.body.silhouette` computed before them (the
tests compare the two); the fits call them thousands of times with a few hundred points
each, where numpy spent its time in per-segment loops and small-array overhead. No
argument checks here: the public functions check and then call these.

Shapes: ``F (T, S, 4, 4)`` bone frame -> world, ``C (S, B, 3)`` ball centres in their bone
frames, ``radii (S, B, 3)`` (mm), ``W (T, J, 4, 4)`` joint frame -> world, ``chain (J, J)``
bool (``chain[k, j]``: joint ``j`` lies on the chain from the root to ``k``), ``seg_joint
(S,)`` the joint carrying each segment; ``root_t = sqrt(-ln(T) / 2)``.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, error_model="numpy")
def chain_transforms(th, s, rot, offset, limb, parent, B):
    """Joint frame -> world ``(T, J, 4, 4)`` (:meth:`Skeleton.transforms`): ``th (T, J)``
    radians, ``s (L,)``, ``rot (J, 3, 3)``, ``offset (J, 3)`` mm, ``limb (J,)`` (-1: not
    scaled), ``parent (J,)`` (-1: the base), ``B (T, 4, 4)``."""
    T, J = th.shape
    out = np.zeros((T, J, 4, 4))
    A = np.zeros((4, 4))
    for t in range(T):
        for j in range(J):
            c, sn = np.cos(th[t, j]), np.sin(th[t, j])
            for r in range(3):                       # rot @ Rz(theta)
                A[r, 0] = rot[j, r, 0] * c + rot[j, r, 1] * sn
                A[r, 1] = -rot[j, r, 0] * sn + rot[j, r, 1] * c
                A[r, 2] = rot[j, r, 2]
            scale = s[limb[j]] if limb[j] >= 0 else 1.0
            for r in range(3):
                A[r, 3] = scale * offset[j, r]
            A[3, 0] = A[3, 1] = A[3, 2] = 0.0
            A[3, 3] = 1.0
            for r in range(4):
                for k in range(4):
                    acc = 0.0
                    for m in range(4):
                        p = B[t, r, m] if parent[j] < 0 else out[t, parent[j], r, m]
                        acc += p * A[m, k]
                    out[t, j, r, k] = acc
    return out


@nb.njit(cache=True, error_model="numpy")
def _skin(x0, x1, x2, M, C, radii, root_t, g, e):
    """Skin distance (mm) of the world point ``x`` to the segment in frame ``M (4, 4)``
    with balls ``C (B, 3)``, ``radii (B, 3)``; writes ``d r / d x`` (world) into ``g (3,)``
    (:func:`lsmta.body.metaballs.surface_distance_terms`); ``e (B,)`` is scratch."""
    d0, d1, d2 = x0 - M[0, 3], x1 - M[1, 3], x2 - M[2, 3]
    l0 = M[0, 0] * d0 + M[1, 0] * d1 + M[2, 0] * d2
    l1 = M[0, 1] * d0 + M[1, 1] * d1 + M[2, 1] * d2
    l2 = M[0, 2] * d0 + M[1, 2] * d1 + M[2, 2] * d2
    nb_ = C.shape[0]
    for b in range(nb_):
        q0 = (l0 - C[b, 0]) / radii[b, 0]
        q1 = (l1 - C[b, 1]) / radii[b, 1]
        q2 = (l2 - C[b, 2]) / radii[b, 2]
        e[b] = -2.0 * (q0 * q0 + q1 * q1 + q2 * q2)
    top = e[0]
    for b in range(1, nb_):
        if e[b] > top:
            top = e[b]
    total = 0.0
    for b in range(nb_):
        e[b] = np.exp(e[b] - top)
        total += e[b]
    psi = -0.5 * (top + np.log(total))
    inside = psi < 1e-9
    sq = np.sqrt(1e-9 if inside else psi)
    mid = nb_ // 2
    ell = np.sqrt(radii[mid, 0] * radii[mid, 1])
    # d psi / d local = sum_b p_b 2 q_b / radii_b, times d r / d psi, rotated to the world
    dr = 0.0 if inside else ell / (2.0 * sq)
    k0 = k1 = k2 = 0.0
    for b in range(nb_):
        w = e[b] / total
        k0 += w * (2.0 * ((l0 - C[b, 0]) / radii[b, 0]) / radii[b, 0])
        k1 += w * (2.0 * ((l1 - C[b, 1]) / radii[b, 1]) / radii[b, 1])
        k2 += w * (2.0 * ((l2 - C[b, 2]) / radii[b, 2]) / radii[b, 2])
    k0, k1, k2 = dr * k0, dr * k1, dr * k2
    for i in range(3):
        g[i] = M[i, 0] * k0 + M[i, 1] * k1 + M[i, 2] * k2
    return ell * (sq - root_t)


@nb.njit(cache=True, error_model="numpy", parallel=True)
def segment_distances(points, segment, frame, F, C, radii, root_t):
    """Skin distance ``(N,)`` (mm) of each point to its segment in its frame."""
    N = len(points)
    out = np.empty(N)
    for i in nb.prange(N):
        g = np.empty(3)
        e = np.empty(C.shape[1])
        s, t = segment[i], frame[i]
        out[i] = _skin(points[i, 0], points[i, 1], points[i, 2], F[t, s], C[s], radii[s],
                       root_t, g, e)
    return out


@nb.njit(cache=True, error_model="numpy", parallel=True)
def all_segment_distances(points, frame, F, C, radii, root_t):
    """Skin distance ``(N, S)`` (mm) of each point to every segment in its frame."""
    N, S = len(points), F.shape[1]
    out = np.empty((N, S))
    for i in nb.prange(N):
        g = np.empty(3)
        e = np.empty(C.shape[1])
        t = frame[i]
        for s in range(S):
            out[i, s] = _skin(points[i, 0], points[i, 1], points[i, 2], F[t, s], C[s],
                              radii[s], root_t, g, e)
    return out


@nb.njit(cache=True, error_model="numpy")
def _derivatives(x, i, s, g, W, chain, seg_joint, d_th, d_t):
    """Row ``i`` of the derivatives of a fixed world point's skin distance while the model
    moves: ``-g . (z_j x (x - o_j))`` for the joints on the segment's chain, ``-g`` for a
    translation."""
    k = seg_joint[s]
    for j in range(W.shape[0]):
        if not chain[k, j]:
            continue
        z0, z1, z2 = W[j, 0, 2], W[j, 1, 2], W[j, 2, 2]
        v0, v1, v2 = x[i, 0] - W[j, 0, 3], x[i, 1] - W[j, 1, 3], x[i, 2] - W[j, 2, 3]
        c0 = z1 * v2 - z2 * v1
        c1 = z2 * v0 - z0 * v2
        c2 = z0 * v1 - z1 * v0
        d_th[i, j] = -(g[0] * c0 + g[1] * c1 + g[2] * c2)
    for a in range(3):
        d_t[i, a] = -g[a]


@nb.njit(cache=True, error_model="numpy", parallel=True)
def segment_terms(x, segment, F, C, radii, W, chain, seg_joint, root_t):
    """One frame: skin distances ``r (N,)`` of world points ``x (N, 3)`` to their segments
    and the derivatives ``d_th (N, J)`` (mm per radian), ``d_t (N, 3)`` by a translation of
    the whole model (``F (S, 4, 4)``, ``W (J, 4, 4)``)."""
    N, J = len(x), W.shape[0]
    r = np.empty(N)
    d_th = np.zeros((N, J))
    d_t = np.empty((N, 3))
    for i in nb.prange(N):
        g = np.empty(3)
        e = np.empty(C.shape[1])
        s = segment[i]
        r[i] = _skin(x[i, 0], x[i, 1], x[i, 2], F[s], C[s], radii[s], root_t, g, e)
        _derivatives(x, i, s, g, W, chain, seg_joint, d_th, d_t)
    return r, d_th, d_t


@nb.njit(cache=True, error_model="numpy", parallel=True)
def closest_approach(origins, dirs, depths, F, C, radii, root_t, n_refine, gold):
    """One frame: for each line ``o + l d``, the segment it comes closest to on the depth
    grid and the depth of its closest approach to that segment's skin, refined by
    golden-section search (:func:`lsmta.body.silhouette.silhouette_terms`); returns
    ``segment (N,)`` and ``closest (N, 3)``."""
    N, S, K = len(origins), F.shape[0], len(depths)
    segment = np.empty(N, np.int64)
    closest = np.empty((N, 3))
    step = depths[1] - depths[0]
    for i in nb.prange(N):
        g = np.empty(3)
        e = np.empty(C.shape[1])
        o0, o1, o2 = origins[i, 0], origins[i, 1], origins[i, 2]
        e0, e1, e2 = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        best, best_s, best_k = np.inf, 0, 0
        for s in range(S):                 # first segment, then first depth, of the minimum
            m, mk = np.inf, 0
            for k in range(K):
                lk = depths[k]
                d = _skin(o0 + lk * e0, o1 + lk * e1, o2 + lk * e2, F[s], C[s], radii[s],
                          root_t, g, e)
                if d < m:
                    m, mk = d, k
            if m < best:
                best, best_s, best_k = m, s, mk
        s = best_s
        lo, hi = depths[best_k] - step, depths[best_k] + step
        a, b = hi - gold * (hi - lo), lo + gold * (hi - lo)
        fa = _skin(o0 + a * e0, o1 + a * e1, o2 + a * e2, F[s], C[s], radii[s], root_t, g, e)
        fb = _skin(o0 + b * e0, o1 + b * e1, o2 + b * e2, F[s], C[s], radii[s], root_t, g, e)
        for _ in range(n_refine):
            if fa < fb:                    # the minimum lies in [lo, b]
                hi = b
                a_new = hi - gold * (hi - lo)
                f = _skin(o0 + a_new * e0, o1 + a_new * e1, o2 + a_new * e2, F[s], C[s],
                          radii[s], root_t, g, e)
                fb, fa, b, a = fa, f, a, a_new
            else:
                lo = a
                b_new = lo + gold * (hi - lo)
                f = _skin(o0 + b_new * e0, o1 + b_new * e1, o2 + b_new * e2, F[s], C[s],
                          radii[s], root_t, g, e)
                fa, fb, a, b = fb, f, b, b_new
        depth = 0.5 * (lo + hi)
        segment[i] = s
        closest[i, 0] = o0 + depth * e0
        closest[i, 1] = o1 + depth * e1
        closest[i, 2] = o2 + depth * e2
    return segment, closest


@nb.njit(cache=True, error_model="numpy", parallel=True)
def ball_field(x, P, radii):
    """The summed field ``(N,)`` of one segment's balls (:func:`lsmta.body.metaballs.field`)
    at world points ``x (N, 3)``: ``P (B, 4, 4)`` ball -> world, ``radii (B, 3)`` mm."""
    N, B = len(x), len(P)
    out = np.empty(N)
    for n in nb.prange(N):
        total = 0.0
        for b in range(B):
            d0, d1, d2 = x[n, 0] - P[b, 0, 3], x[n, 1] - P[b, 1, 3], x[n, 2] - P[b, 2, 3]
            q0 = (P[b, 0, 0] * d0 + P[b, 1, 0] * d1 + P[b, 2, 0] * d2) / radii[b, 0]
            q1 = (P[b, 0, 1] * d0 + P[b, 1, 1] * d1 + P[b, 2, 1] * d2) / radii[b, 1]
            q2 = (P[b, 0, 2] * d0 + P[b, 1, 2] * d1 + P[b, 2, 2] * d2) / radii[b, 2]
            total += np.exp(-2.0 * (q0 * q0 + q1 * q1 + q2 * q2))
        out[n] = total
    return out



@nb.njit(cache=True, error_model="numpy", parallel=True)
def grid_field(origin, step, shape, P, radii, cutoff):
    """The summed field of balls ``P (B, 4, 4)`` (ball -> world), ``radii (B, 3)`` (mm) on
    the regular grid ``origin + step * (i, j, k)`` of ``shape (3,)`` nodes, ``(nx, ny, nz)``
    (:func:`lsmta.body.mesh.metaball_mesh`). A ball adds nothing where its ellipsoidal
    distance ``d`` exceeds ``cutoff``: along each grid line ``d`` is a quadratic in ``k``,
    so only the run of nodes with ``d <= cutoff`` is visited."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    B = len(P)
    M = np.empty((B, 3, 3))                 # world offset -> ball coordinates / radii
    for b in range(B):
        for r in range(3):
            for c in range(3):
                M[b, r, c] = P[b, c, r] / radii[b, r]
    out = np.zeros((nx, ny, nz))
    for i in nb.prange(nx):
        x0 = origin[0] + step * i
        for j in range(ny):
            x1 = origin[1] + step * j
            for b in range(B):
                d0, d1, d2 = x0 - P[b, 0, 3], x1 - P[b, 1, 3], origin[2] - P[b, 2, 3]
                q0 = M[b, 0, 0] * d0 + M[b, 0, 1] * d1 + M[b, 0, 2] * d2
                q1 = M[b, 1, 0] * d0 + M[b, 1, 1] * d1 + M[b, 1, 2] * d2
                q2 = M[b, 2, 0] * d0 + M[b, 2, 1] * d1 + M[b, 2, 2] * d2
                m0, m1, m2 = step * M[b, 0, 2], step * M[b, 1, 2], step * M[b, 2, 2]
                a = m0 * m0 + m1 * m1 + m2 * m2
                hb = q0 * m0 + q1 * m1 + q2 * m2            # half the linear coefficient
                c = q0 * q0 + q1 * q1 + q2 * q2
                disc = hb * hb - a * (c - cutoff)
                if disc < 0.0:
                    continue
                root = np.sqrt(disc)
                k0 = max(int(np.ceil((-hb - root) / a)), 0)
                k1 = min(int(np.floor((-hb + root) / a)), nz - 1)
                for k in range(k0, k1 + 1):
                    out[i, j, k] += np.exp(-2.0 * (c + k * (2.0 * hb + k * a)))
    return out
