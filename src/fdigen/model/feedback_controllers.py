"""The feedback controllers of ``[simulation]``: a PI(D) loop and an on/off thermostat.

Parsed here from their tables (the expression controller, stateless, and the table's own
checks are in :mod:`fdigen.model.simulation_spec`); simulated by
:func:`fdigen.sim.controllers.control_step`.
"""

from __future__ import annotations

import sympy as sp

from fdigen.model.expression import parse_expression
from fdigen.model.simulation_spec import (Controller, _err, _input, _number, _reference,
                                          _text, _with_parameters)


def _pi_controller(name, spec, inputs, out_syms, time_syms, parameters, operating_point,
                   source, fld):
    inp = _input(spec, inputs, source, fld)
    for key in ("measurement", "kp", "ki"):
        if key not in spec:
            raise _err(f"missing '{key}'", source, f"{fld}.{key}")
    text = _text(spec["measurement"], source, fld + ".measurement", "the measurement")
    meas = _with_parameters(text, out_syms, parameters, source, fld + ".measurement")
    kp = _number(spec["kp"], source, fld + ".kp")
    ki = _number(spec["ki"], source, fld + ".ki")
    limits = None
    if "limits" in spec:
        lim = spec["limits"]
        if not isinstance(lim, list) or len(lim) != 2:
            raise _err("expected [low, high]", source, fld + ".limits")
        limits = tuple(_number(v, source, fld + ".limits") for v in lim)
        if not limits[0] < limits[1]:
            raise _err("low must be below high", source, fld + ".limits")
    if "offset" in spec:
        value = spec["offset"]
        if isinstance(value, str):
            expr = parse_expression(value, {q: sp.Symbol(q, real=True) for q in parameters},
                                    source=source, field=fld + ".offset")
            value = expr.xreplace({sp.Symbol(q, real=True): sp.Float(v, 17)
                                   for q, v in parameters.items()})
            if not value.is_number:
                raise _err("offset is not a number", source, fld + ".offset")
            value = float(value)
        offset = _number(value, source, fld + ".offset")
    else:
        offset = float(operating_point.get(inp, 0.0))
    reference = _reference(spec, time_syms, source, fld, required=True)
    column = _text(spec.get("reference_column", f"{name}_ref"), source,
                   fld + ".reference_column", "the reference column")
    kd = _number(spec.get("kd", 0.0), source, fld + ".kd")
    td = _number(spec.get("td", 0.0), source, fld + ".td")
    if td < 0:
        raise _err("must be >= 0 (seconds; 0: one sample)", source, fld + ".td")
    return Controller(name, "pi", inp, reference, column, measurement=meas, kp=kp, ki=ki,
                      limits=limits, offset=offset, kd=kd, td=td)


def _onoff_controller(name, spec, inputs, out_syms, time_syms, parameters, operating_point,
                      source, fld):
    """An on/off controller with hysteresis (a thermostat switching a heating element): a
    user's hot-water tank, whose rig switches its element at +-2 K around 55 degC, could
    only be given a PI loop, and the campaign's thresholds came out 5-160x below the real
    log's levels."""
    inp = _input(spec, inputs, source, fld)
    for key in ("measurement", "levels"):
        if key not in spec:
            raise _err(f"missing '{key}'", source, f"{fld}.{key}")
    text = _text(spec["measurement"], source, fld + ".measurement", "the measurement")
    meas = _with_parameters(text, out_syms, parameters, source, fld + ".measurement")
    lev = spec["levels"]
    if not isinstance(lev, list) or len(lev) != 2:
        raise _err("expected [off, on]: the command when off and when on", source,
                   fld + ".levels")
    levels = tuple(_number(v, source, fld + ".levels") for v in lev)
    if levels[0] == levels[1]:
        raise _err("off and on must differ", source, fld + ".levels")
    hyst = _number(spec.get("hysteresis", 0.0), source, fld + ".hysteresis")
    if hyst < 0:
        raise _err("must be >= 0 (the band's width around the reference)", source,
                   fld + ".hysteresis")
    reference = _reference(spec, time_syms, source, fld, required=True)
    column = _text(spec.get("reference_column", f"{name}_ref"), source,
                   fld + ".reference_column", "the reference column")
    return Controller(name, "onoff", inp, reference, column, measurement=meas,
                      levels=levels, hysteresis=hyst)


#: Parser of each feedback controller type.
FEEDBACK = {"pi": _pi_controller, "onoff": _onoff_controller}
