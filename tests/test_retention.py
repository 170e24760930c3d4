"""Retention on a real store: old samples go in bounded batches, new ones
stay, per tenant and per entity type; the watermarks survive a restart;
queries (the in-memory tails and latest locations included) stop showing
what retention deleted."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Geometry, Kind
from tsdb_service.core.query import EntityFilter, Scope, TimeRange
from tsdb_service.read.requests import LocationsIn, SeriesSelect
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples

NOW = datetime.now(UTC).replace(minute=0, second=0, microsecond=0)
DAY = timedelta(days=1)


def entity(tenant: str, eid: str, etype: str, age: timedelta, n: int = 1, **extra) -> list[EntitySample]:
    """``n`` samples of attribute ``x``, one minute apart, starting ``age`` ago."""
    return [
        EntitySample(
            tenant,
            "/",
            eid,
            etype,
            NOW - age + timedelta(minutes=i),
            [AttrSample("x", "Number", Kind.INTEGER, num=i), *extra.get("attrs", [])],
        )
        for i in range(n)
    ]


def count(store, tenant: str, eid: str | None = None, etype: str | None = None) -> int:
    """Raw samples left (``Querier.count`` also counts what only rollups hold)."""
    q = store.querier()
    refs = q.series(
        SeriesSelect(Scope(tenant), EntityFilter(ids=(eid,) if eid else None, types=(etype,) if etype else None))
    )
    sids = [r.sid for r in refs]
    if not sids:
        return 0
    where, params = q.dialect.sid_filter(sids)
    return q._fetch(f"SELECT count(*) FROM samples_all WHERE {where}", params)[0][0]


class Batches:
    """Records every batch the worker reports."""

    def __init__(self):
        self.seen: list[tuple[str, str, int]] = []

    def batch(self, table: str, tenant: str, rows: int, seconds: float) -> None:
        self.seen.append((table, tenant, rows))


def open_with(url: str, **retention) -> object:
    settings = Settings(db=url, retention_pause=0, **retention)
    return open_store(settings)  # the worker exists but is not started: tests call run_once


def write_in_both_tables(store, first: list, then: list) -> None:
    """On DuckDB the first samples move to the sorted table, the rest stay hot."""
    store.write_sync([AppendSamples(first)])
    if hasattr(store, "compact"):
        store.compact(full=False)
    store.write_sync([AppendSamples(then)])


def test_old_samples_go_in_bounded_batches_new_ones_stay(store_url):
    store = open_with(store_url, retention="*=30d", retention_batch_rows=7)
    try:
        old = entity("", "E1", "Room", 40 * DAY, n=25)
        new = entity("", "E1", "Room", DAY, n=5)
        write_in_both_tables(store, old[:12] + new[:2], old[12:] + new[2:])
        batches = store.retention.observer = Batches()
        deleted = store.retention.run_once()
        assert sum(deleted.values()) == 25
        assert count(store, "") == 5
        rows = [n for _table, _tenant, n in batches.seen]
        assert sum(rows) == 25 and max(rows) <= 7 and len(rows) >= 4
        assert store.retention.run_once() == {}  # nothing left to do
    finally:
        store.close()


def test_per_tenant_and_per_type(store_url):
    store = open_with(store_url, retention="*=365d,acme=30d,acme/Robot=7d")
    try:
        write_in_both_tables(
            store,
            [
                *entity("", "R1", "Room", 40 * DAY, n=3),  # '*': kept (365 d)
                *entity("acme", "R2", "Room", 40 * DAY, n=3),  # 'acme': deleted
                *entity("acme", "R2", "Room", 10 * DAY, n=2),  # 'acme': kept
                *entity("acme", "B1", "Robot", 10 * DAY, n=4),  # 'acme/Robot': deleted
            ],
            [
                *entity("acme", "B1", "Robot", DAY, n=2),  # kept
                *entity("beta", "B2", "Robot", 40 * DAY, n=3),  # '*': kept
                *entity("beta", "B2", "Robot", 400 * DAY, n=6),  # '*': deleted
            ],
        )
        batches = store.retention.observer = Batches()
        store.retention.run_once()
        assert count(store, "") == 3
        assert count(store, "acme", "R2") == 2
        assert count(store, "acme", "B1") == 2
        assert count(store, "beta") == 3
        by_tenant: dict[str, int] = {}
        for _table, tenant, n in batches.seen:
            by_tenant[tenant] = by_tenant.get(tenant, 0) + n
        assert by_tenant == {"acme": 7, "beta": 6}
        marks = store.retention.watermarks
        assert set(marks) == {("samples", "*"), ("samples", "acme"), ("samples", "acme/Robot")}
        assert NOW - 31 * DAY < marks[("samples", "acme")] <= datetime.now(UTC) - 30 * DAY
    finally:
        store.close()


def test_watermarks_survive_a_restart(store_url):
    store = open_with(store_url, retention="*=30d,acme=7d")
    try:
        store.write_sync([AppendSamples(entity("acme", "E", "T", 9 * DAY, n=2))])
        store.retention.run_once()
        before = dict(store.retention.watermarks)
    finally:
        store.close()
    assert set(before) == {("samples", "*"), ("samples", "acme")}
    store = open_with(store_url, retention="*=30d,acme=7d")
    try:
        assert store.retention.watermarks == before
        assert set(store.retention.lags()) == {("samples", "*"), ("samples", "acme")}
    finally:
        store.close()


def test_stop_interrupts_between_batches_and_keeps_the_old_watermark(store_url):
    store = open_with(store_url, retention="*=30d", retention_batch_rows=2)
    try:
        store.write_sync([AppendSamples(entity("", "E", "T", 40 * DAY, n=9))])
        worker = store.retention

        class StopAfterFirst(Batches):
            def batch(self, *args):
                super().batch(*args)
                worker._stop.set()

        worker.observer = StopAfterFirst()
        worker.run_once()
        assert count(store, "") == 7  # one batch of two, then it stopped
        assert ("samples", "*") not in worker.watermarks
    finally:
        store.close()


def test_offline_commands_never_start_the_worker(store_url):
    store = open_with(store_url, retention="*=1d", retention_interval=0.01)
    try:
        store.write_sync([AppendSamples(entity("", "E", "T", 3 * DAY, n=2))])
        assert store.retention._thread is None
        assert count(store, "") == 2
    finally:
        store.close()


def test_queries_stop_showing_deleted_samples(client_factory, store_url, notify):
    """lastN (answered from the in-memory tails on DuckDB) and geo-queries
    (latest locations in memory) see what retention deleted at once."""
    with client_factory(store_url, retention="*=30d", retention_interval=3600) as client:
        point = lambda i: {"type": "geo:point", "value": f"{40 + i}, -3"}  # noqa: E731
        old = [
            {
                "id": "Bot",
                "type": "Robot",
                "x": {"type": "Number", "value": i},
                "location": point(i),
                "TimeInstant": {"type": "DateTime", "value": (NOW - 40 * DAY + timedelta(minutes=i)).isoformat()},
            }
            for i in range(3)
        ]
        new = [
            {
                "id": "Bot2",
                "type": "Robot",
                "x": {"type": "Number", "value": 9},
                "TimeInstant": {"type": "DateTime", "value": (NOW - DAY).isoformat()},
            }
        ]
        notify(client, {"subscriptionId": "s", "data": old + new})
        r = client.get("/v2/entities/Bot/attrs/x?lastN=5")
        assert r.json()["values"] == [0, 1, 2]
        near = "/v2/entities?georel=near;maxDistance:1000&geometry=point&coords=42,-3"
        assert [e["id"] for e in client.get(near).json()] == ["Bot"]
        client.app.state.store.retention.run_once()
        assert client.get("/v2/entities/Bot/attrs/x?lastN=5").json() == []
        assert client.get(near).json() == []
        assert client.get("/v2/entities/Bot2/attrs/x?lastN=5").json()["values"] == [9]


@pytest.mark.parametrize("geo_kind", [Kind.GEO])
def test_latest_location_recomputed_when_an_old_one_goes(store_url, geo_kind):
    """A series whose newest position is old loses it; a newer one stays."""
    store = open_with(store_url, retention="*=30d")
    try:

        def geo(lon):
            return AttrSample(
                "location",
                "geo:json",
                geo_kind,
                js="{}",
                geo=Geometry(f'{{"type":"Point","coordinates":[{lon},0]}}', lon, 0, lon, 0, lon, 0),
            )

        store.write_sync(
            [
                AppendSamples(
                    [
                        EntitySample("", "/", "A", "T", NOW - 40 * DAY, [geo(1.0)]),
                        EntitySample("", "/", "B", "T", NOW - 40 * DAY, [geo(2.0)]),
                        EntitySample("", "/", "B", "T", NOW - DAY, [geo(3.0)]),
                    ]
                )
            ]
        )
        store.retention.run_once()
        q = store.querier()
        refs = q.series(SeriesSelect(Scope(""), EntityFilter(), {"location"}))
        latest = dict(q.latest_geometries(LocationsIn([r.sid for r in refs], TimeRange(), None)))
        by_entity = {r.entity_id: latest.get(r.sid) for r in refs}
        assert by_entity["A"] is None
        assert "[3.0,0]" in by_entity["B"]
    finally:
        store.close()


def test_a_renotified_instance_is_stored_again_after_retention_deleted_it(store_url):
    """An NGSI-LD instance identical to its series' latest stored one is
    stored once (Orion-LD re-notifies unchanged attributes). Once retention
    deleted that instance, the same instance notified again is new: it must
    be stored, not dropped as a repeat of what is gone."""
    store = open_with(store_url, retention="*=30d")
    try:
        observed = NOW - 40 * DAY

        def instance() -> list[EntitySample]:
            temp = AttrSample("temperature", "Property", Kind.NUMBER, num=21.5, observed_at=observed)
            return [EntitySample("", "/", "urn:ngsi-ld:Sensor:1", "Sensor", observed, [temp])]

        store.write_sync([AppendSamples(instance())])
        store.write_sync([AppendSamples(instance())])  # a re-notification: stored once
        assert count(store, "", "urn:ngsi-ld:Sensor:1") == 1
        store.retention.run_once()
        assert count(store, "", "urn:ngsi-ld:Sensor:1") == 0
        store.write_sync([AppendSamples(instance())])
        assert count(store, "", "urn:ngsi-ld:Sensor:1") == 1
    finally:
        store.close()
