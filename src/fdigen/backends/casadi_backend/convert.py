"""sympy -> CasADi SX, node by node, in the evaluation order of the reference backend.

The converter walks sympy's expression tree (never ``sympy.lambdify`` or string
evaluation) and builds one :class:`casadi.SX` per node, memoised on sub-expressions.
Sums and products are associated exactly as the printer behind the reference backend
(:func:`sympy.lambdify` with the numpy printer) writes them: the terms of an ``Add`` in
``as_ordered_terms`` order folded from the left, the factors of a ``Mul`` split into a
numerator and a denominator in ``as_ordered_factors`` order (``a*b*c/(d*e)``). Floating
point addition and multiplication are not associative, so this keeps the CasADi results
equal to the reference to the last bit for everything but the ``pow`` calls (see
:func:`sympy_to_casadi`).
"""

from __future__ import annotations

import math
from contextlib import contextmanager

import casadi as ca
import sympy as sp
from sympy.core.function import Application
from sympy.core.mul import _keep_coeff
from sympy.logic.boolalg import BooleanFalse, BooleanTrue

from fdigen.errors import BuildError

#: sympy function class name -> CasADi builder (one argument).
_UNARY = {
    "exp": ca.exp,
    "log": ca.log,
    "sin": ca.sin,
    "cos": ca.cos,
    "tan": ca.tan,
    "asin": ca.asin,
    "acos": ca.acos,
    "atan": ca.atan,
    "sinh": ca.sinh,
    "cosh": ca.cosh,
    "tanh": ca.tanh,
    "Abs": ca.fabs,
    "sign": ca.sign,
}

#: sympy relational class name -> CasADi comparison.
_RELATIONAL = {
    "StrictLessThan": lambda a, b: a < b,
    "LessThan": lambda a, b: a <= b,
    "StrictGreaterThan": lambda a, b: a > b,
    "GreaterThan": lambda a, b: a >= b,
    "Equality": lambda a, b: a == b,
    "Unequality": lambda a, b: a != b,
}


@contextmanager
def literal_sx():
    """Build SX expressions exactly as written: CasADi's on-the-fly simplification off.

    CasADi simplifies while building SX (``x*(1/y) -> x/y``, ``x**2 -> sq(x)``,
    ``x*1 -> x``...). Some of these rewrites change the rounding, so every SX graph meant
    to reproduce the reference is built inside this context (the previous setting is
    restored on exit). The option is process-global: do not build CasADi expressions
    concurrently in other threads meanwhile.
    """
    previous = ca.GlobalOptions.getSimplificationOnTheFly()
    ca.GlobalOptions.setSimplificationOnTheFly(False)
    try:
        yield
    finally:
        ca.GlobalOptions.setSimplificationOnTheFly(previous)


def supported_functions() -> tuple[str, ...]:
    """Names of the sympy functions :func:`sympy_to_casadi` converts.

    Returns
    -------
    tuple of str
        sympy class names (``"Abs"``, ``"atan2"``, ``"Min"``...), sorted.
    """
    return tuple(sorted(set(_UNARY) | {"atan2", "Min", "Max", "Piecewise", "sqrt"}))


def sympy_to_casadi(expr, mapping: dict, *, memo: dict | None = None) -> ca.SX:
    """Convert a sympy expression into a scalar CasADi ``SX`` expression.

    Parameters
    ----------
    expr : sympy.Expr or sympy.logic.boolalg.Boolean or number
        The expression. Supported nodes: ``Add``, ``Mul``, ``Pow`` (``1/2`` and ``-1/2``
        powers become ``sqrt``, ``-1`` a division), numbers (``Float``, ``Integer``,
        ``Rational``, ``pi``...), symbols, the functions ``sqrt exp log sin cos tan asin
        acos atan atan2 sinh cosh tanh Abs sign Min Max``, ``Piecewise`` (nested
        ``if_else``, ``nan`` where no condition holds), relationals, ``And``/``Or``/
        ``Not`` and ``true``/``false`` (as 1/0).
    mapping : dict of sympy.Symbol to casadi.SX
        The CasADi value of every free symbol. Not modified.
    memo : dict, optional
        Conversion cache shared between calls (sub-expression -> SX). Pass the same dict
        when converting several expressions over the same ``mapping`` (or a mapping that
        only grows) so that common sub-expressions become one SX node.

    Returns
    -------
    casadi.SX
        A 1x1 SX.

    Raises
    ------
    BuildError
        If the expression holds an unsupported function or node (the message names it),
        a symbol missing from ``mapping``, or a non-real constant.

    Notes
    -----
    ``Min``/``Max`` follow ``numpy.minimum``/``numpy.maximum`` folded over the arguments
    in order (as the reference prints them): a NaN argument gives NaN, unlike C's
    ``fmin``/``fmax``. ``Piecewise`` takes the first piece whose condition holds, like
    ``numpy.select``.

    Constants are converted with ``float(expr)`` (the nearest double). Operations are
    associated like the reference backend's printer and built with CasADi's on-the-fly
    simplification off (:func:`literal_sx`), so the results equal numpy's evaluation of
    the printed expression bit for bit. Powers follow numpy's array fast paths: ``x**2``
    is ``x*x`` (``sq``), ``x**-1`` is ``1/x``, ``x**(1/2)`` is ``sqrt(x)``, every other
    constant power calls ``pow``. (numpy *scalars* call the C library's ``pow`` for
    ``x**2`` and ``x**-1.0`` too, which is not always correctly rounded: there the two may
    differ by one unit in the last place.)
    """
    conv = _Converter(mapping, {} if memo is None else memo)
    try:
        with literal_sx():
            return conv(sp.sympify(expr))
    except RecursionError:
        raise BuildError("expression too deeply nested to convert to CasADi") from None


class _Converter:
    def __init__(self, mapping, memo):
        self.mapping = mapping
        self.memo = memo

    def __call__(self, expr) -> ca.SX:
        try:
            return self.memo[expr]
        except KeyError:
            pass
        except TypeError:  # unhashable: should not happen with sympy objects
            return self._convert(expr)
        value = self._convert(expr)
        self.memo[expr] = value
        return value

    # -- dispatch -------------------------------------------------------------------------
    def _convert(self, expr) -> ca.SX:
        if isinstance(expr, (BooleanTrue, BooleanFalse)):
            return ca.SX(1.0 if isinstance(expr, BooleanTrue) else 0.0)
        if expr.is_Symbol:
            try:
                value = self.mapping[expr]
            except KeyError:
                raise BuildError(f"symbol '{expr}' has no CasADi value") from None
            return ca.SX(value)
        if expr.is_Number or isinstance(expr, sp.NumberSymbol):
            return self._number(expr)
        if expr.is_Add:
            return self._add(expr)
        if expr.is_Mul:
            return self._mul(expr)
        if expr.is_Pow:
            return self._pow(expr)
        if isinstance(expr, sp.Piecewise):
            return self._piecewise(expr)
        if expr.is_Relational:
            name = type(expr).__name__
            if name not in _RELATIONAL:
                raise BuildError(f"unsupported relational '{name}' in CasADi conversion")
            return _RELATIONAL[name](self(expr.lhs), self(expr.rhs))
        if isinstance(expr, sp.And):
            return _fold(ca.logic_and, [self(a) for a in expr.args])
        if isinstance(expr, sp.Or):
            return _fold(ca.logic_or, [self(a) for a in expr.args])
        if isinstance(expr, sp.Not):
            return ca.logic_not(self(expr.args[0]))
        if isinstance(expr, (sp.Function, sp.Min, sp.Max, Application)):
            return self._function(expr)
        raise BuildError(f"unsupported expression node '{type(expr).__name__}' "
                         f"in CasADi conversion: {expr}")

    def _number(self, expr) -> ca.SX:
        try:
            value = float(expr)
        except (TypeError, ValueError):
            raise BuildError(f"constant '{expr}' is not a real number") from None
        return ca.SX(value)

    def _add(self, expr) -> ca.SX:
        # StrPrinter._print_Add: ordered terms, a leading '-' becomes a subtraction.
        terms = expr.as_ordered_terms()
        acc = self(terms[0])
        for term in terms[1:]:
            neg = _negated(term)
            acc = acc - self(neg) if neg is not None else acc + self(term)
        return acc

    def _mul(self, expr) -> ca.SX:
        # CodePrinter._print_Mul: sign, numerator a*b*c, denominator / d or /(d*e).
        neg = _negated(expr)
        if neg is not None and neg != expr:
            return -self._mul_body(neg)
        return self._mul_body(expr)

    def _mul_body(self, expr) -> ca.SX:
        num, den = [], []
        for item in expr.as_ordered_factors():
            if (item.is_commutative and item.is_Pow and item.exp.is_Rational
                    and item.exp.is_negative):
                den.append(item.base if item.exp == -1
                           else sp.Pow(item.base, -item.exp, evaluate=False))
            else:
                num.append(item)
        acc = _fold(lambda a, b: a * b, [self(a) for a in num]) if num else ca.SX(1.0)
        if den:
            acc = acc / _fold(lambda a, b: a * b, [self(b) for b in den])
        return acc

    def _pow(self, expr) -> ca.SX:
        base, exp = expr.base, expr.exp
        if exp == sp.S.Half:
            return ca.sqrt(self(base))
        if exp == -sp.S.Half:
            return 1.0 / ca.sqrt(self(base))
        if exp == -1:
            return 1.0 / self(base)
        if exp == 2:
            b = self(base)
            return b * b
        if exp.is_Rational or exp.is_Float:
            return ca.constpow(self(base), float(exp))
        return ca.power(self(base), self(exp))

    def _piecewise(self, expr) -> ca.SX:
        acc = ca.SX(math.nan)
        for piece in reversed(expr.args):
            cond = piece.cond
            if isinstance(cond, BooleanTrue):
                acc = self(piece.expr)
            elif isinstance(cond, BooleanFalse):
                continue
            else:
                acc = ca.if_else(self(cond), self(piece.expr), acc)
        return acc

    def _function(self, expr) -> ca.SX:
        name = type(expr).__name__
        args = expr.args
        if name in _UNARY and len(args) == 1:
            return _UNARY[name](self(args[0]))
        if name == "atan2" and len(args) == 2:
            return ca.atan2(self(args[0]), self(args[1]))
        if name in ("Min", "Max"):
            op = _minimum if name == "Min" else _maximum
            return _fold(op, [self(a) for a in args])
        raise BuildError(f"unsupported function '{name}' in CasADi conversion "
                         f"(supported: {', '.join(supported_functions())}): {expr}")


def _negated(expr):
    """``-expr`` as the printer writes it when ``expr`` prints with a leading minus,
    else ``None``."""
    if expr.is_Number:
        return -expr if expr.is_extended_negative else None
    if expr.is_Mul:
        c, rest = expr.as_coeff_Mul()
        if c < 0:
            return _keep_coeff(-c, rest)
    return None


def _maximum(a, b):
    """numpy.maximum: ``a`` if ``a > b`` or ``a`` is NaN, else ``b`` (NaN propagates)."""
    return ca.if_else(ca.logic_or(a > b, a != a), a, b)


def _minimum(a, b):
    """numpy.minimum: ``a`` if ``a < b`` or ``a`` is NaN, else ``b`` (NaN propagates)."""
    return ca.if_else(ca.logic_or(a < b, a != a), a, b)


def _fold(op, items):
    acc = items[0]
    for item in items[1:]:
        acc = op(acc, item)
    return acc
