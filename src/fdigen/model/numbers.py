"""The numbers a model file may hold: real, finite, and small enough for the derivations.

TOML reads ``1`` followed by 400 zeros as a Python integer; ``math.isfinite`` and
``float`` raise ``OverflowError`` on it, and a model file with one in a parameter's value,
a bound, a noise level or ``[simulation] initial`` ended in an internal error (attack
round 8). Integers are compared with the limit as integers (exact, no conversion).
"""

from __future__ import annotations

import math

from fdigen.model.expression import MAX_MAGNITUDE


#: The largest double: an ``[fdi]`` setting may be as large (a threshold of 1e300 never
#: flags), never larger (an integer of 400 digits has no float).
DOUBLE_MAX = 1.7976931348623157e308


def number_problem(value, limit: float = MAX_MAGNITUDE) -> str | None:
    """Why ``value`` is no usable number of a model file, or ``None`` (``limit``: the
    largest magnitude accepted; the equations' numbers :data:`MAX_MAGNITUDE`)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"expected a number, got {type(value).__name__}"
    if not isinstance(value, int) and not math.isfinite(value):
        return "value is not a finite number"
    if abs(value) > limit:               # an int: compared exactly, never converted
        if limit >= DOUBLE_MAX:
            return "magnitude beyond the range of a double (1.8e308)"
        return (f"magnitude beyond {limit:g}: the derivations square and multiply such "
                "numbers past the range of a double")
    return None
