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


def pytest_collection_modifyitems(config, items):
    """Every notebook run (nbmake) is slow: ``-m "not slow"`` leaves the notebooks out."""
    for item in items:
        if item.path.suffix == ".ipynb":
            item.add_marker(pytest.mark.slow)
