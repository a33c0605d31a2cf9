"""Time offsets between a rig's views adjusted with its cameras (refine_cameras with
``velocities``): a view sampling the scene a fraction of a frame late sees a moving point
displaced along its image velocity. Truth (the offsets, the 3-D motion) stays in the tests."""

import numpy as np
import pytest

from conftest import disturbed, rig_cameras
from lsmta.calibration import RefineParams, refine_cameras


def moving_rig(rng, offsets, *, n=800, speed_mm=30.0):
    """Tie points of a generated rig, half of them moving (``speed_mm`` per frame, each
    coordinate), each view sampling them ``offsets[k]`` frames late; their image velocities
    (central difference of the projections over one frame, with 0.1 px noise, 0 for the
    still ones as a user's flow would give). Returns the true and the disturbed cameras,
    the (K, n, 2) positions with 0.3 px noise and the velocities."""
    cams = rig_cameras()
    X = rng.uniform([-1200, -200, 0], [1200, 1200, 1800], (n, 3))
    V = np.zeros((n, 3))
    moving = rng.uniform(size=n) < 0.5
    V[moving] = rng.normal(0, speed_mm, (int(moving.sum()), 3))
    xy = np.stack([c.project(X + V * d) for c, d in zip(cams, offsets)])
    vel = np.stack([c.project(X + V * (d + 0.5)) - c.project(X + V * (d - 0.5))
                    for c, d in zip(cams, offsets)])
    xy += rng.normal(0, 0.3, xy.shape)
    vel += np.where(moving[None, :, None], rng.normal(0, 0.1, vel.shape), 0.0)
    for k, c in enumerate(cams):
        xy[k, ~c.in_image(xy[k]) | (rng.uniform(size=n) < 0.3)] = np.nan
    vel[np.isnan(xy)] = np.nan
    return cams, disturbed(cams, rng), xy, vel


def test_time_offsets_are_recovered_and_residuals_come_back_to_the_noise(rng):
    truth = np.array([0.0, 0.3, -0.2, 0.5])                    # frames, the first the datum
    _, given, xy, vel = moving_rig(rng, truth)
    keep_xy, keep_vel = xy.copy(), vel.copy()
    plain = refine_cameras(given, xy)
    timed = refine_cameras(given, xy, velocities=vel)
    assert np.array_equal(xy, keep_xy, equal_nan=True)
    assert np.array_equal(vel, keep_vel, equal_nan=True)
    assert plain.time_offsets is None and not plain.offsets_freed.any()
    assert timed.offsets_freed.tolist() == [False, True, True, True]
    assert np.abs(timed.time_offsets - truth).max() < 0.03, timed.time_offsets
    assert np.isnan(timed.offset_z[0]) and (np.abs(timed.offset_z[1:]) > 3).all()
    # 0.3 px per coordinate: a 2-D median of about 0.35 px, less the adjusted share
    after = timed.median_residual()
    assert (after < 0.3).all(), after
    # the moving points' residuals without the offsets are well above the noise
    moving = (np.nan_to_num(vel) != 0).any(axis=2)
    with_, without = (np.nanmedian(np.where(moving & r.used, np.linalg.norm(r.residuals, axis=2),
                                            np.nan), axis=1) for r in (timed, plain))
    assert (with_ < 0.35).all() and (without > 2 * with_).all(), (with_, without)


def test_without_offsets_nothing_is_freed_and_nothing_changes(rng):
    _, given, xy, vel = moving_rig(rng, np.zeros(4))
    plain = refine_cameras(given, xy)
    timed = refine_cameras(given, xy, velocities=vel)
    assert not timed.offsets_freed.any() and (timed.time_offsets == 0).all()
    assert (np.abs(timed.offset_z[1:]) < RefineParams().offset_z).all(), timed.offset_z
    for a, b in zip(plain.cameras, timed.cameras):
        assert np.array_equal(a.R, b.R) and np.array_equal(a.C, b.C)
        assert (a.f, a.cx, a.cy, a.k1, a.k2) == (b.f, b.cx, b.cy, b.k1, b.k2)
    assert np.array_equal(plain.residuals, timed.residuals, equal_nan=True)
    assert plain.freed == timed.freed


def test_bad_velocities_and_offset_settings_are_refused(rng):
    _, given, xy, vel = moving_rig(rng, np.zeros(4), n=200)
    with pytest.raises(ValueError, match="velocities"):
        refine_cameras(given, xy, velocities=vel[:, :10])
    bad = vel.copy()
    bad[1, 3] = np.inf
    with pytest.raises(ValueError, match="velocities"):
        refine_cameras(given, xy, velocities=bad)
    with pytest.raises(ValueError, match="offset_z"):
        RefineParams(offset_z=0)
    with pytest.raises(ValueError, match="sigma_offset"):
        RefineParams(sigma_offset=-1.0)
