"""Whether a second view shows a dot where a marker held by one view can be: an image test
of the frames a marker is not intersected in, to tell a lost dot from a hidden one.

In a frame where exactly one view holds a joined marker, the marker lies on that view's
ray; how far along it is bounded by its own motion: it is at most ``v |t - n|`` from its
3-D position in the nearest frame ``n`` that has one, ``v`` its fastest step between two
consecutive frames with 3-D positions (mm per frame, measured on its own path). That piece
of the ray, projected into every other view whose frame holds it, is where a second view
can show the marker: a dot (a blob of at least ``min_contrast`` above its window's median,
centred on its core, as :func:`~lsmta.tracking.join_checks.fill_gaps` finds them) within
``max_px`` of the projected piece. A frame in which no other view shows any dot there is
*hidden* (:func:`hidden_frames`): no view but one shows the marker, by the pictures. Any dot
within reach counts, another marker's too (a dot on the line may be this marker's); a dot
beyond the reach, farther than ``max_px`` from the line, or fainter than ``min_contrast``
does not, so a frame can be called hidden where a view shows the marker's dot (as on the
demo, below); and another marker's dot within reach makes a hidden frame count as shown.
The count errs both ways: it is neither the hidden frames nor a bound on them, a rough
count to look at the pictures by.
Frames no view holds, frames of markers that are never intersected or have no two
consecutive 3-D frames, and frames where the holding view's ray misses the reach, are not
judged (False). No truth: the frames, the cameras and the marker's own tracks only. The
count is for the lead to judge beside the target, not the target: the marker stage's 3-D
share is scored on all frames, hidden or not.

The limit: the reach is the fastest step the marker was *seen* to make; a marker that moves
faster while lost (a limb swinging behind another) lies beyond it, and its frame can be
called hidden while its dot shows farther along the line. A wrong 3-D position (a wrong
dot filled) makes the step, and so the reach, longer. On the Pose2Sim demo (with the
fill's dot test, ``MarkerParams().fill_dot``) the test calls marker 5 (above the knee,
views cam01 and cam02) hidden at frames 74, 76-83, 87-89 and 95-96, and marker 7 (cam01 and
cam02) at 78-82, 84, 88, 92 and 93; in frames 92 and 93 cam01 shows marker 7's dot by eye,
so those two at least are called hidden wrongly.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_int, as_scalar
from .blob_follow import dot_centre, dot_contrast
from .join_checks import _check_stacks, _members, marker_speeds, ray_piece
from .markers import find_blobs
from .view_tracks import _checked, joined_positions, triangulate_joined

__all__ = ["hidden_frames"]

_STEP_MM = 2.0      # spacing of the ray's samples (about 1 px at 3 m with f about 1500 px)


def _reach(xyz) -> tuple[np.ndarray, float]:
    """``(T,)`` frames to the nearest frame with a 3-D position (inf: none), and the
    fastest step between consecutive 3-D frames, mm per frame (NaN: none)."""
    has = np.isfinite(xyz).all(axis=1)
    idx = np.flatnonzero(has)
    T = len(xyz)
    if not idx.size:
        return np.full(T, np.inf), np.nan
    near = idx[np.abs(np.arange(T)[:, None] - idx[None]).argmin(axis=1)]
    return near, float(marker_speeds(xyz[:, None])[0])


def _shows_dot(cam, img, ends, radius, min_contrast, max_px) -> bool:
    """Whether ``img`` holds a dot within ``max_px`` of the projection of the 3-D piece
    ``ends`` (sampled every ``_STEP_MM``; the samples outside the frame left out)."""
    a, b = ends
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / _STEP_MM)) + 1)
    X = a + (b - a) * np.linspace(0, 1, n)[:, None]
    H, W = img.shape
    pad = 2 * radius + max_px
    c = np.full((n, 2), np.nan)
    lens = cam.in_lens(X)
    if lens.any():
        c[lens] = cam.project(X[lens])
    inside = (np.isfinite(c).all(axis=1) & (c[:, 0] > -pad) & (c[:, 0] < W + pad)
              & (c[:, 1] > -pad) & (c[:, 1] < H + pad))
    keep = inside[:-1] & inside[1:]                                 # segments in the frame
    if not keep.any():
        return False
    p, q = c[:-1][keep], c[1:][keep]
    line = np.concatenate([p, q])
    x0, y0 = np.floor(line.min(axis=0) - pad).astype(int).clip(0)
    x1, y1 = np.ceil(line.max(axis=0) + pad).astype(int) + 1
    x1, y1 = min(x1, W), min(y1, H)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return False
    blobs = find_blobs(np.asarray(img[y0:y1, x0:x1], np.float64), sigma=radius / 1.6,
                       min_strength=min_contrast) + [x0, y0]
    if not len(blobs):
        return False
    blobs = dot_centre(img, blobs, radius=radius)
    blobs = blobs[dot_contrast(img, blobs, radius=radius) >= min_contrast]
    seg = q - p
    u = np.clip(((blobs[:, None] - p[None]) * seg[None]).sum(axis=2)
                / np.maximum((seg ** 2).sum(axis=1), 1e-12)[None], 0, 1)
    dist = np.linalg.norm(blobs[:, None] - (p[None] + u[..., None] * seg[None]), axis=2)
    return bool(len(dist) and dist.min() <= max_px)


def hidden_frames(stacks, cameras, xy, members, *, radius: int = 4,
                  min_contrast: float = 15.0, max_px: float = 3.0) -> np.ndarray:
    """Frames in which one view holds a marker and no other view shows a dot where the
    marker can be (see the module docstring): a rough count of its hidden frames (it errs
    both ways), to judge beside the target, not the target.

    Parameters
    ----------
    stacks : sequence of K (T, H_k, W_k) arrays
        Grey frames of every view.
    cameras : sequence of K Camera
    xy : sequence of K (T, N_k, 2) arrays
        Each view's tracks, px (after the fill, as intersected).
    members : (M, K) int array
        The joins.
    radius : int
        Half-width of a dot's window, px (the fill's ``radius``).
    min_contrast : float
        Smallest peak of a dot above its window's median, grey levels.
    max_px : float
        Largest distance of a dot from the projected piece of the ray, px.

    Returns
    -------
    (T, M) bool array
        True: hidden (one view holds the marker, no other view shows a dot there).
    """
    cams, arrays = _checked(cameras, xy)
    m = _members(members, len(cams))
    radius = as_int(radius, "radius", minimum=1, unit="pixels")
    min_contrast = as_scalar(min_contrast, "min_contrast", positive=True)
    max_px = as_scalar(max_px, "max_px", positive=True)
    T = arrays[0].shape[0]
    _check_stacks(stacks, cams, T)
    pos = joined_positions(arrays, m)                               # (T, K, M, 2)
    xyz, _, _ = triangulate_joined(cams, arrays, m)
    held = np.isfinite(pos).all(axis=3)                             # (T, K, M)
    out = np.zeros((T, len(m)), bool)
    for j in range(len(m)):
        near, speed = _reach(xyz[:, j])
        for t in np.flatnonzero(held[:, :, j].sum(axis=1) == 1):
            if not np.isfinite(speed) or not np.isfinite(near[t]):
                continue
            h = int(np.flatnonzero(held[t, :, j])[0])
            ends = ray_piece(cams[h], pos[t, h, j], xyz[int(near[t]), j],
                             speed * abs(t - int(near[t])))
            if ends is None:
                continue
            out[t, j] = not any(_shows_dot(cams[k], np.asarray(stacks[k][t]), ends, radius,
                                           min_contrast, max_px)
                                for k in range(len(cams)) if k != h)
    return out
