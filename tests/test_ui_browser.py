"""The explorer page (``/ui``) and the API docs (``/docs``) in a real headless browser.

Debian's ``chromium`` and ``chromium-driver``, driven by Selenium, against a
real server subprocess on a DuckDB file fed with a seeded burst of the three
demo use cases (real Orion notifications over HTTP). The browser is
installed by this module when it is missing and we may (root, apt-get); it
is started with no network services of its own, and every request the pages
make is checked to stay on 127.0.0.1.

The page's requests are the Infinity endpoints, whose answers are the same on
both backends (``test_grafana_*``); this module is DuckDB only.

Screenshots go to the session's temporary directory (never the repository);
their paths and the page load times are printed (``pytest -s`` shows them).

Besides the use cases, the server holds one small entity of its own (tenant
``edge``) whose newest sample falls on a whole hour, so a chart's last time
tick sits at the very right end of its axis: where its label used to be cut;
and one (tenant ``gaps``) with more samples than the explorer's point budget
and a 30-minute outage, drawn from time buckets: the outage is a break in
the line, not a straight segment across it.
"""

from __future__ import annotations

import asyncio
import json
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx
import pytest

from tests.grafana_fixtures import feed_live
from tests.support.apt import apt_install
from tests.support.server import ServerProcess

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
CHROME_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--window-size=1400,1100",
)
READY_TIMEOUT_S = 30
LOAD_BUDGET_MS = 10_000  # generous: 2 shared cores; the figure itself is printed


@pytest.fixture(scope="session")
def chromium_binaries():
    """/usr/bin/chromium and /usr/bin/chromedriver, installed here if missing."""
    if not (CHROMIUM.exists() and CHROMEDRIVER.exists()):
        reason = apt_install("chromium", "chromium-driver")
        if reason is not None:
            pytest.skip(reason)
    if not (CHROMIUM.exists() and CHROMEDRIVER.exists()):
        pytest.skip("apt-get installed chromium but /usr/bin/chromium or /usr/bin/chromedriver is missing")
    return CHROMIUM, CHROMEDRIVER


@pytest.fixture(scope="module")
def demo_server(tmp_path_factory):
    """A real server on a DuckDB file with all three use cases' data."""
    server = ServerProcess(tmp_path_factory.mktemp("ui") / "demo.duckdb").start()
    try:
        stats = asyncio.run(feed_live(server.url, int(time.time() * 1000)))
        for name, row in stats.items():
            assert row.sent > 100 and row.failed == 0, f"{name}: {row}"
        _feed_edge(server.url)
        _feed_gap(server.url)
        yield server
    finally:
        server.terminate()


@pytest.fixture(scope="module")
def browser(chromium_binaries, tmp_path_factory):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    binary, driver_path = chromium_binaries
    options = webdriver.ChromeOptions()
    options.binary_location = str(binary)
    for flag in CHROME_FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL", "performance": "ALL"})
    # An explicit driver path: Selenium Manager never runs, nothing is downloaded.
    driver = webdriver.Chrome(service=Service(executable_path=str(driver_path)), options=options)
    driver.set_page_load_timeout(READY_TIMEOUT_S)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("ui-screenshots")


EDGE_END = datetime.fromtimestamp((int(time.time()) // 3600 - 48) * 3600, tz=UTC)  # a whole hour, 2 days ago


def _feed_edge(url: str) -> None:
    """Tenant ``edge``: one temperature every 10 s for the 5 minutes up to EDGE_END."""
    with httpx.Client(base_url=url, timeout=30) as client:
        for i in range(31):
            at = EDGE_END - timedelta(seconds=10 * (30 - i))
            entity = {
                "id": "Probe1",
                "type": "Probe",
                "temperature": {"type": "Number", "value": 20 + i % 5},
                "TimeInstant": {"type": "DateTime", "value": at.isoformat().replace("+00:00", "Z")},
            }
            sent = client.post(
                "/v2/notify", json={"subscriptionId": "edge", "data": [entity]}, headers={"Fiware-Service": "edge"}
            )
            assert sent.status_code == 200, sent.text


GAP_END = EDGE_END
GAP = (GAP_END - timedelta(minutes=75), GAP_END - timedelta(minutes=45))  # no sample in [start, end)


def _feed_gap(url: str) -> None:
    """Tenant ``gaps``: a temperature every 5 s for two hours up to GAP_END
    (1,080 samples, more than Explore's 800 points) but none during ``GAP``."""
    states = []
    for i in range(2 * 720 + 1):
        at = GAP_END - timedelta(seconds=5 * (2 * 720 - i))
        if GAP[0] <= at < GAP[1]:
            continue
        states.append(
            {
                "id": "Probe2",
                "type": "Probe",
                "temperature": {"type": "Number", "value": 20 + (i % 60) / 10},
                "TimeInstant": {"type": "DateTime", "value": at.isoformat().replace("+00:00", "Z")},
            }
        )
    with httpx.Client(base_url=url, timeout=30) as client:
        for k in range(0, len(states), 100):
            sent = client.post(
                "/v2/notify",
                json={"subscriptionId": "gaps", "data": states[k : k + 100]},
                headers={"Fiware-Service": "gaps"},
            )
            assert sent.status_code == 200, sent.text


# -- helpers ----------------------------------------------------------------------------


def _open(browser, url: str, view: str) -> float:
    """Load ``url`` afresh; wait until the page says ``view`` is drawn. Returns ms
    from navigation start to data drawn, as the page measured it."""
    from selenium.webdriver.support.ui import WebDriverWait

    browser.get("about:blank")
    _drain_logs(browser)
    browser.get(url)
    WebDriverWait(browser, READY_TIMEOUT_S).until(
        lambda d: d.execute_script("return document.body.dataset.ready") == view,
        message=f"{url} did not draw {view}",
    )
    error = browser.execute_script(
        "const e = document.getElementById('error'); return e && !e.hidden ? e.textContent : null"
    )
    assert error is None, f"the page reports: {error}"
    return browser.execute_script("return window.explorerReady.ms")


def _drain_logs(browser) -> None:
    browser.get_log("browser")
    browser.get_log("performance")


def _console_errors(browser) -> list[str]:
    return [entry["message"] for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]


def _requested_urls(browser) -> list[str]:
    urls = []
    for entry in browser.get_log("performance"):
        message = json.loads(entry["message"])["message"]
        if message.get("method") == "Network.requestWillBeSent":
            urls.append(message["params"]["request"]["url"])
    return urls


def _check_stayed_local(browser, server) -> list[str]:
    urls = _requested_urls(browser)
    assert urls, "no request was recorded"
    away = [u for u in urls if not u.startswith(server.url + "/") and not u.startswith(("data:", "blob:", "about:"))]
    assert away == [], f"requests left {server.url}: {away}"
    return urls


def _attr(browser, css: str, name: str) -> int:
    return int(browser.find_element("css selector", css).get_attribute(f"data-{name}") or 0)


def _shot(browser, shots: Path, name: str) -> None:
    path = shots / f"{name}.png"
    browser.save_screenshot(str(path))
    print(f"\nscreenshot {path}")


# -- the tests -------------------------------------------------------------------------------


def test_explore_lists_the_tenants_and_draws_an_entity(browser, demo_server, shots):
    ms = _open(browser, demo_server.url + "/ui", "explore")
    tenants = [o.get_attribute("value") for o in browser.find_elements("css selector", "#tenant option")]
    assert {"lawnmower", "warehouse", "drone"} <= set(tenants)
    assert _console_errors(browser) == []
    _check_stayed_local(browser, demo_server)
    ms = _open(browser, demo_server.url + "/ui/#/explore?tenant=lawnmower", "explore")
    print(f"\nexplorer load, lawnmower entity: {ms:.0f} ms")
    assert browser.find_element("css selector", "#entity option").get_attribute("selected")
    assert _attr(browser, '.map-box[data-attr="location"]', "path-points") > 100
    odom = browser.find_element("css selector", '.chart[data-attr="odom"]')
    assert int(odom.get_attribute("data-series")) >= 3 and int(odom.get_attribute("data-points")) > 100
    assert odom.find_elements("css selector", "canvas")
    assert _attr(browser, '.chart[data-attr="obstacleDistance"]', "points") > 100
    assert _console_errors(browser) == []
    _shot(browser, shots, "explore-lawnmower")


def test_lawnmower_path_and_navigation_states(browser, demo_server, shots):
    ms = _open(browser, demo_server.url + "/ui/#/lawnmower", "lawnmower")
    print(f"\nexplorer load, lawnmower view: {ms:.0f} ms")
    assert ms < LOAD_BUDGET_MS
    assert _attr(browser, "#lawnmower-map", "path-points") > 100
    assert browser.find_elements("css selector", "#lawnmower-map polygon")  # the border wire
    assert _attr(browser, "#lawnmower-states", "segments") > 10
    legend = browser.find_element("css selector", "#lawnmower-states").text
    assert "mowing" in legend and "driving straight" in legend
    assert _attr(browser, "#lawnmower-obstacle", "points") > 100
    assert _attr(browser, "#lawnmower-speed", "series") == 2
    assert _console_errors(browser) == []
    _check_stayed_local(browser, demo_server)
    _shot(browser, shots, "lawnmower")


def test_warehouse_door_laser_and_light_timeline(browser, demo_server, shots):
    ms = _open(browser, demo_server.url + "/ui/#/warehouse", "warehouse")
    print(f"\nexplorer load, warehouse view: {ms:.0f} ms")
    assert _attr(browser, "#warehouse-laser", "points") > 100
    assert _attr(browser, "#warehouse-laser", "series") == 2  # the reading and the 0.6 m threshold
    assert _attr(browser, "#warehouse-states", "segments") > 8
    named = {span.text for span in browser.find_elements("css selector", "#warehouse-states .legend span")}
    assert {"open", "closed", "in motion", "on", "off"} <= named
    assert _attr(browser, "#warehouse-robot", "points") > 50
    assert "door opened" in browser.find_element("css selector", "#view-warehouse").text
    assert _console_errors(browser) == []
    _check_stayed_local(browser, demo_server)
    _shot(browser, shots, "warehouse")


def test_drone_route_sensors_and_priorities(browser, demo_server, shots):
    ms = _open(browser, demo_server.url + "/ui/#/drone", "drone")
    print(f"\nexplorer load, drone view: {ms:.0f} ms")
    assert len(browser.find_elements("css selector", "#drone-map circle.sensor")) == 8
    assert _attr(browser, "#drone-map", "path-points") > 100
    rows = browser.find_elements("css selector", "#drone-sensors tr.sensor-row")
    assert len(rows) == 8
    cells = [row.find_elements("css selector", "td") for row in rows]
    assert [float(c[1].text) for c in cells] == [0.075, 0.075, 0.075, 0.175, 0.1, 0.2, 0.125, 0.175]
    assert sum(int(c[2].text) for c in cells) >= 10  # visits
    assert all(c[4].text for c in cells)  # a temperature per sensor
    assert _attr(browser, "#drone-temperature", "series") == 8
    assert _attr(browser, "#drone-states", "segments") > 20
    assert _console_errors(browser) == []
    _check_stayed_local(browser, demo_server)
    _shot(browser, shots, "drone")


def test_docs_render_from_the_package(browser, demo_server, shots):
    from selenium.webdriver.support.ui import WebDriverWait

    browser.get("about:blank")
    _drain_logs(browser)
    browser.get(demo_server.url + "/docs")
    WebDriverWait(browser, READY_TIMEOUT_S).until(
        lambda d: d.find_elements("css selector", ".swagger-ui .opblock"), message="Swagger UI drew no operation"
    )
    assert "tsdb-service" in browser.find_element("css selector", ".swagger-ui .info .title").text
    # Authentication is off: no lock on any operation and no Authorize button.
    assert browser.find_elements("css selector", ".swagger-ui .authorization__btn") == []
    assert browser.find_elements("css selector", ".swagger-ui .btn.authorize") == []
    assert _console_errors(browser) == []
    urls = _check_stayed_local(browser, demo_server)
    assert demo_server.url + "/openapi.json" in urls
    _shot(browser, shots, "docs")


# -- layout: what a reader at 1400 and 1920 px must not meet ------------------------------------

WIDTHS = (1400, 1920)
LAYOUT_CHECKS = (Path(__file__).parent / "support" / "layout_checks.js").read_text()


def _layout(browser, check: str, *args) -> list[str]:
    """Run one function of ``support/layout_checks.js`` in the page: its problems."""
    return browser.execute_script(f"{LAYOUT_CHECKS}\nreturn {check}(...arguments);", *args)


@pytest.fixture
def wide(browser):
    """Each width in turn; the window is set back afterwards."""
    yield lambda width: browser.set_window_size(width, 1100)
    browser.set_window_size(1400, 1100)


@pytest.mark.parametrize("width", WIDTHS)
def test_map_labels_stay_apart_and_inside(browser, demo_server, shots, wide, width):
    """Sensor labels overlapped on the drone's map; the lawnmower map's right-hand
    longitude (and its top and bottom latitudes) were cut by the frame."""
    wide(width)
    for view, hash_ in (("drone", "#/drone"), ("lawnmower", "#/lawnmower"), ("explore", "#/explore?tenant=drone")):
        _open(browser, demo_server.url + "/ui/" + hash_, view)
        assert _layout(browser, "mapLabelProblems", "svg.map") == [], f"{view} at {width} px"
        assert browser.find_elements("css selector", "svg.map text.grat-label"), "the graticule lost every label"
    _shot(browser, shots, f"drone-map-{width}")


@pytest.mark.parametrize("width", WIDTHS)
def test_time_labels_never_overlap(browser, demo_server, wide, width):
    """Date labels collided on the half-width charts (uPlot's two-line first label); the
    last one could be cut by the chart's right edge; every legend began with a row
    reading "Time: --" and every value read "--" while the cursor was elsewhere."""
    wide(width)
    for view, hash_ in (
        ("explore", "#/explore?tenant=lawnmower"),
        ("lawnmower", "#/lawnmower"),
        ("warehouse", "#/warehouse"),
        ("drone", "#/drone"),
    ):
        _open(browser, demo_server.url + "/ui/" + hash_, view)
        for span in RANGES:  # from the default window to a week, where labels become dates
            _choose_range(browser, span, view)
            assert _layout(browser, "timeLabelProblems") == [], f"{view} at {width} px, range {span}"
            assert _layout(browser, "edgeLabelProblems") == [], f"{view} at {width} px, range {span}"
            assert _layout(browser, "idleLegendProblems") == [], f"{view} at {width} px, range {span}"


RANGES = ("auto", "3600", "604800")


def _choose_range(browser, value: str, view: str) -> None:
    from selenium.webdriver.support.ui import WebDriverWait

    browser.execute_script(
        "const r = document.getElementById('range'); delete document.body.dataset.ready;"
        "r.value = arguments[0]; r.dispatchEvent(new Event('change'));",
        value,
    )
    WebDriverWait(browser, READY_TIMEOUT_S).until(
        lambda d: d.execute_script("return document.body.dataset.ready") == view, message=f"range {value}"
    )


@pytest.mark.parametrize("width", WIDTHS)
def test_drone_priority_table_fits_its_card(browser, demo_server, shots, wide, width):
    wide(width)
    _open(browser, demo_server.url + "/ui/#/drone", "drone")
    assert _layout(browser, "tableProblems") == [], f"at {width} px"


def test_a_gap_in_the_data_is_a_break_in_the_line(browser, demo_server, shots):
    """Explore draws all of the entity's data from time buckets (more samples
    than its 800 points): a bucket without a sample is a null, and uPlot
    leaves the line out there. The chart's canvas holds no pixel of the
    series' colour in the middle of the outage, and does elsewhere; the
    page says the points are buckets."""
    _open(browser, demo_server.url + "/ui/#/explore?tenant=gaps", "explore")
    gaps, drawn = browser.execute_script(
        """const box = document.querySelector('.chart[data-attr="temperature"]');
        return [Number(box.dataset.gaps), Number(box.dataset.points)];"""
    )
    assert gaps >= 1 and 500 < drawn <= 800, (gaps, drawn)
    mid = (GAP[0] + (GAP[1] - GAP[0]) / 2).timestamp()
    before = (GAP[0] - timedelta(minutes=20)).timestamp()
    inked = browser.execute_script(
        """const u = document.querySelector('.chart[data-attr="temperature"]').uplot;
        const ink = (t) => {  // pixels of the series' colour (#1f77b4) in 5 columns around time t
          const x = Math.round(u.valToPos(t, 'x', true));
          const data = u.ctx.getImageData(x - 2, 0, 5, u.ctx.canvas.height).data;
          let n = 0;
          const near = (i, c) => Math.abs(data[i] - c) < 40;
          for (let i = 0; i < data.length; i += 4) if (near(i, 31) && near(i + 1, 119) && near(i + 2, 180)) n++;
          return n;
        };
        return [ink(arguments[0]), ink(arguments[1])];""",
        mid,
        before,
    )
    assert inked[0] == 0, f"the line is drawn across the outage: {inked}"
    assert inked[1] > 0, f"no line where the data is: {inked}"
    said = browser.find_element("css selector", "#said").text
    assert "time buckets" in said, said
    _shot(browser, shots, "explore-gap")


def test_explore_names_series_and_states(browser, demo_server, shots):
    """Every legend read ``data:`` (the key inside std_msgs values) instead of the
    attribute's name, and enumerations showed as numbers."""
    _open(browser, demo_server.url + "/ui/#/explore?tenant=lawnmower", "explore")
    labels = browser.execute_script(
        "return [...document.querySelectorAll('.chart')].filter((b) => b.uplot)"
        ".map((b) => [b.dataset.attr, b.uplot.series.slice(1).map((s) => s.label)])"
    )
    by_attr = dict(labels)
    assert by_attr["navigationState"] == ["navigationState"]
    assert by_attr["obstacleDistance"] == ["obstacleDistance"]
    assert not [attr for attr, names in labels if "data" in names], labels
    ticks, shown = browser.execute_script(
        """const u = document.querySelector('.chart[data-attr="navigationState"]').uplot;
        u.setCursor({left: u.bbox.width / devicePixelRatio / 2, top: 10});
        return [u.axes[1]._values.map(String), u.root.querySelector('.u-series:nth-child(2) .u-value').textContent];"""
    )
    usecase = demo_server_usecases(demo_server)["lawnmower"]["enums"]["navigationState"]
    assert set(ticks) <= set(usecase.values()) and "mowing" in ticks, ticks
    assert shown in usecase.values(), shown
    _shot(browser, shots, "explore-states")


def demo_server_usecases(server) -> dict:
    import httpx

    return httpx.get(server.url + "/ui/usecases", timeout=10).json()


# -- the first hour: loading, failures, legends, edges, wide screens, the range, dashboards ----------


def _go(browser, hash_: str, view: str) -> None:
    """Another view of the page already open (no reload), drawn; ``hash_`` is not the current one."""
    browser.execute_script("delete document.body.dataset.ready; location.hash = arguments[0];", hash_)
    _wait_ready(browser, view)


def _wait_ready(browser, view: str) -> None:
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(browser, READY_TIMEOUT_S).until(
        lambda d: d.execute_script("return document.body.dataset.ready") == view, message=f"{view} was not drawn"
    )


def test_a_view_says_it_is_loading_until_its_data_is_drawn(browser, demo_server):
    _open(browser, demo_server.url + "/ui/#/lawnmower", "lawnmower")
    assert browser.find_elements("css selector", "#loading") == []
    # Changing the range starts the view again; until its first answer arrives, it says it is loading.
    loading, flag = browser.execute_script(
        """const r = document.getElementById('range'); r.value = '3600'; r.dispatchEvent(new Event('change'));
        const line = document.getElementById('loading');
        return [line && line.offsetParent !== null ? line.textContent : null, document.body.dataset.loading];"""
    )
    assert loading == "Loading the lawnmower's data…" and flag == "lawnmower"
    _wait_ready(browser, "lawnmower")
    assert browser.find_elements("css selector", "#loading") == []
    assert browser.execute_script("return document.body.dataset.loading") is None
    assert _attr(browser, "#lawnmower-obstacle", "points") > 100


def test_a_failed_request_is_said_where_the_view_would_be(browser, demo_server, shots):
    _open(browser, demo_server.url + "/ui/#/lawnmower", "lawnmower")
    browser.execute_cdp_cmd("Network.enable", {})
    browser.execute_cdp_cmd("Network.setBlockedURLs", {"urls": ["*/grafana/infinity/states*"]})
    try:
        browser.execute_script("location.hash = '#/warehouse'")
        _wait_ready(browser, "warehouse")
        error = browser.find_element("css selector", "main #error").text
        assert "Could not load this view" in error and "/grafana/infinity/states" in error, error
        assert browser.find_elements("css selector", "#loading") == []
        _shot(browser, shots, "warehouse-failed")
    finally:
        browser.execute_cdp_cmd("Network.setBlockedURLs", {"urls": []})
    browser.execute_script("delete document.body.dataset.ready")
    browser.find_element("css selector", "#error button.retry").click()
    _wait_ready(browser, "warehouse")
    assert browser.find_elements("css selector", "#error") == []
    assert _attr(browser, "#warehouse-states", "segments") > 8
    _drain_logs(browser)


def test_legends_show_the_time_and_values_under_the_cursor(browser, demo_server):
    """Away from the charts a legend only names the series (test_time_labels_never_overlap
    checks every view); on one, every chart of the view shows its values at that time."""
    from selenium.webdriver.common.action_chains import ActionChains

    legends = "return [...document.querySelectorAll('.chart .u-legend')].map((l) => l.innerText)"
    _open(browser, demo_server.url + "/ui/#/warehouse", "warehouse")
    assert _layout(browser, "idleLegendProblems") == []
    ActionChains(browser).move_to_element(browser.find_element("css selector", "#warehouse-laser .u-over")).perform()
    hovered = browser.execute_script(legends)
    assert len(hovered) == 3 and all(text.startswith("Time") for text in hovered), hovered  # the cursors are synced
    assert "--" not in hovered[0], hovered[0]
    ActionChains(browser).move_to_element(browser.find_element("css selector", "header h1")).perform()
    assert _layout(browser, "idleLegendProblems") == []


@pytest.mark.parametrize("width", (1280, 2560))
def test_the_last_time_label_stays_inside_its_chart(browser, demo_server, wide, width):
    """The label of a tick at the axis' right end was cut in half (the use cases' views
    are checked at every range by test_time_labels_never_overlap)."""
    wide(width)
    _open(browser, demo_server.url + "/ui/#/explore?tenant=edge", "explore")
    for span in ("auto", "300"):
        _choose_range(browser, span, "explore")
        at_the_end = browser.execute_script(
            """const u = document.querySelector('.chart[data-attr="temperature"]').uplot, splits = u.axes[0]._splits;
            return u.valToPos(splits[splits.length - 1], 'x') >= u.bbox.width / devicePixelRatio - 1;"""
        )
        assert at_the_end, "the edge entity's last tick should sit at the axis' right end"
        assert _layout(browser, "edgeLabelProblems") == [], f"edge at {width} px, range {span}"


def test_wide_screens_are_filled(browser, demo_server, shots, wide):
    """The page stopped at 1400 px: half of a 2560 px screen stayed empty."""
    wide(1280)
    _open(browser, demo_server.url + "/ui/#/warehouse", "warehouse")
    narrow = browser.execute_script("return document.getElementById('warehouse-laser').uplot.height")
    wide(2560)
    _open(browser, demo_server.url + "/ui/#/warehouse", "warehouse")
    main, laser, robot, tall = browser.execute_script(
        """const w = (id) => document.getElementById(id).getBoundingClientRect().width;
        const laser = document.getElementById('warehouse-laser').uplot;
        return [w('main'), w('warehouse-laser'), w('warehouse-robot'), laser.height];"""
    )
    assert main > 2500 and laser > 2400 and robot > 1150, (main, laser, robot)
    assert tall > narrow, (tall, narrow)  # wider charts are taller too
    _shot(browser, shots, "warehouse-2560")


def test_the_time_range_says_what_auto_picks(browser, demo_server):
    _open(browser, demo_server.url + "/ui/#/dashboards", "dashboards")
    assert not browser.find_element("css selector", "label.range").is_displayed()  # no time on that page
    for view, hash_, auto in (
        ("explore", "#/explore?tenant=lawnmower", "auto (all data)"),
        ("lawnmower", "#/lawnmower", "auto (last hour of data)"),
        ("warehouse", "#/warehouse", "auto (last 10 min of data)"),
        ("drone", "#/drone", "auto (last 6 h of data)"),
    ):
        _go(browser, hash_, view)
        label = browser.find_element("css selector", "label.range")
        assert label.is_displayed() and label.find_element("css selector", "option").text == auto
        tip = label.get_attribute("title")
        assert "newest sample" in tip and "Warehouse, the last 10 minutes" in tip, tip


def test_the_dashboards_page_lists_every_dashboard_with_its_json(browser, demo_server, shots):
    """The header's dashboards link opened raw JSON."""
    from selenium.webdriver.support.ui import WebDriverWait

    listed = httpx.get(demo_server.url + "/dashboards", timeout=10).json()
    _open(browser, demo_server.url + "/ui/#/lawnmower", "lawnmower")
    browser.execute_script("delete document.body.dataset.ready")
    browser.find_element("css selector", "header .links a[data-view='dashboards']").click()
    _wait_ready(browser, "dashboards")
    cards = browser.find_elements("css selector", "#dashboards .dashboard")
    assert [card.get_attribute("data-dashboard") for card in cards] == [entry["name"] for entry in listed]
    for card, entry in zip(cards, listed, strict=True):
        assert entry["title"] in card.text and entry["description"] in card.text
        assert entry["sections"][0]["panels"][0] in card.text
        opened = card.find_element("css selector", "a.json").get_attribute("href")
        download = card.find_element("css selector", "a.download")
        assert (
            download.get_attribute("href") == opened and download.get_attribute("download") == f"{entry['name']}.json"
        )
        doc = httpx.get(opened, timeout=10)
        assert doc.status_code == 200 and doc.json()["uid"] == entry["uid"], opened
    steps = browser.find_element("css selector", "ol.steps").text
    assert "yesoreyeram-infinity-datasource" in steps and "Dashboards → New → Import" in steps
    url = browser.find_element("css selector", "#service-url")
    url.clear()
    url.send_keys("http://tsdb-service.lan:8668")
    yaml = httpx.get(browser.find_element("css selector", "#datasources-yaml").get_attribute("href"), timeout=10)
    assert yaml.status_code == 200 and "    url: http://tsdb-service.lan:8668\n" in yaml.text
    copy = cards[0].find_element("css selector", "button.copy")
    copy.click()
    WebDriverWait(browser, 10).until(lambda d: copy.text != "Copy JSON", message="the copy button said nothing")
    assert copy.text == "Copied"
    assert _console_errors(browser) == []
    _check_stayed_local(browser, demo_server)
    _shot(browser, shots, "dashboards")
