"""3-D trajectories from tracked image points: positions, velocities, accelerations.

Positions come from forward intersection (:func:`~lsmta.triangulation.triangulate`) of
each frame's tracked image points; velocities and accelerations from finite differences at
the frame rate: central differences where both neighbouring frames are tracked, one-sided
at the ends of a track, NaN for a single-frame track (velocity) or where the frame or one
of its neighbours is missing (acceleration, ``(x[t+1] - 2 x[t] + x[t-1]) fps^2``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_scalar
from ..triangulation import triangulate
from .points import Tracks


@dataclass(frozen=True)
class Trajectories:
    """N 3-D trajectories over T frames.

    Attributes
    ----------
    xyz : (T, N, 3) array
        Positions in mm; NaN where a point is not tracked.
    fps : float
        Frame rate in Hz.
    """

    xyz: np.ndarray
    fps: float

    def __post_init__(self):
        xyz = np.array(as_array(self.xyz, "xyz", shape=(None, None, 3), allow_nan=True))
        xyz.flags.writeable = False
        object.__setattr__(self, "xyz", xyz)
        object.__setattr__(self, "fps", as_scalar(self.fps, "fps", positive=True))

    @property
    def n_frames(self) -> int:
        return self.xyz.shape[0]

    def __len__(self) -> int:
        return self.xyz.shape[1]

    @property
    def present(self) -> np.ndarray:
        """``(T, N)`` bool: position known."""
        return np.isfinite(self.xyz).all(axis=2)

    @property
    def start(self) -> np.ndarray:
        """``(N,)`` first frame with a position (-1 for an empty trajectory)."""
        p = self.present
        return np.where(p.any(axis=0), p.argmax(axis=0), -1)

    @property
    def end(self) -> np.ndarray:
        """``(N,)`` last frame with a position (-1 for an empty trajectory)."""
        p = self.present
        return np.where(p.any(axis=0), self.n_frames - 1 - p[::-1].argmax(axis=0), -1)

    @property
    def length(self) -> np.ndarray:
        """``(N,)`` number of frames with a position."""
        return self.present.sum(axis=0)

    @property
    def velocity(self) -> np.ndarray:
        """``(T, N, 3)`` velocities in mm/s."""
        x = self.xyz
        prev = np.full_like(x, np.nan)
        nxt = np.full_like(x, np.nan)
        prev[1:] = x[:-1]
        nxt[:-1] = x[1:]
        central = (nxt - prev) * self.fps / 2
        fwd = (nxt - x) * self.fps
        bwd = (x - prev) * self.fps
        v = np.where(np.isfinite(central), central, np.where(np.isfinite(fwd), fwd, bwd))
        return np.where(np.isfinite(x), v, np.nan)

    @property
    def acceleration(self) -> np.ndarray:
        """``(T, N, 3)`` accelerations in mm/s²."""
        x = self.xyz
        a = np.full_like(x, np.nan)
        a[1:-1] = (x[2:] - 2 * x[1:-1] + x[:-2]) * self.fps ** 2
        return a

    @property
    def speed(self) -> np.ndarray:
        """``(T, N)`` speed in mm/s."""
        return np.linalg.norm(self.velocity, axis=2)

    @property
    def step_speed(self) -> np.ndarray:
        """``(T, N)`` speed over the step from the previous frame, ``|x[t] - x[t-1]| fps``,
        mm/s (NaN at a track's first frame): a jump shows at the frame it lands in."""
        s = np.full(self.xyz.shape[:2], np.nan)
        s[1:] = np.linalg.norm(self.xyz[1:] - self.xyz[:-1], axis=2) * self.fps
        return s

    def keep_frames(self, keep) -> Trajectories:
        """A copy with positions outside ``keep`` ``(T, N)`` set to NaN."""
        keep = np.asarray(keep, bool)
        if keep.shape != self.xyz.shape[:2]:
            raise ValueError(f"keep: expected shape {self.xyz.shape[:2]}, got {keep.shape}")
        return Trajectories(np.where(keep[..., None], self.xyz, np.nan), self.fps)


def trajectories_from_tracks(cameras, tracks: Tracks, fps: float, *,
                             min_angle_deg: float = 0.5) -> Trajectories:
    """Forward intersection of every frame's tracked points.

    Parameters
    ----------
    cameras : sequence of K Camera
        The calibrated cameras, in the order of the tracks' cameras.
    tracks : Tracks
        With ``K >= 2`` cameras.
    fps : float
        Frame rate in Hz (> 0).

    Returns
    -------
    Trajectories
        A frame whose point does not intersect (too few rays, too small an angle) is NaN.
    """
    fps = as_scalar(fps, "fps", positive=True)
    if not isinstance(tracks, Tracks):
        raise TypeError(f"tracks: expected lsmta.tracking.Tracks, got {type(tracks).__name__}")
    cameras = list(cameras)
    T, K, N, _ = tracks.xy.shape
    if len(cameras) != K or K < 2:
        raise ValueError(f"cameras: expected {K} cameras (one per tracked sequence, at least 2), "
                         f"got {len(cameras)}")
    xyz = np.full((T, N, 3), np.nan)
    for t in range(T):
        alive = np.isfinite(tracks.xy[t]).all(axis=(0, 2))
        if alive.any():
            res = triangulate(cameras, tracks.xy[t][:, alive], min_angle_deg=min_angle_deg)
            xyz[t, alive] = res.points
    return Trajectories(xyz, fps)
