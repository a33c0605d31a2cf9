"""Image matching: adaptive least squares matching (LSM) and correlation search.

``lsm`` matches N patches of a template in a search image at once; ``lsm_multi`` matches
them in several search images (the triplet: centre template, left and right searches);
``correlation_search`` finds the best normalised cross-correlation position in a box;
``LSMThresholds`` holds the quality indicators that accept or reject a match;
``grow_matches`` grows dense matches from seeds, ``measure_surface`` turns one multi-image
frame into 3-D surface points; ``backdrop_mask`` finds an object in front of a dark backdrop
(a ``template_mask`` for matching next to its silhouette).
"""

from .correlation import CorrelationResult, CorrelationStatus, correlation_search
from .filters import NeighbourhoodCheck, neighbourhood_filter
from .grow import GrowResult, grow_matches
from .lsm import GEOMETRIES, PARAM_NAMES, RADIOMETRIES, LSMResult, LSMThresholds, Status, lsm
from .masks import backdrop_mask
from .multi import lsm_multi
from .seeds import Seeds, find_seeds
from .spline import SplineImage
from .surface import SurfaceResult, enhance_contrast, measure_surface

__all__ = [
    "GEOMETRIES", "PARAM_NAMES", "RADIOMETRIES", "CorrelationResult", "CorrelationStatus",
    "GrowResult", "LSMResult", "LSMThresholds", "NeighbourhoodCheck", "Seeds", "SplineImage",
    "Status", "SurfaceResult", "backdrop_mask", "correlation_search", "enhance_contrast",
    "find_seeds", "grow_matches", "lsm", "lsm_multi", "measure_surface", "neighbourhood_filter",
]
