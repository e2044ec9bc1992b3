"""The traffic driver: the car model, its law, lane-change motives, limits, rewards and styles."""
