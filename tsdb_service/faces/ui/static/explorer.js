/* tsdb-service explorer.
 *
 * A page with no build step: it reads this service's own HTTP API (the
 * Grafana Infinity rows under /grafana/infinity/ and /ui/tenants), draws
 * time series with uPlot (vendored), and state timelines and maps as plain
 * SVG (no tile server: positions are projected on a local flat plane).
 * Nothing is fetched from anywhere but this service.
 *
 * Views (hash routes): #/explore?tenant=&path=&entity=  any entity's attributes;
 * #/lawnmower, #/warehouse, #/drone  the three demo use cases; #/dashboards
 * the Grafana dashboards and how to import them.
 * While a view loads, a status line under what it has drawn says so
 * (#loading, and <body data-loading="VIEW">); a failure replaces it with the
 * error (#error). When a view has drawn its data it sets
 * <body data-ready="VIEW"> and window.explorerReady = {view, ms} (ms since
 * navigation start).
 */
"use strict";
(function () {
  const ROOT = new URL("../", location.href); // the service's root, behind any path prefix
  const PALETTE = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                   "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"];
  const SVGNS = "http://www.w3.org/2000/svg";
  const MAX_COLUMNS = 60; // the Infinity endpoints take at most 64 columns
  const METRES_PER_DEG = 111320;
  const main = document.getElementById("main");
  const rangeSelect = document.getElementById("range");
  const rangeLabel = rangeSelect.closest("label");
  /** What "auto" shows in each view: a window ending at the newest sample (seconds; null: all). */
  const AUTO = {
    explore: { seconds: null, text: "all data" },
    lawnmower: { seconds: 3600, text: "last hour of data" },
    warehouse: { seconds: 600, text: "last 10 min of data" },
    drone: { seconds: 6 * 3600, text: "last 6 h of data" },
  };
  const AUTO_TIP = "Every range ends at the newest sample stored, not at the present, so an old database shows " +
    "its data too. auto picks a window that suits the view: Explore, all the entity's data (the database draws " +
    "each series in at most 800 time buckets); Lawnmower, the last hour; Warehouse, the last 10 minutes; Drone, " +
    "the last 6 hours.";
  let charts = []; // live uPlot instances of the current view
  let generation = 0; // bumps on every navigation; stale async work stops drawing

  // -- small DOM helpers ------------------------------------------------------

  function build(doc, tag, attrs, kids) {
    const node = doc(tag);
    for (const [key, value] of Object.entries(attrs || {})) {
      if (value === null || value === undefined || value === false) continue;
      if (key.startsWith("on")) node.addEventListener(key.slice(2), value);
      else node.setAttribute(key === "className" ? "class" : key, value === true ? "" : String(value));
    }
    for (const kid of kids.flat(Infinity)) {
      if (kid === null || kid === undefined || kid === false) continue;
      node.append(kid instanceof Node ? kid : String(kid));
    }
    return node;
  }
  const h = (tag, attrs, ...kids) => build((t) => document.createElement(t), tag, attrs, kids);
  const s = (tag, attrs, ...kids) => build((t) => document.createElementNS(SVGNS, t), tag, attrs, kids);

  function panel(title, note, ...body) {
    return h("section", { class: "panel" }, h("h2", {}, title, note ? h("small", {}, note) : null), ...body);
  }

  /** The status line under a loading view becomes the error: the reader sees why nothing came. */
  function showError(status, err) {
    const message = String(err && err.message ? err.message : err);
    status.replaceWith(h("div", { id: "error", role: "alert" }, h("b", {}, "Could not load this view: "), message,
      h("div", { class: "caption" }, h("button", { type: "button", class: "retry", onclick: route }, "Try again"),
        " The browser console has the details.")));
    console.error(err);
  }

  // -- the API ------------------------------------------------------------------

  /** What the answers of the view at hand said about themselves: the bucket widths their
   * points stand for (X-Tsdb-Bucket) and what a cap left out (X-Tsdb-Notice). */
  let said = { buckets: new Set(), notices: [] };

  async function api(path, params) {
    const url = new URL(path, ROOT);
    for (const [key, value] of Object.entries(params || {})) {
      if (value !== undefined && value !== null && value !== "") url.searchParams.set(key, value);
    }
    let resp;
    try {
      resp = await fetch(url, { headers: { Accept: "application/json" } });
    } catch (err) { // no answer at all: the service stopped, or the network is down
      throw new Error(`the service did not answer ${url.pathname} (${err.message}): is it still running?`);
    }
    const body = await resp.json().catch(() => null);
    if (!resp.ok) {
      const why = body && body.description ? `: ${body.description}` : "";
      throw new Error(`${url.pathname} answered HTTP ${resp.status}${why}`);
    }
    const bucket = resp.headers.get("X-Tsdb-Bucket");
    if (bucket && bucket !== "raw") said.buckets.add(bucket);
    const notice = resp.headers.get("X-Tsdb-Notice");
    if (notice) for (const text of notice.split(" | ")) if (!said.notices.includes(text)) said.notices.push(text);
    return body;
  }

  /** A line under the view: the bucket widths drawn (a point per bucket, not every sample) and
   * anything the service left out, so a chart never looks complete when it is not. */
  function saidLine() {
    const parts = [];
    if (said.buckets.size) {
      parts.push(h("span", { id: "buckets" }, `Drawn from the database's time buckets (${[...said.buckets].join(", ")}): ` +
        "one point per bucket, a gap where a bucket holds no sample."));
    }
    for (const text of said.notices) parts.push(h("span", { class: "notice" }, `Not shown: ${text}.`));
    return parts.length ? h("p", { id: "said", class: "muted" }, parts) : null;
  }

  let useCasesPromise = null;
  function useCases() {
    useCasesPromise = useCasesPromise || api("ui/usecases");
    return useCasesPromise;
  }

  const scopeOf = (service, servicePath) => ({ service, servicepath: servicePath || "" });

  /** {from, to} (epoch ms) ending at the newest sample, or {} for all data. */
  function timeWindow(newestMs, view) {
    const choice = rangeSelect.value;
    const seconds = choice === "auto" ? AUTO[view].seconds : choice === "all" ? null : Number(choice);
    if (seconds === null || !Number.isFinite(newestMs)) return {};
    return { from: Math.round(newestMs - seconds * 1000), to: Math.round(newestMs) };
  }

  /** The x range to draw: the data's own span, within the window asked for. */
  function xRangeOf(win, ...rowSets) {
    let lo = Infinity, hi = -Infinity;
    for (const rows of rowSets) for (const row of rows) {
      const t = Date.parse(row.time);
      if (t < lo) lo = t;
      if (t > hi) hi = t;
    }
    if (win.from !== undefined) {
      lo = Number.isFinite(lo) ? Math.max(lo, win.from) : win.from;
      hi = win.to;
    }
    return Number.isFinite(lo) ? [lo, Math.max(hi, lo + 1000)] : [Date.now() - 3600e3, Date.now()];
  }

  // -- time formatting ------------------------------------------------------------

  const pad = (n) => String(n).padStart(2, "0");
  function clock(ms, seconds) {
    const d = new Date(ms);
    return `${pad(d.getHours())}:${pad(d.getMinutes())}` + (seconds ? `:${pad(d.getSeconds())}` : "");
  }
  function stamp(ms) {
    const d = new Date(ms);
    return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ${clock(ms, true)}`;
  }
  function span(seconds) {
    if (seconds < 120) return `${Math.round(seconds)} s`;
    if (seconds < 7200) return `${Math.round(seconds / 60)} min`;
    return `${(seconds / 3600).toFixed(1)} h`;
  }
  const TICK_STEPS = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400];

  // -- charts (uPlot) ------------------------------------------------------------------

  /** Rows of one or more entities → uPlot data: shared x (s) and one array per (entity, column).
   * A row without a column has no point of it there (undefined: the line goes on); a null is a gap
   * (no sample in that bucket): the line breaks. */
  function toColumns(rows, keys) {
    const times = [...new Set(rows.map((r) => Date.parse(r.time)))].sort((a, b) => a - b);
    const at = new Map(times.map((t, i) => [t, i]));
    const out = new Map();
    for (const row of rows) {
      const i = at.get(Date.parse(row.time));
      for (const key of keys) {
        if (!(key in row)) continue;
        const id = `${row.entity}\u0000${key}`;
        if (!out.has(id)) out.set(id, { entity: row.entity, key, values: new Array(times.length).fill(undefined) });
        const v = row[key];
        out.get(id).values[i] = v === null ? null : typeof v === "boolean" ? Number(v) : typeof v === "number" ? v : undefined;
      }
    }
    return { xs: times.map((t) => t / 1000), columns: [...out.values()] };
  }
  const drawn = (v) => v !== null && v !== undefined;
  /** One column's values (of the first entity that has it); [] when no row had any. */
  const valuesOf = (data, key) => (data.columns.find((c) => c.key === key) || { values: new Array(data.xs.length).fill(undefined) }).values;

  /** Time tick labels of one kind for a whole axis: dates, clock times, or both. */
  function timeLabel(ms, stepSeconds, spanSeconds) {
    const d = new Date(ms), day = `${pad(d.getMonth() + 1)}-${pad(d.getDate())}`;
    if (stepSeconds >= 86400) return day;
    return (spanSeconds > 86400 ? `${day} ` : "") + clock(ms, stepSeconds < 60);
  }
  const LABEL_PX = 7; // width of a tick label character at the axes' 12 px, with room to spare

  /** The x axis: one label format per axis, and ticks far enough apart for it (uPlot's
   * default puts a two-line date under the first tick, which collides on half-width charts).
   * ``edge``: the room a label centred on the plot's right end needs beyond it, so the last
   * tick's label is never cut by the chart's edge. */
  function timeAxis0(xRange) {
    const spanSeconds = xRange ? (xRange[1] - xRange[0]) / 1000 : 3600;
    const sample = timeLabel(Date.now(), spanSeconds < 600 ? 1 : 60, spanSeconds);
    return { edge: edgeRoom(sample.length * LABEL_PX), axis: { space: sample.length * LABEL_PX + 18,
      values: (u, splits, axisIdx, space, incr) => splits.map((v) => timeLabel(v * 1000, incr, spanSeconds)) } };
  }
  const edgeRoom = (labelPx) => Math.max(16, Math.ceil(labelPx / 2) + 4);

  /** Taller charts on wider cards, so a chart on a wide screen is not a thin strip. */
  const heightFor = (base, width) => Math.round(Math.min(base * 1.6, Math.max(base, width / 5)));

  /** A y axis naming the codes of an enumeration ({"0": "docked", ...}) instead of numbers. */
  function enumAxis(names) {
    const codes = Object.keys(names).map(Number).sort((a, b) => a - b);
    const widest = Math.max(...Object.values(names).map((n) => n.length));
    return { size: widest * LABEL_PX + 14, splits: () => codes, values: (u, ticks) => ticks.map((v) => names[String(v)] || v) };
  }

  /** The legend names the series; the time and the values show only while the cursor is on
   * a chart of the view (uPlot's legend would read "Time: --" and "--" otherwise). */
  function legendFollowsCursor(u) {
    const legend = u.root.querySelector(".u-legend");
    if (legend) legend.classList.toggle("u-live", u.cursor.idx !== null && u.cursor.idx !== undefined);
  }

  /**
   * A time-series chart. series: [{label, values, color?, stepped?, dash?, points?, names?}];
   * ``names`` (an enumeration) labels the y axis and the legend's value with state names.
   * ``height`` is the height on a narrow card; wider cards get taller charts.
   * The container gets data-series / data-points for whoever checks it was drawn, and
   * ``box.uplot`` the chart. No x values: a note says the range holds no samples.
   */
  function lineChart(box, { xs, series, xRange, height = 180, unit = "" }) {
    if (!xs.length) {
      box.replaceChildren(h("p", { class: "muted" }, "No samples in this time range."));
      return null;
    }
    const names = series.length === 1 ? series[0].names : null;
    const codes = names ? Object.keys(names).map(Number) : [];
    const width = Math.max(box.clientWidth, 300);
    const x = timeAxis0(xRange);
    const opts = {
      width,
      height: heightFor(height, width),
      padding: [8, x.edge, 0, 0],
      cursor: { sync: { key: "view" } },
      legend: { live: true },
      hooks: { init: [legendFollowsCursor], setCursor: [legendFollowsCursor] },
      scales: { x: { time: true, range: (u, lo, hi) => (xRange ? [xRange[0] / 1000, xRange[1] / 1000] : [lo, hi]) },
        y: names ? { range: [Math.min(...codes) - 0.5, Math.max(...codes) + 0.5] } : {} },
      axes: [x.axis, names ? enumAxis(names)
        : { size: 60, values: (u, ticks) => ticks.map((v) => `${+v.toPrecision(6)}${unit}`) }],
      series: [{ value: (u, v) => (v === null || v === undefined ? "" : stamp(v * 1000)) }].concat(series.map((one, i) => ({
        label: one.label,
        value: one.names ? (u, v) => (v === null || v === undefined ? "--" : one.names[String(v)] || String(v)) : undefined,
        stroke: one.color || PALETTE[i % PALETTE.length],
        width: one.width || 1.5,
        dash: one.dash,
        spanGaps: false, // a null is a bucket without a sample: the line breaks there
        points: { show: one.points || false, size: 5 },
        paths: one.stepped ? uPlot.paths.stepped({ align: 1 }) : undefined,
      }))),
    };
    const data = [xs].concat(series.map((one) => one.values));
    const chart = new uPlot(opts, data, box);
    box.uplot = chart;
    chart.tsdbHeight = height;
    charts.push(chart);
    box.dataset.series = String(series.length);
    box.dataset.points = String(series.reduce((n, one) => n + one.values.filter(drawn).length, 0));
    box.dataset.gaps = String(series.reduce((n, one) => n + one.values.filter((v) => v === null).length, 0));
    return chart;
  }

  window.addEventListener("resize", () => {
    for (const chart of charts) {
      const width = Math.max(chart.root.parentElement.clientWidth, 300);
      chart.setSize({ width, height: heightFor(chart.tsdbHeight, width) });
    }
  });

  // -- state timelines (SVG) -------------------------------------------------------------------

  function stateColor(value, index) {
    if (value === true) return "#d62728";
    if (value === false) return "#c8d1d9";
    return PALETTE[(Number.isInteger(value) ? value : index) % PALETTE.length];
  }

  const BAND_LABEL_PX = 6; // a timeline tick label character at 10 px ("HH:MM:SS" is 8)

  /**
   * Horizontal bands, one per state column: rows [{time, ...}] of state changes
   * (the /states endpoint), each band coloured by value, named by an enumeration.
   * bands: [{key, label, names?}]. Aligned with the charts' 60 px y axis.
   */
  function stateBands(box, { rows, bands, xRange, entity }) {
    const width = Math.max(box.clientWidth, 300), left = 60, right = edgeRoom(BAND_LABEL_PX * 8), rowH = 20, gap = 18;
    const height = bands.length * (rowH + gap) + 22;
    const x = (t) => left + ((t - xRange[0]) / (xRange[1] - xRange[0])) * (width - left - right);
    const mine = rows.filter((r) => !entity || r.entity === entity);
    const svg = s("svg", { class: "bands", viewBox: `0 0 ${width} ${height}`, width, height });
    const legend = h("div", {});
    let segments = 0;
    bands.forEach((band, b) => {
      const top = b * (rowH + gap) + gap - 4;
      svg.append(s("text", { class: "row-label", x: 0, y: top - 4 }, band.label));
      const seen = new Map();
      const points = mine.filter((r) => r[band.key] !== null && r[band.key] !== undefined);
      points.forEach((row, i) => {
        const t0 = Math.max(Date.parse(row.time), xRange[0]);
        const t1 = Math.min(i + 1 < points.length ? Date.parse(points[i + 1].time) : xRange[1], xRange[1]);
        if (t1 <= t0 && i + 1 < points.length) return;
        const value = row[band.key];
        const name = band.names ? band.names[String(Number(value))] || String(value) : String(value);
        if (!seen.has(name)) seen.set(name, stateColor(value, seen.size));
        const x0 = x(t0), w = Math.max(x(Math.max(t1, t0)) - x0, 1);
        svg.append(s("rect", { class: "seg", x: x0, y: top, width: w, height: rowH, fill: seen.get(name) },
          s("title", {}, `${band.label}: ${name}\n${stamp(t0)} → ${stamp(t1)}`)));
        if (w > name.length * 6 + 6) svg.append(s("text", { class: "seg-label", x: x0 + 3, y: top + 14 }, name));
        segments += 1;
      });
      legend.append(h("div", { class: "legend" }, h("b", {}, `${band.label}:`),
        [...seen].map(([name, color]) => h("span", {}, h("i", { style: `background:${color}` }), name))));
    });
    svg.append(timeAxis(x, xRange, height - 14, left, width - right));
    box.replaceChildren(svg, legend);
    box.dataset.segments = String(segments);
  }

  function timeAxis(x, xRange, y, x0, x1) {
    const seconds = (xRange[1] - xRange[0]) / 1000;
    const most = Math.max(2, Math.min(16, Math.floor((x1 - x0) / 64))); // "HH:MM:SS" at 10 px is ~45 px wide
    const step = TICK_STEPS.find((st) => seconds / st <= most) || 86400 * Math.ceil(seconds / 86400 / most);
    const g = s("g", { class: "axis" }, s("line", { x1: x0, x2: x1, y1: y - 10, y2: y - 10 }));
    const offset = new Date(xRange[0]).getTimezoneOffset() * 60e3;
    for (let t = Math.ceil((xRange[0] - offset) / (step * 1000)) * step * 1000 + offset; t <= xRange[1]; t += step * 1000) {
      g.append(s("line", { x1: x(t), x2: x(t), y1: y - 10, y2: y - 6 }),
        s("text", { x: x(t), y: y + 4, "text-anchor": "middle" }, clock(t, step < 60)));
    }
    return g;
  }

  // -- maps (SVG, no tiles) -------------------------------------------------------------------

  function niceStep(raw) {
    const p = 10 ** Math.floor(Math.log10(raw));
    return [1, 2, 5, 10].map((m) => m * p).find((v) => v >= raw);
  }

  /**
   * Positions on a local flat projection (fine for a site of a few km).
   * paths: [{coords: [[lon, lat]], colors?: [per point], color?, title?}];
   * markers: [{lon, lat, r?, color?, label?, title?, cls?}]; rings: [{coords, stroke?, fill?, title?}].
   */
  function mapChart(box, { paths = [], markers = [], rings = [], height = 420 }) {
    const width = Math.max(box.clientWidth, 300), margin = 28;
    const all = [...paths.flatMap((p) => p.coords), ...markers.map((m) => [m.lon, m.lat]), ...rings.flatMap((r) => r.coords)];
    if (!all.length) {
      box.replaceChildren(h("p", { class: "muted" }, "No positions in this time range."));
      return;
    }
    const lons = all.map((c) => c[0]), lats = all.map((c) => c[1]);
    const lon0 = (Math.min(...lons) + Math.max(...lons)) / 2, lat0 = (Math.min(...lats) + Math.max(...lats)) / 2;
    const kx = Math.cos((lat0 * Math.PI) / 180) * METRES_PER_DEG;
    const spanX = Math.max((Math.max(...lons) - Math.min(...lons)) * kx, 20);
    const spanY = Math.max((Math.max(...lats) - Math.min(...lats)) * METRES_PER_DEG, 20);
    const scale = Math.min((width - 2 * margin) / spanX, (height - 2 * margin) / spanY); // px per metre
    const px = (lon) => width / 2 + (lon - lon0) * kx * scale;
    const py = (lat) => height / 2 - (lat - lat0) * METRES_PER_DEG * scale;
    const svg = s("svg", { class: "map", viewBox: `0 0 ${width} ${height}`, width, height });
    box.replaceChildren(svg); // in the document from here on, so labels can be measured
    const grat = graticule(px, py, lon0, lat0, kx, scale, width, height);
    svg.append(grat);
    for (const ring of rings) {
      svg.append(s("polygon", { points: ring.coords.map((c) => `${px(c[0])},${py(c[1])}`).join(" "),
        fill: ring.fill || "none", stroke: ring.stroke || "#8b949e", "stroke-dasharray": "5 4" },
        ring.title ? s("title", {}, ring.title) : null));
    }
    let drawn = 0;
    for (const path of paths) {
      for (const run of colourRuns(path)) {
        svg.append(s("polyline", { class: "path", fill: "none", stroke: run.color, "stroke-width": path.width || 1.6,
          "stroke-linejoin": "round", points: run.coords.map((c) => `${px(c[0]).toFixed(1)},${py(c[1]).toFixed(1)}`).join(" ") },
          path.title ? s("title", {}, path.title) : null));
        drawn += run.coords.length;
      }
    }
    for (const m of markers) {
      svg.append(s("circle", { class: m.cls || "marker", cx: px(m.lon), cy: py(m.lat), r: m.r || 5,
        fill: m.color || "#d62728", stroke: "#fff", "stroke-width": 1.5 }, m.title ? s("title", {}, m.title) : null));
    }
    const furniture = [scaleBar(scale, height), s("g", { class: "north" },
      s("text", { x: width - 18, y: 18, "text-anchor": "middle" }, "N"),
      s("path", { d: `M${width - 18} 22 l-5 12 l5 -3 l5 3 z`, fill: "#333" }))];
    svg.append(...furniture);
    const taken = furniture.map((g) => g.getBBox()).concat(markers.map((m) => {
      const r = m.r || 5;
      return { x: px(m.lon) - r, y: py(m.lat) - r, width: 2 * r, height: 2 * r };
    }));
    fitGraticuleLabels(grat, width, height, taken);
    for (const m of markers.filter((one) => one.label)) { // labels on top of every marker, apart
      placeLabel(svg, s("text", { class: "label" }, m.label), px(m.lon), py(m.lat), m.r || 5, width, height, taken);
    }
    box.dataset.pathPoints = String(drawn);
    box.dataset.markers = String(markers.length);
  }

  const overlap = (a, b) => Math.max(0, Math.min(a.x + a.width, b.x + b.width) - Math.max(a.x, b.x)) *
    Math.max(0, Math.min(a.y + a.height, b.y + b.height) - Math.max(a.y, b.y));

  /** Put ``label`` beside the marker at (x, y) of radius r: the first of eight places that
   * stays in the frame and covers no other label or marker, else the one that covers least. */
  function placeLabel(svg, label, x, y, r, width, height, taken) {
    svg.append(label);
    const w = label.getBBox().width, h = 11, gap = r + 3;
    const places = [[x + gap, y + 4, "start"], [x - gap, y + 4, "end"], [x, y - gap - 1, "middle"], [x, y + gap + h - 1, "middle"],
      [x + gap - 2, y - gap, "start"], [x - gap + 2, y - gap, "end"], [x + gap - 2, y + gap + h - 3, "start"], [x - gap + 2, y + gap + h - 3, "end"]];
    let best = null;
    for (const [lx, ly, anchor] of places) {
      const left = anchor === "start" ? lx : anchor === "end" ? lx - w : lx - w / 2;
      const box = { x: left, y: ly - h + 2, width: w, height: h };
      const outside = box.x < 0 || box.y < 0 || box.x + w > width || box.y + h > height;
      const cost = (outside ? 1e6 : 0) + taken.reduce((sum, other) => sum + overlap(box, other), 0);
      if (best === null || cost < best.cost) best = { cost, lx, ly, anchor, box };
      if (cost === 0) break;
    }
    label.setAttribute("x", best.lx);
    label.setAttribute("y", best.ly);
    label.setAttribute("text-anchor", best.anchor);
    taken.push(best.box);
  }

  /** Graticule labels that would leave the frame, or sit on the scale bar, the north arrow or
   * another label, are moved inside (longitudes) or left out. */
  function fitGraticuleLabels(grat, width, height, taken) {
    const placed = [];
    for (const text of [...grat.querySelectorAll(".grat-label")]) {
      let box = text.getBBox();
      if (box.x + box.width > width - 2 && text.dataset.axis === "lon") {
        text.setAttribute("text-anchor", "end");
        text.setAttribute("x", Number(text.getAttribute("x")) - 4);
        box = text.getBBox();
      }
      const outside = box.x < 0 || box.y < 0 || box.x + box.width > width || box.y + box.height > height;
      if (outside || taken.concat(placed).some((other) => overlap(box, other) > 0)) text.remove();
      else placed.push(box);
    }
  }

  function colourRuns(path) {
    if (!path.colors) return [{ color: path.color || PALETTE[0], coords: path.coords }];
    const runs = [];
    path.coords.forEach((c, i) => {
      const color = path.colors[i];
      const last = runs[runs.length - 1];
      if (last && last.color === color) last.coords.push(c);
      else runs.push({ color, coords: last ? [last.coords[last.coords.length - 1], c] : [c] });
    });
    return runs;
  }

  function graticule(px, py, lon0, lat0, kx, scale, width, height) {
    const g = s("g", {});
    const latHalf = height / 2 / scale / METRES_PER_DEG, lonHalf = width / 2 / scale / kx;
    const step = niceStep((2 * latHalf) / 5);
    const digits = Math.max(0, -Math.floor(Math.log10(step)));
    for (let lat = Math.ceil((lat0 - latHalf) / step) * step; lat <= lat0 + latHalf; lat += step) {
      g.append(s("line", { class: "grat", x1: 0, x2: width, y1: py(lat), y2: py(lat) }),
        s("text", { class: "grat-label", "data-axis": "lat", x: 3, y: py(lat) - 2 }, `${lat.toFixed(digits)}°`));
    }
    const lonStep = niceStep((2 * lonHalf) / 6);
    const lonDigits = Math.max(0, -Math.floor(Math.log10(lonStep)));
    for (let lon = Math.ceil((lon0 - lonHalf) / lonStep) * lonStep; lon <= lon0 + lonHalf; lon += lonStep) {
      g.append(s("line", { class: "grat", x1: px(lon), x2: px(lon), y1: 0, y2: height }),
        s("text", { class: "grat-label", "data-axis": "lon", x: px(lon) + 2, y: 11 }, `${lon.toFixed(lonDigits)}°`));
    }
    return g;
  }

  function scaleBar(scale, height) {
    const metres = niceStep(90 / scale);
    const length = metres * scale, y = height - 14;
    const label = metres >= 1000 ? `${metres / 1000} km` : `${metres} m`;
    return s("g", { class: "scale" },
      s("line", { x1: 12, x2: 12 + length, y1: y, y2: y }),
      s("line", { x1: 12, x2: 12, y1: y - 4, y2: y + 4 }),
      s("line", { x1: 12 + length, x2: 12 + length, y1: y - 4, y2: y + 4 }),
      s("text", { x: 12 + length / 2, y: y - 6, "text-anchor": "middle" }, label));
  }

  const lonLat = (rows) => rows.map((r) => [r.lon, r.lat]);

  // -- generic entity explorer ----------------------------------------------------------------------

  const GEO_TYPES = new Set(["Point", "LineString", "Polygon", "MultiPoint", "MultiLineString", "MultiPolygon"]);
  const SKIP_KEYS = new Set(["header", "covariance", "stamp"]);
  const KEY = /^[^\s.,\[\]()<>"'=;]+$/;

  function isGeo(name, value) {
    if (value && typeof value === "object" && GEO_TYPES.has(value.type) && value.coordinates) return true;
    return typeof value === "string" && name === "location" && /^\s*-?\d+(\.\d+)?\s*,\s*-?\d+(\.\d+)?\s*$/.test(value);
  }

  /** Value paths (lists of keys) to every number or boolean inside an object, headers aside. */
  function leaves(value, prefix = [], out = []) {
    if (typeof value === "number" || typeof value === "boolean") out.push(prefix);
    else if (value && typeof value === "object" && !Array.isArray(value) && prefix.length < 6) {
      for (const key of Object.keys(value)) {
        if (!SKIP_KEYS.has(key) && KEY.test(key)) leaves(value[key], prefix.concat(key), out);
      }
    }
    return out;
  }

  async function viewExplore(box, params, stale) {
    const [tenants, cases] = await Promise.all([api("ui/tenants"), useCases()]);
    if (!tenants.length) {
      box.append(panel("No data yet", null, h("p", {}, "Nothing is stored. Run ", h("code", {}, "tsdb-service demo"),
        " or point an Orion subscription at ", h("code", {}, "/v2/notify"), ".")));
      return;
    }
    const tenant = tenants.find((t) => t.tenant === params.tenant) || tenants[0];
    const path = tenant.servicePaths.includes(params.path) ? params.path : "";
    const scope = scopeOf(tenant.tenant, path);
    const entities = await api("grafana/infinity/entities", scope);
    const entity = entities.find((e) => e.entity === params.entity && (!params.type || e.type === params.type)) || entities[0];
    const go = (next) => { location.hash = "#/explore?" + new URLSearchParams(next).toString(); };
    box.append(h("div", { class: "controls" },
      h("label", {}, "Tenant (Fiware-Service)", h("select", { id: "tenant", onchange: (e) => go({ tenant: e.target.value }) },
        tenants.map((t) => h("option", { value: t.tenant, selected: t === tenant },
          `${t.tenant || "(default)"} — ${t.entities} ${t.entities === 1 ? "entity" : "entities"}`)))),
      h("label", {}, "Service path", h("select", { id: "path", onchange: (e) => go({ tenant: tenant.tenant, path: e.target.value }) },
        h("option", { value: "" }, "all"), tenant.servicePaths.map((p) => h("option", { value: p, selected: p === path }, p)))),
      h("label", {}, "Entity", h("select", { id: "entity", onchange: (e) => {
        const [id, type] = JSON.parse(e.target.value);
        go({ tenant: tenant.tenant, path, entity: id, type });
      } }, entities.map((e) => h("option", { value: JSON.stringify([e.entity, e.type]), selected: e === entity },
        `${e.entity} (${e.type})`))))));
    if (!entity) {
      box.append(h("p", { class: "muted" }, "No entity in this service path."));
      return;
    }
    const useCase = Object.values(cases).find((one) => one.service === tenant.tenant);
    await exploreEntity(box, { ...scope, id: entity.entity, type: entity.type }, entity.attrs.split(","), stale,
      useCase ? useCase.enums : {});
  }

  async function exploreEntity(box, sel, attrNames, stale, enums) {
    const latest = {};
    let newest = -Infinity;
    for (let i = 0; i < attrNames.length; i += MAX_COLUMNS) {
      const chunk = attrNames.slice(i, i + MAX_COLUMNS);
      const rows = await api("grafana/infinity/latest", { ...sel, attrs: chunk.map((a, j) => `c${j}=${a}`).join(",") });
      for (const row of rows) {
        newest = Math.max(newest, Date.parse(row.time));
        chunk.forEach((a, j) => { if (row[`c${j}`] !== null && row[`c${j}`] !== undefined) latest[a] = row[`c${j}`]; });
      }
    }
    const geo = attrNames.filter((a) => isGeo(a, latest[a]));
    const plotted = []; // [{attr, path, spec}]
    for (const attr of attrNames) {
      if (geo.includes(attr)) continue;
      for (const keys of leaves(latest[attr]).slice(0, 12)) {
        plotted.push({ attr, keys, spec: keys.length ? `${attr}(${keys.join(".")})` : attr });
      }
    }
    const win = timeWindow(newest, "explore");
    const [rows, positions] = await Promise.all([fetchColumns(sel, plotted, win), Promise.all(geo.map((attr) =>
      api("grafana/infinity/positions", { ...sel, ...win, location: attr, max_points: 3000 })))]);
    if (stale()) return;
    const xRange = xRangeOf(win, rows, ...positions);
    box.append(h("p", { class: "muted" }, `${sel.id} · newest sample ${Number.isFinite(newest) ? stamp(newest) : "none"}` +
      ` · showing ${span((xRange[1] - xRange[0]) / 1000)}`));
    geo.forEach((attr, i) => {
      const mapBox = h("div", { class: "map-box", "data-attr": attr });
      box.append(panel(`${attr} — positions`, `${positions[i].length} fixes`, mapBox));
      const coords = lonLat(positions[i]);
      const last = positions[i][positions[i].length - 1];
      mapChart(mapBox, { paths: [{ coords, color: PALETTE[0], title: attr }],
        markers: last ? [{ lon: last.lon, lat: last.lat, r: 6, label: `latest ${clock(Date.parse(last.time), true)}`, cls: "marker latest" }] : [] });
    });
    const grid = h("div", { class: "grid" });
    box.append(grid);
    const draws = attributeCharts(grid, rows, plotted, xRange, enums);
    box.append(latestTable(attrNames, latest));
    for (const draw of draws) draw(); // once every panel is placed, so each chart fits its cell
  }

  /** /series for many columns, in requests of at most MAX_COLUMNS, merged by time. */
  async function fetchColumns(sel, plotted, win) {
    const parts = [];
    for (let i = 0; i < plotted.length; i += MAX_COLUMNS) {
      const chunk = plotted.slice(i, i + MAX_COLUMNS);
      const attrs = chunk.map((p, j) => `c${i + j}=${p.spec}`).join(",");
      parts.push(api("grafana/infinity/series", { ...sel, ...win, attrs, max_points: 800 }));
    }
    const byTime = new Map();
    for (const rows of await Promise.all(parts)) {
      for (const row of rows) byTime.set(row.time, Object.assign(byTime.get(row.time) || {}, row));
    }
    return [...byTime.values()].sort((a, b) => Date.parse(a.time) - Date.parse(b.time));
  }

  /** A panel per attribute in ``grid``; returns the functions that draw their charts. A series
   * is named after its attribute, or after its value path when the attribute has several;
   * an attribute with an enumeration (the use cases' states) shows state names. */
  function attributeCharts(grid, rows, plotted, xRange, enums) {
    const draws = [];
    const byAttr = new Map();
    plotted.forEach((p, i) => {
      if (!byAttr.has(p.attr)) byAttr.set(p.attr, []);
      byAttr.get(p.attr).push({ ...p, key: `c${i}` });
    });
    const data = toColumns(rows.map((r) => ({ ...r, entity: "" })), plotted.map((p, i) => `c${i}`));
    const values = new Map(data.columns.map((c) => [c.key, c.values]));
    for (const [attr, cols] of byAttr) {
      const varying = [], constant = [];
      for (const col of cols) {
        const present = (values.get(col.key) || []).filter(drawn);
        const label = col.keys.length ? col.keys.join(".") : attr;
        if (present.length && present.every((v) => v === present[0]) && cols.length > 1) constant.push(`${label} = ${present[0]}`);
        else varying.push({ label, values: values.get(col.key) || [], stepped: Number.isInteger(present[0]) });
      }
      if (varying.length === 1) { // the attribute's one number (e.g. std_msgs' "data"): named after it
        varying[0].label = attr;
        varying[0].names = enums[attr];
      }
      const box = h("div", { class: "chart", "data-attr": attr });
      const caption = constant.length ? h("div", { class: "caption" }, `constant: ${constant.join(", ")}`) : null;
      grid.append(panel(attr, `${varying.length} series`, box, caption));
      if (varying.length) draws.push(() => lineChart(box, { xs: data.xs, series: varying, xRange }));
      else box.append(h("p", { class: "muted" }, "Nothing that changes in this time range."));
    }
    return draws;
  }

  function latestTable(attrNames, latest) {
    const show = (v) => { const text = typeof v === "string" ? v : JSON.stringify(v); return text.length > 200 ? text.slice(0, 200) + "…" : text; };
    return panel("Latest values", null, h("table", {}, h("tr", {}, h("th", {}, "attribute"), h("th", {}, "value")),
      attrNames.map((a) => h("tr", {}, h("td", {}, a), h("td", {}, h("code", {}, latest[a] === undefined ? "" : show(latest[a])))))));
  }

  // -- use case: Bosch lawnmower ----------------------------------------------------------------------

  function noData(box, cfg) {
    box.append(panel(`${cfg.title}: no data`, null, h("p", {}, `Nothing stored for tenant ${cfg.service}${cfg.servicePath}. `,
      "Run ", h("code", {}, "tsdb-service demo"), " to feed the three use cases.")));
  }

  async function newestOf(sel, attr) {
    const rows = await api("grafana/infinity/latest", { ...sel, attrs: attr });
    return rows.length ? Math.max(...rows.map((r) => Date.parse(r.time))) : null;
  }

  async function viewLawnmower(box, params, stale) {
    const cfg = (await useCases()).lawnmower;
    const sel = { ...scopeOf(cfg.service, cfg.servicePath), id: cfg.entity };
    const newest = await newestOf(sel, "navigationState");
    if (newest === null) return noData(box, cfg);
    const win = timeWindow(newest, "lawnmower");
    const [positions, states, series] = await Promise.all([
      api("grafana/infinity/positions", { ...sel, ...win, attrs: "state=navigationState(data)", max_points: 5000 }),
      api("grafana/infinity/states", { ...sel, ...win,
        attrs: "nav=navigationState(data),sub=navigationSubState(data),left=perimeterLeft(data),right=perimeterRight(data)" }),
      api("grafana/infinity/series", { ...sel, ...win, max_points: 1500,
        attrs: "obstacle=obstacleDistance(range),speed=odom(twist.twist.linear.x),yawRate=odom(twist.twist.angular.z)" }),
    ]);
    if (stale()) return;
    const xRange = xRangeOf(win, positions, states, series);
    const names = cfg.enums.navigationState;
    const colorOf = (code) => stateColor(code, 0);
    const mapBox = h("div", { class: "map-box", id: "lawnmower-map" });
    const legend = h("div", { class: "legend" }, Object.entries(names).map(([code, name]) =>
      h("span", {}, h("i", { style: `background:${colorOf(Number(code))}` }), name)));
    const bandsBox = h("div", { id: "lawnmower-states" });
    const obstacleBox = h("div", { class: "chart", id: "lawnmower-obstacle" });
    const speedBox = h("div", { class: "chart", id: "lawnmower-speed" });
    box.append(h("p", { class: "muted" }, `${cfg.entity} · tenant ${cfg.service}${cfg.servicePath} · ${stamp(xRange[0])} → ${stamp(xRange[1])}`),
      h("div", { class: "grid" },
        panel("Path in the garden", "coloured by navigation state", mapBox, legend),
        panel("Navigation", "state, sub-state and perimeter coils", bandsBox)),
      h("div", { class: "grid" },
        panel("Obstacle distance", "ultrasound, m", obstacleBox),
        panel("Speed", "odometry: forward m/s and yaw rate rad/s", speedBox)));
    const last = positions[positions.length - 1];
    mapChart(mapBox, {
      rings: [{ coords: cfg.garden.map(([lat, lon]) => [lon, lat]), stroke: "#2ca02c", title: "border wire" }],
      paths: [{ coords: lonLat(positions), colors: positions.map((r) => colorOf(r.state)), width: 1.4 }],
      markers: [{ lon: cfg.garden[0][1], lat: cfg.garden[0][0], r: 5, color: "#333", label: "dock", cls: "marker dock" }]
        .concat(last ? [{ lon: last.lon, lat: last.lat, r: 6, color: "#d62728", label: "mower", cls: "marker latest",
          title: `${names[String(last.state)] || last.state} at ${stamp(Date.parse(last.time))}` }] : []),
    });
    stateBands(bandsBox, { rows: states, xRange, bands: [
      { key: "nav", label: "navigationState", names },
      { key: "sub", label: "navigationSubState", names: cfg.enums.navigationSubState },
      { key: "left", label: "perimeterLeft" }, { key: "right", label: "perimeterRight" }] });
    const data = toColumns(series, ["obstacle", "speed", "yawRate"]);
    const col = (key) => valuesOf(data, key);
    lineChart(obstacleBox, { xs: data.xs, xRange, series: [{ label: "obstacle distance (m)", values: col("obstacle") }] });
    lineChart(speedBox, { xs: data.xs, xRange, series: [{ label: "linear x (m/s)", values: col("speed") },
      { label: "angular z (rad/s)", values: col("yawRate") }] });
  }

  // -- use case: PIAP warehouse -----------------------------------------------------------------------

  async function viewWarehouse(box, params, stale) {
    const cfg = (await useCases()).warehouse;
    const scope = scopeOf(cfg.service, cfg.servicePath);
    const sel = { ...scope, id: cfg.entity };
    const newest = await newestOf(sel, "doorState");
    if (newest === null) return noData(box, cfg);
    const win = timeWindow(newest, "warehouse");
    const [states, laser, robot, env] = await Promise.all([
      api("grafana/infinity/states", { ...sel, ...win,
        attrs: "door=doorState(data),command=doorCommand(data),light=warningLight(data),lightCommand=warningLightCommand(data)" }),
      api("grafana/infinity/series", { ...sel, ...win, attrs: "laser=laserDistance(range)", max_points: 2400 }),
      api("grafana/infinity/series", { ...scope, ...win, id: cfg.robot, attrs: "x=odom(pose.pose.position.x)", max_points: 1200 }),
      api("grafana/infinity/series", { ...sel, ...win, attrs: "temperature=temperature(data),humidity=humidity(data)", max_points: 600 }),
    ]);
    if (stale()) return;
    const xRange = xRangeOf(win, states, laser);
    const openings = states.filter((r, i) => r.door === 1 && (i === 0 || states[i - 1].door !== 1)).length;
    const laserBox = h("div", { class: "chart", id: "warehouse-laser" });
    const bandsBox = h("div", { id: "warehouse-states" });
    const robotBox = h("div", { class: "chart", id: "warehouse-robot" });
    const envBox = h("div", { class: "chart", id: "warehouse-env" });
    box.append(h("p", { class: "muted" }, `${cfg.entity} · tenant ${cfg.service}${cfg.servicePath} · ${stamp(xRange[0])} → ${stamp(xRange[1])} · ` +
      `door opened ${openings} times`),
      panel("Laser distance at the door", `m; the door opens below ${cfg.doorOpenDistanceM} m`, laserBox),
      panel("Door and warning light", "state changes", bandsBox),
      h("div", { class: "grid" },
        panel("Robot position", `${cfg.robot}: odometry x, m (door at 0)`, robotBox),
        panel("Environment", "temperature °C, humidity %", envBox)));
    const l = toColumns(laser, ["laser"]);
    lineChart(laserBox, { xs: l.xs, xRange, height: 200, series: [
      { label: "laser distance (m)", values: valuesOf(l, "laser") },
      { label: `opening threshold ${cfg.doorOpenDistanceM} m`, values: l.xs.map(() => cfg.doorOpenDistanceM), color: "#d62728", dash: [6, 4], width: 1 }] });
    stateBands(bandsBox, { rows: states, xRange, bands: [
      { key: "door", label: "doorState", names: cfg.enums.doorState },
      { key: "command", label: "doorCommand", names: cfg.enums.doorCommand },
      { key: "light", label: "warningLight", names: cfg.enums.warningLight },
      { key: "lightCommand", label: "warningLightCommand", names: cfg.enums.warningLightCommand }] });
    const r = toColumns(robot, ["x"]);
    lineChart(robotBox, { xs: r.xs, xRange, series: [{ label: "x (m)", values: valuesOf(r, "x") }] });
    const e = toColumns(env, ["temperature", "humidity"]);
    lineChart(envBox, { xs: e.xs, xRange, series: e.columns.map((c) => ({ label: c.key, values: c.values })) });
  }

  // -- use case: eProsima drone ----------------------------------------------------------------------

  async function viewDrone(box, params, stale) {
    const cfg = (await useCases()).drone;
    const scope = scopeOf(cfg.service, cfg.servicePath);
    const drone = { ...scope, id: cfg.entity };
    const newest = await newestOf(drone, "missionState");
    if (newest === null) return noData(box, cfg);
    const win = timeWindow(newest, "drone");
    const sensors = { ...scope, type: cfg.sensorType };
    const [route, placed, missions, readings, flight] = await Promise.all([
      api("grafana/infinity/positions", { ...drone, ...win, attrs: "state=missionState(data)", max_points: 5000 }),
      api("grafana/infinity/positions", { ...sensors, latest: "true", attrs: "priority,temperature,humidity" }),
      api("grafana/infinity/states", { ...drone, ...win, attrs: "state=missionState(data),target=missionTarget(data)" }),
      api("grafana/infinity/series", { ...sensors, ...win, attrs: "temperature,humidity", max_points: 1000 }),
      api("grafana/infinity/series", { ...drone, ...win, attrs: "altitude=altitude(data),battery=battery(data)", max_points: 2000 }),
    ]);
    if (stale()) return;
    const xRange = xRangeOf(win, route, missions);
    const names = cfg.enums.missionState;
    const targetNames = Object.fromEntries([["0", "none"]].concat(cfg.sensors.map((one, i) => [String(i + 1), shortName(one.id)])));
    const readingCode = Number(Object.keys(names).find((k) => names[k] === "reading sensor"));
    const visits = new Array(cfg.sensors.length + 1).fill(0); // by missionTarget (1-based)
    missions.forEach((row, i) => {
      if (row.state === readingCode && (i === 0 || missions[i - 1].state !== readingCode) && row.target > 0) visits[row.target] += 1;
    });
    const totalVisits = visits.reduce((a, b) => a + b, 0);
    const mapBox = h("div", { class: "map-box", id: "drone-map" });
    const bandsBox = h("div", { id: "drone-states" });
    const tempBox = h("div", { class: "chart", id: "drone-temperature" });
    const humBox = h("div", { class: "chart", id: "drone-humidity" });
    const flightBox = h("div", { class: "chart", id: "drone-flight" });
    box.append(h("p", { class: "muted" }, `${cfg.entity} and ${cfg.sensors.length} sensors · tenant ${cfg.service}${cfg.servicePath} · ` +
      `${stamp(xRange[0])} → ${stamp(xRange[1])} · ${totalVisits} sensor visits`),
      h("div", { class: "grid" },
        panel("Route and sensors", "marker size: mission priority", mapBox, h("div", { class: "legend" },
          Object.entries(names).map(([code, name]) => h("span", {}, h("i", { style: `background:${stateColor(Number(code), 0)}` }), name)))),
        panel("Sensors and mission priorities", "visits counted from missionState / missionTarget",
          sensorTable(cfg, placed, visits, totalVisits))),
      panel("Missions", "missionState", bandsBox),
      h("div", { class: "grid" },
        panel("Sensor temperature", "°C, one reading per visit", tempBox),
        panel("Sensor humidity", "%", humBox)),
      panel("Flight", "altitude m, battery %", flightBox));
    const byId = new Map(placed.map((p) => [p.entity, p]));
    mapChart(mapBox, {
      height: 460,
      rings: [{ coords: cfg.field.map(([lat, lon]) => [lon, lat]), stroke: "#2ca02c", title: "sensor field" }],
      paths: [{ coords: lonLat(route), colors: route.map((r) => stateColor(r.state, 0)), width: 1 }],
      markers: [{ lon: cfg.home[1], lat: cfg.home[0], r: 6, color: "#333", label: "home", cls: "marker home" }].concat(
        cfg.sensors.map((sensor, i) => {
          const seen = byId.get(sensor.id) || {};
          const priority = seen.priority !== undefined && seen.priority !== null ? seen.priority : sensor.priority;
          return { lon: seen.lon !== undefined ? seen.lon : sensor.lon, lat: seen.lat !== undefined ? seen.lat : sensor.lat,
            r: 4 + 40 * priority, color: stateColor(i + 1, 0), cls: "marker sensor", // as missionTarget
            label: `${shortName(sensor.id)} ${priority.toFixed(3)}`,
            title: `${sensor.id}\npriority ${priority}\nvisits ${visits[i + 1]}\ntemperature ${seen.temperature} °C\nhumidity ${seen.humidity} %` };
        })),
    });
    stateBands(bandsBox, { rows: missions, xRange, bands: [{ key: "state", label: "missionState", names }, { key: "target", label: "missionTarget", names: targetNames }] });
    const t = toColumns(readings, ["temperature", "humidity"]);
    const order = (c) => cfg.sensors.findIndex((one) => one.id === c.entity);
    const perSensor = (key) => t.columns.filter((c) => c.key === key).sort((a, b) => order(a) - order(b)).map((c) =>
      ({ label: shortName(c.entity), values: c.values, points: true, color: stateColor(order(c) + 1, 0) }));
    lineChart(tempBox, { xs: t.xs, xRange, series: perSensor("temperature") });
    lineChart(humBox, { xs: t.xs, xRange, series: perSensor("humidity") });
    const f = toColumns(flight, ["altitude", "battery"]);
    lineChart(flightBox, { xs: f.xs, xRange, series: f.columns.map((c) => ({ label: c.key, values: c.values })) });
  }

  const shortName = (id) => id.replace(/:+$/, "").split(":").pop() || id;

  function sensorTable(cfg, placed, visits, total) {
    const byId = new Map(placed.map((p) => [p.entity, p]));
    const fmt = (v, digits) => (typeof v === "number" ? v.toFixed(digits) : "");
    const priorityOf = (sensor) => { const seen = byId.get(sensor.id) || {}; return typeof seen.priority === "number" ? seen.priority : sensor.priority; };
    const widest = Math.max(...cfg.sensors.map((sensor, i) => Math.max(priorityOf(sensor), total ? visits[i + 1] / total : 0)), 1e-9);
    const pct = (v) => `${((v / widest) * 100).toFixed(1)}%`; // of the cell: the table never outgrows its card
    return h("table", { id: "drone-sensors", class: "fit" },
      h("tr", {}, h("th", {}, "sensor"), h("th", { class: "num" }, "priority"), h("th", { class: "num" }, "visits"),
        h("th", { class: "bars" }, "share of visits vs priority"), h("th", { class: "num" }, "°C"), h("th", { class: "num" }, "%"), h("th", {}, "last reading")),
      cfg.sensors.map((sensor, i) => {
        const seen = byId.get(sensor.id) || {};
        const priority = priorityOf(sensor);
        const share = total ? visits[i + 1] / total : 0;
        return h("tr", { class: "sensor-row", "data-sensor": sensor.id },
          h("td", { class: "nowrap" }, h("i", { class: "swatch", style: `background:${stateColor(i + 1, 0)}` }), shortName(sensor.id)),
          h("td", { class: "num" }, fmt(priority, 3)), h("td", { class: "num" }, visits[i + 1]),
          h("td", { class: "bars" }, h("span", { class: "bar", style: `width:${pct(share)}`, title: `share ${(share * 100).toFixed(1)} %` }),
            h("span", { class: "bar expected", style: `width:${pct(priority)}`, title: `priority ${priority}` })),
          h("td", { class: "num" }, fmt(seen.temperature, 2)), h("td", { class: "num" }, fmt(seen.humidity, 1)),
          h("td", { class: "nowrap", title: seen.time ? stamp(Date.parse(seen.time)) : "" }, seen.time ? clock(Date.parse(seen.time), true) : ""));
      }),
      h("tr", {}, h("td", { colspan: 7, class: "caption" }, "Bars: blue = share of visits in this range, gold = mission priority.")));
  }

  // -- the Grafana dashboards ----------------------------------------------------------------------

  const INFINITY = "yesoreyeram-infinity-datasource";
  const code = (text) => h("code", {}, text);
  const pre = (text) => h("pre", {}, h("code", {}, text));

  /** Every shipped dashboard (GET /dashboards): what it shows, its JSON, and how to import it. */
  async function viewDashboards(box) {
    const list = await api("dashboards");
    const serviceUrl = h("input", { id: "service-url", type: "url", size: 36, spellcheck: "false",
      value: ROOT.href.replace(/\/$/, ""), "aria-label": "this service's URL as Grafana reaches it" });
    const yaml = h("a", { id: "datasources-yaml", download: "tsdb-service-datasources.yaml" }, "datasources.yaml");
    const pointYaml = () => {
      const url = serviceUrl.value.trim();
      const ok = /^https?:\/\/[^\s/?#@]+(\/[^\s?#]*)?$/.test(url);
      serviceUrl.classList.toggle("invalid", !ok);
      yaml.href = new URL(`dashboards/provisioning/datasources.yaml?url=${encodeURIComponent(ok ? url : "")}`, ROOT).href;
    };
    serviceUrl.addEventListener("input", pointYaml);
    pointYaml();
    const uids = [...new Set(list.flatMap((d) => d.datasources.map((ds) => ds.uid)))];
    box.append(
      h("p", { class: "muted" }, `${list.length} Grafana dashboards ship with tsdb-service: one per use case, the drone ` +
        "again through the NGSI-LD temporal API, and one for the service itself. Each is plain dashboard JSON " +
        "(schemaVersion 42, Grafana 12), served by this service."),
      h("div", { class: "grid", id: "dashboards" }, list.map(dashboardCard)),
      panel("Import them into Grafana", null, h("ol", { class: "steps" },
        h("li", {}, h("b", {}, "Install the Infinity plugin"), " (the use-case dashboards read this service through it): ",
          code(`grafana cli plugins install ${INFINITY}`), " and restart Grafana; with Docker, set ",
          code(`GF_PLUGINS_PREINSTALL=${INFINITY}`), "."),
        h("li", {}, h("b", {}, "Create the datasources. "), "The dashboards refer to them by uid (",
          uids.map((uid, i) => [i ? ", " : "", code(uid)]), "), which Grafana's ", h("i", {}, "Add data source"),
          " form cannot set, so provision them. Grafana reaches this service at ", serviceUrl,
          " (in a Compose file next to Grafana: ", code("http://tsdb-service:8668"), "). Download ", yaml,
          ": one Infinity datasource per use case, sending its tenant as the ", code("Fiware-Service"), " and ",
          code("Fiware-ServicePath"), " headers, and a Prometheus one for the service dashboard (change its ",
          code("url"), " to your Prometheus). Put it in Grafana's provisioning folder and restart Grafana:",
          pre("cp tsdb-service-datasources.yaml /etc/grafana/provisioning/datasources/tsdb-service.yaml"),
          "With Docker, mount it there instead."),
        h("li", {}, h("b", {}, "Import a dashboard: "), "in Grafana, ", h("i", {}, "Dashboards → New → Import"),
          "; upload the file ", h("i", {}, "Download"), " saved (or paste what ", h("i", {}, "Copy JSON"),
          " copied), pick a folder, ", h("i", {}, "Import"), "."),
        h("li", {}, h("b", {}, "Or load them all at every start: "), "put ",
          h("a", { href: new URL("dashboards/provisioning/dashboards.yaml", ROOT).href, download: "tsdb-service-dashboards.yaml" }, "dashboards.yaml"),
          " in ", code("/etc/grafana/provisioning/dashboards/"), " and the JSON files in ",
          code("/var/lib/grafana/dashboards/tsdb-service/"), ". The repository's ", code("dashboards/"),
          " folder holds them all, and its ", code("docker compose up"), " runs Grafana provisioned this way."))));
  }

  function dashboardCard(d) {
    const json = new URL(`dashboards/${encodeURIComponent(d.name)}.json`, ROOT).href;
    const copy = h("button", { type: "button", class: "copy" }, "Copy JSON");
    copy.addEventListener("click", () => copyText(json, copy));
    const kind = (type) => ({ [INFINITY]: "Infinity", prometheus: "Prometheus" })[type] || type;
    const reads = d.datasources.map((ds, i) => [i ? ", " : "", kind(ds.type), " ", code(ds.uid)]);
    return h("section", { class: "panel dashboard", "data-dashboard": d.name },
      h("h2", {}, d.title, h("small", {}, `${d.name}.json`)),
      h("p", {}, d.description),
      h("ul", { class: "sections" }, (d.sections || []).map((one) =>
        h("li", {}, one.title ? h("b", {}, `${one.title}: `) : null, one.panels.join(" · ")))),
      h("p", { class: "caption" }, "Datasource: ", reads, d.tags.length ? ` · tags: ${d.tags.join(", ")}` : ""),
      h("div", { class: "actions" },
        h("a", { class: "button json", href: json, target: "_blank", rel: "noopener" }, "Open JSON"),
        h("a", { class: "button download", href: json, download: `${d.name}.json` }, "Download"), copy));
  }

  /** Copy what ``url`` answers; the button says how it went. The clipboard API needs a secure
   * context (https or localhost) and may be refused: then a hidden text area and execCommand. */
  async function copyText(url, button) {
    const said = button.textContent;
    try {
      const resp = await fetch(url);
      if (!resp.ok) throw new Error(`HTTP ${resp.status}`);
      const text = await resp.text();
      const viaApi = window.isSecureContext && navigator.clipboard
        ? await navigator.clipboard.writeText(text).then(() => true, () => false) : false;
      if (!viaApi && !copyByCommand(text)) throw new Error("the browser refused to copy");
      button.textContent = "Copied";
    } catch (err) {
      button.textContent = "Copy failed: use Download";
      console.warn(err);
    }
    setTimeout(() => { button.textContent = said; }, 2500);
  }

  function copyByCommand(text) {
    const area = h("textarea", { class: "offscreen", readonly: true });
    area.value = text;
    document.body.append(area);
    area.select();
    const done = document.execCommand("copy");
    area.remove();
    return done;
  }

  // -- routing ----------------------------------------------------------------------------

  const VIEWS = { explore: viewExplore, lawnmower: viewLawnmower, warehouse: viewWarehouse, drone: viewDrone,
    dashboards: viewDashboards };
  const LOADING = { explore: "Loading the stored entities…", lawnmower: "Loading the lawnmower's data…",
    warehouse: "Loading the warehouse's data…", drone: "Loading the drone's data…", dashboards: "Loading the dashboards…" };

  /** The time range control: what "auto" means here, in its text and its tooltip; off where no time is shown. */
  function showRange(view) {
    rangeLabel.hidden = !AUTO[view];
    if (!AUTO[view]) return;
    rangeSelect.options[0].textContent = `auto (${AUTO[view].text})`;
    rangeLabel.title = AUTO_TIP;
  }

  async function route() {
    const mine = ++generation;
    const stale = () => mine !== generation;
    for (const chart of charts) chart.destroy();
    charts = [];
    delete document.body.dataset.ready;
    const [path, query] = location.hash.replace(/^#\/?/, "").split("?");
    const view = VIEWS[path] ? path : "explore";
    const params = Object.fromEntries(new URLSearchParams(query || ""));
    for (const link of document.querySelectorAll("header a[data-view]")) link.classList.toggle("active", link.dataset.view === view);
    showRange(view);
    const box = h("div", { class: "stack", id: `view-${view}` });
    const status = h("p", { id: "loading", role: "status" }, h("span", { class: "spinner" }), LOADING[view]);
    main.replaceChildren(box, status);
    document.body.dataset.loading = view;
    said = { buckets: new Set(), notices: [] };
    try {
      await VIEWS[view](box, params, stale);
      if (!stale()) {
        status.remove();
        const line = saidLine();
        const head = box.querySelector(":scope > p.muted");
        if (line && head) head.after(line);
        else if (line) box.prepend(line);
      }
    } catch (err) {
      if (!stale()) showError(status, err);
    }
    if (stale()) return;
    delete document.body.dataset.loading;
    window.explorerReady = { view, ms: performance.now() };
    document.body.dataset.ready = view;
  }

  window.addEventListener("hashchange", route);
  rangeSelect.addEventListener("change", route);
  route();
})();
