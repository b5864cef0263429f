"""The ``[simulation]`` table: closed-loop settings, read and validated once.

Two forms. The single-loop form (the pneumatic cylinder's) drives one input with one
stateless law::

    [simulation]
    input = "v"
    controller = "min(max(40*(xref - x3), -5), 5)"   # outputs and the reference symbol
    reference_symbol = "xref"                          # [default xref]
    reference = "0.1 + 0.035*sin(2*pi*0.13*t)"        # demand, an expression of t
    reference_column = "xref"                          # log column of the demand

The several-loops form gives each controlled input its own controller::

    [simulation]
    duration = 400.0
    [simulation.controllers.level1]
    type = "pi"               # u = offset + kp*e + ki*I, e = reference - measurement
    input = "q1"
    measurement = "h1_meas"   # an expression of the outputs (and parameters)
    reference = "0.5 + 0.05*sin(2*pi*0.005*t)"
    kp = 2e-4
    ki = 5e-6
    limits = [0.0, 1e-4]      # the command is clipped; the integrator stops winding up
    kd = 0.0                  # optional: derivative of the measurement (a PID), filtered
    td = 0.0                  # over td seconds (0: one sample, a backward difference)
    [simulation.controllers.heater]
    type = "onoff"            # a thermostat: on below ref - h/2, off above ref + h/2
    input = "P"
    measurement = "T_meas"
    reference = "55"
    levels = [0.0, 3000.0]    # the command off and on
    hysteresis = 4.0          # h, the band's width (0: switches at the reference)
    [simulation.controllers.pump2]
    type = "expression"       # u = law(outputs, ref), stateless
    input = "q2"
    law = "min(max(4e-4*(ref - h3_meas) + 3e-5, 0), 1e-4)"
    reference = "0.3"

Laws and measurements may use the model's parameters (``measurement = "y2/kv"``): they
are replaced by their nominal values, the controller's configured constants.

Inputs no controller drives are held at their operating values. Every key is checked
here, at load: an unknown key, a non-text law, an unknown input, output or symbol is an
error naming the field.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import sympy as sp

from fdigen.errors import ModelFileError
from fdigen.model.expression import parse_expression
from fdigen.model.numbers import number_problem

#: keys of the single-loop form
LEGACY_KEYS = ("input", "controller", "reference", "reference_symbol", "reference_column",
               "initial", "duration", "substeps")
#: keys of the several-loops form
KEYS = ("controllers", "initial", "duration", "substeps")
#: keys of one controller, by type
CONTROLLER_KEYS = {
    "pi": ("type", "input", "measurement", "reference", "reference_column", "kp", "ki",
           "limits", "offset", "kd", "td"),
    "expression": ("type", "input", "law", "reference", "reference_symbol",
                   "reference_column"),
    "onoff": ("type", "input", "measurement", "reference", "reference_column", "levels",
              "hysteresis"),
}


@dataclass(frozen=True)
class Controller:
    """One loop of the closed-loop simulation.

    ``kind`` is ``"expression"`` (``u = law(y, ref)``), ``"onoff"`` (a thermostat: the
    command at ``levels[1]`` once the measurement falls below ``r - h/2``, at
    ``levels[0]`` once it rises above ``r + h/2``, held in between; off at the start) or
    ``"pi"``:

    .. math::

        e_k = r_k - m(y_k),\\quad v_k = u_0 + k_p e_k + k_i I_k,\\quad
        u_k = \\min(\\max(v_k, u_{lo}), u_{hi}),\\quad
        I_{k+1} = I_k + T_s e_k \\;\\text{unless}\\; (v_k > u_{hi}, e_k > 0)
        \\;\\text{or}\\; (v_k < u_{lo}, e_k < 0)

    (conditional integration: the integrator does not wind up while the command is
    saturated in the direction the error pushes it). With ``kd`` (a PID) the derivative of
    the measurement, filtered over ``td`` (at least one sample ``T_s``), is subtracted:

    .. math::

        v_k \\mathrel{-}= k_d\\, s_k (m_k - f_k) / \\max(t_d, T_s),\\quad
        f_{k+1} = f_k + \\min(T_s / t_d, 1) (m_k - f_k)

    with ``s_k`` 0 at the first sample (``f`` holds no measurement yet: no kick) and 1
    after; on the measurement, not the error, so a reference step gives no kick either
    (a magnetic levitation rig, unstable open loop, needs it to be stabilised at all).
    """

    name: str
    kind: str
    input: str
    reference: str | None
    reference_column: str
    law: sp.Expr | None = None
    reference_symbol: str = "ref"
    measurement: sp.Expr | None = None
    kp: float = 0.0
    ki: float = 0.0
    limits: tuple[float, float] | None = None
    offset: float = 0.0
    kd: float = 0.0
    td: float = 0.0
    levels: tuple[float, float] | None = None     # "onoff": the command off and on
    hysteresis: float = 0.0                        # "onoff": the band around the reference

    @property
    def stateful(self) -> bool:
        return self.kind in ("pi", "onoff")

    @property
    def states(self) -> int:
        """Controller states carried from sample to sample: the integrator, and with a
        derivative its filter and the first-sample switch; an on/off controller's switch."""
        return 0 if not self.stateful else 1 if self.kind == "onoff" else 3 if self.kd else 1


@dataclass(frozen=True)
class SimulationSpec:
    """The parsed ``[simulation]`` table (see module docstring)."""

    controllers: tuple[Controller, ...]
    duration: float | None = None
    substeps: int | None = None
    initial: dict = field(default_factory=dict)
    legacy: bool = True


def _err(message, source, fld, symbol=None):
    return ModelFileError(message, source=source, field=fld, symbol=symbol)


def _number(value, source, fld, symbol=None):
    problem = number_problem(value)
    if problem:
        raise _err(problem, source, fld, symbol)
    return float(value)


def _text(value, source, fld, what):
    if not isinstance(value, str):
        raise _err(f"{what} must be text (one expression), got {type(value).__name__}",
                   source, fld)
    return value


def _unknown(table, allowed, source, fld):
    extra = sorted(set(table) - set(allowed))
    if extra:
        raise _err(f"unknown key (allowed: {', '.join(allowed)})", source, fld, extra[0])


def parse_simulation(sim: dict, *, inputs, outputs, states, parameters, operating_point,
                     source: str, columns=()) -> SimulationSpec | None:
    """Validate and parse a ``[simulation]`` table; ``None`` when it is empty.

    A controller reads the outputs (what the plant's controller measures), never a state
    or an input: such a name is refused saying so and naming the outputs (see
    :func:`_parse_simulation` for the parameters).
    """
    try:
        return _parse_simulation(sim, inputs=inputs, outputs=outputs, states=states,
                                 parameters=parameters, operating_point=operating_point,
                                 source=source, columns=columns)
    except ModelFileError as exc:
        kind = ("a state" if exc.symbol in set(states) else
                "an input" if exc.symbol in set(inputs) else None)
        if kind is None or not str(exc.field or "").startswith("simulation") or \
                str(exc.field).endswith(".input") or \
                str(exc.field) == "simulation.controllers" or \
                str(exc.field).startswith("simulation.initial"):   # its own key: a state
            raise
        raise _err(f"'{exc.symbol}' is {kind}: a controller reads the measured outputs "
                   f"({', '.join(outputs)}) and parameters, as the plant's controller reads "
                   "its sensors", source, exc.field, exc.symbol) from None


def _parse_simulation(sim: dict, *, inputs, outputs, states, parameters, operating_point,
                      source: str, columns=()) -> SimulationSpec | None:
    """Validate and parse a ``[simulation]`` table; ``None`` when it is empty.

    Parameters
    ----------
    sim : dict
        The table as read from TOML.
    inputs, outputs, states : sequence of str
        Names declared by the model.
    parameters : dict of str to float
        Parameter values (for operating values written as expressions).
    operating_point : dict of str to float
        Operating values of states and inputs (the default PI offset and the value of
        an uncontrolled input).
    source : str
        The model file, for error messages.
    columns : collection of str
        Log columns of the inputs and outputs (a reference column may not reuse one).
    """
    if not sim:
        return None
    legacy = "controllers" not in sim
    _unknown(sim, LEGACY_KEYS if legacy else KEYS, source, "simulation")
    out_syms = {o: sp.Symbol(o, real=True) for o in outputs}
    time_syms = {"t": sp.Symbol("t", real=True), "pi": sp.pi}
    if legacy:
        for key in ("input", "controller", "reference"):
            if key not in sim:
                raise _err(f"missing '{key}' (or write [simulation.controllers.<name>] "
                           "tables)", source, f"simulation.{key}")
        ref_symbol = _text(sim.get("reference_symbol", "xref"), source,
                           "simulation.reference_symbol", "the reference symbol")
        ctrl = _expression_controller(
            "controller", {"input": sim["input"], "controller": sim["controller"],
                           "reference": sim["reference"], "reference_symbol": ref_symbol,
                           "reference_column": sim.get("reference_column", "xref")},
            inputs, out_syms, time_syms, source, "simulation", law_key="controller",
            parameters=parameters)
        controllers = (ctrl,)
    else:
        table = sim["controllers"]
        if not isinstance(table, dict) or not table:
            raise _err("must hold one table per controller: [simulation.controllers.<name>]",
                       source, "simulation.controllers")
        controllers = []
        for name, spec in table.items():
            fld = f"simulation.controllers.{name}"
            if not isinstance(spec, dict):
                raise _err("must be a table {...}", source, fld, name)
            kind = spec.get("type", "expression" if "law" in spec else "pi")
            if kind not in CONTROLLER_KEYS:
                raise _err(f"type must be one of {', '.join(CONTROLLER_KEYS)}", source,
                           fld + ".type", str(kind))
            _unknown(spec, CONTROLLER_KEYS[kind], source, fld)
            if kind == "expression":
                controllers.append(_expression_controller(name, spec, inputs, out_syms,
                                                          time_syms, source, fld,
                                                          parameters=parameters))
            else:
                from fdigen.model.feedback_controllers import FEEDBACK

                controllers.append(FEEDBACK[kind](name, spec, inputs, out_syms, time_syms,
                                                  parameters, operating_point, source, fld))
        seen = {}
        for c in controllers:
            if c.input in seen:
                raise _err(f"input driven by two controllers ({seen[c.input]} and {c.name})",
                           source, "simulation.controllers", c.input)
            seen[c.input] = c.name
        refs = [c.reference_column for c in controllers if c.reference is not None]
        if len(set(refs)) != len(refs):
            raise _err("two controllers write the same reference_column", source,
                       "simulation.controllers")
    for c in controllers:
        if c.reference is not None and c.reference_column in set(columns) | {"t"}:
            fld = ("simulation.reference_column" if legacy
                   else f"simulation.controllers.{c.name}.reference_column")
            raise _err("the demand's log column is already an input, output or time column",
                       source, fld, c.reference_column)
    duration = None
    if "duration" in sim:
        duration = _number(sim["duration"], source, "simulation.duration")
        if duration <= 0:
            raise _err("duration must be > 0", source, "simulation.duration")
    substeps = None
    if "substeps" in sim:
        value = sim["substeps"]
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 1000:
            raise _err("substeps must be an integer in 1..1000", source, "simulation.substeps")
        substeps = value
    initial = sim.get("initial", {})
    if not isinstance(initial, dict):
        raise _err("must be a table {state = value}", source, "simulation.initial")
    for key, value in initial.items():
        if key not in states:
            raise _err("not a state", source, "simulation.initial", key)
        if isinstance(value, str):
            parse_expression(value, {q: sp.Symbol(q, real=True) for q in parameters},
                             source=source, field=f"simulation.initial.{key}")
        elif isinstance(value, list):
            bounds = [_number(v, source, f"simulation.initial.{key}", key) for v in value]
            if len(bounds) != 2 or not bounds[0] < bounds[1]:
                raise _err("an interval [low, high] with low < high (each run starts at a "
                           "value drawn in it)", source, f"simulation.initial.{key}", key)
        else:
            _number(value, source, f"simulation.initial.{key}", key)
    return SimulationSpec(tuple(controllers), duration, substeps, dict(initial), legacy)


def _input(spec, inputs, source, fld):
    name = _text(spec.get("input"), source, fld + ".input", "'input'")
    if name not in inputs:
        raise _err(f"not an input (inputs: {', '.join(inputs)})", source, fld + ".input", name)
    return name


def _reference(spec, time_syms, source, fld, required):
    if "reference" not in spec:
        if required:
            raise _err("missing 'reference' (an expression of t)", source, fld + ".reference")
        return None
    text = spec["reference"]
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        text = repr(float(_number(text, source, fld + ".reference")))
    text = _text(text, source, fld + ".reference", "the reference")
    parse_expression(text, time_syms, source=source, field=fld + ".reference")
    return text


def _with_parameters(text, symbols, parameters, source, fld):
    """Parse a controller expression of ``symbols`` and the model's parameters, the
    parameters replaced by their values (the controller's own, nominal constants: a gain
    converting volts back to cm is configured, not the plant's true value)."""
    par_syms = {q: sp.Symbol(q, real=True) for q in parameters}
    expr = parse_expression(text, {**par_syms, **symbols}, source=source, field=fld)
    return expr.xreplace({par_syms[q]: sp.Float(v, 17) for q, v in parameters.items()
                          if q not in symbols})


def _expression_controller(name, spec, inputs, out_syms, time_syms, source, fld,
                           law_key="law", parameters=None):
    inp = _input(spec, inputs, source, fld)
    ref_symbol = _text(spec.get("reference_symbol", "ref"), source,
                       fld + ".reference_symbol", "the reference symbol")
    if not ref_symbol.isidentifier() or ref_symbol in out_syms:
        raise _err("must be a new identifier", source, fld + ".reference_symbol", ref_symbol)
    if law_key not in spec:
        raise _err(f"missing '{law_key}' (an expression of the outputs and "
                   f"{ref_symbol})", source, f"{fld}.{law_key}")
    text = _text(spec[law_key], source, f"{fld}.{law_key}", "the controller law")
    law = _with_parameters(text, {**out_syms, ref_symbol: sp.Symbol(ref_symbol, real=True)},
                           parameters or {}, source, f"{fld}.{law_key}")
    reference = _reference(spec, time_syms, source, fld, required=False)
    column = _text(spec.get("reference_column", f"{name}_ref"), source,
                   fld + ".reference_column", "the reference column")
    return Controller(name, "expression", inp, reference, column, law=law,
                      reference_symbol=ref_symbol)


#: Parsed ``[simulation]`` tables of this process, by their text and the names they read:
#: a campaign's run parses its (varied) table several times, 16 ms each for a cylinder.
_PARSED: dict = {}
_PARSED_KEPT = 64


def simulation_spec(model) -> SimulationSpec:
    """The parsed ``[simulation]`` table of ``model``.

    Raises
    ------
    FdigenError
        When the model has no ``[simulation]`` table.
    """
    from fdigen.errors import FdigenError

    args = dict(
        inputs=[s.name for s in model.inputs],
        outputs=[o.name for o in model.outputs], states=[s.name for s in model.states],
        parameters={q.name: q.value for q in model.parameters},
        operating_point=dict(model.operating_point), source=model.source,
        columns=[s.column for s in (*model.inputs, *model.outputs)])
    key = json.dumps([model.simulation, args], sort_keys=True, default=repr)
    spec = _PARSED.get(key)
    if spec is None:
        spec = parse_simulation(dict(model.simulation), **args)
        if spec is not None:
            if len(_PARSED) >= _PARSED_KEPT:
                _PARSED.pop(next(iter(_PARSED)))
            _PARSED[key] = spec
    if spec is None:
        raise FdigenError(f"{model.source}: [simulation] needs '(input, controller, "
                          "reference)' or [simulation.controllers.<name>] for closed-loop runs")
    return spec


def initial_value(value, rng=None):
    """A state's ``[simulation.initial]`` entry for one run: a number or an expression as
    written, an interval ``[low, high]`` drawn uniformly by ``rng`` (without one: its
    midpoint)."""
    if isinstance(value, list):
        lo, hi = float(value[0]), float(value[1])
        return float(rng.uniform(lo, hi)) if rng is not None else 0.5 * (lo + hi)
    return value
