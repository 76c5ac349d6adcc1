"""The training loop shared by every agent, as the reference's `BaseAgent`.

An agent owns the observation and action normalisers, its model and optimisers, an experience buffer
of `steps_per_iter` rows × `num_envs`, and train/test return trackers. It talks to the env only
through `BaseEnv`: `reset(env_ids)`, `step(action)`, spaces, `set_mode`, `record_diagnostics`; when the
env's info holds `reward_terms` / `tracking` dicts of [N] tensors, their means over each training
rollout go to metrics.jsonl and TensorBoard.

Checkpoints (`model.pt`): the agent's `state_dict()` (reference key names: `_obs_norm.*`, `_a_norm.*`,
`_model.*`), plus one extra key `_train_state` holding what a resumed run needs (next iteration,
global sample count, wall time, last test result, optimiser states). `load()` loads the model and
normaliser keys strictly and restores `_train_state` when present, so `train_model` continues the
curve; a reference checkpoint (no `_train_state`) loads as a fresh start. The reference's own strict
loader would reject the extra key: `save(path, include_train_state=False)` writes a file it accepts.
Writes are atomic (a reader never sees half a file).

Stopping: `request_stop()` (safe from a signal handler) ends `train_model` after the current
iteration (single process: also between rollout steps, discarding the partial iteration), saves
`model.pt` and returns. With several processes the flag is all-reduced once per iteration so every
rank stops at the same iteration. `test_model` also stops between steps.
"""

from __future__ import annotations

import abc
import copy
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from mimickit.envs.base_env import BaseEnv, DoneFlags, EnvMode
from mimickit.learning import checkpoint, mp_util
from mimickit.learning.agent_config import BaseAgentConfig
from mimickit.learning.checkpoint import TRAIN_STATE_KEY
from mimickit.learning.divergence import first_non_finite, gradient_norm
from mimickit.learning.experience_buffer import ExperienceBuffer
from mimickit.learning.logger import Logger
from mimickit.learning.mp_optimizer import MPOptimizer
from mimickit.learning.normalizer import Normalizer
from mimickit.learning.return_tracker import ReturnTracker
from mimickit.learning.run_folder import INT_MODELS_DIR, MODEL_FILE, int_model_name, resume_row
from mimickit.learning.update_threads import update_threads
from mimickit.util.errors import MimicKitError
from mimickit.util.threads import torch_threads

_OBS_CLIP = 10.0


class AgentMode(IntEnum):
    TRAIN = 0
    TEST = 1


@dataclass
class EpisodeStats:
    """Undiscounted mean return and length (steps) of finished episodes, over all processes, and how many
    of them ended in failure (`num_fail`)."""

    mean_return: float = 0.0
    mean_ep_len: float = 0.0
    num_eps: int = 0
    num_fail: int = 0

    def to_dict(self) -> dict[str, float | int]:
        """For printing / JSON: `mean_return`, `mean_episode_length`, `episodes`."""
        return {"mean_return": self.mean_return, "mean_episode_length": self.mean_ep_len, "episodes": self.num_eps}


@dataclass
class TrainSummary:
    iterations: int
    """Iterations completed, counting those of a resumed checkpoint."""
    samples: int
    """Global env steps, counting those of a resumed checkpoint."""
    stopped: bool
    """True when `request_stop()` ended training before `max_samples`."""
    model_file: Path
    diverged: str = ""
    """The reason line when the divergence guard ended training (`diverged at iteration N: ...`)."""
    out_of_time: bool = False
    """True when the recorded wall time reached `max_hours` (the run ended as it does at `max_samples`)."""


@dataclass
class IterationStep:
    """What one `train_iteration` did."""

    info: dict[str, float]
    """The iteration's losses and statistics (the metrics row's training columns)."""
    non_finite: str | None
    """The divergence reason (`critic loss is nan`), the same on every process; None when all was finite."""
    before: dict[str, Any]
    """The agent's state before the iteration (weights, optimisers, samples), to roll a divergence back."""
    timing: dict[str, float]
    """Seconds in `time.sim_s`, `time.inference_s`, `time.update_s`, and `time.samples_per_s`."""


class BaseAgent(nn.Module, abc.ABC):
    def __init__(self, config: BaseAgentConfig, env: BaseEnv, device: torch.device | str) -> None:
        super().__init__()
        self.config = config
        self._env = env
        self._device = torch.device(device)
        self._iter = 0
        self._sample_count = 0
        self._wall_time_offset = 0.0  # hours of training before the current train_model call
        self._train_start: float | None = None
        self._last_test = EpisodeStats()
        self._resumed = False
        self._stop_requested = False
        self._mode = AgentMode.TRAIN

        self._build_normalizers()
        self._build_model()
        self.to(self._device)
        self._build_optimizers()
        self._exp_buffer = ExperienceBuffer(self._get_exp_buffer_length(), env.get_num_envs(), self._device)
        self._train_return_tracker = ReturnTracker(env.get_num_envs(), self._device)
        self._test_return_tracker = ReturnTracker(env.get_num_envs(), self._device)
        self._info_sums: dict[str, torch.Tensor] = {}
        self._info_steps = 0
        self._sim_time = 0.0
        self._iter_timing: dict[str, float] = {}
        self._curr_obs: torch.Tensor | None = None
        self._curr_info: dict[str, Any] = {}

    # ---------------------------------------------------------------- public API

    def train_model(
        self,
        max_samples: int,
        out_dir: str | Path,
        save_int_models: bool = False,
        logger_type: str = "txt",
        max_hours: float | None = None,
    ) -> TrainSummary:
        """Train until the global sample count reaches `max_samples`, the recorded wall time (resumes
        included, as metrics.jsonl's `wall_time`) reaches `max_hours`, `request_stop()` is called or an
        iteration diverges.

        Every `iters_per_output` iterations (and the last): test episodes, a log.txt row, `model.pt`
        (and `int_models/model_{iter:010d}.pt` with `save_int_models`). Every iteration: the terminal
        table and a metrics.jsonl line; a resumed run first writes one resume marker row there.
        Divergence guard: an iteration with a non-finite observation, action, reward, loss, gradient
        norm or weight ends training. Its metrics row keeps the NaN/inf values; the reason goes to the
        terminal and to log.txt (as a `#` line); the agent is rolled back to the finite state that
        iteration started from, which `model.pt` then holds (so model.pt never holds non-finite weights).
        """
        out_dir = Path(out_dir)
        model_file = out_dir / MODEL_FILE
        int_dir = out_dir / INT_MODELS_DIR if save_int_models else None
        logger = self._open_run(out_dir, int_dir, logger_type, max_samples)
        saved_iter = None
        diverged = ""
        out_of_time = False
        try:
            while self._sample_count < max_samples and not out_of_time and not self._sync_stop_flag():
                step = self.train_iteration()
                if step is None:  # stopped mid-rollout: the partial iteration is discarded
                    break
                out_of_time = self._out_of_time(max_hours)
                output = not step.non_finite and self._is_output_iter(max_samples, out_of_time)
                self._log_iteration(logger, step.info, output)
                if step.non_finite:
                    diverged = self._diverge(logger, step, model_file, saved_iter)
                    break
                if output:
                    self._write_output(logger, model_file, int_dir)
                    saved_iter = self._iter
                self._iter += 1
            stopped = not diverged and not out_of_time and self._sample_count < max_samples
            if stopped and saved_iter != self._iter - 1 and self._iter > 0:
                self._write_checkpoint(model_file, self._iter)
        finally:
            self._wall_time_offset = self._current_wall_hours()
            self._train_start = None
            logger.close()
        return TrainSummary(self._iter, self._sample_count, stopped, model_file, diverged, out_of_time and not diverged)

    def _open_run(self, out_dir: Path, int_dir: Path | None, logger_type: str, max_samples: int) -> Logger:
        """The run folder (rank 0 makes it and clears the temp files of a save that crashed), its logger,
        fresh episodes and the clock; a resumed run's marker row."""
        if mp_util.is_root_proc():
            out_dir.mkdir(parents=True, exist_ok=True)
            checkpoint.remove_stale_temp_files(out_dir)
            if int_dir is not None:
                int_dir.mkdir(exist_ok=True)
        resumed = self._resumed
        logger = Logger(
            out_dir, logger_type, append=resumed, max_samples=max_samples, run_config=self.config.model_dump()
        )
        self.start_training()
        self._train_start = time.time()
        if resumed:
            logger.print(f"Resuming at iteration {self._iter}, {self._sample_count} samples")
            logger.write_event(resume_row(self._iter, self._sample_count, self._current_wall_hours(), max_samples))
        return logger

    def _is_output_iter(self, max_samples: int, out_of_time: bool) -> bool:
        """Every `iters_per_output` iterations, and the last one (the budget in samples or time is reached)."""
        return self._iter % self.config.iters_per_output == 0 or self._sample_count >= max_samples or out_of_time

    def _log_iteration(self, logger: Logger, train_info: dict[str, float], output: bool) -> None:
        """The terminal table and the metrics row of this iteration; on an output iteration, test episodes
        first, whose result the row (and log.txt) carries."""
        if output:
            test = self.test_model(self.config.test_episodes)
            if test.num_eps > 0 or not self._stop_requested:  # keep the last result if a stop cut it short
                self._last_test = test
        self._log_train_info(logger, train_info, self._env.record_diagnostics())
        logger.print_log()
        logger.write_metrics(output)

    def _diverge(self, logger: Logger, step: IterationStep, model_file: Path, saved_iter: int | None) -> str:
        """The end of a diverged run: the reason to the terminal and log.txt, the agent rolled back to the
        finite state the iteration started from, which model.pt then holds. Returns the reason."""
        reason = f"diverged at iteration {self._iter}: {step.non_finite}"
        logger.print(reason)
        logger.write_note(reason)
        self._roll_back(step.before)
        if saved_iter != self._iter - 1:  # else model.pt already holds these weights
            self._write_checkpoint(model_file, self._iter)
        return reason

    def _out_of_time(self, max_hours: float | None) -> bool:
        """Whether the recorded wall time reached `max_hours`, by rank 0's clock (every rank agrees)."""
        if max_hours is None:
            return False
        return bool(mp_util.broadcast_int(int(self._current_wall_hours() >= max_hours)))

    def start_training(self) -> None:
        """Fresh episodes in every env and the counters a run starts from (a resumed run keeps its own).
        `train_model` begins with it; `mimickit bench --train` calls it before each timed iteration."""
        self._curr_obs, self._curr_info = self._reset_envs()
        self._init_train()

    def train_iteration(self) -> IterationStep | None:
        """One training iteration, everything but logging and output: rollout, targets, updates, the global
        sample count and the divergence check. None when a stop request cut the rollout short."""
        before = self._snapshot()
        train_info = self._train_iter()
        if train_info is None:
            return None
        self._sample_count = self._sample_offset + mp_util.reduce_sum(self._exp_buffer.get_total_samples())
        return IterationStep(train_info, self._sync_non_finite(), before, dict(self._iter_timing))

    def test_model(self, num_episodes: int) -> EpisodeStats:
        """Run the deterministic policy (actor mean) until each env has finished at least
        ceil(ceil(num_episodes / procs) / num_envs) episodes; every finished episode counts.
        `num_episodes` 0 returns zeros without stepping. Returns the episode-weighted mean over
        processes (all processes must call it)."""
        self.eval()
        self.set_mode(AgentMode.TEST)
        num_eps_proc = -(-num_episodes // mp_util.get_num_procs())
        with torch.no_grad(), torch_threads(1):
            self._curr_obs, self._curr_info = self._reset_envs()
            local = self._rollout_test(num_eps_proc)
        return _reduce_episode_stats(local)

    def test_steps(self) -> Iterator[tuple[torch.Tensor, torch.Tensor, dict[str, Any]]]:
        """The deterministic policy's test rollout one step at a time, for tools that choose which episodes
        count (`mimickit eval`): every env is reset, then each item is a step's (reward [N], done [N], info),
        yielded before the envs that ended are reset (a reset rewrites their rows of `info`, so read it
        then). It never ends by itself: the caller stops iterating (and closes it), or `request_stop`.
        `test_model` keeps the reference's loop and its way of counting."""
        self.eval()
        self.set_mode(AgentMode.TEST)
        with torch.no_grad(), torch_threads(1):
            obs, info = self._reset_envs()
            while not self._stop_requested:
                action, _ = self._decide_action(obs, info)
                obs, reward, done, info = self._env.step(action)
                yield reward, done, info
                obs, info = self._reset_done_envs(obs, info, done)

    def request_stop(self) -> None:
        """Ask `train_model` / `test_model` to end gracefully (safe to call from a signal handler)."""
        self._stop_requested = True

    @property
    def stop_requested(self) -> bool:
        return self._stop_requested

    @torch.no_grad()
    def compute_action(self, obs: torch.Tensor, deterministic: bool = True) -> torch.Tensor:
        """Env action [N, A] for observations [N, obs_dim] (no recording; for viewers and rollouts)."""
        prev_mode = self._mode
        self._mode = AgentMode.TEST if deterministic else AgentMode.TRAIN
        try:
            action, _ = self._decide_action(obs, {})
        finally:
            self._mode = prev_mode
        return action

    def save(self, path: str | Path, include_train_state: bool = True) -> None:
        """Write the checkpoint atomically (rank 0 only)."""
        self._write_checkpoint(Path(path), self._iter, include_train_state)

    def load(self, path: str | Path) -> None:
        """Load a checkpoint (ours or the reference's); refuse one that does not fit this env/agent
        with a `MimicKitError` naming the file and the mismatching key and shapes."""
        path = Path(path)
        state, train_state = checkpoint.split_train_state(checkpoint.read_checkpoint(path, self._device))
        checkpoint.check_fits(path, self.state_dict(), state)
        checkpoint.check_finite(path, state)
        if train_state is not None:  # first: an optimiser state that does not fit fails before the model changes
            self._restore_train_state(train_state, path)
        self.load_state_dict(state, strict=True)
        self._sync_optimizers()

    def get_num_params(self) -> int:
        """Trainable parameters."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def get_action_size(self) -> int:
        return int(np.prod(self._env.get_action_space().shape))

    def get_obs_size(self) -> int:
        return int(np.prod(self._env.get_obs_space().shape))

    def get_num_envs(self) -> int:
        return self._env.get_num_envs()

    def get_iteration(self) -> int:
        """The next iteration to run (0 for a fresh agent)."""
        return self._iter

    def get_sample_count(self) -> int:
        return self._sample_count

    def set_mode(self, mode: AgentMode) -> None:
        self._mode = mode
        self._env.set_mode(EnvMode.TRAIN if mode == AgentMode.TRAIN else EnvMode.TEST)

    # ---------------------------------------------------------------- for subclasses

    @abc.abstractmethod
    def _build_model(self) -> None: ...

    @abc.abstractmethod
    def _build_optimizers(self) -> None: ...

    def _optimizers(self) -> dict[str, MPOptimizer]:
        """Named optimisers (saved in `_train_state` under these names)."""
        return {}

    @abc.abstractmethod
    def _get_exp_buffer_length(self) -> int: ...

    @abc.abstractmethod
    def _decide_action(self, obs: torch.Tensor, info: dict[str, Any]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """(env action [N, A], extras to record such as log-probs [N])."""

    @abc.abstractmethod
    def _update_model(self) -> dict[str, float]: ...

    def _build_train_data(self) -> dict[str, float]:
        return {}

    def _init_iter(self) -> None:
        self._exp_buffer.reset()
        self._info_sums.clear()
        self._info_steps = 0

    def _record_data_pre_step(
        self, obs: torch.Tensor, info: dict[str, Any], action: torch.Tensor, action_info: dict[str, torch.Tensor]
    ) -> None:
        self._exp_buffer.record("obs", obs)
        self._exp_buffer.record("action", action)
        if self._need_normalizer_update():
            self._obs_norm.record(obs)

    def _record_data_post_step(
        self, next_obs: torch.Tensor, reward: torch.Tensor, done: torch.Tensor, info: dict[str, Any]
    ) -> None:
        self._exp_buffer.record("next_obs", next_obs)
        self._exp_buffer.record("reward", reward)
        self._exp_buffer.record("done", done)
        self._accumulate_info_terms(info)

    def _update_normalizers(self) -> None:
        self._obs_norm.update()

    def _log_train_info(self, logger: Logger, train_info: dict[str, float], env_diag: dict[str, float]) -> None:
        test = self._last_test
        logger.log("Iteration", self._iter, collection="1_Info")
        logger.log("Wall_Time", self._current_wall_hours(), collection="1_Info")
        logger.log("Samples", self._sample_count, collection="1_Info")
        logger.log("Test_Return", test.mean_return, collection="0_Main")
        logger.log("Test_Episode_Length", test.mean_ep_len, collection="0_Main", quiet=True)
        logger.log("Test_Episodes", test.num_eps, collection="1_Info", quiet=True)
        # Episodes may end early without a fall (a clip that does not loop ends them as a success).
        logger.log("Test_Fail_Frac", test.num_fail / max(test.num_eps, 1), collection="0_Main", quiet=True)
        info = dict(train_info)
        logger.log("Train_Return", info.pop("mean_return"), collection="0_Main")
        logger.log("Train_Episode_Length", info.pop("mean_ep_len"), collection="0_Main", quiet=True)
        logger.log("Train_Episodes", mp_util.reduce_sum(int(info.pop("num_eps"))), collection="1_Info", quiet=True)
        for k, v in info.items():
            logger.log(k.title(), v)
        for k, v in env_diag.items():
            logger.log(k.title(), v, collection="2_Env", quiet=True)
        logger.log("Obs_Norm_Mean", self._obs_norm.get_mean().abs().mean().item(), quiet=True)
        logger.log("Obs_Norm_Std", self._obs_norm.get_std().mean().item(), quiet=True)
        steps = max(self._info_steps, 1)
        for name, total in self._info_sums.items():
            logger.log_metric(name, total.item() / steps)
        for name, value in self._iter_timing.items():
            logger.log_metric(name, value)

    def _compute_succ_val(self) -> float:
        return self._env.get_reward_succ() / (1.0 - self.config.discount)

    def _compute_fail_val(self) -> float:
        return self._env.get_reward_fail() / (1.0 - self.config.discount)

    # ---------------------------------------------------------------- the loop

    def _init_train(self) -> None:
        if not self._resumed:
            self._iter = 0
            self._sample_count = 0
            self._wall_time_offset = 0.0
            self._last_test = EpisodeStats()
        self._resumed = False
        self._sample_offset = self._sample_count
        self._exp_buffer.clear()
        self._train_return_tracker.reset()
        self._test_return_tracker.reset()

    def _train_iter(self) -> dict[str, float] | None:
        """One rollout + update; None when a stop request interrupted the rollout."""
        self._init_iter()
        self.eval()
        self.set_mode(AgentMode.TRAIN)
        update_normalizer = self._need_normalizer_update()
        start = time.perf_counter()
        self._sim_time = 0.0
        # One torch thread while the env steps: its tensors are small ([N, ...] per env), so a second thread
        # buys only a fork/join per op and spins on the core a MuJoCo worker needs; the update uses all.
        with torch.no_grad(), torch_threads(1):
            if not self._rollout_train(self.config.steps_per_iter):
                return None
        collected = time.perf_counter()
        # Torch's small ops on one thread, MKL's matrix products on all: the same weights bit for bit, and
        # no per-op wait on a descheduled second thread (see update_threads).
        with update_threads():
            data_info = self._build_train_data()
            train_info = self._update_model()
            if update_normalizer:
                self._update_normalizers()
        end = time.perf_counter()
        samples = self.config.steps_per_iter * self.get_num_envs() * mp_util.get_num_procs()
        # Where an iteration's wall time goes (metrics.jsonl only; log.txt keeps the reference columns).
        self._iter_timing = {
            "time.sim_s": self._sim_time,
            "time.inference_s": collected - start - self._sim_time,
            "time.update_s": end - collected,
            "time.samples_per_s": samples / (end - start),
        }
        info: dict[str, float] = {**train_info, **data_info}
        info["mean_return"] = self._train_return_tracker.get_mean_return()
        info["mean_ep_len"] = self._train_return_tracker.get_mean_ep_len()
        info["num_eps"] = self._train_return_tracker.get_episodes()
        self._non_finite = self._first_non_finite(data_info, train_info)
        return info

    def _first_non_finite(self, data_info: dict[str, float], train_info: dict[str, float]) -> str | None:
        """This iteration's first non-finite quantity, in the order they arose: the rollout's
        observations, actions and rewards, the targets' statistics (before the update), the losses,
        the last update's gradient norm, then the weights and normalisers."""
        buf = self._exp_buffer
        rollout = [("obs", "observation"), ("next_obs", "observation"), ("action", "action"), ("reward", "reward")]
        quantities: list[tuple[str, torch.Tensor | float]] = [
            (label, buf.get_data(name)) for name, label in rollout if buf.has(name)
        ]
        quantities += [(k.replace("_", " "), v) for k, v in {**data_info, **train_info}.items()]
        grad_norm = gradient_norm(self.parameters())
        if grad_norm is not None:
            quantities.append(("gradient norm", grad_norm))
        quantities += [(f"weight {k}", v) for k, v in self.state_dict().items()]
        return first_non_finite(quantities)

    def _sync_non_finite(self) -> str | None:
        """The divergence reason, the same on every process (one all-reduce per iteration)."""
        reason = self._non_finite
        if mp_util.enable_mp() and mp_util.reduce_max(int(reason is not None)) and reason is None:
            reason = "a non-finite value on another process"
        return reason

    def _snapshot(self) -> dict[str, Any]:
        """Copies of what one iteration changes (weights, normalisers, optimiser states, sample count),
        so that a diverged iteration can be undone; a few MB for this project's networks."""
        return {
            "model": {k: v.detach().clone() for k, v in self.state_dict().items()},
            "optimizers": {name: copy.deepcopy(opt.state_dict()) for name, opt in self._optimizers().items()},
            "samples": self._sample_count,
        }

    def _roll_back(self, snapshot: dict[str, Any]) -> None:
        self.load_state_dict(snapshot["model"], strict=True)
        for name, opt in self._optimizers().items():
            opt.load_state_dict(snapshot["optimizers"][name])
        self._sample_count = snapshot["samples"]

    def _write_output(self, logger: Logger, model_file: Path, int_dir: Path | None) -> None:
        """An output iteration's log.txt row and checkpoints; then fresh episodes for the next rollout."""
        logger.write_log()
        self._write_checkpoint(model_file, self._iter + 1)
        if int_dir is not None:
            self._write_checkpoint(int_dir / int_model_name(self._iter), self._iter + 1)
        self._train_return_tracker.reset()
        self._curr_obs, self._curr_info = self._reset_envs()

    def _rollout_train(self, num_steps: int) -> bool:
        can_break = not mp_util.enable_mp()  # other ranks would wait forever in the next collective
        for _ in range(num_steps):
            if can_break and self._stop_requested:
                return False
            action, action_info = self._decide_action(self._curr_obs, self._curr_info)
            self._record_data_pre_step(self._curr_obs, self._curr_info, action, action_info)
            t0 = time.perf_counter()
            next_obs, reward, done, next_info = self._env.step(action)
            t1 = time.perf_counter()
            self._train_return_tracker.update(reward, done)
            self._record_data_post_step(next_obs, reward, done, next_info)
            t2 = time.perf_counter()
            self._curr_obs, self._curr_info = self._reset_done_envs(next_obs, next_info, done)
            self._sim_time += (t1 - t0) + (time.perf_counter() - t2)
            self._exp_buffer.inc()
        return True

    def _rollout_test(self, num_episodes: int) -> EpisodeStats:
        tracker = self._test_return_tracker
        tracker.reset()
        if num_episodes <= 0:
            return EpisodeStats()
        min_eps_per_env = -(-num_episodes // self.get_num_envs())
        while not self._stop_requested:
            action, _ = self._decide_action(self._curr_obs, self._curr_info)
            next_obs, reward, done, next_info = self._env.step(action)
            tracker.update(reward, done)
            self._curr_obs, self._curr_info = self._reset_done_envs(next_obs, next_info, done)
            if bool((tracker.get_eps_per_env() >= min_eps_per_env).all()):
                break
        return EpisodeStats(
            tracker.get_mean_return(), tracker.get_mean_ep_len(), tracker.get_episodes(), tracker.get_failed_episodes()
        )

    def _reset_done_envs(
        self, obs: torch.Tensor, info: dict[str, Any], done: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, Any]]:
        env_ids = (done != DoneFlags.NULL).nonzero().flatten()
        if env_ids.numel() == 0:
            return obs, info
        return self._env.reset(env_ids)

    def _reset_envs(self, env_ids: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, Any]]:
        return self._env.reset(env_ids)

    def _need_normalizer_update(self) -> bool:
        return self._sample_count < self.config.normalizer_samples

    def _sync_stop_flag(self) -> bool:
        if mp_util.enable_mp():
            self._stop_requested = bool(mp_util.reduce_max(int(self._stop_requested)))
        return self._stop_requested

    def _accumulate_info_terms(self, info: dict[str, Any]) -> None:
        """Sum info["reward_terms"] / info["tracking"] ([N] tensors) over this rollout's steps and envs."""
        for group in ("reward_terms", "tracking"):
            terms = info.get(group)
            if not isinstance(terms, dict):
                continue
            for name, val in terms.items():
                key = f"{group}.{name}"
                mean = val.detach().to(torch.float64).mean()
                self._info_sums[key] = self._info_sums[key] + mean if key in self._info_sums else mean
        self._info_steps += 1

    # ---------------------------------------------------------------- builders and checkpoints

    def _build_normalizers(self) -> None:
        obs_shape = self._env.get_obs_space().shape
        self._obs_norm = Normalizer(obs_shape, device=self._device, clip=_OBS_CLIP)
        a_space = self._env.get_action_space()
        low = torch.as_tensor(a_space.low, dtype=torch.float32)
        high = torch.as_tensor(a_space.high, dtype=torch.float32)
        self._action_bounded = bool(torch.isfinite(low).all() and torch.isfinite(high).all())
        if self._action_bounded:
            a_mean, a_std = 0.5 * (high + low), 0.5 * (high - low)
            if not bool((a_std > 0).all()):
                raise MimicKitError("the env's action space has a dimension with high <= low (check the joint limits)")
        else:  # unbounded actions: identity normaliser (the reference would produce NaN here)
            a_mean, a_std = torch.zeros_like(low), torch.ones_like(low)
        self._a_norm = Normalizer(tuple(a_mean.shape), device=self._device, init_mean=a_mean, init_std=a_std)

    def _sync_optimizers(self) -> None:
        for opt in self._optimizers().values():
            opt.sync()

    def _write_checkpoint(self, path: Path, next_iter: int, include_train_state: bool = True) -> None:
        """state_dict (+ `_train_state`) → BytesIO → atomic write; rank 0 only."""
        if not mp_util.is_root_proc():
            return
        state: dict[str, Any] = dict(self.state_dict())
        if include_train_state:
            state[TRAIN_STATE_KEY] = self._train_state(next_iter)
        checkpoint.write_checkpoint(path, state)

    def _train_state(self, next_iter: int) -> dict[str, Any]:
        return checkpoint.make_train_state(
            self.config.agent_name,
            next_iter,
            self._sample_count,
            self._current_wall_hours(),
            asdict(self._last_test),
            self._optimizers(),
        )

    def _current_wall_hours(self) -> float:
        running = (time.time() - self._train_start) / 3600.0 if self._train_start is not None else 0.0
        return self._wall_time_offset + running

    def _restore_train_state(self, state: dict[str, Any], path: Path) -> None:
        """`state` was checked by `checkpoint.check_train_state` (types and ranges)."""
        checkpoint.load_optimizer_states(path, self._optimizers(), state["optimizers"])
        self._iter = state["iteration"]
        self._sample_count = state["samples"]
        self._wall_time_offset = state["wall_time_hours"]
        test = state["test"]
        self._last_test = EpisodeStats(test["mean_return"], test["mean_ep_len"], test["num_eps"], test["num_fail"])
        self._resumed = True


def _reduce_episode_stats(local: EpisodeStats) -> EpisodeStats:
    """Episode-weighted means over processes."""
    if not mp_util.enable_mp():
        return local
    vals = torch.tensor(
        [
            local.mean_return * local.num_eps, local.mean_ep_len * local.num_eps, float(local.num_eps),
            float(local.num_fail),
        ],
        dtype=torch.float64,
        device=mp_util.get_device(),
    )  # fmt: skip
    vals = mp_util.reduce_sum(vals).cpu().tolist()
    n = int(round(vals[2]))
    if n == 0:
        return EpisodeStats()
    return EpisodeStats(vals[0] / n, vals[1] / n, n, int(round(vals[3])))
