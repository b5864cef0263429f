"""The initial state of each re-initialised simulation of the equation-error path's report.

The output error of the equation-error path (:func:`fdigen.discover.report.output_error`)
restarts the simulation every ``reinit`` seconds. It started from the state
reconstruction, a Savitzky-Golay smoothing over half a window: right for slow states, but
a fan motor's armature current (time constant 1.9 ms, sampled every 10 ms) follows each
PWM step within the sample, and its smoothed value at a restart was 0.8 A off. One sample
in a hundred carried that error: the report said 5.65x the sensor noise for the exact
model, which re-initialised from the measurements gives 1.03x.

The start is therefore fitted: Gauss-Newton on the first ``M`` samples of the segment,

.. math::

    \\hat x_0 = \\arg\\min_{x_0} \\sum_{k < M} \\big\\| (y_k - h(x_k(x_0), u_k)) / \\sigma
    \\big\\|^2,

``sigma`` the sensor noise, from the reconstruction, the parameters fixed (the model's own
error shows over the rest of the segment; ``M`` is a tenth of it, at least ``4 n`` and
10 samples). A step that does not lower the cost is halved; a fit that fails keeps the
reconstruction.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

#: Gauss-Newton iterations per segment.
ITERATIONS = 6


def fit_samples(n_states: int, segment: int) -> int:
    """``M``: the samples the start is fitted on (see the module)."""
    return int(min(segment, max(10, 4 * n_states, segment // 10)))


def start_fitter(step: ca.Function, n: int, m: int, samples: int) -> ca.Function:
    """``fit(x0, U, Y, W) -> (r, J)``: the weighted output errors of ``samples`` steps of
    ``step`` (``(x, u) -> (x_next, y)``) from ``x0`` and their Jacobian in ``x0``."""
    run = step.mapaccum("start_fit", samples)
    x0 = ca.MX.sym("x0", n)
    U = ca.MX.sym("U", m, samples)
    p = step.size1_out(1)
    Y = ca.MX.sym("Y", p, samples)
    W = ca.MX.sym("W", p, samples)
    _, ys = run(x0, U)
    r = ca.vec(W * (Y - ys))
    return ca.Function("start_fit", [x0, U, Y, W], [r, ca.jacobian(r, x0)])


def fitted_start(fit: ca.Function, x0: np.ndarray, U: np.ndarray, Y: np.ndarray,
                 sigma: np.ndarray, limits) -> np.ndarray:
    """The start minimising the module's cost from ``x0``; ``x0`` itself when the fit
    cannot improve it. ``Y`` may hold NaN (missing samples: no weight); ``limits`` per
    state ``(lo, hi)`` or None."""
    Y = np.asarray(Y, dtype=float)
    W = np.where(np.isfinite(Y), 1.0 / np.where(sigma > 0, sigma, 1.0)[:, None], 0.0)
    Y = np.where(np.isfinite(Y), Y, 0.0)

    def cost_and_jac(x):
        r, J = fit(x, U, Y, W)
        r, J = np.asarray(r, dtype=float).ravel(), np.asarray(J, dtype=float)
        return (float(r @ r) if np.all(np.isfinite(r)) else np.inf), r, J

    def clamp(x):
        return np.array([x[i] if lim is None else min(max(x[i], lim[0]), lim[1])
                         for i, lim in enumerate(limits)], dtype=float)

    x = clamp(np.asarray(x0, dtype=float))
    cost, r, J = cost_and_jac(x)
    if not np.isfinite(cost):
        return np.asarray(x0, dtype=float)
    for _ in range(ITERATIONS):
        if not np.all(np.isfinite(J)):
            break
        dx = np.linalg.lstsq(J, -r, rcond=None)[0]
        for _ in range(8):
            trial = clamp(x + dx)
            c, rt, Jt = cost_and_jac(trial)
            if c < cost:
                break
            dx = dx / 2
        else:
            break
        improved = cost - c
        x, cost, r, J = trial, c, rt, Jt
        if improved <= 1e-9 * max(cost, 1e-300):
            break
    return x
