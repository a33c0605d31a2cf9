"""ChArUco corners in images (issue 40, item 7): boards the tests draw with OpenCV at known
positions, the corners recovered; the point-symmetry refinement against OpenCV's and
caliscope's; mirrored and inverted boards; clear errors; the corners handed to
calibrate_board; caliscope's board file and a few of its real frames."""

import cv2
import numpy as np
import pytest

from lsmta.calibration.board import calibrate_board
from lsmta.calibration.charuco import (
    CALISCOPE,
    CharucoBoard,
    CharucoCorners,
    CharucoParams,
    detect_charuco,
    read_charuco_toml,
    refine_corners,
    symmetry_windows,
)
from lsmta.camera import Camera
from lsmta.data import CALISCOPE_DIR
from lsmta.io import BoardPoints, read_caliscope_points, read_caliscope_times
from lsmta.matching.symmetry import symmetric_corners

BOARD = CharucoBoard(columns=5, rows=4, square_mm=30.0, marker_mm=22.5,
                     dictionary="DICT_4X4_50")
S = 8                                   # supersampling of the drawn boards


def _drawn(board, px, shift=(0, 0), blur=0.7, flip=False):
    """The board drawn with ``px`` pixels per square, moved by ``shift`` eighths of a
    pixel (drawn 8 times larger and averaged down: exact area sampling), blurred; and
    its corners' true positions (px)."""
    hi = board.image(px * S, margin=px * S)
    dx, dy = shift
    big = np.full((hi.shape[0] + S, hi.shape[1] + S), 0 if board.inverted else 255, np.uint8)
    big[dy:dy + hi.shape[0], dx:dx + hi.shape[1]] = hi
    img = cv2.resize(big, (big.shape[1] // S, big.shape[0] // S), interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), blur) if blur else img
    ij = board.corners[:, :2] / board.square_mm
    truth = (px * S - 0.5 + px * S * ij + [dx, dy] + 0.5) / S - 0.5
    if flip:
        img = np.ascontiguousarray(img[:, ::-1])
        truth = truth * [-1, 1] + [img.shape[1] - 1, 0]
    return img, truth


def test_board_geometry_and_drawing_agree_with_opencv():
    np.testing.assert_allclose(BOARD.corners, BOARD.opencv().getChessboardCorners() * 1000,
                               atol=1e-3)
    assert BOARD.n_corners == 12 and BOARD.corners.shape == (12, 3)
    img, truth = _drawn(BOARD, 32, blur=0)
    res = detect_charuco([img[None]], BOARD, params=CharucoParams(refine="opencv"))
    # an exactly drawn board is symmetric about every corner: OpenCV finds them exactly
    np.testing.assert_allclose(res.xy[0, 0], truth, atol=1e-3)


@pytest.mark.parametrize("px", [24, 40])
def test_corners_recovered_to_a_twentieth_of_a_pixel(px):
    errors = {}
    for name, params in (("symmetry", None), ("opencv", CharucoParams(refine="opencv")),
                         ("caliscope", CALISCOPE)):
        e = []
        for shift in ((1, 3), (3, 6), (5, 2)):
            img, truth = _drawn(BOARD, px, shift)
            res = detect_charuco([img[None]], BOARD, params=params)
            assert res.found[0, 0] == 12 and not res.mirrored.any()
            e.append(np.linalg.norm(res.xy[0, 0] - truth, axis=1))
        errors[name] = np.concatenate(e)
    assert errors["symmetry"].max() < 0.05                  # ours: < 0.1 px asked
    assert errors["opencv"].max() < 0.2                     # steps of 0.1 px
    # caliscope's 23 x 23 window reaches the markers' edges of these squares
    assert errors["caliscope"].max() > 0.4 > errors["symmetry"].max()


def test_inverted_board_seen_in_a_mirror():
    board = CharucoBoard(columns=4, rows=5, square_mm=54.0, marker_mm=40.5,
                         dictionary="DICT_4X4_1000", inverted=True)
    img, truth = _drawn(board, 32, (3, 5), flip=True)
    res = detect_charuco([img[None]], board)
    assert res.mirrored[0, 0] and res.found[0, 0] == 12
    assert np.abs(res.xy[0, 0] - truth).max() < 0.05         # x = W - 1 - x' (pixel centres)
    assert not detect_charuco([img[None]], board, params=CharucoParams(mirror="never")).found.any()
    # the plain board is not found when only its mirror image is searched
    plain, _ = _drawn(board, 32, (3, 5))
    assert not detect_charuco([plain[None]], board,
                              params=CharucoParams(mirror="always")).found.any()


def test_symmetric_corners_under_an_affine_view_and_noise():
    rng = np.random.default_rng(4)
    hi = BOARD.image(36 * S, margin=36 * S).astype(np.float32)
    A = np.array([[0.9, 0.25], [-0.15, 0.8]])
    t = np.array([60.3, 41.7]) * S
    warped = cv2.warpAffine(hi, np.hstack([A, t[:, None]]), (400 * S, 300 * S),
                            flags=cv2.INTER_AREA, borderValue=255)
    img = cv2.resize(warped, (400, 300), interpolation=cv2.INTER_AREA)
    img = np.clip(cv2.GaussianBlur(img, (0, 0), 0.8) + rng.normal(0, 2.0, img.shape), 0, 255)
    ij = BOARD.corners[:, :2] / BOARD.square_mm
    truth = ((36 * S - 0.5 + 36 * S * ij) @ A.T + t + 0.5) / S - 0.5
    start = truth + rng.uniform(-0.6, 0.6, truth.shape)
    fit = symmetric_corners(img, start, half=4)
    assert fit.ok.all() and np.all(fit.iterations < 20)
    err = np.linalg.norm(fit.xy - truth, axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.08                 # (warpAffine's own resampling)
    assert np.all(fit.sigma_xy < 0.05)
    far = symmetric_corners(img, truth + [6.0, 0.0], half=3, max_shift=1.0)
    assert not far.ok.any() and np.isnan(far.xy).all()


def test_symmetry_windows_follow_the_squares():
    xy = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 40.0]])
    # inset 3.75 + frame cell 3.75 = 7.5 mm of a 30 mm square: 0.8 * 0.25 * 40 px = 8
    np.testing.assert_array_equal(symmetry_windows(xy, BOARD), [8, 8, 8])
    np.testing.assert_array_equal(symmetry_windows(xy * 10, BOARD), [10, 10, 10])
    np.testing.assert_array_equal(symmetry_windows(xy / 10, BOARD), [2, 2, 2])
    np.testing.assert_array_equal(symmetry_windows(xy[:1], BOARD), [3])


def _views(board, cameras, poses):
    """The board drawn into each camera's image at each pose ``(R, C)`` (board to world:
    ``X = R X_b + C``), rendered 4 times larger and averaged down; the true corners."""
    s = 4 * board.square_mm                       # board drawn at 4 px per mm
    drawn = board.image(int(s))
    mm_of_px = np.array([[1 / 4, 0, 0.5 / 4], [0, 1 / 4, 0.5 / 4], [0, 0, 1]])
    big_of_px = np.array([[4, 0, 1.5], [0, 4, 1.5], [0, 0, 1.0]])   # pixel centres, x4
    frames, truth = [], []
    for cam in cameras:
        Km = np.array([[cam.f, 0, cam.cx], [0, cam.f, cam.cy], [0, 0, 1.0]])
        imgs, pts = [], []
        for R, C in poses:
            Rc, tc = cam.R @ R, cam.R @ (C - cam.C)
            H = big_of_px @ Km @ np.column_stack([Rc[:, 0], Rc[:, 1], tc]) @ mm_of_px
            big = cv2.warpPerspective(drawn, H, (cam.width * 4, cam.height * 4),
                                      flags=cv2.INTER_LINEAR, borderValue=255)
            imgs.append(cv2.resize(big, (cam.width, cam.height), interpolation=cv2.INTER_AREA))
            pts.append(cam.project(board.corners @ R.T + C))
        frames.append(np.stack(imgs))
        truth.append(np.stack(pts))
    return frames, np.stack(truth)


def test_corners_feed_calibrate_board():
    cams = [Camera.look_at([-400.0, 0, -900], [0, 0, 0], f=700.0, width=640, height=480),
            Camera.look_at([400.0, 50, -900], [0, 0, 0], f=650.0, width=640, height=480)]
    rng = np.random.default_rng(2)
    poses = []
    for _ in range(8):
        R = cv2.Rodrigues(rng.uniform(-0.5, 0.5, 3))[0]
        poses.append((R, rng.uniform([-30, -30, -60], [30, 30, 60]) - R @ [75.0, 60.0, 0]))
    images, truth = _views(BOARD, cams, poses)
    res = detect_charuco(images, BOARD)
    seen = np.isfinite(res.xy[..., 0])
    assert seen.sum() >= 0.8 * seen.size
    assert np.nanmax(np.linalg.norm(res.xy - truth, axis=-1)) < 0.25
    pts = res.board_points(frames=np.arange(100, 108), camera_ids=[3, 7])
    assert isinstance(pts, BoardPoints) and pts.xy.shape == (2, 8, 12, 2)
    np.testing.assert_array_equal(pts.xy, res.xy)
    np.testing.assert_array_equal(pts.board, BOARD.corners)
    assert list(pts.camera_ids) == [3, 7] and pts.frames[0] == 100
    cal = calibrate_board(pts.xy, pts.board, [(640, 480)] * 2)
    np.testing.assert_allclose([c.f for c in cal.cameras], [700.0, 650.0], rtol=0.02)
    base = np.linalg.norm(cal.cameras[1].C - cal.cameras[0].C)
    assert abs(base - np.linalg.norm(cams[1].C - cams[0].C)) < 10.0          # mm of 802


def test_refine_corners_reproduces_detection():
    img, _ = _drawn(BOARD, 30, (2, 5))
    raw = detect_charuco([img[None]], BOARD, params=CharucoParams(refine="opencv"))
    for params in (None, CALISCOPE):
        direct = detect_charuco([img[None]], BOARD, params=params)
        again = refine_corners([img[None]], raw, BOARD, params=params)
        np.testing.assert_allclose(again.xy, direct.xy, atol=1e-6)
        assert again.refine == direct.refine and again.refined.all()
    with pytest.raises(ValueError, match="corners: expected OpenCV's corners"):
        refine_corners([img[None]], direct, BOARD)
    with pytest.raises(ValueError, match="images: expected the 1 cameras x 1 frames"):
        refine_corners([np.stack([img, img])], raw, BOARD)


def test_bad_arguments_are_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match="marker_mm"):
        CharucoBoard(columns=4, rows=5, square_mm=30, marker_mm=30)
    with pytest.raises(ValueError, match="dictionary"):
        CharucoBoard(columns=4, rows=5, square_mm=30, marker_mm=20, dictionary="DICT_9X9")
    with pytest.raises(ValueError, match="columns"):
        CharucoBoard(columns=1, rows=5, square_mm=30, marker_mm=20)
    with pytest.raises(TypeError, match="inverted"):
        CharucoBoard(columns=4, rows=5, square_mm=30, marker_mm=20, inverted="yes")
    with pytest.raises(ValueError, match="refine"):
        CharucoParams(refine="lsm")
    with pytest.raises(ValueError, match="mirror"):
        CharucoParams(mirror="sometimes")
    with pytest.raises(ValueError, match="min_markers"):
        CharucoParams(min_markers=0)
    img, _ = _drawn(BOARD, 30)
    with pytest.raises(ValueError, match=r"images\[0\]: expected a \(T, H, W\) uint8"):
        detect_charuco([img[None].astype(float)], BOARD)
    with pytest.raises(ValueError, match="images: expected"):
        detect_charuco(img, BOARD)
    with pytest.raises(ValueError, match="different numbers of frames"):
        detect_charuco([img[None], np.stack([img, img])], BOARD)
    with pytest.raises(TypeError, match="board: expected a CharucoBoard"):
        detect_charuco([img[None]], "charuco.toml")
    with pytest.raises(TypeError, match="params: expected CharucoParams"):
        detect_charuco([img[None]], BOARD, params={"refine": "opencv"})
    with pytest.raises(ValueError, match="half"):
        symmetric_corners(img, [[10.0, 10.0]], half=1)
    with pytest.raises(FileNotFoundError, match="path"):
        read_charuco_toml(tmp_path / "none.toml")
    (tmp_path / "bad.toml").write_text('columns = 4\nrows = 5\n')
    with pytest.raises(ValueError, match="dictionary"):
        read_charuco_toml(tmp_path / "bad.toml")
    res = detect_charuco([img[None]], BOARD)
    with pytest.raises(ValueError, match="frames: expected 1 frame numbers"):
        res.board_points(frames=[1, 2])
    assert isinstance(res, CharucoCorners) and not res.xy.flags.writeable


def test_caliscope_board_file_and_frame_times():
    board = read_charuco_toml(CALISCOPE_DIR / "charuco.toml")
    assert (board.columns, board.rows, board.dictionary) == (4, 5, "DICT_4X4_1000")
    assert board.square_mm == pytest.approx(54.0) and board.marker_mm == pytest.approx(40.5)
    assert board.inverted and not board.legacy_pattern
    # OpenCV's pattern changed in 4.6.0 only for an even number of rows: with 5 rows the
    # legacy and the new layout are one board, so the detections cannot tell them apart
    legacy = CharucoBoard(columns=4, rows=5, square_mm=54.0, marker_mm=40.5,
                          dictionary="DICT_4X4_1000", legacy_pattern=True)
    np.testing.assert_array_equal(legacy.image(40), CharucoBoard(
        columns=4, rows=5, square_mm=54.0, marker_mm=40.5, dictionary="DICT_4X4_1000").image(40))
    times = read_caliscope_times(CALISCOPE_DIR / "videos" / "timestamps.csv")
    assert times.seconds.shape == (4, 48) and list(times.frames[:2]) == [416, 417]
    assert 0.005 < np.median(times.spread) < 0.010                      # s
    assert np.median(np.diff(times.seconds, axis=1)) == pytest.approx(1 / 6, rel=0.01)


def test_real_frames_match_caliscope_corners():
    """Two frames of each of caliscope's videos: our detection with caliscope's refinement
    lands on its xy.csv (the videos are re-encoded: 0.1 px, not 0)."""
    board = read_charuco_toml(CALISCOPE_DIR / "charuco.toml")
    ref = read_caliscope_points(CALISCOPE_DIR / "xy.csv")
    frames = [30, 31]
    images = []
    for k in range(4):
        cap = cv2.VideoCapture(str(CALISCOPE_DIR / "videos" / f"cam_{k}.mp4"))
        cap.set(cv2.CAP_PROP_POS_FRAMES, frames[0])
        images.append(np.stack([cv2.cvtColor(cap.read()[1], cv2.COLOR_BGR2GRAY) for _ in frames]))
        cap.release()
    res = detect_charuco(images, board, params=CALISCOPE)
    assert res.mirrored[1].all() and not res.mirrored[[0, 2, 3]].any()   # camera 1: from behind
    xy = np.array(res.xy)
    xy[res.mirrored, :, 0] += 1.0                             # caliscope writes W - x'
    d = np.linalg.norm(xy - ref.xy[:, frames], axis=-1)
    assert np.nanmedian(d) < 0.15 and np.isfinite(d).sum() >= 30
