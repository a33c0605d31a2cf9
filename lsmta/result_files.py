"""Results out in files other tools read: trajectories as C3D and TRC, surfaces as PLY.

- **C3D** (written with ezc3d, the library Kinetics Toolkit, OpenSim's tools and most
  motion-capture software read): the ``POINT`` group with ``LABELS``, ``UNITS`` ("mm") and
  ``RATE`` (frames per second), optionally ``DESCRIPTIONS`` (what the points are, e.g. how
  they were filtered); a missing sample has residual -1 (the C3D convention for
  an invalid point, which tools that go by the residual need) and NaN coordinates.
- **TRC** (the tab-separated text of OpenSim and Pose2Sim): a five-line header
  (``PathFileType 4 (X/Y/Z)``; the data rate, frame count, marker count, units), then one
  row per frame, ``Frame#`` (from 1) and ``Time`` (s) before the markers' X, Y, Z. A
  missing sample is an empty field, as OpenSim writes and reads it.
- **PLY** (binary little-endian, written with plyfile): one vertex per measured point
  with ``x y z`` (float32, mm) and any per-point scalars (e.g. ``sigma``, the point's
  standard deviation, mm), and optionally triangle faces. pyvista (VTK) reads the geometry;
  plyfile reads the scalars back.

C3D files are read back with :func:`lsmta.io.read_c3d`, TRC files with :func:`read_trc`;
both give :class:`lsmta.io.MarkerData`.

All writers make the folder as needed, never modify what they are given and return the
path written.
"""

from __future__ import annotations

import re
from pathlib import Path

import ezc3d
import numpy as np
from plyfile import PlyData, PlyElement

from ._validate import as_array, as_scalar
from .io import _UNIT_TO_MM, MarkerData

_LABEL = re.compile(r"^[^\t\r\n]+$")


def _labels(labels, n: int) -> list[str]:
    if labels is None:
        return [f"P{i + 1}" for i in range(n)]
    labels = [str(s) for s in labels]
    if len(labels) != n:
        raise ValueError(f"labels: expected {n} labels (one per point), got {len(labels)}")
    bad = [s for s in labels if not _LABEL.match(s)]
    if bad:
        raise ValueError(f"labels: expected non-empty labels without tabs or line breaks, "
                         f"got {bad[:3]!r}")
    if len(set(labels)) != n:
        raise ValueError("labels: expected distinct labels")
    return labels


def _trajectories(trajectories) -> np.ndarray:
    X = as_array(trajectories, "trajectories", finite=False)
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] < 1 or X.shape[1] < 1:
        raise ValueError(f"trajectories: expected a (T, N, 3) array with T, N >= 1 (mm, NaN "
                         f"for missing), got shape {X.shape}")
    if np.isinf(X).any():
        raise ValueError("trajectories: expected finite values or NaN (missing), got inf")
    return X


def _target(path, suffix: str) -> Path:
    path = Path(path)
    if path.suffix.lower() != suffix:
        raise ValueError(f"path: expected a {suffix} file name, got {path.name!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def write_c3d(path, trajectories, *, rate: float, labels=None, description=None) -> Path:
    """Write labelled trajectories to a C3D file with ezc3d.

    Parameters
    ----------
    path : str or Path
        A ``.c3d`` file name (folders are made).
    trajectories : (T, N, 3) array
        Positions, mm; NaN for a missing sample (written as an invalid point).
    rate : float
        Frames per second (> 0).
    labels : sequence of N str, optional
        Point labels (default ``P1 .. PN``).
    description : str, optional
        Written as every point's ``POINT:DESCRIPTIONS`` entry (e.g. the filter applied).
    """
    X = _trajectories(trajectories)
    rate = as_scalar(rate, "rate", positive=True)
    names = _labels(labels, X.shape[1])
    if description is not None and not isinstance(description, str):
        raise TypeError(f"description: expected a str or None, got "
                        f"{type(description).__name__}")
    path = _target(path, ".c3d")
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = names
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    if description is not None:
        c3d.add_parameter("POINT", "DESCRIPTIONS", [description] * X.shape[1])
    data = np.ones((4, X.shape[1], X.shape[0]))
    data[:3] = X.transpose(2, 1, 0)
    missing = np.isnan(data[:3]).any(axis=0)
    c3d["data"]["points"] = data
    c3d["data"]["meta_points"] = {
        "residuals": np.where(missing, -1.0, 0.0)[None],
        "camera_masks": np.zeros((7, X.shape[1], X.shape[0]), bool)}
    c3d.write(str(path))
    return path


def read_trc(path) -> MarkerData:
    """Read a TRC file (OpenSim / Pose2Sim layout; empty or NaN fields are missing).

    Units ``m`` and ``cm`` are converted to mm.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no TRC file at {path}")
    lines = path.read_text(encoding="utf-8").splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise ValueError(f"path: {path.name} is not a TRC file (no PathFileType header)")
    keys, values = lines[1].split("\t"), lines[2].split("\t")
    head = dict(zip(keys, values))
    rate = float(head["DataRate"])
    scale = _UNIT_TO_MM.get(head.get("Units", "mm").strip(), None)
    if scale is None:
        raise ValueError(f"path: unknown Units {head.get('Units')!r} in {path.name}")
    labels = [s for s in lines[3].split("\t")[2:] if s.strip()]
    rows = [ln.split("\t") for ln in lines[5:] if ln.strip()]
    data = np.full((len(rows), len(labels) * 3), np.nan)
    for t, row in enumerate(rows):
        for j, field in enumerate(row[2:2 + 3 * len(labels)]):
            if field.strip():
                data[t, j] = float(field)
    return MarkerData(labels=tuple(labels), points=data.reshape(len(rows), len(labels), 3) * scale,
                      rate=rate)


def write_trc(path, trajectories, *, rate: float, labels=None) -> Path:
    """Write labelled trajectories as a TRC file (mm), the text format OpenSim reads.

    Parameters
    ----------
    path : str or Path
        A ``.trc`` file name (folders are made).
    trajectories : (T, N, 3) array
        Positions, mm; NaN for a missing sample (written as an empty field).
    rate : float
        Frames per second (> 0).
    labels : sequence of N str, optional
        Point labels (default ``P1 .. PN``).

    Notes
    -----
    Unlike :func:`write_c3d` there is no ``description``: the header's lines are the fixed
    ones OpenSim and Pose2Sim read (file type and name, then rates, counts and units, then
    labels and coordinate names), with no field for a note.
    """
    X = _trajectories(trajectories)
    rate = as_scalar(rate, "rate", positive=True)
    names = _labels(labels, X.shape[1])
    path = _target(path, ".trc")
    T, N, _ = X.shape
    head = [f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\t"
            "OrigDataStartFrame\tOrigNumFrames",
            f"{rate:.10g}\t{rate:.10g}\t{T}\t{N}\tmm\t{rate:.10g}\t1\t{T}",
            "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in names).rstrip("\t"),
            "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, N + 1)),
            ""]
    body = []
    for t in range(T):
        cells = ["" if not np.isfinite(v) else f"{v:.6f}" for v in X[t].ravel()]
        body.append(f"{t + 1}\t{t / rate:.6f}\t" + "\t".join(cells))
    path.write_text("\n".join(head + body) + "\n", encoding="utf-8")
    return path


def write_ply(path, points, *, scalars=None, faces=None) -> Path:
    """Write a point cloud (or a triangle mesh) as binary PLY with plyfile.

    Parameters
    ----------
    path : str or Path
        A ``.ply`` file name (folders are made).
    points : (N, 3) array
        Vertex positions, mm (finite; NaN rows are not allowed — drop them first).
    scalars : dict of str -> (N,) array, optional
        Per-vertex values written as float32 properties, e.g. ``{"sigma": s}``.
    faces : (F, 3) int array, optional
        Triangles as vertex indices.
    """
    X = as_array(points, "points", shape=(None, 3))
    path = _target(path, ".ply")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    columns = [X[:, 0], X[:, 1], X[:, 2]]
    for name, values in (scalars or {}).items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", str(name)) or name in ("x", "y", "z"):
            raise ValueError(f"scalars: expected identifier names other than x, y, z, "
                             f"got {name!r}")
        v = as_array(values, f"scalars[{name!r}]", shape=(len(X),), finite=False)
        fields.append((str(name), "<f4"))
        columns.append(v)
    vertex = np.empty(len(X), dtype=fields)
    for (name, _), col in zip(fields, columns):
        vertex[name] = col
    elements = [PlyElement.describe(vertex, "vertex")]
    if faces is not None:
        F = np.asarray(faces)
        if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer) \
                or (F.size and (F.min() < 0 or F.max() >= len(X))):
            raise ValueError(f"faces: expected an (F, 3) integer array of vertex indices "
                             f"in [0, {len(X)}), got shape {F.shape}, dtype {F.dtype}")
        face = np.empty(len(F), dtype=[("vertex_indices", "i4", (3,))])
        face["vertex_indices"] = F
        elements.append(PlyElement.describe(face, "face"))
    PlyData(elements, byte_order="<").write(str(path))
    return path
