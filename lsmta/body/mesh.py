"""One closed triangle mesh of the whole body: the iso-surface ``F = T`` of the metaball
field (Plänkers et al. 1999, eq. 4) by marching cubes, and its files.

The skin patches of :mod:`lsmta.body.skin` are closed part by part and overlap at the
joints; the field itself is one implicit surface, so its level set, sampled on a voxel grid
and triangulated by marching cubes (scikit-image's ``marching_cubes``, Lewiner's variant),
is one mesh of the whole body.

The grid
    The field of ``B`` balls at a point whose ellipsoidal distance (eq. 6) to every ball is
    ``d_b > k^2`` is below ``B exp(-2 k^2)``; with ``k^2 = ln(B / T) / 2`` that is below
    ``T``. The grid spans the union of the balls' axis-aligned boxes around their
    ellipsoids scaled by ``k``, plus one voxel on every side, so every node on the grid's
    faces lies outside the surface and the mesh closes (no open edges) whatever the pose.
    The field is summed over all balls at every node by a compiled kernel
    (:func:`lsmta.body._kernels.grid_field`, which visits along each grid line only the
    nodes a ball reaches); a ball adds nothing where ``d_b > 12`` (``exp(-24)``, 4e-11,
    far below any level).
What the mesh says about itself (:class:`BodyMesh`)
    Open edges (used by one triangle) and non-manifold edges (by more than two): both 0 for
    a watertight surface; connected pieces (SciPy's ``connected_components`` on the
    vertices joined by the triangles' edges): a model whose field does not join two parts
    gives two pieces, and a gap narrower than a voxel may be bridged; the enclosed volume
    from the triangles (divergence theorem: the sum of ``v0 . (v1 x v2) / 6``, positive
    for outward triangles) and the area. :func:`metaball_volume` / :func:`body_volume`
    count the grid nodes where ``F >= T``, the volume the mesh should enclose, for a check
    that does not go through the mesh.
Files (:func:`write_mesh`)
    PLY (binary) and OBJ through pyvista (VTK's ``vtkPLYWriter`` and ``vtkOBJWriter``,
    no rendering needed): they write the vertices (float32, mm, the body's world) and the
    triangles in formats that Blender, MeshLab and CloudCompare open, and pyvista reads
    them back. glTF is not written: VTK's ``vtkGLTFWriter`` crashed here on a plain
    triangle mesh, its scene exporter needs a render window and adds a camera, and no
    other glTF writer is a dependency.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from skimage.measure import marching_cubes

from .._validate import as_array, as_scalar, freeze
from ._kernels import grid_field
from .metaballs import THRESHOLD, MetaballModel, _radii

CUTOFF = 12.0          # a ball adds nothing beyond this ellipsoidal distance (exp(-24))
FORMATS = (".ply", ".obj")


@dataclass(frozen=True, eq=False)
class BodyMesh:
    """A triangle mesh of the body's skin (:func:`body_mesh`).

    Attributes
    ----------
    vertices : (V, 3) array
        World coordinates, mm.
    faces : (F, 3) int array
        Vertex indices of each triangle, ordered anticlockwise seen from outside.
    voxel_mm : float
        Grid step of the field samples, mm (the mesh's resolution).
    level : float
        The level ``T`` of the field.
    field_volume : float
        The field's own volume on the same grid: the nodes with ``F >= T`` counted, each
        one voxel (mm^3; :func:`metaball_volume`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    voxel_mm: float
    level: float
    field_volume: float = float("nan")

    def __post_init__(self):
        v, f = np.asarray(self.vertices), np.asarray(self.faces)
        if v.ndim != 2 or v.shape[1:] != (3,) or not np.isfinite(v).all():
            raise ValueError(f"vertices: expected a finite (V, 3) array, mm; got shape {v.shape}")
        if (f.ndim != 2 or f.shape[1:] != (3,) or not np.issubdtype(f.dtype, np.integer)
                or (f.size and (f.min() < 0 or f.max() >= len(v)))):
            raise ValueError(f"faces: expected an integer (F, 3) array of indices into the "
                             f"{len(v)} vertices; got {f.dtype} {f.shape}")
        freeze(self, ("vertices", "faces"))

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @cached_property
    def _edge_uses(self) -> np.ndarray:
        """How many triangles use each distinct undirected edge."""
        f = self.faces
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        _, counts = np.unique(e[:, 0] * np.int64(self.n_vertices) + e[:, 1], return_counts=True)
        return counts

    @property
    def n_open_edges(self) -> int:
        """Edges used by one triangle only (0 for a closed surface)."""
        return int((self._edge_uses == 1).sum())

    @property
    def n_nonmanifold_edges(self) -> int:
        """Edges used by more than two triangles (0 for a manifold surface)."""
        return int((self._edge_uses > 2).sum())

    @cached_property
    def component_labels(self) -> np.ndarray:
        """``(V,)`` the connected piece of every vertex (vertices joined by the triangles'
        edges), numbered by size: 0 the piece with the most vertices; -1 a vertex no
        triangle uses."""
        f = self.faces
        i = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
        j = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
        graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(self.n_vertices,) * 2)
        _, label = connected_components(graph, directed=False)
        used = np.zeros(self.n_vertices, bool)
        used[f.ravel()] = True
        sizes = np.bincount(label[used], minlength=label.max() + 1 if len(label) else 0)
        order = np.argsort(-sizes, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        out = np.where(used, rank[label], -1)
        out.flags.writeable = False
        return out

    @property
    def n_components(self) -> int:
        """Connected pieces of the surface (vertices joined by the triangles' edges)."""
        return int(self.component_labels.max()) + 1 if self.n_faces else 0

    @property
    def volume(self) -> float:
        """Enclosed volume from the triangles (signed: positive when they face outwards),
        mm^3."""
        v = self.vertices - self.vertices.mean(axis=0)       # fewer digits cancel
        a, b, c = v[self.faces[:, 0]], v[self.faces[:, 1]], v[self.faces[:, 2]]
        return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)

    @property
    def area(self) -> float:
        """Surface area, mm^2."""
        v = self.vertices
        a, b, c = v[self.faces[:, 0]], v[self.faces[:, 1]], v[self.faces[:, 2]]
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())

    def polydata(self):
        """The mesh as a ``pyvista.PolyData`` (a copy)."""
        import pyvista as pv  # deferred: VTK loads with pyvista; only the writers need it

        return pv.PolyData.from_regular_faces(np.array(self.vertices), np.array(self.faces))

    def save(self, path) -> Path:
        """:func:`write_mesh` of this mesh."""
        return write_mesh(path, self)


def _level(level) -> float:
    level = as_scalar(level, "level", positive=True)
    if not level < 1:
        raise ValueError(f"level: expected a number in (0, 1), got {level}")
    return level


def _grid(poses, radii, voxel: float, level: float):
    """Origin ``(3,)`` and node counts ``(3,)`` of a grid whose faces lie outside the
    surface (module docstring)."""
    k = np.sqrt(max(np.log(len(poses) / level) / 2.0, 1.0))
    half = k * np.sqrt(np.einsum("bij,bj->bi", poses[:, :3, :3] ** 2, radii ** 2))
    lo = (poses[:, :3, 3] - half).min(axis=0) - voxel
    hi = (poses[:, :3, 3] + half).max(axis=0) + voxel
    shape = np.ceil((hi - lo) / voxel).astype(np.int64) + 1
    return lo, shape


def _balls(poses, radii):
    P = as_array(poses, "poses")
    if P.ndim != 3 or P.shape[1:] != (4, 4) or len(P) < 1:
        raise ValueError(f"poses: expected an array of shape (B, 4, 4) with B >= 1, got shape "
                         f"{P.shape}")
    R = _radii(radii, shape=(len(P), 3))
    if not np.allclose(P[:, :3, :3] @ P[:, :3, :3].transpose(0, 2, 1), np.eye(3), atol=1e-6):
        raise ValueError("poses: expected rigid transforms (their 3 x 3 parts rotations)")
    return np.ascontiguousarray(P), np.ascontiguousarray(R)


def _sample(P, R, voxel, level):
    voxel = as_scalar(voxel, "voxel_mm", positive=True)
    level = _level(level)
    origin, shape = _grid(P, R, voxel, level)
    if np.prod(shape.astype(float)) > 3e7:       # 240 MB of float64 before marching cubes
        raise ValueError(f"voxel_mm: a grid of {shape.tolist()} nodes at {voxel} mm is too big; "
                         "expected a coarser voxel")
    values = grid_field(origin, voxel, shape, P, R, CUTOFF)
    return values, origin, voxel, level


def metaball_mesh(poses, radii, *, voxel_mm: float = 8.0, level: float = THRESHOLD) -> BodyMesh:
    """The closed iso-surface ``F = level`` of metaballs in the world.

    Parameters
    ----------
    poses : (B, 4, 4) array
        Each ball's frame -> world (rotation and centre, mm).
    radii : (B, 3) array
        Ball radii along the ball's own axes, mm, positive.
    voxel_mm : float
        Grid step, mm (positive).
    level : float
        ``T`` in (0, 1).

    Returns
    -------
    BodyMesh

    Raises
    ------
    ValueError
        The field does not reach ``level`` at any node (the balls are smaller than a voxel).
    """
    P, R = _balls(poses, radii)
    values, origin, voxel, level = _sample(P, R, voxel_mm, level)
    if not values.max() > level:
        raise ValueError(f"voxel_mm: the field reaches {values.max():.3g} at most on the "
                         f"{voxel} mm grid, below the level {level}; expected a smaller voxel")
    # crop to the inside nodes and one node around them: the cropped grid's faces stay
    # outside, and marching cubes scans fewer cubes
    inside = np.nonzero(values >= level)
    counted = float(len(inside[0]) * voxel ** 3)
    lo = np.maximum([a.min() - 1 for a in inside], 0)
    hi = np.minimum([a.max() + 2 for a in inside], values.shape)
    values = values[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    verts, faces, _, _ = marching_cubes(values, level, spacing=(voxel,) * 3,
                                        allow_degenerate=False)
    origin = origin + voxel * lo
    # scikit-image orders a triangle clockwise seen from the larger values (inside): turn it
    return BodyMesh(vertices=verts.astype(np.float64) + origin,
                    faces=np.ascontiguousarray(faces[:, [0, 2, 1]], dtype=np.int64),
                    voxel_mm=voxel, level=level, field_volume=counted)


def metaball_volume(poses, radii, *, voxel_mm: float = 8.0, level: float = THRESHOLD) -> float:
    """The volume where ``F >= level`` by counting grid nodes (each stands for one voxel),
    mm^3; arguments as :func:`metaball_mesh`. Its error is a share of the voxels the
    surface cuts, of either sign."""
    P, R = _balls(poses, radii)
    values, _, voxel, level = _sample(P, R, voxel_mm, level)
    return float(np.count_nonzero(values >= level) * voxel ** 3)


def body_balls(model: MetaballModel, angles, scales, radii, *, base=None):
    """Every ball of one frame of ``model``: poses ``(S * 3, 4, 4)`` (ball -> world, mm) and
    radii ``(S * 3, 3)`` (mm).

    Parameters
    ----------
    model : MetaballModel
    angles : (J,) or (1, J) array
        Joint angles of the one frame, radians.
    scales : (L,) array
        Limb scales.
    radii : (S, 3, 3) array
        Ball radii, mm, positive.
    base : (4, 4) or (1, 4, 4) array, optional
        Root frame -> world, mm.

    Returns
    -------
    poses : (S * 3, 4, 4) array
    radii : (S * 3, 3) array
    """
    J = model.skeleton.n_joints
    a = as_array(angles, "angles")
    if a.shape not in ((J,), (1, J)):
        raise ValueError(f"angles: expected one frame, shape ({J},) or (1, {J}), got "
                         f"{a.shape}")
    if base is not None:
        b = as_array(base, "base")
        if b.shape not in ((4, 4), (1, 4, 4)):
            raise ValueError(f"base: expected one frame, shape (4, 4) or (1, 4, 4), got "
                             f"{b.shape}")
        base = b.reshape(1, 4, 4)
    r = _radii(radii, shape=(model.n_segments, 3, 3))
    poses = model.ball_poses(a.reshape(1, J), scales, base=base)[0].reshape(-1, 4, 4)
    return poses, r.reshape(-1, 3)


def body_mesh(model: MetaballModel, angles, scales, radii, *, base=None,
              voxel_mm: float = 8.0, level: float = THRESHOLD) -> BodyMesh:
    """One closed mesh of the whole body in one frame: :func:`metaball_mesh` of every
    ball of ``model`` (arguments as :func:`body_balls`; ``voxel_mm`` and ``level`` as
    :func:`metaball_mesh`)."""
    poses, r = body_balls(model, angles, scales, radii, base=base)
    return metaball_mesh(poses, r, voxel_mm=voxel_mm, level=level)


def body_volume(model: MetaballModel, angles, scales, radii, *, base=None,
                voxel_mm: float = 8.0, level: float = THRESHOLD) -> float:
    """:func:`metaball_volume` of every ball of ``model`` in one frame, mm^3 (arguments as
    :func:`body_mesh`)."""
    poses, r = body_balls(model, angles, scales, radii, base=base)
    return metaball_volume(poses, r, voxel_mm=voxel_mm, level=level)


def write_mesh(path, mesh: BodyMesh) -> Path:
    """Write a mesh as PLY (binary) or OBJ, by the file name's suffix (module docstring).

    Parameters
    ----------
    path : str or Path
        A ``.ply`` or ``.obj`` file name (lower case); folders are made.
    mesh : BodyMesh

    Returns
    -------
    Path
    """
    path = Path(path)
    if path.suffix not in FORMATS:          # VTK's writers fail on ".PLY"
        raise ValueError(f"path: expected a file name ending in one of {FORMATS} (lower "
                         f"case), got {path.name!r}")
    if not isinstance(mesh, BodyMesh):
        raise TypeError(f"mesh: expected a BodyMesh, got {type(mesh).__name__}")
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.polydata().save(path)
    return path
