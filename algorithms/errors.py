"""Domain errors of the algorithms package."""


class AlgorithmError(ValueError):
    """Bad input to an algorithm: the message says what was wrong and what is allowed."""
