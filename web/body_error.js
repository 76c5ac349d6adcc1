// The rollout panel's per-body tracking error: one bar per body of the character (model order), for the
// frame the scene shows (the live end or a history frame), with a legend. Each bar's colour comes with the
// state (`rollout.body_error.colours`, studio/scene/view.py's error_colour), so a bar has the colour of its
// body in the 3D view; the legend draws the same stops over the same scale.
import { el } from "./api.js";

const rgb = (c) => `rgb(${c[0]}, ${c[1]}, ${c[2]})`;
const short = (name) => name.replace(/^left_/, "L ").replace(/^right_/, "R ").replace(/_/g, " ");

export class BodyErrorChart {
  constructor(box) {
    this.box = box;
    this.names = null;
    this.bars = [];
  }

  clear() {
    this.box.replaceChildren();
    this.box.hidden = true;
    this.names = null;
    this.bars = [];
  }

  _build(err) {
    this.names = err.bodies.join(",");
    const stops = err.stops.map(rgb).join(", ");
    this.legend = el("span", { class: "be-mean" });
    const chart = el("div", { class: "be-chart" });
    this.bars = err.bodies.map((name) => {
      const fill = el("div", { class: "be-fill" });
      const col = el("div", { class: "be-col", "data-body": name }, el("div", { class: "be-track" }, fill),
        el("span", { class: "be-name" }, short(name)));
      chart.append(col);
      return { col, fill, name };
    });
    this.box.replaceChildren(
      el("div", { class: "be-title" }, "tracking error per body (m)", this.legend),
      chart,
      el("div", { class: "be-legend", title: err.measure },
        el("span", {}, "0"),
        el("span", { class: "be-scale", style: `background: linear-gradient(to right, ${stops})` }),
        el("span", {}, `≥ ${err.scale_m} m`),
        el("span", { class: "muted" }, " root-relative; the root: global")),
    );
    this.box.hidden = false;
  }

  apply(err) {  // the state's `rollout.body_error`, null when the env has no reference
    if (!err) { if (this.names !== null) this.clear(); return; }
    if (err.bodies.join(",") !== this.names) this._build(err);
    this.legend.textContent = ` · mean ${err.mean_m.toFixed(3)}`;
    err.errors_m.forEach((e, i) => {
      const { col, fill, name } = this.bars[i];
      const c = err.colours[i];
      fill.style.height = `${(100 * Math.min(e / err.scale_m, 1)).toFixed(1)}%`;
      fill.style.background = rgb(c);
      col.dataset.error = String(e);
      col.dataset.colour = c.join(",");
      col.title = `${name}: ${(e * 100).toFixed(1)} cm`;
    });
  }
}
