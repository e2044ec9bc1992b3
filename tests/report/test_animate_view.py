"""`behave animate` follows the action on a long road, stops with the vehicle it follows, and draws
vehicles at their vType's size and class. Hand-written FCDs: no SUMO run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import behave
from PIL import Image

from behaviors.report.animate import follow_the_action
from behaviors.sumo.vtypes import VehicleKind, files_named_by, kind_of, read_vtypes

BROWN = np.array([0x8C, 0x56, 0x4B])  # tab:brown, SUMO's lorries
GREY = np.array([0x7F, 0x7F, 0x7F])  # tab:gray, SUMO's cars
BLUE = np.array([0x1F, 0x77, 0xB4])  # tab:blue, the keepers


def write_fcd(path: Path, cars: dict[str, tuple[str, float, float, float, float]], until: float) -> Path:
    """One record per second to `until` for each car (vType, x at t=0, speed, first t, last t),
    driving east on y = 0; `header` names the scenario the way behave populate does."""
    steps = []
    for t in np.arange(0.0, until + 0.5, 1.0):
        rows = "".join(
            f'<vehicle id="{vid}" x="{x0 + v * t:.2f}" y="0.00" angle="90.00" type="{vtype}" speed="{v:.2f}" '
            f'pos="{x0 + v * t:.2f}" lane="e_0" posLat="0.00"/>'
            for vid, (vtype, x0, v, first, last) in cars.items()
            if first <= t <= last
        )
        steps.append(f'<timestep time="{t:.2f}">{rows}</timestep>')
    header = "<!-- behave populate: net=elsewhere.net.xml sumocfg=ramp.sumocfg share=0.5 -->\n"
    path.write_text(
        f'<?xml version="1.0" encoding="UTF-8"?>\n{header}<fcd-export>{"".join(steps)}</fcd-export>\n'
    )
    return path


def scenario(folder: Path) -> Path:
    """A sumocfg whose routes define a 16.5 m lorry (vClass truck) and a 9 m van with no vClass."""
    (folder / "r.rou.xml").write_text(
        '<routes><vType id="lorry" vClass="truck" length="16.5"/><vType id="van" length="9"/></routes>'
    )
    (folder / "mine.net.xml").write_text("<net/>")
    cfg = folder / "ramp.sumocfg"
    cfg.write_text('<configuration><input><net-file value="mine.net.xml"/><route-files value="r.rou.xml"/>'
                   "</input></configuration>")  # fmt: skip
    return cfg


def frames(path: Path) -> list[np.ndarray]:
    with Image.open(path) as image:
        out = []
        for k in range(image.n_frames):
            image.seek(k)
            out.append(np.asarray(image.convert("RGB")).astype(int))
        return out


def extent(frame: np.ndarray, colour: np.ndarray) -> int:
    """The longest run of `colour` along a row about the road (y = 0 is drawn at 40-45% of the
    height; the legend lies above or below): a box's length in pixels, its outline left out."""
    h = frame.shape[0]
    band = np.abs(frame[int(0.3 * h) : int(0.6 * h)] - colour).sum(axis=2) < 40
    longest = 0
    for row in band:
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row.astype(int), [0]])))
        longest = max(longest, int((edges[1::2] - edges[::2]).max(initial=0)))
    return longest


# sizes and classes ------------------------------------------------------------------------------


def test_vtypes_are_read_from_the_scenario_and_fall_back_on_their_class(tmp_path: Path) -> None:
    cfg = scenario(tmp_path)
    known = read_vtypes([tmp_path / "r.rou.xml", tmp_path / "missing.rou.xml"])
    assert known == {"lorry": VehicleKind(16.5, 2.4, "truck"), "van": VehicleKind(9.0, 1.8, "passenger")}
    assert kind_of("lorry@v3", known).length == 16.5  # SUMO's copy of a type for one vehicle
    assert kind_of("hgv_40t", {}) == VehicleKind(7.1, 2.4, "truck")  # named, defined nowhere
    assert kind_of("DEFAULT_BIKETYPE", {}).vclass == "bicycle"
    assert kind_of("behave_background", {}) == VehicleKind(5.0, 1.8, "passenger")
    fcd = write_fcd(tmp_path / "fcd.xml", {"a": ("lorry", 0.0, 10.0, 0.0, 1.0)}, 1.0)
    assert files_named_by(fcd) == [tmp_path / "r.rou.xml"]  # behave's header names the sumocfg
    assert cfg.is_file()


def test_a_lorry_is_drawn_at_its_length_and_as_a_lorry(tmp_path: Path) -> None:
    """A 16.5 m lorry ahead of a 5 m car in an 80 m view: its box is 3.3 times as long and brown (a
    SUMO lorry); the sumocfg is found from the FCD's header."""
    scenario(tmp_path)
    fcd = write_fcd(tmp_path / "fcd.xml", {"car": ("behave_background", 30.0, 10.0, 0.0, 2.0),
                                           "lorry": ("lorry", 55.0, 10.0, 0.0, 2.0)}, 2.0)  # fmt: skip
    out = tmp_path / "a.gif"
    done = behave("animate", str(fcd), "--out", str(out), "--follow", "car", "--window", "80", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    frame = frames(out)[1]
    lorry, car = extent(frame, BROWN), extent(frame, GREY)
    assert car > 20 and lorry / car == pytest.approx(16.5 / 5.0, rel=0.15), (lorry, car)


# the view ---------------------------------------------------------------------------------------


def test_a_long_road_is_followed_not_drawn_as_specks(tmp_path: Path) -> None:
    """A 4.5 km road at 800 px: the whole view made a car under 1 px long; now the view follows the
    learned car (drawn 10+ px long) and a note says so; --whole still draws the whole road."""
    cars = {
        "keeper_0": ("behave_keeper", 100.0, 30.0, 0.0, 10.0),
        "far": ("behave_background", 4400.0, 1.0, 0.0, 10.0),
    }
    fcd = write_fcd(tmp_path / "fcd.xml", cars, 10.0)
    done = behave("animate", str(fcd), "--out", str(tmp_path / "a.gif"), "--every", "5")
    assert done.returncode == 0, done.stderr
    assert "the view follows the learned cars" in done.stderr and "--whole" in done.stderr
    shown = frames(tmp_path / "a.gif")
    assert len(shown) == 3 and shown[0].shape[:2] == (240, 800)
    assert all(extent(frame, BLUE) >= 10 for frame in shown)
    done = behave("animate", str(fcd), "--out", str(tmp_path / "w.gif"), "--every", "5", "--whole")
    assert done.returncode == 0 and "follows" not in done.stderr
    assert extent(frames(tmp_path / "w.gif")[0], BLUE) <= 3


def test_follow_draws_while_the_vehicle_is_there_and_says_so(tmp_path: Path) -> None:
    """The car leaves at 3 s of a 60 s FCD: 4 frames, not 61 of an empty road."""
    cars = {
        "early": ("behave_keeper", 0.0, 20.0, 0.0, 3.0),
        "late": ("behave_background", 0.0, 5.0, 0.0, 60.0),
    }
    fcd = write_fcd(tmp_path / "fcd.xml", cars, 60.0)
    done = behave("animate", str(fcd), "--out", str(tmp_path / "f.gif"), "--follow", "early")
    assert done.returncode == 0, done.stderr
    assert "4 frames" in done.stdout and len(frames(tmp_path / "f.gif")) == 4
    assert "following early: frames from t = 0 to 3 s, while it is in the FCD" in done.stderr


def test_the_followed_car_is_handed_on_when_it_leaves() -> None:
    """Steps 0-2: a (learned, leaving after step 1), b (learned, staying), c (SUMO's)."""
    ids = np.array(["a", "b", "c", "a", "b", "c", "b", "c"], dtype=object)
    xy = np.arange(16, dtype=float).reshape(8, 2)
    starts, ends = np.array([0, 3, 6]), np.array([3, 6, 8])
    learned = np.array([True, True, False, True, True, False, True, False])
    centres, followed = follow_the_action(ids, xy, starts, ends, np.array([0, 1, 2]), learned)
    assert followed == ["b", "b", "b"]  # the learned car that stays longest
    np.testing.assert_array_equal(centres, xy[[1, 4, 6]])
    _, followed = follow_the_action(ids, xy, starts, ends, np.array([0, 1, 2]), np.zeros(8, bool))
    assert followed == ["b", "b", "b"] or followed == ["c", "c", "c"]
