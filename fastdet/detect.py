"""The single-frame detector: scales -> kernels -> heat -> boxes.

Python here only plans and orchestrates.  The region any scale searches is
colour-converted once per frame (OpenCV); for each search scale its region of
interest is then resized so that the scale's window becomes 64 pixels
(:func:`fastdet.kernels.resize.resize_linear`, bit-identical to OpenCV's
bilinear resize); the Numba kernels then compute the whole region's HOG cells
once, and score every window of the scale from them
(:mod:`fastdet.kernels.score`).  Hit windows are merged in a heat map over the
hits' bounding region only, labelled, and filtered into boxes.
"""

from __future__ import annotations

import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from .config import DetectorConfig
from .detections import Detections
from .errors import InputError
from .features import WINDOW, color_planes, histogram_bin_lut, hog_input
from .kernels.colour import colour_maps
from .kernels.heat import box_heat_region
from .kernels.hog import cell_histograms, phase_layout_shape
from .kernels.label import (component_boxes, heat_blobs, label_components, split_component,
                            split_levels)
from .kernels.resize import resize_linear
from .kernels.score import (add_hog_scores_from_phase_cells, add_spatial_scores,
                            add_tile_window_sums, phase_scoring_pad, window_count)
from .model import Model, load_model

#: Work arrays kept before they are all dropped (see Detector._buffer).
_MAX_BUFFERS = 64
#: Sub-sampling of the cheap first pass that decides whether a heat blob splits.
_SPLIT_PROBE = 4
#: Fractions of the way from the heat threshold to a blob's peak at which it is split.
_SPLIT_LEVELS = np.linspace(0.2, 0.8, 5)

#: Names of the timed stages, in pipeline order.
STAGES = ("resize_convert", "cells", "blocks_score", "colour_score", "heat", "label", "total")


def as_bgr_frame(frame):
    """Validate a frame and return it as a C-contiguous BGR uint8 (H, W, 3) array.

    Grey (H, W) or (H, W, 1) frames are replicated to three channels and BGRA
    (H, W, 4) frames drop their alpha channel.

    Raises
    ------
    InputError
        For anything that is not a uint8 image array of those shapes.
    """
    if not isinstance(frame, np.ndarray):
        raise InputError(f"a frame must be a numpy array, got {type(frame).__name__}")
    if frame.dtype != np.uint8:
        raise InputError(f"a frame must be uint8 (BGR, 0-255), got {frame.dtype}")
    if frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 1):
        return cv2.cvtColor(np.ascontiguousarray(frame.reshape(frame.shape[:2])),
                            cv2.COLOR_GRAY2BGR)
    if frame.ndim == 3 and frame.shape[2] == 4:
        return cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_BGRA2BGR)
    if frame.ndim == 3 and frame.shape[2] == 3:
        return np.ascontiguousarray(frame)
    raise InputError(f"a frame must have shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), "
                     f"got {frame.shape}")


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
    axis factors).  Scales with no whole window in the frame are dropped.
    """
    width, height = frame_size
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


class Detector:
    """HOG + linear-SVM vehicle detector for single frames.

    Parameters
    ----------
    model : Model or str or Path, optional
        A :class:`~fastdet.model.Model`, a model file, or ``None`` for the
        bundled default.
    config : DetectorConfig, optional
        Search, heat and box settings; defaults built in.
    threads : int, optional
        Threads per frame.  ``None`` keeps Numba's setting
        (``NUMBA_NUM_THREADS``, all cores by default); 1 runs everything on
        the calling thread.  With more, the search scales of a frame are
        scored concurrently by a pool of that many threads (the kernels
        release the GIL), each scale on one thread: a scale's kernels are
        too short to split well.  OpenCV, which converts the frame's colours,
        is set to the same count so the two do not oversubscribe the cores.

    Notes
    -----
    Frames are BGR uint8 arrays, OpenCV's convention (``cv2.imread`` and
    ``cv2.VideoCapture`` return them); grey and BGRA frames are converted.
    A frame smaller than the smallest window gives no boxes.

    Examples
    --------
    >>> detector = Detector()                      # doctest: +SKIP
    >>> detections = detector(cv2.imread("frame.jpg"))  # doctest: +SKIP
    >>> detections.xyxy, detections.score          # doctest: +SKIP
    """

    def __init__(self, model=None, config=None, threads=None):
        if not isinstance(model, Model):
            model = load_model(model)
        self.model = model
        self.config = config or DetectorConfig()
        if threads is not None:
            if threads < 1:
                raise InputError(f"threads must be at least 1, got {threads}")
            threads = min(int(threads), numba.config.NUMBA_NUM_THREADS)
            numba.set_num_threads(threads)
            cv2.setNumThreads(threads)
        self.threads = numba.get_num_threads() if threads is None else threads
        self._pool = None
        self._timings_lock = threading.Lock()
        self._heat_blob_params = None
        options = model.options
        self._options = options
        hog_w, spatial_w, hist_w = model.split_weights()
        self._hog_weights = np.ascontiguousarray(hog_w)
        self._spatial_weights = np.ascontiguousarray(spatial_w)
        self._hist_lut = None
        if options.hist_bins:
            bins = histogram_bin_lut(options.hist_bins)
            self._hist_lut = np.ascontiguousarray(hist_w[:, bins], dtype=np.float32)
        self._plans = {}
        self._workspace = {}
        self._hog_channels = model.layout.hog_channels
        #: Seconds spent per stage (see ``STAGES``) in the last call; with
        #: several threads, the scales' stage times are summed over threads.
        self.timings = dict.fromkeys(STAGES, 0.0)

    def __del__(self):
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=False)

    def _scale_pool(self):
        """The thread pool that scores scales concurrently (threads > 1)."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=self.threads,
                                            thread_name_prefix="fastdet-scale")
        return self._pool

    def plans(self, frame_size):
        """The scale plans for frames of ``(width, height)`` (cached)."""
        plans = self._plans.get(frame_size)
        if plans is None:
            plans = self._plans[frame_size] = plan_scales(self.config, self._options, frame_size)
        return plans

    # -- stage 1: windows ---------------------------------------------------
    def _buffer(self, plan, kind, shape, dtype):
        """A scale's work array, reused from frame to frame.

        Fresh multi-megabyte arrays every frame would cost page faults;
        callers get the array back filled, so the reuse is invisible.  Each
        plan object has its own arrays, so scales scored concurrently never
        share one; the plan is kept with them so that a recycled ``id`` of a
        discarded plan is never mistaken for a live one.
        """
        key = (kind, id(plan))
        entry = self._workspace.get(key)
        if entry is None or entry[0] is not plan:
            if len(self._workspace) > _MAX_BUFFERS:
                # Plans made outside plans() (e.g. by callers of score_scale).
                self._workspace.clear()
            entry = self._workspace[key] = (plan, np.empty(shape, dtype))
        return entry[1]

    def _resized_buffer(self, plan, channels):
        """The uint8 array a scale's region is resized into."""
        width, height = plan.scaled_size
        return self._buffer(plan, ("resized", channels), (height, width, channels), np.uint8)

    def _scaled_region(self, region, plan, channels):
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
                                   self._options.orientations, plan.step_cells,
                                   self._phase_pad(plan))
        return self._buffer(plan, "cells", shape, np.float32)

    def _cell_grid(self, plan):
        """``(rows, columns)`` of HOG cells of a scale's resized region."""
        ppc = self._options.pixels_per_cell
        return plan.scaled_size[1] // ppc, plan.scaled_size[0] // ppc

    def _phase_pad(self, plan):
        cpb = self._options.cells_per_block
        return phase_scoring_pad(self._cell_grid(plan)[1], plan.step_cells, (cpb, cpb))

    def prepare(self, frame):
        """Colour-convert the part of a frame any scale searches, once.

        Returns
        -------
        PreparedFrame
        """
        plans = self.plans((frame.shape[1], frame.shape[0]))
        if not plans:
            return PreparedFrame(None, None, (0, 0))
        x0 = min(plan.roi[0] for plan in plans)
        y0 = min(plan.roi[1] for plan in plans)
        x1 = max(plan.roi[2] for plan in plans)
        y1 = max(plan.roi[3] for plan in plans)
        converted, grey = color_planes(frame[y0:y1, x0:x1], self._options)
        return PreparedFrame(converted, grey, (x0, y0))

    def score_scale(self, prepared, plan, timings=None):
        """SVM margins of every window of one scale, shape ``plan.grid``.

        Parameters
        ----------
        prepared : PreparedFrame
            From :meth:`prepare`.
        plan : ScalePlan
            One of :meth:`plans` for the frame's size.
        timings : dict, optional
            Stage seconds are added here (default: :attr:`timings`).
        """
        options = self._options
        timings = self.timings if timings is None else timings
        t0 = time.perf_counter()
        ox, oy = prepared.origin
        x0, y0, x1, y1 = plan.roi
        region = (slice(y0 - oy, y1 - oy), slice(x0 - ox, x1 - ox))
        converted = self._scaled_region(prepared.converted[region], plan, 3)
        grey = None
        if prepared.grey is not None:
            grey = self._scaled_region(prepared.grey[region][:, :, None], plan, 1)
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

    def hits(self, frame):
        """Every window whose margin exceeds ``search.decision_threshold``.

        Parameters
        ----------
        frame : ndarray
            BGR uint8 image (see :func:`as_bgr_frame`).

        Returns
        -------
        Hits
        """
        frame = as_bgr_frame(frame)
        for stage in STAGES:
            self.timings[stage] = 0.0
        threshold = self.config.search.decision_threshold
        boxes, scores, scales = [], [], []
        scored = 0
        t0 = time.perf_counter()
        prepared = self.prepare(frame)
        self.timings["resize_convert"] += time.perf_counter() - t0
        plans = self.plans((frame.shape[1], frame.shape[0]))
        if self.threads > 1 and len(plans) > 1:
            grids = list(self._scale_pool().map(
                lambda plan: self._score_scale_timed(prepared, plan), plans))
        else:
            grids = [self.score_scale(prepared, plan) for plan in plans]
        for index, (plan, grid) in enumerate(zip(plans, grids)):
            grid = grid.ravel()
            scored += grid.size
            hit = np.flatnonzero(grid > threshold)
            if hit.size:
                boxes.append(plan.boxes[hit])
                scores.append(grid[hit])
                scales.append(np.full(hit.size, index, dtype=np.int64))
        if not boxes:
            return Hits(np.zeros((0, 4), np.int32), np.zeros(0, np.float32),
                        np.zeros(0, np.int64), scored)
        return Hits(np.concatenate(boxes), np.concatenate(scores), np.concatenate(scales), scored)

    def _score_scale_timed(self, prepared, plan):
        """:meth:`score_scale` on a pool thread, its stage times added afterwards."""
        timings = dict.fromkeys(STAGES, 0.0)
        scores = self.score_scale(prepared, plan, timings)
        with self._timings_lock:
            for stage, seconds in timings.items():
                self.timings[stage] += seconds
        return scores

    def heat_weights(self, hits, frame_size):
        """Heat each hit adds, per ``heat.weighting``."""
        weighting = self.config.heat.weighting
        if weighting == "count":
            return np.ones(len(hits.scores), dtype=np.float32)
        if weighting == "margin":
            return (hits.scores - self.config.search.decision_threshold).astype(np.float32)
        plans = self.plans(frame_size)
        per_scale = np.array([plan.heat_weight for plan in plans], dtype=np.float32)
        return per_scale[hits.scale_index] if len(hits.scores) else np.zeros(0, np.float32)

    def heat_region(self, hits, frame_size):
        """Heat of the hits over their bounding region.

        Returns
        -------
        heat : ndarray of float32, shape (y1 - y0, x1 - x0)
        origin : tuple of int
            ``(x0, y0)`` of the region in the frame.
        """
        width, height = frame_size
        if len(hits.scores) == 0:
            return np.zeros((0, 0), np.float32), (0, 0)
        heat, x0, y0 = box_heat_region(hits.boxes, self.heat_weights(hits, frame_size),
                                       width, height)
        return heat, (x0, y0)

    def heatmap(self, frame):
        """Full-frame heat map of one frame (float32, frame height x width)."""
        frame = as_bgr_frame(frame)
        size = (frame.shape[1], frame.shape[0])
        heat, (x0, y0) = self.heat_region(self.hits(frame), size)
        full = np.zeros(frame.shape[:2], dtype=np.float32)
        full[y0:y0 + heat.shape[0], x0:x0 + heat.shape[1]] = heat
        return full

    # -- stage 2: boxes -----------------------------------------------------
    def boxes_from_heat(self, heat, origin, frame_size):
        """Threshold, label and filter a heat map into detections.

        Parameters
        ----------
        heat : ndarray of float32, shape (h, w)
            Heat over a region of the frame.
        origin : tuple of int
            ``(x0, y0)`` of that region in the frame.
        frame_size : tuple of int
            ``(width, height)`` of the frame, for the size-relative filters.
        """
        boxes, peaks = self.heat_components(heat, origin, frame_size)
        return self.finish_boxes(boxes, peaks, frame_size)

    def heat_components(self, heat, origin, frame_size=None):
        """Boxes and peak heat of each blob (refined and split per ``[heat]``).

        ``heat`` is float32 or float64 (other dtypes are taken as float64).
        """
        if heat.size == 0:
            return np.zeros((0, 4), np.int32), np.zeros(0, np.float32)
        # The kernel's settings, kept while the config and frame size stay:
        # Python work here costs more than the kernel's per-blob work.
        params = self._heat_blob_params
        if params is None or params[0] is not self.config or params[1] != frame_size:
            cfg = self.config.heat
            min_size = -1
            if cfg.split:
                scale = 1.0
                if frame_size is not None:
                    ref_w, ref_h = self.config.search.reference_size
                    scale = math.sqrt(frame_size[0] / ref_w * frame_size[1] / ref_h)
                min_size = int(round(cfg.split_min_size * scale))
            params = self._heat_blob_params = (
                self.config, frame_size, min_size,
                (float(cfg.threshold), cfg.connectivity == 8, bool(cfg.peak_fraction > 0),
                 np.float32(cfg.peak_fraction), min_size, _SPLIT_PROBE, _SPLIT_LEVELS))
        if heat.dtype != np.float32 and heat.dtype != np.float64:
            heat = heat.astype(np.float64)
        # One kernel thresholds and labels the heat on its grid of constant
        # cells, measures the blobs and probes which of them split.
        boxes, peaks, probed, n_probed = heat_blobs(heat, origin[0], origin[1], *params[3])
        if n_probed:
            boxes, peaks = self._split_blobs(heat, origin, boxes, peaks, probed, params[2])
        return boxes, peaks

    def _split_blobs(self, heat, origin, boxes, peaks, probed, min_size):
        """Replace blobs with two car-sized peaks by one box per peak.

        Heat is piecewise constant over window steps of 8+ pixels, so a
        quarter-resolution probe (run by ``heat_blobs``) finds out cheaply
        whether a blob splits at all; the ``probed`` ones are split here at
        full resolution.
        """
        cfg = self.config.heat
        labels, count = label_components(heat > cfg.threshold, cfg.connectivity)
        whole = component_boxes(labels, count)
        shift = np.array([origin[0], origin[1], origin[0], origin[1]], dtype=np.int32)
        out_boxes, out_peaks = [], []
        for k in range(len(peaks)):
            parts = boxes[:0]
            if probed[k]:
                x1, y1, x2, y2 = whole[k]
                region = heat[y1:y2, x1:x2]
                mask = np.ascontiguousarray(labels[y1:y2, x1:x2] == k + 1)
                # The same levels the kernel's probe used (one definition).
                levels = split_levels(np.float32(peaks[k]), float(cfg.threshold), _SPLIT_LEVELS)
                parts = split_component(np.ascontiguousarray(region), mask, levels, min_size,
                                        min_size, cfg.connectivity)
                # A seed that won no pixel yields an empty box; it is no car.
                parts = parts[(parts[:, 2] > parts[:, 0]) & (parts[:, 3] > parts[:, 1])]
            if len(parts) < 2:
                out_boxes.append(boxes[k:k + 1])
                out_peaks.append(peaks[k:k + 1])
                continue
            out_peaks.append(np.array([region[py1:py2, px1:px2][mask[py1:py2, px1:px2]].max()
                                       for px1, py1, px2, py2 in parts], dtype=np.float32))
            out_boxes.append(parts + np.array([x1, y1, x1, y1], dtype=np.int32) + shift)
        return np.concatenate(out_boxes), np.concatenate(out_peaks)

    def finish_boxes(self, boxes, peaks, frame_size):
        """Shape-correct and filter blob boxes into :class:`Detections`."""
        boxes = self.reshape_boxes(boxes, frame_size)
        keep = self.box_filter(boxes, frame_size)
        return Detections(boxes[keep], peaks[keep])

    def reshape_boxes(self, boxes, frame_size):
        """Apply the ``[boxes]`` shape correction about each box centre, clipped to the frame."""
        cfg = self.config.boxes
        if cfg.width_scale == 1 and cfg.height_scale == 1 and cfg.center_dy == 0:
            return boxes
        xyxy = boxes.astype(np.float64)
        cx = (xyxy[:, 0] + xyxy[:, 2]) / 2
        cy = (xyxy[:, 1] + xyxy[:, 3]) / 2
        half_w = (xyxy[:, 2] - xyxy[:, 0]) * cfg.width_scale / 2
        height = xyxy[:, 3] - xyxy[:, 1]
        half_h = height * cfg.height_scale / 2
        cy = cy + cfg.center_dy * height
        out = np.stack([cx - half_w, cy - half_h, cx + half_w, cy + half_h], axis=1)
        out = np.round(out)
        width, height = frame_size
        out[:, 0] = np.clip(out[:, 0], 0, width - 1)
        out[:, 1] = np.clip(out[:, 1], 0, height - 1)
        # A box keeps at least one pixel after rounding and clipping.
        out[:, 2] = np.clip(out[:, 2], out[:, 0] + 1, width)
        out[:, 3] = np.clip(out[:, 3], out[:, 1] + 1, height)
        return out.astype(np.int32)

    def box_filter(self, boxes, frame_size):
        """Boolean mask of the boxes that pass the ``[boxes]`` sanity filters."""
        cfg = self.config.boxes
        ref_w, ref_h = self.config.search.reference_size
        kx, ky = frame_size[0] / ref_w, frame_size[1] / ref_h
        k = math.sqrt(kx * ky)
        width = boxes[:, 2] - boxes[:, 0]
        height = boxes[:, 3] - boxes[:, 1]
        aspect = width / np.maximum(height, 1)
        return ((width >= cfg.min_size * k) & (height >= cfg.min_size * k)
                & (aspect >= cfg.min_aspect) & (aspect <= cfg.max_aspect)
                & (boxes[:, 3] > cfg.horizon_y * ky))

    def __call__(self, frame):
        """Detect vehicles in one frame.

        Parameters
        ----------
        frame : ndarray of uint8, shape (H, W, 3)
            BGR image (grey and BGRA accepted, see :func:`as_bgr_frame`).

        Returns
        -------
        Detections
        """
        start = time.perf_counter()
        frame = as_bgr_frame(frame)
        size = (frame.shape[1], frame.shape[0])
        hits = self.hits(frame)
        t0 = time.perf_counter()
        heat, origin = self.heat_region(hits, size)
        t1 = time.perf_counter()
        detections = self.boxes_from_heat(heat, origin, size)
        end = time.perf_counter()
        self.timings["heat"] = t1 - t0
        self.timings["label"] = end - t1
        self.timings["total"] = end - start
        self.last_windows_scored = hits.windows_scored
        return detections
