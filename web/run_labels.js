// A run's tags and notes (kept in the registry, set by PATCH /api/runs/{id}): chips and a notes line in
// its list entry, an editor it opens; and the run list's filter (by name, tag, status, arg file, id),
// applied again to every list the stream pushes.
import { $, api, el } from "./api.js";

// The parts of a run's entry: chips, notes (one line; the whole text as its tooltip, a click shows it
// all) and the editor (hidden until its "Tags" button opens it).
export function labelParts(entry, onSaved) {
  const f = entry.fields;
  f.tags = el("span", { class: "tags", "data-field": "tags" });
  f.notes = el("div", { class: "meta notes", "data-field": "notes", onclick: (ev) => { ev.stopPropagation(); f.notes.classList.toggle("open"); } });
  f.tagsInput = el("input", { "data-field": "tags-input", placeholder: "tags, comma-separated", "aria-label": "tags" });
  f.notesInput = el("textarea", { "data-field": "notes-input", rows: "2", placeholder: "notes", "aria-label": "notes" });
  f.labelError = el("div", { class: "error" });
  f.editor = el("form", { class: "label-editor", hidden: "", onclick: (ev) => ev.stopPropagation(),
    onsubmit: (ev) => { ev.preventDefault(); saveLabels(entry, onSaved); } },
  f.tagsInput, f.notesInput,
  el("div", { class: "row" }, el("button", { type: "submit", "data-action": "save-labels" }, "Save"),
    el("button", { type: "button", onclick: () => { f.editor.hidden = true; } }, "Cancel")),
  f.labelError);
}

export function openLabels({ run, fields: f }) {
  f.tagsInput.value = (run.tags || []).join(", ");
  f.notesInput.value = run.notes || "";
  f.labelError.textContent = "";
  f.editor.hidden = false;
  f.tagsInput.focus();
}

async function saveLabels(entry, onSaved) {
  const f = entry.fields;
  const tags = f.tagsInput.value.split(",").map((t) => t.trim()).filter(Boolean);
  try {
    await api("PATCH", `/api/runs/${entry.run.id}`, { tags: [...new Set(tags)], notes: f.notesInput.value });
  } catch (e) { f.labelError.textContent = e.message; return; }
  f.editor.hidden = true;
  onSaved();
}

export function updateLabels({ run, fields: f }) {
  const tags = run.tags || [], notes = run.notes || "";
  if (f.tags.dataset.tags !== JSON.stringify(tags)) {
    f.tags.dataset.tags = JSON.stringify(tags);
    f.tags.replaceChildren(...tags.map((t) => el("span", { class: "chip", title: `tag: filter the list by "${t}"`,
      onclick: (ev) => { ev.stopPropagation(); setFilter(t); } }, t)));
  }
  if (f.notes.textContent !== notes) f.notes.textContent = notes;
  f.notes.title = notes;
  f.notes.hidden = !notes;
}

// The filter: every word typed must be in the run's name, one of its tags, its status, its arg file or
// "#id" (any case).
let redraw = () => {};
export function initRunFilter(onChange) {
  redraw = onChange;
  $("run-filter").addEventListener("input", onChange);
}

function setFilter(text) {
  $("run-filter").value = text;
  redraw();
}

export function runMatches(run) {
  const words = $("run-filter").value.toLowerCase().split(/\s+/).filter(Boolean);
  if (!words.length) return true;
  const text = [run.name, `#${run.id}`, run.status, run.config?.arg_file || "", ...(run.tags || [])].join("\n").toLowerCase();
  return words.every((w) => text.includes(w));
}
