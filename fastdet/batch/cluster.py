"""Where a batch runs: a local Dask cluster sized to the machine, or a running cluster.

Without a scheduler, :func:`batch_client` starts a ``distributed.LocalCluster``
of worker *processes* (the pipeline's Python parts hold the GIL, so processes,
not threads, scale it), :func:`plan_layout` workers of one task thread each,
and closes it at the end; :func:`local_layout` gives each task more threads
when there are fewer videos than cores.  Each task's detector scores on ``threads`` threads
(Numba and OpenCV) and decodes with as many FFmpeg threads, so that
``workers x threads`` fills the cores without oversubscribing them; the
background video encoder of each task is one more thread, which overlaps the
others' waits.

With ``scheduler`` (``tcp://host:port``) or ``scheduler_file`` it connects to
a cluster started with ``dask scheduler`` and ``dask worker``, and checks that
every worker runs the same fastdet and sees the output folder at the same path.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import uuid
from pathlib import Path

from distributed import Client, LocalCluster
from distributed.diagnostics.plugin import WorkerPlugin

from .._version import __version__
from ..errors import InputError
from .worker import worker_report

#: Memory planned per worker process (fastdet, OpenCV and a few frames in flight).
WORKER_MEMORY = 768 << 20
#: Seconds to wait for a running cluster's first worker.
WORKER_WAIT = 60


def usable_cores():
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def plan_layout(cores=None, threads=1, memory=None):
    """Worker processes for a machine: one per ``threads`` cores, as memory allows.

    Parameters
    ----------
    cores : int, optional
        Default: :func:`usable_cores`.
    threads : int
        Detector threads per task.
    memory : int, optional
        Bytes of memory; default: the machine's (``psutil``).

    Returns
    -------
    int
    """
    import psutil

    cores = usable_cores() if cores is None else cores
    memory = psutil.virtual_memory().total if memory is None else memory
    return max(1, min(cores // max(threads, 1), memory // WORKER_MEMORY))


def local_layout(video_count, workers=None, threads=None, segmenting=False, cores=None,
                 memory=None):
    """Worker processes and threads per task of a local cluster for ``video_count`` videos.

    Without ``threads``, a task gets one thread and the videos run side by
    side, one per worker; with fewer videos than cores (and no segments,
    which split long videos into more tasks) the cores are shared out among
    the videos instead, so that one video alone still uses every core.

    Parameters
    ----------
    video_count : int
    workers, threads : int, optional
        Asked for (``--workers``, ``--threads``); ``threads`` defaults to the
        cores per worker when only ``workers`` is given.
    segmenting : bool
        Whether long videos are split (``--segment``).
    cores, memory : int, optional
        Default: the machine's (:func:`usable_cores`, ``psutil``).

    Returns
    -------
    tuple of int
        ``(workers, threads)``.
    """
    _check_worker_count(workers)
    cores = usable_cores() if cores is None else cores
    if workers is not None:
        _check_workers_fit(workers, memory)
    if threads is None:
        if workers is not None:
            threads = max(1, cores // workers)
        elif segmenting or video_count >= cores:
            threads = 1
        else:
            threads = max(1, cores // max(video_count, 1))
            workers = max(1, min(video_count, plan_layout(cores, threads, memory)))
    if workers is None:
        workers = plan_layout(cores, threads, memory)
    return workers, threads


@contextlib.contextmanager
def batch_client(out_dir, client=None, scheduler=None, scheduler_file=None, workers=None,
                 threads=1):
    """Yield a ``distributed.Client`` to run a batch on.

    Parameters
    ----------
    out_dir : Path
        The output folder (created); workers of a running cluster must see it.
    client : distributed.Client, optional
        Used as it is, and left open.
    scheduler : str, optional
        Address of a running scheduler.
    scheduler_file : str or Path, optional
        A scheduler file (``dask scheduler --scheduler-file``).
    workers : int, optional
        Worker processes of the local cluster (default: :func:`plan_layout`).
    threads : int
        Detector threads per task.

    Raises
    ------
    InputError
        When the scheduler cannot be reached, no worker joins, or a worker
        runs another fastdet or does not see ``out_dir``.
    """
    if sum(x is not None for x in (client, scheduler, scheduler_file)) > 1:
        raise InputError("give at most one of a client, --scheduler and --scheduler-file")
    with contextlib.ExitStack() as stack:
        if client is None and scheduler is None and scheduler_file is None:
            client = stack.enter_context(_local_client(workers, threads))
        elif client is None:
            client = stack.enter_context(_remote_client(scheduler, scheduler_file))
        check_workers(client, out_dir)
        yield client


@contextlib.contextmanager
def _local_client(workers, threads):
    _check_worker_count(workers)
    environment = {"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": "1"}
    with LocalCluster(n_workers=workers or plan_layout(threads=threads), threads_per_worker=1,
                      processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0",
                      # Dask's own error reports are tracebacks (a worker's heartbeat
                      # failing while Ctrl-C closes the cluster); a batch reports each
                      # failure in one line instead.
                      silence_logs=logging.CRITICAL, env=environment) as cluster, \
            Client(cluster) as client:
        client.register_plugin(_IgnoreInterrupts(), name="fastdet-ignore-interrupts")
        yield client


def _check_worker_count(workers):
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise InputError(f"--workers must be at least 1, got {workers}")


def _check_workers_fit(workers, memory=None):
    """Refuse more local worker processes than the machine's memory holds.

    Each one is a Python process with fastdet, Numba, OpenCV and Dask loaded
    (:data:`WORKER_MEMORY` planned): ``--workers 1000`` started processes
    until Dask's own bookkeeping failed in a traceback, then hung.
    """
    import psutil

    memory = psutil.virtual_memory().total if memory is None else memory
    if workers * WORKER_MEMORY > memory:
        raise InputError(f"--workers {workers}: local worker processes need about "
                         f"{WORKER_MEMORY >> 20} MiB each, {workers * WORKER_MEMORY / 2**30:.1f} "
                         f"GiB in all, more than this machine's {memory / 2**30:.1f} GiB "
                         f"(at most {max(1, memory // WORKER_MEMORY)} here)")


class _IgnoreInterrupts(WorkerPlugin):
    """Ctrl-C reaches the local workers too (one process group); the client alone answers it.

    Registered on the local cluster only: the workers of a cluster someone
    started keep their own handling of Ctrl-C.
    """

    idempotent = True

    def setup(self, worker):
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _remote_client(scheduler, scheduler_file):
    where = scheduler or f"the scheduler file {scheduler_file}"
    if scheduler_file is not None and not Path(scheduler_file).is_file():
        raise InputError(f"scheduler file not found: {scheduler_file}")
    try:
        client = Client(scheduler, scheduler_file=scheduler_file, timeout="20s")
    except (OSError, TimeoutError) as exc:
        raise InputError(f"cannot reach the Dask scheduler at {where}: {exc}") from None
    with client:
        try:
            client.wait_for_workers(1, timeout=WORKER_WAIT)
        except TimeoutError:
            raise InputError(f"no Dask worker joined the scheduler at {where} within "
                             f"{WORKER_WAIT} s (start some with `dask worker`)") from None
        yield client


def check_workers(client, out_dir):
    """Every worker must run this fastdet and see ``out_dir`` (a shared filesystem).

    Raises
    ------
    InputError
        Naming the first worker that does not.
    """
    probe = Path(out_dir) / f".fastdet-probe-{uuid.uuid4().hex}"
    probe.write_text("fastdet batch: every worker must see this file\n", encoding="utf-8")
    try:
        reports = client.run(worker_report, str(probe.parent), probe.name)
    finally:
        probe.unlink()
    for address, report in sorted(reports.items()):
        if report["version"] != __version__:
            raise InputError(f"worker {address} runs fastdet {report['version']}, this client "
                             f"{__version__}: install the same fastdet on every worker")
        if not report["sees_out_dir"]:
            raise InputError(f"worker {address} does not see {Path(out_dir).resolve()}: workers "
                             "need the output folder (and the inputs) on a filesystem they share "
                             "with this client, at the same path")
