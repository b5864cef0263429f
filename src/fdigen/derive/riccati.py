"""Algebraic Riccati equations solved to the correctly rounded double result.

Two stages (see ``docs/reproducibility.md``):

1. **A well-scaled double solve.** The state is scaled by ``D = diag(d)`` (``d`` from the
   states' declared ranges, see :func:`state_scales`) and the outputs by
   ``W = diag(sqrt(diag(R)))``: ``A_s = D^{-1} A D``, ``C_s = W^{-1} C D``,
   ``Q_s = D^{-1} Q D^{-1}``, ``R_s = W^{-1} R W^{-1}``; SciPy's
   ``solve_discrete_are``/``solve_continuous_are`` (the python-control ``dlqe``/``lqe``
   SciPy method) solve the scaled equation and ``P = D P_s D`` transforms back. For the
   pneumatic cylinder the pressures (~1e5 Pa) and the position (~1e-2 m) then are O(1).
2. **Newton refinement in extended precision.** From that stabilising start, Newton's
   method on the Riccati equation (Hewer's iteration in discrete time, Kleinman's in
   continuous time: each step one Stein/Lyapunov equation, solved as a Kronecker linear
   system) runs in :data:`fdigen.derive.precise.PREC` bits with mpmath until the step is
   below ``2^-(PREC-24)`` of the solution; quadratic convergence takes 2-4 steps. The gains
   are formed from the refined ``P`` in the same precision and every result is rounded
   once to double: the correctly rounded solution of the equation for the given (double)
   ``A, C, Q, R``, independent of the BLAS/LAPACK kernels of the stage-1 start.
"""

from __future__ import annotations

import numpy as np

from fdigen.derive import precise

#: Newton steps allowed before the refinement is declared not convergent.
MAX_NEWTON_STEPS = 40


def state_scales(states, T=None) -> np.ndarray:
    """Scale of each state (or of each reduced coordinate ``z = T x``) for the solve.

    A state's scale is the width of its declared ``range``; without a range, its largest
    declared ``limits`` magnitude when numeric, else 1. For reduced coordinates the scale is
    ``|T| d`` (the width of ``z``'s range bounded by the triangle inequality).
    """
    d = []
    for s in states:
        width = None
        if s.range is not None:
            try:
                width = abs(float(s.range[1]) - float(s.range[0]))
            except (TypeError, ValueError):
                width = None
        if not width and s.limits is not None:
            try:
                width = max(abs(float(v)) for v in s.limits)
            except (TypeError, ValueError):
                width = None
        d.append(width if width and np.isfinite(width) else 1.0)
    d = np.array(d, dtype=float)
    if T is not None:
        d = np.abs(np.asarray(T, dtype=float)) @ d
        d[~(d > 0)] = 1.0
    return d


def _scaled(A, C, Q, R, scale):
    n = A.shape[0]
    d = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
    w = np.sqrt(np.diag(R))
    As = A * d[None, :] / d[:, None]
    Cs = C * d[None, :] / w[:, None]
    Qs = Q / d[:, None] / d[None, :]
    Rs = R / w[:, None] / w[None, :]
    return As, Cs, 0.5 * (Qs + Qs.T), 0.5 * (Rs + Rs.T), d


def double_start(A, C, Q, R, scale, discrete: bool) -> np.ndarray:
    """Stage 1: the stabilising Riccati solution ``P`` in double, on the scaled problem."""
    import scipy.linalg

    As, Cs, Qs, Rs, d = _scaled(A, C, Q, R, scale)
    if discrete:
        Ps = scipy.linalg.solve_discrete_are(As.T, Cs.T, Qs, Rs)
    else:
        Ps = scipy.linalg.solve_continuous_are(As.T, Cs.T, Qs, Rs)
    P = Ps * d[:, None] * d[None, :]
    return 0.5 * (P + P.T)


def _kron_solve(mp, Acl, rhs, discrete):
    """Solve ``P = Acl P Acl^T + rhs`` (discrete) or ``Acl P + P Acl^T + rhs = 0``."""
    n = Acl.rows
    K = mp.matrix(n * n, n * n)
    b = mp.matrix(n * n, 1)
    for i in range(n):
        for j in range(n):
            r = i * n + j
            b[r] = rhs[i, j] if discrete else -rhs[i, j]
            for k in range(n):
                for l in range(n):
                    c = k * n + l
                    if discrete:
                        K[r, c] = (1 if r == c else 0) - Acl[i, k] * Acl[j, l]
                    else:
                        v = 0
                        if j == l:
                            v += Acl[i, k]
                        if i == k:
                            v += Acl[j, l]
                        K[r, c] = v
    x = mp.lu_solve(K, b)
    P = mp.matrix(n, n)
    for i in range(n):
        for j in range(n):
            P[i, j] = (x[i * n + j] + x[j * n + i]) / 2
    return P


def _structural_zeros(mp, P, floor):
    """``P`` with the entries at the working precision's noise level set to exactly zero.

    An entry that is zero in exact arithmetic (decoupled states) ends the refinement as
    noise of order ``2^-PREC`` whose value depends on the start; rounded to double it would
    differ between machines. Off the diagonal the level is ``floor * sqrt(|P_ii P_jj|)``,
    on it ``floor * max |P|`` (``floor = 2^-(PREC/2)``, far below double precision and far
    above the noise).
    """
    n = P.rows
    size = _norm(mp, P)
    out = P.copy()
    for i in range(n):
        for j in range(n):
            ref = size if i == j else mp.sqrt(abs(P[i, i] * P[j, j]))
            if abs(P[i, j]) <= floor * ref:
                out[i, j] = 0
    return out


def _norm(mp, M):
    return max((abs(M[i, j]) for i in range(M.rows) for j in range(M.cols)), default=mp.mpf(0))


def refine(A, C, Q, R, P0, discrete: bool) -> dict:
    """Stage 2: Newton's method on the Riccati equation in extended precision.

    Discrete (Hewer), with ``L_k = A P_k C^T (C P_k C^T + R)^{-1}``:

    .. math:: P_{k+1} = (A - L_k C) P_{k+1} (A - L_k C)^T + Q + L_k R L_k^T

    Continuous (Kleinman), with ``L_k = P_k C^T R^{-1}``:

    .. math:: (A - L_k C) P_{k+1} + P_{k+1} (A - L_k C)^T + Q + L_k R L_k^T = 0

    Returns
    -------
    dict
        ``P``, ``S = C P C^T + R``, ``M`` (filter gain ``P C^T S^{-1}``; continuous:
        ``P C^T R^{-1}``), ``L`` (predictor gain ``A M``; continuous: ``M``), ``poles``
        (eigenvalues of ``A - L C``) and ``steps``; each entry correctly rounded to double.

    Raises
    ------
    ArithmeticError
        If the iteration does not converge (no stabilising solution).
    """
    import mpmath as mp

    with mp.workprec(precise.PREC):
        Am, Cm, Qm, Rm = (precise.to_mp(M) for M in (A, C, Q, R))
        P = precise.to_mp(P0)
        tol = mp.mpf(2) ** (-(precise.PREC - 24))
        floor = mp.mpf(2) ** (-(precise.PREC // 2))
        Rinv = mp.inverse(Rm)
        previous = None
        for step in range(1, MAX_NEWTON_STEPS + 1):
            if discrete:
                L = Am * P * Cm.T * mp.inverse(Cm * P * Cm.T + Rm)
            else:
                L = P * Cm.T * Rinv
            Acl = Am - L * Cm
            P_next = _kron_solve(mp, Acl, Qm + L * Rm * L.T, discrete)
            change = _norm(mp, P_next - P)
            P = P_next
            if not mp.isfinite(change):
                raise ArithmeticError("Newton refinement of the Riccati solution diverged")
            size = _norm(mp, P)
            if change <= tol * size:
                break
            # stagnation at the working precision's noise (an ill-conditioned equation)
            if previous is not None and change <= floor * size and change >= previous / 4:
                break
            previous = change
        else:
            raise ArithmeticError("Newton refinement of the Riccati solution did not converge")
        P = _structural_zeros(mp, P, floor)
        S = Cm * P * Cm.T + Rm
        if discrete:
            M = P * Cm.T * mp.inverse(S)
            L = Am * M
        else:
            M = L = P * Cm.T * Rinv
        closed = Am - L * Cm
        out = {k: precise.to_float(v) for k, v in
               (("P", P), ("S", S), ("M", M), ("L", L))}
        out["poles"] = precise.sort_eigenvalues(precise.mp_eigvals(closed))
    out["steps"] = step
    return out
