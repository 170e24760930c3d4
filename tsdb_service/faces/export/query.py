"""What an export asks for: parameters and headers → a frozen ``ExportQuery``.

The same parameters as the history API, parsed by the same request-context
parser (``parse.request_context``: service paths, ids, id pattern, types,
time bounds), so an export selects exactly the samples a history query
with those parameters would. Unlike the history routes, unknown parameters
are refused: a mistyped ``fromdate`` would otherwise silently export the
whole tenant.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
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
PARAMETERS = ("format", "type", "id", "idPattern", "attrs", "fromDate", "toDate", "raw")


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
    return ExportQuery(
        scope=scope(headers, tenant),
        entities=entity_filter(params),
        attrs=_attr_names(get("attrs")),
        time=time_range(get("fromDate"), get("toDate")),
        format=export_format(get("format")),
        raw=_flag(get("raw"), "raw"),
    )


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
