"""Figures of the training data and the features: ``fastdet viz samples|hog|features``."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from ..detector.features import WINDOW, color_planes, crop_features, hog_input
from ..errors import InputError
from ..files.images import read_image
from ..kernels.hog import cell_histograms
from .figure import (CHANNEL_NAMES, GROUP_NAMES, LineCollection, check_output_path, new_figure,
                     rgb, save_figure, show_image, to_rgba)

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
    dataset : fastdet.training.dataset.Dataset
        From :func:`fastdet.training.train.list_dataset`.
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
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))
                             or seed < 0):
        raise InputError(f"the seed must be a whole number >= 0, got {seed!r}")
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
            image = read_image(crop_path)
            axes.imshow(rgb(image), interpolation="nearest")
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


def glyph_cell_px(cells_shape, panel_px, ppc):
    """Side in pixels of a rendered cell of :func:`hog_glyphs` in a panel of ``panel_px``.

    Enough pixels per cell to fill the panel along the side that has fewer
    per cell, and at least one cell's own pixels: the glyph picture is then
    at most about the panel's size, or the image's, whichever is larger.  Sized
    by the width alone, the 1250 cells of an image 10 pixels wide and 10000 tall
    got 480 pixels each: a 600000x480 picture built from 2.6 GB of stamps.
    """
    rows, cols = cells_shape[:2]
    panel_w, panel_h = panel_px
    return max(ppc, math.ceil(min(panel_w / cols, panel_h / rows)))


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
    show_image(panel(0), rgb(covered), f"image {image_bgr.shape[1]}x{image_bgr.shape[0]}")
    cell_px = glyph_cell_px(cells.shape, (panel_w, panel_h), ppc)
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
    show_image(figure.add_subplot(header[0, 0]), rgb(crop),
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
