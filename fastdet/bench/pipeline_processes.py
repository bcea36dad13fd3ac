"""The 1-thread video pipeline in separate processes at once: what the machine gives n copies.

Two frames scored at once in one process (:mod:`fastdet.video.ahead`) can
fall short of 2x for two reasons: fastdet's own (the GIL its threads take
back after each kernel call, the frames' temporal steps in frame order) or the
machine's (two vCPUs sharing a core's units, its caches and memory, or a host
that takes cycles).  The cell kernel's ceiling (:mod:`.two_cores`) measures
the machine for one in-cache kernel only; a whole pipeline pass also streams
frames and scale images through shared caches and memory.  Here the same
pass as the benchmark's 1-thread row runs in ``n`` worker processes, which
share no GIL: ``n`` passes at once against one alone is what this machine
gives that job, and frames at once in one process are judged against it.

Each worker (``python -m fastdet.bench.pipeline_processes FRAMES.npy
ORDER.npy``: each frame once, and the order to play them in) loads the
frames, runs one pass to load its kernels and fill its buffers,
says ``ready`` and then runs one pass per ``pass`` line it reads, answering
with that pass's wall and CPU seconds.  The caller starts all workers' passes
together, so a round of the benchmark can time them beside its in-process
passes (the same spell of a shared machine for both).
"""

from __future__ import annotations

import argparse
import collections
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

#: Seconds a worker may take to load its frames and kernels and run its first pass.
READY_TIMEOUT = 120.0
#: Seconds a worker may take for one timed pass (a pass of the benchmark lasts 0.3-3 s).
PASS_TIMEOUT = 60.0
#: Seconds a worker is given to exit once told to, before it is killed.
EXIT_TIMEOUT = 10.0


class WorkerError(RuntimeError):
    """A worker process that did not start, answer in time, or answer as expected."""


class _Worker:
    """One worker process and the lines it writes, read by a thread of its own."""

    def __init__(self, command, env):
        self.process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, env=env, text=True, bufsize=1)
        self.lines = queue.Queue()
        # Its last lines of stderr, for the error message (a chatty worker cannot fill memory).
        self.errors = collections.deque(maxlen=100)
        threading.Thread(target=self._read, args=(self.process.stdout, self.lines.put),
                         daemon=True).start()
        threading.Thread(target=self._read, args=(self.process.stderr, self.errors.append),
                         daemon=True).start()

    @staticmethod
    def _read(stream, put):
        for line in stream:
            put(line.rstrip("\n"))
        put(None)

    def send(self, line):
        try:
            self.process.stdin.write(line + "\n")
            self.process.stdin.flush()
        except (BrokenPipeError, OSError, ValueError):
            raise WorkerError(self._why("stopped")) from None

    def receive(self, timeout):
        try:
            line = self.lines.get(timeout=timeout)
        except queue.Empty:
            raise WorkerError(self._why(f"gave no answer within {timeout:g} s")) from None
        if line is None:
            raise WorkerError(self._why("stopped"))
        return line

    def _why(self, what):
        last = next((line for line in reversed(self.errors) if line and line.strip()), None)
        return f"a pipeline worker process {what}" + (f": {last.strip()}" if last else "")

    def close(self):
        if self.process.poll() is None:
            try:
                self.send("quit")
                self.process.wait(timeout=EXIT_TIMEOUT)
            except (WorkerError, subprocess.TimeoutExpired):
                self.process.kill()
                self.process.wait()
        for stream in (self.process.stdin, self.process.stdout, self.process.stderr):
            try:
                stream.close()
            except OSError:
                pass


class PipelineProcesses:
    """``count`` worker processes, each ready to time the 1-thread pipeline's pass.

    Use as a context manager: the workers start on entry (each loads the frames
    and runs a first, untimed pass) and are stopped on exit.

    Parameters
    ----------
    frames : list of ndarray
        The pass's BGR frames in order, all of one size (already looped, see
        :func:`fastdet.bench.frame_level.looped`: each worker plays them as they are).
    count : int
        Worker processes (2 for a 2-core comparison).
    model_path, config_path : str or Path, optional
        The model and config file the benchmark loaded (``None``: the bundled
        model, the built-in defaults).
    command : list of str, optional
        The worker command line before its arguments (default: this
        interpreter running this module); tests substitute a stand-in.
    """

    def __init__(self, frames, count=2, model_path=None, config_path=None, command=None):
        if count < 1:
            raise ValueError(f"count must be at least 1, got {count}")
        self.frames, self.count = frames, count
        self.model_path, self.config_path = model_path, config_path
        self.command = command or [sys.executable, "-m", __name__]
        self._workers, self._folder = [], None

    def __enter__(self):
        self._folder = Path(tempfile.mkdtemp(prefix="fastdet-pipeline-processes-"))
        try:
            # Each frame once, and the order to play them in: a looped pass
            # repeats each frame about eight times.
            index_of, unique, order = {}, [], []
            for frame in self.frames:
                if id(frame) not in index_of:
                    index_of[id(frame)] = len(unique)
                    unique.append(frame)
                order.append(index_of[id(frame)])
            np.save(self._folder / "frames.npy", np.stack(unique))
            np.save(self._folder / "order.npy", np.asarray(order, np.int64))
            arguments = [str(self._folder / "frames.npy"), str(self._folder / "order.npy")]
            if self.model_path is not None:
                arguments += ["--model", str(self.model_path)]
            if self.config_path is not None:
                arguments += ["--config", str(self.config_path)]
            # One Numba thread each: a worker is the 1-thread pipeline.
            env = dict(os.environ, NUMBA_NUM_THREADS="1")
            self._workers = [_Worker(self.command + arguments, env) for _ in range(self.count)]
            for worker in self._workers:
                if worker.receive(READY_TIMEOUT) != "ready":
                    raise WorkerError("a pipeline worker process said something other than "
                                      "'ready' after starting")
        except BaseException:
            self.__exit__(*sys.exc_info())
            raise
        return self

    def __exit__(self, *exc):
        for worker in self._workers:
            worker.close()
        self._workers = []
        if self._folder is not None:
            shutil.rmtree(self._folder, ignore_errors=True)
            self._folder = None
        return False

    def passes(self, copies):
        """Wall and CPU seconds of one pass in each of the first ``copies`` workers,
        started together: a list of ``(wall, cpu)``."""
        if not 1 <= copies <= len(self._workers):
            raise ValueError(f"copies must be 1 to {len(self._workers)}, got {copies}")
        workers = self._workers[:copies]
        for worker in workers:
            worker.send("pass")
        answers = []
        for worker in workers:
            answer = worker.receive(PASS_TIMEOUT)
            try:
                wall, cpu = (float(field) for field in answer.split())
            except ValueError:
                raise WorkerError(f"a pipeline worker process answered {answer!r} instead of "
                                  "its pass's seconds") from None
            answers.append((wall, cpu))
        return answers


def timed_pass(pipeline, frames, workers=1):
    """Wall and CPU seconds of one pass of ``pipeline`` over ``frames``, from a reset
    (the CPU time is the whole process's: every thread of a pass counts)."""
    pipeline.reset()
    started, cpu_started = time.perf_counter(), time.process_time()
    for _ in pipeline(frames, workers=workers):
        pass
    return time.perf_counter() - started, time.process_time() - cpu_started


def copies_ratio(alone, together):
    """Work per second of ``len(together)`` passes at once over one pass alone.

    ``alone``: the wall seconds of one pass alone; ``together``: each worker's
    wall seconds of its pass at once, which ended when the last one did.
    ``n`` is n full cores' worth, 1 one core shared.
    """
    return len(together) * alone / max(together)


# -- the worker --------------------------------------------------------------
def _worker_main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m fastdet.bench.pipeline_processes",
                                     description="Time the 1-thread video pipeline's pass, "
                                     "once per 'pass' line read.")
    parser.add_argument("frames")
    parser.add_argument("order")
    parser.add_argument("--model")
    parser.add_argument("--config")
    args = parser.parse_args(argv)

    from ..detector.config import load_config
    from ..detector.detector import Detector
    from ..detector.model import load_model
    from ..video.config import TrackConfig
    from ..video.memory import reuse_freed_frames
    from ..video.pipeline import VideoPipeline

    # As the benchmark's own passes (fastdet.bench.frame_level).
    reuse_freed_frames()
    unique = np.load(args.frames)
    frames = [unique[index] for index in np.load(args.order)]
    detector = Detector(model=load_model(args.model), config=load_config(args.config),
                        threads=1)
    pipeline = VideoPipeline(detector, TrackConfig())

    timed_pass(pipeline, frames)
    print("ready", flush=True)
    for line in sys.stdin:
        command = line.strip()
        if command == "pass":
            wall, cpu = timed_pass(pipeline, frames)
            print(f"{wall!r} {cpu!r}", flush=True)
        elif command == "quit":
            break
        else:
            print(f"unknown command {command!r}", file=sys.stderr, flush=True)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(_worker_main())
