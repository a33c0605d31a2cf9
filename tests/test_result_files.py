"""Results out (C3D, TRC, PLY), read back with the libraries users would use."""

import ezc3d
import numpy as np
import pytest
from plyfile import PlyData

from lsmta.io import read_c3d
from lsmta.result_files import read_trc, write_c3d, write_ply, write_trc


def _trajectories(rng, T=7, N=4):
    X = rng.normal(0, 500, (T, N, 3))
    X[2, 1] = np.nan          # a gap
    X[5:, 3] = np.nan         # a point that ends
    return X


def test_c3d_round_trip_through_ezc3d(tmp_path, rng):
    X = _trajectories(rng)
    keep = X.copy()
    path = write_c3d(tmp_path / "out" / "trajectories.c3d", X, rate=60.0,
                     labels=["C7", "RASI", "LASI", "RKNE"])
    assert np.array_equal(X, keep, equal_nan=True)           # the input is untouched
    back = read_c3d(path)
    assert back.labels == ("C7", "RASI", "LASI", "RKNE")
    assert back.rate == 60.0
    assert np.array_equal(np.isnan(back.points), np.isnan(X))
    np.testing.assert_allclose(back.points, X, rtol=1e-6, atol=1e-3)   # C3D holds float32
    # a missing sample is an invalid point (residual < 0), as tools that go by it expect
    residuals = ezc3d.c3d(str(path))["data"]["meta_points"]["residuals"][0].T   # (T, N)
    assert np.array_equal(residuals < 0, np.isnan(X).any(axis=2))


def test_trc_round_trip(tmp_path, rng):
    X = _trajectories(rng)
    path = write_trc(tmp_path / "t.trc", X, rate=100.0)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("PathFileType\t4\t(X/Y/Z)")
    assert lines[2].split("\t")[:5] == ["100", "100", "7", "4", "mm"]
    assert lines[3].split("\t")[:3] == ["Frame#", "Time", "P1"]
    back = read_trc(path)
    assert back.labels == ("P1", "P2", "P3", "P4") and back.rate == 100.0
    np.testing.assert_allclose(back.points, X, atol=1e-6)
    assert np.array_equal(np.isnan(back.points), np.isnan(X))


def test_ply_round_trip_through_pyvista_and_plyfile(tmp_path, rng):
    pv = pytest.importorskip("pyvista")
    X = rng.normal(0, 300, (50, 3))
    sigma = rng.uniform(0.1, 1.0, 50)
    faces = np.array([[0, 1, 2], [2, 3, 4]])
    path = write_ply(tmp_path / "surfaces" / "frame_0000.ply", X, scalars={"sigma": sigma},
                     faces=faces)
    mesh = pv.read(path)
    assert mesh.n_points == 50 and mesh.n_cells == 2
    np.testing.assert_allclose(mesh.points, X, rtol=1e-6, atol=1e-4)
    ply = PlyData.read(str(path))
    np.testing.assert_allclose(ply["vertex"]["sigma"], sigma, rtol=1e-6)


def test_bad_input_is_named(tmp_path):
    with pytest.raises(ValueError, match="trajectories"):
        write_c3d(tmp_path / "a.c3d", np.zeros((3, 2)), rate=60)
    with pytest.raises(ValueError, match="rate"):
        write_trc(tmp_path / "a.trc", np.zeros((3, 2, 3)), rate=0)
    with pytest.raises(ValueError, match="labels"):
        write_trc(tmp_path / "a.trc", np.zeros((3, 2, 3)), rate=60, labels=["a"])
    with pytest.raises(ValueError, match="labels"):
        write_c3d(tmp_path / "a.c3d", np.zeros((3, 2, 3)), rate=60, labels=["a", "a"])
    with pytest.raises(ValueError, match="path"):
        write_c3d(tmp_path / "a.trc", np.zeros((3, 2, 3)), rate=60)
    with pytest.raises(ValueError, match="points"):
        write_ply(tmp_path / "a.ply", np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="faces"):
        write_ply(tmp_path / "a.ply", np.zeros((3, 3)), faces=[[0, 1, 5]])
    with pytest.raises(ValueError, match="scalars"):
        write_ply(tmp_path / "a.ply", np.zeros((3, 3)), scalars={"x": np.zeros(3)})
