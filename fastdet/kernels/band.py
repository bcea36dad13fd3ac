"""A scale's band in one kernel call: its HOG cells, its colour maps, then its window scores.

The detector scores each scale of a frame in three kernel calls
(:class:`~fastdet.kernels.hog.PhaseCellRows`,
:class:`~fastdet.kernels.colour.ColourMapRows`,
:class:`~fastdet.kernels.score.WindowRowScorer`), and each call gives the
GIL back when it returns.  With two frames detected at once, a thread
returning from a kernel finds the GIL held by the other, sleeps, and is
woken when it is handed over.  On the 2-vCPU virtual machines here
(Intel Xeon, KVM, 2026-12-02) two frames at once slept 5.5 times a frame,
and the sleeping and waking cost about 0.13 ms a frame of CPU that one
thread never spends; one call per scale for the three stages (the same
three kernels, called from one) halved the sleeps (2.9 a frame) and took
two frames at once from 1.44 to 1.34 ms a frame, 1.67x to 1.79x one thread.

:class:`BandScorer` binds the three calls of one scale and runs them in
:func:`_features_and_scores`, which reads the time between the stages
(:func:`~fastdet.kernels.clock.monotonic_ns`) so the stage split of
``fastdet bench`` stays what it was.  It takes the vector cell kernel of the
default options only (:meth:`BandScorer.fits`); other options keep the
three calls.

The band kernel calls the three kernels' own compiled code by its address
(:mod:`fastdet.kernels.calls`), not the kernels themselves: called directly,
Numba builds their code again inside it, which took the band kernel's
compile from 0.25 s to 3.9 s against 2.7 s for the three on their own
(Intel Xeon, 2026-12-03: a cold ``fastdet detect`` 5.34-5.42 s with the
direct calls, 4.67-5.05 s by address; warm 0.43-0.46 against 0.38-0.40 s).
The warm-up's "band" family is this kernel alone; the three are the
families "hog", "score" and "colour".
"""

from __future__ import annotations

import functools
import time

import numpy as np
from numba import njit, types

from .calls import call_compiled, compiled_address
from .clock import MONOTONIC_CLOCK, monotonic_ns
from .colour import _colour_maps
from .hog import _cell_rows_u8_fast
from .score import _score_window_rows

#: Stages a call times, in the order it runs them (keys of the detector's stage timings).
STAGES = ("cells", "colour_maps", "blocks_score")


@njit(cache=True, nogil=True)
def _features_and_scores(cells_kernel, cells_args, colour_kernel, colour_args, colour_result,
                         windows_kernel, windows_args, clock_id, stamps):
    """The cell, colour-map and window-score kernels at these addresses
    (:func:`~fastdet.kernels.calls.compiled_address`), each with its own
    arguments, in turn; ``stamps`` gets the time (ns) before each and after
    the last."""
    stamps[0] = monotonic_ns(clock_id)
    call_compiled(cells_kernel, cells_args, None)
    stamps[1] = monotonic_ns(clock_id)
    call_compiled(colour_kernel, colour_args, colour_result)
    stamps[2] = monotonic_ns(clock_id)
    call_compiled(windows_kernel, windows_args, None)
    stamps[3] = monotonic_ns(clock_id)


class _BoundBand:
    """One band kernel call with its arguments made (see :meth:`BandScorer.bind`)."""

    __slots__ = ("arguments", "stamps")

    def __init__(self, arguments):
        self.arguments, self.stamps = arguments, arguments[-1]

    def __call__(self):
        _features_and_scores(*self.arguments)
        start, cells_done, colour_done, end = self.stamps.tolist()
        return ((cells_done - start) * 1e-9, (colour_done - cells_done) * 1e-9,
                (end - colour_done) * 1e-9)


def _no_band():
    return 0.0, 0.0, 0.0


#: What ``_colour_maps`` returns (the tile-sum path it took), as a value of its type:
#: the band kernel's types do not depend on compiling the kernels it calls.
_COLOUR_RESULT = np.int64(0)


def band_kernel_signature(cells_args, colour_args, windows_args):
    """The argument types of ``_features_and_scores`` for these arguments of the three kernels."""
    return tuple(_features_and_scores.typeof_pyval(value) for value in (
        0, cells_args, 0, colour_args, _COLOUR_RESULT, 0, windows_args, MONOTONIC_CLOCK,
        np.empty(4, np.int64)))


class BandScorer:
    """One scale's cell rows, colour maps and window scores, in one kernel call.

    Parameters
    ----------
    cell_rows : fastdet.kernels.hog.PhaseCellRows
    colour_rows : fastdet.kernels.colour.ColourMapRows
    windows : fastdet.kernels.score.WindowRowScorer
        Bound to the scale's arrays, as the three calls would use them;
        :meth:`fits` must hold for them.

    Notes
    -----
    A call computes exactly what the three bound calls compute: the same
    kernels, with the same arguments, in the same order.
    """

    def __init__(self, cell_rows, colour_rows, windows):
        if not self.fits(cell_rows, colour_rows, windows):
            raise ValueError("these cells, colour maps or windows take calls of their own")
        self.cell_rows, self.colour_rows, self.windows = cell_rows, colour_rows, windows
        # The three kernels' addresses for the calls' argument types, by the
        # flags of the arrays that change from call to call (their dtypes,
        # shapes and layouts the bound calls check).
        self._compiled = {}

    @staticmethod
    def fits(cell_rows, colour_rows, windows):
        """Whether a scale with these bound calls can be scored in one: the vector
        cell kernel on three channels and whole groups of cells (the default
        options' cells at even cell columns: every scale of the default
        search on 16:9 frames), colour maps, and a clock the kernel can read.
        One compiled version of the kernel serves them; others keep the
        three calls rather than compile more."""
        return (MONOTONIC_CLOCK is not None and cell_rows is not None
                and colour_rows is not None and windows is not None
                and cell_rows.kernel is _cell_rows_u8_fast and cell_rows.image_shape[2] == 3)

    def __call__(self, image, colour_image, top, bottom, first, stop, scores):
        """Compute the cells and colour maps of pixel rows ``top`` .. ``bottom - 1``
        of the scale, then add the scores of window rows ``first`` .. ``stop - 1``
        to ``scores``; nothing when ``first >= stop``.

        Parameters
        ----------
        image : ndarray of uint8
            The scale's resized image, as :class:`PhaseCellRows` takes it
            (cell rows ``top // 8`` .. ``bottom // 8 - 1`` are computed).
        colour_image : ndarray of uint8
            Its rows the colour maps cover, as :class:`ColourMapRows` takes them.
        top, bottom, first, stop : int
        scores : ndarray of float32
            The scale's score grid.

        Returns
        -------
        tuple of float
            Seconds of each of :data:`STAGES`.
        """
        return self.bind(image, colour_image, top, bottom, first, stop, scores)()

    def bind(self, image, colour_image, top, bottom, first, stop, scores):
        """What ``self(image, colour_image, top, bottom, first, stop, scores)`` runs, as
        a call without arguments that returns the same seconds.

        A caller that scores the same rows of the same arrays, refilled in place,
        frame after frame makes this once: the checks and argument tuples are
        then not redone (Python run with the GIL held, which a thread scoring
        another frame waits for).  Each call reads the arrays as they are then.
        """
        if first >= stop:
            return _no_band
        ppc_y = self.cell_rows.pixels_per_cell[0]
        cells = self.cell_rows.call(image, top // ppc_y, bottom // ppc_y)
        colour = self.colour_rows.arguments(colour_image, top, bottom)
        windows = self.windows.arguments(scores, first, stop)
        if cells is None or colour is None or windows is None:
            # An edge with nothing to do in some stage: the calls one by one.
            return functools.partial(self._one_by_one, cells, colour, windows)
        key = (image.flags.writeable, image.flags.aligned, colour_image.flags.writeable,
               colour_image.flags.aligned, scores.flags.writeable, scores.flags.aligned)
        compiled = self._compiled.get(key)
        if compiled is None:
            compiled = self._compiled[key] = self.compile(cells[1], colour, windows)
        return _BoundBand((compiled[0], cells[1], compiled[1], colour, _COLOUR_RESULT,
                           compiled[2], windows, MONOTONIC_CLOCK, np.empty(4, np.int64)))

    @staticmethod
    def compile(cells_args, colour_args, windows_args):
        """Compile (or load) the three kernels for these arguments, and the band
        kernel; returns the three kernels' addresses."""
        cells, _ = compiled_address(_cell_rows_u8_fast, cells_args)
        colour, colour_type = compiled_address(_colour_maps, colour_args)
        windows, _ = compiled_address(_score_window_rows, windows_args)
        # Where the CPU has one tile-sum path only, Numba types the result as
        # that literal: a 64-bit integer all the same, as the call expects.
        if not (isinstance(colour_type, types.Integer) and colour_type.bitwidth == 64):
            raise TypeError(f"the colour maps kernel returns {colour_type}, not a 64-bit integer")
        BandScorer.compile_band_kernel(cells_args, colour_args, windows_args)
        return cells, colour, windows

    @staticmethod
    def compile_band_kernel(cells_args, colour_args, windows_args):
        """Compile (or load) the band kernel alone for these arguments of the three
        kernels (the warm-up's "band" family: it needs no kernel it calls)."""
        _features_and_scores.compile(band_kernel_signature(cells_args, colour_args,
                                                           windows_args))

    @staticmethod
    def _one_by_one(cells, colour, windows):
        seconds = [0.0, 0.0, 0.0]
        calls = (cells, colour and (_colour_maps, colour),
                 windows and (_score_window_rows, windows))
        for stage, call in enumerate(calls):
            if call:
                start = time.perf_counter()
                call[0](*call[1])
                seconds[stage] = time.perf_counter() - start
        return tuple(seconds)
