"""Compiled inner loop of the sub-sampled, windowed LED search (numba; see
:mod:`lsmta.widearea.search`).

Why compiled: the search visits a few thousand scattered pixels of a frame. NumPy does that
with index arrays (a gather), which costs more per pixel than comparing the whole frame in
one contiguous pass, so in NumPy the search that tests 6-10 % of the pixels was slower by
the clock than the full search. Here windows, grid and flood fill are one loop.

Why no image-sized scratch: the search reads only the windows' rows and the grid's rows,
so its cost should follow them, not the image. An ``(H, W)`` array of flags, allocated and
cleared per frame, cost about as much as the windows' pixels at 640 x 480 (the pages of a
fresh array are zeroed by the system on first touch). Whether a pixel was tested is instead
known from the geometry (inside a window, or on the grid), and the few pixels the flood
fills visit are kept in a small open-addressing hash set that grows with them.

Why the loops are written out: a call between compiled functions that passes arrays costs
tens of nanoseconds here (the arrays' reference counts), more than the work of one pixel;
a flood fill that looked its neighbours up in the hash set through such calls took about
3 microseconds for a 9-pixel spot, eight times as long as with the look-ups written into
its loop. So the per-pixel and per-row loops (the windows' rows, the grid, the fills) call
nothing with array arguments; helpers are called once per frame or on rare events (the
hash set or a stack growing).

Why prefetch: the frames come from memory (not the cache), and the windows' rows are short
pieces a row apart, too scattered for the processor's own prefetching: the search asks for
each window's row ``_AHEAD`` rows down (LLVM's ``prefetch``, :func:`_prefetch`) while it
compares the current one. When it was added (commit a1ccb7b), the guided search at
640 x 480 took roughly a sixth less time with it in replays of the frames of
``experiments/widearea_detection_benchmark.py`` on our shared two-core machine (load about
4); a hint, whose gain depends on the processor and the load, not re-measured since. Asking
for the next grid row or a seed's neighbourhood as well saved nothing measurable there.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

_EMPTY = -1
_TESTED = 1          # visited by a flood fill, under threshold
_FEATURE = 2         # part of a feature
_AHEAD = 4           # rows of the windows asked for ahead of the row compared
_LINE = 64           # bytes per cache line


@intrinsic
def _prefetch(typingctx, arr, idx):
    """Ask for the cache line of ``arr[idx]`` (1-D array; a hint, no effect on results)."""
    def codegen(context, builder, signature, args):
        aty = signature.args[0]
        a = context.make_array(aty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aty, a, [args[1]], wraparound=False)
        ptr = builder.bitcast(ptr, ir.IntType(8).as_pointer())
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32]),
            "llvm.prefetch.p0")
        builder.call(fn, [ptr, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()
    return types.void(arr, idx), codegen


@nb.njit(cache=True)
def search_kernel(img, thr, bg, centres, half, k, kc, jr, jc, min_area, max_area):
    """Windows of ``2 h`` x ``2 h`` pixels, ``h = ceil(half[i])`` (finite, >= 1), around the
    finite ``centres`` (n, 2) (x, y, rounded half to even; rows and columns ``y - h`` to
    ``y + h - 1``),
    then the grid (rows ``jr`` modulo ``k``, columns ``jc`` modulo ``kc``: ``kc = k`` one
    pixel per ``k x k`` block, ``kc = 1`` every pixel of one row in ``k``; ``jc`` is reduced
    modulo ``kc`` here, so with ``kc = 1`` every column is on the grid whatever ``jc``); every
    pixel over threshold found there seeds a flood fill. Returns the
    centroids (n, 2) and areas (n,) of the features within the area limits, in the raster
    order of each feature's first pixel, and ``tested``: the pixels the search decides on
    (the grid's, the windows', and those the flood fills visit; each once), not the pixels
    read. A grid row is first compared whole with its thresholds in one contiguous pass
    (cheaper than its strided grid pixels); those reads are not counted, so ``tested``
    measures the sub-sampled design (Davis's Fig. 32), not the memory traffic."""
    H, W = img.shape
    jc = jc % kc                  # the only place the column offset is reduced to the step
    box = _boxes(centres, half, H, W)
    imgf = img.ravel()
    thrf = thr.ravel()
    tested = len(range(jr, H, k)) * len(range(jc, W, kc))
    bound = tested
    for w in range(box.shape[0]):
        bound += (box[w, 1] - box[w, 0]) * (box[w, 3] - box[w, 2])
    seeds = np.empty(min(bound, H * W), np.int64)     # not touched beyond the seeds
    n_seeds, tested = _window_rows(imgf, thrf, box, W, k, kc, jr, jc, seeds, tested)
    n_seeds = _grid_seeds(imgf, thrf, box, H, W, k, kc, jr, jc, seeds, n_seeds)
    out, area, n_out, tested = _fills(imgf, thrf, bg.ravel(), H, W, seeds, n_seeds, box, k,
                                      kc, jr, jc, tested)
    return _kept(out, area, n_out, min_area, max_area) + (tested,)


@nb.njit(cache=True)
def _boxes(centres, half, H, W):
    """The windows' row and column ranges on the image ``(n, 4)`` (r0, r1, c0, c1; windows
    off the image or around non-finite centres dropped), sorted by first row. The edges are
    clipped to the image as floats before ``int()`` (which wraps a huge value)."""
    box = np.empty((centres.shape[0], 4), np.int64)
    n = 0
    for w in range(centres.shape[0]):
        if not (np.isfinite(centres[w, 0]) and np.isfinite(centres[w, 1])):
            continue
        if not (half[w] >= 1.0 and np.isfinite(half[w])):
            raise ValueError("half_sizes: expected finite sizes of at least 1 px where the "
                             "position is finite")
        x, y, h = np.rint(centres[w, 0]), np.rint(centres[w, 1]), np.ceil(half[w])
        r0 = int(min(max(y - h, 0.0), float(H)))
        r1 = int(min(max(y + h, 0.0), float(H)))
        c0 = int(min(max(x - h, 0.0), float(W)))
        c1 = int(min(max(x + h, 0.0), float(W)))
        if r0 < r1 and c0 < c1:
            j = n                                 # insertion by first row
            while j > 0 and box[j - 1, 0] > r0:
                box[j] = box[j - 1]
                j -= 1
            box[j, 0], box[j, 1], box[j, 2], box[j, 3] = r0, r1, c0, c1
            n += 1
    return box[:n]


@nb.njit(cache=True)
def _window_rows(imgf, thrf, box, W, k, kc, jr, jc, seeds, tested):
    """Seed every pixel over threshold in the windows ``box`` (sorted by first row), row by
    row over the rows they cover only; per row the windows that cover it (kept sorted by
    first column as the sweep enters and leaves them) give the union of their column
    ranges, each pixel once, and each window's row ``_AHEAD`` rows down is asked for.
    Adds the pixels not on the grid to ``tested`` (the grid's are counted with the grid).
    Returns the number of seeds and ``tested``."""
    n = box.shape[0]
    act = np.empty(n, np.int64)          # the windows covering the row, by first column
    m = 0
    nxt = 0
    n_seeds = 0
    r = 0
    step = _LINE // imgf.itemsize        # elements per cache line: image
    step_t = _LINE // thrf.itemsize      # and thresholds (their own dtype)
    while nxt < n or m > 0:
        if m == 0:
            r = max(r, box[nxt, 0])       # skip rows no window covers
        while nxt < n and box[nxt, 0] <= r:
            for rr in range(r, min(r + _AHEAD, box[nxt, 1])):     # its first rows
                # the prefetch of one window row; kept in step with the copy below
                first, last = rr * W + box[nxt, 2], rr * W + box[nxt, 3] - 1
                for q in range(first, last + step, step):
                    _prefetch(imgf, min(q, last))
                for q in range(first, last + step_t, step_t):
                    _prefetch(thrf, min(q, last))
            j = m                             # insertion by first column
            while j > 0 and box[act[j - 1], 2] > box[nxt, 2]:
                act[j] = act[j - 1]
                j -= 1
            act[j] = nxt
            m += 1
            nxt += 1
        ra = r + _AHEAD
        for i in range(m):
            if ra < box[act[i], 1]:
                # the prefetch of one window row; kept in step with the copy above
                first, last = ra * W + box[act[i], 2], ra * W + box[act[i], 3] - 1
                for q in range(first, last + step, step):
                    _prefetch(imgf, min(q, last))
                for q in range(first, last + step_t, step_t):
                    _prefetch(thrf, min(q, last))
        on_grid_row = (r - jr) % k == 0
        i = 0
        while i < m:
            a, b = box[act[i], 2], box[act[i], 3]
            i += 1
            while i < m and box[act[i], 2] <= b:
                b = max(b, box[act[i], 3])
                i += 1
            tested += b - a
            if on_grid_row:
                tested -= _on_grid(a, b, jc, kc)
            x = imgf[r * W + a:r * W + b]     # any over? (a loop the compiler vectorises)
            t = thrf[r * W + a:r * W + b]
            hit = False
            for p in range(b - a):
                hit |= x[p] > t[p]
            if hit:
                for q in range(r * W + a, r * W + b):
                    if imgf[q] > thrf[q]:
                        seeds[n_seeds] = q
                        n_seeds += 1
        r += 1
        j = 0                                 # leave the windows that end here
        for i in range(m):
            if box[act[i], 1] > r:
                act[j] = act[i]
                j += 1
        m = j
    return n_seeds, tested


@nb.njit(cache=True)
def _grid_seeds(imgf, thrf, box, H, W, k, kc, jr, jc, seeds, n_seeds):
    """Seed the grid's pixels over threshold outside the windows (those inside were seeded
    with the windows). A row with no pixel over threshold has no grid pixel over it either,
    and one contiguous (vectorised) pass over the row says so faster than the strided
    reads of its grid pixels (indexing the flat arrays by ``q`` itself, or with a stride,
    is not vectorised: about 40 times slower per row when measured for
    ``experiments/widearea_detection_benchmark.py``)."""
    for r in range(jr, H, k):
        x = imgf[r * W:(r + 1) * W]
        t = thrf[r * W:(r + 1) * W]
        hit = False
        for p in range(W):
            hit |= x[p] > t[p]
        if not hit:
            continue
        for c in range(jc, W, kc):
            q = r * W + c
            if imgf[q] > thrf[q]:
                inside = False       # inside a window? kept in step with _fills's copy
                for w in range(box.shape[0]):
                    inside |= box[w, 0] <= r < box[w, 1] and box[w, 2] <= c < box[w, 3]
                if not inside:
                    seeds[n_seeds] = q
                    n_seeds += 1
    return n_seeds


@nb.njit(cache=True)
def _hash(q, mask):
    """The first slot of ``q`` in a hash set of ``mask + 1`` slots: the middle bits of a
    multiplicative hash (the low bits of ``q * C`` depend on the low bits of ``q`` only,
    which repeat down an image column)."""
    return np.int64((np.uint64(q) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(32)) & mask


@nb.njit(cache=True)
def _grown(keys, vals):
    """The hash set (keys, values) rehashed into twice the slots."""
    new_k = np.full(2 * keys.shape[0], _EMPTY, np.int64)
    new_v = np.zeros(2 * keys.shape[0], np.uint8)
    mask = new_k.shape[0] - 1
    for i in range(keys.shape[0]):
        if keys[i] != _EMPTY:
            s = _hash(keys[i], mask)     # the probe; kept in step with _fills's two
            while new_k[s] != _EMPTY:
                s = (s + 1) & mask
            new_k[s], new_v[s] = keys[i], vals[i]
    return new_k, new_v


@nb.njit(cache=True)
def _bigger(a):
    """``a`` doubled in length (its entries kept)."""
    b = np.empty(2 * a.shape[0], a.dtype)
    b[:a.shape[0]] = a
    return b


@nb.njit(cache=True)
def _fills(imgf, thrf, bgf, H, W, seeds, n_seeds, box, k, kc, jr, jc, tested):
    """Flood-fill the 8-connected pixels over threshold from every seed not yet part of a
    feature; per feature its weighted centroid, first pixel (raster order) and area.
    The pixels the fills visit are kept in an open-addressing hash set (linear probing;
    doubled before it is half full). Pixels on the grid (``r = jr`` modulo ``k``, ``c = jc``
    modulo ``kc``), in a window (``box``) or visited by a fill were tested before; the others
    add to ``tested``. Returns (x, y, first) (n, 3), areas (n,), n and ``tested``."""
    keys = np.full(256, _EMPTY, np.int64)
    vals = np.zeros(256, np.uint8)
    used = 0
    out = np.empty((n_seeds, 3))
    area_out = np.empty(n_seeds, np.int64)
    stack = np.empty(64, np.int64)
    n_out = 0
    for i in range(n_seeds):
        seed = seeds[i]
        mask = keys.shape[0] - 1
        s = _hash(seed, mask)        # the hash set's probe; kept in step with the
        while keys[s] != _EMPTY and keys[s] != seed:      # neighbours' below and _grown
            s = (s + 1) & mask
        if keys[s] == seed:               # part of a feature found before
            continue
        keys[s], vals[s] = seed, _FEATURE
        used += 1
        stack[0] = seed
        top = 1
        sw = sx = sy = 0.0
        area = 0
        first = seed
        while top > 0:
            top -= 1
            q = stack[top]
            if 2 * (used + 8) > keys.shape[0]:      # room for the 8 neighbours
                keys, vals = _grown(keys, vals)
            if top + 8 > stack.shape[0]:
                stack = _bigger(stack)
            first = min(first, q)
            r = q // W
            c = q - r * W
            w = max(float(imgf[q]) - bgf[q], 0.0) + 1e-9
            sw += w
            sx += w * c
            sy += w * r
            area += 1
            mask = keys.shape[0] - 1
            for rr in range(max(r - 1, 0), min(r + 2, H)):
                for cc in range(max(c - 1, 0), min(c + 2, W)):
                    n = rr * W + cc
                    s = _hash(n, mask)   # the probe; kept in step with the seed's above
                    while keys[s] != _EMPTY and keys[s] != n:
                        s = (s + 1) & mask
                    if keys[s] == n:              # a feature's, or tested and under
                        continue
                    keys[s] = n
                    used += 1
                    if (rr - jr) % k != 0 or (cc - jc) % kc != 0:
                        inside = False   # kept in step with _grid_seeds's copy
                        for b in range(box.shape[0]):
                            inside |= (box[b, 0] <= rr < box[b, 1]
                                       and box[b, 2] <= cc < box[b, 3])
                        tested += not inside
                    if imgf[n] > thrf[n]:
                        vals[s] = _FEATURE
                        stack[top] = n
                        top += 1
                    else:
                        vals[s] = _TESTED
        out[n_out, 0] = sx / sw
        out[n_out, 1] = sy / sw
        out[n_out, 2] = first
        area_out[n_out] = area
        n_out += 1
    return out, area_out, n_out, tested


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
