"""The controllers of the closed-loop simulation, as CasADi expressions of one sample.

Built from the parsed ``[simulation]`` table (:mod:`fdigen.model.simulation_spec`): every
controller computes its input from the measured outputs ``y_k`` and its reference
``r_k``; a PI controller carries its integrator from one sample to the next (a PID also
its derivative filter), an on/off controller its switch; inputs no controller drives are
held at their operating values.
"""

from __future__ import annotations

import casadi as ca
import sympy as sp

from fdigen.model.model import Model
from fdigen.model.simulation_spec import SimulationSpec


def control_step(model: Model, spec: SimulationSpec, y_k, refs, integ, dt: float):
    """Commands of one sample and the next controller state.

    Parameters
    ----------
    model : Model
    spec : SimulationSpec
    y_k : casadi.SX
        Measured outputs at sample ``k`` (noise, faults, stuck sensors included).
    refs : casadi.SX
        One reference per controller, in ``spec.controllers`` order.
    integ : casadi.SX
        Controller states, :attr:`~fdigen.model.simulation_spec.Controller.states` per
        controller, in order.
    dt : float
        Sample time.

    Returns
    -------
    u_cmd : casadi.SX
        The command of every input (uncontrolled inputs at their operating values).
    integ_next : casadi.SX
        Integrators after the sample (see :class:`~fdigen.model.simulation_spec.Controller`).
    """
    from fdigen.backends.casadi_backend.convert import sympy_to_casadi

    m, p = len(model.inputs), len(model.outputs)
    names = [s.name for s in model.inputs]
    u_cmd = ca.SX.zeros(m)
    controlled = {c.input for c in spec.controllers}
    for j, s in enumerate(model.inputs):
        if s.name not in controlled:
            u_cmd[j] = float(model.operating_point[s.name])
    ymeas = ca.SX.sym("ym", p)
    cmap = {o.symbol: ymeas[i] for i, o in enumerate(model.outputs)}
    nxt = []
    k_int = 0
    for c_index, ctrl in enumerate(spec.controllers):
        j = names.index(ctrl.input)
        if ctrl.kind == "expression":
            law_map = dict(cmap)
            law_map[sp.Symbol(ctrl.reference_symbol, real=True)] = refs[c_index]
            u_cmd[j] = ca.substitute(sympy_to_casadi(ctrl.law, law_map), ymeas, y_k)
            continue
        meas = ca.substitute(sympy_to_casadi(ctrl.measurement, cmap), ymeas, y_k)
        e = refs[c_index] - meas
        if ctrl.kind == "onoff":     # on below r - h/2, off above r + h/2, held between
            s_k = integ[k_int]
            half = 0.5 * ctrl.hysteresis
            s_next = ca.if_else(e > half, 1.0, ca.if_else(e < -half, 0.0, s_k))
            off, on = ctrl.levels
            u_cmd[j] = off + (on - off) * s_next
            nxt.append(s_next)
            k_int += ctrl.states
            continue
        i_k = integ[k_int]
        v = ctrl.offset + ctrl.kp * e + ctrl.ki * i_k
        derivative = []
        if ctrl.kd:          # the filtered derivative of the measurement (Controller)
            f_k, started = integ[k_int + 1], integ[k_int + 2]
            td = max(ctrl.td, dt)
            v = v - ctrl.kd * started * (meas - f_k) / td
            f_next = ca.if_else(started > 0.5, f_k + min(dt / td, 1.0) * (meas - f_k), meas)
            derivative = [f_next, ca.SX(1.0)]
        k_int += ctrl.states
        if ctrl.limits is None:
            u_cmd[j] = v
            nxt.extend([i_k + dt * e, *derivative])
            continue
        lo, hi = ctrl.limits
        u_cmd[j] = ca.fmin(ca.fmax(v, lo), hi)
        windup = ca.logic_or(ca.logic_and(v > hi, e > 0), ca.logic_and(v < lo, e < 0))
        nxt.extend([ca.if_else(windup, i_k, i_k + dt * e), *derivative])
    return u_cmd, (ca.vertcat(*nxt) if nxt else ca.SX(0, 1))


def integrator_count(spec: SimulationSpec) -> int:
    """Number of controller states carried from sample to sample."""
    return sum(c.states for c in spec.controllers)
