"""Self-calibrating bundle adjustment with an optional reference bar.

Unknowns
--------
Per camera 16 parameters, in this order (:data:`PARAMETER_NAMES`): the exterior
orientation as a rotation vector ``rx, ry, rz`` (OpenCV's Rodrigues vector of the
world-to-camera rotation ``R``, radians) and the projection centre ``Cx, Cy, Cz`` (mm),
then the interior orientation and additional parameters of :class:`~lsmta.camera.Camera`:
principal distance ``f`` and principal point ``cx, cy`` (px), radial ``k1, k2, k3``,
decentring ``p1, p2`` (OpenCV order, see :mod:`lsmta.camera`), affinity and shear
``b1, b2``. Any subset can be free. Then the object points (mm), three per point.

Observations
------------
Image coordinates (px) with standard deviation ``sigma_px``, and - with a reference bar -
the known distance between the two targets of every bar position as an observation
equation ``|A_i - B_i| - L = v`` with standard deviation ``bar_sigma`` (mm), adjusted
jointly with the image coordinates (not applied as a scale afterwards).

Datum
-----
The exterior orientation of the cameras in ``fixed_exterior`` (default: the first) is
held at its approximation; the scale comes from the bar. Without a bar, ``scale_camera``
names a second camera one of whose centre coordinates (the one along the largest baseline
component) is held too. Either way the datum is minimal: exactly the seven degrees of
freedom of a similarity are fixed, so the network is not distorted by the datum.

The solver is Levenberg-Marquardt on the sparse normal equations (SuperLU); the Jacobian
comes from SciPy's finite differences over its sparsity pattern (the ``jac_sparsity``
machinery of :func:`scipy.optimize.least_squares`): every image coordinate depends on one
camera and one point only, so a Jacobian costs a few dozen residual evaluations instead
of one per unknown. (``least_squares`` itself, trust-region reflective with LSMR, needed
far more iterations on these ill-conditioned networks.) Robust losses by iteratively
reweighted least squares. Standard deviations and correlations come from the
final Jacobian: ``Cov = s0^2 (J^T J)^-1``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numba as nb
import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize._numdiff import group_columns
from scipy.sparse import coo_matrix, csc_matrix, diags, find
from scipy.sparse.linalg import splu
from scipy.spatial.transform import Rotation

from .._validate import as_array, as_int, as_scalar
from ..camera import Camera

EXTERIOR_NAMES = ("rx", "ry", "rz", "Cx", "Cy", "Cz")
INTRINSIC_NAMES = ("f", "cx", "cy", "k1", "k2", "k3", "p1", "p2", "b1", "b2")
PARAMETER_NAMES = EXTERIOR_NAMES + INTRINSIC_NAMES
ALL_INTRINSICS = INTRINSIC_NAMES
# the LSMTA default: interior orientation, K1-K3, P1-P2, B1 (B2 = shear is rarely
# significant for CCD cameras; free it when needed)
DEFAULT_INTRINSICS = ("f", "cx", "cy", "k1", "k2", "k3", "p1", "p2", "b1", "b2")


# ---------------------------------------------------------------------- parameters
def camera_to_params(cam: Camera) -> np.ndarray:
    """The 16 parameters (:data:`PARAMETER_NAMES`) of a camera."""
    rvec, _ = cv2.Rodrigues(np.asarray(cam.R))
    return np.concatenate([rvec.ravel(), cam.C, [getattr(cam, k) for k in INTRINSIC_NAMES]])


def params_to_camera(p, template: Camera) -> Camera:
    """A camera with the 16 parameters ``p`` and the size and name of ``template``."""
    p = np.asarray(p, dtype=float)
    R = Rotation.from_rotvec(p[:3]).as_matrix()
    return template.replace(R=R, C=p[3:6], **dict(zip(INTRINSIC_NAMES, p[6:].tolist())))


def project_params(params, X, *, rows=None) -> np.ndarray:
    """Pixel coordinates of points seen by cameras given by their parameters.

    Parameters
    ----------
    params : (K, 16) array
        Camera parameters (:data:`PARAMETER_NAMES`).
    X : (n, 3) or (3,) array
        Points, mm.
    rows : (n,) int array, optional
        The camera (row of ``params``) of each point: point i is seen by camera
        ``rows[i]`` (each camera's rotation computed once: the same numbers as
        ``project_params(params[rows], X)``). Default: row i for point i, or camera 0 for
        every point when K is 1.

    Returns
    -------
    (n, 2) array
        Pixel coordinates, px. ``X`` and the cameras broadcast as numpy arrays do: a
        single point (``(3,)`` or ``(1, 3)``) is seen by every camera, a single camera
        (``K`` 1 or ``rows`` of length 1) sees every point.
    """
    params = np.asarray(params, dtype=float)
    X = np.atleast_2d(np.asarray(X, dtype=float))
    if rows is None:
        rows = np.arange(len(params))
    rows = np.arange(len(params))[np.asarray(rows)]      # IndexError when out of range
    try:
        n = np.broadcast_shapes((len(X),), (len(rows),))[0]
    except ValueError:
        raise ValueError(f"X: expected 1 or {len(rows)} points (one per camera row), "
                         f"got {len(X)}") from None
    return Projector(params, np.broadcast_to(rows, (n,)))(np.broadcast_to(X, (n, 3)))


class Projector:
    """:func:`project_params` for fixed cameras and fixed camera-of-each-point ``rows``,
    with the per-point rotations and centres gathered once, for repeated calls with new
    points (the same numbers as :func:`project_params`).

    Parameters
    ----------
    params : (K, 16) array
        Camera parameters (:data:`PARAMETER_NAMES`).
    rows : (n,) int array
        The camera (row of ``params``, in ``0..K-1``) of each point the projector will be
        called with.
    """

    def __init__(self, params, rows):
        params = np.asarray(params, dtype=float)
        self.rows = np.ascontiguousarray(np.arange(len(params))[np.asarray(rows)])
        self.R = Rotation.from_rotvec(params[:, :3]).as_matrix()[self.rows]
        self.C = params[self.rows, 3:6]
        self.intr = np.ascontiguousarray(params[:, 6:])

    def subset(self, index) -> Projector:
        """The projector of some of the points only.

        Parameters
        ----------
        index : (m,) int array, or (n,) bool mask
            The points kept (positions in ``rows``, any numpy index of a 1-D array).

        Returns
        -------
        Projector
            The projector of the m points ``rows[index]``.
        """
        out = object.__new__(Projector)
        out.rows = np.ascontiguousarray(self.rows[index])
        out.R, out.C, out.intr = self.R[index], self.C[index], self.intr
        return out

    def frame(self, X) -> np.ndarray:
        """Camera coordinates ``(n, 3)`` of the points ``X`` ``(n, 3)``, mm."""
        # the rotation by numpy's matmul (BLAS: its rounding), the lens compiled
        return (self.R @ (np.asarray(X, dtype=float) - self.C)[:, :, None])[:, :, 0]

    def lens(self, Xc) -> np.ndarray:
        """Pixel coordinates of camera coordinates.

        Parameters
        ----------
        Xc : (n, 3) array
            Camera coordinates, mm (:meth:`frame`); n must equal ``len(rows)``.

        Returns
        -------
        (n, 2) array
            Pixel coordinates, px.
        """
        Xc = np.ascontiguousarray(Xc, dtype=float)
        if Xc.shape != (len(self.rows), 3):
            raise ValueError(f"Xc: expected shape ({len(self.rows)}, 3) (one point per "
                             f"camera row), got {Xc.shape}")
        out = np.empty((len(Xc), 2))
        _lens(Xc, self.intr, self.rows, out)
        return out

    def __call__(self, X) -> np.ndarray:
        """Pixel coordinates of points.

        Parameters
        ----------
        X : (n, 3) array
            Points, mm; n must equal ``len(rows)``.

        Returns
        -------
        (n, 2) array
            Pixel coordinates, px.
        """
        X = np.asarray(X, dtype=float)
        if X.shape != (len(self.rows), 3):
            raise ValueError(f"X: expected shape ({len(self.rows)}, 3) (one point per "
                             f"camera row), got {X.shape}")
        return self.lens(self.frame(X))


@nb.njit(cache=True, error_model="numpy")
def _lens(Xc, intr, rows, out):
    """Perspective division, lens and affinity of :func:`project_params` per point (in place
    into ``out`` (n, 2)): the same operations in the same order as the numpy form it
    replaced (no fused multiply-add), so the same numbers."""
    for i in range(len(Xc)):
        q = rows[i]
        f, cx, cy = intr[q, 0], intr[q, 1], intr[q, 2]
        k1, k2, k3, p1, p2, b1, b2 = (intr[q, 3], intr[q, 4], intr[q, 5], intr[q, 6],
                                      intr[q, 7], intr[q, 8], intr[q, 9])
        x = Xc[i, 0] / Xc[i, 2]
        y = Xc[i, 1] / Xc[i, 2]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        out[i, 0] = cx + f * ((1 + b1) * xd + b2 * yd)
        out[i, 1] = cy + f * yd


# ---------------------------------------------------------------------- inputs
LOSSES = ("linear", "huber", "soft_l1", "cauchy", "arctan")


@dataclass(frozen=True)
class BundleParams:
    """How :func:`bundle_adjust` solves: robust loss, outlier rejection, stopping rules and
    whether it computes the covariance.

    Attributes
    ----------
    loss : str
        Robust loss on the standardised residuals (the losses of
        :func:`scipy.optimize.least_squares`: "linear", "huber", "soft_l1", "cauchy",
        "arctan"), applied by iteratively reweighted least squares.
    f_scale : float
        The residual (in units of ``sigma_px``) where the loss starts to bend.
    reject_k : float, optional
        After the adjustment, reject observations whose residual vector is longer than
        ``reject_k * s0 * sigma_px * sqrt(2)`` and adjust again (once). None: no rejection.
    max_nfev : int, optional
        Most Levenberg-Marquardt iterations (default 100).
    ftol, xtol : float
        Stop when the cost falls by less than ``ftol`` (relative) in an iteration, or the
        step is below ``xtol`` (relative to the unknowns).
    covariance : bool
        Compute standard deviations and correlations (needs a dense ``p x p`` inverse).
    """

    loss: str = "linear"
    f_scale: float = 3.0
    reject_k: float | None = None
    max_nfev: int | None = None
    ftol: float = 1e-10
    xtol: float = 1e-10
    covariance: bool = True

    def __post_init__(self):
        if self.loss not in LOSSES:
            raise ValueError(f"loss: expected one of scipy's losses, got {self.loss!r}")
        as_scalar(self.f_scale, "f_scale", positive=True)
        if self.reject_k is not None:
            as_scalar(self.reject_k, "reject_k", positive=True)
        as_int(self.max_nfev, "max_nfev", allow_none=True)
        as_scalar(self.ftol, "ftol", nonnegative=True)
        as_scalar(self.xtol, "xtol", nonnegative=True)


@dataclass(frozen=True)
class Bar:
    """A reference bar: which points are its two targets at each position.

    Attributes
    ----------
    pairs : (M, 2) int array
        Indices (into the adjustment's points) of the two targets at each of M positions.
    length : float
        Known distance between the targets, mm.
    sigma : float
        Standard deviation of the length observation, mm.
    """

    pairs: np.ndarray
    length: float
    sigma: float = 0.01

    def __post_init__(self):
        pairs = np.asarray(self.pairs)
        if pairs.ndim != 2 or pairs.shape[1] != 2 or not np.issubdtype(pairs.dtype, np.integer):
            raise ValueError(f"bar.pairs: expected an (M, 2) integer array, got {pairs.shape}")
        object.__setattr__(self, "pairs", pairs.copy())
        object.__setattr__(self, "length", as_scalar(self.length, "bar.length", positive=True))
        object.__setattr__(self, "sigma", as_scalar(self.sigma, "bar.sigma", positive=True))


@dataclass(frozen=True, eq=False)
class BundleResult:
    """Result of :func:`bundle_adjust`.

    Attributes
    ----------
    cameras : list of Camera
        The calibrated cameras.
    points : (N, 3) array
        Adjusted object points, mm (NaN for points without observations).
    residuals : (K, N, 2) array
        Image residuals ``projected - observed``, px; NaN where not observed (or dropped).
    rms_per_camera : (K,) array
        Per-coordinate RMS image residual of each camera, px (rejected observations left out).
    rms : float
        Per-coordinate RMS image residual over all cameras, px.
    bar_residuals : (M,) array or None
        Adjusted bar length minus the known length, mm.
    sigma0 : float
        A-posteriori standard deviation of unit weight (1 when the model and the stated
        ``sigma_px``, ``bar_sigma`` fit the data).
    n_observations, n_unknowns : int
        ``n`` (image coordinates + bar lengths) and ``p`` (free parameters) of the final
        adjustment; the redundancy is ``n - p``.
    noise_limit : float
        ``sigma_px * sqrt(1 - p / n)`` over the n image coordinates: the per-coordinate RMS
        residual expected when the only error is image noise of ``sigma_px``; ``p`` is the
        sum of the image coordinates' leverages (``p`` minus the bar lengths for a bar much
        more precise than the images; ``p`` without a bar).
    expected_rms_per_camera : (K,) array
        The same limit per camera from the leverages of its observations (``sigma_px *
        sqrt(mean(1 - h_ii))``), px.
    parameter_names : list of str
        ``"camera.param"`` for every free camera parameter.
    parameter_values, parameter_std : (P,) arrays
        Their adjusted values and standard deviations (``s0^2 (J^T J)^-1``).
    correlation : (P, P) array
        Correlation matrix of the free camera parameters.
    point_std : (N, 3) array
        Standard deviations of the object points, mm.
    rejected : (K, N) bool array
        Observations rejected as outliers.
    n_nan_dropped : int
        Observations (camera, point) given as NaN in either coordinate - not seen, or lost
        by the target measurement - and left out.
    nfev : int
        Residual evaluations of the solver (last pass).
    history : list of (16 K,) arrays
        Camera parameters after each solver iteration of the last pass.
    """

    cameras: list
    points: np.ndarray
    residuals: np.ndarray
    rms_per_camera: np.ndarray
    rms: float
    bar_residuals: np.ndarray | None
    sigma0: float
    n_observations: int
    n_unknowns: int
    noise_limit: float
    expected_rms_per_camera: np.ndarray
    parameter_names: list
    parameter_values: np.ndarray
    parameter_std: np.ndarray
    correlation: np.ndarray
    point_std: np.ndarray
    rejected: np.ndarray
    n_nan_dropped: int
    nfev: int
    history: list = field(default_factory=list, repr=False)

    @property
    def n_rejected(self) -> int:
        return int(self.rejected.sum())

    def std(self, camera: int, name: str) -> float:
        """Standard deviation of parameter ``name`` of camera ``camera`` (NaN if fixed)."""
        key = f"{self.cameras[camera].name or camera}.{name}"
        if key not in self.parameter_names:
            return float("nan")
        return float(self.parameter_std[self.parameter_names.index(key)])


# ---------------------------------------------------------------------- checks
def _check_geometry(points, bar: Bar | None):
    """Refuse a bar track whose targets all lie on one line."""
    if bar is None:
        return
    P = points[bar.pairs.ravel()]
    P = P[np.isfinite(P).all(axis=1)]
    if len(P) < 3:
        return
    s = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    if s[1] < 1e-3 * s[0]:
        raise ValueError(
            f"bar: degenerate bar track - all {len(P)} target positions lie on one line "
            f"(singular values {s[0]:.3g}, {s[1]:.3g}, {s[2]:.3g} mm); move the bar through "
            "the volume in different directions")


def min_points_per_camera(n_free: int) -> int:
    """Fewest points a camera must see to determine its ``n_free`` parameters with
    redundancy (two coordinates per point, plus three spare points)."""
    return int(np.ceil(n_free / 2)) + 3


# ---------------------------------------------------------------------- solver
def bundle_adjust(cameras, xy, points, *, intrinsics=DEFAULT_INTRINSICS, fixed_exterior=(0,),
                  bar: Bar | None = None, scale_camera: int | None = None,
                  sigma_px: float = 1.0, fix_points: bool = False,
                  params: BundleParams | None = None) -> BundleResult:
    """Adjust cameras and object points to image observations (and a reference bar).

    Parameters
    ----------
    cameras : sequence of K Camera
        Approximations (their sizes and names are kept).
    xy : (K, N, 2) array
        Image coordinates, px; NaN marks a point not seen by a camera (counted and dropped).
    points : (N, 3) array
        Approximate object points, mm.
    intrinsics : sequence of str, or sequence of K such sequences
        Names from :data:`INTRINSIC_NAMES` that are free (the same for all cameras, or one
        list per camera); the others are held at the approximations' values.
    fixed_exterior : sequence of int
        Cameras whose exterior orientation is held (the datum).
    bar : Bar, optional
        Reference bar length observations (they define the scale).
    scale_camera : int, optional
        Without a bar: a camera whose largest baseline coordinate (relative to the first
        fixed camera) is held, which fixes the scale.
    sigma_px : float
        Standard deviation of an image coordinate, px (weights, and the noise limit).
    fix_points : bool
        Hold the object points (a resection of all cameras at once).
    params : BundleParams, optional
        Robust loss, outlier rejection, stopping rules, covariance (default:
        ``BundleParams()``: least squares, no rejection, with the covariance).

    Returns
    -------
    BundleResult

    Raises
    ------
    ValueError
        For a camera that sees too few points (named, with its count), fewer observations
        than unknowns, a degenerate (collinear) bar track, or no datum.
    """
    settings = BundleParams() if params is None else params
    if not isinstance(settings, BundleParams):
        raise TypeError(f"params: expected a BundleParams, got {type(settings).__name__}")
    pr = _problem(cameras, xy, points, intrinsics=intrinsics, fixed_exterior=fixed_exterior,
                  bar=bar, scale_camera=scale_camera, sigma_px=sigma_px, fix_points=fix_points)
    reject_k = settings.reject_k
    params0 = np.stack([camera_to_params(c) for c in pr.cameras])
    X0 = pr.points
    rejected = np.zeros(pr.seen.shape, bool)
    for _ in range(1 if reject_k is None else 2):
        use = pr.seen & ~rejected & pr.used_point[None, :]
        adj = _solve(pr, params0, X0, use, settings)
        if reject_k is None:
            break
        lim = reject_k * adj.sigma0 * pr.sigma_px * np.sqrt(2)
        new = pr.seen & (np.linalg.norm(np.nan_to_num(adj.residuals, nan=0.0), axis=2) > lim)
        if not new.any():
            break
        rejected |= new
        params0, X0 = adj.params, adj.points
    return _result(pr, adj, rejected)


@dataclass(frozen=True, eq=False)
class _Problem:
    """The checked inputs of :func:`bundle_adjust` and which unknowns are free."""

    cameras: list
    xy: np.ndarray            # (K, N, 2)
    points: np.ndarray        # (N, 3) approximations
    seen: np.ndarray          # (K, N) finite observations
    used_point: np.ndarray    # (N,) observed often enough to enter
    free: np.ndarray          # (K, 16) free camera parameters
    bar: Bar | None
    sigma_px: float
    fix_points: bool
    n_nan: int


def _problem(cameras, xy, points, *, intrinsics, fixed_exterior, bar, scale_camera, sigma_px,
             fix_points) -> _Problem:
    """Check the arguments, choose the free parameters and the datum."""
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    K = len(cameras)
    xy = as_array(xy, "xy", shape=(K, None, 2), allow_nan=True)
    N = xy.shape[1]
    X0 = as_array(points, "points", shape=(N, 3), allow_nan=True).copy()
    sigma_px = as_scalar(sigma_px, "sigma_px", positive=True)
    if isinstance(intrinsics, str) or (len(intrinsics) and isinstance(intrinsics[0], str)) \
            or len(intrinsics) == 0:
        intrinsics = [tuple(intrinsics)] * K
    if len(intrinsics) != K:
        raise ValueError(f"intrinsics: expected one list of names or {K} lists")
    for names in intrinsics:
        bad = set(names) - set(INTRINSIC_NAMES)
        if bad:
            raise ValueError(f"intrinsics: unknown names {sorted(bad)}; expected some of "
                             f"{INTRINSIC_NAMES}")
    fixed_exterior = [int(i) for i in fixed_exterior]
    if any(not 0 <= i < K for i in fixed_exterior):
        raise ValueError(f"fixed_exterior: expected camera indices in [0, {K})")
    if bar is not None and not isinstance(bar, Bar):
        raise TypeError("bar: expected an lsmta.calibration.Bar")
    if bar is not None and (bar.pairs.min() < 0 or bar.pairs.max() >= N):
        raise ValueError(f"bar.pairs: expected point indices in [0, {N})")
    seen = np.isfinite(xy).all(axis=2)
    free = _free_parameters(cameras, intrinsics, fixed_exterior, bar, scale_camera, fix_points)
    # cameras must see enough points for their own unknowns
    counts = seen.sum(axis=1)
    for k in range(K):
        need = min_points_per_camera(int(free[k].sum()))
        if counts[k] < need:
            raise ValueError(
                f"xy: camera {cameras[k].name or k} sees {counts[k]} point(s); it needs at "
                f"least {need} for its {int(free[k].sum())} free parameters")
    used_pt = seen.sum(axis=0) >= (1 if fix_points else 2)
    if not fix_points:
        bad = np.flatnonzero(used_pt & ~np.isfinite(X0).all(axis=1))
        if len(bad):
            raise ValueError(f"points: {len(bad)} observed point(s) have no approximation "
                             "(NaN)")
    _check_geometry(X0, bar)
    return _Problem(cameras=cameras, xy=xy, points=X0, seen=seen, used_point=used_pt,
                    free=free, bar=bar, sigma_px=sigma_px, fix_points=bool(fix_points),
                    n_nan=int((~seen).sum()))


def _free_parameters(cameras, intrinsics, fixed_exterior, bar, scale_camera,
                     fix_points) -> np.ndarray:
    """(K, 16) free camera parameters: the named intrinsics, the exterior orientation of
    the cameras not in the datum, less one centre coordinate of ``scale_camera`` without
    a bar."""
    K = len(cameras)
    free = np.zeros((K, 16), bool)
    for k in range(K):
        if k not in fixed_exterior:
            free[k, :6] = True
        for name in intrinsics[k]:
            free[k, 6 + INTRINSIC_NAMES.index(name)] = True
    if bar is None and not fix_points:
        if scale_camera is None:
            raise ValueError("scale_camera: without a bar the scale must be fixed; name a "
                             "camera (scale_camera=) or pass a bar")
        if not fixed_exterior:
            raise ValueError("fixed_exterior: name at least one camera for the datum")
        base = cameras[scale_camera].C - cameras[fixed_exterior[0]].C
        free[scale_camera, 3 + int(np.argmax(np.abs(base)))] = False
    if not fixed_exterior and not fix_points:
        raise ValueError("fixed_exterior: name at least one camera for the datum")
    return free


@dataclass(frozen=True, eq=False)
class _Layout:
    """Where the observations and the unknowns of one adjustment sit."""

    kk: np.ndarray            # (n_img,) camera of each image observation
    ii: np.ndarray            # (n_img,) point of each image observation
    pts_free: np.ndarray      # (N,) points adjusted
    pairs: np.ndarray         # (n_bar, 2) bar positions used
    cam_cols: np.ndarray      # (K, 16) column of each free camera parameter, -1 if held
    pt_cols: np.ndarray       # (N,) first column of each free point, -1 if held
    n_cam: int
    n_par: int
    n_obs: int

    @property
    def n_img(self) -> int:
        return len(self.kk)

    def unpack(self, x, params0, X0):
        params = params0.copy()
        params[self.cam_cols >= 0] = x[:self.n_cam]
        X = X0.copy()
        X[self.pts_free] = x[self.n_cam:].reshape(-1, 3)
        return params, X


def _layout(pr: _Problem, use) -> _Layout:
    K, N = use.shape
    kk, ii = np.nonzero(use)
    pts_free = np.zeros(N, bool) if pr.fix_points else use.sum(axis=0) >= 2
    if pr.bar is not None and not pr.fix_points:
        pairs = pr.bar.pairs[pts_free[pr.bar.pairs].all(axis=1)]
    else:
        pairs = np.zeros((0, 2), int)
    cam_cols = np.full((K, 16), -1)
    cam_cols[pr.free] = np.arange(pr.free.sum())
    n_cam = int(pr.free.sum())
    pt_cols = np.full(N, -1)
    pt_cols[pts_free] = n_cam + 3 * np.arange(pts_free.sum())
    n_par = n_cam + 3 * int(pts_free.sum())
    n_obs = 2 * len(kk) + len(pairs)
    if n_obs <= n_par:
        bars = f" and {len(pairs)} bar lengths" if pr.bar else ""
        raise ValueError(
            f"xy: {len(kk)} image points{bars} give {n_obs} observations for {n_par} "
            "unknowns; more bar positions (or points) are needed, or fewer free parameters")
    return _Layout(kk=kk, ii=ii, pts_free=pts_free, pairs=pairs, cam_cols=cam_cols,
                   pt_cols=pt_cols, n_cam=n_cam, n_par=n_par, n_obs=n_obs)


def _sparsity(lay: _Layout):
    """Which unknowns each observation depends on, ``(n_obs, n_par)`` CSR."""
    rows, cols = [], []
    for c in range(16):
        col = lay.cam_cols[lay.kk, c]
        m = col >= 0
        for j in (0, 1):
            rows.append(2 * np.flatnonzero(m) + j)
            cols.append(col[m])
    pc = lay.pt_cols[lay.ii]
    m = pc >= 0
    for a in range(3):
        for j in (0, 1):
            rows.append(2 * np.flatnonzero(m) + j)
            cols.append(pc[m] + a)
    n_bar = len(lay.pairs)
    for e in (0, 1):
        for a in range(3):
            rows.append(2 * lay.n_img + np.arange(n_bar))
            cols.append(lay.pt_cols[lay.pairs[:, e]] + a)
    rows = np.concatenate(rows)
    cols = np.concatenate(cols)
    return coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(lay.n_obs, lay.n_par)).tocsr()


@dataclass(frozen=True, eq=False)
class _Adjusted:
    """One adjustment's solution and statistics (see :class:`BundleResult`)."""

    params: np.ndarray        # (K, 16)
    points: np.ndarray        # (N, 3), NaN for points not adjusted
    residuals: np.ndarray     # (K, N, 2) px
    sigma0: float
    n_obs: int
    n_par: int
    std: np.ndarray           # (n_par,)
    corr: np.ndarray          # (n_cam, n_cam)
    point_std: np.ndarray     # (N, 3)
    expected_rms: np.ndarray  # (K,)
    noise_limit: float
    bar_residuals: np.ndarray | None
    nfev: int
    history: list


def _solve(pr: _Problem, params0, X0, use, st: BundleParams) -> _Adjusted:
    """Adjust the observations ``use`` (K, N) from ``params0`` and ``X0``: Levenberg-Marquardt,
    then iteratively reweighted with the robust loss."""
    lay = _layout(pr, use)
    obs = pr.xy[lay.kk, lay.ii]
    bar = pr.bar

    def fun(x):
        params, X = lay.unpack(x, params0, X0)
        r = (project_params(params, X[lay.ii], rows=lay.kk) - obs).ravel() / pr.sigma_px
        if len(lay.pairs):
            d = np.linalg.norm(X[lay.pairs[:, 0]] - X[lay.pairs[:, 1]], axis=1)
            r = np.concatenate([r, (d - bar.length) / bar.sigma])
        return r

    sparsity = _sparsity(lay)
    history = []

    def callback(intermediate_result):  # noqa: D401 - scipy's callback protocol
        history.append(lay.unpack(intermediate_result.x, params0, X0)[0].ravel().copy())

    x0 = np.concatenate([params0[pr.free], X0[lay.pts_free].ravel()])
    sol = _levenberg_marquardt(fun, x0, sparsity, st.max_nfev, st.ftol, st.xtol, callback)
    if st.loss != "linear":
        # iteratively reweighted least squares with scipy's loss functions: weights
        # sqrt(rho'(z)), z = (r / f_scale)^2, from the previous solution
        for _ in range(5):
            z = (fun(sol.x) / st.f_scale) ** 2
            w = np.sqrt(_LOSS_DERIVATIVE[st.loss](z))
            x_prev = sol.x
            sol = _levenberg_marquardt(lambda x, w=w: fun(x) * w, sol.x, sparsity, 20,
                                       max(st.ftol, 1e-7), st.xtol, callback)
            if np.linalg.norm(sol.x - x_prev) < 1e-8 * (1 + np.linalg.norm(x_prev)):
                break
    return _statistics(pr, lay, sol, fun(sol.x), params0, X0, st.covariance, history)


def _statistics(pr: _Problem, lay: _Layout, sol, r, params0, X0, covariance: bool,
                history) -> _Adjusted:
    """Residuals, s0, and (with ``covariance``) standard deviations, correlations and the
    leverages of the image observations (noise limit) at the solution ``sol``."""
    K, N = pr.seen.shape
    sigma_px, n_img, n_cam, n_par = pr.sigma_px, lay.n_img, lay.n_cam, lay.n_par
    params, X = lay.unpack(sol.x, params0, X0)
    sigma0 = float(np.sqrt(np.sum(r**2) / (lay.n_obs - n_par)))
    res_img = np.full((K, N, 2), np.nan)
    res_img[lay.kk, lay.ii] = r[: 2 * n_img].reshape(-1, 2) * sigma_px
    std = np.full(n_par, np.nan)
    corr = np.full((n_cam, n_cam), np.nan)
    lev = np.full(2 * n_img, np.nan)
    if covariance:
        J = sol.jac.toarray() if hasattr(sol.jac, "toarray") else np.asarray(sol.jac)
        Nmat = J.T @ J
        try:
            Ninv = cho_solve(cho_factor(Nmat), np.eye(len(Nmat)))
        except np.linalg.LinAlgError:
            Ninv = np.linalg.pinv(Nmat, rcond=1e-14, hermitian=True)
        cov = sigma0**2 * Ninv
        std = np.sqrt(np.clip(np.diag(cov), 0, None))
        sc = std[:n_cam]
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = cov[:n_cam, :n_cam] / np.outer(sc, sc)
        Jimg = J[: 2 * n_img]
        lev = ((Jimg @ Ninv) * Jimg).sum(axis=1)
    exp_cam = np.full(K, np.nan)
    lev2 = lev.reshape(-1, 2)
    for k in range(K):
        m = lay.kk == k
        if m.any():
            exp_cam[k] = sigma_px * np.sqrt(np.mean(1 - lev2[m]))
    # sigma sqrt(1 - p/n) over the image coordinates; with bar lengths, p counts the
    # redundancy the image coordinates give up (sum of their leverages), which is p minus
    # the number of bar lengths when the bar is much more precise than the images
    p_img = np.nansum(lev) if covariance else n_par - len(lay.pairs)
    point_std = np.full((N, 3), np.nan)
    point_std[lay.pts_free] = std[n_cam:].reshape(-1, 3)
    X_out = X.copy()
    if not pr.fix_points:
        X_out[~lay.pts_free] = np.nan
    bar_res = None
    if pr.bar is not None:
        d = np.linalg.norm(X_out[pr.bar.pairs[:, 0]] - X_out[pr.bar.pairs[:, 1]], axis=1)
        bar_res = d - pr.bar.length
    return _Adjusted(params=params, points=X_out, residuals=res_img, sigma0=sigma0,
                     n_obs=lay.n_obs, n_par=n_par, std=std, corr=corr, point_std=point_std,
                     expected_rms=exp_cam,
                     noise_limit=float(sigma_px * np.sqrt(1 - p_img / (2 * n_img))),
                     bar_residuals=bar_res, nfev=int(sol.nfev), history=history)


_LOSS_DERIVATIVE = {
    "huber": lambda z: np.where(z <= 1, 1.0, 1 / np.sqrt(np.maximum(z, 1e-300))),
    "soft_l1": lambda z: 1 / np.sqrt(1 + z),
    "cauchy": lambda z: 1 / (1 + z),
    "arctan": lambda z: 1 / (1 + z**2),
}


@dataclass
class _Solution:
    x: np.ndarray
    jac: object
    nfev: int


class _GroupedDifference:
    """The Jacobian by 2-point finite differences over a sparsity pattern, columns perturbed
    together by groups: the numbers of scipy's ``approx_derivative(fun, x, method="2-point",
    f0=f0, sparsity=(sparsity, groups))`` (unbounded), as a CSC matrix, with the pattern's
    rows per group and the CSC order found once instead of at every Jacobian."""

    def __init__(self, sparsity, groups):
        S = csc_matrix(sparsity)
        self.shape = S.shape
        self.masks, self.rows, self.cols = [], [], []
        for g in range(int(np.max(groups)) + 1):
            e = np.equal(g, groups)
            cols, = np.nonzero(e)
            i, j, _ = find(S[:, cols])
            self.masks.append(e)
            self.rows.append(i)
            self.cols.append(cols[j])
        r, c = np.concatenate(self.rows), np.concatenate(self.cols)
        self.order = np.lexsort((r, c))                     # column-major, rows ascending
        self.indices = r[self.order]
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(c, minlength=S.shape[1]))])

    def __call__(self, fun, x0, f0) -> csc_matrix:
        sign = (x0 >= 0).astype(float) * 2 - 1
        h = np.finfo(np.float64).eps ** 0.5 * sign * np.maximum(1.0, np.abs(x0))
        parts = []
        for e, i, j in zip(self.masks, self.rows, self.cols):
            x = x0 + h * e
            dx = x - x0
            df = np.atleast_1d(fun(x)) - f0
            parts.append(df[i] / dx[j])
        data = np.concatenate(parts)[self.order]
        return csc_matrix((data, self.indices.copy(), self.indptr.copy()), shape=self.shape)


def _levenberg_marquardt(fun, x0, sparsity, max_iter, ftol, xtol, callback, step=None):
    """Levenberg-Marquardt on the sparse normal equations (SuperLU factorisation), with
    the Jacobian by finite differences over the sparsity pattern (scipy's grouped
    differences, as ``least_squares(jac_sparsity=...)`` uses). ``step(J, r, lam)``, if
    given, solves ``(JᵀJ + lam diag(JᵀJ)) dx = -Jᵀr`` instead (e.g. by the Schur complement,
    :mod:`lsmta.calibration.refine`)."""
    jacobian = _GroupedDifference(sparsity, group_columns(sparsity))
    x = x0.copy()
    r = fun(x)
    cost = r @ r
    lam = 1e-3
    max_iter = 100 if max_iter is None else int(max_iter)
    nfev = 1
    J = None
    for _ in range(max_iter):
        J = jacobian(fun, x, r)
        nfev += 1
        if step is None:
            N = (J.T @ J).tocsc()
            g = J.T @ r
            d = N.diagonal().copy()
            d[d == 0] = 1.0
        improved = False
        for _ in range(12):
            try:
                dx = -splu((N + diags(lam * d)).tocsc()).solve(g) if step is None \
                    else step(J, r, lam)
            except (RuntimeError, np.linalg.LinAlgError):
                lam *= 10
                continue
            r_new = fun(x + dx)
            nfev += 1
            c_new = r_new @ r_new
            if np.isfinite(c_new) and c_new < cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        rel = (cost - c_new) / cost
        x = x + dx
        r, cost = r_new, c_new
        lam = max(lam / 10, 1e-12)
        if callback is not None:
            callback(_Solution(x=x, jac=None, nfev=nfev))
        if rel < ftol or np.linalg.norm(dx) < xtol * (xtol + np.linalg.norm(x)):
            break
    J = jacobian(fun, x, r)
    return _Solution(x=x, jac=J, nfev=nfev)


def _result(pr: _Problem, adj: _Adjusted, rejected) -> BundleResult:
    K = len(pr.cameras)
    cams = [params_to_camera(adj.params[k], pr.cameras[k]) for k in range(K)]
    res = adj.residuals
    with np.errstate(invalid="ignore"):
        rms_cam = np.sqrt(np.nanmean(res.reshape(K, -1) ** 2, axis=1))
    names = [f"{pr.cameras[k].name or k}.{PARAMETER_NAMES[c]}"
             for k, c in zip(*np.nonzero(pr.free))]
    n_cam = int(pr.free.sum())
    return BundleResult(
        cameras=cams, points=adj.points, residuals=res, rms_per_camera=rms_cam,
        rms=float(np.sqrt(np.nanmean(res**2))), bar_residuals=adj.bar_residuals,
        sigma0=adj.sigma0, n_observations=adj.n_obs, n_unknowns=adj.n_par,
        noise_limit=adj.noise_limit, expected_rms_per_camera=adj.expected_rms,
        parameter_names=names, parameter_values=adj.params[pr.free],
        parameter_std=adj.std[:n_cam], correlation=adj.corr, point_std=adj.point_std,
        rejected=rejected, n_nan_dropped=pr.n_nan, nfev=adj.nfev, history=adj.history)
