"""Steady-state Kalman gains from the algebraic Riccati equation.

The gains are python-control's ``dlqe``/``lqe`` (equal to them within the accuracy of
their SciPy method), computed without importing python-control (seconds at start-up):
SciPy's solver on a well-scaled problem, then Newton steps in extended precision, so that
the numbers are the correctly rounded solution on every machine
(:mod:`fdigen.derive.riccati`, ``docs/reproducibility.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fdigen.derive import riccati
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


def discrete_kalman_gain(Ad, Cd, Qd, Rd, what: str = "Kalman filter",
                         scale=None) -> KalmanGain:
    """Steady-state discrete Kalman gain from the discrete algebraic Riccati equation.

    .. math::

        P = A P A^T - A P C^T (C P C^T + R)^{-1} C P A^T + Q,\\qquad
        M = P C^T (C P C^T + R)^{-1},\\qquad L = A M

    (eqs 13-14 of the paper in discrete time; python-control's ``dlqe`` gains). Solved on
    the scaled problem and refined by Newton steps in extended precision
    (:mod:`fdigen.derive.riccati`): every returned number is the correctly rounded double,
    the same bits on every machine.

    Parameters
    ----------
    Ad : (n, n) array
    Cd : (p, n) array
    Qd : (n, n) array, positive semidefinite (process noise, ``G = I``)
    Rd : (p, p) array, positive definite
    what : str
        Name used in error messages.
    scale : (n,) array, optional
        Scale of each state (:func:`fdigen.derive.riccati.state_scales`) for the double
        solve that starts the refinement.

    Raises
    ------
    DesignError
        If the pair is not detectable or the weights are not (semi)definite.
    """
    return _kalman_gain(Ad, Cd, Qd, Rd, what, scale, True)


def continuous_kalman_gain(A, C, Q, R, what: str = "Kalman filter",
                           scale=None) -> KalmanGain:
    """Steady-state continuous Kalman gain (reference), python-control's ``lqe`` gains.

    .. math:: A P + P A^T - P C^T R^{-1} C P + Q = 0,\\qquad L = P C^T R^{-1}

    Solved and refined as :func:`discrete_kalman_gain`.
    """
    return _kalman_gain(A, C, Q, R, what, scale, False)


def _kalman_gain(A, C, Q, R, what, scale, discrete):
    A = np.atleast_2d(np.asarray(A, dtype=float))
    C = np.atleast_2d(np.asarray(C, dtype=float))
    n, p = A.shape[0], C.shape[0]
    Q, R = _check_weights(Q, R, n, p)
    _check_detectable(A, C, discrete, what)
    try:
        P0 = riccati.double_start(A, C, Q, R, scale, discrete)
        sol = riccati.refine(A, C, Q, R, P0, discrete)
    except Exception as exc:  # ValueError/LinAlgError from SciPy, ArithmeticError
        raise DesignError(f"{what}: Riccati equation has no stabilising solution ({exc})")
    return KalmanGain(sol["L"], sol["M"], sol["P"], sol["S"], sol["poles"], discrete)
