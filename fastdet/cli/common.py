"""Options and helpers that several verbs share."""

from __future__ import annotations


def add_model_options(parser):
    """``--model``, ``--config`` and ``--threads``: what building a detector needs."""
    parser.add_argument("--model", metavar="M", help="model file (.npz); default: bundled model")
    parser.add_argument("--config", metavar="C", help="TOML config overriding built-in defaults")
    parser.add_argument("--threads", type=int, metavar="T",
                        help="threads per frame: scales are scored concurrently (default: "
                             "NUMBA_NUM_THREADS, all cores)")


def make_detector(args):
    """The :class:`~fastdet.detector.detector.Detector` that ``args``' model options ask for."""
    from ..detector.config import load_config
    from ..detector.detector import Detector

    return Detector(model=args.model, config=load_config(args.config),
                    threads=getattr(args, "threads", None))


def log_to_stderr(line):
    """Progress lines of long commands go to stderr, flushed at once."""
    import sys

    print(line, file=sys.stderr, flush=True)
