"""Fuzzing every operation of the OpenAPI description with schemathesis.

The description is the app's own ``/openapi.json``; schemathesis generates
requests from it (valid ones, and invalid ones that break its schemas) and
sends them to the app in-process, on each backend, with a small dataset
loaded first so reads hit data. Every answer must:

* not be a 5xx (a 500 is a bug; a 503 would mean the store broke);
* have a documented status code and content type, and a body that matches
  the documented schema (errors in the NGSI shape included);

and every notification answered 200 must be readable afterwards, value and
time index, before the delete operations run last.

Bounded and deterministic: a fixed number of examples per operation and mode
(``TSDB_FUZZ_EXAMPLES``, default 10; notify twice that), derandomized, no example database.
Derandomized generation gives both backends the same cases, so the second
backend replays the first one's instead of generating them again.
"""

from __future__ import annotations

import contextlib
import os
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from urllib.parse import quote

import hypothesis
import orjson
import pytest
import schemathesis
from hypothesis import HealthCheck, Phase
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.checks import (
    content_type_conformance,
    not_a_server_error,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)
from schemathesis.python import asgi

from tsdb_service.core.timefmt import iso_ms
from tsdb_service.history.service import decode
from tsdb_service.parse import parse_notification

EXAMPLES = int(os.environ.get("TSDB_FUZZ_EXAMPLES", "10"))
CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
    response_headers_conformance,
]
NOTIFY_PATHS = ("/v2/notify", "/ngsi-ld/v1/notify")
# Connection refused at once: /v2/subscribe must not reach out to generated hosts.
UNREACHABLE_BROKER = "http://127.0.0.1:9/v2"

ROOM = "urn:ngsi-ld:Room:1"
DATASET = [
    {
        "subscriptionId": "s1",
        "data": [
            {
                "id": ROOM,
                "type": "Room",
                "temperature": {"type": "Number", "value": 20.5 + i},
                "state": {"type": "Text", "value": "open" if i % 2 else "closed"},
                "on": {"type": "Boolean", "value": i % 2 == 0},
                "odom": {"type": "StructuredValue", "value": {"twist": {"linear": {"x": i / 10}}}},
                "location": {"type": "geo:json", "value": {"type": "Point", "coordinates": [13.4 + i / 1000, 52.5]}},
                "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:0{i}:00Z"},
            }
            for i in range(5)
        ],
    },
    {
        "subscriptionId": "s1",
        "data": [
            {
                "id": "urn:ngsi-ld:Room:2",
                "type": "Room",
                "temperature": {"type": "Number", "value": 18},
                "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"},
            },
            {
                "id": "Lawnmower01",
                "type": "ROS2System",
                "speed": {"type": "Number", "value": 0.4},
                "TimeInstant": {"type": "DateTime", "value": "2024-05-01T10:00:30Z"},
            },
        ],
    },
]
KNOWN_PATH = {
    "entity_id": ROOM,
    "entity_type": "Room",
    "attr_name": "temperature",
    "use_case": "lawnmower",
    "file": "datasources.yaml",
    "subscription_id": "s1",
    "attr_id": "temperature",
    "instance_id": "urn:ngsi-ld:attribute:instance:0000000000000001",
}


@dataclass
class Tally:
    operations: int = 0
    examples: int = 0
    statuses: dict[int, int] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    acked: list[tuple[dict, bytes]] = field(default_factory=list)


@pytest.fixture
def fuzz_app(app_factory, store_url):
    """The app under test, started by schemathesis' own ASGI client (one
    event loop, the lifespan run once), with the dataset stored."""
    app = app_factory(store_url)
    client = asgi.get_client(app).__enter__()
    try:
        for body in DATASET:
            r = client.post("/v2/notify", data=orjson.dumps(body), headers={"Content-Type": "application/json"})
            assert r.status_code == 200, r.text
        yield app, client
    finally:
        asgi.shutdown_lifespans()


def test_fuzz_the_openapi_description(fuzz_app):
    app, client = fuzz_app
    schema = schemathesis.openapi.from_dict(app.openapi())
    operations = [result.ok() for result in schema.get_all_operations()]
    tally = Tally()
    started = time.monotonic()
    writes_last = sorted(operations, key=lambda op: op.method.upper() == "DELETE")
    checked_durability = False
    for operation in writes_last:
        if operation.method.upper() == "DELETE" and not checked_durability:
            _check_acknowledged_readable(app, client, tally)
            checked_durability = True
        _fuzz(operation, app, client, tally)
    if not checked_durability:
        _check_acknowledged_readable(app, client, tally)
    elapsed = time.monotonic() - started
    print(
        f"\nfuzzed {tally.operations} operations with {tally.examples} examples in {elapsed:.1f} s; "
        f"statuses {dict(sorted(tally.statuses.items()))}; {len(tally.acked)} notifications acknowledged"
    )
    assert tally.operations >= 45
    if tally.failures and os.environ.get("TSDB_FUZZ_TRACE"):
        with open(os.environ["TSDB_FUZZ_TRACE"], "w") as out:
            out.write("\n\n".join(tally.failures))
    assert not tally.failures, "\n\n".join(tally.failures)


# The cases generated per (method, path, mode). Generation is derandomized, so
# every backend gets the same cases, and generating them is most of the
# fuzzing's time: the first backend's complete runs are replayed on the next.
_GENERATED: dict[tuple[str, str, str], list] = {}


def _fuzz(operation, app, client, tally: Tally) -> None:
    """Positive and negative examples of one operation; a failure is
    recorded (not raised) so one run reports every operation's problems."""
    tally.operations += 1
    for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
        key = (operation.method.upper(), operation.path, mode.value)

        def check(case):
            tally.examples += 1
            response = case.call(session=client)
            tally.statuses[response.status_code] = tally.statuses.get(response.status_code, 0) + 1
            if response.status_code == 200 and operation.path in NOTIFY_PATHS:
                tally.acked.append((dict(response.request.headers), response.request.body or b""))
            case.validate_response(response, checks=CHECKS)

        t0 = time.monotonic()
        try:
            if key in _GENERATED:
                for case in _GENERATED[key]:
                    check(case)
            else:
                _GENERATED.update(_generate(operation, mode, key, check))
        except (Exception, BaseExceptionGroup) as exc:
            tally.failures.append(f"{operation.method.upper()} {operation.path} ({mode.value}): {exc}")
        if os.environ.get("TSDB_FUZZ_TRACE"):
            print(f"{time.monotonic() - t0:6.2f}s {operation.method.upper()} {operation.path} {mode.value}")


def _generate(operation, mode: GenerationMode, key: tuple[str, str, str], check) -> dict:
    """Generate and ``check`` the cases of one operation and mode; returns
    ``{key: cases}`` for a complete run (nothing when nothing can be
    generated), raises at the first failing case."""
    strategy = _strategy(operation, mode)
    if strategy is None:
        return {}
    generated: list = []

    @hypothesis.settings(
        max_examples=EXAMPLES * (2 if operation.path in NOTIFY_PATHS else 1),
        derandomize=True,
        database=None,
        deadline=None,
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=list(HealthCheck),
        report_multiple_bugs=False,
        verbosity=hypothesis.Verbosity.quiet,
    )
    @hypothesis.given(case=strategy)
    def run(case):
        generated.append(case)
        check(case)

    with contextlib.suppress(hypothesis.errors.Unsatisfiable):  # nothing to break (no parameters, no body)
        run()
    return {key: generated}


def _strategy(operation, mode: GenerationMode):
    names = {p.name for p in operation.path_parameters}
    fixed = {"query": {"orionUrl": UNREACHABLE_BROKER}} if operation.path == "/v2/subscribe" else {}
    try:
        free = operation.as_strategy(generation_mode=mode, **fixed)
    except Exception:
        return None
    if not names:
        return free
    known = operation.as_strategy(generation_mode=mode, path_parameters={n: KNOWN_PATH[n] for n in names}, **fixed)
    return st.one_of(free, known)


# --- acknowledged means stored ------------------------------------------------------------------------


def _check_acknowledged_readable(app, client, tally: Tally) -> None:
    """Each sample of each notification answered 200 is read back: its value
    at its time index (or, where the time index fell back to the reception
    time, among the attribute's values)."""
    layouts = app.state.store.values_layout
    for headers, body in tally.acked:
        first = _parse(body, headers, layouts, datetime(2000, 1, 1, tzinfo=UTC))
        second = _parse(body, headers, layouts, datetime(2001, 1, 1, tzinfo=UTC))
        for one, other in zip(first, second, strict=True):
            for attr in one.attrs:
                _read_back(client, one, attr, fell_back=one.time_index != other.time_index, tally=tally)


def _parse(body, headers, layouts, received_at):
    return parse_notification(body, headers, received_at=received_at, values_layout=layouts)


def _read_back(client, sample, attr, *, fell_back: bool, tally: Tally) -> None:
    params = {"type": sample.entity_type}
    if not fell_back:
        moment = sample.time_index.isoformat()
        params.update(fromDate=moment, toDate=moment)
    headers = {"Fiware-Service": sample.tenant, "Fiware-ServicePath": sample.service_path}
    url = f"/v2/entities/{quote(sample.entity_id, safe='')}/attrs/{quote(attr.name, safe='')}"
    r = client.get(url, params=params, headers=headers)
    expected = decode(int(attr.kind), attr.num, attr.txt, attr.js)
    where = f"{sample.tenant!r}{sample.service_path} {sample.entity_id!r}/{attr.name!r} @ {sample.time_index}"
    if r.status_code != 200:
        tally.failures.append(f"acknowledged sample not readable: {where}: {r.status_code} {r.text[:300]}")
        return
    doc = r.json()
    if expected not in doc["values"] or (not fell_back and iso_ms(sample.time_index) not in doc["index"]):
        tally.failures.append(
            f"acknowledged sample read back differently: {where}: sent {expected!r}, "
            f"read {doc['values'][:5]!r} at {doc['index'][:5]!r}"
        )
