"""The jobs a user runs: populate, evaluate, sweep."""
