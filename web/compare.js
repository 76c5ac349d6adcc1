// Compare runs: the runs ticked in the list, one plot per metric with one curve per run (same x axis and
// smoothing as the single-run curves), their resumes and divergences marked, and the settings (args.json,
// the configs as trained, the launch form's values) on which they differ.
import { $, api, el } from "./api.js";
import { CurvePlot, PALETTE } from "./plots.js";
import { GROUPS, X_LABELS, fillPlots, groupOf, markDivergence, onViewChange, view } from "./curves.js";

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
  onViewChange(() => { if (shown && data) render(); });
}

export async function showCompare(on) {
  shown = on;
  $("compare").hidden = !on;
  $("curves").hidden = on;
  if (!on) return;
  const ids = [...compareSelection.ids].sort((a, b) => a - b);
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

function render() {
  const metrics = new Set();
  for (const r of data.runs) for (const row of r.rows) for (const k of Object.keys(row)) if (groupOf(k)) metrics.add(k);
  const order = [...metrics].sort((a, b) => rank(a) - rank(b) || a.localeCompare(b));
  const box = $("compare-plots");
  box.replaceChildren();
  plots = new Map();
  const colors = Object.fromEntries(data.runs.map((r, i) => [label(r), PALETTE[i % PALETTE.length]]));
  for (const m of order) {
    const div = el("div", { class: "plot", "data-metric": m });
    box.append(div);
    const p = new CurvePlot(div, { title: m, xLabel: X_LABELS[view.x], yLabel: m.replace("reward_terms.", ""), colors });
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
const rank = (k) => GROUPS.indexOf(groupOf(k));

function renderDiff() {
  const box = $("compare-diff");
  if (!data.diff.length) { box.textContent = "no differences in args.json, the configs or the launch settings"; return; }
  const show = (v) => (v === null || v === undefined ? "–" : typeof v === "object" ? JSON.stringify(v) : String(v));
  const head = el("tr", {}, el("th", {}, "setting"), ...data.runs.map((r) => el("th", {}, `#${r.id}`)));
  const rows = data.diff.map((d) => el("tr", {}, el("td", { class: "mono" }, d.key), ...d.values.map((v) => el("td", { class: "mono", title: show(v) }, show(v)))));
  box.replaceChildren(el("table", { class: "diff" }, head, ...rows));
}
