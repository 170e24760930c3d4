"""Rollups answer aggregations over what retention deleted, through the API.

Minute and hour rollups are kept on ingest, so every aggregation whose
period is made of whole minutes or hours (or none) gives the same answer
after retention deleted the old raw samples as before, also when it spans
rolled-up and raw data; late samples, user deletes, rollup retention and a
restart keep it so. Value paths read raw samples only, as documented."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from urllib.parse import quote

import pytest

from tsdb_service.core.query import EntityFilter, Scope
from tsdb_service.read.requests import SeriesSelect

NOW = datetime.now(UTC).replace(minute=0, second=0, microsecond=0)
OLD = NOW - timedelta(days=60) - timedelta(hours=7)  # 50 hours from here: rolled up
NEW = NOW - timedelta(days=2)  # 10 hours from here: raw
MS = timedelta(milliseconds=1)
H = {"Fiware-Service": "acme"}
SETTINGS = dict(retention="acme=30d", retention_batch_rows=40, retention_pause=0, retention_interval=3600)


def iso(moment: datetime) -> str:
    return moment.isoformat(timespec="milliseconds")


def sample(eid: str, moment: datetime, i: int) -> dict:
    """Floats in quarters and integers, so every sum is exact in any order."""
    body = {
        "id": eid,
        "type": "Robot",
        "TimeInstant": {"type": "DateTime", "value": iso(moment)},
        "speed": {"type": "Number", "value": (i % 17) * 0.25 - 1},
        "ticks": {"type": "Integer", "value": i * 3 - 50},
        "label": {"type": "Text", "value": f"s{i % 3}"},
        "odom": {"type": "StructuredValue", "value": {"x": i % 5}},
    }
    # 'mixed' is an integer in some hours and a float in others; one in ten has no value.
    body["mixed"] = {"value": None} if i % 10 == 0 else {"type": "Number", "value": i if i % 4 else i + 0.5}
    return body


def history(eid: str, start: datetime, hours: int, seed: int) -> list[dict]:
    return [
        sample(eid, start + timedelta(hours=h, minutes=m), seed + h * 3 + k)
        for h in range(hours)
        for k, m in enumerate((0, 20, 40))
    ]


def load(client, notify) -> None:
    for eid, seed in (("Robot:1", 0), ("Robot:2", 7)):
        notify(client, {"subscriptionId": "s", "data": history(eid, OLD, 50, seed)}, H)
        notify(client, {"subscriptionId": "s", "data": history(eid, NEW, 10, seed + 500)}, H)


def queries() -> list[str]:
    spans = [
        "",  # everything: rolled-up and raw
        f"&fromDate={quote(iso(OLD + timedelta(hours=5)))}&toDate={quote(iso(OLD + timedelta(hours=29) - MS))}",
        f"&fromDate={quote(iso(OLD + timedelta(hours=30)))}&toDate={quote(iso(NEW + timedelta(hours=4)))}",
    ]
    out = []
    for method in ("count", "sum", "avg", "min", "max"):
        for period in ("", "&aggrPeriod=minute", "&aggrPeriod=hour", "&aggrPeriod=day", "&aggrPeriod=month"):
            for span in spans:
                q = f"aggrMethod={method}{period}{span}"
                out += [f"/v2/entities/Robot:1/attrs/{attr}?{q}" for attr in ("speed", "ticks", "mixed", "label")]
                out.append(f"/v2/entities/Robot:2?{q}")
                out.append(f"/v2/types/Robot/attrs/ticks?{q}")
                out.append(f"/v2/attrs?{q}&aggrScope=global")
            out.append(f"/v2/entities/Robot:1/attrs/speed?aggrMethod={method}{period}&lastN=3")
    return out


def answers(client, paths: list[str]) -> dict[str, tuple[int, object]]:
    return {p: (r.status_code, r.json()) for p in paths for r in [client.get(p, headers=H)]}


def raw_count(client) -> int:
    """Raw samples left (``Querier.count`` also counts rolled-up hours)."""
    return client.app.state.store.querier()._fetch("SELECT count(*) FROM samples_all", [])[0][0]


def rollup_rows(client, level: str = "hour") -> list[tuple]:
    """(sid, bucket, n_present) of each bucket of ``level``, merged and hot rows combined."""
    q = client.app.state.store.querier()
    return q._fetch(
        f"SELECT sid, bucket, sum(n_present) FROM rollups_{level}_all GROUP BY sid, bucket ORDER BY sid, bucket", []
    )


@pytest.fixture
def loaded(client_factory, store_url, notify):
    with client_factory(store_url, **SETTINGS) as client:
        load(client, notify)
        yield client


def test_answers_are_the_same_after_retention_deleted_the_old_samples(loaded):
    paths = queries()
    before = answers(loaded, paths)
    assert before["/v2/entities/Robot:1/attrs/ticks?aggrMethod=sum&aggrPeriod=day"][0] == 200
    assert before["/v2/entities/Robot:1/attrs/label?aggrMethod=sum&aggrPeriod=day"][0] == 404  # text
    assert len(rollup_rows(loaded)) == 2 * (50 + 10) * 6  # one per series and hour, written on ingest
    deleted = loaded.app.state.store.retention.run_once()
    assert deleted and sum(deleted.values()) == 2 * 50 * 3 * 6  # every old sample of 6 attributes (TimeInstant too)
    assert raw_count(loaded) == 2 * 10 * 3 * 6
    assert len(rollup_rows(loaded)) == 2 * (50 + 10) * 6  # retention leaves rollups
    assert len(rollup_rows(loaded, "minute")) == 2 * (50 + 10) * 3 * 6
    after = answers(loaded, paths)
    assert after == before


def test_late_samples_are_counted_before_and_after_retention(loaded, notify):
    path = "/v2/entities/Robot:1/attrs/ticks?aggrMethod=sum&aggrPeriod=day"
    loaded.app.state.store.retention.run_once()
    before = loaded.get(path, headers=H).json()
    late = sample("Robot:1", OLD + timedelta(hours=2, minutes=10), 0)
    late["ticks"]["value"] = 1000
    notify(loaded, {"subscriptionId": "s", "data": [late]}, H)
    day = iso((OLD + timedelta(hours=2)).replace(hour=0)).replace("Z", "+00:00")
    expected = [v + 1000 if i == before["index"].index(day) else v for i, v in enumerate(before["values"])]
    assert loaded.get(path, headers=H).json()["values"] == expected  # rolled up on ingest
    assert sum(loaded.app.state.store.retention.run_once().values()) == 6  # the late notification's samples
    assert loaded.get(path, headers=H).json()["values"] == expected  # its rollups stay


def test_minutes_and_cut_hours_come_from_rollups_value_paths_from_raw(loaded):
    loaded.app.state.store.retention.run_once()
    minute = loaded.get("/v2/entities/Robot:1/attrs/ticks?aggrMethod=count&aggrPeriod=minute", headers=H).json()
    every = [
        iso(start + timedelta(hours=h, minutes=m))
        for start, hours in ((OLD, 50), (NEW, 10))
        for h in range(hours)
        for m in (0, 20, 40)
    ]
    assert (minute["index"], minute["values"]) == (every, [1] * 180)  # one sample a bucket, to the ms
    path = loaded.get("/v2/entities/Robot:1/attrs/odom(x)?aggrMethod=count", headers=H).json()
    assert path["values"] == [30]  # only the raw window
    # A range starting mid-hour counts that hour's later minutes (from minute rollups).
    cut = loaded.get(
        f"/v2/entities/Robot:1/attrs/ticks?aggrMethod=count&fromDate="
        f"{quote(iso(OLD + timedelta(hours=4, minutes=30)))}",
        headers=H,
    ).json()
    assert cut["values"] == [(50 - 5) * 3 + 1 + 30]  # the 4:40 sample too
    # A range ending on an hour's first instant cuts that instant's minute: it is read from raw samples,
    # which retention deleted (documented), so the 10:00 sample is not counted; one ending on the hour's
    # last millisecond before covers whole minutes only.
    ends = [OLD + timedelta(hours=10), OLD + timedelta(hours=10) - MS]
    got = [
        loaded.get(f"/v2/entities/Robot:1/attrs/ticks?aggrMethod=count&toDate={quote(iso(end))}", headers=H).json()[
            "values"
        ]
        for end in ends
    ]
    assert got == [[30], [30]]


def _drawn(client, **params):
    r = client.get("/grafana/infinity/series", params={"id": "Robot:1", "attrs": "v=speed", **params}, headers=H)
    assert r.status_code == 200, r.text
    return r.json(), r.headers["X-Tsdb-Bucket"]


def test_drawing_after_retention_shows_the_rolled_up_history(loaded):
    """A panel of all data starts where the rollups' history does, and raw
    samples that would fit the budget but no longer hold the window's start
    give way to buckets."""
    before = _drawn(loaded, max_points=100)
    assert before[1] == "1d" and before[0][0]["time"] == iso(OLD).replace("+00:00", "Z")
    assert _drawn(loaded, max_points=1000)[1] == "raw"  # 180 samples: drawn as stored
    loaded.app.state.store.retention.run_once()
    assert _drawn(loaded, max_points=100) == before  # the window found from the rollups too
    rows, width = _drawn(loaded, max_points=1000)
    assert width == "2h" and rows[0]["time"] == before[0][0]["time"]  # 30 raw samples left, but buckets
    window = {"from": int(OLD.timestamp() * 1000), "to": int((NEW + timedelta(hours=10)).timestamp() * 1000)}
    assert _drawn(loaded, max_points=1000, **window)[1] == "2h"
    # Ten hours that only rollups hold, from an open start: minute buckets, each sample's value.
    rows, width = _drawn(loaded, max_points=1000, to=int((OLD + timedelta(hours=10)).timestamp() * 1000) - 1)
    drawn = [row for row in rows if row["v"] is not None]
    assert width != "raw" and drawn[0]["time"] == before[0][0]["time"] and len(drawn) == 30


def test_deleting_an_entity_removes_its_rollups(loaded):
    loaded.app.state.store.retention.run_once()
    count = "/v2/entities/Robot:1/attrs/ticks?aggrMethod=count"
    assert loaded.get(count, headers=H).json()["values"] == [180]
    # Over expired samples a range delete drops the buckets it covers whole
    # (10:00 to 19:59) and keeps the ones it only cuts (the 20:00 hour and minute).
    r = loaded.delete(
        f"/v2/entities/Robot:1?type=Robot&fromDate={quote(iso(OLD + timedelta(hours=10)))}"
        f"&toDate={quote(iso(OLD + timedelta(hours=20)))}",
        headers=H,
    )
    assert r.status_code == 204, r.text
    assert loaded.get(count, headers=H).json()["values"] == [180 - 30]
    assert loaded.delete("/v2/entities/Robot:2?type=Robot", headers=H).status_code == 204
    assert loaded.get("/v2/entities/Robot:2?aggrMethod=count", headers=H).json() == []
    store = loaded.app.state.store
    robot2 = {r.sid for r in store.querier().series(SeriesSelect(Scope("acme"), EntityFilter(ids=("Robot:2",))))}
    assert not [row for row in rollup_rows(loaded) + rollup_rows(loaded, "minute") if row[0] in robot2]


@pytest.mark.parametrize(
    "settings",
    [{"retention": "acme=raw:30d,minute:60d,hour:60d"}, {"rollup_retention": "acme=60d"}],
    ids=["levels", "deprecated"],
)
def test_rollup_retention_trims_old_rollup_rows(client_factory, store_url, notify, settings):
    with client_factory(store_url, **{**SETTINGS, **settings}) as client:
        load(client, notify)
        worker = client.app.state.store.retention
        worker.run_once()
        horizon = worker.watermarks[("hour", "acme")].replace(tzinfo=None)
        buckets = [row[1] for row in rollup_rows(client)]
        assert buckets and min(buckets) >= horizon - timedelta(hours=1)
        assert len(buckets) < 2 * 60 * 6  # the oldest hours are gone
        assert OLD.replace(tzinfo=None) < horizon <= datetime.now(UTC).replace(tzinfo=None) - timedelta(days=60)
        assert ("minute", "acme") in worker.watermarks


def test_a_restart_keeps_rollups_and_watermarks(client_factory, store_url, notify):
    paths = [p for p in queries() if "aggrScope" in p or "types" in p]
    with client_factory(store_url, **SETTINGS) as client:
        load(client, notify)
        before = answers(client, paths)
        client.app.state.store.retention.run_once()
        marks = dict(client.app.state.store.retention.watermarks)
    with client_factory(store_url, **SETTINGS) as client:
        assert client.app.state.store.retention.watermarks == marks
        assert answers(client, paths) == before
    # Rollups keep answering with retention switched off later.
    with client_factory(store_url) as client:
        assert answers(client, paths) == before


def test_metrics_count_deleted_rows_and_report_the_watermark_lag(loaded):
    loaded.app.state.store.retention.run_once()
    text = loaded.get("/metrics").text
    deleted = [line for line in text.splitlines() if line.startswith("tsdb_retention_deleted_rows_total{")]
    assert sum(float(line.rsplit(" ", 1)[1]) for line in deleted) == 1800
    assert all('tenant="acme"' in line for line in deleted)
    lag = [line for line in text.splitlines() if line.startswith("tsdb_retention_watermark_lag_seconds{")]
    assert lag and 'rule="acme"' in lag[0] and 'table="samples"' in lag[0]
    assert 0 <= float(lag[0].rsplit(" ", 1)[1]) < 3600
    assert "tsdb_retention_batch_duration_seconds_count" in text
