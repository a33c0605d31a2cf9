"""Arrays kept between the notebooks of one ``lsmta reproduce`` build.

Two notebooks of the compendium compute some of the same deterministic results from the
same inputs (notebooks 17 and 21 find the same tie-point features in the same frames of
the Pose2Sim demo). :func:`cached_arrays` keeps such a result under the build folder, in
``cache/<kind>/<key>.npz``, and the next notebook reads it instead of computing it again.
The key must hash everything the result depends on (the inputs' bytes, the settings, the
library versions); the caller builds it (see :func:`content_key`). Only under ``lsmta
reproduce`` (which sets ``LSMTA_BUILD_DIR`` and empties ``cache/`` when it starts, so a
run never reads an earlier run's arrays): anywhere else every result is computed.
A file that cannot be read is computed again and written anew.
"""

from __future__ import annotations

import hashlib
import os
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .report import BUILD_ENV


def cache_folder(kind: str) -> Path | None:
    """``cache/<kind>`` under the build folder of ``lsmta reproduce``; None when not run by
    it (``LSMTA_BUILD_DIR`` unset)."""
    if not isinstance(kind, str) or not kind.isidentifier():
        raise ValueError(f"kind: expected a name (letters, digits, _), got {kind!r}")
    env = os.environ.get(BUILD_ENV)
    return Path(env).resolve() / "cache" / kind if env else None


def content_key(*parts) -> str:
    """A hex digest of ``parts``: arrays by their dtype, shape and bytes, anything else by
    its ``repr`` (use plain values: strings, numbers, tuples of them)."""
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
    """``compute()`` (a dict of arrays), or the same dict stored by an earlier call with this
    ``kind`` and ``key`` in this build (see the module docstring)."""
    folder = cache_folder(kind)
    if folder is None:
        return compute()
    if not isinstance(key, str) or not key.isalnum():
        raise ValueError(f"key: expected a hex digest (content_key), got {key!r:.60}")
    path = folder / f"{key}.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                return {name: z[name] for name in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):
            pass                                   # unreadable: computed and written again
    out = compute()
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f"{key}.{os.getpid()}.tmp.npz"  # written whole, then moved into place
    np.savez(tmp, **out)
    os.replace(tmp, path)
    return out
