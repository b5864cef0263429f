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
    """d(y_sim/sigma)/d(log theta_free, x0) of the free run, by CasADi's AD.

    A parameter whose value is 0 has no logarithm: its column is ``d/d theta`` (a unit
    step, the fit's own scale for it), not ``theta d/d theta = 0``. A current sensor's
    offset declared 0 read as a direction the outputs do not see, and was held.
    """
    K = len(u)
    lq = ca.MX.sym("lq", len(free))
    xs0 = ca.MX.sym("x0", om.nx)
    pv = []
    for n in om.names:
        v = float(params[n])
        if n not in free:
            pv.append(v)
        elif v == 0.0:
            pv.append(lq[free.index(n)])
        else:
            pv.append(v * ca.exp(lq[free.index(n)]))
    pvec = ca.vertcat(*pv)
    xs = om.step.mapaccum(K - 1)(xs0, u[:-1].T, ca.repmat(pvec, 1, K - 1))
    traj = ca.horzcat(xs0, xs)
    yh = om.out.map(K)(traj, u.T, ca.repmat(pvec, 1, K))
    yw = ca.vec((yh / ca.DM(np.tile(np.asarray(sig)[:, None], (1, K)))).T)
    jac = ca.Function("oe_sensitivity", [lq, xs0], [ca.jacobian(yw, ca.vertcat(lq, xs0))])
    return np.asarray(jac(np.zeros(len(free)), x0))


def standard_deviations(fit, sig, residuals=None) -> dict:
    """One-sigma intervals ``tau s^2 (J^T J)^-1`` (log parameters -> relative), ``s^2``
    the weighted residual mean square per degree of freedom and ``tau``
    (:func:`correlation_time`) the samples per independent one in the residuals.

    ``s^2 (J^T J)^-1`` alone holds for white residuals. A model that does not explain the
    log leaves a smooth error, hundreds of samples long: a user's furnace (error 17.8x
    its sensor noise) got ``Pmax = 2231 +- 10`` W for a true 2730, 50 of its own sigmas
    away. With ``tau`` the interval is that of the independent samples the fit had."""
    return parameter_deviations(fit, sig, residuals)[0]


def conditional_deviations(fit, sig, residuals=None) -> dict:
    """Each parameter's one-sigma interval with the others (and the initial state) at
    their estimates, ``sqrt(tau s^2 / (J^T J)_kk)``: how far it alone may move on this
    log. Parameters the log knows only in combination (a compressor's loaded power
    ``Pl0 + kpw p`` over 6.5-7.5 bar: correlation -0.999, marginal intervals +-8.6 % and
    +-16.6 %) have wide marginal intervals and narrow conditional ones; the campaign,
    which spreads each parameter on its own, takes these (spread by the marginal ones,
    each alone, the power threshold was 25 kW on a 50 kW meter)."""
    return parameter_deviations(fit, sig, residuals)[1]


def parameter_deviations(fit, sig, residuals=None) -> tuple[dict, dict]:
    """``(marginal, conditional)``: :func:`standard_deviations` and
    :func:`conditional_deviations` from one ``J^T J`` and one correlation time."""
    info = _information(fit, sig, residuals)
    if info is None:
        return {}, {}
    JtJ, scale = info
    d = np.diag(JtJ)
    # a parameter at 0 has an absolute column (sensitivity), the others log -> relative
    size = {n: abs(fit.params[n]) or 1.0 for n in fit.free}
    conditional = {n: float(size[n] * np.sqrt(scale / d[i])) if d[i] > 0
                   else float("inf") if d[i] == 0 else float("nan")
                   for i, n in enumerate(fit.free)}
    try:
        cov = scale * np.linalg.pinv(JtJ)
    except np.linalg.LinAlgError:      # a non-finite Jacobian: no interval at all
        return {n: float("nan") for n in fit.free}, conditional
    # one the log does not move at all has no interval (the pseudo-inverse said 0: a
    # parameter known exactly, spread by the floor alone; attack 12)
    marginal = {n: float(size[n] * np.sqrt(max(cov[i, i], 0.0))) if d[i] > 0
                else float("inf") for i, n in enumerate(fit.free)}
    return marginal, conditional


def _information(fit, sig, residuals):
    """``(J^T J, tau s^2)`` of ``fit`` (see :func:`standard_deviations`), or ``None``."""
    J = fit.J
    if J is None or len(fit.free) == 0:
        return None
    dof = max(fit.n - J.shape[1], 1)
    s2 = fit.sse / float(np.mean(np.asarray(sig) ** 2)) / dof
    tau = correlation_time(residuals, sig) if residuals is not None else 1.0
    return J.T @ J, tau * s2


def correlation_time(residuals, sig) -> float:
    """Samples per independent sample of the residuals, ``1 + 2 sum_k rho_k`` (Sokal's
    integrated autocorrelation time, summed while ``rho_k > 0`` and up to a tenth of the
    log), per output, averaged with each output's share of the weighted squared error; at
    least 1."""
    r = np.asarray(residuals, dtype=float)
    if r.ndim == 1:
        r = r[:, None]
    w = np.asarray(sig, dtype=float).reshape(-1)
    taus, shares = [], []
    for j in range(r.shape[1]):
        col = r[:, j][np.isfinite(r[:, j])]
        if col.size < 10 or not np.any(col != col[0]):
            continue
        col = col - col.mean()
        n = col.size
        spec = np.fft.rfft(col, 2 * n)
        acf = np.fft.irfft(spec * np.conj(spec))[:n]
        acf = acf / acf[0]
        tau = 1.0
        for k in range(1, max(2, n // 10)):
            if acf[k] <= 0:
                break
            tau += 2.0 * acf[k]
        taus.append(tau)
        shares.append(float(np.sum(col ** 2)) / (w[j] ** 2 if j < w.size and w[j] > 0
                                                 else 1.0))
    if not taus or sum(shares) <= 0:
        return 1.0
    return max(1.0, float(np.dot(taus, shares) / sum(shares)))


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


def effective_samples(fit, y, noise) -> float:
    """The independent samples the current fit's residuals hold: ``n / tau``, ``tau``
    their correlation time (:func:`fdigen.discover.sensitivity.correlation_time`).

    The BIC counts samples as independent. A model that does not explain the log leaves a
    smooth error: a user's furnace (17.8x its sensor noise) took a saturation of its
    heater command at 92.5 % (the rig never clipped) on a BIC of thousands of correlated
    samples and a 3 % gain on the held-back part. Used when no second log confirms."""
    res = np.asarray(y, dtype=float) - np.asarray(fit.Y, dtype=float)
    return max(float(fit.n) / correlation_time(res, noise), 1.0)
