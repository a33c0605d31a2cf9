"""Markers of a recording in 3-D: found in each view, tracked in 2-D, joined across views by
their paths, intersected frame by frame.

The stage for what a marker-based recording holds beyond the surfaces: small skin markers
(or any small bright blobs) that each view sees on its own side of the subject. Stages
(:func:`capture_markers`):

1. *detection* in the first frame of every view: skin markers
   (:func:`~lsmta.tracking.markers.find_markers`: small grey blobs on skin, which needs the
   colour frame) or any bright blob (:func:`~lsmta.tracking.markers.find_blobs`);
2. *2-D tracking* of every view's markers: LSMTA in 2-D mode
   (:func:`~lsmta.tracking.track_points`, anchored templates) or, as the peer, pyramidal
   KLT (:func:`~lsmta.tracking.klt.track_klt`), from the same start points;
3. *joining* the tracks of views that look from one side (optical axes within
   ``max_angle_deg``) by their whole paths
   (:func:`~lsmta.tracking.view_tracks.join_view_tracks`);
4. *checking and completing the joins* (``MarkerParams.check``, on by default;
   :mod:`~lsmta.tracking.join_checks`): a view that disagrees with the marker's others
   taken out, an ambiguous view of a marker of three or more views taken out, ambiguous
   two-view markers and markers below the floor dropped
   (:func:`~lsmta.tracking.join_checks.check_joins`); free tracks of any view attached to
   the marker whose 3-D path projects onto them
   (:func:`~lsmta.tracking.join_checks.attach_views`); a view whose track is not on a dot
   in most of its frames taken out, and a marker left with fewer than two views dropped
   (``MarkerParams.dot_share``, :func:`~lsmta.tracking.join_checks.check_dots`); a
   marker a view lost looked for at its 3-D position's projection
   (:func:`~lsmta.tracking.join_checks.fill_gaps`; where one view holds it, along that
   view's epipolar line, ``MarkerParams.fill_line``, and after a gap of any length as far
   along it as the marker's own fastest 3-D step allows, ``MarkerParams.fill_reach``); then
   moving markers off the subject's silhouette dropped (``MarkerParams.silhouette``,
   below);
5. *intersection* of every frame from every view that holds the marker
   (:func:`~lsmta.tracking.view_tracks.triangulate_joined`), and each marker's 3-D motion
   range, which tells the subject's markers (moving) from still blobs of the room; a
   position whose reprojection residual is far out of line with the recording's (a view's
   track on another dot, e.g. picked up again on a neighbour after a gap) is gated first:
   intersected without the view to blame where three or more hold it, else dropped, and a
   view's run of frames (a track between gaps) out in most of them taken out throughout
   (``MarkerParams.residual_k``, :func:`~lsmta.tracking.view_tracks.triangulate_gated`);
6. *low-pass filter* of the intersected positions (``MarkerParams.filter_hz``, given the
   frame rate; :func:`~lsmta.tracking.lowpass.lowpass_trajectories`: zero-lag Butterworth,
   per gap-free run, Pose2Sim's nominal 6 Hz, order 4, not tuned on any recording; as
   Pose2Sim does it: no correction for the second pass, -3 dB at about 4.9 Hz at 60
   fps). The raw positions are kept: the residuals and the motion range are theirs.

The silhouette check is for the kind of recording this stage is for: one moving subject
carries the markers. A point on the subject projects inside the subject's silhouette in
every view whose frame holds the projection, whatever hides it there (the silhouette is
the projection of the whole body, so a marker on the back lands inside the front view's
silhouette too), while a wrong join's point, metres off, lands on the background. The
silhouette is the moving subject's mask found in the recording itself
(:func:`~lsmta.systems.subject.subject_masks`: each sampled frame against the median of
the sampled frames, every 5th, at most 21), closed and grown by ``silhouette_px``, its holes
filled (a body's silhouette has none; a torso that barely moves leaves only its moving
outline). A sampled frame whose mask covers fewer pixels than one growth disc
(π r², r the radius: any mask that holds a pixel away from the frame's
edge covers that much) is empty: nothing moved there (a still subject, a frozen view), and
it is not judged in that view (a warning names a view whose masks are empty in more than
half of the sampled frames). For every moving marker (by the motion rule of stage 5, on
the filled tracks) and every view whose frame holds its projection, in a sampled frame
with a mask, in at least half of the sampled frames in which any view does and in at least
3 of them (its own views too: a join of two tracks of the room is off the subject there),
the share of those positions that land on the mask; the least of these shares
(:func:`~lsmta.tracking.join_checks.silhouette_share`) below ``silhouette`` drops the marker
(counted as ``"off_subject"``). Still markers (the room's), markers without a position and
markers no view judges are kept. Where the mask misses the subject (a part still in more
than half of the sampled frames is in the median, so off the mask unless the outline around
it closes) a right marker's share falls: hence a majority of the positions, not every one.
A check that drops more than half of the moving markers it judges warns: the masks may
miss the subject, or the markers are not on one moving subject. The limit: a wrong join
whose two tracks both lie on the subject lands on the silhouette in its own views; only
another view whose frame holds the point where the subject is not can catch it. The rule
and its settings (0.5, the radius ``6 sigma``, holes filled, half of the frames, the least
over the views, after the fill) were chosen on the one real recording at hand (notebook
17's demo), with no held-out recording.
"""

from __future__ import annotations

import enum
import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import ndimage

from .._validate import as_int, as_scalar, freeze
from ..build_cache import cached_result
from ..matching.spline import SplineImage
from ..tracking import TrackerParams, track_points, track_step
from ..tracking.blob_follow import FollowParams, follow_blobs
from ..tracking.join_checks import (
    Filled,
    attach_views,
    check_dots,
    check_joins,
    fill_gaps,
    silhouette_hits,
    silhouette_share,
)
from ..tracking.klt import track_klt
from ..tracking.lowpass import lowpass_trajectories
from ..tracking.markers import find_blobs, find_markers
from ..tracking.view_tracks import (
    join_view_tracks,
    joined_positions,
    triangulate_gated,
    triangulate_joined,
)
from .subject import SubjectMaskParams, background, subject_masks
from .views import axis_angles


class Tracker2D(enum.IntEnum):
    """The 2-D tracker of :func:`capture_markers`."""

    LSMTA = 0   #: least squares matching tracking, 2-D mode, anchored templates
    KLT = 1     #: pyramidal Lucas-Kanade (OpenCV), the peer


@dataclass(frozen=True)
class MarkerParams:
    """Settings of :func:`capture_markers`.

    Attributes
    ----------
    detector : {"skin", "blobs"}
        Skin markers (needs colour first frames) or any small bright blob.
    sigma : float
        Blob scale at the frames' size, px (a marker's radius is about ``1.4 sigma``).
    min_strength : float
        Smallest blob strength, grey levels.
    tracker : Tracker2D
    lsmta : TrackerParams
        LSMTA's settings (2-D mode: its ``template`` is set to 0).
    klt_window : int
        KLT's window, px (odd).
    max_px : float
        Largest median pair residual of two views' tracks joined as one marker, px.
    min_shared : float
        Share of the frames two joined tracks must hold together.
    min_motion_mm : float
        A marker whose 3-D positions span less than this is still (the room), mm.
    max_angle_deg : float
        Only views whose optical axes are within this angle are joined (a marker on the
        skin is seen from one side; see :func:`~lsmta.systems.views.axis_angles`).
    follow : FollowParams or None
        Follow every marker on its blob (:func:`~lsmta.tracking.blob_follow.follow_blobs`:
        the tracker's step from frame to frame, re-centred on the dot, a lost marker
        re-acquired from the blobs near its prediction), for either tracker; None: the
        tracker alone over the whole clip (LSMTA with its anchored templates). The
        re-acquisition's blob scale and strength are ``sigma`` and ``min_strength``.
    check : bool
        Check and complete the joins (stage 4 of the module docstring), with ``max_px``,
        ``min_shared``, ``min_ratio`` and ``floor_mm``; the gaps are filled with the
        follower's window, contrast floor and ``max_gap`` (``follow``, or its defaults)
        and ``fill_search_px``; and the silhouette check (``silhouette``).
    min_ratio : float
        A join is ambiguous when a rival partner's median pair residual is less than this
        times its own (>= 1).
    floor_mm : float or None
        Height of the floor (world Z), mm, where the camera file's world frame has one (a
        Qualisys L-frame on the floor: 0); None (default): not checked, as a world frame
        need not have its Z up (OpenCV's is the first camera's).
    fill_search_px : float or None
        Largest distance of a dot found by the fill from the marker's projection, px
        (:func:`~lsmta.tracking.join_checks.fill_gaps`' ``search_px``); None:
        ``4.8 sigma`` (fill_gaps' default 12 px at the default ``sigma`` 2.5, scaled with
        the frames): an extrapolated position over a few frames is off by more than a
        dot's radius, so the search reaches beyond the re-centring window.
    fill_line : float or None
        With ``check``: in a frame where one view holds a marker, the fill looks for its
        dot in another view along the holding view's epipolar line, up to this many times
        the fill's search radius (``fill_search_px`` or its default) from the extrapolated
        position's projection (:func:`~lsmta.tracking.join_checks.fill_gaps`' ``line_px``;
        the line's width is ``max_px``), > 0; None: searched around the projection only,
        as in the other frames. The default 4 (48 px at the default ``sigma`` 2.5) is a
        rule set before scoring it: an extrapolation over ``max_gap`` (10) frames of a
        limb that moves a few pixels a frame is off by tens of pixels in depth, which the
        line leaves free; it was written after looking at the Pose2Sim demo's frames held
        by one view (their dots lay up to about 40 px along the line from a stale
        prediction), so it is not independent of that recording. The line is searched
        only where the search around the projection finds nothing; for a marker of two
        views a dot found on it is checked by the line's width, its reach, the nearest
        blob's lead (the next at least twice as far) and the other markers' dots only, not
        by reprojection (which any depth on the line passes). :meth:`fill_search` gives
        both radii.
    fill_dot : bool
        With ``check``: a dot the fill finds (either search) must also stand the follower's
        contrast floor (``FollowParams.min_contrast``, 15 grey levels by default) above its
        surround in every direction (:func:`~lsmta.tracking.blob_follow.dot_surround`,
        :func:`~lsmta.tracking.join_checks.fill_gaps`' ``min_surround``), not only its peak
        above its window's median: default True. An edge, a bright fold or flat bright skin
        near a lost marker's projection passes the peak test but not this one. On the
        Pose2Sim demo at full size the peak test alone made 28 fills; by eye 10 of them
        lay on no dot (skin, edges) and this test refuses them, and also 7 it should
        perhaps have kept (a dot beside a bright stripe, and six frames of a faint spot at
        an edge where a dot comes back); the 9 dots the fill had reached only through those
        are no longer reached: 2 fills are left. The floor was not tuned (it is the
        follower's, 15 grey levels), but the test was designed and judged by eye on this
        recording's 28 fills only, with no held-out recording. Its cost there: one marker's
        3-D share falls 0.92 -> 0.77, mostly real dots no longer reached (see
        :mod:`~lsmta.tracking.join_checks`, step 3). False: the peak
        test alone, as before (more fills, some on no dot).
    fill_reach : bool
        With ``check`` and ``fill_line``: where one view holds a marker and the fill's
        other searches find nothing, its dot is also looked for along the holding view's
        epipolar line as far as the marker can have gone since its last 3-D position (its
        own fastest 3-D step times the frames since), however long the gap, forwards and
        backwards (:func:`~lsmta.tracking.join_checks.fill_gaps`' ``grow``; the dot test
        ``fill_dot`` and the line's lead rule kept; the point found must lie within that
        reach; run after the other searches, on their result, so it only adds to them);
        default True, no setting of its own. Designed looking at the Pose2Sim demo's gaps,
        all in frames 50-99, with no held-out frames or recording: in a full run at
        15a0092 (loaded) one dot found by it and 16 followed from it, all on dots by eye,
        one thigh marker's 3-D share 0.74 -> 0.91 (:mod:`~lsmta.tracking.join_checks`).
        False: gaps longer than the follower's ``max_gap`` are not searched.
    dot_share : float or None
        With ``check``: a view's track of a joined marker whose positions stand the
        follower's contrast floor (``FollowParams.min_contrast``, 15 grey levels by
        default) above their surround in every direction
        (:func:`~lsmta.tracking.blob_follow.dot_surround`, as ``fill_dot``) in less than
        this share of the frames it holds is not on a dot and is taken out of the marker;
        a marker left with fewer than two views is dropped
        (:func:`~lsmta.tracking.join_checks.check_dots`; counted as ``"not_dot_views"``
        and ``"not_dots"``), in (0, 1]. Default 0.5, a majority, set before looking: the
        skin detector takes a pale highlight on the skin for a marker, and the follower
        keeps it (its peak stands above its window's median); on the Pose2Sim demo one
        moving "marker" was such a patch of a foot's skin in both its views. None: not
        checked.
    silhouette : float or None
        With ``check``: a moving marker whose positions land on the subject's silhouette in
        less than this share of the sampled frames in some view that judges it is
        dropped (module docstring), in (0, 1]; default 0.5, a majority: a marker on the
        subject lands inside wherever the mask holds the subject, and the mask can miss
        parts of it. None: not checked (markers on several
        subjects, or on something that does not move against the room).
    silhouette_px : float or None
        Radius of the silhouette's closing and growth, px, > 0, rounded to whole pixels (at
        least 1; the subject mask's ``close_px`` and ``grow_px``); None: ``6 sigma`` (15 px
        at the default ``sigma`` 2.5: :class:`~lsmta.systems.subject.SubjectMaskParams`'
        radii, scaled with the frames).
    residual_k : float or None
        Stage 5's residual gate (:func:`~lsmta.tracking.view_tracks.residual_gate`): a
        marker's 3-D position in a frame whose reprojection residual exceeds ``residual_k``
        times the recording's residual scale (``1.4826 *`` the median residual of all its
        markers' positions, the MAD of a zero-mean error, held at no less than
        ``residual_floor_px``) is out: intersected again without one of its views where it
        has three or more, else dropped (NaN, its residual too); a view's run of frames
        (its track between gaps) out in most of them is taken out of the marker throughout
        (:func:`~lsmta.tracking.view_tracks.triangulate_gated`; counted as
        ``joins["residual_out"]`` and ``joins["residual_views_out"]``), > 0. Default 4, set
        before the gate was first run on any recording (the customary 3-5 sigma): under a
        normal error 4 sigma drops about 6 in 100 000 right positions (3 sigma: 3 in 1000,
        a few per recording of a few hundred marker frames), while a track on another dot
        is off by its distance from the epipolar line, many sigma. The run rule and the
        view left out were added after a first run on the Pose2Sim demo (a per-frame gate
        alone kept a wrong track's frames near the line and dropped a three-view marker's
        frames one view spoilt). There, at full size: bound 2.29 px; the shank marker's
        cam01 track picked up again at frame 77 on another dot taken out (its 3-D share
        0.93 -> 0.70), a three-view marker kept without one view in 20 frames (its cam04
        track in frames 0-14 is on something else, residual about 80 px) and dropped in 13
        (1.00 -> 0.87), one two-view frame of another dropped; the thigh/shank pair
        passes the rigid-pair rule again (relative motion 0.37, std 3.81 mm). None: not
        gated (every intersection kept, as before).
    residual_floor_px : float or None
        Least residual scale of the gate, px, >= 0: the cameras' own reprojection residual
        (below it the cameras cannot tell a right position from a wrong one); None:
        ``0.2 sigma`` (0.5 px at the default ``sigma`` 2.5, scaled with the frames: the
        refined demo cameras' held-out residual, 0.27-0.49 px per camera at full size,
        rounded up).
    filter_hz : float or None
        Cut-off of the low-pass filter of the 3-D positions, Hz (stage 6 of the module
        docstring; below the recording's Nyquist frequency); default Pose2Sim's nominal 6
        (as Pose2Sim does it: no correction for the second pass; -3 dB at about 4.9 Hz at
        60 fps); None: not filtered. Applied only when :func:`capture_markers` is given
        ``fps``: without it the positions stay raw, silently (no warning;
        ``MarkerCapture.filter`` says why).
    filter_order : int
        Order of the zero-lag filter (both passes together, even; Pose2Sim's ``order``).
    """

    detector: str = "skin"
    sigma: float = 2.5
    min_strength: float = 20.0
    tracker: Tracker2D = Tracker2D.LSMTA
    lsmta: TrackerParams = field(default_factory=lambda: TrackerParams(template=0))
    klt_window: int = 21
    max_px: float = 4.0
    min_shared: float = 0.5
    min_motion_mm: float = 50.0
    max_angle_deg: float = 75.0
    follow: FollowParams | None = field(default_factory=FollowParams)
    check: bool = True
    min_ratio: float = 2.0
    floor_mm: float | None = None
    fill_search_px: float | None = None
    fill_line: float | None = 4.0
    fill_dot: bool = True
    fill_reach: bool = True
    dot_share: float | None = 0.5
    silhouette: float | None = 0.5
    silhouette_px: float | None = None
    residual_k: float | None = 4.0
    residual_floor_px: float | None = None
    filter_hz: float | None = 6.0
    filter_order: int = 4

    def __post_init__(self):
        if self.detector not in ("skin", "blobs"):
            raise ValueError(f"detector: expected 'skin' or 'blobs', got {self.detector!r}")
        for name in ("sigma", "min_strength", "max_px", "min_shared", "min_motion_mm",
                     "max_angle_deg"):
            as_scalar(getattr(self, name), name, positive=True)
        as_int(self.klt_window, "klt_window", minimum=3, odd=True)
        for name in ("check", "fill_dot", "fill_reach"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name}: expected True or False, got {getattr(self, name)!r}")
        if as_scalar(self.min_ratio, "min_ratio", positive=True) < 1:
            raise ValueError(f"min_ratio: expected a ratio >= 1, got {self.min_ratio}")
        if self.floor_mm is not None:
            as_scalar(self.floor_mm, "floor_mm")
        if self.fill_search_px is not None:
            as_scalar(self.fill_search_px, "fill_search_px", positive=True)
        if self.fill_line is not None:
            if isinstance(self.fill_line, bool):
                raise TypeError(f"fill_line: expected a number > 0 or None, got "
                                f"{self.fill_line!r}")
            as_scalar(self.fill_line, "fill_line", positive=True)
        if self.dot_share is not None and not 0 < as_scalar(self.dot_share,
                                                            "dot_share") <= 1:
            raise ValueError(f"dot_share: expected a share in (0, 1] or None, got "
                             f"{self.dot_share}")
        if self.silhouette is not None and not 0 < as_scalar(self.silhouette,
                                                             "silhouette") <= 1:
            raise ValueError(f"silhouette: expected a share in (0, 1] or None, got "
                             f"{self.silhouette}")
        if self.silhouette_px is not None:
            as_scalar(self.silhouette_px, "silhouette_px", positive=True)
        if self.residual_k is not None:
            if isinstance(self.residual_k, bool):
                raise TypeError(f"residual_k: expected a number > 0 or None, got "
                                f"{self.residual_k!r}")
            as_scalar(self.residual_k, "residual_k", positive=True)
        if self.residual_floor_px is not None:
            as_scalar(self.residual_floor_px, "residual_floor_px", nonnegative=True)
        if self.filter_hz is not None:
            as_scalar(self.filter_hz, "filter_hz", positive=True)
        if as_int(self.filter_order, "filter_order", minimum=2) % 2:
            raise ValueError(f"filter_order: expected an even order (the two passes "
                             f"together), got {self.filter_order}")
        if self.follow is not None and not isinstance(self.follow, FollowParams):
            raise TypeError(f"follow: expected a FollowParams or None, got "
                            f"{type(self.follow).__name__}")
        try:
            object.__setattr__(self, "tracker", Tracker2D(self.tracker))
        except ValueError:
            names = ", ".join(t.name for t in Tracker2D)
            raise ValueError(f"tracker: expected a Tracker2D ({names}), got "
                             f"{self.tracker!r}") from None

    def fill_search(self) -> tuple[float, float | None]:
        """The fill's search radii, px: around the projection (``fill_search_px``, or
        ``4.8 sigma``) and along the epipolar line (``fill_line`` times the first; None
        without ``fill_line``)."""
        search = self.fill_search_px if self.fill_search_px is not None else 4.8 * self.sigma
        return search, None if self.fill_line is None else self.fill_line * search

    def residual_floor(self) -> float:
        """The residual gate's least scale, px: ``residual_floor_px``, or ``0.2 sigma``."""
        return (self.residual_floor_px if self.residual_floor_px is not None
                else 0.2 * self.sigma)

    def fill_follow(self) -> FollowParams:
        """The follower's settings the fill uses (its window, contrast floor and
        ``max_gap``): ``follow``, or its defaults, at this ``sigma``."""
        return replace(self.follow or FollowParams(), sigma=self.sigma)


@dataclass(frozen=True, eq=False)
class MarkerCapture:
    """The markers of a recording (:func:`capture_markers`).

    Attributes
    ----------
    detections : tuple of K (N_k, 2) arrays
        Each view's markers in the first frame, px.
    view_xy : tuple of K (T, N_k, 2) arrays
        Each view's 2-D tracks, px (NaN once lost).
    members : (M, K) int array
        The track of every view joined into each marker (-1: none).
    xy : (T, K, M, 2) array
        The markers' tracked image positions, px.
    xyz : (T, M, 3) array
        Their 3-D positions as intersected (raw), mm (NaN: fewer than two views).
    residual : (T, M) array
        Largest reprojection error of each marker's views, px (NaN where not intersected
        or dropped by the residual gate).
    motion_mm : (M,) array
        Span of each marker's 3-D positions (the diagonal of their bounding box), mm.
    moving : (M,) bool array
        ``motion_mm >= params.min_motion_mm``: the subject's markers.
    seconds : float
        Time of the 2-D tracking, s.
    joins : dict
        What the join check did (``MarkerParams.check``): two-view markers dropped as
        ``"ambiguous"``, ambiguous views of markers of three or more views taken out
        (``"ambiguous_views"``), markers dropped ``"below_floor"``, disagreeing
        ``"views_out"`` taken out, tracks ``"attached"``, tracks not on a dot taken out
        (``"not_dot_views"``) and markers dropped for it (``"not_dots"``,
        ``MarkerParams.dot_share``), dots ``"filled"`` of the markers
        returned and of them ``"filled_line"`` found along an epipolar line
        (``MarkerParams.fill_line``) and ``"filled_reach"`` by the reach search
        (``MarkerParams.fill_reach``) (all 0 without the check), moving markers dropped
        ``"off_subject"`` (their positions off the subject's silhouette,
        ``MarkerParams.silhouette``), and 3-D positions dropped by the residual gate
        (``"residual_out"``, ``MarkerParams.residual_k``; with or without the check) and
        positions kept with a view (in a frame, or a run of frames) taken out by it
        (``"residual_views_out"``).
    xyz_filtered : (T, M, 3) array or None
        ``xyz`` low-pass filtered (``MarkerParams.filter_hz``), mm; samples in runs too
        short to filter are raw. None: not filtered (``filter_hz`` None, or no frame rate
        given to :func:`capture_markers`).
    filter : dict
        The filter applied: ``cutoff_hz``, ``order``, ``fps``, ``runs`` filtered,
        ``short_runs`` and ``raw_samples`` left raw; or ``{"applied": False, "reason":
        ...}``.
    residual_bound_px : float
        The residual gate's bound, px (NaN: not gated).
    """

    detections: tuple
    view_xy: tuple
    members: np.ndarray
    xy: np.ndarray
    xyz: np.ndarray
    residual: np.ndarray
    motion_mm: np.ndarray
    moving: np.ndarray
    seconds: float
    joins: dict = field(default_factory=dict)
    xyz_filtered: np.ndarray | None = None
    filter: dict = field(default_factory=dict)
    residual_bound_px: float = float("nan")

    def __post_init__(self):
        freeze(self, ("members", "xy", "xyz", "residual", "motion_mm", "moving"))
        if self.xyz_filtered is not None:
            freeze(self, ("xyz_filtered",))

    @property
    def xyz_written(self) -> np.ndarray:
        """The positions a file holds: ``xyz_filtered``, or ``xyz`` where not filtered
        (also when :func:`capture_markers` was called without ``fps``: then these are the
        raw intersections, whatever ``MarkerParams.filter_hz`` says)."""
        return self.xyz if self.xyz_filtered is None else self.xyz_filtered

    def triangulated_share(self) -> np.ndarray:
        """``(M,)`` share of the frames in which each marker has a 3-D position."""
        return np.isfinite(self.xyz).all(axis=2).mean(axis=0)


def detect_markers(image, *, params: MarkerParams | None = None) -> np.ndarray:
    """One view's markers, ``(N, 2)`` px: ``image`` is ``(H, W, 3)`` BGR for skin markers,
    ``(H, W)`` grey (or BGR) for blobs."""
    p = params or MarkerParams()
    img = np.asarray(image)
    if p.detector == "skin":
        return find_markers(img, sigma=p.sigma, min_strength=p.min_strength)
    grey = img if img.ndim == 2 else img.mean(axis=2)
    return find_blobs(grey, sigma=p.sigma, min_strength=p.min_strength)


def track_view(frames, start_xy, *, params: MarkerParams | None = None) -> np.ndarray:
    """Track one view's points with the chosen 2-D tracker: ``(T, N, 2)`` px (followed on
    their blobs unless ``params.follow`` is None)."""
    p = params or MarkerParams()
    start = np.asarray(start_xy, float)[None]
    if start.shape[1] == 0:
        return np.full((len(frames), 0, 2), np.nan)
    if p.follow is not None:
        fp = replace(p.follow, sigma=p.sigma, min_strength=p.min_strength)
        return follow_blobs(frames, start[0], _step(frames, p), params=fp).xy
    if p.tracker == Tracker2D.KLT:
        tracks = track_klt([frames], start, window=p.klt_window)
    else:
        tracks = track_points([frames], start, params=p.lsmta)
    return tracks.xy[:, 0]


def _step(frames, p: MarkerParams):
    """The chosen tracker's step from frame t to t + 1 (see :func:`follow_blobs`): KLT with
    its pyramid; LSMTA (:func:`~lsmta.tracking.track_step`) from the prediction in the
    normal search box, then in the bigger one, then the bigger one around the last position
    (a marker that stopped)."""
    if p.tracker == Tracker2D.KLT:
        def klt(t, xy, predicted):
            return track_klt([frames[t:t + 2]], xy[None], window=p.klt_window).xy[1, 0]
        return klt
    lp = p.lsmta
    built: dict[int, SplineImage] = {}      # frame -> its interpolant: each prefiltered once

    def spline(t):
        if t not in built:
            if len(built) > 2:
                built.pop(max(built, key=lambda u: abs(u - t)))    # the farthest frame
            built[t] = SplineImage(frames[t], "frame")
        return built[t]

    def lsmta(t, xy, predicted):
        out = np.full_like(xy, np.nan)
        todo = np.arange(len(xy))
        pair = ([spline(t)], [spline(t + 1)])
        for radius, pred in ((lp.radius, predicted), (lp.retry_radius, predicted),
                             (lp.retry_radius, xy)):
            r = track_step(frames[t][None], frames[t + 1][None], xy[None, todo],
                           pred[None, todo], radius, params=lp, splines=pair)
            out[todo[r.ok]] = r.xy[0, r.ok]
            todo = todo[~r.ok]
            if not todo.size:
                break
        return out
    return lsmta


def capture_markers(stacks, cameras, first_frames, *, params: MarkerParams | None = None,
                    like: MarkerCapture | None = None,
                    fps: float | None = None) -> MarkerCapture:
    """Markers of a synchronised recording in 3-D (see the module docstring).

    Parameters
    ----------
    stacks : sequence of K (T, H_k, W_k) arrays
        Grey frames of every view.
    cameras : sequence of K Camera
        Calibrated cameras that fit the frames.
    first_frames : sequence of K arrays
        The first frame of every view as the detector wants it (BGR for skin markers).
    params : MarkerParams, optional
    like : MarkerCapture, optional
        The same markers as this earlier capture of the same recording: its detections are
        tracked again (with ``params``' tracker) and joined and told moving as it joined and
        told them, so that two trackers are compared on the same markers.
    fps : float, optional
        The recording's frame rate, Hz: needed by the low-pass filter
        (``params.filter_hz``); without it the positions are not filtered
        (``xyz_filtered`` None, ``filter`` says why).

    Returns
    -------
    MarkerCapture

    Notes
    -----
    Under ``lsmta reproduce`` a call with the same arguments as an earlier one of the run
    (notebooks 17 and 21) returns that call's result (:func:`lsmta.build_cache.cached_result`;
    its ``seconds`` are then the earlier call's).
    """
    return cached_result("marker_capture", _capture_markers, (stacks, cameras, first_frames),
                         kwargs={"params": params, "like": like, "fps": fps})


def _capture_markers(stacks, cameras, first_frames, *, params, like, fps) -> MarkerCapture:
    p = params or MarkerParams()
    cams = list(cameras)
    if not len(stacks) == len(cams) == len(first_frames):
        raise ValueError(f"stacks, cameras, first_frames: expected one per view, got "
                         f"{len(stacks)}, {len(cams)} and {len(first_frames)}")
    if like is not None and (not isinstance(like, MarkerCapture)
                             or len(like.detections) != len(cams)):
        raise ValueError(f"like: expected a MarkerCapture of the same {len(cams)} views, got "
                         f"{like!r:.60}")
    detections = (like.detections if like is not None
                  else tuple(detect_markers(f, params=p) for f in first_frames))
    t0 = time.perf_counter()
    view_xy = tuple(track_view(s, d, params=p) for s, d in zip(stacks, detections))
    seconds = time.perf_counter() - t0
    if like is None:
        angles = axis_angles(cams)
        pairs = [(a, b) for a in range(len(cams)) for b in range(a + 1, len(cams))
                 if angles[a, b] <= p.max_angle_deg]
        members = join_view_tracks(cams, view_xy, max_px=p.max_px, min_shared=p.min_shared,
                                   pairs=pairs).members
        members, joins = _checked_joins(stacks, cams, view_xy, members, p)
    else:
        members, joins = like.members, {k: v for k, v in like.joins.items()
                                        if k not in ("filled", "filled_line", "filled_reach",
                                                     "residual_out", "residual_views_out")}
    joins["filled"] = joins["filled_line"] = joins["filled_reach"] = 0
    if p.check:
        fp = p.fill_follow()
        search, line = p.fill_search()
        view_xy, found = fill_gaps(stacks, cams, view_xy, members, radius=fp.window(),
                                   search_px=search, min_contrast=fp.min_contrast,
                                   max_gap=fp.max_gap, max_px=p.max_px, line_px=line,
                                   min_surround=fp.min_contrast if p.fill_dot else None,
                                   grow=p.fill_reach)
        off = np.zeros(len(members), bool)
        if like is None and p.silhouette is not None and len(members):
            share = silhouette_shares(stacks, cams, view_xy, members, params=p)
            off = share < p.silhouette                      # NaN (not judged): kept
            if off.sum() > np.isfinite(share).sum() / 2:
                warnings.warn(f"silhouette check: {int(off.sum())} of the "
                              f"{int(np.isfinite(share).sum())} moving markers it judged are off "
                              f"the subject's masks and dropped (more than half): the masks may "
                              f"miss the subject, or the markers are not on one moving subject "
                              f"(MarkerParams(silhouette=None) turns the check off)",
                              RuntimeWarning, stacklevel=4)
            members = members[~off]
            joins["off_subject"] = int(off.sum())
        joins["filled"] = int((found[..., ~off] > 0).sum())         # of the markers kept
        joins["filled_line"] = int((found[..., ~off] == Filled.LINE).sum())   # of those
        joins["filled_reach"] = int((found[..., ~off] == Filled.REACH).sum())
    xyz, residual, bound = _intersected(cams, view_xy, members, p, joins)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # never intersected
        span = np.nanmax(xyz, axis=0) - np.nanmin(xyz, axis=0)
    motion = np.nan_to_num(np.linalg.norm(span, axis=1))
    moving = motion >= p.min_motion_mm if like is None else like.moving
    filtered, record = marker_lowpass(xyz, fps, params=p)
    return MarkerCapture(detections=detections, view_xy=view_xy, members=members,
                         xy=joined_positions(view_xy, members), xyz=xyz,
                         residual=residual, motion_mm=motion, moving=moving,
                         seconds=seconds, joins=joins, xyz_filtered=filtered, filter=record,
                         residual_bound_px=bound)


def _intersected(cams, view_xy, members, p: MarkerParams, joins: dict):
    """Stage 5's intersection, gated by the residual unless ``residual_k`` is None
    (:func:`~lsmta.tracking.view_tracks.triangulate_gated`): positions, residuals and the
    bound (NaN: not gated); counts the gate's work into ``joins``."""
    if p.residual_k is None:
        xyz, residual, _ = triangulate_joined(cams, view_xy, members)
        joins["residual_out"] = joins["residual_views_out"] = 0
        return xyz, residual, float("nan")
    g = triangulate_gated(cams, view_xy, members, k=p.residual_k, floor_px=p.residual_floor())
    joins["residual_out"], joins["residual_views_out"] = g.dropped, g.views_out
    return np.array(g.xyz), np.array(g.residual), g.bound_px


def marker_lowpass(xyz, fps: float | None, *, params: MarkerParams | None = None):
    """Stage 6: ``(T, M, 3)`` positions (mm) low-pass filtered as ``params`` says.

    Returns
    -------
    filtered : (T, M, 3) array or None
        None where not filtered (``params.filter_hz`` None, or ``fps`` None).
    record : dict
        :attr:`MarkerCapture.filter`.
    """
    p = params or MarkerParams()
    if p.filter_hz is None:
        return None, {"applied": False, "reason": "MarkerParams.filter_hz is None"}
    if fps is None:
        return None, {"applied": False, "reason": "no frame rate given (fps=None)"}
    fps = as_scalar(fps, "fps", positive=True)
    if p.filter_hz >= fps / 2:
        raise ValueError(f"params.filter_hz: expected a cut-off below the Nyquist frequency "
                         f"fps / 2 = {fps / 2:g} Hz, got {p.filter_hz:g} Hz")
    lp = lowpass_trajectories(xyz, fps, cutoff_hz=p.filter_hz, order=p.filter_order)
    return lp.xyz, {"applied": True, "cutoff_hz": lp.cutoff_hz, "order": lp.order,
                    "fps": lp.fps, "runs": lp.runs, "short_runs": lp.short_runs,
                    "raw_samples": int(lp.raw.sum())}


def nyquist_checked(params: MarkerParams | None, fps: float, *,
                    explicit: bool | None = None):
    """The marker stage's parameters for a recording at ``fps``, decided before any stage.

    A cut-off at or above the Nyquist frequency ``fps / 2`` (e.g. the default 6 Hz at
    12 fps or less) is refused when it was chosen (``explicit``), and turned off with a
    warning when it is the default (``MarkerParams.filter_hz`` 6).

    Parameters
    ----------
    params : MarkerParams or None
        None: no marker stage (returned as is).
    fps : float
        Frame rate, Hz (> 0).
    explicit : bool, optional
        Whether the cut-off was chosen by the caller; None: chosen when it is not the
        default.

    Returns
    -------
    params : MarkerParams or None
        ``params``, or a copy with ``filter_hz`` None.
    reason : str or None
        Why the filter was turned off (for ``MarkerCapture.filter``), or None.

    Raises
    ------
    ValueError
        ``fps`` not positive; a chosen cut-off not below ``fps / 2``.
    """
    fps = as_scalar(fps, "fps", positive=True)
    if params is None or params.filter_hz is None or params.filter_hz < fps / 2:
        return params, None
    default = MarkerParams.__dataclass_fields__["filter_hz"].default
    if explicit or (explicit is None and params.filter_hz != default):
        raise ValueError(f"params.markers.filter_hz: expected a cut-off below the Nyquist "
                         f"frequency fps / 2 = {fps / 2:g} Hz, got {params.filter_hz:g} Hz")
    reason = (f"default cut-off {params.filter_hz:g} Hz not below the Nyquist frequency "
              f"{fps / 2:g} Hz ({fps:g} fps): filter off")
    warnings.warn(f"markers: {reason} (positions written raw)", RuntimeWarning, stacklevel=3)
    return replace(params, filter_hz=None), reason


def _checked_joins(stacks, cams, view_xy, members, p: MarkerParams):
    """Stage 4's check, attachment and dot check (the fill, then the silhouette check,
    follow in :func:`capture_markers`; the fill runs for every tracker)."""
    if not p.check:
        return members, {"ambiguous": 0, "ambiguous_views": 0, "below_floor": 0,
                         "views_out": 0, "attached": 0, "not_dot_views": 0, "not_dots": 0,
                         "off_subject": 0}
    c = check_joins(cams, view_xy, members, max_px=p.max_px, min_ratio=p.min_ratio,
                    min_shared=p.min_shared, floor_mm=p.floor_mm)
    members, attached = attach_views(cams, view_xy, c.members, max_px=p.max_px,
                                     min_shared=p.min_shared)
    out = dropped = 0
    if p.dot_share is not None and len(members):
        fp = p.fill_follow()
        d = check_dots(stacks, cams, view_xy, members, radius=fp.window(),
                       min_surround=fp.min_contrast, min_share=p.dot_share)
        members, out, dropped = d.members, d.views_out, d.dropped
    return members, {"ambiguous": c.ambiguous, "ambiguous_views": c.ambiguous_views,
                     "below_floor": c.below_floor, "views_out": c.views_out,
                     "attached": attached, "not_dot_views": out, "not_dots": dropped,
                     "off_subject": 0}


def silhouette_shares(stacks, cameras, xy, members, *, params: MarkerParams | None = None,
                      min_positions: int = 3) -> np.ndarray:
    """Each moving marker's share of positions on the subject's silhouette (the module
    docstring's silhouette check).

    Parameters
    ----------
    stacks : sequence of K (T, H_k, W_k) arrays
        Grey frames of every view (fewer than 3: nothing judged).
    cameras : sequence of K Camera
    xy : sequence of K (T, N_k, 2) arrays
        Each view's tracks, px.
    members : (M, K) int array
        The joins.
    params : MarkerParams, optional
        Its ``sigma``, ``silhouette_px`` and ``min_motion_mm``.
    min_positions : int
        A view judges a marker only on at least this many sampled frames
        (:func:`~lsmta.tracking.join_checks.silhouette_share`).

    Returns
    -------
    (M,) array
        The least share over the judging views in [0, 1]
        (:func:`~lsmta.tracking.join_checks.silhouette_share`); NaN for still markers and
        markers no view judges. Warns for a view whose masks are empty (fewer than
        π r² pixels, r the radius) in more than half of the sampled frames.
    """
    p = params or MarkerParams()
    if len(stacks) != len(cameras):
        raise ValueError(f"stacks: expected {len(cameras)} frame stacks (one per camera), got "
                         f"{len(stacks)}")
    xyz, _, _ = triangulate_joined(cameras, xy, members)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)          # never intersected
        span = np.nan_to_num(np.linalg.norm(np.nanmax(xyz, axis=0) - np.nanmin(xyz, axis=0),
                                            axis=1))
    moving = np.flatnonzero(span >= p.min_motion_mm)
    share = np.full(len(members), np.nan)
    if not moving.size or len(stacks[0]) < 3:        # a median needs 3 frames
        return share
    radius = max(1, round(p.silhouette_px if p.silhouette_px is not None else 6 * p.sigma))
    mp = SubjectMaskParams(close_px=radius, grow_px=radius)
    min_area = int(np.ceil(np.pi * radius ** 2))          # one growth disc
    hits, seen = [], []
    for stack, cam in zip(stacks, cameras):
        v = np.asarray(stack)[None]
        bg = background(v, params=mp)                     # once per view
        masks = np.stack([ndimage.binary_fill_holes(
            subject_masks(v, int(t), params=mp, background=bg).masks[0])
            for t in bg[1]])                              # (S, H, W): one view at a time
        empty = int((masks.sum(axis=(1, 2)) < min_area).sum())
        if empty > len(masks) / 2:
            warnings.warn(f"silhouette check: view {cam.name!r}'s subject mask is empty (fewer "
                          f"than {min_area} px) in {empty} of its {len(masks)} sampled frames "
                          f"(a still subject or a frozen view?): those frames are not judged "
                          f"in it", RuntimeWarning, stacklevel=2)
        i, s = silhouette_hits(cam, xyz[bg[1]][:, moving], masks, min_area=min_area)
        hits.append(i)
        seen.append(s)
    share[moving] = silhouette_share(np.stack(hits), np.stack(seen), min_seen=0.5,
                                     min_positions=min_positions)
    return share
