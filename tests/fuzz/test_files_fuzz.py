"""Fuzzing the readers of files users hand to fastdet: detections files and annotations.

The promise: a reader returns what the file holds or raises
:class:`fastdet.InputError` naming the file; nothing else escapes.

Fuzzing found ``read_detections`` letting OverflowError (``1e400``, ``inf``),
UnicodeDecodeError and NumPy's ValueError escape; the cases it found are
kept as regression tests (``test_found_detections_escapes``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fastdet import Detections, InputError
from fastdet.evaluation.annotations import load_annotations
from fastdet.video.detection_files import DetectionWriter, read_detections

FRAMES = {
    0: Detections([[10, 20, 50, 60], [100, 110, 130, 150]], [2.5, 1.25], [1, 2]),
    1: Detections(np.zeros((0, 4)), [], np.zeros(0, np.int64)),
    2: Detections([[12, 20, 52, 61]], [3.0], [7]),
}
SUFFIX = {"jsonl": ".jsonl", "csv": ".csv", "mot": ".txt"}


def valid_lines(tmp_path_factory, fmt):
    path = tmp_path_factory.mktemp("valid") / f"dets{SUFFIX[fmt]}"
    with DetectionWriter(path, fmt) as writer:
        for index, detections in FRAMES.items():
            writer.write(index, detections)
    return path.read_bytes().splitlines(keepends=True)


#: Tokens that break parsers: huge and non-finite numbers, wrong types, other encodings.
TOKENS = [b"1e400", b"-1e400", b"nan", b"inf", b"99999999999999999999", b"-1", b"", b"\xff\xfe",
          b'"x"', b"null", b"[]", b"{}", b"true", b",", b'"', b"\x00", b"0.5", b"\xc3\x28"]


@st.composite
def mutated_files(draw, lines):
    """A valid detections file with a few of its lines mutated."""
    lines = list(lines)
    for _ in range(draw(st.integers(1, 3))):
        index = draw(st.integers(0, len(lines) - 1))
        line = lines[index]
        how = draw(st.sampled_from(["replace", "insert", "truncate", "random", "drop"]))
        if how == "drop" and len(lines) > 1:
            del lines[index]
            continue
        position = draw(st.integers(0, max(0, len(line) - 1)))
        if how == "replace":
            # Swap one number or field for a token.
            parts = line.split(b",")
            k = draw(st.integers(0, len(parts) - 1))
            parts[k] = draw(st.sampled_from(TOKENS))
            line = b",".join(parts)
        elif how == "insert":
            line = line[:position] + draw(st.sampled_from(TOKENS)) + line[position:]
        elif how == "truncate":
            line = line[:position] + b"\n"
        else:
            line = draw(st.binary(max_size=40)) + b"\n"
        lines[index] = line
    return b"".join(lines)


def read(tmp_path_factory, data, fmt):
    path = tmp_path_factory.mktemp("dets") / f"dets{SUFFIX[fmt]}"
    path.write_bytes(data)
    try:
        result = read_detections(path)
    except InputError as exc:
        assert str(path) in str(exc)
        return
    for detections in result.values():
        assert detections.xyxy.shape == (len(detections), 4)


@pytest.mark.parametrize("fmt", ["jsonl", "csv", "mot"])
@given(data=st.data())
def test_mutated_detections_files(tmp_path_factory, fmt, data):
    read(tmp_path_factory, data.draw(mutated_files(valid_lines(tmp_path_factory, fmt))), fmt)


@pytest.mark.parametrize("fmt, data", [
    ("jsonl", b'{"frame": 1e400, "boxes": []}\n'),                        # was OverflowError
    ("jsonl", b'{"frame": 0, "boxes": [{"box": ["a", 1, 2, 3], "score": 1}]}\n'),  # ValueError
    ("jsonl", b'{"frame": 0, "boxes": [{"box": [1, 2, 3, 99999999999], "score": 1}]}\n'),
    ("mot", b"1,1,inf,2,3,4,0.5,-1,-1,-1\n"),                             # was OverflowError
    ("csv", b"frame,track,x1,y1,x2,y2,score\n0,,1,2,3,4,\xff\n"),         # UnicodeDecodeError
    ("jsonl", b'{"frame": 0, "boxes": [{"box": [5, 2, 3, 4], "score": 1}]}\n'),  # x2 < x1
    ("jsonl", b'{"frame": 0, "boxes": [{"box": [1, 2, 3, 4], "score": NaN}]}\n'),
    ("jsonl", b'{"frame": true, "boxes": []}\n'),
    ("jsonl", b'[' * 100000 + b']' * 100000 + b'\n'),                     # nesting too deep
    ("csv", b"frame,track,x1,y1,x2,y2,score\n0,x,1,2,3,4,0.5\n"),
])
def test_found_detections_cases_are_input_errors(tmp_path, fmt, data):
    path = tmp_path / f"dets{SUFFIX[fmt]}"
    path.write_bytes(data)
    with pytest.raises(InputError, match=f"{path}:"):
        read_detections(path)


def test_mot_coordinates_may_be_fractional(tmp_path):
    path = tmp_path / "dets.txt"
    path.write_text("1,3,10.5,20.25,30.5,40.0,0.9,-1,-1,-1\n")
    detections = read_detections(path)[0]
    assert detections.xyxy.tolist() == [[10, 20, 40, 60]] and detections.track_id.tolist() == [3]


# -- annotations (fastdet/evaluation/annotations.py) ------------------------------
json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=6),
              st.integers(-10 ** 400, 10 ** 400)),
    lambda inner: st.one_of(st.lists(inner, max_size=5),
                            st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8)
boxes = st.one_of(st.lists(st.one_of(st.integers(-5, 2000), st.floats(), st.booleans(),
                                     st.integers(-10 ** 400, 10 ** 400)),
                           min_size=3, max_size=5), json_values)
objects = st.one_of(st.fixed_dictionaries({"box": boxes}, optional={
    "label": json_values, "difficult": json_values}), json_values)


@given(images=st.one_of(st.dictionaries(st.text(max_size=8), st.one_of(
    st.lists(objects, max_size=3), json_values), max_size=3), json_values))
def test_annotation_documents(tmp_path_factory, images):
    path = tmp_path_factory.mktemp("annotations") / "annotations.json"
    # allow_nan: Python's json writes NaN and Infinity, which its reader accepts.
    path.write_text(json.dumps({"images": images}))
    try:
        annotations = load_annotations(path)
    except InputError as exc:
        assert str(path) in str(exc)
        return
    for objects_of_image in annotations.values():
        for obj in objects_of_image:
            x1, y1, x2, y2 = obj["box"]
            assert np.isfinite(obj["box"]).all() and x2 > x1 and y2 > y1


@given(data=st.binary(max_size=120))
def test_annotation_bytes(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("annotations") / "annotations.json"
    path.write_bytes(data)
    try:
        load_annotations(path)
    except InputError as exc:
        assert str(path) in str(exc)


@pytest.mark.parametrize("text", [
    '{"images": {"a.jpg": [{"box": [0, 0, 1, 1' + "0" * 400 + ']}]}}',   # int beyond float
    '{"images": {"a.jpg": [{"box": [0, 0, 1, 1' + "0" * 5000 + ']}]}}',  # beyond int()'s digits
    '{"images": ' + "[" * 100000 + "]" * 100000 + "}",                   # nesting too deep
    '{"images": {"a.jpg": [{"box": [0, 0, Infinity, 1]}]}}',
])
def test_found_annotation_cases_are_input_errors(tmp_path, text):
    path = tmp_path / "annotations.json"
    path.write_text(text)
    with pytest.raises(InputError, match="annotations.json"):
        load_annotations(path)
