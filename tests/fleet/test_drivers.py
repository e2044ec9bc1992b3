"""Driver models are objects found by name: a new one is one class and one registration."""

from __future__ import annotations

import numpy as np
import pytest

from behaviors.errors import BehaveError
from behaviors.fleet.drivers import DRIVERS, PaperDriver, TrafficDriver, driver_of_obs_size, make_driver
from behaviors.learn.env import make_env
from behaviors.paper.sensors import OBS_SIZE, OBS_SIZE_WITH_ID
from behaviors.traffic.lanes import TRAFFIC_OBS_SIZE
from behaviors.traffic.settings import CarFollowing, LaneDriving


class CautiousDriver(TrafficDriver):
    """The README's example: the traffic driver's sensing and policy interface, following at 2 s
    and pulling away gently (a truck, or a cautious driving style)."""

    name = "cautious"

    def __init__(self) -> None:
        super().__init__(LaneDriving(following=CarFollowing(time_headway=2.0, accel=1.0)))


def test_drivers_are_found_by_name_and_by_the_size_of_a_policy_input() -> None:
    assert isinstance(make_driver("paper"), PaperDriver) and isinstance(make_driver("traffic"), TrafficDriver)
    assert make_driver("traffic") is not make_driver("traffic")  # one per fleet: they cache per road
    assert driver_of_obs_size(OBS_SIZE) == ("paper", False)
    assert driver_of_obs_size(OBS_SIZE_WITH_ID) == ("paper", True)
    assert driver_of_obs_size(TRAFFIC_OBS_SIZE)[0] == "traffic"
    with pytest.raises(BehaveError, match="unknown driver 'truck'"):
        make_driver("truck")
    with pytest.raises(BehaveError, match="no driver takes 7 observations"):
        driver_of_obs_size(7)


def run_speeds(driver: str, steps: int = 60) -> np.ndarray:
    env = make_env(
        "roads", behaviour="multi", overtakers=2, keepers=2, driver=driver, seed=4, max_steps=steps
    )
    try:
        obs = env.reset_arrays(seed=4)
        assert obs.shape[1] == TRAFFIC_OBS_SIZE and env.fleet.driver.name == driver
        speeds = []
        for _ in range(steps):
            if not env.agents:
                break
            batch = env.step_arrays(np.tile([0.0, 0.5, 0.0], (len(env.agents), 1)).astype(np.float32))
            speeds.append(batch.speed.mean())
        return np.array(speeds)
    finally:
        env.close()


@pytest.mark.sumo
def test_a_new_driver_is_one_class_and_one_registration(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(DRIVERS, CautiousDriver.name, CautiousDriver)
    cautious, usual = run_speeds("cautious"), run_speeds("traffic")
    assert len(cautious) == len(usual)
    assert cautious.mean() < usual.mean()  # same seed, same traffic: it pulls away more gently
