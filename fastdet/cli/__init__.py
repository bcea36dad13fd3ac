"""The ``fastdet`` command line: the parser (:mod:`.app`) and one module per verb.

Nothing outside this package imports it; it imports the library below.
"""


def main(argv=None):
    """Run one ``fastdet`` command; returns the exit code.

    See :func:`fastdet.cli.app.main`.
    """
    from .app import main as run_command

    return run_command(argv)


def console_main(argv=None):
    """Entry point of the ``fastdet`` console script: :func:`main`, then the end of the process.

    Every command has closed its outputs when it returns; what Python would
    still do is tear the interpreter down, module by module, and with
    Numba's compiled kernels loaded that took 0.15-0.23 s (AMD EPYC Zen 3:
    0.06 s after importing numpy, OpenCV and Numba alone), as long as a
    hundred frames' detection.  So the process ends the way Python's own
    shutdown begins (other threads joined, exit handlers run: logging
    flushed, temporary cache folders removed), the standard streams are
    flushed, and then it exits without the teardown.
    """
    import atexit
    import os
    import sys
    import threading

    _compile_ahead(sys.argv[1:] if argv is None else argv)
    code = main(argv)
    code = 0 if code is None else int(code)
    try:
        threading._shutdown()      # what Py_FinalizeEx does first: join non-daemon threads
        atexit._run_exitfuncs()
        sys.stdout.flush()
        sys.stderr.flush()
    except BrokenPipeError:
        # What was printed last reached no reader (``fastdet ... | head``):
        # quiet, as in main() (Python's own exit would print a traceback).
        from .app import EXIT_BROKEN_PIPE

        os._exit(EXIT_BROKEN_PIPE)
    except BaseException:  # noqa: BLE001 - Python's own exit reports it
        sys.exit(code)
    os._exit(code)


#: Verbs that detect in this process: on a first run their kernels compile
#: partly in a helper process started before the imports (see
#: :func:`_compile_ahead`).
DETECTING_VERBS = ("detect", "run", "eval")


def _compile_ahead(argv):
    """Start compiling an empty kernel cache now, if the command will detect.

    The command's own imports (NumPy, OpenCV, Numba, the verb's modules)
    take 0.4-0.5 s on one core; a helper process started here compiles its
    share of the kernels meanwhile (:func:`fastdet.compile_ahead.start_early`;
    it does nothing when anything of this fastdet is cached).  The verb is
    the first argument that is not an option (the global ones take no value).
    """
    verb = next((arg for arg in argv if not arg.startswith("-")), None)
    if verb in DETECTING_VERBS and not {"-h", "--help"} & set(argv):
        from ..compile_ahead import start_early

        start_early()
