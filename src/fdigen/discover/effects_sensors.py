"""Sensor offsets: of an output that alone measures a state, and of a measured input.

==================  =========================  ============================================
effect              role                       term(s)
==================  =========================  ============================================
sensor_offset_<y>   output that alone          ``y += off_<y>``
                    measures a state
input_offset_<u>    measured input u (``kind   ``x_i += f_i(x, u + off_<u>) - f_i(x, u)``
                    = "measured"``: a current, and ``y_j += h_j(x, u + off_<u>) - h_j(x,
                    a flow, a temperature      u)`` wherever u acts, definitions included;
                    read by a sensor)          ``b_i off_<u>`` where f_i is affine in u
==================  =========================  ============================================

A measured input is read by a sensor, and the model integrates what it reads: a battery's
current sensor 0.4 A off moves the charge by 1440 C an hour, which no constant term of the
equations it feeds can stand in for (its effect is the gain of ``u`` in each, times the
offset). The offset's bounds are a quarter of the input's declared range either way.
"""

from __future__ import annotations

import sympy as sp

from fdigen.discover.effects import EffectParameter, LibraryEffect, register_family
from fdigen.model.expression import MAX_LENGTH, expression_text
from fdigen.model.model import Model


def _sensor_offsets(model: Model) -> list[LibraryEffect]:
    """One ``sensor_offset_<y>`` per output that is the only measurement of a state
    (through an invertible map: its span is the state's range through the map).

    Offsets of redundant sensors (two outputs measuring the same state) show as the
    difference of the two sensors, which the FDI's voter watches; from the equations they
    are not identifiable, so they are not in the library.
    """
    from fdigen.model.sensor_maps import sensor_maps

    out = []
    for sname, maps in sensor_maps(model).items():   # y = x, y = kc*x (volts), ...
        if len(maps) != 1:
            continue
        o = model.output(maps[0].output)
        state = model.states[model.state_index(sname)]
        lo, hi = state.range or (-1.0, 1.0)
        span = float(hi - lo) * abs(float(maps[0].gain))    # the range through the map
        out.append(LibraryEffect(
            f"sensor_offset_{o.name}", f"constant offset of sensor {o.name}",
            (EffectParameter(f"off_{o.name}", o.unit, (-span, span), 0.05 * span,
                             f"offset of sensor {o.name}"),),
            outputs={o.name: f"off_{o.name}"}, family="sensor_offset"))
    return out


def _input_offsets(model: Model) -> list[LibraryEffect]:
    """One ``input_offset_<u>`` per measured input (``kind = "measured"``) with a declared
    range that some state equation or output reads: the terms are what reading
    ``u + off`` instead of ``u`` changes in each (see the module docstring)."""
    zero = {f.symbol: 0 for f in model.faults}
    rhs = [e.xreplace(zero) for e in model.f()]
    outs = [e.xreplace(zero) for e in model.h()]
    out = []
    for u in model.inputs:
        if u.is_actuator or u.range is None:
            continue
        name = f"off_{u.name}"
        off = sp.Symbol(name, real=True)
        states = _shift_terms(model.states, rhs, u.symbol, off)
        outputs = _shift_terms(model.outputs, outs, u.symbol, off)
        if not states and not outputs or any(
                len(t) > MAX_LENGTH for t in [*states.values(), *outputs.values()]):
            continue      # (a term a model file cannot hold is no candidate)
        span = float(u.range[1] - u.range[0])
        out.append(LibraryEffect(
            f"input_offset_{u.name}", f"constant offset of the sensor of input {u.name}",
            (EffectParameter(name, u.unit, (-0.25 * span, 0.25 * span), 0.01 * span,
                             f"offset of the measured input {u.name}: the plant sees "
                             f"{u.name} + {name}"),),
            states=states, outputs=outputs, family="input_offset"))
    return out


def _shift_terms(items, exprs, u, off) -> dict[str, str]:
    """``name -> text of e(u + off) - e(u)`` for each expression that reads ``u``
    (``(de/du) off`` where ``e`` is affine in ``u``)."""
    terms = {}
    for item, e in zip(items, exprs):
        if not e.has(u):
            continue
        gain = sp.diff(e, u)
        if gain.has(u):
            shifted = e.xreplace({u: u + off}) - e
            term = shifted
            if _small_expansion(shifted):
                # the terms without u cancel; exponentials stay whole (exp(u/12 + 1)
                # split into E*exp(u/12) read back as a model's own E)
                expanded = sp.expand(shifted, power_exp=False, power_base=False,
                                     log=False)
                if sp.count_ops(expanded) <= sp.count_ops(shifted):
                    term = expanded
        else:
            term = gain * off
        terms[item.name] = expression_text(term)
    return terms


#: Largest expression (sympy operations) and integer power :func:`_shift_terms` expands:
#: ``((u + h)**7 + 1)**7`` has 6435 terms and its expansion 32 million (an attack ran
#: discover out of memory).
MAX_EXPANDED_OPS = 400
MAX_EXPANDED_POWER = 4


def _small_expansion(expr) -> bool:
    """Whether expanding ``expr`` stays small: few operations and no integer power above
    ``MAX_EXPANDED_POWER`` of a sum."""
    if sp.count_ops(expr) > MAX_EXPANDED_OPS:
        return False
    return not any(p.exp.is_Integer and abs(int(p.exp)) > MAX_EXPANDED_POWER
                   and p.base.is_Add for p in expr.atoms(sp.Pow))


register_family("sensor_offset", _sensor_offsets)
register_family("input_offset", _input_offsets)
