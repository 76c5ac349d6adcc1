// Export MP4: `mimickit video` of what the scene shows (the clip on its character, or the rollout's
// checkpoint with its configs), rendered by the server as a background job (POST /api/videos). The
// job's progress arrives as the stream's `videos` events, with a Stop button while it waits or renders;
// when it has finished, a download link.
import { $, api, el, withToken } from "./api.js";
import { sceneState } from "./player.js";

const WIDTH = 640, HEIGHT = 480;
const ROLLOUT_SECONDS = 10, MAX_CLIP_SECONDS = 30;
let mine = null;      // the id of the job this page started last
let jobs = [];        // the latest `videos` event
let ticker = null;    // while it renders: the elapsed seconds, counted here (no request)

// The request for what the scene shows now, or null when it shows nothing.
function videoRequest(s) {
  if (!s) return null;
  const size = { width: WIDTH, height: HEIGHT };
  if (s.mode === "rollout") {
    const r = s.rollout, body = { checkpoint: r.checkpoint, env_config: r.env_config, agent_config: r.agent_config };
    if (r.engine_config) body.engine_config = r.engine_config;
    return { ...body, ...size, seconds: ROLLOUT_SECONDS };
  }
  if (!s.clip) return null;
  const seconds = Math.min(MAX_CLIP_SECONDS, Math.max(1, Math.round(s.duration * 10) / 10));
  return { clip: s.clip, char: s.char, ...size, seconds };
}

function show(job) {
  const box = $("video-status");
  clearInterval(ticker);
  ticker = null;
  box.hidden = false;
  box.classList.toggle("error", job.status === "failed");
  const what = job.kind === "clip" ? job.clip.split("/").pop() : job.checkpoint.split("/").slice(-2).join("/");
  if (job.status === "finished") {
    const name = `${what.replace(/[^A-Za-z0-9._-]+/g, "_").replace(/\.(pkl|pt)$/, "")}.mp4`;
    const link = el("a", { id: "video-link", href: withToken(job.download), download: name }, name);
    box.replaceChildren(`MP4 of ${what} ready: `, link, ` (${(job.bytes / 1e6).toFixed(2)} MB, ${job.seconds} s)`);
  } else if (job.status === "failed") {
    box.textContent = `MP4 of ${what} failed: ${job.error}`;
  } else if (job.status === "stopped") {
    box.textContent = `MP4 of ${what} stopped`;
  } else {
    // Queued or running: the progress and a Stop button (its render's processes are killed).
    const text = el("span", { id: "video-progress" });
    const stop = el("button", { id: "video-stop", title: "stop this export (its renderer is killed)", onclick: () => stopVideo(job.id) }, "Stop");
    box.replaceChildren(text, " ", stop);
    if (job.status === "running") {
      const tick = () => {
        const s = Math.max(0, Date.now() / 1000 - job.started_at);
        text.textContent = `rendering ${job.seconds} s of ${what} as MP4 (${job.width}×${job.height})… ${s.toFixed(0)} s`;
      };
      tick();
      ticker = setInterval(tick, 1000);
    } else {
      text.textContent = `MP4 of ${what}: waiting for the renderer…`;
    }
  }
  $("export-video").disabled = job.status === "queued" || job.status === "running";
}

// The stream's `videos` event: every job of the server, newest first.
export function renderVideos(list) {
  jobs = list;
  const job = jobs.find((j) => j.id === mine);
  if (job) show(job);
}

async function stopVideo(id) {
  $("video-stop").disabled = true;
  try {
    show(await api("POST", `/api/videos/${id}/stop`, {}));
  } catch (e) {  // it ended meanwhile (409): the stream brings how
    $("video-status").append(` (${e.message})`);
  }
}

async function exportVideo() {
  const body = videoRequest(sceneState());
  const box = $("video-status");
  box.hidden = false;
  if (!body) { box.textContent = "nothing to export: load a clip or a rollout"; return; }
  $("export-video").disabled = true;
  try {
    const job = await api("POST", "/api/videos", body);
    mine = job.id;
    show(jobs.find((j) => j.id === mine && j.status !== "queued") || job);  // the stream may have been faster
  } catch (e) {
    box.classList.add("error");
    box.textContent = `cannot export MP4: ${e.message}`;
    $("export-video").disabled = false;
  }
}

export function initVideo() {
  $("export-video").addEventListener("click", exportVideo);
}
