"""Roles: where in a model a library effect belongs, found from the model's structure.

The effect library (:mod:`fdigen.discover.effects`) declares its effects by role, never by
a model's names. A role is recognised from the equations and the units the model file
declares:

* **motion** (a force or torque balance): a state ``v`` in ``m/s`` (translation) or
  ``rad/s`` (rotation; the library's force terms are SI) whose equation is a sum of
  forces over an inertia parameter,
  ``dv/dt = g(x, u, p) / I`` (``I`` a parameter such that ``I f_v`` does not contain
  ``I``). Its sizes: the speed amplitude ``a`` (half the span of ``v``'s range), the
  viscous damping ``d = -I df_v/dv`` at the operating point, the force scale ``d a``
  (cylinder: 100 N s/m x 0.3 m/s = 30 N; DC motor: 1e-5 N m s x 300 rad/s = 3 mN m),
  the smoothing speed of a friction sign ``a/60`` and the Stribeck speed ``a/15``.
* **gas chamber**: a state in ``Pa`` whose equation is affine in an input ``u`` with a
  gain ``b = df/du`` that holds a mass-flow constant ``K`` (a parameter in
  ``kg/(s ...)``): ``g = |b/K|`` is the chamber's factor from a mass flow to ``dP/dt``
  (``gamma R Ts / Vp``) and the state's lower limit is the ambient pressure it leaks to.
* **actuator**: an input that enters equations affinely (``df_i/du`` free of ``u``);
  a *valve* if it drives a gas chamber.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import sympy as sp

from fdigen.derive.nonsmooth import drop_impulses
from fdigen.model.model import Model

#: Units of a velocity state: rotational or not, and ``c``, the state's value per SI unit
#: (m/s, rad/s). The library's force terms are ``F/I`` in the SI; in a model whose speed
#: is in mm/s (``dv/dt = 1000*F/M``) or rpm (``dw/dt = 30/pi*T/J``) a term is ``c F/I``:
#: without ``c`` a first-time user's servo in mm/s got a 2000 N load 1000 times too weak,
#: and a motor written in rpm got no friction at all and two sensor offsets instead.
VELOCITY_UNITS = {"m/s": (False, 1.0), "mm/s": (False, 1000.0), "cm/s": (False, 100.0),
                  "rad/s": (True, 1.0), "rpm": (True, 30.0 / math.pi),
                  "r/min": (True, 30.0 / math.pi), "rev/min": (True, 30.0 / math.pi),
                  "deg/s": (True, 180.0 / math.pi)}


def velocity_kind(unit: str) -> tuple[bool, float] | None:
    """``(rotational, c)`` of a velocity unit (:data:`VELOCITY_UNITS`, spaces ignored), or
    ``None`` for any other."""
    return VELOCITY_UNITS.get((unit or "").replace(" ", ""))
#: Units of a pressure state.
PRESSURE_UNITS = {"Pa"}


@dataclass(frozen=True)
class Motion:
    """A force (torque) balance ``dv/dt = g/I``.

    Attributes
    ----------
    velocity, inertia : str
        The velocity state and the inertia parameter.
    rotational : bool
    amplitude : float
        Half the span of the velocity's range.
    force : float
        Force (torque) scale: viscous damping times amplitude, two significant digits.
    v_eps, v_stribeck : float
        Smoothing speed of the friction sign and Stribeck speed (the state's unit).
    scale : float
        The velocity's value per SI unit, ``c`` (1 for m/s and rad/s, 30/pi for rpm): a
        force ``F`` moves the state at ``c F/I``.
    drive : float
        The largest force (torque) term of the balance, SI, each term ``t`` of
        ``I f_v`` at the corners of the ranges of the states it reads (inputs at the
        operating point): ``max |t| / c``. A hydraulic cylinder's 130 bar on its piston
        is 25.5 kN, where its mass and speed range gave a scale of 3 N.
    """

    velocity: str
    inertia: str
    rotational: bool
    amplitude: float
    force: float
    v_eps: float
    v_stribeck: float
    scale: float = 1.0
    drive: float = 0.0


@dataclass(frozen=True)
class Chamber:
    """A gas chamber: pressure state, mass-flow gain (model text) and ambient (text)."""

    pressure: str
    gain: str
    ambient: str
    input: str
    suffix: str


@dataclass(frozen=True)
class Actuator:
    """An input entering equations affinely.

    ``gains``: state -> ``(text, negative)``, the gain ``df/du`` as model text (of its
    magnitude, ``negative`` telling its sign at the operating point).
    """

    input: str
    unit: str
    span: float
    gains: dict
    drives_chamber: bool


def _round2(v: float) -> float:
    return float(f"{v:.2g}")


def _values(model: Model) -> dict:
    vals = dict(model.parameter_values)
    for s in (*model.states, *model.inputs):
        if s.name in model.operating_point:
            vals[s.symbol] = float(model.operating_point[s.name])
    return vals


def _number(expr, model: Model) -> float | None:
    try:
        v = float(model.expand(expr).xreplace(_values(model)))
    except (TypeError, ValueError):
        return None
    return v


def motions(model: Model) -> list[Motion]:
    """Every force/torque balance of ``model`` (see the module docstring)."""
    out = []
    params = {q.symbol: q for q in model.parameters}
    for k, s in enumerate(model.states):
        kind = velocity_kind(s.unit)
        if kind is None or s.range is None:
            continue
        rotational, c = kind
        f = model.dynamics[k]
        inertia = None
        for sym in sorted(f.free_symbols & set(params), key=str):
            if not sp.simplify(f * sym).has(sym):
                inertia = params[sym]
                break
        if inertia is None:
            continue
        a = 0.5 * float(s.range[1] - s.range[0])
        damping = _number(-drop_impulses(sp.diff(f, s.symbol)) * inertia.symbol,
                          model) or 0.0
        # -I df/dv is the SI damping in any unit (c cancels); the amplitude is c times SI
        force = _round2(damping * a / c) if damping > 0 else _round2(
            float(inertia.value) * a / c)  # no damping: the force that stops it in 1 s
        out.append(Motion(s.name, inertia.name, rotational,
                          a, force, _round2(a / 60.0), _round2(a / 15.0), c,
                          _largest_term(model, f * inertia.symbol) / c))
    return out


def _largest_term(model: Model, expr) -> float:
    """``max |t|`` over the additive terms ``t`` of ``expr`` (definitions expanded), each
    at the corners of the declared ranges of the (at most three) states it reads, the
    parameters at their values and the inputs at the operating point; 0 when none can be
    evaluated."""
    import itertools

    from fdigen.derive.linearisation import operating_point_substitution

    try:
        expr = sp.expand(drop_impulses(model.expand(expr)))
        base = operating_point_substitution(model)
    except Exception:  # noqa: BLE001 - a scale estimate never breaks the library
        return 0.0
    ranges = {s.symbol: s.range for s in model.states if s.range}
    best = 0.0
    for term in (expr.args if expr.is_Add else (expr,)):
        reads = sorted(term.free_symbols & set(ranges), key=str)
        if len(reads) > 3:
            continue
        for corner in itertools.product(*[(float(ranges[r][0]), float(ranges[r][1]))
                                          for r in reads]):
            try:
                at = sp.sympify(term.xreplace(dict(zip(reads, corner))))
                value = float(sp.sympify(at.xreplace(base)))
            except Exception:  # noqa: BLE001 - a term that is no number there is skipped
                continue
            if math.isfinite(value):
                best = max(best, abs(value))
    return best


def _affine_gains(model: Model, u) -> dict:
    gains = {}
    for k, s in enumerate(model.states):
        b = drop_impulses(sp.diff(model.dynamics[k], u.symbol))
        if b != 0 and not model.expand(b).has(u.symbol):
            gains[s.name] = b
    return gains


def _text(expr) -> str:
    return str(expr)


def chambers(model: Model) -> list[Chamber]:
    """Every gas chamber of ``model`` (see the module docstring), in model order."""
    found = []
    for u in model.inputs:
        for name, b in _affine_gains(model, u).items():
            s = model.states[model.state_index(name)]
            if s.unit.strip() not in PRESSURE_UNITS or not s.limits:
                continue
            flow = [q for q in model.parameters if q.symbol in b.free_symbols
                    and q.unit.replace(" ", "").startswith(("kg/(s", "kg/s"))]
            if len(flow) != 1:
                continue
            g = sp.simplify(b / flow[0].symbol)
            sign = _number(g, model)
            if not sign:
                continue
            g = g if sign > 0 else -g
            amb = s.limits[0]
            found.append((s.name, _text(g), _text(amb), u.name))
    names = [f[0] for f in found]
    prefix = ""
    if len(names) > 1:
        import os

        prefix = os.path.commonprefix(names)
    return [Chamber(p, g, amb, u, p[len(prefix):] if len(names) > 1 else "")
            for p, g, amb, u in found]


def actuators(model: Model) -> list[Actuator]:
    """Every actuator input (``kind`` not ``"measured"``) that enters some equation
    affinely, with its gains as model text."""
    valves = {c.input for c in chambers(model)}
    out = []
    for u in model.inputs:
        if not u.is_actuator:          # a measured disturbance has no dead band
            continue
        gains = _affine_gains(model, u)
        if not gains or u.range is None:
            continue
        texts = {}
        for name, b in gains.items():
            sign = _number(b, model)
            texts[name] = (_text(-b), True) if sign is not None and sign < 0 \
                else (_text(b), False)
        out.append(Actuator(u.name, u.unit, float(u.range[1] - u.range[0]), texts,
                            u.name in valves))
    return out
