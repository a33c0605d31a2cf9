"""Object masks from the images themselves, for matching near a silhouette."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .spline import check_image


def backdrop_mask(image, threshold: float, *, smooth: float = 1.0) -> np.ndarray:
    """Pixels of an object in front of a dark, untextured backdrop.

    The image is smoothed by a Gaussian of ``smooth`` pixels (SciPy's ``gaussian_filter``,
    so that noise on the backdrop does not pass) and thresholded. Holes are not filled: the
    backdrop shows through the gaps between arm and torso or between the legs, and dark
    spots on the object only leave a few pixels out. Pass the result as ``template_mask``
    to :func:`~lsmta.matching.grow.grow_matches` or
    :func:`~lsmta.matching.surface.measure_surface`.

    Parameters
    ----------
    image : (H, W) array
        Grey image (any real dtype); not modified.
    threshold : float
        Grey level between the backdrop's and the object's darkest parts.
    smooth : float
        Gaussian standard deviation in pixels (0: no smoothing).

    Returns
    -------
    (H, W) bool array
    """
    img = check_image(image, "image")
    if not np.isfinite(threshold):
        raise ValueError(f"threshold: expected a finite grey level, got {threshold}")
    if not (np.isfinite(smooth) and smooth >= 0):
        raise ValueError(f"smooth: expected a non-negative number of pixels, got {smooth}")
    if smooth > 0:
        img = ndimage.gaussian_filter(img, smooth)
    return img > threshold
