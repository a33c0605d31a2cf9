"""Results kept between the notebooks of one ``lsmta reproduce`` run.

Two notebooks of the compendium compute some of the same deterministic results from the
same inputs (notebooks 17 and 21 find the same tie-point features in the same frames of
the Pose2Sim demo, refine the same rig and capture the same markers). Two ways to keep one
in the run's cache folder, so that a later notebook of the same run reads it instead of
computing it again:

* :func:`cached_arrays` keeps a dict of arrays, ``<kind>/<key>.npz``; the caller builds the
  key, which must hash everything the result depends on (the inputs' bytes, the settings,
  the library versions, the code that computes it; see :func:`content_key`);
* :func:`cached_result` keeps a library call's whole result, ``<kind>/<key>.pkl``, under a
  key of its own: the call's arguments, the package's code, the library versions and the
  thread settings.

Only under ``lsmta reproduce``, which sets ``LSMTA_BUILD_CACHE`` to a folder of its own run
and removes it when the run ends: anywhere else every result is computed. A file that
cannot be read or written is computed again.
"""

from __future__ import annotations

import hashlib
import io
import os
import pickle
import re
import warnings
import zipfile
from collections.abc import Callable
from importlib import metadata
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


#: in a kind's folder: one line (key, process id) per result :func:`cached_result` read back
READS_FILE = "reads.txt"
#: distributions whose versions go into :func:`cached_result`'s key
KEY_VERSIONS = ("numpy", "scipy", "opencv-python-headless", "numba", "scikit-image")
#: environment variables that set thread counts (a threaded sum may round differently)
KEY_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


def _array(rebuild, args, state, writeable):
    a = rebuild(*args)
    a.__setstate__(state)
    if not writeable:
        a.flags.writeable = False
        return a
    return a if a.flags.owndata else a.copy(order="K")   # not the pickle's bytes


class _Pickler(pickle.Pickler):
    """Pickles arrays with their ``writeable`` flag (results hold read-only arrays)."""

    def reducer_override(self, obj):
        if type(obj) is np.ndarray:
            rebuild, args, state = obj.__reduce__()
            return _array, (rebuild, args, state, bool(obj.flags.writeable))
        return NotImplemented


class _KeyPickler(pickle.Pickler):
    """Pickles for a key: arrays as dtype, shape and bytes (whatever their strides or
    flags), no memo (an object shared twice is written twice, as its unpickled copy is)."""

    def reducer_override(self, obj):
        if type(obj) is np.ndarray:           # subclasses (masked arrays) by their own reduce
            return np.ndarray, (), (obj.dtype.descr, obj.shape,
                                    np.ascontiguousarray(obj).tobytes()
                                    if obj.dtype != object else obj.tolist())
        return NotImplemented


def _key_digest(obj) -> str:
    h = hashlib.sha256()

    class Sink:
        write = h.update

    pickler = _KeyPickler(Sink(), protocol=pickle.HIGHEST_PROTOCOL)
    pickler.fast = True                            # no memo
    pickler.dump(obj)
    return h.hexdigest()


def _dumps(obj) -> bytes:
    buf = io.BytesIO()
    _Pickler(buf, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    return buf.getvalue()


def package_digest() -> str:
    """SHA-256 of every ``.py`` file of the ``lsmta`` package (relative path and bytes)."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + b"\x00" + f.read_bytes() + b"\x00")
    return h.hexdigest()


def _threads() -> tuple:
    import numba  # deferred: only for a key under lsmta reproduce

    return (numba.get_num_threads(), tuple(os.environ.get(v) for v in KEY_ENV))


def cached_result(kind: str, compute: Callable, args: tuple, *, kwargs: dict | None = None):
    """``compute(*args, **kwargs)``, or what an earlier call of this run returned for the
    same arguments.

    Parameters
    ----------
    kind : str
        As in :func:`cache_folder`; one kind per function.
    compute : callable
        A deterministic library function: its result depends only on its arguments, the
        package's code (:func:`package_digest`), the versions of :data:`KEY_VERSIONS` and
        the thread settings (numba's thread count, :data:`KEY_ENV`), all in the key.
    args : tuple
        Its positional arguments.
    kwargs : dict, optional
        Its keyword arguments. The key hashes their pickle (arrays by dtype, shape and bytes; an
        object referred to twice hashed twice, so that a result read back from the cache,
        passed on, gives the same key as the computed one).

    Returns
    -------
    object
        The result; from the run's cache folder (``<kind>/<key>.pkl``, written by this
        run's own kernels) equal to the computed one field by field, arrays bit for bit and
        with their ``writeable`` flags, and a line added to :data:`READS_FILE` there; the
        warnings the computation gave are given again.
        Computed when not run by ``lsmta reproduce``, when
        the arguments do not pickle or when the file cannot be read or written.
    """
    args, kwargs = tuple(args), dict(kwargs or {})
    folder = cache_folder(kind)
    if folder is None:
        return compute(*args, **kwargs)
    try:
        versions = tuple(metadata.version(d) for d in KEY_VERSIONS)
        key = content_key(kind, getattr(compute, "__qualname__", repr(compute)), versions,
                          package_digest(), _threads(),
                          _key_digest((args, sorted(kwargs.items()))))
    except Exception:                              # not keyable (or no version): computed
        return compute(*args, **kwargs)
    path = folder / f"{key}.pkl"
    if path.is_file():
        try:
            with open(path, "rb") as fh:
                out, warned = pickle.load(fh)   # this run's own file (its private folder)
            with open(folder / READS_FILE, "a", encoding="utf-8") as fh:
                fh.write(f"{key} {os.getpid()}\n")   # a reader can say what was not computed
        except Exception:
            pass                                   # unreadable: computed again
        else:
            _warn_again(warned)
            return out
    caught = []
    try:
        with warnings.catch_warnings(record=True) as caught:   # the filters as they are
            out = compute(*args, **kwargs)
    finally:                                       # given again also when it raises
        warned = [(w.message, w.category, w.filename, w.lineno) for w in caught]
        _warn_again(warned)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f"{key}.{os.getpid()}.tmp"   # written whole, then moved into place
        tmp.write_bytes(_dumps((out, warned)))
        os.replace(tmp, path)
    except Exception:
        pass                                       # not kept: the next call computes it
    return out


def _warn_again(warned) -> None:
    """Issue the warnings a computation gave (kept with its result: a call that reads it
    warns as the computing one did)."""
    for message, category, filename, lineno in warned:
        warnings.warn_explicit(message, category, filename, lineno)
