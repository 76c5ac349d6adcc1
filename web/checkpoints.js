// Checkpoints: the list (runs' model.pt and the data folders'), inspection with a fit check, roll out.
import { $, api, el } from "./api.js";
import { loadRollout } from "./player.js";

// A model trained on a clip the data folders lack (MimicKit's clips are not shipped) says so in the list.
export const needsData = (c) => c.needs_data ? ` · needs ${c.needs_data.split("/").pop()}: start the studio with --data-dir` : "";

// The list comes grouped (GET /api/checkpoints): one <optgroup> per run ("#id name"), its checkpoints by
// iteration, the newest first (model.pt marked "latest", the --save_int_models ones below it), then the
// data folders' models. A and B get the same groups.
export async function refreshCheckpoints() {
  let list;
  try { list = await api("GET", "/api/checkpoints"); } catch (e) { return; }
  const groups = checkpointGroups(list);
  const sel = $("checkpoint"), keep = sel.value;
  sel.replaceChildren(...(groups.length ? groups : [el("option", { value: "" }, "(no checkpoints yet)")]));
  if (keep && list.some((c) => c.path === keep)) sel.value = keep;
  const b = $("checkpoint-b"), keepB = b.value;  // A/B: the same list, B's pick
  b.replaceChildren(el("option", { value: "" }, "B: (pick a second checkpoint)"), ...groups.map((g) => g.cloneNode(true)));
  if (keepB && list.some((c) => c.path === keepB)) b.value = keepB;
}

function checkpointGroups(list) {
  const groups = new Map();
  for (const c of list) {
    if (!groups.has(c.group)) groups.set(c.group, el("optgroup", { label: c.group }));
    groups.get(c.group).append(el("option", { value: c.path, title: c.path, "data-iteration": c.iteration ?? "" }, checkpointLabel(c)));
  }
  return [...groups.values()];
}

// "iter 12 · 98304 samples · latest": the training its weights have seen, as a rollout's label counts it;
// a file with no known iteration by its name (a shipped model), in a run also the time it was saved.
const samplesText = (n) => (n < 1e6 ? `${n}` : `${(n / 1e6).toFixed(2)} M`);
function checkpointLabel(c) {
  const name = c.path.split("/").slice(-2).join("/");
  const trained = c.iteration !== null
    ? `iter ${c.iteration}${c.samples !== null ? ` · ${samplesText(c.samples)} samples` : ""}`
    : c.run_id !== null ? `${name} · ${new Date(c.mtime * 1000).toLocaleTimeString()}` : name;
  return `${trained}${c.latest ? " · latest" : ""}${needsData(c)}`;
}

export function fillFitTargets(library) {
  const sel = $("fit-target"), keep = sel.value;
  sel.replaceChildren(el("option", { value: "" }, "fits… (env config or character)"),
    ...library.configs.envs.map((c) => el("option", { value: `env_config=${c.path}` }, `env: ${c.path}`)),
    ...library.characters.filter((c) => !c.error).map((c) => el("option", { value: `char=${c.path}` }, `character: ${c.path}`)));
  sel.value = keep;
}

const chosenCheckpoint = () => $("checkpoint-path").value.trim() || $("checkpoint").value;
let lastInspected = null;

export function initCheckpoints() {
  $("rollout-button").addEventListener("click", () => {
    const path = chosenCheckpoint();
    // Several envs only when asked: the body stays the one-env request otherwise.
    const n = Number($("rollout-envs").value) || 1;
    if (path) loadRollout({ checkpoint: path, ...(n !== 1 ? { num_envs: n, layout: $("rollout-layout").value } : {}) });
  });
  $("ab-button").addEventListener("click", () => {
    const a = chosenCheckpoint(), b = $("checkpoint-b").value;
    if (!a || !b) { $("checkpoint-error").textContent = "A/B: pick a checkpoint (A) and a second one (B)"; return; }
    loadRollout({ checkpoint: a, b_checkpoint: b });
  });
  $("inspect-button").addEventListener("click", () => inspectCheckpoint(chosenCheckpoint()));
  $("fit-target").addEventListener("change", () => { if (lastInspected) inspectCheckpoint(lastInspected); });
}

export async function inspectCheckpoint(path) {
  if (!path) return;
  lastInspected = path;
  $("checkpoints-box").open = true;
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
