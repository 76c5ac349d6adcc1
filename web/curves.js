// The selected run's live curves (rows pushed by the stream) and the controls both curve views share:
// the x axis (samples, wall time, iteration) and the smoothing weight.
import { $ } from "./api.js";
import { CurvePlot } from "./plots.js";

export const X_LABELS = { samples: "samples", wall_time: "wall time (h)", iteration: "iteration" };
const GROUP_LABELS = {
  returns: "return", lengths: "episode length", falls: "share of test episodes that fell",
  pos_err: "position error (m, the paper's)", vel_err: "DoF velocity error (rad/s, the paper's)",
  rewards: "reward terms", losses: "losses",
};
export const GROUPS = Object.keys(GROUP_LABELS);  // the plots' order
export const view = { x: "samples", smoothing: 0 };
const changeListeners = [];
export const onViewChange = (fn) => changeListeners.push(fn);

// Which plot a metrics column belongs on (null: not drawn), one unit per plot: "falls" the share of test
// episodes that ended in a fall (0–1), then the paper's tracking errors, the figures imitation is judged
// by, in metres and in rad/s (the reference code's own tracking columns stay in metrics.jsonl).
export const groupOf = (k) => (k === "train_return" || k === "test_return" ? "returns"
  : k.endsWith("episode_length") ? "lengths" : k === "test_fail_frac" ? "falls"
  : k === "tracking.paper_pos_err_m" ? "pos_err" : k === "tracking.paper_dof_vel_err" ? "vel_err"
  : k.startsWith("reward_terms.") ? "rewards" : k.includes("loss") ? "losses" : null);

export const xOf = (row) => row[view.x] ?? row.samples ?? row.iteration ?? 0;

// test_return is carried forward between test iterations: drawn only where the tests ran (`output`).
export const drawn = (row, k) => !(k.startsWith("test_") && row.output === false);

const plots = {};
let rows = [];
let divergedAt = null; // {iteration, samples} of the selected run, or null

export function initCurves() {
  document.querySelectorAll("#curves .plot").forEach((c) => {
    const g = c.dataset.group;
    plots[g] = new CurvePlot(c, { title: GROUP_LABELS[g], xLabel: X_LABELS[view.x], yLabel: GROUP_LABELS[g] });
  });
  $("x-axis").addEventListener("change", (ev) => { view.x = ev.target.value; changed(); });
  $("smoothing").addEventListener("input", (ev) => { view.smoothing = Number(ev.target.value); changed(); });
}

function changed() {
  $("smoothing-value").textContent = view.smoothing.toFixed(2);
  for (const p of Object.values(plots)) p.setXLabel(X_LABELS[view.x]);
  redraw();
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
  const all = Object.values(plots);
  fillPlots(newRows, (k) => plots[groupOf(k)], (k) => k, all);  // only the new rows: a long run has many
  for (const p of all) p.draw();
}

export function setDiverged(at) {
  const key = JSON.stringify(at);
  if (key === JSON.stringify(divergedAt)) return;
  divergedAt = at;
  redraw();
}

function redraw() {
  for (const p of Object.values(plots)) { p.clear(); p.smoothing = view.smoothing; }
  const all = Object.values(plots);
  fillPlots(rows, (k) => plots[groupOf(k)], (k) => k, all);
  markDivergence(rows, divergedAt, all);
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
