"""How one database spells SQL, and the small renderers every read shares.

A ``SqlDialect`` knows how one database spells placeholders, time
truncation, ISO formatting, JSON paths and regular expressions; the readers
of this package render their statements through it. Values are always bound
parameters. The only text put into SQL is our own: identifiers through
``quote_ident`` and aggregation period names from the ``AggrPeriod`` enum.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable, Iterable, Sequence
from datetime import UTC, datetime
from functools import partial
from typing import TypeVar

from tsdb_service.core.model import Kind
from tsdb_service.core.query import WITHIN, Prefilter, RowMask, TimeRange

NUMERIC_KINDS = f"{int(Kind.NUMBER)}, {int(Kind.INTEGER)}"
NULL_KIND = int(Kind.NULL)
INTEGER_KIND = int(Kind.INTEGER)
GEO_KIND = int(Kind.GEO)
MAX_BIGINT = 2**62  # LIMIT/OFFSET values stay well inside int64
T = TypeVar("T", bound=tuple)


def quote_ident(name: str) -> str:
    """The one way an identifier enters SQL."""
    return '"' + name.replace('"', '""') + '"'


class SqlDialect:
    """What differs between DuckDB and PostgreSQL. Subclass per backend."""

    name = "abstract"
    placeholder = "?"
    samples_table = "samples_all"  # every committed sample (a view on DuckDB)
    many_sids = 64  # above this many ids, bind one array instead of a list
    # Ends a subquery whose computed columns are used several times, so that
    # they are computed once a row: PostgreSQL pulls a plain subquery up
    # into its parent and then computes an expression at every use.
    fence = ""

    def samples(self, columns: str) -> str:
        """A FROM item with ``columns`` of every committed sample."""
        return self.samples_table

    def sid_filter(self, sids: Sequence[int]) -> tuple[str, list]:
        """``sid`` restricted to ``sids``: the pruning predicate."""
        p = self.placeholder
        if len(sids) == 1:
            return f"sid = {p}", [sids[0]]
        return f"sid IN ({', '.join([p] * len(sids))})", list(sids)

    def time_value(self, moment: datetime) -> object:
        """A bound value comparable with the ``t`` column."""
        return moment.astimezone(UTC).replace(tzinfo=None)

    @abstractmethod
    def iso_ms(self, expr: str) -> str:
        """``expr`` (a UTC timestamp) as ``YYYY-MM-DDTHH:MM:SS.mmm+00:00``."""

    @abstractmethod
    def epoch_us(self, expr: str) -> str:
        """``expr`` as integer microseconds since the epoch."""

    def date_trunc(self, period: str, expr: str) -> str:
        # ``period`` comes from the AggrPeriod enum, never from a request.
        return f"date_trunc('{period}', {expr})"

    def bucket_key(self, period: str, expr: str) -> str:
        """A per-row grouping key for ``period``; ``bucket_time`` turns one
        key (once per group, not per row) back into the truncated time."""
        return self.date_trunc(period, expr)

    def bucket_time(self, period: str, key: str) -> str:
        return key

    @abstractmethod
    def json_path(self, steps: tuple[str | int, ...]) -> object:
        """The bound value naming ``steps`` for the JSON functions below."""

    @abstractmethod
    def json_number(self, col: str, path: object) -> tuple[str, list]:
        """The number at ``path`` in JSON text ``col``; NULL where the path is
        missing or leads to something else than a number."""

    @abstractmethod
    def json_is_integer(self, col: str, path: object) -> tuple[str, list]:
        """True where the value at ``path`` is an integer number."""

    @abstractmethod
    def json_present(self, col: str, path: object) -> tuple[str, list]:
        """True where a non-null value exists at ``path``."""

    def mask_relation(self) -> str:
        """A FROM item of five bound arrays zipped into rows
        ``(m_sid, m_t0, m_r0, m_t1, m_r1)`` (see ``RowMask``)."""
        p = self.placeholder
        return (
            f"unnest({p}::integer[], {p}::timestamp[], {p}::bigint[], {p}::timestamp[], {p}::bigint[]) "
            "AS m(m_sid, m_t0, m_r0, m_t1, m_r1)"
        )

    # Integer division of BIGINTs (DuckDB's ``/`` divides exactly).
    int_div = "/"

    @abstractmethod
    def json_array_length(self, col: str) -> str:
        """SQL: the length of the JSON array in text column ``col``."""

    def spans_relation(self) -> str:
        """A FROM item of three bound arrays zipped into rows ``(s_sid,
        s_start, s_end)`` (``InstanceWindow.spans``)."""
        p = self.placeholder
        return f"unnest({p}::integer[], {p}::timestamp[], {p}::timestamp[]) AS sp(s_sid, s_start, s_end)"

    @abstractmethod
    def periods_relation(self) -> str:
        """A FROM item of two bound BIGINT arrays zipped into rows
        ``per(lo, hi)`` (consecutive periods, epoch µs)."""

    # -- time buckets (``storage.sql.buckets``) ---------------------------------
    # The aggregates below take column names of the bucket query's inner
    # select: a number ``v``, its ``value_key`` ``vk``, its time ``tu`` (epoch
    # µs) and its row id.

    @abstractmethod
    def bucket_index(self, t: str, tu: str, width_us: int) -> tuple[str, list]:
        """A per-row grouping key of the bucket of ``width_us`` (aligned to
        the epoch) holding timestamp ``t`` (``tu``: the same in epoch µs)."""

    @abstractmethod
    def bucket_start(self, key: str, width_us: int) -> tuple[str, list]:
        """The bucket's start in epoch µs, from its key (once per group)."""

    def value_key(self, v: str) -> str:
        """A per-row key of ``v`` that ``time_of_min``/``time_of_max`` use."""
        return "NULL"

    @abstractmethod
    def time_of_min(self, v: str, vk: str, tu: str) -> str:
        """Aggregate: the time of the smallest ``v``, the earliest among equals."""

    @abstractmethod
    def time_of_max(self, v: str, vk: str, tu: str) -> str:
        """Aggregate: the time of the largest ``v``, the earliest among equals."""

    @abstractmethod
    def value_at_first(self, v: str, tu: str, rid: str) -> str:
        """Aggregate: ``v`` of the earliest row by (``tu``, ``rid``)."""

    @abstractmethod
    def value_at_last(self, v: str, tu: str, rid: str) -> str:
        """Aggregate: ``v`` of the latest row by (``tu``, ``rid``)."""

    @abstractmethod
    def json_value(self, col: str, path: object) -> tuple[str, list]:
        """The JSON value at ``path`` in JSON text ``col``, comparable with
        ``IS DISTINCT FROM`` (NULL where missing)."""


def mask_filter(dialect: SqlDialect, mask: RowMask) -> tuple[str, list]:
    """SQL: the sample's (t, rid) lies in one of its series' mask intervals.
    ``sid``, ``t`` and ``rid`` are the enclosing query's columns."""
    return (
        f"EXISTS (SELECT 1 FROM {dialect.mask_relation()} WHERE m_sid = sid "
        "AND (t > m_t0 OR (t = m_t0 AND rid >= m_r0)) "
        "AND (m_t1 IS NULL OR t < m_t1 OR (t = m_t1 AND rid < m_r1)))",
        mask.arrays(),
    )


def box_sql(placeholder: str, prefilter: Prefilter | None) -> tuple[str, list]:
    """SQL over the columns min_lon... : the stored box passes ``prefilter``
    (None passes everything; ``core.query.box_passes`` is the same test in memory)."""
    if prefilter is None:
        return "TRUE", []
    how, box = prefilter
    p = placeholder
    if how == WITHIN:
        sql = f"(min_lon >= {p} AND max_lon <= {p} AND min_lat >= {p} AND max_lat <= {p})"
    else:
        sql = f"(max_lon >= {p} AND min_lon <= {p} AND max_lat >= {p} AND min_lat <= {p})"
    return sql, [box.min_lon, box.max_lon, box.min_lat, box.max_lat]


def box_test(dialect: SqlDialect, prefilter: Prefilter | None) -> tuple[str, list]:
    """SQL: a sample's stored bounding box passes ``prefilter`` (``box_sql``)."""
    return box_sql(dialect.placeholder, prefilter)


def series_time_filter(dialect: SqlDialect, sids: Sequence[int], time: TimeRange) -> tuple[str, list]:
    """WHERE text and parameters: the series ids, then the inclusive time bounds."""
    where, params = dialect.sid_filter(sids)
    if time.start is not None:
        where += f" AND t >= {dialect.placeholder}"
        params.append(dialect.time_value(time.start))
    if time.end is not None:
        where += f" AND t <= {dialect.placeholder}"
        params.append(dialect.time_value(time.end))
    return where, params


def latest_per_series(
    columns: str, source: str, where: str, *, inner: str | None = None, order: str = "t DESC, rid DESC"
) -> str:
    """SQL: ``columns`` (expressions over ``inner``, the columns read; by
    default the same) of each series' first row of ``source`` by ``order``
    (the newest by default), among those matching ``where``."""
    return (
        f"SELECT {columns} FROM (SELECT {inner or columns}, row_number() OVER (PARTITION BY sid ORDER BY {order}) "
        f"AS rn FROM {source} WHERE {where}) ranked WHERE rn = 1"
    )


def rows_as(row_type: type[T]) -> Callable[[Iterable[tuple]], list[T]]:
    """Driver rows as ``row_type`` (a NamedTuple): one C-level
    ``tuple.__new__`` per row, no Python frame."""
    new = partial(tuple.__new__, row_type)
    return lambda rows: list(map(new, rows))
