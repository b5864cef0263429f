"""Threshold design from the healthy maxima, and rounding to the written value.

Holds :func:`design_thresholds` (per residual: fit, Sidak share of the false-alarm rate,
margin, start-up floor, fitted and in-sample false-alarm estimates), :func:`round_up`
(round *up* to three significant digits, with its TOML text) and :func:`_literal` (the
TOML spelling of a threshold).
"""

from __future__ import annotations

import math
from decimal import Decimal

import numpy as np

from fdigen.errors import FdigenError
from fdigen.tune.extremes import fit_maxima, gev_cdf
from fdigen.tune.settings import TuneSettings


def round_up(value: float, digits: int = 3) -> tuple[float, str]:
    """``value`` rounded *up* to ``digits`` significant digits, and its TOML text.

    Numbers in [0.1, 100) print plainly (``0.35``), others as ``1.43e-4`` / ``2.1e3``.
    """
    if not (value > 0 and math.isfinite(value)):
        raise FdigenError(f"cannot write threshold {value!r}")
    m, e = f"{value:.{digits - 1}e}".split("e")
    mant, exp = Decimal(m), int(e)
    if float(mant.scaleb(exp)) < value:
        mant += Decimal(1).scaleb(-(digits - 1))
        if mant >= 10:
            mant, exp = mant / 10, exp + 1
    v = float(mant.scaleb(exp))
    if 0.1 <= v < 100:
        text = repr(v)
    else:
        ms = f"{mant:f}".rstrip("0")
        text = f"{ms}0e{exp}" if ms.endswith(".") else f"{ms}e{exp}"
    return v, text


def design_thresholds(names, maxima, current: dict, settings: TuneSettings,
                      startup=None) -> dict:
    """Tuned threshold per residual from the healthy per-run maxima.

    Parameters
    ----------
    names : sequence of str
        Residual names (column order of ``maxima``).
    maxima : array_like, shape (runs, residuals)
        Per-run maxima :math:`M_i` of the RMS after settling.
    current : dict
        The model file's thresholds (reported, and kept for residuals the healthy runs
        never excite); a residual absent from it has no threshold in the file yet.
    settings : TuneSettings
    startup : array_like, optional
        Per-run start-up maxima :math:`S_i` (before settling): no threshold is set below
        them (the core flags from the first sample).

    Returns
    -------
    dict
        ``alpha_per_residual``, ``thresholds`` (name -> value written), ``text`` (name ->
        TOML literal), ``residuals`` (name -> statistics), ``fitted_false_alarm``
        (:math:`1 - \\prod_i F_i(J_i)`, None when any residual is empirical),
        ``empirical_false_alarm_in_sample``, ``basis``.
    """
    maxima = np.asarray(maxima, dtype=float)
    n_r = len(names)
    alpha = settings.false_alarm_rate
    alpha_i = 1.0 - (1.0 - alpha) ** (1.0 / n_r)
    out = {"alpha_per_run": alpha, "alpha_per_residual": alpha_i, "margin": settings.margin,
           "runs": int(maxima.shape[0]), "residuals": {}, "thresholds": {}, "text": {}}
    survive = 1.0
    fitted_ok = True
    for j, name in enumerate(names):
        fit = fit_maxima(maxima[:, j], alpha_i, settings.min_fit_runs)
        if name in settings.keep:
            value, text = float(current[name]), None
            fit["note"] = "kept as in the model file (--keep)"
            fit["kept"] = True
        elif fit["basis"] == "degenerate" and fit["empirical_max"] <= 0:
            if name not in current:
                raise FdigenError(f"residual {name} stayed at 0 in every healthy run and the "
                                  "model file has no threshold for it: set one by hand")
            value, text = float(current[name]), None
            fit["note"] = "never excited by healthy runs: current threshold kept"
            fitted_ok = False
        else:
            base = fit["empirical_max"] if fit["quantile"] is None else max(
                fit["quantile"], fit["empirical_max"])
            if startup is not None:
                su = float(np.max(np.asarray(startup)[:, j]))
                fit["startup_sets_threshold"] = su > base
                base = max(base, su)
            value, text = round_up(settings.margin * base)
        chosen = fit.get(fit["basis"]) if fit["basis"] in ("gev", "gumbel") else None
        if chosen is None:
            fitted_ok = False
        else:
            p_exc = 1.0 - gev_cdf(value, chosen["xi"], chosen["mu"], chosen["sigma"])
            fit["fitted_exceedance_at_threshold"] = p_exc
            survive *= 1.0 - p_exc
        fit["threshold"] = value
        fit["current"] = float(current[name]) if name in current else None
        fit["ratio_to_current"] = value / float(current[name]) if name in current else None
        if startup is not None:
            fit["startup_max"] = float(np.max(np.asarray(startup)[:, j]))
        seen = max(fit["empirical_max"], fit.get("startup_max", 0.0))
        if value <= seen:
            fit["warning"] = f"threshold {value:g} is below a healthy RMS seen ({seen:g})"
        out["residuals"][name] = fit
        out["thresholds"][name] = value
        out["text"][name] = text or _literal(value)
    J = np.array([out["thresholds"][n] for n in names])
    whole = maxima if startup is None else np.maximum(maxima, np.asarray(startup, dtype=float))
    out["empirical_false_alarm_in_sample"] = float(np.mean(np.any(whole > J, axis=1)))
    out["fitted_false_alarm"] = (1.0 - survive) if fitted_ok else None
    bases = {f["basis"] for f in out["residuals"].values()}
    out["basis"] = ("empirical (too few runs for an extreme-value fit)"
                    if "empirical" in bases else "extreme-value fit")
    return out


def _literal(value: float) -> str:
    if value > 0 and math.isfinite(value):
        v, text = round_up(value, 3)
        if v == value:
            return text
    return repr(float(value))
