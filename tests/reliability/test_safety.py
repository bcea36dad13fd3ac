"""No input makes fastdet run code or write outside the paths it was given."""

from __future__ import annotations

import io
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from fastdet.cli.app import EXIT_ERROR, main
from fastdet.errors import ModelError
from fastdet.detector.model import load_model


class TouchOnUnpickle:
    """An object whose unpickling would create a file: the canary of code execution."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (Path(self.marker),))


def test_a_model_holding_a_pickle_is_refused_unexecuted(tmp_path):
    marker = tmp_path / "executed"
    for member in ("weights", "metadata"):
        buffer = io.BytesIO()
        payload = np.array([TouchOnUnpickle(marker)], dtype=object)
        other = np.zeros(3, np.float32) if member == "metadata" else np.zeros(3, np.uint8)
        np.savez(buffer, **{member: payload,
                            ("metadata" if member == "weights" else "weights"): other})
        path = tmp_path / f"{member}.npz"
        path.write_bytes(buffer.getvalue())
        with pytest.raises(ModelError, match=str(path)):
            load_model(path)
    assert not marker.exists(), "loading a model ran code"


def test_detect_out_dir_keeps_outputs_inside(tmp_path, data_dir, capsys):
    # An image reached through '..' and a name that looks like a path: the
    # drawn image is the base name, inside --out-dir.
    images = tmp_path / "images" / "sub"
    images.mkdir(parents=True)
    shutil.copy(data_dir / "test_images" / "test1.jpg", images.parent / "a.jpg")
    out = tmp_path / "out"
    assert main(["detect", str(images / ".." / "a.jpg"), "--out-dir", str(out)]) == 0
    record = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert Path(record["output"]) == out / "a.jpg"
    assert sorted(p.name for p in out.iterdir()) == ["a.jpg"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["images", "out"]


def test_detect_out_dir_refuses_a_planted_symlink(tmp_path, data_dir, capsys):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (out / "test1.jpg").symlink_to(victim)
    assert main(["detect", str(data_dir / "test_images" / "test1.jpg"),
                 "--out-dir", str(out)]) == EXIT_ERROR
    assert "symbolic link" in capsys.readouterr().err
    assert victim.read_text() == "precious"


# -- the video layer: names built from inputs, streams -----------------------------------
@pytest.mark.parametrize("url", [
    "http://127.0.0.1:9/../../etc/passwd",
    "http://127.0.0.1:9/a/..",
    "http://127.0.0.1:9/%2e%2e%2f%2e%2e%2fevil.mp4",
    "http://127.0.0.1:9/live/..%2F..%2Fetc%2Fcron.d%2Fjob.ts",
    "rtsp://127.0.0.1:9/",
    "udp://127.0.0.1:5000",
    "tcp://127.0.0.1:5000?listen",
    "3",
    "/dev/video0",
])
def test_run_default_output_of_a_stream_stays_in_the_current_folder(url):
    from fastdet.cli.run import default_output

    path = default_output(url)
    assert path.parent == Path(".") and path.name.endswith("_fastdet.mp4")
    assert re.fullmatch(r"[\w-][\w.-]*", path.name), path.name   # plain, not hidden


def test_run_default_output_of_a_file_is_beside_it_as_given(tmp_path):
    from fastdet.cli.run import default_output

    (tmp_path / "real").mkdir()
    (tmp_path / "links").mkdir()
    (tmp_path / "real" / "clip.mp4").write_bytes(b"")
    (tmp_path / "links" / "clip.mp4").symlink_to(tmp_path / "real" / "clip.mp4")
    # Beside the path the user typed (a link's folder), never the link's target's folder.
    assert default_output(tmp_path / "links" / "clip.mp4") == tmp_path / "links" / "clip_fastdet.mp4"
    assert default_output(tmp_path / "real" / ".." / "links" / "clip.mp4") == \
        tmp_path / "real" / ".." / "links" / "clip_fastdet.mp4"


def test_run_on_a_realtime_stream_writes_only_where_told(tmp_path, monkeypatch, capsys):
    """A hostile stream URL, --realtime: only the outputs given, or the default in the cwd."""
    import http.server
    import threading

    from video_files import write_clip

    served = tmp_path / "served"
    served.mkdir()
    clip = write_clip(served / "clip.mp4", 6, fps=12.0, size=(64, 48))

    class AnyPath(http.server.BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_GET(self):
            data = clip.read_bytes()
            self.send_response(200)
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), AnyPath)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    url = f"http://127.0.0.1:{server.server_address[1]}/%2e%2e%2fvictim/..%2F..%2Fevil.mp4"
    try:
        assert main(["run", url, "--realtime", "--quiet", "--timeout", "5"]) == 0
        assert main(["run", url, "--realtime", "--quiet", "--timeout", "5",
                     "--detections", "d.jsonl"]) == 0
    finally:
        server.shutdown()
        server.server_close()
    assert sorted(p.name for p in work.iterdir()) == ["d.jsonl", "evil_fastdet.mp4"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["served", "work"]
    assert sorted(p.name for p in served.iterdir()) == ["clip.mp4"]
    capsys.readouterr()
