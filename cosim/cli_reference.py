"""The command-line reference, generated from the argparse parser (:func:`cosim.cli.build_parser`).

``cli_markdown()`` renders ``python -m cosim`` and every command as the page
``reference/cli.md`` of the docs site (built by the MkDocs hook ``docs/hooks/reference.py``):
usage, description, and one row per argument with its default and help text.
``undocumented_arguments()`` lists arguments without a help text (a test keeps it empty).
"""
from __future__ import annotations

import argparse

from cosim.cli import build_parser
from cosim.results.exits import exit_codes_line


def _commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _arguments(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]


def _name(action: argparse.Action) -> str:
    if action.option_strings:
        names = ", ".join(action.option_strings)
        if action.nargs == 0:
            return names
        metavar = action.metavar or ("{" + ",".join(map(str, action.choices)) + "}" if action.choices
                                     else action.dest.upper())
        return f"{names} {metavar}"
    return str(action.metavar or action.dest)


def _text(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """The help text as ``--help`` prints it (``%(default)s`` and the like filled in)."""
    if not action.help:
        return ""
    return parser._get_formatter()._expand_help(action)


def _fixed_width(prog: str) -> argparse.HelpFormatter:
    return argparse.HelpFormatter(prog, width=100)


def _default(action: argparse.Action) -> str:
    if action.nargs == 0 or action.default in (None, argparse.SUPPRESS) or not action.option_strings:
        return ""
    return f"`{action.default}`"


def undocumented_arguments() -> list[tuple[str, str]]:
    """(command, argument) of every argument without a help text."""
    parser = build_parser()
    found = [("", _name(a)) for a in _arguments(parser) if not (a.help or "").strip()]
    for name, sub in _commands(parser).items():
        found += [(name, _name(a)) for a in _arguments(sub) if not (a.help or "").strip()]
    return found


def cli_markdown() -> str:
    """The page ``reference/cli.md``: usage and arguments of every command."""
    parser = build_parser()
    commands = _commands(parser)
    for each in (parser, *commands.values()):  # the usage lines wrap the same whatever the terminal
        each.formatter_class = _fixed_width
    lines = [
        "# Command line (reference)",
        "",
        "Generated from the argparse parser (`cosim/cli.py`, `cosim/commands/*.py`) by",
        "`cosim/cli_reference.py` when the site is built. `python -m cosim` and the installed `cosim`",
        "script are the same program. Exit codes: " + exit_codes_line() + "; see",
        "[Verdicts and exit codes](verdicts.md).",
        "",
        "```text",
        parser.format_usage().strip(),
        "```",
        "",
        "| command | what it does |",
        "|---|---|",
    ]
    for name, sub in commands.items():
        lines.append(f"| [`{name}`](#{name}) | {_text(sub.description or '')} |")
    for name, sub in commands.items():
        lines += ["", f"## `{name}` {{#{name}}}", "", _text(sub.description or ""), "",
                  "```text", sub.format_usage().strip(), "```", "",
                  "| argument | default | meaning |", "|---|---|---|"]
        for action in _arguments(sub):
            lines.append(f"| `{_name(action)}` | {_default(action)} | {_text(_help(sub, action))} |")
    return "\n".join(lines) + "\n"


__all__ = ["cli_markdown", "undocumented_arguments"]
