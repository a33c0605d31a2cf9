"""The caliscope recording from pixels (issue 40, item 7), its pieces on inputs with known
answers: corners moved to a common time, a board measured in 3-D, the corners of a drawn
board tracked by LSMTA and KLT, caliscope's mirror convention."""

import cv2
import numpy as np
import pytest

from lsmta.calibration.charuco import CharucoBoard, CharucoCorners
from lsmta.camera import Camera
from lsmta.real.board_video import (
    CornerTracks,
    at_common_time,
    board_geometry,
    caliscope_convention,
    corner_differences,
    corner_jumps,
    swept_window,
    track_board_corners,
)

BOARD = CharucoBoard(columns=5, rows=4, square_mm=30.0, marker_mm=22.5,
                     dictionary="DICT_4X4_50")


def test_common_time_undoes_linear_motion():
    T = np.array([[0.0, 1.0, 2.0, 3.0], [0.1, 1.05, 1.9, 3.2]])          # (K, F) s
    v = np.array([2.0, -1.0])                                             # px / s
    xy = np.zeros((2, 4, 3, 2)) + T[..., None, None] * v
    xy[1, 3, 2] = np.nan
    out = at_common_time(xy, T)
    mean = T.mean(axis=0)
    np.testing.assert_allclose(out[:, :, :2], np.broadcast_to(mean[None, :, None, None] * v,
                                                              (2, 4, 2, 2)), atol=1e-12)
    np.testing.assert_allclose(out[1, :3, 2], mean[:3, None] * v, atol=1e-12)
    # camera 1's frame 2 is later than the mean, and frame 1 is there: interpolated
    np.testing.assert_allclose(out[1, 2, 2], mean[2] * v)
    # camera 1's frame 3 lacks corner 2: left missing; one corner missing on both sides
    # of a frame is left as it is
    assert np.isnan(out[1, 3, 2]).all()
    lone = xy.copy()
    lone[0, [0, 2], 1] = np.nan
    np.testing.assert_allclose(at_common_time(lone, T)[0, 1, 1], xy[0, 1, 1])
    assert not np.shares_memory(out, xy) and np.isnan(xy[1, 3, 2, 0])
    with pytest.raises(ValueError, match="seconds"):
        at_common_time(xy, T[:, :3])


def test_board_geometry_of_an_exact_board():
    cams = [Camera.look_at([-500.0, 0, -1000], [0, 0, 0], f=800.0, width=800, height=600),
            Camera.look_at([500.0, 100, -1000], [0, 0, 0], f=800.0, width=800, height=600)]
    rng = np.random.default_rng(0)
    F = 5
    xy = np.full((2, F, BOARD.n_corners, 2), np.nan)
    bent = xy.copy()
    for f in range(F):
        R = cv2.Rodrigues(rng.uniform(-0.4, 0.4, 3))[0]
        X = BOARD.corners @ R.T + rng.uniform(-100, 100, 3)
        Xb = X.copy()
        Xb[0] += 2.0 * R[:, 2]                          # one corner 2 mm off the board
        for k, c in enumerate(cams):
            xy[k, f], bent[k, f] = c.project(X), c.project(Xb)
    xy[1, 0, 5:] = np.nan                        # frame 0: 5 corners in both cameras
    xy[0, 1, 4:] = np.nan                        # frame 1: one row only -> no plane
    geo = board_geometry(cams, xy, BOARD.corners)
    assert geo.square_rms < 1e-6 and geo.planarity_rms < 1e-6
    assert np.isnan(geo.plane_rms[1]) and np.isfinite(geo.plane_rms[[0, 2, 3, 4]]).all()
    # 17 neighbouring pairs on a 4 x 3 grid of corners; frame 0: 3 + 1, frame 1: 3
    assert len(geo.square_error) == 3 * 17 + 4 + 3
    # 2 mm off the plane of 12: RMS 2 sqrt(11) / 12 = 0.55 mm (the fit takes a little)
    off = board_geometry(cams, bent, BOARD.corners).plane_rms[2:]
    assert np.all((off > 0.4) & (off < 0.6))


def _moving_board(T=5, speed=(4.0, 2.5)):
    """A drawn board translating by ``speed`` px a frame (area-sampled); its corners."""
    S, px = 8, 30
    hi = BOARD.image(px * S, margin=0)
    frames, truth = [], []
    for t in range(T):
        off = np.array([60.0, 50.0]) + t * np.array(speed)
        M = np.array([[1.0, 0, off[0] * S], [0, 1.0, off[1] * S]])
        big = cv2.warpAffine(hi, M, (320 * S, 240 * S), flags=cv2.INTER_NEAREST,
                             borderValue=255)
        frames.append(cv2.GaussianBlur(cv2.resize(big, (320, 240), interpolation=cv2.INTER_AREA),
                                       (0, 0), 0.8))
        ij = BOARD.corners[:, :2] / BOARD.square_mm
        truth.append((px * S * ij - 0.5 + off * S + 0.5) / S - 0.5)
    return np.stack(frames), np.stack(truth)


def test_trackers_follow_a_drawn_board():
    frames, truth = _moving_board()
    detected = truth[None].copy()
    detected[0, 0, 11] = np.nan                                         # not found at first
    tr = track_board_corners([frames], detected)
    assert tr.start[0] == 0 and tr.window.shape == (1, 4)
    for mode in ("long", "step"):
        for tracker in ("lsmta", "klt"):
            e = tr.errors(mode, tracker)
            assert np.isnan(e[0, 0]).all()                             # the start frame
            assert np.nanmedian(e) < 0.1, (mode, tracker)
    # steps start from frame t - 1's detections with the velocity from t - 2: none at t = 1
    step = tr.step["lsmta"][0]
    assert np.isnan(step[:2]).all() and np.isfinite(step[2:, :11]).all()
    assert np.isnan(tr.long["lsmta"][0, :, 11]).all()
    with pytest.raises(ValueError, match="mode, tracker"):
        tr.errors("long", "sift")
    with pytest.raises(ValueError, match="images: expected 5 frames"):
        track_board_corners([frames[:4]], detected)


def test_small_pieces():
    assert list(swept_window(np.array([[10.2, 20.0], [50.0, 30.7]]), (100, 60), margin=5)) == \
        [5, 15, 56, 37]
    assert list(swept_window(np.full((2, 2), np.nan), (100, 60))) == [0, 0, 100, 60]
    xy = np.zeros((2, 3, 12, 2))
    mirrored = np.array([[False, True, False], [False, False, False]])
    c = CharucoCorners(xy=xy, board=BOARD.corners, markers=np.zeros((2, 3), int),
                       mirrored=mirrored, refine="opencv", refined=np.ones((2, 3, 12), bool))
    moved = caliscope_convention(c)
    assert np.all(moved[0, 1, :, 0] == 1.0) and np.all(moved[0, [0, 2]] == 0.0)
    d = corner_differences(moved, xy)
    assert d.shape == (2, 3, 12) and d[0, 1, 0] == 1.0 and d.sum() == 12.0


def test_corner_jumps_sorts_far_positions_by_the_lattice():
    # one camera, two frames, the board seen through a known homography; in frame 1 four
    # tracks are moved: onto their diagonal neighbour, an adjacent corner, 3 px off (own),
    # and half a square off (elsewhere)
    grid = BOARD.corners[:, :2] / BOARD.square_mm
    h = np.array([[40.0, 3.0, 100.0], [-2.0, 38.0, 80.0], [1e-3, 2e-3, 1.0]])
    img = cv2.perspectiveTransform(grid[None], h)[0]
    det = np.stack([img, img])[None]                                  # (1, 2, C, 2)
    on = cv2.perspectiveTransform(np.array([[grid[0] + [1, 1], grid[1] + [1, 0],
                                             grid[2] + [0.5, 0.5]]]), h)[0]
    trk = det.copy()
    trk[0, 1, 0], trk[0, 1, 1], trk[0, 1, 2] = on
    trk[0, 1, 3] += [3.0, 0.0]
    nan = np.full_like(det, np.nan)
    tracks = CornerTracks(detected=det, start=np.array([0]), window=np.zeros((1, 4), int),
                          long={"lsmta": trk, "klt": det.copy()}, step={"lsmta": nan, "klt": nan},
                          seconds={})
    j = corner_jumps(tracks, BOARD)
    assert (j.far, j.diagonal, j.other_corner, j.own, j.elsewhere) == (4, 1, 1, 1, 1)
    assert corner_jumps(tracks, BOARD, tracker="klt").far == 0
    assert corner_jumps(tracks, BOARD, far_px=5.0).own == 0          # 3 px is no longer far
    with pytest.raises(ValueError, match="far_px"):
        corner_jumps(tracks, BOARD, far_px=-1.0)
    with pytest.raises(ValueError, match="tol"):
        corner_jumps(tracks, BOARD, tol=0.5)
    with pytest.raises(ValueError, match="mode, tracker"):
        corner_jumps(tracks, BOARD, mode="steps")
