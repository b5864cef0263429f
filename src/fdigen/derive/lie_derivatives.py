r"""Output derivatives along the dynamics, and their sensitivity to faults: the
coordinate-free form of the linearisation's Markov parameters.

For ``dx/dt = f(x, u) + E(x, u) phi + O(phi^2)``, ``y = h(x, u) + F(x, u) phi + O(phi^2)``
with inputs held constant, the ``k``-th time derivative of the output is, to first order
in the faults and their derivatives ``phi^{(m)}``,

.. math::

    y^{(k)} = \Phi_k(x) + \sum_{m=0}^{k} B_{k,m}(x)\, \phi^{(m)} + O(\phi^2),

    \Phi_0 = h,\quad \Phi_{k+1} = L_f \Phi_k = \frac{\partial \Phi_k}{\partial x} f,

    B_{0,0} = F,\quad
    B_{k+1,m} = L_f B_{k,m} + B_{k,m-1} + [m = 0]\, \frac{\partial \Phi_k}{\partial x} E

(``B_{k,-1} = 0``, ``B_{k,m} = 0`` for ``m > k``). For a linear model ``∂Φ_k/∂x = C A^k``
and ``B_{k,m} = C A^{k-1-m} E`` (``F`` for ``m = k``): the Markov parameters. For a
nonlinear one, ``C A^k`` at a point away from equilibrium changes with the coordinates
the states are written in (a mixing tank's salt as concentration ``c`` or as mass
``M = c A h``); ``∂Φ_k/∂x`` and ``B_{k,m}`` transform with the coordinates' Jacobian
only, so every rank built from them is the same in any spelling of the states.

Parameters are substituted by their values and non-smooth terms by their equivalent gains
(:func:`~fdigen.derive.linearisation.equivalent_linear`), as for the linearisation.
"""

from __future__ import annotations

import sympy as sp

from fdigen.derive.linearisation import smooth_dynamics, symbolic_jacobians
from fdigen.derive.nonsmooth import derivative
from fdigen.model.model import Model

#: Operations one derivative may hold (parameters substituted) before the series is cut
#: (:class:`LieSeries` ``complete`` False). The models fdigen has met stay below 2 000.
MAX_OPS = 20_000


class LieSeries:
    """``∂Φ_k/∂x`` and ``B_{k,m}`` of the module docstring for ``k = 0..order`` (fewer
    when a derivative outgrows :data:`MAX_OPS`: ``complete`` is then False).

    Attributes
    ----------
    gradients : list of sympy.Matrix
        ``∂Φ_k/∂x`` (rows: measured expressions, columns: states).
    fault_blocks : list of list of sympy.Matrix
        ``fault_blocks[k][m] = B_{k,m}`` (rows: measured expressions, columns: faults);
        empty when ``with_faults`` is False.
    """

    def __init__(self, gradients, fault_blocks, complete: bool):
        self.gradients = gradients
        self.fault_blocks = fault_blocks
        self.complete = complete


_SWITCHES = (sp.Abs, sp.sign, sp.Heaviside, sp.DiracDelta)


def _d(e, v):
    """``de/dv``: sympy's own where ``e`` holds no switch, else taken almost everywhere
    (:func:`~fdigen.derive.nonsmooth.derivative`)."""
    return derivative(e, v) if e.has(*_SWITCHES) else sp.diff(e, v)


def _grad(phi: sp.MatrixBase, x) -> sp.MatrixBase:
    return sp.Matrix(phi.rows, len(x), lambda i, j: _d(phi[i], x[j]))


def _along(B: sp.MatrixBase, x, f) -> sp.MatrixBase:
    """``L_f B = sum_i (dB/dx_i) f_i`` of a matrix ``B``, element by element."""
    return B.applyfunc(lambda e: sp.Add(*(_d(e, xi) * fi for xi, fi in zip(x, f))))


def _too_big(m: sp.MatrixBase) -> bool:
    return sum(sp.count_ops(e, visual=False) for e in m) > MAX_OPS


def series_inputs(model: Model, measurement: sp.MatrixBase | None = None,
                  faults: list | None = None):
    """``(f, m, E, F)`` the series starts from, parameters at their values: the dynamics
    and the measured expressions (``measurement`` in output symbols, default every
    output) at their equivalent gains (:func:`~fdigen.derive.linearisation.smooth_dynamics`),
    and the fault directions of the faults at the indices ``faults`` (default all) in
    the state equations and in the measured expressions."""
    pv = {k: sp.Float(float(v), 17) for k, v in model.parameter_values.items()}
    f, h = smooth_dynamics(model)
    jac = symbolic_jacobians(model)
    cols = list(range(jac.E.cols)) if faults is None else list(faults)
    E = jac.E.extract(list(range(jac.E.rows)), cols)
    F = jac.F.extract(list(range(jac.F.rows)), cols)
    if measurement is not None:
        ys = sp.Matrix([o.symbol for o in model.outputs])
        F = measurement.jacobian(ys) * F
        h = measurement.xreplace({o.symbol: e for o, e in zip(model.outputs, h)})
    return tuple(m.xreplace(pv) for m in (f, h, E, F))


def lie_series(model: Model, measurement: sp.MatrixBase | None = None, order: int | None = None,
               with_faults: bool = True, faults: list | None = None) -> LieSeries:
    """The series of the module docstring for the measured expressions ``measurement``
    (in output symbols; default: every output) up to ``order`` (default: the number of
    states minus one); the fault blocks' columns are the faults at the indices ``faults``
    (default: all, in the model's order)."""
    x = list(model.x)
    order = len(x) - 1 if order is None else order
    f, phi, E, F = series_inputs(model, measurement, faults if with_faults else [])
    blocks = [[F]] if with_faults else []
    grads = []
    for k in range(order + 1):
        grads.append(_grad(phi, x))
        if k == order:
            return LieSeries(grads, blocks, True)
        phi = grads[-1] * f
        if with_faults:
            prev = blocks[-1]
            nxt = []
            for m in range(k + 2):
                term = grads[-1] * E if m == 0 else prev[m - 1]
                if m <= k:
                    term = term + _along(prev[m], x, f)
                nxt.append(term)
            blocks.append(nxt)
            if any(_too_big(b) for b in nxt):
                return LieSeries(grads, blocks[:-1], False)
        if _too_big(phi):
            return LieSeries(grads, blocks[:len(grads)], False)
    return LieSeries(grads, blocks, True)
