"""Linearisation of a model at an operating point and zero-order-hold discretisation.

Non-smooth terms (a friction sign smoothed by a steep ``tanh``, ``sign``, ``abs``,
``min``/``max`` dead bands and saturations) are linearised by their *equivalent gain over
the operating range*, not by their slope at the operating point (see
:func:`equivalent_linear`): the slope of ``tanh(xdot/v_eps)`` at ``xdot = 0`` is
``1/v_eps``, hundreds of times what the term does over the piston's normal speeds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp

from fdigen.derive import precise
from fdigen.errors import DesignError
from fdigen.model.model import Model
from fdigen.safe_lambdify import safe_lambdify


@dataclass(frozen=True)
class SymbolicLinearisation:
    """Symbolic Jacobians of a model, functions of states, inputs and parameters.

    ``A = df/dx``, ``B = df/du``, ``C = dh/dx``, ``D = dh/du``, ``E = df/df_a`` (fault input
    matrix of the dynamics) and ``F = dh/df_a`` (fault matrix of the outputs), all taken at
    zero fault.
    """

    A: sp.Matrix
    B: sp.Matrix
    C: sp.Matrix
    D: sp.Matrix
    E: sp.Matrix
    F: sp.Matrix


@dataclass(frozen=True)
class LinearModel:
    """A numeric linear model ``dx = A (x - x0) + B (u - u0)``, ``y = y0 + C (x - x0) + D (u - u0)``.

    For a discrete model (``dt`` set), ``x[k+1] - x0 = A (x[k] - x0) + B (u[k] - u0)``.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    E: np.ndarray
    F: np.ndarray
    x0: np.ndarray
    u0: np.ndarray
    y0: np.ndarray
    dt: float | None = None


#: A ``tanh``/``atan``/``erf`` whose argument changes by more than this over the amplitude of
#: its variable is a smoothed switch (it saturates within a tenth of the normal range).
SWITCH_STEEPNESS = 10.0
#: Quadrature points of the describing-function integral (one period).
DF_POINTS = 4096

_SWITCHES = (sp.sign, sp.Abs, sp.Min, sp.Max, sp.Heaviside)
_SMOOTHED = (sp.tanh, sp.atan, sp.erf)


def _amplitudes(model: Model) -> dict:
    """Variable symbol -> ``(x0, a)``: operating value and half the span of its range."""
    out = {}
    for s in (*model.states, *model.inputs):
        if s.range is None or s.name not in model.operating_point:
            continue
        lo, hi = (float(v) for v in s.range)
        out[s.symbol] = (float(model.operating_point[s.name]), 0.5 * (hi - lo))
    return out


#: Points at which :func:`_settled_switch` evaluates a switch over its variable's range.
SETTLED_POINTS = 257


def _settled_switch(node, ranges, pvals) -> bool:
    """Whether a switch (``abs``, ``sign``, ``Heaviside``, ``min``, ``max``) of one ranged
    variable ``v`` (and parameters) takes one branch over all of ``v``'s declared
    ``range`` (``ranges``: symbol -> (low, high)): the argument of ``abs``/``sign``/``Heaviside`` keeps a strict sign, the
    same argument of ``min``/``max`` wins, at :data:`SETTLED_POINTS` points. Such a switch
    is smooth where the model runs: a level's guard ``sqrt(max(h, 0))`` on a range of
    0.5-1.5 m linearised by a describing function over the range gave its tank
    ``-0.513 Cv/At`` where ``sqrt(h)`` gives the tangent's exact ``-0.5 Cv/At``, and
    switched its filter to the nonlinear prediction."""
    vs = node.free_symbols & set(ranges)
    if len(vs) != 1 or not (node.free_symbols - vs) <= set(pvals):
        return False
    v = vs.pop()
    grid = np.linspace(*ranges[v], SETTLED_POINTS)

    def values(e):
        fn = safe_lambdify(v, e.xreplace(pvals), modules="numpy")
        with np.errstate(all="ignore"):
            out = np.broadcast_to(np.asarray(fn(grid), dtype=float), grid.shape)
        return out if np.all(np.isfinite(out)) else None

    if node.func in (sp.Min, sp.Max):
        vals = [values(arg) for arg in node.args]
        if any(x is None for x in vals):
            return False
        stack = np.vstack(vals)
        best = np.argmax(stack, axis=0) if node.func == sp.Max else np.argmin(stack, axis=0)
        ordered = np.sort(stack, axis=0)
        gap = ordered[-1] - ordered[-2] if node.func == sp.Max else ordered[1] - ordered[0]
        scale = np.maximum(np.abs(ordered).max(axis=0), 1e-300)
        return bool(np.all(best == best[0]) and np.all(gap > 1e-9 * scale))
    g = values(node.args[0])
    return g is not None and bool(np.all(g > 0) or np.all(g < 0))


def _is_switch(node, amps, pvals, ranges=None) -> bool:
    if node.func in _SWITCHES:
        return not _settled_switch(node, ranges or {}, pvals)
    if node.func in _SMOOTHED and len(node.args) == 1:
        arg = node.args[0]
        vs = arg.free_symbols & set(amps)
        if len(vs) != 1:
            return False
        v = vs.pop()
        x0, a = amps[v]
        slope = sp.diff(arg, v).xreplace(pvals).xreplace({v: x0})
        try:
            slope = abs(float(slope))
        except TypeError:
            return False
        return slope * a > SWITCH_STEEPNESS
    return False


def describing_gain(g, v, x0: float, a: float) -> float:
    """Sinusoidal-input describing function of ``g(v)`` about ``x0`` at amplitude ``a``.

    .. math::

        N(a) = \\frac{1}{\\pi a} \\int_0^{2\\pi} g(x_0 + a \\sin\\theta)\\,
        \\sin\\theta\\, d\\theta

    the gain of the first harmonic in phase with the input (for a smooth linear ``g`` its
    slope; for the ideal relay ``F sign(v)`` the classical ``4 F / (pi a)``). Evaluated by
    the trapezoidal rule over one period (``DF_POINTS`` points, spectrally accurate for a
    periodic integrand).
    """
    theta = 2.0 * np.pi * np.arange(DF_POINTS) / DF_POINTS
    fn = safe_lambdify(v, g, modules="numpy")
    vals = np.broadcast_to(np.asarray(fn(x0 + a * np.sin(theta)), dtype=float), theta.shape)
    return float(2.0 / a * np.mean(vals * np.sin(theta)))


def equivalent_linear(expr, model: Model):
    """``expr`` with its non-smooth sub-terms replaced by their equivalent straight line.

    A sub-term ``g(v)`` of one state or input ``v`` (and parameters) that holds a switch
    (``sign``, ``abs``, ``min``, ``max``, ``Heaviside``, or a ``tanh``/``atan``/``erf`` whose
    argument changes by more than ``SWITCH_STEEPNESS`` over the amplitude of ``v``) is
    replaced by

    .. math:: g(v) \\to g(x_0) + N(a)\\,(v - x_0)

    with :func:`describing_gain` ``N(a)`` at the amplitude ``a`` = half the span of ``v``'s
    ``range`` (its normal operation) about the operating value ``x0``. Factors of a product
    that hold no state or input stay symbolic (``-Fc/M * N(a) * xdot``). A Jacobian of the
    result is the *equivalent* (describing-function) linearisation over the operating range:
    for the Coulomb term ``-Fc/M tanh(xdot/v_eps)`` it is ``-4 Fc/(pi M a)``, not the
    ``-Fc/(M v_eps)`` of the tangent at ``xdot = 0``; for a dead band
    ``min(max(v, -db), db)`` it is the small gain of the band, not 1. Smooth models are
    returned unchanged, and so is a switch that takes one branch over its variable's whole
    range (:func:`_settled_switch`: a guard ``sqrt(max(h, 0))`` on a level that never
    empties). Variables without a ``range`` are left to the ordinary derivative.
    """
    amps = _amplitudes(model)
    pvals = {k: sp.Float(float(v), 17) for k, v in model.parameter_values.items()}
    ranges = {s.symbol: (float(s.range[0]), float(s.range[1]))
              for s in (*model.states, *model.inputs) if s.range is not None}

    def has_switch(e):
        return any(_is_switch(n, amps, pvals, ranges) for n in sp.preorder_traversal(e)
                   if isinstance(n, sp.Basic) and not n.is_Atom)

    def surrogate(g, v):
        if not (g.free_symbols - {v}) <= set(pvals):
            return None  # depends on something without a value (a fault symbol)
        x0, a = amps[v]
        num = g.xreplace(pvals)
        gain = describing_gain(num, v, x0, a)
        g0 = safe_lambdify(v, num, modules="numpy")(x0)
        return sp.Float(float(g0), 17) + sp.Float(gain, 17) * (v - sp.Float(x0, 17))

    def rebuild(e):
        if e.is_Atom or not has_switch(e):
            return e
        vs = e.free_symbols & set(amps)
        if isinstance(e, sp.Mul):
            coeff = [f for f in e.args if not f.free_symbols & set(amps)]
            rest = [f for f in e.args if f.free_symbols & set(amps)]
            if coeff and rest:
                return sp.Mul(*coeff) * rebuild(sp.Mul(*rest))
        if len(vs) == 1:
            sub = surrogate(e, next(iter(vs)))
            if sub is not None:
                return sub
        return e.func(*[rebuild(a) for a in e.args])

    if isinstance(expr, sp.MatrixBase):
        return expr.applyfunc(rebuild)
    return rebuild(expr)


def symbolic_jacobians(model: Model) -> SymbolicLinearisation:
    """Symbolic Jacobians of the model's dynamics and outputs.

    .. math::

        A = \\frac{\\partial f}{\\partial x},\\; B = \\frac{\\partial f}{\\partial u},\\;
        C = \\frac{\\partial h}{\\partial x},\\; D = \\frac{\\partial h}{\\partial u},\\;
        E = \\frac{\\partial f}{\\partial \\phi}\\Big|_{\\phi=0},\\;
        F = \\frac{\\partial h}{\\partial \\phi}\\Big|_{\\phi=0}

    with ``f`` the right-hand side of eqs (1)-(3) for the cylinder and ``phi`` the faults.
    Non-smooth terms enter with their equivalent gain over the operating range
    (:func:`equivalent_linear`); a smooth model's Jacobians are the exact ones.
    """
    memo = model.derived("symbolic_jacobians")
    if "jac" not in memo:
        memo["jac"] = _symbolic_jacobians(model)
    return memo["jac"]


def smooth_dynamics(model: Model):
    """``(f, h)`` of the model with non-smooth terms at their equivalent gains
    (:func:`equivalent_linear`), kept on the model instance."""
    memo = model.derived("smooth")
    if "fh" not in memo:
        memo["fh"] = (equivalent_linear(model.f(), model), equivalent_linear(model.h(), model))
    return memo["fh"]


def _symbolic_jacobians(model: Model) -> SymbolicLinearisation:
    f, h = smooth_dynamics(model)
    zero_faults = {s: 0 for s in model.f_sym}
    ff = equivalent_linear(model.f(with_faults=True), model)
    hf = equivalent_linear(model.h(with_faults=True), model)
    from fdigen.derive.nonsmooth import jacobian

    if len(model.faults):
        E = jacobian(ff, model.f_sym).xreplace(zero_faults)
        F = jacobian(hf, model.f_sym).xreplace(zero_faults)
    else:
        E = sp.zeros(len(model.states), 0)
        F = sp.zeros(len(model.outputs), 0)
    # derivatives almost everywhere: a sign/Heaviside left by equivalent_linear (a switch
    # of two variables) differentiates to an impulse, which has no numeric value
    return SymbolicLinearisation(
        A=jacobian(f, model.x), B=jacobian(f, model.u), C=jacobian(h, model.x),
        D=jacobian(h, model.u), E=E, F=F)


class NotRealError(DesignError, TypeError):
    """An entry evaluated to a complex number (a ``TypeError`` to the callers that probe
    points, a design error naming the point to the user)."""


def numeric(expr, subs) -> np.ndarray:
    """Evaluate a sympy matrix or expression with numbers substituted (fast ``xreplace``).

    Raises
    ------
    NotRealError
        An entry is not real there (``asin'(x)`` at ``|x| = 1``, a sqrt of a negative
        number: attack round 8 met it as "Cannot convert complex to float", exit 3).
    """
    values = {k: sp.Float(float(v), 17) for k, v in subs.items()}
    mat = sp.Matrix(expr) if not isinstance(expr, sp.MatrixBase) else expr
    out = mat.xreplace(values).evalf()
    try:
        return np.array(out, dtype=float).reshape(mat.shape)
    except TypeError:
        shown = ", ".join(f"{k} = {float(v):.6g}" for k, v in values.items()
                          if not str(k).startswith(("p_", "f_")))[:400]
        raise NotRealError(f"a derivative of the model is not real at {shown} (a sqrt, "
                           "log, asin or acos at or past the edge of its domain): move the "
                           "operating point inside it, or guard the argument") from None


def operating_point_substitution(model: Model, operating_point=None, parameters=None):
    """The substitution ``{symbol: value}`` for states, inputs and parameters at a point."""
    op = dict(model.operating_point)
    if operating_point:
        op.update(operating_point)
    subs = dict(model.parameter_values)
    if parameters:
        subs.update({sp.Symbol(k, real=True): float(v) for k, v in parameters.items()})
    for s in (*model.states, *model.inputs):
        subs[s.symbol] = float(op[s.name])
    return subs


def linearise(model: Model, operating_point=None, parameters=None) -> LinearModel:
    """Evaluate the symbolic Jacobians at an operating point.

    Parameters
    ----------
    model : Model
    operating_point : mapping of str to float, optional
        Overrides of the model's operating point (states and inputs).
    parameters : mapping of str to float, optional
        Overrides of parameter values.

    Returns
    -------
    LinearModel
        Continuous-time matrices; ``x0``, ``u0`` the point, ``y0 = h(x0, u0)``.
    """
    subs = operating_point_substitution(model, operating_point, parameters)
    jac = symbolic_jacobians(model)

    def num(mat):
        value = numeric(mat, subs)
        if not np.all(np.isfinite(value)):
            raise DesignError(f"linearisation is not finite at the operating point {subs}")
        return value

    x0 = np.array([subs[s.symbol] for s in model.states], dtype=float)
    u0 = np.array([subs[s.symbol] for s in model.inputs], dtype=float)
    y0 = num(model.h()).ravel()
    return LinearModel(num(jac.A), num(jac.B), num(jac.C), num(jac.D), num(jac.E),
                       num(jac.F), x0, u0, y0)


def discretise_zoh(lin: LinearModel, dt: float) -> LinearModel:
    """Zero-order-hold discretisation of a continuous linear model.

    .. math::

        A_d = e^{A\\,dt},\\quad B_d = \\int_0^{dt} e^{A s}\\,ds\\,B,\\quad
        E_d = \\int_0^{dt} e^{A s}\\,ds\\,E

    computed from one matrix exponential ``expm([[A, I], [0, 0]] dt)`` (Van Loan), in
    extended precision and correctly rounded (:func:`fdigen.derive.precise.zoh`): the same
    bits on every machine.
    """
    if not (np.isfinite(dt) and dt > 0):
        raise DesignError(f"sample time must be positive and finite, got {dt}")
    m = lin.B.shape[1]
    Ad, BEd = precise.zoh(lin.A, np.hstack([lin.B, lin.E]), dt)
    return LinearModel(Ad, BEd[:, :m], lin.C, lin.D, BEd[:, m:], lin.F,
                       lin.x0, lin.u0, lin.y0, dt)


def discretise_noise(A: np.ndarray, Qc: np.ndarray, dt: float) -> np.ndarray:
    """Discrete process noise covariance of continuous white noise of intensity ``Qc``.

    .. math:: Q_d = \\int_0^{dt} e^{A s} Q_c e^{A^T s}\\,ds

    by Van Loan's method: ``expm([[-A, Qc], [0, A^T]] dt)``, in extended precision and
    correctly rounded (:func:`fdigen.derive.precise.noise_covariance`).
    """
    return precise.noise_covariance(A, Qc, dt)


def growth_rate(model) -> float:
    """The largest real part of the linearised modes at the operating point (1/s), 0 when
    none is positive: an unstable mode makes every open-loop simulation of the model (a
    parallel model without realignment, a free-run output-error fit) depart from the
    plant (a magnetic levitation rig: 44 1/s). A real part within the eigenvalues'
    rounding error, ``1e-9 max_i |lambda_i|``, is 0: a pure integrator (a position, a tank
    without outflow) is marginal, not unstable (a user's servo in bar and mm got 2.4e-32
    1/s and an "unstable" warning its SI spelling did not).

    .. math:: \\max(0, \\max_i \\mathrm{Re}\\,\\lambda_i(\\partial f / \\partial x))
    """
    eig = np.linalg.eigvals(np.asarray(linearise(model).A, dtype=float))
    if not eig.size:
        return 0.0
    worst = float(np.max(eig.real))
    return worst if worst > 1e-9 * float(np.max(np.abs(eig))) else 0.0

