"""highway-env beside behave: agent-steps per second of highway-v0 with about as many cars as
bench_env's "6 agents among 50 SUMO cars" row, on the same machine in the same run.

highway-v0 is set up as close to that row as it allows: 3 lanes, 50 other cars (its IDM and
MOBIL drivers), 6 controlled cars (its multi-agent action and observation), continuous actions
(acceleration and steering, like behave's), and a decision every 0.2 s (policy frequency 5 Hz:
3 frames of its 15 Hz simulation per step) as well as at its default 1 Hz (15 frames per step).
The controlled cars get small random accelerations and no steering (the road is straight, so
they keep their lanes); an episode that ends (highway-env ends it when the first controlled car
crashes) is reset outside the timing. Agent-steps count every controlled car every step.
"""

from __future__ import annotations

import subprocess
import time
from dataclasses import dataclass

import numpy as np

CONTROLLED = 6
OTHER_CARS = 50
LANES = 3
HIGHWAY_WARMUP = 5
POLICY_HZ = (5, 1)
"""Decisions per simulated second: 5 = behave's 0.2 s step; 1 = highway-env's default."""
INSTALL_HINT = "highway-env is not installed: pip install 'behave-traffic[bench]' -c constraints.txt"


@dataclass(frozen=True)
class AnchorResult:
    label: str
    agents: int
    cars: int
    step_s: float  # simulated seconds per step
    agent_steps: int
    seconds: float

    @property
    def agent_steps_per_s(self) -> float:
        return self.agent_steps / self.seconds

    @property
    def agent_seconds_per_s(self) -> float:
        """Simulated agent-seconds per wall second: the rate with the step length taken out."""
        return self.agent_steps_per_s * self.step_s


def highway_config(policy_hz: int) -> dict:
    return {
        "lanes_count": LANES,
        "vehicles_count": OTHER_CARS,
        "controlled_vehicles": CONTROLLED,
        "policy_frequency": policy_hz,
        "duration": 10**6,  # no time limit inside the measurement
        "action": {"type": "MultiAgentAction", "action_config": {"type": "ContinuousAction"}},
        "observation": {"type": "MultiAgentObservation", "observation_config": {"type": "Kinematics"}},
    }


def run_highway(policy_hz: int, steps: int, seed: int) -> AnchorResult:
    """`steps` timed highway-v0 steps (after a few untimed ones) with 6 controlled cars."""
    import gymnasium
    import highway_env  # noqa: F401  (registers highway-v0)

    env = gymnasium.make("highway-v0", config=highway_config(policy_hz))
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    seconds = 0.0
    try:
        for k in range(HIGHWAY_WARMUP + steps):
            actions = tuple(np.array([rng.uniform(-0.1, 0.1), 0.0], np.float32) for _ in range(CONTROLLED))
            start = time.perf_counter()
            _, _, terminated, truncated, _ = env.step(actions)
            if k >= HIGHWAY_WARMUP:
                seconds += time.perf_counter() - start
            if terminated or truncated:
                env.reset()
        cars = len(env.unwrapped.road.vehicles)
    finally:
        env.close()
    label = f"highway-env highway-v0, {policy_hz} Hz decisions"
    return AnchorResult(label, CONTROLLED, cars, 1.0 / policy_hz, CONTROLLED * steps, seconds)


def cpu_model() -> str:
    """lscpu's model name (the machine the table was measured on)."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return "unknown (no lscpu)"
    names = [line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name:")]
    return names[0] if names else "unknown"


ANCHOR_COLUMNS = ("simulator", "agents", "cars", "s per step", "agent-steps/s", "behave / it",
                  "agent-s simulated / s", "behave / it (simulated)")  # fmt: skip


def anchor_rows(behave: AnchorResult, others: list[AnchorResult]) -> list[list[str]]:
    """behave first, then each anchor with behave's rates over its own (per step, per simulated s)."""
    rows = []
    for r in (behave, *others):
        per_step = behave.agent_steps_per_s / r.agent_steps_per_s
        per_second = behave.agent_seconds_per_s / r.agent_seconds_per_s
        rows.append([
            r.label, str(r.agents), str(r.cars), f"{r.step_s:g}", rate(r.agent_steps_per_s),
            f"{per_step:,.0f}x", rate(r.agent_seconds_per_s), f"{per_second:,.0f}x",
        ])  # fmt: skip
    return rows


def rate(value: float) -> str:
    """Whole numbers from 100 up, three significant digits below (highway-env's rates are small)."""
    return f"{value:,.0f}" if value >= 100 else f"{value:.3g}"
