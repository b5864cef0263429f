"""Residuals that are blind to one fault by construction (unknown-input decoupling).

When a fault enters two state equations whose states are both measured, a combination of
the two equations does not contain it (and where the weights that cancel it depend on the
two states, a balance of them: :mod:`fdigen.design.first_integral`). For the pneumatic
cylinder the valve flow enters
the chamber equations (1) and (2) with opposite signs; with ``c = (Vp, Vn)``

.. math::

    m = V_p P_p + V_n P_n,\\qquad
    \\dot m = V_p \\dot P_p + V_n \\dot P_n + A\\dot x (P_p - P_n)
            = -(\\gamma - 1) A (P_p - P_n)\\,\\dot x

holds whatever the valve does, while a leak or a blockage (flows that do not cancel)
changes it. The tool finds ``c`` itself: for the fault direction ``e = df/dphi`` restricted
to the states it enters, ``c`` spans the left null space of ``e`` (for two states,
``c = (e_2, -e_1)`` with common factors cancelled). The combined state ``m`` replaces those
states in a driven sub-model (other measured states become inputs), which is run as a
nonlinear parallel model against ``m`` computed from the measurements.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import sympy as sp

from fdigen.derive.kalman import discrete_kalman_gain
from fdigen.derive.linearisation import discretise_noise, discretise_zoh, linearise, numeric
from fdigen.derive.nonsmooth import derivative, jacobian
from fdigen.derive.riccati import state_scales
from fdigen.design.first_integral import first_integral
from fdigen.design.readable import almost_everywhere
from fdigen.design.submodel import driver_range, measured_states, state_from_sensor
from fdigen.model.model import Fault, Model, Output, Variable


@dataclass(frozen=True)
class ParallelResidual:
    """A residual from a nonlinear parallel model of a driven sub-model.

    ``measured`` is an expression of the full model's output symbols, ``predicted`` the
    same quantity as an expression of the sub-model's states; ``realign_gain`` re-aligns
    the parallel model (``x += M r``) while no flag is raised.
    """

    residual: str
    model: Model
    drivers: dict
    measured: sp.Expr
    predicted: sp.Expr
    realign_gain: np.ndarray
    decoupled: str
    initial_expr: tuple
    signature: dict

    def initial(self, full_state: dict, y_by_name: dict) -> list:
        """Initial sub-model state from the full model's initial state values."""
        subs = {sp.Symbol(k, real=True): v for k, v in full_state.items()}
        return [e.xreplace(subs) for e in self.initial_expr]


def _nonzero(expr, model: Model | None = None) -> bool:
    """Whether ``expr`` is not identically 0 (sympy's simplify cannot decide some guarded
    expressions, ``Max(0, Ps - PL*sign(u))``, and raises: those are kept as nonzero).

    With ``model``, a value clearly away from 0 at a point of the declared ranges
    settles it first: ``simplify`` of a separator's fault directions (its pressure
    through the moles in the gas volume) took 11 s of a 23 s derivation."""
    if model is not None and expr != 0 and _clearly_nonzero(expr, model):
        return True
    try:
        return sp.simplify(expr) != 0
    except (ValueError, TypeError):
        return expr != 0


def _clearly_nonzero(expr, model: Model) -> bool:
    """``expr`` at two seeded points of the declared ranges
    (:func:`~fdigen.design.signatures.random_points`) is real and larger than 1e-9 of its
    largest term there."""
    from fdigen.design.signatures import random_points, value_at

    terms = sp.Add.make_args(sp.expand(expr)) if len(str(expr)) < 4000 else (expr,)
    for point in random_points(model, 2, 17):
        total = value_at(expr, point)
        scale = [value_at(t, point) for t in terms]
        if total is None or None in scale or not np.isfinite(total):
            continue
        if abs(total) > 1e-9 * max(max(abs(v) for v in scale), 1e-300):
            return True
    return False


def decoupling_direction(model: Model, fault: Fault):
    """``(idx, m)``: the two states the fault enters and the combination ``m`` of them it
    cannot move (``c_a x_a + c_b x_b``, or a balance of the two with state-dependent
    weights, :mod:`fdigen.design.first_integral`), or ``None``.

    Only faults entering exactly two state equations whose states are measured are
    decoupled here (:func:`decoupling_refusal` says which condition a fault fails).
    """
    found, _ = _direction_or_reason(model, fault)
    return found


def decoupling_refusal(model: Model, fault: Fault) -> str:
    """Why no residual blind to ``fault`` is constructed ("" when one is)."""
    return _direction_or_reason(model, fault)[1]


def _direction_or_reason(model: Model, fault: Fault):
    memo = model.derived("decoupling")       # asked for each fault by several steps
    if fault.name not in memo:
        memo[fault.name] = _find_direction(model, fault)
    return memo[fault.name]


def _find_direction(model: Model, fault: Fault):
    e = jacobian(model.f(with_faults=True), [fault.symbol]).xreplace(
        {s: 0 for s in model.f_sym})
    e = e.applyfunc(almost_everywhere)    # d sign(u)/du = 2 DiracDelta(u): 0 a.e.
    idx = [i for i in range(e.rows) if _nonzero(e[i], model)]
    direct = measured_states(model)
    if len(idx) < 2:
        return None, (f"{fault.name} enters {len(idx)} state equation"
                      f"{'' if len(idx) == 1 else 's'}; fdigen cancels a fault entering "
                      "two or more")
    hidden = [model.states[i].name for i in idx if model.states[i].name not in direct]
    if len(idx) - len(hidden) < 2:
        return None, (f"{fault.name} enters the balance of {', '.join(hidden)}, which no "
                      "sensor measures directly")
    # any two measured states it enters: a fed-batch's feed enters the volume, the biomass
    # and the substrate, and the biomass mass X V does not move with it
    reasons = []
    for a, b in itertools.combinations([i for i in idx if model.states[i].name in direct], 2):
        m, why = _cancelling_balance(model, e, a, b, fault)
        if m is not None:
            return ([a, b], m), ""
        reasons.append(why)
    return None, "; ".join(reasons)


def _cancelling_balance(model: Model, e, a: int, b: int, fault: Fault):
    """``(m, "")``: a combination of states ``a`` and ``b`` the fault direction ``e`` does
    not move, or ``(None, why)``."""
    xa, xb = model.states[a].symbol, model.states[b].symbol
    ratio = sp.cancel(-e[a] / e[b])
    num, den = sp.fraction(ratio)
    if not (num.free_symbols | den.free_symbols) & {xa, xb}:
        m = den * xa + num * xb
        why = "whose weights depend on other states the fault enters"
    else:
        # weights that depend on the two states: a balance m(xa, xb) the fault cannot move
        slope = sp.cancel(e[b] / e[a])            # dxb/dxa along the fault
        others = slope.free_symbols - {xa, xb} - set(model.p)
        m = None if others else first_integral(slope, xa, xb)
        if m is not None and _flat_at_op(model, m, (xa, xb)):
            # generic in the parameters, constant at their values (x**(1-k) at k = 1):
            # the integral of the direction at the values themselves
            values = {k: sp.nsimplify(float(v), rational=True)
                      for k, v in model.parameter_values.items()}
            m = first_integral(slope.xreplace(values), xa, xb)
            e = e.xreplace(values)
        why = (f"which depends on those states and on {', '.join(sorted(map(str, others)))}"
               if others else "which depends on those states, and no balance of the two "
               "in closed form cancels it")
        if m is not None and not _real_over_ranges(model, m, (a, b)):
            m, why = None, (f"which depends on those states; the balance {m} that cancels "
                            "it is not real over their declared ranges")
    if m is not None and _nonzero((jacobian([m], model.x) * e)[0]):
        m = None      # the fault also enters a state the weights read
    if m is None:
        return None, (f"{fault.name} enters {model.states[a].name} and "
                      f"{model.states[b].name} in the ratio {ratio}, {why}: fdigen "
                      "cancels a fault in a ratio of parameters and other signals, or in a "
                      "balance of two states it finds in closed form (a mass or an "
                      "energy, such as a level times a concentration)")
    return m, ""


def _flat_at_op(model: Model, m, pair) -> bool:
    """``m``'s gradient in the two states vanishes (or is not a number) at the operating
    point, parameters at their values."""
    from fdigen.derive.linearisation import numeric, operating_point_substitution

    try:
        g = numeric(sp.Matrix([m]).jacobian(sp.Matrix(pair)),
                    operating_point_substitution(model)).ravel()
    except (TypeError, ValueError, ZeroDivisionError):
        return True
    return not (np.all(np.isfinite(g)) and np.any(np.abs(g) > 0))


def _real_over_ranges(model: Model, m, pair) -> bool:
    """``m`` is finite and real on a grid over the two states' declared ranges (a
    power of a temperature difference is not, where the difference changes sign), and
    its denominator keeps one sign there (a pole between two grid points: attack round
    5's ``xb/(xa - 1.4)`` over [1, 2])."""
    from fdigen.derive.linearisation import operating_point_substitution
    from fdigen.safe_lambdify import safe_lambdify

    point = operating_point_substitution(model)
    grids = []
    for i in pair:
        st = model.states[i]
        x0 = point[st.symbol]
        lo, hi = (float(v) for v in st.range) if st.range else (x0, x0)
        grids.append((st.symbol, np.linspace(lo, hi, 41)))
    fixed = {k: v for k, v in point.items() if k not in {g[0] for g in grids}}
    den = sp.fraction(sp.together(m))[1]
    try:
        f = safe_lambdify([g[0] for g in grids], [m.xreplace(fixed), den.xreplace(fixed)],
                          "numpy")
        with np.errstate(all="ignore"):
            vals, dens = (np.asarray(np.broadcast_to(v, (41, 41)), dtype=complex) for v in
                          f(*np.meshgrid(*(g[1] for g in grids))))
    except Exception:  # noqa: BLE001 - a function numpy cannot print: no balance to run
        return False
    real = np.all(np.isfinite(vals)) and np.all(
        np.abs(vals.imag) <= 1e-12 * np.maximum(np.abs(vals.real), 1.0))
    one_sign = np.all(dens.real > 0) or np.all(dens.real < 0)
    if not (real and one_sign):
        return False
    return not _touches_zero(den.xreplace(fixed), grids, np.abs(dens.real))


def _touches_zero(den, grids, values) -> bool:
    """Whether ``den`` (of the two grid variables) reaches zero inside the box although
    it keeps one sign on the grid: a double pole between grid points (attack round 6:
    ``yb/(c - ya)**2`` with ``c = 1.4125`` over [1, 2] passed the sign test). A bounded
    local minimisation of ``log(den**2)`` from the grid point of smallest ``|den|``; zero
    means below 1e-6 of the largest ``|den|`` on the grid."""
    from scipy.optimize import minimize

    from fdigen.safe_lambdify import safe_lambdify

    syms = [g[0] for g in grids]
    if not den.free_symbols & set(syms):
        return False
    g = safe_lambdify(syms, den, "numpy")

    def sq(z):
        with np.errstate(all="ignore"):
            v = complex(g(*z)).real
        return v * v if np.isfinite(v) else 1e300

    k = np.unravel_index(int(np.argmin(values)), values.shape)
    mesh = np.meshgrid(*(gr[1] for gr in grids))
    start = [float(mg[k]) for mg in mesh]
    box = [(float(gr[1][0]), float(gr[1][-1])) for gr in grids]
    # on log(den**2): a double pole's den**2 is quartic, and flat enough near its zero for
    # the minimiser to stop 0.01 away from it
    res = minimize(lambda z: np.log(sq(z) + 1e-300), start, bounds=box, method="L-BFGS-B")
    return bool(np.sqrt(min(sq(res.x), sq(start))) <= 1e-6 * float(values.max()))


def decoupled_submodel(model: Model, fault: Fault, name: str):
    """The driven sub-model with the combined state ``m`` that ``fault`` does not enter.

    Returns ``(submodel, drivers, measured, predicted, initial)`` or ``None``.
    """
    found = decoupling_direction(model, fault)
    if found is None:
        return None
    idx, m_expr = found
    if m_expr.free_symbols & set(model.u) or m_expr.has(sp.Heaviside, sp.DiracDelta, sp.sign):
        # weights that switch with an input (max(V - Vnom, 0) read at its kink gave
        # Heaviside(V - Vnom)): no combination of the sensors alone (attack round 8)
        return None
    direct = measured_states(model)
    f = model.f(with_faults=True)
    m_sym = sp.Symbol(name, real=True)
    # dm/dt = grad(m) . f: the weights' own rates included (c_i x_i with c_i a signal)
    mdot = sp.cancel(sp.expand((jacobian([m_expr], model.x) * f)[0]))
    # states the combination still needs: keep unmeasured ones (closed under dependencies),
    # replace measured ones (and the two combined states) by their sensors
    state_names = [s.name for s in model.states]
    keep = []
    todo = [s.name for s in model.states
            if s.symbol in mdot.free_symbols and s.name not in direct]
    while todo:
        sname = todo.pop()
        if sname in keep:
            continue
        keep.append(sname)
        for sym in f[state_names.index(sname)].free_symbols:
            if sym.name in state_names and sym.name not in direct and sym.name not in keep:
                todo.append(sym.name)
    keep = [s for s in state_names if s in keep]
    # every measured state drives the sub-model through its sensor; an unmeasured state
    # neither the combination nor a kept state reads (a shaft twist whose torque the
    # combination cancels) is left out
    drivers = {}
    subs = {}
    for s in model.states:
        if s.name not in keep and s.name in direct:
            out = model.output(direct[s.name])
            drivers[s.name] = out.name
            subs[s.symbol] = state_from_sensor(model, s.name, out.name)
    dyn = [mdot.xreplace(subs)] + [f[state_names.index(k)].xreplace(subs) for k in keep]
    fault_syms = set(model.f_sym)
    states = [Variable(name, "", f"combination {m_expr} (blind to {fault.name})", None)]
    states += [s for s in model.states if s.name in keep]
    inputs = list(model.inputs) + [Variable(o, model.output(o).unit, f"measured {s}",
                                            driver_range(model, model.states[
                                                model.state_index(s)], o),
                                            model.output(o).column)
                                   for s, o in drivers.items()]
    dyn_nofault = [d.xreplace({s: 0 for s in fault_syms}) for d in dyn]
    outputs = [Output(f"{name}_meas", m_sym, "", f"{name} from the sensors", 0.0)]
    op = {s.name: model.operating_point[s.name] for s in model.states if s.name in keep}
    op.update({s.name: model.operating_point[s.name] for s in model.inputs})
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name] for s in (*model.states, *model.inputs)})
    h0 = numeric(model.h(), point).ravel()
    for s, o in drivers.items():
        op[o] = float(h0[model.output_index(o)])
    op[name] = float(numeric(sp.Matrix([m_expr]), point)[0, 0])
    sub = Model(name=f"{model.name}_{name}", states=tuple(states), inputs=tuple(inputs),
                outputs=tuple(outputs), parameters=model.parameters, definitions=(),
                dynamics=tuple(dyn_nofault), faults=(), operating_point=op,
                description=f"{fault.name}-decoupled combination of {model.name}",
                source=model.source)
    y_of = {s.symbol: state_from_sensor(model, s.name, direct[s.name]) for s in model.states
            if s.name in direct}
    measured = model.expand(m_expr).xreplace(y_of)
    initial = [model.expand(m_expr)] + [s.symbol for s in model.states if s.name in keep]
    # structural sensitivity of the combined equation to each fault (exact: symbolic terms)
    signature = {}
    used_outputs = {o.name for o in model.outputs if o.symbol in measured.free_symbols}
    used_outputs |= set(drivers.values())
    for flt in model.faults:
        if flt.location == "sensor":
            signature[flt.name] = bool(set(model.outputs_reached(flt)) & used_outputs)
        else:
            # a fault in a sensor's map the combination reads (a buck converter's load
            # step inside the output voltage through the capacitor's ESR) moves it too
            signature[flt.name] = bool(set(model.outputs_reached(flt)) & used_outputs) or any(
                sp.simplify(derivative(d, flt.symbol).xreplace({s: 0 for s in fault_syms}))
                != 0 for d in dyn)
    return sub, drivers, measured, m_sym, tuple(initial), signature


def parallel_residual(model: Model, fault: Fault, residual: str, process_noise: dict,
                      dt: float, realign_scale: float) -> ParallelResidual | None:
    """Design the decoupled residual for ``fault`` (see module docstring), or ``None``."""
    found = decoupled_submodel(model, fault, f"m_{fault.name}")
    if found is None:
        return None
    sub, drivers, measured, predicted, initial, signature = found
    # realignment gain: Kalman gain of the linearised sub-model measured by m
    lin = linearise(sub)
    disc = discretise_zoh(lin, dt)
    n = len(sub.states)
    names = [s.name for s in model.states]
    idx, m_expr = decoupling_direction(model, fault)
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name] for s in (*model.states, *model.inputs)})
    cn = numeric(jacobian([m_expr], [model.states[i].symbol for i in idx]), point).ravel()
    q_m = np.sqrt(sum((cn[k] * process_noise[names[idx[k]]]) ** 2 for k in range(2)))
    qs = [q_m] + [process_noise[s.name] for s in sub.states[1:]]
    Qd = discretise_noise(lin.A, np.diag(np.square(qs)), dt) * realign_scale ** 2
    grad = [float(v) for v in numeric(sp.Matrix([measured]).jacobian(
        sp.Matrix([o.symbol for o in model.outputs])), _output_point(model)).ravel()]
    var = sum((g * o.noise_std) ** 2 for g, o in zip(grad, model.outputs))
    C = np.zeros((1, n))
    C[0, 0] = 1.0
    gain = discrete_kalman_gain(disc.A, C, Qd + 1e-300 * np.eye(n), np.array([[var]]),
                                f"realignment of {residual}", state_scales(sub.states))
    return ParallelResidual(residual, sub, drivers, measured, predicted, gain.M,
                            fault.name, initial, signature)


def _output_point(model):
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name] for s in (*model.states, *model.inputs)})
    h0 = numeric(model.h(), point).ravel()
    point.update({o.symbol: h0[i] for i, o in enumerate(model.outputs)})
    return point
