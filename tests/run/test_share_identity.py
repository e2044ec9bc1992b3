"""`--share`: SUMO's cars drive exactly as in the plain SUMO run until they interact, with agents on
the same road.

An interaction spreads: a car is touched from the first step it is within INTERACTION_RANGE of an
agent or of a car touched before; every row of a car before that step must equal the plain run's.

The scenario's drivers do not dawdle (Krauss sigma 0). SUMO draws a car's dawdling from the random
stream of the lane it is on (`MSBaseVehicle::getRNG` is its lane's, one of `--thread-rngs`), one
draw per car and step in the order SUMO steps the lane's cars: an agent that is on a lane, or in an
order, where its car would not have been re-deals the draws of every dawdling car on that lane (and
on the lanes sharing its stream), however far away. With sigma 0.5 cars 500 m from any agent left
the plain run's trajectory the step an agent changed their lane's draws (README, "Your own scenario").
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from behaviors.report.agents_table import agents_path
from behaviors.report.fcd_read import fcd_options, read_fcd
from behaviors.run.populate import populate
from behaviors.run.populate_config import config_from
from behaviors.sumo.sim import COLLISION_OPTIONS
from behaviors.sumo.sumo_home import sumo_binary
from sumo_scenarios.osm_like import Demand, build_osm_like

pytestmark = pytest.mark.sumo

INTERACTION_RANGE = 200.0  # m between front bumpers
SEED = 2
STEP = 0.2  # populate's step where the sumocfg sets none
DEMAND = Demand(end=120.0, scale=0.6, sigma=0.0)


def plain_run(cfg: Path, fcd: Path) -> pd.DataFrame:
    """The scenario by SUMO alone, with the options populate documents it sets on SUMO's command line."""
    subprocess.run(
        [sumo_binary("sumo"), "-c", str(cfg), "--seed", str(SEED), "--step-length", str(STEP),
         "--lateral-resolution", "0.8", "--no-step-log", "true", *COLLISION_OPTIONS,
         *fcd_options(fcd, geo=False)],
        check=True, capture_output=True,
    )  # fmt: skip
    return read_fcd(fcd)


def touch_times(ours: pd.DataFrame, plain: pd.DataFrame, agents: set[str]) -> dict[str, float]:
    """When each vehicle first came within range of a touched one (agents from their departure).

    A touched vehicle counts where it is in either run; a candidate where the plain run has it
    (in ours a car the agents held back may not be on the road yet). A car touched at step t may
    only differ from t on: it moved into t knowing where the others were at t - 1 step.
    """
    touched: dict[str, float] = {}
    both = pd.concat([ours.assign(run=0), plain.assign(run=1)])
    for time, rows in both.groupby("time", sort=True):
        touched.update({v: time for v in agents.intersection(rows["id"]) if v not in touched})
        source = rows["id"].isin(touched.keys()).to_numpy()
        candidate = ~source & (rows["run"] == 1).to_numpy()
        if source.any() and candidate.any():
            xy = rows[["x", "y"]].to_numpy()
            gap = np.linalg.norm(xy[candidate][:, None] - xy[source][None], axis=2).min(axis=1)
            near = rows["id"].to_numpy()[candidate][gap <= INTERACTION_RANGE]
            touched.update(dict.fromkeys(near, time))
    return touched


def before_touch(fcd: pd.DataFrame, touched: dict[str, float]) -> pd.DataFrame:
    limit = fcd["id"].map(touched).astype(float).fillna(np.inf)
    return fcd[fcd["time"] < limit].sort_values(["id", "time"]).reset_index(drop=True)


def test_sumo_cars_drive_as_in_plain_sumo_until_an_agent_could_reach_them(tmp_path):
    net = build_osm_like("motorway3", tmp_path / "net", DEMAND)
    fcd = tmp_path / "ours.parquet"
    populate(config_from(net.sumocfg, share=0.2, seed=SEED, fcd=fcd, shield=False))
    ours, plain = read_fcd(fcd), plain_run(net.sumocfg, tmp_path / "plain.parquet")
    agents = set(pd.read_csv(agents_path(fcd))["id"])
    touched = touch_times(ours, plain, agents)
    never = set(plain["id"]) - touched.keys()
    same_ours, same_plain = before_touch(ours, touched), before_touch(plain, touched)
    assert len(agents) >= 5 and len(touched) - len(agents) >= 20 and len(never) >= 3
    assert len(same_plain) >= 800  # rows of SUMO's cars before anything could reach them
    pd.testing.assert_frame_equal(same_ours, same_plain)
