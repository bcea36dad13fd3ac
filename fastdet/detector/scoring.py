"""Per-scale scoring: a frame's searched region -> SVM margins of every window of a scale.

The region any scale searches is colour-converted once per frame
(:meth:`ScaleScorer.prepare`); each scale's part of it is then resized so the
scale's window becomes 64 pixels (:func:`fastdet.kernels.resize.resize_linear`,
bit-identical to OpenCV's bilinear resize), its HOG cells computed once, and
every window scored from them (:mod:`fastdet.kernels.score`), plus the colour
features' part of the score (:mod:`fastdet.kernels.colour`).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from ..kernels.colour import colour_maps
from ..kernels.hog import cell_histograms, phase_layout_shape
from ..kernels.resize import resize_linear
from ..kernels.score import (
    add_hog_scores_from_phase_cells,
    add_spatial_scores,
    add_tile_window_sums,
    phase_scoring_pad,
)
from .features import WINDOW, color_planes, histogram_bin_lut, hog_input
from .plan import search_band

#: Work arrays kept before they are all dropped (see ScaleScorer._buffer).
_MAX_BUFFERS = 64

#: Names of the timed stages, in pipeline order.
STAGES = ("resize_convert", "cells", "blocks_score", "colour_score", "heat", "label", "total")


@dataclass
class PreparedFrame:
    """A frame's searched region, colour-converted once for all scales."""

    converted: np.ndarray | None  # uint8 (h, w, 3) in the model's colour space
    grey: np.ndarray | None       # uint8 (h, w), only for grey HOG
    origin: tuple                 # (x0, y0) of the region in the frame


@dataclass
class Hits:
    """Windows whose SVM margin passed the decision threshold."""

    boxes: np.ndarray      # int32 (N, 4) frame pixels
    scores: np.ndarray     # float32 (N,) SVM margins
    scale_index: np.ndarray  # int64 (N,) index into the frame's scale plans
    windows_scored: int


class ScaleScorer:
    """Scores the windows of one scale plan at a time, for one model.

    Parameters
    ----------
    model : fastdet.detector.model.Model

    Notes
    -----
    Work arrays are kept per thread and plan object and reused from frame to
    frame, so any number of threads may score with one scorer at once, the
    same plan included.
    """

    def __init__(self, model):
        self.model = model
        options = model.options
        self.options = options
        hog_w, spatial_w, hist_w = model.split_weights()
        self._hog_weights = np.ascontiguousarray(hog_w)
        self._spatial_weights = np.ascontiguousarray(spatial_w)
        self._hist_lut = None
        if options.hist_bins:
            bins = histogram_bin_lut(options.hist_bins)
            self._hist_lut = np.ascontiguousarray(hist_w[:, bins], dtype=np.float32)
        self._hog_channels = model.layout.hog_channels
        self._local = threading.local()

    def _buffer(self, plan, kind, shape, dtype):
        """A scale's work array, reused from frame to frame.

        Fresh multi-megabyte arrays every frame would cost page faults;
        callers get the array back filled, so the reuse is invisible.  Each
        thread has its own arrays per plan object, so scales scored
        concurrently (by the detector's pool, or by callers sharing one
        detector between threads) never share one; the plan is kept with
        them so that a recycled ``id`` of a discarded plan is never mistaken
        for a live one.
        """
        workspace = getattr(self._local, "workspace", None)
        if workspace is None:
            workspace = self._local.workspace = {}
        key = (kind, id(plan))
        entry = workspace.get(key)
        if entry is None or entry[0] is not plan:
            if len(workspace) > _MAX_BUFFERS:
                # Plans made outside Detector.plans() (e.g. by callers of score_scale).
                workspace.clear()
            entry = workspace[key] = (plan, np.empty(shape, dtype))
        return entry[1]

    def _resized_buffer(self, plan, channels):
        """The uint8 array a scale's region is resized into."""
        width, height = plan.scaled_size
        return self._buffer(plan, ("resized", channels), (height, width, channels), np.uint8)

    def scaled_region(self, region, plan, channels):
        """A scale's region resized to ``plan.scaled_size``; at scale 1, the
        region itself when its rows are contiguous (a full-width region)."""
        width, height = plan.scaled_size
        if region.shape[:2] == (height, width) and region.flags.c_contiguous:
            return region
        # Bit-identical to cv2.resize(..., INTER_LINEAR), in about half its time.
        return resize_linear(region, plan.scaled_size,
                             out=self._resized_buffer(plan, channels))

    def _cells_buffer(self, plan):
        """The phase-layout cell array of a scale."""
        shape = phase_layout_shape(*self._cell_grid(plan), self._hog_channels,
                                   self.options.orientations, plan.step_cells,
                                   self._phase_pad(plan))
        return self._buffer(plan, "cells", shape, np.float32)

    def _cell_grid(self, plan):
        """``(rows, columns)`` of HOG cells of a scale's resized region."""
        ppc = self.options.pixels_per_cell
        return plan.scaled_size[1] // ppc, plan.scaled_size[0] // ppc

    def _phase_pad(self, plan):
        cpb = self.options.cells_per_block
        return phase_scoring_pad(self._cell_grid(plan)[1], plan.step_cells, (cpb, cpb))

    def prepare(self, frame, plans):
        """Colour-convert the part of a frame any of ``plans`` searches, once.

        Returns
        -------
        PreparedFrame
        """
        band = search_band(plans)
        if band is None:
            return PreparedFrame(None, None, (0, 0))
        x0, y0, x1, y1 = band
        converted, grey = color_planes(frame[y0:y1, x0:x1], self.options)
        return PreparedFrame(converted, grey, (x0, y0))

    def score_scale(self, prepared, plan, timings):
        """SVM margins of every window of one scale, shape ``plan.grid``.

        Parameters
        ----------
        prepared : PreparedFrame
            From :meth:`prepare`.
        plan : ScalePlan
            A plan for the prepared frame's size.
        timings : dict
            Stage seconds (keys of :data:`STAGES`) are added here.
        """
        options = self.options
        t0 = time.perf_counter()
        ox, oy = prepared.origin
        x0, y0, x1, y1 = plan.roi
        region = (slice(y0 - oy, y1 - oy), slice(x0 - ox, x1 - ox))
        converted = self.scaled_region(prepared.converted[region], plan, 3)
        grey = None
        if prepared.grey is not None:
            grey = self.scaled_region(prepared.grey[region][:, :, None], plan, 1)
        t1 = time.perf_counter()
        timings["resize_convert"] += t1 - t0
        scores = np.full(plan.grid, self.model.bias, dtype=np.float32)
        step_px = plan.step_cells * options.pixels_per_cell
        if options.use_hog:
            ppc, cpb = options.pixels_per_cell, options.cells_per_block
            # Cells in the phase layout of the window step, so each block row
            # is normalised and scored along whole rows, never writing the
            # block map to memory.
            cells = cell_histograms(hog_input(converted, grey, options), (ppc, ppc),
                                    options.orientations, out=self._cells_buffer(plan),
                                    phase_step=plan.step_cells,
                                    phase_pad=self._phase_pad(plan))
            t2 = time.perf_counter()
            add_hog_scores_from_phase_cells(cells, plan.scaled_size[0] // ppc, (cpb, cpb),
                                            options.block_norm, self._hog_weights,
                                            plan.step_cells, scores)
            timings["cells"] += t2 - t1
            t1 = time.perf_counter()
            timings["blocks_score"] += t1 - t2
        if options.spatial_size or options.hist_bins:
            tile = math.gcd(step_px, WINDOW)
            factor = WINDOW // options.spatial_size if options.spatial_size else 0
            tiles, spatial = colour_maps(converted, self._hist_lut, tile, factor)
            if options.spatial_size:
                add_spatial_scores(spatial, self._spatial_weights, step_px // factor, scores)
            if options.hist_bins:
                add_tile_window_sums(tiles, WINDOW // tile, step_px // tile, scores)
        timings["colour_score"] += time.perf_counter() - t1
        return scores
