"""The command line's parser: argparse's, with errors an operator takes in at a glance.

A mistake on the command line gets three things and exit status 2: one usage
line (``serve`` alone has 81 flags, which ``--help`` lists by group), the
error, and the command, flag or choice meant when a close one exists
(``did you mean --port?``). Subcommands' parsers are ``CommandParser`` too:
argparse makes them with their parent's class.
"""

from __future__ import annotations

import argparse
import ast
import difflib
import re
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

# argparse's "argument NAME: invalid choice: 'VALUE' (choose from ...)", VALUE as repr() writes it.
_INVALID_CHOICE = re.compile(r"argument (.+?): invalid choice: ('(?:[^'\\]|\\.)*'|\"(?:[^\"\\]|\\.)*\") \(", re.S)


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Wider help columns, so flag help with its default stays readable."""

    def __init__(self, prog: str):
        super().__init__(prog, max_help_position=32)


class CommandParser(argparse.ArgumentParser):
    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._given: list[str] = []

    # argparse types this method by three overloads; it is only wrapped here
    def parse_known_args(self, args: Sequence[str] | None = None, namespace: Any = None) -> Any:  # type: ignore[override]
        # kept for the hint: argparse's "required" error does not name the flag that was mistyped
        self._given = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.format_usage()}{self.prog}: error: {self.hinted(message)}\n")

    def format_usage(self) -> str:
        return f"usage: {self.usage_line()}\n"

    def format_help(self) -> str:
        if self.usage is None:  # the help opens with the same line, not the whole flag list twice
            self.usage = self.usage_line().replace("%", "%%")
        return super().format_help()

    def usage_line(self) -> str:
        """argparse's usage when it fits on a line; else the command, its
        required flags, ``[options]`` and its positionals."""
        usage = super().format_usage().removeprefix("usage: ").strip()
        if "\n" not in usage:
            return usage
        words = [self.prog]
        for action in self._actions:
            if action.required and action.option_strings:
                words.append(f"{action.option_strings[-1]} {action.metavar or action.dest.upper()}")
        words.append("[options]")
        for action in self._get_positional_actions():
            name = str(action.metavar or action.dest)
            words.append(f"{name} ..." if action.nargs == argparse.PARSER else name)
        return " ".join(words)

    def hinted(self, message: str) -> str:
        """argparse's ``message`` with what was meant, when it is close:
        ``unknown command 'sevre' (did you mean serve?)``, ``argument --format:
        invalid choice 'cvs' (did you mean csv?)``, ``... (did you mean --port?)``."""
        found = _INVALID_CHOICE.match(message)
        action = next((a for a in self._actions if found and _name(a) == found[1] and a.choices), None)
        if found is None or action is None or action.choices is None:
            typo = self._unknown_flag()
            if typo is None:
                return message
            given, meant = typo  # named, when argparse's message does not ("required: --out")
            return f"{message} ({'' if given in message else given + ': '}did you mean {meant}?)"
        value = ast.literal_eval(found[2])
        choices = [str(choice) for choice in action.choices]
        close = difflib.get_close_matches(value, choices, n=1)
        hint = f" (did you mean {close[0]}?)" if close else f": choose from {', '.join(choices)}"
        if isinstance(action, argparse._SubParsersAction):
            return f"unknown command {value!r}{hint}"
        return f"argument {found[1]}: invalid choice {value!r}{hint}"

    def _unknown_flag(self) -> tuple[str, str] | None:
        """The first ``--flag`` given that this parser does not know, and its
        closest known flag; None when there is none close."""
        flags = [flag for action in self._actions for flag in action.option_strings]
        for arg in self._given:
            if arg == "--":
                return None
            given = arg.split("=", 1)[0]
            if not given.startswith("--") or given in flags or any(f.startswith(given) for f in flags):
                continue  # a value, a known flag, or an abbreviation argparse accepts
            close = difflib.get_close_matches(given, flags, n=1)
            return (given, close[0]) if close else None
        return None


def _name(action: argparse.Action) -> str | None:
    """How argparse names an action in its messages: its flags, or its metavar or dest."""
    if action.option_strings:
        return "/".join(action.option_strings)
    if action.metavar not in (None, argparse.SUPPRESS):
        return str(action.metavar)
    return action.dest if action.dest is not argparse.SUPPRESS else None
