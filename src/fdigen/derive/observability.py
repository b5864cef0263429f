"""Observability: rank test per measurement set and reduction to the observable part."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp
from sympy.matrices.utilities import dotprodsimp

from fdigen.derive import precise
from fdigen.derive.linearisation import numeric, operating_point_substitution, symbolic_jacobians
from fdigen.derive.reduction_basis import echelon_rows, normal_form, null_space, reduced_A_C
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
    numeric_fallback : str
        Empty for the symbolic reduction; else why the numeric basis of
        :func:`numeric_reduction` was used (the symbolic step ran past its budget).
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
    numeric_fallback: str = ""


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
    """Eigenvalues of ``A`` that are unstable or marginal and unobservable through ``C``.

    An eigenvalue within rounding of zero (``|lambda| <= 1e-12 ||A||``: an integrator) is
    tested as exactly zero: the computed one (-2.5e-15 or -3.0e-15 on a hydraulic press
    whose ``||A||`` is 5.6e9, by the last bits of its operating point) moved the rank
    test's ratio across its tolerance, and a valve command written in % instead of V
    changed which sensors could detect the ram's position, and a parity residual's
    realignment."""
    n = A.shape[0]
    out = []
    zero = 1e-12 * float(np.linalg.norm(A, 2)) if A.size else 0.0
    for lam in np.linalg.eigvals(A):
        if not discrete and abs(lam) <= zero:
            lam = 0.0
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
    from fdigen.derive.nonsmooth import jacobian

    return jacobian(sp.Matrix(exprs), model.x)


def measurement_expressions(model: Model, measurement: tuple[str, ...],
                            with_faults: bool = False) -> list[sp.Expr]:
    """Measured expressions as functions of the states (outputs' ``h`` substituted; with
    ``with_faults``, the faults' terms in ``h`` kept)."""
    outs = {o.name: o.symbol for o in model.outputs}
    h = model.h(with_faults=with_faults)
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

    The observability matrix ``O = [C_m; C_m A; ...; C_m A^{n-1}]`` at the symbolic
    operating point has a numeric rank ``r`` at the numeric operating point, which decides
    the order; the first ``r`` rows of its reduced row echelon form give the coordinate
    change ``T`` (see :func:`echelon_rows`: the echelon form is computed from a row
    basis chosen numerically, not by eliminating all of ``O`` symbolically). Then (see
    :class:`ObservableReduction`)

    .. math::

        A_r = T A T^T (T T^T)^{-1},\\quad B_r = T B,\\quad C_r = C_m T^T (T T^T)^{-1}.

    For the pneumatic cylinder measured by position this yields eq (15) of the paper: the
    third-order model in ``[Pd, x, xdot]`` with ``dPd/dt = (a - b) xdot + (c - d) v``.

    Raises
    ------
    DesignError
        If nothing is observable, or the reduction does not reproduce the measurement.
    """
    from fdigen.derive.budget import (BudgetExceeded, known_over_budget, mark_over_budget,
                                      symbolic_budget, time_budget)

    budget = symbolic_budget()
    import warnings

    from fdigen.errors import FdigenNote

    key = _reduction_key(model, measurement, operating_point, parameters, budget)
    red = _REDUCTIONS.get(key)
    if red is not None:
        if red.numeric_fallback:              # the note again, for this derivation too
            warnings.warn(red.numeric_fallback, FdigenNote, stacklevel=2)
        return red
    msg = (f"{model.source or model.name}: the symbolic observable reduction for "
           f"measurement {list(measurement)} exceeded its budget of {budget:g} s "
           "(FDIGEN_SYMBOLIC_BUDGET); using a numeric basis at the operating point instead "
           "(the reduced matrices are numbers: a filter or parallel model on it uses the "
           "operating point's, not scheduled ones)")
    mark = f"{key}-{_code_key()}"
    if known_over_budget(mark):
        warnings.warn(msg + "; known from an earlier attempt, not tried again", FdigenNote,
                      stacklevel=2)
        red = numeric_reduction(model, measurement, operating_point, parameters, note=msg)
    else:
        try:
            with dotprodsimp(False), time_budget(
                    budget, f"observable reduction for {list(measurement)}"):
                red = _observable_reduction(model, measurement, operating_point, parameters)
        except BudgetExceeded:
            warnings.warn(msg, FdigenNote, stacklevel=2)
            mark_over_budget(mark)
            red = numeric_reduction(model, measurement, operating_point, parameters,
                                    note=msg)
    if len(_REDUCTIONS) >= 64:
        _REDUCTIONS.clear()
    _REDUCTIONS[key] = red
    return red


#: reductions derived in this process, by :func:`_reduction_key`: a design derived again
#: with other thresholds (``fdigen tune`` and ``inspect`` fill missing ones in rounds)
#: reuses them instead of repeating minutes of symbolic work
_REDUCTIONS: dict = {}


def _code_key() -> str:
    """Digest of the reduction's source (this module and its row-basis algebra): a budget
    mark holds for the code that ran past it."""
    import hashlib
    from pathlib import Path

    from fdigen.derive import reduction_basis

    here = Path(__file__).read_bytes() + Path(reduction_basis.__file__).read_bytes()
    return hashlib.sha256(here).hexdigest()[:16]


def _reduction_key(model, measurement, operating_point, parameters, budget) -> str:
    """Everything an observable reduction reads: the physical model (its canonical
    description without ``[fdi]`` and ``[simulation]``), the measurement, the point and
    the budget (a budget that ran out gave the numeric fallback)."""
    import hashlib
    import json

    from fdigen.model.model_file import canonical_description

    desc = canonical_description(model)
    desc.pop("fdi", None)
    desc.pop("simulation", None)
    text = json.dumps([desc, list(measurement), operating_point, parameters, budget],
                      sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def numeric_reduction(model: Model, measurement: tuple[str, ...], operating_point=None,
                      parameters=None, note: str = "") -> ObservableReduction:
    """The observable reduction computed numerically at the operating point.

    The fallback of :func:`observable_reduction` past its time budget. With ``A``,
    ``C_m`` the Jacobians at the numeric operating point, ``O = [C_m; C_m A; ...]``, its
    rank ``r`` and a row basis ``O_b`` of ``r`` rows (pivoted QR), the pivot columns ``P``
    of ``O_b`` (its leftmost independent columns, as in the reduced row echelon form)
    give the same basis as the symbolic reduced row echelon form, numerically

    .. math:: T = O_b[:, P]^{-1} O_b \\quad (T[:, P] = I),\\qquad A_r = (T A)[:, P],
              \\quad C_r = C_m[:, P],\\quad B_r = T B,\\quad E_r = T E

    (``ker T = ker O`` is ``A``-invariant and holds ``ker C_m``). Entries within
    ``1e-12`` of an integer are rounded to it, so ``Pp - Pn`` keeps its name ``Pd``.
    """
    import scipy.linalg

    jac = symbolic_jacobians(model)
    subs = operating_point_substitution(model, operating_point, parameters)
    A = numeric(jac.A, subs)
    B = numeric(jac.B, subs)
    E = numeric(jac.E, subs) if jac.E.shape[1] else np.zeros((A.shape[0], 0))
    Cm = numeric(measurement_jacobian(model, measurement), subs)
    n = A.shape[0]
    r = observability_rank(A, Cm)
    if r == 0:
        raise DesignError(f"nothing is observable from measurement {list(measurement)}")
    O = observability_matrix(A, Cm)
    _, _, rows = scipy.linalg.qr(O.T, pivoting=True)
    Ob = O[sorted(rows[:r])]
    P = []
    for j in range(n):  # leftmost independent columns: the pivots of the echelon form
        if len(P) < r and np.linalg.matrix_rank(Ob[:, P + [j]] / np.abs(Ob).max(
                axis=1, keepdims=True)) > len(P):
            P.append(j)
    T = np.linalg.solve(Ob[:, P], Ob)
    near = np.abs(T - np.round(T)) < 1e-12
    T[near] = np.round(T[near])
    A_r, C_r = (T @ A)[:, P], Cm[:, P]
    B_r, E_r = T @ B, T @ E

    def sym(M):
        return sp.Matrix(M.shape[0], M.shape[1],
                         lambda i, j: sp.Integer(int(M[i, j])) if float(M[i, j]).is_integer()
                         else sp.Float(float(M[i, j]), 17))

    Ts = sym(T)
    null = null_space(T)
    unobs = (np.linalg.eigvals(np.linalg.lstsq(null, A @ null, rcond=None)[0])
             if null.shape[1] else np.zeros(0))
    return ObservableReduction(
        measurement=tuple(measurement), T=Ts, A_r=sym(A_r), B_r=sym(B_r), C_r=sym(C_r),
        E_r=sym(E_r), z_names=_coordinate_names(model, Ts), rank=r, T_num=T, A_num=A_r,
        B_num=B_r, C_num=C_r, E_num=E_r, unobservable_eigenvalues=unobs,
        numeric_fallback=note or "numeric basis at the operating point")


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

    T = echelon_rows(Cm, A, num, r)
    A_r, C_r = reduced_A_C(T, A, Cm)
    B_r = (T * B).applyfunc(normal_form)
    E_r = (T * E).applyfunc(normal_form)

    T_n = num(T)
    A_rn = num(A_r)
    if not np.allclose(T_n @ A_n, A_rn @ T_n, rtol=1e-8, atol=1e-8 * np.abs(T_n @ A_n).max()):
        raise DesignError("observable reduction failed: ker T is not A-invariant")
    # unobservable dynamics: A restricted to ker T (N A_u = A N, least squares), computed
    # without BLAS so that design.json has the same bits on every CPU
    null = null_space(T_n)
    if null.shape[1]:
        A_u = precise.solve(precise.matmul(null.T, null), precise.matmul(null.T, A_n, null))
        unobs = precise.eigvals(A_u)
    else:
        unobs = np.zeros(0)
    return ObservableReduction(
        measurement=tuple(measurement), T=T, A_r=A_r, B_r=B_r, C_r=C_r, E_r=E_r,
        z_names=_coordinate_names(model, T), rank=r, T_num=T_n, A_num=A_rn,
        B_num=num(B_r), C_num=num(C_r), E_num=num(E_r), unobservable_eigenvalues=unobs)


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
