"""The NGSI-LD query language (``q``, ETSI GS CIM 009 clause 4.9) as a frozen AST.

``parse(text)`` turns ``q`` into nested ``And``/``Or`` nodes over ``Term``s;
``evaluate(node, holds)`` folds it with a caller's idea of when one term
holds. The temporal API gives terms their meaning over a time window (a
term holds when *some* instance of its attribute in the window satisfies
it, see ``ngsild.query``); ``Term.matches(value)`` is the comparison itself.

Grammar (clause 4.9, with ``;`` binding tighter than ``|``)::

    query   = and *("|" and)
    and     = atom *(";" atom)
    atom    = "(" query ")" / "!" path / term
    term    = path [op value]
    path    = name *("." name) *("[" member *("." member) "]")
    member  = name / "*"
    op      = "==" / "!=" / ">=" / ">" / "<=" / "<" / "~=" / "!~="
    value   = number / quoted string / date-time / true / false / URI
            / value "," value ... (a list, == and != only)
            / comparable ".." comparable (a range, == and != only)

``a.b`` names sub-property ``b`` of attribute ``a``; ``a[k.l]`` (or
``a[k][l]``) the member ``k.l`` inside ``a``'s value: for a
LanguageProperty ``name[en]`` is its English string, ``name[*]`` any of
its strings (clause 4.9); ``*`` is any member of an object, every element
of an array. ``!a`` holds when ``a`` does not (the attribute has no
value). Attribute names are terms, expanded with the request's @context by
the caller (``Term.attr``).

A value that is an array matches a term when one of its elements does;
``!=`` and ``!~=`` against an array hold only when no element is equal (or
matches). Linked-entity projection (``owner{name}``, V1.9.1's linked-entity
retrieval) is not part of the temporal API's ``q``: it is refused.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from typing import Any

from tsdb_service.core.errors import BadRequest
from tsdb_service.core.idpattern import compile_pattern

MAX_Q_LENGTH = 4096
MAX_DEPTH = 32
OPERATORS = ("==", "!=", ">=", ">", "<=", "<", "~=", "!~=")
_NUMBER = re.compile(r"-?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?$")
_DATETIME = re.compile(r"\d{4}-\d{2}-\d{2}(?:T\d{2}:\d{2}(?::\d{2}(?:\.\d+)?)?(?:Z|[+-]\d{2}:?\d{2})?)?$")
_NAME_STOP = set(';|()[].=!<>~",{}*') | {" "}


class QueryError(ValueError):
    """``q`` is not valid; the message says where and why."""


@dataclass(frozen=True, slots=True)
class Range:
    low: Any
    high: Any


@dataclass(frozen=True, slots=True)
class Term:
    """``attr`` (expanded by the caller), ``sub`` a sub-property path,
    ``inner`` a path inside the value; ``op``/``value`` None tests existence."""

    attr: str
    sub: tuple[str, ...] = ()
    inner: tuple[str, ...] = ()
    op: str | None = None
    value: Any = None  # a scalar, a tuple (value list), a Range, or a compiled RE2 regex

    def matches(self, value: Any) -> bool:
        """Does one instance value (already reduced along ``sub``/``inner``) satisfy the term?"""
        if self.op is None:
            return value is not None
        if value is None:
            return False
        if isinstance(value, list):  # an array matches when one of its elements does;
            if self.op in NEGATIONS:  # != (!~=) holds when none is equal (matches)
                return all(self.matches(v) for v in value)
            return any(self.matches(v) for v in value)
        op = self.op
        if op in ("~=", "!~="):
            found = isinstance(value, str) and self.value.search(value) is not None
            return found if op == "~=" else not found
        if isinstance(self.value, tuple):
            hit = any(_equal(value, v) for v in self.value)
            return hit if op == "==" else not hit
        if isinstance(self.value, Range):
            inside = _compare(value, self.value.low, ">=") and _compare(value, self.value.high, "<=")
            return inside if op == "==" else not inside
        if op == "==":
            return _equal(value, self.value)
        if op == "!=":
            return not _equal(value, self.value)
        return _compare(value, self.value, op)


@dataclass(frozen=True, slots=True)
class And:
    parts: tuple[Node, ...]


@dataclass(frozen=True, slots=True)
class Or:
    parts: tuple[Node, ...]


@dataclass(frozen=True, slots=True)
class Not:
    """``!a``: the term (an existence test) does not hold."""

    part: Term


Node = Term | And | Or | Not
NEGATIONS = ("!=", "!~=")
ORDERING = (">", ">=", "<", "<=")


def terms(node: Node) -> list[Term]:
    """Every term of ``node``, left to right."""
    if isinstance(node, Term):
        return [node]
    if isinstance(node, Not):
        return [node.part]
    return [t for part in node.parts for t in terms(part)]


def negates(node: Node) -> bool:
    """Does ``node`` hold anywhere through a ``!``? (Then it may hold
    without any instance of its attributes.)"""
    if isinstance(node, Term):
        return False
    if isinstance(node, Not):
        return True
    return any(negates(part) for part in node.parts)


def evaluate(node: Node, holds: Callable[[Term], bool]) -> bool:
    if isinstance(node, Term):
        return holds(node)
    if isinstance(node, Not):
        return not holds(node.part)
    if isinstance(node, And):
        return all(evaluate(p, holds) for p in node.parts)
    return any(evaluate(p, holds) for p in node.parts)


def map_attrs(node: Node, expand: Callable[[str], str]) -> Node:
    """``node`` with every term's attribute name passed through ``expand``."""
    if isinstance(node, Term):
        return replace(node, attr=expand(node.attr))
    if isinstance(node, Not):
        return Not(replace(node.part, attr=expand(node.part.attr)))
    return type(node)(tuple(map_attrs(p, expand) for p in node.parts))


def parse(text: str) -> Node:
    if not text or not text.strip():
        raise QueryError("q is empty")
    if len(text) > MAX_Q_LENGTH:
        raise QueryError(f"q is longer than {MAX_Q_LENGTH} characters")
    parser = _Parser(text)
    node = parser.query(0)
    if parser.pos != len(text):
        raise QueryError(f"unexpected {text[parser.pos : parser.pos + 20]!r} at position {parser.pos}")
    return node


class _Parser:
    def __init__(self, text: str):
        self.text = text
        self.pos = 0

    def peek(self, token: str) -> bool:
        return self.text.startswith(token, self.pos)

    def query(self, depth: int) -> Node:
        if depth > MAX_DEPTH:
            raise QueryError(f"q nests deeper than {MAX_DEPTH} levels")
        parts = [self.conjunction(depth)]
        while self.peek("|"):
            self.pos += 1
            parts.append(self.conjunction(depth))
        return parts[0] if len(parts) == 1 else Or(tuple(parts))

    def conjunction(self, depth: int) -> Node:
        parts = [self.atom(depth)]
        while self.peek(";"):
            self.pos += 1
            parts.append(self.atom(depth))
        return parts[0] if len(parts) == 1 else And(tuple(parts))

    def atom(self, depth: int) -> Node:
        if self.peek("("):
            self.pos += 1
            node = self.query(depth + 1)
            if not self.peek(")"):
                raise QueryError(f"missing ')' at position {self.pos}")
            self.pos += 1
            return node
        if self.peek("!"):
            self.pos += 1
            where = self.pos
            negated = self.term()
            if negated.op is not None:
                raise QueryError(f"'!' at position {where - 1} negates an attribute's existence only (!attr)")
            return Not(negated)
        return self.term()

    def term(self) -> Term:
        start = self.pos
        names = [self.name()]
        while self.peek("."):
            self.pos += 1
            names.append(self.name())
        inner: list[str] = []
        while self.peek("["):
            self.pos += 1
            inner.append(self.member())
            while self.peek("."):
                self.pos += 1
                inner.append(self.member())
            if not self.peek("]"):
                raise QueryError(f"missing ']' at position {self.pos}")
            self.pos += 1
        if self.peek("{"):
            raise QueryError(
                f"linked-entity projection ({{...}}, at position {self.pos}) is not supported by the temporal API"
            )
        op = next((o for o in sorted(OPERATORS, key=len, reverse=True) if self.peek(o)), None)
        if op is None:
            return Term(names[0], tuple(names[1:]), tuple(inner))
        self.pos += len(op)
        raw = self.value_text()
        if not raw:
            raise QueryError(f"missing value after {op!r} at position {self.pos}")
        return Term(names[0], tuple(names[1:]), tuple(inner), op, _value(op, raw, start))

    def member(self) -> str:
        """A member name inside ``[...]``, or ``*``: any member."""
        if self.peek("*"):
            self.pos += 1
            return "*"
        return self.name()

    def name(self) -> str:
        start = self.pos
        while self.pos < len(self.text) and self.text[self.pos] not in _NAME_STOP:
            # an IRI's ':' and '/' are part of the name ("https://x.org/ns#a")
            self.pos += 1
        if self.pos == start:
            raise QueryError(f"expected an attribute name at position {start}")
        return self.text[start : self.pos]

    def value_text(self) -> str:
        """The raw value up to the next logical operator or closing parenthesis
        outside a quoted string."""
        start = self.pos
        quoted = False
        while self.pos < len(self.text):
            ch = self.text[self.pos]
            if ch == '"':
                quoted = not quoted
            elif ch == "\\" and quoted:
                self.pos += 1
            elif not quoted and ch in ";|)":
                break
            self.pos += 1
        if quoted:
            raise QueryError(f"unterminated string at position {start}")
        return self.text[start : self.pos]


def _value(op: str, raw: str, where: int) -> Any:
    if op in ("~=", "!~="):
        pattern = _string(raw) if raw.startswith('"') else raw
        try:  # RE2, as idPattern: linear time whatever the pattern (core.idpattern)
            return compile_pattern(pattern, f"the regular expression after {op!r} at position {where}")
        except BadRequest as exc:
            raise QueryError(exc.description) from None
    items = _split_list(raw)
    if len(items) > 1:
        if op not in ("==", "!="):
            raise QueryError(f"a value list needs == or !=, not {op!r}")
        return tuple(_scalar(item) for item in items)
    if ".." in raw and not raw.startswith('"'):
        if op not in ("==", "!="):
            raise QueryError(f"a range needs == or !=, not {op!r}")
        low, _, high = raw.partition("..")
        return Range(_scalar(low), _scalar(high))
    value = _scalar(raw)
    if op not in ("==", "!=") and isinstance(value, bool):
        raise QueryError(f"{op!r} cannot compare booleans")
    return value


def _split_list(raw: str) -> list[str]:
    items: list[str] = []
    current: list[str] = []
    quoted = False
    for ch in raw:
        if ch == '"':
            quoted = not quoted
        if ch == "," and not quoted:
            items.append("".join(current))
            current = []
            continue
        current.append(ch)
    items.append("".join(current))
    return items


def _scalar(raw: str) -> Any:
    """A JSON-ish literal: number, quoted string, true/false, date-time; any
    other bare word is a URI or plain text compared as a string."""
    text = raw.strip()
    if not text:
        raise QueryError("empty value")
    if text.startswith('"'):
        return _string(text)
    if text in ("true", "false"):
        return text == "true"
    if _NUMBER.match(text):
        number = float(text)
        return int(number) if number.is_integer() and re.fullmatch(r"-?\d+", text) else number
    if _DATETIME.match(text):
        moment = parse_datetime(text)
        if moment is not None:
            return moment
    return text


def _string(text: str) -> str:
    if len(text) < 2 or not text.endswith('"'):
        raise QueryError(f"unterminated string {text[:40]!r}")
    return text[1:-1].replace('\\"', '"')


def parse_datetime(text: str) -> datetime | None:
    try:
        moment = datetime.fromisoformat(text)
    except ValueError:
        return None
    return moment.replace(tzinfo=UTC) if moment.tzinfo is None else moment.astimezone(UTC)


def _coerce(value: Any, like: Any) -> Any:
    """Stored DateTimes are ISO text: compare them as times against a time."""
    if isinstance(like, datetime) and isinstance(value, str):
        return parse_datetime(value)
    return value


def _equal(value: Any, wanted: Any) -> bool:
    value = _coerce(value, wanted)
    if isinstance(wanted, bool) or isinstance(value, bool):
        return type(value) is type(wanted) and value == wanted
    return value == wanted


def _compare(value: Any, wanted: Any, op: str) -> bool:
    value = _coerce(value, wanted)
    if not _comparable(value, wanted):
        return False
    if op == ">":
        return value > wanted
    if op == ">=":
        return value >= wanted
    if op == "<":
        return value < wanted
    return value <= wanted


def _comparable(value: Any, wanted: Any) -> bool:
    """Only numbers with numbers, text with text and times with times have an
    order (a boolean has none)."""
    if isinstance(value, bool) or isinstance(wanted, bool):
        return False
    numeric = (int, float)
    return (
        (isinstance(value, numeric) and isinstance(wanted, numeric))
        or (isinstance(value, str) and isinstance(wanted, str))
        or (isinstance(value, datetime) and isinstance(wanted, datetime))
    )
