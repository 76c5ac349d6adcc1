// The 3D view (viser's page in the iframe): its resolution and the rate it really draws at.
//
// Without a GPU driver (a container, a VM, CI's Chromium) WebGL runs on the CPU (SwiftShader, llvmpipe)
// and each frame of the 3D view costs the page's main thread, which the same-origin iframe shares: a
// click on Pause waited behind the frames (benchmarks/page_latency.py). viser's `fixedDpr` URL setting
// draws fewer pixels; "auto" picks half resolution on a software renderer and leaves viser's own
// adaptive resolution on a GPU. The choice is kept in the browser (localStorage).
import { $ } from "./api.js";

const KEY = "studio-scene-quality";
export const QUALITIES = { auto: null, full: 1, half: 0.5, quarter: 0.25 };
let softwareGl = null;

// The WebGL renderer's name says whether it is a CPU rasteriser.
export function isSoftwareGl() {
  if (softwareGl !== null) return softwareGl;
  try {
    const gl = document.createElement("canvas").getContext("webgl");
    const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
    const name = gl ? String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER)) : "";
    softwareGl = /swiftshader|llvmpipe|softpipe|software/i.test(name);
    const lose = gl && gl.getExtension("WEBGL_lose_context");
    if (lose) lose.loseContext();  // one probe context, not kept
  } catch (e) {
    softwareGl = false;
  }
  return softwareGl;
}

export function sceneQuality() {
  const q = localStorage.getItem(KEY);
  return q in QUALITIES ? q : "auto";
}

// The device-pixel ratio the scene is asked for (null: viser's adaptive one).
export function sceneDpr(quality = sceneQuality()) {
  if (quality === "auto") return isSoftwareGl() ? QUALITIES.half : null;
  return QUALITIES[quality];
}

export function withSceneDpr(url) {
  const dpr = sceneDpr();
  return dpr === null ? url : `${url}${url.includes("?") ? "&" : "?"}fixedDpr=${dpr}`;
}

// Frames the 3D view drew over the last second, counted from viser's own animation-frame callbacks
// (its render loop runs on demand: an idle scene draws about once a second, a playing clip up to the
// screen's rate when the renderer keeps up).
const drawn = [];
export function countSceneFrames(win) {
  const raf = win.requestAnimationFrame.bind(win);
  win.requestAnimationFrame = (cb) => raf((t) => { drawn.push(performance.now()); cb(t); });
}

export function sceneFps() {
  const now = performance.now();
  while (drawn.length && drawn[0] < now - 1000) drawn.shift();
  return drawn.length;
}

export function initSceneQuality(onChange) {
  const sel = $("scene-quality");
  sel.value = sceneQuality();
  sel.title = `3D view resolution (auto: ${isSoftwareGl() ? "half, WebGL runs on the CPU here" : "viser's adaptive one"})`;
  sel.addEventListener("change", () => { localStorage.setItem(KEY, sel.value); onChange(); });
}
