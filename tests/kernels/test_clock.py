"""The clock probe: its chain against plain Python, and the clock it measures."""

import numpy as np
import pytest

from fastdet.bench.floor import measured_clock_hz
from fastdet.kernels.clock import integer_chain
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
