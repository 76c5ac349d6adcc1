// The dashboard's entry point: builds each panel (one module each), opens the one event stream that
// feeds them, and shows the banner while the server is gone. Commands go through the REST API; what
// changes is pushed by the server (web/stream.js): no polling. The 3D scene is viser's page in the iframe.
import { $, api, withToken } from "./api.js";
import { fillFitTargets, initCheckpoints, refreshCheckpoints } from "./checkpoints.js";
import { initCompare } from "./compare.js";
import { initAnalysis, sceneChanged } from "./analysis.js";
import { initCurves } from "./curves.js";
import { evalCheckpointsChanged, fillEvalForm, initEvals, renderEvals } from "./evals.js";
import { initKeys } from "./keys.js";
import { initLibrary, loadLibrary, onLibraryLoaded } from "./library.js";
import { applyState, initPlayer, rolloutView } from "./player.js";
import { addLog, addMetrics, fillLaunchForm, initRuns, renderRuns } from "./runs.js";
import { countSceneFrames, initSceneQuality, sceneFps, withSceneDpr } from "./scene_view.js";
import { StudioStream } from "./stream.js";
import { initVideo, renderVideos } from "./video.js";

let sceneUrl = null;
async function loadHealth() {
  const health = await api("GET", "/api/health");
  $("health").textContent = `runs: ${health.runs_dir} · data: ${health.data_dirs.join(", ")}`;
  $("health").title = $("health").textContent;
  sceneUrl = health.viser_port ? health.scene_url || "/scene/" : null;
}

// The scene is relayed by the studio itself (one port, one token check); the token's cookie lets
// viser's page open its websocket, which it does without the query string. `reload` (a new server
// after a restart): a fresh page, since viser's client would otherwise stay on the old, grey scene.
let sceneLoads = 0;
function showScene() {
  if (!sceneUrl) return;
  sceneLoads += 1;
  const url = withSceneDpr(withToken(sceneUrl));
  $("scene").src = sceneLoads === 1 ? url : `${url}${url.includes("?") ? "&" : "?"}reload=${sceneLoads}`;
}

// viser's control panel is minimised (studio/scene/player_gui.py), but under viser's mobile breakpoint (36em
// of the iframe's width) it becomes a bottom sheet that opens expanded over the middle of the 3D view,
// and viser has no setting for that sheet (1.1.1: its BottomPanel always starts expanded; neither
// configure_theme nor main_panel.minimize() reaches it, and the page's own CSS cannot reach into the
// iframe): the page hides it (the scene's iframe is same-origin). Without this the narrow-screen browser
// test finds the sheet, not the canvas, at the centre of the 3D view.
const SCENE_NARROW_CSS = "@media (max-width: 36em) { .mantine-Paper-root[style*='position: fixed'][style*='bottom: 0'] { display: none !important; } }";
$("scene").addEventListener("load", () => {
  const doc = $("scene").contentDocument;
  if (doc && doc.head) doc.head.append(Object.assign(doc.createElement("style"), { textContent: SCENE_NARROW_CSS }));
  if (doc) followStudioFocus($("scene").contentWindow);
  if (doc) countSceneFrames($("scene").contentWindow);
});
// What the 3D view really draws, beside the player (a clip plays at its rate on the server whatever the
// view keeps up with).
setInterval(() => { $("scene-fps").textContent = `3D ${sceneFps()} fps`; }, 1000);

// viser's client (1.1.1, WebsocketInterface.tsx) retries a lost or failed websocket only while its own
// document has the focus, which the embedded scene rarely has: the studio's page has it. A scene whose
// connection failed once stayed grey for good (a CI failure: no frame for 60 s after a restart). Its
// document follows the studio page's focus instead, and a focus of the page is passed on to it.
function followStudioFocus(win) {
  win.document.hasFocus = () => document.hasFocus();
  win.dispatchEvent(new Event("focus"));
}
window.addEventListener("focus", () => {
  const win = $("scene").contentWindow;
  if (win) win.dispatchEvent(new Event("focus"));
});

let serverId = null;
const stream = new StudioStream({
  url: withToken,
  handlers: {
    scene: (s) => { applyState(s); sceneChanged(s); },
    rollout: (h) => rolloutView.addRows(h),
    runs: (runs) => { renderRuns(runs); evalCheckpointsChanged(runs); },
    evals: (jobs) => renderEvals(jobs),
    videos: (jobs) => renderVideos(jobs),
    metrics: (m) => addMetrics(m),
    log: (l) => addLog(l),
  },
  onDown: (attempt) => {
    $("banner").hidden = false;
    $("banner-detail").textContent = attempt > 1 ? `(attempt ${attempt})` : "";
  },
  onUp: async (hello, afterOutage) => {
    $("banner").hidden = true;
    const restarted = serverId !== null && hello.server !== serverId;
    serverId = hello.server;
    if (!afterOutage) return;
    // Back after an outage: the stream re-sent the scene, runs and the selected run's rows; fetch what
    // it does not carry (library, checkpoints) and give a restarted server's scene a fresh page.
    try {
      await loadHealth();
      if (restarted) showScene();
      await loadLibrary();
      refreshCheckpoints();
    } catch (e) { /* gone again: the stream's next error shows the banner */ }
  },
});

onLibraryLoaded((library) => { fillLaunchForm(library); fillFitTargets(library); fillEvalForm(library); });
initLibrary();
initPlayer();
initCurves();
initCompare();
initCheckpoints();
initRuns(stream);
initEvals();
initVideo();
initAnalysis();
initKeys();
initSceneQuality(showScene);
// A clicked button must not keep the focus: Enter would press it again instead of play/pause.
document.addEventListener("mouseup", (ev) => { const b = ev.target.closest && ev.target.closest("button"); if (b) b.blur(); });

async function init() {
  await loadHealth();
  showScene();
  await loadLibrary();
  refreshCheckpoints();
  stream.open({});
}
init().catch((e) => { $("health").textContent = `cannot reach the studio API: ${e.message}`; });
