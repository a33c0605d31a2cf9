"""The LSMTA system on any synchronised recording with calibrated cameras.

What goes in is what a user has: the videos (files opened with :func:`lsmta.io.read_videos`,
or arrays) and cameras that fit them: from a camera file refined on the recording
(:func:`~lsmta.systems.refine_rig`), from a bar recording
(:func:`~lsmta.systems.calibrate_rig`), from a board (:func:`~lsmta.calibration.calibrate_board`)
or as given. Nothing of a generator's truth enters. The stages (:func:`capture_recording`):

1. *view groups*: which cameras see the same side (:func:`~lsmta.systems.views.view_groups`);
   every later stage runs once per group, on the group's views;
2. *image noise* measured in each group's videos (:func:`~lsmta.noise.temporal_noise`), the
   sigma of every LSM threshold that needs one;
3. *surfaces* of the first frame and of every ``density_every``-th frame, from automatic
   seeds (:func:`~lsmta.systems.surfaces.measure_surfaces`); a group of three or more
   cameras with ``SurfaceParams(method="rectified")`` (which measures pairs) is measured
   by the growth, with a warning naming it;
   optionally *more views*: every surface point matched in the cameras outside its group
   that see it, and intersected from all its views (:func:`~lsmta.systems.more_views.add_views`);
4. *surface tracking* (:func:`track_surface`);
5. *trajectories*: forward intersection per group, all groups' trajectories side by side,
   then the trajectory filters (:func:`~lsmta.tracking.apply_filters`);
6. optionally *markers*: found in every view, tracked in 2-D, joined across views by their
   paths (:func:`~lsmta.systems.markers.capture_markers`);
7. optionally *the arm model* (:func:`~lsmta.systems.arm.fit_arm`).

Videos of one group that differ in size (a tool that cut a few columns off some files) are
cut to the group's common size at their right and bottom edges, with their cameras
(:func:`lsmta.camera.cropped_camera`), so every camera keeps its principal point.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import asdict, dataclass, field, replace

import numpy as np
from tqdm.auto import tqdm

from .._validate import as_int, as_scalar
from ..camera import cropped_camera
from ..io import Videos
from ..noise import NoiseEstimate, temporal_noise
from ..tracking import (
    TrackerParams,
    Tracks,
    Trajectories,
    apply_filters,
    track_points,
    trajectories_from_tracks,
)
from .arm import ArmFit, ArmFitParams, fit_arm
from .capture_files import save_capture
from .checks import check_cameras
from .markers import MarkerCapture, MarkerParams, capture_markers, nyquist_checked
from .more_views import MoreViewsParams, add_views, group_xy
from .surfaces import SurfaceParams, measure_surfaces
from .views import ViewGroup, view_groups


@dataclass(frozen=True)
class FilterParams:
    """Trajectory filters (:func:`~lsmta.tracking.apply_filters`; notebook 05's values).

    Speeds in mm/s, accelerations in mm/s², the uniformity filter's ``voxel`` in mm.
    :meth:`walking` gives the values for a whole walking person.
    """

    max_speed: float = 2000.0
    max_acceleration: float = 40000.0
    voxel: float = 150.0
    max_deviation: float = 400.0
    window: int = 10
    max_drift: float = 8.0

    @classmethod
    def walking(cls) -> FilterParams:
        """The filters for the whole body of a walking person (:func:`~lsmta.systems.
        capture_walk`'s default).

        Notebook 05's values cut the swinging limbs: a walking person's swing foot and
        shank move at up to about 4.5-5 m/s (some 3.5 times a 1.3-1.4 m/s walking speed;
        Winter's gait data) and a swinging limb accelerates at several g. So: speeds up to
        6 m/s and accelerations up to 100 m/s² (about 10 g) pass (a rule written down
        before scoring), and the uniformity filter compares a velocity with its
        neighbours in a 75 mm voxel, about a limb's thickness, so that a forearm's points
        are not judged against the trunk's beside it (chosen on the generated walk, seed
        36; held out: seed 37, the same body and walk with other camera jitter, texture and
        noise, ``experiments/results/walk_cover.json``).
        """
        return cls(max_speed=6000.0, max_acceleration=100000.0, voxel=75.0)


@dataclass(frozen=True)
class CaptureParams:
    """Settings of :func:`capture_recording`, one bundle per stage.

    Attributes
    ----------
    max_angle_deg : float
        Largest angle between the optical axes of a view group's template and its other
        cameras (:func:`~lsmta.systems.views.view_groups`).
    surface : SurfaceParams
        Its ``template`` is replaced by each group's.
    density_every : int
        Frames between density checks (and so between measured surfaces).
    tracker : TrackerParams
    filters : FilterParams
    arm : ArmFitParams or None
        The arm model stage; None leaves it out (any subject).
    markers : MarkerParams or None
        The marker stage (:func:`~lsmta.systems.markers.capture_markers`); None leaves it
        out. Skin markers need the colour first frames: pass videos from
        :func:`lsmta.io.read_videos`.
    more_views : MoreViewsParams or None
        The more-views stage (:func:`~lsmta.systems.more_views.add_views`, the reference
        being each group's template); None leaves it out.
    min_group_share : float
        A view group of three or more cameras whose surfaces hold points in fewer than this
        share of its measured frames (a point must be seen by all of them: a rig whose
        cameras do not all see the same side of the subject, or a subject absent in many
        frames) has its pairs of its template with each other camera measured too. It is
        split into them, with a warning, only if the pairs together hold points in clearly
        more measured frames than the whole group: at least twice as many, and at least
        one more (a subject simply absent leaves the pairs empty too, and the group, with
        its points seen by all its cameras, whole). 0 never splits a group.
    """

    max_angle_deg: float = 75.0
    surface: SurfaceParams = field(default_factory=SurfaceParams)
    density_every: int = 4
    tracker: TrackerParams = field(default_factory=TrackerParams)
    filters: FilterParams = field(default_factory=FilterParams)
    arm: ArmFitParams | None = None
    markers: MarkerParams | None = None
    more_views: MoreViewsParams | None = None
    min_group_share: float = 0.5

    def __post_init__(self):
        as_scalar(self.max_angle_deg, "max_angle_deg", positive=True)
        if isinstance(self.min_group_share, bool | np.bool_):
            raise TypeError(f"min_group_share: expected a share in [0, 1], got "
                            f"{self.min_group_share!r}")
        share = as_scalar(self.min_group_share, "min_group_share")
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"min_group_share: expected a share in [0, 1], got "
                             f"{self.min_group_share!r}")
        as_int(self.density_every, "density_every", minimum=1)
        if self.arm is not None and not isinstance(self.arm, ArmFitParams):
            raise TypeError(f"arm: expected an ArmFitParams or None, got "
                            f"{type(self.arm).__name__}")
        if self.markers is not None and not isinstance(self.markers, MarkerParams):
            raise TypeError(f"markers: expected a MarkerParams or None, got "
                            f"{type(self.markers).__name__}")
        if self.more_views is not None and not isinstance(self.more_views, MoreViewsParams):
            raise TypeError(f"more_views: expected a MoreViewsParams or None, got "
                            f"{type(self.more_views).__name__}")


@dataclass(frozen=True, eq=False)
class ViewCapture:
    """What one view group measured.

    Attributes
    ----------
    group : ViewGroup
    cameras : list of Camera
        The group's cameras as its frames were processed (cut to a common size).
    noise : NoiseEstimate
    surfaces : dict of int -> SurfaceResult
        Measured surfaces, by processed frame; image positions in the group's views.
    tracks : Tracks or None
        Tracked image positions in the group's views, over all processed frames (NaN before
        :attr:`tracking_from`); None when no surface of the group had a point to start from
        (a warning says so).
    points : slice
        The group's trajectories within :attr:`BodyCapture.trajectories`.
    more_views : dict of int -> MultiViewPoints
        With ``CaptureParams.more_views``: each measured frame's kept surface points matched
        in every camera that sees them (all K cameras' rows, the capture's order); else empty.
    """

    group: ViewGroup
    cameras: list
    noise: NoiseEstimate
    surfaces: dict
    tracks: Tracks | None
    points: slice
    more_views: dict = field(default_factory=dict)

    @property
    def tracking_from(self) -> int | None:
        """The processed frame the tracks start at: the first with a surface point (None
        without tracks)."""
        return (None if self.tracks is None else
                _tracking_start(self.surfaces, self.tracks.xy.shape[0]))


@dataclass(frozen=True, eq=False)
class BodyCapture:
    """Everything the LSMTA system measured, stage by stage.

    Attributes
    ----------
    cameras : list of Camera
        The cameras used, user's world, mm.
    calibration : object or None
        Where they came from (a RigCalibration, RigRefinement, BoardCalibration ...); None
        for cameras taken as given.
    frames : (T,) int array
        The frames of the input videos that were processed (index 0 here is ``frames[0]``):
        for a :class:`~lsmta.io.Videos`, the frame numbers in its files; for arrays, indices
        into them.
    fps : float
    views : tuple of ViewCapture
        One per view group.
    trajectories : Trajectories
        Every group's, side by side, before the filters.
    filters : tuple of FilterReport
        The three filters in order; the last one's trajectories are the result.
    arm : ArmFit or None
    markers : MarkerCapture or None
    seconds : dict of str -> float
        Wall time per stage.
    params : CaptureParams
        The settings it ran with.
    """

    cameras: list
    calibration: object
    frames: np.ndarray
    fps: float
    views: tuple
    trajectories: Trajectories
    filters: tuple
    arm: ArmFit | None
    markers: MarkerCapture | None
    seconds: dict
    params: CaptureParams

    @property
    def filtered(self) -> Trajectories:
        """The trajectories after all filters."""
        return self.filters[-1].trajectories

    def points_at(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """The filtered trajectories' points in processed frame ``t``: ``(M, 3)`` mm (the
        cameras' world) and ``(M,)`` the view group that measured each."""
        traj = self.filtered
        T = len(traj.xyz)
        if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or not 0 <= t < T:
            raise ValueError(f"t: expected a processed frame index in [0, {T - 1}], got {t!r}")
        present = traj.present[t]
        return traj.xyz[t, present].copy(), self.group_of[present]

    @property
    def group_of(self) -> np.ndarray:
        """``(N,)`` the view group of every trajectory."""
        out = np.empty(len(self.trajectories), int)
        for g, v in enumerate(self.views):
            out[v.points] = g
        return out

    def _only(self, name: str):
        if len(self.views) != 1:
            raise AttributeError(f"{name}: this capture has {len(self.views)} view groups; use "
                                 f"views[i].{name}")
        return getattr(self.views[0], name)

    @property
    def surfaces(self) -> dict:
        """The surfaces of the only view group (see :attr:`views` for several)."""
        return self._only("surfaces")

    @property
    def tracks(self) -> Tracks:
        """The tracks of the only view group."""
        return self._only("tracks")

    @property
    def noise(self) -> NoiseEstimate:
        """The image noise of the only view group."""
        return self._only("noise")

    def save(self, directory, *, report: bool = True) -> dict:
        """Write the capture where other tools read it: ``cameras.toml``,
        ``trajectories.c3d`` / ``.trc``, ``surfaces/frame_NNNN.ply``, ``summary.json`` and
        ``report.html`` (:func:`~lsmta.systems.capture_files.save_capture`); returns the
        paths written, by kind."""
        return save_capture(self, directory, report=report)

    def summary(self) -> list:
        """One row per stage: ``{"stage", "seconds", "result"}``, for a table."""
        kept = int(self.filtered.present.any(axis=0).sum())

        def per_view(text) -> str:
            return "; ".join(f"{_names(v)}: {text(v)}" for v in self.views)

        rows = [("calibration", _calibration_text(self.calibration)),
                ("view groups", per_view(lambda v: f"template {v.group.template}")),
                ("image noise", per_view(lambda v: f"sigma {v.noise.sigma:.2f} grey levels")),
                ("surfaces", per_view(lambda v: f"{len(v.surfaces)} frames, first frame "
                                                f"{_surface_points(v.surfaces)} points"
                                                + _off_subject_text(v.surfaces))),
                ("tracking", per_view(lambda v: "none" if v.tracks is None else
                                      f"from frame {int(self.frames[v.tracking_from])}: "
                                      f"{len(v.tracks)} tracks, "
                                      f"{int(v.tracks.alive[-1].sum())} alive at the end")),
                ("trajectories", f"{kept} of {len(self.trajectories)} kept by the filters")]
        if self.params.more_views is not None:        # after the surfaces it extends
            rows.insert(4, ("more views", per_view(_more_views_text)))
        if self.markers is not None:
            m = self.markers
            share = m.triangulated_share()[m.moving]
            rows.append(("markers", f"{[len(d) for d in m.detections]} found per view; "
                                    f"{len(m.members)} joined across views, "
                                    f"{int(m.moving.sum())} of them moving; those in "
                                    f"3-D in {np.mean(share) if len(share) else 0:.0%} of "
                                    "the frames on average; join checks "
                                    + ", ".join(f"{k.replace('_', ' ')} {v}"
                                                for k, v in m.joins.items())
                                    + "; " + _filter_text(m.filter)))
        if self.arm is not None:
            full = self.arm.full
            rows.append(("arm model", f"{full.status.name} after {full.rounds} round(s) in "
                                      f"{len(self.arm.frames)} of {len(self.frames)} frames "
                                      f"(both arm segments tracked); bone lengths "
                                      f"{full.lengths[0]:.1f} / {full.lengths[1]:.1f} mm; sigma "
                                      f"{self.arm.sigma_mm:.2f} mm"))
        return [{"stage": s, "seconds": self.seconds.get(s, float("nan")), "result": r}
                for s, r in rows]


def _names(view: ViewCapture) -> str:
    return "+".join(c.name or str(k) for k, c in zip(view.group.cameras, view.cameras))


def _joined_names(cameras) -> str:
    return "+".join(c.name or "?" for c in cameras)


def _more_views_text(view: ViewCapture) -> str:
    """First measured frame's points in 3 or more views and their median residual."""
    if not view.more_views:
        return "no surface"
    mv = view.more_views[min(view.more_views)]
    three = mv.n_views >= 3
    med = f", median residual {np.median(mv.residual[three]):.2f} px" if three.any() else ""
    return f"first frame {int(three.sum())} of {len(three)} points in >= 3 views{med}"


def _off_subject_text(surfaces: dict) -> str:
    """``" (N off the subject dropped)"`` where a subject mask dropped any in the first
    measured frame (the frame :func:`_surface_points` counts), else ``""``."""
    first = surfaces[min(surfaces)] if surfaces else None
    return f" ({first.off_subject} off the subject dropped)" if first and first.off_subject \
        else ""


def _surface_points(surfaces: dict) -> int:
    """Points of the first measured frame's surface (0 without one)."""
    return int(surfaces[min(surfaces)].kept.sum()) if surfaces else 0


def _calibration_text(cal) -> str:
    if cal is None:
        return "cameras as given"
    if hasattr(cal, "held_out_after"):                       # a RigRefinement
        before, after = np.nanmedian(cal.held_out_before), np.nanmedian(cal.held_out_after)
        used = "refined cameras used" if cal.improved else "the given cameras kept"
        return (f"refined from the recording; held-out {cal.held_out_kind} {before:.2f} px before, "
                f"{after:.2f} px after (median over cameras): {used}")
    text = f"image RMS {cal.bundle.rms:.4f} px ({cal.rms_over_limit:.3f} x the noise limit)"
    if hasattr(cal, "n_positions"):                          # a RigCalibration
        text = (f"{cal.n_positions} bar positions, {text}, {cal.labels.n_swapped} swapped "
                "target labels fixed")
        level = getattr(cal, "level", None)
        if level is not None:
            text += (f"; levelled with {level.n_frames} upright-bar frames (world turned by "
                     f"{level.correction_deg:.2f} deg)")
    return text


def track_surface(videos, surfaces: dict, *, params: TrackerParams | None = None,
                  start_cameras=None, progress: bool = False) -> Tracks:
    """Surface tracking (Fig. 9): every point of the first surface with a kept point (before
    the last frame), new points from later ones.

    Parameters
    ----------
    videos : (K, T, H, W) array
    surfaces : dict of int -> SurfaceResult
        Surfaces by frame. The tracks start at the first frame before the last whose
        surface has a kept point, from its points that passed the neighbourhood filter;
        the later frames' feed the density check (every ``params.density_every`` frames
        counted from the start frame).
    params : TrackerParams, optional
    start_cameras : sequence of K Camera, optional
        Only to start the spatial LSM of each new track from the map the cameras predict
        where a camera sees the template's patch turned or scaled (a camera mounted on its
        side; :func:`~lsmta.tracking.track_points`' ``start_cameras``); no reprojection
        check.
    progress : bool

    Returns
    -------
    Tracks
        Over all T frames: NaN before the start frame (``start.min()`` is the start frame).
    """
    s = _tracking_start(surfaces, len(videos[0]))
    if s is None:
        raise ValueError("surfaces: no frame before the last has a surface point to track")
    first = surfaces[s]
    start = first.xy[:, first.neighbourhood_ok]
    new = {t - s: r.xy[:, r.neighbourhood_ok] for t, r in surfaces.items() if t > s}
    tracks = track_points(videos[:, s:], start, params=params, new_points=new,
                          start_cameras=start_cameras, progress=progress)
    return _delayed(tracks, s)


def _tracking_start(surfaces: dict, n_frames: int) -> int | None:
    """The first frame whose surface has a kept point and that has a frame after it to track
    into (None when there is none)."""
    return next((t for t in sorted(surfaces) if t < n_frames - 1 and surfaces[t].kept.any()),
                None)


def _delayed(tracks: Tracks, s: int) -> Tracks:
    """Tracks of frames ``s:`` as tracks of all frames (untracked before ``s``)."""
    if s == 0:
        return tracks

    def pad(a, value):
        return np.concatenate([np.full((s,) + a.shape[1:], value, a.dtype), a])

    return replace(tracks, xy=pad(tracks.xy, np.nan), start=tracks.start + s,
                   end=np.where(tracks.end >= 0, tracks.end + s, tracks.end),
                   retried=pad(tracks.retried, False), recovered=pad(tracks.recovered, False),
                   anchor=pad(np.where(tracks.anchor >= 0, tracks.anchor + s, -1), -1))


# ------------------------------------------------------------------------- arguments
def _frame_indices(frames, T: int) -> np.ndarray:
    if frames is None:
        return np.arange(T)
    if isinstance(frames, slice):
        idx = np.arange(T)[frames]
    else:
        idx = np.asarray(frames)
        if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
            raise ValueError(f"frames: expected a slice or a sequence of frame indices, got "
                             f"{frames!r}")
    if len(idx) < 3:
        raise ValueError(f"frames: expected at least 3 frames, got {len(idx)}")
    if idx.min() < 0 or idx.max() >= T:
        raise ValueError(f"frames: expected indices in [0, {T - 1}], got {idx.min()}..{idx.max()}")
    if np.any(np.diff(idx) != 1):
        raise ValueError("frames: expected consecutive frames (the tracker follows them one "
                         "by one)")
    return idx


def _stacks(videos, n_cameras: int, progress: bool) -> tuple[list, float | None]:
    """K grey ``(T, H_k, W_k)`` arrays (not copied where they are arrays already) and the
    frame rate a Videos object states."""
    if isinstance(videos, Videos):
        return videos.load(progress=progress), videos.fps
    if isinstance(videos, np.ndarray):
        if videos.ndim != 4:
            raise ValueError(f"videos: expected an array of shape (K, T, H, W) (K cameras, T "
                             f"frames) or K (T, H, W) arrays, got shape {videos.shape}")
        stacks = list(videos)
    else:
        stacks = [np.asarray(v) for v in videos]
    if len(stacks) != n_cameras:
        raise ValueError(f"videos: expected {n_cameras} videos, one per camera, got "
                         f"{len(stacks)}")
    for k, v in enumerate(stacks):
        if v.ndim != 3:
            raise ValueError(f"videos[{k}]: expected (T, H, W) grey frames, got shape {v.shape}")
        if v.dtype == bool or not (np.issubdtype(v.dtype, np.integer)
                                   or np.issubdtype(v.dtype, np.floating)):
            raise TypeError(f"videos[{k}]: expected grey values (uint8 or float), got dtype "
                            f"{v.dtype}")
        if np.issubdtype(v.dtype, np.floating) and not np.isfinite(v).all():
            raise ValueError(f"videos[{k}]: contains non-finite values; expected grey levels")
    if len({len(v) for v in stacks}) != 1:
        raise ValueError(f"videos: expected the same number of frames in every video, got "
                         f"{[len(v) for v in stacks]}")
    return stacks, None


def _first_frames(videos, stacks, idx, markers: MarkerParams | None):
    """The first processed frame of every view as the marker detector wants it."""
    if markers is None:
        return None
    if isinstance(videos, Videos):
        return videos.read(int(idx[0]), colour=markers.detector == "skin")
    if markers.detector == "skin":
        raise ValueError("params.markers: skin markers are found in colour frames; pass the "
                         "videos from lsmta.io.read_videos, or use detector='blobs'")
    return [s[idx[0]] for s in stacks]


def _check_sizes(stacks, cameras) -> None:
    for k, (v, cam) in enumerate(zip(stacks, cameras)):
        if (v.shape[2], v.shape[1]) != (cam.width, cam.height):
            raise ValueError(f"videos[{k}]: frames are {v.shape[2]} x {v.shape[1]} px but camera "
                             f"{cam.name or k} is {cam.width} x {cam.height}; fit the cameras "
                             "to the videos first (lsmta.io.cameras_for_videos)")


# ------------------------------------------------------------------------- stages
@dataclass
class _State:
    """What the stages of :func:`capture_recording` hand on."""

    stacks: list
    cameras: list
    frames: np.ndarray
    fps: float
    params: CaptureParams
    progress: bool
    seed: int
    groups: tuple = ()
    inputs: list = field(default_factory=list)      # per group: (videos, cameras)
    noise: list = field(default_factory=list)
    surfaces: list = field(default_factory=list)
    more_views: list = field(default_factory=list)
    tracks: list = field(default_factory=list)
    trajectories: Trajectories | None = None
    slices: list = field(default_factory=list)
    filters: tuple | None = None
    arm: ArmFit | None = None
    first_frames: list | None = None
    markers: MarkerCapture | None = None
    filter_off: str | None = None                   # why the markers' filter was turned off


def _span(frames) -> slice:
    """The consecutive frames as a slice (a view of the stacks, not a copy)."""
    return slice(int(frames[0]), int(frames[-1]) + 1)


def _view_groups(st: _State) -> None:
    st.groups = view_groups(st.cameras, max_angle_deg=st.params.max_angle_deg)
    for g in st.groups:
        w = min(st.stacks[k].shape[2] for k in g.cameras)
        h = min(st.stacks[k].shape[1] for k in g.cameras)
        videos = np.stack([st.stacks[k][_span(st.frames), :h, :w] for k in g.cameras])
        cams = [st.cameras[k] if (st.cameras[k].width, st.cameras[k].height) == (w, h)
                else cropped_camera(st.cameras[k], 0, 0, w, h) for k in g.cameras]
        st.inputs.append((videos, cams))


def _image_noise(st: _State) -> None:
    st.noise = [temporal_noise(v) for v, _ in st.inputs]


def _surfaces(st: _State) -> None:
    """Every view group's surfaces; a group of >= 3 cameras split into pairs by the rule of
    :class:`CaptureParams` (``min_group_share``)."""
    groups, inputs, noises = [], [], []
    for g, (v, cams), noise in zip(st.groups, st.inputs, st.noise):
        measured, frames = _group_surfaces(st, g, v, cams, noise)
        held = _held(measured)
        pairs = []
        if len(cams) >= 3 and len(held) < st.params.min_group_share * len(frames):
            pairs = _pairs(st, g, v, cams)
            by_pairs = set().union(*(_held(m) for *_, m in pairs))
            if len(by_pairs) < max(2 * len(held), len(held) + 1):
                pairs = []                    # not clearly more: the group stays whole
            else:
                warnings.warn(
                    f"capture_recording: view group {_joined_names(cams)} holds surface "
                    f"points in {len(held)} of its {len(frames)} measured frames (a point "
                    f"must be seen by all its cameras), its pairs in {len(by_pairs)}; it is "
                    "measured as pairs of its template with each other camera "
                    "(CaptureParams.min_group_share)", stacklevel=3)
        if not pairs:
            pairs = [(g, (v, cams), noise, measured)]
        for pg, pin, pn, pm in pairs:
            groups.append(pg)
            inputs.append(pin)
            noises.append(pn)
            st.surfaces.append(pm)
    st.groups, st.inputs, st.noise = tuple(groups), inputs, noises


def _held(measured: dict) -> set:
    """The measured frames whose surface holds a kept point."""
    return {f for f, r in measured.items() if r.kept.any()}


def _pairs(st: _State, g, v, cams) -> list:
    """A view group's pairs of its template with each other camera, measured: (group,
    (videos, cameras), noise, surfaces) each."""
    out = []
    for j in range(len(cams)):
        if j == g.template_position:
            continue
        pos = sorted((j, g.template_position))
        pair = ViewGroup(cameras=tuple(g.cameras[i] for i in pos), template=g.template)
        pv, pc = v[pos], [cams[i] for i in pos]
        pn = temporal_noise(pv)
        out.append((pair, (pv, pc), pn, _group_surfaces(st, pair, pv, pc, pn)[0]))
    return out


def _group_surfaces(st: _State, g, v, cams, noise) -> tuple[dict, range]:
    """One view group's surfaces (:func:`measure_surfaces`) in every measured frame, and
    those frames."""
    p = st.params
    surface = replace(p.surface, template=g.template_position)
    if surface.method == "rectified" and len(cams) != 2:
        warnings.warn(f"capture_recording: view group {_joined_names(cams)} has "
                      f"{len(cams)} cameras, and SurfaceParams(method='rectified') "
                      "(lsmta capture --surface-method rectified-sgbm) measures pairs "
                      "only; this group is measured by the growth", stacklevel=5)
        surface = replace(surface, method="grow")
    frames = range(0, v.shape[1], p.density_every)
    return measure_surfaces(v, cams, frames, sigma=noise.sigma, params=surface,
                            progress=st.progress), frames


def _more_views(st: _State) -> None:
    p = st.params.more_views
    for g, surfaces in zip(st.groups, st.surfaces):
        got = {}
        if p is not None:
            for f, r in surfaces.items():
                xy = group_xy(r, g.cameras, len(st.cameras))
                images = [s[st.frames[f]] for s in st.stacks]
                got[f] = add_views(images, st.cameras, xy, reference=g.template, params=p)
        st.more_views.append(got)


def _tracking(st: _State) -> None:
    p = st.params
    for g, (v, cams), surfaces in zip(st.groups, st.inputs, st.surfaces):
        if _tracking_start(surfaces, len(v[0])) is None:
            warnings.warn(f"capture_recording: view group {_joined_names(cams)} has no "
                          "surface point in any measured frame before the last; it is left "
                          "out", stacklevel=3)
            st.tracks.append(None)
            continue
        tracker = replace(p.tracker, density_every=p.density_every,
                          template=g.template_position)
        st.tracks.append(track_surface(v, surfaces, params=tracker, start_cameras=cams,
                                       progress=st.progress))
    if all(t is None for t in st.tracks) and st.params.markers is None:
        off = sum(r.off_subject for s in st.surfaces for r in s.values())
        why = (f"the subject mask (SurfaceParams.subject_mask, --subject-mask) dropped {off} "
               "n-tuples off the moving subject; try without it, or " if off else "")
        raise ValueError("videos: no view group found a surface point in any measured frame "
                         "before the last "
                         "(no seed matched, or every match failed LSM's thresholds"
                         + (", or the subject mask dropped them" if off else "") + "); "
                         + why + "check the cameras and the frames")


def _trajectories(st: _State) -> None:
    parts, n = [], 0
    for (_, cams), tracks in zip(st.inputs, st.tracks):
        xyz = (np.empty((len(st.frames), 0, 3)) if tracks is None else
               trajectories_from_tracks(cams, tracks, st.fps).xyz)
        parts.append(xyz)
        st.slices.append(slice(n, n + xyz.shape[1]))
        n += xyz.shape[1]
    st.trajectories = Trajectories(xyz=np.concatenate(parts, axis=1), fps=st.fps)
    st.filters = apply_filters(st.trajectories, **asdict(st.params.filters))


def _markers(st: _State) -> None:
    if st.params.markers is not None:
        stacks = [s[_span(st.frames)] for s in st.stacks]
        st.markers = capture_markers(stacks, st.cameras, st.first_frames,
                                     params=st.params.markers, fps=st.fps)
        if st.filter_off is not None:
            st.markers = replace(st.markers, filter={"applied": False,
                                                     "reason": st.filter_off})


def _arm_model(st: _State) -> None:
    if st.params.arm is not None:
        st.arm = fit_arm(st.filters[-1].trajectories, st.cameras, settings=st.params.arm,
                         rng=st.seed)


STAGES = (("view groups", _view_groups), ("image noise", _image_noise),
          ("surfaces", _surfaces), ("more views", _more_views), ("tracking", _tracking),
          ("trajectories", _trajectories),
          ("markers", _markers), ("arm model", _arm_model))


def _filter_text(record: dict) -> str:
    """The marker stage's low-pass filter in a few words."""
    if not record.get("applied"):
        return f"not low-pass filtered ({record.get('reason', 'no filter')})"
    return (f"low-pass filtered at {record['cutoff_hz']:g} Hz (zero-lag Butterworth, order "
            f"{record['order']}; {record['short_runs']} short runs left raw)")


def capture_recording(videos, cameras, *, fps: float | None = None, frames=None,
                      calibration=None, params: CaptureParams | None = None,
                      progress: bool = True, seed: int = 0) -> BodyCapture:
    """Run the LSMTA system on a synchronised recording with calibrated cameras.

    Parameters
    ----------
    videos : Videos, (K, T, H, W) array or sequence of K (T, H_k, W_k) arrays
        Grey frames (uint8 or float) from K >= 2 synchronised cameras, e.g.
        :func:`lsmta.io.read_videos` (read here, once).
    cameras : sequence of K Camera
        Calibrated cameras that fit the frames (:func:`lsmta.io.cameras_for_videos`).
    fps : float, optional
        Frame rate, Hz (the trajectory filters' speeds are per second); taken from
        ``videos`` when it is a Videos object.
    frames : slice or sequence of int, optional
        Consecutive frames to process (default: all).
    calibration : object, optional
        Where the cameras came from, kept in the result (e.g. a RigRefinement).
    params : CaptureParams, optional
        A marker cut-off (``params.markers.filter_hz``) not below ``fps / 2`` is decided
        on before any stage (:func:`~lsmta.systems.markers.nyquist_checked`): a chosen one
        raises ValueError, the default one is turned off with a warning (``summary.json``'s
        ``marker_filter`` gives the reason).
    progress : bool
        Progress bars per stage.
    seed : int
        Seeds the only random step (the arm stage's sample of trajectories).

    Returns
    -------
    BodyCapture
        Nothing passed in is modified.
    """
    cams = check_cameras(cameras, "cameras")
    p = params or CaptureParams()
    if not isinstance(p, CaptureParams):
        raise TypeError(f"params: expected a CaptureParams, got {type(p).__name__}")
    stacks, rate = _stacks(videos, len(cams), progress)
    _check_sizes(stacks, cams)
    file_frames = np.asarray(videos.frames) if isinstance(videos, Videos) else None
    if fps is None and rate is None:
        raise ValueError("fps: expected the frame rate (Hz) of videos given as arrays")
    fps = as_scalar(fps if fps is not None else rate, "fps", positive=True)
    markers, off = nyquist_checked(p.markers, fps)          # before minutes of stages
    idx = _frame_indices(frames, len(stacks[0]))
    st = _State(stacks=stacks, cameras=cams, frames=idx, fps=fps,
                params=replace(p, markers=markers), progress=progress, seed=int(seed),
                first_frames=_first_frames(videos, stacks, idx, p.markers), filter_off=off)
    seconds = {}
    for name, stage in tqdm(STAGES, desc="LSMTA system", disable=not progress):
        t0 = time.perf_counter()
        stage(st)
        seconds[name] = time.perf_counter() - t0
    for name, stage_params in (("arm model", p.arm), ("markers", p.markers),
                               ("more views", p.more_views)):
        if stage_params is None:
            del seconds[name]
    views = tuple(ViewCapture(group=g, cameras=c, noise=n, surfaces=s, tracks=t, points=sl,
                              more_views=m)
                  for g, (_, c), n, s, t, sl, m in zip(st.groups, st.inputs, st.noise,
                                                       st.surfaces, st.tracks, st.slices,
                                                       st.more_views))
    frames = idx if file_frames is None else file_frames[idx]
    return BodyCapture(cameras=cams, calibration=calibration, frames=frames, fps=fps, views=views,
                       trajectories=st.trajectories, filters=st.filters, arm=st.arm,
                       markers=st.markers, seconds=seconds, params=p)
