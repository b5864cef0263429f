"""Free-run sensitivity of an output-error fit: blind directions and intervals.

``J = d(y_sim / sigma) / d(log theta, x0)`` of the free-run simulation, by CasADi's
algorithmic differentiation; its SVD gives the directions of parameter space the outputs
do not see (:func:`null_directions`), ``s^2 (J^T J)^{-1}`` the one-sigma intervals
(:func:`standard_deviations`).
"""

from __future__ import annotations

import casadi as ca
import numpy as np


def sensitivity(om, x0, u, params, free, sig) -> np.ndarray:
    """d(y_sim/sigma)/d(log theta_free, x0) of the free run, by CasADi's AD."""
    K = len(u)
    lq = ca.MX.sym("lq", len(free))
    xs0 = ca.MX.sym("x0", om.nx)
    pv = []
    for n in om.names:
        pv.append(float(params[n]) * ca.exp(lq[free.index(n)]) if n in free
                  else float(params[n]))
    pvec = ca.vertcat(*pv)
    xs = om.step.mapaccum(K - 1)(xs0, u[:-1].T, ca.repmat(pvec, 1, K - 1))
    traj = ca.horzcat(xs0, xs)
    yh = om.out.map(K)(traj, u.T, ca.repmat(pvec, 1, K))
    yw = ca.vec((yh / ca.DM(np.tile(np.asarray(sig)[:, None], (1, K)))).T)
    jac = ca.Function("oe_sensitivity", [lq, xs0], [ca.jacobian(yw, ca.vertcat(lq, xs0))])
    return np.asarray(jac(np.zeros(len(free)), x0))


def standard_deviations(fit, sig) -> dict:
    """One-sigma intervals ``s^2 (J^T J)^-1`` (log parameters -> relative), ``s^2`` the
    weighted residual mean square per degree of freedom."""
    J = fit.J
    nfree = len(fit.free)
    if J is None or nfree == 0:
        return {}
    dof = max(fit.n - J.shape[1], 1)
    s2 = fit.sse / float(np.mean(np.asarray(sig) ** 2)) / dof
    cov = s2 * np.linalg.pinv(J.T @ J)
    return {n: float(abs(fit.params[n]) * np.sqrt(max(cov[i, i], 0.0)))
            for i, n in enumerate(fit.free)}


def null_directions(J: np.ndarray, free, nx: int, rtol: float = 1e-7) -> list[dict]:
    """Directions of (log) parameter space the outputs do not see.

    The right singular vectors of the sensitivity ``J`` (columns: ``log theta_free``,
    then the initial state) whose singular value is below ``rtol`` times the largest:
    moving the parameters as ``theta_i * exp(v_i e)`` leaves the simulated outputs
    unchanged to first order. Each is returned as parameter -> exponent ``v_i``, scaled so
    the largest is 1 (entries below 1e-3 dropped); e.g. ``{k4: 1, k1: 0.5, k2: -0.5}``:
    only ``k1*k2`` and ``k4/k1**2``... are determined.
    """
    npar = len(free)
    if npar == 0 or J is None or not np.all(np.isfinite(J)):
        return []
    cols = np.linalg.norm(J, axis=0)
    if not np.any(cols > 0):
        return []
    _, sv, vt = np.linalg.svd(J, full_matrices=False)
    out = []
    for s, v in zip(sv, vt):
        if s > rtol * sv[0]:
            continue
        vp = v[:npar]
        if np.max(np.abs(vp)) < 1e-6:
            continue
        vp = vp / vp[np.argmax(np.abs(vp))]
        out.append({n: float(round(c, 3)) for n, c in zip(free, vp) if abs(c) > 1e-3})
    return out
