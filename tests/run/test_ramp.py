"""Lane drops at any share: a car waiting at the end of a lane that ends is let in,
zip fashion, by the through lane's agents, and nobody stands at a work zone's lane drop.

The scenario is `make ramp`'s (benchmarks/ramp_bars.py): a 3-lane motorway built by netconvert from
plain XML, an on-ramp, a work zone that closes the right lane, cars, lorries and vans."""

from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from helpers import behave

from behaviors.traffic.motives.cooperative import letting_in
from behaviors.traffic.scene import lane_traffic
from behaviors.traffic.settings import LaneDriving
from tests.learn.test_traffic import leaders_of

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from ramp_bars import build_ramp, write_sumocfg

SPEED, DESIRED = np.array([20.0]), np.array([30.0])


def let_in(leaders, slow_lane_leads_on: float, speed: np.ndarray = SPEED) -> float:
    ruled = LaneDriving()
    ends = np.array([[2000.0, 2000.0, slow_lane_leads_on]])  # own, fast-side, slow-side lane
    return float(letting_in(lane_traffic(speed, DESIRED, *leaders, ruled.following), ends, ruled)[0])


def test_a_car_standing_at_its_lanes_end_is_let_in_by_the_first_car_that_can_stop_for_it():
    """The through lane flows at 20 m/s past a car standing at the end of the lane beside it, 80 m
    on: the car whose own leader (40 m on) is passing it drops back for it. It used to be let in only
    within the look-ahead (60 m at 20 m/s), where stopping for it took more than `safe_decel`, and only
    once it fitted in front of the own leader, which the leader passing it left too late: every car
    passed it for the next one back, and none let it in."""
    ruled = LaneDriving()
    waiting = leaders_of(lead=(0, 40.0, 20.0), slow_lead=(4, 80.0, 0.0))
    assert -ruled.safe_decel <= let_in(waiting, slow_lane_leads_on=90.0) < -0.5
    assert (
        let_in(waiting, slow_lane_leads_on=2000.0) == np.inf
    )  # its lane leads on: it waits for something else
    # no nearer than the car can stop behind it comfortably: passed, the next car back lets it in
    assert (
        let_in(leaders_of(lead=(0, 10.0, 20.0), slow_lead=(4, 25.0, 0.0)), slow_lane_leads_on=35.0) == np.inf
    )
    # a car in the ending lane as fast as the own leader, beyond it: the leader lets it in (as before)
    alongside_the_leader = leaders_of(lead=(0, 33.0, 20.0), slow_lead=(4, 45.0, 20.0))
    assert let_in(alongside_the_leader, slow_lane_leads_on=300.0) == np.inf


@pytest.mark.sumo
def test_every_car_learned_on_a_work_zones_lane_drop_nobody_stands_and_nobody_collides(tmp_path):
    """Share 1.0 of the ramp scenario for 300 s: before the through lane's agents let in the car
    standing at the lane drop's end, such a car (an agent SUMO drove there) stood 60 s while agents
    streamed past it at 70-80 km/h."""
    duration = 300.0
    net, routes = build_ramp(tmp_path / "road", duration)
    sumocfg = write_sumocfg(tmp_path / "run", net, routes, duration)
    fcd = tmp_path / "run" / "fcd.parquet"
    done = behave(
        "populate", "--sumocfg", str(sumocfg), "--share", "1", "--seed", "1", "--duration", f"{duration:g}",
        "--fcd", str(fcd), "--json", "--quiet", timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["of_them_agents"] > 150  # every passenger car became an agent (the lorries and vans SUMO's)
    assert out["collisions"] == 0 and out["off_tracks"] == 0
    collisions = [e for _, e in ET.iterparse(tmp_path / "run" / "collisions.xml") if e.tag == "collision"]
    assert collisions == []  # SUMO's own count, every vehicle
    assert out["agents_standing_30s"] == 0, out["longest_standstill_s"]
    assert out["sumo_standing_30s"] == 0, out["sumo_longest_standstill_s"]
