"""Measurements as the FDI step reads them.

Holds :func:`outputs_in` (the outputs a measurement expression of the configuration reads)
and :func:`validity_bound` (the largest magnitude a measured input or output may take
before the step counts it as invalid).
"""

from __future__ import annotations

import sympy as sp

from fdigen.model.expression import parse_expression
from fdigen.model.model import Model
from fdigen.model.sensor_maps import state_of_output


def outputs_in(model: Model, text: str) -> set:
    outs = {o.name: o.symbol for o in model.outputs}
    expr = parse_expression(text, outs, source=model.source, field="fdi")
    return {s.name for s in expr.free_symbols}


def validity_bound(model: Model, item) -> float:
    """Largest magnitude a measured input or output may take before it counts as invalid.

    Ten times the physical limits of the state an output measures (or of the item itself),
    else a thousand times its normal range, else 1e12. NaN and Inf always count as invalid.
    """
    target, forward = item, None
    if hasattr(item, "expr"):
        sm = state_of_output(model, item.name)
        target = None if sm is None else model.states[model.state_index(sm.state)]
        if sm is not None:
            def forward(v):
                return sm.forward.xreplace({target.symbol: sp.sympify(v)})
    values = model.parameter_values
    if target is not None and getattr(target, "limits", None):
        ends = [sp.sympify(b) for b in target.limits]
        if forward is not None:   # the state's limits as the sensor reads them
            ends = [forward(b) for b in ends]
        lims = [abs(float(b.xreplace(values))) for b in ends]
        return 10.0 * max(lims)
    span = getattr(target, "range", None) or getattr(item, "range", None)
    if span and forward is not None:
        span = [float(forward(v).xreplace(values)) for v in span]
    if span:
        return 1000.0 * max(abs(span[0]), abs(span[1]))
    return 1e12
