"""TSDB_RETENTION (and the deprecated TSDB_ROLLUP_RETENTION): the rule
syntax with its levels, which rule decides each level of a series, the
order levels must keep, and a clear error for every malformed setting. No
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
    monkeypatch.setenv("TSDB_RETENTION_BATCH_ROWS", "1000")
    config = RetentionConfig.from_settings(Settings())
    assert config.batch_rows == 1000 and config.active
    assert config.policy.rule_for("acme", "T") == ("acme", 30 * DAY)
    assert config.policy.resolve("acme", "T")["hour"] == (None, None)  # rollups: forever


def test_levels_per_rule_most_specific_first():
    policy = RetentionPolicy.parse("*=raw:365d,hour:5y, acme=30d, acme/Robot=raw:7d,minute:90d,hour:forever")
    assert policy.resolve("acme", "Robot") == {
        "raw": ("acme/Robot", 7 * DAY),
        "minute": ("acme/Robot", 90 * DAY),
        "hour": ("acme/Robot", None),
    }
    # acme names raw only: its rollups follow '*'; minute, named nowhere, follows hour.
    assert policy.resolve("acme", "Room") == {
        "raw": ("acme", 30 * DAY),
        "minute": ("*", 5 * 365 * DAY),
        "hour": ("*", 5 * 365 * DAY),
    }
    assert policy.resolve("beta", "X")["raw"] == ("*", 365 * DAY)
    assert policy.describe() == "*=raw:1y,hour:5y,acme=30d,acme/Robot=raw:7d,minute:90d,hour:forever"
    as_json = RetentionPolicy.parse(
        '{"*": {"raw": "365d", "hour": "5y"}, "acme": "30d", "acme/Robot": "raw:7d,minute:90d,hour:forever"}'
    )
    assert as_json == policy


def test_a_rule_may_name_rollup_levels_only():
    policy = RetentionPolicy.parse("*=raw:7d, acme=minute:30d,hour:1y")
    assert policy.rule_for("acme", "T") == ("*", 7 * DAY)  # raw follows '*'
    assert policy.resolve("acme", "T")["minute"] == ("acme", 30 * DAY)


@pytest.mark.parametrize(
    ("spec", "fragment"),
    [
        ("acme=raw:30d,minute:7d", "minute (7d) would be kept less long than raw (30d)"),
        ("acme=hour:30d", "minute (30d) would be kept less long than raw (forever)"),
        ("*=raw:1d,minute:30d,hour:7d", "hour (7d) would be kept less long than minute (30d)"),
        ("*=raw:1d,hour:7d, acme=raw:30d", "'acme': minute (7d) would be kept less long than raw (30d)"),
        ("acme=raw:1d,raw:2d", "the rule 'acme' is given twice"),
        ("acme=raw:1d,minute:2d,minute:3d", "the minute level of the rule 'acme' is given twice"),
        ("minute:1d", "is not rule=duration"),
        ("acme=second:1d", "a duration is a whole number"),
        ('{"acme": {"second": "1d"}}', "unknown level 'second'"),
    ],
)
def test_levels_out_of_order_or_malformed_are_refused(spec, fragment):
    with pytest.raises(ValueError, match="TSDB_RETENTION") as info:
        RetentionPolicy.parse(spec)
    assert fragment in str(info.value)


def test_deprecated_rollup_settings_are_mapped_with_a_warning(monkeypatch, caplog):
    monkeypatch.setenv("TSDB_RETENTION", "*=365d,acme=30d")
    monkeypatch.setenv("TSDB_ROLLUPS", "true")
    monkeypatch.setenv("TSDB_ROLLUP_RETENTION", "*=5y")
    with caplog.at_level("WARNING"):
        config = RetentionConfig.from_settings(Settings())
    assert config.policy.resolve("acme", "T") == {
        "raw": ("acme", 30 * DAY),
        "minute": ("*", 5 * 365 * DAY),
        "hour": ("*", 5 * 365 * DAY),
    }
    said = caplog.text
    assert "TSDB_ROLLUPS is deprecated and has no effect" in said
    assert "TSDB_ROLLUP_RETENTION is deprecated" in said and "TSDB_RETENTION=*=raw:1y,minute:5y,hour:5y" in said


def test_deprecated_rollup_retention_never_drops_a_level_before_raw():
    """It held only what raw retention had deleted: shorter than raw, it
    kept nothing raw did not, so the levels follow raw there."""
    policy = Settings(retention="acme=365d,acme/Robot=400d", rollup_retention="acme=30d").retention_policy()
    assert policy.resolve("acme", "T")["hour"] == ("acme", 365 * DAY)
    assert policy.resolve("acme", "Robot")["minute"] == ("acme/Robot", 400 * DAY)
    alone = Settings(rollup_retention="*=365d").retention_policy()  # raw forever: nothing was ever rolled up
    assert not alone.active
    with pytest.raises(ValidationError, match="also given in TSDB_RETENTION"):
        Settings(retention="acme=raw:30d,hour:1y", rollup_retention="acme=2y")
