"""Figures of the search and of one detection: ``fastdet viz windows|detect``."""

from __future__ import annotations

import numpy as np

from ..detector.frames import as_bgr_frame
from ..errors import InputError
from ..kernels.label import label_components
from .figure import (Line2D, Normalize, Rectangle, ScalarMappable, check_output_path, colormaps,
                     new_figure, outline_boxes, rgb, save_figure)

# -- viz windows ------------------------------------------------------------
#: Width in pixels of :func:`windows_figure`; the height follows the frame.
WINDOWS_FIGURE_WIDTH = 1280
#: Tallest figure drawn: a frame far taller than wide (10x10000) asked matplotlib
#: for a canvas it could not allocate.
MAX_FIGURE_HEIGHT = 20000


def _checked_height(height, frame_shape):
    if height > MAX_FIGURE_HEIGHT:
        raise InputError(f"a picture of a {frame_shape[1]}x{frame_shape[0]} frame would be "
                         f"{height} pixels tall (at most {MAX_FIGURE_HEIGHT}): the frame is "
                         "too tall for its width")
    return height


def windows_figure_size(frame_shape):
    """``(width, height)`` in pixels of :func:`windows_figure` for a frame of ``frame_shape``."""
    height, width = frame_shape[:2]
    return WINDOWS_FIGURE_WIDTH, _checked_height(
        max(1, round(WINDOWS_FIGURE_WIDTH * height / width)), frame_shape)


def windows_figure(frame_bgr, plans, path):
    """Every search window of every scale drawn on the frame, a colour per scale.

    Parameters
    ----------
    frame_bgr : ndarray of uint8, shape (H, W, 3)
    plans : sequence of ScalePlan
        :meth:`fastdet.detector.detector.Detector.plans` for the frame's size.
    path : str or Path
        Output image file, :func:`windows_figure_size`.

    Returns
    -------
    Path
    """
    check_output_path(path)
    width, height = windows_figure_size(frame_bgr.shape)
    figure = new_figure(width, height)
    axes = figure.add_axes((0, 0, 1, 1))
    # Dimmed so the thin window outlines stand out against the road.
    axes.imshow(rgb((frame_bgr * 0.6).astype(np.uint8)), interpolation="antialiased")
    axes.set_axis_off()
    palette = colormaps["tab10"]
    handles = []
    # Largest windows first so that the small, dense scales are drawn on top.
    order = sorted(range(len(plans)), key=lambda i: -(plans[i].boxes[0, 2] - plans[i].boxes[0, 0]))
    for index in order:
        plan = plans[index]
        colour = palette(index % 10)
        outline_boxes(axes, plan.boxes, [colour], linewidth=0.8, alpha=0.8)
        outline_boxes(axes, [plan.roi], [colour], linewidth=2.0, linestyle="dashed")
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
    return DETECT_FIGURE_WIDTH, _checked_height(4 * (panel_h + _DETECT_TITLE_PX) + 8,
                                                frame_shape)


#: Box colours of the final panel by verdict (see ``detect_figure``'s ``verdicts``).
VERDICT_COLOURS = {"match": "lime", "ignored": "lightgrey", "duplicate": "magenta",
                   "localisation": "orange", "difficult": "yellow", "background": "red"}


def detect_figure(frame_bgr, detector, path, ground_truth=None, verdicts=None):
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
        "difficult": bool}``, as :func:`fastdet.evaluation.annotations.load_annotations`
        gives them), drawn dashed white in the hits and boxes panels
        (dotted when ``difficult``).
    verdicts : callable, optional
        ``verdicts(boxes, scores)`` gives one word per final box (a key of
        :data:`VERDICT_COLOURS`: a match, a box the rules ignore, or a kind
        of false positive), written beside its score and setting its colour.

    Returns
    -------
    Path
    """
    check_output_path(path)
    frame = as_bgr_frame(frame_bgr)
    height, width = frame.shape[:2]
    size = (width, height)
    # The detector's own stages, called one by one to keep what each produced.
    hits = detector.hits(frame)
    heat_region, origin = detector.heat_region(hits, size)
    detections = detector.boxes_from_heat(heat_region, origin, size, frame)
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

    dimmed = rgb((frame * 0.45).astype(np.uint8))
    threshold = detector.config.search.decision_threshold
    truth_note = "; ground truth dashed white (dotted: difficult)" if ground_truth else ""

    axes = panel(0, f"{len(hits.scores)} hit windows of {hits.windows_scored} scored "
                    f"(SVM margin > {threshold:g}){truth_note}", dimmed)
    if len(hits.scores):
        order = np.argsort(hits.scores)  # best drawn last, on top
        norm = Normalize(threshold, max(float(hits.scores.max()), threshold + 1e-3))
        outline_boxes(axes, hits.boxes[order], colormaps["viridis"](norm(hits.scores[order])),
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

    words = verdicts(detections.xyxy, detections.score) if verdicts else [""] * len(detections)
    colours = [VERDICT_COLOURS.get(word, "lime") for word in words]
    shown_as = ("coloured by verdict, heat peak and verdict above each" if verdicts
                else "green, heat peak above each")
    axes = panel(3, f"{len(detections)} detections after the box filters ({shown_as})"
                    f"{truth_note}", rgb(frame))
    _draw_ground_truth(axes, ground_truth)
    if len(detections):
        outline_boxes(axes, detections.xyxy, colours, linewidth=2.0)
        for (x1, y1, _, _), score, word, colour in zip(detections.xyxy.tolist(),
                                                       detections.score.tolist(), words, colours):
            axes.text(x1, y1 - 3, f"{score:.1f} {word}".strip(), color=colour, fontsize=10,
                      va="bottom")
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
            outline_boxes(axes, boxes, ["white"], linewidth=1.5, linestyle=style)
