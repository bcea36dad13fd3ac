"""The kernels that read cold image rows ask for them ahead (fastdet.kernels.prefetch).

A prefetch never changes a result (the conversion's and resize's own tests
compare their bytes with OpenCV's), so what is checked here is that it is
there: each kernel compiled afresh from its Python source, its LLVM IR and,
on x86-64, its machine code (the helpers they call are linked in).
"""

from __future__ import annotations

import platform

import numpy as np
import pytest
from numba import njit

from fastdet.kernels import convert, refine, resize

X86_64 = platform.machine().lower() in ("x86_64", "amd64")


def fresh(kernel, *args):
    """``kernel`` compiled again without the cache, for ``args``; its IR and assembly."""
    copy = njit(nogil=True)(kernel.py_func)
    copy(*args)
    signature = copy.signatures[0]
    return copy.inspect_llvm(signature), copy.inspect_asm(signature)


def check_prefetches(llvm_ir, assembly):
    assert "llvm.prefetch" in llvm_ir
    if X86_64:
        assert "prefetcht0" in assembly


def test_the_conversion_asks_for_rows_ahead():
    image = np.zeros((4, 32, 3), np.uint8)
    check_prefetches(*fresh(convert._bgr_to_hls, image, np.empty_like(image)))


def test_the_resize_asks_for_source_rows_ahead():
    image = np.zeros((20, 40, 3), np.uint8)
    out = np.empty((30, 50, 3), np.uint8)
    calls = []
    original = resize._resize

    class Recorder:
        def __call__(self, *args):
            calls.append(args)
            return original(*args)

    try:
        resize._resize = Recorder()
        resize.resize_linear(image, (50, 30), out=out)
    finally:
        resize._resize = original
    if not calls:
        pytest.fail("resize_linear did not call _resize for a 20x40 -> 30x50 resize")
    check_prefetches(*fresh(original, *calls[0]))


def test_the_halving_asks_for_source_rows_ahead():
    image = np.zeros((20, 64 * 3), np.uint8)
    check_prefetches(*fresh(resize._halve, image, 3, np.empty((10, 32 * 3), np.uint8)))


def test_the_side_snap_asks_for_its_strips_at_once():
    frame = np.zeros((40, 60, 3), np.uint8)
    boxes = np.array([[10, 5, 40, 35]], np.int64)
    limits = np.array([0, 0, 60, 40], np.int64)
    check_prefetches(*fresh(refine.snap_box_sides, frame, boxes, 0.1, limits,
                            np.empty_like(boxes)))
