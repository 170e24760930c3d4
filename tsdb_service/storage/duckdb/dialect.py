"""How DuckDB spells the shared SQL renderer's pieces (``storage.sql.dialect.SqlDialect``)."""

from __future__ import annotations

from collections.abc import Sequence

from tsdb_service.storage.sql.dialect import SqlDialect

# Periods of a fixed number of microseconds (UTC has no leap seconds here);
# floor division is truncation because times before 1970 round down too.
_PERIOD_US = {"second": 10**6, "minute": 60 * 10**6, "hour": 3600 * 10**6, "day": 86400 * 10**6}
_YEAR_1_US = 62_135_596_800 * 10**6  # 0001-01-01 to 1970-01-01


def _shift(width: int) -> int:
    """The smallest multiple of ``width`` that is at least ``_YEAR_1_US``."""
    return -(-_YEAR_1_US // width) * width


class DuckDBDialect(SqlDialect):
    name = "duckdb"

    def samples(self, columns: str) -> str:
        # The sorted table and the hot one; naming only the needed columns
        # binds faster than the 16-column ``samples_all`` view.
        return f"(SELECT {columns} FROM samples UNION ALL SELECT {columns} FROM samples_hot) AS samples_all"

    def sid_filter(self, sids: Sequence[int]) -> tuple[str, list]:
        if len(sids) > self.many_sids:
            # The range is a filter the scan applies to each row group's
            # zone map, so the sorted table is read only between the first
            # and last series (the IN list alone is a join above the scan).
            return "sid BETWEEN ? AND ? AND sid IN (SELECT unnest(?::INTEGER[]))", [min(sids), max(sids), list(sids)]
        return super().sid_filter(sids)

    def iso_ms(self, expr: str) -> str:
        return f"strftime({expr}, '%Y-%m-%dT%H:%M:%S.%g+00:00')"

    def bucket_key(self, period: str, expr: str) -> str:
        # Fixed-width UTC periods: an integer division per row is cheaper
        # than date_trunc, and an integer key hashes faster than a timestamp.
        # DuckDB's // truncates toward zero: shifted by a multiple of the
        # width past year 1, every dividend is positive, so it floors.
        width = _PERIOD_US.get(period)
        if width is None:
            return super().bucket_key(period, expr)
        return f"((epoch_us({expr}) + {_shift(width)}) // {width})"

    def bucket_time(self, period: str, key: str) -> str:
        width = _PERIOD_US.get(period)
        if width is None:
            return key
        return f"make_timestamp({key} * {width} - {_shift(width)})"

    def epoch_us(self, expr: str) -> str:
        return f"epoch_us({expr})"

    def json_path(self, steps: tuple[str | int, ...]) -> object:
        # A JSON Pointer: no wildcard or quoting rules, any key is literal.
        return "".join("/" + str(step).replace("~", "~0").replace("/", "~1") for step in steps)

    def json_number(self, col: str, path: object) -> tuple[str, list]:
        return (
            f"CASE WHEN json_type({col}, ?) IN ('BIGINT', 'UBIGINT', 'DOUBLE') "
            f"THEN CAST(json_extract_string({col}, ?) AS DOUBLE) END",
            [path, path],
        )

    def json_is_integer(self, col: str, path: object) -> tuple[str, list]:
        return f"json_type({col}, ?) IN ('BIGINT', 'UBIGINT')", [path]

    def json_present(self, col: str, path: object) -> tuple[str, list]:
        return f"coalesce(json_type({col}, ?), 'NULL') <> 'NULL'", [path]

    int_div = "//"

    def json_array_length(self, col: str) -> str:
        return f"json_array_length({col})"

    def periods_relation(self) -> str:
        # unnest() in a SELECT list zips arrays of equal length.
        return "(SELECT unnest(?::BIGINT[]) AS lo, unnest(?::BIGINT[]) AS hi) per"

    def spans_relation(self) -> str:
        # unnest() in a SELECT list zips arrays of equal length.
        return (
            "(SELECT unnest(?::INTEGER[]) AS s_sid, unnest(?::TIMESTAMP[]) AS s_start, "
            "unnest(?::TIMESTAMP[]) AS s_end) AS sp"
        )

    def mask_relation(self) -> str:
        # unnest() in a SELECT list zips arrays of equal length.
        return (
            "(SELECT unnest(?::INTEGER[]) AS m_sid, unnest(?::TIMESTAMP[]) AS m_t0, unnest(?::BIGINT[]) AS m_r0, "
            "unnest(?::TIMESTAMP[]) AS m_t1, unnest(?::BIGINT[]) AS m_r1) AS m"
        )
