"""Errors a training run reports in one line instead of a traceback."""


class NonFiniteError(RuntimeError):
    """A loss, gradient, parameter or return estimate became NaN or inf."""
