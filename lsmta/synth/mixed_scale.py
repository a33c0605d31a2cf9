"""The mixed-scale scene of Davis (2002, Figs. 4, 5): a person walks across the room making
expressions, LEDs on the head and shoulders for the ceiling cameras, painted markers on the
face for the pan-tilt heads.

* :func:`mixed_scale_scene` — the truth: the face (76 markers, expressions, head pose) and
  the LEDs sampled finely in time, the true ceiling rig and the true pan-tilt heads;
* :func:`render_pantilt_video` — the face-marker video a pan-tilt camera makes at the angles
  its motors reached (:func:`lsmta.synth.marker_video.render_marker_video` through
  :meth:`lsmta.pantilt.PanTiltCamera.camera_at`);
* :class:`SimulatedHead` — one head as a device: it takes commands, its motors follow them
  (dead time, rate limit: :class:`lsmta.pantilt.Motor`), and it grabs a frame at the angles
  reached, read back as the head reports them (its encoder's 0.1° steps, thesis §5.2);
* :func:`ceiling_videos` — each ceiling camera's rendered LED frames at its own clock.

Which face markers a head sees (``occlusion`` of :class:`MixedScaleScene`): with
``"normals"`` those whose surface faces the head (:func:`lsmta.synth.face.visible`); with
``"surface"`` those whose line of sight clears the head itself (ray casting,
:func:`lsmta.synth.head_surface.self_occlusion`: the nose hides a cheek, the far cheek
hides behind the face; thesis §5.3, Fig. 59); with ``"both"`` only those both draw.

The generator only renders: no calibration, detection or estimate is made here.
World frame as in :mod:`lsmta.synth.widearea`: X along the room, Y across, Z up, mm, s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .._validate import as_array, as_rng, as_scalar
from ..pantilt import Motor, PanTiltCamera
from ..pantilt.aiming import aim
from .face import VISIBLE_MIN_COS, MarkedFace, expression_weights, face_model, visible
from .head_surface import self_occlusion
from .marker_video import MarkerVideo, render_marker_video, skin_texture
from .pantilt import pantilt_head
from .widearea import (
    Clocks,
    LedScene,
    LedVideoParams,
    ceiling_rig,
    make_clocks,
    render_led_video,
    small_camera,
)

#: LEDs in the head frame (x right, y up, z forward out of the face), mm: top of the head
#: and the two shoulders; they shine upwards, to the ceiling.
LED_HEAD = np.array([[0.0, 140.0, -20.0], [-190.0, -260.0, -60.0], [190.0, -260.0, -60.0]])
LED_NAMES = ("head", "shoulder_r", "shoulder_l")
#: Home projection centres of the pan-tilt heads, mm, by their number (``heads`` of
#: :func:`mixed_scale_scene`). Two: side by side, 2 m apart, 2.6 m in front of the walk's
#: line. Four (thesis Fig. 54: four heads on one side of the room looking at the same point
#: from different directions): the same two plus one beyond each end of the walk, lower on
#: the left and higher on the right, so that the four look at the face from the left, the
#: front and the right, and from above and below.
HEAD_LAYOUTS = {
    2: ((-1000.0, -2300.0, 1700.0), (1000.0, -2300.0, 1700.0)),
    4: ((-1000.0, -2300.0, 1700.0), (1000.0, -2300.0, 1700.0),
        (-2600.0, -1900.0, 1350.0), (2600.0, -1900.0, 2050.0)),
}
#: The rules for which face markers a pan-tilt head sees (``occlusion`` of
#: :class:`MixedScaleScene`).
OCCLUSION_RULES = ("normals", "surface", "both")
#: The face looks along world -Y (towards the pan-tilt heads): head x -> X, y -> Z, z -> -Y.
_BASE = np.stack([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]], axis=1)


@dataclass(frozen=True, eq=False)
class MixedScaleScene:
    """The truth of one walk.

    Attributes
    ----------
    times : (S,) array
        Sample times, s (uniform, ``rate`` Hz).
    face : MarkedFace
    head : (S, M, 3) array
        Markers in the head frame (expressions), mm.
    R : (S, 3, 3) array
    t : (S, 3) array
        Head pose, ``world = head @ R.T + t``.
    leds : LedScene
        The LEDs (always on; the head LED hidden during ``head_hidden``).
    ceiling : list of Camera
        The true ceiling cameras (half size).
    heads : list of PanTiltCamera
        The true pan-tilt heads.
    walk_start, walk_end : float
        When the person starts and stops walking, s.
    occlusion : {"normals", "surface", "both"}
        Which face markers a pan-tilt head sees (:data:`OCCLUSION_RULES`). ``"normals"``
        (the default, and every number made before the others existed): those whose
        surface faces it, ``cos > 0.3`` between the normal and the line of sight
        (:func:`lsmta.synth.face.visible`, a stand-in). ``"surface"``: those whose line of
        sight clears the head itself (ray casting against the head surface,
        :func:`lsmta.synth.head_surface.self_occlusion`; thesis §5.3; as
        :func:`lsmta.evaluation.face.observe_face` with ``occlusion="surface"``): the nose
        can hide a cheek, and a marker seen at a grazing angle is drawn. ``"both"``: only
        markers both rules draw. The rules use no random numbers: the walk is the same under
        each (``dataclasses.replace(scene, occlusion=...)``).
    """

    times: np.ndarray
    face: MarkedFace
    head: np.ndarray
    R: np.ndarray
    t: np.ndarray
    leds: LedScene
    ceiling: list
    heads: list
    walk_start: float
    walk_end: float
    occlusion: str = "normals"

    def __post_init__(self):
        if self.occlusion not in OCCLUSION_RULES:
            raise ValueError(f"occlusion: expected one of {OCCLUSION_RULES}, got "
                             f"{self.occlusion!r}")

    def _index(self, t):
        u = np.clip((np.atleast_1d(np.asarray(t, float)) - self.times[0])
                    / (self.times[1] - self.times[0]), 0, len(self.times) - 1)
        return np.rint(u).astype(int)

    def face_at(self, t):
        """World markers ``(T, M, 3)``, normals ``(T, M, 3)`` and head origins ``(T, 3)`` at
        times ``t`` (nearest sample)."""
        i = self._index(t)
        world = np.einsum("tij,tmj->tmi", self.R[i], self.head[i]) + self.t[i, None]
        normals = np.einsum("tij,mj->tmi", self.R[i], self.face.normals)
        return world, normals, self.t[i].copy()

    def pose_at(self, t):
        """Head pose at times ``t`` (nearest sample): rotations ``(T, 3, 3)`` and origins
        ``(T, 3)`` mm, ``world = head @ R.T + t``."""
        i = self._index(t)
        return self.R[i].copy(), self.t[i].copy()

    def unhidden(self, t, centres) -> np.ndarray:
        """``(T, C, M)`` bool: the face markers at times ``t`` (``(T,)`` s, nearest sample)
        whose line of sight to each camera centre (``(C, 3)`` or ``(T, C, 3)`` mm) clears the
        head itself (:func:`lsmta.synth.head_surface.self_occlusion`, one call vectorised
        over frames, cameras and markers); all True with ``occlusion="normals"``."""
        i = self._index(t)
        c = np.asarray(centres, float)
        n_cams = c.shape[-2] if c.ndim >= 2 else 1
        if self.occlusion == "normals":
            return np.ones((len(i), n_cams, self.head.shape[1]), dtype=bool)
        world, _, _ = self.face_at(self.times[i])
        return self_occlusion(world, self.R[i], self.t[i], c, neutral=self.face.neutral)

    def head_led_at(self, t) -> np.ndarray:
        """The head LED's position ``(T, 3)`` at times ``t``, mm."""
        return self.leds.positions_at(t)[:, 0]


def _walk_path(times, start_x, end_x, walk_start, walk_end, y, height, rng):
    """Head origin: standing, walking at constant speed with smooth 0.3 s ramps, standing;
    a vertical bob of 20 mm at the step frequency while walking."""
    ramp = 0.3
    d = end_x - start_x
    v = d / (walk_end - walk_start - ramp)
    s = np.clip(times - walk_start, 0, walk_end - walk_start)
    T = walk_end - walk_start
    # piecewise: accelerate over ramp, cruise, decelerate over ramp (area = d)
    x = np.where(s < ramp, 0.5 * v / ramp * s**2,
                 np.where(s < T - ramp, 0.5 * v * ramp + v * (s - ramp),
                          d - 0.5 * v / ramp * (T - s) ** 2))
    walking = (times > walk_start) & (times < walk_end)
    bob = 20.0 * np.sin(2 * np.pi * 1.8 * (times - walk_start)) * walking
    sway = 25.0 * np.sin(2 * np.pi * 0.9 * (times - walk_start) + rng.uniform(0, 2 * np.pi))
    return np.stack([start_x + x, y + sway * walking, height + bob], axis=1)


def mixed_scale_scene(*, rng: np.random.Generator | int | None = None, travel: float = 4000.0,
                      speed: float = 1200.0, stand: float = 1.0, rate: float = 200.0,
                      y: float = 300.0, height: float = 1650.0, turn_deg=(12.0, 5.0),
                      n_ceiling: int = 6, heads=2, head_f: float = 3000.0,
                      head_hidden=None) -> MixedScaleScene:
    """A person walks ``travel`` mm along X at ``speed`` mm/s, standing ``stand`` s before
    and after, looking towards -Y (the pan-tilt heads) and turning the head a little, with
    expressions (:func:`lsmta.synth.face.expression_weights`).

    Parameters
    ----------
    turn_deg : (2,)
        Amplitudes of the head's yaw and pitch, degrees (sines at 0.4 and 0.6 Hz).
    n_ceiling : int
        Ceiling cameras kept (those of :func:`lsmta.synth.widearea.ceiling_rig` that see the
        head LED's path best), at half size.
    heads : {2, 4} or sequence of (3,)
        The pan-tilt heads: a layout of :data:`HEAD_LAYOUTS` by its number of heads (the
        first two of the four are the two of the two-head layout, with the same misaligned
        axes, the same ``rng``, so that a walk seen by four heads is the walk seen by two
        plus two more), or the heads' home projection centres, mm. Each looks at the middle
        of the walk at home and has the misaligned axes of
        :func:`lsmta.synth.pantilt.pantilt_head`.
    head_f : float
        The heads' principal distance, px (zoomed in: at 2.5-3.5 m the face is 120-170 px
        wide in the 640 x 480 frame, 1 px about 1 mm).
    head_hidden : (2,) or None
        ``(start, end)``, s: the head LED is hidden from every ceiling camera in between (a
        hand over it; :attr:`LedScene.hidden`); the face stays in view. None: never.

    Returns
    -------
    MixedScaleScene
        With ``occlusion="normals"``; ``dataclasses.replace(scene, occlusion="surface")``
        is the same walk with the face hiding its own markers (:class:`MixedScaleScene`).
    """
    rng = as_rng(rng)
    travel = as_scalar(travel, "travel", positive=True)
    speed = as_scalar(speed, "speed", positive=True)
    stand = as_scalar(stand, "stand", nonnegative=True)
    rate = as_scalar(rate, "rate", positive=True)
    turn = as_array(turn_deg, "turn_deg", shape=(2,))
    head_positions = _head_positions(heads)
    hidden = np.full((len(LED_HEAD), 2), np.inf)
    if head_hidden is not None:
        hidden[0] = as_array(head_hidden, "head_hidden", shape=(2,))
        if not hidden[0, 1] > hidden[0, 0] >= 0:
            raise ValueError(f"head_hidden: expected (start, end) s with 0 <= start < end, "
                             f"got {tuple(head_hidden)}")
    walk_time = travel / speed + 0.3
    duration = 2 * stand + walk_time
    times = np.arange(int(np.ceil(duration * rate)) + 1) / rate
    fm = face_model()
    w = expression_weights(len(times), rng=rng, hold=0.6 * rate)
    head = fm.shapes(w)
    t = _walk_path(times, -travel / 2, travel / 2, stand, stand + walk_time, y, height, rng)
    ph = rng.uniform(0, 2 * np.pi, 3)
    yaw = turn[0] * np.sin(2 * np.pi * 0.4 * times + ph[0])
    pitch = turn[1] * np.sin(2 * np.pi * 0.6 * times + ph[1])
    roll = 3.0 * np.sin(2 * np.pi * 0.5 * times + ph[2])
    R = _BASE @ Rotation.from_euler("YXZ", np.stack([yaw, pitch, roll], 1),
                                    degrees=True).as_matrix()
    pos = np.einsum("tij,nj->tni", R, LED_HEAD) + t[:, None]
    # shoulders do not nod with the head: keep only the yaw for them
    Ry = _BASE @ Rotation.from_euler("Y", yaw[:, None], degrees=True).as_matrix()
    pos[:, 1:] = np.einsum("tij,nj->tni", Ry, LED_HEAD[1:]) + t[:, None]
    normals = np.broadcast_to([0.0, 0.0, 1.0], pos.shape).copy()
    leds = LedScene(name="walk with a face", times=times, positions=pos, normals=normals,
                    on=np.tile([0.0, np.inf], (len(LED_HEAD), 1)), hidden=hidden)
    rig = [small_camera(c) for c in ceiling_rig(rng=rng)]
    path = pos[::10, 0]   # the head LED's path, hidden or not
    seen = [cam.in_image(cam.project(path, behind="nan")).mean() for cam in rig]
    ceiling = [rig[i] for i in np.sort(np.argsort(seen)[::-1][:int(n_ceiling)])]
    middle = np.array([0.0, y, height])
    heads = [pantilt_head(rng=rng, position=p, look_at=middle, f=head_f, name=f"head{i}")
             for i, p in enumerate(head_positions)]
    return MixedScaleScene(times=times, face=fm, head=head, R=R, t=t, leds=leds,
                           ceiling=ceiling, heads=heads, walk_start=stand,
                           walk_end=stand + walk_time)


def _head_positions(heads) -> np.ndarray:
    """``mixed_scale_scene``'s ``heads`` as (K, 3) home positions, mm."""
    if np.ndim(heads) == 0:
        if heads not in HEAD_LAYOUTS:
            raise ValueError(f"heads: expected one of {sorted(HEAD_LAYOUTS)} or (K, 3) "
                             f"positions, got {heads!r}")
        heads = HEAD_LAYOUTS[heads]
    positions = as_array(heads, "heads", shape=(None, 3))
    if len(positions) < 1:
        raise ValueError("heads: expected at least one (3,) position")
    return positions


def wide_heads(scene: MixedScaleScene, *, f: float = 270.0,
               rng: np.random.Generator | int | None = None) -> list:
    """Wide-angle cameras where the scene's heads are, each looking at the middle of the
    walk with principal distance ``f`` px (270: the whole 4 m walk inside the 640 x 480
    frame), misaligned like :func:`lsmta.synth.pantilt.pantilt_head` (on fixed mounts, the
    axes do not matter)."""
    rng = as_rng(rng)
    middle = np.array([0.0, float(scene.t[0, 1]), float(scene.t[:, 2].mean())])
    return [pantilt_head(rng=rng, position=h.camera.C, look_at=middle, f=f,
                         name=f"wide{i}") for i, h in enumerate(scene.heads)]


def render_pantilt_video(head: PanTiltCamera, settings, points, normals, anchor, *,
                         rng: np.random.Generator | int | None = None,
                         min_cos: float = VISIBLE_MIN_COS, texture=None, noise: float = 2.0,
                         drawn=None) -> MarkerVideo:
    """The face-marker video of a pan-tilt camera at the settings its motors reached.

    Parameters
    ----------
    head : PanTiltCamera
        The true head.
    settings : (T, 2) array
        Pan and tilt of each frame, degrees (the angles reached, not the commands).
    points, normals : (T, M, 3) arrays
        World markers and their unit normals, mm.
    anchor : (T, 3) array
        Head origin (the skin texture moves with it).
    min_cos : float
        A marker is drawn where its surface faces the camera
        (:func:`lsmta.synth.face.visible`).
    drawn : (T, M) bool array, optional
        The markers to draw, in place of the ``min_cos`` rule (e.g.
        :meth:`SimulatedHead.drawn`, which follows the scene's ``occlusion``).
    texture, noise, rng
        As :func:`lsmta.synth.marker_video.render_marker_video`.
    """
    if not isinstance(head, PanTiltCamera):
        raise TypeError(f"head: expected a PanTiltCamera, got {type(head).__name__}")
    s = as_array(settings, "settings", shape=(None, 2))
    pts = as_array(points, "points", shape=(len(s), None, 3))
    nrm = as_array(normals, "normals", shape=pts.shape)
    cams = [head.camera_at(p, q) for p, q in s]
    if drawn is None:
        vis = np.stack([visible(pts[f], nrm[f], cams[f].C, min_cos=min_cos)
                        for f in range(len(s))])
    else:
        vis = np.asarray(drawn)
        if vis.dtype != bool or vis.shape != pts.shape[:2]:
            raise ValueError(f"drawn: expected a bool array of shape {pts.shape[:2]}, got "
                             f"{vis.dtype} {vis.shape}")
    return render_marker_video(cams, pts, vis, anchor, rng=rng, noise=noise, texture=texture)


class SimulatedHead:
    """A pan-tilt head as a device (the system talks to it; the truth stays inside).

    :meth:`command` sends a setting at a time; the motors start towards it ``motor.latency``
    s later at a speed that would reach it in ``period`` s, at most ``motor.max_rate``.
    :meth:`grab` returns the frame at a time, taken at the angles the head has reached, and
    the angles the head reports then: the reached angle plus ``readback_noise`` (Gaussian,
    degrees), rounded to the encoder's ``readback_step`` degrees. The thesis's heads "have
    precision of only 0.1 degree" (§5.2), so the default reports in 0.1° steps, off by up to
    0.05° from where the head is; ``readback_step=0`` and ``readback_noise=0`` report the
    angles exactly. The mechanics turn continuously between the steps (the thesis gives
    no finer mechanical step); ``motor.quantum`` is not used here.

    Parameters
    ----------
    head : PanTiltCamera
        The true head.
    scene : MixedScaleScene
    motor : Motor
    period : float
        The command period, s.
    rng : numpy.random.Generator, int or None
        Skin texture and image noise.
    start : (2,)
        The setting at time 0, degrees.
    fixed : bool
        A camera on a fixed mount: commands are ignored, it stays at ``start``.
    readback_step : float
        The encoder's step, degrees (0: no quantisation).
    readback_noise : float
        Standard deviation of the encoder's noise before the rounding, degrees.

    Notes
    -----
    With the scene's ``occlusion="surface"`` a frame draws only the markers whose line of
    sight clears the head (:meth:`MixedScaleScene.unhidden`). The ray cast runs in batches:
    at a frame not yet cast, for it and the next ``occlusion_batch - 1`` frames one command
    period apart, each from the projection centre at the setting that centres the face
    (:func:`lsmta.pantilt.aiming.aim`: the head's centre moves a few tens of mm with its
    angles; a ``fixed`` head's from where it stands); a frame whose head stands more than
    ``centre_tol`` mm from that centre is cast again from where it is. :meth:`grab` and
    :meth:`true_xy` read the same casts.
    """

    #: frames cast together, and how far (mm) a head's centre may stand from the one a frame
    #: was cast from (5 mm: 0.1 degree at the walk's 2.5-3.5 m)
    occlusion_batch = 64
    centre_tol = 5.0

    def __init__(self, head: PanTiltCamera, scene: MixedScaleScene, *, motor: Motor | None = None,
                 period: float = 1 / 30, rng: np.random.Generator | int | None = None,
                 start=(0.0, 0.0), noise: float = 2.0, step: float = 1e-3,
                 fixed: bool = False, readback_step: float = 0.1,
                 readback_noise: float = 0.0):
        self.head, self.scene = head, scene
        self.motor = Motor() if motor is None else motor
        self.period = as_scalar(period, "period", positive=True)
        self._rng = as_rng(rng)
        self._texture = skin_texture((960, 1280), rng=self._rng)
        self._pos = np.array(as_array(start, "start", shape=(2,)))
        self._goal = self._pos.copy()
        self._speed = np.zeros(2)
        self._now = 0.0
        self._commanded = -np.inf       # time of the last command
        self._pending = []              # (active time, setting)
        self._noise = noise
        self._step = step
        self.fixed = bool(fixed)
        self.readback_step = as_scalar(readback_step, "readback_step", nonnegative=True)
        self.readback_noise = as_scalar(readback_noise, "readback_noise", nonnegative=True)
        self.settings = []              # (time, pan, tilt) reached at every frame grabbed
        self.readbacks = []             # (time, pan, tilt) reported at every frame grabbed
        self._cast = {}                 # scene sample -> (centre (3,), clear (M,)): ray casts

    def _check_time(self, t, last: float) -> float:
        t = as_scalar(t, "t")
        if t < last - 1e-12:
            raise ValueError(f"t: expected a time at or after the head's clock ({last:.4f} s: "
                             f"its last command or frame), got {t}")
        return t

    def command(self, t: float, setting) -> None:
        """Send a setting (pan, tilt degrees) at time ``t`` (s, not before the last command
        or frame)."""
        t = self._check_time(t, max(self._now, self._commanded))
        self._commanded = t
        if self.fixed:
            return
        s = np.clip(np.asarray(setting, float), [self.head.pan_limits[0],
                    self.head.tilt_limits[0]], [self.head.pan_limits[1],
                                               self.head.tilt_limits[1]])
        self._pending.append((float(t) + self.motor.latency, s))

    def _run_to(self, t: float) -> None:
        rate = np.asarray(self.motor.max_rate, float)
        while self._now < t - 1e-12:
            dt = min(self._step, t - self._now)
            while self._pending and self._pending[0][0] <= self._now + 1e-12:
                self._goal = self._pending.pop(0)[1]
                self._speed = np.minimum(np.abs(self._goal - self._pos) / self.period, rate)
            self._pos += np.clip(self._goal - self._pos, -self._speed * dt, self._speed * dt)
            self._now += dt

    def reached(self, t: float) -> np.ndarray:
        """The setting the head is at, at time ``t`` (s, not before the head's clock),
        degrees (the truth, not what it reports)."""
        self._run_to(self._check_time(t, self._now))
        return self._pos.copy()

    def read_back(self, setting) -> np.ndarray:
        """What the encoder reports for the head at ``setting`` (2,) degrees: plus
        ``readback_noise``, rounded to ``readback_step``."""
        s = np.asarray(setting, float) + self._rng.normal(0.0, self.readback_noise, 2) \
            if self.readback_noise > 0 else np.array(setting, float)
        q = self.readback_step
        return np.round(s / q) * q if q > 0 else s

    def clear_of_head(self, t: float, centre) -> np.ndarray:
        """``(M,)`` bool: the face markers at time ``t`` (s) whose line of sight to the
        camera centre ``centre`` (3,) mm clears the head itself, within ``centre_tol``
        (class notes); all True with the scene's ``occlusion="normals"``."""
        scene = self.scene
        if scene.occlusion == "normals":
            return np.ones(scene.head.shape[1], dtype=bool)
        centre = np.asarray(centre, float)
        i = int(scene._index(t)[0])
        if i not in self._cast:
            ahead = scene._index(float(t) + self.period * np.arange(self.occlusion_batch))
            todo = np.unique([j for j in ahead if j not in self._cast])
            if self.fixed:              # it stays where it is
                centres = np.tile(self.head.camera_at(*self._pos).C, (len(todo), 1))
            else:
                world, _, _ = scene.face_at(scene.times[todo])
                towards = aim(self.head, world.mean(axis=1), current=self._pos, tol_px=2.0)
                _, centres = self.head.poses(towards.pan, towards.tilt)
            clear = scene.unhidden(scene.times[todo], centres[:, None])[:, 0]
            self._cast.update((j, (c, v)) for j, c, v in zip(todo.tolist(), centres, clear))
        if np.linalg.norm(self._cast[i][0] - centre) > self.centre_tol:
            self._cast[i] = (centre, scene.unhidden(scene.times[[i]], centre[None])[0, 0])
        return self._cast[i][1]

    def drawn(self, t: float, points, normals, centre) -> np.ndarray:
        """``(M,)`` bool: the face markers ``points``, ``normals`` ``(M, 3)`` at time ``t``
        that the scene's ``occlusion`` rule draws for a camera centre ``centre`` (3,) mm (the
        image bounds are not checked here)."""
        occ = self.scene.occlusion
        faces = visible(points, normals, centre) if occ != "surface" else True
        return faces & self.clear_of_head(t, centre)

    def grab(self, t: float):
        """The frame at time ``t``, taken at the angles reached: ``(image (H, W) uint8,
        setting read back (2,) degrees)``."""
        s = self.reached(t)
        world, normals, anchor = self.scene.face_at(t)
        drawn = self.drawn(t, world[0], normals[0], self.head.camera_at(*s).C)
        video = render_pantilt_video(self.head, s[None], world, normals, anchor,
                                     rng=self._rng, texture=self._texture, noise=self._noise,
                                     drawn=drawn[None])
        r = self.read_back(s)
        self.settings.append((float(t), *s))
        self.readbacks.append((float(t), *r))
        return video.images[0], r

    def true_settings(self, times) -> np.ndarray:
        """The angles the head was at ``(T, 2)``, degrees, in the frames it grabbed at
        ``times`` (s) — the truth behind the read-back, to score."""
        rec = np.array(self.settings).reshape(-1, 3)
        times = np.atleast_1d(np.asarray(times, float))
        if not len(rec):
            raise ValueError("times: the head has grabbed no frame yet")
        gap = np.abs(rec[None, :, 0] - times[:, None])
        i = gap.argmin(axis=1)
        if gap[np.arange(len(times)), i].max() > 1e-9:
            raise ValueError("times: expected times of frames the head grabbed")
        return rec[i, 1:].copy()

    def true_xy(self, t: float, setting) -> np.ndarray:
        """True image positions ``(M, 2)`` of the drawn markers at time ``t`` and a setting
        (NaN where not drawn) — the truth behind a frame, and what an operator clicks."""
        world, normals, _ = self.scene.face_at(t)
        cam = self.head.camera_at(*setting)
        p = cam.project(world[0], behind="nan")
        ok = self.drawn(t, world[0], normals[0], cam.C) & np.isfinite(p).all(axis=1) \
            & cam.in_image(p)
        return np.where(ok[:, None], p, np.nan)


def hand_labels(device: SimulatedHead, *, sigma_px: float = 0.5,
                rng: np.random.Generator | int | None = None):
    """An operator who identifies the markers in a head's frame by hand: a callable
    ``(t, setting) -> (M, 2)`` giving the drawn markers' positions in the frame grabbed at
    ``t`` with ``sigma_px`` of click noise (NaN for markers not seen) and no mislabel: the
    true projections at the angles the head was at (the image, not the read-back
    ``setting``), as an operator would click them (the thesis labels the markers once, by
    hand)."""
    rng = as_rng(rng)
    sigma_px = as_scalar(sigma_px, "sigma_px", nonnegative=True)

    def label(t, setting):
        xy = device.true_xy(t, device.true_settings(t)[0])
        return xy + rng.normal(0, sigma_px, xy.shape)

    return label


@dataclass(frozen=True, eq=False)
class CeilingVideos:
    """The ceiling cameras' rendered frames.

    Attributes
    ----------
    videos : list of LedVideo
        One per camera (``times``: true capture times).
    clocks : Clocks
    stamps : list of (T_k,) arrays
        Each frame's time stamp by its camera's clock, s.
    arrival : list of (T_k,) arrays
        When each frame reaches the estimator, s.
    """

    videos: list
    clocks: Clocks
    stamps: list
    arrival: list


def ceiling_videos(scene: MixedScaleScene, *, rng: np.random.Generator | int | None = None,
                   duration: float | None = None, monitor_flicker: float = 0.0,
                   reflections: float = 0.0) -> CeilingVideos:
    """Render every ceiling camera of ``scene`` at its own rate, phase and clock offset
    (:func:`lsmta.synth.widearea.make_clocks`) for ``duration`` s (default: the scene)."""
    rng = as_rng(rng)
    duration = scene.times[-1] if duration is None else as_scalar(duration, "duration",
                                                                   positive=True)
    clocks = make_clocks(len(scene.ceiling), rng=rng)
    videos, stamps, arrival = [], [], []
    for k, cam in enumerate(scene.ceiling):
        tt = clocks.phase[k] + np.arange(0, duration * clocks.rate[k]) / clocks.rate[k]
        tt = tt[tt < duration]
        v = render_led_video(scene.leds, cam, tt, rng=rng,
                             params=LedVideoParams(monitor_flicker=monitor_flicker,
                                                   reflections=reflections))
        videos.append(v)
        stamps.append(tt + clocks.offset[k])
        arrival.append(tt + clocks.latency[k]
                       + clocks.jitter * np.abs(rng.normal(size=len(tt))))
    return CeilingVideos(videos=videos, clocks=clocks, stamps=stamps, arrival=arrival)
