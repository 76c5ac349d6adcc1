// A rollout of several envs: one small cell per env under the rollout label, coloured by its falls
// (none: grey, then amber to red), red-outlined while its figure is marked by a recent fall; the title
// gives each env's episodes, current step and mean return. Drawn from the stream's scene state.
import { $, el } from "./api.js";

const fallColour = (n) => (n === 0 ? "#59606e" : n === 1 ? "#d9a33a" : n <= 3 ? "#e0702f" : "#e1322d");

export function showEnvs(envs) {
  const box = $("rollout-envs-summary");
  if (!envs || envs.num_envs <= 1) {
    box.hidden = true;
    box.replaceChildren();
    return;
  }
  box.hidden = false;
  const cells = envs.per_env.map((e) => el("span", {
    class: `env-cell${e.marked ? " marked" : ""}`,
    "data-env": String(e.env),
    "data-falls": String(e.falls),
    style: `background:${fallColour(e.falls)}`,
    title: `env ${e.env}${e.env === 0 ? " (main)" : ""}: ${e.episodes} episodes, ${e.falls} falls, step ${e.episode_step}` +
      (e.mean_return === null ? "" : `, mean return ${e.mean_return.toFixed(1)}`),
  }, String(e.falls)));
  box.replaceChildren(`${envs.num_envs} envs (${envs.layout}) · falls: `, ...cells);
}
