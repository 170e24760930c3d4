"""The disk-full scenario shared by the disk-full tests (DuckDB and PostgreSQL,
in process and through a real server): notifications with a unique sequence
number each, the outcome of every POST, and the check that what was
acknowledged is stored exactly once and what was refused as "nothing was
stored" is not stored at all.

``post`` is any callable ``(method, path, body|None) -> (status, json)``, so
the same code drives a TestClient and a real server over HTTP.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

TENANT = "diskfull"
ENTITY = "urn:ngsi-ld:Disk:1"
HEADERS = {"Content-Type": "application/json", "Fiware-Service": TENANT, "Fiware-ServicePath": "/"}
READ_HEADERS = {"Fiware-Service": TENANT}
PAD = "p" * 900  # makes every notification grow the write-ahead log by ~1 kB

Post = Callable[[str, str, bytes | None], tuple[int, dict]]


def notification(seq: int) -> bytes:
    stamp = f"2024-05-01T{seq // 3600000 % 24:02d}:{seq // 60000 % 60:02d}:{seq // 1000 % 60:02d}.{seq % 1000:03d}Z"
    entity = {
        "id": ENTITY,
        "type": "DiskSensor",
        "seq": {"type": "Number", "value": seq},
        "pad": {"type": "Text", "value": f"{PAD}{seq}"},
        "TimeInstant": {"type": "DateTime", "value": stamp},
    }
    return json.dumps({"subscriptionId": "5f00000000000000000d15c0", "data": [entity]}).encode()


@dataclass
class Outcomes:
    acked: set[int] = field(default_factory=set)
    not_stored: set[int] = field(default_factory=set)  # 503 saying nothing was stored
    unsure: set[int] = field(default_factory=set)  # 503 saying it may have been stored
    statuses: Counter = field(default_factory=Counter)
    bodies: list[dict] = field(default_factory=list)
    next_seq: int = 1
    lock: threading.Lock = field(default_factory=threading.Lock)

    def send(self, post: Post) -> int:
        """POST the next notification and record its outcome (thread-safe)."""
        with self.lock:
            seq = self.next_seq
            self.next_seq += 1
        status, body = post("POST", "/v2/notify", notification(seq))
        with self.lock:
            self._record(seq, status, body)
        return status

    def _record(self, seq: int, status: int, body: dict) -> None:
        self.statuses[status] += 1
        if status == 200:
            self.acked.add(seq)
        elif status == 503:
            self.bodies.append(body)
            assert body.get("error") == "ServiceUnavailable", body
            text = body.get("description", "")
            if "nothing was stored" in text:
                self.not_stored.add(seq)
            else:
                assert "may" in text, body  # never a false "nothing was stored"
                self.unsure.add(seq)
        else:
            raise AssertionError(f"POST /v2/notify {seq} answered {status}: {body}")


def health(post: Post) -> tuple[int, dict]:
    return post("GET", "/health", None)


def wait_healthy(post: Post, outcomes: Outcomes, timeout: float = 30.0) -> dict:
    """Post notifications until /health passes: it fails until a write has
    succeeded again (or the database was reopened), as an operator's traffic
    would show."""
    deadline = time.monotonic() + timeout
    while True:
        outcomes.send(post)
        status, body = health(post)
        if status == 200 and body["status"] == "pass":
            return body
        assert status == 503 and body["status"] == "fail", (status, body)
        if time.monotonic() > deadline:
            raise AssertionError(f"not healthy after {timeout} s: {body}")
        time.sleep(0.2)


def stored_seqs(post: Post) -> Counter:
    status, body = post("GET", f"/v2/entities/{ENTITY}/attrs/seq?limit=10000", None)
    assert status == 200, body
    return Counter(int(v) for v in body["values"])


def check_exactly_once(outcomes: Outcomes, stored: Counter) -> None:
    duplicated = sorted(seq for seq, n in stored.items() if n > 1)
    assert not duplicated, f"stored more than once: {duplicated}"
    lost = sorted(outcomes.acked - stored.keys())
    assert not lost, f"acknowledged but not stored: {lost}"
    phantom = sorted(outcomes.not_stored & stored.keys())
    assert not phantom, f"answered 'nothing was stored' but stored: {phantom}"
    unexplained = sorted(stored.keys() - outcomes.acked - outcomes.unsure)
    assert not unexplained, f"stored without a 200: {unexplained}"
