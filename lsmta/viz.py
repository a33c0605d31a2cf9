"""Plotting helpers: image rows and correspondences (matplotlib), 3-D scenes (pyvista, off-screen).

pyvista renders off-screen through VTK's EGL window (Mesa's ``libEGL`` must be installed;
``scripts/bootstrap.sh`` does it). :func:`scene_image` returns the picture as an array, so a
notebook shows it with ``plt.imshow`` and needs no interactive 3-D backend.

Under ``lsmta reproduce`` (``LSMTA_VIEWS_DIR`` set) :func:`scene_image`, :func:`cloud_image`,
:func:`metaball_image` and :func:`mesh_image` also write the same scene as an interactive view
(:func:`export_3d_html`, from :mod:`lsmta.interactive`), which the book shows after the
picture; the PNG stays for print.
"""

from __future__ import annotations

import os

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import ConnectionPatch

from .interactive import VIEWS_ENV, Lines, Mesh, Points, export_3d_html

__all__ = ["show_images", "draw_correspondences", "part_colours", "scene_image", "cloud_image",
           "draw_marker_pose", "metaball_image", "mesh_image", "export_3d_html", "Mesh", "Points",
           "Lines"]


def _pyvista():
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv  # deferred: the EGL window must be chosen before VTK loads

    pv.OFF_SCREEN = True
    return pv


def _hex(rgb) -> str:
    r, g, b = (int(round(255 * float(c))) for c in np.asarray(rgb, float)[:3])
    return f"#{r:02x}{g:02x}{b:02x}"


def _mesh_item(mesh, color, opacity=1.0, name="") -> Mesh:
    """A pyvista surface as a :class:`Mesh` (triangulated)."""
    tri = mesh.triangulate()
    faces = np.asarray(tri.faces).reshape(-1, 4)[:, 1:]
    return Mesh(np.asarray(tri.points), faces, color=color if isinstance(color, str)
                else _hex(color), opacity=opacity, name=name)


def _export_under_reproduce(items, title: str) -> None:
    """The interactive twin of a static picture, only under ``lsmta reproduce``."""
    if os.environ.get(VIEWS_ENV) and items:
        export_3d_html(*items, title=title)


def show_images(images, *, titles=None, axes=None, cmap="gray", vmin=0, vmax=255,
                figsize_per=(5.0, 3.9)):
    """Show ``images`` ``(K, H, W)`` side by side; returns the matplotlib axes."""
    images = list(images)
    if axes is None:
        _, axes = plt.subplots(1, len(images), figsize=(figsize_per[0] * len(images),
                                                        figsize_per[1]), squeeze=False)
        axes = axes[0]
    for k, (ax, img) in enumerate(zip(axes, images)):
        ax.imshow(img, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
        if titles is not None:
            ax.set_title(titles[k])
        ax.set_xlabel("x [px]")
        ax.set_ylabel("y [px]")
    return axes


def draw_correspondences(axes, xy, *, colors=None, lines=True, size=18):
    """Mark corresponding points ``xy`` ``(K, N, 2)`` in K image axes and join them.

    Each of the N points gets one colour in every image; with ``lines``, a line joins its
    positions across neighbouring images (drawn across the figure).
    """
    xy = np.asarray(xy, float)
    K, N, _ = xy.shape
    if colors is None:
        colors = plt.cm.turbo(np.linspace(0, 1, max(N, 1)))
    for k in range(K):
        axes[k].scatter(xy[k, :, 0], xy[k, :, 1], s=size, c=colors[:N], edgecolors="white",
                        linewidths=0.6, zorder=3)
    if lines:
        for k in range(K - 1):
            for n in range(N):
                if np.all(np.isfinite(xy[[k, k + 1], n])):
                    con = ConnectionPatch(xyA=xy[k, n], coordsA=axes[k].transData,
                                          xyB=xy[k + 1, n], coordsB=axes[k + 1].transData,
                                          color=colors[n], lw=0.6, alpha=0.7)
                    axes[k + 1].figure.add_artist(con)
    return axes


def part_colours(part_id, n_parts: int):
    """An RGB image ``(H, W, 3)`` of a part-id map: one colour per part, grey background."""
    part_id = np.asarray(part_id)
    rgb = np.full(part_id.shape + (3,), 0.85)
    rgb[part_id == -2] = 1.0
    palette = plt.cm.tab20(np.arange(max(n_parts, 1)) % 20)[:, :3]
    on = part_id >= 0
    rgb[on] = palette[part_id[on]]
    return rgb


def scene_image(cameras, *, body=None, poses=None, background=None, frustum_depth=900.0,
                window_size=(1100, 700), view_from=(-5200.0, -7500.0, 4200.0),
                focal_point=(0.0, 0.0, 900.0), points=None) -> np.ndarray:
    """An off-screen 3-D picture of a rig, a posed body and the floor; ``(H, W, 3)`` uint8.

    Parameters
    ----------
    cameras : sequence of Camera
        Drawn as pyramids of their field of view, ``frustum_depth`` mm deep.
    body : Body, optional
    poses : (P, 4, 4) array, optional
        Part -> world transforms of one frame (``body.part_poses(motion, frame)[0]``).
    background : Background, optional
        Draws the floor and wall.
    view_from, focal_point : (3,) mm
        Viewpoint of the picture.
    points : (N, 3) array, optional
        Extra world points to draw (mm).
    """
    pv = _pyvista()
    pl = pv.Plotter(off_screen=True, window_size=list(window_size))
    pl.set_background("white")
    items = []
    for cam in cameras:
        corners = np.array([[-0.5, -0.5], [cam.width - 0.5, -0.5],
                            [cam.width - 0.5, cam.height - 0.5], [-0.5, cam.height - 0.5]])
        _, d = cam.rays(corners)
        depth = frustum_depth / (d @ cam.R[2])
        far = cam.C + d * depth[:, None]
        pts = np.vstack([cam.C, far])
        faces = np.hstack([[3, 0, 1, 2], [3, 0, 2, 3], [3, 0, 3, 4], [3, 0, 4, 1],
                           [4, 1, 2, 3, 4]])
        pl.add_mesh(pv.PolyData(pts, faces), color="royalblue", opacity=0.35,
                    show_edges=True, edge_color="navy")
        items.append(_mesh_item(pv.PolyData(pts, faces), "royalblue", 0.35,
                                cam.name or "camera"))
        items.append(Lines(tuple(np.array([cam.C, c]) for c in far)
                           + (np.vstack([far, far[:1]]),), color="navy", width=2))
        if cam.name:
            pl.add_point_labels(cam.C[None], [cam.name], font_size=14, point_size=8,
                                shape_opacity=0.6)
    if body is not None and poses is not None:
        palette = plt.cm.tab20(np.arange(len(body.parts)) % 20)[:, :3]
        for p, spec in enumerate(body.parts):
            mesh = pv.ParametricEllipsoid(*spec.radii, u_res=30, v_res=30)
            mesh.translate(spec.centre, inplace=True)
            mesh.transform(poses[p], inplace=True)
            pl.add_mesh(mesh, color=palette[p], smooth_shading=True)
            items.append(_mesh_item(mesh, palette[p]))
    if background is not None:
        if background.floor:
            floor = pv.Plane(center=(0, background.wall_y / 2 - 2500, 0), direction=(0, 0, 1),
                             i_size=7000, j_size=background.wall_y + 5000)
            pl.add_mesh(floor, color="tan", opacity=0.5)
            items.append(_mesh_item(floor, "tan", 0.5, "floor"))
        wall = pv.Plane(center=(0, background.wall_y, 1500), direction=(0, 1, 0),
                        i_size=3000, j_size=7000)
        pl.add_mesh(wall, color="lightgrey", opacity=0.5)
        items.append(_mesh_item(wall, "lightgrey", 0.5, "wall"))
    if points is not None:
        pl.add_points(np.asarray(points, float), color="crimson", point_size=6,
                      render_points_as_spheres=True)
        items.append(Points(np.asarray(points, float), color="crimson", size=3, name="points"))
    named = [cam for cam in cameras if cam.name]
    if named:
        items.append(Points(np.array([cam.C for cam in named]), text=[c.name for c in named],
                            as_text=True))
    _export_under_reproduce(items, "rig, cameras and body")
    pl.add_axes()
    pl.camera_position = [tuple(view_from), tuple(focal_point), (0, 0, 1)]
    image = pl.screenshot(return_img=True)
    pl.close()
    return image


_PLOTLY_SCALES = {"Viridis", "Plasma", "Inferno", "Magma", "Cividis", "Turbo", "Jet", "Hot",
                  "Greys", "Blues", "Reds", "Rainbow", "Portland", "Picnic"}


def cloud_image(points, *, scalars=None, cmap="viridis", clim=None, scalar_label="",
                window_size=(900, 700), view_from=None, focal_point=None,
                point_size=4.0) -> np.ndarray:
    """An off-screen picture ``(H, W, 3)`` of a point cloud (mm), optionally coloured.

    By default the view looks at the cloud's centre from the front (-Y) and a little above.
    """
    pv = _pyvista()
    pts = np.asarray(points, float)
    centre = np.nanmedian(pts, axis=0)
    extent = float(np.nanmax(np.ptp(pts, axis=0)))
    pl = pv.Plotter(off_screen=True, window_size=list(window_size))
    pl.set_background("white")
    cloud = pv.PolyData(pts)
    if scalars is not None:
        cloud[scalar_label or "value"] = np.asarray(scalars, float)
        pl.add_mesh(cloud, scalars=scalar_label or "value", cmap=cmap, clim=clim,
                    point_size=point_size, render_points_as_spheres=True,
                    scalar_bar_args={"title": scalar_label, "color": "black"})
    else:
        pl.add_mesh(cloud, color="steelblue", point_size=point_size,
                    render_points_as_spheres=True)
    _export_under_reproduce([Points(pts, color="steelblue", size=2, values=scalars,
                                    clim=clim, label=scalar_label,
                                    colorscale=cmap.capitalize() if isinstance(cmap, str)
                                    and cmap.capitalize() in _PLOTLY_SCALES else "Viridis")],
                            "point cloud" + (f", coloured by {scalar_label}"
                                             if scalar_label else ""))
    eye = view_from if view_from is not None else centre + [0.6 * extent, -2.2 * extent,
                                                             0.5 * extent]
    pl.camera_position = [tuple(eye), tuple(centre if focal_point is None else focal_point),
                          (0, 0, 1)]
    image = pl.screenshot(return_img=True)
    pl.close()
    return image


def draw_marker_pose(ax, model, points, *, labels=None, colors=None, link_color=None, title="",
                     size=14):
    """Draw a marker pose on a matplotlib 3-D axis.

    Parameters
    ----------
    ax : mpl_toolkits.mplot3d.Axes3D
    model : lsmta.sapm.MarkerModel
        Gives the segments and their stick links (:meth:`MarkerModel.edges`).
    points : (N, 3) array
        Points, mm.
    labels : (N,) int array, optional
        Model marker of each point (-1: unidentified). Identified points are coloured by
        segment and joined by their segment's stick links; without ``labels`` every point
        is drawn grey and unjoined (an unidentified pose).
    colors : (N, 3 or 4) array, optional
        Point colours overriding the segment colours (e.g. right/wrong).
    link_color : colour, optional
        One colour for every stick link instead of the segment colours.
    """
    points = np.asarray(points, float)
    palette = plt.cm.tab20(np.arange(model.n_segments) % 20)
    if labels is None:
        c = np.full((len(points), 4), (0.3, 0.3, 0.3, 1.0))
    else:
        labels = np.asarray(labels)
        c = np.where((labels >= 0)[:, None],
                     palette[model.point_segment[np.maximum(labels, 0)]], (0.6, 0.6, 0.6, 1))
        where = {int(lab): i for i, lab in enumerate(labels) if lab >= 0}
        for a, b in model.edges():
            if a in where and b in where:
                seg = model.point_segment[a]
                ax.plot(*points[[where[a], where[b]]].T, lw=1.5,
                        color=palette[seg] if link_color is None else link_color)
    if colors is not None:
        c = colors
    ax.scatter(*points.T, c=c, s=size, depthshade=False)
    lo, hi = np.nanmin(points, axis=0), np.nanmax(points, axis=0)
    mid, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
        setter(m - half, m + half)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_zlabel("z [mm]")
    ax.set_title(title)
    return ax


def metaball_image(ball_poses, radii, *, threshold_scale: float = 0.589, mesh=None,
                   points=None, point_colors=None, lines=None, line_color="steelblue",
                   window_size=(900, 700), view_from=None, focal_point=None,
                   mesh_opacity=0.35) -> np.ndarray:
    """Off-screen picture of metaballs as ellipsoids, with an optional skin mesh and points.

    Parameters
    ----------
    ball_poses : (B, 4, 4) array
        Ball frame -> world transforms (mm), e.g. ``model.ball_poses(...)[0].reshape(-1, 4, 4)``.
    radii : (B, 3) array
        Ball radii (mm); each ellipsoid is drawn at ``threshold_scale`` times them, the size
        of a lone ball's own surface ``F = 1/2`` (``sqrt(ln 2 / 2)``).
    mesh : (vertices (V, 3), faces (F, 3)), optional
        A skin surface drawn translucent over the balls.
    points : (N, 3) array, optional
    point_colors : (N, 3) array of RGB in [0, 1], optional
    lines : sequence of (M, 3) arrays, optional
        Polylines (e.g. 3-D trajectories), drawn in ``line_color``; NaN rows break a line.
    view_from, focal_point : (3,) mm, optional
        Camera of the picture (default: in front of the balls).
    """
    pv = _pyvista()
    pl = pv.Plotter(off_screen=True, window_size=list(window_size))
    pl.set_background("white")
    poses = np.asarray(ball_poses, float)
    radii = np.asarray(radii, float)
    palette = plt.cm.tab10(np.arange(len(poses)) // 3 % 10)[:, :3]
    items = []
    for k, (T, r) in enumerate(zip(poses, radii)):
        e = pv.ParametricEllipsoid(*(threshold_scale * r), u_res=24, v_res=24)
        e.transform(T, inplace=True)
        pl.add_mesh(e, color=palette[k], smooth_shading=True, opacity=0.9)
        items.append(_mesh_item(e, palette[k], 0.9))
    if mesh is not None:
        v, f = mesh
        faces = np.hstack([np.full((len(f), 1), 3), np.asarray(f)]).ravel()
        pl.add_mesh(pv.PolyData(np.asarray(v, float), faces), color="wheat",
                    opacity=mesh_opacity, smooth_shading=True)
        items.append(Mesh(np.asarray(v, float), np.asarray(f), color="wheat",
                          opacity=mesh_opacity, name="skin"))
    if points is not None:
        kw = {"color": "crimson"} if point_colors is None else {
            "scalars": np.asarray(point_colors), "rgb": True}
        pl.add_points(np.asarray(points, float), point_size=4, render_points_as_spheres=True,
                      **kw)
        items.append(Points(np.asarray(points, float), size=2.5, name="points"))
    if lines is not None:
        # one poly-data: a polyline per run of known positions
        verts, cells, n = [], [], 0
        for line in lines:
            line = np.asarray(line, float)
            idx = np.flatnonzero(np.isfinite(line).all(axis=1))
            for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
                if len(run) >= 2:
                    verts.append(line[run])
                    cells.append(np.concatenate([[len(run)], n + np.arange(len(run))]))
                    n += len(run)
        if verts:
            pl.add_mesh(pv.PolyData(np.concatenate(verts), lines=np.concatenate(cells)),
                        color=line_color, line_width=2)
        items.append(Lines(tuple(np.asarray(line, float) for line in lines),
                           color=line_color if isinstance(line_color, str)
                           else _hex(line_color), width=2, name="trajectories"))
    _export_under_reproduce(items, "fitted model (metaballs)")
    centre = poses[:, :3, 3].mean(axis=0) if focal_point is None else np.asarray(focal_point)
    eye = centre + np.array([250.0, -1000.0, 250.0]) if view_from is None else view_from
    pl.camera_position = [tuple(eye), tuple(centre), (0, 0, 1)]
    image = pl.screenshot(return_img=True)
    pl.close()
    return image


def mesh_image(vertices, faces, *, color="wheat", labels=None, window_size=(450, 600),
               views=None, title: str = "closed mesh") -> np.ndarray:
    """Off-screen picture ``(H, W, 3)`` of one triangle mesh (mm), shaded, from one or more
    viewpoints side by side.

    Parameters
    ----------
    vertices : (V, 3) array
        mm.
    faces : (F, 3) int array
        Vertex indices of each triangle.
    color : str or RGB tuple
        The surface's colour (label 0's with ``labels``).
    labels : (V,) int array, optional
        A label per vertex (e.g. its connected piece): label 0 in ``color``, the others in
        tab10's colours (the interactive copy for the book is drawn in ``color`` only).
    window_size : (int, int)
        Width and height of each view, px.
    views : sequence of (3,) offsets, optional
        Each viewpoint's direction from the mesh's centre (the camera then backs off until
        the whole mesh is in view); by default from -Y and from +X of the world (turned
        by 20 degrees), a little above.
    title : str
        Title of the interactive copy written for the book (under ``lsmta reproduce``).
    """
    pv = _pyvista()
    v, f = np.asarray(vertices, float), np.asarray(faces)
    if labels is not None and np.shape(labels) != (len(v),):
        raise ValueError(f"labels: expected one label per vertex, shape ({len(v)},), got "
                         f"{np.shape(labels)}")
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    views = [(-0.6, -1.6, 0.35), (1.6, -0.6, 0.35)] if views is None else views
    pl = pv.Plotter(off_screen=True, shape=(1, len(views)),
                    window_size=[window_size[0] * len(views), window_size[1]], border=False)
    surface = pv.PolyData.from_regular_faces(v, f)
    kw = {"color": color}
    if labels is not None:
        lab = np.asarray(labels, int)
        rgb = np.asarray(plt.cm.tab10(np.maximum(lab, 0) % 10)[:, :3])
        rgb[lab == 0] = plt.matplotlib.colors.to_rgb(color)
        surface["rgb"] = (255 * rgb).astype(np.uint8)
        kw = {"scalars": "rgb", "rgb": True}
    for k, eye in enumerate(views):
        pl.subplot(0, k)
        pl.set_background("white")
        pl.add_mesh(surface, smooth_shading=True, **kw)
        pl.camera_position = [tuple(centre + np.asarray(eye, float)), tuple(centre), (0, 0, 1)]
        pl.reset_camera()                  # the same direction, the whole mesh in view
        pl.camera.zoom(1.35)               # reset_camera fits the bounding sphere: too far
    _export_under_reproduce([Mesh(v, f, color=color if isinstance(color, str) else _hex(color),
                                  name="mesh")], title)
    image = pl.screenshot(return_img=True)
    pl.close()
    return image
