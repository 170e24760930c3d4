"""The ETSI NGSI-LD conformance suite's temporal cases, run against the
service as deployed (issues 28 and 40).

The suite is vendored (``tests/vendor/ngsi-ld-conformance``, BSD-3-Clause,
its README names the upstream commit) and runs offline: it serves every
@context from its own server on 127.0.0.1 (``tests.support.etsi_suite``).
This test starts ``tsdb-service serve`` on a fresh DuckDB database on a
free port, lets it fetch @contexts from 127.0.0.1 (``TSDB_LD_CONTEXT_ALLOW``),
runs the main set less the cases the suite's maintainers call defective or
disputed (146 cases) and fails below the floor, naming every case that
failed and why. Its figure (``etsi temporal: N/146``) is printed at the end
of pytest's output (``conftest.pytest_terminal_summary``) and kept in
docs/ngsi-ld.md. The per-kind tests on both backends are in
``test_ngsild_conformance_kinds``.

About 40 s on the 2-core machine.
"""

from __future__ import annotations

from tests.support import etsi_suite
from tests.support.server import ServerProcess

TOTAL_SECONDS = 240


def test_the_etsi_temporal_suite_passes_above_the_floor(tmp_path, record_property):
    with ServerProcess(tmp_path / "db.duckdb", extra_env={"TSDB_LD_CONTEXT_ALLOW": "http://127.0.0.1:"}) as server:
        result = etsi_suite.run(server.url, tmp_path / "etsi", total_timeout=TOTAL_SECONDS)
    record_property("etsi", f"{result.line} in {result.seconds:.0f} s")
    print(result.line)
    assert result.total == etsi_suite.CASES, (
        f"the harness selected {result.total} cases, not {etsi_suite.CASES}: has the suite or its id lists "
        f"changed? {result.line}\n" + "\n".join(result.failures)
    )
    assert result.passed >= etsi_suite.FLOOR, (
        f"{result.line}: below the floor of {etsi_suite.FLOOR}/{etsi_suite.CASES}; results in {result.out}\n"
        + "\n".join(result.failures)
    )
