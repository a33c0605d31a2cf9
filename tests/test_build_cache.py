"""Arrays kept between the notebooks of one ``lsmta reproduce`` run (lsmta.build_cache)."""

import numpy as np
import pytest

from lsmta.build_cache import CACHE_ENV, cache_folder, cached_arrays, content_key


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
