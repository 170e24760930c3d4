"""The export route's part of the OpenAPI description."""

from __future__ import annotations

from tsdb_service.http.openapi import FROM_DATE, ID, ID_PATTERN, READ_ERRORS, TENANCY, TO_DATE, TYPE, query, spec

EXPORT = [
    *TENANCY,
    ID,
    TYPE,
    ID_PATTERN,
    FROM_DATE,
    TO_DATE,
    query("attrs", "Attribute names (not value paths), comma-separated."),
    query("format", "File format (mcap: for Foxglove).", {"enum": ["csv", "parquet", "mcap"], "default": "csv"}),
    query(
        "raw",
        "CSV: write text cells as stored. By default a cell starting with =, +, -, @, tab or CR gets a "
        "leading ' so a spreadsheet does not run it as a formula (OWASP CSV injection).",
        {"type": "boolean", "default": False},
    ),
    query(
        "bucket",
        "A width (10s, 5min, 1h, 1d; ms, s, min, h, d): one row per series and time bucket (from the epoch, UTC) "
        "with n, avg, min, max, first, last of its numbers instead of one row per sample.",
        {"type": "string", "pattern": "^[1-9][0-9]{0,9}(ms|s|min|m|h|d)$"},
    ),
]


EXPORT_SPEC = spec(
    *EXPORT,
    ok_={
        200: {
            "description": "One row per sample, streamed",
            "content": {
                "text/csv": {"schema": {"type": "string"}},
                "application/vnd.apache.parquet": {"schema": {"type": "string", "format": "binary"}},
                "application/x-mcap": {"schema": {"type": "string", "format": "binary"}},
            },
        }
    },
    errors_=READ_ERRORS,
)
