"""The project's bundled recordings (``data/``, each folder with its licence and source),
loaded into arrays and cameras.

* :func:`load_stereo_pair` — a Middlebury pair with its disparity truth, one of
  :data:`STEREO_PAIRS` (``data/middlebury_*``); :func:`load_cones` the "Cones" pair;
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
#: the real rectified pairs with truth: name -> (folder, ``truth_step`` px). Cones' truth
#: is quantised to 1/4 px, Teddy's to 1/4, Art's to 1/3; Tsukuba's is stored in 1/16 px but
#: hand-labelled in whole pixels.
STEREO_PAIRS = {
    "cones": ("middlebury_cones", 0.25),
    "teddy": ("middlebury_teddy", 0.25),
    "art": ("middlebury_art", 1.0 / 3.0),
    "tsukuba": ("middlebury_tsukuba", 1.0),
}
POSE2SIM_DIR = DATA_DIR / "pose2sim_demo"
POSE2SIM_VIEWS = ("cam01", "cam02", "cam03", "cam04")
#: the demo's videos, in the views' order, and its camera file
POSE2SIM_VIDEOS = tuple(POSE2SIM_DIR / f"{v}.mp4" for v in POSE2SIM_VIEWS)
POSE2SIM_CAMERAS = POSE2SIM_DIR / "Calib.qca.txt"
RECORDING_FILES = {
    "tennis": DATA_DIR / "kineticstoolkit" / "kinematics_tennis_serve.c3d",
    "two players": DATA_DIR / "kineticstoolkit" / "kinematics_tennis_serve_2players.c3d",
    "racing": DATA_DIR / "kineticstoolkit" / "kinematics_racing_propulsion.c3d",
    "racing static": DATA_DIR / "kineticstoolkit" / "kinematics_racing_static.c3d",
    "clouthier": DATA_DIR / "clouthier2021" / "KneeltoProne01.c3d",
}


# ---------------------------------------------------------------------- Middlebury pairs
@dataclass(frozen=True)
class StereoPair:
    """A rectified pair with ground truth for the left image.

    ``left``, ``right`` (H, W) uint8 grey; a left pixel ``(x, y)`` appears at ``(x - d, y)``
    in the right image. ``disparity`` (H, W) float, px, NaN where unknown; ``nonoccluded``
    (H, W) bool. ``name``; ``truth_step`` (px) the truth's quantisation step;
    ``disparity_range`` ``(0, largest)`` px: the largest disparity the truth file can encode
    (255 / its scale), rounded up to a multiple of 16 (OpenCV's matchers need one) — a
    search range from the file's format, not from the truth's values.
    """

    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    nonoccluded: np.ndarray
    name: str = "cones"
    truth_step: float = 0.25
    disparity_range: tuple = (0, 64)

    def grid(self, step: int):
        """Truth on the grid of spacing ``step``: ``(disparity, scored)``, both
        ``(rows, cols)``; ``scored`` marks the non-occluded nodes with known disparity."""
        d = self.disparity[::step, ::step]
        return d, self.nonoccluded[::step, ::step] & np.isfinite(d)


def load_stereo_pair(name: str, *, path=None) -> StereoPair:
    """A Middlebury pair of :data:`STEREO_PAIRS` (``"cones"``, ``"teddy"``, ``"art"``,
    ``"tsukuba"``) from ``data/middlebury_<name>/<name>.npz`` (see each folder's README for
    the source, licence and how the occlusion mask was made); ``path`` another copy."""
    if name not in STEREO_PAIRS:
        raise ValueError(f"name: expected one of {sorted(STEREO_PAIRS)}, got {name!r}")
    folder, truth_step = STEREO_PAIRS[name]
    d = np.load(Path(path) if path is not None else DATA_DIR / folder / f"{name}.npz")
    if "disparity4" in d:                                 # the Cones file (convert_cones.py)
        raw, scale = d["disparity4"], 4
    else:
        raw, scale = d["disparity_raw"], int(d["disparity_scale"])
    disparity = raw.astype(float) / scale
    disparity[raw == 0] = np.nan
    largest = int(np.ceil(255.0 / scale / 16.0)) * 16
    return StereoPair(left=d["left"], right=d["right"], disparity=disparity,
                      nonoccluded=d["nonoccluded"].astype(bool), name=name,
                      truth_step=truth_step, disparity_range=(0, largest))


def load_cones(*, path=None) -> StereoPair:
    """The Middlebury "Cones" pair from ``data/middlebury_cones/cones.npz`` (see its README)."""
    return load_stereo_pair("cones", path=path)


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
    cams = read_qca(folder / POSE2SIM_CAMERAS.name)
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
