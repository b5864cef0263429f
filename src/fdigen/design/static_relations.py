"""Static relations between sensors: residuals with no dynamics to drift.

An output whose map reads only states that *other* sensors measure directly (and inputs
and parameters) is predicted by those sensors at every sample, with no model state:

.. math:: r_k = y_{c,k} - h_c\\bigl(g_D^{-1}(y_{D,k}),\\, u_k\\bigr)

with ``y_c`` the checked output, ``h_c`` its map, ``y_D`` the sensors of the states it
reads and ``g_D^{-1}`` their inverse maps (:mod:`fdigen.model.sensor_maps`). A pump's
outlet pressure ``rho g (1 - wear) (H0 (n/100)^2 - Kc Q |Q|)`` beside a flow meter, a
second sensor of a state, a force sensor beside two chamber pressures: analytical (or
hardware) redundancy in its simplest form. Nothing in it integrates, so nothing drifts
with the parameter spread of the dynamics and nothing re-aligns onto a fault: its level on
a healthy plant is the sensors' noise and the spread of the static map alone, where a
parallel model of the whole plant drifts by its open-loop error (a user's pump tank:
parity thresholds 25-46 times the noise) and a Kalman filter absorbs a slow sensor fault.

Its signature: fault ``phi_j`` moves ``r`` when

.. math:: \\frac{\\partial}{\\partial \\phi_j}\\Bigl[H_c(x, u, \\phi)
          - h_c\\bigl(g_D^{-1}(H_D(x, u, \\phi)), u\\bigr)\\Bigr]_{\\phi = 0} \\neq 0

(``H`` the outputs with the fault terms) at random points of the declared ranges: the
checked sensor's faults, the drivers' sensor faults, and actuator or plant faults that
enter the checked map itself (the pump's wear); never a fault of the dynamics alone.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import sympy as sp

from fdigen.model.model import Model
from fdigen.model.sensor_maps import output_preference

#: Static relations a design adds at most (each is one subtraction per sample).
MAX_STATIC_RELATIONS = 8

#: Choices of driver sensors tried per checked output.
MAX_DRIVER_CHOICES = 4

_REL_TOL = 1e-9


@dataclass(frozen=True)
class StaticRelation:
    """The residual ``measured - predicted`` of a static relation (module docstring).

    ``measured`` is the checked output's symbol; ``predicted`` its map with the read states
    replaced by their sensors' inverse maps, in output, input and parameter symbols.
    """

    residual: str
    check: str
    drivers: dict
    measured: sp.Expr
    predicted: sp.Expr
    signature: dict

    def initial(self, full_state: dict, y_by_name: dict) -> list:
        """No state: nothing to initialise."""
        return []


def _driver_choices(model: Model, output, direct: dict) -> list[dict]:
    """Every way to read the states ``output`` reads from *other* sensors (state -> sensor;
    at most :data:`MAX_DRIVER_CHOICES`, best sensors first); none when one of those states
    has no other direct sensor. A state with three sensors gives each pair its relation,
    so that a fault of any one of them is told from the others'."""
    expr = model.expand(output.expr)
    options = []
    for s in model.states:
        if s.symbol not in expr.free_symbols:
            continue
        others = [o for o in direct.get(s.name, []) if o != output.name]
        if not others:
            return []
        options.append([(s.name, o) for o in others])
    return [dict(c) for c in itertools.islice(itertools.product(*options),
                                              MAX_DRIVER_CHOICES)]


def predicted_output(model: Model, check: str, drivers: dict, faults: bool = False):
    """``h_c(g_D^{-1}(y_D), u)``: the checked output predicted from its drivers' sensors.

    With ``faults``, the pair ``(H_c(x, u, phi), h_c(g_D^{-1}(H_D(x, u, phi)), u))``: the
    checked output and its prediction, both with the fault terms in the sensors they read.
    """
    from fdigen.design.submodel import state_from_sensor

    k = model.output_index(check)
    nominal = model.expand(model.outputs[k].expr)
    if not faults:
        subs = {model.states[model.state_index(s)].symbol: state_from_sensor(model, s, o)
                for s, o in drivers.items()}
        return nominal.xreplace(subs)
    h_f = model.h(with_faults=True)
    subs = {model.states[model.state_index(s)].symbol:
            state_from_sensor(model, s, o, h_f[model.output_index(o)])
            for s, o in drivers.items()}
    return h_f[k], nominal.xreplace(subs)


def _signature(model: Model, check: str, drivers: dict, faults: list, points=3, seed=7):
    """Which faults move the relation: ``d/dphi_j (H_c - prediction) != 0`` (relative to
    the larger of the two terms, so a cancellation in floating point reads as 0) at
    ``points`` random points of the declared ranges."""
    from fdigen.design.signatures import random_points

    measured, predicted = predicted_output(model, check, drivers, faults=True)
    result = {name: False for name in faults}
    pts = random_points(model, points, seed)
    for fault in model.faults:
        if fault.name not in result:
            continue
        terms = (sp.diff(measured, fault.symbol), sp.diff(predicted, fault.symbol))
        if terms[0] == terms[1]:
            continue
        for subs in pts:
            values = [_value(t, subs) for t in terms]
            if None in values:
                continue
            if abs(values[0] - values[1]) > _REL_TOL * max(abs(values[0]), abs(values[1])):
                result[fault.name] = True
                break
    return result


def _value(expr, subs):
    from fdigen.design.signatures import value_at

    v = value_at(expr, subs)
    return v if v is not None and np.isfinite(v) else None


def static_relations(model: Model, faults: list, exclude=()) -> list[tuple[str, dict, dict]]:
    """Every static relation of ``model`` as ``(check, drivers, signature)``, the outputs
    in :func:`~fdigen.model.sensor_maps.output_preference` order, without the outputs
    ``exclude`` (a voter's channels), relations that no fault moves, and a relation whose
    signature another one already has (a sensor pair's mirror), at most
    :data:`MAX_STATIC_RELATIONS`."""
    from fdigen.design.submodel import direct_sensors

    direct = direct_sensors(model)
    rank = output_preference(model)
    found, seen = [], set()
    for out in sorted(model.outputs, key=lambda o: rank[o.name]):
        if out.name in exclude:
            continue
        for drivers in _driver_choices(model, out, direct):
            if set(drivers.values()) & set(exclude) or len(found) >= MAX_STATIC_RELATIONS:
                continue
            if not drivers and not _reads_an_input(model, out):
                continue
            sig = _signature(model, out.name, drivers, faults)
            key = frozenset(f for f, on in sig.items() if on)
            if not key or key in seen:
                continue
            seen.add(key)
            found.append((out.name, drivers, sig))
    return found


def _reads_an_input(model: Model, output) -> bool:
    expr = model.expand(output.expr)
    return any(s.symbol in expr.free_symbols for s in model.inputs)


def static_label(check: str, drivers: dict) -> str:
    """``static relation y_press from [Q<-y_flow]``."""
    drv = ", ".join(f"{s}<-{o}" for s, o in drivers.items())
    return f"static relation: {check} predicted from [{drv}] and the inputs"


def static_residual(model: Model, check: str, drivers: dict, signature: dict,
                    residual: str) -> StaticRelation:
    """The :class:`StaticRelation` of ``check`` predicted from ``drivers``."""
    return StaticRelation(residual, check, dict(drivers), model.output(check).symbol,
                          predicted_output(model, check, drivers), dict(signature))
