"""The learned car both drivers share: its physical limits, the bounds the shield sets on it, and
what one step of actuation commands."""
