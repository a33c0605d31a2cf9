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
   per camera the exterior orientation, the focal length and the chosen radial
   distortion are free, the principal point stays at the image centre; robustly (soft-L1
   loss, then rejection of residuals beyond four sigma) unless ``robust=False``;
5. *datum*: the world frame is the first camera's (its centre at the origin, its axes the
   world axes), the scale the wand's;
6. *scores*: the wand's ends intersected with the calibrated cameras (forward
   intersection; not the adjusted points, which carry the length observation) and their
   distance per frame: the scatter of the lengths is the wand score easyWand reports.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from .._validate import as_array, as_scalar
from ..camera import Camera
from ..triangulation import triangulate
from .approximations import next_camera, relative_orientation_start, resect_pnp
from .bundle import Bar, BundleParams, BundleResult, bundle_adjust, min_points_per_camera
from .labels import consistent_bar_labels
from .result import CalibrationResult

MIN_FRAMES = 10
DISTORTION_MODELS = {"none": (), "k1": ("k1",), "k1k2": ("k1", "k2")}
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
        coordinate); rejected observations left out.
    tie_points : (N, 3) array or None
        Adjusted tie points, mm.
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
    wand_xy: np.ndarray
    swapped: np.ndarray
    used: np.ndarray
    pair: tuple
    focal_guessed: bool
    status: WandStatus
    messages: tuple = field(default_factory=tuple)
    seconds: float = 0.0


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
                   distortion: str = "k1", robust: bool = True,
                   sigma_px: float = 1.0) -> WandCalibration:
    """Calibrate K cameras from a wand of known length (see the module docstring).

    Parameters
    ----------
    wand_xy : (K, T, 2, 2) array
        Image positions of the wand's two ends in T frames, px (top-left origin; see
        :func:`lsmta.io.read_xypts`); NaN where a camera does not see an end.
    length : float
        The wand's length (distance between the ends' centres), mm.
    image_sizes : (K, 2) array or (width, height)
        Image sizes in px.
    focal_px : float or (K,) array, optional
        Focal lengths to start from, px; by default ``max(width, height)`` (and a message
        says so). Adjusted either way.
    tie_xy : (K, N, 2) array, optional
        Background points of unknown 3-D position, px, NaN where unseen; each must be seen
        by at least two cameras.
    distortion : {"none", "k1", "k1k2"}
        Radial distortion adjusted per camera.
    robust : bool
        Soft-L1 loss and rejection of residuals beyond four sigma.
    sigma_px : float
        A-priori standard deviation of an image coordinate, px (the weights of the image
        against the wand length, and the unit of the robust loss).

    Returns
    -------
    WandCalibration
        Nothing the caller passed is modified.

    Raises
    ------
    ValueError
        Wrong shapes, a point outside its image (wrong ``image_sizes``), a coordinate
        pair with one NaN, fewer than 10 frames with the wand seen by two cameras, a
        camera that sees the wand in no such frame (or too few to be resected), a tie
        point seen by fewer than two cameras.
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
    tie: np.ndarray                # (K, N, 2)
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
        if distortion not in DISTORTION_MODELS:
            raise ValueError(f"distortion: expected one of {sorted(DISTORTION_MODELS)}, got "
                             f"{distortion!r}")
        names = [f"cam{k + 1}" for k in range(K)]
        _check_observations(xy, sizes, "wand_xy", names)
        if tie_xy is None:
            tie = np.zeros((K, 0, 2))
        else:
            tie = as_array(tie_xy, "tie_xy", shape=(K, None, 2), allow_nan=True)
            _check_observations(tie, sizes, "tie_xy", names)
            few = np.isfinite(tie).all(axis=2).sum(axis=0) < 2
            if few.any():
                raise ValueError(f"tie_xy: {int(few.sum())} tie point(s) are seen by fewer "
                                 "than 2 cameras; each must be seen by at least 2")
        return cls(xy=xy, tie=tie, sizes=sizes, names=names, length=length,
                   sigma_px=sigma_px, distortion=distortion, messages=[])


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
    free = 6 + 1 + len(DISTORTION_MODELS[st.distortion])
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
    """The bundle adjustment; the ends checked again with its cameras, and once more
    adjusted if that changed any labels."""
    intrinsics = ("f",) + DISTORTION_MODELS[st.distortion]
    settings = BundleParams(loss="soft_l1" if robust else "linear", f_scale=3.0,
                            reject_k=REJECT_K if robust else None)

    def adjust(cams, X, w):
        return bundle_adjust(cams, st.flat(w), X, intrinsics=intrinsics,
                             fixed_exterior=(st.pair[0],), bar=st.bar, sigma_px=st.sigma_px,
                             params=settings)

    bundle = adjust(st.cams0, st.X0, st.labels.xy)
    try:
        again = consistent_bar_labels(bundle.cameras, st.xy, st.length)
    except ValueError as err:            # the lens model folds over inside the image
        raise ValueError(f"distortion: the adjusted {st.distortion!r} lens model cannot be "
                         f"inverted at some observed points ({err}); too few points near "
                         "the image edges for it - try distortion='k1'") from None
    if not np.array_equal(again.swapped, st.labels.swapped):
        st.labels = again
        bundle = adjust(bundle.cameras, _start_points(bundle, again.xy, st.K, st.T, st.tie),
                        again.xy)
    if st.labels.n_swapped:
        st.messages.append(f"the two ends were exchanged in {st.labels.n_swapped} camera "
                           "frame(s) to agree with the other cameras")
    if bundle.n_rejected:
        st.messages.append(f"{bundle.n_rejected} observation(s) rejected as outliers "
                           f"(beyond {REJECT_K:g} sigma)")
    st.bundle = bundle


def _result(st: _State, t0: float) -> WandCalibration:
    """The datum (the first camera's frame), the wand scores and the status."""
    bundle, K, T = st.bundle, st.K, st.T
    R0, C0 = np.asarray(bundle.cameras[0].R), bundle.cameras[0].C
    cameras = [c.replace(R=np.asarray(c.R) @ R0.T, C=R0 @ (c.C - C0)) for c in bundle.cameras]
    tie_points = None
    if st.tie.shape[1]:
        tie_points = (bundle.points[2 * T:] - C0) @ R0.T
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
        wand_xy=st.labels.xy, swapped=st.labels.swapped, used=st.used, bundle=bundle,
        pair=st.pair, focal_guessed=st.guessed, status=status, messages=tuple(st.messages),
        seconds=time.perf_counter() - t0)
