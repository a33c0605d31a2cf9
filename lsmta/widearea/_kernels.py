"""Compiled inner loop of the sub-sampled, windowed LED search (numba; see
:mod:`lsmta.widearea.search`).

Why compiled: the search visits a few thousand scattered pixels of a frame. NumPy does that
with index arrays (a gather), which costs more per pixel than comparing the whole frame in
one contiguous pass, so in NumPy the search that tests 6-10 % of the pixels was slower by
the clock than the full search. Here windows, grid and flood fill are one loop.

Why no image-sized scratch: the search reads only the windows' rows and the grid's pixels,
so its cost should follow them, not the image. An ``(H, W)`` array of flags, allocated and
cleared per frame, cost about as much as the windows' pixels at 640 x 480 (the pages of a
fresh array are zeroed by the system on first touch). Whether a pixel was tested is instead
known from the geometry (inside a window, or on the grid), and the few pixels the flood
fills visit are kept in a small open-addressing hash set that grows with them.
"""

from __future__ import annotations

import numba as nb
import numpy as np

_EMPTY = -1
_TESTED = 1          # visited by a flood fill, under threshold
_FEATURE = 2         # part of a feature


@nb.njit(cache=True)
def search_kernel(img, thr, bg, centres, half, k, jr, jc, min_area, max_area):
    """Windows of ``2 half[i]`` x ``2 half[i]`` pixels around the finite ``centres`` (n, 2)
    (x, y, rounded half to even; rows and columns ``y - half[i]`` to ``y + half[i] - 1``),
    then the grid; every pixel over threshold found there seeds a flood fill. Returns the
    centroids (n, 2) and areas (n,) of the features within the area limits, in the raster
    order of each feature's first pixel, and ``tested``: the pixels the search decides on
    (the grid's, the windows', and those the flood fills visit; each once), not the pixels
    read. A grid row is first compared whole with its thresholds in one contiguous pass
    (cheaper than its strided grid pixels); those reads are not counted, so ``tested``
    measures the sub-sampled design (Davis's Fig. 32), not the memory traffic."""
    H, W = img.shape
    box, r_lo, r_hi = _boxes(centres, half, H, W)
    imgf = img.ravel()
    thrf = thr.ravel()
    tested = len(range(jr, H, k)) * len(range(jc, W, k))
    bound = tested
    for w in range(box.shape[0]):
        bound += (box[w, 1] - box[w, 0]) * (box[w, 3] - box[w, 2])
    seeds = np.empty(min(bound, H * W), np.int64)     # not touched beyond the seeds
    n_seeds = 0
    # the windows' rows only: per row the union of the windows' column ranges (each pixel
    # once; the grid's pixels there are counted with the grid)
    n_win = box.shape[0]
    iv = np.empty((n_win, 2), np.int64)
    for r in range(r_lo, r_hi):
        m = 0
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
            tested += b - a
            if on_grid_row:
                tested -= _on_grid(a, b, jc, k)
            if _any_over(imgf, thrf, r * W + a, r * W + b):
                for q in range(r * W + a, r * W + b):
                    if imgf[q] > thrf[q]:
                        seeds[n_seeds] = q
                        n_seeds += 1
    # the grid's pixels (those inside a window were seeded above); a row with no pixel over
    # threshold has no grid pixel over it either, and one contiguous (vectorised) pass over
    # the row says so faster than the strided reads of its grid pixels
    for r in range(jr, H, k):
        if not _any_over(imgf, thrf, r * W, (r + 1) * W):
            continue
        for q in range(r * W + jc, (r + 1) * W, k):
            if imgf[q] > thrf[q] and not _in_boxes(box, r, q - r * W):
                seeds[n_seeds] = q
                n_seeds += 1
    # the features: a flood fill from every seed not yet part of one
    keys = np.full(256, _EMPTY, np.int64)     # the hash set of the pixels the fills visit
    vals = np.zeros(256, np.uint8)
    used = np.zeros(1, np.int64)
    out = np.empty((n_seeds, 3))              # x, y, first pixel in raster order
    area = np.empty(n_seeds, np.int64)
    stack = np.empty(256, np.int64)
    n_out = 0
    for i in range(n_seeds):
        if _get(keys, vals, seeds[i]) == _FEATURE:
            continue
        tested, stack, keys, vals = _fill(img, thr, bg, seeds[i], keys, vals, used, stack,
                                          out, area, n_out, tested, k, jr, jc, box)
        n_out += 1
    return _kept(out, area, n_out, min_area, max_area) + (tested,)


@nb.njit(cache=True)
def _boxes(centres, half, H, W):
    """The windows' row and column ranges on the image ``(n, 4)`` (r0, r1, c0, c1; windows
    off the image or around non-finite centres dropped) and the rows they span."""
    box = np.empty((centres.shape[0], 4), np.int64)
    n = 0
    r_lo, r_hi = H, 0
    for w in range(centres.shape[0]):
        if not (np.isfinite(centres[w, 0]) and np.isfinite(centres[w, 1])):
            continue
        x = int(np.rint(centres[w, 0]))
        y = int(np.rint(centres[w, 1]))
        r0, r1 = max(y - half[w], 0), min(y + half[w], H)
        c0, c1 = max(x - half[w], 0), min(x + half[w], W)
        if r0 < r1 and c0 < c1:
            box[n, 0], box[n, 1], box[n, 2], box[n, 3] = r0, r1, c0, c1
            r_lo, r_hi = min(r_lo, r0), max(r_hi, r1)
            n += 1
    return box[:n], r_lo, r_hi


@nb.njit(cache=True)
def _any_over(imgf, thrf, q0, q1):
    """Whether any of the pixels ``q0:q1`` is over its threshold (a loop without branches
    over two slices, which the compiler vectorises: most rows have none; indexing the flat
    arrays by ``q`` itself, or with a stride, is not vectorised: about 40 times slower per row
    when measured for ``experiments/widearea_detection_benchmark.py``)."""
    a = imgf[q0:q1]
    t = thrf[q0:q1]
    hit = False
    for i in range(a.shape[0]):
        hit |= a[i] > t[i]
    return hit


@nb.njit(cache=True)
def _in_boxes(box, r, c):
    for w in range(box.shape[0]):
        if box[w, 0] <= r < box[w, 1] and box[w, 2] <= c < box[w, 3]:
            return True
    return False


@nb.njit(cache=True)
def _push(a, n, q):
    """Append ``q`` to the first ``n`` entries of ``a`` (doubled when full)."""
    if n == a.shape[0]:
        bigger = np.empty(2 * n, a.dtype)
        bigger[:n] = a
        a = bigger
    a[n] = q
    return a, n + 1


@nb.njit(cache=True)
def _slot(keys, q):
    """Where ``q`` is in the hash set, or the empty slot it would take (linear probing)."""
    mask = keys.shape[0] - 1
    s = (q * 2654435761) & mask
    while keys[s] != _EMPTY and keys[s] != q:
        s = (s + 1) & mask
    return s


@nb.njit(cache=True)
def _get(keys, vals, q):
    s = _slot(keys, q)
    return vals[s] if keys[s] == q else 0


@nb.njit(cache=True)
def _set(keys, vals, used, q, v):
    """Set ``q``'s value to ``v``; the table doubles when half full. Returns the table."""
    s = _slot(keys, q)
    if keys[s] != q:
        if 2 * (used[0] + 1) > keys.shape[0]:
            old_k, old_v = keys, vals
            keys = np.full(2 * old_k.shape[0], _EMPTY, np.int64)
            vals = np.zeros(2 * old_k.shape[0], np.uint8)
            for i in range(old_k.shape[0]):
                if old_k[i] != _EMPTY:
                    t = _slot(keys, old_k[i])
                    keys[t], vals[t] = old_k[i], old_v[i]
            s = _slot(keys, q)
        keys[s] = q
        used[0] += 1
    vals[s] = v
    return keys, vals


@nb.njit(cache=True)
def _kept(out, area, n_out, min_area, max_area):
    """The features within the area limits, by first pixel (insertion sort: a few features;
    NumPy's masks and argsort cost microseconds per call here)."""
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
    return xy[:n_kept], kept_area[:n_kept]


@nb.njit(cache=True)
def _on_grid(a, b, j, k):
    """How many of a, ..., b - 1 are j modulo k."""
    first = a + (j - a) % k
    return 0 if first >= b else (b - 1 - first) // k + 1


@nb.njit(cache=True)
def _fill(img, thr, bg, seed, keys, vals, used, stack, out, area_out, n_out, tested, k, jr,
          jc, box):
    """Flood-fill the 8-connected pixels over threshold from ``seed`` (flat index, tested
    and over threshold); record the component's weighted centroid, first pixel and area
    as feature ``n_out``; returns the pixels tested so far, the (possibly grown) stack and
    hash set. Pixels on the grid (``r = jr``, ``c = jc`` modulo ``k``), in a window
    (``box``) or visited by a fill were tested before."""
    H, W = img.shape
    keys, vals = _set(keys, vals, used, seed, _FEATURE)
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
                state = _get(keys, vals, n)
                if state != 0:                    # a feature's, or tested and under
                    continue
                if ((rr - jr) % k != 0 or (cc - jc) % k != 0) and not _in_boxes(box, rr, cc):
                    tested += 1
                if img[rr, cc] > thr[rr, cc]:
                    keys, vals = _set(keys, vals, used, n, _FEATURE)
                    stack, top = _push(stack, top, n)
                else:
                    keys, vals = _set(keys, vals, used, n, _TESTED)
    out[n_out, 0] = sx / sw
    out[n_out, 1] = sy / sw
    out[n_out, 2] = first
    area_out[n_out] = area
    return tested, stack, keys, vals
