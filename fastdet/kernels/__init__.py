"""Numba kernels: pure functions over arrays, one module per kernel family.

Numba's default OpenMP layer spins its worker threads; on a shared machine
that made the two-thread kernels several times slower than one thread, so
unless the user chose a layer (``NUMBA_THREADING_LAYER``) the portable
``workqueue`` layer is used.
"""

import os

import numba

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"
