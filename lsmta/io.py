"""Reading marker data (C3D files through ezc3d, Maya ASCII animation curves), 2-D point
files (DLTdv / Argus xypts CSV, caliscope's board corners and frame times), a Qualisys
calibration, one video's frames and a multi-camera recording's videos (OpenCV, decoded as
needed). The project's own recordings under ``data/`` are loaded by :mod:`lsmta.data`."""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import ezc3d
import numpy as np
from tqdm.auto import tqdm

from ._validate import as_array, as_int, as_scalar
from .camera import Camera, cropped_camera, scaled_camera
from .camera_files import read_qca

_UNIT_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}


@dataclass(frozen=True)
class MarkerData:
    """Labelled marker trajectories.

    Attributes
    ----------
    labels : tuple of str, length M
    points : (T, M, 3) array
        Positions, mm; NaN where a marker is missing (a gap).
    rate : float
        Frames per second.

    Unpacks as ``labels, points, rate = read_c3d(path)``.
    """

    labels: tuple
    points: np.ndarray
    rate: float

    def __iter__(self):
        return iter((self.labels, self.points, self.rate))


def read_c3d(path) -> MarkerData:
    """Read the 3-D points of a C3D file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    MarkerData
        Labels, (T, M, 3) points in mm (converted from the file's POINT:UNITS; a gap,
        which C3D marks by a negative residual or NaN in any coordinate, becomes a NaN
        point) and the frame rate.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no C3D file at {path}")
    c = ezc3d.c3d(str(path))
    point = c["parameters"]["POINT"]
    labels = tuple(str(s).strip() for s in point["LABELS"]["value"])
    units = point.get("UNITS", {}).get("value", ["mm"])
    unit = (units[0] if len(units) else "mm").strip().lower() or "mm"
    if unit not in _UNIT_TO_MM:
        raise ValueError(f"path: unknown POINT:UNITS {unit!r} in {path}")
    xyz = np.array(c["data"]["points"][:3], dtype=float).transpose(2, 1, 0) * _UNIT_TO_MM[unit]
    residuals = c["data"].get("meta_points", {}).get("residuals")
    if residuals is not None:
        xyz[np.asarray(residuals)[0].T < 0] = np.nan
    xyz[np.isnan(xyz).any(axis=2)] = np.nan          # a gap is a whole point
    rate = float(np.ravel(point["RATE"]["value"])[0])
    return MarkerData(labels=labels[: xyz.shape[1]], points=xyz, rate=rate)


_MAYA_LINEAR_TO_MM = {"mm": 1.0, "millimeter": 1.0, "cm": 10.0, "centimeter": 10.0,
                      "m": 1000.0, "meter": 1000.0, "in": 25.4, "inch": 25.4}


@dataclass(frozen=True)
class MayaCurves:
    """Marker trajectories read from Maya ``animCurveTL`` nodes.

    Attributes
    ----------
    labels : tuple of str, length M
        Marker names (node names without ``_translateX``), in file order.
    points : (T, M, 3) array
        Positions, mm; NaN where a marker has no key at a time.
    times : (T,) array
        Key times in the file's time unit (sorted union of all keys).

    Unpacks as ``labels, points, times = read_maya_curves(path)``.
    """

    labels: tuple
    points: np.ndarray
    times: np.ndarray

    def __iter__(self):
        return iter((self.labels, self.points, self.times))


def read_maya_curves(path) -> MayaCurves:
    """Read marker trajectories stored as Maya ASCII translate animation curves.

    Every ``createNode animCurveTL -n "<Marker>_translateX"`` (and ``Y``, ``Z``) node's
    ``.ktv`` attribute lists ``time value`` key pairs; a marker needs all three axes. The
    linear unit comes from the file's ``currentUnit -l`` line (centimetres by default in
    Maya) and is converted to mm. Only the keys are read: no tangents, no scene
    transforms.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    MayaCurves
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no Maya ASCII file at {path}")
    text = path.read_text(encoding="utf-8", errors="replace")
    unit_match = re.search(r"currentUnit\s+-l\s+(\w+)", text)
    unit = unit_match.group(1).lower() if unit_match else "centimeter"
    if unit not in _MAYA_LINEAR_TO_MM:
        raise ValueError(f"path: unknown Maya linear unit {unit!r} in {path}")
    scale = _MAYA_LINEAR_TO_MM[unit]
    curves: dict[tuple[str, int], dict[float, float]] = {}
    order: list[str] = []
    nodes = re.split(r"^createNode\s+", text, flags=re.MULTILINE)
    for node in nodes[1:]:
        head = re.match(r'animCurveTL\s+-n\s+"([^"]+)_translate([XYZ])"', node)
        if not head:
            continue
        name, axis = head.group(1), "XYZ".index(head.group(2))
        keys: dict[float, float] = {}
        for m in re.finditer(r'setAttr\s+"\.ktv\[[^\]]*\]"\s+([^;]*);', node):
            vals = np.array(m.group(1).split(), dtype=float)
            if len(vals) % 2:
                raise ValueError(f"path: odd number of values in a .ktv list of {name}")
            keys.update(zip(vals[0::2].tolist(), vals[1::2].tolist()))
        curves[(name, axis)] = keys
        if name not in order:
            order.append(name)
    labels = tuple(n for n in order if all((n, a) in curves for a in range(3)))
    if not labels:
        raise ValueError(f"path: no complete <Marker>_translateX/Y/Z animCurveTL nodes in "
                         f"{path}")
    times = np.array(sorted({t for n in labels for a in range(3) for t in curves[(n, a)]}))
    index = {t: i for i, t in enumerate(times.tolist())}
    pts = np.full((len(times), len(labels), 3), np.nan)
    for j, n in enumerate(labels):
        for a in range(3):
            k = curves[(n, a)]
            pts[[index[t] for t in k], j, a] = np.fromiter(k.values(), float, len(k)) * scale
    pts[np.isnan(pts).any(axis=2)] = np.nan
    return MayaCurves(labels=labels, points=pts, times=times)


# ---------------------------------------------------------------------- Qualisys
def read_qualisys_calibration(path) -> list:
    """The cameras of a Qualisys (QTM) calibration file, ``.qca`` / ``.qca.txt`` (XML).

    The documented entry point for Qualisys calibrations; the parser is
    :func:`lsmta.camera_files.read_qca`, whose docstring gives the conventions (rotation
    rows as camera axes turned to this project's y-down camera, intrinsics in sensor units
    of 64 per pixel, the video window's offset, Brown distortion read as it stands:
    Pose2Sim's converter divides the distortion by 64, this reader does not).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    list of :class:`~lsmta.camera.Camera`
        One per ``<camera>``, in the file's order, named by its ``serial``; millimetres.
    """
    return read_qca(path)


# ---------------------------------------------------------------------- video
def read_video(path, *, scale: float = 1.0, frames: int | None = None):
    """A video's frames as grey ``(T, H, W)`` uint8 (scaled by ``scale``, area
    interpolation), its frame 0 in colour (BGR, full size) and its frame rate."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no video at {path}")
    scale = as_scalar(scale, "scale", positive=True)
    cap = cv2.VideoCapture(str(path))
    fps = float(cap.get(cv2.CAP_PROP_FPS))
    grey, first = [], None
    while frames is None or len(grey) < frames:
        ok, f = cap.read()
        if not ok:
            break
        first = f if first is None else first
        g = cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)
        if scale != 1.0:
            g = cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        grey.append(g)
    cap.release()
    if not grey:
        raise ValueError(f"path: {path} holds no frame OpenCV can decode")
    return np.stack(grey), first, fps


# ---------------------------------------------------------------------- 2-D point files
_XYPTS_COLUMN = re.compile(r"^(?P<point>.+?)_cam_?(?P<camera>\d+)_(?P<axis>[XYxy])$")
_SPARSE_SHAPE = re.compile(r"^\s*\d+\t\d+\t\d+\s*$")


def _image_heights(image_heights, n_cameras: int) -> np.ndarray:
    h = np.asarray(image_heights, dtype=float)
    h = np.broadcast_to(h, (n_cameras,)) if h.ndim == 0 else h
    if h.shape != (n_cameras,) or not np.all(np.isfinite(h)) or np.any(h < 1) \
            or np.any(h != np.round(h)):
        raise ValueError(f"image_heights: expected one positive whole number of pixels or "
                         f"{n_cameras} of them, got {image_heights!r}")
    return h


def read_xypts(path, n_cameras: int, *, image_heights, flip_y: bool = True) -> np.ndarray:
    """Read a DLTdv / Argus "xypts" CSV of digitised 2-D points.

    The file has a header row and one row per frame; its columns are ``pt1_cam1_X,
    pt1_cam1_Y, pt1_cam2_X, ...`` (DLTdv; Argus writes ``<track>_cam_1_x``): for every point
    the x and y of every camera. An unseen point is ``NaN`` (DLTdv's ``%f`` of a NaN,
    pandas' ``na_rep="NaN"`` in Argus) or an empty cell. The *sparse* form DLTdv 8 and
    Argus write for long videos (``*-xypts.tsv``) is read too: the header, a line
    ``frames<TAB>columns<TAB>count``, then one ``frame<TAB>column<TAB>value`` line (1-based)
    per stored value; a cell not listed is unseen (DLTdv stores NaN as an absent zero).

    easyWand's wand file and Argus' paired points are such a file with two points (the
    wand's ends): ``(K, T, 2, 2)``, what :func:`~lsmta.calibration.calibrate_wand` takes.
    Background (unpaired) points are one or more tracks whose every frame is another
    point; :func:`~lsmta.calibration.calibrate_wand` takes the ``(K, T, P, 2)`` array as
    it is (``tie_xy``) and drops the rows seen by one camera.

    DLTdv and Argus measure y *upwards from the bottom edge* of the image; this project
    (like OpenCV) measures it downwards from the top. With ``flip_y`` the reader converts::

        y = H_k - y_file

    for camera k of height ``H_k`` px; x is kept. Argus writes ``H - y`` of its top-left
    coordinates, which this reverses exactly. A constant shift of a tool's pixel origin
    (MATLAB numbers pixel centres from 1) moves all of a camera's points alike; a
    self-calibration absorbs it in the principal point.

    Parameters
    ----------
    path : str or Path
    n_cameras : int
        K; the file's camera numbers must be 1..K.
    image_heights : int or sequence of K ints
        Image heights in pixels (needed for the flip; ignored without it).
    flip_y : bool
        Convert y from the bottom-left origin (False: the file is already top-left).

    Returns
    -------
    (K, T, P, 2) array
        Pixel coordinates of P points in T frames per camera, this project's convention;
        NaN where unseen.

    Raises
    ------
    ValueError
        A header that is not of this form, cameras other than 1..K, a point without both
        coordinates of every camera, or a row of the wrong length.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no xypts file at {path}")
    K = as_int(n_cameras, "n_cameras")
    heights = _image_heights(image_heights, K) if flip_y else None
    with open(path, newline="", encoding="utf-8-sig") as fh:
        lines = [ln for ln in fh.read().splitlines() if ln.strip()]
    if not lines:
        raise ValueError(f"path: {path} is empty")
    sparse = len(lines) > 1 and _SPARSE_SHAPE.match(lines[1]) is not None
    delimiter = "\t" if sparse or ("\t" in lines[0] and "," not in lines[0]) else ","
    header = [c.strip() for c in next(csv.reader([lines[0]], delimiter=delimiter))]
    points, slots = _xypts_columns(header, K, path)
    if sparse:
        values = _xypts_sparse(lines[1:], header, path)
    else:
        values = _xypts_values(list(csv.reader(lines[1:], delimiter=delimiter)), header,
                               path)
    xy = np.full((K, len(values), len(points), 2), np.nan)
    for i, p in enumerate(points):
        for k in range(K):
            xy[k, :, i, 0] = values[:, slots[(p, k, "X")]]
            xy[k, :, i, 1] = values[:, slots[(p, k, "Y")]]
    xy[np.isnan(xy).any(axis=-1)] = np.nan          # a point is seen with both coordinates
    if flip_y:
        xy[..., 1] = heights[:, None, None] - xy[..., 1]
    return xy


def _xypts_columns(header, K: int, path) -> tuple[list, dict]:
    """The points named by an xypts header, in order, and the column of each
    ``(point, camera index, "X" | "Y")``; every point needs both coordinates of every
    camera."""
    points: list[str] = []
    slots = {}
    for j, name in enumerate(header):
        m = _XYPTS_COLUMN.match(name)
        if m is None:
            raise ValueError(f"path: column {j + 1} of {path} is {name!r}; expected "
                             "<point>_cam<k>_X or <point>_cam<k>_Y (DLTdv / Argus xypts)")
        cam = int(m["camera"])
        if not 1 <= cam <= K:
            raise ValueError(f"n_cameras: the file names camera {cam}, outside 1..{K}")
        if m["point"] not in points:
            points.append(m["point"])
        slots[(m["point"], cam - 1, m["axis"].upper())] = j
    missing = [f"{p}_cam{k + 1}_{a}" for p in points for k in range(K) for a in "XY"
               if (p, k, a) not in slots]
    if missing:
        raise ValueError(f"path: {path} lacks the columns {missing[:4]}"
                         + (" ..." if len(missing) > 4 else ""))
    return points, slots


def _xypts_values(rows, header, path) -> np.ndarray:
    """The cells of the data rows as numbers ``(T, columns)``: NaN for an empty or ``NaN``
    cell."""
    values = np.full((len(rows), len(header)), np.nan)
    for t, row in enumerate(rows):
        if len(row) != len(header):
            raise ValueError(f"path: row {t + 2} of {path} has {len(row)} cells; the header "
                             f"has {len(header)}")
        for j, cell in enumerate(row):
            cell = cell.strip()
            if cell and cell.lower() != "nan":
                try:
                    values[t, j] = float(cell)
                except ValueError:
                    raise ValueError(f"path: row {t + 2}, column {header[j]} of {path} is "
                                     f"{cell!r}, not a number") from None
    return values


def _xypts_sparse(lines, header, path) -> np.ndarray:
    """The sparse form (DLTdv 8, Argus ``.tsv``): ``frames columns count``, then 1-based
    ``frame column value`` lines; cells not listed are NaN."""
    T, n_cols, count = (int(v) for v in lines[0].split())
    if n_cols != len(header):
        raise ValueError(f"path: {path} says {n_cols} columns; its header has {len(header)}")
    values = np.full((T, n_cols), np.nan)
    body = lines[1:]
    if len(body) != count:
        raise ValueError(f"path: {path} says {count} values and lists {len(body)}")
    for i, line in enumerate(body):
        cells = line.split("\t")
        try:
            t, j, v = int(cells[0]), int(cells[1]), float(cells[2])
        except (ValueError, IndexError):
            raise ValueError(f"path: line {i + 3} of {path} is {line!r}, not "
                             "frame<TAB>column<TAB>value") from None
        if not (1 <= t <= T and 1 <= j <= n_cols):
            raise ValueError(f"path: line {i + 3} of {path} names frame {t}, column {j}; "
                             f"expected 1..{T}, 1..{n_cols}")
        values[t - 1, j - 1] = v
    return values


def write_xypts(path, xy, *, image_heights, flip_y: bool = True) -> Path:
    """Write ``(K, T, P, 2)`` pixel coordinates as a DLTdv xypts CSV (the inverse of
    :func:`read_xypts`: header ``pt1_cam1_X, pt1_cam1_Y, ...``, y flipped to the bottom-left
    origin with ``flip_y``, ``NaN`` where unseen, numbers written to round-trip exactly)."""
    xy = as_array(xy, "xy", shape=(None, None, None, 2), allow_nan=True)
    K, T, P, _ = xy.shape
    out = xy.copy()
    if flip_y:
        out[..., 1] = _image_heights(image_heights, K)[:, None, None] - out[..., 1]
    header = [f"pt{p + 1}_cam{k + 1}_{a}" for p in range(P) for k in range(K) for a in "XY"]
    table = out.transpose(1, 2, 0, 3).reshape(T, -1)       # (T, P*K*2) in header order
    path = Path(path)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(",".join(header) + "\n")
        for row in table:
            fh.write(",".join("NaN" if np.isnan(v) else repr(float(v)) for v in row) + "\n")
    return path


@dataclass(frozen=True)
class BoardPoints:
    """Corners of a calibration board seen by K cameras in F synchronised frames.

    Attributes
    ----------
    xy : (K, F, C, 2) array
        Image positions of the C corners, px (top-left origin); NaN where not detected.
    board : (C, 3) array
        The corners' coordinates on the board, mm (z = 0: a plane board).
    frames : (F,) int array
        The recording's frame (synchronisation) numbers.
    camera_ids : (K,) int array
        The recording's camera numbers, in the order of ``xy``.
    """

    xy: np.ndarray
    board: np.ndarray
    frames: np.ndarray
    camera_ids: np.ndarray

    @property
    def n_observations(self) -> int:
        return int(np.isfinite(self.xy[..., 0]).sum())


def _csv_columns(path: Path, need: tuple, what: str) -> np.ndarray:
    """The ``need`` columns of a CSV file as a float array ``(rows, len(need))``."""
    with open(path, newline="", encoding="utf-8-sig") as fh:
        reader = csv.DictReader(fh)
        lacking = [c for c in need if c not in (reader.fieldnames or ())]
        if lacking:
            raise ValueError(f"path: {path} lacks the columns {lacking}")
        rows = [[float(r[c]) for c in need] for r in reader]
    if not rows:
        raise ValueError(f"path: {path} has no {what}")
    return np.array(rows)


def read_caliscope_points(path, *, unit: str = "m") -> BoardPoints:
    """Read the board corners of a caliscope recording (its ``xy.csv``).

    One row per detected corner: ``sync_index`` (synchronised frame), ``cam_id``,
    ``keypoint_id`` (the corner), ``img_loc_x, img_loc_y`` (px, top-left origin, as
    OpenCV) and ``obj_loc_x, obj_loc_y`` (the corner on the board, in ``unit``; the board
    is plane, z = 0). The board coordinates of each corner must agree between rows.

    Parameters
    ----------
    path : str or Path
    unit : {"mm", "cm", "m"}
        Unit of the board coordinates (caliscope writes metres).

    Returns
    -------
    BoardPoints
        Board coordinates converted to mm.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no caliscope point file at {path}")
    if unit not in _UNIT_TO_MM:
        raise ValueError(f"unit: expected one of {sorted(_UNIT_TO_MM)}, got {unit!r}")
    a = _csv_columns(path, ("sync_index", "cam_id", "keypoint_id", "img_loc_x", "img_loc_y",
                            "obj_loc_x", "obj_loc_y"), "corners")
    frames, f_idx = np.unique(a[:, 0].astype(int), return_inverse=True)
    cams, k_idx = np.unique(a[:, 1].astype(int), return_inverse=True)
    corners, c_idx = np.unique(a[:, 2].astype(int), return_inverse=True)
    board = np.zeros((len(corners), 3))
    board[c_idx, :2] = a[:, 5:7] * _UNIT_TO_MM[unit]
    if not np.allclose(board[c_idx, :2], a[:, 5:7] * _UNIT_TO_MM[unit], atol=1e-6):
        raise ValueError(f"path: a corner of {path} has different board coordinates in "
                         "different rows")
    xy = np.full((len(cams), len(frames), len(corners), 2), np.nan)
    xy[k_idx, f_idx, c_idx] = a[:, 3:5]
    return BoardPoints(xy=xy, board=board, frames=frames, camera_ids=cams)


@dataclass(frozen=True)
class FrameTimes:
    """When each camera took each synchronised frame of a recording whose cameras are not
    frame-locked.

    Attributes
    ----------
    frames : (F,) int array
        The synchronised frames' numbers (caliscope's ``sync_index``), ascending.
    camera_ids : (K,) int array
    seconds : (K, F) array
        Camera ``k``'s frame time in synchronised frame ``f``, s (one clock for all
        cameras); NaN where the camera has no frame.
    """

    frames: np.ndarray
    camera_ids: np.ndarray
    seconds: np.ndarray

    @property
    def spread(self) -> np.ndarray:
        """``(F,)`` latest minus earliest camera time of each frame, s."""
        return np.nanmax(self.seconds, axis=0) - np.nanmin(self.seconds, axis=0)


def read_caliscope_times(path) -> FrameTimes:
    """Read the frame times of a caliscope recording (``timestamps.csv`` beside its
    videos: ``sync_index, cam_id, frame_time`` in seconds, one row per camera and frame).

    Frame ``i`` of every camera's synchronised video is the ``i``-th ``sync_index``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no caliscope time stamp file at {path}")
    a = _csv_columns(path, ("sync_index", "cam_id", "frame_time"), "frames")
    frames, f_idx = np.unique(a[:, 0].astype(int), return_inverse=True)
    cams, k_idx = np.unique(a[:, 1].astype(int), return_inverse=True)
    if len(set(zip(k_idx, f_idx))) != len(a):
        raise ValueError(f"path: {path} has two rows for one camera and sync_index")
    seconds = np.full((len(cams), len(frames)), np.nan)
    seconds[k_idx, f_idx] = a[:, 2]
    return FrameTimes(frames=frames, camera_ids=cams, seconds=seconds)


# ---------------------------------------------------------------------- videos
@dataclass(frozen=True)
class Videos:
    """A synchronised multi-camera recording opened for reading.

    Frames are decoded as they are asked for, so memory does not grow with the recording:
    iterating holds one grey frame per view (``sum(H * W)`` bytes), :meth:`read` the
    same; only :meth:`load` keeps every selected frame (``T * sum(H * W)`` bytes, e.g.
    835 MB for 100 frames of four 1088 x 1920 views, a quarter of that at ``scale=0.5``).

    Attributes
    ----------
    paths : tuple of K Path
    frames : tuple of int
        The selected frame indices (0-based, in the files).
    fps : float
        Frames per second (the same in every file).
    file_sizes : tuple of K (width, height)
        The frames as stored, px.
    sizes : tuple of K (width, height)
        The frames as delivered, after ``crop`` and ``scale``, px.
    scale : float
    crop : tuple of K (x0, y0, x1, y1) or None
        The pixel window of each file that is kept (half-open, file pixels).
    """

    paths: tuple
    frames: tuple
    fps: float
    file_sizes: tuple
    sizes: tuple
    scale: float
    crop: tuple | None

    @property
    def n_views(self) -> int:
        return len(self.paths)

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def _grey(self, frame, k: int, colour: bool = False) -> np.ndarray:
        g = frame if colour or frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        if self.crop is not None:
            x0, y0, x1, y1 = self.crop[k]
            g = g[y0:y1, x0:x1]
        if self.scale != 1.0:
            g = cv2.resize(g, self.sizes[k], interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(g)

    def read(self, i: int, *, colour: bool = False) -> list:
        """Frame ``i`` of the selection: K grey uint8 images ``(H_k, W_k)`` (with ``colour``,
        the files' BGR frames ``(H_k, W_k, 3)``, cropped and scaled alike)."""
        i = as_int(i, "i", minimum=0)
        if i >= self.n_frames:
            raise IndexError(f"i: expected 0 <= i < {self.n_frames}, got {i}")
        out = []
        for k, path in enumerate(self.paths):
            cap = cv2.VideoCapture(str(path))
            cap.set(cv2.CAP_PROP_POS_FRAMES, self.frames[i])
            ok, frame = cap.read()
            cap.release()
            if not ok:
                raise ValueError(f"{path.name}: frame {self.frames[i]} cannot be decoded")
            out.append(self._grey(frame, k, colour))
        return out

    def __iter__(self):
        """Yield ``(frame index, [K grey images])`` in order, decoding each file once."""
        caps = [cv2.VideoCapture(str(p)) for p in self.paths]
        try:
            for cap in caps:
                cap.set(cv2.CAP_PROP_POS_FRAMES, self.frames[0])
            position = self.frames[0]
            for t in self.frames:
                images = []
                for k, cap in enumerate(caps):
                    if t != position:
                        cap.set(cv2.CAP_PROP_POS_FRAMES, t)
                    ok, frame = cap.read()
                    if not ok:
                        raise ValueError(f"{self.paths[k].name}: frame {t} cannot be decoded")
                    images.append(self._grey(frame, k))
                position = t + 1
                yield t, images
        finally:
            for cap in caps:
                cap.release()

    def load(self, *, progress: bool = True) -> list:
        """Every selected frame: K arrays ``(T, H_k, W_k)`` uint8 (see the memory note)."""
        stacks = [np.empty((self.n_frames, h, w), np.uint8) for w, h in self.sizes]
        for i, (_, images) in enumerate(tqdm(self, total=self.n_frames, unit="frame",
                                             desc="reading videos", disable=not progress)):
            for k, g in enumerate(images):
                stacks[k][i] = g
        return stacks


def _probe(path: Path, k: int):
    if not path.is_file():
        raise FileNotFoundError(f"paths[{k}]: no video at {path}")
    cap = cv2.VideoCapture(str(path))
    ok = cap.isOpened()
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if ok else 0
    fps = float(cap.get(cv2.CAP_PROP_FPS)) if ok else 0.0
    size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    cap.release()
    if not ok or n < 1 or min(size) < 1:
        raise ValueError(f"paths[{k}]: OpenCV cannot read {path.name} as a video (not a "
                         "video, or a codec this OpenCV build lacks)")
    return n, fps, size


def _frame_selection(frames, n: int) -> tuple:
    if frames is None:
        return tuple(range(n))
    if isinstance(frames, slice):
        if frames.stop is not None and frames.stop > n:
            raise ValueError(f"frames: stop {frames.stop} is past the videos' {n} frames")
        if not range(n)[frames]:
            raise ValueError(f"frames: {frames} selects none of the videos' {n} frames")
        return tuple(range(n)[frames])
    sel = [as_int(f, "frames", minimum=0) for f in np.atleast_1d(np.asarray(frames))]
    bad = [f for f in sel if f >= n]
    if bad:
        raise ValueError(f"frames: frame {bad[0]} is out of range: the videos have {n} frames "
                         f"(0..{n - 1})")
    if not sel:
        raise ValueError("frames: expected at least one frame")
    return tuple(sel)


def _crops(crop, sizes) -> tuple | None:
    if crop is None:
        return None
    c = np.asarray(crop)
    if c.shape == (4,):
        c = np.tile(c, (len(sizes), 1))
    if c.shape != (len(sizes), 4) or not np.all(c == np.round(c)):
        raise ValueError(f"crop: expected (x0, y0, x1, y1) in whole pixels, or one such "
                         f"window per video, got {crop!r}")
    out = []
    for k, ((w, h), (x0, y0, x1, y1)) in enumerate(zip(sizes, c.astype(int))):
        if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
            raise ValueError(f"crop: window {(x0, y0, x1, y1)} does not fit video {k} "
                             f"({w} x {h} px)")
        out.append((int(x0), int(y0), int(x1), int(y1)))
    return tuple(out)


def read_videos(paths, *, frames=None, scale: float = 1.0, crop=None) -> Videos:
    """Open a synchronised multi-camera recording (one video file per camera).

    Parameters
    ----------
    paths : sequence of K str or Path
        The videos, one per camera, in the cameras' order.
    frames : None, slice, or sequence of int, optional
        Which frames to use (0-based); all by default.
    scale : float
        Resize factor of the delivered frames (area interpolation), e.g. 0.5; it must give
        whole pixels in both directions, so that a camera scaled by it fits the frames.
    crop : (x0, y0, x1, y1), or K of them, optional
        A pixel window of each file to keep (half-open, in file pixels), before scaling.

    Returns
    -------
    Videos
        Opened lazily: nothing is decoded until frames are read.

    Raises
    ------
    FileNotFoundError, ValueError
        A missing or unreadable file (named), files with different frame counts or rates
        (each file's value listed), frames out of range, a crop outside a frame.
    """
    paths = tuple(Path(p) for p in ([paths] if isinstance(paths, str | Path) else paths))
    if not paths:
        raise ValueError("paths: expected at least one video")
    scale = as_scalar(scale, "scale", positive=True)
    probes = [_probe(p, k) for k, p in enumerate(paths)]
    counts = [n for n, _, _ in probes]
    rates = [r for _, r, _ in probes]
    if len(set(counts)) != 1:
        listed = ", ".join(f"{p.name}: {n}" for p, n in zip(paths, counts))
        raise ValueError(f"paths: the videos hold different numbers of frames ({listed}); "
                         "trim them to the same synchronised span, or pass frames=")
    if max(rates) - min(rates) > 1e-3 * max(rates):
        listed = ", ".join(f"{p.name}: {r:g}" for p, r in zip(paths, rates))
        raise ValueError(f"paths: the videos have different frame rates ({listed})")
    file_sizes = tuple(s for _, _, s in probes)
    crops = _crops(crop, file_sizes)
    kept = file_sizes if crops is None else tuple((x1 - x0, y1 - y0) for x0, y0, x1, y1 in crops)
    odd = [(w, h) for w, h in kept if abs(w * scale - round(w * scale)) > 1e-9
           or abs(h * scale - round(h * scale)) > 1e-9]
    if odd:
        raise ValueError(f"scale: {scale:g} x {odd[0][0]} x {odd[0][1]} px is not a whole number "
                         "of pixels (the cameras could not follow the frames exactly); choose a "
                         "scale that divides the frame sizes, e.g. 0.5, or crop first")
    sizes = tuple((max(1, int(round(w * scale))), max(1, int(round(h * scale))))
                  for w, h in kept)
    return Videos(paths=paths, frames=_frame_selection(frames, counts[0]), fps=rates[0],
                  file_sizes=file_sizes, sizes=sizes, scale=scale, crop=crops)


MISMATCH = ("error", "crop")


def cameras_for_videos(cameras, videos: Videos, *, mismatch: str = "error") -> list:
    """The cameras of a camera file made to fit the frames ``videos`` delivers.

    Each camera's image size must be its video's (as stored). With ``mismatch="crop"``, a
    video smaller than its camera is taken as the camera's frame with its right and bottom
    edges cut off (principal point unchanged), the way some tools write narrower videos
    than the sensor they calibrated. Then the videos' own ``crop`` and ``scale`` are applied
    (:func:`lsmta.camera.cropped_camera`, :func:`lsmta.camera.scaled_camera`).

    Raises
    ------
    ValueError
        A count that differs from the videos', or a size that does not fit, naming the
        video, both sizes and the option that fits, e.g. "cam01.mp4 is 1080 x 1920 but
        its camera is 1088 x 1920".
    """
    cameras = list(cameras)
    if not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected lsmta Camera objects")
    if len(cameras) != videos.n_views:
        raise ValueError(f"cameras: {len(cameras)} cameras for {videos.n_views} videos; the "
                         "camera file must hold one camera per video, in the videos' order")
    if mismatch not in MISMATCH:
        raise ValueError(f"mismatch: expected one of {MISMATCH}, got {mismatch!r}")
    out = []
    for k, (cam, (w, h), path) in enumerate(zip(cameras, videos.file_sizes, videos.paths)):
        if (cam.width, cam.height) != (w, h):
            smaller = w <= cam.width and h <= cam.height
            hint = ("if the video is the camera's frame with its right or bottom edge cut "
                    "off, pass mismatch='crop'" if smaller else
                    "check the order of the cameras and the videos, and whether the video "
                    "was resized or turned")
            if mismatch == "error" or not smaller:
                raise ValueError(f"cameras[{k}]: {path.name} is {w} x {h} but its camera "
                                 f"({cam.name or 'unnamed'}) is {cam.width} x {cam.height}; "
                                 f"{hint}")
            cam = cropped_camera(cam, 0, 0, w, h)
        if videos.crop is not None:
            x0, y0, x1, y1 = videos.crop[k]
            cam = cropped_camera(cam, x0, y0, x1 - x0, y1 - y0)
        if videos.scale != 1.0:
            cam = scaled_camera(cam, videos.scale)
        out.append(cam)
    return out
