// The Analysis box: curves of what the scene shows (GET /api/scene/analysis, studio/scene/analysis.py),
// a clip's every frame or a rollout's recorded history with its reference beside it (dashed): the picked
// joints' angles and velocities, the root path (top view, and height over time) and a foot-contact
// timeline. A cursor follows the player; a click on any of them seeks the player there. Nothing is
// fetched while the box is closed; a live rollout is fetched again at most every REFRESH_MS.
import { $, api, el } from "./api.js";
import { CurvePlot, PALETTE } from "./plots.js";
import { playerCommand, sceneState } from "./player.js";

const REFRESH_MS = 2000;
const MAX_JOINTS = 8; // the server's cap (studio/scene/analysis.py MAX_JOINTS)
const REF = " ref";
const CHAR_COLOR = "#f0a830", REF_COLOR = "#3cc878";

let box = null;
let plots = null;
let data = null; // the last analysis
let shownKey = null; // what it was fetched for (sourceKey)
let fetchedStep = null; // a rollout's newest step it holds
let picked = null; // joint names, once the first answer said which are the defaults
let inFlight = false;
let lastFetch = 0;
let refreshTimer = null;

export function initAnalysis() {
  box = $("analysis-box");
  const common = { height: 140, xLabel: "time (s)", gaps: true, onPick: seekTime, dashed: (n) => n.endsWith(REF) };
  plots = {
    angle: new CurvePlot($("analysis-angle"), { ...common, title: "joint angle (rad)", yLabel: "rad" }),
    velocity: new CurvePlot($("analysis-velocity"), { ...common, title: "joint velocity (rad/s)", yLabel: "rad/s" }),
    height: new CurvePlot($("analysis-height"), { ...common, title: "root height (m)", yLabel: "m" }),
  };
  box.addEventListener("toggle", () => { if (box.open) { shownKey = null; sceneChanged(sceneState()); } });
  $("analysis-path").addEventListener("click", (ev) => pickOnPath(ev));
  $("analysis-contacts").addEventListener("click", (ev) => pickOnTimeline(ev));
  new ResizeObserver(() => drawCanvases()).observe($("analysis-contacts"));
}

// Each scene state: fetch again when the clip or rollout changed (or a live rollout moved on, at most
// every REFRESH_MS), and move the cursors.
export function sceneChanged(s) {
  if (!box || !box.open || !s || !s.num_frames) return;
  const key = sourceKey(s);
  const moved = s.mode === "rollout" && s.rollout.step !== fetchedStep;
  const wait = lastFetch + REFRESH_MS - Date.now();
  if (key !== shownKey || (moved && wait <= 0)) fetchAnalysis(key, s);
  // A rollout paused meanwhile sends no more states: its last steps are fetched when the time comes.
  else if (moved && !refreshTimer) refreshTimer = setTimeout(() => { refreshTimer = null; sceneChanged(sceneState()); }, wait);
  if (data && shownKey === key) setCursor(s.time);
}

function sourceKey(s) {
  if (s.mode !== "rollout") return `clip ${s.clip} ${s.char}`;
  const r = s.rollout;
  return `rollout ${r.checkpoint} ${r.checkpoint_mtime} ${r.reloads}`;
}

async function fetchAnalysis(key, s) {
  if (inFlight) return;
  inFlight = true;
  lastFetch = Date.now();
  const query = picked && picked.length ? `?joints=${encodeURIComponent(picked.join(","))}` : "";
  try {
    const a = await api("GET", `/api/scene/analysis${query}`);
    picked = a.picked;
    data = a;
    shownKey = key;
    fetchedStep = s.mode === "rollout" ? s.rollout.step : null;
    $("analysis-status").textContent = status(a);
    renderPicker(a);
    render(a);
  } catch (e) {
    $("analysis-status").textContent = e.message;
    inFlight = false;
    // A joint another character lacks (a new clip or rollout): that one's default joints instead.
    if (picked && /joint/.test(e.message)) { picked = null; fetchAnalysis(key, s); }
  } finally {
    inFlight = false;
  }
  // What the scene shows now: the cursor, or a fetch of what was loaded while this one ran.
  if (shownKey === key) sceneChanged(sceneState());
}

function status(a) {
  const what = a.mode === "rollout" ? `rollout history, ${a.time.length} steps, reference dashed` : `clip, ${a.time.length} frames`;
  return `${what} · ${a.measure}`;
}

function renderPicker(a) {
  const list = $("analysis-joints");
  list.replaceChildren(...a.joints.map((j) => {
    const tick = el("input", { type: "checkbox", value: j.name });
    tick.checked = a.picked.includes(j.name);
    tick.addEventListener("change", () => pickJoints());
    return el("label", { title: j.type === "ball" ? "3 DoF: rotation angle from the zero pose, angular speed" : "hinge: angle, dθ/dt" }, tick, ` ${j.name}`);
  }));
  limitPicks();
}

function limitPicks() {
  const ticks = [...$("analysis-joints").querySelectorAll("input")];
  const full = ticks.filter((t) => t.checked).length >= MAX_JOINTS;
  for (const t of ticks) t.disabled = full && !t.checked;
}

function pickJoints() {
  picked = [...$("analysis-joints").querySelectorAll("input:checked")].map((t) => t.value);
  limitPicks();
  const s = sceneState();
  if (s) fetchAnalysis(sourceKey(s), s);
}

function render(a) {
  const colors = {};
  a.picked.forEach((n, i) => { colors[n] = PALETTE[i % PALETTE.length]; colors[n + REF] = colors[n]; });
  colors.root = CHAR_COLOR;
  colors["root" + REF] = REF_COLOR;
  for (const p of Object.values(plots)) { p.options.colors = colors; p.names = ""; p.clear(); }
  const figures = [["", a.char], ...(a.ref ? [[REF, a.ref]] : [])];
  for (const [suffix, fig] of figures) {
    for (const n of a.picked) {
      addSeries(plots.angle, n + suffix, a.time, fig.angle[n]);
      addSeries(plots.velocity, n + suffix, a.time, fig.velocity[n]);
    }
    addSeries(plots.height, "root" + suffix, a.time, fig.root.z);
  }
  // A rollout's episodes: no line from one episode's end to the next one's start.
  if (a.episode) a.episode.forEach((e, i) => { if (i && e !== a.episode[i - 1]) for (const p of Object.values(plots)) p.addGap(a.time[i] - 0.5 / a.fps); });
  for (const p of Object.values(plots)) p.draw();
  drawCanvases();
}

function addSeries(plot, name, xs, ys) {
  xs.forEach((x, i) => { if (ys[i] !== null) plot.add(name, x, ys[i]); });
}

function setCursor(t) {
  for (const p of Object.values(plots)) p.setCursor(t);
  box.dataset.cursor = String(t);
  drawCanvases();
}

// The frame nearest to time t (a rollout's episode end and the next start share a time: the later).
function nearest(t) {
  const ts = data.time;
  let lo = 0, hi = ts.length - 1;
  while (lo < hi) { const mid = (lo + hi + 1) >> 1; if (ts[mid] <= t) lo = mid; else hi = mid - 1; }
  return lo + 1 < ts.length && ts[lo + 1] - t < t - ts[lo] ? lo + 1 : lo;
}

// A clip seeks its frame; a rollout its time (the history may have moved on since it was fetched).
function seekTime(t) {
  if (!data || !Number.isFinite(t)) return;
  const i = nearest(t);
  playerCommand("seek", data.mode === "rollout" ? { time: data.time[i] } : { frame: i });
}

function cursorIndex() {
  const c = Number(box.dataset.cursor);
  return data && Number.isFinite(c) ? nearest(c) : null;
}

function drawCanvases() {
  if (!data || !box.open) return;
  drawPath($("analysis-path"));
  drawContacts($("analysis-contacts"));
}

// The canvas sized to its box in device pixels; its 2D context.
function fit(canvas) {
  const r = devicePixelRatio || 1, w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== Math.round(w * r) || canvas.height !== Math.round(h * r)) {
    canvas.width = Math.round(w * r);
    canvas.height = Math.round(h * r);
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(r, 0, 0, r, 0, 0);
  ctx.clearRect(0, 0, w, h);
  return [ctx, w, h];
}

// The root path seen from above, x right and y up, one scale on both axes; the shown frame as a dot.
function pathScale(canvas) {
  const figs = [data.char, ...(data.ref ? [data.ref] : [])];
  const xs = figs.flatMap((f) => f.root.x), ys = figs.flatMap((f) => f.root.y);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const w = canvas.clientWidth, h = canvas.clientHeight, pad = 14;
  const k = Math.min((w - 2 * pad) / Math.max(x1 - x0, 0.1), (h - 2 * pad) / Math.max(y1 - y0, 0.1));
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  return { to: (x, y) => [w / 2 + (x - cx) * k, h / 2 - (y - cy) * k], size: `${(x1 - x0).toFixed(2)} × ${(y1 - y0).toFixed(2)} m` };
}

function drawPath(canvas) {
  const [ctx] = fit(canvas);
  const { to, size } = pathScale(canvas);
  const i = cursorIndex();
  const figs = [[data.char, CHAR_COLOR, []], ...(data.ref ? [[data.ref, REF_COLOR, [6, 4]]] : [])];
  for (const [f, color, dash] of figs) {
    ctx.strokeStyle = color; ctx.setLineDash(dash); ctx.lineWidth = 1.5; ctx.beginPath();
    f.root.x.forEach((x, j) => {
      const [px, py] = to(x, f.root.y[j]);
      const jump = j === 0 || (data.episode && data.episode[j] !== data.episode[j - 1]);
      if (jump) ctx.moveTo(px, py); else ctx.lineTo(px, py);
    });
    ctx.stroke();
    if (i !== null) { const [px, py] = to(f.root.x[i], f.root.y[i]); ctx.fillStyle = color; ctx.beginPath(); ctx.arc(px, py, 4, 0, 2 * Math.PI); ctx.fill(); }
  }
  ctx.setLineDash([]); ctx.fillStyle = "#8a91a0"; ctx.font = "11px system-ui, sans-serif";
  ctx.fillText(`root path, top view (x →, y ↑): ${size}`, 6, 12);
  canvas.dataset.points = String(data.char.root.x.length);
}

function pickOnPath(ev) {
  if (!data) return;
  const { to } = pathScale(ev.currentTarget);
  let best = 0, bestD = Infinity;
  data.char.root.x.forEach((x, j) => {
    const [px, py] = to(x, data.char.root.y[j]);
    const d = (px - ev.offsetX) ** 2 + (py - ev.offsetY) ** 2;
    if (d < bestD) { bestD = d; best = j; }
  });
  seekTime(data.time[best]);
}

const LABEL_W = 110;

// One lane per foot (a rollout: the character's, then the reference's, lighter): filled where it
// touches the ground; the shown time as a line.
function contactLanes() {
  const lanes = data.feet.map((f) => [f, data.char.contacts[f], CHAR_COLOR]);
  if (data.ref) for (const f of data.feet) lanes.push([`${f}${REF}`, data.ref.contacts[f], REF_COLOR]);
  return lanes;
}

function timeToX(t, w) {
  const t0 = data.time[0], t1 = data.time[data.time.length - 1];
  return LABEL_W + ((t - t0) / Math.max(t1 - t0, 1e-9)) * (w - LABEL_W - 6);
}

function drawContacts(canvas) {
  const lanes = contactLanes();
  canvas.style.height = `${lanes.length * 16 + 6}px`;
  const [ctx, w] = fit(canvas);
  ctx.font = "11px system-ui, sans-serif";
  lanes.forEach(([name, on, color], k) => {
    const y = 3 + k * 16;
    ctx.fillStyle = "#8a91a0"; ctx.fillText(name, 4, y + 11);
    ctx.fillStyle = color; ctx.globalAlpha = name.endsWith(REF) ? 0.55 : 1;
    for (let i = 0; i < on.length; i++) {  // one bar per run of frames in contact (no seams between frames)
      if (!on[i] || (i > 0 && on[i - 1])) continue;
      let j = i;
      while (j + 1 < on.length && on[j + 1]) j += 1;
      const end = j + 1 < on.length ? data.time[j + 1] : data.time[j] + 1 / data.fps;
      const x = timeToX(data.time[i], w);
      ctx.fillRect(x, y + 2, Math.max(1, timeToX(end, w) - x), 11);
    }
    ctx.globalAlpha = 1;
  });
  const c = Number(box.dataset.cursor);
  if (Number.isFinite(c)) { ctx.fillStyle = "#d8dce4"; ctx.fillRect(timeToX(c, w), 0, 1, canvas.clientHeight); }
  canvas.dataset.lanes = String(lanes.length);
}

function pickOnTimeline(ev) {
  if (!data || ev.offsetX < LABEL_W) return;
  const w = ev.currentTarget.clientWidth;
  const t0 = data.time[0], t1 = data.time[data.time.length - 1];
  seekTime(t0 + ((ev.offsetX - LABEL_W) / (w - LABEL_W - 6)) * (t1 - t0));
}
