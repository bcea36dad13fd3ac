"""The clock probe: its chain against plain Python, and the clock it measures."""

import time

import numpy as np
import pytest
from numba import njit

from fastdet.bench.floor import measured_clock_hz
from fastdet.kernels.clock import MONOTONIC_CLOCK, integer_chain, monotonic_ns
from naive import naive_integer_chain


@pytest.mark.parametrize("steps", [0, 1, 2, 7, 1000])
@pytest.mark.parametrize("seed", [0, 1, 3, 2**63 + 12345, 2**64 - 1])
def test_chain_matches_python(steps, seed):
    # Seeds past int64 go in as uint64, as they would from a kernel.
    value = seed if seed < 2**63 else np.uint64(seed)
    assert int(integer_chain(steps, value)) == naive_integer_chain(steps, seed)


def test_measured_clock_is_a_cpu_clock():
    # A sanity range, not a speed figure: 3 dependent one-cycle operations a
    # step.  A chain the compiler had shortened would measure far above it.
    assert 0.2e9 < measured_clock_hz(seconds=0.05, steps=200_000) < 10e9


@njit(cache=True)
def _read_clock(clock_id):
    return monotonic_ns(clock_id)


@pytest.mark.skipif(MONOTONIC_CLOCK is None, reason="no clock_gettime on this platform")
def test_the_kernel_clock_reads_the_monotonic_clock():
    _read_clock(MONOTONIC_CLOCK)
    before = time.clock_gettime_ns(MONOTONIC_CLOCK)
    inside = _read_clock(MONOTONIC_CLOCK)
    after = time.clock_gettime_ns(MONOTONIC_CLOCK)
    assert before <= inside <= after
