"""Start-up of a whole ``fastdet detect test1.jpg`` process: cold and warm.

* cold: every run gets a new, empty ``NUMBA_CACHE_DIR``, so the command
  compiles every kernel a detection needs (the first command of a new
  installation); the median of :data:`COLD_RUNS` runs.
* warm: the cache is filled; each run of the command is paired with a run
  of ``python -c "import numpy, cv2, numba"``, the floor any Numba + OpenCV
  program pays, and the warm start-up is the median of the paired
  differences (what fastdet costs on top of importing its dependencies);
  :data:`WARM_RUNS` pairs.

fastdet's modules are byte-compiled first (:mod:`fastdet.files.bytecode`), as
``pip install`` leaves them: an editable install under
``PYTHONDONTWRITEBYTECODE`` would otherwise compile every source in every run.

Each figure is a fresh process's wall clock as the parent sees it,
interpreter start included, the way a user waits for it, and its CPU time
(user + system, the helper compile process included), which other
processes' load does not inflate.  The command runs through the same entry
point as the ``fastdet`` console script.
"""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from fastdet.files.bytecode import compile_package
from fastdet.files.shared_data import data_dir

from ._common import skip_if_missing

#: Cold start-ups measured (each compiles everything; about 10-20 s each).
COLD_RUNS = 3
#: Warm start-ups measured, each paired with one run of the import floor.
WARM_RUNS = 7

#: The ``fastdet`` console script, run by this interpreter.
_FASTDET = "import sys; from fastdet.cli import console_main; console_main(sys.argv[1:])"
#: What every Numba + OpenCV program pays before its own code runs.
_IMPORT_FLOOR = "import numpy, cv2, numba"


def _image():
    return data_dir() / "test_images" / "test1.jpg"


def run_seconds(code, args=(), cache_dir=None):
    """``(wall, cpu)`` seconds of ``python -c code args`` in a fresh process (raises if it fails)."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = str(cache_dir)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    completed = subprocess.run([sys.executable, "-c", code, *map(str, args)], env=env,
                               capture_output=True, text=True, timeout=900)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if completed.returncode != 0:
        raise RuntimeError(f"{code!r} failed: {completed.stderr.strip()[-500:]}")
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return seconds, cpu


def measure(cold_runs=COLD_RUNS, warm_runs=WARM_RUNS):
    """Cold and warm start-up figures (seconds), as :class:`StartUp` reports them."""
    image = _image()
    # As pip does at install: without the .pyc files (an editable install under
    # PYTHONDONTWRITEBYTECODE) every run would compile fastdet's sources again.
    compile_package()
    cold = []
    for _ in range(cold_runs):
        with tempfile.TemporaryDirectory(prefix="fastdet-cold-") as cache:
            cold.append(run_seconds(_FASTDET, ("detect", image), cache))
    with tempfile.TemporaryDirectory(prefix="fastdet-warm-") as cache:
        run_seconds(_FASTDET, ("detect", image), cache)  # fills the cache
        floor, warm = [], []
        for _ in range(warm_runs):
            floor.append(run_seconds(_IMPORT_FLOOR, (), cache))
            warm.append(run_seconds(_FASTDET, ("detect", image), cache))
    # No cold runs asked for (``0``): no cold figure.
    median = lambda pairs, k: (statistics.median(pair[k] for pair in pairs)  # noqa: E731
                               if pairs else None)
    above = lambda k: statistics.median(w[k] - f[k] for w, f in zip(warm, floor))  # noqa: E731
    return {"cold": median(cold, 0), "cold_cpu": median(cold, 1),
            "warm": median(warm, 0), "import_floor": median(floor, 0),
            "warm_above_floor": above(0), "warm_cpu_above_floor": above(1),
            "cold_runs": cold, "warm_runs": warm, "floor_runs": floor}


class StartUp:
    """``fastdet detect test1.jpg``: cold compile and warm start, in seconds."""

    timeout = 1800

    def setup_cache(self):
        if not _image().is_file():
            return {"skip": f"no test image at {_image()}: set FASTDET_DATA"}
        return measure()

    def setup(self, figures):
        skip_if_missing(figures)

    def track_cold_detect(self, figures):
        """Whole command with an empty kernel cache (median): compiling included."""
        return figures["cold"]

    def track_warm_detect(self, figures):
        """Whole command with the cache filled (median)."""
        return figures["warm"]

    def track_import_floor(self, figures):
        """``python -c "import numpy, cv2, numba"`` (median)."""
        return figures["import_floor"]

    def track_warm_above_import_floor(self, figures):
        """Warm command minus the import floor, run in pairs (median difference)."""
        return figures["warm_above_floor"]

    def track_cold_detect_cpu(self, figures):
        """CPU seconds of the cold command, its helper compile process included (median)."""
        return figures["cold_cpu"]

    def track_warm_cpu_above_import_floor(self, figures):
        """CPU seconds of the warm command minus the import floor's (median of pairs)."""
        return figures["warm_cpu_above_floor"]


for _name in dir(StartUp):
    if _name.startswith("track_"):
        getattr(StartUp, _name).unit = "seconds"
del _name


if __name__ == "__main__":  # pragma: no cover - by hand: python -m benchmarks.bench_startup
    import json

    print(json.dumps(measure(int(sys.argv[1]) if len(sys.argv) > 1 else COLD_RUNS,
                             int(sys.argv[2]) if len(sys.argv) > 2 else WARM_RUNS), indent=1))
