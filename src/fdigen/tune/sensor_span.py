"""Thresholds the sensor cannot reach: a residual's threshold against its output's span.

A residual that compares one output with a prediction (a parity residual ``R = "y"``, a
Kalman filter measuring ``y``, a derived residual checked on ``y``) cannot cross a
threshold as large as the span ``y`` can cover: a fault that keeps the reading inside that
span never raises it. A user's pH tank got ``RpH = 9.21`` pH (RMS) on a loop that moves
8.1-8.9 pH, and tune printed it without a word (only ``commission`` refused such designs).

The span of ``y = h(x, u)`` is taken over the declared ranges of the states and inputs it
reads (a grid of :data:`GRID` points per variable, at most :data:`MAX_POINTS` points):
sensors in volts or through a nonlinear map (a cell's OCV) included.
"""

from __future__ import annotations

import itertools

import numpy as np

#: Grid points per variable, and the most points evaluated.
GRID = 5
MAX_POINTS = 20000


def output_span(model, output: str) -> float | None:
    """``max - min`` of ``output`` over the declared ranges of the states and inputs it
    reads (parameters at their values); None when one of them has no range."""
    import sympy as sp

    j = model.output_index(output)
    expr = model.h()[j].xreplace(model.parameter_values)
    variables = [v for v in (*model.states, *model.inputs) if v.symbol in expr.free_symbols]
    if any(v.range is None for v in variables):
        return None
    if not variables:
        return 0.0
    per = max(2, min(GRID, int(MAX_POINTS ** (1.0 / len(variables)))))
    axes = [np.linspace(float(v.range[0]), float(v.range[1]), per) for v in variables]
    from fdigen.safe_lambdify import safe_lambdify

    fn = safe_lambdify([v.symbol for v in variables], expr, "numpy")
    with np.errstate(all="ignore"):
        vals = np.asarray([fn(*pt) for pt in itertools.product(*axes)], dtype=float)
    vals = vals[np.isfinite(vals)]
    return float(vals.max() - vals.min()) if vals.size else None


def checked_outputs(design) -> dict:
    """Residual -> the one output it compares with a prediction (declared parity residuals,
    Kalman filters measuring one output, derived residuals)."""
    names = {o.name for o in design.model.outputs}
    out = {r: str(y).strip() for r, y in design.config.parity.items()
           if str(y).strip() in names}
    for kr in design.kalman:
        if len(kr.measurement) == 1 and kr.measurement[0].strip() in names:
            out[kr.residual] = kr.measurement[0].strip()
    for e in design.extra_residuals:
        if e.get("check") in names:
            out[e["residual"]] = e["check"]
    return out


#: A threshold from this fraction of its sensor's span up is said as a limit of the design
#: (from the whole span up, no fault inside the span can cross it).
WIDE_THRESHOLD = 0.25


def thresholds_beyond_span(design, thresholds: dict, fraction: float = 1.0) -> dict:
    """Residual -> ``{"output", "threshold", "span"}`` for every threshold at least
    ``fraction`` of the span its output can cover (:func:`output_span`)."""
    found = {}
    for res, y in checked_outputs(design).items():
        thr = thresholds.get(res)
        span = output_span(design.model, y)
        if thr is not None and span and float(thr) >= fraction * span:
            found[res] = {"output": y, "threshold": float(thr), "span": span}
    return found


def wide_warning(entries: dict) -> str | None:
    """One warning for thresholds from :data:`WIDE_THRESHOLD` of their span up (but under
    it), or None. A user's conveyor encoder got 67 degrees on a 240 degree span, said
    nowhere; its offsets were never isolated."""
    entries = {r: e for r, e in entries.items() if e["threshold"] < e["span"]}
    if not entries:
        return None
    listed = ", ".join(f"{r} = {e['threshold']:.3g} is {100 * e['threshold'] / e['span']:.0f} "
                       f"% of {e['output']}'s span {e['span']:.3g}" for r, e in entries.items())
    return (f"thresholds of a large part of their sensor's span ({listed}): only a fault "
            "that moves the reading by that much crosses them; the parameter spread or the "
            "model's error sets them: calibrate (fdigen commission), add the effects the "
            "model lacks (fdigen discover), or re-align the parallel models ([fdi] "
            "realign_noise_scale)")


def span_warning(entries: dict) -> str | None:
    """One warning for :func:`thresholds_beyond_span`'s result, or None."""
    if not entries:
        return None
    listed = ", ".join(f"{r} = {e['threshold']:.3g} against {e['output']}'s span "
                       f"{e['span']:.3g}" for r, e in entries.items())
    return (f"thresholds at least the span their sensor can cover over the declared ranges "
            f"({listed}): no fault that keeps the reading inside that span can cross them; "
            "the parameter spread (--tolerance) or the model's error sets them: calibrate "
            "(fdigen commission), add the effects the model lacks (fdigen discover), or "
            "re-align the parallel models ([fdi] realign_noise_scale)")
