"""The frame of every matplotlib figure: canvas, output checks, shared drawing helpers.

matplotlib comes with the ``viz`` extra (``pip install 'fastdet[viz]'``); this
module imports it at once and fails with :class:`~fastdet.errors.MissingExtraError`
(an ``ImportError`` the command line reports in one line) when it is absent.
Figures are drawn on an Agg canvas created directly, never through ``pyplot``:
no display is needed and the global backend of a program that imports
fastdet is left alone.

Every figure has a size in pixels fixed by its inputs (given in each
function's docstring, at :data:`FIGURE_DPI`), so outputs of different runs
line up, and each is written atomically: a reader never sees half a file.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError, MissingExtraError
from ..files.atomic import atomic_path

MATPLOTLIB_MISSING = "matplotlib is needed for figures: pip install 'fastdet[viz]'"

# The one place fastdet imports matplotlib: the figure modules take what they
# draw with from here, so a missing extra is reported once, the same way.
try:
    from matplotlib import colormaps
    from matplotlib.backend_bases import FigureCanvasBase
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.colors import Normalize, to_rgba
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle
except ImportError as exc:
    raise MissingExtraError(MATPLOTLIB_MISSING) from exc

__all__ = ["CHANNEL_NAMES", "FIGURE_DPI", "GROUP_NAMES", "LineCollection", "Line2D", "Normalize",
           "Rectangle", "ScalarMappable", "box_polygons", "check_output_path", "colormaps",
           "new_figure", "outline_boxes", "rgb", "save_figure", "show_image", "to_rgba"]

#: Dots per inch of every figure; figure sizes below are in pixels at this density.
FIGURE_DPI = 100

#: Channel names of each colour space, for labelling per-channel pictures.
CHANNEL_NAMES = {
    "RGB": ("R", "G", "B"),
    "HSV": ("H", "S", "V"),
    "HLS": ("H", "L", "S"),
    "LUV": ("L", "U", "V"),
    "YCrCb": ("Y", "Cr", "Cb"),
    "YUV": ("Y", "U", "V"),
    "LAB": ("L", "a", "b"),
}

#: Display names of the feature groups, in feature-vector order.
GROUP_NAMES = ("HOG", "spatial", "histogram")


def new_figure(width_px, height_px):
    """An empty matplotlib figure of the given pixel size on an Agg canvas."""
    figure = Figure(figsize=(width_px / FIGURE_DPI, height_px / FIGURE_DPI), dpi=FIGURE_DPI)
    FigureCanvasAgg(figure)
    return figure


def check_output_path(path):
    """Raise :class:`InputError` unless a figure can be written to ``path``.

    Checked before any work is done, so that a typo in ``--out`` fails at
    once rather than after a detector run.  The format follows the suffix:
    ``.png`` and the other formats matplotlib writes (``.svg``, ``.pdf``...).
    A name ending in a slash names a folder and is refused (``Path`` drops
    the slash: ``--out fig.png/`` wrote the file ``fig.png``).
    """
    if os.fspath(path).endswith(("/", os.sep)):
        raise InputError(f"cannot write a figure to {os.fspath(path)}: the name ends in a "
                         "slash, so it names a folder")
    path = Path(path)
    fmt = path.suffix.lstrip(".").lower()
    supported = _supported_formats()
    if fmt not in supported:
        raise InputError(f"cannot write a figure to {path}: the name must end in one of "
                         f"{', '.join('.' + s for s in supported)}")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"output folder not found: {parent}")
    return path


def _supported_formats():
    return sorted(FigureCanvasBase.get_supported_filetypes())


def save_figure(figure, path):
    """Write ``figure`` atomically; returns ``path`` as a Path."""
    path = check_output_path(path)
    with atomic_path(path) as tmp:
        # No bbox_inches='tight': it would make the pixel size depend on the labels.
        figure.savefig(tmp, format=path.suffix.lstrip(".").lower(), dpi=FIGURE_DPI)
    return path


def rgb(image_bgr):
    """BGR (OpenCV) to RGB (matplotlib)."""
    return cv2.cvtColor(image_bgr, cv2.COLOR_BGR2RGB)


def box_polygons(boxes):
    """``(N, 4)`` xyxy boxes (exclusive ends) as closed corner lists for a PolyCollection."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    # Pixel (x, y) covers [x - 0.5, x + 0.5] in imshow coordinates.
    x1, y1, x2, y2 = (boxes[:, 0] - 0.5, boxes[:, 1] - 0.5, boxes[:, 2] - 0.5, boxes[:, 3] - 0.5)
    return np.stack([np.stack([x1, y1], 1), np.stack([x2, y1], 1),
                     np.stack([x2, y2], 1), np.stack([x1, y2], 1)], axis=1)


def outline_boxes(axes, boxes, colours, linewidth=1.0, linestyle="solid", alpha=1.0):
    """Draw unfilled boxes on ``axes`` in one collection (fast for thousands of boxes)."""
    collection = PolyCollection(box_polygons(boxes), closed=True, facecolors="none",
                                edgecolors=colours, linewidths=linewidth, linestyles=linestyle,
                                alpha=alpha)
    axes.add_collection(collection)
    return collection


def show_image(axes, image_rgb, title=None):
    axes.imshow(image_rgb, interpolation="antialiased")
    axes.set_xticks([])
    axes.set_yticks([])
    if title:
        axes.set_title(title, fontsize=11)
