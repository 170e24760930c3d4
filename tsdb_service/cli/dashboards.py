"""CLI: ``tsdb-service dashboards build [--out dashboards/]``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(subparsers, command) -> None:
    p = subparsers.add_parser("dashboards", help="the Grafana dashboards of the three use cases")
    actions = p.add_subparsers(dest="dashboards_action", required=True)
    build = actions.add_parser(
        "build",
        help="regenerate dashboards/*.json and the provisioning YAML from the code",
        description="Write <use case>.json for each use case, provisioning/dashboards.yaml and "
        "provisioning/datasources.yaml into --out.",
    )
    build.add_argument("--out", default="dashboards", help="folder (default ./dashboards)")
    build.add_argument("--check", action="store_true", help="write nothing; exit 1 if any file differs")
    command("dashboards")(cmd_dashboards)


def cmd_dashboards(args: argparse.Namespace) -> int:
    from tsdb_service.faces.grafana.dashboards import files, write

    out = Path(args.out)
    if args.check:
        stale = [
            rel for rel, content in files().items() if not (out / rel).exists() or (out / rel).read_text() != content
        ]
        for rel in stale:
            print(f"stale: {out / rel}", file=sys.stderr)
        return 1 if stale else 0
    for path in write(out):
        print(f"wrote {path}")
    return 0
