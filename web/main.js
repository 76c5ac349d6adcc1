// The dashboard's entry point: builds each panel (one module each), opens the one event stream that
// feeds them, and shows the banner while the server is gone. Commands go through the REST API; what
// changes is pushed by the server (web/stream.js): no polling. The 3D scene is viser's page in the iframe.
import { $, api, withToken } from "./api.js";
import { fillFitTargets, initCheckpoints, refreshCheckpoints } from "./checkpoints.js";
import { initCompare } from "./compare.js";
import { initCurves } from "./curves.js";
import { evalCheckpointsChanged, fillEvalForm, initEvals, renderEvals } from "./evals.js";
import { initKeys } from "./keys.js";
import { initLibrary, loadLibrary, onLibraryLoaded } from "./library.js";
import { applyState, initPlayer, rolloutView } from "./player.js";
import { addLog, addMetrics, fillLaunchForm, initRuns, renderRuns } from "./runs.js";
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
  const url = withToken(sceneUrl);
  $("scene").src = sceneLoads === 1 ? url : `${url}${url.includes("?") ? "&" : "?"}reload=${sceneLoads}`;
}

// viser's control panel is minimised (studio/player_gui.py), but under viser's mobile breakpoint (36em
// of the iframe's width) it becomes a bottom sheet that opens expanded over the middle of the 3D view,
// and viser has no setting for that sheet: the page hides it (the scene's iframe is same-origin).
const SCENE_NARROW_CSS = "@media (max-width: 36em) { .mantine-Paper-root[style*='position: fixed'][style*='bottom: 0'] { display: none !important; } }";
$("scene").addEventListener("load", () => {
  const doc = $("scene").contentDocument;
  if (doc && doc.head) doc.head.append(Object.assign(doc.createElement("style"), { textContent: SCENE_NARROW_CSS }));
});

let serverId = null;
const stream = new StudioStream({
  url: withToken,
  handlers: {
    scene: (s) => applyState(s),
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
initKeys();
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
