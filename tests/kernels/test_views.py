"""fastdet.kernels.views.flat: a 1-D view of a C-contiguous array, lowered inline."""

from __future__ import annotations

import gc

import numba
import numpy as np
import pytest
from numba.core import base

from fastdet.kernels.views import flat


@numba.njit(cache=False)
def _flat(array):
    return flat(array)


@numba.njit(cache=False)
def _write_first(array, value):
    view = flat(array)
    if view.size:
        view[0] = value
    return view.size


@pytest.mark.parametrize("shape, dtype", [((3, 5, 3), np.uint8), ((7, 11), np.float32),
                                          ((13,), np.int64), ((0, 4), np.float32),
                                          ((1, 1, 1), np.float64), ((2, 0, 3), np.uint8)])
def test_equals_numpys_reshape(shape, dtype):
    rng = np.random.default_rng(sum(shape))
    array = (rng.random(shape) * 200).astype(dtype)
    want = array.reshape(array.size)
    for got in (_flat(array), flat(array)):
        assert got.shape == want.shape and got.dtype == want.dtype and got.flags.c_contiguous
        np.testing.assert_array_equal(got, want)
    # A band of whole rows of a bigger array is C-contiguous too.
    if array.shape[0] > 1:
        np.testing.assert_array_equal(_flat(array[1:]), array[1:].reshape(-1))


def test_is_a_view_that_keeps_its_array_alive():
    array = np.zeros((4, 6), np.float32)
    assert _write_first(array, 5.0) == 24
    assert array[0, 0] == 5.0
    view = _flat(np.arange(12, dtype=np.int64).reshape(3, 4))
    gc.collect()
    np.testing.assert_array_equal(view, np.arange(12))
    assert np.shares_memory(_flat(array), array)


def test_read_only_stays_read_only():
    array = np.ones((2, 3))
    array.flags.writeable = False
    assert not _flat(array).flags.writeable


def test_refuses_arrays_that_are_not_c_contiguous():
    array = np.zeros((4, 6), np.float32)
    for strided in (array[:, ::2], array.T):
        with pytest.raises(numba.core.errors.TypingError):
            _flat(strided)


def test_compiles_no_reshape_implementation(monkeypatch):
    subroutines = []
    compile_subroutine = base.BaseContext.compile_subroutine

    def recording(self, builder, impl, *args, **kwargs):
        subroutines.append(getattr(impl, "__name__", ""))
        return compile_subroutine(self, builder, impl, *args, **kwargs)

    monkeypatch.setattr(base.BaseContext, "compile_subroutine", recording)

    @numba.njit(cache=False)
    def with_flat(array):
        return flat(array)[1]

    @numba.njit(cache=False)
    def with_reshape(array):
        return array.reshape(array.size)[1]

    image = np.ones((2, 3, 3), np.uint8)
    assert with_flat(image) == 1
    assert "normalize_reshape_value" not in subroutines, subroutines
    # The check can fail: NumPy's reshape compiles it.
    assert with_reshape(image) == 1
    assert "normalize_reshape_value" in subroutines
