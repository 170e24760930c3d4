"""``values``-format layouts: their rows in ``subscriptions``, and memory's copy.

A subscription registered with ``attrsFormat: values`` sends bare value
arrays; the layout (attribute names, entity id and type) that reads them is
stored by the writers (``PutLayout``) and kept in memory by ``Layouts``, so
the notification parser finds it without a database call.

``Layouts`` holds the invariant of every cache here: never ahead of the
database. A writer publishes the layouts it committed after the commit; a
read of the table replaces the whole copy, under the lock, so a layout this
process commits meanwhile is never replaced by an older read (``reload``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Sequence
from datetime import datetime

import orjson

from tsdb_service.parse import ValuesLayout
from tsdb_service.storage.columns import naive_utc
from tsdb_service.write.ops import PutLayout

LayoutKey = tuple[str, str]  # tenant, subscription id

LOAD_LAYOUTS_SQL = "SELECT tenant, subscription_id, attrs, entity_id, entity_type FROM subscriptions"


def layouts_from_rows(rows: Iterable[tuple]) -> dict[LayoutKey, ValuesLayout]:
    """``LOAD_LAYOUTS_SQL`` rows by (tenant, subscription id)."""
    return {
        (tenant, sub): ValuesLayout(tuple(orjson.loads(attrs)), eid, etype) for tenant, sub, attrs, eid, etype in rows
    }


def layout_values(put: PutLayout, now: datetime) -> list:
    """A ``subscriptions`` row, in column order."""
    layout = put.layout
    return [
        put.tenant,
        put.subscription_id,
        orjson.dumps(list(layout.attrs)).decode(),
        layout.entity_id,
        layout.entity_type,
        naive_utc(now),
    ]


def upsert_layout_sql(p: str) -> str:
    return (
        f"INSERT INTO subscriptions VALUES ({p}, {p}, {p}, {p}, {p}, {p}) "
        "ON CONFLICT (tenant, subscription_id) DO UPDATE SET attrs = EXCLUDED.attrs, "
        "entity_id = EXCLUDED.entity_id, entity_type = EXCLUDED.entity_type, "
        "registered_at = EXCLUDED.registered_at"
    )


class Layouts:
    """The registered layouts in memory, by (tenant, subscription id).

    Lookups take no lock (a dict read); ``publish``, ``replace`` and
    ``reload`` change the copy under ``_lock``."""

    def __init__(self) -> None:
        self._by_key: dict[LayoutKey, ValuesLayout] = {}
        self._lock = threading.Lock()
        self._read_at = float("-inf")  # when the table was last read (monotonic seconds)

    def get(self, tenant: str, subscription_id: str) -> ValuesLayout | None:
        return self._by_key.get((tenant, subscription_id))

    def of_tenant(self, tenant: str) -> dict[str, ValuesLayout]:
        """The tenant's layouts by subscription id."""
        return {sub: layout for (t, sub), layout in list(self._by_key.items()) if t == tenant}

    def publish(self, puts: Sequence[PutLayout]) -> None:
        """After the commit that stored ``puts``: current at once."""
        if puts:
            with self._lock:
                for put in puts:
                    self._by_key[(put.tenant, put.subscription_id)] = put.layout

    def replace(self, layouts: dict[LayoutKey, ValuesLayout]) -> None:
        """Every layout the table holds, read while nothing wrote it (a store's open)."""
        with self._lock:
            self._by_key = dict(layouts)
            self._read_at = time.monotonic()

    def reload(self, read: Callable[[], dict[LayoutKey, ValuesLayout]], max_age: float = 0.0) -> None:
        """Read the table again (``read``: a database call) unless another
        thread read it less than ``max_age`` seconds ago. Under the lock, so a
        layout published meanwhile is never replaced by an older read."""
        with self._lock:
            started = time.monotonic()
            if started - self._read_at <= max_age:
                return
            self._by_key = read()
            self._read_at = started

    def age(self) -> float:
        """Seconds since the table was last read."""
        return time.monotonic() - self._read_at
