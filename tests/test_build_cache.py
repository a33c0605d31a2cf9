"""Arrays kept between the notebooks of one ``lsmta reproduce`` run (lsmta.build_cache)."""

import numpy as np
import pytest

from lsmta import build_cache
from lsmta.build_cache import (
    CACHE_ENV,
    READS_FILE,
    cache_folder,
    cached_arrays,
    cached_result,
    content_key,
    package_digest,
)


def _counting():
    calls = []

    def compute():
        calls.append(1)
        return {"xy": np.arange(6.0).reshape(3, 2) / 7, "des": np.arange(4, dtype=np.uint8)}
    return compute, calls


def test_computed_every_time_outside_a_build(monkeypatch):
    monkeypatch.delenv(CACHE_ENV, raising=False)
    compute, calls = _counting()
    assert cache_folder("tie_features") is None
    for _ in range(2):
        cached_arrays("tie_features", content_key("a"), compute)
    assert len(calls) == 2


def test_kept_in_the_build_folder_bit_for_bit(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    compute, calls = _counting()
    key = content_key("tie features", np.zeros((2, 3), np.uint8), ("sift", 1, 0.04))
    first = cached_arrays("tie_features", key, compute)
    again = cached_arrays("tie_features", key, compute)
    assert len(calls) == 1
    assert (tmp_path / "tie_features" / f"{key}.npz").is_file()
    for name, value in first.items():
        assert again[name].dtype == value.dtype and np.array_equal(again[name], value)
    # another key: computed; an unreadable file: computed and written again
    cached_arrays("tie_features", content_key("other"), compute)
    assert len(calls) == 2
    (tmp_path / "tie_features" / f"{key}.npz").write_bytes(b"not a zip")
    cached_arrays("tie_features", key, compute)
    assert len(calls) == 3
    assert len(cached_arrays("tie_features", key, compute)) == 2 and len(calls) == 3


def test_key_tells_arrays_apart():
    a = np.zeros((2, 3), np.uint8)
    assert content_key(a) == content_key(a.copy())
    assert content_key(a) != content_key(a.reshape(3, 2))
    assert content_key(a) != content_key(a.astype(np.int8))
    b = a.copy()
    b[1, 2] = 1
    assert content_key(a) != content_key(b)
    assert content_key("x", 1) != content_key("x", 2)


def test_bad_kind_or_key(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    with pytest.raises(ValueError, match="kind"):
        cached_arrays("../up", content_key("a"), dict)
    with pytest.raises(ValueError, match="key"):
        cached_arrays("tie_features", "../x", dict)


def test_not_arrays_refused_and_unwritable_folder_computes(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    with pytest.raises(TypeError, match="compute"):
        cached_arrays("tie_features", content_key("a"), lambda: {"x": [1, 2]})
    (tmp_path / "tie_features").write_text("a file where the folder would be")
    compute, calls = _counting()
    for _ in range(2):
        cached_arrays("tie_features", content_key("b"), compute)
    assert len(calls) == 2


def _result_counting():
    calls = []

    def compute(a, *, scale=1.0):
        calls.append(1)
        frozen = np.asarray(a, float) * scale
        frozen.flags.writeable = False
        return {"frozen": frozen, "free": np.arange(100_000), "note": f"scale {scale}"}
    return compute, calls


def test_result_kept_for_the_same_arguments_only(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    compute, calls = _result_counting()
    first = cached_result("some_call", compute, (np.arange(4.0),), kwargs={"scale": 2.0})
    again = cached_result("some_call", compute, (np.arange(4.0),), kwargs={"scale": 2.0})
    assert len(calls) == 1 and len(list((tmp_path / "some_call").glob("*.pkl"))) == 1
    assert len((tmp_path / "some_call" / READS_FILE).read_text().splitlines()) == 1  # one read
    assert again["note"] == first["note"] and np.array_equal(again["frozen"], first["frozen"])
    # read-only arrays stay read-only, the others writeable
    assert not again["frozen"].flags.writeable and again["free"].flags.writeable
    again["free"][0] = 7                       # writeable arrays can be written
    cached_result("some_call", compute, (np.arange(4.0),), kwargs={"scale": 3.0})  # another
    cached_result("some_call", compute, (np.arange(4.0) + 1e-12,), kwargs={"scale": 2.0})
    assert len(calls) == 3


def test_result_key_changes_with_the_code_and_threads(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    compute, calls = _result_counting()
    assert len(package_digest()) == 64 and package_digest() == package_digest()
    cached_result("some_call", compute, ([1.0],))
    monkeypatch.setattr(build_cache, "package_digest", lambda: "0" * 64)   # the code changed
    cached_result("some_call", compute, ([1.0],))
    assert len(calls) == 2
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "7")
    cached_result("some_call", compute, ([1.0],))
    assert len(calls) == 3


def test_result_computed_outside_a_build_or_when_not_pickled(monkeypatch, tmp_path):
    monkeypatch.delenv(CACHE_ENV, raising=False)
    compute, calls = _result_counting()
    for _ in range(2):
        cached_result("some_call", compute, ([1.0],))
    assert len(calls) == 2
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    for _ in range(2):                         # an argument that does not pickle: computed
        assert cached_result("some_call", lambda f: f(), (lambda: 5,)) == 5
    (tmp_path / "some_call").mkdir(exist_ok=True)
    cached_result("some_call", compute, ([2.0],))
    for f in (tmp_path / "some_call").glob("*.pkl"):
        f.write_bytes(b"not a pickle")         # unreadable: computed again
    cached_result("some_call", compute, ([2.0],))
    assert len(calls) == 4


def test_a_result_read_back_and_passed_on_gives_the_same_key(monkeypatch, tmp_path):
    """A kept result handed to another call (``like=``) keys as the computed one did,
    though its arrays are no longer shared or views."""
    import pickle
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    compute, calls = _result_counting()
    shared = np.arange(1000.0)
    computed = {"a": shared, "b": shared, "every_third": shared[::3]}
    back = pickle.loads(build_cache._dumps(computed))
    assert back["a"] is not back["every_third"].base
    for arg in (computed, back):
        cached_result("some_call", compute, ([1.0],), kwargs={"scale": arg["every_third"][1]})
        cached_result("other_call", lambda like: compute(like["a"]), (arg,))
    assert len(calls) == 2


def test_a_result_read_back_warns_as_the_computed_one(monkeypatch, tmp_path):
    import warnings
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))

    def compute(x):
        warnings.warn(f"few places: {x}", UserWarning, stacklevel=2)
        return np.array([x])
    for _ in range(2):
        with pytest.warns(UserWarning, match="few places: 3"):
            assert cached_result("warning_call", compute, (3,))[0] == 3
    assert len((tmp_path / "warning_call" / READS_FILE).read_text().splitlines()) == 1


def test_warnings_before_an_error_are_given(monkeypatch, tmp_path):
    import warnings
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))

    def compute(x):
        warnings.warn(f"about to fail: {x}", UserWarning, stacklevel=2)
        raise ValueError("x: bad")
    with pytest.warns(UserWarning, match="about to fail: 4"), pytest.raises(ValueError):
        cached_result("failing_call", compute, (4,))


def test_key_tells_masks_and_record_fields_apart(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    calls = []

    def compute(a):
        calls.append(1)
        return a.copy()
    data = np.arange(4.0)
    for mask in ([0, 0, 0, 0], [0, 1, 0, 0]):
        cached_result("some_call", compute, (np.ma.array(data, mask=mask),))
    for names in (("a", "b"), ("c", "d")):
        cached_result("some_call", compute, (np.zeros(2, dtype=[(n, "f8") for n in names]),))
    assert len(calls) == 4
