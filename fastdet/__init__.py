"""fastdet: fast classical vehicle detection (HOG + linear SVM, Numba kernels).

Public API::

    detector = fastdet.Detector()            # bundled model, default config
    detections = detector(frame_bgr_uint8)   # Detections: xyxy, score
    pipeline = fastdet.VideoPipeline(detector, fastdet.TrackConfig(every=5))
    for index, frame, boxes, track_ids in pipeline(frames): ...
"""

from .config import DetectorConfig, load_config
from .detect import Detector
from .detections import Detections
from .errors import ConfigError, FastdetError, InputError, ModelError
from .features import FeatureOptions
from .hog_api import hog
from .model import Model, load_model
from .track import TrackConfig, VideoPipeline, load_track_config
from .train import train

__version__ = "0.1.0"

__all__ = [
    "ConfigError", "Detections", "Detector", "DetectorConfig", "FastdetError", "FeatureOptions",
    "InputError", "Model", "ModelError", "TrackConfig", "VideoPipeline", "hog", "load_config",
    "load_model", "load_track_config", "train",
]
