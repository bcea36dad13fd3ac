"""``fastdet bench``'s pipeline processes: the 1-thread pass in separate processes at once."""

from __future__ import annotations

import sys
import textwrap
import time

import numpy as np
import pytest

import fastdet.bench.pipeline_processes as pipeline_processes
from fastdet.bench.frame_level import (PipelinePoint, _points, format_frame_level,
                                       frame_level_study, looped)
from fastdet.bench.pipeline_processes import PipelineProcesses, WorkerError, copies_ratio


def stand_in(tmp_path, body):
    """A worker command whose script is ``body`` (it gets the worker's arguments)."""
    script = tmp_path / "stand_in_worker.py"
    script.write_text(textwrap.dedent(body))
    return [sys.executable, str(script)]


#: Says ready, then answers each pass with the frames' count and the first
#: frame's first byte as its wall and CPU seconds, and says what it was given.
ECHO = """
    import sys
    import numpy as np
    frames, order = np.load(sys.argv[1]), np.load(sys.argv[2])
    print("ready", flush=True)
    for line in sys.stdin:
        if line.strip() == "quit":
            break
        print(len(order), float(frames[order[0]][0, 0, 0]), flush=True)
        print("args", *sys.argv[3:], file=sys.stderr, flush=True)
"""


def test_the_workers_get_each_frame_once_and_the_order_to_play_them(tmp_path):
    a = np.full((4, 6, 3), 7, np.uint8)
    b = np.full((4, 6, 3), 9, np.uint8)
    frames = looped([a, b], 5)          # a b b a a b: two frames, six in the pass
    with PipelineProcesses(frames, 2, command=stand_in(tmp_path, ECHO)) as workers:
        folder = workers._folder
        np.testing.assert_array_equal(np.load(folder / "frames.npy"), np.stack([a, b]))
        assert np.load(folder / "order.npy").tolist() == [0, 1, 1, 0, 0, 1]
        assert workers.passes(1) == [(6.0, 7.0)]
        assert workers.passes(2) == [(6.0, 7.0), (6.0, 7.0)]
        processes = [worker.process for worker in workers._workers]
    assert not folder.exists()
    assert [process.poll() for process in processes] == [0, 0]     # told to quit, they did


def test_the_workers_get_the_model_and_config_files(tmp_path):
    with PipelineProcesses([np.zeros((4, 6, 3), np.uint8)], 1, "m.npz", "c.toml",
                           command=stand_in(tmp_path, ECHO)) as workers:
        workers.passes(1)
        worker = workers._workers[0]
        deadline = time.monotonic() + 10
        while not any(line.startswith("args") for line in worker.errors):
            assert time.monotonic() < deadline, "the stand-in never said its arguments"
            time.sleep(0.01)
        assert "args --model m.npz --config c.toml" in worker.errors


def test_a_worker_that_fails_to_start_is_one_clear_error(tmp_path):
    command = stand_in(tmp_path, """
        import sys
        print("cannot read the frames", file=sys.stderr, flush=True)
        sys.exit(1)
    """)
    processes = PipelineProcesses([np.zeros((4, 6, 3), np.uint8)], 2, command=command)
    with pytest.raises(WorkerError, match="stopped: cannot read the frames"):
        with processes:
            pass
    assert processes._folder is None and processes._workers == []


def test_a_worker_that_never_answers_is_stopped_in_bounded_time(tmp_path, monkeypatch):
    monkeypatch.setattr(pipeline_processes, "PASS_TIMEOUT", 0.5)
    monkeypatch.setattr(pipeline_processes, "EXIT_TIMEOUT", 1.0)
    command = stand_in(tmp_path, """
        import sys, time
        print("ready", flush=True)
        for line in sys.stdin:
            if line.strip() == "quit":
                break
            time.sleep(60)
    """)
    started = time.monotonic()
    with pytest.raises(WorkerError, match="gave no answer within 0.5 s"):
        with PipelineProcesses([np.zeros((4, 6, 3), np.uint8)], 1, command=command) as workers:
            process = workers._workers[0].process
            workers.passes(1)
    # Told to quit while asleep, it is killed after EXIT_TIMEOUT.
    assert process.poll() == -9
    assert time.monotonic() - started < 20


def test_an_answer_that_is_not_seconds_is_an_error(tmp_path):
    command = stand_in(tmp_path, """
        import sys
        print("ready", flush=True)
        for line in sys.stdin:
            if line.strip() == "quit":
                break
            print("busy", flush=True)
    """)
    with PipelineProcesses([np.zeros((4, 6, 3), np.uint8)], 1, command=command) as workers:
        with pytest.raises(WorkerError, match="answered 'busy' instead of its pass's seconds"):
            workers.passes(1)
        with pytest.raises(ValueError, match="copies must be 1 to 1, got 2"):
            workers.passes(2)


def test_copies_ratio_is_the_work_per_second_against_one_alone():
    assert copies_ratio(1.0, [1.0, 1.0]) == 2.0         # two full cores
    assert copies_ratio(1.0, [2.0, 1.5]) == 1.0         # one core shared: the last one counts
    assert copies_ratio(1.0, [1.25, 1.0]) == 1.6
    assert copies_ratio(2.0, [2.0]) == 1.0


def test_the_real_worker_times_the_one_thread_pass(small_frames):
    frames = looped(small_frames, 4)
    with PipelineProcesses(frames, 2) as workers:
        (alone,) = workers.passes(1)
        together = workers.passes(2)
    assert len(together) == 2
    # A pass of four 640x360 frames: milliseconds, not seconds or microseconds.
    for wall, cpu in [alone, *together]:
        assert 1e-4 < wall < 10 and 0 < cpu < 10


def test_the_processes_row_and_the_share_of_frames_at_once():
    settings = [(1, 1), (2, 1), (2, 2)]
    # ms a frame per round: one thread, two sharing each frame, two frames at once.
    wall = {(1, 1): [2.0, 4.0, 2.0], (2, 1): [1.5, 3.0, 1.5], (2, 2): [1.25, 2.0, 1.0]}
    cpu = {key: [1.0] * 3 for key in settings}
    switches = {key: [] for key in settings}
    # Per round: one process alone, then both at once (ms a frame of each).
    together = [([2.0], [2.0, 2.5], [1.0, 3.0]),      # 1.6x, frames at once 1.6x: 100 %
                ([2.0], [2.0, 2.0], [1.0, 1.0]),      # 2.0x, frames at once 2.0x: 100 %
                ([2.0], [2.0, 2.0], [1.0, 1.0])]      # 2.0x, frames at once 2.0x: 100 %
    points = _points(settings, wall, cpu, switches, together)
    assert [(p.threads, p.frames_at_once, p.processes) for p in points] == [
        (1, 1, 0), (2, 1, 0), (2, 2, 0), (2, 2, 2)]
    processes = points[3]
    assert processes.ms_per_frame == 1.0                 # median of 1.25, 1.0, 1.0
    assert processes.cpu_ms_per_frame == 1.0             # median of 2.0, 1.0, 1.0
    assert processes.paired_speedup == 2.0               # median of 1.6, 2.0, 2.0
    assert points[2].share_of_processes == 1.0
    assert points[0].share_of_processes is None and points[1].share_of_processes is None
    # The third round's frames at once only 1.0 / 2.0 = 0.5 of the processes: median 1.0.
    wall[(2, 2)][2] = 2.0
    assert _points(settings, wall, cpu, switches, together)[2].share_of_processes == 1.0
    wall[(2, 2)][1] = 4.0
    assert _points(settings, wall, cpu, switches, together)[2].share_of_processes == 0.5
    table = format_frame_level(points).splitlines()
    assert table[5] == ("| 2 processes of 1 thread at once (no GIL shared) | 1.00 | 1.00 | 2.00x "
                        "| 2.00x | - |")
    assert table[-1] == ("2 frames at once in one process reached 100 % of the processes' "
                         "speed-up (median over rounds of the two speed-ups' ratio in the same "
                         "round).")
    assert "gives 2 copies of the 1-thread pass when no GIL is shared" in table[-2]


def test_a_table_without_processes_has_no_processes_lines():
    table = format_frame_level([PipelinePoint(1, 1, 2.0, 2.0, 1.0, None)])
    assert "processes" not in table


def test_the_study_goes_on_without_processes_that_fail(small_frames):
    notes = []

    class Failing:
        def __init__(self, frames, count):
            assert count == 2 and len(frames) == 6

        def __enter__(self):
            raise WorkerError("a pipeline worker process stopped: out of memory")

        def __exit__(self, *exc):
            return False

    points = frame_level_study(small_frames, threads=(1, 2), rounds=1, log=notes.append,
                               min_frames=6, processes=Failing)
    assert [(p.threads, p.frames_at_once, p.processes) for p in points] == [
        (1, 1, 0), (2, 1, 0), (2, 2, 0)]
    assert ("note: the pipeline processes were left out: a pipeline worker process stopped: "
            "out of memory") in notes


def test_the_study_times_the_processes_in_its_rounds(small_frames):
    calls = []

    class Recorded:
        def __init__(self, frames, count):
            self.count = count

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def passes(self, copies):
            calls.append(copies)
            return [(0.006, 0.006)] * copies

    points = frame_level_study(small_frames, threads=(1, 2), rounds=2, log=lambda *a: None,
                               min_frames=6, processes=Recorded)
    assert calls == [1, 2, 1, 2]                # one alone, then two, in each kept round
    assert points[3].processes == 2 and points[3].paired_speedup == 2.0
    assert points[3].ms_per_frame == pytest.approx(0.5)     # 6 ms for 6 frames, two at once
    assert points[2].share_of_processes > 0
