"""Silhouettes and their contours (D'Apuzzo et al. 2000, Fig. 16).

``background``  a per-pixel background model learnt from frames without the person; the
                person's silhouette as the largest connected region that differs from it
``contours``    closed contours of masks; snakes (scikit-image's ``active_contour``, Kass et
                al. 1988) tracked over frames, each start predicted from the projected 3-D
                trajectories of the points near the contour

Image points are ``(x, y)`` pixels (x right, y down, origin at the centre of the top-left
pixel), as everywhere in lsmta; scikit-image's ``(row, col)`` stays inside this package.
"""

from .background import (
    BackgroundModel,
    SilhouetteParams,
    largest_region,
    learn_background,
    silhouettes,
)
from .contours import (
    ContourTracks,
    SnakeParams,
    fit_snake,
    mask_contour,
    predict_contour,
    track_contours,
)

__all__ = [
    "BackgroundModel", "ContourTracks", "SilhouetteParams", "SnakeParams", "fit_snake",
    "largest_region",
    "learn_background", "mask_contour", "predict_contour", "silhouettes", "track_contours",
]
