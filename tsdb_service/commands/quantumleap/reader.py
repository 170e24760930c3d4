"""Reading QuantumLeap's tables over the PostgreSQL protocol (psycopg).

One reader for both of QuantumLeap's backends: TimescaleDB/PostgreSQL, and
CrateDB, which speaks the same wire protocol (port 5432). What differs is
small and lives in ``rows.Dialect``: the schema of a table without a tenant
(``public`` / ``doc``) and how a few types come back (see ``rows``).

Only SQL both understand is used: ``information_schema``, ``count(*)``,
``ORDER BY``/``LIMIT``, ``CASE``, bound parameters. Identifiers are
QuantumLeap's own names from ``md_ets_metadata`` and
``information_schema``, entered through ``quote_ident``; every value
(dates, the time to page from, the size limit) is a bound parameter. Rows
are read in ``time_index`` order and handed over in pages cut at a change
of ``time_index``, so a page never splits the rows of one instant (what the
importer commits and resumes by).

**Bounded, whatever the tables hold** (a hostile or damaged database must
cost an error line, never the machine):

* a cell larger than ``max_value_bytes`` is never sent: the query answers
  NULL for it and a flag, and the row names it in ``REFUSED_CELLS``;
* on PostgreSQL a time PostgreSQL holds and Python cannot (``infinity``,
  BC dates, years past 9999) is never loaded: a ``time_index`` like that
  (or NULL) leaves its row out of the pages (``untimed`` counts them), a
  time attribute like that is refused as an oversized cell is;
* on PostgreSQL rows come from a server-side cursor, fetched a few at a
  time, as many as fit ``PAGE_BYTES`` judged by the rows fetched so far;
  CrateDB (before 5.1 without cursors) is read in ``LIMIT`` pages.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from tsdb_service.commands.quantumleap.rows import (
    METADATA_TABLE,
    TIME_INDEX,
    Dialect,
    SkippedTable,
    TableMeta,
    table_meta,
)
from tsdb_service.storage.sql.dialect import quote_ident

CONNECT_TIMEOUT_S = 10
PAGE_ROWS = 5_000
PAGE_BYTES = 32 * 1024 * 1024  # what a page of rows may weigh, about (cursor reads)
FIRST_FETCH = 64  # rows of a table's first fetch, before its rows' size is known
MAX_VALUE_BYTES = 9 * 1024 * 1024  # TSDB_MAX_BODY_BYTES' default: no notification could carry more
REFUSED_CELLS = "__tsdb_refused_cells__"  # a row's key: [(column, reason)] of the cells left out
_FLAG = "__tsdb_refused_"
_TIME_TYPES = frozenset({"timestamp with time zone", "timestamp without time zone", "date"})
# Times Python's datetime holds, with a day's margin for time zones.
_TIME_OK = "isfinite({c}) AND {c} >= '0001-01-02' AND {c} < '9999-12-31'"


class SourceUnavailable(RuntimeError):
    """The QuantumLeap database cannot be read; the message is one line."""


@dataclass(frozen=True, slots=True)
class Window:
    """The part of history to import: ``start`` inclusive, ``end`` exclusive."""

    start: datetime | None = None
    end: datetime | None = None

    def where(self, extra: str = "", params: Sequence[Any] = ()) -> tuple[str, list[Any]]:
        clauses, bound = [], []
        if self.start is not None:
            clauses.append(f"{TIME_INDEX} >= %s")
            bound.append(self.start)
        if self.end is not None:
            clauses.append(f"{TIME_INDEX} < %s")
            bound.append(self.end)
        if extra:
            clauses.append(extra)
            bound.extend(params)
        return (" WHERE " + " AND ".join(clauses) if clauses else ""), bound


class QuantumLeapReader:
    """A read-only view of one QuantumLeap database."""

    def __init__(self, url: str):
        import psycopg
        from psycopg.rows import dict_row

        from tsdb_service.storage import redact

        self.where = redact(url)
        try:
            self._conn = psycopg.connect(url, autocommit=True, connect_timeout=CONNECT_TIMEOUT_S, row_factory=dict_row)
        except Exception as exc:  # psycopg's many failures to connect: one line each
            text = " ".join(str(exc).split()).removeprefix("connection failed: ")
            raise SourceUnavailable(f"cannot connect to QuantumLeap's database at {self.where}: {text}") from None
        self.dialect = self._dialect()
        self.skipped: list[SkippedTable] = []  # QuantumLeap's tables ``tables`` found and cannot import

    def close(self) -> None:
        self._conn.close()

    def _fetch(self, sql: str, params: Sequence[Any] = ()) -> list[dict[str, Any]]:
        import psycopg

        try:
            with self._conn.cursor() as cur:
                cur.execute(sql, list(params))  # our own SQL: identifiers quoted, values bound
                return list(cur.fetchall()) if cur.description else []
        except psycopg.Error as exc:  # a lost connection, a table we may not read: one line
            text = " ".join(str(exc).split())
            raise SourceUnavailable(f"reading QuantumLeap's database at {self.where} failed: {text}") from None

    def _dialect(self) -> Dialect:
        """CrateDB names itself in ``version()``; ``tables`` also tells it by its ``doc`` schema."""
        try:
            row = self._fetch("SELECT version() AS v")
        except SourceUnavailable:
            return Dialect.POSTGRESQL
        return Dialect.CRATE if "crate" in str(row[0]["v"]).lower() else Dialect.POSTGRESQL

    def tables(self) -> list[TableMeta]:
        """Every QuantumLeap table whose metadata and data table both exist,
        in (tenant, table) order; those that cannot be imported go to
        ``skipped``. ``SourceUnavailable`` if there is no
        ``md_ets_metadata``: then this is no QuantumLeap database."""
        found = self._fetch(
            "SELECT table_schema FROM information_schema.tables WHERE table_name = %s", [METADATA_TABLE]
        )
        schemas = [r["table_schema"] for r in found]
        if not schemas:
            raise SourceUnavailable(
                f"{self.where} holds no QuantumLeap tables (no {METADATA_TABLE} table): "
                "give the database QuantumLeap writes to"
            )
        if "doc" in schemas and "public" not in schemas:
            self.dialect = Dialect.CRATE  # whatever version() said: only CrateDB has a schema "doc" by default
        schema = self.dialect.default_schema if self.dialect.default_schema in schemas else schemas[0]
        rows = self._fetch(f"SELECT table_name, entity_attrs FROM {quote_ident(schema)}.{quote_ident(METADATA_TABLE)}")
        existing = {
            (r["table_schema"], r["table_name"])
            for r in self._fetch("SELECT table_schema, table_name FROM information_schema.tables")
        }
        if rows and not {"table_name", "entity_attrs"} <= set(rows[0]):
            raise SourceUnavailable(
                f"{self.where}: {METADATA_TABLE} has no table_name and entity_attrs columns: not QuantumLeap's"
            )
        metas, self.skipped = [], []
        for r in rows:
            meta = table_meta(r["table_name"], r["entity_attrs"], self.dialect)
            if isinstance(meta, SkippedTable):
                self.skipped.append(meta)
            elif meta is not None and (meta.schema, meta.table) in existing:
                metas.append(meta)
        self.skipped.sort(key=lambda m: m.name)
        return sorted(metas, key=lambda m: (m.tenant, m.table))

    def columns(self, meta: TableMeta) -> list[str]:
        """The table's columns, as they are (QuantumLeap adds one per new attribute)."""
        return sorted(self.column_types(meta))

    def column_types(self, meta: TableMeta) -> dict[str, str]:
        """The table's columns → their ``information_schema`` data type."""
        rows = self._fetch(
            "SELECT column_name, data_type FROM information_schema.columns WHERE table_schema = %s AND table_name = %s",
            [meta.schema, meta.table],
        )
        return {r["column_name"]: str(r["data_type"]).lower() for r in rows}

    def count(self, meta: TableMeta, window: Window) -> int:
        where, params = window.where()
        row = self._fetch(f"SELECT count(*) AS n FROM {self._name(meta)}{where}", params)
        return int(row[0]["n"])

    def untimed(self, meta: TableMeta, window: Window) -> int:
        """Rows of ``window`` (all of them: no window) left out of the pages
        for want of a usable ``time_index``: NULL, and on PostgreSQL
        ``infinity`` or a year Python cannot hold."""
        where, params = window.where(f"NOT ({self._timed()})")
        row = self._fetch(f"SELECT count(*) AS n FROM {self._name(meta)}{where}", params)
        return int(row[0]["n"])

    def _timed(self) -> str:
        """The rows that have a usable time index."""
        if self.dialect is Dialect.CRATE:
            return f"{TIME_INDEX} IS NOT NULL"
        return f"{TIME_INDEX} IS NOT NULL AND " + _TIME_OK.format(c=TIME_INDEX)

    def pages(
        self,
        meta: TableMeta,
        columns: Sequence[str],
        window: Window,
        page_rows: int = PAGE_ROWS,
        max_value_bytes: int = MAX_VALUE_BYTES,
    ) -> Iterator[list[dict[str, Any]]]:
        """The rows in ``window`` with a usable ``time_index``, in
        ``time_index`` order, in pages that never split one ``time_index``'s
        rows; a cell left out (too large, a time Python cannot hold) is
        NULL, and named in the row's ``REFUSED_CELLS``."""
        select, select_params, flags = self._select(meta, columns, max_value_bytes)
        if self.dialect is Dialect.POSTGRESQL:
            where, params = window.where(self._timed())
            sql = f"SELECT {select} FROM {self._name(meta)}{where} ORDER BY {TIME_INDEX}"
            pages = self._cursor_pages(sql, [*select_params, *params], page_rows)
        else:
            pages = self._limit_pages(meta, select, select_params, window, page_rows)
        for page in pages:
            yield _flagged(page, flags) if flags else page

    def _select(
        self, meta: TableMeta, columns: Sequence[str], max_value_bytes: int
    ) -> tuple[str, list[Any], list[tuple[str, str, str]]]:
        """The select list: each column, NULL where it is left out, plus one
        flag per guarded column; (sql, params, [(flag, column, reason)])."""
        types = self.column_types(meta)
        parts: list[str] = []
        params: list[Any] = []
        flags: list[tuple[str, str, str]] = []
        too_large = f"larger than {max_value_bytes} bytes"
        for i, column in enumerate(columns):
            c = quote_ident(column)
            kind = types.get(column, "")
            if column == TIME_INDEX:
                parts.append(c)
                continue
            if kind in _TIME_TYPES and self.dialect is Dialect.POSTGRESQL:
                ok, ok_params, why = _TIME_OK.format(c=c), [], "a time outside the years 1 to 9999 (or infinity)"
            elif self.dialect is Dialect.POSTGRESQL or kind in ("text", "string", "character varying"):
                ok, ok_params, why = f"octet_length(CAST({c} AS TEXT)) <= %s", [max_value_bytes], too_large
            else:
                parts.append(c)
                continue
            flag = f"{_FLAG}{i}"
            parts.append(f"CASE WHEN {ok} THEN {c} END AS {c}")
            parts.append(f"({c} IS NOT NULL AND NOT ({ok})) AS {quote_ident(flag)}")
            params += ok_params + ok_params
            flags.append((flag, column, why))
        return ", ".join(parts), params, flags

    def _cursor_pages(self, sql: str, params: list[Any], page_rows: int) -> Iterator[list[dict[str, Any]]]:
        """A server-side cursor (in a transaction of its own), fetched a few
        rows at a time: at most ``page_rows``, fewer when rows are large."""
        import psycopg

        try:
            with self._conn.transaction(), self._conn.cursor(name="tsdb_ql_import") as cur:
                cur.execute(sql, params)
                fetch = min(FIRST_FETCH, page_rows)
                carry: list[dict[str, Any]] = []
                while rows := cur.fetchmany(fetch):
                    fetch = _next_fetch(rows, page_rows)
                    rows = carry + rows
                    cut = len(rows)
                    last = rows[-1][TIME_INDEX]
                    while cut and rows[cut - 1][TIME_INDEX] == last:
                        cut -= 1  # the last instant may go on in the next fetch
                    head, carry = rows[:cut], rows[cut:]
                    if head:
                        yield head
                if carry:
                    yield carry
        except psycopg.Error as exc:
            text = " ".join(str(exc).split())
            raise SourceUnavailable(f"reading QuantumLeap's database at {self.where} failed: {text}") from None

    def _limit_pages(
        self, meta: TableMeta, select: str, select_params: list[Any], window: Window, page_rows: int
    ) -> Iterator[list[dict[str, Any]]]:
        """``LIMIT`` pages from the time after the last one (CrateDB)."""
        after: datetime | None = None
        timed = self._timed()
        while True:
            extra = f"{timed} AND {TIME_INDEX} > %s" if after is not None else timed
            where, params = window.where(extra, [after] if after is not None else [])
            rows = self._fetch(
                f"SELECT {select} FROM {self._name(meta)}{where} ORDER BY {TIME_INDEX} LIMIT {int(page_rows)}",
                [*select_params, *params],
            )
            if len(rows) < page_rows:
                if rows:
                    yield rows
                return
            last = rows[-1][TIME_INDEX]
            head = [r for r in rows if r[TIME_INDEX] != last]
            if not head:  # one instant fills the page: read all of it
                where, params = window.where(f"{TIME_INDEX} = %s", [last])
                head = self._fetch(f"SELECT {select} FROM {self._name(meta)}{where}", [*select_params, *params])
                after = last
            else:
                after = head[-1][TIME_INDEX]
            yield head

    def _name(self, meta: TableMeta) -> str:
        return f"{quote_ident(meta.schema)}.{quote_ident(meta.table)}"


def _flagged(rows: list[dict[str, Any]], flags: list[tuple[str, str, str]]) -> list[dict[str, Any]]:
    """Each row without its flag columns, the cells they flag named in ``REFUSED_CELLS``."""
    for row in rows:
        refused = [(column, why) for flag, column, why in flags if row.pop(flag)]
        if refused:
            row[REFUSED_CELLS] = refused
    return rows


def _next_fetch(rows: list[dict[str, Any]], page_rows: int) -> int:
    """Rows to fetch next so that a fetch weighs about ``PAGE_BYTES``, judged by ``rows``."""
    weight = sum(len(v) if isinstance(v, str | bytes) else 16 for row in rows for v in row.values())
    per_row = max(1, weight // len(rows))
    return max(1, min(page_rows, PAGE_BYTES // per_row))
