"""Calibrate: estimate parameters from the equation error of a log's calibration part.

What is minimised
-----------------
The weighted equation error of :mod:`fdigen.discover.locate` over the calibration windows
(by default the first 60 % of the log), all testable equations together:

.. math::

    \\hat\\theta = \\arg\\min_{\\theta \\in [\\theta_{lo}, \\theta_{hi}]}
    \\sum_{i} \\sum_{w \\in \\text{cal}} \\left(\\frac{E_i[w](\\theta)}{\\sigma_i}\\right)^2,

``theta`` being the model's ``uncertain`` parameters (for the cylinder ``Ff`` and ``K``,
bounded by the model file) plus the parameters of any library effect switched on, and
``sigma_i`` each equation's white-noise level (estimated once, from successive
differences of the nominal model's residual, so that the same weights compare every
candidate model). Solved by :func:`scipy.optimize.least_squares` (trust region
reflective, bounds, parameters scaled by their nominal size).

Why the equation error and not the output error: the cylinder integrates (the position
is the integral of the velocity, the pressures integrate the valve flow), so an open-loop
simulation driven by the measured command drifts away from the log whatever the
parameters, and the fit would chase the drift. The equation error needs no simulation
and no initial state, it is linear in ``Ff`` and ``K`` (and in most effect parameters),
and the modulating windows make its noise white and small, so least squares is
efficient and its covariance is meaningful. Its known weakness, the bias from noise in
the regressors, is small here because the states in ``f`` are smoothed measurements with
a high signal-to-noise ratio; the simulated-log tests bound it (parameters within a few
per cent).

Uncertainty: ``cov = s^2 (J^T J)^{-1}`` with ``J`` the Jacobian of the weighted residuals
at the optimum and ``s^2`` their mean square per degree of freedom.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from fdigen.discover.locate import EquationData, EquationModel


@dataclass
class Fit:
    """A least-squares fit of some parameters on the equation error.

    Attributes
    ----------
    model : EquationModel
    free : list of str
        The estimated parameters.
    params : dict of str to float
        Every parameter value of the fit (fixed ones at their defaults).
    std : dict of str to float
        Standard deviation of each estimated parameter.
    sigma : numpy.ndarray
        Weights (noise level) of the equations.
    sse : float
        Weighted sum of squares on the fitted windows.
    n : int
        Number of weighted residuals.
    E : numpy.ndarray
        Equation errors (W, neq) of every window with the fitted parameters.
    success : bool
    null_directions : list of dict
        Directions of parameter space the equation error does not see
        (:func:`fdigen.discover.sensitivity.null_directions`): the parameter that moves
        most along each is held at its value (``held``, infinite standard deviation) and
        the others fitted, since only a combination is determined.
    held : list of str
    """

    model: EquationModel
    free: list
    params: dict
    std: dict
    sigma: np.ndarray
    sse: float
    n: int
    E: np.ndarray = field(repr=False, default=None)
    success: bool = True
    null_directions: list = field(default_factory=list)
    held: list = field(default_factory=list)
    conditional_std: dict = field(default_factory=dict)

    def sse_on(self, mask: np.ndarray) -> float:
        """Weighted sum of squares of the equation errors on the windows ``mask``."""
        return float(np.sum((self.E[mask] / self.sigma) ** 2))


def noise_levels(E: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """White-noise level of each equation's error: RMS of successive differences / sqrt 2.

    Differences remove the slowly varying structure, so the level is that of the noise
    even where the model is wrong.
    """
    d = np.diff(E[mask], axis=0)
    s = np.sqrt(np.mean(d ** 2, axis=0) / 2.0)
    return np.where(s > 0, s, 1.0)


#: Singular values of the scaled finite-difference Jacobian below this fraction of the
#: largest are blind directions (the differences carry about 1e-8 of relative error).
NULL_RTOL = 1e-6


#: The weighted equation error of a window where the equations are not a finite real
#: number (a noise-normalised residual of 1e6: no fit prefers it).
OUTSIDE_DOMAIN = 1e6


def fit_parameters(eq: EquationModel, free, mask: np.ndarray, sigma: np.ndarray, *,
                   fixed: dict | None = None, start: dict | None = None,
                   bounds: dict | None = None) -> Fit:
    """Fit the parameters ``free`` on the windows ``mask`` (weighted equation error).

    Parameters
    ----------
    eq : EquationModel
    free : sequence of str
        Parameter names to estimate.
    mask : numpy.ndarray
        Windows used (bool, length W).
    sigma : numpy.ndarray
        Noise level per equation (weights ``1/sigma``).
    fixed : dict, optional
        Values of parameters held fixed (others at their defaults).
    start : dict, optional
        Starting values of the free parameters (default: current value, effects' nominal).
    bounds : dict, optional
        Name -> (low, high).
    """
    free = list(free)
    fixed = dict(fixed or {})
    start = dict(start or {})
    bounds = dict(bounds or {})
    base = eq.values(fixed)
    x0 = np.array([float(start.get(n, base[n])) for n in free])
    lo = np.array([bounds.get(n, (-np.inf, np.inf))[0] for n in free], dtype=float)
    hi = np.array([bounds.get(n, (-np.inf, np.inf))[1] for n in free], dtype=float)
    scale = np.array([_scale(x0[i], lo[i], hi[i]) for i in range(len(free))])
    x0 = np.clip(x0, lo, hi)
    # keep the start strictly inside the bounds (trf needs it)
    inside = np.where(np.isfinite(hi - lo), 1e-9 * (hi - lo), 0.0)
    x0 = np.clip(x0, lo + inside, hi - inside)

    def resid(q):
        vals = dict(base)
        vals.update(dict(zip(free, q * scale)))
        with np.errstate(all="ignore"):
            r = (eq.errors(vals)[mask] / sigma).ravel()
        # where the equations are not real (sqrt(u + off) of a negative number) the error
        # is a large finite penalty: the search steps back, and a candidate that lives
        # there loses on its sum of squares (scipy raised "array must not contain infs or
        # NaNs": discover ended in an internal error)
        return np.where(np.isfinite(r), r, OUTSIDE_DOMAIN)

    if free:
        sol = least_squares(resid, x0 / scale, bounds=(lo / scale, hi / scale),
                            method="trf", x_scale=1.0, diff_step=1e-4, xtol=1e-10,
                            ftol=1e-12, gtol=1e-10, max_nfev=200)
        q = sol.x
        r = resid(q)
        J = _jacobian(resid, q, r, lo / scale, hi / scale)  # in scaled units
        success = bool(sol.success)
    else:
        q = np.zeros(0)
        r = resid(q)
        J = np.zeros((len(r), 0))
        success = True
    vals = dict(base)
    vals.update(dict(zip(free, q * scale)))
    sse = float(r @ r)
    dof = max(len(r) - len(free), 1)
    std, cond = {}, {}
    nulls = []
    if free:
        try:
            cov = (sse / dof) * np.linalg.pinv(J.T @ J) * np.outer(scale, scale)
            std = {n: float(np.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(free)}
        except np.linalg.LinAlgError:  # pragma: no cover
            std = {n: float("nan") for n in free}
        # each alone, the others at their estimates (sensitivity.conditional_deviations)
        d = np.einsum("ij,ij->j", J, J)
        cond = {n: float(np.sqrt(sse / dof / d[i]) * scale[i]) if d[i] > 0
                else float("inf") for i, n in enumerate(free)}
        # a direction the equation error does not see (a pump curve's and a pipe's
        # friction entering only as their sum): pinv reported a tight interval for each
        # of the two arbitrary values the search stopped at
        from fdigen.discover.sensitivity import null_directions

        nulls = null_directions(J, free, 0, rtol=NULL_RTOL)
        if nulls:
            # hold, per blind direction, the parameter that moves most along it at its
            # value (the datasheet's) and fit the others: values that mean something
            held = {max(d, key=lambda n: abs(d[n])) for d in nulls}
            refit = fit_parameters(eq, [n for n in free if n not in held], mask, sigma,
                                   fixed={**fixed, **{n: base[n] for n in held}},
                                   start=start, bounds=bounds)
            refit.free = free
            refit.std.update({n: float("inf") for n in held})
            refit.null_directions = nulls + refit.null_directions
            refit.held = sorted(held)
            return refit
    return Fit(eq, free, vals, std, sigma, sse, len(r), eq.errors(vals), success, nulls,
               conditional_std=cond)


def _jacobian(resid, q, r, lo, hi, h=1e-4):
    """Central-difference Jacobian of the (scaled) residuals, one-sided at a bound."""
    J = np.empty((len(r), len(q)))
    for i in range(len(q)):
        step = h * max(1.0, abs(q[i]))
        up, dn = q.copy(), q.copy()
        up[i] = min(q[i] + step, hi[i])
        dn[i] = max(q[i] - step, lo[i])
        if up[i] == dn[i]:  # pragma: no cover - degenerate bounds
            J[:, i] = 0.0
            continue
        J[:, i] = (resid(up) - resid(dn)) / (up[i] - dn[i])
    return J


def _scale(x0, lo, hi):
    if x0 != 0 and np.isfinite(x0):
        return abs(float(x0))
    if np.isfinite(hi) and hi > 0:
        return float(hi) * 0.01
    if np.isfinite(lo) and lo < 0:
        return abs(float(lo)) * 0.01
    return 1.0


def uncertain_parameters(data: EquationData) -> tuple[list, dict]:
    """The model's ``uncertain`` parameters and their bounds."""
    model = data.model
    names = [q.name for q in model.parameters if q.uncertain]
    bounds = {q.name: q.bounds or (-np.inf, np.inf) for q in model.parameters if q.uncertain}
    return names, bounds


def calibrate(data: EquationData, mask: np.ndarray, effects=(), *, sigma=None,
              start: dict | None = None) -> Fit:
    """Estimate the uncertain parameters (and the effects' parameters) on ``mask``.

    Parameters
    ----------
    data : EquationData
    mask : numpy.ndarray
        Calibration windows.
    effects : sequence of LibraryEffect
        Effects switched on; their parameters are estimated too, within their bounds,
        starting from their nominal size.
    sigma : numpy.ndarray, optional
        Equation weights; default: estimated from the nominal model's residual.

    Returns
    -------
    Fit
    """
    eq = EquationModel(data, effects)
    names, bounds = uncertain_parameters(data)
    st = {}
    for e in effects:
        for p in e.parameters:
            names.append(p.name)
            bounds[p.name] = p.bounds
            st[p.name] = p.nominal
    st.update(start or {})
    if sigma is None:
        sigma = noise_levels(eq.errors(), mask)
    return fit_parameters(eq, names, mask, sigma, start=st, bounds=bounds)
