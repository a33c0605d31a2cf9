"""Evaluation harnesses: generate data with ground truth, run the library (and its peers) on
it, and score the results. The only package besides ``lsmta.synth`` that may import the
generator; notebooks and experiments are built from it."""
