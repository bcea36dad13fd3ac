"""Feature options and the one feature path shared by training and detection.

A 64x64 training crop and a detection window are described by the same three
feature groups, computed by the same functions:

* HOG: :func:`hog_blocks` runs the Numba cell and block kernels over a whole
  image (a crop, or a whole resized search region).  A window's HOG features
  are the ``n x n`` blocks it covers, read row by row, each block ordered
  ``(channel, cell_y, cell_x, bin)``.
* spatial: :func:`spatial_image` box-averages the colour-converted image by
  ``window / spatial_size`` (exact float means); a window's spatial features
  are the
  ``spatial_size x spatial_size x 3`` pixels it covers in that image.
* colour histogram: per channel, counts of ``hist_bins`` equal-width bins of
  the colour-converted uint8 values over the window.

The feature vector is ``[hog, spatial, histogram]``; :class:`FeatureLayout`
knows each group's slice and shape, so a model's weights can be split into
per-group weight arrays that the window-scoring kernels read directly.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import ConfigError, InputError
from ..kernels.blocks import NORM_CODES, normalize_blocks
from ..kernels.colour import colour_maps
from ..kernels.convert import bgr_to_hls
from ..kernels.hog import cell_histograms
from .plain import plain_numbers

#: Side of a training crop and of every detection window after resizing.
WINDOW = 64

#: OpenCV conversions from BGR, by colour-space name.
COLOR_CODES = {
    "RGB": cv2.COLOR_BGR2RGB,
    "HSV": cv2.COLOR_BGR2HSV,
    "HLS": cv2.COLOR_BGR2HLS,
    "LUV": cv2.COLOR_BGR2Luv,
    "YCrCb": cv2.COLOR_BGR2YCrCb,
    "YUV": cv2.COLOR_BGR2YUV,
    "LAB": cv2.COLOR_BGR2Lab,
}

#: Values of ``FeatureOptions.hog_channel`` besides a channel index.
HOG_CHANNEL_NAMES = ("all", "gray")


@dataclass(frozen=True)
class FeatureOptions:
    """What a feature vector is made of.

    Parameters
    ----------
    color_space : str
        One of ``RGB, HSV, HLS, LUV, YCrCb, YUV, LAB`` (inputs are BGR).
    hog_channel : str or int
        ``"all"`` (HOG of each channel of the colour space, concatenated per
        block), ``"gray"`` (HOG of the grey image) or a channel index 0-2.
    orientations : int
        Unsigned orientation bins.
    pixels_per_cell : int
        Square cell side in pixels; must divide the 64-pixel window.
    cells_per_block : int
        Square block side in cells.
    block_norm : str
        ``L1``, ``L1-sqrt``, ``L2`` or ``L2-Hys``.
    spatial_size : int
        Side of the down-sampled window used as raw colour features; must
        divide 64.  0 disables the group.
    hist_bins : int
        Colour-histogram bins per channel over 0-255.  0 disables the group.
    use_hog : bool
        Whether the HOG group is used.
    """

    color_space: str = "HLS"
    hog_channel: str | int = "all"
    orientations: int = 9
    pixels_per_cell: int = 8
    cells_per_block: int = 2
    block_norm: str = "L2-Hys"
    spatial_size: int = 32
    hist_bins: int = 32
    use_hog: bool = True

    def __post_init__(self):
        plain_numbers(self)
        self.validate()

    def validate(self):
        """Raise :class:`~fastdet.errors.ConfigError` naming the first invalid option."""
        # Type checks first: a model's metadata is any JSON (a list is unhashable,
        # the string "false" is true).
        if not isinstance(self.color_space, str) or self.color_space not in COLOR_CODES:
            raise ConfigError(f"color_space must be one of {sorted(COLOR_CODES)}, "
                             f"got {self.color_space!r}")
        if not isinstance(self.use_hog, bool):
            raise ConfigError(f"use_hog must be true or false, got {self.use_hog!r}")
        channel = self.hog_channel
        if isinstance(channel, bool) or not (
                (isinstance(channel, str) and channel in HOG_CHANNEL_NAMES)
                or (isinstance(channel, int) and 0 <= channel <= 2)):
            raise ConfigError(f"hog_channel must be 'all', 'gray' or 0-2, got {channel!r}")
        for name in ("orientations", "pixels_per_cell", "cells_per_block", "spatial_size",
                     "hist_bins"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ConfigError(f"{name} must be a non-negative integer, got {value!r}")
        if self.use_hog:
            if not 1 <= self.orientations <= 180:
                raise ConfigError(f"orientations must be in 1..180, got {self.orientations}")
            if self.pixels_per_cell < 1 or WINDOW % self.pixels_per_cell:
                raise ConfigError(f"pixels_per_cell must divide {WINDOW}, "
                                 f"got {self.pixels_per_cell}")
            if not 1 <= self.cells_per_block <= WINDOW // self.pixels_per_cell:
                raise ConfigError(f"cells_per_block must be in 1..{WINDOW // self.pixels_per_cell}, "
                                 f"got {self.cells_per_block}")
            if not isinstance(self.block_norm, str) or self.block_norm not in NORM_CODES:
                raise ConfigError(f"block_norm must be one of {sorted(NORM_CODES)}, "
                                 f"got {self.block_norm!r}")
        if self.spatial_size and WINDOW % self.spatial_size:
            raise ConfigError(f"spatial_size must divide {WINDOW} (or be 0), "
                             f"got {self.spatial_size}")
        if self.hist_bins > 256:
            raise ConfigError(f"hist_bins must be at most 256, got {self.hist_bins}")
        if not (self.use_hog or self.spatial_size or self.hist_bins):
            raise ConfigError("at least one feature group must be enabled")

    def to_dict(self):
        """Plain-JSON form."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data):
        """Build from :meth:`to_dict` output, rejecting unknown keys by name."""
        if not isinstance(data, dict):
            # A model's metadata is any JSON: a list failed on joining its items.
            raise ConfigError(f"feature options must be a table (a dict), got "
                              f"{type(data).__name__}")
        known = {field.name for field in dataclasses.fields(cls)}
        unknown = sorted(map(str, set(data) - known))
        if unknown:
            raise ConfigError(f"unknown feature option(s): {', '.join(unknown)}")
        return cls(**data)


@dataclass(frozen=True)
class FeatureLayout:
    """Where each feature group sits in the feature vector, and its shape."""

    options: FeatureOptions

    @property
    def hog_channels(self):
        """Number of channels the HOG is computed on."""
        return 3 if self.options.hog_channel == "all" else 1

    @property
    def cells_per_window(self):
        return WINDOW // self.options.pixels_per_cell

    @property
    def blocks_per_window(self):
        return self.cells_per_window - self.options.cells_per_block + 1

    @property
    def block_length(self):
        """Features in one block: channels x cells x bins."""
        o = self.options
        return self.hog_channels * o.cells_per_block ** 2 * o.orientations

    @property
    def hog_shape(self):
        if not self.options.use_hog:
            return (0, 0, 0)
        n = self.blocks_per_window
        return (n, n, self.block_length)

    @property
    def spatial_shape(self):
        s = self.options.spatial_size
        return (s, s, 3) if s else (0, 0, 3)

    @property
    def hist_shape(self):
        return (3, self.options.hist_bins)

    @property
    def sizes(self):
        return tuple(int(np.prod(shape)) for shape in
                     (self.hog_shape, self.spatial_shape, self.hist_shape))

    @property
    def length(self):
        """Total feature-vector length."""
        return sum(self.sizes)

    def split(self, vector):
        """Split a feature (or weight) vector into its three groups, reshaped.

        Returns
        -------
        hog : ndarray, shape ``hog_shape``
        spatial : ndarray, shape ``spatial_shape``
        hist : ndarray, shape ``hist_shape``
        """
        vector = np.asarray(vector)
        if vector.shape != (self.length,):
            raise ValueError(f"expected a vector of length {self.length}, got shape {vector.shape}")
        n_hog, n_spatial, _ = self.sizes
        hog = vector[:n_hog].reshape(self.hog_shape)
        spatial = vector[n_hog:n_hog + n_spatial].reshape(self.spatial_shape)
        hist = vector[n_hog + n_spatial:].reshape(self.hist_shape)
        return hog, spatial, hist


def convert_color(image_bgr, color_space, out=None):
    """Convert a BGR uint8 image to ``color_space`` (uint8, 3 channels).

    uint8 BGR images to HLS take :func:`fastdet.kernels.convert.bgr_to_hls`,
    bit-identical to OpenCV's AVX2 code (all 2**24 colours, on its vector and
    on its scalar pixels) and faster (1.3x one-thread OpenCV with AVX2, 2x
    with AVX-512); everything else goes to ``cv2.cvtColor``.  ``out``: a
    C-contiguous uint8 array of the image's shape to write into.
    """
    if (color_space == "HLS" and image_bgr.dtype == np.uint8 and image_bgr.ndim == 3
            and image_bgr.shape[2] == 3):
        return bgr_to_hls(image_bgr, out)
    return cv2.cvtColor(image_bgr, COLOR_CODES[color_space], dst=out)


def color_planes(image_bgr, options, out=(None, None)):
    """The images every feature group is computed from.

    ``out``: arrays to write ``converted`` and ``grey`` into (``None``: new).

    Returns
    -------
    converted : ndarray of uint8, shape (H, W, 3)
        ``image_bgr`` in ``options.color_space``.
    grey : ndarray of uint8, shape (H, W) or None
        The grey image, when the HOG is computed on grey.
    """
    converted = convert_color(image_bgr, options.color_space, out[0])
    grey = None
    if options.hog_channel == "gray":
        grey = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY, dst=out[1])
    return converted, grey


def hog_input(converted, grey, options):
    """The uint8 (H, W, C) image the HOG is computed on.

    uint8 keeps the cell kernel on its exact integer-gradient paths (see
    :func:`fastdet.kernels.hog.cell_histograms`).
    """
    channel = options.hog_channel
    if channel == "gray":
        return grey.reshape(grey.shape[0], grey.shape[1], 1)
    if channel == "all":
        return converted
    return np.ascontiguousarray(converted[:, :, channel])[:, :, None]


def hog_blocks(hog_image, options, parallel=False):
    """Normalised HOG block map of a whole image.

    Parameters
    ----------
    hog_image : ndarray of uint8, shape (H, W, C)
        From :func:`hog_input`.
    options : FeatureOptions
    parallel : bool
        Let the kernels use Numba's threads.

    Returns
    -------
    ndarray of float32, shape (Hb, Wb, block_length)
    """
    ppc = options.pixels_per_cell
    cells = cell_histograms(hog_image, (ppc, ppc), options.orientations, parallel=parallel)
    cpb = options.cells_per_block
    return normalize_blocks(cells, (cpb, cpb), options.block_norm, parallel=parallel)


def spatial_image(converted, options):
    """Box-average the colour image by ``64 / spatial_size`` (float32, exact means).

    Window origins are multiples of the cell size, which is a multiple of the
    averaging factor, so each window's spatial features are an aligned crop of
    this image.
    """
    return colour_maps(converted, factor=WINDOW // options.spatial_size)[1]


def histogram_bin_lut(bins):
    """uint8 value -> histogram bin index, for ``bins`` equal-width bins."""
    return (np.arange(256) * bins // 256).astype(np.intp)


def crop_features(crop_bgr, options):
    """Feature vector of one 64x64 BGR uint8 crop.

    Parameters
    ----------
    crop_bgr : ndarray of uint8, shape (64, 64, 3)
    options : FeatureOptions

    Returns
    -------
    ndarray of float32, shape (FeatureLayout(options).length,)
    """
    if crop_bgr.shape != (WINDOW, WINDOW, 3) or crop_bgr.dtype != np.uint8:
        raise InputError(f"a crop must be a {WINDOW}x{WINDOW}x3 uint8 array, "
                         f"got {crop_bgr.shape} {crop_bgr.dtype}")
    converted, grey = color_planes(np.ascontiguousarray(crop_bgr), options)
    parts = []
    if options.use_hog:
        parts.append(hog_blocks(hog_input(converted, grey, options), options).ravel())
    if options.spatial_size:
        parts.append(spatial_image(converted, options).ravel())
    if options.hist_bins:
        lut = histogram_bin_lut(options.hist_bins)
        counts = [np.bincount(lut[converted[:, :, c].ravel()], minlength=options.hist_bins)
                  for c in range(3)]
        parts.append(np.concatenate(counts).astype(np.float32))
    return np.concatenate(parts).astype(np.float32, copy=False)


def features_of_crops(crops_bgr, options):
    """Stack :func:`crop_features` of an iterable of crops into (N, F) float32."""
    layout = FeatureLayout(options)
    crops = list(crops_bgr)
    out = np.empty((len(crops), layout.length), dtype=np.float32)
    for i, crop in enumerate(crops):
        out[i] = crop_features(crop, options)
    return out
