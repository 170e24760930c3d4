"""A small Python client for tsdb-service that answers with pandas DataFrames.

For the people who analyse robot logs in a notebook: the QuantumLeap-style
history queries (one entity, one attribute, a whole type, the entity list,
lastN, time windows, aggregation per period) come back as DataFrames with
UTC timestamps, and ``export`` fetches a whole selection through the
Parquet endpoint. It works against any QuantumLeap 1.0-compatible service
for everything but ``export``.

Usage::

    from datetime import UTC, datetime, timedelta

    from tsdb_service.client import Client

    with Client("http://localhost:8668", service="lawnmower", service_path="/bosch") as tsdb:
        tsdb.entities(entity_type="ROS2System")              # entity_id, entity_type, time
        mower = "urn:ngsiv2:ROS2System:Lawnmower01"
        speed = tsdb.entity_attr(mower, "odom(twist.twist.linear.x)", last_n=500)
        speed.plot()                                         # index: time (UTC)
        hour_ago = datetime.now(UTC) - timedelta(hours=1)      # the demo's data is live
        tsdb.entity(mower, ["navigationState(data)", "obstacleDistance(range)"], from_date=hour_ago)
        tsdb.entity_attr(mower, "odom(twist.twist.linear.x)", aggr_method="avg", aggr_period="minute")
        tsdb.type_history("ROS2System", ["obstacleDistance(range)"], last_n=100)  # entity_id, time, ...
        samples = tsdb.export(entity_type="ROS2System")      # one row per sample, typed columns

Time bounds are ISO 8601 strings or ``datetime`` / ``pandas.Timestamp``
values (naive means UTC). Raw (not aggregated, not lastN) queries are read
page by page (``page_size`` rows, QuantumLeap's ``limit``/``offset``) until
the service has no more, so nothing is silently cut at the service's
default limit; ``limit`` caps the total. An empty answer is an empty
DataFrame (also for QuantumLeap's 404 "Not Found"). Any other error raises
``TsdbClientError`` with the service's NGSI ``error`` and ``description``.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeAlias
from urllib.parse import quote

import httpx
import pandas as pd

__all__ = ["Client", "TsdbClientError"]

TimeBound: TypeAlias = str | datetime | pd.Timestamp | None


class TsdbClientError(RuntimeError):
    """An error answer: HTTP status, NGSI error name and description."""

    def __init__(self, status: int, error: str, description: str):
        super().__init__(f"{status} {error}: {description}")
        self.status = status
        self.error = error
        self.description = description


class Client:
    """One tenant (``service``) and service path of one tsdb-service.

    ``service_path`` may be a comma list, and a path includes its children,
    as in the history API. ``transport`` is passed to ``httpx.Client`` (for
    example to mount a custom one); ``timeout`` is in seconds.
    """

    def __init__(
        self,
        url: str = "http://localhost:8668",
        *,
        service: str | None = None,
        service_path: str | None = None,
        timeout: float = 60.0,
        page_size: int = 10_000,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        headers = {"Accept": "application/json"}
        if service:
            headers["Fiware-Service"] = service
        if service_path:
            headers["Fiware-ServicePath"] = service_path
        self.page_size = page_size
        self._http = httpx.Client(base_url=url.rstrip("/"), headers=headers, timeout=timeout, transport=transport)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    # -- entities ----------------------------------------------------------------------

    def entities(
        self,
        *,
        entity_type: str | None = None,
        entity_id: str | Iterable[str] | None = None,
        id_pattern: str | None = None,
        from_date: TimeBound = None,
        to_date: TimeBound = None,
    ) -> pd.DataFrame:
        """``GET /v2/entities``: one row per entity with its latest time index
        (columns ``entity_id``, ``entity_type``, ``time``)."""
        params = _params(type=entity_type, id=_csv(entity_id), idPattern=id_pattern, fromDate=from_date, toDate=to_date)
        rows: list[dict] = []
        offset = 0
        while page := self._get("/v2/entities", {**params, "limit": self.page_size, "offset": offset}) or []:
            rows += [{"entity_id": e["id"], "entity_type": e["type"], "time": e["index"]} for e in page]
            offset += len(page)
        frame = pd.DataFrame(rows, columns=["entity_id", "entity_type", "time"])
        frame["time"] = _times(frame["time"])
        return frame

    # -- history ---------------------------------------------------------------------------

    def entity(
        self,
        entity_id: str,
        attrs: Iterable[str] | None = None,
        *,
        entity_type: str | None = None,
        from_date: TimeBound = None,
        to_date: TimeBound = None,
        last_n: int | None = None,
        limit: int | None = None,
        offset: int | None = None,
        aggr_method: str | None = None,
        aggr_period: str | None = None,
    ) -> pd.DataFrame:
        """``GET /v2/entities/{id}``: one column per attribute (or value path),
        indexed by ``time``. With ``aggr_method`` and no ``aggr_period`` there
        is one row and no time index."""
        params = _params(
            type=entity_type,
            attrs=_csv(attrs),
            fromDate=from_date,
            toDate=to_date,
            lastN=last_n,
            aggrMethod=aggr_method,
            aggrPeriod=aggr_period,
        )
        frames = [
            _wide(page.get("index", []), {a["attrName"]: a["values"] for a in page.get("attributes", [])})
            for page in self._pages(f"/v2/entities/{_segment(entity_id)}", params, limit, offset)
        ]
        return _concat(frames)

    def entity_attr(
        self,
        entity_id: str,
        attr: str,
        *,
        entity_type: str | None = None,
        from_date: TimeBound = None,
        to_date: TimeBound = None,
        last_n: int | None = None,
        limit: int | None = None,
        offset: int | None = None,
        aggr_method: str | None = None,
        aggr_period: str | None = None,
    ) -> pd.DataFrame:
        """``GET /v2/entities/{id}/attrs/{attr}``: one column named ``attr``
        (a value path such as ``odom(twist.twist.linear.x)`` works), indexed
        by ``time``."""
        params = _params(
            type=entity_type,
            fromDate=from_date,
            toDate=to_date,
            lastN=last_n,
            aggrMethod=aggr_method,
            aggrPeriod=aggr_period,
        )
        path = f"/v2/entities/{_segment(entity_id)}/attrs/{_segment(attr)}"
        frames = [
            _wide(page.get("index", []), {page.get("attrName", attr): page.get("values", [])})
            for page in self._pages(path, params, limit, offset)
        ]
        frame = _concat(frames)
        return frame if len(frame.columns) else pd.DataFrame({attr: []}, index=_times([]).rename("time"))

    def type_history(
        self,
        entity_type: str,
        attrs: Iterable[str] | None = None,
        *,
        entity_id: str | Iterable[str] | None = None,
        id_pattern: str | None = None,
        from_date: TimeBound = None,
        to_date: TimeBound = None,
        last_n: int | None = None,
        limit: int | None = None,
        offset: int | None = None,
        aggr_method: str | None = None,
        aggr_period: str | None = None,
        aggr_scope: str | None = None,
    ) -> pd.DataFrame:
        """``GET /v2/types/{type}``: every entity of a type, one row per entity
        and time (columns ``entity_id``, ``time``, then one per attribute).
        With ``aggr_scope="global"`` the ``entity_id`` of a row lists the
        aggregated entities, comma-separated."""
        params = _params(
            attrs=_csv(attrs),
            id=_csv(entity_id),
            idPattern=id_pattern,
            fromDate=from_date,
            toDate=to_date,
            lastN=last_n,
            aggrMethod=aggr_method,
            aggrPeriod=aggr_period,
            aggrScope=aggr_scope,
        )
        frames = []
        for page in self._pages(f"/v2/types/{_segment(entity_type)}", params, limit, offset):
            for ent in page.get("entities", []):
                one = _wide(ent.get("index", []), {a["attrName"]: a["values"] for a in ent.get("attributes", [])})
                one = one.reset_index() if one.index.name == "time" else one.reset_index(drop=True)
                one.insert(0, "entity_id", ent.get("id") or ",".join(ent.get("ids", [])))
                frames.append(one)
        if not frames:
            return pd.DataFrame({"entity_id": [], "time": _times([])})
        # Each page lists its entities in id order; regroup the pages' rows
        # per entity (a stable sort keeps each entity's rows in time order).
        frame = pd.concat(frames, ignore_index=True)
        return frame.sort_values("entity_id", kind="stable", ignore_index=True)

    # -- export ------------------------------------------------------------------------------

    def export(
        self,
        *,
        entity_type: str | Iterable[str] | None = None,
        entity_id: str | Iterable[str] | None = None,
        id_pattern: str | None = None,
        attrs: Iterable[str] | None = None,
        from_date: TimeBound = None,
        to_date: TimeBound = None,
    ) -> pd.DataFrame:
        """``GET /v2/export?format=parquet`` as a DataFrame: one row per sample
        with ``time`` (UTC, microseconds), ``entity_id``, ``entity_type``,
        ``service_path``, ``attribute``, ``ngsi_type`` and the typed value
        columns ``value_number``, ``value_text``, ``value_bool``,
        ``value_json`` (one is set per row). The file goes through a
        temporary file, not memory."""
        fd, name = tempfile.mkstemp(suffix=".parquet", prefix="tsdb-export-")
        os.close(fd)
        try:
            self.export_file(
                name,
                entity_type=entity_type,
                entity_id=entity_id,
                id_pattern=id_pattern,
                attrs=attrs,
                from_date=from_date,
                to_date=to_date,
            )
            return pd.read_parquet(name)
        finally:
            os.unlink(name)

    def export_file(
        self,
        path: str | os.PathLike[str],
        *,
        format: str = "parquet",
        entity_type: str | Iterable[str] | None = None,
        entity_id: str | Iterable[str] | None = None,
        id_pattern: str | None = None,
        attrs: Iterable[str] | None = None,
        from_date: TimeBound = None,
        to_date: TimeBound = None,
    ) -> Path:
        """Download an export (``format`` ``parquet``, ``csv`` or ``mcap``) to ``path``,
        streamed to disk; returns the path."""
        params = _params(
            format=format,
            type=_csv(entity_type),
            id=_csv(entity_id),
            idPattern=id_pattern,
            attrs=_csv(attrs),
            fromDate=from_date,
            toDate=to_date,
        )
        target = Path(path)
        with self._http.stream("GET", "/v2/export", params=params) as response:
            if response.status_code != 200:
                response.read()
                raise _error(response)
            with open(target, "wb") as out:
                for chunk in response.iter_bytes():
                    out.write(chunk)
        return target

    # -- plumbing ----------------------------------------------------------------------------

    def _get(self, path: str, params: Mapping[str, Any]) -> Any:
        response = self._http.get(path, params=params)
        if response.status_code == 200:
            return response.json()
        if response.status_code == 404 and _ngsi_error(response)[0] == "Not Found":
            return None  # QuantumLeap's "no records", where we answer 200 []
        raise _error(response)

    def _pages(self, path: str, params: dict, limit: int | None, offset: int | None) -> list[dict]:
        """The answer's pages. lastN and aggregations come in one request;
        raw histories page by ``offset`` until a page is empty or ``limit``
        rows were read."""
        start = offset or 0
        if "lastN" in params or "aggrMethod" in params:
            page = self._get(path, {**params, **_params(limit=limit, offset=offset)})
            return [page] if page else []
        pages, read = [], 0
        while limit is None or read < limit:
            size = self.page_size if limit is None else min(self.page_size, limit - read)
            page = self._get(path, {**params, "limit": size, "offset": start + read})
            rows = _rows_in(page)
            if not rows:
                break
            pages.append(page)
            read += rows
        return pages


# -- helpers -----------------------------------------------------------------------------


def _rows_in(page) -> int:
    if not page:
        return 0
    if "entities" in page:
        return sum(len(e.get("index", [])) for e in page["entities"])
    return len(page.get("index", []))


def _wide(index: list, columns: dict[str, list]) -> pd.DataFrame:
    """Parallel ``index``/``values`` arrays → a frame indexed by time. An
    aggregate without a period has no per-row times: no time index then."""
    rows = max((len(v) for v in columns.values()), default=0)
    frame = pd.DataFrame({name: pd.Series(values, dtype=_dtype(values)) for name, values in columns.items()})
    if len(index) == rows:
        frame.index = _times(index).rename("time")
    return frame


def _dtype(values: list):
    """Object columns for structured values (dicts, lists) and mixed kinds;
    pandas' own inference otherwise."""
    return object if any(isinstance(v, dict | list) for v in values) else None


def _concat(frames: list[pd.DataFrame]) -> pd.DataFrame:
    frames = [f for f in frames if len(f)]
    if not frames:
        return pd.DataFrame(index=_times([]).rename("time"))
    return frames[0] if len(frames) == 1 else pd.concat(frames)


def _times(values) -> pd.DatetimeIndex | pd.Series:
    if isinstance(values, pd.Series):
        return pd.to_datetime(values, utc=True, format="ISO8601")
    return pd.DatetimeIndex(pd.to_datetime(list(values), utc=True, format="ISO8601"))


def _params(**values) -> dict[str, str]:
    return {k: _text(v) for k, v in values.items() if v is not None}


def _text(value) -> str:
    if isinstance(value, datetime):  # pandas.Timestamp is one too
        moment = value if value.tzinfo is not None else value.replace(tzinfo=UTC)
        return moment.isoformat()
    return str(value)


def _csv(value: str | Iterable[str] | None) -> str | None:
    if value is None or isinstance(value, str):
        return value
    return ",".join(value)


def _segment(text: str) -> str:
    return quote(text, safe="")


def _ngsi_error(response: httpx.Response) -> tuple[str, str]:
    try:
        body = response.json()
    except ValueError:
        return "", response.text[:500]
    if isinstance(body, dict):
        return str(body.get("error", "")), str(body.get("description", ""))
    return "", str(body)[:500]


def _error(response: httpx.Response) -> TsdbClientError:
    error, description = _ngsi_error(response)
    return TsdbClientError(response.status_code, error or response.reason_phrase, description)
