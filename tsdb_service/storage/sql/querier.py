"""The SQL querier: every read of the seam, for any backend with a ``SqlDialect``.

Each role is rendered in its own module (``series``, ``samples``,
``aggregate``, ``locations``, ``instances``, ``bulk``, ``buckets``); a backend subclasses
``SqlQuerier``, gives it a connection (``_fetch``, ``_batches``) and
overrides what it answers faster (DuckDB from memory, PostgreSQL by index).
Every query filters samples by series id first (``sid = ?`` or
``sid IN (...)``): the sample tables are sorted by (sid, t), so that filter
is what prunes them.
"""

from __future__ import annotations

from tsdb_service.read import Querier
from tsdb_service.storage.sql.aggregate import SqlAggregates
from tsdb_service.storage.sql.buckets import SqlBuckets
from tsdb_service.storage.sql.bulk import SqlBulk
from tsdb_service.storage.sql.instances import SqlInstances
from tsdb_service.storage.sql.locations import SqlLocations
from tsdb_service.storage.sql.samples import SqlSamples
from tsdb_service.storage.sql.series import SqlSeries


class SqlQuerier(SqlSeries, SqlSamples, SqlAggregates, SqlLocations, SqlInstances, SqlBulk, SqlBuckets, Querier):
    """Every read, on the backend's connection."""
