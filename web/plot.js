// A small line plot on a <canvas>: several named series, autoscaled axes, a legend, labelled vertical
// markers (a run's resumes) and marks where a series went non-finite (NaN/inf: no point to draw, but a
// red tick with its token at the top). Enough for training curves; no library (the studio runs without internet).
"use strict";

const PLOT_COLORS = ["#f0a830", "#5a9ae0", "#3cc878", "#e0564f", "#b77fe0", "#40c8c8", "#e07fb0", "#a0a060"];

class LinePlot {
  // options: window (keep only the last `window` x units), yRange ([lo, hi], fixed axis),
  // colors ({name: color}); `marker` (an x value) draws a vertical line there.
  constructor(canvas, title, options = {}) {
    this.canvas = canvas;
    this.title = title;
    this.options = options;
    this.series = new Map(); // name -> [[x, y], ...]
    this.marker = null;
    this.markers = []; // [{x, label}]: labelled dashed lines (resumes)
    this.nonfinite = []; // [{name, x, token}]: where a series had no finite value
  }

  clear() {
    this.series.clear();
    this.markers = [];
    this.nonfinite = [];
    this.draw();
  }

  addMarker(x, label) {
    if (Number.isFinite(x)) this.markers.push({ x, label });
  }

  markNonfinite(name, x, token) {
    if (Number.isFinite(x)) this.nonfinite.push({ name, x, token });
  }

  add(name, x, y) {
    if (!Number.isFinite(x) || !Number.isFinite(y)) return;
    if (!this.series.has(name)) this.series.set(name, []);
    const pts = this.series.get(name);
    pts.push([x, y]);
    const w = this.options.window;
    if (w && pts[0][0] < x - w * 1.5) {  // trim now and then, not on every point
      const keep = pts.findIndex(([px]) => px >= x - w);
      pts.splice(0, keep);
    }
  }

  bounds() {
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
    for (const pts of this.series.values()) {
      for (const [x, y] of pts) {
        x0 = Math.min(x0, x); x1 = Math.max(x1, x);
        y0 = Math.min(y0, y); y1 = Math.max(y1, y);
      }
    }
    for (const { x } of [...this.markers, ...this.nonfinite]) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); }
    if (!Number.isFinite(y0)) { y0 = 0; y1 = 1; }  // only non-finite marks so far
    const w = this.options.window;
    if (w && Number.isFinite(x1)) x0 = Math.max(x0, x1 - w);
    if (this.options.yRange) [y0, y1] = this.options.yRange;
    if (x0 === x1) { x0 -= 1; x1 += 1; }
    if (y0 === y1) { y0 -= 1; y1 += 1; }
    return [x0, x1, y0, y1];
  }

  draw() {
    // Let tests (and curious users) see what is drawn.
    this.canvas.dataset.series = String(this.series.size);
    this.canvas.dataset.markers = String(this.markers.length);
    this.canvas.dataset.nonfinite = String(new Set(this.nonfinite.map((m) => m.x)).size);
    // Draw at the element's real size so lines stay sharp when CSS scales the canvas.
    const c = this.canvas, ratio = window.devicePixelRatio || 1;
    const w = c.clientWidth || c.width, h = c.clientHeight || c.height;
    if (c.width !== Math.round(w * ratio)) { c.width = Math.round(w * ratio); c.height = Math.round(h * ratio); }
    const g = c.getContext("2d");
    g.setTransform(ratio, 0, 0, ratio, 0, 0);
    g.clearRect(0, 0, w, h);
    g.font = "11px system-ui, sans-serif";
    g.fillStyle = "#8a91a0";
    g.fillText(this.title, 6, 12);
    if (this.series.size === 0 && this.nonfinite.length === 0) { g.fillText("no data yet", w / 2 - 28, h / 2); return; }
    const pad = { l: 46, r: 8, t: 18, b: 16 };
    const [x0, x1, y0, y1] = this.bounds();
    const sx = (x) => pad.l + (x - x0) / (x1 - x0) * (w - pad.l - pad.r);
    const sy = (y) => h - pad.b - (y - y0) / (y1 - y0) * (h - pad.t - pad.b);
    g.strokeStyle = "#2e323c";
    g.beginPath(); g.moveTo(pad.l, pad.t); g.lineTo(pad.l, h - pad.b); g.lineTo(w - pad.r, h - pad.b); g.stroke();
    g.fillText(fmt(y1), 2, pad.t + 4); g.fillText(fmt(y0), 2, h - pad.b);
    g.fillText(fmt(x1), w - pad.r - 40, h - 3);
    if (this.marker !== null && this.marker >= x0 && this.marker <= x1) {
      g.strokeStyle = "#d8dce4"; g.setLineDash([3, 3]); g.beginPath();
      g.moveTo(sx(this.marker), pad.t); g.lineTo(sx(this.marker), h - pad.b); g.stroke(); g.setLineDash([]);
    }
    for (const m of this.markers) {
      if (m.x < x0 || m.x > x1) continue;
      g.strokeStyle = "#8fa8ff"; g.setLineDash([4, 3]); g.beginPath();
      g.moveTo(sx(m.x), pad.t); g.lineTo(sx(m.x), h - pad.b); g.stroke(); g.setLineDash([]);
      g.fillStyle = "#8fa8ff"; g.fillText(m.label, sx(m.x) + 3, h - pad.b - 4);
    }
    const shown = new Set();
    for (const m of this.nonfinite) {
      if (m.x < x0 || m.x > x1) continue;
      g.strokeStyle = "#ff4d4d"; g.lineWidth = 2; g.beginPath();
      g.moveTo(sx(m.x), pad.t); g.lineTo(sx(m.x), pad.t + 10); g.stroke(); g.lineWidth = 1;
      const key = String(m.x);  // one label per iteration, however many columns went non-finite there
      if (!shown.has(key)) { shown.add(key); g.fillStyle = "#ff4d4d"; g.fillText(`${m.token} ${m.name.replace("reward_terms.", "")}`, sx(m.x) + 3, pad.t + 20); }
    }
    let i = 0, legendX = Math.max(60, g.measureText(this.title).width - 24);
    for (const [name, pts] of this.series) {
      const color = (this.options.colors && this.options.colors[name]) || PLOT_COLORS[i % PLOT_COLORS.length];
      i++;
      g.strokeStyle = color; g.lineWidth = 1.5; g.beginPath();
      let started = false;
      for (const [x, y] of pts) {
        if (x < x0) continue;
        if (started) g.lineTo(sx(x), sy(y)); else { g.moveTo(sx(x), sy(y)); started = true; }
      }
      g.stroke();
      g.fillStyle = color;
      const label = name.replace("reward_terms.", "");
      g.fillText(label, legendX + 40, 12);
      legendX += g.measureText(label).width + 10;
    }
  }
}

function fmt(v) {
  const a = Math.abs(v);
  if (a >= 1e4 || (a > 0 && a < 1e-2)) return v.toExponential(1);
  return v.toFixed(a >= 100 ? 0 : 2);
}
