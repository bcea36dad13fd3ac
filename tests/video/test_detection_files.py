"""Tests for ``fastdet.video.detection_files``: detections files in jsonl, csv and MOT formats."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fastdet.detector.detections import Detections
from fastdet.errors import InputError
from fastdet.video.detection_files import DetectionWriter, format_for, read_detections

FRAMES = {
    0: Detections([[10, 20, 50, 60], [100, 110, 130, 150]], [2.5, 1.25], [1, 2]),
    1: Detections(np.zeros((0, 4)), [], np.zeros(0, np.int64)),
    2: Detections([[12, 20, 52, 61]], [3.0], [1]),
}


def write_all(path, fmt=None, frames=FRAMES):
    with DetectionWriter(path, fmt) as writer:
        for index, detections in frames.items():
            writer.write(index, detections)
    return writer


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".part" in p.name)


def test_jsonl_has_one_line_per_frame(tmp_path):
    path = tmp_path / "dets.jsonl"
    writer = write_all(path)
    assert (writer.frames, writer.boxes) == (3, 3)
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert lines == [
        {"frame": 0, "boxes": [{"box": [10, 20, 50, 60], "score": 2.5, "track": 1},
                               {"box": [100, 110, 130, 150], "score": 1.25, "track": 2}]},
        {"frame": 1, "boxes": []},
        {"frame": 2, "boxes": [{"box": [12, 20, 52, 61], "score": 3.0, "track": 1}]},
    ]


def test_jsonl_lines_skip_the_strict_json_walk(tmp_path, monkeypatch):
    # A line is written every frame: fastdet.files.strict_json's walk of every key and
    # value cost ~3 us a box there, for lines of fixed ASCII keys and numbers only.
    import fastdet.files.strict_json as strict_json

    def walked(*args, **kwargs):
        raise AssertionError("strict_value walked a detections line")

    monkeypatch.setattr(strict_json, "strict_value", walked)
    path = tmp_path / "dets.jsonl"
    write_all(path)
    lines = path.read_text().splitlines()
    assert lines[0] == ('{"frame": 0, "boxes": [{"box": [10, 20, 50, 60], "score": 2.5, '
                        '"track": 1}, {"box": [100, 110, 130, 150], "score": 1.25, "track": 2}]}')
    assert lines[1] == '{"frame": 1, "boxes": []}'


def test_csv_has_a_header_and_one_row_per_box(tmp_path):
    path = tmp_path / "dets.csv"
    write_all(path)
    assert path.read_text().splitlines() == [
        "frame,track,x1,y1,x2,y2,score",
        "0,1,10,20,50,60,2.5000",
        "0,2,100,110,130,150,1.2500",
        "2,1,12,20,52,61,3.0000",
    ]


def test_mot_counts_frames_from_one_with_width_and_height(tmp_path):
    path = tmp_path / "dets.txt"
    write_all(path, "mot")
    assert path.read_text().splitlines() == [
        "1,1,10,20,40,40,2.5000,-1,-1,-1",
        "1,2,100,110,30,40,1.2500,-1,-1,-1",
        "3,1,12,20,40,41,3.0000,-1,-1,-1",
    ]


@pytest.mark.parametrize("name, fmt", [("d.jsonl", None), ("d.csv", None), ("d.txt", None),
                                       ("d.out", "csv"), ("d.out", None)])
def test_round_trip(tmp_path, name, fmt):
    path = tmp_path / name
    write_all(path, fmt)
    back = read_detections(path, fmt)
    expected = FRAMES if format_for(path, fmt) == "jsonl" else {
        k: v for k, v in FRAMES.items() if len(v)}
    assert sorted(back) == sorted(expected)
    for index, detections in expected.items():
        np.testing.assert_array_equal(back[index].xyxy, detections.xyxy)
        np.testing.assert_allclose(back[index].score, detections.score)
        np.testing.assert_array_equal(back[index].track_id, detections.track_id)


def test_boxes_without_track_ids(tmp_path):
    frame = {0: Detections([[1, 2, 3, 4]], [0.5])}
    write_all(tmp_path / "a.jsonl", frames=frame)
    write_all(tmp_path / "a.csv", frames=frame)
    write_all(tmp_path / "a.txt", frames=frame)
    assert json.loads((tmp_path / "a.jsonl").read_text()) == {
        "frame": 0, "boxes": [{"box": [1, 2, 3, 4], "score": 0.5}]}
    assert (tmp_path / "a.csv").read_text().splitlines()[1] == "0,,1,2,3,4,0.5000"
    assert (tmp_path / "a.txt").read_text() == "1,-1,1,2,2,2,0.5000,-1,-1,-1\n"
    assert read_detections(tmp_path / "a.csv")[0].track_id is None


def test_format_choice():
    assert format_for("x.jsonl") == format_for("x.JSON") == format_for("x") == "jsonl"
    assert format_for("x.csv") == "csv" and format_for("x.txt") == "mot"
    assert format_for("x.csv", "mot") == "mot"
    with pytest.raises(InputError, match="unknown detections format 'xml'"):
        format_for("x.csv", "xml")


def test_writes_are_atomic(tmp_path):
    path = tmp_path / "dets.jsonl"
    path.write_text("old\n")
    with pytest.raises(ValueError):
        with DetectionWriter(path) as writer:
            writer.write(0, FRAMES[0])
            assert len(leftovers(tmp_path)) == 1
            raise ValueError("boom")
    assert path.read_text() == "old\n" and leftovers(tmp_path) == []


def test_ctrl_c_keeps_every_frame_written(tmp_path):
    path = tmp_path / "dets.csv"
    with pytest.raises(KeyboardInterrupt):
        with DetectionWriter(path) as writer:
            writer.write(0, FRAMES[0])
            raise KeyboardInterrupt
    assert len(path.read_text().splitlines()) == 3 and leftovers(tmp_path) == []


def test_unwritable_destination(tmp_path):
    with pytest.raises(InputError, match="cannot write .*dets.jsonl: No such file or directory"):
        DetectionWriter(tmp_path / "missing" / "dets.jsonl")
    with pytest.raises(InputError, match="it is a directory"):
        DetectionWriter(tmp_path)


def test_read_errors_name_the_line(tmp_path):
    path = tmp_path / "bad.jsonl"
    path.write_text('{"frame": 0, "boxes": []}\nnot json\n')
    with pytest.raises(InputError, match=r"bad.jsonl:2: not a jsonl detections line"):
        read_detections(path)
    with pytest.raises(InputError, match="detections file not found"):
        read_detections(tmp_path / "none.csv")
    (tmp_path / "bad.csv").write_text("a,b\n")
    with pytest.raises(InputError, match="expected the header"):
        read_detections(tmp_path / "bad.csv")
