"""The error every plant check raises."""


class FmuError(RuntimeError):
    """An FMU that cannot be used, or that failed a call; the message names the file, the
    variable or FMI call, and what would be valid."""
