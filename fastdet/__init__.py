"""fastdet: fast classical vehicle detection (HOG + linear SVM, Numba kernels).

Public API::

    detector = fastdet.Detector()            # bundled model, default config
    detections = detector(frame_bgr_uint8)   # Detections: xyxy, score
    pipeline = fastdet.VideoPipeline(detector, fastdet.TrackConfig(every=5))
    for index, frame, boxes, track_ids in pipeline(frames): ...
    records = fastdet.batch(["footage/"], "out/")   # many videos on Dask (imported on first use)
"""

from .detector.config import DetectorConfig, load_config
from .detector.detections import Detections
from .detector.detector import Detector
from .detector.features import FeatureOptions
from .detector.hog_api import hog
from .detector.model import Model, load_model
from ._version import __version__
from .errors import ConfigError, FastdetError, InputError, ModelError
from .training.train import train
from .video.config import TrackConfig, load_track_config
from .video.pipeline import VideoPipeline

__all__ = [
    "ConfigError", "Detections", "Detector", "DetectorConfig", "FastdetError", "FeatureOptions",
    "InputError", "Model", "ModelError", "TrackConfig", "VideoPipeline", "hog", "load_config",
    "__version__", "load_model", "load_track_config", "train",
]


def __getattr__(name):
    # fastdet.batch imports Dask: only when it is first used.
    if name == "batch":
        import importlib

        return importlib.import_module(".batch", __name__)
    raise AttributeError(f"module 'fastdet' has no attribute {name!r}")
