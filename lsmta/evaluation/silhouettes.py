"""Silhouette and contour trials on the generated walk (D'Apuzzo et al. 2000, Fig. 16).

One camera of the triplet rig films the empty studio (wall and floor), then the person
walking across it. The library learns the background from the empty frames, cuts out the
silhouettes, and tracks their contour with snakes, once with each start predicted from
the projected 3-D trajectories of surface points and once from the previous contour.
The contours are scored after the fact against the generator's true silhouettes.

The peer is OpenCV's MOG2 subtractor on the same frames (:func:`mog2_silhouettes`).
:func:`outline_rays` makes lines of sight through a metaball model's own outline (for the
silhouette term's fits, where the model is the generator).

Truth as an input: the trajectories that predict the contour are the generator's true
surface points, projected and with Gaussian image noise added (the LSMTA system's tracked
trajectories would take this place; notebook 14 runs that system on the arm wave).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from skimage.measure import find_contours

from .._validate import as_array
from ..body import silhouette_terms
from ..camera import Camera, scaled_camera
from ..silhouettes import (
    ContourTracks,
    SilhouetteParams,
    SnakeParams,
    largest_region,
    learn_background,
    mask_contour,
    silhouettes,
    track_contours,
)
from ..synth import Renderer, Scene, make_background, make_body, project_surface_points, walk
from ..synth.rigs import triplet_rig
from ..synth.silhouette import empty_scene, true_silhouettes


@dataclass(frozen=True, eq=False)
class SilhouetteWalk:
    """One camera's view of the empty studio and of the walk, with the truth.

    Attributes
    ----------
    scene : Scene
    camera : Camera
    images : (T, H, W) uint8 array
    empty : (E, H, W) uint8 array
        Frames of the empty studio (same camera, fresh noise).
    true_masks : (T, H s, W s) bool array
        True silhouettes on the ``s x s`` sub-pixel grid.
    supersample : int
    tracks : (T, N, 2) array
        Projected true surface points with image noise; NaN where hidden (truth input).
    """

    scene: Scene
    camera: Camera
    images: np.ndarray
    empty: np.ndarray
    true_masks: np.ndarray
    supersample: int
    tracks: np.ndarray


def silhouette_walk(*, seed: int = 25, n_frames: int = 12, scale: float = 0.5, camera: int = 1,
                    n_empty: int = 8, n_points: int = 400, track_noise_px: float = 0.3,
                    noise_sigma: float = 2.0, supersample: int = 4,
                    fps: float = 25.0) -> SilhouetteWalk:
    """Render the walk and the empty studio in one camera of the triplet rig (4.5 m away,
    images ``scale`` x 768 x 576), with true silhouettes and projected trajectories."""
    rng = np.random.default_rng(seed)
    cam = scaled_camera(triplet_rig(rng=rng)[camera], scale)
    body = make_body(rng=rng, contrast=0.3, wavelength=(20.0 / scale, 80.0 / scale))
    scene = Scene(body=body, motion=walk(n_frames=n_frames, fps=fps),
                  background=make_background(rng=rng))
    renderer = Renderer(scene, [cam], noise_sigma=noise_sigma)
    images = np.stack([renderer.render(t, rng=rng).images[0] for t in range(n_frames)])
    studio = renderer.with_scene(empty_scene(scene))
    empty = np.stack([studio.render(t % n_frames, rng=rng).images[0] for t in range(n_empty)])
    truth = true_silhouettes(scene, [cam], range(n_frames), supersample=supersample)[:, 0]
    part, local = body.sample_surface(n_per_part=n_points // len(body.parts) + 1, rng=rng)
    proj = project_surface_points(scene, [cam], part, local)
    xy = proj.xy[:, 0] + rng.normal(0.0, track_noise_px, proj.xy[:, 0].shape)
    tracks = np.where(proj.visible[:, 0, :, None], xy, np.nan)
    return SilhouetteWalk(scene=scene, camera=cam, images=images, empty=empty, true_masks=truth,
                          supersample=int(supersample), tracks=tracks)


def mog2_silhouettes(empty, images, *, learning_rate: float = -1.0,
                     closing: int = 2) -> np.ndarray:
    """The peer: OpenCV's MOG2 subtractor (no shadow detection) trained on the empty frames,
    then run over ``images (T, H, W)`` with ``learning_rate`` (-1: OpenCV's automatic rate,
    as a user would run it); the same clean-up as ours (closing, largest region, holes)."""
    sub = cv2.createBackgroundSubtractorMOG2(history=len(empty), detectShadows=False)
    for frame in np.asarray(empty, np.uint8):
        sub.apply(frame, learningRate=1.0 / len(empty))
    fg = np.stack([sub.apply(f, learningRate=learning_rate) > 0
                   for f in np.asarray(images, np.uint8)])
    return largest_region(fg, closing=closing)


def true_outline(true_mask, supersample: int) -> np.ndarray:
    """All outline points ``(M, 2)`` (x, y pixels) of a sub-pixel true mask."""
    m = np.pad(np.asarray(true_mask, bool), 1).astype(float)
    rc = np.concatenate(find_contours(m, 0.5)) - 1.0
    return (rc[:, ::-1] + 0.5) / supersample - 0.5


@dataclass(frozen=True, eq=False)
class ContourScore:
    """Distances between a contour and the true outline (pixels): ``to_truth (n,)`` from
    each contour vertex, ``from_truth (M,)`` from each true outline point."""

    to_truth: np.ndarray
    from_truth: np.ndarray


def contour_score(contour, true_mask, supersample: int) -> ContourScore:
    """Score ``contour (n, 2)`` against the true mask of one frame (both directions)."""
    contour = as_array(contour, "contour", shape=(None, 2))
    outline = true_outline(true_mask, supersample)
    # the contour as a dense polyline, so that the reverse distance is not its spacing
    loop = np.vstack([contour, contour[:1]])
    u = np.linspace(0, 1, 8, endpoint=False)
    dense = (loop[:-1, None] * (1 - u[None, :, None]) + loop[1:, None] * u[None, :, None])
    return ContourScore(to_truth=cKDTree(outline).query(contour)[0],
                        from_truth=cKDTree(dense.reshape(-1, 2)).query(outline)[0])


@dataclass(frozen=True, eq=False)
class ContourTrial:
    """Silhouettes and contour tracking on a :class:`SilhouetteWalk`, scored.

    Attributes
    ----------
    masks : (T, H, W) bool array
        Silhouettes from the background model.
    predicted, previous : ContourTracks
        Snakes started from the trajectory prediction / from the previous contour.
    median_predicted, median_previous : (T,) arrays
        Median distance (pixels) of each frame's contour vertices to the true outline.
    median_from_truth_predicted, median_from_truth_previous : (T,) arrays
        Median distance of the true outline to the contour (the other direction).
    mask_iou : (T,) array
        Intersection over union of the silhouette with the true one (pixel centres).
    """

    masks: np.ndarray
    predicted: ContourTracks
    previous: ContourTracks
    median_predicted: np.ndarray
    median_previous: np.ndarray
    median_from_truth_predicted: np.ndarray
    median_from_truth_previous: np.ndarray
    mask_iou: np.ndarray


def run_contour_trial(data: SilhouetteWalk, *, n_points: int = 400,
                      silhouette_params: SilhouetteParams | None = None,
                      snake_params: SnakeParams | None = None) -> ContourTrial:
    """Background -> silhouettes -> snakes with and without the prediction -> scores."""
    bg = learn_background(data.empty)
    masks = silhouettes(data.images, bg, params=silhouette_params)
    first = mask_contour(masks[0], n_points=n_points)
    evidence = masks.astype(float)
    pred = track_contours(evidence, first, tracks=data.tracks, params=snake_params)
    prev = track_contours(evidence, first, params=snake_params)
    s = data.supersample
    centre = data.true_masks[:, s // 2::s, s // 2::s] if s % 2 else None
    scores = {}
    for key, tr in (("predicted", pred), ("previous", prev)):
        sc = [contour_score(c, m, s) for c, m in zip(tr.contours, data.true_masks)]
        scores[key] = (np.array([np.median(x.to_truth) for x in sc]),
                       np.array([np.median(x.from_truth) for x in sc]))
    if centre is None:      # even s: a pixel's centre lies between samples; use their mean
        T, Hs, Ws = data.true_masks.shape
        centre = data.true_masks.reshape(T, Hs // s, s, Ws // s, s).mean(axis=(2, 4)) >= 0.5
    iou = (masks & centre).sum(axis=(1, 2)) / np.maximum((masks | centre).sum(axis=(1, 2)), 1)
    return ContourTrial(masks=masks, predicted=pred, previous=prev,
                        median_predicted=scores["predicted"][0],
                        median_previous=scores["previous"][0],
                        median_from_truth_predicted=scores["predicted"][1],
                        median_from_truth_previous=scores["previous"][1], mask_iou=iou)


def outline_rays(model, angles, scales, radii, eyes, *, look_at, focal: float = 900.0,
                 size: int = 120, n_points: int = 120):
    """Lines of sight through a metaball model's own outline in ideal pinhole views.

    The model is the generator here (its pose ``angles (1, J)`` is the truth): each eye
    ``(3,)`` of ``eyes (K, 3)`` looks at ``look_at (3,)`` with a ``size x size`` image of
    principal distance ``focal`` pixels; a pixel is inside the outline when its line of
    sight passes through the skin; the outline's ``n_points`` contour points give the lines.

    Returns
    -------
    origins, directions : (K n_points, 3) arrays
    """
    eyes = as_array(eyes, "eyes", shape=(None, 3))
    look_at = as_array(look_at, "look_at", shape=(3,))
    origins, directions = [], []
    for eye in eyes:
        z = (look_at - eye) / np.linalg.norm(look_at - eye)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        c = (size - 1) / 2

        def dirs(xy, x=x, y=y, z=z, c=c):
            d = ((xy[:, :1] - c) / focal) * x + ((xy[:, 1:] - c) / focal) * y + z
            return d / np.linalg.norm(d, axis=1, keepdims=True)

        yy, xx = np.mgrid[0:size, 0:size]
        d = dirs(np.stack([xx.ravel(), yy.ravel()], 1).astype(float))
        dist = float(np.linalg.norm(look_at - eye))
        r = silhouette_terms(model, np.broadcast_to(eye, d.shape), d, angles, scales, radii,
                             near=max(dist - 500.0, 0.0), far=dist + 500.0, n_steps=160).r
        contour = mask_contour((r < 0).reshape(size, size), n_points=n_points)
        directions.append(dirs(contour))
        origins.append(np.broadcast_to(eye, (n_points, 3)))
    return np.vstack(origins), np.vstack(directions)
