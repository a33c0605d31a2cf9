"""Segment-based articulated point matching (Li & Holstein 2002): label an unlabelled 3-D
marker pose from one frame with an articulated marker model, and the baseline a user might
try instead (one global rigid fit plus optimal assignment)."""

from .baseline import global_assignment
from .identify import Identification, SAPMParams, identify
from .model import MarkerModel

__all__ = ["Identification", "MarkerModel", "SAPMParams", "global_assignment", "identify"]
