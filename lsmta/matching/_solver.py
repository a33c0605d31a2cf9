"""Compiled Gauss-Newton solver of least squares matching: every iteration of every point
in one call (numba, parallel over points).

One point is one template patch matched in ``K`` search images. Its unknowns are

* the *shift block*: the patch centre ``c`` in the search image (2 unknowns, ``K = 1``),
  or one parameter ``t`` shared by all search images, whose centres must lie on given
  curves ``c_k(t) = base_k + dir_k (t - t_exp) + quad_k (t - t_exp)**2`` (the epipolar
  condition of geometrically constrained matching, 1 unknown);
* per search image, the shape of ``A`` (0, 2 or 4 unknowns) and the radiometry (0, 1 or 2).

Two ways to iterate:

* **forward additive** (Gruen 1985): the design matrix is built from the search image's
  gradient at the warped pixels in every iteration;
* **inverse compositional** (Baker & Matthews 2001): the geometric increment is a warp of
  the *template*, ``f(u + du(dp)) = r0 + r1 g(c + A u) + e``, composed with the current warp
  by its inverse. The geometric columns of the design matrix then come from the
  template's gradient and stay the same in every iteration; only the gain's column (the
  search values ``g``) changes, so an iteration samples the search image's values, without
  gradients, and updates one column of the normal matrix. The radiometry stays on the
  search side as in the forward model (putting the gain on the template instead made the
  first step explode on flat patches with one strong edge).

Per-image normal equations use a fixed layout of 8 columns ``[x, y, g2, g3, g4, g5, r0, r1]``
(unused columns zero; fixed bounds keep the sums in registers); they are mapped into the
point's joint unknowns afterwards.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba as nb
import numpy as np

from ._kernels import _spline_at

# status codes (lsm.Status)
CONVERGED, MAX_ITERATIONS, DIVERGED, OUTSIDE, SINGULAR = 0, 1, 2, 3, 4
#: the early stop (``stall``): an update not below ``1 / STALL_FACTOR`` of the one
#: ``STALL_WINDOW`` iterations before stops the point (the kernel keeps the last three)
STALL_FACTOR, STALL_WINDOW = 2.0, 3


@nb.njit(cache=True, error_model="numpy", inline="always")
def _value_at(coef, pad, x, y):
    """Value of the cubic B-spline with coefficients ``coef`` (padded by ``pad``) at
    ``(x, y)``, without the gradient (the inverse compositional iterations need no more)."""
    ix = np.floor(x)
    iy = np.floor(y)
    tx = x - ix
    ty = y - iy
    sx = 1.0 - tx
    sy = 1.0 - ty
    tx2 = tx * tx
    ty2 = ty * ty
    wx0 = sx * sx * sx / 6.0
    wx1 = (3.0 * tx2 * tx - 6.0 * tx2 + 4.0) / 6.0
    wx2 = (-3.0 * tx2 * tx + 3.0 * tx2 + 3.0 * tx + 1.0) / 6.0
    wx3 = tx2 * tx / 6.0
    wy0 = sy * sy * sy / 6.0
    wy1 = (3.0 * ty2 * ty - 6.0 * ty2 + 4.0) / 6.0
    wy2 = (-3.0 * ty2 * ty + 3.0 * ty2 + 3.0 * ty + 1.0) / 6.0
    wy3 = ty2 * ty / 6.0
    r = int(iy) + pad - 1
    q = int(ix) + pad - 1
    v0 = coef[r, q] * wx0 + coef[r, q + 1] * wx1 + coef[r, q + 2] * wx2 + coef[r, q + 3] * wx3
    v1 = (coef[r + 1, q] * wx0 + coef[r + 1, q + 1] * wx1 + coef[r + 1, q + 2] * wx2
          + coef[r + 1, q + 3] * wx3)
    v2 = (coef[r + 2, q] * wx0 + coef[r + 2, q + 1] * wx1 + coef[r + 2, q + 2] * wx2
          + coef[r + 2, q + 3] * wx3)
    v3 = (coef[r + 3, q] * wx0 + coef[r + 3, q + 1] * wx1 + coef[r + 3, q + 2] * wx2
          + coef[r + 3, q + 3] * wx3)
    return v0 * wy0 + v1 * wy1 + v2 * wy2 + v3 * wy3


@nb.njit(cache=True, error_model="numpy")
def _fill(a, value):
    """Set every element of ``a`` (any shape) to ``value``."""
    flat = a.reshape(a.size)
    for j in range(flat.size):
        flat[j] = value


@nb.njit(cache=True, error_model="numpy")
def _copy(src, dst):
    """``dst[...] = src`` for arrays of one shape."""
    s = src.reshape(src.size)
    d = dst.reshape(dst.size)
    for j in range(s.size):
        d[j] = s[j]


@nb.njit(cache=True, error_model="numpy")
def _value_grad(coef, pad, x, y, wx, dwx, wy, dwy):
    """Value and gradient of the spline (:func:`lsmta.matching._kernels._spline_at`)."""
    return _spline_at(coef, pad, x, y, wx, dwx, wy, dwy)


@nb.njit(cache=True, error_model="numpy", inline="always")
def _value_grad_at(coef, pad, x, y):
    """Value and x, y derivatives of the spline at ``(x, y)``: the sums of
    :func:`lsmta.matching._kernels._spline_at` in the same order, with the weights in
    registers instead of work arrays (the forward iterations' inner loop)."""
    ix = np.floor(x)
    iy = np.floor(y)
    tx = x - ix
    ty = y - iy
    sx = 1.0 - tx
    sy = 1.0 - ty
    tx2 = tx * tx
    ty2 = ty * ty
    tx3 = tx2 * tx
    ty3 = ty2 * ty
    wx0 = sx * sx * sx / 6.0
    wx1 = (3.0 * tx3 - 6.0 * tx2 + 4.0) / 6.0
    wx2 = (-3.0 * tx3 + 3.0 * tx2 + 3.0 * tx + 1.0) / 6.0
    wx3 = tx3 / 6.0
    dx0 = -sx * sx / 2.0
    dx1 = (3.0 * tx2 - 4.0 * tx) / 2.0
    dx2 = (-3.0 * tx2 + 2.0 * tx + 1.0) / 2.0
    dx3 = tx2 / 2.0
    wy0 = sy * sy * sy / 6.0
    wy1 = (3.0 * ty3 - 6.0 * ty2 + 4.0) / 6.0
    wy2 = (-3.0 * ty3 + 3.0 * ty2 + 3.0 * ty + 1.0) / 6.0
    wy3 = ty3 / 6.0
    dy0 = -sy * sy / 2.0
    dy1 = (3.0 * ty2 - 4.0 * ty) / 2.0
    dy2 = (-3.0 * ty2 + 2.0 * ty + 1.0) / 2.0
    dy3 = ty2 / 2.0
    r = int(iy) + pad - 1
    q = int(ix) + pad - 1
    g = 0.0
    gx = 0.0
    gy = 0.0
    for mm in range(4):
        c0 = coef[r + mm, q]
        c1 = coef[r + mm, q + 1]
        c2 = coef[r + mm, q + 2]
        c3 = coef[r + mm, q + 3]
        v = c0 * wx0 + c1 * wx1 + c2 * wx2 + c3 * wx3
        dv = c0 * dx0 + c1 * dx1 + c2 * dx2 + c3 * dx3
        wym = wy0 if mm == 0 else wy1 if mm == 1 else wy2 if mm == 2 else wy3
        dym = dy0 if mm == 0 else dy1 if mm == 1 else dy2 if mm == 2 else dy3
        g += v * wym
        gx += dv * wym
        gy += v * dym
    return g, gx, gy


@nb.njit(cache=True, error_model="numpy")
def _invert(M, n, out, W):
    """Gauss-Jordan inverse of the leading ``n x n`` block of ``M`` into ``out`` (partial
    pivoting; ``W`` is an ``(>= n, >= 2 n)`` work array); False if a pivot vanishes."""
    for a in range(n):
        for b in range(n):
            W[a, b] = M[a, b]
            W[a, n + b] = 1.0 if a == b else 0.0
    for col in range(n):
        piv = col
        best = abs(W[col, col])
        for r in range(col + 1, n):
            if abs(W[r, col]) > best:
                best = abs(W[r, col])
                piv = r
        if best == 0.0:
            return False
        if piv != col:
            for b in range(2 * n):
                tmp = W[col, b]
                W[col, b] = W[piv, b]
                W[piv, b] = tmp
        d = W[col, col]
        for b in range(2 * n):
            W[col, b] /= d
        for r in range(n):
            if r != col:
                fct = W[r, col]
                if fct != 0.0:
                    for b in range(2 * n):
                        W[r, b] -= fct * W[col, b]
    for a in range(n):
        for b in range(n):
            out[a, b] = W[a, n + b]
    return True


@nb.njit(cache=True, error_model="numpy")
def _adapt(N, n, fixed, max_vif, C, Ci, s, W):
    """Fix badly determined unknowns, worst variance inflation factor first (lsm's
    adaptive parameter control); ``fixed`` is updated in place, the rest is work space."""
    scale = 0.0
    for a in range(n):
        scale = max(scale, N[a, a])
    for a in range(n):
        fixed[a] = N[a, a] <= 1e-12 * max(scale, 1e-300)
    for _ in range(n):
        for a in range(n):
            s[a] = 0.0 if fixed[a] else 1.0 / np.sqrt(N[a, a])
        for a in range(n):
            for b in range(n):
                if fixed[a] or fixed[b]:
                    C[a, b] = 1.0 if (a == b) else 0.0
                else:
                    C[a, b] = N[a, b] * s[a] * s[b]
            C[a, a] += 1e-10
        if not _invert(C, n, Ci, W):
            break
        worst = -1
        big = max_vif
        for a in range(n):
            if not fixed[a] and abs(Ci[a, a]) > big:
                big = abs(Ci[a, a])
                worst = a
        if worst < 0:
            break
        fixed[worst] = True


@nb.njit(cache=True, error_model="numpy")
def _solve_free(N, b, n, fixed, dx, sel, L, z, x):
    """Cholesky solution of ``N dx = b`` over the free unknowns (fixed ones get 0);
    False if the free block is not positive definite (``sel, L, z, x``: work space)."""
    m = 0
    for a in range(n):
        dx[a] = 0.0
        if not fixed[a]:
            sel[m] = a
            m += 1
    if m == 0:
        return False
    for r in range(m):
        for q in range(r + 1):
            acc = N[sel[r], sel[q]]
            for t in range(q):
                acc -= L[r, t] * L[q, t]
            if r == q:
                if acc <= 0.0:
                    return False
                L[r, r] = np.sqrt(acc)
            else:
                L[r, q] = acc / L[q, q]
    for r in range(m):
        acc = b[sel[r]]
        for t in range(r):
            acc -= L[r, t] * z[t]
        z[r] = acc / L[r, r]
    for r in range(m - 1, -1, -1):
        acc = z[r]
        for t in range(r + 1, m):
            acc -= L[t, r] * x[t]
        x[r] = acc / L[r, r]
    for r in range(m):
        dx[sel[r]] = x[r]
    return True


@nb.njit(cache=True, error_model="numpy")
def _row(row, geometry, radiometry, Gx, Gy, ux, uy, value):
    row[0] = Gx
    row[1] = Gy
    if geometry == 1:
        row[2] = Gx * ux + Gy * uy
        row[3] = -Gx * uy + Gy * ux
    elif geometry == 2:
        row[2] = Gx * ux
        row[3] = Gx * uy
        row[4] = Gy * ux
        row[5] = Gy * uy
    elif geometry == 3:
        row[2] = Gx * ux
        row[3] = Gx * uy
    if radiometry >= 1:
        row[6] = 1.0
    if radiometry == 2:
        row[7] = value


@nb.njit(cache=True, error_model="numpy")
def _curve(base, direction, quad, k, t, t_exp, out):
    d = t - t_exp
    out[0] = base[k, 0] + direction[k, 0] * d + quad[k, 0] * d * d
    out[1] = base[k, 1] + direction[k, 1] * d + quad[k, 1] * d * d


@nb.njit(cache=True, error_model="numpy")
def _tangent(direction, quad, k, t, t_exp, out):
    d = t - t_exp
    out[0] = direction[k, 0] + 2.0 * quad[k, 0] * d
    out[1] = direction[k, 1] + 2.0 * quad[k, 1] * d


FAST = {"contract", "arcp", "nsz", "reassoc"}   # no nnan/ninf: the tests must see NaN


@nb.njit(cache=True, error_model="numpy", fastmath=FAST)
def _sample_patch(coef, pad, height, width, cx, cy, a11, a12, a21, a22, U, gv, ins, partial):
    """Search image values at ``c + A u`` into ``gv`` and 1 into ``ins`` for the pixels
    inside the image. A pixel outside fails the patch (False), or with ``partial`` gets
    ``ins = 0``."""
    for p in range(U.shape[0]):
        x = cx + a11 * U[p, 0] + a12 * U[p, 1]
        y = cy + a21 * U[p, 0] + a22 * U[p, 1]
        if not (x >= 0.0 and x <= width - 1.0 and y >= 0.0 and y <= height - 1.0):
            if not partial:
                return False
            gv[p] = 0.0
            ins[p] = 0.0
            continue
        gv[p] = _value_at(coef, pad, x, y)
        ins[p] = 1.0
    return True


@nb.njit(cache=True, error_model="numpy")
def _radiometric_start(f, fw, gv, radiometry):
    """``(r0, r1)`` from the means and spreads of the weighted pixels (``f = r0 + r1 g``)."""
    sf = 0.0
    sg = 0.0
    cnt = 0.0
    for p in range(f.shape[0]):
        if fw[p] > 0:
            sf += f[p]
            sg += gv[p]
            cnt += 1.0
    if cnt == 0.0:
        return 0.0, 1.0
    fm = sf / cnt
    gm = sg / cnt
    r1 = 1.0
    if radiometry == 2:
        vf = 0.0
        vg = 0.0
        for p in range(f.shape[0]):
            if fw[p] > 0:
                vf += (f[p] - fm) ** 2
                vg += (gv[p] - gm) ** 2
        gs = np.sqrt(vg / cnt)
        r1 = np.sqrt(vf / cnt) / gs if gs > 1e-9 else 1.0
    return fm - r1 * gm, r1


@nb.njit(cache=True, error_model="numpy", fastmath=FAST)
def _forward_equations(coef, pad, height, width, f, fw, U, cx, cy, a11, a12, a21, a22, r0, r1,
                       geometry, radiometry, cut, partial, N8, b8, row, Jt, used, we, wt):
    """One image's normal equations (upper triangle) with the search image's gradients at
    the warped pixels; returns (inside, e^T W e, trace W). With ``partial`` pixels outside
    the image are left out. The design rows go into ``Jt`` (8, P) and the weights into
    ``wt``, ``we`` (P,) first, and the sums are then taken row by row (:func:`_gram`:
    contiguous dot products, vectorised; summing into the 8 x 8 matrix pixel by pixel, and
    the spline's weights in work arrays, made the forward iterations about 1.7 times slower
    in ``experiments/lsm_benchmark.py`` on this project's 2-core machine)."""
    ee = 0.0
    sw = 0.0
    for p in range(U.shape[0]):
        ux = U[p, 0]
        uy = U[p, 1]
        x = cx + a11 * ux + a12 * uy
        y = cy + a21 * ux + a22 * uy
        if not (x >= 0.0 and x <= width - 1.0 and y >= 0.0 and y <= height - 1.0):
            if not partial:
                return False, ee, sw
            wt[p] = 0.0
            we[p] = 0.0
            for a in range(8):
                Jt[a, p] = 0.0
            continue
        g, gx, gy = _value_grad_at(coef, pad, x, y)
        e = f[p] - (r0 + r1 * g)
        wgt = fw[p]
        if cut > 0.0:
            q = e / cut
            q = 1.0 - q * q
            wgt *= q * q if q > 0.0 else 0.0
        sw += wgt
        ee += wgt * e * e
        _row(row, geometry, radiometry, r1 * gx, r1 * gy, ux, uy, g)
        for a in range(8):
            Jt[a, p] = row[a]
        wt[p] = wgt
        we[p] = wgt * e
    for a in range(8):
        acc = 0.0
        if used[a]:
            for p in range(U.shape[0]):
                acc += Jt[a, p] * we[p]
        b8[a] = acc
    _gram(Jt, used, wt, N8)
    return True, ee, sw


@nb.njit(cache=True, error_model="numpy", fastmath=FAST)
def _inverse_equations(gv, f, fw, Jt, used, r0, r1, radiometry, cut, full, H0, N8, b8, we,
                       wt):
    """One image's normal equations (upper triangle) from the template's design rows ``Jt``
    (8, P; the gain's row is set here to the sampled search values ``gv``), residuals
    ``f - r0 - r1 g``; returns (e^T W e, trace W). ``used``: the model's rows (the others are
    zero); ``we, wt``: (P,) work space. Without a Tukey cut-off and unless ``full`` (the
    weights ``fw`` differ from ``H0``'s), the normal matrix is ``H0`` except for the gain's
    column."""
    P = f.shape[0]
    if radiometry == 2:
        for p in range(P):
            Jt[7, p] = gv[p]
    ee = 0.0
    sw = 0.0
    for p in range(P):
        e = f[p] - r0 - r1 * gv[p]
        wgt = fw[p]
        if cut > 0.0:
            q = e / cut
            q = 1.0 - q * q
            wgt *= q * q if q > 0.0 else 0.0
        wt[p] = wgt
        we[p] = wgt * e
        sw += wgt
        ee += wgt * e * e
    for a in range(8):
        acc = 0.0
        if used[a]:
            for p in range(P):
                acc += Jt[a, p] * we[p]
        b8[a] = acc
    if cut > 0.0 or full:
        _gram(Jt, used, wt, N8)
        return ee, sw
    _copy(H0, N8)
    if radiometry == 2:
        for a in range(8):
            if used[a]:
                acc = 0.0
                for p in range(P):
                    acc += Jt[a, p] * wt[p] * Jt[7, p]
                N8[a, 7] = acc
    return ee, sw


@nb.njit(cache=True, error_model="numpy", fastmath=FAST)
def _gram(Jt, used, wt, N8):
    """Upper triangle of ``Jt diag(wt) Jt^T`` (8 x 8) over the ``used`` rows (zero else)."""
    P = Jt.shape[1]
    for a in range(8):
        for bb in range(a, 8):
            acc = 0.0
            if used[a] and used[bb]:
                for p in range(P):
                    acc += Jt[a, p] * wt[p] * Jt[bb, p]
            N8[a, bb] = acc


@nb.njit(cache=True, error_model="numpy")
def _covariance_factor(N, n, fixed, Q, M, W):
    """``Q = N^-1`` over the free unknowns (zero rows and columns for fixed ones)."""
    for a in range(n):
        for b in range(n):
            if fixed[a] or fixed[b]:
                M[a, b] = 1.0 if a == b else 0.0
            else:
                M[a, b] = N[a, b]
    if not _invert(M, n, Q, W):
        _fill(Q, np.nan)
        return
    for a in range(n):
        for b in range(n):
            if fixed[a] or fixed[b]:
                Q[a, b] = 0.0


def solve(images, points, spec, unknowns, out):
    """Match every point ``i`` with ``active[i]``, in the sequence ``order``; see the
    module docstring.

    The inputs come packed in five tuples by role; the compiled chunks unpack them. Arrays
    marked *in/out* or *out* are changed in place.

    Parameters
    ----------
    images : tuple ``(coef, pad, height, width, t_coef, t_img, t_gx, t_gy, t_mask)``
        ``coef`` (K, Hp, Wp): padded spline coefficients of the K search images (padded by
        ``pad``); ``height, width``: search image size. ``t_coef, t_img``: the template's
        padded coefficients and grey values; ``t_gx, t_gy``: the template spline's gradient
        at the pixel centres (``(0, 0)`` arrays in the forward mode); ``t_mask`` (H, W):
        0/1 template pixel weights, or a ``(0, 0)`` array.
    points : tuple ``(t_xy, U, order, active, base, direction, quad, t_exp)``
        ``t_xy`` (n, 2): patch centres in the template; ``U`` (P, 2): patch offsets;
        ``order`` (n,) int: the points in an order that keeps neighbours together (cache
        reuse); ``active`` (n,) bool: points to match; ``base, direction, quad`` (n, K, 2)
        and ``t_exp`` (n,): the constraint curves (constrained matching).
    spec : tuple ``(geometry, radiometry, inverse, constrained, start_radiometry, settings)``
        The model and its settings. ``geometry``: 0 shift, 1 similarity, 2 affine,
        3 row-affine (only A's first row moves); ``radiometry``: 0 none, 1 offset, 2 linear;
        ``inverse``: inverse compositional (else forward additive); ``constrained``: shared
        ``t``; ``start_radiometry``: start r0, r1 from the patches' mean and spread.
        ``settings``: float array
        ``[max_iter, tol, max_disp, max_vif, tukey_c, ramp, support, partial, stall]``:
        iteration limit, convergence (px), divergence distance (px), the adaptive control's
        variance inflation limit, the Tukey cut-off (0: least squares) and its ramp (cut-off
        ``(1 + ramp - it) tukey_c`` in the first iterations), and the support weights'
        grey-level scale (0: none; else template pixels weigh
        ``exp(-|f - f_centre| / support)``), and whether patches may reach over the image
        borders (1: pixels outside either image get zero weight), and the early stop
        (0: off; else from iteration ``stall`` on, a point whose update is not below
        ``1 / STALL_FACTOR`` of its update ``STALL_WINDOW`` iterations before stops, status
        ``MAX_ITERATIONS``).
    unknowns : tuple ``(c, A, r0, r1, t)``
        *in/out* start and solution: ``c`` (n, K, 2), ``A`` (n, K, 2, 2), ``r0, r1`` (n, K),
        ``t`` (n,) (forward convention ``f = r0 + r1 g``).
    out : tuple ``(status, iterations, fixed, Q_out, ee_last, sw_last, ee_img)``
        *out*: ``status, iterations`` (n,); ``fixed`` (n, k) bool: unknowns fixed by the
        adaptive control; ``Q_out`` (n, k, k): the inverse of the joint normal matrix of the
        last iteration over the free unknowns; ``ee_last, sw_last`` (n,): weighted squared
        residuals and weight sum (in the units of the equations); ``ee_img`` (n, K): each
        image's share of ee.
    """
    n = points[0].shape[0]
    threads = nb.get_num_threads()      # numba.set_num_threads is honoured (0.5 us a call)
    if threads <= 1 or n < MIN_PARALLEL:
        _chunk(0, 1, images, points, spec, unknowns, out)
        return
    # a few chunks per thread balance points that need more iterations than others
    n_chunks = min(4 * threads, n)
    list(_pool(threads).map(lambda ch: _chunk(ch, n_chunks, images, points, spec, unknowns,
                                              out), range(n_chunks)))


#: fewer points than this are solved on the calling thread (a thread hand-over costs more)
MIN_PARALLEL = 8
_POOLS: dict = {}


def _pool(threads: int) -> ThreadPoolExecutor:
    """One thread pool per thread count, kept for the process (the compiled chunks release
    the GIL, so the threads run in parallel)."""
    if threads not in _POOLS:
        _POOLS[threads] = ThreadPoolExecutor(threads, thread_name_prefix="lsmta-lsm")
    return _POOLS[threads]


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _chunk(ch, n_chunks, images, points, spec, unknowns, out):
    """The points of chunk ``ch`` of ``n_chunks``, one after the other; they share their
    work space (few allocations; chunks balance the threads). The tuples are
    :func:`solve`'s."""
    coef, pad, height, width, t_coef, t_img, t_gx, t_gy, t_mask = images
    t_xy, U, order, active, base, direction, quad, t_exp = points
    geometry, radiometry, inverse, constrained, start_radiometry, settings = spec
    c, A, r0, r1, t = unknowns
    status, iterations, fixed, Q_out, ee_last, sw_last, ee_img = out
    n = t_xy.shape[0]
    K = coef.shape[0]
    P = U.shape[0]
    ns = 4 if geometry == 2 else (0 if geometry == 0 else 2)
    kj = (1 if constrained else 2) + K * (ns + radiometry)
    lo = ch * n // n_chunks
    hi = (ch + 1) * n // n_chunks
    fv = np.empty((6, P))           # f, fw, gv, we, inside, fw x inside
    wt = np.empty(P)
    Jt = np.zeros((8, P))
    w4 = np.empty((4, 4))           # spline weights
    m8 = np.zeros((2, 8, 8))        # H0, N8
    v8 = np.zeros((3, 8))           # b8, row, coefm
    jmap = np.empty(8, dtype=np.int64)
    used = np.zeros(8, dtype=np.bool_)  # the model's rows of the 8-column layout
    used[0] = used[1] = True
    for a in range(ns):
        used[2 + a] = True
    for a in range(radiometry):
        used[6 + a] = True
    mk = np.zeros((6, kj, kj))      # N, N_keep, C, Ci, L, M
    vk = np.zeros((5, kj))          # b, dx, s, z, x
    sel = np.empty(kj, dtype=np.int64)
    W = np.zeros((kj, 2 * kj))
    fx_i = np.zeros(kj, dtype=np.bool_)
    kv = np.empty((2, K))           # start x, start y
    v2 = np.empty((2, 2))           # tangent, curve point
    for j in range(lo, hi):
        i = order[j]
        if active[i]:
            _point(i, coef, pad, height, width, t_coef, t_img, t_gx, t_gy, t_mask, t_xy, U,
                   geometry, radiometry, inverse, constrained, start_radiometry,
                   c, A, r0, r1, t, base, direction, quad, t_exp, settings, status,
                   iterations, fixed, Q_out, ee_last, sw_last, ee_img, K, P, ns, kj,
                   fv, wt, Jt, w4, m8, v8, jmap, used, mk, vk, sel, W, fx_i, kv, v2)


@nb.njit(cache=True, error_model="numpy", fastmath=FAST)
def _point(i, coef, pad, height, width, t_coef, t_img, t_gx, t_gy, t_mask, t_xy, U,
           geometry, radiometry, inverse, constrained, start_radiometry,
           c, A, r0, r1, t, base, direction, quad, t_exp, settings, status,
           iterations, fixed, Q_out, ee_last, sw_last, ee_img, K, P, ns, kj,
           fv, wt, Jt, w4, m8, v8, jmap, used, mk, vk, sel, W, fx_i, kv, v2):
    """Gauss-Newton iterations of point ``i`` (the arguments after ``kj`` are work space)."""
    max_iter = int(settings[0])
    tol = settings[1]
    max_disp = settings[2]
    max_vif = settings[3]
    tukey_c = settings[4]
    ramp = int(settings[5])
    support = settings[6]
    partial = settings[7] > 0.0
    stall = int(settings[8])
    nr = radiometry
    nshift = 1 if constrained else 2
    f, fw, gv, we, ins, fwi = fv[0], fv[1], fv[2], fv[3], fv[4], fv[5]
    wx, dwx, wy, dwy = w4[0], w4[1], w4[2], w4[3]
    H0, N8 = m8[0], m8[1]
    b8, row, coefm = v8[0], v8[1], v8[2]
    N, N_keep, C, Ci, L, M = mk[0], mk[1], mk[2], mk[3], mk[4], mk[5]
    b, dx, s, z, x_ = vk[0], vk[1], vk[2], vk[3], vk[4]
    start_x, start_y = kv[0], kv[1]
    w, cc = v2[0], v2[1]
    h = 0.0
    for p in range(P):
        h = max(h, abs(U[p, 0]))
    # the template patch: values, weights and (inverse mode) design rows
    tx = t_xy[i, 0]
    ty = t_xy[i, 1]
    whole = tx == np.floor(tx) and ty == np.floor(ty)
    use_mask = t_mask.shape[0] > 0
    _fill(row, 0.0)
    t_h, t_w = t_img.shape
    for p in range(P):
        x = tx + U[p, 0]
        y = ty + U[p, 1]
        fxp = 0.0
        fyp = 0.0
        if not (x >= 0.0 and x <= t_w - 1.0 and y >= 0.0 and y <= t_h - 1.0):
            # (partial patches only) a pixel outside the template does not count
            f[p] = 0.0
            fw[p] = 0.0
            for a in range(8):
                Jt[a, p] = 0.0
            continue
        if whole:
            ix = int(x)
            iy = int(y)
            f[p] = t_img[iy, ix]
            if inverse:
                fxp = t_gx[iy, ix]
                fyp = t_gy[iy, ix]
        else:
            f[p], fxp, fyp = _value_grad(t_coef, pad, x, y, wx, dwx, wy, dwy)
        if inverse:
            # geometric rows -grad f du/dp (the template's increment), the offset's 1; the
            # gain's row (the search values) is filled in every iteration
            _row(row, geometry, radiometry, fxp, fyp, U[p, 0], U[p, 1], 0.0)
            for a in range(8):
                Jt[a, p] = -row[a] if a < 6 else row[a]
        fw[p] = 1.0
        if use_mask:
            ix = min(max(int(np.rint(x)), 0), t_mask.shape[1] - 1)
            iy = min(max(int(np.rint(y)), 0), t_mask.shape[0] - 1)
            fw[p] = t_mask[iy, ix]
    if support > 0.0:
        # adaptive support: pixels unlike the centre (another surface) weigh less
        fc = f[P // 2]
        for p in range(P):
            fw[p] *= np.exp(-abs(f[p] - fc) / support)
    for p in range(P):
        ins[p] = 1.0
    for k in range(K):
        start_x[k] = c[i, k, 0]
        start_y[k] = c[i, k, 1]
    if start_radiometry and not inverse:
        # the forward iterations start r0, r1 from the patches' means and spreads (the
        # inverse ones do the same from their first samples)
        for k in range(K):
            if not _sample_patch(coef[k], pad, height, width, c[i, k, 0], c[i, k, 1],
                                 A[i, k, 0, 0], A[i, k, 0, 1], A[i, k, 1, 0], A[i, k, 1, 1],
                                 U, gv, ins, partial):
                status[i] = OUTSIDE
                return
            for p in range(P):
                fwi[p] = fw[p] * ins[p]
            r0[i, k], r1[i, k] = _radiometric_start(f, fwi, gv, radiometry)
    if inverse and tukey_c <= 0.0:
        _gram(Jt, used, fw, H0)      # the template's normal matrix (gain column: per iteration)
    status[i] = MAX_ITERATIONS
    s1 = s2 = s3 = np.inf           # the updates of the last three iterations (``stall``)
    for it in range(max_iter):
        cut = 0.0
        if tukey_c > 0.0:
            cut = tukey_c * (1.0 + max(ramp - it, 0))
        _fill(N, 0.0)
        _fill(b, 0.0)
        ee = 0.0
        sw = 0.0
        for k in range(K):
            _fill(N8, 0.0)
            _fill(b8, 0.0)
            a11 = A[i, k, 0, 0]
            a12 = A[i, k, 0, 1]
            a21 = A[i, k, 1, 0]
            a22 = A[i, k, 1, 1]
            if inverse:
                if not _sample_patch(coef[k], pad, height, width, c[i, k, 0], c[i, k, 1],
                                     a11, a12, a21, a22, U, gv, ins, partial):
                    status[i] = OUTSIDE
                    return
                full = False
                for p in range(P):
                    fwi[p] = fw[p] * ins[p]
                    full = full or ins[p] == 0.0
                if it == 0 and start_radiometry:
                    # the radiometry starts from the patches' means and spreads
                    r0[i, k], r1[i, k] = _radiometric_start(f, fwi, gv, radiometry)
                eek, swk = _inverse_equations(gv, f, fwi, Jt, used, r0[i, k], r1[i, k],
                                              radiometry, cut, full, H0, N8, b8, we, wt)
            else:
                ok, eek, swk = _forward_equations(
                    coef[k], pad, height, width, f, fw, U, c[i, k, 0], c[i, k, 1],
                    a11, a12, a21, a22, r0[i, k], r1[i, k], geometry, radiometry, cut,
                    partial, N8, b8, row, Jt, used, we, wt)
                if not ok:
                    status[i] = OUTSIDE
                    return
            ee += eek
            sw += swk
            ee_img[i, k] = eek
            for a in range(8):
                for bb in range(a + 1, 8):
                    N8[bb, a] = N8[a, bb]
            # map the image's 8 columns into the joint unknowns
            for a in range(8):
                jmap[a] = -1
                coefm[a] = 1.0
            off = nshift + k * (ns + nr)
            if constrained:
                _tangent(direction[i], quad[i], k, t[i], t_exp[i], w)
                if inverse:
                    # a step along the curve, as an increment of the template warp
                    det = a11 * a22 - a12 * a21
                    w0 = -(a22 * w[0] - a12 * w[1]) / det
                    w1 = -(-a21 * w[0] + a11 * w[1]) / det
                    w[0] = w0
                    w[1] = w1
                jmap[0] = 0
                jmap[1] = 0
                coefm[0] = w[0]
                coefm[1] = w[1]
            else:
                jmap[0] = 0
                jmap[1] = 1
            for a in range(ns):
                jmap[2 + a] = off + a
            for a in range(nr):
                jmap[6 + a] = off + ns + a
            for a in range(8):
                ja = jmap[a]
                if ja < 0:
                    continue
                b[ja] += coefm[a] * b8[a]
                for bb in range(8):
                    jb = jmap[bb]
                    if jb >= 0:
                        N[ja, jb] += coefm[a] * coefm[bb] * N8[a, bb]
        iterations[i] = it + 1
        _copy(N, N_keep)
        ee_last[i] = ee
        sw_last[i] = sw
        if it == 0:
            _adapt(N, kj, fx_i, max_vif, C, Ci, s, W)
            for a in range(kj):
                fixed[i, a] = fx_i[a]
        solved = _solve_free(N, b, kj, fx_i, dx, sel, L, z, x_)
        singular = (fx_i[0] if constrained else (fx_i[0] and fx_i[1])) or not solved
        if singular:
            status[i] = SINGULAR
            break
        # the update, image by image
        step = 0.0
        bad = False
        if constrained:
            t[i] += dx[0]
        for k in range(K):
            off = nshift + k * (ns + nr)
            d11 = 0.0
            d12 = 0.0
            d21 = 0.0
            d22 = 0.0
            if geometry == 1:
                d11 = dx[off]
                d22 = dx[off]
                d12 = -dx[off + 1]
                d21 = dx[off + 1]
            elif geometry == 2:
                d11 = dx[off]
                d12 = dx[off + 1]
                d21 = dx[off + 2]
                d22 = dx[off + 3]
            elif geometry == 3:
                d11 = dx[off]
                d12 = dx[off + 1]
            old_x = c[i, k, 0]
            old_y = c[i, k, 1]
            o11 = A[i, k, 0, 0]
            o12 = A[i, k, 0, 1]
            o21 = A[i, k, 1, 0]
            o22 = A[i, k, 1, 1]
            if inverse:
                # A <- A (I + dA)^-1 ; c <- c - A_new dc (free shift)
                m11 = 1.0 + d11
                m22 = 1.0 + d22
                det = m11 * m22 - d12 * d21
                n11 = (o11 * m22 - o12 * d21) / det
                n12 = (-o11 * d12 + o12 * m11) / det
                n21 = (o21 * m22 - o22 * d21) / det
                n22 = (-o21 * d12 + o22 * m11) / det
                A[i, k, 0, 0] = n11
                A[i, k, 0, 1] = n12
                A[i, k, 1, 0] = n21
                A[i, k, 1, 1] = n22
                if not constrained:
                    c[i, k, 0] = old_x - (n11 * dx[0] + n12 * dx[1])
                    c[i, k, 1] = old_y - (n21 * dx[0] + n22 * dx[1])
            else:
                A[i, k, 0, 0] = o11 + d11
                A[i, k, 0, 1] = o12 + d12
                A[i, k, 1, 0] = o21 + d21
                A[i, k, 1, 1] = o22 + d22
                if not constrained:
                    c[i, k, 0] = old_x + dx[0]
                    c[i, k, 1] = old_y + dx[1]
            if nr >= 1:
                r0[i, k] += dx[off + ns]
            if nr == 2:
                r1[i, k] += dx[off + ns + 1]
            if constrained:
                _curve(base[i], direction[i], quad[i], k, t[i], t_exp[i], cc)
                c[i, k, 0] = cc[0]
                c[i, k, 1] = cc[1]
            mx = c[i, k, 0] - start_x[k]
            my = c[i, k, 1] - start_y[k]
            det = A[i, k, 0, 0] * A[i, k, 1, 1] - A[i, k, 0, 1] * A[i, k, 1, 0]
            if (np.sqrt(mx * mx + my * my) > max_disp or not (det > 0.2) or not (det < 5.0)
                    or not np.isfinite(c[i, k, 0]) or not np.isfinite(c[i, k, 1])):
                bad = True
            sk = (max(abs(c[i, k, 0] - old_x), abs(c[i, k, 1] - old_y))
                  + (abs(A[i, k, 0, 0] - o11) + abs(A[i, k, 0, 1] - o12)
                     + abs(A[i, k, 1, 0] - o21) + abs(A[i, k, 1, 1] - o22)) * h)
            step = max(step, sk)
        if bad:
            status[i] = DIVERGED
            break
        if step < tol and it >= ramp:
            status[i] = CONVERGED
            break
        if stall > 0 and it + 1 >= stall and step >= tol and STALL_FACTOR * step > s3:
            break                   # still moving: the update has not fallen enough (stall)
        s3 = s2
        s2 = s1
        s1 = step
    _covariance_factor(N_keep, kj, fx_i, Q_out[i], M, W)


@nb.njit(cache=True, error_model="numpy")
def threshold_failures(A, sigma0, sigma_xy, displacement, weight_share, limits, out):
    """The tests of :meth:`lsmta.matching.LSMThresholds.failures` for every match, in one
    pass: ``out`` (6, n) bool, rows in the order of ``THRESHOLD_TESTS`` (True: fails; NaN
    fails). ``A`` (n, 2, 2), ``sigma0`` (n,), ``sigma_xy`` (n, 2) (NaN counts as 0),
    ``displacement``, ``weight_share`` (n,); ``limits``: max_sigma0, max_sigma_xy,
    max_displacement, the scale range's low and high end, max_shear, min_weight_share.
    The singular values in closed form, ``s² = (q ± sqrt(q² - 4 det²)) / 2`` with ``q``
    the squared Frobenius norm, and the shear as ``|cos|`` of the angle between the
    columns."""
    for i in range(A.shape[0]):
        a, b, c, d = A[i, 0, 0], A[i, 0, 1], A[i, 1, 0], A[i, 1, 1]
        q = a * a + b * b + c * c + d * d
        det = a * d - b * c
        disc = q * q - 4 * det * det
        root = np.sqrt(disc if disc != disc or disc > 0.0 else 0.0)    # NaN stays NaN
        small = q - root
        s_hi = np.sqrt((q + root) / 2)
        s_lo = np.sqrt((small if small != small or small > 0.0 else 0.0) / 2)
        cos = abs(a * b + c * d) / (np.sqrt(a * a + c * c) * np.sqrt(b * b + d * d))
        sx = 0.0 if np.isnan(sigma_xy[i, 0]) else sigma_xy[i, 0]
        sy = 0.0 if np.isnan(sigma_xy[i, 1]) else sigma_xy[i, 1]
        out[0, i] = not sigma0[i] <= limits[0]
        out[1, i] = not max(sx, sy) <= limits[1]
        out[2, i] = not displacement[i] <= limits[2]
        out[3, i] = not (s_lo >= limits[3] and s_hi <= limits[4])
        out[4, i] = not cos <= limits[5]
        out[5, i] = not weight_share[i] >= limits[6]
