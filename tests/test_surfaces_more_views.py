"""The subject mask (lsmta.systems.subject) and more views for a pair's points
(lsmta.systems.more_views) on a generated walking body seen by a triplet, scored against the
renderer's silhouettes and depth after the fact (truth only here)."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import ndimage

import lsmta.systems.surfaces as surfaces_module
from conftest import smaller
from lsmta.camera import Camera
from lsmta.matching import DisparityParams
from lsmta.synth import Renderer, Scene, make_body, triplet_rig, walk
from lsmta.systems import CaptureParams, SurfaceParams, capture_recording, measure_surfaces
from lsmta.systems.more_views import (
    MoreViewsParams,
    add_views,
    group_xy,
    normal_angles,
)
from lsmta.systems.subject import (
    SubjectMaskParams,
    background,
    on_subject,
    subject_masks,
)
from lsmta.systems.surfaces import grow_failed
from lsmta.triangulation import triangulate, voxel_filter

SGBM = SurfaceParams(method="rectified", template=0, rectified_start="sgbm",
                     rectified_geometry="shift")


@pytest.fixture(scope="module")
def triplet():
    """A half-resolution triplet at 2.5 m (outer cameras 1.4 m apart), a walking body, five
    frames (every fourth of 20); frame 1 of them is measured."""
    rng = np.random.default_rng(5)
    cams = [smaller(c) for c in triplet_rig(rng=rng, distance=2500.0, baseline=700.0)]
    scene = Scene(make_body(rng=rng, wavelength=(12.0, 50.0)),
                  walk(n_frames=20, start=(-300.0, 0.0)), None)
    renderer = Renderer(scene, cams, noise_sigma=1.0)
    frames = [renderer.render(f, rng=rng) for f in range(0, 20, 4)]
    videos = np.stack([np.stack([f.images[k] for f in frames]) for k in range(3)])
    return cams, videos, frames[1]


@pytest.fixture(scope="module")
def pair_points(triplet):
    """The outer pair's SGBM-started LSM points of frame 1, as a (3, N, 2) array."""
    cams, videos, _ = triplet
    res = measure_surfaces(videos[[0, 2]], [cams[0], cams[2]], [1], sigma=1.0, params=SGBM)[1]
    xy = group_xy(res, (0, 2), 3)
    assert np.array_equal(xy[[0, 2]], res.xy[:, res.kept]) and np.isnan(xy[1]).all()
    return xy


def test_subject_mask_covers_the_moving_body(triplet):
    cams, videos, frame = triplet
    sm = subject_masks(videos, 1)
    assert np.all(sm.threshold == 10.0 * sm.noise)
    reused = subject_masks(videos, 1, background=background(videos))      # the same background
    assert np.array_equal(reused.masks, sm.masks)
    p = SubjectMaskParams()
    for k in range(3):
        body = np.isfinite(frame.depth[k])
        assert (sm.masks[k] & body).sum() > 0.95 * body.sum()
        off = ndimage.distance_transform_edt(~body)[sm.masks[k]]
        # the rim the closing and dilation add, and the ghosts of a five-frame median
        assert np.mean(off <= p.close_px + p.grow_px) > 0.7
        assert sm.masks[k].mean() < 0.5


def test_subject_mask_option_drops_and_counts(triplet):
    cams, videos, _ = triplet
    pair = [cams[0], cams[2]]
    plain = measure_surfaces(videos[[0, 2]], pair, [1], sigma=1.0, params=SGBM)[1]
    masked = measure_surfaces(videos[[0, 2]], pair, [1], sigma=1.0,
                              params=SurfaceParams(**{**SGBM.__dict__,
                                                      "subject_mask": SubjectMaskParams()}))[1]
    assert plain.off_subject == 0
    assert masked.xy.shape[1] + masked.off_subject == plain.xy.shape[1]
    assert masked.kept.sum() > 0.9 * plain.kept.sum()       # the body's points stay
    mask = subject_masks(videos[[0, 2]], 1).masks[0]
    ij = np.rint(masked.points_xy[0]).astype(int)
    assert mask[ij[:, 1], ij[:, 0]].all()


def test_more_views_reach_the_middle_camera(triplet, pair_points):
    cams, videos, frame = triplet
    th = DisparityParams().grow_params().lsm_thresholds()
    mv = add_views(list(videos[:, 1]), cams, pair_points, reference=0,
                   params=MoreViewsParams(thresholds=th))
    three = mv.n_views >= 3
    assert three.sum() > 0.5 * pair_points.shape[1]        # 425 of 614 when written
    assert np.median(mv.residual[three]) < 0.5              # 0.22 px when written
    assert mv.census[1]["accepted"] == three.sum()
    ij = np.rint(mv.xy[0, three]).astype(int)
    depth = (mv.intersection.points[three] - cams[0].C) @ cams[0].R[2]
    err = np.abs(depth - frame.depth[0][ij[:, 1], ij[:, 0]])
    assert np.nanmedian(err) < 4.0 and np.nanmean(err > 30.0) < 0.05
    assert np.isnan(pair_points[1]).all()                   # input unchanged


def test_more_views_skip_a_camera_behind_the_body(triplet, pair_points):
    """A camera mirrored through the working point sees the body's other side: the normals
    face away from it, nothing is tried there."""
    cams, videos, _ = triplet
    axes = np.stack([[[c.cx, c.cy]] for c in (cams[0], cams[2])])
    X0 = triangulate([cams[0], cams[2]], axes, min_angle_deg=0.0).points[0]
    back = Camera.look_at(2 * X0 - cams[1].C, X0, f=cams[1].f, width=cams[1].width,
                          height=cams[1].height)
    mv = add_views(list(videos[:, 1]), [cams[0], back, cams[2]], pair_points, reference=0)
    assert mv.census[1]["tried"] == 0 and mv.census[1]["not_facing"] > 0
    assert (mv.n_views <= 2).all()


def test_bad_input(triplet, pair_points):
    cams, videos, _ = triplet
    with pytest.raises(ValueError, match="factor"):
        SubjectMaskParams(factor=0.0)
    with pytest.raises(ValueError, match="min_share"):
        SubjectMaskParams(min_share=1.5)
    with pytest.raises(ValueError, match="videos"):
        subject_masks(videos[:, :2], 0)
    with pytest.raises(ValueError, match="frame"):
        subject_masks(videos, 5)
    with pytest.raises(TypeError, match="params"):
        subject_masks(videos, 0, params="strict")
    with pytest.raises(ValueError, match="background: expected a median"):
        subject_masks(videos, 0, background=background(videos[:2]))
    with pytest.raises(TypeError, match="subject_mask"):
        SurfaceParams(subject_mask=True)
    with pytest.raises(ValueError, match="subject_mask needs at least 3 frames"):
        measure_surfaces(videos[[0, 2], :1], [cams[0], cams[2]], [0], sigma=1.0,
                         params=SurfaceParams(**{**SGBM.__dict__,
                                                 "subject_mask": SubjectMaskParams()}))
    res = measure_surfaces(videos[[0, 2]], [cams[0], cams[2]], [1], sigma=1.0, params=SGBM)[1]
    with pytest.raises(ValueError, match="mask"):
        on_subject(res, np.ones(5, bool), template=0)
    with pytest.raises(ValueError, match="max_view_angle_deg"):
        MoreViewsParams(max_view_angle_deg=95.0)
    with pytest.raises(ValueError, match="patch"):
        MoreViewsParams(patch=12)
    with pytest.raises(TypeError, match="thresholds"):
        MoreViewsParams(thresholds=None)
    images = list(videos[:, 1])
    with pytest.raises(ValueError, match="images: expected 3"):
        add_views(images[:2], cams, pair_points, reference=0)
    with pytest.raises(ValueError, match="images: image 1"):
        add_views([images[0], images[1][:-1], images[2]], cams, pair_points, reference=0)
    with pytest.raises(ValueError, match="reference"):
        add_views(images, cams, pair_points, reference=1)
    with pytest.raises(ValueError, match="xy"):
        add_views(images, cams, pair_points[:2], reference=0)


def test_auto_keeps_a_working_growth_and_replaces_a_failed_one(triplet):
    """method="auto": where the growth works its result is the growth's, node for node; a
    rule that calls it failed (auto_min_share near 1) measures the pair by SGBM-started LSM."""
    cams, videos, _ = triplet
    pair, v = [cams[0], cams[2]], videos[[0, 2], 1:2]
    grow = measure_surfaces(v, pair, [0], sigma=1.0, params=SurfaceParams(template=0))
    assert not grow_failed(grow)
    auto = measure_surfaces(v, pair, [0], sigma=1.0,
                            params=SurfaceParams(template=0, method="auto"))
    assert np.array_equal(auto[0].xy, grow[0].xy)
    with pytest.warns(UserWarning, match="rectified images"):
        failed = measure_surfaces(v, pair, [0], sigma=1.0,
                                  params=SurfaceParams(template=0, method="auto",
                                                       auto_min_share=0.99))
    sgbm = measure_surfaces(v, pair, [0], sigma=1.0, params=SGBM)
    assert np.array_equal(failed[0].xy, sgbm[0].xy)
    assert grow_failed({})
    with pytest.raises(ValueError, match="auto_min_share"):
        SurfaceParams(method="auto", auto_min_share=0.0)


def test_grow_failed_counts_the_growths_matched_nodes():
    """The rule reads the growth's own census of the first measured frame: nodes matched
    against the textured ones (not the points kept after the filters)."""
    def result(matched, kept):
        census = {"outside": 50, "masked": 10, "no_texture": 40, "matched": matched,
                  "given_up": 900 - matched, "failed_open": 60, "never_reached": 40}
        return SimpleNamespace(grown=[SimpleNamespace(node_census=census)],
                               kept=np.arange(100) < kept)
    # 1,000 textured nodes: 1 % is 10 matched, whatever the filters kept afterwards
    assert not grow_failed({3: result(10, 0), 7: result(0, 0)})
    assert grow_failed({3: result(9, 100), 7: result(500, 100)})
    assert not grow_failed({3: result(9, 0)}, min_share=0.005)


def test_a_still_clip_has_no_mask_and_says_so(triplet):
    """Nothing moves: the mask is empty, every point is dropped with a warning naming the
    option, and the capture's error names the mask."""
    cams, videos, _ = triplet
    still = np.repeat(videos[:, 1:2], 4, axis=1)
    assert not subject_masks(still, 0).masks.any()
    masked = SurfaceParams(**{**SGBM.__dict__, "subject_mask": SubjectMaskParams()})
    with pytest.warns(UserWarning, match="subject_mask.*--subject-mask\\) is empty"):
        r = measure_surfaces(still[[0, 2]], [cams[0], cams[2]], [0], sigma=1.0,
                             params=masked)[0]
    assert r.kept.sum() == 0 and r.off_subject > 0
    with pytest.warns(UserWarning, match="subject mask"), \
            pytest.raises(ValueError, match="subject mask .*--subject-mask\\) dropped"):
        capture_recording(still[[0, 2]], [cams[0], cams[2]], fps=25.0, progress=False,
                          params=CaptureParams(surface=masked))


def test_on_subject_refuses_a_voxel_cloud(triplet):
    cams, videos, _ = triplet
    res = measure_surfaces(videos[[0, 2]], [cams[0], cams[2]], [1], sigma=1.0, params=SGBM)[1]
    thinned = replace(res, cloud=voxel_filter(res.intersection.points, 10.0))
    with pytest.raises(ValueError, match="result: a surface thinned to a voxel cloud"):
        on_subject(thinned, np.ones((cams[0].height, cams[0].width), bool), template=0)


def test_auto_decides_on_the_first_frame_and_keeps_the_growth_if_rectified_fails(
        triplet, monkeypatch):
    cams, videos, _ = triplet
    pair, v = [cams[0], cams[2]], videos[[0, 2], :3]
    grown = []
    real = surfaces_module._grown_surfaces

    def counting(v_, cams_, frames, *args):
        grown.extend(frames)
        return real(v_, cams_, frames, *args)

    def broken(*args):
        raise ValueError("rectify_pair: no overlap")

    monkeypatch.setattr(surfaces_module, "_grown_surfaces", counting)
    monkeypatch.setattr(surfaces_module, "_rectified_surfaces", broken)
    failing = SurfaceParams(template=0, method="auto", auto_min_share=0.99)
    with pytest.warns(UserWarning, match="rectified pair failed.*keeps the growth"):
        out = measure_surfaces(v, pair, [0, 2], sigma=1.0, params=failing)
    assert sorted(out) == [0, 2] and grown == [0, 2]
    grown.clear()
    monkeypatch.setattr(surfaces_module, "_rectified_surfaces", lambda *a: {})
    with pytest.warns(UserWarning, match="rectified images"):
        measure_surfaces(v, pair, [0, 2], sigma=1.0, params=failing)
    assert grown == [0], "the growth runs on the first measured frame only"


def test_normal_angles(triplet, pair_points):
    cams, videos, _ = triplet
    mv = add_views(list(videos[:, 1]), cams, pair_points, reference=0)
    ang = normal_angles(mv.normals, mv.intersection.points, cams)
    has = np.isfinite(mv.normals).all(axis=1)
    assert ang.shape == (3, len(has)) and np.isnan(ang[:, ~has]).all()
    assert np.all(ang[0, has] <= 90.0), "normals are turned to the reference camera"
    tried = mv.tried[1]
    assert np.all(ang[1, tried] <= MoreViewsParams().max_view_angle_deg + 1e-9)
