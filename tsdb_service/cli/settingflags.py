"""A setting's flag as ``serve --help`` and every command that takes one say it:
its help line (what, default, ``TSDB_*`` variable) and its value's placeholder.

Kept apart from ``cli.main`` so that a command module (``cli.rollups``) can
word its ``--db`` as ``serve`` does without importing the entry point that
registers it.
"""

from __future__ import annotations

from tsdb_service.core.config import MIB, Settings


def setting_help(name: str) -> str:
    """A flag's help from its setting: what it does, its default and its variable."""
    what = (Settings.model_fields[name].description or "").rstrip(".")
    default = setting_default(name)
    if default is None:  # the description says what applies when unset
        return f"{what} (env TSDB_{name.upper()})"
    if default == "":
        return f"{what} (not set by default; env TSDB_{name.upper()})"
    return f"{what} (default {default}; env TSDB_{name.upper()})"


def setting_default(name: str) -> str | None:
    """A setting's default as ``serve --help`` and the docs' settings table
    say it: ``8668``, ``true``, ``9437184 = 9 MiB``; ``""`` when it is unset
    by default, None when its description says what applies."""
    default = Settings.model_fields[name].default
    if default is None or isinstance(default, str):
        return default
    if isinstance(default, bool):
        return str(default).lower()
    if "_bytes" in name and default >= 1024 and default % 1024 == 0:
        unit, size = ("MiB", default // MIB) if default % MIB == 0 else ("KiB", default // 1024)
        return f"{default} = {size} {unit}"
    return str(default)


# The placeholder of a text setting's flag, where its name does not say it.
_TEXT_METAVARS = {
    "host": "ADDRESS",
    "api_keys": "KEY:SCOPES[:TENANTS]",
    "api_keys_file": "FILE",
    "api_key_header": "HEADER",
    "jwt_jwks_url": "URL",
    "jwt_key": "PEM|SECRET",
    "jwt_algorithms": "ALGORITHMS",
    "jwt_audience": "AUDIENCE",
    "jwt_issuer": "ISSUER",
    "jwt_scopes_claims": "CLAIMS",
    "jwt_scope_prefix": "PREFIX",
    "jwt_tenants_claim": "CLAIM",
    "ngsild_contexts": "URL=PATH;...",
    "cors_origins": "ORIGINS",
    "retention": "RULES",
    "time_index_paths": "RULES",
    "rollup_retention": "RULES",
    "mqtt_url": "URL",
    "mqtt_topics": "FILTERS",
    "mqtt_topic_template": "TEMPLATES",
    "mqtt_default_tenant": "NAME",
    "mqtt_client_id": "ID",
    "mqtt_username": "USER",
    "mqtt_password": "PASSWORD",
    "mqtt_ca_file": "FILE",
    "mqtt_cert_file": "FILE",
    "mqtt_key_file": "FILE",
    "mqtt_share_group": "GROUP",
    "backup_dir": "DIR",
}


_SECONDS = ("_s", "_seconds", "_timeout", "_interval", "_pause")


def setting_metavar(name: str) -> str:
    """What a flag's value is: ``BYTES``, ``SECONDS``, ``DAYS``, ``N`` (a
    count), ``NUMBER``, ``PORT``, or what a text setting holds."""
    annotation = Settings.model_fields[name].annotation
    if name in _TEXT_METAVARS:
        return _TEXT_METAVARS[name]
    if name == "port":
        return "PORT"
    if "_bytes" in name:
        return "BYTES"
    if name.endswith(_SECONDS):
        return "SECONDS"
    if name.endswith("_days"):
        return "DAYS"
    if annotation in (int, int | None):
        return "N"
    if annotation in (float, float | None):
        return "NUMBER"
    return "TEXT"
