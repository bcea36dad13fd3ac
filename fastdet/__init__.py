"""fastdet: fast classical vehicle detection (HOG + linear SVM, Numba kernels).

Public API::

    detector = fastdet.Detector()            # bundled model, default config
    detections = detector(frame_bgr_uint8)   # Detections: xyxy, score
    pipeline = fastdet.VideoPipeline(detector, fastdet.TrackConfig(every=5))
    for index, frame, boxes, track_ids in pipeline(frames): ...
    with fastdet.VideoSource("clip.mp4") as video: ...  # files, URLs, cameras: BGR frames
    with fastdet.VideoSink("out.mp4", video.fps, video.size) as sink: sink.write(frame)
    fastdet.process_video("clip.mp4", "out.mp4")    # the pipelined `fastdet run`
    records = fastdet.batch(["footage/"], "out/")   # many videos on Dask (imported on first use)
"""

from ._version import __version__
from .errors import ConfigError, FastdetError, InputError, ModelError

#: Every other public name is imported on first use (PEP 562), so ``import
#: fastdet`` costs next to nothing: the ``fastdet`` command starts compiling
#: a cold kernel cache in a second process before it imports NumPy, OpenCV
#: and Numba (see :mod:`fastdet.compile_ahead`), a library user pays for
#: what they use, and PyAV (and, for batch runs, Dask) load only when video
#: I/O is used.
_LAZY = {
    "DetectorConfig": ("fastdet.detector.config", "DetectorConfig"),
    "load_config": ("fastdet.detector.config", "load_config"),
    "Detections": ("fastdet.detector.detections", "Detections"),
    "Detector": ("fastdet.detector.detector", "Detector"),
    "FeatureOptions": ("fastdet.detector.features", "FeatureOptions"),
    "hog": ("fastdet.detector.hog_api", "hog"),
    "Model": ("fastdet.detector.model", "Model"),
    "load_model": ("fastdet.detector.model", "load_model"),
    "train": ("fastdet.training.train", "train"),
    "TrackConfig": ("fastdet.video.config", "TrackConfig"),
    "load_track_config": ("fastdet.video.config", "load_track_config"),
    "VideoPipeline": ("fastdet.video.pipeline", "VideoPipeline"),
    "VideoSource": ("fastdet.video.source", "VideoSource"),
    "VideoSink": ("fastdet.video.sink", "VideoSink"),
    "process_video": ("fastdet.video.run", "process_video"),
    # The batch package is itself callable: fastdet.batch(inputs, out_dir, ...).
    "batch": ("fastdet.batch", None),
}


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module 'fastdet' has no attribute {name!r}")
    import importlib

    module, attribute = _LAZY[name]
    value = importlib.import_module(module)
    if attribute is not None:
        value = getattr(value, attribute)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "ConfigError", "Detections", "Detector", "DetectorConfig", "FastdetError", "FeatureOptions",
    "InputError", "Model", "ModelError", "TrackConfig", "VideoPipeline", "VideoSink",
    "VideoSource", "hog", "load_config", "__version__", "load_model", "load_track_config",
    "batch", "process_video", "train",
]
