"""A rig's cameras refined from its own recording: the calibration stage for a user who has
video files and a camera file from another tool.

Stages: check the cameras against the videos (:func:`lsmta.io.cameras_for_videos`) ->
read evenly spaced frames -> tie points guided by the given cameras
(:func:`lsmta.calibration.find_tie_points`) -> the tie points refined by least squares
matching in the frames they were found in (:func:`lsmta.calibration.refine_tie_points`;
``lsm``) -> a check that the cameras fit the videos at all -> the tie points grouped into
places -> cameras adjusted with the given ones as priors
(:func:`lsmta.calibration.refine_cameras`) on most places -> a check that no camera had
to turn far from the file's orientation -> the residuals of the held-out places, with the
given and with the refined cameras.

Places. A still background gives the same feature at the same pixels in every frame: the
tie points of different frames that agree within ``place_px`` in every view they share are
one place, adjusted once at its median position (a feature found in six frames is not six
independent observations). A moving subject's feature is a place of one frame. First, tie
points of one frame within the tie-point finder's ``distinct_px`` of each other in every view
they share are one feature found twice (ASIFT's tilts, SIFT's orientations; :func:`_twins`),
joined at their median; then a place holds at most one such feature per frame and spans at
most ``place_px`` in every view; a chain that breaks this is split into its single features
(:func:`_places`; both: :func:`_feature_places`). On the Pose2Sim demo twins had broken the
rear pair's still features into one-frame places, each counted several times among the
held-out ones.

Held out. Every ``hold_out_every``-th still place, and the one-frame places of every
``hold_out_every``-th frame, take no part in the adjustment, nor does any other place with a
point within ``place_px`` of a held-out place's point in some view (a feature matched in
different views in different frames splits into several places, which would otherwise land
on both sides); triangulated with each set of cameras and reprojected into every view, they
say whether the refinement generalises. The residuals reported are those of the held-out
still places where every camera sees at least ``min_still_held`` of them, else (with a
warning) of all held-out places. Holding out frames alone (as before) measured only the
moving subject's points, since a still place of a held-out frame is a training place seen
again: on the Pose2Sim demo those stay at 0.8-0.9 px on the neighbouring pair cam01-cam02
with the file's and with the refined cameras (they measure the moving points, not the
cameras), while held-out still places go from 1.2-1.4 to 0.9-1.0 px there
(``experiments/refinement_held_out.py``).

One geometry for the recording (``TieParams.recording_geometry``, off by default). The tie
points are found with each frame's pairs checked against their own relative orientation
only; AFTER the split above, the places to adjust must agree, in each view pair, with ONE
relative orientation fitted to those places alone (:func:`lsmta.calibration.recording_inliers`:
MAGSAC++, ``ransac_px`` of the frames searched; a pair with fewer than ``min_matches`` gives
none); the others are kept out of the adjustment (:attr:`RigRefinement.inconsistent_places`).
The held-out places never pass through it: they are judged as matched per frame (each
frame's own fit, twins joined), so the check can neither clean the judging set nor be fitted
on it. So applied, it made the Pose2Sim demo's judged held-out residuals worse in cam03 (and
most other cameras) on two frame splits at full size, so it is off by default (README).

Least squares matching (``lsm``, on by default). The tie points are keypoints, each view's
own estimate of its feature's position; :func:`lsmta.calibration.refine_tie_points` moves
them, in the frames they were found in, to where each view shows the template view's patch,
before they are grouped into places. It uses the frames and the given cameras only (they
give each point's template view and local plane), not the adjustment, so the held-out
places stay held out. On the Pose2Sim demo at full size (frames 0-99,
``experiments/refinement_held_out.py`` with ``--lsm both``; two runs, each adjusted and judged
on its own places) it drops 676 of 1125 tie points (failed matches), and the adjusted
places' median residual is 0.26/0.37/0.10/0.14 px (cam01-cam04) with it against
0.63/0.60/0.60/0.54 without. The held-out still places are another matter: without the
matching 44 of them, at 1.04/0.95/1.10/0.89 px with that run's cameras; with it only 19
(15/14/4/5 per camera), at 0.30/0.23/0.30/0.24 px at their matched positions, which that
run's cameras were fitted to. Different places at different positions: the two do not
compare the runs' cameras (the experiment's ``common`` scores both on the places held out
of both runs: 4, too few to compare them). cam03 and
cam04 see fewer than ``min_still_held`` of them, so that run is judged on all held-out
places (0.25/0.23/0.60/0.46 px): the 0.5-px target was NOT met there (cam03), by copies of
twins and false matches of repeated structure among the held-out places. With twins joined
(:func:`_twins`; the default) it is still NOT met: 0.27/0.25/2.59/0.71 px (70 moving and 21
still places; cam03 sees 23 of them), and on another frame split (7 sampled frames, held out
16 and 66, never inspected) 0.29/0.28/1.29/0.78 px, while the adjusted places fit to
0.11-0.37 px; with the recording's one geometry on the adjusted places as well (off by
default) 0.26/0.24/4.06/2.28 and 0.26/0.34/3.54/0.76 px (README, "Your own recording").
The rear views' held-out places are mostly the moving subject's, matched in one frame, which
each frame's own fit lets through wrong.
Two options keep more still places of the wide pairs (``lsm_still_once``: a still feature
matched once over its frames; ``TieLSMParams.larger_patches``: failed matches retried with
larger patches) but each made some camera's judged held-out residual worse there, so both
are off by default (the numbers in their docstrings).

More frames for still places (``still_between``, off by default). A still place needs its
feature matched at the same pixels in two frames; on a wide pair each frame keeps some tens of
matches, so among ``n_frames`` few features are matched twice. ``still_between`` frames
between each two sampled ones are searched too; their tie points join places like any other,
and a place of one of them alone (the moving subject's) is neither adjusted nor held out, so
the held-out frames stay the sampled frames' (which places are held out is drawn again:
the in-between frames' points join the labels the draw ranks). On the Pose2Sim demo at
full size (``experiments/refinement_held_out.py --lsm on --still-between 2``, 10 or 12 more
frames) the still places grew from 63 to 97 (frames 0-99 in 6, held out 20 and 79), the rear
pair's from 11 to 17 (4 held out in both), cam03's held-out still places from 5 to 7 and
cam04's from 5 to 14; at 7 sampled frames (held out 16 and 66) the rear pair had 19 (6 held
out), cam03 8 held-out still places. The rear pair grows slowly: more frames mostly find the
same few features again. All held-out places went from 0.27/0.25/2.59/0.71 to
0.32/0.27/1.18/0.63 px (cam01-cam04) and, at 7 frames, from 0.29/0.28/1.29/0.78 to
0.36/0.38/1.40/0.49 px: worse in some camera on both splits, so off by default (the rule of
the options above), and it costs 6-9 s of CPU per frame added at full size. On a split not
inspected while designing it (8 sampled frames, held out 14, 57 and 99) it gave cam03 10
held-out still places (4 without) at 0.60 px (NOT met), the others 0.45/0.40/0.47 px; all
its held-out places 0.42/0.37/0.91/0.62 px (NOT met). With 4 between
(6 sampled frames) all held-out places came to 0.25/0.19/0.39/0.39 px (cam03 with 7
held-out still places), but at 7 and 8 sampled frames cam03 had 15 and 13 held-out still
places, at 1.33 and 1.80 px: its residual is not only the moving subject's wrong matches
(README).

A refined camera whose lens model cannot be inverted everywhere in its frame
(:func:`_folds`: the fitted distortion folds over inside it) makes the whole refinement
unused (:attr:`RigRefinement.folded`; warned): the other cameras were adjusted with it.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .._validate import as_int, as_scalar, freeze
from ..build_cache import cached_result
from ..calibration.refine import CameraRefinement, RefineParams, refine_cameras
from ..calibration.tie_lsm import TieLSM, TieLSMParams, refine_tie_points
from ..calibration.tie_points import (
    TieParams,
    TiePoints,
    find_tie_points,
    recording_inliers,
)
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
        Every ``hold_out_every``-th still place (the 2nd, 2nd + n, ...) and the moving
        subject's places in every ``hold_out_every``-th sampled frame are held out of the
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
    place_px : float
        Tie points of different frames within this of each other in every view they share
        (at least two) are one place, px of the videos as stored (scaled with them).
    min_still_held : int
        The held-out residuals are those of the held-out still places where every camera
        sees at least this many, else of all held-out places.
    mismatch : str
        How a video smaller than its camera is taken (:func:`lsmta.io.cameras_for_videos`).
    tie : TieParams
        Its ``band_px`` is in pixels of the videos as stored: it is scaled with them and with
        the working size; its ``ransac_px`` is in pixels of the frames searched. Its
        ``recording_geometry`` is checked here after the hold-out split, on the places to
        adjust only (:func:`_off_geometry`), not in :func:`lsmta.calibration.find_tie_points`.
    lsm : bool
        Refine the tie points by least squares matching before they are grouped into places
        (:func:`lsmta.calibration.refine_tie_points`), in the frames they were found in (the
        working size; see that module for why not the full size): the keypoints' positions
        move to where each view shows the template view's patch; failed matches are dropped
        and counted (:attr:`RigRefinement.lsm`). It uses the frames and the given cameras
        only, never the adjustment: held-out places stay held out.
    tie_lsm : TieLSMParams
        Its pixels are those of the frames searched for tie points (the working size).
    lsm_still_once : bool
        With ``lsm``: a still feature (tie points of different frames within ``place_px`` of
        each other in every view they share, :func:`_feature_places` on the positions as
        found) is matched once, with one template position, its best converged match over its frames
        taken for all of them (``groups`` of :func:`lsmta.calibration.refine_tie_points`);
        else each tie point alone, and a still feature whose match fails in some frames or
        lands apart in others breaks into one-frame places. Default False, by the rule that a
        matching rule is on by default only if it worsens no camera's judged held-out
        residual at full size on the Pose2Sim demo: on, it kept more held-out still places in
        all (22 against 19) but fewer in cam03 and cam04 (19/19/3/3 per camera against
        15/14/4/5), and the judged residuals went from
        0.25/0.23/0.60/0.46 to 0.24/0.25/0.96/0.73 px (cam01-cam04,
        ``experiments/refinement_held_out.py --lsm on --lsm-once --larger-patches none``).
    still_between : int
        Frames searched for still places only, between each two sampled frames (evenly, at
        least one frame from either; 0: none). A still place needs its feature matched at
        the same pixels in two frames, and on a wide pair each frame's own relative
        orientation keeps only some tens of matches, so few features are matched twice among
        ``n_frames``; more frames give more still places without changing the moving
        subject's hold-out split. Their tie points join places like any other; a place of one
        of these frames alone (the moving subject's) is neither adjusted nor held out
        (:attr:`RigRefinement.unused_places`). Each costs a frame's tie-point search and
        matching. Default 0: on the Pose2Sim demo 2 gave more still places, the rear pair's
        too, but a worse held-out residual in some camera on both splits measured (module
        docstring).
    refine : RefineParams
    """

    n_frames: int = 6
    hold_out_every: int = 3
    tie_max_side: int = 1024
    max_points: int = 2000
    max_median_px: float = 25.0
    max_rotation_deg: float = 10.0
    place_px: float = 2.0
    min_still_held: int = 10
    mismatch: str = "error"
    tie: TieParams = field(default_factory=TieParams)
    lsm: bool = True
    tie_lsm: TieLSMParams = field(default_factory=TieLSMParams)
    lsm_still_once: bool = False
    still_between: int = 0
    refine: RefineParams = field(default_factory=RefineParams)

    def __post_init__(self):
        as_int(self.n_frames, "n_frames", minimum=2)
        as_int(self.hold_out_every, "hold_out_every", minimum=2)
        as_int(self.max_points, "max_points", minimum=6)
        as_int(self.tie_max_side, "tie_max_side", minimum=64)
        as_scalar(self.max_median_px, "max_median_px", positive=True)
        as_scalar(self.max_rotation_deg, "max_rotation_deg", positive=True)
        as_scalar(self.place_px, "place_px", positive=True)
        as_int(self.min_still_held, "min_still_held", minimum=1)
        as_int(self.still_between, "still_between", minimum=0)
        if not isinstance(self.tie, TieParams) or not isinstance(self.refine, RefineParams):
            raise TypeError("tie, refine: expected TieParams and RefineParams")
        if not isinstance(self.lsm, bool):
            raise TypeError(f"lsm: expected True or False, got {self.lsm!r}")
        if not isinstance(self.tie_lsm, TieLSMParams):
            raise TypeError("tie_lsm: expected TieLSMParams")
        if not isinstance(self.lsm_still_once, bool):
            raise TypeError(f"lsm_still_once: expected True or False, got "
                            f"{self.lsm_still_once!r}")


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
        The recording's frames the tie points come from: the ``n_frames`` sampled ones, then
        those searched for still places only (``still_between``).
    held_out : (F,) bool array
        Which of those frames' places of one frame (a moving subject's) were kept out of
        the adjustment.
    still_search : (F,) bool array
        Which of those frames were searched for still places only.
    tie_points : TiePoints
        The tie points adjusted and held out: refined by least squares matching with
        ``params.lsm`` (the failed ones dropped), else as found.
    raw_tie_points : TiePoints
        The tie points as found (the keypoints' positions, scaled back).
    lsm : TieLSM or None
        What the least squares matching did (None without ``params.lsm``); its arrays are
        over ``raw_tie_points``.
    places : (N,) int array
        The place of each tie point (:func:`_feature_places`: a frame's twins joined, then
        a still background's feature found again at the same pixels in other frames is one
        place).
    still : (P,) bool array
        Places found in two or more frames.
    held_out_places : (P,) bool array
        Places kept out of the adjustment: every ``hold_out_every``-th still place and the
        one-frame places of the held-out frames.
    unused_places : (P,) bool array
        Places of one frame searched for still places only (``still_search``): neither
        adjusted nor held out.
    dropped_places : (P,) bool array
        Places kept out of the adjustment though not held out: those with a point within
        ``place_px``, in some view, of a held-out place's point (a piece of a held-out
        feature that did not join it; see :func:`_near_held_out`).
    inconsistent_places : (P,) bool array
        Places to adjust that some view pair's one relative orientation for the recording,
        fitted to those places only, rejects (``params.tie.recording_geometry``,
        :func:`lsmta.calibration.recording_inliers`); kept out of the adjustment. The
        held-out places never pass through this check.
    held_out_kind : {"still places", "all places"}
        Which held-out places the residuals below are of: the still ones where every camera
        sees at least ``min_still_held`` of them, else all (a weaker judgement: the moving
        subject's points measure the points more than the cameras; warned).
    adjustment : CameraRefinement
        The adjustment on the other places (one tie point per place, its median position).
    held_out_points : int
        Held-out places measured.
    held_out_before, held_out_after : (K,) arrays
        Median residual of those places per camera with the given and with the refined
        cameras, px (NaN: none seen).
    held_out_still_before, held_out_still_after : (K,) arrays
        The same for the held-out still places alone, px.
    held_out_all_before, held_out_all_after : (K,) arrays
        The same for all held-out places, px.
    held_out_still_points, held_out_all_points : int
        How many places those are.
    folded : tuple of str
        The refined cameras (by name, else index) whose lens model cannot be inverted
        everywhere in the frame (:func:`_folds`: the fitted distortion folds over inside
        it, so rays, and every stage after, fail at some pixels). Any at all: the refinement
        is not used (:attr:`improved` is False, :attr:`chosen` the given cameras); rejecting
        only that camera's intrinsics would leave the other cameras adjusted against it.
    """

    cameras: tuple
    given: tuple
    frames: tuple
    held_out: np.ndarray
    still_search: np.ndarray
    tie_points: TiePoints
    raw_tie_points: TiePoints
    lsm: TieLSM | None
    places: np.ndarray
    still: np.ndarray
    held_out_places: np.ndarray
    unused_places: np.ndarray
    dropped_places: np.ndarray
    inconsistent_places: np.ndarray
    held_out_kind: str
    adjustment: CameraRefinement
    held_out_points: int
    held_out_before: np.ndarray
    held_out_after: np.ndarray
    held_out_still_before: np.ndarray
    held_out_still_after: np.ndarray
    held_out_all_before: np.ndarray
    held_out_all_after: np.ndarray
    held_out_still_points: int
    held_out_all_points: int
    folded: tuple

    def __post_init__(self):
        freeze(self, ("held_out", "still_search", "places", "still", "held_out_places",
                      "unused_places", "dropped_places",
                      "inconsistent_places",
                      "held_out_before", "held_out_after", "held_out_still_before",
                      "held_out_still_after", "held_out_all_before", "held_out_all_after"))

    @property
    def place_xy(self) -> np.ndarray:
        """(K, P, 2) position of each place per view, px: the median over its tie points
        (NaN where none of them is seen in that view)."""
        return _merged(self.tie_points.xy, self.places)

    @property
    def raw_place_xy(self) -> np.ndarray:
        """(K, P, 2) :attr:`place_xy` from the same tie points and views as found, before the
        least squares matching (the same as :attr:`place_xy` without it): the two side by
        side say what the matching changed, with any cameras."""
        if self.lsm is None:
            return self.place_xy
        raw = self.raw_tie_points.xy[:, self.lsm.kept]
        return _merged(np.where(np.isfinite(self.tie_points.xy), raw, np.nan), self.places)

    def held_out_residuals(self, *, cameras=None, raw: bool = False) -> np.ndarray:
        """(K,) median residual per camera of the held-out places that judge the refinement
        (``held_out_kind``), intersected with ``cameras`` (default: the refined ones), at
        their positions refined by least squares matching or (``raw``) as found, px."""
        sel = self.held_out_places & (self.still if self.held_out_kind == "still places"
                                      else True)
        xy = (self.raw_place_xy if raw else self.place_xy)[:, sel]
        return _held_out_residuals(self.cameras if cameras is None else cameras, xy)

    @property
    def improved(self) -> bool:
        """Whether the refined cameras fit the held-out places at least as well as the
        given ones in every camera that saw some, and none of them :attr:`folded` (the
        rule for using them)."""
        seen = np.isfinite(self.held_out_before) & np.isfinite(self.held_out_after)
        return bool(not self.folded and seen.any() and np.all(self.held_out_after[seen]
                                          <= self.held_out_before[seen]))

    @property
    def chosen(self) -> tuple:
        """The refined cameras where :attr:`improved`, else the given ones."""
        return self.cameras if self.improved else self.given

    def summary(self) -> dict:
        """Per camera: tie points, median residuals (adjusted and held out, before and
        after: those judged by, ``held_out_kind``, also at the tie points' positions as found
        (:meth:`held_out_residuals`), and of the held-out still places and of all held-out
        places), the held-out still places it sees, the intrinsics freed; as plain numbers
        for a JSON file."""
        seen = np.isfinite(self.tie_points.xy[..., 0])
        raw = self.held_out_residuals(raw=True)
        held_still = np.isfinite(self.place_xy[:, self.held_out_places & self.still, 0])
        out = {}
        for k, cam in enumerate(self.cameras):
            out[cam.name or f"camera {k}"] = {
                "tie_points": int(seen[k].sum()),
                "adjusted_before_px": float(self.adjustment.median_residual(before=True)[k]),
                "adjusted_after_px": float(self.adjustment.median_residual()[k]),
                "held_out_before_px": float(self.held_out_before[k]),
                "held_out_after_px": float(self.held_out_after[k]),
                "held_out_after_raw_positions_px": float(raw[k]),
                "held_out_still_before_px": float(self.held_out_still_before[k]),
                "held_out_still_after_px": float(self.held_out_still_after[k]),
                "held_out_still_places": int(held_still[k].sum()),
                "held_out_all_before_px": float(self.held_out_all_before[k]),
                "held_out_all_after_px": float(self.held_out_all_after[k]),
                "freed": list(self.adjustment.freed[k]),
                "folds": (cam.name or str(k)) in self.folded,
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
                  "held_out_points": self.held_out_points,
                  "held_out_kind": self.held_out_kind,
                  "held_out_still_points": self.held_out_still_points,
                  "held_out_all_points": self.held_out_all_points,
                  "still_search_frames": [f for f, s in zip(self.frames, self.still_search)
                                          if s],
                  "places": int(len(self.still)), "still_places": int(self.still.sum()),
                  "unused_places": int(self.unused_places.sum()),
                  "dropped_places": int(self.dropped_places.sum()),
                  "inconsistent_places": int(self.inconsistent_places.sum()),
                  "lsm": None if self.lsm is None else self.lsm.summary(),
                  "folded": list(self.folded), "used_refined": self.improved,
                  "cameras": self.summary()}
        summary = folder / "refinement.json"
        summary.write_text(json.dumps(plain(record), indent=2), encoding="utf-8")
        return {"cameras": cameras, "summary": summary}


def _held_out_residuals(cameras, xy) -> np.ndarray:
    """Median reprojection residual per camera of tie points triangulated with ``cameras``
    (a view's point where that camera's lens model cannot be inverted is left out: a refined
    camera whose distortion folds over, :func:`_folds`, gives it no ray)."""
    out = np.full(len(cameras), np.nan)
    if xy.shape[1] == 0:
        return out
    seen = np.isfinite(xy[..., 0])
    ok = np.zeros_like(seen)
    for k, cam in enumerate(cameras):
        ok[k, seen[k]] = cam.invertible(xy[k, seen[k]])
    xy = np.where(ok[..., None], xy, np.nan)
    err = triangulate(list(cameras), xy, min_angle_deg=0.0).reprojection_error
    for k in range(len(cameras)):
        if np.isfinite(err[k]).any():
            out[k] = np.nanmedian(err[k])
    return out


def _places(xy, tol_px: float, frame=None) -> np.ndarray:
    """Label each tie point with its place: points (of any frames) that lie within
    ``tol_px`` of each other in every view they share, sharing at least two, are joined
    (connected components). A still background gives the same feature at the same pixels in
    every frame, so its place holds a point per frame; a moving subject's point is a place
    of its own.

    Chaining is guarded: a component is a place only if it holds at most one point per frame
    (when ``frame`` is given) and its points lie within ``tol_px`` of each other in every
    view (the largest distance between two of its points seen in that view). Joining pairs
    alone would chain a moving point of frame 0 to one of frame 2 and on to frame 4 into one
    'still' place several ``tol_px`` across. A component that breaks either rule is split
    into its single points, each a place of one frame: moving points that pass one another's
    pixels never form a still place (a still feature whose repeats scatter wider than
    ``tol_px`` is lost as a still place, and its pieces are kept from training next to a
    held-out one by :func:`_near_held_out`).

    Returns ``(N,)`` labels, numbered in the order of each place's first point."""
    K, N, _ = xy.shape
    seen = np.isfinite(xy[..., 0])
    near = [np.flatnonzero(seen[k])[cKDTree(xy[k, seen[k]]).query_pairs(
        tol_px, output_type="ndarray")] for k in range(K) if seen[k].sum() > 1]
    return _grouped(xy, near, tol_px, frame)


def _twins(xy, frame, twin_px: float) -> np.ndarray:
    """Label each tie point with its feature: points of ONE frame within ``twin_px`` of each
    other in every view they share, sharing at least two, are one feature found twice (ASIFT
    finds a feature again under several simulated tilts and SIFT gives it one keypoint per
    dominant orientation: the twins :class:`lsmta.calibration.TieParams`' ``distinct_px``
    keeps from rejecting each other as rivals). A group of twins is one feature only if its
    points lie within ``twin_px`` of each other in every view (else each is its own).

    Returns ``(N,)`` labels, numbered in the order of each feature's first point. Without
    this a feature found twice in a frame is two places of that frame and breaks the still
    place of its other frames into one-frame places (:func:`_places` keeps one point per
    frame)."""
    K = xy.shape[0]
    seen = np.isfinite(xy[..., 0])
    near = []
    for f in np.unique(frame):
        idx = np.flatnonzero(frame == f)
        for k in range(K):
            s = idx[seen[k, idx]]
            if len(s) > 1:
                near.append(s[cKDTree(xy[k, s]).query_pairs(twin_px, output_type="ndarray")])
    return _grouped(xy, near, twin_px)


def _grouped(xy, near, tol_px: float, frame=None) -> np.ndarray:
    """(N,) labels of :func:`_places` and :func:`_twins`: the candidate pairs ``near`` (a
    list of (n, 2) index arrays, points within ``tol_px`` in some view) joined where they
    share two views and lie within ``tol_px`` in every view they share; a component wider
    than ``tol_px`` in some view, or (``frame`` given) holding two points of one frame,
    split into its single points; labels in the order of each group's first point."""
    N = xy.shape[1]
    seen = np.isfinite(xy[..., 0])
    pairs = np.unique(np.concatenate(near).reshape(-1, 2), axis=0) if near else \
        np.zeros((0, 2), int)
    i, j = pairs[:, 0], pairs[:, 1]
    shared = seen[:, i] & seen[:, j]
    with np.errstate(invalid="ignore"):
        far = np.linalg.norm(xy[:, i] - xy[:, j], axis=2) > tol_px
    same = (shared.sum(axis=0) >= 2) & ~(far & shared).any(axis=0)
    graph = coo_matrix((np.ones(int(same.sum())), (i[same], j[same])), shape=(N, N))
    n, labels = connected_components(graph, directed=False)
    order = np.argsort(labels, kind="stable")
    for g in np.split(order, np.flatnonzero(np.diff(labels[order])) + 1):
        if len(g) < 2:
            continue
        v = xy[:, g]                                                       # (K, n, 2)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)                # no shared view
            dist = np.nan_to_num(np.nanmax(np.linalg.norm(v[:, :, None] - v[:, None],
                                                          axis=-1), axis=0))
        if frame is not None:
            dist[frame[g][:, None] == frame[g][None]] = np.inf
        np.fill_diagonal(dist, 0.0)
        if dist.max() > tol_px:                                # split into its points
            labels[g[1:]] = n + np.arange(len(g) - 1)
            n += len(g) - 1
    _, first = np.unique(labels, return_index=True)        # renumber: first point's order
    order = np.empty(len(first), int)
    order[np.argsort(first)] = np.arange(len(first))
    return order[labels]


def _feature_places(xy, frame, tol_px: float, twin_px: float) -> np.ndarray:
    """(N,) place of each tie point: twins (:func:`_twins`) joined first, each feature at
    the median of its twins, then the features grouped into places (:func:`_places`)."""
    twins = _twins(xy, frame, twin_px)
    first = np.unique(twins, return_index=True)[1]
    return _places(_merged(xy, twins), tol_px, frame[first])[twins]


def _near_held_out(xy, labels, held, tol_px: float) -> np.ndarray:
    """(P,) bool: the places not held out with a point within ``tol_px``, in any view, of
    a point of a held-out place. A background feature matched in different views in
    different frames splits into several places (joining needs two shared views); kept in
    the adjustment, a piece next to a held-out one would let the held-out place be fitted."""
    near = np.zeros(len(held), bool)
    for k in range(xy.shape[0]):
        seen = np.isfinite(xy[k, :, 0])
        test = seen & held[labels]
        train = seen & ~held[labels]
        if not test.any() or not train.any():
            continue
        d, _ = cKDTree(xy[k, test]).query(xy[k, train], distance_upper_bound=tol_px)
        near[labels[np.flatnonzero(train)[d <= tol_px]]] = True
    return near


def _merged(xy, labels) -> np.ndarray:
    """(K, P, 2) position of each place per view: the median over its points (NaN where no
    point of it is seen in that view), places in the order of their labels.

    All places at once: each view's coordinate sorted by place, then by value (NaN last),
    the median the half-sum of the middle two finite values (of the middle one twice), as
    ``np.nanmedian`` computes it, so the same numbers bit for bit (one ``np.nanmedian`` call
    per place took seconds for some thousand places)."""
    K, N = xy.shape[:2]
    _, place = np.unique(labels, return_inverse=True)
    P = int(place.max()) + 1 if N else 0
    start = np.searchsorted(np.sort(place), np.arange(P))        # each place's first slot
    out = np.full((K, P, 2), np.nan)
    for k in range(K):
        for c in range(2):
            v = xy[k, :, c]
            ordered = v[np.lexsort((v, place))]                  # NaN last within a place
            n = np.bincount(place, weights=np.isfinite(v), minlength=P).astype(int)
            lo, hi = start + np.maximum(n - 1, 0) // 2, start + n // 2
            with np.errstate(invalid="ignore"):
                out[k, :, c] = np.where(n > 0, (ordered[lo] + ordered[hi]) / 2.0, np.nan)
    return out


def _hold_out(labels, frame, held_frames, every: int):
    """Which places are held out, and which are still (found in >= 2 frames): every
    ``every``-th still place (the 2nd, 2nd + every, ...) with all its points, and the
    places of one frame (a moving subject's) found in a held-out frame."""
    n = labels.max() + 1
    frames = np.zeros((n, len(held_frames)), bool)
    frames[labels, frame] = True
    still = frames.sum(axis=1) >= 2
    rank = np.cumsum(still) - 1
    first = np.argmax(frames, axis=1)
    held = np.where(still, rank % every == 1, held_frames[first])
    return held, still


def _warn_worse(given, before, after) -> None:
    """Warn where the refined cameras fit the held-out places worse than the given ones."""
    worse = [c.name or str(k) for k, (c, b, a) in enumerate(zip(given, before, after)) if a > b]
    if worse:
        warnings.warn(f"refine_rig: the refined cameras fit the held-out places "
                      f"worse than the given ones in {', '.join(worse)} (see summary()); the "
                      "tie points may not determine them: keep the given cameras there",
                      stacklevel=5)


def _between(picks, m: int) -> np.ndarray:
    """Frames searched for still places only: ``m`` evenly between each two consecutive
    ``picks`` (sorted frame indices), rounded; none that is a pick, fewer where a gap is
    narrower than ``m + 1`` frames."""
    out = []
    for a, b in zip(picks[:-1], picks[1:]):
        take = np.unique(np.round(a + (b - a) * np.arange(1, m + 1) / (m + 1)).astype(int))
        out.extend(int(t) for t in take if a < t < b)
    return np.asarray(out, int)


def _split(tie: TiePoints, labels, held_frames, search, tol_px: float, every: int):
    """(P,) bool masks ``(held, still, unused, dropped)`` of the places ``labels``:
    :func:`_hold_out`; the places of one frame searched for still places only (``search``,
    (F,) bool), neither adjusted nor held out; and the others next to a held-out place
    (:func:`_near_held_out`)."""
    held, still = _hold_out(labels, tie.frame, held_frames, every)
    frame_of = np.empty(len(held), int)
    frame_of[labels] = tie.frame                          # one-frame places: their frame
    unused = ~still & search[frame_of]
    dropped = _near_held_out(tie.xy, labels, held, tol_px) & ~unused
    return held, still, unused, dropped


def _judged_on(still_xy, min_still_held: int, names) -> str:
    """Which held-out places judge the refinement: ``"still places"`` when every camera sees
    at least ``min_still_held`` of the held-out still places ``still_xy`` (K, S, 2), else
    ``"all places"``, with a warning naming the cameras short of them."""
    seen = np.isfinite(still_xy[..., 0]).sum(axis=1)
    if (seen >= min_still_held).all():
        return "still places"
    short = [n for n, m in zip(names, seen) if m < min_still_held]
    warnings.warn(f"refine_rig: {', '.join(short)} see(s) fewer than min_still_held = "
                  f"{min_still_held} held-out still places ({seen.tolist()} per camera): the "
                  "refinement is judged on all held-out places, the moving subject's too, a "
                  "weaker check (both residual sets are in summary())", stacklevel=5)
    return "all places"


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


def _check_lsm_kept(given, raw: TiePoints, tie: TiePoints, lsm: TieLSM) -> None:
    """Refuse tie points the least squares matching left too few of: fewer than 6, or none
    in a camera that had some as found (the places and the adjustment need them)."""
    had = np.isfinite(raw.xy[..., 0]).sum(axis=1)
    has = np.isfinite(tie.xy[..., 0]).sum(axis=1)
    if tie.xy.shape[1] >= 6 and not ((had > 0) & (has == 0)).any():
        return
    s = lsm.summary()
    raise ValueError(
        f"tie_lsm: least squares matching of the tie points kept {tie.xy.shape[1]} of "
        f"{raw.xy.shape[1]} ({has.tolist()} per camera, {had.tolist()} as found; "
        f"{s['failed']} of {s['matched']} matches failed): too few to adjust the cameras "
        "(at least 6, some in every camera). Loosen RigRefinementParams.tie_lsm (max_sigma_px, "
        "max_shift_px) or set lsm=False to adjust the tie points as found")


def _folds(camera, *, step: int = 16) -> bool:
    """Whether ``camera``'s lens model cannot be inverted somewhere in its frame: checked
    (:meth:`lsmta.camera.Camera.invertible`) on a grid of pixels ``step`` px apart that
    takes in the frame's borders and corners (-0.5 and width - 0.5, height - 0.5)."""
    u = np.unique(np.r_[np.arange(-0.5, camera.width - 0.5, step), camera.width - 0.5])
    v = np.unique(np.r_[np.arange(-0.5, camera.height - 0.5, step), camera.height - 0.5])
    grid = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
    return not bool(camera.invertible(grid).all())


def _folded(cameras) -> tuple:
    """The names (else indices) of ``cameras`` that :func:`_folds`, with a warning."""
    folded = tuple(c.name or str(k) for k, c in enumerate(cameras) if _folds(c))
    if folded:
        warnings.warn(f"refine_rig: the refined lens model of {', '.join(folded)} cannot be "
                      "inverted everywhere in its frame (the fitted distortion folds over "
                      "inside it): the refined cameras are not used (RigRefinement.chosen is "
                      "the given ones; see folded in summary())", stacklevel=5)
    return folded


def _loaded(stacks, videos: Videos) -> list:
    """``stacks`` checked against ``videos``: K arrays (T, H_k, W_k) uint8 as
    :meth:`lsmta.io.Videos.load` returns them."""
    stacks = list(stacks)
    want = [(videos.n_frames, h, w) for w, h in videos.sizes]
    got = [(getattr(s, "shape", None), getattr(s, "dtype", None)) for s in stacks]
    if len(stacks) != videos.n_views or got != [(w, np.dtype(np.uint8)) for w in want]:
        raise ValueError(f"stacks: expected the videos' frames as Videos.load() returns them, "
                         f"{videos.n_views} uint8 arrays of shapes {want}; got "
                         f"{[(s, str(d)) for s, d in got]}")
    return stacks


def _sampled(videos: Videos, picks, stacks=None) -> list:
    """The picked frames as delivered (decoded, or taken from ``stacks``): a list of K
    grey images per frame."""
    return [videos.read(int(i)) if stacks is None else [st[int(i)] for st in stacks]
            for i in picks]


def _halvings(given, params) -> int:
    """How often the frames are halved for tie points (longer side <= ``tie_max_side``)."""
    longest = max(max(c.width, c.height) for c in given)
    return max(0, int(np.ceil(np.log2(longest / params.tie_max_side))))


def _twin_px(given, params) -> float:
    """The tie-point finder's ``distinct_px`` (px of the frames searched) in px of the
    videos as delivered: the farthest apart two points of one frame are twins."""
    return params.tie.distinct_px * 2 ** _halvings(given, params)


def _tie_points_at_work_size(videos: Videos, given, picks, params, stacks=None, *,
                             frames=None, lsm: bool = False):
    """Tie points of the picked frames (decoded, or taken from ``stacks``, or ``frames`` as
    :func:`_sampled` gives them), found in frames halved until their longer side is at most
    ``params.tie_max_side`` and scaled back to the frames as delivered. Returns
    ``(raw, refined, TieLSM)``: with ``lsm`` the tie points refined by least squares matching
    in the frames searched (``params.tie_lsm``) and what it did; without, ``(raw, raw,
    None)``."""
    halvings = _halvings(given, params)
    factor, m = 0.5 ** halvings, 2 ** halvings
    # right and bottom edges cut to a multiple of 2^halvings: every scale is exact
    sizes = [(c.width - c.width % m, c.height - c.height % m) for c in given]
    cams = [scaled_camera(cropped_camera(c, 0, 0, w, h), factor)
            for c, (w, h) in zip(given, sizes)] if halvings else list(given)
    frames = _sampled(videos, picks, stacks) if frames is None else frames
    images = []
    for frame in frames:
        images.append([cv2.resize(g[:h, :w], (c.width, c.height), interpolation=cv2.INTER_AREA)
                       if halvings else g for g, c, (w, h) in zip(frame, cams, sizes)])
    # the recording's one geometry per pair is checked later, on the adjusted places only
    tie_params = replace(params.tie, band_px=params.tie.band_px * videos.scale * factor,
                         recording_geometry=False)
    tie = find_tie_points(images, cams, params=tie_params)

    def back(t):
        return replace(t, xy=(t.xy + 0.5) / factor - 0.5) if halvings else t

    if not lsm:
        return back(tie), back(tie), None
    groups = (_feature_places(tie.xy, tie.frame, params.place_px * videos.scale * factor,
                              params.tie.distinct_px) if params.lsm_still_once else None)
    refined, info = refine_tie_points(images, tie, cams, params=params.tie_lsm, groups=groups)
    return back(tie), back(refined), info


def _off_geometry(given, places, train, params) -> np.ndarray:
    """(P,) bool: the places to adjust (``train``) that some view pair's one relative
    orientation for the recording rejects (:func:`lsmta.calibration.recording_inliers`,
    fitted to those places only; with ``params.tie.recording_geometry``). Its ``ransac_px``
    is in px of the frames searched, scaled here to the videos as delivered."""
    out = np.zeros(places.shape[1], bool)
    if not params.tie.recording_geometry:
        return out
    idx = np.flatnonzero(train)
    tie = replace(params.tie, ransac_px=params.tie.ransac_px * 2 ** _halvings(given, params))
    out[idx[~recording_inliers(given, places[:, idx], params=tie)]] = True
    return out


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


def refine_rig(videos: Videos, cameras, *, params: RigRefinementParams | None = None,
               stacks=None) -> RigRefinement:
    """Refine a camera file's cameras from the recording itself.

    Parameters
    ----------
    videos : lsmta.io.Videos
        The synchronised recording (:func:`lsmta.io.read_videos`), one video per camera.
    cameras : sequence of K Camera
        The cameras as read from a camera file (:mod:`lsmta.camera_files`), in the videos'
        order, for the videos as stored (crop and scale of ``videos`` are applied here).
    params : RigRefinementParams, optional
    stacks : sequence of K (T, H_k, W_k) uint8 arrays, optional
        The videos' frames already in memory (:meth:`lsmta.io.Videos.load`): the sampled
        frames are taken from them instead of decoded again (seeking into a video decodes
        from its last key frame; the frames are the same).

    Returns
    -------
    RigRefinement

    Raises
    ------
    ValueError
        Cameras that do not fit the videos (sizes, count, tie points far from where the
        cameras put them, or an adjustment that turns a camera far from the file's
        orientation), with what was found; ``stacks`` that are not the videos' frames.

    Notes
    -----
    Under ``lsmta reproduce`` a call with the same arguments as an earlier one of the run
    (notebooks 17 and 21) with ``stacks`` returns that call's result
    (:func:`lsmta.build_cache.cached_result`; its ``lsm.seconds`` are then the earlier
    call's). Without ``stacks`` it is always computed: the key would hold the files' paths,
    not their bytes.
    """
    if stacks is None:
        return _refine_rig(videos, cameras, params=params, stacks=None)
    return cached_result("rig_refinement", _refine_rig, (videos, cameras),
                         kwargs={"params": params, "stacks": stacks})


def _refine_rig(videos, cameras, *, params, stacks) -> RigRefinement:
    params = RigRefinementParams() if params is None else params
    if not isinstance(videos, Videos):
        raise TypeError("videos: expected lsmta.io.Videos (from lsmta.io.read_videos)")
    given = tuple(cameras_for_videos(cameras, videos, mismatch=params.mismatch))
    n = min(params.n_frames, videos.n_frames)
    picks = np.unique(np.linspace(0, videos.n_frames - 1, n).round().astype(int))
    extra = _between(picks, params.still_between)          # for still places only
    search = np.r_[np.zeros(len(picks), bool), np.ones(len(extra), bool)]
    picks = np.r_[picks, extra]
    stacks = None if stacks is None else _loaded(stacks, videos)
    raw, tie, lsm = _tie_points_at_work_size(videos, given, picks, params, stacks,
                                             lsm=params.lsm)
    if lsm is None:
        tie = raw                                                  # the same object
    _check_fit(given, raw, params)
    if lsm is not None:
        _check_lsm_kept(given, raw, tie, lsm)
    held_frames = ((np.arange(len(picks)) % params.hold_out_every) == 1) & ~search
    tol = params.place_px * videos.scale
    labels = _feature_places(tie.xy, tie.frame, tol, _twin_px(given, params))
    places = _merged(tie.xy, labels)
    held, still, unused, dropped = _split(tie, labels, held_frames, search, tol,
                                          params.hold_out_every)
    inconsistent = _off_geometry(given, places, ~held & ~dropped & ~unused, params)
    adjustment = refine_cameras(given, _strongest(
        places[:, ~held & ~dropped & ~unused & ~inconsistent], params.max_points),
        params=params.refine)
    _check_turn(given, adjustment.cameras, params.max_rotation_deg)
    sets = {"still places": places[:, held & still], "all places": places[:, held]}
    res = {k: (_held_out_residuals(given, xy), _held_out_residuals(adjustment.cameras, xy))
           for k, xy in sets.items()}
    kind = _judged_on(sets["still places"], params.min_still_held,
                      [c.name or str(k) for k, c in enumerate(given)])
    test_xy = sets[kind]
    before, after = res[kind]
    folded = _folded(adjustment.cameras)
    _warn_worse(given, before, after)
    return RigRefinement(
        cameras=adjustment.cameras, given=given,
        frames=tuple(int(videos.frames[i]) for i in picks), held_out=held_frames,
        still_search=search, tie_points=tie, raw_tie_points=raw, lsm=lsm, places=labels,
        still=still, held_out_places=held, unused_places=unused, dropped_places=dropped,
        inconsistent_places=inconsistent,
        held_out_kind=kind, adjustment=adjustment,
        held_out_points=int(test_xy.shape[1]), held_out_before=before, held_out_after=after,
        held_out_still_before=res["still places"][0], held_out_still_after=res["still places"][1],
        held_out_all_before=res["all places"][0], held_out_all_after=res["all places"][1],
        held_out_still_points=int(sets["still places"].shape[1]),
        held_out_all_points=int(sets["all places"].shape[1]), folded=folded)
