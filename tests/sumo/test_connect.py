"""`behave populate --connect`: behave joins a SUMO another program runs, as one more TraCI client.
The bar: `sumo --remote-port P --num-clients 2`, a user's TraCI script stepping it to
the end, and behave beside them; all three end cleanly, SUMO's own FCD holds the learned vehicles,
nobody is lost. And leaving early (Ctrl-C, --duration) hands the agents back and leaves SUMO running."""

from __future__ import annotations

import json
import shutil
import signal
import socket
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

import pytest
from helpers import BEHAVE, behave

from behaviors.errors import BehaveError
from behaviors.sumo.sumo_home import sumo_binary
from behaviors.sumo.traci_connection import Address, parse_address, sumo_seconds

AGENT_TYPES = {"behave_keeper", "behave_overtaker"}
USER_SCRIPT = """
import sys, time, traci
import traci.constants as tc
port, log, pause, subscribe = int(sys.argv[1]), sys.argv[2], float(sys.argv[3]), sys.argv[4] == "1"
traci.init(port)
traci.setOrder(1)
if subscribe:  # subscriptions of its own, which SUMO shares with every client
    traci.edge.subscribe("e1", [tc.LAST_STEP_VEHICLE_NUMBER])
    traci.simulation.subscribe([tc.VAR_TIME, tc.VAR_LOADED_VEHICLES_NUMBER])
steps = 0
while traci.simulation.getMinExpectedNumber() > 0:
    traci.simulationStep()
    steps += 1
    for vid in traci.simulation.getDepartedIDList() if subscribe else ():
        traci.vehicle.subscribe(vid, [tc.VAR_ANGLE, tc.VAR_ROAD_ID])
        if vid == "car.2":
            traci.vehicle.subscribeContext(vid, tc.CMD_GET_VEHICLE_VARIABLE, 30.0, [tc.VAR_SPEED])
    if subscribe:
        assert traci.edge.getSubscriptionResults("e1")[tc.LAST_STEP_VEHICLE_NUMBER] >= 0
    if steps % 10 == 0:
        open(log, "w").write(str(steps))
    time.sleep(pause)
open(log, "w").write(f"done {steps} {traci.simulation.getTime():g}")
traci.close()
"""
"""A user's TraCI script, the simulation's owner: order 1, steps until no vehicle is left, then closes;
with `subscribe`, subscriptions of its own (a vehicle's, an edge's, a context)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return int(s.getsockname()[1])


def scenario(folder: Path, *, cars_per_hour: int = 3000, until: float = 20.0) -> Path:
    """A straight 3-lane 1 km road, passenger cars (and a lorry flow) departing for `until` s, and a
    sumocfg at the bundled policies' step with sublanes: what a user would start SUMO with."""
    from sumo_scenarios.build import build_straight

    build_straight(folder, name="road", length=1000.0, edge_length=250.0, lanes=3, lane_width=3.5,
                   description="connect test road")  # fmt: skip
    (folder / "demand.rou.xml").write_text(
        '<routes><vType id="car" vClass="passenger" sigma="0.5"/>'
        '<vType id="lorry" vClass="truck" length="12" maxSpeed="25"/>'
        '<route id="r" edges="e0 e1 e2 e3"/>'
        f'<flow id="car" type="car" route="r" begin="0" end="{until}" vehsPerHour="{cars_per_hour}" '
        'departLane="random" departSpeed="max"/>'
        f'<flow id="lorry" type="lorry" route="r" begin="0" end="{until}" vehsPerHour="300" departLane="0" '
        'departSpeed="max"/></routes>'
    )
    cfg = folder / "road.sumocfg"
    cfg.write_text(
        '<configuration><input><net-file value="road.net.xml"/><route-files value="demand.rou.xml"/></input>'
        '<time><begin value="0"/><step-length value="0.2"/></time>'
        '<processing><lateral-resolution value="0.8"/></processing></configuration>'
    )
    return cfg


def start_sumo(cfg: Path, port: int, clients: int, *, gui: bool = False) -> subprocess.Popen[str]:
    """SUMO as its owner starts it, waiting for `clients` TraCI clients, with its own outputs."""
    out = cfg.parent
    command = [
        sumo_binary("sumo-gui" if gui else "sumo"), "-c", str(cfg), "--remote-port", str(port),
        "--num-clients", str(clients), "--fcd-output", str(out / "fcd.xml"),
        "--statistic-output", str(out / "stats.xml"), "--tripinfo-output", str(out / "trips.xml"),
        "--no-step-log", "true",
    ]  # fmt: skip
    if gui:
        command = ["xvfb-run", "-a", *command, "--start", "true", "--quit-on-end", "true"]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def start_user_script(
    folder: Path, port: int, pause: float = 0.0, subscribe: bool = False
) -> subprocess.Popen[str]:
    script = folder / "owner.py"
    script.write_text(USER_SCRIPT)
    log = folder / "owner.log"
    return subprocess.Popen(
        [sys.executable, str(script), str(port), str(log), str(pause), str(int(subscribe))],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip


def finish(process: subprocess.Popen[str], timeout: float = 240) -> tuple[int, str]:
    try:
        out, _ = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        out, _ = process.communicate()
        pytest.fail(f"{process.args} did not end within {timeout} s: {out[-2000:]}")
    return process.returncode, out


def fcd_types(fcd: Path) -> dict[str, set[str]]:
    """Each vehicle's vTypes over SUMO's FCD."""
    types: dict[str, set[str]] = {}
    for _, elem in ET.iterparse(fcd):
        if elem.tag == "vehicle":
            types.setdefault(elem.get("id", ""), set()).add(elem.get("type", ""))
            elem.clear()
    return types


def last_types(fcd: Path) -> dict[str, str]:
    """Each vehicle's vType in the last step SUMO's FCD has it."""
    last: dict[str, str] = {}
    for _, elem in ET.iterparse(fcd):
        if elem.tag == "vehicle":
            last[elem.get("id", "")] = elem.get("type", "")
            elem.clear()
    return last


def nobody_lost(folder: Path) -> None:
    """SUMO's statistics: every vehicle loaded was inserted and arrived (tripinfo), none teleported,
    no collision."""
    stats = ET.parse(folder / "stats.xml").getroot()
    vehicles = stats.find("vehicles")
    teleports = stats.find("teleports")
    safety = stats.find("safety")
    assert vehicles is not None and teleports is not None and safety is not None
    assert vehicles.get("loaded") == vehicles.get("inserted")
    assert (vehicles.get("running"), vehicles.get("waiting")) == ("0", "0")
    assert teleports.get("total") == "0"
    assert safety.get("collisions") == "0"
    trips = ET.parse(folder / "trips.xml").getroot().findall("tripinfo")
    assert len(trips) == int(vehicles.get("loaded", -1))


@pytest.mark.sumo
def test_behave_joins_a_users_traci_script_and_all_three_end_cleanly(tmp_path):
    """The bar: SUMO for two clients, a user's script (order 1) stepping to the end, behave (order 2)
    driving half its passenger cars; SUMO's FCD shows them in behave's vTypes, nobody is lost."""
    cfg = scenario(tmp_path)
    port = free_port()
    sumo = start_sumo(cfg, port, clients=2)
    owner = start_user_script(tmp_path, port)
    table = tmp_path / "agents.csv"
    result = behave("populate", "--connect", f"localhost:{port}", "--share", "0.5", "--agents", str(table),
                    "--json", timeout=300)  # fmt: skip
    owner_code, owner_out = finish(owner)
    sumo_code, sumo_out = finish(sumo)
    assert result.returncode == 0, result.stderr
    assert owner_code == 0, owner_out
    assert sumo_code == 0, sumo_out
    summary = json.loads(result.stdout)
    assert summary["left_simulation"] == "simulation_over"
    assert (tmp_path / "owner.log").read_text().startswith("done")
    assert summary["collisions"] == summary["off_tracks"] == 0
    assert summary["of_them_agents"] > 3
    assert summary["left_to_sumo_not_car_sized"] == 0  # the lorries are trucks: never drawn
    # the last stderr line says how it ended, in one line
    assert result.stderr.strip().splitlines()[-1].startswith("behave: the simulation at localhost:")
    rows = table.read_text().splitlines()[1:]
    assert len(rows) == summary["of_them_agents"]
    assert Counter(r.split(",")[6] for r in rows) == {"arrived": len(rows)}
    # SUMO's own FCD holds the learned vehicles, in behave's vTypes, and only cars
    types = fcd_types(tmp_path / "fcd.xml")
    learned = {vid for vid, seen in types.items() if seen & AGENT_TYPES}
    assert learned == {r.split(",")[0] for r in rows}
    assert all(vid.startswith("car.") for vid in learned)
    assert any(not (seen & AGENT_TYPES) for vid, seen in types.items() if vid.startswith("car."))
    nobody_lost(tmp_path)


@pytest.mark.sumo
def test_ctrl_c_hands_the_agents_back_and_leaves_sumo_and_the_other_client_running(tmp_path):
    cfg = scenario(tmp_path, until=40.0)
    port = free_port()
    sumo = start_sumo(cfg, port, clients=2)
    owner = start_user_script(tmp_path, port, pause=0.01)
    table = tmp_path / "agents.csv"
    joined = subprocess.Popen([*BEHAVE, "populate", "--connect", f"localhost:{port}", "--share", "1",
                               "--agents", str(table), "--json"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    log = tmp_path / "owner.log"
    deadline = time.monotonic() + 200
    while not (log.exists() and log.read_text().isdigit() and int(log.read_text()) >= 60):
        assert time.monotonic() < deadline and joined.poll() is None, "the run did not get going"
        time.sleep(0.1)  # 60 steps in lockstep: behave is stepping, and cars are on the road
    joined.send_signal(signal.SIGINT)
    out, err = joined.communicate(timeout=120)
    assert joined.returncode == 130, err
    summary = json.loads(out)
    assert summary["left_simulation"] == "interrupted" and summary["agents_handed_back_to_sumo"] > 0
    last = err.strip().splitlines()[-1]
    assert last.startswith("behave: interrupted (Ctrl-C) at t=") and "SUMO runs on" in last
    owner_code, owner_out = finish(owner)
    sumo_code, sumo_out = finish(sumo)
    assert owner_code == 0 and log.read_text().startswith("done"), owner_out
    assert sumo_code == 0, sumo_out
    # the cars handed back (still driving when behave left) drive on in their own vType to the road's end
    rows = [row.split(",") for row in table.read_text().splitlines()[1:]]
    handed = {row[0] for row in rows if row[6] == "still_driving"}
    assert len(handed) == summary["agents_handed_back_to_sumo"]
    last = last_types(tmp_path / "fcd.xml")
    assert {last[vid] for vid in handed} == {"car"}
    assert any(fcd_types(tmp_path / "fcd.xml")[vid] == {"car", "behave_keeper"} for vid in handed)
    nobody_lost(tmp_path)


@pytest.mark.sumo
def test_duration_leaves_after_that_long_and_the_owner_runs_to_its_end(tmp_path):
    """Also: the owner's own subscriptions (SUMO shares every client's with all) disturb neither, and
    --leave-alone keeps behave off the vehicles it names."""
    cfg = scenario(tmp_path)
    port = free_port()
    sumo = start_sumo(cfg, port, clients=2)
    owner = start_user_script(tmp_path, port, subscribe=True)
    table = tmp_path / "agents.csv"
    result = behave("populate", "--connect", f"localhost:{port}", "--share", "0.5", "--duration", "10",
                    "--leave-alone", "car.1", "--agents", str(table), "--json", timeout=300)  # fmt: skip
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["left_simulation"] == "duration" and summary["simulated_s"] == pytest.approx(10.0)
    assert "SUMO runs on with the other clients" in result.stderr.strip().splitlines()[-1]
    owner_code, owner_out = finish(owner)
    assert owner_code == 0, owner_out
    assert finish(sumo)[0] == 0
    agents = [row.split(",")[0] for row in table.read_text().splitlines()[1:]]
    assert agents and not [vid for vid in agents if vid.startswith("car.1")]
    nobody_lost(tmp_path)


@pytest.mark.sumo
def test_sumo_killed_midway_ends_behave_with_one_line_and_its_table(tmp_path):
    cfg = scenario(tmp_path, until=60.0)
    port = free_port()
    sumo = start_sumo(cfg, port, clients=1)
    table = tmp_path / "agents.csv"
    joined = subprocess.Popen([*BEHAVE, "populate", "--connect", f"localhost:{port}", "--share", "0.5",
                               "--agents", str(table)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    time.sleep(1.0)
    deadline = time.monotonic() + 120
    while not (tmp_path / "fcd.xml").exists() or (tmp_path / "fcd.xml").stat().st_size < 20_000:
        assert time.monotonic() < deadline and joined.poll() is None, "the run did not get going"
        time.sleep(0.1)
    sumo.kill()
    _, err = joined.communicate(timeout=120)
    sumo.communicate()
    assert joined.returncode == 0, err
    assert err.strip().splitlines()[-1].startswith(f"behave: SUMO at localhost:{port} closed the connection")
    assert table.read_text().startswith("id,behaviour")


@pytest.mark.sumo
def test_batching_changes_nothing_sumo_sees(tmp_path, monkeypatch):
    """Batched subscriptions and messages give SUMO the same commands as traci's one call per message:
    SUMO's FCD is identical either way."""
    import behaviors.sumo.joined as joined
    from behaviors.run.populate import populate_joined
    from behaviors.run.populate_config import config_from

    traces = []
    for batch in (True, False):
        folder = tmp_path / f"batch{batch}"
        folder.mkdir()
        cfg = scenario(folder, until=10.0)
        port = free_port()
        sumo = start_sumo(cfg, port, clients=1)
        if not batch:
            monkeypatch.setattr(joined, "batches", lambda connection: False)
        config = config_from(None, connect=f"localhost:{port}", share=0.5, agents_csv=folder / "agents.csv")
        summary = populate_joined(config)
        assert finish(sumo)[0] == 0
        assert summary.scenario_agents > 2
        text = (folder / "fcd.xml").read_text()
        traces.append(text[text.index("<timestep") :])
        assert "behave_keeper" in traces[-1] and "behave_overtaker" in traces[-1]
    assert traces[0] == traces[1]


@pytest.mark.sumo
@pytest.mark.skipif(
    shutil.which("xvfb-run") is None, reason="xvfb-run not installed: no display for sumo-gui"
)
def test_behave_joins_sumo_gui(tmp_path):
    """Recipe (b): sumo-gui --remote-port P --start, behave its one client, stepping it to the end."""
    cfg = scenario(tmp_path)
    port = free_port()
    gui = start_sumo(cfg, port, clients=1, gui=True)
    result = behave("populate", "--connect", f"localhost:{port}", "--share", "0.5",
                    "--agents", str(tmp_path / "agents.csv"), "--json", timeout=300)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert finish(gui)[0] == 0
    assert any(seen & AGENT_TYPES for seen in fcd_types(tmp_path / "fcd.xml").values())
    nobody_lost(tmp_path)


def test_addresses_parse_and_bad_ones_are_refused():
    assert parse_address("localhost:8813") == Address("localhost", 8813)
    assert parse_address("[::1]:9000") == Address("::1", 9000)
    assert str(parse_address("10.0.0.2:1")) == "10.0.0.2:1"
    for bad in ("localhost", ":8813", "host:0", "host:70000", "host:port"):
        with pytest.raises(BehaveError, match="HOST:PORT"):
            parse_address(bad)


def test_sumo_time_options_read_in_seconds_and_clock_format():
    assert sumo_seconds("-1") == -1.0
    assert sumo_seconds("3600") == 3600.0
    assert sumo_seconds("01:00:30") == 3630.0
    assert sumo_seconds("nonsense") == -1.0


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"keepers": 2}, "--keepers, --overtakers, --lorries or --background does not apply"),
        ({"routes": Path(__file__)}, "--routes does not apply"),
        ({"geo": True}, "--geo does not apply"),
        ({"share": 0.0}, "give --share F > 0"),
        ({"order": 0}, "--order must be 1 or more"),
        ({"step_length": 0.5}, "drop --step-length"),
        ({"connect": None, "leave_alone": ("carla",)}, "--leave-alone names another client's vehicles"),
    ],
)
def test_what_a_joined_run_cannot_do_is_refused_before_joining(given, message):
    from behaviors.run.populate_config import config_from

    values = {"connect": "localhost:1", "share": 0.5, **given}
    with pytest.raises(BehaveError, match=message):
        config_from(None, **values).validate()


@pytest.mark.sumo  # the behave command (it refuses before starting SUMO, but loads torch)
def test_cli_refusals_are_one_line_before_joining(tmp_path):
    for args, message in (
        (["--connect", "localhost:1", "--share", "0.5", "--fcd", "x.xml"], "writes no FCD of its own"),
        (["--connect", "nohost", "--share", "0.5"], "HOST:PORT"),
        (["--share", "0.5", "--order", "3"], "--order goes with --connect"),
    ):
        result = behave("populate", *args, cwd=tmp_path)
        assert result.returncode == 2, result.stderr
        assert result.stderr.strip().splitlines() == [
            f"behave: error: {result.stderr.split('error: ')[1].strip()}"
        ]
        assert message in result.stderr
