"""Sensor noise read from a log: second differences, robustly, and the quantisation
floor of a sensor whose values lie on a grid (an encoder's counts, an ADC's steps)."""

from __future__ import annotations

import numpy as np


def noise_level(y: np.ndarray) -> np.ndarray:
    """Sensor noise per output column: from second differences, robustly
    (``1.4826 MAD(d2 y)/sqrt 6``), samples where the column sits on its largest or smallest
    value (a saturated sensor's rail) left out; at least the quantisation noise ``q/sqrt 12``
    of a column whose values lie on a grid of step ``q`` (an encoder, an ADC)."""
    out = []
    for col in np.atleast_2d(np.asarray(y, float).T):
        col = col[np.isfinite(col)]
        if col.size < 4:
            out.append(1e-12)
            continue
        d2 = np.diff(col, 2)
        rail = (held_at(col, col.max()) | held_at(col, col.min()))[1:-1]
        d2 = d2[~rail] if (~rail).sum() > 10 else d2
        est = np.median(np.abs(d2 - np.median(d2))) * 1.4826 / np.sqrt(6.0)
        q = quantisation_step(col)
        if q > 0 and est < q:
            # noise of the order of the step: d2 takes a few values (0, +-q, ...) and
            # their MAD is q or 0, not a spread; the RMS of d2 (its largest 1 % left
            # out: kinks of the signal) is
            small = np.abs(d2) <= np.quantile(np.abs(d2), 0.99)
            est = float(np.sqrt(np.mean(d2[small] ** 2)) / np.sqrt(6.0))
        out.append(max(est, q / np.sqrt(12.0), 1e-12))
    return np.array(out)


def held_at(col: np.ndarray, value: float) -> np.ndarray:
    """Samples that equal ``value`` next to a neighbour that equals it too: a sensor
    resting on it (a rail), not a signal passing through."""
    at = col == value
    return at & (np.r_[False, at[:-1]] | np.r_[at[1:], False])


def quantisation_step(col: np.ndarray) -> float:
    """The step ``q`` of the grid a sensor's values lie on (an encoder's count, an ADC's
    least significant bit), 0 when they do not: the smallest gap between distinct values,
    kept when at most half the samples are distinct and 95 % of them lie within 5 % of
    ``q`` of a grid point."""
    col = np.asarray(col, float)
    values = np.unique(col)
    if values.size < 3 or values.size > col.size / 2:
        return 0.0
    q = float(np.min(np.diff(values)))
    scale = max(abs(float(values[0])), abs(float(values[-1])), 1e-300)
    if q <= 1e-9 * scale:
        return 0.0
    r = (col - values[0]) / q
    return q if float(np.quantile(np.abs(r - np.round(r)), 0.95)) < 0.05 else 0.0


#: A column resting on its extreme value in at least this share of the samples is a rail.
RAIL_SHARE = 0.02


def rails(y: np.ndarray) -> list[tuple[int, float, float, str]]:
    """Columns that rest on their largest or smallest value (a saturated sensor, an ADC at
    full scale) in at least :data:`RAIL_SHARE` of the samples, in runs of repeated
    values: ``(column, value, share, "largest" | "smallest")`` each."""
    out = []
    for j, col in enumerate(np.atleast_2d(np.asarray(y, float).T)):
        col = col[np.isfinite(col)]
        if col.size < 10:
            continue
        for value, side in ((col.max(), "largest"), (col.min(), "smallest")):
            share = float(held_at(col, value).mean())
            if share >= RAIL_SHARE:
                out.append((j, float(value), share, side))
    return out


def rail_warnings(model, y) -> list[str]:
    """A warning per output resting on a rail (:func:`fdigen.discover.noise.rails`): the
    equation test reads the clipped signal as the plant's (a user's tachometer at 5 V on
    44 % of the samples got a sensor offset)."""
    return [f"{model.outputs[j].column} sits at {value:.6g} {model.outputs[j].unit or ''}"
            f" (its {side} value) on {100 * share:.3g} % of the samples: a saturated "
            "sensor; the equation test reads the clipped signal as the plant's "
            "(`fdigen discover --method output-error` fits a sensor saturation)"
            for j, value, share, side in rails(y)]


def noise_of(model, y, u=None) -> np.ndarray:
    """Sensor noise per output: the log's (second differences), the model's
    ``noise_std`` if the log gives none. With the commands ``u``, an output that reads no
    state (``y = g(u, p)``, a heater's power meter) is read as ``y - g(u, p)`` at the
    datasheet values too, and the smaller kept: its signal follows every step of the
    command, which the second differences took for noise (29.7 W for a meter of 10 W)."""
    est = noise_level(y)
    if u is not None:
        est = np.minimum(est, _static_output_noise(model, y, u, est))
    decl = np.array([o.noise_std for o in model.outputs], float)
    return np.where(est > 1e-12, est, decl)


def _static_output_noise(model, y, u, est) -> np.ndarray:
    """:func:`noise_of`'s estimate from ``y - g(u, p)`` per static output (``est``
    elsewhere)."""
    import sympy as sp

    from fdigen.safe_lambdify import safe_lambdify

    out = np.array(est, dtype=float)
    states = {s.symbol for s in model.states}
    args = [s.symbol for s in model.inputs]
    u = np.asarray(u, dtype=float).reshape(len(y), -1)
    for j, expr in enumerate(model.h()):
        if expr.free_symbols & states or not expr.free_symbols & set(args):
            continue
        g = sp.sympify(expr).xreplace(model.parameter_values)
        try:
            with np.errstate(all="ignore"):
                values = np.broadcast_to(np.asarray(safe_lambdify(args, g)(
                    *[u[:, k] for k in range(u.shape[1])]), dtype=float), (len(y),))
        except (TypeError, ValueError, ZeroDivisionError, NameError):
            continue
        if np.all(np.isfinite(values)):
            out[j] = float(noise_level(np.asarray(y, float)[:, j] - values)[0])
    return out
