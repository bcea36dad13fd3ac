"""The peers fastdet is timed against, and where they live.

* ``reference``: the seed-faithful reference pipeline
  (``benchmarks/reference.py`` of the checkout; scikit-image HOG and one
  scikit-learn call per window), same model, same windows;
* ``opencv``: OpenCV's ``HOGDescriptor`` with a linear SVM trained on its own
  grey HOG features, run by ``benchmarks/opencv_peer/peer.py`` in its own
  virtual environment (OpenCV 5, which fastdet uses, has no
  ``HOGDescriptor``); see :func:`run_opencv_peer`.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError
from .timing import PipelineResult

#: Environment variable naming the OpenCV peer's virtual environment.
OPENCV_PEER_ENV = "FASTDET_OPENCV_PEER"

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
    """The job description :func:`run_opencv_peer` hands the peer (without frames)."""
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


def run_opencv_peer(frames, plans, threads=(1,), repeat=3, data=None, timeout=1800,
                    peer_script=None):
    """Time OpenCV's HOGDescriptor on ``frames`` in its own environment.

    Parameters
    ----------
    frames : list of ndarray
        BGR frames, all of one size (the ones fastdet is timed on).
    plans : tuple of ScalePlan
        fastdet's plans for that size (pixels per cell must be 8, OpenCV's cell).
    threads : sequence of int
        ``cv2.setNumThreads`` values to time.
    repeat : int
        Timed passes per frame (the median is kept).
    data : path, optional
        Data set for the peer's SVM (default: the shared data).
    timeout : float
        Seconds the peer may take (training its SVM included, on a cold cache).
    peer_script : path, optional
        ``peer.py`` (default: the checkout's ``benchmarks/opencv_peer/peer.py``).

    Returns
    -------
    results : list of PipelineResult
        ``opencv same windows, T thread(s)`` and ``opencv native, ...``.
    info : dict
        The peer's report: OpenCV version, training figures.

    Raises
    ------
    InputError
        When the peer environment is missing or the peer fails.
    """
    python = opencv_peer_python()
    if peer_script is None and benchmarks_dir() is not None:
        peer_script = benchmarks_dir() / "opencv_peer" / "peer.py"
    if python is None or peer_script is None:
        raise InputError("OpenCV peer not set up: run `bash benchmarks/opencv_peer/setup.sh` "
                         f"from the checkout (or set {OPENCV_PEER_ENV} to its environment)")
    job = opencv_peer_job(plans, threads, repeat, data)
    with tempfile.TemporaryDirectory(prefix="fastdet-opencv-peer-") as tmp:
        job["frames"] = str(Path(tmp) / "frames.npy")
        np.save(job["frames"], np.stack(frames))
        job_file = Path(tmp) / "job.json"
        job_file.write_text(json.dumps(job))
        completed = subprocess.run([str(python), str(peer_script), str(job_file)],
                                   capture_output=True, text=True, timeout=timeout, cwd=tmp)
    if completed.returncode != 0:
        tail = " ".join(completed.stderr.strip().splitlines()[-3:])
        raise InputError(f"OpenCV peer failed (exit {completed.returncode}): {tail}")
    report = json.loads(completed.stdout.strip().splitlines()[-1])
    results = []
    for entry in report["results"]:
        label = "same windows" if entry["mode"] == "same_windows" else "native multiscale"
        threads_label = f"{entry['threads']} thread" + ("s" if entry["threads"] > 1 else "")
        results.append(PipelineResult(f"opencv {label}, {threads_label}", entry["seconds"],
                                      list(range(len(entry["seconds"]))),
                                      entry["windows_per_frame"]))
    return results, report
