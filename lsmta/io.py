"""Reading marker data: C3D files (through ezc3d) and Maya ASCII animation curves."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

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
    import ezc3d

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
