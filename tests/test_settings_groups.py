"""Settings are declared in groups (``core.config``), and the groups are the
one source of ``Settings``, of ``serve --help``'s headings and of the docs'
settings table (docs/settings.md); grouping renamed nothing: every flag and
``TSDB_*`` variable that existed before it still sets its setting.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.support.cli import run_cli
from tsdb_service.cli.main import _settings, build_parser
from tsdb_service.cli.settingflags import setting_default
from tsdb_service.core.config import SETTING_GROUPS, Settings, load_settings, setting_groups

SETTINGS_PAGE = Path(__file__).resolve().parent.parent / "docs" / "settings.md"

# `serve`'s flags before the settings were grouped (issue 36), in their order then.
FLAGS_BEFORE_GROUPS = [
    "--db",
    "--host",
    "--port",
    "--workers",
    "--max-body-bytes",
    "--max-request-body-bytes",
    "--rejected-body-max-bytes",
    "--default-limit",
    "--compact-rows",
    "--major-compact-runs",
    "--writer-threads",
    "--tail-cache-series",
    "--tail-cache-rows",
    "--tail-cache-samples",
    "--agg-partials-hours",
    "--wal-checkpoint-bytes",
    "--ingest-log",
    "--no-ingest-log",
    "--ingest-log-lag-bytes",
    "--read-max-series",
    "--read-max-rows",
    "--read-max-response-bytes",
    "--read-max-seconds",
    "--rejected-max-per-tenant",
    "--rejected-max-bytes-per-tenant",
    "--rejected-max-total",
    "--rejected-max-total-bytes",
    "--rejected-max-age-days",
    "--rejected-page-max-bytes",
    "--header-timeout-s",
    "--body-timeout-s",
    "--max-connections",
    "--keep-alive-s",
    "--max-header-bytes",
    "--log-level",
    "--access-log",
    "--api-keys",
    "--api-keys-file",
    "--api-key-header",
    "--jwt-jwks-url",
    "--jwt-key",
    "--jwt-algorithms",
    "--jwt-audience",
    "--jwt-issuer",
    "--jwt-scopes-claims",
    "--jwt-scope-prefix",
    "--jwt-tenants-claim",
    "--jwt-jwks-cache-seconds",
    "--ngsild-default-limit",
    "--ngsild-max-limit",
    "--ngsild-max-instances",
    "--ngsild-contexts",
    "--ngsild-context-timeout",
    "--ld-context-allow",
    "--subscribe-broker-allow",
    "--ld-context-offline",
    "--ld-context-max-bytes",
    "--ld-context-cache-bytes",
    "--ld-inline-context-max-bytes",
    "--cors-origins",
    "--cors-allow-unauthenticated",
    "--retention",
    "--rollups",
    "--rollup-retention",
    "--retention-interval",
    "--retention-batch-rows",
    "--retention-pause",
    "--mqtt-url",
    "--mqtt-topics",
    "--mqtt-topic-template",
    "--mqtt-default-tenant",
    "--mqtt-client-id",
    "--mqtt-username",
    "--mqtt-password",
    "--mqtt-ca-file",
    "--mqtt-cert-file",
    "--mqtt-key-file",
    "--mqtt-qos",
    "--mqtt-share-group",
    "--mqtt-session-expiry-s",
    "--mqtt-inflight",
    "--mqtt-reconnect-max-s",
]
SETTINGS_BEFORE_GROUPS = [f[2:].replace("-", "_") for f in FLAGS_BEFORE_GROUPS if f != "--no-ingest-log"]

# A valid value other than the default for each setting whose text is checked.
TEXT_SAMPLES = {
    "db": "/tmp/elsewhere.duckdb",
    "host": "127.0.0.1",
    "log_level": "debug",
    "ld_context_allow": "http://127.0.0.1:9000/",
    "subscribe_broker_allow": "http://orion:1026/",
    "retention": "*=30d",
    "time_index_paths": "odom=header.stamp",
    "rollup_retention": "*=365d",
    "mqtt_url": "mqtt://broker:1883",
    "mqtt_default_tenant": "acme",
    "mqtt_client_id": "replica-1",
    "mqtt_share_group": "tsdb",
}


def sample(name: str) -> object:
    """A valid value other than ``name``'s default."""
    field = Settings.model_fields[name]
    default = field.default
    if isinstance(default, bool):
        return not default
    if name in TEXT_SAMPLES:
        return TEXT_SAMPLES[name]
    if isinstance(default, str):
        return default + "x" if default else "sample"
    if default is None:
        return 2
    bound = next((m.le for m in field.metadata if getattr(m, "le", None) is not None), None)
    return type(default)(default - 1 if bound is not None and default + 1 > bound else default + 1)


def test_every_setting_is_in_exactly_one_group():
    grouped = [name for _, names in setting_groups() for name in names]
    assert sorted(grouped) == sorted(Settings.model_fields)
    assert len(grouped) == len(set(grouped))
    assert [group.title for group in SETTING_GROUPS] == [
        "Storage",
        "HTTP server",
        "Ingest",
        "Ingest log",
        "Caches",
        "Reads and budgets",
        "Rejected store",
        "Security",
        "NGSI-LD",
        "MQTT",
        "Retention and rollups",
        "Logging",
    ]


def test_no_setting_was_renamed_or_lost():
    """Settings come and stay: every one of the snapshot is still there,
    under its name and flag (new ones may join)."""
    assert set(SETTINGS_BEFORE_GROUPS) <= set(Settings.model_fields)
    serve = dict(_subcommands())["serve"]
    flags = [flag for action in serve._actions for flag in action.option_strings if flag not in ("-h", "--help")]
    assert set(FLAGS_BEFORE_GROUPS) <= set(flags)


def _subcommands():
    import argparse

    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices.items()


@pytest.mark.parametrize("name", SETTINGS_BEFORE_GROUPS)
def test_each_flag_still_sets_its_setting(name):
    value = sample(name)
    flag = "--" + name.replace("_", "-")
    argv = [flag, str(value)]
    if isinstance(value, bool):  # --access-log, or --no-ingest-log for one on by default
        argv = [flag] if value else [f"--no-{flag[2:]}"]
    settings = _settings(build_parser().parse_args(["serve", *argv]))
    assert getattr(settings, name) == value


@pytest.mark.parametrize("name", SETTINGS_BEFORE_GROUPS)
def test_each_variable_still_sets_its_setting(name, monkeypatch):
    value = sample(name)
    monkeypatch.setenv(f"TSDB_{name.upper()}", str(value).lower() if isinstance(value, bool) else str(value))
    assert getattr(load_settings(), name) == value


def test_serve_help_shows_each_group_with_its_flags():
    """The real command's help: each group's heading, then its flags, in order."""
    done = run_cli("serve", "--help")
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[0] == "usage: tsdb-service serve [options]"
    sections = _help_sections(done.stdout)
    for group, names in setting_groups():
        assert group.title in sections, group.title
        flags = re.findall(r"^  (--[a-z0-9-]+)", sections[group.title], re.M)
        assert flags == ["--" + n.replace("_", "-") for n in names], group.title


def _help_sections(text: str) -> dict[str, str]:
    sections: dict[str, str] = {}
    title = None
    for line in text.splitlines():
        if line and not line.startswith(" ") and line.endswith(":"):
            title = line[:-1]
            sections[title] = ""
        elif title is not None:
            sections[title] += line + "\n"
    return sections


def _page_tables() -> list[tuple[str, list[list[str]]]]:
    """docs/settings.md: each ``## heading`` with its table's rows (cells, backticks removed)."""
    tables: list[tuple[str, list[list[str]]]] = []
    for line in SETTINGS_PAGE.read_text().splitlines():
        if line.startswith("## "):
            tables.append((line[3:], []))
        elif line.startswith("| `") and tables:
            cells = [cell.strip() for cell in re.split(r"(?<!\\)\|", line)[1:-1]]
            tables[-1][1].append([cell.replace("`", "") for cell in cells])
    return tables


def test_the_docs_settings_table_matches_the_groups():
    tables = _page_tables()
    assert [title for title, _ in tables] == [group.title for group in SETTING_GROUPS]
    for (title, rows), (_, names) in zip(tables, setting_groups(), strict=True):
        assert [row[1] for row in rows] == [f"TSDB_{n.upper()}" for n in names], title
        for row, name in zip(rows, names, strict=True):
            flag = "--" + name.replace("_", "-")
            assert row[0].split(" / ")[0] == flag, row
            default = setting_default(name)
            expected = "see what it does" if default is None else ("not set" if default == "" else default)
            assert row[2] == expected, row
