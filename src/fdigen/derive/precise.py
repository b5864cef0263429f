"""Kernel-independent small-matrix arithmetic in extended precision (mpmath).

Every number a design writes into generated text must be the same bits on every machine.
Products, solves, exponentials and eigenvalues computed with NumPy/SciPy go through the
BLAS/LAPACK kernels the CPU selects (OpenBLAS picks Haswell, SkylakeX, ... at run time);
their rounding differs in the last bits, and an ill-conditioned problem amplifies that.
The functions here take double matrices (exact binary values), compute in ``PREC`` bits
with mpmath (pure Python, the same on every machine) and round each result once to the
nearest double: the result is the correctly rounded value of the exact operation on the
given inputs (up to an error of ``2^-PREC`` relative, far below half an ulp), whatever the
CPU. The matrices of a design are small (at most ~15 x 15), so this costs milliseconds.
"""

from __future__ import annotations

import numpy as np

#: Working precision in bits (double has 53).
PREC = 200


def _mp():
    import mpmath

    return mpmath


def to_mp(A):
    """An mpmath matrix holding the exact values of a real (double) array."""
    mpmath = _mp()
    A = np.atleast_2d(np.asarray(A, dtype=float))
    return mpmath.matrix([[mpmath.mpf(float(v)) for v in row] for row in A])


def to_float(M, shape=None) -> np.ndarray:
    """Round an mpmath matrix to doubles, entry by entry (round to nearest even)."""
    out = np.array([[float(M[i, j]) for j in range(M.cols)] for i in range(M.rows)],
                   dtype=float).reshape(M.rows, M.cols)
    return out.reshape(shape) if shape is not None else out


def matmul(*arrays) -> np.ndarray:
    """The product ``A_1 A_2 ... A_k`` of double arrays, correctly rounded once.

    Vectors are accepted as the last factor (the result is then a vector).
    """
    mpmath = _mp()
    vector = np.ndim(arrays[-1]) == 1
    with mpmath.workprec(PREC):
        mats = [to_mp(a) for a in arrays[:-1]]
        last = np.asarray(arrays[-1], dtype=float)
        mats.append(to_mp(last.reshape(-1, 1) if vector else last))
        out = mats[0]
        for m in mats[1:]:
            out = out * m
        res = to_float(out)
    return res.ravel() if vector else res


def expm(A, dt: float = 1.0) -> np.ndarray:
    """The matrix exponential ``e^{A dt}``, correctly rounded (Taylor series with scaling
    and squaring in ``PREC`` bits, :func:`mpmath.expm`)."""
    mpmath = _mp()
    with mpmath.workprec(PREC):
        M = to_mp(A) * mpmath.mpf(float(dt))
        return to_float(mpmath.expm(M))


def zoh(A, G, dt: float):
    """Zero-order-hold matrices ``(e^{A dt}, (int_0^dt e^{A s} ds) G)``, correctly rounded.

    From ``expm([[A, I], [0, 0]] dt) = [[e^{A dt}, Gamma], [0, I]]`` (Van Loan), with the
    product ``Gamma G`` formed before rounding. The exponential is ``2n x 2n`` whatever the
    number of columns of ``G`` (inputs and faults).
    """
    mpmath = _mp()
    A = np.atleast_2d(np.asarray(A, dtype=float))
    n = A.shape[0]
    with mpmath.workprec(PREC):
        big = mpmath.zeros(2 * n, 2 * n)
        Am, h = to_mp(A), mpmath.mpf(float(dt))
        for i in range(n):
            big[i, n + i] = h
            for j in range(n):
                big[i, j] = Am[i, j] * h
        phi = mpmath.expm(big)
        Ad = mpmath.matrix([[phi[i, j] for j in range(n)] for i in range(n)])
        gamma = mpmath.matrix([[phi[i, n + j] for j in range(n)] for i in range(n)])
        G = np.asarray(G, dtype=float).reshape(n, -1)
        Gd = to_float(gamma * to_mp(G)) if G.shape[1] else np.zeros((n, 0))
        return to_float(Ad), Gd


def noise_covariance(A, Qc, dt: float) -> np.ndarray:
    """``Q_d = int_0^dt e^{A s} Q_c e^{A^T s} ds``, symmetric and correctly rounded.

    Van Loan: ``expm([[-A, Q_c], [0, A^T]] dt) = [[., Phi_12], [0, Phi_22]]`` and
    ``Q_d = Phi_22^T Phi_12``, symmetrised, all in ``PREC`` bits.
    """
    mpmath = _mp()
    A = np.atleast_2d(np.asarray(A, dtype=float))
    Qc = np.atleast_2d(np.asarray(Qc, dtype=float))
    n = A.shape[0]
    with mpmath.workprec(PREC):
        Am, Qm, h = to_mp(A), to_mp(Qc), mpmath.mpf(float(dt))
        big = mpmath.zeros(2 * n, 2 * n)
        for i in range(n):
            for j in range(n):
                big[i, j] = -Am[i, j] * h
                big[i, n + j] = Qm[i, j] * h
                big[n + i, n + j] = Am[j, i] * h
        phi = mpmath.expm(big)
        p12 = mpmath.matrix([[phi[i, n + j] for j in range(n)] for i in range(n)])
        p22t = mpmath.matrix([[phi[n + j, n + i] for j in range(n)] for i in range(n)])
        Qd = p22t * p12
        return to_float((Qd + Qd.T) / 2)


def solve(A, B) -> np.ndarray:
    """``A^{-1} B`` (LU with partial pivoting in ``PREC`` bits, column by column),
    correctly rounded."""
    mpmath = _mp()
    B = np.asarray(B, dtype=float)
    vector = B.ndim == 1
    B2 = B.reshape(B.shape[0], -1)
    with mpmath.workprec(PREC):
        Am = to_mp(A)
        cols = [mpmath.lu_solve(Am, to_mp(B2[:, [k]])) for k in range(B2.shape[1])]
        out = np.array([[float(c[i]) for c in cols] for i in range(B2.shape[0])],
                       dtype=float).reshape(B2.shape)
    return out.ravel() if vector else out


def inv(A) -> np.ndarray:
    """``A^{-1}``, correctly rounded."""
    mpmath = _mp()
    with mpmath.workprec(PREC):
        return to_float(mpmath.inverse(to_mp(A)))


def eigvals(A) -> np.ndarray:
    """Eigenvalues of a real matrix, each correctly rounded, in a fixed order.

    Sorted by decreasing modulus, then real part, then imaginary part (of the rounded
    values), so the order does not depend on the algorithm either.
    """
    mpmath = _mp()
    A = np.atleast_2d(np.asarray(A, dtype=float))
    if A.size == 0:
        return np.zeros(0, dtype=complex)
    with mpmath.workprec(PREC):
        return sort_eigenvalues(mp_eigvals(to_mp(A)))


def mp_eigvals(M) -> list:
    """Eigenvalues of an mpmath matrix (:func:`mpmath.eig`; a 1 x 1 matrix directly)."""
    if M.rows == 1:
        return [M[0, 0]]
    return list(_mp().eig(M, left=False, right=False))


def sort_eigenvalues(values) -> np.ndarray:
    """mpmath eigenvalues rounded to complex doubles, in a fixed order (see :func:`eigvals`).

    An imaginary part below ``2^-(PREC/2)`` of the modulus (the algorithm's noise on a real
    eigenvalue) is set to zero.
    """
    mpmath = _mp()
    vals = []
    for e in values:
        re, im = mpmath.re(e), mpmath.im(e)
        if abs(im) <= mpmath.mpf(2) ** (-PREC // 2) * abs(e):
            im = 0
        vals.append(complex(float(re), float(im)))
    vals.sort(key=lambda z: (-abs(z), z.real, z.imag))
    return np.array(vals, dtype=complex)
