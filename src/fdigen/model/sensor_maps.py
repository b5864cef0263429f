"""Output maps as functions of the states: which sensors measure one state, and how.

A sensor measures a state when its output map ``y = g(x_i, p)`` depends on that one state
(and parameters) only and is invertible over the state's declared range: ``y = x``,
``y = kc*x`` (a level sensor in volts), ``y = kc*x + off``, ``y = 100*x`` (metres read in
centimetres). The derivations that drive a sub-model by a measured state, initialise a state
from its sensor or schedule a filter on it substitute the inverse ``x = g^{-1}(y)``; for the
identity map the inverse is the output's own symbol, so plants written ``y = x`` derive the
same expressions as before.

An output of one state that is not invertible over the range (``y = x**2`` with a range
crossing 0, ``y = sin(x)`` over more than a half period) measures nothing directly;
:func:`not_invertible` lists them with the reason, for ``inspect`` and the build to say.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp

from fdigen.model.model import Model


@dataclass(frozen=True)
class SensorMap:
    """``y = forward(x)`` and ``x = inverse(y)`` of one output measuring one state.

    Attributes
    ----------
    output, state : str
    forward : sympy.Expr
        The output map in the state's symbol and parameters.
    inverse : sympy.Expr
        The state in the output's symbol and parameters (``y`` itself for ``y = x``).
    gain : float
        ``dg/dx`` at the operating point (1 for ``y = x``): a sensor noise ``sigma_y`` is
        ``sigma_y / |gain|`` on the state.
    """

    output: str
    state: str
    forward: sp.Expr
    inverse: sp.Expr
    gain: float

    @property
    def identity(self) -> bool:
        return self.inverse == sp.Symbol(self.output, real=True)


_CACHE: dict = {}


def sensor_maps(model: Model) -> dict[str, list[SensorMap]]:
    """State name -> the invertible sensor maps measuring it, best first: a sensor the
    parity residuals compare, then the least noisy on the state's scale
    (``noise_std / |dg/dx|``), then the file's order (so reordering the outputs changes
    nothing unless two sensors are alike in all of these)."""
    return _analyse(model)[0]


def not_invertible(model: Model) -> dict[str, str]:
    """Output name -> why an output of a single state is not used as that state's measurement."""
    return _analyse(model)[1]


def state_of_output(model: Model, output: str) -> SensorMap | None:
    """The map of an output that measures one state invertibly, or ``None``."""
    for maps in sensor_maps(model).values():
        for m in maps:
            if m.output == output:
                return m
    return None


def _analyse(model: Model):
    key = (tuple((o.name, sp.srepr(model.expand(o.expr))) for o in model.outputs),
           tuple((s.name, s.range, model.operating_point.get(s.name)) for s in model.states),
           tuple((p.name, p.value) for p in model.parameters),
           tuple((o.name, o.noise_std) for o in model.outputs),
           tuple(dict((model.fdi or {}).get("parity", {})).values()))
    if key not in _CACHE:
        if len(_CACHE) > 256:      # parameter sweeps (tune, calibrate) make many variants
            _CACHE.clear()
        _CACHE[key] = _derive(model)
    return _CACHE[key]


def _derive(model: Model):
    states = {s.symbol: s for s in model.states}
    values = model.parameter_values
    maps: dict[str, list[SensorMap]] = {}
    refused: dict[str, str] = {}
    for o in model.outputs:
        expr = model.expand(o.expr)
        free = expr.free_symbols
        used = [s for s in free if s in states]
        if len(used) != 1 or not free - {used[0]} <= set(values):
            continue   # several states, inputs or faults: not a direct measurement
        x = used[0]
        state = states[x]
        found = _invert(expr, x, o.symbol, state, model, values)
        if isinstance(found, str):
            refused[o.name] = found
            continue
        inverse, gain = found
        maps.setdefault(state.name, []).append(SensorMap(o.name, state.name, expr, inverse,
                                                         gain))
    rank = output_preference(model)
    for state in maps:   # the choice of a state's sensor must not depend on the file's order
        maps[state].sort(key=lambda m: rank[m.output])
    return maps, refused


def output_preference(model: Model) -> dict:
    """Output name -> sort key, best first: compared by a parity residual, then the least
    noisy relative to the span of the state it reads (``noise_std / (|dg/dx| span)``, the
    same in any unit), then the file's order."""
    parity = set(dict((model.fdi or {}).get("parity", {})).values())
    values = model.parameter_values
    out = {}
    for k, o in enumerate(model.outputs):
        rel = float("inf")
        expr = model.expand(o.expr)
        xs = [s for s in model.states if s.symbol in expr.free_symbols]
        if len(xs) == 1 and xs[0].range:
            x = xs[0]
            x0 = sp.sympify(model.operating_point[x.name]).xreplace(values)
            span = abs(float(x.range[1]) - float(x.range[0]))
            try:
                gain = abs(float(sp.diff(expr, x.symbol).xreplace({x.symbol: x0})
                                 .xreplace(values)))
                rel = o.noise_std / (gain * span) if gain * span > 0 else rel
            except (TypeError, ValueError):
                pass
        out[o.name] = (o.name not in parity, rel, k)
    return out


def _invert(expr, x, y, state, model, values):
    """``(inverse, gain)`` of ``y = expr(x)`` over the state's range, or the reason not."""
    if expr == x:
        return y, 1.0
    x0 = float(sp.sympify(model.operating_point[state.name]).xreplace(values))
    lo, hi = state.range if state.range else (x0, x0)
    probe = sorted({x0, *np.linspace(float(lo), float(hi), 9).tolist()})
    g = sp.lambdify(x, expr.xreplace(values), "math")
    dg = sp.lambdify(x, sp.diff(expr, x).xreplace(values), "math")
    try:
        slopes = [float(dg(v)) for v in probe]
    except (ValueError, TypeError, ZeroDivisionError, OverflowError):
        return f"{expr} cannot be evaluated over the range of {state.name}"
    if not all(np.isfinite(slopes)) or not (all(s > 0 for s in slopes)
                                              or all(s < 0 for s in slopes)):
        return (f"{expr} is not monotonic in {state.name} over its range "
                f"[{lo}, {hi}] (its slope changes sign or vanishes)")
    try:
        sols = sp.solve(sp.Eq(y, expr), x, dict=False)
    except (NotImplementedError, ValueError):
        sols = []
    for sol in sols:
        h = sp.lambdify(y, sol.xreplace(values), "math")
        try:
            ok = all(abs(float(h(g(v))) - v) <= 1e-9 * max(1.0, abs(v)) for v in probe)
        except (ValueError, TypeError, ZeroDivisionError, OverflowError):
            ok = False
        if ok:
            return sp.simplify(sol), float(dg(x0))
    return f"no closed-form inverse of {expr} for {state.name} was found"
