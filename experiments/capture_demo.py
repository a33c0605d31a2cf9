"""`lsmta capture` on the Pose2Sim demo at full size, and its markers beside KLT's.

    .venv/bin/python experiments/capture_demo.py [--scale 1.0] [--frames 0:100]
        [--out build/benchmarks/capture_demo] [--plain] [--reuse]

Runs the command as a user would (the demo's four videos and its Qualisys camera file,
refined from the recording, skin markers tracked with LSMTA), times it, and reads its files
back with ezc3d and pyvista. Then, on the same frames, cameras and start points, the markers
are tracked again under the same pipeline (`lsmta.systems.capture_markers`): LSMTA, then
OpenCV's pyramidal KLT (the peer a user would pick instead) on the SAME markers (LSMTA's
detections, joins and moving set, ``like=``) and the same rigid pair (chosen by
`lsmta.real.own_recording.rigid_pair`'s rule on LSMTA's markers); KLT joined on its own is
recorded beside, for reference. The join checks (``MarkerParams.check``) decide on LSMTA's
tracks by the residual that is then scored, and KLT is scored on the markers they kept:
that favours LSMTA's residual. Both trackers are followed on the blobs (``MarkerParams.follow``)
unless ``--plain`` (each tracker alone over the clip, as before issue #40's marker fix).
Prints and writes ``<out>/experiment.json``: the command's time, stages and files; for both
trackers the moving markers, their coverage, median residual and the rigid-pair distance's
spread (the pair's heights and relative motion beside), raw (the intersections) and
low-pass filtered (``MarkerParams``' default, Pose2Sim's: zero-lag Butterworth, nominal 6 Hz,
order 4; what markers.c3d / .trc hold; the same pair, chosen on the raw positions), the join
check's counts (``MarkerParams.check``: ambiguous joins dropped, views taken out, tracks
attached, tracks not on a dot taken out and markers dropped for it (``not_dot_views``,
``not_dots``: ``MarkerParams.dot_share``), moving markers off the subject's silhouette
dropped, dots found again, of them along an epipolar line and by the reach search (a gap
of any length, once the other searches find nothing), ``MarkerParams.fill_reach``; 3-D
positions dropped by the residual gate and kept without a view, ``MarkerParams.residual_k``,
with the gate's bound), the 2-D
tracking's CPU time, the ratios LSMTA / KLT, and the targets' verdicts; per LSMTA marker
its views, 3-D share, the frames only one view (or none) holds it, the frames two or more
hold it but the residual gate dropped it, and of the one-view frames the
frames no other view shows a dot where the marker can be (`lsmta.tracking.second_view`'s
image test on LSMTA's tracks: on the holding view's epipolar line, within the marker's own
fastest 3-D step times the frames to its nearest 3-D position); beside the target, and
labelled apart from it, each moving marker's share of 3-D frames with those frames left out
(a count for the lead to judge, not the target's verdict). The run the README quotes
last is committed as ``experiments/results/capture_demo.json`` (with its command, date,
commit and load: at 5e1e7b9, load 4.4, the command 183 s; no idle run of this code).
The residual gate (``MarkerParams.residual_k`` = 4, on by default; at 3e8617b, uncommitted,
run 5 in the README: this script's run at full size, load about 4 with other jobs, the
command 314 s, CPU 213 s for the whole script; the committed run at 5e1e7b9 gives the same
markers and numbers): bound 2.29 px (4 x 1.4826 x the median residual of all markers' positions,
above
its 0.5 px floor); the shank marker's cam01 track, picked up again at frame 77 on another
dot (residual 3.3 -> 16 px, under 2.3 px in frames 79-83), is taken out as a run; a
three-view marker's cam04 track, on something else in frames 0-14 (about 80 px), is left
out there and in 5 other frames, and 13 of its two-view frames (cam02 + cam04, 5-7 px) are
dropped. Per moving marker the 3-D share goes 1.00 / 0.91 / 0.77 / 0.93 -> 0.87 / 0.91 /
0.76 / 0.70 (>= 90 %: 0.75 -> 0.25); the rigid-pair rule finds the thigh/shank pair again
(574 and 396 mm high, 187 mm apart, relative motion 0.85 -> 0.37), distance std 3.81 mm
raw and 3.84 mm filtered with LSMTA, 3.80 and 3.84 with KLT; residual LSMTA 0.557 ->
0.497 px, KLT 0.564 -> 0.494 px (each gated with its own bound, 2.29 and 2.31 px): LSMTA
now above KLT by 0.003 px.
Targets (issue #40): the command under 5 minutes on 2 cores; every marker seen by >= 2 views
in 3-D in >= 90 % of the frames; the rigid pair's distance std <= 3 mm; LSMTA at or below
KLT on residual and spread (spread judged raw and filtered, each verdict labelled; the
residual is the raw intersections' only).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import ezc3d
import numpy as np
import pyvista as pv

from lsmta.camera_files import read_camera_toml
from lsmta.cli import main as lsmta
from lsmta.data import POSE2SIM_CAMERAS, POSE2SIM_VIDEOS
from lsmta.io import read_videos
from lsmta.real.own_recording import marker_scores, moving_pairs
from lsmta.report import verdict, write_json
from lsmta.systems import MarkerParams, Tracker2D, capture_markers
from lsmta.tracking.second_view import hidden_frames


def _command(args, out, videos):
    """Run `lsmta capture` (unless --reuse finds its files): its time (None when reused),
    summary and the files read back."""
    t0 = time.perf_counter()
    if args.reuse and (out / "capture" / "summary.json").exists():
        status = 0
    else:
        status = lsmta(["capture", "--videos", *videos, "--cameras",
                        str(POSE2SIM_CAMERAS), "--mismatch", "crop",
                        "--frames", args.frames, "--scale", str(args.scale), "--markers",
                        "skin", "--out", str(out / "capture")])
        args.reuse = False
    seconds = None if args.reuse else time.perf_counter() - t0
    if status != 0:
        raise SystemExit(f"lsmta capture failed with status {status}")
    summary = json.loads((out / "capture" / "summary.json").read_text())
    c3d = ezc3d.c3d(str(out / "capture" / "markers.c3d"))
    plys = sorted((out / "capture" / "surfaces").glob("*.ply"))
    described = c3d["parameters"]["POINT"].get("DESCRIPTIONS", {}).get("value", [""])
    readback = {"markers_c3d_points": int(c3d["parameters"]["POINT"]["USED"]["value"][0]),
                "markers_c3d_description": described[0] if described else "",
                "markers_c3d_frames": int(c3d["data"]["points"].shape[2]),
                "ply_files": len(plys),
                "ply_points_first": int(pv.read(plys[0]).n_points) if plys else 0}
    return seconds, summary, readback


def _trackers(args, out, videos):
    """The same markers, cameras and frames through both 2-D trackers: the captures and
    their CPU times."""
    start, stop = (int(x) for x in args.frames.split(":"))
    v = read_videos(videos, frames=range(start, stop), scale=args.scale)
    cameras = read_camera_toml(out / "capture" / "cameras.toml", unit="mm")
    stacks = v.load(progress=False)
    first = v.read(0, colour=True)

    def params(tracker):
        extra = {"follow": None} if args.plain else {}
        return MarkerParams(sigma=2.5 * args.scale, max_px=4.0 * args.scale, tracker=tracker,
                            **extra)

    runs, cpu = {}, {}
    for name, tracker, like in (("LSMTA", Tracker2D.LSMTA, None), ("KLT", Tracker2D.KLT, "LSMTA"),
                                ("KLT own joins", Tracker2D.KLT, None)):
        c0 = time.process_time()
        runs[name] = capture_markers(stacks, cameras, first, params=params(tracker),
                                     like=runs.get(like), fps=v.fps)
        cpu[name] = time.process_time() - c0
    p = params(Tracker2D.LSMTA)
    fp = p.fill_follow()                                          # the fill's dot settings
    lm = runs["LSMTA"]
    hidden = hidden_frames(stacks, cameras, lm.view_xy, lm.members, radius=fp.window(),
                           min_contrast=fp.min_contrast, max_px=p.max_px)
    return runs, cpu, hidden


def _scores(runs, cpu):
    """Both trackers' scores on LSMTA's markers and rigid pair (KLT's own joins beside)."""
    scores = {"LSMTA": marker_scores(runs["LSMTA"])}
    pair = scores["LSMTA"]["pair"]
    # without LSMTA's pair, KLT's spread is not measured (its own pair would not compare)
    scores["KLT"] = marker_scores(runs["KLT"], pair=pair)
    if pair is None:
        scores["KLT"]["pair_std_mm"] = float("nan")
    scores["KLT own joins"] = marker_scores(runs["KLT own joins"])
    for name, s in scores.items():
        m = runs[name]
        measured = (m.xyz_filtered is not None and s["pair"] is not None
                    and not (name == "KLT" and pair is None))
        s["pair_std_filtered_mm"] = (marker_scores(m, pair=s["pair"], xyz=m.xyz_filtered)
                                     ["pair_std_mm"] if measured else float("nan"))
        s["filter"] = dict(m.filter)
        s["cpu_seconds"] = cpu[name]
        s["share_per_marker"] = runs[name].triangulated_share()[runs[name].moving].round(3).tolist()
        s["residual_bound_px"] = m.residual_bound_px
    return scores


def _filtered(record: dict) -> tuple:
    """The filter's words for the labels (``"6.0 Hz"``, or ``"filter off"``) and, when off,
    the verdict of every filtered target (else None)."""
    if not record.get("applied"):
        return "filter off", f"not measured (filter off: {record.get('reason', '?')})"
    return f"{record['cutoff_hz']} Hz", None


def _per_marker(lm, hidden):
    """Per moving LSMTA marker: its views, 3-D share, the frames one view (or none) holds
    it, the frames two or more hold it but the residual gate dropped it, and of the first
    the frames the image test calls hidden (``hidden``, (T, M) bool)."""
    out = []
    for j in np.flatnonzero(lm.moving):
        views = np.isfinite(lm.xy[:, :, j]).all(axis=2)            # (T, K) views holding it
        in3d = np.isfinite(lm.xyz[:, j]).all(axis=1)
        out.append({
            "marker": int(j), "views": lm.members[j].tolist(),
            "share_3d": float(np.isfinite(lm.xyz[:, j]).all(axis=1).mean()),
            "frames_one_view": int((views.sum(axis=1) == 1).sum()),
            "frames_no_view": int((views.sum(axis=1) == 0).sum()),
            "frames_gated": int(((views.sum(axis=1) >= 2) & ~in3d).sum()),
            "frames_hidden_image_test": np.flatnonzero(hidden[:, j]).tolist(),
            "share_3d_without_hidden": float(in3d.sum() / max(1, (~hidden[:, j]).sum())),
            "median_xyz_mm": np.round(np.nanmedian(lm.xyz[:, j], axis=0)).tolist()})
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--frames", default="0:100")
    parser.add_argument("--out", default="build/benchmarks/capture_demo")
    parser.add_argument("--reuse", action="store_true",
                        help="reuse <out>/capture of an earlier run (its cameras) and run "
                             "only the marker comparison")
    parser.add_argument("--plain", action="store_true",
                        help="track the markers without following them on their blobs")
    args = parser.parse_args(argv)
    out = Path(args.out)
    videos = [str(v) for v in POSE2SIM_VIDEOS]
    seconds, summary, readback = _command(args, out, videos)
    runs, cpu, hidden = _trackers(args, out, videos)
    scores = _scores(runs, cpu)
    pair = scores["LSMTA"]["pair"]
    L, K = scores["LSMTA"], scores["KLT"]
    ratios = {k: L[k] / K[k] for k in ("residual_px", "pair_std_mm", "pair_std_filtered_mm",
                                       "cpu_seconds")}
    hz, off = _filtered(L["filter"])
    lm = runs["LSMTA"]
    per_marker = _per_marker(lm, hidden)
    without = min((m["share_3d_without_hidden"] for m in per_marker), default=np.nan)
    verdicts = {
        "command under 5 minutes": ("not run (--reuse)" if seconds is None
                                    else verdict(seconds < 300)),
        "every moving marker in 3-D in >= 90 % of the frames": verdict(L["share_min"] >= 0.9),
        ("NOT the target, for the lead: every moving marker in 3-D in >= 90 % of the frames "
         "left when those the image test calls hidden (one view holds it, no other view "
         "shows a dot where it can be) are left out"): verdict(without >= 0.9),
        "rigid pair std <= 3 mm (raw intersections)": verdict(L["pair_std_mm"] <= 3.0),
        f"rigid pair std <= 3 mm (filtered, {hz}: the files' positions)": off or verdict(
            L["pair_std_filtered_mm"] <= 3.0),
        "LSMTA at or below KLT on residual and spread (raw; same markers and pair)": (
            "not measured (no rigid pair)" if pair is None else verdict(
                L["residual_px"] <= K["residual_px"] and L["pair_std_mm"] <= K["pair_std_mm"])),
        f"LSMTA at or below KLT on residual (raw) and spread (filtered, {hz})": off or (
            "not measured (no rigid pair)" if pair is None else verdict(
                L["residual_px"] <= K["residual_px"]
                and L["pair_std_filtered_mm"] <= K["pair_std_filtered_mm"]))}
    pair_info = None if pair is None else {
        "markers": pair, "views": [lm.members[j].tolist() for j in pair],
        "median_height_mm": [float(np.nanmedian(lm.xyz[:, j, 2])) for j in pair]}
    record = {"command_seconds": seconds, "scale": args.scale, "frames": args.frames,
              "plain": args.plain, "reused_capture": args.reuse,
              "cameras_note": summary.get("cameras_note"), "stages": summary["stages"],
              "readback": readback, "markers": scores, "rigid_pair": pair_info,
              "per_marker_lsmta": per_marker,
              "least_share_without_hidden_lsmta": without, "pairs_lsmta": moving_pairs(lm),
              "ratios_lsmta_over_klt": ratios, "verdicts": verdicts}
    write_json(out / "experiment.json", record)
    print(json.dumps(record, indent=1, default=str))
    for name in ("LSMTA", "KLT"):
        print(f"{name}: rigid pair {pair} distance std {scores[name]['pair_std_mm']:.2f} mm raw, "
              f"{scores[name]['pair_std_filtered_mm']:.2f} mm filtered ({hz})")
    for target, v in verdicts.items():
        print(f"target {target}: {v}")


if __name__ == "__main__":
    main()
