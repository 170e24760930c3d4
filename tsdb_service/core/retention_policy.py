"""How long rows are kept: the ``TSDB_RETENTION`` / ``TSDB_ROLLUP_RETENTION``
policy as a value, parsed once.

Beside the vocabulary (``config`` validates the settings with it, the
retention worker in ``storage.retention`` applies it), so the settings
never import storage.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from datetime import timedelta

FOREVER = "forever"
_DURATION = re.compile(r"^(\d+)([smhdwy])$")
_UNIT_SECONDS = {"s": 1, "m": 60, "h": 3600, "d": 86_400, "w": 7 * 86_400, "y": 365 * 86_400}
_TENANT = re.compile(r"^[a-z0-9_]{0,50}$")  # Fiware-Service, lower-cased; "" = default tenant

Keep = timedelta | None  # None: forever


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


def _entries(text: str, setting: str) -> list[tuple[str, str]]:
    """(key, duration) pairs from the compact form or a JSON object."""
    if text.startswith("{"):
        try:
            obj = json.loads(text)
        except ValueError as exc:
            raise ValueError(f"{setting}: not a valid JSON object ({exc})") from None
        if not isinstance(obj, dict):
            raise ValueError(f"{setting}: the JSON form must be an object of rule: duration")
        out = []
        for key, value in obj.items():
            if value is None:
                value = FOREVER
            if not isinstance(value, str):
                raise ValueError(f'{setting}: {key!r}: the duration must be a string such as "30d" or "forever"')
            out.append((key, value))
        return out
    out = []
    for entry in text.split(","):
        key, eq, value = entry.strip().rpartition("=")
        if not eq:
            raise ValueError(
                f"{setting}: {entry.strip()!r} is not rule=duration (e.g. '*=365d,acme=30d,acme/Robot=7d')"
            )
        out.append((key, value))
    return out


@dataclass(frozen=True)
class RetentionPolicy:
    """How long each tenant's (and type's) rows are kept.

    Rules: ``*`` (every tenant), ``tenant``, ``tenant/Type``; the most
    specific one that matches wins (tenant/Type, then tenant, then ``*``).
    No matching rule, or ``forever``: kept forever."""

    rules: tuple[tuple[str, Keep], ...] = ()
    _by_key: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_key", dict(self.rules))

    @classmethod
    def parse(cls, text: str | None, setting: str = "TSDB_RETENTION") -> RetentionPolicy:
        text = (text or "").strip()
        if not text:
            return cls()
        rules: dict[str, Keep] = {}
        for raw_key, value in _entries(text, setting):
            key = _rule_key(raw_key, setting)
            if key in rules:
                raise ValueError(f"{setting}: the rule {key!r} is given twice")
            rules[key] = parse_duration(value, setting, key)
        return cls(tuple(rules.items()))

    @property
    def active(self) -> bool:
        """Whether any rule deletes anything."""
        return any(keep is not None for _, keep in self.rules)

    def rule_for(self, tenant: str, entity_type: str) -> tuple[str, Keep] | None:
        rules = self._by_key
        for key in (f"{tenant}/{entity_type}", tenant, "*"):
            if key in rules:
                return key, rules[key]
        return None

    def describe(self) -> str:
        return ",".join(f"{k}={_fmt(v)}" for k, v in self.rules) or "(keep everything)"


def _fmt(keep: Keep) -> str:
    if keep is None:
        return FOREVER
    seconds = int(keep.total_seconds())
    for unit in "ydhms":
        if seconds % _UNIT_SECONDS[unit] == 0:
            return f"{seconds // _UNIT_SECONDS[unit]}{unit}"
    return f"{seconds}s"  # pragma: no cover - "s" always divides
