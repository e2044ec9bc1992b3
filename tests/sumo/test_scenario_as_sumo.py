"""A user's scenario runs as `sumo -c` runs it: its step, end and lateral
resolution hold, or one line says what behave changed and why; `--sumocfg` without `--share` is
refused; the summary counts the scenario's vehicles; a sweep writes every output the scenario names
into each run's own folder and never beside the scenario."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd
import pytest

from behaviors.report.fcd_read import read_fcd
from behaviors.sumo.scenario_config import read_sumocfg
from behaviors.sumo.sumo_home import sumo_binary
from tests.sumo.test_own_scenario import netconvert

pytestmark = pytest.mark.sumo  # every test builds a net with netconvert and runs SUMO

SEED = 3


def road_scenario(folder: Path, *, time: str = '<end value="40"/>', options: str = "") -> Path:
    """A 3-lane 800 m road fed by passenger cars for 30 s, an induction loop per lane (one output in a
    sub-folder, one beside the additional file), and a sumocfg with `time` and `options` of its own."""
    folder.mkdir(parents=True, exist_ok=True)
    netconvert(folder, "road", '<node id="a" x="0" y="0"/><node id="b" x="800" y="0"/>',
               '<edge id="r" from="a" to="b" numLanes="3" speed="30"/>')  # fmt: skip
    (folder / "demand.rou.xml").write_text(
        '<routes><vType id="car" vClass="passenger"/>'
        '<flow id="f" type="car" begin="0" end="30" vehsPerHour="3000" departLane="random" departSpeed="max">'
        '<route edges="r"/></flow></routes>'
    )
    (folder / "det").mkdir(exist_ok=True)
    (folder / "loops.add.xml").write_text(
        "<additional>"
        '<inductionLoop id="l0" lane="r_0" pos="400" period="10" file="det/loop0.xml"/>'
        '<inductionLoop id="l1" lane="r_1" pos="400" period="10" file="loop1.xml"/>'
        "</additional>"
    )
    cfg = folder / "road.sumocfg"
    cfg.write_text(
        '<configuration><input><net-file value="road.net.xml"/><route-files value="demand.rou.xml"/>'
        f'<additional-files value="loops.add.xml"/></input><time>{time}</time>{options}</configuration>'
    )
    return cfg


OUTPUTS = '<output><summary-output value="summary.xml"/><tripinfo-output value="det/trips.xml"/></output>'
"""The scenario's own outputs in its sumocfg (one in a sub-folder)."""


def behave(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "behaviors.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=600,
        env=os.environ | {"COLUMNS": "200"},
    )  # fmt: skip


def notes(result: subprocess.CompletedProcess) -> list[str]:
    return [line for line in result.stderr.splitlines() if line.startswith("note: ")]


def one_error(result: subprocess.CompletedProcess) -> str:
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert lines[0].startswith("behave: error: ")
    return lines[0]


def listing(folder: Path) -> dict[str, int]:
    """Every file and folder below `folder` with its mtime (ns)."""
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in sorted(folder.rglob("*"))}


def test_share_0_is_sumo_c_with_the_same_options_and_the_summary_counts_its_vehicles(tmp_path):
    """No step length and no lateral resolution in the sumocfg: SUMO runs it at 1 s without sublanes,
    and so does `behave populate --share 0` (it ran at 0.2 s with 0.8 m sublanes and said nothing)."""
    cfg = road_scenario(tmp_path / "scenario")
    plain = tmp_path / "plain.xml"
    subprocess.run(
        [sumo_binary("sumo"), "-c", str(cfg), "--seed", str(SEED), "--fcd-output", str(plain),
         "--no-step-log"],
        check=True, capture_output=True,
    )  # fmt: skip
    fcd = tmp_path / "ours.xml"
    result = behave("populate", "--sumocfg", str(cfg), "--share", "0", "--seed", str(SEED), "--fcd", str(fcd),
                    "--json")  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert notes(result) == []  # nothing changed, nothing to say
    key = ["id", "time"]
    ours = read_fcd(fcd).sort_values(key).reset_index(drop=True)
    theirs = read_fcd(plain).sort_values(key).reset_index(drop=True)
    assert len(theirs) > 500 and theirs["time"].diff().max() == pytest.approx(1.0)
    columns = [*key, "x", "y", "speed", "lane"]
    pd.testing.assert_frame_equal(ours[columns], theirs[columns])
    summary = json.loads(result.stdout)
    assert summary["vehicles"] == theirs["id"].nunique() > 20  # was 0: only behave's own cars counted
    assert summary["scenario_passenger_cars"] == summary["vehicles"] and summary["of_them_agents"] == 0


def test_without_agents_any_step_sumo_takes_holds(tmp_path):
    """A 2 s sumocfg was refused (populate's steps went to 1 s) though no policy drives in it."""
    from behaviors.run.populate import populate
    from behaviors.run.populate_config import config_from

    cfg = road_scenario(tmp_path / "scenario", time='<end value="40"/><step-length value="2"/>')
    fcd = tmp_path / "o.xml"
    populate(config_from(cfg, share=0.0, fcd=fcd))
    assert read_fcd(fcd)["time"].diff().max() == pytest.approx(2.0)


def test_the_summary_counts_the_scenarios_vehicles(tmp_path):
    """It said `vehicles 0` for a scenario's 1,000: only behave's own cars were counted."""
    from behaviors.run.populate import populate
    from behaviors.run.populate_config import config_from

    cfg = road_scenario(tmp_path / "scenario", time='<end value="20"/>')
    fcd = tmp_path / "o.xml"
    summary = populate(config_from(cfg, share=0.5, fcd=fcd, seed=SEED))
    assert summary.vehicles == read_fcd(fcd)["id"].nunique() > 10
    assert summary.vehicles == summary.scenario_cars > summary.scenario_agents > 0


def test_agents_run_at_their_policys_step_and_with_sublanes_each_said_in_one_line(tmp_path):
    """A sumocfg at 1 s ran the policy (trained at 0.2 s) at 1 s without a word."""
    options = '<processing><lateral-resolution value="0.4"/></processing>'
    cfg = road_scenario(tmp_path / "one", time='<end value="20"/><step-length value="1"/>', options=options)
    fcd = tmp_path / "one.csv"
    result = behave("populate", "--sumocfg", str(cfg), "--share", "0.5", "--fcd", str(fcd))
    assert result.returncode == 0, result.stderr
    assert notes(result) == [
        "note: road.sumocfg runs at 0.2 s steps, not the 1 s it sets: the policy was trained at 0.2 s "
        "steps and drives at no other"
    ]  # its own lateral resolution holds: no line
    assert read_fcd(fcd)["time"].diff().max() == pytest.approx(0.2)
    # none set: SUMO's 1 s and no sublanes, both changed and said
    cfg = road_scenario(tmp_path / "none", time='<end value="20"/>')
    result = behave("populate", "--sumocfg", str(cfg), "--share", "0.5", "--fcd", str(tmp_path / "none.csv"))
    assert result.returncode == 0, result.stderr
    said = notes(result)
    assert len(said) == 2 and "not the 1 s of SUMO's default (it sets no step-length)" in said[0]
    assert said[1].startswith("note: road.sumocfg runs with SUMO's sublane model (--lateral-resolution 0.8)")
    # asked for in so many words: refused, one line, before anything runs
    line = one_error(behave("populate", "--sumocfg", str(cfg), "--share", "0.5", "--step-length", "1",
                            "--fcd", str(tmp_path / "refused.csv")))  # fmt: skip
    assert "traffic was trained at 0.2 s steps and drives at no other: --step-length 1" in line
    assert not (tmp_path / "refused.csv").exists()


def test_a_duration_past_the_sumocfgs_end_is_refused_and_no_end_is_said(tmp_path):
    cfg = road_scenario(tmp_path / "scenario", time='<begin value="10"/><end value="40"/>')
    fcd = tmp_path / "o.xml"
    line = one_error(behave("populate", "--sumocfg", str(cfg), "--share", "0", "--duration", "31",
                            "--fcd", str(fcd)))  # fmt: skip
    assert "--duration 31 runs past the end of road.sumocfg at 40 s (30 s after its begin)" in line
    assert "give --duration 30 or less" in line and not fcd.exists()
    result = behave("populate", "--sumocfg", str(cfg), "--share", "0", "--duration", "5", "--fcd", str(fcd))
    assert result.returncode == 0 and notes(result) == [], result.stderr  # shorter: a part of the run
    endless = road_scenario(tmp_path / "endless", time="")
    result = behave("populate", "--sumocfg", str(endless), "--share", "0", "--fcd", str(fcd), "-v")
    assert result.returncode == 0, result.stderr
    assert notes(result) == [
        "note: road.sumocfg sets no end: behave runs 180 s of it (--duration S for another length; SUMO "
        "would run until its last vehicle left)"
    ]


def test_sumocfg_without_share_is_refused_in_one_line(tmp_path):
    cfg = road_scenario(tmp_path / "scenario")
    line = one_error(behave("populate", "--sumocfg", str(cfg), "--fcd", str(tmp_path / "o.xml")))
    assert "--sumocfg needs --share F" in line and "--share 0: SUMO's cars alone" in line
    line = one_error(behave("sweep", "--sumocfg", str(cfg), "--out", str(tmp_path / "sweep")))
    assert "--sumocfg needs --share" in line and not (tmp_path / "sweep").exists()


def test_outputs_go_where_asked_with_their_places_kept_and_the_scenario_untouched(tmp_path):
    from behaviors.sumo.scenario_config import redirect_outputs

    cfg = road_scenario(tmp_path / "scenario", options=OUTPUTS)
    (tmp_path / "elsewhere").mkdir()
    add = cfg.parent / "loops.add.xml"
    add.write_text(add.read_text().replace("</additional>", f'<inductionLoop id="l2" lane="r_2" pos="400" '
                   f'period="10" file="{tmp_path / "elsewhere" / "far.xml"}"/></additional>'))  # fmt: skip
    options, additional = redirect_outputs(read_sumocfg(cfg), tmp_path / "run", tmp_path / "staging")
    assert options == ("--summary-output", str(tmp_path / "run" / "summary.xml"),
                       "--tripinfo-output", str(tmp_path / "run" / "det" / "trips.xml"))  # fmt: skip
    loops = {e.get("id"): e.get("file") for e in ET.parse(additional[0]).getroot()}
    run = tmp_path / "run"
    assert loops == {
        "l0": str(run / "det" / "loop0.xml"),
        "l1": str(run / "loop1.xml"),
        "l2": str(run / "far.xml"),
    }
    before = listing(cfg.parent)
    result = behave("populate", "--sumocfg", str(cfg), "--share", "0.5", "--outputs", str(tmp_path / "run"),
                    "--fcd", str(tmp_path / "o.xml"))  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert listing(cfg.parent) == before and not (tmp_path / "elsewhere" / "far.xml").exists()
    written = sorted(str(p.relative_to(tmp_path / "run")) for p in (tmp_path / "run").rglob("*.xml"))
    assert written == ["det/loop0.xml", "det/trips.xml", "far.xml", "loop1.xml", "summary.xml"]


def test_a_sweep_writes_each_runs_outputs_into_its_own_folder_and_never_beside_the_scenario(tmp_path):
    """Parallel runs all wrote the same files beside the sumocfg: a detector's file ended in "junk
    after document element"."""
    pytest.importorskip("ray", reason="ray is not installed (the distributed extra)")
    cfg = road_scenario(tmp_path / "scenario", options=OUTPUTS)
    before = listing(cfg.parent)
    out = tmp_path / "sweep"
    result = behave("sweep", "--sumocfg", str(cfg), "--share", "0,0.5", "--seeds", "0,1", "--workers", "2",
                    "--out", str(out))  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert listing(cfg.parent) == before  # not a file written, created or touched
    table = pd.read_csv(out / "sweep.csv")
    assert list(table["status"]) == ["ok"] * 4
    assert (table["vehicles"] == table["scenario_passenger_cars"]).all() and (table["vehicles"] > 20).all()
    assert (table["step_length_s"] == 0.2).all()  # share 0 runs as the runs with agents do: they compare
    assert "sweep: note: road.sumocfg's runs without agents run as those with agents do" in result.stderr
    expected = ["det/loop0.xml", "det/trips.xml", "loop1.xml", "summary.xml"]
    for run in table["id"]:
        folder = out / "outputs" / run
        assert sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()) == expected
        for name in expected:
            ET.parse(folder / name)  # whole, well-formed XML
        trips = ET.parse(folder / "det" / "trips.xml").getroot()
        assert len(trips) > 3  # cars that crossed the 800 m in the 40 s
    seeds = [ET.parse(out / "outputs" / run / "det" / "trips.xml").getroot() for run in table["id"]]
    assert len({ET.tostring(root) for root in seeds}) == 4  # each run's own, none another's
