"""Reading QuantumLeap's tables over the PostgreSQL protocol (psycopg).

One reader for both of QuantumLeap's backends: TimescaleDB/PostgreSQL, and
CrateDB, which speaks the same wire protocol (port 5432). What differs is
small and lives in ``rows.Dialect``: the schema of a table without a tenant
(``public`` / ``doc``) and how a few types come back (see ``rows``).

Only SQL both understand is used: ``information_schema``, ``count(*)``,
``ORDER BY``/``LIMIT``, bound parameters. Identifiers are QuantumLeap's own
names from ``md_ets_metadata`` and ``information_schema``, entered through
``quote_ident``; every value (dates, the time to page from) is a bound
parameter. Rows are read in pages ordered by ``time_index`` and cut at a
change of ``time_index``, so a page never splits the rows of one instant
(what the importer commits and resumes by) and no server-side cursor is
needed (CrateDB before 5.1 has none).
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
    TableMeta,
    table_meta,
)
from tsdb_service.storage.sql.dialect import quote_ident

CONNECT_TIMEOUT_S = 10
PAGE_ROWS = 5_000


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
        in (tenant, table) order. ``SourceUnavailable`` if there is no
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
        metas = [table_meta(r["table_name"], r["entity_attrs"], self.dialect) for r in rows]
        return sorted(
            (m for m in metas if m is not None and (m.schema, m.table) in existing),
            key=lambda m: (m.tenant, m.table),
        )

    def columns(self, meta: TableMeta) -> list[str]:
        """The table's columns, as they are (QuantumLeap adds one per new attribute)."""
        rows = self._fetch(
            "SELECT column_name FROM information_schema.columns WHERE table_schema = %s AND table_name = %s",
            [meta.schema, meta.table],
        )
        return sorted(r["column_name"] for r in rows)

    def count(self, meta: TableMeta, window: Window) -> int:
        where, params = window.where()
        row = self._fetch(f"SELECT count(*) AS n FROM {self._name(meta)}{where}", params)
        return int(row[0]["n"])

    def pages(
        self, meta: TableMeta, columns: Sequence[str], window: Window, page_rows: int = PAGE_ROWS
    ) -> Iterator[list[dict[str, Any]]]:
        """The rows in ``window``, in ``time_index`` order, in pages that never
        split one ``time_index``'s rows."""
        select = ", ".join(quote_ident(c) for c in columns)
        after: datetime | None = None
        while True:
            where, params = window.where(*((f"{TIME_INDEX} > %s", [after]) if after is not None else ()))
            rows = self._fetch(
                f"SELECT {select} FROM {self._name(meta)}{where} ORDER BY {TIME_INDEX} LIMIT {int(page_rows)}",
                params,
            )
            if len(rows) < page_rows:
                if rows:
                    yield rows
                return
            last = rows[-1][TIME_INDEX]
            head = [r for r in rows if r[TIME_INDEX] != last]
            if not head:  # one instant fills the page: read all of it
                where, params = window.where(f"{TIME_INDEX} = %s", [last])
                head = self._fetch(f"SELECT {select} FROM {self._name(meta)}{where}", params)
                after = last
            else:
                after = head[-1][TIME_INDEX]
            yield head

    def _name(self, meta: TableMeta) -> str:
        return f"{quote_ident(meta.schema)}.{quote_ident(meta.table)}"
