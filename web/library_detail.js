// The library's detail pane, under the list (never over the 3D view): a character's joints (the scene
// shows it in its default pose), an arg file's or config's text read-only with what it trains resolved,
// a dataset's clips with their weights. Clips named there play with a click.
import { $, api, el } from "./api.js";
import { applyState, loadClip } from "./player.js";

let shown = null;  // the path the pane shows; an answer for another one (clicked since) is dropped

function open(path, title) {
  shown = path;
  $("detail-title").textContent = title;
  $("detail-title").title = path;
  $("detail-body").replaceChildren(el("div", { class: "muted" }, "loading…"));
  $("library-detail").hidden = false;
}

function fill(path, ...children) {
  if (shown === path) $("detail-body").replaceChildren(...children);
}

export function closeDetail() {
  shown = null;
  $("library-detail").hidden = true;
  $("detail-body").replaceChildren();
}

const name = (p) => p.split("/").pop();
const fmt = (v) => Number(v).toFixed(2);

// A character: into the scene in its default pose, and its bodies with the joint that moves each.
export async function showCharacter(ch) {
  open(ch.path, `${name(ch.path)} · default pose`);
  try {
    const [state, pose] = await Promise.all([
      api("POST", "/api/scene/show_character", { path: ch.path }),
      api("GET", `/api/characters/pose?path=${encodeURIComponent(ch.path)}`),
    ]);
    applyState(state);
    $("clip-label").textContent = `${name(ch.path)} in its default pose`;
    $("clip-label").title = ch.path;
    fill(ch.path, el("div", { class: "meta" }, `${pose.bodies.length} bodies · ${pose.dof_size} DoFs · frame width ${pose.frame_dim}`),
      jointTable(pose.bodies));
  } catch (e) {
    fill(ch.path, el("div", { class: "error" }, `cannot show ${name(ch.path)}: ${e.message}`));
  }
}

// One row a body: its joint, the joint's type, the clip columns it takes; its limits (radians) in the tooltip.
function jointTable(bodies) {
  const head = el("tr", {}, ...["body", "joint", "type", "cols"].map((h) => el("th", { title: h === "cols" ? "its columns in a clip frame" : h }, h)));
  const rows = bodies.map((b) => {
    const j = b.joint;
    const cols = j.dof_dim ? (j.dof_dim === 1 ? `${6 + j.dof_idx}` : `${6 + j.dof_idx}–${5 + j.dof_idx + j.dof_dim}`) : "–";
    const limits = j.low.length ? j.low.map((lo, i) => `${fmt(lo)}…${fmt(j.high[i])}`).join(" ") : "–";
    return el("tr", { "data-joint": j.name, title: `${b.name}: ${j.name}, ${j.type}, limits ${limits}` },
      el("td", {}, b.name), el("td", {}, j.name), el("td", {}, j.type), el("td", {}, cols));
  });
  return el("table", { class: "diff joints" }, head, ...rows);
}

const KINDS = { arg_file: "arg file", envs: "env config", agents: "agent config", engines: "engine config", datasets: "dataset" };

// An arg file, an env/agent/engine yaml or a dataset yaml, read-only.
export async function showConfig(path) {
  open(path, name(path));
  let file;
  try {
    file = await api("GET", `/api/configs/file?path=${encodeURIComponent(path)}`);
  } catch (e) {
    fill(path, el("div", { class: "error" }, `cannot open ${name(path)}: ${e.message}`));
    return;
  }
  const parts = [el("div", { class: "meta" }, KINDS[file.kind] || file.kind)];
  if (file.error) parts.push(el("div", { class: "error" }, file.error));
  if (file.trains) parts.push(trainsBlock(file.trains));
  if (file.kind === "datasets" && file.motions) parts.push(datasetTable(file));
  parts.push(el("pre", { class: "mono config-text", "aria-label": `${name(path)}, read-only` }, file.text));
  fill(path, ...parts);
}

// What it trains: the env config, the clip or dataset and the character, each as resolved (or missing).
function trainsBlock(trains) {
  const box = el("div", { class: "trains" });
  if (trains.error) box.append(el("div", { class: "error" }, trains.error));
  const line = (label, f, ...actions) => {
    if (!f) return;
    const where = f.resolved ? f.resolved : `${f.file} (outside the studio's folders)`;
    box.append(el("div", { class: "meta", "data-trains": label },
      el("div", {}, el("span", { class: "muted" }, f.from ? `${label} · from the ${f.from}` : label),
        f.exists ? "" : el("span", { class: "error" }, " · missing"), ...(f.exists ? actions : [])),
      el("div", { class: "path", title: f.file }, where)));
  };
  const button = (label, action, fn) => el("button", { "data-action": action, onclick: fn }, label);
  line("env config", trains.env_config, button("Open", "open-env", () => showConfig(trains.env_config.resolved)));
  const m = trains.motion_file;
  if (m) {
    line(m.kind === "dataset" ? "dataset" : "clip", m, m.kind === "dataset"
      ? button("Open", "open-dataset", () => showConfig(m.resolved))
      : button("Play", "play-clip", () => loadClip({ path: m.resolved })));
  }
  line("character", trains.char_file, button("Show", "show-character", () => showCharacter({ path: trains.char_file.resolved })));
  return box;
}

// A dataset's clips: weight, share of the total weight, and which files are missing; a click plays one.
function datasetTable(d) {
  const head = el("tr", {}, ...["clip", "weight", "share"].map((h) => el("th", {}, h)));
  const rows = d.motions.map((c) => {
    const title = c.exists ? c.resolved : `missing: ${c.resolved || c.file} is not in the data folders`;
    const row = el("tr", { class: c.exists ? "clip" : "clip missing", "data-clip": c.file, title },
      el("td", {}, c.exists ? "" : el("span", { class: "error", "aria-label": "missing" }, "✗ "), name(c.file)),
      el("td", {}, String(c.weight)), el("td", {}, `${(100 * c.share).toFixed(1)} %`));
    if (c.exists) row.addEventListener("click", () => loadClip({ path: c.resolved }));
    return row;
  });
  const summary = `${d.motions.length} clips${d.missing ? ` · ${d.missing} missing (not in the data folders)` : ""}`;
  return el("div", {}, el("div", { class: "meta" }, summary), el("table", { class: "diff dataset" }, head, ...rows));
}
