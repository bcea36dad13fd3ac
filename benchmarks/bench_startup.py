"""Start-up: cold (empty Numba cache, every kernel compiled) and warm (cache filled).

Each measurement is a fresh Python process whose ``NUMBA_CACHE_DIR`` is a
new temporary folder: the first process compiles every kernel one-thread
detection needs and writes the cache; the following processes load it.
Phases are timed inside the process (``import fastdet``, building the
``Detector``, its first call on a video frame, a second call for
comparison); ``total`` is the parent's wall clock from process start to the
first detection done, interpreter start-up included.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile

from ._common import bench_model, model_path, skip_if_missing, skip_reason, video_path

#: Warm start-ups measured (the median is reported).
WARM_RUNS = 3

_PROBE = r"""
import json, sys, time
started = time.perf_counter()
import fastdet
imported = time.perf_counter()
import cv2
capture = cv2.VideoCapture(sys.argv[1])
ok, frame = capture.read()
capture.release()
assert ok, "cannot read the test video"
model = sys.argv[2] if len(sys.argv) > 2 else None
ready = time.perf_counter()
detector = fastdet.Detector(model, threads=1)
built = time.perf_counter()
detector(frame)
first = time.perf_counter()
detector(frame)
second = time.perf_counter()
print(json.dumps({"import": imported - started, "detector": built - ready,
                  "first_call": first - built, "second_call": second - first,
                  "to_first_detection": (imported - started) + (first - ready)}))
"""


def probe(cache_dir):
    """One fresh process with ``NUMBA_CACHE_DIR=cache_dir``; its phase timings (s)."""
    import time

    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    command = [sys.executable, "-c", _PROBE, str(video_path())]
    if model_path():
        command.append(model_path())
    start = time.perf_counter()
    completed = subprocess.run(command, capture_output=True, text=True, env=env, timeout=900)
    wall = time.perf_counter() - start
    if completed.returncode != 0:
        raise RuntimeError(f"start-up probe failed: {completed.stderr.strip()[-500:]}")
    phases = json.loads(completed.stdout.strip().splitlines()[-1])
    phases["process_wall"] = wall
    return phases


class StartUp:
    """Cold and warm start-up phases, in seconds (one cold, median of 3 warm)."""

    timeout = 1200

    def setup_cache(self):
        if skip_reason(bench_model):
            return {"skip": skip_reason(bench_model)}
        with tempfile.TemporaryDirectory(prefix="fastdet-numba-cache-") as cache:
            cold = probe(cache)
            warm_runs = [probe(cache) for _ in range(WARM_RUNS)]
        warm = {key: statistics.median(run[key] for run in warm_runs) for key in cold}
        return {"cold": cold, "warm": warm}

    def setup(self, cache):
        skip_if_missing(cache)

    def track_cold_import(self, cache):
        return cache["cold"]["import"]

    def track_cold_first_call(self, cache):
        """First detection with an empty cache: compiling the one-thread kernels."""
        return cache["cold"]["first_call"]

    def track_cold_to_first_detection(self, cache):
        return cache["cold"]["to_first_detection"]

    def track_warm_import(self, cache):
        return cache["warm"]["import"]

    def track_warm_first_call(self, cache):
        """First detection with the cache filled: loading compiled kernels."""
        return cache["warm"]["first_call"]

    def track_warm_to_first_detection(self, cache):
        """import + Detector + first detection, cache filled: the < 1 s target."""
        return cache["warm"]["to_first_detection"]

    def track_warm_process_wall(self, cache):
        """Interpreter start to exit after two detections, as a user waits for it."""
        return cache["warm"]["process_wall"]

    def track_steady_call(self, cache):
        return cache["warm"]["second_call"]


for _name in dir(StartUp):
    if _name.startswith("track_"):
        getattr(StartUp, _name).unit = "seconds"
del _name
