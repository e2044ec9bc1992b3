"""The recipe that rebuilds the shipped traffic.pt (`benchmarks/make_pretrained.py --stages traffic`):
its start is in the repository, and a fine-tuning from it comes out the same weight for weight when
run again, which the bit-for-bit rebuild rests on (the full run takes 40-80 minutes of one core)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch

from behaviors.learn.ddpg.checkpoint import load_checkpoint

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

import make_pretrained


def shortened(command: list[str], out: Path) -> list[str]:
    """The recipe's command, one short episode long, into `out`."""
    short = {"--episodes": "1", "--max-steps": "40", "--out": str(out), "--max-minutes": "5"}
    flags = [short.get(prev, arg) for prev, arg in zip(["", *command[:-1]], command, strict=True)]
    return [*flags, "--warmup", "32", "--batch-size", "16", "--quiet"]


def weights(checkpoint: Path) -> dict[str, torch.Tensor]:
    state = load_checkpoint(checkpoint)
    assert state.critic_state is not None  # a full checkpoint, not an actor-only file
    nets = {"actor": state.actor_state, "critic": state.critic_state}
    return {f"{net}.{key}": value for net, params in nets.items() for key, value in params.items()}


@pytest.mark.sumo
@pytest.mark.train
def test_the_traffic_recipe_starts_from_its_bundled_checkpoint_and_repeats_weight_for_weight(tmp_path):
    command = make_pretrained.traffic_command(tmp_path, 150.0)
    assert make_pretrained.TRAFFIC_START.is_file()
    assert command[command.index("--init") + 1] == str(make_pretrained.TRAFFIC_START)
    runs = [tmp_path / "a", tmp_path / "b"]
    for out in runs:
        subprocess.run(shortened(command, out), check=True, capture_output=True)
    start = weights(make_pretrained.TRAFFIC_START)
    first, again = (weights(out / "checkpoints" / "final.pt") for out in runs)
    assert first.keys() == start.keys() == again.keys()
    assert all(torch.equal(first[key], again[key]) for key in first)
    assert not all(torch.equal(first[key], start[key]) for key in first)  # it learnt from the start


def test_the_model_card_shows_the_recipe_as_a_clean_checkout_runs_it(tmp_path):
    command = make_pretrained.traffic_command(tmp_path, 150.0)
    shown = [make_pretrained.as_shown(arg) for arg in command]
    assert shown[shown.index("--init") + 1] == "behaviors/pretrained/starts/traffic_start.pt"
    assert shown[shown.index("--out") + 1] == str(tmp_path / "traffic")  # outside: as given
    assert make_pretrained.as_shown("0.0005") == "0.0005"
