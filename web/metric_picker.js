// Which metrics (metrics.jsonl's columns) the curves draw, which come first (pinned), and which plots have
// a log y axis: the user's choices, kept in this browser (localStorage) and shared by a run's curves and
// Compare. The picker lists every metric the page has seen, with a text filter.
import { $, el } from "./api.js";

const STORE = "studio-curves";
// Columns that are the x axes or a row's bookkeeping, not metrics.
const NOT_METRICS = new Set(["iteration", "samples", "wall_time", "time", "output", "event", "nonfinite"]);
const strings = (v) => (Array.isArray(v) ? v.filter((x) => typeof x === "string") : []);
const prefs = load();
const known = new Set();
const listeners = [];
let byDefault = () => true;

// A stored value this page did not write (another version's, or edited by hand) counts as no choice.
function load() {
  let v = {};
  try { v = JSON.parse(localStorage.getItem(STORE) || "{}") || {}; } catch (e) { v = {}; }
  return { shown: new Set(strings(v.shown)), hidden: new Set(strings(v.hidden)), pinned: strings(v.pinned), log: new Set(strings(v.log)) };
}

function changed() {
  const { shown, hidden, pinned, log } = prefs;
  try {
    localStorage.setItem(STORE, JSON.stringify({ shown: [...shown], hidden: [...hidden], pinned, log: [...log] }));
  } catch (e) { /* storage full or off: the choice holds until the page reloads */ }
  renderList();
  listeners.forEach((fn) => fn());
}

export const onPrefsChange = (fn) => listeners.push(fn);
export const isMetric = (k) => !NOT_METRICS.has(k);
// A metric no one chose for or against is drawn when `byDefault` says so (it has a unit's plot).
export const isShown = (k) => prefs.shown.has(k) || (!prefs.hidden.has(k) && byDefault(k));
export const pinRank = (k) => { const i = prefs.pinned.indexOf(k); return i < 0 ? Infinity : i; };
export const logOn = (key) => prefs.log.has(key);
export const pinnedMetrics = () => prefs.pinned;

export function setLog(key, on) {
  if (on) prefs.log.add(key); else prefs.log.delete(key);
  changed();
}

function setShown(k, on) {
  prefs.shown.delete(k);
  prefs.hidden.delete(k);
  if (on !== byDefault(k)) (on ? prefs.shown : prefs.hidden).add(k);
  changed();
}

function togglePin(k) {
  const i = prefs.pinned.indexOf(k);
  if (i >= 0) prefs.pinned.splice(i, 1); else prefs.pinned.push(k);
  changed();
}

function reset() {
  prefs.shown.clear(); prefs.hidden.clear(); prefs.pinned.length = 0; prefs.log.clear();
  changed();
}

// `drawnByDefault(column)`: whether a metric nobody chose for is drawn.
export function initMetricPicker(drawnByDefault) {
  byDefault = drawnByDefault;
  $("metric-filter").addEventListener("input", renderList);
  $("metric-reset").addEventListener("click", reset);
  renderList();
}

// The columns of rows the page got: new metrics join the picker's list.
export function noteMetrics(keys) {
  const before = known.size;
  for (const k of keys) if (isMetric(k)) known.add(k);
  if (known.size !== before) renderList();
}

function renderList() {
  const filter = $("metric-filter").value.trim().toLowerCase();
  const all = [...known].sort((a, b) => pinRank(a) - pinRank(b) || a.localeCompare(b));
  const rows = all.filter((k) => k.toLowerCase().includes(filter)).map((k) => {
    const pinned = pinRank(k) < Infinity;
    const tick = el("input", { type: "checkbox", "data-metric-toggle": k, onchange: (ev) => setShown(k, ev.target.checked) });
    tick.checked = isShown(k);
    const pin = el("button", { "data-metric-pin": k, "aria-pressed": String(pinned), onclick: () => togglePin(k),
      title: pinned ? "unpin: its plot goes back to its place" : "pin: its plot comes first" }, pinned ? "unpin" : "pin");
    return el("div", { class: "metric-row" }, el("label", { class: "mono" }, tick, ` ${k}`), pin);
  });
  $("metric-list").replaceChildren(...rows);
  $("metric-count").textContent = `${all.filter(isShown).length} of ${all.length} drawn${prefs.pinned.length ? `, ${prefs.pinned.length} pinned` : ""}`;
}
