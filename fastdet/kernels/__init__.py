"""Numba kernels: pure functions over arrays, one module per kernel family.

Numba's default OpenMP layer spins its worker threads; on a shared machine
that made the parallel kernels (``parallel=True`` options, used for training
features) several times slower than one thread, so unless the user chose a
layer (``NUMBA_THREADING_LAYER``) the portable ``workqueue`` layer is used.
The detector itself runs only serial kernels, from a pool of threads (see
``fastdet.detector.detector``): workqueue must not start parallel kernels from several
threads at once.

Compiled kernels are cached in the user's cache folder, never inside the
installed package (see :mod:`fastdet.kernels.cache`), and compile with
Python's garbage collector held back (see :mod:`fastdet.kernels.compile_gc`).
"""

import os

import numba

from . import cache, compile_gc

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"
# Before any kernel module is imported: each takes its cache folder when defined.
cache.configure()
compile_gc.install()
