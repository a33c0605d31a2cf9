"""Where LSMTA's tracking time goes, per point-frame, beside KLT's total (issue #35).

    .venv/bin/python experiments/tracking_profile.py [--frames 20] [--points 384]
        [--videos caliscope pose2sim] [--pose2sim-scale 0.5]

The real-video comparison of ``real_video_tracking.py`` (2-D mode, every video tracked
forward and back from its Shi-Tomasi corners, one numba thread), with LSMTA's CPU time
(``time.process_time``: this process, every thread) split by what it was spent on. Each
stage is timed *exclusively* (a stage called inside another counts for itself, not for
its caller), so the rows add up to the total:

- ``inverse compositional LSM``: the compiled iterations of the anchored templates;
- ``forward LSM``: the compiled forward additive LSM (retries, partial patches);
- ``spline prefilter``: B-spline coefficients of every image the tracker interpolates
  (each frame, each pyramid level, the forward LSM's stacked templates);
- ``pyramid (pyrDown, float32)``: building the coarse-to-fine levels, besides their
  prefilter;
- ``coarse-to-fine translation``: the compiled translation matches on the levels;
- ``correlation search``: the box search (OpenCV ``matchTemplate`` per track);
- ``template sampling``: the compiled spline sampling, normal matrices and their
  inverses of new templates;
- ``quality checks``: :meth:`~lsmta.matching.LSMThresholds.apply` (the thresholds);
- ``Python and NumPy orchestration``: everything else (the per-frame bookkeeping,
  selections, results).

A point-frame is one start point tracked over one frame step (forward or back), whether or
not it survived: the same count for both trackers. Writes
``build/benchmarks/tracking_profile.json``.
"""

from __future__ import annotations

import argparse
import importlib
import time
from collections import Counter

import cv2
import numba
from real_video_tracking import clips_and_tracker, forward_backward, klt_end

from lsmta.report import write_json

#: (module, attribute, stage): the functions timed; a class attribute as "Class.method"
STAGES = [
    ("lsmta.tracking.templates", "_solve", "inverse compositional LSM"),
    ("lsmta.matching._solver", "solve", "forward LSM"),
    ("lsmta.matching._kernels", "prefilter", "spline prefilter"),
    ("lsmta.tracking.points", "_Pyramids.get", "pyramid (pyrDown, float32)"),
    ("lsmta.tracking.templates", "_solve_translation", "coarse-to-fine translation"),
    ("lsmta.matching.correlation", "_search", "correlation search"),
    ("lsmta.matching._kernels", "sample", "template sampling"),
    ("lsmta.tracking.templates", "_normals", "template sampling"),
    ("lsmta.tracking.templates", "_inverses", "template sampling"),
    ("lsmta.matching.lsm", "LSMThresholds.apply", "quality checks"),
]
REST = "Python and NumPy orchestration"


class StageClock:
    """Exclusive CPU time per stage: a stage's time less that of the stages it calls."""

    def __init__(self):
        self.seconds, self.calls, self._stack = Counter(), Counter(), []

    def wrap(self, fn, stage):
        def timed(*args, **kwargs):
            self._stack.append(0.0)                 # time of the stages called inside
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                dt = time.process_time() - t0
                inner = self._stack.pop()
                self.seconds[stage] += dt - inner
                self.calls[stage] += 1
                if self._stack:
                    self._stack[-1] += dt
        return timed

    def install(self):
        """Replace the timed functions (in their modules, for the rest of the process)."""
        for module, name, stage in STAGES:
            owner = importlib.import_module(module)
            *path, attr = name.split(".")
            for part in path:
                owner = getattr(owner, part)
            setattr(owner, attr, self.wrap(getattr(owner, attr), stage))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--points", type=int, default=384)
    parser.add_argument("--pose2sim-scale", type=float, default=0.5)
    parser.add_argument("--videos", nargs="+", default=["caliscope"],
                        choices=["caliscope", "pose2sim"])
    parser.add_argument("--out", default="build/benchmarks/tracking_profile.json")
    args = parser.parse_args(argv)
    numba.set_num_threads(1)
    clips, lsmta = clips_and_tracker(args.videos, args.frames, args.pose2sim_scale)
    clock = StageClock()
    clock.install()
    cpu = {"lsmta": 0.0, "klt": 0.0}
    point_frames = 0
    for _, seq in clips:
        start = cv2.goodFeaturesToTrack(seq[0], args.points, 0.01, 8, blockSize=7)[:, 0]
        start = start.astype(float)
        point_frames += 2 * len(start) * (len(seq) - 1)
        c0 = time.process_time()
        before = sum(clock.seconds.values())
        forward_backward(lsmta, seq, start)
        dt = time.process_time() - c0
        cpu["lsmta"] += dt
        clock.seconds[REST] += dt - (sum(clock.seconds.values()) - before)
        cpu["klt"] += forward_backward(klt_end, seq, start)[3]
    us = {k: 1e6 * v / point_frames for k, v in cpu.items()}
    print(f"{len(clips)} videos, {point_frames} point-frames (forward and back): LSMTA "
          f"{us['lsmta']:.1f} us CPU per point-frame, KLT {us['klt']:.1f} "
          f"(x{cpu['lsmta'] / cpu['klt']:.2f})")
    rows = []
    for stage, s in clock.seconds.most_common():
        rows.append({"stage": stage, "cpu_s": s, "us_per_point_frame": 1e6 * s / point_frames,
                     "share": s / cpu["lsmta"], "calls": clock.calls[stage]})
        calls = f", {clock.calls[stage]} calls" if stage != REST else ""
        print(f"  {stage:32s} {rows[-1]['us_per_point_frame']:6.1f} us "
              f"({100 * rows[-1]['share']:4.1f} %){calls}")
    write_json(args.out, {"args": vars(args), "point_frames": point_frames,
                          "cpu_s": cpu, "us_per_point_frame": us, "stages": rows})


if __name__ == "__main__":
    main()
