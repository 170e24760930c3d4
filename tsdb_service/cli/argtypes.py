"""Types of the commands' own flags (``--batch-samples``, ``--speedup``, ...).

Each raises ``argparse.ArgumentTypeError`` with a message that names the
value and what to give instead. A plain ``ValueError`` would make argparse
print the function's name ("invalid _positive_int value: 'abc'"). Times
(``utc_time``) are read after parsing, naming their flag in one
``SettingsError`` line.
"""

from __future__ import annotations

import argparse
import math
from datetime import UTC, datetime

from tsdb_service.core.config import SettingsError
from tsdb_service.parse.timeindex import parse_time


def positive_int(text: str) -> int:
    """A whole number of at least 1 (a count)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number: give 1 or more") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} is too small: give 1 or more")
    return value


def positive_number(text: str) -> float:
    """A finite number above 0 (a rate, a duration)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number: give one above 0, e.g. 2 or 0.5") from None
    if not value > 0 or math.isinf(value):
        raise argparse.ArgumentTypeError(f"{text!r}: give a finite number above 0, e.g. 2 or 0.5")
    return value


def integer(text: str) -> int:
    """Any whole number (a seed)."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number, e.g. 42") from None


def port(text: str) -> int:
    """A TCP port, 1-65535."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port: give 1-65535") from None
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{value} is not a port: give 1-65535")
    return value


def utc_time(text: str | None, flag: str) -> datetime | None:
    """An ISO 8601 time a flag gave, in UTC (None when not given)."""
    if text is None:
        return None
    moment = parse_time(text)
    if moment is None:
        raise SettingsError(f"{flag}: {text!r} is not an ISO 8601 time (e.g. 2024-05-01T00:00:00Z)")
    return moment.astimezone(UTC)
