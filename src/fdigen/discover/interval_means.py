"""The states over each sample interval, where the equation test evaluates ``f``.

The equation test (:mod:`fdigen.discover.locate`) compares the measured increment
``z_{k+1} - z_k`` of a state with ``dt f(x, u_k)`` evaluated over the interval, the
command held. For a state slow against the sample time the interval's mean is the
midpoint of the (smoothed) reconstruction. A state whose own time constant is shorter
than the sample time is not: a fan motor's armature current (``La/Ra`` = 1.9 ms, sampled
every 10 ms) jumps to each PWM step's level within the sample, its smoothed value
misses those jumps, and the equation test "located" structure in the current and the
speed of a log simulated from the exact model (p 3e-13).

For such a state the interval's mean is computed from the raw measurements (smoothing
would average the jumps away) as the exact mean of ``dx/dt = a x + b0 + b1 t``
(:func:`exact_mean`): ``a = df_i/dx_i``, ``b1`` the rate at which the rest of ``f``
changes over the interval (``sum_j df_i/dx_j dx_j/dt``, the command held), ``b0``
fixed by the two samples. With the current's mean taken as if the back-EMF were held
the fan's equation errors at the true parameters were 4.57 A/s (current) and 0.64
rad/s^2 (speed) on a noise-free log; with ``b1``, 0.27 and 0.046, and on the noisy log
neither equation is located (p 0.84 and 0.26). A state is *fast* when the median of
``|a| dt`` over the log exceeds :data:`FAST`; slow states keep the midpoint of the
reconstruction.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.safe_lambdify import safe_lambdify

#: A state with ``median |df_i/dx_i| dt`` above this is fast at the log's sampling.
FAST = 0.5


def jacobian_rows(model, xs: np.ndarray, u: np.ndarray, states) -> dict:
    """``df_i/dx`` (K, n) at every sample for the states ``states`` (indices), the model's
    parameter values; NaN where it cannot be evaluated."""
    rhs = model.f()
    pv = model.parameter_values
    syms = [s.symbol for s in model.states]
    args = syms + [s.symbol for s in model.inputs]
    cols = [xs[:, i] for i in range(xs.shape[1])] + [u[:, j] for j in range(u.shape[1])]
    out = {}
    for i in states:
        row = np.full((len(xs), len(syms)), np.nan)
        for j, x in enumerate(syms):
            expr = sp.diff(rhs[i], x).xreplace(pv)
            try:
                fn = safe_lambdify(args, expr, modules="numpy")
                with np.errstate(all="ignore"):
                    row[:, j] = np.broadcast_to(np.asarray(fn(*cols), dtype=float),
                                                (len(xs),))
            except (TypeError, ValueError, ZeroDivisionError, NameError):
                pass
        out[i] = row
    return out


def exact_mean(x0, x1, a, b1, dt):
    r"""The mean over ``[0, dt]`` of ``x`` with ``dx/dt = a x + b0 + b1 t`` through ``x(0) =
    x0`` and ``x(dt) = x1`` (``b0`` follows from the two values).

    .. math::

        b_0 = \frac{a\,\big(x_1 - x_0 e^{s} - b_1 (e^{s} - 1 - s)/a^2\big)}{e^{s} - 1},
        \quad
        \bar x = -\frac{b_0 + b_1 dt/2}{a} - \frac{b_1}{a^2}
                  + \Big(x_0 + \frac{b_0}{a} + \frac{b_1}{a^2}\Big)\varphi_1(s),

    ``s = a dt``; for ``a dt`` near 0 it tends to the midpoint (only used for
    ``|a dt| >`` :data:`FAST`).
    """
    s = np.clip(a * dt, -700.0, 700.0)
    em1 = np.expm1(s)
    es = em1 + 1.0
    with np.errstate(all="ignore"):
        b0 = a * (x1 - x0 * es - b1 * (em1 - s) / a ** 2) / em1
        mean = -(b0 + b1 * dt / 2) / a - b1 / a ** 2 + (x0 + b0 / a + b1 / a ** 2) * em1 / s
    return np.where(np.isfinite(mean), mean, 0.5 * (x0 + x1))


def interval_means(model, xs: np.ndarray, z: dict, measured, u: np.ndarray,
                   dt: float) -> tuple[np.ndarray, tuple]:
    """The states over each of the ``K - 1`` intervals (the module) and the fast states'
    names.

    Parameters
    ----------
    xs : numpy.ndarray
        The smoothed reconstruction at the samples (K, n).
    z : dict of str to numpy.ndarray
        Measured state name -> raw measurement (K,).
    measured : iterable of int
        Indices of the measured states (the others keep the midpoint of ``xs``).
    """
    xh = 0.5 * (xs[1:] + xs[:-1])
    rows = jacobian_rows(model, xs, u, list(measured))
    fast = [i for i, J in rows.items()
            if np.isfinite(J[:-1, i]).any()
            and np.nanmedian(np.abs(J[:-1, i] * dt)) > FAST]
    if not fast:
        return xh, ()
    signal = xs.copy()
    for i in fast:
        signal[:, i] = z[model.states[i].name]
    rate = np.diff(signal, axis=0) / dt
    for i in fast:
        J = rows[i][:-1]
        a = J[:, i]
        others = np.where(np.isfinite(J), J, 0.0)
        others[:, i] = 0.0
        b1 = np.sum(others * rate, axis=1)      # the rest of f, varying over the interval
        raw = signal[:, i]
        ok = np.isfinite(a) & (np.abs(a * dt) > 1e-3)
        xh[:, i] = np.where(ok, exact_mean(raw[:-1], raw[1:], np.where(ok, a, -1.0), b1, dt),
                            0.5 * (raw[1:] + raw[:-1]))
    return xh, tuple(model.states[i].name for i in fast)
