"""Batches on real Dask clusters on 127.0.0.1: faults, resumption, segments, the dask CLI.

Every cluster runs worker *processes* (as ``fastdet batch`` does) and every
wait is bounded.  The clips are the shared test video (38 frames), copies of
it, and the test video played forwards and backwards (``batch_stubs.looped_clip``).
"""

from __future__ import annotations

import filecmp
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from batch_stubs import looped_clip
from chromium import Browser, executable
from distributed import Client, LocalCluster
from video_files import top_level_boxes

import fastdet
from fastdet.batch import run_batch
from fastdet.cli.app import main
from fastdet.errors import InputError

#: Seconds any cluster, subprocess or batch in this module may take.
LIMIT = 240


@pytest.fixture(scope="module")
def client():
    """Two single-threaded worker processes on 127.0.0.1."""
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0", env={"NUMBA_NUM_THREADS": "1"}) as cluster, \
            Client(cluster) as dask:
        yield dask


@pytest.fixture(scope="module")
def clips(tmp_path_factory, data_dir):
    """footage/ with two copies of the test video and a corrupt file; a 300-frame loop."""
    root = tmp_path_factory.mktemp("clips")
    footage = root / "footage"
    (footage / "day1").mkdir(parents=True)
    shutil.copy(data_dir / "test_video.mp4", footage / "a.mp4")
    shutil.copy(data_dir / "test_video.mp4", footage / "day1" / "b.mp4")
    (footage / "day1" / "broken.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + os.urandom(4000))
    loop = looped_clip(data_dir / "test_video.mp4", root / "loop300.mp4", 300)
    return {"footage": footage, "loop": loop, "video": data_dir / "test_video.mp4"}


@pytest.fixture(scope="module")
def loop_whole(client, clips, tmp_path_factory):
    """The loop's detections from one task: what segmented and interrupted runs must equal."""
    out = tmp_path_factory.mktemp("loop-whole")
    [record] = fastdet.batch(clips["loop"], out, client, video=False)
    assert record["status"] == "done" and record["frames"] == 300
    return out / "loop300.jsonl"


def manifest_lines(out):
    return [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]


def test_a_folder_with_a_corrupt_file_then_a_rerun_then_force(client, clips, tmp_path):
    out = tmp_path / "out"
    run = run_batch(clips["footage"], out, client)
    by_name = {r["relative"]: r for r in run.records}
    assert list(by_name) == ["a.mp4", "day1/b.mp4", "day1/broken.mp4"]
    broken = by_name.pop("day1/broken.mp4")
    assert broken["status"] == "failed" and "as a video" in broken["reason"]
    assert "\n" not in broken["reason"]
    for name, rec in by_name.items():
        assert rec["status"] == "done" and rec["frames"] == 38 and rec["vehicles"] >= 1
        assert rec["outputs"] == {"video": name[:-4] + ".mp4", "detections": name[:-4] + ".jsonl",
                                  "thumbnail": name[:-4] + ".jpg"}
        assert all((out / path).is_file() for path in rec["outputs"].values())
    assert filecmp.cmp(out / "a.jsonl", out / "day1" / "b.jsonl", shallow=False)
    assert not list(out.rglob(".*.part*")) and not (out / ".fastdet-parts").exists()
    assert sorted(r["relative"] for r in manifest_lines(out)) == sorted(r["relative"]
                                                                       for r in run.records)
    page = (out / "index.html").read_text()
    assert all(f'data-relative="{name}"' in page for name in ("a.mp4", "day1/b.mp4",
                                                               "day1/broken.mp4"))

    # The same command again: everything done is skipped, the failure tried again.
    stamp = (out / "a.mp4").stat().st_mtime_ns
    again = run_batch(clips["footage"], out, client)
    assert again.skipped == {"a.mp4", "day1/b.mp4"}
    assert [r["status"] for r in again.records] == ["done", "done", "failed"]
    assert (out / "a.mp4").stat().st_mtime_ns == stamp
    # An input that changed is done again; --force redoes the rest.
    forced = run_batch(clips["footage"], out, client, force=True, video=True)
    assert forced.skipped == set() and (out / "a.mp4").stat().st_mtime_ns != stamp


def test_a_killed_worker_has_its_video_redone_elsewhere(client, clips, loop_whole, tmp_path):
    out = tmp_path / "out"
    done = {}
    batch = threading.Thread(target=lambda: done.update(
        records=fastdet.batch(clips["loop"], out, client, video=False)))
    batch.start()
    deadline = time.monotonic() + LIMIT
    victim = None
    while victim is None and time.monotonic() < deadline and batch.is_alive():
        busy = {worker: tasks for worker, tasks in client.processing().items() if tasks}
        # Kill only once the video is well under way (its detections file has grown).
        started = list(out.glob(".loop300.*.part.jsonl"))
        if busy and started and started[0].stat().st_size > 20_000:
            victim = next(iter(busy))
        time.sleep(0.05)
    assert victim is not None, "the video finished before its worker could be killed"
    pid = client.run(os.getpid, workers=[victim])[victim]
    os.kill(pid, signal.SIGKILL)
    batch.join(LIMIT)
    assert not batch.is_alive()
    [record] = done["records"]
    assert record["status"] == "done" and record["frames"] == 300
    assert filecmp.cmp(out / "loop300.jsonl", loop_whole, shallow=False)
    assert not list(out.glob(".loop300.*"))            # the killed attempt's file is gone
    client.wait_for_workers(2, timeout=LIMIT)          # the nanny restarted the worker


def test_a_segmented_long_video_equals_the_whole_video(client, clips, loop_whole, tmp_path):
    """Two segments, the second warmed up on 174 frames and its boundary checked."""
    [record] = fastdet.batch(clips["loop"], tmp_path, client, video=False, segment="150")
    assert record["status"] == "done" and record["segments"] == 2 and record["frames"] == 300
    assert filecmp.cmp(tmp_path / "loop300.jsonl", loop_whole, shallow=False)
    assert not (tmp_path / ".fastdet-parts").exists()


def test_segments_are_encoded_with_the_codec_asked_for_and_joined_index_first(client, clips,
                                                                             tmp_path):
    """--codec reaches every segment's encoder; the joined MP4 has its index first."""
    import av

    [record] = fastdet.batch(clips["loop"], tmp_path, client, segment="150", codec="mp4v",
                             crf=3)
    assert record["status"] == "done" and record["segments"] == 2
    joined = tmp_path / "loop300.mp4"
    with av.open(str(joined)) as video:
        assert video.streams.video[0].codec_context.name == "mpeg4"
        assert sum(1 for _ in video.decode(video=0)) == 300
    boxes = top_level_boxes(joined)
    assert boxes.index("moov") < boxes.index("mdat")


def test_a_real_batch_page_plays_every_video_in_chromium(client, clips, tmp_path):
    """End to end: the page of a batch plays its own outputs inline, a whole video and a
    segmented one whose parts were joined."""
    assert executable(), "Chromium is missing: apt-get install chromium (.ci/run does)"
    records = fastdet.batch([clips["video"], clips["loop"]], tmp_path, client, segment="150")
    assert [(r["status"], r["segments"]) for r in records] == [("done", 1), ("done", 2)]
    with Browser() as browser:
        browser.open((tmp_path / "index.html").as_uri())
        assert browser.evaluate("document.querySelectorAll('video').length") == 2
        for k in range(2):
            video = f"document.querySelectorAll('video')[{k}]"
            browser.evaluate(f"{video}.scrollIntoView()")
            assert browser.wait_for(f"{video}.currentTime > 0.2"), f"video {k} does not play"
            assert browser.evaluate(f"{video}.error === null")


@pytest.mark.slow
def test_a_segmented_1000_frame_h264_video_equals_the_whole_video(client, clips, tmp_path):
    """The issue's clip: the test video forwards and backwards to 1000 frames, H.264 with
    B-frames; two and four segments, each boundary checked, the merge byte-identical."""
    import av

    loop = looped_clip(clips["video"], tmp_path / "loop1000.mp4", 1000, codec="h264")
    [whole] = fastdet.batch(loop, tmp_path / "whole", client, video=False)
    assert whole["frames"] == 1000
    for segment, count in (("500", 2), ("250", 4)):
        out = tmp_path / f"segments-{segment}"
        [record] = fastdet.batch(loop, out, client, segment=segment)
        assert record["status"] == "done" and record["segments"] == count
        assert filecmp.cmp(out / "loop1000.jsonl", tmp_path / "whole" / "loop1000.jsonl",
                           shallow=False)
        with av.open(str(out / "loop1000.mp4")) as video:
            assert sum(1 for _ in video.decode(video=0)) == 1000


def test_short_warmups_are_redone_until_exact(client, clips, tmp_path):
    """Warm-ups of 3 frames fail their checks; the segments are redone with longer ones (and
    from frame 0 at the end), and the annotated video is drawn and joined."""
    whole = tmp_path / "whole"
    fastdet.batch(clips["video"], whole, client, video=False)
    [record] = fastdet.batch(clips["video"], tmp_path / "seg", client, segment="10", warmup=3)
    assert record["status"] == "done" and record["segments"] == 4 and record["redone"] >= 1
    assert filecmp.cmp(tmp_path / "seg" / "test_video.jsonl", whole / "test_video.jsonl",
                       shallow=False)
    import av

    with av.open(str(tmp_path / "seg" / "test_video.mp4")) as video:
        assert sum(1 for _ in video.decode(video=0)) == 38
    assert (tmp_path / "seg" / "test_video.jpg").is_file()


def test_the_cli_on_its_own_local_cluster(clips, tmp_path, capsys):
    code = main(["batch", str(clips["footage"] / "a.mp4"), str(clips["footage"] / "day1"),
                 "--out-dir", str(tmp_path), "--workers", "2", "--no-video", "--format", "csv",
                 "--quiet"])
    printed = capsys.readouterr().out
    assert code == 1                                  # broken.mp4 failed
    assert "failed: broken.mp4: cannot read" in printed
    assert "3 videos: 2 done, 0 already done, 1 failed" in printed
    assert (tmp_path / "a.csv").is_file() and (tmp_path / "b.csv").is_file()


@pytest.fixture
def dask_cli_cluster(tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1, stopped afterwards."""
    dask = str(Path(sys.executable).with_name("dask"))
    scheduler_file = tmp_path / "scheduler.json"
    common = ["--no-dashboard"]
    processes = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0",
                                   "--scheduler-file", str(scheduler_file), *common],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + LIMIT
        while not scheduler_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        for _ in range(2):
            processes.append(subprocess.Popen(
                [dask, "worker", "--scheduler-file", str(scheduler_file), "--host", "127.0.0.1",
                 "--nworkers", "1", "--nthreads", "1", *common],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                env={**os.environ, "NUMBA_NUM_THREADS": "1"}))
        with Client(scheduler_file=str(scheduler_file), timeout=60) as dask_client:
            dask_client.wait_for_workers(2, timeout=LIMIT)
            address = dask_client.scheduler.address
        yield scheduler_file, address
    finally:
        for process in reversed(processes):
            process.terminate()
        for process in processes:
            try:
                process.wait(30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def test_a_cluster_started_with_the_dask_cli(clips, dask_cli_cluster, tmp_path, capsys):
    scheduler_file, address = dask_cli_cluster
    assert address.startswith("tcp://127.0.0.1:")
    code = main(["batch", str(clips["footage"] / "a.mp4"), str(clips["video"]),
                 "--out-dir", str(tmp_path / "by-file"), "--scheduler-file", str(scheduler_file),
                 "--quiet"])
    assert code == 0, capsys.readouterr()
    code = main(["batch", str(clips["footage"] / "a.mp4"), "--out-dir", str(tmp_path / "by-file"),
                 "--scheduler", address, "--quiet", "--no-video"])
    printed = capsys.readouterr().out
    assert code == 0 and "1 videos: 1 done" in printed          # other outputs: redone
    records = manifest_lines(tmp_path / "by-file")
    assert {r["relative"]: r["status"] for r in records} == {"a.mp4": "done",
                                                               "test_video.mp4": "done"}
    assert filecmp.cmp(tmp_path / "by-file" / "a.jsonl", tmp_path / "by-file" / "test_video.jsonl",
                       shallow=False)


def _as_from_a_terminal():
    # Signal masks and ignored signals are inherited: whatever this test process has blocked
    # or ignored on the way (its own worker threads, other tests), a shell's child has not.
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_leaves_a_manifest_the_next_run_continues(clips, tmp_path):
    footage = tmp_path / "footage"
    footage.mkdir()
    for k in range(4):
        shutil.copy(clips["video"], footage / f"clip{k}.mp4")
    out = tmp_path / "out"
    command = [str(Path(sys.executable).with_name("fastdet")), "batch", str(footage),
               "--out-dir", str(out), "--workers", "1", "--quiet"]
    process = subprocess.Popen(command, start_new_session=True, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, preexec_fn=_as_from_a_terminal)
    deadline = time.monotonic() + LIMIT
    while time.monotonic() < deadline and process.poll() is None:
        if (out / "manifest.jsonl").is_file() and manifest_lines(out):
            break
        time.sleep(0.05)
    assert process.poll() is None, "the batch ended before it could be interrupted"
    os.killpg(process.pid, signal.SIGINT)     # what a terminal's Ctrl-C does
    _, err = process.communicate(timeout=LIMIT)
    assert process.returncode == 130, err.decode()[-2000:]
    assert b"fastdet: interrupted" in err
    records = manifest_lines(out)
    finished = {r["relative"] for r in records if r["status"] == "done"}
    assert 1 <= len(finished) < 4, records
    assert b"Traceback" not in err, err.decode()[-2000:]
    for k in range(4):
        # A task running at the interrupt may finish its (complete) outputs unrecorded;
        # nothing is ever half-written under a final name.
        detections = out / f"clip{k}.jsonl"
        if f"clip{k}.mp4" not in finished and detections.exists():
            assert len(detections.read_text().splitlines()) == 38
    rerun = subprocess.run(command, capture_output=True, timeout=LIMIT)
    assert rerun.returncode == 0, rerun.stderr.decode()[-2000:]
    assert f"4 videos: {4 - len(finished)} done, {len(finished)} already done, 0 failed" \
        in rerun.stdout.decode()


def test_importing_fastdet_does_not_import_dask():
    code = ("import sys, fastdet; assert 'dask' not in sys.modules and 'distributed' not in "
            "sys.modules; batch = fastdet.batch; assert 'distributed' in sys.modules; "
            "assert callable(batch) and fastdet.batch is batch")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=LIMIT)


def test_the_local_layout_fills_the_cores_within_memory():
    from fastdet.batch.cluster import WORKER_MEMORY, plan_layout

    plenty = 64 * WORKER_MEMORY
    assert plan_layout(cores=8, memory=plenty) == 8
    assert plan_layout(cores=8, threads=2, memory=plenty) == 4
    assert plan_layout(cores=8, threads=3, memory=plenty) == 2
    assert plan_layout(cores=8, memory=3 * WORKER_MEMORY) == 3
    assert plan_layout(cores=1, threads=4, memory=WORKER_MEMORY // 2) == 1


class _Workers:
    """A client whose workers answer the checks with ``reports``."""

    def __init__(self, reports):
        self.reports = reports

    def run(self, function, *args):
        return self.reports


def test_fewer_videos_than_cores_share_the_cores():
    from fastdet.batch.cluster import WORKER_MEMORY, local_layout

    plenty = 64 * WORKER_MEMORY
    assert local_layout(1, cores=2, memory=plenty) == (1, 2)
    assert local_layout(3, cores=8, memory=plenty) == (3, 2)
    assert local_layout(2, cores=2, memory=plenty) == (2, 1)
    assert local_layout(9, cores=8, memory=plenty) == (8, 1)
    assert local_layout(1, segmenting=True, cores=2, memory=plenty) == (2, 1)
    assert local_layout(1, threads=1, cores=4, memory=plenty) == (4, 1)   # as asked
    assert local_layout(5, workers=2, cores=4, memory=plenty) == (2, 2)
    assert local_layout(1, cores=8, memory=WORKER_MEMORY) == (1, 8)
    with pytest.raises(InputError, match="--workers must be at least 1"):
        local_layout(1, workers=0)
    # As many workers as the memory holds, not one more (--workers 1000 hung after a traceback).
    assert local_layout(1, workers=4, threads=1, cores=2, memory=4 * WORKER_MEMORY) == (4, 1)
    with pytest.raises(InputError, match=r"--workers 5: .* more than this machine's .*at most 4"):
        local_layout(1, workers=5, cores=2, memory=4 * WORKER_MEMORY)


def test_one_video_alone_on_the_local_cluster_uses_every_core(client, clips, tmp_path):
    """The cluster fastdet starts gives a lone video all the cores; its detections are those
    of a one-thread task."""
    from fastdet.batch.cluster import usable_cores

    run = run_batch(clips["video"], tmp_path / "alone", video=False)
    assert run.workers == 1 and run.settings.threads == usable_cores()
    assert [r["status"] for r in run.records] == ["done"]
    [one] = fastdet.batch(clips["video"], tmp_path / "one-thread", client, video=False)
    assert one["status"] == "done"
    assert filecmp.cmp(tmp_path / "alone" / "test_video.jsonl",
                       tmp_path / "one-thread" / "test_video.jsonl", shallow=False)


def test_workers_that_cannot_run_the_batch_are_named(tmp_path):
    from fastdet.batch.cluster import check_workers

    good = {"version": fastdet.__version__, "sees_out_dir": True}
    check_workers(_Workers({"tcp://10.0.0.1:1": good}), tmp_path)
    with pytest.raises(InputError, match="worker tcp://10.0.0.2:1 runs fastdet 0.0.1"):
        check_workers(_Workers({"tcp://10.0.0.1:1": good,
                                "tcp://10.0.0.2:1": dict(good, version="0.0.1")}), tmp_path)
    with pytest.raises(InputError, match="does not see .* on a filesystem they share"):
        check_workers(_Workers({"tcp://10.0.0.3:1": dict(good, sees_out_dir=False)}), tmp_path)
    assert list(tmp_path.iterdir()) == []          # the probe file is removed


def test_the_probe_of_a_worker_reads_the_shared_folder(tmp_path):
    from fastdet.batch.worker import worker_report

    (tmp_path / "probe").write_text("x")
    assert worker_report(str(tmp_path), "probe") == {"version": fastdet.__version__,
                                                     "sees_out_dir": True}
    assert not worker_report(str(tmp_path), "missing")["sees_out_dir"]
