"""``fastdet batch INPUT... --out-dir DIR``: many videos on Dask, a thin layer over fastdet.batch.

Prints the summary table on stdout at the end; progress bars go to stderr
when it is a terminal.  Exit code 0 when every video is done, 1 when some
failed (their reasons are in the table and the manifest), 2 for bad input.
"""

from __future__ import annotations

import sys

from ..video.detection_files import FORMATS
from .common import add_encoder_options, add_horizon_option, add_schedule_options, compile_notice

#: Exit code when the batch ran but some videos failed.
EXIT_SOME_FAILED = 1


def add_batch_parser(subparsers):
    """Add the ``batch`` command to an ``argparse`` subparsers object."""
    batch = subparsers.add_parser(
        "batch", help="detect and track vehicles in many videos, on every core or a Dask cluster",
        description="Run `fastdet run` over many videos on Dask distributed: a local cluster "
                    "sized to this machine, or a running cluster (--scheduler).  Outputs mirror "
                    "each input's relative path under DIR, beside DIR/manifest.jsonl and "
                    "DIR/index.html; videos the manifest lists as done are skipped.")
    batch.add_argument("inputs", nargs="+", metavar="INPUT",
                       help="a video, a folder (searched recursively) or a text file of paths")
    batch.add_argument("--out-dir", required=True, metavar="DIR", help="output folder")
    batch.add_argument("--model", metavar="M", help="model file (.npz); default: bundled model")
    batch.add_argument("--config", metavar="C",
                       help="TOML config overriding built-in defaults ([track] for video settings)")
    add_horizon_option(batch)
    add_schedule_options(batch)
    batch.add_argument("--format", choices=FORMATS, help="detections format (default: jsonl)")
    batch.add_argument("--no-video", action="store_true", help="do not write annotated videos")
    batch.add_argument("--no-detections", action="store_true",
                       help="do not write detections files")
    add_encoder_options(batch)
    # Not given (rather than h264) so that --codec without a video output is refused.
    batch.set_defaults(codec=None)
    batch.add_argument("--segment", metavar="N|Ns",
                       help="split videos longer than N frames (or N seconds: 30s) into segments "
                            "processed in parallel")
    where = batch.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="a running Dask scheduler (default: a local cluster)")
    where.add_argument("--scheduler-file", metavar="FILE",
                       help="the file `dask scheduler --scheduler-file FILE` wrote")
    batch.add_argument("--workers", type=int, metavar="W",
                       help="worker processes of the local cluster (default: cores / threads)")
    batch.add_argument("--threads", type=int, metavar="T",
                       help="decoder and detector threads per video (default 1: videos in "
                            "parallel; on a local cluster with fewer videos than cores, the "
                            "cores shared among them)")
    batch.add_argument("--force", action="store_true",
                       help="redo videos the manifest lists as done")
    batch.add_argument("--quiet", "-q", action="store_true", help="no progress bars")
    batch.set_defaults(handler=cmd_batch)
    return batch


def cmd_batch(args):
    """Run the ``batch`` command; returns 0, or 1 when some video failed."""
    from ..batch import run_batch
    from ..batch.inputs import display_name
    from ..batch.report import summary_table

    run = run_batch(args.inputs, args.out_dir, scheduler=args.scheduler,
                    scheduler_file=args.scheduler_file, workers=args.workers,
                    threads=args.threads, segment=args.segment, force=args.force,
                    progress=not args.quiet and sys.stderr.isatty(), model=args.model,
                    config=args.config, horizon=args.horizon, every=args.every,
                    track=args.track,
                    video=not args.no_video, detections=not args.no_detections,
                    format=args.format, codec=args.codec, crf=args.crf, preset=args.preset,
                    compile_notice=lambda: compile_notice(enabled=not args.quiet))
    print(summary_table(run.records, run.skipped, run.wall))
    manifest = run.manifest.path
    print(f"{run.workers} workers, set up in {run.setup_seconds:.1f} s; manifest: "
          f"{display_name(str(manifest))}; report: "
          f"{display_name(str(manifest.parent / 'index.html'))}", flush=True)
    return EXIT_SOME_FAILED if any(r["status"] == "failed" for r in run.records) else 0
