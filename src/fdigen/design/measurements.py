"""Measurements as the FDI step reads them.

Holds :func:`outputs_in` (the outputs a measurement expression of the configuration reads)
and :func:`validity_bound` (the largest magnitude a measured input or output may take
before the step counts it as invalid).
"""

from __future__ import annotations

import sympy as sp

from fdigen.model.expression import parse_expression
from fdigen.model.model import Model


def outputs_in(model: Model, text: str) -> set:
    outs = {o.name: o.symbol for o in model.outputs}
    expr = parse_expression(text, outs, source=model.source, field="fdi")
    return {s.name for s in expr.free_symbols}


def validity_bound(model: Model, item) -> float:
    """Largest magnitude a measured input or output may take before it counts as invalid.

    Ten times the physical limits of the state an output measures (or of the item itself),
    else a thousand times its normal range, else 1e12. NaN and Inf always count as invalid.
    """
    target = item
    if hasattr(item, "expr"):
        expr = model.expand(item.expr)
        target = next((s for s in model.states if expr == s.symbol), None)
    values = model.parameter_values
    if target is not None and getattr(target, "limits", None):
        lims = [abs(float(sp.sympify(b).xreplace(values))) for b in target.limits]
        return 10.0 * max(lims)
    span = getattr(target, "range", None) or getattr(item, "range", None)
    if span:
        return 1000.0 * max(abs(span[0]), abs(span[1]))
    return 1e12
