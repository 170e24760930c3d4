"""MQTT ingest beside HTTP ingest: rate and publish-to-queryable latency, both backends.

    .venv/bin/python benchmarks/mqtt.py [--messages 20000] [--duration 10] [--latency-samples 200]
    .venv/bin/python benchmarks/mqtt.py --backend postgresql --json benchmarks/results/mqtt.json
    .venv/bin/python benchmarks/mqtt.py --quick          # a smoke run: does it work at all

Per backend (DuckDB on a fresh file; PostgreSQL on a fresh database of a
private cluster, as ``ingest.py``), one private Mosquitto on a free port
(``tsdb_service.demo.mosquitto``: Debian's ``mosquitto``, not installed by
this script) and one ``tsdb-service serve --mqtt-url`` consuming it, then
four phases, one after the other (two cores: never two loads at once):

1. **HTTP ingest**: ``loadgen.py`` POSTs one-entity normalized Orion
   notifications to ``/v2/notify`` over ``--connections`` keep-alive
   connections for ``--duration`` seconds (after a warm-up): acknowledged
   notifications per second, and the acknowledgement's p50 and p99.
2. **MQTT ingest at QoS 1**: ``--messages`` of the same notifications
   published as fast as one paho-mqtt client can (QoS 1, up to 1,000 in
   flight), on ``tsdb/bench``; the rate is messages stored per second from
   the first publication until the service's ``tsdb_mqtt_messages_total
   {outcome="stored"}`` counts them all (each PUBACK is sent only after the
   write is durable, so that is also the acknowledged rate). The publisher's
   own rate is printed too: if it is barely above the service's, the
   publisher (in this process, on the same machine) was the limit.
3. **Latency, HTTP**: ``--latency-samples`` notifications one at a time, a
   new entity each; from the POST until ``GET /v2/entities/ID?lastN=1``
   first answers it (polled back to back on a kept-alive connection).
4. **Latency, MQTT**: the same, from ``publish`` (QoS 1) until the same GET
   answers: broker, consumer, write and read together.

The server's CPU per notification comes from its process tree (and, on
PostgreSQL, the cluster's). Exit status 0 only if every notification sent
was stored once (the MQTT counters: stored = published, nothing rejected or
redelivered) and every latency sample became queryable.
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
import statistics
import sys
import tempfile
import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import common
import httpx
import orjson
from common import HOST, fmt, free_port, ours_cmd
from loadgen import build_request, run_load
from pgutil import BenchCluster

TENANT = "bench"
TOPIC = f"tsdb/{TENANT}"  # the service's default template: tenant bench, service path /
HEADERS = {"Fiware-Service": TENANT, "Fiware-ServicePath": "/", "Content-Type": "application/json"}
ENTITIES = 1000  # ingest phases cycle through this many entities (one series each)
T0 = datetime(2025, 1, 1, tzinfo=UTC)


def notification(prefix: str, seq: int, entity: str | None = None) -> bytes:
    """One normalized Orion notification: a number and a text, stamped with
    the sequence number's own instant (so every sample is new)."""
    stamp = {"TimeInstant": {"type": "DateTime", "value": (T0 + timedelta(milliseconds=seq)).isoformat()}}
    body = {
        "id": entity or f"urn:ngsi-ld:Robot:{prefix}{seq % ENTITIES}",
        "type": "Robot",
        "seq": {"type": "Number", "value": seq, "metadata": stamp},
        "label": {"type": "Text", "value": f"{prefix} {seq}", "metadata": stamp},
    }
    return orjson.dumps({"subscriptionId": f"bench-{prefix}", "data": [body]})


class Publisher:
    """One MQTT 5 client at QoS 1; ``acked`` counts the broker's PUBACKs."""

    def __init__(self, url: str, inflight: int = 1000):
        import paho.mqtt.client as paho

        host, port = url.removeprefix("mqtt://").rsplit(":", 1)
        self.client = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id="bench-pub", protocol=paho.MQTTv5)
        self.client.max_inflight_messages_set(inflight)
        self.client.max_queued_messages_set(0)
        self.acked = 0
        self._cond = threading.Condition()
        self.client.on_publish = self._on_publish
        self.client.connect(host, int(port))
        self.client.loop_start()

    def _on_publish(self, client, userdata, mid, reason_code, properties) -> None:
        with self._cond:
            self.acked += 1
            self._cond.notify_all()

    def publish(self, payload: bytes) -> None:
        self.client.publish(TOPIC, payload, qos=1)

    def wait_acked(self, count: int, timeout: float = 300.0) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self.acked >= count, timeout)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def mqtt_counts(url: str) -> dict[str, int]:
    """The consumer's settled messages by outcome, from ``/metrics``."""
    counts = {"stored": 0, "rejected": 0, "redelivered": 0}
    for line in httpx.get(url + "/metrics", timeout=10).text.splitlines():
        if line.startswith("tsdb_mqtt_messages_total{"):
            outcome = line.split('outcome="', 1)[1].split('"', 1)[0]
            counts[outcome] = int(float(line.rsplit(" ", 1)[1]))
    return counts


def wait_subscribed(url: str, timeout: float = 60.0) -> None:
    """Until ``/health`` passes: the consumer is connected and subscribed
    (what is published before that is not queued for it)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError, ValueError):
            if httpx.get(url + "/health", timeout=5).json().get("status") == "pass":
                return
        time.sleep(0.1)
    raise RuntimeError(f"the service's MQTT consumer did not subscribe within {timeout:g} s")


def cpu_now(server, cluster) -> float:
    return server.cpu_seconds() + (cluster.cpu_seconds() if cluster is not None else 0.0)


def http_ingest(server, cluster, connections: int, duration: float, warmup: float) -> dict:
    port = server.port

    def factory(seq: int) -> bytes:
        return build_request("POST", "/v2/notify", HOST, port, HEADERS, notification("h", seq))

    cpu0 = cpu_now(server, cluster)
    stats = run_load(HOST, port, factory, connections=connections, duration=duration, warmup=warmup)
    cpu = cpu_now(server, cluster) - cpu0
    total = stats.total_ok or 1
    return {
        "path": "HTTP /v2/notify",
        "sent": stats.total_sent,
        "stored": stats.total_ok,
        "rate": stats.rps,
        "ack_p50_ms": stats.p50_ms,
        "ack_p99_ms": stats.p99_ms,
        "cpu_ms_per_msg": 1000 * cpu / total,
        "ok": stats.total_errors == 0 and stats.total_non_2xx == 0,
    }


def mqtt_ingest(server, cluster, broker_url: str, messages: int) -> dict:
    bodies = [notification("m", seq) for seq in range(messages)]  # encoded before the clock starts
    before = mqtt_counts(server.url)
    publisher = Publisher(broker_url)
    try:
        cpu0 = cpu_now(server, cluster)
        t0 = time.perf_counter()
        for body in bodies:
            publisher.publish(body)
        published = publisher.wait_acked(messages)
        t_published = time.perf_counter()
        deadline = time.monotonic() + 300
        while (counts := mqtt_counts(server.url))["stored"] - before["stored"] < messages:
            if time.monotonic() > deadline:
                break
            time.sleep(0.02)
        elapsed = time.perf_counter() - t0
        cpu = cpu_now(server, cluster) - cpu0
    finally:
        publisher.close()
    stored = counts["stored"] - before["stored"]
    return {
        "path": "MQTT QoS 1",
        "sent": messages,
        "stored": stored,
        "rate": stored / elapsed,
        "publish_rate": messages / (t_published - t0),
        "cpu_ms_per_msg": 1000 * cpu / max(stored, 1),
        "ok": published
        and stored == messages
        and counts["rejected"] == before["rejected"]
        and counts["redelivered"] == before["redelivered"],
    }


def queryable(client: httpx.Client, entity: str, seq: int, timeout: float = 30.0) -> bool:
    """Poll until the entity's newest sample is ``seq``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        answer = client.get(f"/v2/entities/{entity}", params={"lastN": 1}, headers=HEADERS)
        if answer.status_code == 200:
            doc = answer.json()
            if not isinstance(doc, dict):  # [] while the entity is unknown
                continue
            attrs = {a["attrName"]: a["values"] for a in doc.get("attributes", [])}
            if attrs.get("seq") == [seq]:
                return True
    return False


def latency(server, samples: int, via_mqtt: bool, broker_url: str) -> dict:
    """Publish (or POST) one notification at a time; time until a read returns it."""
    prefix = "lm" if via_mqtt else "lh"
    times, missing = [], 0
    publisher = Publisher(broker_url) if via_mqtt else None
    try:
        with httpx.Client(base_url=server.url, timeout=30) as client:
            for seq in range(samples):
                entity = f"urn:ngsi-ld:Robot:{prefix}{seq}"
                body = notification(prefix, seq, entity)
                t0 = time.perf_counter()
                if publisher is not None:
                    publisher.publish(body)
                elif client.post("/v2/notify", content=body, headers=HEADERS).status_code != 200:
                    missing += 1
                    continue
                if queryable(client, entity, seq):
                    times.append(1000 * (time.perf_counter() - t0))
                else:
                    missing += 1
    finally:
        if publisher is not None:
            publisher.close()
    ordered = sorted(times)
    return {
        "e2e_p50_ms": statistics.median(ordered) if ordered else None,
        "e2e_p99_ms": ordered[min(len(ordered) - 1, int(len(ordered) * 0.99))] if ordered else None,
        "e2e_missing": missing,
    }


def run_backend(backend: str, args: argparse.Namespace) -> list[dict]:
    from tsdb_service.demo.mosquitto import LocalMosquitto

    work = Path(tempfile.mkdtemp(prefix=f"bench-mqtt-{backend}-"))
    cluster = BenchCluster("bench_mqtt").start() if backend == "postgresql" else None
    try:
        db = cluster.url if cluster is not None else work / "bench.duckdb"
        with LocalMosquitto(directory=work / "mosquitto") as broker:
            port = free_port()
            cmd = [*ours_cmd(db, port), "--mqtt-url", broker.url, "--mqtt-client-id", f"bench-{backend}"]
            server = common.spawned(f"tsdb-{backend}", cmd, port, work).start()
            try:
                wait_subscribed(server.url)
                print(f"[{backend}] HTTP ingest, {args.connections} connections, {args.duration:g} s ...", flush=True)
                http = http_ingest(server, cluster, args.connections, args.duration, args.warmup)
                print(f"[{backend}] MQTT ingest, {args.messages:,} messages at QoS 1 ...", flush=True)
                mqtt = mqtt_ingest(server, cluster, broker.url, args.messages)
                print(f"[{backend}] publish -> queryable, {args.latency_samples} samples each ...", flush=True)
                http.update(latency(server, args.latency_samples, False, broker.url))
                mqtt.update(latency(server, args.latency_samples, True, broker.url))
                after = mqtt_counts(server.url)
                mqtt["ok"] = mqtt["ok"] and after["rejected"] == 0 and after["redelivered"] == 0
            finally:
                server.stop()
    finally:
        if cluster is not None:
            cluster.stop()
        shutil.rmtree(work, ignore_errors=True)
    rows = [http, mqtt]
    for row in rows:
        row["backend"] = backend
        row["ok"] = row["ok"] and row["e2e_missing"] == 0
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", choices=("both", "duckdb", "postgresql"), default="both")
    parser.add_argument("--messages", type=int, default=20_000, help="MQTT ingest: messages published")
    parser.add_argument("--duration", type=float, default=10.0, help="HTTP ingest: measured seconds")
    parser.add_argument("--warmup", type=float, default=2.0, help="HTTP ingest: seconds before measuring")
    parser.add_argument("--connections", type=int, default=32, help="HTTP ingest: keep-alive connections")
    parser.add_argument("--latency-samples", type=int, default=200, help="publish -> queryable samples per path")
    parser.add_argument("--quick", action="store_true", help="a smoke run: 300 messages, 2 s, 20 samples")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args(argv)
    if args.quick:
        args.messages, args.duration, args.warmup, args.latency_samples = 300, 2.0, 0.5, 20
    from tsdb_service.demo.mosquitto import find_mosquitto

    if find_mosquitto() is None:
        print("error: mosquitto is not installed (Debian: apt-get install mosquitto)", file=sys.stderr)
        return 2
    backends = ("duckdb", "postgresql") if args.backend == "both" else (args.backend,)
    load0 = common.loadavg()
    rows = [row for backend in backends for row in run_backend(backend, args)]
    print(f"\nload average before {common.load_text(load0)}, after {common.load_text()}")
    common.print_rows(
        [
            "backend",
            "path",
            "sent",
            "stored",
            "msg/s",
            "cpu ms/msg",
            "ack p50 ms",
            "ack p99 ms",
            "e2e p50 ms",
            "e2e p99 ms",
            "ok",
        ],
        [
            [
                r["backend"],
                r["path"],
                f"{r['sent']:,}",
                f"{r['stored']:,}",
                fmt(r["rate"]),
                fmt(r["cpu_ms_per_msg"], 2),
                fmt(r.get("ack_p50_ms"), 2),
                fmt(r.get("ack_p99_ms"), 2),
                fmt(r["e2e_p50_ms"], 2),
                fmt(r["e2e_p99_ms"], 2),
                "yes" if r["ok"] else "NO",
            ]
            for r in rows
        ],
        left=2,
    )
    for r in rows:
        if "publish_rate" in r:
            print(f"{r['backend']}: the publisher sent {fmt(r['publish_rate'])} msg/s (acknowledged by the broker)")
    if args.json:
        common.write_json(args.json, {"machine": common.machine(), "args": vars(args), "rows": rows})
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
