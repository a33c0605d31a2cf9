"""Compiled cubic B-spline evaluation (numba): value and exact gradient at any point,
batched over points (``sample``) or one at a time inside other kernels (``_spline_at``,
used by the matching solver ``_solver.py``).
"""

from __future__ import annotations

import numba as nb
import numpy as np


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
