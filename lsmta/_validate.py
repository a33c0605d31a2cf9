"""Argument checks shared by the public functions.

Every check names the argument and says what was expected. The helpers return new
float64 arrays (or the caller's array untouched when no conversion was needed), and
nothing here writes into what the caller passed.
"""

from __future__ import annotations

import math
import numbers

import numpy as np


def as_array(value, name: str, *, shape: tuple | None = None, finite: bool = True,
             allow_nan: bool = False) -> np.ndarray:
    """Return ``value`` as a float64 array after checking its shape and values.

    Parameters
    ----------
    value : array_like
        What the caller passed.
    name : str
        Argument name used in error messages.
    shape : tuple, optional
        Required shape; ``None`` entries match any length, e.g. ``(None, 3)``.
    finite : bool
        Reject infinities and NaN.
    allow_nan : bool
        With ``finite``, still accept NaN (for "missing" entries) but not infinities.
    """
    arr = np.asarray(value)
    if arr.dtype != np.float64:      # (the checks below pass a float64 array: skipped)
        if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number)
                                       or arr.dtype == bool):
            raise TypeError(f"{name}: expected a real numeric array, got dtype {arr.dtype}")
        if np.iscomplexobj(arr):
            raise TypeError(f"{name}: expected real numbers, got complex dtype {arr.dtype}")
        arr = arr.astype(np.float64, copy=False)
    if shape is not None and (
        arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape))
    ):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape)
        want += ",)" if len(shape) == 1 else ")"
        raise ValueError(f"{name}: expected an array of shape {want}, got shape {arr.shape}")
    if finite and not np.isfinite(arr).all():
        bad = ~np.isfinite(arr)
        if allow_nan:
            bad &= ~np.isnan(arr)
        if bad.any():
            what = "infinite values" if allow_nan else "non-finite values (NaN or inf)"
            raise ValueError(f"{name}: contains {what}; expected finite numbers")
    return arr


def as_points(value, name: str, dim: int = 3, *, allow_nan: bool = False) -> np.ndarray:
    """An ``(N, dim)`` float64 array of finite coordinates."""
    return as_array(value, name, shape=(None, dim), allow_nan=allow_nan)


def as_point_pairs(first, second, first_name: str, second_name: str):
    """Two ``(N, 2)`` float64 arrays of finite image points with the same N."""
    a = as_array(first, first_name, shape=(None, 2))
    b = as_array(second, second_name, shape=(None, 2))
    if len(a) != len(b):
        raise ValueError(f"{second_name}: expected {len(a)} points like {first_name}, "
                         f"got {len(b)}")
    return a, b


def as_vector(value, name: str, n: int) -> np.ndarray:
    """A finite float64 vector of length ``n``."""
    return as_array(value, name, shape=(n,))


_PLAIN_FLOATS = (float, np.float64)


def as_scalar(value, name: str, *, positive: bool = False, nonnegative: bool = False) -> float:
    """A finite Python float, optionally > 0 or >= 0."""
    if type(value) in _PLAIN_FLOATS and math.isfinite(value):    # the common case, quickly
        x = float(value)
    else:
        x = float(as_array(value, name, shape=()))
    if positive and not x > 0:
        raise ValueError(f"{name}: expected a positive number, got {x}")
    if nonnegative and not x >= 0:
        raise ValueError(f"{name}: expected a number >= 0, got {x}")
    return x


def as_int(value, name: str, *, minimum: int | None = 1, odd: bool = False,
           allow_none: bool = False, unit: str = "") -> int | None:
    """A Python int from an integral number (``bool`` refused), optionally ``>= minimum``
    (default 1: a positive integer) and odd; ``None`` passes through when ``allow_none``.

    The error names the argument, what was expected and what came, e.g.
    ``"step: expected an integer >= 1 (pixels), got 0.5"``.
    """
    if value is None and allow_none:
        return None
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if ok:
        try:
            ok = bool(np.isfinite(value)) and int(value) == value
        except (TypeError, ValueError, OverflowError):
            ok = False
    if ok and minimum is not None:
        ok = int(value) >= minimum
    if ok and odd:
        ok = int(value) % 2 == 1
    if not ok:
        what = "an odd integer" if odd else "an integer"
        if minimum is not None:
            what += f" >= {minimum}"
        if allow_none:
            what = f"None or {what}"
        if unit:
            what += f" ({unit})"
        raise ValueError(f"{name}: expected {what}, got {value!r}")
    return int(value)


_I3 = np.eye(3)


def _det3(R) -> float:
    """The determinant of a 3x3 array (its rows' triple product)."""
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def as_rotation(value, name: str) -> np.ndarray:
    """A proper 3x3 rotation matrix (orthonormal, determinant +1, to 1e-6)."""
    R = as_array(value, name, shape=(3, 3))
    # np.allclose(R @ R.T, I, atol=1e-6) (its rtol 1e-5 included) and det(R) >= 0, quicker
    if not (np.abs(R @ R.T - _I3) <= 1e-6 + 1e-5 * _I3).all() or _det3(R) < 0:
        raise ValueError(f"{name}: expected a proper rotation (R @ R.T == I, det(R) == +1)")
    return R


def as_rng(rng, name: str = "rng") -> np.random.Generator:
    """A :class:`numpy.random.Generator` from ``rng``: a Generator (returned as it is), an
    integer seed, or None (a fresh, unseeded generator)."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None:
        return np.random.default_rng()
    if isinstance(rng, int | np.integer) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise TypeError(
        f"{name}: expected a numpy.random.Generator, an integer seed or None, "
        f"got {type(rng).__name__}"
    )


def check_patch(patch, name: str = "patch") -> int:
    """An odd patch size >= 5 (pixels), as a Python int."""
    if isinstance(patch, bool) or int(patch) != patch or patch < 5 or patch % 2 == 0:
        raise ValueError(f"{name}: expected an odd integer >= 5 (pixels), got {patch}")
    return int(patch)


def freeze(obj, names) -> None:
    """Store read-only copies of the named array fields of a frozen dataclass (call it
    from ``__post_init__``); the caller's arrays are not touched."""
    for key in names:
        a = np.array(getattr(obj, key))
        a.flags.writeable = False
        object.__setattr__(obj, key, a)


def pack_windows(sizes, *, width: int = 2048):
    """Places ``(n, 2)`` (x, y of the top-left pixel) of rectangles ``sizes (n, 2)``
    (width, height, px) packed row by row into a mosaic ``width`` wide (wider if one
    rectangle is), and the mosaic's ``(width, height)``: small windows of many images
    processed as one image (one spline, one batched call) instead of one call each."""
    sizes = np.asarray(sizes, dtype=int).reshape(-1, 2)
    width = max(int(width), int(sizes[:, 0].max(initial=1)))
    places, x, y, row = [], 0, 0, 0
    for w, h in sizes:
        if x + w > width:
            x, y, row = 0, y + row, 0
        places.append((x, y))
        x, row = x + int(w), max(row, int(h))
    return np.array(places, dtype=int).reshape(-1, 2), (width, y + row)
