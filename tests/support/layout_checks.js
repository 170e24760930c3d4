/* Layout checks the explorer's browser test runs in the page (tests/test_ui_browser.py).
 * Each returns a list of problems, empty when the page is right. */
"use strict";

/** Labels of the SVGs matching ``selector``: inside their frame, on no other label, on no marker. */
function mapLabelProblems(selector) {
const problems = [];
const hit = (a, b) => Math.max(0, Math.min(a.right, b.right) - Math.max(a.left, b.left)) *
  Math.max(0, Math.min(a.bottom, b.bottom) - Math.max(a.top, b.top));
for (const svg of document.querySelectorAll(selector)) {
  const frame = svg.getBoundingClientRect();
  const labels = [...svg.querySelectorAll("text.label, text.grat-label")].map((t) => [t.textContent, t.getBoundingClientRect()]);
  const circles = [...svg.querySelectorAll("circle")].map((c) => c.getBoundingClientRect());
  for (const [text, r] of labels) {
    if (r.left < frame.left - 0.5 || r.right > frame.right + 0.5 || r.top < frame.top - 0.5 || r.bottom > frame.bottom + 0.5)
      problems.push(`${svg.parentElement.id || svg.parentElement.dataset.attr}: '${text}' is cut by the frame`);
  }
  labels.forEach(([a, ra], i) => labels.slice(i + 1).forEach(([b, rb]) => {
    if (hit(ra, rb) > 1) problems.push(`'${a}' overlaps '${b}'`);
  }));
  for (const [text, r] of labels) for (const c of circles) if (hit(r, c) > 2) problems.push(`'${text}' covers a marker`);
}
return problems;
}

/** Every drawn chart's time-axis tick labels, as uPlot rendered them and measured in its font:
 * [{name, u, labels: [{line, row, x (centre, px from the plot's left), w}]}]. A label may have
 * several lines (a date under some times), one entry each. */
function timeAxes() {
const ctx = document.createElement("canvas").getContext("2d");
return [...document.querySelectorAll(".chart")].filter((box) => box.uplot).map((box) => {
  const u = box.uplot, axis = u.axes[0], labels = [];
  ctx.font = axis.font[0];
  (axis._values || []).forEach((v, i) => String(v).split("\n").forEach((line, row) => {
    if (line) labels.push({ line, row, x: u.valToPos(axis._splits[i], "x"), w: ctx.measureText(line).width });
  }));
  return { name: box.id || box.dataset.attr, u, labels };
});
}

/** Tick labels of every chart's time axis and of every state timeline: none may reach into
 * the next (compared line by line). */
function timeLabelProblems() {
const problems = [];
for (const { name, labels } of timeAxes()) {
  const rows = [];
  for (const label of labels) (rows[label.row] = rows[label.row] || []).push(label);
  for (const row of rows) for (let i = 1; i < (row || []).length; i++) {
    const a = row[i - 1], b = row[i];
    if (b.x - a.x < (a.w + b.w) / 2 + 2) problems.push(`${name}: '${a.line}' and '${b.line}' overlap`);
  }
}
for (const axis of document.querySelectorAll(".bands .axis")) {
  const r = [...axis.querySelectorAll("text")].map((t) => [t.textContent, t.getBoundingClientRect()]);
  for (let i = 1; i < r.length; i++) if (r[i][1].left < r[i - 1][1].right + 2) problems.push(`timeline: '${r[i - 1][0]}' and '${r[i][0]}' overlap`);
}
return problems;
}

/** The drone's priority table: inside its card, no cell cut. */
function tableProblems() {
const table = document.getElementById("drone-sensors"), card = table.closest(".panel");
const problems = [];
if (table.getBoundingClientRect().right > card.getBoundingClientRect().right - 1) problems.push("the table leaves its card");
for (const cell of table.querySelectorAll("td, th"))
  if (cell.scrollWidth > cell.clientWidth + 1) problems.push(`'${cell.textContent}' is cut (${cell.scrollWidth} > ${cell.clientWidth})`);
return problems;
}

/** Time tick labels of every chart and state timeline: each inside its chart's box (the last
 * one was cut by the right edge). uPlot's labels are centred on their tick. */
function edgeLabelProblems() {
const problems = [];
for (const { name, u, labels } of timeAxes()) {
  const left = u.bbox.left / devicePixelRatio;
  for (const { line, x, w } of labels) {
    const from = left + x - w / 2, to = left + x + w / 2;
    if (to > u.width + 0.5 || from < -0.5) problems.push(`${name}: '${line}' is cut (${from.toFixed(1)} to ${to.toFixed(1)} of ${u.width})`);
  }
}
for (const svg of document.querySelectorAll("svg.bands")) {
  const frame = svg.getBoundingClientRect();
  for (const text of svg.querySelectorAll(".axis text")) {
    const r = text.getBoundingClientRect();
    if (r.right > frame.right + 0.5 || r.left < frame.left - 0.5) problems.push(`timeline: '${text.textContent}' is cut`);
  }
}
return problems;
}

/** Legend rows reading "Time: --" (or any value "--") while the cursor is on no chart. */
function idleLegendProblems() {
const problems = [];
for (const legend of document.querySelectorAll(".chart .u-legend")) {
  for (const row of legend.querySelectorAll("tr")) {
    if (row.offsetParent === null) continue; // not shown
    const text = row.innerText.replace(/\s+/g, " ").trim();
    if (/--/.test(text) || /^Time\b/.test(text)) problems.push(`${legend.closest(".chart").id || legend.closest(".chart").dataset.attr}: '${text}'`);
  }
}
return problems;
}
