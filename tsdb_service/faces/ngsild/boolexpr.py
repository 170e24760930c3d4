"""The NGSI-LD expressions that only combine terms with AND and OR: type
expressions (clause 4.17) and ``scopeQ`` (clause 4.19). ``;`` is AND and
binds tighter than OR (``,``, and for types also ``|``); parentheses group.
A term is whatever the caller's ``leaf`` makes of a token.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

from tsdb_service.core.errors import BadRequestData
from tsdb_service.faces.ngsild import qlang

MAX_DEPTH = 16


# The nodes are q's own (``qlang.And``/``qlang.Or``): one shape for every
# AND/OR tree of the API.
All = qlang.And
AnyOf = qlang.Or


def holds(expr: Any, test: Callable[[Any], bool]) -> bool:
    """Does ``expr`` hold, ``test`` deciding each term?"""
    if isinstance(expr, All):
        return all(holds(p, test) for p in expr.parts)
    if isinstance(expr, AnyOf):
        return any(holds(p, test) for p in expr.parts)
    return test(expr)


def leaves(expr: Any) -> list:
    """The terms of ``expr``, left to right."""
    if isinstance(expr, (All, AnyOf)):
        return [leaf for p in expr.parts for leaf in leaves(p)]
    return [expr]


def tokens(raw: str, or_ops: str, what: str) -> list[str]:
    """``raw`` split into operators, parentheses and terms (white space dropped)."""
    ops = re.escape(f"(){or_ops};")
    found = re.findall(rf"\s*([{ops}]|[^{ops}\s]+)", raw)
    if not found or "".join(found) != re.sub(r"\s+", "", raw):
        raise BadRequestData(f"bad {what} {raw[:80]!r}")
    return found


def parse(raw: str, found: list[str], or_ops: str, what: str, leaf: Callable[[str], Any]) -> Any:
    """The expression ``found`` (``tokens(raw, or_ops, what)``) spells;
    BadRequestData naming ``what`` when it spells none."""
    levels = (or_ops, ";")
    pos = 0

    def level(i: int, depth: int) -> Any:
        nonlocal pos
        if i == len(levels):
            return atom(depth)
        parts = [level(i + 1, depth)]
        while pos < len(found) and found[pos] in levels[i]:
            pos += 1
            parts.append(level(i + 1, depth))
        if len(parts) == 1:
            return parts[0]
        return AnyOf(tuple(parts)) if i == 0 else All(tuple(parts))

    def atom(depth: int) -> Any:
        nonlocal pos
        if pos >= len(found):
            raise BadRequestData(f"{what} {raw[:80]!r} ends early")
        token = found[pos]
        pos += 1
        if token == "(":
            if depth >= MAX_DEPTH:
                raise BadRequestData(f"{what} nests too deeply")
            inner = level(0, depth + 1)
            if pos >= len(found) or found[pos] != ")":
                raise BadRequestData(f"missing ')' in {what} {raw[:80]!r}")
            pos += 1
            return inner
        if token in f"(){or_ops};":
            raise BadRequestData(f"unexpected {token!r} in {what} {raw[:80]!r}")
        return leaf(token)

    expr = level(0, 0)
    if pos != len(found):
        raise BadRequestData(f"unexpected {found[pos][:40]!r} in {what} {raw[:80]!r}")
    return expr
