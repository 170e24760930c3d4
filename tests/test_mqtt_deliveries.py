"""MQTT deliveries in the store (issue 31, migration 0012), on both backends.

A message's identity (``write.ops.Delivery``) is recorded in the same
transaction as what it stored, samples or a rejected row, so the consumer
(``ingest.mqtt``) can tell a broker's redelivery of a stored message after a
crash. Here the store's side: deliveries come back newest first per client
id, a delivery recorded twice (an ingest-log replay) is kept once,
``prune_below`` forgets older ones, and a rejected message keeps its topic.
"""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind, RejectedNotification
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples, Delivery, RecordRejected

T0 = datetime(2025, 3, 1, 12, tzinfo=UTC)


def delivery(seq: int, client: str = "tsdb-a", prune_below: int = 0) -> Delivery:
    return Delivery(client, seq, seq % 65535 + 1, seq.to_bytes(16, "big"), T0, prune_below)


def sample(n: int) -> EntitySample:
    return EntitySample("acme", "/", f"e{n}", "T", T0, [AttrSample("x", "Number", Kind.NUMBER, num=float(n))])


@pytest.fixture
def store(store_url):
    s = open_store(Settings(db=store_url))
    yield s
    s.close()


def test_deliveries_are_recorded_with_their_samples_newest_first(store):
    store.write_sync([AppendSamples([sample(1)], deliveries=(delivery(1),))])
    store.write_sync([AppendSamples([sample(2), sample(3)], deliveries=(delivery(2), delivery(3)))])
    store.write_sync([AppendSamples([sample(4)], deliveries=(delivery(1, client="tsdb-b"),))])
    store.sync()
    assert store.deliveries("tsdb-a", 10) == [(s, s + 1, s.to_bytes(16, "big")) for s in (3, 2, 1)]
    assert store.deliveries("tsdb-a", 2) == [(3, 4, (3).to_bytes(16, "big")), (2, 3, (2).to_bytes(16, "big"))]
    assert store.deliveries("tsdb-b", 10) == [(1, 2, (1).to_bytes(16, "big"))]
    assert store.deliveries("nobody", 10) == []


def test_a_message_without_samples_is_recorded_too(store):
    """An empty notification (``data: []``) stores nothing but was delivered."""
    store.write_sync([AppendSamples([], deliveries=(delivery(5),))])
    store.sync()
    assert [seq for seq, _, _ in store.deliveries("tsdb-a", 10)] == [5]


def test_a_delivery_recorded_again_is_kept_once(store):
    store.write_sync([AppendSamples([sample(1)], deliveries=(delivery(1),))])
    store.write_sync([AppendSamples([], deliveries=(delivery(1),))])  # as a replay of the log would
    store.sync()
    assert [seq for seq, _, _ in store.deliveries("tsdb-a", 10)] == [1]


def test_prune_below_forgets_older_deliveries_of_that_client_only(store):
    store.write_sync([AppendSamples([sample(n)], deliveries=(delivery(n),)) for n in range(1, 6)])
    store.write_sync([AppendSamples([sample(9)], deliveries=(delivery(1, client="tsdb-b"),))])
    store.write_sync([AppendSamples([sample(6)], deliveries=(delivery(6, prune_below=4),))])
    store.sync()
    assert [seq for seq, _, _ in store.deliveries("tsdb-a", 10)] == [6, 5, 4]
    assert [seq for seq, _, _ in store.deliveries("tsdb-b", 10)] == [1]


def test_a_rejected_message_keeps_its_topic_and_its_delivery(store):
    now = datetime.now(UTC)  # older rejections are dropped (TSDB_REJECTED_MAX_AGE_DAYS)
    rejected = RejectedNotification(
        "acme", now, "ParseError", "not JSON", '{"content-type":"application/json"}', b"{oops", topic="tsdb/acme/"
    )
    store.write_sync([RecordRejected(rejected, delivery(7))])
    (row,), _ = store.rejected_page("acme", 10, 0, 1 << 20)
    assert (row["topic"], row["body"], row["error"]) == ("tsdb/acme/", "{oops", "ParseError")
    assert [seq for seq, _, _ in store.deliveries("tsdb-a", 10)] == [7]
    assert store.rejected_notifications()[0].topic == "tsdb/acme/"  # copies carry it
