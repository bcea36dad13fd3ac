"""``fastdet.hog``: a drop-in for ``skimage.feature.hog`` on fastdet's kernels.

The HOG that fastdet's detector computes is scikit-image's HOG (same gradients,
same hard orientation binning, same cell pooling, same four block norms; the
kernel tests pin it), so the kernels can serve scikit-image's public function
directly: same arguments (the subset below), same output shape, order and
dtype, values equal to within float32 rounding (< 1e-5).

uint8 images take the kernels' exact integer-gradient paths (vector code
for 9 bins and 8x8 cells, a lookup table otherwise); float32 images the
float32 path; float64 and other integer images a float64 path that computes
as scikit-image does, in float64 throughout (see
:func:`fastdet.kernels.hog.cell_histograms` and
:func:`fastdet.kernels.blocks.normalize_blocks`).
"""

from __future__ import annotations

import operator

import numpy as np

from ..kernels.blocks import NORM_CODES, normalize_blocks
from ..kernels.hog import cell_histograms

#: scikit-image's messages, word for word, so code that matches on them works.
_TWO_SPATIAL_DIMS = ("Only images with two spatial dimensions are supported. If using with "
                     "color/multichannel images, specify `channel_axis`.")
_INVALID_NORM = "Selected block normalization method is invalid."
_ONE_CHANNEL_AXIS = "only a single channel axis is currently supported"
_COMPLEX = "complex valued input is not supported"


def _integer(value, name):
    """``value`` as an int: integers only (NumPy's too), as scikit-image's ``range`` takes them.

    ``int()`` truncated 7.5 to 7 and read "9" and True, so a call scikit-image
    refuses (or computes at 7.5) returned other features here.
    """
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    try:
        return operator.index(value)
    except TypeError:
        raise TypeError(f"{name} must be an integer, got {value!r}") from None


def _pair(value, name):
    """``value`` as a pair of positive ints (scikit-image takes any 2-sequence)."""
    try:
        first, second = value
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair of positive integers, got {value!r}") from None
    first, second = _integer(first, name), _integer(second, name)
    if first < 1 or second < 1:
        raise ValueError(f"{name} must be a pair of positive integers, got {value!r}")
    return first, second


def _output_dtype(dtype):
    """The float dtype scikit-image computes and returns for an input dtype.

    float16 and float32 give float32; every other dtype (integers, bool,
    float64) gives float64, as in ``skimage._shared.utils._supported_float_type``.
    """
    return np.dtype(np.float32) if dtype in (np.float16, np.float32) else np.dtype(np.float64)


def _kernel_input(image, multichannel):
    """The C-contiguous (H, W, C) array the cell kernel reads.

    uint8 stays uint8 (exact integer-gradient paths); float32 and float64
    stay as they are.  bool becomes uint8 (0 and 1 give the same gradients as
    scikit-image's 0.0 and 1.0).  float16 is widened to float32 and every
    other dtype (integers, objects holding numbers) converted to float64, as
    scikit-image does (and with its ``ValueError`` for strings).
    """
    if image.dtype == np.bool_:
        image = image.astype(np.uint8)
    elif image.dtype == np.float16:
        image = image.astype(np.float32)
    elif image.dtype not in (np.uint8, np.float32, np.float64):
        image = image.astype(np.float64)
    if not multichannel:
        image = image[:, :, None]
    return np.ascontiguousarray(image)


def hog(image, orientations=9, pixels_per_cell=(8, 8), cells_per_block=(2, 2),
        block_norm="L2-Hys", channel_axis=None, feature_vector=True, *, visualize=False,
        transform_sqrt=False):
    """Histogram of Oriented Gradients, as ``skimage.feature.hog`` computes it.

    Parameters
    ----------
    image : ndarray, shape (M, N) or (M, N, C) with ``channel_axis``
        Input image.  uint8 images use the exact integer-gradient paths.
    orientations : int
        Number of unsigned orientation bins over 0-180 degrees.
    pixels_per_cell : 2-tuple of int
        ``(rows, cols)`` of a cell.
    cells_per_block : 2-tuple of int
        ``(rows, cols)`` of a block, in cells.  Note that the default here,
        ``(2, 2)`` (the block fastdet's models use), differs from
        scikit-image's ``(3, 3)``: pass it explicitly when porting code.
    block_norm : {'L1', 'L1-sqrt', 'L2', 'L2-Hys'}
        Block normalisation, as in scikit-image.
    channel_axis : int or None
        The axis holding colour channels.  ``None`` means a grey (M, N)
        image.  With channels, each pixel uses the gradient of the channel
        with the largest magnitude (scikit-image's multichannel rule).
    feature_vector : bool
        Return ``ravel()`` of the block array.
    visualize : bool
        Only ``False`` (scikit-image's default, which code ported from it
        often passes); ``True`` raises ``TypeError``.
    transform_sqrt : bool
        Take the square root of the image (in its output float dtype) before
        computing the HOG, as scikit-image does (negative values give NaN).
        The image then takes the float path, not the integer-gradient one.

    Returns
    -------
    ndarray
        Shape ``(n_blocks_row, n_blocks_col, b_row, b_col, orientations)``
        or its ravel; float32 for float16/float32 images, float64 otherwise
        (scikit-image's dtypes).

    Raises
    ------
    ValueError
        With scikit-image's messages: not two spatial dimensions, an
        unknown block norm, more than one channel axis, complex input, or an
        image smaller than one block.
    TypeError
        For ``visualize=True``, a ``channel_axis`` of ``True`` or ``False``
        (in scikit-image's positional order the sixth argument is
        ``visualize``: here it is ``channel_axis``, where a bool would read
        as axis 0 or 1), and parameters that are not integers.

    Notes
    -----
    ``visualize=True`` is not supported (``fastdet viz hog`` draws HOG
    pictures).  ``visualize`` and ``transform_sqrt`` are keyword-only: the
    positional order is fastdet's own.  Values match scikit-image to float32
    rounding for uint8 and float32 images (scikit-image's own tests ask 5
    decimals of float32) and to float64 rounding for float64 and other
    integer images (its tests ask 7 decimals): those are computed in float64.

    Examples
    --------
    >>> import numpy as np, fastdet
    >>> image = np.zeros((64, 64), np.uint8)
    >>> fastdet.hog(image, feature_vector=False).shape
    (7, 7, 2, 2, 9)
    """
    image = np.atleast_2d(np.asarray(image))
    if image.dtype.kind == "c":
        raise ValueError(_COMPLEX)
    if visualize:
        raise TypeError("visualize=True is not supported by fastdet.hog "
                        "(use skimage.feature.hog for the HOG image)")
    if isinstance(channel_axis, (bool, np.bool_)):
        raise TypeError(f"channel_axis must be an axis (an integer) or None, got "
                        f"{channel_axis!r} (fastdet.hog's sixth positional argument is "
                        f"channel_axis, scikit-image's is visualize: pass them by keyword)")
    if not image.dtype.isnative:
        # ">f4" is not np.float32 to a dtype comparison: big-endian float32
        # took the float64 path and returned float64, where scikit-image
        # returns float32.  Native order gives every dtype rule below.
        image = image.astype(image.dtype.newbyteorder("="))
    multichannel = channel_axis is not None
    if multichannel:
        axes = (channel_axis,) if np.isscalar(channel_axis) else tuple(channel_axis)
        if len(axes) > 1:
            raise ValueError(_ONE_CHANNEL_AXIS)
        image = np.moveaxis(image, axes[0], -1)
    if (image.ndim - 1 if multichannel else image.ndim) != 2:
        raise ValueError(_TWO_SPATIAL_DIMS)
    if multichannel and image.shape[-1] == 0:
        # scikit-image's own error (an empty argmax); the kernels would read no channel.
        raise ValueError("attempt to get argmax of an empty sequence")
    if block_norm not in NORM_CODES:
        raise ValueError(_INVALID_NORM)
    cell_rows, cell_cols = _pair(pixels_per_cell, "pixels_per_cell")
    block_rows, block_cols = _pair(cells_per_block, "cells_per_block")
    orientations = _integer(orientations, "orientations")
    if orientations < 1:
        raise ValueError(f"orientations must be a positive integer, got {orientations}")
    n_blocks_row = image.shape[0] // cell_rows - block_rows + 1
    n_blocks_col = image.shape[1] // cell_cols - block_cols + 1
    if n_blocks_row <= 0 or n_blocks_col <= 0:
        raise ValueError("The input image is too small given the values of pixels_per_cell and "
                         "cells_per_block. It should have at least: "
                         f"{block_rows * cell_rows} rows and {block_cols * cell_cols} cols.")

    out_dtype = _output_dtype(image.dtype)
    if transform_sqrt:
        # scikit-image's order: the image in its output float dtype, then the root.
        image = np.sqrt(image.astype(out_dtype))
    cells = cell_histograms(_kernel_input(image, multichannel), (cell_rows, cell_cols),
                            orientations, merge_channels=multichannel)
    blocks = normalize_blocks(cells, (block_rows, block_cols), block_norm)
    # One histogram channel (grey, or merged colour): the kernel's block order
    # (channel, cell_y, cell_x, bin) is scikit-image's (cell_y, cell_x, bin).
    blocks = blocks.reshape(n_blocks_row, n_blocks_col, block_rows, block_cols, orientations)
    blocks = blocks.astype(out_dtype, copy=False)
    return blocks.ravel() if feature_vector else blocks
