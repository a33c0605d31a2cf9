"""Cramér-Rao lower bound of the position found by least squares matching.

For the model of :mod:`lsmta.matching.lsm`, ``f(u) = r0 + r1 g(c + A u) + e``, with
independent Gaussian noise of standard deviation ``sigma`` in *both* images, the
difference image has noise variance ``sigma**2 (1 + r1**2)``, and the bound on the
parameters is ``sigma**2 (1 + r1**2) (J^T J)^-1`` with ``J`` the design matrix at the true
parameters, built from the noise-free search image and its gradient (the bound for
registering two equally noisy images; Robinson & Milanfar 2004, Pham et al. 2005). The
caller supplies those noise-free values; this module only does the algebra.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array, as_scalar, check_patch
from .lsm import GEOMETRIES, RADIOMETRIES


def patch_offsets(patch: int) -> np.ndarray:
    """Offsets ``u`` ``(P, 2)`` (x, y) of the pixels of a ``patch x patch`` patch, row by row."""
    h = check_patch(patch) // 2
    gy, gx = np.mgrid[-h:h + 1, -h:h + 1]
    return np.stack([gx.ravel(), gy.ravel()], axis=1).astype(float)


def cramer_rao_xy(g, gx, gy, *, patch: int, r1=1.0, noise_sigma: float,
                  geometry: str = "affine", radiometry: str = "linear") -> np.ndarray:
    """Cramér-Rao covariance ``(N, 2, 2)`` (px²) of the matched position.

    Parameters
    ----------
    g, gx, gy : (N, P) arrays
        Noise-free search image and its x, y derivatives at the true positions
        ``c + A u`` of the ``P = patch**2`` patch pixels (order of :func:`patch_offsets`).
    patch : int
    r1 : float or (N,) array
        True radiometric gain.
    noise_sigma : float
        Noise standard deviation of each image, grey levels.
    geometry, radiometry : str
        The parameter set whose bound is wanted (as in :func:`~lsmta.matching.lsm`).
    """
    if geometry not in GEOMETRIES or radiometry not in RADIOMETRIES:
        raise ValueError("geometry, radiometry: expected names known to lsm()")
    U = patch_offsets(patch)
    g = as_array(g, "g", shape=(None, len(U)))
    gx = as_array(gx, "gx", shape=g.shape)
    gy = as_array(gy, "gy", shape=g.shape)
    sigma = as_scalar(noise_sigma, "noise_sigma", nonnegative=True)
    r1 = np.broadcast_to(np.asarray(r1, float), (len(g),))
    Gx, Gy = r1[:, None] * gx, r1[:, None] * gy
    ux, uy = U[None, :, 0], U[None, :, 1]
    cols = [Gx, Gy]
    if geometry == "similarity":
        cols += [Gx * ux + Gy * uy, -Gx * uy + Gy * ux]
    elif geometry == "affine":
        cols += [Gx * ux, Gx * uy, Gy * ux, Gy * uy]
    elif geometry == "row-affine":
        cols += [Gx * ux, Gx * uy]
    if radiometry != "none":
        cols.append(np.ones_like(g))
    if radiometry == "linear":
        cols.append(g)
    J = np.stack(cols, axis=-1)
    info = J.transpose(0, 2, 1) @ J
    cov = np.linalg.inv(info)[:, :2, :2]
    return sigma**2 * (1 + r1[:, None, None] ** 2) * cov
