"""Python's cyclic garbage collector, held back while fastdet's kernels compile.

Compiling a kernel allocates hundreds of thousands of container objects
(Numba's IR and types, llvmlite's IR values), most of which live until the
compile ends.  With CPython's default thresholds (700, 10, 10) that set off,
while the eight families of a detection compiled in one process, 1429
young, 129 middle and 11 full collections; each full one walks every object
of the process (NumPy's, OpenCV's, Numba's and SciPy's modules included).
Timed with ``gc.callbacks``: 0.90-1.15 s of the 13.9-14.7 s compile (AMD
EPYC, Zen 3).  With the thresholds of :data:`COMPILE_THRESHOLDS` the same
compile made 181, 14 and 1 collections taking 0.19-0.26 s, and its peak
resident memory rose from 248 to 289 MB; switching the collector off
altogether saved no more and peaked at 347 MB.

:func:`install` registers a listener for Numba's ``"numba:compile"`` events
(its documented event API) that raises the thresholds when a compile of a
fastdet kernel starts (not a cache load: Numba sends the event only for
compiles) and restores the previous ones when the outermost such compile
ends, failed or not.  Compiles of other packages' functions are left alone.
Numba compiles under its global compiler lock, so starts and ends of
compiles never interleave between threads.
"""

from __future__ import annotations

import gc

from numba.core import event

#: Collector thresholds while a fastdet kernel compiles (CPython's defaults: 700, 10, 10).
COMPILE_THRESHOLDS = (50_000, 50, 1_000)


def _is_fastdet_kernel(event_data):
    dispatcher = (event_data or {}).get("dispatcher")
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", None) or ""
    return module.startswith("fastdet.")


class CompileCollectorHold(event.Listener):
    """Raises the collector's thresholds for the duration of fastdet kernel compiles."""

    def __init__(self, thresholds=COMPILE_THRESHOLDS):
        self.thresholds = tuple(thresholds)
        self._depth = 0
        self._saved = None

    def on_start(self, compile_event):
        if not _is_fastdet_kernel(compile_event.data):
            return
        if self._depth == 0:
            self._saved = gc.get_threshold()
            gc.set_threshold(*self.thresholds)
        self._depth += 1

    def on_end(self, compile_event):
        if not _is_fastdet_kernel(compile_event.data) or self._depth == 0:
            return
        self._depth -= 1
        if self._depth == 0:
            gc.set_threshold(*self._saved)


_listener = None


def install():
    """Register the listener with Numba (once per process); returns it."""
    global _listener
    if _listener is None:
        _listener = CompileCollectorHold()
        event.register("numba:compile", _listener)
    return _listener
