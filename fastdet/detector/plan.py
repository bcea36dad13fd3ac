"""The search plan: every configured scale laid out on a frame of a given size.

The default search is relative to the frame (:func:`window_regions`): each
window size, a fraction of the frame height, is searched in the band of rows
around the horizon where a vehicle of that size stands, within a reach of the
middle column.  Explicit pixel scales are given for
``config.search.reference_size`` and scaled with the frame
(:func:`scale_regions`).  Either way a plan depends only on the
configuration, the feature options and the frame size;
:class:`~fastdet.detector.detector.Detector` caches one per frame size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..kernels.score import window_count
from .features import WINDOW


@dataclass(frozen=True)
class ScalePlan:
    """One search scale laid out on a frame of a given size.

    Attributes
    ----------
    roi : tuple of int
        ``(x0, y0, x1, y1)`` searched region in frame pixels.
    scaled_size : tuple of int
        ``(width, height)`` the region is resized to.
    step_cells : int
        Window step in HOG cells.
    grid : tuple of int
        ``(ny, nx)`` windows.
    boxes : ndarray of int32, shape (ny * nx, 4)
        Every window of the scale in frame pixels, row-major over the grid.
    heat_weight : float
        Heat a hit adds under ``weighting = 'area'`` (times its margin under
        ``'margin_area'``): ``(64 / side) ** 2`` with the window's side in
        pixels of a ``search.reference_size`` frame, so the same at every
        frame size.
    """

    roi: tuple
    scaled_size: tuple
    step_cells: int
    grid: tuple
    boxes: np.ndarray
    heat_weight: float

    @property
    def n_windows(self):
        return self.grid[0] * self.grid[1]


#: Frame-relative windows smaller than this many pixels are not searched: the
#: search would enlarge them more than four times to the model's 64 pixels,
#: and nothing that small is a vehicle the classifier can tell (at 360 rows
#: the smallest default window is exactly this size).
MIN_WINDOW = 16


def window_regions(search, options, frame_size):
    """``(window, overlap, x0, y0, x1, y1, reference_window)`` of every frame-relative size.

    Pixels of the frame; ``reference_window`` is the side on a
    ``search.reference_size`` frame.

    A window of side ``s`` (``size`` times the frame height ``H``) has its
    top edge between ``horizon * H + band[0] * s`` and ``horizon * H +
    band[1] * s``, widened by ``margin * H`` both ways; its centre lies
    within ``reach * s`` of the middle column.  The number of windows is
    decided here, on the unrounded region measured in window sides, and the
    region is cut to that grid plus a cell of slack: so every frame size of
    one aspect ratio gets the same grid of windows, which the rounding of
    pixel coordinates could otherwise change by a row.  Sizes below
    :data:`MIN_WINDOW` pixels are left out.
    """
    width, height = frame_size
    ppc = options.pixels_per_cell
    cells = WINDOW // ppc
    horizon = search.horizon * height
    margin = search.margin * height
    low, high = search.band
    regions = []
    for window in search.windows:
        side = window.size * height
        if side < MIN_WINDOW - 1e-6:
            continue
        factor = WINDOW / side
        step = _step_cells(window.overlap, cells)
        half_span = search.reach * side + side / 2
        xs = _grid_span(width / 2 - half_span, width / 2 + half_span, width, factor, ppc, step)
        ys = _grid_span(horizon + low * side - margin, horizon + high * side + margin + side,
                        height, factor, ppc, step)
        if xs is not None and ys is not None:
            regions.append((side, window.overlap, xs[0], ys[0], xs[1], ys[1],
                            window.size * search.reference_size[1]))
    return regions


def _grid_span(start, stop, limit, factor, ppc, step):
    """``[start, stop)`` clipped to ``[0, limit)`` and cut to the windows it holds (None: none)."""
    start, stop = max(start, 0.0), min(stop, float(limit))
    cells = WINDOW // ppc
    # A thousandth of a cell of tolerance: a size given as a rounded fraction
    # (64 / 720 = 0.0888889) must still fit 160 cells into 1280 pixels.
    count = window_count(int(math.floor((stop - start) * factor / ppc + 1e-3)), cells, step)
    if count == 0:
        return None
    # Scaled pixels the grid reads, one more for the last cells' outward
    # gradient, and a cell of slack for rounding the region to whole pixels.
    used = ((count - 1) * step + cells) * ppc + 1 + ppc
    return start, min(float(limit), start + used / factor)


def _step_cells(overlap, cells_per_window):
    return max(1, int(round((1.0 - overlap) * cells_per_window)))


def scale_regions(search, frame_size):
    """``(window, overlap, x0, y0, x1, y1, reference_window)`` of every explicit pixel scale.

    Scale coordinates are given for ``search.reference_size`` and scaled
    proportionally (window sides by the geometric mean of the two axis
    factors).
    """
    width, height = frame_size
    ref_w, ref_h = search.reference_size
    kx, ky = width / ref_w, height / ref_h
    k = math.sqrt(kx * ky)
    return [(scale.window * k, scale.overlap, scale.x[0] * kx, scale.y[0] * ky,
             scale.x[1] * kx, scale.y[1] * ky, scale.window) for scale in search.scales]


def plan_scales(config, options, frame_size):
    """Lay every configured window size out on a frame of ``(width, height)``.

    The frame-relative windows (:func:`window_regions`), or the explicit
    pixel scales (:func:`scale_regions`) when the configuration lists any.
    Regions are clipped to the frame; sizes with no whole window in the
    frame are dropped (all of them for a frame without pixels).  An
    ``"auto"`` horizon must have been resolved (a :class:`ConfigError`).
    """
    search = config.search
    if search.auto_horizon:
        raise ConfigError('search.horizon "auto" is estimated from the frames by fastdet run, '
                          'eval, detect and batch; here give a number (in code, call '
                          'Detector.resolve_horizon(frames) first)')
    width, height = frame_size
    if width <= 0 or height <= 0:
        return ()  # no pixel, no window
    regions = (scale_regions(search, frame_size) if search.scales
               else window_regions(search, options, frame_size))
    ppc = options.pixels_per_cell
    cells_per_window = WINDOW // ppc
    plans = []
    for window, overlap, rx0, ry0, rx1, ry1, reference_window in regions:
        x0 = int(np.clip(round(rx0), 0, width))
        x1 = int(np.clip(round(rx1), 0, width))
        y0 = int(np.clip(round(ry0), 0, height))
        y1 = int(np.clip(round(ry1), 0, height))
        if x1 <= x0 or y1 <= y0:
            continue
        factor = WINDOW / window
        scaled_w, scaled_h = int(round((x1 - x0) * factor)), int(round((y1 - y0) * factor))
        step_cells = _step_cells(overlap, cells_per_window)
        ny = window_count(scaled_h // ppc, cells_per_window, step_cells)
        nx = window_count(scaled_w // ppc, cells_per_window, step_cells)
        if ny == 0 or nx == 0:
            continue
        # Trim the region to what the window grid covers, plus one scaled pixel
        # so the last row and column of cells keep their outward gradient:
        # pixels no window reads are neither resized nor histogrammed.
        step_px = step_cells * ppc
        used_w = (nx - 1) * step_px + WINDOW + 1
        used_h = (ny - 1) * step_px + WINDOW + 1
        trimmed_x1 = x0 + math.ceil(used_w / factor)
        if used_w < scaled_w and trimmed_x1 < x1:
            x1 = trimmed_x1
            scaled_w = min(used_w, int(round((x1 - x0) * factor)))
        trimmed_y1 = y0 + math.ceil(used_h / factor)
        if used_h < scaled_h and trimmed_y1 < y1:
            y1 = trimmed_y1
            scaled_h = min(used_h, int(round((y1 - y0) * factor)))
        fx, fy = scaled_w / (x1 - x0), scaled_h / (y1 - y0)
        px = np.arange(nx) * step_px
        py = np.arange(ny) * step_px
        gx1 = np.round(x0 + px / fx)
        gx2 = np.round(x0 + (px + WINDOW) / fx)
        gy1 = np.round(y0 + py / fy)
        gy2 = np.round(y0 + (py + WINDOW) / fy)
        boxes = np.empty((ny, nx, 4), dtype=np.int32)
        boxes[..., 0] = gx1[None, :]
        boxes[..., 1] = gy1[:, None]
        boxes[..., 2] = gx2[None, :]
        boxes[..., 3] = gy2[:, None]
        plans.append(ScalePlan((x0, y0, x1, y1), (scaled_w, scaled_h), step_cells, (ny, nx),
                               boxes.reshape(-1, 4), (WINDOW / reference_window) ** 2))
    return tuple(plans)


def search_band(plans):
    """``(x0, y0, x1, y1)``: the bounding box of every plan's region (``None`` without plans)."""
    if not plans:
        return None
    return (min(plan.roi[0] for plan in plans), min(plan.roi[1] for plan in plans),
            max(plan.roi[2] for plan in plans), max(plan.roi[3] for plan in plans))
