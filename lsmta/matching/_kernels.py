"""Compiled inner loop of least squares matching (numba, parallel over points).

One pass over every pixel of every patch: warp the pixel, evaluate the cubic B-spline of
the search image and its exact gradient there, form the row of the design matrix and
accumulate the normal equations. Doing this in one compiled loop avoids the large
temporary arrays that make the same computation in NumPy about 30 times slower.
"""

from __future__ import annotations

import numba as nb
import numpy as np

# geometry codes: 0 shift, 1 similarity, 2 affine; radiometry codes: 0 none, 1 offset, 2 linear


@nb.njit(cache=True, inline="always")
def _bspline(t, w, dw):
    s = 1.0 - t
    t2 = t * t
    t3 = t2 * t
    w[0] = s * s * s / 6.0
    w[1] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0
    w[2] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0
    w[3] = t3 / 6.0
    dw[0] = -s * s / 2.0
    dw[1] = (3.0 * t2 - 4.0 * t) / 2.0
    dw[2] = (-3.0 * t2 + 2.0 * t + 1.0) / 2.0
    dw[3] = t2 / 2.0


@nb.njit(cache=True, inline="always")
def _spline_at(coef, pad, x, y, wx, dwx, wy, dwy):
    """Value and x, y derivatives of the cubic B-spline with coefficients ``coef`` (padded
    by ``pad``) at ``(x, y)``; ``wx, dwx, wy, dwy`` are work arrays of length 4."""
    ix = int(np.floor(x))
    iy = int(np.floor(y))
    _bspline(x - ix, wx, dwx)
    _bspline(y - iy, wy, dwy)
    g = 0.0
    gx = 0.0
    gy = 0.0
    r = iy + pad - 1
    q = ix + pad - 1
    for mm in range(4):
        v = 0.0
        dv = 0.0
        for nn in range(4):
            cf = coef[r + mm, q + nn]
            v += cf * wx[nn]
            dv += cf * dwx[nn]
        g += v * wy[mm]
        gx += dv * wy[mm]
        gy += v * dwy[mm]
    return g, gx, gy


@nb.njit(parallel=True, cache=True, fastmath=True)
def normal_equations(coef, pad, height, width, idx, f, fw, c, A, r0, r1, U, geometry, radiometry,
                     tukey_c, N_out, b_out, ee_out, sw_out, ok_out):
    """For every active point ``i = idx[j]``: ``N_out[j] = J^T W J`` (8 x 8),
    ``b_out[j] = J^T W e``, ``ee_out[j] = e^T W e``, ``sw_out[j] = trace W`` and ``ok_out[j]``
    (the warped patch lies inside the image). ``W`` holds the template pixels' weights
    ``fw`` (0 or 1: a mask) times the Tukey biweights of the current residuals,
    ``(1 - (e / tukey_c)^2)^2`` inside ``|e| < tukey_c`` and 0 outside; with
    ``tukey_c <= 0`` the Tukey factor is 1 (ordinary least squares).

    The design row always has 8 columns ``[x, y, g2, g3, g4, g5, r0, r1]``; columns the
    model does not use stay zero (fixed loop bounds let the compiler keep the sums in
    registers, about twice as fast as a variable size); the caller takes the sub-block.
    """
    m = idx.shape[0]
    P = U.shape[0]
    for j in nb.prange(m):
        i = idx[j]
        wx = np.empty(4)
        dwx = np.empty(4)
        wy = np.empty(4)
        dwy = np.empty(4)
        row = np.zeros(8)
        N = np.zeros((8, 8))
        b = np.zeros(8)
        ee = 0.0
        sw = 0.0
        ok = True
        a11, a12, a21, a22 = A[i, 0, 0], A[i, 0, 1], A[i, 1, 0], A[i, 1, 1]
        gain = r1[i]
        offset = r0[i]
        cx = c[i, 0]
        cy = c[i, 1]
        for p in range(P):
            ux = U[p, 0]
            uy = U[p, 1]
            x = cx + a11 * ux + a12 * uy
            y = cy + a21 * ux + a22 * uy
            if not (x >= 0.0 and x <= width - 1.0 and y >= 0.0 and y <= height - 1.0):
                ok = False
                break
            g, gx, gy = _spline_at(coef, pad, x, y, wx, dwx, wy, dwy)
            e = f[i, p] - (offset + gain * g)
            wgt = fw[i, p]
            if tukey_c > 0.0:
                t = e / tukey_c
                t = 1.0 - t * t
                wgt *= t * t if t > 0.0 else 0.0
            sw += wgt
            ee += wgt * e * e
            Gx = gain * gx
            Gy = gain * gy
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
            if radiometry >= 1:
                row[6] = 1.0
            if radiometry == 2:
                row[7] = g
            for a in range(8):
                ra = row[a] * wgt
                b[a] += ra * e
                for bb in range(a, 8):
                    N[a, bb] += ra * row[bb]
        for a in range(8):
            for bb in range(a + 1, 8):
                N[bb, a] = N[a, bb]
        N_out[j] = N
        b_out[j] = b
        ee_out[j] = ee
        sw_out[j] = sw
        ok_out[j] = ok


@nb.njit(parallel=True, cache=True)
def solve_free(N, b, free, dx_out, ok_out):
    """Solve ``N[j] dx = b[j]`` over the free parameters of each point (Cholesky); fixed
    parameters get ``dx = 0``. ``ok_out[j]`` is False where the free block is not positive
    definite."""
    m, k = b.shape
    for j in nb.prange(m):
        sel = np.empty(k, dtype=np.int64)
        n = 0
        for a in range(k):
            if free[j, a]:
                sel[n] = a
                n += 1
        L = np.zeros((n, n))
        ok = n > 0
        for r in range(n):
            for q in range(r + 1):
                acc = N[j, sel[r], sel[q]]
                for t in range(q):
                    acc -= L[r, t] * L[q, t]
                if r == q:
                    if acc <= 0.0:
                        ok = False
                        acc = 1.0
                    L[r, r] = np.sqrt(acc)
                else:
                    L[r, q] = acc / L[q, q]
        z = np.zeros(n)
        for r in range(n):
            acc = b[j, sel[r]]
            for t in range(r):
                acc -= L[r, t] * z[t]
            z[r] = acc / L[r, r]
        x = np.zeros(n)
        for r in range(n - 1, -1, -1):
            acc = z[r]
            for t in range(r + 1, n):
                acc -= L[t, r] * x[t]
            x[r] = acc / L[r, r]
        for a in range(k):
            dx_out[j, a] = 0.0
        if ok:
            for r in range(n):
                dx_out[j, sel[r]] = x[r]
        ok_out[j] = ok


@nb.njit(parallel=True, cache=True)
def sample(coef, pad, x, y, value, gx, gy, gradient):
    """Spline value (and gradient) at points ``x, y`` (1-D); points are clamped to the
    padded coefficient array (values beyond the image border are the mirror extension)."""
    lo_x = -pad + 1.0
    lo_y = -pad + 1.0
    hi_x = coef.shape[1] - pad - 3.0
    hi_y = coef.shape[0] - pad - 3.0
    for s in nb.prange(x.shape[0]):
        wx = np.empty(4)
        dwx = np.empty(4)
        wy = np.empty(4)
        dwy = np.empty(4)
        xs = min(max(x[s], lo_x), hi_x)
        ys = min(max(y[s], lo_y), hi_y)
        g, ggx, ggy = _spline_at(coef, pad, xs, ys, wx, dwx, wy, dwy)
        value[s] = g
        if gradient:
            gx[s] = ggx
            gy[s] = ggy
