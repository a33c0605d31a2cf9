"""The surface stage on the rectified pair (SurfaceParams(method="rectified")): a generated
wide pair with known cameras, scored against the renderer's depth after the fact."""

import numpy as np
import pytest
from scipy import ndimage

from conftest import smaller
from lsmta.synth import Renderer, Scene, make_body, triplet_rig, walk
from lsmta.systems import SurfaceParams, measure_surfaces
from lsmta.systems.rectified import rectify_pair, to_original
from lsmta.triangulation import triangulate


@pytest.fixture(scope="module")
def pair():
    """The outer two cameras of a half-resolution triplet at 2.5 m (1.4 m apart, with lens
    distortion added), a walking body, frame 5."""
    rng = np.random.default_rng(5)
    cams = [smaller(c) for c in triplet_rig(rng=rng, distance=2500.0, baseline=700.0)]
    cams = [cams[0].replace(k1=-0.08, k2=0.05), cams[2].replace(k1=0.06, p1=0.001)]
    scene = Scene(make_body(rng=rng, wavelength=(12.0, 50.0)),
                  walk(n_frames=20, start=(-300.0, 0.0)), None)
    return cams, Renderer(scene, cams, noise_sigma=1.0).render(5, rng=rng)


def test_rectified_rows_are_epipolar_lines(pair):
    cams, _ = pair
    xy = np.stack([[[c.cx, c.cy]] for c in cams])
    point = triangulate(cams, xy, min_angle_deg=0.0).points[0]
    rect = rectify_pair(cams[0], cams[1], working_point=point)
    X = point + np.random.default_rng(1).normal(0.0, 200.0, (50, 3))
    # a world point's rectified pixels lie on one row, and map back to its original pixels
    p = [(X - cams[k].C) @ rect.R.T for k in (rect.left, rect.right)]
    xr = [np.c_[rect.f * q[:, 0] / q[:, 2] + rect.cx[v], rect.f * q[:, 1] / q[:, 2] + rect.cy]
          for v, q in enumerate(p)]
    assert np.allclose(xr[0][:, 1], xr[1][:, 1])
    back = to_original(rect, cams[0], cams[1], xr[0], xr[1])
    for k in (0, 1):
        assert np.abs(back[k] - cams[k].project(X)).max() < 1e-6


def test_rectified_surface_lies_on_the_true_surface(pair):
    cams, frame = pair
    videos = frame.images[:, None]                                  # (2, 1, H, W)
    res = measure_surfaces(videos, cams, [0], sigma=1.0,
                           params=SurfaceParams(method="rectified", template=0))[0]
    kept = res.kept
    body_nodes = np.isfinite(frame.depth[0][::4, ::4]).sum()      # the body seen in the template
    assert kept.sum() > 0.3 * body_nodes                           # 340 of 739 when written
    err = np.nanmax(res.intersection.reprojection_error[:, kept], axis=0)
    assert np.median(err) < 0.05
    # the truth: the renderer's depth at the template pixel (nearest pixel)
    xy = res.xy[0, kept]
    ij = np.rint(xy).astype(int)
    true_depth = frame.depth[0][ij[:, 1], ij[:, 0]]
    depth = (res.intersection.points[kept] - cams[0].C) @ cams[0].R[2]
    d = np.abs(depth - true_depth)
    assert np.isfinite(true_depth).mean() > 0.95
    assert np.nanmedian(d) < 4.0 and np.nanmean(d > 30.0) < 0.05
    assert abs(np.nanmedian(depth - true_depth)) < 2.0        # no half-pixel bias


@pytest.mark.parametrize("geometry", ["row-affine", "shift"])
def test_sgbm_started_lsm_lies_on_the_true_surface(pair, geometry):
    """rectified_start="sgbm": LSM at SGBM's nodes; the accepted points lie on the renderer's
    surface, and none on the background (flat, noise only) away from the silhouette."""
    cams, frame = pair
    res = measure_surfaces(frame.images[:, None], cams, [0], sigma=1.0,
                           params=SurfaceParams(method="rectified", template=0,
                                                rectified_start="sgbm",
                                                rectified_geometry=geometry))[0]
    kept = res.kept
    ij = np.rint(res.xy[0, kept]).astype(int)
    true_depth = frame.depth[0][ij[:, 1], ij[:, 0]]
    body = np.isfinite(frame.depth[0])
    assert np.isfinite(true_depth).sum() > 0.5 * body[::4, ::4].sum()   # 394 / 453 of 739
    off = ndimage.distance_transform_edt(~body)[ij[:, 1], ij[:, 0]]
    assert off.max() < 12.0                     # at most a patch outside the silhouette
    depth = (res.intersection.points[kept] - cams[0].C) @ cams[0].R[2]
    d = depth - true_depth
    assert np.nanmedian(np.abs(d)) < 4.0 and np.nanmean(np.abs(d) > 30.0) < 0.05
    assert abs(np.nanmedian(d)) < 2.0
    assert np.median(res.sigma_xy[1, kept, 0]) < 0.1                   # disparity sigma, px


def test_growth_stays_off_the_rectified_border(pair):
    """Rectified pixels outside the left image are zero-filled; their step edge must give
    no match: every match's left pixel lies a patch inside the image."""
    cams, frame = pair
    res = measure_surfaces(frame.images[:, None], cams, [0], sigma=1.0,
                           params=SurfaceParams(method="rectified", template=0))[0]
    point = triangulate(cams, np.stack([[[c.cx, c.cy]] for c in cams]),
                        min_angle_deg=0.0).points[0]
    rect = rectify_pair(cams[0], cams[1], working_point=point, depth_range=(0.8, 1.25))
    res_xy = res.xy[rect.left]
    xy = res_xy[np.isfinite(res_xy[:, 0])]
    half = 4                                                  # the growth's 9 x 9 patch
    w, h = cams[rect.left].image_size
    assert len(xy) > 100
    assert (xy.min(axis=0) >= half - 1).all() and (xy.max(axis=0) <= [w - half, h - half]).all()


def test_rectified_method_bad_input(pair):
    cams, frame = pair
    videos = frame.images[:, None]
    with pytest.raises(ValueError, match="method"):
        SurfaceParams(method="sgbm")
    with pytest.raises(ValueError, match="rectified_start"):
        SurfaceParams(rectified_start="bm")
    with pytest.raises(ValueError, match="rectified_geometry"):
        SurfaceParams(rectified_geometry="affine")
    with pytest.raises(ValueError, match="rectified_depths"):
        SurfaceParams(rectified_depths=(1.2, 0.8))
    with pytest.raises(ValueError, match="expected 2 cameras"):
        measure_surfaces(np.concatenate([videos, videos[:1]]), [*cams, cams[0]], [0],
                         sigma=1.0, params=SurfaceParams(method="rectified"))
