"""Topics: which tenant and service path a topic names, and what to subscribe to.

Orion's MQTT notifications carry no headers, so a subscription says its
tenant and service path in its topic, with ``mqttCustom``'s macros:
``"topic": "tsdb/${service}${servicePath}"`` publishes a notification of
tenant ``acme``, service path ``/floor1`` on ``tsdb/acme/floor1`` (and the
default tenant's, path ``/``, on ``tsdb//``). A ``TopicTemplate`` is that
topic read backwards: ``${service}`` is one topic level (empty: the message
names no tenant), ``${servicePath}`` the levels from its ``/`` on (as few
as the rest of the template lets it take; none: ``/``), and any other
``${...}`` (Orion has ``${id}``, ``${type}``, attribute names) one level,
matched and ignored. Without macros a template is a fixed topic.

The filter a template implies is its literal levels up to the first macro,
then ``#``: ``tsdb/${service}${servicePath}`` subscribes to ``tsdb/#``.

**Tenants by topic** (``TSDB_MQTT_TENANTS``). A subscriber never learns who
published a message (MQTT carries no publisher identity to it), so the
tenants a message may write are decided by its topic, whose publishers the
broker's ACLs restrict: ``tsdb/alpha/#=alpha; tsdb/shared/#=beta,gamma``.
A message may write the tenants of every rule whose filter matches its
topic (MQTT's ``+`` and ``#``), none when no rule does; without rules, any
tenant (the broker's ACLs are then the only restriction).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from tsdb_service.parse.request_context import is_stored_tenant

SERVICE = "service"
SERVICE_PATH = "servicePath"
_MACRO = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}")
MAX_TOPIC_BYTES = 65535  # MQTT's UTF-8 string limit


@dataclass(frozen=True, slots=True)
class Route:
    """What a topic says: the tenant (``""``: the topic names none) and the
    service path (None: it names none)."""

    service: str
    service_path: str | None


@dataclass(frozen=True, slots=True)
class TopicTemplate:
    text: str
    pattern: re.Pattern[str]
    filter: str

    @classmethod
    def parse(cls, text: str) -> TopicTemplate:
        """A template, or ValueError saying what is wrong with it."""
        if not text:
            raise ValueError("a topic template is empty")
        if "+" in text or "#" in text or "\0" in text:
            raise ValueError(f"topic template {text[:80]!r}: no wildcards (+, #) in a template, only ${{...}} macros")
        if len(text.encode()) > MAX_TOPIC_BYTES:
            raise ValueError(f"topic template {text[:80]!r}...: longer than an MQTT topic may be")
        regex, seen, last = [], set(), 0
        for macro in _MACRO.finditer(text):
            literal = text[last : macro.start()]
            if "$" in literal:
                raise ValueError(f"topic template {text[:80]!r}: a '$' must open a macro such as ${{service}}")
            regex.append(re.escape(literal))
            name = macro[1]
            if name in (SERVICE, SERVICE_PATH):
                if name in seen:
                    raise ValueError(f"topic template {text[:80]!r}: ${{{name}}} appears twice")
                seen.add(name)
            if name == SERVICE:
                regex.append(r"(?P<service>[^/]*)")
            elif name == SERVICE_PATH:
                regex.append(r"(?P<path>(?:/.*?)?)")
            else:
                regex.append(r"[^/]*")
            last = macro.end()
        if "$" in text[last:]:
            raise ValueError(f"topic template {text[:80]!r}: a '$' must open a macro such as ${{service}}")
        regex.append(re.escape(text[last:]))
        first = _MACRO.search(text)
        if first is None:
            topic_filter = text
        else:
            prefix = text[: first.start()]
            topic_filter = prefix[: prefix.rfind("/") + 1] + "#"
        return cls(text, re.compile("".join(regex) + r"\Z", re.DOTALL), topic_filter)

    def match(self, topic: str) -> Route | None:
        found = self.pattern.match(topic)
        if found is None:
            return None
        groups = found.groupdict()
        path = groups.get("path")
        return Route(groups.get("service") or "", None if path is None else path or "/")


def parse_templates(spec: str) -> tuple[TopicTemplate, ...]:
    """A comma list of templates (``TSDB_MQTT_TOPIC_TEMPLATE``), blanks skipped."""
    return tuple(TopicTemplate.parse(item.strip()) for item in spec.split(",") if item.strip())


def route(templates: tuple[TopicTemplate, ...], topic: str) -> Route | None:
    """The first template's reading of ``topic``; None when none matches."""
    for template in templates:
        found = template.match(topic)
        if found is not None:
            return found
    return None


def check_filter(topic_filter: str) -> str:
    """An MQTT topic filter (``#`` last and alone in its level, ``+`` alone
    in its level), or ValueError."""
    if not topic_filter or "\0" in topic_filter or len(topic_filter.encode()) > MAX_TOPIC_BYTES:
        raise ValueError(f"topic filter {topic_filter[:80]!r} is empty, too long or holds a NUL")
    if topic_filter.startswith("$share/"):
        raise ValueError(f"topic filter {topic_filter[:80]!r}: give the group as --mqtt-share-group instead")
    levels = topic_filter.split("/")
    for i, level in enumerate(levels):
        if "#" in level and (level != "#" or i != len(levels) - 1):
            raise ValueError(f"topic filter {topic_filter[:80]!r}: '#' must be a whole level, and the last")
        if "+" in level and level != "+":
            raise ValueError(f"topic filter {topic_filter[:80]!r}: '+' must be a whole level")
    return topic_filter


def filter_matches(topic_filter: str, topic: str) -> bool:
    """Does ``topic`` match the MQTT filter (``+`` one level, ``#`` the rest,
    its parent level included)? Wildcards never match a ``$`` topic's first level."""
    if topic.startswith("$") and topic_filter[:1] in ("+", "#"):
        return False
    levels, wanted = topic.split("/"), topic_filter.split("/")
    for i, want in enumerate(wanted):
        if want == "#":
            return True
        if i >= len(levels) or (want != "+" and want != levels[i]):
            return False
    return len(levels) == len(wanted)


DEFAULT_TENANT_TOKEN = "-"  # the default tenant in a list, as in TSDB_API_KEYS


@dataclass(frozen=True, slots=True)
class TenantRule:
    """Messages on topics matching ``filter`` may write ``tenants`` (as stored: lower case, ``""`` the default)."""

    filter: str
    tenants: frozenset[str]


def parse_tenant_rules(spec: str) -> tuple[TenantRule, ...]:
    """``FILTER=TENANT[,TENANT...]`` entries separated by ``;``
    (``TSDB_MQTT_TENANTS``), or ValueError saying which entry is wrong."""
    rules = []
    for entry in spec.split(";"):
        if not entry.strip():
            continue
        topic_filter, sep, names = entry.strip().rpartition("=")
        if not sep or not topic_filter.strip():
            raise ValueError(f"entry {entry.strip()[:80]!r} is not FILTER=TENANT[,TENANT...]")
        topic_filter = check_filter(topic_filter.strip())
        tenants = set()
        for name in names.split(","):
            tenant = name.strip().lower()
            tenant = "" if tenant == DEFAULT_TENANT_TOKEN else tenant
            if not name.strip() or not is_stored_tenant(tenant):
                raise ValueError(
                    f"entry {entry.strip()[:80]!r}: {name.strip()[:60]!r} is not a tenant (1 to 50 letters, "
                    "digits or underscores, or '-' for the default tenant)"
                )
            tenants.add(tenant)
        rules.append(TenantRule(topic_filter, frozenset(tenants)))
    return tuple(rules)


def topic_tenants(rules: tuple[TenantRule, ...], topic: str) -> frozenset[str]:
    """The tenants a message on ``topic`` may write under ``rules`` (non-empty)."""
    out: set[str] = set()
    for rule in rules:
        if filter_matches(rule.filter, topic):
            out |= rule.tenants
    return frozenset(out)
