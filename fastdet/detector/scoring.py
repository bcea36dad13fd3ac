"""Per-scale scoring: a frame's searched region -> SVM margins of every window of a scale.

The region any scale searches is colour-converted once per frame
(:meth:`ScaleScorer.prepare`); each scale's part of it is then resized so the
scale's window becomes 64 pixels (:func:`fastdet.kernels.resize.resize_linear`,
bit-identical to OpenCV's bilinear resize), its HOG cells computed once, and
every window scored from them (:mod:`fastdet.kernels.score`), plus the colour
features' part of the score (:mod:`fastdet.kernels.colour`).  With colour
features and the default HOG, those three run in one kernel call per scale
(:class:`fastdet.kernels.band.BandScorer`), which hands the GIL over fewer
times when two frames are searched at once.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from ..kernels.band import BandScorer
from ..kernels.colour import ColourMapRows
from ..kernels.hog import PhaseCellRows, phase_layout_shape
from ..kernels.resize import RowResizer
from ..kernels.score import WindowRowScorer, phase_scoring_pad
from .features import WINDOW, color_planes, histogram_bin_lut, hog_input
from .plan import search_band

#: Plans with work arrays (and frame bands) kept before all are dropped, about three
#: frame sizes of the default search (see ScaleScorer._start_frame).
_MAX_BUFFERS = 16

#: How far a thread's share of whole scales may exceed an even share of the
#: frame's resized pixels before the largest scales are cut into row tasks.
#: Cutting balances finer but costs kernel calls, GIL hand-overs and a wait
#: for the rows before the windows: with the default search, whose two
#: largest scales hold 27 % of the pixels each, two threads on whole scales
#: (shares within 0.1 % of even) were 1.58x and 1.53x one thread against
#: 1.54x and 1.46x with those two scales cut in halves (medians of 12 and 10
#: rounds timed in turn, whole scales faster in 11 and 9; AMD EPYC Zen 4).
BALANCE_TOLERANCE = 0.1

#: Names of the timed stages, in pipeline order.
STAGES = ("resize_convert", "cells", "blocks_score", "colour_maps", "heat", "label", "total")


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
    """The kernel families (``kernels.warmup.FAMILIES``) a detection with ``options`` runs."""
    # "refine": the default config refines boxes (a config without weights
    # only loads two small kernels it does not call).
    families = ["resize", "heat", "label", "refine"]
    if options.color_space == "HLS":
        families.append("convert")
    colour = bool(options.spatial_size or options.hist_bins)
    if options.use_hog and options.hog_channel == "all" and (
            options.pixels_per_cell, options.orientations, options.cells_per_block,
            options.block_norm) == (8, 9, 2, "L2-Hys"):
        # The warm-up's shapes; other settings compile at their first frame.
        # With colour features the scales take one call for the three
        # (_ScaleWork.band), which calls their compiled code.
        families += ["hog", "score", "band"] if colour else ["hog", "score"]
    if colour:
        families.append("colour")
    return tuple(families)


@dataclass(frozen=True)
class ScaleBand:
    """One task of a frame's scoring, on the scale plan at ``index``.

    ``kind`` is ``"whole"`` (window rows ``first`` .. ``stop - 1``: their
    pixels' features, then their margins), ``"rows"`` (the features of
    scaled pixel rows ``first`` .. ``stop - 1`` only) or ``"windows"`` (the
    margins of window rows ``first`` .. ``stop - 1`` from features that the
    plan's ``"rows"`` tasks computed: it runs after them).  ``pixels``: the
    resized pixels it computes, its estimated cost.
    """

    index: int
    kind: str
    first: int
    stop: int
    pixels: int


class ScaleScorer:
    """Scores the windows of one scale plan at a time, for one model.

    Parameters
    ----------
    model : fastdet.detector.model.Model

    Notes
    -----
    Work arrays are kept per plan object and reused from frame to frame
    (made under a lock, so threads that start on a new plan at once share
    one), so one scorer may score different plans concurrently, and tasks of
    one plan with disjoint rows, but not the same rows twice at once.
    """

    def __init__(self, model):
        self.model = model
        options = model.options
        self.options = options
        hog_w, spatial_w, hist_w = model.split_weights()
        self.hog_weights = np.ascontiguousarray(hog_w)
        self.spatial_weights = np.ascontiguousarray(spatial_w)
        self.hist_lut = None
        if options.hist_bins:
            bins = histogram_bin_lut(options.hist_bins)
            self.hist_lut = np.ascontiguousarray(hist_w[:, bins], dtype=np.float32)
        self.hog_channels = model.layout.hog_channels
        self._workspace = {}
        self._workspace_lock = threading.Lock()

    def _work(self, plan):
        """The :class:`_ScaleWork` of a scale plan: its work arrays, reused from frame to frame.

        Fresh multi-megabyte arrays every frame would cost page faults;
        callers get the arrays back filled, so the reuse is invisible.  Each
        plan object has its own, so scales scored concurrently never share
        one (tasks of one scale write disjoint rows of them); the plan is
        kept with them so that a recycled ``id`` of a discarded plan is
        never mistaken for a live one.
        """
        work = self._workspace.get(id(plan))
        if work is None or work.plan is not plan:
            # Threads sharing a frame run tasks of one plan at once: two of
            # them making its first arrays would each fill their own, and the
            # windows would be scored from arrays holding only one's rows.
            with self._workspace_lock:
                work = self._workspace.get(id(plan))
                if work is None or work.plan is not plan:
                    work = self._workspace[id(plan)] = _ScaleWork(plan, self)
        return work

    def _start_frame(self):
        """Drop the work arrays once too many frame sizes have left theirs behind.

        Only here, before a frame's first array is taken: dropping them in the
        middle of a frame would hand a scale a new, unfilled array between
        computing its cells and scoring them.
        """
        if len(self._workspace) > _MAX_BUFFERS:
            self._workspace.clear()

    def scaled_region(self, region, plan, channels, rows=None):
        """A scale's region resized to ``plan.scaled_size``; at scale 1, the
        region itself when its rows are contiguous (a full-width region).

        ``rows``: only these rows of the result are computed (see
        :func:`~fastdet.kernels.resize.resize_linear`).
        """
        scaled, resize = self._scaled_region_call(region, plan, rows)
        if resize is not None:
            resize[0](*resize[1])
        return scaled

    def _scaled_region_call(self, region, plan, rows=None):
        """``(scaled, resize)``: the array :meth:`scaled_region` returns, and the
        ``(function, arguments)`` that fill its ``rows`` from ``region`` (None at
        scale 1, where it is the region itself)."""
        width, height = plan.scaled_size
        if region.shape[:2] == (height, width) and region.flags.c_contiguous:
            return region, None
        # Bit-identical to cv2.resize(..., INTER_LINEAR), in about half its time.
        resizer = self._work(plan).resizer(region.shape)
        return resizer.out, resizer.bind(region, *(rows or (0, height)))

    @staticmethod
    def _region(prepared, plan):
        """The slices of ``prepared``'s arrays that hold a scale's region."""
        ox, oy = prepared.origin
        x0, y0, x1, y1 = plan.roi
        return slice(y0 - oy, y1 - oy), slice(x0 - ox, x1 - ox)

    # -- the colour-converted band ----------------------------------------------
    def prepare(self, frame, plans):
        """Colour-convert the part of a frame any of ``plans`` searches, once.

        Returns
        -------
        PreparedFrame
        """
        self._start_frame()
        band = search_band(plans)
        if band is None:
            return PreparedFrame(None, None, (0, 0))
        x0, y0, x1, y1 = band
        converted, grey = color_planes(frame[y0:y1, x0:x1], self.options)
        return PreparedFrame(converted, grey, (x0, y0))

    def frame_buffers(self, plans):
        """A :class:`PreparedFrame` of reused arrays, to be filled by :meth:`convert_rows`."""
        self._start_frame()
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

    def bands(self, plans, threads):
        """A frame's scoring tasks for ``threads`` threads, costliest first.

        One ``"whole"`` task per scale, when the threads, each taking the
        costliest task left as it finishes one, end within
        :data:`BALANCE_TOLERANCE` of an even share of the frame's resized
        pixels (always with one thread; with two on the default search).
        Otherwise a scale costing more than ``1 / (2 * threads)`` of those
        pixels is cut into ``"rows"`` tasks of whole colour tiles, which
        threads compute at the same time, and one ``"windows"`` task scoring
        all its windows after them.
        """
        ppc = self.options.pixels_per_cell
        used = [((plan.grid[0] - 1) * plan.step_cells * ppc + WINDOW) * plan.scaled_size[0]
                for plan in plans]
        total = sum(used)
        cut = (threads > 1 and total
               and _longest_share(used, threads) > (1 + BALANCE_TOLERANCE) * total / threads)
        tasks = []
        for index, plan in enumerate(plans):
            count = 1
            if cut:
                count = math.ceil(used[index] * 2 * threads / total)
            height = used[index] // plan.scaled_size[0]
            align = self._row_alignment(plan)
            cuts = sorted({round(height * part / count / align) * align
                           for part in range(1, count)} - {0, height})
            if not cuts:
                tasks.append(ScaleBand(index, "whole", 0, plan.grid[0], used[index]))
                continue
            for top, bottom in zip([0] + cuts, cuts + [height]):
                tasks.append(ScaleBand(index, "rows", top, bottom,
                                       (bottom - top) * plan.scaled_size[0]))
            tasks.append(ScaleBand(index, "windows", 0, plan.grid[0], 0))
        return tuple(sorted(tasks, key=lambda task: -task.pixels))

    def _row_alignment(self, plan):
        """Row cuts at multiples of this keep cells, colour tiles and boxes whole."""
        options = self.options
        step_px = plan.step_cells * options.pixels_per_cell
        align = options.pixels_per_cell
        if options.hist_bins:
            align = math.lcm(align, math.gcd(step_px, WINDOW))
        if options.spatial_size:
            align = math.lcm(align, WINDOW // options.spatial_size)
        return align

    def run(self, task, prepared, plans, grids, timings):
        """Run one task of :meth:`bands` (its ``"windows"`` task only after its ``"rows"``)."""
        plan = plans[task.index]
        if task.kind == "rows":
            self.score_rows(prepared, plan, task.first, task.stop, timings)
        elif task.kind == "windows":
            self.score_windows(plan, task.first, task.stop, grids[task.index], timings)
        else:
            self.score_band(prepared, plan, task.first, task.stop, grids[task.index], timings)

    def score_band(self, prepared, plan, first, stop, scores, timings):
        """Add the margins of window rows ``first`` .. ``stop - 1`` of a scale to ``scores``.

        Only the resized rows, cells and colour maps those windows cover are
        computed; each window's margin is exactly what :meth:`score_scale`
        gives it.
        """
        if first >= stop:
            return
        step_px = plan.step_cells * self.options.pixels_per_cell
        top, bottom = first * step_px, (stop - 1) * step_px + WINDOW
        work = self._work(plan)
        if work.band is None:
            self.score_rows(prepared, plan, top, bottom, timings)
            self.score_windows(plan, first, stop, scores, timings)
            return
        # One kernel call for the cells, colour maps and scores: fewer GIL
        # hand-overs (see fastdet.kernels.band).  Its arguments and the resize's
        # are made once per task and arrays (the frame's converted band and the
        # score grid are refilled in place from frame to frame): the Python
        # between the kernels runs with the GIL held, which a thread scoring
        # another frame waits for.
        key = (first, stop, id(prepared.converted), prepared.origin, id(scores))
        bound = work.bound_bands.get(key)
        if bound is None:
            bound = self._bind_band(prepared, plan, work, top, bottom, first, stop, scores)
            if len(work.bound_bands) >= _MAX_BOUND_BANDS:
                work.bound_bands.clear()   # arrays of frames that are gone
            work.bound_bands[key] = bound
        t0 = time.perf_counter()
        if bound.resize is not None:
            bound.resize[0](*bound.resize[1])
        timings["resize_convert"] += time.perf_counter() - t0
        cells, colour, windows = bound.band()
        timings["cells"] += cells
        timings["colour_maps"] += colour
        timings["blocks_score"] += windows

    def _bind_band(self, prepared, plan, work, top, bottom, first, stop, scores):
        """The resize and band kernel calls of :meth:`score_band`, made once (a
        :class:`_BoundTask`; it keeps ``prepared.converted`` and ``scores``, whose
        ids key it, alive)."""
        converted, resize = self._scaled_region_call(
            prepared.converted[self._region(prepared, plan)], plan, (top - 1, bottom + 1))
        band = work.band.bind(converted, converted[:work.covered_rows], top, bottom, first,
                              stop, scores)
        return _BoundTask(resize, band, (prepared.converted, scores))

    def score_rows(self, prepared, plan, top, bottom, timings):
        """The features of scaled pixel rows ``top`` .. ``bottom - 1`` of a scale.

        The rows are resized (plus one either side, for the gradients of the
        outer cells), their cells and colour maps computed into the plan's
        work arrays.  ``top`` and ``bottom`` keep cells and colour tiles
        whole (see :meth:`_row_alignment`); tasks of one plan with disjoint
        rows may run at the same time.
        """
        options = self.options
        work = self._work(plan)
        converted, grey = self._scaled_rows(prepared, plan, top, bottom, timings)
        t1 = time.perf_counter()
        if options.use_hog:
            # Cells in the phase layout of the window step, so each block row
            # is normalised and scored along whole rows, never writing the
            # block map to memory.
            ppc = options.pixels_per_cell
            work.cell_rows(hog_input(converted, grey, options), top // ppc, bottom // ppc)
            t2 = time.perf_counter()
            timings["cells"] += t2 - t1
            t1 = t2
        if work.colour_rows is not None:
            # Tiles and boxes are local to their pixels: the rows' maps are
            # the rows of the scale's maps.
            work.colour_rows(converted[:work.covered_rows], top, bottom)
            timings["colour_maps"] += time.perf_counter() - t1

    def _scaled_rows(self, prepared, plan, top, bottom, timings):
        """``(colour, grey)``: the scale's resized region with rows ``top - 1`` ..
        ``bottom`` computed (the gradients of the outer cells need one row
        either side); ``grey`` None unless the HOG is grey."""
        t0 = time.perf_counter()
        region = self._region(prepared, plan)
        rows = (top - 1, bottom + 1)
        converted = self.scaled_region(prepared.converted[region], plan, 3, rows)
        grey = None
        if prepared.grey is not None:
            grey = self.scaled_region(prepared.grey[region][:, :, None], plan, 1, rows)
        timings["resize_convert"] += time.perf_counter() - t0
        return converted, grey

    def score_windows(self, plan, first, stop, scores, timings):
        """Add the margins of window rows ``first`` .. ``stop - 1`` to ``scores``, from
        the features :meth:`score_rows` computed for the rows they cover."""
        if first >= stop:
            return
        t0 = time.perf_counter()
        # One kernel call for the three parts (see score_window_rows).
        self._work(plan).score_windows(scores, first, stop)
        timings["blocks_score"] += time.perf_counter() - t0


#: Bound band calls a scale keeps (tasks x frame sizes' arrays); more are made again.
_MAX_BOUND_BANDS = 32


@dataclass
class _BoundTask:
    """A band task's resize (``(function, arguments)`` or None) and band kernel call."""

    resize: tuple | None
    band: object
    keep: tuple   # the arrays whose ids key it


def _longest_share(costs, threads):
    """The largest total a thread gets when each takes the costliest task left."""
    shares = [0] * threads
    for cost in sorted(costs, reverse=True):
        shares[shares.index(min(shares))] += cost
    return max(shares)


class _ScaleWork:
    """A scale plan's work arrays, and the sizes its kernel calls take, made once.

    The Python around the kernels runs with the GIL held, which a thread
    scoring another frame then waits for: what depends on the plan alone is
    worked out here, once, rather than on every frame.

    Parameters
    ----------
    plan : ScalePlan
    scorer : ScaleScorer
        Its options and weights.
    """

    def __init__(self, plan, scorer):
        options = scorer.options
        self.plan = plan
        self._resized = {}
        self._resizers = {}
        self.bound_bands = {}
        ppc = options.pixels_per_cell
        step_px = plan.step_cells * ppc
        width = plan.scaled_size[0]
        cells_y, cells_x = plan.scaled_size[1] // ppc, width // ppc
        cpb = options.cells_per_block
        self.cell_rows = hog_args = None
        if options.use_hog:
            phase_pad = phase_scoring_pad(cells_x, plan.step_cells, (cpb, cpb))
            # Zeros: the positions no cell maps to stay zero from frame to
            # frame (the cell kernels never write them; the scorer rewrites
            # its wrapped phases before reading them), so the cell rows leave
            # them as they are.
            cells = np.zeros(phase_layout_shape(cells_y, cells_x, scorer.hog_channels,
                                                options.orientations, plan.step_cells,
                                                phase_pad), np.float32)
            self.cell_rows = PhaseCellRows(
                (plan.scaled_size[1], width, scorer.hog_channels), (ppc, ppc),
                options.orientations, cells, plan.step_cells, phase_pad)
            hog_args = (cells, cells_x, (cpb, cpb), options.block_norm, scorer.hog_weights,
                        plan.step_cells)
        # The histogram tile side and the spatial box factor.
        tile = math.gcd(step_px, WINDOW)
        factor = WINDOW // options.spatial_size if options.spatial_size else 0
        # The colour maps cover the rows the windows cover.
        height = self.covered_rows = max(0, (plan.grid[0] - 1) * step_px + WINDOW)
        tile_sums = np.empty((height // tile, width // tile) if options.hist_bins else (0, 0),
                             np.float32)
        box = np.empty((height // factor, width // factor, 3) if factor else (0, 0, 3),
                       np.float32)
        self.colour_rows = None
        if options.spatial_size or options.hist_bins:
            self.colour_rows = ColourMapRows((height, width, 3), scorer.hist_lut, tile, factor,
                                             (tile_sums, box))
        self.score_windows = WindowRowScorer(
            plan.grid, WINDOW, step_px, hog_args,
            (box, scorer.spatial_weights) if options.spatial_size else None,
            (tile_sums, tile) if options.hist_bins else None)
        # The three in one call, where the kernel serves these options (HOG of
        # the colour image itself, not of its grey).
        self.band = None
        if (options.hog_channel == "all"
                and BandScorer.fits(self.cell_rows, self.colour_rows, self.score_windows)):
            self.band = BandScorer(self.cell_rows, self.colour_rows, self.score_windows)

    def resizer(self, region_shape):
        """The :class:`~fastdet.kernels.resize.RowResizer` of regions of this shape to
        the plan's size (made on first use; one output array per channel count)."""
        resizer = self._resizers.get(region_shape)
        if resizer is None:
            width, height = self.plan.scaled_size
            channels = region_shape[2]
            # setdefault is atomic: threads starting on this plan at once all
            # get what was stored first.
            out = self._resized.setdefault(channels,
                                           np.empty((height, width, channels), np.uint8))
            resizer = self._resizers.setdefault(region_shape,
                                                RowResizer(region_shape, (width, height), out))
        return resizer
