// The runs panel: the launch form, the run list (pushed by the stream, updated in place) with each run's
// actions, its "compare" tick, tags and notes (run_labels.js, also the list's filter), the selected run's
// curves and console.
import { $, api, el } from "./api.js";
import { refreshCheckpoints, inspectCheckpoint } from "./checkpoints.js";
import { addRows, clearCurves, setCurvesRun, setDiverged } from "./curves.js";
import { compareSelection, showCompare } from "./compare.js";
import { startEval } from "./evals.js";
import { loadRollout } from "./player.js";
import { initRunFilter, labelParts, openLabels, runMatches, updateLabels } from "./run_labels.js";

let stream = null;
let selectedRun = null;
export const selectedRunId = () => selectedRun;

// The launch form's inputs come from GET /api/runs/fields (studio/runs/launch_fields.py, the one table of
// a launch's fields): each field's input with its help as its tooltip, fields of one row side by side; the
// submit reads them back by the same table. Fetched once (again after a failure, when the library reloads).
let launchFields = [];
let fieldsReady = null;
function launchFieldsReady() {
  if (!fieldsReady) {
    fieldsReady = api("GET", "/api/runs/fields").then(buildLaunchFields)
      .catch((e) => { fieldsReady = null; throw e; });
  }
  return fieldsReady;
}

function buildLaunchFields(fields) {
  const box = $("launch-fields"), rows = new Map();
  box.replaceChildren();
  for (const f of fields) {
    const label = f.widget.kind === "checkbox"  // a box before its text, as the page's other checkboxes
      ? el("label", {}, fieldInput(f), ` ${f.widget.label}`)
      : el("label", {}, `${f.widget.label} `, fieldInput(f));
    const row = f.widget.row;
    if (row && !rows.has(row)) box.append(rows.set(row, el("div", { class: "row" })).get(row));
    (row ? rows.get(row) : box).append(label);
  }
  launchFields = fields;
}

function fieldInput(f) {
  const w = f.widget, attrs = { id: w.id, title: f.help };
  if (f.required) attrs.required = "";
  if (w.kind === "select") return el("select", attrs, ...(f.required ? [] : [el("option", { value: "" }, w.placeholder)]));
  if (w.kind === "checkbox") return el("input", { ...attrs, type: "checkbox" });
  Object.assign(attrs, { type: w.kind, placeholder: w.placeholder });
  if (w.kind === "number") Object.assign(attrs, f.min === null ? {} : { min: f.min }, { step: w.step });
  return el("input", attrs);
}

// The body of POST /api/runs: each field that has a value (a required one always), a number as a number,
// a ticked box as true (an unticked one is left out, as the server takes false).
function launchBody() {
  const body = {};
  for (const f of launchFields) {
    if (f.widget.kind === "checkbox") { if ($(f.widget.id).checked) body[f.name] = true; continue; }
    const value = $(f.widget.id).value;
    if (value !== "" || f.required) body[f.name] = f.type === "string" ? value : Number(value);
  }
  return body;
}

const DEFAULT_ARG_FILE = "deepmimic_humanoid_demo_ppo_args";  // trains on the project's own clip: no MimicKit data needed
export async function fillLaunchForm(library) {
  try { await launchFieldsReady(); } catch (e) {
    $("launch-error").textContent = `cannot read the launch form's fields: ${e.message}`;
    return;
  }
  const argSel = $("arg-file"), keep = argSel.value;
  argSel.replaceChildren(...library.configs.arg_files.map((a) => el("option", { value: a.path, title: a.path }, a.name)));
  const demo = library.configs.arg_files.find((a) => a.name === DEFAULT_ARG_FILE);
  if (keep) argSel.value = keep;
  else if (demo) argSel.value = demo.path;
  argSel.onchange = clipsForArgFile;  // the select is built from the fields' table: set here, once per form
  shownLibrary = library;
  fillClips(library, null);
  clipsForArgFile();
  $("launch-button").disabled = library.configs.arg_files.length === 0;
  if (!library.configs.arg_files.length) $("launch-error").textContent = "no arg files found (args/*.txt)";
}

// The clip choices are the clips the arg file's character can play (values per frame: its DoF count; every
// clip until that is known). Datasets stay: their clips are checked when the run starts.
let shownLibrary = null;
function fillClips(library, frameDim) {
  const sel = $("motion-file"), keep = sel.value;
  const clips = library.clips.filter((m) => !m.error && (frameDim === null || m.frame_dim === frameDim));
  sel.replaceChildren(sel.options[0],
    ...library.configs.datasets.map((d) => el("option", { value: d.path }, `dataset: ${d.name}`)),
    ...clips.map((m) => el("option", { value: m.path }, m.path)));
  sel.value = [...sel.options].some((o) => o.value === keep) ? keep : "";
  sel.dataset.frameDim = frameDim ?? "";
}

async function clipsForArgFile() {
  const library = shownLibrary, path = $("arg-file").value;
  if (!library || !path) return;
  let frameDim = null;
  try {
    const char = (await api("GET", `/api/configs/file?path=${encodeURIComponent(path)}`)).trains?.char_file?.resolved;
    frameDim = library.characters.find((c) => c.path === char)?.frame_dim ?? null;
  } catch (e) { /* an arg file that does not read: every clip is offered; the launch says what is wrong */ }
  if (path === $("arg-file").value) fillClips(library, frameDim);  // not if another was picked meanwhile
}

export function initRuns(theStream) {
  stream = theStream;
  initRunFilter(filterRuns);
  launchFieldsReady().catch(() => {});  // fillLaunchForm says when it failed
  $("launch").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const body = launchBody();
    try {
      const values = sweepValues($("sweep-values").value);
      if ($("sweep-dataset").checked) {
        if (!body.motion_file || !body.motion_file.endsWith(".yaml")) throw new Error("sweep: choose a dataset as the clip to run one run per clip");
        body.dataset = body.motion_file;
        delete body.motion_file;
      }
      if (Object.keys(values).length || body.dataset) {
        const sweep = await api("POST", "/api/sweeps", { ...body, values });
        selectRun(sweep.runs[sweep.runs.length - 1].id);
      } else {
        selectRun((await api("POST", "/api/runs", body)).id);
      }
      $("launch-error").textContent = "";
      await refreshRuns();
    } catch (e) {
      $("launch-error").textContent = e.message;
    }
  });
}

// "rand_seed=0,1,2" a line -> {rand_seed: [0, 1, 2]}; numbers stay numbers, the server checks keys and values.
// "devices=cpu cpu" -> {devices: [["cpu", "cpu"]]}: one value of several devices, each its own argument.
export function sweepValues(text) {
  const values = {};
  text.split("\n").map((l) => l.trim()).filter(Boolean).forEach((line, i) => {
    const eq = line.indexOf("=");
    if (eq < 1) throw new Error(`sweep, line ${i + 1}: write key=value1,value2 (got "${line}")`);
    const key = line.slice(0, eq).trim().replace(/^--/, "");
    values[key] = line.slice(eq + 1).split(",").map((v) => v.trim()).filter((v) => v !== "")
      .map((v) => (key === "devices" ? v.split(/\s+/) : Number.isFinite(Number(v)) ? Number(v) : v));
  });
  return values;
}

// A sweep's runs, ticked together and compared.
function compareSweep(sweepId) {
  for (const { run } of runNodes.values()) compareSelection.toggle(run.id, run.sweep_id === sweepId);
  showCompare(true);
}

// After a user's action: the new list at once (the stream would bring it within a second). An answer
// that arrives after a push is older than it and is dropped: applied, it would show an ended run as
// running until the list changes again.
let pushes = 0;  // how many run lists the stream has pushed
async function refreshRuns() {
  const before = pushes;
  try {
    const runs = await api("GET", "/api/runs");
    if (pushes === before) drawRuns(runs);
  } catch (e) { /* the banner tells when the server is gone */ }
}

// The stream's `runs` event.
export function renderRuns(runs) {
  pushes += 1;
  drawRuns(runs);
}

// The run list, pushed by the stream when it changed: each run keeps its element, updated in place, so a
// focused button keeps its focus and a click in flight lands; the list is re-laid only when runs came
// or went. The checkpoint list is fetched again only when a run's checkpoint or status changed.
const runNodes = new Map();  // run id -> {node, run, key, fields}
let checkpointsKey = null;
function drawRuns(runs) {
  const list = $("run-list");
  const nodes = runs.slice().reverse().map((run) => runNode(run));
  // Insert and remove around the elements that stay: moving an element would take its focus away.
  const keep = new Set(nodes);
  for (const child of [...list.children]) if (!keep.has(child)) child.remove();
  nodes.forEach((n, i) => { if (list.children[i] !== n) list.insertBefore(n, list.children[i] || null); });
  for (const id of runNodes.keys()) if (!runs.some((r) => r.id === id)) { runNodes.delete(id); compareSelection.delete(id); }
  // The status too: a run's last int_models/ checkpoint is written just after its model.pt, so a fetch
  // between the two would miss it; the run's end fetches the list once more.
  const key = JSON.stringify(runs.map((r) => [r.id, r.status, r.checkpoint, r.checkpoint_mtime ?? null]));
  if (checkpointsKey !== null && key !== checkpointsKey) refreshCheckpoints();
  checkpointsKey = key;
  compareSelection.changed();
  filterRuns();
  const selected = runs.find((r) => r.id === selectedRun);
  if (selected && selected.status === "diverged") divergenceOf(selected.id);
}

// The filter applies to each list pushed, so a run that starts or ends keeps to it.
function filterRuns() {
  let n = 0;
  for (const { node, run } of runNodes.values()) { node.hidden = !runMatches(run); n += node.hidden ? 0 : 1; }
  $("run-filter-count").textContent = $("run-filter").value.trim() ? `${n} of ${runNodes.size}` : "";
}

let divergenceAsked = null;
async function divergenceOf(id) {
  if (divergenceAsked === id) return;
  divergenceAsked = id;
  try {
    const c = await api("GET", `/api/compare?runs=${id}`);
    if (selectedRun === id) setDiverged(c.runs[0].diverged);
  } catch (e) { divergenceAsked = null; }
}

const ENDED = ["finished", "stopped", "diverged", "failed", "interrupted"];
const num = (v) => (v === null || v === undefined ? "–" : Number(v).toLocaleString("en-US"));
const duration = (s) => (s === null || s === undefined ? "–" : s < 60 ? `${s.toFixed(0)} s` : s < 3600 ? `${(s / 60).toFixed(1)} min` : `${(s / 3600).toFixed(2)} h`);

function runNode(run) {
  let entry = runNodes.get(run.id);
  if (!entry) { entry = buildRunNode(run); runNodes.set(run.id, entry); }
  entry.run = run;
  const { duration_s, ...content } = run;  // GET /api/runs has the clock-driven duration; the stream does not
  const key = JSON.stringify(content);
  if (key !== entry.key) { entry.key = key; updateRunNode(entry); }
  return entry.node;
}

// One run's element; its buttons act on the run's latest record (entry.run).
function buildRunNode(run) {
  const entry = { run, key: null, fields: {} };
  const f = entry.fields;
  const field = (name) => (f[name] = el("span", { "data-field": name }));
  const act = (label, fn) => (f[label] = el("button", { "data-action": label.toLowerCase(), onclick: (ev) => { ev.stopPropagation(); fn(entry.run); } }, label));
  f.title = el("span", {});
  f.progress = el("progress", { "data-field": "progress" });
  f.reason = el("div", { class: "meta reason", "data-field": "reason" });
  f.resumes = el("span", {});
  labelParts(entry, refreshRuns);
  f.compare = el("input", { type: "checkbox", "data-compare": run.id, title: "compare this run with the others ticked",
    onclick: (ev) => ev.stopPropagation(),
    onchange: (ev) => compareSelection.toggle(run.id, ev.target.checked) });
  entry.node = el("div", { class: "item", "data-run-id": run.id, onclick: () => selectRun(run.id) },
    el("div", {}, el("label", { class: "compare-tick", onclick: (ev) => ev.stopPropagation() }, f.compare), f.title, " ", field("status"), " ", f.tags),
    f.notes,
    el("div", { class: "meta" }, field("clip"), " on ", field("char"), " · ", field("envs"), " · seed ", field("seed")),
    el("div", { class: "meta" }, f.progress, " ", field("samples")),
    el("div", { class: "meta" }, field("elapsed"), " · ", field("rate"), " · test return ", field("test-return"), " · falls ", field("test-falls"), f.resumes),
    el("div", { class: "meta" }, field("sweep")),
    f.reason,
    el("div", { class: "actions" },
      act("Stop", (r) => runAction(r, "stop")),
      act("Continue", (r) => continueRun(r)),
      act("Again", (r) => runAction(r, "again")),
      act("Rollout", (r) => loadRollout({ run_id: r.id })),
      act("Inspect", (r) => inspectCheckpoint(r.checkpoint)),
      act("Evaluate", (r) => startEval({ run_id: r.id })),
      act("Delete", (r) => deleteRun(r)),
      act("Compare sweep", (r) => compareSweep(r.sweep_id)),
      act("Stop sweep", (r) => stopSweep(r)),
      act("Tags", () => openLabels(entry))),
    f.editor);
  f.Tags.title = "tags (the list's filter finds them) and notes of this run";
  f["test-falls"].title = "share of the last test's episodes that ended in a fall (a clip that does not loop ends episodes early without one)";
  return entry;
}

// What the run's folder says (run.summary): what it trains, how far, at what rate, with which seed, how it ended.
function updateRunNode(entry) {
  const { run, node, fields: f } = entry;
  const s = run.summary || {};
  const active = ["running", "stopping", "queued"].includes(run.status);
  const ended = ENDED.includes(run.status);
  const set = (e, text) => { if (e.textContent !== text) e.textContent = text; };
  node.classList.toggle("selected", run.id === selectedRun);
  set(f.title, `#${run.id} ${run.name}`);
  set(f.status, run.status);
  f.status.className = `status ${run.status}`;
  set(f.clip, s.motion_file ? `${s.dataset ? "dataset " : ""}${s.motion_file.split("/").pop()}` : run.config.arg_file.split("/").pop());
  set(f.char, s.char_file ? s.char_file.split("/").pop() : "–");
  set(f.envs, `${num(s.num_envs ?? run.config.num_envs)} envs`);
  set(f.seed, num(s.seed));
  const budget = s.max_samples ?? run.config.max_samples ?? null;
  f.progress.max = budget || 1;
  if (budget) f.progress.value = Math.min(s.samples || 0, budget);
  else f.progress.removeAttribute("value");  // no budget: an indeterminate bar
  set(f.samples, `${num(s.samples)} / ${budget ? num(budget) : "no limit"} samples`);
  const hours = s.max_hours ?? run.config.max_hours ?? null;
  set(f.elapsed, hours ? `${duration(s.elapsed_s)} / ${hours} h` : duration(s.elapsed_s));
  set(f.rate, `${s.samples_per_s ? s.samples_per_s.toFixed(0) : "–"} samples/s`);
  set(f["test-return"], s.test_return !== null && s.test_return !== undefined ? s.test_return.toFixed(2) : "–");
  set(f["test-falls"], s.test_fail_frac !== null && s.test_fail_frac !== undefined ? `${Math.round(100 * s.test_fail_frac)}%` : "–");
  set(f.resumes, s.resumes ? ` · resumed ${s.resumes}×` : "");
  updateLabels(entry);
  set(f.reason, run.reason || "");
  f.reason.hidden = !run.reason;
  f.Stop.disabled = !(active && run.status !== "stopping");
  f.Continue.disabled = !(ended && !!run.checkpoint);
  f.Again.disabled = !(s.seed !== null && s.seed !== undefined);
  f.Rollout.disabled = !run.checkpoint;
  f.Inspect.disabled = !run.checkpoint;
  f.Evaluate.disabled = !run.checkpoint;
  f.Evaluate.title = "mimickit eval of this run's model.pt on its clip or dataset (the Evals panel)";
  f.Delete.disabled = active;
  set(f.sweep, run.sweep_id ? `sweep #${run.sweep_id}` : "");
  f.sweep.parentNode.hidden = !run.sweep_id;
  f["Compare sweep"].hidden = !run.sweep_id;
  f["Stop sweep"].hidden = !run.sweep_id;
  f["Stop sweep"].title = "stop every queued and running run of this sweep (queued ones never start)";
}

// A refused action's reason, in a line above the list: a modal alert would block the page (a reload
// while a request is in flight aborts it, and its alert would hold the navigation).
function showRunError(run, e) {
  $("run-error").textContent = e ? `run #${run.id}: ${e.message}` : "";
}

// POSTs carry a JSON body (the server refuses cross-site form posts).
async function runAction(run, action, body = {}) {
  let result = null;
  try {
    result = await api("POST", `/api/runs/${run.id}/${action}`, body);
    showRunError(run, null);
  } catch (e) { showRunError(run, e); }
  if (result && action === "resume") selectRun(run.id);
  if (result && action === "again") selectRun(result.id);
  refreshRuns();
}

// Every run of the run's sweep, in one request (POST /api/runs/stop).
async function stopSweep(run) {
  try {
    await api("POST", "/api/runs/stop", { sweep_id: run.sweep_id });
    showRunError(run, null);
  } catch (e) { showRunError(run, e); }
  refreshRuns();
}

// Continue: resume from the checkpoint with a budget (total samples, or hours as "2h"); a run that
// reached its budget needs a larger one.
function continueRun(run) {
  const s = run.summary || {};
  const budget = s.max_samples ?? run.config.max_samples ?? null, samples = s.samples;
  const hours = s.max_hours ?? run.config.max_hours ?? null, trainedH = (s.elapsed_s || 0) / 3600;
  const suggested = hours && trainedH >= hours ? `${2 * hours}h` : budget && samples >= budget ? 2 * budget : budget || "";
  const answer = prompt(`Continue run #${run.id} up to how many samples in all, or hours as "2h"? `
    + `(trained: ${num(samples)} samples, ${trainedH.toFixed(2)} h)`, String(suggested));
  if (answer === null) return;
  const text = answer.trim(), inHours = /h$/i.test(text);
  const value = Number(inHours ? text.slice(0, -1) : text);
  if (text && !(value > 0)) { showRunError(run, new Error(`not a budget: ${text}`)); return; }
  runAction(run, "resume", !text ? {} : inHours ? { max_hours: value } : { max_samples: value });
}

async function deleteRun(run) {
  if (!confirm(`Delete run #${run.id} "${run.name}" and its folder ${run.out_dir}?`)) return;
  try {
    await api("DELETE", `/api/runs/${run.id}`);
    showRunError(run, null);
  } catch (e) { showRunError(run, e); }
  if (selectedRun === run.id) {
    selectedRun = null;
    setCurvesRun(null);
    $("curves-title").textContent = "Curves";
    $("console").textContent = "";
    clearCurves();
    stream.open({});
  }
  refreshRuns();
}

// Live curves and console: the stream, subscribed to the selected run, pushes its metrics rows and log lines.
export function selectRun(id) {
  showCompare(false);
  if (id === selectedRun) return;
  selectedRun = id;
  setCurvesRun(id);
  divergenceAsked = null;
  clearCurves();
  $("console").textContent = "";
  $("curves-title").textContent = `Curves · run #${id}`;
  document.querySelectorAll("#run-list .item").forEach((e) => e.classList.toggle("selected", Number(e.dataset.runId) === id));
  const run = runNodes.get(id);
  if (run && run.run.status === "diverged") divergenceOf(id);
  stream.open({ run: id });
}

// {run, reset, start, rows}: the first batch of a connection has reset (the rows start again from 0).
export function addMetrics(m) {
  if (m.run !== selectedRun) return;
  addRows(m.rows, m.reset);
}

const CONSOLE_LINES = 200;
export function addLog(l) {  // {run, reset, lines}
  if (l.run !== selectedRun) return;
  const box = $("console");
  const stick = box.scrollTop + box.clientHeight >= box.scrollHeight - 4;  // follow the end unless scrolled up
  const lines = (l.reset || !box.textContent ? [] : box.textContent.split("\n")).concat(l.lines);
  box.textContent = lines.slice(-CONSOLE_LINES).join("\n");
  if (stick) box.scrollTop = box.scrollHeight;
}
