"""`python -m behaviors.cli` runs the behave command line (used by scripts that need this interpreter)."""

from behaviors.cli.main import main

main()
