"""Heavy readers against a running service, and one light reader timed beside them.

For ``tests/test_read_pool.py`` (a few seconds) and
``benchmarks/read_fairness.py`` (the full measurement). ``prepare`` writes a
store before the service opens it: tenant ``heavy`` with one long series
(``Meter:0``, attribute ``v``, one sample a second) and tenant ``light``
with ``Lamp:0``'s five samples. ``heavy_load`` runs in a process of its
own (``python -m tests.support.read_load URL SECONDS READERS``) so that
the readers' own work does not slow the light reader's clock; each reader
alternates an aggregation per second (as many rows as samples: past
``TSDB_READ_MAX_ROWS`` it is refused, 422, after reading them) and a
Grafana SimpleJSON query of raw points over the whole series.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections import Counter
from datetime import UTC, datetime, timedelta

import httpx

T0 = datetime(2024, 1, 1, tzinfo=UTC)
HEAVY = {"Fiware-Service": "heavy"}
LIGHT = {"Fiware-Service": "light"}


def prepare(db: str, samples: int) -> None:
    """Write the two tenants' history into the store at ``db`` (then closed)."""
    from tsdb_service.core.config import Settings
    from tsdb_service.core.model import AttrSample, EntitySample, Kind
    from tsdb_service.storage import open_store
    from tsdb_service.write.ops import AppendSamples

    store = open_store(Settings(db=db))
    try:
        step = 50_000
        for start in range(0, samples, step):
            batch = [
                EntitySample(
                    "heavy",
                    "/",
                    "Meter:0",
                    "Meter",
                    T0 + timedelta(seconds=i),
                    [AttrSample("v", "Number", Kind.NUMBER, num=float(i))],
                )
                for i in range(start, min(samples, start + step))
            ]
            store.write_sync([AppendSamples(batch)])
        lamp = [
            EntitySample(
                "light",
                "/",
                "Lamp:0",
                "Lamp",
                T0 + timedelta(minutes=i),
                [AttrSample("on", "Number", Kind.NUMBER, num=1.0)],
            )
            for i in range(5)
        ]
        store.write_sync([AppendSamples(lamp)])
    finally:
        store.close()


def _heavy_reader(url: str, until: float, outcomes: Counter, lock: threading.Lock) -> None:
    grafana = {
        "range": {"from": T0.isoformat(), "to": (T0 + timedelta(days=400)).isoformat()},
        "maxDataPoints": 10_000_000,
        "targets": [{"target": "Meter:0/v", "refId": "A"}],
    }
    with httpx.Client(base_url=url, headers=HEAVY, timeout=120) as client:
        n = 0
        while time.monotonic() < until:
            if n % 2 == 0:
                r = client.get("/v2/entities/Meter:0/attrs/v", params={"aggrMethod": "sum", "aggrPeriod": "second"})
            else:
                r = client.post("/grafana/simplejson/query", json=grafana)
            with lock:
                outcomes[r.status_code] += 1
            n += 1


def heavy_load(url: str, seconds: float, readers: int) -> Counter:
    """``readers`` threads reading for ``seconds``; the answers' status codes, counted."""
    until = time.monotonic() + seconds
    outcomes: Counter = Counter()
    lock = threading.Lock()
    threads = [threading.Thread(target=_heavy_reader, args=(url, until, outcomes, lock)) for _ in range(readers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return outcomes


def start_heavy(url: str, seconds: float, readers: int) -> subprocess.Popen:
    """``heavy_load`` in a process of its own; its last line of output is the outcome counts."""
    return subprocess.Popen(
        [sys.executable, "-m", "tests.support.read_load", url, str(seconds), str(readers)],
        stdout=subprocess.PIPE,
        text=True,
    )


def light_latencies(url: str, seconds: float, pause: float = 0.05) -> list[float]:
    """The light tenant's five-row read, again and again: each answer's time in seconds."""
    out = []
    until = time.monotonic() + seconds
    with httpx.Client(base_url=url, headers=LIGHT, timeout=60) as client:
        while time.monotonic() < until:
            start = time.perf_counter()
            r = client.get("/v2/entities/Lamp:0")
            out.append(time.perf_counter() - start)
            assert r.status_code == 200 and len(r.json()["index"]) == 5, r.text
            time.sleep(pause)
    return out


def percentile(values: list[float], p: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(p / 100 * (len(ordered) - 1)))]


if __name__ == "__main__":
    counts = heavy_load(sys.argv[1], float(sys.argv[2]), int(sys.argv[3]))
    print(" ".join(f"{code}={n}" for code, n in sorted(counts.items())))
