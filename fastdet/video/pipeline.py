"""Temporal logic for video: smoothing, frame skipping, patch tracking, stable ids.

:class:`VideoPipeline` turns a stream of frames into boxes with track ids.
Each temporal component is a small class, switched and tuned by the
``[track]`` section of the TOML configuration (:class:`TrackConfig`)::

    [track]
    every = 5                        # a full detection at least every 5th frame
    heat_smoothing = "exponential"   # or "fir" (mean of the last heat_frames maps) or "none"
    heat_alpha = 0.25                # new = (1 - alpha) * old + alpha * current
    box_frames = 4                   # box corners averaged over the last 4 measurements
    tracking = true                  # patch tracking between full detections

One frame goes through these steps:

1. With ``tracking``, every vehicle is looked for near its last position by
   the overlap of saturation masks with the patch it was first detected in
   (:class:`PatchModel`); the box moves with the best match, or the vehicle
   is *lost* when no placement overlaps more than ``min_patch_overlap``.
2. A full detection runs when ``every`` frames have passed since the last
   one (every frame by default without tracking), and with ``tracking`` also
   when no vehicle is tracked, one was lost, or the frame differs enough
   from the last fully searched one (:class:`SceneChangeTrigger`).
3. A full detection takes the detector's hits; with ``tracking``, hits
   entirely inside a tracked box are dropped (the vehicle is already known
   there), so only new vehicles are searched for.  Their heat is smoothed
   over frames (:class:`ExponentialHeat`, :class:`FirHeat`) and turned into
   boxes by the detector.
4. Boxes are associated with tracks (:class:`TrackTable`), so a vehicle
   keeps its id: without tracking by IoU; with tracking a new box lying
   mostly inside a tracked box (``merge_overlap``) is merged into it, and a
   box matching a lost vehicle revives its id.
5. Each track's box is the mean of its last ``box_frames`` measured boxes
   (:class:`BoxHistory`), so boxes do not jitter.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import threading
import time

import numpy as np

from ..detector.detections import Detections
from ..detector.frames import as_bgr_frame
from ..detector.plan import search_band
from ..errors import InputError
from .ahead import MAX_WORKERS, process_ahead
from .config import TrackConfig
from .patch import SceneChangeTrigger
from .smoothing import make_heat_smoother
from .tracking import TrackTable


# -- the pipeline -------------------------------------------------------------------
class _Stopwatch:
    """Calls methods and sums the time they take."""

    def __init__(self):
        self.seconds = 0.0

    def __call__(self, method, *args):
        start = time.perf_counter()
        result = method(*args)
        self.seconds += time.perf_counter() - start
        return result


#: What :class:`VideoPipeline` calls on its detector.
DETECTOR_METHODS = ("hits", "heat_region", "boxes_from_heat")


def detector_problem(detector):
    """Why ``detector`` cannot be a :class:`VideoPipeline`'s detector, or ``None``.

    The one rule for both entry points: :class:`VideoPipeline` raises it as a
    ``TypeError``, :func:`fastdet.video.run.process_video` as the
    :class:`~fastdet.errors.InputError` its one-line problems are.
    """
    if isinstance(detector, type):
        return f"detector must be an instance, got the class {detector.__name__}"
    missing = [name for name in DETECTOR_METHODS if not callable(getattr(detector, name, None))]
    if missing:
        return (f"detector must be a fastdet.Detector or have its methods "
                f"{', '.join(DETECTOR_METHODS)}; {type(detector).__name__} "
                f"lacks {', '.join(missing)}")
    return None


def _whole_number(name, value, low=None, high=None):
    # Checked when the run is asked for, not at its first frame: 2.5 once gave
    # indices 2.5, 3.5, ... and workers=10**6 built a million detectors.
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InputError(f"{name} must be a whole number, got {value!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise InputError(f"{name} must be {low}-{high}, got {value}")
    return int(value)


def _on_schedule(first, period, index):
    """Whether frame ``index`` is searched when every ``period``-th from ``first`` is."""
    return (index - first) % period == 0


def hits_outside(hits, boxes):
    """The hits whose window is not entirely inside any of ``boxes``.

    Parameters
    ----------
    hits : fastdet.detector.scoring.Hits
    boxes : ndarray of int, shape (T, 4)

    Returns
    -------
    Hits
    """
    if len(boxes) == 0 or len(hits.scores) == 0:
        return hits
    h = hits.boxes[:, None, :]
    b = np.asarray(boxes)[None, :, :]
    inside = ((h[..., 0] >= b[..., 0]) & (h[..., 1] >= b[..., 1])
              & (h[..., 2] <= b[..., 2]) & (h[..., 3] <= b[..., 3]))
    keep = ~inside.any(axis=1)
    return dataclasses.replace(hits, boxes=hits.boxes[keep], scores=hits.scores[keep],
                               scale_index=hits.scale_index[keep])


class VideoPipeline:
    """Detection with temporal logic over a stream of frames.

    Parameters
    ----------
    detector : fastdet.Detector
        Anything with the detector's ``hits(frame)``,
        ``heat_region(hits, size)`` and ``boxes_from_heat(heat, origin,
        size, frame)`` methods.
    config : TrackConfig, optional
        Temporal settings; defaults built in (detection on every frame,
        exponential heat smoothing, stable ids).

    Attributes
    ----------
    seconds : dict
        Time spent in ``"detect"`` (the detector's calls) and ``"track"``
        (everything temporal), summed over the frames processed.
    frames, full_searches : int
        Frames processed and how many of them were fully searched.

    Raises
    ------
    TypeError
        When ``detector`` is a class or lacks one of those methods, or
        ``config`` is not a :class:`TrackConfig`.

    Notes
    -----
    Frames must come in order; a change of frame size starts over (new
    tracks).  Frame indices are counted from ``first_index``.

    A pipeline is the state of one stream: calling :meth:`process` from a
    second thread while one call is running raises :class:`RuntimeError`
    rather than mixing two streams' frames.  Give each thread a pipeline of
    its own (they may share one :class:`~fastdet.Detector`).

    Examples
    --------
    >>> pipeline = VideoPipeline(Detector(), TrackConfig(every=5))   # doctest: +SKIP
    >>> capture = cv2.VideoCapture(0)                                # doctest: +SKIP
    >>> frames = iter(lambda: capture.read()[1], None)               # doctest: +SKIP
    >>> for index, frame, boxes, track_ids in pipeline(frames):      # doctest: +SKIP
    ...     print(index, boxes.tolist(), track_ids.tolist())
    """

    def __init__(self, detector, config=None):
        # Checked here: else the first frame failed deep inside, with an AttributeError.
        problem = detector_problem(detector)
        if problem is not None:
            raise TypeError(problem)
        if config is None:
            config = TrackConfig()
        elif not isinstance(config, TrackConfig):
            raise TypeError(f"config must be a TrackConfig (TrackConfig.from_dict or "
                            f"load_track_config make one), got {type(config).__name__}")
        self.detector = detector
        self.config = config
        self._busy = threading.Lock()
        self.reset()

    def __getstate__(self):
        # A lock does not pickle or copy: a copy (copy.deepcopy, pickle) gets its own.
        state = self.__dict__.copy()
        del state["_busy"]
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._busy = threading.Lock()

    def warm_up(self, frame):
        """Load (or compile) every kernel processing ``frame`` calls; returns the seconds it took.

        The detector's warm-up, then two frames through a scratch pipeline
        of the same detector and settings: the heat smoothing's and the
        tracker's kernels load too, so that a run's first frame waits for
        none (on a cold cache they compiled inside it, counted as frame
        time).  This pipeline's own state is untouched.
        """
        start = time.perf_counter()
        detector_warm_up = getattr(self.detector, "warm_up", None)
        if detector_warm_up is not None:
            detector_warm_up(frame)
        scratch = VideoPipeline(self.detector, self.config)
        for _ in range(2):
            scratch.process(frame)
        return time.perf_counter() - start

    def reset(self):
        """Forget all temporal state (tracks, smoothed heat, counters)."""
        self._tracks = TrackTable(self.config)
        self._heat = make_heat_smoother(self.config)
        self._since_full = None
        self._size = None
        self.seconds = {"detect": 0.0, "track": 0.0}
        self.last_heat = None
        self.frames = 0
        self.full_searches = 0

    def __call__(self, frames, first_index=0, workers=1):
        """Process an iterable of frames lazily.

        Parameters
        ----------
        frames : iterable of ndarray
            BGR uint8 frames (grey and BGRA accepted), in order; a stack of
            frames (one array of shape (N, H, W, C)) too, but not one frame.
        first_index : int
            Index of the first frame (e.g. the ``--start`` frame of a video);
            any whole number, negative too (warm-up frames before a range).
        workers : int
            Frames scored at once (1 to :data:`~fastdet.video.ahead.MAX_WORKERS`),
            each by a single-thread detector of its own
            (:func:`fastdet.video.ahead.process_ahead`; without patch
            tracking and with a :class:`~fastdet.Detector`): the same
            results as one at a time.

        Yields
        ------
        frame_index : int
        frame : ndarray
            The frame as given.
        boxes : ndarray of int32, shape (N, 4)
            ``[x1, y1, x2, y2]``, ``x2``/``y2`` exclusive.
        track_ids : ndarray of int64, shape (N,)

        Raises
        ------
        InputError
            At the call, before any frame is read, for a ``first_index`` or
            ``workers`` that is not such a whole number.
        TypeError
            At the call, for one frame given instead of an iterable of them
            (iterating it would take its rows for frames).
        """
        first_index = _whole_number("first_index", first_index)
        workers = _whole_number("workers", workers, 1, MAX_WORKERS)
        if isinstance(frames, np.ndarray) and (frames.ndim == 2 or frames.ndim == 3
                                               and frames.shape[2] in (1, 3, 4)):
            raise TypeError(f"frames must be an iterable of frames, got one frame of shape "
                            f"{frames.shape} (give [frame], or call process(frame))")
        return self._run(frames, first_index, workers)

    def _run(self, frames, first_index, workers):
        for offset, (frame, _, detections) in enumerate(process_ahead(self, frames, workers)):
            yield first_index + offset, frame, detections.xyxy, detections.track_id

    run = __call__

    @property
    def wants_frame(self):
        """Whether the next :meth:`process` call looks at the frame's pixels.

        It does not between periodic full detections without tracking; a
        caller may then pass ``None`` instead of decoding the frame (e.g.
        ``cv2.VideoCapture.grab`` without ``retrieve``).
        """
        return self.config.tracking or self._search_due()

    def rows_read(self, size):
        """``(y0, y1)``: the only rows of a ``size`` frame that :meth:`process` reads, or ``None``.

        Without tracking, the pipeline looks at nothing outside the detector's
        search band, so a caller may convert only those rows of a decoded
        frame (:class:`~fastdet.video.frame_arrays.FrameConverter`).
        ``None`` when it reads whole frames (tracking, or a detector without
        scale plans).
        """
        plans = getattr(self.detector, "plans", None)
        if self.config.tracking or plans is None:
            return None
        band = search_band(plans(size))
        return None if band is None else (band[1], band[3])

    def _search_due(self):
        # The periodic schedule only; tracking adds its triggers on top.
        period = self.config.search_period
        return self._since_full is None or (period is not None
                                            and self._since_full + 1 >= period)

    def frames_needed(self, first):
        """``needed(index) -> bool``: the frames :meth:`process` will look at, the next
        frame given to it being frame ``first``.

        ``None`` when it looks at every frame, or when that is not known
        ahead (tracking).  Readers leave the others undecoded where they can
        (:meth:`fastdet.video.source.VideoSource.decoded_frames`).
        """
        period = self.config.search_period
        if self.config.tracking or period is None or period <= 1:
            return None
        # The first True of searches_ahead(period), without a list of ``period``
        # entries (a period of 2**31 frames took minutes and gigabytes).
        since = self._since_full
        due = 0 if since is None else max(0, period - 1 - since)
        return functools.partial(_on_schedule, first + due, period)

    def searches_ahead(self, count):
        """Whether each of the next ``count`` frames will be fully searched, or ``None``.

        Known in advance only without tracking, where the schedule is the
        period alone (a frame of another size, which starts the stream over,
        is searched whatever this says).  Callers use it to compute the
        detector's hits of upcoming frames ahead (:mod:`fastdet.video.ahead`)
        and pass them to :meth:`process`.
        """
        if self.config.tracking:
            return None
        period = self.config.search_period
        since, due = self._since_full, []
        for _ in range(count):
            search = since is None or (period is not None and since + 1 >= period)
            due.append(search)
            since = 0 if search else since + 1
        return due

    def process(self, frame, hits=None):
        """Process the next frame of the stream.

        Parameters
        ----------
        frame : ndarray or None
            BGR uint8 frame (grey and BGRA accepted); ``None`` is allowed
            when :attr:`wants_frame` is False.
        hits : Hits, optional
            The detector's hits of this frame, computed ahead (by a detector
            with the same model and config); used if the frame is fully
            searched and ignored otherwise.

        Returns
        -------
        Detections
            With ``track_id`` set.

        Raises
        ------
        InputError
            For a frame that is not an image array, or ``None`` when the
            frame is needed.
        RuntimeError
            While another thread is in this pipeline's :meth:`process`.
        """
        if not self._busy.acquire(blocking=False):
            # Two threads' frames interleaved would be one stream's tracks and
            # heat fed with another's, silently: say so instead.
            raise RuntimeError("VideoPipeline.process called from two threads at once; "
                               "give each thread a pipeline of its own")
        try:
            return self._process(frame, hits)
        finally:
            self._busy.release()

    def _process(self, frame, hits):
        start = time.perf_counter()
        if frame is None:
            if self.wants_frame:
                raise InputError("this frame is needed (a full detection or tracking is due)")
            self._since_full += 1
            self.frames += 1
            detections = self._tracks.visible()
            self.seconds["track"] += time.perf_counter() - start
            return detections
        frame = as_bgr_frame(frame)
        size = (frame.shape[1], frame.shape[0])
        if size != self._size:
            self._start_stream(size)
        cfg = self.config
        search = self._search_due()
        thumbnail = None
        if cfg.tracking:
            lost = self._tracks.follow(frame, self._radius) if self._tracks.tracks else False
            no_vehicle = not any(not t.lost for t in self._tracks.tracks)
            search = search or lost or no_vehicle
            if not search:
                thumbnail = self._scene.thumbnail(frame)
                search = self._scene.changed(frame, thumbnail)
        detect_seconds = 0.0
        if search:
            detect_seconds = self._full_search(frame, size, thumbnail, hits)
            self._since_full = 0
            self.full_searches += 1
        else:
            self._since_full += 1
        detections = self._tracks.visible()
        self.frames += 1
        self.seconds["detect"] += detect_seconds
        self.seconds["track"] += time.perf_counter() - start - detect_seconds
        return detections

    # -- internals ------------------------------------------------------------------
    def _start_stream(self, size):
        # A new frame size is a new stream: no track or heat carries over,
        # but ids keep counting up so they stay unique for this pipeline.
        self._tracks.reset()
        self._heat.reset()
        self._since_full = None
        self._size = size
        width, height = size
        self._band = (0, 0, width, height)
        plans = getattr(self.detector, "plans", None)
        if plans is not None:
            # Heat is only ever non-zero where some scale searches.
            self._band = search_band(plans(size)) or self._band
        # Like the detector's scales, the radius is given for its reference
        # frame size (a detector without one: for the frame itself).
        search_config = getattr(getattr(self.detector, "config", None), "search", None)
        reference = getattr(search_config, "reference_size", None)
        # Not size / size: a frame without pixels (0 x 0) divided by zero.
        scale = 1.0 if reference is None else math.sqrt(width / reference[0]
                                                        * height / reference[1])
        self._radius = int(round(self.config.search_radius * scale))
        self._scene = SceneChangeTrigger(self.config.scene_change_threshold,
                                         self.config.thumbnail_factor,
                                         rows=(self._band[1], self._band[3]))

    def _full_search(self, frame, size, thumbnail=None, hits=None):
        """Detect, smooth, associate; returns the seconds spent in the detector."""
        detector = self.detector
        in_detector = _Stopwatch()
        if hits is None:
            hits = in_detector(detector.hits, frame)
        if not self.config.tracking:
            self._tracks.associate(self._detect(hits, size, in_detector, frame), frame)
            return in_detector.seconds
        tracked = self._tracks.tracked_boxes()
        everything = Detections.empty()
        if len(tracked):
            # The detector's own view, from all hits and unsmoothed, confirms
            # and refits the followed vehicles independently of the tracker.
            heat, origin = in_detector(detector.heat_region, hits, size)
            everything = in_detector(detector.boxes_from_heat, heat, origin, size, frame)
        # New vehicles are searched for outside the tracked boxes only.
        detections = self._detect(hits_outside(hits, tracked), size, in_detector, frame)
        self._tracks.merge(detections, everything, frame)
        self._scene.set_reference(frame, thumbnail)
        return in_detector.seconds

    def _detect(self, hits, size, in_detector, frame):
        heat, origin = in_detector(self.detector.heat_region, hits, size)
        heat, origin = self._smoothed_heat(heat, origin)   # the tracker's time
        #: The smoothed heat over a region of the last fully searched frame, and its origin.
        self.last_heat = (heat, origin)
        return in_detector(self.detector.boxes_from_heat, heat, origin, size, frame)

    def _smoothed_heat(self, heat, origin):
        if self.config.heat_smoothing == "none":
            return heat, origin
        # Smoothing needs the same pixels every frame: the whole search band.
        bx1, by1, bx2, by2 = self._band
        x1, y1 = max(origin[0], bx1), max(origin[1], by1)
        x2 = min(origin[0] + heat.shape[1], bx2)
        y2 = min(origin[1] + heat.shape[0], by2)
        region = np.zeros((0, 0), np.float32)
        if x2 > x1 and y2 > y1:
            region = heat[y1 - origin[1]:y2 - origin[1], x1 - origin[0]:x2 - origin[0]]
        else:
            x1, y1 = bx1, by1
        smoothed = self._heat.update(region, (x1 - bx1, y1 - by1), (by2 - by1, bx2 - bx1))
        return smoothed, (bx1, by1)
