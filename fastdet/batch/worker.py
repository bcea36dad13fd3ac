"""What runs on the workers: the set-up plugin and the tasks.

:class:`BatchSetup` is registered once per batch (named after the model's
and the configuration's hashes) and set up once per worker process: it
sets the allocator up for frames (:mod:`fastdet.video.memory`), loads the
model from the bytes it carries and runs the pipeline on a noise frame,
which loads the compiled kernels from Numba's cache (or compiles them once,
on a machine whose cache is empty).  Tasks then only
carry paths and the plugin's name; each task thread builds its
:class:`~fastdet.Detector` on the shared model once.

A task turns the errors a bad video causes (:class:`~fastdet.FastdetError`,
``OSError``) into a ``failed`` result with a one-line reason, so they are
not retried; anything else propagates, and Dask retries the task.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import threading
import time
from pathlib import Path

import numba
import numpy as np
from distributed import get_worker
from distributed.diagnostics.plugin import WorkerPlugin

from ..detector.detector import Detector
from ..detector.scoring import kernel_families
from ..errors import FastdetError
from ..kernels.warmup import cold_families, warm
from .boundary import IdMap
from .job import process_one, render_one, warm_up
from ..video.memory import reuse_freed_frames
from .merge import concatenate_videos, merge_detections
from .outputs import OutputPaths
from .split_search import replay_segments, search_segment

#: Size of the synthetic frame the set-up detects on (noise makes many windows
#: hits, so heat and labelling run as well as scoring).
WARMUP_FRAME = (720, 1280, 3)


class BatchSetup(WorkerPlugin):
    """Per-worker set-up of a batch: thread counts, model, compiled kernels.

    Parameters
    ----------
    settings : fastdet.batch.settings.BatchSettings
    """

    idempotent = True

    def __init__(self, settings):
        self.settings = settings
        self.name = settings.name
        self.model = None
        self.setup_seconds = None
        self._local = threading.local()

    def __getstate__(self):
        return {"settings": self.settings, "name": self.name}

    def __setstate__(self, state):
        self.__init__(state["settings"])

    async def setup(self, worker):
        # Off the worker's event loop: compiling kernels may take half a minute.
        await asyncio.get_running_loop().run_in_executor(None, self.prepare)

    def prepare(self):
        """Load the model and the kernels in this process (idempotent)."""
        if self.model is not None:
            return
        start = time.perf_counter()
        adopt_thread_count()
        reuse_freed_frames()
        self.model = self.settings.model()
        warm_up(self.detector(), self.settings.track_config, warm_up_frame())
        self.setup_seconds = time.perf_counter() - start

    def detector(self):
        """This thread's detector on the shared model (Numba's thread count is per thread)."""
        detector = getattr(self._local, "detector", None)
        if detector is None:
            detector = self._local.detector = Detector(
                self.model, self.settings.detector_config, threads=self.settings.threads)
        return detector


def warm_up_frame():
    """The frame a batch's pipeline warms up on (a 720p frame of noise)."""
    return np.random.default_rng(0).integers(0, 256, WARMUP_FRAME, dtype=np.uint8)


def compile_for_local_workers(settings, notice=contextlib.nullcontext):
    """Compile the kernels the batch's workers will need here, once, if none are cached yet.

    The workers of a local cluster share this machine's kernel cache.  On a
    cold cache each would compile every kernel itself as it sets up, all of
    them at once and each with a helper process of its own (2 workers of 2
    videos on 2 cores: the batch took 26 s against 9 s warm).  Compiled here
    first, over two processes as a detection compiles them, and run through
    the workers' own warm-up, the workers load them.

    Parameters
    ----------
    settings : BatchSettings
    notice : callable, optional
        A context manager factory wrapped around the compile (the command
        line's "compiling kernels" notice).

    Returns
    -------
    float
        Seconds it took (0.0 with the detection's kernels cached).
    """
    model = settings.model()
    # The video pipeline's own kernels too: heat smoothing, and patch tracking if asked for.
    families = [*kernel_families(model.options), "smooth"]
    if settings.track_config.tracking:
        families.append("track")
    if not cold_families(families):
        return 0.0
    start = time.perf_counter()
    with notice():
        warm(families)
        warm_up(Detector(model, settings.detector_config, threads=1), settings.track_config,
                warm_up_frame())
    return time.perf_counter() - start


def adopt_thread_count():
    """Let Numba take ``NUMBA_NUM_THREADS`` from the environment now, before its threads start.

    A worker process that Dask's nanny spawns from a script which imports
    fastdet (the ``fastdet`` console script does) imports Numba while it
    loads that script, before the nanny sets the worker's environment: Numba
    then sizes its thread pool for every core, and the first kernel compiled
    after the pool started (a cold cache) failed on the changed variable.
    If the pool already runs, the variable is set back to its size instead.
    """
    try:
        numba.core.config.reload_config()
    except RuntimeError:   # the pool was started before: keep its size
        os.environ["NUMBA_NUM_THREADS"] = str(numba.config.NUMBA_NUM_THREADS)


def _setup(name):
    worker = get_worker()
    plugin = worker.plugins.get(name)
    if plugin is None:
        raise RuntimeError(f"worker {worker.address} has no plugin {name}")
    plugin.prepare()
    return worker, plugin


def _reporter(worker, topic, key):
    if topic is None:
        return None
    return lambda frames: worker.log_event(topic, {"key": key, "frames": int(frames)})


def _failed(exc):
    return {"status": "failed", "reason": " ".join(str(exc).split()) or type(exc).__name__}


def video_task(name, job):
    """Process one video or one segment on a worker (see :func:`fastdet.batch.job.process_one`).

    ``job`` holds ``input``, ``outputs`` (a dict of paths), ``frame_range``,
    ``warmup``, ``format``, ``track_order``, ``topic`` and ``key``.
    """
    worker, plugin = _setup(name)
    outputs = OutputPaths.from_dict(job["outputs"])
    try:
        result = process_one(job["input"], outputs, plugin.settings, job.get("frame_range"),
                             job.get("warmup", 0), detector=plugin.detector(),
                             detections_format=job.get("format"),
                             track_order=job.get("track_order"),
                             callback=_reporter(worker, job.get("topic"), job.get("key")))
        result["status"] = "done"
    except (FastdetError, OSError) as exc:
        result = _failed(exc)
    result.update(worker=worker.address, setup_seconds=plugin.setup_seconds)
    return result


def search_task(name, job):
    """Phase 1 of a segmented video without patch tracking (:func:`~.split_search.search_segment`).

    ``job`` holds ``input``, ``frame_range``, ``hits`` (the file to write),
    ``topic`` and ``key``.
    """
    started = time.time()
    worker, plugin = _setup(name)
    try:
        result = search_segment(job["input"], job["frame_range"], Path(job["hits"]),
                                plugin.settings, detector=plugin.detector(),
                                callback=_reporter(worker, job.get("topic"), job.get("key")))
        result["status"] = "done"
    except (FastdetError, OSError) as exc:
        result = _failed(exc)
    result.update(started=started, finished=time.time(), worker=worker.address)
    return result


def replay_task(name, job):
    """Phase 2 of a segmented video without patch tracking (:func:`~.split_search.replay_segments`).

    ``job`` holds ``hits`` and ``detections``: per segment, the file its
    search wrote and its detections to write for drawing (or ``None``); and
    ``whole``: the video's detections file (or ``None``).
    """
    started = time.time()
    worker, plugin = _setup(name)
    try:
        segments = replay_segments([Path(p) for p in job["hits"]],
                                   [p and Path(p) for p in job["detections"]], plugin.settings,
                                   detector=plugin.detector(),
                                   whole=job["whole"] and Path(job["whole"]))
        result = {"status": "done", "segments": segments}
    except (FastdetError, OSError) as exc:
        result = _failed(exc)
    result.update(started=started, finished=time.time(), worker=worker.address)
    return result


def render_task(job):
    """Draw a segment's boxes into its part of the annotated video (``job``: see the runner)."""
    started = time.time()
    outputs = OutputPaths.from_dict({"video": job["video"], "detections": None,
                                     "thumbnail": job["thumbnail"]})
    try:
        frames = render_one(job["input"], job["frame_range"], Path(job["detections"]),
                            IdMap.from_dict(job["ids"]), outputs, job["threads"],
                            job["encoder"])
        result = {"status": "done", "frames": frames}
    except (FastdetError, OSError) as exc:
        result = _failed(exc)
    result.update(started=started, finished=time.time(), worker=get_worker().address)
    return result


def merge_task(job):
    """Join a long video's segments into its outputs (see :mod:`fastdet.batch.merge`).

    ``job`` holds ``parts`` (per segment: ``video``, ``detections`` and its
    ``ids`` map as a dict), ``outputs`` and ``format``.
    """
    started = time.time()
    try:
        parts, outputs = job["parts"], job["outputs"]
        if outputs.get("detections"):
            merge_detections([Path(p["detections"]) for p in parts],
                             [IdMap.from_dict(p["ids"]) for p in parts],
                             Path(outputs["detections"]), job["format"])
        if outputs.get("video"):
            concatenate_videos([Path(p["video"]) for p in parts], Path(outputs["video"]))
        result = {"status": "done"}
    except (FastdetError, OSError) as exc:
        result = _failed(exc)
    result.update(started=started, finished=time.time(), worker=get_worker().address)
    return result


def worker_report(out_dir, probe_name):
    """What the client checks on every worker: fastdet's version and the shared folder."""
    from .._version import __version__

    probe = Path(out_dir) / probe_name
    return {"version": __version__, "sees_out_dir": probe.is_file()}
