"""``python -m fastdet.cli``: the ``fastdet`` command, as the console script runs it."""

from . import console_main

console_main()
