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


def kernel_families(options):
    """The kernel families (:data:`fastdet.kernels.warmup.FAMILIES`) detection with ``options`` runs."""
    families = ["resize", "heat", "label"]
    if options.color_space == "HLS":
        families.append("convert")
    if options.use_hog and options.hog_channel == "all" and (
            options.pixels_per_cell, options.orientations, options.cells_per_block,
            options.block_norm) == (8, 9, 2, "L2-Hys"):
        # The warm-up's shapes; other settings compile at their first frame.
        families += ["hog", "score"]
    if options.spatial_size or options.hist_bins:
        families.append("colour")
    return tuple(families)


@dataclass(frozen=True)
class ScaleBand:
    """Window rows ``first`` .. ``stop - 1`` of the scale plan at ``index``: one task of a frame.

    ``slot`` picks the band's work arrays (bands of one plan run at once);
    ``pixels``: the resized pixels it computes, its estimated cost.
    """

    index: int
    first: int
    stop: int
    slot: int
    pixels: int


def scale_bands(plans, pixels_per_cell, threads):
    """A frame's scoring tasks for ``threads`` threads, costliest first.

    With one thread, one band per scale.  With more, a scale costing more
    than ``1 / (2 * threads)`` of the frame (the 48-px scale of the default
    search: 45 % of the resized pixels) is cut into bands of window rows,
    so that the threads, taking the next task as they finish one, end
    together.  A band recomputes the cell rows it shares with the next
    (``window - step`` pixels), which is why only large scales are cut.
    """
    def pixels(plan, first, stop):
        step_px = plan.step_cells * pixels_per_cell
        return ((stop - 1 - first) * step_px + WINDOW) * plan.scaled_size[0]

    total = sum(pixels(plan, 0, plan.grid[0]) for plan in plans)
    bands = []
    for index, plan in enumerate(plans):
        rows = plan.grid[0]
        whole = pixels(plan, 0, rows)
        count = 1
        if threads > 1 and total:
            count = min(rows, max(1, math.ceil(whole * 2 * threads / total)))
        for part in range(count):
            first, stop = part * rows // count, (part + 1) * rows // count
            bands.append(ScaleBand(index, first, stop, part, pixels(plan, first, stop)))
    return tuple(sorted(bands, key=lambda band: -band.pixels))


class ScaleScorer:
    """Scores the windows of one scale plan at a time, for one model.

    Parameters
    ----------
    model : fastdet.detector.model.Model

    Notes
    -----
    Work arrays are kept per plan object and reused from frame to frame, so
    one scorer may score different plans concurrently (one thread per plan)
    but not the same plan twice at once.
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
        self._workspace = {}

    def _buffer(self, plan, kind, shape, dtype, slot=0):
        """A scale's work array, reused from frame to frame.

        Fresh multi-megabyte arrays every frame would cost page faults;
        callers get the array back filled, so the reuse is invisible.  Each
        plan object (and each ``slot``: bands of one plan computed at once)
        has its own arrays, so work scored concurrently never shares one;
        the plan is kept with them so that a recycled ``id`` of a discarded
        plan is never mistaken for a live one.
        """
        key = (kind, id(plan), slot)
        entry = self._workspace.get(key)
        if entry is None or entry[0] is not plan:
            if len(self._workspace) > _MAX_BUFFERS:
                # Plans made outside Detector.plans() (e.g. by callers of score_scale).
                self._workspace.clear()
            entry = self._workspace[key] = (plan, np.empty(shape, dtype))
        return entry[1]

    def scaled_region(self, region, plan, channels, rows=None, slot=0):
        """A scale's region resized to ``plan.scaled_size``; at scale 1, the
        region itself when its rows are contiguous (a full-width region).

        ``rows``: only these rows of the result are computed (see
        :func:`~fastdet.kernels.resize.resize_linear`).
        """
        width, height = plan.scaled_size
        if region.shape[:2] == (height, width) and region.flags.c_contiguous:
            return region
        # Bit-identical to cv2.resize(..., INTER_LINEAR), in about half its time.
        out = self._buffer(plan, ("resized", channels), (height, width, channels), np.uint8, slot)
        return resize_linear(region, plan.scaled_size, out=out, rows=rows)

    def _cells_buffer(self, plan, slot=0):
        """The phase-layout cell array of a scale."""
        shape = phase_layout_shape(*self._cell_grid(plan), self._hog_channels,
                                   self.options.orientations, plan.step_cells,
                                   self._phase_pad(plan))
        return self._buffer(plan, "cells", shape, np.float32, slot)

    def _cell_grid(self, plan):
        """``(rows, columns)`` of HOG cells of a scale's resized region."""
        ppc = self.options.pixels_per_cell
        return plan.scaled_size[1] // ppc, plan.scaled_size[0] // ppc

    def _phase_pad(self, plan):
        cpb = self.options.cells_per_block
        return phase_scoring_pad(self._cell_grid(plan)[1], plan.step_cells, (cpb, cpb))

    # -- the colour-converted band ----------------------------------------------
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

    def frame_buffers(self, plans):
        """A :class:`PreparedFrame` of reused arrays, to be filled by :meth:`convert_rows`."""
        band = search_band(plans)
        if band is None:
            return PreparedFrame(None, None, (0, 0))
        x0, y0, x1, y1 = band
        shape = (y1 - y0, x1 - x0)
        key = ("frame", shape)
        arrays = self._workspace.get(key)
        if arrays is None:
            grey = np.empty(shape, np.uint8) if self.options.hog_channel == "gray" else None
            arrays = self._workspace[key] = (np.empty(shape + (3,), np.uint8), grey)
        return PreparedFrame(arrays[0], arrays[1], (x0, y0))

    def convert_rows(self, frame, prepared, first, stop):
        """Colour-convert rows ``first`` .. ``stop - 1`` of the band into ``prepared``."""
        if prepared.converted is None or first >= stop:
            return
        x0, y0 = prepared.origin
        width = prepared.converted.shape[1]
        grey = prepared.grey[first:stop] if prepared.grey is not None else None
        color_planes(frame[y0 + first:y0 + stop, x0:x0 + width], self.options,
                     out=(prepared.converted[first:stop], grey))

    # -- scoring ------------------------------------------------------------------
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
        scores = np.full(plan.grid, self.model.bias, dtype=np.float32)
        self.score_band(prepared, plan, 0, plan.grid[0], scores, timings)
        return scores

    def score_band(self, prepared, plan, first, stop, scores, timings, slot=0):
        """Add the margins of window rows ``first`` .. ``stop - 1`` of a scale to ``scores``.

        Only the resized rows, cells and colour maps those windows cover are
        computed, into the work arrays of ``slot``; each window's margin is
        exactly what :meth:`score_scale` gives it.  Bands of one plan scored
        at the same time need different slots.
        """
        options = self.options
        if first >= stop:
            return
        ppc = options.pixels_per_cell
        step_px = plan.step_cells * ppc
        # The pixel rows the band's windows cover, plus one either side for
        # the gradients of their outer cells.
        top, bottom = first * step_px, (stop - 1) * step_px + WINDOW
        t0 = time.perf_counter()
        ox, oy = prepared.origin
        x0, y0, x1, y1 = plan.roi
        region = (slice(y0 - oy, y1 - oy), slice(x0 - ox, x1 - ox))
        rows = (top - 1, bottom + 1)
        converted = self.scaled_region(prepared.converted[region], plan, 3, rows, slot)
        grey = None
        if prepared.grey is not None:
            grey = self.scaled_region(prepared.grey[region][:, :, None], plan, 1, rows, slot)
        t1 = time.perf_counter()
        timings["resize_convert"] += t1 - t0
        band_scores = scores[first:stop]
        if options.use_hog:
            cpb = options.cells_per_block
            # Cells in the phase layout of the window step, so each block row
            # is normalised and scored along whole rows, never writing the
            # block map to memory.
            cells = cell_histograms(hog_input(converted, grey, options), (ppc, ppc),
                                    options.orientations, out=self._cells_buffer(plan, slot),
                                    phase_step=plan.step_cells,
                                    phase_pad=self._phase_pad(plan),
                                    rows=(top // ppc, bottom // ppc))
            t2 = time.perf_counter()
            add_hog_scores_from_phase_cells(cells, plan.scaled_size[0] // ppc, (cpb, cpb),
                                            options.block_norm, self._hog_weights,
                                            plan.step_cells, scores,
                                            window_rows=(first, stop))
            timings["cells"] += t2 - t1
            t1 = time.perf_counter()
            timings["blocks_score"] += t1 - t2
        if options.spatial_size or options.hist_bins:
            tile = math.gcd(step_px, WINDOW)
            factor = WINDOW // options.spatial_size if options.spatial_size else 0
            # Tiles and boxes are local to their pixels: the band's rows
            # (a multiple of both from the top) give the band's maps.
            tiles, spatial = colour_maps(converted[top:bottom], self._hist_lut, tile, factor)
            if options.spatial_size:
                add_spatial_scores(spatial, self._spatial_weights, step_px // factor, band_scores)
            if options.hist_bins:
                add_tile_window_sums(tiles, WINDOW // tile, step_px // tile, band_scores)
        timings["colour_score"] += time.perf_counter() - t1
