"""Frames of the deformed block: surface quads coloured by displacement, tool/target/goal marked.

matplotlib with the Agg canvas (no display needed); every frame has the same shape
(``FRAME_SIZE`` x ``FRAME_SIZE`` x 3, uint8). The figure is built once and only its artists are
updated per frame, which keeps rendering well above 5 frames/s.
"""

from __future__ import annotations

import numpy as np

FRAME_SIZE = 256
_DPI = 64
MARKER_STYLE = {
    "tool": dict(color="black", marker="v", s=60),
    "tumor": dict(color="red", marker="o", s=40),
    "goal": dict(color="lime", marker="*", s=90),
    "inclusion": dict(color="red", marker="x", s=50),
}


class Renderer:
    """Draw ``positions`` (N, 3) m of a block's surface; ``values`` (N,) colour the quads."""

    def __init__(self, faces, size, centre, human=False, fps=10):
        import matplotlib

        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        self.faces = np.asarray(faces)
        self.figure = Figure(figsize=(FRAME_SIZE / _DPI, FRAME_SIZE / _DPI), dpi=_DPI)
        self.canvas = FigureCanvasAgg(self.figure)
        self.axes = self.figure.add_axes((0, 0, 1, 1), projection="3d")
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
        self.colormap = matplotlib.colormaps["viridis"]
        self.scale = 0.2 * float(np.max(size))  # displacement of full colour, m
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
            style = MARKER_STYLE.get(name, dict(color="orange", marker="s", s=40))
            self.markers[name] = self.axes.scatter([point[0]], [point[2]], [point[1]], depthshade=False, zorder=10, **style)
        for artist in self.extras:
            artist.remove()
        self.extras = []
        for kind, data in extras:
            if kind == "rectangle":  # (x0, x1, z0, z1, y) horizontal rectangle, e.g. a target region
                x0, x1, z0, z1, y = data
                (line,) = self.axes.plot([x0, x1, x1, x0, x0], [z0, z0, z1, z1, z0], [y] * 5, color="red", lw=1.5, zorder=0)
                self.extras.append(line)
            elif kind == "segment":  # ((3,), (3,)) m: a straight path, e.g. a planned needle path
                start, end = np.asarray(data, dtype=float)
                (line,) = self.axes.plot([start[0], end[0]], [start[2], end[2]], [start[1], end[1]], color="red",
                                         lw=1.5, zorder=11)
                self.extras.append(line)
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
