"""The bad-input matrix's rows of ``batch`` (see ``test_matrix.py`` for the promises).

Refusals (exit 2) come before any cluster starts.  A bad video among good
ones is not a refusal: ``batch`` isolates it, finishes the others and exits
1; its manifest record says ``failed`` and why, and no output of it exists.
``batch`` is strict about damage: a video cut short or with undecodable data
is ``failed`` (``fastdet run`` processes such a file as far as it decodes).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from pathlib import Path

import dask
from matrix_checks import Row, full_disk, read_only_out

EXIT_SOME_FAILED = 1
#: What a batch prints on stdout and stderr (its table and summary): anything but an error.
BATCH_LINES = r"^(?!fastdet: error)"


def batch(*args):
    # One worker of one thread: rows stay quick and the machine's cores free.
    return ["batch", *map(str, args), "--workers", "1", "--quiet"]


def records(out_dir):
    """The manifest's records by the video's relative path."""
    lines = (Path(out_dir) / "manifest.jsonl").read_text().splitlines()
    return {record["relative"]: record for record in map(json.loads, lines)}


#: The videos of ``VideoInputs`` and what batch records for each.
FOLDER_OUTCOMES = {
    "clip.mp4": ("done", None),
    "link.mp4": ("done", None),
    "real.mp4": ("done", None),
    "empty.mp4": ("failed", "as a video"),
    "random.mp4": ("failed", "as a video"),
    "garbled.mp4": ("failed", "damaged"),
    "truncated.mp4": ("failed", "after frame 3"),   # how FFmpeg words it depends on threads
    "sizes.ts": ("failed", "frame size changes"),
    "audio.mp4": ("failed", "no video stream"),
    "zero.avi": ("failed", "holds no frames"),
}


def folder_outcomes(i, o, stdout):
    """Every video recorded as promised; outputs of the done ones only."""
    found = records(o / "b")
    assert set(found) == set(FOLDER_OUTCOMES), sorted(found)
    for name, (status, reason) in FOLDER_OUTCOMES.items():
        record = found[name]
        assert record["status"] == status, record
        stem = Path(name).stem
        outputs = sorted(p.name for p in (o / "b").glob(f"{stem}.*"))
        if status == "done":   # and the report's thumbnail
            assert outputs == [f"{stem}.jpg", f"{stem}.jsonl", f"{stem}.mp4"], outputs
        else:
            assert reason in record["reason"] and outputs == [], (record, outputs)
    return True


@contextlib.contextmanager
def full_disk_kept(o):
    """:func:`full_disk`, its files copied to ``o/kept`` before it is unmounted."""
    with full_disk(o, 4000) as disk:
        yield disk
        shutil.copytree(disk, o / "kept")


def full_disk_outcome(i, o, stdout):
    record = records(o / "kept")["real.mp4"]
    assert record["status"] == "failed" and "No space left" in record["reason"], record
    assert sorted(p.name for p in (o / "kept").iterdir() if not p.name.startswith(".")) == \
        ["index.html", "manifest.jsonl", "previous"]
    return True


@contextlib.contextmanager
def quick_connect_timeout():
    """Give up on a scheduler that does not answer after 2 s (Dask's default: 30 s)."""
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        yield


BATCH_ROWS = [
    Row("batch", "input missing", lambda i, o: batch(i.video / "missing.mp4", "--out-dir", o),
        names=lambda i, o: i.video / "missing.mp4", problem="not found"),
    Row("batch", "a folder without videos",
        lambda i, o: batch(i / "empty_data", "--out-dir", o / "b"),
        names=lambda i, o: i / "empty_data", problem="no videos found"),
    Row("batch", "input a FIFO named like a video",
        lambda i, o: batch(o / "pipe.mp4", "--out-dir", o / "b"),
        names=lambda i, o: o / "pipe.mp4", problem="not a regular file",
        setup=lambda i, o: contextlib.nullcontext(os.mkfifo(o / "pipe.mp4"))),
    Row("batch", "--out-dir is a file",
        lambda i, o: batch(i.video.clip, "--out-dir", i / "grey.png"),
        names=lambda i, o: i / "grey.png", problem="not a folder",
        guarded=lambda i, o: [i / "grey.png"]),
    Row("batch", "--out-dir read-only", lambda i, o: batch(i.video.clip, "--out-dir", o),
        names=lambda i, o: o, problem="Read-only file system|Permission denied",
        setup=lambda i, o: read_only_out(o)),
    Row("batch", "model random bytes",
        lambda i, o: batch(i.video.clip, "--out-dir", o / "b", "--model", i / "random.npz"),
        names=lambda i, o: i / "random.npz", problem="not a readable"),
    Row("batch", "model tampered with",
        lambda i, o: batch(i.video.clip, "--out-dir", o / "b", "--model", i / "tampered.npz"),
        names=lambda i, o: i / "tampered.npz", problem="checksum"),
    Row("batch", "config with an unknown key",
        lambda i, o: batch(i.video.clip, "--out-dir", o / "b", "--config", i / "unknown.toml"),
        names=lambda i, o: i / "unknown.toml", problem="unknown key"),
    Row("batch", "--preset x264 does not have",
        lambda i, o: batch(i.video.clip, "--out-dir", o / "b", "--preset", "warp-speed"),
        names=lambda i, o: "warp-speed", problem="h264 has no preset"),
    Row("batch", "--preset the encoder refuses",
        lambda i, o: batch(i.video.clip, "--out-dir", o / "b", "--codec", "vp9", "--preset", "99"),
        names=lambda i, o: "99", problem="the vp9 encoder refuses"),
    Row("batch", "--crf outside the encoder's range",
        lambda i, o: batch(i.video.clip, "--out-dir", o / "b", "--codec", "mp4v", "--crf", "40"),
        names=lambda i, o: "40", problem="must be 2-31"),
    Row("batch", "--scheduler that does not answer",
        lambda i, o: batch(i.video.clip, "--out-dir", o / "b", "--scheduler",
                           "tcp://127.0.0.1:9"),
        names=lambda i, o: "tcp://127.0.0.1:9", problem="cannot reach the Dask scheduler",
        setup=lambda i, o: quick_connect_timeout()),
    Row("batch", "a folder of good and bad videos (bad ones failed, the others done)",
        lambda i, o: batch(i.video.dir, "--out-dir", o / "b"), code=EXIT_SOME_FAILED,
        messages=BATCH_LINES, check=folder_outcomes),
    Row("batch", "--out-dir on a full disk (the video failed, recorded)",
        lambda i, o: batch(i.video.real, "--out-dir", o / "disk"), code=EXIT_SOME_FAILED,
        messages=BATCH_LINES, guarded=lambda i, o: [o / "disk" / "previous"],
        setup=lambda i, o: full_disk_kept(o), check=full_disk_outcome),
]
