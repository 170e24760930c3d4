"""Bounds and pages of the rejected store, the same on both backends.

Every notification we refuse is kept so an operator can recover it, but a
client that keeps sending bad notifications must not fill the disk, and one
listing must not hand out gigabytes. So:

* **bounds**, per tenant: at most ``max_count`` rows and ``max_bytes`` of
  stored body and headers, none older than ``max_age_s``; and over all
  tenants together at most ``max_total_count`` rows and ``max_total_bytes``
  (the tenant is the one the row is stored under, and a tenant header the
  API refuses is its own tenant, as received: chosen by the sender, so the
  per-tenant bounds alone multiply by the headers an attacker invents).
  Enforced in the transaction that records a rejection (oldest dropped
  first; a tenant's newest rejection, and the newest of all, are always
  kept, so what was just refused can be read); what is dropped is counted
  by reason (``count``, ``bytes``, ``age``) for ``/metrics``.
* **pages** by size as well as by count: a listing stops before its rendered
  rows pass ``max_bytes`` (always at least one row), and says where the next
  page starts.

Backends differ only in placeholders and how a string's byte length is
written (``RejectedSpelling``); every value is a bound parameter. The rows
a writer inserts (``INSERT_COLUMNS``, ``insert_values``) are the same too.

**The rejected store takes anything.** It is where a message that cannot
be stored goes, so it must never refuse one itself: the body is kept as
bytes, and the text columns (a tenant header as received, a description
quoting the input, the headers, the topic) have the characters no
PostgreSQL text can hold escaped (``storable``: NUL as ``\\u0000``, a lone
surrogate as ``\\udXXX``), on both backends alike.
"""

from __future__ import annotations

import base64
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import orjson

from tsdb_service.core.model import RejectedNotification
from tsdb_service.core.timefmt import received_at_z
from tsdb_service.storage.columns import naive_utc

REASONS = ("count", "bytes", "age")
# What the listing shows, in ``rejected_row``'s argument order.
COLUMNS = "id, tenant, received_at, error, description, headers, body, body_size, body_truncated, topic"
# What a writer inserts (the id is the column's default, or the store's own).
INSERT_COLUMNS = "tenant, received_at, error, description, headers, body, body_size, body_truncated, topic"


def insert_values(r: RejectedNotification) -> tuple:
    """A ``rejected_notifications`` row (``INSERT_COLUMNS``), its text storable anywhere."""
    size = len(r.body) if r.body_size is None else r.body_size
    return (
        storable(r.tenant),
        naive_utc(r.received_at),
        storable(r.error),
        storable(r.description),
        storable(r.headers),
        r.body,
        size,
        r.body_truncated,
        None if r.topic is None else storable(r.topic),
    )


def storable(text: str) -> str:
    """``text`` with NUL written ``\\u0000`` and lone surrogates escaped
    (``\\udXXX``): PostgreSQL text holds neither, UTF-8 has no surrogates."""
    if text.isascii() and "\x00" not in text:
        return text
    text = text.replace("\x00", "\\u0000")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        text = text.encode("utf-8", "backslashreplace").decode("ascii", "backslashreplace")
    return text


@dataclass(frozen=True, slots=True)
class RejectedLimits:
    max_count: int = 1000
    max_bytes: int = 64 * 1024 * 1024
    max_age_s: float = 30 * 86400.0
    max_total_count: int = 10_000
    max_total_bytes: int = 256 * 1024 * 1024

    @classmethod
    def from_settings(cls, settings) -> RejectedLimits:
        return cls(
            settings.rejected_max_per_tenant,
            settings.rejected_max_bytes_per_tenant,
            settings.rejected_max_age_days * 86400.0,
            settings.rejected_max_total,
            settings.rejected_max_total_bytes,
        )


@dataclass(frozen=True, slots=True)
class RejectedSpelling:
    placeholder: str  # "?" (DuckDB) or "%s" (psycopg)
    text_bytes: str  # the function giving a text column's length in bytes

    @property
    def row_bytes(self) -> str:
        """Stored bytes of a row: body and headers (what the bounds count)."""
        return f"octet_length(body) + {self.text_bytes}(headers)"


DUCKDB = RejectedSpelling("?", "strlen")
POSTGRES = RejectedSpelling("%s", "octet_length")

Execute = Callable[[str, list], list[tuple]]


def prune(
    execute: Execute,
    dialect: RejectedSpelling,
    tenants: Iterable[str],
    limits: RejectedLimits,
    now: datetime | None = None,
) -> dict[str, int]:
    """Drop what is over the bounds, oldest first, inside the caller's
    transaction; returns rows dropped per reason. ``tenants`` are the ones
    that just got a rejection (only they can be over count or bytes)."""
    p = dialect.placeholder
    now = now or datetime.now(UTC)
    oldest = (now - timedelta(seconds=limits.max_age_s)).replace(tzinfo=None)
    dropped = dict.fromkeys(REASONS, 0)
    dropped["age"] = len(execute(f"DELETE FROM rejected_notifications WHERE received_at < {p} RETURNING id", [oldest]))
    ranked = (
        "SELECT id, row_number() OVER w AS n, sum({bytes}) OVER w AS b FROM rejected_notifications "
        "{where}WINDOW w AS (ORDER BY id DESC)"
    )
    per_tenant = ranked.format(bytes=dialect.row_bytes, where=f"WHERE tenant = {p} ")
    for tenant in sorted({storable(t) for t in tenants}):  # as insert_values stored them
        for reason, condition, bound in (("count", "n", limits.max_count), ("bytes", "b", limits.max_bytes)):
            sql = (
                f"DELETE FROM rejected_notifications WHERE id IN (SELECT id FROM ({per_tenant}) r "
                f"WHERE n > 1 AND {condition} > {p}) RETURNING id"
            )
            dropped[reason] += len(execute(sql, [tenant, bound]))
    every = ranked.format(bytes=dialect.row_bytes, where="")
    for reason, condition, bound in (("count", "n", limits.max_total_count), ("bytes", "b", limits.max_total_bytes)):
        sql = (
            f"DELETE FROM rejected_notifications WHERE id IN (SELECT id FROM ({every}) r "
            f"WHERE n > 1 AND {condition} > {p}) RETURNING id"
        )
        dropped[reason] += len(execute(sql, [bound]))
    return dropped


def page(
    execute: Execute,
    dialect: RejectedSpelling,
    tenant: str | None,
    limit: int,
    offset: int,
    max_bytes: int,
    render: Callable[..., dict[str, Any]],
) -> tuple[list[dict[str, Any]], int | None]:
    """Rows newest first, ``limit`` at most and about ``max_bytes`` of JSON
    at most (never fewer than one row), and the offset of the next page
    (None when this is the last). Sizes are read first, so rows that would
    not fit are never loaded."""
    p = dialect.placeholder
    where, params = ("", []) if tenant is None else (f"WHERE tenant = {p} ", [tenant])
    sizes = execute(
        f"SELECT id, {dialect.row_bytes} + {dialect.text_bytes}(description) FROM rejected_notifications {where}"
        f"ORDER BY id DESC LIMIT {p} OFFSET {p}",
        [*params, limit + 1, offset],
    )
    more = len(sizes) > limit
    sizes = sizes[:limit]
    take, estimate = 0, 0
    for _id, size in sizes:
        estimate += int(size) * 4 // 3 + 256  # base64 for binary bodies, JSON punctuation
        if take and estimate > max_bytes:
            break
        take += 1
    if not take:
        return [], None
    first = sizes[0][0]
    and_or_where = "AND" if where else "WHERE"
    rows = execute(
        f"SELECT {COLUMNS} FROM rejected_notifications {where}{and_or_where} id <= {p} ORDER BY id DESC LIMIT {p}",
        [*params, first, take],
    )
    out: list[dict[str, Any]] = []
    used = 0
    for row in rows:
        item = render(*row)
        used += len(orjson.dumps(item))
        if out and used > max_bytes:
            break
        out.append(item)
    cut = len(out) < len(sizes)
    return out, (offset + len(out) if more or cut else None)


_COUNT_LOCK = threading.Lock()


def count_dropped(totals: dict[str, int], dropped: dict[str, int]) -> None:
    """Add one commit's drops to a store's totals (writer threads share them)."""
    with _COUNT_LOCK:
        for reason, n in dropped.items():
            totals[reason] = totals.get(reason, 0) + n


def rejected_row(
    rid, tenant, received_at, error, description, headers, body, body_size, body_truncated, topic=None
) -> dict[str, Any]:
    """One rejected notification as the listing shows it: the body as text
    when it is UTF-8, else base64; its size as received and whether only its
    first bytes were kept (rows from before migration 0002 have no size);
    the MQTT topic it came on (null over HTTP)."""
    body = bytes(body)
    try:
        text, encoding = body.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        text, encoding = base64.b64encode(body).decode(), "base64"
    return {
        "id": rid,
        "tenant": tenant,
        "receivedAt": received_at_z(received_at),
        "error": error,
        "description": description,
        "headers": orjson.loads(headers),
        "body": text,
        "bodyEncoding": encoding,
        "bodySize": len(body) if body_size is None else int(body_size),
        "bodyTruncated": bool(body_truncated),
        "topic": topic,
    }
