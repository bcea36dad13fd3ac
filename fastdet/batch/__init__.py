"""Many videos on Dask distributed: ``fastdet batch`` and :func:`fastdet.batch`.

The package itself is callable: ``fastdet.batch(inputs, out_dir)`` calls
:func:`batch` whether ``fastdet.batch`` names this package (once it is
imported) or not yet (``fastdet`` imports it on first use, so that importing
``fastdet`` does not import Dask).

Modules, from the task up: :mod:`.job` (one video or segment through the
video layer), :mod:`.state` and :mod:`.boundary` (is a segment boundary
exact, how ids continue), :mod:`.merge` (segments joined), :mod:`.worker`
(the worker plugin and tasks), :mod:`.segments`, :mod:`.inputs`,
:mod:`.outputs`, :mod:`.settings`, :mod:`.manifest`, :mod:`.cluster`,
:mod:`.runner` (the client's loop), :mod:`.progress` and :mod:`.report`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import sys
import time
import types
from pathlib import Path

from ..files.atomic import output_folder
from .cluster import batch_client, local_layout
from .inputs import find_videos
from .outputs import check_outputs
from .report import write_report
from .runner import BatchRun
from .segments import parse_segment
from .settings import make_settings
from .worker import compile_for_local_workers

__all__ = ["batch", "run_batch"]


def run_batch(inputs, out_dir, client=None, *, scheduler=None, scheduler_file=None, workers=None,
              threads=None, segment=None, force=False, warmup=None, progress=False,
              compile_notice=contextlib.nullcontext, **run_options):
    """Run a batch and return its :class:`~fastdet.batch.runner.BatchRun` (what the CLI reports).

    See :func:`batch` for the parameters; ``compile_notice`` is a context
    manager factory wrapped around compiling a cold kernel cache before a
    local cluster starts (:func:`~fastdet.batch.worker.compile_for_local_workers`).
    The run's ``wall`` attribute holds its duration in seconds, cluster
    start included.
    """
    start = time.perf_counter()
    unknown = sorted(set(run_options) - set(inspect.signature(make_settings).parameters))
    if unknown:
        # Named against batch(), which the caller called, not the helper it passes them to.
        raise TypeError(f"batch() got an unexpected keyword argument {unknown[0]!r}")
    if isinstance(inputs, (str, Path)):
        inputs = [inputs]
    settings = make_settings(threads=1 if threads is None else threads, **run_options)
    if segment is not None:
        parse_segment(segment)   # a one-line error now, not once the cluster has started
    out_dir = Path(out_dir)
    videos = find_videos(inputs, exclude=out_dir)
    check_outputs(videos, out_dir, settings)
    output_folder(out_dir)
    if client is None and scheduler is None and scheduler_file is None:
        workers, threads = local_layout(len(videos), workers, threads, segment is not None)
        settings = dataclasses.replace(settings, threads=threads)
        compile_for_local_workers(settings, compile_notice)
    with batch_client(out_dir, client, scheduler, scheduler_file, workers,
                      settings.threads) as dask:
        run = BatchRun(dask, settings, out_dir, force=force, segment=segment, warmup=warmup)
        try:
            run.run(videos, progress=progress)
        finally:
            write_report(out_dir, [run.manifest.records[k] for k in sorted(run.manifest.records)])
    run.wall = time.perf_counter() - start
    return run


def batch(inputs, out_dir, client=None, **run_options):
    """Detect and track vehicles in many videos on Dask; return their manifest records.

    Parameters
    ----------
    inputs : str, Path or list of them
        Videos, folders (searched recursively) and text files listing paths.
    out_dir : str or Path
        Outputs mirror each input's relative path here, beside
        ``manifest.jsonl`` and ``index.html``.
    client : distributed.Client, optional
        Run on this client's cluster; by default a local cluster sized to the
        machine is started and closed.
    **run_options
        ``model``, ``config``, ``every``, ``track``, ``video`` (write the
        annotated videos, default True), ``detections`` (default True),
        ``format`` ('jsonl', 'csv', 'mot'), ``codec``, ``crf``, ``preset``
        (the annotated videos' encoder, as ``fastdet run`` takes them),
        ``threads`` (decoder and detector threads per task; default 1, or on
        a local cluster with fewer videos than cores the cores shared among
        them), ``workers`` (local cluster size), ``scheduler`` /
        ``scheduler_file`` (a running cluster instead of ``client``),
        ``segment`` (frames ``"500"`` or seconds ``"30s"`` per segment of a
        long video), ``warmup`` (frames before each segment; default from the
        ``[track]`` settings), ``force`` (redo videos already done),
        ``progress`` (progress bars on a terminal).

    Returns
    -------
    list of dict
        The manifest record of every video, in input order: ``status``
        (``"done"`` or ``"failed"`` with a ``reason``), ``frames``,
        ``vehicles``, ``fps``, ``outputs`` (relative to ``out_dir``), hashes.

    Raises
    ------
    FastdetError
        For bad inputs, model, configuration or cluster, before any video
        is processed.  A video that cannot be processed does not raise: its
        record says ``failed``.
    KeyboardInterrupt
        After cancelling the remaining work; a second call continues.

    Examples
    --------
    >>> records = fastdet.batch("footage/", "out/")                 # doctest: +SKIP
    >>> [r["status"] for r in records]                              # doctest: +SKIP
    ['done', 'done', 'failed']
    """
    return run_batch(inputs, out_dir, client, **run_options).records


class _CallableModule(types.ModuleType):
    """This package's type: calling it calls :func:`batch`."""

    def __call__(self, *args, **kwargs):
        # Passed on as given, so that a wrong call is reported against batch()'s
        # own signature, not this method's.
        return batch(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
