"""One policy loader: every bundled policy and a traffic-driver training run through every command that
takes a policy (evaluate, populate, sweep, train --init) on real SUMO, and what the loader infers for
older files. `behave report` and the Gymnasium and PettingZoo envs take no policy."""

from __future__ import annotations

import io
from pathlib import Path

import pandas as pd
import pytest
import torch
from typer.testing import CliRunner

from behaviors.cli.main import app
from behaviors.errors import BehaveError
from behaviors.learn.ddpg.checkpoint import load_actor, load_checkpoint, save_checkpoint
from behaviors.learn.ddpg.networks import Actor
from behaviors.learn.policy import PRETRAINED, Policy, bundled_names, load_policy
from behaviors.paper.sensors import OBS_SIZE_WITH_ID
from behaviors.run.sweep import Grid, check_grid, resolve_net, resolve_policy, run_point
from behaviors.traffic.lanes import TRAFFIC_OBS_SIZE

BUNDLED = bundled_names()


def run(*args: str) -> str:
    result = CliRunner().invoke(app, list(args))
    assert result.exit_code == 0, result.output
    return result.output


def agent_options(policy: Policy) -> list[str]:
    """A couple of agents of the kinds the policy drives (none of the others)."""
    overtakers = {"multi": 1, "overtaking": 2}.get(policy.behaviour, 0)
    keepers = {"multi": 1, "lanekeeping": 2}.get(policy.behaviour, 0)
    return ["--overtakers", str(overtakers), "--keepers", str(keepers)]


def evaluate_options(policy: Policy) -> list[str]:
    """The smallest evaluation of its behaviour: one short episode, the paper's on the tiny road."""
    if policy.driver in ("traffic", "styled"):
        return agent_options(policy)
    multi = ["--overtakers", "1", "--keepers", "1", "--placement", "C"]
    return ["--scenario", "tiny", *(multi if policy.behaviour == "multi" else ["--agents", "1"])]


def test_the_bundled_policies_are_the_five_of_the_model_card():
    assert BUNDLED == ["lanekeeping", "multi", "overtaking", "styled", "traffic"]
    kinds = {name: (p.driver, p.behaviour) for name in BUNDLED for p in [load_policy(name)]}
    assert kinds == {"lanekeeping": ("paper", "lanekeeping"), "multi": ("paper", "multi"),
                     "overtaking": ("paper", "overtaking"), "styled": ("styled", "multi"),
                     "traffic": ("traffic", "multi")}  # fmt: skip


@pytest.mark.sumo
@pytest.mark.parametrize("name", BUNDLED)
@pytest.mark.parametrize("as_path", [False, True], ids=["by-name", "by-path"])
def test_evaluate_runs_every_bundled_policy(tmp_path, name, as_path):
    policy = load_policy(name)
    spec = str(PRETRAINED / f"{name}.pt") if as_path else name
    out = tmp_path / "eval"
    run("evaluate", spec, *evaluate_options(policy), "--episodes", "1", "--max-steps", "10", "--no-realism",
        "--out", str(out))  # fmt: skip
    table = pd.read_csv(out / "results.csv")
    assert list(table["policy"]) == [name] and (table["steps"] <= 10).all()


@pytest.mark.sumo
@pytest.mark.parametrize("name", BUNDLED)
def test_populate_runs_every_bundled_policy(tmp_path, name):
    fcd = tmp_path / "fcd.xml"
    agents = agent_options(load_policy(name))
    run("populate", "--policy", name, *agents, "--background", "2", "--duration", "4", "--fcd", str(fcd))
    assert len(pd.read_csv(tmp_path / "fcd.agents.csv")) >= 2 and fcd.is_file()


@pytest.mark.sumo
@pytest.mark.parametrize("name", BUNDLED)
def test_a_sweep_point_runs_every_bundled_policy(name):
    """The sweep's own checks and one of its runs, in this process (the Ray workers run the same)."""
    overtakers, keepers = agent_options(load_policy(name))[1::2]
    counts = {"overtakers": (int(overtakers),), "keepers": (int(keepers),)}
    grid = Grid(
        nets=(resolve_net("highway"),), policies=(resolve_policy(name),), background=2, duration=4.0, **counts
    )
    (point,) = check_grid(grid)
    result = run_point(point, keep_fcd=True)
    assert result.agents is not None, result.row
    agents = pd.read_csv(io.BytesIO(result.agents))
    assert len(agents) >= 2 and set(agents["policy"]) == {name}


def train_options(policy: Policy) -> list[str]:
    """The smallest training of the policy's driver and behaviour, one agent of each kind it drives."""
    if policy.driver in ("traffic", "styled"):
        return [policy.behaviour, "--driver", policy.driver, "--scenario", "roads", *agent_options(policy)]
    agents = {"multi": agent_options(policy), "overtaking": ["--agents", "1", "--opponents", "1"]}
    return [policy.behaviour, "--scenario", "tiny", *agents.get(policy.behaviour, ["--agents", "1"])]


@pytest.mark.sumo
@pytest.mark.parametrize("name", BUNDLED)
def test_train_starts_from_every_bundled_policy(tmp_path, name):
    """`--init NAME`: before its first update the new run's policy is the bundled one."""
    out = tmp_path / "run"
    run("train", *train_options(load_policy(name)), "--init", name, "--episodes", "1", "--max-steps", "5",
        "--out", str(out))  # fmt: skip
    bundled, trained = load_actor(PRETRAINED / f"{name}.pt"), load_actor(out / "checkpoints" / "final.pt")
    for key, value in bundled.state_dict().items():
        torch.testing.assert_close(trained.state_dict()[key], value)


@pytest.fixture(scope="module")
def traffic_run(tmp_path_factory) -> Path:
    """A real (tiny) `behave train multi --driver traffic` run directory."""
    out = tmp_path_factory.mktemp("train") / "run"
    run("train", "multi", "--driver", "traffic", "--scenario", "roads", "--overtakers", "1", "--keepers", "1",
        "--max-steps", "10", "--episodes", "1", "--hidden", "16,16", "--out", str(out))  # fmt: skip
    return out


@pytest.mark.sumo
def test_a_traffic_training_run_names_its_driver_and_drives_evaluate_and_populate(tmp_path, traffic_run):
    assert load_checkpoint(traffic_run / "checkpoints" / "final.pt").meta["driver"] == "traffic"
    policy = load_policy(traffic_run)
    assert (policy.label, policy.driver, policy.behaviour) == ("run", "traffic", "multi")
    for spec in (traffic_run, traffic_run / "checkpoints" / "last.pt"):
        run("evaluate", str(spec), "--overtakers", "1", "--keepers", "1", "--episodes", "1",
            "--max-steps", "10", "--no-realism", "--out", str(tmp_path / "eval"))  # fmt: skip
    run("populate", "--policy", str(traffic_run), "--overtakers", "1", "--keepers", "1", "--background", "2",
        "--duration", "4", "--fcd", str(tmp_path / "fcd.xml"))  # fmt: skip


def old_file(path: Path, obs_dim: int, behaviours: list[str], **extra: object) -> Path:
    """A checkpoint as behave wrote them before checkpoints named their driver (nor, earlier, their
    behaviour)."""
    meta = {"algorithm": "ps-ddpg", "behaviours": behaviours, "obs_dim": obs_dim, "format_version": 1,
            "observation_layout": "t", "normalisation": "t", "hidden": [8], "training_steps": 0}  # fmt: skip
    meta.update(extra)
    payload = {"meta": meta, "actor": Actor(obs_dim, (8,)).state_dict(), "critic": None, "extra": None}
    torch.save(payload, path)
    return path


def test_older_files_get_their_driver_from_their_input_size(tmp_path):
    both = ["overtaking", "lanekeeping"]
    traffic = load_policy(old_file(tmp_path / "t.pt", TRAFFIC_OBS_SIZE, both))
    paper = load_policy(old_file(tmp_path / "p.pt", OBS_SIZE_WITH_ID, both))
    assert (traffic.driver, traffic.behaviour) == ("traffic", "multi")
    assert (paper.driver, paper.behaviour) == ("paper", "multi")
    assert paper.act(torch.zeros(3, OBS_SIZE_WITH_ID).numpy(), None).shape == (3, 3)


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        (lambda tmp: "no_such_policy", "checkpoint not found: no_such_policy .*bundled policy: lanekeeping"),
        (lambda tmp: tmp, "not a training run"),
        (lambda tmp: old_file(tmp / "odd.pt", 7, ["lanekeeping"]), "no driver takes 7 observations"),
        (
            lambda tmp: old_file(tmp / "old.pt", 26, ["lanekeeping"], driver="traffic"),
            "takes 26 observations, but the traffic driver's lanekeeping agents see",
        ),
    ],
)
def test_what_cannot_drive_is_refused_in_one_line(tmp_path, spec, message):
    with pytest.raises(BehaveError, match=message):
        load_policy(spec(tmp_path))


def test_new_checkpoints_name_their_driver(tmp_path):
    meta = {"algorithm": "ps-ddpg", "behaviours": ["lanekeeping"], "obs_dim": TRAFFIC_OBS_SIZE,
            "observation_layout": "t", "normalisation": "t", "hidden": [8], "training_steps": 0}  # fmt: skip
    save_checkpoint(tmp_path / "a.pt", actor_state=Actor(TRAFFIC_OBS_SIZE, (8,)).state_dict(), meta=meta)
    assert load_checkpoint(tmp_path / "a.pt").meta["driver"] == "traffic"
