"""Observability: rank test per measurement set and reduction to the observable part."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp
from sympy.matrices.utilities import dotprodsimp

from fdigen.derive.linearisation import numeric, operating_point_substitution, symbolic_jacobians
from fdigen.errors import DesignError
from fdigen.model.expression import parse_expression
from fdigen.model.model import Model

RANK_TOL = 1e-9


@dataclass(frozen=True)
class ObservableReduction:
    """The observable part of ``(A, B, C)`` for one measurement set.

    The coordinate change ``z = T x`` (``T`` has full row rank ``r``) maps the state onto the
    observable quotient. Because the unobservable subspace ``ker T`` is ``A``-invariant,

    .. math:: T A = A_r T,\\qquad C_m = C_r T,\\qquad B_r = T B

    so ``dz/dt = A_r z + B_r u``, ``y_m = C_r z`` reproduces the measured output exactly.

    Attributes
    ----------
    measurement : tuple of str
        The measured expressions (in output names), e.g. ``("x3",)`` or ``("pp - pn",)``.
    T, A_r, B_r, C_r, E_r : sympy.Matrix
        Symbolic, at the symbolic operating point (states whose operating value is zero and
        all inputs substituted; the other states stand for their operating values).
    z_names : tuple of str
        Names of the reduced coordinates (``Pp - Pn`` is named ``Pd`` when it is a difference
        of two states whose names share their first letter, otherwise ``z1``...).
    rank : int
    T_num, A_num, B_num, C_num, E_num : numpy.ndarray
        The same at the numeric operating point.
    unobservable_eigenvalues : numpy.ndarray
        Eigenvalues of ``A`` on its unobservable subspace (continuous time).
    """

    measurement: tuple[str, ...]
    T: sp.Matrix
    A_r: sp.Matrix
    B_r: sp.Matrix
    C_r: sp.Matrix
    E_r: sp.Matrix
    z_names: tuple[str, ...]
    rank: int
    T_num: np.ndarray
    A_num: np.ndarray
    B_num: np.ndarray
    C_num: np.ndarray
    E_num: np.ndarray
    unobservable_eigenvalues: np.ndarray


def observability_matrix(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Kalman observability matrix ``[C; CA; ...; CA^{n-1}]``."""
    n = A.shape[0]
    blocks = [C]
    for _ in range(n - 1):
        blocks.append(blocks[-1] @ A)
    return np.vstack(blocks)


def observability_rank(A: np.ndarray, C: np.ndarray, tol: float = RANK_TOL) -> int:
    """Numerical rank of the observability matrix, columns scaled to unit norm first.

    Scaling makes the test independent of units (pressures in Pa and positions in m
    differ by ten orders of magnitude).
    """
    O = observability_matrix(A, C)
    scale = np.linalg.norm(O, axis=0)
    scale[scale == 0] = 1.0
    O = O / scale
    rows = np.linalg.norm(O, axis=1)
    rows[rows == 0] = 1.0
    s = np.linalg.svd(O / rows[:, None], compute_uv=False)
    return int(np.sum(s > tol * max(s[0], 1e-300)))


def is_detectable(A: np.ndarray, C: np.ndarray, discrete: bool, tol: float = 1e-9) -> bool:
    """PBH detectability test: every mode with ``|lambda| >= 1`` (discrete) or
    ``Re(lambda) >= 0`` (continuous) satisfies ``rank [A - lambda I; C] = n``."""
    return not undetectable_modes(A, C, discrete, tol)


def undetectable_modes(A, C, discrete, tol=1e-9):
    """Eigenvalues of ``A`` that are unstable or marginal and unobservable through ``C``."""
    n = A.shape[0]
    out = []
    for lam in np.linalg.eigvals(A):
        unstable = abs(lam) >= 1 - tol if discrete else lam.real >= -tol
        if not unstable:
            continue
        M = np.vstack([A - lam * np.eye(n), C])
        scale = np.linalg.norm(M, axis=0)
        scale[scale == 0] = 1
        s = np.linalg.svd(M / scale, compute_uv=False)
        if s[-1] <= 1e-8 * s[0]:
            out.append(lam)
    return out


def measurement_jacobian(model: Model, measurement: tuple[str, ...]) -> sp.Matrix:
    """Rows ``d m_i / dx`` of measured expressions written in output names."""
    exprs = measurement_expressions(model, measurement)
    return sp.Matrix(exprs).jacobian(model.x)


def measurement_expressions(model: Model, measurement: tuple[str, ...]) -> list[sp.Expr]:
    """Measured expressions as functions of the states (outputs' ``h`` substituted)."""
    outs = {o.name: o.symbol for o in model.outputs}
    h = model.h()
    subs = {o.symbol: h[i] for i, o in enumerate(model.outputs)}
    return [parse_expression(m, outs, source=model.source, field="fdi.measurement").xreplace(subs)
            for m in measurement]


def symbolic_operating_point(model: Model) -> dict:
    """Substitution for the symbolic operating point: inputs and zero-valued states.

    The states with a nonzero operating value stay symbols (they denote that value); this
    keeps expressions such as ``a = -gamma A Pp / Vp`` of eq (15) readable.
    """
    subs = {}
    for s in model.inputs:
        subs[s.symbol] = sp.nsimplify(model.operating_point[s.name])
    for s in model.states:
        if model.operating_point[s.name] == 0:
            subs[s.symbol] = sp.Integer(0)
    return subs


def observable_reduction(model: Model, measurement: tuple[str, ...],
                         operating_point=None, parameters=None) -> ObservableReduction:
    """Reduce the linearised model to the part observable from ``measurement``.

    The observability matrix ``O = [C_m; C_m A; ...; C_m A^{n-1}]`` is formed symbolically
    at the symbolic operating point; its numeric rank ``r`` at the numeric operating point
    decides the order, and the first ``r`` rows of its reduced row echelon form give the
    coordinate change ``T``. Then (see :class:`ObservableReduction`)

    .. math::

        A_r = T A T^T (T T^T)^{-1},\\quad B_r = T B,\\quad C_r = C_m T^T (T T^T)^{-1}.

    For the pneumatic cylinder measured by position this yields eq (15) of the paper: the
    third-order model in ``[Pd, x, xdot]`` with ``dPd/dt = (a - b) xdot + (c - d) v``.

    Raises
    ------
    DesignError
        If nothing is observable, or the reduction does not reproduce the measurement.
    """
    with dotprodsimp(False):
        return _observable_reduction(model, measurement, operating_point, parameters)


def _observable_reduction(model, measurement, operating_point, parameters):
    jac = symbolic_jacobians(model)
    sop = symbolic_operating_point(model)
    A = sp.Matrix(jac.A.xreplace(sop))
    B = sp.Matrix(jac.B.xreplace(sop))
    E = sp.Matrix(jac.E.xreplace(sop))
    Cm = sp.Matrix(measurement_jacobian(model, measurement).xreplace(sop))
    n = A.shape[0]
    num_subs = operating_point_substitution(model, operating_point, parameters)

    def num(mat):
        return numeric(mat, num_subs)

    A_n, C_n = num(A), num(Cm)
    r = observability_rank(A_n, C_n)
    if r == 0:
        raise DesignError(f"nothing is observable from measurement {list(measurement)}")

    blocks = [Cm]
    for _ in range(n - 1):
        blocks.append((blocks[-1] * A).applyfunc(_normal))
    O = sp.Matrix.vstack(*blocks)
    rref, pivots = O.rref(iszerofunc=lambda e: _normal(e) == 0, simplify=_normal)
    T = sp.Matrix(rref[:r, :]).applyfunc(_normal)
    if len(pivots) != r or np.linalg.matrix_rank(num(T)) != r:
        T = _numeric_basis(O, num, r)
    pinv = T.T * (T * T.T).inv()
    A_r = (T * A * pinv).applyfunc(_normal)
    B_r = (T * B).applyfunc(_normal)
    E_r = (T * E).applyfunc(_normal)
    C_r = (Cm * pinv).applyfunc(_normal)

    T_n = num(T)
    A_rn = num(A_r)
    if not np.allclose(T_n @ A_n, A_rn @ T_n, rtol=1e-8, atol=1e-8 * np.abs(T_n @ A_n).max()):
        raise DesignError("observable reduction failed: ker T is not A-invariant")
    # unobservable dynamics: A restricted to ker T
    null = _null_space(T_n)
    if null.shape[1]:
        A_u = np.linalg.lstsq(null, A_n @ null, rcond=None)[0]
        unobs = np.linalg.eigvals(A_u)
    else:
        unobs = np.zeros(0)
    return ObservableReduction(
        measurement=tuple(measurement), T=T, A_r=A_r, B_r=B_r, C_r=C_r, E_r=E_r,
        z_names=_coordinate_names(model, T), rank=r, T_num=T_n, A_num=A_rn,
        B_num=num(B_r), C_num=num(C_r), E_num=num(E_r), unobservable_eigenvalues=unobs)


def _normal(expr):
    """A cheap canonical form of a rational expression (``cancel`` of ``together``)."""
    return sp.factor_terms(sp.cancel(sp.together(expr)))


def _numeric_basis(O, num, r):
    """Fallback: a row basis of O chosen by pivoted QR at the numeric point."""
    import scipy.linalg

    On = num(O)
    _, _, piv = scipy.linalg.qr(On.T, pivoting=True)
    return sp.Matrix([O.row(int(i)) for i in sorted(piv[:r])])


def _null_space(T):
    _, s, vt = np.linalg.svd(T)
    rank = int(np.sum(s > 1e-12 * s[0]))
    return vt[rank:].T


def _coordinate_names(model: Model, T: sp.Matrix) -> tuple[str, ...]:
    names = []
    states = [s.name for s in model.states]
    for i in range(T.rows):
        row = list(T.row(i))
        nz = [k for k, v in enumerate(row) if v != 0]
        if len(nz) == 1 and row[nz[0]] == 1:
            names.append(states[nz[0]])
        elif (len(nz) == 2 and row[nz[0]] == 1 and row[nz[1]] == -1
              and states[nz[0]][0] == states[nz[1]][0]):
            names.append(states[nz[0]][0] + "d")
        else:
            names.append(f"z{i + 1}")
    # keep names unique
    seen = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}_{seen[n]}")
    return tuple(out)
