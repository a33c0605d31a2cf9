"""Reading marker data: C3D files (through ezc3d)."""

from __future__ import annotations

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
    return MarkerData(labels[: xyz.shape[1]], xyz, rate)
