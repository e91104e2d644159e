"""Frames of the deformed block: surface quads coloured by displacement, tool/target/goal marked.

matplotlib with the Agg canvas (no display needed); every frame of a renderer has the same shape:
``FRAME_SIZE`` x ``FRAME_SIZE`` x 3 (uint8), or ``FRAME_SIZE`` x ``KEY_FRAME_WIDTH`` x 3 with the key
(``key=True``: a legend of the markers drawn and a colour bar of the displacement, in mm, on the
right). The colour range is ``scale`` (m, full colour; the tasks pass the largest tool offset their
workspace allows, ``TissueEnv.render_scale``); larger displacements take the top colour, which the
colour bar's arrow marks. The figure is built once and only its artists are updated per frame,
which keeps rendering well above 5 frames/s. ``legend_handles`` and ``colour_bar`` draw the same
key on a figure of one's own (``training.demo``'s episode strip).
"""

from __future__ import annotations

import numpy as np

FRAME_SIZE = 256
#: the width (pixels) of a frame with its key
KEY_FRAME_WIDTH = 384
_DPI = 64
COLORMAP = "viridis"
MARKER_STYLE = {
    "tool": dict(color="black", marker="v", s=60),
    "tumor": dict(color="red", marker="o", s=40),
    "goal": dict(color="lime", marker="*", s=90),
    "inclusion": dict(color="red", marker="x", s=50),
}
#: what a legend calls each marker (a marker not listed: its name) and each extra drawing
LABELS = {"tool": "tool", "tumor": "tumour (hidden)", "goal": "goal", "inclusion": "inclusion (hidden)",
          "rectangle": "target region", "segment": "needle path"}
DEFAULT_STYLE = dict(color="orange", marker="s", s=40)
LINE_STYLE = dict(color="red", lw=1.5)


def legend_handles(markers, extras=()):
    """matplotlib proxies and labels ``(handles, labels)`` of the named ``markers`` (names or a
    dict keyed by name) and of the kinds of ``extras`` ((kind, data) items), for ``legend``."""
    from matplotlib.lines import Line2D

    handles, labels = [], []
    for name in markers:
        style = MARKER_STYLE.get(name, DEFAULT_STYLE)
        handles.append(Line2D([], [], linestyle="none", marker=style["marker"], color=style["color"],
                              markersize=float(np.sqrt(style["s"]))))
        labels.append(LABELS.get(name, name))
    for kind in dict.fromkeys(kind for kind, _ in extras):
        handles.append(Line2D([], [], **LINE_STYLE))
        labels.append(LABELS.get(kind, kind))
    return handles, labels


def colour_bar(figure, scale, cax=None, ax=None, **kwargs):
    """A colour bar of the frames' displacement colours on ``figure`` (in ``cax``, or beside
    ``ax``): 0 to ``scale`` m, labelled in mm, with an arrow for the displacements past it."""
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    mappable = ScalarMappable(Normalize(0.0, 1e3 * scale), matplotlib.colormaps[COLORMAP])
    bar = figure.colorbar(mappable, cax=cax, ax=ax, extend="max", **kwargs)
    bar.set_label("displacement (mm)")
    return bar


class Renderer:
    """Draw ``positions`` (N, 3) m of a block's surface; ``values`` (N,) m colour the quads, full
    colour at ``scale`` m (default a fifth of the block's largest side); ``key`` adds a legend and a
    colour bar to the right of the view."""

    def __init__(self, faces, size, centre, human=False, fps=10, scale=None, key=False):
        import matplotlib

        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        self.faces = np.asarray(faces)
        self.key = bool(key)
        width = KEY_FRAME_WIDTH if self.key else FRAME_SIZE
        self.figure = Figure(figsize=(width / _DPI, FRAME_SIZE / _DPI), dpi=_DPI)
        self.canvas = FigureCanvasAgg(self.figure)
        self.axes = self.figure.add_axes((0, 0, FRAME_SIZE / width, 1), projection="3d")
        half = 0.75 * float(np.max(size))
        # Scene coordinates: x right, z into the screen, y up (matplotlib's 3D z is up).
        self.axes.set_xlim(centre[0] - half, centre[0] + half)
        self.axes.set_ylim(centre[2] - half, centre[2] + half)
        self.axes.set_zlim(centre[1] - half, centre[1] + half)
        self.axes.set_box_aspect((1, 1, 1))
        self.axes.view_init(elev=25, azim=-60)
        self.axes.set_axis_off()
        # Markers (tool, goal, hidden tumour) are drawn over the tissue rather than depth-sorted.
        self.axes.computed_zorder = False
        self.colormap = matplotlib.colormaps[COLORMAP]
        self.scale = 0.2 * float(np.max(size)) if scale is None else float(scale)  # displacement of full colour, m
        if not self.scale > 0:
            raise ValueError(f"scale must be a positive displacement in m, got {scale!r}")
        self.legend = None
        if self.key:
            left = (FRAME_SIZE + 8) / width
            colour_bar(self.figure, self.scale, cax=self.figure.add_axes((left, 0.06, 0.05, 0.5)))
        self.collection = Poly3DCollection(np.zeros((len(self.faces), 4, 3)), edgecolor="k", linewidths=0.2)
        self.axes.add_collection3d(self.collection)
        self.markers = {}
        self.extras = []
        self.human = human
        self.fps = fps
        self._window = None

    def draw(self, positions, values, markers, extras=()):
        quads = positions[self.faces][..., [0, 2, 1]]
        self.collection.set_verts(quads)
        colour = np.clip(values[self.faces].mean(axis=1) / self.scale, 0.0, 1.0)
        self.collection.set_facecolor(self.colormap(colour))
        for artist in self.markers.values():
            artist.remove()
        self.markers = {}
        for name, point in markers.items():
            point = np.asarray(point, dtype=float)
            style = MARKER_STYLE.get(name, DEFAULT_STYLE)
            self.markers[name] = self.axes.scatter([point[0]], [point[2]], [point[1]], depthshade=False, zorder=10, **style)
        for artist in self.extras:
            artist.remove()
        self.extras = []
        for kind, data in extras:
            if kind == "rectangle":  # (x0, x1, z0, z1, y) horizontal rectangle, e.g. a target region
                x0, x1, z0, z1, y = data
                (line,) = self.axes.plot([x0, x1, x1, x0, x0], [z0, z0, z1, z1, z0], [y] * 5, zorder=0, **LINE_STYLE)
                self.extras.append(line)
            elif kind == "segment":  # ((3,), (3,)) m: a straight path, e.g. a planned needle path
                start, end = np.asarray(data, dtype=float)
                (line,) = self.axes.plot([start[0], end[0]], [start[2], end[2]], [start[1], end[1]], zorder=11,
                                         **LINE_STYLE)
                self.extras.append(line)
        if self.key:
            if self.legend is not None:
                self.legend.remove()
            self.legend = self.figure.legend(*legend_handles(markers, extras), loc="upper right", fontsize=9,
                                             frameon=False, borderaxespad=0.2, handletextpad=0.3)
        self.canvas.draw()
        frame = np.asarray(self.canvas.buffer_rgba())[..., :3].copy()
        if self.human:
            self._show(frame)
        return frame

    def _show(self, frame):
        import matplotlib.pyplot as plt

        if self._window is None:
            plt.ion()
            figure, axes = plt.subplots()
            axes.set_axis_off()
            self._window = (figure, axes.imshow(frame))
        self._window[1].set_data(frame)
        plt.pause(1.0 / self.fps)

    def close(self):
        if self._window is not None:
            import matplotlib.pyplot as plt

            plt.close(self._window[0])
            self._window = None


class FrameRendering:
    """``TissueEnv``'s frames (a mixin): ``render`` for the ``render_mode``, the colour range
    ``render_scale`` and the ``render_legend``; a task names its points in ``_markers`` and its
    other drawings in ``_extra_drawing``."""

    def _markers(self) -> dict:
        """Named points (m) to draw: tool, target, goal ..."""
        return {}

    def render(self):
        if self.render_mode is None:
            import gymnasium as gym

            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to gym.make")
            return None
        self._require_reset("render()")
        if self.render_mode == "depth_array":
            return self._worlds.camera_images()[1][0].astype(np.float32)
        if self._renderer is None:
            self._renderer = Renderer(self._surface_faces, self.mesh.size, self.centre,
                                      human=self.render_mode == "human", fps=self.metadata["render_fps"],
                                      scale=self.render_scale, key=self.render_key)
        positions = self.state.positions[:self.episode_mesh.n_nodes]  # a cut's copied nodes follow (not drawn)
        displacement = np.linalg.norm(positions - self.episode_mesh.nodes, axis=1)
        frame = self._renderer.draw(positions, displacement, self._markers(), self._extra_drawing())
        return frame if self.render_mode == "rgb_array" else None

    def _extra_drawing(self):
        """Optional (kind, data) items the renderer draws (floor, target region ...)."""
        return []

    @property
    def render_scale(self) -> float:
        """The displacement (m) of full colour in the rendered frames: the largest tool offset along
        one axis that the workspace allows (the grasped tissue moves with the tool), so that the
        colours do not saturate within an episode of the task."""
        return float(np.max(np.maximum(np.abs(self.workspace_low), np.abs(self.workspace_high))))

    def render_legend(self):
        """``(handles, labels)`` for a matplotlib legend of what the frames mark now (tool, goal,
        hidden tumour, target region ...; ``rendering.legend_handles``)."""
        self._require_reset("render_legend()")
        return legend_handles(self._markers(), self._extra_drawing())

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
