"""The full body fitted to a few frames of 3-D points and silhouette lines of sight, the
shape shared across the frames (Plänkers et al. 1999, Section 4; D'Apuzzo et al. 2000,
Fig. 17).

Unknowns
    per frame: the pelvis' position (3, mm) and the joint angles (radians; ``hold`` names
    joints kept at their start); shared by all frames: the limb scales ``s`` (the template's
    lengths times ``s``, :mod:`lsmta.body.full_body`) and a shape per limb (left and right
    share it), in two forms:

    * tied: one width, one depth and one length-radius factor for the limb's three balls
      (times the template's ball sizes and the radius along the bone, which
      :mod:`lsmta.body.metaballs` ties to the bone length);
    * free (Plänkers' full model, which frees each ball's size): a width and a depth factor
      per ball, the length-radius factor and a shift of the balls along the bone frame's y
      axis (mm; forward for an arm or a leg, backward for the trunk and head, up for a
      foot). No sideways shift: a limb's joints swing about the sideways axis in a walk,
      which does not show where along that axis they sit, so a sideways shift would trade
      freely with the shoulder and hip widths.
      Each free entry is drawn towards the tied solution by a prior (``size_prior``,
      ``offset_prior``): the points do not constrain every ball alike.

    The free shape starts from the tied solution. Its rounds use ``free_loss`` (the model
    then lies near the points, and a redescending loss lets far outliers go: with the
    soft-l1 loss of the tied rounds, outliers near the feet and hands blew those balls up
    and the fit ran off). Measured on the generated walk (notebook 20,
    ``experiments/full_body_walk.py``): with points all round the body the free shape
    brought the skin within 2 mm of the true body; with points from the front only it
    came closer too, but the back is never seen there and rests on the template's depths
    and the priors. ``free_rounds=0`` by default: each free round costs about as much as a
    tied one again.

Start from the data, no pose given
    The stature is the height above the floor (``z = floor``) of the highest point with
    ``min_neighbours`` others within ``neighbour_radius`` (lone outliers above the head do
    not count); it builds the template. Each frame's pelvis starts at the points' median
    (x, y) at the template's hip height, the body upright, limbs at rest (knees bent by
    ``knee_start``), facing the direction in which the points' median moves over the
    frames (the person walks forwards; with one frame, the heading must be given).
Stages, in ``n_rounds`` rounds with the tied shape, then ``free_rounds`` with the free one
    1. per frame, ``n_inner`` times: assign the points to their nearest segment, gate the
       lines of sight (closest approach within ``gate`` mm of the skin), solve the pose by
       robust least squares (analytic Jacobian; joint limits as bounds). Lines of sight
       join from round ``silhouette_from`` on (the start is too far from the outline
       before).
    2. the shape: limb scales and the shape over all frames' points at once, the poses
       held (forward differences, one residual call for a whole group of columns: a
       limb's shape moves only its own segments' points, so one entry of every limb's
       shape is stepped at once).
    The residuals are skin distances over ``sigma_point`` and closest approaches over
    ``sigma_silhouette`` (:mod:`lsmta.body.silhouette`); a weighted residual above
    ``outlier_k`` at the solution counts as an outlier.

Build starts (off by default: ``build_starts=()``)
    The rounds do not leave the valley of builds a start lies in: on the generated studio
    walk, with the generator's noise-free skin all round, the template's build stayed at a
    trunk 16 % short under a longer head, the shoulders set 11 % wider on upper arms 8 %
    long (median |skin distance| 2.95 mm), while started from the true joint centres the
    same fit kept those three within 3 % (2.41 mm; experiments/walk_full_fit_ladder.py, a
    controlled study). With ``build_starts`` (the caller's builds, each as factors of the
    start's limb scales) the first round also runs from each of those builds, and the round
    whose median |skin distance| of all frames' points is lowest goes on
    (:attr:`FullBodyFit.build` says which). This is the mechanism only, not a fit result:
    the only builds tried so far (``BUILDS`` of experiments/walk_full_fit_ladder.py) were
    read off the generator's true build after seeing that walk's rungs, so what they did
    is no evidence of what the fit finds alone. With them the fit on the generator's skin
    ended within 3.3 % of the true trunk, shoulder width and upper arm; on the LSMTA
    system's points of the same walk, and of seed 37 (the same body and walk; only the
    cameras' jitter, the texture and the noise differ), the shoulder width came right but
    the upper arm 10.4 and 11.5 % short, and an elbow flipped.

A shape from elsewhere
    ``shape`` (a :class:`BodyShape`, e.g. :meth:`FullBodyFit.body_shape` of a fit to a
    range-of-motion clip of the same person) replaces the stature measured from the points
    and the start of the limb scales and shape; with ``fit_shape=False`` they stay there
    (only the poses are solved).

A sequence (off by default: ``temporal_sigma=None``, ``warm_start=False``)
    The frames are taken as evenly spaced in time, in order. With ``warm_start`` the first
    round's solve of frame ``t > 0`` starts from frame ``t - 1``'s solved joint angles (its
    pelvis still at its own points' median) instead of the rest pose. With
    ``temporal_sigma`` (radians) each free joint angle gets the residuals
    ``(theta_t - theta_{t-1}) / temporal_sigma`` and ``(theta_t - theta_{t+1}) /
    temporal_sigma`` against its neighbouring frames' current solutions (only neighbours
    already solved: in the first round the previous frame only), under the same loss as the
    points. The rule for the value: a plausible largest angular speed of a joint times the
    frame spacing (:func:`lsmta.evaluation.walk_full_fit.fit_walk`: 8 rad/s, above the
    knee's swing peak in a walk, ~6 rad/s). A well-seen limb's thousand points outweigh
    it; a limb with a point or none in a frame rests on it, so it is drawn to its
    neighbours' angle (its prior residuals are then all it has) instead of flipping. No
    separate "hold the angle below k points" rule: the prior does that smoothly.

Bad frames (off by default; no truth: the fit's own residuals)
    A frame's cost is the 90th percentile of its points' |skin distance| (mm): a flipped
    limb carries a tenth or so of the points, which the median would not see. A warm
    start can carry a flip from one far-apart frame to the next (a range-of-motion clip).
    ``rest_start``: the first round also solves each frame from the rest pose; ``starts``
    (:func:`fit_full_body`): also from given poses (e.g. another fit of the same frames);
    of the solves the one with the lowest cost is kept. ``drop_k``: before each shape
    solve, the frames whose cost is above ``drop_k`` times the median cost are left out
    of it (their poses are still solved); :attr:`FullBodyFit.shape_frames` says which
    frames the last shape solve used.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from .._validate import as_array, as_int, as_scalar, freeze
from ._kernels import segment_distances
from .full_body import LIMBS, RATIOS, full_body_model, limits, template_size
from .metaballs import _ROOT_T, MetaballModel
from .silhouette import point_terms, silhouette_terms


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
        Rounds of (poses, tied shape); pose solves per frame and round.
    free_rounds : int
        Rounds of (poses, free shape) after those (module docstring; 0 with points from one
        side only).
    free_loss : str
        Loss of the free rounds. By then the model lies near the points, and a loss that
        redescends ("cauchy") lets far outliers go; from the start it would let the model
        go too.
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
    offset_bound : float
        Bound of the balls' shift along the bone frame's y axis (mm, either way).
    size_prior, offset_prior : float
        Standard deviations of the priors that draw the free shape's size factors and shift
        (mm) towards the tied solution.
    floor : float
        Height of the floor (mm).
    neighbour_radius, min_neighbours
        The top of the head (module docstring).
    knee_start : float
        Start of the knees (radians; inside their limits).
    hold : tuple of str
        Joints held at their start.
    temporal_sigma : float or None
        Standard deviation (radians) of a joint angle's change between neighbouring frames
        (module docstring, "A sequence"); None: no temporal prior.
    warm_start : bool
        Start each frame's first solve from the previous frame's angles.
    fit_shape : bool
        Solve the limb scales and shape after each round's poses (False: they stay at
        their start, e.g. a given :class:`BodyShape`).
    rest_start : bool
        With ``warm_start``: the first round also solves each frame from the rest pose and
        keeps the solve of the lower frame cost (module docstring, "Bad frames").
    drop_k : float or None
        Frames whose cost exceeds ``drop_k`` times the median of all frames' costs are left
        out of the shape solve (module docstring, "Bad frames"); None: none left out.
    build_starts : tuple of tuples of (str, float)
        Further builds of the first round (the caller's), each a non-empty tuple of (limb,
        factor of the start's limb scale) pairs, the factors within ``scale_bounds``
        (module docstring, "Build starts"; needs ``fit_shape``).
    """

    sigma_point: float = 3.0
    sigma_silhouette: float = 6.0
    loss: str = "soft_l1"
    outlier_k: float = 3.0
    n_rounds: int = 3
    free_rounds: int = 0
    free_loss: str = "cauchy"
    n_inner: int = 2
    silhouette_from: int = 1
    max_nfev: int = 25
    n_steps: int = 64
    depth_margin: float = 1200.0
    gate: float = 40.0
    scale_bounds: tuple = (0.7, 1.4)
    size_bounds: tuple = (0.5, 2.0)
    offset_bound: float = 50.0
    size_prior: float = 0.15
    offset_prior: float = 10.0
    floor: float = 0.0
    neighbour_radius: float = 30.0
    min_neighbours: int = 5
    knee_start: float = -0.1
    hold: tuple = ()
    temporal_sigma: float | None = None
    warm_start: bool = False
    fit_shape: bool = True
    rest_start: bool = False
    drop_k: float | None = None
    build_starts: tuple = ()

    def __post_init__(self):
        if self.temporal_sigma is not None:
            as_scalar(self.temporal_sigma, "temporal_sigma", positive=True)
        if self.drop_k is not None and as_scalar(self.drop_k, "drop_k", positive=True) <= 1:
            raise ValueError(f"drop_k: expected above 1 or None, got {self.drop_k}")
        for name in ("warm_start", "fit_shape", "rest_start"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name}: expected a bool, got "
                                f"{type(getattr(self, name)).__name__}")
        for name in ("n_rounds", "n_inner", "max_nfev", "min_neighbours"):
            as_int(getattr(self, name), name)
        as_int(self.free_rounds, "free_rounds", minimum=0)
        as_int(self.n_steps, "n_steps", minimum=3)
        for name in ("sigma_point", "sigma_silhouette", "outlier_k", "depth_margin", "gate",
                     "neighbour_radius", "offset_bound", "size_prior", "offset_prior"):
            as_scalar(getattr(self, name), name, positive=True)
        as_scalar(self.floor, "floor")
        for name in ("loss", "free_loss"):
            if getattr(self, name) not in ("linear", "soft_l1", "huber", "cauchy", "arctan"):
                raise ValueError(f"{name}: expected a least_squares loss name, got "
                                 f"{getattr(self, name)!r}")
        for name in ("scale_bounds", "size_bounds"):
            lo, hi = getattr(self, name)
            if not 0 < lo < 1 < hi:
                raise ValueError(f"{name}: expected (low, high) with 0 < low < 1 < high")
        _check_builds(self.build_starts, self.scale_bounds, self.fit_shape)


@dataclass(frozen=True, eq=False)
class BodyShape:
    """What :func:`fit_full_body` shares across frames: a person's build.

    Attributes
    ----------
    stature : float
        Builds the template (mm).
    scales : (L,) array
        Limb scales (:data:`~lsmta.body.full_body.LIMBS`).
    limb_shape : (L, 8) array
        Per limb: three balls' width and depth factors, the length-radius factor and the
        balls' shift (mm; module docstring).
    """

    stature: float
    scales: np.ndarray
    limb_shape: np.ndarray

    def __post_init__(self):
        L = len(LIMBS)
        object.__setattr__(self, "stature", as_scalar(self.stature, "stature", positive=True))
        object.__setattr__(self, "scales", as_array(self.scales, "scales", shape=(L,)).copy())
        object.__setattr__(self, "limb_shape",
                           as_array(self.limb_shape, "limb_shape", shape=(L, _SHAPE)).copy())
        freeze(self, ("scales", "limb_shape"))

    @classmethod
    def template(cls, stature: float) -> BodyShape:
        """The template's build for ``stature`` (mm): scales 1, the tied shape's start."""
        return cls(stature=stature, scales=np.ones(len(LIMBS)), limb_shape=_shape_start())


@dataclass(frozen=True, eq=False)
class FullBodyFit:
    """Result of :func:`fit_full_body`.

    Attributes
    ----------
    model : MetaballModel
        The template built for the measured stature, its balls shifted as fitted.
    stature : float
        Measured from the points (mm).
    angles : (T, J) array
        Joint angles (radians).
    base : (T, 4, 4) array
        The pelvis' translation per frame (mm).
    scales : (L,) array
        Limb scales (shared).
    size : (S, 2) array
        Width and depth of each segment's middle ball (mm, shared); ``radii`` holds every
        ball's.
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
    limb_shape : (L, 8) array or None
        The per-limb shape (:class:`BodyShape`).
    shape_frames : (T,) bool array or None
        The frames the last shape solve used (module docstring, "Bad frames"); None: no
        shape solved.
    build : int
        The first round's build that went on: 0 the start's, ``i + 1`` the start's times
        ``build_starts[i]`` (module docstring, "Build starts").
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
    limb_shape: np.ndarray | None = None
    shape_frames: np.ndarray | None = None
    build: int = 0

    def __post_init__(self):
        freeze(self, ("angles", "base", "scales", "size", "radii", "start_angles",
                      "start_base") + tuple(k for k in ("limb_shape", "shape_frames")
                                            if getattr(self, k) is not None))

    def body_shape(self) -> BodyShape:
        """The fitted build, to start or fix another fit of the same person."""
        if self.limb_shape is None:
            raise ValueError("limb_shape: this fit does not carry its per-limb shape")
        return BodyShape(stature=self.stature, scales=self.scales, limb_shape=self.limb_shape)


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

    def __init__(self, points, rays, camera_centre, params):
        self.pts, self.p = points, params
        if rays is None:
            self.origins = self.dirs = np.zeros((0, 3))
        else:
            self.origins, self.dirs = rays
        d = np.linalg.norm(np.median(points, axis=0) - camera_centre) if len(self.origins) \
            else params.depth_margin
        self.near = max(d - params.depth_margin, 0.0)
        self.far = d + params.depth_margin

    def sil(self, model, angles, base, scales, radii):
        return silhouette_terms(model, self.origins, self.dirs, angles, scales, radii,
                                near=self.near, far=self.far, base=base,
                                n_steps=self.p.n_steps)

    def solve(self, m, angles, base, scales, radii, free, bounds, use_rays, loss, near=()):
        """Assign, gate, solve; returns the new angles (1, J), base (1, 4, 4), nfev.
        ``near``: neighbouring frames' angles ``(J,)`` the temporal prior draws towards."""
        p = self.p
        seg = np.argmin(m.all_distances(self.pts, angles, scales, radii, base=base), axis=1)
        keep = np.zeros(len(self.origins), bool)
        if use_rays and len(self.origins):
            keep = np.abs(self.sil(m, angles, base, scales, radii).r) <= p.gate
        origins, dirs = self.origins[keep], self.dirs[keep]

        def unpack(x):
            a = angles.copy()
            a[0, free] = x[3:]
            return a, _translation(x[:3])[None]

        cache, n_free = {}, int(free.sum())

        def terms(x):
            key = x.tobytes()
            if key not in cache:
                a, b = unpack(x)
                r, d_th, d_t = point_terms(m, self.pts, seg, a, scales, radii, base=b)
                r = r / p.sigma_point
                jac = np.hstack([d_t, d_th[:, free]]) / p.sigma_point
                if len(origins):
                    s = silhouette_terms(m, origins, dirs, a, scales, radii, near=self.near,
                                         far=self.far, base=b, n_steps=p.n_steps)
                    r = np.concatenate([r, s.r / p.sigma_silhouette])
                    jac = np.vstack([jac, np.hstack([s.d_translation, s.d_angles[:, free]])
                                     / p.sigma_silhouette])
                if len(near):
                    eye = np.hstack([np.zeros((n_free, 3)), np.eye(n_free)])
                    r = np.concatenate([r, *[(x[3:] - q[free]) / p.temporal_sigma
                                             for q in near]])
                    jac = np.vstack([jac, *[eye / p.temporal_sigma] * len(near)])
                cache.clear()
                cache[key] = (r, jac)
            return cache[key]

        x0 = np.concatenate([base[0, :3, 3], angles[0, free]])
        lo = np.concatenate([np.full(3, -np.inf), bounds[free, 0]])
        hi = np.concatenate([np.full(3, np.inf), bounds[free, 1]])
        sol = least_squares(lambda x: terms(x)[0], np.clip(x0, lo, hi),
                            jac=lambda x: terms(x)[1], bounds=(lo, hi), loss=loss,
                            max_nfev=int(p.max_nfev), x_scale="jac")
        a, b = unpack(sol.x)
        return a, b, int(sol.nfev)


def _check_builds(builds, bounds, fit_shape):
    """Refuse ``FullBodyFitParams.build_starts`` other than a tuple of non-empty tuples of
    (limb name, finite factor within ``bounds``) pairs; any with ``fit_shape`` False."""
    lo, hi = bounds
    msg = ("build_starts: expected a tuple of builds, each a non-empty tuple of (limb name, "
           f"finite factor within scale_bounds {lo:g}..{hi:g}) pairs with limb names of "
           f"{LIMBS}")
    if not isinstance(builds, tuple):
        raise ValueError(f"{msg}; got {builds!r}")
    for b in builds:
        if not isinstance(b, tuple) or not b or not all(
                isinstance(e, tuple) and len(e) == 2 and e[0] in LIMBS
                and isinstance(e[1], numbers.Real) and not isinstance(e[1], (bool, np.bool_))
                and np.isfinite(e[1]) and lo <= e[1] <= hi for e in b):
            raise ValueError(f"{msg}; got {b!r}")
    if builds and not fit_shape:
        raise ValueError("build_starts: expected () with fit_shape=False (the builds are "
                         "limb scales the shape solve starts from)")


_SHAPE = 8          # per limb: 3 balls x (width, depth) factors, length-radius factor, shift


def _shaped(model, template, scales, shape):
    """The model with its balls shifted, and radii ``(S, 3, 3)``, from the limb scales and
    the per-limb ``shape (L, 8)`` (module docstring)."""
    rows = shape[_limb_rows(model)]
    radii = model.simplified_radii(template, scales)
    radii[..., :2] *= rows[:, :6].reshape(-1, 3, 2)
    radii[..., 2] *= rows[:, 6:7]
    shift = np.zeros((model.n_segments, 3, 2))
    shift[..., 1] = rows[:, 7:8]
    return model.with_offsets(shift), radii


def _limb_rows(model):
    return np.array([s.limb for s in model.segments])


def _shape_start():
    shape = np.ones((len(LIMBS), _SHAPE))
    shape[:, 7] = 0.0
    return shape


# the tied shape: one width, one depth and one length factor per limb for all three balls
_TIED = np.zeros((3, _SHAPE))
_TIED[0, 0:6:2] = _TIED[1, 1:6:2] = _TIED[2, 6] = 1.0


def _solve_shape(model, frames, angles, base, scales, shape, template, p, *, loss, prior=None):
    """Limb scales and shapes ``(L, 8)`` over all frames' points, poses held; with a
    ``prior (L, 8)`` (the tied solution) every entry of the shape, drawn towards it; else
    the tied shape."""
    L = len(scales)
    free = prior is not None
    basis = np.eye(_SHAPE) if free else _TIED
    q = len(basis)
    keep = shape * (basis.sum(axis=0) == 0)             # entries this stage leaves alone
    k0 = shape @ basis.T / basis.sum(axis=1)
    m, radii = _shaped(model, template, scales, shape)
    segs = [np.argmin(m.all_distances(f.pts, angles[[t]], scales, radii, base=base[[t]]), axis=1)
            for t, f in enumerate(frames)]
    limb_of_point = np.concatenate([_limb_rows(model)[seg] for seg in segs])
    sparsity = np.hstack([np.ones((len(limb_of_point), L), bool),
                          np.repeat(limb_of_point[:, None] == np.arange(L), q, axis=1)])
    if free:
        prior_sigma = np.r_[np.full(_SHAPE - 1, p.size_prior), p.offset_prior]
        sparsity = np.vstack([sparsity, np.hstack([np.zeros((L * q, L), bool),
                                                   np.eye(L * q, dtype=bool)])])

    # every frame's points in one call (each point in its own frame)
    all_pts, all_seg = np.vstack([f.pts for f in frames]), np.concatenate(segs).astype(np.int64)
    all_frame = np.concatenate([np.full(len(f.pts), t, np.int64) for t, f in enumerate(frames)])

    def residual(x):
        s, k = x[:L], x[L:].reshape(L, q)
        m, radii = _shaped(model, template, s, k @ basis + keep)
        # MetaballModel.distance without its argument checks (done once above)
        r = [segment_distances(all_pts, all_seg, all_frame, m.frames(angles, s, base=base),
                               m.centres(s), radii, _ROOT_T) / p.sigma_point]
        if free:
            r.append(((k - prior) / prior_sigma).ravel())
        return np.concatenate(r)

    sizes = basis[:, :_SHAPE - 1].any(axis=1)
    lo_k = np.where(sizes, p.size_bounds[0], -p.offset_bound)
    hi_k = np.where(sizes, p.size_bounds[1], p.offset_bound)
    lo = np.r_[np.full(L, p.scale_bounds[0]), np.tile(lo_k, L)]
    hi = np.r_[np.full(L, p.scale_bounds[1]), np.tile(hi_k, L)]
    groups = [np.array([j]) for j in range(L)] + [L + j + q * np.arange(L) for j in range(q)]
    sol = least_squares(residual, np.clip(np.r_[scales, k0.ravel()], lo, hi), bounds=(lo, hi),
                        jac=lambda x: _grouped_jacobian(residual, x, groups, sparsity, hi),
                        loss=loss, max_nfev=int(p.max_nfev),
                        x_scale=np.r_[np.ones(L), np.tile(np.where(sizes, 1.0, 10.0), L)])
    return sol.x[:L], sol.x[L:].reshape(L, q) @ basis + keep, int(sol.nfev)


def _grouped_jacobian(residual, x, groups, sparsity, upper):
    """Forward differences, one residual call per group of columns that share no row of
    ``sparsity`` (dense result; steps turned back at the upper bounds)."""
    r0 = residual(x)
    J = np.zeros((len(r0), len(x)))
    h = 1e-6 * np.maximum(1.0, np.abs(x))
    h = np.where(x + h > upper, -h, h)
    for g in groups:
        dx = np.zeros_like(x)
        dx[g] = h[g]
        diff = residual(x + dx) - r0
        for j in g:
            rows = sparsity[:, j]
            J[rows, j] = diff[rows] / h[j]
    return J


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
                  shape: BodyShape | None = None, starts=(),
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
    shape : BodyShape, optional
        The stature and the start of the limb scales and shape (module docstring, "A shape
        from elsewhere"); by default the stature is measured and the shape starts at the
        template's.
    starts : sequence of (angles (T, J), base (T, 4, 4)), optional
        Further starts of each frame's first-round solve, e.g. another fit's poses of the
        same frames (module docstring, "Bad frames").
    params : FullBodyFitParams, optional
    """
    p = FullBodyFitParams() if params is None else params
    if not isinstance(p, FullBodyFitParams):
        raise TypeError(f"params: expected FullBodyFitParams, got {type(p).__name__}")
    if shape is not None and not isinstance(shape, BodyShape):
        raise TypeError(f"shape: expected a BodyShape or None, got {type(shape).__name__}")
    pts, rays, centre = _check(points, rays, camera_centre)
    stature = shape.stature if shape is not None else measure_stature(
        np.vstack(pts), floor=p.floor, radius=p.neighbour_radius,
        min_neighbours=p.min_neighbours)
    model = full_body_model(stature=stature)
    starts = _check_starts(starts, len(pts), model.skeleton.n_joints)
    angles, base = body_start(model, pts, stature=stature, heading=heading,
                              knee_start=p.knee_start)
    start_angles, start_base = angles.copy(), base.copy()
    frames = [_Frame(x, r, centre, p) for x, r in zip(pts, rays)]
    template = template_size(model, stature=stature)
    if shape is None:
        scales, shape = np.ones(len(LIMBS)), _shape_start()
    else:
        scales, shape = shape.scales.copy(), shape.limb_shape.copy()
    bounds = limits(model)
    bounds[[model.skeleton.names.index(n) for n in ("pelvis_b", "pelvis_a", "pelvis_c")]] = \
        [-np.inf, np.inf]
    free = ~np.isin(model.skeleton.names, p.hold)
    nfev, tied, used, build = 0, None, None, 0
    how = (model, frames, template, (start_angles, start_base), starts, free, bounds, p)
    for k in range(int(p.n_rounds) + int(p.free_rounds)):
        if k == p.n_rounds:
            tied = shape.copy()
        builds = [scales] + ([scales * _build_factors(b) for b in p.build_starts]
                             if k == 0 and p.fit_shape
                             else [])
        best = None
        for i, s in enumerate(builds):
            out = _round(k, angles.copy(), base.copy(), s, shape, tied, how)
            nfev += out[-1]
            c = _cost(model, frames, template, *out[:4]) if len(builds) > 1 else 0.0
            if best is None or c < best[0]:
                best = (c, out, i)
        angles, base, scales, shape, used = best[1][:5]
        build = best[2] if k == 0 else build
    fitted, radii = _shaped(model, template, scales, shape)
    return replace(_finish(fitted, frames, stature, angles, base, scales, radii, start_angles,
                           start_base, nfev, p), limb_shape=shape, shape_frames=used,
                   build=build)


def _round(k, angles, base, scales, shape, tied, how):
    """Round ``k`` of :func:`fit_full_body` from ``angles``, ``base`` (changed in place),
    ``scales`` and ``shape``: every frame's pose, then the shape; returns angles, base,
    scales, shape, the frames of the shape solve and nfev."""
    model, frames, template, (start_angles, start_base), starts, free, bounds, p = how
    m, radii = _shaped(model, template, scales, shape)
    loss = p.loss if k < p.n_rounds else p.free_loss
    nfev, used = 0, None
    for t, f in enumerate(frames):
        if k == 0 and t > 0 and p.warm_start:
            angles[t] = angles[t - 1]
        others = [] if k else (
            [(start_angles[t], start_base[t])] * (p.rest_start and p.warm_start and t > 0)
            + [(a[t], b[t]) for a, b in starts])
        angles[t], base[t], n = _solve_frame(
            f, m, [(angles[t], base[t])] + others, scales, radii, free, bounds,
            (k >= p.silhouette_from, loss, _neighbours(angles, t, k, p)))
        nfev += n
    if p.fit_shape:
        used = _shape_frames(m, frames, angles, base, scales, radii, p.drop_k)
        i = np.flatnonzero(used)
        scales, shape, n = _solve_shape(model, [frames[j] for j in i], angles[i], base[i],
                                        scales, shape, template, p, loss=loss, prior=tied)
        nfev += n
    return angles, base, scales, shape, used, nfev


def _build_factors(build) -> np.ndarray:
    """``(L,)`` limb-scale factors of one of ``FullBodyFitParams.build_starts``."""
    out = np.ones(len(LIMBS))
    for name, factor in build:
        out[LIMBS.index(name)] = factor
    return out


def _cost(model, frames, template, angles, base, scales, shape) -> float:
    """The median |skin distance| (mm) of all frames' points: what picks a build start."""
    m, radii = _shaped(model, template, scales, shape)
    return float(np.median(np.abs(np.concatenate([
        _skin_distance(m, f.pts, angles[t], scales, radii, base[t])
        for t, f in enumerate(frames)]))))


def _skin_distance(model, points, angles, scales, radii, base) -> np.ndarray:
    """``(N,)`` signed distance (mm) of ``points (N, 3)`` to their nearest segment's skin at
    ``angles (J,)``, ``base (4, 4)``."""
    d = model.all_distances(points, angles[None], scales, radii, base=base[None])
    return d[np.arange(len(d)), np.argmin(np.abs(d), axis=1)]


def _check_starts(starts, T, J):
    out = []
    for i, s in enumerate(starts):
        if len(s) != 2:
            raise ValueError(f"starts[{i}]: expected (angles (T, J), base (T, 4, 4))")
        a = as_array(s[0], f"starts[{i}][0]", shape=(T, J))
        out.append((a, as_array(s[1], f"starts[{i}][1]", shape=(T, 4, 4))))
    return out


def frame_cost(model, points, angles, scales, radii, *, base) -> float:
    """A frame's cost (module docstring, "Bad frames"): the 90th percentile of the
    |skin distance| of ``points (N, 3)`` (mm) at ``angles (J,)``, ``base (4, 4)``."""
    return float(np.percentile(np.abs(_skin_distance(model, points, angles, scales, radii,
                                                     base)), 90))


def _solve_frame(f, m, cands, scales, radii, free, bounds, how):
    """Solve one frame ``n_inner`` times from each of ``cands`` ((angles, base) pairs);
    keep the lowest :func:`frame_cost` (the only one without a choice)."""
    best, nfev = None, 0
    for a, b in cands:
        a, b = a[None].copy(), b[None].copy()
        for _ in range(int(f.p.n_inner)):
            a, b, n = f.solve(m, a, b, scales, radii, free, bounds, *how)
            nfev += n
        c = frame_cost(m, f.pts, a[0], scales, radii, base=b[0]) if len(cands) > 1 else 0.0
        if best is None or c < best[0]:
            best = (c, a[0], b[0])
    return best[1], best[2], nfev


def _shape_frames(m, frames, angles, base, scales, radii, drop_k):
    """(T,) bool: the frames the shape solve uses (module docstring, "Bad frames")."""
    if drop_k is None:
        return np.ones(len(frames), bool)
    cost = np.array([frame_cost(m, f.pts, angles[t], scales, radii, base=base[t])
                     for t, f in enumerate(frames)])
    return cost <= drop_k * np.median(cost)


def _neighbours(angles, t, k, p):
    """The solved neighbours of frame ``t`` in round ``k`` the temporal prior draws
    towards (module docstring)."""
    if p.temporal_sigma is None:
        return []
    ts = [t - 1] + ([t + 1] if k > 0 else [])
    return [angles[u].copy() for u in ts if 0 <= u < len(angles)]


def _finish(model, frames, stature, angles, base, scales, radii, start_angles, start_base,
            nfev, p) -> FullBodyFit:
    r_p, r_s = [], []
    for t, f in enumerate(frames):
        r_p.append(_skin_distance(model, f.pts, angles[t], scales, radii, base[t]))
        r_s.append(f.sil(model, angles[[t]], base[[t]], scales, radii).r if len(f.origins)
                   else np.zeros(0))
    size = radii[:, 1, :2]
    return FullBodyFit(
        model=model, stature=stature, angles=angles, base=base, scales=scales, size=size,
        radii=radii, start_angles=start_angles, start_base=start_base,
        point_residuals=tuple(r_p), silhouette_residuals=tuple(r_s),
        n_point_outliers=int(sum((np.abs(r) > p.outlier_k * p.sigma_point).sum() for r in r_p)),
        n_silhouette_outliers=int(sum((np.abs(r) > p.outlier_k * p.sigma_silhouette).sum()
                                      for r in r_s)),
        nfev=nfev)
