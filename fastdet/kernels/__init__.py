"""Numba kernels: pure functions over arrays, one module per kernel family.

Numba's default OpenMP layer spins its worker threads; on a shared machine
that made the parallel kernels (``parallel=True`` options, used for training
features) several times slower than one thread, so unless the user chose a
layer (``NUMBA_THREADING_LAYER``) the portable ``workqueue`` layer is used.
The detector itself runs only serial kernels, from a pool of threads (see
``fastdet.detector.detector``): workqueue must not start parallel kernels from several
threads at once.
"""

import os

import numba

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"
