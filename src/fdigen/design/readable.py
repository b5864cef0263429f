"""Symbolic matrices as a reader wants them: no ``DiracDelta``, no ``Piecewise`` of NaN.

Jacobians of models written with ``sign`` and ``abs`` (Torricelli flows, dry friction)
hold ``d sign(x)/dx = 2 DiracDelta(x)``, which is 0 almost everywhere, and ``Piecewise``
guards ``(nan, x == x0), (e, True)`` where ``abs`` is not differentiable. For printing,
the delta terms are dropped (0 almost everywhere), the guards reduced to their general
piece ``e``, and numbers shown with a few significant digits. The design itself never
uses these forms: it evaluates the Jacobians numerically away from the kinks.
"""

from __future__ import annotations

import sympy as sp

from fdigen.model.expression import expression_text


def almost_everywhere(expr: sp.Expr) -> sp.Expr:
    """``expr`` with ``DiracDelta`` terms set to 0 and ``Piecewise`` guards that hold only on
    equalities (``x == x0``: NaN or 0 at a kink of ``abs``) reduced to the general piece.

    .. math:: \\frac{d}{dx}\\,\\mathrm{sign}(x) = 2\\,\\delta(x) = 0 \\quad (x \\ne 0)
    """
    expr = sp.sympify(expr)
    if expr.has(sp.DiracDelta):
        expr = expr.replace(lambda e: isinstance(e, sp.DiracDelta), lambda e: sp.Integer(0))
    if expr.has(sp.Piecewise):
        def general(pw):
            # pieces guarded by equalities hold on a set of measure zero (the kinks)
            last = pw.args[-1]
            if last.cond == True and all(_on_kink(p.cond) for p in pw.args[:-1]):  # noqa: E712
                return last.expr
            return pw
        expr = expr.replace(lambda e: isinstance(e, sp.Piecewise), general)
    return expr


def _on_kink(cond) -> bool:
    """Whether a Piecewise condition is an equality (or a disjunction of them)."""
    if isinstance(cond, sp.Eq):
        return True
    return isinstance(cond, sp.Or) and all(isinstance(a, sp.Eq) for a in cond.args)


def readable(expr, digits: int = 5) -> str:
    """Text of ``expr`` after :func:`almost_everywhere`: ``sign(x)**2 = 1`` (``x != 0``),
    long rationals (operating-point values) shown as ``digits``-digit decimals."""
    e = almost_everywhere(expr)
    if e.has(sp.sign):
        e = e.replace(lambda x: x.is_Pow and isinstance(x.base, sp.sign)
                      and x.exp.is_integer and x.exp.is_even, lambda x: sp.Integer(1))
    e = e.replace(lambda x: x.is_Rational and not x.is_Integer and abs(x.q) > 1000,
                  lambda x: sp.Float(x, digits))
    # a number's fractional power (2**(23/216)*3**(143/216), a user's drone: an exponent
    # of 5.25588 in its barometer, rationalised) is a number too
    e = e.replace(lambda x: x.is_Pow and x.base.is_Number and x.exp.is_Rational
                  and not x.exp.is_Integer, lambda x: sp.Float(x.evalf(digits + 2), digits))
    try:
        e = sp.factor_terms(e)
    except (sp.PolynomialError, TypeError, ValueError):
        pass
    return expression_text(e)


def readable_matrix(mat, digits: int = 5) -> list[list[str]]:
    """Each entry of a sympy matrix through :func:`readable`."""
    mat = sp.Matrix(mat)
    return [[readable(mat[i, j], digits) for j in range(mat.cols)] for i in range(mat.rows)]
