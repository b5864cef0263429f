"""click parameter types for the values every command checks before it starts.

A bad value is a usage error naming the option (``Invalid value for '--duration': ...``,
exit status 2), never a traceback or a long run on nonsense.
"""

from __future__ import annotations

import math

import click


class FiniteFloat(click.ParamType):
    """A finite float (no ``nan``/``inf``), optionally ``> 0``.

    Parameters
    ----------
    positive : bool
        Require ``x > 0``.
    """

    name = "number"

    def __init__(self, positive: bool = True):
        self.positive = positive

    def convert(self, value, param, ctx):
        if isinstance(value, float) and math.isfinite(value) and \
                (value > 0 or not self.positive):
            return value
        try:
            x = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(x):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if self.positive and not x > 0:
            self.fail(f"{value!r} must be greater than 0", param, ctx)
        return x


#: A duration, a time step: finite and > 0.
POSITIVE_SECONDS = FiniteFloat(positive=True)
#: A count of at least 1 (points, runs, workers).
COUNT = click.IntRange(min=1)
