"""Steady-state Kalman gains from the algebraic Riccati equation.

The gains are python-control's ``dlqe``/``lqe`` as computed by its SciPy method (the one it
uses when Slycot is absent), written out here step for step: the same SciPy calls on the
same arrays give the same bits, without importing python-control (seconds at start-up).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fdigen.derive.observability import undetectable_modes
from fdigen.errors import DesignError


@dataclass(frozen=True)
class KalmanGain:
    """A steady-state Kalman gain and the Riccati solution it comes from.

    For a discrete design, ``L`` is the predictor gain of python-control's ``dlqe``
    (``x[k+1] = A x[k] + B u[k] + L (y[k] - C x[k])``), ``M = P C^T (C P C^T + R)^{-1}`` the
    filter (measurement-update) gain, ``P`` the a-priori error covariance and ``S`` the
    innovation covariance ``C P C^T + R``. For a continuous design, ``L = P C^T R^{-1}`` and
    ``M`` equals ``L``.
    """

    L: np.ndarray
    M: np.ndarray
    P: np.ndarray
    S: np.ndarray
    poles: np.ndarray
    discrete: bool


def _check_weights(Q, R, n, p):
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    R = np.atleast_2d(np.asarray(R, dtype=float))
    if Q.shape != (n, n):
        raise DesignError(f"process noise Q must be {n}x{n}, got {Q.shape}")
    if R.shape != (p, p):
        raise DesignError(f"measurement noise R must be {p}x{p}, got {R.shape}")
    for name, W, strict in (("Q", Q, False), ("R", R, True)):
        if not np.all(np.isfinite(W)):
            raise DesignError(f"noise weight {name} is not finite")
        if not np.allclose(W, W.T, rtol=1e-12, atol=0):
            raise DesignError(f"noise weight {name} is not symmetric")
        eig = np.linalg.eigvalsh(W)
        if strict and eig.min() <= 0:
            raise DesignError(f"measurement noise weight R must be positive definite "
                              f"(smallest eigenvalue {eig.min():.3g})")
        if not strict and eig.min() < -1e-12 * max(1.0, eig.max()):
            raise DesignError(f"process noise weight Q must be positive semidefinite "
                              f"(smallest eigenvalue {eig.min():.3g})")
    return Q, R


def _check_detectable(A, C, discrete, what):
    bad = undetectable_modes(A, C, discrete)
    if bad:
        kind = "on or outside the unit circle" if discrete else "in the closed right half-plane"
        raise DesignError(
            f"{what}: the pair (A, C) is not detectable: mode(s) "
            f"{', '.join(f'{complex(b):.4g}' for b in bad)} {kind} are unobservable; "
            "reduce the model to its observable part for this measurement set first")


def discrete_kalman_gain(Ad, Cd, Qd, Rd, what: str = "Kalman filter") -> KalmanGain:
    """Steady-state discrete Kalman gain from the discrete algebraic Riccati equation.

    .. math::

        P = A P A^T - A P C^T (C P C^T + R)^{-1} C P A^T + Q,\\qquad
        M = P C^T (C P C^T + R)^{-1},\\qquad L = A M

    (eqs 13-14 of the paper in discrete time; solved as :func:`control.dlqe` does with
    its SciPy method, see :func:`_dlqe`).

    Parameters
    ----------
    Ad : (n, n) array
    Cd : (p, n) array
    Qd : (n, n) array, positive semidefinite (process noise, ``G = I``)
    Rd : (p, p) array, positive definite
    what : str
        Name used in error messages.

    Raises
    ------
    DesignError
        If the pair is not detectable or the weights are not (semi)definite.
    """
    Ad = np.atleast_2d(np.asarray(Ad, dtype=float))
    Cd = np.atleast_2d(np.asarray(Cd, dtype=float))
    n, p = Ad.shape[0], Cd.shape[0]
    Qd, Rd = _check_weights(Qd, Rd, n, p)
    _check_detectable(Ad, Cd, True, what)
    try:
        L, P, E = _dlqe(Ad, np.eye(n), Cd, Qd, Rd)
    except Exception as exc:  # ValueError/LinAlgError from SciPy
        raise DesignError(f"{what}: Riccati equation has no stabilising solution ({exc})")
    P = np.asarray(P)
    S = Cd @ P @ Cd.T + Rd
    M = P @ Cd.T @ np.linalg.inv(S)
    return KalmanGain(np.asarray(L), M, P, S, np.asarray(E), True)


def continuous_kalman_gain(A, C, Q, R, what: str = "Kalman filter") -> KalmanGain:
    """Steady-state continuous Kalman gain (reference), as :func:`control.lqe` (:func:`_lqe`).

    .. math:: A P + P A^T - P C^T R^{-1} C P + Q = 0,\\qquad L = P C^T R^{-1}
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    C = np.atleast_2d(np.asarray(C, dtype=float))
    n, p = A.shape[0], C.shape[0]
    Q, R = _check_weights(Q, R, n, p)
    _check_detectable(A, C, False, what)
    try:
        L, P, E = _lqe(A, np.eye(n), C, Q, R)
    except Exception as exc:
        raise DesignError(f"{what}: Riccati equation has no stabilising solution ({exc})")
    P = np.asarray(P)
    return KalmanGain(np.asarray(L), np.asarray(L), P, C @ P @ C.T + R, np.asarray(E), False)


def _dlqe(A, G, C, QN, RN):
    """python-control 0.10's ``dlqe(A, G, C, QN, RN, method="scipy")``, operation for operation.

    .. math::

        P = A P A^T - A P C^T (C P C^T + R)^{-1} C P A^T + G Q G^T,\\qquad
        L^T = (C P C^T + R)^{-1} C P A^T

    Returns
    -------
    L : (n, p) array
        Predictor gain.
    P : (n, n) array
        Stabilising solution of the discrete algebraic Riccati equation.
    E : (n,) array
        Eigenvalues of ``A - L C``.
    """
    import scipy.linalg

    A, G, C, QN, RN = (np.array(M, ndmin=2, dtype=float) for M in (A, G, C, QN, RN))
    At, Bt, Q = A.T, C.T, G @ QN @ G.T
    _check_riccati(At, Bt, Q, RN)
    X = scipy.linalg.solve_discrete_are(At, Bt, Q, RN, e=None, s=None)
    LT = scipy.linalg.solve(Bt.T @ X @ Bt + RN, Bt.T @ X @ At)
    E = scipy.linalg.eigvals(At - Bt @ LT)
    return LT.T, X, E


def _lqe(A, G, C, QN, RN):
    """python-control 0.10's ``lqe(A, G, C, QN, RN, method="scipy")``, operation for operation.

    .. math:: A P + P A^T - P C^T R^{-1} C P + G Q G^T = 0,\\qquad L^T = R^{-1} C P

    Returns
    -------
    L, P, E
        Gain, Riccati solution and the eigenvalues of ``A - L C``.
    """
    import scipy.linalg

    A, G, C, QN, RN = (np.array(M, ndmin=2, dtype=float) for M in (A, G, C, QN, RN))
    At, Bt, Q = A.T, C.T, G @ QN @ G.T
    _check_riccati(At, Bt, Q, RN)
    X = scipy.linalg.solve_continuous_are(At, Bt, Q, RN)
    LT = np.linalg.solve(RN, Bt.T @ X)
    E, _ = np.linalg.eig(At - Bt @ LT)
    return LT.T, X, E


def _check_riccati(A, B, Q, R):
    """python-control's shape and exact-symmetry checks of the Riccati data
    (``mateqn._check_shape``); raises ValueError."""
    n, m = A.shape[0], B.shape[1]
    for name, M, shape in (("A", A, (n, n)), ("C", B, (n, m)), ("QN", Q, (n, n)),
                           ("RN", R, (m, m))):
        if M.shape != shape:
            raise ValueError(f"Incompatible dimensions of {name} matrix; expected {shape} "
                             f"but found {M.shape}")
    for name, M in (("QN", Q), ("RN", R)):
        if not ((M - M.T) < np.finfo(M.dtype).eps).all():
            raise ValueError(f"{name} must be a symmetric matrix")
