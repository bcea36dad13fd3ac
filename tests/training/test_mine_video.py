"""Mining reads only the annotated frames of a video, decoding as few others as it can."""

from __future__ import annotations

from fastdet.training.mine import annotated_frames
from video_files import frame_number, record_sources, write_clip


def test_annotated_frames_of_a_video_are_those_frames(tmp_path, monkeypatch):
    from fastdet.training import mine

    path = write_clip(tmp_path / "b.mp4", 80, fps=25.0,
                      options={"preset": "medium", "g": "12", "bf": "3"})
    sources = record_sources(monkeypatch, mine)
    annotations = {"frame3": [], "frame0010": [], "frame57": [], "frame61": [], "test1.jpg": []}
    got = {key: frame_number(frame) for key, frame in annotated_frames(path, annotations)}
    assert got == {"frame3": 3, "frame0010": 10, "frame57": 57, "frame61": 61}
    assert sources[0].frames_left_undecoded > 0
