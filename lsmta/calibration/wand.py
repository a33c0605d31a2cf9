"""Calibration from a wand, in one call, as users of easyWand, Argus and aniposelib do it.

What a user has: the 2-D image positions of a wand's two ends in K synchronised videos
(digitised in DLTdv or Argus, or tracked), NaN where a camera does not see the wand; the
wand's length; the image sizes; perhaps the cameras' focal lengths; perhaps background
points seen by two or more cameras (tie points). Typical recordings are short and patchy:
25 frames in which each camera sees the wand in only some.

:func:`calibrate_wand` runs, without any ground truth:

1. *checks*: shapes, image sizes (every point inside its image), frames in which both
   ends are seen by at least two cameras (the others are dropped and counted);
2. *approximations*: every camera starts with the given focal length, or ``max(width,
   height)`` px (said in the messages), the principal point at the image centre, no
   distortion; the two cameras sharing the most points get their relative orientation
   (:func:`~lsmta.calibration.relative_orientation_start`, essential matrix with RANSAC,
   scaled by the median wand length); the other cameras are added one at a time, the one
   seeing most of the points intersected so far first, by space resection (RANSAC);
3. *consistent ends*: a wand's ends look alike, so each camera's labels may be swapped in
   some frames; :func:`~lsmta.calibration.labels.consistent_bar_labels` picks per frame
   the labelling whose intersected ends reproject best and lie one wand length apart, and
   step 2 runs again on the corrected labels;
4. *bundle adjustment* (:func:`~lsmta.calibration.bundle_adjust`) of all cameras, wand
   ends and tie points with the wand length as an observation ``|A_t - B_t| - L = v_t``;
   per camera the exterior orientation, the focal length and the lens model are free
   (the principal point stays at the image centre unless the model frees it); robustly
   (soft-L1 loss, then rejection of residuals beyond four sigma) unless ``robust=False``.
   The lens model is given (``distortion="none"``, ``"k1"``, ``"k1k2"``, ``"k1k2p1p2"``)
   or chosen from the data (``"auto"``, the default; see *The lens model* below);
5. *datum*: the world frame is the first camera's (its centre at the origin, its axes the
   world axes), the scale the wand's;
6. *scores*: the wand's ends intersected with the calibrated cameras (forward
   intersection; not the adjusted points, which carry the length observation) and their
   distance per frame: the scatter of the lengths is the wand score easyWand reports;
   beside it the image RMS per camera (2-D, and per coordinate as easyWand reports it).

Tie points (background points, easyWand's and Argus' "unpaired points") seen by fewer than
two cameras cannot be intersected: they are dropped and counted (``n_tie_dropped``, and a
message), not refused; the result keeps the caller's indexing (NaN rows for them). Rows
seen by no camera at all (the empty frames of a DLTdv / Argus background track) are
ignored.

The lens model (``distortion="auto"``)
--------------------------------------
Forward selection along a fixed ladder of parameter groups, each per camera:
``k1``, then ``k2``, then the decentring pair ``p1, p2``, then the principal point ``cx,
cy``. Starting from the pinhole camera with its focal length (``"none"``), each group is
added to every camera and the network adjusted again (from the previous solution); the
group is kept where both hold:

* *determined*, per camera: at least one of its parameters moved from the value it was
  held at by more than ``3`` standard deviations of the adjustment (``|x - x0| > 3
  sigma_x``; a camera whose observations do not reach far enough from the image centre
  cannot determine ``k2`` and keeps it at 0); cameras where it is not determined are
  adjusted again without it;
* *significant*, for the network: the F-test of the two nested adjustments on the
  observations both kept, ``F = ((S0 - S1) / dp) / (S1 / r1)`` (``S``: the weighted sums
  of squared residuals, ``dp``: the parameters added, ``r1``: the larger model's
  redundancy), rejects "no improvement" at the 1 % level.

A group that fails is left out and the next one tried. Of the accepted models the richest
whose lenses can be inverted at every observed point is used (``k1`` alone may fold over
inside the image where ``k1`` and ``k2`` together do not). The result says which parameters
each camera got (``intrinsics``) and what every step gave (``model_steps``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from scipy.special import fdtrc

from .._validate import as_array, as_scalar
from ..camera import Camera
from ..triangulation import triangulate
from .approximations import next_camera, relative_orientation_start, resect_pnp
from .bundle import Bar, BundleParams, BundleResult, bundle_adjust, min_points_per_camera
from .labels import consistent_bar_labels
from .result import CalibrationResult

MIN_FRAMES = 10
DISTORTION_MODELS = {"none": (), "k1": ("k1",), "k1k2": ("k1", "k2"),
                     "k1k2p1p2": ("k1", "k2", "p1", "p2")}
#: the ladder of ``distortion="auto"``: parameter groups tried in this order
AUTO_LADDER = (("k1",), ("k2",), ("p1", "p2"), ("cx", "cy"))
#: a group is determined in a camera when one of its parameters moves by more than this
#: many standard deviations from the value it was held at
DETERMINED_SIGMA = 3.0
#: significance level of the F-test that adds a group
F_TEST_ALPHA = 0.01
# a wand length observation 10 000 times more precise than the wand is long
BAR_SIGMA_REL = 1e-4
# residuals beyond this many (a-posteriori) sigma are rejected in the robust adjustment
REJECT_K = 4.0


class WandStatus(IntEnum):
    """Outcome of :func:`calibrate_wand`."""

    OK = 0
    #: the RMS residual is more than 3 times the assumed ``sigma_px`` (s0 > 3)
    LARGE_RESIDUALS = 1
    #: the wand lengths scatter by more than 1 % (a poor calibration or mislabelled ends)
    WAND_SCATTER = 2


@dataclass(frozen=True, eq=False)
class WandCalibration(CalibrationResult):
    """Result of :func:`calibrate_wand`.

    Attributes
    ----------
    cameras : list of K Camera
        Calibrated cameras; world frame = the first camera's, mm.
    bundle : BundleResult
        The final adjustment (its frame: the first camera of the relative orientation).
    wand_points : (T, 2, 3) array
        The wand's two ends intersected with the calibrated cameras, mm (NaN in frames
        that were not used).
    wand_lengths : (T,) array
        Their distances, mm.
    wand_length_std_percent : float
        Standard deviation of ``wand_lengths`` in per cent of the wand's length (easyWand's
        wand score).
    rms_px : (K,) array
        Per camera, the root mean square of the 2-D reprojection error of its
        observations, px (OpenCV's and caliscope's convention: sqrt 2 times the RMS per
        coordinate, :attr:`rms_px_per_coordinate`); rejected observations left out.
    tie_points : array (..., 3) or None
        Adjusted tie points, mm, indexed as the caller's ``tie_xy`` (``(N, 3)``, or ``(T,
        P, 3)`` for a ``(K, T, P, 2)`` background file); NaN for the points dropped.
    n_tie_dropped : int
        Tie points seen by exactly one camera, dropped (points seen by none are ignored).
    distortion : str
        The lens model asked for ("auto" or a fixed one).
    intrinsics : tuple of K tuples of str
        The interior parameters adjusted per camera (``"f"`` and the lens model's).
    model_steps : tuple of dict
        With ``distortion="auto"``: per group of the ladder its parameters, the cameras
        where it was determined, the F statistic, its p-value and whether it was kept.
    wand_xy : (K, T, 2, 2) array
        The observations with consistent ends (as adjusted; NaN in dropped frames).
    swapped : (K, T) bool array
        Where a camera's labels of the two ends were exchanged.
    used : (T,) bool array
        Frames in which both ends are seen by at least two cameras.
    pair : (int, int)
        The cameras of the relative orientation.
    focal_guessed : bool
        The focal lengths started from the image size (no ``focal_px``).
    status : WandStatus
    messages : tuple of str
        What was assumed, dropped or corrected, in words.
    seconds : float
    """

    wand_points: np.ndarray
    wand_lengths: np.ndarray
    wand_length_std_percent: float
    rms_px: np.ndarray
    tie_points: np.ndarray | None
    n_tie_dropped: int
    distortion: str
    intrinsics: tuple
    model_steps: tuple
    wand_xy: np.ndarray
    swapped: np.ndarray
    used: np.ndarray
    pair: tuple
    focal_guessed: bool
    status: WandStatus
    messages: tuple = field(default_factory=tuple)
    seconds: float = 0.0

    @property
    def rms_px_per_coordinate(self) -> np.ndarray:
        """``(K,)`` the RMS per image coordinate, px: ``rms_px / sqrt 2`` (easyWand's and
        DLTdv's convention: ``sqrt(sum(residuals^2) / numel)`` over u and v)."""
        return self.rms_px / np.sqrt(2.0)

    def summary(self) -> dict:
        """The wand score beside the image RMS of every camera, the lens model per camera
        and what was dropped, as plain numbers (for a JSON file or a table)."""
        names = [c.name or f"camera {k}" for k, c in enumerate(self.cameras)]
        return {
            "status": self.status.name,
            "wand_length_std_percent": float(self.wand_length_std_percent),
            "frames_used": int(self.used.sum()),
            "frames": int(len(self.used)),
            "tie_points_used": 0 if self.tie_points is None else int(
                np.isfinite(self.tie_points.reshape(-1, 3)).all(axis=1).sum()),
            "tie_points_dropped": int(self.n_tie_dropped),
            "distortion": self.distortion,
            "cameras": {n: {"rms_px": float(self.rms_px[k]),
                            "rms_px_per_coordinate": float(self.rms_px_per_coordinate[k]),
                            "intrinsics": list(self.intrinsics[k])}
                        for k, n in enumerate(names)},
        }


# ---------------------------------------------------------------------- checks
def _image_sizes(image_sizes, K: int) -> np.ndarray:
    sizes = np.asarray(image_sizes, dtype=float)
    if sizes.shape == (2,):
        sizes = np.tile(sizes, (K, 1))
    if sizes.shape != (K, 2) or not np.all(np.isfinite(sizes)) or np.any(sizes < 2) \
            or np.any(sizes != np.round(sizes)):
        raise ValueError(f"image_sizes: expected {K} (width, height) pairs of whole pixels "
                         f"(or one pair for all), got {image_sizes!r}")
    return sizes.astype(int)


def _check_observations(xy, sizes, name: str, cameras_named):
    """Half-NaN points and points outside their image are refused."""
    half = np.isnan(xy).any(axis=-1) & ~np.isnan(xy).all(axis=-1)
    if half.any():
        raise ValueError(f"{name}: {int(half.sum())} point(s) have one coordinate NaN and "
                         "the other not; an unseen point is NaN in both")
    for k, (w, h) in enumerate(sizes):
        p = xy[k].reshape(-1, 2)
        p = p[np.isfinite(p).all(axis=1)]
        out = (p[:, 0] < -0.5) | (p[:, 0] > w - 0.5) | (p[:, 1] < -0.5) | (p[:, 1] > h - 0.5)
        if out.any():
            raise ValueError(
                f"{name}: {int(out.sum())} point(s) of camera {cameras_named[k]} lie outside "
                f"its {w} x {h} px image (x up to {p[:, 0].max():.1f}, y up to "
                f"{p[:, 1].max():.1f}); check image_sizes (width, height) and the y "
                "direction (read_xypts flips it)")


def _focal(focal_px, sizes, messages) -> tuple[np.ndarray, bool]:
    K = len(sizes)
    if focal_px is None:
        f = sizes.max(axis=1).astype(float)
        messages.append("focal_px not given: every camera starts at f = max(width, height) "
                        f"px ({', '.join(f'{v:.0f}' for v in f)}; a 53 degree field of view "
                        "across the longer side) and is adjusted from there")
        return f, True
    f = np.asarray(focal_px, dtype=float)
    f = np.full(K, float(f)) if f.ndim == 0 else f
    if f.shape != (K,) or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError(f"focal_px: expected a positive number of pixels or {K} of them, "
                         f"got {focal_px!r}")
    return f, False


# ---------------------------------------------------------------------- stages
def _pair(nominal, xy, bar, threshold_px) -> tuple:
    """The two cameras whose relative orientation intersects the most points at a good
    angle (at least 10 degrees between the rays' lines): sharing many points is not
    enough - two cameras facing each other see the same points along nearly the same
    lines."""
    K = len(nominal)
    seen = np.isfinite(xy).all(axis=2)
    best, pair, n_max = -1, None, 0
    for i in range(K):
        for j in range(i + 1, K):
            n = int((seen[i] & seen[j]).sum())
            n_max = max(n_max, n)
            if n < 8:
                continue
            try:
                two, _ = relative_orientation_start([nominal[i], nominal[j]], xy[[i, j]],
                                                    bar=bar, pair=(0, 1),
                                                    threshold_px=threshold_px)
            except ValueError:
                continue
            angle = triangulate(two, xy[[i, j]], min_angle_deg=0.0).angle_deg
            good = int(np.sum(angle >= 10.0))
            if good > best:
                best, pair = good, (i, j)
    if pair is None:
        raise ValueError(f"wand_xy: no two cameras share 8 or more points (at most {n_max}) "
                         "with a usable relative orientation; the start needs such a pair")
    return pair


def _approximations(nominal, xy, bar, pair, threshold_px):
    """Relative orientation of ``pair``, then resection of one camera at a time (the one
    that sees most of the points intersected so far), each followed by an intersection."""
    K = len(nominal)
    i, j = pair
    two, _ = relative_orientation_start([nominal[i], nominal[j]], xy[[i, j]], bar=bar,
                                        pair=(0, 1), threshold_px=threshold_px)
    cams = list(nominal)
    cams[i], cams[j] = two
    placed = [i, j]
    while len(placed) < K:
        k, m, X = next_camera(cams, placed, xy, min_angle_deg=1.0)
        if m.sum() >= 6:
            cams[k] = resect_pnp(nominal[k], X[m], xy[k, m], max_error_px=4 * threshold_px,
                                 arg="wand_xy")
        else:
            cams[k] = _relative_to_placed(nominal, cams, placed, k, xy, bar, threshold_px)
        placed.append(k)
    return cams, triangulate(cams, xy, min_angle_deg=0.0).points


def _relative_to_placed(nominal, cams, placed, k, xy, bar, threshold_px) -> Camera:
    """Camera k by its relative orientation to the placed camera it shares most points
    with (when it sees too few of the points intersected so far for a resection)."""
    seen = np.isfinite(xy).all(axis=2)
    shared = [int((seen[p] & seen[k]).sum()) for p in placed]
    p = placed[int(np.argmax(shared))]
    if max(shared) < 8:
        raise ValueError(
            f"wand_xy: camera {nominal[k].name} shares at most {max(shared)} points with "
            f"cameras {[nominal[q].name for q in placed]}; it needs 6 of their intersected "
            "points for a resection or 8 with one of them for a relative orientation (more "
            "frames in which it sees the wand together with others)")
    (_, rel), _ = relative_orientation_start([nominal[p], nominal[k]], xy[[p, k]], bar=bar,
                                             pair=(0, 1), threshold_px=threshold_px)
    Rp, Cp = np.asarray(cams[p].R), cams[p].C
    return nominal[k].replace(R=np.asarray(rel.R) @ Rp, C=Cp + Rp.T @ rel.C)


def _start_points(bundle: BundleResult, wand_xy, K, T, tie) -> np.ndarray:
    """Points intersected with the adjustment's cameras (after a change of labels)."""
    obs = np.concatenate([wand_xy.reshape(K, 2 * T, 2), tie], axis=1)
    return triangulate(bundle.cameras, obs, min_angle_deg=0.0).points


def _rms_2d(residuals) -> np.ndarray:
    """Per camera RMS of the 2-D residual vectors, px."""
    sq = np.sum(residuals**2, axis=2)                    # NaN where not observed
    with np.errstate(invalid="ignore"):
        return np.sqrt(np.nanmean(sq, axis=1))


def calibrate_wand(wand_xy, length: float, image_sizes, *, focal_px=None, tie_xy=None,
                   distortion: str = "auto", robust: bool = True,
                   sigma_px: float = 1.0) -> WandCalibration:
    """Calibrate K cameras from a wand of known length (see the module docstring).

    Parameters
    ----------
    wand_xy : (K, T, 2, 2) array
        Image positions of the wand's two ends in T frames, px (top-left origin; see
        :func:`lsmta.io.read_xypts`, which reads a DLTdv / easyWand / Argus wand file in
        this shape); NaN where a camera does not see an end.
    length : float
        The wand's length (distance between the ends' centres), mm.
    image_sizes : (K, 2) array or (width, height)
        Image sizes in px.
    focal_px : float or (K,) array, optional
        Focal lengths to start from, px; by default ``max(width, height)`` (and a message
        says so). Adjusted either way. Give it for wide-angle lenses (the generated
        100 degree rig does not converge from the guess).
    tie_xy : (K, N, 2) or (K, T, P, 2) array, optional
        Background points of unknown 3-D position, px, NaN where unseen (easyWand's
        background points, Argus' unpaired points; a ``(K, T, P, 2)`` file as read by
        :func:`lsmta.io.read_xypts` is taken point by point, each frame of each track
        one point). Points seen by one camera only are dropped and counted; rows seen by
        none are ignored.
    distortion : {"auto", "none", "k1", "k1k2", "k1k2p1p2"}
        The lens model adjusted per camera: chosen from the data by the rule of the module
        docstring (``"auto"``), or the one named (radial ``k1``, ``k2``; decentring ``p1,
        p2``; the principal point stays at the image centre).
    robust : bool
        Soft-L1 loss and rejection of residuals beyond four sigma.
    sigma_px : float
        A-priori standard deviation of an image coordinate, px (the weights of the image
        against the wand length, the unit of the robust loss, and of the F-test's sums).

    Returns
    -------
    WandCalibration
        Nothing the caller passed is modified.

    Raises
    ------
    ValueError
        Wrong shapes, a point outside its image (wrong ``image_sizes``), a coordinate
        pair with one NaN, fewer than 10 frames with the wand seen by two cameras, a
        camera that sees the wand in no such frame (or too few to be resected).
    """
    t0 = time.perf_counter()
    st = _State.initial(wand_xy, length, image_sizes, tie_xy, distortion, sigma_px)
    _usable_frames(st)
    _approximations_and_ends(st, focal_px)
    _bundle(st, robust)
    return _result(st, t0)


@dataclass
class _State:
    """What the stages of :func:`calibrate_wand` hand on."""

    xy: np.ndarray                 # (K, T, 2, 2), frames without two views set to NaN
    tie: np.ndarray                # (K, N_kept, 2): the tie points seen by >= 2 cameras
    tie_kept: np.ndarray           # (N,) bool, which of the caller's points those are
    tie_shape: tuple               # the caller's point indexing, (N,) or (T, P)
    n_tie_dropped: int
    sizes: np.ndarray              # (K, 2)
    names: list
    length: float
    sigma_px: float
    distortion: str
    messages: list
    used: np.ndarray | None = None
    bar: Bar | None = None
    pair: tuple | None = None
    guessed: bool = False
    cams0: list | None = None
    X0: np.ndarray | None = None
    labels: object = None
    bundle: BundleResult | None = None
    intrinsics: list | None = None
    steps: list = field(default_factory=list)

    @property
    def K(self) -> int:
        return self.xy.shape[0]

    @property
    def T(self) -> int:
        return self.xy.shape[1]

    def flat(self, w) -> np.ndarray:
        """Wand ends ``(K, T, 2, 2)`` and tie points as one ``(K, 2T + N, 2)`` array."""
        return np.concatenate([w.reshape(self.K, 2 * self.T, 2), self.tie], axis=1)

    @classmethod
    def initial(cls, wand_xy, length, image_sizes, tie_xy, distortion, sigma_px) -> _State:
        xy = as_array(wand_xy, "wand_xy", shape=(None, None, 2, 2), allow_nan=True).copy()
        K = xy.shape[0]
        if K < 2:
            raise ValueError(f"wand_xy: expected observations of at least 2 cameras, got {K}")
        length = as_scalar(length, "length", positive=True)
        sigma_px = as_scalar(sigma_px, "sigma_px", positive=True)
        sizes = _image_sizes(image_sizes, K)
        if distortion != "auto" and distortion not in DISTORTION_MODELS:
            raise ValueError(f"distortion: expected 'auto' or one of "
                             f"{sorted(DISTORTION_MODELS)}, got {distortion!r}")
        names = [f"cam{k + 1}" for k in range(K)]
        _check_observations(xy, sizes, "wand_xy", names)
        messages: list = []
        tie, kept, shape, dropped = _tie_points(tie_xy, K, sizes, names, messages)
        return cls(xy=xy, tie=tie, tie_kept=kept, tie_shape=shape, n_tie_dropped=dropped,
                   sizes=sizes, names=names, length=length, sigma_px=sigma_px,
                   distortion=distortion, messages=messages)


def _tie_points(tie_xy, K, sizes, names, messages):
    """The tie points seen by at least two cameras, which of the caller's they are, the
    caller's indexing and how many were dropped (seen by one camera)."""
    if tie_xy is None:
        return np.zeros((K, 0, 2)), np.zeros(0, bool), (0,), 0
    arr = np.asarray(tie_xy)
    if arr.ndim == 4:                        # (K, T, P, 2): a background xypts file
        tie = as_array(tie_xy, "tie_xy", shape=(K, None, None, 2), allow_nan=True)
        shape = tie.shape[1:3]
        tie = tie.reshape(K, -1, 2)
    else:
        tie = as_array(tie_xy, "tie_xy", shape=(K, None, 2), allow_nan=True)
        shape = tie.shape[1:2]
    _check_observations(tie, sizes, "tie_xy", names)
    views = np.isfinite(tie).all(axis=2).sum(axis=0)
    kept = views >= 2
    dropped = int((views == 1).sum())
    if dropped:
        messages.append(f"{dropped} of {int((views > 0).sum())} tie point(s) dropped: seen "
                        "by one camera only (a point needs two views to be intersected)")
    return tie[:, kept], kept, tuple(shape), dropped


def _usable_frames(st: _State) -> None:
    """Frames whose two ends are seen by at least two cameras; every camera must see
    enough of them (and tie points) for its parameters."""
    seen_end = np.isfinite(st.xy).all(axis=3)                        # (K, T, 2)
    used = (seen_end.sum(axis=0) >= 2).all(axis=1)                   # (T,)
    if used.sum() < MIN_FRAMES:
        raise ValueError(f"wand_xy: both ends of the wand are seen by at least two cameras "
                         f"in {int(used.sum())} of {st.T} frames; calibrate_wand needs >= "
                         f"{MIN_FRAMES}")
    if (~used).any():
        st.messages.append(f"{int((~used).sum())} of {st.T} frames dropped: an end seen by "
                           "fewer than two cameras")
    st.xy[:, ~used] = np.nan
    # "auto" starts from the pinhole camera and adds only what a camera determines
    free = 6 + 1 + len(DISTORTION_MODELS.get(st.distortion, ()))
    for k in range(st.K):
        n_pts = int(seen_end[k, used].sum() + np.isfinite(st.tie[k]).all(axis=1).sum())
        if n_pts == 0:
            raise ValueError(f"wand_xy: camera {st.names[k]} sees the wand in none of the "
                             "usable frames (and no tie point)")
        if n_pts < min_points_per_camera(free):
            raise ValueError(f"wand_xy: camera {st.names[k]} sees {n_pts} wand ends and tie "
                             f"points; its {free} parameters need >= "
                             f"{min_points_per_camera(free)}")
    st.used = used


def _approximations_and_ends(st: _State, focal_px) -> None:
    """Approximations from a guessed (or given) focal length, the ends made consistent
    across cameras, then the approximations again."""
    f0, st.guessed = _focal(focal_px, st.sizes, st.messages)
    nominal = [Camera(f=f0[k], cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h,
                      R=np.eye(3), C=np.zeros(3), name=st.names[k])
               for k, (w, h) in enumerate(st.sizes)]
    pairs_all = np.arange(2 * st.T).reshape(st.T, 2)
    st.bar = Bar(pairs=pairs_all[st.used], length=st.length,
                 sigma=BAR_SIGMA_REL * st.length)
    # RANSAC threshold: generous, the approximations know neither the lens nor f
    threshold = 0.015 * float(st.sizes.max())
    st.pair = _pair(nominal, st.flat(st.xy), st.bar, threshold)
    cams0, _ = _approximations(nominal, st.flat(st.xy), st.bar, st.pair, threshold)
    st.labels = consistent_bar_labels(cams0, st.xy, st.length)
    st.cams0, st.X0 = _approximations(nominal, st.flat(st.labels.xy), st.bar, st.pair,
                                      threshold)


def _bundle(st: _State, robust: bool) -> None:
    """The bundle adjustment (with the lens model chosen first for "auto"); the ends
    checked again with its cameras, and once more adjusted if that changed any labels."""
    settings = BundleParams(loss="soft_l1" if robust else "linear", f_scale=3.0,
                            reject_k=REJECT_K if robust else None)

    def adjust(cams, X, w, intrinsics):
        X = np.where(np.isfinite(X), X, st.X0)          # points a rejection left without
        return bundle_adjust(cams, st.flat(w), X, intrinsics=intrinsics,
                             fixed_exterior=(st.pair[0],), bar=st.bar, sigma_px=st.sigma_px,
                             params=settings)

    def settle(fit, intrinsics):
        """The ends checked with the adjusted cameras; adjusted again if labels changed."""
        try:
            again = consistent_bar_labels(fit.cameras, st.xy, st.length)
        except ValueError as err:        # the lens model folds over inside the image
            raise ValueError(f"distortion: the adjusted {st.distortion!r} lens model cannot "
                             f"be inverted at some observed points ({err}); too few points "
                             "near the image edges for it - try distortion='auto' or "
                             "'k1'") from None
        if np.array_equal(again.swapped, st.labels.swapped):
            return fit
        st.labels = again
        return adjust(fit.cameras, _start_points(fit, again.xy, st.K, st.T, st.tie),
                      again.xy, intrinsics)

    try:
        if st.distortion == "auto":
            bundle, st.intrinsics = _choose_lens(st, adjust, settle)
        else:
            st.intrinsics = [("f",) + DISTORTION_MODELS[st.distortion]] * st.K
            bundle = settle(adjust(st.cams0, st.X0, st.labels.xy, st.intrinsics),
                            st.intrinsics)
    except ValueError as err:
        if not str(err).startswith("f:"):
            raise
        raise ValueError(
            "focal_px: the adjustment diverged to a focal length <= 0 from f = "
            f"{', '.join(f'{c.f:.0f}' for c in st.cams0)} px; give focal_px (a wide-angle "
            "lens is far from the guess max(width, height), a 53 degree field of view; "
            "easyWand and Argus ask for it too)") from None
    if st.labels.n_swapped:
        st.messages.append(f"the two ends were exchanged in {st.labels.n_swapped} camera "
                           "frame(s) to agree with the other cameras")
    if bundle.n_rejected:
        st.messages.append(f"{bundle.n_rejected} observation(s) rejected as outliers "
                           f"(beyond {REJECT_K:g} sigma)")
    st.bundle = bundle


def _choose_lens(st: _State, adjust, settle) -> tuple[BundleResult, list]:
    """``distortion="auto"``: forward selection along :data:`AUTO_LADDER` (the rule of the
    module docstring); the ends' labels checked after every model kept (``settle``).
    Returns the adjustment of the chosen model and its intrinsics."""
    K = st.K
    free = [("f",)] * K
    fit = settle(adjust(st.cams0, st.X0, st.labels.xy, free), free)
    accepted = [(fit, free)]
    for group in AUTO_LADDER:
        xy = st.labels.xy
        trial = [f + group for f in free]
        step = {"parameters": group, "determined_in": [], "F": float("nan"),
                "p_value": float("nan"), "kept": False}
        st.steps.append(step)
        try:
            fit1 = adjust(fit.cameras, fit.points, xy, trial)
        except ValueError as err:        # too few points for the added parameters
            step["reason"] = str(err)
            continue
        det = [_determined(fit, fit1, k, group) for k in range(K)]
        step["determined_in"] = [st.names[k] for k in range(K) if det[k]]
        if not any(det):
            step["reason"] = "determined in no camera"
            continue
        if not all(det):
            trial = [f + group if det[k] else f for k, f in enumerate(free)]
            fit1 = adjust(fit.cameras, fit.points, xy, trial)
        step["F"], step["p_value"] = _f_test(fit, fit1, st.sigma_px, st.bar.sigma)
        if not step["p_value"] < F_TEST_ALPHA:
            step["reason"] = f"F-test: p = {step['p_value']:.3g} >= {F_TEST_ALPHA:g}"
            continue
        step["kept"] = True
        try:
            fit1 = settle(fit1, trial)
        except ValueError:               # folds over: left to the choice below
            pass
        fit, free = fit1, trial
        accepted.append((fit, free))
    # the richest accepted model whose lenses can be inverted at every observed point (k1
    # alone may fold over inside the image where k1 and k2 together do not)
    obs = st.flat(st.labels.xy)
    for fit, free in accepted[::-1]:
        if all(c.invertible(obs[k][np.isfinite(obs[k]).all(axis=1)]).all()
               for k, c in enumerate(fit.cameras)):
            break
        st.messages.append("a lens model the F-test accepted ("
                           + "; ".join(", ".join(f) for f in free)
                           + ") folds over at observed points: the one before it is used")
    chosen = sorted({", ".join(f) for f in free})
    st.messages.append("lens model chosen from the data (distortion='auto'): "
                       + "; ".join(f"{st.names[k]}: {', '.join(free[k])}" for k in range(K))
                       if len(chosen) > 1 else
                       f"lens model chosen from the data (distortion='auto'): {chosen[0]} "
                       "for every camera")
    return fit, free


def _determined(fit0: BundleResult, fit1: BundleResult, k: int, group) -> bool:
    """One of ``group``'s parameters of camera k moved from its held value by more than
    :data:`DETERMINED_SIGMA` standard deviations."""
    c0, c1 = fit0.cameras[k], fit1.cameras[k]
    return any(abs(getattr(c1, n) - getattr(c0, n)) > DETERMINED_SIGMA * fit1.std(k, n)
               for n in group)


def _f_test(fit0: BundleResult, fit1: BundleResult, sigma_px: float,
            bar_sigma: float) -> tuple[float, float]:
    """F statistic and p-value of "the larger model ``fit1`` fits no better than
    ``fit0``", on the image observations both adjustments kept and the wand lengths."""
    both = np.isfinite(fit0.residuals).all(axis=2) & np.isfinite(fit1.residuals).all(axis=2)

    def ssr(fit):
        img = np.sum(fit.residuals[both] ** 2) / sigma_px**2
        return img + np.nansum((fit.bar_residuals / bar_sigma) ** 2)

    n = 2 * int(both.sum()) + int(np.isfinite(fit1.bar_residuals).sum())
    dp = fit1.n_unknowns - fit0.n_unknowns
    r1 = n - fit1.n_unknowns
    s0, s1 = ssr(fit0), ssr(fit1)
    if dp <= 0 or r1 <= 0 or s1 <= 0:
        return float("nan"), 1.0
    F = ((s0 - s1) / dp) / (s1 / r1)
    # the F distribution's survival function (scipy.stats.f.sf, which is 1 below its support),
    # without importing scipy.stats (~0.4 s)
    return float(F), 1.0 if F <= 0 else float(fdtrc(dp, r1, F))


def _result(st: _State, t0: float) -> WandCalibration:
    """The datum (the first camera's frame), the wand scores and the status."""
    bundle, K, T = st.bundle, st.K, st.T
    R0, C0 = np.asarray(bundle.cameras[0].R), bundle.cameras[0].C
    cameras = [c.replace(R=np.asarray(c.R) @ R0.T, C=R0 @ (c.C - C0)) for c in bundle.cameras]
    tie_points = None
    if st.tie_kept.size:
        tie_points = np.full((st.tie_kept.size, 3), np.nan)
        tie_points[st.tie_kept] = (bundle.points[2 * T:] - C0) @ R0.T
        tie_points = tie_points.reshape(st.tie_shape + (3,))
    ends = triangulate(cameras, st.labels.xy.reshape(K, 2 * T, 2), min_angle_deg=0.0).points
    ends = ends.reshape(T, 2, 3)
    lengths = np.linalg.norm(ends[:, 0] - ends[:, 1], axis=1)
    std_pct = float(100 * np.nanstd(lengths, ddof=1) / st.length)
    rms = _rms_2d(np.where(bundle.rejected[..., None], np.nan, bundle.residuals))
    status = WandStatus.OK
    if bundle.sigma0 > 3:
        status = WandStatus.LARGE_RESIDUALS
        st.messages.append(f"residuals {bundle.sigma0:.1f} times sigma_px = {st.sigma_px:g} px")
    elif std_pct > 1.0:
        status = WandStatus.WAND_SCATTER
        st.messages.append(f"the wand lengths scatter by {std_pct:.2f} % (> 1 %)")
    return WandCalibration(
        cameras=cameras, wand_points=ends, wand_lengths=lengths,
        wand_length_std_percent=std_pct, rms_px=rms, tie_points=tie_points,
        n_tie_dropped=st.n_tie_dropped, distortion=st.distortion,
        intrinsics=tuple(tuple(i) for i in st.intrinsics),
        model_steps=tuple(dict(s) for s in st.steps),
        wand_xy=st.labels.xy, swapped=st.labels.swapped, used=st.used, bundle=bundle,
        pair=st.pair, focal_guessed=st.guessed, status=status, messages=tuple(st.messages),
        seconds=time.perf_counter() - t0)
