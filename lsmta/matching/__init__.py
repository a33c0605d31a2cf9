"""Image matching: adaptive least squares matching (LSM) and correlation search.

``lsm`` matches N patches of a template in a search image at once; ``lsm_multi`` matches
them in several search images (the triplet: centre template, left and right searches);
``correlation_search`` finds the best normalised cross-correlation position in a box;
``LSMThresholds`` holds the quality indicators that accept or reject a match.
"""

from .correlation import CorrelationResult, CorrelationStatus, correlation_search
from .lsm import GEOMETRIES, PARAM_NAMES, RADIOMETRIES, LSMResult, LSMThresholds, Status, lsm
from .multi import lsm_multi
from .spline import SplineImage

__all__ = [
    "GEOMETRIES", "PARAM_NAMES", "RADIOMETRIES", "CorrelationResult", "CorrelationStatus",
    "LSMResult", "LSMThresholds", "SplineImage", "Status", "correlation_search", "lsm",
    "lsm_multi",
]
