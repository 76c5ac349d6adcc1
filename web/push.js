// The rollout panel's Push control (issue 37): push a body of the character with a force in a direction
// for a moment (POST /api/scene/rollout/push) and watch the policy recover or fall. The body list and
// the bounds come with the state (`rollout.push`); a click on one of the character's bodies in the 3D
// view picks it (the server's `picked`), and the select follows. The reward plot marks each push and a
// fall after one (web/player.js, from the history rows' `push` and `fall_after_push_s`).
import { $, api } from "./api.js";

// Directions in the scene's world (z up): the humanoid's clips face +x.
const DIRECTIONS = {
  "+x": [1, 0, 0], "-x": [-1, 0, 0], "+y": [0, 1, 0], "-y": [0, -1, 0], "+z": [0, 0, 1],
};

export const pushView = {
  bodies: "", picked: null, applyState: null,
  init(applyState) {
    this.applyState = applyState;
    $("push-force").addEventListener("input", () => this.showForce());
    $("push-button").addEventListener("click", () => this.push());
    this.showForce();
  },
  showForce() {
    $("push-force-label").textContent = `${$("push-force").value} N`;
  },
  async push() {
    const dir = DIRECTIONS[$("push-dir").value];
    const newtons = Number($("push-force").value);
    const body = { body: $("push-body").value || null, force: dir.map((c) => c * newtons), duration_s: Number($("push-duration").value) };
    try {
      this.applyState(await api("POST", "/api/scene/rollout/push", body));
    } catch (e) {
      $("push-status").textContent = `push refused: ${e.message}`;
    }
  },
  show(r) {  // the state's rollout
    const p = r.push;
    if (!p) return;
    const names = p.bodies.join(",");
    if (names !== this.bodies) {  // another character: its bodies
      this.bodies = names;
      $("push-body").replaceChildren(...p.bodies.map((b) => new Option(b, b)));
      $("push-force").max = String(p.max_force_n);
    }
    if (p.picked !== this.picked) {  // a click in the 3D view (or the first state): the select follows
      this.picked = p.picked;
      $("push-body").value = p.picked;
    }
    const last = p.last, fell = r.episodes.filter((e) => e.fall_after_push_s !== null).pop();
    const text = last
      ? `pushed ${last.body} ${Math.round(Math.hypot(...last.force))} N for ${last.duration_s.toFixed(2)} s` +
        (p.acting.length ? " · pushing" : "") +
        (fell ? ` · episode ${fell.episode} fell ${fell.fall_after_push_s.toFixed(2)} s after a push` : "")
      : "";
    const status = $("push-status");
    if (status.textContent !== text) status.textContent = text;
    status.dataset.pushed = last ? String(last.at_step) : "";
    status.dataset.fell = fell ? String(fell.episode) : "";
  },
};
