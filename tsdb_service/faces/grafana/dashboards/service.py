"""tsdb-service itself: ingest, commits, queries and storage, from its Prometheus
``/metrics`` (see ``tsdb_service.telemetry``), for the operator rather than the use cases.

Counters, histograms and the queue sum over replicas scraped separately; the
store sizes describe the one shared database, so they take the ``max``.
"""

from __future__ import annotations

from dataclasses import dataclass

from grafana_foundation_sdk.builders import common as cb
from grafana_foundation_sdk.builders import prometheus
from grafana_foundation_sdk.builders import stat as gstat
from grafana_foundation_sdk.models import common

from tsdb_service.faces.grafana.dashboards import kit

UID = "tsdb-service"
PROMETHEUS = "prometheus"
PROMETHEUS_URL = "http://prometheus:9090"  # the Prometheus service's name in a compose file
RATE = "[$__rate_interval]"


@dataclass(frozen=True)
class PrometheusSource:
    """The provisioned Prometheus datasource that scrapes tsdb-service's ``/metrics``."""

    uid: str
    name: str

    @property
    def ref(self) -> common.DataSourceRef:
        return common.DataSourceRef(type_val=PROMETHEUS, uid=self.uid)


DS = PrometheusSource("tsdb-prometheus", "tsdb-service Prometheus")


def q(expr: str, legend: str, ref_id: str = "A") -> prometheus.Dataquery:
    return prometheus.Dataquery().datasource(DS.ref).ref_id(ref_id).expr(expr).legend_format(legend).range()


def rate(metric: str, by: str = "", where: str = "") -> str:
    grouping = f" by ({by})" if by else ""
    selector = f"{metric}{{{where}}}" if where else metric
    return f"sum{grouping} (rate({selector}{RATE}))"


def quantile(phi: float, metric: str, by: str = "", where: str = "") -> str:
    return f"histogram_quantile({phi}, {rate(metric + '_bucket', ', '.join(filter(None, ('le', by))), where)})"


def stat(ids: kit.Ids, title: str, expr: str, unit: str, description: str, steps=None) -> gstat.Panel:
    """A big number: the query's last value (kit's stat panel picks a field by
    name, which a Prometheus frame does not have)."""
    panel = (
        gstat.Panel()
        .id(ids())
        .title(title)
        .span(4)
        .height(4)
        .datasource(DS.ref)
        .with_target(q(expr, title))
        .description(description)
        .unit(unit)
        .reduce_options(cb.ReduceDataOptions().calcs(["lastNotNull"]).values(False))
        .graph_mode(common.BigValueGraphMode.AREA)
        .color_mode(common.BigValueColorMode.VALUE)
        .text_mode(common.BigValueTextMode.VALUE)
        .no_value("0")
    )
    return panel.thresholds(steps) if steps is not None else panel


def series(ids: kit.Ids, title: str, targets: list[tuple[str, str]], unit: str, description: str, w: int = 12):
    panel = kit.timeseries_panel(ids, DS, title, q(*targets[0]), w=w, unit=unit, description=description)
    for i, (expr, legend) in enumerate(targets[1:], start=1):
        panel = panel.with_target(q(expr, legend, chr(ord("A") + i)))
    return panel


def build():
    ids = kit.Ids()
    dash = kit.dashboard(
        UID,
        "tsdb-service",
        "The service itself: notifications in, commits, query latency, store size. Needs Prometheus "
        "scraping tsdb-service's /metrics.",
        ["operations", "prometheus"],
        "now-1h",
        "30s",
    )
    red = kit.thresholds("green", (1, "red"))
    dash = dash.with_row(kit.row(ids, "Ingest"))
    for title, expr, unit, steps, description in (
        (
            "Accepted/s",
            rate("tsdb_notifications_accepted_total"),
            "reqps",
            None,
            "Notifications committed and answered 200",
        ),
        (
            "Rejected/s",
            rate("tsdb_notifications_rejected_total"),
            "reqps",
            red,
            "Answered 4xx and kept in the rejected store (GET /v2/notify/rejected)",
        ),
        (
            "Failed/s",
            rate("tsdb_notifications_failed_total"),
            "reqps",
            kit.thresholds("green", (0.001, "red")),
            "Could not be committed (503): nothing stored",
        ),
        (
            "Write queue",
            "sum(tsdb_write_queue_depth)",
            "short",
            kit.thresholds("green", (1000, "orange")),
            "Write ops waiting for a writer thread",
        ),
        (
            "Time index fallbacks/s",
            rate("tsdb_time_index_fallbacks_total"),
            "reqps",
            kit.thresholds("green", (0.001, "orange")),
            "Entities stored at the reception time: the notification carried no usable time",
        ),
        ("Store size", "max(tsdb_store_size_bytes)", "bytes", None, "DuckDB file + WAL, or pg_database_size"),
    ):
        dash = dash.with_panel(stat(ids, title, expr, unit, description, steps))
    dash = dash.with_panel(
        series(
            ids,
            "Notifications per tenant",
            [
                (rate("tsdb_notifications_accepted_total", "tenant"), "accepted {{tenant}}"),
                (rate("tsdb_notifications_rejected_total", "tenant"), "rejected {{tenant}}"),
                (rate("tsdb_notifications_failed_total", "tenant"), "failed {{tenant}}"),
            ],
            "reqps",
            "Per tenant (Fiware-Service); beyond the first 100 tenants, 'other'",
        )
    )
    dash = dash.with_panel(
        series(
            ids,
            "Rejections by reason",
            [
                (rate("tsdb_notifications_rejected_total", "tenant, reason"), "{{tenant}}: {{reason}}"),
            ],
            "reqps",
            "The NGSI error name each rejected notification got",
        )
    )

    dash = dash.with_row(kit.row(ids, "Group commit"))
    samples = 'kind="samples"'
    dash = dash.with_panel(
        series(
            ids,
            "Commit latency",
            [
                (quantile(0.5, "tsdb_commit_duration_seconds", where=samples), "p50"),
                (quantile(0.99, "tsdb_commit_duration_seconds", where=samples), "p99"),
            ],
            "s",
            "Stage + commit of one group of notifications",
            w=8,
        )
    )
    dash = dash.with_panel(
        series(
            ids,
            "Group size",
            [
                (
                    f"{rate('tsdb_commit_group_size_sum', where=samples)} / "
                    f"{rate('tsdb_commit_group_size_count', where=samples)}",
                    "mean",
                ),
                (quantile(0.99, "tsdb_commit_group_size", where=samples), "p99"),
            ],
            "short",
            "Notifications committed per transaction: bigger under load",
            w=8,
        )
    )
    dash = dash.with_panel(
        series(
            ids,
            "Write queue depth",
            [
                ("sum(tsdb_write_queue_depth)", "queued"),
            ],
            "short",
            "Grows when writers cannot keep up",
            w=8,
        )
    )

    dash = dash.with_row(kit.row(ids, "HTTP"))
    not_notify = 'route!~".*/notify"'
    dash = dash.with_panel(
        series(
            ids,
            "Query latency p99 by route",
            [
                (quantile(0.99, "tsdb_http_request_duration_seconds", "route", not_notify), "{{route}}"),
            ],
            "s",
            "Labelled by route template, never by the raw path",
        )
    )
    dash = dash.with_panel(
        series(
            ids,
            "Notification answer latency",
            [
                (quantile(0.5, "tsdb_http_request_duration_seconds", where='route=~".*/notify"'), "p50"),
                (quantile(0.99, "tsdb_http_request_duration_seconds", where='route=~".*/notify"'), "p99"),
            ],
            "s",
            "Receipt to answer, commit included (ack after commit)",
        )
    )
    dash = dash.with_panel(
        series(
            ids,
            "Requests by route and status",
            [
                (rate("tsdb_http_request_duration_seconds_count", "route, status"), "{{route}} {{status}}"),
            ],
            "reqps",
            "Every HTTP request, notifications included",
            w=24,
        )
    )

    dash = dash.with_row(kit.row(ids, "Storage and process"))
    dash = dash.with_panel(
        series(
            ids,
            "Store size",
            [
                ("max(tsdb_store_size_bytes)", "store"),
                ("max(tsdb_rejected_store_bytes)", "rejected store"),
            ],
            "bytes",
            "Measured at scrape time, cached 5 s",
            w=8,
        )
    )
    dash = dash.with_panel(
        series(
            ids,
            "Rejected notifications kept",
            [
                ("max(tsdb_rejected_notifications)", "rows"),
            ],
            "short",
            "Rows in the rejected store",
            w=8,
        )
    )
    dash = dash.with_panel(
        series(
            ids,
            "Process",
            [
                ("sum(process_resident_memory_bytes)", "resident memory"),
            ],
            "bytes",
            "Resident memory of the scraped process(es)",
            w=8,
        )
    )
    return dash
