"""Linearisation of a model at an operating point and zero-order-hold discretisation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import sympy as sp

from fdigen.errors import DesignError
from fdigen.model.model import Model


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


def symbolic_jacobians(model: Model) -> SymbolicLinearisation:
    """Symbolic Jacobians of the model's dynamics and outputs.

    .. math::

        A = \\frac{\\partial f}{\\partial x},\\; B = \\frac{\\partial f}{\\partial u},\\;
        C = \\frac{\\partial h}{\\partial x},\\; D = \\frac{\\partial h}{\\partial u},\\;
        E = \\frac{\\partial f}{\\partial \\phi}\\Big|_{\\phi=0},\\;
        F = \\frac{\\partial h}{\\partial \\phi}\\Big|_{\\phi=0}

    with ``f`` the right-hand side of eqs (1)-(3) for the cylinder and ``phi`` the faults.
    """
    f = model.f()
    h = model.h()
    zero_faults = {s: 0 for s in model.f_sym}
    ff = model.f(with_faults=True)
    hf = model.h(with_faults=True)
    if len(model.faults):
        E = ff.jacobian(model.f_sym).xreplace(zero_faults)
        F = hf.jacobian(model.f_sym).xreplace(zero_faults)
    else:
        E = sp.zeros(len(model.states), 0)
        F = sp.zeros(len(model.outputs), 0)
    return SymbolicLinearisation(
        A=f.jacobian(model.x), B=f.jacobian(model.u), C=h.jacobian(model.x),
        D=h.jacobian(model.u), E=E, F=F)


def numeric(expr, subs) -> np.ndarray:
    """Evaluate a sympy matrix or expression with numbers substituted (fast ``xreplace``)."""
    values = {k: sp.Float(float(v), 17) for k, v in subs.items()}
    mat = sp.Matrix(expr) if not isinstance(expr, sp.MatrixBase) else expr
    out = mat.xreplace(values).evalf()
    return np.array(out, dtype=float).reshape(mat.shape)


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

    computed from one matrix exponential of the augmented matrix
    ``[[A, B, E], [0, 0, 0]] * dt`` (Van Loan).
    """
    if not (np.isfinite(dt) and dt > 0):
        raise DesignError(f"sample time must be positive and finite, got {dt}")
    n, m, q = lin.A.shape[0], lin.B.shape[1], lin.E.shape[1]
    big = np.zeros((n + m + q, n + m + q))
    big[:n, :n] = lin.A
    big[:n, n:n + m] = lin.B
    big[:n, n + m:] = lin.E
    phi = scipy.linalg.expm(big * dt)
    return LinearModel(phi[:n, :n], phi[:n, n:n + m], lin.C, lin.D, phi[:n, n + m:], lin.F,
                       lin.x0, lin.u0, lin.y0, dt)


def discretise_noise(A: np.ndarray, Qc: np.ndarray, dt: float) -> np.ndarray:
    """Discrete process noise covariance of continuous white noise of intensity ``Qc``.

    .. math:: Q_d = \\int_0^{dt} e^{A s} Q_c e^{A^T s}\\,ds

    by Van Loan's method: ``expm([[-A, Qc], [0, A^T]] dt)``.
    """
    n = A.shape[0]
    big = np.zeros((2 * n, 2 * n))
    big[:n, :n] = -A
    big[:n, n:] = Qc
    big[n:, n:] = A.T
    phi = scipy.linalg.expm(big * dt)
    Ad = phi[n:, n:].T
    Qd = Ad @ phi[:n, n:]
    return 0.5 * (Qd + Qd.T)
