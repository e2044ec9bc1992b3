"""TorchRL's PettingZooWrapper over behave's PettingZoo env: its spec check, and a rollout through
an episode where agents leave one by one and the last two end in one step for different reasons."""

from __future__ import annotations

import pytest
import torch

from behaviors.learn.env import make_env

pytest.importorskip("torchrl", reason="TorchRL is not installed (the integrations extra)")
from tensordict import TensorDictBase
from torchrl.envs import PettingZooWrapper
from torchrl.envs.utils import check_env_specs

pytestmark = pytest.mark.sumo

STEER = torch.tensor([1.0, -0.08, 0.0])
"""agent_0 hard right: off the road at step 2; agent_1 slightly left: off at step 7; agent_2 straight."""
LAST_STEP = 7


def wrapped() -> PettingZooWrapper:
    """Agents leave at different times: TorchRL needs the mask, and done only once all are done
    (by default a parallel env is reset as soon as one agent is done)."""
    env = make_env("tiny", agents=3, max_steps=LAST_STEP, seed=0, start_speed=10.0)
    return PettingZooWrapper(env, use_mask=True, done_on_any=False)


def scripted(td: TensorDictBase) -> TensorDictBase:
    """The steering above, half throttle, no brake; for every agent slot (TorchRL passes actions for
    agents that left too; the env ignores them)."""
    return td.set(("agent", "action"), torch.stack([STEER, torch.full((3,), 0.5), torch.zeros(3)], -1))


def test_torchrl_wrapper_passes_check_env_specs() -> None:
    env = wrapped()
    try:
        assert env.group_map == {"agent": ["agent_0", "agent_1", "agent_2"]}
        check_env_specs(env, seed=0)
    finally:
        env.close()


def test_torchrl_rollout_through_agents_leaving_apart_and_a_mixed_last_step() -> None:
    """The rollout runs until every agent is done (7 steps, not 2): per agent the mask shows who
    drove, the off-road endings are terminated with their -1000, the time-limited agent is
    truncated, and the next episode starts with all three agents again."""
    env = wrapped()
    try:
        start = env.reset(seed=0)
        rollout = env.rollout(LAST_STEP + 3, scripted, auto_reset=False, tensordict=start,
                              break_when_any_done=False)  # fmt: skip
    finally:
        env.close()
    done = rollout["next", "done"].squeeze(-1).tolist()
    assert done[: LAST_STEP - 1] == [False] * (LAST_STEP - 1) and done[LAST_STEP - 1]
    mask = rollout["agent", "mask"]  # who acted in each step
    assert mask[:, 0].tolist()[:LAST_STEP] == [True, True] + [False] * (LAST_STEP - 2)
    assert mask[:LAST_STEP, 1:].all() and mask[LAST_STEP].all()  # after the end: a new episode, 3 agents
    terminated = rollout["next", "agent", "terminated"].squeeze(-1)[:LAST_STEP]
    truncated = rollout["next", "agent", "truncated"].squeeze(-1)[:LAST_STEP]
    reward = rollout["next", "agent", "reward"].squeeze(-1)
    assert terminated[1, 0] and not truncated[1, 0] and reward[1, 0] < -900
    assert terminated[-1, 1] and not truncated[-1, 1] and reward[LAST_STEP - 1, 1] < -900
    assert truncated[-1, 2] and not terminated[-1, 2] and reward[LAST_STEP - 1, 2] > 0
    assert not terminated[:-1, 1:].any() and not truncated[:-1, 1:].any()
    # TorchRL's env-level keys: done, yet neither terminated nor truncated (the README says so)
    last = rollout["next"][LAST_STEP - 1]
    assert last["done"] and not last["terminated"] and not last["truncated"]
