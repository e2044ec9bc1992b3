"""behave populate on real SUMO: bundled highway, a hand-built curved net with a ramp, FCD, bad input."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from behaviors.errors import BehaveError
from behaviors.fleet.drivers import STYLED_OBS_SIZE
from behaviors.learn.ddpg.checkpoint import load_checkpoint, save_checkpoint
from behaviors.learn.ddpg.networks import Actor
from behaviors.learn.policy import PRETRAINED
from behaviors.report.agents_table import INCIDENT_COLUMNS, agents_path, columns
from behaviors.report.fcd_read import read_fcd, validate_fcd_xml
from behaviors.road.routes import INSERT_LANE_RUN, lane_runs_out
from behaviors.run.fcd_sealing import partial_path
from behaviors.run.populate import populate
from behaviors.run.populate_config import DEFAULT_POLICY, PopulateConfig, populate_policy
from behaviors.run.population import Population
from behaviors.run.precision import BFLOAT16_MIN_BATCH, use_bfloat16
from behaviors.sumo.sumo_home import sumo_binary
from behaviors.traffic.lanes import TRAFFIC_OBS_SIZE
from behaviors.traffic.limits import LIMIT_NAMES
from behaviors.traffic.settings import LaneDriving
from sumo_scenarios.osm_like import Chain, run_netconvert, write_plain


def policy_file(tmp: Path, obs_dim: int, behaviour: str) -> Path:
    path = tmp / f"{behaviour}.pt"
    meta = {
        "algorithm": "ps-ddpg", "behaviour": behaviour, "behaviours": [behaviour], "obs_dim": obs_dim,
        "observation_layout": "test", "normalisation": "test", "hidden": [32, 32], "training_steps": 0,
    }  # fmt: skip
    save_checkpoint(path, actor_state=Actor(obs_dim, (32, 32)).state_dict(), meta=meta)
    return path


def curved_net(tmp: Path) -> Path:
    """Four 3.0 m lanes on an arc of radius ~300 m, then a single-lane ramp and a two-lane exit."""
    arc = " ".join(f"{300 * np.sin(a):.3f},{300 - 300 * np.cos(a):.3f}" for a in np.linspace(0, 1.2, 60))
    (tmp / "c.nod.xml").write_text(
        '<nodes><node id="a" x="0" y="0"/><node id="b" x="279.6" y="191.3"/>'
        '<node id="c" x="420" y="420"/><node id="d" x="560" y="250"/></nodes>'
    )
    (tmp / "c.edg.xml").write_text(
        f'<edges><edge id="arc" from="a" to="b" numLanes="4" width="3.0" speed="27" shape="{arc}"/>'
        '<edge id="ramp" from="b" to="c" numLanes="1" speed="15"/>'
        '<edge id="exit" from="b" to="d" numLanes="2" width="3.0" speed="27"/></edges>'
    )
    net = tmp / "c.net.xml"
    subprocess.run(
        [sumo_binary("netconvert"), "-n", str(tmp / "c.nod.xml"), "-e", str(tmp / "c.edg.xml"),
         "-o", str(net), "--no-turnarounds"],
        check=True, capture_output=True,
    )  # fmt: skip
    return net


@pytest.fixture(scope="module")
def multi_policy(tmp_path_factory) -> Path:
    if DEFAULT_POLICY.is_file():
        return DEFAULT_POLICY
    return policy_file(tmp_path_factory.mktemp("policy"), 66, "multi")


@pytest.mark.sumo
def test_populate_the_bundled_highway_writes_valid_fcd_with_both_behaviours(tmp_path, multi_policy):
    fcd = tmp_path / "out" / "fcd.xml"
    summary = populate(PopulateConfig(policy=multi_policy, overtakers=3, keepers=3, background=10,
                                      duration=30.0, fcd=fcd, seed=1))  # fmt: skip
    validate_fcd_xml(fcd)
    df = read_fcd(fcd)
    types = set(df["type"])
    assert {"behave_keeper", "behave_overtaker", "behave_background"} <= types
    assert summary.vehicles >= 16 and summary.agent_steps > 0
    assert not [p for p in fcd.parent.iterdir() if p.name.startswith(".")]  # no temp files left


@pytest.mark.sumo
def test_the_summary_counts_what_each_limit_of_the_traffic_driver_held(tmp_path):
    summary = populate(PopulateConfig(overtakers=3, keepers=3, background=10, duration=20.0,
                                      fcd=tmp_path / "fcd.xml", seed=1))  # fmt: skip
    assert list(summary.limits) == list(LIMIT_NAMES)
    assert sum(summary.limits.values()) > 0 and max(summary.limits.values()) <= summary.agent_steps
    assert summary.as_dict()["limits"].startswith(f"{LIMIT_NAMES[0]} ")


@pytest.mark.sumo
def test_the_same_seed_gives_byte_identical_fcd(tmp_path, multi_policy):
    runs = []
    for name in ("a", "b"):
        fcd = tmp_path / name / "fcd.xml"
        populate(PopulateConfig(policy=multi_policy, overtakers=2, keepers=2, background=8, duration=20.0,
                                fcd=fcd, seed=5))  # fmt: skip
        runs.append(fcd.read_bytes())
    assert runs[0] == runs[1]
    other = tmp_path / "c" / "fcd.xml"
    populate(PopulateConfig(policy=multi_policy, overtakers=2, keepers=2, background=8, duration=20.0,
                            fcd=other, seed=6))  # fmt: skip
    assert other.read_bytes() != runs[0]


@pytest.mark.sumo
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_fcd_in_csv_and_parquet(tmp_path, multi_policy, suffix):
    fcd = tmp_path / f"fcd{suffix}"
    populate(
        PopulateConfig(policy=multi_policy, overtakers=1, keepers=1, background=4, duration=10.0, fcd=fcd)
    )
    df = read_fcd(fcd)
    assert {"behave_keeper", "behave_overtaker"} <= set(df["type"])


@pytest.mark.sumo
def test_agents_on_a_curved_four_lane_net_never_take_the_single_lane_ramp(tmp_path, multi_policy):
    net = curved_net(tmp_path)
    fcd = tmp_path / "fcd.xml"
    summary = populate(PopulateConfig(net=net, policy=multi_policy, overtakers=3, keepers=3, background=6,
                                      duration=40.0, fcd=fcd, keep_count=True, seed=2))  # fmt: skip
    validate_fcd_xml(fcd)
    df = read_fcd(fcd)
    agents = df[df["type"].isin(["behave_keeper", "behave_overtaker"])]
    assert len(agents) > 0
    assert not agents["lane"].str.startswith("ramp").any()
    assert agents["lane"].str.startswith("arc").any()
    assert summary.vehicles >= 12


@pytest.mark.sumo
def test_keep_count_reinserts_agents_that_leave(tmp_path, multi_policy):
    base = {"policy": multi_policy, "overtakers": 2, "keepers": 2, "background": 0, "duration": 150.0}
    kept = populate(PopulateConfig(**base, fcd=tmp_path / "k.xml", keep_count=True))
    dropped = populate(PopulateConfig(**base, fcd=tmp_path / "d.xml", keep_count=False))
    steps = round(150.0 / 0.2)
    assert kept.vehicles > 4  # the 3 km highway is left after ~100 s: replacements came in
    assert kept.agent_steps > dropped.agent_steps
    assert kept.agent_steps >= 0.9 * 4 * steps


@pytest.mark.sumo
def test_a_lanekeeping_policy_drives_keepers_only(tmp_path):
    lanekeeping = policy_file(tmp_path, 65, "lanekeeping")
    fcd = tmp_path / "fcd.xml"
    populate(PopulateConfig(policy=lanekeeping, overtakers=0, keepers=2, background=2, duration=5.0, fcd=fcd))
    assert set(read_fcd(fcd)["type"]) == {"behave_keeper", "behave_background"}
    with pytest.raises(BehaveError, match="lanekeeping policy: use --keepers"):
        populate(PopulateConfig(policy=lanekeeping, overtakers=2, keepers=0, duration=5.0, fcd=fcd))


def single_lane_net(tmp: Path) -> Path:
    (tmp / "s.nod.xml").write_text('<nodes><node id="a" x="0" y="0"/><node id="b" x="300" y="0"/></nodes>')
    (tmp / "s.edg.xml").write_text('<edges><edge id="e" from="a" to="b" numLanes="1"/></edges>')
    net = tmp / "s.net.xml"
    subprocess.run([sumo_binary("netconvert"), "-n", str(tmp / "s.nod.xml"), "-e", str(tmp / "s.edg.xml"),
                    "-o", str(net)], check=True, capture_output=True)  # fmt: skip
    return net


def bad_inputs(tmp: Path, policy: Path) -> list[tuple[dict, str]]:
    malformed = tmp / "bad.net.xml"
    malformed.write_text("<net><edge")
    corrupt = tmp / "corrupt.pt"
    corrupt.write_bytes(b"not a checkpoint")
    file_in_the_way = tmp / "file"
    file_in_the_way.write_text("x")
    return [
        ({"net": tmp / "missing.net.xml"}, "network file not found"),
        ({"net": malformed}, "cannot read network"),
        ({"net": single_lane_net(tmp)}, "no multi-lane edge"),
        ({"overtakers": 400, "keepers": 400}, "do not fit"),
        ({"overtakers": 0, "keepers": 0, "background": 0}, "nothing to simulate"),
        ({"overtakers": -1}, ">= 0"),
        ({"policy": corrupt}, "not a behave checkpoint"),
        ({"policy": tmp / "nope.pt"}, "checkpoint not found"),
        ({"policy": policy_file(tmp, 65, "overtaking"), "keepers": 2, "overtakers": 0}, "overtaking policy"),
        ({"fcd": file_in_the_way / "fcd.xml"}, "cannot create output directory"),
        ({"fcd": tmp / "fcd.txt"}, "must end in"),
        ({"precision": "float16"}, "unknown precision"),
    ]


@pytest.mark.sumo
def test_bad_input_gives_a_clear_error_and_no_output(tmp_path, multi_policy):
    for overrides, message in bad_inputs(tmp_path, multi_policy):
        fcd = overrides.pop("fcd", tmp_path / "out" / "fcd.xml")
        config = PopulateConfig(**{"policy": multi_policy, "duration": 5.0, "fcd": fcd, **overrides})
        with pytest.raises(BehaveError, match=message):
            populate(config)
        assert not fcd.exists()
        out = tmp_path / "out"
        assert not out.exists() or not list(out.iterdir())


@pytest.mark.sumo
def test_cli_errors_are_one_line_on_stderr_without_traceback(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "behaviors.cli", "populate", "--net", str(tmp_path / "missing.net.xml"),
         "--fcd", str(tmp_path / "f.xml")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"behave: error: network file not found: {tmp_path}/missing.net.xml"
    ]
    assert not (tmp_path / "f.xml").exists()


def test_bundled_policies_load_and_match_their_behaviours():
    for name, obs_dim in (("lanekeeping", 65), ("overtaking", 65), ("multi", 66)):
        meta = load_checkpoint(PRETRAINED / f"{name}.pt").meta
        assert meta["obs_dim"] == obs_dim and meta["behaviour"] == name
    traffic = load_checkpoint(PRETRAINED / "traffic.pt").meta  # populate's default
    assert traffic["obs_dim"] == TRAFFIC_OBS_SIZE and traffic["behaviour"] == "multi"
    assert traffic["observation_layout"].startswith("traffic:")
    styled = load_checkpoint(PRETRAINED / "styled.pt").meta
    assert styled["driver"] == "styled" and styled["obs_dim"] == STYLED_OBS_SIZE
    assert (PRETRAINED / "MODEL_CARD.md").read_text().count("\n## ") == 5


@pytest.mark.sumo
def test_own_routes_file_brings_sumo_traffic(tmp_path, multi_policy):
    routes = tmp_path / "demand.rou.xml"
    edges = " ".join(f"e{i}" for i in range(10))
    routes.write_text(
        f'<routes><route id="r" edges="{edges}"/>'
        '<flow id="f" type="behave_background" route="r" begin="0" end="20" number="8" departLane="random"/>'
        "</routes>"
    )
    fcd = tmp_path / "fcd.xml"
    populate(PopulateConfig(policy=multi_policy, overtakers=1, keepers=1, background=0, routes=routes,
                            duration=20.0, fcd=fcd))  # fmt: skip
    ids = set(read_fcd(fcd)["id"])
    assert sum(i.startswith("f.") for i in ids) == 8
    assert {"keeper_0", "overtaker_0"} <= ids


def highway_observations(steps: int = 40) -> np.ndarray:
    """Real observations: the bundled highway with 30 agents of the bundled policy, stacked over steps."""
    config = PopulateConfig(overtakers=15, keepers=15, background=10, duration=steps * 0.2,
                            fcd=Path("unused.xml"), precision="float32")  # fmt: skip
    population = Population(config)
    seen = []
    with tempfile.TemporaryDirectory() as tmp:
        population.start(partial_path(Path(tmp) / "fcd.xml"))
        try:
            for _ in range(steps):
                population.step()
                if len(population.fleet):
                    seen.append(population.fleet.sense(population.sim, population.vehicles, True))
        finally:
            population.close()
    return np.concatenate(seen)


@pytest.mark.sumo
def test_bfloat16_actions_stay_close_to_float32():
    """Measured on 1,100 real observations: steer differs by 0.003 (median), 0.03 (99%), 0.06 (max)."""
    obs = highway_observations()
    assert len(obs) >= 1000
    exact = populate_policy(PopulateConfig(precision="float32")).act
    half = populate_policy(PopulateConfig(precision="bfloat16")).act
    diff = np.abs(half(obs, None) - exact(obs, None))
    assert np.median(diff) < 0.005 and np.quantile(diff, 0.99) < 0.05 and diff.max() < 0.1
    assert diff.max() > 0  # it did run in bfloat16


def test_auto_precision_uses_bfloat16_only_for_big_fleets():
    assert not use_bfloat16("auto", BFLOAT16_MIN_BATCH - 1)
    assert not use_bfloat16("float32", 10_000)
    assert use_bfloat16("bfloat16", 1)


@pytest.mark.sumo
def test_the_shield_removes_most_crashes_on_a_crowded_highway(tmp_path):
    """The paper's multi policy keeps full throttle behind slower cars and drifts sideways: without
    the shield it crashes on a crowded road (the traffic driver's rules leave the shield little to do)."""
    policy = DEFAULT_POLICY.parent / "multi.pt"
    base = {"policy": policy, "overtakers": 60, "keepers": 60, "background": 60, "duration": 40.0,
            "keep_count": True, "seed": 3}  # fmt: skip
    bare = populate(PopulateConfig(**base, fcd=tmp_path / "bare.xml", shield=False))
    shielded = populate(PopulateConfig(**base, fcd=tmp_path / "shielded.xml"))
    assert bare.side_cuts == bare.speed_cuts == 0
    assert shielded.side_cuts > 0 and shielded.speed_cuts > 0
    assert bare.collisions >= 4 and shielded.collisions <= bare.collisions / 4


def steering_policy(tmp: Path, steer: float) -> Path:
    """A lane-keeping policy that ignores what it sees: always `steer`, half throttle, no brake."""
    path = policy_file(tmp, 65, "lanekeeping")
    actor = Actor(65, (32, 32))
    with torch.no_grad():
        actor.head.weight.zero_()
        actor.head.bias.copy_(torch.tensor([np.arctanh(steer), 0.0, -10.0]))
    save_checkpoint(path, actor_state=actor.state_dict(), meta=load_checkpoint(path).meta)
    return path


@pytest.mark.sumo
def test_every_collision_and_off_track_is_explained_in_the_agents_table(tmp_path):
    """Keepers that all steer left, unshielded, among as many of SUMO's cars (a crowded road: populate
    puts no car down beside another): those in the left lane leave the road by its left edge, some
    of the others side-swipe the cars in the lane beside them."""
    fcd = tmp_path / "fcd.xml"
    summary = populate(PopulateConfig(policy=steering_policy(tmp_path, 0.3), overtakers=0, keepers=60,
                                      background=60, duration=8.0, shield=False, fcd=fcd))  # fmt: skip
    table = pd.read_csv(tmp_path / "fcd.agents.csv", dtype={"incident_other": str})
    assert tuple(table.columns) == columns("populate")  # one schema, incidents or not
    crashed, left = table[table.end_reason == "collision"], table[table.end_reason == "off_track"]
    assert (len(crashed), len(left)) == (summary.collisions, summary.off_tracks)
    assert len(crashed) >= 1 and len(left) >= 1
    lost = pd.concat([crashed, left])
    assert lost["incident_lane"].str.match(r"e\d+_\d$").all()
    assert lost["incident_speed_mps"].gt(0).all() and lost["incident_lane_offset_m"].notna().all()
    assert (left["incident_side"] == "left").all() and left["incident_other"].isna().all()
    assert left["incident_lateral_gap_m"].between(-1.0, 1.0).all()  # to the road's left edge
    assert crashed["incident_other"].isin(set(read_fcd(fcd)["id"])).all()
    assert crashed["incident_other_speed_mps"].gt(0).all()
    beside = crashed["incident_side"].isin(["left", "right"])
    assert crashed["incident_lateral_gap_m"].notna().eq(beside).all()
    assert crashed["incident_headway_s"].notna().eq(~beside).all()
    quiet = table[~table.end_reason.isin(["collision", "off_track"])]
    assert quiet[list(INCIDENT_COLUMNS)].isna().all().all()


@pytest.mark.sumo
def test_no_agent_is_put_down_in_a_lane_that_ends_before_it_could_merge_out(tmp_path):
    """A lane drop (4 -> 3 lanes after 800 m): no car, learned or SUMO's, starts in the right lane's
    last INSERT_LANE_RUN metres (one put at the end of a dropping lane stood there and the lane queued),
    and no lane keeper in the fast-most lane (it would only move out of it). Near the road's start,
    where SUMO puts cars down, no agent changes lanes (LaneDriving.entry_clearance)."""
    chain = Chain()
    chain.way("wide", 4, [(800.0, 0.0)], 3.75)
    chain.way("narrow", 3, [(800.0, 0.0)], 3.75)
    write_plain(tmp_path, "drop", chain.ways, [("wide", "narrow", i + 1, i) for i in range(3)])
    net = run_netconvert(tmp_path, "drop", lefthand=False)
    fcd = tmp_path / "fcd.parquet"
    summary = populate(
        PopulateConfig(net=net, overtakers=30, keepers=30, background=60, duration=40.0, fcd=fcd, seed=0)
    )
    by_car = read_fcd(fcd).sort_values("time").groupby("id")
    everyone = by_car.first()
    first = everyone[everyone.index.isin(pd.read_csv(agents_path(fcd))["id"])]  # withdrawn: not in the table
    stayed = everyone[by_car.size() > 1]  # a car withdrawn leaves one row, of the step SUMO placed it
    theirs = stayed[stayed.index.str.startswith("background_") & (stayed["lane"] == "wide_0")]
    assert len(theirs) and (theirs["pos"] <= 800.0 - INSERT_LANE_RUN).all(), theirs[["pos", "speed"]]
    assert len(first) >= 40 and summary.insert_retries > 0
    dropping = first[first["lane"] == "wide_0"]
    trace = read_fcd(fcd).sort_values(["id", "time"])
    agent_rows = trace[trace["id"].isin(first.index)]
    crossed = (agent_rows["lane"] != agent_rows.groupby("id")["lane"].shift()) & agent_rows["id"].eq(
        agent_rows["id"].shift()
    )
    on_wide = agent_rows[crossed & agent_rows["lane"].str.startswith("wide_")]
    assert (on_wide["pos"] >= LaneDriving().entry_clearance).all(), on_wide[["id", "lane", "pos"]]
    assert len(dropping) and (dropping["pos"] <= 800.0 - INSERT_LANE_RUN).all(), dropping[["pos", "speed"]]
    keepers_first = first[first.index.str.startswith("keeper_")]
    assert len(keepers_first) and not keepers_first["lane"].isin(["wide_3", "narrow_2"]).any()
    assert (first.loc[first.index.str.startswith("overtaker_"), "lane"] == "wide_3").any()
    left, best = np.array([399.0, 399.0, 900.0]), np.array([2000.0, 405.0, 2000.0])
    # 399 m left in a lane that ends while another goes on; the route ends there; room to merge out
    assert lane_runs_out(left, best, np.zeros(3), np.zeros(3)).tolist() == [True, False, False]
