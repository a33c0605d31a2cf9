"""Controlled studies: the generator (:mod:`lsmta.synth`) and the library joined. Each trial
makes data with a known truth, runs the library (and its peers) on what a user would have
(images, centroids, marker clouds), and compares the results with the truth only after the
fact. Apart from ``lsmta.synth`` itself, the only package that imports the generator;
notebooks and experiments are built from it. Studies of real recordings, which have no
generator behind them, are in :mod:`lsmta.real`.
"""
