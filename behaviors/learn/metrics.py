"""Episode metrics of the paper, shared by training and evaluation.

% colliding steps counts a step once however many agents collide in it;
colliding steps per agent counts every colliding agent.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from behaviors.learn.env_core import KEEPER_TYPE, OVERTAKER_TYPE, BehaveEnv, StepBatch
from behaviors.report.agents_table import AgentRun
from behaviors.sumo.sim import STANDSTILL_SPEED


@dataclass
class EpisodeStats:
    """Counters of one episode (all agents), reduced by `summary`.

    Agents leave at their first collision, so colliding steps per agent equal collisions per agent.
    Each agent's end (step and reason) and standstills give its row of the agents table (`agent_runs`).
    """

    n_agents: int
    behaviour_id: np.ndarray
    step_length: float
    start_s: float  # SUMO's clock when the episode started
    steps: int = 0
    colliding_steps: int = 0
    agent_colliding_steps: int = 0
    collisions: int = 0
    off_tracks: int = 0
    no_progress: int = 0
    speed_sum: np.ndarray = field(init=False)  # per agent slot, like the arrays below
    speed_steps: np.ndarray = field(init=False)
    lane_deviation_sum: float = 0.0
    reward: np.ndarray = field(init=False)
    progress: np.ndarray = field(init=False)
    collided: np.ndarray = field(init=False)
    standing: np.ndarray = field(init=False)  # seconds standing still up to now
    longest_standstill: np.ndarray = field(init=False)
    end_step: np.ndarray = field(init=False)  # the step an agent left after (0: still on the road)
    end_reason: np.ndarray = field(init=False)
    placed: np.ndarray = field(init=False)  # [n_agents] bool: the slot's car started (`place`; all: default)

    def __post_init__(self) -> None:
        for name in ("speed_sum", "speed_steps", "reward", "progress", "collided", "standing",
                     "longest_standstill"):  # fmt: skip
            setattr(self, name, np.zeros(self.n_agents))
        self.end_step = np.zeros(self.n_agents, np.int64)
        self.end_reason = np.full(self.n_agents, "still_driving", dtype=object)
        self.placed = np.ones(self.n_agents, bool)

    def place(self, slots: np.ndarray) -> None:
        """Only these slots' cars started: the traffic env puts agents down at free places and a slot
        that finds none sits the episode out. Per-agent figures count the placed agents."""
        self.placed = np.zeros(self.n_agents, bool)
        self.placed[slots] = True

    def record(self, slots: np.ndarray, batch: StepBatch) -> None:
        self.steps += 1
        self.colliding_steps += int(batch.collided.any())
        self.agent_colliding_steps += int(batch.collided.sum())
        self.collisions += int(batch.collided.sum())
        np.add.at(self.collided, slots, batch.collided)
        self.off_tracks += int(batch.off_track.sum())
        self.no_progress += int(batch.no_progress.sum())
        np.add.at(self.reward, slots, batch.reward)
        np.add.at(self.progress, slots, batch.terms.progress)
        np.add.at(self.speed_sum, slots, batch.speed)
        np.add.at(self.speed_steps, slots, 1)
        self.lane_deviation_sum += float(batch.lane_deviation.sum())
        standing = np.where(batch.speed < STANDSTILL_SPEED, self.standing[slots] + self.step_length, 0.0)
        self.standing[slots] = standing
        self.longest_standstill[slots] = np.maximum(self.longest_standstill[slots], standing)
        ended = batch.terminated | batch.truncated
        if ended.any():  # most steps: no per-agent strings
            self.end_step[slots[ended]] = self.steps
            for reason, flag in (("collision", batch.collided), ("off_track", batch.off_track),
                                 ("no_progress", batch.no_progress)):  # fmt: skip
                self.end_reason[slots[ended & flag]] = reason


def agent_runs(stats: EpisodeStats, ids: list[str], policy: str) -> list[AgentRun]:
    """The episode's rows of the agents table, by agent slot, for the slots whose car started
    (`placed`: a slot that found no free place has no row); an agent that left at the time limit or
    the road's end was still driving."""
    dt, start = stats.step_length, stats.start_s
    end = start + np.where(stats.end_step > 0, stats.end_step, stats.steps) * dt
    overtaker = stats.behaviour_id > 0
    behaviour = ["overtaker" if over else "keeper" for over in overtaker]
    vtype = [OVERTAKER_TYPE if over else KEEPER_TYPE for over in overtaker]
    distance, longest = stats.speed_sum * dt, stats.longest_standstill
    runs = []
    for k in np.flatnonzero(stats.placed).tolist():
        ending = float(end[k]), str(stats.end_reason[k]), float(distance[k]), float(longest[k])
        runs.append(AgentRun(ids[k], behaviour[k], vtype[k], policy, start, *ending))
    return runs


def summary(stats: EpisodeStats, speed_limit: float, passed: float | None = None) -> dict[str, Any]:
    """One episode's row: system metrics and per-behaviour mean speeds (fractions of the limit).

    Per-agent figures are per agent placed (`agents_placed`; EpisodeStats.place): a slot whose car
    found no free place to start drove nothing and counts for nothing."""
    placed = stats.placed
    count = max(int(placed.sum()), 1)
    row: dict[str, Any] = {
        "steps": stats.steps,
        "agents_placed": int(placed.sum()),
        "reward_per_agent": float(stats.reward[placed].sum() / count),
        "progress_per_agent": float(stats.progress[placed].sum() / count),
        "colliding_steps_per_agent": stats.agent_colliding_steps / count,
        "colliding_steps_pct": 100.0 * stats.colliding_steps / max(stats.steps, 1),
        "reward_sum": float(stats.reward.sum()),
        "progress_sum": float(stats.progress.sum()),
        "collisions": stats.collisions,
        "off_tracks": stats.off_tracks,
        "no_progress": stats.no_progress,
        "mean_speed_frac": float(stats.speed_sum.sum() / max(stats.speed_steps.sum(), 1) / speed_limit),
        "lane_deviation": stats.lane_deviation_sum / max(stats.speed_steps.sum(), 1),
    }
    for name, flag in (("overtaker", 1.0), ("keeper", 0.0)):
        mask = stats.behaviour_id == flag
        if mask.any():
            row[f"{name}s_placed"] = int((mask & placed).sum())
            mask &= placed
        if mask.any():
            row[f"{name}_speed_frac"] = float(
                stats.speed_sum[mask].sum() / max(stats.speed_steps[mask].sum(), 1) / speed_limit
            )
            row[f"{name}_reward_per_agent"] = float(stats.reward[mask].mean())
            row[f"{name}_progress_per_agent"] = float(stats.progress[mask].mean())
            row[f"{name}_collisions_per_agent"] = float(stats.collided[mask].mean())
    if passed is not None:
        row["passed_frac"] = passed
    return row


def passed_fraction(env: BehaveEnv) -> float | None:
    """Share of (overtaker, passive car) pairs where the overtaker ended ahead of the passive car."""
    n_opp = env.config.n_opponents
    if n_opp == 0 or not env.slot_behaviour.any():
        return None
    agents = env.progress[n_opp:][env.slot_behaviour == 1]
    passive = env.progress[:n_opp]
    return float((agents[:, None] > passive[None, :]).mean())


def mean_rows(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Average of every numeric column over the episodes that have it (an episode whose overtakers all
    found no place to start has no overtaker figures)."""
    numeric = (k for r in rows for k, v in r.items() if isinstance(v, int | float))
    keys = dict.fromkeys(k for k in numeric if k != "episode")
    return {k: float(np.mean([r[k] for r in rows if k in r])) for k in keys}
