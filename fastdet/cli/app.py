"""The ``fastdet`` command: the parser of every verb, and error handling.

Every user-facing failure (a :class:`~fastdet.errors.FastdetError` or an
``OSError``) becomes one line ``fastdet: error: ...`` on stderr and exit code 2;
Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import FastdetError
from .batch import add_batch_parser
from .bench import add_bench_parser
from .detect import add_detect_parser
from .eval import add_eval_parser
from .mine import add_mine_parser
from .run import add_run_parser
from .train import add_train_parser
from .tune import add_tune_parser
from .viz import add_viz_parser

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def build_parser():
    """The argument parser of the ``fastdet`` command."""
    parser = argparse.ArgumentParser(
        prog="fastdet", description="Fast classical vehicle detection (HOG + linear SVM).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_verb in (add_detect_parser, add_eval_parser, add_train_parser, add_mine_parser,
                     add_tune_parser, add_run_parser, add_batch_parser, add_viz_parser,
                     add_bench_parser):
        add_verb(sub)
    return parser


def main(argv=None):
    """Entry point of the ``fastdet`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except KeyboardInterrupt:
        print("fastdet: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (FastdetError, OSError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"fastdet: error: {message}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
