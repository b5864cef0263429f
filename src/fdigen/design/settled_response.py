"""What a Kalman residual sees of a constant fault once its filter has settled.

A filter with a state its measurement does not pin down can explain a constant fault by
a shifted estimate of that state: its innovation answers the fault's step while it
settles, then returns to zero. The signature table is structural (the fault reaches the
measured expression), so it says the residual responds; the running filter does not.
A user's two-mass drive: the filter of the motor side took a 20 % torque-constant loss
for a shifted shaft twist, its residual never left its noise, and the pair it alone
separated (the torque constant from a load-side friction) was never isolated: a friction
increase, whose action is none, stopped the machine.

For the filter of :class:`fdigen.design.observers.KalmanResidual` on the linearised,
discretised sub-model (``z[k+1] = A z + B u + E f``, measured ``C z + F f``) the prior
estimation error ``eps = z - z^-`` and the residual obey

.. math::

    \\varepsilon[k+1] = (A - A M C)\\,\\varepsilon[k] + (E - A M F)\\,f,\\qquad
    e[k] = C\\,\\varepsilon[k] + F f

from ``eps = 0`` at the fault's onset. The residual's response to a constant fault of
size ``f`` is ``e[k]``; settled, ``e_ss = (C (I - A + A M C)^{-1} (E - A M F) + F) f``.
An entry whose settled response is below :data:`SETTLED_FRACTION` of its peak is
*transient*: the residual sees the fault only while the filter settles.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

#: a settled response below this fraction of the step response's peak is none
SETTLED_FRACTION = 1e-6
#: samples of the step response followed at most (the filter's slowest pole sets how many)
MAX_SAMPLES = 20000


def fault_columns(kr) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The faults of the filter's sub-model and their columns ``E`` (discrete, reduced
    coordinates) and ``F`` (the measured expression's direct dependence on each fault at
    the operating point)."""
    from fdigen.derive.observability import measurement_expressions

    model = kr.model
    names = [f.name for f in model.faults]
    E = np.asarray(kr.discrete.E, dtype=float).reshape(kr.discrete.A.shape[0], -1)
    if E.shape[1] != len(names):
        E = np.zeros((kr.discrete.A.shape[0], len(names)))
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name]
                  for s in (*model.states, *model.inputs)})
    point.update({f.symbol: 0 for f in model.faults})
    F = np.zeros((len(kr.measurement), len(names)))
    for i, expr in enumerate(measurement_expressions(model, kr.measurement, True)):
        for j, f in enumerate(model.faults):
            d = sp.diff(expr, f.symbol)
            if d != 0:
                F[i, j] = float(sp.sympify(d.xreplace(point)).evalf())
    return names, E, F


def step_responses(kr, E: np.ndarray, F: np.ndarray, samples: int) -> np.ndarray:
    """``e[k]``, ``k = 0 .. samples-1``, of the filter's residual to a unit step of each
    fault of the columns ``E`` (n x m) and ``F`` (1 x m): an array (samples, m)."""
    A, C, M = kr.discrete.A, kr.discrete.C, kr.gain.M
    AM = A @ M
    Acl = A - AM @ C
    drive = E - AM @ F
    eps = np.zeros_like(drive)
    out = np.empty((samples, E.shape[1]))
    for k in range(samples):
        out[k] = C[0] @ eps + F[0]
        eps = Acl @ eps + drive
    return out


def settled_responses(design) -> dict:
    """Per Kalman residual updated by its own measurement, the faults it sees only while
    its filter settles: residual -> fault -> ``{"peak", "settled"}`` (``|e|`` per unit
    fault), ``"rms_peak"`` (the largest moving RMS of the response to a step of the
    fault's test size, window ``N``), ``"noise"`` (the residual's noise level
    ``sigma``), ``"threshold"`` and ``"seen"``: whether ``sqrt(sigma^2 + rms_peak^2)``
    exceeds the threshold (``3 sigma`` without one). A step the residual does not see
    while settling, it never sees: the flag never rises.

    Filters updated with the voter's fused sensors, and faults whose columns are zero,
    are left out.
    """
    from fdigen.design.evaluation import NEVER_FLAGS
    from fdigen.design.observers import residual_noise_level

    ev = design.evaluation
    limit = dict(zip(ev.residuals, (float(v) for v in ev.thresholds)))
    out = {}
    for kr in design.kalman:
        if kr.update != "measurement" or kr.discrete.C.shape[0] != 1:
            continue
        names, E, F = fault_columns(kr)
        A, C, M = kr.discrete.A, kr.discrete.C, kr.gain.M
        n = A.shape[0]
        Acl = A - A @ M @ C
        rho = max(np.abs(np.linalg.eigvals(Acl)).max(initial=0.0), 1e-12)
        if rho >= 1.0:
            continue
        # the step response settles to 1e-9 of its start in ln(1e-9)/ln(rho) samples
        samples = int(min(MAX_SAMPLES, max(50, np.ceil(np.log(1e-9) / np.log(rho)))))
        sigma = residual_noise_level(kr)
        J = limit.get(kr.residual)        # a stand-in that never flags is no threshold
        J = J if J is not None and np.isfinite(J) and J < NEVER_FLAGS else None
        # the settled response of each fault with a size to judge it at; the step
        # responses of all of them are followed at once
        followed, settled = [], {}
        for j, name in enumerate(names):
            size = abs(float(design.model.fault(name).test_size or 0.0))
            if not size or not (np.any(E[:, j]) or np.any(F[:, j])):
                continue                   # no declared size to judge it at (attack 10)
            try:
                ss = C @ np.linalg.solve(np.eye(n) - Acl, E[:, j] - A @ M @ F[:, j]) + F[:, j]
            except np.linalg.LinAlgError:
                continue
            followed.append(j)
            settled[j] = (float(np.abs(ss).max()), size)
        entries = {}
        resp = (step_responses(kr, E[:, followed], F[:, followed], samples)
                if followed else np.zeros((0, 0)))
        for col, j in enumerate(followed):
            r = resp[:, col]
            peak = float(np.abs(r).max())
            ss, size = settled[j]
            # a response not yet settled when the horizon ends: no claim (a filter whose
            # pole is at 1 - 1e-8 settles in 1e9 samples)
            if peak <= 0 or ss > SETTLED_FRACTION * peak or abs(r[-1]) > 0.01 * peak:
                continue
            rms = float(np.sqrt(_moving_mean(r ** 2, ev.window).max())) * size
            level = float(np.hypot(sigma, rms))
            # (4 digits: a diagnostic, written into design.json, the same on every BLAS)
            entries[names[j]] = {"peak": _digits(peak), "settled": _digits(ss),
                                 "rms_peak": _digits(rms), "noise": _digits(sigma),
                                 "threshold": J,
                                 "seen": bool(level > (J if J is not None else 3.0 * sigma)),
                                 "hidden": [s.name for s in kr.model.states]}
        if entries:
            out[kr.residual] = entries
    return out


def _digits(v: float) -> float:
    return float(f"{v:.4g}")


def _moving_mean(x: np.ndarray, N: int) -> np.ndarray:
    """Mean of the last ``N`` samples of ``x`` (zeros before the first)."""
    c = np.concatenate([np.zeros(int(N)), np.cumsum(x)])
    return (c[int(N):] - c[:-int(N)]) / int(N)


def transient_only_pairs(table: dict, settled: dict) -> list:
    """Ordered pairs ``(fi, fj)`` the signature ``table`` isolates only through entries of
    ``settled`` (:func:`settled_responses`) that a step at the test size does not flag:
    with those entries removed, no residual responds to ``fi`` and not to ``fj``."""
    from fdigen.design.structure import table_isolability

    steady = {f: {r for r in rs if settled.get(r, {}).get(f, {}).get("seen", True)}
              for f, rs in table.items()}
    full, kept = table_isolability(table), table_isolability(steady)
    return sorted(p for p, ok in full.items() if p[0] != p[1] and ok and not kept[p])
