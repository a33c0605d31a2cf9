"""Multi-camera calibration: our joint bar adjustment against the no-bar-then-rescale peer,
and Davis's alternation run long against the joint adjustment.

    .venv/bin/python experiments/calibration_benchmark.py [--seeds 3] [--positions 150]
        [--alternations 300] [--linear-alternations 80]

Reference bar (projected targets with Gaussian noise of 0.01 px, as measured in the
rendered images of notebook 01): per seed, the image RMS residual against sigma*sqrt(1-p/n),
held-out bar length error and 3-D check-point error for ours, the no-bar-then-rescale peer
and (if installed) aniposelib's ``CameraGroup.bundle_adjust_iter`` from the same
approximations, their ratios peer / ours, and the wall times with the ratios peer / ours.
``--alternations 0`` skips the virtual calibration object, ``--no-bar`` the reference bar;
``--intrinsics f --true-fixed`` frees only the principal distance of the ring cameras (the
rest held at the truth), a diagnostic of why the alternation creeps.
Virtual calibration object:
per seed of the initial guess, the alternation (reprojection-optimal point step: block-
coordinate descent on the joint objective) run for ``--alternations`` iterations, Davis's
linear-intersection variant for ``--linear-alternations``, and the joint adjustment: final
projection errors on the independent path and fit errors on the calibration path (the
objective), their ratios to the joint optimum, the iterations each alternation needs to
come within 1 % of the joint optimum (None: not within the run), and whether it ends there.
The improved alternation (exterior-only sweeps first, joint steps every four sweeps) runs
beside them, and ``--partial-seeds`` seeds of the long room whose cameras see only parts of
the path (chain, datum from a 4 m distance; plain, improved and joint from the chain): the
joint adjustment against the true-camera floor, the improved alternation's iterations to
within 1 % of the joint optimum, 3-D and scale errors, and the wall times.
Writes build/benchmarks/calibration.json.

Real rigs (issue 24; ``--only-real-rigs`` runs just this part): caliscope's real four-camera
ChArUco recording (data/caliscope_4cam) calibrated by us (everything from the recording;
and poses only with caliscope's interior orientation), by caliscope (its file) and by
aniposelib's ``bundle_adjust_iter`` from our approximations: reprojection RMS per camera,
board-corner distance errors on all frames and on held-out (odd) frames, camera position
differences, wall times; and ``calibrate_wand`` on generated wand recordings (25 frames,
each seen by 2-3 of 4 cameras) per seed: wand length scatter against the floor of the true
cameras. Writes build/benchmarks/calibration_real_rigs.json, which notebook 19 quotes.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lsmta.calibration import IMPROVED_ALTERNATION, Bar, relative_orientation_start
from lsmta.calibration.board import calibrate_board
from lsmta.evaluation.calibration import (
    aniposelib_peer,
    bar_trial,
    partial_overlap_trial,
    ring_trial,
)
from lsmta.evaluation.wand import wand_trial
from lsmta.real.board import (
    aniposelib_board_peer,
    board_scores,
    caliscope_comparison,
    position_differences,
)
from lsmta.report import write_json
from lsmta.synth.rigs import triplet_rig


def rms(a):
    return float(np.sqrt(np.nanmean(np.asarray(a) ** 2)))


def _scores(s):
    return dict(rms_px=s.rms_px.tolist(), distance_rms_mm=s.distance_rms,
                distance_rms_percent=s.distance_rms_percent,
                distance_max_abs_mm=float(np.abs(s.distance_error).max()))


def real_rigs(seeds: int, out: str):
    """Caliscope's recording by us, caliscope and aniposelib; generated wand recordings."""
    t0 = time.perf_counter()
    comp = caliscope_comparison()
    seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    calibrate_board(comp.points.xy, comp.points.board, [c.image_size for c in comp.caliscope],
                    names=[c.name for c in comp.caliscope])
    ours_s = time.perf_counter() - t0
    board = dict(file_error_px=comp.file_error_px.tolist(), time_ours_s=ours_s,
                 time_comparison_s=seconds,
                 centre_difference_mm=comp.centre_difference.tolist(),
                 attitude_difference_deg=comp.attitude_difference.tolist(),
                 **{f"{k}_all": _scores(v) for k, v in comp.scores.items()},
                 **{f"{k}_heldout": _scores(v) for k, v in comp.heldout.items()})
    try:
        odd = np.arange(1, comp.points.xy.shape[1], 2)
        even = np.arange(0, comp.points.xy.shape[1], 2)
        cams, sec = aniposelib_board_peer(comp.points, comp.ours.start)
        half = calibrate_board(comp.points.xy[:, even], comp.points.board,
                               [c.image_size for c in comp.caliscope])
        cams_h, _ = aniposelib_board_peer(comp.points, half.start, frames=even)
        dist, ang = position_differences(cams, comp.caliscope)
        board.update(aniposelib_all=_scores(board_scores(cams, comp.points)),
                     aniposelib_heldout=_scores(board_scores(cams_h, comp.points, frames=odd)),
                     aniposelib_centre_difference_mm=dist.tolist(),
                     aniposelib_attitude_difference_deg=ang.tolist(),
                     time_aniposelib_s=sec, time_ratio_aniposelib_over_ours=sec / ours_s)
    except ImportError as err:
        print(f"aniposelib peer skipped: {err}")
        board["aniposelib_skipped"] = str(err)
    for key in ("ours", "ours_fixed", "aniposelib"):
        if f"{key}_all" in board:
            board[f"distance_ratio_{key}_over_caliscope_all"] = (
                board[f"{key}_all"]["distance_rms_mm"]
                / board["caliscope_all"]["distance_rms_mm"])
            board[f"distance_ratio_{key}_over_caliscope_heldout"] = (
                board[f"{key}_heldout"]["distance_rms_mm"]
                / board["caliscope_heldout"]["distance_rms_mm"])
    print(board)
    wand = []
    for s in range(seeds):
        t = wand_trial(seed=s)
        wand.append(dict(seed=s, std_percent=t.result.wand_length_std_percent,
                         floor_percent=t.floor_std_percent,
                         heldout_rms_percent=rms(t.heldout_error_percent),
                         centre_error_max_mm=float(t.centre_error.max()),
                         focal_error_max_percent=float(np.abs(t.focal_error_percent).max()),
                         labels_consistent=t.labels_consistent, seconds=t.result.seconds,
                         status=t.result.status.name))
        print(wand[-1])
    write_json(out, dict(caliscope=board, wand=wand))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--positions", type=int, default=150)
    parser.add_argument("--alternations", type=int, default=300)
    parser.add_argument("--linear-alternations", type=int, default=80)
    parser.add_argument("--intrinsics", default="f,cx,cy,k1,k2",
                        help="free interior parameters of the ring cameras (comma-separated)")
    parser.add_argument("--true-fixed", action="store_true",
                        help="hold the other interior parameters at the truth (diagnostic)")
    parser.add_argument("--no-bar", action="store_true",
                        help="only the virtual calibration object")
    parser.add_argument("--partial-seeds", type=int, default=3,
                        help="seeds of the partial-overlap room (0: skip)")
    parser.add_argument("--out", default="build/benchmarks/calibration.json")
    parser.add_argument("--real-out", default="build/benchmarks/calibration_real_rigs.json")
    parser.add_argument("--only-real-rigs", action="store_true",
                        help="only the real-rig part (caliscope recording, wand recordings)")
    args = parser.parse_args(argv)
    real_rigs(max(args.seeds, 5), args.real_out)
    if args.only_real_rigs:
        return

    bar = []
    for s in range(0 if args.no_bar else args.seeds):
        t = bar_trial(seed=s, n_positions=args.positions, n_heldout=40, mode="projected",
                      sigma_px=0.01)
        row = dict(seed=s, rms_over_limit=t.ours.rms / t.ours.noise_limit,
                   bar_rms_mm=rms(t.bar_error), peer_bar_rms_mm=rms(t.peer_bar_error),
                   check_rms_mm=rms(t.check_error), peer_check_rms_mm=rms(t.peer_check_error),
                   time_ours_s=t.times["ours"], time_peer_s=t.times["peer"])
        row["bar_ratio_peer_over_ours"] = row["peer_bar_rms_mm"] / row["bar_rms_mm"]
        row["check_ratio_peer_over_ours"] = row["peer_check_rms_mm"] / row["check_rms_mm"]
        row["time_ratio_peer_over_ours"] = row["time_peer_s"] / row["time_ours_s"]
        try:
            bar_ = Bar(np.arange(t.xy.shape[1]).reshape(-1, 2), t.track.length)
            c0, _ = relative_orientation_start(triplet_rig(), t.xy, bar=bar_, pair=(0, 2))
            _, be, ce, sec = aniposelib_peer(t, c0)
            row.update(aniposelib_bar_rms_mm=rms(be), aniposelib_check_rms_mm=rms(ce),
                       time_aniposelib_s=sec,
                       bar_ratio_aniposelib_over_ours=rms(be) / row["bar_rms_mm"],
                       check_ratio_aniposelib_over_ours=rms(ce) / row["check_rms_mm"],
                       time_ratio_aniposelib_over_ours=sec / row["time_ours_s"])
        except ImportError as err:
            print(f"aniposelib peer skipped: {err}")
        bar.append(row)
        print(row)

    if args.alternations == 0:
        write_json(args.out, dict(bar=bar))
        return
    ring = ring_trial(seeds=tuple(range(args.seeds)), n_cameras=8, n_path=150, n_check=80,
                      n_alternation=args.alternations, n_joint=30,
                      n_linear=args.linear_alternations, improved=IMPROVED_ALTERNATION,
                      intrinsics=tuple(args.intrinsics.split(",")), true_fixed=args.true_fixed)
    virt = []
    for s, (a, j) in enumerate(zip(ring.alternation, ring.joint)):
        row = dict(seed=s, joint_final_px=float(j.error[-1]),
                   joint_fit_px=float(j.fit_error[-1]),
                   joint_iterations_to_1pct=j.iterations_to(tolerance=0.01))
        variants = [("alternation", a), ("improved_alternation", ring.improved[s])]
        if ring.linear:
            variants.append(("linear_alternation", ring.linear[s]))
        for name, h in variants:
            row.update({
                f"{name}_iterations": len(h.error) - 1,
                f"{name}_final_px": float(h.error[-1]),
                f"{name}_fit_px": float(h.fit_error[-1]),
                f"{name}_final_over_joint": float(h.error[-1] / j.error[-1]),
                f"{name}_fit_over_joint": float(h.fit_error[-1] / j.fit_error[-1]),
                # iterations until the score (independent path) / the objective (calibration
                # path) is within 1 % of the joint adjustment's optimum; None: never
                f"{name}_iterations_to_1pct_of_joint": h.iterations_to_value(j.error[-1]),
                f"{name}_fit_iterations_to_1pct_of_joint":
                    h.iterations_to_value(j.fit_error[-1], fit=True),
                f"{name}_same_optimum_within_1pct": bool(abs(h.error[-1] / j.error[-1] - 1)
                                                         < 0.01),
                f"{name}_fit_monotone": bool(np.all(np.diff(h.fit_error) <= 1e-12))})
        virt.append(row)
        print(row)
    partial = []
    for r in partial_overlap_trial(seeds=tuple(range(args.partial_seeds)), n_plain=50):
        opt = r.joint.fit_error[-1]
        row = dict(seed=r.seed, joint_over_floor=float(r.joint.error[-1] / r.floor),
                   improved_iterations_to_1pct=r.improved.iterations_to_value(opt, fit=True),
                   plain_fit_over_joint_after_50=float(r.plain.fit_error[-1] / opt),
                   error_3d_mm=r.error_3d, scale_error_mm=r.scale_error,
                   seconds={k: getattr(r, k).seconds for k in ("plain", "improved", "joint")})
        partial.append(row)
        print(row)
    write_json(args.out, dict(bar=bar, virtual_object=virt, floor_px=ring.truth_error,
                              partial_overlap=partial))


if __name__ == "__main__":
    main()
