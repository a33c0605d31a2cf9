"""2-D tracks of several views joined into 3-D points by their paths
(lsmta.tracking.view_tracks), and the marker stage built on it (lsmta.systems.markers)."""

import numpy as np
import pytest

from lsmta.camera import Camera
from lsmta.real.own_recording import rigid_pair
from lsmta.systems import MarkerParams, Tracker2D, capture_markers
from lsmta.tracking.markers import find_blobs
from lsmta.tracking.view_tracks import (
    join_view_tracks,
    joined_positions,
    pair_residuals,
    residual_gate,
    triangulate_gated,
    triangulate_joined,
)


def _rig(n=3, radius=3000.0, spread_deg=40.0):
    cams = []
    for k, a in enumerate(np.radians(np.linspace(-spread_deg, spread_deg, n))):
        C = radius * np.array([np.sin(a), -np.cos(a), 0.0])
        z = -C / np.linalg.norm(C)
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        cams.append(Camera(f=1200.0, cx=400.0, cy=300.0, width=800, height=600, R=R, C=C,
                           name=f"v{k}"))
    return cams


def _scene(rng, cams, T=40, M=12, noise=0.2):
    """M points moving smoothly near the origin; each view's tracks in its own shuffled
    order, some lost part-way, plus tracks of nothing (random walks)."""
    t = np.arange(T)[:, None, None]
    X = rng.uniform(-400, 400, (1, M, 3)) + 150 * np.sin(0.15 * t + rng.uniform(0, 6, (1, M, 3)))
    views, orders = [], []
    for cam in cams:
        xy = cam.project(X.reshape(-1, 3)).reshape(T, M, 2) + rng.normal(0, noise, (T, M, 2))
        lost = rng.random(M) < 0.3
        xy[T // 2:, lost] = np.nan
        walk = np.cumsum(rng.normal(0, 2, (T, 4, 2)), axis=0) + rng.uniform(100, 500, (1, 4, 2))
        order = rng.permutation(M + 4)
        views.append(np.concatenate([xy, walk], axis=1)[:, order])
        orders.append(order)
    return X, views, orders


def test_join_by_paths_finds_every_point_and_nothing_else():
    rng = np.random.default_rng(3)
    cams = _rig()
    X, views, orders = _scene(rng, cams)
    J = join_view_tracks(cams, views, max_px=2.0)
    truth = np.stack([o[J.members[:, k]] for k, o in enumerate(orders)], axis=1)
    assert len(J) == X.shape[1]                           # every point once, no walk joined
    assert np.all((truth == truth[:, :1]) & (truth < X.shape[1]))
    assert np.all((J.members >= 0).sum(axis=1) == 3) and np.all(J.pair_px < 2.0)
    xyz, residual, n_views = triangulate_joined(cams, views, J.members)
    err = np.linalg.norm(xyz - X[:, truth[:, 0]], axis=2)
    assert np.nanmedian(err) < 2.0 and np.nanmax(residual) < 2.0
    assert np.isfinite(xyz).all(axis=2).mean() > 0.8 and n_views.max() == 3
    pos = joined_positions(views, J.members)
    assert pos.shape == (X.shape[0], 3, len(J), 2)
    assert np.array_equal(pos[:, 1, 0], views[1][:, J.members[0, 1]], equal_nan=True)


def test_pair_residuals_need_shared_frames_and_points_in_front():
    cams = _rig(2)
    a = cams[0].project(np.array([[0.0, 0.0, 0.0]]))[None]           # (1, 1, 2)
    b = cams[1].project(np.array([[0.0, 0.0, 0.0]]))[None]
    assert pair_residuals(cams[0], cams[1], a, b)[0, 0] < 1e-6
    gone = np.full_like(b, np.nan)
    assert np.isnan(pair_residuals(cams[0], cams[1], a, gone)[0, 0])
    # rays that meet only behind the cameras: a point in front of a, mirrored through b's
    # centre, is seen by b along the same line from behind
    X = np.array([[0.0, 0.0, 0.0]])
    behind = cams[1].project(2 * cams[1].C - X + 1e-3, behind="nan")
    assert np.isnan(behind).all() or np.isnan(pair_residuals(cams[0], cams[1], a,
                                                             behind[None])[0, 0])
    with pytest.raises(ValueError, match="xy: expected 2 track arrays"):
        join_view_tracks(cams, [a])
    with pytest.raises(ValueError, match="min_shared"):
        join_view_tracks(cams, [a, b], min_shared=2.0)
    with pytest.raises(ValueError, match="frames"):
        join_view_tracks(cams, [a, np.concatenate([b, b])])


def _dot_video(cams, X, size=(600, 800)):
    """Grey frames of bright Gaussian dots at the projections of X (T, M, 3)."""
    H, W = size
    yy, xx = np.mgrid[:H, :W]
    out = []
    for cam in cams:
        frames = np.full((len(X), H, W), 40.0)
        for t in range(len(X)):
            for x, y in cam.project(X[t]):
                r2 = (xx - x) ** 2 + (yy - y) ** 2
                frames[t] += 180 * np.exp(-r2 / (2 * 2.5 ** 2)) * (r2 < 200)
        out.append(np.clip(frames, 0, 255).astype(np.uint8))
    return out


@pytest.mark.parametrize("tracker", [Tracker2D.LSMTA, Tracker2D.KLT])
def test_capture_markers_on_rendered_dots(tracker):
    cams = _rig(2, spread_deg=20.0)
    t = np.arange(8)[:, None, None]
    grid = np.array([[x, y, z] for x, z in ((-250, -150), (0, -150), (250, -150),
                                            (-250, 150), (0, 150), (250, 150))
                     for y in (0.0,)])
    grid[:, 1] = [0, 120, -80, 60, -40, 100]          # some depth
    X = grid[None] + np.array([25.0, 0, 15.0]) * np.sin(0.3 * t + np.arange(6)[:, None])
    X[:, :2] = grid[:2]                                # two still dots
    stacks = _dot_video(cams, X)
    assert len(find_blobs(stacks[0][0], min_strength=20.0)) == 6
    params = MarkerParams(detector="blobs", tracker=tracker, max_px=1.0, min_motion_mm=20.0)
    m = capture_markers(stacks, cams, [s[0] for s in stacks], params=params)
    assert len(m.members) == 6 and m.moving.sum() == 4
    near = [np.min(np.linalg.norm(X[0] - p, axis=1)) for p in m.xyz[0]]
    assert max(near) < 3.0
    assert np.all(m.triangulated_share() == 1.0) and np.nanmax(m.residual) < 0.5
    # the residual gate: every residual far below its floor's bound (4 x 0.2 sigma), none out
    assert m.joins["residual_out"] == 0 and m.residual_bound_px == pytest.approx(2.0)
    # no frame rate: not low-pass filtered, and the capture says why
    assert m.xyz_filtered is None and m.filter["applied"] is False and m.xyz_written is m.xyz
    # with one: 8 frames are a run too short for the zero-lag filter (10): left raw, counted
    f = capture_markers(stacks, cams, [s[0] for s in stacks], params=params, fps=30.0)
    assert f.filter == {"applied": True, "cutoff_hz": 6.0, "order": 4, "fps": 30.0, "runs": 0,
                        "short_runs": 6, "raw_samples": 48}
    assert np.array_equal(f.xyz_filtered, f.xyz) and np.array_equal(f.xyz, m.xyz)
    with pytest.raises(ValueError, match=r"^params.filter_hz: .*Nyquist .* 5 Hz, got 6 Hz$"):
        capture_markers(stacks, cams, [s[0] for s in stacks], fps=10.0, params=params)
    with pytest.raises(ValueError, match="filter_order: expected an even"):
        MarkerParams(filter_order=3)
    with pytest.raises(ValueError, match="filter_hz"):
        MarkerParams(filter_hz=-6.0)
    with pytest.raises(ValueError, match="detector"):
        MarkerParams(detector="leds")
    with pytest.raises(ValueError, match="one per view"):
        capture_markers(stacks, cams[:1], [s[0] for s in stacks], params=params)


def test_capture_markers_under_a_build_reads_the_kept_result(monkeypatch, tmp_path):
    """Under ``lsmta reproduce`` a second call with the same arguments (notebook 21 after 17)
    reads the first call's result: every field equal, arrays bit for bit and as read-only;
    another tracker on the same markers (``like=``) is another call."""
    from dataclasses import fields

    from lsmta.build_cache import CACHE_ENV, READS_FILE
    cams = _rig(2, spread_deg=20.0)
    t = np.arange(6)[:, None, None]
    X = np.array([[-250.0, 0, -150], [0, 120, -150], [250, -80, 150]])[None] + np.array(
        [25.0, 0, 15.0]) * np.sin(0.3 * t + np.arange(3)[:, None])
    stacks = _dot_video(cams, X)
    params = MarkerParams(detector="blobs", max_px=1.0, min_motion_mm=20.0)
    monkeypatch.delenv(CACHE_ENV, raising=False)
    plain = capture_markers(stacks, cams, [s[0] for s in stacks], params=params)
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    first, again = (capture_markers(stacks, cams, [s[0] for s in stacks], params=params)
                    for _ in range(2))
    assert len(list((tmp_path / "marker_capture").glob("*.pkl"))) == 1
    assert len((tmp_path / "marker_capture" / READS_FILE).read_text().splitlines()) == 1
    for f in fields(plain):
        a, b, c = (getattr(m, f.name) for m in (plain, first, again))
        if isinstance(a, np.ndarray):
            assert a.dtype == c.dtype and np.array_equal(a, c, equal_nan=a.dtype.kind == "f")
            assert a.flags.writeable == c.flags.writeable, f.name
        elif f.name != "seconds":                  # the kept call's time, not this one's
            assert repr(a) == repr(b) == repr(c), f.name
    klt = MarkerParams(detector="blobs", max_px=1.0, min_motion_mm=20.0, tracker=Tracker2D.KLT)
    # like= the computed result (notebook 17), then like= the one read back (notebook 21)
    for like in (first, again):
        capture_markers(stacks, cams, [s[0] for s in stacks], params=klt, like=like)
    assert len(list((tmp_path / "marker_capture").glob("*.pkl"))) == 2


def test_rigid_pair_is_the_longest_held_pair_at_a_foot_span_in_the_same_views():
    rng = np.random.default_rng(2)
    T = 50
    walk = np.cumsum(rng.normal(0, 5, (T, 1, 3)), axis=0)
    heel, toe = np.array([0.0, 0, 50]), np.array([180.0, 0, 40])
    hip, knee = np.array([0.0, 0, 950]), np.array([20.0, 0, 500])
    X = walk + np.stack([hip, knee, heel, toe])[None] + rng.normal(0, 1.0, (T, 4, 3))
    X[::7, 1] = np.nan
    p = rigid_pair(X)
    assert p.markers == (2, 3) and abs(p.median_mm - 180.3) < 2 and p.std_mm < 2.5
    assert p.frames == T
    assert rigid_pair(X[:, :2]) is None                  # hip-knee: 450 mm, not a foot
    # a second foot pair, held in fewer frames, lower: the longer-held pair still wins
    Y = np.concatenate([X, X[:, 2:] - [0.0, 400, 30]], axis=1)     # the other foot
    Y[::3, 4] = np.nan
    assert rigid_pair(Y).markers == (2, 3)
    Y[::3, 2] = np.nan                                   # now equally held: the lower wins
    assert rigid_pair(Y).markers == (4, 5)
    views = np.array([[1, 1, 0]] * 5 + [[0, 1, 1]], bool)     # marker 5 seen from elsewhere
    assert rigid_pair(Y, views=views).markers == (2, 3)
    below = X.copy()
    below[:, 2:, 2] -= 500.0                             # below the floor: a wrong join
    assert rigid_pair(below) is None
    with pytest.raises(ValueError, match="views"):
        rigid_pair(Y, views=views[:3])


def test_camera_invertible_marks_where_the_lens_folds():
    cam = _rig(1)[0].replace(k1=0.3, k2=-0.5)           # folds some way outside the image
    grid = np.stack(np.meshgrid(np.linspace(-4000, 4800, 40), np.linspace(-4000, 4600, 40)),
                    axis=-1).reshape(-1, 2)
    ok = cam.invertible(grid)
    assert 0 < (~ok).sum() < len(grid) and ok[np.argmin(np.linalg.norm(grid - 400, axis=1))]
    cam.rays(grid[ok])                                    # every one it accepts is inverted
    for xy in grid[~ok][:: max(1, (~ok).sum() // 20)]:
        with pytest.raises(ValueError, match="cannot be inverted"):
            cam.rays(xy[None])
    assert np.all(_rig(1)[0].invertible(grid))           # no distortion: always
    # past the fold Newton's method also lands on roots on the far side of the centre
    # (radial factor < 0) that distort to the same point: not a ray of this lens
    bent = _rig(1)[0].replace(k1=-0.25)                   # r_d is at most 0.77 (r = 1.15)
    r_d = np.linspace(0.0, 2.0, 41)
    ok = bent.invertible(np.c_[bent.cx + bent.f * r_d, np.full_like(r_d, bent.cy)])
    assert ok[r_d < 0.76].all() and not ok[r_d > 0.78].any()


def _gap_scene(rng, T=40, M=6, noise=0.2):
    """Two views' tracks of M moving points (px noise ``noise``); in view 1 points 0 and 1
    are lost for frames 10-16 and picked up again at 17: point 0 on another dot (the
    projection of a point 40 mm above it, off the epipolar line), point 1 on its own."""
    cams = _rig(2, spread_deg=20.0)
    t = np.arange(T)[:, None, None]
    X = rng.uniform(-300, 300, (1, M, 3)) + 120 * np.sin(0.1 * t + rng.uniform(0, 6, (1, M, 3)))
    views = [c.project(X.reshape(-1, 3)).reshape(T, M, 2) + rng.normal(0, noise, (T, M, 2))
             for c in cams]
    views[1][10:17, :2] = np.nan
    other = cams[1].project((X[17:, 0] + [0.0, 0.0, 40.0]))
    views[1][17:, 0] = other + rng.normal(0, noise, other.shape)
    return cams, X, views


def test_residual_gate_drops_a_wrong_dot_after_a_gap_and_keeps_the_right_ones():
    cams, X, views = _gap_scene(np.random.default_rng(5))
    members = np.stack([np.arange(6)] * 2, axis=1)
    xyz, residual, _ = triangulate_joined(cams, views, members)
    assert np.nanmin(residual[17:, 0]) > 4.0                  # the wrong dot: many px off
    before = [v.copy() for v in views]
    g = triangulate_gated(cams, views, members)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(views, before))
    assert 1.0 < g.bound_px < 4.0                             # 4 sigma of 0.2 px noise, floored
    assert np.isnan(g.xyz[17:, 0]).all() and np.isnan(g.residual[17:, 0]).all()
    assert g.dropped == 40 - 17 and g.views_out == 0          # only those frames
    assert (g.n_views[17:, 0] == 0).all() and (g.n_views[:10] == 2).all()
    assert np.array_equal(g.xyz[:10, 0], xyz[:10, 0])         # the same track before the gap
    assert np.isfinite(g.xyz[17:, 1]).all()                   # a right dot after its gap
    assert np.array_equal(g.xyz[:, 1:], xyz[:, 1:], equal_nan=True)
    assert np.allclose(g.xyz[:, 2:], X[:, 2:], atol=5.0)
    none = triangulate_gated(cams, [v[:, 1:] for v in views], members[1:] - 1)
    assert none.dropped == 0 and np.array_equal(none.xyz, xyz[:, 1:], equal_nan=True)


def test_residual_gate_takes_out_a_wrong_run_of_a_view_even_where_it_is_near_the_line():
    """A third view's wrong run: the point is intersected from the other two; the run's
    frames near the epipolar line (within the bound) go with it."""
    rng = np.random.default_rng(6)
    cams = _rig(3, spread_deg=20.0)
    T, M = 40, 6
    t = np.arange(T)[:, None, None]
    X = rng.uniform(-300, 300, (1, M, 3)) + 120 * np.sin(0.1 * t + rng.uniform(0, 6, (1, M, 3)))
    views = [c.project(X.reshape(-1, 3)).reshape(T, M, 2) + rng.normal(0, 0.2, (T, M, 2))
             for c in cams]
    views[2][10:17, 0] = np.nan
    # after its gap view 2 is on another dot whose offset from the right one grows from 0
    off = np.zeros((T - 17, 3))
    off[:, 2] = np.linspace(0.0, 60.0, T - 17)
    views[2][17:, 0] = cams[2].project(X[17:, 0] + off)
    members = np.stack([np.arange(M)] * 3, axis=1)
    g = triangulate_gated(cams, views, members)
    assert np.isfinite(g.xyz[:, 0]).all() and (g.n_views[17:, 0] == 2).all()
    assert (g.n_views[:10, 0] == 3).all() and g.dropped == 0 and g.views_out == T - 17
    assert np.nanmax(g.residual) <= g.bound_px
    # from frame 17 the point is the right two views' intersection, before it all three's
    xyz, _, _ = triangulate_joined(cams, views, members)
    two, _, _ = triangulate_joined(cams[:2], views[:2], members[:, :2])
    assert np.allclose(g.xyz[17:, 0], two[17:, 0]) and np.array_equal(g.xyz[:10], xyz[:10])
    assert np.array_equal(g.xyz[:, 1:], xyz[:, 1:])            # the other points untouched


def test_residual_gate_scale_floor_and_bad_input():
    r = np.array([[0.5, 0.5, 0.5, 20.0], [0.5, np.nan, np.inf, 0.5]])
    keep, bound = residual_gate(r, k=4.0, floor_px=0.1)
    assert bound == pytest.approx(4 * 1.4826 * 0.5)
    assert keep.tolist() == [[True, True, True, False], [True, True, False, True]]
    keep, bound = residual_gate(r, k=4.0, floor_px=1.0)        # the floor rules
    assert bound == pytest.approx(4.0)
    keep, bound = residual_gate(np.full((3, 2), np.nan))
    assert keep.all() and np.isnan(bound)
    with pytest.raises(ValueError, match="k: "):
        residual_gate(r, k=0.0)
    with pytest.raises(ValueError, match="floor_px"):
        residual_gate(r, floor_px=-1.0)
    with pytest.raises(ValueError, match="residual: expected reprojection errors >= 0"):
        residual_gate(-r)
    with pytest.raises(ValueError, match="residual: expected an array of shape"):
        residual_gate(r[0])
    for bad in (0.0, -3.0, float("nan")):
        with pytest.raises(ValueError, match="residual_k"):
            MarkerParams(residual_k=bad)
    with pytest.raises(TypeError, match="residual_k: expected a number"):
        MarkerParams(residual_k=True)
    with pytest.raises(ValueError, match="residual_floor_px"):
        MarkerParams(residual_floor_px=-0.5)
    assert MarkerParams(sigma=1.25).residual_floor() == pytest.approx(0.25)
    assert MarkerParams(residual_floor_px=0.0).residual_floor() == 0.0
