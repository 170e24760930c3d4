"""Value paths: reaching inside structured attribute values.

Syntax: ``attr(step.step[n].step)``. The attribute name comes first, the
path inside the value goes in parentheses: object keys separated by ``.``,
array indices as ``[n]``. NGSIv2 forbids ``(`` and ``)`` in attribute names,
so a value path can never be mistaken for an attribute: ``odom`` is the
whole attribute, ``odom(twist.twist.linear.x)`` one number inside it.

Keys may use any character except ``. , [ ] ( ) < > " ' = ;`` and white space.
Attribute names follow the one rule of ``tsdb_service.parse.names``, the
same the ingest applies, so every stored name can be asked for.
"""

from __future__ import annotations

import re

from tsdb_service.core.errors import BadRequest
from tsdb_service.core.query import ValuePath
from tsdb_service.parse.names import name_problem

_KEY = r"""[^\s.,\[\]()<>"'=;]+"""
_STEP = re.compile(rf"\.?({_KEY})|\[(\d{{1,9}})\]")
_MAX_STEPS = 32


def parse_value_path(text: str) -> ValuePath:
    """``"odom(twist.linear.x)"`` → ``ValuePath("odom", ("twist", "linear", "x"))``."""
    open_at = text.find("(")
    if open_at < 0:
        if name_problem(text) is not None:
            raise BadRequest(f"invalid attribute name {text[:80]!r}")
        return ValuePath(text)
    attr, inner = text[:open_at], text[open_at + 1 :]
    if name_problem(attr) is not None:
        raise BadRequest(f"invalid attribute name {attr[:80]!r} in value path {text[:80]!r}")
    if not inner.endswith(")") or not inner[:-1]:
        raise BadRequest(f"invalid value path {text[:80]!r}: expected attr(key.key[0]...)")
    return ValuePath(attr, _steps(inner[:-1], text))


def _steps(path: str, text: str) -> tuple[str | int, ...]:
    steps: list[str | int] = []
    pos = 0
    while pos < len(path):
        match = _STEP.match(path, pos)
        # A leading "." or a "." right after nothing is not allowed.
        if match is None or (pos == 0 and path[0] == "."):
            raise BadRequest(f"invalid value path {text[:80]!r} at {path[pos : pos + 20]!r}")
        if match.group(1) is not None:
            if pos > 0 and path[pos] != ".":
                raise BadRequest(f"invalid value path {text[:80]!r}: keys must be separated by '.'")
            steps.append(match.group(1))
        else:
            steps.append(int(match.group(2)))
        pos = match.end()
        if len(steps) > _MAX_STEPS:
            raise BadRequest(f"value path {text[:80]!r} is deeper than {_MAX_STEPS} steps")
    return tuple(steps)


def parse_attr_list(raw: str | None) -> tuple[ValuePath, ...] | None:
    """``attrs=a,b(c.d)`` → value paths, duplicates dropped, order kept."""
    if raw is None:
        return None
    items = [part.strip() for part in raw.split(",")]
    items = [part for part in items if part]
    if not items:
        return None
    seen: dict[ValuePath, None] = {}
    for item in items:
        seen.setdefault(parse_value_path(item), None)
    return tuple(seen)


_MISSING = object()


def extract(value: object, steps: tuple[str | int, ...]) -> object:
    """Follow ``steps`` into a decoded JSON value; ``None`` where it leads nowhere."""
    for step in steps:
        if isinstance(step, int):
            if type(value) is list and step < len(value):
                value = value[step]
                continue
            return None
        if type(value) is dict:
            value = value.get(step, _MISSING)
            if value is _MISSING:
                return None
            continue
        return None
    return value
