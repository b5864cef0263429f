"""Roles of other physics than motion and gas: liquid levels, thermal nodes, currents,
transfer flows and the inputs that drive them (see :mod:`fdigen.discover.roles`).

Recognised from the equations and the declared units, never from names:

* **liquid level**: a state in ``m`` whose equation is a sum of volume flows over an area
  parameter in ``m^2`` (``dh/dt = q/A``, ``A f_h`` free of ``A``). Its flow scale is the
  largest operating value of an input in ``m^3/s`` (else ``A`` times the range per 100 s).
* **thermal node**: a state in ``degC``/``K`` whose equation is a heat balance over a heat
  capacity parameter in ``J/K``. Its conductance scale is ``C |df/dT|`` at the operating
  point; its ambient is a parameter of the same unit described as ambient, else the
  state's lower limit.
* **current**: a state in ``A`` whose equation is a voltage balance over an inductance in
  ``H``, whose resistive term ``-R i/L`` is not already calibrated (``R`` not uncertain).
* **transfer flow**: a definition that enters exactly two state equations with gains of
  opposite signs (a pipe between two tanks, the heat through an exchanger wall).
* **driven input**: an input that enters a liquid or thermal balance affinely (a pump,
  a heater).
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from fdigen.model.dimensions import same_dimension
from fdigen.discover.roles import _affine_gains, _number, _text
from fdigen.model.model import Model

# roles go by dimension (fdigen.model.dimensions): a level in cm over an area in cm^2
# is a level like one in m over m^2
LEVEL_UNITS = "m"
AREA_UNITS = "m^2"
TEMPERATURE_UNITS = "K"
CAPACITY_UNITS = "J/K"


@dataclass(frozen=True)
class Balance:
    """A level or thermal balance ``dx/dt = g/C``: the state, its capacity parameter, the
    scale of its flows (m^3/s or W/K) and its operating value; ``ambient`` (model text)
    for thermal nodes."""

    state: str
    capacity: str
    kind: str
    scale: float
    value: float
    ambient: str = ""
    #: the ambient is the state's lower limit (or 0): no parameter of its unit is
    #: described as ambient
    assumed: bool = False


@dataclass(frozen=True)
class Transfer:
    """A definition ``d`` entering two equations: state -> gain ``df/dd`` (model text)."""

    definition: str
    gains: dict


def _unit(s: str) -> str:
    return s.replace(" ", "")


def _capacity(model: Model, k: int, units: str):
    f = model.dynamics[k]
    for q in model.parameters:
        if same_dimension(q.unit, units) and q.symbol in f.free_symbols \
                and not sp.simplify(f * q.symbol).has(q.symbol):
            return q
    return None


def balances(model: Model) -> list[Balance]:
    """Every liquid level and thermal node of ``model``, in model order."""
    out = []
    flows = [abs(float(model.operating_point.get(u.name, 0.0))) for u in model.inputs
             if same_dimension(u.unit, "m^3/s")]
    for k, s in enumerate(model.states):
        unit = _unit(s.unit)
        value = float(model.operating_point.get(s.name, 0.0))
        if same_dimension(unit, LEVEL_UNITS):
            cap = _capacity(model, k, AREA_UNITS)
            if cap is None:
                continue
            span = float(s.range[1] - s.range[0]) if s.range else 1.0
            scale = max(flows) if flows and max(flows) > 0 else cap.value * span / 100.0
            out.append(Balance(s.name, cap.name, "level", scale, value))
        elif same_dimension(unit, TEMPERATURE_UNITS):
            cap = _capacity(model, k, CAPACITY_UNITS)
            if cap is None:
                continue
            slope = _number(sp.diff(model.f()[k], s.symbol) * cap.symbol, model)
            scale = abs(slope) if slope else cap.value / 100.0
            amb = [q for q in model.parameters if same_dimension(q.unit, unit)
                   and "ambient" in q.description.lower()]
            ambient = amb[0].name if amb else (_text(s.limits[0]) if s.limits else "0")
            out.append(Balance(s.name, cap.name, "thermal", scale, value, ambient,
                               assumed=not amb))
    return out


def currents(model: Model) -> list[tuple[str, str, str]]:
    """``(current state, inductance, resistance)`` of every uncalibrated voltage balance."""
    out = []
    for k, s in enumerate(model.states):
        if not same_dimension(s.unit, "A"):
            continue
        ind = _capacity(model, k, "H")
        if ind is None:
            continue
        g = sp.expand(model.f()[k] * ind.symbol)
        coeff = sp.diff(g, s.symbol)
        res = [q for q in model.parameters if same_dimension(q.unit, "Ohm")
               and coeff.has(q.symbol)]
        if len(res) == 1 and not res[0].uncertain:
            out.append((s.name, ind.name, res[0].name))
    return out


def transfers(model: Model) -> list[Transfer]:
    """Every definition entering exactly two state equations with opposite-sign gains."""
    out = []
    for dname, _ in model.definitions:
        d = sp.Symbol(dname, real=True)
        gains = {}
        for k, s in enumerate(model.states):
            g = sp.diff(model.dynamics[k], d)
            if g != 0:
                gains[s.name] = g
        if len(gains) != 2:
            continue
        signs = [_number(g, model) for g in gains.values()]
        if None in signs or signs[0] * signs[1] >= 0:
            continue
        out.append(Transfer(dname, {s: _text(g) for s, g in gains.items()}))
    return out


def driven_inputs(model: Model) -> list[tuple[str, dict]]:
    """Actuator inputs (``kind`` not ``"measured"``) entering a level or thermal balance
    affinely: ``(input, {state: (gain text, negative)})``."""
    nodes = {b.state for b in balances(model)}
    out = []
    for u in model.inputs:
        if not u.is_actuator:          # a measured inlet temperature wears no pump
            continue
        gains = {s: g for s, g in _affine_gains(model, u).items() if s in nodes}
        if not gains:
            continue
        texts = {}
        for s, g in gains.items():
            v = _number(g, model)
            texts[s] = (_text(-g), True) if v is not None and v < 0 else (_text(g), False)
        out.append((u.name, texts))
    return out
