"""The unit of an expression of outputs and parameters, from their declared units.

A derived combination such as ``yb/(c - ya)**2`` or a balance ``AA*pA*xA + ...`` was
labelled "that of the expression (AA: mm^2, pA: bar, ...)": its threshold of 2.12e5 could
not be read as a quantity (a user's hydraulic press and CSTR). Each declared unit is read
as a product of powers of unit names (``"J/(kg K)"``, ``"m^2.5/s"``, ``"mm^2"``), through
the model language's whitelist parser (never ``sympify`` on text), and the expression's
unit follows the rules of dimensional analysis:

.. math:: [a b] = [a][b],\\quad [a^k] = [a]^k,\\quad [a + b] = [a] = [b],\\quad
          [f(a)] = 1 \\text{ for } [a] = 1,

with ``abs`` keeping and ``sign`` dropping its argument's unit; ``degC`` counts as
``K`` (a heat capacity in J/K times a temperature in degC is an energy in J). Anything else (a sum of
different units, a unit the parser cannot read such as ``%``, a function of a quantity
with a unit) has no unit here: :func:`expression_unit` returns None and the caller keeps
its description of the parts.
"""

from __future__ import annotations

import re

import sympy as sp

#: Unit names are given this prefix as symbols (a unit ``s`` is no state ``s``).
_PREFIX = "unit_"


def unit_expr(text: str) -> sp.Expr | None:
    """``text`` (a declared unit) as a product of powers of unit symbols; 1 for ``""``,
    ``"1"`` or ``"-"``; None when it cannot be read."""
    from fdigen.model.expression import parse_expression

    text = (text or "").strip()
    if text in ("", "1", "-"):
        return sp.Integer(1)
    text = re.sub(r"\bdegC\b", "K", text)   # a difference or a weight per kelvin: J/K*degC is J
    names = sorted(set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", text)))
    spelled = re.sub(r"(?<=[\w)])\s+(?=[\w(])", "*", text).replace("^", "**")
    for name in sorted(names, key=len, reverse=True):
        spelled = re.sub(rf"\b{name}\b", _PREFIX + name, spelled)
    try:
        return parse_expression(spelled, {_PREFIX + n: sp.Symbol(_PREFIX + n, positive=True)
                                          for n in names}, source="unit", field="unit")
    except Exception:  # noqa: BLE001 - a unit the parser cannot read has no algebra
        return None


def expression_unit(expr: sp.Expr, units: dict) -> str | None:
    """The unit of ``expr`` from ``units`` (symbol -> declared unit text), printed as
    ``"K*m^3"``; ``"1"`` for a pure number; None when it has none (see the module)."""
    known = {}
    for sym, text in units.items():
        u = unit_expr(text)
        if u is not None:
            known[sym] = u
    u = _unit_of(expr, known)
    if u is None:
        return None
    u = sp.powsimp(sp.simplify(u), force=True)
    if u == 1:
        return "1"
    return sp.sstr(u).replace("**", "^").replace(_PREFIX, "")


def _unit_of(expr, known):
    if expr.is_Number or expr.is_NumberSymbol:
        return sp.Integer(1)
    if expr.is_Symbol:
        return known.get(expr)
    if expr.is_Add:
        parts = [_unit_of(a, known) for a in expr.args]
        if any(p is None for p in parts):
            return None
        first = parts[0]
        return first if all(sp.simplify(p / first) == 1 for p in parts[1:]) else None
    if expr.is_Mul:
        out = sp.Integer(1)
        for a in expr.args:
            p = _unit_of(a, known)
            if p is None:
                return None
            out = out * p
        return out
    if expr.is_Pow:
        base = _unit_of(expr.base, known)
        if base is None:
            return None
        if expr.exp.is_Number:
            return base ** expr.exp
        # a symbolic power (T^(C/(rho V cp))): only of a pure number, by a pure number
        return sp.Integer(1) if base == 1 and _unit_of(expr.exp, known) == 1 else None
    if isinstance(expr, sp.Abs):
        return _unit_of(expr.args[0], known)
    if isinstance(expr, sp.sign):
        return sp.Integer(1)
    if isinstance(expr, (sp.Max, sp.Min)):
        return _unit_of(sp.Add(*expr.args), known)
    if isinstance(expr, sp.Function):
        return sp.Integer(1) if all(_unit_of(a, known) == 1 for a in expr.args) else None
    return None
