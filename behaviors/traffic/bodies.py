"""The sizes of the vehicles an agent senses: every gap and every side room is measured between
bodies, and a lorry's body is three cars long."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.traffic.actuation import CarModel


@dataclass(frozen=True)
class Bodies:
    """Every vehicle's size (rows as the positions handed to `surroundings`, SUMO's cars too) and
    the agents' own: a gap runs from a front bumper to the rear of the car ahead, so a 16.5 m lorry
    ahead is 11.5 m nearer than a 5 m car whose front is as far."""

    length: np.ndarray  # [M] metres
    width: np.ndarray  # [M] metres
    own_length: float = CarModel.length
    own_width: float = CarModel.width

    @staticmethod
    def cars(count: int) -> Bodies:
        """`count` vehicles all of the agents' size."""
        return Bodies(np.full(count, CarModel.length), np.full(count, CarModel.width))

    @property
    def longest(self) -> float:
        return max(float(self.length.max(initial=0.0)), self.own_length)
