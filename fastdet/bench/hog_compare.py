"""``fastdet.hog`` against ``skimage.feature.hog`` on the same images.

scikit-image comes with the ``bench`` and ``test`` extras.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass

import cv2
from skimage.feature import hog as skimage_hog

from ..detector.hog_api import hog
from .timing import resize_frame


# -- fastdet.hog vs scikit-image ------------------------------------------------
@dataclass
class HogComparison:
    size: tuple
    fastdet_ms: float
    skimage_ms: float

    @property
    def speedup(self):
        return self.skimage_ms / self.fastdet_ms


def _median_seconds(function, repeat):
    function()  # warm-up (compilation, caches) untimed
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        samples.append(time.perf_counter() - start)
    return statistics.median(samples)


def hog_vs_skimage(frame, sizes=((1280, 720),), repeat=5, skimage_repeat=3,
                   cells_per_block=(2, 2), log=print):
    """Time ``fastdet.hog`` and ``skimage.feature.hog`` on the grey frame at each size.

    Both run with the same arguments (9 orientations, 8x8 cells, 2x2 blocks,
    L2-Hys) on the same uint8 image, one after the other, one thread.
    """

    rows = []
    for size in sizes:
        grey = cv2.cvtColor(resize_frame(frame, size), cv2.COLOR_BGR2GRAY)
        log(f"hog vs skimage at {size[0]}x{size[1]} ...")
        ours = _median_seconds(
            lambda image=grey: hog(image, cells_per_block=cells_per_block), repeat)
        theirs = _median_seconds(
            lambda image=grey: skimage_hog(image, cells_per_block=cells_per_block),
            skimage_repeat)
        rows.append(HogComparison(tuple(size), ours * 1e3, theirs * 1e3))
    return rows


def format_hog(rows):
    lines = ["| image (grey uint8) | fastdet.hog ms | skimage.feature.hog ms | x faster |",
             "|---|---:|---:|---:|"]
    for row in rows:
        lines.append(f"| {row.size[0]}x{row.size[1]} | {row.fastdet_ms:.2f} "
                     f"| {row.skimage_ms:.1f} | {row.speedup:.0f}x |")
    return "\n".join(lines)
