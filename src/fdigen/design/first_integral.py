r"""A balance that a fault entering two state equations cannot change, when the
weights that cancel it depend on those two states.

A fault ``phi`` entering ``dx_a/dt`` and ``dx_b/dt`` along ``(e_a, e_b)`` is cancelled by
``m = c_a x_a + c_b x_b`` with ``c = (e_b, -e_a)`` when that ratio depends on parameters
and other signals only (:mod:`fdigen.design.decoupling`). Where it depends on ``x_a`` and
``x_b`` themselves, the same physics written in other state variables needs weights that
vary: a mixing tank's brine valve enters the level ``h`` and the concentration ``c`` in
the ratio ``(c1 - c)/h``, which a salt-mass spelling ``M = c A h`` turns into the
constant ``c1``; a hydrophore's pump enters the water level and the air pressure in the
ratio ``(p + p_atm)/(H - h)``, and the air mass ``(p + p_atm)(H - h)`` does not move with
it. Such an ``m(x_a, x_b)`` is a first integral of the fault's direction field,

.. math::

    \frac{\partial m}{\partial x_a} e_a + \frac{\partial m}{\partial x_b} e_b = 0
    \iff m \text{ constant along } \frac{dx_b}{dx_a} = \frac{e_b}{e_a},

found by solving that ordinary differential equation (sympy's ``dsolve``) and reading
its integration constant, and checked symbolically. Its balance ``dm/dt = grad(m) . f``
does not contain the fault.
"""

from __future__ import annotations

import sympy as sp

from fdigen.derive.budget import BudgetExceeded, time_budget

#: CPU seconds the search may spend on one fault (a ratio ``dsolve`` cannot integrate
#: can keep it busy): past it, no balance is built and the refusal says so.
BUDGET = 10.0


def first_integral(ratio: sp.Expr, xa: sp.Symbol, xb: sp.Symbol) -> sp.Expr | None:
    """``m(x_a, x_b)`` constant along ``dx_b/dx_a = ratio`` (``ratio`` in ``x_a``,
    ``x_b`` and parameters), or None when none is found in closed form within
    :data:`BUDGET`."""
    y = sp.Function("_xb")
    C1 = sp.Symbol("C1")
    try:
        with time_budget(BUDGET, "first integral of a fault direction"):
            sol = sp.dsolve(sp.Eq(y(xa).diff(xa), ratio.xreplace({xb: y(xa)})), y(xa))
            for eq in (sol if isinstance(sol, list) else [sol]):
                eq = eq.xreplace({y(xa): xb}) if hasattr(eq, "xreplace") else eq
                consts = [c for c in eq.free_symbols if c.name == "C1"]
                if len(consts) != 1:
                    continue
                for m in sp.solve(eq, consts[0]):
                    m = sp.simplify(m)
                    if m.free_symbols & {xa, xb} and _constant_along(m, ratio, xa, xb):
                        return _without_constant_factor(m.xreplace({consts[0]: C1}), xa, xb)
    except (BudgetExceeded, NotImplementedError, ValueError, TypeError, AttributeError):
        return None
    return None


def _constant_along(m, ratio, xa, xb) -> bool:
    """``dm/dx_a + dm/dx_b * ratio == 0`` identically."""
    try:
        return sp.simplify(sp.diff(m, xa) + sp.diff(m, xb) * ratio) == 0
    except (ValueError, TypeError):
        return False


def _without_constant_factor(m, xa, xb):
    """``m`` with numeric factors and powers of exponentials of constants dropped: any
    function of a first integral is one; the plainest is kept."""
    m = m.rewrite(sp.Pow)                    # exp(k log(b)) as the power b**k
    coeff, rest = sp.factor(m).as_independent(xa, xb, as_Add=False)
    return rest if rest.free_symbols & {xa, xb} else m
