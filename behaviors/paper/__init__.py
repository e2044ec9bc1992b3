"""The paper's driver: its 65-value TORCS-like state."""
