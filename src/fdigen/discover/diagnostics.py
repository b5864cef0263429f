"""What one log can and cannot tell: bounds, ties, look-alike effects, implausible units.

A fit always returns numbers. These checks say when they should not be trusted as they
stand, and what to do about it:

* **Parameters at a bound.** An estimate within ``1e-6`` of its span from a bound of the
  search (the model file's ``bounds``, an effect's physical range) is not an interior
  optimum: the bound, not the data, decided it (a wrong model, a bound too tight, or a
  sign convention).
* **Ties.** Candidates whose BIC is within ``tie`` (default 2, "not worth more than a
  bare mention" on the Kass-Raftery scale) of the chosen one, both significant, are
  reported as tied: the choice among them is not supported by this log.
* **Look-alike effects.** Two terms that change the equation error in the same way on
  this log cannot be told apart by it, however good the fit. With ``g_a``, ``g_b`` the
  change of the weighted equation errors per unit parameter (the regressors, on the
  calibration windows),

  .. math:: c_{ab} = \\frac{|g_a^T g_b|}{\\|g_a\\|\\,\\|g_b\\|} > 0.95

  for the chosen effect against every other candidate and every calibrated model
  parameter (Coulomb friction against viscous friction when the piston runs at one
  speed per direction: ``tanh(v/v_eps)`` and ``v`` are then both a sign). The report
  names the variables the two terms depend on and the excitation that separates them
  (several magnitudes of that variable per sign; both signs; the other variable varied
  independently).
* **Implausible units.** A measured state whose samples lie well outside its physical
  limits (below the ambient pressure a chamber cannot go below, above supply) is most
  likely logged in other units or another reference: gauge pressure logged as absolute
  reads one atmosphere low.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.discover.explain import FREE_RUN_DECIDES, TIE
from fdigen.discover.fit_checks import on_bound

#: Cosine above which two regressors are not separable on the log.
COLLINEAR = 0.95


def at_bounds(params: dict, bounds: dict, rel: float = 1e-6) -> list[dict]:
    """Estimates at (within ``rel`` of the span from) a bound of their search."""
    out = []
    for name, (lo, hi) in bounds.items():
        if name not in params or not (np.isfinite(lo) and np.isfinite(hi)):
            continue
        v, span = float(params[name]), float(hi - lo)
        for side, b in (("lower", lo), ("upper", hi)):
            if abs(v - b) <= rel * span:
                out.append({"parameter": name, "value": v, "bound": float(b), "side": side,
                            "on_bound": on_bound(v, float(b))})
    return out


def ties(candidates, chosen: list[str], bic_margin: float, tie: float = TIE) -> list[dict]:
    """Candidates of the chosen effects' rounds within ``tie`` of their BIC, significant."""
    out = []
    for c in candidates:
        if not c.accepted or c.effect not in chosen:
            continue
        rivals = [o for o in candidates if o.round == c.round and o is not c
                  and o.delta_bic < -bic_margin and o.delta_bic - c.delta_bic < tie]
        if rivals:
            runs = {o.effect: o.free_run for o in [c, *rivals] if o.free_run is not None}
            # the free run decided: the chosen one's error well below every rival's
            decided = c.effect in runs and all(
                o.effect in runs and runs[c.effect] < FREE_RUN_DECIDES * runs[o.effect]
                for o in rivals)
            out.append({"chosen": c.effect, "delta_bic": c.delta_bic,
                        "tied_with": {o.effect: o.delta_bic for o in rivals},
                        "free_run": runs, "decided_by_free_run": decided})
    return out


def _regressor(data, effects, fit_params: dict, name: str, cal, sigma, scale: float):
    from fdigen.discover.locate import EquationModel

    eq = EquationModel(data, effects)
    base = eq.values(fit_params)
    hi = dict(base)
    hi[name] = base.get(name, 0.0) + scale
    lo = dict(base)
    lo[name] = base.get(name, 0.0) - scale
    return ((eq.errors(hi) - eq.errors(lo))[cal] / sigma).ravel() / (2 * scale)


def _term_variables(model, terms) -> set:
    xs = {s.symbol: s.name for s in (*model.states, *model.inputs)}
    out = set()
    for t in terms:
        out |= {xs[s] for s in model.expand(t).free_symbols if s in xs}
    return out


def _excitation(va: set, vb: set) -> str:
    if va and va == vb and len(va) == 1:
        v = next(iter(va))
        return (f"both depend on {v} alone: excite {v} at several magnitudes in each "
                "direction (e.g. two or more speeds per direction), and both signs")
    if not va or not vb:
        v = ", ".join(sorted(va | vb)) or "the state"
        return (f"one of them is constant: excite {v} in both directions and at "
                "several levels")
    if va == vb:
        return (f"both depend on {', '.join(sorted(va))}: vary them independently of each "
                "other, at several magnitudes")
    if not va & vb:     # disjoint: "vary Pboil, Tsup independently of Tsup" read wrong
        return (f"vary {', '.join(sorted(va))} and {', '.join(sorted(vb))} independently "
                "of each other")
    return (f"vary {', '.join(sorted(va ^ vb))} independently of "
            f"{', '.join(sorted(va & vb))}")


def look_alikes(data, fit, chosen, candidates_effects, cal, model_parameters,
                threshold: float = COLLINEAR) -> list[dict]:
    """Pairs (chosen effect, other effect or model parameter) not separable on the log."""
    model = data.model
    out = []
    sigma = fit.sigma
    for e in chosen:
        pe = e.parameters[0]
        scale_e = max(abs(fit.params.get(pe.name, 0.0)), abs(pe.nominal), 1e-30) * 1e-3
        ga = _regressor(data, chosen, fit.params, pe.name, cal, sigma, scale_e)
        na = np.linalg.norm(ga)
        if not na > 0:
            continue
        va = _term_variables(model, e.terms(model).values())
        rivals = []
        for o in candidates_effects:
            if o.name in {c.name for c in chosen}:
                continue
            po = o.parameters[0]
            gb = _regressor(data, [*chosen, o], {**fit.params, po.name: 0.0}, po.name, cal,
                            sigma, max(abs(po.nominal), 1e-30) * 1e-3)
            rivals.append((o.name, gb, _term_variables(model, o.terms(model).values())))
        for q in model_parameters:
            v = float(fit.params.get(q, 0.0))
            gb = _regressor(data, chosen, fit.params, q, cal, sigma, max(abs(v), 1e-30) * 1e-3)
            k = model.parameters[[p.name for p in model.parameters].index(q)].symbol
            terms = [f for f in model.f() if f.has(k)]
            rivals.append((q, gb, _term_variables(
                model, [sp.diff(t, k) * k for t in terms])))
        for name, gb, vb in rivals:
            nb = np.linalg.norm(gb)
            if not nb > 0:
                continue
            c = float(abs(ga @ gb) / (na * nb))
            if c > threshold:
                out.append({"effect": e.name, "other": name, "cosine": c,
                            "excitation": _excitation(va, vb)})
    return out


def implausible_units(data, margin: float = 0.02, share: float = 0.01) -> list[str]:
    """Warnings for measured states far outside their physical limits (each column read
    as its state through the sensor's map)."""
    from fdigen.discover.locate import sensor_gain, state_values

    model = data.model
    pvals = model.parameter_values
    out = []
    for i, outs in data.state_outputs.items():
        s = model.states[i]
        if not s.limits:
            continue
        lo, hi = (float(sp.sympify(b).xreplace(pvals)) for b in s.limits)
        span = hi - lo
        for j in outs:
            o = model.outputs[j]
            # the state the column reads, through the sensor's map (a thermocouple in mV)
            y = state_values(model, [j], data.y)
            noise = float(data.noise_std[j]) / abs(sensor_gain(model, j))
            tol = margin * span + 5.0 * noise
            below = float(np.mean(y < lo - tol))
            above = float(np.mean(y > hi + tol))
            if below > share or above > share:
                side = (f"{100 * below:.3g} % of the samples below the lower limit {lo:g}"
                        if below >= above else
                        f"{100 * above:.3g} % of the samples above the upper limit {hi:g}")
                out_of = y[(y < lo - tol) | (y > hi + tol)]
                if np.ptp(out_of) <= 5.0 * noise:
                    hint = (f" There it reads a constant {np.median(out_of):.4g}: a lost "
                            "signal, not a unit problem?")
                elif s.unit.strip() == "Pa" and below >= above:
                    hint = (" Gauge pressure logged as absolute? (absolute = gauge + the "
                            "atmospheric pressure)")
                else:
                    hint = " Check the column's unit and reference."
                out.append(f"implausible values in column {o.column} ({o.name}, state "
                           f"{s.name} [{s.unit}]): {side} (min {np.min(y):.4g}, max "
                           f"{np.max(y):.4g}).{hint}")
    return out


#: Noise-level ratio of the pressure equations above which the log reads as gauge.
GAUGE_RATIO = 2.0


def gauge_pressure(data, fraction: float = 0.6) -> dict | None:
    """Whether the pressures read as gauge while the model wants them absolute.

    A chamber's pressure equation holds the pressure itself (compression
    ``gamma P A xdot / V``), so a pressure one atmosphere off leaves an error that moves
    with the speed: the calibrated equation error of the pressure equations gets rough.
    The white-noise level of those errors (``sigma``, from successive differences) is
    compared between the log as it is and the log with every pressure state (unit ``Pa``,
    lower limit the ambient ``P_amb > 0``) raised by its ambient:

    .. math:: \\rho = \\frac{\\sigma_{as\\ logged}}{\\sigma_{+P_{amb}}} > 2

    reads as gauge pressure (on the rig's logs ``rho`` is 4.6 for a gauge log and 0.25
    for the absolute one).

    Returns
    -------
    dict or None
        ``{"columns", "ratio", "sigma", "sigma_shifted"}`` when the log reads as gauge.
    """
    from fdigen.discover.calibrate import calibrate
    from fdigen.discover.locate import prepare

    model = data.model
    pvals = model.parameter_values
    shift = np.zeros(data.y.shape[1])
    eqs = []
    for i, outs in data.state_outputs.items():
        s = model.states[i]
        if s.unit.strip() != "Pa" or not s.limits or s.name not in data.equations:
            continue
        amb = float(sp.sympify(s.limits[0]).xreplace(pvals))
        if amb <= 0:
            continue
        for j in outs:
            shift[j] = amb
        eqs.append(data.equations.index(s.name))
    if not eqs:
        return None
    fits = []
    for y in (data.y, data.y + shift):
        d = prepare(model, data.t, data.u, y, window=data.window, smooth=data.smooth)
        cal, _, _ = d.split(fraction)
        fits.append(calibrate(d, cal))
    s0, s1 = (float(np.sqrt(np.mean(f.sigma[eqs] ** 2))) for f in fits)
    ratio = s0 / s1 if s1 > 0 else float("inf")
    if ratio <= GAUGE_RATIO:
        return None
    return {"columns": [model.outputs[j].column for j in np.flatnonzero(shift)],
            "ratio": ratio, "sigma": s0, "sigma_shifted": s1}


def diagnose_fit(info, data, lg, ex, final, base, cal, s, say) -> None:
    """Bounds, ties, look-alike effects, implausible units, parameters far from their
    datasheet, effects a calibrated parameter absorbs and effects that are declared faults
    into ``info`` (warnings) of the equation-error loop."""
    from fdigen.discover.calibrate import uncertain_parameters
    from fdigen.discover.declared_faults import effects_as_declared_faults
    from fdigen.discover.fit_report import absorbed_candidates, far_from_datasheet
    from fdigen.discover.effects import library

    _, bounds = uncertain_parameters(data)
    for e in ex.effects:
        bounds.update({p.name: p.bounds for p in e.parameters})
    for d in base.null_directions:
        names = [n for n, c in d.items() if abs(c) >= 0.1]
        held = [n for n in names if n in base.held]
        info["warnings"].append(
            f"the log cannot determine {', '.join(names)} separately: moving them together "
            "leaves every equation's error unchanged; only a combination of them is "
            "determined" + (f", so {', '.join(held)} is held at its datasheet value and "
                            "the others calibrated with it" if held else "")
            + ": a datasheet value you trust, or a measurement that tells them apart, "
            "decides the rest")
    info["at_bounds"] = at_bounds(final.params, bounds)
    for b in info["at_bounds"]:
        info["warnings"].append(
            f"parameter {b['parameter']} = {b['value']:.4g} ended at its {b['side']} bound "
            f"{b['bound']:.4g}: the bound, not the log, decided it (check the model, the "
            "bounds and the sign convention)")
    # as the output-error loop says it (a user's axis on a one-speed ramp: viscous
    # b = 1024 +- 1500, said nowhere on this path)
    from fdigen.discover.fit_checks import poorly_determined

    names = [n for n in final.params if n in bounds and n not in base.held]
    info["poorly_determined"] = poorly_determined(final, names)
    for p in info["poorly_determined"]:
        info["warnings"].append(
            f"parameter {p['parameter']} = {p['value']:.4g} +- {p['std']:.2g} "
            f"({100 * p['relative']:.0f} %): the log hardly determines it (a log that "
            "excites it apart from the other parameters does, or a datasheet value you "
            "trust: then it is not `uncertain`)")
    chosen = [e.name for e in ex.effects]
    info["ties"] = ties(ex.candidates, chosen, s.bic_margin)
    for t in info["ties"]:
        runs = t.get("free_run") or {}
        decided = (f": one free run of the validation part decided ({t['chosen']} "
                   f"{runs[t['chosen']]:.3g}x the sensor noise, " + ", ".join(
                       f"{k} {v:.3g}x" for k, v in runs.items() if k != t["chosen"])
                   + ")") if t["decided_by_free_run"] else (
                       ": this log does not decide between them" + (
                           " (nor does one free run of the validation part: " + ", ".join(
                               f"{k} {v:.3g}x" for k, v in runs.items()) + " the sensor "
                           "noise)" if len(runs) > 1 else ""))
        info["warnings"].append(
            f"tie: {t['chosen']} (dBIC {t['delta_bic']:.1f}) was chosen, but "
            + ", ".join(f"{k} (dBIC {v:.1f})" for k, v in t["tied_with"].items())
            + f" explain the equation error within {TIE:g} of its BIC" + decided)
    from fdigen.discover.input_kind import measured_input_warnings

    tied = {k for t in info["ties"] for k in t["tied_with"]}
    info["warnings"].extend(measured_input_warnings(
        data.model, [*ex.effects, *(e for e in library(data.model) if e.name in tied)]))
    info["look_alikes"] = []
    if ex.effects:
        try:
            others = [e for e in library(data.model) if e.name not in chosen]
            unc = [q.name for q in data.model.parameters if q.uncertain]
            info["look_alikes"] = look_alikes(data, final, ex.effects, others, cal, unc)
        except Exception as exc:  # noqa: BLE001 - a diagnostic never breaks discover
            say(f"look-alike check skipped: {type(exc).__name__}: {exc}")
    for a in info["look_alikes"]:
        info["warnings"].append(
            f"{a['effect']} and {a['other']} cannot be told apart on this log (their "
            f"regressors' cosine {a['cosine']:.3f}); {a['excitation']}")
    units = implausible_units(data)
    try:
        gauge = gauge_pressure(data, s.fraction)
    except Exception as exc:  # noqa: BLE001 - a diagnostic never breaks discover
        gauge = None
        say(f"gauge-pressure check skipped: {type(exc).__name__}: {exc}")
    info["gauge_pressure"] = gauge
    if gauge:
        units.append(
            f"columns {', '.join(gauge['columns'])} read as gauge pressure, the model wants "
            "absolute: the pressure equations' error is {:.3g} times rougher than with the "
            "ambient pressure added (add the atmospheric pressure to these columns)".format(
                gauge["ratio"]))
    info["implausible_units"] = units
    info["warnings"].extend(units)
    info["far_from_datasheet"] = far_from_datasheet(data.model, final, info["warnings"])
    info["absorbed"] = absorbed_candidates(ex.candidates, info["far_from_datasheet"],
                                           s.bic_margin, info["warnings"])
    info["declared_faults"] = effects_as_declared_faults(data.model, ex.effects,
                                                         info["parameters"], info["warnings"])
