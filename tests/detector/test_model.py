"""Tests for ``fastdet.detector.model``: save / load round trip, and a one-line
``ModelError`` for every kind of bad model file.

The bundled default model is not tested here.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import FORMAT_VERSION, Model, load_model, model_from_bytes
from fastdet.errors import FastdetError, ModelError


# -- helpers ----------------------------------------------------------------
def make_model(options=None, seed=0, report=None):
    options = options or FeatureOptions()
    rng = np.random.default_rng(seed)
    weights = (rng.normal(size=FeatureLayout(options).length) * 0.01).astype(np.float32)
    return Model(weights=weights, bias=float(rng.normal()), options=options,
                 report=report if report is not None else {"accuracy": 0.99, "n_train": 123})


def read_arrays(path):
    """All arrays of an npz, as plain numpy arrays."""
    with np.load(path, allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def read_metadata(path):
    return json.loads(read_arrays(path)["metadata"].tobytes().decode("utf-8"))


def metadata_blob(metadata):
    return np.frombuffer(json.dumps(metadata).encode("utf-8"), dtype=np.uint8)


def sha256(weights):
    return hashlib.sha256(np.ascontiguousarray(weights, dtype="<f4").tobytes()).hexdigest()


def write_npz(path, **arrays):
    with open(path, "wb") as handle:
        np.savez(handle, **arrays)
    return path


@pytest.fixture
def saved(tmp_path):
    """A valid model file and the model it holds."""
    model = make_model()
    path = tmp_path / "model.npz"
    model.save(path)
    return path, model


def assert_model_error(path, *fragments):
    """Loading ``path`` raises ModelError with a one-line message."""
    with pytest.raises(ModelError) as info:
        load_model(path)
    message = str(info.value)
    assert message.strip(), "empty error message"
    assert "\n" not in message and "\r" not in message, f"multi-line message: {message!r}"
    for fragment in fragments:
        assert fragment.lower() in message.lower(), f"{fragment!r} not in {message!r}"
    assert isinstance(info.value, FastdetError) and isinstance(info.value, ValueError)
    return message


# -- round trip ---------------------------------------------------------------
@pytest.mark.parametrize("options", [
    FeatureOptions(),
    FeatureOptions(hog_channel="gray", spatial_size=16, hist_bins=16),
    FeatureOptions(color_space="HSV", hog_channel=2, orientations=11, block_norm="L1"),
    FeatureOptions(use_hog=False, spatial_size=0, hist_bins=8),
], ids=["default", "gray", "hsv-channel2", "hist-only"])
def test_save_load_round_trip(tmp_path, options):
    model = make_model(options, seed=4, report={"accuracy": 0.5, "sizes": [1, 2],
                                                "note": "x\ny"})
    path = tmp_path / "m.npz"
    model.save(path)
    loaded = load_model(path)
    assert loaded.options == options
    assert loaded.bias == model.bias
    assert loaded.weights.dtype == np.float32
    np.testing.assert_array_equal(loaded.weights, model.weights)
    assert loaded.report == model.report
    features = np.random.default_rng(1).random((3, model.layout.length))
    np.testing.assert_array_equal(loaded.decision_function(features),
                                  model.decision_function(features))
    # A str path works too, and nothing is left beside the file.
    assert load_model(str(path)).bias == model.bias
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


def test_bytes_are_the_saved_file_and_load_the_same_model(saved):
    path, model = saved
    data = model.to_bytes()
    # The same archive as the file but for the members' zip timestamps.
    with zipfile.ZipFile(io.BytesIO(data)) as built, zipfile.ZipFile(path) as saved_file:
        assert built.namelist() == saved_file.namelist()
        for name in built.namelist():
            assert built.read(name) == saved_file.read(name)
    loaded = model_from_bytes(data)
    assert (loaded.options, loaded.bias, loaded.report) == (model.options, model.bias,
                                                            model.report)
    np.testing.assert_array_equal(loaded.weights, model.weights)


def test_damaged_bytes_name_what_they_are(saved):
    _, model = saved
    data = bytearray(model.to_bytes())
    with pytest.raises(ModelError, match="^the batch's model is not a readable fastdet model"):
        model_from_bytes(bytes(data[:len(data) // 2]), "the batch's model")
    with pytest.raises(ModelError, match="^the model's bytes is not a readable fastdet model"):
        model_from_bytes(b"\x80\x04pickle")


def test_save_overwrites_and_file_holds_plain_arrays(saved):
    path, _ = saved
    other = make_model(seed=9)
    other.save(path)
    assert load_model(path).bias == other.bias
    arrays = read_arrays(path)  # loads with allow_pickle=False
    assert set(arrays) == {"weights", "metadata"}
    assert arrays["weights"].dtype == np.float32
    assert arrays["metadata"].dtype == np.uint8
    metadata = read_metadata(path)
    assert metadata["format_version"] == FORMAT_VERSION
    assert metadata["feature_length"] == other.weights.size
    assert metadata["weights_sha256"] == sha256(other.weights)


def test_rebuilt_file_with_unchanged_content_loads(saved, tmp_path):
    # The by-hand rebuild used below is itself a valid model file: the
    # failures of the tampered files come from what was changed, only.
    path, model = saved
    arrays = read_arrays(path)
    rebuilt = write_npz(tmp_path / "rebuilt.npz", **arrays)
    loaded = load_model(rebuilt)
    np.testing.assert_array_equal(loaded.weights, model.weights)
    assert loaded.bias == model.bias


def test_model_rejects_inconsistent_weights():
    options = FeatureOptions()
    length = FeatureLayout(options).length
    for weights in (np.zeros(length - 1), np.zeros(length + 1), np.zeros((1, length))):
        with pytest.raises(ModelError):
            Model(weights=weights, bias=0.0, options=options)
    bad = np.zeros(length, np.float32)
    bad[5] = np.inf
    with pytest.raises(ModelError):
        Model(weights=bad, bias=0.0, options=options)
    with pytest.raises(ModelError):
        Model(weights=np.zeros(length), bias=float("nan"), options=options)


# -- bad files ----------------------------------------------------------------
def test_missing_file(tmp_path):
    assert_model_error(tmp_path / "nope.npz", "not found")


def test_directory_instead_of_file(tmp_path):
    assert_model_error(tmp_path, "is a folder")


def test_empty_file(tmp_path):
    path = tmp_path / "empty.npz"
    path.write_bytes(b"")
    assert_model_error(path)


def test_text_file(tmp_path):
    path = tmp_path / "text.npz"
    path.write_text("weights = 1, 2, 3\nmetadata = {}\n")
    assert_model_error(path)


def test_pickle_is_refused_without_suggesting_to_unpickle_it(tmp_path):
    import pickle

    path = tmp_path / "model.npz"
    path.write_bytes(pickle.dumps({"weights": [1.0, 2.0]}))
    with pytest.raises(ModelError, match="not an .npz archive") as raised:
        load_model(path)
    assert "pickle" not in str(raised.value).replace(str(path), "")


def test_plain_npy_file(tmp_path):
    path = tmp_path / "weights.npz"
    np.save(path, np.zeros(8460, np.float32))  # an .npy, not an .npz
    assert_model_error(path)


@pytest.mark.parametrize("fraction", [0.5, 0.1, 0.9, "minus-one-byte"])
def test_truncated_file(saved, fraction):
    path, _ = saved
    data = path.read_bytes()
    cut = len(data) - 1 if fraction == "minus-one-byte" else int(len(data) * fraction)
    path.write_bytes(data[:cut])
    assert_model_error(path)


def test_corrupted_bytes_inside_the_archive(saved):
    # Flip bytes in the middle of the stored weights: the zip's CRC or the
    # checksum must catch it.
    path, _ = saved
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 4] = bytes(b ^ 0xFF for b in data[middle:middle + 4])
    path.write_bytes(bytes(data))
    assert_model_error(path)


def test_extra_array(saved, tmp_path):
    path, _ = saved
    arrays = read_arrays(path)
    bad = write_npz(tmp_path / "extra.npz", **arrays, scaler_mean=np.zeros(3))
    assert_model_error(bad)


@pytest.mark.parametrize("missing", ["weights", "metadata"])
def test_missing_array(saved, tmp_path, missing):
    path, _ = saved
    arrays = read_arrays(path)
    del arrays[missing]
    bad = write_npz(tmp_path / "missing.npz", **arrays)
    assert_model_error(bad)


def test_zip_whose_members_are_not_arrays(tmp_path):
    # A zip with members named like the model's arrays but holding raw bytes
    # (numpy's NpzFile returns such members as bytes, not arrays).
    path = tmp_path / "raw.npz"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("weights", b"\x00" * 16)
        archive.writestr("metadata", b"{}")
    assert_model_error(path)


def test_tampered_weights_keep_the_stored_checksum(saved, tmp_path):
    path, model = saved
    arrays = read_arrays(path)
    weights = arrays["weights"].copy()
    weights[1234] += np.float32(0.5)
    bad = write_npz(tmp_path / "tampered.npz", weights=weights, metadata=arrays["metadata"])
    assert read_metadata(bad)["weights_sha256"] == sha256(model.weights)
    assert_model_error(bad, "checksum")


def rewrite_metadata(path, tmp_path, edit, weights=None, name="edited.npz"):
    arrays = read_arrays(path)
    metadata = read_metadata(path)
    edit(metadata)
    weights = arrays["weights"] if weights is None else weights
    return write_npz(tmp_path / name, weights=weights, metadata=metadata_blob(metadata))


@pytest.mark.parametrize("version", [2, 0, "1", None])
def test_unknown_format_version(saved, tmp_path, version):
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path, lambda m: m.update(format_version=version))
    assert_model_error(bad, "version")


def test_missing_format_version(saved, tmp_path):
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path, lambda m: m.pop("format_version"))
    assert_model_error(bad, "version")


def test_wrong_format_name(saved, tmp_path):
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path, lambda m: m.update(format="something-else"))
    assert_model_error(bad)


def test_unknown_feature_option_key(saved, tmp_path):
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path,
                           lambda m: m["feature_options"].update(colour_space="RGB"))
    assert_model_error(bad, "colour_space")


def test_invalid_feature_option_value(saved, tmp_path):
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path,
                           lambda m: m["feature_options"].update(pixels_per_cell=7))
    assert_model_error(bad, "pixels_per_cell")


@pytest.mark.parametrize("option, value", [
    ("use_hog", "false"),          # a string, which is true: the HOG was used
    ("use_hog", 0),
    ("color_space", ["HLS"]),      # unhashable: a message about hashing, not the option
    ("hog_channel", ["all"]),
    ("block_norm", {"L2": 1}),
])
def test_feature_option_of_another_type(saved, tmp_path, option, value):
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path,
                           lambda m: m["feature_options"].update({option: value}))
    assert_model_error(bad, option)


@pytest.mark.parametrize("key", ["feature_options", "bias", "feature_length",
                                 "weights_sha256"])
def test_missing_metadata_key(saved, tmp_path, key):
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path, lambda m: m.pop(key))
    assert_model_error(bad)


@pytest.mark.parametrize("key, value", [
    ("feature_options", None),
    ("feature_options", [1, 2]),
    ("bias", "high"),
    ("bias", [1.0]),
    ("feature_length", "many"),
    ("window", 32),
])
def test_malformed_metadata_value(saved, tmp_path, key, value):
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path, lambda m: m.update({key: value}))
    assert_model_error(bad)


@pytest.mark.parametrize("blob", [
    np.frombuffer(b"{not json", dtype=np.uint8),
    np.frombuffer(b"\xff\xfe\x00", dtype=np.uint8),
    np.frombuffer(b"[1, 2, 3]", dtype=np.uint8),
    np.zeros((2, 3), np.uint8),
    np.zeros(4, np.float32),
], ids=["bad-json", "bad-utf8", "json-list", "2d", "float"])
def test_unreadable_metadata(saved, tmp_path, blob):
    path, _ = saved
    bad = write_npz(tmp_path / "meta.npz", weights=read_arrays(path)["weights"], metadata=blob)
    assert_model_error(bad)


@pytest.mark.parametrize("length_change", [-1, 1, -100])
def test_weights_length_inconsistent_with_options(saved, tmp_path, length_change):
    # Weights, feature_length and checksum agree with each other, but the
    # feature options need another length.
    path, model = saved
    n = model.weights.size + length_change
    weights = np.resize(model.weights, n).astype(np.float32)

    def edit(metadata):
        metadata["feature_length"] = n
        metadata["weights_sha256"] = sha256(weights)

    bad = rewrite_metadata(path, tmp_path, edit, weights=weights)
    assert_model_error(bad)


def test_weights_length_inconsistent_with_metadata(saved, tmp_path):
    path, model = saved
    weights = model.weights[:-1].copy()
    bad = rewrite_metadata(path, tmp_path, lambda m: m.update(weights_sha256=sha256(weights)),
                           weights=weights)
    assert_model_error(bad)


@pytest.mark.parametrize("dtype", [np.float64, np.float16, ">f4", np.int32])
def test_weights_of_another_dtype(saved, tmp_path, dtype):
    path, model = saved
    weights = model.weights.astype(dtype)
    bad = rewrite_metadata(path, tmp_path, lambda m: m.update(weights_sha256=sha256(weights)),
                           weights=weights)
    assert_model_error(bad)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_weights(saved, tmp_path, value):
    path, model = saved
    weights = model.weights.copy()
    weights[77] = value
    bad = rewrite_metadata(path, tmp_path, lambda m: m.update(weights_sha256=sha256(weights)),
                           weights=weights)
    assert_model_error(bad, "finite")


def test_non_finite_bias(saved, tmp_path):
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path, lambda m: m.update(bias=float("inf")))
    assert_model_error(bad)


class _Payload:
    """Unpickling this creates ``marker``: proof that the file was unpickled."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.mark.parametrize("member", ["weights", "metadata"])
def test_pickle_in_the_archive_is_never_unpickled(saved, tmp_path, member):
    path, _ = saved
    marker = tmp_path / "unpickled"
    arrays = read_arrays(path)
    payload = np.empty(1, dtype=object)
    payload[0] = _Payload(marker)
    arrays[member] = payload
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # saving pickles the object array
    bad = tmp_path / "pickled.npz"
    bad.write_bytes(buffer.getvalue())
    assert not marker.exists()
    assert_model_error(bad)
    assert not marker.exists(), "the model loader unpickled data from the file"


def test_pickle_file_is_never_unpickled(tmp_path):
    import pickle

    marker = tmp_path / "unpickled"
    path = tmp_path / "model.npz"
    path.write_bytes(pickle.dumps(_Payload(marker)))
    assert_model_error(path)
    assert not marker.exists(), "the model loader unpickled the file"


def test_payload_really_creates_the_marker_when_unpickled(tmp_path):
    # Guards the two tests above: their payload does leave a trace.
    import pickle

    marker = tmp_path / "unpickled"
    handle = pickle.loads(pickle.dumps(_Payload(marker)))
    handle.close()
    assert Path(marker).exists()


def test_edited_bias_fails_the_settings_checksum(tmp_path):
    import json as _json

    from fastdet.detector.features import FeatureLayout, FeatureOptions
    from fastdet.detector.model import Model, load_model

    options = FeatureOptions()
    model = Model(np.zeros(FeatureLayout(options).length, np.float32), 0.5, options)
    path = tmp_path / "m.npz"
    model.save(path)
    with np.load(path) as archive:
        weights, blob = archive["weights"], archive["metadata"]
    metadata = _json.loads(blob.tobytes())
    metadata["bias"] = 9.0
    edited = tmp_path / "edited.npz"
    np.savez(edited, weights=weights,
             metadata=np.frombuffer(_json.dumps(metadata).encode(), np.uint8))
    with pytest.raises(ModelError, match="bias or feature options were modified"):
        load_model(edited)


# -- models built in code, and what load_model is given -------------------------
@pytest.mark.parametrize("options", [None, {}, FeatureOptions().to_dict()],
                         ids=["none", "empty", "dict"])
def test_options_must_be_feature_options(options):
    """A dict or None failed on an attribute (``'dict' object has no attribute 'use_hog'``)."""
    with pytest.raises(TypeError, match="options must be a FeatureOptions"):
        Model(np.zeros(FeatureLayout(FeatureOptions()).length, np.float32), 0.0, options)


@pytest.mark.parametrize("dtype", [np.complex64, np.str_, object])
def test_weights_must_be_real_numbers(dtype):
    """Complex weights lost their imaginary part (with only a warning)."""
    weights = np.zeros(FeatureLayout(FeatureOptions()).length).astype(dtype)
    if dtype is np.complex64:
        weights += 1j
    with pytest.raises(ModelError, match="must be real numbers"):
        Model(weights, 0.0, FeatureOptions())


@pytest.mark.parametrize("bias, weight", [(1e38, 0.0), (1e300, 0.0), (-1e10, 0.0), (0.0, 1e6),
                                          (0.0, 3e38)])
def test_scores_beyond_float32_heat_are_refused(bias, weight):
    """A bias of 1e38 (finite) made the float32 heat infinite and detection
    failed with "cannot convert float NaN to integer"; 1e300 overflowed."""
    options = FeatureOptions()
    weights = np.full(FeatureLayout(options).length, weight, np.float32)
    with pytest.raises(ModelError, match="could give window scores"):
        Model(weights, bias, options)
    # The bound is far above any trained model's (the bundled one's is about 770).
    Model(np.full(FeatureLayout(options).length, 1e-3, np.float32), 1e8, options)


def test_largest_score_is_reached_by_some_features():
    """The bound is each group at its largest: HOG 1, spatial 255, histogram counts 64 * 64."""
    model = make_model()
    hog, spatial, hist = model.split_weights()
    features = np.concatenate([np.sign(hog).ravel(), 255 * np.sign(spatial).ravel(),
                               4096 * np.sign(hist).ravel()])
    assert model._largest_score() == pytest.approx(abs(model.decision_function(features)
                                                       - model.bias) + abs(model.bias))


@pytest.mark.parametrize("path", [3, b"model.npz", {}, 2.5])
def test_model_path_of_another_type_is_a_type_error(path):
    """``Path()``'s "expected str, bytes or os.PathLike object" (and then bytes refused)."""
    with pytest.raises(TypeError, match="a model must be a Model, a model file's path or None"):
        load_model(path)


def test_empty_model_path_is_not_the_current_folder():
    with pytest.raises(ModelError, match="path is empty"):
        load_model("")


def test_a_device_is_not_a_missing_file():
    """``/dev/null`` exists: it was reported "model file not found"."""
    with pytest.raises(ModelError, match="not a regular file"):
        load_model("/dev/null")


@pytest.mark.parametrize("field, value, message", [
    ("bias", "0.5", "bias must be a number"),               # float() read the string
    ("bias", True, "bias must be a number"),
    ("feature_length", 8460.7, "feature_length must be an integer"),   # int() cut it
    ("feature_length", "8460", "feature_length must be an integer"),
    ("weights_sha256", 12, "weights_sha256 must be a string"),
    ("format_version", True, "model format version True"),  # True == 1 in Python
    ("format_version", 1.0, "model format version 1.0"),
    ("window", 64.0, "64.0-pixel windows"),
])
def test_metadata_of_another_json_type_is_refused(saved, tmp_path, field, value, message):
    """Metadata fastdet does not write was coerced: a bias of "0.5", a length of 8460.7."""
    path, _ = saved
    bad = rewrite_metadata(path, tmp_path, lambda metadata: metadata.update({field: value}))
    with pytest.raises(ModelError, match=message):
        load_model(bad)
