"""Helpers shared by the asv benchmark modules: data, model, frames, skips.

asv skips a benchmark whose ``setup`` raises ``NotImplementedError``; every
missing prerequisite (no model, no OpenCV peer environment, no video
pipeline) is turned into that, with the reason and the fix in the message.
"""

from __future__ import annotations

import functools
import os

import numpy as np

from fastdet.bench.timing import read_frames, resize_frame
from fastdet.files.shared_data import data_dir

#: Frame sizes the kernel benchmarks are parametrised over, as asv labels.
SIZES = {"640x360": (640, 360), "1280x720": (1280, 720), "1920x1080": (1920, 1080),
         "3840x2160": (3840, 2160)}

#: Model the benchmarks use instead of the bundled one (a path), if set.
MODEL_ENV = "FASTDET_BENCH_MODEL"


def model_path():
    """``$FASTDET_BENCH_MODEL`` or None (the bundled default model)."""
    return os.environ.get(MODEL_ENV) or None


@functools.lru_cache(maxsize=None)
def bench_model():
    """The model to benchmark: ``$FASTDET_BENCH_MODEL``, else the bundled default.

    Raises
    ------
    NotImplementedError
        (asv's skip) when neither loads.
    """
    from fastdet.detector.model import load_model

    try:
        return load_model(model_path())
    except Exception as exc:  # noqa: BLE001 - any failure to load means "skip"
        raise NotImplementedError(f"no model to benchmark ({exc}); set {MODEL_ENV} to a "
                                  "model file") from None


def video_path():
    return data_dir() / "test_video.mp4"


@functools.lru_cache(maxsize=None)
def video_frames(size=None):
    """All frames of the shared test video (BGR), optionally resized; cached per process."""
    return tuple(read_frames(video_path(), None, size))


@functools.lru_cache(maxsize=None)
def test_frame(size=(1280, 720)):
    """The first video frame at ``size`` (BGR uint8)."""
    return resize_frame(video_frames()[0], size)


def spread(frames, count):
    """``count`` frames spread evenly over ``frames``."""
    indices = np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int)
    return [frames[i] for i in sorted(set(indices.tolist()))]


def skip_reason(prerequisite):
    """The ``NotImplementedError`` message of ``prerequisite()``, or None if it passes.

    asv counts an exception in ``setup_cache`` as a failure, not a skip: a
    ``setup_cache`` returns this reason instead, and ``setup`` raises it.
    """
    try:
        prerequisite()
    except NotImplementedError as exc:
        return str(exc)
    return None


def skip_if_missing(cache):
    """``setup`` of a class whose ``setup_cache`` may have returned a skip reason."""
    if isinstance(cache, dict) and cache.get("skip"):
        raise NotImplementedError(cache["skip"])
