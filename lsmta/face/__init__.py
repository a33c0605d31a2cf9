"""Facial markers: occluded markers filled from a model of faces (Davis 2002, thesis
section 5.4), the peer from biomechanics, and a face model chosen by cross-validation.

* :mod:`lsmta.face.basis`: the thesis's basis-face model (``fill_missing``, extreme-face and
  PCA bases), rigid alignment of a sequence, the Fig. 64 accuracy measure;
* :mod:`lsmta.face.peer`: PCA gap filling from marker intercorrelations (Federolf 2013;
  Gløersen & Federolf 2016, with their distance weighting);
* :mod:`lsmta.face.model`: :func:`learn` -> :class:`FaceModel`, whose method and size are
  chosen by cross-validation over blocks of time of the training sequence
  (:func:`choose_face_model` -> :class:`FaceChoice`): plain PCA unless a learnt model is
  clearly better.

Conventions: sequences are ``(T, M, 3)`` arrays in millimetres with NaN for a missing
marker (a marker is missing when any of its coordinates is NaN).
"""

from .basis import (
                    FaceBasis,
                    FaceFit,
                    align_sequence,
                    distance_deviation,
                    extreme_basis,
                    fill_missing,
                    min_observed_markers,
                    pca_basis,
)
from .model import (
    FaceChoice,
    FaceModel,
    FaceParams,
    build_face_model,
    choose_face_model,
    learn,
)
from .peer import GapFill, pca_gap_fill

__all__ = [
    "FaceBasis", "FaceChoice", "FaceFit", "FaceModel", "FaceParams", "GapFill", "align_sequence",
    "build_face_model", "choose_face_model", "distance_deviation", "extreme_basis",
    "fill_missing", "learn", "min_observed_markers", "pca_basis", "pca_gap_fill",
]
