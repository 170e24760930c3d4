"""``tsdb-service register --broker URL --type TYPE``: become the broker's temporal context source.

The command around ``broker.registrations.ensure_registration``: it
registers this service with an NGSI-LD broker as an auxiliary context
source of the temporal retrieve and query for the given entity types, once
(a second run finds the first registration and creates nothing, like
``subscribe``). A broker that forwards temporal queries to its registered
sources then answers its clients' ``/ngsi-ld/v1/temporal/...`` requests
with our history (docs/ngsi-ld.md, "Temporal context source"). A refusal is
one ``error:`` line and exit status 2; a broker that refused or could not
be reached, status 1.
"""

from __future__ import annotations

import argparse
import sys

DEFAULT_PORT = 8668


def register(subparsers, command) -> None:
    p = subparsers.add_parser(
        "register",
        help="register this service with an NGSI-LD broker as the context source of its temporal queries, once",
        description="Create an NGSI-LD context source registration (mode auxiliary, operations retrieveTemporal "
        "and queryTemporal) on the broker, for the entity types given, pointing at this service. A broker that "
        "forwards temporal queries to registered sources then serves its clients' temporal requests from our "
        "history. Running it again creates nothing when the broker already has the same registration.",
    )
    p.add_argument("--broker", required=True, metavar="URL", help="the broker's base URL, e.g. http://orion-ld:1026")
    p.add_argument(
        "--type",
        dest="types",
        action="append",
        required=True,
        metavar="TYPE",
        help="an entity type whose history the broker should ask us for (a term of --context, or an IRI); "
        "repeat, or give a comma list",
    )
    p.add_argument(
        "--endpoint",
        metavar="URL",
        help="this service's base URL as the broker reaches it; the broker appends /ngsi-ld/v1/temporal/... "
        "(default: port 8668 of this machine, at the address the broker reaches it by; printed)",
    )
    p.add_argument("--tenant", metavar="TENANT", help="the NGSI-LD tenant to register in (default: the default one)")
    p.add_argument(
        "--context",
        metavar="URL",
        help="the JSON-LD @context the type names are terms of, sent as the Link header (default: the core context)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="register even if the broker has the same registration already (default: keep that one)",
    )
    command("register")(cmd_register)


def cmd_register(args: argparse.Namespace) -> int:
    from tsdb_service.broker.registrations import Registration, check_types, ensure_registration
    from tsdb_service.broker.subscriptions import default_notify_url

    try:
        types = check_types(args.types)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    endpoint = args.endpoint or default_notify_url(args.broker, DEFAULT_PORT, path="")
    given = "" if args.endpoint else " (this machine as the broker reaches it; --endpoint to choose)"
    print(f"endpoint: {endpoint}{given}")
    wanted = Registration(endpoint.rstrip("/"), types, args.tenant or None, args.context or None)
    ok, answer = ensure_registration(args.broker, wanted, force=args.force)
    print(answer)
    return 0 if ok else 1
