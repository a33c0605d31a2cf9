"""Compiled inner loop of the sub-sampled, windowed LED search (numba; see
:mod:`lsmta.widearea.search`).

Why compiled: the search visits a few thousand scattered pixels of a frame. NumPy does that
with index arrays (a gather), which costs more per pixel than comparing the whole frame in
one contiguous pass, so in NumPy the search that tests 6-10 % of the pixels was slower by
the clock than the full search. Here windows, grid and flood fill are one loop.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def search_kernel(img, thr, bg, centres, half, k, jr, jc, min_area, max_area):
    """Windows of ``2 half[i]`` x ``2 half[i]`` pixels around the finite ``centres`` (n, 2)
    (x, y, rounded half to even; rows and columns ``y - half[i]`` to ``y + half[i] - 1``),
    then the grid; every pixel over threshold found there seeds a flood fill. Returns the
    centroids (n, 2) and areas (n,) of the features within the area limits, in the raster
    order of each feature's first pixel, and the number of pixels tested."""
    H, W = img.shape
    flag = np.zeros(H * W, np.uint8)          # 1: tested, 2: part of a feature
    bound = ((H + k - 1) // k) * ((W + k - 1) // k)
    for w in range(centres.shape[0]):
        bound += 4 * half[w] * half[w]
    seeds = np.empty(min(bound, H * W), np.int32)
    n_seeds = 0
    tested = 0
    # the windows: every pixel, clipped at the border; row by row, the union of the
    # windows' column ranges is scanned (each pixel once)
    imgf = img.ravel()
    thrf = thr.ravel()
    n_win = centres.shape[0]
    box = np.full((n_win, 4), -1, np.int64)
    r_lo, r_hi = H, 0
    for w in range(n_win):
        if not (np.isfinite(centres[w, 0]) and np.isfinite(centres[w, 1])):
            continue
        x = int(np.rint(centres[w, 0]))
        y = int(np.rint(centres[w, 1]))
        r0, r1 = max(y - half[w], 0), min(y + half[w], H)
        c0, c1 = max(x - half[w], 0), min(x + half[w], W)
        if r0 < r1 and c0 < c1:
            box[w, 0], box[w, 1], box[w, 2], box[w, 3] = r0, r1, c0, c1
            r_lo, r_hi = min(r_lo, r0), max(r_hi, r1)
    # one pass down the rows: the union of the windows' column ranges, then the grid pixels
    # of the row outside them
    tested += len(range(jr, H, k)) * len(range(jc, W, k))
    iv = np.empty((n_win, 2), np.int64)
    for r in range(H):
        m = 0
        if r_lo <= r < r_hi:
            for w in range(n_win):
                if box[w, 0] <= r < box[w, 1]:
                    j = m                             # insertion by column start
                    while j > 0 and iv[j - 1, 0] > box[w, 2]:
                        iv[j] = iv[j - 1]
                        j -= 1
                    iv[j, 0], iv[j, 1] = box[w, 2], box[w, 3]
                    m += 1
        on_grid_row = (r - jr) % k == 0
        i = 0
        while i < m:
            a, b = iv[i, 0], iv[i, 1]
            i += 1
            while i < m and iv[i, 0] <= b:
                b = max(b, iv[i, 1])
                i += 1
            q0, q1 = r * W + a, r * W + b
            flag[q0:q1] = 1
            tested += q1 - q0
            if on_grid_row:
                tested -= _on_grid(a, b, jc, k)       # counted with the grid above
            for q in range(q0, q1):
                if imgf[q] > thrf[q]:
                    seeds[n_seeds] = q
                    n_seeds += 1
        if on_grid_row:
            for q in range(r * W + jc, (r + 1) * W, k):
                if imgf[q] > thrf[q] and flag[q] == 0:
                    flag[q] = 1
                    seeds[n_seeds] = q
                    n_seeds += 1
    # the features: a flood fill from every seed not yet part of one
    out = np.empty((n_seeds, 3))              # x, y, first pixel in raster order
    area = np.empty(n_seeds, np.int64)
    stack = np.empty(256, np.int32)
    n_out = 0
    for i in range(n_seeds):
        if flag[seeds[i]] & 2:
            continue
        tested, stack = _fill(img, thr, bg, seeds[i], flag, stack, out, area, n_out, tested,
                              k, jr, jc)
        n_out += 1
    # the features within the area limits, by first pixel (insertion sort: a few features;
    # NumPy's masks and argsort cost microseconds per call here)
    xy = np.empty((n_out, 2))
    kept_area = np.empty(n_out, np.int64)
    n_kept = 0
    for i in range(n_out):
        if area[i] < min_area or area[i] > max_area:
            continue
        x, y, first, a = out[i, 0], out[i, 1], out[i, 2], area[i]   # out[:n_kept]: sorted
        j = n_kept
        while j > 0 and out[j - 1, 2] > first:
            out[j] = out[j - 1]
            kept_area[j] = kept_area[j - 1]
            j -= 1
        out[j, 0], out[j, 1], out[j, 2] = x, y, first
        kept_area[j] = a
        n_kept += 1
    xy[:n_kept] = out[:n_kept, :2]
    return xy[:n_kept], kept_area[:n_kept], tested


@nb.njit(cache=True)
def _on_grid(a, b, j, k):
    """How many of a, ..., b - 1 are j modulo k."""
    first = a + (j - a) % k
    return 0 if first >= b else (b - 1 - first) // k + 1


@nb.njit(cache=True)
def _fill(img, thr, bg, seed, flag, stack, out, area_out, n_out, tested, k, jr, jc):
    """Flood-fill the 8-connected pixels over threshold from ``seed`` (flat index, tested
    and over threshold); record the component's weighted centroid, first pixel and area
    as feature ``n_out``; returns the pixels tested so far and the (possibly grown) stack.
    Pixels flagged or on the grid (``r = jr``, ``c = jc`` modulo ``k``) were tested before."""
    H, W = img.shape
    flag[seed] |= 2
    stack[0] = seed
    top = 1
    sw = 0.0
    sx = 0.0
    sy = 0.0
    area = 0
    first = seed
    while top > 0:
        top -= 1
        q = stack[top]
        first = min(first, q)
        r = q // W
        c = q - r * W
        w = max(float(img[r, c]) - bg[r, c], 0.0) + 1e-9
        sw += w
        sx += w * c
        sy += w * r
        area += 1
        for dr in range(-1, 2):
            rr = r + dr
            if rr < 0 or rr >= H:
                continue
            for dc in range(-1, 2):
                cc = c + dc
                if cc < 0 or cc >= W or (dr == 0 and dc == 0):
                    continue
                n = rr * W + cc
                if flag[n] & 2:
                    continue
                if not flag[n] & 1:
                    flag[n] |= 1
                    if (rr - jr) % k != 0 or (cc - jc) % k != 0:
                        tested += 1
                if img[rr, cc] > thr[rr, cc]:
                    flag[n] |= 2
                    if top == stack.shape[0]:
                        bigger = np.empty(2 * top, np.int32)
                        bigger[:top] = stack
                        stack = bigger
                    stack[top] = n
                    top += 1
    out[n_out, 0] = sx / sw
    out[n_out, 1] = sy / sw
    out[n_out, 2] = first
    area_out[n_out] = area
    return tested, stack
