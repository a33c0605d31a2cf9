"""Face markers identified without an operator: which dot in each pan-tilt head's frame is
which marker of the face model (Davis 2002 labels them once, by hand; issue 39).

:func:`identify_face_markers` works on one frame of every head, at the heads' read-back
angles:

1. *dots*: bright round blobs in each frame (:func:`~lsmta.tracking.markers.find_blobs`,
   the detector the marker systems use), and their rays. Two touching dots merge into one
   elongated blob, found once or twice (a strength peak on each lobe, both refined to the
   whole blob's centroid, between the two dots): each blob is kept once and a blob whose
   brightness spreads along one axis as two dots ``split_px`` or more apart would is split
   into its two dots only when its profile along that axis has two maxima of comparable
   height with a dip between them deeper than the image noise makes
   (:func:`~lsmta.tracking.markers.split_merged_blobs`; one stretched or motion-blurred
   dot is not split, nor two dots 3 px apart or closer). Before, a merged blob
   stayed one dot and both its markers went unlabelled;
2. *stereo*: the dots of each pair of heads matched one to one by the distance between
   their rays (the epipolar constraint at the heads' calibrated models; an optimal
   assignment, :func:`scipy.optimize.linear_sum_assignment`) and triangulated: unlabelled
   3-D points. With two heads side by side the epipolar lines run along the face's rows of
   dots, so many of these matches pair a dot with its neighbour (on notebook 15's scene
   about three in four): they only give where the face is (their median) and how far;
3. *rigid fit and assignment* (ICP): the face model's mean face (``basis.reference``) is
   placed there, its outward normal (its thinnest principal axis, on the side to which the
   face bulges) turned onto each normal of a cone about the direction to the heads, and
   turned about it in ``n_angles`` steps. The cone's rings stand a step of ``n_angles``
   apart (30° by default) up to 90° less half a step, with as many normals on a ring as
   that spacing allows: a face is seen only from the side it faces, and every normal
   within 75° of the heads' direction lies within about 21° of one of the cone's (before,
   the starts turned the normal only towards the heads and onto the stereo points'
   thinnest axis, which their wrong matches turn about 90° away: a face turned 42° from
   the heads, as at the start of a walk past them, was 42° from every start and refused;
   seed 21 of ``experiments/mixed_scale_system.py``). Every
   start is labelled once at the widest gate; the ``n_starts`` cheapest are fitted. From
   each fitted start: each
   head's dots are assigned to the projected markers (an optimal assignment, pairs within
   a gate), the markers with a dot in two heads triangulated (a pair that reprojects
   farther than ``max_px`` is two markers' dots and left out), the rigid motion fitted to
   them (:func:`~lsmta.rigid.fit_rigid`, the farthest left out), and again until the
   labels no longer change, with the gate shrinking (``gate_steps``). Labels are decided
   in the images, where the dots are distinct, not among the ambiguous stereo points. The
   ``n_poses`` best starts after the widest gate are carried on; the lowest cost wins;
4. *expression*: an expression moves markers by up to 16 mm, twice their spacing, so the
   mean face alone mislabels the mouth. From the rigid pose, ``n_expressions`` faces along
   the model's main expression (``±expression_mm`` at the marker it moves most) start the
   same loop with the face model fitted instead of a rigid motion
   (:meth:`lsmta.face.FaceModel.fill`: pose and expression weights); the lowest cost wins;
5. *labels*: each head's dots assigned to the fitted face projected (within ``gate_px``),
   a dot seen by one head only included; a marker projected within ``crowd_px`` of
   another that got no dot is left unlabelled (the two dots may have merged into one blob
   too close to split), unless its dot is one round dot alone (spread below ``round_px``,
   brightness below 1.5 times the median dot's, no other dot within ``crowd_px``) and its
   marker faces the head more than that neighbour (normals from the fitted face): one
   dot, the other marker turned away or behind the face, hidden. Before, every such marker
   went unlabelled: at the edge of a face turned from a head, markers turned away project
   within ``crowd_px`` of visible ones (coverage measured in
   ``experiments/results/mixed_scale_heads.json``, ``experiments/mixed_scale_system.py``'s
   seeds 18 to 22). A fit whose labelled markers lie farther than ``max_residual_mm``
   (RMS) from the fitted face has wrong labels in it: then nothing is labelled (a face
   turned far from the heads).

The cost of a labelling is the summed squared image distance of the pairs plus ``gate**2``
for every dot left without a marker.

Why not SAPM (:mod:`lsmta.sapm`): it is made for a body of articulated rigid parts seen by
many cameras, with candidate instances per part; a face is one part whose markers differ
only in their layout and the expression's shift, which a fit of the face model with an
optimal assignment uses whole, and the face model already describes the expressions.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_array, as_int, as_scalar
from ..face import FaceModel
from ..pantilt import PanTiltCamera
from ..rigid import fit_rigid
from ..tracking.correspondence import ray_distances
from ..tracking.markers import find_blobs, split_merged_blobs
from ..triangulation import intersect_rays


@dataclass(frozen=True)
class IdentifyParams:
    """Settings of :func:`identify_face_markers`.

    Attributes
    ----------
    sigma, min_strength, spacing : float, float, int
        The dot detector's scale (px), contrast (grey levels) and the square in which a dot
        is the strongest (px) (:func:`~lsmta.tracking.markers.find_blobs`); the heads' dots
        are about 1.3 px Gaussians at least 6 px apart.
    max_ray_distance : float
        Largest distance between the rays of a stereo match, mm (room for the read-back's
        0.05°, 2.6 mm at 3 m).
    max_px : float
        A labelled marker whose triangulation reprojects farther than this from its dot in
        a head is left out of the fits, px (as :class:`~lsmta.systems.MixedScaleParams`'s
        ``max_reprojection_px``).
    gate_px : float
        A projected marker and a dot farther apart than this are not paired in the final
        labels, px (the heads' dots are at least 6 px apart).
    crowd_px : float
        A marker whose projection lies closer than this to that of another marker left
        without a dot is left unlabelled too (their dots may have merged into one blob),
        px, unless its dot is round (``round_px``), no brighter than 1.5 times the
        frame's median dot (two merged dots are brighter), no other dot lies within
        ``crowd_px`` of it and its marker faces the head more than that neighbour.
    split_px : float
        A blob whose brightness spreads less than two dots this far apart is never split
        (:func:`~lsmta.tracking.markers.split_merged_blobs`), px: a round dot of the heads
        spreads as 1.5 px at most (with a neighbour's tail). Spreading farther is not
        enough: the blob's profile must dip between two maxima, which two of the heads'
        dots (sigma 1.3 px) 2.5-3 px apart do not (they stay one blob), 3.3 px apart do
        when bright, from about 3.5 px apart nearly always.
    round_px : float
        A dot whose spread is below this, with no other dot within ``crowd_px``, is one dot
        (not two merged ones too close to split), px: its marker keeps its label by the
        crowding rule.
    gate_steps : tuple of float
        The fits' gates, as multiples of ``gate_px`` (>= 1), widest first and never
        widening (the start may be off by half a step of ``n_angles``, a centimetre at the
        face's edge).
    n_angles : int
        Start angles about the face's normal; their step is also the spacing of the cone
        of normals (see the module).
    n_starts : int
        Starts, of all the cone's, fitted at the widest gate to rank them (the cheapest by
        their first labelling): 48, as many as the two normals with two signs each fitted
        before the cone (issue 39).
    n_iter : int
        Assignment and fit passes per gate, at most.
    n_iter_start : int
        Passes per start at the widest gate, to rank the starts.
    n_poses : int
        Starts carried on (best first) from there through every gate.
    expression_mm, n_expressions : float, int
        Faces tried along the model's main expression: ``n_expressions`` (odd, so that
        the neutral face is one of them) evenly from ``-expression_mm`` to
        ``+expression_mm`` mm at the marker it moves most.
    min_points : int
        Fewest triangulated markers a fit needs.
    max_residual_mm : float
        The labelled markers' RMS distance from the fitted face above which the
        identification is refused (nothing labelled), mm: right labels fit to about 1 mm
        at the heads' 0.1° read-back, a labelling with wrong ones in it to 2 mm and more.
    """

    sigma: float = 1.5
    min_strength: float = 20.0
    spacing: int = 5
    max_ray_distance: float = 5.0
    max_px: float = 4.0
    gate_px: float = 4.0
    crowd_px: float = 5.0
    split_px: float = 2.5
    round_px: float = 1.5
    gate_steps: tuple = (12.0, 6.0, 3.0, 1.0)
    n_angles: int = 12
    n_starts: int = 48
    n_iter: int = 10
    n_iter_start: int = 10
    n_poses: int = 3
    expression_mm: float = 20.0
    n_expressions: int = 9
    min_points: int = 6
    max_residual_mm: float = 1.5

    def __post_init__(self):
        for key in ("sigma", "min_strength", "max_ray_distance", "max_px", "gate_px",
                    "split_px", "round_px"):
            as_scalar(getattr(self, key), key, positive=True)
        as_scalar(self.crowd_px, "crowd_px", nonnegative=True)
        as_int(self.spacing, "spacing", minimum=1)
        as_int(self.n_iter, "n_iter", minimum=1)
        as_int(self.n_angles, "n_angles", minimum=1)
        as_int(self.n_starts, "n_starts", minimum=1)
        as_int(self.n_poses, "n_poses", minimum=1)
        as_int(self.n_iter_start, "n_iter_start", minimum=1)
        steps = as_array(self.gate_steps, "gate_steps", shape=(None,))
        if not len(steps) or (steps < 1).any() or (np.diff(steps) > 0).any():
            raise ValueError(f"gate_steps: expected factors >= 1 of gate_px, widest first "
                             f"(non-increasing), got {self.gate_steps}")
        if as_int(self.n_expressions, "n_expressions", minimum=1) % 2 == 0:
            raise ValueError(f"n_expressions: expected an odd number (the middle face is "
                             f"the neutral one), got {self.n_expressions}")
        as_scalar(self.expression_mm, "expression_mm", nonnegative=True)
        as_int(self.min_points, "min_points", minimum=3)
        as_scalar(self.max_residual_mm, "max_residual_mm", positive=True)


@dataclass(frozen=True, eq=False)
class FaceIdentification:
    """Result of :func:`identify_face_markers`.

    Attributes
    ----------
    xy : (K, M, 2) array
        Each marker's dot in each head's frame, px (NaN: no dot given that marker).
    points : (M, 3) array
        The labelled triangulated points, mm (NaN: the marker has no stereo point).
    face : (M, 3) array
        The face model fitted to them, every marker, mm (NaN when nothing was identified).
    dots : list of K (D_k, 2) arrays
        The dots found in each frame, px.
    split : list of K (D_k,) bool arrays
        The dots that are one of a merged blob's two
        (:func:`~lsmta.tracking.markers.split_merged_blobs`).
    n_points : int
        Dots matched across the heads by stereo and triangulated (unlabelled).
    residual_mm : float
        RMS distance of the labelled triangulated markers from the fitted face, mm (NaN:
        none).
    """

    xy: np.ndarray
    points: np.ndarray
    face: np.ndarray
    dots: list
    split: list
    n_points: int
    residual_mm: float

    @property
    def labelled(self) -> np.ndarray:
        """(K, M) bool: markers given a dot in each head."""
        return np.isfinite(self.xy).all(axis=2)


_SAME_BLOB_PX = 1.0   # blobs refined closer than this are one (px): two dots whose
                      # centroids stand farther apart (2 px and more) are told apart


def _blobs(image, p):
    """The dots of one frame (:func:`~lsmta.tracking.markers.find_blobs`, strongest first),
    each blob once, merged blobs split (:func:`~lsmta.tracking.markers.split_merged_blobs`):
    a :class:`~lsmta.tracking.markers.SplitBlobs`."""
    grey = image.astype(float)
    d = find_blobs(grey, sigma=p.sigma, min_strength=p.min_strength, spacing=p.spacing)
    return split_merged_blobs(grey, d, radius=int(np.ceil(2 * p.sigma)),
                              min_separation=p.split_px, same_px=_SAME_BLOB_PX)


def _dots(image, p):
    """The dots of one frame (:func:`_blobs`), (D, 2) px."""
    return _blobs(image, p).xy


def _rotation_to(a, b):
    """The rotation carrying unit vector ``a`` onto unit vector ``b`` (about their cross
    product; a half turn about a perpendicular axis when they are opposite)."""
    v, c = np.cross(a, b), float(a @ b)
    if c < -1 + 1e-12:
        u = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        u /= np.linalg.norm(u)
        return 2 * np.outer(u, u) - np.eye(3)
    V = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + V + V @ V / (1 + c)


def _about(axis, angle):
    """Rotation by ``angle`` (radians) about unit vector ``axis``."""
    V = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * V + (1 - np.cos(angle)) * V @ V


def _thinnest(P):
    """The unit axis along which points ``P`` (N, 3) vary least."""
    return np.linalg.svd(P - P.mean(axis=0), full_matrices=False)[2][2]


def _outward(ref):
    """The reference face's outward normals: its thinnest principal axis on the side to
    which it bulges (its depth along the axis falls with the squared distance from its
    centre: the nose stands out, the cheeks fall back); both signs when the layout does
    not bulge (depth and squared distance correlated by less than 0.5)."""
    n = _thinnest(ref)
    c = ref - ref.mean(axis=0)
    z = c @ n
    r2 = np.sum(c**2, axis=1) - z**2
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.corrcoef(r2, z)[0, 1]
    if not abs(rho) >= 0.5:
        return [n, -n]
    return [n if rho < 0 else -n]


def _cone(axis, step):
    """Unit normals about unit vector ``axis``: the axis and rings tilted by multiples of
    ``step`` (radians) up to pi/2 - step/2, each ring with ceil(2 pi sin(tilt) / step)
    normals evenly around it."""
    u = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    out = [axis]
    for tilt in np.arange(step, np.pi / 2 - step / 2 + 1e-9, step):
        for a in np.linspace(0, 2 * np.pi, int(np.ceil(2 * np.pi * np.sin(tilt) / step)),
                             endpoint=False):
            out.append(np.cos(tilt) * axis + np.sin(tilt) * (np.cos(a) * u + np.sin(a) * v))
    return out


def _starts(ref, towards, n_angles):
    """Start rotations: the reference's outward normal (:func:`_outward`) turned onto each
    normal of the cone about ``towards`` (unit vector, to the heads; :func:`_cone` with the
    step of ``n_angles``), then turned about it by ``n_angles`` equal steps."""
    step = 2 * np.pi / n_angles
    out = []
    for normal in _outward(ref):
        for axis in _cone(towards, step):
            R0 = _rotation_to(normal, axis)
            out += [_about(axis, a) @ R0
                    for a in np.linspace(0, 2 * np.pi, n_angles, endpoint=False)]
    return out


def _assign(Y, X, gate):
    """Optimal one-to-one pairs of rows of ``Y`` (M, d) and ``X`` (P, d) within ``gate``
    (NaN rows of ``Y`` take no part). Returns (row of Y, row of X, cost), the cost counting
    ``gate**2`` for every row of ``X`` left without a partner."""
    ok = np.flatnonzero(np.isfinite(Y).all(axis=1))
    if not len(ok) or not len(X):
        return np.zeros(0, int), np.zeros(0, int), gate**2 * len(X)
    C = np.minimum(np.sum((Y[ok, None] - X[None]) ** 2, axis=2), gate**2)
    r, c = linear_sum_assignment(C)
    keep = C[r, c] < gate**2
    cost = C[r[keep], c[keep]].sum() + gate**2 * (len(X) - keep.sum())
    return ok[r[keep]], c[keep], float(cost)


class _Frame:
    """One frame of every head: the cameras at the read-back angles, the dots and their
    rays, and the largest reprojection error of a labelled marker's triangulation."""

    def __init__(self, cams, dots, max_px):
        self.cams, self.dots, self.max_px = cams, dots, max_px
        self.rays = [cam.rays(d) if len(d) else (np.zeros((0, 3)), np.zeros((0, 3)))
                     for cam, d in zip(cams, dots)]

    def label(self, face, gate):
        """Each head's dots assigned to ``face`` (M, 3) projected: the dot of each marker
        in each head (K, M) int (-1: none) and the summed cost."""
        idx = np.full((len(self.cams), len(face)), -1)
        cost = 0.0
        on = np.isfinite(face).all(axis=1)
        for k, cam in enumerate(self.cams):
            proj = np.full((len(face), 2), np.nan)
            if on.any():
                proj[on] = cam.project(face[on], behind="nan")
            m, d, c = _assign(proj, self.dots[k], gate)
            idx[k, m] = d
            cost += c
        return idx, cost

    def xy(self, idx):
        """(K, M, 2) px of labels ``idx`` (NaN: none)."""
        out = np.full(idx.shape + (2,), np.nan)
        for k, d in enumerate(self.dots):
            on = idx[k] >= 0
            out[k, on] = d[idx[k, on]]
        return out

    def points(self, idx):
        """The markers with a dot in at least two heads, triangulated: (M, 3), NaN elsewhere
        and where the intersection reprojects farther than ``max_px`` from a dot (dots of
        two different markers)."""
        K, M = idx.shape
        if not M:
            return np.zeros((0, 3))
        o = np.full((K, M, 3), np.nan)
        d = np.full((K, M, 3), np.nan)
        for k, (ro, rd) in enumerate(self.rays):
            on = idx[k] >= 0
            o[k, on], d[k, on] = ro[idx[k, on]], rd[idx[k, on]]
        X = intersect_rays(o, d).points
        xy = self.xy(idx)
        for k, cam in enumerate(self.cams):
            on = np.isfinite(X).all(axis=1) & (idx[k] >= 0)
            if on.any():
                e = np.linalg.norm(cam.project(X[on], behind="nan") - xy[k, on], axis=1)
                bad = np.flatnonzero(on)[~(e <= self.max_px)]
                X[bad] = np.nan
        return X

    def stereo(self, max_ray_distance):
        """Unlabelled 3-D points: the dots of each pair of heads matched one to one by the
        distance between their rays (the epipolar constraint; an optimal assignment, pairs
        within ``max_ray_distance`` mm) and intersected."""
        out = []
        for a, b in itertools.combinations(range(len(self.cams)), 2):
            if not len(self.dots[a]) or not len(self.dots[b]):
                continue
            D = ray_distances(self.rays[a], self.rays[b])
            i, j = linear_sum_assignment(np.minimum(D, max_ray_distance))
            keep = D[i, j] < max_ray_distance
            idx = np.full((len(self.cams), keep.sum()), -1)
            idx[a], idx[b] = i[keep], j[keep]
            out.append(self.points(idx))
        X = np.concatenate(out) if out else np.zeros((0, 3))
        return X[np.isfinite(X).all(axis=1)]


def _trimmed(X, face):
    """``X`` with the points farther from ``face`` than three times their median distance
    (plus 1 mm) set to NaN: wrong labels left out of a fit."""
    d = np.linalg.norm(X - face, axis=1)
    if not np.isfinite(d).any():
        return X
    with np.errstate(invalid="ignore"):
        far = d > 3 * np.nanmedian(d) + 1.0
    return np.where(far[:, None], np.nan, X)


def _rigid(frame, shape, R, t, gates, n_iter, min_points):
    """ICP: alternate labels (each head's dots assigned to ``shape`` posed by R, t) and the
    rigid motion fitted to the triangulated labelled markers (trimmed), for each gate in
    turn, until the labels no longer change (at most ``n_iter`` fits per gate; when they
    run out, the last fit's pose is labelled once more, so that the cost is the pose's).
    Returns R, t, cost at the last gate."""
    cost = np.inf
    for gate in gates:
        last = None
        for _ in range(n_iter):
            xy, cost = frame.label(shape @ R.T + t, gate)
            if last is not None and np.array_equal(xy, last):
                break
            last = xy
            X = _trimmed(frame.points(xy), shape @ R.T + t)
            ok = np.isfinite(X).all(axis=1)
            if ok.sum() < min_points:
                return R, t, np.inf
            R, t = fit_rigid(shape[ok], X[ok])
            if not (np.isfinite(R).all() and np.isfinite(t).all()):
                return R, t, np.inf
        else:
            _, cost = frame.label(shape @ R.T + t, gate)
    return R, t, cost


def _shaped(frame, face_model, face, gates, n_iter, min_points):
    """Alternate labels and the face model fitted to the triangulated labelled markers
    (trimmed), for each gate in turn (as :func:`_rigid`: the last fit labelled once more
    when ``n_iter`` runs out). Returns the face (M, 3) and the cost."""
    cost = np.inf
    for gate in gates:
        last = None
        for _ in range(n_iter):
            xy, cost = frame.label(face, gate)
            if last is not None and np.array_equal(xy, last):
                break
            last = xy
            X = _trimmed(frame.points(xy), face)
            if np.isfinite(X).all(axis=1).sum() < min_points:
                return face, np.inf
            fit = face_model.fill(X[None])
            if not fit.fitted[0]:
                return face, np.inf
            face = fit.model[0]
        else:
            _, cost = frame.label(face, gate)
    return face, cost


def _expression(face_model):
    """The face model's main expression direction (M, 3), scaled to 1 mm at the marker it
    moves most: its first principal direction (or the extreme faces' main variation)."""
    b = face_model.basis
    v = np.asarray(b.vectors, float)
    if b.kind == "pca":
        if len(v) < 2:
            return np.zeros_like(v[0])
        d = v[1]
    else:
        D = (v - v.mean(axis=0)).reshape(len(v), -1)
        d = np.linalg.svd(D, full_matrices=False)[2][0].reshape(v.shape[1:])
    return d / max(np.linalg.norm(d, axis=1).max(), 1e-12)


def _normals(face, towards, n_neighbours=8):
    """Outward unit normals (M, 3) of a face's markers (M, 3): the thinnest axis of each
    marker and its ``n_neighbours`` nearest, turned away from a point behind the face (its
    centre set back along its outward normal, :func:`_outward`, by its width). When the
    face does not bulge enough to tell its outward side (:func:`_outward` gives both signs),
    the side towards ``towards`` (3,) (the heads, which see the face's front) is taken."""
    c = face.mean(axis=0)
    n0 = max(_outward(face), key=lambda n: float(n @ towards))
    back = c - n0 * np.ptp(face, axis=0).max()
    d = np.linalg.norm(face[:, None] - face[None], axis=2)
    out = np.empty_like(face)
    for m, near in enumerate(np.argsort(d, axis=1)[:, :n_neighbours + 1]):
        n = _thinnest(face[near])
        out[m] = n if n @ (face[m] - back) >= 0 else -n
    return out


_MERGED_BRIGHTNESS = 1.5  # a blob this many times the frame's median blob brightness or
                          # more may be two merged dots (two carry 1.9-2.1 times one's when
                          # 1.5 px apart or less, 1.3-1.6 times when 2.5-3 px apart: the
                          # window cuts off the farther tails)


def _uncrowded(idx, cams, face, crowd_px, blobs=None, round_px=0.0):
    """Labels ``idx`` (K, M) without the markers projected within ``crowd_px`` of another
    marker that got no dot in that head (their dots may have merged into one blob), unless
    the marker's dot is one round dot alone: of ``blobs[k]`` (a :class:`~lsmta.tracking.
    markers.SplitBlobs`), its spread measured and below ``round_px``, its brightness below
    ``_MERGED_BRIGHTNESS`` times the median dot's (two merged dots carry 1.9-2.1 times
    one's when 1.5 px apart or less, 1.3-1.6 times when 2.5-3 px apart), no other dot
    within ``crowd_px``; and the marker faces the head more than every such neighbour (the
    cosine of its normal, :func:`_normals`, with the line of sight; the dot is the one that
    faces the head, the other is hidden; the neighbour need not face away: hidden
    neighbours are mostly behind the face, not turned away) (None: no dot is taken for
    round)."""
    idx = idx.copy()
    if blobs is not None:
        centre = face.mean(axis=0)
        towards = np.mean([c.C for c in cams], axis=0) - centre
        normals = _normals(face, towards / np.linalg.norm(towards))
    for k, cam in enumerate(cams):
        proj = cam.project(face, behind="nan")
        d = np.nan_to_num(np.linalg.norm(proj[:, None] - proj[None], axis=2), nan=np.inf)
        np.fill_diagonal(d, np.inf)
        d[:, idx[k] >= 0] = np.inf                # a neighbour with its own dot is apart
        crowded = d.min(axis=1) < crowd_px
        if blobs is not None:
            sight = cam.C - face
            cos = np.sum(normals * sight, axis=1) / np.linalg.norm(sight, axis=1)
            faces_more = np.all((d >= crowd_px) | (cos[:, None] > cos[None]), axis=1)
            crowded &= ~(_one_round_dot(blobs[k], idx[k], crowd_px, round_px) & faces_more)
        idx[k, crowded] = -1
    return idx


def _one_round_dot(b, idx, crowd_px, round_px):
    """(M,) bool: the marker's dot (``idx`` (M,), -1: none) of blobs ``b`` (a
    :class:`~lsmta.tracking.markers.SplitBlobs`) is one round dot alone (see
    :func:`_uncrowded`)."""
    gap = np.linalg.norm(b.xy[:, None] - b.xy[None], axis=2)
    np.fill_diagonal(gap, np.inf)
    bright = b.brightness < _MERGED_BRIGHTNESS * np.nanmedian(b.brightness) \
        if np.isfinite(b.brightness).any() else np.zeros(len(b.xy), bool)
    single = (b.spread < round_px) & bright & (gap.min(axis=1, initial=np.inf) >= crowd_px)
    has = idx >= 0
    out = np.zeros(len(idx), bool)
    out[has] = single[idx[has]]
    return out


def _check(images, heads, settings, face_model):
    heads = list(heads)
    if len(heads) < 2 or not all(isinstance(h, PanTiltCamera) for h in heads):
        raise TypeError("heads: expected at least 2 calibrated lsmta.pantilt.PanTiltCamera")
    K = len(heads)
    if not isinstance(face_model, FaceModel):
        raise TypeError(f"face_model: expected an lsmta.face.FaceModel, got "
                        f"{type(face_model).__name__}")
    settings = as_array(settings, "settings", shape=(K, 2))
    try:
        imgs = [np.asarray(im) for im in images]
    except TypeError:
        raise TypeError("images: expected a sequence of K (H, W) grey frames") from None
    if len(imgs) != K:
        raise ValueError(f"images: expected {K} frames, one per head, got {len(imgs)}")
    for k, (im, h) in enumerate(zip(imgs, heads)):
        cam = h.camera
        if im.ndim != 2 or im.shape != (cam.height, cam.width):
            raise ValueError(f"images: head {k}'s frame has shape {im.shape}; expected "
                             f"({cam.height}, {cam.width}), the head's grey image")
        if not (np.issubdtype(im.dtype, np.integer) or np.issubdtype(im.dtype, np.floating)) \
                or im.dtype == bool:
            raise TypeError(f"images: head {k}'s frame has dtype {im.dtype}; expected grey "
                            "levels (uint8 or float)")
    return imgs, heads, settings


def _shifted_labels(proj, dots, gate_px):
    """The dot of each projected marker ``proj`` (M, 2) among ``dots`` (D, 2), (M,) int (-1:
    none), allowing the projections a common image shift: the fitted face from one pair
    lands a few pixels off in another head (each head's read-back angle is off by up to
    0.05°, 2.6 px at a 3000 px zoom). Optimal assignments within 3, 1.5 and 1 times
    ``gate_px``, the shift re-estimated (median) after each; the last one gives the labels."""
    shift = np.zeros(2)
    out = np.full(len(proj), -1)
    for g in (3.0, 1.5, 1.0):
        m, d, _ = _assign(proj + shift, dots, g * gate_px)
        out[:] = -1
        out[m] = d
        if len(m):
            shift = np.median(dots[d] - proj[m], axis=0)
    return out


def _identify_from_pair(imgs, heads, settings, face_model, p):
    """K > 2 heads: the face identified from one pair, the pair whose poorer frame has the
    most dots (ties: the pair listed first), then every other head's dots assigned to that
    face projected, shifted as a whole in the image (:func:`_shifted_labels`; crowded
    markers left out, as step 5). The rays of
    more than two heads are never intersected together: each head's read-back angles carry
    their own small bias (0.1° steps), and rays of three or four heads miss each other by
    more than a pair's (on notebook 15's walk the residual of a four-head fit was 2.5 mm
    against 1.0 mm from a pair, above ``max_residual_mm``)."""
    K = len(heads)
    cams = [h.camera_at(*settings[k]) for k, h in enumerate(heads)]
    blobs = [_blobs(im, p) for im in imgs]
    dots = [b.xy for b in blobs]
    pairs = list(itertools.combinations(range(K), 2))
    a, b = max(pairs, key=lambda ab: (min(len(dots[ab[0]]), len(dots[ab[1]])), -pairs.index(ab)))
    r = identify_face_markers([imgs[a], imgs[b]], [heads[a], heads[b]], settings[[a, b]],
                              face_model, params=p)
    M = r.xy.shape[1]
    xy = np.full((K, M, 2), np.nan)
    if r.labelled.any():
        idx = np.full((K, M), -1)
        for k, cam in enumerate(cams):
            if k not in (a, b):
                idx[k] = _shifted_labels(cam.project(r.face, behind="nan"), dots[k], p.gate_px)
        xy = _Frame(cams, dots, p.max_px).xy(
            _uncrowded(idx, cams, r.face, p.crowd_px, blobs, p.round_px))
        xy[a], xy[b] = r.xy
    return FaceIdentification(xy=xy, points=r.points, face=r.face, dots=dots,
                              split=[b.split for b in blobs],
                              n_points=r.n_points, residual_mm=r.residual_mm)


def _best_pose(frame, X, cams, ref, gates, p: IdentifyParams):
    """The mean face's rigid pose ``(R, t, cost)`` on the stereo points ``X``: starts on
    the cone of normals about the direction to the heads (:func:`_starts`), each labelled
    once at the widest gate, the ``n_starts`` cheapest fitted at that gate, the best
    ``n_poses`` of those refined with every gate. (The stereo points' own thinnest axis is
    no normal: their wrong matches spread them in depth, and on notebook 15's walks it
    stood about 90° from the face's normal.)"""
    centre = np.median(X, axis=0)
    towards = np.mean([c.C for c in cams], axis=0) - centre
    towards /= np.linalg.norm(towards)
    first = []
    for R0 in _starts(ref, towards, p.n_angles):
        t0 = centre - ref.mean(axis=0) @ R0.T
        first.append((frame.label(ref @ R0.T + t0, gates[0])[1], R0, t0))
    first.sort(key=lambda r: r[0])
    poses = []
    for _, R0, t0 in first[:p.n_starts]:
        poses.append(_rigid(frame, ref, R0, t0, gates[:1], p.n_iter_start, p.min_points))
    poses = [_rigid(frame, ref, R, t, gates, p.n_iter, p.min_points)
             for R, t, _ in sorted(poses, key=lambda r: r[2])[:p.n_poses]]
    return min(poses, key=lambda r: r[2])


def identify_face_markers(images, heads, settings, face_model: FaceModel, *,
                          params: IdentifyParams | None = None) -> FaceIdentification:
    """Which dot in each head's frame is which face marker, without an operator (see the
    module).

    Parameters
    ----------
    images : sequence of K (H, W) arrays
        One frame of each head, grabbed at the same time, grey levels.
    heads : sequence of K >= 2 PanTiltCamera
        The heads as calibrated. With more than two, the face is identified from one
        pair (the pair whose poorer frame has the most dots) and the other heads' dots are
        labelled from that face projected into them, shifted as a whole to fit (never the
        rays of three or more heads intersected together: each head's read-back angles
        carry their own bias).
    settings : (K, 2) array
        The pan and tilt each head reported for its frame, degrees.
    face_model : lsmta.face.FaceModel
        The face's markers: its mean face (``basis.reference``, M markers) gives the
        layout, its basis the expressions.
    params : IdentifyParams, optional

    Returns
    -------
    FaceIdentification
        Nothing passed in is modified. When fewer than ``params.min_points`` dots are
        matched across the heads, or no fit keeps that many, nothing is identified (every
        ``xy`` NaN): a frame without the face, or one whose dots merge; nor when the best
        fit's residual exceeds ``params.max_residual_mm`` (its ``face`` and
        ``residual_mm`` are kept, to see why).
    """
    p = IdentifyParams() if params is None else params
    if not isinstance(p, IdentifyParams):
        raise TypeError(f"params: expected an IdentifyParams, got {type(p).__name__}")
    imgs, heads, settings = _check(images, heads, settings, face_model)
    if len(heads) > 2:
        return _identify_from_pair(imgs, heads, settings, face_model, p)
    ref = np.asarray(face_model.basis.reference, float)
    K, M = len(heads), len(ref)
    cams = [h.camera_at(*settings[k]) for k, h in enumerate(heads)]
    blobs = [_blobs(im, p) for im in imgs]
    dots = [b.xy for b in blobs]
    nothing = dict(xy=np.full((K, M, 2), np.nan), points=np.full((M, 3), np.nan),
                   face=np.full((M, 3), np.nan), dots=dots,
                   split=[b.split for b in blobs], n_points=0,
                   residual_mm=float("nan"))
    if sum(len(d) > 0 for d in dots) < 2:
        return FaceIdentification(**nothing)
    frame = _Frame(cams, dots, p.max_px)
    X = frame.stereo(p.max_ray_distance)
    if len(X) < p.min_points:
        return FaceIdentification(**{**nothing, "n_points": len(X)})
    gates = tuple(p.gate_px * g for g in p.gate_steps)
    R, t, cost = _best_pose(frame, X, cams, ref, gates, p)
    if not np.isfinite(cost):
        return FaceIdentification(**{**nothing, "n_points": len(X)})
    best = (np.inf, ref @ R.T + t)
    direction = _expression(face_model)
    for s in np.linspace(-p.expression_mm, p.expression_mm, p.n_expressions):
        face, cost = _shaped(frame, face_model, (ref + s * direction) @ R.T + t, gates,
                             p.n_iter, p.min_points)
        if cost < best[0]:
            best = (cost, face)
    face = best[1]
    idx, _ = frame.label(face, p.gate_px)
    idx = _uncrowded(idx, cams, face, p.crowd_px, blobs, p.round_px)
    points, xy = frame.points(idx), frame.xy(idx)
    ok = np.isfinite(points).all(axis=1)
    resid = float(np.sqrt(np.mean(np.sum((face[ok] - points[ok]) ** 2, axis=1)))) \
        if ok.any() else float("nan")
    if not resid <= p.max_residual_mm:          # a fit this poor has wrong labels in it
        return FaceIdentification(**{**nothing, "n_points": len(X), "face": face,
                                     "residual_mm": resid})
    return FaceIdentification(xy=xy, points=points, face=face, dots=dots,
                              split=[b.split for b in blobs], n_points=len(X),
                              residual_mm=resid)
