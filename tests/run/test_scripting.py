"""populate for scripts and batch jobs: -q/-v, progress lines in a log, Ctrl-C that keeps the run
so far, and --gui where no display exists."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
from helpers import BEHAVE, behave

from behaviors.cli.progress import ProgressLines, line_due, verbosity
from behaviors.errors import BehaveError
from behaviors.report.fcd_read import read_fcd, validate_fcd_xml
from behaviors.sumo.display import display_missing
from behaviors.sumo.interrupt import sigint_between_steps
from behaviors.sumo.sim import SimOptions

# -q / -v and progress lines ---------------------------------------------------------------------


def test_quiet_and_verbose_exclude_each_other():
    assert (verbosity(False, False), verbosity(True, False), verbosity(False, True)) == (0, -1, 1)
    with pytest.raises(BehaveError, match="exclude each other"):
        verbosity(True, True)


def test_a_line_every_tenth_of_the_work_or_every_half_minute():
    assert not line_due(5.0, 100.0, 0.0, now=1.0, last_time=0.0)
    assert line_due(10.0, 100.0, 0.0, now=1.0, last_time=0.0)
    assert line_due(0.3, 0.3 * 10, 0.0, now=1.0, last_time=0.0)  # a tenth that floats round down
    assert line_due(12.0, 100.0, 10.0, now=31.0, last_time=0.0)  # slow work: 30 s of wall time
    assert line_due(100.0, 100.0, 95.0, now=1.0, last_time=0.0)  # the end is always shown
    assert not line_due(100.0, 100.0, 100.0, now=1.0, last_time=0.0)  # ... once


def test_progress_lines_of_a_run():
    clock = iter([0.0, *range(1, 1000)]).__next__
    out = io.StringIO()
    lines = ProgressLines("simulating", 10.0, "s", out, clock=clock)
    for k in range(1, 51):
        lines.update(k * 0.2)
    text = out.getvalue().splitlines()
    assert len(text) == 10
    assert text[0].startswith("simulating: 1/10 s (10%)") and text[-1].startswith(
        "simulating: 10/10 s (100%)"
    )


@pytest.mark.sumo
def test_populate_in_a_log_prints_progress_lines_and_the_summary(tmp_path: Path):
    done = behave("populate", "--duration", "10", "--fcd", str(tmp_path / "fcd.xml"))
    assert done.returncode == 0, done.stderr
    progress = [line for line in done.stderr.splitlines() if line.startswith("simulating: ")]
    assert len(progress) == 10, done.stderr  # every 10%
    assert progress[-1].startswith("simulating: 10/10 s (100%)")
    assert "collisions" in done.stdout and "FCD written to" in done.stdout
    assert "phase " not in done.stderr


@pytest.mark.sumo
def test_quiet_populate_prints_nothing_but_json_if_asked(tmp_path: Path):
    done = behave("populate", "--duration", "4", "--fcd", str(tmp_path / "a.xml"), "-q")
    assert done.returncode == 0, done.stderr
    assert (done.stdout, done.stderr) == ("", "")
    assert (tmp_path / "a.xml").is_file()
    done = behave("populate", "--duration", "4", "--fcd", str(tmp_path / "b.xml"), "--quiet", "--json")
    assert done.returncode == 0 and done.stderr == ""
    summary = json.loads(done.stdout)
    assert summary["simulated_s"] == pytest.approx(4.0) and summary["cut_short"] is False


@pytest.mark.sumo
def test_verbose_populate_shows_phase_timings(tmp_path: Path):
    done = behave("populate", "--duration", "4", "--fcd", str(tmp_path / "a.xml"), "-v")
    assert done.returncode == 0, done.stderr
    assert re.search(r"^phase sumo: [\d.]+ s of [\d.]+ s wall$", done.stderr, re.MULTILINE), done.stderr
    assert re.search(r"^phase policy: ", done.stderr, re.MULTILINE)
    assert "-q/--quiet and -v/--verbose" in behave("populate", "-q", "-v").stderr


@pytest.mark.sumo
def test_train_in_a_log_prints_a_line_per_tenth_and_one_per_episode_with_v(tmp_path: Path):
    args = ("train", "lanekeeping", "--scenario", "tiny", "--agents", "1", "--episodes", "2",
            "--max-steps", "10", "--warmup", "5", "--batch-size", "4")  # fmt: skip
    done = behave(*args, "--out", str(tmp_path / "a"))
    assert done.returncode == 0, done.stderr
    progress = [line for line in done.stderr.splitlines() if line.startswith("training: ")]
    assert [line.split(" (")[0] for line in progress] == ["training: 1/2 episodes", "training: 2/2 episodes"]
    assert "reward " in progress[-1] and "done: 2 of 2 episodes" in done.stdout
    done = behave(*args, "--out", str(tmp_path / "b"), "-v")
    episodes = [line for line in done.stderr.splitlines() if line.startswith("episode ")]
    assert done.returncode == 0 and [line.split(":")[0] for line in episodes] == [
        "episode 1/2",
        "episode 2/2",
    ]
    done = behave(*args, "--out", str(tmp_path / "c"), "-q")
    assert (done.returncode, done.stdout, done.stderr) == (0, "", "")
    assert (tmp_path / "c" / "metrics.csv").is_file()


@pytest.mark.sumo
def test_quiet_evaluate_writes_its_files_and_prints_nothing(tmp_path: Path):
    args = ("evaluate", "lanekeeping", "--agents", "1", "--episodes", "1", "--max-steps", "20",
            "--scenario", "tiny", "--no-realism")  # fmt: skip
    done = behave(*args, "--out", str(tmp_path / "q"), "-q")
    assert (done.returncode, done.stdout, done.stderr) == (0, "", "")
    assert (tmp_path / "q" / "results.csv").is_file()
    done = behave(*args, "--out", str(tmp_path / "v"), "-v")
    assert done.returncode == 0 and re.search(
        r"^  lanekeeping 1 agents?: .*?progress/agent", done.stdout, re.M | re.S
    ), done.stdout  # the line may wrap at the console's width


# Ctrl-C -----------------------------------------------------------------------------------------


def test_sigint_is_held_until_the_step_ends_and_a_second_one_is_not():
    before = signal.getsignal(signal.SIGINT)
    with sigint_between_steps() as interrupted:
        assert not interrupted()
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.01)  # the handler runs between bytecodes
        assert interrupted()
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)
    assert signal.getsignal(signal.SIGINT) is before


@pytest.mark.sumo
def test_ctrl_c_keeps_a_whole_fcd_up_to_the_last_step(tmp_path: Path):
    out = tmp_path / "fcd.xml"
    command = [*BEHAVE, "populate", "--duration", "3600", "--keep-count", "--fcd", str(out), "--json"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not any(p.stat().st_size > 200_000 for p in tmp_path.iterdir()) and time.monotonic() < deadline:
        time.sleep(0.2)  # until the run has stepped a while (SUMO writes its FCD as it goes)
    assert not out.exists()  # the FCD is still a temp file
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    stopped = re.search(r"interrupted after ([\d.]+) of 3600 simulated s", stderr)
    assert stopped, stderr
    simulated = float(stopped[1])
    assert 0 < simulated < 3600
    summary = json.loads(stdout)
    assert summary["cut_short"] is True and summary["simulated_s"] == pytest.approx(simulated)
    validate_fcd_xml(out)  # SUMO's schema: closed properly
    df = read_fcd(out)
    assert df["time"].max() == pytest.approx(simulated - 0.2)  # SUMO's last written step
    assert f"cut-short-after={simulated:g}" in out.read_text()[:2000]
    agents = (tmp_path / "fcd.agents.csv").read_text().splitlines()
    assert len(agents) > 1 and agents[0].startswith("id,behaviour")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fcd.agents.csv", "fcd.xml"]  # no temp left


# --gui -------------------------------------------------------------------------------------------


@pytest.mark.sumo
def test_gui_needs_a_display_except_on_windows():
    assert display_missing({}, "linux") is not None
    assert "DISPLAY" in (display_missing({"DISPLAY": ""}, "darwin") or "")
    assert display_missing({"DISPLAY": ":0"}, "linux") is None
    assert display_missing({}, "win32") is None
    assert SimOptions(Path("n.net.xml"), gui=True).command()[0].endswith("sumo-gui")
    assert SimOptions(Path("n.net.xml")).command()[0].endswith("sumo")


@pytest.mark.sumo
def test_gui_without_a_display_stops_before_anything_runs(tmp_path: Path):
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    done = behave("populate", "--gui", "--duration", "5", "--fcd", str(tmp_path / "fcd.xml"), env=env)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("behave: error: --gui needs a display"), done.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.sumo
@pytest.mark.skipif(
    not os.environ.get("DISPLAY") and shutil.which("xvfb-run") is None, reason="no display and no xvfb-run"
)
def test_gui_runs_the_same_simulation(tmp_path: Path):
    args = ["populate", "--duration", "3", "-q"]
    gui = [*BEHAVE, *args, "--gui", "--fcd", str(tmp_path / "gui.xml")]
    if not os.environ.get("DISPLAY"):
        gui = ["xvfb-run", "-a", *gui]
    done = subprocess.run(gui, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert behave(*args, "--fcd", str(tmp_path / "plain.xml")).returncode == 0
    assert (tmp_path / "gui.xml").read_text() == (tmp_path / "plain.xml").read_text()
