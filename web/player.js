// The player bar and the rollout panel. The player lives on the server: a click posts a command, the
// answer and the stream's `scene` events set the controls; the rollout's reward terms arrive as
// `rollout` events (each recorded step not sent yet) and are drawn with the page's uPlot plots.
import { $, api, el, withToken } from "./api.js";
import { CurvePlot } from "./plots.js";
import { BodyErrorChart } from "./body_error.js";
import { pushView } from "./push.js";
import { showEnvs } from "./envs_summary.js";

let scrubbing = false;
let pendingCommands = 0;
let shownClip = null;
let sceneMode = "clip";
let last = null; // the latest scene state
let predicted = null; // the controls the commands on their way will set

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
  // A pushed state older than a click must not flip the controls back: until the command's answer the
  // controls show what the click predicted.
  showControls(pendingCommands > 0 && predicted ? predicted : s);
  if (pendingCommands > 0) return;
  $("loop").checked = s.loop;
  $("follow").checked = s.follow;
  if (document.activeElement !== $("speed")) $("speed").value = String(s.speed);
}

function showControls(s) {
  const t = $("timeline");
  t.max = Math.max(0, s.num_frames - 1);
  if (!scrubbing) t.value = s.frame;
  $("frame-label").textContent = s.mode === "rollout"
    ? `step ${s.rollout.shown.step} · ${s.time.toFixed(2)} s${s.rollout.live ? "" : ` · history ${s.frame}/${s.num_frames - 1}`}`
    : s.clip ? `${s.frame}/${s.num_frames - 1} · ${s.time.toFixed(2)} s` : "–";
  $("play").textContent = s.playing ? "Pause" : "Play";
}

// What a command will make of the controls, shown at the click: the page does not wait for the server
// (whose answer, queued behind the 3D view's frames, took seconds) to show a pause or a step. The server
// decides; its answer replaces the guess. The rules are the server's players' (the clip's and the rollout's).
function predict(s, path, body) {
  if (!s || !s.num_frames) return null;
  const p = { ...s };
  const move = (frame) => {
    const n = s.num_frames;
    p.frame = s.mode === "clip" && s.loop ? ((frame % n) + n) % n : Math.max(0, Math.min(frame, n - 1));
    if (s.mode === "clip" && s.fps) p.time = p.frame / s.fps;
  };
  if (path === "toggle") p.playing = !s.playing;
  else if (path === "play" || path === "pause") p.playing = path === "play";
  else if (path === "seek" && body.frame !== undefined) {
    move(body.frame);
    if (s.mode === "rollout") p.playing = false;
  } else if (path === "step") {
    p.playing = false;
    const frames = body.frames ?? 1;
    if (s.mode === "clip") move(s.frame + frames);
    else if (s.rollout.live && frames > 0) {  // simulates on: the next steps of the live end
      p.rollout = { ...s.rollout, shown: { ...s.rollout.shown, step: s.rollout.shown.step + frames } };
      p.time = s.time + frames / s.fps;
    } else return { ...p, frame: s.frame };
  } else return null;
  return p;
}

export async function playerCommand(path, body) {
  const guess = predict(predicted || last, path, body || {});
  pendingCommands += 1;
  if (guess) { predicted = guess; showControls(guess); }
  const settle = () => { pendingCommands -= 1; if (pendingCommands === 0) predicted = null; };
  try {
    const s = await api("POST", `/api/scene/${path}`, body);
    settle();
    applyState(s);
  } catch (e) {
    settle();
    if (last) applyState(last);  // the guess did not happen
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

// One side's label: who, the training its weights have seen, when its checkpoint was saved, the episode
// shown and its reward terms.
// A task env's target (ShowsTaskTarget): where it is and how far the character is from it.
function taskText(t) {
  if (t.kind === "location") {
    return `target (${t.x.toFixed(1)}, ${t.y.toFixed(1)}) ${t.distance_m.toFixed(2)} m away${t.reached ? ", reached" : ""}`;
  }
  if (t.kind === "steering") {
    return `target heading ${t.heading_deg.toFixed(0)}° at ${t.speed_mps.toFixed(2)} m/s` +
      ` (now ${t.speed_along_mps.toFixed(2)} m/s along it), facing ${t.facing_deg.toFixed(0)}°`;
  }
  return `target ${JSON.stringify(t)}`;
}

// Its own line under the label (the label is cut to one line): A's target, and B's beside it.
function showTask(r, b) {
  const parts = [r, b].filter((s) => s && s.task).map((s) => taskText(s.task));
  $("rollout-task").hidden = !parts.length;
  $("rollout-task").textContent = b ? parts.map((p, k) => `${"AB"[k]}: ${p}`).join(" · ") : parts.join("");
}

function sideLabel(r, side) {
  const who = r.run_id !== null ? `run #${r.run_id} ${r.run_name || ""}` : r.checkpoint.split("/").slice(-2).join("/");
  const saved = new Date(r.checkpoint_mtime * 1000).toLocaleTimeString();
  const samples = r.samples >= 1e6 ? `${(r.samples / 1e6).toFixed(2)} M` : r.samples.toLocaleString("en-US");
  const trained = r.samples ? `iteration ${r.iteration}, ${samples} samples` : "no training record";
  const terms = Object.entries(r.reward_terms).map(([k, v]) => `${k} ${v.toFixed(2)}`).join(" · ");
  return `${side ? `${side}: ` : ""}${who} · ${trained} · file saved ${saved}${r.reloads ? ` (reloaded ${r.reloads}×)` : ""}` +
    ` · episode ${r.episode} · return ${r.episode_return.toFixed(2)}${r.waiting ? " · ended, waiting for the other" : ""}` +
    `${terms ? ` · ${terms}` : ""}${r.error ? ` · ${r.error}` : ""}`;
}

const plotOptions = (title) => ({
  title, xLabel: "time (s)", yLabel: "reward", height: 130, window: 10, keep: 60, yRange: [0, 1], colors: { reward: "#ffffff" },
  gaps: true,  // an A/B side holding its pose has no reward: a gap, not a line across
});

export const rolloutView = {
  plot: null, plotB: null, lastStep: -1, bodyError: null,
  init() {
    this.bodyError = new BodyErrorChart($("body-error"));
    this.plot = new CurvePlot($("rollout-plot"), plotOptions("rollout: reward and its terms, last 10 s"));
    this.plotB = new CurvePlot($("rollout-plot-b"), plotOptions("B: reward and its terms, last 10 s"));
  },
  reset() {
    this.lastStep = -1;
    for (const p of [this.plot, this.plotB]) p.clear();
    this.bodyError.clear();
  },
  apply(s) {
    const r = s.rollout, b = r.b;
    for (const id of ["rollout-b", "rollout-b-bar"]) $(id).hidden = !b;
    $("rollout-panel").classList.toggle("ab", !!b);  // the two plots side by side, no error bars
    $("rollout-label").textContent = sideLabel(r, b ? "A" : "");
    showTask(r, b);
    $("clip-label").textContent = b
      ? `A/B: ${r.checkpoint.split("/").slice(-2).join("/")} (front) and ${b.checkpoint.split("/").slice(-2).join("/")} (behind), each episode from the same clip start`
      : `rollout of ${r.checkpoint.split("/").slice(-2).join("/")} in ${r.env_config.split("/").pop()} (ghost: the reference clip)`;
    if (r.real_time_factor !== null) $("clip-label").textContent += ` · ${r.real_time_factor.toFixed(2)}× real time`;
    this.plot.setTitle(b ? "A: reward and its terms, last 10 s" : "rollout: reward and its terms, last 10 s");
    this.bodyError.apply(r.body_error);  // the frame shown's (live or history)
    if (b) $("rollout-label-b").textContent = sideLabel(b, "B");
    pushView.show(r);
    showEnvs(r.envs);  // several envs: falls per env
    const cursor = r.live ? null : s.time;
    for (const p of b ? [this.plot, this.plotB] : [this.plot]) {
      if (cursor !== p.cursor) { p.cursor = cursor; p.draw(); }
    }
  },
  addRows(h) {  // {reset, step, reward_weights, rows}: reset = another rollout, checkpoint or step numbering
    if (h.reset) this.reset();
    const add = (plot, time, side) => {
      if (side.reward === null) plot.addGap(time);
      else plot.add("reward", time, side.reward);
      for (const [k, v] of Object.entries(side.terms)) plot.add(k, time, v);
    };
    for (const row of h.rows) {
      if (row.step <= this.lastStep) continue;
      add(this.plot, row.time, row);
      if (row.b) add(this.plotB, row.time, row.b);
      if (row.push) this.plot.addMarker(row.time, "push", "push");  // where a push began
      if (row.fall_after_push_s !== null) this.plot.addMarker(row.time, "fell", "fall");  // a fall after one
      this.lastStep = row.step;
    }
    this.plot.draw();
    if (this.plotB.series.size) this.plotB.draw();
  },
};

export function initPlayer() {
  rolloutView.init();
  pushView.init(applyState);
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
