"""Robots benchmark: ``import rosbag`` messages/s and samples/s for a big bag, and ``replay``'s pacing.

    .venv/bin/python benchmarks/rosbag.py                          # a 1 GB bag (MCAP) into DuckDB
    .venv/bin/python benchmarks/rosbag.py --size-mb 5              # a quick check
    .venv/bin/python benchmarks/rosbag.py --storage sqlite3 --target postgresql [--size-mb N] [--json FILE]
    .venv/bin/python benchmarks/rosbag.py --map fields             # 2-4 fields per message as attributes

1. Writes a rosbag2 of about ``--size-mb`` MB with rosbags (not timed): a
   robot at work, ``nav_msgs/Odometry`` at 100 Hz, ``sensor_msgs/LaserScan``
   (360 ranges) at 10 Hz, ``sensor_msgs/NavSatFix`` at 5 Hz,
   ``geometry_msgs/Twist`` at 20 Hz and ``sensor_msgs/BatteryState`` at 1 Hz.
2. Imports it with the library calls the command uses (``PreparedImport``:
   the checking read, then the import with the default map: one entity per
   topic, the message as one attribute; or with ``--map fields`` 2 to 4
   fields of each message as attributes, so samples/s is not messages/s)
   into a new DuckDB file or a private PostgreSQL (``pgutil.BenchCluster``),
   and times both; the peak RSS of the process (bag writing included).
3. Replays ``--replay-seconds`` of the imported ``/fix`` history (5 Hz) at ``--speed`` into
   a local receiver (an HTTP server answering ``/v2/notify`` that records
   when each notification arrives) and compares each arrival with its due
   time: the pacing error, mean and maximum, as a share of the replay.
"""

from __future__ import annotations

import argparse
import http.server
import json
import resource
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import ClassVar

sys.path.insert(0, str(Path(__file__).resolve().parent))

from pgutil import BenchCluster  # puts the repository on sys.path

T0_NS = 1_714_557_600 * 10**9  # 2024-05-01T10:00:00Z
# --map fields: the fields an integration would keep, several attributes per message (so samples/s
# differs from messages/s); the entity ids stay the default ones so the replay reads the same /fix entity.
FIELDS_MAP = {
    "topics": {
        "/odom": {"entity": "urn:ngsi-ld:ROS2Topic:odom", "attributes": {
            "x": "pose.pose.position.x", "y": "pose.pose.position.y",
            "speed": "twist.twist.linear.x", "yawRate": "twist.twist.angular.z"}},
        "/scan": {"entity": "urn:ngsi-ld:ROS2Topic:scan", "attributes": {"ranges": "ranges", "rangeMax": "range_max"}},
        "/fix": {"entity": "urn:ngsi-ld:ROS2Topic:fix", "attributes": {
            "location": {"path": "", "type": "geo:json"}, "altitude": "altitude"}},
        "/cmd_vel": {"entity": "urn:ngsi-ld:ROS2Topic:cmd_vel", "attributes": {
            "linear": "linear.x", "angular": "angular.z"}},
        "/battery": {"entity": "urn:ngsi-ld:ROS2Topic:battery", "attributes": {
            "voltage": "voltage", "percentage": "percentage", "temperature": "temperature"}},
    }
}  # fmt: skip
RATES = {  # topic: (message type, messages per second)
    "/odom": ("nav_msgs/msg/Odometry", 100),
    "/scan": ("sensor_msgs/msg/LaserScan", 10),
    "/fix": ("sensor_msgs/msg/NavSatFix", 5),
    "/cmd_vel": ("geometry_msgs/msg/Twist", 20),
    "/battery": ("sensor_msgs/msg/BatteryState", 1),
}


def write_bag(path: Path, size_mb: float, storage: str) -> dict:
    """A bag of about ``size_mb`` MB; its message count and size."""
    import numpy as np
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    limit = size_mb * 1024 * 1024
    written = messages = 0
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = {topic: writer.add_connection(topic, kind, typestore=store) for topic, (kind, _) in RATES.items()}
        tick = 0
        while written < limit:
            at = T0_NS + tick * 10_000_000  # 100 Hz ticks
            header = t["std_msgs/msg/Header"](
                stamp=t["builtin_interfaces/msg/Time"](sec=at // 10**9, nanosec=at % 10**9), frame_id="base_link"
            )
            for topic, (kind, rate) in RATES.items():
                if tick % (100 // rate):
                    continue
                raw = store.serialize_cdr(_message(t, kind, header, tick, np), kind)
                writer.write(connections[topic], at + 2_000_000, raw)
                written += len(raw)
                messages += 1
            tick += 1
    size = sum(p.stat().st_size for p in path.iterdir())
    return {"messages": messages, "bytes": size, "seconds_of_history": tick / 100}


def _message(t, kind: str, header, tick: int, np):
    vector = t["geometry_msgs/msg/Vector3"]
    if kind == "nav_msgs/msg/Odometry":
        cov = np.zeros(36)
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=tick * 0.004, y=1.0, z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )
        twist = t["geometry_msgs/msg/Twist"](linear=vector(x=0.4, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.1))
        return t[kind](
            header=header,
            child_frame_id="base_link",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov),
        )
    if kind == "sensor_msgs/msg/LaserScan":
        ranges = (np.arange(360, dtype=np.float32) % 7 + tick % 3).astype(np.float32)
        return t[kind](
            header=header, angle_min=-3.14, angle_max=3.14, angle_increment=0.0174, time_increment=0.0,
            scan_time=0.1, range_min=0.1, range_max=10.0, ranges=ranges, intensities=np.zeros(0, dtype=np.float32),
        )  # fmt: skip
    if kind == "sensor_msgs/msg/NavSatFix":
        return t[kind](
            header=header, status=t["sensor_msgs/msg/NavSatStatus"](status=0, service=1), latitude=48.76,
            longitude=8.93 + tick * 1e-7, altitude=400.0, position_covariance=np.zeros(9), position_covariance_type=0,
        )  # fmt: skip
    if kind == "geometry_msgs/msg/Twist":
        return t[kind](linear=vector(x=0.4, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.1))
    return t[kind](
        header=header, voltage=25.0, temperature=30.0, current=-1.0, charge=2.0, capacity=5.0, design_capacity=5.0,
        percentage=0.8, power_supply_status=2, power_supply_health=1, power_supply_technology=2, present=True,
        cell_voltage=np.zeros(0, dtype=np.float32), cell_temperature=np.zeros(0, dtype=np.float32), location="",
        serial_number="",
    )  # fmt: skip


def import_bag(path: Path, db: str, spec: dict | None = None, batch_samples: int = 0) -> dict:
    from tsdb_service.commands.rosbag.importer import BATCH_SAMPLES, PreparedImport
    from tsdb_service.core.config import Settings
    from tsdb_service.storage import open_store

    started = time.perf_counter()
    with PreparedImport.open(path, spec) as prepared:
        checked = time.perf_counter()
        store = open_store(Settings(db=db))
        try:
            report = prepared.run(store, batch_samples=batch_samples or BATCH_SAMPLES)
        finally:
            store.close()
    done = time.perf_counter()
    seconds = done - started
    return {
        "messages": report.messages,
        "samples": report.samples,
        "check_seconds": round(checked - started, 2),
        "import_seconds": round(done - checked, 2),
        "total_seconds": round(seconds, 2),
        "messages_per_second": round(report.messages / seconds),
        "samples_per_second": round(report.samples / seconds),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),  # bag writing included
    }


class _Receiver(http.server.BaseHTTPRequestHandler):
    arrivals: ClassVar[list[float]] = []

    def do_POST(self) -> None:
        self.rfile.read(int(self.headers.get("content-length", 0)))
        _Receiver.arrivals.append(time.monotonic())
        self.send_response(200)
        self.send_header("content-length", "0")
        self.end_headers()

    def log_message(self, *args) -> None:
        pass


def replay_pacing(db: str, seconds: float, speed: float) -> dict:
    """Replay ``seconds`` of /fix history (5 Hz) at ``speed``; each arrival against its due time."""
    from datetime import UTC, datetime, timedelta

    from tsdb_service.commands.replay.runner import replay
    from tsdb_service.commands.replay.source import Selection, store_updates
    from tsdb_service.commands.replay.targets import Marker, NotifyTarget
    from tsdb_service.core.config import Settings
    from tsdb_service.core.query import EntityFilter, Scope, TimeRange
    from tsdb_service.storage import open_store

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Receiver)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    start = datetime.fromtimestamp(T0_NS / 1e9, UTC)
    selection = Selection(
        Scope(""),
        EntityFilter(ids=("urn:ngsi-ld:ROS2Topic:fix",)),
        None,
        TimeRange(start, start + timedelta(seconds=seconds)),
    )
    store = open_store(Settings(db=db))
    target = NotifyTarget(f"http://127.0.0.1:{server.server_address[1]}")
    _Receiver.arrivals = []
    try:
        report = replay(store_updates(store, selection), target, Marker("bench", "bench"), tenant="bench", speed=speed)
    finally:
        target.close()
        store.close()
        server.shutdown()
    arrivals = _Receiver.arrivals
    wall = seconds / speed
    period = 1 / RATES["/fix"][1]
    errors = [abs((a - arrivals[0]) - i * period / speed) for i, a in enumerate(arrivals)]
    return {
        "updates": report.updates,
        "history_seconds": seconds,
        "speed": speed,
        "wall_seconds": round(report.seconds, 3),
        "expected_wall_seconds": wall,
        "error_mean_ms": round(1000 * sum(errors) / len(errors), 2),
        "error_max_ms": round(1000 * max(errors), 2),
        "error_max_share_of_replay": round(max(errors) / wall, 4),
        "late_max_ms": round(1000 * report.late_max, 2),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size-mb", type=float, default=1000.0, help="bag size to write (default 1000)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    p.add_argument("--target", choices=("duckdb", "postgresql"), default="duckdb")
    p.add_argument("--replay-seconds", type=float, default=60.0, help="history replayed (default 60 s of /fix)")
    p.add_argument("--speed", type=float, default=10.0, help="replay speed (default 10)")
    p.add_argument(
        "--map",
        choices=("message", "fields"),
        default="message",
        help="message: the default map (each message one attribute, as the ROS 2 IoT Agent sends it); "
        "fields: 2 to 4 fields of each message as attributes (default message)",
    )
    p.add_argument(
        "--batch-samples",
        type=int,
        default=0,
        help="samples per committed batch (the command's --batch-samples; default the command's, 50000): "
        "the peak RSS follows it",
    )
    p.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = p.parse_args()
    spec = FIELDS_MAP if args.map == "fields" else None
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "big"
        made = write_bag(bag, args.size_mb, args.storage)
        print(f"bag: {made['messages']:,} messages, {made['bytes'] / 1e6:,.1f} MB, {made['seconds_of_history']:,.0f} s")
        if args.target == "postgresql":
            with BenchCluster("rosbag") as pg:
                assert pg.url is not None
                result = {"bag": made, "import": import_bag(bag, pg.url, spec, args.batch_samples)}
                seconds = min(args.replay_seconds, made["seconds_of_history"])
                result["replay"] = replay_pacing(pg.url, seconds, args.speed)
        else:
            db = str(Path(tmp) / "t.duckdb")
            result = {"bag": made, "import": import_bag(bag, db, spec, args.batch_samples)}
            result["replay"] = replay_pacing(db, min(args.replay_seconds, made["seconds_of_history"]), args.speed)
    result.update({"storage": args.storage, "target": args.target, "map": args.map})
    imp, rep = result["import"], result["replay"]
    print(
        f"import: {imp['messages_per_second']:,} messages/s, {imp['samples_per_second']:,} samples/s "
        f"({imp['check_seconds']} s checking, {imp['import_seconds']} s importing; map {args.map}, "
        f"peak RSS {imp['peak_rss_mb']} MB)"
    )
    print(
        f"replay at x{rep['speed']:g}: {rep['updates']} updates in {rep['wall_seconds']} s "
        f"(due {rep['expected_wall_seconds']:g} s); error {rep['error_mean_ms']} ms mean, {rep['error_max_ms']} ms max "
        f"({100 * rep['error_max_share_of_replay']:.2f}% of the replay)"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
