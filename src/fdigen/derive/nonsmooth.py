r"""Derivatives of non-smooth functions: no impulses in a Jacobian.

sympy differentiates ``sign(v)`` to ``2 DiracDelta(v)``, ``Heaviside(v)`` (from ``min`` /
``max`` and ``Piecewise``) to ``DiracDelta(v)``, ``Abs(v)`` to ``sign(v)``. An impulse is
zero everywhere but on a set of measure zero, it has no numeric value (``lambdify``
raises ``NameError: DiracDelta``, ``float`` fails at ``v = 0``) and no backend prints it.
A Jacobian used numerically (linearisation, stiffness, scheduling) therefore takes the
derivative almost everywhere:

.. math:: \\frac{d}{dv}\\,\\mathrm{sign}(v) = 0,\\qquad
          \\frac{d}{dv}\\,H(v) = 0 \\quad (v \\ne 0),

which :func:`drop_impulses` applies (``DiracDelta`` and its derivatives replaced by 0).

sympy differentiates ``sign``, ``Abs`` and ``Heaviside`` only when it can prove the argument
real; an argument it cannot (``h1 - y2/kv``: ``kv`` might be 0, so ``y2/kv`` might be
``zoo``, as a scaled sensor map's inverse substituted into a sub-model gives) is left as an
unevaluated ``Derivative(sign(h1 - y2/kv), phi)``, which has no value either and makes
``xreplace({phi: 0})`` raise "Can't calculate derivative wrt 0". Every model quantity is
real, so :func:`derivative` and :func:`jacobian` differentiate these functions by their
real, almost-everywhere rules whatever sympy can prove:

.. math:: \frac{d}{dx}\,|g| = \mathrm{sign}(g)\,\frac{dg}{dx},\qquad
          \frac{d}{dx}\,\mathrm{sign}(g) = \frac{d}{dx}\,H(g) = 0 .
The equivalent gain of a switch over the operating range is
:func:`fdigen.derive.linearisation.equivalent_linear`'s business; this module only makes
sure what remains can be evaluated.
"""

from __future__ import annotations

import sympy as sp


def drop_impulses(expr):
    """``expr`` (expression or matrix) with every ``DiracDelta(...)`` replaced by 0."""
    if isinstance(expr, sp.MatrixBase):
        return expr.applyfunc(drop_impulses)
    expr = sp.sympify(expr)
    if not expr.has(sp.DiracDelta):
        return expr
    return expr.replace(lambda e: isinstance(e, sp.DiracDelta), lambda e: sp.Integer(0))


class _RealAbs(sp.Function):
    """``Abs`` of a real argument: ``d|g| = sign(g) dg``."""

    is_extended_real = True

    def fdiff(self, argindex=1):
        return sp.sign(self.args[0])


class _RealStep(sp.Function):
    """``sign`` or ``Heaviside`` of a real argument: derivative 0 almost everywhere."""

    is_extended_real = True

    def fdiff(self, argindex=1):
        return sp.Integer(0)


class _RealSign(_RealStep):
    nargs = 1


class _RealHeaviside(_RealStep):
    nargs = (1, 2)


_REAL = {sp.Abs: _RealAbs, sp.sign: _RealSign, sp.Heaviside: _RealHeaviside}
_BACK = {_RealAbs: sp.Abs, _RealSign: sp.sign, _RealHeaviside: sp.Heaviside}


def _swap(expr, table):
    """``expr`` with every function of ``table``'s keys rebuilt as its value."""
    if not expr.has(*table):
        return expr
    return expr.replace(lambda e: getattr(e, "func", None) in table,
                        lambda e: table[e.func](*e.args))


def derivative(expr, v):
    """``d expr / d v`` taken almost everywhere, for real arguments of ``Abs``, ``sign``
    and ``Heaviside`` whether or not sympy can prove them real (see module docstring)."""
    return drop_impulses(_swap(sp.diff(_swap(sp.sympify(expr), _REAL), v), _BACK))


def jacobian(f: sp.Matrix, x) -> sp.Matrix:
    """``df/dx`` taken almost everywhere (impulses of ``sign``/``Heaviside`` dropped,
    ``Abs``/``sign``/``Heaviside`` differentiated as functions of a real argument)."""
    f = [_swap(e, _REAL) for e in sp.Matrix(f)]   # a row or a column, as Matrix.jacobian
    x = list(x)
    return drop_impulses(sp.Matrix(len(f), len(x),
                                   lambda i, j: _swap(sp.diff(f[i], x[j]), _BACK)))
