import cv2
import numpy as np
import pytest

from lsmta.camera import Camera


def random_camera(rng: np.random.Generator, *, shear: bool = False, name: str = "") -> Camera:
    """A camera with random pose, interior orientation and realistic distortion."""
    eye = rng.uniform([-3000, -6000, 500], [3000, -3000, 2500])
    target = rng.uniform([-300, -300, 700], [300, 300, 1300])
    return Camera.look_at(
        eye, target, f=rng.uniform(700, 1400), width=768, height=576,
        cx=383.5 + rng.normal(0, 5), cy=287.5 + rng.normal(0, 5), name=name,
    ).replace(
        k1=rng.uniform(-0.15, 0.05), k2=rng.uniform(-0.05, 0.15), k3=rng.uniform(-0.03, 0.03),
        p1=rng.normal(0, 5e-4), p2=rng.normal(0, 5e-4), b1=rng.normal(0, 5e-4),
        b2=rng.normal(0, 5e-4) if shear else 0.0,
    )


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


def smaller(cam: Camera, factor: int = 2) -> Camera:
    """The same camera with a coarser sensor: same field of view, fewer pixels (fast tests)."""
    return cam.replace(f=cam.f / factor, cx=(cam.cx + 0.5) / factor - 0.5,
                       cy=(cam.cy + 0.5) / factor - 0.5, width=cam.width // factor,
                       height=cam.height // factor)


def occlusion_pair(rng: np.random.Generator):
    """Background moving 3 px, a foreground (x >= 100 in the template) moving 9 px over it."""
    from scipy import ndimage

    def texture():
        t = ndimage.gaussian_filter(rng.normal(0, 1, (120, 220)), 1.5)
        return 128 + 40 * t / t.std()

    back, fore = texture(), texture()
    template = np.where(np.arange(220) >= 100, fore, back)
    xx = np.arange(220)
    search = np.where(xx >= 109, np.roll(fore, 9, axis=1), np.roll(back, 3, axis=1))
    noise = rng.normal(0, 1.0, (2, 120, 220))
    return template + noise[0], search + noise[1]


def rig_cameras(n=4, width=640, height=480, f=560.0):
    """``n`` cameras 3 m out on an arc of 70 degrees, 1.4 m up, looking at (0, 400, 700) mm,
    with a little radial distortion (tests/test_rig_refinement*.py)."""
    cams = []
    for a in np.deg2rad(np.linspace(-35, 35, n)):
        eye = np.array([3000 * np.sin(a), -3000 * np.cos(a), 1400.0])
        cams.append(Camera.look_at(eye, (0, 400, 700), f=f, width=width, height=height,
                                   name=f"cam{len(cams) + 1:02d}").replace(k1=-0.08, k2=0.05))
    return cams


def disturbed(cams, rng, *, px=6.0):
    """Cameras a few pixels off: centre moved, principal distance and point changed."""
    out = []
    for c in cams:
        out.append(c.replace(C=c.C + rng.normal(0, 15, 3), f=c.f * (1 + rng.normal(0, 0.008)),
                             cx=c.cx + rng.normal(0, px), cy=c.cy + rng.normal(0, px)))
    return out


def random_texture(rng, size=1024):
    """(size, size) float32 texture of blurred noise stretched to 0..255."""
    t = cv2.GaussianBlur(rng.uniform(0, 255, (size, size)), (0, 0), 2.0)
    t = cv2.normalize(t, None, 0, 255, cv2.NORM_MINMAX)
    return t.astype(np.float32)


def render_room(cam, floor_tex, wall_tex, shift):
    """A floor (z = 0) and a wall (y = 1500) with random texture, seen by ``cam``; the
    textures slide by ``shift`` px per frame (a moving scene: frames hold new points)."""
    xy = cam.pixel_grid().reshape(-1, 2)
    o, d = cam.rays(xy)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
        t_wall = np.where(d[:, 1] > 0, (1500 - o[:, 1]) / d[:, 1], np.inf)
    P = o + np.minimum(t_floor, t_wall)[:, None] * d
    on_wall = t_wall < t_floor
    u = (P[:, 0] / 4 + 512 + shift).reshape(cam.height, cam.width).astype(np.float32)
    v = (np.where(on_wall, P[:, 2], P[:, 1]) / 4 + 512).reshape(u.shape).astype(np.float32)
    floor, wall = (cv2.remap(tex, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
                   for tex in (floor_tex, wall_tex))
    out = np.where(on_wall.reshape(u.shape), wall, floor)
    return out.reshape(cam.height, cam.width).astype(np.uint8)


def tiny_studio_walk(*, scale: float, n_frames: int, frames=None, rom_per_phase: int = 0):
    """A tiny generated studio walk through the LSMTA system, as the walk tests use it (seed
    36, 60 bar positions, 12 seeds per surface; no arm model): ``(session, capture,
    system params)``. ``scale``, ``n_frames``, ``frames`` and ``rom_per_phase`` are what the
    tests choose differently."""
    from lsmta.evaluation import walk_system as ws
    from lsmta.systems import BodySystemParams, SurfaceParams, capture_walk

    params = ws.WalkSessionParams(rig="studio", scale=scale, n_bar=60, n_heldout=12,
                                  level_places=0, rom_per_phase=rom_per_phase)
    session = ws.walk_session(seed=36, n_frames=n_frames, params=params)
    system = BodySystemParams(density_every=2, reject_k=4.0, arm=None,
                              surface=SurfaceParams(n_seeds=12))
    cap = capture_walk(session.videos, session.bar_videos, session.bar_length,
                       session.nominal, fps=session.fps, progress=False, frames=frames,
                       params=system)
    return session, cap, system


def pytest_collection_modifyitems(config, items):
    """Every notebook run (nbmake) is slow: ``-m "not slow"`` leaves the notebooks out."""
    for item in items:
        if item.path.suffix == ".ipynb":
            item.add_marker(pytest.mark.slow)
