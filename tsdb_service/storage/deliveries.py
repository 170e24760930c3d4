"""MQTT deliveries as rows (``ingest.mqtt``; migration 0012).

A writer records each delivery in the transaction that stores what the
message carried (its samples or its rejection), so a redelivered message is
recognised exactly when its content is stored. Both backends write the same
statements, differing only in placeholders.

``tsdb-service import rosbag`` records its progress the same way, as one
delivery per import (client id ``rosbag:<identity>``, ``seq`` the messages
stored, older rows pruned): ``commands.rosbag.importer``.
"""

from __future__ import annotations

from collections.abc import Sequence

from tsdb_service.storage.columns import naive_utc
from tsdb_service.write.ops import Delivery

_DELIVERY_ROWS = 500  # rows per INSERT statement
DELIVERY_COLUMNS = "client_id, seq, packet_id, digest, received_at"

# The newest deliveries of one client id, newest first: (seq, packet id, digest).
RECENT_DELIVERIES_SQL = (
    "SELECT seq, packet_id, digest FROM mqtt_deliveries WHERE client_id = ? ORDER BY seq DESC LIMIT ?"
)


def delivery_statements(p: str, deliveries: Sequence[Delivery]) -> list[tuple[str, list]]:
    """Record ``deliveries`` (in the caller's transaction, with what they
    stored): INSERTs that skip a delivery recorded already (an ingest-log
    replay may apply one twice), then the DELETEs their ``prune_below`` ask for."""
    out: list[tuple[str, list]] = []
    row = f"({p}, {p}, {p}, {p}, {p})"
    for start in range(0, len(deliveries), _DELIVERY_ROWS):
        chunk = deliveries[start : start + _DELIVERY_ROWS]
        params: list = []
        for d in chunk:
            params += [d.client_id, d.seq, d.packet_id, d.digest, naive_utc(d.received_at)]
        values = ", ".join([row] * len(chunk))
        out.append((f"INSERT INTO mqtt_deliveries ({DELIVERY_COLUMNS}) VALUES {values} ON CONFLICT DO NOTHING", params))
    prune: dict[str, int] = {}
    for d in deliveries:
        if d.prune_below:
            prune[d.client_id] = max(prune.get(d.client_id, 0), d.prune_below)
    for client_id, below in sorted(prune.items()):
        out.append((f"DELETE FROM mqtt_deliveries WHERE client_id = {p} AND seq < {p}", [client_id, below]))
    return out
