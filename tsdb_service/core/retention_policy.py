"""How long rows are kept: the ``TSDB_RETENTION`` policy as a value, parsed once.

A rule names a tenant (``acme``), a tenant's entity type (``acme/Robot``)
or every tenant (``*``), and how long each *level* of history is kept: the
raw samples (``raw``) and the two rollup levels (``minute``, ``hour``;
``storage.rollups``)::

    *=365d,acme=30d,acme/Robot=raw:30d,minute:1y,hour:forever

A bare duration (``acme=30d``) is the raw level, as before rollups had
levels. In the compact form, an entry without ``=`` that starts with a
level name continues the rule before it (``minute:1y`` above).

Invariants:

* per level, the most specific rule that names the level decides
  (``tenant/Type``, then ``tenant``, then ``*``); a level no rule names is
  kept forever, except ``minute``, which then follows ``hour``;
* for every tenant and type, a coarser level is kept at least as long as a
  finer one (raw <= minute <= hour): a rollup is what remains once the
  finer level is gone, so a policy that would drop it first is refused;
* a malformed policy raises ``ValueError`` naming the setting and the rule.

Beside the vocabulary (``config`` validates the settings with it, the
retention worker in ``storage.retention`` applies it), so the settings
never import storage.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import timedelta

FOREVER = "forever"
RAW, MINUTE, HOUR = "raw", "minute", "hour"
LEVELS = (RAW, MINUTE, HOUR)  # finest first
_DURATION = re.compile(r"^(\d+)([smhdwy])$")
_LEVEL_ENTRY = re.compile(r"^\s*(raw|minute|hour)\s*:(.*)$")
_UNIT_SECONDS = {"s": 1, "m": 60, "h": 3600, "d": 86_400, "w": 7 * 86_400, "y": 365 * 86_400}
_TENANT = re.compile(r"^[a-z0-9_]{0,50}$")  # Fiware-Service, lower-cased; "" = default tenant

Keep = timedelta | None  # None: forever
Rule = tuple[str, Keep]  # (the rule's key, how long)


def parse_duration(text: str, setting: str, key: str) -> Keep:
    """``30d`` → 30 days; ``forever`` → None. Units: s, m, h, d, w, y (365 d)."""
    value = text.strip().lower()
    if value == FOREVER:
        return None
    match = _DURATION.match(value)
    if not match:
        raise ValueError(
            f"{setting}: {key or '(default tenant)'}={text!r}: a duration is a whole number followed by "
            "s, m, h, d, w or y (e.g. 30d, 12h), or 'forever'"
        )
    seconds = int(match[1]) * _UNIT_SECONDS[match[2]]
    if seconds <= 0:
        raise ValueError(f"{setting}: {key or '(default tenant)'}={text!r}: a duration must be positive")
    return timedelta(seconds=seconds)


def _rule_key(raw: str, setting: str) -> str:
    """``*``, ``tenant`` or ``tenant/Type``; tenants lower-cased as the API
    does, the empty tenant is the default one (``=30d``, ``/Robot=7d``)."""
    key = raw.strip()
    if key == "*":
        return key
    tenant, slash, entity_type = key.partition("/")
    tenant = tenant.lower()
    if tenant == "*" and slash:
        raise ValueError(f"{setting}: {key!r}: a type rule needs its tenant (acme/{entity_type})")
    if not _TENANT.match(tenant):
        raise ValueError(
            f"{setting}: {key!r}: a tenant is up to 50 letters, digits or '_' (its Fiware-Service), "
            "or '*' for every tenant"
        )
    if slash and not entity_type:
        raise ValueError(f"{setting}: {key!r}: the entity type after '/' is missing")
    return f"{tenant}/{entity_type}" if slash else tenant


def _level_value(text: str) -> tuple[str, str]:
    """``raw:30d`` → (raw, 30d); a bare ``30d`` is the raw level."""
    match = _LEVEL_ENTRY.match(text)
    return (match[1], match[2]) if match else (RAW, text)


def _entries(text: str, setting: str) -> list[tuple[str, str, str]]:
    """(key, level, duration) triples from the compact form or a JSON object."""
    if text.startswith("{"):
        return _json_entries(text, setting)
    out: list[tuple[str, str, str]] = []
    for entry in text.split(","):
        key, eq, value = entry.strip().rpartition("=")
        if not eq:
            continued = _LEVEL_ENTRY.match(entry)
            if continued and out:
                out.append((out[-1][0], continued[1], continued[2]))
                continue
            raise ValueError(
                f"{setting}: {entry.strip()!r} is not rule=duration "
                "(e.g. '*=365d,acme=30d,acme/Robot=raw:7d,minute:1y,hour:forever')"
            )
        out.append((key, *_level_value(value)))
    return out


def _json_entries(text: str, setting: str) -> list[tuple[str, str, str]]:
    try:
        obj = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"{setting}: not a valid JSON object ({exc})") from None
    if not isinstance(obj, dict):
        raise ValueError(f"{setting}: the JSON form must be an object of rule: duration")
    out = []
    for key, value in obj.items():
        if isinstance(value, dict):
            for level, keep in value.items():
                if level not in LEVELS:
                    raise ValueError(f"{setting}: {key!r}: unknown level {level!r} (raw, minute or hour)")
                out.append((key, level, _json_duration(key, keep, setting)))
            continue
        value = _json_duration(key, value, setting)
        for part in value.split(","):
            out.append((key, *_level_value(part)))
    return out


def _json_duration(key: str, value: object, setting: str) -> str:
    if value is None:
        return FOREVER
    if not isinstance(value, str):
        raise ValueError(f'{setting}: {key!r}: the duration must be a string such as "30d" or "forever"')
    return value


def _longer(a: Keep, b: Keep) -> bool:
    """``a`` keeps rows longer than ``b`` (None: forever)."""
    return (a is None and b is not None) or (a is not None and b is not None and a > b)


@dataclass(frozen=True)
class RetentionPolicy:
    """How long each tenant's (and type's) rows are kept, per level.

    ``rules`` holds (key, level, keep) in the order given. Resolution and
    the ordering of levels: see the module's invariants."""

    rules: tuple[tuple[str, str, Keep], ...] = ()
    _by_level: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        by_level: dict[str, dict[str, Keep]] = {level: {} for level in LEVELS}
        for key, level, keep in self.rules:
            by_level[level][key] = keep
        object.__setattr__(self, "_by_level", by_level)

    @classmethod
    def parse(cls, text: str | None, setting: str = "TSDB_RETENTION") -> RetentionPolicy:
        text = (text or "").strip()
        if not text:
            return cls()
        rules: dict[tuple[str, str], Keep] = {}
        for raw_key, level, value in _entries(text, setting):
            key = _rule_key(raw_key, setting)
            if (key, level) in rules:
                what = f"the rule {key!r}" if level == RAW else f"the {level} level of the rule {key!r}"
                raise ValueError(f"{setting}: {what} is given twice")
            rules[(key, level)] = parse_duration(value, setting, key)
        policy = cls(tuple((key, level, keep) for (key, level), keep in rules.items()))
        policy.check(setting)
        return policy

    def with_rollup_rules(self, rollups: RetentionPolicy, setting: str) -> RetentionPolicy:
        """This policy with ``rollups``' rules as both rollup levels: the
        deprecated ``TSDB_ROLLUP_RETENTION``, whose one hourly level held only
        what raw retention had deleted. So a level it would drop before raw
        is kept as long as raw instead, which is what the old setting kept."""
        merged: dict[tuple[str, str], Keep] = {(key, level): keep for key, level, keep in self.rules}
        for key, level, keep in rollups.rules:
            if level != RAW:
                raise ValueError(f"{setting}: {key!r}: give levels in TSDB_RETENTION (raw:, minute:, hour:)")
            for rollup_level in (MINUTE, HOUR):
                if (key, rollup_level) in merged:
                    raise ValueError(
                        f"{setting}: {key!r}: its {rollup_level} level is also given in TSDB_RETENTION; "
                        "keep only TSDB_RETENTION"
                    )
                merged[(key, rollup_level)] = keep
        keys = sorted({"*", *(key for key, _ in merged)}, key=lambda k: (k != "*", "/" in k, k))
        for key in keys:  # least specific first: what a key gets, the more specific ones inherit
            tenant, slash, entity_type = key.partition("/")
            keeps = RetentionPolicy(tuple((k, lv, v) for (k, lv), v in merged.items())).resolve(
                tenant, entity_type if slash else "\0"
            )
            for rollup_level in (MINUTE, HOUR):
                if _longer(keeps[RAW][1], keeps[rollup_level][1]):
                    merged[(key, rollup_level)] = keeps[RAW][1]
        policy = RetentionPolicy(tuple((key, level, keep) for (key, level), keep in merged.items()))
        policy.check("TSDB_RETENTION with " + setting)
        return policy

    def check(self, setting: str) -> None:
        """Refuse a coarser level kept less long than a finer one."""
        for key in ["*", *(k for k, _, _ in self.rules)]:
            tenant, slash, entity_type = key.partition("/")
            keeps = self.resolve(tenant, entity_type if slash else "\0")
            for finer, coarser in ((RAW, MINUTE), (MINUTE, HOUR)):
                if _longer(keeps[finer][1], keeps[coarser][1]):
                    raise ValueError(
                        f"{setting}: {key!r}: {coarser} ({_fmt(keeps[coarser][1])}) would be kept less long than "
                        f"{finer} ({_fmt(keeps[finer][1])}): a coarser level is what remains once a finer one is "
                        "gone, so it must be kept at least as long"
                    )

    @property
    def active(self) -> bool:
        """Whether any rule deletes anything, at any level."""
        return any(keep is not None for _, _, keep in self.rules)

    def rule_for(self, tenant: str, entity_type: str, level: str = RAW) -> Rule | None:
        """The most specific rule naming ``level`` for this tenant and type."""
        rules = self._by_level[level]
        for key in (f"{tenant}/{entity_type}", tenant, "*"):
            if key in rules:
                return key, rules[key]
        return None

    def resolve(self, tenant: str, entity_type: str) -> dict[str, Rule | tuple[None, None]]:
        """Every level's deciding rule ``(key, keep)``, ``(None, None)`` where
        none names it (forever); ``minute`` follows ``hour`` when unnamed."""
        out: dict[str, Rule | tuple[None, None]] = {}
        for level in (RAW, HOUR, MINUTE):
            found: Rule | tuple[None, None] | None = self.rule_for(tenant, entity_type, level)
            if found is None and level == MINUTE:
                found = out[HOUR]
            out[level] = found if found is not None else (None, None)
        return out

    def levels_of(self, key: str) -> Iterable[tuple[str, Keep]]:
        return ((level, keep) for k, level, keep in self.rules if k == key)

    def describe(self) -> str:
        keys = list(dict.fromkeys(k for k, _, _ in self.rules))
        parts = []
        for key in keys:
            levels = list(self.levels_of(key))
            if levels == [(RAW, levels[0][1])]:
                parts.append(f"{key}={_fmt(levels[0][1])}")
            else:
                parts.append(f"{key}=" + ",".join(f"{level}:{_fmt(keep)}" for level, keep in levels))
        return ",".join(parts) or "(keep everything)"


def _fmt(keep: Keep) -> str:
    if keep is None:
        return FOREVER
    seconds = int(keep.total_seconds())
    for unit in "ydhms":
        if seconds % _UNIT_SECONDS[unit] == 0:
            return f"{seconds // _UNIT_SECONDS[unit]}{unit}"
    return f"{seconds}s"  # pragma: no cover - "s" always divides
