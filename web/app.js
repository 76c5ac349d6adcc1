// The dashboard: library, clip player controls (driving the server's player), runs and live curves.
// Commands go through the REST API; what changes (scene state, rollout history, runs, the selected run's
// metrics and log) is pushed by the server on one event stream (web/stream.js): no polling. The 3D
// scene is viser's page in the iframe.
"use strict";

// ---------------------------------------------------------------- API access (token when required)
const params = new URLSearchParams(location.search);
const TOKEN = params.get("token") || sessionStorage.getItem("studio-token") || "";
if (TOKEN) sessionStorage.setItem("studio-token", TOKEN);

async function api(method, path, body, raw = false) {
  // X-Studio-Request: the server refuses state-changing requests without it (or a JSON body), which
  // no cross-site form can send.
  const headers = TOKEN ? { "X-Studio-Token": TOKEN, "X-Studio-Request": "1" } : { "X-Studio-Request": "1" };
  const init = { method, headers };
  if (body instanceof Blob) { init.body = body; headers["Content-Type"] = "application/octet-stream"; }
  else if (body !== undefined) { init.body = JSON.stringify(body); headers["Content-Type"] = "application/json"; }
  const r = await fetch(path, init);
  if (raw) return r;
  const data = r.status === 204 ? null : await r.json();
  if (!r.ok) throw new Error((data && data.detail && (typeof data.detail === "string" ? data.detail : JSON.stringify(data.detail))) || r.statusText);
  return data;
}
const withToken = (url) => (TOKEN ? `${url}${url.includes("?") ? "&" : "?"}token=${encodeURIComponent(TOKEN)}` : url);
const $ = (id) => document.getElementById(id);
const el = (tag, attrs = {}, ...children) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) (k.startsWith("on") ? e.addEventListener(k.slice(2), v) : e.setAttribute(k, v));
  for (const c of children) e.append(c);
  return e;
};

// ---------------------------------------------------------------- start-up
let sceneUrl = null;
async function loadHealth() {
  const health = await api("GET", "/api/health");
  $("health").textContent = `runs: ${health.runs_dir} · data: ${health.data_dirs.join(", ")}`;
  sceneUrl = health.viser_port ? health.scene_url || "/scene/" : null;
}

// The scene is relayed by the studio itself (one port, one token check); the token's cookie lets
// viser's page open its websocket, which it does without the query string. `reload` (a new server
// after a restart): a fresh page, since viser's client would otherwise stay on the old, grey scene.
let sceneLoads = 0;
function showScene() {
  if (!sceneUrl) return;
  sceneLoads += 1;
  const url = withToken(sceneUrl);
  $("scene").src = sceneLoads === 1 ? url : `${url}${url.includes("?") ? "&" : "?"}reload=${sceneLoads}`;
}

async function init() {
  await loadHealth();
  showScene();
  await loadLibrary();
  refreshCheckpoints();
  stream.open({});
}

// ---------------------------------------------------------------- the live stream, and the banner when it breaks
let serverId = null;
const stream = new StudioStream({
  url: withToken,
  handlers: {
    scene: (s) => applyState(s),
    rollout: (h) => rolloutView.addRows(h),
    runs: (runs) => renderRuns(runs),
    metrics: (m) => addMetrics(m),
    log: (l) => addLog(l),
  },
  onDown: (attempt) => {
    $("banner").hidden = false;
    $("banner-detail").textContent = attempt > 1 ? `(attempt ${attempt})` : "";
  },
  onUp: async (hello, afterOutage) => {
    $("banner").hidden = true;
    const restarted = serverId !== null && hello.server !== serverId;
    serverId = hello.server;
    if (!afterOutage) return;
    // Back after an outage: the stream re-sent the scene, runs and the selected run's rows; fetch what
    // it does not carry (library, checkpoints) and give a restarted server's scene a fresh page.
    try {
      await loadHealth();
      if (restarted) showScene();
      await loadLibrary();
      refreshCheckpoints();
    } catch (e) { /* gone again: the stream's next error shows the banner */ }
  },
});

// ---------------------------------------------------------------- library
const library = { tab: "clips", clips: [], characters: [], configs: null };

async function loadLibrary() {
  [library.clips, library.characters, library.configs] = await Promise.all([
    api("GET", "/api/motions"), api("GET", "/api/characters"), api("GET", "/api/configs"),
  ]);
  fillLaunchForm();
  fillFitTargets();
  renderLibrary();
}

function renderLibrary() {
  const q = $("filter").value.toLowerCase();
  const list = $("library-list");
  list.replaceChildren();
  const rows = {
    clips: () => library.clips.map((m) => [m.path, m.error ? m.error :
      `${m.num_frames} frames · ${m.fps} fps · ${m.duration.toFixed(2)} s · ${m.loop_mode} · ${m.character || "no character fits"}`,
      () => loadClip(m)]),
    characters: () => library.characters.map((c) => [c.path, c.error || `${c.num_bodies} bodies · ${c.dof_size} DoFs · frame width ${c.frame_dim}`]),
    datasets: () => library.configs.datasets.map((d) => [d.path, d.error || `${d.motions.length} clips`]),
    configs: () => [
      ...library.configs.arg_files.map((a) => [a.path, a.error || `arg file · ${Object.keys(a.args).length} keys`]),
      ...["envs", "agents", "engines"].flatMap((k) => library.configs[k].map((c) => [c.path, k])),
    ],
  }[library.tab]();
  const failed = new Set([...library.clips, ...library.characters, ...library.configs.arg_files, ...library.configs.datasets]
    .filter((x) => x.error).map((x) => x.error));
  for (const [title, meta, onclick] of rows) {
    if (q && !title.toLowerCase().includes(q)) continue;
    const bad = failed.has(meta);  // a file that cannot be read: its one-line error, not a dead panel
    const item = el("div", { class: bad ? "item broken" : "item", title },
      el("div", {}, title.split("/").pop()), el("div", { class: bad ? "meta error" : "meta" }, meta));
    if (onclick && !bad) item.addEventListener("click", () => { document.querySelectorAll("#library-list .selected").forEach((e) => e.classList.remove("selected")); item.classList.add("selected"); onclick(); });
    list.append(item);
  }
}

async function loadClip(m) {
  shownClip = null;
  $("clip-label").textContent = `loading ${m.path}…`;
  try {
    applyState(await api("POST", "/api/scene/load_clip", { path: m.path, play: true }));
  } catch (e) {
    $("clip-label").textContent = `cannot load ${m.path}: ${e.message}`;
  }
}

document.querySelectorAll(".tabs button").forEach((b) => b.addEventListener("click", () => {
  document.querySelectorAll(".tabs button").forEach((x) => x.classList.toggle("active", x === b));
  library.tab = b.dataset.tab;
  renderLibrary();
}));
$("filter").addEventListener("input", renderLibrary);
$("upload").addEventListener("change", async (ev) => {
  const file = ev.target.files[0];
  if (!file) return;
  try {
    const r = await api("POST", `/api/motions/upload?filename=${encodeURIComponent(file.name)}`, file);
    $("clip-label").textContent = `uploaded ${r.path}`;
    await loadLibrary();
  } catch (e) {
    $("clip-label").textContent = `upload refused: ${e.message}`;
  }
  ev.target.value = "";
});

// ---------------------------------------------------------------- player (state lives on the server)
let scrubbing = false;

let shownClip = null;
let sceneMode = "clip";
function applyState(s) {
  const rollout = s.mode === "rollout";
  if (rollout !== (sceneMode === "rollout")) {  // switched between a clip and a rollout
    shownClip = null;
    rolloutView.reset();
  }
  sceneMode = rollout ? "rollout" : "clip";
  $("rollout-panel").hidden = !rollout;
  if (rollout) rolloutView.apply(s);
  else if (s.clip && s.clip !== shownClip) {  // also after a reload: the player lives on the server
    shownClip = s.clip;
    $("clip-label").textContent = `${s.clip} on ${s.char}`;
  }
  const t = $("timeline");
  t.max = Math.max(0, s.num_frames - 1);
  if (!scrubbing) t.value = s.frame;
  $("frame-label").textContent = rollout
    ? `step ${s.rollout.shown.step} · ${s.time.toFixed(2)} s${s.rollout.live ? "" : ` · history ${s.frame}/${s.num_frames - 1}`}`
    : s.clip ? `${s.frame}/${s.num_frames - 1} · ${s.time.toFixed(2)} s` : "–";
  $("play").textContent = s.playing ? "Pause" : "Play";
  if (pendingCommands > 0) return;  // a pushed state older than the click must not flip the controls back
  $("loop").checked = s.loop;
  $("follow").checked = s.follow;
  if (document.activeElement !== $("speed")) $("speed").value = String(s.speed);
}

// ---------------------------------------------------------------- live rollout (state lives on the server)
// The reward-term plot is fed by the stream's `rollout` events (each recorded step not sent yet).
const rolloutView = {
  plot: null, lastStep: -1,
  init() {
    this.plot = new LinePlot($("rollout-plot"), "rollout, last 10 s:",
      { window: 10, yRange: [0, 1], colors: { reward: "#ffffff" } });
    this.plot.draw();
  },
  reset() { this.lastStep = -1; this.plot.clear(); },
  apply(s) {
    const r = s.rollout;
    const who = r.run_id !== null ? `run #${r.run_id} ${r.run_name || ""}` : r.checkpoint.split("/").slice(-2).join("/");
    const saved = new Date(r.checkpoint_mtime * 1000).toLocaleTimeString();
    const terms = Object.entries(r.reward_terms).map(([k, v]) => `${k} ${v.toFixed(2)}`).join(" · ");
    $("rollout-label").textContent = `${who} · checkpoint saved ${saved}${r.reloads ? ` (reloaded ${r.reloads}×)` : ""}` +
      ` · episode ${r.episode} · return ${r.episode_return.toFixed(2)} · ${terms}${r.error ? ` · ${r.error}` : ""}`;
    $("clip-label").textContent = `rollout of ${r.checkpoint} in ${r.env_config} (ghost: the reference clip)`;
    this.plot.marker = r.live ? null : s.time;
  },
  addRows(h) {  // {reset, step, reward_weights, rows}: reset = another rollout, checkpoint or step numbering
    if (h.reset) this.reset();
    for (const row of h.rows) {
      if (row.step <= this.lastStep) continue;
      this.plot.add("reward", row.time, row.reward);
      for (const [k, v] of Object.entries(row.terms)) this.plot.add(k, row.time, v);
      this.lastStep = row.step;
    }
    this.plot.draw();
  },
};
rolloutView.init();
$("rollout-reset").addEventListener("click", () => playerCommand("rollout/reset"));
$("rollout-close").addEventListener("click", () => playerCommand("rollout/close"));

async function loadRollout(body) {
  $("checkpoint-error").textContent = "";
  $("clip-label").textContent = "building the rollout (env, policy, checkpoint)…";
  try {
    applyState(await api("POST", "/api/scene/load_rollout", body));
  } catch (e) {
    $("checkpoint-error").textContent = e.message;
    $("clip-label").textContent = `cannot roll out: ${e.message}`;
  }
}

let pendingCommands = 0;
async function playerCommand(path, body) {
  pendingCommands += 1;
  try {
    const s = await api("POST", `/api/scene/${path}`, body);
    pendingCommands -= 1;
    applyState(s);
  } catch (e) {
    pendingCommands -= 1;
    $("clip-label").textContent = `${path}: ${e.message}`;
  }
}
$("play").addEventListener("click", () => playerCommand("toggle"));
$("step").addEventListener("click", () => playerCommand("step", { frames: 1 }));
$("timeline").addEventListener("input", (ev) => { scrubbing = true; playerCommand("seek", { frame: Number(ev.target.value) }); });
$("timeline").addEventListener("change", () => { scrubbing = false; });
$("speed").addEventListener("change", (ev) => playerCommand("configure", { speed: Number(ev.target.value) }));
$("loop").addEventListener("change", (ev) => playerCommand("configure", { loop: ev.target.checked }));
$("follow").addEventListener("change", (ev) => playerCommand("configure", { follow: ev.target.checked }));

// Export replay: the server writes a standalone HTML file of the clip or rollout shown; the browser downloads it.
$("export-replay").addEventListener("click", async () => {
  const button = $("export-replay");
  button.disabled = true;
  $("clip-label").textContent = "writing the replay…";
  try {
    const r = await api("POST", "/api/scene/export_replay", { follow: $("follow").checked });
    $("clip-label").textContent = `replay: ${r.frames} poses, ${(r.bytes / 1e6).toFixed(2)} MB (${r.path})`;
    el("a", { href: withToken(r.download), download: r.download.split("/").pop() }).click();
  } catch (e) {
    $("clip-label").textContent = `cannot export: ${e.message}`;
  } finally {
    button.disabled = false;
  }
});

// MimicKit's keys: Enter plays/pauses, Space steps one frame (not while typing in a field).
document.addEventListener("keydown", (ev) => {
  if (ev.target.closest && ev.target.closest("input, select, textarea, button, form")) return;
  if (ev.key === "Enter") { ev.preventDefault(); playerCommand("toggle"); }
  else if (ev.key === " ") { ev.preventDefault(); playerCommand("step", { frames: 1 }); }
});

// ---------------------------------------------------------------- runs
let selectedRun = null;
const plots = {};
document.querySelectorAll("#curves canvas").forEach((c) => {
  plots[c.dataset.group] = new LinePlot(c, { returns: "return", lengths: "episode length", rewards: "reward terms", losses: "losses" }[c.dataset.group]);
  plots[c.dataset.group].draw();
});

const DEFAULT_ARG_FILE = "deepmimic_humanoid_demo_ppo_args";  // trains on the project's own clip: no MimicKit data needed
function fillLaunchForm() {
  const argSel = $("arg-file"), keep = argSel.value;
  argSel.replaceChildren(...library.configs.arg_files.map((a) => el("option", { value: a.path }, a.name)));
  const demo = library.configs.arg_files.find((a) => a.name === DEFAULT_ARG_FILE);
  if (keep) argSel.value = keep;
  else if (demo) argSel.value = demo.path;
  const motionSel = $("motion-file"), keepMotion = motionSel.value;
  motionSel.replaceChildren(el("option", { value: "" }, "(from the arg file)"),
    ...library.configs.datasets.map((d) => el("option", { value: d.path }, `dataset: ${d.name}`)),
    ...library.clips.filter((m) => !m.error).map((m) => el("option", { value: m.path }, m.path)));
  motionSel.value = keepMotion;
  $("launch-button").disabled = library.configs.arg_files.length === 0;
  if (!library.configs.arg_files.length) $("launch-error").textContent = "no arg files found (args/*.txt)";
}

$("launch").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const body = { arg_file: $("arg-file").value };
  if ($("run-name").value) body.name = $("run-name").value;
  if ($("num-envs").value) body.num_envs = Number($("num-envs").value);
  if ($("max-samples").value) body.max_samples = Number($("max-samples").value);
  if ($("motion-file").value) body.motion_file = $("motion-file").value;
  if ($("rand-seed").value !== "") body.rand_seed = Number($("rand-seed").value);
  try {
    const run = await api("POST", "/api/runs", body);
    $("launch-error").textContent = "";
    selectRun(run.id);
    await refreshRuns();
  } catch (e) {
    $("launch-error").textContent = e.message;
  }
});

// After a user's action: the new list at once (the stream would bring it within a second).
async function refreshRuns() {
  try { renderRuns(await api("GET", "/api/runs")); } catch (e) { /* the banner tells when the server is gone */ }
}

// The run list, pushed by the stream when it changed: each run keeps its element, updated in place, so a
// focused button keeps its focus and a click in flight lands; the list is re-laid only when runs came
// or went. The checkpoint list is fetched again only when a run's checkpoint changed.
const runNodes = new Map();  // run id -> {node, run, key, fields}
let checkpointsKey = null;
function renderRuns(runs) {
  const list = $("run-list");
  const nodes = runs.slice().reverse().map((run) => runNode(run));
  // Insert and remove around the elements that stay: moving an element would take its focus away.
  const keep = new Set(nodes);
  for (const child of [...list.children]) if (!keep.has(child)) child.remove();
  nodes.forEach((n, i) => { if (list.children[i] !== n) list.insertBefore(n, list.children[i] || null); });
  for (const id of runNodes.keys()) if (!runs.some((r) => r.id === id)) runNodes.delete(id);
  const key = JSON.stringify(runs.map((r) => [r.id, r.checkpoint, r.checkpoint_mtime ?? null]));
  if (checkpointsKey !== null && key !== checkpointsKey) refreshCheckpoints();
  checkpointsKey = key;
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
  entry.node = el("div", { class: "item", "data-run-id": run.id, onclick: () => selectRun(run.id) },
    el("div", {}, f.title, " ", field("status")),
    el("div", { class: "meta" }, field("clip"), " on ", field("char"), " · ", field("envs"), " · seed ", field("seed")),
    el("div", { class: "meta" }, f.progress, " ", field("samples")),
    el("div", { class: "meta" }, field("elapsed"), " · ", field("rate"), " · test return ", field("test-return"), f.resumes),
    f.reason,
    el("div", { class: "actions" },
      act("Stop", (r) => runAction(r, "stop")),
      act("Continue", (r) => continueRun(r)),
      act("Again", (r) => runAction(r, "again")),
      act("Rollout", (r) => loadRollout({ run_id: r.id })),
      act("Inspect", (r) => inspectCheckpoint(r.checkpoint)),
      act("Delete", (r) => deleteRun(r))));
  return entry;
}

// What the run's folder says (run.summary): what it trains, how far, at what rate, with which seed, how it ended.
function updateRunNode({ run, node, fields: f }) {
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
  set(f.elapsed, duration(s.elapsed_s));
  set(f.rate, `${s.samples_per_s ? s.samples_per_s.toFixed(0) : "–"} samples/s`);
  set(f["test-return"], s.test_return !== null && s.test_return !== undefined ? s.test_return.toFixed(2) : "–");
  set(f.resumes, s.resumes ? ` · resumed ${s.resumes}×` : "");
  set(f.reason, run.reason || "");
  f.reason.hidden = !run.reason;
  f.Stop.disabled = !(active && run.status !== "stopping");
  f.Continue.disabled = !(ended && !!run.checkpoint);
  f.Again.disabled = !(s.seed !== null && s.seed !== undefined);
  f.Rollout.disabled = !run.checkpoint;
  f.Inspect.disabled = !run.checkpoint;
  f.Delete.disabled = active;
}

// POSTs carry a JSON body (the server refuses cross-site form posts).
async function runAction(run, action, body = {}) {
  let result = null;
  try { result = await api("POST", `/api/runs/${run.id}/${action}`, body); } catch (e) { alert(e.message); }
  if (result && action === "resume") selectRun(run.id);
  if (result && action === "again") selectRun(result.id);
  refreshRuns();
}

// Continue: resume from the checkpoint with a budget (total samples); a run that reached its budget needs a larger one.
function continueRun(run) {
  const s = run.summary || {};
  const budget = s.max_samples ?? run.config.max_samples ?? null, samples = s.samples;
  const suggested = budget && samples >= budget ? 2 * budget : budget || "";
  const answer = prompt(`Continue run #${run.id} up to how many samples in all? (trained: ${num(samples)})`, String(suggested));
  if (answer === null) return;
  runAction(run, "resume", answer.trim() ? { max_samples: Number(answer) } : {});
}

async function deleteRun(run) {
  if (!confirm(`Delete run #${run.id} "${run.name}" and its folder ${run.out_dir}?`)) return;
  try { await api("DELETE", `/api/runs/${run.id}`); } catch (e) { alert(e.message); }
  if (selectedRun === run.id) {
    selectedRun = null;
    $("curves-title").textContent = "Curves";
    $("console").textContent = "";
    stream.open({});
  }
  refreshRuns();
}

// Live curves and console: the stream, subscribed to the selected run, pushes its metrics rows and log lines.
function selectRun(id) {
  if (id === selectedRun) return;
  selectedRun = id;
  Object.values(plots).forEach((p) => { p.clear(); p.draw(); });
  $("console").textContent = "";
  $("curves-title").textContent = `Curves · run #${id}`;
  document.querySelectorAll("#run-list .item").forEach((e) => e.classList.toggle("selected", Number(e.dataset.runId) === id));
  stream.open({ run: id });
}

// {run, reset, start, rows}: the first batch of a connection has reset (the rows start again from 0).
function addMetrics(m) {
  if (m.run !== selectedRun) return;
  if (m.reset) Object.values(plots).forEach((p) => p.clear());
  m.rows.forEach(addRow);
  if (!m.rows.length) Object.values(plots).forEach((p) => p.draw());
}

const CONSOLE_LINES = 200;
function addLog(l) {  // {run, reset, lines}
  if (l.run !== selectedRun) return;
  const box = $("console");
  const stick = box.scrollTop + box.clientHeight >= box.scrollHeight - 4;  // follow the end unless scrolled up
  const lines = (l.reset || !box.textContent ? [] : box.textContent.split("\n")).concat(l.lines);
  box.textContent = lines.slice(-CONSOLE_LINES).join("\n");
  if (stick) box.scrollTop = box.scrollHeight;
}

let redrawPending = false;
const plotFor = (k) => (k === "train_return" || k === "test_return" ? plots.returns
  : k.endsWith("episode_length") ? plots.lengths : k.startsWith("reward_terms.") ? plots.rewards
  : k.includes("loss") ? plots.losses : null);
// A row: one iteration, or a marker ({"event": "resume"}); a non-finite value arrives as null named in `nonfinite`.
function addRow(row) {
  const x = row.samples ?? row.iteration ?? 0;
  if (row.event === "resume") Object.values(plots).forEach((p) => p.addMarker(x, "resume"));
  else {
    const bad = row.nonfinite || {};
    for (const [k, v] of Object.entries(row)) {
      const plot = plotFor(k);
      if (!plot) continue;
      if (k in bad) plot.markNonfinite(k, x, bad[k]);
      else if (typeof v === "number") plot.add(k, x, v);
    }
  }
  if (!redrawPending) {  // many rows arrive at once when a stream starts: draw once per frame
    redrawPending = true;
    requestAnimationFrame(() => { redrawPending = false; Object.values(plots).forEach((p) => p.draw()); });
  }
}

// ---------------------------------------------------------------- checkpoints: list, inspect, roll out
async function refreshCheckpoints() {
  let list;
  try { list = await api("GET", "/api/checkpoints"); } catch (e) { return; }
  const sel = $("checkpoint"), keep = sel.value;
  const opts = list.map((c) => el("option", { value: c.path },
    `${c.run_id !== null ? `#${c.run_id} ${c.run_name} · ` : ""}${c.path.split("/").slice(-2).join("/")} · ${new Date(c.mtime * 1000).toLocaleTimeString()}`));
  sel.replaceChildren(...(opts.length ? opts : [el("option", { value: "" }, "(no checkpoints yet)")]));
  if (keep && list.some((c) => c.path === keep)) sel.value = keep;
}

function fillFitTargets() {
  const sel = $("fit-target"), keep = sel.value;
  sel.replaceChildren(el("option", { value: "" }, "fits… (env config or character)"),
    ...library.configs.envs.map((c) => el("option", { value: `env_config=${c.path}` }, `env: ${c.path}`)),
    ...library.characters.filter((c) => !c.error).map((c) => el("option", { value: `char=${c.path}` }, `character: ${c.path}`)));
  sel.value = keep;
}

const chosenCheckpoint = () => $("checkpoint-path").value.trim() || $("checkpoint").value;
$("rollout-button").addEventListener("click", () => {
  const path = chosenCheckpoint();
  if (path) loadRollout({ checkpoint: path });
});
$("inspect-button").addEventListener("click", () => inspectCheckpoint(chosenCheckpoint()));
$("fit-target").addEventListener("change", () => { if (lastInspected) inspectCheckpoint(lastInspected); });

let lastInspected = null;
async function inspectCheckpoint(path) {
  if (!path) return;
  lastInspected = path;
  const target = $("fit-target").value;
  const [key, value] = target ? [target.slice(0, target.indexOf("=")), target.slice(target.indexOf("=") + 1)] : [null, null];
  const q = new URLSearchParams({ path });
  if (key) q.set(key, value);
  $("checkpoint-error").textContent = "";
  $("inspect").textContent = target ? "inspecting (building the env to compare sizes)…" : "inspecting…";
  try {
    renderInspection(await api("GET", `/api/checkpoints/inspect?${q}`));
  } catch (e) {
    $("inspect").textContent = "";
    $("checkpoint-error").textContent = e.message;
  }
}

function renderInspection(c) {
  const f = (v, d = 3) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));
  const lines = [
    `${c.display_path}`,
    `agent ${c.agent} (${c.agent_reason})`,
    `observations ${c.obs_size} · actions ${c.action_size} · ${(c.num_params / 1e6).toFixed(2)} M parameters · ${(c.size_bytes / 1e6).toFixed(1)} MB`,
  ];
  for (const [net, layers] of Object.entries(c.networks)) {
    lines.push(`${net}: ${layers.map((l) => (l.in !== undefined ? `${l.in}→${l.out}` : `[${l.shape.join("×")}]`)).join(", ")}`);
  }
  for (const [name, n] of Object.entries(c.normalizers)) {
    lines.push(`${name} normaliser: count ${n.count} · mean |μ| ${f(n.mean_abs_mean)} · mean σ ${f(n.mean_std)}` +
      ` · μ ∈ [${f(n.mean_min, 2)}, ${f(n.mean_max, 2)}] · σ ∈ [${f(n.std_min, 4)}, ${f(n.std_max, 2)}]`);
  }
  const t = c.train_state;
  if (t) lines.push(`trained: iteration ${t.iteration} · ${t.samples} samples (${t.samples_per_iteration ?? "–"}/iteration) · ${f(t.wall_time_hours * 60, 1)} min` +
    (t.test ? ` · test return ${f(t.test.mean_return, 2)}` : ""));
  else lines.push("no _train_state (a reference or exported checkpoint)");
  const box = $("inspect");
  box.replaceChildren(lines.join("\n"));
  if (c.nonfinite_message) box.append("\n", el("span", { class: "misfit error", "data-nonfinite": "true" }, c.nonfinite_message));
  if (c.fit) box.append("\n", el("span", { class: c.fit.fits ? "fits" : "misfit", "data-fits": String(c.fit.fits) }, c.fit.message));
}

init().catch((e) => { $("health").textContent = `cannot reach the studio API: ${e.message}`; });

// Clicking a player button must not leave it focused: Space/Enter would press it again.
document.querySelectorAll("#player button").forEach((b) => b.addEventListener("mouseup", () => b.blur()));
