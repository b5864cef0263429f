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
    \iff m \text{ constant along } \frac{dx_b}{dx_a} = s(x_a, x_b) = \frac{e_b}{e_a}.

Two forms of ``s`` are integrated, the forms mass and energy balances take:

* separable, ``s = c g(x_a) h(x_b)``: :math:`m = \int dx_b / h - c \int g\, dx_a`;
* linear in ``x_b``, ``s = a(x_a) x_b + b(x_a)``: with :math:`\mu = e^{-\int a\, dx_a}`,
  :math:`m = \mu x_b - \int \mu b\, dx_a`.

Each integral must come out in closed form (no ``Integral`` left, no case split), within
:data:`BUDGET` CPU seconds, and the result is checked symbolically. The search is by
form, not by a general ODE solver under a clock: a solver that ran 6-10 s against its
budget made one file derive two designs depending on the machine's load (attack round 5).
"""

from __future__ import annotations

import functools

import sympy as sp

from fdigen.derive.budget import BudgetExceeded, time_budget

#: CPU seconds the integrals of one fault's direction may take (a pathological integrand
#: only; the balances of mass and energy integrate in milliseconds).
BUDGET = 10.0


@functools.lru_cache(maxsize=256)
def first_integral(ratio: sp.Expr, xa: sp.Symbol, xb: sp.Symbol) -> sp.Expr | None:
    """``m(x_a, x_b)`` constant along ``dx_b/dx_a = ratio`` (``ratio`` in ``x_a``,
    ``x_b`` and parameters), or None when ``ratio`` is of neither form of the module or
    an integral has no closed form.

    Memoised (sympy expressions are immutable and hash by structure): ``inspect`` derives
    a design before and after its thresholds, and a user's HVAC zone spent 6 s in sympy's
    ``integrate`` each time."""
    try:
        with time_budget(BUDGET, "first integral of a fault direction"):
            for m in (_separable(ratio, xa, xb), _linear(ratio, xa, xb)):
                if m is not None and _closed(m) and m.free_symbols & {xa, xb} \
                        and _constant_along(m, ratio, xa, xb):
                    m = _plain(m, xa, xb)
                    return m if _constant_along(m, ratio, xa, xb) else None
    except BudgetExceeded:
        return None
    except (Exception, RecursionError):  # noqa: BLE001 - sympy's own failures: no form
        return None
    return None


def _integral(expr, x):
    return sp.integrate(expr, x, conds="none")


def _separable(ratio, xa, xb):
    parts = sp.separatevars(ratio, symbols=[xa, xb], dict=True, force=True)
    if not parts or set(parts) - {"coeff", xa, xb}:
        return None
    g, h = parts.get(xa, sp.Integer(1)), parts.get(xb, sp.Integer(1))
    coeff = parts.get("coeff", sp.Integer(1))
    if h == 0:
        return None
    return _integral(1 / h, xb) - coeff * _integral(g, xa)


def _linear(ratio, xa, xb):
    poly = sp.Poly(sp.expand(ratio), xb) if ratio.is_polynomial(xb) else None
    if poly is None or poly.degree() != 1:
        return None
    a, b = poly.coeff_monomial(xb), poly.coeff_monomial(1)
    if a.has(xb) or b.has(xb):
        return None
    mu = sp.exp(-_integral(a, xa))
    return mu * xb - _integral(mu * b, xa)


def _closed(m) -> bool:
    """No integral left unevaluated and no case split."""
    return not m.has(sp.Integral, sp.Piecewise)


def _constant_along(m, ratio, xa, xb) -> bool:
    """``dm/dx_a + dm/dx_b * ratio == 0`` identically."""
    return sp.simplify(sp.diff(m, xa) + sp.diff(m, xb) * ratio) == 0


def _plain(m, xa, xb):
    """``m`` in its plainest form (any function of a first integral is one): logs summed
    into one and taken off (``log(h (c - c1))`` is ``h (c - c1)``, real where the log is
    not), powers for exponentials of logs, constant factors dropped, a reciprocal of the
    states inverted."""
    m = sp.logcombine(sp.expand_log(m, force=True), force=True)
    _, m = m.as_independent(xa, xb, as_Add=False)
    if isinstance(m, sp.log):
        m = m.args[0]
    elif m.is_Add and any(isinstance(t, sp.log) for t in m.args):
        m = sp.exp(m)
    m = m.rewrite(sp.Pow)                    # exp(k log(b)) as the power b**k
    coeff, rest = sp.factor(m).as_independent(xa, xb, as_Add=False)
    m = rest if rest.free_symbols & {xa, xb} else m
    num, den = sp.fraction(sp.together(m))
    if not num.free_symbols & {xa, xb}:       # 1/(h (c - c1)): its reciprocal
        m = sp.factor(den)
    return m
