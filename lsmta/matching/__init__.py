"""Image matching: adaptive least squares matching (LSM) and correlation search.

``lsm`` matches N patches of a template in a search image at once; ``lsm_multi`` matches
them in several search images (the triplet: centre template, left and right searches);
``correlation_search`` finds the best normalised cross-correlation position in a box;
``LSMThresholds`` holds the quality indicators that accept or reject a match;
``grow_matches`` grows dense matches from seeds, ``measure_surface`` turns one multi-image
frame into 3-D surface points; ``backdrop_mask`` finds an object in front of a dark backdrop
(a ``template_mask`` for matching next to its silhouette). Beyond the paper: ``mpgc``
matches one template in all search images jointly under the epipolar condition (Gruen &
Baltsavias 1988; ``RectifiedPair``, ``CameraGeometry``), ``grow_joint`` grows that way, and
``measure_disparity`` gives the dense disparity of a rectified pair (``seeds="sgbm"``: started
from OpenCV SGBM's disparities, ``sgbm_start``, ``refine_disparities``); ``symmetric_corners``
finds chessboard corners by the point symmetry of their neighbourhood.

Every matcher takes its settings as one frozen dataclass, ``params=``: ``LSMParams`` (``lsm``,
``lsm_multi``, ``mpgc``), ``GrowParams`` (``grow_matches``, ``grow_joint``),
``MeasureSurfaceParams`` (``measure_surface``, holding a ``GrowParams``) and
``DisparityParams`` (``measure_disparity``).
"""

from .correlation import CorrelationResult, CorrelationStatus, correlation_search
from .disparity import DisparityParams, DisparityResult, measure_disparity, refine_disparities
from .filters import NeighbourhoodCheck, neighbourhood_filter
from .grow import AttemptOutcome, GrowParams, GrowResult, NodeOutcome, grow_joint, grow_matches
from .lsm import (
    GEOMETRIES,
    PARAM_NAMES,
    RADIOMETRIES,
    LSMParams,
    LSMResult,
    LSMThresholds,
    Status,
    lsm,
)
from .masks import backdrop_mask
from .mpgc import CameraGeometry, ConstrainedResult, RectifiedPair, mpgc
from .multi import lsm_multi
from .refine import refine_at_nodes, sgbm_start
from .seeds import Seeds, find_disparity_seeds, find_seeds
from .spline import SplineImage
from .surface import MeasureSurfaceParams, SurfaceResult, enhance_contrast, measure_surface
from .symmetry import SymmetricCorners, symmetric_corners

__all__ = [
    "GEOMETRIES", "PARAM_NAMES", "RADIOMETRIES", "AttemptOutcome", "CameraGeometry",
    "ConstrainedResult",
    "CorrelationResult", "CorrelationStatus", "DisparityParams", "DisparityResult",
    "GrowParams", "GrowResult", "LSMParams", "LSMResult", "LSMThresholds",
    "MeasureSurfaceParams", "NeighbourhoodCheck", "NodeOutcome", "RectifiedPair", "Seeds",
    "SplineImage",
    "Status", "SurfaceResult", "SymmetricCorners", "backdrop_mask", "correlation_search",
    "enhance_contrast",
    "find_disparity_seeds", "find_seeds", "grow_joint", "grow_matches", "lsm", "lsm_multi",
    "measure_disparity", "measure_surface", "mpgc", "neighbourhood_filter",
    "refine_at_nodes", "refine_disparities", "sgbm_start", "symmetric_corners",
]
