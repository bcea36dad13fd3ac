"""The single-frame detector: search plan -> per-scale scoring -> heat -> boxes.

:class:`Detector` owns a model and a configuration and orchestrates three
parts, each testable on its own: the search plan of a frame size
(:mod:`.plan`), the per-scale scoring (:class:`~.scoring.ScaleScorer`) and
the heat-to-boxes step (:class:`~.boxes.BoxFinder`).  All per-pixel and
per-window work happens in the Numba kernels those parts call.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import cv2
import numba
import numpy as np

from ..errors import InputError
from .boxes import BoxFinder
from .config import DetectorConfig
from .frames import as_bgr_frame
from .model import Model, load_model
from .plan import plan_scales
from .scoring import STAGES, Hits, ScaleScorer


class Detector:
    """HOG + linear-SVM vehicle detector for single frames.

    Parameters
    ----------
    model : Model or str or Path, optional
        A :class:`~fastdet.detector.model.Model`, a model file, or ``None`` for the
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

    Attributes
    ----------
    scorer : ScaleScorer
        Scores one scale plan of a prepared frame.
    box_finder : BoxFinder
        Turns hits into heat and heat into boxes.
    timings : dict
        Seconds spent per stage (see ``STAGES``) in the last call; with
        several threads, the scales' stage times are summed over threads.

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
        if threads is not None:
            if threads < 1:
                raise InputError(f"threads must be at least 1, got {threads}")
            threads = min(int(threads), numba.config.NUMBA_NUM_THREADS)
            numba.set_num_threads(threads)
            cv2.setNumThreads(threads)
        self.threads = numba.get_num_threads() if threads is None else threads
        self._pool = None
        self._timings_lock = threading.Lock()
        self.scorer = ScaleScorer(model)
        self.box_finder = BoxFinder(config or DetectorConfig())
        self._plans = {}
        self.timings = dict.fromkeys(STAGES, 0.0)

    @property
    def config(self):
        """The :class:`DetectorConfig` searched with; assigning one replans every frame size."""
        return self.box_finder.config

    @config.setter
    def config(self, config):
        self.box_finder.config = config
        self._plans = {}

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
            plans = self._plans[frame_size] = plan_scales(self.config, self.model.options,
                                                          frame_size)
        return plans

    # -- stage 1: windows ---------------------------------------------------
    def prepare(self, frame):
        """Colour-convert the part of a frame any scale searches, once.

        Returns
        -------
        PreparedFrame
        """
        return self.scorer.prepare(frame, self.plans((frame.shape[1], frame.shape[0])))

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
        return self.scorer.score_scale(prepared, plan,
                                       self.timings if timings is None else timings)

    def hits(self, frame):
        """Every window whose margin exceeds ``search.decision_threshold``.

        Parameters
        ----------
        frame : ndarray
            BGR uint8 image (see :func:`~fastdet.detector.frames.as_bgr_frame`).

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

    # -- stage 2: heat and boxes ----------------------------------------------
    def heat_region(self, hits, frame_size):
        """Heat of the hits over their bounding region (see :meth:`BoxFinder.heat_region`)."""
        return self.box_finder.heat_region(hits, frame_size, self.plans(frame_size))

    def heatmap(self, frame):
        """Full-frame heat map of one frame (float32, frame height x width)."""
        frame = as_bgr_frame(frame)
        size = (frame.shape[1], frame.shape[0])
        heat, (x0, y0) = self.heat_region(self.hits(frame), size)
        full = np.zeros(frame.shape[:2], dtype=np.float32)
        full[y0:y0 + heat.shape[0], x0:x0 + heat.shape[1]] = heat
        return full

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
        boxes, peaks = self.box_finder.heat_components(heat, origin, frame_size)
        return self.box_finder.finish_boxes(boxes, peaks, frame_size, heat, origin)

    def warm_up(self, frame):
        """Detect once on ``frame`` so that every kernel a detection needs is loaded.

        The first detection of a process loads the compiled kernels from the
        cache, or compiles them when the cache is empty (once per machine and
        fastdet version); callers that report speed call this first, so the
        speed they report is the detector's own.

        Returns
        -------
        float
            Seconds it took.
        """
        start = time.perf_counter()
        self(frame)
        return time.perf_counter() - start

    def __call__(self, frame):
        """Detect vehicles in one frame.

        Parameters
        ----------
        frame : ndarray of uint8, shape (H, W, 3)
            BGR image (grey and BGRA accepted, see
            :func:`~fastdet.detector.frames.as_bgr_frame`).

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
