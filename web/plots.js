// Line plots on uPlot (vendored in web/vendor/, MIT): named series on one x axis, axes with ticks and
// labels, labelled vertical markers (a run's resumes, where it diverged), red ticks where a series went
// non-finite (NaN/inf: no point to draw), an optional cursor line (the rollout's shown step) and
// exponential smoothing. The page's one plotting code: run curves, compared runs, rollout reward terms.
import uPlot from "./vendor/uPlot.esm.js";

export const PALETTE = ["#f0a830", "#5a9ae0", "#3cc878", "#e0564f", "#b77fe0", "#40c8c8", "#e07fb0", "#a0a060"];
const AXIS = { stroke: "#8a91a0", grid: { stroke: "#2a2e37", width: 1 }, ticks: { stroke: "#2e323c", width: 1 }, font: "11px system-ui, sans-serif", labelFont: "11px system-ui, sans-serif" };
const MARKER_COLORS = { resume: "#8fa8ff", diverged: "#ff4d4d", push: "#00c8ff", fall: "#ff4d4d" };

export class CurvePlot {
  // options: title, xLabel, yLabel, height, window (show the last `window` x units, or those around the
  // cursor when it is further back), keep (x units kept for that, default `window`), yRange ([lo, hi]: the
  // least y range shown, widened to take in every value: an AMP rollout's style reward is above 1),
  // colors ({name: color}), gaps (true: lines break at `addGap` points instead of spanning missing values),
  // dashed (name => true for a series drawn dashed: a reference beside the simulated one), onPick (x => …,
  // called with the x of a click in the plot); `cursor` (an x value, or null, `setCursor`) draws a dashed line there.
  // log (a log y axis: values ≤ 0 are not drawn, and the plot says how many), onLog (on => …: the plot
  // shows a "log" toggle, which calls it), nearest (the legend gives each series' value nearest the cursor:
  // compared runs have their rows at different x), sync (a key: plots of one key move their cursors together).
  constructor(container, options = {}) {
    this.box = container;
    this.options = { height: 150, ...options };
    this.series = new Map(); // name -> {xs, ys}
    this.markers = []; // [{x, label, kind}]
    this.nonfinite = []; // [{name, x, token}]
    this.gaps = []; // x values where no series has a value (an A/B side holding its pose)
    this.cursor = null;
    this.smoothing = 0;
    this.uplot = null;
    this.names = ""; // the series the uPlot instance was built for
    this.pending = false;
    this.dropped = 0; // values ≤ 0 a log axis did not draw
    if (this.options.onLog) this._logTools();
    this.resizer = new ResizeObserver(() => this._resize());
    this.resizer.observe(container);
    this.draw();
  }

  // A plot taken off the page: its uPlot leaves its cursor-sync group (it would go on being moved).
  destroy() {
    this.resizer.disconnect();
    if (this.uplot) this.uplot.destroy();
    this.uplot = null;
    this.dead = true;  // a frame already asked for draws nothing
  }

  // The "log" toggle and the note of what a log axis leaves out, over the plot's top right corner.
  _logTools() {
    const button = document.createElement("button");
    button.className = "plot-log";
    button.textContent = "log";
    button.title = "log scale for this plot's y axis (values ≤ 0 are left out)";
    button.addEventListener("click", (ev) => { ev.stopPropagation(); this.options.onLog(!this.options.log); });
    this.note = document.createElement("span");
    this.note.className = "plot-note";
    const tools = document.createElement("div");
    tools.className = "plot-tools";
    tools.append(this.note, button);
    this.box.append(tools);
    this.logButton = button;
  }

  setLog(on) {
    if (!!this.options.log === on) return;
    this.options.log = on;
    this.names = "";  // the y scale's distribution is fixed at construction: build again
    this.draw();
  }

  clear() {
    this.series.clear();
    this.markers = [];
    this.nonfinite = [];
    this.gaps = [];
    this.draw();
  }

  addGap(x) {
    if (!Number.isFinite(x)) return;
    this.gaps.push(x);
    const w = this._kept();
    if (w && this.gaps[0] < x - w * 1.5) this.gaps = this.gaps.filter((g) => g >= x - w);
  }

  add(name, x, y) {
    if (!Number.isFinite(x) || !Number.isFinite(y)) return;
    if (!this.series.has(name)) this.series.set(name, { xs: [], ys: [] });
    const s = this.series.get(name);
    s.xs.push(x);
    s.ys.push(y);
    const w = this._kept();
    if (w && s.xs[0] < x - w * 1.5) {  // trim now and then, not on every point
      const keep = s.xs.findIndex((px) => px >= x - w);
      s.xs.splice(0, keep);
      s.ys.splice(0, keep);
    }
  }

  _kept() {
    return this.options.keep ?? this.options.window;
  }

  addMarker(x, label, kind = "resume") {
    if (Number.isFinite(x)) this.markers.push({ x, label, kind });
  }

  markNonfinite(name, x, token) {
    if (Number.isFinite(x)) this.nonfinite.push({ name, x, token });
  }

  // Only the overlay is drawn again (uPlot keeps the curves' paths): a cursor that follows the player
  // at 10 Hz costs no re-alignment of thousands of points.
  setCursor(x) {
    if (this.cursor === x) return;
    this.cursor = x;
    if (this.uplot && !this.pending) this.uplot.redraw(false, false);
  }

  setXLabel(label) {
    if (this.options.xLabel === label) return;
    this.options.xLabel = label;
    this.names = "";  // axis labels are fixed at construction: build again
  }

  setTitle(title) {
    if (this.options.title === title) return;
    this.options.title = title;
    this.names = "";  // the title is fixed at construction: build again
    this.draw();
  }

  // Many rows arrive at once when a stream starts: draw once per animation frame.
  draw() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => { this.pending = false; if (!this.dead) this._draw(); });
  }

  _draw() {
    const names = [...this.series.keys()];
    this.box.dataset.series = String(names.filter((n) => this.series.get(n).xs.length).length);
    this.box.dataset.markers = String(this.markers.length);
    this.box.dataset.nonfinite = String(new Set(this.nonfinite.map((m) => m.x)).size);
    this.box.classList.toggle("empty", names.length === 0 && this.nonfinite.length === 0);
    const key = names.join("\u0000");
    if (!this.uplot || key !== this.names) this._build(names, key);
    this.uplot.setData(this._aligned(names), true);
    this._showLog();
  }

  _showLog() {
    const log = !!this.options.log;
    this.box.dataset.log = String(log);
    this.box.dataset.dropped = String(this.dropped);
    if (!this.logButton) return;
    this.logButton.setAttribute("aria-pressed", String(log));
    this.note.textContent = this.dropped ? `${this.dropped} values ≤ 0 not drawn` : "";
  }

  // uPlot wants one x array and, per series, a y (or null) for each x.
  _aligned(names) {
    const xs = new Set();
    for (const s of this.series.values()) for (const x of s.xs) xs.add(x);
    for (const m of [...this.markers, ...this.nonfinite]) xs.add(m.x);
    for (const g of this.gaps) xs.add(g);
    let x = [...xs].sort((a, b) => a - b);
    const w = this.options.window;
    if (w && x.length) {  // the last `w` units, or `w` around a cursor further back (a rollout scrubbed back)
      const last = x[x.length - 1], c = this.cursor;
      const end = c !== null && c < last - w ? Math.min(last, c + w / 2) : last;
      x = x.filter((v) => v >= end - w && v <= end);
    }
    const index = new Map(x.map((v, i) => [v, i]));
    const data = [x], log = !!this.options.log;
    this.dropped = 0;
    for (const n of names) {
      const s = this.series.get(n), y = new Array(x.length).fill(null);
      const ys = smooth(s.ys, this.smoothing);
      s.xs.forEach((px, i) => {
        const j = index.get(px);
        if (j === undefined) return;
        if (log && ys[i] <= 0) this.dropped += 1;  // no place on a log axis: left out, and counted
        else y[j] = ys[i];
      });
      data.push(y);
    }
    return data;
  }

  _build(names, key) {
    if (this.uplot) this.uplot.destroy();
    this.names = key;
    const o = this.options, colors = o.colors || {};
    const yRange = o.yRange;
    const y = o.log
      ? { distr: 3, log: 10, range: (u, lo, hi) => (lo === null ? [1, 10] : uPlot.rangeLog(lo, hi, 10, true)) }
      : { range: (u, lo, hi) => (yRange ? coverRange(yRange, lo, hi) : padRange(lo, hi)) };
    // uPlot's own hover: `skip` null values makes each series' legend value its nearest point, not "–".
    const cursor = { drag: { x: false, y: false }, ...(o.nearest ? { hover: { skip: [null, undefined] } } : {}),
      ...(o.sync ? { sync: { key: o.sync } } : {}) };
    const opts = {
      width: Math.max(100, this.box.clientWidth), height: o.height,
      title: o.title,
      scales: { x: { time: false }, y },
      axes: [{ ...AXIS, label: o.xLabel, size: 34, labelSize: 14, values: (u, v) => v.map(fmt) },
             { ...AXIS, label: o.yLabel, size: 48, labelSize: 14, values: (u, v) => v.map(fmt) }],
      series: [{ label: o.xLabel || "x", value: (u, v) => (v === null ? "–" : fmt(v)) },
        ...names.map((n, i) => ({
          label: n.replace("reward_terms.", ""), stroke: colors[n] || PALETTE[i % PALETTE.length], width: 1.5,
          spanGaps: !o.gaps, points: { show: false }, value: (u, v) => (v === null ? "–" : fmt(v)),
          ...(o.dashed && o.dashed(n) ? { dash: [6, 4] } : {}),
        }))],
      legend: { show: true, live: true },
      cursor,
      hooks: { draw: [(u) => this._drawn(u)] },
    };
    this.uplot = new uPlot(opts, [[], ...names.map(() => [])], this.box);
    if (o.onPick) this.uplot.over.addEventListener("click", (ev) => o.onPick(this.uplot.posToVal(ev.offsetX, "x")));
  }

  _resize() {
    if (this.uplot && this.box.clientWidth > 0 && Math.abs(this.uplot.width - this.box.clientWidth) > 1) {
      this.uplot.setSize({ width: this.box.clientWidth, height: this.options.height });
    }
  }

  _drawn(u) {
    this._overlay(u);
    const d = this.box.dataset;  // the axes' ranges drawn, for a reader of the page (and its tests)
    d.xRange = `${u.scales.x.min},${u.scales.x.max}`;
    d.yRange = `${u.scales.y.min},${u.scales.y.max}`;
  }

  // Markers, non-finite ticks and the cursor line, drawn over the curves.
  _overlay(u) {
    const { ctx } = u, { top, height } = u.bbox, ratio = devicePixelRatio || 1;
    const [x0, x1] = [u.scales.x.min, u.scales.x.max];
    const at = (x) => u.valToPos(x, "x", true);
    const vline = (x, color, dash, label, labelY) => {
      ctx.save();
      ctx.strokeStyle = color; ctx.lineWidth = ratio; ctx.setLineDash(dash.map((d) => d * ratio));
      ctx.beginPath(); ctx.moveTo(at(x), top); ctx.lineTo(at(x), top + height); ctx.stroke();
      if (label) { ctx.setLineDash([]); ctx.fillStyle = color; ctx.font = `${11 * ratio}px system-ui, sans-serif`; ctx.fillText(label, at(x) + 3 * ratio, labelY); }
      ctx.restore();
    };
    for (const m of this.markers) if (m.x >= x0 && m.x <= x1) vline(m.x, MARKER_COLORS[m.kind] || MARKER_COLORS.resume, [4, 3], m.label, top + height - 4 * ratio);
    const shown = new Set();
    for (const m of this.nonfinite) {
      if (m.x < x0 || m.x > x1) continue;
      const key = String(m.x);  // one label per iteration, however many columns went non-finite there
      vline(m.x, "#ff4d4d", [], shown.has(key) ? "" : `${m.token} ${m.name.replace("reward_terms.", "")}`, top + 12 * ratio);
      shown.add(key);
    }
    if (this.cursor !== null && this.cursor >= x0 && this.cursor <= x1) vline(this.cursor, "#d8dce4", [3, 3], "", 0);
    this.box.dataset.cursor = this.cursor === null ? "" : String(this.cursor);  // what is drawn, for the page's tests
  }
}

// Exponential moving average with TensorBoard's debiasing: weight 0 is the raw curve.
export function smooth(ys, weight) {
  if (!weight) return ys;
  let last = 0, n = 0;
  return ys.map((y) => { last = last * weight + (1 - weight) * y; n += 1; return last / (1 - weight ** n); });
}

function coverRange([least, most], lo, hi) {
  if (lo === null || hi === null || (lo >= least && hi <= most)) return [least, most];
  return padRange(Math.min(lo, least), Math.max(hi, most));
}

function padRange(lo, hi) {
  if (lo === null || hi === null) return [0, 1];
  if (lo === hi) return [lo - 1, hi + 1];
  const pad = (hi - lo) * 0.05;
  return [lo - pad, hi + pad];
}

export function fmt(v) {
  if (v === null || v === undefined) return "";
  const a = Math.abs(v);
  if (a >= 1e6) return `${+(v / 1e6).toFixed(2)}M`;
  if (a >= 1e4) return `${+(v / 1e3).toFixed(1)}k`;
  if (a > 0 && a < 1e-2) return v.toExponential(1);
  return String(+v.toFixed(a >= 100 ? 0 : 2));
}
