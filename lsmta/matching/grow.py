"""Dense matching by region growing from seed points (D'Apuzzo 1998; LSMTA paper, Section 2.2).

The template's area is split into the Voronoi cells of the seeds. Starting from each seed,
the matcher steps to neighbouring nodes of a regular grid (spacing ``step`` pixels),
horizontally first and then vertically, and runs least squares matching there, starting
from the neighbour's solution: the approximation is the neighbour's match moved by its
affine matrix, ``search = parent_search + A_parent (node - parent_node)``, and the start
of ``A`` is ``A_parent``. A match is kept when it passes the quality thresholds; otherwise
it is tried once more with a bigger patch. Growth stays inside each seed's cell; when no
cell can grow any more, holes are closed by growing into the remaining nodes from every
side, across cell borders.

Batched: each growth step sends the whole front (all candidate nodes of all cells) through
one :func:`~lsmta.matching.lsm` call, so the number of calls grows with the width of the
region in grid steps, not with the number of points.

Choices where the paper is vague: the retry changes the patch size only (a smaller step
would leave the grid); a node may be tried up to ``max_attempts`` times from different
neighbours; nodes whose patch does not fit or whose template patch has no texture are
never tried.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, check_patch
from .lsm import LSMThresholds, Status, _check_robust, lsm
from .spline import SplineImage

HORIZONTAL = ((1, 0), (-1, 0))
VERTICAL = ((0, 1), (0, -1))
METHODS = ("patch", "retry", "robust", "shifted")


@dataclass(frozen=True)
class GrowResult:
    """Matches grown from seeds.

    Attributes
    ----------
    template_xy : (N, 2) array
        Matched grid nodes in the template (pixels).
    search_xy : (N, 2) array
        Their matches in the search image (pixels).
    A : (N, 2, 2) array
        Affine matrices of the matches.
    sigma0 : (N,) array
        A-posteriori standard deviation of unit weight (grey levels).
    sigma_xy : (N, 2) array
        Standard deviations of ``search_xy`` (pixels).
    seed : (N,) int array
        The seed whose Voronoi cell holds the node.
    wave : (N,) int array
        Growth step in which the node was matched (0: the seeds' own nodes); the phase of
        hole closing continues the count.
    hole_closing : (N,) bool array
        Matched while closing holes (across cell borders).
    seeds_matched : (S,) bool array
        Which seeds LSM could match (the others are reported, not grown from).
    n_lsm : int
        Number of points sent to LSM in all (attempts, including retries).
    grid_shape : (int, int)
        Rows and columns of the node grid; node ``(r, c)`` lies at ``(c * step, r * step)``.
    node_index : (N, 2) int array
        Grid row and column of each match.
    method : (N,) str array
        Which attempt matched the node: ``"patch"`` (the main patch), ``"retry"`` (a retry
        patch size), ``"robust"`` or ``"shifted"``.
    """

    template_xy: np.ndarray
    search_xy: np.ndarray
    A: np.ndarray
    sigma0: np.ndarray
    sigma_xy: np.ndarray
    seed: np.ndarray
    wave: np.ndarray
    hole_closing: np.ndarray
    seeds_matched: np.ndarray
    n_lsm: int
    grid_shape: tuple
    node_index: np.ndarray
    method: np.ndarray

    def __len__(self) -> int:
        return len(self.template_xy)


def voronoi_cells(seeds_xy: np.ndarray, nodes_xy: np.ndarray) -> np.ndarray:
    """Index of the nearest seed for every node (the seeds' Voronoi cells)."""
    from scipy.spatial import cKDTree

    return cKDTree(seeds_xy).query(nodes_xy)[1]


def grow_matches(template, search, seeds_template, seeds_search, *, step: int = 4,
                 patch: int = 13, retry_patch: int | None = None,
                 thresholds: LSMThresholds | None = None, mask=None,
                 geometry: str = "affine", radiometry: str = "linear", max_attempts: int = 3,
                 min_texture: float = 2.0, close_holes: bool = True,
                 shift: int = 0, robust: float | None = None,
                 robust_patch: int | None = None, template_mask=None) -> GrowResult:
    """Grow dense matches between two images from a few seed correspondences.

    Parameters
    ----------
    template, search : (H, W) arrays
        Grey images (any real dtype).
    seeds_template : (S, 2) array
        Seed positions in the template (pixels).
    seeds_search : (S, 2) array
        Approximate seed positions in the search image; refined by LSM first.
    step : int
        Grid spacing in pixels.
    patch : int
        LSM patch size (odd, >= 5).
    retry_patch : int or sequence of int, optional
        Patch sizes of further attempts at a failed node, in order (default
        ``patch + 6``). A smaller patch can match closer to an occlusion border.
    thresholds : LSMThresholds, optional
        Quality indicators a match must pass (default :class:`LSMThresholds` with
        ``max_displacement = step``).
    mask : (H, W) bool array, optional
        Where in the template to grow (default: everywhere the patch fits).
    geometry, radiometry : str
        LSM model (see :func:`~lsmta.matching.lsm`).
    max_attempts : int
        How often a node may be tried from different neighbours.
    min_texture : float
        Nodes whose template patch has a grey-value standard deviation below this are
        skipped (no texture to match).
    close_holes : bool
        After growing inside the cells, grow into the remaining nodes from every side.
    shift : int
        If positive, a node that failed every patch size is tried once more with the
        ``patch`` window moved by ``shift`` pixels in each of the 8 grid directions, so
        that the window can lie on one side of an occlusion border; the node's match is
        then the shifted match carried back by its affine matrix,
        ``search = search_shifted - A (shift offset)``, from the passing window with the
        smallest ``sigma0``. 0 (default) turns this off.
    robust : float, optional
        If given, a node that failed every patch size is tried once more by robust LSM
        (Tukey cut-off ``robust`` grey levels, see :func:`~lsmta.matching.lsm`), which
        lets the pixels across an occlusion border drop out; before the shifted windows.
    robust_patch : int, optional
        Patch size of the robust attempt (default ``patch``).
    template_mask : (H, W) bool array, optional
        Template pixels on the object: every LSM ignores the others (see
        :func:`~lsmta.matching.lsm`), so a patch next to the silhouette rests on the
        object alone (a patch with less than ``thresholds.min_weight_share`` of object
        pixels is rejected). Unlike ``mask``, it does not say where to grow.

    Returns
    -------
    GrowResult
    """
    patch = check_patch(patch)
    if retry_patch is None:
        retry_patch = (patch + 6,)
    retry_patches = tuple(check_patch(p, "retry_patch") for p in np.atleast_1d(retry_patch))
    robust_patch = patch if robust_patch is None else check_patch(robust_patch, "robust_patch")
    _check_robust(robust)
    if isinstance(step, bool) or int(step) != step or step < 1:
        raise ValueError(f"step: expected a positive integer (pixels), got {step}")
    step = int(step)
    if isinstance(shift, bool) or int(shift) != shift or shift < 0:
        raise ValueError(f"shift: expected a non-negative integer (pixels), got {shift}")
    offsets = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                        if dx or dy], dtype=float) * int(shift)
    f_img = template if isinstance(template, SplineImage) else SplineImage(template, "template")
    g_img = search if isinstance(search, SplineImage) else SplineImage(search, "search")
    seeds_t = as_array(seeds_template, "seeds_template", shape=(None, 2))
    seeds_s = as_array(seeds_search, "seeds_search", shape=(None, 2))
    if len(seeds_t) != len(seeds_s):
        raise ValueError(f"seeds_search: expected {len(seeds_t)} seeds like seeds_template, "
                         f"got {len(seeds_s)}")
    if len(seeds_t) == 0:
        raise ValueError("seeds_template: expected at least one seed")
    if thresholds is None:
        thresholds = LSMThresholds(max_displacement=float(step))
    model = dict(geometry=geometry, radiometry=radiometry, template_mask=template_mask)
    H, W = f_img.shape
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (H, W) or mask.dtype != bool:
            raise ValueError(f"mask: expected a boolean array of shape {(H, W)}, got "
                             f"{mask.dtype} {mask.shape}")

    # the node grid and the nodes that can be tried at all
    rows, cols = (H - 1) // step + 1, (W - 1) // step + 1
    gr, gc = np.mgrid[0:rows, 0:cols]
    nodes = np.stack([gc * step, gr * step], axis=-1).astype(float)        # (rows, cols, 2)
    h = max((patch, robust_patch) + retry_patches) // 2
    usable = f_img.inside(nodes, margin=h)
    if mask is not None:
        usable &= mask[gr * step, gc * step]
    flat = nodes.reshape(-1, 2)
    texture = np.zeros(rows * cols)
    idx_usable = np.flatnonzero(usable.ravel())
    if idx_usable.size:
        hp = patch // 2
        yy, xx = np.mgrid[-hp:hp + 1, -hp:hp + 1]
        U = np.stack([xx.ravel(), yy.ravel()], axis=1).astype(float)
        texture[idx_usable] = f_img.patches(flat[idx_usable], U).std(axis=1)
    usable &= (texture >= min_texture).reshape(rows, cols)
    cell = voronoi_cells(seeds_t, flat).reshape(rows, cols)

    # per-node state
    state = np.zeros((rows, cols), dtype=np.int8)          # 0 open, 1 matched, 2 given up
    attempts = np.zeros((rows, cols), dtype=np.int16)
    s_xy = np.full((rows, cols, 2), np.nan)
    A_all = np.full((rows, cols, 2, 2), np.nan)
    sig0 = np.full((rows, cols), np.nan)
    sigxy = np.full((rows, cols, 2), np.nan)
    wave = np.full((rows, cols), -1)
    holes = np.zeros((rows, cols), dtype=bool)
    method = np.zeros((rows, cols), dtype=np.int8)
    n_lsm = 0

    def match(node_rc, approx, A0):
        """LSM at grid nodes, then the retry patch sizes, the robust attempt and the shifted
        windows in turn; returns the accepted mask, the results and how each was matched."""
        nonlocal n_lsm
        t_xy = nodes[node_rc[:, 0], node_rc[:, 1]]
        ok = np.zeros(len(t_xy), dtype=bool)
        xy, A = np.full((len(t_xy), 2), np.nan), np.full((len(t_xy), 2, 2), np.nan)
        s0, sxy = np.full(len(t_xy), np.nan), np.full((len(t_xy), 2), np.nan)
        how = np.zeros(len(t_xy), dtype=np.int8)

        def adopt(again, res, label, pick=None, node_xy=None):
            """Take the converged results ``res[pick]`` for the nodes ``again``."""
            pick = np.arange(len(again)) if pick is None else pick
            good = res.status[pick] == Status.CONVERGED
            take, pick = again[good], pick[good]
            ok[take] = True
            how[take] = METHODS.index(label)
            xy[take] = (res.xy if node_xy is None else node_xy)[pick]
            A[take], s0[take], sxy[take] = res.A[pick], res.sigma0[pick], res.sigma_xy[pick]

        attempts = [(patch, None, "patch")] + [(size, None, "retry") for size in retry_patches]
        if robust is not None:
            attempts.append((robust_patch, robust, "robust"))
        for size, cut, label in attempts:
            again = np.flatnonzero(~ok)
            if again.size == 0:
                break
            res = lsm(f_img, g_img, t_xy[again], approx[again], patch=size, initial_A=A0[again],
                      robust=cut, thresholds=thresholds, **model)
            n_lsm += again.size
            adopt(again, res, label)
        again = np.flatnonzero(~ok)
        if shift and again.size:
            # every failed node in every shifted window, in one call
            n_a, n_o = again.size, len(offsets)
            A0a = np.repeat(A0[again], n_o, axis=0)
            o = np.tile(offsets, (n_a, 1))
            res = lsm(f_img, g_img, np.repeat(t_xy[again], n_o, axis=0) + o,
                      np.repeat(approx[again], n_o, axis=0) + np.einsum("nij,nj->ni", A0a, o),
                      patch=patch, initial_A=A0a, thresholds=thresholds, **model)
            n_lsm += n_a * n_o
            passed = (res.status == Status.CONVERGED).reshape(n_a, n_o)
            best = np.argmin(np.where(passed, res.sigma0.reshape(n_a, n_o), np.inf), axis=1)
            # the node's match: the best window's match carried back by its affine matrix
            adopt(again, res, "shifted", pick=np.arange(n_a) * n_o + best,
                  node_xy=res.xy - np.einsum("nij,nj->ni", res.A, o))
        return ok, xy, A, s0, sxy, how

    def store(node_rc, ok, xy, A, s0, sxy, how, w, hole):
        r, c = node_rc[:, 0], node_rc[:, 1]
        good = np.flatnonzero(ok)
        state[r[good], c[good]] = 1
        s_xy[r[good], c[good]] = xy[good]
        A_all[r[good], c[good]] = A[good]
        sig0[r[good], c[good]] = s0[good]
        sigxy[r[good], c[good]] = sxy[good]
        wave[r[good], c[good]] = w
        holes[r[good], c[good]] = hole
        method[r[good], c[good]] = how[good]
        bad = np.flatnonzero(~ok)
        attempts[r[bad], c[bad]] += 1
        state[r[bad], c[bad]] = np.where(attempts[r[bad], c[bad]] >= max_attempts, 2, 0)

    # 1. the seeds: LSM at the seed itself, then its nearest usable node of its own cell
    seed_res = lsm(f_img, g_img, seeds_t, seeds_s, patch=max((patch,) + retry_patches),
                   **model)
    n_lsm += len(seeds_t)
    seeds_ok = seed_res.status == Status.CONVERGED
    start_nodes, start_approx, start_A = [], [], []
    for k in np.flatnonzero(seeds_ok):
        cand = np.argwhere(usable & (cell == k) & (state == 0))
        if cand.size == 0:
            continue
        d = np.linalg.norm(nodes[cand[:, 0], cand[:, 1]] - seeds_t[k], axis=1)
        rc = cand[np.argmin(d)]
        start_nodes.append(rc)
        offset = nodes[rc[0], rc[1]] - seeds_t[k]
        start_approx.append(seed_res.xy[k] + seed_res.A[k] @ offset)
        start_A.append(seed_res.A[k])
    if start_nodes:
        rc = np.array(start_nodes)
        store(rc, *match(rc, np.array(start_approx), np.array(start_A)), 0, False)

    # 2. growth inside the cells, then 3. hole closing across cells
    w = 1
    for hole_phase in ((False, True) if close_holes else (False,)):
        frontier = state == 1
        while frontier.any():
            grown = np.zeros_like(frontier)
            for directions in (HORIZONTAL, VERTICAL):
                cand_rc, parent_rc = _candidates(frontier | grown, state, usable, cell,
                                                 directions, same_cell=not hole_phase)
                if cand_rc.size == 0:
                    continue
                pr, pc = parent_rc[:, 0], parent_rc[:, 1]
                offset = nodes[cand_rc[:, 0], cand_rc[:, 1]] - nodes[pr, pc]
                approx = s_xy[pr, pc] + np.einsum("nij,nj->ni", A_all[pr, pc], offset)
                ok, *out = match(cand_rc, approx, A_all[pr, pc])
                store(cand_rc, ok, *out, w, hole_phase)
                grown[cand_rc[ok, 0], cand_rc[ok, 1]] = True
            frontier = grown
            w += 1

    r, c = np.nonzero(state == 1)
    return GrowResult(template_xy=nodes[r, c], search_xy=s_xy[r, c], A=A_all[r, c],
                      sigma0=sig0[r, c], sigma_xy=sigxy[r, c], seed=cell[r, c], wave=wave[r, c],
                      hole_closing=holes[r, c], seeds_matched=seeds_ok, n_lsm=n_lsm,
                      grid_shape=(rows, cols), node_index=np.stack([r, c], axis=1),
                      method=np.array(METHODS)[method[r, c]])


def _candidates(frontier, state, usable, cell, directions, *, same_cell):
    """Open usable neighbours of frontier nodes in the given directions, one parent each."""
    rows, cols = state.shape
    fr = np.argwhere(frontier)
    cands, parents = [], []
    for dc, dr in directions:
        nb = fr + (dr, dc)
        inside = (nb[:, 0] >= 0) & (nb[:, 0] < rows) & (nb[:, 1] >= 0) & (nb[:, 1] < cols)
        nb, par = nb[inside], fr[inside]
        keep = usable[nb[:, 0], nb[:, 1]] & (state[nb[:, 0], nb[:, 1]] == 0)
        if same_cell:
            keep &= cell[nb[:, 0], nb[:, 1]] == cell[par[:, 0], par[:, 1]]
        cands.append(nb[keep])
        parents.append(par[keep])
    if not cands:
        return np.empty((0, 2), int), np.empty((0, 2), int)
    cand = np.concatenate(cands)
    par = np.concatenate(parents)
    if cand.size == 0:
        return cand, par
    _, first = np.unique(cand[:, 0] * cols + cand[:, 1], return_index=True)
    return cand[first], par[first]
