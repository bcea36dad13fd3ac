"""Resources over a long run: resident memory and open files of ``fastdet run`` as frames pass.

The promise (``docs/reliability.md``): memory and open files stay flat over a
video of any length.  :func:`long_run_profile` checks it the way a user would
meet it: one ``fastdet run`` process over the test clip looped forward and
back to ``frames`` frames (10,000 by default), writing the annotated video
and the detections file.  While it runs, the process is sampled from
``/proc`` (``VmRSS``, ``VmHWM``, ``Threads`` and the entries of ``fd/``); the
frames done are counted from the lines of the detections file's temporary
file, which the run writes one frame at a time.  The table holds the sample
taken as each multiple of ``every`` frames is passed.

Linux only (``/proc``); a benchmark, never a timed test.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

#: Frames of the long input, and the spacing of the table's rows.
LONG_RUN_FRAMES = 10_000
ROW_EVERY = 1_000
#: libx264 preset of the long input: made once, in about a minute.
LONG_RUN_PRESET = "veryfast"


@dataclass(frozen=True)
class ResourceSample:
    """The process's resources once ``frames`` frames were written."""

    frames: int
    seconds: float
    rss_mib: float
    peak_rss_mib: float
    open_files: int
    threads: int
    #: The last look before the process ended, when it was closing its outputs.
    closing: bool = False


def process_resources(pid):
    """``(rss_mib, peak_rss_mib, threads, open_files)`` of a live process, from ``/proc``.

    Raises
    ------
    FileNotFoundError
        If the process has ended.
    KeyError
        If it is ending (a zombie has no memory lines).
    """
    fields = {}
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            key, _, value = line.partition(":")
            fields[key] = value.split()
    open_files = len(os.listdir(f"/proc/{pid}/fd"))
    return (int(fields["VmRSS"][0]) / 1024, int(fields["VmHWM"][0]) / 1024,
            int(fields["Threads"][0]), open_files)


class _LineCounter:
    """Lines of a growing file, reading only what was added since the last look."""

    def __init__(self):
        self.path, self.offset, self.lines = None, 0, 0

    def count(self, path):
        if path is None:
            return self.lines
        if path != self.path:
            self.path, self.offset, self.lines = path, 0, 0
        try:
            with open(path, "rb") as handle:
                handle.seek(self.offset)
                added = handle.read()
        except FileNotFoundError:
            return self.lines
        self.offset += len(added)
        self.lines += added.count(b"\n")
        return self.lines


def _detections_temporary(folder, name):
    from ..files.atomic import is_temporary

    stem = Path(name).stem
    return next((p for p in folder.iterdir()
                 if is_temporary(p) and p.name.startswith(f".{stem}.")), None)


def long_run_profile(video, every=ROW_EVERY, options=(), interval=0.05, log=None):
    """Sample one ``fastdet run`` process over ``video`` as it passes each ``every`` frames.

    Parameters
    ----------
    video : str or Path
        The input (see :func:`long_input`).
    every : int
        Spacing of the samples kept, in frames.
    options : sequence of str
        More ``fastdet run`` options (e.g. ``("--threads", "1")``).
    interval : float
        Seconds between looks at the process.
    log : callable, optional
        Called with a line of progress per kept sample.

    Returns
    -------
    list of ResourceSample
        One per multiple of ``every`` passed, and the last look before the process ended.

    Raises
    ------
    RuntimeError
        If the run fails.
    """
    with tempfile.TemporaryDirectory(prefix="fastdet-long-run-") as folder:
        folder = Path(folder)
        out, dets = folder / "out.mp4", folder / "dets.jsonl"
        command = [sys.executable, "-m", "fastdet.cli", "run", str(video), "--out", str(out),
                   "--detections", str(dets), "--quiet", *options]
        samples, temporary, last, counter = [], None, None, _LineCounter()
        started = time.perf_counter()
        with tempfile.TemporaryFile("w+") as errors:
            process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=errors)
            while process.poll() is None:
                temporary = temporary or _detections_temporary(folder, dets.name)
                try:
                    resources = process_resources(process.pid)
                except (FileNotFoundError, ProcessLookupError, KeyError):
                    break
                frames = counter.count(temporary)
                last = (frames, time.perf_counter() - started, resources)
                if frames >= (len(samples) + 1) * every:
                    samples.append(_sample(*last))
                    if log:
                        log(_row(samples[-1]))
                time.sleep(interval)
            process.wait()
            if process.returncode != 0:
                errors.seek(0)
                raise RuntimeError(f"fastdet run failed: {errors.read().strip()[-500:]}")
        # The last look at the living process, if no row was kept for it.
        if last is not None and (not samples or samples[-1].frames != last[0]):
            samples.append(_sample(*last, closing=True))
    return samples


def _sample(frames, seconds, resources, closing=False):
    rss, peak, threads, open_files = resources
    return ResourceSample(frames, seconds, rss, peak, open_files, threads, closing)


def _row(sample):
    label = f"{sample.frames} (end)" if sample.closing else str(sample.frames)
    return (f"| {label:>12} | {sample.seconds:7.1f} | {sample.rss_mib:7.1f} | "
            f"{sample.peak_rss_mib:8.1f} | {sample.open_files:10} | {sample.threads:7} |")


def long_input(source, frames=LONG_RUN_FRAMES):
    """The long run's input: ``source`` looped forward and back to ``frames`` frames (cached)."""
    from .video_run import looped_video

    return looped_video(source, frames, preset=LONG_RUN_PRESET)


def format_long_run(samples):
    """Markdown: the samples, then their growth while frames flowed (the closing look aside)."""
    lines = ["|       frames | seconds | RSS MiB | peak MiB | open files | threads |",
             "|-------------:|--------:|--------:|---------:|-----------:|--------:|"]
    lines += [_row(sample) for sample in samples]
    running = [sample for sample in samples if not sample.closing]
    if len(running) >= 2:
        first, final = running[0], running[-1]
        lines += ["", f"From {first.frames} to {final.frames} frames: RSS "
                      f"{final.rss_mib - first.rss_mib:+.1f} MiB, peak RSS "
                      f"{final.peak_rss_mib - first.peak_rss_mib:+.1f} MiB, open files "
                      f"{final.open_files - first.open_files:+d}, threads "
                      f"{final.threads - first.threads:+d}."]
    return "\n".join(lines)
