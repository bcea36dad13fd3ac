"""Every JSON document fastdet writes is strict JSON (RFC 8259) that any parser reads.

Python's ``json.dumps`` writes ``NaN``/``Infinity`` and a file name that is
not UTF-8 as the lone-surrogate escape ``"\\udcff"``, which serde_json refuses
and Go and jq turn into U+FFFD.  Each writer is read back here with a strict
parser: ``json.loads`` refusing the non-JSON constants, and every string
(keys too) encoded to UTF-8 with ``errors="strict"``.
"""

from __future__ import annotations

import base64
import io
import json
import math
import os
import shutil

import numpy as np
import pytest

from fastdet.batch.manifest import Manifest
from fastdet.cli.app import main
from fastdet.detector.detections import Detections
from fastdet.detector.features import FeatureLayout, FeatureOptions
from fastdet.detector.model import Model, load_model
from fastdet.files.strict_json import display_text, dumps, restore_names
from fastdet.video.detection_files import DetectionWriter, read_detections

#: ``v\xff.mp4``: a file name that is not UTF-8, as Python sees it (surrogateescape).
ODD_NAME = os.fsdecode(b"v\xff.mp4")


def _refuse(constant):
    raise ValueError(f"{constant} is not JSON")


def _strings(value):
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield key
            yield from _strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from _strings(item)


def strict_loads(text):
    """Parse ``text`` as a strict parser does: no NaN/Infinity, no lone surrogate."""
    if isinstance(text, bytes):
        text = text.decode("utf-8")            # strict
    text.encode("utf-8")                       # strict: a lone surrogate fails
    value = json.loads(text, parse_constant=_refuse)
    for string in _strings(value):
        string.encode("utf-8")                 # a "\udcff" escape parses to a lone surrogate
    return value


def test_the_helper_writes_names_as_text_and_bytes_and_reads_them_back():
    record = {"relative": ODD_NAME, "outputs": {"video": ODD_NAME, "plain": "a.mp4"},
              "list": [ODD_NAME], ODD_NAME: 1, "fps": 2.5}
    text = dumps(record, sort_keys=True)
    parsed = strict_loads(text)
    assert parsed["relative"] == "v\\xff.mp4"
    assert base64.b64decode(parsed["relative_bytes"]) == b"v\xff.mp4"
    assert base64.b64decode(parsed["outputs"]["video_bytes"]) == b"v\xff.mp4"
    assert "plain_bytes" not in parsed["outputs"] and parsed["list"] == ["v\\xff.mp4"]
    restored = restore_names(parsed)
    assert restored["relative"] == ODD_NAME and restored["outputs"] == record["outputs"]
    # UTF-8 names are written exactly as json.dumps wrote them.
    assert dumps({"a": "café", "n": 1}) == json.dumps({"a": "café", "n": 1})
    assert display_text("\ud800") == "\\ud800"


def test_the_helper_refuses_or_nulls_non_finite_numbers():
    with pytest.raises(ValueError):
        dumps({"x": math.nan})
    assert strict_loads(dumps({"x": [math.inf, -math.inf, math.nan, 1.5]}, nonfinite="null")) \
        == {"x": [None, None, None, 1.5]}


def test_detections_files_are_strict_json(tmp_path):
    path = tmp_path / "dets.jsonl"
    with DetectionWriter(path) as out:
        out.write(0, Detections(np.array([[1, 2, 30, 40]]), [0.5], [3]))
        out.write(1, Detections(np.zeros((0, 4)), [], np.zeros(0)))
    lines = [strict_loads(line) for line in path.read_bytes().splitlines()]
    assert lines[0] == {"frame": 0, "boxes": [{"box": [1, 2, 30, 40], "score": 0.5, "track": 3}]}
    assert len(read_detections(path)) == 2


def test_the_manifest_is_strict_json_and_finds_a_name_that_is_not_utf8_again(tmp_path):
    record = {"relative": ODD_NAME, "status": "done", "input": f"/footage/{ODD_NAME}",
              "frames": 3, "fps": None, "seconds": 0.5,
              "outputs": {"video": ODD_NAME, "detections": os.fsdecode(b"v\xff.jsonl")}}
    failed = {"relative": "b.mp4", "status": "failed", "reason": f"cannot read {ODD_NAME}"}
    manifest = Manifest(tmp_path)
    manifest.add(record)
    manifest.add(failed)
    path = tmp_path / "manifest.jsonl"
    for check in ("appended", "compacted"):
        lines = [strict_loads(line) for line in path.read_bytes().splitlines()]
        by_name = {line["relative"]: line for line in lines}
        odd = by_name["v\\xff.mp4"]
        assert base64.b64decode(odd["relative_bytes"]) == b"v\xff.mp4", check
        assert base64.b64decode(odd["outputs"]["detections_bytes"]) == b"v\xff.jsonl"
        assert base64.b64decode(by_name["b.mp4"]["reason_bytes"]) == b"cannot read v\xff.mp4"
        again = Manifest(tmp_path)                     # what a re-run reads
        assert again.get(ODD_NAME) == record and again.get("b.mp4") == failed, check
        again.compact()


def test_a_manifest_written_before_still_reads_its_lone_surrogate_escapes(tmp_path):
    old = {"relative": ODD_NAME, "status": "done", "outputs": {"video": ODD_NAME}}
    (tmp_path / "manifest.jsonl").write_text(json.dumps(old, sort_keys=True) + "\n")
    assert 'v\\udcff.mp4' in (tmp_path / "manifest.jsonl").read_text()
    assert Manifest(tmp_path).get(ODD_NAME) == old


def _metadata(path):
    with np.load(path) as data:
        return data["metadata"].tobytes()


def test_model_metadata_is_strict_json_and_keeps_the_report(tmp_path):
    options = FeatureOptions()
    weights = np.zeros(FeatureLayout(options).length, np.float32)
    report = {"data": f"/crops/{ODD_NAME}", "accuracy": math.nan, "crops": 4}
    path = tmp_path / "m.npz"
    Model(weights=weights, bias=0.25, options=options, report=report).save(path)
    metadata = strict_loads(_metadata(path))
    assert metadata["report"]["accuracy"] is None
    assert base64.b64decode(metadata["report"]["data_bytes"]) == b"/crops/v\xff.mp4"
    loaded = load_model(path)
    assert loaded.report == {"data": report["data"], "accuracy": None, "crops": 4}
    assert loaded.bias == 0.25


def test_the_bundled_model_metadata_is_strict_json():
    from importlib import resources

    from fastdet.detector.model import DEFAULT_MODEL_NAME

    blob = resources.files("fastdet").joinpath("data", DEFAULT_MODEL_NAME).read_bytes()
    with np.load(io.BytesIO(blob)) as data:
        strict_loads(data["metadata"].tobytes())


def test_detect_lines_are_strict_json_for_an_image_name_that_is_not_utf8(
        capsys, data_dir, tmp_path):
    image = tmp_path / os.fsdecode(b"road\xff.jpg")
    shutil.copy(data_dir / "test_images" / "test1.jpg", image)
    code = main(["detect", str(image), "--threads", "1", "--out-dir", str(tmp_path / "drawn")])
    out = capsys.readouterr().out
    assert code == 0
    record = strict_loads(out.strip().splitlines()[0])
    assert record["image"] == display_text(str(image))
    assert base64.b64decode(record["image_bytes"]) == os.fsencode(image)
    assert os.fsdecode(base64.b64decode(record["output_bytes"])) == str(
        tmp_path / "drawn" / image.name)
    assert (tmp_path / "drawn" / image.name).is_file()


def test_eval_json_is_strict_json_without_vehicles(capsys, data_dir, tmp_path):
    """Figures without a denominator are null (as documented), never NaN."""
    annotations = tmp_path / "empty.json"
    annotations.write_text(json.dumps({"images": {"test1.jpg": []}}))
    code = main(["eval", str(annotations), str(data_dir / "test_images"), "--threads", "1",
                 "--json"])
    out = capsys.readouterr().out
    assert code == 0
    report = strict_loads(out)
    assert (report["recall"], report["ap"]) == (None, None)


def test_eval_json_is_strict_json_for_an_image_name_that_is_not_utf8(capsys, data_dir, tmp_path):
    """An annotations file naming r\\xff.jpg (written by Python as "r\\udcff.jpg") gave the
    per-image key back as a lone-surrogate escape; it is display text now."""
    shutil.copy(data_dir / "test_images" / "test1.jpg", tmp_path / os.fsdecode(b"r\xff.jpg"))
    annotations = tmp_path / "a.json"
    annotations.write_text(json.dumps({"images": {os.fsdecode(b"r\xff.jpg"):
                                                  [{"box": [10, 10, 80, 80]}]}}))
    code = main(["eval", str(annotations), str(tmp_path), "--threads", "1", "--json"])
    out = capsys.readouterr().out
    assert code == 0
    report = strict_loads(out)
    assert list(report["images"]) == ["r\\xff.jpg"] and report["n_gt"] == 1
