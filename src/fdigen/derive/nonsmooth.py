"""Derivatives of non-smooth functions: no impulses in a Jacobian.

sympy differentiates ``sign(v)`` to ``2 DiracDelta(v)``, ``Heaviside(v)`` (from ``min`` /
``max`` and ``Piecewise``) to ``DiracDelta(v)``, ``Abs(v)`` to ``sign(v)``. An impulse is
zero everywhere but on a set of measure zero, it has no numeric value (``lambdify``
raises ``NameError: DiracDelta``, ``float`` fails at ``v = 0``) and no backend prints it.
A Jacobian used numerically (linearisation, stiffness, scheduling) therefore takes the
derivative almost everywhere:

.. math:: \\frac{d}{dv}\\,\\mathrm{sign}(v) = 0,\\qquad
          \\frac{d}{dv}\\,H(v) = 0 \\quad (v \\ne 0),

which :func:`drop_impulses` applies (``DiracDelta`` and its derivatives replaced by 0).
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


def jacobian(f: sp.Matrix, x) -> sp.Matrix:
    """``df/dx`` taken almost everywhere (impulses of ``sign``/``Heaviside`` dropped)."""
    return drop_impulses(sp.Matrix(f).jacobian(x))
