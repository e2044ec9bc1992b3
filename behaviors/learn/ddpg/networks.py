"""Actor and critic MLPs of DDPG (Lillicrap et al. 2015), sized for the 65/66-float observation."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from itertools import pairwise

import numpy as np
import torch
from torch import nn

ACTION_NAMES = ("steer", "accel", "brake")
ACTION_LOW = (-1.0, 0.0, 0.0)
ACTION_HIGH = (1.0, 1.0, 1.0)
ACT_DIM = len(ACTION_NAMES)
FINAL_INIT = 3e-3  # DDPG paper: final layers start tiny so the first actions and Qs are ~neutral
INITIAL_BRAKE_BIAS = -3.0
"""The brake head starts at sigmoid(-3) = 0.05, not 0.5: half brake outweighs half throttle
(7.5 vs 3 m/s^2), so a fresh policy would stand still and learn nothing but 'no progress'."""


def _small_init(layer: nn.Linear) -> nn.Linear:
    nn.init.uniform_(layer.weight, -FINAL_INIT, FINAL_INIT)
    nn.init.uniform_(layer.bias, -FINAL_INIT, FINAL_INIT)
    return layer


def _mlp(sizes: Sequence[int]) -> nn.Sequential:
    """Linear+ReLU stack; PyTorch's default init is the paper's uniform ±1/sqrt(fan_in)."""
    layers: list[nn.Module] = []
    for n_in, n_out in pairwise(sizes):
        layers += [nn.Linear(n_in, n_out), nn.ReLU()]
    return nn.Sequential(*layers)


def squash_actions(raw: torch.Tensor) -> torch.Tensor:
    """Map raw head outputs [N,3] onto the action ranges: tanh steer, sigmoid accel and brake."""
    return torch.cat([torch.tanh(raw[:, :1]), torch.sigmoid(raw[:, 1:])], dim=1)


class Actor(nn.Module):
    """mu(s): observation [N,D] -> action [N,3] (steer, accel, brake); starts near (0, .5, .05)."""

    def __init__(self, obs_dim: int, hidden: Sequence[int] = (256, 256)) -> None:
        super().__init__()
        self.obs_dim = obs_dim
        self.hidden = tuple(hidden)
        self.body = _mlp([obs_dim, *hidden])
        self.head = _small_init(nn.Linear(hidden[-1], ACT_DIM))
        with torch.no_grad():
            self.head.bias[2] = INITIAL_BRAKE_BIAS

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return squash_actions(self.head(self.body(obs)))


class Critic(nn.Module):
    """Q(s, a) -> [N] with [s, a] concatenated at the input (as in TD3/SAC), which learns faster
    than the DDPG paper's join at the second layer (docs/history.md)."""

    def __init__(self, obs_dim: int, act_dim: int = ACT_DIM, hidden: Sequence[int] = (256, 256)) -> None:
        super().__init__()
        self.body = _mlp([obs_dim + act_dim, *hidden])
        self.head = _small_init(nn.Linear(hidden[-1], 1))

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        return self.head(self.body(torch.cat([obs, act], dim=1))).squeeze(1)


def driving_function(actor: Actor) -> Callable[[np.ndarray], np.ndarray]:
    """The actor as a function of a fleet's float32 observations [N, D] -> float32 actions [N, 3],
    for driving, in the actor's own dtype (float32, or bfloat16 for populate's big fleets).

    The same arithmetic as `actor(x)` (each layer is the addmm that `nn.Linear` runs), but every
    layer writes into a buffer kept between calls. `actor(x)` asks the allocator for fresh memory
    at every layer, page faults at every call of a big fleet (docs/benchmarks.md). Buffers grow to the
    largest fleet seen; the weights are read at each call, so the function follows the actor if
    it is trained further.
    """
    layers = [m for m in actor.body if isinstance(m, nn.Linear)] + [actor.head]
    dtype = actor.head.weight.dtype
    inputs = torch.empty(0, actor.obs_dim, dtype=dtype)  # observations rounded to `dtype`, if not float32
    buffers: list[torch.Tensor] = []
    out = torch.empty(0, ACT_DIM, dtype=dtype)

    def act(obs: np.ndarray) -> np.ndarray:
        nonlocal inputs, buffers, out
        n = len(obs)
        if n > len(out):
            inputs = torch.empty(n, actor.obs_dim, dtype=dtype)
            buffers = [torch.empty(n, layer.out_features, dtype=dtype) for layer in layers]
            out = torch.empty(n, ACT_DIM, dtype=dtype)
        with torch.inference_mode():
            x = torch.from_numpy(obs)
            if dtype != x.dtype:
                x = inputs[:n].copy_(x)
            for k, layer in enumerate(layers):
                h = buffers[k][:n]
                torch.addmm(layer.bias, x, layer.weight.t(), out=h)
                if layer is not actor.head:
                    h.relu_()
                x = h
            y = out[:n]
            torch.tanh(x[:, :1], out=y[:, :1])
            torch.sigmoid(x[:, 1:], out=y[:, 1:])
            return y.float().numpy() if dtype != torch.float32 else y.numpy().copy()

    return act
