"""Ellipsoidal metaballs on a skeleton (Plänkers et al. 1999, Sections 3.3 and 3.4).

One primitive ``i`` has the ellipsoidal distance (eq. 6)
``d_i = (x/lx)^2 + (y/ly)^2 + (z/lz)^2`` in its own frame and the potential (eq. 7)
``f_i = w_i exp(-2 d_i)``; the field is the sum over primitives (eq. 5) and the skin is the
level set ``F = T`` (eq. 4), with ``w_i = 1`` and ``T = 1/2`` as in the paper's eq. 14.

The simplified limb of Section 3.3: every limb segment carries three metaballs at fixed
fractions of its bone, oriented with the bone; their radii are what the fit changes. The
higher-level size parameters of the simplified model are one width and one depth per
segment (e.g. "upper-arm width"), which scale a fixed profile of the three balls; the full
model frees the width and depth of each ball. The radius along the bone is tied to the
bone, ``lz = 0.3 L s`` (our choice: with it free, the ends of a segment can be moved by
the bone length or by the end balls' radius alike, and the fit trades one for the other).

Distance to the skin in millimetres
    The fit needs a residual per 3-D point. Eq. 14 uses ``F - T`` itself, which is in field
    units and vanishes far from the limb (``exp`` underflows), so distant points barely
    pull. We use its logarithm, ``psi = -ln(F) / 2`` (for a single ball ``psi = d``,
    evaluated as a log-sum-exp), and ``r = l (sqrt(psi) - sqrt(psi_T))`` with
    ``psi_T = -ln(T) / 2`` and ``l = sqrt(lx ly)`` of the segment's middle ball: the exact
    distance for a round ball, zero on the same surface as eq. 14, and in mm, so that
    a-priori standard deviations in mm weigh it (eq. 11). (A first-order distance
    ``(psi - psi_T) / |grad psi|`` was tried first; its analytic derivative needs the
    Hessian of ``psi``, and dropping that term stalled the fit away from the skin.)
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from skimage.measure import marching_cubes

from .._validate import as_array, as_scalar
from ._kernels import all_segment_distances, segment_distances
from .skeleton import Skeleton

THRESHOLD = 0.5                      # T of eq. 4 / w_t of eq. 13
FRACTIONS = (1 / 6, 1 / 2, 5 / 6)    # ball positions along the bone (share of its length)
PROFILE = (0.9, 1.0, 0.9)            # relative size of the three balls (simplified model)
LENGTH_RADIUS = 0.3                  # ball radius along the bone, share of the bone length
_ROOT_T = float(np.sqrt(-0.5 * np.log(THRESHOLD)))   # sqrt(psi_T) of the default threshold


def _radii(radii, name: str = "radii", shape=None) -> np.ndarray:
    """Radii as a float array: finite, positive, last axis 3 (mm)."""
    r = as_array(radii, name, shape=shape)
    if r.ndim == 0 or r.shape[-1] != 3:
        raise ValueError(f"{name}: expected radii with a last axis of length 3, got shape "
                         f"{r.shape}")
    if not (r > 0).all():
        raise ValueError(f"{name}: expected positive radii (mm), got min {r.min()}")
    return r


def _local(local, name: str = "local", ndim: int | None = None) -> np.ndarray:
    """Local coordinates, last axis 3 (NaN allowed: it propagates)."""
    q = as_array(local, name, allow_nan=True)
    if q.ndim == 0 or q.shape[-1] != 3 or (ndim is not None and q.ndim != ndim):
        want = "(..., 3)" if ndim is None else "(" + ", ".join(["N", "B", "3"][-ndim:]) + ")"
        raise ValueError(f"{name}: expected an array of shape {want}, got shape {q.shape}")
    return q


def ellipsoid_distance(local, radii) -> np.ndarray:
    """Eq. 6: ``(x/lx)^2 + (y/ly)^2 + (z/lz)^2`` for ``local (..., 3)`` and ``radii (..., 3)``
    (mm, broadcast against each other; radii positive)."""
    q = _local(local) / _radii(radii)
    return np.sum(q * q, axis=-1)


def potential(d, *, weight=1.0) -> np.ndarray:
    """Eq. 7: ``w exp(-2 d)``."""
    return weight * np.exp(-2.0 * np.asarray(d, float))


def field(local, radii) -> np.ndarray:
    """Eq. 5: the summed field ``(N,)`` of B balls; ``local (N, B, 3)`` and ``radii (B, 3)``
    in mm (radii positive)."""
    q = _local(local, ndim=3)
    r = _radii(radii, shape=(q.shape[1], 3))
    return potential(ellipsoid_distance(q, r)).sum(axis=-1)


def surface_distance(local, radii, *, threshold: float = THRESHOLD) -> np.ndarray:
    """Distance-like residual (mm) of points to the skin ``F = T`` of one segment's balls.

    ``r = l (sqrt(psi) - sqrt(psi_T))`` with ``psi = -ln(F) / 2``, ``psi_T = -ln(T) / 2``
    and ``l = sqrt(lx ly)`` of the middle ball: exactly the distance to the surface for a
    single round ball, zero exactly on the surface of eq. 14 (module docstring).

    Parameters
    ----------
    local : (N, B, 3) array
        Each point in each ball's frame (all balls of a segment share the orientation),
        mm.
    radii : (B, 3) array
        Ball radii, mm.
    threshold : float
        ``T``.

    Returns
    -------
    (N,) array
        Positive outside, negative inside (mm).
    """
    return _skin(local, radii, threshold).r


@dataclass(frozen=True, eq=False)
class SkinDistance:
    """:func:`surface_distance` and the quantities its analytic Jacobian needs.

    Attributes
    ----------
    r : (N,) array
        The distance-like residual, mm.
    grad : (N, 3) array
        ``d psi / d x`` in the segment's frame.
    p : (N, B) array
        Each ball's share of the field (``d psi / d d_b``).
    dr_dpsi : (N,) array
    ell : float
        ``l``, mm.
    root : (N,) array
        ``sqrt(psi) - sqrt(psi_T)``.
    """

    r: np.ndarray
    grad: np.ndarray
    p: np.ndarray
    dr_dpsi: np.ndarray
    ell: float
    root: np.ndarray


def surface_distance_terms(local, radii, *, threshold: float = THRESHOLD) -> SkinDistance:
    """:func:`surface_distance` (same arguments) with its derivatives (:class:`SkinDistance`)."""
    sk = _skin(local, radii, threshold)
    p = sk.p / sk.total                                   # softmax weights
    grad = np.einsum("nb,nbk->nk", p, 2.0 * sk.q / sk.radii)
    dr = np.where(sk.inside, 0.0, sk.ell / (2 * sk.sq))
    return SkinDistance(r=sk.r, grad=grad, p=p, dr_dpsi=dr, ell=sk.ell, root=sk.root)


@dataclass(frozen=True, eq=False)
class _Skin:
    r: np.ndarray
    q: np.ndarray        # (N, B, 3) local / radii
    radii: np.ndarray
    p: np.ndarray        # (N, B) exp(-2 d_b - max), not normalised
    total: np.ndarray    # (N, 1) their sum
    inside: np.ndarray   # (N,) deep inside a blend (F > 1)
    sq: np.ndarray       # (N,) sqrt(psi)
    ell: float
    root: np.ndarray


def _skin(local, radii, threshold) -> _Skin:
    local = _local(local, ndim=3)
    radii = _radii(radii, shape=(local.shape[1], 3))
    threshold = as_scalar(threshold, "threshold", positive=True)
    if not threshold < 1:
        raise ValueError(f"threshold: expected a number in (0, 1), got {threshold}")
    q = local / radii                                     # (N, B, 3)
    d = np.sum(q * q, axis=-1)                            # (N, B)
    e = -2.0 * d
    top = e.max(axis=1, keepdims=True)
    p = np.exp(e - top)
    total = p.sum(axis=1, keepdims=True)
    lnF = (top + np.log(total))[:, 0]                     # log-sum-exp, (N,)
    psi = -0.5 * lnF
    inside = psi < 1e-9                                   # deep inside a blend (F > 1)
    sq = np.sqrt(np.where(inside, 1e-9, psi))
    ell = float(np.sqrt(radii[len(radii) // 2, 0] * radii[len(radii) // 2, 1]))
    root = sq - np.sqrt(-0.5 * np.log(threshold))
    return _Skin(r=ell * root, q=q, radii=radii, p=p, total=total, inside=inside, sq=sq,
                 ell=ell, root=root)


@dataclass(frozen=True)
class Segment:
    """A limb segment carrying three metaballs along its bone.

    Attributes
    ----------
    name : str
    joint : int
        Skeleton joint whose frame carries the segment.
    rotation : (3, 3) tuple of tuples
        Bone frame -> joint frame rotation; the bone runs along the bone frame's -z axis
        from the joint.
    length : float
        Bone length at scale 1 (mm).
    limb : int
        Limb scale that multiplies the length.
    """

    name: str
    joint: int
    rotation: tuple
    length: float
    limb: int


@dataclass(frozen=True)
class MetaballModel:
    """A skeleton with metaball segments; shapes are ``(S, 3, 3)`` radii (segment, ball,
    axis) in mm.

    Attributes
    ----------
    skeleton : Skeleton
    segments : tuple of Segment
    fractions : (3,) tuple
        Ball centres along each bone, as shares of its (scaled) length.
    profile : (3,) tuple
        Relative ball sizes of the simplified model.
    length_radius : float
        Ball radius along the bone, as a share of the bone length.
    offsets : tuple or None
        ``(S, 3, 2)`` nested tuple: each ball's shift across its bone (bone-frame x and y,
        mm), for parts that do not sit on their bone (a foot below the ankle, a head in
        front of the neck); None: every ball on its bone (:meth:`with_offsets`).
    """

    skeleton: Skeleton
    segments: tuple
    fractions: tuple = FRACTIONS
    profile: tuple = PROFILE
    length_radius: float = LENGTH_RADIUS
    offsets: tuple | None = None

    @property
    def n_segments(self) -> int:
        return len(self.segments)

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.segments]

    def with_offsets(self, offsets) -> MetaballModel:
        """This model with its balls shifted across their bones by ``offsets (S, 3, 2)`` mm."""
        o = as_array(offsets, "offsets", shape=(self.n_segments, 3, 2))
        return replace(self, offsets=tuple(tuple(map(tuple, b)) for b in o.tolist()))

    def simplified_radii(self, size, scales) -> np.ndarray:
        """Radii ``(S, 3, 3)`` from the higher-level sizes ``(S, 2)`` = (width, depth) per
        segment (mm) and the limb scales ``(L,)``."""
        size = as_array(size, "size", shape=(self.n_segments, 2))
        w = np.asarray(self.profile)[None, :, None] * size[:, None, :]
        return self.full_radii(w, scales)

    def full_radii(self, widths, scales) -> np.ndarray:
        """Radii ``(S, 3, 3)`` from per-ball widths and depths ``(S, 3, 2)`` (mm) and the
        limb scales: the third radius is ``length_radius`` times the bone length."""
        widths = as_array(widths, "widths", shape=(self.n_segments, 3, 2))
        lz = self.length_radius * self.bone_lengths(as_array(scales, "scales"))
        return np.concatenate([widths, np.broadcast_to(lz[:, None, None],
                                                       (self.n_segments, 3, 1))], axis=2)

    @cached_property
    def _arrays(self) -> tuple:
        """The segments as arrays: bone frame -> joint frame ``(S, 4, 4)``, joint ``(S,)``,
        length ``(S,)`` (mm), limb ``(S,)``, and the offsets ``(S, 3, 2)`` or None."""
        S = self.n_segments
        R = np.tile(np.eye(4), (S, 1, 1))
        R[:, :3, :3] = np.array([seg.rotation for seg in self.segments], float).reshape(S, 3, 3)
        out = (R, np.array([seg.joint for seg in self.segments], np.int64),
               np.array([seg.length for seg in self.segments], float),
               np.array([seg.limb for seg in self.segments], np.int64),
               None if self.offsets is None else np.array(self.offsets, float))
        for a in out[:4]:
            a.flags.writeable = False
        return out

    def frames(self, angles, scales, *, base=None) -> np.ndarray:
        """Bone frame -> world transforms ``(T, S, 4, 4)``."""
        W = self.skeleton.transforms(angles, scales, base=base)
        R, joint = self._arrays[:2]
        return W[:, joint] @ R

    def centres(self, scales) -> np.ndarray:
        """Ball centres in their bone frames, ``(S, 3, 3)`` (mm)."""
        scales = as_array(scales, "scales", shape=(len(self.skeleton.limbs),))
        _, _, length, limb, offsets = self._arrays
        out = np.zeros((self.n_segments, 3, 3))
        out[:, :, 2] = -np.asarray(self.fractions)[None] * length[:, None] * scales[limb][:, None]
        if offsets is not None:
            out[..., :2] = offsets
        return out

    def bone_lengths(self, scales) -> np.ndarray:
        """Segment lengths ``(S,)`` in mm."""
        _, _, length, limb, _ = self._arrays
        return length * np.asarray(scales)[limb]

    def distance(self, points, segment, angles, scales, radii, *, base=None, frame=None):
        """Signed distance (mm) of world points to their segment's skin.

        Parameters
        ----------
        points : (N, 3) array
        segment : (N,) int array
            Segment of each point.
        angles : (T, J) array; scales : (L,); radii : (S, 3, 3); base : (T, 4, 4)
        frame : (N,) int array, optional
            Frame of each point (default all 0).
        """
        points = as_array(points, "points", shape=(None, 3), allow_nan=True)
        N = len(points)
        segment = self._indices(segment, "segment", N, self.n_segments)
        radii = _radii(radii, shape=(self.n_segments, 3, 3))
        F = self.frames(angles, scales, base=base)
        C = self.centres(scales)
        frame = np.zeros(N, int) if frame is None else self._indices(frame, "frame", N, len(F))
        return segment_distances(points, segment.astype(np.int64, copy=False),
                                 frame.astype(np.int64, copy=False), F, C, radii, _ROOT_T)

    @staticmethod
    def _indices(value, name: str, n: int, upper: int) -> np.ndarray:
        """``(n,)`` integer indices in ``[0, upper)``."""
        v = np.asarray(value)
        if v.shape != (n,) or not (np.issubdtype(v.dtype, np.integer) or v.size == 0):
            raise ValueError(f"{name}: expected an integer array of shape ({n},), got "
                             f"{v.dtype} of shape {v.shape}")
        if v.size and (v.min() < 0 or v.max() >= upper):
            raise ValueError(f"{name}: expected indices in [0, {upper}), got "
                             f"[{v.min()}, {v.max()}]")
        return v

    def all_distances(self, points, angles, scales, radii, *, base=None, frame=None):
        """Distances ``(N, S)`` of every point to every segment's skin (for segmentation)."""
        points = as_array(points, "points", shape=(None, 3), allow_nan=True)
        N = len(points)
        radii = _radii(radii, shape=(self.n_segments, 3, 3))
        F = self.frames(angles, scales, base=base)
        C = self.centres(scales)
        frame = np.zeros(N, int) if frame is None else self._indices(frame, "frame", N, len(F))
        return all_segment_distances(points, frame.astype(np.int64, copy=False), F, C, radii,
                                     _ROOT_T)

    def world_field(self, points, angles, scales, radii, *, base=None) -> np.ndarray:
        """The whole model's field ``(N,)`` at world points ``(N, 3)`` (mm) for one frame
        (display); radii ``(S, 3, 3)`` mm, positive."""
        points = as_array(points, "points", shape=(None, 3))
        radii = _radii(radii, shape=(self.n_segments, 3, 3))
        F = self.frames(angles, scales, base=base)[0]
        C = self.centres(scales)
        total = np.zeros(len(points))
        for k in range(self.n_segments):
            local = (points - F[k, :3, 3]) @ F[k, :3, :3]
            total += field(local[:, None, :] - C[k][None], radii[k])
        return total

    def ball_poses(self, angles, scales, *, base=None) -> np.ndarray:
        """World pose of every ball ``(T, S, 3, 4, 4)`` (for drawing the ellipsoids)."""
        F = self.frames(angles, scales, base=base)
        C = self.centres(scales)
        T = np.tile(np.eye(4), C.shape[:2] + (1, 1))
        T[..., :3, 3] = C
        return F[:, :, None] @ T[None]


def iso_surface(model: MetaballModel, angles, scales, radii, *, base=None, spacing: float = 8.0,
                threshold: float = THRESHOLD, margin: float = 10.0):
    """The skin ``F = T`` of one frame as a triangle mesh (marching cubes, scikit-image).

    For figures and skin distances. Its grid reaches ``max(radii) + margin`` beyond the
    balls, which closes the skin of the models' usual shapes but is not a bound;
    :func:`lsmta.body.mesh.body_mesh` sizes its grid so that the mesh is closed in any pose
    (and counts its open edges, pieces and volume): use it for a mesh to export.

    Parameters
    ----------
    model : MetaballModel
    angles : (1, J) array
        Joint angles of the one frame, radians.
    scales : (L,) array
        Limb scales (dimensionless).
    radii : (S, 3, 3) array
        Ball radii, mm, positive.
    base : (1, 4, 4) array, optional
        Root frame -> world, mm.
    spacing : float
        Grid step of the field samples, mm (the mesh's resolution).
    threshold : float
        ``T`` of eq. 4, in (0, 1).
    margin : float
        Extra grid around the balls, mm (>= 0).

    Returns
    -------
    vertices : (V, 3) array
        World coordinates, mm.
    faces : (F, 3) int array
        Vertex indices of each triangle.
    """
    spacing = as_scalar(spacing, "spacing", positive=True)
    margin = as_scalar(margin, "margin", nonnegative=True)
    threshold = as_scalar(threshold, "threshold", positive=True)
    if not threshold < 1:
        raise ValueError(f"threshold: expected a number in (0, 1), got {threshold}")
    angles = as_array(angles, "angles", shape=(1, None))
    radii = _radii(radii, shape=(model.n_segments, 3, 3))
    poses = model.ball_poses(angles, scales, base=base)[0].reshape(-1, 4, 4)
    # a lone ball's skin lies at 0.59 of its radii; three blended ones stay inside 1.0
    reach = float(np.max(radii)) + margin + spacing
    lo = poses[:, :3, 3].min(axis=0) - reach
    hi = poses[:, :3, 3].max(axis=0) + reach
    axes = [np.arange(a, b + spacing, spacing) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    values = model.world_field(grid.reshape(-1, 3), angles, scales, radii, base=base)
    values = values.reshape(grid.shape[:3])
    verts, faces, _, _ = marching_cubes(values, threshold, spacing=(spacing,) * 3)
    return verts + lo, faces
