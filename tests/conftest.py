"""Fixtures more than one test folder uses (pytest finds them here); plain helpers such as the
`behave()` runner are in helpers.py. Nothing here imports SUMO at collection: the fast tier must
pass with SUMO out of reach."""

from __future__ import annotations

import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from sumo_scenarios.osm_like import OsmLikeNet


@pytest.fixture(scope="session")
def motorway(tmp_path_factory: pytest.TempPathFactory) -> OsmLikeNet:
    """A 3-lane motorway of about 4 km with an exit and an on-ramp, built by netconvert from plain
    XML, with demand dense enough that its cars are on the road 10 s after the start, and its
    sumocfg; built once per test session."""
    from sumo_scenarios.osm_like import Demand, build_osm_like

    return build_osm_like("motorway3", tmp_path_factory.mktemp("motorway3"), Demand(end=600.0, scale=2.0))


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Callable[[int], Path]]:
    """`tmpfs(kb)`: a file system of `kb` kB of its own under tmp_path, to fill up (a full disk);
    skips the test where mounting is not permitted; unmounted after the test."""
    mounts: list[Path] = []

    def mount(kb: int) -> Path:
        folder = tmp_path / f"small{len(mounts)}"
        folder.mkdir()
        done = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={kb}k", "tmpfs", str(folder)], capture_output=True
        )
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
        mounts.append(folder)
        return folder

    try:
        yield mount
    finally:
        for folder in mounts:
            subprocess.run(["umount", "--lazy", str(folder)], check=False)
