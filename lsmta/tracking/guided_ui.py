"""The guided tracking interface (Davis 2002, Fig. 56) as ipywidgets, and its static figure.

:class:`GuidedTracker` shows a marker video's tracking state (markers x frames, coloured by
:class:`~lsmta.tracking.guided.MarkerState`), an enlarged view of the chosen marker in the
chosen frame, and the controls to place a lost marker by hand: a frame slider, a marker
list, x / y boxes (pre-filled with the marker's last known position) and a *place & resume*
button that calls :func:`~lsmta.tracking.guided.resume_from`. The pictures are matplotlib
figures rendered to PNG into ``ipywidgets.Image`` widgets, so the whole interface is built
and driven without a front end (tests, ``nbmake``); :meth:`GuidedTracker.static_summary`
draws the same two pictures as one matplotlib figure for static output. One camera
(2-D mode).
"""

from __future__ import annotations

import io

import ipywidgets as widgets
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import BoundaryNorm, ListedColormap

from .guided import MarkerState, feature_view, last_known, resume_from, tracking_state
from .points import TrackerParams, Tracks, as_sequences

#: colour of each MarkerState, in code order
STATE_COLOURS = ("#3a7d44", "#7fc97f", "#1f78b4", "#fdb863", "#d7301f", "#e8e8e8")


def draw_state(ax, state, *, frame: int | None = None, marker: int | None = None) -> None:
    """Draw the ``(T, N)`` :func:`~lsmta.tracking.guided.tracking_state` codes as an image
    (markers down, frames across) on ``ax``, with a legend; mark ``frame`` and ``marker``."""
    state = np.asarray(state)
    n = len(MarkerState)
    ax.imshow(state.T, aspect="auto", interpolation="nearest", cmap=ListedColormap(STATE_COLOURS),
              norm=BoundaryNorm(np.arange(n + 1) - 0.5, n))
    if frame is not None:
        ax.axvline(frame, color="k", lw=1)
    if marker is not None:
        ax.axhline(marker, color="k", lw=0.8, ls=":")
    ax.set_xlabel("frame")
    ax.set_ylabel("marker")
    handles = [plt.Rectangle((0, 0), 1, 1, color=STATE_COLOURS[s]) for s in MarkerState]
    ax.legend(handles, [s.name.lower().replace("_", " ") for s in MarkerState], fontsize=7,
              loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)


def draw_feature(ax, image, tracks: Tracks, marker: int, frame: int, *, half: int = 15,
                 click=None, truth=None) -> None:
    """Enlarged view of ``marker`` in ``image`` (frame ``frame``) on ``ax``: centred on its
    tracked position there (cross), else its last known one (circle); ``click`` (+) and
    ``truth`` (x, grey) are drawn if given, (2,) px."""
    centre = last_known(tracks, marker, frame)
    if not np.isfinite(centre).all():
        centre = np.array(image.shape[::-1], float) / 2
    view = feature_view(image, centre, half=half)
    ax.imshow(view.patch, cmap="gray", extent=view.extent, interpolation="nearest")
    here = tracks.xy[frame, 0, marker]
    if np.isfinite(here).all():
        ax.plot(*here, "+", color="lime", ms=14, mew=2, label="tracked")
    else:
        ax.plot(*centre, "o", mfc="none", color="orange", ms=14, label="last known")
    if click is not None:
        ax.plot(*np.asarray(click, float), "+", color="deepskyblue", ms=12, mew=1.5,
                label="placed")
    if truth is not None:
        ax.plot(*np.asarray(truth, float), "x", color="0.6", ms=8, label="truth")
    ax.set_xlim(view.extent[:2])
    ax.set_ylim(view.extent[2:])
    ax.set_title(f"marker {marker}, frame {frame}", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


class GuidedTracker:
    """An ipywidgets interface to watch a tracked marker video and place lost markers.

    Parameters
    ----------
    images : (T, H, W) array, or a sequence of one image sequence
        The marker video (one camera).
    tracks : Tracks
        Its tracks (one camera); not modified: :attr:`tracks` holds the current ones.
    params : TrackerParams, optional
        As used for ``tracks`` (for resuming and for ``max_gap``).
    half : int
        Half-width of the enlarged view, px.

    Attributes
    ----------
    tracks : Tracks
        The tracks after the placements so far.
    placed : (T, N) bool array
        Frames placed by hand.
    history : list of Resumed
        Every placement, in order.
    widget : ipywidgets.VBox
        The interface (display it in a notebook).
    """

    def __init__(self, images, tracks: Tracks, *, params: TrackerParams | None = None,
                 half: int = 15):
        seq = as_sequences([images] if np.ndim(images) == 3 else images)
        if seq.shape[0] != 1:
            raise ValueError(f"images: expected one camera's image sequence, got {seq.shape[0]}")
        self.images = seq
        self.params = params or TrackerParams()
        self.half = half
        self.tracks = tracks
        self.placed = np.zeros((tracks.n_frames, len(tracks)), bool)
        tracking_state(tracks)                               # checks the tracks
        if tracks.xy.shape[1] != 1:
            raise ValueError(f"tracks: expected tracks of one camera, got {tracks.xy.shape[1]}")
        if tracks.n_frames != seq.shape[1]:
            raise ValueError(f"tracks: expected {seq.shape[1]} frames (as images), got "
                             f"{tracks.n_frames}")
        self.history = []
        T, N = self.placed.shape
        self.frame = widgets.IntSlider(value=0, min=0, max=T - 1, description="frame")
        self.marker = widgets.Dropdown(options=self._marker_options(), value=0,
                                       description="marker")
        self.x = widgets.FloatText(description="x [px]", step=0.1)
        self.y = widgets.FloatText(description="y [px]", step=0.1)
        self.button = widgets.Button(description="place & resume", button_style="primary")
        self.message = widgets.HTML()
        self.overview = widgets.Image(format="png")
        self.enlarged = widgets.Image(format="png")
        self.frame.observe(self._on_change, names="value")
        self.marker.observe(self._on_change, names="value")
        self.button.on_click(self._on_place)
        self.widget = widgets.VBox([
            widgets.HBox([self.frame, self.marker]),
            self.overview,
            widgets.HBox([self.enlarged,
                          widgets.VBox([self.x, self.y, self.button, self.message])]),
        ])
        self._refresh(fill=True)

    # ------------------------------------------------------------------ state
    def state(self) -> np.ndarray:
        """``(T, N)`` :class:`~lsmta.tracking.guided.MarkerState` codes of :attr:`tracks`."""
        return tracking_state(self.tracks, placed=self.placed, max_gap=self.params.max_gap)

    def _marker_options(self):
        last = self.state()[-1]
        return [(f"{n} ({MarkerState(int(s)).name.lower().replace('_', ' ')} at the end)", n)
                for n, s in enumerate(last)]

    def place(self, marker: int, frame: int, xy):
        """Place ``marker`` at ``xy`` (2,) px in ``frame`` and resume tracking from it
        (:func:`~lsmta.tracking.guided.resume_from`); updates :attr:`tracks`, :attr:`placed`,
        :attr:`history` and the pictures. Returns the :class:`Resumed`."""
        res = resume_from(self.images, self.tracks, marker, frame, xy, params=self.params,
                          placed=self.placed)
        self.tracks, self.placed = res.tracks, res.placed
        self.history.append(res)
        self.message.value = (f"marker {res.marker} placed in frame {res.frame}"
                              f"{' (refined by its template)' if res.snapped else ''}; tracked "
                              f"in {res.frames_tracked} of the "
                              f"{self.placed.shape[0] - 1 - res.frame} frames after it")
        current = self.marker.value
        self.marker.options = self._marker_options()
        self.marker.value = current
        self._refresh()
        return res

    # ------------------------------------------------------------------ callbacks
    def _on_change(self, _change=None) -> None:
        self._refresh(fill=True)

    def _on_place(self, _button=None) -> None:
        try:
            self.place(self.marker.value, self.frame.value, (self.x.value, self.y.value))
        except ValueError as exc:                  # a click outside the image, say
            self.message.value = f"not placed: {exc}"

    def _refresh(self, *, fill: bool = False) -> None:
        m, f = self.marker.value, self.frame.value
        if fill:
            c = last_known(self.tracks, m, f)
            if np.isfinite(c).all():
                self.x.value, self.y.value = (round(float(v), 2) for v in c)
        fig, ax = plt.subplots(figsize=(8, 3.2), dpi=80)
        draw_state(ax, self.state(), frame=f, marker=m)
        fig.tight_layout()
        self.overview.value = _png(fig)
        fig, ax = plt.subplots(figsize=(3.6, 3.6), dpi=80)
        draw_feature(ax, self.images[0, f], self.tracks, m, f, half=self.half,
                     click=(self.x.value, self.y.value))
        fig.tight_layout()
        self.enlarged.value = _png(fig)

    # ------------------------------------------------------------------ static output
    def static_summary(self, *, marker: int | None = None, frames=None, truth=None):
        """The overview and enlarged views as one matplotlib figure (for static output):
        the state image on top, below the enlarged view of ``marker`` (default: the chosen
        one) in each of ``frames`` (default: the chosen frame); ``truth`` (T, 2) px of that
        marker is drawn if given. Returns the figure."""
        m = self.marker.value if marker is None else marker
        frames = [self.frame.value] if frames is None else list(frames)
        fig = plt.figure(figsize=(max(10, 2.6 * len(frames)), 7.5))
        grid = fig.add_gridspec(2, len(frames), height_ratios=[1.1, 1])
        draw_state(fig.add_subplot(grid[0, :]), self.state(), marker=m)
        for j, f in enumerate(frames):
            ax = fig.add_subplot(grid[1, j])
            click = None
            for r in self.history:
                if r.marker == m and r.frame == f:
                    click = r.click[0]
            draw_feature(ax, self.images[0, f], self.tracks, m, f, half=self.half, click=click,
                         truth=None if truth is None else truth[f])
        fig.tight_layout()
        return fig

    def _repr_mimebundle_(self, **kwargs):
        bundle = self.widget._repr_mimebundle_(**kwargs)
        bundle["text/plain"] = ("GuidedTracker: interactive controls (open the notebook in "
                                "Jupyter to use them; the figure above is the static view)")
        return bundle
