"""A rig's cameras refined from its own recording: the calibration stage for a user who has
video files and a camera file from another tool.

Stages: check the cameras against the videos (:func:`lsmta.io.cameras_for_videos`) ->
read evenly spaced frames -> tie points guided by the given cameras
(:func:`lsmta.calibration.find_tie_points`) -> a check that the cameras fit the videos at
all -> cameras adjusted with the given ones as priors
(:func:`lsmta.calibration.refine_cameras`) on some frames -> a check that no camera had
to turn far from the file's orientation -> the residuals of the tie points
of the other frames (held out), with the given and with the refined cameras.

The held-out frames say whether the refinement generalises: tie points that took no part
in the adjustment (and are not a still background's training points seen again at the same
pixels), triangulated with each set of cameras, are reprojected into every view.
A refinement that only absorbed its own tie points' errors lowers the adjusted residuals but
not the held-out ones.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_int, as_scalar, freeze
from ..calibration.refine import CameraRefinement, RefineParams, refine_cameras
from ..calibration.tie_points import TieParams, TiePoints, find_tie_points
from ..camera import cropped_camera, scaled_camera
from ..camera_files import write_camera_toml
from ..io import Videos, cameras_for_videos
from ..triangulation import triangulate


@dataclass(frozen=True)
class RigRefinementParams:
    """Settings of :func:`refine_rig`.

    Attributes
    ----------
    n_frames : int
        Frames sampled evenly over the recording for tie points (>= 2).
    hold_out_every : int
        Every ``hold_out_every``-th sampled frame (the 2nd, 2nd + n, ...) is held out of the
        adjustment to check it (>= 2).
    tie_max_side : int
        Tie points are found in frames halved until their longer side is at most this, px;
        positions are scaled back. ASIFT's time grows with the pixels, and on the Pose2Sim
        demo (1920 px) the tie points found at full size did not generalise to held-out
        frames (median over cameras 4.9 -> 6.0 px) where those found at half size did
        (8.1 -> 2.4 px; ``experiments/capture_demo.py``, before the ratio test's
        ``distinct_px``).
    max_points : int
        Most tie points adjusted; beyond it those seen by the most views are kept (then
        evenly over the rest), which bounds the adjustment's time.
    max_median_px : float
        The given cameras do not fit the videos when the median residual of the tie points
        with them exceeds this in some camera, px.
    max_rotation_deg : float
        ... or when the adjustment turns some camera by more than this away from the file's,
        degrees (a file a few pixels off: a fraction of a degree; cameras in the wrong order
        or another rotation convention: tens, which the tie points then pull it through).
    mismatch : str
        How a video smaller than its camera is taken (:func:`lsmta.io.cameras_for_videos`).
    tie : TieParams
        Its ``band_px`` is in pixels of the videos as stored: it is scaled with them and with
        the working size; its ``ransac_px`` is in pixels of the frames searched.
    refine : RefineParams
    """

    n_frames: int = 6
    hold_out_every: int = 3
    tie_max_side: int = 1024
    max_points: int = 2000
    max_median_px: float = 25.0
    max_rotation_deg: float = 10.0
    mismatch: str = "error"
    tie: TieParams = field(default_factory=TieParams)
    refine: RefineParams = field(default_factory=RefineParams)

    def __post_init__(self):
        as_int(self.n_frames, "n_frames", minimum=2)
        as_int(self.hold_out_every, "hold_out_every", minimum=2)
        as_int(self.max_points, "max_points", minimum=6)
        as_int(self.tie_max_side, "tie_max_side", minimum=64)
        as_scalar(self.max_median_px, "max_median_px", positive=True)
        as_scalar(self.max_rotation_deg, "max_rotation_deg", positive=True)
        if not isinstance(self.tie, TieParams) or not isinstance(self.refine, RefineParams):
            raise TypeError("tie, refine: expected TieParams and RefineParams")


@dataclass(frozen=True)
class RigRefinement:
    """Result of :func:`refine_rig`.

    Attributes
    ----------
    cameras : tuple of K Camera
        The refined cameras, for the frames as the videos deliver them.
    given : tuple of K Camera
        The camera file's cameras fitted to the videos (before the refinement).
    frames : tuple of int
        The recording's frames the tie points come from.
    held_out : (F,) bool array
        Which of those frames were kept out of the adjustment.
    tie_points : TiePoints
    adjustment : CameraRefinement
        The adjustment on the other frames' tie points.
    held_out_points : int
        Tie points of the held-out frames that are not training points seen again.
    held_out_before, held_out_after : (K,) arrays
        Median residual of those points per camera with the given and with the refined
        cameras, px (NaN: none seen).
    """

    cameras: tuple
    given: tuple
    frames: tuple
    held_out: np.ndarray
    tie_points: TiePoints
    adjustment: CameraRefinement
    held_out_points: int
    held_out_before: np.ndarray
    held_out_after: np.ndarray

    def __post_init__(self):
        freeze(self, ("held_out", "held_out_before", "held_out_after"))

    @property
    def improved(self) -> bool:
        """Whether the refined cameras fit the held-out tie points at least as well as the
        given ones in every camera that saw some (the rule for using them)."""
        seen = np.isfinite(self.held_out_before) & np.isfinite(self.held_out_after)
        return bool(seen.any() and np.all(self.held_out_after[seen]
                                          <= self.held_out_before[seen]))

    @property
    def chosen(self) -> tuple:
        """The refined cameras where :attr:`improved`, else the given ones."""
        return self.cameras if self.improved else self.given

    def summary(self) -> dict:
        """Per camera: tie points, median residuals (adjusted and held out, before and
        after), the intrinsics freed; as plain numbers for a JSON file."""
        seen = np.isfinite(self.tie_points.xy[..., 0])
        out = {}
        for k, cam in enumerate(self.cameras):
            out[cam.name or f"camera {k}"] = {
                "tie_points": int(seen[k].sum()),
                "adjusted_before_px": float(self.adjustment.median_residual(before=True)[k]),
                "adjusted_after_px": float(self.adjustment.median_residual()[k]),
                "held_out_before_px": float(self.held_out_before[k]),
                "held_out_after_px": float(self.held_out_after[k]),
                "freed": list(self.adjustment.freed[k]),
            }
        return out

    def save(self, directory) -> dict:
        """Write the refinement where other tools read it: ``cameras.toml`` (the refined
        cameras in the aniposelib / Pose2Sim layout, mm, read back by
        :func:`lsmta.camera_files.read_camera_toml`) and ``refinement.json`` (the frames
        used and held out, and :meth:`summary`; null where a value is not defined). The
        folder is made as needed; returns the paths written, by name."""
        folder = Path(directory)
        folder.mkdir(parents=True, exist_ok=True)
        cameras = write_camera_toml(folder / "cameras.toml", self.cameras, unit="mm")

        def plain(v):
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            if isinstance(v, list | tuple):
                return [plain(x) for x in v]
            return None if isinstance(v, float) and not np.isfinite(v) else v

        record = {"frames": list(self.frames),
                  "held_out_frames": [f for f, h in zip(self.frames, self.held_out) if h],
                  "held_out_points": self.held_out_points, "cameras": self.summary()}
        summary = folder / "refinement.json"
        summary.write_text(json.dumps(plain(record), indent=2), encoding="utf-8")
        return {"cameras": cameras, "summary": summary}


def _held_out_residuals(cameras, xy) -> np.ndarray:
    """Median reprojection residual per camera of tie points triangulated with ``cameras``."""
    out = np.full(len(cameras), np.nan)
    if xy.shape[1] == 0:
        return out
    err = triangulate(list(cameras), xy, min_angle_deg=0.0).reprojection_error
    for k in range(len(cameras)):
        if np.isfinite(err[k]).any():
            out[k] = np.nanmedian(err[k])
    return out


def _new_points(train_xy, test_xy, tol_px: float = 2.0):
    """The held-out tie points that are not training points seen again: a still background
    gives the same feature at the same pixels in every frame. A point is new where, in some
    view, it lies farther than ``tol_px`` from every training point."""
    new = np.zeros(test_xy.shape[1], bool)
    for k in range(len(test_xy)):
        seen = np.isfinite(test_xy[k, :, 0])
        train = train_xy[k][np.isfinite(train_xy[k, :, 0])]
        if not len(train):
            new |= seen
            continue
        d, _ = cKDTree(train).query(test_xy[k, seen])
        new[np.flatnonzero(seen)[d > tol_px]] = True
    return test_xy[:, new]


def _strongest(xy, n: int):
    """At most ``n`` tie points: most views first, then evenly over each view count."""
    views = np.isfinite(xy[..., 0]).sum(axis=0)
    keep = []
    for v in sorted(set(views.tolist()), reverse=True):
        idx = np.flatnonzero(views == v)
        room = n - len(keep)
        if room <= 0:
            break
        keep.extend(idx if len(idx) <= room else
                    idx[np.linspace(0, len(idx) - 1, room).round().astype(int)])
    return xy[:, np.sort(np.asarray(keep, int))]


def _check_fit(given, tie: TiePoints, params: RigRefinementParams) -> None:
    """Refuse cameras that do not fit the videos: no view pair with tie points of its own
    epipolar geometry, or tie points far from where the cameras put them."""
    if tie.pair_matches.sum() == 0 or tie.xy.shape[1] < 6:
        raise ValueError(
            "cameras: the given cameras do not fit the videos: no pair of views has tie "
            f"points in the cameras' epipolar band that agree with a relative orientation of "
            f"their own (band "
            f"{params.tie.band_px:g} px; matches in the band per pair: "
            f"{tie.pair_guided[np.triu_indices(len(given), 1)].tolist()}). Check that the "
            "cameras are in the videos' order, the file's units and image size, and that "
            "the videos are synchronised")
    med = _held_out_residuals(given, tie.xy)
    if np.nanmax(med) > params.max_median_px:
        listed = ", ".join(f"{c.name or k}: {m:.1f} px" for k, (c, m) in enumerate(zip(given, med)))
        raise ValueError(f"cameras: the given cameras do not fit the videos: the tie points lie "
                         f"{listed} (median) from where the cameras put them, more than "
                         f"max_median_px = {params.max_median_px:g}. Check the cameras' order "
                         "and the file's units")


def _tie_points_at_work_size(videos: Videos, given, picks, params) -> TiePoints:
    """Tie points of the picked frames, found in frames halved until their longer side is
    at most ``params.tie_max_side`` and scaled back to the frames as delivered."""
    longest = max(max(c.width, c.height) for c in given)
    halvings = max(0, int(np.ceil(np.log2(longest / params.tie_max_side))))
    factor, m = 0.5 ** halvings, 2 ** halvings
    # right and bottom edges cut to a multiple of 2^halvings: every scale is exact
    sizes = [(c.width - c.width % m, c.height - c.height % m) for c in given]
    cams = [scaled_camera(cropped_camera(c, 0, 0, w, h), factor)
            for c, (w, h) in zip(given, sizes)] if halvings else list(given)
    images = []
    for i in picks:
        frame = videos.read(int(i))
        images.append([cv2.resize(g[:h, :w], (c.width, c.height), interpolation=cv2.INTER_AREA)
                       if halvings else g for g, c, (w, h) in zip(frame, cams, sizes)])
    tie_params = replace(params.tie, band_px=params.tie.band_px * videos.scale * factor)
    tie = find_tie_points(images, cams, params=tie_params)
    return replace(tie, xy=(tie.xy + 0.5) / factor - 0.5) if halvings else tie


def _check_turn(given, refined, limit_deg: float) -> None:
    """Refuse a refinement that had to turn cameras far from the file's orientation."""
    turn = np.array([np.degrees(np.arccos(np.clip(
        (np.trace(np.asarray(r.R) @ np.asarray(g.R).T) - 1.0) / 2.0, -1.0, 1.0)))
        for g, r in zip(given, refined)])
    if (turn > limit_deg).any():
        listed = ", ".join(f"{g.name or k}: {t:.1f} deg" for k, (g, t) in
                           enumerate(zip(given, turn)) if t > limit_deg)
        raise ValueError(f"cameras: the given cameras do not fit the videos: the tie points "
                         f"turn them far from the file's orientation ({listed}; more than "
                         f"max_rotation_deg = {limit_deg:g}). Check the cameras' order and the "
                         "file's rotation convention; if they are right, the tie points do not "
                         "hold these cameras (too few, or in one small part of the view)")


def refine_rig(videos: Videos, cameras, *,
               params: RigRefinementParams | None = None) -> RigRefinement:
    """Refine a camera file's cameras from the recording itself.

    Parameters
    ----------
    videos : lsmta.io.Videos
        The synchronised recording (:func:`lsmta.io.read_videos`), one video per camera.
    cameras : sequence of K Camera
        The cameras as read from a camera file (:mod:`lsmta.camera_files`), in the videos'
        order, for the videos as stored (crop and scale of ``videos`` are applied here).
    params : RigRefinementParams, optional

    Returns
    -------
    RigRefinement

    Raises
    ------
    ValueError
        Cameras that do not fit the videos (sizes, count, tie points far from where the
        cameras put them, or an adjustment that turns a camera far from the file's
        orientation), with what was found.
    """
    params = RigRefinementParams() if params is None else params
    if not isinstance(videos, Videos):
        raise TypeError("videos: expected lsmta.io.Videos (from lsmta.io.read_videos)")
    given = tuple(cameras_for_videos(cameras, videos, mismatch=params.mismatch))
    n = min(params.n_frames, videos.n_frames)
    picks = np.unique(np.linspace(0, videos.n_frames - 1, n).round().astype(int))
    tie = _tie_points_at_work_size(videos, given, picks, params)
    _check_fit(given, tie, params)
    held = (np.arange(len(picks)) % params.hold_out_every) == 1
    train = ~held[tie.frame]
    adjustment = refine_cameras(given, _strongest(tie.xy[:, train], params.max_points),
                                params=params.refine)
    _check_turn(given, adjustment.cameras, params.max_rotation_deg)
    test_xy = _new_points(tie.xy[:, train], tie.xy[:, ~train])
    before = _held_out_residuals(given, test_xy)
    after = _held_out_residuals(adjustment.cameras, test_xy)
    worse = [c.name or str(k) for k, (c, b, a) in enumerate(zip(given, before, after)) if a > b]
    if worse:
        warnings.warn(f"refine_rig: the refined cameras fit the held-out frames' tie points "
                      f"worse than the given ones in {', '.join(worse)} (see summary()); the "
                      "tie points may not determine them: keep the given cameras there",
                      stacklevel=2)
    return RigRefinement(
        cameras=adjustment.cameras, given=given,
        frames=tuple(int(videos.frames[i]) for i in picks), held_out=held, tie_points=tie,
        adjustment=adjustment, held_out_points=int(test_xy.shape[1]),
        held_out_before=before, held_out_after=after)
