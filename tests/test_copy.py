"""``tsdb-service copy`` moves all history between backends and verifies it.

History copied DuckDB → PostgreSQL → DuckDB answers every query exactly as
the original does, and the rejected store and 'values' layouts come along.
Copying cannot hurt: a non-empty target is refused unless ``--append``, the
check compares totals, an interrupted copy resumes, a missing source is an
error (before: a second copy doubled all history and still printed "copy
verified"; a mistyped source was created empty and "copied").
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from datetime import UTC, datetime, timedelta

import pytest

from tests.support.interrupt import Interrupted, InterruptedTarget
from tests.support.rollups import differences
from tsdb_service.cli.main import main
from tsdb_service.commands.copy import copy_history, store_identity
from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.retention_policy import RetentionPolicy
from tsdb_service.storage import open_store
from tsdb_service.storage.retention import RetentionConfig, RetentionWorker
from tsdb_service.storage.rollup_repair import expired_history, put_expired_history
from tsdb_service.storage.rollups import COLUMNS, LEVELS, combine_partials
from tsdb_service.write.ops import AppendSamples

H = {"Content-Type": "application/json", "Fiware-Service": "copyland", "Fiware-ServicePath": "/site/a"}
QUERIES = [
    "/v2/entities",
    "/v2/entities/Mower:1",
    "/v2/entities/Mower:1/attrs/odom(twist.twist.linear.x)?lastN=3",
    "/v2/types/Mower/attrs/battery?aggrMethod=avg&aggrPeriod=minute",
    "/v2/entities?georel=near;maxDistance:500&geometry=point&coords=40.4168,-3.7038",
]


def _notification(i: int) -> dict:
    return {
        "subscriptionId": "s",
        "data": [
            {
                "id": f"Mower:{i % 2}",
                "type": "Mower",
                "battery": {"type": "Number", "value": 90 - i},
                "mode": {"type": "Text", "value": "mowing" if i % 3 else "docked"},
                "odom": {"type": "Object", "value": {"twist": {"twist": {"linear": {"x": i / 10}}}}},
                "location": {"type": "geo:point", "value": f"40.4168, -3.70{i % 10}"},
                "TimeInstant": {"type": "DateTime", "value": f"2024-05-01T10:{i // 60:02d}:{i % 60:02d}.250Z"},
            }
        ],
    }


def _answers(client) -> list:
    return [(q, client.get(q, headers=H).status_code, client.get(q, headers=H).json()) for q in QUERIES]


def test_copy_round_trip_keeps_every_answer(tmp_path, pg_cluster, client_factory, capsys):
    original = str(tmp_path / "original.duckdb")
    with client_factory(original) as client:
        for i in range(40):
            assert client.post("/v2/notify", json=_notification(i), headers=H).status_code == 200
        assert client.post("/v2/notify", content=b"{broken", headers=H).status_code == 400
        client.put("/v2/notify/subscriptions/sub-1", json={"attrs": ["id", "battery"]}, headers=H)
        expected = _answers(client)
    assert all(status == 200 for _, status, _ in expected)

    pg_url = pg_cluster.database("copy_target")
    assert main(["copy", "--from", original, "--to", pg_url, "--quiet"]) == 0
    back = str(tmp_path / "back.duckdb")
    assert main(["copy", "--from", pg_url, "--to", back, "--quiet"]) == 0
    assert "copy verified" in capsys.readouterr().out

    for url in (pg_url, back):
        with client_factory(url) as client:
            assert _answers(client) == expected, url
            assert not differences(client.app.state.store)  # the writers rolled up what they copied
            rejected = client.get("/v2/notify/rejected", headers=H).json()
            assert [r["body"] for r in rejected] == ["{broken"]
            assert client.get("/v2/notify/subscriptions", headers=H).json()["sub-1"]["attrs"] == ["id", "battery"]


def test_copy_refuses_the_same_store(tmp_path):
    same = str(tmp_path / "x.duckdb")
    assert main(["copy", "--from", same, "--to", same]) == 2


# -- copying cannot hurt: refusals, totals, resuming -------------------------------------------
#
# These run the real command (``python -m tsdb_service copy``) as a subprocess,
# in both directions. Before: a second copy into the same target doubled all
# history and still printed "copy verified"; a missing source file was created
# empty and "copied".

T0 = datetime(2024, 5, 1, 10, tzinfo=UTC)
DIRECTIONS = ["duckdb-to-postgresql", "postgresql-to-duckdb"]


def copy_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("TSDB_")}
    return subprocess.run(
        [sys.executable, "-m", "tsdb_service", "copy", *args, "--quiet"],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )


def _fill(url: str, entities: int, tenant: str = "copyland", start: int = 0) -> int:
    """``entities`` notifications of 3 samples each, written through the store; returns samples written."""
    store = open_store(Settings(db=url))
    try:
        batch = [
            EntitySample(
                tenant,
                "/",
                f"Robot:{i % 7}",
                "Robot",
                T0 + timedelta(seconds=start + i),
                [
                    AttrSample("battery", "Number", Kind.NUMBER, num=float(i % 100)),
                    AttrSample("mode", "Text", Kind.TEXT, txt="mowing" if i % 2 else "docked"),
                    AttrSample("speed", "Number", Kind.NUMBER, num=i / 10),
                ],
            )
            for i in range(entities)
        ]
        store.write_sync([AppendSamples(batch)])
    finally:
        store.close()
    return 3 * entities


def _counts(url: str) -> dict[str, int]:
    store = open_store(Settings(db=url))
    try:
        rows = store.querier()._fetch(
            "SELECT s.tenant, count(*) FROM samples_all x JOIN series s ON s.sid = x.sid GROUP BY s.tenant", []
        )
        return {tenant: int(n) for tenant, n in rows}
    finally:
        store.close()


@pytest.fixture
def pair(request, tmp_path, pg_cluster):
    """(source, target) locations for the direction under test; the source holds 200 samples."""
    duck = str(tmp_path / "history.duckdb")
    pg = pg_cluster.database(f"copy_{request.node.name[-40:].replace('-', '_').replace('[', '_').strip(']')}"[:60])
    source, target = (duck, pg) if request.param == "duckdb-to-postgresql" else (pg, duck)
    _fill(source, 200 // 3 + 1)
    return source, target


@pytest.mark.parametrize("pair", DIRECTIONS, indirect=True)
def test_a_second_copy_into_the_same_target_is_refused(pair):
    source, target = pair
    first = copy_cli("--from", source, "--to", target)
    assert first.returncode == 0 and "copy verified" in first.stdout, first.stderr
    copied = _counts(target)
    assert copied == _counts(source)
    again = copy_cli("--from", source, "--to", target)
    assert again.returncode == 2, again.stdout + again.stderr
    lines = again.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "--append" in lines[0], again.stderr
    assert "copy verified" not in again.stdout
    assert _counts(target) == copied, "a refused copy writes nothing"


@pytest.mark.parametrize("pair", DIRECTIONS, indirect=True)
def test_append_verifies_the_totals(pair):
    source, target = pair
    _fill(target, 10, tenant="already")
    _fill(target, 10, tenant="copyland", start=10_000)
    before, src = _counts(target), _counts(source)
    done = copy_cli("--from", source, "--to", target, "--append")
    assert done.returncode == 0 and "copy verified" in done.stdout, done.stderr
    assert _counts(target) == {"already": before["already"], "copyland": before["copyland"] + src["copyland"]}


@pytest.mark.parametrize("pair", DIRECTIONS, indirect=True)
def test_an_interrupted_copy_resumes_without_duplicates(pair):
    source, target = pair
    src, tgt = open_store(Settings(db=source)), open_store(Settings(db=target))
    try:
        with pytest.raises(Interrupted):
            copy_history(src, InterruptedTarget(tgt, 2), source_id=store_identity(source), batch_rows=30)
    finally:
        src.close()
        tgt.close()
    partial = sum(_counts(target).values())
    assert 0 < partial < sum(_counts(source).values())

    done = copy_cli("--from", source, "--to", target, "--batch-rows", "30")
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"resumed an interrupted copy: {partial} samples were already there" in done.stdout
    assert "copy verified" in done.stdout
    assert _counts(target) == _counts(source)


@pytest.mark.parametrize("pair", DIRECTIONS[:1], indirect=True)
def test_an_interrupted_copy_is_not_mistaken_for_another_source(pair, tmp_path):
    source, target = pair
    src, tgt = open_store(Settings(db=source)), open_store(Settings(db=target))
    try:
        with pytest.raises(Interrupted):
            copy_history(src, InterruptedTarget(tgt, 1), source_id=store_identity(source), batch_rows=30)
    finally:
        src.close()
        tgt.close()
    other = str(tmp_path / "other.duckdb")
    _fill(other, 5)
    refused = copy_cli("--from", other, "--to", target, "--append")
    assert refused.returncode == 2 and "interrupted copy from" in refused.stderr and source in refused.stderr


def test_a_killed_copy_process_resumes(tmp_path, pg_cluster):
    """SIGKILL the real command mid-copy, run it again: every sample once."""
    source, target = str(tmp_path / "big.duckdb"), pg_cluster.database("copy_killed")
    _fill(source, 3000)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TSDB_")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "tsdb_service", "copy", "--from", source, "--to", target, "--batch-rows", "60"],
        stderr=subprocess.PIPE,
        env=env,
    )
    try:
        progress = b""
        while b"%" not in progress:  # the first batch is committed
            chunk = proc.stderr.read1(4096)
            assert chunk, "the copy ended before it showed progress"
            progress += chunk
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stderr.close()
    assert 0 < sum(_counts(target).values()) < 9000
    done = copy_cli("--from", source, "--to", target, "--batch-rows", "60")
    assert done.returncode == 0 and "copy verified" in done.stdout, done.stdout + done.stderr
    assert _counts(target) == _counts(source) == {"copyland": 9000}


def test_a_missing_source_is_an_error_and_is_not_created(tmp_path):
    missing, target = tmp_path / "typo.duckdb", tmp_path / "target.duckdb"
    done = copy_cli("--from", str(missing), "--to", str(target))
    assert done.returncode == 2 and done.stderr.strip() == f"error: {missing} does not exist"
    assert not missing.exists() and not target.exists()


def test_a_missing_postgresql_source_is_an_error(tmp_path, pg_cluster):
    url = pg_cluster.url.rsplit("/", 1)[0] + "/no_such_database"
    done = copy_cli("--from", url, "--to", str(tmp_path / "t.duckdb"))
    assert done.returncode == 2 and "no_such_database" in done.stderr and "does not exist" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not (tmp_path / "t.duckdb").exists()


def test_a_source_without_history_is_an_error(tmp_path):
    import duckdb

    other = tmp_path / "other.duckdb"
    duckdb.connect(str(other)).close()
    done = copy_cli("--from", str(other), "--to", str(tmp_path / "t.duckdb"))
    assert done.returncode == 2 and "without tsdb-service history" in done.stderr, done.stderr


def _rolled_up(store) -> dict[tuple, tuple]:
    """Every bucket's combined rollup by (level, series key, bucket), row ids
    aside (each store numbers its own rows), and every series' expiry mark."""
    q = store.querier()
    keys = {
        r[0]: tuple(r[1:])
        for r in q._fetch("SELECT sid, tenant, service_path, entity_id, entity_type, attr FROM series", [])
    }
    out: dict[tuple, tuple] = {}
    for level in LEVELS:
        for row in q._fetch(combine_partials(q.dialect, level.view), []):
            out[(level.name, keys[row[0]], row[1])] = tuple(
                v for c, v in zip(COLUMNS[2:], row[2:], strict=True) if not c.endswith("_rid")
            )
    for sid, upto in q._fetch("SELECT sid, upto FROM rollups_expired", []):
        out[("expired", keys[sid], None)] = (upto,)
    return out


@pytest.mark.parametrize("direction", DIRECTIONS)
def test_copy_carries_the_history_only_rollups_hold(direction, tmp_path, pg_cluster):
    """After retention deleted the source's old raw samples, the target's
    rollups hold what the source's do: the expired buckets' as the source
    kept them, the rest rolled up from the copied samples. A series with no
    raw sample left is said, not copied."""
    duck, pg = str(tmp_path / "rolled.duckdb"), pg_cluster.database(f"copy_rolled_{direction[:4]}")
    source_url, target_url = (duck, pg) if direction.startswith("duckdb") else (pg, duck)
    now = datetime.now(UTC).replace(second=0, microsecond=0)
    old, new = now - timedelta(days=40), now - timedelta(days=2)
    source = open_store(Settings(db=source_url))
    try:
        attrs = [AttrSample("speed", "Number", Kind.NUMBER, num=i / 4) for i in range(9)]
        batch = [
            EntitySample(
                "copyland", "/", f"Robot:{e}", "Robot", start + timedelta(minutes=7 * i, seconds=i % 13),
                [attrs[i % 9], AttrSample("mode", "Text", Kind.TEXT, txt="on")],
            )
            for e, starts in ((0, (old, new)), (1, (old, new)), (2, (old,)))  # Robot:2 stopped reporting long ago
            for start in starts
            for i in range(40)
        ]  # fmt: skip
        source.write_sync([AppendSamples(batch, dedup=False)])
        config = RetentionConfig(policy=RetentionPolicy.parse("copyland=30d"), batch_rows=1000, pause=0)
        assert RetentionWorker(source, config).run_once()
        expected = _rolled_up(source)
        report = copy_history(source, target := open_store(Settings(db=target_url)), source_id=source_url)
        try:
            assert report.rolled_up_buckets > 0 and report.rolled_up_left_out == 2  # Robot:2's speed and mode
            got = _rolled_up(target)
            gone = {key for key in expected if key[1][2] == "Robot:2"}
            assert got == {key: v for key, v in expected.items() if key not in gone}
            keys = {r[0]: r[1:] for r in source.querier()._fetch("SELECT sid, entity_id, attr FROM series", [])}
            sids = {r[1:]: r[0] for r in target.querier()._fetch("SELECT sid, entity_id, attr FROM series", [])}
            for page in expired_history(source):  # what a resumed copy does again changes nothing
                if keys[page.sid] in sids:
                    put_expired_history(target, page, sids[keys[page.sid]])
            assert _rolled_up(target) == got
        finally:
            target.close()
    finally:
        source.close()
