"""Segment-based articulated point matching (Holstein & Li 2002): label an unlabelled 3-D
marker pose from one frame with an articulated marker model, and the baseline a user might
try instead (one global rigid fit plus optimal assignment). A model comes from one clear
frame (the paper) or is learned from a labelled clip (:meth:`MarkerModel.from_labelled_frames`,
segments proposed by :func:`suggest_segments`); several instances of one model in one cloud
are labelled by :func:`identify_instances`."""

from .baseline import global_assignment
from .grouping import SegmentSuggestion, suggest_segments
from .identify import Identification, SAPMParams, identify
from .instances import Instances, identify_instances
from .learning import LearnParams
from .model import MarkerModel

__all__ = ["Identification", "Instances", "LearnParams", "MarkerModel", "SAPMParams",
           "SegmentSuggestion", "global_assignment", "identify", "identify_instances",
           "suggest_segments"]
