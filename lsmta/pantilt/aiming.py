"""Aiming a pan-tilt camera at a world point (Davis 2002, Section 4.3).

Inverting the projection has several solutions, and a controller that jumps between them
makes the camera jitter. :func:`aim` therefore searches locally, started from the current
setting: it tries a small pan or tilt change in each direction, keeps any that brings the
target's image nearer the principal point, and repeats until the target is within
``tol_px`` of it. Our search is a compass search: the first step is the angle that the
current image error subtends, it is kept while moves succeed and divided by three when none
of the four does (the thesis gives no step rule; this one needs about ten iterations from
the previous command's setting). :func:`aim_least_squares` solves
the same problem directly with :func:`scipy.optimize.least_squares`, for comparison.

Both are vectorised over targets and return an :class:`Aim`; a target the head cannot centre
(outside its range, or behind it) is reported with ``reachable = False`` and the best
setting found, never silently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .._validate import as_int, as_points, as_scalar, freeze
from .model import PanTiltCamera

_MOVES = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


@dataclass(frozen=True, eq=False)
class Aim:
    """Settings that centre targets.

    Attributes
    ----------
    pan, tilt : (N,) arrays
        Settings found, degrees (inside the head's range).
    error_px : (N,) array
        Distance of each target's image from the principal point at that setting, pixels
        (inf where the target is behind the camera).
    reachable : (N,) bool array
        ``error_px <= tol_px``; False means the head cannot centre the target (outside its
        range or behind it), or the search stopped at ``max_iter``.
    iterations : (N,) int array
        Search iterations (accepted or rejected moves) per target.
    evaluations : int
        Projections computed in all (for cost comparisons).
    """

    pan: np.ndarray
    tilt: np.ndarray
    error_px: np.ndarray
    reachable: np.ndarray
    iterations: np.ndarray
    evaluations: int

    def __post_init__(self):
        freeze(self, ("pan", "tilt", "error_px", "reachable", "iterations"))

    @property
    def settings(self) -> np.ndarray:
        """``(N, 2)`` pan and tilt, degrees."""
        return np.stack([self.pan, self.tilt], axis=-1)


def _targets_and_start(model, X, current):
    if not isinstance(model, PanTiltCamera):
        raise TypeError(f"model: expected a PanTiltCamera, got {type(model).__name__}")
    X = as_points(X, "X")
    cur = np.asarray(current, dtype=float)
    if cur.shape not in ((2,), (len(X), 2)):
        raise ValueError(f"current: expected (pan, tilt) or an array of shape ({len(X)}, 2), "
                         f"got shape {cur.shape}")
    cur = np.broadcast_to(cur, (len(X), 2)).copy()
    model.check(cur[:, 0], cur[:, 1])
    return X, cur


def _centre_error(model, X, pan, tilt):
    xy = model._project(X, pan, tilt)
    e = np.hypot(xy[:, 0] - model.camera.cx, xy[:, 1] - model.camera.cy)
    return np.where(np.isfinite(e), e, np.inf)


def aim(model: PanTiltCamera, X, *, current=(0.0, 0.0), tol_px: float = 0.5,
        step_deg: float | None = None, min_step_deg: float = 1e-4, max_iter: int = 200) -> Aim:
    """The (pan, tilt) that puts each world point at the principal point, by local search.

    Parameters
    ----------
    model : PanTiltCamera
        The calibrated camera.
    X : (N, 3) array
        Targets, world mm.
    current : (2,) or (N, 2) array
        Setting(s) to start from, degrees (the camera's current setting).
    tol_px : float
        Stop when the target is this close to the principal point, pixels.
    step_deg : float, optional
        First trial step; default: the angle the current image error subtends.
    min_step_deg : float
        Give up (``reachable = False`` unless within ``tol_px``) below this step.
    max_iter : int
        Iteration limit per target.

    Returns
    -------
    Aim
    """
    X, cur = _targets_and_start(model, X, current)
    tol_px = as_scalar(tol_px, "tol_px", positive=True)
    min_step_deg = as_scalar(min_step_deg, "min_step_deg", positive=True)
    as_int(max_iter, "max_iter")
    n = len(X)
    lo = np.array([model.pan_limits[0], model.tilt_limits[0]])
    hi = np.array([model.pan_limits[1], model.tilt_limits[1]])
    err = _centre_error(model, X, cur[:, 0], cur[:, 1])
    evaluations = n
    if step_deg is None:
        step = np.degrees(np.arctan(np.where(np.isfinite(err), err, model.camera.f)
                                    / model.camera.f))
        step = np.clip(step, 10 * min_step_deg, 20.0)
    else:
        step = np.full(n, as_scalar(step_deg, "step_deg", positive=True))
    iters = np.zeros(n, dtype=int)
    active = err > tol_px
    while active.any():
        idx = np.flatnonzero(active)
        cand = cur[idx, None, :] + step[idx, None, None] * _MOVES[None]        # (A, 4, 2)
        cand = np.clip(cand, lo, hi)
        flat = cand.reshape(-1, 2)
        e = _centre_error(model, np.repeat(X[idx], 4, axis=0), flat[:, 0], flat[:, 1])
        evaluations += len(flat)
        e = e.reshape(-1, 4)
        best = np.argmin(e, axis=1)
        e_best = e[np.arange(len(idx)), best]
        better = e_best < err[idx]
        ok = idx[better]
        cur[ok] = cand[better, best[better]]
        err[ok] = e_best[better]
        step[idx[~better]] /= 3.0
        iters[idx] += 1
        active = (err > tol_px) & (step >= min_step_deg) & (iters < max_iter)
    return Aim(pan=cur[:, 0].copy(), tilt=cur[:, 1].copy(), error_px=err, reachable=err <= tol_px,
               iterations=iters, evaluations=evaluations)


def aim_least_squares(model: PanTiltCamera, X, *, current=(0.0, 0.0), tol_px: float = 0.5) -> Aim:
    """The same problem as :func:`aim`, solved per target by ``scipy.optimize.least_squares``
    (trust-region, bounded by the head's range) from ``current``."""
    X, cur = _targets_and_start(model, X, current)
    tol_px = as_scalar(tol_px, "tol_px", positive=True)
    lo = [model.pan_limits[0], model.tilt_limits[0]]
    hi = [model.pan_limits[1], model.tilt_limits[1]]
    centre = np.array([model.camera.cx, model.camera.cy])
    out = np.empty((len(X), 2))
    iters = np.zeros(len(X), dtype=int)
    evaluations = 0
    for i, x in enumerate(X):
        x1 = x[None]

        def fun(s, x1=x1):
            r = model.project(x1, s[0], s[1], behind="nan")[0] - centre
            return np.where(np.isfinite(r), r, 1e4)

        res = least_squares(fun, cur[i], bounds=(lo, hi), method="trf", xtol=1e-10)
        out[i] = res.x
        iters[i] = res.nfev
        evaluations += res.nfev + 2 * res.njev  # a forward-difference Jacobian costs two
    err = _centre_error(model, X, out[:, 0], out[:, 1])
    return Aim(pan=out[:, 0], tilt=out[:, 1], error_px=err, reachable=err <= tol_px,
               iterations=iters, evaluations=evaluations)
