"""Fuzzing ``fastdet.hog`` against ``skimage.feature.hog`` on random images and parameters.

Either both raise ``ValueError`` (with the same message, for scikit-image's
own checks) or both return arrays of the same shape and dtype whose values
agree at the output's precision: float64 images (and integers other than
uint8) to float64 rounding, uint8 and float32 ones to float32 rounding.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from skimage.feature import hog as skimage_hog

import fastdet

NORMS = ("L1", "L1-sqrt", "L2", "L2-Hys")

#: Largest difference allowed per input dtype: the float64 path computes as
#: scikit-image does; the others sum in float32.
TOLERANCE = {"float64": 1e-12, "int16": 1e-12, "uint16": 1e-12, "uint8": 1e-5,
             "float32": 1e-5, "bool": 1e-5}


@st.composite
def images(draw, finite=True):
    dtype = draw(st.sampled_from(sorted(TOLERANCE)))
    height = draw(st.integers(1, 48))
    width = draw(st.integers(1, 48))
    channel_axis = draw(st.sampled_from([None, None, -1, 0, 2]))
    shape = [height, width]
    if channel_axis is not None:
        shape.insert(channel_axis if channel_axis >= 0 else 2, draw(st.integers(1, 4)))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    if dtype == "bool":
        image = rng.random(shape) < 0.5
    elif dtype in ("uint8", "int16", "uint16"):
        info = np.iinfo(dtype)
        image = rng.integers(max(info.min, -300), min(info.max, 300), shape, dtype=dtype,
                             endpoint=True)
    else:
        # Fractional values, values that are integers (gradients on bin
        # boundaries) and a constant patch (zero gradients).
        image = rng.random(shape) * draw(st.sampled_from([1.0, 255.0, 1e-3]))
        if draw(st.booleans()):
            image = np.round(image * 10)
        image = image.astype(dtype)
        if not finite:
            flat = image.reshape(-1)
            picks = rng.integers(0, flat.size, draw(st.integers(1, 3)))
            flat[picks] = rng.choice([np.nan, np.inf, -np.inf], picks.size)
    return image, channel_axis


options = st.fixed_dictionaries({
    "orientations": st.integers(1, 12),
    "pixels_per_cell": st.tuples(st.integers(1, 10), st.integers(1, 10)),
    "cells_per_block": st.tuples(st.integers(1, 4), st.integers(1, 4)),
    "block_norm": st.sampled_from(NORMS),
    "feature_vector": st.booleans(),
})


def run(function, image, channel_axis, kwargs):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # scikit-image's NaN / inf divisions
            return function(image, channel_axis=channel_axis, **kwargs), None
    except ValueError as exc:
        return None, str(exc)


@given(case=images(), kwargs=options)
def test_hog_matches_skimage(case, kwargs):
    image, channel_axis = case
    expected, expected_error = run(skimage_hog, image, channel_axis, kwargs)
    actual, actual_error = run(fastdet.hog, image, channel_axis, kwargs)
    assert actual_error == expected_error
    if expected is None:
        return
    assert actual.shape == expected.shape and actual.dtype == expected.dtype
    if actual.size:
        difference = float(np.max(np.abs(actual.astype(np.float64) - expected)))
        assert difference <= TOLERANCE[image.dtype.name], difference


@given(case=images(finite=False), kwargs=options)
def test_hog_of_nan_and_inf_raises_nothing_else(case, kwargs):
    image, channel_axis = case
    expected, expected_error = run(skimage_hog, image, channel_axis, kwargs)
    actual, actual_error = run(fastdet.hog, image, channel_axis, kwargs)
    assert actual_error == expected_error
    if expected is not None:
        assert actual.shape == expected.shape and actual.dtype == expected.dtype
        if image.dtype == np.float64:
            # The float64 path is scikit-image's computation: same NaNs, same values.
            np.testing.assert_array_equal(np.isnan(actual), np.isnan(expected))
            finite = ~np.isnan(expected)
            np.testing.assert_allclose(actual[finite], expected[finite], rtol=0, atol=1e-12)


@pytest.mark.parametrize("value", [
    [[1, 2, 3, 4]] * 4,                       # nested lists are images
    np.arange(16, dtype=object).reshape(4, 4),  # so are object arrays of numbers
    np.array([["a"] * 4] * 4),                # strings are not
    np.zeros((4, 4), "M8[s]"),
    "image",
    None,
])
def test_hog_of_other_array_likes_behaves_like_skimage(value):
    kwargs = dict(pixels_per_cell=(2, 2), cells_per_block=(1, 1))
    try:
        expected = skimage_hog(value, **kwargs)
    except (ValueError, TypeError):
        with pytest.raises((ValueError, TypeError)):
            fastdet.hog(value, **kwargs)
        return
    actual = fastdet.hog(value, **kwargs)
    assert actual.dtype == expected.dtype
    np.testing.assert_allclose(actual, expected, rtol=0, atol=1e-12)
