"""The LSMTA system on the generated walk, from the papers' triplet or an all-round studio,
scored against the generator's surface after the fact.

:func:`walk_session` makes what a user brings to :func:`lsmta.systems.capture_walk`: the
videos of a person walking through the volume, a bar video, the bar's length, the bar stood
upright with a spirit level, and the cameras as built (tape-measured pose, nominal lens).
The rig is the papers' three cameras in front (:func:`~lsmta.synth.triplet_rig`) or an
all-round studio of 6-8 cameras on poles (:func:`~lsmta.synth.studio_rig`). The truth stays
beside it.

:func:`score_walk` compares the system's filtered trajectories, frame by frame, with the
generator's skin after carrying them into the true world by the rigid motion that best maps
the held-out bar targets onto their true positions
(:func:`~lsmta.evaluation.body_system.world_alignment`, no scale): the distance of every
system point to the true skin, the distance of every true skin sample on the seen side (seen
by two cameras of one view group) to the nearest system point, and the body segments the
points land on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_int, as_scalar, as_vector
from ..camera import scaled_camera
from ..rigid import fit_rigid
from ..synth import Scene, make_body, range_of_motion, studio_rig, triplet_rig, walk
from ..synth.body import Motion
from ..synth.calibration import BarTrack, bar_footage
from ..synth.render import Renderer, project_surface_points
from ..synth.surface import distance_to_body, distance_to_ellipsoid
from ..triangulation import triangulate
from .body_system import Alignment, heldout_points

RIGS = ("triplet", "studio")


@dataclass(frozen=True)
class WalkSessionParams:
    """The studio, the bar and the tape measure of :func:`walk_session`.

    Attributes
    ----------
    rig : {"triplet", "studio"}
        The papers' three cameras in front, 4.5 m from the walk's line, or the all-round
        studio of :func:`~lsmta.synth.studio_rig`.
    n_cameras, rows : int
        The studio's cameras and cameras per pole (ignored for the triplet).
    scale : float
        Image scale of the 768 x 576 sensors (0.5: 384 x 288, for quick runs); the body's
        texture wavelengths scale with it, so a pixel sees the same texture.
    noise : float
        Image noise, grey levels.
    backdrop : float
        The dark backdrop's grey level.
    bar_length : float
        mm.
    n_bar, n_heldout : int
        Bar positions filmed for the calibration and held out for the check points.
    bar_half_size : (3,) floats
        Half size of the volume the bar moves in (centred at 0, 0, 950), mm.
    tape_mm, tape_deg, lens_rel : float
        The nominal cameras' errors (:func:`~lsmta.synth.calibration.poor_guess`).
    level_places : int
        Places the bar is stood upright to level the world.
    rom_per_phase : int
        Frames rendered of each movement of the range-of-motion clip (0: no clip; else
        at least 2): the clip :func:`~lsmta.synth.range_of_motion` of ``rom_clip`` frames
        at 25 Hz, standing at the volume's centre facing -Y, and of each of its six
        movements the frames at clock ``k / rom_per_phase`` of the movement (``k = 0 ..
        rom_per_phase - 1``; 0 is the standing start, 1/2 the movement's extreme).
    rom_clip : int
        Frames of the whole clip (>= 24).
    """

    rig: str = "triplet"
    n_cameras: int = 8
    rows: int = 2
    scale: float = 1.0
    noise: float = 2.0
    backdrop: float = 20.0
    bar_length: float = 800.0
    n_bar: int = 150
    n_heldout: int = 40
    bar_half_size: tuple = (1000.0, 700.0, 500.0)
    tape_mm: float = 30.0
    tape_deg: float = 2.0
    lens_rel: float = 0.01
    level_places: int = 4
    rom_per_phase: int = 0
    rom_clip: int = 200

    def __post_init__(self):
        if self.rig not in RIGS:
            raise ValueError(f"rig: expected one of {RIGS}, got {self.rig!r}")
        as_int(self.n_cameras, "n_cameras", minimum=2)
        as_int(self.rows, "rows")
        as_scalar(self.scale, "scale", positive=True)
        for key in ("noise", "backdrop", "tape_mm", "tape_deg", "lens_rel"):
            as_scalar(getattr(self, key), key, nonnegative=True)
        as_scalar(self.bar_length, "bar_length", positive=True)
        as_vector(self.bar_half_size, "bar_half_size", 3)
        as_int(self.n_bar, "n_bar", minimum=10)
        as_int(self.n_heldout, "n_heldout")
        as_int(self.level_places, "level_places", minimum=0)
        if as_int(self.rom_per_phase, "rom_per_phase", minimum=0) == 1:
            raise ValueError("rom_per_phase: expected 0 (no clip) or at least 2 frames per "
                             "movement, got 1")
        as_int(self.rom_clip, "rom_clip", minimum=24)
        if self.rom_per_phase > self.rom_clip // 6:    # six movements: no frame twice
            raise ValueError(f"rom_per_phase: expected at most rom_clip // 6 = "
                             f"{self.rom_clip // 6} frames per movement, got {self.rom_per_phase}")


@dataclass(frozen=True, eq=False)
class WalkSession:
    """A generated walk session: what a user has, and the truth.

    Attributes
    ----------
    videos : (K, T, H, W) uint8 array
    bar_videos, heldout_videos : (K, Tb, H, W) uint8 arrays
        The bar for the calibration, and held out (check points).
    level_videos : (K, Tl, H, W) uint8 array or None
        The bar stood upright with a spirit level.
    bar_length : float
    nominal : list of Camera
        The cameras as built (tape-measured pose, nominal lens, no distortion).
    fps : float
    cameras : list of Camera
        The true cameras (truth).
    scene : Scene
        The body and its walk (truth).
    bar, heldout, level : BarTrack
        True bar positions (``level`` None without levelling).
    params : WalkSessionParams
    seed : int
    rom_videos : (K, R, H, W) uint8 array or None
        The range-of-motion clip's rendered frames (``params.rom_per_phase``), same cameras.
    rom_scene : Scene or None
        The same body in the clip's motion (truth).
    rom_frames : (R,) int array or None
        The clip's frame of each of ``rom_videos``' frames (25 Hz; the movements are
        ``rom_scene.motion.phases``).
    """

    videos: np.ndarray
    bar_videos: np.ndarray
    heldout_videos: np.ndarray
    level_videos: np.ndarray | None
    bar_length: float
    nominal: list
    fps: float
    cameras: list
    scene: Scene
    bar: BarTrack
    heldout: BarTrack
    level: BarTrack | None
    params: WalkSessionParams
    seed: int
    rom_videos: np.ndarray | None = None
    rom_scene: Scene | None = None
    rom_frames: np.ndarray | None = None


def _session_cameras(params: WalkSessionParams, rng) -> list:
    """The true cameras of the session's rig (drawn from ``rng``)."""
    if params.rig == "triplet":
        cams = triplet_rig(rng=rng)
    else:
        cams = studio_rig(n=params.n_cameras, rows=params.rows, rng=rng)
    return [scaled_camera(c, params.scale) for c in cams]


def walk_session(*, seed: int = 36, n_frames: int = 50,
                 params: WalkSessionParams | None = None) -> WalkSession:
    """Render ``n_frames`` of the walk (25 Hz, 1.3 m/s along +X, centred on the volume:
    the default 50 frames cross 2.6 m), a bar video, held-out bar positions and the bar
    stood upright, in the rig of ``params``; make the tape-measured cameras.

    Parameters
    ----------
    seed : int
        Draws the rig's build errors, the texture, the noise, the bar and the tape.
    n_frames : int
        Frames of the walk (>= 3).
    params : WalkSessionParams, optional
    """
    p = WalkSessionParams() if params is None else params
    if not isinstance(p, WalkSessionParams):
        raise TypeError(f"params: expected a WalkSessionParams, got {type(p).__name__}")
    n_frames = as_int(n_frames, "n_frames", minimum=3)
    rng = np.random.default_rng(seed)
    cams = _session_cameras(p, rng)
    body = make_body(rng=rng, contrast=0.3, wavelength=(20.0 / p.scale, 80.0 / p.scale))
    speed, fps = 1300.0, 25.0
    motion: Motion = walk(n_frames=n_frames, fps=fps, speed=speed,
                          start=(-speed * (n_frames - 1) / fps / 2, 0.0))
    scene = Scene(body=body, motion=motion, backdrop=p.backdrop)
    renderer = Renderer(scene, cams, noise_sigma=p.noise)
    videos = np.stack([renderer.render(t, rng=rng).images for t in range(n_frames)], axis=1)
    f = bar_footage(cams, rng=rng, length=p.bar_length, center=(0.0, 0.0, 950.0),
                    half_size=p.bar_half_size, n=(p.n_bar, p.n_heldout), noise=p.noise,
                    tape=(p.tape_mm, p.tape_deg, p.lens_rel), level_places=p.level_places)
    rom = _rom_clip(body, cams, p, seed) if p.rom_per_phase else (None, None, None)
    return WalkSession(videos=videos, bar_videos=f.bar_videos, heldout_videos=f.heldout_videos,
                       level_videos=f.level_videos, bar_length=p.bar_length, nominal=f.nominal,
                       fps=fps, cameras=cams, scene=scene, bar=f.bar, heldout=f.heldout,
                       level=f.level, params=p, seed=int(seed), rom_videos=rom[0],
                       rom_scene=rom[1], rom_frames=rom[2])


def rom_clip_frames(motion: Motion, per_phase: int) -> np.ndarray:
    """The frames of ``motion`` (a range-of-motion clip) at clock ``k / per_phase``
    (``k = 0 .. per_phase - 1``) of each of its movements, in order ``(6 per_phase,)``."""
    per_phase = as_int(per_phase, "per_phase", minimum=1)
    if not motion.phases:
        raise ValueError("motion: expected a clip with named movements (phases)")
    return np.array([a + int(round(k * (b - a) / per_phase)) for _, a, b in motion.phases
                     for k in range(per_phase)])


def _rom_clip(body, cams, p: WalkSessionParams, seed: int):
    """The range-of-motion clip's videos, scene and frames (its own noise stream, so the
    walk's session is the same with or without it)."""
    motion = range_of_motion(n_frames=p.rom_clip, fps=25.0)
    scene = Scene(body=body, motion=motion, backdrop=p.backdrop)
    frames = rom_clip_frames(motion, p.rom_per_phase)
    rng = np.random.default_rng([int(seed), 1])
    renderer = Renderer(scene, cams, noise_sigma=p.noise)
    videos = np.stack([renderer.render(int(t), rng=rng).images for t in frames], axis=1)
    return videos, scene, frames


# ------------------------------------------------------------------ alignment
def check_alignment(cameras, session: WalkSession) -> tuple[Alignment, np.ndarray]:
    """The rigid motion (no scale) from the system's world onto the true one, on the held-out
    bar's check points, whichever way round each position's ends were named.

    All-round cameras lose a bar end's name when the bar points at one of them, so a
    position's measured ends may be the truth's B and A; a first fit on the bar midpoints
    (which do not depend on the names) orders each position's ends by the nearest true end,
    and the fit on all ends follows, then once more without the ends more than ten times
    the median error off (so the errors returned include those dropped ends, but the fit
    does not) (a position whose ends were mixed up between cameras). Returns the
    alignment and every check point's error after it, mm (``(2 Th,)``, NaN where not intersected).
    """
    X = triangulate(cameras, heldout_points(cameras, session)).points.reshape(-1, 2, 3)
    truth = session.heldout.points.reshape(-1, 2, 3)
    ok = np.isfinite(X).all(axis=(1, 2))
    if ok.sum() < 3:
        raise ValueError("cameras: fewer than 3 held-out bar positions intersected")
    R, t = fit_rigid(X[ok].mean(axis=1), truth[ok].mean(axis=1))
    moved = X @ R.T + t
    straight = np.linalg.norm(moved - truth, axis=2).sum(axis=1)
    crossed = np.linalg.norm(moved[:, ::-1] - truth, axis=2).sum(axis=1)
    X = np.where((crossed < straight)[:, None, None], X[:, ::-1], X)
    X, truth = X.reshape(-1, 3), truth.reshape(-1, 3)
    ok = np.isfinite(X).all(axis=1)
    R, t = fit_rigid(X[ok], truth[ok])
    err = np.linalg.norm(X[ok] @ R.T + t - truth[ok], axis=1)
    keep = np.flatnonzero(ok)[err <= 10 * np.median(err)]
    R, t = fit_rigid(X[keep], truth[keep])
    al = Alignment(R=R, t=t, n_points=len(keep))
    return al, np.linalg.norm(al.points(X) - truth, axis=1)


# ------------------------------------------------------------------ scores
def nearest_part(body, poses, points) -> np.ndarray:
    """The body part ``(N,)`` whose ellipsoid's surface is nearest to each world point of
    ``points (N, 3)`` in one frame (``poses (P, 4, 4)``)."""
    pts = np.asarray(points, float).reshape(-1, 3)
    if not len(pts):
        return np.empty(0, int)
    d = np.stack([distance_to_ellipsoid((pts - poses[p, :3, 3]) @ poses[p, :3, :3]
                                        - np.asarray(spec.centre, float), spec.radii)
                  for p, spec in enumerate(body.parts)], axis=1)
    return np.argmin(np.abs(d), axis=1)


@dataclass(frozen=True, eq=False)
class WalkScore:
    """The system's points against the true skin, per processed frame.

    Attributes
    ----------
    frames : (T,) int array
        Frames of the session scored.
    to_truth : list of (M_t,) arrays
        Each system point's distance to the true skin, mm
        (:func:`~lsmta.synth.surface.distance_to_body`: exact outside the union of the
        parts; for a point inside it, the distance to the nearest part's surface, not to
        the union's skin).
    from_truth : list of (S_t,) arrays
        Each true skin sample on the seen side: distance to the nearest system point, mm.
    segment : list of (M_t,) int arrays
        The body part each system point is nearest to.
    seen_segments : list of (P,) bool arrays
        Parts with at least ``min_points`` true samples on the seen side.
    covered : list of (P,) bool arrays
        Parts with at least ``min_points`` system points within ``near_mm`` of their skin.
    names : list of str
    """

    frames: np.ndarray
    to_truth: list
    from_truth: list
    segment: list
    seen_segments: list
    covered: list
    names: list

    def summary(self) -> dict:
        """Medians over all frames' points (mm), and coverage counts."""
        to = np.concatenate(self.to_truth) if self.to_truth else np.empty(0)
        fr = np.concatenate(self.from_truth) if self.from_truth else np.empty(0)
        cov = np.array([c.sum() for c in self.covered])
        seen = np.array([s.sum() for s in self.seen_segments])
        ever = np.any(self.covered, axis=0)
        return {"to_truth_median_mm": float(np.median(to)) if to.size else float("nan"),
                "from_truth_median_mm": float(np.median(fr)) if fr.size else float("nan"),
                "points_per_frame_median": float(np.median([len(t) for t in self.to_truth])),
                "segments_covered_median": float(np.median(cov)),
                "segments_covered_min": int(cov.min()),
                "segments_seen_median": float(np.median(seen)),
                "segments_covered_any_frame": [n for n, e in zip(self.names, ever) if e]}


def score_walk(capture, session: WalkSession, alignment: Alignment, *, n_per_part: int = 300,
               min_points: int = 10, near_mm: float = 10.0, rng=None) -> WalkScore:
    """Score a :class:`~lsmta.systems.BodyCapture` of the walk against the true skin.

    Parameters
    ----------
    capture : BodyCapture
        Of ``session.videos`` (its ``frames`` index the session's frames).
    session : WalkSession
    alignment : Alignment
        The system's world -> the true world (e.g. on the held-out bar's check points).
    n_per_part : int
        True skin samples per part and frame (the seen side is taken from them).
    min_points, near_mm
        A part is seen with ``min_points`` true samples seen by two cameras of one view
        group; covered with ``min_points`` system points within ``near_mm`` of its skin.
    rng : numpy.random.Generator, int or None
        Draws the skin samples.
    """
    body, motion = session.scene.body, session.scene.motion
    part, local = body.sample_surface(n_per_part=n_per_part, rng=rng)
    groups = [np.asarray(v.group.cameras) for v in capture.views]
    frames = np.asarray(capture.frames)
    proj = project_surface_points(session.scene, session.cameras, part, local, frames=frames)
    poses = body.part_poses(motion, frames=frames)
    traj = capture.filtered
    P = len(body.parts)
    out = {k: [] for k in ("to_truth", "from_truth", "segment", "seen_segments", "covered")}
    for i in range(len(frames)):
        present = traj.present[i]
        pts = alignment.points(traj.xyz[i, present])
        skin = distance_to_body(body, poses[i], pts)
        seg = nearest_part(body, poses[i], pts)
        vis = proj.visible[i]                                      # (K, N)
        seen = np.zeros(len(part), bool)
        for g in groups:
            seen |= vis[g].sum(axis=0) >= 2
        true_pts = proj.world[i, seen]
        if len(pts) and len(true_pts):
            gap, _ = cKDTree(pts).query(true_pts)
        else:
            gap = np.full(len(true_pts), np.inf)
        near = np.abs(skin) <= near_mm
        out["to_truth"].append(np.abs(skin))
        out["from_truth"].append(gap)
        out["segment"].append(seg)
        out["seen_segments"].append(np.bincount(part[seen], minlength=P) >= min_points)
        out["covered"].append(np.bincount(seg[near], minlength=P) >= min_points)
    return WalkScore(frames=frames, names=body.names, **out)
