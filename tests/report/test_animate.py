"""`behave animate`: frames per requested interval, the followed view, bad inputs as one line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import behave
from PIL import Image

from behaviors.report.animate import (
    car_boxes,
    fit_view,
    follow_centres,
    frame_times,
    named_net,
    step_at,
    time_label,
)
from behaviors.report.fcd_read import read_fcd
from sumo_scenarios import get_scenario

DURATION = 10.0


@pytest.fixture(scope="module")
def fcd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short real populate run on the bundled highway."""
    out = tmp_path_factory.mktemp("animate") / "fcd.xml"
    done = behave("populate", "--duration", f"{DURATION:g}", "--fcd", str(out), "-q")
    assert done.returncode == 0, done.stderr
    return out


def frames(path: Path) -> list[np.ndarray]:
    with Image.open(path) as image:
        out = []
        for k in range(image.n_frames):
            image.seek(k)
            out.append(np.asarray(image.convert("RGB")))
        return out


def one_error(done: subprocess.CompletedProcess[str]) -> str:
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1 and lines[0].startswith("behave: error: "), done.stderr
    return lines[0]


# pure parts ------------------------------------------------------------------------------------


def test_one_frame_per_requested_interval():
    last = DURATION - 0.2  # SUMO's last step of a 10 s run
    assert len(frame_times(0.0, last, 1.0)) == 10
    assert len(frame_times(0.0, last, 0.5)) == 20
    assert len(frame_times(0.0, last, 0.2)) == 50  # one per step: rounding must not drop the last
    assert len(frame_times(0.0, last, 100.0)) == 1
    np.testing.assert_allclose(frame_times(3.0, 5.0, 1.0), [3.0, 4.0, 5.0])


def test_a_frame_shows_the_last_step_at_or_before_it():
    steps = np.array([0.0, 0.2, 0.4, 0.6])
    np.testing.assert_array_equal(step_at(steps, np.array([0.0, 0.3, 0.4, 0.6, 9.0])), [0, 1, 2, 3, 3])


def test_time_stamps_differ_from_frame_to_frame():
    for every in (0.2, 0.25, 0.5, 1.0, 2.5, 10.0):
        labels = [time_label(t, every) for t in frame_times(0.0, 60.0, every)]
        assert len(set(labels)) == len(labels), every
    assert time_label(12.0, 1.0) == "t = 12 s"
    assert time_label(12.4, 0.2) == "t = 12.4 s"


def test_cars_are_boxes_behind_their_front_bumper():
    east = car_boxes(np.array([10.0]), np.array([0.0]), np.array([90.0]), 5.0, 2.0)[0]
    np.testing.assert_allclose(east.min(0), [5.0, -1.0], atol=1e-9)
    np.testing.assert_allclose(east.max(0), [10.0, 1.0], atol=1e-9)
    north = car_boxes(np.array([0.0]), np.array([10.0]), np.array([0.0]), 5.0, 2.0)[0]
    np.testing.assert_allclose(north.min(0), [-1.0, 5.0], atol=1e-9)


def test_the_view_widens_a_long_road_to_a_strip_and_keeps_its_centre():
    low, high, ratio = fit_view(np.array([0.0, -10.0]), np.array([3000.0, 10.0]))
    assert ratio == pytest.approx(0.3)
    np.testing.assert_allclose((high - low)[1] / (high - low)[0], 0.3)
    np.testing.assert_allclose((low + high) / 2, [1500.0, 0.0])
    low, high, ratio = fit_view(np.array([0.0, 0.0]), np.array([100.0, 400.0]))
    assert ratio == 1.0 and (high - low)[0] == pytest.approx(400.0)


def test_the_followed_view_waits_where_the_car_enters_and_stays_where_it_leaves():
    centres = follow_centres(
        np.array([2.0, 3.0]), np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([0.0, 2.5, 9.0])
    )
    np.testing.assert_allclose(centres, [[0.0, 0.0], [5.0, 0.0], [10.0, 0.0]])


@pytest.mark.sumo
def test_the_net_a_populate_fcd_names_is_found(fcd: Path, tmp_path: Path):
    assert named_net(fcd) == get_scenario("highway").net
    other = tmp_path / "other.xml"
    other.write_text(fcd.read_text().replace("net=highway.net.xml", "net=nowhere.net.xml"))
    assert named_net(other) is None


# the command on a real run -------------------------------------------------------------------


@pytest.mark.sumo
@pytest.mark.parametrize("every", [0.5, 2.0])
def test_a_gif_has_one_frame_per_requested_interval(fcd: Path, tmp_path: Path, every: float):
    out = tmp_path / "run.gif"
    done = behave("animate", str(fcd), "--out", str(out), "--every", f"{every:g}")
    assert done.returncode == 0, done.stderr
    assert f"{int(DURATION / every)} frames" in done.stdout
    shown = frames(out)
    assert len(shown) == int(DURATION / every)
    assert all(frame.shape == shown[0].shape for frame in shown)
    assert [p.name for p in tmp_path.iterdir()] == ["run.gif"]  # no temp file left


@pytest.mark.sumo
def test_follow_keeps_the_vehicle_in_the_middle_of_the_view(fcd: Path, tmp_path: Path):
    out = tmp_path / "follow.gif"
    records = read_fcd(fcd)["id"].astype(str)
    followed = records[records.str.startswith("keeper_")].value_counts().index[0]  # one there throughout
    done = behave("animate", str(fcd), "--out", str(out), "--follow", followed, "--window", "120", "-q")
    assert done.returncode == 0, done.stderr
    assert done.stdout == "" and done.stderr == ""  # -q
    shown = frames(out)
    assert len(shown) == int(DURATION)
    keeper = np.array([0x1F, 0x77, 0xB4])  # tab:blue, the keepers' colour
    for frame in shown:
        h, w, _ = frame.shape
        middle = frame[int(0.3 * h) : int(0.7 * h), int(0.3 * w) : int(0.7 * w)].astype(int)
        assert (np.abs(middle - keeper).sum(axis=2) < 40).sum() > 20  # the followed keeper is there
    whole = tmp_path / "whole.gif"
    assert behave("animate", str(fcd), "--out", str(whole), "-q").returncode == 0
    assert frames(whole)[0].shape != shown[0].shape  # a 3 km strip, not the square window


@pytest.mark.sumo
def test_an_fcd_without_a_net_named_is_drawn_with_net_given(fcd: Path, tmp_path: Path):
    bare = tmp_path / "bare.xml"
    bare.write_text(fcd.read_text().replace("net=highway.net.xml", "net=elsewhere.net.xml"))
    done = behave("animate", str(bare), "--out", str(tmp_path / "a.gif"), "--every", "5")
    assert done.returncode == 0 and "lanes not drawn" in done.stderr
    done = behave("animate", str(bare), "--out", str(tmp_path / "b.gif"), "--every", "5", "--net", "highway")
    assert done.returncode == 0 and "lanes not drawn" not in done.stderr
    assert len(frames(tmp_path / "b.gif")) == 2


@pytest.mark.sumo
def test_bad_input_is_one_line_and_writes_nothing(fcd: Path, tmp_path: Path):
    gif = str(tmp_path / "x.gif")
    assert "no such vehicle" in one_error(behave("animate", str(fcd), "--out", gif, "--follow", "nobody"))
    assert "not found" in one_error(behave("animate", str(tmp_path / "none.xml"), "--out", gif))
    assert ".gif or .mp4" in one_error(behave("animate", str(fcd), "--out", str(tmp_path / "x.png")))
    assert "--every" in one_error(behave("animate", str(fcd), "--out", gif, "--every", "0"))
    assert "--window" in one_error(behave("animate", str(fcd), "--out", gif, "--window", "-5"))
    (tmp_path / "notfcd.xml").write_text("<routes/>")
    assert "not an FCD file" in one_error(behave("animate", str(tmp_path / "notfcd.xml"), "--out", gif))
    assert list(tmp_path.glob("x.*")) == []


@pytest.mark.sumo
def test_mp4_without_ffmpeg_says_why(fcd: Path, tmp_path: Path):
    """PATH without ffmpeg and the video extra hidden (a Python that cannot import it)."""
    hide = tmp_path / "hide"
    (hide / "imageio_ffmpeg").mkdir(parents=True)
    (hide / "imageio_ffmpeg" / "__init__.py").write_text("raise ImportError('hidden')")
    env = {**os.environ, "PATH": str(Path(sys.executable).parent), "PYTHONPATH": str(hide)}
    message = one_error(behave("animate", str(fcd), "--out", str(tmp_path / "run.mp4"), env=env))
    assert "ffmpeg" in message and "video" in message
    assert not (tmp_path / "run.mp4").exists()


@pytest.mark.sumo
def test_mp4_with_the_video_extras_ffmpeg(fcd: Path, tmp_path: Path):
    pytest.importorskip("imageio_ffmpeg", reason="the video extra (make test installs it)")
    done = behave("animate", str(fcd), "--out", str(tmp_path / "run.mp4"), "--every", "2")
    assert done.returncode == 0, done.stderr
    header = (tmp_path / "run.mp4").read_bytes()[:12]
    assert header[4:8] == b"ftyp"  # an ISO media file, as ffmpeg writes MP4
