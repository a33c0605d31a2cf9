"""The LSMTA system on any recording with calibrated cameras (lsmta.systems.capture_recording),
its files (BodyCapture.save, read back with ezc3d and pyvista), camera files recognised by
content, and the ``lsmta capture`` command."""

import argparse
import json
import warnings
from dataclasses import replace
from types import SimpleNamespace

import cv2
import ezc3d
import numpy as np
import pytest
import pyvista as pv
from plyfile import PlyData

from lsmta.body import FitStatus, ModelState, arm_model
from lsmta.camera import Camera
from lsmta.camera_files import (
    camera_file_format,
    read_camera_file,
    read_camera_toml,
    write_camera_toml,
    write_opencv_yaml,
)
from lsmta.cli import main
from lsmta.data import CALISCOPE_DIR, POSE2SIM_DIR
from lsmta.evaluation import body_system as bs
from lsmta.result_files import read_trc
from lsmta.systems import (
    CaptureParams,
    axis_angles,
    capture_recording,
    track_surface,
    view_groups,
)


def _ring(n: int, radius: float = 3000.0) -> list:
    """n cameras evenly round a circle, all looking at its centre."""
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        C = radius * np.array([np.cos(a), np.sin(a), 0.0])
        z = -C / np.linalg.norm(C)
        x = np.cross([0.0, 0.0, 1.0], z)
        R = np.stack([x, np.cross(z, x), z])
        cams.append(Camera(f=1000.0, cx=320.0, cy=240.0, width=640, height=480, R=R, C=C,
                           name=f"c{k}"))
    return cams


def test_view_groups_of_rings():
    ring = view_groups(_ring(8))                       # 45 degrees between neighbours
    assert [g.cameras for g in ring] == [tuple(sorted({(k - 1) % 8, k, (k + 1) % 8}))
                                         for k in range(8)]
    assert all(g.template in g.cameras for g in ring)
    four = view_groups(_ring(4), max_angle_deg=100.0)  # 90 degrees: each with both neighbours
    assert len(four) == 4 and all(len(g.cameras) == 3 for g in four)
    with pytest.raises(ValueError, match="no two cameras"):
        view_groups(_ring(4))                          # 90 > 75: no group at all
    with pytest.raises(ValueError, match="max_angle_deg"):
        view_groups(_ring(4), max_angle_deg=-1.0)
    A = axis_angles(_ring(4))
    assert np.allclose(A, A.T) and np.allclose(np.diag(A), 0.0, atol=1e-6)
    assert np.isclose(A[0, 2], 180.0)


def test_the_demo_rig_is_two_groups():
    groups = view_groups(read_camera_file(POSE2SIM_DIR / "Calib.qca.txt"))
    assert [g.cameras for g in groups] == [(0, 1), (2, 3)]


def test_camera_files_recognised_by_content(tmp_path):
    cams = read_camera_file(POSE2SIM_DIR / "Calib.qca.txt")
    assert camera_file_format(POSE2SIM_DIR / "Calib.qca.txt") == "qualisys"
    assert camera_file_format(CALISCOPE_DIR / "camera_array.toml") == "caliscope"
    cali = read_camera_file(CALISCOPE_DIR / "camera_array.toml")
    assert np.allclose([c.C for c in cali],
                       [c.C for c in read_camera_toml(CALISCOPE_DIR / "camera_array.toml",
                                                      unit="m")])
    ours = write_camera_toml(tmp_path / "rig.txt", cams, unit="cm")   # any file name
    assert camera_file_format(ours) == "toml"
    back = read_camera_file(ours)
    assert np.allclose([c.C for c in back], [c.C for c in cams], atol=1e-6)
    yml = write_opencv_yaml(tmp_path / "rig.yml", cams, unit="m")
    assert camera_file_format(yml) == "opencv"
    assert np.allclose([c.C for c in read_camera_file(yml)], [c.C for c in cams], atol=1e-6)
    with pytest.raises(ValueError, match="unit.*mm by the format"):
        read_camera_file(POSE2SIM_DIR / "Calib.qca.txt", unit="m")
    with pytest.raises(ValueError, match="states its unit as 'cm'"):
        read_camera_file(ours, unit="m")
    bare = tmp_path / "bare.toml"
    bare.write_text("\n".join(line for line in ours.read_text().splitlines()
                              if "unit" not in line and "[metadata]" not in line))
    with pytest.raises(ValueError, match="unit: .*does not state"):
        read_camera_file(bare)
    assert np.allclose(read_camera_file(bare, unit="cm")[0].C, cams[0].C, atol=1e-6)
    junk = tmp_path / "notes.txt"
    junk.write_text("hello")
    with pytest.raises(ValueError, match="not a camera file"):
        read_camera_file(junk)
    with pytest.raises(FileNotFoundError, match="no camera file"):
        read_camera_file(tmp_path / "missing.toml")


@pytest.fixture(scope="module")
def session():
    return bs.arm_wave_session(seed=7, n_frames=6, first=20, scale=0.5,
                               params=bs.ArmWaveSessionParams(n_bar=60, n_heldout=20))


@pytest.fixture(scope="module")
def capture(session):
    """The system on the session with cameras given (the generator's: a calibrated rig),
    no arm model."""
    videos = session.videos.copy()
    cap = capture_recording(session.videos, session.cameras, fps=session.fps, progress=False,
                            params=CaptureParams(density_every=3))
    assert np.array_equal(videos, session.videos)
    return cap


@pytest.mark.slow
def test_capture_recording_any_subject(capture, session):
    assert capture.arm is None and "arm model" not in capture.seconds
    assert len(capture.views) == 1 and capture.views[0].group.cameras == (0, 1, 2)
    assert capture.views[0].group.template == 1          # the centre camera
    assert capture.tracks is capture.views[0].tracks
    assert len(capture.trajectories) == len(capture.tracks)
    assert np.all(capture.group_of == 0)
    kept = capture.filtered.present.any(axis=0)
    assert kept.sum() > 0.8 * len(kept)
    assert capture.surfaces[0].neighbourhood_ok.sum() > 300
    rows = {r["stage"]: r for r in capture.summary()}
    assert set(rows) == {"calibration", "view groups", "image noise", "surfaces", "tracking",
                         "trajectories"}
    assert rows["calibration"]["result"] == "cameras as given"


@pytest.mark.slow
def test_capture_saved_files_read_back(capture, tmp_path):
    files = capture.save(tmp_path / "out")
    X = capture.filtered.xyz
    c3d = ezc3d.c3d(str(files["c3d"]))
    assert c3d["parameters"]["POINT"]["RATE"]["value"][0] == pytest.approx(capture.fps)
    assert c3d["parameters"]["POINT"]["UNITS"]["value"][0] == "mm"
    pts = np.moveaxis(c3d["data"]["points"][:3], (0, 1, 2), (2, 1, 0))      # (T, N, 3)
    missing = c3d["data"]["meta_points"]["residuals"][0].T < 0
    assert np.array_equal(missing, ~np.isfinite(X).all(axis=2))
    assert np.allclose(pts[~missing], X[~missing], atol=1e-3)
    assert c3d["parameters"]["POINT"]["LABELS"]["value"][:2] == ["G1_1", "G1_2"]
    trc = read_trc(files["trc"])
    assert np.allclose(trc.points[~missing], X[~missing], atol=1e-3)
    assert np.isnan(trc.points[missing]).all() and trc.labels[0] == "G1_1"
    ply = pv.read(files["surfaces"][0])
    s = capture.surfaces[0]
    ok = s.neighbourhood_ok & s.intersection.valid
    assert np.allclose(ply.points, s.intersection.points[ok], atol=1e-2)
    vertex = PlyData.read(str(files["surfaces"][0]))["vertex"]       # pyvista reads no scalars
    assert np.allclose(vertex["ray_distance_mm"], s.intersection.rms_ray_distance[ok],
                       rtol=1e-6)
    assert np.all(vertex["group"] == 1) and np.all(vertex["sigma_px"] > 0)
    assert files["surfaces"][0].name == f"frame_{int(capture.frames[0]):04d}.ply"
    back = read_camera_toml(files["cameras"], unit="mm")
    assert np.allclose([c.C for c in back], [c.C for c in capture.cameras], atol=1e-6)
    record = json.loads(files["summary"].read_text())
    assert record["trajectories"]["total"] == X.shape[1]
    assert record["view_groups"][0]["tracks"] == len(capture.tracks)
    # the tracked samples' median reprojection error (px), from the group's tracks
    assert 0 < record["view_groups"][0]["track_residual_px"] < 1.0
    page = files["report"].read_text()
    assert "<img" in page
    assert "<td>nan</td>" not in page and "<td>calibration</td><td>-</td>" in page
    assert files["mesh"] == [] and not (tmp_path / "out" / "mesh").exists()
    assert record["mesh"]["written"] is False and "no body model" in record["mesh"]["reason"]


@pytest.mark.slow
def test_capture_saved_meshes(capture, tmp_path):
    """With a body model (a stand-in arm fit: the fields save reads), one closed mesh per
    fitted frame, named by its file frame number."""
    model = arm_model()
    T = len(capture.frames)
    state = ModelState(angles=np.tile([0.4, 0.3, 0.2, 1.2, 0.1], (2, 1)),
                       shoulder=np.tile([180.0, 0.0, 400.0], (2, 1)), scales=np.ones(3),
                       radii=model.simplified_radii([[80, 80], [65, 65], [35, 70]], [1, 1, 1]))
    full = SimpleNamespace(state=state, status=FitStatus.OK, rounds=1,
                           lengths=np.array([300.0, 250.0, 100.0]))
    arm = SimpleNamespace(frames=np.array([0, T - 1]), full=full, sigma_mm=2.0,
                          start=SimpleNamespace(torso_poses=np.tile(np.eye(4), (T, 1, 1))))
    files = replace(capture, arm=arm).save(tmp_path / "out", report=False)
    assert [p.name for p in files["mesh"]] == [f"frame_{int(capture.frames[t]):04d}.ply"
                                               for t in (0, T - 1)]
    record = json.loads(files["summary"].read_text())["mesh"]
    for path, row in zip(files["mesh"], record["frames"]):
        mesh = pv.read(path)
        assert mesh.n_open_edges == 0 and row["open_edges"] == 0 and row["components"] == 1
        assert row["vertices"] == mesh.n_points
        assert mesh.volume / 1000 == pytest.approx(row["volume_ml"], abs=0.01)


@pytest.mark.slow
def test_capture_starts_tracking_at_the_first_surface(session, tmp_path):
    """Frame 0 blank (no surface point): the tracks start at the next measured surface
    (frame 3), NaN before it, and the trajectories are written from there."""
    videos = session.videos.copy()
    videos[:, 0] = videos[:, 0].mean().astype(videos.dtype)    # nothing to match
    given = videos.copy()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cap = capture_recording(videos, session.cameras, fps=session.fps, progress=False,
                                params=CaptureParams(density_every=3))
    assert np.array_equal(videos, given)
    said = [str(w.message) for w in caught]
    assert any("no seed found in frame 0" in m for m in said)        # measure_surfaces'
    assert not any("view group" in m for m in said)                  # the group is kept
    view = cap.views[0]
    assert 0 not in view.surfaces and view.surfaces[3].kept.sum() > 0
    assert view.tracking_from == 3 and view.tracks.n_frames == len(cap.frames)
    assert np.isnan(view.tracks.xy[:3]).all() and view.tracks.alive[3].sum() > 0
    assert np.all(view.tracks.start >= 3) and np.all(view.tracks.anchor[:3] == -1)
    present = cap.filtered.present
    assert not present[:3].any() and present[3:].any(axis=0).sum() > 0.8 * len(view.tracks)
    rows = {r["stage"]: r["result"] for r in cap.summary()}
    assert "from frame 3:" in rows["tracking"]
    files = cap.save(tmp_path / "out")                                 # with the report
    assert files["c3d"].exists() and files["trc"].exists()
    assert json.loads(files["summary"].read_text())["view_groups"][0]["tracking_from"] == 3
    with pytest.raises(ValueError, match="no frame before the last"):
        track_surface(videos[:, :3], {})


def test_capture_recording_bad_input(session):
    v, cams = session.videos, session.cameras
    with pytest.raises(ValueError, match="fps"):
        capture_recording(v, cams, progress=False)
    with pytest.raises(ValueError, match="expected 3 videos"):
        capture_recording(v[:2], cams, fps=25.0, progress=False)
    with pytest.raises(ValueError, match=r"videos\[0\]: frames are"):
        capture_recording(v[:, :, :-2], cams, fps=25.0, progress=False)
    with pytest.raises(TypeError, match="grey values"):
        capture_recording(v.astype(bool), cams, fps=25.0, progress=False)
    with pytest.raises(ValueError, match="frames"):
        capture_recording(v, cams, fps=25.0, frames=[0, 2, 3], progress=False)
    with pytest.raises(TypeError, match="CaptureParams"):
        capture_recording(v, cams, fps=25.0, params={"density_every": 2}, progress=False)
    with pytest.raises(ValueError, match="density_every"):
        CaptureParams(density_every=0)


def _write_videos(folder, videos, fps):
    paths = []
    for k, frames in enumerate(videos):
        path = folder / f"cam{k}.avi"
        h, w = frames.shape[1:]
        out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
        for f in frames:
            out.write(cv2.cvtColor(np.ascontiguousarray(f, np.uint8), cv2.COLOR_GRAY2BGR))
        out.release()
        paths.append(str(path))
    return paths


def test_command_help_and_bad_input(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["capture", "--help"])
    assert exit_.value.code == 0
    assert "example" in capsys.readouterr().out
    rig = write_camera_toml(tmp_path / "rig.toml", _ring(2, 2000.0), unit="mm")
    assert main(["capture", "--videos", "a.mp4", "b.mp4", "--cameras",
                 str(tmp_path / "none.toml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no camera file" in err[0]
    assert main(["capture", "--videos", "a.mp4", "--cameras", str(rig), "--out",
                 str(tmp_path / "o")]) == 2
    assert "no video" in capsys.readouterr().err
    assert main(["capture", "--videos", "a.mp4", "--cameras", str(rig), "--out",
                 str(tmp_path / "o"), "--frames", "x"]) == 2
    assert "--frames" in capsys.readouterr().err
    videos = _write_videos(tmp_path, np.zeros((2, 3, 48, 64), np.uint8), 25.0)
    assert main(["capture", "--videos", *videos, "--out", str(tmp_path / "o")]) == 2
    assert "--cameras: a camera file is needed" in capsys.readouterr().err
    assert main(["capture", "--videos", *videos, "--board", *videos, "--out",
                 str(tmp_path / "o")]) == 2
    assert "--board-config" in capsys.readouterr().err


@pytest.mark.slow
def test_command_end_to_end(session, tmp_path, capsys):
    paths = _write_videos(tmp_path, session.videos[:, :6], session.fps)
    rig = write_camera_toml(tmp_path / "rig.toml", session.cameras, unit="mm")
    out = tmp_path / "result"
    assert main(["capture", "--videos", *paths, "--cameras", str(rig), "--out", str(out),
                 "--no-refine", "--quiet"]) == 0
    assert "cameras as given" in capsys.readouterr().err
    record = json.loads((out / "summary.json").read_text())
    assert record["cameras_note"] == "as given"
    assert record["trajectories"]["kept_by_filters"] > 100
    assert (out / "trajectories.c3d").is_file() and (out / "report.html").is_file()
    assert "refinement" not in record
    refined = tmp_path / "refined"
    assert main(["capture", "--videos", *paths, "--cameras", str(rig), "--out", str(refined),
                 "--quiet"]) == 0
    record = json.loads((refined / "summary.json").read_text())
    assert record["cameras_note"].startswith("refined from the recording")
    per_camera = json.loads((refined / record["refinement"]["summary"]).read_text())["cameras"]
    assert len(per_camera) == 3 and all(c["tie_points"] > 0 for c in per_camera.values())
    assert (refined / "refinement" / "cameras.toml").is_file()
    wrong = write_camera_toml(tmp_path / "wrong.toml", session.cameras[:2], unit="mm")
    assert main(["capture", "--videos", *paths, "--cameras", str(wrong), "--out", str(out),
                 "--no-refine", "--quiet"]) == 2
    assert "2 cameras for 3 videos" in capsys.readouterr().err


def test_a_surface_only_on_the_last_frame_starts_no_tracks():
    """A start needs a frame after it: a group whose only surface point lies on the last
    frame (a subject who walks in at the end) has nothing to track, with a clear error."""
    empty = SimpleNamespace(kept=np.zeros(0, bool), xy=np.zeros((2, 0, 2)),
                            neighbourhood_ok=np.zeros(0, bool))
    last = SimpleNamespace(kept=np.ones(1, bool), xy=np.full((2, 1, 2), 10.0),
                           neighbourhood_ok=np.ones(1, bool))
    videos = np.zeros((2, 5, 32, 32), np.float32)
    with pytest.raises(ValueError, match="surfaces: no frame before the last"):
        track_surface(videos, {0: empty, 2: empty, 4: last})


@pytest.mark.slow
def test_command_surface_options(session, tmp_path, capsys):
    """--subject-mask and --more-views end to end; --surface-method rectified-sgbm measures a
    three-camera view group by the growth, with a warning naming the group and the option;
    a method not offered is an argparse error."""
    paths = _write_videos(tmp_path, session.videos[:, :6], session.fps)
    rig = write_camera_toml(tmp_path / "rig.toml", session.cameras, unit="mm")
    out = tmp_path / "result"
    assert main(["capture", "--videos", *paths, "--cameras", str(rig), "--out", str(out),
                 "--no-refine", "--quiet", "--subject-mask", "--more-views"]) == 0
    record = json.loads((out / "summary.json").read_text())
    group = record["view_groups"][0]
    first = str(record["frames"][0])
    assert group["off_subject"][first] >= 0
    # one group of all three cameras: its points are in three views already
    assert group["points_in_3_or_more_views"][first] == group["surface_points"][first] > 0
    assert group["median_residual_3_or_more_views_px"][first] < 0.5
    assert any(row["stage"] == "more views" for row in record["stages"])
    capsys.readouterr()
    with pytest.warns(UserWarning, match="view group left\\+centre\\+right has 3 cameras.*"
                                         "--surface-method rectified-sgbm.*by the growth"):
        assert main(["capture", "--videos", *paths, "--cameras", str(rig), "--out",
                     str(tmp_path / "fallback"), "--no-refine", "--quiet",
                     "--surface-method", "rectified-sgbm"]) == 0
    fallback = json.loads((tmp_path / "fallback" / "summary.json").read_text())
    # the growth's points, before the subject mask of the first run drops any
    assert fallback["view_groups"][0]["surface_points"][first] >= group["surface_points"][first]
    with pytest.raises(SystemExit) as exit_:
        main(["capture", "--videos", *paths, "--cameras", str(rig), "--out", str(out),
              "--surface-method", "sgbm"])
    assert exit_.value.code == 2
    assert "--surface-method" in capsys.readouterr().err


def test_command_scales_the_mask_and_patches_with_the_frames():
    """--scale resizes the frames: the subject mask's radii and the more-views patches (px of
    full-size frames) follow; at scale 1 they are the library's defaults."""
    from lsmta.capture_command import _params
    from lsmta.systems.more_views import MoreViewsParams
    from lsmta.systems.subject import SubjectMaskParams

    def params(scale):
        args = SimpleNamespace(markers=None, surface_method="growth", subject_mask=True,
                               more_views=True, arm=False, scale=scale, tracker="lsmta")
        return _params(args)

    full, half = params(1.0), params(0.5)
    assert full.surface.subject_mask == SubjectMaskParams()
    assert full.more_views == MoreViewsParams()
    assert (half.surface.subject_mask.close_px, half.surface.subject_mask.grow_px) == (8, 8)
    assert (half.more_views.patch, half.more_views.retry_patch) == (7, (11,))
    assert params(0.1).more_views.patch == 5, "the smallest patch"


def test_command_marker_filter_option():
    """--marker-filter-hz sets the markers' low-pass cut-off (default Pose2Sim's 6 Hz); 0
    turns it off; a negative one is refused naming the option."""
    from lsmta.capture_command import _params, add_parser

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    base = ["capture", "--videos", "a.mp4", "--out", "o", "--markers", "skin"]
    for extra, hz in (([], 6.0), (["--marker-filter-hz", "8"], 8.0),
                      (["--marker-filter-hz", "0"], None)):
        args = parser.parse_args(base + extra)
        assert _params(args).markers.filter_hz == hz
        assert _params(args).markers.filter_order == 4
    with pytest.raises(ValueError, match="filter_hz"):
        _params(parser.parse_args(base + ["--marker-filter-hz", "-1"]))


def test_a_cutoff_above_nyquist_is_decided_before_any_stage(tmp_path, capsys, monkeypatch):
    """At 12 fps or less the default 6 Hz cut-off is at or above the Nyquist frequency: a
    chosen cut-off is refused at once (naming the argument and fps / 2); the default one is
    turned off with a warning, and the capture records why."""
    import lsmta.systems.capture as capture_module
    from lsmta.systems import MarkerParams, nyquist_checked

    blobs = MarkerParams(detector="blobs")
    assert nyquist_checked(blobs, 13.0) == (blobs, None)             # 6 < 6.5: kept
    assert nyquist_checked(None, 6.0) == (None, None)
    with pytest.warns(RuntimeWarning, match="Nyquist frequency 3 Hz"):
        off, reason = nyquist_checked(blobs, 6.0)
    assert off.filter_hz is None and off.detector == "blobs" and "6 fps" in reason
    assert blobs.filter_hz == 6.0                                     # not modified
    for params, explicit in ((MarkerParams(filter_hz=5.0), None), (blobs, True)):
        with pytest.raises(ValueError, match=r"^params.markers.filter_hz: .* fps / 2 = 3 Hz"):
            nyquist_checked(params, 6.0, explicit=explicit)
    cams, v = _ring(8)[:2], np.zeros((2, 12, 480, 640), np.uint8)
    with pytest.raises(ValueError, match="filter_hz: .*Nyquist"):
        capture_recording(v, cams, fps=6.0, progress=False,
                          params=CaptureParams(markers=MarkerParams(filter_hz=4.0)))
    ran = []
    stages = dict(capture_module.STAGES)
    monkeypatch.setattr(capture_module, "STAGES", tuple(
        (name, (lambda st, n=name: ran.append(n) or stages[n](st)))
        for name in ("more views", "markers", "arm model")))
    with pytest.warns(RuntimeWarning, match="default cut-off 6 Hz"):
        cap = capture_recording(v, cams, fps=6.0, progress=False,
                                params=CaptureParams(markers=blobs))
    assert ran == ["more views", "markers", "arm model"]
    assert cap.markers.filter == {"applied": False, "reason": reason}
    assert cap.markers.xyz_filtered is None
    # the command: a chosen --marker-filter-hz is refused before the cameras are read
    videos = _write_videos(tmp_path, np.zeros((2, 3, 48, 64), np.uint8), 6.0)
    assert main(["capture", "--videos", *videos, "--out", str(tmp_path / "o"), "--markers",
                 "blobs", "--marker-filter-hz", "6"]) == 2
    err = capsys.readouterr().err
    assert "--marker-filter-hz: expected a cut-off below the Nyquist frequency fps / 2 = 3 Hz" \
        in err


@pytest.mark.slow
def test_summary_carries_the_marker_join_checks_as_numbers(capture):
    """summary.json's markers: the join checks' counts as a structured entry."""
    from lsmta.systems.capture_files import capture_record
    from lsmta.systems.markers import MarkerCapture

    T = len(capture.frames)
    xyz = np.zeros((T, 1, 3))
    xyz[:, 0, 0] = np.arange(T) * 30.0
    joins = {"ambiguous": 2, "ambiguous_views": 1, "below_floor": 0, "views_out": 3,
             "attached": 1, "filled": np.int64(7)}
    markers = MarkerCapture(detections=(np.zeros((1, 2)),) * 3,
                            view_xy=(np.zeros((T, 1, 2)),) * 3,
                            members=np.array([[0, 0, -1]]), xy=np.zeros((T, 3, 1, 2)),
                            xyz=xyz, residual=np.zeros((T, 1)), motion_mm=np.array([150.0]),
                            moving=np.array([True]), seconds=0.1, joins=joins)
    record = capture_record(replace(capture, markers=markers))
    assert record["marker_join_checks"] == {k: int(v) for k, v in joins.items()}
    assert all(type(v) is int for v in record["marker_join_checks"].values())
    json.dumps(record)                                     # plain values


@pytest.mark.slow
def test_saved_markers_are_the_filtered_positions(capture, tmp_path):
    """markers.c3d / .trc hold the low-pass filtered positions and say so (C3D
    POINT:DESCRIPTIONS, summary.json's marker_filter); without the filter, the raw ones."""
    from lsmta.systems.markers import MarkerCapture

    T = len(capture.frames)
    raw = np.zeros((T, 2, 3))
    raw[:, :, 0] = np.arange(T)[:, None] * 30.0 + [0.0, 100.0]
    raw[2, 1] = np.nan
    smooth = raw + 0.5                       # stands for the filter's output (NaN kept)
    record = {"applied": True, "cutoff_hz": 6.0, "order": 4, "fps": capture.fps, "runs": 1,
              "short_runs": 2, "raw_samples": 5}
    common = dict(detections=(np.zeros((2, 2)),) * 3, view_xy=(np.zeros((T, 2, 2)),) * 3,
                  members=np.array([[0, 0, -1], [1, 1, -1]]), xy=np.zeros((T, 3, 2, 2)),
                  xyz=raw, residual=np.zeros((T, 2)), motion_mm=np.array([150.0, 150.0]),
                  moving=np.array([True, True]), seconds=0.1)
    for filtered, rec, want, words in (
            (smooth, record, smooth, "low-pass 6 Hz"),
            (None, {"applied": False, "reason": "MarkerParams.filter_hz is None"}, raw,
             "not filtered")):
        markers = MarkerCapture(**common, xyz_filtered=filtered, filter=rec)
        files = replace(capture, markers=markers).save(tmp_path / words, report=False)
        c3d = ezc3d.c3d(str(files["markers_c3d"]))
        pts = np.moveaxis(c3d["data"]["points"][:3], (0, 1, 2), (2, 1, 0))      # (T, N, 3)
        missing = c3d["data"]["meta_points"]["residuals"][0].T < 0
        assert np.array_equal(missing, np.isnan(want).any(axis=2))
        assert np.allclose(pts[~missing], want[~missing], atol=1e-3)
        assert all(words in d for d in c3d["parameters"]["POINT"]["DESCRIPTIONS"]["value"])
        trc = read_trc(files["markers_trc"])
        assert np.allclose(trc.points[~missing], want[~missing], atol=1e-3)
        summary = json.loads(files["summary"].read_text())
        assert summary["marker_filter"] == rec


@pytest.mark.slow
def test_a_group_that_does_not_see_one_side_is_measured_as_pairs(session):
    """A camera of the triplet that sees nothing the others see (blank frames): the group
    holds no surface point, so it is measured as pairs of its template with each other
    camera (CaptureParams.min_group_share), with a warning; the pair that sees the surface
    is tracked. With min_group_share=0 the group stays whole and nothing is measured."""
    videos = session.videos.copy()
    assert [g.template for g in view_groups(session.cameras)] == [1]   # one group, centre
    blank = 2
    videos[blank] = videos[blank].mean().astype(videos.dtype)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cap = capture_recording(videos, session.cameras, fps=session.fps, progress=False,
                                params=CaptureParams(density_every=3))
    said = [str(w.message) for w in caught]
    assert any("measured as pairs" in m for m in said)
    assert all(len(v.group.cameras) == 2 for v in cap.views) and len(cap.views) == 2
    seeing = [v for v in cap.views if blank not in v.group.cameras]
    assert len(seeing) == 1 and seeing[0].tracks is not None
    assert sum(s.kept.sum() for s in seeing[0].surfaces.values()) > 100
    assert cap.filtered.present.any(axis=0).sum() > 50
    with pytest.raises(ValueError, match="no view group found a surface point"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            capture_recording(videos, session.cameras, fps=session.fps, progress=False,
                              params=CaptureParams(density_every=3, min_group_share=0.0))
    with pytest.raises(ValueError, match="min_group_share"):
        CaptureParams(min_group_share=1.5)


@pytest.mark.slow
def test_a_group_whose_subject_is_absent_in_half_the_frames_stays_whole(session):
    """The subject gone from the second half of the recording (blank frames in every camera):
    the triplet holds points in 1 of its 2 measured frames, below min_group_share=0.75, so
    its pairs are measured too; they hold points in no more frames than the whole group, so
    it is not split and keeps its points seen by all three cameras."""
    videos = session.videos.copy()
    half = videos.shape[1] // 2
    videos[:, half:] = videos[:, half:].mean().astype(videos.dtype)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cap = capture_recording(videos, session.cameras, fps=session.fps, progress=False,
                                params=CaptureParams(density_every=3, min_group_share=0.75))
    assert not any("measured as pairs" in str(w.message) for w in caught)
    assert len(cap.views) == 1 and cap.views[0].group.cameras == (0, 1, 2)
    held = {f for f, s in cap.views[0].surfaces.items() if s.kept.any()}
    assert held == {0}
    assert cap.views[0].surfaces[0].kept.sum() > 100


def test_min_group_share_is_a_share():
    for bad in (True, 1.5, -0.1, "half"):
        with pytest.raises((TypeError, ValueError), match="min_group_share"):
            CaptureParams(min_group_share=bad)
    assert CaptureParams(min_group_share=np.float32(0.25)).min_group_share == 0.25
