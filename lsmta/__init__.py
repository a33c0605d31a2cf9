"""lsmta: recovering human shape and motion from multi-camera video.

A notebook-first compendium that re-implements D'Apuzzo, Plaenkers & Fua (2000),
Holstein & Li (2002), Davis (2002) and Plaenkers & Fua (1999). See README.md and
ARCHITECTURE.md for the layout.
"""

from .camera import Camera
from .triangulation import Intersection, intersect_rays, triangulate

__version__ = "0.1.0"
__all__ = ["Camera", "Intersection", "intersect_rays", "triangulate", "__version__"]
