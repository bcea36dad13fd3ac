"""fastdet.kernels.alloc: NumPy's empty and zeros, allocated inline in compiled kernels."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from numba.core import event

from fastdet.kernels.alloc import empty, full, zeros


@pytest.mark.parametrize("shape, dtype", [(5, np.float32), ((3, 4), np.int32), (0, np.uint8),
                                          ((2, 0), np.bool_), (3, float)])
def test_python_calls_are_numpys(shape, dtype):
    assert zeros(shape, dtype).dtype == np.zeros(shape, dtype).dtype
    np.testing.assert_array_equal(zeros(shape, dtype), np.zeros(shape, dtype))
    got = empty(shape, dtype)
    assert got.shape == np.empty(shape, dtype).shape and got.dtype == np.dtype(dtype)


@numba.njit(cache=False)
def _allocate(n, like):
    # Every form the kernels use: int, uint64 and tuple shapes; dtype classes,
    # a dtype taken from an array, the default, positional and keyword.
    a = empty(n, np.float32)
    b = zeros((n, 3), dtype=np.int32)
    c = zeros(n)
    d = empty((2, n), dtype=like.dtype)
    e = zeros(np.uint64(n), np.bool_)
    f = zeros((n + 1, 2), np.float64)
    a[:] = 1.5
    d[:] = 2.0
    return a, b, c, d, e, f


def test_compiled_calls_give_numpys_arrays():
    a, b, c, d, e, f = _allocate(4, np.ones(1, np.float64))
    for array, shape, dtype in ((a, (4,), np.float32), (b, (4, 3), np.int32),
                                (c, (4,), np.float64), (d, (2, 4), np.float64),
                                (e, (4,), np.bool_), (f, (5, 2), np.float64)):
        assert array.shape == shape and array.dtype == dtype and array.flags.c_contiguous
    for array in (b, c, e, f):
        assert not array.any()
    assert (a == 1.5).all() and (d == 2.0).all()


@numba.njit(cache=False)
def _dirty_then(make_zeros, n):
    # Freed blocks of the same size are handed out again: a zeros that
    # skipped its memset would return the 7s written here.
    for _ in range(4):
        dirty = empty(n, np.float32)
        dirty[:] = 7.0
    fresh = zeros(n, np.float32) if make_zeros else empty(n, np.float32)
    return fresh.sum(), empty(0, np.int64).size


def test_zeros_are_zero_on_reused_memory():
    for n in (3, 64, 1000):
        assert _dirty_then(True, n) == (0.0, 0)
    # The check can fail: empty on the same reused memory is not zero.
    assert any(_dirty_then(False, n)[0] != 0.0 for n in (3, 64, 1000))


def test_compiling_them_compiles_none_of_numpys_implementations():
    compiled = []

    class Listener(event.Listener):
        def on_start(self, ev):
            pass

        def on_end(self, ev):
            dispatcher = ev.data.get("dispatcher")
            compiled.append(getattr(getattr(dispatcher, "py_func", None), "__qualname__", ""))

    @numba.njit(cache=False)
    def fresh(n):
        return empty((n, 2), np.int16), zeros(n, np.uint16), full(n, 1.5, np.float32)

    with event.install_listener("numba:compile", Listener()):
        fresh(3)
    assert any("fresh" in name for name in compiled)
    numpys = [name for name in compiled
              if "ol_np_" in name or "zero_fill" in name or "np_full" in name]
    assert numpys == [], numpys


def test_a_negative_dimension_is_numpys_error():
    @numba.njit(cache=False)
    def negative(n):
        return zeros((2, n), np.float32), empty(n, np.int32)

    with pytest.raises(ValueError, match="negative dimensions"):
        negative(-1)


@numba.njit(cache=False)
def _filled(n):
    # The fill values the kernels use: -inf, a Python float, a negative int.
    return (full(n, -np.inf, np.float32), full((n, 2), 1.0, np.float32),
            full(np.uint64(n), -1, np.int64))


def test_full_gives_numpys_arrays_python_and_compiled():
    for n in (0, 1, 5):
        for got, want in zip(_filled(n), (np.full(n, -np.inf, np.float32),
                                          np.full((n, 2), 1.0, np.float32),
                                          np.full(n, -1, np.int64))):
            assert got.dtype == want.dtype and got.flags.c_contiguous
            np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(full((2, 3), 7, np.uint8), np.full((2, 3), 7, np.uint8))
