// Checkpoints: the list (runs' model.pt and the data folders'), inspection with a fit check, roll out.
import { $, api, el } from "./api.js";
import { loadRollout } from "./player.js";

// A model trained on a clip the data folders lack (MimicKit's clips are not shipped) says so in the list.
export const needsData = (c) => c.needs_data ? ` · needs ${c.needs_data.split("/").pop()}: start the studio with --data-dir` : "";

export async function refreshCheckpoints() {
  let list;
  try { list = await api("GET", "/api/checkpoints"); } catch (e) { return; }
  const sel = $("checkpoint"), keep = sel.value;
  const opts = list.map((c) => el("option", { value: c.path, title: c.path },
    `${c.run_id !== null ? `#${c.run_id} ${c.run_name} · ` : ""}${c.path.split("/").slice(-2).join("/")} · ${new Date(c.mtime * 1000).toLocaleTimeString()}${needsData(c)}`));
  sel.replaceChildren(...(opts.length ? opts : [el("option", { value: "" }, "(no checkpoints yet)")]));
  if (keep && list.some((c) => c.path === keep)) sel.value = keep;
  const b = $("checkpoint-b"), keepB = b.value;  // A/B: the same list, B's pick
  b.replaceChildren(el("option", { value: "" }, "B: (pick a second checkpoint)"), ...opts.map((o) => o.cloneNode(true)));
  if (keepB && list.some((c) => c.path === keepB)) b.value = keepB;
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
    if (path) loadRollout({ checkpoint: path });
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
