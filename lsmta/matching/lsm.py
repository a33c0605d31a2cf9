"""Adaptive least squares matching (Gruen 1985), batched over points.

Model
-----
A square template patch of ``patch x patch`` pixels around ``template_xy`` is related to
the search image by a geometric and a radiometric transformation::

    f(u) = r0 + r1 * g(c + A u) + e(u)

``f`` is the template, ``g`` the search image (cubic B-spline interpolant), ``u`` the
offset of a patch pixel from the patch centre (pixels, x then y), ``c`` the matched
position in the search image, ``A`` a 2 x 2 matrix, ``r0, r1`` offset and gain, ``e``
noise. ``geometry`` chooses what ``A`` may do: ``"shift"`` (A fixed at its start value,
2 parameters), ``"similarity"`` (rotation and scale, 4), ``"affine"`` (6), or
``"row-affine"`` (4: only the first row of ``A`` moves, every patch row stays a row — the
exact model between the images of a rectified pair); ``radiometry``
chooses ``"none"`` (r0 = 0, r1 = 1), ``"offset"`` (r0) or ``"linear"`` (r0 and r1).

The parameters are estimated by Gauss-Newton iterations on the linearised observation
equations, with the exact gradients of the spline interpolant of ``g`` at the warped
positions (the gradient of the resampled search patch, without finite differences). All
iterations of all points run in one compiled call (numba, ``_solver.py``), in parallel
over points.

Inverse compositional iterations (``method="inverse"``, beyond the paper)
--------------------------------------------------------------------------
Baker & Matthews (2001) solve for an increment of a warp of the *template*,
``f(u + dc + dA u) = r0 + r1 g(c + A u) + e``, and compose it with the current warp by its
inverse: ``A <- A (I + dA)^-1``, ``c <- c - A dc``. The geometric columns of the design
matrix are then the template's gradients, the same in every iteration, so an iteration
samples only the search image's grey values and updates only the gain's column of the
normal matrix. It is about three times faster than the forward iterations and
statistically as good (``experiments/lsm_benchmark.py`` compares both with the
Cramér-Rao bound). The radiometric parameters and ``sigma0`` keep their forward meaning;
the adaptive control works on the template's normal matrix, and a fixed parameter there
means "no increment in that direction of the template's warp".

Adaptive parameter control
--------------------------
Before each step the normal matrix of every point is scaled to unit diagonal; a
parameter whose variance inflation factor ``(C^-1)_ii`` exceeds ``max_vif`` (the patch
cannot tell it apart from the others, e.g. a shift along an edge, or scale in a patch of
parallel stripes) is fixed at its current value, worst first, until the rest is well
determined. The test runs on the first iteration's normal matrix; a fixed parameter stays at its
start value. ``LSMResult.fixed`` says which were fixed.

Precision
---------
From the normal equations of the last iteration, ``sigma0**2 = e^T e / (n - u)``
(``n`` pixels, ``u`` free parameters) and the covariance of the parameters is
``sigma0**2 (J^T J)^-1``; ``cov_xy`` and ``sigma_xy`` are its position block. This is the
classical a-posteriori estimate. It treats the search image as exact and charges all noise
to the template; with noise in both images ``sigma0`` counts both, so the estimate stays
close to the truth (the notebook checks how close).

Robust matching (beyond the paper)
----------------------------------
With ``robust=c`` the normal equations weight every patch pixel by the Tukey biweight of
its current residual, ``(1 - (e / c)^2)^2`` for ``|e| < c`` and 0 beyond (iteratively
reweighted least squares). Pixels that the model cannot fit — the part of a patch that
lies across an occlusion border, or a specular highlight — then drop out instead of
dragging the match. The cut-off starts at ``4 c`` and falls to ``c`` over the first
iterations, so that the start, still misaligned by a fraction of a pixel, is not cut
away; a point is not declared converged before the cut-off has reached ``c``.
``sigma0`` and the covariance are then the weighted ones,
``sigma0**2 = e^T W e / (trace W - u)``, and ``weight_share = trace W / n`` says how much
of the patch the match rests on. On clean patches with ``c`` about 4.7 times the residual
standard deviation, this ``sigma0`` comes out about 9 % below the plain one and
``weight_share`` about 0.92; a ``max_sigma0`` threshold is correspondingly a little
easier to pass.

Parameter vector (``LSMResult.params``), always 8 columns whatever the model:
``[x, y, a11, a12, a21, a22, r0, r1]`` — ``(x, y) = c`` and ``A = [[a11, a12], [a21, a22]]``.
"""

from __future__ import annotations

import enum
import functools
import numbers
from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_array, as_int, as_point_pairs, check_patch
from . import _solver
from .spline import PAD, SplineImage

PARAM_NAMES = ("x", "y", "a11", "a12", "a21", "a22", "r0", "r1")
GEOMETRIES = {"shift": 2, "similarity": 4, "affine": 6, "row-affine": 4}
RADIOMETRIES = {"none": 0, "offset": 1, "linear": 2}


class Status(enum.IntEnum):
    """Outcome of matching one point.

    Array code compares and fills with ``Status.X.value`` (a plain int): numpy converts an
    IntEnum member 1 to 2 us more slowly, thousands of times per tracked video.
    """

    CONVERGED = 0       #: the update fell below ``tol``
    MAX_ITERATIONS = 1  #: still moving after ``max_iter`` iterations (or stopped by ``stall``)
    DIVERGED = 2        #: moved further than ``max_displacement`` or ``A`` degenerated
    OUTSIDE = 3         #: the patch left the search image (or did not fit the template)
    SINGULAR = 4        #: too few determinable parameters (no texture)
    REJECTED = 5        #: converged, but rejected by quality thresholds


@dataclass(frozen=True)
class LSMResult:
    """Least squares matching of N points (see the module docstring for the model).

    Attributes
    ----------
    xy : (N, 2) array
        Matched positions in the search image (pixels).
    params : (N, 8) array
        ``[x, y, a11, a12, a21, a22, r0, r1]``.
    fixed : (N, 8) bool array
        Parameters fixed by the adaptive control (the model's own constant parameters are
        not marked).
    sigma0 : (N,) array
        A-posteriori standard deviation of unit weight, in grey levels.
    sigma_xy : (N, 2) array
        Standard deviations of ``xy`` in pixels (NaN for a fixed coordinate).
    cov_xy : (N, 2, 2) array
        Covariance of ``xy`` in px² (the fixed coordinate's row and column are zero).
    iterations : (N,) int array
    displacement : (N,) array
        Distance of ``xy`` from the approximation, pixels.
    status : (N,) int array
        :class:`Status` codes.
    weight_share : (N,) array
        Sum of the pixel weights over the number of patch pixels: 1 without ``robust`` and
        ``template_mask``. With ``robust`` about 0.92 on a clean patch (Tukey weights of
        inliers are below 1) and lower where part of the patch drops out; with
        ``template_mask`` at most the patch's share of object pixels.
    """

    xy: np.ndarray
    params: np.ndarray
    fixed: np.ndarray
    sigma0: np.ndarray
    sigma_xy: np.ndarray
    cov_xy: np.ndarray
    iterations: np.ndarray
    displacement: np.ndarray
    status: np.ndarray
    weight_share: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        """``status == CONVERGED``."""
        return self.status == Status.CONVERGED.value

    @property
    def A(self) -> np.ndarray:
        """``(N, 2, 2)`` affine matrices."""
        return self.params[:, 2:6].reshape(-1, 2, 2)

    def __len__(self) -> int:
        return len(self.xy)


#: the tests of :class:`LSMThresholds`, in the order :meth:`LSMThresholds.failures` names them
THRESHOLD_TESTS = ("sigma0", "sigma_xy", "displacement", "scale", "shear", "weight_share")


@dataclass(frozen=True)
class LSMThresholds:
    """Quality indicators of the LSMTA paper, as thresholds for accepting a match.

    Attributes
    ----------
    max_sigma0 : float
        Largest a-posteriori standard deviation of unit weight (grey levels).
    max_sigma_xy : float
        Largest standard deviation of either coordinate of the position (pixels).
    max_displacement : float
        Largest distance from the approximation (pixels).
    scale_range : (float, float)
        Accepted range of both singular values of ``A``.
    max_shear : float
        Largest ``|cos|`` of the angle between the columns of ``A``.
    min_weight_share : float
        Smallest :attr:`LSMResult.weight_share` accepted: a robust or masked match must
        rest on this share of its patch (always passed without ``robust`` and
        ``template_mask``).
    """

    max_sigma0: float = 20.0
    max_sigma_xy: float = 0.1
    max_displacement: float = 3.0
    scale_range: tuple = (0.7, 1.4)
    max_shear: float = 0.3
    min_weight_share: float = 0.5

    def failures(self, result: LSMResult) -> dict:
        """Which test each match fails: ``{name: (N,) bool}`` for the names of
        :data:`THRESHOLD_TESTS`, in that order (True: fails it; NaN fails). One compiled
        pass over the matches (:func:`lsmta.matching._solver.threshold_failures`)."""
        return dict(zip(THRESHOLD_TESTS, self._failures(
            result.A, result.sigma0, result.sigma_xy, result.displacement,
            result.weight_share)))

    def _failures(self, A, sigma0, sigma_xy, displacement, weight_share) -> np.ndarray:
        """:meth:`failures` from the arrays ((n, 2, 2), (n,), (n, 2), (n,), (n,)), as a
        (len(THRESHOLD_TESTS), n) bool array."""
        n = len(sigma0)
        out = np.empty((len(THRESHOLD_TESTS), n), bool)
        limits = np.array([self.max_sigma0, self.max_sigma_xy, self.max_displacement,
                           self.scale_range[0], self.scale_range[1], self.max_shear,
                           self.min_weight_share], float)
        _solver.threshold_failures(
            np.ascontiguousarray(A, float).reshape(n, 2, 2),
            np.asarray(sigma0, float), np.asarray(sigma_xy, float).reshape(n, 2),
            np.asarray(displacement, float), np.asarray(weight_share, float), limits, out)
        return out

    def accept(self, result: LSMResult) -> np.ndarray:
        """Boolean ``(N,)``: converged and passing every threshold."""
        return result.ok & ~np.any(list(self.failures(result).values()), axis=0)

    def apply(self, result: LSMResult) -> LSMResult:
        """A copy of ``result`` whose converged matches failing a threshold are REJECTED."""
        status = result.status.copy()
        status[result.ok & ~self.accept(result)] = Status.REJECTED.value
        return replace(result, status=status)


def _positive(value, *, allow_inf: bool = False) -> bool:
    """A real number > 0 (``bool`` refused), finite unless ``allow_inf``."""
    return (not isinstance(value, bool) and isinstance(value, numbers.Real)
            and (allow_inf or np.isfinite(value)) and value > 0)


def _check_robust(robust) -> None:
    if robust is not None and not _positive(robust):
        raise ValueError(f"robust: expected a positive Tukey cut-off in grey levels or None, "
                         f"got {robust!r}")


METHODS = ("forward", "inverse")
#: iterations of the Tukey cut-off's ramp (4c, 3c, 2c, then c) with ``robust``
RAMP = 3


@dataclass(frozen=True)
class LSMParams:
    """Settings of :func:`lsm`: the model, its iterations and the quality thresholds.

    :func:`~lsmta.matching.multi.lsm_multi` and :func:`~lsmta.matching.mpgc.mpgc` take the
    same settings (one model in every search image). Built by keyword; every field is
    checked here, and the error names it.

    Attributes
    ----------
    patch : int
        Odd patch size in pixels, at least 5.
    geometry : {"shift", "similarity", "affine", "row-affine"}
    radiometry : {"none", "offset", "linear"}
    method : {"forward", "inverse"}
        How to iterate (see the module docstring): ``"forward"`` (Gruen's forward additive
        Gauss-Newton, the search image's gradients in every iteration) or ``"inverse"``
        (inverse compositional: the template's gradients, once; about three times faster).
    max_iter : int, optional
        Iteration limit (default 40, or 100 with ``robust``: reweighting converges
        linearly, not quadratically).
    tol : float
        Convergence: largest change of the position and of ``A u`` over the patch, pixels.
    max_displacement : float, optional
        A point moving further than this from its approximation (in any search image) has
        diverged, pixels (default: the patch size).
    max_vif : float
        Variance inflation factor above which a parameter is fixed (adaptive control).
    robust : float, optional
        Tukey cut-off ``c`` in grey levels: residuals beyond it get zero weight (see the
        module docstring). About 4.7 times the residual standard deviation of a good match
        (for noise ``s`` in both images, roughly ``4.7 * sqrt(2) * s``) keeps 95 %
        efficiency on clean patches. None (default): ordinary least squares.
    support : float, optional
        Adaptive support weights (beyond the paper; Yoon & Kweon 2006): every template
        pixel weighs ``exp(-|f - f_centre| / support)``, so that the part of a patch that
        looks unlike its centre — likely another surface, across a depth edge — pulls less.
        Grey levels; None (default): equal weights.
    partial : bool
        Let patches reach over the images' borders (beyond the paper): pixels outside the
        template or the search image get zero weight, and only the patch centre must lie
        inside the template. ``weight_share`` then says how much of the patch was inside, and
        ``thresholds.min_weight_share`` rejects patches that were mostly outside. False
        (default): a patch must lie inside both images.
    thresholds : LSMThresholds, optional
        Applied to the result (:meth:`LSMThresholds.apply`); None (default): none.
    stall : int, optional
        Early stop of points that will not converge, an iteration count (>=
        ``STALL_WINDOW + 1`` = 4): from iteration ``stall`` on, a point whose update (the
        measure ``tol`` is compared with, px) has not fallen by ``STALL_FACTOR`` = 2 over the
        last ``STALL_WINDOW`` = 3 iterations stops as ``MAX_ITERATIONS`` (a converging
        Gauss-Newton iteration mostly shrinks it faster; slow ones are stopped too, see
        ``experiments/dense_real_pairs.py``). None (default): off.
    """

    patch: int = 13
    geometry: str = "affine"
    radiometry: str = "linear"
    method: str = "forward"
    max_iter: int | None = None
    tol: float = 1e-4
    max_displacement: float | None = None
    max_vif: float = 1e3
    robust: float | None = None
    support: float | None = None
    partial: bool = False
    thresholds: LSMThresholds | None = None
    stall: int | None = None

    def __post_init__(self):
        _check_model(self)
        if not _positive(self.tol):
            raise ValueError(f"tol: expected a positive convergence limit in pixels, "
                             f"got {self.tol!r}")
        if self.max_displacement is not None and not _positive(self.max_displacement):
            raise ValueError(f"max_displacement: expected a positive distance in pixels or "
                             f"None, got {self.max_displacement!r}")
        if not _positive(self.max_vif, allow_inf=True):
            raise ValueError(f"max_vif: expected a positive variance inflation factor, "
                             f"got {self.max_vif!r}")
        if self.thresholds is not None and not isinstance(self.thresholds, LSMThresholds):
            raise TypeError(f"thresholds: expected an LSMThresholds or None, got "
                            f"{type(self.thresholds).__name__}")


def _check_model(p) -> None:
    """Check (and normalise) the model fields that :class:`LSMParams` and the growth's
    settings share: ``patch``, ``geometry``, ``radiometry``, ``method``, ``robust``,
    ``max_iter``, ``stall``, ``support``, ``partial`` of the frozen dataclass ``p``."""
    if p.geometry not in GEOMETRIES:
        raise ValueError(f"geometry: expected one of {list(GEOMETRIES)}, got {p.geometry!r}")
    if p.radiometry not in RADIOMETRIES:
        raise ValueError(f"radiometry: expected one of {list(RADIOMETRIES)}, "
                         f"got {p.radiometry!r}")
    if p.method not in METHODS:
        raise ValueError(f"method: expected one of {list(METHODS)}, got {p.method!r}")
    object.__setattr__(p, "patch", check_patch(p.patch))
    _check_robust(p.robust)
    max_iter = as_int(p.max_iter, "max_iter", allow_none=True)
    if p.robust is not None and max_iter is not None and max_iter <= RAMP:
        raise ValueError(f"max_iter: expected more than {RAMP} iterations with robust, "
                         f"got {p.max_iter}")
    object.__setattr__(p, "max_iter", max_iter)
    object.__setattr__(p, "stall", as_int(p.stall, "stall", minimum=_solver.STALL_WINDOW + 1,
                                          allow_none=True, unit="iterations"))
    if p.support is not None and not _positive(p.support):
        raise ValueError(f"support: expected a positive grey-level scale or None, "
                         f"got {p.support!r}")
    if not isinstance(p.partial, (bool, np.bool_)):
        raise ValueError(f"partial: expected True or False, got {p.partial!r}")
    object.__setattr__(p, "partial", bool(p.partial))


def _params(params, cls):
    """``params``, or the defaults of ``cls`` for None; anything else is refused."""
    if params is None:
        return cls()
    if not isinstance(params, cls):
        raise TypeError(f"params: expected {cls.__name__} or None, got "
                        f"{type(params).__name__}")
    return params


@dataclass(frozen=True)
class _Model:
    """The checked matching model of one call."""

    patch: int
    geometry: str
    radiometry: str
    method: str
    max_iter: int
    robust: float | None
    support: float | None
    partial: bool
    tol: float
    max_disp: float
    max_vif: float
    stall: int = 0      # 0: off

    @classmethod
    def of(cls, p: LSMParams) -> _Model:
        """The model of checked settings, with the defaults that depend on other fields
        (``max_iter`` 40, or 100 with ``robust``; ``max_displacement`` the patch size)."""
        max_iter = p.max_iter
        if max_iter is None:
            max_iter = 40 if p.robust is None else 100
        return cls(patch=p.patch, geometry=p.geometry, radiometry=p.radiometry,
                   method=p.method, max_iter=int(max_iter),
                   robust=None if p.robust is None else float(p.robust),
                   support=None if p.support is None else float(p.support),
                   partial=bool(p.partial), tol=p.tol,
                   max_disp=float(p.patch) if p.max_displacement is None
                   else float(p.max_displacement), max_vif=p.max_vif,
                   stall=0 if p.stall is None else p.stall)

    @property
    def ramp(self) -> int:
        """Iterations of the Tukey cut-off's ramp (4c, 3c, 2c, then c)."""
        return RAMP if self.robust is not None else 0

    @property
    def U(self) -> np.ndarray:
        """Offsets ``(P, 2)`` (x, y) of the patch pixels, row by row (don't write)."""
        return _offsets(self.patch)

    def unknowns(self, K: int, constrained: bool) -> int:
        """Joint unknowns of one point: the shift block, then shape and radiometry per image."""
        shape = GEOMETRIES[self.geometry] - 2
        return (1 if constrained else 2) + K * (shape + RADIOMETRIES[self.radiometry])


@functools.lru_cache(maxsize=16)
def _offsets(patch: int) -> np.ndarray:
    h = patch // 2
    gy, gx = np.mgrid[-h:h + 1, -h:h + 1]
    out = np.stack([gx.ravel(), gy.ravel()], axis=1).astype(float)
    out.flags.writeable = False
    return out


def _spline(image, name: str) -> SplineImage:
    return image if isinstance(image, SplineImage) else SplineImage(image, name)


def _initial_A(initial_A, n: int) -> np.ndarray:
    if initial_A is None:
        return np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    A0 = as_array(initial_A, "initial_A")
    if A0.shape == (2, 2):
        return np.broadcast_to(A0, (n, 2, 2)).copy()
    if A0.shape != (n, 2, 2):
        raise ValueError(f"initial_A: expected shape (2, 2) or ({n}, 2, 2), got {A0.shape}")
    return A0.copy()


def _template_weights(template_mask, f_img: SplineImage) -> np.ndarray:
    """The template mask as 0/1 weights, or a ``(0, 0)`` array without one."""
    if template_mask is None:
        return np.zeros((0, 0))
    tm = np.asarray(template_mask)
    if tm.shape != f_img.shape or tm.dtype != bool:
        raise ValueError(f"template_mask: expected a boolean array of shape {f_img.shape}, "
                         f"got {tm.dtype} {tm.shape}")
    return tm.astype(float)


@dataclass
class _State:
    """The arrays of one matching call, one row per point and one column per search image;
    the compiled solver changes them in place."""

    t_xy: np.ndarray        # (n, 2) patch centres in the template
    c: np.ndarray           # (n, K, 2) positions in the search images
    A: np.ndarray           # (n, K, 2, 2)
    r0: np.ndarray          # (n, K)
    r1: np.ndarray          # (n, K)
    t: np.ndarray           # (n,) the shared curve parameter (constrained matching)
    base: np.ndarray        # (n, K, 2) the curves c_k(t) (constrained matching) ...
    direction: np.ndarray   # (n, K, 2)
    quad: np.ndarray        # (n, K, 2)
    t_exp: np.ndarray       # (n,) ... expanded about t_exp
    constrained: bool
    status: np.ndarray      # (n,) Status
    iterations: np.ndarray  # (n,)
    fixed: np.ndarray       # (n, k) unknowns fixed by the adaptive control
    Q: np.ndarray           # (n, k, k) inverse normal matrix of the last iteration
    ee_last: np.ndarray     # (n,) weighted squared residuals of the last iteration
    sw_last: np.ndarray     # (n,) weight sum of the last iteration
    ee_img: np.ndarray      # (n, K) each image's share of ee_last

    @classmethod
    def initial(cls, model: _Model, f_img: SplineImage, t_xy, c0, A0, *, curves=None) -> _State:
        """Starting values; points whose template patch does not fit are OUTSIDE."""
        n, K = c0.shape[:2]
        k = model.unknowns(K, curves is not None)
        status = np.full(n, Status.MAX_ITERATIONS.value, dtype=np.int64)
        status[~f_img.inside(t_xy, margin=0 if model.partial else model.patch // 2)] = \
            Status.OUTSIDE.value
        zeros = np.zeros((n, K, 2))
        t, base, direction, quad, t_exp = (np.zeros(n), zeros, zeros, zeros, np.zeros(n)) \
            if curves is None else curves
        return cls(t_xy=np.ascontiguousarray(t_xy, dtype=float), c=np.array(c0, dtype=float),
                   A=np.array(A0, dtype=float), r0=np.zeros((n, K)), r1=np.ones((n, K)),
                   t=np.array(t, dtype=float), base=np.ascontiguousarray(base, dtype=float),
                   direction=np.ascontiguousarray(direction, dtype=float),
                   quad=np.ascontiguousarray(quad, dtype=float),
                   t_exp=np.ascontiguousarray(t_exp, dtype=float), constrained=curves is not None,
                   status=status, iterations=np.zeros(n, dtype=np.int64),
                   fixed=np.zeros((n, k), dtype=bool), Q=np.full((n, k, k), np.nan),
                   ee_last=np.full(n, np.nan), sw_last=np.full(n, float(K * model.patch**2)),
                   ee_img=np.full((n, K), np.nan))


def _solve(state: _State, model: _Model, f_img: SplineImage, g_imgs, weights, *, active=None,
           start_radiometry: bool = True) -> None:
    """Gauss-Newton iterations of every point (``active``, default: all that fit) in one
    compiled call (:func:`lsmta.matching._solver.solve`, its inputs packed by role); the
    radiometry starts from the patches' means and spreads, or (``start_radiometry=False``)
    from ``state``."""
    if active is None:
        active = state.status != Status.OUTSIDE.value
    shape = g_imgs[0].shape
    if any(g.shape != shape for g in g_imgs):
        raise ValueError(f"searches: expected images of one size, got {[g.shape for g in g_imgs]}")
    coef = g_imgs[0].coefficients[None] if len(g_imgs) == 1 else \
        np.stack([g.coefficients for g in g_imgs])
    inverse = model.method == "inverse"
    gx, gy = f_img.pixel_gradients() if inverse else (np.zeros((0, 0)), np.zeros((0, 0)))
    images = (coef, PAD, shape[0], shape[1], f_img.coefficients, f_img.image, gx, gy, weights)
    order = np.lexsort((state.t_xy[:, 0], np.floor(state.t_xy[:, 1] / 16)))
    points = (state.t_xy, model.U, order, active, state.base, state.direction, state.quad,
              state.t_exp)
    settings = np.array([model.max_iter, model.tol, model.max_disp, model.max_vif,
                         0.0 if model.robust is None else model.robust, model.ramp,
                         0.0 if model.support is None else model.support,
                         float(model.partial), model.stall], dtype=float)
    spec = (list(GEOMETRIES).index(model.geometry), RADIOMETRIES[model.radiometry], inverse,
            state.constrained, start_radiometry and model.radiometry != "none", settings)
    unknowns = (state.c, state.A, state.r0, state.r1, state.t)
    out = (state.status, state.iterations, state.fixed, state.Q, state.ee_last, state.sw_last,
           state.ee_img)
    _solver.solve(images, points, spec, unknowns, out)


def _precision(state: _State) -> tuple[np.ndarray, np.ndarray]:
    """A-posteriori ``sigma0`` (n,) in the units of the solved equations and the
    covariance ``(n, k, k)`` of the unknowns (zero rows and columns for fixed ones), from
    each point's normal equations of its last iteration."""
    seen = np.isfinite(state.ee_last)
    dof = np.maximum(state.sw_last - (~state.fixed).sum(axis=1), 1.0)
    sigma0 = np.where(seen, np.sqrt(np.where(seen, state.ee_last, 0.0) / dof), np.nan)
    return sigma0, sigma0[:, None, None] ** 2 * state.Q


def lsm(template, search, template_xy, search_xy, *, initial_A=None, template_mask=None,
        params: LSMParams | None = None) -> LSMResult:
    """Least squares matching of N template patches in a search image, all at once.

    Parameters
    ----------
    template, search : (H, W) arrays
        Grey images of any real dtype (colour images are refused; convert them first).
        A :class:`~lsmta.matching.spline.SplineImage` may be passed instead to reuse its
        spline coefficients over several calls.
    template_xy : (N, 2) array
        Patch centres in the template (pixels; sub-pixel allowed).
    search_xy : (N, 2) array
        Approximate positions in the search image (pixels).
    initial_A : (N, 2, 2) or (2, 2) array, optional
        Starting affine matrices (default identity), e.g. a neighbour's solution.
    template_mask : (H, W) bool array, optional
        Template pixels that belong to the object; the others (e.g. the backdrop around a
        silhouette) get zero weight in every patch (nearest pixel). Without it every patch
        pixel counts. A patch with less than ``thresholds.min_weight_share`` (default 0.5)
        of object pixels is rejected.
    params : LSMParams, optional
        The model, its iterations and the thresholds (default :class:`LSMParams`).

    Returns
    -------
    LSMResult
        One row per point; a point that fails gets a status code, never an exception.
    """
    p = _params(params, LSMParams)
    model = _Model.of(p)
    f_img, g_img = _spline(template, "template"), _spline(search, "search")
    t_xy, s_xy = as_point_pairs(template_xy, search_xy, "template_xy", "search_xy")
    n = len(t_xy)
    A0 = _initial_A(initial_A, n)
    weights = _template_weights(template_mask, f_img)

    state = _State.initial(model, f_img, t_xy, s_xy[:, None], A0[:, None])
    _solve(state, model, f_img, [g_img], weights)
    result = _result(state, model, s_xy)
    return p.thresholds.apply(result) if p.thresholds is not None else result


def _result(state: _State, model: _Model, s_xy: np.ndarray) -> LSMResult:
    """The frozen result of one search image, with the precision of its position."""
    n = len(s_xy)
    c, A = state.c[:, 0], state.A[:, 0]
    r0, r1 = state.r0[:, 0], state.r1[:, 0]
    sigma0, cov = _precision(state)
    cov_xy = cov[:, :2, :2]
    if model.method == "inverse":
        # the shift was solved as a template increment dc; the position moves by -A dc
        cov_xy = A @ cov_xy @ A.transpose(0, 2, 1)
    fixed = state.fixed
    k_geo = GEOMETRIES[model.geometry]
    fixed8 = np.zeros((n, 8), dtype=bool)
    fixed8[:, :2] = fixed[:, :2]
    if model.geometry == "similarity":
        fixed8[:, 2:6] = (fixed[:, 2] | fixed[:, 3])[:, None]
    elif model.geometry == "affine":
        fixed8[:, 2:6] = fixed[:, 2:6]
    elif model.geometry == "row-affine":
        fixed8[:, 2:4] = fixed[:, 2:4]
    if model.radiometry == "offset":
        fixed8[:, 6] = fixed[:, k_geo]
    elif model.radiometry == "linear":
        fixed8[:, 6:8] = fixed[:, k_geo:k_geo + 2]
    cov_xy = cov_xy.copy()
    with np.errstate(invalid="ignore"):
        sigma_xy = np.sqrt(np.diagonal(cov_xy, axis1=1, axis2=2)).copy()
    sigma_xy[fixed[:, :2]] = np.nan
    failed = state.status == Status.OUTSIDE.value
    params = np.concatenate([c, A.reshape(n, 4), r0[:, None], r1[:, None]], axis=1)
    return LSMResult(xy=c.copy(), params=params, fixed=fixed8, sigma0=sigma0,
                     sigma_xy=sigma_xy, cov_xy=cov_xy, iterations=state.iterations,
                     displacement=np.where(failed, np.nan, np.linalg.norm(c - s_xy, axis=1)),
                     status=state.status, weight_share=state.sw_last / model.patch**2)
