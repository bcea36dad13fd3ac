"""``fastdet tune SOURCE... --annotations A.json``: thresholds on annotated frames."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from .common import add_annotation_options, annotated_sources

#: Largest ``--jitter``, in rows at 720: the window grid steps 8-16 rows, so a
#: shift of more than a few steps no longer samples where the grid falls on a
#: car but searches another band of the road than the config lays out.
MAX_JITTER_ROWS = 64


def add_tune_parser(subparsers):
    """Register ``tune`` on the ``fastdet`` command's sub-parsers."""
    tune = subparsers.add_parser("tune", help="choose detection thresholds on annotated frames")
    tune.add_argument("sources", nargs="+", metavar="SOURCE", help="videos and/or images")
    add_annotation_options(tune, "tune on")
    tune.add_argument("--out", metavar="CONFIG.toml", help="write the best thresholds as TOML")
    tune.add_argument("--top", type=int, default=10, help="rows of the table to print (default %(default)s)")
    tune.add_argument("--model", metavar="M", help="model file (default: bundled)")
    tune.add_argument("--config", metavar="C", help="TOML config with the scales and box filters")
    tune.add_argument("--jitter", type=float, nargs="+", default=(), metavar="ROWS",
                      help="also search every frame with the window grid moved up and down by "
                           "each of ROWS rows (at 720 rows): each counts as a frame of its own")
    tune.set_defaults(handler=cmd_tune)
    return tune


def cmd_tune(args):
    """Print the tuning table; write the best setting as TOML with ``--out``."""
    from ..detector.config import load_config, read_toml
    from ..detector.model import load_model
    from ..errors import InputError
    from ..files.atomic import atomic_path, check_writable, refuse_overwriting_inputs
    from ..training.tune import as_toml, format_results, tune
    from .common import message_stream

    if args.top < 1:
        raise InputError(f"--top must be at least 1 (rows of the table), got {args.top}")
    refuse_overwriting_inputs(args.out, [*args.annotations, args.config, args.model,
                                         *args.sources])
    check_writable(args.out)
    config = load_config(args.config)
    # The written config carries the file's [track] on: a mistake there is refused now.
    from ..video.config import load_track_config

    load_track_config(args.config)
    jitter = [sign * rows for rows in args.jitter for sign in (1, -1)]
    _check_jitter(args.jitter, config)
    sources = annotated_sources(args.sources, args.annotations, args.split)
    results = tune(load_model(args.model), sources, None, config,
                   log=lambda line: print(line, file=sys.stderr), jitter=jitter)
    messages = message_stream(args.out)
    print(format_results(results, top=args.top), file=messages)
    if args.out:
        # The whole --config with the tuned values in: the file alone reproduces the result.
        base = read_toml(args.config) if args.config else None
        with atomic_path(args.out) as tmp:
            Path(tmp).write_text(as_toml(results[0], base))
        print(f"best thresholds written to {args.out}", file=messages)
    return 0


def _check_jitter(jitter, config):
    """Refuse a --jitter the search cannot be moved by, naming --jitter (not the horizon)."""
    from ..errors import ConfigError, InputError
    from ..training.tune import _moved

    for rows in jitter:
        if not math.isfinite(rows) or abs(rows) > MAX_JITTER_ROWS:
            raise InputError(f"--jitter must be rows between -{MAX_JITTER_ROWS} and "
                             f"{MAX_JITTER_ROWS} (the window grid steps 8-16 rows at 720), "
                             f"got {rows}")
        for shift in (rows, -rows):
            try:
                _moved(config, shift)
            except ConfigError as exc:
                raise InputError(f"--jitter {rows:g} moves the search out of the frame with "
                                 f"this config ({exc})") from None
