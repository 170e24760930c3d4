"""``tsdb-service backup`` and ``restore`` (DuckDB), with real processes.

A backup beside a stopped store holds what its ingest log still had to
apply; a backup through a running service, taken while clients keep
writing, holds every notification acknowledged before it was asked for,
exactly once; a restore makes a new store (with a new database id) that
serves the same history, and never overwrites anything. The service writes
backups only into the directory its operator set, only for an admin
credential over every tenant.
"""

from __future__ import annotations

import itertools
import subprocess
import sys
import threading

import duckdb
import httpx

from tests.support.ingest_log import leave_unapplied, readings
from tests.support.server import ServerProcess

TENANT = "backedup"
HEADERS = {"Fiware-Service": TENANT, "Fiware-ServicePath": "/"}
ADMIN_KEY = "admin-key-0123456789abcdef"
WRITER_KEY = "write-key-0123456789abcdef"
OTHER_ADMIN_KEY = "other-admin-0123456789abcd"
KEYS = f"{ADMIN_KEY}:admin;{WRITER_KEY}:read,write;{OTHER_ADMIN_KEY}:admin:{TENANT}"


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "tsdb_service", *args], capture_output=True, text=True, timeout=300, check=False
    )


def notify(client: httpx.Client, n: int, key: str | None = None) -> int:
    entity = {"id": f"Tank:{n % 7}", "type": "Tank", "n": {"type": "Number", "value": n}}
    headers = {**HEADERS, **({"Authorization": f"Bearer {key}"} if key else {})}
    body = {"subscriptionId": "5f00000000000000000bac0f", "data": [entity]}
    return client.post("/v2/notify", json=body, headers=headers).status_code


def stored(db_path) -> dict[str, int]:
    """(entity, value) -> how many times the store holds it."""
    con = duckdb.connect(str(db_path), read_only=True)
    try:
        rows = con.execute(
            "SELECT s.entity_id, a.num, count(*) FROM series s JOIN samples_all a ON a.sid = s.sid "
            "WHERE s.tenant = ? GROUP BY ALL",
            [TENANT],
        ).fetchall()
    finally:
        con.close()
    return {f"{entity}={num}": count for entity, num, count in rows}


def database_id(db_path) -> str:
    con = duckdb.connect(str(db_path), read_only=True)
    try:
        return str(con.execute("SELECT database_id FROM store_state").fetchall()[0][0])
    finally:
        con.close()


def test_a_stopped_store_is_backed_up_with_its_log_and_restored_as_a_new_store(tmp_path):
    db, out, new = tmp_path / "live.duckdb", tmp_path / "copy.duckdb", tmp_path / "restored.duckdb"
    with ServerProcess(db) as server, httpx.Client(base_url=server.url, timeout=30) as client:
        assert all(notify(client, n) == 200 for n in range(50))
    leave_unapplied(db, [readings(TENANT, "Tank:crash", [1, 2, 3])])  # acknowledged, in the log only

    done = cli("backup", "--db", str(db), str(out))
    assert done.returncode == 0, done.stderr
    assert "verified" in done.stdout and "samples_hot" in done.stdout, done.stdout
    expected = stored(db)
    assert expected["Tank:crash=3.25"] == 1 and sum(expected.values()) == 53
    assert stored(out) == expected

    again = cli("backup", "--db", str(db), str(out))  # never over a file
    assert again.returncode == 2 and "exists" in again.stderr

    restored = cli("restore", str(out), "--db", str(new))
    assert restored.returncode == 0, restored.stderr
    assert "verified" in restored.stdout
    assert database_id(new) != database_id(db)
    with ServerProcess(new) as server, httpx.Client(base_url=server.url, timeout=30) as client:
        answer = client.get("/v2/entities/Tank:crash/attrs/level", headers=HEADERS)
        assert answer.json()["values"] == [1.25, 2.25, 3.25]
        assert notify(client, 1000) == 200  # a restored store takes writes
    assert stored(new)["Tank:6=1000.0"] == 1

    before = new.read_bytes()
    refused = cli("restore", str(out), "--db", str(new))  # never over a store
    assert refused.returncode == 2 and "exists" in refused.stderr
    assert new.read_bytes() == before


def test_a_running_service_backs_up_under_load_everything_acknowledged_before(tmp_path):
    db, backups = tmp_path / "busy.duckdb", tmp_path / "backups"
    backups.mkdir()
    env = {"TSDB_BACKUP_DIR": str(backups), "TSDB_API_KEYS": KEYS}
    acked: list[int] = []
    with ServerProcess(db, extra_env=env) as server:
        held = cli("backup", "--db", str(db), str(tmp_path / "x.duckdb"))  # the service holds the file
        assert held.returncode == 2 and "--url" in held.stderr, held.stderr

        stop = threading.Event()
        numbers = itertools.count()

        def load() -> None:
            with httpx.Client(base_url=server.url, timeout=30) as client:
                while not stop.is_set():
                    n = next(numbers)
                    if notify(client, n, WRITER_KEY) == 200:
                        acked.append(n)

        clients = [threading.Thread(target=load) for _ in range(3)]
        for thread in clients:
            thread.start()
        try:
            while len(acked) < 200:
                stop.wait(0.01)
            before_backup = set(acked)
            done = cli("backup", "--url", server.url, "--api-key", ADMIN_KEY, "nightly.duckdb")
            assert done.returncode == 0, done.stderr
            assert "verified" in done.stdout, done.stdout
        finally:
            stop.set()
            for thread in clients:
                thread.join()

    restored = tmp_path / "restored.duckdb"
    assert cli("restore", str(backups / "nightly.duckdb"), "--db", str(restored)).returncode == 0
    in_backup = stored(restored)
    assert all(count == 1 for count in in_backup.values()), "a sample twice in the backup"
    values = {float(key.split("=")[1]) for key in in_backup}
    missing = sorted(n for n in before_backup if float(n) not in values)
    assert not missing, f"acknowledged before the backup, missing from it: {missing[:10]}"


def test_backups_through_the_service_are_confined_and_need_an_admin_over_every_tenant(tmp_path):
    backups = tmp_path / "backups"
    backups.mkdir()
    with ServerProcess(tmp_path / "off.duckdb") as server:
        answer = httpx.post(server.url + "/admin/backup", json={})
        assert answer.status_code == 409 and "TSDB_BACKUP_DIR" in answer.json()["description"]
    env = {"TSDB_BACKUP_DIR": str(backups), "TSDB_API_KEYS": KEYS}
    with ServerProcess(tmp_path / "on.duckdb", extra_env=env) as server:

        def ask(body: dict, key: str | None = ADMIN_KEY) -> httpx.Response:
            headers = {"Authorization": f"Bearer {key}"} if key else {}
            return httpx.post(server.url + "/admin/backup", json=body, headers=headers, timeout=60)

        assert ask({}, key=None).status_code == 401
        assert ask({}, key=WRITER_KEY).status_code == 403
        assert ask({}, key=OTHER_ADMIN_KEY).status_code == 403  # restricted to one tenant
        for name in ("../escape.duckdb", "/tmp/abs.duckdb", "a/b.duckdb", ".hidden", "", 7):
            answer = ask({"name": name})
            assert answer.status_code == 400, (name, answer.text)
        assert ask({"path": "/etc/x"}).status_code == 400
        first = ask({"name": "one.duckdb"})
        assert first.status_code == 201, first.text
        report = first.json()
        assert report["verified"] and report["path"] == str(backups / "one.duckdb")
        assert report["tables"]["store_state"] == {"source": 1, "copy": 1}
        assert ask({"name": "one.duckdb"}).status_code == 409  # never overwritten
        default = ask({})
        assert default.status_code == 201 and default.json()["path"].startswith(str(backups / "tsdb-"))
    assert sorted(p.name for p in backups.iterdir() if not p.name.startswith("tsdb-")) == ["one.duckdb"]
    assert not list(tmp_path.glob("escape*")) and not (tmp_path.parent / "escape.duckdb").exists()
