"""Arrays kept between the notebooks of one ``lsmta reproduce`` run.

Two notebooks of the compendium compute some of the same deterministic results from the
same inputs (notebooks 17 and 21 find the same tie-point features in the same frames of
the Pose2Sim demo). :func:`cached_arrays` keeps such a result in the run's cache folder,
``<kind>/<key>.npz``, and a later notebook of the same run reads it instead of computing it
again. The key must hash everything the result depends on (the inputs' bytes, the
settings, the library versions, the code that computes it); the caller builds it (see
:func:`content_key`). Only under ``lsmta reproduce``, which sets ``LSMTA_BUILD_CACHE`` to a
folder of its own run and removes it when the run ends: anywhere else every result is
computed. A file that cannot be read or written is computed again.
"""

from __future__ import annotations

import hashlib
import os
import re
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

CACHE_ENV = "LSMTA_BUILD_CACHE"


def cache_folder(kind: str) -> Path | None:
    """The folder of the kept arrays of one kind in this run.

    Parameters
    ----------
    kind : str
        A name (letters, digits, ``_``), e.g. ``"tie_features"``.

    Returns
    -------
    Path or None
        ``<run cache>/<kind>``; None when not run by ``lsmta reproduce`` (``LSMTA_BUILD_CACHE``
        unset).
    """
    if not isinstance(kind, str) or not kind.isidentifier():
        raise ValueError(f"kind: expected a name (letters, digits, _), got {kind!r}")
    env = os.environ.get(CACHE_ENV)
    return Path(env).resolve() / kind if env else None


def content_key(*parts) -> str:
    """A key for :func:`cached_arrays`.

    Parameters
    ----------
    *parts
        Arrays (hashed by dtype, shape and bytes) or plain values (strings, numbers, tuples
        of them; hashed by ``repr``).

    Returns
    -------
    str
        The SHA-256 hex digest (64 characters).
    """
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            h.update(f"array {part.dtype.str} {part.shape}".encode())
            h.update(np.ascontiguousarray(part).tobytes())
        else:
            h.update(f"value {part!r}".encode())
        h.update(b"\x00")
    return h.hexdigest()


def cached_arrays(kind: str, key: str, compute: Callable[[], dict[str, np.ndarray]]
                  ) -> dict[str, np.ndarray]:
    """``compute()``, or what an earlier call of this run stored under ``kind`` and ``key``.

    Parameters
    ----------
    kind : str
        As in :func:`cache_folder`.
    key : str
        A digest from :func:`content_key` of everything the result depends on.
    compute : callable
        Returns a dict of NumPy arrays (no object arrays).

    Returns
    -------
    dict of str to ndarray
        The arrays, bit for bit as ``compute()`` gave them.
    """
    folder = cache_folder(kind)
    if folder is None:
        return compute()
    if not isinstance(key, str) or not re.fullmatch(r"[0-9a-f]{64}", key):
        raise ValueError(f"key: expected a SHA-256 hex digest (content_key), got {key!r:.70}")
    path = folder / f"{key}.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                return {name: z[name] for name in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            pass                                   # unreadable: computed again
    out = compute()
    if not all(isinstance(v, np.ndarray) and v.dtype != object for v in out.values()):
        raise TypeError(f"compute: expected a dict of numeric arrays, got {sorted(out)}")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f"{key}.{os.getpid()}.tmp.npz"  # written whole, then moved into place
        np.savez(tmp, **out)
        os.replace(tmp, path)
    except OSError:
        pass                                       # not kept: the next call computes it
    return out
