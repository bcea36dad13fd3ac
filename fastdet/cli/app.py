"""The ``fastdet`` command: the parser of every verb, and error handling.

Exit codes (the bad-input matrix, ``docs/reliability.md``, tests them):

* 0: done;
* 2: a user-facing failure (a :class:`~fastdet.errors.FastdetError` or an
  ``OSError``: bad input, an unwritable output, a full disk), reported as one
  line ``fastdet: error: ...`` on stderr; also argparse's usage errors;
* 70: an internal error (a bug), reported as one line too;
* 141: standard output's reader went away (``fastdet eval ... | head``), as
  for Unix tools that SIGPIPE ends; nothing is printed;
* 130: interrupted (Ctrl-C); 143: terminated (SIGTERM) (128 + the signal):
  SIGTERM is handled like Ctrl-C by every verb, so a scheduler stopping
  fastdet gets complete outputs or none, never a temporary file left over.

``--debug`` lets the exception through with its traceback instead;
``--verbose`` also logs what fastdet decides on the way (the kernel cache,
damaged cache entries, kernels loaded and compiled).  Both are accepted
before or after the verb.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import select
import signal
import sys
import threading

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
from .warmup import add_warmup_parser

EXIT_ERROR = 2
EXIT_INTERNAL = 70
EXIT_INTERRUPTED = 130
#: 128 + SIGPIPE, the status of a Unix tool whose output's reader went away.
EXIT_BROKEN_PIPE = 141


def _add_global_options(parser, default):
    parser.add_argument("--verbose", "-v", action="store_true", default=default,
                        help="say more: the run's thread plan, where kernels are cached and what was "
                             "loaded or compiled")
    parser.add_argument("--debug", action="store_true", default=default,
                        help="show the traceback of an error instead of one line")


def _add_to_every_verb(parser):
    """``--verbose`` and ``--debug`` after any verb too (without overriding them when absent)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for verb in action.choices.values():
                _add_global_options(verb, argparse.SUPPRESS)
                _add_to_every_verb(verb)


class _Parser(argparse.ArgumentParser):
    """An argument parser that takes options only as spelt in full, and whose
    verbs report their own usage errors.

    With argparse's prefix matching, ``fastdet detect --out x.jpg`` was
    ``--out-dir x.jpg`` and made a folder named ``x.jpg``; an option given
    as a prefix is now an unrecognised argument.  The verbs' parsers are of
    this class too (``add_subparsers`` makes them of its parser's class).

    ``verb``: a verb's parser refuses arguments it does not know itself, with
    its own usage (``usage: fastdet detect ...``).  argparse hands them up
    to the top-level parser, which printed the usage of ``fastdet`` alone,
    not of the verb that was given them.
    """

    def __init__(self, *args, verb=True, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self.verb = verb

    def parse_known_args(self, args=None, namespace=None):
        namespace, extras = super().parse_known_args(args, namespace)
        if extras and self.verb:
            self.error("unrecognized arguments: " + " ".join(extras))
        if self.verb:
            self._refuse_empty_values(namespace)
        return namespace, extras

    def _refuse_empty_values(self, namespace):
        """No option or input of fastdet means anything as an empty string, and
        ``detect --out-dir ''`` was taken as no ``--out-dir`` at all."""
        for action in self._actions:
            value = getattr(namespace, action.dest, None)
            values = value if isinstance(value, list) else [value]
            if any(isinstance(item, str) and not item for item in values):
                name = "/".join(action.option_strings) or action.metavar or action.dest
                self.error(f"argument {name}: expected a value, got an empty string")


def build_parser():
    """The argument parser of the ``fastdet`` command."""
    parser = _Parser(
        prog="fastdet", description="Fast classical vehicle detection (HOG + linear SVM).",
        verb=False)
    _add_global_options(parser, False)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_verb in (add_detect_parser, add_eval_parser, add_train_parser, add_mine_parser,
                     add_tune_parser, add_run_parser, add_batch_parser, add_viz_parser,
                     add_bench_parser, add_warmup_parser):
        add_verb(sub)
    _add_to_every_verb(parser)
    return parser


def _stdout_reader_gone():
    """Whether standard output is a pipe or socket that nobody reads any more.

    Asked of the descriptor itself (``poll`` reports an error on a pipe
    without readers), so that a broken pipe of anything else (a stream, a
    helper process) stays an error.
    """
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(event & (select.POLLERR | select.POLLHUP) for _, event in poller.poll(0))
    except (OSError, ValueError, AttributeError):   # no descriptor, or no poll here
        return False


def _discard_stdout():
    """Point standard output at the null device, so that the flush at exit
    does not report the broken pipe once more."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass


def _one_line(exc):
    return " ".join(str(exc).split()) or type(exc).__name__


def _start_verbose_log():
    """Log fastdet's notes to stderr as ``fastdet: ...`` lines."""
    from ..kernels import cache

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("fastdet: %(message)s"))
    logger = logging.getLogger("fastdet")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.info(cache.describe())
    return handler


def _terminated(signum, _frame):
    interrupt = KeyboardInterrupt(signal.Signals(signum).name)
    interrupt.signum = signum
    raise interrupt


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """SIGTERM raises KeyboardInterrupt (exit 143), unless someone else handles it already."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL):
        yield
        return
    signal.signal(signal.SIGTERM, _terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def main(argv=None):
    """Entry point of the ``fastdet`` console script; returns the exit code."""
    with _sigterm_as_interrupt():
        return _main(argv)


def _main(argv):
    parser = build_parser()
    args = parser.parse_args(argv)
    handler = _start_verbose_log() if args.verbose else None
    try:
        return args.handler(args)
    except KeyboardInterrupt as exc:
        if args.debug:
            raise
        print("fastdet: interrupted", file=sys.stderr)
        return 128 + getattr(exc, "signum", EXIT_INTERRUPTED - 128)
    except (FastdetError, OSError) as exc:
        if args.debug:
            raise
        if _stdout_reader_gone():
            # ``fastdet eval ... | head -2``: the reader stopped on purpose.
            # Unix tools end quietly then (SIGPIPE), and so does fastdet.
            _discard_stdout()
            return EXIT_BROKEN_PIPE
        print(f"fastdet: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as exc:  # noqa: BLE001 - a bug: still one line, the traceback on --debug
        if args.debug:
            raise
        print(f"fastdet: internal error: {type(exc).__name__}: {_one_line(exc)} (a bug; "
              "--debug shows where)", file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        if handler is not None:
            from ..kernels import cache

            logging.getLogger("fastdet").info(cache.summary())
            logging.getLogger("fastdet").removeHandler(handler)

