"""Row bases of the observable subspace and the reduced matrices in those coordinates.

The algebra behind :func:`fdigen.derive.observability.observable_reduction`: a basis ``T``
of the row space of the observability matrix ``O = [C; C A; ...]`` chosen by echelon rows
(symbolic where the generic rank equals the numeric one, else numeric at the operating
point), and ``A_r = T A T^T (T T^T)^{-1}``, ``C_r = C_m T^T (T T^T)^{-1}`` in a canonical
form.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.safe_lambdify import safe_lambdify

def reduced_A_C(T, A, Cm):
    """``A_r = T A T^T (T T^T)^{-1}`` and ``C_r = C_m T^T (T T^T)^{-1}``, in :func:`normal_form` form.

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
        return (T * A * pinv).applyfunc(normal_form), (Cm * pinv).applyfunc(normal_form)
    TA = T * A.extract(list(range(A.rows)), P)
    return TA.applyfunc(normal_form), Cm.extract(list(range(Cm.rows)), P).applyfunc(normal_form)


def _reduced_A_C_fraction_free(T, A, Cm):
    """``T A T^T (T T^T)^{-1}`` and ``C_m T^T (T T^T)^{-1}`` over a polynomial ring.

    With ``T = D^{-1} N`` (each row over the least common multiple ``D_i`` of its
    denominators), ``A = N_A / d_A``, ``C_m = N_C / d_C`` and ``G = N N^T`` inverted
    fraction free (``G^{-1} = H / g``, :meth:`DomainMatrix.inv_den`):

    .. math::

        (A_r)_{ij} = \\frac{(N N_A N^T H)_{ij} D_j}{D_i\\, d_A\\, g},\\qquad
        (C_r)_{ij} = \\frac{(N_C N^T H)_{ij} D_j}{d_C\\, g}

    every product exact in the ring, then one cancellation per entry (:func:`normal_form`):
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
    A_r = sp.Matrix(r, r, lambda i, j: normal_form(XA[i, j] * Dx[j] / (Dx[i] * dA * g)))
    C_r = sp.Matrix(p, r, lambda i, j: normal_form(XC[i, j] * Dx[j] / (dC * g)))
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


def normal_form(expr):
    """A cheap canonical form of a rational expression (``cancel`` of ``together``)."""
    return sp.factor_terms(sp.cancel(sp.together(expr)))



def echelon_rows(Cm, A, num, r):
    """The first ``r`` rows of the reduced row echelon form of ``O = [C_m; C_m A; ...]``.

    Equal to ``O.rref()[0][:r, :]`` with every entry in the :func:`normal_form` form (the
    reduced row echelon form of a matrix over the field of rational functions is unique,
    and :func:`normal_form` is a canonical form), with the same fallback to a numeric row basis
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
        rref, pivots = O.rref(iszerofunc=lambda e: normal_form(e) == 0, simplify=normal_form)
        T = sp.Matrix(rref[:r, :]).applyfunc(normal_form)
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
    """``[C_m; C_m A; ...; C_m A^(blocks-1)]``, each block in :func:`normal_form` form."""
    out = [Cm]
    for _ in range(blocks - 1):
        out.append((out[-1] * A).applyfunc(normal_form))
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
    ``T = X / d``; each entry is then brought to the :func:`normal_form` form (one
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
    T = sp.Matrix(r, n, lambda i, j: normal_form(X[i, j] / det) if j not in pivot_cols else 0)
    for k, j in enumerate(pivot_cols):
        T[k, j] = sp.Integer(1)
    return T


def _gauss_jordan_symbolic(Ob, pivot_cols, values):
    """:func:`_gauss_jordan` by symbolic row operations, pivots chosen by their value at
    the random point (never a hidden zero), entries kept in :func:`normal_form` form."""
    rows = [list(Ob.row(i)) for i in range(Ob.rows)]
    vals = [list(v) for v in values]
    for k, j in enumerate(pivot_cols):
        best = max(range(k, len(rows)), key=lambda i: abs(vals[i][j]))
        rows[k], rows[best] = rows[best], rows[k]
        vals[k], vals[best] = vals[best], vals[k]
        piv, pv = rows[k][j], vals[k][j]
        rows[k] = [normal_form(e / piv) for e in rows[k]]
        vals[k] = [v / pv for v in vals[k]]
        for i in range(len(rows)):
            if i == k:
                continue
            f, fv = rows[i][j], vals[i][j]
            if f != 0:
                rows[i] = [normal_form(a - f * b) for a, b in zip(rows[i], rows[k])]
                vals[i] = [a - fv * b for a, b in zip(vals[i], vals[k])]
    T = sp.Matrix(rows)
    for k, j in enumerate(pivot_cols):
        for i in range(T.rows):
            T[i, j] = sp.Integer(1) if i == k else sp.Integer(0)
    return T.applyfunc(normal_form)


def _numeric_basis(O, num, r):
    """Fallback: a row basis of O chosen by pivoted QR at the numeric point."""
    import scipy.linalg

    On = num(O)
    _, _, piv = scipy.linalg.qr(On.T, pivoting=True)
    return sp.Matrix([O.row(int(i)) for i in sorted(piv[:r])])


def null_space(T):
    """A basis of ``ker T`` (columns), exact: sympy on the binary values of ``T`` (the rows
    of ``T`` are independent by construction), rounded once."""
    T = np.atleast_2d(np.asarray(T, dtype=float))
    basis = sp.Matrix([[sp.Rational(float(v)) for v in row] for row in T]).nullspace()
    if not basis:
        return np.zeros((T.shape[1], 0))
    return np.array([[float(v) for v in b] for b in basis], dtype=float).T
