"""Driven sub-models: part of a model's equations, with measured states as inputs."""

from __future__ import annotations

from dataclasses import replace

import sympy as sp

from fdigen.derive.linearisation import numeric
from fdigen.model.model import Fault, Model, Variable
from fdigen.model.sensor_maps import compound_sensor_maps, sensor_maps


def driven_submodel(model: Model, keep: tuple[str, ...], drivers: dict[str, str]) -> Model:
    """The equations of the states ``keep``, other states replaced by measurements.

    Every state outside ``keep`` that appears in the kept equations must be measured
    directly by an output (``drivers[state] = output``); that output becomes an input of the
    sub-model. Outputs that read kept states (and driven ones, replaced by their sensors'
    readings) stay outputs. Faults are carried over:
    plant faults on kept states, actuator faults, sensor faults on kept outputs, and sensor
    faults on a driver become actuator faults on the driver input.

    Parameters
    ----------
    model : Model
    keep : tuple of str
        The state equations kept.
    drivers : dict of str to str
        State name -> output name that measures it directly.

    Returns
    -------
    Model
        A new model named ``<model>_<keep...>``.
    """
    kept = [s for s in model.states if s.name in keep]
    drv_in = []
    subs = {}
    for sname, oname in drivers.items():
        out = model.output(oname)
        state = model.states[model.state_index(sname)]
        drv_in.append(Variable(oname, out.unit, f"measured {sname} ({out.description})",
                               driver_range(model, state, oname), out.column))
        subs[state.symbol] = state_from_sensor(model, sname, oname)
        for rstate, routput in driver_reads(model, sname, oname).items():
            if rstate in keep:   # a compound reading of a kept state: its simulated value
                kept_map = _sensor_map(model, rstate, routput)
                subs[state.symbol] = subs[state.symbol].xreplace(
                    {sp.Symbol(routput, real=True): kept_map.forward})
    f_full = model.f()
    dyn = tuple(f_full[model.state_index(s.name)].xreplace(subs) for s in kept)
    kept_syms = {s.symbol for s in kept}
    input_syms = {s.symbol for s in model.inputs}
    param_syms = set(model.p)
    driver_syms = {v.symbol for v in drv_in}
    outputs = []
    for out in model.outputs:
        if out.name in drivers.values():
            continue
        # a sensor whose map also reads driven states measures the kept ones once those
        # are known (a conductivity probe reading salt mass over volume, M/(A h), with h
        # measured): the driven states are replaced by their sensors' readings
        expr = model.expand(out.expr).xreplace(subs)
        if (expr.free_symbols <= kept_syms | input_syms | param_syms | driver_syms
                and expr.free_symbols & kept_syms):
            outputs.append(replace(out, expr=expr))
    faults = []
    for fault in model.faults:
        if fault.multi or _in_definitions(model, fault):
            carried = _carried_fault(model, fault, kept, dyn, subs, drivers, outputs)
            if carried is not None:
                faults.append(carried)
            continue
        term = model.expand(fault.term).xreplace(subs)
        if fault.location == "plant" and fault.target in keep:
            faults.append(replace(fault, term=term))
        elif fault.location == "actuator":
            faults.append(replace(fault, term=term))
        elif fault.location == "sensor" and fault.target in drivers.values():
            # a faulty driver sensor corrupts the sub-model's input
            faults.append(Fault(fault.name, "actuator", fault.mode, fault.target,
                                term, fault.fault_class,
                                fault.description, fault.test_size))
        elif fault.location == "sensor" and fault.target in {o.name for o in outputs}:
            faults.append(replace(fault, term=term))
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name] for s in (*model.states, *model.inputs)})
    h0 = numeric(model.h(), point).ravel()
    op = {s.name: model.operating_point[s.name] for s in (*kept, *model.inputs)}
    for oname in drivers.values():
        op[oname] = float(h0[model.output_index(oname)])
    return Model(
        name=f"{model.name}_{'_'.join(keep)}",
        states=tuple(kept), inputs=(*model.inputs, *drv_in), outputs=tuple(outputs),
        parameters=model.parameters, definitions=(), dynamics=dyn, faults=tuple(faults),
        operating_point=op, description=f"equations {', '.join(keep)} of {model.name}",
        source=model.source)


def _in_definitions(model: Model, fault: Fault) -> bool:
    return any(fault.symbol in e.free_symbols for _, e in model.definitions)


def _carried_fault(model, fault, kept, dyn, subs, drivers, outputs):
    """A fault entering several equations (or through a definition), in the sub-model.

    Its term on each kept state is the change it makes to that equation with every other
    fault at zero, ``f_k(x, u, phi_j) - f_k(x, u, 0)``; its terms on a driver sensor
    corrupt the driver input, and on a kept output the output. ``None`` when it reaches
    nothing the sub-model keeps.
    """
    others = {f.symbol: 0 for f in model.faults if f.name != fault.name}
    f_with = model.f(with_faults=True)
    terms = []
    for s, nominal in zip(kept, dyn):
        diff = f_with[model.state_index(s.name)].xreplace(others).xreplace(subs) - nominal
        if diff != 0:
            terms.append((s.name, diff))
    kept_outputs = {o.name for o in outputs}
    # on a driver the fault enters with the opposite sign: the sub-model's plant runs on
    # the state the sensor reads, x = g^-1(y - term), while its equations' own terms are
    # the plant's. With both paths (a trailer's mass in a car's speed equation and in its
    # accelerometer's specific force) they cancel exactly as the physics does; with +term
    # on the driver the table claimed a residual the trailer cannot move
    for target, term in fault.terms:
        if model.target_kind(target) != "output":
            continue
        if target in drivers.values():
            terms.append((target, -model.expand(term).xreplace(subs)))
        elif target in kept_outputs:
            terms.append((target, model.expand(term).xreplace(subs)))
    # a fault written in a definition that an output reads (a cell's R0e = R0*(1 +
    # r_incr) in its terminal voltage): its change to that output, as the terms spelling
    # would write it (the sub-model kept the output's expression with faults at zero); on
    # a driver sensor (a thermometer's gain loss in its map) it corrupts the driver input
    written = {t for t, _ in terms}
    h_with, h_without = model.h(with_faults=True), model.h()
    for name in [o.name for o in outputs] + list(drivers.values()):
        if name in written:
            continue
        j = model.output_index(name)
        diff = sp.expand(h_with[j].xreplace(others).xreplace(subs)
                         - h_without[j].xreplace(subs))
        if diff != 0:
            terms.append((name, -diff if name in drivers.values() else diff))
            written.add(name)
    terms = _uncancelled(model, fault, kept, dyn, drivers, terms)
    if not terms:
        return None
    location = fault.location
    if len(terms) == 1:
        kind = "input" if terms[0][0] in drivers.values() else (
            "output" if terms[0][0] in kept_outputs else "state")
        location = {"state": "plant", "input": "actuator", "output": "sensor"}[kind]
    return Fault(fault.name, location, fault.mode, terms[0][0], terms[0][1],
                 fault.fault_class, fault.description, fault.test_size,
                 terms=tuple(terms) if len(terms) > 1 else ())


#: A fault's effect on a kept equation through its own term and through a driver cancels
#: when their sum is below this share of the larger of the two (float coefficients of
#: 17 digits leave a remainder of 1e-10 where the algebra cancels exactly).
CANCELLED = 1e-8


def _uncancelled(model, fault, kept, dyn, drivers, terms):
    """``terms`` without the ones whose effects cancel: a fault entering a kept equation
    and the sensor of a driver that equation reads (a trailer's mass in a car's speed
    equation and in its accelerometer, whose specific force the equation is driven by)
    changes the equation by ``d f/d phi + d f/d y_d * d term_d/d phi``; when that is zero
    at the operating point and at two points across the ranges, the sub-model is blind
    to the fault (the terms are dropped), where the table would claim a residual the
    fault cannot move."""
    import numpy as np

    by_target = dict(terms)
    driver_terms = {t: e for t, e in by_target.items() if t in drivers.values()}
    if not driver_terms:
        return terms
    phi = fault.symbol
    values = dict(model.parameter_values)
    rng = np.random.default_rng(7)
    h = model.h()
    points = []
    for k in range(3):
        pt = {}
        for v in (*model.states, *model.inputs):
            x0 = float(sp.sympify(model.operating_point[v.name]).xreplace(values))
            lo, hi = v.range if v.range else (x0, x0)
            pt[v.symbol] = sp.Float(x0 if k == 0 else rng.uniform(float(lo), float(hi)), 17)
        for o in drivers.values():
            pt[sp.Symbol(o, real=True)] = h[model.output_index(o)].xreplace(pt).xreplace(values)
        points.append(pt)
    cancelled = set()
    for s, f in zip(kept, dyn):
        own = by_target.get(s.name)
        if own is None:
            continue
        paths = [sp.diff(own, phi)]
        for o, term in driver_terms.items():
            paths.append(sp.diff(f, sp.Symbol(o, real=True)) * sp.diff(term, phi))
        at = {phi: 0}
        try:
            vals = [[complex(p.xreplace(at).xreplace(pt).xreplace(values).evalf())
                     for p in paths] for pt in points]
        except (TypeError, ValueError):
            continue
        # against the paths' largest size anywhere (at a point where both nearly vanish,
        # a buck converter's operating point, their rounding is all that is left)
        scale = max(abs(x) for v in vals for x in v)
        if scale > 0 and all(abs(sum(v)) <= CANCELLED * scale for v in vals):
            cancelled.add(s.name)
    if not cancelled:
        return terms
    # the equation's term goes; the driver's too, unless another kept equation reads it
    keep_driver = {o for o in driver_terms
                   if any(sp.Symbol(o, real=True) in f.free_symbols
                          for s, f in zip(kept, dyn) if s.name not in cancelled)}
    return [(t, e) for t, e in terms
            if t not in cancelled and (t not in driver_terms or t in keep_driver)]


def direct_sensors(model: Model) -> dict[str, list[str]]:
    """State name -> every output that measures it directly, in order: an output map of
    that state alone, invertible over its range (``y = x``, ``y = kc*x + off``; see
    :mod:`fdigen.model.sensor_maps`)."""
    return {state: [m.output for m in maps] for state, maps in sensor_maps(model).items()}


def direct_measurements(model: Model) -> dict[str, str]:
    """State name -> first output that measures it directly (see :func:`direct_sensors`)."""
    return {state: outs[0] for state, outs in direct_sensors(model).items()}


def measured_states(model: Model) -> dict[str, str]:
    """State name -> the output that measures it: directly (:func:`direct_measurements`),
    or, for a state no sensor measures alone, through an output that reads it with other
    directly measured states (:func:`~fdigen.model.sensor_maps.compound_sensor_maps`: a
    probe of a mass over a measured volume). A sub-model driven by such a state is driven
    by the other states' sensors as well (:func:`driver_reads`)."""
    out = {state: maps[0].output for state, maps in compound_sensor_maps(model).items()}
    out.update(direct_measurements(model))
    return out


def driver_reads(model: Model, state: str, output: str) -> dict[str, str]:
    """The other ``{state: output}`` the reading of ``state`` by ``output`` needs (empty
    for a direct measurement)."""
    return dict(_sensor_map(model, state, output).reads)


def _sensor_map(model: Model, state: str, output: str):
    maps = [*sensor_maps(model).get(state, []), *compound_sensor_maps(model).get(state, [])]
    return next(m for m in maps if m.output == output)


def state_from_sensor(model: Model, state: str, output: str, value=None) -> sp.Expr:
    """The state measured by ``output``, ``x = g^{-1}(y)``, with ``value`` (an expression,
    default the output's symbol) in place of ``y``: ``y`` itself for ``y = x``. The inverse
    of a compound map (:func:`measured_states`) also reads the other states' sensors."""
    sm = _sensor_map(model, state, output)
    y = sp.Symbol(output, real=True)
    return sm.inverse if value is None else sm.inverse.xreplace({y: value})


def driver_range(model: Model, state: Variable, output: str):
    """The driver input's range: the state's range through the sensor map."""
    if state.range is None:
        return None
    sm = _sensor_map(model, state.name, output)
    values = model.parameter_values
    others = {s.symbol: sp.sympify(model.operating_point[s.name]) for s in model.states
              if s.name in dict(sm.reads)}           # a compound map: the others at the op
    others.update({v.symbol: sp.sympify(model.operating_point[v.name]) for v in model.inputs
                   if v.name in model.operating_point})       # and the inputs it reads
    ends = sorted(float(sm.forward.xreplace(others).xreplace(
        {state.symbol: sp.Float(float(v))}).xreplace(values)) for v in state.range)
    return (ends[0], ends[1])
