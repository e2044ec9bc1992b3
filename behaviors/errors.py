"""The one domain exception: the CLI turns it into a single stderr line and exit code 2."""


class BehaveError(ValueError):
    """A problem the user can fix (bad option, bad file); its message names the problem."""
