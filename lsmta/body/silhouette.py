"""The silhouette term: lines of sight through the observed contour touch the skin.

Our form of the silhouette observation of Plänkers et al.'s earlier work (their ref. [5]):
a point on a camera's observed contour defines a line of sight ``x(l) = o + l d``; if the
contour belongs to the model, that line grazes the model's skin. The residual is the
line's closest approach to the skin,

    ``r = min_l D(o + l d)``,  ``D(x) = min_s D_s(x)``

with ``D_s`` the signed skin distance of segment ``s`` (mm, :meth:`MetaballModel.distance`):
zero for a tangent line, positive when the line misses the model (the model's outline lies
inside the contour there), negative when it passes through it. The minimum over ``l`` is
found on a grid of depths and refined by golden-section search on the nearest segment.

Its derivative needs no derivative of the minimiser (envelope theorem): at the minimum
``dD/dl = 0``, so ``dr/dtheta = dD_s/dtheta`` at the fixed world point ``x*``; moving the
segment by ``dX/dtheta`` (a point carried by the segment, :meth:`Skeleton.jacobian`) is
moving ``x*`` the other way in the segment's frame: ``dr/dtheta = -grad_x D_s(x*) . dX/dtheta``.
The same holds for a 3-D point's skin distance, so :func:`fit_pose` fits joint angles to
points, lines of sight, or both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .._validate import as_array, as_int, as_scalar, freeze
from ._kernels import closest_approach, segment_terms
from .metaballs import _ROOT_T, MetaballModel, _radii

_GOLD = (np.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True, eq=False)
class SilhouetteTerms:
    """Residuals of lines of sight and their derivatives.

    Attributes
    ----------
    r : (N,) array
        Closest approach of each line to the skin (mm; negative: through the model).
    d_angles : (N, J) array
        ``dr / dtheta`` (mm per radian).
    d_translation : (N, 3) array
        ``dr / dt`` for a translation ``t`` of the whole model (dimensionless).
    closest : (N, 3) array
        The point of closest approach (world mm).
    segment : (N,) int array
        The segment the line comes closest to.
    """

    r: np.ndarray
    d_angles: np.ndarray
    d_translation: np.ndarray
    closest: np.ndarray
    segment: np.ndarray

    def __post_init__(self):
        freeze(self, ("r", "d_angles", "d_translation", "closest", "segment"))


def silhouette_terms(model: MetaballModel, origins, directions, angles, scales, radii, *,
                     near: float, far: float, base=None, n_steps: int = 64,
                     n_refine: int = 40) -> SilhouetteTerms:
    """The silhouette residual of each line of sight and its derivative by the joint angles.

    Parameters
    ----------
    model : MetaballModel
    origins, directions : (N, 3) arrays
        Lines of sight through the observed contour points (e.g. ``Camera.rays``), mm and
        unit vectors.
    angles : (1, J) array
        Joint angles of the one frame (radians).
    scales : (L,) array; radii : (S, 3, 3) array (mm); base : (1, 4, 4) array, optional
    near, far : float
        Depth range searched along every line (mm from its origin), e.g. the person's
        distance from the camera plus or minus a metre.
    n_steps : int
        Depth grid; n_refine : int, golden-section steps.

    Returns
    -------
    SilhouetteTerms
    """
    origins = as_array(origins, "origins", shape=(None, 3))
    directions = as_array(directions, "directions", shape=origins.shape)
    angles = as_array(angles, "angles", shape=(1, model.skeleton.n_joints))
    radii = _radii(radii, shape=(model.n_segments, 3, 3))
    near, far = as_scalar(near, "near", nonnegative=True), as_scalar(far, "far", positive=True)
    if not far > near:
        raise ValueError(f"far: expected a depth beyond near = {near}, got {far}")
    as_int(n_steps, "n_steps", minimum=3)
    as_int(n_refine, "n_refine")
    depths = np.linspace(near, far, int(n_steps))
    F = model.frames(angles, scales, base=base)[0]
    C = model.centres(scales)
    # the depth grid's minimum over every segment, then golden-section search on the nearest
    segment, closest = closest_approach(origins, directions, depths, F, C, radii, _ROOT_T,
                                        int(n_refine), _GOLD)
    r, d_th, d_t = point_terms(model, closest, segment, angles, scales, radii, base=base,
                               _frames=(F, C))
    return SilhouetteTerms(r=r, d_angles=d_th, d_translation=d_t, closest=closest,
                           segment=segment)


def point_terms(model: MetaballModel, x, segment, angles, scales, radii, *, base=None,
                _frames=None):
    """Skin distances of world points on their segments and their derivatives
    (:func:`point_derivatives`), in one compiled pass.

    Parameters
    ----------
    model : MetaballModel
    x : (N, 3) array
        World points, mm (NaN allowed: it propagates).
    segment : (N,) int array
        Each point's segment, in ``[0, model.n_segments)``.
    angles : (1, J) array; scales : (L,); radii : (S, 3, 3), mm; base : (1, 4, 4), optional
    _frames : (F, C), optional
        The one frame's bone frames and ball centres when the caller has them.

    Returns
    -------
    r : (N,) array
        Signed skin distances, mm.
    d_angles : (N, J) array
        mm per radian.
    d_translation : (N, 3) array
    """
    x = as_array(x, "x", shape=(None, 3), allow_nan=True)
    segment = MetaballModel._indices(segment, "segment", len(x), model.n_segments)
    radii = _radii(radii, "radii", shape=(model.n_segments, 3, 3))
    W = model.skeleton.transforms(angles, scales, base=base)[0]
    if _frames is None:
        R, joint = model._arrays[:2]
        F, C = W[joint] @ R, model.centres(scales)
    else:
        F, C = _frames
    return segment_terms(np.ascontiguousarray(x, float), segment.astype(np.int64), F, C,
                         np.ascontiguousarray(radii, float), W, model.skeleton.arrays[4],
                         model._arrays[1], _ROOT_T)


def point_derivatives(model: MetaballModel, x, segment, angles, scales, radii, *, base=None):
    """Derivatives of the skin distance of world points ``x (N, 3)`` (mm) on segments
    ``(N,)`` held fixed while the model moves: by the joint angles, ``-grad_x D_s(x) .
    dX/dtheta`` ``(N, J)`` (mm per radian), and by a translation of the whole model,
    ``-grad_x D_s(x)`` ``(N, 3)``; ``angles (1, J)``, ``base (1, 4, 4)``."""
    _, d_th, d_t = point_terms(model, x, segment, angles, scales, radii, base=base)
    return d_th, d_t


@dataclass(frozen=True)
class PoseFitParams:
    """Settings of :func:`fit_pose`.

    Attributes
    ----------
    sigma_point : float
        A-priori standard deviation of a 3-D point's skin distance (mm).
    sigma_silhouette : float
        A-priori standard deviation of a line of sight's closest approach (mm).
    loss : str
        ``scipy.optimize.least_squares`` loss on the weighted residuals ("linear" for plain
        least squares; "soft_l1", "huber", "cauchy" are robust).
    outlier_k : float
        A weighted residual above ``outlier_k`` at the solution counts as an outlier.
    near, far : float
        Depth range searched along the lines of sight (mm).
    n_steps : int
        Depth grid of :func:`silhouette_terms` (its step must be finer than the thinnest
        part, or a line through it is missed).
    max_nfev : int
        Function evaluations of the solver per round.
    n_rounds : int
        Rounds of segmentation (points to their nearest segment) and solve.
    gate : float
        A line of sight takes part in a round only when its closest approach at the
        round's start is within ``gate`` mm of the skin (its contour point is near the
        model's outline: the association of contour points with the model).
    """

    sigma_point: float = 2.0
    sigma_silhouette: float = 2.0
    loss: str = "soft_l1"
    outlier_k: float = 3.0
    near: float = 0.0
    far: float = 10000.0
    n_steps: int = 160
    max_nfev: int = 100
    n_rounds: int = 3
    gate: float = 30.0

    def __post_init__(self):
        as_int(self.n_rounds, "n_rounds")
        for name in ("sigma_point", "sigma_silhouette", "outlier_k", "far", "gate"):
            as_scalar(getattr(self, name), name, positive=True)
        as_scalar(self.near, "near", nonnegative=True)
        if self.loss not in ("linear", "soft_l1", "huber", "cauchy", "arctan"):
            raise ValueError(f"loss: expected a least_squares loss name, got {self.loss!r}")
        as_int(self.n_steps, "n_steps", minimum=3)
        as_int(self.max_nfev, "max_nfev")


@dataclass(frozen=True, eq=False)
class PoseFit:
    """Result of :func:`fit_pose`.

    Attributes
    ----------
    angles : (1, J) array
        Fitted joint angles (radians).
    point_residuals : (N,) array
        Skin distances of the points at the solution (mm).
    silhouette_residuals : (M,) array
        Closest approaches of all the lines of sight at the solution (mm).
    used : (M,) bool array
        The lines inside the gate in the last round.
    n_point_outliers, n_silhouette_outliers : int
        Residuals above ``outlier_k`` standard deviations (lines outside the gate count).
    nfev : int
    """

    angles: np.ndarray
    point_residuals: np.ndarray
    silhouette_residuals: np.ndarray
    used: np.ndarray
    n_point_outliers: int
    n_silhouette_outliers: int
    nfev: int

    def __post_init__(self):
        freeze(self, ("angles", "point_residuals", "silhouette_residuals", "used"))


def fit_pose(model: MetaballModel, angles, scales, radii, *, points=None, rays=None, base=None,
             free=None, params: PoseFitParams | None = None) -> PoseFit:
    """Joint angles of one frame from 3-D points and/or silhouette lines of sight.

    Robust weighted least squares (``scipy.optimize.least_squares``, analytic Jacobian) in
    ``n_rounds`` rounds: each round assigns the points to their nearest segment and keeps
    the lines of sight whose closest approach lies within ``gate`` of the skin, then
    solves for each point's skin distance divided by ``sigma_point`` and each kept line's
    closest approach (:func:`silhouette_terms`) divided by ``sigma_silhouette``. The shape
    (``scales``, ``radii``) is held.

    Parameters
    ----------
    model : MetaballModel
    angles : (1, J) array
        Start (radians).
    scales : (L,) array; radii : (S, 3, 3) array (mm); base : (1, 4, 4) array, optional
    points : (N, 3) array, optional
        3-D points on the skin (world mm).
    rays : (origins (M, 3), directions (M, 3)), optional
        Lines of sight through observed contour points.
    free : (J,) bool array, optional
        Angles the fit may change (default all).
    params : PoseFitParams, optional
    """
    p = PoseFitParams() if params is None else params
    if not isinstance(p, PoseFitParams):
        raise TypeError(f"params: expected PoseFitParams, got {type(p).__name__}")
    J = model.skeleton.n_joints
    start = as_array(angles, "angles", shape=(1, J))
    pts = np.zeros((0, 3)) if points is None else as_array(points, "points", shape=(None, 3))
    if rays is None:
        origins = directions = np.zeros((0, 3))
    else:
        origins = as_array(rays[0], "rays[0]", shape=(None, 3))
        directions = as_array(rays[1], "rays[1]", shape=origins.shape)
    if len(pts) + len(origins) < 1:
        raise ValueError("points, rays: expected at least one observation")
    mask = np.ones(J, bool) if free is None else np.asarray(free, bool)
    if mask.shape != (J,) or not mask.any():
        raise ValueError(f"free: expected ({J},) bools with at least one True")
    current, nfev = start.copy(), 0
    for _ in range(int(p.n_rounds)):
        seg = (np.argmin(model.all_distances(pts, current, scales, radii, base=base), axis=1)
               if len(pts) else np.zeros(0, int))
        near_outline = np.ones(len(origins), bool)
        if len(origins):
            r0 = silhouette_terms(model, origins, directions, current, scales, radii,
                                  near=p.near, far=p.far, base=base, n_steps=p.n_steps).r
            near_outline = np.abs(r0) <= p.gate
        solve = _Residuals(model, current, mask, seg, pts, origins[near_outline],
                           directions[near_outline], scales, radii, base, p)
        sol = least_squares(solve.r, current[0, mask], jac=solve.jac, loss=p.loss,
                            max_nfev=int(p.max_nfev), x_scale="jac")
        current = solve.angles(sol.x)
        nfev += int(sol.nfev)
    r_p = solve.terms(current[0, mask])[2]
    r_s = (silhouette_terms(model, origins, directions, current, scales, radii, near=p.near,
                            far=p.far, base=base, n_steps=p.n_steps).r
           if len(origins) else np.zeros(0))
    out = current
    return PoseFit(angles=out, point_residuals=r_p, silhouette_residuals=r_s, used=near_outline,
                   n_point_outliers=int((np.abs(r_p) > p.outlier_k * p.sigma_point).sum()),
                   n_silhouette_outliers=int((np.abs(r_s) > p.outlier_k * p.sigma_silhouette)
                                             .sum()),
                   nfev=nfev)


class _Residuals:
    """Weighted residuals and Jacobian of one round of :func:`fit_pose` (last one cached)."""

    def __init__(self, model, start, mask, seg, pts, origins, directions, scales, radii, base,
                 params):
        self.model, self.start, self.mask, self.seg = model, start, mask, seg
        self.pts, self.origins, self.directions = pts, origins, directions
        self.scales, self.radii, self.base, self.p = scales, radii, base, params
        self._key, self._value = None, None

    def angles(self, x) -> np.ndarray:
        a = self.start.copy()
        a[0, self.mask] = x
        return a

    def terms(self, x):
        if self._key == x.tobytes():
            return self._value
        m, p, a = self.model, self.p, self.angles(x)
        J = m.skeleton.n_joints
        r_p, j_p = np.zeros(0), np.zeros((0, J))
        if len(self.pts):
            r_p, j_p, _ = point_terms(m, self.pts, self.seg, a, self.scales, self.radii,
                                      base=self.base)
        r_s, j_s = np.zeros(0), np.zeros((0, J))
        if len(self.origins):
            s = silhouette_terms(m, self.origins, self.directions, a, self.scales, self.radii,
                                 near=p.near, far=p.far, base=self.base, n_steps=p.n_steps)
            r_s, j_s = s.r, s.d_angles
        r = np.concatenate([r_p / p.sigma_point, r_s / p.sigma_silhouette])
        jac = np.vstack([j_p / p.sigma_point, j_s / p.sigma_silhouette])[:, self.mask]
        self._key, self._value = x.tobytes(), (r, jac, r_p, r_s)
        return self._value

    def r(self, x):
        return self.terms(x)[0]

    def jac(self, x):
        return self.terms(x)[1]
