"""`python -m cli` runs the behave command line (used by scripts that need this interpreter)."""

from cli.main import main

main()
