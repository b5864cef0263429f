"""Observability: rank test per measurement set and reduction to the observable part."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp
from sympy.matrices.utilities import dotprodsimp

from fdigen.derive import precise
from fdigen.derive.linearisation import numeric, operating_point_substitution, symbolic_jacobians
from fdigen.errors import DesignError
from fdigen.model.expression import parse_expression
from fdigen.model.model import Model
from fdigen.safe_lambdify import safe_lambdify

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
    change ``T`` (see :func:`_echelon_rows`: the echelon form is computed from a row
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
        warnings.warn(msg + "; known from an earlier command, not tried again", FdigenNote,
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
    """Digest of this module's source: a budget mark holds for the code that ran past it."""
    import hashlib
    from pathlib import Path

    return hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]


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
    null = _null_space(T)
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

    T = _echelon_rows(Cm, A, num, r)
    A_r, C_r = _reduced_A_C(T, A, Cm)
    B_r = (T * B).applyfunc(_normal)
    E_r = (T * E).applyfunc(_normal)

    T_n = num(T)
    A_rn = num(A_r)
    if not np.allclose(T_n @ A_n, A_rn @ T_n, rtol=1e-8, atol=1e-8 * np.abs(T_n @ A_n).max()):
        raise DesignError("observable reduction failed: ker T is not A-invariant")
    # unobservable dynamics: A restricted to ker T (N A_u = A N, least squares), computed
    # without BLAS so that design.json has the same bits on every CPU
    null = _null_space(T_n)
    if null.shape[1]:
        A_u = precise.solve(precise.matmul(null.T, null), precise.matmul(null.T, A_n, null))
        unobs = precise.eigvals(A_u)
    else:
        unobs = np.zeros(0)
    return ObservableReduction(
        measurement=tuple(measurement), T=T, A_r=A_r, B_r=B_r, C_r=C_r, E_r=E_r,
        z_names=_coordinate_names(model, T), rank=r, T_num=T_n, A_num=A_rn,
        B_num=num(B_r), C_num=num(C_r), E_num=num(E_r), unobservable_eigenvalues=unobs)


def _reduced_A_C(T, A, Cm):
    """``A_r = T A T^T (T T^T)^{-1}`` and ``C_r = C_m T^T (T T^T)^{-1}``, in :func:`_normal` form.

    When ``T`` holds the unit vectors (an echelon form: ``T[:, P] = I`` for its pivot
    columns ``P``), ``T A = A_r T`` and ``C_m = C_r T`` (ker T is A-invariant and holds
    ker C_m) give ``A_r = (T A)[:, P]`` and ``C_r = C_m[:, P]``: the same rational
    functions without the symbolic inverse. Otherwise (a numeric row basis) the formula
    is used as written.
    """
    P = _unit_columns(T)
    if P is None:
        fast = _reduced_A_C_fraction_free(T, A, Cm)
        if fast is not None:
            return fast
        pinv = T.T * (T * T.T).inv()
        return (T * A * pinv).applyfunc(_normal), (Cm * pinv).applyfunc(_normal)
    TA = T * A.extract(list(range(A.rows)), P)
    return TA.applyfunc(_normal), Cm.extract(list(range(Cm.rows)), P).applyfunc(_normal)


def _reduced_A_C_fraction_free(T, A, Cm):
    """``T A T^T (T T^T)^{-1}`` and ``C_m T^T (T T^T)^{-1}`` over a polynomial ring.

    With ``T = D^{-1} N`` (each row over the least common multiple ``D_i`` of its
    denominators), ``A = N_A / d_A``, ``C_m = N_C / d_C`` and ``G = N N^T`` inverted
    fraction free (``G^{-1} = H / g``, :meth:`DomainMatrix.inv_den`):

    .. math::

        (A_r)_{ij} = \\frac{(N N_A N^T H)_{ij} D_j}{D_i\\, d_A\\, g},\\qquad
        (C_r)_{ij} = \\frac{(N_C N^T H)_{ij} D_j}{d_C\\, g}

    every product exact in the ring, then one cancellation per entry (:func:`_normal`):
    the same rational functions as the formula, without rational-function arithmetic in
    the inverse. None when the entries are not rational functions over ZZ or QQ.
    """
    from sympy.polys.matrices import DomainMatrix
    from sympy.polys.polytools import parallel_poly_from_expr

    r, n = T.shape
    p = Cm.rows
    entries = [*T, *A, *Cm]
    fracs = [e.as_numer_denom() for e in entries]
    try:
        polys, _ = parallel_poly_from_expr([x for pair in fracs for x in pair])
    except sp.PolynomialError:
        return None
    if not (polys[0].domain.is_ZZ or polys[0].domain.is_QQ):
        return None
    pairs = [(polys[2 * k], polys[2 * k + 1]) for k in range(len(entries))]

    def lcm(dens):
        out = dens[0]
        for d in dens[1:]:
            out = out.lcm(d)
        return out

    T_pairs = [pairs[i * n:(i + 1) * n] for i in range(r)]
    A_pairs = pairs[r * n:r * n + n * n]
    C_pairs = pairs[r * n + n * n:]
    D = [lcm([d for _, d in row]) for row in T_pairs]
    dA = lcm([d for _, d in A_pairs])
    dC = lcm([d for _, d in C_pairs])
    N = [[num * D[i].exquo(den) for num, den in T_pairs[i]] for i in range(r)]
    NA = [[num * dA.exquo(den) for num, den in A_pairs[i * n:(i + 1) * n]] for i in range(n)]
    NC = [[num * dC.exquo(den) for num, den in C_pairs[i * n:(i + 1) * n]] for i in range(p)]
    exprs = [q.as_expr() for q in (*[x for row in N for x in row],
                                     *[x for row in NA for x in row],
                                     *[x for row in NC for x in row])]
    M = DomainMatrix.from_Matrix(sp.Matrix(len(exprs), 1, exprs))
    ring = M.domain.domain if M.domain.is_PolynomialRing else M.domain
    if not (ring.is_ZZ or ring.is_QQ):
        return None
    flat = [M[k, 0].element for k in range(len(exprs))]
    K = M.domain
    Nm = DomainMatrix([flat[:r * n][i * n:(i + 1) * n] for i in range(r)], (r, n), K)
    off = r * n
    NAm = DomainMatrix([flat[off + i * n:off + (i + 1) * n] for i in range(n)], (n, n), K)
    off += n * n
    NCm = DomainMatrix([flat[off + i * n:off + (i + 1) * n] for i in range(p)], (p, n), K)
    H, g = (Nm * Nm.transpose()).inv_den()
    NtH = Nm.transpose() * H
    XA = (Nm * NAm * NtH).to_Matrix()
    XC = (NCm * NtH).to_Matrix()
    Dx = [d.as_expr() for d in D]
    g = K.to_sympy(g)
    dA, dC = dA.as_expr(), dC.as_expr()
    A_r = sp.Matrix(r, r, lambda i, j: _normal(XA[i, j] * Dx[j] / (Dx[i] * dA * g)))
    C_r = sp.Matrix(p, r, lambda i, j: _normal(XC[i, j] * Dx[j] / (dC * g)))
    return A_r, C_r


def _unit_columns(T):
    """Columns ``P`` with ``T[:, P]`` the identity, or None."""
    out = []
    for k in range(T.rows):
        hit = [j for j in range(T.cols)
               if all(T[i, j] == (1 if i == k else 0) for i in range(T.rows))]
        if not hit:
            return None
        out.append(hit[0])
    return out


def _normal(expr):
    """A cheap canonical form of a rational expression (``cancel`` of ``together``)."""
    return sp.factor_terms(sp.cancel(sp.together(expr)))



def _echelon_rows(Cm, A, num, r):
    """The first ``r`` rows of the reduced row echelon form of ``O = [C_m; C_m A; ...]``.

    Equal to ``O.rref()[0][:r, :]`` with every entry in the :func:`_normal` form (the
    reduced row echelon form of a matrix over the field of rational functions is unique,
    and :func:`_normal` is a canonical form), with the same fallback to a numeric row basis
    (:func:`_numeric_basis`) when the generic rank of ``O`` is not the numeric rank ``r`` at
    the operating point or the echelon rows lose rank there. The generic rank, a row basis
    of ``O`` and the pivot columns are decided in 50-digit arithmetic at two random points
    (:func:`_generic_structure`); then

    * full rank (``r = n``): the echelon form is the identity, nothing symbolic is needed;
    * otherwise only the blocks ``C_m A^k`` that hold the basis rows are formed, and the
      ``r x n`` basis is brought to echelon form by Gauss-Jordan elimination, pivots
      chosen by their value at the random point.

    When the random points disagree (or cannot be evaluated), the whole of ``O`` is
    reduced symbolically, as before.
    """
    n = A.shape[0]
    plan = _generic_structure(Cm, A)
    if plan is None:
        O = _observability_symbolic(Cm, A, n)
        rref, pivots = O.rref(iszerofunc=lambda e: _normal(e) == 0, simplify=_normal)
        T = sp.Matrix(rref[:r, :]).applyfunc(_normal)
        generic = len(pivots)
    else:
        generic, rows, pivot_cols, values = plan
        T = None
        if generic == r == n:
            T = sp.eye(n)
        elif generic == r:
            p = Cm.rows
            O = _observability_symbolic(Cm, A, max(rows) // p + 1)
            T = _gauss_jordan(sp.Matrix([list(O.row(i)) for i in rows]), pivot_cols,
                              [values[i] for i in rows])
    if generic != r or np.linalg.matrix_rank(num(T)) != r:
        T = _numeric_basis(_observability_symbolic(Cm, A, n), num, r)
    return T


def _observability_symbolic(Cm, A, blocks):
    """``[C_m; C_m A; ...; C_m A^(blocks-1)]``, each block in :func:`_normal` form."""
    out = [Cm]
    for _ in range(blocks - 1):
        out.append((out[-1] * A).applyfunc(_normal))
    return sp.Matrix.vstack(*out)


#: Decimal digits of the random-point arithmetic, and the relative size below which a
#: reduced row or pivot counts as zero there.
_DIGITS = 50
_ZERO = 1e-30


def _generic_structure(Cm, A, points: int = 2, seed: int = 20240611):
    """Generic rank, a row basis and the echelon pivot columns of ``O``, numerically.

    ``A`` and ``C_m`` are evaluated with :data:`_DIGITS` digits at ``points`` random points
    (every free symbol uniform in [0.5, 2], a fixed seed: deterministic); ``O`` is formed
    there, its rows are taken greedily in order while they raise the rank, and the pivot
    columns are those of the echelon form of the chosen rows. At a random point the rank
    equals the generic (symbolic) rank with probability one; two points that agree make a
    coincidence negligible.

    Returns
    -------
    tuple or None
        ``(rank, rows, pivot_columns, O_values)`` with ``O_values`` the rows of ``O`` at
        the first point (lists of mpmath numbers), or None when the points disagree or an
        entry cannot be evaluated (then the caller reduces symbolically).
    """
    import random

    import mpmath

    n, p = A.shape[0], Cm.rows
    syms = sorted(A.free_symbols | Cm.free_symbols, key=sp.default_sort_key)
    rng = random.Random(seed)
    found = []
    with mpmath.workdps(_DIGITS):
        try:
            fA = safe_lambdify(syms, A, modules="mpmath")
            fC = safe_lambdify(syms, Cm, modules="mpmath")
        except Exception:  # noqa: BLE001 - any failure means: do it symbolically
            return None
        for _ in range(points):
            args = [mpmath.mpf(rng.randint(500, 2000)) / 1000 for _ in syms]
            try:
                An, Cn = mpmath.matrix(fA(*args)), mpmath.matrix(fC(*args))
            except Exception:  # noqa: BLE001
                return None
            if An.rows != n or An.cols != n or Cn.rows != p or Cn.cols != n:
                return None
            values = [[Cn[i, j] for j in range(n)] for i in range(p)]
            block = Cn
            for _ in range(n - 1):
                block = block * An
                values += [[block[i, j] for j in range(n)] for i in range(p)]
            if not all(mpmath.isfinite(v) for row in values for v in row):
                return None
            rows = _independent_rows(values)
            found.append((len(rows), tuple(rows), _pivot_columns([values[i] for i in rows]),
                          values))
    if any(f[:3] != found[0][:3] for f in found[1:]):
        return None
    return found[0]


def _independent_rows(values):
    """Indices of the rows that raise the rank, taken in order (Gram-Schmidt, twice)."""
    import mpmath

    basis, chosen = [], []
    for i, row in enumerate(values):
        norm = mpmath.sqrt(sum(abs(v) ** 2 for v in row))
        if norm == 0:
            continue
        v = list(row)
        for _ in range(2):
            for b in basis:
                c = sum(mpmath.conj(bk) * vk for bk, vk in zip(b, v))
                v = [vk - c * bk for vk, bk in zip(v, b)]
        rest = mpmath.sqrt(sum(abs(x) ** 2 for x in v))
        if rest > _ZERO * norm:
            basis.append([x / rest for x in v])
            chosen.append(i)
    return chosen


def _pivot_columns(rows):
    """Pivot columns of the reduced row echelon form of full-row-rank ``rows``."""
    M = [list(r) for r in rows]
    scale = max((abs(v) for r in M for v in r), default=0) or 1
    pivots, k = [], 0
    for j in range(len(M[0]) if M else 0):
        if k == len(M):
            break
        best = max(range(k, len(M)), key=lambda i: abs(M[i][j]))
        if abs(M[best][j]) <= _ZERO * scale:
            continue
        M[k], M[best] = M[best], M[k]
        for i in range(len(M)):
            if i != k:
                f = M[i][j] / M[k][j]
                M[i] = [a - f * b for a, b in zip(M[i], M[k])]
        pivots.append(j)
        k += 1
    return tuple(pivots)


def _gauss_jordan(Ob, pivot_cols, values):
    """Reduced row echelon form of the full-row-rank symbolic ``Ob`` with known pivot columns.

    Fraction free: each row is multiplied by the least common multiple of its denominators
    (which leaves the echelon form unchanged), the polynomial matrix ``N`` goes into a
    :class:`~sympy.polys.matrices.DomainMatrix` over a polynomial ring, whose
    fraction-free echelon form ``X / d`` (Bareiss, exact divisions, no gcds) gives
    ``T = X / d``; each entry is then brought to the :func:`_normal` form (one
    cancellation per entry). When the entries are not rational
    functions of their symbols (no polynomial domain), the rows are eliminated
    symbolically (:func:`_gauss_jordan_symbolic`).
    """
    from sympy.polys.matrices import DomainMatrix
    from sympy.polys.polytools import parallel_poly_from_expr

    r, n = Ob.shape
    fracs = [[e.as_numer_denom() for e in Ob.row(i)] for i in range(r)]
    flat = [part for row in fracs for pair in row for part in pair]
    try:
        polys, _ = parallel_poly_from_expr(flat)
    except sp.PolynomialError:
        return _gauss_jordan_symbolic(Ob, pivot_cols, values)
    if not (polys[0].domain.is_ZZ or polys[0].domain.is_QQ):
        return _gauss_jordan_symbolic(Ob, pivot_cols, values)
    polys = iter(polys)
    rows = []
    for i in range(r):
        pairs = [(next(polys), next(polys)) for _ in range(n)]
        common = pairs[0][1]
        for _, den in pairs[1:]:
            common = common.lcm(den)
        rows.append([(num * common.exquo(den)).as_expr() for num, den in pairs])
    N = DomainMatrix.from_Matrix(sp.Matrix(rows))
    ring = N.domain.domain if N.domain.is_PolynomialRing else N.domain
    if not (ring.is_ZZ or ring.is_QQ):
        return _gauss_jordan_symbolic(Ob, pivot_cols, values)
    X, det, pivots = N.rref_den()
    if tuple(pivots) != tuple(pivot_cols):
        return _gauss_jordan_symbolic(Ob, pivot_cols, values)
    X, det = X.to_Matrix(), N.domain.to_sympy(det)
    T = sp.Matrix(r, n, lambda i, j: _normal(X[i, j] / det) if j not in pivot_cols else 0)
    for k, j in enumerate(pivot_cols):
        T[k, j] = sp.Integer(1)
    return T


def _gauss_jordan_symbolic(Ob, pivot_cols, values):
    """:func:`_gauss_jordan` by symbolic row operations, pivots chosen by their value at
    the random point (never a hidden zero), entries kept in :func:`_normal` form."""
    rows = [list(Ob.row(i)) for i in range(Ob.rows)]
    vals = [list(v) for v in values]
    for k, j in enumerate(pivot_cols):
        best = max(range(k, len(rows)), key=lambda i: abs(vals[i][j]))
        rows[k], rows[best] = rows[best], rows[k]
        vals[k], vals[best] = vals[best], vals[k]
        piv, pv = rows[k][j], vals[k][j]
        rows[k] = [_normal(e / piv) for e in rows[k]]
        vals[k] = [v / pv for v in vals[k]]
        for i in range(len(rows)):
            if i == k:
                continue
            f, fv = rows[i][j], vals[i][j]
            if f != 0:
                rows[i] = [_normal(a - f * b) for a, b in zip(rows[i], rows[k])]
                vals[i] = [a - fv * b for a, b in zip(vals[i], vals[k])]
    T = sp.Matrix(rows)
    for k, j in enumerate(pivot_cols):
        for i in range(T.rows):
            T[i, j] = sp.Integer(1) if i == k else sp.Integer(0)
    return T.applyfunc(_normal)


def _numeric_basis(O, num, r):
    """Fallback: a row basis of O chosen by pivoted QR at the numeric point."""
    import scipy.linalg

    On = num(O)
    _, _, piv = scipy.linalg.qr(On.T, pivoting=True)
    return sp.Matrix([O.row(int(i)) for i in sorted(piv[:r])])


def _null_space(T):
    """A basis of ``ker T`` (columns), exact: sympy on the binary values of ``T`` (the rows
    of ``T`` are independent by construction), rounded once."""
    T = np.atleast_2d(np.asarray(T, dtype=float))
    basis = sp.Matrix([[sp.Rational(float(v)) for v in row] for row in T]).nullspace()
    if not basis:
        return np.zeros((T.shape[1], 0))
    return np.array([[float(v) for v in b] for b in basis], dtype=float).T


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
