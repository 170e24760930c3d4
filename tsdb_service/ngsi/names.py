"""Attribute names: the one rule, for ingest and for every query parser.

"Store what you accept, accept what you can serve": an attribute name the
ingest stores must be one every endpoint can be asked for, so the same rule
runs on both sides. A name is 1 to 256 characters (Orion's limit) without

* Orion's forbidden characters ``< > " ' = ;`` and ``( )``: Orion refuses
  them, and ``(`` opens a value path (``odom(twist.linear.x)``);
* ``,``: it separates the names of an ``attrs=`` list;
* white space (anywhere: leading and trailing white space would be lost
  from ``attrs=`` items, and Orion refuses it too) and control characters.

Everything else is kept: unicode letters, and NGSI-LD names that are IRIs
(``https://example.org/ns#speed``, ``ex:speed``). A name with ``/`` is stored
and reachable through ``attrs=`` lists and ``POST /v2/op/query``, but not yet
as one URL path segment (``/attrs/{name}``), where ``/`` splits the path.
"""

from __future__ import annotations

import re

MAX_NAME_CHARS = 256
FORBIDDEN = "<>\"'=;(),"
RULE = (
    f"attribute names are 1 to {MAX_NAME_CHARS} characters, without white space, "
    "control characters or any of the characters <>\"'=;(),"
)

_BAD = re.compile(r"[\s<>\"'=;(),\x00-\x1f\x7f-\x9f]")

# Names already found valid: a notification repeats the same few names, so
# the hot path pays a set lookup instead of a regex scan. Bounded: a sender
# inventing names cannot make it grow without limit.
_VALID: set[str] = set()
_VALID_MAX = 65_536


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot be an attribute name, or None when it can."""
    if name in _VALID:
        return None
    if not name:
        return "is empty"
    if len(name) > MAX_NAME_CHARS:
        return f"is {len(name)} characters long (at most {MAX_NAME_CHARS})"
    bad = _BAD.search(name)
    if bad is not None:
        return f"contains {_describe(bad.group())}"
    if len(_VALID) >= _VALID_MAX:
        _VALID.clear()
    _VALID.add(name)
    return None


def _describe(char: str) -> str:
    if char.isspace():
        return f"white space ({char!r})"
    if char in FORBIDDEN:
        return repr(char)
    return f"the control character U+{ord(char):04X}"
