"""Parameter-only coefficients lifted out of the model's right-hand sides.

Holds :class:`DerivedParameters` (each parameter-only coefficient one named assignment of
the program, computed once per step) and :func:`rational_form` (a right-hand side as one
quotient whose coefficients are such derived parameters: one division per derivative).
"""

from __future__ import annotations

import sympy as sp

from fdigen.design.symbolic import double


class DerivedParameters:
    """Parameter-only coefficients of the step, each one named assignment of the program.

    ``coefficient(c)`` returns ``c`` itself when it is a number or a (negated) parameter,
    else the symbol ``dp<k>`` of an assignment ``dp<k> = c`` added once to the program
    (``-c`` reuses the symbol of ``c``). Every backend evaluates these assignments as any
    other (the same operations, so the same bits); the C compiler computes them once per
    step instead of once per use, and turns no division by a parameter into a repeated one.

    Parameters
    ----------
    assign : callable
        ``assign(name, expr) -> Symbol`` of the program being built.
    """

    def __init__(self, assign):
        self._assign = assign
        self._symbols = {}

    def coefficient(self, c):
        """``c`` (parameter-only) as a number, a signed parameter or a derived symbol."""
        c = sp.sympify(c)
        if c.is_Number:
            return c if c.is_Integer or c.is_Float else double(c)
        if c.could_extract_minus_sign():
            return -self.coefficient(-c)
        if c.is_Symbol:
            return c
        if c not in self._symbols:
            self._symbols[c] = self._assign(f"dp{len(self._symbols)}", c)
        return self._symbols[c]


def rational_form(expr, params: set, derived: DerivedParameters):
    r"""A right-hand side as one quotient with parameter-only coefficients lifted out.

    .. math::

        f = \frac{\sum_j c_j\, m_j}{\sum_l e_l\, n_l}

    where the monomials ``m_j``, ``n_l`` hold the non-parameter symbols (states, inputs,
    drivers) and the coefficients ``c_j``, ``e_l`` only parameters (each a number, a
    parameter or a :class:`DerivedParameters` symbol; terms with coefficients equal up to
    sign share one product, ``c (m_1 - m_2)``). For the pneumatic chamber,
    ``-A gamma Pp xdot/V + K R Ts gamma v/V`` becomes ``(dp1 v - dp0 Pp xdot)/V``: one
    division instead of two, no product of parameters repeated per RK4 stage. An
    expression with functions (``sqrt``, ``Min``, ``Piecewise``...) is returned as is.

    Parameters
    ----------
    expr : sympy.Expr
    params : set of sympy.Symbol
        The model's parameters.
    derived : DerivedParameters

    Returns
    -------
    sympy.Expr
        Equal to ``expr`` in exact arithmetic.
    """
    if expr.atoms(sp.Function, sp.Piecewise) or not expr.free_symbols - params:
        return expr
    gens = tuple(sorted(expr.free_symbols - params, key=str))
    num, den = sp.fraction(sp.together(expr))
    if not num.atoms(sp.Float):
        num = sp.factor(num)
    if not den.atoms(sp.Float):
        den = sp.factor(den)
    c_num, rest_num = num.as_independent(*gens, as_Add=False)
    c_den, rest_den = den.as_independent(*gens, as_Add=False)
    scale = c_num / c_den
    if rest_num.is_Add:
        top = _collected(rest_num, scale, gens, derived)
    else:
        top = derived.coefficient(scale) * rest_num
    if rest_den == 1:
        return top
    bottom = _collected(rest_den, sp.Integer(1), gens, derived) if rest_den.is_Add else rest_den
    return top / bottom


def _collected(expr, scale, gens, derived):
    """``scale * expr`` as a sum over the monomials of ``expr`` in ``gens``, each with its
    parameter-only coefficient; monomials whose coefficients agree up to sign share one."""
    by_monomial = {}
    for term in sp.Add.make_args(sp.expand(expr)):
        coeff, mono = term.as_independent(*gens, as_Add=False)
        by_monomial[mono] = by_monomial.get(mono, 0) + coeff * scale
    groups = {}
    for mono, coeff in by_monomial.items():
        coeff = sp.factor(coeff) if not coeff.atoms(sp.Float) else coeff
        if coeff == 0:
            continue
        sign = -1 if coeff.could_extract_minus_sign() else 1
        groups.setdefault(sign * coeff, []).append((sign, mono))
    out = sp.Integer(0)
    for coeff, members in groups.items():
        c = derived.coefficient(coeff)
        if len(members) == 1 or c.is_Number:
            out += sum((sign * c * mono for sign, mono in members), sp.Integer(0))
        else:
            out += c * sp.Add(*[sign * mono for sign, mono in members])
    return out
