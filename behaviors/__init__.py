"""behave: learned, behaviour-based traffic in SUMO."""
