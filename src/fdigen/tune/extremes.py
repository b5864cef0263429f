"""Extreme-value and binomial statistics of the tuning campaigns.

Holds the GEV / Gumbel quantile and distribution function (:func:`gev_quantile`,
:func:`gev_cdf`), the Coles-Dixon shape penalty (:func:`coles_dixon_penalty`), the fit of
per-run maxima (:func:`fit_maxima`, with the likelihood-ratio test against
:data:`LR_CRITICAL`) and the one-sided Clopper-Pearson upper bound
(:func:`clopper_pearson_upper`). SciPy is imported lazily.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

#: chi^2 with one degree of freedom, 95 %: the likelihood-ratio test GEV vs Gumbel.
LR_CRITICAL = 3.841458820694124


def gev_quantile(p: float, xi: float, mu: float, sigma: float) -> float:
    """Quantile of the GEV distribution (Gumbel for :math:`\\xi = 0`).

    .. math::

        F^{-1}(p) = \\mu + \\frac{\\sigma}{\\xi}\\left[(-\\ln p)^{-\\xi} - 1\\right],\\qquad
        \\lim_{\\xi \\to 0} F^{-1}(p) = \\mu - \\sigma \\ln(-\\ln p)
    """
    y = -math.log(p)
    if abs(xi) < 1e-9:
        return mu - sigma * math.log(y)
    return mu + sigma / xi * (y ** (-xi) - 1.0)


def gev_cdf(x: float, xi: float, mu: float, sigma: float) -> float:
    """:math:`F(x) = \\exp\\{-[1 + \\xi (x - \\mu)/\\sigma]^{-1/\\xi}\\}` (Gumbel for
    :math:`\\xi = 0`)."""
    z = (x - mu) / sigma
    if abs(xi) < 1e-9:
        return math.exp(-math.exp(-z))
    arg = 1.0 + xi * z
    if arg <= 0:
        return 0.0 if xi > 0 else 1.0
    return math.exp(-arg ** (-1.0 / xi))


def coles_dixon_penalty(xi: float) -> float:
    """Log of the Coles-Dixon (1999) penalty on the GEV shape for small samples.

    .. math::

        P(\\xi) = \\begin{cases} 1 & \\xi \\le 0 \\\\
        \\exp\\{-\\lambda (1/(1-\\xi) - 1)^{a}\\} & 0 < \\xi < 1 \\\\
        0 & \\xi \\ge 1 \\end{cases}\\qquad \\lambda = a = 1

    It keeps the maximum-likelihood shape finite (:math:`\\xi < 1`, finite mean) and shrinks
    heavy tails that a few runs cannot support.
    """
    if xi <= 0:
        return 0.0
    if xi >= 1:
        return -math.inf
    return -(1.0 / (1.0 - xi) - 1.0)


def _gev_loglik(z, xi, mu, sigma):
    if sigma <= 0:
        return -math.inf
    s = (z - mu) / sigma
    if abs(xi) < 1e-9:
        return float(np.sum(-np.log(sigma) - s - np.exp(-s)))
    arg = 1.0 + xi * s
    if np.any(arg <= 0):
        return -math.inf
    return float(np.sum(-np.log(sigma) - (1.0 + 1.0 / xi) * np.log(arg) - arg ** (-1.0 / xi)))


def fit_maxima(x, alpha: float, min_fit_runs: int = 20) -> dict:
    """Fit Gumbel and GEV to per-run maxima; the :math:`1 - \\alpha` quantile.

    Parameters
    ----------
    x : array_like
        Per-run maxima of one residual's RMS.
    alpha : float
        Exceedance probability per run of this residual.
    min_fit_runs : int
        With fewer samples no fit is made (``basis = "empirical"``).

    Returns
    -------
    dict
        ``basis`` ("gev", "gumbel", "empirical" or "degenerate"), ``quantile`` (of the
        chosen fit, or None), ``gumbel`` and ``gev`` parameters (``xi``, ``mu``,
        ``sigma``, ``loglik``) and their quantiles, ``lr_statistic``, ``empirical_max``,
        ``empirical_quantile`` (None when ``n * alpha < 1``: not estimable from the sample),
        ``extrapolation`` (:math:`1/(n\\alpha)`: how far the quantile lies beyond the
        sample's own return period), ``n``.

    Notes
    -----
    The sample is standardised (:math:`z = (x - \\bar x)/s`). The Gumbel is the maximum
    likelihood fit (``scipy.stats.gumbel_r.fit``); the GEV maximises the log-likelihood
    plus the Coles-Dixon log-penalty (:func:`coles_dixon_penalty`), by Nelder-Mead from the
    Gumbel fit (plain maximum likelihood of a three-parameter GEV on a few tens of maxima
    often returns :math:`\\xi > 1` and absurd quantiles). The GEV is preferred only if the
    likelihood ratio :math:`2(\\ell_\\mathrm{GEV} - \\ell_\\mathrm{Gumbel})` exceeds
    :math:`\\chi^2_{1;0.95} = 3.84`.
    """
    from scipy import optimize, stats

    x = np.asarray(x, dtype=float)
    n = int(x.size)
    p = 1.0 - alpha
    out = {"n": n, "alpha": alpha, "empirical_max": float(x.max()),
           "empirical_quantile": float(np.quantile(x, p)) if n * alpha >= 1 else None,
           "extrapolation": 1.0 / (n * alpha), "quantile": None, "gumbel": None,
           "gev": None, "lr_statistic": None}
    centre, scale = float(x.mean()), float(x.std(ddof=1)) if n > 1 else 0.0
    if not np.all(np.isfinite(x)) or scale <= 1e-12 * max(abs(centre), 1e-300):
        out["basis"] = "degenerate"
        return out
    if n < min_fit_runs:
        out["basis"] = "empirical"
        return out
    z = (x - centre) / scale
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        loc_g, sc_g = stats.gumbel_r.fit(z)
        ll_g = _gev_loglik(z, 0.0, loc_g, sc_g)

        def cost(theta):
            xi, mu, ls = theta
            if xi <= -1.0:
                return 1e300
            val = _gev_loglik(z, xi, mu, math.exp(ls)) + coles_dixon_penalty(xi)
            return -val if np.isfinite(val) else 1e300

        best = None
        for xi0 in (0.0, 0.2, -0.2):
            r = optimize.minimize(cost, [xi0, loc_g, math.log(sc_g)], method="Nelder-Mead",
                                  options={"xatol": 1e-8, "fatol": 1e-10, "maxiter": 4000})
            if r.fun < 1e299 and (best is None or r.fun < best.fun):
                best = r
    gum = {"xi": 0.0, "mu": centre + scale * loc_g, "sigma": scale * sc_g, "loglik": ll_g}
    gum["quantile"] = gev_quantile(p, 0.0, gum["mu"], gum["sigma"])
    out["gumbel"] = gum
    out["basis"] = "gumbel"
    out["quantile"] = gum["quantile"]
    if best is not None:
        xi, mu, ls = (float(v) for v in best.x)
        ll = _gev_loglik(z, xi, mu, math.exp(ls))
        gev = {"xi": xi, "mu": centre + scale * mu, "sigma": scale * math.exp(ls),
               "loglik": ll, "penalised": True}
        gev["quantile"] = gev_quantile(p, xi, gev["mu"], gev["sigma"])
        out["gev"] = gev
        out["lr_statistic"] = max(2.0 * (ll - ll_g), 0.0)
        if out["lr_statistic"] > LR_CRITICAL and np.isfinite(gev["quantile"]):
            out["basis"] = "gev"
            out["quantile"] = gev["quantile"]
    return out


def clopper_pearson_upper(k: int, n: int, level: float = 0.95) -> float:
    """One-sided upper confidence bound of a binomial proportion (``k`` of ``n``)."""
    from scipy import stats

    if n == 0:
        return 1.0
    if k >= n:
        return 1.0
    return float(stats.beta.ppf(level, k + 1, n - k))
