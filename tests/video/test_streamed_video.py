"""Videos written through in place: ``-``, a FIFO, a device (see docs/reliability.md, "Outputs").

A FIFO or device whose name has no suffix (``/dev/null``, ``/dev/stdout``,
a FIFO named ``ff``) gets the container ``-`` gets, fragmented MP4; a
suffix still chooses the container.
"""

from __future__ import annotations

import io
import os
import threading

import av
import pytest
from video_files import SIZE, frame_number, numbered_frame

from fastdet.cli import app as cli
from fastdet.video.sink import VideoSink

#: Seconds a FIFO's reader may take; the writer blocks without one, so a test never waits longer.
READ_TIMEOUT = 30


class FifoReader:
    """A FIFO at ``path`` read to its end by a daemon thread (a test that fails never hangs)."""

    def __init__(self, path):
        os.mkfifo(path)
        self.data = None
        self._thread = threading.Thread(target=self._read, args=(path,), daemon=True)
        self._thread.start()

    def _read(self, path):
        with open(path, "rb") as fifo:
            self.data = fifo.read()

    def result(self):
        self._thread.join(READ_TIMEOUT)
        assert not self._thread.is_alive(), "the FIFO's writer never closed it"
        return self.data


def decoded_numbers(data):
    """``(container format, frame numbers)`` of a video held in ``data``."""
    with av.open(io.BytesIO(data)) as container:
        numbers = [frame_number(frame.to_ndarray(format="bgr24")[:SIZE[1], :SIZE[0]])
                   for frame in container.decode(video=0)]
        return container.format.name, numbers


def test_dev_null_takes_a_video():
    with VideoSink("/dev/null", 25.0, SIZE) as sink:
        for i in range(3):
            sink.write(numbered_frame(i))
    assert sink.frames == 3


@pytest.mark.parametrize("name, container", [("ff", "mp4"), ("ff.mkv", "matroska")])
def test_a_fifo_gets_its_suffix_s_container_and_without_one_mp4(tmp_path, name, container):
    path = tmp_path / name
    reader = FifoReader(path)
    with VideoSink(path, 25.0, SIZE) as sink:
        for i in range(3):
            sink.write(numbered_frame(i))
    found, numbers = decoded_numbers(reader.result())
    assert container in found.split(",") and numbers == [0, 1, 2]


def test_run_writes_to_dev_null(data_dir, capsys):
    code = cli.main(["run", str(data_dir / "test_video.mp4"), "--out", "/dev/null", "--end", "2",
                     "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert "wrote /dev/null" in capsys.readouterr().out
