"""Geometrically constrained multi-image matching (Gruen & Baltsavias 1988), batched.

One template patch is matched in all ``K`` search images *jointly*. Besides the grey-value
observation equations of least squares matching in every search image (one affine and
one radiometric transformation per image, :mod:`lsmta.matching.lsm`), the centres of the
matched patches must satisfy the collinearity condition: they are the images of one
object point on the template pixel's viewing ray. With known orientations that point has
a single degree of freedom ``t`` along the ray, and every search position is a function of
it, ``c_k = c_k(t)`` — a point on the epipolar curve of image ``k``. Gruen & Baltsavias
write the condition as weighted observation equations linking the shifts to the object
point's coordinates; we use it strictly (infinite weight), which is their limit case and
what Baltsavias (1991) calls the 1-D search along the epipolar line. So each node gets:

* one ``t`` and its standard deviation from the joint adjustment — a 3-D point with its
  covariance (along the ray) for calibrated cameras, or a disparity for a rectified pair;
* one ``sigma0`` over all images, and each image's own residual (``sigma0_image``): an
  image that sees something else (an occlusion) stands out there;
* the usual quality indicators per image (affine matrix, displacement), so that
  :class:`~lsmta.matching.lsm.LSMThresholds` apply image by image.

Unknowns per node: ``t``, and per search image the shape of ``A`` and the radiometry (13
for an affine pair of search images with linear radiometry, instead of 16 for two
independent matches). The condition removes the shift along the epipolar line's normal,
where a match at an oblique edge or an occlusion border would otherwise slide.

The curves are expanded to second order about the current ``t`` (``c_k(t) = base +
dir (t - t_exp) + quad (t - t_exp)**2``) inside the compiled solver; a converged node whose
model position differs from the exact projection by more than ``1e-3`` px is re-expanded
at its solution and solved again (rectified pairs are exactly linear).

Two geometries:

* :class:`RectifiedPair` — a template and one search image of a rectified pair; ``t`` is
  the disparity in pixels, ``x_search = x_template - t`` (template left) on the same row;
* :class:`CameraGeometry` — calibrated cameras (:class:`~lsmta.camera.Camera`, with their
  distortion), any number of search images; ``t`` is the inverse depth in 1/m of the
  object point in the template camera (``1000 / Z`` with ``Z`` in mm along its axis).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_array
from ..camera import Camera
from ..triangulation import triangulate
from .lsm import (
    LSMParams,
    LSMResult,
    LSMThresholds,
    Status,
    _initial_A,
    _Model,
    _params,
    _precision,
    _solve,
    _spline,
    _State,
    _template_weights,
)
from .spline import SplineImage

#: a converged node whose quadratic curve model is further than this from the exact
#: projection (px) is expanded again at its solution
CURVE_TOL = 1e-3


@dataclass(frozen=True)
class RectifiedPair:
    """A rectified pair: the search image's match of template pixel ``(x, y)`` is
    ``(x - t, y)`` (``template_left=True``) or ``(x + t, y)``; ``t`` is the disparity (px)."""

    template_left: bool = True

    n_search = 1
    parameter_name = "disparity [px]"

    def positions(self, template_xy: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Search positions ``(n, 1, 2)`` of the template points at parameters ``t``."""
        sign = -1.0 if self.template_left else 1.0
        xy = template_xy.astype(float).copy()
        xy[:, 0] += sign * t
        return xy[:, None, :]

    def curves(self, template_xy: np.ndarray, t: np.ndarray):
        """``(base, direction, quad, t_exp)`` of the constraint, expanded about ``t``."""
        base = self.positions(template_xy, t)
        direction = np.zeros_like(base)
        direction[..., 0] = -1.0 if self.template_left else 1.0
        return base, direction, np.zeros_like(base), np.asarray(t, dtype=float).copy()

    def parameter(self, template_xy: np.ndarray, search_xy: np.ndarray) -> np.ndarray:
        """The ``t`` whose positions are nearest to approximations ``search_xy`` (n, 1, 2)."""
        d = template_xy[:, 0] - search_xy[:, 0, 0]
        return d if self.template_left else -d

    def points(self, template_xy, t):
        """No object points without cameras."""
        return None


@dataclass(frozen=True, eq=False)
class CameraGeometry:
    """Calibrated cameras: ``cameras[template]`` took the template, the others (in their
    order) the search images. ``t`` is the object point's inverse depth in 1/m along the
    template camera's axis."""

    cameras: tuple
    template: int = 0

    parameter_name = "inverse depth [1/m]"

    def __post_init__(self):
        cams = tuple(self.cameras)
        if len(cams) < 2 or not all(isinstance(c, Camera) for c in cams):
            raise ValueError("cameras: expected at least 2 lsmta.camera.Camera")
        if not 0 <= self.template < len(cams):
            raise ValueError(f"template: expected an index in [0, {len(cams) - 1}], "
                             f"got {self.template}")
        object.__setattr__(self, "cameras", cams)

    @property
    def n_search(self) -> int:
        return len(self.cameras) - 1

    @property
    def search_cameras(self) -> list:
        return [c for k, c in enumerate(self.cameras) if k != self.template]

    def _rays(self, template_xy):
        cam = self.cameras[self.template]
        o, d = cam.rays(template_xy)
        return o, d / (d @ np.asarray(cam.R)[2])[:, None]    # d: unit depth per step

    def points(self, template_xy: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Object points ``(n, 3)`` (mm) at inverse depths ``t`` (1/m)."""
        o, d = self._rays(template_xy)
        with np.errstate(divide="ignore", invalid="ignore"):
            return o + (1000.0 / np.asarray(t, dtype=float))[:, None] * d

    def positions(self, template_xy: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Search positions ``(n, K, 2)`` (NaN behind a camera)."""
        X = self.points(template_xy, t)
        good = np.isfinite(X).all(axis=1)
        out = np.full((len(X), self.n_search, 2), np.nan)
        for k, cam in enumerate(self.search_cameras):
            out[good, k] = cam.project(X[good], behind="nan")
        return out

    def curves(self, template_xy: np.ndarray, t: np.ndarray, *, step: float = 2e-3):
        """Second-order expansion of the epipolar curves about ``t`` (central differences
        ``t (1 +- step)``)."""
        t = np.asarray(t, dtype=float)
        dt = step * np.abs(t)
        lo, mid, hi = (self.positions(template_xy, t + s * dt) for s in (-1.0, 0.0, 1.0))
        direction = (hi - lo) / (2 * dt)[:, None, None]
        quad = (hi - 2 * mid + lo) / (2 * dt**2)[:, None, None]
        return mid, direction, quad, t.copy()

    def parameter(self, template_xy: np.ndarray, search_xy: np.ndarray) -> np.ndarray:
        """Inverse depth of the point intersected from the template pixel and approximate
        positions ``search_xy`` (n, K, 2) in the search images."""
        K1 = len(self.cameras)
        xy = np.empty((K1, len(template_xy), 2))
        xy[self.template] = template_xy
        xy[[k for k in range(K1) if k != self.template]] = search_xy.transpose(1, 0, 2)
        X = triangulate(list(self.cameras), xy).points
        cam = self.cameras[self.template]
        Z = (X - cam.C) @ np.asarray(cam.R)[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(Z > 0, 1000.0 / Z, np.nan)


@dataclass(frozen=True)
class ConstrainedResult:
    """Geometrically constrained matching of N template points in K search images.

    Attributes
    ----------
    t : (N,) array
        The shared parameter: disparity (px, :class:`RectifiedPair`) or inverse depth
        (1/m, :class:`CameraGeometry`).
    sigma_t : (N,) array
        Its standard deviation from the joint adjustment.
    xy : (K, N, 2) array
        Matched positions in every search image (on the epipolar curves).
    A : (K, N, 2, 2) array
        Affine matrices per search image.
    radiometry : (K, N, 2) array
        ``[r0, r1]`` per search image (``f = r0 + r1 g``).
    sigma0 : (N,) array
        A-posteriori standard deviation of unit weight over all images (template grey levels).
    sigma0_image : (K, N) array
        Each image's own residual standard deviation (a quality indicator: an occluded or
        mismatched image has a larger one).
    sigma_xy : (K, N, 2) array
        Standard deviations of the positions (along the curve, from ``sigma_t``).
    points : (N, 3) array or None
        Object points (mm) with :class:`CameraGeometry`.
    cov_points : (N, 3, 3) array or None
        Their covariance (mm², rank one: along the template ray).
    iterations : (N,) int array
    displacement : (K, N) array
        Distance of each position from its approximation, pixels.
    status : (N,) int array
        :class:`~lsmta.matching.lsm.Status` codes (thresholds applied image by image).
    weight_share : (N,) array
        As in :class:`~lsmta.matching.lsm.LSMResult`, over all images.
    fixed : (N, k) bool array
        Joint unknowns ``[t, then per image shape and radiometry]`` fixed by the adaptive
        control.
    """

    t: np.ndarray
    sigma_t: np.ndarray
    xy: np.ndarray
    A: np.ndarray
    radiometry: np.ndarray
    sigma0: np.ndarray
    sigma0_image: np.ndarray
    sigma_xy: np.ndarray
    points: np.ndarray | None
    cov_points: np.ndarray | None
    iterations: np.ndarray
    displacement: np.ndarray
    status: np.ndarray
    weight_share: np.ndarray
    fixed: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        return self.status == Status.CONVERGED

    def __len__(self) -> int:
        return len(self.t)

    def image(self, k: int) -> LSMResult:
        """Search image ``k``'s view as an :class:`~lsmta.matching.lsm.LSMResult` (joint
        ``sigma0``, status and weight share; its own position, ``A`` and radiometry)."""
        n = len(self.t)
        params = np.concatenate([self.xy[k], self.A[k].reshape(n, 4), self.radiometry[k]],
                                axis=1)
        fixed8 = np.zeros((n, 8), dtype=bool)
        fixed8[:, :2] = self.fixed[:, :1]
        cov = self.sigma_xy[k][:, :, None] * self.sigma_xy[k][:, None, :]
        return LSMResult(xy=self.xy[k], params=params, fixed=fixed8, sigma0=self.sigma0,
                         sigma_xy=self.sigma_xy[k], cov_xy=cov, iterations=self.iterations,
                         displacement=self.displacement[k], status=self.status,
                         weight_share=self.weight_share)


def _check_constraint(constraint):
    if not isinstance(constraint, (RectifiedPair, CameraGeometry)):
        raise ValueError(f"constraint: expected a RectifiedPair or CameraGeometry, got "
                         f"{type(constraint).__name__}")


def _search_list(searches, K: int) -> list:
    if isinstance(searches, SplineImage) or (isinstance(searches, np.ndarray)
                                             and searches.ndim == 2):
        searches = [searches]
    searches = list(searches)
    if len(searches) != K:
        raise ValueError(f"searches: expected {K} search image(s) for this constraint, "
                         f"got {len(searches)}")
    return [_spline(s, f"searches[{k}]") for k, s in enumerate(searches)]


def mpgc(template, searches, template_xy, t0, constraint, *, initial_A=None, template_mask=None,
         params: LSMParams | None = None) -> ConstrainedResult:
    """Match N template points in K search images jointly under the epipolar condition.

    Parameters
    ----------
    template : (H, W) array or SplineImage
    searches : sequence of K (H, W) arrays or SplineImages (one array for a pair)
        All of one size.
    template_xy : (N, 2) array
        Patch centres in the template (pixels).
    t0 : (N,) array
        Approximate parameters (disparity or inverse depth, see the constraint); e.g. from
        ``constraint.parameter(template_xy, approximate_search_xy)``.
    constraint : RectifiedPair or CameraGeometry
    initial_A : (N, K, 2, 2), (N, 2, 2) or (2, 2) array, optional
        Starting affine matrices (default identity).
    template_mask : (H, W) bool array, optional
        As in :func:`~lsmta.matching.lsm`.
    params : LSMParams, optional
        The model of :func:`~lsmta.matching.lsm`, the same in every search image. A node
        moving further than ``max_displacement`` (in any image) from its approximation has
        diverged; ``thresholds`` apply to every search image's view, and a node must pass
        in all of them.

    Returns
    -------
    ConstrainedResult
    """
    _check_constraint(constraint)
    p = _params(params, LSMParams)
    model = _Model.of(p)
    K = constraint.n_search
    f_img = _spline(template, "template")
    g_imgs = _search_list(searches, K)
    t_xy = as_array(template_xy, "template_xy", shape=(None, 2))
    n = len(t_xy)
    t_start = as_array(t0, "t0", shape=(n,), finite=False)
    A0 = _initial_A_joint(initial_A, n, K)
    weights = _template_weights(template_mask, f_img)

    c0 = constraint.positions(t_xy, t_start)
    state = _State.initial(model, f_img, t_xy, np.nan_to_num(c0, nan=-1e6), A0,
                         curves=(t_start, *constraint.curves(t_xy, t_start)))
    state.status[~(np.isfinite(t_start) & np.isfinite(c0).all(axis=(1, 2)))] = Status.OUTSIDE
    _solve(state, model, f_img, g_imgs, weights)
    _refine_curves(state, model, constraint, f_img, g_imgs, weights, c0)
    result = _constrained_result(state, model, constraint, c0)
    return _apply(p.thresholds, result) if p.thresholds is not None else result


def _initial_A_joint(initial_A, n: int, K: int) -> np.ndarray:
    if initial_A is not None and np.ndim(initial_A) == 4:
        A0 = as_array(initial_A, "initial_A", shape=(n, K, 2, 2))
        return A0.copy()
    return np.repeat(_initial_A(initial_A, n)[:, None], K, axis=1)


def _refine_curves(state, model: _Model, constraint, f_img, g_imgs, weights, c0,
                   rounds: int = 3) -> None:
    """Re-expand the curves of converged nodes whose quadratic model is off the exact
    projection, and solve those again from their solution (keeping their radiometry)."""
    if isinstance(constraint, RectifiedPair):
        return
    for _ in range(rounds):
        exact = constraint.positions(state.t_xy, state.t)
        off = np.abs(exact - state.c).max(axis=(1, 2))
        again = (state.status == Status.CONVERGED) & ~(off <= CURVE_TOL)
        if not again.any():
            return
        state.status[again] = Status.MAX_ITERATIONS
        base, direction, quad, t_exp = constraint.curves(state.t_xy[again], state.t[again])
        state.base[again], state.direction[again] = base, direction
        state.quad[again], state.t_exp[again] = quad, t_exp
        state.c[again] = base
        _solve(state, model, f_img, g_imgs, weights, active=again, start_radiometry=False)
        # the displacement test is against the original approximation
        far = np.linalg.norm(state.c - c0, axis=2).max(axis=1) > model.max_disp
        state.status[again & far] = Status.DIVERGED


def _constrained_result(state: _State, model, constraint, c0) -> ConstrainedResult:
    n, K = state.c.shape[:2]
    sigma0, cov = _precision(state)
    var_t = cov[:, 0, 0]
    # each image's share of the weights and of the unknowns
    dof = np.maximum((state.sw_last - (~state.fixed).sum(axis=1)) / K, 1.0)
    with np.errstate(invalid="ignore"):
        sigma_t = np.sqrt(var_t)
        sigma0_image = np.sqrt(state.ee_img / dof[:, None]).T
    tangent = np.stack([state.direction[..., j] + 2 * state.quad[..., j]
                        * (state.t - state.t_exp)[:, None] for j in (0, 1)], axis=-1)
    sigma_xy = np.abs(tangent) * sigma_t[:, None, None]
    points = constraint.points(state.t_xy, state.t)
    cov_points = None
    if points is not None:
        _, d = constraint._rays(state.t_xy)
        with np.errstate(divide="ignore", invalid="ignore"):
            dX = -1000.0 / state.t[:, None] ** 2 * d          # dX / dt
        cov_points = dX[:, :, None] * dX[:, None, :] * var_t[:, None, None]
    failed = state.status == Status.OUTSIDE
    disp = np.where(failed[:, None], np.nan, np.linalg.norm(state.c - c0, axis=2))
    return ConstrainedResult(
        t=state.t, sigma_t=sigma_t, xy=state.c.transpose(1, 0, 2).copy(),
        A=state.A.transpose(1, 0, 2, 3).copy(),
        radiometry=np.stack([state.r0, state.r1], axis=-1).transpose(1, 0, 2).copy(),
        sigma0=sigma0, sigma0_image=sigma0_image, sigma_xy=sigma_xy.transpose(1, 0, 2).copy(),
        points=points, cov_points=cov_points, iterations=state.iterations,
        displacement=disp.T.copy(), status=state.status,
        weight_share=state.sw_last / (K * model.patch**2), fixed=state.fixed)


def _apply(thresholds: LSMThresholds, result: ConstrainedResult) -> ConstrainedResult:
    accept = np.ones(len(result), dtype=bool)
    for k in range(result.xy.shape[0]):
        accept &= thresholds.accept(result.image(k))
    status = result.status.copy()
    status[result.ok & ~accept] = Status.REJECTED
    return replace(result, status=status)


def _rectified_once(f_img: SplineImage, g_img: SplineImage, t_xy, t0, A0, weights,
                    model: _Model, thresholds: LSMThresholds | None,
                    constraint: RectifiedPair) -> tuple:
    """:func:`mpgc` of a :class:`RectifiedPair` as the growth calls it in every step
    (:meth:`lsmta.matching.grow._Matcher.once`), without building a
    :class:`ConstrainedResult`: the same state, solver call and formulas, with the thresholds'
    tests computed once.

    Parameters
    ----------
    f_img, g_img : SplineImage
    t_xy : (n, 2) float array
    t0 : (n,) array
        Starting disparities, px.
    A0 : (n, 1, 2, 2) array
    weights : array
        :func:`~lsmta.matching.lsm._template_weights`.
    model : _Model
    thresholds : LSMThresholds or None
    constraint : RectifiedPair

    Returns
    -------
    tuple
        ``(status (n,), c (n, 1, 2), A (n, 1, 2, 2), t (n,), sigma_t (n,), sigma0 (n,),
        sigma_xy (n, 1, 2), failures)``: the status with the thresholds applied (REJECTED),
        and their failures ``(len(THRESHOLD_TESTS), n)`` bool (None without thresholds).
    """
    t_start = np.asarray(t0, dtype=float)
    c0 = constraint.positions(t_xy, t_start)
    direction = np.zeros_like(c0)       # constraint.curves(t_xy, t_start), c0 its base
    direction[..., 0] = -1.0 if constraint.template_left else 1.0
    curves = (c0.copy(), direction, np.zeros_like(c0), t_start.copy())
    finite = np.isfinite(c0).all(axis=(1, 2))
    start = c0 if finite.all() else np.nan_to_num(c0, nan=-1e6)
    state = _State.initial(model, f_img, t_xy, start, np.array(A0, dtype=float),
                           curves=(t_start, *curves))
    state.status[~(np.isfinite(t_start) & finite)] = Status.OUTSIDE.value
    _solve(state, model, f_img, [g_img], weights)
    # _constrained_result's formulas, one search image
    sigma0, cov = _precision(state)
    with np.errstate(invalid="ignore"):
        sigma_t = np.sqrt(cov[:, 0, 0])
    tangent = np.stack([state.direction[..., j] + 2 * state.quad[..., j]
                        * (state.t - state.t_exp)[:, None] for j in (0, 1)], axis=-1)
    sigma_xy = np.abs(tangent) * sigma_t[:, None, None]
    status = state.status
    fails = None
    if thresholds is not None:
        disp = np.where((status == Status.OUTSIDE.value)[:, None], np.nan,
                        np.linalg.norm(state.c - c0, axis=2))
        fails = thresholds._failures(state.A[:, 0], sigma0, sigma_xy[:, 0], disp[:, 0],
                                     state.sw_last / model.patch**2)
        status = status.copy()
        status[(status == Status.CONVERGED.value) & fails.any(axis=0)] = Status.REJECTED.value
    return status, state.c, state.A, state.t, sigma_t, sigma0, sigma_xy, fails
