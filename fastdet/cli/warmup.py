"""``fastdet warmup``: compile every kernel once (building an image, starting a worker)."""

from __future__ import annotations

import time


def add_warmup_parser(subparsers):
    """Register ``warmup`` on the ``fastdet`` command's sub-parsers."""
    from ..kernels.warmup import FAMILIES

    warmup = subparsers.add_parser(
        "warmup", help="compile (or load) every kernel once and say what it took",
        description="Compile the Numba kernels into the kernel cache (or load them if they are "
                    "there) and byte-compile fastdet's Python modules where they are not yet, so "
                    "that later commands start at once.  Prints one line per kernel family.")
    warmup.add_argument("--families", nargs="+", choices=sorted(FAMILIES), metavar="F",
                        help=f"only these families (default: all: {', '.join(FAMILIES)})")
    warmup.add_argument("--processes", type=int, default=None, metavar="N",
                        help="compile uncompiled families in up to 2 processes (default: 2 "
                             "with two or more cores; 1: this process only)")
    warmup.set_defaults(handler=cmd_warmup)
    return warmup


def cmd_warmup(args):
    """Warm the families and print what each cost; returns the exit code."""
    from ..errors import InputError
    from ..files.bytecode import compile_package
    from ..kernels.cache import describe
    from ..kernels.warmup import FAMILIES, compiled_here, warm

    if args.processes is not None and args.processes < 1:
        raise InputError(f"--processes must be at least 1, got {args.processes}")
    # Each family once, in the order given: its table row is printed once.
    names = list(dict.fromkeys(args.families or FAMILIES))
    bytecode = compile_package()
    if bytecode["compiled"]:
        done = "" if bytecode["ok"] else " (some could not be written: a read-only installation)"
        print(f"python modules: {bytecode['compiled']} byte-compiled in "
              f"{bytecode['seconds']:.2f} s{done}")
    else:
        print("python modules: already byte-compiled")
    # Where the kernels go, and that they are not kept when the configured
    # folder cannot be written (a warm-up whose work is then lost at exit).
    print(describe())
    start = time.perf_counter()
    seconds = warm(names, processes=args.processes)
    total = time.perf_counter() - start
    helper = seconds.pop("helper", {})
    print("| family | kernels were | seconds |")
    print("|---|---|---:|")
    for name in names:
        if name in helper:
            print(f"| {name} | compiled (helper process) | {helper[name]:.2f} |")
        else:
            what = "compiled" if compiled_here(name) else "loaded from the cache"
            print(f"| {name} | {what} | {seconds[name]:.2f} |")
    print(f"\n{len(names)} families ready in {total:.1f} s"
          + (f" ({len(helper)} compiled by a second process)" if helper else ""))
    return 0
