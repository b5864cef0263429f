"""Sensors on a model's definitions, in the sensor placement advice.

The placement advice (:func:`fdigen.design.structure.sensor_placement`) tries one more
sensor on every unknown of the structure: the states and the inputs as an actuator
delivers them. A quantity the model names in ``[definitions]`` -- an oven's heater power
``P = (1 - element) Pmax sat(u)``, a flow, a force -- is often what a real sensor
measures (a wattmeter, a flow meter, a load cell), and a fault written inside it enters
that sensor's equation directly. A user's oven with a heater-element loss and an open
door (both only in the wall's heat balance, in the same direction) was told "no single
extra sensor separates them"; a wattmeter on ``P`` does: it sees the element and not the
door.

A sensor on definition ``d`` makes ``d`` known where the equations read it, and adds the
definition's own relation ``y = d(x, u)``, which the faults written in ``d`` enter
(:func:`definition_structures`). A definition an output already reads (up to a gain and
an offset) gets no advice: a second sensor on it reads nothing new.
"""

from __future__ import annotations

import sympy as sp

from fdigen.derive.nonsmooth import derivative
from fdigen.errors import FdigenError


def definition_structures(model) -> dict:
    """``{definition: structure of the model with one more sensor measuring it}``.

    Measuring ``d`` makes it known where the equations use it: the structure is that of
    the model with ``d`` an input (the equations that read ``d`` no longer see what it is
    made of, nor the faults written in it) and one more output ``y = d(x, u)`` (the
    definition's own relation, which those faults enter). Definitions of parameters only
    are skipped."""
    import dataclasses

    from fdigen.design.structure import model_structure
    from fdigen.model.model import Output, Variable

    states = {s.symbol for s in model.states}
    inputs = {s.symbol for s in model.inputs}
    taken = {s.name for s in (*model.states, *model.inputs, *model.outputs)}
    out = {}
    # the definitions the model file's parser makes itself, for a fault written in an
    # equation or a sensor's map (d<state>_dt, <output>_map), measure nothing a sensor
    # could: a "sensor on dh_dt" sees every term of the level's balance
    internal = {f"d{s.name}_dt" for s in model.states} | {
        f"{o.name}_map" for o in model.outputs}
    read = list(model.h(with_faults=True))
    faults = {f.symbol for f in model.faults}
    for name, _ in model.definitions:
        if name in internal:
            continue
        expr = model.expand(sp.Symbol(name, real=True), with_faults=True)
        if not expr.free_symbols & (states | inputs):
            continue
        # what a sensor on it reads: the inputs as the actuators deliver them
        delivered = model._with_faults(sp.Matrix([expr]), plant=False)[0]
        if read_by_an_output(delivered, read, states | inputs, faults):
            continue
        meas = f"{name}_meas"
        if meas in taken or f"{name}_relation" in dict(model.definitions):
            continue
        # its relation stays a definition (under another name): faults may be written
        # in definitions, not in an output's expression
        relation = f"{name}_relation"
        own = dict(model.definitions)[name]
        rest = tuple((n, e) for n, e in model.definitions if n != name)
        try:
            value = float(model.expand(sp.Symbol(name, real=True)).xreplace(
                {**model.parameter_values, **{s.symbol: model.operating_point[s.name]
                                              for s in (*model.states, *model.inputs)}}))
        except (TypeError, KeyError, ValueError):
            value = 0.0
        try:
            variant = dataclasses.replace(
                model, definitions=rest + ((relation, own),),
                operating_point={**model.operating_point, name: value},
                inputs=model.inputs + (Variable(name),),
                outputs=model.outputs + (Output(meas, sp.Symbol(relation, real=True)),))
            out[name] = model_structure(variant)
        except FdigenError:       # a variant the model language refuses: no advice on it
            continue
    return out


def read_by_an_output(expr, outputs, variables, faults=frozenset()) -> bool:
    """Whether one of ``outputs`` (expanded, with their faults) is ``a expr + b`` with
    ``a != 0`` free of ``variables`` and ``faults`` and ``b`` free of ``variables`` (a
    sensor's own additive fault): a sensor on ``expr`` (with the faults written in it)
    would read what that output reads. A user's quarter car measures the body's
    acceleration ``acc_s`` in g, ``az = acc_s/g0``, and was told to add a sensor on
    ``acc_s``; a tachometer reading ``v`` does not read the friction force
    ``(bc + fric) v``, whose fault a load cell would see."""
    grads = {v: sp.diff(expr, v) for v in sorted(expr.free_symbols & variables, key=str)}
    pivot = next((v for v, g in grads.items() if g != 0), None)
    if pivot is None:
        return False
    for h in outputs:
        try:
            gain = sp.cancel(sp.diff(h, pivot) / grads[pivot])
            if gain == 0 or gain.free_symbols & (variables | set(faults)) \
                    or gain.has(sp.zoo, sp.oo, sp.nan):
                continue
            if not sp.cancel(h - gain * expr).free_symbols & variables:
                return True
        except (TypeError, ValueError, ZeroDivisionError):
            continue
    return False


def faults_in(model, name: str) -> set:
    """The faults written in definition ``name`` (its expansion depends on them)."""
    expr = model.expand(sp.Symbol(name, real=True), with_faults=True)
    zero = {f.symbol: 0 for f in model.faults}
    return {f.name for f in model.faults
            if sp.simplify(derivative(expr, f.symbol).xreplace(zero)) != 0}
