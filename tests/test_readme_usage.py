"""README's command synopses name only options the ``fastdet`` parser has.

The synopses (the "Use" block, and those of "Video", "Batch runs", "`fastdet bench`" and
"Start-up") are checked against the parser ``fastdet.cli.app.main`` builds
(:func:`~fastdet.cli.app.build_parser`), so an option renamed or removed in the code, or
misspelt in the README, fails here instead of drifting.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from fastdet.cli.app import build_parser

README = Path(__file__).resolve().parents[1] / "README.md"

#: Sections whose first ``bash`` block is a synopsis, by their heading.
SYNOPSIS_SECTIONS = ("## Use", "## Video", "## Batch runs", "### `fastdet bench`",
                     "### Start-up")
OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
#: ``--format jsonl|csv|mot``: an option followed by the values it takes.
CHOICES = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)\s+\[?([a-z0-9]+(?:\|[a-z0-9]+)+)\]?")


def _subcommands(parser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices
    return {}


def _first_bash_block(text, heading):
    start = re.search(rf"^{re.escape(heading)}\s*$", text, re.M)
    assert start, f"README has no section {heading!r}"
    level = heading.split()[0]
    end = re.search(rf"^#{{1,{len(level)}}} ", text[start.end():], re.M)
    section = text[start.end(): start.end() + end.start() if end else len(text)]
    block = re.search(r"^```bash\n(.*?)^```", section, re.M | re.S)
    assert block, f"README section {heading!r} has no bash block"
    return block.group(1)


def _commands(block):
    """The ``fastdet ...`` commands of a block, continuation lines joined, comments dropped."""
    commands = []
    current = None
    for line in block.splitlines():
        line = re.sub(r"\s#.*$", "", line).rstrip().removesuffix("\\").rstrip()
        if line.startswith("fastdet "):
            current = [line]
            commands.append(current)
        elif current is not None and line[:1].isspace() and line.strip():
            current.append(line.strip())
        else:
            current = None
    return [" ".join(parts) for parts in commands]


def _readme_commands(heading):
    return _commands(_first_bash_block(README.read_text(encoding="utf-8"), heading))


def _verb_parser(command):
    """The parser of the verb (or ``viz`` picture) ``command`` names, and its name."""
    words = command.split()
    verbs = _subcommands(build_parser())
    assert words[1] in verbs, f"README shows `{command}`, but fastdet has no verb {words[1]!r}"
    parser, name = verbs[words[1]], words[1]
    pictures = _subcommands(parser)
    if pictures and len(words) > 2 and words[2] in pictures:
        parser, name = pictures[words[2]], f"{name} {words[2]}"
    return parser, name


def _all_commands():
    return [(heading, command) for heading in SYNOPSIS_SECTIONS
            for command in _readme_commands(heading)]


def test_the_synopses_are_found():
    """The blocks are where the README keeps them (an empty list would check nothing)."""
    shown = {command.split()[1] for command in _readme_commands("## Use")}
    assert shown >= {"detect", "eval", "train", "mine", "tune", "bench", "batch", "warmup", "viz"}
    for heading in SYNOPSIS_SECTIONS:
        assert _readme_commands(heading), f"no fastdet command in the block of {heading!r}"


def test_every_verb_is_in_the_use_block():
    shown = {command.split()[1] for command in _readme_commands("## Use")}
    missing = sorted(set(_subcommands(build_parser())) - shown)
    assert not missing, f"README's Use block shows no `fastdet {missing[0]}`"


@pytest.mark.parametrize("heading, command", _all_commands())
def test_every_option_shown_exists(heading, command):
    parser, name = _verb_parser(command)
    unknown = [option for option in OPTION.findall(command)
               if option not in parser._option_string_actions]
    assert not unknown, (f"README ({heading}) shows `fastdet {name}` with {', '.join(unknown)}, "
                         f"which `fastdet {name} --help` does not list")


@pytest.mark.parametrize("heading, command", _all_commands())
def test_the_values_shown_are_the_choices(heading, command):
    parser, name = _verb_parser(command)
    for option, values in CHOICES.findall(command):
        action = parser._option_string_actions.get(option)
        if action is None or action.choices is None:
            continue
        assert set(values.split("|")) == set(action.choices), (
            f"README ({heading}) shows `fastdet {name} {option} {values}`; the parser takes "
            f"{'|'.join(action.choices)}")


def test_the_check_catches_a_bogus_option():
    """The parsing above finds an option that does not exist (and not only in theory)."""
    block = "fastdet detect IMAGE... [--model M] \\\n    [--no-such-option]   # comment --ignored\n"
    (command,) = _commands(block)
    parser, _ = _verb_parser(command)
    assert [o for o in OPTION.findall(command) if o not in parser._option_string_actions] == [
        "--no-such-option"]


def test_the_viz_pictures_shown_are_the_parsers():
    (line,) = [c for c in _readme_commands("## Use") if c.split()[1] == "viz"]
    viz = _subcommands(build_parser())["viz"]
    assert set(line.split()[2].split("|")) == set(_subcommands(viz)), (
        f"README shows `{line}`; fastdet viz has {'|'.join(_subcommands(viz))}")
