"""What each residual compares, in which unit, and its level on noise alone.

A threshold is read against the residual's own scale: ``R6 = 3.0e-4`` means little until
one knows R6 is a position in m whose noise-only level is 2e-5 m (a threshold 15 times
the noise), and not a pressure beside 2e4 Pa of sensor noise. For every residual of a
design, :func:`residual_scales` gives

* ``compares``: the measured quantity the residual is the error of (an output, or an
  expression of outputs for a combination);
* ``unit``: that quantity's unit, from the outputs' ``unit`` (an expression of several
  outputs: the units' algebra, :mod:`fdigen.design.unit_algebra`, ``"K*m^3"``; where it
  has none, ``"that of the expression (<symbol>: <unit>, ...)"``; a voter weight or a
  validity flag: ``"1"``);
* ``noise_level`` and ``basis``: the residual's standard deviation with noise only,

  - a Kalman filter: :math:`\\sigma_r = \\sqrt{C_r P C_r^T + R_1}`
    (:func:`fdigen.design.observers.residual_noise_level`);
  - a parallel model or parity residual (re-aligned or free): the sensor noise carried
    through the compared quantity, :math:`\\sigma = \\sqrt{\\sum_i (\\partial m/\\partial
    y_i)^2 \\sigma_i^2}` at the operating point (a lower bound: the model's own error adds
    to it);
  - a static relation: the noise of every sensor it reads, carried the same way through
    ``y_c - h_c(g_D^{-1}(y_D), u)`` at the operating point;
  - a voter weight or a validity flag: none (0 on noise alone).
"""

from __future__ import annotations

import math

import sympy as sp

from fdigen.design.innovation_filter import filtered_kalman, innovation_alpha, noise_factor
from fdigen.design.observers import residual_noise_level
from fdigen.design.static_relations import predicted_output
from fdigen.model.expression import expression_text, parse_expression


def _compared(model, text: str) -> sp.Expr:
    # a derived residual's check reads the inputs too (a lateral accelerometer's balance
    # holds the steering angle: "symbol 'dsw': undefined symbol")
    symbols = {u.name: u.symbol for u in model.inputs}
    symbols.update({o.name: o.symbol for o in model.outputs})
    symbols.update({p.name: p.symbol for p in model.parameters})
    return parse_expression(text, symbols, source=model.source, field="fdi")


def _unit(model, expr: sp.Expr) -> str:
    outs = {o.symbol: o for o in model.outputs}
    if expr in outs:
        return outs[expr].unit or "(no unit given)"
    used = [outs[s] for s in expr.free_symbols if s in outs]
    units = {o.unit for o in used}
    # (a balance of ratios, yb/ya, is no polynomial of the outputs: attack round 5)
    if len(units) == 1 and expr.is_polynomial(*[o.symbol for o in used]) \
            and sp.Poly(expr, *[o.symbol for o in used]).is_linear \
            and not (expr.free_symbols - {o.symbol for o in used}):
        return next(iter(units)) or "(no unit given)"   # a combination with pure numbers
    units = {u.symbol: u.unit for u in model.inputs}
    units.update({o.symbol: o.unit for o in model.outputs})
    units.update({q.symbol: q.unit for q in model.parameters})
    from fdigen.design.unit_algebra import expression_unit

    found = expression_unit(expr, units)   # the units' algebra (K*m^3), when it has one
    if found is not None:
        return found
    parts = ", ".join(f"{sym}: {units.get(sym) or '?'}"
                      for sym in sorted(expr.free_symbols, key=str))
    return f"that of the expression ({parts})"


def _sensor_noise(model, expr: sp.Expr) -> float:
    """``sqrt(sum (dm/dy_i sigma_i)^2)`` at the operating point's outputs."""
    point = dict(model.parameter_values)
    values = {s.symbol: model.operating_point[s.name] for s in (*model.states, *model.inputs)}
    for o in model.outputs:
        point[o.symbol] = float(model.expand(o.expr).subs(values).subs(point))
    total = 0.0
    for o in model.outputs:
        if o.symbol in expr.free_symbols:
            slope = float(sp.diff(expr, o.symbol).subs(values).subs(point))
            total += (slope * o.noise_std) ** 2
    return math.sqrt(total)


def residual_scales(design) -> dict:
    """``{residual: {"compares", "unit", "noise_level", "basis"}}`` for every residual of
    ``design`` (see the module docstring)."""
    model, cfg = design.model, design.config
    kalman = {k.residual: k for k in design.kalman}
    compares = dict(cfg.parity)
    compares.update({k.residual: k.measurement for k in cfg.kalman})
    compares.update({e["residual"]: e["check"] for e in design.extra_residuals})
    voter = set(cfg.voter.names) if cfg.voter else set()
    static = {e["residual"]: e for e in design.extra_residuals
              if e.get("realisation") == "static relation"}
    out = {}
    for name in design.residual_names:
        if name in voter:
            out[name] = {"compares": "voter weight", "unit": "1", "noise_level": None,
                         "basis": "0 while the channel has its equal share"}
            continue
        if name not in compares:       # nf_<y>: a measurement validity flag
            out[name] = {"compares": "validity of " + name[3:], "unit": "1",
                         "noise_level": None, "basis": "0 or 1 (NaN or out of range)"}
            continue
        expr = _compared(model, compares[name])
        entry = {"compares": expression_text(expr), "unit": _unit(model, expr)}
        if name in kalman and filtered_kalman(cfg, name):
            alpha = innovation_alpha(cfg.innovation_filter, cfg.sample_time)
            entry.update(noise_level=residual_noise_level(kalman[name]) * noise_factor(alpha),
                         basis="Kalman filter, low-passed innovation: "
                               "sqrt(C P C^T + R) sqrt((1 - a)/(1 + a))")
        elif name in kalman:
            entry.update(noise_level=residual_noise_level(kalman[name]),
                         basis="Kalman filter: sqrt(C P C^T + R)")
        elif name in static:
            relation = expr - predicted_output(model, static[name]["check"],
                                               static[name]["drivers"])
            entry.update(noise_level=_sensor_noise(model, relation),
                         basis="static relation: the noise of every sensor it reads")
        else:
            entry.update(noise_level=_sensor_noise(model, expr),
                         basis="sensor noise through the compared quantity (lower bound)")
        out[name] = entry
    return out


#: a threshold this many times its residual's level on noise alone is set by something
#: else than the noise (white noise over an RMS window of N samples needs ~1.2-2x)
SPREAD_DOMINATED_RATIO = 5.0


def spread_dominated_thresholds(scales: dict, thresholds: dict,
                                limit: float = SPREAD_DOMINATED_RATIO, parity=(),
                                realign_noise_scale: float | None = None) -> tuple:
    """A warning for the residuals whose threshold is ``limit`` or more times their level
    on noise alone, or nothing.

    .. math:: J_r / \\sigma_r \\ge \\text{limit}

    Such a threshold is set by the parameter spread (or the start-up) the design must
    accept, not by the sensor: a fault whose effect on the residual stays below it is not
    detected, however far above the noise it is. For the parity residuals among them
    (``parity``), the realignment's strength is the other lever (a user's cone tank: R1 at
    105x its noise with ``realign_noise_scale = 0.05``, 3.4x with 1).
    """
    high = [(n, thresholds[n] / sc["noise_level"]) for n, sc in scales.items()
            if sc.get("noise_level") and thresholds.get(n)
            and thresholds[n] / sc["noise_level"] >= limit]
    if not high:
        return ()
    listed = ", ".join(f"{n} {r:.3g}x" for n, r in high)
    par = [n for n, _ in high if n in set(parity)]
    lever = (f"; for the parity residuals {', '.join(par)}, a stronger realignment of their "
             f"parallel models ([fdi] realign_noise_scale, now {realign_noise_scale:g}) "
             "follows the plant closer and lowers them, at the price of absorbing slow "
             "faults (fdigen tune measures both)"
             if par and realign_noise_scale is not None else "")
    return (f"thresholds of {limit:g} or more times their residual's level on noise alone "
            f"({listed}): set by the parameter spread the design accepts, not by the "
            "sensors; a fault whose effect stays below them is not detected however far "
            "above the noise; calibrating the uncertain parameters (fdigen commission) "
            "narrows the spread and the thresholds" + lever,)
