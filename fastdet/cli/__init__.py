"""The ``fastdet`` command line: the parser (:mod:`.app`) and one module per verb.

Nothing outside this package imports it; it imports the library below.
"""


def main(argv=None):
    """Entry point of the ``fastdet`` console script; returns the exit code.

    See :func:`fastdet.cli.app.main`.
    """
    from .app import main as run_command

    return run_command(argv)
