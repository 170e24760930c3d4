"""TSDB_RETENTION / TSDB_ROLLUP_RETENTION: the rule syntax, which rule a
series falls under, and a clear error for every malformed setting. No
database is involved."""

from __future__ import annotations

from datetime import timedelta

import pytest
from pydantic import ValidationError

from tsdb_service.core.config import Settings
from tsdb_service.core.retention_policy import RetentionPolicy
from tsdb_service.storage.retention import RetentionConfig

DAY = timedelta(days=1)


def test_compact_form_and_precedence():
    policy = RetentionPolicy.parse("*=365d, acme=30d, acme/Robot=7d, =12h, /Room=90m, vip=forever")
    assert policy.rule_for("acme", "Robot") == ("acme/Robot", 7 * DAY)
    assert policy.rule_for("acme", "Room") == ("acme", 30 * DAY)
    assert policy.rule_for("beta", "Robot") == ("*", 365 * DAY)
    assert policy.rule_for("", "Room") == ("/Room", timedelta(minutes=90))
    assert policy.rule_for("", "Robot") == ("", timedelta(hours=12))
    assert policy.rule_for("vip", "Robot") == ("vip", None)  # forever shadows '*'
    assert policy.active


def test_json_form_is_the_same_policy():
    compact = RetentionPolicy.parse("*=365d,acme=30d,acme/Robot=7d,vip=forever")
    as_json = RetentionPolicy.parse('{"*": "365d", "acme": "30d", "acme/Robot": "7d", "vip": null}')
    assert compact == as_json
    assert as_json.describe() == "*=1y,acme=30d,acme/Robot=7d,vip=forever"


def test_tenants_are_lower_cased_types_kept():
    policy = RetentionPolicy.parse("ACME/Robot=2w,Beta=1y")
    assert policy.rule_for("acme", "Robot") == ("acme/Robot", 14 * DAY)
    assert policy.rule_for("acme", "robot") is None
    assert policy.rule_for("beta", "X") == ("beta", 365 * DAY)


def test_types_may_contain_slashes_and_equals():
    policy = RetentionPolicy.parse("acme/nav_msgs/msg/Odometry=1d")
    assert policy.rule_for("acme", "nav_msgs/msg/Odometry") == ("acme/nav_msgs/msg/Odometry", DAY)
    assert RetentionPolicy.parse('{"acme/https://x.org/T?a=b": "1d"}').rule_for("acme", "https://x.org/T?a=b")


def test_empty_or_only_forever_deletes_nothing():
    assert not RetentionPolicy.parse("").active
    assert not RetentionPolicy.parse(None).active
    assert not RetentionPolicy.parse("*=forever").active
    assert RetentionPolicy.parse("").rule_for("acme", "Robot") is None


@pytest.mark.parametrize(
    ("spec", "fragment"),
    [
        ("acme=30x", "a duration is a whole number followed by s, m, h, d, w or y"),
        ("acme=", "a duration is a whole number"),
        ("acme=0d", "must be positive"),
        ("acme=-1d", "a duration is a whole number"),
        ("acme=1.5d", "a duration is a whole number"),
        ("acme", "is not rule=duration"),
        ("acme=1d,,beta=2d", "is not rule=duration"),
        ("acme=1d,acme=2d", "given twice"),
        ("ACME=1d,acme=2d", "given twice"),
        ("acme corp=1d", "a tenant is up to 50 letters, digits or '_'"),
        ("*/Robot=1d", "a type rule needs its tenant"),
        ("acme/=1d", "the entity type after '/' is missing"),
        ("{not json", "not a valid JSON object"),
        ('["acme"]', "is not rule=duration"),
        ('{"acme": 30}', "the duration must be a string"),
    ],
)
def test_bad_specs_are_refused_clearly(spec, fragment):
    with pytest.raises(ValueError, match="TSDB_RETENTION") as info:
        RetentionPolicy.parse(spec)
    assert fragment in str(info.value)


def test_settings_validate_both_specs():
    with pytest.raises(ValidationError) as info:
        Settings(retention="acme=30 days")
    assert "TSDB_RETENTION: acme='30 days'" in str(info.value)
    with pytest.raises(ValidationError) as info:
        Settings(rollup_retention="acme=soon")
    assert "TSDB_ROLLUP_RETENTION" in str(info.value)
    with pytest.raises(ValidationError):
        Settings(retention_batch_rows=0)
    with pytest.raises(ValidationError):
        Settings(retention_interval=0)


def test_settings_from_the_environment(monkeypatch):
    monkeypatch.setenv("TSDB_RETENTION", "*=365d,acme=30d")
    monkeypatch.setenv("TSDB_ROLLUPS", "true")
    monkeypatch.setenv("TSDB_ROLLUP_RETENTION", "*=5y")
    monkeypatch.setenv("TSDB_RETENTION_BATCH_ROWS", "1000")
    config = RetentionConfig.from_settings(Settings())
    assert config.rollups and config.batch_rows == 1000 and config.active
    assert config.samples.rule_for("acme", "T") == ("acme", 30 * DAY)
    assert config.rollup_policy.rule_for("acme", "T") == ("*", 5 * 365 * DAY)
