"""Throughput measurements of the MuJoCo engine against raw `mujoco.rollout` (not tests: they print figures),
and that raw baseline (`RawRollout`, `raw_rollout(engine)`), which `mimickit bench` times env steps against.
The engine interface knows nothing of it: the bench asks for it here.

`python -m mimickit.engines.bench_util [num_envs ...]` prints env-steps/s of `MujocoEngine` stepping the
project humanoid with random in-range PD targets next to raw rollout on the same compiled model with
the same substeps, and their ratio.
"""

from __future__ import annotations

import copy
import sys
import time
from collections.abc import Sequence

import mujoco
import numpy as np
import torch
from mujoco import rollout

from mimickit.engines.engine import Engine, EngineConfig
from mimickit.engines.engine_records import ObjType
from mimickit.engines.mujoco_engine import MujocoEngine
from mimickit.util.paths import PROJECT_DATA_DIR

HUMANOID_XML = PROJECT_DATA_DIR / "assets" / "humanoid" / "humanoid.xml"
HUMANOID_INIT_ROOT_POS = (0.0, 0.0, 0.882416)


class RawRollout:
    """`mujoco.rollout` advancing N full-physics states in calls of `substeps` physics steps each, with the
    final state fed back in (the RL pattern: a policy acts between calls). The states start as copies of
    `mj_data_list` (only read); `nthread` scratch MjData are rollout's per-thread workspaces."""

    def __init__(self, mj_model: mujoco.MjModel, mj_data_list: Sequence[mujoco.MjData], nthread: int, substeps: int):
        self.model, self.substeps = mj_model, substeps
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        nstate = mujoco.mj_stateSize(mj_model, self._spec)
        self.state = np.empty((len(mj_data_list), nstate))  # [N, nstate]
        for i, d in enumerate(mj_data_list):
            mujoco.mj_getState(mj_model, d, self.state[i], self._spec)
        self._out = np.empty((len(mj_data_list), substeps, nstate))
        self._scratch = [mujoco.MjData(mj_model) for _ in range(nthread)]
        self._rollout = rollout.Rollout(nthread=nthread)

    def step(self, ctrl: np.ndarray) -> float:
        """Advance every state `substeps` steps holding ctrl [N, nu]; returns the seconds it took."""
        ctrl = np.ascontiguousarray(ctrl[:, None, :], dtype=np.float64)  # [N, 1, nu]: tiled over substeps
        start = time.perf_counter()
        self._rollout.rollout(self.model, self._scratch, self.state, ctrl, nstep=self.substeps, state=self._out)
        self.state[:] = self._out[:, -1]
        return time.perf_counter() - start

    def replay(self, state: np.ndarray, warmstart: np.ndarray, ctrl: np.ndarray) -> float:
        """Advance the given states [N, nstate] (warm starts [N, nv]) `substeps` steps holding ctrl [N, nu],
        leaving `self.state` alone; returns the seconds it took."""
        ctrl = np.ascontiguousarray(ctrl[:, None, :], dtype=np.float64)
        start = time.perf_counter()
        self._rollout.rollout(
            self.model, self._scratch, state, ctrl, nstep=self.substeps, initial_warmstart=warmstart, state=self._out
        )
        return time.perf_counter() - start

    @property
    def last_state(self) -> np.ndarray:
        """[N, nstate]: the states after the last call."""
        return self._out[:, -1]

    def close(self) -> None:
        self._rollout.close()


def raw_rollout(engine: Engine) -> RawRollout | None:
    """Raw `mujoco.rollout` on a MuJoCo engine's own compiled model and threads, from copies of its envs'
    current states; None for an engine without a MuJoCo model of its own (Newton): env figures only."""
    if not isinstance(engine, MujocoEngine):
        return None
    return RawRollout(engine.mj_model, engine.mj_datas, engine.num_threads, engine.config.substeps)


def raw_rollout_steps_per_s(
    mj_model: mujoco.MjModel,
    mj_data_list: Sequence[mujoco.MjData],
    nsteps: int,
    nthread: int,
    substeps: int | None = None,
    ctrl: np.ndarray | None = None,
) -> float:
    """Physics steps per second, summed over envs, of `mujoco.rollout` advancing every state in
    `mj_data_list` (only read) by `nsteps` physics steps.

    With `substeps`, rollout is called once per control step of `substeps` physics steps and the final
    state is fed back in; divide the result by `substeps` for env-steps/s. `ctrl` [ncalls, N, nu] is the
    control held during each call (cycled if shorter); default zeros.
    """
    substeps = substeps or nsteps
    ncalls = max(1, nsteps // substeps)
    if ctrl is None:
        ctrl = np.zeros((1, len(mj_data_list), mj_model.nu))
    raw = RawRollout(mj_model, mj_data_list, nthread, substeps)
    try:
        elapsed = sum(raw.step(ctrl[k % len(ctrl)]) for k in range(ncalls))
    finally:
        raw.close()
    return len(mj_data_list) * ncalls * substeps / elapsed


def make_humanoid_engine(num_envs: int, config: EngineConfig | None = None) -> MujocoEngine:
    """A MujocoEngine with one standing project humanoid per env (control pos, 30 Hz / 240 Hz)."""
    config = config or EngineConfig(
        engine_name="mujoco", control_mode="pos", control_freq=30, sim_freq=240, env_spacing=5
    )
    engine = MujocoEngine(config, num_envs, "cpu")
    for _ in range(num_envs):
        env_id = engine.create_env()
        engine.create_obj(env_id, ObjType.articulated, str(HUMANOID_XML), "humanoid", start_pos=HUMANOID_INIT_ROOT_POS)
    engine.initialize_sim()
    return engine


def random_targets(low: np.ndarray, high: np.ndarray, nsteps: int, num_envs: int, seed: int = 0) -> torch.Tensor:
    """[nsteps, num_envs, D] PD targets drawn uniformly within the DoF limits low/high [D]."""
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(nsteps, num_envs, len(low), generator=g, dtype=torch.float64)
    return (torch.from_numpy(low) + u * torch.from_numpy(high - low)).float()


def engine_env_steps_per_s(engine: MujocoEngine, targets: torch.Tensor) -> float:
    """Control steps per second, summed over envs: `set_cmd` + `step` for every row of targets [T, N, D]."""
    start = time.perf_counter()
    for cmd in targets:
        engine.set_cmd(0, cmd)
        engine.step()
    return targets.shape[0] * engine.get_num_envs() / (time.perf_counter() - start)


def compare_engine_to_raw(num_envs: int, nsteps: int = 60, nthread: int = 2) -> dict[str, float]:
    """Env-steps/s of the engine and of raw rollout on the same model, start states, targets, substeps and
    thread count, and their ratio. "raw_nosensor" is rollout on a copy of the model with sensors switched
    off: bare physics, an upper bound. All advance in lockstep, one control step each in turn, so that load
    from other processes on the machine falls on them alike; each is timed on its own part only."""
    config = EngineConfig(engine_name="mujoco", control_mode="pos", control_freq=30, sim_freq=240,
                          env_spacing=5, num_threads=nthread)  # fmt: skip
    engine = make_humanoid_engine(num_envs, config)
    targets = random_targets(*engine.get_obj_dof_limits(0, 0), nsteps, num_envs)
    bare = copy.copy(engine.mj_model)
    bare.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SENSOR
    raws = {
        "raw": RawRollout(engine.mj_model, engine.mj_datas, nthread, config.substeps),
        "raw_nosensor": RawRollout(bare, engine.mj_datas, nthread, config.substeps),
    }
    seconds = dict.fromkeys(["engine", *raws], 0.0)
    try:
        for cmd in targets:
            for name, raw in raws.items():
                seconds[name] += raw.step(cmd.double().numpy())  # actuators in DoF order: targets = controls
            start = time.perf_counter()
            engine.set_cmd(0, cmd)
            engine.step()
            seconds["engine"] += time.perf_counter() - start
    finally:
        for raw in raws.values():
            raw.close()
        engine.close()
    result: dict[str, float] = {"num_envs": num_envs}
    result.update({name: nsteps * num_envs / t for name, t in seconds.items()})
    result["ratio"] = seconds["raw"] / seconds["engine"]
    result["ratio_nosensor"] = seconds["raw_nosensor"] / seconds["engine"]
    return result


def humanoid_init_dof(num_dofs: int = 28) -> torch.Tensor:
    """[D] the humanoid's standing init pose: arms down (shoulder exp-map x = ±π/2), everything else 0."""
    dof = torch.zeros(num_dofs)
    dof[6], dof[10] = 1.5708, -1.5708  # right_shoulder x, left_shoulder x
    return dof


def pd_stability(
    sim_freq: int,
    episodes: int = 20,
    seconds: float = 3.0,
    control_freq: int = 30,
    integrator: str = "implicitfast",
    seed: int = 0,
) -> dict[str, float]:
    """Random in-range PD targets, redrawn every control step, on `episodes` humanoids (one per env) that
    start standing; counts the episodes that blow up (NaN, |qvel| > 1e3 or a MuJoCo instability reset)
    and reports the largest |qvel| of the others and the env-steps/s."""
    config = EngineConfig(engine_name="mujoco", control_mode="pos", control_freq=control_freq, sim_freq=sim_freq,
                          env_spacing=5, integrator=integrator)  # fmt: skip
    engine = make_humanoid_engine(episodes, config)
    engine.set_dof_pos(None, 0, humanoid_init_dof())
    nsteps = round(seconds * control_freq)
    targets = random_targets(*engine.get_obj_dof_limits(0, 0), nsteps, episodes, seed)
    blown = np.zeros(episodes, dtype=bool)
    max_qvel = np.zeros(episodes)
    start = time.perf_counter()
    for cmd in targets:
        engine.set_cmd(0, cmd)
        engine.step()
        qvel = np.abs(np.stack([d.qvel for d in engine.mj_datas])).max(axis=1)
        bad_qacc = np.array([d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0 for d in engine.mj_datas])
        blown |= ~np.isfinite(qvel) | (qvel > 1e3) | bad_qacc
        max_qvel = np.maximum(max_qvel, np.nan_to_num(qvel, nan=np.inf))
    elapsed = time.perf_counter() - start
    engine.close()
    ok = max_qvel[~blown]
    return {
        "sim_freq": sim_freq,
        "blown_up": int(blown.sum()),
        "episodes": episodes,
        "max_abs_qvel": float(ok.max()) if len(ok) else float("nan"),
        "env_steps_per_s": episodes * nsteps / elapsed,
    }


def main(argv: Sequence[str], repeats: int = 3) -> None:
    """Print the engine-vs-raw table; each row is the run with the median ratio of `repeats` lockstep runs."""
    sizes = [int(a) for a in argv] or [64, 256, 1024]
    print(f"env-steps/s, 30 Hz control, 240 Hz sim, 2 threads; median of {repeats} runs")
    print(f"{'envs':>6} {'engine':>8} {'raw':>8} {'ratio':>6} {'raw, no sensors':>16} {'ratio':>6}")
    for n in sizes:
        runs = sorted((compare_engine_to_raw(n) for _ in range(repeats)), key=lambda r: r["ratio"])
        r = runs[len(runs) // 2]
        print(
            f"{n:>6} {r['engine']:>8.0f} {r['raw']:>8.0f} {r['ratio']:>6.3f} "
            f"{r['raw_nosensor']:>16.0f} {r['ratio_nosensor']:>6.3f}"
        )


if __name__ == "__main__":
    main(sys.argv[1:])
