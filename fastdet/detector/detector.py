"""The single-frame detector: search plan -> per-scale scoring -> heat -> boxes.

:class:`Detector` owns a model and a configuration and orchestrates three
parts, each testable on its own: the search plan of a frame size
(:mod:`.plan`), the per-scale scoring (:class:`~.scoring.ScaleScorer`) and
the heat-to-boxes step (:class:`~.boxes.BoxFinder`).  All per-pixel and
per-window work happens in the Numba kernels those parts call.
"""

from __future__ import annotations

import numbers
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from ..errors import ConfigError, InputError
from ..kernels.heat import windows_above
from ..kernels.warmup import warm
from .boxes import BoxFinder
from .config import DetectorConfig, load_config
from .frames import as_bgr_frame
from .horizon import HorizonEstimate, estimate_horizon, searched_at
from .model import Model, load_model
from .plan import plan_scales, search_band
from .scoring import STAGES, Hits, ScaleScorer, kernel_families


@dataclass(frozen=True)
class _Windows:
    """All windows of a frame size: boxes, the plan each is from, and the score
    array a frame's scales are scored into, one grid view per plan."""

    boxes: np.ndarray        # int32 (N, 4)
    scale_index: np.ndarray  # int64 (N,)
    scores: np.ndarray       # float32 (N,), refilled every frame under the detection lock
    grids: list              # per plan, its (Ny, Nx) view of ``scores``


class _Aborted(Exception):
    """Another thread of the frame failed (its own error is raised by the caller)."""


class _TaskQueue:
    """A frame's tasks, handed out in order to whichever thread asks; a scale's
    ``"windows"`` task waits until all of its ``"rows"`` tasks are done."""

    def __init__(self, tasks):
        self._tasks = iter(tasks)  # next() on a tuple iterator is atomic under the GIL
        self._lock = threading.Lock()
        self._pending = {}
        for task in tasks:
            if task.kind == "rows":
                self._pending[task.index] = self._pending.get(task.index, 0) + 1
        self._done = {index: threading.Event() for index in self._pending}
        self._aborted = False

    def __iter__(self):
        return self

    def __next__(self):
        return next(self._tasks)

    def rows_done(self, index):
        with self._lock:
            self._pending[index] -= 1
            if self._pending[index] == 0:
                self._done[index].set()

    def wait_for_rows(self, index):
        if index in self._done:
            self._done[index].wait()
        if self._aborted:
            raise _Aborted

    def abort(self):
        self._aborted = True
        for event in self._done.values():
            event.set()


#: Frame sizes whose plans, tasks and windows a detector keeps; older sizes are planned again.
PLANNED_SIZES = 16


def _as_config(config):
    """``config`` as a :class:`DetectorConfig`: a TOML file loaded, ``None`` the defaults."""
    if config is None:
        return DetectorConfig()
    if isinstance(config, (str, os.PathLike)):
        return load_config(config)
    if not isinstance(config, DetectorConfig):
        raise ConfigError(f"config must be a DetectorConfig or a TOML file, got "
                          f"{type(config).__name__}")
    return config


def _load_kernels(families):
    """The preload thread: a failure here only means each kernel loads (and
    reports any error) at its first call instead."""
    try:
        warm(families)
    except Exception:  # noqa: BLE001 - see the docstring
        pass


class Detector:
    """HOG + linear-SVM vehicle detector for single frames.

    Parameters
    ----------
    model : Model or str or Path, optional
        A :class:`~fastdet.detector.model.Model`, a model file, or ``None`` for the
        bundled default.
    config : DetectorConfig or str or Path, optional
        Search, heat and box settings, or a TOML file of them (see
        :func:`~fastdet.detector.config.load_config`); defaults built in.
    threads : int, optional
        Threads per frame.  ``None`` keeps Numba's setting
        (``NUMBA_NUM_THREADS``, all cores by default); 1 runs everything on
        the calling thread.  With more, the calling thread and a pool share
        each frame (the kernels release the GIL): each converts a chunk of
        the searched band's rows, then they take the frame's tasks
        (:meth:`~fastdet.detector.scoring.ScaleScorer.bands`: whole scales;
        the largest one's pixel rows cut in two, then its windows)
        costliest first, as each finishes one.  OpenCV is set to the same
        count so the two do not oversubscribe the cores.
    preload : bool
        Load the kernels a detection needs in a background thread from
        now on (compiling them on first use, shared with a second process;
        see :func:`fastdet.kernels.warmup.warm`); the first
        detection waits for it.  False: each kernel loads at its first call.

    Attributes
    ----------
    scorer : ScaleScorer
        Scores one scale plan of a prepared frame.
    box_finder : BoxFinder
        Turns hits into heat and heat into boxes.
    timings : dict
        Seconds spent per stage (see ``STAGES``) in the last call; with
        several threads, the scales' stage times are summed over threads.
    thread_busy : list of float
        Seconds each thread worked on the last frame's conversion and
        scoring (the calling thread first); the rest of ``timings["total"]``
        it waited, or (the calling thread) found boxes.
    thread_cpu : list of float
        CPU seconds each thread used for that work (``time.thread_time``):
        below ``thread_busy`` when other processes took the cores.

    Notes
    -----
    Frames are BGR uint8 arrays, OpenCV's convention (``cv2.imread`` and
    ``cv2.VideoCapture`` return them); grey and BGRA frames are converted.
    A frame smaller than the smallest window gives no boxes.

    One detector may be shared between threads: its detections (calls,
    :meth:`hits`, :meth:`heatmap`) run one at a time, each already using
    ``threads`` cores and the detector's reused work arrays, and give what
    serial calls give.  For detections running side by side, give each
    thread its own detector.

    A detector can be pickled (to hand it to ``multiprocessing``,
    ``concurrent.futures`` or joblib workers): the copy is built again from
    the model, the configuration and the arguments it was given, and searches
    at the horizon the original had taken.

    Examples
    --------
    >>> detector = Detector()                      # doctest: +SKIP
    >>> detections = detector(cv2.imread("frame.jpg"))  # doctest: +SKIP
    >>> detections.xyxy, detections.score          # doctest: +SKIP
    """

    def __init__(self, model=None, config=None, threads=None, preload=True):
        self._arguments = (threads, preload)
        if not isinstance(model, Model):
            model = load_model(model)
        self.model = model
        if threads is not None:
            if isinstance(threads, bool) or not isinstance(threads, numbers.Integral):
                raise InputError(f"threads must be a whole number, got {threads!r}")
            if threads < 1:
                raise InputError(f"threads must be at least 1, got {threads}")
            threads = min(int(threads), numba.config.NUMBA_NUM_THREADS)
            numba.set_num_threads(threads)
            cv2.setNumThreads(threads)
        self.threads = numba.get_num_threads() if threads is None else threads
        self._pool = None
        # One detection at a time per detector: the work arrays are reused.
        self._detecting = threading.RLock()
        self.scorer = ScaleScorer(model)
        self.box_finder = BoxFinder(_as_config(config))
        self._requested_config = self.box_finder.config
        self._plans = {}
        self._bands = {}
        self._all_windows = {}
        self._search_bands = {}
        self.timings = dict.fromkeys(STAGES, 0.0)
        self.thread_busy = [0.0] * self.threads
        self.thread_cpu = [0.0] * self.threads
        self._loader = None
        if preload:
            # Load (or compile) the kernels while the caller reads its first
            # frame; the first detection waits for it (see _kernels_loaded).
            self._loader = threading.Thread(target=_load_kernels,
                                            args=(kernel_families(model.options),),
                                            name="fastdet-kernels", daemon=True)
            self._loader.start()

    @property
    def config(self):
        """The :class:`DetectorConfig` searched with; assigning one replans every frame size.

        Its ``[search] horizon`` may be ``"auto"``: then :meth:`resolve_horizon`
        must give it the camera's before a frame is searched.
        """
        return self.box_finder.config

    @config.setter
    def config(self, config):
        config = _as_config(config)
        self._requested_config = config
        self._search_with(config)

    def _search_with(self, config):
        self.box_finder.config = config
        self._plans = {}
        self._bands = {}
        self._all_windows = {}
        self._search_bands = {}

    @property
    def auto_horizon(self):
        """Whether the configured horizon is ``"auto"`` (see :meth:`resolve_horizon`)."""
        return self._requested_config.search.auto_horizon

    def resolve_horizon(self, frames):
        """Search at the horizon ``frames`` show, if the configured one is ``"auto"``.

        Resolved from the configuration as assigned, so a detector serving
        several cameras (videos in turn) takes each one's horizon.

        Parameters
        ----------
        frames : iterable of ndarray
            Frames of the camera (a video's first few, or one image); read
            only when the horizon is ``"auto"``.

        Returns
        -------
        HorizonEstimate or None
            ``None`` when the configured horizon is a number.  Without lane
            lines in enough frames the estimate's ``fraction`` is ``None`` and
            the built-in default horizon is searched.

        Raises
        ------
        TypeError
            For one frame not in a list (``[frame]``).
        InputError
            For a frame that detection refuses too.
        """
        if not self.auto_horizon:
            return None
        estimate = estimate_horizon(frames)
        self.take_horizon(estimate)
        return estimate

    def take_horizon(self, estimate):
        """Search at the horizon of an ``estimate`` already made (of the camera's
        frames, :func:`~fastdet.detector.horizon.estimate_horizon`), if the
        configured horizon is ``"auto"``; a numeric one stays.

        Raises
        ------
        TypeError
            When ``estimate`` is not a
            :class:`~fastdet.detector.horizon.HorizonEstimate` (a number is
            not one: ``detector.config = detector.config.with_horizon(0.55)``
            searches at a given horizon).
        """
        # Checked whatever the configured horizon, so that a wrong argument is
        # found on the first call; it failed on an attribute only when "auto".
        if not isinstance(estimate, HorizonEstimate):
            raise TypeError(f"take_horizon needs a HorizonEstimate (from estimate_horizon), "
                            f"got {type(estimate).__name__}; to search at a given horizon, "
                            f"assign detector.config = detector.config.with_horizon(fraction)")
        if self.auto_horizon:
            config = searched_at(self._requested_config, estimate)
            if config != self.config:
                self._search_with(config)

    def __reduce__(self):
        # Locks, threads and compiled plans do not cross processes: the copy is
        # built again from the model, the configuration as given and as searched
        # (a horizon taken stays taken) and the arguments, so that a detector can
        # be handed to multiprocessing, concurrent.futures or joblib workers.
        threads, preload = self._arguments
        return (_rebuilt_detector,
                (self.model, self._requested_config, self.config, threads, preload))

    def __del__(self):
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=False)

    def _kernels_loaded(self):
        """Wait for the kernel loading started by ``__init__`` (once)."""
        loader = self._loader
        if loader is not None:
            loader.join()
            self._loader = None

    def _worker_pool(self):
        """The threads that score bands beside the calling thread (threads > 1)."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=self.threads - 1,
                                            thread_name_prefix="fastdet-scale")
        return self._pool

    def plans(self, frame_size):
        """The scale plans for frames of ``(width, height)`` (cached for the last
        :data:`PLANNED_SIZES` sizes)."""
        plans = self._plans.get(frame_size)
        if plans is None:
            # Threads planning the same size at once all keep the first plans stored.
            plans = self._plans.setdefault(
                frame_size, plan_scales(self.config, self.model.options, frame_size))
            # A folder of images of every size must not grow the caches without end.
            for size in list(self._plans)[:-PLANNED_SIZES]:
                for cache in (self._plans, self._bands, self._all_windows, self._search_bands):
                    cache.pop(size, None)
        return plans

    def _search_band(self, frame_size):
        """:func:`~fastdet.detector.plan.search_band` of the size's plans, kept with them."""
        band = self._search_bands.get(frame_size)
        if band is None:
            band = self._search_bands[frame_size] = search_band(self.plans(frame_size))
        return band

    def bands(self, frame_size):
        """The frame's scoring tasks for this detector's threads (:meth:`.ScaleScorer.bands`)."""
        bands = self._bands.get(frame_size)
        if bands is None:
            bands = self._bands[frame_size] = self.scorer.bands(self.plans(frame_size),
                                                                self.threads)
        return bands

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
        with self._detecting:
            return self._hits(frame)

    def _hits(self, frame):
        """:meth:`hits` of a checked frame, with the detection lock held."""
        self._kernels_loaded()
        for stage in STAGES:
            self.timings[stage] = 0.0
        size = (frame.shape[1], frame.shape[0])
        plans = self.plans(size)
        bands = self.bands(size)
        windows = self._windows(size)
        # Every scale's grid is a view of one score array: one threshold and
        # one gather find the hits of all of them.  The array is the frame
        # size's own, reused (the hits are copied out of it).
        scores, grids = windows.scores, windows.grids
        scores.fill(self.model.bias)
        prepared = self.scorer.frame_buffers(plans)
        workers = min(self.threads, max(len(bands), 1))
        if workers > 1:
            self._score_concurrently(frame, prepared, plans, bands, grids, workers)
        else:
            timings = dict.fromkeys(STAGES, 0.0)
            share = self._score_share(frame, prepared, plans, _TaskQueue(bands), grids, timings,
                                      (0, 1))
            self._record_shares([share])
            self._add_timings(timings)
        # One kernel, not five NumPy calls (see windows_above).
        threshold = np.float32(self.config.search.decision_threshold)
        return Hits(*windows_above(scores, threshold, windows.boxes, windows.scale_index),
                    len(scores))

    def _windows(self, frame_size):
        """Every window of a frame size's plans, in plan order (cached)."""
        windows = self._all_windows.get(frame_size)
        if windows is None:
            plans = self.plans(frame_size)
            counts = [plan.n_windows for plan in plans]
            starts = np.cumsum([0] + counts).tolist()
            scores = np.empty(starts[-1], np.float32)
            windows = self._all_windows[frame_size] = _Windows(
                np.concatenate([plan.boxes for plan in plans]) if plans
                else np.zeros((0, 4), np.int32),
                np.repeat(np.arange(len(plans), dtype=np.int64), counts),
                scores,
                [scores[start:start + plan.n_windows].reshape(plan.grid)
                 for plan, start in zip(plans, starts)])
        return windows

    def _score_share(self, frame, prepared, plans, tasks, grids, timings, part, converted=None):
        """One thread's share of a frame: its part of the colour conversion, then
        bands taken from ``tasks`` until none is left.  Returns the seconds it
        worked and the CPU seconds it used.

        ``part``: ``(k, n)``, this thread converts the k-th of n row chunks;
        ``converted``: a barrier all chunks pass before any band is scored.
        """
        try:
            cpu = time.thread_time()
            start = time.perf_counter()
            if prepared.converted is not None:
                rows = prepared.converted.shape[0]
                k, n = part
                self.scorer.convert_rows(frame, prepared, k * rows // n, (k + 1) * rows // n)
            busy = time.perf_counter() - start
            timings["resize_convert"] += busy
            if converted is not None:
                converted.wait()
            # Tasks are taken in order, costliest first, by whichever thread is free.
            for task in tasks:
                if task.kind == "windows":
                    tasks.wait_for_rows(task.index)
                begin = time.perf_counter()
                self.scorer.run(task, prepared, plans, grids, timings)
                busy += time.perf_counter() - begin
                if task.kind == "rows":
                    tasks.rows_done(task.index)
            return busy, time.thread_time() - cpu
        except BaseException:
            # The other threads stop waiting for this one.
            tasks.abort()
            if converted is not None:
                converted.abort()
            raise

    def _score_concurrently(self, frame, prepared, plans, bands, grids, workers):
        """Score the bands of a frame on ``workers`` threads, the calling one included."""
        tasks = _TaskQueue(bands)
        converted = threading.Barrier(workers)
        shares = [dict.fromkeys(STAGES, 0.0) for _ in range(workers)]
        futures = [self._worker_pool().submit(self._score_share, frame, prepared, plans, tasks,
                                              grids, shares[k], (k, workers), converted)
                   for k in range(1, workers)]
        try:
            mine = self._score_share(frame, prepared, plans, tasks, grids, shares[0],
                                     (0, workers), converted)
        except (threading.BrokenBarrierError, _Aborted):
            mine = (0.0, 0.0)  # a worker failed: future.result() raises its error
        self._record_shares([mine] + [future.result() for future in futures])
        for timings in shares:
            self._add_timings(timings)

    def _record_shares(self, shares):
        idle = [0.0] * (self.threads - len(shares))
        self.thread_busy = [busy for busy, _ in shares] + idle
        self.thread_cpu = [cpu for _, cpu in shares] + idle

    def _add_timings(self, timings):
        for stage, seconds in timings.items():
            self.timings[stage] += seconds

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

    def boxes_from_heat(self, heat, origin, frame_size, frame=None):
        """Threshold, label and filter a heat map into detections.

        Parameters
        ----------
        heat : ndarray of float32, shape (h, w)
            Heat over a region of the frame.
        origin : tuple of int
            ``(x0, y0)`` of that region in the frame.
        frame_size : tuple of int
            ``(width, height)`` of the frame, for the size-relative filters.
        frame : ndarray of uint8, optional
            The frame the heat is of (BGR; grey and BGRA accepted, see
            :func:`~fastdet.detector.frames.as_bgr_frame`): the refined boxes'
            sides snap to its edges (``[boxes] snap_sides``), read inside the
            search band only.
        """
        boxes, peaks = self.box_finder.heat_components(heat, origin, frame_size)
        readable = None
        if frame is not None:
            frame = as_bgr_frame(frame)   # a grey or BGRA frame too, as detection takes them
            readable = self._search_band(frame_size)
        return self.box_finder.finish_boxes(boxes, peaks, frame_size, heat, origin, frame,
                                            readable)

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
        with self._detecting:
            hits = self._hits(frame)
            t0 = time.perf_counter()
            heat, origin = self.heat_region(hits, size)
            t1 = time.perf_counter()
            detections = self.boxes_from_heat(heat, origin, size, frame)
            end = time.perf_counter()
            self.timings["heat"] = t1 - t0
            self.timings["label"] = end - t1
            self.timings["total"] = end - start
            self.last_windows_scored = hits.windows_scored
        return detections


def _rebuilt_detector(model, requested_config, searched_config, threads, preload):
    """A pickled :class:`Detector` again (see ``Detector.__reduce__``)."""
    detector = Detector(model, requested_config, threads, preload)
    if searched_config != requested_config:
        detector._search_with(searched_config)
    return detector
