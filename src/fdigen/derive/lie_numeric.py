r"""The series of :mod:`fdigen.derive.lie_derivatives` evaluated at points by CasADi's
algorithmic differentiation instead of sympy's symbolic one.

Differentiating ``L_f^k h`` symbolically ``n`` times swells the expressions: the
cylinder's rank test spent 3 s and a cart-pole's 6 s in ``sympy.diff``. The same
recursions on CasADi expression graphs (``jacobian`` and ``jtimes`` of shared
sub-expressions) take milliseconds. The model's equations enter through
:func:`~fdigen.safe_lambdify.safe_lambdify` with CasADi's functions as the namespace (the
names in the generated code are fdigen's, never the model's); an expression with a
function CasADi is not given here returns None, and the caller takes the symbolic path.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import sympy as sp

from fdigen.derive.lie_derivatives import series_inputs


def _printer_class():
    from sympy.printing.lambdarepr import LambdaPrinter

    class CasadiPrinter(LambdaPrinter):
        """Calls, never Python conditionals (an SX has no truth value)."""

        def _print_Heaviside(self, expr):
            return f"Heaviside({self._print(expr.args[0])})"

        def _print_sign(self, expr):
            return f"sign({self._print(expr.args[0])})"

        def _print_Piecewise(self, expr):
            raise ValueError("a Piecewise has no CasADi form here")

    return CasadiPrinter


def _CasadiPrinter(settings):
    return _printer_class()(settings)


def _namespace(ca) -> dict:
    def heaviside(x, h0=0.5):
        return ca.if_else(x > 0, 1.0, ca.if_else(x < 0, 0.0, h0))

    return {
        "sqrt": ca.sqrt, "exp": ca.exp, "log": ca.log, "sin": ca.sin, "cos": ca.cos,
        "tan": ca.tan, "asin": ca.asin, "acos": ca.acos, "atan": ca.atan,
        "atan2": ca.atan2, "sinh": ca.sinh, "cosh": ca.cosh, "tanh": ca.tanh,
        "Abs": ca.fabs, "abs": ca.fabs, "sign": ca.sign, "Heaviside": heaviside,
        "Max": lambda *a: functools.reduce(ca.fmax, a),
        "Min": lambda *a: functools.reduce(ca.fmin, a),
        "max": lambda *a: functools.reduce(ca.fmax, a),
        "min": lambda *a: functools.reduce(ca.fmin, a),
        "copysign": lambda a, b: ca.fabs(a) * ca.sign(b),
        "pi": math.pi, "E": math.e,
    }


#: Expression nodes of one order's gradient beyond which the series stops growing: each
#: order of a 12-state chain of ``sin(x_i) exp(-x_i x_j)/(1 + x_j^2)`` multiplied them by
#: 3 (4.4e6 at order 12, 1.5 GB and 60-200 s for `inspect`: attack round 6); the shipped
#: models need at most 2828.
MAX_SERIES_NODES = 200_000


class SeriesTooLarge(Exception):
    """The series with fault blocks outgrew :data:`MAX_SERIES_NODES`."""


def lie_values(model, points: list[dict], order: int, faults: list | None = None,
               measurement: sp.MatrixBase | None = None):
    """``[(dPhi_0/dx .. dPhi_order/dx, B)]`` at each point (``{name: value}`` of the
    states and inputs), ``B[k][m]`` the fault blocks of
    :mod:`fdigen.derive.lie_derivatives` for the faults at the indices ``faults``
    (default all), of the measured expressions ``measurement`` (in output symbols;
    default every output); None when the model holds a function this module does not
    map. A point whose values are not finite is None in the list. Past
    :data:`MAX_SERIES_NODES` the remaining gradients are the linearisation's
    ``(d/dx L_f^k m) A^j`` (as :func:`fdigen.design.signatures.lie_gradients` does), and
    with fault blocks asked for :class:`SeriesTooLarge` is raised (the rank test then
    uses the linearisation's)."""
    import casadi as ca

    from fdigen.safe_lambdify import safe_lambdify

    f, h, E, F = series_inputs(model, measurement, faults)
    n, m, p, nf = len(model.x), len(model.u), h.rows, E.cols
    x, u = ca.SX.sym("x", n), ca.SX.sym("u", m)
    flat = [*f, *h, *E, *F]
    try:
        printer = _CasadiPrinter({"fully_qualified_modules": False, "inline": True,
                                  "allow_unknown_functions": True, "user_functions": {}})
        build = safe_lambdify([*model.x, *model.u], flat, modules=[_namespace(ca)],
                              printer=printer)
        parts = build(*[x[i] for i in range(n)], *[u[i] for i in range(m)])
    except Exception:  # noqa: BLE001 - any function or construct CasADi is not given
        return None
    parts = [ca.SX(v) if not isinstance(v, ca.SX) else v for v in parts]
    fx = ca.vertcat(*parts[:n])
    phi = ca.vertcat(*parts[n:n + p])
    if nf:
        Ex = ca.reshape(ca.vertcat(*parts[n + p:n + p + n * nf]), nf, n).T
        Fx = ca.reshape(ca.vertcat(*parts[n + p + n * nf:]), nf, p).T
    else:
        Ex, Fx = ca.SX(n, 0), ca.SX(p, 0)

    def along(B):          # L_f B, element by element
        return ca.reshape(ca.jtimes(ca.vec(B), x, fx), B.shape[0], B.shape[1])

    grads, blocks = [], [[Fx]]
    linear = False
    A = ca.jacobian(fx, x)
    for k in range(order + 1):
        grads.append(ca.mtimes(grads[-1], A) if linear else ca.jacobian(phi, x))
        if not linear and ca.n_nodes(grads[-1]) > MAX_SERIES_NODES:
            if nf:              # the rank test: the linearisation's test instead
                raise SeriesTooLarge(f"order {k} of the output derivatives has "
                                     f"{ca.n_nodes(grads[-1])} nodes")
            linear = True       # the remaining orders are the linearisation's, d/dx L^k A^j
        if k == order:
            break
        phi = None if linear else ca.mtimes(grads[-1], fx)
        prev = blocks[-1]
        nxt = []
        for mm in range(k + 2):
            term = ca.mtimes(grads[-1], Ex) if mm == 0 else prev[mm - 1]
            if mm <= k:
                term = term + along(prev[mm])
            nxt.append(term)
        blocks.append(nxt)
    outs = [*grads, *(b for row in blocks for b in row)]
    fun = ca.Function("lie_series", [x, u], outs)
    names = [s.name for s in model.states], [s.name for s in model.inputs]
    out = []
    for point in points:
        try:
            vals = fun([float(point[k]) for k in names[0]], [float(point[k]) for k in names[1]])
        except (RuntimeError, KeyError, TypeError, ValueError):
            out.append(None)
            continue
        vals = [np.asarray(v, dtype=float) for v in vals]
        if not all(np.all(np.isfinite(v)) for v in vals):
            out.append(None)
            continue
        g, rest = vals[:order + 1], iter(vals[order + 1:])
        out.append((g, [[next(rest) for _ in range(k + 1)] for k in range(order + 1)]))
    return out
