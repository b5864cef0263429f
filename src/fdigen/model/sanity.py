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
from fdigen.model.numbers import DOUBLE_MAX


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




def overflowing_term(expr, values, limit: float):
    """The first exponential or power in ``expr`` whose value under ``values``
    (evaluated with 30 digits, no exponent limit) exceeds ``limit`` in magnitude, and that
    value, or ``None``: a term a backend computing in double (``limit`` ``DBL_MAX``) or
    float reads as infinity, though the whole expression may be finite
    (``1e-300*cosh(700*Ra) - 1e-300*sinh(700*Ra)``: inf - inf, NaN in every backend,
    attack round 8)."""
    for node in sp.preorder_traversal(sp.sympify(expr)):
        if not _may_overflow(node):
            continue
        value = node.xreplace(values)
        if value.free_symbols:
            continue
        mag = sp.Abs(value.evalf(30))
        if mag.is_number and mag.is_finite and mag > limit:
            return node, sp.Float(mag, 3)     # printed as 1.26e+304, never inf
    return None


def _may_overflow(node) -> bool:
    """An exponential, a hyperbolic function, or a power other than a small constant one
    (squares, square roots and the like cannot take a number in a model file's range past
    a double's); the other terms are not evaluated (a model file loads in its time)."""
    if isinstance(node, (sp.exp, sp.cosh, sp.sinh)):
        return True
    if isinstance(node, sp.Pow):
        e = node.exp
        return not (e.is_Number and abs(e) <= 2)
    return False


def check_terms_in_range(model: Model, expr, values, fld: str, limit: float,
                         where: str) -> None:
    """Refuse (naming ``fld``) an equation ``expr`` with a term beyond ``limit`` at the
    operating point (:func:`overflowing_term`): the double of every backend
    (:func:`check_physical_sanity`) or a C float (the float variant)."""
    big = overflowing_term(expr, values, limit)
    if big is not None:
        raise ModelFileError(
            f"the term {big[0]} is {big[1]} at the operating point, beyond the range of "
            f"{where} ({limit:.4g}): it reads infinity there and the residuals NaN, "
            "although the equation as a whole may be finite; write it so that its terms "
            "stay in range (cosh(a) - sinh(a) = exp(-a)), or rescale the units",
            model.source, fld)


def equation_terms(model: Model):
    """``(field, expression)`` of every equation of ``model``: definitions, dynamics and
    outputs (fault terms inside them at zero)."""
    for name, expr in model.definitions:
        yield f"definitions.{name}", expr
    for s, expr in zip(model.states, model.dynamics):
        yield f"dynamics.{s.name}", expr
    for o in model.outputs:
        yield f"outputs.{o.name}.expr", o.expr


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
        check_terms_in_range(model, expr, values, fld, DOUBLE_MAX,
                             "a double, in which every backend computes it")

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


def check_controllers(model: Model) -> None:
    """Every controller of ``[simulation]`` reads a finite real measurement (and gives a
    finite command) at the operating point, with its reference at ``t = 0``; an on/off
    controller's levels lie in its input's range.

    A thermostat reading ``log(R_T - 1000)`` was NaN at every sample: it never switched,
    the tank cooled for four hours and ``tune`` designed thresholds on that dead loop; a
    measurement dividing by a parameter's zero ended in "unsupported expression node
    'ComplexInfinity'" naming nothing (attack round 9).

    Raises
    ------
    ModelFileError
        Naming the controller's field.
    """
    if not model.simulation:
        return
    from fdigen.model.simulation_spec import simulation_spec

    spec = simulation_spec(model)
    values = {q.symbol: sp.Float(q.value, 17) for q in model.parameters}
    point = {v.symbol: sp.Float(model.operating_point[v.name], 17)
             for v in (*model.states, *model.inputs)}
    zero = {f.symbol: sp.Integer(0) for f in model.faults}
    h = model.h()
    y_op = {o.symbol: h[k].xreplace(point).xreplace(values).xreplace(zero)
            for k, o in enumerate(model.outputs)}
    t = sp.Symbol("t", real=True)
    ranges = {v.name: v.range for v in model.inputs}
    for c in spec.controllers:
        fld = ("simulation.controller" if spec.legacy
               else f"simulation.controllers.{c.name}")
        ref = sp.Integer(0)
        if c.reference is not None:
            from fdigen.model.expression import parse_expression

            ref = parse_expression(c.reference, {"t": t, "pi": sp.pi}, source=model.source,
                                   field=fld + ".reference").xreplace({t: sp.Integer(0)})
            if numeric_value(ref, {}) is None:
                raise ModelFileError("the reference is not a finite real number at t = 0",
                                     model.source, fld + ".reference")
        if c.kind == "expression":
            expr = c.law.xreplace({sp.Symbol(c.reference_symbol, real=True): ref})
            what = ".law" if not spec.legacy else ""
        else:
            expr, what = c.measurement, ".measurement"
        if numeric_value(expr, {**y_op, **values}) is None:
            raise ModelFileError(
                "not a finite real number at the operating point, where the outputs read "
                + ", ".join(f"{o.name} = {float(y_op[o.symbol]):.6g}" for o in model.outputs)
                + ": the controller would read NaN at every sample (a log or sqrt of a "
                "negative number, a zero denominator)", model.source, fld + what)
        if c.kind == "onoff" and ranges.get(c.input):
            lo, hi = (float(v) for v in ranges[c.input])
            if not all(lo <= v <= hi for v in c.levels):
                raise ModelFileError(
                    f"levels {list(c.levels)} leave the range [{lo:g}, {hi:g}] of input "
                    f"{c.input}: the command would be one the design was never derived "
                    "for", model.source, fld + ".levels")
