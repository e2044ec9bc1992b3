"""The one domain exception: the CLI turns it into a single stderr line and exit code 2.

It lives here, at the bottom of the import tree, so that the scenario builders raise it too
without importing `behaviors` (which re-exports it as `behaviors.errors.BehaveError`).
"""


class BehaveError(ValueError):
    """A problem the user can fix (bad option, bad file); its message names the problem."""
