"""NGSI-LD notifications keep every attribute instance (issue 13): each its
own observedAt, createdAt/modifiedAt and datasetId, a stable instanceId,
deletions as instances, and re-notified unchanged instances stored once.

Examples follow ETSI GS CIM 009 (the Vehicle/speed examples of clause
5.2 and annex C, abridged), sent as Orion-LD sends them."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from tsdb_service.core.model import Kind, instance_iid, instance_urn
from tsdb_service.core.query import EntityFilter, InstanceWindow, Scope
from tsdb_service.read.requests import ANY_TIME, InstancesRead, SeriesSelect

SCOPE = Scope("")
LD_HEADERS = {"Content-Type": "application/json"}


def notify_ld(client, *entities, headers=None):
    body = {
        "id": "urn:ngsi-ld:Notification:1",
        "type": "Notification",
        "subscriptionId": "urn:sub:1",
        "notifiedAt": "2024-05-01T12:00:00Z",
        "data": list(entities),
    }
    response = client.post("/ngsi-ld/v1/notify", json=body, headers={**LD_HEADERS, **(headers or {})})
    assert response.status_code == 200, response.text


def instances(client, eid="urn:ngsi-ld:Vehicle:A4567", window=ANY_TIME, **kw):
    q = client.app.state.store.querier()
    refs = q.series(SeriesSelect(SCOPE, EntityFilter(ids=(eid,))))
    by_sid = {r.sid: r for r in refs}
    rows = q.temporal_instances(InstancesRead([r.sid for r in refs], window, **kw))
    return [(by_sid[r.sid].ld_attr, r) for r in rows]


def utc(text: str) -> datetime:
    return datetime.fromisoformat(text.replace("Z", "+00:00")).astimezone(UTC).replace(tzinfo=None)


def vehicle(**attrs) -> dict:
    return {"id": "urn:ngsi-ld:Vehicle:A4567", "type": "Vehicle", **attrs}


def test_each_instance_keeps_its_own_observed_at(client):
    notify_ld(
        client,
        vehicle(
            speed={"type": "Property", "value": 55, "observedAt": "2024-05-01T10:00:00Z", "unitCode": "KMH"},
            brandName={"type": "Property", "value": "Mercedes", "observedAt": "2024-05-01T09:30:00+01:00"},
        ),
    )
    got = {name: r for name, r in instances(client)}
    assert got["speed"].observed_at == utc("2024-05-01T10:00:00Z")
    assert got["brandName"].observed_at == utc("2024-05-01T08:30:00Z")
    # The NGSIv2 row time stays shared (the newest observedAt).
    assert got["speed"].t == got["brandName"].t == utc("2024-05-01T10:00:00Z")
    assert got["speed"].kind == Kind.INTEGER and got["speed"].num == 55
    assert '"unitCode":"KMH"' in got["speed"].md


def test_created_and_modified_at_are_kept(client):
    notify_ld(
        client,
        vehicle(
            speed={
                "type": "Property",
                "value": 10,
                "observedAt": "2024-05-01T10:00:00Z",
                "createdAt": "2024-04-01T00:00:00Z",
                "modifiedAt": "2024-05-01T10:00:01Z",
            }
        ),
    )
    [(_, row)] = instances(client)
    assert (row.created_at, row.modified_at) == (utc("2024-04-01T00:00:00Z"), utc("2024-05-01T10:00:01Z"))
    window = InstanceWindow("modifiedAt", datetime(2024, 5, 1, 10, tzinfo=UTC), None)
    assert len(instances(client, window=window)) == 1
    window = InstanceWindow("modifiedAt", None, datetime(2024, 5, 1, 10, 0, 1, tzinfo=UTC))
    assert instances(client, window=window) == []  # end is exclusive


def test_every_dataset_id_is_kept(client):
    notify_ld(
        client,
        vehicle(
            speed=[
                {"type": "Property", "value": 55, "observedAt": "2024-05-01T10:00:00Z"},
                {
                    "type": "Property",
                    "value": 54.5,
                    "datasetId": "urn:ngsi-ld:Property:gpsBxyz123-speed",
                    "observedAt": "2024-05-01T10:00:00Z",
                },
                {
                    "type": "Property",
                    "value": 56,
                    "datasetId": "urn:ngsi-ld:Property:speedometerA4567-speed",
                    "observedAt": "2024-05-01T10:00:00Z",
                },
            ]
        ),
    )
    rows = instances(client)
    assert sorted((name, r.dataset_id or "", r.num) for name, r in rows) == [
        ("speed", "", 55),
        ("speed", "urn:ngsi-ld:Property:gpsBxyz123-speed", 54.5),
        ("speed", "urn:ngsi-ld:Property:speedometerA4567-speed", 56),
    ]
    # NGSIv2 sees one attribute per datasetId, one value per row.
    v2 = client.get("/v2/entities/urn:ngsi-ld:Vehicle:A4567/attrs/speed~urn:ngsi-ld:Property:gpsBxyz123-speed")
    assert v2.status_code == 200, v2.text
    assert v2.json()["values"] == [54.5]
    assert client.get("/v2/entities/urn:ngsi-ld:Vehicle:A4567/attrs/speed").json()["values"] == [55]


def test_the_same_dataset_id_twice_is_refused(client):
    body = {
        "type": "Notification",
        "data": [
            vehicle(
                speed=[
                    {"type": "Property", "value": 1, "datasetId": "urn:d"},
                    {"type": "Property", "value": 2, "datasetId": "urn:d"},
                ]
            )
        ],
    }
    response = client.post("/ngsi-ld/v1/notify", json=body, headers=LD_HEADERS)
    assert response.status_code == 400
    assert "twice" in response.json()["description"]


def test_renotified_unchanged_instances_are_stored_once(client):
    """Orion-LD notifies the whole entity; the unchanged brandName comes
    back with its old observedAt and must not become a second instance."""
    brand = {"type": "Property", "value": "Mercedes", "observedAt": "2024-05-01T09:00:00Z"}
    for second in range(3):
        notify_ld(
            client,
            vehicle(
                brandName=brand,
                speed={"type": "Property", "value": 50 + second, "observedAt": f"2024-05-01T10:00:0{second}Z"},
            ),
        )
    rows = instances(client)
    assert [r.num for name, r in rows if name == "speed"] == [50, 51, 52]
    assert [r.txt for name, r in rows if name == "brandName"] == ["Mercedes"]
    # Same observedAt with another value is another instance; so is a new observedAt.
    notify_ld(client, vehicle(brandName={**brand, "value": "Daimler"}))
    notify_ld(client, vehicle(brandName={**brand, "observedAt": "2024-05-01T11:00:00Z"}))
    assert [r.txt for name, r in instances(client) if name == "brandName"] == ["Mercedes", "Daimler", "Mercedes"]


def test_dedup_survives_a_restart(client_factory, store_url):
    brand = {"type": "Property", "value": "Mercedes", "observedAt": "2024-05-01T09:00:00Z"}
    with client_factory(store_url) as client:
        notify_ld(client, vehicle(brandName=brand))
    with client_factory(store_url) as client:  # cold cache: looked up in the database
        notify_ld(client, vehicle(brandName=brand))
        notify_ld(client, vehicle(brandName=brand))
        assert len(instances(client)) == 1


def test_instances_without_observed_at_are_never_dropped(client):
    for _ in range(2):
        notify_ld(client, vehicle(speed={"type": "Property", "value": 5}))
    assert len(instances(client)) == 2


def test_attribute_deletion_is_an_instance(client):
    notify_ld(client, vehicle(speed={"type": "Property", "value": 5, "observedAt": "2024-05-01T10:00:00Z"}))
    notify_ld(
        client, vehicle(speed={"type": "Property", "value": "urn:ngsi-ld:null", "deletedAt": "2024-05-01T11:00:00Z"})
    )
    rows = instances(client)
    assert [(r.kind, r.deleted_at) for _, r in rows] == [(Kind.INTEGER, None), (Kind.NULL, utc("2024-05-01T11:00:00Z"))]
    found = instances(client, window=InstanceWindow("deletedAt", datetime(2024, 5, 1, 10, 30, tzinfo=UTC)))
    assert [(name, r.deleted_at) for name, r in found] == [("speed", utc("2024-05-01T11:00:00Z"))]


def test_entity_deletion_marks_every_attribute(client):
    notify_ld(
        client,
        vehicle(
            speed={"type": "Property", "value": 5, "observedAt": "2024-05-01T10:00:00Z"},
            isParked={"type": "Relationship", "object": "urn:ngsi-ld:OffStreetParking:Downtown1"},
            brandName=[{"type": "Property", "value": "M"}, {"type": "Property", "value": "D", "datasetId": "urn:d"}],
        ),
    )
    notify_ld(client, {"id": "urn:ngsi-ld:Vehicle:A4567", "type": "Vehicle", "deletedAt": "2024-05-02T00:00:00Z"})
    found = instances(client, window=InstanceWindow("deletedAt"))
    assert sorted((name, r.dataset_id or "", r.deleted_at, r.kind) for name, r in found) == [
        ("brandName", "", utc("2024-05-02T00:00:00Z"), Kind.NULL),
        ("brandName", "urn:d", utc("2024-05-02T00:00:00Z"), Kind.NULL),
        ("isParked", "", utc("2024-05-02T00:00:00Z"), Kind.NULL),
        ("speed", "", utc("2024-05-02T00:00:00Z"), Kind.NULL),
    ]
    # NGSIv2 sees the deletion as a null at the deletion time.
    v2 = client.get("/v2/entities/urn:ngsi-ld:Vehicle:A4567/attrs/speed").json()
    assert v2["values"][-1] is None and v2["index"][-1] == "2024-05-02T00:00:00.000+00:00"


def test_instance_ids_are_unique_and_survive_compaction_and_restart(client_factory, store_url):
    with client_factory(store_url) as client:
        for second in range(4):
            notify_ld(
                client,
                vehicle(
                    speed={"type": "Property", "value": second, "observedAt": f"2024-05-01T10:00:0{second}Z"},
                    heading={"type": "Property", "value": second * 10},
                ),
            )
        before = {(name, r.num): r.iid for name, r in instances(client)}
        assert len(set(before.values())) == 8
        store = client.app.state.store
        if hasattr(store, "compact"):
            store.compact(full=True)
        assert {(name, r.num): r.iid for name, r in instances(client)} == before
    with client_factory(store_url) as client:
        assert {(name, r.num): r.iid for name, r in instances(client)} == before
        notify_ld(client, vehicle(speed={"type": "Property", "value": 9}))
        after = {r.iid for _, r in instances(client)}
        assert len(after) == 9 and after > set(before.values())


def test_instance_urn_round_trip():
    assert instance_iid(instance_urn(12345)) == 12345
    assert instance_urn(1) == "urn:ngsi-ld:attribute:instance:0000000000000001"
    for bad in (
        "urn:ngsi-ld:attribute:instance:",
        "urn:x:1",
        "urn:ngsi-ld:attribute:instance:xyz",
        "urn:ngsi-ld:attribute:instance:00000000000000001",
    ):
        assert instance_iid(bad) is None


def test_last_n_and_limit(client):
    for second in range(5):
        notify_ld(
            client,
            vehicle(
                speed={"type": "Property", "value": second, "observedAt": f"2024-05-01T10:00:0{second}Z"},
                heading={"type": "Property", "value": 100 + second, "observedAt": f"2024-05-01T10:00:0{second}Z"},
            ),
        )
    last = instances(client, last_n=2)
    assert sorted((name, r.num) for name, r in last) == [("heading", 103), ("heading", 104), ("speed", 3), ("speed", 4)]
    first = instances(client, limit=3)
    assert sorted(r.num for _, r in first) == [0, 1, 100]
    newest = instances(client, limit=1, newest_first=True)
    assert [r.observed_at for _, r in newest] == [utc("2024-05-01T10:00:04Z")]


def test_observed_at_window_falls_back_to_row_time(client, notify):
    """NGSIv2 samples have no observedAt: their row time stands in."""
    notify(
        client,
        {
            "data": [
                {
                    "id": "urn:ngsi-ld:Vehicle:A4567",
                    "type": "Vehicle",
                    "speed": {"type": "Number", "value": 3},
                    "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
                }
            ]
        },
    )
    window = InstanceWindow("observedAt", datetime(2024, 5, 1, 10, tzinfo=UTC), datetime(2024, 5, 1, 11, tzinfo=UTC))
    got = instances(client, window=window)
    assert {name for name, _ in got} == {"speed", "TimeInstant"}
    assert all(r.observed_at is None and r.at == utc("2024-05-01T10:00:00Z") for _, r in got)


def test_unknown_time_property_is_refused():
    with pytest.raises(ValueError):
        InstanceWindow("foo")


def test_copy_keeps_instances(client_factory, store_url, store_url_factory):
    """``tsdb-service copy`` carries observedAt, datasets and deletions, and
    keeps instances that repeat (the copy is not a re-notification)."""
    from tsdb_service.commands.copy import copy_history
    from tsdb_service.core.config import Settings
    from tsdb_service.storage import open_store

    with client_factory(store_url) as client:
        notify_ld(
            client,
            vehicle(
                speed=[
                    {"type": "Property", "value": 1, "observedAt": "2024-05-01T10:00:00Z"},
                    {"type": "Property", "value": 2, "datasetId": "urn:d", "observedAt": "2024-05-01T10:00:00Z"},
                ]
            ),
        )
        notify_ld(
            client,
            vehicle(speed={"type": "Property", "value": "urn:ngsi-ld:null", "deletedAt": "2024-05-01T11:00:00Z"}),
        )
        source_rows = sorted(
            (n, r.dataset_id or "", repr(r.num), r.observed_at, r.deleted_at) for n, r in instances(client)
        )
    target_url = store_url_factory("copy_target")
    source, target = open_store(Settings(db=store_url)), open_store(Settings(db=target_url))
    try:
        copy_history(source, target, source_id=store_url)
    finally:
        source.close()
        target.close()
    with client_factory(target_url) as client:
        rows = sorted((n, r.dataset_id or "", repr(r.num), r.observed_at, r.deleted_at) for n, r in instances(client))
    assert rows == source_rows and len(rows) == 3


def test_repeats_within_one_batch_of_a_new_series_are_stored_once(client):
    """Orion-LD's first notifications of an entity can land in one group
    commit, before the series exists: the repeat is still recognised."""
    from tsdb_service.core.model import AttrSample, EntitySample
    from tsdb_service.write.ops import AppendSamples

    observed = datetime(2024, 5, 1, 9, tzinfo=UTC)

    def sample(value: str, t: int) -> EntitySample:
        attr = AttrSample("brandName", "Property", Kind.TEXT, txt=value, observed_at=observed)
        return EntitySample(
            "", "/", "urn:ngsi-ld:Vehicle:A4567", "Vehicle", datetime(2024, 5, 1, 10, t, tzinfo=UTC), [attr]
        )

    store = client.app.state.store
    store.write_sync([AppendSamples([sample("M", 0), sample("M", 1), sample("D", 2), sample("D", 3)])])
    assert [r.txt for _, r in instances(client)] == ["M", "D"]
    # dedup=False (copies, API writes) stores every one, and the latest is still known.
    store.write_sync([AppendSamples([sample("D", 4)], dedup=False)])
    store.write_sync([AppendSamples([sample("D", 5)])])
    assert [r.txt for _, r in instances(client)] == ["M", "D", "D"]
