"""Read budgets: what one request may cost before it is refused.

A read used to cost whatever it asked for: a SimpleJSON query with 50
wildcard targets over 100k samples took 36 CPU seconds and 1.2 GB to build a
154 MB answer, and ``/v2/attrs`` over 300k series 10.7 s and 951 MB, while
every other client waited (two cores, one GIL). Each request now carries a
budget, checked once per layer:

* **series**: the series one resolution step selects (``SeriesCatalog.select``);
* **rows**: samples and aggregate rows read from storage, summed over the
  request; reads ask for at most the remaining budget plus one row, so an
  overflow is detected without reading further (``history.service``,
  ``storage.sql``);
* **response bytes**: the rendered answer's size (``http.budget``);
* **wall time**: a deadline checked between steps (series resolution, each
  read, each Grafana target).

Running out is ``422 QueryTooLarge`` in the NGSI shape, saying which limit
and how to narrow the query. Limits come from settings (``TSDB_READ_*``).
The budget rides in a context variable set by the middleware, so layers that
are called outside a request (CLI, tests, copies) run without limits, and it
reaches the threadpool because Starlette copies the context into it.
"""

from __future__ import annotations

import contextvars
import time
from dataclasses import dataclass

from tsdb_service.core.errors import TsdbError

NARROW = (
    "narrow the query: fewer entities (id, type, idPattern) or attributes (attrs), a time window "
    "(fromDate/toDate, or from/to on Grafana), fewer rows (lastN, limit), or aggregation "
    "(aggrMethod/aggrPeriod, or Grafana's downsampling)"
)


class QueryTooLarge(TsdbError):
    """The request would cost more than its budget; the client can narrow it."""

    status = 422
    error = "QueryTooLarge"
    ld_type = "TooComplexQuery"  # on /ngsi-ld/ paths


@dataclass(frozen=True, slots=True)
class ReadLimits:
    max_series: int
    max_rows: int
    max_response_bytes: int
    max_seconds: float

    @classmethod
    def from_settings(cls, settings) -> ReadLimits:
        return cls(
            settings.read_max_series,
            settings.read_max_rows,
            settings.read_max_response_bytes,
            settings.read_max_seconds,
        )


class ReadBudget:
    """One request's allowance; shared by the threads serving that request."""

    __slots__ = ("deadline", "limits", "rows")

    def __init__(self, limits: ReadLimits):
        self.limits = limits
        self.deadline = time.monotonic() + limits.max_seconds
        self.rows = 0

    def check_series(self, n: int) -> None:
        if n > self.limits.max_series:
            raise QueryTooLarge(
                f"this query selects {n} series, more than the {self.limits.max_series} one request may read "
                f"(TSDB_READ_MAX_SERIES); {NARROW}"
            )

    def row_cap(self, limit: int) -> int:
        """``limit``, lowered to one row past what is left of the budget."""
        return max(1, min(limit, self.limits.max_rows - self.rows + 1))

    def charge_rows(self, n: int) -> None:
        self.rows += n
        if self.rows > self.limits.max_rows:
            raise QueryTooLarge(
                f"this query reads more than {self.limits.max_rows} samples or aggregate rows "
                f"(TSDB_READ_MAX_ROWS); {NARROW}"
            )

    def check_time(self) -> None:
        if time.monotonic() > self.deadline:
            raise QueryTooLarge(
                f"this query ran longer than {self.limits.max_seconds:g} s (TSDB_READ_MAX_SECONDS) and was "
                f"stopped; {NARROW}"
            )


_CURRENT: contextvars.ContextVar[ReadBudget | None] = contextvars.ContextVar("tsdb_read_budget", default=None)


def current() -> ReadBudget | None:
    return _CURRENT.get()


def check_series(n: int) -> None:
    """Series selected by one resolution step; also a deadline checkpoint."""
    budget = _CURRENT.get()
    if budget is not None:
        budget.check_time()
        budget.check_series(n)


def row_cap(limit: int) -> int:
    budget = _CURRENT.get()
    return limit if budget is None else budget.row_cap(limit)


def charge_rows(n: int) -> None:
    """Rows just read; also a deadline checkpoint."""
    budget = _CURRENT.get()
    if budget is not None:
        budget.charge_rows(n)
        budget.check_time()


def checkpoint() -> None:
    """Between steps: stop a request that is past its deadline."""
    budget = _CURRENT.get()
    if budget is not None:
        budget.check_time()


def mark() -> int | None:
    """Rows charged so far, to ``rewind`` to when a step is redone (a read
    tried from memory first and re-run in the threadpool)."""
    budget = _CURRENT.get()
    return None if budget is None else budget.rows


def rewind(rows: int | None) -> None:
    budget = _CURRENT.get()
    if budget is not None and rows is not None:
        budget.rows = rows


def begin(limits: ReadLimits) -> contextvars.Token:
    """Give the current context (one request) a fresh budget; ``end`` with the token."""
    return _CURRENT.set(ReadBudget(limits))


def end(token: contextvars.Token) -> None:
    _CURRENT.reset(token)
