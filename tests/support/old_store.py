"""A store as an older version left it: the migrations before ``version``
applied (and recorded), then rows written straight in SQL, for the tests of
a migration on data from before it."""

from __future__ import annotations

from collections.abc import Sequence

import duckdb
import psycopg

from tsdb_service.storage.migrations import SCHEMA_TABLE, load_migrations, split_statements


def old_store(
    url: str, backend: str, version: int, rows: Sequence[tuple[str, list]] = (), attrs: Sequence[str] = ()
) -> None:
    """Migrate ``url`` up to (not including) ``version``, add the series of
    ``attrs`` (entity ``e`` of type ``T`` in the default tenant, sids from 1),
    then run ``rows``: (SQL with ``{p}`` placeholders, parameters)."""
    old = [m for m in load_migrations(backend) if m.version < version]
    rows = [*_series(backend, attrs), *rows]
    if backend == "duckdb":
        con = duckdb.connect(url)
        try:
            con.execute(SCHEMA_TABLE)
            for m in old:
                for statement in split_statements(m.sql):
                    con.execute(statement)
                con.execute("INSERT INTO schema_migrations (version, name) VALUES (?, ?)", [m.version, m.name])
            for sql, params in rows:
                con.execute(sql.format(p="?"), params)
        finally:
            con.close()
        return
    with psycopg.connect(url) as conn:
        conn.execute(SCHEMA_TABLE)
        for m in old:
            conn.execute(m.sql)
            conn.execute("INSERT INTO schema_migrations (version, name) VALUES (%s, %s)", [m.version, m.name])
        for sql, params in rows:
            conn.execute(sql.format(p="%s"), params)


def _series(backend: str, attrs: Sequence[str]) -> list[tuple[str, list]]:
    if not attrs:
        return []
    values = ", ".join("({p}, '', '/', 'e', 'T', {p})" for _ in attrs)
    params = [v for sid, attr in enumerate(attrs, 1) for v in (sid, attr)]
    out = [(f"INSERT INTO series (sid, tenant, service_path, entity_id, entity_type, attr) VALUES {values}", params)]
    if backend == "postgresql":
        out.append(("SELECT setval(pg_get_serial_sequence('series', 'sid'), {p})", [len(attrs)]))
    return out
