"""The discover loop by output error: hidden states, slow sampling, a free-run verdict.

Used when the equation error cannot be formed (a state neither measured nor the
derivative of a measured one) or the log is too short for its windows. Every fit is an
output-error fit of the whole log (:func:`fdigen.discover.output_error.fit_output_error`,
multiple shooting, IPOPT), every error reported is the **free-run** RMS:

1. calibrate the uncertain parameters and the initial state (hidden states included);
2. explain: forward selection over the library (:mod:`fdigen.discover.effects_real` and
   the role library of :mod:`fdigen.discover.effects`), each candidate refitted with the
   uncertain parameters, scored by BIC with the residual variance unknown, the squared
   errors of each output in units of its noise ``sigma_j``,

   .. math:: \\Delta BIC = N \\ln(S_{new} / S_{old}) + k \\ln N < -10, \\quad
             S = \\sum_j (RMS_j / \\sigma_j)^2,

   and confirmed on data it was not fitted on: the free-run error on the ``--validate``
   log (initial state re-estimated, parameters fixed) must drop, or, without one, the
   error on the held-back last part of the log of a fit on the first part;
3. report the free-run error before and after, its ratio to the sensor noise (the model
   *explains* the log only within :data:`EXPLAINS_FACTOR` of it), the parameters the log
   cannot determine, and values far from their datasheet.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fdigen.discover.fit_checks import (FAR_FACTOR, at_bounds,  # noqa: F401 (re-exported)
                                       blind_effect, effect_at_bound, identifiability,
                                       output_error_ties,
                                       poorly_determined, switch_refusal)
from fdigen.discover.fit_report import inflated_noise_warning, verdict_noise
from fdigen.discover.noise import noise_level, noise_of  # noqa: F401 (noise_of re-exported)
from fdigen.discover.sensitivity import effective_samples
from fdigen.discover.output_error import check_length, fit_output_error

#: The model explains a log when its free-run RMS is within this factor of the noise.
EXPLAINS_FACTOR = 3.0

#: IPOPT iterations of a candidate's screening fit (each phase: Gauss-Newton, then the
#: exact Hessian). A candidate still not converged is scored where it stopped: its error
#: is its single-shooting free-run error there, an upper bound of what the candidate can
#: reach, so a stopped fit can lose a candidate, never invent one. Measured on a user's
#: 1500-sample heatsink log: every useful candidate converged within 50 iterations, while
#: one overflow candidate ran 300 (146 s, its error 7 times the calibrated model's). A
#: stalled Gauss-Newton phase restarts with the exact Hessian only when the candidate is
#: already better than the current model there (``dBIC < 0``): a screening fit that
#: could only lose is not worth the exact Hessian's cost (4 s an iteration on a user's
#: 10,000-sample drive log, against 0.6-1.5 s for Gauss-Newton).
SCREEN_ITERATIONS = 60


def _bounds(model, effects):
    b = {q.name: tuple(q.bounds) if q.bounds else (-np.inf, np.inf)
         for q in model.parameters}
    for e in effects:
        b.update({p.name: p.bounds for p in e.parameters})
    return b


def _fit(model, lg, free, effects, start=None, sl=slice(None), hold=None, report=False,
         max_iter=300, restart_if=None):
    # each output weighted by its noise as noise_of reads it (a static output's from
    # y - g(u, p): a power meter's 10 W had been read as 29.7 W and weighed 9x too little)
    return fit_output_error(model, lg.t[sl], lg.u[sl], lg.y[sl],
                            list(free) + [p.name for e in effects for p in e.parameters],
                            _bounds(model, effects), effects=tuple(effects), start=start,
                            hold=hold, report=report, max_iter=max_iter,
                            restart_if=restart_if,
                            sigma=noise_of(model, lg.y[sl], lg.u[sl]))


def replay(model, lg, fit) -> np.ndarray:
    """Free-run RMS per output of ``fit``'s parameters on another log (its initial state
    re-estimated on the log's beginning, the parameters fixed:
    :func:`fdigen.discover.replay.free_run_rms`)."""
    from fdigen.discover.replay import free_run_rms

    return free_run_rms(model, lg.t, lg.u, lg.y, effects=fit.effects, params=fit.params,
                        bounds=_bounds(model, fit.effects), sigma=noise_of(model, lg.y, lg.u))


def _confirm(model, lg, val, free, cur, cand, fraction) -> tuple[bool, str]:
    if val is not None:
        a, b = replay(model, val, cur), replay(model, val, cand)
        ok = float(np.sum(b ** 2)) < float(np.sum(a ** 2))
        return ok, (f"validation log free-run RMS {_fmt(a)} -> {_fmt(b)}")
    k = int(fraction * len(lg.t))
    rest = slice(k, None)
    f0 = _fit(model, lg, free, cur.effects, start=cur.params, sl=slice(0, k), hold=cur.held)
    f1 = _fit(model, lg, free, cand.effects, start=cand.params, sl=slice(0, k),
              hold=cur.held)
    from fdigen.discover.output_error import accurate_substeps, build_model, simulate

    errs = []
    for f in (f0, f1):
        dt = float(np.median(np.diff(lg.t)))
        om = build_model(model, f.effects, dt, accurate_substeps(model, dt))
        _, Y = simulate(om, f.x0, lg.u, f.params)
        errs.append(float(np.sqrt(np.nanmean((lg.y[rest] - Y[rest]) ** 2))))
    return errs[1] < errs[0], (f"held-back part ({lg.t[k]:g} s on) free-run RMS "
                               f"{errs[0]:.4g} -> {errs[1]:.4g}")


def _fmt(a) -> str:
    return ", ".join(f"{v:.4g}" for v in np.atleast_1d(a))


def explain_by_output_error(model, lg, val, free, *, max_effects=2, bic_margin=10.0,
                            fraction=0.6, say=lambda m: None):
    """Forward selection of effects by output error (see the module)."""
    from fdigen.discover.effects import library
    from fdigen.discover.effects_real import real_plant_effects

    pool = real_plant_effects(model, lg.t, lg.u, lg.y)
    names = {e.name for e in pool}
    pool += [e for e in library(model) if e.name not in names]
    import time

    t0 = time.perf_counter()
    base = _fit(model, lg, free, (), report=True)
    took = time.perf_counter() - t0
    say(f"calibrated by output error in {took:.0f} s: free-run RMS {_fmt(base.rms)}")
    if base.success and max_effects > 0 and pool:
        # a user's 15000-sample log ran 10 minutes without saying how long it would take
        say(f"screening {len(pool)} candidate effects, up to {max_effects} round"
            f"{'s' if max_effects > 1 else ''}: each a fit of the whole log like the "
            f"calibration ({took:.0f} s here), so up to about "
            f"{max(1, round(took * len(pool) * max_effects / 60))} min; a shorter log or "
            "--max-effects 1 takes less")
    if not base.success:
        # a candidate's fit starts where the calibration stopped and runs on: what it
        # gains may be the calibration's own unfinished descent, not the effect (a user's
        # heating zone: every fit stopped, and two sensor offsets were chosen and
        # committed). No effect is chosen against a calibration that did not converge.
        say("the calibration did not converge (IPOPT): no effect is compared against it")
        return base, base, [], []
    starts = _threshold_starts(model, lg, base)
    noise = noise_of(model, lg.y, lg.u)
    cur, chosen, candidates = base, [], []
    while len(chosen) < max_effects:
        # a second log confirms on data independent of the fit (every sample counts in
        # the screening); without one, the held-back part of the same log does, and the
        # BIC counts the independent samples only (the cascaded tanks' overflow, 0.669 ->
        # 0.59 V on the benchmark's second record, is taken either way)
        N = float(base.n) if val is not None else effective_samples(cur, lg.y, noise)
        scored = []
        for e in pool:
            if e in chosen:
                continue
            k = len(e.parameters)
            # the exact-Hessian restart of a stalled fit only for a candidate already
            # better than the current model where Gauss-Newton stopped (dBIC < 0)
            promising = (lambda sse, k=k: N * np.log(max(sse, 1e-300) / cur.sse)
                         + k * np.log(N) < 0)
            try:
                f = _fit(model, lg, free, chosen + [e], start={**starts, **cur.params},
                         hold=base.held, max_iter=SCREEN_ITERATIONS, restart_if=promising)
            except Exception as exc:  # noqa: BLE001 - one candidate never breaks the loop
                say(f"  {e.name}: fit failed ({type(exc).__name__}: {exc})")
                continue
            dbic = N * np.log(max(_scaled(f, noise), 1e-300)
                              / max(_scaled(cur, noise), 1e-300)) + k * np.log(N)
            stopped = "" if f.success else " (fit stopped before converging: an upper bound)"
            refused = (effect_at_bound(e, f, _bounds(model, chosen + [e]))
                       or switch_refusal(e, f.params, model, lg.u, lg.y, noise))
            say(f"  {e.name}: free-run RMS {_fmt(f.rms)}, dBIC {dbic:.1f}{stopped}"
                + (f"; refused: {refused}" if refused else ""))
            candidates.append({"effect": e.name, "round": len(chosen) + 1,
                               "acts_on": "sensor" if e.outputs and not e.states
                               else "plant",
                               "delta_bic": float(dbic), "rms": f.rms.tolist(),
                               "converged": bool(f.success),
                               "parameters": {p.name: f.params[p.name]
                                              for p in e.parameters},
                               **({"refused": refused} if refused else {})})
            if not refused:
                scored.append((dbic, e, f))
        scored.sort(key=lambda s: s[0])
        took = False
        for dbic, e, f in scored:
            if dbic >= -bic_margin:
                break
            ok, why = _confirm(model, lg, val, free, cur, f, fraction)
            say(f"  {e.name}: {'confirmed' if ok else 'not confirmed'} ({why})")
            for c in candidates:
                if c["effect"] == e.name and c["round"] == len(chosen) + 1:
                    c["confirmation"] = why
                    c["confirmed"] = ok
            if ok:
                chosen.append(e)
                cur = f
                took = True
                break
        if not took:
            break
    while chosen:  # the chosen fit again, with its intervals and blind directions
        cur = _fit(model, lg, free, chosen, start=cur.params, hold=base.held, report=True)
        cur.null_directions = base.null_directions[:1] + cur.null_directions
        # an effect whose own parameter moves no output at the fit is not what the log
        # shows (a user's zone: off_y_Tr = -2.0 "does not move any output", committed)
        blind = blind_effect(chosen, cur)
        if blind is None:
            break
        say(f"  {blind.name}: refused: its parameter moves no output at the fit")
        for c in candidates:
            if c["effect"] == blind.name:
                c["refused"] = "its parameter moves no output at the fit"
        chosen = [e for e in chosen if e is not blind]
        cur = base
    return base, cur, chosen, candidates



def _scaled(fit, noise) -> float:
    """The fit's free-run error summed in units of each output's noise,
    ``sum_j (rms_j / sigma_j)^2``: the BIC's sum of squares. Unscaled, a power meter's
    W^2 drowned a thermistor's K^2, and a heat loss that cut the thermistor's error 3.6x
    scored dBIC -1.1."""
    return float(np.sum((np.asarray(fit.rms, float) / np.asarray(noise, float)) ** 2))


def _threshold_starts(model, lg, fit) -> dict:
    """Start values of the effects' switching levels inside what the calibrated model
    visits (the 90th percentile of its free-run state, of the input): a level started
    beyond it leaves its rounded kink flat, and the search never moves it."""
    from fdigen.discover.output_error import accurate_substeps, build_model, simulate

    dt = float(np.median(np.diff(lg.t)))
    om = build_model(model, (), dt, accurate_substeps(model, dt))
    X, _ = simulate(om, fit.x0, lg.u, fit.params)
    out = {f"xof_{s.name}": float(np.nanquantile(X[:, i], 0.9))
           for i, s in enumerate(model.states)}
    out.update({f"umax_{v.name}": float(np.nanquantile(np.asarray(lg.u)[:, j], 0.9))
                for j, v in enumerate(model.inputs)})
    return out


def hidden_states(model) -> list[str]:
    """States neither measured nor the derivative of a measured state (the equation
    error cannot be formed for them)."""
    from fdigen.discover.locate import chain_gain, measured_states

    meas = measured_states(model)
    f = model.f()
    derived = {j for i in meas for j, s in enumerate(model.states)
               if j not in meas and chain_gain(model, f[i], s.symbol) is not None}
    return [s.name for j, s in enumerate(model.states) if j not in meas and j not in derived]


def run_output_loop(model_path, mdl, lg, *, val=None, settings, out_dir, reason: str,
                    build: bool, say, plot: bool = True) -> dict:
    """The whole output-error loop: the ``discover.json`` dict (see docs/discover.md)."""
    free = [q.name for q in mdl.parameters if q.uncertain]
    check_length(len(lg.t), len(free) + len(mdl.states), float(lg.sample_time))
    datasheet = {q.name: float(q.value) for q in mdl.parameters}
    say(f"{reason}: calibrating {', '.join(free) or 'nothing'} by output error over the "
        "whole log (free-run simulation, hidden states' initial values estimated)")
    base, final, chosen, candidates = explain_by_output_error(
        mdl, lg, val, free, max_effects=settings.max_effects,
        bic_margin=settings.bic_margin, fraction=settings.fraction, say=say)
    # the values the written model keeps from the datasheet, the others fitted again
    # with them held: the error reported is the written model's
    from fdigen.discover.held_values import hold_undetermined

    same = final is base
    final, kept = hold_undetermined(
        mdl, final, free, _bounds(mdl, chosen),
        lambda hold, start: _fit(mdl, lg, free, chosen, start=start, hold=hold,
                                 report=True), say)
    if same:
        base = final
    elif kept:
        base, _ = hold_undetermined(
            mdl, base, free, _bounds(mdl, ()),
            lambda hold, start: _fit(mdl, lg, free, (), start=start, hold=hold,
                                     report=True))
    names = [o.name for o in mdl.outputs]
    noise = noise_of(mdl, lg.y, lg.u)
    nominal = fit_output_error(mdl, lg.t, lg.u, lg.y, [], _bounds(mdl, ()), hold={},
                               sigma=noise, report=False)
    per = (lambda a: {n: float(v) for n, v in zip(names, a)})
    eff_params = [p.name for e in chosen for p in e.parameters]
    # judged against the declared noise where the log's estimate is far above it (a
    # user's differentiated encoders read 3.71 rad/s for 1.0 declared, and a fit 2.9x the
    # declared noise was "explained", as the equation-error path no longer says)
    judged, inflated = verdict_noise(mdl, noise)
    ratio = final.rms / judged
    explains = bool(np.all(ratio <= EXPLAINS_FACTOR))
    msg = ("effects: " + ", ".join(e.name for e in chosen) if chosen
           else "no effect chosen: the calibration by output error did not converge "
           "(IPOPT), and an effect's gain against it could be the calibration's own "
           "unfinished descent; fewer uncertain parameters, bounds, or a longer or richer "
           "log let it converge" if not base.success
           else "no effect of the library explains the log better (BIC and confirmation)")
    verdict = (f"the model explains the log: free-run error within {EXPLAINS_FACTOR:g}x "
               "the sensor noise" if explains else
               "the model does not explain the log to its noise: free-run error "
               + ", ".join(f"{n} {r:.3g}x" for n, r in zip(names, ratio))
               + f" the sensor noise (explained means within {EXPLAINS_FACTOR:g}x)")
    info = {
        "log": str(lg.path), "model": str(model_path), "method": "output_error",
        "reason": reason,
        "equation": next(iter(chosen[0].states), None) if chosen else None,
        "equations": sorted({s for e in chosen for s in e.states}),
        "effect": chosen[0].name if chosen else None,
        "effects": [e.name for e in chosen],
        # the sensors each effect reads through, when it acts on no state's equation
        "sensor_effects": {e.name: sorted(e.outputs) for e in chosen
                           if e.outputs and not e.states},
        "parameters": {k: final.params[k] for k in eff_params + free},
        # a parameter held at its datasheet value (a blind direction) has no interval
        "uncertainty": {k: final.std.get(k) for k in eff_params + free},
        "conditional_uncertainty": {k: final.conditional_std.get(k)
                                    for k in eff_params + free},
        "calibrated": {k: base.params[k] for k in free},
        "calibrated_std": {k: base.std.get(k) for k in free},
        "calibrated_conditional_std": {k: base.conditional_std.get(k) for k in free},
        "initial_state": {s.name: float(v) for s, v in zip(mdl.states, final.x0)},
        "error_nominal": per(nominal.rms), "error_before": per(base.rms),
        "error_after": per(final.rms), "error_kind": "free-run RMS over the whole log",
        "noise": per(judged), "noise_ratio_before": per(base.rms / judged),
        "noise_ratio_after": per(ratio), "explains": explains,
        "explains_factor": EXPLAINS_FACTOR, "verdict": verdict,
        "calibration": [float(lg.t[0]), float(lg.t[-1])],
        "validation_split": float(lg.t[int(settings.fraction * (len(lg.t) - 1))]),
        "candidates": candidates, "message": msg,
        "warnings": [inflated_noise_warning(mdl, inflated)] if inflated else [],
        "settings": dict(settings.__dict__),
        "kept_datasheet": kept,
    }
    from fdigen.discover.fit_checks import worse_after_fit

    info["warnings"].extend(worse_after_fit(info["error_nominal"], info["error_after"],
                                            info["noise"]))
    info["warnings"].extend(
        f"{k['reason']}: the written model keeps the datasheet value {k['datasheet']:.4g} "
        f"(estimate {k['estimate']:.4g}), and the others are fitted again with it held "
        "(the errors above are that model's)" for k in kept.values())
    if val is not None:
        vb, va = replay(mdl, val, base), replay(mdl, val, final)
        info["validation"] = {"log": str(val.path), "error_before": per(vb),
                              "error_after": per(va),
                              "noise_ratio_after": per(
                                  va / verdict_noise(mdl, noise_of(mdl, val.y, val.u))[0])}
    ident, warns = identifiability(mdl, final, datasheet)
    # compared in units of each sensor's noise (the unweighted sum of squares of a power
    # meter in W outweighed a thermistor's in K: a calibration better on both counts of
    # noise was called worse than the datasheet)
    if np.sum((nominal.rms / noise) ** 2) < np.sum((base.rms / noise) ** 2):
        # the calibration's free run is worse than the datasheet's: multiple shooting
        # settled where the shooting segments fit and the free run does not (a user's arm:
        # 3.87 with the datasheet, 46.8 calibrated, and nothing said)
        warns.append(
            "the calibrated model's free-run error ("
            + ", ".join(f"{n} {v:.4g}" for n, v in zip(names, base.rms))
            + ") is larger than the datasheet model's ("
            + ", ".join(f"{n} {v:.4g}" for n, v in zip(names, nominal.rms))
            + "): the calibration settled where the multiple-shooting segments fit and the "
            "whole-log simulation does not; its values and the effects chosen from them "
            "are not to be trusted (bounds on the parameters, or a longer or richer log)")
        if info["explains"]:
            info["explains"] = False
            info["verdict"] = ("the model does not explain the log: the calibration's "
                               "free run is worse than the datasheet's")
    info["identifiability"] = ident
    info["at_bounds"] = at_bounds(final, _bounds(mdl, chosen))
    for b in info["at_bounds"]:
        sd = final.std.get(b["parameter"])
        near = b["on_bound"]
        warns.append(f"parameter {b['parameter']} = {b['value']:.4g} ended at its "
                     f"{b['side']} bound {b['bound']:.4g}: the bound, not the log, decided it"
                     if near or sd is None else
                     f"parameter {b['parameter']} = {b['value']:.4g} +- {sd:.2g}: its interval "
                     f"reaches its {b['side']} bound {b['bound']:.4g}, so the bound, not the "
                     "log, limits it")
    from fdigen.discover.diagnostics import TIE

    info["poorly_determined"] = poorly_determined(final, eff_params + free)
    for p in info["poorly_determined"]:
        warns.append(f"parameter {p['parameter']} = {p['value']:.4g} +- {p['std']:.2g} "
                     f"({100 * p['relative']:.0f} %): the log hardly determines it")
    from fdigen.discover.declared_faults import effects_as_declared_faults

    info["declared_faults"] = effects_as_declared_faults(mdl, chosen, info["parameters"],
                                                         warns)
    info["ties"] = output_error_ties(candidates, chosen, TIE)
    from fdigen.discover.input_kind import measured_input_warnings

    warns.extend(measured_input_warnings(mdl, chosen))
    from fdigen.discover.effects_physics import assumed_ambient_notes

    warns.extend(assumed_ambient_notes(chosen))
    info["look_alikes"] = []
    for t in info["ties"]:
        warns.append(f"{t['other']} explains the log as well as {t['chosen']} (dBIC "
                     f"{t['delta_bic']:.1f} against {t['chosen_delta_bic']:.1f}): the log "
                     "cannot tell them apart; a log that excites them differently can")
    from fdigen.derive.linearisation import growth_rate

    try:
        unstable = growth_rate(mdl)
    except Exception:  # noqa: BLE001 - a diagnostic never breaks discover
        unstable = 0.0
    if unstable > 0:
        warns.append(f"the plant is unstable open loop at its operating point (a mode of "
                     f"{unstable:.3g} 1/s): a free-run simulation departs from the log "
                     "within a few time constants whatever the parameters, so its error, "
                     "the calibration and any effect chosen by it say little; calibrate on "
                     "logs whose states are all measured (the equation error), or on short "
                     "segments")
    info["warnings"].extend(warns)
    info["converged"] = bool(final.success)
    if plot and base.Y is not None and final.Y is not None:
        from fdigen.discover.report import plot_free_run

        info["plot"] = str(plot_free_run(Path(out_dir) / "discover.png", mdl, lg.t, lg.y,
                                         base.Y, final.Y, title=f"{mdl.name}: {msg}"))
    if not final.success:
        info["warnings"].append("the output-error fit did not converge (IPOPT): the "
                                "numbers are those of its last iterate")
    if chosen:
        from fdigen.discover.augment import rebuild, write_augmented

        path, aug = write_augmented(model_path, out_dir, mdl, chosen, final.params,
                                    final.std, None,
                                    calibrated={k: final.params[k] for k in free},
                                    origin=lg.path and str(lg.path).rsplit("/", 1)[-1],
                                    notes=info["warnings"])
        info["model_file"] = str(path)
        say(f"wrote {path}")
        if build:
            from fdigen.discover.design_check import ensure_design

            try:
                # thresholds the file lacks are read from the log, as the equation-error
                # loop does (a user's air tunnel: "written but not built", exit 0)
                _, _, notes = ensure_design(path, aug, say, (lg.u, lg.y))
                info["warnings"].extend(notes)
                res = rebuild(path, out_dir)
                info["build"] = str(res.folder)
            except Exception as exc:  # noqa: BLE001 - the loop's result stands without code
                info["warnings"].append(f"the augmented model was written but its code "
                                        f"was not built: {type(exc).__name__}: {exc}")
    else:
        from fdigen.discover.augment import write_augmented

        path, _ = write_augmented(model_path, out_dir, mdl, [], final.params, final.std,
                                  None, calibrated={k: final.params[k] for k in free},
                                  origin=str(lg.path).rsplit("/", 1)[-1],
                                  file_name=f"{mdl.name}_calibrated.toml",
                                  notes=info["warnings"])
        info["calibrated_model_file"] = str(path)
    return info

