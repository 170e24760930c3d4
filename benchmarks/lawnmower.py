"""Issue 15's workload: a 5-attribute Lawnmower entity in Orion's normalized format.

Every notification carries one ``Lawnmower`` entity with ``TimeInstant`` (the
time index) and five attributes of the kinds a robot sends: ``batteryLevel``
and ``speed`` (Number), ``status`` (Text), ``location`` (geo:json Point) and
``cmd_vel`` (StructuredValue).

- Ingest (``ingest_*``): entity ``urn:ngsi-ld:Lawnmower:<run>-<seq % pool>``,
  ``batteryLevel`` = seq + 0.25 and ``TimeInstant`` = 2024-05-01 + seq ms:
  every notification is unique and can be found in the store afterwards.
  The same body is built in Lua (for wrk) and in Python (sanity request,
  loadgen fallback); ``test_body_matches_lua`` in compare.py's self-check
  keeps them equal.
- Queries (``dataset_*``): 20 entities x 1 day at one sample per minute
  (1,440 notifications, each with the 20 entities of one minute, as Orion
  sends after a batch update), tenant ``benchquery``; loaded over HTTP into
  any service (ours or QuantumLeap) with ``load_dataset``.
"""

from __future__ import annotations

import http.client
import json
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime, timedelta
from urllib.parse import urlsplit

ENTITY_TYPE = "Lawnmower"
INGEST_TENANT = "benchingest"
QUERY_TENANT = "benchquery"
SUBSCRIPTION = "65f1a2b3c4d5e6f7081920a1"
BASE = datetime(2024, 5, 1, tzinfo=UTC)
BASE_EPOCH = int(BASE.timestamp())
STATES = ("mowing", "docked", "returning")
DATASET_ENTITIES = 20
DATASET_MINUTES = 24 * 60
DAY_FROM = "2024-05-01T00:00:00Z"
DAY_TO = "2024-05-01T23:59:59Z"

ENTITY_FMT = (
    '{"id":"urn:ngsi-ld:Lawnmower:%s","type":"Lawnmower",'
    '"TimeInstant":{"type":"DateTime","value":"%s","metadata":{}},'
    '"batteryLevel":{"type":"Number","value":%s,"metadata":{}},'
    '"speed":{"type":"Number","value":%.2f,"metadata":{}},'
    '"status":{"type":"Text","value":"%s","metadata":{}},'
    '"location":{"type":"geo:json","value":{"type":"Point","coordinates":[%.6f,%.6f]},"metadata":{}},'
    '"cmd_vel":{"type":"StructuredValue","value":{"linear":{"x":%.1f,"y":0,"z":0},'
    '"angular":{"x":0,"y":0,"z":%.1f}},"metadata":{}}}'
)
NOTIFICATION_FMT = '{"subscriptionId":"' + SUBSCRIPTION + '","data":[%s]}'


def headers(tenant: str) -> dict[str, str]:
    return {
        "Content-Type": "application/json",
        "Fiware-Service": tenant,
        "Fiware-ServicePath": "/",
        "Ngsiv2-AttrsFormat": "normalized",
    }


def query_headers(tenant: str = QUERY_TENANT) -> dict[str, str]:
    return {"Fiware-Service": tenant, "Fiware-ServicePath": "/"}


# --- ingest ----------------------------------------------------------------------------


def ingest_body(run_id: str, seq: int, pool: int) -> bytes:
    """The notification number ``seq`` of run ``run_id`` (must equal the Lua one)."""
    e = seq % pool
    ms = seq % 1000
    t = datetime.fromtimestamp(BASE_EPOCH + seq // 1000, UTC)
    stamp = t.strftime("%Y-%m-%dT%H:%M:%S") + f".{ms:03d}Z"
    entity = ENTITY_FMT % (
        f"{run_id}-{e}",
        stamp,
        f"{seq}.25",
        (seq % 50) / 100,
        STATES[seq % 3],
        -3.7 + (seq % 1000) / 100000,
        40.4 + (e % 1000) / 100000,
        (seq % 10) / 10,
        (seq % 7) / 10,
    )
    return (NOTIFICATION_FMT % entity).encode()


def ingest_lua(run_id: str, pool: int) -> tuple[str, str]:
    """(prelude, body expression) building ``ingest_body`` in wrk's Lua."""
    entity = ENTITY_FMT.replace('"id":"urn:ngsi-ld:Lawnmower:%s"', '"id":"urn:ngsi-ld:Lawnmower:%s-%d"')
    prelude = f"""
local FMT = [==[{NOTIFICATION_FMT.replace("%s", entity)}]==]
local STATES = {{"{STATES[0]}", "{STATES[1]}", "{STATES[2]}"}}
local RUN = "{run_id}"
local POOL = {pool}
local function body(seq)
  local e = seq % POOL
  local stamp = os.date("!%Y-%m-%dT%H:%M:%S", {BASE_EPOCH} + math.floor(seq / 1000)) ..
                string.format(".%03dZ", seq % 1000)
  return string.format(FMT, RUN, e, stamp, string.format("%d.25", seq), (seq % 50) / 100,
                       STATES[seq % 3 + 1], -3.7 + (seq % 1000) / 100000, 40.4 + (e % 1000) / 100000,
                       (seq % 10) / 10, (seq % 7) / 10)
end
"""
    return prelude, "body(seq)"


# --- the query data set ------------------------------------------------------------------


def dataset_entity(e: int) -> str:
    return f"q{e:02d}"


def dataset_notification(minute: int) -> bytes:
    """Minute ``minute`` of the day for all 20 entities, in one notification."""
    t = BASE + timedelta(minutes=minute)
    stamp = t.strftime("%Y-%m-%dT%H:%M:%S.000Z")
    parts = []
    for e in range(DATASET_ENTITIES):
        seq = minute * DATASET_ENTITIES + e
        battery = 100 - (minute % 600) / 10 + e
        parts.append(
            ENTITY_FMT
            % (
                dataset_entity(e),
                stamp,
                repr(battery),
                ((minute + e) % 50) / 100,
                STATES[(minute // 60) % 3],
                -3.7 + (seq % 1000) / 100000,
                40.4 + e / 1000,
                (minute % 10) / 10,
                (minute % 7) / 10,
            )
        )
    return (NOTIFICATION_FMT % ",".join(parts)).encode()


def load_dataset(url: str, connections: int = 4, minutes: int = DATASET_MINUTES) -> dict:
    """POST the query data set to ``url``'s /v2/notify; returns counts and seconds.
    Raises if a notification is refused."""
    parts = urlsplit(url)
    local = threading.local()
    hdrs = headers(QUERY_TENANT)

    def post(minute: int) -> int:
        conn = getattr(local, "conn", None)
        if conn is None:
            conn = local.conn = http.client.HTTPConnection(parts.hostname, parts.port or 80, timeout=60)
        conn.request("POST", "/v2/notify", body=dataset_notification(minute), headers=hdrs)
        resp = conn.getresponse()
        data = resp.read()
        if not 200 <= resp.status < 300:
            raise RuntimeError(f"loading the data set: minute {minute} answered {resp.status}: {data[:300]!r}")
        return resp.status

    t0 = time.perf_counter()
    with ThreadPoolExecutor(connections) as pool:
        list(pool.map(post, range(minutes)))
    seconds = time.perf_counter() - t0
    return {"notifications": minutes, "samples": minutes * DATASET_ENTITIES * 5, "seconds": round(seconds, 1)}


def query_paths() -> dict[str, list[str]]:
    """The measured GETs: lastN=100 on one entity, the type-level hourly average
    over the day, the type-level lastN=1000."""
    lastn = [
        f"/v2/entities/urn:ngsi-ld:Lawnmower:{dataset_entity(e)}/attrs/{a}?lastN=100"
        for e in range(DATASET_ENTITIES)
        for a in ("batteryLevel", "speed")
    ]
    hourly = [
        f"/v2/types/{ENTITY_TYPE}/attrs/{a}?aggrMethod=avg&aggrPeriod=hour&fromDate={DAY_FROM}&toDate={DAY_TO}"
        for a in ("batteryLevel", "speed")
    ]
    types = [f"/v2/types/{ENTITY_TYPE}/attrs/{a}?lastN=1000" for a in ("batteryLevel", "speed")]
    return {"lastN": lastn, "hourly_avg": hourly, "type_lastN": types}


def check_dataset(url: str) -> dict:
    """The measured queries must answer what was loaded (100 values; 20
    entities x 24 hours; 1,000 values). Returns what was found."""
    parts = urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port or 80, timeout=60)
    found = {}
    try:
        for name, paths in query_paths().items():
            conn.request("GET", paths[0], headers=query_headers())
            resp = conn.getresponse()
            data = resp.read()
            if resp.status != 200:
                raise RuntimeError(f"{name}: {paths[0]} answered {resp.status}: {data[:300]!r}")
            doc = json.loads(data)
            if "entities" in doc:
                found[name] = {
                    "entities": len(doc["entities"]),
                    "values": sum(len(x.get("values", [])) for x in doc["entities"]),
                }
            else:
                found[name] = {"values": len(doc.get("values", []))}
    finally:
        conn.close()
    want = {
        "lastN": {"values": 100},
        "hourly_avg": {"entities": DATASET_ENTITIES, "values": DATASET_ENTITIES * 24},
        "type_lastN": {"values": 1000},
    }
    for name, expected in want.items():
        for key, value in expected.items():
            if found[name].get(key) != value:
                raise RuntimeError(f"{name}: expected {key}={value}, got {found[name]}")
    return found
