"""Studies of real recordings: the library run on data a camera or a motion-capture system
recorded, scored against peers (other tools on the same data) and against published or
surveyed values (a board's known geometry, Middlebury's disparity truth, a recording's own
labels), never against a generator.

* :mod:`lsmta.real.board` — caliscope's board recording: our calibration, caliscope's and
  aniposelib's, scored on the same corners (notebook 19);
* :mod:`lsmta.real.board_video` — the same recording from its videos: ChArUco corners
  against caliscope's, calibration, LSMTA and KLT tracking, the board in 3-D (notebook 19);
* :mod:`lsmta.real.stereo` — the Middlebury measures of a disparity map (notebook 16);
* :mod:`lsmta.real.marker_captures` — SAPM on real marker captures: the recordings' marker
  sets, models learned from a training clip, later frames labelled (notebooks 08, 18);
* :mod:`lsmta.real.pose2sim_video` — tracking in the Pose2Sim demo's four real videos and
  the readings of its calibration, judged without truth (notebook 17).

The recordings themselves are loaded by :mod:`lsmta.data`. These modules import neither
:mod:`lsmta.synth` nor :mod:`lsmta.evaluation` (a test checks it).
"""
