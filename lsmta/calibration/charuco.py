"""ChArUco board corners detected in video frames (OpenCV's ``cv2.aruco.CharucoDetector``).

A ChArUco board is a chessboard whose white squares carry ArUco markers: the markers name
the squares, so every inner corner of the chessboard is identified even when the board is
only partly seen. Per image:

1. the image is inverted where the board is printed inverted (white markers on black, as
   caliscope's ``inverted = true``);
2. OpenCV's ``CharucoDetector.detectBoard`` finds the markers, interpolates the inner
   corners next to them (by a local homography of the markers, no camera model) and
   refines each with ``cv2.cornerSubPix`` -- the point ``q`` where the image gradients of
   a window are orthogonal to the lines to it,
   :math:`\\sum_i \\nabla I(x_i) \\nabla I(x_i)^T (x_i - q) = 0` -- in a window that
   stops 2 px short of the nearest marker corner (at most 21 x 21 px) and in steps down to
   0.1 px;
3. the corners are refined (``params.refine``): by default (ours) by the point symmetry of
   a chessboard corner's neighbourhood, least squares matching of the image against its
   own reflection about the corner (:mod:`lsmta.matching.symmetry`), which edges that are
   symmetric about the corner -- the markers' black frames -- do not pull; or (caliscope's,
   :data:`CALISCOPE`) a second ``cornerSubPix`` in a fixed 23 x 23 px window, which the
   markers' edges do pull once they are inside it;
4. a board seen from behind (through glass or thin paper) appears mirrored and its markers
   do not decode; with ``mirror="auto"`` (caliscope's rule) a frame where the plain image
   yields nothing is searched again in its mirror image, and a corner found at ``x'`` there
   is at ``x = W - 1 - x'`` in the frame (OpenCV's pixel-centre convention; caliscope writes
   ``W - x``, one pixel to the right).

Corner ``c`` is OpenCV's (and caliscope's) charuco id: row-major over the
``(columns - 1) x (rows - 1)`` inner corners, at ``((c mod (columns - 1)) + 1,
(c div (columns - 1)) + 1)`` squares on the board. The result feeds
:func:`lsmta.calibration.board.calibrate_board` (``xy``, ``board``) as
:func:`lsmta.io.read_caliscope_points` does.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm.auto import tqdm

from .._validate import as_int, as_scalar, freeze, pack_windows
from ..camera_files import tomllib
from ..io import BoardPoints
from ..matching.symmetry import symmetric_corners

MIRROR = ("never", "auto", "always")
REFINE = ("symmetry", "opencv", "subpix")
_CM_PER_INCH = 2.54


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board as printed.

    Attributes
    ----------
    columns, rows : int
        Squares across and down (``>= 2``); the board has ``(columns - 1) * (rows - 1)``
        inner corners.
    square_mm : float
        Side of a square, mm (as printed: measure it).
    marker_mm : float
        Side of an ArUco marker, mm (``< square_mm``).
    dictionary : str
        OpenCV's name of the marker dictionary, e.g. ``"DICT_4X4_1000"``.
    legacy_pattern : bool
        OpenCV's layout before 4.6.0 (it differs only for an even number of rows).
    inverted : bool
        Printed inverted (white markers on black squares).
    """

    columns: int
    rows: int
    square_mm: float
    marker_mm: float
    dictionary: str = "DICT_4X4_50"
    legacy_pattern: bool = False
    inverted: bool = False

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "columns", as_int(self.columns, "columns", minimum=2, unit="squares"))
        set_(self, "rows", as_int(self.rows, "rows", minimum=2, unit="squares"))
        set_(self, "square_mm", as_scalar(self.square_mm, "square_mm", positive=True))
        set_(self, "marker_mm", as_scalar(self.marker_mm, "marker_mm", positive=True))
        if self.marker_mm >= self.square_mm:
            raise ValueError(f"marker_mm: expected a marker smaller than its square "
                             f"({self.square_mm} mm), got {self.marker_mm}")
        names = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        if not isinstance(self.dictionary, str) or self.dictionary not in names:
            raise ValueError(f"dictionary: expected an OpenCV ArUco dictionary name such as "
                             f"'DICT_4X4_1000' (one of {names}), got {self.dictionary!r}")
        for name in ("legacy_pattern", "inverted"):
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise TypeError(f"{name}: expected True or False, got "
                                f"{getattr(self, name)!r}")
            set_(self, name, bool(getattr(self, name)))

    @property
    def n_corners(self) -> int:
        return (self.columns - 1) * (self.rows - 1)

    @property
    def corners(self) -> np.ndarray:
        """``(C, 3)`` the inner corners on the board, mm (z = 0), in charuco id order."""
        c = np.arange(self.n_corners)
        i, j = c % (self.columns - 1) + 1, c // (self.columns - 1) + 1
        return np.stack([i, j, np.zeros_like(i)], axis=1) * self.square_mm

    def opencv(self):
        """The board as OpenCV's ``cv2.aruco.CharucoBoard`` (lengths in metres)."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        board = cv2.aruco.CharucoBoard((self.columns, self.rows), self.square_mm / 1000.0,
                                       self.marker_mm / 1000.0, dictionary)
        board.setLegacyPattern(self.legacy_pattern)
        return board

    def image(self, px_per_square: int, *, margin: int = 0) -> np.ndarray:
        """The board drawn by OpenCV, ``(rows s + 2 m, columns s + 2 m)`` uint8 with
        ``s = px_per_square`` and ``m = margin`` (white, or black when inverted); corner
        ``c`` is at ``m - 0.5 + s * (i, j)`` px for its square indices ``(i, j)``."""
        s = as_int(px_per_square, "px_per_square", minimum=4, unit="pixels")
        m = as_int(margin, "margin", minimum=0, unit="pixels")
        size = (self.columns * s + 2 * m, self.rows * s + 2 * m)
        img = self.opencv().generateImage(size, marginSize=m, borderBits=1)
        return 255 - img if self.inverted else img


def read_charuco_toml(path) -> CharucoBoard:
    """A board from caliscope's ``charuco.toml``.

    Keys: ``columns``, ``rows``, ``dictionary``, ``units`` (``"inch"`` or ``"cm"``),
    ``board_width``, ``board_height`` (the paper), ``aruco_scale`` (marker / square),
    ``square_size_override_cm`` (the square as printed; without it caliscope takes the
    largest square that fits the paper), ``inverted``, ``legacy_pattern``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no charuco file at {path}")
    with open(path, "rb") as fh:
        d = tomllib.load(fh)
    lacking = [k for k in ("columns", "rows", "dictionary") if k not in d]
    if lacking:
        raise ValueError(f"path: {path} lacks the keys {lacking}")
    if d.get("square_size_override_cm"):
        square_cm = float(d["square_size_override_cm"])
    else:
        units = d.get("units", "inch")
        if units not in ("inch", "cm"):
            raise ValueError(f"path: units in {path} must be 'inch' or 'cm', got {units!r}")
        scale = _CM_PER_INCH if units == "inch" else 1.0
        square_cm = min(float(d["board_height"]) * scale / d["rows"],
                        float(d["board_width"]) * scale / d["columns"])
    return CharucoBoard(columns=d["columns"], rows=d["rows"], square_mm=10 * square_cm,
                        marker_mm=10 * square_cm * float(d.get("aruco_scale", 0.75)),
                        dictionary=d["dictionary"],
                        legacy_pattern=bool(d.get("legacy_pattern", False)),
                        inverted=bool(d.get("inverted", False)))


@dataclass(frozen=True)
class CharucoParams:
    """Settings of :func:`detect_charuco` and :func:`refine_corners`.

    Attributes
    ----------
    refine : {"symmetry", "opencv", "subpix"}
        The corners' final positions: ``"symmetry"`` (ours) the point-symmetry fit of
        :func:`lsmta.matching.symmetry.symmetric_corners` from OpenCV's positions, in a
        window that stays inside the board's symmetric neighbourhood of the corner (the
        square's inset plus the markers' black frame, 80 % of it, 2..10 px: see
        :func:`symmetry_windows`); ``"opencv"`` OpenCV's positions as they come (its
        ``cornerSubPix`` in windows 2 px short of the nearest marker corner, stopped at
        0.1 px steps); ``"subpix"`` a second ``cv2.cornerSubPix`` in a fixed window
        (caliscope's: :data:`CALISCOPE`).
    subpix_window : int
        Half-size ``w`` of the ``"subpix"`` window, px (``2 w + 1`` square; caliscope's 11
        reaches the markers' edges once a square is smaller than about 90 px in the image,
        and they pull the corner: notebook 19).
    subpix_iterations : int
        Iteration limit of ``cornerSubPix``.
    subpix_eps : float
        Its convergence limit, px.
    mirror : {"never", "auto", "always"}
        Search the mirror image: never, where the plain image yields nothing, or only.
        With ``"auto"``, a camera whose previous frame was found mirrored is searched
        mirrored first (a board is found in one orientation only: in the other its
        markers do not decode in the board's layout).
    min_markers : int
        Markers a frame needs for its corners to count (caliscope: 4).
    """

    refine: str = "symmetry"
    subpix_window: int = 11
    subpix_iterations: int = 30
    subpix_eps: float = 1e-4
    mirror: str = "auto"
    min_markers: int = 4

    def __post_init__(self):
        set_ = object.__setattr__
        if self.refine not in REFINE:
            raise ValueError(f"refine: expected one of {list(REFINE)}, got {self.refine!r}")
        set_(self, "subpix_window", as_int(self.subpix_window, "subpix_window",
                                           unit="pixels"))
        set_(self, "subpix_iterations", as_int(self.subpix_iterations, "subpix_iterations",
                                               unit="iterations"))
        set_(self, "subpix_eps", as_scalar(self.subpix_eps, "subpix_eps", positive=True))
        set_(self, "min_markers", as_int(self.min_markers, "min_markers", unit="markers"))
        if self.mirror not in MIRROR:
            raise ValueError(f"mirror: expected one of {list(MIRROR)}, got {self.mirror!r}")


# caliscope's detector: a second cornerSubPix in a 23 x 23 window on OpenCV's corners
CALISCOPE = CharucoParams(refine="subpix", subpix_window=11)


@dataclass(frozen=True, eq=False)
class CharucoCorners:
    """ChArUco corners found in K cameras' frames.

    Attributes
    ----------
    xy : (K, F, C, 2) array
        Image position of corner ``c`` (charuco id) in frame ``f`` of camera ``k``, px
        (origin at the centre of the top-left pixel, as OpenCV); NaN where not found.
    board : (C, 3) array
        The corners on the board, mm (z = 0).
    markers : (K, F) int array
        ArUco markers found in the frame (in the image the corners came from).
    mirrored : (K, F) bool array
        The corners came from the frame's mirror image.
    refine : str
        How the positions were refined (:class:`CharucoParams`).
    refined : (K, F, C) bool array
        The refinement succeeded (elsewhere a found corner keeps OpenCV's position).
    """

    xy: np.ndarray
    board: np.ndarray
    markers: np.ndarray
    mirrored: np.ndarray
    refine: str
    refined: np.ndarray

    def __post_init__(self):
        freeze(self, ("xy", "board", "markers", "mirrored", "refined"))

    @property
    def found(self) -> np.ndarray:
        """``(K, F)`` corners found per camera and frame."""
        return np.isfinite(self.xy[..., 0]).sum(axis=-1)

    def board_points(self, *, frames=None, camera_ids=None) -> BoardPoints:
        """The corners as :class:`lsmta.io.BoardPoints` (what
        :func:`~lsmta.io.read_caliscope_points` returns): ``frames`` are the F frames'
        numbers (default ``0 .. F-1``; caliscope's ``sync_index``), ``camera_ids`` the K
        cameras' (default ``0 .. K-1``)."""
        K, F = self.xy.shape[:2]
        frames = np.arange(F) if frames is None else np.asarray(frames, dtype=int)
        ids = np.arange(K) if camera_ids is None else np.asarray(camera_ids, dtype=int)
        if frames.shape != (F,):
            raise ValueError(f"frames: expected {F} frame numbers, got shape {frames.shape}")
        if ids.shape != (K,):
            raise ValueError(f"camera_ids: expected {K} camera numbers, got shape {ids.shape}")
        return BoardPoints(xy=np.array(self.xy), board=np.array(self.board), frames=frames,
                           camera_ids=ids)


def detect_charuco(images, board: CharucoBoard, *, params: CharucoParams | None = None,
                   progress: bool = False) -> CharucoCorners:
    """Find a ChArUco board's corners in every frame of K cameras (see the module notes).

    Parameters
    ----------
    images : (K, T, H, W) uint8 array, or sequence of K (T, H_k, W_k) uint8 arrays
        Grey frames (``lsmta.io.Videos.load()`` gives them); cameras may differ in size
        but not in frame count. A single image is ``[image[None]]``.
    board : CharucoBoard
    params : CharucoParams, optional
    progress : bool
        Show a progress bar over the cameras' frames.

    Returns
    -------
    CharucoCorners
    """
    board, p = _check_board(board), _check_params(params)
    stacks = _grey_stacks(images)
    K, T = len(stacks), len(stacks[0])
    detector = cv2.aruco.CharucoDetector(board.opencv())
    xy = np.full((K, T, board.n_corners, 2), np.nan)
    markers = np.zeros((K, T), int)
    mirrored = np.zeros((K, T), bool)
    bar = tqdm(total=K * T, desc="ChArUco corners", unit="frame", disable=not progress)
    for k, stack in enumerate(stacks):
        for t in range(T):
            first = p.mirror == "auto" and t > 0 and mirrored[k, t - 1]
            ids, pts, markers[k, t], mirrored[k, t] = _detect_one(detector, stack[t], board,
                                                                  p, mirrored_first=first)
            xy[k, t, ids] = pts
            bar.update()
    bar.close()
    found = CharucoCorners(xy=xy, board=board.corners, markers=markers, mirrored=mirrored,
                           refine="opencv", refined=np.isfinite(xy[..., 0]))
    return found if p.refine == "opencv" else _refined(stacks, found, board, p)


def refine_corners(images, corners: CharucoCorners, board: CharucoBoard, *,
                   params: CharucoParams | None = None) -> CharucoCorners:
    """OpenCV's corners (``detect_charuco(..., params=CharucoParams(refine="opencv"))``)
    refined as ``params.refine`` says, e.g. both ways from one detection.

    Both refinements commute with the mirror image and with inverting the grey values,
    so the frames are used as they are.

    Parameters
    ----------
    images : (K, T, H, W) uint8 array, or sequence of K (T, H_k, W_k) uint8 arrays
        The frames ``corners`` were found in.
    corners : CharucoCorners
        Found with ``refine="opencv"``.
    board : CharucoBoard
    params : CharucoParams, optional

    Returns
    -------
    CharucoCorners
        The same corners, moved.
    """
    board, p = _check_board(board), _check_params(params)
    if not isinstance(corners, CharucoCorners):
        raise TypeError(f"corners: expected CharucoCorners, got {type(corners).__name__}")
    if corners.refine != "opencv":
        raise ValueError(f"corners: expected OpenCV's corners (refine='opencv'), got corners "
                         f"already refined by {corners.refine!r}")
    stacks = _grey_stacks(images)
    K, F = corners.xy.shape[:2]
    if (len(stacks), len(stacks[0])) != (K, F) or corners.xy.shape[2] != board.n_corners:
        raise ValueError(f"images: expected the {K} cameras x {F} frames the corners of this "
                         f"board were found in, got {len(stacks)} x {len(stacks[0])}")
    return corners if p.refine == "opencv" else _refined(stacks, corners, board, p)


def symmetry_windows(xy, board: CharucoBoard) -> np.ndarray:
    """``(n,)`` half-sizes of the point-symmetry windows of the corners ``xy (n, 2)`` of
    one image: 80 % of the board's symmetric neighbourhood of a corner -- the square's
    inset ``(s - m) / 2`` plus one cell of the markers' black frame ``m / (b + 2)``
    (``s`` square, ``m`` marker, ``b`` bits per side) -- scaled by ``d / s`` with ``d`` the
    distance to the nearest other corner in the image, 2..10 px (3 for a lone corner)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(xy) < 2:
        return np.full(len(xy), 3)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    np.fill_diagonal(d, np.inf)
    bits = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board.dictionary)).markerSize
    zone = ((board.square_mm - board.marker_mm) / 2 + board.marker_mm / (bits + 2)) \
        / board.square_mm
    return np.clip(np.floor(0.8 * zone * d.min(axis=1)), 2, 10).astype(int)


def _check_board(board) -> CharucoBoard:
    if not isinstance(board, CharucoBoard):
        raise TypeError(f"board: expected a CharucoBoard (see read_charuco_toml), got "
                        f"{type(board).__name__}")
    return board


def _check_params(params) -> CharucoParams:
    p = params or CharucoParams()
    if not isinstance(p, CharucoParams):
        raise TypeError(f"params: expected CharucoParams, got {type(p).__name__}")
    return p


def _grey_stacks(images) -> list:
    if isinstance(images, np.ndarray) and images.ndim != 4:
        raise ValueError(f"images: expected (K, T, H, W) grey frames or K (T, H, W) stacks, "
                         f"got shape {images.shape}; one camera's frames go in as [frames]")
    stacks = [np.asarray(s) for s in images]
    if not stacks:
        raise ValueError("images: expected at least one camera's frames")
    for k, s in enumerate(stacks):
        if s.dtype != np.uint8 or s.ndim != 3 or min(s.shape) < 1:
            raise ValueError(f"images[{k}]: expected a (T, H, W) uint8 stack of grey frames, "
                             f"got shape {s.shape} and dtype {s.dtype}")
    counts = [len(s) for s in stacks]
    if len(set(counts)) != 1:
        raise ValueError(f"images: the cameras hold different numbers of frames {counts}")
    return stacks


def _detect_one(detector, image, board: CharucoBoard, p: CharucoParams, *,
                mirrored_first: bool = False):
    """One grey frame: ``(ids, xy (n, 2), markers, mirrored)`` in the frame's pixels."""
    grey = 255 - image if board.inverted else image
    tries = {"never": (False,), "auto": (False, True), "always": (True,)}[p.mirror]
    if mirrored_first:
        tries = tries[::-1]
    for mirror in tries:
        g = np.ascontiguousarray(grey[:, ::-1]) if mirror else grey
        corners, ids, _, marker_ids = detector.detectBoard(g)
        n_markers = 0 if marker_ids is None else len(marker_ids)
        if ids is None or len(ids) == 0 or n_markers < p.min_markers:
            continue
        pts = corners.reshape(-1, 2).astype(float)
        if mirror:
            pts[:, 0] = g.shape[1] - 1 - pts[:, 0]
        return np.asarray(ids).ravel().astype(int), pts, n_markers, mirror
    return np.zeros(0, int), np.zeros((0, 2)), 0, False


def _refined(stacks, corners: CharucoCorners, board: CharucoBoard,
             p: CharucoParams) -> CharucoCorners:
    """OpenCV's corners moved by ``p.refine`` (failures keep theirs)."""
    xy = np.array(corners.xy)
    refined = np.zeros(xy.shape[:3], bool)
    if p.refine == "subpix":
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, p.subpix_iterations,
                p.subpix_eps)
        w = (p.subpix_window, p.subpix_window)
        for k, f in zip(*np.nonzero(np.isfinite(xy[..., 0]).any(axis=-1))):
            m = np.flatnonzero(np.isfinite(xy[k, f, :, 0]))
            start = np.ascontiguousarray(xy[k, f, m], dtype=np.float32).reshape(-1, 1, 2)
            xy[k, f, m] = cv2.cornerSubPix(stacks[k][f], start, w, (-1, -1), crit).reshape(-1, 2)
            refined[k, f, m] = True
    else:
        _symmetric(stacks, xy, refined, board)
    return CharucoCorners(xy=xy, board=corners.board, markers=corners.markers,
                          mirrored=corners.mirrored, refine=p.refine, refined=refined)


def _symmetric(stacks, xy, refined, board: CharucoBoard) -> None:
    """The point-symmetry fit of every frame's corners in one call: the frames' windows
    (their corners plus the largest window and shift, 23 px) side by side in a mosaic."""
    frames = list(zip(*np.nonzero(np.isfinite(xy[..., 0]).any(axis=-1))))
    if not frames:
        return
    reach = 23
    windows, rows, halves = [], [], []
    for k, f in frames:
        m = np.flatnonzero(np.isfinite(xy[k, f, :, 0]))
        H, W = stacks[k].shape[1:]
        lo = np.maximum(np.floor(xy[k, f, m].min(axis=0)).astype(int) - reach, 0)
        hi = np.minimum(np.ceil(xy[k, f, m].max(axis=0)).astype(int) + reach + 1, [W, H])
        windows.append(np.concatenate([lo, hi]))
        rows.append(m)
        halves.append(symmetry_windows(xy[k, f, m], board))
    places, (W, H) = pack_windows([w[2:] - w[:2] for w in windows])
    mosaic = np.zeros((H, W), np.uint8)
    starts = []
    for (k, f), w, m, o in zip(frames, windows, rows, places):
        mosaic[o[1]:o[1] + w[3] - w[1], o[0]:o[0] + w[2] - w[0]] = stacks[k][f, w[1]:w[3],
                                                                          w[0]:w[2]]
        starts.append(xy[k, f, m] - w[:2] + o)
    fit = symmetric_corners(mosaic, np.concatenate(starts), half=np.concatenate(halves))
    i = 0
    for (k, f), w, m, o in zip(frames, windows, rows, places):
        ok = fit.ok[i:i + len(m)]
        xy[k, f, m[ok]] = fit.xy[i:i + len(m)][ok] - o + w[:2]
        refined[k, f, m[ok]] = True
        i += len(m)
