"""The project's bundled recordings (``data/``, each folder with its licence and source),
loaded into arrays and cameras.

* :func:`load_cones` — the Middlebury "Cones" pair with its disparity truth
  (``data/middlebury_cones``);
* :func:`load_demo` — the four views of Pose2Sim's demo with their Qualisys calibration
  (``data/pose2sim_demo``);
* :func:`load_recording` — a real marker recording (C3D) split for the SAPM protocol of
  :mod:`lsmta.real.marker_captures` (``data/kineticstoolkit``, ``data/clouthier2021``);
* :func:`load_animface` — the AnimFace facial captures (``data/animface``);
* :data:`CALISCOPE_DIR` — caliscope's four-camera board recording
  (read by :func:`lsmta.real.board.caliscope_comparison`).

Generic file readers (C3D, xypts, video) are in :mod:`lsmta.io`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .camera import scaled_camera
from .camera_files import read_qca
from .io import read_c3d, read_video

DATA_DIR = Path(__file__).resolve().parents[1] / "data"
ANIMFACE_DIR = DATA_DIR / "animface"
CALISCOPE_DIR = DATA_DIR / "caliscope_4cam"
CONES_DIR = DATA_DIR / "middlebury_cones"
POSE2SIM_DIR = DATA_DIR / "pose2sim_demo"
POSE2SIM_VIEWS = ("cam01", "cam02", "cam03", "cam04")
RECORDING_FILES = {
    "tennis": DATA_DIR / "kineticstoolkit" / "kinematics_tennis_serve.c3d",
    "two players": DATA_DIR / "kineticstoolkit" / "kinematics_tennis_serve_2players.c3d",
    "racing": DATA_DIR / "kineticstoolkit" / "kinematics_racing_propulsion.c3d",
    "racing static": DATA_DIR / "kineticstoolkit" / "kinematics_racing_static.c3d",
    "clouthier": DATA_DIR / "clouthier2021" / "KneeltoProne01.c3d",
}


# ---------------------------------------------------------------------- Middlebury Cones
@dataclass(frozen=True)
class StereoPair:
    """A rectified pair with ground truth for the left image.

    ``left``, ``right`` (H, W) uint8; ``disparity`` (H, W) float, NaN where unknown;
    ``nonoccluded`` (H, W) bool.
    """

    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    nonoccluded: np.ndarray

    def grid(self, step: int):
        """Truth on the grid of spacing ``step``: ``(disparity, scored)``, both
        ``(rows, cols)``; ``scored`` marks the non-occluded nodes with known disparity."""
        d = self.disparity[::step, ::step]
        return d, self.nonoccluded[::step, ::step] & np.isfinite(d)


def load_cones(*, path=None) -> StereoPair:
    """The Middlebury "Cones" pair from ``data/middlebury_cones/cones.npz`` (see its README)."""
    d = np.load(Path(path) if path is not None else CONES_DIR / "cones.npz")
    disparity = d["disparity4"].astype(float) / 4.0
    disparity[d["disparity4"] == 0] = np.nan
    return StereoPair(left=d["left"], right=d["right"], disparity=disparity,
                      nonoccluded=d["nonoccluded"])


# ---------------------------------------------------------------------- Pose2Sim demo
@dataclass(frozen=True)
class RealVideo:
    """The demo's four views, grey and scaled.

    Attributes
    ----------
    grey : list of K (T, H_k, W_k) uint8 arrays
        Every frame, grey, scaled by ``scale`` (the views' widths differ by a few px).
    first : list of K (H, W, 3) uint8 arrays
        Frame 0 in colour (BGR), full size: for finding markers.
    cameras : list of K Camera
        The Qualisys calibration scaled by ``scale``.
    scale : float
    fps : float
    """

    grey: list
    first: list
    cameras: list
    scale: float
    fps: float


def load_demo(*, scale: float = 0.5, frames: int | None = None,
              folder: Path | None = None) -> RealVideo:
    """The four views of the demo (``folder`` defaults to the project's copy)."""
    folder = Path(folder) if folder is not None else POSE2SIM_DIR
    cams = read_qca(folder / "Calib.qca.txt")
    grey, first, fps = zip(*(read_video(folder / f"{v}.mp4", scale=scale, frames=frames)
                             for v in POSE2SIM_VIEWS))
    if len(set(fps)) != 1:
        raise ValueError(f"folder: the views' frame rates differ: {fps}")
    return RealVideo(grey=list(grey), first=list(first),
                     cameras=[scaled_camera(c, scale) for c in cams], scale=float(scale),
                     fps=fps[0])


# ---------------------------------------------------------------------- marker recordings
@dataclass(frozen=True)
class Recording:
    """One recording split for the protocol of :mod:`lsmta.real.marker_captures`.

    Attributes
    ----------
    name : str
    labels : tuple of str
        Marker labels (a two-player file's ``Name:`` prefix removed for the player's own).
    points : (T, L, 3) array
        Every frame, mm, NaN for gaps (markers absent from every frame removed).
    rate : float
        Frames per second.
    n_train : int
        Frames of the training clip (the first ``train_share``).
    frames : (F,) int array
        Test frames: every ``step``-th frame after the training clip.
    """

    name: str
    labels: tuple
    points: np.ndarray
    rate: float
    n_train: int
    frames: np.ndarray

    @property
    def training(self) -> np.ndarray:
        return self.points[: self.n_train]


def load_recording(name: str, *, train_share: float = 0.1, step: int = 10) -> Recording:
    """A recording of :data:`RECORDING_FILES` ("tennis", "two players", "racing",
    "clouthier"), split for the protocol. The two-player file keeps its 78 labels
    (``Derrick:C7``, ...)."""
    if name not in RECORDING_FILES:
        raise ValueError(f"name: expected one of {sorted(RECORDING_FILES)}, got {name!r}")
    labels, points, rate = read_c3d(RECORDING_FILES[name])
    if name == "tennis":
        labels = tuple(k.split(":")[-1] for k in labels)
    seen = np.isfinite(points).all(axis=2).any(axis=0)
    labels = tuple(k for k, s in zip(labels, seen) if s)
    points = points[:, seen]
    n_train = int(round(train_share * len(points)))
    return Recording(name=name, labels=labels, points=points, rate=rate, n_train=n_train,
                     frames=np.arange(n_train, len(points), step))


# ---------------------------------------------------------------------- AnimFace
def load_animface(name: str, *, step: int = 1):
    """``labels``, ``points`` (T, 41, 3) float64 mm of the project's AnimFace copy
    (``"JawMoCap"`` or ``"CheeksMoCap"``), every ``step``-th frame."""
    d = np.load(ANIMFACE_DIR / f"{name}.npz")
    return tuple(str(s) for s in d["labels"]), d["points"][::step].astype(float)
