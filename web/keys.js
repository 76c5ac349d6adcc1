// The page's keys. They act wherever the focus is (a button, a checkbox, the timeline after a drag),
// except in a text field or a list box, where keys belong to what is typed or picked. Inside the 3D
// view the scene's own commands (studio/scene/player_gui.py) handle Enter and Space.
import { $, el } from "./api.js";
import { playerCommand, sceneState } from "./player.js";

const TYPING = "input[type=text], input[type=search], input[type=number], input:not([type]), textarea, select, [contenteditable]";

// The frame →/← last asked for while a seek is on its way: quick presses count from it, not from the frame
// the page last heard of (10 fast presses moved one frame), and one seek at a time goes out, so the
// server sees them in order and the newest target last.
let seekTarget = null;
let seeking = false;
const seekBy = async (d) => {
  const s = sceneState();
  if (!s || !s.num_frames) return;
  seekTarget = Math.min(Math.max(0, (seekTarget ?? s.frame) + d), s.num_frames - 1);
  $("timeline").value = seekTarget;  // shown at once; the server's answer reconciles it
  if (seeking) return;
  seeking = true;
  try {
    for (let sent = null; sent !== seekTarget;) {
      sent = seekTarget;
      await playerCommand("seek", { frame: sent });
    }
  } finally {
    seeking = false;
    seekTarget = null;
  }
};
const toggle = (id) => { const c = $(id); c.checked = !c.checked; c.dispatchEvent(new Event("change")); };

export const SHORTCUTS = [
  [["Enter"], "play / pause", () => playerCommand("toggle")],
  [[" "], "step one frame (pauses)", () => playerCommand("step", { frames: 1 })],
  [["ArrowRight"], "next frame (clip) or history step (rollout)", () => seekBy(1)],
  [["ArrowLeft"], "previous frame / history step", () => seekBy(-1)],
  [["Home"], "first frame", () => seekBy(-Infinity)],
  [["f"], "camera follow on / off", () => toggle("follow")],
  [["l"], "loop on / off", () => toggle("loop")],
  [["?"], "this list", () => showShortcuts()],
];
const KEY_NAMES = { " ": "Space", ArrowRight: "→", ArrowLeft: "←" };

export function showShortcuts() {
  const d = $("shortcuts");
  if (!d.open) d.showModal();
}

export function initKeys() {
  $("shortcut-table").replaceChildren(...SHORTCUTS.map(([keys, what]) =>
    el("tr", {}, el("td", {}, ...keys.map((k) => el("kbd", {}, KEY_NAMES[k] || k))), el("td", {}, what))),
    el("tr", {}, el("td", {}, el("kbd", {}, "Esc")), el("td", {}, "close this list")));
  $("shortcuts-button").addEventListener("click", showShortcuts);
  document.addEventListener("keydown", (ev) => {
    if (ev.ctrlKey || ev.metaKey || ev.altKey || ev.repeat && ev.key === "Enter") return;
    if ($("shortcuts").open) return;  // the dialog's own keys (Esc, its button)
    const t = ev.target;
    if (t instanceof Element && t.closest(TYPING)) return;
    const hit = SHORTCUTS.find(([keys]) => keys.includes(ev.key));
    if (!hit) return;
    // preventDefault: a focused button would otherwise be pressed too, a slider moved, the page scrolled.
    ev.preventDefault();
    hit[2]();
  });
}
