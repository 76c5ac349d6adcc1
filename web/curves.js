// The selected run's live curves (rows pushed by the stream) and the controls both curve views share:
// the x axis (samples, wall time, iteration), the smoothing weight, and the metrics picked and pinned
// (metric_picker.js). One unit per plot: a metric of no known unit gets a plot (an axis) of its own.
import { $, el } from "./api.js";
import { initMetricPicker, isMetric, isShown, logOn, noteMetrics, onPrefsChange, pinnedMetrics, setLog } from "./metric_picker.js";
import { CurvePlot } from "./plots.js";

export const X_LABELS = { samples: "samples", wall_time: "wall time (h)", iteration: "iteration" };
const GROUP_LABELS = {
  returns: "return", lengths: "episode length", falls: "share of test episodes that fell",
  pos_err: "position error (m, the paper's)", vel_err: "DoF velocity error (rad/s, the paper's)",
  rewards: "reward terms", losses: "losses",
};
export const GROUPS = Object.keys(GROUP_LABELS);  // the plots' order
export const view = { x: "samples", smoothing: 0, run: null };  // run: the selected run's id
const changeListeners = [];
export const onViewChange = (fn) => changeListeners.push(fn);

// Which plot a metrics column belongs on (null: not drawn), one unit per plot: "falls" the share of test
// episodes that ended in a fall (0–1), then the paper's tracking errors, the figures imitation is judged
// by, in metres and in rad/s (the reference code's own tracking columns stay in metrics.jsonl).
export const groupOf = (k) => (k === "train_return" || k === "test_return" ? "returns"
  : k.endsWith("episode_length") ? "lengths" : k === "test_fail_frac" ? "falls"
  : k === "tracking.paper_pos_err_m" ? "pos_err" : k === "tracking.paper_dof_vel_err" ? "vel_err"
  : k.startsWith("reward_terms.") ? "rewards" : k.includes("loss") ? "losses" : null);

// The plot a column is drawn on in a run's curves: its unit's, or its own. Also the key of its log choice.
export const plotKeyOf = (k) => groupOf(k) ?? k;

// Plots in order: the pinned metrics' first (in the order pinned), then the units' order, then by name.
// `key` is a plot key (a group) or a metric (Compare's plots).
const unitRank = (key) => { const i = GROUPS.indexOf(GROUPS.includes(key) ? key : groupOf(key)); return i < 0 ? GROUPS.length : i; };
const pinOf = (key) => { const i = pinnedMetrics().findIndex((m) => m === key || plotKeyOf(m) === key); return i < 0 ? Infinity : i; };
export const plotOrder = (a, b) => pinOf(a) - pinOf(b) || unitRank(a) - unitRank(b) || a.localeCompare(b);

export const xOf = (row) => row[view.x] ?? row.samples ?? row.iteration ?? 0;

// test_return is carried forward between test iterations: drawn only where the tests ran (`output`).
export const drawn = (row, k) => !(k.startsWith("test_") && row.output === false);

const plots = new Map(); // plot key -> CurvePlot: each unit's (index.html's boxes), and one per metric of no unit
const seen = new Map(); // plot key -> the metrics of the selected run drawn on it or unticked
let rows = [];
let divergedAt = null; // {iteration, samples} of the selected run, or null

// A plot with a "log" toggle whose choice is kept per plot key (a unit: the same in Compare).
export const logOptions = (key) => ({ log: logOn(key), onLog: (on) => setLog(key, on), nearest: true });

export function initCurves() {
  document.querySelectorAll("#curves .plot").forEach((c) => {
    const g = c.dataset.group;
    plots.set(g, new CurvePlot(c, { title: GROUP_LABELS[g], xLabel: X_LABELS[view.x], yLabel: GROUP_LABELS[g], ...logOptions(g) }));
  });
  initMetricPicker((k) => groupOf(k) !== null);
  onPrefsChange(() => { for (const [key, p] of plots) p.setLog(logOn(key)); redraw(); });
  $("x-axis").addEventListener("change", (ev) => { view.x = ev.target.value; changed(); });
  $("smoothing").addEventListener("input", (ev) => { view.smoothing = Number(ev.target.value); changed(); });
}

function changed() {
  $("smoothing-value").textContent = view.smoothing.toFixed(2);
  for (const p of plots.values()) p.setXLabel(X_LABELS[view.x]);
  redraw();
  changeListeners.forEach((fn) => fn());
}

// The run whose curves are shown (null: none): what the CSV button downloads.
export function setCurvesRun(id) {
  view.run = id;
  changeListeners.forEach((fn) => fn());
}

export function clearCurves() {
  rows = [];
  divergedAt = null;
  redraw();
}

export function addRows(newRows, reset) {
  if (reset) { rows = newRows.slice(); redraw(); return; }
  rows.push(...newRows);
  for (const r of newRows) noteMetrics(Object.keys(r));
  const all = [...plots.values()], before = plots.size;
  fillPlots(newRows, plotFor, (k) => k, all);  // only the new rows: a long run has many
  if (plots.size !== before) { redraw(); return; }  // a new metric's plot: the earlier resumes on it too
  arrange();
  for (const p of all) p.draw();
}

// The plot of a picked metric (a metric of no unit gets one of its own, made when first drawn).
function plotFor(k) {
  if (!isMetric(k)) return null;
  const key = plotKeyOf(k);
  if (!seen.has(key)) seen.set(key, new Set());
  seen.get(key).add(k);
  if (!isShown(k)) return null;
  if (!plots.has(key)) {
    const box = el("div", { class: "plot", "data-metric": k });
    $("curves").append(box);
    plots.set(key, new CurvePlot(box, { title: k, xLabel: X_LABELS[view.x], yLabel: k, ...logOptions(key) }));
  }
  return plots.get(key);
}

// Pinned plots first; a plot whose metrics are all unticked is hidden, as is a metric's own plot that
// the shown run does not have (an empty unit's plot stays: its place tells what the run lacks).
function arrange() {
  const box = $("curves"), order = [...plots.keys()].sort(plotOrder);
  order.forEach((key, i) => { const b = plots.get(key).box; if (box.children[i] !== b) box.insertBefore(b, box.children[i] || null); });
  for (const [key, p] of plots) p.box.hidden = seen.has(key) ? ![...seen.get(key)].some(isShown) : !GROUPS.includes(key);
}

export function setDiverged(at) {
  const key = JSON.stringify(at);
  if (key === JSON.stringify(divergedAt)) return;
  divergedAt = at;
  redraw();
}

function redraw() {
  seen.clear();
  for (const r of rows) {  // every plot first, so that each gets the resume markers of all rows
    noteMetrics(Object.keys(r));
    for (const [k, v] of Object.entries(r)) if (typeof v === "number" || (r.nonfinite && k in r.nonfinite)) plotFor(k);
  }
  const all = [...plots.values()];
  for (const p of all) { p.clear(); p.smoothing = view.smoothing; }
  fillPlots(rows, plotFor, (k) => k, all);
  markDivergence(rows, divergedAt, all);
  arrange();
  for (const p of all) p.draw();
}

// Where a run diverged ({iteration, samples} from its state.json): at the x of the last row up to that
// iteration, on whichever x axis is shown.
export function markDivergence(rowList, at, plotList, label = "") {
  if (!at) return;
  const before = rowList.filter((r) => !r.event && r.iteration <= at.iteration).pop();
  const x = view.x === "iteration" ? at.iteration : before ? xOf(before) : view.x === "samples" ? at.samples : null;
  if (x !== null) for (const p of plotList) p.addMarker(x, `${label}diverged`, "diverged");
}

// Rows onto plots: `plotFor(column)` picks the plot, `nameFor(column)` the series name; a resume
// marker goes on every plot of `markerPlots`. A row is one iteration or a marker ({"event": "resume"});
// a non-finite value arrives as null named in `nonfinite`.
export function fillPlots(rowList, plotFor, nameFor, markerPlots, label = "") {
  for (const row of rowList) {
    const x = xOf(row);
    if (row.event === "resume") {
      for (const p of markerPlots) p.addMarker(x, `${label}resume`);
      continue;
    }
    const bad = row.nonfinite || {};
    for (const [k, v] of Object.entries(row)) {
      const plot = plotFor(k);
      if (!plot || !drawn(row, k)) continue;
      if (k in bad) plot.markNonfinite(nameFor(k), x, bad[k]);
      else if (typeof v === "number") plot.add(nameFor(k), x, v);
    }
  }
}
