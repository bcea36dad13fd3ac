"""SIGINT and SIGTERM at a random frame of a real ``fastdet run``: complete, valid outputs.

The input is the benchmark's: the test clip looped forward and back to 1000
frames (``fastdet.bench.video_run.looped_video``).  A ``fastdet run`` process
writes the annotated video and the detections file; once the detections
file holds a randomly chosen number of frames the test sends the signal and
checks the promises of ``docs/reliability.md``:

* exit status 130 (SIGINT) or 143 (SIGTERM), and the summary says so;
* the detections file parses and holds frames ``0..n-1``;
* the video decodes to its end, no frame damaged, and holds the same ``n``
  frames (from its timestamps);
* no temporary file is left.

The default profile sends a few signals early in the video; the ``slow``
stress version (``python -m pytest -m slow tests/video/test_signals.py -s``)
sends 20 of each anywhere in the 1000 frames and prints a table.
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import pytest

from fastdet.bench.video_run import LOOPED_FRAMES, looped_video
from fastdet.files.atomic import is_temporary
from fastdet.video.detection_files import read_detections

ROOT = Path(__file__).resolve().parents[2]
#: ``--every 5`` keeps a run quick; every frame still reaches both outputs.
OPTIONS = ("--every", "5", "--quiet")
SIGNALS = {signal.SIGINT: 130, signal.SIGTERM: 143}


@dataclass
class Trial:
    """One run stopped by a signal: what was asked and what the outputs hold."""

    signum: int
    at_frame: int
    returncode: int
    detections: int
    video: int
    seconds: float


def frames_of_video(path):
    """The frame indices of an output video, from its timestamps; fails on any damage."""
    with av.open(str(path)) as video:
        stream = video.streams.video[0]
        # Read while the container is open: a closed stream's fields are garbage.
        step = stream.time_base * (stream.average_rate or Fraction(25))
        pts = []
        for frame in video.decode(stream):
            assert not frame.is_corrupt, f"{path}: frame {len(pts)} damaged"
            pts.append(frame.pts)
    return [round((p - pts[0]) * step) for p in pts]


def lines_in(path):
    try:
        with open(path, "rb") as handle:
            return handle.read().count(b"\n")
    except FileNotFoundError:
        return 0


def temporary_of(folder, name):
    """The temporary file of the output ``name`` in ``folder`` (while it is being written)."""
    stem = Path(name).stem
    return next((p for p in folder.iterdir() if is_temporary(p) and p.name.startswith(f".{stem}.")),
                None)


def signal_at_frame(video, folder, signum, at_frame, timeout=300):
    """Run ``fastdet run`` on ``video``; send ``signum`` once ``at_frame`` frames are done."""
    out, dets = folder / "out.mp4", folder / "dets.jsonl"
    command = [sys.executable, "-m", "fastdet.cli", "run", str(video), "--out", str(out),
               "--detections", str(dets), *OPTIONS]
    started = time.monotonic()
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, cwd=ROOT)
    try:
        # The detections file is written line by line into its temporary file.
        while process.poll() is None and time.monotonic() - started < timeout:
            temporary = temporary_of(folder, dets.name)
            if temporary is not None and lines_in(temporary) >= at_frame:
                process.send_signal(signum)
                break
            time.sleep(0.005)
        stdout, stderr = process.communicate(timeout=timeout)
    finally:
        if process.poll() is None:
            process.kill()
    seconds = time.monotonic() - started
    assert process.returncode == SIGNALS[signum], stderr
    assert stdout.startswith("interrupted after "), stdout
    assert stderr.strip().splitlines()[-1] == "fastdet: interrupted", stderr
    detected = sorted(read_detections(dets))
    assert detected == list(range(len(detected))) and len(detected) >= at_frame
    shown = frames_of_video(out)
    assert shown == detected, f"video frames {shown[:3]}..{shown[-3:]}, detections {len(detected)}"
    assert f"interrupted after {len(detected)} frames" in stdout
    assert [p.name for p in folder.iterdir() if is_temporary(p)] == []
    return Trial(signum, at_frame, process.returncode, len(detected), len(shown), seconds)


def trials(video, tmp_path, count, frames, seed):
    """``count`` SIGINTs and ``count`` SIGTERMs, interleaved, at random frames in ``frames``."""
    rng = random.Random(seed)
    results = []
    for number in range(count):
        for signum in SIGNALS:
            folder = tmp_path / f"{signum.name}-{number}"
            folder.mkdir()
            results.append(signal_at_frame(video, folder, signum, rng.randrange(*frames)))
    return results


def table(results):
    lines = ["signal  | at frame | exit | detections | video frames | seconds",
             "--------|---------:|-----:|-----------:|-------------:|-------:"]
    lines += [f"{signal.Signals(t.signum).name:7} | {t.at_frame:8} | {t.returncode:4} | "
              f"{t.detections:10} | {t.video:12} | {t.seconds:6.1f}" for t in results]
    return "\n".join(lines)


@pytest.fixture(scope="module")
def quick_loop(tmp_path_factory, data_dir):
    """The 1000-frame loop, encoded fast (seconds) for the default profile."""
    return looped_video(data_dir / "test_video.mp4", LOOPED_FRAMES,
                        tmp_path_factory.mktemp("loop"), preset="ultrafast")


def test_signals_at_random_frames_leave_complete_outputs(quick_loop, tmp_path):
    results = trials(quick_loop, tmp_path, count=2, frames=(5, 120), seed=17)
    assert len(results) == 4


def test_a_killed_run_leaves_temporaries_the_next_run_removes(quick_loop, tmp_path):
    out, dets = tmp_path / "out.mp4", tmp_path / "dets.jsonl"
    command = [sys.executable, "-m", "fastdet.cli", "run", str(quick_loop), "--out",
               str(out), "--detections", str(dets), *OPTIONS]
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and lines_in(temporary_of(tmp_path, dets.name) or
                                                   tmp_path / "none") < 5:
        time.sleep(0.01)
    process.send_signal(signal.SIGKILL)
    process.wait()
    left = sorted(p.name for p in tmp_path.iterdir())
    # Hidden, never under (or with the suffix of) an output's name: no reader takes them.
    assert len(left) == 2 and all(is_temporary(tmp_path / name) for name in left), left
    assert not out.exists() and not dets.exists()
    subprocess.run([*command, "--end", "3"], cwd=ROOT, check=True, capture_output=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dets.jsonl", "out.mp4"]
    assert frames_of_video(out) == sorted(read_detections(dets)) == [0, 1, 2]


@pytest.mark.slow
def test_signal_stress_20_of_each_over_the_whole_loop(data_dir, tmp_path):
    """20 SIGINTs and 20 SIGTERMs at random frames of the benchmark's own 1000-frame input."""
    video = looped_video(data_dir / "test_video.mp4")
    seed = int(os.environ.get("FASTDET_SIGNAL_SEED", random.randrange(1 << 30)))
    results = trials(video, tmp_path, count=20, frames=(1, LOOPED_FRAMES - 10), seed=seed)
    print(f"\nseed {seed}\n{table(results)}")
    assert len(results) == 40


class SilentServer:
    """A TCP server on 127.0.0.1 that accepts connections and never answers them."""

    def __init__(self):
        self.listener = socket.socket()
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(4)
        self.port = self.listener.getsockname()[1]
        self.accepted = threading.Event()
        self.connections = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        with contextlib.suppress(OSError):
            while True:
                connection, _ = self.listener.accept()
                self.connections.append(connection)
                self.accepted.set()

    def close(self):
        for connection in self.connections:
            connection.close()
        self.listener.close()


@pytest.mark.parametrize("signum", list(SIGNALS), ids=lambda s: s.name)
def test_a_signal_while_a_stream_connects_ends_the_run_at_once(tmp_path, signum):
    """FFmpeg waits in C for the stream's first bytes (here up to 60 s); the signal must not."""
    server = SilentServer()
    try:
        command = [sys.executable, "-m", "fastdet.cli", "run",
                   f"http://127.0.0.1:{server.port}/clip.mp4", "--timeout", "60", "--quiet"]
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                   text=True, cwd=tmp_path, env=dict(os.environ,
                                                                     PYTHONPATH=str(ROOT)))
        try:
            assert server.accepted.wait(60), "fastdet run never connected"
            time.sleep(0.3)   # into FFmpeg's wait for the response
            sent = time.monotonic()
            process.send_signal(signum)
            stdout, stderr = process.communicate(timeout=30)
            waited = time.monotonic() - sent
        finally:
            if process.poll() is None:
                process.kill()
    finally:
        server.close()
    assert process.returncode == SIGNALS[signum], stderr
    assert (stdout, stderr) == ("", "fastdet: interrupted\n")
    assert waited < 10, f"the run took {waited:.1f} s to end after the signal"
    assert list(tmp_path.iterdir()) == []


def processes_naming(text):
    """PIDs of the processes whose command line holds ``text``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError):
                if text.encode() in (entry / "cmdline").read_bytes():
                    found.append(int(entry.name))
    return found


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="the compile helper needs a second core")
def test_a_signal_while_kernels_compile_stops_the_compile_helper(data_dir, tmp_path):
    """The kernels compile on a thread of this process and in a helper process; Ctrl-C
    ended the run at once but left the helper compiling for up to a family's compile
    (about 6 s) and its claims folder behind."""
    temporary, cache = tmp_path / "tmp", tmp_path / "cache"
    temporary.mkdir()
    env = dict(os.environ, PYTHONPATH=str(ROOT), TMPDIR=str(temporary),
               FASTDET_CACHE_DIR=str(cache))
    # Set by this process's fastdet (the suite's warm cache), it would win over the empty one.
    env.pop("NUMBA_CACHE_DIR", None)
    command = [sys.executable, "-m", "fastdet.cli", "run",
               str((data_dir / "test_video.mp4").resolve()), "--out", str(tmp_path / "out.mp4"),
               "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, cwd=tmp_path, env=env)
    try:
        deadline = time.monotonic() + 60
        claims = []
        while not claims and time.monotonic() < deadline and process.poll() is None:
            claims = [p for p in temporary.glob("fastdet-compile-*") if any(p.iterdir())]
            time.sleep(0.05)
        assert claims, "no compile helper was started"
        assert processes_naming(str(claims[0])), "the helper is not running"
        time.sleep(0.5)   # both processes compiling
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1] == "fastdet: interrupted"
    assert processes_naming(str(claims[0])) == []
    assert list(temporary.iterdir()) == []
    assert not (tmp_path / "out.mp4").exists()
