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


@nb.njit(cache=True)
def prefilter(img, pad, out):
    """Cubic B-spline coefficients of the image ``img`` (H, W) (mirror boundary, as
    ``scipy.ndimage.spline_filter(order=3, mode="mirror")`` computes them, to round-off)
    written into ``out`` (H + 2 pad, W + 2 pad) and padded by ``pad`` on every side as
    ``np.pad(mode="reflect")`` pads.

    Each line is filtered by the causal and anti-causal recursions of the pole
    ``sqrt(3) - 2`` (Unser 1999), columns first (vectorised over a row), then rows (16 at
    a time, interleaved); the causal start sums the mirrored line until the pole's power
    is below 1e-18 (SciPy sums the whole line: the terms left out are below round-off).
    Both line passes (columns, then rows) run in place in ``out``, then the ``pad`` border
    is filled by reflection: no intermediate arrays, unlike SciPy's line-buffered passes
    followed by a separate ``np.pad``.
    """
    H, W = img.shape
    z = np.sqrt(3.0) - 2.0
    gain = (1.0 - z) * (1.0 - 1.0 / z)
    eps = 1e-18
    c = out[pad:pad + H, pad:pad + W]
    for i in range(H):
        for j in range(W):
            c[i, j] = img[i, j] * gain
    if H > 1:
        zn = z ** (H - 1)
        acc = np.empty(W)
        for j in range(W):
            acc[j] = c[0, j] + zn * c[H - 1, j]
        zi = z
        for i in range(1, H - 1):
            if abs(zi) < eps:
                break
            for j in range(W):
                acc[j] += zi * (c[i, j] + zn * c[H - 1 - i, j])
            zi *= z
        for j in range(W):
            c[0, j] = acc[j] / (1 - zn * zn)
        for i in range(1, H):
            for j in range(W):
                c[i, j] += z * c[i - 1, j]
        for j in range(W):
            c[H - 1, j] = (z * c[H - 2, j] + c[H - 1, j]) * z / (z * z - 1)
        for i in range(H - 2, -1, -1):
            for j in range(W):
                c[i, j] = z * (c[i + 1, j] - c[i, j])
    if W > 1:
        zn = z ** (W - 1)
        B = 16
        a = np.empty(B)
        for i0 in range(0, H, B):
            i1 = min(i0 + B, H)
            for i in range(i0, i1):
                a[i - i0] = (c[i, 0] * gain) + zn * (c[i, W - 1] * gain)
            zi = z
            for j in range(1, W - 1):
                if abs(zi) < eps:
                    break
                for i in range(i0, i1):
                    a[i - i0] += zi * (c[i, j] * gain + zn * (c[i, W - 1 - j] * gain))
                zi *= z
            for i in range(i0, i1):
                c[i, 0] = a[i - i0] / (1 - zn * zn)
            for j in range(1, W):
                for i in range(i0, i1):
                    c[i, j] = c[i, j] * gain + z * c[i, j - 1]
            for i in range(i0, i1):
                c[i, W - 1] = (z * c[i, W - 2] + c[i, W - 1]) * z / (z * z - 1)
            for j in range(W - 2, -1, -1):
                for i in range(i0, i1):
                    c[i, j] = z * (c[i, j + 1] - c[i, j])
    for k in range(pad):          # numpy's "reflect" padding: the edge is not repeated
        for i in range(pad, pad + H):
            out[i, pad - 1 - k] = out[i, pad + 1 + k]
            out[i, pad + W + k] = out[i, pad + W - 2 - k]
    for k in range(pad):
        for j in range(W + 2 * pad):
            out[pad - 1 - k, j] = out[pad + 1 + k, j]
            out[pad + H + k, j] = out[pad + H - 2 - k, j]
