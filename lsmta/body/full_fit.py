"""The full body fitted to a few frames of 3-D points and silhouette lines of sight, the
shape shared across the frames (Plänkers et al. 1999, Section 4; D'Apuzzo et al. 2000,
Fig. 17).

Unknowns
    per frame: the pelvis' position (3, mm) and the joint angles (radians; ``hold`` names
    joints kept at their start); shared by all frames: the limb scales ``s`` (the template's
    lengths times ``s``, :mod:`lsmta.body.full_body`) and a width, a depth and a
    length-radius factor per limb (times the template's ball sizes and the radius along the
    bone, which :mod:`lsmta.body.metaballs` ties to the bone length: the generator's parts
    are not shaped like three balls, and one tie cannot suit the hand and the thigh).
Start from the data, no pose given
    The stature is the height above the floor (``z = floor``) of the highest point with
    ``min_neighbours`` others within ``neighbour_radius`` (lone outliers above the head do
    not count); it builds the template. Each frame's pelvis starts at the points' median
    (x, y) at the template's hip height, the body upright, limbs at rest (knees bent by
    ``knee_start``), facing the direction in which the points' median moves over the
    frames (the person walks forwards; with one frame, the heading must be given).
Stages, in ``n_rounds`` rounds
    1. per frame, ``n_inner`` times: assign the points to their nearest segment, gate the
       lines of sight (closest approach within ``gate`` mm of the skin), solve the pose by
       robust least squares (analytic Jacobian; joint limits as bounds). Lines of sight
       join from round ``silhouette_from`` on (the start is too far from the outline
       before).
    2. the shape: limb scales and ball sizes over all frames' points at once (finite
       differences; the poses held).
    The residuals are skin distances over ``sigma_point`` and closest approaches over
    ``sigma_silhouette`` (:mod:`lsmta.body.silhouette`); a weighted residual above
    ``outlier_k`` at the solution counts as an outlier.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from .._validate import as_array, as_scalar, freeze
from .full_body import LIMBS, RATIOS, full_body_model, limits, template_size
from .metaballs import MetaballModel
from .silhouette import point_derivatives, silhouette_terms


@dataclass(frozen=True)
class FullBodyFitParams:
    """Settings of :func:`fit_full_body` (module docstring).

    Attributes
    ----------
    sigma_point, sigma_silhouette : float
        A-priori standard deviations of a point's skin distance and of a line of sight's
        closest approach (mm).
    loss : str
        ``least_squares`` loss ("soft_l1", "huber", "cauchy", "arctan" or "linear").
    outlier_k : float
    n_rounds, n_inner : int
        Rounds of (poses, shape); pose solves per frame and round.
    silhouette_from : int
        First round (0-based) that uses the lines of sight.
    max_nfev : int
        Solver evaluations per pose solve.
    n_steps : int
        Depth grid of the silhouette term.
    depth_margin : float
        Lines of sight are searched from the camera distance of the points' median minus
        this to plus this (mm).
    gate : float
        Lines of sight further than this from the skin at a solve's start are left out (mm).
    scale_bounds, size_bounds : (float, float)
        Bounds of the limb scales and of the ball-size factors.
    floor : float
        Height of the floor (mm).
    neighbour_radius, min_neighbours
        The top of the head (module docstring).
    knee_start : float
        Start of the knees (radians; inside their limits).
    hold : tuple of str
        Joints held at their start.
    """

    sigma_point: float = 3.0
    sigma_silhouette: float = 6.0
    loss: str = "soft_l1"
    outlier_k: float = 3.0
    n_rounds: int = 3
    n_inner: int = 2
    silhouette_from: int = 1
    max_nfev: int = 25
    n_steps: int = 64
    depth_margin: float = 1200.0
    gate: float = 40.0
    scale_bounds: tuple = (0.7, 1.4)
    size_bounds: tuple = (0.5, 2.0)
    floor: float = 0.0
    neighbour_radius: float = 30.0
    min_neighbours: int = 5
    knee_start: float = -0.1
    hold: tuple = ()

    def __post_init__(self):
        for name in ("n_rounds", "n_inner", "max_nfev", "min_neighbours"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name}: expected a positive integer, got {v}")
        if int(self.n_steps) != self.n_steps or self.n_steps < 3:
            raise ValueError(f"n_steps: expected an integer >= 3, got {self.n_steps}")
        for name in ("sigma_point", "sigma_silhouette", "outlier_k", "depth_margin", "gate",
                     "neighbour_radius"):
            as_scalar(getattr(self, name), name, positive=True)
        as_scalar(self.floor, "floor")
        if self.loss not in ("linear", "soft_l1", "huber", "cauchy", "arctan"):
            raise ValueError(f"loss: expected a least_squares loss name, got {self.loss!r}")
        for name in ("scale_bounds", "size_bounds"):
            lo, hi = getattr(self, name)
            if not 0 < lo < 1 < hi:
                raise ValueError(f"{name}: expected (low, high) with 0 < low < 1 < high")


@dataclass(frozen=True, eq=False)
class FullBodyFit:
    """Result of :func:`fit_full_body`.

    Attributes
    ----------
    model : MetaballModel
        The template built for the measured stature.
    stature : float
        Measured from the points (mm).
    angles : (T, J) array
        Joint angles (radians).
    base : (T, 4, 4) array
        The pelvis' translation per frame (mm).
    scales : (L,) array
        Limb scales (shared).
    size : (S, 2) array
        Width and depth of each segment's middle ball (mm, shared); ``radii`` also holds
        the fitted radius along the bone.
    radii : (S, 3, 3) array
        Ball radii (mm).
    start_angles : (T, J) array; start_base : (T, 4, 4) array
        The start found from the data.
    point_residuals : tuple of (N_t,) arrays
        Skin distances of each frame's points (mm).
    silhouette_residuals : tuple of (M_t,) arrays
        Closest approaches of each frame's lines of sight (mm; empty without).
    n_point_outliers, n_silhouette_outliers : int
        Weighted residuals above ``outlier_k`` (all frames).
    nfev : int
    """

    model: MetaballModel
    stature: float
    angles: np.ndarray
    base: np.ndarray
    scales: np.ndarray
    size: np.ndarray
    radii: np.ndarray
    start_angles: np.ndarray
    start_base: np.ndarray
    point_residuals: tuple
    silhouette_residuals: tuple
    n_point_outliers: int
    n_silhouette_outliers: int
    nfev: int

    def __post_init__(self):
        freeze(self, ("angles", "base", "scales", "size", "radii", "start_angles",
                      "start_base"))


def measure_stature(points, *, floor: float = 0.0, radius: float = 30.0,
                    min_neighbours: int = 5) -> float:
    """Height (mm) above ``floor`` of the highest of ``points (N, 3)`` with at least
    ``min_neighbours`` others within ``radius`` mm."""
    pts = as_array(points, "points", shape=(None, 3))
    tree = cKDTree(pts)
    for i in np.argsort(-pts[:, 2]):
        if len(tree.query_ball_point(pts[i], radius)) > min_neighbours:
            return float(pts[i, 2] - floor)
    raise ValueError(f"points: no point has {min_neighbours} neighbours within {radius} mm")


def _translation(t) -> np.ndarray:
    B = np.eye(4)
    B[:3, 3] = t
    return B


def body_start(model: MetaballModel, points, *, stature: float, heading=None,
               knee_start: float = -0.1):
    """Start angles ``(T, J)`` and bases ``(T, 4, 4)`` from each frame's points (module
    docstring); ``points`` a sequence of ``(N_t, 3)`` arrays, ``heading`` (radians from
    +x, optional) overrides the direction of motion."""
    centres = np.array([np.median(p, axis=0) for p in points])
    if heading is None:
        if len(points) < 2:
            raise ValueError("heading: needed with a single frame (no motion to face along)")
        step = centres[-1, :2] - centres[0, :2]
        heading = float(np.arctan2(step[1], step[0]))
    names = model.skeleton.names
    angles = np.zeros((len(points), model.skeleton.n_joints))
    angles[:, names.index("pelvis_c")] = heading - np.pi / 2
    for side in ("r", "l"):
        angles[:, names.index(f"knee_{side}")] = knee_start
    hip = RATIOS["thigh"] + RATIOS["shank"] + 0.039         # Winter: ankle at 0.039 H
    base = np.stack([_translation((c[0], c[1], hip * stature)) for c in centres])
    return angles, base


class _Frame:
    """One frame's data and its pose solve."""

    def __init__(self, model, points, rays, camera_centre, params):
        self.model, self.pts, self.p = model, points, params
        if rays is None:
            self.origins = self.dirs = np.zeros((0, 3))
        else:
            self.origins, self.dirs = rays
        d = np.linalg.norm(np.median(points, axis=0) - camera_centre) if len(self.origins) \
            else params.depth_margin
        self.near = max(d - params.depth_margin, 0.0)
        self.far = d + params.depth_margin

    def sil(self, angles, base, scales, radii):
        return silhouette_terms(self.model, self.origins, self.dirs, angles, scales, radii,
                                near=self.near, far=self.far, base=base,
                                n_steps=self.p.n_steps)

    def solve(self, angles, base, scales, radii, free, bounds, use_rays):
        """Assign, gate, solve; returns the new angles (1, J), base (1, 4, 4), nfev."""
        m, p = self.model, self.p
        seg = np.argmin(m.all_distances(self.pts, angles, scales, radii, base=base), axis=1)
        keep = np.zeros(len(self.origins), bool)
        if use_rays and len(self.origins):
            keep = np.abs(self.sil(angles, base, scales, radii).r) <= p.gate
        origins, dirs = self.origins[keep], self.dirs[keep]

        def unpack(x):
            a = angles.copy()
            a[0, free] = x[3:]
            return a, _translation(x[:3])[None]

        cache = {}

        def terms(x):
            key = x.tobytes()
            if key not in cache:
                a, b = unpack(x)
                r = m.distance(self.pts, seg, a, scales, radii, base=b) / p.sigma_point
                d_th, d_t = point_derivatives(m, self.pts, seg, a, scales, radii, base=b)
                jac = np.hstack([d_t, d_th[:, free]]) / p.sigma_point
                if len(origins):
                    s = silhouette_terms(m, origins, dirs, a, scales, radii, near=self.near,
                                         far=self.far, base=b, n_steps=p.n_steps)
                    r = np.concatenate([r, s.r / p.sigma_silhouette])
                    jac = np.vstack([jac, np.hstack([s.d_translation, s.d_angles[:, free]])
                                     / p.sigma_silhouette])
                cache.clear()
                cache[key] = (r, jac)
            return cache[key]

        x0 = np.concatenate([base[0, :3, 3], angles[0, free]])
        lo = np.concatenate([np.full(3, -np.inf), bounds[free, 0]])
        hi = np.concatenate([np.full(3, np.inf), bounds[free, 1]])
        sol = least_squares(lambda x: terms(x)[0], np.clip(x0, lo, hi),
                            jac=lambda x: terms(x)[1], bounds=(lo, hi), loss=p.loss,
                            max_nfev=int(p.max_nfev), x_scale="jac")
        a, b = unpack(sol.x)
        return a, b, int(sol.nfev)


def _ball_radii(model, template, scales, factors):
    """Radii ``(S, 3, 3)``: the template's widths and depths and the length radius of the
    bone, each times its limb's factor (``factors (L, 3)``)."""
    k = factors.reshape(-1, 3)[_limb_rows(model)]
    radii = model.simplified_radii(template * k[:, :2], scales)
    radii[..., 2] *= k[:, 2:3]
    return radii


def _limb_rows(model):
    return np.array([s.limb for s in model.segments])


def _solve_shape(model, frames, angles, base, scales, factors, template, p):
    """Limb scales and size factors ``(L, 3)`` over all frames' points, poses held."""
    L = len(scales)
    segs = [np.argmin(model.all_distances(f.pts, angles[[t]], scales,
                                          _ball_radii(model, template, scales, factors),
                                          base=base[[t]]), axis=1)
            for t, f in enumerate(frames)]

    def residual(x):
        s, k = x[:L], x[L:].reshape(L, 3)
        radii = _ball_radii(model, template, s, k)
        return np.concatenate([model.distance(f.pts, seg, angles[[t]], s, radii, base=base[[t]])
                               for t, (f, seg) in enumerate(zip(frames, segs))]) / p.sigma_point

    x0 = np.concatenate([scales, factors.ravel()])
    lo = np.concatenate([np.full(L, p.scale_bounds[0]), np.full(3 * L, p.size_bounds[0])])
    hi = np.concatenate([np.full(L, p.scale_bounds[1]), np.full(3 * L, p.size_bounds[1])])
    sol = least_squares(residual, np.clip(x0, lo, hi), bounds=(lo, hi), loss=p.loss,
                        max_nfev=int(p.max_nfev), x_scale=1.0)
    return sol.x[:L], sol.x[L:].reshape(L, 3), int(sol.nfev)


def _check(points, rays, camera_centre):
    pts = [as_array(p, f"points[{t}]", shape=(None, 3)) for t, p in enumerate(points)]
    if not pts:
        raise ValueError("points: expected one (N, 3) array per frame, got none")
    if rays is None:
        return pts, [None] * len(pts), np.zeros(3)
    if len(rays) != len(pts):
        raise ValueError(f"rays: expected one (origins, directions) per frame ({len(pts)}), "
                         f"got {len(rays)}")
    out = []
    for t, r in enumerate(rays):
        o = as_array(r[0], f"rays[{t}][0]", shape=(None, 3))
        out.append((o, as_array(r[1], f"rays[{t}][1]", shape=o.shape)))
    if camera_centre is None:
        raise ValueError("camera_centre: needed with rays (sets their depth range)")
    return pts, out, as_array(camera_centre, "camera_centre", shape=(3,))


def fit_full_body(points, *, rays=None, camera_centre=None, heading=None,
                  params: FullBodyFitParams | None = None) -> FullBodyFit:
    """Fit the full-body template to a few frames (module docstring).

    Parameters
    ----------
    points : sequence of (N_t, 3) arrays
        3-D points on the skin per frame (world mm, z up, outliers allowed).
    rays : sequence of (origins (M_t, 3), directions (M_t, 3)), optional
        Lines of sight through each frame's observed contour points.
    camera_centre : (3,) array
        Where the lines of sight come from (mm; needed with ``rays``).
    heading : float, optional
        Walking direction (radians from +x); by default the points' motion.
    params : FullBodyFitParams, optional
    """
    p = FullBodyFitParams() if params is None else params
    if not isinstance(p, FullBodyFitParams):
        raise TypeError(f"params: expected FullBodyFitParams, got {type(p).__name__}")
    pts, rays, centre = _check(points, rays, camera_centre)
    stature = measure_stature(np.vstack(pts), floor=p.floor, radius=p.neighbour_radius,
                              min_neighbours=p.min_neighbours)
    model = full_body_model(stature=stature)
    angles, base = body_start(model, pts, stature=stature, heading=heading,
                              knee_start=p.knee_start)
    start_angles, start_base = angles.copy(), base.copy()
    frames = [_Frame(model, x, r, centre, p) for x, r in zip(pts, rays)]
    template = template_size(model, stature=stature)
    L = len(LIMBS)
    scales, factors = np.ones(L), np.ones((L, 3))
    bounds = limits(model)
    bounds[[model.skeleton.names.index(n) for n in ("pelvis_b", "pelvis_a", "pelvis_c")]] = \
        [-np.inf, np.inf]
    free = ~np.isin(model.skeleton.names, p.hold)
    nfev = 0
    for k in range(int(p.n_rounds)):
        radii = _ball_radii(model, template, scales, factors)
        for t, f in enumerate(frames):
            for _ in range(int(p.n_inner)):
                a, b, n = f.solve(angles[[t]], base[[t]], scales, radii, free, bounds,
                                  k >= p.silhouette_from)
                angles[t], base[t], nfev = a[0], b[0], nfev + n
        scales, factors, n = _solve_shape(model, frames, angles, base, scales, factors,
                                          template, p)
        nfev += n
    return _finish(model, frames, stature, angles, base, scales, factors, template,
                   start_angles, start_base, nfev, p)


def _finish(model, frames, stature, angles, base, scales, factors, template, start_angles,
            start_base, nfev, p) -> FullBodyFit:
    radii = _ball_radii(model, template, scales, factors)
    r_p, r_s = [], []
    for t, f in enumerate(frames):
        d = model.all_distances(f.pts, angles[[t]], scales, radii, base=base[[t]])
        r_p.append(d[np.arange(len(d)), np.argmin(np.abs(d), axis=1)])
        r_s.append(f.sil(angles[[t]], base[[t]], scales, radii).r if len(f.origins)
                   else np.zeros(0))
    size = template * factors[_limb_rows(model), :2]
    return FullBodyFit(
        model=model, stature=stature, angles=angles, base=base, scales=scales, size=size,
        radii=radii, start_angles=start_angles, start_base=start_base,
        point_residuals=tuple(r_p), silhouette_residuals=tuple(r_s),
        n_point_outliers=int(sum((np.abs(r) > p.outlier_k * p.sigma_point).sum() for r in r_p)),
        n_silhouette_outliers=int(sum((np.abs(r) > p.outlier_k * p.sigma_silhouette).sum()
                                      for r in r_s)),
        nfev=nfev)
