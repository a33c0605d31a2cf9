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


@nb.njit(parallel=True, cache=True, fastmath=True)
def normal_equations(coef, pad, height, width, idx, f, c, A, r0, r1, U, geometry, radiometry,
                     N_out, b_out, ee_out, ok_out):
    """For every active point ``i = idx[j]``: ``N_out[j] = J^T J``, ``b_out[j] = J^T e``,
    ``ee_out[j] = e^T e`` and ``ok_out[j]`` (the warped patch lies inside the image)."""
    m = idx.shape[0]
    P = U.shape[0]
    k = N_out.shape[1]
    for j in nb.prange(m):
        i = idx[j]
        wx = np.empty(4)
        dwx = np.empty(4)
        wy = np.empty(4)
        dwy = np.empty(4)
        row = np.empty(k)
        N = np.zeros((k, k))
        b = np.zeros(k)
        ee = 0.0
        ok = True
        a11, a12, a21, a22 = A[i, 0, 0], A[i, 0, 1], A[i, 1, 0], A[i, 1, 1]
        gain = r1[i]
        for p in range(P):
            ux = U[p, 0]
            uy = U[p, 1]
            x = c[i, 0] + a11 * ux + a12 * uy
            y = c[i, 1] + a21 * ux + a22 * uy
            if not (x >= 0.0 and x <= width - 1.0 and y >= 0.0 and y <= height - 1.0):
                ok = False
                break
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
            e = f[i, p] - (r0[i] + gain * g)
            ee += e * e
            Gx = gain * gx
            Gy = gain * gy
            row[0] = Gx
            row[1] = Gy
            col = 2
            if geometry == 1:
                row[2] = Gx * ux + Gy * uy
                row[3] = -Gx * uy + Gy * ux
                col = 4
            elif geometry == 2:
                row[2] = Gx * ux
                row[3] = Gx * uy
                row[4] = Gy * ux
                row[5] = Gy * uy
                col = 6
            if radiometry >= 1:
                row[col] = 1.0
                col += 1
            if radiometry == 2:
                row[col] = g
            for a in range(k):
                b[a] += row[a] * e
                for bb in range(a, k):
                    N[a, bb] += row[a] * row[bb]
        for a in range(k):
            for bb in range(a + 1, k):
                N[bb, a] = N[a, bb]
        N_out[j] = N
        b_out[j] = b
        ee_out[j] = ee
        ok_out[j] = ok


@nb.njit(parallel=True, cache=True)
def sample(coef, pad, x, y, value, gx, gy, gradient):
    """Spline value (and gradient) at points ``x, y`` (1-D, already inside the image)."""
    for s in nb.prange(x.shape[0]):
        wx = np.empty(4)
        dwx = np.empty(4)
        wy = np.empty(4)
        dwy = np.empty(4)
        ix = int(np.floor(x[s]))
        iy = int(np.floor(y[s]))
        _bspline(x[s] - ix, wx, dwx)
        _bspline(y[s] - iy, wy, dwy)
        g = 0.0
        ggx = 0.0
        ggy = 0.0
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
            ggx += dv * wy[mm]
            ggy += v * dwy[mm]
        value[s] = g
        if gradient:
            gx[s] = ggx
            gy[s] = ggy
