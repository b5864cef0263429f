"""What a discover report may claim: honest errors, noise ratios, a second log, datasheets.

* the equation-error path's output error re-initialises at least every
  :data:`MIN_REINIT_SAMPLES` samples (a shorter period would report a one-step prediction
  as the error; the report says when it lengthened ``--reinit``);
* the error is compared with the sensor noise (second differences of the log): the model
  *explains* the log only within ``EXPLAINS_FACTOR`` of it;
* ``--validate``: free-run RMS of the calibrated nominal and augmented models on a second
  log (initial state estimated, parameters fixed);
* parameters calibrated far from their datasheet with a tight interval are warned about.
"""

from __future__ import annotations

import numpy as np


#: The output-error simulation of the equation-error path runs at least this many samples
#: between re-initialisations (fewer would report a one-step prediction as the error).
MIN_REINIT_SAMPLES = 50


def honest_error(mdl, lg, rms: dict, asked: float, used: float, dt: float,
                 hint: str = "") -> dict:
    """Noise levels, the error's ratio to them, and what the report may claim (``hint``
    appended to a "does not explain")."""
    from fdigen.discover.output_loop import EXPLAINS_FACTOR, noise_of

    noise, inflated = verdict_noise(mdl, noise_of(mdl, lg.y, lg.u))
    ratio = {}
    for j, o in enumerate(mdl.outputs):
        key = o.name if o.name in rms else o.column
        if key in rms and noise[j] > 0 and np.isfinite(rms[key]):
            ratio[key] = float(rms[key] / noise[j])
    warnings = [inflated_noise_warning(mdl, inflated)] if inflated else []
    if used > asked:
        warnings.append(f"--reinit {asked:g} s is {asked / dt:.3g} samples at this log's "
                        f"{dt:g} s: the error would be a one-step prediction; the "
                        f"simulation is re-initialised every {used:g} s "
                        f"({MIN_REINIT_SAMPLES} samples) instead")
    worst = max(ratio.items(), key=lambda kv: kv[1], default=(None, 0.0))
    explains = worst[1] <= EXPLAINS_FACTOR
    msg = "" if explains else (
        f"; the output error is {worst[1]:.3g}x the sensor noise on {worst[0]} (over "
        f"{used:g} s re-initialisations): the model does not explain the log to its "
        f"noise (explained means within {EXPLAINS_FACTOR:g}x){hint}")
    keys = [o.name if o.name in rms else o.column for o in mdl.outputs]
    return {"noise": {k: float(v) for k, v in zip(keys, noise)},
            "ratio": ratio, "explains": bool(explains), "warnings": warnings,
            "message": msg}


#: A log's noise estimate more than this many times the declared ``noise_std`` is taken
#: for signal between samples, not noise, when the fit is judged.
INFLATED = 3.0


def inflated_noise_warning(mdl, inflated) -> str:
    """The warning of :func:`verdict_noise`'s outputs ``[(j, estimate, declared)]``."""
    return ("the log's own noise estimate (second differences) is more than "
            f"{INFLATED:g}x the declared noise_std on " + ", ".join(
                f"{mdl.outputs[j].name} ({est:.3g} against {decl:.3g})"
                for j, est, decl in inflated)
            + ": the signal moves between samples at this sampling, or a differentiated "
            "encoder's counts (or the sensor is noisier than declared: correct its "
            "noise_std); the fit is judged against the declared noise")


def verdict_noise(mdl, estimated):
    """The noise a fit is judged against, per output: the log's estimate, or the declared
    ``noise_std`` where the estimate is more than :data:`INFLATED` times it; and those
    outputs ``[(j, estimate, declared)]``.

    Second differences of a log sampled slowly take the signal's motion for noise: a
    user's pump rig logged at 1 Hz read its tachometer's noise as 127 rpm (5 rpm on the
    datasheet) and its pressure's as 0.029 bar (0.005), and a fit 13x the pressure
    sensor's noise was "explained"."""
    est = np.asarray(estimated, dtype=float)
    decl = np.array([o.noise_std for o in mdl.outputs], dtype=float)
    bad = (decl > 0) & (est > INFLATED * decl)
    return (np.where(bad, decl, est),
            [(int(j), float(est[j]), float(decl[j])) for j in np.flatnonzero(bad)])


def too_short(data, cal, val, s, window, t) -> str | None:
    """Why the equation test cannot run on this log (too few windows), or ``None``.

    The length it names is the one that would give the test its 20 calibration and 10
    validation windows at the share of windows this log could use (windows at a state's
    limits or a sensor's range, and those the smoothing cannot fill, are not usable).
    """
    if cal.sum() >= 20 and val.sum() >= 10:
        return None
    t = np.asarray(t, dtype=float)
    duration = float(t[-1] - t[0])
    dt = float(np.median(np.diff(t))) if t.size > 1 else window
    nominal = max(1, int(duration // window))
    usable = max(int(cal.sum() + val.sum()), 1) / nominal
    need = max(20 / s.fraction, 10 / (1 - s.fraction)) / min(usable, 1.0) * window
    shortest = 10 * dt
    if window > 1.01 * shortest and duration < need * shortest / window:
        # not even the shortest window gives the test its windows: offering it sent a
        # user with a 4 s log at 1 Hz from --window 2 to "at least 77 s" and round again
        other = ""
        samples = int(t.size)
        if samples < 30:
            return (f"the log holds {samples} samples over {duration:.4g} s: too short for "
                    f"the equation test (20 calibration and 10 validation windows of at "
                    f"least 10 samples each: about {need * shortest / window:.4g} s at "
                    f"least) and for the output-error loop (at least 30 samples, "
                    f"{30 * dt:g} s at {dt:g} s, and 10 per unknown); record a longer "
                    "healthy log")
    elif window > 1.01 * shortest:
        other = f"a shorter window (`fdigen discover --window`, down to 10 samples: {shortest:g} s), "
    elif window < 0.99 * shortest:
        other = f"windows of at least 10 samples (`fdigen discover --window {shortest:g}`), "
    else:
        other = ""
    return (f"too few usable windows ({int(cal.sum())} calibration, {int(val.sum())} "
            f"validation; the equation test needs 20 and 10) of {window:g} s "
            f"({window / dt:.3g} samples each; {usable:.0%} of this log's windows usable): "
            f"it needs a log of at least about {need:.4g} s (this one is {duration:.4g} s), "
            f"{other}or the output-error loop, which needs no windows (`fdigen {s.command} "
            "--method output-error`)")


def validate_equation_loop(mdl, val_log, ex, base, final, s) -> dict:
    """Free-run RMS per output on a second log, calibrated nominal vs augmented model
    (:func:`fdigen.discover.replay.free_run_rms`)."""
    from fdigen.discover.replay import free_run_rms

    out = {"log": str(val_log.path)}
    for key, effs, params in (("error_before", (), base.params),
                              ("error_after", tuple(ex.effects), final.params)):
        bounds = {q.name: q.bounds or (-np.inf, np.inf) for q in mdl.parameters}
        bounds.update({p.name: p.bounds for e in effs for p in e.parameters})
        rms = free_run_rms(mdl, val_log.t, val_log.u, val_log.y, effects=effs,
                           params=params, bounds=bounds)
        out[key] = {o.name: float(v) for o, v in zip(mdl.outputs, rms)}
    return out


def far_from_datasheet(model, fit, warnings: list) -> list[dict]:
    """Uncertain parameters calibrated far off their datasheet value
    (:func:`fdigen.discover.fit_checks.far_off`); a warning naming both is appended."""
    from fdigen.discover.fit_checks import far_off, far_text

    out = []
    for q in model.parameters:
        v, sd = fit.params.get(q.name), fit.std.get(q.name, np.nan)
        if not q.uncertain or v is None or sd is None or not far_off(v, q.value, sd):
            continue
        out.append({"parameter": q.name, "value": v, "datasheet": q.value, "std": sd})
        warnings.append(far_text(q.name, v, q.value, sd))
    return out


#: An effect parameter this many standard deviations from zero is "estimated tightly".
TIGHT_Z = 10.0


def absorbed_candidates(candidates, far: list, bic_margin: float, warnings: list) -> list:
    """Effects the BIC did not take although the log estimates them tightly, while an
    uncertain parameter sits far from its datasheet: the parameter may be absorbing the
    effect. A user's motor with Coulomb friction: ``Tc = 7.84e-3 +- 2.1e-4`` (truth 8e-3,
    37 sigma from zero) was left out at dBIC -1.3, the viscous ``b`` calibrated to 1.77
    times its datasheet, and nothing said the two were linked. A warning names both.
    """
    if not far:
        return []
    out = []
    for c in candidates:
        c = c.as_dict() if hasattr(c, "as_dict") else c
        if c.get("accepted") or not c.get("parameters") or c.get("round", 1) != 1:
            continue
        dbic = c.get("delta_bic")
        if dbic is None or not -bic_margin <= dbic < 0:
            continue
        z = [abs(v) / c["std"][k] for k, v in c["parameters"].items()
             if c.get("std", {}).get(k) and np.isfinite(c["std"][k]) and c["std"][k] > 0]
        if not z or min(z) < TIGHT_Z:
            continue
        out.append({"effect": c["effect"], "delta_bic": dbic, "z": min(z)})
        est = ", ".join(f"{k} = {v:.4g} +- {c['std'][k]:.2g}"
                        for k, v in c["parameters"].items())
        names = ", ".join(f"{f['parameter']} ({abs(f['value'] / f['datasheet']):.3g}x its "
                          "datasheet)" for f in far)
        warnings.append(
            f"{c['effect']} is estimated tightly ({est}, {min(z):.0f} sigma from zero) but "
            f"was not added (dBIC {dbic:.1f}; an effect needs below {-bic_margin:g}): the "
            f"calibrated {names} may be absorbing it. If the datasheet holds, the log "
            f"shows {c['effect']}; a log that excites them differently (both signs and "
            "several levels of the signal) decides")
    return out


def _noise_units(errors: dict, noise: dict) -> float | None:
    """``sum_k (e_k / sigma_k)^2`` over the outputs with a noise level, or None."""
    terms = [(float(e) / float(noise[k])) ** 2 for k, e in (errors or {}).items()
             if noise.get(k) and e is not None]
    return sum(terms) if terms else None


def unconfirmed_effects(info: dict, model=None) -> list[str]:
    """Why discover's effects are not confirmed: a parameter of theirs whose interval
    holds zero, a free-run output error, in units of the sensors' noise, larger with
    them on the log or on the validation log, or a sensor's effect (``sensor_effects``:
    effect -> the outputs it reads through) that makes its own sensor's error larger (one
    sentence each; none: confirmed so far). ``fdigen commission`` does not commit such
    effects (:mod:`fdigen.commission.withhold`).
    With ``model``, an output's errors and noise are matched by its name or its log
    column (discover keys the whole-log errors by column, a validation log's by name)."""
    effects = list(info.get("effects") or ())
    if not effects:
        return []
    out = []
    calibrated = info.get("calibrated") or {}
    std = info.get("uncertainty") or {}
    for k, v in (info.get("parameters") or {}).items():
        sd = std.get(k)
        if k not in calibrated and sd is not None and abs(float(v)) < float(sd):
            # the output-error loop wrote a pump rig's encoder offset of 6.03 +- 49 rpm
            out.append(f"the log does not determine {k} = {float(v):.4g} +- {float(sd):.2g} "
                       "(its interval holds zero)")
    aliases = {}
    for o in getattr(model, "outputs", ()):
        aliases[o.name], aliases[o.column] = o.column, o.name
    noise = info.get("noise") or {}
    checks = [("on the log", info.get("error_before"), info.get("error_after"))]
    val = info.get("validation")
    if isinstance(val, dict):
        checks.append((f"on the validation log {val.get('log')}", val.get("error_before"),
                       val.get("error_after")))
    for where, before, after in checks:
        # the outputs are matched by name or by log column
        n = {k: noise.get(k, noise.get(aliases.get(k))) for k in before or {}}
        b, a = _noise_units(before, n), _noise_units(after, n)
        if b is not None and a is not None and a > b * (1 + 1e-9):
            worse = ", ".join(f"{k} {before[k]:.4g} -> {after[k]:.4g}" for k in before
                              if k in after and after[k] > before[k])
            out.append(f"the free-run output error {where} is larger with the effects, in "
                       f"units of the sensors' noise ({worse})")
            continue
        # a sensor's effect must explain its own sensor: a pressure-transmitter offset
        # that made that transmitter's error 24 % larger was taken on a hydraulic axis,
        # the position's error (416x its noise) outweighing it in the sum
        own = info.get("sensor_effects") or {}
        for e in effects:
            for k in [k for k in before or {} if {k, aliases.get(k)} & set(own.get(e, ()))]:
                if k in (after or {}) and after[k] > 1.05 * before[k] \
                        and after[k] - before[k] > float(n.get(k) or 0.0):
                    out.append(f"{e} makes its own sensor's free-run error larger {where} "
                               f"({k} {before[k]:.4g} -> {after[k]:.4g})")
    return out


#: A model whose linearisation has an eigenvalue with real part above this (1/s) drifts
#: open loop (an integrator, an unstable balance): its free run says nothing of the fit.
STABLE_MARGIN = -1e-9


def free_run_ratios(mdl, data, mask, effects, params: dict, noise: dict) -> dict | None:
    """Output error of one free run of the samples ``mask`` over each output's noise
    level (``noise``: column -> level), or ``None`` when the model drifts open loop (an
    eigenvalue of its linearisation at or right of ``STABLE_MARGIN``) or the part is
    shorter than 30 samples.

    The run starts from the state the part's first sample reconstructs
    (:func:`fdigen.discover.report.output_error` with one period: every state of the
    equation-error path is measured).
    """
    from fdigen.derive.linearisation import linearise
    from fdigen.discover.report import output_error

    stable = mdl.derived("free_run_stable")
    if "stable" not in stable:
        try:
            eig = np.linalg.eigvals(np.asarray(linearise(mdl).A, dtype=float))
            stable["stable"] = bool(eig.size and float(np.max(eig.real)) <= STABLE_MARGIN)
        except Exception:  # noqa: BLE001 - no linearisation: no free-run verdict
            stable["stable"] = False
    if not stable["stable"] or int(np.sum(mask)) < 30:
        return None
    span = float(np.sum(mask)) * float(data.dt) + float(data.dt)
    rms = output_error(data, tuple(effects), params, mask, reinit=span)["rms"]
    # a free run that diverged (NaN, inf) is an infinite error, never a missing one
    return {key: float(v / noise[key]) if np.isfinite(v) else float("inf")
            for key, v in rms.items() if noise.get(key, 0.0) > 0}


def free_run_judge(mdl, data, lg, mask):
    """``judge(effects, params)``: the worst output error of one free run of the samples
    ``mask`` in sensor noise levels (:func:`free_run_ratios`; ``None`` where it says
    nothing), the noise levels those of the fit's verdict (:func:`honest_error`)."""
    from fdigen.discover.output_loop import noise_of

    levels, _ = verdict_noise(mdl, noise_of(mdl, lg.y, lg.u))
    noise = {}
    for o, n in zip(mdl.outputs, levels):
        noise[o.name] = noise[o.column] = float(n)

    def judge(effects, params):
        ratio = free_run_ratios(mdl, data, mask, effects, params, noise)
        return max(ratio.values()) if ratio else None
    return judge


def free_run_verdict(mdl, data, mask, effects, params: dict, honesty: dict,
                     reinit: float) -> dict | None:
    """Judge the equation-error path's fit by one free run over the validation part too.

    The error re-initialised every ``reinit`` seconds shows what the model predicts over
    that horizon only: a user's water rig with a 2 s transmitter lag and a leak the model
    lacked read 2.06x its noise re-initialised every 25 s ("explains") and 3.24x over one
    free run. When the model is stable open loop, the validation part is run once
    (:func:`free_run_ratios`) and the fit is judged on the worse of the two; ``honesty``
    (:func:`honest_error`'s result) is updated in place.
    Returns the free run's ratios (``None`` when the model drifts open loop, or the part
    is too short).
    """
    from fdigen.discover.output_loop import EXPLAINS_FACTOR

    ratio = free_run_ratios(mdl, data, mask, effects, params, honesty["noise"])
    if ratio is None:
        return None
    worst = max(ratio.items(), key=lambda kv: kv[1], default=(None, 0.0))
    if honesty["explains"] and worst[1] > EXPLAINS_FACTOR:
        honesty["explains"] = False
        honesty["message"] = (
            f"; over one free run of the validation part the output error is "
            f"{worst[1]:.3g}x the sensor noise on {worst[0]} (re-initialised every "
            f"{reinit:g} s it is {honesty['ratio'].get(worst[0], float('nan')):.3g}x: what "
            f"builds up over longer than that, a lag or a small leak, does not show there): "
            f"the model does not explain the log to its noise (explained means within "
            f"{EXPLAINS_FACTOR:g}x)")
    return ratio
