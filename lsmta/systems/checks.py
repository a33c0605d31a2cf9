"""Argument checks of the systems: cameras, multi-camera videos, pan-tilt heads as devices."""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..pantilt import PanTiltCamera


def check_cameras(cameras, name: str) -> list:
    """A list of K >= 2 :class:`~lsmta.camera.Camera`."""
    try:
        cams = list(cameras)
    except TypeError:
        raise TypeError(f"{name}: expected a sequence of lsmta.camera.Camera, got "
                        f"{type(cameras).__name__}") from None
    if len(cams) < 2 or not all(isinstance(c, Camera) for c in cams):
        raise TypeError(f"{name}: expected a sequence of at least 2 lsmta.camera.Camera, got "
                        f"{[type(c).__name__ for c in cams]}")
    return cams


def check_videos(videos, name: str, cameras, *, min_frames: int = 2) -> np.ndarray:
    """K synchronised grey videos as one ``(K, T, H, W)`` array (the caller's array itself
    when it already is one), each camera's frames of that camera's image size.

    Raises
    ------
    TypeError
        Not grey values (integer or floating point).
    ValueError
        A wrong shape, a camera count or image size that does not match ``cameras``, fewer
        than ``min_frames`` frames, or non-finite values.
    """
    K = len(cameras)
    try:
        v = np.asarray(videos)
    except ValueError:
        raise ValueError(f"{name}: expected K videos of equal length and image size") from None
    if v.dtype == object:
        raise ValueError(f"{name}: expected K videos of equal length and image size")
    if not (np.issubdtype(v.dtype, np.integer) or np.issubdtype(v.dtype, np.floating)) \
            or v.dtype == bool:
        raise TypeError(f"{name}: expected grey values (uint8 or float), got dtype {v.dtype}")
    if v.ndim != 4:
        raise ValueError(f"{name}: expected an array of shape (K, T, H, W) (K cameras, T "
                         f"frames), got shape {v.shape}")
    if v.shape[0] != K:
        raise ValueError(f"{name}: expected {K} videos, one per camera, got {v.shape[0]}")
    if v.shape[1] < min_frames:
        raise ValueError(f"{name}: expected at least {min_frames} frames, got {v.shape[1]}")
    for k, cam in enumerate(cameras):
        if v.shape[2:] != (cam.height, cam.width):
            raise ValueError(f"{name}: camera {cam.name or k} is {cam.width} x {cam.height} px "
                             f"but its frames are {v.shape[3]} x {v.shape[2]}")
    if np.issubdtype(v.dtype, np.floating) and not np.isfinite(v).all():
        raise ValueError(f"{name}: contains non-finite values; expected grey levels")
    return v


def check_heads(heads, devices, identify) -> tuple:
    """Lists of K >= 2 calibrated :class:`~lsmta.pantilt.PanTiltCamera`, K devices (with
    ``command(t, setting)`` and ``grab(t)``) and K callables ``identify[k](t, setting)``
    (or None: identified automatically)."""
    heads, devices = list(heads), list(devices)
    identify = None if identify is None else list(identify)
    if len(heads) < 2 or not all(isinstance(h, PanTiltCamera) for h in heads):
        raise TypeError("heads: expected at least 2 calibrated lsmta.pantilt.PanTiltCamera")
    for name, v in (("devices", devices), ("identify", identify)):
        if v is not None and len(v) != len(heads):
            raise ValueError(f"{name}: expected one per head ({len(heads)}), got {len(v)}")
    for k, d in enumerate(devices):
        if not (callable(getattr(d, "command", None)) and callable(getattr(d, "grab", None))):
            raise TypeError(f"devices[{k}]: expected an object with command(t, setting) and "
                            "grab(t) -> (image, setting)")
    for k, f in enumerate(identify or ()):
        if not callable(f):
            raise TypeError(f"identify[{k}]: expected a callable (t, setting) -> (M, 2) px")
    return heads, devices, identify
