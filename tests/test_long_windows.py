"""Long windows on the faces that draw, on both backends: the whole window in
buckets whose values are those of a Python computation over the samples as
sent (late and out of order), each mode and fill, gaps as nulls, states
never averaged, the min-max mode keeping a one-sample spike, caps said and
never silent (Infinity headers, SimpleJSON frame notices, QuantumLeap's
default limit), raw samples when they fit, and ``export`` by bucket.
"""

from __future__ import annotations

import csv
import io
import itertools
from datetime import timedelta

import pytest

from tests.support import long_windows as data
from tsdb_service.core.buckets import choose_width

API = "/grafana/infinity"
H = data.HEADERS
ROBOT = data.ROBOTS[0]
T0_US = data.micros(data.T0.isoformat())
SPAN_US = data.HOURS * 3_600_000_000
SPIKE = "urn:Spike:1"


@pytest.fixture(scope="module")
def served(client_factory, store_url_factory):
    with client_factory(store_url_factory("long_windows"), default_limit=100) as client:
        states = data.load(client)
        _load_spike(client)
        yield client, states


def _load_spike(client) -> None:
    """2,000 samples of 1.0 a second apart, one of them 100.0."""
    states = []
    for i in range(2000):
        at = data.T0 + timedelta(seconds=i)
        value = 100.0 if i == 1234 else 1.0
        states.append(
            {
                "id": SPIKE,
                "type": "Spike",
                "level": {"type": "Number", "value": value},
                "TimeInstant": {"type": "DateTime", "value": at.isoformat().replace("+00:00", "Z")},
            }
        )
    for i in range(0, len(states), 200):
        response = client.post("/v2/notify", json={"subscriptionId": "s", "data": states[i : i + 200]}, headers=H)
        assert response.status_code == 200, response.text


def _series(client, **params):
    response = client.get(f"{API}/series", params=params, headers=H)
    assert response.status_code == 200, response.text
    return response.json(), response.headers


def _expected(samples, width_us: int, window: tuple[int, int]) -> dict[int, list]:
    """Bucket start → the numeric samples (time, value) of a window, as sent."""
    out: dict[int, list] = {}
    for t, v in samples:
        if window[0] <= t <= window[1] and isinstance(v, (int, float)) and not isinstance(v, bool):
            out.setdefault(t - t % width_us, []).append((t, v))
    return out


def _value(mode: str, bucket: list):
    values = [v for _, v in bucket]
    return {
        "avg": sum(values) / len(values),
        "min": min(values),
        "max": max(values),
        "first": values[0],
        "last": values[-1],
        "count": len(values),
        "sum": sum(values),
    }[mode]


def _ms(micros: int) -> int:
    return micros // 1000


def _times(rows) -> list[int]:
    return [data.micros(r["time"]) for r in rows]


def _by_time(rows, key: str = "v") -> dict[int, object]:
    return dict(zip(_times(rows), [r[key] for r in rows], strict=True))


@pytest.mark.parametrize("mode", ["avg", "min", "max", "first", "last", "count", "sum"])
@pytest.mark.parametrize("bounded", [True, False])
def test_every_bucket_of_the_whole_window_equals_python(served, mode, bounded):
    """Buckets from the window's first to its last, each valued as Python
    values the samples sent (out of order, with equal instants), the first
    stamped where the window starts."""
    client, states = served
    samples = data.samples(states, ROBOT, "speed")
    if bounded:
        window = (T0_US + 123_000, T0_US + SPAN_US - 456_000)
        params = {"from": _ms(window[0]), "to": _ms(window[1])}
    else:  # all data: the window is the data's own
        times = [t for t, _ in samples]
        window = (min(times), max(times))
        params = {}
    rows, headers = _series(client, id=ROBOT, attrs="v=speed", max_points=50, agg=mode, fill="null", **params)
    width = choose_width(timedelta(microseconds=window[1] - window[0]), 50)
    width_us = width // timedelta(microseconds=1)
    assert headers["X-Tsdb-Bucket-Ms"] == str(width_us // 1000)
    expected = _expected(samples, width_us, window)
    grid = range(window[0] - window[0] % width_us, window[1] + 1, width_us)
    assert len(rows) == len(grid) <= 50, "one row per bucket of the window, the empty ones null (fill=null)"
    assert _times(rows) == [max(start, window[0]) // 1000 * 1000 for start in grid]
    for start, row in zip(grid, rows, strict=True):
        bucket = expected.get(start)
        if bucket is None:
            assert row["v"] is None
        else:
            assert row["v"] == pytest.approx(_value(mode, bucket)), start
    assert rows[0]["v"] is not None and rows[-1]["v"] is not None, "the first and last buckets hold data"


def test_a_gap_is_one_null_or_filled(served):
    """The hour without samples: fill=none marks it with one null at its
    first empty bucket; null, previous and linear fill every empty bucket."""
    client, states = served
    window = (T0_US, T0_US + SPAN_US - 1000)
    params = {"id": ROBOT, "attrs": "v=speed", "from": _ms(window[0]), "to": _ms(window[1]), "max_points": 100}
    width_us = choose_width(timedelta(microseconds=SPAN_US), 100) // timedelta(microseconds=1)
    expected = _expected(data.samples(states, ROBOT, "speed"), width_us, window)
    outage = [data.micros(t.isoformat()) for t in data.OUTAGE]
    empty = [s for s in range(outage[0], outage[1], width_us) if s not in expected]
    assert len(empty) >= 10
    rows, _ = _series(client, **params)
    nulls = [r for r in rows if r["v"] is None]
    starts = sorted(expected)
    breaks = [a + width_us for a, b in itertools.pairwise(starts) if b - a > width_us]
    assert empty[0] in breaks
    assert _times(nulls) == breaks, "one null where a run of empty buckets starts: the line breaks"
    assert len(rows) == len(expected) + len(breaks)
    before = max(s for s in expected if s < empty[0])
    after = min(s for s in expected if s > empty[-1])
    at = {fill: _by_time(_series(client, fill=fill, **params)[0]) for fill in ("null", "previous", "linear")}
    v0, v1 = _value("avg", expected[before]), _value("avg", expected[after])
    for start in empty:
        assert at["null"][start] is None
        assert at["previous"][start] == pytest.approx(v0)
        assert at["linear"][start] == pytest.approx(v0 + (v1 - v0) * (start - before) / (after - before))


def test_minmax_keeps_a_one_sample_spike(served):
    client, _ = served
    params = {"id": SPIKE, "attrs": "level", "max_points": 20}
    averaged, _ = _series(client, agg="avg", **params)
    assert max(r["level"] for r in averaged) < 100.0
    rows, headers = _series(client, agg="minmax", **params)
    assert headers["X-Tsdb-Bucket"] != "raw"
    spike = [r for r in rows if r["level"] == 100.0]
    assert [data.micros(r["time"]) for r in spike] == [T0_US + 1234 * 1_000_000], "at its own time"
    assert len(rows) <= 4 * 20


def test_states_are_never_averaged(served):
    """Integer codes show the bucket's last code (auto); texts and booleans
    their transitions as sent, in /series and /states, never a mean."""
    client, states = served
    codes = data.samples(states, ROBOT, "count")
    window = (codes[0][0], codes[-1][0])
    width_us = choose_width(timedelta(microseconds=window[1] - window[0]), 30) // timedelta(microseconds=1)
    expected = _expected(codes, width_us, window)
    rows, _ = _series(client, id=ROBOT, attrs="c=count", max_points=30)
    shown = [r["c"] for r in rows if r["c"] is not None]
    assert shown == [expected[start][-1][1] for start in sorted(expected)], "each bucket's last code"
    assert all(type(c) is int for c in shown)
    flags = data.samples(states, ROBOT, "busy")
    transitions = [(t, v) for i, (t, v) in enumerate(flags) if i == 0 or v != flags[i - 1][1]]
    if flags[-1][0] != transitions[-1][0]:
        transitions.append(flags[-1])  # the line of states ends with the last sample
    assert len(transitions) < 200 < len(flags)
    rows, headers = _series(client, id=ROBOT, attrs="b=busy", max_points=200)
    assert [(data.micros(r["time"]), r["b"]) for r in rows] == transitions
    assert "X-Tsdb-Truncated" not in headers
    texts = [(t, v) for t, v in data.samples(states, ROBOT, "mode") if v is not None]
    rows, headers = _series(client, id=ROBOT, attrs="m=mode", max_points=100_000)
    assert headers["X-Tsdb-Bucket"] == "raw"
    assert [(data.micros(r["time"]), r["m"]) for r in rows] == texts, "as few as that: drawn as stored"
    response = client.get(f"{API}/states", params={"id": ROBOT, "attrs": "m=mode,b=busy"}, headers=H)
    assert response.status_code == 200
    timeline = response.json()
    assert {r["m"] for r in timeline} <= {None, *data.MODES}
    assert {r["b"] for r in timeline} <= {True, False, None}


def test_caps_are_said(served):
    """A cap that bites keeps the newest and says so; one that does not bite says nothing."""
    client, _ = served
    whole = client.get(f"{API}/states", params={"id": ROBOT, "attrs": "b=busy"}, headers=H)
    assert "X-Tsdb-Truncated" not in whole.headers
    capped = client.get(f"{API}/states", params={"id": ROBOT, "attrs": "b=busy", "max_points": 3}, headers=H)
    assert capped.headers["X-Tsdb-Truncated"] == "true"
    assert "state changes" in capped.headers["X-Tsdb-Notice"]
    assert capped.json() == whole.json()[-len(capped.json()) :], "the newest are kept"
    events = client.get(f"{API}/events", params={"id": ROBOT, "attrs": "b=busy", "limit": 2}, headers=H)
    assert events.headers["X-Tsdb-Truncated"] == "true" and len(events.json()) == 2
    body = {
        "range": {"from": data.T0.isoformat(), "to": (data.T0 + timedelta(hours=data.HOURS)).isoformat()},
        "maxDataPoints": 3,
        "targets": [{"target": f"{ROBOT}/mode", "refId": "A", "payload": {"format": "dataframe"}}],
    }
    response = client.post("/grafana/simplejson/query", json=body, headers=H)
    (frame,) = response.json()
    assert frame["meta"]["notices"][0]["severity"] == "warning"
    assert response.headers["X-Tsdb-Truncated"] == "true"
    body["maxDataPoints"] = 1000
    (frame,) = client.post("/grafana/simplejson/query", json=body, headers=H).json()
    assert "notices" not in frame["meta"]


def test_simplejson_draws_the_range_in_max_data_points(served):
    client, states = served
    start, end = T0_US, T0_US + SPAN_US
    body = {
        "range": {"from": _ms(start), "to": _ms(end)},
        "maxDataPoints": 40,
        "intervalMs": 60_000,
        "targets": [
            {"target": f"{ROBOT}/speed", "refId": "A", "payload": {"format": "dataframe"}},
            {"target": f"{ROBOT}/speed", "refId": "B", "payload": {"agg": "max"}},
        ],
    }
    response = client.post("/grafana/simplejson/query", json=body, headers=H)
    frame, classic = response.json()
    width = choose_width(timedelta(microseconds=end - start), 40, timedelta(minutes=1))
    width_ms = width // timedelta(milliseconds=1)
    assert frame["meta"]["custom"] == {"bucket": "10min", "agg": "auto", "bucketMs": width_ms}
    assert frame["fields"][0]["config"] == {"interval": width_ms}
    expected = _expected(data.samples(states, ROBOT, "speed"), width_ms * 1000, (start, end))
    times, values = frame["fields"][0]["values"], frame["fields"][1]["values"]
    assert times[0] == _ms(start) and times[-1] == max(expected) // 1000
    for t, v in zip(times, values, strict=True):
        if v is not None:
            assert v == pytest.approx(_value("avg", expected[t * 1000]))
    assert [v for v, _ in classic["datapoints"] if v is not None] == [
        pytest.approx(_value("max", expected[s])) for s in sorted(expected)
    ]


def test_raw_samples_when_they_fit(served):
    client, states = served
    start = T0_US
    end = T0_US + 600_000_000
    rows, headers = _series(client, id=ROBOT, attrs="v=speed", max_points=1000, **{"from": _ms(start), "to": _ms(end)})
    assert headers["X-Tsdb-Bucket"] == "raw"
    sent = [(t, v) for t, v in data.samples(states, ROBOT, "speed") if start <= t <= end and v is not None]
    assert sorted((data.micros(r["time"]), r["v"]) for r in rows) == sorted(sent)


def test_quantumleap_says_when_its_default_limit_ends_the_answer(served):
    client, _ = served
    path = f"/v2/entities/{ROBOT}/attrs/count"
    capped = client.get(path, headers=H)
    assert capped.status_code == 200 and len(capped.json()["index"]) == 100
    assert capped.headers["X-Tsdb-Truncated"] == "true"
    assert "offset=100" in capped.headers["Link"] and 'rel="next"' in capped.headers["Link"]
    asked = client.get(path, params={"limit": 10}, headers=H)
    assert "X-Tsdb-Truncated" not in asked.headers and len(asked.json()["index"]) == 10
    few = client.get(path, params={"lastN": 5}, headers=H)
    assert "X-Tsdb-Truncated" not in few.headers


def test_export_by_bucket(served):
    client, states = served
    response = client.get("/v2/export", params={"bucket": "1h", "attrs": "speed", "id": ROBOT}, headers=H)
    assert response.status_code == 200, response.text
    rows = list(csv.DictReader(io.StringIO(response.text)))
    assert list(rows[0]) == [
        "time",
        "entity_id",
        "entity_type",
        "service_path",
        "attribute",
        "n",
        "avg",
        "min",
        "max",
        "first",
        "last",
    ]
    expected = _expected(data.samples(states, ROBOT, "speed"), 3_600_000_000, (0, 2**62))
    assert [data.micros(r["time"]) for r in rows] == sorted(expected)
    for row in rows:
        bucket = expected[data.micros(row["time"])]
        assert int(row["n"]) == len(bucket)
        for name in ("avg", "min", "max", "first", "last"):
            assert float(row[name]) == pytest.approx(_value(name, bucket))
    bad = client.get("/v2/export", params={"bucket": "1 hour"}, headers=H)
    assert bad.status_code == 400 and "bucket" in bad.json()["description"]
