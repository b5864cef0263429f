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
    reads : tuple of (str, str)
        For a map of several states (:func:`compound_sensor_maps`): the ``(state, output)``
        of the other states, each measured directly, whose readings the inverse uses.
        Empty for a map of one state.
    """

    output: str
    state: str
    forward: sp.Expr
    inverse: sp.Expr
    gain: float
    reads: tuple = ()

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
        maps, refused = _derive(model)
        _CACHE[key] = (maps, refused, _derive_compound(model, maps))
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


def compound_sensor_maps(model: Model) -> dict[str, list[SensorMap]]:
    """State name -> maps of outputs that read it together with other states, each of
    which some sensor measures directly: with those states known, the output measures
    this one. A conductivity probe reads a salt mass over a volume, ``y = kc M/(A h)``,
    and an optical-density probe a biomass over a volume; with ``h`` (or ``V``) measured,
    ``M = A h y/kc``. Written with concentrations as states the same sensor measures one
    state directly: the derivations that drive sub-models by measured states must not
    depend on that choice of state variables.

    The inverse reads the other states through their best sensors' outputs
    (:attr:`SensorMap.reads`); it must be monotonic in the state over its range with the
    others at their operating values, and found in closed form. A state with a direct
    sensor gets no compound map."""
    return _analyse(model)[2]


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


#: CPU seconds ``sympy.solve`` may spend inverting one sensor map (after the fast inverse
#: of composed functions found none): an NTC read through a divider,
#: ``y = V Rf/(Rf + R25 exp(B (1/(T + 273.15) - 1/298.15)))``, took ``solve`` past 16 GB.
SOLVE_BUDGET = 5.0


def closed_form_inverses(expr, x, y) -> list:
    """Candidate closed forms of ``x`` with ``y = expr(x)``: the inverse of the composed
    functions (sympy's ``invert_real``, fast), else ``sympy.solve`` within
    :data:`SOLVE_BUDGET` CPU seconds. Each candidate is to be checked by its caller."""
    from sympy.solvers.solveset import invert_real

    from fdigen.derive.budget import BudgetExceeded, time_budget

    # a power with a decimal exponent (the barometric formula's (1 - c z)**5.25588) is
    # inverted with the exponent as the fraction it reads as, then written back as it was
    decimal = {}

    def exact(pw):
        q = sp.Rational(repr(float(pw.exp)))     # 5.25588 -> 131397/25000
        decimal[q] = pw.exp
        return sp.Pow(pw.base, q)

    expr = expr.replace(lambda e: e.is_Pow and e.exp.is_Float and e.base.has(x), exact)

    def back(sol):
        if not decimal:
            return sol
        return sol.replace(lambda e: e.is_Pow and e.exp.is_Rational and not e.exp.is_Integer,
                           lambda e: sp.Pow(e.base, next((sp.Float(1 / v, 17) for q, v in
                                                          decimal.items() if 1 / q == e.exp),
                                                         e.exp)))
    try:
        var, found = invert_real(expr, y, x)
        if var == x:
            cands = _finite_members(found)
            if cands:
                return [back(c) for c in cands]
    except (Exception, RecursionError):  # noqa: BLE001 - sympy's failures: solve next
        pass
    try:
        with time_budget(SOLVE_BUDGET, "inverse of a sensor map"):
            return [back(c) for c in sp.solve(sp.Eq(y, expr), x, dict=False)]
    except BudgetExceeded:
        return []
    except (Exception, RecursionError, MemoryError):  # noqa: BLE001 - no closed form
        return []


def _finite_members(found) -> list:
    """The explicit elements of a solution set (a finite set, or one intersected with the
    reals, or the image of one); [] for anything else (a condition set)."""
    if isinstance(found, sp.FiniteSet):
        return list(found.args)
    if isinstance(found, (sp.Intersection, sp.Union)):
        out = []
        for part in found.args:
            out.extend(_finite_members(part))
        return out
    if isinstance(found, sp.ImageSet) and len(found.base_sets) == 1:
        # f(x) over {y/p0} (intersected with where f is defined: the caller checks the
        # round trip over the state's range): the barometric formula's inverse
        return [found.lamda(m) for m in _finite_members(found.base_sets[0])]
    return []


def _monotonic(expr, x, state, model, values):
    """``(probe, g, dg)``: points over the state's range and ``y = expr(x)`` and its slope
    as functions, when the slope keeps one sign there; else the reason not."""
    from fdigen.safe_lambdify import safe_lambdify

    x0 = float(sp.sympify(model.operating_point[state.name]).xreplace(values))
    lo, hi = state.range if state.range else (x0, x0)
    probe = sorted({x0, *np.linspace(float(lo), float(hi), 9).tolist()})
    try:
        g = safe_lambdify([x], expr.xreplace(values), "numpy")
        dg = safe_lambdify([x], sp.diff(expr, x).xreplace(values), "numpy")
        with np.errstate(all="ignore"):
            slopes = [float(dg(v)) for v in probe]
    except (ValueError, TypeError, ZeroDivisionError, OverflowError):
        slopes = [float("nan")]
    if not all(np.isfinite(slopes)):
        return f"{expr} cannot be evaluated over the range of {state.name}"
    if not (all(s > 0 for s in slopes) or all(s < 0 for s in slopes)):
        return (f"{expr} is not monotonic in {state.name} over its range "
                f"[{lo}, {hi}] (its slope changes sign or vanishes)")
    return probe, g, dg


def _invert(expr, x, y, state, model, values):
    """``(inverse, gain)`` of ``y = expr(x)`` over the state's range, or the reason not."""
    from fdigen.safe_lambdify import safe_lambdify

    if expr == x:
        return y, 1.0
    checked = _monotonic(expr, x, state, model, values)
    if isinstance(checked, str):
        return checked
    probe, g, dg = checked
    x0 = float(sp.sympify(model.operating_point[state.name]).xreplace(values))
    for sol in closed_form_inverses(expr, x, y):
        try:
            h = safe_lambdify([y], sol.xreplace(values), "numpy")
            with np.errstate(all="ignore"):
                ok = all(abs(float(h(g(v))) - v) <= 1e-9 * max(1.0, abs(v)) for v in probe)
        except (ValueError, TypeError, ZeroDivisionError, OverflowError):
            ok = False
        if ok:
            return _guarded_roots(sp.simplify(sol)), float(dg(x0))
    return f"no closed-form inverse of {expr} for {state.name} was found"


def _guarded_roots(expr):
    """``expr`` with every even root's argument clipped at 0: ``sqrt(max(a, 0))``.

    The inverse is exact over the state's range, but a reading's noise near the bottom
    of the range leaves it: a thrust stand's load cell read -0.51 g at spin-up, the
    inverse ``w = sqrt(lc/kT)`` was NaN, and the two residuals built on it latched their
    flags for the whole log (safety_stop at 0.1 s, a later sensor fault "unexplained").
    """
    def even_root(e):
        return (isinstance(e, sp.Pow) and e.exp.is_Rational and not e.exp.is_Integer
                and e.exp.q % 2 == 0)

    return expr.replace(even_root, lambda e: sp.Pow(sp.Max(e.base, 0), e.exp))


def _derive_compound(model: Model, direct: dict) -> dict:
    states = {s.symbol: s for s in model.states}
    values = model.parameter_values
    used_outputs = {m.output for maps in direct.values() for m in maps}
    out: dict[str, list[SensorMap]] = {}
    # the inputs (read by the FDI core as they are) at their operating values where the
    # map is checked; the faults at 0 (a trailer's extra mass in an accelerometer's map)
    u_op = {v.symbol: sp.Float(model.operating_point[v.name], 17) for v in model.inputs
            if v.name in model.operating_point}
    healthy = {f.symbol: sp.Integer(0) for f in model.faults}
    for o in model.outputs:
        if o.name in used_outputs:
            continue
        expr = model.expand(o.expr).xreplace(healthy)
        free = expr.free_symbols
        xs = [x for x in free if x in states]
        if len(xs) < 2 or not free - set(xs) <= set(values) | set(u_op):
            continue
        unknown = [x for x in xs if states[x].name not in direct]
        if len(unknown) != 1:
            continue
        x = unknown[0]
        state = states[x]
        others = sorted((states[v].name for v in xs if v != x))
        reads = tuple((n, direct[n][0].output) for n in others)
        used = {v: direct[states[v].name][0] for v in xs if v != x}
        known = {v: m.inverse for v, m in used.items()}
        at_op = {states[v].symbol: sp.sympify(model.operating_point[states[v].name])
                 .xreplace(values) for v in xs if v != x}
        at_op.update(u_op)
        checked = _monotonic(expr.xreplace(at_op), x, state, model, values)
        if isinstance(checked, str):
            continue
        x0 = float(sp.sympify(model.operating_point[state.name]).xreplace(values))
        gain = float(checked[2](x0))
        sols = closed_form_inverses(expr.xreplace(known), x, o.symbol)
        sols = [sol for sol in sols if _round_trip(sol, expr, x, o.symbol, at_op, used,
                                                   state, model, values)]
        if sols:
            out.setdefault(state.name, []).append(
                SensorMap(o.name, state.name, expr, _guarded_roots(sp.simplify(sols[0])),
                          gain, reads))
    return out


def _round_trip(sol, expr, x, y, at_op, used, state, model, values) -> bool:
    """``sol`` (the state from the output and the other sensors ``used``: state symbol ->
    its direct map) returns the state over its range, the other states at their operating
    values."""
    x0 = float(sp.sympify(model.operating_point[state.name]).xreplace(values))
    lo, hi = state.range if state.range else (x0, x0)
    readings = {sp.Symbol(m.output, real=True): m.forward.xreplace({sym: at_op[sym]})
                .xreplace(values) for sym, m in used.items()}
    readings.update({k: v for k, v in at_op.items() if k in set(model.u)})   # inputs
    try:
        for v in sorted({x0, *np.linspace(float(lo), float(hi), 5).tolist()}):
            yv = expr.xreplace(at_op).xreplace({x: sp.Float(v)}).xreplace(values)
            back = float(sol.xreplace({y: yv, **readings}).xreplace(values))
            if not abs(back - v) <= 1e-9 * max(1.0, abs(v)):
                return False
    except (TypeError, ValueError, ZeroDivisionError):
        return False
    return True
