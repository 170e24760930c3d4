"""Entity scopes (ETSI GS CIM 009 clause 4.18) and ``scopeQ`` (clause 4.19).

A scope is a path of levels, ``/Madrid/Gardens/ParqueNorte``; an entity has
one or several. A temporal write stores the entity's ``scope`` member as
instances of its ``scope`` Property (the core context's term), so the
history keeps it like any attribute.

``scopeQ`` selects entities by scope: a term is a scope in which a level may
be ``+`` (any one level) and that may end in ``/#`` (that scope and every
scope below it; ``/#`` alone: any scope); ``;`` is AND and binds tighter
than ``,`` (OR); parentheses group. An entity satisfies a term when one of
its current scopes (those of its latest ``scope`` instance: what Stellio
matches, the entity's scope now) matches it.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from tsdb_service.core.errors import BadRequestData
from tsdb_service.faces.ngsild import boolexpr

MAX_TERMS = 100
_LEVEL = r"[^/#+,;()\s]{1,256}"
_SCOPE = re.compile(rf"(?:/{_LEVEL})+\Z")
_TERM = re.compile(rf"/#|(?:/(?:{_LEVEL}|\+))+(?:/#)?")


def scopes(value: Any) -> list[str]:
    """The scopes of an entity's ``scope`` member (a string or an array of
    them), each checked; BadRequestData otherwise."""
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not items or len(items) > MAX_TERMS:
        raise BadRequestData("scope must be a scope string (such as /Madrid/Gardens) or a non-empty array of them")
    for item in items:
        if not isinstance(item, str) or not _SCOPE.match(item):
            raise BadRequestData(f"bad scope {str(item)[:80]!r}: a scope is /level/level... (clause 4.18)")
    return items


@dataclass(frozen=True, slots=True)
class Term:
    levels: tuple[str, ...]  # "+" matches any one level
    below: bool  # ends in /#: this scope and every scope below it

    def matches(self, scope: str) -> bool:
        levels = scope.split("/")[1:]
        n = len(self.levels)
        if len(levels) < n or (len(levels) > n and not self.below):
            return False
        return all(want in ("+", have) for want, have in zip(self.levels, levels, strict=False))


ScopeExpr = Term | boolexpr.All | boolexpr.AnyOf


def parse(raw: str) -> ScopeExpr:
    """``scopeQ``; BadRequestData when it is not one."""
    found = boolexpr.tokens(raw, ",", "scopeQ")
    if sum(t not in "(),;" for t in found) > MAX_TERMS:
        raise BadRequestData(f"scopeQ has more than {MAX_TERMS} terms")
    return boolexpr.parse(raw, found, ",", "scopeQ", _term)


def _term(token: str) -> Term:
    if not _TERM.fullmatch(token):
        raise BadRequestData(f"bad scopeQ term {token[:80]!r}: /level/level, + for one level, /# for all below")
    below = token.endswith("/#")
    path = token[:-2] if below else token
    return Term(tuple(path.split("/")[1:]) if path else (), below)


def holds(expr: ScopeExpr, entity_scopes: Iterable[str]) -> bool:
    """Does an entity with these scopes satisfy ``expr``?"""
    have = list(entity_scopes)
    return boolexpr.holds(expr, lambda term: any(term.matches(s) for s in have))
