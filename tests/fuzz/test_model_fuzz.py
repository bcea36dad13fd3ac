"""Fuzzing the model loader with mutated model files.

The promise: ``load_model`` returns a model whose weights are the bundled
model's (a mutation that leaves the archive readable and consistent, such as
a changed timestamp, changes nothing), or raises :class:`fastdet.ModelError`;
nothing else escapes, and nothing is ever unpickled.
"""

from __future__ import annotations

import io
import json
from importlib import resources

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fastdet import ModelError, load_model
from fastdet.detector.model import DEFAULT_MODEL_NAME

BUNDLED = resources.files("fastdet").joinpath("data", DEFAULT_MODEL_NAME).read_bytes()
REFERENCE = load_model()


def archive(**members):
    buffer = io.BytesIO()
    np.savez(buffer, **members)
    return buffer.getvalue()


def bundled_members():
    with np.load(io.BytesIO(BUNDLED), allow_pickle=False) as data:
        return data["weights"], json.loads(data["metadata"].tobytes().decode())


def check(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("model") / "model.npz"
    path.write_bytes(data)
    try:
        model = load_model(path)
    except ModelError:
        return
    np.testing.assert_array_equal(model.weights, REFERENCE.weights)
    assert model.bias == REFERENCE.bias and model.options == REFERENCE.options


@given(position=st.integers(0, len(BUNDLED) - 1), value=st.integers(0, 255))
def test_one_byte_changed(tmp_path_factory, position, value):
    data = bytearray(BUNDLED)
    data[position] = value
    check(tmp_path_factory, bytes(data))


@given(cuts=st.lists(st.integers(0, len(BUNDLED)), min_size=1, max_size=3),
       junk=st.binary(max_size=64))
def test_cut_and_spliced(tmp_path_factory, cuts, junk):
    # Truncations, deleted spans and inserted bytes.
    cuts = sorted(cuts)
    data = BUNDLED[:cuts[0]] + junk + BUNDLED[cuts[-1]:] if len(cuts) > 1 else BUNDLED[:cuts[0]]
    check(tmp_path_factory, data)


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=6)),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=6)


@given(key=st.sampled_from(["format", "format_version", "window", "feature_options",
                            "feature_length", "bias", "weights_sha256", "settings_sha256",
                            "report", "extra"]),
       value=json_values, option=st.sampled_from([None, "color_space", "hog_channel",
                                                  "orientations", "pixels_per_cell",
                                                  "spatial_size", "use_hog", "unknown"]))
def test_metadata_values_changed(tmp_path_factory, key, value, option):
    weights, metadata = bundled_members()
    if option is not None and key == "feature_options":
        metadata[key][option] = value
    else:
        metadata[key] = value
    blob = np.frombuffer(json.dumps(metadata).encode(), dtype=np.uint8)
    check(tmp_path_factory, archive(weights=weights, metadata=blob))


@given(dtype=st.sampled_from(["<f4", ">f4", "<f8", "<i4", "|u1", "<c8", "|b1"]),
       length=st.integers(0, 9000), special=st.sampled_from([None, np.nan, np.inf, 1e38]))
def test_weights_replaced(tmp_path_factory, dtype, length, special):
    _, metadata = bundled_members()
    weights = np.zeros(length, dtype=dtype)
    if special is not None and length and weights.dtype.kind in "fc":
        weights[length // 2] = special
    blob = np.frombuffer(json.dumps(metadata).encode(), dtype=np.uint8)
    check(tmp_path_factory, archive(weights=weights, metadata=blob))


@pytest.mark.parametrize("members", [
    {"weights": np.array([{"x": 1}], dtype=object)},            # needs pickle
    {"weights": np.zeros(3), "metadata": np.array(["text"])},
    {"weights": np.zeros(3), "metadata": np.zeros((2, 2), np.uint8)},
    {"weights": np.zeros(3), "metadata": np.frombuffer(b"\xff\xfe", np.uint8)},
    {"a": np.zeros(1)},
])
def test_archives_that_are_no_model(tmp_path, members):
    path = tmp_path / "model.npz"
    buffer = io.BytesIO()
    np.savez(buffer, **{"metadata": np.zeros(0, np.uint8), **members})
    path.write_bytes(buffer.getvalue())
    with pytest.raises(ModelError):
        load_model(path)


@pytest.mark.parametrize("text", [
    '{"format": "fastdet-model", "feature_length": 1' + "0" * 5000 + "}",
    "[" * 100000 + "]" * 100000,
    '{"format": "fastdet-model", "format_version": 1, "window": 64, "feature_length": 1e400}',
])
def test_found_metadata_cases_are_model_errors(tmp_path, text):
    weights, _ = bundled_members()
    path = tmp_path / "model.npz"
    path.write_bytes(archive(weights=weights,
                             metadata=np.frombuffer(text.encode(), dtype=np.uint8)))
    with pytest.raises(ModelError, match="model.npz"):
        load_model(path)
