"""The full-body model fitted to the LSMTA system's own points over the walk (issue 36, item
3), scored against the generator after the fact.

:func:`fit_walk` takes only a :class:`~lsmta.systems.BodyCapture`: every ``every``-th
processed frame's filtered points (:meth:`~lsmta.systems.BodyCapture.points_at`, the
system's own world: the tape-measured floor at ``z = 0``, up levelled with the upright bar)
go into :func:`lsmta.body.full_fit.fit_full_body`, shape shared, pose per frame, by default
as a sequence: each frame warm-started from the previous one and its joint angles drawn
towards its neighbours' by a plausible angular speed (``angular_speed``; without it a
forearm that carries a point or none in a frame flipped). No generator point, camera or
pose goes in.

:func:`aligned_fit` then carries the fit into the true world by the rigid motion of
:func:`~lsmta.evaluation.walk_system.check_alignment` (held-out bar targets, no scale): the
pelvis' base of every frame is moved, the joint angles and shape are untouched. And
:func:`score_walk_fit` scores it with :mod:`lsmta.evaluation.full_body`: each major joint's
angle per frame, the segment lengths, and the skin both ways on the seen side (true skin
samples seen by two cameras of one view group of the capture; the fitted skin's outer
vertices whose nearest true sample is such a one), beside the same distances all round.
:func:`verdicts` compares them with issue 36's targets.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_array, as_int, as_scalar
from ..body.full_fit import (
    BodyShape,
    FullBodyFit,
    FullBodyFitParams,
    fit_full_body,
    measure_stature,
)
from ..body.skin import SkinParams, merge_patches, model_skin
from ..synth.body import inside_parts
from ..synth.render import project_surface_points
from ..synth.surface import distance_to_body
from .body_system import Alignment
from .full_body import MAJOR, joint_angle_errors, length_errors

# rad/s: a plausible largest joint angular speed in a walk (the knee's swing peak is ~6)
ANGULAR_SPEED = 8.0

# fit_rom: a clip frame whose cost (90th percentile |skin distance|) is above this many times
# the clip's median cost is left out of the shared-shape solve (fixed before any run)
ROM_DROP_K = 2.0

# issue 36: (every major joint in every frame, deg; segment lengths, %; skin median, mm)
TARGETS = {"triplet": (5.0, 3.0, 3.0), "studio": (3.0, 2.0, 2.0)}


@dataclass(frozen=True, eq=False)
class WalkFit:
    """The full body fitted to a capture's points.

    Attributes
    ----------
    fit : FullBodyFit
        In the system's world.
    processed : (T,) int array
        The capture's processed frames fitted (indices into ``capture.frames``).
    frames : (T,) int array
        The same as frames of the input videos.
    n_points : (T,) int array
        The system's points per fitted frame (after ``max_points``).
    seconds : float
        Wall time of the fit.
    """

    fit: FullBodyFit
    processed: np.ndarray
    frames: np.ndarray
    n_points: np.ndarray
    seconds: float


def fit_walk(capture, *, every: int = 1, first: int = 0, last: int | None = None,
             max_points: int | None = None, angular_speed: float | None = ANGULAR_SPEED,
             shape: BodyShape | None = None, heading: float | None = None,
             starts: tuple = (), params: FullBodyFitParams | None = None) -> WalkFit:
    """Fit the full body to the system's points of every ``every``-th processed frame from
    ``first`` up to ``last`` (exclusive; default all) of ``capture``.

    Parameters
    ----------
    capture : BodyCapture
        Of the walk (:func:`lsmta.systems.capture_walk`).
    every, first, last : int
        Processed frames fitted: ``range(first, last, every)``; at least two (the heading
        comes from the points' motion).
    max_points : int, optional
        At most this many points per frame, evenly spaced in the capture's order (the
        fit's time grows with the points; default all).
    angular_speed : float or None
        A plausible largest joint angular speed (rad/s; default 8, above the knee's swing
        peak in a walk, ~6 rad/s). The fit then runs as a sequence (:mod:`lsmta.body.
        full_fit`, "A sequence"): ``warm_start`` and ``temporal_sigma`` = this times the
        median spacing of the fitted frames (``capture.fps``), overriding ``params``'.
        None: ``params`` as given (each frame from the rest pose, no temporal prior).
    shape : BodyShape, optional
        The build to start from (or, with ``params.fit_shape`` False, to keep), e.g.
        :func:`fit_rom`'s; by default measured from these points.
    heading : float, optional
        The direction the person faces (radians from +x, the system's world); by default
        the direction the points move in.
    starts : sequence of (angles, base), optional
        Further starts of each frame's first solve (:func:`~lsmta.body.full_fit.
        fit_full_body`), e.g. ``(fit.angles, fit.base)`` of the walk-alone fit of the same
        frames: each frame keeps the solve of the lower cost, so a start from another build
        cannot flip a limb the other fit had right.
    params : FullBodyFitParams, optional
        ``floor`` is the system world's floor height (0: the tape-measured world's).
    """
    T = len(capture.frames)
    every = as_int(every, "every", minimum=1)
    first = as_int(first, "first", minimum=0)
    last = T if last is None else as_int(last, "last", minimum=0)
    processed = np.arange(first, min(last, T), every)
    if len(processed) < 2:
        raise ValueError(f"every, first, last: select at least 2 of the {T} processed frames "
                         f"(got {len(processed)})")
    points = [capture.points_at(int(t))[0] for t in processed]
    if max_points is not None:
        n = as_int(max_points, "max_points", minimum=10)
        points = [p[np.unique(np.linspace(0, len(p) - 1, n).astype(int))] if len(p) > n else p
                  for p in points]
    p = FullBodyFitParams() if params is None else params
    if not isinstance(p, FullBodyFitParams):
        raise TypeError(f"params: expected FullBodyFitParams, got {type(p).__name__}")
    if angular_speed is not None:
        p = sequence_params(p, np.asarray(capture.frames)[processed], capture.fps,
                            angular_speed=angular_speed)
    if heading is not None:
        heading = as_scalar(heading, "heading")
    t0 = time.perf_counter()
    fit = fit_full_body(points, heading=heading, shape=shape, starts=starts, params=p)
    return WalkFit(fit=fit, processed=processed,
                   frames=np.asarray(capture.frames)[processed],
                   n_points=np.array([len(p) for p in points]),
                   seconds=time.perf_counter() - t0)


def sequence_params(params: FullBodyFitParams, frames, fps: float, *,
                    angular_speed: float = ANGULAR_SPEED) -> FullBodyFitParams:
    """:func:`fit_walk`'s sequence settings: ``params`` with each frame warm-started from
    the previous one and the temporal prior's ``temporal_sigma`` = ``angular_speed``
    (rad/s) times the median step of ``frames (T,)`` (the walk's frame numbers) at ``fps``
    (frames/s)."""
    if not isinstance(params, FullBodyFitParams):
        raise TypeError(f"params: expected FullBodyFitParams, got {type(params).__name__}")
    frames = as_array(frames, "frames", shape=(None,))
    if len(frames) < 2:
        raise ValueError(f"frames: expected at least 2 frame numbers, got {len(frames)}")
    speed = as_scalar(angular_speed, "angular_speed", positive=True)
    dt = float(np.median(np.diff(frames))) / as_scalar(fps, "fps", positive=True)
    return replace(params, temporal_sigma=speed * dt, warm_start=True)


@dataclass(frozen=True, eq=False)
class RomFit:
    """The full body fitted to a range-of-motion clip's capture (:func:`fit_rom`).

    Attributes
    ----------
    walk_fit : WalkFit
        The fit over the clip's processed frames (its ``fit.body_shape()`` starts the walk).
    heading : float
        The direction the person was found to face (radians from +x, the system's world;
        :func:`rom_heading`).
    statures : (T,) array
        Each processed frame's stature measurement (mm); their median builds the template.
    """

    walk_fit: WalkFit
    heading: float
    statures: np.ndarray


def rom_heading(points, *, stature: float, floor: float = 0.0) -> float:
    """The direction (radians from +x) a person standing still faces, from the points of
    frames of them ``points`` (sequence of ``(N_t, 3)``): across the widest horizontal axis
    of the first frame's points (the shoulders and hips are wider than deep), the way the
    feet point: the side on which the points below the ankles (``z - floor < 0.045
    stature``) lie, summed over the frames, against those of the shanks (0.10-0.25
    stature)."""
    stature = as_scalar(stature, "stature", positive=True)
    floor = as_scalar(floor, "floor")
    if len(points) == 0:
        raise ValueError("points: expected a non-empty sequence of (N, 3) arrays, got none")
    points = [as_array(p, f"points[{t}]", shape=(None, 3), allow_nan=True)
              for t, p in enumerate(points)]
    first = points[0]
    xy = first[:, :2] - first[:, :2].mean(axis=0)
    _, vecs = np.linalg.eigh(xy.T @ xy)
    ahead = np.array([vecs[1, -1], -vecs[0, -1]])           # the wide axis turned by -90 deg
    toe = np.zeros(2)
    for p in points:
        h = (p[:, 2] - floor) / stature
        low, mid = p[h < 0.045, :2], p[(h > 0.10) & (h < 0.25), :2]
        if len(low) >= 5 and len(mid) >= 5:
            toe += low.mean(axis=0) - mid.mean(axis=0)
    if not toe.any():
        raise ValueError("points: no frame shows both the feet and the shanks")
    if toe @ ahead < 0:
        ahead = -ahead
    return float(np.arctan2(ahead[1], ahead[0]))


def fit_rom(capture, *, max_points: int | None = None, shape: BodyShape | None = None,
            rest_start: bool = True, drop_k: float | None = ROM_DROP_K,
            params: FullBodyFitParams | None = None) -> RomFit:
    """Fit the full body over a range-of-motion clip's capture: the build from the system's
    points of movements that show the joint centres (issue 36, item 2).

    No pose or heading is given, and by default no build: the template's stature is then
    the median of the frames' stature measurements (a raised arm or a bend moves a frame's
    highest point; most frames stand upright); the clip starts standing still, so the
    heading comes from the first frame's points and the feet (:func:`rom_heading`); then every
    frame is fitted as a sequence (each warm-started from the previous, no temporal prior:
    the clip's frames are far apart), the build shared. A warm start can carry a flipped
    limb into the next extreme, so by default each frame is also solved from the rest pose
    and keeps the lower cost, and the frames still fitted badly are left out of the shape
    solve (:mod:`lsmta.body.full_fit`, "Bad frames"; the fit's own residuals, no truth).

    Parameters
    ----------
    capture : BodyCapture
        Of the clip (e.g. :func:`lsmta.systems.capture_recording` with the walk's
        calibration).
    max_points : int, optional
        As :func:`fit_walk`.
    shape : BodyShape, optional
        A build to start from (its stature builds the template), e.g. the system's own
        walk fit's: the clip's far-apart frames then start nearer the person.
    rest_start : bool
        Also solve each frame from the rest pose (``FullBodyFitParams.rest_start``).
    drop_k : float or None
        ``FullBodyFitParams.drop_k`` (default :data:`ROM_DROP_K`, 2, fixed before any run);
        None: every frame in the shape solve.
    params : FullBodyFitParams, optional
        Its ``warm_start``, ``rest_start`` and ``drop_k`` are set, ``temporal_sigma``
        cleared.
    """
    p = FullBodyFitParams() if params is None else params
    if not isinstance(p, FullBodyFitParams):
        raise TypeError(f"params: expected FullBodyFitParams, got {type(p).__name__}")
    T = len(capture.frames)
    if T < 2:
        raise ValueError(f"capture: expected at least 2 processed frames, got {T}")
    statures = []
    for t in range(T):
        try:
            statures.append(measure_stature(capture.points_at(t)[0], floor=p.floor,
                                            radius=p.neighbour_radius,
                                            min_neighbours=p.min_neighbours))
        except ValueError:
            statures.append(np.nan)
    statures = np.array(statures)
    if not np.isfinite(statures).any():
        raise ValueError("capture: no frame's points give a stature")
    if shape is not None and not isinstance(shape, BodyShape):
        raise TypeError(f"shape: expected a BodyShape or None, got {type(shape).__name__}")
    start = shape or BodyShape.template(float(np.nanmedian(statures)))
    heading = rom_heading([capture.points_at(t)[0] for t in range(T)],
                          stature=start.stature, floor=p.floor)
    wf = fit_walk(capture, max_points=max_points, angular_speed=None, shape=start,
                  heading=heading, params=replace(p, warm_start=True, temporal_sigma=None,
                                                  rest_start=rest_start, drop_k=drop_k))
    return RomFit(walk_fit=wf, heading=heading, statures=statures)


def aligned_fit(fit: FullBodyFit, alignment: Alignment) -> FullBodyFit:
    """The fit carried into the true world: every frame's base (and start base) moved by
    ``alignment`` (``x_true = R x + t``); angles, scales and shape unchanged."""
    if not isinstance(fit, FullBodyFit):
        raise TypeError(f"fit: expected a FullBodyFit, got {type(fit).__name__}")
    if not isinstance(alignment, Alignment):
        raise TypeError(f"alignment: expected an Alignment, got {type(alignment).__name__}")
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = alignment.R, alignment.t
    return replace(fit, base=A @ fit.base, start_base=A @ fit.start_base)


@dataclass(frozen=True, eq=False)
class WalkFitScore:
    """A fit (in the true world) against the generator.

    Attributes
    ----------
    frames : (T,) int array
        Frames of the walk.
    joints_deg : dict of str -> (T,) array
        Angle error per major joint and frame, and the pelvis' orientation
        (:func:`~lsmta.evaluation.full_body.joint_angle_errors`).
    lengths : dict of str -> (fitted, true)
        mm (:func:`~lsmta.evaluation.full_body.length_errors`).
    skin_to_truth, skin_from_truth : list of (V_t,), (S_t,) arrays
        Seen side, mm (module docstring).
    skin_to_truth_all, skin_from_truth_all : list of arrays
        The same all round.
    open_edges : (T,) int array
        Of each frame's merged skin.
    """

    frames: np.ndarray
    joints_deg: dict
    lengths: dict
    skin_to_truth: list
    skin_from_truth: list
    skin_to_truth_all: list
    skin_from_truth_all: list
    open_edges: np.ndarray

    def length_pct(self) -> dict:
        """Signed length errors, % of the true length."""
        return {k: 100.0 * (a / b - 1.0) for k, (a, b) in self.lengths.items()}

    def summary(self) -> dict:
        """The headline numbers: worst major joint (deg, and which), worst length (%, and
        which), skin medians over all frames (mm)."""
        major = {k: _worst(v) for k, v in self.joints_deg.items() if k in MAJOR}
        worst = max(major, key=major.get)
        pct = self.length_pct()
        wl = max(pct, key=lambda k: abs(pct[k]))

        def med(a):
            a = np.concatenate(a) if a else np.empty(0)
            return float(np.median(a)) if a.size else float("nan")

        return {"worst_joint_deg": major[worst], "worst_joint": worst,
                "worst_length_pct": float(abs(pct[wl])), "worst_length": wl,
                "skin_to_truth_mm": med(self.skin_to_truth),
                "skin_from_truth_mm": med(self.skin_from_truth),
                "skin_to_truth_all_mm": med(self.skin_to_truth_all),
                "skin_from_truth_all_mm": med(self.skin_from_truth_all)}


def seen_samples(session, groups, frames, *, n_per_part: int = 300, rng=None) -> list:
    """True outer skin samples of ``frames`` of ``session``'s walk (truth): per frame the
    world points ``(N_t, 3)`` (mm) and whether two cameras of one of ``groups`` (camera
    indices) see each, ``(N_t,)`` bool; ``n_per_part`` samples per part before the outer
    and seen tests, drawn by ``rng``."""
    n_per_part = as_int(n_per_part, "n_per_part", minimum=1)
    frames = np.asarray(frames, int).ravel()
    if not isinstance(groups, (list, tuple)) or not groups:
        raise ValueError("groups: expected a non-empty list of view groups (camera indices)")
    n_cam = len(session.cameras)
    groups = [np.asarray(g, int).ravel() for g in groups]
    for i, g in enumerate(groups):
        if len(g) < 2 or g.min() < 0 or g.max() >= n_cam:
            raise ValueError(f"groups[{i}]: expected at least 2 camera indices in 0..{n_cam - 1}, "
                             f"got {g.tolist()}")
    body, motion = session.scene.body, session.scene.motion
    part, local = body.sample_surface(n_per_part=n_per_part, rng=rng)
    proj = project_surface_points(session.scene, session.cameras, part, local, frames=frames)
    poses = body.part_poses(motion, frames=frames)
    out = []
    for i in range(len(frames)):
        seen = np.zeros(len(part), bool)
        for g in groups:
            seen |= proj.visible[i][g].sum(axis=0) >= 2
        outer = ~inside_parts(body, poses[i], proj.world[i], exclude=part)
        out.append((proj.world[i][outer], seen[outer]))
    return out


def _skin(fit, t):
    """Frame ``t``'s skin: merged mesh, outer vertices ``(V, 3)``."""
    m = fit.model
    patches = model_skin(m, fit.angles[[t]], fit.scales, fit.radii, base=fit.base[[t]],
                         params=SkinParams(n_u=36, n_v=28))
    v = np.vstack([p.vertices for p in patches])
    seg = np.concatenate([np.full(len(p.vertices), k) for k, p in enumerate(patches)])
    d = m.all_distances(v, fit.angles[[t]], fit.scales, fit.radii, base=fit.base[[t]])
    d[np.arange(len(v)), seg] = np.inf
    return merge_patches(patches), v[d.min(axis=1) >= 0]


def score_walk_fit(fit: FullBodyFit, session, frames, groups, *, n_per_part: int = 300,
                   rng=None) -> WalkFitScore:
    """Score a fit already in the true world (:func:`aligned_fit`) against the generator.

    Parameters
    ----------
    fit : FullBodyFit
    session : WalkSession
        The truth (scene, true cameras).
    frames : (T,) int array
        The walk's frame of each of the fit's frames.
    groups : sequence of sequences of int
        The capture's view groups (camera indices): the seen side is seen by two cameras
        of one group.
    n_per_part : int
        True skin samples per part and frame.
    rng : numpy.random.Generator, int or None
        Draws the skin samples.
    """
    frames = np.asarray(frames, int).ravel()
    if len(frames) != len(fit.angles):
        raise ValueError(f"frames: expected {len(fit.angles)} frames (the fit's), got "
                         f"{len(frames)}")
    n_per_part = as_int(n_per_part, "n_per_part", minimum=1)
    body, motion = session.scene.body, session.scene.motion
    groups = [np.asarray(g, int) for g in groups]
    samples = seen_samples(session, groups, frames, n_per_part=n_per_part, rng=rng)
    poses = body.part_poses(motion, frames=frames)
    out = {k: [] for k in ("skin_to_truth", "skin_from_truth", "skin_to_truth_all",
                           "skin_from_truth_all")}
    edges = []
    for t, (world, seen) in enumerate(samples):
        mesh, v = _skin(fit, t)
        to = np.abs(distance_to_body(body, poses[t], v))
        _, near = cKDTree(world).query(v)
        _, closest = mesh.find_closest_cell(world, return_closest_point=True)
        fr = np.linalg.norm(world - closest, axis=1)
        out["skin_to_truth"].append(to[seen[near]])
        out["skin_from_truth"].append(fr[seen])
        out["skin_to_truth_all"].append(to)
        out["skin_from_truth_all"].append(fr)
        edges.append(int(mesh.n_open_edges))
    joints = joint_angle_errors(fit, body, motion, frames)
    return WalkFitScore(frames=frames, joints_deg=joints, lengths=length_errors(fit, body),
                        open_edges=np.array(edges), **out)


def _worst(errors) -> float:
    """The largest error over the frames; a frame without one (NaN) counts as failed (inf)."""
    return float(np.nan_to_num(np.asarray(errors, float), nan=np.inf, posinf=np.inf).max())


def verdicts(score: WalkFitScore, rig: str) -> dict:
    """Issue 36's targets for ``rig`` ("triplet" or "studio") against ``score``: per target
    the value, the limit and whether it is met, and the joints / lengths that fail."""
    if rig not in TARGETS:
        raise ValueError(f"rig: expected one of {tuple(TARGETS)}, got {rig!r}")
    s = score.summary()
    worst = {k: _worst(v) for k, v in score.joints_deg.items() if k in MAJOR}
    return target_verdicts(worst, score.length_pct(), s["skin_to_truth_mm"],
                           s["skin_from_truth_mm"], rig)


def target_verdicts(worst_joints: dict, length_pct: dict, skin_to: float, skin_from: float,
                    rig: str) -> dict:
    """Issue 36's targets for ``rig`` from the headline numbers (as :func:`verdicts`, which
    calls it; a result file's numbers go in here directly).

    Parameters
    ----------
    worst_joints : dict
        Major joint -> its worst angle error over the frames, deg (NaN or inf: a frame not
        fitted, failed); joints not in ``MAJOR`` are ignored.
    length_pct : dict
        Segment -> signed length error, % of the true length.
    skin_to, skin_from : float
        The skin medians, fitted -> true and true -> fitted, mm.
    rig : {"triplet", "studio"}
        Whose limits (:data:`TARGETS`).

    Returns
    -------
    dict
        ``"joints"``, ``"lengths"``, ``"skin_to_truth"``, ``"skin_from_truth"``: each the
        ``value`` (deg, |%|, mm), ``limit``, ``unit`` and ``met``; the joints and lengths also
        the ``failing`` names, sorted.

    Raises
    ------
    ValueError
        When ``rig`` is unknown, or there is no major joint or no length.
    """
    if rig not in TARGETS:
        raise ValueError(f"rig: expected one of {tuple(TARGETS)}, got {rig!r}")
    deg, pct, mm = TARGETS[rig]
    worst = {k: float(np.nan_to_num(float(v), nan=np.inf, posinf=np.inf))
             for k, v in worst_joints.items() if k in MAJOR}
    if not worst or not length_pct:
        raise ValueError("worst_joints, length_pct: expected the major joints' and the "
                         "lengths' errors, got none")
    wj = max(worst, key=worst.get)
    wl = max(length_pct, key=lambda k: abs(length_pct[k]))
    skin_to, skin_from = float(skin_to), float(skin_from)
    return {
        "joints": {"value": worst[wj], "limit": deg, "unit": "deg", "met": worst[wj] <= deg,
                   "failing": sorted(k for k, v in worst.items() if v > deg)},
        "lengths": {"value": float(abs(length_pct[wl])), "limit": pct, "unit": "%",
                    "met": abs(length_pct[wl]) <= pct,
                    "failing": sorted(k for k, v in length_pct.items() if abs(v) > pct)},
        "skin_to_truth": {"value": skin_to, "limit": mm, "unit": "mm", "met": skin_to <= mm},
        "skin_from_truth": {"value": skin_from, "limit": mm, "unit": "mm",
                            "met": skin_from <= mm},
    }
