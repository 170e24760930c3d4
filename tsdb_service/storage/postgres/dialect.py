"""How PostgreSQL spells the shared SQL renderer's pieces (``storage.sql.dialect.SqlDialect``)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from datetime import timedelta

from tsdb_service.storage.sql.dialect import SqlDialect

# Where ``date_part('epoch', ...)`` in microseconds rounds to the exact value
# (``PostgresDialect.epoch_us``): within ±2^31 s of 1970.
_FLOAT_EXACT_FROM = "TIMESTAMP '1902-01-01 00:00:00'"
_FLOAT_EXACT_TO = "TIMESTAMP '2038-01-01 00:00:00'"


class PostgresDialect(SqlDialect):
    name = "postgresql"
    placeholder = "%s"
    samples_table = "samples"
    fence = " OFFSET 0"

    def samples(self, columns: str) -> str:
        return "samples"

    def sid_filter(self, sids: Sequence[int]) -> tuple[str, list]:
        if len(sids) == 1:
            return "sid = %s", [sids[0]]
        # One array parameter: the index on (sid, t) serves = ANY(...).
        return "sid = ANY(%s::integer[])", [int_array(sids)]

    def iso_ms(self, expr: str) -> str:
        return f"""to_char({expr}, 'YYYY-MM-DD"T"HH24:MI:SS.MS"+00:00"')"""

    def epoch_us(self, expr: str) -> str:
        # ``extract`` answers a numeric: exact, but it costs about 0.2 µs a
        # row (2 ms of a 10,000-instance aggregation). ``date_part``'s
        # float8 is as exact, once rounded, wherever the seconds stay below
        # 2^31 (an ulp of at most 0.24 µs); the rest of the range (years
        # 1..1901, 2038..) keeps ``extract``.
        return (
            f"CASE WHEN {expr} >= {_FLOAT_EXACT_FROM} AND {expr} < {_FLOAT_EXACT_TO} "
            f"THEN (date_part('epoch', {expr}) * 1000000)::bigint "
            f"ELSE (extract(epoch from {expr}) * 1000000)::bigint END"
        )

    def json_path(self, steps: tuple[str | int, ...]) -> object:
        return [str(step) for step in steps]

    def json_number(self, col: str, path: object) -> tuple[str, list]:
        return (
            f"CASE WHEN jsonb_typeof(({col})::jsonb #> %s::text[]) = 'number' "
            f"THEN (({col})::jsonb #>> %s::text[])::double precision END",
            [path, path],
        )

    def json_is_integer(self, col: str, path: object) -> tuple[str, list]:
        return (
            f"(jsonb_typeof(({col})::jsonb #> %s::text[]) = 'number' "
            f"AND (({col})::jsonb #>> %s::text[]) ~ '^-?[0-9]+$')",
            [path, path],
        )

    def json_present(self, col: str, path: object) -> tuple[str, list]:
        return f"coalesce(jsonb_typeof(({col})::jsonb #> %s::text[]), 'null') <> 'null'", [path]

    def json_array_length(self, col: str) -> str:
        return f"jsonb_array_length(({col})::jsonb)"

    def periods_relation(self) -> str:
        return "unnest(%s::bigint[], %s::bigint[]) AS per(lo, hi)"

    # -- time buckets ------------------------------------------------------------
    # ``date_bin`` from the epoch; among equal values the earliest sample wins
    # through arrays compared element by element (``min(float8[])``): a time
    # in epoch µs and a row id are exact in a float8 below 2**53.

    def bucket_index(self, t: str, tu: str, width_us: int) -> tuple[str, list]:
        return f"date_bin(%s::interval, {t}, TIMESTAMP '1970-01-01')", [timedelta(microseconds=width_us)]

    def bucket_start(self, key: str, width_us: int) -> tuple[str, list]:
        return self.epoch_us(key), []

    def time_of_min(self, v: str, vk: str, tu: str) -> str:
        return f"((min(ARRAY[{v}, {tu}::float8]))[2])::bigint"

    def time_of_max(self, v: str, vk: str, tu: str) -> str:
        return f"(-(max(ARRAY[{v}, (-{tu})::float8]))[2])::bigint"

    def value_at_first(self, v: str, tu: str, rid: str) -> str:
        return f"(min(ARRAY[{tu}::float8, {rid}::float8, {v}]))[3]"

    def value_at_last(self, v: str, tu: str, rid: str) -> str:
        return f"(max(ARRAY[{tu}::float8, {rid}::float8, {v}]))[3]"

    def json_value(self, col: str, path: object) -> tuple[str, list]:
        return f"(({col})::jsonb #> %s::text[])", [path]


def int_array(values: Iterable[int]) -> str:
    """Integers as one PostgreSQL array literal, bound as a text parameter
    and cast in SQL (``%s::integer[]``): psycopg adapts a Python list
    element by element, about 0.7 µs each, which over the thousands of
    series of a geo-query is milliseconds per statement. Only our own ids
    go through here; ``int`` refuses anything else."""
    return "{" + ",".join(map(str, map(int, values))) + "}"
