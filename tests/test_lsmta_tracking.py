"""LSMTA tracking (D'Apuzzo 2000, §2.3): tracker, density check, trajectories, filters, KLT."""

import numba
import numpy as np
import pytest
from scipy import ndimage

from lsmta.evaluation import tracking as et
from lsmta.matching import SplineImage
from lsmta.synth import triplet_rig
from lsmta.tracking import (
    Reason,
    TrackerParams,
    TrackStatus,
    Trajectories,
    drift_deviation,
    drift_filter,
    threshold_filter,
    track_klt,
    track_points,
    track_step,
    trajectories_from_tracks,
    uniformity_filter,
)
from lsmta.tracking.density import sparse_candidates
from lsmta.tracking.templates import match_translation, sample_templates
from lsmta.triangulation import triangulate

numba.set_num_threads(1)


def _texture(rng, shape=(120, 160), sigma=1.5):
    img = ndimage.gaussian_filter(rng.normal(size=shape), sigma)
    return 128 + 60 * img / img.std()


OFFSET = 0.2   # camera k sees the texture shifted by 0.2 k px in x and y


def _shifted_sequence(rng, velocities, n_frames=5, K=3):
    """K cameras see one texture, each translating at its own constant velocity (px/frame)."""
    base = _texture(rng)
    seqs = []
    for k in range(K):
        frames = [ndimage.shift(base, (OFFSET * k + velocities[k][1] * t,
                                       OFFSET * k + velocities[k][0] * t), order=3,
                                mode="reflect") for t in range(n_frames)]
        seqs.append(np.stack(frames))
    return np.stack(seqs)


@pytest.fixture(scope="module")
def translation():
    rng = np.random.default_rng(5)
    vel = np.array([[1.3, -0.7], [0.4, 0.9], [-1.1, 0.25]])
    images = _shifted_sequence(rng, vel)
    g = np.stack(np.meshgrid(np.arange(40, 121, 10.0), np.arange(35, 86, 10.0)), -1).reshape(-1, 2)
    xy0 = np.stack([g + OFFSET * k for k in range(3)])
    return images, xy0, vel


def test_tracks_a_known_translation(translation):
    images, xy0, vel = translation
    before = (images.copy(), xy0.copy())
    tr = track_points(images, xy0)
    T = images.shape[1]
    truth = xy0[None] + np.arange(T)[:, None, None, None] * vel[None, :, None, :]
    assert (tr.status == TrackStatus.ALIVE).mean() > 0.9
    ok = tr.status == TrackStatus.ALIVE
    err = np.linalg.norm(tr.xy[:, :, ok] - truth[:, :, ok], axis=3)
    assert np.median(err) < 0.02 and err.max() < 0.1
    assert np.array_equal(images, before[0]) and np.array_equal(xy0, before[1])


def test_two_d_mode_and_klt_on_a_translation(translation):
    images, xy0, vel = translation
    truth = xy0[0][None] + np.arange(images.shape[1])[:, None, None] * vel[0]
    tr = track_points(images[:1], xy0[:1])
    assert tr.xy.shape[1] == 1
    assert np.nanmax(np.linalg.norm(tr.xy[:, 0] - truth, axis=2)) < 0.1
    kl = track_klt(images, xy0)
    e = np.linalg.norm(kl.xy[:, 0] - truth, axis=2)
    assert np.isfinite(e).mean() > 0.9 and np.nanmedian(e) < 0.1


def test_track_step_is_the_trackers_first_step(translation):
    images, xy0, vel = translation
    tr = track_points(images[:, :2], xy0, initial_velocity=np.broadcast_to(vel[:, None],
                                                                              xy0.shape))
    p = TrackerParams()
    st = track_step(images[:, 0], images[:, 1], xy0, xy0 + vel[:, None], p.radius, params=p)
    # against the truth: the step moves (almost) every point by the known translation
    assert st.ok.mean() > 0.9
    err = np.linalg.norm(st.xy[:, st.ok] - (xy0 + vel[:, None])[:, st.ok], axis=2)
    assert np.median(err) < 0.02 and err.max() < 0.1
    # from a good prediction the anchored LSM needs no correlation search
    assert st.direct[:, st.ok].all() and np.isnan(st.correlation_xy[:, st.ok]).all()
    assert np.array_equal(st.ok, tr.alive[1])
    assert np.allclose(st.xy[:, st.ok], tr.xy[1][:, st.ok])
    assert np.isnan(st.spatial_xy[p.template]).all()
    assert np.isfinite(st.spatial_xy[0, st.ok]).all() and st.temporal_A.shape[-2:] == (2, 2)
    # without the direct match: the correlation peak (to a pixel or so), then the LSM
    st2 = track_step(images[:, 0], images[:, 1], xy0, xy0, 4, params=p, direct=False)
    assert st2.ok.mean() > 0.9 and not st2.direct.any()
    c_err = np.linalg.norm(st2.correlation_xy[:, st2.ok] - (xy0 + vel[:, None])[:, st2.ok],
                           axis=2)
    assert c_err.max() <= 1.0
    assert np.allclose(st2.xy[:, st2.ok], st.xy[:, st2.ok], atol=0.02)
    with pytest.raises(ValueError, match="next_frame"):
        track_step(images[:, 0], images[:2, 1], xy0, xy0, 4)
    with pytest.raises(ValueError, match="radius"):
        track_step(images[:, 0], images[:, 1], xy0, xy0, 0)
    # the caller's interpolants of the same images: the same step, to the bit
    own = ([SplineImage(im) for im in images[:, 0]], [SplineImage(im) for im in images[:, 1]])
    st3 = track_step(images[:, 0], images[:, 1], xy0, xy0 + vel[:, None], p.radius, params=p,
                     splines=own)
    for name, value in vars(st).items():
        np.testing.assert_array_equal(getattr(st3, name), value)    # NaNs in the same places
    for bad in ((own[0][:2], own[1]), own[0], (own[0],), ([im for im in images[:, 0]], own[1])):
        with pytest.raises(ValueError, match="splines"):
            track_step(images[:, 0], images[:, 1], xy0, xy0, 4, splines=bad)


def _occluded_sequence(rng, frames, n_frames=9, K=3, vel=(0.6, -0.3)):
    """The translation of ``_shifted_sequence`` with a new texture over the first point's
    region in camera 0 during ``frames``."""
    images = _shifted_sequence(rng, np.tile(vel, (K, 1)), n_frames=n_frames, K=K)
    occluder = _texture(rng, (40, 40), sigma=0.7)
    for t in frames:
        images[0, t, 20:60, 20:60] = occluder
    xy0 = np.stack([np.array([[40.0, 40.0], [100.0, 70.0]]) + OFFSET * k for k in range(K)])
    truth = xy0[None] + np.arange(n_frames)[:, None, None, None] * np.array(vel)
    return images, xy0, truth


def test_an_occluded_point_is_recovered_where_its_trajectory_predicts_it():
    images, xy0, truth = _occluded_sequence(np.random.default_rng(8), frames=(4, 5, 6))
    tr = track_points(images, xy0, params=TrackerParams(max_gap=4))
    assert tr.status[0] == TrackStatus.ALIVE and tr.end[0] == 8
    assert np.isnan(tr.xy[4:7, :, 0]).all() and np.isfinite(tr.xy[7:, :, 0]).all()
    assert tr.recovered[7, 0] and tr.recovered.sum() == 1
    err = np.linalg.norm(tr.xy[7:, :, 0] - truth[7:, :, 0], axis=2)
    assert err.max() < 0.05
    assert tr.status[1] == TrackStatus.ALIVE and not tr.recovered[:, 1].any()


def test_a_point_missing_for_longer_than_max_gap_ends():
    images, xy0, _ = _occluded_sequence(np.random.default_rng(8), frames=(4, 5, 6))
    tr = track_points(images, xy0, params=TrackerParams(max_gap=2))
    assert tr.status[0] == TrackStatus.LOST and tr.end[0] == 3
    assert np.isnan(tr.xy[4:, :, 0]).all() and np.isfinite(tr.xy[:4, :, 0]).all()
    tr = track_points(images[:, :6], xy0, params=TrackerParams(max_gap=4))
    assert tr.status[0] == TrackStatus.MISSING and tr.end[0] == 3


def test_the_pyramid_follows_a_jerky_motion_beyond_the_single_level_search():
    """Back-and-forth steps of about 13 px: the linear prediction is off by about 26 px,
    beyond the retry box and the single-level LSM; the coarse-to-fine prediction finds it."""
    rng = np.random.default_rng(11)
    base = sum(ndimage.gaussian_filter(rng.normal(size=(240, 320)), s) * s ** 0.5
               for s in (1.5, 3.0, 6.0, 12.0))
    base = 128 + 50 * base / base.std()
    steps = np.array([[0, 0], [12, 5], [-13, -4], [12, 6], [-12, -5]], float)
    pos = np.cumsum(steps, axis=0)
    frames = np.stack([ndimage.shift(base, (y, x), order=3, mode="reflect") for x, y in pos])
    g = np.stack(np.meshgrid(np.arange(80, 241, 20.0), np.arange(70, 171, 20.0)),
                 -1).reshape(-1, 2)
    alive = {}
    for levels in (0, 3):
        tr = track_points(frames[None], g[None], params=TrackerParams(pyramid_levels=levels))
        ok = tr.status == TrackStatus.ALIVE
        err = np.linalg.norm(tr.xy[:, 0][:, ok] - (g[ok][None] + pos[:, None]), axis=2)
        assert np.nanmax(err, initial=0.0) < 0.01          # no false track either way
        alive[levels] = ok.sum()
    assert alive[0] < 0.1 * len(g) and alive[3] > 0.6 * len(g)


def test_return_to_first_brings_a_track_found_by_its_fallback_back_to_its_first_template():
    """A jerk of 3 px on a fine texture: from the linear prediction the first template does
    not converge, the fallback template is found by the correlation search. By default
    the track holds the fallback in those frames; with ``return_to_first`` its first
    template, matched again from the fallback's position, passes, and every frame is
    the first template's (``anchor`` 0), at the same positions."""
    rng = np.random.default_rng(3)
    base = ndimage.gaussian_filter(rng.normal(size=(120, 160)), 1.0)
    base = 128 + 50 * base / base.std()
    steps = np.array([[0, 0], [1, 0.5], [1, 0.5], [1, 0.5], [4, 0.5], [1, 0.5], [1, 0.5]])
    pos = np.cumsum(steps, axis=0)
    frames = np.stack([ndimage.shift(base, (y, x), order=3, mode="reflect") for x, y in pos])
    g = np.stack(np.meshgrid(np.arange(30, 111, 16.0), np.arange(30, 91, 16.0)),
                 -1).reshape(-1, 2)
    on_fallback = {}
    for back in (False, True):
        tr = track_points(frames[None], g[None], params=TrackerParams(return_to_first=back))
        assert (tr.status == TrackStatus.ALIVE).all()
        err = np.linalg.norm(tr.xy[:, 0] - (g[None] + pos[:, None]), axis=2)
        assert err.max() < 0.02
        on_fallback[back] = int((tr.anchor > 0).sum())
    assert on_fallback[False] > len(g) and on_fallback[True] == 0
    assert TrackerParams().return_to_first is False
    with pytest.raises(ValueError, match="params.return_to_first"):
        track_points(frames[None], g[None], params=TrackerParams(return_to_first=1))


def test_match_translation_recovers_a_shift_and_a_grey_offset():
    rng = np.random.default_rng(2)
    img = ndimage.gaussian_filter(rng.normal(size=(80, 80)), 2.0)
    img = 100 + 40 * img / img.std()
    moved = ndimage.shift(img, (-1.7, 2.4), order=3, mode="reflect") + 15.0
    tm = sample_templates(SplineImage(img), np.array([[40.0, 40.0]]), 11)
    xy, conv = match_translation(tm, [0], SplineImage(moved), np.array([[40.0, 40.0]]))
    assert conv[0] and np.abs(xy[0] - [42.4, 38.3]).max() < 0.02
    with pytest.raises(ValueError, match="rows"):
        match_translation(tm, [1], SplineImage(moved), np.array([[40.0, 40.0]]))
    with pytest.raises(ValueError, match="start_xy"):
        match_translation(tm, [0], SplineImage(moved), np.zeros((2, 2)))
    # the light store (no normal matrices) gives the same match
    light = sample_templates(SplineImage(img), np.array([[40.0, 40.0]]), 11, normals=False)
    assert np.isnan(light.update).all() and np.isnan(light.q_xy).all()
    xy2, conv2 = match_translation(light, [0], SplineImage(moved), np.array([[40.0, 40.0]]))
    assert conv2[0] and np.array_equal(xy2, xy)
    # a row that does not converge returns its last iterate
    xy1, conv1 = match_translation(tm, [0], SplineImage(moved), np.array([[40.0, 40.0]]),
                                   max_iter=1)
    assert not conv1[0] and np.abs(xy1[0] - [40.0, 40.0]).max() > 0.5


@pytest.mark.parametrize("kwargs, match", [
    (dict(rows=[0.9]), "rows"), (dict(rows=[True]), "rows"),
    (dict(max_iter=0), "max_iter"), (dict(max_iter=2.5), "max_iter"),
    (dict(tol=0.0), "tol"), (dict(tol=-0.1), "tol"),
    (dict(max_displacement=0.0), "max_displacement"),
    (dict(max_displacement=np.nan), "max_displacement"),
])
def test_match_translation_refuses_bad_arguments(kwargs, match):
    img = 100 + 40 * ndimage.gaussian_filter(np.random.default_rng(3).normal(size=(60, 60)), 2)
    tm = sample_templates(SplineImage(img), np.array([[30.0, 30.0]]), 11)
    args = dict(rows=[0], max_iter=30, tol=0.01, max_displacement=None) | kwargs
    rows = args.pop("rows")
    with pytest.raises(ValueError, match=match):
        match_translation(tm, rows, SplineImage(img), np.array([[30.0, 30.0]]), **args)
    with pytest.raises(TypeError, match="templates"):
        match_translation(tm.values, [0], SplineImage(img), np.array([[30.0, 30.0]]))
    with pytest.raises(TypeError, match="search"):
        match_translation(tm, [0], img, np.array([[30.0, 30.0]]))


def test_search_templates_refuses_a_colour_frame():
    from lsmta.tracking.templates import search_templates

    img = 100 + 40 * ndimage.gaussian_filter(np.random.default_rng(3).normal(size=(60, 60)), 2)
    tm = sample_templates(SplineImage(img), np.array([[30.0, 30.0]]), 11)
    xy = search_templates(tm, [0], img, np.array([[30.0, 30.0]]), 3)
    assert np.abs(xy - 30.0).max() < 0.05
    with pytest.raises(ValueError, match="search: expected a 2-D grey image, got a colour"):
        search_templates(tm, [0], np.dstack([img] * 3), np.array([[30.0, 30.0]]), 3)


def _appearance_sequence(rng, n_frames=60, noise=6.0):
    """A texture translating by (0.37, -0.23) px a frame while it blurs (to 0.6 px) and
    fades (to 80 % contrast) slowly: its appearance changes, its position is known."""
    base = _texture(rng, (150, 170), sigma=1.5)
    frames = []
    for t in range(n_frames):
        img = ndimage.shift(base, (-0.23 * t, 0.37 * t), order=3, mode="reflect")
        img = ndimage.gaussian_filter(img, 0.6 * t / n_frames)
        img = 128 + (1 - 0.2 * t / n_frames) * (img - 128)
        frames.append(img + rng.normal(scale=noise, size=img.shape))
    g = np.stack(np.meshgrid(np.arange(40, 111, 14.0), np.arange(40, 101, 14.0)), -1)
    xy0 = g.reshape(1, -1, 2)
    truth = xy0[0][None] + np.arange(n_frames)[:, None, None] * np.array([0.37, -0.23])
    return np.stack(frames)[None], xy0, truth


def test_anchored_templates_do_not_drift_where_frame_to_frame_tracking_does():
    images, xy0, truth = _appearance_sequence(np.random.default_rng(11))
    errors = {}
    for anchor in ("first", "previous"):
        tr = track_points(images, xy0, params=TrackerParams(anchor=anchor))
        assert tr.alive[-1].mean() > 0.9
        errors[anchor] = np.linalg.norm(tr.xy[:, 0] - truth, axis=2)         # (T, N)
    first = {a: float(np.nanmedian(e[1:11])) for a, e in errors.items()}
    last = {a: float(np.nanmedian(e[-10:])) for a, e in errors.items()}
    # anchored: bounded by the single-match error (which grows a little as the texture
    # blurs and fades); frame to frame: the errors of 60 matches add up
    assert last["first"] < 0.08 and last["first"] < 2 * first["first"]
    assert last["previous"] > 4 * first["previous"]
    assert last["previous"] > 3 * last["first"]


def test_a_flat_start_is_not_started(translation):
    images, xy0, _ = translation
    flat = images.copy()
    flat[:, 0, 30:50, 30:50] = 100.0                  # no texture around the first point
    xy = xy0.copy()
    xy[:, 0] = [40.0, 40.0]
    tr = track_points(flat, xy)
    assert tr.status[0] == TrackStatus.NOT_STARTED


def test_incomplete_start_point_is_not_tracked(translation):
    images, xy0, _ = translation
    xy = xy0.copy()
    xy[2, 0] = np.nan
    tr = track_points(images, xy)
    assert tr.status[0] == TrackStatus.NOT_STARTED and np.isnan(tr.xy[:, :, 0]).all()


def test_bad_input(translation):
    images, xy0, _ = translation
    with pytest.raises(ValueError, match="unequal lengths"):
        track_points([images[0], images[1], images[2, :-1]], xy0)
    with pytest.raises(ValueError, match="unequal sizes"):
        track_points([images[0], images[1], images[2][:, :-2]], xy0)
    with pytest.raises(ValueError, match="no point matched"):
        track_points(images, np.full_like(xy0, np.nan))
    with pytest.raises(ValueError, match="initial_xy"):
        track_points(images, xy0[:2])
    with pytest.raises(ValueError, match="density_every"):
        track_points(images, xy0, params=TrackerParams(density_every=0))
    with pytest.raises(ValueError, match="radius"):
        track_points(images, xy0, params=TrackerParams(radius=0))
    with pytest.raises(ValueError, match="no point matched"):
        track_klt(images, np.full_like(xy0, np.nan))
    for bad in (TrackerParams(neighbours=0), TrackerParams(neighbours=2.5)):
        with pytest.raises(ValueError, match="params.neighbours"):
            track_points(images, xy0, params=bad)
    for v in (0.0, -1.0, np.nan):
        with pytest.raises(ValueError, match="params.max_disagreement"):
            track_points(images, xy0, params=TrackerParams(max_disagreement=v))
    with pytest.raises(ValueError, match="params.min_distance"):
        track_points(images, xy0, params=TrackerParams(min_distance=-1.0))
    for name, bad in (("anchor", "last"), ("max_gap", -1), ("max_gap", 1.5),
                      ("max_reprojection", 0.0), ("reanchor_sigma0", 1.0),
                      ("reanchor_distortion", -0.1), ("max_iter", 0), ("patch", 8),
                      ("pyramid_levels", -1), ("pyramid_levels", 1.5)):
        with pytest.raises(ValueError, match=f"params.{name}"):
            track_points(images, xy0, params=TrackerParams(**{name: bad}))
    cams = triplet_rig()
    for bad in (cams[:2], [None] * 3):
        with pytest.raises(ValueError, match="cameras"):
            track_points(images, xy0, cameras=bad)
    with pytest.raises(ValueError, match="cameras"):
        track_points(images[:1], xy0[:1], cameras=cams[:1])
    for w in (1, 4, 20, 3.5, True):
        with pytest.raises(ValueError, match="window"):
            track_klt(images, xy0, window=w)
    for lv in (-1, 1.5):
        with pytest.raises(ValueError, match="levels"):
            track_klt(images, xy0, levels=lv)
    for fb in (0.0, -0.5):
        with pytest.raises(ValueError, match="fb_threshold"):
            track_klt(images, xy0, fb_threshold=fb)
    with pytest.raises(ValueError, match="fps"):
        Trajectories(np.zeros((3, 2, 3)), 0.0)
    tr = track_points(images[:, :2], xy0)
    with pytest.raises(ValueError, match="fps"):
        trajectories_from_tracks(triplet_rig(), tr, 0)


def test_density_check_fills_sparse_cells_only():
    tracked = np.array([[5.0, 5.0], [8.0, 9.0], [20.0, 5.0]])
    cand = np.array([[6.0, 6.0],    # too close to a track
                     [12.0, 12.0],  # cell (0, 0) already holds 2 tracks
                     [25.0, 5.0],   # cell (1, 0) holds 1 -> gets one
                     [28.0, 12.0],  # ... but only one
                     [40.0, 40.0],  # empty cell -> two
                     [44.0, 44.0], [46.0, 42.0]])
    add = sparse_candidates(tracked, cand, cell=16, min_per_cell=2, min_distance=3)
    assert sorted(add.tolist()) == [2, 4, 5]


def test_surface_tracking_adds_new_points(translation):
    images, xy0, vel = translation
    T = images.shape[1]
    new = {}
    for t in range(T):
        p = np.array([[130.0, 95.0], [135.0, 60.0]])      # right part, no start points
        new[t] = np.stack([p + OFFSET * k + t * vel[k] for k in range(3)])
    tr = track_points(images, xy0[:, :5], new_points=new, params=TrackerParams(density_every=2))
    assert tr.added.sum() == 2 and (tr.start[tr.added] == 2).all()
    assert (tr.origin[tr.added] == [0, 1]).all()
    i = np.flatnonzero(tr.added)
    truth = new[2][:, :, None, :] + (np.arange(T) - 2)[None, None, :, None] * vel[:, None, None]
    got = tr.xy[2:, :, i].transpose(1, 2, 0, 3)          # (K, 2, T-2, 2)
    assert np.nanmax(np.abs(got - truth[:, :, 2:])) < 0.1 and np.isnan(tr.xy[:2, :, i]).all()


def test_trajectories_velocity_acceleration_and_gaps():
    fps = 25.0
    t = np.arange(8) / fps
    x = np.zeros((8, 2, 3))
    x[:, 0, 0] = 100 * t + 0.5 * 2000 * t ** 2          # a = 2000 mm/s^2
    x[:, 1, 1] = 50.0
    x[:2, 1] = np.nan
    x[6:, 1] = np.nan
    tr = Trajectories(x, fps)
    assert tr.start.tolist() == [0, 2] and tr.end.tolist() == [7, 5]
    assert tr.length.tolist() == [8, 4]
    assert np.allclose(tr.velocity[1:-1, 0, 0], 100 + 2000 * t[1:-1])
    assert np.allclose(tr.acceleration[1:-1, 0, 0], 2000)
    assert np.isnan(tr.acceleration[[0, 7], 0]).all() and np.isnan(tr.acceleration[2, 1]).all()
    assert np.isnan(tr.velocity[:2, 1]).all() and np.allclose(tr.velocity[2:6, 1], 0)


def _field(rng, N=60, T=12):
    """N points on a 300 mm patch moving together at 500 mm/s along x."""
    p0 = rng.uniform(0, 300, (N, 3))
    t = np.arange(T) / 25.0
    return p0[None] + t[:, None, None] * np.array([500.0, 0, 0])


def test_threshold_filter_truncates_at_a_jump_and_says_why():
    rng = np.random.default_rng(3)
    x = _field(rng)
    x[6:, 0] += [0, 0, 80.0]           # jumps 80 mm at frame 6 -> 2000 mm/s more
    x[2:, 1] += [0, 0, 80.0]           # jumps at frame 2 -> too short after truncation
    rep = threshold_filter(Trajectories(x, 25.0), max_speed=1500, max_acceleration=1e5,
                           min_length=3)
    assert rep.truncated[0] and rep.cut_frame[0] == 6 and rep.reason[0] == Reason.SPEED
    assert np.isfinite(rep.trajectories.xyz[:6, 0]).all()
    assert np.isnan(rep.trajectories.xyz[6:, 0]).all()
    assert rep.removed[1] and np.isnan(rep.trajectories.xyz[:, 1]).all()
    assert not (rep.removed[2:] | rep.truncated[2:]).any()
    assert rep.summary()["speed"] == {"removed": 1, "truncated": 1}


def test_uniformity_filter_finds_a_point_moving_against_its_neighbours():
    rng = np.random.default_rng(4)
    x = _field(rng)
    t = np.arange(x.shape[0]) / 25.0
    x[4:, 0, 0] = x[4, 0, 0] - 400 * (t[4:] - t[4])     # from frame 4 on, moves backwards
    before = x.copy()
    rep = uniformity_filter(Trajectories(x, 25.0), voxel=400, max_deviation=300, window=1,
                            min_neighbours=3, min_length=3)
    assert rep.truncated[0] and rep.reason[0] == Reason.NOT_UNIFORM and rep.cut_frame[0] <= 4
    assert not (rep.removed[1:] | rep.truncated[1:]).any()
    assert np.array_equal(x, before)


def _rotating_patch(rng, T=30, fps=25.0, omega=1.5, noise=0.3):
    """A 9 x 9 grid (40 mm spacing) of surface points on a plate rotating at ``omega`` rad/s
    about the z axis 300 mm away while translating at 700 mm/s: (T, 81, 3) mm."""
    g = np.arange(9) * 40.0
    u, w = np.meshgrid(g, g)
    p0 = np.stack([u.ravel() + 300.0, np.zeros(u.size), w.ravel()], axis=1)
    a = omega * np.arange(T) / fps
    c, s = np.cos(a)[:, None], np.sin(a)[:, None]
    x = np.stack([c * p0[:, 0] - s * p0[:, 1], s * p0[:, 0] + c * p0[:, 1],
                  np.broadcast_to(p0[:, 2], (T, len(p0)))], axis=2)
    x[..., 0] += 700.0 * np.arange(T)[:, None] / fps
    return x + rng.normal(scale=noise, size=x.shape)


def test_drift_filter_truncates_a_slow_drift_that_the_paper_filter_misses():
    rng = np.random.default_rng(5)
    x = _rotating_patch(rng)
    i, start = 40, 12                       # the middle point slides 1.5 mm a frame from 12 on
    x[start:, i, 2] += 1.5 * np.arange(1, x.shape[0] - start + 1)
    before = x.copy()
    traj = Trajectories(x, 25.0)
    rep = drift_filter(traj, max_drift=8.0, window=10, k=10, radius=200.0)
    assert np.array_equal(x, before)
    assert rep.truncated[i] and rep.reason[i] == Reason.DRIFT
    # 8 mm of drift are reached about 5-6 frames after it starts
    assert start + 3 <= rep.cut_frame[i] <= start + 8
    assert np.isfinite(rep.trajectories.xyz[:rep.cut_frame[i], i]).all()
    assert np.isnan(rep.trajectories.xyz[rep.cut_frame[i]:, i]).all()
    others = np.arange(x.shape[1]) != i
    assert not (rep.truncated[others] | rep.removed[others]).any()
    # per frame the drift (37.5 mm/s) hides in the rotation's spread of velocities
    paper = uniformity_filter(traj, voxel=400, max_deviation=150, min_neighbours=3)
    assert not paper.truncated[i]
    # a median of the neighbours ignores the rotation: it needs a much looser threshold
    clean = Trajectories(_rotating_patch(np.random.default_rng(7)), 25.0)
    dev_med = drift_deviation(clean, local="median")
    dev_aff = drift_deviation(clean, local="affine")
    assert np.nanmax(dev_aff) < 4.0              # half the 8 mm threshold: no false cut
    assert np.nanmax(dev_med) > 8.0              # the median alone would cut clean points


def test_drift_filter_gives_no_verdict_without_neighbours_and_rejects_bad_input():
    x = _rotating_patch(np.random.default_rng(6))[:, :4]
    rep = drift_filter(Trajectories(x, 25.0), min_neighbours=5)
    assert not (rep.truncated | rep.removed).any()
    traj = Trajectories(_rotating_patch(np.random.default_rng(6), T=5), 25.0)
    assert np.isnan(drift_deviation(traj, window=10)).all()      # shorter than the window
    with pytest.raises(ValueError, match="window"):
        drift_filter(traj, window=0)
    with pytest.raises(ValueError, match="min_neighbours"):
        drift_filter(traj, k=4, min_neighbours=5)
    with pytest.raises(ValueError, match="local"):
        drift_filter(traj, local="mean")
    with pytest.raises(ValueError, match="max_drift"):
        drift_filter(traj, max_drift=-1.0)
    with pytest.raises(TypeError, match="trajectories"):
        drift_filter(x)


def test_rendered_walk_tracks_against_truth():
    seq = et.walk_sequence(seed=7, n_frames=4, surface_every=4)
    trial = et.run_tracking_trial(seq, 80, rng=np.random.default_rng(1), density=False)
    # with the cameras, every accepted frame intersects within max_reprojection
    geo = et.run_tracking_trial(seq, 80, rng=np.random.default_rng(1), density=False, klt=False,
                       geometric=True, params=TrackerParams(max_reprojection=0.3))
    alive = geo.tracks.alive[1:]
    assert alive.sum() >= 20
    for t in range(1, 4):
        res = triangulate(seq.cameras, geo.tracks.xy[t][:, geo.tracks.alive[t]])
        assert np.nanmax(res.reprojection_error) <= 0.3
    sc = trial.score
    assert trial.tracks.alive[-1].sum() >= 10
    assert np.nanmedian(sc.step_error) < 0.2
    assert np.nanmedian(sc.error_3d[1:]) < 5.0
    # LSMTA's per-frame error is at most half KLT's, also on the entries alive in both
    # (its own survivors alone would flatter it: it drops the hard points KLT keeps)
    ls, kl = sc.step_error, trial.klt_score.step_error
    both = np.isfinite(ls) & np.isfinite(kl)
    assert both.sum() >= 50
    assert np.median(ls[both]) < 0.5 * np.median(kl[both])
    assert np.nanmedian(ls) < 0.5 * np.nanmedian(kl)


def test_score_filter_counts_caught_false_and_correct_length():
    from lsmta.evaluation.tracking import TrackScore

    T, N = 6, 3
    x = np.zeros((T, N, 3))
    before = Trajectories(x, 25.0)
    false_from = np.array([-1, 3, 2])
    score = TrackScore(image_error=None, step_error=None, error_3d=None, false_from=false_from,
                       truth_xy=None, truth_xyz=None, visible=None)
    keep = np.ones((T, N), bool)
    keep[3:, 1] = False          # false part of trajectory 1 cut: caught
    keep[4:, 0] = False          # 2 of 6 correct frames of trajectory 0 cut
    s = et.score_filter(before, before.keep_frames(keep), score)
    assert s["n_false"] == 2 and s["n_caught"] == 1 and s["recall"] == 0.5
    assert s["precision"] == 0.5
    correct = 6 + 3 + 2
    assert s["correct_length_removed"] == pytest.approx(2 / correct)
    assert s["false_length_left"] == pytest.approx(4 / keep.sum())


def test_arm_sequence_and_bad_motion():
    seq = et.walk_sequence(seed=3, n_frames=2, scale=0.25, motion="arm", surface_every=1)
    assert seq.images.shape[:2] == (3, 2) and len(seq.surface[0].part) > 0
    pr = seq.truth(seq.surface[1].part, seq.surface[1].local)
    assert np.allclose(pr.xy[1], seq.surface[1].xy)
    with pytest.raises(ValueError, match="motion"):
        et.walk_sequence(seed=3, n_frames=2, motion="run")


def _warped_pair(rng, A, c0, p0=(100.0, 100.0), gain=1.2, offset=10.0):
    """A texture and its copy under ``search(c0 + A u) = offset + gain * texture(p0 + u)``."""
    img = _texture(rng, (200, 200), sigma=2.0)
    Ainv = np.linalg.inv(A)
    M = Ainv[::-1, ::-1]                                    # (row, col) order for ndimage
    off = np.asarray(p0)[::-1] - M @ np.asarray(c0)[::-1]
    return img, offset + gain * ndimage.affine_transform(img, M, offset=off, order=3,
                                                         mode="reflect")


def test_inverse_compositional_templates_recover_a_known_affinity_and_radiometry():
    from lsmta.matching import LSMParams, lsm
    from lsmta.matching.spline import SplineImage
    from lsmta.tracking.templates import match_templates, sample_templates

    A = np.array([[1.05, 0.08], [-0.05, 0.97]])
    c0 = np.array([101.3, 99.4])
    img, search = _warped_pair(np.random.default_rng(1), A, c0)
    before = (img.copy(), search.copy())
    tm = sample_templates(SplineImage(img), np.array([[100.0, 100.0]]), 15)
    start = c0[None] + [0.8, -0.6]
    res = match_templates(tm, [0], SplineImage(search), start, np.eye(2)[None], tol=1e-4)
    assert res.status[0] == 0 and res.iterations[0] <= 8
    assert np.abs(res.xy[0] - c0).max() < 2e-3 and np.abs(res.A[0] - A).max() < 2e-3
    # the radiometry as lsm reports it, f = r0 + r1 g: r1 = 1 / 1.2, r0 = -10 / 1.2
    assert res.params[0, 7] == pytest.approx(1 / 1.2, abs=2e-3)
    fa = lsm(img, search, np.array([[100.0, 100.0]]), start,
             params=LSMParams(patch=15, tol=1e-4))
    assert np.abs(res.xy - fa.xy).max() < 1e-3 and res.sigma0[0] == pytest.approx(
        fa.sigma0[0], rel=0.05)
    # the forward path alone (inverse=False) reaches the same match
    fwd = match_templates(tm, [0], SplineImage(search), start, np.eye(2)[None], tol=1e-4,
                          inverse=False)
    assert np.abs(fwd.xy - fa.xy).max() < 1e-6
    assert np.array_equal(img, before[0]) and np.array_equal(search, before[1])


def test_a_per_row_forward_retry_gives_the_two_calls_positions_and_statuses():
    """``match_templates`` with a per-row ``fallback`` (one call for the tracks with and
    without the forward retry, as the tracker makes it) gives the positions (to 1e-6 px)
    and statuses of one call per group; the retry rescues some rows, so the groups differ."""
    from lsmta.synth.patches import warped_pair
    from lsmta.tracking.templates import match_templates

    rng = np.random.default_rng(3)
    pair = warped_pair(rng=rng, A=((1.12, 0.15), (-0.1, 0.9)), c=(3.2, -1.7), r0=8.0,
                       r1=0.9, noise_sigma=2.0)
    pts = rng.uniform(40, 216, (200, 2))
    truth = pair.true_xy(pts)
    start = truth + rng.uniform(-4.0, 4.0, truth.shape)       # some too far for the IC step
    tm = sample_templates(SplineImage(pair.template), pts, 11, partial=True)
    search, eye = SplineImage(pair.search), np.broadcast_to(np.eye(2), (200, 2, 2)).copy()
    th = TrackerParams().thresholds
    retry = rng.random(200) < 0.5
    rows = np.arange(200)
    both = match_templates(tm, rows, search, start, eye, thresholds=th, fallback=retry,
                           partial=True)
    ref = {}
    for group in (True, False):
        sel = rows[retry == group]
        ref[group] = match_templates(tm, sel, search, start[sel], eye[sel], thresholds=th,
                                     fallback=group, partial=True)
    for group, res in ref.items():
        sel = rows[retry == group]
        assert np.array_equal(both.status[sel], res.status)
        assert np.array_equal(np.isnan(both.xy[sel]), np.isnan(res.xy))
        assert np.nanmax(np.abs(both.xy[sel] - res.xy)) < 1e-6
    assert ref[True].ok.mean() > ref[False].ok.mean()          # the retry did something


def test_without_retry_rejected_only_diverged_or_unfinished_matches_are_retried():
    """The tracker's matches with ``retry_rejected=False``: where the inverse compositional match
    converged but was rejected, or found no positive correlation (REJECTED, SINGULAR), the
    result is the inverse compositional one (no forward retry); everywhere else it is the
    result with the retry. The default keeps every retry, and ``retry_rejected`` is checked."""
    from lsmta.matching.lsm import Status
    from lsmta.synth.patches import warped_pair
    from lsmta.tracking.templates import _match, match_templates

    rng = np.random.default_rng(3)
    pair = warped_pair(rng=rng, A=((1.12, 0.15), (-0.1, 0.9)), c=(3.2, -1.7), r0=8.0,
                       r1=0.9, noise_sigma=2.0)
    pts = rng.uniform(40, 216, (300, 2))
    start = pair.true_xy(pts) + rng.uniform(-6.0, 6.0, (300, 2))   # many too far
    tm = sample_templates(SplineImage(pair.template), pts, 11, partial=True)
    search, eye = SplineImage(pair.search), np.broadcast_to(np.eye(2), (300, 2, 2)).copy()
    rows = np.arange(300)
    kw = dict(thresholds=TrackerParams().thresholds, partial=True)
    ic = match_templates(tm, rows, search, start, eye, fallback=False, **kw)
    full = match_templates(tm, rows, search, start, eye, fallback=True, **kw)
    new = _match(tm, rows, search, start, eye, fallback=True, retry_rejected=False,
                 max_iter=30, tol=0.01, max_displacement=None, inverse=True, **kw)
    hopeless = np.isin(ic.status, [Status.REJECTED, Status.SINGULAR])
    retried = ~ic.ok & ~hopeless
    assert hopeless.sum() > 30 and retried.sum() > 30
    assert (full.status[hopeless] != ic.status[hopeless]).any()     # the flag does something
    for sel, ref in ((hopeless, ic), (~hopeless, full)):
        assert np.array_equal(new.status[sel], ref.status[sel])
        assert np.array_equal(np.isnan(new.xy[sel]), np.isnan(ref.xy[sel]))
        assert np.nanmax(np.abs(new.xy[sel] - ref.xy[sel])) < 1e-9
    assert TrackerParams().retry_rejected is True
    with pytest.raises(ValueError, match="params.retry_rejected"):
        track_points(np.zeros((1, 2, 40, 40)), np.full((1, 1, 2), 20.0),
                     params=TrackerParams(retry_rejected="no"))


def test_the_lsm_solver_runs_on_the_threads_numba_is_set_to(monkeypatch):
    """With ``numba.set_num_threads(1)`` the forward LSM runs on the calling thread (no
    thread pool), and with 2 threads it gives the same matches."""
    from lsmta.matching import LSMParams, _solver, lsm
    from lsmta.synth.patches import warped_pair

    rng = np.random.default_rng(4)
    pair = warped_pair(rng=rng, A=((1.03, 0.05), (-0.04, 0.98)), c=(1.2, 0.7))
    pts = rng.uniform(30, 226, (64, 2))
    start = pair.true_xy(pts) + rng.uniform(-1, 1, (64, 2))
    runs = {}
    for threads in (2, 1) if numba.config.NUMBA_NUM_THREADS >= 2 else (1,):
        numba.set_num_threads(threads)
        if threads == 1:
            monkeypatch.setattr(_solver, "_pool", lambda n: pytest.fail("pool used"))
        runs[threads] = lsm(pair.template, pair.search, pts, start, params=LSMParams(patch=11))
    numba.set_num_threads(1)
    assert (runs[1].status == 0).mean() > 0.9
    for other in runs.values():
        assert np.array_equal(other.status, runs[1].status)
        assert np.abs(other.xy - runs[1].xy).max() < 1e-12


def _coarse_to_fine_per_frame(state, pyramids, idx, pred, t, p, calls):
    """The coarse-to-fine step as it was before it was batched: one template sampling and
    one translation match per level and per last tracked frame (the reference)."""
    K, n = pred.shape[:2]
    out = np.full((K, n, 2), np.nan)
    last = state.end[idx]
    calls.append(len(np.unique(last)))
    for k in range(K):
        target = pyramids.get(k, t)
        sources = {f: pyramids.get(k, f) for f in np.unique(last)}
        est = np.array(pred[k], float)
        found = np.zeros(n, bool)
        for lv in range(len(target) - 1, 0, -1):
            s = 2.0 ** lv
            for f, src in sources.items():
                sel = np.flatnonzero(last == f)
                tm = sample_templates(src[lv], state.xy[f, k, idx[sel]] / s, p.patch,
                                      normals=False)
                xy, conv = match_translation(tm, np.arange(sel.size), target[lv],
                                             est[sel] / s, max_iter=p.max_iter, tol=p.tol)
                est[sel[conv]] = xy[conv] * s
                found[sel[conv]] = True
        out[k, found] = est[found]
    return out


def _occluded_walk():
    """Frames of a texture moving in jerks, parts occluded in frames 2-4 (tracks go
    missing in different frames), and a grid of start points."""
    rng = np.random.default_rng(11)
    base = sum(ndimage.gaussian_filter(rng.normal(size=(240, 320)), s) * s ** 0.5
               for s in (1.5, 3.0, 6.0, 12.0))
    base = 128 + 50 * base / base.std()
    steps = np.array([[0, 0], [3, 1], [12, 5], [-13, -4], [2, 6], [-12, -5], [9, 9]], float)
    pos = np.cumsum(steps, axis=0)
    frames = np.stack([ndimage.shift(base, (y, x), order=3, mode="reflect") for x, y in pos])
    occluder = _texture(rng, (60, 60), sigma=0.7)
    for t, (r, c) in ((2, (60, 90)), (3, (120, 180)), (4, (60, 180))):
        frames[t, r:r + 60, c:c + 60] = occluder       # tracks go missing in different frames
    g = np.stack(np.meshgrid(np.arange(60, 261, 16.0), np.arange(50, 191, 16.0)),
                 -1).reshape(-1, 2)
    return frames, g


def test_batched_coarse_to_fine_gives_the_per_frame_positions_and_statuses(monkeypatch):
    """Tracks missing since different frames are matched coarse-to-fine in one call per
    level, each missing track's patches sampled once (kept from one frame's call to the
    next, and only the last call's tracks); the positions (to 1e-6 px) and statuses are
    those of sampling and matching per frame and per last frame."""
    from lsmta.tracking import points

    frames, g = _occluded_walk()
    asked, sampled, kept = [], [], []
    templates, sampled_from = points._Pyramids.templates, points._sampled_from

    def ask(self, k, lv, idx, *a, **kw):
        asked.append(len(idx))
        out = templates(self, k, lv, idx, *a, **kw)
        kept.append(len(self.patches[(k, lv)]["idx"]))
        return out

    monkeypatch.setattr(points._Pyramids, "templates", ask)
    monkeypatch.setattr(points, "_sampled_from",
                        lambda im, which, xy, patch: sampled.append(len(xy))
                        or sampled_from(im, which, xy, patch))
    batched = track_points(frames[None], g[None])
    assert sum(sampled) < 0.8 * sum(asked)                  # the kept patches were reused
    assert kept == asked                    # only the last call's tracks are kept, no more
    calls = []
    monkeypatch.setattr(points, "_coarse_to_fine",
                        lambda *a: _coarse_to_fine_per_frame(*a, calls))
    reference = track_points(frames[None], g[None])
    assert max(calls) > 1                                   # several last frames at once
    assert np.array_equal(batched.status, reference.status)
    assert np.array_equal(np.isnan(batched.xy), np.isnan(reference.xy))
    assert np.nanmax(np.abs(batched.xy - reference.xy)) < 1e-6
    assert (batched.status == TrackStatus.ALIVE).sum() > 0.3 * len(g)


def test_a_patch_over_the_border_is_tracked_with_a_partial_template():
    """Points whose patch reaches over the image border (at the start, or as they move out)
    are tracked with partial templates, as KLT keeps such windows; without ``partial`` they
    are not started or get lost."""
    rng = np.random.default_rng(21)
    base = _texture(rng, (120, 160), sigma=2.0)
    vel = np.array([-0.6, 0.35])                        # towards the left border
    T = 8
    frames = np.stack([ndimage.shift(base, (vel[1] * t, vel[0] * t), order=3, mode="reflect")
                       for t in range(T)])
    ys = np.arange(30.0, 91.0, 12.0)
    edge = np.stack([np.full(ys.size, 156.0), ys], axis=1)       # patch over the border
    near = np.stack([np.full(ys.size, 9.0), ys], axis=1)         # reaches over it later
    xy0 = np.concatenate([edge, near])
    truth = xy0[None] + np.arange(T)[:, None, None] * vel
    tm = sample_templates(SplineImage(frames[0]), edge, 11, partial=True)
    assert tm.ok.all() and not tm.full.any()
    assert not tm.mask.reshape(-1, 11, 11)[:, :, -2:].any()       # x 160, 161: outside
    assert tm.mask.reshape(-1, 11, 11)[:, :, :-2].all()
    assert not sample_templates(SplineImage(frames[0]), edge, 11).ok.any()
    # both anchors: with "previous" every match is the forward LSM, whose patch leaves the
    # image when the point nears the border (then matched again with a partial patch)
    for anchor in ("first", "previous"):
        tr = track_points(frames[None], xy0[None],
                          params=TrackerParams(partial=True, anchor=anchor))
        assert (tr.status == TrackStatus.ALIVE).all(), anchor
        err = np.linalg.norm(tr.xy[:, 0] - truth, axis=2)
        assert np.median(err) < 0.05 and err.max() < 0.2, anchor
    off = track_points(frames[None], xy0[None], params=TrackerParams(partial=False))
    assert (off.status[:ys.size] == TrackStatus.NOT_STARTED).all()
    assert not (off.status[ys.size:] == TrackStatus.ALIVE).any()
    with pytest.raises(ValueError, match="params.partial"):
        track_points(frames[None], xy0[None], params=TrackerParams(partial="yes"))


def test_partial_templates_change_nothing_away_from_the_border(translation):
    images, xy0, _ = translation
    on = track_points(images, xy0, params=TrackerParams(partial=True))
    off = track_points(images, xy0, params=TrackerParams(partial=False))
    assert np.array_equal(on.status, off.status)
    assert np.array_equal(on.xy, off.xy, equal_nan=True)
