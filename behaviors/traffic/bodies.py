"""The sizes of the vehicles an agent senses: every gap and every side room is measured between
bodies, and a lorry's body is three cars long."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from behaviors.car.model import CarModel


@dataclass(frozen=True)
class Bodies:
    """Every vehicle's size (rows as the positions handed to `surroundings`, SUMO's cars too) and
    the agents' own (rows as the agents'): a gap runs from a front bumper to the rear of the car
    ahead, so a 16.5 m lorry ahead is 11.5 m nearer than a 5 m car whose front is as far."""

    length: np.ndarray  # [M] metres
    width: np.ndarray  # [M] metres
    own_length: np.ndarray | None = None  # [N] the agents' own, by agent (None: all of CarModel's size)
    own_width: np.ndarray | None = None

    @staticmethod
    def cars(count: int) -> Bodies:
        """`count` vehicles all of the agents' size."""
        return Bodies(np.full(count, CarModel.length), np.full(count, CarModel.width))

    def own_size(self, agents: np.ndarray) -> tuple[np.ndarray | float, np.ndarray | float]:
        """Length and width of the agents in rows `agents` (a learned lorry is longer than a car)."""
        if self.own_length is None or self.own_width is None:
            return CarModel.length, CarModel.width
        return self.own_length[agents], self.own_width[agents]

    @property
    def own_longest(self) -> float:
        return (
            CarModel.length
            if self.own_length is None
            else float(self.own_length.max(initial=CarModel.length))
        )

    @property
    def longest(self) -> float:
        return max(float(self.length.max(initial=0.0)), self.own_longest)
