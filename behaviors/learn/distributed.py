"""`behave train --workers N`: PS-DDPG with N rollout workers on Ray and one learner.

libsumo runs one simulation per process, so each rollout worker is a Ray actor (its own
process, its own SUMO). A worker drives whole episodes with the shared actor's weights as of
the episode's start and its own exploration noise, and sends the episode's transitions back.
The learner (train.py's DistributedTrainer, in the calling process) owns the one replay buffer:
it stores each finished episode, does that episode's share of updates (one per agent transition,
the paper's schedule, unless --updates-per-step) while the workers drive the next episodes, and
hands the new weights to the worker it starts next. Metrics, checkpoints, TensorBoard and --resume
are the Trainer's; a resumed run continues with fresh episodes (the workers' timing makes runs not
bit-repeatable). This module is the Ray side only: it is given what it needs (WorkerSetup) and
imports nothing of train.py, which imports it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from behaviors.errors import BehaveError
from behaviors.learn.ddpg.learner import DDPGConfig, clip_actions
from behaviors.learn.ddpg.networks import Actor
from behaviors.learn.ddpg.noise import OUNoise
from behaviors.learn.env import EnvConfig, StepBatch, create_env
from behaviors.learn.episode import drive_episode
from behaviors.learn.metrics import EpisodeStats

WAIT_S = 0.5
"""How often the learner looks for a stop signal while it waits for an episode."""
OBJECT_STORE_BYTES = 256 * 2**20
"""A local Ray's shared memory: an episode's transitions are a few MB."""
CONNECT_S = 5.0
INSTALL_HINT = "--workers needs Ray: pip install 'behave-traffic[distributed]'"


@dataclass(frozen=True)
class Rollout:
    """One episode of one worker: its transitions, row by row in step order, and its counters."""

    obs: np.ndarray
    act: np.ndarray
    rew: np.ndarray  # scaled for the critic
    next_obs: np.ndarray
    terminated: np.ndarray
    steps: int
    stats: EpisodeStats
    wall_s: float


@dataclass(frozen=True)
class WorkerSetup:
    """What each rollout worker is sent of the run: its env, the learner's network and noise
    settings, the critic's reward scale and the run's seed (each worker's noise seed derives from it)."""

    env: EnvConfig
    learner: DDPGConfig
    reward_scale: float
    seed: int


class RolloutWorker:
    """Drives episodes in its own process (a Ray actor) with the weights it is given."""

    def __init__(self, setup: WorkerSetup, index: int) -> None:
        torch.set_num_threads(1)  # SUMO and the actor share the worker's core
        self.reward_scale = setup.reward_scale
        self.env = create_env(setup.env)
        learner = setup.learner
        self.actor = Actor(self.env.config.obs_size, learner.hidden)
        self.noise = OUNoise(
            learner.ou_mu, learner.ou_theta, learner.ou_sigma, setup.seed + 1000 * (index + 1),
            learner.explore_decay_steps,
        )  # fmt: skip

    def episode(self, actor_state: dict[str, torch.Tensor], seed: int, explore_step: int) -> Rollout:
        """One episode; `explore_step` (env steps so far, all workers) sets the noise's decay."""
        start = time.perf_counter()
        env, scale = self.env, self.reward_scale
        self.actor.load_state_dict(actor_state)
        self.noise.steps = explore_step
        rows: list[tuple[np.ndarray, ...]] = []

        def choose(obs: np.ndarray, slots: np.ndarray) -> np.ndarray:
            with torch.inference_mode():
                mean = self.actor(torch.as_tensor(obs, dtype=torch.float32)).numpy()
            return clip_actions(mean + self.noise.sample(len(mean)))

        def keep(obs: np.ndarray, actions: np.ndarray, batch: StepBatch) -> None:
            reward = (batch.reward * scale).astype(np.float32)
            rows.append((obs, actions, reward, batch.next_obs, batch.terminated.astype(np.float32)))

        log = drive_episode(env, env.reset_arrays(seed), choose, keep)
        assert log is not None  # nothing stops a worker's episode
        obs_, act, rew, next_obs, terminated = (np.concatenate(parts) for parts in zip(*rows, strict=True))
        return Rollout(obs_, act, rew, next_obs, terminated, len(rows), log, time.perf_counter() - start)


class RayWorkers:
    """Rollout workers on Ray: an idle worker is handed an episode; episodes come back as they end."""

    def __init__(self, ray: Any, workers: list[Any]) -> None:
        self.ray = ray
        self.workers = workers
        self.pending: dict[Any, Any] = {}  # episode under way -> its worker

    def idle(self) -> list[Any]:
        busy = set(self.pending.values())
        return [worker for worker in self.workers if worker not in busy]

    def start(self, worker: Any, actor_state: dict[str, torch.Tensor], seed: int, explore_step: int) -> None:
        self.pending[worker.episode.remote(actor_state, seed, explore_step)] = worker

    def finished(self, stop: Callable[[], bool]) -> Rollout | None:
        """The next episode any worker finishes; None as soon as `stop()` holds."""
        done: list[Any] = []
        while not done:
            if stop():
                return None
            done, _ = self.ray.wait(list(self.pending), num_returns=1, timeout=WAIT_S)
        self.pending.pop(done[0])
        return fetch(self.ray, done[0])


@contextmanager
def ray_workers(address: str | None, setup: WorkerSetup, count: int) -> Iterator[RayWorkers]:
    """`count` rollout workers on Ray (local, or the cluster at `address`), ended on exit."""
    ray = start_ray(address, count)
    try:
        remote = ray.remote(num_cpus=1)(RolloutWorker)
        yield RayWorkers(ray, [remote.remote(setup, k) for k in range(count)])
    finally:
        ray.shutdown()  # ends this run's workers (a cluster keeps running)


def start_ray(address: str | None, workers: int, *, log_to_driver: bool = True) -> Any:
    """Ray, local (as many CPUs as workers at least) or the cluster at `address`; `log_to_driver=False`
    leaves the workers' output in Ray's logs."""
    try:
        import ray
    except ImportError:
        raise BehaveError(INSTALL_HINT) from None
    if address is not None:
        check_reachable(address)
    options: dict[str, Any] = {
        "include_dashboard": False, "logging_level": logging.WARNING, "log_to_driver": log_to_driver,
    }  # fmt: skip
    if address is None:
        options |= {"num_cpus": max(workers, os.cpu_count() or 1), "object_store_memory": OBJECT_STORE_BYTES}
    quiet_token_note()
    said: list[str] = []
    try:
        with contextlib.nullcontext() if address is None else held_stderr(said):
            ray.init(address=address, **options)
    except (ConnectionError, RuntimeError, ValueError, ray.exceptions.RayError) as exc:
        text = " ".join(str(exc).split())
        if address is not None and "token" not in text.lower():
            refused = any(REFUSED_TOKEN in line for line in said)
            text += f" ({'the cluster refused the token: ' if refused else ''}{TOKEN_HINT})"
        raise BehaveError(f"cannot start or join Ray at {address or 'this machine'}: {text}") from None
    sys.stderr.write("".join(said))
    return ray


TOKEN_HINT = (
    "a cluster started with RAY_AUTH_MODE=token takes drivers with that setting and its token, in "
    "RAY_AUTH_TOKEN or ~/.ray/auth_token: docs/manual/cli.md, `behave sweep`"
)
"""What a refused connection to a cluster most likely lacks (Ray says only that it failed)."""
REFUSED_TOKEN = "InvalidAuthToken"
"""What Ray's core prints, once a second while it retries, when the cluster refuses the token."""


@contextmanager
def held_stderr(said: list[str]) -> Iterator[None]:
    """This process's stderr (file descriptor 2, where Ray's core writes) kept back into `said`: joining
    a cluster that refuses the token prints a warning a second for twenty seconds, then fails."""
    sys.stderr.flush()
    kept = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(kept, 2)
            os.close(kept)
            held.seek(0)
            said.extend(held.read().decode(errors="replace").splitlines(keepends=True))


TOKEN_LOGGER = "ray._private.authentication.authentication_token_setup"
TOKEN_NOTE = "Token authentication is enabled for this Ray cluster"
"""Ray (2.5x on) starts every local cluster with token authentication (a token in ~/.ray/auth_token,
made once) and says so each time as a WARNING, which behave's sweeps and trainings printed. The cluster
is as safe as Ray makes it, so the note is dropped (see `quiet_token_note`); RAY_AUTH_MODE=disabled
still opts out, as Ray's note says."""


class _DropTokenNote(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(TOKEN_NOTE)


def quiet_token_note() -> None:
    """Drop Ray's token-authentication note (TOKEN_NOTE) and nothing else of its logging; once."""
    logger = logging.getLogger(TOKEN_LOGGER)
    if not any(isinstance(f, _DropTokenNote) for f in logger.filters):
        logger.addFilter(_DropTokenNote())


def check_reachable(address: str) -> None:
    """A `host:port` that nothing answers on is refused at once (Ray itself retries for minutes)."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or "://" in address:
        return  # "auto", ray://...: Ray's own forms, left to Ray
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_S).close()
    except OSError as exc:
        raise BehaveError(f"no Ray cluster answers at {address} ({exc.strerror or exc})") from None


def fetch(ray: Any, ref: Any) -> Rollout:
    """A worker's episode; a worker's BehaveError comes back as itself, one clear line."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        cause = exc.cause
        if isinstance(cause, BehaveError):
            raise BehaveError(str(cause)) from None
        raise
