"""What an output-error fit's numbers do not say by themselves: estimates their search's
bound decided, parameters the log hardly determines, effects the log cannot tell apart
(``fdigen discover``'s output-error loop, :mod:`fdigen.discover.output_loop`)."""

from __future__ import annotations

import numpy as np

#: A calibrated value this many times off its datasheet value warns, when its interval
#: excludes the datasheet value (:func:`far_off`).
FAR_FACTOR = 1.5
#: ... by this many standard deviations.
FAR_SIGMAS = 3.0


def far_off(value: float, datasheet: float, std: float) -> bool:
    """Whether a calibrated ``value`` (same sign as ``datasheet``) is ``FAR_FACTOR`` times
    off its datasheet value and ``FAR_SIGMAS`` standard deviations from it: the log
    contradicts the datasheet. (A tight interval, below 10 %, was asked before: a zone's
    outdoor conductance at 2.6x its datasheet, +-20 %, 3.1 sigma off, was not said.)"""
    if std is None or not (datasheet and value and np.isfinite(std) and value * datasheet > 0):
        return False
    ratio = abs(value / datasheet)
    return max(ratio, 1 / ratio) >= FAR_FACTOR and abs(value - datasheet) > FAR_SIGMAS * std


def on_bound(value: float, bound: float) -> bool:
    """An estimate at its search bound itself: within ``1e-4`` of the bound's scale."""
    return abs(value - bound) <= 1e-4 * max(abs(bound), 1e-12)


def at_bounds(fit, bounds: dict) -> list[dict]:
    """Estimates their search's bound decided: within ``1e-4`` of the scale of the bound,
    or a bound inside one standard deviation of the estimate (the interval reaches it:
    ``0.5999 +- 0.48`` under a bound of 0.6 was the bound's value, not the log's).
    ``on_bound`` tells the first (:func:`on_bound`) from the second."""
    out = []
    for n in fit.free:
        lo, hi = bounds.get(n, (-np.inf, np.inf))
        v = fit.params[n]
        sd = fit.std.get(n) if getattr(fit, "std", None) else None
        reach = max(1e-4 * max(abs(b) for b in (lo, hi, 1e-12) if np.isfinite(b)),
                    float(sd) if sd is not None and np.isfinite(sd) else 0.0)
        for side, b in (("lower", lo), ("upper", hi)):
            if np.isfinite(b) and abs(v - b) <= reach:
                out.append({"parameter": n, "value": v, "side": side, "bound": b,
                            "on_bound": on_bound(v, b)})
    return out


#: a relative standard deviation beyond which a calibrated value is reported as barely
#: determined by the log
POORLY_DETERMINED = 0.5


def poorly_determined(fit, names) -> list[dict]:
    """Parameters of ``names`` whose standard deviation exceeds ``POORLY_DETERMINED`` of
    their value (``sigma / |p| > 0.5``): the log hardly determines them."""
    out = []
    for n in names:
        sd, v = fit.std.get(n), fit.params.get(n)
        if sd is not None and v and np.isfinite(sd) and sd > POORLY_DETERMINED * abs(v):
            out.append({"parameter": n, "value": float(v), "std": float(sd),
                        "relative": float(sd / abs(v))})
    return out


def output_error_ties(candidates: list, chosen: list, tie: float) -> list[dict]:
    """Candidates of a chosen effect's round whose BIC is within ``tie`` of the chosen
    one's (the log cannot tell them apart; both significant), with what each acts on
    (``"sensor"``: an output's reading only, ``"plant"``: a state's equation)."""
    out = []
    for rnd, e in enumerate(chosen, start=1):
        mine = next((c for c in candidates if c["round"] == rnd and c["effect"] == e.name),
                    None)
        if mine is None:
            continue
        for c in candidates:
            if c["round"] == rnd and c["effect"] != e.name \
                    and abs(c["delta_bic"] - mine["delta_bic"]) <= tie:
                out.append({"chosen": e.name, "other": c["effect"], "round": rnd,
                            "delta_bic": c["delta_bic"], "chosen_delta_bic":
                            mine["delta_bic"], "acts_on": mine.get("acts_on"),
                            "other_acts_on": c.get("acts_on")})
    return out


#: A switching effect must act on at least this share of the log's samples (and on 3).
MIN_ACTIVE = 0.01


def switch_refusal(effect, params: dict, model, u, y, noise) -> str | None:
    """Why a clipping or switching effect's fit is not a finding, or None.

    A knot rounded by a softplus acts a little on either side of its level: an overflow
    level above everything the log visits still bleeds a small loss through its rounded
    tail, a "saturation" at a level the sensor reads past still bends the fit. Such a fit
    finds the tail, not the effect (a user's heater got an overflow at 55.4 degC from a
    log that never passed 45.9 degC: a heat loss in disguise). The effect's signal
    (:attr:`LibraryEffect.switch`) must reach its level on at least
    :data:`MIN_ACTIVE` of the samples, and a sensor rail must not be read past by more
    than three noise levels on as many. A hidden state's level cannot be checked: None.
    """
    if effect.switch is None:
        return None
    kind, name, par, side = effect.switch
    level = float(params[par])
    y = np.asarray(y, dtype=float)
    if kind == "output":
        j = model.output_index(name)
        values, eps = y[:, j], 3.0 * float(noise[j])
    elif kind == "input":
        j = [s.name for s in model.inputs].index(name)
        values, eps = np.asarray(u, dtype=float)[:, j], 0.0
    else:
        from fdigen.discover.locate import measured_states, state_values

        outs = measured_states(model).get(model.state_index(name))
        if not outs:
            return None
        values = state_values(model, outs, y)
        eps = 3.0 * max(float(noise[j]) for j in outs)
    values = values[np.isfinite(values)]
    sign = 1.0 if side == "above" else -1.0
    reached = np.count_nonzero(sign * (values - level) >= -eps)
    need = max(3, int(np.ceil(MIN_ACTIVE * values.size)))
    lo, hi = float(values.min()), float(values.max())
    if reached < need:
        return (f"{par} = {level:.4g}: the log's {name} ({lo:.4g} to {hi:.4g}) reaches "
                f"it on {reached} of {values.size} samples, so the fit acts through the "
                "term's rounded tail, not through the effect")
    if kind == "output":
        past = np.count_nonzero(sign * (values - level) > eps)
        if past >= need:
            return (f"{par} = {level:.4g}: sensor {name} reads past it by more than three "
                    f"noise levels on {past} of {values.size} samples: not a rail")
    return None


def effect_at_bound(effect, fit, bounds: dict) -> str | None:
    """An effect parameter its search's bound decided (:func:`at_bounds`), or None."""
    own = set(effect.parameter_names)
    hits = [b for b in at_bounds(fit, bounds) if b["parameter"] in own]
    if not hits:
        return None
    b = hits[0]
    return (f"{b['parameter']} = {b['value']:.4g} ended at its {b['side']} search bound "
            f"{b['bound']:.4g}: the bound, not the log, decided it")


def leading(direction: dict) -> list:
    """The parameters of a blind direction that matter: a direction made of one parameter
    and crumbs of others (``b1^+1 cf^-0.016`` on a user's conveyor, ``b1`` barely excited)
    is that parameter alone, not a scale (entries below a tenth of the largest dropped)."""
    top = max((abs(v) for v in direction.values()), default=0.0)
    return [k for k, v in direction.items() if abs(v) >= 0.1 * top]


def blind_effect(chosen, fit):
    """The chosen effect with a parameter alone in a blind direction of ``fit`` (it moves
    no output there), or ``None``."""
    for d in fit.null_directions:
        alone = leading(d)
        if len(alone) == 1:
            for e in chosen:
                if alone[0] in {p.name for p in e.parameters}:
                    return e
    return None


def identifiability(model, fit, datasheet: dict) -> tuple[dict, list]:
    """What the log cannot determine, and values far from their datasheet (warnings)."""
    warnings = []
    info = {"not_identifiable": [], "correlated": [], "held": dict(fit.held),
            "far_from_datasheet": []}
    for d in fit.null_directions:
        pars = {k: v for k, v in d.items()}
        info["not_identifiable"].append(pars)
        pars = {k: pars[k] for k in leading(pars)}
        if len(pars) == 1:
            # one parameter alone: the outputs do not move with it at its value (a
            # heatsink's overflow coefficient at its bound 0 was called "the scale of
            # the hidden state" by a user)
            (name,) = pars
            warnings.append(
                f"{name} = {fit.params.get(name, float('nan')):.4g} does not move any "
                "output at this value: the log does not determine it, and the effect it "
                "belongs to acts only through its other parameters, or not at all")
            continue
        combo = " ".join(f"{k}^{v:+g}" for k, v in pars.items())
        hidden = [s.name for s in model.states if not is_measured(model, s.name)]
        warnings.append(
            "the log cannot determine " + ", ".join(pars) + f" separately: scaling them as "
            f"{combo} (times a common factor) leaves every output unchanged"
            + (f" (the scale of the hidden state{'s' if len(hidden) > 1 else ''} "
               f"{', '.join(hidden)})" if hidden else "")
            + "; only their invariant combinations are determined"
            + (f" ({', '.join(f'{k} = {v:.4g}' for k, v in fit.held.items())} held at "
               "the datasheet value)" if fit.held else "")
            + ". To determine them: measure " + (", ".join(hidden) if hidden else
                                                 "another state")
            + " or fix one of them from a datasheet")
    J = fit.J
    if J is not None and len(fit.free):
        try:
            # columns scaled to unit norm first: a correlation does not depend on the
            # parameters' units, and the pseudo-inverse of the unscaled J^T J (1e-27
            # next to 1) had given a user "correlations" of -16.5 and -20.1
            norms = np.linalg.norm(J, axis=0)
            Jn = J / np.where(norms > 0, norms, 1.0)
            cov = np.linalg.pinv(Jn.T @ Jn, rcond=1e-12, hermitian=True)
            cov = cov[: len(fit.free), : len(fit.free)]
            sd = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
            corr = cov / np.outer(sd, sd)
            for i in range(len(fit.free)):
                for j in range(i + 1, len(fit.free)):
                    if 0.95 < abs(corr[i, j]) <= 1.0 + 1e-9:
                        a, b = fit.free[i], fit.free[j]
                        c = float(np.clip(corr[i, j], -1.0, 1.0))
                        info["correlated"].append({"parameters": [a, b],
                                                   "correlation": c})
                        warnings.append(
                            f"{a} and {b} are correlated on this log ({c:+.3f}): "
                            "the log fixes mainly one combination of them; an input that "
                            "moves the plant through a wider range of levels (steps of "
                            "different sizes, a slow sweep) would separate them")
        except np.linalg.LinAlgError:  # pragma: no cover
            pass
    for n in fit.free:
        v, s = fit.params[n], fit.std.get(n, np.nan)
        v0 = datasheet.get(n)
        if v0 and v and v0 * v < 0:
            # a damping or a gain of the other sign is another plant, whatever its
            # interval (a user's arm: Bm = -0.115 from a datasheet 0.002)
            info["far_from_datasheet"].append({"parameter": n, "value": v,
                                               "datasheet": v0, "std": s})
            warnings.append(
                f"{n} calibrated to {v:.4g}, the opposite sign of its datasheet value "
                f"{v0:.4g}: not a calibration of the same plant; give it bounds of the "
                "datasheet's sign ([parameters] bounds), or look for the effect it stands "
                "in for")
            continue
        if v0 is not None and far_off(v, v0, s):
            info["far_from_datasheet"].append({"parameter": n, "value": v,
                                               "datasheet": v0, "std": s})
            warnings.append(far_text(n, v, v0, s))
    return info, warnings


def far_text(name: str, value: float, datasheet: float, std: float) -> str:
    """The warning of a value :func:`far_off` its datasheet's."""
    return (f"{name} calibrated to {value:.4g} +- {std:.2g}, {abs(value / datasheet):.3g} "
            f"times its datasheet value {datasheet:.4g} ({abs(value - datasheet) / std:.3g} "
            "sigma): a value the log sets far from the datasheet points at a model error "
            "the parameter absorbs (or a wrong datasheet value)")


def is_measured(model, state: str) -> bool:
    """Whether ``state`` is measured through an invertible sensor map."""
    from fdigen.discover.locate import measured_states

    return model.state_index(state) in measured_states(model)


def worse_after_fit(nominal: dict, after: dict, noise: dict, factor: float = 1.2) -> list:
    """A warning per output whose free-run error the fit made worse than the datasheet
    model's, by more than ``factor`` and by more than its noise: the fit traded that
    output for the others (a user's boiler: the current transducer 0.305 -> 0.496 V after
    the heater power was calibrated 18 % low to stand in for a heat loss the model lacks,
    shown only as two numbers side by side)."""
    out = []
    for k, before in nominal.items():
        a = after.get(k)
        if a is None or not (before > 0 and a > factor * before and a - before > noise[k]):
            continue
        out.append(f"{k}: the fitted model follows it worse than the datasheet model "
                   f"(free-run RMS {before:.4g} -> {a:.4g}, noise {noise[k]:.3g}): the fit "
                   "traded this output for the others; a parameter this output reads may "
                   "stand in for an effect the model lacks (its calibrated value is then "
                   "not the plant's)")
    return out
