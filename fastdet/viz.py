"""Pictures: boxes on frames, the live debug view, and the ``fastdet viz`` figures.

Two kinds of picture live here:

* OpenCV drawings on BGR frames, cheap enough for every frame of a video:
  :func:`draw_detections` and :func:`debug_frame` (``fastdet run --debug-view``).
* matplotlib figures written to image files, for looking at the training
  data, the features, the search and the results: :func:`samples_figure`,
  :func:`hog_figure`, :func:`features_figure`, :func:`windows_figure`,
  :func:`detect_figure` and :func:`training_report_figure`.

matplotlib is an optional dependency (``pip install 'fastdet[viz]'``),
imported only inside the figure functions.  Figures are drawn on an Agg
canvas created directly, never through ``pyplot``: no display is needed and
the global backend of a program that imports fastdet is left alone.

Every figure has a size in pixels fixed by its inputs (given in each
function's docstring, at :data:`FIGURE_DPI`), so outputs of different runs
line up, and each is written atomically: a reader never sees half a file.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from .atomic import atomic_path
from .errors import InputError

#: BGR colours cycled by track id.
_PALETTE = ((0, 0, 255), (0, 200, 0), (255, 0, 0), (0, 200, 255), (255, 0, 255),
            (255, 255, 0), (0, 128, 255), (128, 0, 255))

#: Dots per inch of every figure; figure sizes below are in pixels at this density.
FIGURE_DPI = 100

MATPLOTLIB_MISSING = "matplotlib is needed for fastdet viz: pip install 'fastdet[viz]'"

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


# -- frames (OpenCV) --------------------------------------------------------
def draw_detections(frame, detections, thickness=3):
    """Draw boxes (and track ids when present) on a copy of a BGR frame.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
    detections : Detections
    thickness : int

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
    """
    canvas = frame.copy()
    draw_detections_inplace(canvas, detections, thickness)
    return canvas


def draw_detections_inplace(canvas, detections, thickness=3):
    """Like :func:`draw_detections`, drawing on ``canvas`` itself."""
    for i, (x1, y1, x2, y2) in enumerate(detections.xyxy.tolist()):
        track = None if detections.track_id is None else int(detections.track_id[i])
        colour = _PALETTE[(track if track is not None else 0) % len(_PALETTE)]
        cv2.rectangle(canvas, (x1, y1), (x2 - 1, y2 - 1), colour, thickness)
        label = f"#{track}" if track is not None else f"{detections.score[i]:.1f}"
        cv2.putText(canvas, label, (x1, max(y1 - 6, 12)), cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2,
                    cv2.LINE_AA)
    return canvas


def write_image(path, image):
    """Write an image atomically; the format follows ``path``'s suffix."""
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(image)):
            raise InputError(f"cannot write image {path} (unsupported extension?)")


def debug_frame(frame, detections, heat, timings_ms, heat_max=None):
    """A frame annotated for watching the detector live.

    Draws the detections, an inset of the heat map in the top-right corner
    and the per-stage timings as text in the top-left corner.  OpenCV only,
    a few milliseconds per 1280x720 frame, so it can run on every frame.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
        BGR frame (not modified).
    detections : Detections
        Boxes to draw (with track ids when present).
    heat : ndarray of float, shape (h, w), or None
        Heat map to show in the inset, normally the full-frame one
        (:meth:`fastdet.detect.Detector.heatmap`); ``None`` or an empty array
        shows an empty inset.
    timings_ms : mapping of str to float
        Stage name to milliseconds, printed in the given order.
    heat_max : float, optional
        Heat shown as the brightest colour.  Default: the map's own maximum;
        pass a constant (e.g. a few times the heat threshold) to stop the
        inset's brightness from changing with every frame's maximum.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        A new annotated BGR frame.
    """
    from .detect import as_bgr_frame

    canvas = as_bgr_frame(frame).copy()
    height, width = canvas.shape[:2]
    # Text and inset follow the frame size so a 640-pixel frame is not all caption.
    text_scale = max(0.35, 0.5 * width / 1280)
    draw_detections_inplace(canvas, detections, thickness=max(1, round(2 * width / 1280)))
    _draw_heat_inset(canvas, heat, heat_max, text_scale)
    _draw_timings(canvas, timings_ms, text_scale)
    return canvas


def _draw_heat_inset(canvas, heat, heat_max, text_scale):
    """Colour-mapped heat, a quarter of the frame's width, in the top-right corner."""
    height, width = canvas.shape[:2]
    heat = np.zeros((1, 1), np.float32) if heat is None or np.size(heat) == 0 else heat
    heat = np.asarray(heat, dtype=np.float32)
    if heat.ndim != 2:
        raise InputError(f"heat must be a 2-D array, got shape {heat.shape}")
    inset_w = max(16, width // 4)
    inset_h = max(9, min(height // 2, round(inset_w * heat.shape[0] / max(heat.shape[1], 1))))
    if inset_w + 8 > width or inset_h + 8 > height:
        return  # frame too small to hold an inset
    peak = float(heat.max()) if heat_max is None else float(heat_max)
    scaled = cv2.resize(heat, (inset_w, inset_h), interpolation=cv2.INTER_AREA)
    level = np.clip(scaled * (255.0 / peak if peak > 0 else 0.0), 0, 255).astype(np.uint8)
    x0, y0 = width - inset_w - 4, 4
    canvas[y0:y0 + inset_h, x0:x0 + inset_w] = cv2.applyColorMap(level, cv2.COLORMAP_INFERNO)
    cv2.rectangle(canvas, (x0 - 1, y0 - 1), (x0 + inset_w, y0 + inset_h), (255, 255, 255), 1)
    cv2.putText(canvas, f"heat (max {float(heat.max()):.1f})", (x0 + 4, y0 + inset_h - 6),
                cv2.FONT_HERSHEY_SIMPLEX, text_scale, (255, 255, 255), 1, cv2.LINE_AA)


def _draw_timings(canvas, timings_ms, text_scale):
    """Stage timings on a darkened box in the top-left corner, numbers right-aligned."""
    if not timings_ms:
        return
    font = cv2.FONT_HERSHEY_SIMPLEX
    lines = [(str(name), f"{float(ms):.1f} ms") for name, ms in timings_ms.items()]
    line_h = int(round(26 * text_scale / 0.5))
    name_w = max(cv2.getTextSize(name, font, text_scale, 1)[0][0] for name, _ in lines)
    value_w = max(cv2.getTextSize(value, font, text_scale, 1)[0][0] for _, value in lines)
    box_w, box_h = name_w + value_w + 30, line_h * len(lines) + 10
    box_w, box_h = min(box_w, canvas.shape[1]), min(box_h, canvas.shape[0])
    # Darken rather than paint over, so the road under the text stays visible.
    canvas[:box_h, :box_w] = (canvas[:box_h, :box_w] * 0.35).astype(np.uint8)
    for row, (name, value) in enumerate(lines):
        baseline = 5 + line_h * (row + 1) - line_h // 4
        cv2.putText(canvas, name, (8, baseline), font, text_scale, (255, 255, 255), 1, cv2.LINE_AA)
        value_x = box_w - 8 - cv2.getTextSize(value, font, text_scale, 1)[0][0]
        cv2.putText(canvas, value, (value_x, baseline), font, text_scale, (120, 255, 120), 1,
                    cv2.LINE_AA)


# -- figures (matplotlib) ---------------------------------------------------
def new_figure(width_px, height_px):
    """An empty matplotlib figure of the given pixel size on an Agg canvas."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise InputError(MATPLOTLIB_MISSING) from None
    figure = Figure(figsize=(width_px / FIGURE_DPI, height_px / FIGURE_DPI), dpi=FIGURE_DPI)
    FigureCanvasAgg(figure)
    return figure


def check_output_path(path):
    """Raise :class:`InputError` unless a figure can be written to ``path``.

    Checked before any work is done, so that a typo in ``--out`` fails at
    once rather than after a detector run.  The format follows the suffix:
    ``.png`` and the other formats matplotlib writes (``.svg``, ``.pdf``...).
    """
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
    try:
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError:
        raise InputError(MATPLOTLIB_MISSING) from None
    return sorted(FigureCanvasBase.get_supported_filetypes())


def save_figure(figure, path):
    """Write ``figure`` atomically; returns ``path`` as a Path."""
    path = check_output_path(path)
    with atomic_path(path) as tmp:
        # No bbox_inches='tight': it would make the pixel size depend on the labels.
        figure.savefig(tmp, format=path.suffix.lstrip(".").lower(), dpi=FIGURE_DPI)
    return path


def _rgb(image_bgr):
    """BGR (OpenCV) to RGB (matplotlib)."""
    return cv2.cvtColor(image_bgr, cv2.COLOR_BGR2RGB)


def _box_polygons(boxes):
    """``(N, 4)`` xyxy boxes (exclusive ends) as closed corner lists for a PolyCollection."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    # Pixel (x, y) covers [x - 0.5, x + 0.5] in imshow coordinates.
    x1, y1, x2, y2 = (boxes[:, 0] - 0.5, boxes[:, 1] - 0.5, boxes[:, 2] - 0.5, boxes[:, 3] - 0.5)
    return np.stack([np.stack([x1, y1], 1), np.stack([x2, y1], 1),
                     np.stack([x2, y2], 1), np.stack([x1, y2], 1)], axis=1)


def _outline_boxes(axes, boxes, colours, linewidth=1.0, linestyle="solid", alpha=1.0):
    """Draw unfilled boxes on ``axes`` in one collection (fast for thousands of boxes)."""
    from matplotlib.collections import PolyCollection

    collection = PolyCollection(_box_polygons(boxes), closed=True, facecolors="none",
                                edgecolors=colours, linewidths=linewidth, linestyles=linestyle,
                                alpha=alpha)
    axes.add_collection(collection)
    return collection


def _show_image(axes, image_rgb, title=None):
    axes.imshow(image_rgb, interpolation="antialiased")
    axes.set_xticks([])
    axes.set_yticks([])
    if title:
        axes.set_title(title, fontsize=11)


# -- viz samples ------------------------------------------------------------
#: Pixel size of one crop's cell in the samples grid (crop plus its file name).
SAMPLE_CELL = (150, 175)
#: Most crops per row of the samples grid.
SAMPLE_COLUMNS = 8


def samples_figure_size(n):
    """``(width, height)`` in pixels of :func:`samples_figure` with ``n`` crops per class."""
    columns = min(n, SAMPLE_COLUMNS)
    rows = 2 * math.ceil(n / columns)
    return columns * SAMPLE_CELL[0] + 40, rows * SAMPLE_CELL[1] + 50


def samples_figure(dataset, path, n=8, seed=None):
    """Grid of random vehicle and non-vehicle crops with their file names.

    Parameters
    ----------
    dataset : fastdet.train.Dataset
        From :func:`fastdet.train.list_dataset`.
    path : str or Path
        Output image file.
    n : int
        Crops per class (8 per row; the figure is :func:`samples_figure_size`).
    seed : int, optional
        Seed of the random choice; a fresh one (shown in the title) if ``None``.

    Returns
    -------
    Path
        ``path``.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 256:
        raise InputError(f"the number of crops per class must be in 1..256, got {n!r}")
    if seed is None:
        # Drawn here (not left to the generator) so the title can show it for a re-run.
        seed = int(np.random.default_rng().integers(2**31))
    rng = np.random.default_rng(seed)
    check_output_path(path)
    width, height = samples_figure_size(n)
    figure = new_figure(width, height)
    columns = min(n, SAMPLE_COLUMNS)
    rows_per_class = math.ceil(n / columns)
    grid = figure.subplots(2 * rows_per_class, columns, squeeze=False)
    figure.subplots_adjust(left=40 / width, right=1 - 4 / width, bottom=4 / height,
                           top=1 - 50 / height, wspace=0.06, hspace=0.22)
    classes = ((1, "vehicles", "tab:green"), (0, "non-vehicles", "tab:red"))
    for block, (label, name, colour) in enumerate(classes):
        members = np.flatnonzero(np.asarray(dataset.labels) == label)
        chosen = rng.choice(members, size=min(n, members.size), replace=False)
        for slot in range(rows_per_class * columns):
            axes = grid[block * rows_per_class + slot // columns, slot % columns]
            axes.set_xticks([])
            axes.set_yticks([])
            if slot % columns == 0:
                axes.set_ylabel(name, fontsize=11, color=colour)
            if slot >= chosen.size:
                axes.set_axis_off()
                continue
            crop_path = Path(dataset.paths[chosen[slot]])
            image = cv2.imread(str(crop_path), cv2.IMREAD_COLOR)
            if image is None:
                raise InputError(f"cannot read {crop_path} as an image")
            axes.imshow(_rgb(image), interpolation="nearest")
            # Folder and name: the folder is the crop's source (GTI_Far, KITTI...).
            axes.set_title("/".join(crop_path.parts[-2:]), fontsize=7)
            for spine in axes.spines.values():
                spine.set_edgecolor(colour)
                spine.set_linewidth(2)
    counts = np.bincount(np.asarray(dataset.labels, dtype=np.int64), minlength=2)
    figure.suptitle(f"{counts[1]} vehicle and {counts[0]} non-vehicle crops: {n} random of each "
                    f"(seed {seed})", fontsize=12)
    return save_figure(figure, path)


# -- viz hog ----------------------------------------------------------------
def glyph_stamps(nbins, cell_px, levels):
    """Line glyphs of every orientation bin at every length level.

    Parameters
    ----------
    nbins : int
        Unsigned orientation bins over 0-180 degrees.
    cell_px : int
        Side of a rendered cell in pixels.
    levels : int
        Number of line lengths; level ``k`` is ``k / levels`` of the longest
        (level 0 draws nothing).

    Returns
    -------
    ndarray of uint8, shape (nbins, levels + 1, cell_px, cell_px)
    """
    stamps = np.zeros((nbins, levels + 1, cell_px, cell_px), dtype=np.uint8)
    centre = (cell_px - 1) / 2.0
    radius = cell_px / 2.0 - 1.0
    thickness = max(1, cell_px // 24)
    shift = 4  # OpenCV fixed-point bits: sub-pixel end points keep short glyphs symmetric
    for o in range(nbins):
        # The kernel's orientation is atan2(gy, gx) with y pointing down; an
        # edge runs perpendicular to its gradient, so the glyph's direction in
        # (x, y-down) is (-sin, cos) of the bin's mid angle.
        angle = math.pi * (o + 0.5) / nbins
        dx, dy = -math.sin(angle), math.cos(angle)
        for level in range(1, levels + 1):
            half = radius * level / levels
            ends = [(round((centre + sign * half * dx) * (1 << shift)),
                     round((centre + sign * half * dy) * (1 << shift))) for sign in (-1, 1)]
            cv2.line(stamps[o, level], ends[0], ends[1], 255, thickness, cv2.LINE_AA, shift)
    return stamps


def hog_glyphs(cells, cell_px, levels=16):
    """Render one channel's cell histograms as orientation glyphs.

    Each cell gets, for every orientation bin, a line through its centre
    perpendicular to the bin's gradient direction (along the edge), of
    length proportional to the bin's value.  Lengths are relative to the
    99th percentile of the channel's non-zero bins, so that a few strong
    edges do not shrink every other glyph to a dot.

    Parameters
    ----------
    cells : ndarray of float, shape (Hc, Wc, nbins)
        From :func:`fastdet.kernels.hog.cell_histograms` (one channel).
    cell_px : int
        Side of a rendered cell in pixels.
    levels : int
        Number of distinct line lengths (lengths are quantised so the
        picture is a sum of precomputed stamps rather than a line per bin).

    Returns
    -------
    ndarray of float32, shape (Hc * cell_px, Wc * cell_px)
        Glyph image in [0, 1].
    """
    cells = np.asarray(cells, dtype=np.float32)
    rows, cols, nbins = cells.shape
    positive = cells[cells > 0]
    reference = float(np.percentile(positive, 99)) if positive.size else 1.0
    level = np.clip(np.floor(cells / reference * levels), 0, levels).astype(np.intp)
    stamps = glyph_stamps(nbins, cell_px, levels)
    # (rows, cols, nbins, px, px): each bin's stamp at its level; overlapping
    # lines of one cell take the brighter value rather than saturating.
    glyphs = stamps[np.arange(nbins), level].max(axis=2)
    image = glyphs.transpose(0, 2, 1, 3).reshape(rows * cell_px, cols * cell_px)
    return image.astype(np.float32) / 255.0


#: Pixels above each panel of :func:`hog_figure` (its title) and above the grid (the caption).
_HOG_TITLE_PX, _HOG_CAPTION_PX = 30, 40


def _hog_panel_px(image_shape, options):
    """Pixel ``(width, height)`` of the picture in one panel of :func:`hog_figure`."""
    height, width = image_shape[:2]
    cells_x = max(1, width // options.pixels_per_cell)
    # About 10 screen pixels per cell so glyphs stay readable, within sane bounds.
    panel_w = int(np.clip(cells_x * 10, 480, 1280))
    aspect = float(np.clip(height / width, 0.25, 4.0))
    return panel_w, int(round(panel_w * aspect))


def hog_figure_size(image_shape, options):
    """``(width, height)`` in pixels of :func:`hog_figure` for an image of ``image_shape``.

    Two panels per row (the image, then one per HOG channel), each
    :func:`_hog_panel_px` plus a title line, under a caption line.
    """
    panel_w, panel_h = _hog_panel_px(image_shape, options)
    panels = 1 + (3 if options.hog_channel == "all" else 1)
    return 2 * panel_w, math.ceil(panels / 2) * (panel_h + _HOG_TITLE_PX) + _HOG_CAPTION_PX


def hog_figure(image_bgr, options, path):
    """The image beside the HOG glyphs of each channel the features use.

    Parameters
    ----------
    image_bgr : ndarray of uint8, shape (H, W, 3)
    options : FeatureOptions
        Colour space, HOG channel(s), cell size and bins (a model's options).
    path : str or Path
        Output image file; the figure is :func:`hog_figure_size`.

    Returns
    -------
    Path
    """
    from .features import color_planes, hog_input
    from .kernels.hog import cell_histograms

    check_output_path(path)
    ppc = options.pixels_per_cell
    if image_bgr.shape[0] < ppc or image_bgr.shape[1] < ppc:
        raise InputError(f"the image ({image_bgr.shape[1]}x{image_bgr.shape[0]}) is smaller than "
                         f"one {ppc}-pixel HOG cell")
    converted, grey = color_planes(np.ascontiguousarray(image_bgr), options)
    cells = cell_histograms(np.ascontiguousarray(hog_input(converted, grey, options)), (ppc, ppc),
                            options.orientations)
    if options.hog_channel == "all":
        names = [f"{options.color_space} {c}" for c in CHANNEL_NAMES[options.color_space]]
    elif options.hog_channel == "gray":
        names = ["grey"]
    else:
        names = [f"{options.color_space} {CHANNEL_NAMES[options.color_space][options.hog_channel]}"]

    width, height = hog_figure_size(image_bgr.shape, options)
    panel_w, panel_h = _hog_panel_px(image_bgr.shape, options)
    figure = new_figure(width, height)

    def panel(index):
        # Exact pixel rectangles: fractions of a gridspec would let titles
        # collide with the caption at some image aspects.
        row, col = divmod(index, 2)
        top = height - _HOG_CAPTION_PX - row * (panel_h + _HOG_TITLE_PX) - _HOG_TITLE_PX
        return figure.add_axes((col * panel_w / width + 0.002, (top - panel_h) / height,
                                panel_w / width - 0.004, panel_h / height))

    # Pixels beyond the last whole cell are ignored by the kernel; crop the
    # picture the same way so image and glyphs line up.
    covered = image_bgr[:cells.shape[0] * ppc, :cells.shape[1] * ppc]
    _show_image(panel(0), _rgb(covered), f"image {image_bgr.shape[1]}x{image_bgr.shape[0]}")
    cell_px = max(ppc, math.ceil(panel_w / cells.shape[1]))
    for index, name in enumerate(names, start=1):
        axes = panel(index)
        axes.imshow(hog_glyphs(cells[:, :, index - 1], cell_px), cmap="gray", vmin=0, vmax=1,
                    interpolation="antialiased")
        axes.set_xticks([])
        axes.set_yticks([])
        axes.set_title(f"HOG of {name}", fontsize=11)
    used = "" if options.use_hog else " (this model does not use HOG)"
    figure.text(0.5, 1 - 10 / height,
                f"{options.orientations} orientations, {ppc}-pixel cells; line length "
                f"proportional to the bin, relative to each channel's 99th percentile{used}",
                ha="center", va="top", fontsize=11)
    return save_figure(figure, path)


# -- viz features -----------------------------------------------------------
#: Pixel size of :func:`features_figure`.
FEATURES_FIGURE_SIZE = (1400, 900)


def features_figure(image_bgr, model, path):
    """A 64x64 crop's raw feature vector and each feature's contribution to its score.

    The model's weights have the training scaler folded in, so
    ``features * weights`` is exactly what each feature adds to the SVM
    margin ``bias + sum(features * weights)``.

    Parameters
    ----------
    image_bgr : ndarray of uint8, shape (H, W, 3)
        The crop; resized to 64x64 (INTER_AREA, as training does) if needed.
    model : Model
    path : str or Path
        Output image file, :data:`FEATURES_FIGURE_SIZE`.

    Returns
    -------
    Path
    """
    from matplotlib.collections import LineCollection
    from matplotlib.colors import to_rgba

    from .features import WINDOW, crop_features

    check_output_path(path)
    crop = np.ascontiguousarray(image_bgr)
    if crop.shape[:2] != (WINDOW, WINDOW):
        crop = cv2.resize(crop, (WINDOW, WINDOW), interpolation=cv2.INTER_AREA)
    features = crop_features(crop, model.options).astype(np.float64)
    contributions = features * model.weights.astype(np.float64)
    margin = model.bias + contributions.sum()
    edges = np.concatenate([[0], np.cumsum(model.layout.sizes)])
    groups = [(name, edges[i], edges[i + 1]) for i, name in enumerate(GROUP_NAMES)
              if edges[i + 1] > edges[i]]

    figure = new_figure(*FEATURES_FIGURE_SIZE)
    total = features.size
    # Each group gets its own column, at least a quarter of the width: the 96
    # histogram bins would be a sliver on an axis shared with 5000 HOG values.
    widths = [max(stop - start, total / 4) for _, start, stop in groups]
    layout = figure.add_gridspec(3, len(groups), height_ratios=(0.6, 1, 1), width_ratios=widths,
                                 left=0.075, right=0.99, bottom=0.06, top=0.97, hspace=0.35,
                                 wspace=0.2)
    header = layout[0, :].subgridspec(1, 5, wspace=0.3)
    _show_image(figure.add_subplot(header[0, 0]), _rgb(crop),
                f"crop {image_bgr.shape[1]}x{image_bgr.shape[0]}"
                + (" -> 64x64" if image_bgr.shape[:2] != (WINDOW, WINDOW) else ""))
    summary = figure.add_subplot(header[0, 1:])
    summary.set_axis_off()
    verdict = "vehicle" if margin > 0 else "non-vehicle"
    lines = [f"SVM margin {margin:+.3f}  ->  {verdict}", f"bias {model.bias:+.3f}"]
    for name, start, stop in groups:
        part = contributions[start:stop]
        lines.append(f"{name} ({stop - start} features): sum {part.sum():+.3f}, "
                     f"positive {part[part > 0].sum():+.3f}, negative {part[part < 0].sum():+.3f}")
    top = np.argsort(-np.abs(contributions))[:3]
    lines.append("largest single contributions: "
                 + ", ".join(f"#{i} ({_group_of(i, groups)}) {contributions[i]:+.3f}" for i in top))
    summary.text(0.0, 0.9, "\n".join(lines), va="top", ha="left", fontsize=12, family="monospace",
                 transform=summary.transAxes)

    shared_contribution_axis = None
    for column, (name, start, stop) in enumerate(groups):
        index = np.arange(start, stop)
        raw = figure.add_subplot(layout[1, column])
        # Raw values: each group on its own linear scale (HOG ~0-0.3, spatial
        # pixels 0-255, histogram counts in the thousands).
        raw.plot(index, features[start:stop], linewidth=0.5, color="tab:blue")
        raw.set_title(f"raw {name}", fontsize=11)
        part = contributions[start:stop]
        contribution = figure.add_subplot(layout[2, column], sharex=raw,
                                          sharey=shared_contribution_axis)
        shared_contribution_axis = shared_contribution_axis or contribution
        # One LineCollection from an (N, 2, 2) array: ``vlines`` builds a masked
        # array per line, seconds for the ~8000 features.
        stems = np.zeros((part.size, 2, 2))
        stems[:, :, 0] = index[:, None]
        stems[:, 1, 1] = part
        contribution.add_collection(LineCollection(
            stems, linewidths=0.6, colors=np.where((part >= 0)[:, None], to_rgba("tab:green"),
                                                   to_rgba("tab:red"))))
        contribution.autoscale_view()
        contribution.axhline(0, color="black", linewidth=0.5)
        contribution.set_title(f"{name} x weight (sum {part.sum():+.3f})", fontsize=11)
        contribution.set_xlabel("feature index")
        raw.set_xlim(start - 0.5, stop - 0.5)
        if name == GROUP_NAMES[2]:
            # One histogram per colour channel, side by side.
            bins = model.options.hist_bins
            for axes in (raw, contribution):
                for boundary in range(start + bins, stop, bins):
                    axes.axvline(boundary - 0.5, color="gray", linestyle=":", linewidth=0.8)
        if column == 0:
            raw.set_ylabel("raw value")
            contribution.set_ylabel("contribution to the margin\n(green: towards vehicle)")
    return save_figure(figure, path)


def _group_of(index, groups):
    for name, start, stop in groups:
        if start <= index < stop:
            return name
    return "?"


# -- viz windows ------------------------------------------------------------
#: Width in pixels of :func:`windows_figure`; the height follows the frame.
WINDOWS_FIGURE_WIDTH = 1280


def windows_figure_size(frame_shape):
    """``(width, height)`` in pixels of :func:`windows_figure` for a frame of ``frame_shape``."""
    height, width = frame_shape[:2]
    return WINDOWS_FIGURE_WIDTH, max(1, round(WINDOWS_FIGURE_WIDTH * height / width))


def windows_figure(frame_bgr, plans, path):
    """Every search window of every scale drawn on the frame, a colour per scale.

    Parameters
    ----------
    frame_bgr : ndarray of uint8, shape (H, W, 3)
    plans : sequence of ScalePlan
        :meth:`fastdet.detect.Detector.plans` for the frame's size.
    path : str or Path
        Output image file, :func:`windows_figure_size`.

    Returns
    -------
    Path
    """
    from matplotlib import colormaps
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle

    check_output_path(path)
    width, height = windows_figure_size(frame_bgr.shape)
    figure = new_figure(width, height)
    axes = figure.add_axes((0, 0, 1, 1))
    # Dimmed so the thin window outlines stand out against the road.
    axes.imshow(_rgb((frame_bgr * 0.6).astype(np.uint8)), interpolation="antialiased")
    axes.set_axis_off()
    palette = colormaps["tab10"]
    handles = []
    # Largest windows first so that the small, dense scales are drawn on top.
    order = sorted(range(len(plans)), key=lambda i: -(plans[i].boxes[0, 2] - plans[i].boxes[0, 0]))
    for index in order:
        plan = plans[index]
        colour = palette(index % 10)
        _outline_boxes(axes, plan.boxes, [colour], linewidth=0.8, alpha=0.8)
        _outline_boxes(axes, [plan.roi], [colour], linewidth=2.0, linestyle="dashed")
    for index, plan in enumerate(plans):
        # One window per scale filled, spread along the bottom rows, so each
        # scale's window size can be seen in the mesh of outlines.
        ny, nx = plan.grid
        column = int(round((index + 0.5) / len(plans) * (nx - 1)))
        example = plan.boxes[(ny - 1) * nx + column]
        axes.add_patch(Rectangle((example[0] - 0.5, example[1] - 0.5), example[2] - example[0],
                                 example[3] - example[1], facecolor=palette(index % 10),
                                 alpha=0.45, edgecolor=palette(index % 10), linewidth=2.5))
    for index, plan in enumerate(plans):
        side = int(plan.boxes[0, 2] - plan.boxes[0, 0])
        step = int(plan.boxes[1, 0] - plan.boxes[0, 0]) if plan.grid[1] > 1 else side
        handles.append(Line2D([], [], color=palette(index % 10), linewidth=3,
                              label=f"scale {index}: {side} px, step {step} px, "
                                    f"{plan.grid[0]}x{plan.grid[1]} = {plan.n_windows} windows"))
    total = sum(plan.n_windows for plan in plans)
    axes.legend(handles=handles, loc="upper left", fontsize=10, framealpha=0.85,
                title=f"{total} windows in {len(plans)} scales\n"
                      "(dashed: searched region; filled: one window)")
    axes.set_xlim(-0.5, frame_bgr.shape[1] - 0.5)
    axes.set_ylim(frame_bgr.shape[0] - 0.5, -0.5)
    return save_figure(figure, path)


# -- viz detect -------------------------------------------------------------
#: Width in pixels of :func:`detect_figure`, and of the frame in each of its panels.
DETECT_FIGURE_WIDTH, _DETECT_PANEL_WIDTH = 1600, 1420
#: Pixels above each panel of :func:`detect_figure` (its title) and rows of frame kept
#: above and below the searched band.
_DETECT_TITLE_PX, _DETECT_PAD_ROWS = 34, 16


def detect_view_rows(frame_shape, plans):
    """``(y0, y1)``: the rows of a frame :func:`detect_figure` shows.

    Only the band the scales search (plus a margin) can hold hits, heat or
    boxes; leaving out the sky and the bonnet makes the cars larger.
    """
    height = frame_shape[0]
    if not plans:
        return 0, height
    y0 = min(plan.roi[1] for plan in plans) - _DETECT_PAD_ROWS
    y1 = max(plan.roi[3] for plan in plans) + _DETECT_PAD_ROWS
    return max(0, y0), min(height, y1)


def detect_figure_size(frame_shape, plans):
    """``(width, height)`` in pixels of :func:`detect_figure`.

    Parameters
    ----------
    frame_shape : tuple
        Shape of the frame.
    plans : sequence of ScalePlan
        The detector's plans for the frame's size.
    """
    y0, y1 = detect_view_rows(frame_shape, plans)
    panel_h = round(_DETECT_PANEL_WIDTH * (y1 - y0) / frame_shape[1])
    return DETECT_FIGURE_WIDTH, 4 * (panel_h + _DETECT_TITLE_PX) + 8


def detect_figure(frame_bgr, detector, path, ground_truth=None):
    """The detector's stages on one frame, in four panels.

    Top to bottom: the hit windows coloured by SVM margin; the heat map with
    its threshold; the labelled components of the thresholded heat; the
    final boxes.  Panels show the band of rows the scales search.

    Parameters
    ----------
    frame_bgr : ndarray of uint8, shape (H, W, 3)
    detector : Detector
    path : str or Path
        Output image file, :func:`detect_figure_size`.
    ground_truth : list of dict, optional
        Annotated objects of the frame (``{"box": [x1, y1, x2, y2],
        "difficult": bool}``, as :func:`fastdet.evaluate.load_annotations`
        gives them), drawn dashed white in the hits and boxes panels
        (dotted when ``difficult``).

    Returns
    -------
    Path
    """
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    from .detect import as_bgr_frame
    from .kernels.label import label_components

    check_output_path(path)
    frame = as_bgr_frame(frame_bgr)
    height, width = frame.shape[:2]
    size = (width, height)
    # The detector's own stages, called one by one to keep what each produced.
    hits = detector.hits(frame)
    heat_region, origin = detector.heat_region(hits, size)
    detections = detector.boxes_from_heat(heat_region, origin, size)
    heat = np.zeros((height, width), np.float32)
    heat[origin[1]:origin[1] + heat_region.shape[0],
         origin[0]:origin[0] + heat_region.shape[1]] = heat_region
    heat_config = detector.config.heat
    labels, n_components = label_components(heat > heat_config.threshold,
                                            heat_config.connectivity)

    plans = detector.plans(size)
    view_y0, view_y1 = detect_view_rows(frame.shape, plans)
    figure_w, figure_h = detect_figure_size(frame.shape, plans)
    panel_h = (figure_h - 8) // 4 - _DETECT_TITLE_PX
    figure = new_figure(figure_w, figure_h)

    frame_panels = []

    def panel_rect(row, left_px, width_px):
        # Exact pixel rectangles keep the four frames the same size and aligned,
        # whether or not a panel has a colour bar.
        top = figure_h - row * (panel_h + _DETECT_TITLE_PX) - _DETECT_TITLE_PX
        return (left_px / figure_w, (top - panel_h) / figure_h, width_px / figure_w,
                panel_h / figure_h)

    def panel(row, title, image_rgb):
        axes = figure.add_axes(panel_rect(row, 10, _DETECT_PANEL_WIDTH))
        # The panel already has the view's aspect; 'auto' stops imshow from
        # shrinking the axes by a rounding pixel.
        axes.imshow(image_rgb, aspect="auto")
        axes.set_xticks([])
        axes.set_yticks([])
        axes.set_title(title, fontsize=12)
        frame_panels.append(axes)
        return axes

    def colour_bar(row, mappable, label):
        bar = figure.add_axes(panel_rect(row, _DETECT_PANEL_WIDTH + 30, 16))
        figure.colorbar(mappable, cax=bar, label=label)

    dimmed = _rgb((frame * 0.45).astype(np.uint8))
    threshold = detector.config.search.decision_threshold
    truth_note = "; ground truth dashed white (dotted: difficult)" if ground_truth else ""

    axes = panel(0, f"{len(hits.scores)} hit windows of {hits.windows_scored} scored "
                    f"(SVM margin > {threshold:g}){truth_note}", dimmed)
    if len(hits.scores):
        order = np.argsort(hits.scores)  # best drawn last, on top
        norm = Normalize(threshold, max(float(hits.scores.max()), threshold + 1e-3))
        _outline_boxes(axes, hits.boxes[order], colormaps["viridis"](norm(hits.scores[order])),
                       linewidth=1.2)
        colour_bar(0, ScalarMappable(norm, "viridis"), "SVM margin")
    _draw_ground_truth(axes, ground_truth)

    axes = panel(1, f"heat ({heat_config.weighting} weighting); cyan: threshold "
                    f"{heat_config.threshold:g}", dimmed)
    if heat.max() > 0:
        shown = axes.imshow(np.ma.masked_equal(heat, 0), cmap="inferno", alpha=0.85,
                            interpolation="nearest", vmin=0, vmax=float(heat.max()),
                            aspect="auto")
        colour_bar(1, shown, "heat")
        if heat.max() > heat_config.threshold:
            axes.contour(heat, levels=[heat_config.threshold], colors="cyan", linewidths=0.8)

    axes = panel(2, f"{n_components} connected components of heat > {heat_config.threshold:g} "
                    f"({heat_config.connectivity}-connected)", dimmed)
    if n_components:
        # A qualitative map, cycled, so neighbouring labels get different colours.
        axes.imshow((np.ma.masked_equal(labels, 0) - 1) % 20, cmap="tab20", vmin=0, vmax=19,
                    alpha=0.8, interpolation="nearest", aspect="auto")

    axes = panel(3, f"{len(detections)} detections after the box filters (green, heat peak "
                    f"above each){truth_note}", _rgb(frame))
    _draw_ground_truth(axes, ground_truth)
    if len(detections):
        _outline_boxes(axes, detections.xyxy, ["lime"], linewidth=2.0)
        for (x1, y1, _, _), score in zip(detections.xyxy.tolist(), detections.score.tolist()):
            axes.text(x1, y1 - 3, f"{score:.1f}", color="lime", fontsize=10, va="bottom")
    for axes in frame_panels:
        axes.set_xlim(-0.5, width - 0.5)
        axes.set_ylim(view_y1 - 0.5, view_y0 - 0.5)
    return save_figure(figure, path)


def _draw_ground_truth(axes, ground_truth):
    """Annotated boxes dashed white; 'difficult' ones (neither required nor penalised) dotted."""
    if not ground_truth:
        return
    for difficult, style in ((False, "dashed"), (True, "dotted")):
        boxes = [obj["box"] for obj in ground_truth if bool(obj.get("difficult")) == difficult]
        if boxes:
            _outline_boxes(axes, boxes, ["white"], linewidth=1.5, linestyle=style)


# -- training report --------------------------------------------------------
#: Pixel size of :func:`training_report_figure`.
TRAINING_REPORT_SIZE = (1500, 520)


def training_report_figure(model_report, test_scores, test_labels, path):
    """Decision-score histograms, confusion matrix and accuracy figures of a training run.

    Parameters
    ----------
    model_report : dict
        :attr:`fastdet.model.Model.report` (any keys; the known ones, such as
        ``random_split`` and ``leak_free_split``, are listed by name).
    test_scores : array_like of float, shape (N,)
        SVM margins of the held-out crops.
    test_labels : array_like, shape (N,)
        Their classes: 1 for vehicle; 0 (or -1) for non-vehicle.
    path : str or Path
        Output image file, :data:`TRAINING_REPORT_SIZE`.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        When the scores and labels are empty, of different lengths, not
        finite, or the labels are not binary.
    """
    scores = np.asarray(test_scores, dtype=np.float64).reshape(-1)
    labels = np.asarray(test_labels).reshape(-1)
    if scores.size == 0 or scores.shape != labels.shape:
        raise InputError(f"need one label per test score, got {scores.size} scores and "
                         f"{labels.size} labels")
    if not np.all(np.isfinite(scores)):
        raise InputError("test scores must be finite")
    if not np.isin(labels.astype(np.float64), (-1, 0, 1)).all():
        raise InputError(f"test labels must be 1 (vehicle) or 0/-1 (non-vehicle), "
                         f"got values {np.unique(labels)[:5].tolist()}")
    check_output_path(path)
    vehicle = labels.astype(np.float64) == 1
    predicted = scores > 0
    true_pos = int(np.sum(vehicle & predicted))
    false_neg = int(np.sum(vehicle & ~predicted))
    false_pos = int(np.sum(~vehicle & predicted))
    true_neg = int(np.sum(~vehicle & ~predicted))

    figure = new_figure(*TRAINING_REPORT_SIZE)
    layout = figure.add_gridspec(1, 3, width_ratios=(1.5, 0.9, 1.3), left=0.05, right=0.99,
                                 bottom=0.12, top=0.9, wspace=0.25)
    axes = figure.add_subplot(layout[0])
    bins = np.linspace(scores.min(), scores.max(), 61) if np.ptp(scores) > 0 else 10
    for members, colour, name in ((vehicle, "tab:orange", "vehicles"),
                                  (~vehicle, "tab:blue", "non-vehicles")):
        axes.hist(scores[members], bins=bins, histtype="stepfilled", alpha=0.45, color=colour,
                  edgecolor=colour, linewidth=1.2, label=f"{name} ({int(members.sum())})")
    axes.axvline(0, color="black", linestyle="--", linewidth=1, label="decision boundary")
    cv = model_report.get("cross_validation")
    if isinstance(cv, dict) and isinstance(cv.get("threshold"), (int, float)) and cv["threshold"]:
        axes.axvline(cv["threshold"], color="tab:purple", linestyle=":", linewidth=1.5,
                     label=f"cross-validated threshold {cv['threshold']:+.3f}")
    # Log counts: the few misclassified crops near 0 are what matters, and
    # they would vanish next to the two tall modes on a linear axis.
    axes.set_yscale("log")
    axes.set_ylim(top=axes.get_ylim()[1] * 8)  # head-room for the legend
    axes.set_xlabel("SVM margin")
    axes.set_ylabel("test crops")
    axes.set_title("decision scores on the test split", fontsize=11)
    axes.legend(fontsize=9, loc="upper left", framealpha=0.9)

    axes = figure.add_subplot(layout[1])
    matrix = np.array([[true_pos, false_neg], [false_pos, true_neg]])
    rates = matrix / np.maximum(matrix.sum(axis=1, keepdims=True), 1)
    axes.imshow(rates, cmap="Blues", vmin=0, vmax=1)
    for row in range(2):
        for col in range(2):
            axes.text(col, row, f"{matrix[row, col]}\n{rates[row, col]:.1%}", ha="center",
                      va="center", fontsize=12, color="white" if rates[row, col] > 0.5 else "black")
    axes.set_xticks([0, 1], ["vehicle", "non-vehicle"])
    axes.set_yticks([0, 1], ["vehicle", "non-vehicle"])
    axes.set_xlabel("predicted (margin > 0)")
    axes.set_ylabel("true class")
    axes.set_title("confusion matrix", fontsize=11)

    axes = figure.add_subplot(layout[2])
    axes.set_axis_off()
    total = scores.size
    precision = true_pos / max(true_pos + false_pos, 1)
    recall = true_pos / max(true_pos + false_neg, 1)
    lines = [f"{'these test scores:':19}{total} crops",
             f"{'accuracy:':19}{(true_pos + true_neg) / total:.4f}",
             f"{'precision:':19}{precision:.4f}",
             f"{'recall:':19}{recall:.4f}",
             f"{'false positives:':19}{false_pos}",
             f"{'false negatives:':19}{false_neg}", "", "model report:"]
    lines += _report_lines(model_report)
    axes.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", family="monospace", fontsize=10,
              transform=axes.transAxes)
    axes.set_title("accuracy figures", fontsize=11, loc="left")
    return save_figure(figure, path)


def _report_lines(report):
    """Readable lines of a training report: splits first, then other scalar entries."""
    lines = []
    for key, title in (("random_split", "random split"), ("leak_free_split", "leak-free split")):
        split = report.get(key)
        if isinstance(split, dict) and "accuracy" in split:
            detail = (f" ({split['test_crops']} test crops)" if "test_crops" in split else "")
            lines.append(f"{title + ':':19}{float(split['accuracy']):.4f}{detail}")
    cv = report.get("cross_validation")
    if isinstance(cv, dict) and "C" in cv:
        lines.append(f"{'cross-validated:':19}C {float(cv['C']):g}"
                     + (f", threshold {float(cv['threshold']):+.3f}" if "threshold" in cv else ""))
    for key, value in report.items():
        if (key in ("random_split", "leak_free_split") or value is None
                or isinstance(value, (dict, list))):
            continue
        text = f"{value:.4g}" if isinstance(value, float) else str(value)
        lines.append(f"{key.replace('_', ' ') + ':':19}{text}"[:46])
    return lines
