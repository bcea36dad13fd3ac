"""Linear vehicle/non-vehicle models: plain data in a ``.npz``, validated on load.

A model file holds two arrays and nothing that needs pickle:

* ``weights``: float32 (F,), the linear SVM weights already divided by the
  training scaler's standard deviations, in :class:`~fastdet.detector.features.FeatureLayout`
  order;
* ``metadata``: the UTF-8 bytes of a JSON object with the format name and
  version, the feature options, the bias (with the scaler's mean folded in),
  the feature length, SHA-256 digests of the weights and of the bias and
  feature options, and the training report.

The decision value of a feature vector ``x`` is ``bias + weights @ x``.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import ModelError
from ..files.atomic import atomic_path
from ..files.strict_json import dumps, restore_names
from .features import WINDOW, FeatureLayout, FeatureOptions

FORMAT_NAME = "fastdet-model"
FORMAT_VERSION = 1
DEFAULT_MODEL_NAME = "default_model.npz"
#: Largest window score a model may give (see :meth:`Model._largest_score`):
#: float32 scores and their heat stay finite far beyond it, and trained models
#: lie far below it (the bundled one's is about 770).
MAX_SCORE = 1e9


@dataclass
class Model:
    """A linear classifier over fastdet features.

    Parameters
    ----------
    weights : ndarray of float32, shape (F,)
        Weights in feature-vector order, scaler folded in.
    bias : float
        Intercept, scaler folded in.
    options : FeatureOptions
        How features are computed; fixes ``F``.
    report : dict
        Training report (accuracies, sizes, times); informational.

    Raises
    ------
    ModelError
        For weights of another length than the options need, weights that
        are not real numbers, non-finite weights or bias, and weights and
        bias that could give a window a score beyond :data:`MAX_SCORE`.
    TypeError
        When ``options`` is not a :class:`FeatureOptions`.
    """

    weights: np.ndarray
    bias: float
    options: FeatureOptions
    report: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.options, FeatureOptions):
            raise TypeError(f"options must be a FeatureOptions, got {type(self.options).__name__}"
                            + (" (FeatureOptions.from_dict reads a dict)"
                               if isinstance(self.options, dict) else ""))
        weights = np.asarray(self.weights)
        if weights.dtype.kind not in "biuf":
            # The float32 cast dropped the imaginary part of complex weights
            # (with a warning) and read strings as numbers.
            raise ModelError(f"model weights must be real numbers, got {weights.dtype}")
        with np.errstate(over="ignore"):   # too large for float32: refused as not finite below
            self.weights = np.ascontiguousarray(weights, dtype=np.float32)
        self.bias = float(self.bias)
        expected = self.layout.length
        if self.weights.shape != (expected,):
            raise ModelError(f"model weights have shape {self.weights.shape}, but its feature "
                             f"options need ({expected},)")
        if not (np.all(np.isfinite(self.weights)) and np.isfinite(self.bias)):
            raise ModelError("model weights or bias are not finite")
        largest = self._largest_score()
        if largest > MAX_SCORE:
            # Windows are scored and their heat summed in float32: a bias of
            # 1e38 (finite) made the heat infinite, and the boxes failed on
            # NaN deep inside; 1e300 overflowed the score array to inf.
            raise ModelError(f"model weights and bias could give window scores of "
                             f"{largest:.3g}; at most {MAX_SCORE:g} in size is supported")

    def _largest_score(self):
        """The largest ``|score|`` any window can have: every feature at its largest.

        Block-normalised HOG values are at most 1 (every norm), spatial values
        255 (means of uint8 pixels) and histogram counts a window's pixels.
        """
        hog, spatial, hist = self.split_weights()
        return (abs(self.bias) + float(np.abs(hog, dtype=np.float64).sum())
                + 255.0 * float(np.abs(spatial, dtype=np.float64).sum())
                + float(WINDOW * WINDOW) * float(np.abs(hist, dtype=np.float64).sum()))

    @property
    def layout(self):
        """The :class:`FeatureLayout` of this model's features."""
        return FeatureLayout(self.options)

    @property
    def window(self):
        """Side of the square window the model scores, in pixels."""
        return WINDOW

    def decision_function(self, features):
        """SVM margins of feature vectors.

        Parameters
        ----------
        features : ndarray, shape (N, F) or (F,)

        Returns
        -------
        ndarray of float64, shape (N,) or ()
        """
        return np.asarray(features, dtype=np.float64) @ self.weights.astype(np.float64) + self.bias

    def split_weights(self):
        """Weights per feature group: ``(hog, spatial, hist)`` arrays."""
        return self.layout.split(self.weights)

    def save(self, path):
        """Write the model atomically to ``path`` (``.npz``)."""
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as handle:
                handle.write(self.to_bytes())

    def to_bytes(self):
        """The bytes of the model's ``.npz`` file (what :meth:`save` writes)."""
        metadata = {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "window": WINDOW,
            "feature_options": self.options.to_dict(),
            "feature_length": int(self.weights.size),
            "bias": self.bias,
            "weights_sha256": _digest(self.weights),
            "settings_sha256": _settings_digest(self.bias, self.options.to_dict()),
            "report": self.report,
        }
        # Strict JSON: the bias is finite (checked above); a non-finite figure of the
        # informational report is null, and a name that is not UTF-8 (its "data" folder)
        # is text plus "<field>_bytes" (fastdet.files.strict_json), read back by _parse.
        text = dumps(metadata, nonfinite="null", sort_keys=True)
        blob = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
        buffer = io.BytesIO()
        np.savez(buffer, weights=self.weights, metadata=blob)
        return buffer.getvalue()


def _digest(weights):
    return hashlib.sha256(np.ascontiguousarray(weights, dtype="<f4").tobytes()).hexdigest()


def _settings_digest(bias, feature_options):
    """SHA-256 of what besides the weights decides a model's scores."""
    text = json.dumps({"bias": float(bias), "feature_options": feature_options}, sort_keys=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def load_model(path=None):
    """Load and validate a model file; ``None`` loads the bundled default.

    Raises
    ------
    ModelError
        With a one-line reason when the file is missing, not a model, of an
        unknown version, inconsistent or tampered with.
    TypeError
        When ``path`` is neither a path nor ``None``.
    """
    if path is None:
        data = resources.files("fastdet").joinpath("data", DEFAULT_MODEL_NAME).read_bytes()
        return _parse(io.BytesIO(data), "the bundled default model")
    if not isinstance(path, (str, os.PathLike)):
        # Path() said "expected str, bytes or os.PathLike", and bytes failed too.
        raise TypeError(f"a model must be a Model, a model file's path or None, got "
                        f"{type(path).__name__}"
                        + (" (model_from_bytes reads a model's bytes)"
                           if isinstance(path, (bytes, bytearray, memoryview)) else ""))
    if not os.fspath(path):
        raise ModelError("the model file's path is empty")   # Path("") is ".", a folder
    path = Path(path)
    if path.is_dir():
        raise ModelError(f"{path} is a folder, not a model file")
    if path.exists() and not path.is_file():
        raise ModelError(f"{path} is not a regular file (a model is read from a file)")
    if not path.is_file():
        raise ModelError(f"model file not found: {path}")
    with open(path, "rb") as handle:
        return _parse(handle, str(path))


def model_from_bytes(data, name="the model's bytes"):
    """Load and validate a model from the bytes of its ``.npz`` file
    (:meth:`Model.to_bytes`); ``name`` says what they are in an error.

    Raises
    ------
    ModelError
        As :func:`load_model`.
    """
    return _parse(io.BytesIO(data), name)


#: How every .npz (a zip archive) starts: a local file header, or the end record of an empty one.
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


def _parse(handle, name):
    start = handle.read(4)
    handle.seek(0)
    if start not in _ZIP_MAGIC:
        # np.load would take any other bytes for a pickle and suggest unpickling them.
        raise ModelError(f"{name} is not a readable fastdet model: not an .npz archive")
    try:
        with np.load(handle, allow_pickle=False) as archive:
            members = set(archive.files)
            if members != {"weights", "metadata"}:
                raise ModelError(f"{name} is not a fastdet model (arrays: {sorted(members)})")
            weights = archive["weights"]
            blob = archive["metadata"]
        if not (isinstance(weights, np.ndarray) and isinstance(blob, np.ndarray)):
            raise ModelError(f"{name} is not a fastdet model (its members are not arrays)")
    except ModelError:
        raise
    except Exception as exc:  # noqa: BLE001 - see below
        # The archive is untrusted bytes read by zipfile, zlib and NumPy's
        # header parser, whose failures on damaged input are open-ended
        # (BadZipFile, zlib.error, EOFError, tokenize's TokenError,
        # SyntaxError, NotImplementedError, ... found by fuzzing): any of
        # them means the file is not a readable model.
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ModelError(f"{name} is not a readable fastdet model: {reason}") from None
    if blob.dtype != np.uint8 or blob.ndim != 1:
        raise ModelError(f"{name} has malformed metadata")
    try:
        metadata = json.loads(blob.tobytes().decode("utf-8"))
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError too
        raise ModelError(f"{name} has unreadable metadata: {exc}") from None
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT_NAME:
        raise ModelError(f"{name} is not a fastdet model")
    version = metadata.get("format_version")
    # Types too: true and 1.0 compare equal to 1 (and 64.0 to 64) in Python, and a file
    # that spells them so was not written by fastdet.
    if not _is_json_int(version) or version != FORMAT_VERSION:
        raise ModelError(f"{name} has model format version {version!r}; "
                         f"this fastdet reads version {FORMAT_VERSION}")
    if not _is_json_int(metadata.get("window")) or metadata.get("window") != WINDOW:
        raise ModelError(f"{name} was trained on {metadata.get('window')!r}-pixel windows; "
                         f"fastdet uses {WINDOW}")
    try:
        options = FeatureOptions.from_dict(metadata["feature_options"])
        bias, length, digest = (metadata["bias"], metadata["feature_length"],
                                metadata["weights_sha256"])
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise ModelError(f"{name} has invalid metadata: {exc}") from None
    # A JSON number, an integer and a string, as fastdet writes them: float() read the
    # string "1.5" and true as a bias, int() cut a length of 8460.7 to 8460.
    if isinstance(bias, bool) or not isinstance(bias, (int, float)):
        raise ModelError(f"{name} has invalid metadata: bias must be a number, got {bias!r}")
    if not _is_json_int(length):
        raise ModelError(f"{name} has invalid metadata: feature_length must be an integer, "
                         f"got {length!r}")
    if not isinstance(digest, str):
        raise ModelError(f"{name} has invalid metadata: weights_sha256 must be a string, "
                         f"got {digest!r}")
    bias = float(bias)
    if weights.dtype != np.float32 or weights.shape != (length,):
        raise ModelError(f"{name} has weights of {weights.dtype} {weights.shape}, "
                         f"metadata says float32 ({length},)")
    if _digest(weights) != digest:
        raise ModelError(f"{name} failed its checksum: the weights were modified")
    settings = metadata.get("settings_sha256")
    if settings is not None and settings != _settings_digest(bias, options.to_dict()):
        raise ModelError(f"{name} failed its checksum: the bias or feature options were modified")
    report = restore_names(metadata.get("report", {}))
    try:
        return Model(weights=weights, bias=bias, options=options,
                     report=report if isinstance(report, dict) else {})
    except ModelError as exc:  # weights of the wrong length or not finite: name the file
        raise ModelError(f"{name}: {exc}") from None


def _is_json_int(value):
    """An integer as JSON holds it (``true`` and ``1.0`` are not)."""
    return isinstance(value, int) and not isinstance(value, bool)
