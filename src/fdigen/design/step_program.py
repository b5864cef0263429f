"""The FDI step and initialisation as backend-neutral programs.

Holds :func:`build_programs`, which writes one sample of the FDI as named assignments
(measurement validity, the parity parallel models, the Kalman predictions, updates and
residuals, Broen's voter), and :func:`init_program`, the initial FDI state from the first
sample.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.derive.linearisation import numeric
from fdigen.design.derived_parameters import DerivedParameters
from fdigen.design.innovation_filter import filtered_kalman, innovation_alpha
from fdigen.design.measurements import validity_bound
from fdigen.design.nonlinear_prediction import (check_nonlinear_filter, nonlinear_prediction,
                                                reference_states, smoothed_dynamics)
from fdigen.design.parallel_model import parallel_block, parity_block_prefix
from fdigen.design.program import Program
from fdigen.design.scheduled_prediction import schedule_signals, scheduled_transition
from fdigen.design.static_relations import StaticRelation
from fdigen.design.submodel import direct_sensors, state_from_sensor
from fdigen.design.symbolic import double, doubles, real_symbol
from fdigen.model.expression import parse_expression


def block_inputs(kr, y_by_name) -> list:
    """The inputs of Kalman filter ``kr``'s model: the measured output that drives an
    input of a driven sub-model, the input's own symbol otherwise."""
    return [y_by_name[s.name] if s.name in kr.drivers.values() else real_symbol(s.name)
            for s in kr.model.inputs]


def reference_block(assign, model, cfg, realignment, kal, y_by_name, h_expr, gate, dt,
                    derived, held=None):
    """A parallel model re-aligned on every parity sensor, the nonlinear filters' reference.

    A Kalman filter with a nonlinear prediction rebuilds the states it does not estimate
    from a reference (:func:`~fdigen.design.nonlinear_prediction.reference_states`). With
    dedicated realignment (one parity model per sensor,
    :func:`~fdigen.design.parallel_model.parity_realignment`) no parity model tracks every
    state: the one re-aligned on the position lets the pressures run open loop, and on a
    real rig, whose plant the model only approximates, the reference drifts and so does
    the filter's residual (the rig's Coulomb log: R4's largest moving RMS 2.2 x its
    threshold with the position-only model, 0.43 x with this one). This block is the
    shared-realignment model (``M`` of :func:`~fdigen.design.parallel_model.
    realignment_gain` on every parity output, frozen with the others), kept only as a
    reference: its innovations are no residual.

    Returns
    -------
    (list of str, list, dict or None)
        Its state names and next states (empty when not needed: shared realignment, or no
        nonlinear filter), and ``state -> (symbol, sigma)`` for the reference, ``sigma =
        sqrt(P_ii)`` of its Riccati solution.
    """
    from fdigen.design.parallel_model import realignment_gain
    from fdigen.errors import DesignError

    if not any(kr.schedule == "nonlinear" for kr in kal):
        return [], [], None
    if len(realignment) == 1:
        gain = realignment[0][2]
        return [], [], None if gain is None else {
            s.name: (real_symbol(f"{parity_block_prefix(0, realignment[0][0])}_{s.name}"),
                     float(np.sqrt(gain.P[i, i]))) for i, s in enumerate(model.states)}
    try:
        M, gain = realignment_gain(model, cfg)
    except DesignError:
        return [], [], None
    if gain is None:            # realignment off (realign_noise_scale = 0): no estimate
        return [], [], None
    checks = [(f"ref_{rname}", y_by_name[oname], h_expr[model.output_index(oname)])
              for rname, oname in cfg.parity.items()]
    names, z_next = parallel_block(assign, model, REFERENCE_PREFIX, checks, M, gate, {}, dt,
                                   cfg.substeps, {}, derived, held, hold_samples(cfg))
    return names, z_next, {s.name: (real_symbol(f"{REFERENCE_PREFIX}_{s.name}"),
                                    float(np.sqrt(gain.P[i, i])))
                           for i, s in enumerate(model.states)}


def hold_samples(cfg) -> int:
    """Samples ``N_h`` of the exponential average of a block's correction (``a = 1/N_h``):
    ``[fdi] hold_windows`` RMS windows. A fault's first flag comes about a window after
    its onset, so the average held at the freeze carries about ``1/hold_windows`` of what
    the realignment absorbed of the fault; a longer average also follows the plant's
    balance more slowly (``docs/isolation.md``, section 13)."""
    return cfg.hold_windows * cfg.window


#: Name prefix of the reference parallel model's states (:func:`reference_block`).
REFERENCE_PREFIX = "parref"
#: A nonlinear prediction beyond this magnitude (or NaN) is outside the equations'
#: domain: the filter holds its updated estimate for that sample (a bound a C float
#: holds: the float variant of the core compares against it too).
FINITE_BOUND = 1e30


def build_programs(model, cfg, kal, realignment, names, parallel_blocks=()):
    """The step and init :class:`~fdigen.design.program.Program` of a design.

    ``realignment`` lists the parity parallel models as
    :func:`~fdigen.design.parallel_model.parity_realignment` returns them.

    Returns
    -------
    (Program, Program, tuple of str, tuple of str)
        The step, the initialisation, the FDI state names and the auxiliary output names.
    """
    dt = cfg.sample_time
    u = [s.symbol for s in model.inputs]
    y = [o.symbol for o in model.outputs]
    y_by_name = {o.name: o.symbol for o in model.outputs}
    p = list(model.p)
    freeze, accommodate = real_symbol("freeze"), real_symbol("accommodate")
    asg = []
    residual = {}
    aux = {}

    def assign(name, expr):
        s = real_symbol(name)
        asg.append((s, doubles(sp.sympify(expr))))
        return s

    derived = DerivedParameters(assign)

    # -- measurement validity: non-finite or absurd samples never reach the observers ------
    h_expr = model.h()
    raw_u = [real_symbol(f"{s.name}_raw") for s in model.inputs]
    raw_y = [real_symbol(f"{o.name}_raw") for o in model.outputs]
    # an invalid sample of y is replaced by the prediction of the parity model that checks
    # y (re-aligned on y alone), else of the first one: no residual reads another sensor
    block_of = {cfg.parity[r]: parity_block_prefix(k, rnames)
                for k, (rnames, _, _) in enumerate(realignment) for r in rnames}
    for s, raw in zip(model.inputs, raw_u):
        bound = double(validity_bound(model, s))
        assign(s.name, sp.Piecewise((raw, sp.Abs(raw) <= bound),
                                    (double(model.operating_point[s.name]), True)))
    for k, (o, raw) in enumerate(zip(model.outputs, raw_y)):
        bound = double(validity_bound(model, o))
        assign(o.name, sp.Piecewise((raw, sp.Abs(raw) <= bound),
                                    (h_expr[k].xreplace(
                                        {s.symbol: real_symbol(
                                            f"{block_of.get(o.name, 'par')}_{s.name}")
                                         for s in model.states}), True)))
        residual[f"nf_{o.name}"] = assign(f"r_nf_{o.name}", sp.Piecewise(
            (sp.Integer(0), sp.Abs(raw) <= bound), (sp.Integer(1), True)))

    # -- parity: parallel model -----------------------------------------------------------
    gate = assign("realign_gate", 1 - freeze)
    state_names, z_next = [], []
    # held corrections of the frozen blocks (parallel_block), after every other state
    held = [] if cfg.hold_windows else None
    for k, (rnames, realign_M, _) in enumerate(realignment):
        checks = [(rname, y_by_name[cfg.parity[rname]],
                   h_expr[model.output_index(cfg.parity[rname])]) for rname in rnames]
        names_b, next_b = parallel_block(assign, model, parity_block_prefix(k, rnames), checks,
                                         realign_M, gate, {}, dt, cfg.substeps, residual,
                                         derived, held, hold_samples(cfg))
        state_names += names_b
        z_next += next_b
    ref_names, ref_next, estimates = reference_block(assign, model, cfg, realignment, kal,
                                                     y_by_name, h_expr, gate, dt, derived,
                                                     held)
    state_names += ref_names
    z_next += ref_next
    for block in parallel_blocks:
        if isinstance(block, StaticRelation):
            # no state: the checked sensor against its map of the drivers' sensors
            residual[block.residual] = assign(f"r_{block.residual}",
                                              block.measured - block.predicted)
            continue
        drivers = {real_symbol(s.name): y_by_name[s.name] for s in block.model.inputs
                   if s.name in block.drivers.values()}
        checks = [(block.residual, block.measured, block.predicted)]
        names_b, next_b = parallel_block(assign, block.model, block.residual, checks,
                                          block.realign_gain, gate, drivers, dt,
                                          cfg.substeps, residual, derived, held, hold_samples(cfg))
        state_names += names_b
        z_next += next_b

    # -- Kalman filters: predictions ------------------------------------------------------
    kal_state = {}
    innovation, lowpass = {}, []     # filtered derived residuals (innovation_filter)
    for kr in kal:
        zn = [f"{kr.residual}_{n}" for n in kr.reduction.z_names]
        state_names.extend(zn)
        zs = [real_symbol(n) for n in zn]
        kal_state[kr.residual] = zs
        yhat = double(kr.m0[0]) + sum((double(kr.discrete.C[0, j]) * (zs[j] - double(kr.z0[j]))
                                   for j in range(len(zs)) if kr.discrete.C[0, j] != 0),
                                  sp.Integer(0))
        # an input measured directly (the feedthrough D_r of a terminal voltage's R0 I)
        yhat += sum((double(kr.discrete.D[0, j]) * (u - double(kr.discrete.u0[j]))
                     for j, u in enumerate(block_inputs(kr, y_by_name))
                     if kr.discrete.D[0, j] != 0), sp.Integer(0))
        aux[f"yhat_{kr.residual}"] = assign(f"yhat_{kr.residual}", yhat)
        m = parse_expression(kr.measurement[0], y_by_name, source=model.source, field="fdi")
        if filtered_kalman(cfg, kr.residual):
            # the raw innovation updates the filter; its low-pass is the residual
            alpha = innovation_alpha(cfg.innovation_filter, dt)
            lp = real_symbol(f"{kr.residual}_lp")
            innovation[kr.residual] = assign(f"e_{kr.residual}",
                                             m - aux[f"yhat_{kr.residual}"])
            residual[kr.residual] = assign(f"r_{kr.residual}",
                                           double(alpha) * lp
                                           + double(1 - alpha) * innovation[kr.residual])
            lowpass.append((lp.name, residual[kr.residual]))
        else:
            residual[kr.residual] = assign(f"r_{kr.residual}", m - aux[f"yhat_{kr.residual}"])

    # -- voter ----------------------------------------------------------------------------
    fused = None
    vout = None
    if cfg.voter:
        chan = []
        for c in cfg.voter.channels:
            chan.append(y_by_name[c] if c in y_by_name else aux[f"yhat_{c}"])
        a = double(cfg.voter.tolerance)
        d = {}
        for i, j in ((0, 1), (0, 2), (1, 2)):
            d[(i, j)] = assign(f"vd{i + 1}{j + 1}", ((chan[i] - chan[j]) / a) ** 2)
        w = [assign("vw1", 1 / (1 + d[(0, 1)] * d[(0, 2)])),
             assign("vw2", 1 / (1 + d[(0, 1)] * d[(1, 2)])),
             assign("vw3", 1 / (1 + d[(0, 2)] * d[(1, 2)]))]
        vout = None
        wsum = assign("vw_sum", w[0] + w[1] + w[2])
        winv = assign("vw_inv", 1 / wsum)     # one division for the four normalisations
        for j, name in enumerate(cfg.voter.names):
            # inverted normalised weight: 0 while the channel has its equal share 1/3 or
            # more, 1 when its normalised weight vanishes
            residual[name] = assign(f"r_{name}", sp.Max(1 - 3 * w[j] * winv, 0))
        vout = assign("voter_out", (w[0] * chan[0] + w[1] * chan[1] + w[2] * chan[2]) * winv)
        sensors = [j for j, c in enumerate(cfg.voter.channels) if c in y_by_name]
        fused = assign("voter_fused", sum(w[j] * chan[j] for j in sensors)
                       / sum(w[j] for j in sensors))
        primary = chan[2]
        aux["voter_out"] = vout
        aux["position_for_control"] = assign(
            "position_for_control", accommodate * vout + (1 - accommodate) * primary)

    # -- Kalman filters: update and prediction --------------------------------------------
    signals, shared, references = None, {}, None
    if any(kr.schedule in ("measured", "nonlinear") for kr in kal):
        signals = schedule_signals(assign, model, cfg, y_by_name, vout)
    if any(kr.schedule == "nonlinear" for kr in kal):
        references = reference_states(model, cfg, signals, estimates)
    for kr in kal:
        zs = kal_state[kr.residual]
        if kr.update == "voter":
            e_u = assign(f"eu_{kr.residual}", fused - aux[f"yhat_{kr.residual}"])
        else:
            e_u = innovation.get(kr.residual, residual[kr.residual])
        zplus = [assign(f"{kr.residual}_post{j}", zs[j] + double(kr.gain.M[j, 0]) * e_u)
                 for j in range(len(zs))]
        u_block = block_inputs(kr, y_by_name)
        if kr.schedule == "nonlinear":
            f_kr = smoothed_dynamics(kr, references, dt / cfg.substeps)
            sub = check_nonlinear_filter(kr, references, f_kr, dt, cfg.substeps)
            pred = nonlinear_prediction(assign, kr, references, f_kr, u_block, zplus, dt,
                                        sub, derived)
            # a prediction that leaves the equations' domain (a driver's glitch under a
            # sqrt: NaN for the rest of the run, said nowhere; attack 12) holds the
            # updated estimate for that sample, and the filter recovers with the reading
            z_next.extend(assign(f"{kr.residual}_nl_next{k}", sp.Piecewise(
                (z, sp.Abs(z) <= double(FINITE_BOUND)), (zplus[k], True)))
                for k, z in enumerate(pred))
            continue
        if kr.schedule == "measured":
            Ad, Bd = scheduled_transition(assign, kr, signals, dt, shared)
        else:
            Ad = sp.Matrix(kr.discrete.A).applyfunc(double)
            Bd = sp.Matrix(kr.discrete.B).applyfunc(double)
        for i in range(len(zs)):
            expr = double(kr.z0[i])
            expr += sum((Ad[i, j] * (zplus[j] - double(kr.z0[j])) for j in range(len(zs))
                         if Ad[i, j] != 0), sp.Integer(0))
            expr += sum((Bd[i, j] * (u_block[j] - double(kr.discrete.u0[j]))
                         for j in range(len(u_block)) if Bd[i, j] != 0), sp.Integer(0))
            z_next.append(assign(f"{kr.residual}_next{i}", expr))

    for name, nxt in (*lowpass, *(held or ())):
        state_names.append(name)
        z_next.append(nxt)
    inputs = {"z": tuple(real_symbol(n) for n in state_names), "u": tuple(raw_u), "y": tuple(raw_y),
              "p": tuple(p), "mode": (freeze, accommodate)}
    aux_names = tuple(k for k in ("voter_out", "position_for_control") if k in aux)
    step = Program(inputs, tuple(asg), {"z_next": tuple(z_next),
                                        "r": tuple(residual[n] for n in names),
                                        "aux": tuple(aux[k] for k in aux_names)})
    step.check_closed()
    step.check_unique_names(model.source)
    init = init_program(model, cfg, kal, parallel_blocks, state_names,
                        len(realignment) + (1 if ref_names else 0),
                        len(lowpass) + len(held or ()))
    return step, init, tuple(state_names), aux_names


def init_program(model, cfg, kal, parallel_blocks, state_names, parity_models=1,
                 zero_states=0):
    """Initial FDI state from the first sample: measured states from their sensors,
    the others at the operating point (every one of the ``parity_models`` parity parallel
    models starts there); Kalman states ``z = T x``; the last ``zero_states`` (innovation
    low-passes, held corrections) at 0. An invalid first sample (non-finite or absurd) is
    replaced by the output at the operating point."""
    raw_u = [real_symbol(f"{s.name}_raw") for s in model.inputs]
    raw_y = [real_symbol(f"{o.name}_raw") for o in model.outputs]
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name] for s in (*model.states, *model.inputs)})
    h0 = numeric(model.h(), point).ravel()
    asg = []
    for k, (o, raw) in enumerate(zip(model.outputs, raw_y)):
        bound = double(validity_bound(model, o))
        asg.append((o.symbol, sp.Piecewise((raw, sp.Abs(raw) <= bound), (double(h0[k]), True))))
    y_by_name = {o.name: o.symbol for o in model.outputs}
    x0 = []
    for s in model.states:
        sensors = direct_sensors(model).get(s.name, [])
        prefer = [o for o in cfg.parity.values() if o in sensors] or sensors[:1]
        if prefer:
            x0.append(state_from_sensor(model, s.name, prefer[0]))
        else:
            x0.append(double(model.operating_point[s.name]))
    z = list(x0) * parity_models
    full = {s.name: x0[i] for i, s in enumerate(model.states)}
    for block in parallel_blocks:
        z.extend(block.initial(full, y_by_name))
    for kr in kal:
        xs = [full[s.name] for s in kr.model.states]
        T = kr.reduction.T_num
        for i in range(T.shape[0]):
            # a reduction read at the operating point (a kink's switch there, max(V - Vnom,
            # 0) at V = Vnom, left Heaviside(V - Vnom) in it: attack round 8)
            z.append(sum((double(sp.sympify(T[i, j]).xreplace(point)) * xs[j]
                          for j in range(len(xs)) if T[i, j] != 0), sp.Integer(0)))
    z.extend([sp.Integer(0)] * zero_states)     # no innovation yet, no correction held
    # the inputs an initial state reads (a sensor map of a state over others and the
    # inputs: an accelerometer's, with the road grade), as the step reads them
    read = set().union(*(sp.sympify(e).free_symbols for e in z)) if z else set()
    asg[:0] = [(s.symbol, sp.Piecewise((raw, sp.Abs(raw) <= double(validity_bound(model, s))),
                                       (double(model.operating_point[s.name]), True)))
               for s, raw in zip(model.inputs, raw_u) if s.symbol in read]
    inputs = {"u": tuple(raw_u), "y": tuple(raw_y), "p": tuple(model.p)}
    prog = Program(inputs, tuple(asg), {"z0": tuple(z)})
    prog.check_closed()
    prog.check_unique_names(model.source)
    return prog
