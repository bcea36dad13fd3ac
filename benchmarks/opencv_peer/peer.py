"""OpenCV ``HOGDescriptor`` peer: times OpenCV's HOG detector on fastdet's frames.

This script runs in its own virtual environment (``setup.sh`` beside it makes
one with ``opencv-python-headless<5``): OpenCV 5 dropped ``HOGDescriptor``,
fastdet's environment keeps OpenCV 5, and the two wheels cannot share an
environment.  It therefore imports nothing from fastdet.  The caller
(``fastdet bench`` or the asv suite, through ``fastdet.bench.peers.OpenCVPeer``)
writes the decoded frames and a job description and starts this script as a
subprocess, which then times one frame at a time when asked: the caller
times fastdet on a frame, then asks for OpenCV's times on the same frame, so
both are timed within milliseconds of each other and a slow spell of a
shared machine hits both alike.  Timed a minute apart instead, the ratio
moved with the machine (2.0-3.5x in runs of ``fastdet bench`` on one AMD
EPYC whose speed swung by 30-40 %).

The detector is OpenCV's own: a linear SVM (scikit-learn ``LinearSVC``)
trained on ``cv2.HOGDescriptor((64, 64), (16, 16), (8, 8), (8, 8), 9)``
features of the grey 64x64 crops of the shared data set, handed to
``setSVMDetector``.  The trained vector is cached outside the checkout,
keyed by the data set and the OpenCV version (nothing data-derived is
committed).

Two searches are timed per frame, each the median of ``repeat`` calls:

``same_windows``
    Exactly fastdet's windows: per fastdet scale plan, the plan's region of
    interest of the grey frame is resized to the plan's size (as fastdet
    resizes it) and ``hog.detect`` scores the window grid with
    ``winStride`` = the plan's step.
``native``
    OpenCV used as it usually is: ``detectMultiScale`` over the band all
    scales search, upscaled so the smallest window is 64 pixels, with as
    many pyramid levels as fastdet has scales spanning the same window
    sizes, a fixed ``winStride`` and OpenCV's default grouping.

Protocol (one JSON object per line)::

    python peer.py JOB.json
    -> {"opencv_version": ..., "python": ..., "cpu_features": ..., "detector": {...},
        "windows_per_frame": {"same_windows": N, "native": M}}      once ready
    <- {"frame": I, "threads": T, "repeat": R}                       per request
    -> {"frame": I, "threads": T, "seconds": {mode: median}, "hits": {mode: n}}

An empty line or the end of the input ends it (exit 0).  Every thread count
of the job is warmed up on the first frame before the ready line, so no
request pays for training, loading or OpenCV's thread pool.
"""

from __future__ import annotations

import hashlib
import json
import os
import statistics
import sys
import time
from pathlib import Path

WINDOW = 64
#: OpenCV's HOG geometry matching fastdet's: 8x8 cells, 2x2-cell blocks, 9 bins.
HOG_ARGS = ((WINDOW, WINDOW), (16, 16), (8, 8), (8, 8), 9)
#: LinearSVC regularisation for OpenCV's 1764 HOG features.
SVM_C = 0.01
#: Version of the cached-detector format (bump when training changes).
CACHE_VERSION = 1


def make_hog(cv2, nlevels=64):
    """The HOG descriptor with OpenCV's defaults spelled out (``nlevels`` varies)."""
    return cv2.HOGDescriptor(*HOG_ARGS, 1, -1.0, cv2.HOGDESCRIPTOR_L2HYS, 0.2, False, nlevels,
                             False)


def crop_paths(data_dir):
    """Vehicle and non-vehicle PNG crops of the data set, in a stable order."""
    data_dir = Path(data_dir)
    positives = sorted((data_dir / "vehicles").rglob("*.png"))
    negatives = sorted((data_dir / "non-vehicles").rglob("*.png"))
    if not positives or not negatives:
        raise SystemExit(f"opencv peer: no vehicles/ or non-vehicles/ PNG crops in {data_dir}")
    return positives, negatives


def cache_key(cv2, positives, negatives, train_stride):
    """Digest of everything the trained vector depends on."""
    digest = hashlib.sha256()
    digest.update(json.dumps([CACHE_VERSION, cv2.__version__, HOG_ARGS, SVM_C,
                              train_stride]).encode())
    for path in positives + negatives:
        stat = path.stat()
        digest.update(f"{path}\0{stat.st_size}\0{stat.st_mtime_ns}\n".encode())
    return digest.hexdigest()[:20]


def train_detector(cv2, data_dir, cache_dir, train_stride=1):
    """OpenCV SVM detector vector (weights then bias), trained or from the cache.

    Returns
    -------
    detector : ndarray of float32, shape (1765,)
    info : dict
        Crops used, training seconds, whether the cache was hit, training
        accuracy, cache file.
    """
    import numpy as np

    positives, negatives = crop_paths(data_dir)
    positives, negatives = positives[::train_stride], negatives[::train_stride]
    key = cache_key(cv2, positives, negatives, train_stride)
    cache_file = Path(cache_dir) / f"opencv-hog-svm-{key}.npz"
    if cache_file.is_file():
        with np.load(cache_file) as cached:
            return cached["detector"], {**json.loads(str(cached["info"])), "cached": True,
                                        "cache_file": str(cache_file)}
    from sklearn.svm import LinearSVC

    start = time.perf_counter()
    hog = make_hog(cv2)
    paths = positives + negatives
    features = np.empty((len(paths), hog.getDescriptorSize()), np.float32)
    for row, path in enumerate(paths):
        grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if grey is None:
            raise SystemExit(f"opencv peer: cannot read {path}")
        if grey.shape != (WINDOW, WINDOW):
            grey = cv2.resize(grey, (WINDOW, WINDOW), interpolation=cv2.INTER_AREA)
        features[row] = hog.compute(grey).ravel()
    labels = np.r_[np.ones(len(positives)), np.zeros(len(negatives))]
    svm = LinearSVC(C=SVM_C, dual="auto", max_iter=5000, random_state=0).fit(features, labels)
    # OpenCV's detector vector is the weights followed by the bias: it
    # scores a window as w . x + b, the SVM's decision function.
    detector = np.r_[svm.coef_.ravel(), svm.intercept_].astype(np.float32)
    info = {"crops": len(paths), "train_seconds": round(time.perf_counter() - start, 2),
            "train_accuracy": round(float(svm.score(features, labels)), 4),
            "train_stride": train_stride}
    cache_file.parent.mkdir(parents=True, exist_ok=True)
    partial = cache_file.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(partial, detector=detector, info=json.dumps(info))
    os.replace(partial, cache_file)  # atomic: concurrent runs never read half a file
    return detector, {**info, "cached": False, "cache_file": str(cache_file)}


class SameWindows:
    """fastdet's windows scored by ``hog.detect``, scale plan by scale plan."""

    def __init__(self, cv2, detector, plans, threshold):
        self.cv2 = cv2
        self.hog = make_hog(cv2)
        self.hog.setSVMDetector(detector)
        self.plans = plans
        self.threshold = threshold
        self.origin = (min(p["roi"][0] for p in plans), min(p["roi"][1] for p in plans))
        self.band = (max(p["roi"][2] for p in plans), max(p["roi"][3] for p in plans))

    def _scaled_regions(self, frame):
        cv2 = self.cv2
        (x0, y0), (x1, y1) = self.origin, self.band
        # Grey once per frame for all scales, as fastdet converts once.
        grey = cv2.cvtColor(frame[y0:y1, x0:x1], cv2.COLOR_BGR2GRAY)
        for plan in self.plans:
            rx0, ry0, rx1, ry1 = plan["roi"]
            region = grey[ry0 - y0:ry1 - y0, rx0 - x0:rx1 - x0]
            yield plan, cv2.resize(region, tuple(plan["scaled_size"]),
                                   interpolation=cv2.INTER_LINEAR)

    def windows(self, frame):
        """Windows scored per frame, counted by OpenCV itself (every window a hit)."""
        total = 0
        for plan, scaled in self._scaled_regions(frame):
            step = plan["step_px"]
            found, _ = self.hog.detect(scaled, hitThreshold=-1e30, winStride=(step, step),
                                       padding=(0, 0))
            total += len(found)
        return total

    def __call__(self, frame):
        hits = 0
        for plan, scaled in self._scaled_regions(frame):
            step = plan["step_px"]
            found, _ = self.hog.detect(scaled, hitThreshold=self.threshold,
                                       winStride=(step, step), padding=(0, 0))
            hits += len(found)
        return hits


class Native:
    """``detectMultiScale`` over the searched band, as OpenCV is usually used."""

    def __init__(self, cv2, detector, native, threshold):
        self.cv2 = cv2
        self.native = native
        self.hog = make_hog(cv2, nlevels=native["nlevels"])
        self.hog.setSVMDetector(detector)
        self.threshold = threshold

    def _band(self, frame):
        cv2 = self.cv2
        x0, y0, x1, y1 = self.native["region"]
        grey = cv2.cvtColor(frame[y0:y1, x0:x1], cv2.COLOR_BGR2GRAY)
        factor = self.native["upscale"]
        return cv2.resize(grey, None, fx=factor, fy=factor, interpolation=cv2.INTER_LINEAR)

    def windows(self, frame):
        """Windows scored per frame, counted by OpenCV itself (all hits, no grouping)."""
        stride = self.native["win_stride"]
        boxes, _ = self.hog.detectMultiScale(self._band(frame), hitThreshold=-1e30,
                                             winStride=(stride, stride), padding=(0, 0),
                                             scale=self.native["scale"], groupThreshold=0)
        return len(boxes)

    def __call__(self, frame):
        stride = self.native["win_stride"]
        boxes, _ = self.hog.detectMultiScale(self._band(frame), hitThreshold=self.threshold,
                                             winStride=(stride, stride), padding=(0, 0),
                                             scale=self.native["scale"])
        return len(boxes)


def time_frame(pipeline, frame, repeat):
    """Median seconds of ``repeat`` timed calls on one frame, and the hits found."""
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        found = pipeline(frame)
        samples.append(time.perf_counter() - start)
    return statistics.median(samples), found


def prepare(job):
    """Frames, the timed searches by mode, and the ready report of a job."""
    import cv2
    import numpy as np

    if not hasattr(cv2, "HOGDescriptor"):
        raise SystemExit(f"opencv peer: OpenCV {cv2.__version__} has no HOGDescriptor; "
                         "run benchmarks/opencv_peer/setup.sh (installs opencv<5)")
    frames = np.load(job["frames"], mmap_mode="r")
    frames = [np.ascontiguousarray(frame) for frame in frames]
    detector, train_info = train_detector(cv2, job["data_dir"], job["cache_dir"],
                                          job.get("train_stride", 1))
    threshold = float(job.get("hit_threshold", 0.0))
    modes = {"same_windows": SameWindows(cv2, detector, job["plans"], threshold)}
    if job.get("native"):
        modes["native"] = Native(cv2, detector, job["native"], threshold)
    for threads in job["threads"]:
        cv2.setNumThreads(int(threads))
        for pipeline in modes.values():
            pipeline(frames[0])
    ready = {"opencv_version": cv2.__version__, "python": sys.version.split()[0],
             "cpu_features": cv2.getCPUFeaturesLine(),
             "detector": train_info,
             "windows_per_frame": {mode: pipeline.windows(frames[0])
                                   for mode, pipeline in modes.items()}}
    return cv2, frames, modes, ready


def serve(job, requests, replies):
    """Answer the timing requests read from ``requests``, one line each, on ``replies``."""
    cv2, frames, modes, ready = prepare(job)
    _send(replies, ready)
    for line in requests:
        if not line.strip():
            break
        request = json.loads(line)
        index, threads = int(request["frame"]), int(request["threads"])
        cv2.setNumThreads(threads)
        reply = {"frame": index, "threads": threads, "seconds": {}, "hits": {}}
        for mode, pipeline in modes.items():
            reply["seconds"][mode], reply["hits"][mode] = time_frame(
                pipeline, frames[index], int(request.get("repeat", 3)))
        _send(replies, reply)


def _send(replies, message):
    replies.write(json.dumps(message) + "\n")
    replies.flush()


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        raise SystemExit("usage: python peer.py JOB.json")
    job = json.loads(Path(argv[0]).read_text())
    serve(job, sys.stdin, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
