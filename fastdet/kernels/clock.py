"""Clocks for kernels: the one a core actually runs at, and the time inside a kernel call.

``fastdet bench`` sets a frame's arithmetic against one core's cycles
(:mod:`fastdet.bench.floor`).  The clock ``/proc/cpuinfo`` names is the
nominal one, and cores boost above it: an AMD EPYC (Zen 3) listed at 2.45 GHz
ran this chain at 3.2 GHz, so a floor counted at the nominal clock was a
third too high.  Each step of :func:`integer_chain` is a shift, an exclusive
or and an add, each needing the one before: one cycle each on every x86-64
and ARM64 core, so :data:`CYCLES_PER_STEP` cycles a step, whatever else the
core could do alongside.

:func:`monotonic_ns` reads the time from inside a kernel, for kernels that
run several stages in one call and report each stage's time.
"""

from __future__ import annotations

import time

from llvmlite import ir
from numba import njit, types, uint64
from numba.core import cgutils
from numba.extending import intrinsic

#: Cycles one step of :func:`integer_chain` takes (three dependent one-cycle operations).
CYCLES_PER_STEP = 3


@njit(cache=True, nogil=True)
def integer_chain(steps, seed):
    """``seed`` put through ``steps`` steps of ``x = (x ^ (x >> 7)) + 1`` (uint64, wrapping)."""
    x = uint64(seed)
    for _ in range(steps):
        x = (x ^ (x >> uint64(7))) + uint64(1)
    return x


#: The clock :func:`monotonic_ns` reads inside kernels (``time.perf_counter``'s on
#: Linux), or None where the C library has no ``clock_gettime`` (Windows).
MONOTONIC_CLOCK = getattr(time, "CLOCK_MONOTONIC", None)


@intrinsic
def monotonic_ns(typingctx, clock_id):
    """Nanoseconds on the C library's ``clock_gettime(clock_id)``, read inside a kernel.

    For stage times within one kernel call (:mod:`fastdet.kernels.band`): a
    cycle counter would be cheaper, but ``llvm.readcyclecounter`` reads a
    register that ARM64 Linux traps in user space.  ``clock_id`` is
    :data:`MONOTONIC_CLOCK`, passed in because its value differs between C
    libraries (1 on Linux, 6 on macOS).  The call goes through the vDSO on
    Linux: about 20 ns, no system call.
    """
    if not isinstance(clock_id, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        i32, i64 = ir.IntType(32), ir.IntType(64)
        # struct timespec of LP64 C libraries: two 64-bit fields.
        timespec = ir.LiteralStructType([i64, i64])
        slot = cgutils.alloca_once(builder, timespec)
        function = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(i32, [i32, timespec.as_pointer()]), "clock_gettime")
        builder.call(function, [builder.trunc(args[0], i32), slot])
        seconds = builder.load(cgutils.gep_inbounds(builder, slot, 0, 0))
        nanoseconds = builder.load(cgutils.gep_inbounds(builder, slot, 0, 1))
        return builder.add(builder.mul(seconds, ir.Constant(i64, 1_000_000_000)), nanoseconds)

    return types.int64(clock_id), codegen
