"""``call_compiled``: a kernel calling another's own compiled code by its address.

What a call by address returns and writes must be what a direct call
returns and writes, an error raised in the callee must reach the caller's
Python caller, and the caller's code must not hold the callee's (the reason
for calling by address: Numba would build that code again inside it).
"""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from fastdet.kernels import band
from fastdet.kernels.calls import call_compiled, compiled_address
from fastdet.kernels.warmup import band_scale_calls


@njit
def _scaled_sum(values, factor, out):
    """``out[:] = values * factor``; returns their sum (a callee with a result)."""
    if factor < 0:
        raise ValueError("negative factor")
    total = 0.0
    for k in range(values.size):
        out[k] = values[k] * factor
        total += out[k]
    return total


@njit
def _fill(out, value):
    """A callee without a result."""
    for k in range(out.size):
        out[k] = value


@njit
def _through(scaled, scaled_args, fill, fill_args):
    call_compiled(fill, fill_args, None)
    return call_compiled(scaled, scaled_args, 0.0)


def test_a_call_by_address_returns_and_writes_what_a_direct_call_does():
    rng = np.random.default_rng(7)
    for size in (0, 1, 13, 257):
        values = rng.normal(size=size)
        direct_out, out = np.empty(size), np.empty(size)
        filled, direct_filled = np.zeros(5, np.int32), np.zeros(5, np.int32)
        expected = _scaled_sum(values, 3.5, direct_out)
        _fill(direct_filled, size)
        scaled, scaled_type = compiled_address(_scaled_sum, (values, 3.5, out))
        fill, fill_type = compiled_address(_fill, (filled, size))
        assert (str(scaled_type), str(fill_type)) == ("float64", "none")
        result = _through(scaled, (values, 3.5, out), fill, (filled, size))
        assert result == expected
        np.testing.assert_array_equal(out, direct_out)
        np.testing.assert_array_equal(out, values * 3.5)
        np.testing.assert_array_equal(filled, direct_filled)


def test_an_error_in_the_callee_reaches_the_caller():
    values, out, filled = np.ones(4), np.empty(4), np.zeros(2, np.int32)
    scaled, _ = compiled_address(_scaled_sum, (values, -1.0, out))
    fill, _ = compiled_address(_fill, (filled, 1))
    with pytest.raises(ValueError, match="negative factor"):
        _through(scaled, (values, -1.0, out), fill, (filled, 1))


def test_compiled_address_compiles_for_the_arguments_types():
    # A float32 array is another type than float64: its own compiled code.
    out32, out64 = np.empty(3, np.float32), np.empty(3)
    first, _ = compiled_address(_fill, (out32, 2))
    second, _ = compiled_address(_fill, (out64, 2))
    assert first != second
    assert compiled_address(_fill, (np.empty(9, np.float32), 5))[0] == first


def test_the_band_kernel_holds_no_code_of_the_kernels_it_calls():
    # The signature the warm-up's "band" family compiles.
    signature = band.band_kernel_signature(*band_scale_calls()[3])
    # The same source compiled afresh (not from the cache, which keeps no IR).
    fresh = njit(nogil=True)(band._features_and_scores.py_func)
    fresh.compile(signature)
    llvm = fresh.inspect_llvm(signature)
    defined = [line for line in llvm.splitlines() if line.startswith("define")]
    for callee in ("_cell_rows_u8_fast", "_colour_maps", "_score_window_rows"):
        assert not any(callee in line for line in defined), callee
    # The three calls are there, as calls through pointers.
    assert llvm.count("inttoptr") >= 3
