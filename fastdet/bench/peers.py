"""The peers fastdet is timed against, and where they live.

* ``reference``: the seed-faithful reference pipeline
  (``benchmarks/reference.py`` of the checkout; scikit-image HOG and one
  scikit-learn call per window), same model, same windows;
* ``opencv``: OpenCV's ``HOGDescriptor`` with a linear SVM trained on its own
  grey HOG features, run by ``benchmarks/opencv_peer/peer.py`` in its own
  virtual environment (OpenCV 5, which fastdet uses, has no
  ``HOGDescriptor``), frame by frame on request; see :class:`OpenCVPeer`.
"""

from __future__ import annotations

import importlib.util
import json
import os
import queue
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

from ..errors import InputError
from .timing import PipelineResult

#: Environment variable naming the OpenCV peer's virtual environment.
OPENCV_PEER_ENV = "FASTDET_OPENCV_PEER"

#: OpenCV's run-time dispatch levels (its names in ``OPENCV_CPU_DISABLE`` and
#: ``cv2.getCPUFeaturesLine()``) above its x86 baseline, lowest first.
OPENCV_DISPATCH_LEVELS = ("SSE4.1", "SSE4.2", "AVX", "FP16", "AVX2", "AVX512-SKX")


#: ``winStride`` of the OpenCV peer's native ``detectMultiScale`` search, in
#: pixels of the 64-pixel window (75% overlap: the densest overlap fastdet's
#: default scales use).
NATIVE_WIN_STRIDE = 16


# -- peers: where they live ---------------------------------------------------
def benchmarks_dir():
    """The checkout's ``benchmarks/`` folder (peers live there), or None."""
    for root in (Path.cwd(), Path(__file__).resolve().parents[2]):
        if (root / "benchmarks" / "reference.py").is_file():
            return root / "benchmarks"
    return None


def load_reference_module():
    """The seed-faithful reference from the checkout's ``benchmarks/``, or None."""
    folder = benchmarks_dir()
    if folder is None:
        return None
    spec = importlib.util.spec_from_file_location("fastdet_bench_reference",
                                                  folder / "reference.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def opencv_peer_python():
    """Python of the OpenCV peer's virtual environment, or None if not set up.

    The environment is ``$FASTDET_OPENCV_PEER`` (default
    ``~/.cache/fastdet/opencv-peer``), made by
    ``benchmarks/opencv_peer/setup.sh``.
    """
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    venv = Path(os.environ.get(OPENCV_PEER_ENV, cache / "fastdet" / "opencv-peer"))
    python = venv / "bin" / "python"
    return python if python.is_file() else None


def cache_dir():
    """Where benchmarks keep data-derived artefacts (never in the checkout)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return cache / "fastdet"


# -- OpenCV peer ---------------------------------------------------------------
def opencv_levels_above_build():
    """OpenCV's dispatch levels above the vector paths fastdet's kernels are compiled for.

    ``NUMBA_CPU_NAME=haswell NUMBA_CPU_FEATURES=`` on an AVX-512 machine builds
    the kernels every AVX2-only CPU runs; the peer then leaves out
    OpenCV's AVX-512 code too, so the ratio is the one such a CPU would show.
    With AVX-512 kernels nothing is left out; with neither AVX2 nor AVX-512
    (the SSE paths) every level above OpenCV's SSE3 baseline is.  Levels the
    CPU lacks are named as well, which OpenCV ignores.
    """
    from ..kernels._llvm import HAVE_AVX2, HAVE_AVX512F

    if HAVE_AVX512F:
        return ()
    if HAVE_AVX2:
        return ("AVX512-SKX",)
    return OPENCV_DISPATCH_LEVELS


def opencv_peer_environment(environ=None):
    """The peer's environment: ``environ`` (default ``os.environ``) with
    :func:`opencv_levels_above_build` added to ``OPENCV_CPU_DISABLE``."""
    environ = dict(os.environ if environ is None else environ)
    levels = opencv_levels_above_build()
    if levels:
        given = [name for name in environ.get("OPENCV_CPU_DISABLE", "").split(",") if name]
        environ["OPENCV_CPU_DISABLE"] = ",".join(given + [n for n in levels if n not in given])
    return environ


def native_search(plans):
    """The OpenCV peer's ``detectMultiScale`` settings comparable to fastdet's plans.

    The band every scale searches is upscaled so that the smallest fastdet
    window becomes OpenCV's 64-pixel window; the pyramid has one level per
    fastdet scale, spaced geometrically from the smallest to the largest
    window side, with a fixed ``winStride`` of ``NATIVE_WIN_STRIDE`` pixels.
    """
    sides = [(plan.roi[2] - plan.roi[0]) * 64.0 / plan.scaled_size[0] for plan in plans]
    smallest, largest = min(sides), max(sides)
    levels = len(plans)
    return {
        "region": [min(p.roi[0] for p in plans), min(p.roi[1] for p in plans),
                   max(p.roi[2] for p in plans), max(p.roi[3] for p in plans)],
        "upscale": 64.0 / smallest,
        "scale": (largest / smallest) ** (1.0 / (levels - 1)) if levels > 1 else 1.05,
        "nlevels": levels,
        "win_stride": NATIVE_WIN_STRIDE,
    }


def opencv_peer_job(plans, threads=(1,), repeat=3, data=None, train_stride=1):
    """The job description :class:`OpenCVPeer` hands the peer (without frames)."""
    from ..files.shared_data import data_dir

    return {
        "data_dir": str(Path(data or data_dir()).resolve()),
        "cache_dir": str(cache_dir() / "opencv_peer"),
        "threads": [int(t) for t in threads],
        "repeat": int(repeat),
        "train_stride": int(train_stride),
        "hit_threshold": 0.0,
        "plans": [{"roi": list(plan.roi), "scaled_size": list(plan.scaled_size),
                   "step_px": plan.step_cells * 8} for plan in plans],
        "native": native_search(plans),
    }


class OpenCVPeer:
    """OpenCV's HOGDescriptor, timed frame by frame in its own environment.

    The peer (``benchmarks/opencv_peer/peer.py``) runs as a subprocess that
    times the frame it is asked for, so a caller can time fastdet and OpenCV
    in turns over the same frames
    (:func:`fastdet.bench.timing.time_fastdet_in_turn`) and a slow spell of
    a shared machine hits both alike.  Use it as a
    context manager; the peer process and its files go when it closes.

    Parameters
    ----------
    frames : list of ndarray
        BGR frames, all of one size (the ones fastdet is timed on).
    plans : tuple of ScalePlan
        fastdet's plans for that size (pixels per cell must be 8, OpenCV's cell).
    threads : sequence of int
        ``cv2.setNumThreads`` values to time, each on every frame.
    repeat : int
        Timed calls per frame and mode (the median is kept).
    data : path, optional
        Data set for the peer's SVM (default: the shared data).
    start_timeout : float
        Seconds the peer may take to be ready (training its SVM included, on
        a cold cache).
    frame_timeout : float
        Seconds the peer may take to answer for one frame.
    peer_script : path, optional
        ``peer.py`` (default: the checkout's ``benchmarks/opencv_peer/peer.py``).

    Raises
    ------
    InputError
        When the peer environment is missing, the peer fails or does not
        answer in time (from :meth:`start`, :meth:`time_turn` and :meth:`time_frame`).
    """

    def __init__(self, frames, plans, threads=(1,), repeat=3, data=None, start_timeout=1800,
                 frame_timeout=120, peer_script=None):
        self.frames, self.threads, self.repeat = frames, [int(t) for t in threads], int(repeat)
        self.job = opencv_peer_job(plans, self.threads, repeat, data)
        self.start_timeout, self.frame_timeout = start_timeout, frame_timeout
        self.peer_script = peer_script
        if peer_script is None and benchmarks_dir() is not None:
            self.peer_script = benchmarks_dir() / "opencv_peer" / "peer.py"
        self.report = None
        self._seconds = {}  # (mode, threads) -> seconds per timed frame
        self._indices = []
        self._process = self._folder = self._stderr = self._reader = None
        self._replies = queue.Queue()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def start(self):
        """Start the peer and wait until it is ready (its SVM trained or loaded)."""
        python = opencv_peer_python()
        if python is None or self.peer_script is None:
            raise InputError("OpenCV peer not set up: run `bash benchmarks/opencv_peer/setup.sh` "
                             f"from the checkout (or set {OPENCV_PEER_ENV} to its environment)")
        try:
            self._start(python)
        except BaseException:
            self.close()
            raise
        return self

    def _start(self, python):
        self._folder = tempfile.TemporaryDirectory(prefix="fastdet-opencv-peer-")
        folder = Path(self._folder.name)
        job = dict(self.job, frames=str(folder / "frames.npy"))
        np.save(job["frames"], np.stack(self.frames))
        (folder / "job.json").write_text(json.dumps(job))
        # stderr to a file: a pipe nobody reads could fill and stall the peer.
        self._stderr = open(folder / "stderr.txt", "w+")  # closed in close()
        self._process = subprocess.Popen(
            [str(python), str(self.peer_script), str(folder / "job.json")], cwd=folder,
            env=opencv_peer_environment(), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=self._stderr, text=True, bufsize=1)
        self._reader = threading.Thread(target=self._read_replies, args=(self._process.stdout,),
                                        name="fastdet-opencv-peer", daemon=True)
        self._reader.start()
        self.report = self._reply(self.start_timeout)

    def time_turn(self, indices):
        """One untimed call on the first of ``indices``, then :meth:`time_frame` of each.

        The peer's turn in :func:`~fastdet.bench.timing.time_fastdet_in_turn`,
        warmed up as fastdet's detectors are.
        """
        if indices:
            self._ask(indices[0], repeat=1)
        for index in indices:
            self.time_frame(index)

    def time_frame(self, index):
        """Time frame ``index`` (of ``frames``) with every thread count."""
        replies = self._ask(index, self.repeat)
        # Recorded once the frame is complete: a failure leaves no partial frame.
        for threads, reply in replies:
            for mode, seconds in reply["seconds"].items():
                self._seconds.setdefault((mode, threads), []).append(seconds)
        self._indices.append(int(index))

    def _ask(self, index, repeat):
        """The peer's replies for frame ``index``, one per thread count."""
        replies = []
        for threads in self.threads:
            request = {"frame": int(index), "threads": threads, "repeat": int(repeat)}
            try:
                self._process.stdin.write(json.dumps(request) + "\n")
                self._process.stdin.flush()
            except OSError:  # the peer has gone: its reply says why
                pass
            replies.append((threads, self._reply(self.frame_timeout)))
        return replies

    def results(self):
        """One :class:`PipelineResult` per thread count and mode, on the frames timed."""
        results = []
        for threads in self.threads if self.report else ():
            for mode, windows in self.report["windows_per_frame"].items():
                label = "same windows" if mode == "same_windows" else "native multiscale"
                threads_label = f"{threads} thread" + ("s" if threads > 1 else "")
                results.append(PipelineResult(f"opencv {label}, {threads_label}",
                                              self._seconds.get((mode, threads), []),
                                              list(self._indices), windows))
        return results

    def close(self):
        """End the peer (the end of its input stops it) and remove its files."""
        process, self._process = self._process, None
        if process is not None:
            try:
                process.stdin.close()
            except OSError:  # it has gone already
                pass
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            self._reader.join(timeout=10)  # it stops at the end of the peer's output
            process.stdout.close()
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None
        if self._folder is not None:
            self._folder.cleanup()
            self._folder = None

    def _read_replies(self, stream):
        for line in stream:
            self._replies.put(line)
        self._replies.put(None)

    def _reply(self, timeout):
        try:
            line = self._replies.get(timeout=timeout)
        except queue.Empty:
            self._process.kill()  # it may be stuck: closing its input would not end it
            raise InputError(f"OpenCV peer did not answer within {timeout:g} s") from None
        if line is None:
            code = self._process.wait()
            self._stderr.seek(0)
            tail = " ".join(self._stderr.read().strip().splitlines()[-3:])
            raise InputError(f"OpenCV peer failed (exit {code}): {tail}")
        return json.loads(line)

