// The player bar and the rollout panel. The player lives on the server: a click posts a command, the
// answer and the stream's `scene` events set the controls; the rollout's reward terms arrive as
// `rollout` events (each recorded step not sent yet) and are drawn with the page's uPlot plots.
import { $, api, el, withToken } from "./api.js";
import { CurvePlot } from "./plots.js";
import { BodyErrorChart } from "./body_error.js";

let scrubbing = false;
let pendingCommands = 0;
let shownClip = null;
let sceneMode = "clip";
let last = null; // the latest scene state

export const sceneState = () => last;

export function applyState(s) {
  last = s;
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
    $("clip-label").textContent = `${s.clip.split("/").pop()} on ${s.char.split("/").pop()}`;
    $("clip-label").title = `${s.clip} on ${s.char}`;
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

export async function playerCommand(path, body) {
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

export async function loadClip(m) {
  shownClip = null;
  $("clip-label").textContent = `loading ${m.path}…`;
  try {
    applyState(await api("POST", "/api/scene/load_clip", { path: m.path, play: true }));
  } catch (e) {
    $("clip-label").textContent = `cannot load ${m.path}: ${e.message}`;
  }
}

export async function loadRollout(body) {
  $("checkpoint-error").textContent = "";
  $("clip-label").textContent = "building the rollout (env, policy, checkpoint)…";
  try {
    applyState(await api("POST", "/api/scene/load_rollout", body));
  } catch (e) {
    $("checkpoint-error").textContent = e.message;
    $("clip-label").textContent = `cannot roll out: ${e.message}`;
  }
}

export const rolloutView = {
  plot: null, lastStep: -1, bodyError: null,
  init() {
    this.bodyError = new BodyErrorChart($("body-error"));
    this.plot = new CurvePlot($("rollout-plot"), {
      title: "rollout: reward and its terms, last 10 s", xLabel: "time (s)", yLabel: "reward",
      height: 130, window: 10, yRange: [0, 1], colors: { reward: "#ffffff" },
    });
  },
  reset() { this.lastStep = -1; this.plot.clear(); this.bodyError.clear(); },
  apply(s) {
    const r = s.rollout;
    const who = r.run_id !== null ? `run #${r.run_id} ${r.run_name || ""}` : r.checkpoint.split("/").slice(-2).join("/");
    const saved = new Date(r.checkpoint_mtime * 1000).toLocaleTimeString();
    const terms = Object.entries(r.reward_terms).map(([k, v]) => `${k} ${v.toFixed(2)}`).join(" · ");
    $("rollout-label").textContent = `${who} · checkpoint saved ${saved}${r.reloads ? ` (reloaded ${r.reloads}×)` : ""}` +
      ` · episode ${r.episode} · return ${r.episode_return.toFixed(2)} · ${terms}${r.error ? ` · ${r.error}` : ""}`;
    $("clip-label").textContent = `rollout of ${r.checkpoint.split("/").slice(-2).join("/")} in ${r.env_config.split("/").pop()} (ghost: the reference clip)`;
    this.bodyError.apply(r.body_error);  // the frame shown's (live or history)
    const cursor = r.live ? null : s.time;
    if (cursor !== this.plot.cursor) { this.plot.cursor = cursor; this.plot.draw(); }
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

export function initPlayer() {
  rolloutView.init();
  $("rollout-reset").addEventListener("click", () => playerCommand("rollout/reset"));
  $("rollout-close").addEventListener("click", () => playerCommand("rollout/close"));
  $("play").addEventListener("click", () => playerCommand("toggle"));
  $("step").addEventListener("click", () => playerCommand("step", { frames: 1 }));
  $("timeline").addEventListener("input", (ev) => { scrubbing = true; playerCommand("seek", { frame: Number(ev.target.value) }); });
  $("timeline").addEventListener("change", () => { scrubbing = false; });
  $("speed").addEventListener("change", (ev) => playerCommand("configure", { speed: Number(ev.target.value) }));
  $("loop").addEventListener("change", (ev) => playerCommand("configure", { loop: ev.target.checked }));
  $("follow").addEventListener("change", (ev) => playerCommand("configure", { follow: ev.target.checked }));
  $("export-replay").addEventListener("click", exportReplay);
}

// Export replay: the server writes a standalone HTML file of the clip or rollout shown; the browser downloads it.
async function exportReplay() {
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
}
