"""Fuzzing ``Detector`` with arbitrary arrays: shapes, dtypes, strides, views, NaN and inf.

The promise: a frame the detector accepts (uint8, ``(H, W)``, ``(H, W, 1)``,
``(H, W, 3)`` or ``(H, W, 4)``, any strides) gives detections inside the
frame, the same as its contiguous copy gives; anything else raises
:class:`fastdet.InputError`.  Nothing else may escape.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from fastdet import Detector, InputError

DTYPES = [np.uint8, np.int8, np.uint16, np.int32, np.int64, np.float16, np.float32,
          np.float64, np.bool_, np.complex64]

#: View transformations of a base array: none keep it C-contiguous.
VIEWS = ("contiguous", "step", "reversed", "transposed", "fortran", "readonly", "broadcast",
         "padded")


@pytest.fixture(scope="module")
def detector():
    return Detector(threads=1)


def accepted(frame):
    """Whether the detector's documented contract accepts ``frame``."""
    return (isinstance(frame, np.ndarray) and frame.dtype == np.uint8
            and (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] in (1, 3, 4))))


def make_view(base, view):
    """``base`` (H, W[, C]) seen through a view that keeps its shape's meaning."""
    if view == "step":
        return base[::2, ::3]
    if view == "reversed":
        return base[::-1, ::-1]
    if view == "transposed":
        return np.swapaxes(base, 0, 1)
    if view == "fortran":
        return np.asfortranarray(base)
    if view == "readonly":
        base = base.copy()
        base.flags.writeable = False
        return base
    if view == "broadcast":
        return np.broadcast_to(base[:1], base.shape)
    if view == "padded":
        # Rows with a gap: a slice of a wider array.
        wide = np.zeros((base.shape[0], base.shape[1] + 5) + base.shape[2:], base.dtype)
        wide[:, 2:-3] = base
        return wide[:, 2:-3]
    return base


def finite_or_not(dtype):
    """Element strategy: for float dtypes NaN and inf included."""
    kind = np.dtype(dtype).kind
    if kind in "fc":
        return hnp.from_dtype(np.dtype(dtype), allow_nan=True, allow_infinity=True)
    return hnp.from_dtype(np.dtype(dtype))


@st.composite
def any_frames(draw):
    """Small arrays of any dtype, rank 0-4, through any view."""
    dtype = draw(st.sampled_from(DTYPES))
    shape = draw(hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=12))
    base = draw(hnp.arrays(dtype, shape, elements=finite_or_not(dtype)))
    if base.ndim >= 2:
        base = make_view(base, draw(st.sampled_from(VIEWS)))
    return base


@st.composite
def image_frames(draw):
    """uint8 frames big enough to be searched (noise from a drawn seed), through any view."""
    height = draw(st.integers(1, 400))
    width = draw(st.integers(1, 720))
    channels = draw(st.sampled_from([None, 1, 3, 4]))
    shape = (height, width) if channels is None else (height, width, channels)
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    # Smooth blobs and noise: some windows score high enough to be hits.
    base = rng.integers(0, 256, shape, dtype=np.uint8)
    if draw(st.booleans()):
        base[: height // 2] = draw(st.integers(0, 255))
    return make_view(base, draw(st.sampled_from(VIEWS)))


def check(detector, frame):
    if not accepted(frame):
        with pytest.raises(InputError):
            detector(frame)
        return
    detections = detector(frame)
    height, width = frame.shape[:2]
    xyxy = detections.xyxy
    assert xyxy.dtype == np.int32 and xyxy.shape == (len(detections), 4)
    assert detections.score.dtype == np.float32 and np.all(np.isfinite(detections.score))
    assert np.all((xyxy[:, 0] >= 0) & (xyxy[:, 1] >= 0))
    assert np.all((xyxy[:, 2] <= width) & (xyxy[:, 3] <= height))
    assert np.all((xyxy[:, 2] > xyxy[:, 0]) & (xyxy[:, 3] > xyxy[:, 1]))
    again = detector(np.ascontiguousarray(frame))
    np.testing.assert_array_equal(again.xyxy, xyxy)
    np.testing.assert_array_equal(again.score, detections.score)


@given(frame=any_frames())
def test_any_array_gives_detections_or_input_error(detector, frame):
    check(detector, frame)


@given(frame=image_frames())
def test_searched_frames_through_any_view(detector, frame):
    check(detector, frame)


@given(value=st.one_of(st.none(), st.integers(), st.floats(), st.text(max_size=5),
                       st.lists(st.lists(st.integers(0, 255), max_size=3), max_size=3)))
def test_non_arrays_raise_input_error(detector, value):
    with pytest.raises(InputError):
        detector(value)


@pytest.mark.parametrize("shape", [(0, 0), (0, 5), (5, 0, 4), (0, 0, 1), (0, 3, 3)])
def test_frames_without_pixels_have_no_boxes(detector, shape):
    # Found by the fuzzer: OpenCV refused to convert them, and planning divided by zero.
    frame = np.zeros(shape, np.uint8)
    assert len(detector(frame)) == 0
    assert detector.heatmap(frame).shape == shape[:2]
