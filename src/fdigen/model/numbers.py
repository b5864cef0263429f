"""The numbers a model file may hold: real, finite, and small enough for the derivations.

TOML reads ``1`` followed by 400 zeros as a Python integer; ``math.isfinite`` and
``float`` raise ``OverflowError`` on it, and a model file with one in a parameter's value,
a bound, a noise level or ``[simulation] initial`` ended in an internal error (attack
round 8). Integers are compared with the limit as integers (exact, no conversion).
"""

from __future__ import annotations

import math

from fdigen.model.expression import MAX_MAGNITUDE


def number_problem(value) -> str | None:
    """Why ``value`` is no usable number of a model file, or ``None``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"expected a number, got {type(value).__name__}"
    if not isinstance(value, int) and not math.isfinite(value):
        return "value is not a finite number"
    if abs(value) > MAX_MAGNITUDE:       # an int: compared exactly, never converted
        return (f"magnitude beyond {MAX_MAGNITUDE:g}: the derivations square and multiply "
                "such numbers past the range of a double")
    return None
