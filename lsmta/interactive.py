"""Interactive 3-D views: one HTML file per view that a reader can turn, zoom and hover.

A view is made of :class:`Mesh`, :class:`Points` and :class:`Lines` items (mm) and written
by :func:`export_3d_html` with plotly: the page holds the data and loads ``plotly.min.js``
from the same folder (written once per folder, from the plotly package), so it opens from
the file system with no server and no network. plotly draws 3-D with WebGL on a canvas.

Under ``lsmta reproduce`` (``LSMTA_VIEWS_DIR`` set) the 3-D helpers of :mod:`lsmta.viz`
also write the scene of each static picture they render, and the book (:mod:`lsmta.book`)
shows it after the cell that made it; a notebook can call :func:`export_3d_html` itself for
any other scene.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .report import build_dir

VIEWS_ENV = "LSMTA_VIEWS_DIR"
NOTEBOOK_ENV = "LSMTA_NOTEBOOK"
#: at most this many points of one Points item go into a page (evenly strided beyond)
MAX_POINTS = 60_000
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")


def _array(value, name: str, cols: int, *, dtype=float) -> np.ndarray:
    arr = np.array(value, dtype=dtype)         # a copy: the caller's array is never touched
    if arr.ndim != 2 or arr.shape[1] != cols:
        raise ValueError(f"{name}: expected an (N, {cols}) array, got shape {arr.shape}")
    return arr


@dataclass(frozen=True)
class Mesh:
    """A triangle surface: ``vertices`` (V, 3) mm, ``faces`` (F, 3) vertex indices."""

    vertices: np.ndarray
    faces: np.ndarray
    color: str = "wheat"
    opacity: float = 1.0
    name: str = ""

    def __post_init__(self):
        v = _array(self.vertices, "vertices", 3)
        f = _array(self.faces, "faces", 3, dtype=np.int64)
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise ValueError(f"faces: expected indices in [0, {len(v)}), got {f.min()}..{f.max()}")
        if not 0.0 <= float(self.opacity) <= 1.0:
            raise ValueError(f"opacity: expected a number in [0, 1], got {self.opacity}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)


@dataclass(frozen=True)
class Points:
    """Points ``xyz`` (N, 3) mm, one colour or coloured by ``values`` (N,) on ``colorscale``
    (then ``label`` titles the colour bar); ``text`` (N,) labels shown on hover, or drawn
    as text when ``as_text``."""

    xyz: np.ndarray
    color: str = "crimson"
    values: np.ndarray | None = None
    colorscale: str = "Viridis"
    clim: tuple[float, float] | None = None
    label: str = ""
    size: float = 3.0
    text: tuple[str, ...] | None = None
    as_text: bool = False
    name: str = ""

    def __post_init__(self):
        xyz = _array(self.xyz, "xyz", 3)
        object.__setattr__(self, "xyz", xyz)
        if self.values is not None:
            values = np.array(self.values, dtype=float).ravel()
            if len(values) != len(xyz):
                raise ValueError(f"values: expected {len(xyz)} values (one per point), "
                                 f"got {len(values)}")
            object.__setattr__(self, "values", values)
        if self.text is not None:
            text = tuple(str(t) for t in self.text)
            if len(text) != len(xyz):
                raise ValueError(f"text: expected {len(xyz)} labels, got {len(text)}")
            object.__setattr__(self, "text", text)


@dataclass(frozen=True)
class Lines:
    """Polylines (e.g. 3-D trajectories): a sequence of (M, 3) arrays, mm; a NaN row breaks
    a line."""

    polylines: tuple = field(default_factory=tuple)
    color: str = "steelblue"
    width: float = 3.0
    name: str = ""

    def __post_init__(self):
        lines = tuple(_array(p, f"polylines[{k}]", 3) for k, p in enumerate(self.polylines))
        object.__setattr__(self, "polylines", lines)


def views_dir() -> Path:
    """Where views go by default: ``LSMTA_VIEWS_DIR`` if set (``lsmta reproduce`` sets it
    to ``build/views3d``), else ``views3d/`` in :func:`lsmta.report.build_dir`."""
    env = os.environ.get(VIEWS_ENV)
    return Path(env) if env else build_dir() / "views3d"


def next_view_name() -> str:
    """``<notebook>_view<k>`` for the next view of the running notebook (``LSMTA_NOTEBOOK``,
    else ``view``), k counting the views already in :func:`views_dir`."""
    stem = os.environ.get(NOTEBOOK_ENV) or "view"
    folder = views_dir()
    k = len(list(folder.glob(f"{stem}_view*.html"))) if folder.is_dir() else 0
    return f"{stem}_view{k:02d}"


def _xyz(arr: np.ndarray) -> dict:
    a = np.round(arr.astype(np.float32), 2)
    return {"x": a[:, 0], "y": a[:, 1], "z": a[:, 2]}


def _traces(items) -> list:
    import plotly.graph_objects as go  # deferred: plotly is only needed for a view

    traces = []
    for item in items:
        if isinstance(item, Mesh):
            f = item.faces
            traces.append(go.Mesh3d(**_xyz(item.vertices), i=f[:, 0], j=f[:, 1], k=f[:, 2],
                                    color=item.color, opacity=float(item.opacity),
                                    name=item.name or None, showlegend=bool(item.name),
                                    flatshading=False, hoverinfo="name" if item.name else "skip",
                                    lighting={"ambient": 0.55, "diffuse": 0.8, "specular": 0.2}))
        elif isinstance(item, Points):
            xyz, values, text = item.xyz, item.values, item.text
            keep = np.flatnonzero(np.isfinite(xyz).all(axis=1))
            if len(keep) > MAX_POINTS:                  # evenly strided, deterministic
                keep = keep[::-(-len(keep) // MAX_POINTS)]
            xyz = xyz[keep]
            values = None if values is None else values[keep]
            text = None if text is None else [text[k] for k in keep]
            marker = {"size": float(item.size), "color": item.color}
            if values is not None:
                marker.update(color=np.round(values.astype(np.float32), 4),
                              colorscale=item.colorscale, showscale=True,
                              colorbar={"title": {"text": item.label}})
                if item.clim is not None:
                    marker.update(cmin=float(item.clim[0]), cmax=float(item.clim[1]))
            mode = "text" if item.as_text else "markers"
            traces.append(go.Scatter3d(**_xyz(xyz), mode=mode, marker=marker, text=text,
                                       name=item.name or None, showlegend=bool(item.name),
                                       hoverinfo="text+name" if text else "x+y+z+name"))
        elif isinstance(item, Lines):
            parts = []
            for line in item.polylines:
                parts += [line, np.full((1, 3), np.nan)]
            xyz = np.vstack(parts) if parts else np.zeros((0, 3))
            traces.append(go.Scatter3d(**_xyz(xyz), mode="lines", connectgaps=False,
                                       line={"color": item.color, "width": float(item.width)},
                                       name=item.name or None, showlegend=bool(item.name),
                                       hoverinfo="name" if item.name else "skip"))
        else:
            raise TypeError(f"items: expected Mesh, Points or Lines, got {type(item).__name__}")
    return traces


def export_3d_html(*items, title: str = "", path=None, name: str | None = None) -> Path:
    """Write an interactive 3-D view of ``items`` to an HTML file that opens offline.

    Parameters
    ----------
    *items : Mesh, Points or Lines
        What to draw, in mm (world frame, z up).
    title : str
        Shown above the view.
    path : str or Path, optional
        The HTML file. Default: ``<name>.html`` in :func:`views_dir`.
    name : str, optional
        File name without ``.html`` when ``path`` is not given (letters, digits, ``_.-``);
        default :func:`next_view_name`, which the book uses to place the view after the
        notebook cell that wrote it.

    Returns
    -------
    Path
        The file written; ``plotly.min.js`` is written beside it if not there yet.
    """
    if not items:
        raise ValueError("items: expected at least one Mesh, Points or Lines")
    if not isinstance(title, str):
        raise TypeError(f"title: expected a string, got {type(title).__name__}")
    traces = _traces(items)
    if path is None:
        name = next_view_name() if name is None else name
        if not isinstance(name, str) or not _NAME.match(name):
            raise ValueError(f"name: expected letters, digits and _.- only, got {name!r}")
        path = views_dir() / f"{name}.html"
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    import plotly.graph_objects as go  # deferred: as above

    fig = go.Figure(traces)
    fig.update_layout(
        title={"text": title, "x": 0.02, "font": {"size": 14}} if title else None,
        scene={"aspectmode": "data", "xaxis_title": "x [mm]", "yaxis_title": "y [mm]",
               "zaxis_title": "z [mm]", "camera": {"up": {"x": 0, "y": 0, "z": 1},
                                                   "eye": {"x": -0.9, "y": -1.6, "z": 0.8}}},
        margin={"l": 0, "r": 0, "t": 36 if title else 0, "b": 0}, paper_bgcolor="white",
        legend={"x": 0.01, "y": 0.98})
    fig.write_html(path, include_plotlyjs="directory", full_html=True, include_mathjax=False,
                   config={"displaylogo": False, "responsive": True},
                   default_width="100%", default_height="92vh")
    return path
