"""Physical sanity of a model at its operating point, checked when the file is read.

A model whose equations cannot be evaluated where it is linearised (``log(-V)``, the
square root of a negative number, a zero denominator), whose state limits are reversed
or not finite, or whose operating point lies outside the state limits, is refused with
an error naming the equation, instead of failing deep in the derivation ("Cannot convert
complex to float") or, worse, building.
"""

from __future__ import annotations

import math

import sympy as sp

from fdigen.errors import ModelFileError
from fdigen.model.model import Model


def numeric_value(expr, subs) -> float | None:
    """The real value of ``expr`` under ``subs``, or ``None`` when it is not a finite real
    number (complex, infinite, NaN, or still symbolic).

    Parameters
    ----------
    expr : sympy.Expr
    subs : dict of sympy.Symbol to sympy.Number
    """
    value = sp.sympify(expr).xreplace(subs)
    if value.has(sp.zoo, sp.nan, sp.oo, -sp.oo) or value.free_symbols:
        return None
    try:
        c = complex(value.evalf(30))
    except (TypeError, ValueError, OverflowError):
        return None
    if not (math.isfinite(c.real) and math.isfinite(c.imag)):
        return None
    if c.imag != 0.0 and abs(c.imag) > 1e-12 * max(1.0, abs(c.real)):
        return None
    return c.real


def check_physical_sanity(model: Model) -> None:
    """Check the state limits, the operating point and every equation of ``model``.

    * every state's ``limits`` evaluate (at the parameter values) to finite reals with
      ``low < high``;
    * the operating point lies within the limits, ``low <= x_op <= high``;
    * every definition, state derivative, output and fault term evaluates to a finite
      real number at the operating point ``f(x_op, u_op, p)`` (fault terms with every
      fault at 0 and at its ``test_size``).

    Raises
    ------
    ModelFileError
        Naming the file, the field (``dynamics.Pp``, ``states.x.limits``...) and the value.
    """
    src = model.source
    subs = {q.symbol: sp.Float(q.value, 17) for q in model.parameters}
    for s in model.states:
        if s.limits is None:
            continue
        fld = f"states.{s.name}.limits"
        lo, hi = (numeric_value(b, subs) for b in s.limits)
        if lo is None or hi is None:
            raise ModelFileError("limits are not finite real numbers at the parameter values",
                                 src, fld, s.name)
        if not lo < hi:
            raise ModelFileError(f"limits reversed or empty: low {lo:g} >= high {hi:g}", src,
                                 fld, s.name)
        op = model.operating_point.get(s.name)
        if op is not None and not lo <= op <= hi:
            raise ModelFileError(f"operating point {op:g} outside the limits "
                                 f"[{lo:g}, {hi:g}]", src, f"operating_point.{s.name}", s.name)
    point = {v.symbol: sp.Float(model.operating_point[v.name], 17)
             for v in (*model.states, *model.inputs) if v.name in model.operating_point}
    subs.update(point)
    where = ", ".join(f"{k} = {v:g}" for k, v in sorted(model.operating_point.items()))

    def check(expr, fld, values):
        if numeric_value(expr, values) is None:
            raise ModelFileError(
                "not a finite real number at the operating point (" + where + "): a "
                "logarithm or square root of a negative number, a zero denominator...",
                src, fld)

    zero = {f.symbol: sp.Integer(0) for f in model.faults}
    subs.update(zero)  # fault symbols may appear in definitions: healthy there
    for name, expr in model.definitions:
        check(expr, f"definitions.{name}", subs)
        subs[sp.Symbol(name, real=True)] = sp.Float(numeric_value(expr, subs), 17)
    for s, expr in zip(model.states, model.dynamics):
        check(expr, f"dynamics.{s.name}", subs)
    for o in model.outputs:
        check(o.expr, f"outputs.{o.name}.expr", subs)
    for f in model.faults:
        for k, (_, term) in enumerate(f.terms):
            if term is None:
                continue
            fld = f"faults.{f.name}.term" if len(f.terms) == 1 else f"faults.{f.name}.terms[{k}]"
            check(term, fld, subs)
            check(term, fld, {**subs, f.symbol: sp.Float(f.test_size, 17)})
