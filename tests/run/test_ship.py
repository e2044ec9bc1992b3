"""What a sweep sends a cluster's worker with each run (behaviors/run/ship.py): a sumocfg and every file
it reads, at places that keep its relative names valid, its absolute names rewritten; a policy's
checkpoint under the label it has here. No SUMO, no Ray: the files are only packed and unpacked."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from behaviors.errors import BehaveError
from behaviors.learn.policy import resolve
from behaviors.run.ship import pack_policy, pack_scenario, unpack
from behaviors.sumo.scenario_config import read_sumocfg


def scenario(root: Path) -> Path:
    """A sumocfg naming its net out of its folder (../), its routes by an absolute path, an additional
    that names a file beside it, an output by an absolute path within its folder and one outside."""
    (root / "shared").mkdir(parents=True)
    (root / "elsewhere").mkdir()
    cfg = root / "scenario" / "cfg"
    cfg.mkdir(parents=True)
    (root / "shared" / "road.net.xml").write_text("<net/>")
    (root / "elsewhere" / "cars.rou.xml").write_text("<routes/>")
    (cfg / "programs.xml").write_text("<additional/>")
    (cfg / "det.add.xml").write_text(
        '<additional><include href="programs.xml"/>'
        '<inductionLoop id="l" lane="e_0" pos="5" period="10" file="out/loop.xml"/></additional>'
    )
    sumocfg = cfg / "run.sumocfg"
    sumocfg.write_text(
        '<configuration><input><net-file value="../../shared/road.net.xml"/>'
        f'<route-files value="{root / "elsewhere" / "cars.rou.xml"}"/>'
        '<additional-files value="det.add.xml"/></input>'
        f'<output><summary-output value="{cfg / "out" / "summary.xml"}"/>'
        '<tripinfo-output value="/var/trips.xml"/></output></configuration>'
    )
    return sumocfg


def test_a_sumocfg_travels_with_every_file_it_reads_and_reads_them_unpacked(tmp_path: Path) -> None:
    sumocfg = scenario(tmp_path / "here")
    package = pack_scenario(str(sumocfg), "sumocfg")
    assert package.entry == "scenario/cfg/run.sumocfg"
    assert sorted(name for name, _ in package.files) == [
        "elsewhere/cars.rou.xml", "scenario/cfg/det.add.xml", "scenario/cfg/programs.xml",
        "scenario/cfg/run.sumocfg", "shared/road.net.xml",
    ]  # fmt: skip
    shutil.rmtree(tmp_path / "here")  # the worker's disk: only what was sent
    unpacked = unpack(package, tmp_path / "worker")
    config = read_sumocfg(unpacked)  # it checks that each file it names is there
    assert config.net == unpacked.parent / "../../shared/road.net.xml"
    assert config.routes == (unpacked.parent / "../../elsewhere/cars.rou.xml",)
    options = dict(config.options)
    assert options["summary-output"] == "out/summary.xml"  # within its folder: the same place in the run's
    assert options["tripinfo-output"] == "/var/trips.xml"  # outside it: by its name, as here
    assert (unpacked.parent / "programs.xml").is_file()


def test_a_net_travels_alone_and_an_unreadable_file_is_one_line(tmp_path: Path) -> None:
    net = tmp_path / "a.net.xml"
    net.write_text("<net/>")
    assert pack_scenario(str(net), "net").files == (("a.net.xml", b"<net/>"),)
    with pytest.raises(BehaveError, match=r"^cannot read .*gone.net.xml to send it to the cluster: "):
        pack_scenario(str(tmp_path / "gone.net.xml"), "net")


def test_a_policy_travels_under_its_label_and_a_bundled_one_by_name(tmp_path: Path) -> None:
    assert pack_policy("traffic") is None  # every node has behave's bundled policies
    checkpoint, _ = resolve("traffic")
    run = tmp_path / "my-run"
    (run / "checkpoints").mkdir(parents=True)
    shutil.copy(checkpoint, run / "checkpoints" / "final.pt")
    shutil.copy(checkpoint, tmp_path / "mine.pt")
    for spec, label in ((run, "my-run"), (tmp_path / "mine.pt", "mine")):
        package = pack_policy(str(spec))
        assert package is not None and len(package.files) == 1
        unpacked = unpack(package, tmp_path / "worker" / label)
        found, name = resolve(unpacked)
        assert name == label and found.read_bytes() == checkpoint.read_bytes()
