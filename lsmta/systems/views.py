"""Which cameras of a rig see the same side of the subject: the groups the LSMTA system
measures and tracks together.

A surface point is matched by LSM between views that see it from similar directions: the
affine patch model absorbs the foreshortening between two views only while it is moderate.
A rig of three cameras in front of the person (the papers' triplet) is one group; a studio
of cameras all round is several groups, one per side. Each camera is the template of the
group of every camera whose optical axis is within ``max_angle_deg`` of its own; groups with
the same members are kept once, with the camera that is closest to all the others (the
smallest largest angle) as the template.

A group whose members all belong to a bigger group is dropped (its points are measured
there). Overlapping groups of a ring of cameras measure the sides between them twice; the
points are kept apart by group.

The default of 75° is a choice, not a derived bound: the papers' triplet converges within
30°, the Pose2Sim demo's neighbouring cameras at 49° and 67° and its other pairs at
101°–138°, where two views of one patch from either side of a limb do not exist.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_scalar
from .checks import check_cameras


@dataclass(frozen=True)
class ViewGroup:
    """Cameras measured and tracked together.

    Attributes
    ----------
    cameras : tuple of int
        Indices into the rig's cameras, ascending.
    template : int
        The template camera (an index into the rig, one of ``cameras``).
    """

    cameras: tuple
    template: int

    @property
    def template_position(self) -> int:
        """Index of the template within ``cameras``."""
        return self.cameras.index(self.template)


def axis_angles(cameras) -> np.ndarray:
    """``(K, K)`` angles between the cameras' optical axes, degrees."""
    cams = check_cameras(cameras, "cameras")
    z = np.stack([c.R[2] for c in cams])
    return np.degrees(np.arccos(np.clip(z @ z.T, -1.0, 1.0)))


def view_groups(cameras, *, max_angle_deg: float = 75.0) -> tuple:
    """The groups of cameras that see the same side (see the module docstring).

    Parameters
    ----------
    cameras : sequence of K Camera
    max_angle_deg : float
        Largest angle between a group's template axis and another member's, degrees.

    Returns
    -------
    tuple of ViewGroup
        Ordered by template; every group has at least two cameras.

    Raises
    ------
    ValueError
        No two cameras look within ``max_angle_deg`` of each other.
    """
    limit = as_scalar(max_angle_deg, "max_angle_deg", positive=True)
    angles = axis_angles(cameras)
    groups: dict[tuple, int] = {}
    for k in range(len(angles)):
        members = tuple(int(j) for j in np.flatnonzero(angles[k] <= limit))
        if len(members) >= 2 and members not in groups:
            sub = angles[np.ix_(members, members)]
            groups[members] = members[int(np.argmin(sub.max(axis=1)))]
    groups = {m: t for m, t in groups.items()
              if not any(set(m) < set(other) for other in groups)}
    if not groups:
        raise ValueError(f"cameras: no two cameras' optical axes are within {limit:g} degrees "
                         f"(smallest angle {np.min(angles + 1e9 * np.eye(len(angles))):.0f}); "
                         "no surface point can be matched between views")
    return tuple(sorted((ViewGroup(cameras=m, template=t) for m, t in groups.items()),
                        key=lambda g: g.template))
