"""Camera files that other tools read and write, to and from :class:`~lsmta.camera.Camera`.

=====================  ========  =====================================================
format                 access    layout
=====================  ========  =====================================================
OpenCV FileStorage     read,     ``names`` (a list), then per camera ``K_<name>``,
YAML                   write     ``dist_<name>`` (k1, k2, p1, p2, k3), ``Rot_<name>``
                                 (3 x 3, world to camera), ``R_<name>`` (its Rodrigues
                                 vector), ``T_<name>`` (translation, mm), ``W_<name>``,
                                 ``H_<name>`` (image size): EasyMocap's intri/extri keys
                                 in one file (written and read by ``cv2.FileStorage``)
TOML (aniposelib,      read,     one table per camera with ``name``, ``size``,
caliscope, Pose2Sim)   write     ``matrix``, ``distortions`` (k1, k2, p1, p2[, k3]),
                                 ``rotation`` (Rodrigues vector; caliscope: 3 x 3
                                 matrix), ``translation``; aniposelib's tables are
                                 ``[cam_0]`` ..., caliscope's ``[cameras.0]`` ...
Qualisys ``.qca``      read      XML; see :func:`read_qca`
DLT (easyWand, Argus)  read,     11 coefficients per camera, one column per camera
                       write     (CSV), for image y measured upwards; see
                                 :func:`dlt_coefficients`
=====================  ========  =====================================================

:func:`read_camera_file` recognises the format from the file's content, and takes the
unit from the format's convention where it has one.

All of them hold OpenCV's pinhole camera: ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]``,
``x_cam = R X + t``, the five Brown coefficients. In :class:`~lsmta.camera.Camera` terms
``fx = f (1 + b1)``, ``fy = f``, ``s = f b2`` (only DLT carries a shear), ``C = -R^T t``.
Translations in a file are in the file's ``unit``, converted to and from this project's
millimetres. Numbers are written with all their digits (round trip to < 1e-9 px).
"""

from __future__ import annotations

import csv
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import tomli_w

from ._validate import as_array
from .camera import Camera

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

UNIT_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}


def _unit(unit) -> float:
    if unit not in UNIT_TO_MM:
        raise ValueError(f"unit: expected one of {sorted(UNIT_TO_MM)} (the unit of the "
                         f"file's translations), got {unit!r}")
    return UNIT_TO_MM[unit]


def _cameras(cameras) -> list:
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise TypeError("cameras: expected a non-empty sequence of lsmta.camera.Camera")
    return cameras


def _names(cameras) -> list[str]:
    """File keys: each camera's name, or its index; letters, digits and _ only."""
    names = [re.sub(r"[^A-Za-z0-9_]", "_", c.name) if c.name else str(k)
             for k, c in enumerate(cameras)]
    if len(set(names)) != len(names):
        raise ValueError(f"cameras: names must be unique in a camera file, got {names}")
    return names


def _file(path, what: str) -> Path:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no {what} at {path}")
    return path


def _from_matrices(K, dist, R, t, size, name, scale) -> Camera:
    """A Camera from OpenCV's ``K``, ``dist``, world-to-camera ``R`` and ``t`` (file unit)."""
    K = np.asarray(K, float)
    R = np.asarray(R, float)
    if R.shape == (3,) or R.size == 3:
        R, _ = cv2.Rodrigues(R.reshape(3))
    t = np.asarray(t, float).reshape(3) * scale
    cam = Camera.from_opencv(K, dist, cv2.Rodrigues(R)[0], t, size, name=name)
    # from_opencv goes through the Rodrigues vector; keep the file's own matrix and centre
    return cam.replace(R=R, C=-R.T @ t)


def _to_matrices(cam: Camera, scale):
    K, dist, _, tvec = cam.to_opencv()
    return K, dist, np.asarray(cam.R), tvec / scale


# ---------------------------------------------------------------------- OpenCV YAML
def write_opencv_yaml(path, cameras, *, unit: str = "mm") -> Path:
    """Write cameras as an OpenCV FileStorage YAML file (layout in the module docstring).

    Parameters
    ----------
    path : str or Path
        Written with ``cv2.FileStorage`` (``.yml``/``.yaml``; ``.xml`` and ``.json`` work
        too).
    cameras : sequence of Camera
        Without shear (``b2 == 0``): OpenCV's camera has none.
    unit : {"mm", "cm", "m"}
        Unit of the translations in the file.
    """
    cameras = _cameras(cameras)
    scale = _unit(unit)
    names = _names(cameras)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        fs.startWriteStruct("names", cv2.FileNode_SEQ)
        for n in names:
            fs.write("", n)
        fs.endWriteStruct()
        fs.write("unit", unit)
        for n, cam in zip(names, cameras):
            K, dist, R, t = _to_matrices(cam, scale)
            fs.write(f"K_{n}", K)
            fs.write(f"dist_{n}", dist.reshape(1, 5))
            fs.write(f"Rot_{n}", R)
            fs.write(f"R_{n}", cv2.Rodrigues(R)[0])
            fs.write(f"T_{n}", t.reshape(3, 1))
            fs.write(f"W_{n}", cam.width)
            fs.write(f"H_{n}", cam.height)
    finally:
        fs.release()
    return Path(path)


def read_opencv_yaml(path, *, unit: str | None = None, image_sizes=None) -> list[Camera]:
    """Read cameras from an OpenCV FileStorage YAML file (layout in the module docstring).

    Parameters
    ----------
    path : str or Path
    unit : {"mm", "cm", "m"}, optional
        Unit of the file's translations; by default the file's ``unit`` entry (written by
        :func:`write_opencv_yaml`), which a file without one must be given.
    image_sizes : sequence of (width, height), optional
        For files without ``W_<name>``/``H_<name>`` (EasyMocap's intri.yml has none).
        ``Rot_<name>`` is used where present, else the Rodrigues vector ``R_<name>``.
    """
    path = _file(path, "OpenCV YAML file")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        node = fs.getNode("names")
        if node.empty() or not node.isSeq():
            raise ValueError(f"path: {path} has no 'names' list of cameras")
        names = [node.at(i).string() or str(int(node.at(i).real())) for i in range(node.size())]
        if unit is None:
            u = fs.getNode("unit")
            if u.empty():
                raise ValueError(f"unit: {path} does not say the unit of its translations; "
                                 "pass unit='mm', 'cm' or 'm'")
            unit = u.string()
        scale = _unit(unit)
        if image_sizes is not None and len(image_sizes) != len(names):
            raise ValueError(f"image_sizes: expected {len(names)} (width, height) pairs")
        cams = []
        for k, n in enumerate(names):
            def get(key, n=n):
                m = fs.getNode(f"{key}_{n}")
                return None if m.empty() else (m.mat() if m.isMap() else m.real())
            K, dist, T = get("K"), get("dist"), get("T")
            R = get("Rot")
            R = get("R") if R is None else R
            if any(v is None for v in (K, dist, R, T)):
                raise ValueError(f"path: camera {n!r} of {path} lacks K_, dist_, R_/Rot_ or "
                                 "T_")
            if image_sizes is not None:
                size = tuple(image_sizes[k])
            elif get("W") is not None and get("H") is not None:
                size = (int(get("W")), int(get("H")))
            else:
                raise ValueError(f"image_sizes: {path} has no W_/H_ for camera {n!r}; pass "
                                 "image_sizes")
            cams.append(_from_matrices(K, dist, R, T, size, n, scale))
        return cams
    finally:
        fs.release()


# ---------------------------------------------------------------------- TOML
def write_camera_toml(path, cameras, *, unit: str = "mm", layout: str = "aniposelib") -> Path:
    """Write cameras as TOML for aniposelib / Pose2Sim or caliscope.

    ``layout="aniposelib"``: tables ``[cam_0]`` ... with ``name``, ``size``, ``matrix``,
    ``distortions`` (k1, k2, p1, p2, k3), ``rotation`` (Rodrigues vector), ``translation``
    and a ``[metadata]`` table with the unit. ``layout="caliscope"``: tables
    ``[cameras.0]`` ... with ``cam_id``, ``size``, ``rotation_count = 0``, ``ignore =
    false``, ``matrix``, ``distortions``, ``rotation`` (3 x 3) and ``translation``
    (caliscope works in metres: pass ``unit="m"``).
    """
    cameras = _cameras(cameras)
    scale = _unit(unit)
    if layout not in ("aniposelib", "caliscope"):
        raise ValueError(f"layout: expected 'aniposelib' or 'caliscope', got {layout!r}")
    names = _names(cameras)
    tables = {}
    for k, (n, cam) in enumerate(zip(names, cameras)):
        K, dist, R, t = _to_matrices(cam, scale)
        entry = {"size": [cam.width, cam.height], "matrix": K.tolist(),
                 "distortions": dist.tolist(), "translation": t.tolist()}
        if layout == "aniposelib":
            entry = {"name": n, **entry, "rotation": cv2.Rodrigues(R)[0].ravel().tolist()}
            tables[f"cam_{k}"] = entry
        else:
            entry = {"cam_id": k, "rotation_count": 0, "ignore": False, **entry,
                     "rotation": R.tolist()}
            tables[str(k)] = entry
    doc = ({**tables, "metadata": {"unit": unit}} if layout == "aniposelib"
           else {"cameras": tables})
    path = Path(path)
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    return path


def read_camera_toml(path, *, unit: str) -> list[Camera]:
    """Read cameras from an aniposelib / Pose2Sim / caliscope TOML file.

    Every table (or, in caliscope's files, every table under ``[cameras]``) with a
    ``matrix`` is a camera; ``rotation`` may be a Rodrigues vector or a 3 x 3 matrix
    (world to camera). Cameras that caliscope marks ``ignore = true`` are skipped.

    Parameters
    ----------
    path : str or Path
    unit : {"mm", "cm", "m"}
        Unit of the translations (caliscope: "m"; aniposelib: the unit of the board's
        square size the user gave). Required: the files do not say it.
    """
    path = _file(path, "camera TOML file")
    scale = _unit(unit)
    with open(path, "rb") as fh:
        doc = tomllib.load(fh)
    tables = doc.get("cameras", doc)
    cams = []
    for key, entry in tables.items():
        if not isinstance(entry, dict) or "matrix" not in entry:
            continue
        if entry.get("ignore", False):
            continue
        missing = [f for f in ("size", "distortions", "rotation", "translation")
                   if f not in entry]
        if missing:
            raise ValueError(f"path: camera {key!r} of {path} lacks {missing}")
        name = str(entry.get("name", key))
        cams.append(_from_matrices(entry["matrix"], entry["distortions"], entry["rotation"],
                                   entry["translation"], tuple(entry["size"]), name, scale))
    if not cams:
        raise ValueError(f"path: no camera tables (with a 'matrix') in {path}")
    return cams


# ---------------------------------------------------------------------- Qualisys
def read_qca(path, *, sensor_units_per_px: float | None = None) -> list[Camera]:
    """Read the cameras of a Qualisys calibration (``.qca`` / ``.qca.txt``, XML).

    Per ``<camera>``: ``<transform>`` holds the camera's position ``x, y, z`` (mm, world)
    and a rotation matrix ``r11 .. r33`` whose *rows* are the camera axes in the world,
    with the camera's y and z axes pointing up and backwards (Qualisys' convention); this
    project's camera (y down, z forward) is that turned by 180 degrees about x:
    ``R = diag(1, -1, -1) M``. ``<intrinsic>`` gives ``focalLengthU/V`` and
    ``centerPointU/V`` in sensor units, ``sensorMaxU + 1`` of them spanning the sensor
    (64 per pixel in current files); pixels are ``value / units_per_px`` less the video
    window's ``left``/``top``. ``radialDistortion1..3`` and ``tangentalDistortion1..2``
    are read as OpenCV's k1, k2, k3, p1, p2 on normalised coordinates (dimensionless, so
    not scaled by the sensor units; Pose2Sim's converter divides them by 64, which this
    reader does not). The image size is ``fov_video`` (right - left + 1, bottom - top + 1).

    Parameters
    ----------
    path : str or Path
    sensor_units_per_px : float, optional
        Sensor units per pixel; by default ``(sensorMaxU + 1) / (fov_video_max width)``.
    """
    path = _file(path, "Qualisys calibration")
    root = ET.parse(path).getroot()
    cams = []
    for node in root.iter("camera"):
        tr, intr = node.find("transform"), node.find("intrinsic")
        fov = node.find("fov_video")
        fov_max = node.find("fov_video_max") if node.find("fov_video_max") is not None else fov
        if tr is None or intr is None or fov is None:
            raise ValueError(f"path: a camera of {path} lacks transform, intrinsic or "
                             "fov_video")
        g = {**{k: float(v) for k, v in tr.attrib.items()},
             **{k: float(v) for k, v in intr.attrib.items()},
             **{f"fov_{k}": float(v) for k, v in fov.attrib.items()}}
        width = int(g["fov_right"] - g["fov_left"] + 1)
        height = int(g["fov_bottom"] - g["fov_top"] + 1)
        if sensor_units_per_px is None:
            full = float(fov_max.get("right")) - float(fov_max.get("left")) + 1
            units = (g["sensorMaxU"] - g.get("sensorMinU", 0.0) + 1) / full
            units = float(np.round(units))        # a whole number of sub-pixel steps
        else:
            units = float(sensor_units_per_px)
        M = np.array([[g[f"r{i}{j}"] for j in (1, 2, 3)] for i in (1, 2, 3)])
        R = np.diag([1.0, -1.0, -1.0]) @ M
        # the file's 6-7 digits: make the matrix exactly orthonormal (nearest rotation)
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
        fu, fv = g["focalLengthU"] / units, g["focalLengthV"] / units
        cams.append(Camera(
            f=fv, b1=fu / fv - 1.0, b2=g.get("skew", 0.0) / units / fv,
            cx=g["centerPointU"] / units - g["fov_left"],
            cy=g["centerPointV"] / units - g["fov_top"], width=width, height=height,
            R=R, C=np.array([g["x"], g["y"], g["z"]]),
            k1=g.get("radialDistortion1", 0.0), k2=g.get("radialDistortion2", 0.0),
            k3=g.get("radialDistortion3", 0.0), p1=g.get("tangentalDistortion1", 0.0),
            p2=g.get("tangentalDistortion2", 0.0), name=node.get("serial", str(len(cams)))))
    if not cams:
        raise ValueError(f"path: no <camera> elements in {path}")
    return cams


# ---------------------------------------------------------------------- DLT
def dlt_coefficients(camera: Camera, *, y_up: bool = True) -> np.ndarray:
    """The 11 DLT coefficients ``L1..L11`` of a camera (easyWand, Argus, DLTdv)::

        u = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1)
        v = (L5 X + L6 Y + L7 Z + L8) / (L9 X + L10 Y + L11 Z + 1)

    with X in mm and ``(u, v)`` *undistorted* pixel coordinates: DLT is the linear camera
    (interior orientation, affinity, shear, exterior orientation: 11 parameters);
    easyWand and Argus keep the lens distortion in a separate profile. With ``y_up``,
    ``v`` is measured upwards from the bottom edge, ``v = H - y`` (DLTdv's and Argus'
    convention, the inverse of :func:`lsmta.io.read_xypts`).
    """
    if not isinstance(camera, Camera):
        raise TypeError("camera: expected an lsmta.camera.Camera")
    K = np.array([[camera.f * (1 + camera.b1), camera.f * camera.b2, camera.cx],
                  [0.0, camera.f, camera.cy], [0.0, 0.0, 1.0]])
    R = np.asarray(camera.R)
    P = K @ np.hstack([R, (-R @ camera.C)[:, None]])
    if y_up:
        P = np.array([[1.0, 0, 0], [0, -1.0, camera.height], [0, 0, 1.0]]) @ P
    if abs(P[2, 3]) < 1e-12 * np.abs(P[2, :3]).max() * (1 + np.abs(camera.C).max()):
        raise ValueError("camera: the world origin lies in the camera's focal plane (e.g. at "
                         "its centre, the datum of calibrate_wand); DLT (normalised by L12 = 1) "
                         "cannot describe it: move the origin first, e.g. C - mean of the "
                         "measured points")
    P = P / P[2, 3]
    return np.concatenate([P[0], P[1], P[2, :3]])


def camera_from_dlt(L, image_size, *, y_up: bool = True, name: str = "") -> Camera:
    """The distortion-free camera of 11 DLT coefficients (RQ decomposition of the 3 x 4
    projection matrix; the inverse of :func:`dlt_coefficients`).

    Parameters
    ----------
    L : (11,) array
    image_size : (width, height)
    y_up : bool
        The coefficients are for v measured upwards (easyWand, Argus).
    """
    L = as_array(L, "L", shape=(11,))
    width, height = image_size
    P = np.vstack([L[:4], L[4:8], np.append(L[8:], 1.0)])
    if y_up:
        P = np.array([[1.0, 0, 0], [0, -1.0, height], [0, 0, 1.0]]) @ P
    A = P[:, :3]
    if abs(np.linalg.det(A)) < 1e-300:
        raise ValueError("L: the coefficients do not describe a camera (singular 3 x 3 part)")
    C = -np.linalg.solve(A, P[:, 3])
    K, R = _rq(A)
    if np.linalg.det(R) < 0:                 # P is defined up to sign: take the proper one
        K, R = -K, -R
    S = np.diag(np.sign(np.diag(K)))         # positive focal lengths
    K, R = K @ S, S @ R
    K = K / K[2, 2]
    f = K[1, 1]
    return Camera(f=f, cx=K[0, 2], cy=K[1, 2], b1=K[0, 0] / f - 1.0, b2=K[0, 1] / f,
                  width=width, height=height, R=R, C=C, name=name)


def _rq(A):
    """``A = K R`` with K upper triangular and R orthonormal."""
    Q, U = np.linalg.qr(np.flipud(A).T)
    K = np.flipud(np.fliplr(U.T))
    R = np.flipud(Q.T)
    return K, R


def write_dlt(path, cameras, *, y_up: bool = True) -> Path:
    """Write the 11 DLT coefficients of every camera as easyWand's ``*_dltCoefs.csv``: 11
    rows, one column per camera, full precision. The lens distortion is not part of DLT
    (see :func:`dlt_coefficients`); write it with the camera files above."""
    cameras = _cameras(cameras)
    L = np.stack([dlt_coefficients(c, y_up=y_up) for c in cameras], axis=1)
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        for row in L:
            w.writerow([repr(float(v)) for v in row])
    return path


def read_dlt(path) -> np.ndarray:
    """``(K, 11)`` DLT coefficients from an easyWand / Argus ``*_dltCoefs.csv`` (11 rows,
    one column per camera); :func:`camera_from_dlt` turns a row into a camera."""
    path = _file(path, "DLT coefficient file")
    with open(path, newline="", encoding="utf-8") as fh:
        rows = [[float(c) for c in r] for r in csv.reader(fh) if r]
    L = np.array(rows, dtype=float)
    if L.ndim != 2 or L.shape[0] != 11:
        raise ValueError(f"path: expected 11 rows of coefficients (one column per camera) "
                         f"in {path}, got shape {L.shape}")
    return L.T.copy()


# ---------------------------------------------------------------------- any of them
FORMAT_UNITS = {"qualisys": "mm", "caliscope": "m"}


def camera_file_format(path) -> str:
    """The format of a camera file, from its content: ``"qualisys"``, ``"opencv"``,
    ``"caliscope"`` or ``"toml"`` (aniposelib / Pose2Sim / this project's).

    Raises
    ------
    ValueError
        A file none of them reads (a DLT coefficient file holds no image size: read it
        with :func:`read_dlt` and :func:`camera_from_dlt`).
    """
    path = _file(path, "camera file")
    head = path.read_bytes()[:4096].decode("utf-8", errors="replace").lstrip("\ufeff \t\r\n")
    if head.startswith("<?xml") or "<calibration" in head:
        return "qualisys"
    if head.startswith("%YAML") or "opencv-storage" in head:
        return "opencv"
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError):
        doc = None
    if isinstance(doc, dict):
        if isinstance(doc.get("cameras"), dict):
            return "caliscope"
        if any(isinstance(v, dict) and "matrix" in v for v in doc.values()):
            return "toml"
    raise ValueError(f"path: {path.name} is not a camera file this library reads (Qualisys "
                     "XML, OpenCV YAML, aniposelib / Pose2Sim / caliscope TOML)")


def read_camera_file(path, *, unit: str | None = None) -> list[Camera]:
    """Read cameras from any file :func:`camera_file_format` recognises.

    Parameters
    ----------
    path : str or Path
    unit : {"mm", "cm", "m"}, optional
        Unit of the file's translations. Qualisys files are in mm and caliscope's in m by
        the format; an OpenCV YAML or TOML file written by this library states its unit.
        Other files need it, and a ``unit`` that contradicts the format's is an error.
    """
    fmt = camera_file_format(path)
    fixed = FORMAT_UNITS.get(fmt)
    if fixed is not None and unit is not None and unit != fixed:
        raise ValueError(f"unit: {Path(path).name} is a {fmt} file, whose translations are in "
                         f"{fixed} by the format; got unit={unit!r}")
    if fmt == "qualisys":
        return read_qca(path)
    if fmt == "opencv":
        return read_opencv_yaml(path, unit=unit)
    if fmt == "toml":
        with open(path, "rb") as fh:
            stated = tomllib.load(fh).get("metadata", {}).get("unit")
        if stated is not None and unit is not None and unit != stated:
            raise ValueError(f"unit: {Path(path).name} states its unit as {stated!r}; got "
                             f"unit={unit!r}")
        unit = unit or stated
        if unit is None:
            raise ValueError(f"unit: {Path(path).name} (aniposelib / Pose2Sim TOML) does not "
                             "state the unit of its translations; give it (mm, cm or m; "
                             "Pose2Sim writes m)")
    return read_camera_toml(path, unit=fixed or unit)
