"""What every video of a batch is processed with, and the hashes that identify it.

A :class:`BatchSettings` is built once on the client from the options of
``fastdet run`` (model, config, ``--every``, ``--track``, outputs) and sent to
each worker once, inside the worker plugin; tasks name it by its hashes.  The
model travels as the bytes of its ``.npz`` file (models are never pickled) and
is validated again where it is loaded.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from ..detector.config import DetectorConfig, load_config, with_search_horizon
from ..detector.model import DEFAULT_MODEL_NAME, load_model, model_from_bytes
from ..errors import InputError
from ..video.codecs import DEFAULT_CODEC, DEFAULT_CRF, DEFAULT_PRESET
from ..video.config import TrackConfig, load_track_config
from ..video.detection_files import FORMATS
from ..video.sink import check_encoder, refuse_encoder_options_without_video
from ..video.source import MAX_THREADS

#: ``BatchSettings.encoder`` when no --codec, --crf or --preset is given.
DEFAULT_ENCODER = ("h264", None, None)
#: Suffix of the detections file per format.
DETECTION_SUFFIXES = {"jsonl": ".jsonl", "csv": ".csv", "mot": ".txt"}


@dataclass(frozen=True)
class BatchSettings:
    """The model, configuration and outputs of a batch.

    Attributes
    ----------
    model_bytes : bytes
        The model file (``.npz``).
    model_sha256 : str
        SHA-256 of ``model_bytes``.
    detector_config : DetectorConfig
    track_config : TrackConfig
    write_video : bool
        Write the annotated video.
    detections_format : str or None
        ``"jsonl"``, ``"csv"``, ``"mot"``, or ``None`` for no detections file.
    threads : int
        Threads each task's detector scores scales on (Numba and OpenCV).
    codec : str
        Codec of the annotated videos (``fastdet run --codec``).
    crf : int or None
        Encoder quality, ``None`` for the codec's default.
    preset : str or None
        Encoder speed preset, ``None`` for the codec's default.
    """

    model_bytes: bytes = field(repr=False)
    model_sha256: str
    detector_config: DetectorConfig
    track_config: TrackConfig
    write_video: bool = True
    detections_format: str | None = "jsonl"
    threads: int = 1
    codec: str = "h264"
    crf: int | None = None
    preset: str | None = None

    @property
    def config_sha256(self):
        """SHA-256 of everything besides the model that decides the outputs' content."""
        settings = {"detector": dataclasses.asdict(self.detector_config),
                    "track": dataclasses.asdict(self.track_config),
                    "video": self.write_video, "detections": self.detections_format}
        if self.write_video and self.encoder != DEFAULT_ENCODER:
            # Only a non-default encoder joins the hash, so that folders done
            # before --codec existed are still recognised as done.
            settings["encoder"] = self.encoder
        text = json.dumps(settings, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()

    def model(self):
        """The model, loaded (and validated) from :attr:`model_bytes`."""
        return model_from_bytes(self.model_bytes, "the batch's model")

    @property
    def encoder(self):
        """``(codec, crf, preset)`` of the annotated videos."""
        return (self.codec, self.crf, self.preset)

    @property
    def name(self):
        """Names the worker plugin holding this model and configuration."""
        return f"fastdet-batch-{self.model_sha256[:16]}-{self.config_sha256[:16]}-t{self.threads}"

    def detections_suffix(self):
        """Suffix of the detections files (``.jsonl``, ``.csv``, ``.txt``)."""
        return DETECTION_SUFFIXES[self.detections_format]


def make_settings(model=None, config=None, every=None, track=False, video=True,
                  detections=True, format=None, threads=1, codec=None, crf=None,
                  preset=None, horizon=None):
    """Build and validate :class:`BatchSettings` from ``fastdet run``'s options.

    Parameters
    ----------
    model : str or Path, optional
        Model file; the bundled model by default.
    config : str or Path, optional
        TOML configuration (its ``[track]`` section included).
    horizon : float or "auto", optional
        Overrides ``[search] horizon``.
    every : int, optional
        Overrides ``track.every``.
    track : bool
        Sets ``track.tracking``.
    video, detections : bool
        Which outputs to write (at least one).
    format : {'jsonl', 'csv', 'mot'}, optional
        Detections format, jsonl by default.
    threads : int
        Detector threads per task.
    codec, crf, preset : str, int, str, optional
        Encoder of the annotated videos, as ``fastdet run`` takes them
        (default H.264 at its defaults); refused without ``video``.

    Raises
    ------
    InputError, ModelError, ConfigError
        With a one-line reason, before any work starts.
    """
    if not (video or detections):
        raise InputError("nothing to write: keep the annotated video, the detections or both")
    if format is not None and format not in FORMATS:
        raise InputError(f"unknown detections format {format!r} (choose from {', '.join(FORMATS)})")
    if every is not None and (isinstance(every, bool) or not isinstance(every, int) or every < 1):
        raise InputError(f"--every must be a whole number >= 1, got {every!r}")
    if (isinstance(threads, bool) or not isinstance(threads, int)
            or not 1 <= threads <= MAX_THREADS):
        # As fastdet run bounds them: 100000 failed in MemoryError tracebacks.
        raise InputError(f"--threads must be 1-{MAX_THREADS}, got {threads}")
    if crf is not None and (isinstance(crf, bool) or not isinstance(crf, int)):
        raise InputError(f"--crf must be a whole number, got {crf!r}")
    if video:
        codec = DEFAULT_CODEC if codec is None else codec
        check_encoder(codec, crf, preset)     # a one-line error here, not on every worker
    else:
        # They would decide nothing (as fastdet run without --out refuses them).
        refuse_encoder_options_without_video(codec, crf, preset, "drop --no-video")
        codec = DEFAULT_CODEC
    if model is None:
        model_bytes = resources.files("fastdet").joinpath("data", DEFAULT_MODEL_NAME).read_bytes()
    else:
        load_model(model)                     # a one-line error here, not on every worker
        model_bytes = Path(model).read_bytes()
    track_config = load_track_config(config)
    if every is not None:
        track_config = track_config.replace(every=every)
    if track:
        track_config = track_config.replace(tracking=True)
    return BatchSettings(model_bytes=model_bytes,
                         model_sha256=hashlib.sha256(model_bytes).hexdigest(),
                         detector_config=with_search_horizon(load_config(config), horizon),
                         track_config=track_config, write_video=bool(video),
                         detections_format=(format or "jsonl") if detections else None,
                         threads=threads, codec=codec,
                         # A default given explicitly is the default: same outputs, same hash.
                         crf=None if crf == DEFAULT_CRF.get(codec) else crf,
                         preset=(None if preset is None or str(preset) == DEFAULT_PRESET.get(codec)
                                 else str(preset)))
