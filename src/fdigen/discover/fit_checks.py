"""What an output-error fit's numbers do not say by themselves: estimates their search's
bound decided, parameters the log hardly determines, effects the log cannot tell apart
(``fdigen discover``'s output-error loop, :mod:`fdigen.discover.output_loop`)."""

from __future__ import annotations

import numpy as np


def at_bounds(fit, bounds: dict) -> list[dict]:
    """Estimates their search's bound decided: within ``1e-4`` of the scale of the bound,
    or a bound inside one standard deviation of the estimate (the interval reaches it:
    ``0.5999 +- 0.48`` under a bound of 0.6 was the bound's value, not the log's)."""
    out = []
    for n in fit.free:
        lo, hi = bounds.get(n, (-np.inf, np.inf))
        v = fit.params[n]
        sd = fit.std.get(n) if getattr(fit, "std", None) else None
        reach = max(1e-4 * max(abs(b) for b in (lo, hi, 1e-12) if np.isfinite(b)),
                    float(sd) if sd is not None and np.isfinite(sd) else 0.0)
        for side, b in (("lower", lo), ("upper", hi)):
            if np.isfinite(b) and abs(v - b) <= reach:
                out.append({"parameter": n, "value": v, "side": side, "bound": b})
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
    one's (the log cannot tell them apart; both significant)."""
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
                            mine["delta_bic"]})
    return out
