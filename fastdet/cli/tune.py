"""``fastdet tune SOURCE... --annotations A.json``: thresholds on annotated frames."""

from __future__ import annotations

import sys
from pathlib import Path

from .common import add_annotation_options, annotated_sources


def add_tune_parser(subparsers):
    """Register ``tune`` on the ``fastdet`` command's sub-parsers."""
    tune = subparsers.add_parser("tune", help="choose detection thresholds on annotated frames")
    tune.add_argument("sources", nargs="+", metavar="SOURCE", help="videos and/or images")
    add_annotation_options(tune, "tune on")
    tune.add_argument("--out", metavar="CONFIG.toml", help="write the best thresholds as TOML")
    tune.add_argument("--top", type=int, default=10, help="rows of the table to print")
    tune.add_argument("--model", metavar="M", help="model file (default: bundled)")
    tune.add_argument("--config", metavar="C", help="TOML config with the scales and box filters")
    tune.add_argument("--jitter", type=float, nargs="+", default=(), metavar="ROWS",
                      help="also search every frame with the window grid moved up and down by "
                           "each of ROWS rows (at 720 rows): each counts as a frame of its own")
    tune.set_defaults(handler=cmd_tune)
    return tune


def cmd_tune(args):
    """Print the tuning table; write the best setting as TOML with ``--out``."""
    from ..detector.config import load_config
    from ..detector.model import load_model
    from ..files.atomic import atomic_path, check_writable, refuse_overwriting_inputs
    from ..training.tune import as_toml, format_results, tune
    from .common import message_stream

    refuse_overwriting_inputs(args.out, [*args.annotations, args.config, args.model,
                                         *args.sources])
    check_writable(args.out)
    sources = annotated_sources(args.sources, args.annotations, args.split)
    jitter = [sign * rows for rows in args.jitter for sign in (1, -1)]
    results = tune(load_model(args.model), sources, None, load_config(args.config),
                   log=lambda line: print(line, file=sys.stderr), jitter=jitter)
    messages = message_stream(args.out)
    print(format_results(results, top=args.top), file=messages)
    if args.out:
        with atomic_path(args.out) as tmp:
            Path(tmp).write_text(as_toml(results[0]))
        print(f"best thresholds written to {args.out}", file=messages)
    return 0
