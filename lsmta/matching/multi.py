"""Multi-image least squares matching: one template, several search images."""

from __future__ import annotations

from .._validate import as_array
from .lsm import LSMParams, LSMResult, lsm
from .spline import SplineImage


def lsm_multi(template, searches, template_xy, search_xys, *, initial_A=None,
              template_mask=None, params: LSMParams | None = None) -> list[LSMResult]:
    """Match the same template patches in each of K search images.

    Parameters
    ----------
    template : (H, W) array
        The template image (in the LSMTA triplet, the centre camera's image).
    searches : sequence of K (H, W) arrays
        The search images (left and right).
    template_xy : (N, 2) array
        Patch centres in the template.
    search_xys : sequence of K (N, 2) arrays, or a (K, N, 2) array
        Approximations in each search image.
    initial_A, template_mask
        As in :func:`~lsmta.matching.lsm`, the same for every search image.
    params : LSMParams, optional
        The settings of every match (:func:`~lsmta.matching.lsm`).

    Returns
    -------
    list of K :class:`~lsmta.matching.LSMResult`, one per search image.
    """
    searches = list(searches)
    if not searches:
        raise ValueError("searches: expected at least one search image")
    if len(search_xys) != len(searches):
        raise ValueError(f"search_xys: expected {len(searches)} arrays of approximations "
                         f"(one per search image), got {len(search_xys)}")
    f = template if isinstance(template, SplineImage) else SplineImage(template, "template")
    t_xy = as_array(template_xy, "template_xy", shape=(None, 2))
    return [lsm(f, g, t_xy, xy, initial_A=initial_A, template_mask=template_mask, params=params)
            for g, xy in zip(searches, search_xys)]
