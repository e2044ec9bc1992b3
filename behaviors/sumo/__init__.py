"""SUMO itself: the one access layer (libsumo or TraCI), scenario files, SUMO's outputs."""
