"""Multi-camera calibration (lsmta.calibration): targets, bundle adjustment, virtual object."""

import numpy as np
import pytest

from lsmta.calibration import (
    Bar,
    BundleParams,
    bundle_adjust,
    relative_orientation_start,
    track_targets,
)
from lsmta.calibration.approximations import scaled
from lsmta.calibration.bundle import Projector, project_params
from lsmta.calibration.chain import chain_cameras, datum_from_distance, shared_points
from lsmta.calibration.virtual_object import (
    IMPROVED_ALTERNATION,
    AlternationParams,
    alternate,
    joint_adjustment,
    projection_error,
    resect,
    resect_all,
    triangulate_optimal,
)
from lsmta.evaluation.calibration import check_point_errors, heldout_bar_errors
from lsmta.synth.calibration import (
    bar_track,
    led_path,
    levelled_bar,
    long_room_rig,
    poor_guess,
    project_observations,
    render_bar_images,
    sweep_path,
)
from lsmta.synth.rigs import ring_rig, triplet_rig
from lsmta.triangulation import triangulate


def _bar_data(seed, n, sigma, length=800.0):
    rng = np.random.default_rng(seed)
    truth = triplet_rig(rng=rng)
    track = bar_track(n=n, rng=rng, length=length)
    xy = project_observations(truth, track.points.reshape(-1, 3), rng=rng, sigma_px=sigma)
    bar = Bar(np.arange(2 * n).reshape(-1, 2), length, 0.01)
    return rng, truth, track, xy, bar


@pytest.fixture(scope="module")
def noisy():
    # 0.01 px: about what the target measurement reaches in the rendered images
    rng, truth, track, xy, bar = _bar_data(3, 100, 0.01)
    cams0, X0 = relative_orientation_start(triplet_rig(), xy, bar=bar, pair=(0, 2))
    xy_in = xy.copy()
    res = bundle_adjust(cams0, xy, X0, bar=bar, sigma_px=0.01)
    assert np.array_equal(xy, xy_in)  # input untouched
    held = bar_track(n=30, rng=rng, half_size=(800.0, 560.0, 400.0))
    xy_h = project_observations(truth, held.points.reshape(-1, 3), rng=rng, sigma_px=0.01)
    return truth, res, heldout_bar_errors(res.cameras, xy_h, 800.0)


def test_targets_measured_to_subpixel_in_rendered_images():
    rng = np.random.default_rng(0)
    cam = triplet_rig(rng=rng)[1]
    track = bar_track(n=25, rng=rng)
    tracks = track_targets(render_bar_images(cam, track, rng=rng))
    truth = cam.project(track.points.reshape(-1, 3)).reshape(-1, 2, 2)
    assert tracks.n_lost == 0
    err = np.linalg.norm(tracks.xy - truth, axis=2)
    assert err.max() < 0.1          # labels consistent (A stays A) and sub-pixel
    assert np.sqrt(np.mean(err**2)) < 0.03


def test_noise_free_bar_recovers_the_interior_orientation():
    rng, truth, track, xy, bar = _bar_data(1, 80, 0.0)
    cams0, X0 = relative_orientation_start(triplet_rig(), xy, bar=bar, pair=(0, 2))
    res = bundle_adjust(cams0, xy, X0, bar=bar, sigma_px=0.05,
                        params=BundleParams(covariance=False))
    assert res.rms < 1e-4
    for est, true in zip(res.cameras, truth):
        assert abs(est.f - true.f) < 0.05
        assert abs(est.cx - true.cx) < 0.05 and abs(est.cy - true.cy) < 0.05
        assert abs(est.k1 - true.k1) < 1e-4
    # relative geometry: baselines to camera 0
    for k in (1, 2):
        b_est = np.linalg.norm(res.cameras[k].C - res.cameras[0].C)
        b_true = np.linalg.norm(truth[k].C - truth[0].C)
        assert abs(b_est - b_true) < 0.05
    assert np.nanmax(np.abs(res.bar_residuals)) < 1e-3


def test_noisy_residuals_match_the_noise_limit(noisy):
    truth, res, bar_err = noisy
    assert 0.9 < res.rms / res.noise_limit < 1.1
    assert 0.9 < res.sigma0 < 1.1
    assert np.all(np.isfinite(res.parameter_std))
    assert res.correlation.shape == (len(res.parameter_names),) * 2
    # parameter errors consistent with the predicted standard deviations
    z = [(getattr(e, n) - getattr(t, n)) / res.std(k, n)
         for k, (e, t) in enumerate(zip(res.cameras, truth)) for n in ("f", "k1", "p1", "b1")]
    assert np.max(np.abs(z)) < 4.5
    assert np.sqrt(np.mean(bar_err**2)) < 0.0005 * 800


@pytest.mark.slow
def test_outliers_rejected_and_reported():
    rng, truth, track, xy, bar = _bar_data(4, 40, 0.05)
    xy = xy.copy()
    xy[1, 10] += [6.0, -4.0]
    xy[2, 33] += [0.0, 8.0]
    cams0, X0 = relative_orientation_start(triplet_rig(), xy, bar=bar, pair=(0, 2))
    res = bundle_adjust(cams0, xy, X0, bar=bar, sigma_px=0.05,
                        params=BundleParams(reject_k=4.0, covariance=False))
    assert res.rejected[1, 10] and res.rejected[2, 33]
    assert res.n_rejected <= 4
    assert res.rms < 0.06


def test_nan_observations_dropped_and_counted():
    rng, truth, track, xy, bar = _bar_data(5, 60, 0.05)
    xy = xy.copy()
    xy[0, :7] = np.nan
    xy[1, 20, 0] = np.nan
    cams0, X0 = relative_orientation_start(triplet_rig(), xy, bar=bar, pair=(0, 2))
    res = bundle_adjust(cams0, xy, X0, bar=bar, sigma_px=0.05,
                        params=BundleParams(covariance=False))
    assert res.n_nan_dropped == 8
    assert np.isnan(res.residuals[0, :7]).all() and res.rms < 0.06


def test_bad_input_is_refused_with_clear_errors():
    rng, truth, track, xy, bar = _bar_data(6, 40, 0.05)
    cams0, X0 = relative_orientation_start(triplet_rig(), xy, bar=bar, pair=(0, 2))
    few = xy.copy()
    few[2, 5:] = np.nan
    with pytest.raises(ValueError, match="camera right sees 5 point"):
        bundle_adjust(cams0, few, X0, bar=bar)
    short = Bar(bar.pairs[:6], 800.0)
    with pytest.raises(ValueError, match="observations for .* unknowns"):
        bundle_adjust(cams0, xy[:, :12], X0[:12], bar=short)
    line = X0.copy()
    line[:, 1:] = 0.0
    line[:, 0] = np.arange(len(line)) * 100.0
    with pytest.raises(ValueError, match="degenerate bar track"):
        bundle_adjust(cams0, xy, line, bar=bar)
    with pytest.raises(ValueError, match="scale_camera"):
        bundle_adjust(cams0, xy, X0)
    with pytest.raises(ValueError, match="intrinsics: unknown"):
        bundle_adjust(cams0, xy, X0, bar=bar, intrinsics=("f", "k9"))
    with pytest.raises(ValueError, match="xy: expected an array of shape"):
        bundle_adjust(cams0, xy[:2], X0, bar=bar)
    with pytest.raises(ValueError, match="pair: expected two different"):
        relative_orientation_start(triplet_rig(), xy, bar=bar, pair=(1, 1))
    with pytest.raises(ValueError, match="pair: expected two different"):
        relative_orientation_start(triplet_rig(), xy, bar=bar, pair=(0, 3))
    with pytest.raises(ValueError, match="threshold_px"):
        relative_orientation_start(triplet_rig(), xy, bar=bar, threshold_px=0.0)
    with pytest.raises(ValueError, match="factor"):
        scaled(cams0, X0, -1.0)
    with pytest.raises(ValueError, match="n_targets"):
        track_targets(np.zeros((2, 8, 8)), n_targets=0)


def test_bundle_adjust_leaves_the_callers_arrays_alone():
    rng, truth, track, xy, bar = _bar_data(7, 40, 0.05)
    cams0, X0 = relative_orientation_start(triplet_rig(), xy, bar=bar, pair=(0, 2))
    xy_before, X0_before = xy.copy(), X0.copy()
    res = bundle_adjust(cams0, xy, X0, bar=bar, sigma_px=0.05,
                        params=BundleParams(covariance=False))
    assert np.array_equal(xy, xy_before, equal_nan=True)
    assert np.array_equal(X0, X0_before, equal_nan=True)
    assert not np.allclose(res.points, X0, equal_nan=True)


@pytest.mark.slow
def test_virtual_object_alternation_and_joint_adjustment_converge():
    # a calibration path long enough to cover the room: with fewer positions the joint
    # adjustment fits its own path to the noise but not an independent one (seed 2, 120
    # positions: 0.37 px on the path, 1.8 px on the check path)
    rng = np.random.default_rng(100)
    truth = ring_rig(n=8, rng=rng)
    path, check = led_path(n=150, rng=rng), led_path(n=80, rng=rng)
    xy = project_observations(truth, path, rng=rng, sigma_px=0.3)
    xy_c = project_observations(truth, check, rng=rng, sigma_px=0.3)
    floor = projection_error(truth, xy_c)
    guess = poor_guess(truth, rng=np.random.default_rng(0))
    alt = alternate(guess, xy, params=AlternationParams(n_iter=8), xy_check=xy_c)
    jnt = joint_adjustment(guess, xy, n_iter=15, xy_check=xy_c)
    assert alt.error[0] > 20 * floor
    assert jnt.error[-1] < 1.1 * floor
    # block-coordinate descent on the joint objective: the fit error never goes up; still
    # well above the floor after 8 (it creeps), where the joint adjustment is at it
    assert np.all(np.diff(alt.fit_error) <= 1e-9)
    assert alt.error[-1] < alt.error[0] / 10
    assert jnt.error[8] < alt.error[-1]


@pytest.mark.slow
def test_alternation_reaches_the_joint_optimum_on_a_small_ring():
    # six cameras, a milder guess: both blocks minimise the joint adjustment's objective,
    # so the alternation ends at the joint optimum; Davis's linear point step (3-D ray
    # distances, not image residuals) settles above it
    rng = np.random.default_rng(100)
    truth = ring_rig(n=6, rng=rng)
    xy = project_observations(truth, led_path(n=80, rng=rng), rng=rng, sigma_px=0.3)
    guess = poor_guess(truth, rng=np.random.default_rng(0), pose_mm=50.0, pose_deg=1.0, f_rel=0.02)
    jnt = joint_adjustment(guess, xy, n_iter=15)
    alt = alternate(guess, xy, params=AlternationParams(n_iter=16))
    lin = alternate(guess, xy, params=AlternationParams(n_iter=16, triangulation="linear"))
    opt = jnt.fit_error[-1]
    assert opt < projection_error(truth, xy)          # the optimum fits better than the truth
    assert np.all(np.diff(alt.fit_error) <= 1e-9)
    assert alt.fit_error[-1] < 1.01 * opt
    assert alt.iterations_to_value(opt, fit=True) <= 16
    # the linear variant has stopped moving, above the joint optimum
    assert abs(lin.fit_error[-1] / lin.fit_error[-3] - 1) < 1e-4
    assert lin.fit_error[-1] > 1.001 * opt
    with pytest.raises(ValueError, match="triangulation"):
        AlternationParams(n_iter=1, triangulation="dlt")


def _long_room(seed, n_path=500):
    rng = np.random.default_rng(seed)
    truth = long_room_rig(rng=rng, n_per_side=3, length=7000.0)
    path = sweep_path(n=n_path, rng=rng, passes=3, half_size=(3300.0, 1800.0, 700.0))
    check = sweep_path(n=120, rng=rng, half_size=(3300.0, 1800.0, 700.0))
    xy, xy_c = (project_observations(truth, p, rng=rng, sigma_px=0.3) for p in (path, check))
    return rng, truth, path, check, xy, xy_c


@pytest.mark.slow
def test_partial_overlap_calibration_against_the_truth():
    # six cameras in a 7 m room: each sees part of the path, some pairs nothing in common
    rng, truth, path, check, xy, xy_c = _long_room(3)
    shared = shared_points(xy)
    assert (shared == 0).any() and (np.diag(shared) < 0.7 * xy.shape[1]).all()
    guess = poor_guess(truth, rng=rng)
    chain = chain_cameras(guess, xy)
    assert sorted(chain.order.tolist()) == list(range(6)) and chain.parent[chain.order[0]] == -1
    marks = np.array([[-1500.0, 0.0, 1000.0], [1500.0, 0.0, 1000.0]])
    m_xy = project_observations(truth, marks, rng=rng, sigma_px=0.3)
    start = datum_from_distance(chain.cameras, m_xy, 3000.0, pose=guess[0])
    assert np.allclose(start[0].C, guess[0].C) and np.allclose(start[0].R, guess[0].R)
    X = triangulate(start, m_xy).points
    assert abs(np.linalg.norm(X[1] - X[0]) - 3000.0) < 1e-6
    floor = projection_error(truth, xy_c)
    jnt = joint_adjustment(start, xy, n_iter=40, xy_check=xy_c)
    imp = alternate(start, xy, params=IMPROVED_ALTERNATION, xy_check=xy_c)
    plain = alternate(start, xy, params=AlternationParams(n_iter=10), xy_check=xy_c)
    assert jnt.error[-1] < 1.1 * floor
    opt = jnt.fit_error[-1]
    assert imp.iterations_to_value(opt, fit=True) <= 50
    assert plain.fit_error[-1] > 1.05 * opt               # the paper's alternation creeps
    assert set(imp.steps[1:4]) == {"exterior sweep"} and "joint" in imp.steps
    # against the truth: the independent path in 3-D after a rigid alignment (the datum
    # is camera 0's tape-measured pose), and the scale from the known distance
    cal = datum_from_distance(jnt.cameras[-1], m_xy, 3000.0, pose=guess[0])
    err = check_point_errors(cal, xy_c, check)
    ref = check_point_errors(truth, xy_c, check)
    assert np.sqrt(np.nanmean(err**2)) < 2.5 * np.sqrt(np.nanmean(ref**2))
    assert np.sqrt(np.nanmean(err**2)) < 10.0


def test_chain_and_datum_refuse_bad_input():
    rng, truth, path, check, xy, xy_c = _long_room(4, n_path=200)
    cut = xy.copy()
    cut[5] = np.nan                                        # camera 5 sees nothing
    with pytest.raises(ValueError, match="cam05"):
        chain_cameras(truth, cut)
    with pytest.raises(ValueError, match="first"):
        chain_cameras(truth, xy, first=9)
    with pytest.raises(ValueError, match="xy"):
        chain_cameras(truth, xy[:, :, :1])
    m_xy = np.full((6, 2, 2), np.nan)
    with pytest.raises(ValueError, match="marks_xy"):
        datum_from_distance(truth, m_xy, 1000.0, pose=truth[0])
    with pytest.raises(ValueError, match="distance"):
        datum_from_distance(truth, m_xy, -1.0, pose=truth[0])
    with pytest.raises(TypeError, match="pose"):
        datum_from_distance(truth, m_xy, 1000.0, pose=None)
    for bad in ({"n_iter": -1}, {"joint_every": 0}, {"joint_steps": 0},
                {"intrinsics": ("focal",)}, {"joint_every": 2, "triangulation": "linear"}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            AlternationParams(**bad)
    with pytest.raises(TypeError, match="params"):
        alternate(truth, xy, params={"n_iter": 3})


def test_resection_of_all_cameras_at_once_recovers_the_truth():
    rng = np.random.default_rng(11)
    truth = ring_rig(n=5, rng=rng)
    X = led_path(n=120, rng=rng)
    xy = project_observations(truth, X)
    guess = poor_guess(truth, rng=rng, pose_mm=40.0, pose_deg=1.0, f_rel=0.01)
    guess = [g.replace(k1=t.k1, k2=t.k2) for g, t in zip(guess, truth)]
    xy_before = xy.copy()
    cams = resect_all(guess, X, xy, intrinsics=("f", "cx", "cy"))
    assert np.array_equal(xy, xy_before, equal_nan=True)
    for c, t in zip(cams, truth):
        assert np.linalg.norm(c.C - t.C) < 1e-3 and abs(c.f - t.f) < 1e-4
    one = resect(guess[2], X, xy[2], intrinsics=("f", "cx", "cy"))
    assert np.allclose(one.C, cams[2].C, atol=1e-6)
    blind = xy.copy()
    blind[1, 5:] = np.nan                                 # too few points: unchanged
    assert resect_all(guess, X, blind)[1] is guess[1]


def test_reprojection_optimal_triangulation():
    rng = np.random.default_rng(8)
    cams = ring_rig(n=5, rng=rng)
    X = led_path(n=60, rng=rng)
    exact = project_observations(cams, X)
    Xo = triangulate_optimal(cams, exact)
    ok = np.isfinite(Xo).all(axis=1)
    assert ok.sum() > 40
    assert np.abs(Xo[ok] - X[ok]).max() < 1e-6
    noisy = project_observations(cams, X, rng=rng, sigma_px=0.5)
    noisy[1:, 0] = np.nan                              # seen once: not intersected
    Xo = triangulate_optimal(cams, noisy)
    Xl = triangulate(cams, noisy, min_angle_deg=0.0).points
    assert np.isnan(Xo[0]).all()

    both = np.isfinite(Xo).all(axis=1)

    def cost(P):
        d = np.stack([c.project(P[both]) - noisy[k, both] for k, c in enumerate(cams)])
        return np.nansum(d**2, axis=(0, 2))

    assert np.all(cost(Xo) <= cost(Xl) + 1e-9)
    assert cost(Xo).sum() < 0.99 * cost(Xl).sum()
    assert projection_error(cams, noisy) < projection_error(cams, noisy, triangulation="linear")


def test_robust_loss_downweights_an_outlier():
    rng, truth, track, xy, bar = _bar_data(7, 30, 0.05)
    xy = xy.copy()
    xy[0, 5] += [10.0, 10.0]
    cams0, X0 = relative_orientation_start(triplet_rig(), xy, bar=bar, pair=(0, 2))
    res = bundle_adjust(cams0, xy, X0, bar=bar, sigma_px=0.05,
                        intrinsics=("f", "cx", "cy", "k1", "k2", "k3"),
                        params=BundleParams(loss="cauchy", f_scale=3.0, covariance=False))
    # the outlier keeps (nearly) its full error; the others stay at the noise level
    assert np.linalg.norm(res.residuals[0, 5]) > 10.0
    others = np.delete(res.residuals.reshape(-1, 2), 5, axis=0)
    assert np.sqrt(np.nanmean(others**2)) < 0.06


def test_levelled_bar():
    """The bar stood upright: ``frames_per_place`` still frames per place, its length kept,
    B on top, off vertical by about the level's error."""
    bar = levelled_bar(n_places=50, frames_per_place=2, rng=3, length=400.0, tilt_deg=0.5)
    assert bar.A.shape == (100, 3)
    assert np.array_equal(bar.A[0::2], bar.A[1::2])
    assert np.allclose(np.linalg.norm(bar.B - bar.A, axis=1), 400.0)
    d = (bar.B - bar.A)[::2] / 400.0
    tilt = np.degrees(np.arccos(d[:, 2]))
    assert np.all(d[:, 2] > 0) and 0.3 < np.sqrt(np.mean(tilt**2)) / np.sqrt(2) < 0.7
    assert np.allclose(levelled_bar(n_places=2, rng=0, tilt_deg=0.0).B[:, :2],
                       levelled_bar(n_places=2, rng=0, tilt_deg=0.0).A[:, :2])


@pytest.mark.parametrize("kwargs, match", [
    (dict(n_places=0), "n_places"), (dict(frames_per_place=1.5), "frames_per_place"),
    (dict(length=-1.0), "length"), (dict(tilt_deg=-0.1), "tilt_deg"),
    (dict(center=(0.0, 0.0)), "center"), (dict(half_size=(1.0, 2.0)), "half_size"),
])
def test_levelled_bar_bad_input(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        levelled_bar(**kwargs)


def _random_params(rng, K):
    return np.column_stack([rng.normal(0, 0.5, (K, 3)), rng.normal(0, 1000, (K, 3)),
                            rng.uniform(800, 1200, K), rng.normal(0, 1e-3, (K, 9))])


def test_project_params_broadcasts_like_the_numpy_form_and_refuses_bad_rows():
    rng = np.random.default_rng(0)
    P = _random_params(rng, 7)
    X = rng.normal(0, 500, (2000, 3))
    # one camera row for all points, a single (3,) point for one camera: broadcast
    one = project_params(P, X, rows=np.array([2]))
    assert one.shape == (2000, 2)
    assert np.array_equal(one, project_params(P[[2]], X))
    single = project_params(P[:1], X[0])
    assert single.shape == (1, 2)
    assert np.array_equal(single, project_params(P[:1], X[:1]))
    every = project_params(P, X[0])                   # one point seen by every camera
    assert np.array_equal(every, project_params(P, np.tile(X[0], (7, 1))))
    # rows out of range, or a length that does not match the points: refused
    with pytest.raises(IndexError):
        project_params(P, X[:3], rows=np.array([0, 1, 9]))
    with pytest.raises(ValueError, match="X"):
        project_params(P, X[:3], rows=np.array([0, 1]))
    project = Projector(P, np.array([0, 1, 2]))
    with pytest.raises(ValueError, match="Xc"):
        project.lens(np.ones((2, 3)))
    with pytest.raises(ValueError, match="X"):
        project.subset(np.array([0, 1]))(X[:3])
    with pytest.raises(IndexError):
        Projector(P, np.array([0, 7]))
