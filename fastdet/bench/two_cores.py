"""What two cores of this machine give two copies of one job: the 2-thread ceiling.

A 2-thread speed-up is judged against 2x, but not every machine's "two cores"
do twice the work of one.  A virtual machine's two CPUs can be hyperthreads of
one physical core (they share its execution units), or the host can be busy;
either way two copies of the same single-thread job at once then take longer
each than one alone.  :func:`two_core_ceiling` measures that directly with two
of fastdet's own GIL-free kernels, each run alone and as two copies at once in
two threads:

* the cell kernel (``cell_histograms`` on one frame, serial): floating-point
  throughput bound, the stage with most of a frame's work, so the ceiling for
  fastdet's own 2-thread figures;
* a chain of dependent integer operations (:mod:`fastdet.kernels.clock`):
  bound by latency and leaves a core's units mostly idle, so two copies
  reach about 2x even on two hyperthreads of one core, and fall short only
  when the host takes the cycles.

Both alone and at once are alternated round by round, so that a change of the
machine's speed between rounds falls on both.
"""

from __future__ import annotations

import statistics
import threading
import time

import cv2
import numpy as np

#: Alternating rounds of (one copy alone, two copies at once); the median ratio is kept.
ROUNDS = 7
#: Calls of the cell kernel per copy and round (about 30-60 ms on one core).
CELL_CALLS = 12
#: Steps of the integer chain per copy and round (about 20-30 ms).
CHAIN_STEPS = 20_000_000


def _at_once(job, copies):
    """Seconds ``copies`` threads take to run ``job`` once each, started together."""
    barrier = threading.Barrier(copies + 1)

    def worker():
        barrier.wait()
        job()

    workers = [threading.Thread(target=worker) for _ in range(copies)]
    for thread in workers:
        thread.start()
    barrier.wait()
    start = time.perf_counter()
    for thread in workers:
        thread.join()
    return time.perf_counter() - start


def throughput_ratio(job, rounds=ROUNDS):
    """Work done per second by two copies of ``job`` at once over one copy alone.

    ``job`` must release the GIL (a ``nogil`` Numba kernel).  2.0 is two full
    cores; 1.0 is one core shared.

    Returns
    -------
    dict
        ``ratio`` (median over rounds of 2 x alone / at once), ``alone_ms``
        and ``together_ms`` (medians).
    """
    job()  # compiled or loaded, pages touched
    alone, together, ratios = [], [], []
    for _ in range(rounds):
        one = _at_once(job, 1)
        two = _at_once(job, 2)
        alone.append(one)
        together.append(two)
        ratios.append(2.0 * one / two)
    return {"ratio": statistics.median(ratios), "alone_ms": statistics.median(alone) * 1e3,
            "together_ms": statistics.median(together) * 1e3}


def two_core_ceiling(frame, rounds=ROUNDS):
    """Two copies at once against one, for the cell kernel on ``frame`` and the integer chain.

    Parameters
    ----------
    frame : ndarray, shape (H, W, 3), uint8
        A BGR frame; its HLS image is the cell kernel's input, as in detection.
    rounds : int
        Alternating rounds.

    Returns
    -------
    dict
        ``cells`` and ``chain``: each the dict of :func:`throughput_ratio`.
    """
    from ..kernels.clock import integer_chain
    from ..kernels.hog import cell_histograms

    hls = np.ascontiguousarray(cv2.cvtColor(frame, cv2.COLOR_BGR2HLS))

    def cells():
        out = cell_histograms(hls, (8, 8), 9)
        for _ in range(CELL_CALLS - 1):
            cell_histograms(hls, (8, 8), 9, out=out)

    return {"cells": throughput_ratio(cells, rounds),
            "chain": throughput_ratio(lambda: integer_chain(CHAIN_STEPS, 1), rounds)}


def format_two_cores(ceiling):
    """The ceiling as a markdown line or two."""
    cells, chain = ceiling["cells"], ceiling["chain"]
    return (f"Two copies of one single-thread job at once on this machine's cores do "
            f"{cells['ratio']:.2f}x the work of one copy alone for the cell kernel "
            f"({cells['alone_ms']:.1f} ms alone, {cells['together_ms']:.1f} ms both at once) "
            f"and {chain['ratio']:.2f}x for a chain of dependent integer operations: "
            f"an in-cache kernel's 2-thread speed-up cannot exceed about {cells['ratio']:.2f}x "
            f"here (a low integer figure too: the host takes cycles; a low cell figure only: "
            f"the two CPUs share one core's units). The whole pipeline's own ceiling, caches "
            f"and memory shared, is its processes row below.")
