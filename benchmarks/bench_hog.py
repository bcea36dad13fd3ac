"""``fastdet.hog`` against ``skimage.feature.hog`` on grey frames of four sizes.

Same call for both (9 orientations, 8x8 cells, 2x2 blocks, L2-Hys, feature
vector), same uint8 image.  ``track_speedup`` times both in the same process
one after the other, so the ratio is measured under the same load.
"""

from __future__ import annotations

import cv2

import fastdet
from fastdet.bench.hog_compare import hog_vs_skimage

from ._common import SIZES, test_frame

HOG_ARGS = {"orientations": 9, "pixels_per_cell": (8, 8), "cells_per_block": (2, 2),
            "block_norm": "L2-Hys"}


def grey_frame(label):
    return cv2.cvtColor(test_frame(SIZES[label]), cv2.COLOR_BGR2GRAY)


class Hog:
    params = (list(SIZES),)
    param_names = ("frame_size",)

    def setup(self, label):
        self.grey = grey_frame(label)
        fastdet.hog(self.grey, **HOG_ARGS)  # compile / load the kernels

    def time_fastdet_hog(self, label):
        fastdet.hog(self.grey, **HOG_ARGS)


class SkimageHog:
    params = (list(SIZES),)
    param_names = ("frame_size",)
    # scikit-image takes about 6 s at 3840x2160: one call per sample.
    number = 1
    repeat = (1, 3, 30.0)
    warmup_time = 0
    timeout = 600

    def setup(self, label):
        from skimage.feature import hog  # the bench extra

        self.hog = hog
        self.grey = grey_frame(label)

    def time_skimage_hog(self, label):
        self.hog(self.grey, **HOG_ARGS)


class HogSpeedup:
    """skimage time / fastdet time, both measured here, in the same run."""

    params = (list(SIZES),)
    param_names = ("frame_size",)
    timeout = 600

    def setup(self, label):
        import skimage.feature  # noqa: F401 - skip cleanly if the bench extra is missing

    def track_speedup(self, label):
        (row,) = hog_vs_skimage(test_frame(SIZES[label]), [SIZES[label]], repeat=5,
                                skimage_repeat=1 if label == "3840x2160" else 3,
                                log=lambda line: None)
        return row.speedup

    track_speedup.unit = "x faster than skimage"
