// The library panel: clips, characters, datasets and configs on disk; a click on a clip plays it.
import { $, api, el } from "./api.js";
import { loadClip } from "./player.js";

export const library = { tab: "clips", clips: [], characters: [], configs: null };
const loadedListeners = [];
export const onLibraryLoaded = (fn) => loadedListeners.push(fn);

export async function loadLibrary() {
  [library.clips, library.characters, library.configs] = await Promise.all([
    api("GET", "/api/motions"), api("GET", "/api/characters"), api("GET", "/api/configs"),
  ]);
  loadedListeners.forEach((fn) => fn(library));
  renderLibrary();
}

function renderLibrary() {
  if (!library.configs) return;
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
    if (onclick && !bad) item.addEventListener("click", () => { list.querySelectorAll(".selected").forEach((e) => e.classList.remove("selected")); item.classList.add("selected"); onclick(); });
    list.append(item);
  }
}

export function initLibrary() {
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
}
