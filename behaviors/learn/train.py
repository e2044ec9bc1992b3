"""`behave train`: PS-DDPG (and the paper's single- and multi-DDPG baselines) on SUMO.

One loop for the three algorithms; what differs is who acts and learns:
* ps-ddpg: one learner; all live agents act in ONE forward pass, all their
  transitions go to the shared buffer, and the shared networks get one update
  per live agent per step (the paper's schedule; `updates_per_step` overrides);
* ddpg: the same learner with a single agent on the road;
* multi-ddpg: a learner per agent slot, each updated once per step.

A run directory holds config.json, metrics.csv (one row per episode), agents.csv (the agents
table, agents_table.py: one row per agent and episode),
checkpoints/ (last, best, final, interrupted: policy + critic), state.pt and
replay/ (the training state as of the end of the last finished episode, for
--resume; saved after every episode, the replay rows as append-only chunks)
and curve.png. Everything is written atomically; Ctrl-C or SIGTERM stops at
the next step: the partial episode is dropped, and a resumed run replays it
exactly as an uninterrupted run would.
"""

from __future__ import annotations

import dataclasses
import json
import numbers
import signal
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from behaviors.errors import BehaveError
from behaviors.files import atomic_path, atomic_write_bytes, atomic_write_text, ensure_writable_dir
from behaviors.fleet.drivers import make_driver
from behaviors.learn.ddpg.checkpoint import load_checkpoint, save_checkpoint
from behaviors.learn.ddpg.learner import DDPGLearner, IndependentLearners, Learner, Transitions, UpdateStats
from behaviors.learn.ddpg.replay_files import ReplayFiles
from behaviors.learn.distributed import RayWorkers, WorkerSetup, ray_workers
from behaviors.learn.env import StepBatch, create_env
from behaviors.learn.episode import drive_episode
from behaviors.learn.metrics import EpisodeStats, agent_runs, summary
from behaviors.learn.policy import resolve
from behaviors.learn.train_config import TrainConfig
from behaviors.report.agents_table import cell, table_text

STATE_VERSION = 2
UPDATE_LOG_EVERY = 10
"""TensorBoard's per-update scalars are the means of blocks of this many updates: writing every
update's scalars would cost a noticeable share of the update time (docs/history.md)."""


@dataclass(frozen=True)
class Episode:
    """A finished training episode: its counters, wall time and the network updates it brought."""

    stats: EpisodeStats
    wall_s: float
    updates: int


def episode_row(episode: int, done: Episode, speed_limit: float) -> dict[str, Any]:
    """The metrics.csv row: the paper's system metrics, agent-steps, wall time and updates."""
    row: dict[str, Any] = {"episode": episode, **summary(done.stats, speed_limit)}
    row["agent_steps"] = int(done.stats.speed_steps.sum())
    row["wall_s"] = done.wall_s
    row["updates"] = done.updates
    return row


def episode_agents(episode: int, stats: EpisodeStats, ids: list[str], policy: str) -> list[list[Any]]:
    """The episode's rows of the run's agents table (agents_table, "train"): each agent and its reward."""
    runs = agent_runs(stats, ids, policy)
    rewards = stats.reward[stats.placed]  # agent_runs: the slots whose car started
    return [[*run.cells(), episode, cell(float(r))] for run, r in zip(runs, rewards, strict=True)]


class Trainer:
    """Owns the env and the learner(s) of one run; `run()` trains until done or stopped."""

    def __init__(self, config: TrainConfig, out: Path) -> None:
        config.validate()
        self.config = config
        self.out = out
        torch.set_num_threads(1)  # SUMO runs beside the learner: more threads slow it (docs/history.md)
        torch.manual_seed(config.seed)
        self.env = create_env(config.env_config())
        self.obs_dim = self.env.config.obs_size
        n = self.env.config.n_agents
        if config.algo == "multi-ddpg":
            self.learner: Learner = IndependentLearners(n, self.obs_dim, config.ddpg_config(), config.seed)
        else:
            self.learner = DDPGLearner(self.obs_dim, config.ddpg_config(), config.seed)
        self.speed_limit = max(info.speed for info in self.env.geometry.edges.values() if info.normal)
        self.replay = ReplayFiles(out / "replay", self.learner.buffers)
        self.rows: list[dict[str, Any]] = []
        self.agent_rows: list[list[Any]] = []  # the agents table's, all episodes'
        self.episode = 0
        self.best = -np.inf
        self.stop_signal: int | None = None  # SIGINT or SIGTERM, once one asked to stop
        self.tensorboard: Any = None  # a SummaryWriter while run() trains, if tensorboard is installed
        self.update_stats: list[UpdateStats] = []  # the updates not yet in TensorBoard, the latest last

    @property
    def stop_requested(self) -> bool:
        return self.stop_signal is not None

    @property
    def update_log(self) -> list[UpdateStats] | None:
        """Where the learner puts each update's losses and Q: only while TensorBoard logs."""
        return None if self.tensorboard is None else self.update_stats

    # --- policy I/O -------------------------------------------------------------------
    def meta(self) -> dict[str, Any]:
        """What a checkpoint records: its driver names the observation, the policy loader reads it."""
        c, env = self.config, self.env.config
        driver = make_driver(env.driver)
        behaviours = ["overtaking", "lanekeeping"] if env.behaviour == "multi" else [env.behaviour]
        return {
            "algorithm": c.algo,
            "driver": driver.name,
            "behaviour": env.behaviour,
            "behaviours": behaviours,
            "obs_dim": self.obs_dim,
            "observation_layout": driver.observation_layout(env.with_id),
            "normalisation": driver.normalisation,
            "hidden": list(c.ddpg.hidden),
            "training_steps": self.transitions,
            "episodes": self.episode,
            "seed": c.seed,
            "step_length": env.step_length,
        }

    @property
    def transitions(self) -> int:
        return self.learner.transitions

    def save_policy(self, name: str) -> Path:
        actor, critic, extra = self.learner.checkpoint_states()
        path = self.out / "checkpoints" / f"{name}.pt"
        save_checkpoint(path, actor_state=actor, critic_state=critic, extra_state=extra, meta=self.meta())
        return path

    def initialise_from(self, spec: str) -> None:
        """Curriculum: copy actor and critic weights (and their targets) from a policy as every command
        takes it (policy.resolve: a file, a run directory or a bundled name).

        A 65-input policy may start a 66-input (multi-behaviour) run: the behaviour id's
        input weights start at zero, so the new network first drives exactly like the old.
        """
        path = resolve(spec)[0]
        ckpt = load_checkpoint(path)
        if ckpt.meta["obs_dim"] not in (self.obs_dim, self.obs_dim - 1):
            load_checkpoint(path, expect_obs_dim=self.obs_dim, expect_layout=self.env.config.behaviour)
        actor = widen_inputs(ckpt.actor_state, self.obs_dim, obs_first=True)
        critic = ckpt.critic_state and widen_inputs(ckpt.critic_state, self.obs_dim, obs_first=False)
        try:
            for lr in self.learner.learners:
                lr.actor.load_state_dict(actor)
                lr.actor_target.load_state_dict(actor)
                if critic is not None:
                    lr.critic.load_state_dict(critic)
                    lr.critic_target.load_state_dict(critic)
        except RuntimeError:
            sizes = f"{ckpt.meta['hidden']} vs this run's {list(self.config.ddpg.hidden)}"
            raise BehaveError(f"{path}: network sizes differ ({sizes})") from None

    # --- resume -----------------------------------------------------------------------
    def save_state(self) -> None:
        """The whole training state between episodes, as plain data (tensors, numbers, strings):
        the new replay rows go to replay/ first, then state.pt names the chunks it needs."""
        payload = {
            "version": STATE_VERSION,
            "episode": self.episode,
            "best": float(self.best),
            "rows": json.dumps(self.rows),
            "agents": json.dumps(self.agent_rows),
            "learner": self.learner.state_dict(replay_rows=False),
            "replay": self.replay.write_new_rows(),
            "config": self.config.to_json(),
        }
        with atomic_path(self.out / "state.pt") as tmp:
            torch.save(payload, tmp)
        self.replay.prune()

    def load_state(self) -> None:
        """Read as data (weights_only): a run directory from elsewhere cannot run code."""
        path = self.out / "state.pt"
        if not path.is_file():
            raise BehaveError(f"nothing to resume in {self.out}: no state.pt")
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except Exception:
            raise BehaveError(f"{path} is not a behave training state (corrupt or truncated)") from None
        if not isinstance(payload, dict) or payload.get("version") != STATE_VERSION:
            version = payload.get("version") if isinstance(payload, dict) else None
            raise BehaveError(f"{path} is training state version {version!r}; behave resumes {STATE_VERSION}")
        try:
            self.learner.load_state_dict(payload["learner"])
            self.replay.restore(payload["replay"])
        except Exception as exc:
            raise BehaveError(f"{path}: cannot restore the learner or its replay/ rows ({exc})") from None
        self.episode = int(payload["episode"])
        self.best = float(payload["best"])
        self.rows = json.loads(payload["rows"])
        self.agent_rows = json.loads(payload.get("agents", "[]"))  # runs saved before the agents table: none

    # --- the loop ---------------------------------------------------------------------
    def run(self, on_episode: Callable[[dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
        with _stop_on_signals(self):
            started = time.perf_counter()
            budget = np.inf if self.config.max_minutes is None else 60.0 * self.config.max_minutes
            self.tensorboard = open_tensorboard(self.out / "tensorboard")
            try:
                while (
                    self.episode < self.config.episodes
                    and not self.stop_requested
                    and time.perf_counter() - started < budget
                ):
                    done = self.run_episode()
                    if done is None:
                        break
                    row = episode_row(self.episode, done, self.speed_limit)
                    self.rows.append(row)
                    self.agent_rows += episode_agents(
                        self.episode, done.stats, self.env.possible_agents, self.out.name
                    )
                    self.episode += 1
                    self._after_episode(row)
                    if on_episode:
                        on_episode(row)
            finally:
                self.env.close()
                if self.tensorboard is not None:
                    self.tensorboard.close()
        self.save_policy("interrupted" if self.stop_requested else "final")
        self.write_tables()
        plot_curve(self.out / "curve.png", self.rows)
        return self.rows

    def run_episode(self) -> Episode | None:
        """One episode; None if stopped by a signal (the partial episode is not logged)."""
        env, learner, c = self.env, self.learner, self.config
        start = time.perf_counter()
        updates_before = learner.updates
        scale = c.critic_reward_scale

        def learn(obs: np.ndarray, actions: np.ndarray, batch: StepBatch) -> None:
            reward = (batch.reward * scale).astype(np.float32)
            step = Transitions(
                obs, actions, reward, batch.next_obs, batch.terminated.astype(np.float32), batch.slots
            )
            learner.learn(step, c.updates_per_step, self.update_log)

        log = drive_episode(
            env,
            env.reset_arrays(episode_seed(c.seed, self.episode)),
            lambda obs, slots: learner.act_for(obs, slots, explore=True),
            learn,
            lambda: self.stop_requested,
        )
        if log is None:
            return None
        return Episode(log, time.perf_counter() - start, learner.updates - updates_before)

    def write_tables(self) -> None:
        """metrics.csv and agents.csv of the episodes so far; neither before the first episode ends."""
        if self.rows:
            write_metrics(self.out / "metrics.csv", self.rows)
            atomic_write_text(self.out / "agents.csv", table_text("train", self.agent_rows))

    def _after_episode(self, row: dict[str, Any]) -> None:
        """The state first (it holds the metrics rows too): a kill after it redoes no episode."""
        improved = row["reward_sum"] > self.best
        if improved:
            self.best = row["reward_sum"]
        self.save_state()
        if self.tensorboard is not None:  # after the state: a resumed run never logs an episode twice
            self.update_stats = log_update_blocks(self.tensorboard, self.update_stats, self.learner.updates)
            log_scalars(self.tensorboard, row)
        self.save_policy("last")
        if improved:
            self.save_policy("best")
        self.write_tables()
        if self.episode % self.config.checkpoint_every == 0:
            self.save_policy(f"episode_{self.episode:05d}")
            plot_curve(self.out / "curve.png", self.rows)


class DistributedTrainer(Trainer):
    """The Trainer's loop and run directory, with episodes driven by Ray rollout workers."""

    def __init__(self, config: TrainConfig, out: Path, ray_address: str | None = None) -> None:
        super().__init__(config, out)  # TrainConfig.validate refuses multi-ddpg with workers
        self.ray_address = ray_address
        self.workers: RayWorkers | None = None  # while run() trains
        self.started = 0  # episodes handed out so far (the next one's seed)

    def run(self, on_episode: Callable[[dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
        c = self.config
        setup = WorkerSetup(c.env_config(), c.ddpg_config(), c.critic_reward_scale, c.seed)
        with ray_workers(self.ray_address, setup, c.workers) as self.workers:
            self.started = self.episode
            return super().run(on_episode)

    def run_episode(self) -> Episode | None:
        """The next episode any worker finishes, stored and learnt from; None if stopped."""
        learner, workers = self.learner, self.workers
        assert isinstance(learner, DDPGLearner) and workers is not None
        for worker in workers.idle():
            if self.started < self.config.episodes:
                weights = {name: value.detach().clone() for name, value in learner.actor.state_dict().items()}
                seed = episode_seed(self.config.seed, self.started)
                workers.start(worker, weights, seed, learner.noise.steps)
                self.started += 1
        rollout = workers.finished(lambda: self.stop_requested)
        if rollout is None:
            return None
        updates_before = learner.updates
        learner.observe(rollout.obs, rollout.act, rollout.rew, rollout.next_obs, rollout.terminated)
        learner.noise.steps += rollout.steps  # env steps of all workers: the exploration decay
        per_step = self.config.updates_per_step
        learner.update(len(rollout.obs) if per_step is None else per_step * rollout.steps, self.update_log)
        return Episode(rollout.stats, rollout.wall_s, learner.updates - updates_before)


def widen_inputs(state: dict, obs_dim: int, obs_first: bool) -> dict:
    """A state dict whose first layer gets zero weights for inputs it did not have (the behaviour id).

    The critic's first layer sees [observation, action]: the new column goes between them.
    """
    key = next(k for k in state if k.endswith("weight"))
    weight = state[key]
    missing = obs_dim - (weight.shape[1] - (0 if obs_first else 3))
    if missing <= 0:
        return state
    zeros = torch.zeros(weight.shape[0], missing, dtype=weight.dtype)
    split = weight.shape[1] if obs_first else weight.shape[1] - 3
    return {**state, key: torch.cat([weight[:, :split], zeros, weight[:, split:]], dim=1)}


def episode_seed(seed: int, episode: int) -> int:
    """A distinct, reproducible SUMO/placement seed per episode."""
    return int(np.random.SeedSequence([seed, episode]).generate_state(1)[0] % (2**31 - 1))


@contextmanager
def _stop_on_signals(trainer: Trainer) -> Iterator[None]:
    """SIGINT/SIGTERM ask the loop to stop at the next step; a second Ctrl-C is not swallowed."""

    def request(signum, frame) -> None:
        if trainer.stop_requested:
            raise KeyboardInterrupt
        trainer.stop_signal = signum

    previous = {sig: signal.signal(sig, request) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def write_metrics(path: Path, rows: list[dict[str, Any]]) -> None:
    """The episodes' rows as CSV."""
    import pandas as pd

    atomic_write_text(path, pd.DataFrame(rows).to_csv(index=False))


def open_tensorboard(directory: Path) -> Any:
    """A SummaryWriter into the run's tensorboard/ folder, or None without the tensorboard package
    (an optional extra: metrics.csv stays the record). A resumed run adds an event file beside."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        return None
    return SummaryWriter(log_dir=str(directory))


def log_scalars(writer: Any, row: dict[str, Any]) -> None:
    """Every numeric column of an episode's metrics row, at the episode number as global step."""
    for name, value in row.items():
        if isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_):
            writer.add_scalar(name, float(value), global_step=int(row["episode"]))
    writer.flush()


def log_update_blocks(
    writer: Any, stats: list[UpdateStats], last_update: int, every: int = UPDATE_LOG_EVERY
) -> list[UpdateStats]:
    """Write the mean critic loss, actor loss and Q of every block of `every` updates that is over
    by update number `last_update` (the number of `stats[-1]`), at the block's last update number;
    returns the stats of the block under way. Blocks end at multiples of `every`, so a resumed run
    (which lost the unwritten part of its block) writes no step twice."""
    first = last_update - len(stats) + 1
    values = np.asarray(stats, dtype=np.float64).reshape(-1, 3)
    for end in range(-(-first // every) * every, last_update + 1, every):
        block = values[max(0, end - every + 1 - first) : end - first + 1].mean(axis=0)
        for tag, value in zip(("critic_loss", "actor_loss", "mean_q"), block, strict=True):
            writer.add_scalar(f"update/{tag}", float(value), global_step=end)
    written = last_update - last_update % every
    return stats[max(0, written - first + 1) :]


def plot_curve(path: Path, rows: list[dict[str, Any]]) -> None:
    """Training curve: system reward per episode and % colliding steps."""
    if not rows:
        return
    import io

    from matplotlib.figure import Figure

    episodes = [r["episode"] for r in rows]
    fig = Figure(figsize=(8, 5), tight_layout=True)
    top, bottom = fig.subplots(2, 1, sharex=True)
    reward = np.array([r["reward_sum"] for r in rows])
    top.plot(episodes, reward, color="tab:blue", alpha=0.4, label="sum of reward, all agents")
    if len(reward) >= 5:
        window = min(20, len(reward))
        smooth = np.convolve(reward, np.ones(window) / window, mode="valid")
        top.plot(episodes[window - 1 :], smooth, color="tab:blue", label=f"{window}-episode mean")
    top.set_ylabel("reward")
    top.legend(loc="lower right")
    top.grid(alpha=0.3)
    bottom.plot(
        episodes, [r["colliding_steps_pct"] for r in rows], color="tab:red", label="% colliding steps"
    )
    bottom.plot(
        episodes,
        [100 * r["mean_speed_frac"] for r in rows],
        color="tab:green",
        label="mean speed, % of limit",
    )
    bottom.set_xlabel("episode")
    bottom.set_ylabel("%")
    bottom.legend(loc="upper right")
    bottom.grid(alpha=0.3)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    atomic_write_bytes(path, buffer.getvalue())


def prepare_run(
    config: TrainConfig,
    out: Path,
    *,
    resume: bool,
    episodes: int | None = None,
    ray_address: str | None = None,
) -> Trainer:
    """Create (or reopen with --resume) a run directory and its trainer; a new run's state is
    saved at once, so that a run stopped in its first episode can be resumed.

    On resume the stored config is used; `episodes` (if given) sets the new total. With more than
    one worker the episodes run on Ray (local, or the cluster at `ray_address`).
    """
    if resume:
        saved = out / "config.json"
        if not saved.is_file():
            raise BehaveError(f"nothing to resume in {out}: no config.json")
        stored = TrainConfig.from_json(saved.read_text())
        total = stored.episodes if episodes is None else episodes
        config = dataclasses.replace(stored, episodes=total, max_minutes=None)
    else:
        if (out / "state.pt").exists():
            raise BehaveError(f"{out} already holds a run: use --resume or another --out")
        config.validate()  # a bad setting (a reward term, counts) leaves no run directory behind
    ensure_writable_dir(out)
    ensure_writable_dir(out / "checkpoints")
    if config.workers > 1:
        trainer: Trainer = DistributedTrainer(config, out, ray_address)
    else:
        trainer = Trainer(config, out)
    if resume:
        trainer.load_state()
        if trainer.episode > config.episodes:
            raise BehaveError(f"{out} has {trainer.episode} episodes already: --episodes is the total")
    atomic_write_text(out / "config.json", config.to_json())
    if resume:
        return trainer
    if config.init:
        trainer.initialise_from(config.init)
    trainer.save_state()
    return trainer
