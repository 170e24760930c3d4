"""Value paths: reaching inside structured attribute values.

Syntax: ``attr(step.step[n].step)``. The attribute name comes first, the
path inside the value goes in parentheses: object keys separated by ``.``,
array indices as ``[n]``. NGSIv2 forbids ``(`` and ``)`` in attribute names,
so a value path can never be mistaken for an attribute: ``odom`` is the
whole attribute, ``odom(twist.twist.linear.x)`` one number inside it.

Keys may use any character except ``. , [ ] ( ) < > " ' = ;`` and white space
(the grammar is ``core.valuesteps``'s, shared with the time index and imports).
Attribute names follow the one rule of ``tsdb_service.parse.names``, the
same the ingest applies, so every stored name can be asked for.
"""

from __future__ import annotations

from tsdb_service.core.errors import BadRequest
from tsdb_service.core.query import ValuePath
from tsdb_service.core.valuesteps import extract, split_value_path
from tsdb_service.parse.names import name_problem

__all__ = ["extract", "parse_attr_list", "parse_value_path"]


def parse_value_path(text: str) -> ValuePath:
    """``"odom(twist.linear.x)"`` → ``ValuePath("odom", ("twist", "linear", "x"))``."""
    open_at = text.find("(")
    attr = text if open_at < 0 else text[:open_at]
    if name_problem(attr) is not None:
        where = "" if open_at < 0 else f" in value path {text[:80]!r}"
        raise BadRequest(f"invalid attribute name {attr[:80]!r}{where}")
    try:
        attr, steps = split_value_path(text)  # the one grammar (core.valuesteps)
    except ValueError as exc:
        raise BadRequest(str(exc)) from None
    return ValuePath(attr, steps)


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
