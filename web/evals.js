// The evals panel: `mimickit eval` of a checkpoint on each clip of a clip or dataset, run by the server
// as a background job. The job list is pushed by the stream (`evals` events) and updated in place; a
// finished job shows its table, and a click on a row rolls that clip out in the scene.
import { $, api, el } from "./api.js";
import { needsData } from "./checkpoints.js";
import { applyState } from "./player.js";

const ACTIVE = ["queued", "running"];
const COLUMNS = [  // [header, title, row -> text]
  ["clip", "the clip, as the dataset names it", (r) => r.clip.split("/").pop()],
  ["ep.", "episodes: exactly the number asked for (each env counts its first ones; see mimickit eval --help)", (r) => String(r.episodes)],
  ["length", "mean episode length (control steps)", (r) => fixed(r.mean_ep_len, 1)],
  ["full time", "time-weighted full length: the counted episodes' control steps / the steps they had available (to the time limit, or to the end of a clip that does not loop, whichever is first); a fall loses the rest of its episode, and an episode that starts just before a clip's end weighs only its few steps", (r) => (r.full_length_frac === null || r.full_length_frac === undefined ? "–" : `${(100 * r.full_length_frac).toFixed(0)}%`)],
  ["pos err", "position error (m) by the paper's formula (Table 1), mean over the counted episodes' steps", (r) => fixed(r.paper_pos_err_m, 3)],
  ["vel err", "DoF velocity error (rad/s) by the paper's formula, mean over the counted episodes' steps", (r) => fixed(r.paper_dof_vel_err, 3)],
];
const fixed = (v, d) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));
const short = (path, parts = 1) => path.split("/").slice(-parts).join("/");

// The form's checkpoint list, fetched again only when a run's checkpoint changed (the runs event says).
let checkpointsKey = null;
export function evalCheckpointsChanged(runs) {
  const key = JSON.stringify(runs.map((r) => [r.id, r.checkpoint, r.checkpoint_mtime ?? null]));
  if (key !== checkpointsKey) { checkpointsKey = key; refreshEvalCheckpoints(); }
}

async function refreshEvalCheckpoints() {
  let list;
  try { list = await api("GET", "/api/checkpoints"); } catch (e) { return; }
  const sel = $("eval-checkpoint"), keep = sel.value;
  const opts = list.map((c) => el("option", { value: c.path, title: c.path, "data-run": c.run_id ?? "" },
    `${c.run_id !== null ? `#${c.run_id} ${c.run_name} · ` : ""}${short(c.path, 2)}${c.has_configs ? "" : " (no configs beside: pick an arg file)"}${needsData(c)}`));
  sel.replaceChildren(...(opts.length ? opts : [el("option", { value: "" }, "(no checkpoints yet)")]));
  const playable = list.find((c) => !c.needs_data);  // the first pick is one that evaluates here
  if (keep && list.some((c) => c.path === keep)) sel.value = keep;
  else if (playable) sel.value = playable.path;
  $("eval-button").disabled = !list.length;
}

export function fillEvalForm(library) {
  const motion = $("eval-motion"), keepMotion = motion.value;
  motion.replaceChildren(el("option", { value: "" }, "(the env config's clip)"),
    ...library.configs.datasets.filter((d) => !d.error).map((d) => el("option", { value: d.path }, `dataset: ${d.name}`)),
    ...library.clips.filter((m) => !m.error).map((m) => el("option", { value: m.path }, m.path)));
  motion.value = keepMotion;
  const args = $("eval-arg-file"), keepArgs = args.value;
  args.replaceChildren(el("option", { value: "" }, "(the configs beside the checkpoint)"),
    ...library.configs.arg_files.filter((a) => !a.error).map((a) => el("option", { value: a.path, title: a.path }, a.name)));
  args.value = keepArgs;
}

// Start an eval: {run_id} or {checkpoint}, with arg_file, motion_file, episodes (the server checks them).
export async function startEval(body) {
  $("eval-error").textContent = "";
  try {
    await api("POST", "/api/evals", body);
    await refreshEvals();
  } catch (e) {
    $("eval-error").textContent = e.message;
  }
}

export function initEvals() {
  $("eval-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    const option = $("eval-checkpoint").selectedOptions[0];
    if (!option || !option.value) return;
    const runId = option.dataset.run, body = {};
    // A run's own model.pt goes by its run (the rollout of a row is then labelled with the run).
    if (runId && option.value.endsWith("/model.pt")) body.run_id = Number(runId);
    else body.checkpoint = option.value;
    if ($("eval-arg-file").value) body.arg_file = $("eval-arg-file").value;
    if ($("eval-motion").value) body.motion_file = $("eval-motion").value;
    if ($("eval-episodes").value) body.episodes = Number($("eval-episodes").value);
    startEval(body);
  });
}

// The job list, pushed by the stream when a job's status or rows changed: each job keeps its element,
// updated in place (a focused button keeps its focus); its table is built once, when it has finished.
const jobNodes = new Map();  // job id -> {node, job, key, fields}
let pushes = 0;  // how many job lists the stream has pushed

// The stream's `evals` event: the job list now.
export function renderEvals(jobs) {
  pushes += 1;
  drawEvals(jobs);
}

// The job list fetched at once after an action (the stream would bring it within a second). An answer
// that arrives after a push is older than it and is dropped: applied, it would put a finished job back
// to running, and no push would come to correct it.
async function refreshEvals() {
  const before = pushes;
  const jobs = await api("GET", "/api/evals");
  if (pushes === before) drawEvals(jobs);
}

function drawEvals(jobs) {
  const list = $("eval-list");
  const byId = new Map(jobs.map((j) => [j.id, j]));
  const nodes = [...byId.values()].sort((a, b) => b.id - a.id).map((job) => jobNode(job));
  const keep = new Set(nodes);
  for (const child of [...list.children]) if (!keep.has(child)) child.remove();
  nodes.forEach((n, i) => { if (list.children[i] !== n) list.insertBefore(n, list.children[i] || null); });
  for (const id of [...jobNodes.keys()]) if (!byId.has(id)) jobNodes.delete(id);
  $("eval-empty").hidden = jobs.length > 0;
}

function jobNode(job) {
  let entry = jobNodes.get(job.id);
  if (!entry) { entry = buildJobNode(job); jobNodes.set(job.id, entry); }
  entry.job = job;
  const key = JSON.stringify(job);
  if (key !== entry.key) { entry.key = key; updateJobNode(entry); }
  return entry.node;
}

function buildJobNode(job) {
  const entry = { job, key: null, fields: {} };
  const f = entry.fields;
  const act = (label, fn) => (f[label] = el("button", { "data-action": label.toLowerCase(), onclick: () => fn(entry.job) }, label));
  f.title = el("span", {});
  f.status = el("span", { "data-field": "status" });
  f.what = el("div", { class: "meta" });
  f.error = el("div", { class: "meta reason error", "data-field": "error" });
  f.table = el("div", { class: "eval-table" });
  entry.node = el("div", { class: "item eval", "data-eval-id": job.id },
    el("div", {}, f.title, " ", f.status), f.what, f.error, f.table,
    el("div", { class: "actions" }, act("Stop", (j) => jobAction(j, "POST", "stop")), act("Delete", (j) => jobAction(j, "DELETE"))));
  return entry;
}

function updateJobNode({ job, fields: f }) {
  const set = (e, text) => { if (e.textContent !== text) e.textContent = text; };
  set(f.title, `#${job.id} ${job.run_id !== null ? `run #${job.run_id}` : short(job.checkpoint, 2)}`);
  f.title.title = job.checkpoint;
  set(f.status, job.status);
  f.status.className = `status ${job.status}`;
  const took = job.started_at && job.ended_at ? ` · ${(job.ended_at - job.started_at).toFixed(1)} s` : "";
  set(f.what, `${job.motion_file ? short(job.motion_file) : "the env config's clip"} · ${job.episodes} episode${job.episodes === 1 ? "" : "s"} per clip${took}`);
  set(f.error, job.error || "");
  f.error.hidden = !job.error;
  f.Stop.hidden = !ACTIVE.includes(job.status);
  f.Delete.hidden = ACTIVE.includes(job.status);
  if (job.status === "finished" && !f.table.firstChild) f.table.append(resultTable(job));
  if (job.status !== "finished") f.table.replaceChildren();
}

// One row per clip (a click rolls it out) and the mean row (the rows pooled, as `mimickit eval` gives it).
function resultTable(job) {
  const head = el("tr", {}, ...COLUMNS.map(([h, title]) => el("th", { title }, h)));
  const rows = job.rows.map((r, i) => el("tr", { class: "eval-row", "data-row": i, title: `roll out ${r.clip}`, onclick: (ev) => rollOutRow(job.id, i, ev.currentTarget) },
    ...COLUMNS.map(([h, , text], c) => el("td", {}, c === 0 ? el("button", { class: "link" }, text(r)) : text(r)))));
  const table = el("table", { class: "diff evals" }, el("thead", {}, head), el("tbody", {}, ...rows));
  if (job.mean && job.rows.length > 1) {
    const mean = { ...job.mean, clip: `mean of ${job.mean.clips}` };
    table.append(el("tfoot", {}, el("tr", {}, ...COLUMNS.map(([, , text]) => el("td", {}, text(mean))))));
  }
  return table;
}

async function rollOutRow(jobId, row, tr) {
  $("eval-error").textContent = "";
  document.querySelectorAll("#eval-list tr.selected").forEach((e) => e.classList.remove("selected"));
  tr.classList.add("selected");
  $("eval-note").textContent = "building the rollout (env, policy, checkpoint)…";
  try {
    applyState(await api("POST", `/api/evals/${jobId}/rollout`, { row }));
    $("eval-note").textContent = "";
  } catch (e) {
    $("eval-note").textContent = "";
    $("eval-error").textContent = e.message;
  }
}

async function jobAction(job, method, action) {
  if (method === "DELETE" && !confirm(`Delete eval #${job.id} and its folder ${job.folder}?`)) return;
  try {
    await api(method, `/api/evals/${job.id}${action ? `/${action}` : ""}`, method === "POST" ? {} : undefined);
    await refreshEvals();
  } catch (e) {
    $("eval-error").textContent = e.message;
  }
}
