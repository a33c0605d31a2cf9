"""The silhouette term: lines of sight through the observed contour touch the skin.

Our form of the silhouette observation of Plänkers et al.'s earlier work (their ref. [5]):
a point on a camera's observed contour defines a line of sight ``x(l) = o + l d``; if the
contour belongs to the model, that line grazes the model's skin. The residual is the
line's closest approach to the skin,

    ``r = min_l D(o + l d)``,  ``D(x) = min_s D_s(x)``

with ``D_s`` the signed skin distance of segment ``s`` (mm, :meth:`MetaballModel.distance`):
zero for a tangent line, positive when the line misses the model (the model's outline lies
inside the contour there), negative when it passes through it. The minimum over ``l`` is
found on a grid of depths and refined by golden-section search on the nearest segment.

Its derivative needs no derivative of the minimiser (envelope theorem): at the minimum
``dD/dl = 0``, so ``dr/dtheta = dD_s/dtheta`` at the fixed world point ``x*``; moving the
segment by ``dX/dtheta`` (a point carried by the segment, :meth:`Skeleton.jacobian`) is
moving ``x*`` the other way in the segment's frame: ``dr/dtheta = -grad_x D_s(x*) . dX/dtheta``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_scalar, freeze
from .metaballs import MetaballModel, _radii, surface_distance_terms

_GOLD = (np.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True, eq=False)
class SilhouetteTerms:
    """Residuals of lines of sight and their derivatives.

    Attributes
    ----------
    r : (N,) array
        Closest approach of each line to the skin (mm; negative: through the model).
    d_angles : (N, J) array
        ``dr / dtheta`` (mm per radian).
    closest : (N, 3) array
        The point of closest approach (world mm).
    segment : (N,) int array
        The segment the line comes closest to.
    """

    r: np.ndarray
    d_angles: np.ndarray
    closest: np.ndarray
    segment: np.ndarray

    def __post_init__(self):
        freeze(self, ("r", "d_angles", "closest", "segment"))


def _distance(model, origins, directions, depth, segment, angles, scales, radii, base):
    pts = origins + depth[:, None] * directions
    return model.distance(pts, segment, angles, scales, radii, base=base)


def silhouette_terms(model: MetaballModel, origins, directions, angles, scales, radii, *,
                     near: float, far: float, base=None, n_steps: int = 64,
                     n_refine: int = 40) -> SilhouetteTerms:
    """The silhouette residual of each line of sight and its derivative by the joint angles.

    Parameters
    ----------
    model : MetaballModel
    origins, directions : (N, 3) arrays
        Lines of sight through the observed contour points (e.g. ``Camera.rays``), mm and
        unit vectors.
    angles : (1, J) array
        Joint angles of the one frame (radians).
    scales : (L,) array; radii : (S, 3, 3) array (mm); base : (1, 4, 4) array, optional
    near, far : float
        Depth range searched along every line (mm from its origin), e.g. the person's
        distance from the camera plus or minus a metre.
    n_steps : int
        Depth grid; n_refine : int, golden-section steps.

    Returns
    -------
    SilhouetteTerms
    """
    origins = as_array(origins, "origins", shape=(None, 3))
    directions = as_array(directions, "directions", shape=origins.shape)
    angles = as_array(angles, "angles", shape=(1, model.skeleton.n_joints))
    radii = _radii(radii, shape=(model.n_segments, 3, 3))
    near, far = as_scalar(near, "near", nonnegative=True), as_scalar(far, "far", positive=True)
    if not far > near:
        raise ValueError(f"far: expected a depth beyond near = {near}, got {far}")
    if int(n_steps) != n_steps or n_steps < 3 or int(n_refine) != n_refine or n_refine < 1:
        raise ValueError(f"n_steps, n_refine: expected integers >= 3 and >= 1, got {n_steps}, "
                         f"{n_refine}")
    N = len(origins)
    depths = np.linspace(near, far, int(n_steps))
    grid = origins[:, None, :] + depths[None, :, None] * directions[:, None, :]
    D = model.all_distances(grid.reshape(-1, 3), angles, scales, radii, base=base) \
        .reshape(N, len(depths), model.n_segments)
    segment = np.argmin(D.min(axis=1), axis=1)
    k = np.argmin(D[np.arange(N), :, segment], axis=1)
    step = depths[1] - depths[0]
    lo, hi = depths[k] - step, depths[k] + step
    args = (segment, angles, scales, radii, base)
    a, b = hi - _GOLD * (hi - lo), lo + _GOLD * (hi - lo)
    fa = _distance(model, origins, directions, a, *args)
    fb = _distance(model, origins, directions, b, *args)
    for _ in range(int(n_refine)):
        left = fa < fb                          # the minimum lies in [lo, b]
        lo, hi = np.where(left, lo, a), np.where(left, b, hi)
        a_new, b_new = hi - _GOLD * (hi - lo), lo + _GOLD * (hi - lo)
        moved = np.where(left, a_new, b_new)
        f_moved = _distance(model, origins, directions, moved, *args)
        fa, fb, a, b = (np.where(left, f_moved, fb), np.where(left, fa, f_moved),
                        np.where(left, a_new, b), np.where(left, a, b_new))
    depth = 0.5 * (lo + hi)
    closest = origins + depth[:, None] * directions
    r = model.distance(closest, segment, angles, scales, radii, base=base)
    return SilhouetteTerms(r=r, d_angles=_angle_derivative(model, closest, segment, angles,
                                                           scales, radii, base),
                           closest=closest, segment=segment)


def _angle_derivative(model, x, segment, angles, scales, radii, base) -> np.ndarray:
    """``-grad_x D_s(x) . dX/dtheta`` for world points ``x (N, 3)`` on segments ``(N,)``."""
    F = model.frames(angles, scales, base=base)[0]
    W = model.skeleton.transforms(angles, scales, base=base)[0]
    C = model.centres(scales)
    out = np.zeros((len(x), model.skeleton.n_joints))
    for s in np.unique(segment):
        sel = segment == s
        R, o = F[s, :3, :3], F[s, :3, 3]
        local = (x[sel] - o) @ R
        t = surface_distance_terms(local[:, None, :] - C[s][None], radii[s])
        grad = (t.dr_dpsi[:, None] * t.grad) @ R.T                        # world gradient
        j = model.segments[s].joint
        in_joint = (x[sel] - W[j, :3, 3]) @ W[j, :3, :3]
        d_th, _ = model.skeleton.jacobian(angles, scales, np.full(sel.sum(), j), in_joint,
                                          base=base)
        out[sel] = -np.einsum("nk,nkj->nj", grad, d_th[0])
    return out
