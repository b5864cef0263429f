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
                      startup=None, vertices: dict | None = None) -> dict:
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
    vertices : dict, optional
        :func:`vertex_maxima` of the runs at the vertices of the tolerance box: no
        threshold is set below their largest RMS :math:`V_i` (start-up included), so
        that the threshold holds for a plant anywhere inside the declared tolerance:

        .. math:: J_i = m \\max(q_i, \\max_k M_{ki}, \\max_k S_{ki}, V_i)

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
            if vertices is not None:
                vx = float(np.max(vertices["maxima"][:, j]))
                fit["vertex_max"] = vx
                fit["vertex_sets_threshold"] = vx > base
                fit["vertex_parameters"] = vertices["parameters"][
                    int(np.argmax(vertices["maxima"][:, j]))]
                base = max(base, vx)
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


def vertex_maxima(runs: list, names) -> dict | None:
    """The largest RMS of each residual (start-up included) in each run at a vertex of
    the tolerance box: ``{"maxima": (runs, residuals), "parameters": [dict per run]}``,
    None without such runs."""
    if not runs:
        return None
    rows = np.array([[max(r["max_rms"][n], r["max_rms_startup"][n]) for n in names]
                     for r in runs], dtype=float)
    ok = np.all(np.isfinite(rows), axis=1)
    out = {"maxima": rows[ok], "parameters": [dict(r["parameters"])
                                              for r, good in zip(runs, ok) if good]}
    if not ok.all():
        # a corner the controller does not hold (the loop diverges there): no threshold
        # can cover it, and the random draws' thresholds stand for the rest of the box
        bad = [", ".join(f"{p} {v:.4g}" for p, v in r["parameters"].items())
               for r, good in zip(runs, ok) if not good]
        out["diverged"] = (f"{len(bad)} vertices of the parameter tolerance ({'; '.join(bad)}) "
                           "gave a healthy RMS that is not finite (the closed loop or a "
                           "filter diverges there): not counted; the declared tolerance "
                           "holds plants this loop does not hold, narrow it (a parameter's "
                           "own tolerance, or commission's calibration)")
    return out if len(out["maxima"]) else None


def vertex_note(tuned: dict, names, planned: int, kept: int,
                nominal: dict) -> str | None:
    """What the runs at the tolerance box's vertices did to the thresholds, in a line."""
    if not planned:
        return None
    res = tuned["residuals"]
    setting = [n for n in names if res[n].get("vertex_sets_threshold") and not res[n].get("kept")]
    head = (f"{kept} healthy runs at the vertices of the parameter tolerance"
            + (f" ({planned - kept} left the equations' domain, not counted)"
               if kept < planned else ""))
    if not setting:
        return head + ": no threshold set by them (the random draws covered the spread)"
    parts = []
    for n in setting:
        worst = ", ".join(f"{p} {100 * (v / nominal[p] - 1):+.3g} %" if nominal.get(p)
                          else f"{p} {v:.4g}"
                          for p, v in res[n]["vertex_parameters"].items())
        parts.append(f"{n} (RMS {res[n]['vertex_max']:.3g} at {worst})")
    return (head + ": they set " + "; ".join(parts) + ", above what the random draws of "
            "the spread reached")


def _literal(value: float) -> str:
    if value > 0 and math.isfinite(value):
        v, text = round_up(value, 3)
        if v == value:
            return text
    return repr(float(value))
