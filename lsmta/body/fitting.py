"""Least-squares fit of a metaball model to 3-D points (Plänkers et al. 1999, Section 4).

Observation equations
    One per 3-D point on its body part (eq. 14): the point should lie on the skin of its
    segment's three metaballs. We write it as the signed distance of the point to that
    skin in mm (:func:`~lsmta.body.metaballs.surface_distance`, the log form of eq. 14), so
    that the weight of eq. 11 is ``1 / sigma_mm^2`` with ``sigma_mm`` the a-priori standard
    deviation of a point: the residual vector is ``r / sigma_mm``. Optionally, tracked
    joint positions (Section 4.2) enter as a second observation type, three equations per
    joint, weighted by eq. 11 through their own ``sigma_joint_mm``.
Unknowns
    Metaball sizes (the simplified model's width and depth per segment, or width and depth
    of each ball for the full model), limb scales, the shoulder position in the
    torso frame, and the free joint angles of every frame. In sequence mode the static
    state (radii, scales and, by default, the shoulder) is shared by all frames; each
    frame has its own angles.
Solver
    :func:`scipy.optimize.least_squares`, ``method="trf"`` (a trust-region
    Levenberg–Marquardt relative that accepts robust losses and sparse Jacobians) with a
    robust loss (``soft_l1`` by default, scale ``2 sigma_mm``) against outlier points. The
    Jacobian is analytic (:func:`_residuals`). For a sequence it is mostly empty (a
    frame's angles touch only that frame's points, a segment's radii only that segment's
    points); ``sparse_jacobian=True`` hands it to scipy as a sparse matrix (LSMR instead of
    a dense SVD for the trust-region step). It does not pay at our sizes
    (``experiments/body_benchmark.py``: half the speed at 9 frames, equal at 40), so the
    default is dense.
Segmentation
    Each point goes to the segment whose skin is nearest; points farther than ``gate_mm``
    from every segment are left out (torso, background, gross outliers). The segmentation
    is redone after every ``nfev_per_round`` model evaluations, as in Section 3.3; the fit
    has converged when the solver has and at most 0.2 % of the points (or 2) changed
    segment.
Alternation
    ``strategy="alternating"`` fits the primitives' radii with the skeleton held, then
    the skeleton (angles, scales, shoulder) with the radii held, round after round (the
    paper's choice, Section 4.3); ``"simultaneous"`` frees everything at once.
Checks
    NaN points are dropped and counted; a segment with fewer than ``min_points_per_param``
    points per free shape parameter keeps its shape and scale (named in
    ``fixed_segments``); a limb without such a segment at or beyond its far joint may
    shorten but not lengthen past its starting scale or its own farthest point, whichever
    is longer (named in ``capped_scales``: nothing
    beyond the joint fixes where the bone ends, and the one-sided point-to-skin distances
    would let it stretch past every point); if fewer than ``min_inlier_share`` of the
    points lie within ``gate_mm`` of the initial model the fit is not run
    (``FitStatus.INIT_FAR``), and a fit that ends with fewer inliers than that is reported
    as ``FitStatus.POOR_FIT``. Segments without
    points of their own in a frame are named in ``unobserved``.
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares

from .._validate import as_array, as_scalar
from .arm import base_poses
from .metaballs import MetaballModel, surface_distance, surface_distance_terms

LOSSES = ("linear", "soft_l1", "huber", "cauchy")
SCALE_BOUNDS = (0.3, 3.0)   #: lower and upper bound of a limb scale


class FitStatus(enum.IntEnum):
    """How a fit ended."""

    OK = 0             #: converged
    NOT_CONVERGED = 1  #: iteration budget used up; the result is usable with care
    POOR_FIT = 2       #: too few points near the final model: do not trust it
    INIT_FAR = 3       #: the initial posture is too far from the data; nothing was fitted


@dataclass(frozen=True, eq=False)
class ModelState:
    """Shape and motion of a metaball model over T frames.

    Attributes
    ----------
    angles : (T, J) array
        Joint angles, radians.
    shoulder : (T, 3) array
        Root joint position in the torso frame, mm.
    scales : (L,) array
        Limb scales.
    radii : (S, 3, 3) array
        Metaball radii, mm.
    """

    angles: np.ndarray
    shoulder: np.ndarray
    scales: np.ndarray
    radii: np.ndarray


@dataclass(frozen=True, eq=False)
class BodyFit:
    """Result of :func:`fit_sequence` / :func:`fit_frame`.

    Attributes
    ----------
    status : FitStatus
        ``INIT_FAR``: nothing was fitted and :attr:`state` is the initial state.
    message : str
    state : ModelState
        The estimate (or the initial state when ``status == FitStatus.INIT_FAR``).
    lengths : (S,) array
        Bone lengths, mm.
    segment : list of T (N_t,) int arrays
        Segment of each given point (-1: outside the gate or NaN).
    residuals : list of T (N_t,) arrays
        Signed distance of each point to its segment's skin, mm (NaN where unassigned).
    n_nan : (T,) int array
        NaN points dropped per frame.
    fixed_segments : tuple of str
        Segments whose shape and scale were held (too few points).
    capped_scales : tuple of str
        Limbs kept from lengthening past their starting scale or the farthest point of
        their own segment, whichever is longer (they may shorten), in at least one round
        because no segment at or beyond their far joint had enough points: nothing there
        fixes where the bone ends.
    unobserved : tuple of (int, str)
        ``(frame, segment)`` pairs with fewer than ``min_points_per_param`` points at the
        end: that segment's pose in that frame rests on its neighbours, the tracked joints
        or the start, not on its own points.
    inlier_share : (T,) array
        Share of the finite points within ``gate_mm`` of the final model.
    sigma_mm : float
        Robust residual scale (1.4826 x median absolute residual of assigned points), mm.
    nfev : int
        Model evaluations in all rounds.
    rounds : int
        Segmentation rounds.
    seconds : float
    names : tuple of str
        Names of the parameters of the last solve (see :attr:`covariance`).
    params : (P,) array
    covariance : (P, P) array
        ``s² (JᵀJ)⁻¹`` of the last solve's free parameters at the solution, with ``J``
        scipy's loss-weighted Jacobian and ``s²`` the residual variance per degree of
        freedom (approximate under a robust loss); units as in :attr:`names`.
    """

    status: FitStatus
    message: str
    state: ModelState
    lengths: np.ndarray
    segment: list
    residuals: list
    n_nan: np.ndarray
    fixed_segments: tuple
    capped_scales: tuple
    unobserved: tuple
    inlier_share: np.ndarray
    sigma_mm: float
    nfev: int
    rounds: int
    seconds: float
    names: tuple
    params: np.ndarray
    covariance: np.ndarray

    @property
    def ok(self) -> bool:
        return self.status == FitStatus.OK


class _Layout:
    """Where each unknown sits in the parameter vector."""

    def __init__(self, model: MetaballModel, T: int, shape: str, share_shoulder: bool,
                 free_joints):
        S, L = model.n_segments, len(model.skeleton.limbs)
        self.T, self.S, self.L, self.shape = T, S, L, shape
        self.free_joints = np.asarray(free_joints, int)
        names, kind, seg, frame = [], [], [], []

        def add(n, k, s=-1, f=-1):
            names.append(n)
            kind.append(k)
            seg.append(s)
            frame.append(f)

        n_sh = 1 if share_shoulder else T
        for t in range(n_sh):
            for a in "xyz":
                add(f"shoulder_{a}" + ("" if share_shoulder else f"[{t}]"), "skeleton",
                    -1, -1 if share_shoulder else t)
        for limb in model.skeleton.limbs:
            add(f"scale_{limb}", "skeleton", model.skeleton.limbs.index(limb))
        if shape == "simplified":
            for k, sname in enumerate(model.names):
                for a in ("width", "depth"):
                    add(f"{sname}_{a}", "shape", k)
        else:
            for k, sname in enumerate(model.names):
                for b in range(3):
                    for a in ("width", "depth"):
                        add(f"{sname}_ball{b}_{a}", "shape", k)
        jn = model.skeleton.names
        for t in range(T):
            for j in self.free_joints:
                add(f"{jn[j]}[{t}]", "skeleton", -1, t)
        self.names = tuple(names)
        J = model.skeleton.n_joints
        self.i_sh = np.arange(3 * n_sh).reshape(n_sh, 3)
        self.i_scale = 3 * n_sh + np.arange(L)
        n_shape = (2 if shape == "simplified" else 6) * S
        self.i_shape = 3 * n_sh + L + np.arange(n_shape).reshape(S, -1)
        self.i_ang = np.full((T, J), -1)
        start = 3 * n_sh + L + n_shape
        for t in range(T):
            self.i_ang[t, self.free_joints] = start + t * len(self.free_joints) + np.arange(
                len(self.free_joints))
        self.kind = np.array(kind)
        self.seg = np.array(seg)
        self.frame = np.array(frame)
        self.share_shoulder = share_shoulder
        # scale parameters carry their limb index in ``seg``; map limb -> segments
        self.limb_of_segment = np.array([s.limb for s in model.segments])

    def pack(self, st: ModelState) -> np.ndarray:
        sh = st.shoulder[:1] if self.share_shoulder else st.shoulder
        if self.shape == "simplified":
            shape = st.radii[:, 1, :2].ravel()          # the middle ball = the size
        else:
            shape = st.radii[:, :, :2].ravel()
        return np.concatenate([sh.ravel(), st.scales, shape,
                               st.angles[:, self.free_joints].ravel()])

    def unpack(self, x, template: ModelState, model: MetaballModel) -> ModelState:
        i = 0
        n_sh = 3 if self.share_shoulder else 3 * self.T
        sh = x[:n_sh].reshape(-1, 3)
        sh = np.broadcast_to(sh, (self.T, 3))
        i = n_sh
        scales = x[i:i + self.L]
        i += self.L
        if self.shape == "simplified":
            radii = model.simplified_radii(x[i:i + 2 * self.S].reshape(self.S, 2)
                                           / model.profile[1], scales)
            i += 2 * self.S
        else:
            radii = model.full_radii(x[i:i + 6 * self.S].reshape(self.S, 3, 2), scales)
            i += 6 * self.S
        angles = template.angles.copy()
        angles[:, self.free_joints] = x[i:].reshape(self.T, len(self.free_joints))
        return ModelState(angles=angles, shoulder=np.array(sh), scales=scales, radii=radii)


def _distances(model, st, bases, pts, frame, segment):
    return model.distance(pts, segment, st.angles, st.scales, st.radii, base=bases, frame=frame)


def _residuals(model: MetaballModel, lay: _Layout, st: ModelState, torso, pts, frame,
               segment, *, jac: bool):
    """Distances (mm) of the points to their segments' skins and, with ``jac``, their
    analytic derivatives ``(N, P)`` with respect to all parameters of ``lay``.

    ``r = l (sqrt(psi) - sqrt(psi_T))``, so ``dr = dr/dpsi dpsi (+ root dl for the
    middle ball's width and depth)``. A change of the
    skeleton moves a segment's frame rigidly (``dX = z_j x (X - o_j)`` for an angle,
    ``dX = R_parent offset`` for a scale, ``dX = R_torso dq`` for the shoulder), which
    changes ``psi`` by ``-grad_world . dX``; a limb's own scale also slides its balls
    along the bone and stretches their length radius.
    """
    sk = model.skeleton
    bases = base_poses(torso, st.shoulder)
    W = sk.transforms(st.angles, st.scales, base=bases)        # (T, J, 4, 4)
    C = model.centres(st.scales)
    N = len(pts)
    r = np.empty(N)
    Jm = np.zeros((N, len(lay.names))) if jac else None
    prof = np.asarray(model.profile) / model.profile[1]
    fr = np.asarray(model.fractions)
    for k, segm in enumerate(model.segments):
        idx = np.flatnonzero(segment == k)
        if idx.size == 0:
            continue
        f = frame[idx]
        Rb = np.asarray(segm.rotation, float)
        R = W[f, segm.joint, :3, :3] @ Rb                       # bone -> world rotation
        o = W[f, segm.joint, :3, 3]
        X = pts[idx]
        x = np.einsum("nji,nj->ni", R, X - o)
        local = x[:, None, :] - C[k][None]
        radii = st.radii[k]
        if not jac:
            r[idx] = surface_distance(local, radii)
            continue
        det = surface_distance_terms(local, radii)
        r[idx] = det.r
        inv = det.dr_dpsi
        n = np.einsum("nij,nj->ni", R, det.grad)                # world gradient of psi
        pb = det.p
        # shoulder position (torso frame)
        dq = -np.einsum("ni,nij->nj", n, torso[f, :3, :3])
        sh_rows = lay.i_sh[0 if lay.share_shoulder else f]     # (3,) or (n, 3)
        if lay.share_shoulder:
            Jm[idx[:, None], sh_rows[None]] = dq * inv[:, None]
        else:
            Jm[idx[:, None], sh_rows] = dq * inv[:, None]
        chain = sk.chain(segm.joint)
        for j in chain:
            cols = lay.i_ang[f, j]
            if (cols >= 0).any():
                z, oj = W[f, j, :3, 2], W[f, j, :3, 3]
                dpsi = -np.sum(n * np.cross(z, X - oj), axis=1)
                Jm[idx, cols] = dpsi * inv
            limb = sk.joints[j].limb
            if limb >= 0:
                parent = sk.joints[j].parent
                Rp = bases[f, :3, :3] if parent < 0 else W[f, parent, :3, :3]
                dO = Rp @ np.asarray(sk.joints[j].offset, float)
                Jm[idx, lay.i_scale[limb]] += -np.sum(n * dO, axis=1) * inv
        # the segment's own scale: balls slide along the bone, lz stretches
        L0 = segm.length
        lz = radii[:, 2]
        own = np.sum(pb * (2 * local[:, :, 2] / lz ** 2 * fr * L0
                           - 2 * local[:, :, 2] ** 2 / lz ** 3 * model.length_radius * L0),
                     axis=1)
        Jm[idx, lay.i_scale[segm.limb]] += own * inv
        # widths and depths
        dl = -2 * local[:, :, :2] ** 2 / radii[None, :, :2] ** 3 * pb[:, :, None]  # (n, B, 2)
        mid = radii[1, :2]
        dell = det.root[:, None] * (det.ell / (2 * mid))[None]     # (n, 2)
        if lay.shape == "simplified":
            Jm[idx[:, None], lay.i_shape[k][None]] = np.einsum("nba,b->na", dl, prof) \
                * inv[:, None] + dell
        else:
            block = dl.reshape(len(idx), 6) * inv[:, None]
            block[:, 2:4] += dell
            Jm[idx[:, None], lay.i_shape[k][None]] = block
    return r, Jm


def _joint_residuals(model: MetaballModel, lay: _Layout, st: ModelState, torso, tracked,
                     joints):
    """Tracked joint positions as a second observation type: model joint minus tracked
    joint (mm), ``(M,)`` for the finite entries of ``tracked (T, K, 3)``, and the
    derivatives ``(M, P)``."""
    sk = model.skeleton
    bases = base_poses(torso, st.shoulder)
    W = sk.transforms(st.angles, st.scales, base=bases)
    rows_r, rows_J = [], []
    for k, j in enumerate(joints):
        for t in range(lay.T):
            obs = tracked[t, k]
            if not np.isfinite(obs).all():
                continue
            X = W[t, j, :3, 3]
            D = np.zeros((3, len(lay.names)))
            D[:, lay.i_sh[0 if lay.share_shoulder else t]] = torso[t, :3, :3]
            for i in sk.chain(j):
                if lay.i_ang[t, i] >= 0:
                    D[:, lay.i_ang[t, i]] = np.cross(W[t, i, :3, 2], X - W[t, i, :3, 3])
                limb = sk.joints[i].limb
                if limb >= 0:
                    parent = sk.joints[i].parent
                    Rp = bases[t, :3, :3] if parent < 0 else W[t, parent, :3, :3]
                    D[:, lay.i_scale[limb]] += Rp @ np.asarray(sk.joints[i].offset, float)
            rows_r.append(X - obs)
            rows_J.append(D)
    if not rows_r:
        return np.zeros(0), np.zeros((0, len(lay.names)))
    return np.concatenate(rows_r), np.concatenate(rows_J)


def _segment(model, st, bases, pts, frame, gate):
    D = np.abs(model.all_distances(pts, st.angles, st.scales, st.radii, base=bases, frame=frame))
    seg = np.argmin(D, axis=1)
    seg[D[np.arange(len(pts)), seg] > gate] = -1
    return seg


def _check_state(init: ModelState, model: MetaballModel, T: int) -> ModelState:
    if not isinstance(init, ModelState):
        raise TypeError(f"init: expected a ModelState, got {type(init).__name__}")
    J, L, S = model.skeleton.n_joints, len(model.skeleton.limbs), model.n_segments
    angles = as_array(init.angles, "init.angles", shape=(T, J))
    sh = as_array(init.shoulder, "init.shoulder")
    if sh.shape == (3,):
        sh = np.tile(sh, (T, 1))
    if sh.shape != (T, 3):
        raise ValueError(f"init.shoulder: expected shape (3,) or ({T}, 3), got {sh.shape}")
    scales = as_array(init.scales, "init.scales", shape=(L,))
    radii = as_array(init.radii, "init.radii", shape=(S, 3, 3))
    if np.any(scales <= 0) or np.any(radii <= 0):
        raise ValueError("init: scales and radii must be positive")
    radii = model.full_radii(radii[:, :, :2], scales)        # lz follows the bone
    return ModelState(angles=angles.copy(), shoulder=sh.copy(), scales=scales.copy(), radii=radii)


@dataclass(frozen=True)
class FitParams:
    """Settings of :func:`fit_sequence` (lengths in mm).

    Attributes
    ----------
    shape : {"simplified", "full"}
        Simplified: two size parameters per segment (one width and one depth scaling a
        fixed three-ball profile, Section 3.3); full: six (width and depth of each of the
        three balls). In both, the radius along the bone is not free: it is tied to the
        bone length (``MetaballModel.length_radius`` times it).
    strategy : {"simultaneous", "alternating"}
    share_shoulder : bool
        One shoulder position (torso frame) for all frames (static state) or one per frame.
    free_joints : tuple of int
        Joints whose angles are estimated (the others keep their initial angles).
    sigma_mm : float
        A-priori standard deviation of a 3-D point: residuals are divided by it.
    loss : str
        ``"linear"``, ``"soft_l1"``, ``"huber"`` or ``"cauchy"``; robust scale ``2 sigma_mm``.
    gate_mm : float
        Points farther than this from every segment's skin are not used.
    min_inlier_share : float
        Minimum share of finite points within ``gate_mm``, at the start and at the end.
    nfev_per_round, max_rounds : int
        Model evaluations between re-segmentations; number of rounds.
    sparse_jacobian : bool
        Hand scipy the Jacobian as a sparse matrix.
    jacobian : {"analytic", "2-point"}
        Analytic Jacobian or scipy's finite differences (for checks).
    sigma_joint_mm : float
        A-priori standard deviation of a tracked joint (weight of ``tracked`` by eq. 11,
        ``p_joint / p_point = sigma_mm² / sigma_joint_mm²``).
    max_radius_mm : float
        Upper bound of a ball's width and depth; scales are kept in
        ``SCALE_BOUNDS`` = [0.3, 3] (and capped, see ``min_points_per_param``).
    min_points_per_param : int
        A segment with fewer points than this many per free shape parameter keeps its
        shape and scale (the bare minimum would be one point per parameter); a limb none of
        whose segments at or beyond its far joint has that many may not lengthen past its
        starting scale or its own segment's farthest point, whichever is longer.
    """

    shape: str = "simplified"
    strategy: str = "simultaneous"
    share_shoulder: bool = True
    free_joints: tuple = (0, 1, 2, 3)
    sigma_mm: float = 3.0
    loss: str = "soft_l1"
    gate_mm: float = 60.0
    min_inlier_share: float = 0.5
    nfev_per_round: int = 30
    max_rounds: int = 6
    sparse_jacobian: bool = False
    jacobian: str = "analytic"
    sigma_joint_mm: float = 15.0
    max_radius_mm: float = 300.0
    min_points_per_param: int = 5

    def __post_init__(self):
        if self.shape not in ("simplified", "full"):
            raise ValueError(f"shape: expected 'simplified' or 'full', got {self.shape!r}")
        if self.strategy not in ("simultaneous", "alternating"):
            raise ValueError(f"strategy: expected 'simultaneous' or 'alternating', got "
                             f"{self.strategy!r}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss: expected one of {LOSSES}, got {self.loss!r}")
        if self.jacobian not in ("analytic", "2-point"):
            raise ValueError(f"jacobian: expected 'analytic' or '2-point', got "
                             f"{self.jacobian!r}")
        for key in ("sigma_mm", "sigma_joint_mm", "max_radius_mm", "gate_mm"):
            object.__setattr__(self, key, as_scalar(getattr(self, key), key, positive=True))
        fj = np.asarray(self.free_joints)
        if fj.ndim != 1 or (fj.size and not np.issubdtype(fj.dtype, np.integer)):
            raise ValueError(f"free_joints: expected a sequence of joint indices, got "
                             f"{self.free_joints!r}")
        object.__setattr__(self, "free_joints", tuple(int(j) for j in fj))


def fit_sequence(model: MetaballModel, points, torso_poses, init: ModelState, *,
                 params: FitParams | None = None, tracked=None,
                 tracked_joints=(0, 3, 4)) -> BodyFit:
    """Fit shape and motion of ``model`` to T frames of 3-D points.

    Parameters
    ----------
    model : MetaballModel
        E.g. :func:`~lsmta.body.arm.arm_model`.
    points : sequence of T (N_t, 3) arrays
        World points per frame, mm; NaN rows are dropped (and counted).
    torso_poses : (T, 4, 4) array
        Torso frame -> world per frame (the frame the root joint sits in), mm.
    init : ModelState
        Starting state, e.g. from :func:`~lsmta.body.arm.angles_from_joints` of tracked
        joints and template radii.
    params : FitParams, optional
    tracked : (T, K, 3) array, optional
        Tracked world positions of the joints ``tracked_joints`` (NaN: not tracked): a
        second observation type (Section 4.2), weighted by ``params.sigma_joint_mm``.
    tracked_joints : sequence of K int
        Skeleton joints of ``tracked`` (default: the arm's shoulder, elbow, wrist).

    Returns
    -------
    BodyFit
    """
    t0 = time.perf_counter()
    p = FitParams() if params is None else params
    if not isinstance(p, FitParams):
        raise TypeError(f"params: expected a FitParams, got {type(p).__name__}")
    if not isinstance(model, MetaballModel):
        raise TypeError(f"model: expected a MetaballModel, got {type(model).__name__}")
    data = _data(model, points, torso_poses, tracked, tracked_joints)
    if any(not 0 <= j < model.skeleton.n_joints for j in p.free_joints):
        raise ValueError(f"free_joints: expected joint indices in [0, "
                         f"{model.skeleton.n_joints - 1}]")
    fit = _Fit.initial(model, data, _check_state(init, model, data.T), p)
    share0 = _inlier_share(fit.seg, data)
    if share0.min() < p.min_inlier_share:
        worst = int(np.argmin(share0))
        return _finish(fit, FitStatus.INIT_FAR, f"only {share0[worst]:.0%} of the points of "
                       f"frame {worst} lie within {p.gate_mm:g} mm of the initial model (need "
                       f"{p.min_inlier_share:.0%}); initialise closer to the data", t0)
    groups = [None] if p.strategy == "simultaneous" else ["shape", "skeleton"]
    for fit.rounds in range(1, p.max_rounds + 1):
        free = _hold_thin_segments(fit)
        solved = [_solve_group(fit, free, g) for g in groups]
        settled = _resegment(fit)
        if all(solved) and settled and (p.strategy == "simultaneous" or fit.rounds > 1):
            fit.converged = True
            break
    status, message = _verdict(fit)
    return _finish(fit, status, message, t0)


@dataclass(frozen=True, eq=False)
class _Data:
    """The points of all frames as one cloud, and what the result needs to give them back
    frame by frame."""

    T: int
    torso: np.ndarray          # (T, 4, 4)
    pts: np.ndarray            # (N, 3) finite points of all frames
    frame: np.ndarray          # (N,) their frame
    counts: np.ndarray         # (T,) finite points per frame
    keep: list                 # per frame: indices of the finite points among the given
    n_given: list              # per frame: points given
    n_nan: np.ndarray          # (T,) NaN points dropped
    tracked: np.ndarray | None
    tracked_joints: list


def _data(model, points, torso_poses, tracked, tracked_joints) -> _Data:
    pts_in = list(points) if not isinstance(points, np.ndarray) or points.ndim == 3 else None
    if pts_in is None:
        raise ValueError("points: expected a sequence of (N_t, 3) arrays, one per frame")
    T = len(pts_in)
    if T == 0:
        raise ValueError("points: expected at least one frame")
    P = as_array(torso_poses, "torso_poses", shape=(T, 4, 4))
    tracked_joints = [int(j) for j in tracked_joints]
    if tracked is not None:
        tracked = as_array(tracked, "tracked", shape=(T, len(tracked_joints), 3),
                           allow_nan=True)
        if any(not 0 <= j < model.skeleton.n_joints for j in tracked_joints):
            raise ValueError("tracked_joints: expected skeleton joint indices")
    clouds, n_nan, keep = [], [], []
    for t, p in enumerate(pts_in):
        a = as_array(p, f"points[{t}]", shape=(None, 3), allow_nan=True)
        good = np.isfinite(a).all(axis=1)
        n_nan.append(int((~good).sum()))
        keep.append(np.flatnonzero(good))
        clouds.append(a[good])
    pts = np.concatenate(clouds)
    if pts.shape[0] == 0:
        raise ValueError("points: no finite point in any frame")
    return _Data(T=T, torso=P, pts=pts,
                 frame=np.concatenate([np.full(len(c), t) for t, c in enumerate(clouds)]),
                 counts=np.array([len(c) for c in clouds]), keep=keep,
                 n_given=[len(p) for p in pts_in], n_nan=np.array(n_nan), tracked=tracked,
                 tracked_joints=tracked_joints)


@dataclass
class _Fit:
    """The state of one fit, changed round by round."""

    model: MetaballModel
    data: _Data
    p: FitParams
    lay: _Layout
    state: ModelState
    x: np.ndarray                # the parameter vector of ``lay``
    seg: np.ndarray              # (N,) segment of each point, -1 outside the gate
    fixed: list = field(default_factory=list)   # segments whose shape was held
    capped_scales: list = field(default_factory=list)  # limbs kept from lengthening
    scale0: np.ndarray | None = None   # (L,) the starting scales
    scale_cap: np.ndarray | None = None   # (L,) upper bound of each scale this round
    nfev: int = 0
    rounds: int = 0
    converged: bool = False
    last: tuple | None = None    # (scipy solution, mask of its parameters) of the last solve

    @classmethod
    def initial(cls, model, data: _Data, state: ModelState, p: FitParams) -> _Fit:
        lay = _Layout(model, data.T, p.shape, p.share_shoulder, np.asarray(p.free_joints, int))
        fit = cls(model=model, data=data, p=p, lay=lay, state=state, x=lay.pack(state),
                  seg=np.zeros(0, int), scale0=np.array(state.scales, float))
        fit.seg = fit.segment(state)
        return fit

    def bases(self, st: ModelState) -> np.ndarray:
        return base_poses(self.data.torso, st.shoulder)

    def segment(self, st: ModelState) -> np.ndarray:
        return _segment(self.model, st, self.bases(st), self.data.pts, self.data.frame,
                        self.p.gate_mm)


def _inlier_share(seg, data: _Data) -> np.ndarray:
    """(T,) share of each frame's finite points assigned to a segment."""
    return np.array([np.mean(seg[data.frame == t] >= 0) if data.counts[t] else 0.0
                     for t in range(data.T)])


def _hold_thin_segments(fit: _Fit) -> np.ndarray:
    """Segments with too few points keep their shape and scale: the free parameters.

    Also sets ``fit.scale_cap``: a limb none of whose segments at or beyond its far joint
    has enough points may shorten but not lengthen past its starting scale or past the
    farthest point of its own segment along the bone, whichever is longer. A limb's scale
    is its bone's length, which places its far joint (the wrist, for the forearm). The
    point-to-skin distances pull the skin out to cover points, so the limb's own points
    stop it from getting shorter than they reach; but nothing pulls the skin back where
    there are no points, so without points beyond the far joint (a hand with too few
    points of its own) the bone could stretch, carrying the segments beyond it, far past
    every point at no cost -- its length is not determined by the data.
    """
    model, lay = fit.model, fit.lay
    sk = model.skeleton
    per_segment = 2 if fit.p.shape == "simplified" else 6
    n_on = np.bincount(fit.seg[fit.seg >= 0], minlength=model.n_segments)
    thin = n_on < fit.p.min_points_per_param * per_segment
    free = np.ones(len(fit.x), bool)
    for k in np.flatnonzero(thin):
        if model.names[k] not in fit.fixed:
            fit.fixed.append(model.names[k])
        free[(lay.kind == "shape") & (lay.seg == k)] = False
        free[lay.i_scale[model.segments[k].limb]] = False
    fit.scale_cap = np.full(lay.L, SCALE_BOUNDS[1])
    for j, joint in enumerate(sk.joints):
        if joint.limb < 0:
            continue                   # the joint's offset is not a limb's length
        beyond = [k for k, sg in enumerate(model.segments) if j in sk.chain(sg.joint)]
        if beyond and thin[beyond].all():
            reach = max(fit.scale0[joint.limb], _reach(fit, joint.limb))
            fit.scale_cap[joint.limb] = min(fit.scale_cap[joint.limb],
                                            max(reach, SCALE_BOUNDS[0] + 1e-6))
            if sk.limbs[joint.limb] not in fit.capped_scales:
                fit.capped_scales.append(sk.limbs[joint.limb])
    return free


def _reach(fit: _Fit, limb: int) -> float:
    """How far along its bone the points of the segments of ``limb`` reach, as a scale
    (the farthest point's distance from the segment's joint over the template length;
    0 without points)."""
    model, st = fit.model, fit.state
    W = model.skeleton.transforms(st.angles, st.scales, base=fit.bases(st))
    out = 0.0
    for k, sg in enumerate(model.segments):
        idx = np.flatnonzero(fit.seg == k)
        if sg.limb != limb or idx.size == 0:
            continue
        f = fit.data.frame[idx]
        R = W[f, sg.joint, :3, :3] @ np.asarray(sg.rotation, float)
        x = np.einsum("nji,nj->ni", R, fit.data.pts[idx] - W[f, sg.joint, :3, 3])
        out = max(out, float(np.max(-x[:, 2])) / sg.length)      # the bone runs along -z
    return out


class _Objective:
    """Weighted residuals and their Jacobian over the parameters ``mask`` of ``fit.x``
    (point distances, and tracked joints), evaluated once per parameter vector."""

    def __init__(self, fit: _Fit, mask):
        self.fit, self.mask = fit, mask
        use = fit.seg >= 0
        self.pts, self.frame, self.seg = fit.data.pts[use], fit.data.frame[use], fit.seg[use]
        self.template = fit.state
        self.key, self.value = None, None

    def evaluate(self, xf):
        key = xf.tobytes()
        if key != self.key:
            f, p = self.fit, self.fit.p
            xx = f.x.copy()
            xx[self.mask] = xf
            s = f.lay.unpack(xx, self.template, f.model)
            res, Jm = _residuals(f.model, f.lay, s, f.data.torso, self.pts, self.frame,
                                 self.seg, jac=True)
            res, Jm = res / p.sigma_mm, Jm / p.sigma_mm
            if f.data.tracked is not None:
                rj, Jj = _joint_residuals(f.model, f.lay, s, f.data.torso, f.data.tracked,
                                          f.data.tracked_joints)
                res = np.concatenate([res, rj / p.sigma_joint_mm])
                Jm = np.concatenate([Jm, Jj / p.sigma_joint_mm])
            self.key, self.value = key, (res, Jm[:, self.mask])
        return self.value

    def fun(self, xf):
        return self.evaluate(xf)[0]

    def jac(self, xf):
        Jm = self.evaluate(xf)[1]
        return sparse.csr_matrix(Jm) if self.fit.p.sparse_jacobian else Jm


def _solve_group(fit: _Fit, free, group) -> bool:
    """One bounded robust least-squares solve over the free parameters of ``group``
    (None: all); True when scipy reports convergence (or there was nothing to solve)."""
    lay, p = fit.lay, fit.p
    mask = free.copy()
    if group is not None:
        mask &= lay.kind == group
    if not mask.any():
        return True
    obj = _Objective(fit, mask)
    lower = np.full(mask.sum(), -np.inf)
    upper = np.full(mask.sum(), np.inf)
    is_shape = lay.kind[mask] == "shape"
    is_scale = np.array([n.startswith("scale_") for n in np.array(lay.names)[mask]], bool)
    lower[is_shape], upper[is_shape] = 1.0, p.max_radius_mm
    lower[is_scale] = SCALE_BOUNDS[0]
    upper[is_scale] = fit.scale_cap[np.searchsorted(lay.i_scale, np.flatnonzero(mask)[is_scale])]
    sol = least_squares(obj.fun, np.clip(fit.x[mask], lower + 1e-9, upper - 1e-9),
                        jac=obj.jac if p.jacobian == "analytic" else "2-point", loss=p.loss,
                        f_scale=2.0, method="trf", x_scale="jac", max_nfev=p.nfev_per_round,
                        bounds=(lower, upper))
    fit.nfev += sol.nfev
    fit.x[mask] = sol.x
    fit.last = (sol, mask)
    return sol.status > 0


def _resegment(fit: _Fit) -> bool:
    """Take the new state and segment the points again; True when at most 0.2 % of them
    (or 2) changed segment."""
    fit.state = fit.lay.unpack(fit.x, fit.state, fit.model)
    new = fit.segment(fit.state)
    changed = int(np.sum(new != fit.seg))
    fit.seg = new
    return changed <= max(2, int(0.002 * len(fit.data.pts)))


def _verdict(fit: _Fit) -> tuple[FitStatus, str]:
    inl = _inlier_share(fit.seg, fit.data)
    if inl.min() < fit.p.min_inlier_share:
        status, msg = FitStatus.POOR_FIT, (f"only {inl.min():.0%} of the points of a frame "
                                           f"lie within {fit.p.gate_mm:g} mm of the fitted "
                                           "model; the fit is not trusted")
    elif not fit.converged:
        status, msg = FitStatus.NOT_CONVERGED, (f"stopped after {fit.rounds} rounds "
                                                f"({fit.nfev} evaluations)")
    else:
        status, msg = FitStatus.OK, f"converged in {fit.rounds} rounds ({fit.nfev} evaluations)"
    if fit.fixed:
        msg += f"; shape held for {', '.join(fit.fixed)} (too few points)"
    if fit.capped_scales:
        msg += (f"; {', '.join(fit.capped_scales)} kept from lengthening past its start "
                "or its farthest point (too few points beyond its far joint)")
    n_nan = int(fit.data.n_nan.sum())
    if n_nan:
        msg += f"; {n_nan} NaN points dropped"
    return status, msg


def _covariance(fit: _Fit):
    """Names, values and ``s² (JᵀJ)⁻¹`` of the last solve's parameters (empty before any)."""
    if fit.last is None:
        return (), np.zeros(0), np.zeros((0, 0))
    sol, mask = fit.last
    J = sol.jac.toarray() if sparse.issparse(sol.jac) else np.asarray(sol.jac)
    m, n = J.shape
    sigma = fit.p.sigma_mm
    s2 = float(np.sum(sol.fun ** 2) / max(m - n, 1)) * sigma ** 2
    try:
        cov = np.linalg.pinv(J.T @ J) * s2 / sigma ** 2
    except np.linalg.LinAlgError:
        cov = np.full((n, n), np.nan)
    return tuple(np.array(fit.lay.names)[mask]), sol.x, cov


def _finish(fit: _Fit, status: FitStatus, message: str, t0: float) -> BodyFit:
    """The result: per-frame segments and residuals in the caller's point order."""
    model, data, seg, st = fit.model, fit.data, fit.seg, fit.state
    res_all = np.full(len(data.pts), np.nan)
    if (seg >= 0).any():
        res_all[seg >= 0] = _distances(model, st, fit.bases(st), data.pts[seg >= 0],
                                       data.frame[seg >= 0], seg[seg >= 0])
    seg_out, res_out = [], []
    for t in range(data.T):
        s_t = np.full(data.n_given[t], -1)
        r_t = np.full(data.n_given[t], np.nan)
        s_t[data.keep[t]] = seg[data.frame == t]
        r_t[data.keep[t]] = res_all[data.frame == t]
        seg_out.append(s_t)
        res_out.append(r_t)
    assigned = res_all[np.isfinite(res_all)]
    unobs = tuple((t, model.names[k]) for t in range(data.T) for k in range(model.n_segments)
                  if np.sum(seg[data.frame == t] == k) < fit.p.min_points_per_param)
    if unobs and status != FitStatus.INIT_FAR:
        message += "; no points of its own for " + ", ".join(
            f"{n} in frame {t}" for t, n in unobs)
    names, values, cov = _covariance(fit) if status != FitStatus.INIT_FAR \
        else ((), np.zeros(0), np.zeros((0, 0)))
    return BodyFit(status=status, message=message, state=st,
                   lengths=model.bone_lengths(st.scales), segment=seg_out, residuals=res_out,
                   n_nan=data.n_nan, fixed_segments=tuple(fit.fixed),
                   capped_scales=tuple(fit.capped_scales), unobserved=unobs,
                   inlier_share=_inlier_share(seg, data),
                   sigma_mm=float(1.4826 * np.median(np.abs(assigned))) if assigned.size
                   else np.nan, nfev=fit.nfev, rounds=fit.rounds,
                   seconds=time.perf_counter() - t0, names=names, params=values,
                   covariance=cov)


def fit_frame(model: MetaballModel, points, torso_pose, init: ModelState, *,
              params: FitParams | None = None) -> BodyFit:
    """:func:`fit_sequence` for one frame: ``points (N, 3)``, ``torso_pose (4, 4)``, and an
    ``init`` with ``angles (1, J)`` (or ``(J,)``) and ``shoulder (3,)``."""
    P = as_array(torso_pose, "torso_pose", shape=(4, 4))
    pts = as_array(points, "points", shape=(None, 3), allow_nan=True)
    if isinstance(init, ModelState) and np.ndim(init.angles) == 1:
        init = ModelState(angles=np.asarray(init.angles)[None], shoulder=init.shoulder,
                          scales=init.scales, radii=init.radii)
    return fit_sequence(model, [pts], P[None], init, params=params)
