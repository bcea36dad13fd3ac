"""The search plan: every configured scale laid out on a frame of a given size.

Scale coordinates are given for ``config.search.reference_size`` and scaled
with the frame, so a plan depends only on the configuration, the feature
options and the frame size; :class:`~fastdet.detector.detector.Detector`
caches one per frame size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

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
        Heat a hit adds under ``weighting = 'area'``: (64 / window side)**2.
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


def plan_scales(config, options, frame_size):
    """Lay every configured scale out on a frame of ``(width, height)``.

    Scale coordinates are given for ``config.search.reference_size`` and
    scaled proportionally (window sides by the geometric mean of the two
    axis factors).  Scales with no whole window in the frame are dropped (all
    of them for a frame without pixels).
    """
    width, height = frame_size
    if width <= 0 or height <= 0:
        return ()  # no pixel, no window
    ref_w, ref_h = config.search.reference_size
    kx, ky = width / ref_w, height / ref_h
    k = math.sqrt(kx * ky)
    ppc = options.pixels_per_cell
    cells_per_window = WINDOW // ppc
    plans = []
    for scale in config.search.scales:
        window = scale.window * k
        x0 = int(np.clip(round(scale.x[0] * kx), 0, width))
        x1 = int(np.clip(round(scale.x[1] * kx), 0, width))
        y0 = int(np.clip(round(scale.y[0] * ky), 0, height))
        y1 = int(np.clip(round(scale.y[1] * ky), 0, height))
        factor = WINDOW / window
        scaled_w, scaled_h = int(round((x1 - x0) * factor)), int(round((y1 - y0) * factor))
        step_cells = max(1, int(round((1.0 - scale.overlap) * cells_per_window)))
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
                               boxes.reshape(-1, 4), (WINDOW / window) ** 2))
    return tuple(plans)


def search_band(plans):
    """``(x0, y0, x1, y1)``: the bounding box of every plan's region (``None`` without plans)."""
    if not plans:
        return None
    return (min(plan.roi[0] for plan in plans), min(plan.roi[1] for plan in plans),
            max(plan.roi[2] for plan in plans), max(plan.roi[3] for plan in plans))
