"""Modulating-window and smoothing lengths of discover, from the sample time and the plant.

The equation test (:mod:`fdigen.discover.locate`) integrates every equation over disjoint
windows; the state reconstruction smooths the measurements with a Savitzky-Golay filter.
Both need enough samples to average the sensor noise, and a window must stay short against
the plant's slowest time constant (beyond about ten of them it only sees steady state):

.. math::

    T_w = \\max\\bigl(10\\,T_s,\\; \\min(50\\,T_s,\\; 10\\,\\tau_{slow})\\bigr),
    \\qquad T_{sg} = T_w / 2

capped at the log's duration / 40 (never below 10 samples), with :math:`T_s` the log's
sample time and :math:`\\tau_{slow} = 1/\\min|\\mathrm{Re}\\,
\\lambda|` over the stable eigenvalues of the linearisation at the operating point. At
1 kHz (cylinder, DC motor) this is 50 ms and 25 ms; the three tanks sampled at 0.1 s get
5 s and 2.5 s, the heat exchanger at 0.5 s 25 s and 12.5 s.
"""

from __future__ import annotations

import numpy as np


#: A log is cut into at least this many windows (when each keeps 10 samples or more).
MIN_WINDOWS = 40


def slowest_time_constant(model) -> float:
    """:math:`1/\\min|\\mathrm{Re}\\,\\lambda|` over the stable modes at the operating point
    (``inf`` when there is none)."""
    from fdigen.derive.linearisation import linearise

    try:
        ev = np.linalg.eigvals(np.asarray(linearise(model).A, dtype=float))
    except Exception:  # a model whose Jacobian cannot be evaluated: no cap
        return float("inf")
    stable = [-e.real for e in ev if e.real < -1e-9]
    return 1.0 / min(stable) if stable else float("inf")


def discover_windows(model, t, window: float | None = None,
                     smooth: float | None = None) -> tuple[float, float]:
    """Window and smoothing lengths [s]: the given ones, or the rule of the module."""
    if window is not None and smooth is not None:
        return float(window), float(smooth)
    t = np.asarray(t, dtype=float)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1e-3
    tw = max(10 * dt, min(50 * dt, 10 * slowest_time_constant(model)))
    # from the data's own length too: at least MIN_WINDOWS windows in the log (a slowly
    # sampled log of 1024 samples at 4 s held only 20 windows of 50 samples)
    duration = float(t[-1] - t[0]) if t.size > 1 else tw
    tw = min(tw, max(10 * dt, duration / MIN_WINDOWS))
    # round to a whole number of samples, so that 50 samples at 1 kHz is exactly 0.05 s
    tw = round(tw / dt) * dt
    tw = float(f"{tw:.12g}")
    return (float(window) if window is not None else tw,
            float(smooth) if smooth is not None else float(f"{tw / 2:.12g}"))
