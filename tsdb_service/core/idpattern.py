"""Entity-id regular expressions (``idPattern``, Grafana ad hoc ``=~``), in RE2.

Python's ``re`` backtracks: a pattern such as ``^(.|.)*$!`` takes
exponential time in the length of the id it is tried on, and the catalog
matches ``idPattern`` against every entity id of a tenant, on the event loop
when the answer comes from memory. One such request froze every client,
ingest included. RE2 (Google's engine, the ``google-re2`` wheel) runs in
time linear in the id's length whatever the pattern, so no pattern can cost
more than a scan of the ids. The price is RE2's syntax: no backreferences
(``\\1``) and no lookaround (``(?=``, ``(?!``, ``(?<=``, ``(?<!``); a pattern
using them is refused with a 400 that says so.

Every ``idPattern`` a request carries (history, export, op/query, Grafana,
NGSI-LD) is validated by ``parse.request_context.id_pattern``, which calls
``compile_pattern`` (answers 400); matching uses ``compiled`` on an already
validated pattern (Grafana's ad hoc ``=~`` filters call both directly), so
there is one engine and one rule everywhere.
"""

from __future__ import annotations

from functools import lru_cache

import re2

from tsdb_service.core.errors import BadRequest

MAX_PATTERN = 512
SYNTAX = "RE2 syntax (https://github.com/google/re2/wiki/Syntax): no backreferences or lookaround"

_OPTIONS = re2.Options()
_OPTIONS.log_errors = False  # a client's bad pattern is a 400, not a line on stderr


@lru_cache(maxsize=512)
def _compile(pattern: str):
    return re2.compile(pattern, options=_OPTIONS)


def compile_pattern(raw: str, name: str = "idPattern"):
    """``raw`` compiled by RE2, or a 400 naming ``name`` and the syntax used."""
    if len(raw) > MAX_PATTERN:
        raise BadRequest(f"{name} is longer than {MAX_PATTERN} characters")
    try:
        return _compile(raw)
    except re2.error as exc:
        reason = exc.args[0].decode(errors="replace") if exc.args and isinstance(exc.args[0], bytes) else str(exc)
        raise BadRequest(f"{name} is not a valid regular expression ({reason}); {SYNTAX}") from None


def compiled(pattern: str):
    """An already validated pattern, compiled (cached): for matching."""
    return _compile(pattern)
