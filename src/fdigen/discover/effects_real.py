"""Effects real plants have, offered by the role a state or signal plays in the equations.

Used by the output-error loop (:mod:`fdigen.discover.output_loop`), which simulates the
model and so can fit effects that clip or switch. Each is a smooth additive term (model-file
text), the kink rounded by ``softplus(z) = (z + sqrt(z**2 + eps**2))/2`` with ``eps`` 1 %
of the variable's span, so the augmented model stays differentiable for IPOPT and for
the FDI design:

=========================  ==================================  ===============================
effect                     role (from the equations / the log)  term
=========================  ==================================  ===============================
``sensor_saturation_<y>``  an output whose log sits at its      ``y += -softplus(h - ysat)``
                           maximum for several samples (the     (upper; ``+softplus(ylow - h)``
                           sensor's rail)                       for a lower rail)
``overflow_<x>``           a storage state: non-negative range, ``x += -k*softplus(x - xof)``,
                           its own equation decreasing in it    ``x_d += c*k*softplus(x - xof)``
                           (an outflow), with a downstream      for the downstream state
                           state ``x_d`` it feeds (df_d/dx > 0) ``x_d`` (the spill that falls
                                                                into it), ``k = 1/Ts``
``actuator_saturation_<u>`` an input entering equations          ``x += -b*softplus(u - umax)``
                           affinely (gain ``b``)                for every such equation
=========================  ==================================  ===============================

Roles come from the equations and the declared ranges, never from unit spellings: the
same tank written in cm, m or volts gets the same effects.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.discover.effects import EffectParameter, LibraryEffect
from fdigen.model.model import Model


def _softplus(z: str, eps: float) -> str:
    return f"0.5*(({z}) + sqrt(({z})**2 + {eps * eps!r}))"


def _span(var, data: np.ndarray | None = None) -> tuple[float, float]:
    if var is not None and getattr(var, "range", None):
        lo, hi = (float(v) for v in var.range)
        if hi > lo:
            return lo, hi
    if data is not None and data.size:
        lo, hi = float(np.nanmin(data)), float(np.nanmax(data))
        return lo, hi if hi > lo else lo + 1.0
    return 0.0, 1.0


def _longest_run(col: np.ndarray, value: float) -> int:
    """The longest run of consecutive samples of ``col`` equal to ``value``."""
    hit = np.concatenate(([0], (col == value).astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(hit))
    return int((edges[1::2] - edges[::2]).max()) if edges.size else 0


def rails(column: np.ndarray, min_run: int = 3, pile: float = 3.0) -> dict:
    """Rails a sensor sits on: ``{"high": value}`` / ``{"low": value}`` when the column
    sits on its extreme value for at least ``min_run`` consecutive samples, and for at
    least ``pile`` times as long as it ever sits on the next value inward. A quantised
    sensor (an encoder in rpm, a thermocouple read to 0.1 degC) dwells on its extreme
    reading no longer than on its neighbours: a user's motor held at 3000 rpm by its PI
    loop (longest runs 5 samples on the top count, 9 on the one below) was given a
    "saturation" at its setpoint; the cascaded tanks' level sits on its 10 V rail for 27
    samples, never twice on the value below."""
    out = {}
    col = np.asarray(column, float)
    col = col[np.isfinite(col)]
    values = np.unique(col)
    if values.size < 2:
        return out
    for side, at, inward in (("high", -1, -2), ("low", 0, 1)):
        run = _longest_run(col, values[at])
        if run >= min_run and run >= pile * _longest_run(col, values[inward]):
            out[side] = float(values[at])
    return out


def sensor_saturation(model: Model, y: np.ndarray) -> list[LibraryEffect]:
    """One ``sensor_saturation_<y>`` per output whose log sits on a rail."""
    out = []
    for j, o in enumerate(model.outputs):
        col = np.asarray(y, float)[:, j]
        found = rails(col)
        lo, hi = _span(None, col)
        span = hi - lo
        h = str(o.expr)
        for side, v in found.items():
            name = f"sensor_saturation_{o.name}" + ("" if side == "high" else "_low")
            par = f"ysat_{o.name}" if side == "high" else f"ylow_{o.name}"
            term = (f"-{_softplus(f'{h} - {par}', 0.01 * span)}" if side == "high"
                    else _softplus(f"{par} - ({h})", 0.01 * span))
            out.append(LibraryEffect(
                name, f"sensor {o.name} saturates at its {side} rail ({v:g} in the log)",
                (EffectParameter(par, o.unit, (v - 0.05 * span, v + 0.05 * span), v,
                                 f"{side} saturation of sensor {o.name}"),),
                outputs={o.name: term}, family="sensor_saturation",
                switch=("output", o.name, par, "above" if side == "high" else "below")))
    return out


def storages(model: Model) -> list[tuple[str, str | None]]:
    """Storage states and the state each feeds: ``(x, downstream or None)``.

    A storage has a non-negative range and its own equation decreases in it (an outflow
    at mid-range); the downstream state is one whose equation increases in it."""
    f = model.f()
    mid = {}
    for s in model.states:
        lo, hi = _span(s)
        mid[s.symbol] = lo + 0.5 * (hi - lo)
    for s in model.inputs:
        lo, hi = _span(s)
        mid[s.symbol] = lo + 0.5 * (hi - lo)
    mid.update(model.parameter_values)
    out = []
    for i, s in enumerate(model.states):
        if not s.range or float(s.range[0]) < 0:
            continue
        try:
            own = float(sp.diff(f[i], s.symbol).xreplace(mid))
        except (TypeError, ValueError):
            continue
        if not own < 0:
            continue
        down = None
        for j, t in enumerate(model.states):
            if j == i:
                continue
            try:
                if float(sp.diff(f[j], s.symbol).xreplace(mid)) > 0:
                    down = t.name
                    break
            except (TypeError, ValueError):
                continue
        out.append((s.name, down))
    return out


def overflow(model: Model, dt: float) -> list[LibraryEffect]:
    """One ``overflow_<x>`` per storage state (the spill, a share of it into the next)."""
    out = []
    for x, down in storages(model):
        var = model.states[model.state_index(x)]
        lo, hi = _span(var)
        span = hi - lo
        k = float(f"{1.0 / dt:.6g}")
        spill = f"{k!r}*{_softplus(f'{x} - xof_{x}', 0.01 * span)}"
        params = [EffectParameter(f"xof_{x}", var.unit, (lo + 0.1 * span, hi + 4 * span), hi,
                                  f"overflow level of {x}")]
        states = {x: f"-{spill}"}
        if down is not None:
            params.append(EffectParameter(f"cof_{x}", "1", (0.0, 1.0), 0.5,
                                          f"share of the spill of {x} that reaches {down}"))
            states[down] = f"cof_{x}*{spill}"
        out.append(LibraryEffect(
            f"overflow_{x}", f"{x} overflows above xof_{x}"
            + (f"; a share cof_{x} of the spill falls into {down}" if down else ""),
            tuple(params), states=states, family="overflow",
            switch=("state", x, f"xof_{x}", "above")))
    return out


def actuator_saturation(model: Model, u: np.ndarray) -> list[LibraryEffect]:
    """One ``actuator_saturation_<u>`` per actuator input (``kind`` not ``"measured"``)
    entering the equations affinely."""
    f = model.f()
    out = []
    for j, inp in enumerate(model.inputs):
        if not inp.is_actuator:        # a measured disturbance does not saturate
            continue
        gains = {}
        for i, s in enumerate(model.states):
            b = sp.diff(f[i], inp.symbol)
            if b != 0 and not b.has(inp.symbol):
                gains[s.name] = b
        if not gains:
            continue
        col = np.asarray(u, float)[:, j]
        lo, hi = _span(None, col)
        span = hi - lo
        par = f"umax_{inp.name}"
        z = _softplus(f"{inp.name} - {par}", 0.01 * span)
        out.append(LibraryEffect(
            f"actuator_saturation_{inp.name}",
            f"input {inp.name} saturates: the plant sees min({inp.name}, {par})",
            (EffectParameter(par, inp.unit, (lo + 0.5 * span, hi), hi,
                             f"saturation of input {inp.name}"),),
            states={x: f"-({b})*{z}" for x, b in gains.items()},
            family="actuator_saturation", switch=("input", inp.name, par, "above")))
    return out


def real_plant_effects(model: Model, t, u, y) -> list[LibraryEffect]:
    """Every effect of this module applicable to ``model`` and its log."""
    dt = float(np.median(np.diff(np.asarray(t, float))))
    effs = sensor_saturation(model, y) + overflow(model, dt) + actuator_saturation(model, u)
    return [e for e in effs if e.applicable(model)]
