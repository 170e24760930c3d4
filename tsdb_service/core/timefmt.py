"""Every time format the APIs answer with, and the one way back to a number.

Times are stored in UTC with microsecond precision. Each API writes them its
own way; all of those writers live here, so a format is defined once:

* ``iso_ms`` / ``iso_ms_us``: the QuantumLeap 1.0 history format,
  ``2024-05-01T10:00:00.123+00:00`` (milliseconds, explicit offset). The SQL
  renderer's ``Dialect.iso_ms`` writes the same text in the database; the
  DuckDB tail cache formats its in-memory rows with ``iso_ms_us``.
* ``iso_z`` / ``z_of``: Grafana's ``2024-05-01T10:00:00.123Z``.
* ``ld_iso`` / ``ld_iso_us``: NGSI-LD, ``Z`` and as many fractional
  digits as the time needs: none on a whole second, milliseconds, or
  microseconds (Stellio's ``ISO_INSTANT``), so ``12:03:00Z`` sent comes
  back ``12:03:00Z``.
* ``epoch_ms`` / ``ms_of``: back to epoch milliseconds (Grafana's unit).

Why the querier keeps answering ISO text rather than epoch microseconds
(and Grafana parses it back): ``benchmarks/timefmt.py``, 10,000 rows of one
series, median ms of 30 runs on the shared 2-core machine (two runs; the
PostgreSQL figures vary with the load):

=============================================  ========  ==========
                                               DuckDB    PostgreSQL
=============================================  ========  ==========
history: ISO from SQL (kept)                   4.3-4.7   11-15
history: epoch from SQL + ``iso_ms_us``        15.3      36
Grafana: ISO from SQL + ``epoch_ms`` (kept)    8.3-8.6   15-19
Grafana: epoch from SQL + ``// 1000``          2.9       9-16
=============================================  ========  ==========

The database formats 10,000 times in about 2 ms; Python needs about 13 ms
even with integer arithmetic and a cached date (``iso_ms_us``; 22 ms
through ``datetime``), while Grafana's parse back costs 4 ms. Epoch
microseconds would make Grafana about 5 ms faster per 10,000 rows and the
history API, the hot path (QuantumLeap clients, lastN, aggregation), 11 to
20 ms slower; so the history format stays in SQL and Grafana pays its parse.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from functools import lru_cache

_EPOCH = datetime(1970, 1, 1)


def iso_ms(moment: datetime) -> str:
    """A UTC datetime → ``2024-05-01T10:00:00.123+00:00`` (history)."""
    return (
        f"{moment.year:04d}-{moment.month:02d}-{moment.day:02d}T{moment.hour:02d}:"
        f"{moment.minute:02d}:{moment.second:02d}.{moment.microsecond // 1000:03d}+00:00"
    )


@lru_cache(maxsize=4096)
def _day(days: int) -> str:
    moment = _EPOCH + timedelta(days=days)
    return f"{moment.year:04d}-{moment.month:02d}-{moment.day:02d}T"


def iso_ms_us(micros: int) -> str:
    """Epoch microseconds → the history format (``iso_ms``): integer
    arithmetic and a cached date, twice as fast as going through datetime."""
    days, rest = divmod(micros, 86_400_000_000)
    seconds, ms = divmod(rest // 1000, 1000)
    minutes, seconds = divmod(seconds, 60)
    hours, minutes = divmod(minutes, 60)
    return f"{_day(days)}{hours:02d}:{minutes:02d}:{seconds:02d}.{ms:03d}+00:00"


def iso_z(ms: int) -> str:
    """Epoch milliseconds → ``2024-05-01T10:00:00.123Z`` (Grafana)."""
    moment = datetime.fromtimestamp(ms / 1000.0, tz=UTC)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{ms % 1000:03d}Z"


def iso_z_ms(ms: int) -> str:
    """Epoch milliseconds → ``iso_z``'s text, with the minute's text cached
    (drawn points are up to 100,000 a request)."""
    minute, rest = divmod(ms, 60_000)
    return f"{_minute(minute)}{rest // 1000:02d}.{rest % 1000:03d}Z"


@lru_cache(maxsize=65_536)
def _minute(minutes: int) -> str:
    days, rest = divmod(minutes, 1440)
    return f"{_day(days)}{rest // 60:02d}:{rest % 60:02d}:"


@lru_cache(maxsize=4096)
def _day_ms(date: str) -> int:
    return round(datetime.fromisoformat(date).replace(tzinfo=UTC).timestamp()) * 1000


def ms_of_iso(iso: str) -> int:
    """A history-format time (``YYYY-MM-DDTHH:MM:SS.mmm+00:00``, what the
    backends format) → epoch milliseconds, with a cached date; any other
    ISO text through ``epoch_ms``."""
    if len(iso) == 29 and iso[10] == "T" and iso.endswith("+00:00") and iso[19] == ".":
        hours, minutes, seconds, ms = iso[11:13], iso[14:16], iso[17:19], iso[20:23]
        if (hours + minutes + seconds + ms).isdigit():
            return _day_ms(iso[:10]) + ((int(hours) * 60 + int(minutes)) * 60 + int(seconds)) * 1000 + int(ms)
    return epoch_ms(iso)


def z_of(iso: str) -> str:
    """A history-format time with ``Z`` for ``+00:00`` (Grafana)."""
    return iso[:-6] + "Z" if iso.endswith("+00:00") else iso


def epoch_ms(iso: str) -> int:
    """A history-format time (``...+00:00``) → epoch milliseconds."""
    return round(datetime.fromisoformat(iso).timestamp() * 1000)


def ms_of(moment: datetime | None) -> int | None:
    """An aware datetime → epoch milliseconds (None stays None)."""
    return None if moment is None else round(moment.timestamp() * 1000)


def ld_iso(moment: datetime) -> str:
    """A UTC datetime (naive or aware) → ``YYYY-MM-DDTHH:MM:SSZ`` on a whole
    second, ``...SS.sssZ`` on a whole millisecond, else ``...SS.ssssssZ``
    (NGSI-LD: what was sent comes back as sent when it had at most
    millisecond precision; Java's ``ISO_INSTANT``, as Stellio writes)."""
    text = (
        f"{moment.year:04d}-{moment.month:02d}-{moment.day:02d}T"
        f"{moment.hour:02d}:{moment.minute:02d}:{moment.second:02d}"
    )
    micro = moment.microsecond
    if micro == 0:
        return f"{text}Z"
    return f"{text}.{micro // 1000:03d}Z" if micro % 1000 == 0 else f"{text}.{micro:06d}Z"


@lru_cache(maxsize=65_536)
def ld_iso_us(us: int) -> str:
    """Epoch microseconds → ``ld_iso``; cached, as the periods of every
    series of an aggregated response share their bounds."""
    return ld_iso(_EPOCH + timedelta(microseconds=us))


def received_at_z(moment: datetime) -> str:
    """A rejected notification's ``receivedAt``: milliseconds and ``Z``."""
    return moment.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
