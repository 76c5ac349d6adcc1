// Compare runs: the runs ticked in the list, one plot per metric with one curve per run (same x axis and
// smoothing as the single-run curves), their resumes and divergences marked, and the settings (args.json,
// the configs as trained, the launch form's values) on which they differ.
import { $, api, el, withToken } from "./api.js";
import { CurvePlot, PALETTE } from "./plots.js";
import { X_LABELS, fillPlots, logOptions, markDivergence, onViewChange, plotKeyOf, plotOrder, view } from "./curves.js";
import { isMetric, isShown, noteMetrics, onPrefsChange } from "./metric_picker.js";

let shown = false;
let data = null; // {runs: [{id, name, status, diverged, rows}], diff}
let plots = new Map(); // metric -> CurvePlot

export const compareSelection = {
  ids: new Set(),
  toggle(id, on) { if (on) this.ids.add(id); else this.ids.delete(id); this.changed(); },
  delete(id) { this.ids.delete(id); },
  changed() {
    const n = this.ids.size, b = $("compare-button");
    b.disabled = n < 2;
    b.textContent = n ? `Compare ${n}` : "Compare";
    document.querySelectorAll("#run-list [data-compare]").forEach((c) => { c.checked = this.ids.has(Number(c.dataset.compare)); });
  },
};

export function initCompare() {
  $("compare-button").addEventListener("click", () => showCompare(true));
  $("csv-button").addEventListener("click", downloadCsv);
  onViewChange(() => { if (shown && data) render(); csvButton(); });
  onPrefsChange(() => { if (shown && data) render(); });
}

// The whole metrics.jsonl of the run shown (or of the runs compared) as CSV, from the server: the page
// holds only the rows it drew.
function downloadCsv() {
  const url = shown ? `/api/compare/metrics.csv?runs=${shownIds.join(",")}` : `/api/runs/${view.run}/metrics.csv`;
  el("a", { href: withToken(url), download: "" }).click();
}

let shownIds = [];
function csvButton() {
  const b = $("csv-button");
  b.disabled = shown ? shownIds.length === 0 : view.run === null;
  b.title = shown ? `download the metrics of runs ${shownIds.map((i) => `#${i}`).join(", ")} as one CSV (a run column first)`
    : "download the selected run's metrics.jsonl as CSV";
}

export async function showCompare(on) {
  shown = on;
  $("compare").hidden = !on;
  $("curves").hidden = on;
  const ids = [...compareSelection.ids].sort((a, b) => a - b);
  shownIds = ids;
  csvButton();
  if (!on) return;
  $("curves-title").textContent = `Compare · ${ids.map((i) => `#${i}`).join(", ")}`;
  $("compare-diff").textContent = "reading the runs…";
  try {
    const [info, ...rows] = await Promise.all([api("GET", `/api/compare?runs=${ids.join(",")}`),
      ...ids.map((i) => api("GET", `/api/runs/${i}/metrics`))]);
    data = { runs: info.runs.map((r, i) => ({ ...r, rows: rows[i] })), diff: info.diff };
  } catch (e) {
    $("compare-diff").textContent = `cannot compare: ${e.message}`;
    return;
  }
  if (shown) render();
}

// One plot per picked metric (pinned first), its log choice its unit's; the cursors of all move together
// and each legend gives every run's value nearest the cursor (uPlot's cursor sync and hover).
function render() {
  const metrics = new Set();
  for (const r of data.runs) {
    for (const row of r.rows) {
      noteMetrics(Object.keys(row));
      for (const [k, v] of Object.entries(row)) if (isMetric(k) && isShown(k) && (typeof v === "number" || row.nonfinite?.[k])) metrics.add(k);
    }
  }
  const order = [...metrics].sort(plotOrder);
  const box = $("compare-plots");
  for (const p of plots.values()) p.destroy();
  box.replaceChildren();
  plots = new Map();
  const colors = Object.fromEntries(data.runs.map((r, i) => [label(r), PALETTE[i % PALETTE.length]]));
  for (const m of order) {
    const div = el("div", { class: "plot", "data-metric": m });
    box.append(div);
    const p = new CurvePlot(div, { title: m, xLabel: X_LABELS[view.x], yLabel: m.replace("reward_terms.", ""), colors,
      ...logOptions(plotKeyOf(m)), sync: "compare" });
    p.smoothing = view.smoothing;
    plots.set(m, p);
  }
  const all = [...plots.values()];
  for (const r of data.runs) {
    fillPlots(r.rows, (k) => plots.get(k), () => label(r), all, `#${r.id} `);
    markDivergence(r.rows, r.diverged, all, `#${r.id} `);
  }
  all.forEach((p) => p.draw());
  renderDiff();
}

const label = (r) => `#${r.id} ${r.name}`;

function renderDiff() {
  const box = $("compare-diff");
  if (!data.diff.length) { box.textContent = "no differences in args.json, the configs or the launch settings"; return; }
  const show = (v) => (v === null || v === undefined ? "–" : typeof v === "object" ? JSON.stringify(v) : String(v));
  const head = el("tr", {}, el("th", {}, "setting"), ...data.runs.map((r) => el("th", {}, `#${r.id}`)));
  const rows = data.diff.map((d) => el("tr", {}, el("td", { class: "mono" }, d.key), ...d.values.map((v) => el("td", { class: "mono", title: show(v) }, show(v)))));
  box.replaceChildren(el("table", { class: "diff" }, head, ...rows));
}
