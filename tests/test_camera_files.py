"""Camera files in and out (issue 24): every format round-trips to 1e-9 px in projection,
the 2-D point readers, and clear errors for bad files."""

from pathlib import Path

import numpy as np
import pytest

from conftest import random_camera
from lsmta import camera_files as cf
from lsmta.io import read_caliscope_points, read_xypts, write_xypts

DATA = Path(__file__).resolve().parents[1] / "data"
QCA = DATA / "pose2sim_demo" / "Calib.qca.txt"
CALISCOPE = DATA / "caliscope_4cam"
TOL_PX = 1e-9


def _points(rng, n=60):
    return rng.uniform([-300, -300, 700], [300, 300, 1300], (n, 3))


def _max_projection_difference(a, b, X):
    assert len(a) == len(b)
    return max(float(np.abs(p.project(X) - q.project(X)).max()) for p, q in zip(a, b))


@pytest.fixture
def cameras(rng):
    return [random_camera(rng, name=f"cam{k}") for k in range(3)]


@pytest.mark.parametrize("unit", ["mm", "m"])
def test_opencv_yaml_round_trip(tmp_path, cameras, rng, unit):
    path = cf.write_opencv_yaml(tmp_path / "cams.yml", cameras, unit=unit)
    back = cf.read_opencv_yaml(path)
    assert [c.name for c in back] == [c.name for c in cameras]
    assert [c.image_size for c in back] == [c.image_size for c in cameras]
    assert _max_projection_difference(cameras, back, _points(rng)) < TOL_PX


@pytest.mark.parametrize("layout, unit", [("aniposelib", "mm"), ("caliscope", "m")])
def test_toml_round_trip(tmp_path, cameras, rng, layout, unit):
    path = cf.write_camera_toml(tmp_path / "cams.toml", cameras, unit=unit, layout=layout)
    back = cf.read_camera_toml(path, unit=unit)
    assert _max_projection_difference(cameras, back, _points(rng)) < TOL_PX


def test_dlt_round_trip_of_the_linear_camera(tmp_path, rng):
    # DLT is the linear camera: interior orientation, affinity and shear, exterior
    cams = [random_camera(rng, shear=True).replace(k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0)
            for _ in range(3)]
    path = cf.write_dlt(tmp_path / "dltCoefs.csv", cams)
    L = cf.read_dlt(path)
    assert L.shape == (3, 11)
    back = [cf.camera_from_dlt(L[k], c.image_size) for k, c in enumerate(cams)]
    X = _points(rng)
    assert _max_projection_difference(cams, back, X) < TOL_PX
    # the coefficients themselves project with y measured upwards (easyWand, Argus)
    for k, cam in enumerate(cams):
        den = X @ L[k, 8:] + 1
        u = (X @ L[k, :3] + L[k, 3]) / den
        v = (X @ L[k, 4:7] + L[k, 7]) / den
        xy = cam.project(X)
        assert np.abs(u - xy[:, 0]).max() < TOL_PX
        assert np.abs(v - (cam.height - xy[:, 1])).max() < TOL_PX


def test_qualisys_file_is_read_and_its_cameras_face_the_volume(tmp_path, rng):
    cams = cf.read_qca(QCA)
    assert [c.name for c in cams] == ["cam01", "cam02", "cam03", "cam04"]
    assert all(c.image_size == (1088, 1920) for c in cams)
    # focal length and principal point in pixels: sensor units / 64
    assert cams[0].f == pytest.approx(107588.828125 / 64)
    assert cams[0].f * (1 + cams[0].b1) == pytest.approx(107599.671875 / 64)
    assert cams[0].cx == pytest.approx(34110.316406 / 64)
    assert cams[0].k1 == pytest.approx(-0.046183)
    # the optical axes of the four cameras meet in front of all of them, below the cameras
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in cams:
        P = np.eye(3) - np.outer(c.R[2], c.R[2])
        A += P
        b += P @ c.C
    meet = np.linalg.solve(A, b)
    assert all(c.to_camera(meet[None])[0, 2] > 1000 for c in cams)
    assert all(meet[2] < c.C[2] for c in cams)
    # and survive a round trip through the other formats
    X = meet + rng.uniform(-500, 500, (40, 3))
    path = cf.write_camera_toml(tmp_path / "q.toml", cams, unit="m")
    assert _max_projection_difference(cams, cf.read_camera_toml(path, unit="m"), X) < TOL_PX


def test_caliscope_reference_file_is_read():
    cams = cf.read_camera_toml(CALISCOPE / "camera_array.toml", unit="m")
    assert len(cams) == 4 and all(c.image_size == (1280, 720) for c in cams)
    assert cams[1].f == pytest.approx(706.235022552987)
    # camera 1 is caliscope's origin
    assert np.linalg.norm(cams[1].C) < 5.0


def test_camera_file_errors_name_the_argument(tmp_path, cameras):
    with pytest.raises(ValueError, match="unit"):
        cf.write_camera_toml(tmp_path / "c.toml", cameras, unit="furlong")
    cf.write_camera_toml(tmp_path / "c.toml", cameras, unit="mm")
    with pytest.raises(TypeError, match="unit"):
        cf.read_camera_toml(tmp_path / "c.toml")                          # no unit
    with pytest.raises(ValueError, match="layout"):
        cf.write_camera_toml(tmp_path / "c.toml", cameras, unit="mm", layout="easywand")
    with pytest.raises(FileNotFoundError, match="path"):
        cf.read_opencv_yaml(tmp_path / "missing.yml")
    with pytest.raises(TypeError, match="cameras"):
        cf.write_dlt(tmp_path / "d.csv", ["not a camera"])
    (tmp_path / "bad.csv").write_text("1,2\n3,4\n")
    with pytest.raises(ValueError, match="11 rows"):
        cf.read_dlt(tmp_path / "bad.csv")
    dup = [cameras[0], cameras[1].replace(name=cameras[0].name)]
    with pytest.raises(ValueError, match="unique"):
        cf.write_opencv_yaml(tmp_path / "c.yml", dup)


# ---------------------------------------------------------------------- 2-D point files
XYPTS = """pt1_cam1_X,pt1_cam1_Y,pt1_cam2_X,pt1_cam2_Y,pt2_cam1_X,pt2_cam1_Y,pt2_cam2_X,pt2_cam2_Y
100.5,400.25,NaN,NaN,110,390,210.5,300
NaN,NaN,12,34,,,56,78
"""


def test_xypts_reader_flips_y_to_the_top_left_origin(tmp_path):
    path = tmp_path / "wandxypts.csv"
    path.write_text(XYPTS)
    xy = read_xypts(path, 2, image_heights=(480, 720))
    assert xy.shape == (2, 2, 2, 2)                     # (K, T, P, 2)
    np.testing.assert_array_equal(xy[0, 0, 0], [100.5, 480 - 400.25])
    np.testing.assert_array_equal(xy[1, 0, 1], [210.5, 720 - 300])
    np.testing.assert_array_equal(xy[1, 1, 0], [12, 720 - 34])
    assert np.isnan(xy[1, 0, 0]).all() and np.isnan(xy[0, 1, 1]).all()    # NaN and empty
    raw = read_xypts(path, 2, image_heights=None, flip_y=False)
    np.testing.assert_array_equal(raw[0, 0, 0], [100.5, 400.25])
    # and back
    out = write_xypts(tmp_path / "again.csv", xy, image_heights=(480, 720))
    np.testing.assert_array_equal(read_xypts(out, 2, image_heights=(480, 720)), xy)
    assert out.read_text().splitlines()[0] == XYPTS.splitlines()[0]


def test_xypts_reader_takes_argus_columns_and_the_sparse_form(tmp_path):
    # Argus: <track>_cam_<k>_x, lower case, NaN written by pandas as "NaN"
    argus = XYPTS.replace("pt1_cam1_X", "wand_a_cam_1_x").replace("pt1_cam1_Y", "wand_a_cam_1_y")
    argus = argus.replace("pt1_cam2_X", "wand_a_cam_2_x").replace("pt1_cam2_Y", "wand_a_cam_2_y")
    (tmp_path / "a.csv").write_text(argus)
    dense = read_xypts(_write(tmp_path, XYPTS), 2,
                       image_heights=(480, 720))
    np.testing.assert_array_equal(read_xypts(tmp_path / "a.csv", 2, image_heights=(480, 720)),
                                  dense)
    # DLTdv 8 / Argus sparse .tsv: header, "frames columns count", 1-based triplets
    header = XYPTS.splitlines()[0].split(",")
    table = np.array([[float(c) if c.strip() else np.nan for c in row.split(",")]
                      for row in XYPTS.splitlines()[1:]])
    rows, cols = np.nonzero(np.isfinite(table))
    lines = ["\t".join(header), f"{table.shape[0]}\t{table.shape[1]}\t{len(rows)}"]
    lines += [f"{i + 1}\t{j + 1}\t{float(table[i, j])!r}" for i, j in zip(rows, cols)]
    (tmp_path / "s-xypts.tsv").write_text("\n".join(lines) + "\n")
    sparse = read_xypts(tmp_path / "s-xypts.tsv", 2, image_heights=(480, 720))
    np.testing.assert_array_equal(sparse, dense)
    lines[1] = f"{table.shape[0]}\t{table.shape[1]}\t{len(rows) + 1}"
    (tmp_path / "s-xypts.tsv").write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match="values and lists"):
        read_xypts(tmp_path / "s-xypts.tsv", 2, image_heights=(480, 720))


def _write(tmp_path, text):
    path = tmp_path / "dense.csv"
    path.write_text(text)
    return path


def test_xypts_reader_refuses_bad_files(tmp_path):
    path = tmp_path / "x.csv"
    path.write_text(XYPTS)
    with pytest.raises(ValueError, match="n_cameras"):
        read_xypts(path, 1, image_heights=480)
    with pytest.raises(ValueError, match="image_heights"):
        read_xypts(path, 2, image_heights=(480,))
    with pytest.raises(ValueError, match="image_heights"):
        read_xypts(path, 2, image_heights=(480, -1))
    path.write_text("frame,pt1_cam1_X\n1,2\n")
    with pytest.raises(ValueError, match="frame"):
        read_xypts(path, 1, image_heights=480)
    path.write_text("pt1_cam1_X,pt1_cam1_Y\n1,2,3\n")
    with pytest.raises(ValueError, match="row 2"):
        read_xypts(path, 1, image_heights=480)
    path.write_text("pt1_cam1_X,pt1_cam1_Y\n1,abc\n")
    with pytest.raises(ValueError, match="abc"):
        read_xypts(path, 1, image_heights=480)


def test_caliscope_points_are_read_per_camera_frame_and_corner():
    pts = read_caliscope_points(CALISCOPE / "xy.csv")
    assert pts.xy.shape == (4, 48, 12, 2)
    assert pts.n_observations == 1725
    np.testing.assert_allclose(pts.board[:3, :2], [[54, 54], [108, 54], [162, 54]], atol=1e-4)
    assert np.all(pts.board[:, 2] == 0)


def test_qualisys_reader_projects_as_the_file_says():
    """One camera's projection of a point computed by hand from the numbers in the file."""
    from lsmta.io import read_qualisys_calibration

    cams = read_qualisys_calibration(QCA)
    assert len(cams) == 4
    # cam02 as written in Calib.qca.txt: rows of M are the camera axes (y up, z backwards)
    M = np.array([[-0.1966832217091926, 0.979523227309506, -0.043011131806342306],
                  [-0.31478107085300017, -0.02153908797812718, 0.9489198834051846],
                  [0.9285626460991909, 0.20017570994064315, 0.3125717476340885]])
    C = np.array([2582.0136248568124, 706.5662881637625, 1690.9818366061595])
    fu, fv, cu, cv = 107118.695313 / 64, 107123.023438 / 64, 34207.652344 / 64, 61646.457031 / 64
    k1, k2, p1, p2 = -0.047847, 0.136786, 0.000972, 0.000291
    X = np.array([150.0, -220.0, 900.0])                 # mm, in front of cam02
    xc = M @ (X - C)
    x, y = xc[0] / -xc[2], -xc[1] / -xc[2]               # y down, z forward
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    by_hand = np.array([fu * xd + cu, fv * yd + cv])
    np.testing.assert_allclose(cams[1].project(X[None])[0], by_hand, atol=0.05)
    assert 0 < by_hand[0] < 1088 and 0 < by_hand[1] < 1920


def test_qualisys_reader_bad_input(tmp_path):
    from lsmta.io import read_qualisys_calibration

    with pytest.raises(FileNotFoundError, match="path"):
        read_qualisys_calibration(tmp_path / "missing.qca.txt")
    empty = tmp_path / "empty.qca.txt"
    empty.write_text("<calibration><cameras/></calibration>")
    with pytest.raises(ValueError, match="path"):
        read_qualisys_calibration(empty)
