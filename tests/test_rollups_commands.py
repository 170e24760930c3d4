"""``tsdb-service rollups rebuild|check`` on both backends.

``check`` finds rollups that differ from raw (a row missing, a value
changed, a stray hot row) and exits 1, listing them; ``rebuild`` puts them
right, creates the rows of samples loaded behind the writers' back, keeps
the history only rollups hold (expired raw samples) unless
``--drop-expired``, and touches only the tenant, type and window asked for.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from tests.support.rollups import differences
from tsdb_service.cli.main import main
from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.storage import open_store
from tsdb_service.write.ops import AppendSamples

T0 = datetime(2024, 5, 1, 22, 10, tzinfo=UTC)
NOW = datetime.now(UTC).replace(microsecond=0)


def entities(tenant: str, etype: str, start: datetime, n: int) -> list[EntitySample]:
    return [
        EntitySample(
            tenant,
            "/",
            f"{etype}:{i % 3}",
            etype,
            start + timedelta(seconds=23 * i),
            [AttrSample("v", "Number", Kind.NUMBER, num=(i % 11) / 4), AttrSample("n", "Integer", Kind.INTEGER, num=i)],
        )
        for i in range(n)
    ]


def stored(url: str, *batches: list[EntitySample], **settings):
    store = open_store(Settings(db=url, **settings))
    for batch in batches:
        store.write_sync([AppendSamples(batch)])
    return store


def damage(store, where: str) -> None:
    """Rollup rows changed behind the service's back, in the tenant of ``where``."""
    q = store.querier()
    sids = f"sid IN (SELECT sid FROM series WHERE {where})"
    store.compact()  # hot rows merged into their levels
    first_hour = f"(SELECT min(bucket) FROM rollups_hour WHERE {sids})"
    last_minute = f"(SELECT max(bucket) FROM rollups_minute WHERE {sids})"
    store.rewrite_rollups(
        [
            (f"DELETE FROM rollups_hour WHERE {sids} AND bucket = {first_hour}", []),
            (f"UPDATE rollups_minute SET num_max = 99 WHERE {sids} AND bucket = {last_minute}", []),
            (
                f"INSERT INTO rollups_hot (level, sid, bucket, n_present, n_numeric, n_integer) "
                f"SELECT 1, min(sid), {q.dialect.placeholder}, 1, 0, 0 FROM series WHERE {where}",
                [q.dialect.time_value(T0 - timedelta(days=2))],
            ),
        ]
    )


def test_check_finds_damage_and_rebuild_repairs_it(store_url, capsys):
    store = stored(store_url, entities("acme", "Robot", T0, 400))
    damage(store, "tenant = 'acme'")
    store.close()
    assert main(["rollups", "check", "--db", store_url, "--seed", "3", "--samples", "4000"]) == 1
    out = capsys.readouterr().out
    assert "row is None in rollups, 'present' from raw" in out  # the hour row deleted
    assert "num_max is 99.0 in rollups" in out
    assert "row is 'present' in rollups, None from raw" in out  # the stray row
    assert main(["rollups", "rebuild", "--db", store_url, "--quiet"]) == 0
    assert "rebuilt" in capsys.readouterr().out
    assert main(["rollups", "check", "--db", store_url]) == 0
    assert ": 0 differences" in capsys.readouterr().out
    store = open_store(Settings(db=store_url))
    try:
        assert not differences(store)
    finally:
        store.close()


def test_rebuild_keeps_what_only_rollups_hold_unless_asked(store_url, capsys):
    old = NOW - timedelta(days=40)
    store = stored(
        store_url, entities("acme", "Robot", old, 200), entities("acme", "Robot", NOW - timedelta(days=1), 50)
    )
    count = "SELECT sum(n_present) FROM rollups_hour_all"
    before = store.querier()._fetch(count, [])[0][0]
    store.close()
    store = open_store(Settings(db=store_url, retention="acme=30d", retention_pause=0))
    assert store.retention.run_once()  # the old raw samples go, their rollups stay
    store.close()
    assert main(["rollups", "rebuild", "--db", store_url, "--quiet"]) == 0
    assert main(["rollups", "check", "--db", store_url]) == 0
    assert "skipped: retention deleted" in capsys.readouterr().out
    store = open_store(Settings(db=store_url))
    assert store.querier()._fetch(count, [])[0][0] == before
    store.close()
    assert main(["rollups", "rebuild", "--db", store_url, "--drop-expired", "--quiet"]) == 0
    store = open_store(Settings(db=store_url))
    try:
        assert store.querier()._fetch(count, [])[0][0] == 50 * 2  # what raw holds
    finally:
        store.close()


def test_rebuild_touches_only_the_selection(store_url, capsys):
    store = stored(store_url, entities("acme", "Robot", T0, 200), entities("beta", "Robot", T0, 200))
    damage(store, "tenant = 'beta'")
    damage(store, "tenant = 'acme'")
    store.close()
    window = ["--from", "2024-04-29T00:00:00Z", "--to", "2024-05-03T00:00:00Z"]
    assert (
        main(["rollups", "rebuild", "--db", store_url, "--tenant", "ACME", "--type", "Robot", *window, "--quiet"]) == 0
    )
    capsys.readouterr()
    assert main(["rollups", "check", "--db", store_url, "--tenant", "acme", "--samples", "4000"]) == 0
    assert main(["rollups", "check", "--db", store_url, "--tenant", "beta", "--samples", "4000", "--seed", "1"]) == 1
    assert main(["rollups", "rebuild", "--db", store_url, "--type", "Room", "--quiet"]) == 0
    assert "nothing to rebuild: 0 series" in capsys.readouterr().out


def test_rebuild_rolls_up_samples_loaded_behind_the_writers_back(store_url, backend):
    store = stored(store_url, entities("", "Room", T0, 10))
    q = store.querier()
    # A bulk load in SQL (as benchmarks/growth.py does); PostgreSQL's trigger
    # folds it, DuckDB's writer never sees it.
    store.rewrite_rollups(
        [
            (
                "INSERT INTO samples (rid, sid, t, kind, num) SELECT 1000 + i, (SELECT min(sid) FROM series), "
                f"{q.dialect.placeholder} + i * INTERVAL '1 minute', 1, i FROM generate_series(1, 300) AS g(i)",
                [q.dialect.time_value(T0)],
            )
        ]
    )
    if backend == "duckdb":
        assert differences(store)
    store.close()
    assert main(["rollups", "rebuild", "--db", store_url, "--quiet"]) == 0
    store = open_store(Settings(db=store_url))
    try:
        assert not differences(store)
    finally:
        store.close()


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--from", "2024-05-02T00:00:00Z", "--to", "2024-05-01T00:00:00Z"], "--from must be before --to"),
        (["--from", "yesterday"], "--from: 'yesterday' is not an ISO 8601 time"),
    ],
)
def test_refusals_are_one_line(store_url, capsys, args, said):
    stored(store_url, entities("", "Room", T0, 3)).close()
    assert main(["rollups", "rebuild", "--db", store_url, *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and said in err[0]


def test_a_missing_file_is_not_created(tmp_path, capsys):
    missing = tmp_path / "nope.duckdb"
    assert main(["rollups", "check", "--db", str(missing)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not missing.exists()
