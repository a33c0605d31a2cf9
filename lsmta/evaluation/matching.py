"""Matching trials: generated image pairs, every method on the same patches, scored against truth.

A trial draws patch centres on a :class:`~lsmta.synth.patches.WarpedPair`, starts every
method from the same perturbed positions, and keeps each method's error vectors and run
time, plus the Cramér-Rao covariance of the LSM parameter set from the noise-free images.
Notebook 02 and ``experiments/lsm_benchmark.py`` are built from these trials.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .._validate import as_rng
from ..matching import LSMParams, lsm, peers
from ..matching.bounds import cramer_rao_xy, patch_offsets
from ..synth.patches import WarpedPair

#: method name -> (callable(template, search, template_xy, search_xy, params) -> result);
#: LSM runs with the trial's :class:`~lsmta.matching.LSMParams`, the peers with its patch
METHODS = {
    "lsm": lambda f, g, t, s, p: lsm(f, g, t, s, params=p),
    "lsm_inverse": lambda f, g, t, s, p: lsm(f, g, t, s, params=replace(p, method="inverse")),
    "ecc_affine": lambda f, g, t, s, p: peers.ecc(f, g, t, s, patch=p.patch),
    "ecc_translation": lambda f, g, t, s, p: peers.ecc(f, g, t, s, patch=p.patch,
                                                       motion="translation"),
    "klt": lambda f, g, t, s, p: peers.klt(f, g, t, s, patch=p.patch),
    "phase_correlation": lambda f, g, t, s, p: peers.phase_correlation(f, g, t, s,
                                                                       patch=p.patch),
    "ilk": lambda f, g, t, s, p: peers.ilk(f, g, t, s, patch=p.patch),
}


@dataclass
class MatchTrial:
    """Errors of several methods on the same patches.

    Attributes
    ----------
    truth : (N, 2) array
        True positions in the search image.
    start : (N, 2) array
        Common starting positions.
    errors : dict
        Method name -> (N, 2) error vectors (NaN where the method gave no result or LSM
        did not converge).
    seconds : dict
        Method name -> wall time of the whole batch.
    crb : (N, 2, 2) array or None
        Cramér-Rao covariance of the position for LSM's parameter set.
    lsm_result : LSMResult or None
        The result of the (last) LSM variant run.
    """

    truth: np.ndarray
    start: np.ndarray
    errors: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    crb: np.ndarray | None = None
    lsm_result: object = None

    def summary(self, method: str, *, fail_px: float = 0.5) -> dict:
        """Median and RMS error (px), failure rate (no result or error > ``fail_px``),
        and time per point (µs)."""
        e = np.linalg.norm(self.errors[method], axis=1)
        good = e <= fail_px
        return {
            "median_px": float(np.median(e[good])) if good.any() else float("nan"),
            "rms_px": float(np.sqrt(np.mean(e[good] ** 2))) if good.any() else float("nan"),
            "failure_rate": float(1 - good.mean()),
            "us_per_point": 1e6 * self.seconds[method] / len(e),
        }

    def crb_median(self, *, mask=None, rng: np.random.Generator | int | None = None) -> float:
        """Median error that the Cramér-Rao covariance predicts (by drawing from it)."""
        rng = as_rng(rng)
        cov = self.crb if mask is None else self.crb[mask]
        draws = np.einsum("nij,nkj->nki", np.linalg.cholesky(cov),
                          rng.normal(size=(len(cov), 50, 2)))
        return float(np.median(np.linalg.norm(draws, axis=2)))


def random_starts(truth, *, rng: np.random.Generator | int | None = None, start_error=0.5,
                  start_distance=None):
    """Starts uniform in a square of half-width ``start_error`` around the truth, or at
    exactly ``start_distance`` pixels in a random direction."""
    rng = as_rng(rng)
    if start_distance is None:
        return truth + rng.uniform(-start_error, start_error, truth.shape)
    angle = rng.uniform(0, 2 * np.pi, len(truth))
    return truth + start_distance * np.stack([np.cos(angle), np.sin(angle)], axis=1)


def draw_points(shape, n_points: int, *, margin: int = 30,
                rng: np.random.Generator | int | None = None) -> np.ndarray:
    """Whole-pixel patch centres ``(n, 2)`` at least ``margin`` pixels inside ``shape``."""
    rng = as_rng(rng)
    H, W = shape
    return np.rint(rng.uniform(margin, [W - 1 - margin, H - 1 - margin], (n_points, 2)))


def unit_bound(pair: WarpedPair, points, *, patch: int, geometry: str, radiometry: str):
    """Cramér-Rao covariance ``(N, 2, 2)`` for noise 1 grey level (it scales with sigma²)."""
    truth = pair.true_xy(points)
    U = patch_offsets(patch)
    g, gx, gy = pair.clean_search(truth[:, None, :] + U @ pair.A.T, gradient=True)
    return cramer_rao_xy(g, gx, gy, patch=patch, r1=pair.r1, noise_sigma=1.0,
                         geometry=geometry, radiometry=radiometry)


def run_trial(pair: WarpedPair, *, rng: np.random.Generator | int | None = None, methods=("lsm",),
              n_points: int = 200, start_error: float = 0.5,
              start_distance: float | None = None, margin: int = 30, bound: bool = True,
              points=None, bound_unit=None, params: LSMParams | None = None) -> MatchTrial:
    """Run ``methods`` on ``n_points`` whole-pixel patch centres of ``pair``.

    Parameters
    ----------
    pair : WarpedPair
    rng : numpy.random.Generator, int or None
        Draws the points and the starts.
    methods : sequence of str
        Keys of :data:`METHODS`.
    bound : bool
        Compute the Cramér-Rao covariance (needs the noise-free images' gradients).
    points : (N, 2) array, optional
        Patch centres to use instead of drawing ``n_points``.
    bound_unit : (N, 2, 2) array, optional
        :func:`unit_bound` for these points, to save recomputing it.
    params : LSMParams, optional
        LSM's settings (default :class:`~lsmta.matching.LSMParams`); its ``patch`` serves
        the peers too, and its ``patch``, ``geometry`` and ``radiometry`` the bound.
    """
    p = LSMParams() if params is None else params
    patch, geometry, radiometry = p.patch, p.geometry, p.radiometry
    rng = as_rng(rng)
    if points is None:
        pts = draw_points(pair.template.shape, n_points, margin=margin, rng=rng)
    else:
        pts = points
    truth = pair.true_xy(pts)
    start = random_starts(truth, rng=rng, start_error=start_error, start_distance=start_distance)
    trial = MatchTrial(truth=truth, start=start)
    for name in methods:
        ours = name.startswith("lsm")
        t0 = time.perf_counter()
        res = METHODS[name](pair.template, pair.search, pts, start, p)
        trial.seconds[name] = time.perf_counter() - t0
        trial.errors[name] = np.where(res.ok[:, None], res.xy - truth, np.nan)
        if ours:
            trial.lsm_result = res
    if bound and pair.noise_sigma > 0:
        if bound_unit is None:
            bound_unit = unit_bound(pair, pts, patch=patch, geometry=geometry,
                                    radiometry=radiometry)
        trial.crb = pair.noise_sigma**2 * bound_unit
    return trial


def noise_sweep(pair: WarpedPair, sigmas, *, rng: np.random.Generator | int | None = None,
                patch: int = 13, geometry: str = "affine", radiometry: str = "linear",
                n_points: int = 200, start_error: float = 0.5) -> dict:
    """LSM against its Cramér-Rao bound over noise levels, on fresh noise of one clean pair.

    Returns a dict of arrays over ``sigmas``: ``median_px`` (LSM's median error),
    ``bound_median_px`` (the bound's), ``error_ratio`` (their ratio; 1: at the bound),
    ``rms_ratio`` and ``coverage_95`` (:func:`honesty`), ``failure_rate``. Both medians are
    taken over the same points, those LSM matched to within 0.5 px; ``failure_rate`` is the
    share of the others (no result, or farther off), which the error ratio leaves out.
    """
    rng = as_rng(rng)
    pts = draw_points(pair.template.shape, n_points, rng=rng)
    unit = unit_bound(pair, pts, patch=patch, geometry=geometry, radiometry=radiometry)
    keys = ("median_px", "bound_median_px", "error_ratio", "rms_ratio", "coverage_95",
            "failure_rate")
    out = {k: [] for k in keys}
    for sigma in sigmas:
        trial = run_trial(pair.noisy(sigma, rng=rng), rng=rng, points=pts, bound_unit=unit,
                          start_error=start_error, params=LSMParams(
                              patch=patch, geometry=geometry, radiometry=radiometry))
        summ = trial.summary("lsm")
        out["median_px"].append(summ["median_px"])
        out["failure_rate"].append(summ["failure_rate"])
        if sigma > 0:
            good = np.linalg.norm(trial.errors["lsm"], axis=1) <= 0.5   # as summary()'s
            out["bound_median_px"].append(trial.crb_median(mask=good, rng=rng))
            h = honesty(trial)
            out["rms_ratio"].append(h["rms_ratio"])
            out["coverage_95"].append(h["coverage_95"])
        else:
            for k in ("bound_median_px", "rms_ratio", "coverage_95"):
                out[k].append(np.nan)
        out["error_ratio"].append(out["median_px"][-1] / out["bound_median_px"][-1])
    return {"sigma": np.asarray(sigmas, float), **{k: np.asarray(v) for k, v in out.items()}}


def honesty(trial: MatchTrial) -> dict:
    """Is LSM's own precision estimate right? RMS actual / RMS predicted error, and the
    share of true positions inside LSM's 95 % error ellipse (chi-square, 2 dof: 5.991)."""
    res = trial.lsm_result
    ok = res.ok & np.isfinite(res.sigma_xy).all(axis=1)
    e = trial.errors["lsm"][ok]
    cov = res.cov_xy[ok]
    m2 = np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov), e)
    return {
        "rms_ratio": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))
                           / np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2)))),
        "coverage_95": float(np.mean(m2 <= 5.991)),
    }


def success_rate(pair: WarpedPair, *, rng: np.random.Generator | int | None = None,
                 start_distance: float, patch: int = 13, geometry: str = "affine",
                 radiometry: str = "linear", n_points: int = 200, tol_px: float = 0.1,
                 margin: int = 30) -> float:
    """Share of points where LSM converges to within ``tol_px`` of the truth when started
    ``start_distance`` pixels away (random direction): the pull-in range's test."""
    rng = as_rng(rng)
    trial = run_trial(pair, rng=rng, n_points=n_points, start_distance=start_distance,
                      bound=False, margin=margin, params=LSMParams(
                          patch=patch, geometry=geometry, radiometry=radiometry))
    e = np.linalg.norm(trial.errors["lsm"], axis=1)
    return float(np.mean(e <= tol_px))
