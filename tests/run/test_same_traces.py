"""The same seed gives the same FCD, byte for byte, as recorded: a change to how the code is laid out
must not change what the cars do.

The policies here are built so that their arithmetic is exact on any CPU (every unit sums at most
two non-zero products, the rest are exact zeros), so the recorded hashes hold on whatever machine
the tests run: a trained network's float32 sums may round differently on another CPU's kernels.
The traffic policy seeks the middle lane (it changes lanes, holds centres, follows); the paper
policy drives straight at half throttle. Each case is a short `make run`-like populate, and one
`--sumocfg --share` run on a net with a lane drop.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import torch

from behaviors.learn.ddpg.checkpoint import save_checkpoint
from behaviors.learn.ddpg.networks import Actor
from behaviors.paper.sensors import OBS_SIZE_WITH_ID
from behaviors.run.populate import populate
from behaviors.run.populate_config import PopulateConfig, config_from
from behaviors.traffic.lanes import TRAFFIC_OBS_SIZE, TRAFFIC_SLICES
from sumo_scenarios.osm_like import Demand, build_osm_like

pytestmark = pytest.mark.sumo

HIDDEN = (4, 4)


def exact_actor(obs_dim: int, steer_inputs: dict[int, float]) -> Actor:
    """An actor whose steer is tanh of a weighted sum of at most two inputs (through two ReLU
    layers that pass them on), accel 0.5 and brake ~0."""
    actor = Actor(obs_dim, HIDDEN)
    with torch.no_grad():
        for layer in (actor.body[0], actor.body[2], actor.head):
            layer.weight.zero_()
            layer.bias.zero_()
        for unit, (index, weight) in enumerate(steer_inputs.items()):
            sign = 1.0 if weight > 0 else -1.0
            actor.body[0].weight[unit, index] = 1.0
            actor.body[2].weight[unit, unit] = 1.0
            actor.head.weight[0, unit] = abs(weight) * sign
        actor.head.bias[2] = -30.0
    return actor


def save_actor(actor: Actor, path: Path, behaviour: str) -> Path:
    meta = {
        "algorithm": "ps-ddpg",
        "behaviour": behaviour,
        "behaviours": ["overtaking", "lanekeeping"],
        "obs_dim": actor.obs_dim,
        "observation_layout": "built by tests/run/test_same_traces.py",
        "normalisation": "as the driver's observation",
        "hidden": list(HIDDEN),
        "training_steps": 0,
    }
    save_checkpoint(path, actor_state=actor.state_dict(), meta=meta)
    return path


def middle_lane_seeker(path: Path) -> Path:
    """Steer towards the side with more lanes: every agent ends up in the middle of three."""
    fast = TRAFFIC_SLICES["lanes_fast_side"].start
    slow = TRAFFIC_SLICES["lanes_slow_side"].start
    return save_actor(exact_actor(TRAFFIC_OBS_SIZE, {fast: 3.0, slow: -3.0}), path, "multi")


def straight_driver(path: Path) -> Path:
    return save_actor(exact_actor(OBS_SIZE_WITH_ID, {}), path, "multi")


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


RECORDED = {
    "highway_traffic": "27cfdb0b59fbb878ced03f6c478f86d47c795c19614bbcd872e29394f363f141",
    "highway_paper": "5a431bf7749e8e20c0e9c94547cca5b3f0ebeece52ea9cc9e31f92bfcca41a27",
    "share_lanedrop": "af559a97adaa1876512e411a45893d822d6cd8adcfe30673fd688c5b845e3f9e",
}
"""sha256 of each case's FCD (csv), recorded on the code before the driver became one object (the
traffic case again when lane changes began to wait for an acceptable gap, and both traffic-driver
cases when the driver began to keep the rules of the road, and again when agents wanted speeds
nearer the limit, began no lane change inside a junction and let cars in from an ending lane;
both highway cases when populate stopped putting cars down fast just behind a slower one; all three
when the two behaviours got their own lane habits and populate stopped putting keepers down in the
fast-most lane; both traffic-driver cases when passing began to wait out a patience, keeping right
to judge the slow lane at the speed wanted, a change to go on into the next lane in one move, and
through cars to let in a car from an ending lane from further back, and again when a change began
to want a 1 s lag behind and SUMO's cars to see agents' braking as their own, and the lane-drop case
when a car let in earned no shorter gap by being faster and SUMO's driver of an agent braked as a
passenger car does, and again when a scenario's car made an agent got the agents' lcAccelLat, so
that SUMO moves it sideways as the driver asks, and again when sensing began to follow a lane
through a junction into the lane it leads into, and both traffic-driver cases when the car-following
law began to stand 2.5 m behind a car, as SUMO's cars do, and the lane-drop case when no change
began any more near the start of an edge nothing leads onto, and both traffic-driver cases when
overtakers came to want 1.02-1.12 of the limit and keepers to keep even the fast-most lane, and all
three when SUMO came to work out its own plans for an agent once a second instead of every step
(the agents' moves are as before, but SUMO puts an agent in at a speed safe for a second's
reaction, and draws fewer random numbers, so its own cars dawdle differently; SUMO's position
update is given as Euler, since such vTypes turn SUMO to the ballistic one by themselves): a change of
behaviour on purpose is a new recording, in the same commit), and the lane-drop case when agents came
to sense every vehicle's own length and width (its 12 m lorries had been sensed as 5 m cars; with
every size read as 5 m the old hash came back)."""


def run_case(case: str, tmp_path: Path) -> Path:
    fcd = tmp_path / f"{case}.csv"
    common = {"seed": 3, "fcd": fcd, "precision": "float32"}
    if case == "highway_traffic":
        policy = middle_lane_seeker(tmp_path / "seeker.pt")
        populate(PopulateConfig(policy=policy, duration=40.0, keep_count=True, **common))
    elif case == "highway_paper":
        policy = straight_driver(tmp_path / "straight.pt")
        populate(PopulateConfig(policy=policy, duration=40.0, keep_count=True, **common))
    else:
        built = build_osm_like("lanedrop", tmp_path, Demand(end=60.0, scale=0.6))
        policy = middle_lane_seeker(tmp_path / "seeker.pt")
        populate(config_from(built.sumocfg, share=0.3, policy=policy, shield=True, **common))
    return fcd


@pytest.mark.parametrize("case", sorted(RECORDED))
def test_fcd_is_byte_for_byte_as_recorded(case: str, tmp_path: Path) -> None:
    assert sha256(run_case(case, tmp_path)) == RECORDED[case]
