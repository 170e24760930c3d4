"""Rollups stay exact: a seeded random model on both backends.

Random batches of samples (late, out of order, several at one instant,
integers, floats, text and nulls), range deletes that cut buckets, NGSI-LD
instance deletes and replacements, raw retention and rollup retention. The
model keeps, per level and bucket, the samples its rollup counts, following
the documented rules (``storage.rollups``): a write adds to both levels; a
delete or an instance edit recomputes a complete bucket from raw, and an
incomplete one only when a deleted range covers it whole; retention leaves
rollups alone. After every step each bucket's rollup (merged and hot rows
combined) must equal the model's, and before retention the QuantumLeap
aggregations over random windows (whole hours and minutes from rollups,
edges from raw) must equal the raw samples'.

Numbers are multiples of 1/8: every sum is exact in any order."""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta

import pytest

from tsdb_service.core.config import Settings
from tsdb_service.core.model import AttrSample, EntitySample, Kind
from tsdb_service.core.query import AggBranch, Aggregation, AggrMethod, AggrPeriod, EntityFilter, Scope, TimeRange
from tsdb_service.core.retention_policy import RetentionPolicy
from tsdb_service.read.requests import SeriesSelect
from tsdb_service.storage import open_store
from tsdb_service.storage.retention import RetentionConfig, RetentionWorker
from tsdb_service.storage.rollup_repair import check
from tsdb_service.storage.rollups import LEVELS, combine_partials
from tsdb_service.write.ops import AppendSamples, DeleteInstance, DeleteSamples, ReplaceInstance

T0 = datetime(2024, 5, 1, 21, 30, tzinfo=UTC)  # an hour, a day and a month boundary inside the data
SPAN_US = 5 * 3600 * 10**6
US = timedelta(microseconds=1)
EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
ENTITIES = ("E0", "E1", "E2")
NUMERIC = (Kind.NUMBER, Kind.INTEGER)


def micros(moment: datetime) -> int:
    return (moment - EPOCH) // US


def moment(us: int) -> datetime:
    return EPOCH + timedelta(microseconds=us)


@dataclass
class Sample:
    entity: str
    attr: str
    t: int  # epoch µs
    order: int  # write order of its entity notification (the store's row ids follow it)
    kind: Kind
    num: float | None


@dataclass
class Model:
    raw: list[Sample] = field(default_factory=list)
    # (level index, entity, attr, bucket µs) -> what the rollup counts: (t, order, kind, num)
    counted: dict[tuple, list[tuple]] = field(default_factory=dict)
    expired_upto: dict[tuple[str, str], int] = field(default_factory=dict)
    order: int = 0

    def bucket(self, level: int, t: int) -> int:
        width = LEVELS[level].width // US
        return t - t % width

    def add(self, s: Sample) -> None:
        self.raw.append(s)
        for level in range(len(LEVELS)):
            self.counted.setdefault((level, s.entity, s.attr, self.bucket(level, s.t)), []).append(snap(s))

    def complete(self, entity: str, attr: str, bucket: int) -> bool:
        upto = self.expired_upto.get((entity, attr))
        return upto is None or bucket > upto

    def recompute(self, level: int, entity: str, attr: str, bucket: int) -> None:
        width = LEVELS[level].width // US
        held = [snap(s) for s in self.raw if (s.entity, s.attr) == (entity, attr) and bucket <= s.t < bucket + width]
        key = (level, entity, attr, bucket)
        if held:
            self.counted[key] = held
        else:
            self.counted.pop(key, None)

    def touched(self, level: int, entity: str, attr: str, start: int | None, end: int | None) -> set[int]:
        width = LEVELS[level].width // US
        return {
            b
            for (lv, e, a, b) in self.counted
            if (lv, e, a) == (level, entity, attr)
            and (start is None or b + width > start)
            and (end is None or b <= end)
        }


def snap(s: Sample) -> tuple:
    return (s.t, s.order, s.kind, s.num)


def partial(held: list[tuple]) -> tuple:
    """The rollup columns after (sid, bucket), rid columns left out."""
    present = sum(1 for _, _, kind, _ in held if kind != Kind.NULL)
    numbers = [(t, o, num, kind) for t, o, kind, num in held if kind in NUMERIC and num is not None]
    if not numbers:
        return (present, 0, 0, None, None, None, None, None, None, None, None, None)
    values = [n for _, _, n, _ in numbers]
    low, high = min(values), max(values)
    first = min(numbers, key=lambda x: (x[0], x[1]))
    last = max(numbers, key=lambda x: (x[0], x[1]))
    return (
        present,
        len(numbers),
        sum(1 for *_, kind in numbers if kind == Kind.INTEGER),
        float(sum(values)),
        low,
        min(t for t, _, n, _ in numbers if n == low),
        high,
        min(t for t, _, n, _ in numbers if n == high),
        first[2],
        first[0],
        last[2],
        last[0],
    )


def without_rids(row: tuple) -> tuple:
    # COLUMNS after (sid, bucket): ... first_us, first_rid, num_last, last_us, last_rid
    counts = tuple(int(v) for v in row[2:5])
    return (*counts, *row[5:12], row[13], row[14])


def store_rollups(store, sid_of: dict[int, tuple[str, str]]) -> dict[tuple, tuple]:
    q = store.querier()
    out = {}
    for index, level in enumerate(LEVELS):
        for row in q._fetch(combine_partials(q.dialect, level.view), []):
            bucket = row[1].replace(tzinfo=UTC)
            out[(index, *sid_of[row[0]], micros(bucket))] = without_rids(row)
    return out


def assert_rollups_match(store, model: Model, sid_of: dict[int, tuple[str, str]]) -> None:
    got = store_rollups(store, sid_of)
    want = {key: partial(held) for key, held in model.counted.items() if held}
    assert sorted(got) == sorted(want)
    for key in want:
        assert got[key] == want[key], key


class Harness:
    def __init__(self, store, seed: int):
        self.store = store
        self.rng = random.Random(seed)
        self.model = Model()

    def sids(self) -> dict[int, tuple[str, str]]:
        q = self.store.querier()
        refs = q.series(SeriesSelect(Scope(""), EntityFilter(types=("T",))))
        return {r.sid: (r.entity_id, r.attr) for r in refs}

    def sids_of(self, entity: str, attr: str | None = None) -> tuple[int, ...]:
        return tuple(sid for sid, (e, a) in self.sids().items() if e == entity and (attr is None or a == attr))

    def value(self, attr: str) -> tuple[Kind, float | None]:
        pick = self.rng.random()
        if attr == "b" and pick < 0.25:
            return (Kind.TEXT, None) if pick < 0.12 else (Kind.NULL, None)
        if pick < 0.45:
            return Kind.INTEGER, float(self.rng.randrange(-20, 20))
        return Kind.NUMBER, self.rng.randrange(-400, 400) / 8

    def write(self, n: int, start_us: int, span_us: int) -> None:
        rng, entities = self.rng, []
        for _ in range(n):
            entity = rng.choice(ENTITIES)
            same = [s.t for s in self.model.raw if s.entity == entity]
            t = rng.choice(same) if same and rng.random() < 0.15 else start_us + rng.randrange(span_us)
            self.model.order += 1
            attrs = []
            for attr in ("a", "b"):
                kind, num = self.value(attr)
                if kind == Kind.TEXT:
                    attrs.append(AttrSample(attr, "Text", kind, txt="on"))
                elif kind == Kind.NULL:
                    attrs.append(AttrSample(attr, None, kind))
                else:
                    attrs.append(AttrSample(attr, "Number", kind, num=num))
                self.model.add(Sample(entity, attr, t, self.model.order, kind, num))
            entities.append(EntitySample("", "/", entity, "T", moment(t), attrs))
        self.store.write_sync([AppendSamples(entities, dedup=False)])

    def delete_range(self) -> None:
        rng = self.rng
        entity = rng.choice(ENTITIES)
        start = micros(T0) + rng.randrange(SPAN_US) if rng.random() < 0.85 else None
        end = (start or micros(T0)) + rng.randrange(SPAN_US // 3) if rng.random() < 0.85 else None
        if rng.random() < 0.3 and start is not None:
            start -= start % (60 * 10**6)  # a minute's first instant
        self.store.write_sync(
            [
                DeleteSamples(
                    self.sids_of(entity), None if start is None else moment(start), moment(end) if end else None
                )
            ]
        )
        m = self.model
        m.raw = [
            s
            for s in m.raw
            if not (s.entity == entity and (start is None or s.t >= start) and (end is None or s.t <= end))
        ]
        for attr in ("a", "b"):
            for level in range(len(LEVELS)):
                width = LEVELS[level].width // US
                for b in m.touched(level, entity, attr, start, end):
                    wholly = (start is None or b >= start) and (end is None or b + width - 1 <= end)
                    if m.complete(entity, attr, b) or wholly:
                        m.recompute(level, entity, attr, b)

    def edit_instance(self) -> None:
        """Delete or replace one sample by its instance id, as NGSI-LD does."""
        rng, m = self.rng, self.model
        if not m.raw:
            return
        target = rng.choice(m.raw)
        [sid] = self.sids_of(target.entity, target.attr)
        q = self.store.querier()
        iids = [
            r[0]
            for r in q._fetch(f"SELECT iid FROM samples_all WHERE sid = {q.dialect.placeholder} ORDER BY rid", [sid])
        ]
        ranked = sorted((s for s in m.raw if (s.entity, s.attr) == (target.entity, target.attr)), key=lambda s: s.order)
        iid = iids[ranked.index(target)]  # row ids follow write order, one sample of a series per row
        if rng.random() < 0.5:
            self.store.write_sync([DeleteInstance(sid, iid)])
            m.raw.remove(target)
        else:
            num = rng.randrange(-400, 400) / 8
            attr = AttrSample(target.attr, "Number", Kind.NUMBER, num=num)
            self.store.write_sync([ReplaceInstance(sid, iid, attr, T0)])
            target.kind, target.num = Kind.NUMBER, num
        for level in range(len(LEVELS)):
            b = m.bucket(level, target.t)
            if m.complete(target.entity, target.attr, b):
                m.recompute(level, target.entity, target.attr, b)

    def retention(self, spec: str, now: datetime) -> dict[str, int]:
        config = RetentionConfig(policy=RetentionPolicy.parse(spec), batch_rows=17, pause=0)
        deleted = RetentionWorker(self.store, config, clock=lambda: now).run_once()
        m = self.model
        for level_name in ("minute", "hour"):
            keep = config.policy.resolve("", "T")[level_name][1]
            if keep is None:
                continue
            level = [lv.name for lv in LEVELS].index(level_name)
            width = LEVELS[level].width // US
            cutoff = micros(now - keep)
            for key in [k for k in m.counted if k[0] == level and k[3] + width <= cutoff]:
                del m.counted[key]
        keep = config.policy.resolve("", "T")["raw"][1]
        if keep is not None:
            cutoff = micros(now - keep)
            for s in [s for s in m.raw if s.t < cutoff]:
                m.raw.remove(s)
                series = (s.entity, s.attr)
                m.expired_upto[series] = max(m.expired_upto.get(series, s.t), s.t)
        return deleted

    def check(self) -> None:
        assert_rollups_match(self.store, self.model, self.sids())

    def check_aggregates(self, windows: int) -> None:
        """Random windows, every period and method: rollups plus raw edges
        give what the raw samples give."""
        sids = tuple(sorted(self.sids()))
        rng = self.rng
        for _ in range(windows):
            a = micros(T0) - 3600 * 10**6 + rng.randrange(SPAN_US + 2 * 3600 * 10**6)
            b = a + rng.randrange(SPAN_US)
            if rng.random() < 0.3:
                a -= a % (3600 * 10**6)
            if rng.random() < 0.3:
                b -= b % 1000
            time = TimeRange(moment(a) if rng.random() < 0.9 else None, moment(b) if rng.random() < 0.9 else None)
            for period in (None, AggrPeriod.MINUTE, AggrPeriod.HOUR, AggrPeriod.DAY, AggrPeriod.MONTH):
                for method in (AggrMethod.COUNT, AggrMethod.SUM, AggrMethod.MIN, AggrMethod.MAX):
                    self._same_aggregate(sids, time, Aggregation(method, period))

    def _same_aggregate(self, sids: tuple[int, ...], time: TimeRange, agg: Aggregation) -> None:
        q = self.store.querier()
        got: dict[tuple, list] = {}
        for row in q._aggregate_sql([AggBranch(sids)], time, agg):
            cell = got.setdefault((row.sid, row.bucket), [0, 0, None, None])
            cell[0] += row.n_present
            cell[1] += row.n_numeric
            if row.value is not None:
                pick = {AggrMethod.MIN: min, AggrMethod.MAX: max}.get(agg.method, lambda x, y: x + y)
                cell[2] = row.value if cell[2] is None else pick(cell[2], row.value)
            cell[3] = row.all_integer if cell[3] is None else (cell[3] and row.all_integer)
        assert got == self._want(sids, time, agg), (time, agg)

    def _want(self, sids: tuple[int, ...], time: TimeRange, agg: Aggregation) -> dict[tuple, list]:
        series = {v: k for k, v in self.sids().items()}
        start = None if time.start is None else micros(time.start)
        end = None if time.end is None else micros(time.end)
        want: dict[tuple, list] = {}
        for s in self.model.raw:
            if (start is not None and s.t < start) or (end is not None and s.t > end):
                continue
            key = (series[(s.entity, s.attr)], _label(s.t, agg.period))
            cell = want.setdefault(key, [0, 0, None, None])
            cell[0] += s.kind != Kind.NULL
            if s.kind in NUMERIC and s.num is not None:
                cell[1] += 1
                if agg.method is not AggrMethod.COUNT:
                    pick = {AggrMethod.MIN: min, AggrMethod.MAX: max}.get(agg.method, lambda x, y: x + y)
                    cell[2] = s.num if cell[2] is None else pick(cell[2], s.num)
                cell[3] = (s.kind == Kind.INTEGER) if cell[3] is None else (cell[3] and s.kind == Kind.INTEGER)
        return want


def _label(t: int, period: AggrPeriod | None) -> str | None:
    if period is None:
        return None
    at = moment(t)
    at = {
        AggrPeriod.MINUTE: at.replace(second=0, microsecond=0),
        AggrPeriod.HOUR: at.replace(minute=0, second=0, microsecond=0),
        AggrPeriod.DAY: at.replace(hour=0, minute=0, second=0, microsecond=0),
        AggrPeriod.MONTH: at.replace(day=1, hour=0, minute=0, second=0, microsecond=0),
    }[period]
    return at.strftime("%Y-%m-%dT%H:%M:%S.000+00:00")


@pytest.fixture
def harness(store_url):
    store = open_store(Settings(db=store_url))
    yield Harness(store, seed=38)
    store.close()


def test_late_out_of_order_deletes_and_edits_keep_rollups_exact(harness):
    h = harness
    h.write(200, micros(T0), SPAN_US)  # a small batch: DuckDB's writer aggregates it in Python
    h.write(1100, micros(T0), SPAN_US)  # a big one: in SQL over the batch (PostgreSQL: the trigger, always)
    h.check()
    h.check_aggregates(6)
    for step in range(8):
        h.write(40, micros(T0) + h.rng.randrange(SPAN_US // 2), SPAN_US // 2)  # late and out of order
        if step % 2 == 0:
            h.delete_range()
        else:
            h.edit_instance()
        if step == 4:
            h.store.compact()  # merged rows and hot rows combine alike
        h.check()
    h.check_aggregates(6)
    report = check(h.store, sorted(h.sids()), samples=400, seed=1)
    assert report.buckets and not report.differences


def test_retention_keeps_rollups_and_deletes_over_expired_buckets_follow_the_rules(harness):
    h = harness
    h.write(250, micros(T0), SPAN_US)
    now = T0 + timedelta(days=10, hours=2, minutes=17, seconds=5)
    # Raw samples older than T0 + 2h17m5s go; the cutoff cuts a minute and an hour.
    deleted = h.retention("*=raw:10d,minute:30d", now)
    assert deleted.get("samples", 0) + deleted.get("samples_hot", 0) > 0
    h.check()
    for _ in range(6):
        h.delete_range()  # over complete, incomplete, and partly expired buckets
        h.write(20, micros(T0), SPAN_US)  # late samples, some into expired buckets
        h.edit_instance()
        h.check()
    # Rollup retention: minute rows of whole minutes older than the cutoff go, hours stay.
    h.retention("*=raw:10d,minute:10d,hour:forever", now + timedelta(hours=1))
    h.check()
    report = check(h.store, sorted(h.sids()), samples=400, seed=2)
    assert not report.differences and report.incomplete > 0
