"""``fastdet.hog`` against ``skimage.feature.hog``: values, shapes, dtypes, errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage.feature import hog as skimage_hog

import fastdet

NORMS = ("L1", "L1-sqrt", "L2", "L2-Hys")

#: Largest absolute difference allowed between the two HOGs.
TOL = 1e-5

#: (shape (H, W), pixels_per_cell, cells_per_block, orientations).
CONFIGS = [
    ((64, 64), (8, 8), (2, 2), 9),
    ((37, 53), (8, 8), (2, 2), 9),
    ((65, 97), (6, 8), (3, 2), 7),
    ((48, 40), (16, 16), (1, 1), 12),
]

#: Kinds of image: uint8 (lookup-table path), float32 and float64 (float path).
KINDS = ("uint8", "float32", "float64")


def make_image(rng, shape, kind):
    if kind == "uint8":
        return rng.integers(0, 256, shape, dtype=np.uint8)
    return rng.random(shape).astype(kind)


def both(image, **kwargs):
    return fastdet.hog(image, **kwargs), skimage_hog(image, **kwargs)


def assert_same(actual, expected):
    assert actual.shape == expected.shape
    assert actual.dtype == expected.dtype
    difference = float(np.max(np.abs(actual.astype(np.float64) - expected)))
    assert difference < TOL, f"max abs difference {difference:.3g}"


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: "x".join(map(str, c[0])))
@pytest.mark.parametrize("norm", NORMS)
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("channel_axis", [None, -1])
def test_matches_skimage_block_array(channel_axis, kind, norm, config):
    shape, ppc, cpb, orientations = config
    rng = np.random.default_rng(sum(shape) + len(norm))
    image = make_image(rng, shape + ((3,) if channel_axis is not None else ()), kind)
    actual, expected = both(image, orientations=orientations, pixels_per_cell=ppc,
                            cells_per_block=cpb, block_norm=norm, channel_axis=channel_axis,
                            feature_vector=False)
    assert_same(actual, expected)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("channel_axis", [None, -1])
def test_feature_vector_is_skimage_ravel(kind, channel_axis):
    rng = np.random.default_rng(5)
    image = make_image(rng, (40, 56) + ((3,) if channel_axis is not None else ()), kind)
    actual, expected = both(image, cells_per_block=(2, 2), channel_axis=channel_axis)
    assert actual.ndim == 1
    assert_same(actual, expected)


def test_real_frame_matches_skimage(data_dir):
    frame = cv2.imread(str(data_dir / "test_images" / "test1.jpg"))
    assert frame is not None, "test_images/test1.jpg is unreadable"
    frame = np.ascontiguousarray(frame[360:520, 200:520])
    for image, axis in ((cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), None), (frame, -1)):
        actual, expected = both(image, cells_per_block=(2, 2), channel_axis=axis,
                                feature_vector=False)
        assert_same(actual, expected)


def test_channel_axis_first_is_moved_like_skimage():
    rng = np.random.default_rng(2)
    image = rng.integers(0, 256, (3, 32, 40), dtype=np.uint8)
    actual, expected = both(image, cells_per_block=(2, 2), channel_axis=0)
    assert_same(actual, expected)


@pytest.mark.parametrize("dtype", [np.bool_, np.int16, np.uint16, np.float16])
def test_other_dtypes_follow_skimage(dtype):
    rng = np.random.default_rng(3)
    image = (rng.integers(0, 2 if dtype == np.bool_ else 200, (32, 40))).astype(dtype)
    actual, expected = both(image, cells_per_block=(2, 2), block_norm="L1")
    assert_same(actual, expected)


@pytest.mark.parametrize("orientations", [255, 256, 257, 300])
@pytest.mark.parametrize("channel_axis", [None, -1])
def test_more_bins_than_a_byte_holds_match_skimage(orientations, channel_axis):
    """uint8 images look their bins up in an 8-bit table, which holds up to 255
    bins and the mark of a dropped pixel; from 256 bins they wrapped, and the
    features were off by up to 0.2."""
    rng = np.random.default_rng(orientations)
    image = make_image(rng, (32, 40) + ((3,) if channel_axis is not None else ()), "uint8")
    assert_same(*both(image, orientations=orientations, cells_per_block=(2, 2),
                      channel_axis=channel_axis, feature_vector=False))


def test_default_options_give_fastdet_block_shape():
    blocks = fastdet.hog(np.zeros((64, 64), np.uint8), feature_vector=False)
    assert blocks.shape == (7, 7, 2, 2, 9)


# -- errors: same exception type and message as scikit-image ------------------
def skimage_error(image, **kwargs):
    with pytest.raises(ValueError) as info:
        skimage_hog(image, **kwargs)
    return str(info.value)


@pytest.mark.parametrize("image, kwargs", [
    (np.zeros((32, 32, 3), np.uint8), {}),                       # colour without channel_axis
    (np.zeros((4, 32, 32, 3), np.uint8), {"channel_axis": -1}),  # 3 spatial dimensions
    (np.zeros((15, 40), np.uint8), {"cells_per_block": (2, 2)}),  # too few rows
    (np.zeros((40, 23), np.float32), {"cells_per_block": (3, 3)}),  # too few columns
    (np.zeros((5, 5), np.uint8), {"cells_per_block": (1, 1)}),   # not one cell
    (np.zeros((32, 32), np.uint8), {"block_norm": "L3"}),
    (np.zeros((32, 32), np.complex64), {}),
    (np.zeros((32, 32, 0), np.uint8), {"channel_axis": -1}),     # no channel at all
])
def test_invalid_input_raises_like_skimage(image, kwargs):
    with pytest.raises(ValueError) as info:
        fastdet.hog(image, **kwargs)
    assert str(info.value) == skimage_error(image, **kwargs)


@pytest.mark.parametrize("kwargs", [
    {"orientations": 2.5}, {"orientations": "9"}, {"orientations": True},
    {"pixels_per_cell": (7.5, 8)}, {"cells_per_block": (2.5, 2)},
    {"cells_per_block": (np.True_, 2)},
])
def test_parameters_that_are_not_integers_are_refused(kwargs):
    """They were truncated (7.5 to 7, True to 1): other features than scikit-image's,
    which refuses most of them and computes pixels_per_cell=7.5 as given."""
    with pytest.raises(TypeError, match="must be an integer"):
        fastdet.hog(np.zeros((67, 91), np.uint8), **kwargs)


def test_numpy_integers_are_integers():
    image = np.random.default_rng(3).integers(0, 256, (67, 91), dtype=np.uint8)
    np.testing.assert_array_equal(
        fastdet.hog(image, orientations=np.int64(9), pixels_per_cell=(np.int32(8), 8)),
        fastdet.hog(image))


# -- inputs and arguments ported from scikit-image code ------------------------
@pytest.mark.parametrize("dtype", [">f4", ">f2", ">f8", ">u2", ">i4"])
def test_non_native_byte_order_follows_skimage(dtype):
    """Big-endian float32 is not ``np.float32`` to a dtype comparison: it took the
    float64 path and returned float64, where scikit-image returns float32."""
    rng = np.random.default_rng(8)
    image = (rng.random((32, 40)) * (1 if dtype[1] == "f" else 200)).astype(dtype)
    actual, expected = both(image, cells_per_block=(2, 2))
    assert_same(actual, expected)
    assert_same(fastdet.hog(image.astype(image.dtype.newbyteorder("=")), cells_per_block=(2, 2)),
                expected)


@pytest.mark.parametrize("kind", KINDS + ("bool", "int16"))
@pytest.mark.parametrize("channel_axis", [None, -1])
def test_transform_sqrt_matches_skimage(kind, channel_axis):
    """``transform_sqrt`` (which ported code passes, often as ``False``) was a TypeError."""
    rng = np.random.default_rng(9)
    shape = (40, 48) + ((3,) if channel_axis is not None else ())
    if kind == "bool":
        image = rng.random(shape) > 0.5
    elif kind == "int16":
        image = rng.integers(0, 1000, shape).astype(np.int16)
    else:
        image = make_image(rng, shape, kind)
    for transform_sqrt in (True, False):
        actual, expected = both(image, cells_per_block=(2, 2), channel_axis=channel_axis,
                                transform_sqrt=transform_sqrt, feature_vector=False)
        assert_same(actual, expected)


def test_visualize_false_is_taken_and_true_refused():
    image = np.random.default_rng(4).integers(0, 256, (32, 40), dtype=np.uint8)
    assert_same(fastdet.hog(image, visualize=False), skimage_hog(image, cells_per_block=(2, 2)))
    with pytest.raises(TypeError, match="visualize=True is not supported"):
        fastdet.hog(image, visualize=True)


@pytest.mark.parametrize("channel_axis", [True, False, np.True_])
def test_bool_channel_axis_is_refused(channel_axis):
    """In scikit-image's positional order the sixth argument is ``visualize``; here
    it is ``channel_axis``, where ``False`` read as axis 0 (a colour image's rows
    taken for channels)."""
    image = np.zeros((32, 40, 3), np.uint8)
    with pytest.raises(TypeError, match="channel_axis must be an axis"):
        fastdet.hog(image, channel_axis=channel_axis)
    with pytest.raises(TypeError, match="pass them by keyword"):
        fastdet.hog(np.zeros((32, 40), np.uint8), 9, (8, 8), (2, 2), "L2-Hys", False, True)
