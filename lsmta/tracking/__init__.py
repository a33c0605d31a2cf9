"""Tracking in image space. Built: small-scale marker tracking in video (``markers``);
LSMTA tracking and 3-D trajectories are planned."""
