"""The RL environments on a user's road (net=, sumocfg=), the Gym env's multi behaviour, reward
weights from the config, and the Stable-Baselines3 helper: real SUMO through libsumo, small nets,
a few simulated seconds each."""

from __future__ import annotations

import subprocess
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test

from behaviors.errors import BehaveError
from behaviors.learn.env import make_env
from behaviors.learn.gym_env import ENV_ID
from behaviors.sumo.sumo_home import sumo_binary
from behaviors.traffic.lanes import TRAFFIC_OBS_SIZE
from behaviors.traffic.rewards import TRAFFIC_TERM_NAMES, RewardWeightError
from sumo_scenarios.osm_like import OsmLikeNet

BEHAVIOUR_ID = TRAFFIC_OBS_SIZE - 1
"""The traffic observation's last value: 0 keeper, 1 overtaker."""
FORWARD = np.array([0.0, 0.5, 0.0], np.float32)
"""Hold the lane, drive by the car-following law."""


def a10kw() -> Path | None:
    """The OSM motorway net shipped in the eclipse-sumo wheel, if this install has it."""
    sumo = pytest.importorskip("sumo")
    net = Path(sumo.SUMO_HOME) / "tools" / "game" / "A10KW" / "osm.net.xml"
    return net if net.is_file() else None


def netconvert(folder: Path, edges: str) -> Path:
    """A net from plain XML: two nodes 500 m apart and `edges` between them."""
    (folder / "n.nod.xml").write_text('<nodes><node id="a" x="0" y="0"/><node id="b" x="500" y="0"/></nodes>')
    (folder / "n.edg.xml").write_text(f"<edges>{edges}</edges>")
    net = folder / "n.net.xml"
    subprocess.run(
        [sumo_binary("netconvert"), "-n", str(folder / "n.nod.xml"), "-e", str(folder / "n.edg.xml"),
         "-o", str(net), "--no-turnarounds"],
        check=True, capture_output=True,
    )  # fmt: skip
    return net


def drive(env: gymnasium.Env, seed: int) -> tuple[dict, int, bool]:
    """One episode with FORWARD: (the reset's info, steps, whether it ended by the time limit)."""
    obs, info = env.reset(seed=seed)
    steps, terminated, truncated = 0, False, False
    while not (terminated or truncated):
        assert obs in env.observation_space
        obs, reward, terminated, truncated, _ = env.step(FORWARD)
        assert np.isfinite(reward)
        steps += 1
    return info, steps, truncated


@pytest.mark.sumo
def test_gym_env_drives_a_netconvert_net_among_sumo_cars(motorway: OsmLikeNet) -> None:
    """net=: the car enters on a multi-lane edge of the user's net among SUMO's cars and drives to
    the time limit."""
    env = gymnasium.make(ENV_ID, net=motorway.net, max_steps=25, traffic_density=(8.0, 12.0))
    try:
        info, steps, truncated = drive(env, seed=0)
        traffic = env.unwrapped.traffic
        assert info == {"road": "motorway3.net.xml", "behaviour": "lanekeeping"}
        assert any(v.startswith("traffic_") for v in traffic.sim.vehicle_ids())
        assert (steps, truncated) == (25, True)
    finally:
        env.close()


@pytest.mark.sumo
def test_gym_env_on_the_osm_motorway_of_the_sumo_wheel() -> None:
    net = a10kw()
    if net is None:
        pytest.skip("this eclipse-sumo wheel has no tools/game/A10KW")
    env = gymnasium.make(ENV_ID, net=net, behaviour="overtaking", max_steps=10, traffic_density=(1.0, 1.0))
    try:
        obs, info = env.reset(seed=1)
        traffic = env.unwrapped.traffic
        edge = traffic.sim.read_lanes(["agent_0"])[0].rpartition("_")[0]
        assert info["road"] == "osm.net.xml" and obs[BEHAVIOUR_ID] == 1.0
        assert traffic.geometry.edges[edge].lanes >= 2  # populate's routes: multi-lane edges only
        _, steps, truncated = drive(env, seed=1)
        assert steps == 10 and truncated
    finally:
        env.close()


@pytest.mark.sumo
def test_pettingzoo_env_runs_a_sumocfg_with_its_own_traffic(motorway: OsmLikeNet) -> None:
    """sumocfg=: SUMO's cars are the scenario's own (its flows' ids), the env adds none."""
    env = make_env(driver="traffic", sumocfg=motorway.sumocfg, agents=3, max_steps=20, seed=2)
    try:
        obs, _ = env.reset(seed=2)
        assert env.agents and all(o.shape == (TRAFFIC_OBS_SIZE,) for o in obs.values())
        others = [v for v in env.sim.vehicle_ids() if v not in env.agents]
        assert others and not any(v.startswith("traffic_") for v in others)
        assert {v.rpartition(".")[0] for v in others} <= {"through", "leaving", "joining", "lorries"}
        while env.agents:
            env.step({a: FORWARD for a in env.agents})
    finally:
        env.close()


@pytest.mark.sumo
def test_the_envs_on_a_users_road_pass_the_library_checks(motorway: OsmLikeNet) -> None:
    """Gymnasium's check_env on net= (seeded resets and steps repeat, spaces honoured) and
    PettingZoo's parallel_api_test on sumocfg=."""
    env = gymnasium.make(ENV_ID, net=motorway.net, max_steps=20, traffic_density=(6.0, 6.0))
    try:
        check_env(env.unwrapped, skip_render_check=True)  # one SUMO per process: no render env
    finally:
        env.close()
    parallel = make_env(driver="traffic", sumocfg=motorway.sumocfg, agents=3, max_steps=40, seed=0)
    try:
        parallel_api_test(parallel, num_cycles=60)
    finally:
        parallel.close()


def multi_draws(net: Path, seed: int, episodes: int) -> list[tuple[str, float]]:
    """The behaviour info names and the observation's behaviour id of consecutive episodes."""
    env = gymnasium.make(ENV_ID, net=net, behaviour="multi", max_steps=5, traffic_density=(2.0, 2.0))
    try:
        draws = []
        for k in range(episodes):
            obs, info = env.reset(seed=seed if k == 0 else None)
            draws.append((info["behaviour"], float(obs[BEHAVIOUR_ID])))
        return draws
    finally:
        env.close()


@pytest.mark.sumo
def test_multi_draws_the_behaviour_per_episode_from_the_seed(motorway: OsmLikeNet) -> None:
    first = multi_draws(motorway.net, seed=5, episodes=6)
    assert first == multi_draws(motorway.net, seed=5, episodes=6)
    assert {name for name, _ in first} == {"lanekeeping", "overtaking"}
    assert all(behaviour_id == (name == "overtaking") for name, behaviour_id in first)


def episode_terms(net: Path, weights: dict[str, float] | None) -> dict[str, np.ndarray]:
    """Each reward term and the total, per step, of a seeded episode with fixed actions."""
    env = make_env(driver="traffic", net=net, agents=1, max_steps=15, seed=3, reward_weights=weights,
                   traffic_density=(6.0, 6.0))  # fmt: skip
    try:
        env.reset_arrays(seed=3)
        rows = []
        while env.agents:
            batch = env.step_arrays(FORWARD[None])
            rows.append({**batch.terms.as_dict(), "total": batch.reward})
        return {name: np.concatenate([row[name] for row in rows]) for name in rows[0]}
    finally:
        env.close()


@pytest.mark.sumo
def test_reward_weights_scale_their_terms_and_the_default_is_unchanged(motorway: OsmLikeNet) -> None:
    default = episode_terms(motorway.net, None)
    ones = episode_terms(motorway.net, dict.fromkeys(TRAFFIC_TERM_NAMES, 1.0))
    for name in default:
        assert np.array_equal(default[name], ones[name]), name
    weighted = episode_terms(motorway.net, {"speed": 3.0, "centre": 0.0})
    assert np.array_equal(weighted["speed"], 3.0 * default["speed"])
    assert not weighted["centre"].any()
    np.testing.assert_allclose(
        weighted["total"], default["total"] + 2.0 * default["speed"] - default["centre"], atol=1e-12
    )
    assert default["speed"].any()


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"driver": "traffic", "reward_weights": {"sped": 2.0}}, "no reward term 'sped' in the traffic"),
        ({"driver": "traffic", "reward_weights": {"race": 1.0}}, "no reward term 'race'"),
        ({"driver": "traffic", "reward_weights": {"speed": float("nan")}}, "'speed' must be a finite number"),
        ({"driver": "paper", "reward_weights": {"speed": 1.0}}, "no reward term 'speed' in the paper"),
    ],
)
def test_bad_reward_weights_raise(settings: dict, message: str) -> None:
    with pytest.raises(RewardWeightError, match=message):
        make_env("tiny" if settings["driver"] == "paper" else "roads", **settings)


@pytest.mark.sumo
def test_paper_driver_takes_reward_weights_too() -> None:
    env = make_env("tiny", agents=2, max_steps=3, seed=0, reward_weights={"progress": 0.0})
    try:
        env.reset_arrays(seed=0)
        batch = env.step_arrays(np.tile(FORWARD, (2, 1)))
        assert not batch.terms.progress.any()
    finally:
        env.close()


@pytest.mark.sumo
@pytest.mark.parametrize(
    "where", ["missing", "one_lane", "sumocfg_as_net", "missing_sumocfg", "both", "paper"]
)
def test_bad_road_is_one_clear_error(tmp_path: Path, motorway: OsmLikeNet, where: str) -> None:
    settings, message = {
        "missing": ({"net": tmp_path / "nowhere.net.xml"}, "network file not found"),
        "one_lane": (
            {"net": netconvert(tmp_path, '<edge id="e" from="a" to="b" numLanes="1" speed="30"/>')},
            "has no multi-lane edge",
        ),
        "sumocfg_as_net": (
            {"net": motorway.sumocfg},
            "is a SUMO configuration, not a network: pass it as sumocfg=",
        ),
        "missing_sumocfg": ({"sumocfg": tmp_path / "nowhere.sumocfg"}, "sumocfg not found"),
        "both": ({"net": motorway.net, "sumocfg": motorway.sumocfg}, "both name a network"),
        "paper": ({"net": motorway.net, "driver": "paper"}, "need a driver that drives among traffic"),
    }[where]
    with pytest.raises(BehaveError, match=message):
        gymnasium.make(ENV_ID, **settings) if where != "paper" else make_env(**settings)


@pytest.mark.sumo
@pytest.mark.train
def test_sb3_learns_from_a_seeded_vec_env_of_the_gym_env(motorway: OsmLikeNet) -> None:
    """Two envs (each in its own process: libsumo runs one simulation per process), a few hundred
    steps of PPO."""
    sb3 = pytest.importorskip("stable_baselines3")
    from behaviors.learn.sb3 import sb3_vec_env

    venv = sb3_vec_env(2, seed=0, net=str(motorway.net), behaviour="multi", max_steps=40,
                       traffic_density=(4.0, 4.0))  # fmt: skip
    try:
        model = sb3.PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu")
        model.learn(total_timesteps=256)
        assert model.num_timesteps >= 256
    finally:
        venv.close()
