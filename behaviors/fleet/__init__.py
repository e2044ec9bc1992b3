"""The controlled cars: their rows, the drivers that observe and act for them, the hand-over to SUMO."""
