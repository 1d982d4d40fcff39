"""Domain errors of the simulator package."""


class TwinError(Exception):
    """A user-facing error: one line that says what was wrong and what is allowed."""
