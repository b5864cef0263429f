"""Datasheet values the written model keeps, and the fit of the others with them held.

An output-error calibration estimates the uncertain parameters jointly. Some of them the
log does not determine: an interval that reaches zero, a sign opposite to the datasheet's
(:func:`fdigen.discover.augment.undetermined`), or an estimate that ended on its search
bound (the bound, not the log, decided it). The written model keeps their datasheet
values. The other estimates were fitted *with* the undetermined ones at their estimates,
though, and do not fit the log beside the datasheet values: a user's building zone was
reported at 0.452 degF free-run error with its slab capacity at its bound (2e8 J/K) and
its slab-to-outdoor conductance at its bound (5 W/K), and the model written with both at
their datasheet values (2.5e7, 40) and the other values of that fit ran at 6.997 degF,
six times the datasheet model's own error; the thresholds the campaign then designed
were those of that model.

:func:`hold_undetermined` therefore fits the others again with the kept values held, and
the loop reports, writes and commissions that fit: the error said is the written model's.
"""

from __future__ import annotations

import numpy as np

from fdigen.discover.augment import undetermined
from fdigen.discover.fit_checks import at_bounds


def kept_values(model, fit, free, bounds: dict) -> dict:
    """The uncertain parameters of ``fit`` the written model keeps at their datasheet
    value: ``name -> reason`` (undetermined, or decided by their search bound)."""
    calibrated = {k: fit.params[k] for k in free if k not in (fit.held or {})}
    kept = undetermined(model, calibrated, fit.std)
    for b in at_bounds(fit, bounds):
        name = b["parameter"]
        if b["on_bound"] and name in calibrated and name not in kept:
            kept[name] = (f"{name} = {b['value']:.4g} ended at its {b['side']} search bound "
                          f"{b['bound']:.4g}: the bound, not the log, decided it")
    return kept


def hold_undetermined(model, fit, free, bounds: dict, refit, say=lambda m: None):
    """``fit`` with the values :func:`kept_values` names held at the datasheet's and the
    others fitted again.

    Parameters
    ----------
    model : Model
    fit : OutputErrorFit
        The joint calibration (``params``, ``std``, ``held``, ``rms``).
    free : list of str
        The uncertain parameters it estimated.
    bounds : dict
        Their search bounds.
    refit : callable
        ``refit(hold, start) -> fit``: the same fit with ``hold`` (name -> value) held.
    say : callable

    Returns
    -------
    (fit, dict)
        The fit the written model is (``fit`` itself when nothing is kept), and
        ``{name: {"estimate", "datasheet", "reason"}}`` of the kept values.
    """
    kept = kept_values(model, fit, free, bounds)
    if not kept:
        return fit, {}
    sheet = {q.name: float(q.value) for q in model.parameters}
    hold = {**(fit.held or {}), **{k: sheet[k] for k in kept}}
    start = {k: v for k, v in fit.params.items() if k not in hold}
    new = refit(hold, start)
    say("the written model keeps " + ", ".join(f"{k} = {sheet[k]:.4g}" for k in kept)
        + " from the datasheet (" + "; ".join(kept.values()) + "): the others fitted "
        "again with them held, free-run RMS " + _fmt(fit.rms) + " -> " + _fmt(new.rms))
    return new, {k: {"estimate": float(fit.params[k]), "datasheet": sheet[k],
                     "reason": kept[k]} for k in kept}


def _fmt(a) -> str:
    return ", ".join(f"{v:.4g}" for v in np.atleast_1d(a))
