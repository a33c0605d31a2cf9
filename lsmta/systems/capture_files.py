"""A capture written where other tools read it (:meth:`BodyCapture.save`).

Files, in one folder:

* ``cameras.toml``: the cameras used, aniposelib / Pose2Sim layout, mm
  (:func:`lsmta.camera_files.write_camera_toml`);
* ``trajectories.c3d`` and ``trajectories.trc``: the filtered trajectories, mm, at the
  recording's frame rate, labelled ``G<group>_<n>`` (view group, then the point's number in
  it); a sample the filters removed is missing (C3D residual -1, an empty TRC field);
* ``markers.c3d`` and ``markers.trc`` (with the marker stage): the moving markers' 3-D
  positions, labelled ``M<n>`` in the order of ``summary.json``'s ``markers`` list, low-pass
  filtered (``MarkerParams.filter_hz``: zero-lag Butterworth, Pose2Sim's nominal 6 Hz,
  order 4 by default, per gap-free run; gaps stay missing) unless the filter is off; the
  C3D's ``POINT:DESCRIPTIONS`` and ``summary.json``'s ``marker_filter`` say which, while
  ``markers.trc`` carries no filter note (its header has no field for one; the residuals
  in ``summary.json`` are those of the raw intersections);
* ``surfaces/frame_NNNN.ply``: each measured frame's surface points of every view group
  (file frame numbers), with per-point ``group``, ``sigma_px`` (largest LSM standard deviation
  of the point's image positions) and ``ray_distance_mm`` (RMS distance of the point to its
  rays);
* ``mesh/frame_NNNN.ply`` (with the arm model stage): one closed triangle mesh of the fitted
  body model per fitted frame, the iso-surface of its metaball field by marching cubes
  (:func:`lsmta.body.mesh.body_mesh`, mm, the cameras' world); ``summary.json``'s ``mesh``
  entry gives each frame's vertices, open edges, components and volume, or says why no
  mesh was written (no body model was fitted: the stage is optional);
* ``summary.json``: the stages with their times and results, counts (per view group also
  ``track_residual_px``: the median reprojection error of its tracked samples intersected
  from all its cameras), the calibration's own summary where it has one;
* ``report.html``: the summary table and figures of this recording (the views with the
  tracked points, the trajectories), one file with the images inside it.
"""

from __future__ import annotations

import base64
import html
import io
import json
import warnings
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ..body import arm_model, base_poses
from ..body.mesh import body_mesh, write_mesh
from ..camera_files import write_camera_toml
from ..result_files import write_c3d, write_ply, write_trc
from ..triangulation import triangulate


def _plain(v):
    """JSON-ready: NaN and inf -> None, numpy scalars -> Python numbers."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    return None if isinstance(v, float) and not np.isfinite(v) else v


def trajectory_labels(capture) -> list:
    """``G<group>_<n>`` for every trajectory (groups and points counted from 1)."""
    labels = []
    for g, view in enumerate(capture.views):
        n = view.points.stop - view.points.start
        labels += [f"G{g + 1}_{i + 1}" for i in range(n)]
    return labels


def surface_cloud(capture, frame: int):
    """Every view group's surface points of processed frame ``frame``.

    Returns
    -------
    points : (M, 3) array, mm
    scalars : dict of str -> (M,) array
        ``group``, ``sigma_px``, ``ray_distance_mm``.
    """
    parts, groups, sigma, dist = [], [], [], []
    for g, view in enumerate(capture.views):
        s = view.surfaces.get(frame)
        if s is None:
            continue
        ok = s.kept
        parts.append(s.intersection.points[ok])
        groups.append(np.full(int(ok.sum()), g + 1.0))
        sigma.append(np.linalg.norm(s.sigma_xy, axis=2).max(axis=0)[ok])
        dist.append(s.intersection.rms_ray_distance[ok])
    if not parts:
        return np.empty((0, 3)), {"group": np.empty(0), "sigma_px": np.empty(0),
                                  "ray_distance_mm": np.empty(0)}
    return np.concatenate(parts), {"group": np.concatenate(groups),
                                   "sigma_px": np.concatenate(sigma),
                                   "ray_distance_mm": np.concatenate(dist)}


def _seconds(value) -> str:
    """A stage's time for the report: one decimal, or a dash where it was not timed."""
    return f"{value:.1f}" if value is not None and np.isfinite(value) else "-"


def _track_residual(view) -> float | None:
    """Median reprojection error (px) of a view group's tracked samples intersected from
    all its cameras (None without tracks)."""
    if view.tracks is None:
        return None
    errors = []
    for xy in view.tracks.xy:
        alive = np.isfinite(xy).all(axis=(0, 2))
        if alive.any():
            e = triangulate(view.cameras, xy[:, alive]).reprojection_error
            errors.append(e[np.isfinite(e)])
    errors = np.concatenate(errors) if errors else np.empty(0)
    return float(np.median(errors)) if len(errors) else None


def capture_record(capture) -> dict:
    """The numbers of ``summary.json``, as plain Python values."""
    present = capture.filtered.present
    record = {
        "frames": [int(capture.frames[0]), int(capture.frames[-1])],
        "fps": capture.fps,
        "stages": capture.summary(),
        "view_groups": [{
            "cameras": [c.name or str(k) for k, c in zip(v.group.cameras, v.cameras)],
            "template": v.cameras[v.group.template_position].name or str(v.group.template),
            "noise_sigma": float(v.noise.sigma),
            "surface_points": {int(capture.frames[t]): int(s.kept.sum())
                               for t, s in sorted(v.surfaces.items())},
            "off_subject": {int(capture.frames[t]): int(s.off_subject)
                            for t, s in sorted(v.surfaces.items())},
            "points_in_3_or_more_views": {int(capture.frames[t]): int((m.n_views >= 3).sum())
                                          for t, m in sorted(v.more_views.items())},
            "median_residual_3_or_more_views_px": {
                int(capture.frames[t]): (float(np.median(m.residual[m.n_views >= 3]))
                                         if (m.n_views >= 3).any() else None)
                for t, m in sorted(v.more_views.items())},
            "tracking_from": (None if v.tracks is None else
                              int(capture.frames[v.tracking_from])),
            "tracks": 0 if v.tracks is None else len(v.tracks),
            "alive_at_end": 0 if v.tracks is None else int(v.tracks.alive[-1].sum()),
            "trajectories": v.points.stop - v.points.start,
            "track_residual_px": _track_residual(v),
        } for v in capture.views],
        "trajectories": {"total": len(capture.trajectories),
                         "kept_by_filters": int(present.any(axis=0).sum()),
                         "samples": int(present.sum())},
    }
    if capture.markers is not None:
        m = capture.markers
        share = m.triangulated_share()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)      # never intersected
            med = np.nanmedian(m.residual, axis=0)
        record["markers"] = [{
            "label": f"M{i + 1}",
            "views": [capture.cameras[k].name or str(k) for k in np.flatnonzero(row >= 0)],
            "triangulated_share": float(share[j]), "median_residual_px": float(med[j]),
            "motion_mm": float(m.motion_mm[j])}
            for i, (j, row) in enumerate((j, m.members[j]) for j in np.flatnonzero(m.moving))]
        record["still_blobs_joined"] = int((~m.moving).sum())
        record["marker_join_checks"] = {k: int(v) for k, v in m.joins.items()}
        record["marker_filter"] = dict(m.filter)
    if hasattr(capture.calibration, "summary") and callable(capture.calibration.summary):
        record["calibration"] = capture.calibration.summary()
    return _plain(record)


def marker_description(record: dict) -> str:
    """The markers' C3D description: how their positions were filtered (``record``:
    :attr:`~lsmta.systems.MarkerCapture.filter`)."""
    if not record.get("applied"):
        return "lsmta marker, raw intersection (not filtered)"
    return (f"lsmta marker, low-pass {record['cutoff_hz']:g} Hz (zero-lag Butterworth, order "
            f"{record['order']}, per gap-free run)")


MESH_VOXEL_MM = 6.0      # grid step of the saved meshes, mm


def capture_meshes(capture, *, voxel_mm: float = MESH_VOXEL_MM) -> list:
    """One closed mesh of the fitted body model per fitted frame.

    Parameters
    ----------
    capture : BodyCapture
    voxel_mm : float
        Grid step of :func:`lsmta.body.mesh.body_mesh`, mm.

    Returns
    -------
    list of (int, BodyMesh)
        The processed frame index and its mesh; empty without a body model (the arm model
        stage did not run).
    """
    arm = capture.arm
    if arm is None:
        return []
    model, state = arm_model(), arm.full.state
    torso = arm.start.torso_poses
    out = []
    for i, t in enumerate(arm.frames):
        base = base_poses(torso[t:t + 1], state.shoulder[i])
        out.append((int(t), body_mesh(model, state.angles[i], state.scales, state.radii,
                                      base=base, voxel_mm=voxel_mm)))
    return out


def mesh_record(meshes) -> dict:
    """``summary.json``'s ``mesh`` entry from ``(file frame number, BodyMesh)`` pairs: each
    mesh's counts and volume (ml), or why there is none."""
    if not meshes:
        return {"written": False,
                "reason": "no body model was fitted (the arm model stage is optional and did "
                          "not run), so no mesh"}
    return {"written": True, "model": "arm", "voxel_mm": meshes[0][1].voxel_mm,
            "level": meshes[0][1].level,
            "frames": [{"frame": f, "vertices": m.n_vertices, "faces": m.n_faces,
                        "open_edges": m.n_open_edges,
                        "nonmanifold_edges": m.n_nonmanifold_edges,
                        "components": m.n_components,
                        "volume_ml": round(m.volume / 1000.0, 2)} for f, m in meshes]}


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _figures(capture) -> list:
    """(caption, base64 PNG) of the report's figures (matplotlib's object interface: no
    pyplot state is touched)."""
    out = []
    for g, view in enumerate(capture.views):
        tracks, K = view.tracks, len(view.cameras)
        if tracks is None:
            continue
        fig = Figure(figsize=(3.2 * K, 4.2))
        ax = fig.subplots(1, K, squeeze=False)
        for k in range(K):
            cam = view.cameras[k]
            ax[0, k].set_xlim(0, cam.width)
            ax[0, k].set_ylim(cam.height, 0)
            ax[0, k].set_aspect("equal")
            for t, colour in ((view.tracking_from, "tab:blue"), (tracks.n_frames - 1, "tab:red")):
                xy = tracks.xy[t, k]
                ax[0, k].plot(xy[:, 0], xy[:, 1], ".", ms=1.5, color=colour,
                              label=f"frame {int(capture.frames[t])}")
            ax[0, k].set_title(cam.name or f"camera {view.group.cameras[k]}", fontsize=9)
        ax[0, 0].legend(fontsize=7, loc="lower left")
        out.append((f"View group G{g + 1}: tracked points in the first tracked (blue) and "
                    "last (red) frame, in image pixels of every view", _png(fig)))
    X = capture.filtered.xyz
    if np.isfinite(X).any():
        fig = Figure(figsize=(12, 3.5))
        ax = fig.subplots(1, 3)
        t = np.arange(len(X)) / capture.fps
        for i, name in enumerate("XYZ"):
            ax[i].plot(t, X[:, :, i], lw=0.5, alpha=0.6)
            ax[i].set_xlabel("time (s)")
            ax[i].set_ylabel(f"{name} (mm)")
        out.append(("Filtered trajectories over time, one line per point (world X, Y, Z)",
                    _png(fig)))
    return out


def _report(capture, record: dict) -> str:
    rows = "".join(f"<tr><td>{html.escape(r['stage'])}</td><td>{_seconds(r['seconds'])}</td>"
                   f"<td>{html.escape(r['result'])}</td></tr>" for r in capture.summary())
    figs = "".join(f'<figure><img alt="{html.escape(c)}" src="data:image/png;base64,{b}">'
                   f"<figcaption>{html.escape(c)}</figcaption></figure>"
                   for c, b in _figures(capture))
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>lsmta capture</title>"
            "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}"
            "td,th{border-bottom:1px solid #ccc;padding:4px;text-align:left;"
            "vertical-align:top}img{max-width:100%}</style></head><body>"
            f"<h1>lsmta capture</h1><p>frames {record['frames'][0]}–{record['frames'][1]} at "
            f"{record['fps']:g} Hz; {record['trajectories']['kept_by_filters']} of "
            f"{record['trajectories']['total']} trajectories kept by the filters.</p>"
            "<table><tr><th>stage</th><th>s</th><th>result</th></tr>"
            f"{rows}</table>{figs}</body></html>")


def save_capture(capture, directory, *, report: bool = True) -> dict:
    """Write a :class:`~lsmta.systems.BodyCapture` (see the module docstring).

    Parameters
    ----------
    capture : BodyCapture
    directory : str or Path
        Made as needed; files already there with these names are replaced.
    report : bool
        Also write ``report.html`` (matplotlib figures).

    Returns
    -------
    dict of str -> Path
        The files written, by kind (``surfaces`` and ``mesh`` map to lists; ``mesh`` is
        empty without a body model).
    """
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    X, labels = capture.filtered.xyz, trajectory_labels(capture)
    out = {"cameras": write_camera_toml(folder / "cameras.toml", capture.cameras, unit="mm")}
    if X.shape[1]:
        out["c3d"] = write_c3d(folder / "trajectories.c3d", X, rate=capture.fps, labels=labels)
        out["trc"] = write_trc(folder / "trajectories.trc", X, rate=capture.fps, labels=labels)
    if capture.markers is not None and capture.markers.moving.any():
        M = capture.markers.xyz_written[:, capture.markers.moving]
        names = [f"M{i + 1}" for i in range(M.shape[1])]
        out["markers_c3d"] = write_c3d(folder / "markers.c3d", M, rate=capture.fps, labels=names,
                                       description=marker_description(capture.markers.filter))
        out["markers_trc"] = write_trc(folder / "markers.trc", M, rate=capture.fps, labels=names)
    frames = sorted({t for v in capture.views for t in v.surfaces})
    out["surfaces"] = []
    for t in frames:
        points, scalars = surface_cloud(capture, t)
        if len(points):
            out["surfaces"].append(write_ply(folder / "surfaces" /
                                             f"frame_{int(capture.frames[t]):04d}.ply",
                                             points, scalars=scalars))
    meshes = [(int(capture.frames[t]), m) for t, m in capture_meshes(capture)]
    out["mesh"] = [write_mesh(folder / "mesh" / f"frame_{f:04d}.ply", m) for f, m in meshes]
    record = capture_record(capture)
    record["mesh"] = mesh_record(meshes)
    if meshes:
        record["mesh"]["fit_status"] = capture.arm.full.status.name   # OK, or fit with care
    record["files"] = {k: ([str(p.relative_to(folder)) for p in v] if isinstance(v, list)
                           else str(v.relative_to(folder))) for k, v in out.items()}
    out["summary"] = folder / "summary.json"
    out["summary"].write_text(json.dumps(record, indent=2), encoding="utf-8")
    if report:
        out["report"] = folder / "report.html"
        out["report"].write_text(_report(capture, record), encoding="utf-8")
    return out
