// The library panel: clips, characters, datasets and configs on disk. A click on a clip plays it; on a
// character, dataset or config it opens in the detail pane below the list (web/library_detail.js).
// Uploaded clips can be deleted; a file that fails to load stays listed with its reason.
import { $, api, el } from "./api.js";
import { closeDetail, showCharacter, showConfig } from "./library_detail.js";
import { loadClip } from "./player.js";

export const library = { tab: "clips", clips: [], characters: [], configs: null, selected: null };
const loadedListeners = [];
export const onLibraryLoaded = (fn) => loadedListeners.push(fn);

export async function loadLibrary() {
  [library.clips, library.characters, library.configs] = await Promise.all([
    api("GET", "/api/motions"), api("GET", "/api/characters"), api("GET", "/api/configs"),
  ]);
  loadedListeners.forEach((fn) => fn(library));
  renderLibrary();
}

const clipFacts = (m) => `${m.num_frames} frames · ${m.fps} fps · ${m.duration.toFixed(2)} s · ${m.loop_mode}`;

// One row per file of the tab: {key, title, meta, error, tried, upload, open}. `error`: the file does not
// load (its one line); `tried`: a clip no character fits, with why each character does not take it.
function rowsOf(tab) {
  const c = library.configs;
  if (tab === "clips") {
    return library.clips.map((m) => ({
      key: m.path, title: m.path, upload: m.upload, error: m.error,
      meta: m.error ? m.error : `${clipFacts(m)} · ${m.character ? m.character.split("/").pop() : "no character fits"}`,
      tried: m.error || m.character ? null : { line: m.character_error, list: m.characters_tried || [] },
      open: () => loadClip(m),
    }));
  }
  if (tab === "characters") {
    return library.characters.map((ch) => ({
      key: ch.path, title: ch.path, error: ch.error,
      meta: ch.error || `${ch.num_bodies} bodies · ${ch.dof_size} DoFs · frame width ${ch.frame_dim}`,
      open: () => showCharacter(ch),
    }));
  }
  if (tab === "datasets") {
    return c.datasets.map((d) => ({
      key: d.path, title: d.path, error: d.error,
      meta: d.error || `${d.motions.length} clips${d.missing ? ` · ${d.missing} missing` : ""}`,
      open: () => showConfig(d.path),
    }));
  }
  return [
    ...c.arg_files.map((a) => ({
      key: a.path, title: a.path, error: a.error,
      meta: a.error || `arg file · ${Object.keys(a.args).length} keys`, open: () => showConfig(a.path),
    })),
    ...["envs", "agents", "engines"].flatMap((k) => c[k].map((f) => ({
      key: f.path, title: f.path, meta: k, open: () => showConfig(f.path),
    }))),
  ];
}

// Each file keeps its element while what it shows is unchanged, so a focused button (Delete) keeps its
// focus and a click in flight lands when the library is loaded again; only changed rows are rebuilt.
const nodes = new Map();  // `${tab} ${path}` -> {node, sig}
function renderLibrary() {
  if (!library.configs) return;
  const q = $("filter").value.toLowerCase();
  const rows = rowsOf(library.tab).filter((r) => !q || r.title.toLowerCase().includes(q));
  const wanted = rows.map((r) => {
    const key = `${library.tab} ${r.key}`;
    const { open, ...shown } = r;
    const sig = JSON.stringify(shown);
    let entry = nodes.get(key);
    if (!entry || entry.sig !== sig) {
      const node = rowNode(r);
      if (entry) entry.node.replaceWith(node);
      entry = { node, sig };
      nodes.set(key, entry);
    }
    entry.node.classList.toggle("selected", library.selected === key);
    return entry.node;
  });
  const list = $("library-list");
  const keep = new Set(wanted);
  for (const child of [...list.children]) if (!keep.has(child)) child.remove();
  wanted.forEach((n, i) => { if (list.children[i] !== n) list.insertBefore(n, list.children[i] || null); });
  for (const [key, entry] of nodes) if (!keep.has(entry.node)) nodes.delete(key);
}

function rowNode(r) {
  const key = `${library.tab} ${r.key}`;
  const bad = Boolean(r.error);
  const item = el("div", { class: bad ? "item broken" : r.tried ? "item nofit" : "item", title: r.title, "data-path": r.key },
    el("div", { class: "name" }, r.title.split("/").pop()),
    el("div", { class: bad || r.tried ? "meta error" : "meta" }, r.meta));
  if (r.tried) {  // a clip no character takes: each character tried and why, not just "no character fits"
    item.title = r.tried.line || r.title;
    item.append(el("ul", { class: "tried meta" }, ...r.tried.list.map((t) =>
      el("li", { "data-character": t.path }, `${t.path.split("/").pop()}: ${t.reason}`))));
  }
  if (r.upload) {
    item.append(el("div", { class: "actions" }, el("button", {
      "data-action": "delete", title: "delete this uploaded clip",
      onclick: (ev) => { ev.stopPropagation(); deleteUpload(r.key); },
    }, "Delete")));
  }
  if (!bad) {
    item.addEventListener("click", () => {
      library.selected = key;
      document.querySelectorAll("#library-list .selected").forEach((e) => e.classList.remove("selected"));
      item.classList.add("selected");
      r.open();
    });
  }
  return item;
}

const status = (text, error = false) => {
  $("library-status").textContent = text;
  $("library-status").classList.toggle("error", error);
};

async function deleteUpload(path) {
  if (!confirm(`Delete the uploaded clip ${path}?`)) return;
  try {
    await api("DELETE", `/api/motions/upload?path=${encodeURIComponent(path)}`);
    status(`deleted ${path.split("/").pop()}`);
    await loadLibrary();
  } catch (e) {
    status(`cannot delete ${path.split("/").pop()}: ${e.message}`, true);
  }
}

// The clips tab with one clip selected and in view (after an upload, new or the same bytes again).
function reveal(path) {
  switchTab("clips");
  library.selected = `clips ${path}`;
  renderLibrary();
  const entry = nodes.get(library.selected);
  if (entry) entry.node.scrollIntoView({ block: "nearest" });
}

function switchTab(tab) {
  document.querySelectorAll(".tabs button").forEach((x) => x.classList.toggle("active", x.dataset.tab === tab));
  library.tab = tab;
  renderLibrary();
}

export function initLibrary() {
  document.querySelectorAll(".tabs button").forEach((b) => b.addEventListener("click", () => switchTab(b.dataset.tab)));
  $("filter").addEventListener("input", renderLibrary);
  $("detail-close").addEventListener("click", closeDetail);
  $("upload").addEventListener("change", async (ev) => {
    const file = ev.target.files[0];
    if (!file) return;
    try {
      const r = await api("POST", `/api/motions/upload?filename=${encodeURIComponent(file.name)}`, file);
      const name = r.path.split("/").pop();
      status(r.duplicate ? `${file.name} is the same clip as ${name}, uploaded before (same bytes): no copy made`
        : `uploaded ${name} · ${r.num_frames} frames at ${r.fps} fps`);
      await loadLibrary();
      reveal(r.path);
    } catch (e) {
      status(`upload refused: ${e.message}`, true);
    }
    ev.target.value = "";
  });
}
