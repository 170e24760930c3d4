"""What an export asks for: parameters and headers → a frozen ``ExportQuery``.

The same parameters as the history API, parsed by the same request-context
parser (``parse.request_context``: service paths, ids, id pattern, types,
time bounds), so an export selects exactly the samples a history query
with those parameters would. Unlike the history routes, unknown parameters
are refused: a mistyped ``fromdate`` would otherwise silently export the
whole tenant.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import timedelta
from enum import Enum

from tsdb_service.core.errors import BadRequest
from tsdb_service.core.query import EntityFilter, Scope, TimeRange
from tsdb_service.history.valuepath import parse_attr_list
from tsdb_service.parse.request_context import entity_filter, scope, time_range


class ExportFormat(str, Enum):
    CSV = "csv"
    PARQUET = "parquet"
    MCAP = "mcap"  # for Foxglove (faces.export.mcap)

    @property
    def media_type(self) -> str:
        return _MEDIA_TYPES[self]

    @property
    def suffix(self) -> str:
        return "." + self.value


_MEDIA_TYPES = {
    ExportFormat.CSV: "text/csv; charset=utf-8",
    ExportFormat.PARQUET: "application/vnd.apache.parquet",
    ExportFormat.MCAP: "application/x-mcap",
}
PARAMETERS = ("format", "type", "id", "idPattern", "attrs", "fromDate", "toDate", "raw", "bucket")
_WIDTH = re.compile(r"^([1-9][0-9]{0,9})(ms|s|min|m|h|d)$")
_UNITS = {"ms": 1e-3, "s": 1, "min": 60, "m": 60, "h": 3600, "d": 86400}
LONGEST_BUCKET = timedelta(days=366)


@dataclass(frozen=True, slots=True)
class ExportQuery:
    """The samples of ``scope`` matching ``entities``, ``attrs`` (plain
    attribute names, ``None`` = all) and the inclusive ``time`` bounds."""

    scope: Scope
    entities: EntityFilter
    attrs: tuple[str, ...] | None
    time: TimeRange
    format: ExportFormat = ExportFormat.CSV
    raw: bool = False  # CSV cells as stored, formulas included (encode.neutralised)
    bucket: timedelta | None = None  # one row per series and bucket of this width (``stream.BUCKET_SCHEMA``)


def export_format(raw: str | None, default: ExportFormat = ExportFormat.CSV) -> ExportFormat:
    if raw in (None, ""):
        return default
    try:
        return ExportFormat(raw.strip().lower())
    except ValueError:
        raise BadRequest(f"format must be csv, parquet or mcap, not {raw[:40]!r}") from None


def export_query(params: Mapping[str, str], headers: Mapping[str, str], tenant: str) -> ExportQuery:
    """Parse an export request; any bad or unknown parameter is a 400."""
    unknown = sorted(set(params) - set(PARAMETERS))
    if unknown:
        raise BadRequest(f"unknown parameter {unknown[0][:40]!r}; export takes {', '.join(PARAMETERS)}")
    get = params.get
    query = ExportQuery(
        scope=scope(headers, tenant),
        entities=entity_filter(params),
        attrs=_attr_names(get("attrs")),
        time=time_range(get("fromDate"), get("toDate")),
        format=export_format(get("format")),
        raw=_flag(get("raw"), "raw"),
        bucket=bucket_width(get("bucket")),
    )
    if query.format is ExportFormat.MCAP and query.bucket is not None:
        raise BadRequest("bucket exports aggregates, as csv or parquet; mcap exports the samples themselves")
    return query


def bucket_width(raw: str | None) -> timedelta | None:
    """``bucket``: ``500ms``, ``10s``, ``5min`` (or ``5m``), ``1h``, ``1d``; buckets
    start at multiples of it from the Unix epoch (UTC), as the charts' do."""
    if raw in (None, ""):
        return None
    match = _WIDTH.match(raw.strip())
    if match is None:
        raise BadRequest(f"bucket must be a width such as 10s, 5min, 1h or 1d (ms, s, min, h, d), not {raw[:40]!r}")
    width = timedelta(seconds=int(match.group(1)) * _UNITS[match.group(2)])
    if width > LONGEST_BUCKET:
        raise BadRequest(f"bucket is at most {LONGEST_BUCKET.days} days, not {raw[:40]!r}")
    return width


def _flag(raw: str | None, name: str) -> bool:
    if raw in (None, "", "false"):
        return False
    if raw == "true":
        return True
    raise BadRequest(f"{name} must be true or false, not {raw[:40]!r}")


def _attr_names(raw: str | None) -> tuple[str, ...] | None:
    """Attribute names: an export writes whole values, so a value path
    (``odom(twist.linear.x)``) is refused rather than silently widened."""
    paths = parse_attr_list(raw)
    if paths is None:
        return None
    for path in paths:
        if path.steps:
            raise BadRequest(
                f"export takes attribute names, not value paths ({path.text[:80]!r}): "
                "it writes whole values; structured ones are in value_json"
            )
    return tuple(path.attr for path in paths)
