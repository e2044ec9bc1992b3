"""A top-down picture of the road and its cars, as an RGB array (no display, no matplotlib)."""

from __future__ import annotations

import numpy as np

from behaviors.errors import BehaveError

RENDER_MODES = ("rgb_array",)
ROAD = (90, 90, 90)
AGENT = (220, 40, 40)
OTHER = (40, 90, 220)
BACKGROUND = (235, 235, 235)


def check_render_mode(mode: str | None) -> str | None:
    """None (no pictures) or one of RENDER_MODES; anything else is a BehaveError."""
    if mode is not None and mode not in RENDER_MODES:
        raise BehaveError(f"unknown render_mode {mode!r} (choose None or {', '.join(RENDER_MODES)})")
    return mode


def top_down(
    seg_a: np.ndarray, seg_b: np.ndarray, cars: np.ndarray, is_agent: np.ndarray, size: int = 256
) -> np.ndarray:
    """[size, size, 3] uint8: lane axes (segments seg_a -> seg_b) in grey, agents red, other cars
    blue, scaled to fit the road with north up."""
    low = np.minimum(seg_a.min(0), seg_b.min(0)) - 5.0
    span = max(float((np.maximum(seg_a.max(0), seg_b.max(0)) + 5.0 - low).max()), 1.0)
    image = np.empty((size, size, 3), np.uint8)
    image[:] = BACKGROUND

    def pixels(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        scaled = np.clip(((points - low) / span * (size - 1)).astype(int), 0, size - 1)
        return size - 1 - scaled[:, 1], scaled[:, 0]

    along = np.linspace(0.0, 1.0, size)[:, None, None]  # a point per pixel of the longest segment
    image[pixels((seg_a + along * (seg_b - seg_a)).reshape(-1, 2))] = ROAD
    for dy in (-1, 0, 1):  # cars as 3x3 squares
        for dx in (-1, 0, 1):
            rows, cols = pixels(cars)
            rows, cols = np.clip(rows + dy, 0, size - 1), np.clip(cols + dx, 0, size - 1)
            image[rows[~is_agent], cols[~is_agent]] = OTHER
            image[rows[is_agent], cols[is_agent]] = AGENT
    return image
