"""The backend-neutral FDI design: one step of residual generation, evaluation, isolation.

``fdi_design(model)`` derives, from the model written once:

* parity residuals R1..R3 (eqs 8-10): measured output minus the output of a nonlinear
  parallel model (RK4) driven by the measured input, re-aligned on the measurements through
  a low-gain steady-state Kalman correction while no flag is raised;
* dedicated Kalman residuals R4, R5 (eqs 13-17) on the observable reduction (eq 15) of the
  linearised model for each measurement set;
* Broen's voter (eqs 18-21, with the corrected ``w1``) over the Kalman estimate and the
  sensors, whose inverted weights ``1 - w_j`` are residuals;
* further residuals found from the model's structure (driven sub-models) that make fault
  classes isolable where the paper's residuals cannot;
* moving-window RMS (eq 22), thresholds, latched flags, the signature table (Table 1) and
  the isolation logic with an action per class.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import sympy as sp

from fdigen.derive.kalman import KalmanGain, discrete_kalman_gain
from fdigen.derive.linearisation import (discretise_noise, discretise_zoh, linearise, numeric,
                                         operating_point_substitution, symbolic_jacobians)
from fdigen.design.config import ACTIONS, FdiConfig, read_fdi_config
from fdigen.design.observers import KalmanResidual, kalman_residual
from fdigen.design.program import Program
from fdigen.design.decoupling import parallel_residual
from fdigen.design.signatures import (candidate_residuals, decoupling_candidates,
                                      select_extra_residuals, structural_signature,
                                      unresolved_pairs)
from fdigen.design.submodel import direct_measurements, direct_sensors, driven_submodel
from fdigen.errors import DesignError
from fdigen.model.expression import parse_expression
from fdigen.model.model import Model


def _f(value) -> sp.Float:
    """A double as a sympy Float that prints back to the same double."""
    return sp.Float(float(value), 17)


def _doubles(expr):
    """``expr`` with every floating constant rounded to the nearest double.

    Constants that sympy folds (``h * A0``...) carry more bits than a double; each
    backend would round them on its own (the numpy printer's decimal string, the C
    printer's 17 digits, CasADi's ``float``) and the results could differ in the last
    place. Rounded here, every backend reads the same double.
    """
    return expr.xreplace({c: _f(float(c)) for c in expr.atoms(sp.Float)})


def _sym(name: str) -> sp.Symbol:
    return sp.Symbol(name, real=True)


@dataclass(frozen=True)
class Evaluation:
    """Residual evaluation and isolation, identical in every backend.

    Per sample ``k`` and residual ``i`` (eq 22 with a running sum, O(1) per sample):

    .. math::

        S_i[k] = S_i[k-1] + r_i[k]^2 - r_i[k-N]^2,\\quad
        \\mathrm{RMS}_i[k] = \\sqrt{\\max(S_i[k], 0)/N},\\quad
        \\mathrm{flag}_i[k] = \\mathrm{flag}_i[k-1] \\lor (\\mathrm{RMS}_i[k] > J_i)

    The latched flags form a bit mask ``F``. A fault with signature mask ``S`` is
    *consistent* with the flags when every raised flag is in its signature,
    ``F & ~S == 0`` (flags rise one after another, so a signature is matched while it
    builds up). When ``F != 0`` and every consistent fault belongs to one class, that class
    is the candidate; when it stays the candidate for ``confirm`` consecutive samples it is
    isolated and latched. ``patterns`` holds ``(S, class)`` for every declared fault.
    """

    residuals: tuple[str, ...]
    window: int
    thresholds: np.ndarray
    confirm: int
    classes: tuple[str, ...]          # index 0 is "none"
    actions: tuple[str, ...]          # per class
    patterns: tuple[tuple[int, int], ...]  # (flag mask, class index)
    action_codes: tuple[int, ...] = field(default=())

    def __post_init__(self):
        object.__setattr__(self, "action_codes",
                           tuple(ACTIONS.index(a) for a in self.actions))


@dataclass(frozen=True)
class FdiDesign:
    """Everything a backend needs to emit the FDI step, and the derivations behind it."""

    model: Model
    config: FdiConfig
    step: Program
    init: Program
    evaluation: Evaluation
    residual_names: tuple[str, ...]
    state_names: tuple[str, ...]
    aux_names: tuple[str, ...]
    kalman: tuple[KalmanResidual, ...]
    realign_gain: np.ndarray
    realign: KalmanGain | None
    signature_table: dict          # fault -> set of residuals
    paper_residuals: tuple[str, ...]
    extra_residuals: tuple[dict, ...]
    unresolved_within_class: tuple
    unresolved_across_classes: tuple

    @property
    def name(self) -> str:
        return self.model.name


def fdi_design(model: Model) -> FdiDesign:
    """Derive the complete FDI design of a model (pure: returns a new object).

    Raises
    ------
    ModelFileError, DesignError
        On a bad configuration, or a design that cannot be built (not detectable...).
    """
    cfg = read_fdi_config(model)
    dt = cfg.sample_time
    outputs = {o.name: o for o in model.outputs}
    y_syms = {o.name: o.symbol for o in model.outputs}
    faults = [f.name for f in model.faults]
    classes_of = {f.name: f.fault_class for f in model.faults}

    # -- realignment gain of the parallel model ------------------------------------------
    check_parallel_model_step(model, cfg)
    realign_gain, realign = _realign_gain(model, cfg)

    # -- Kalman filters: paper's, then structural extras --------------------------------
    kal = []
    table = {f: set() for f in faults}
    for spec in cfg.kalman:
        meas = (spec.measurement,)
        fused = 1
        if spec.update == "voter":
            if cfg.voter is None or spec.residual not in cfg.voter.channels:
                raise DesignError(f"Kalman filter {spec.residual} is updated by the voter "
                                  "but is not one of its channels")
            fused = sum(1 for c in cfg.voter.channels if c in outputs)
        kal.append(kalman_residual(model, spec.residual, meas, cfg.process_noise, dt,
                                   update=spec.update, fused=fused, schedule=spec.schedule))
        sig = structural_signature(model, meas, faults)
        if spec.update == "voter":
            # the update is protected by the voter; only the compared sensor acts directly
            meas_outputs = _outputs_in(model, spec.measurement)
            for f in model.faults:
                if f.location == "sensor" and f.target not in meas_outputs:
                    sig[f.name] = False
        for f, hit in sig.items():
            if hit:
                table[f].add(spec.residual)
    for rname, oname in cfg.parity.items():
        for f, hit in structural_signature(model, (oname,), faults).items():
            if hit:
                table[f].add(rname)
    if cfg.voter:
        for j, ch in enumerate(cfg.voter.channels):
            exclusive = _voter_channel_faults(model, cfg, ch)
            for f in exclusive:
                table[f].add(cfg.voter.names[j])

    paper = tuple(list(cfg.parity) + [k.residual for k in cfg.kalman]
                  + (list(cfg.voter.names) if cfg.voter else []))
    extras = []
    blocks = []
    if cfg.extra_residuals:
        cands = candidate_residuals(model, faults)
        chosen, _ = select_extra_residuals(table, classes_of, cands, across_classes=True)
        index = 1 + max([int(n[1:]) for n in paper if n[:1] == "R" and n[1:].isdigit()] or [0])
        index = _add_extras(model, cfg, chosen, index, table, kal, blocks, extras, "classes")
        if cfg.isolate_within_classes:
            # within a class, only residuals blind to a fault by construction: linear
            # sub-model filters separate faults of one class structurally but not
            # numerically (their linearisation error is as large as the faults' effect)
            chosen, _ = select_extra_residuals(table, classes_of,
                                               decoupling_candidates(model, faults),
                                               across_classes=False,
                                               limit=cfg.isolate_within_classes)
            _add_extras(model, cfg, chosen, index, table, kal, blocks, extras, "faults")
    validity = tuple(f"nf_{o.name}" for o in model.outputs)
    for f in model.faults:
        if f.location == "sensor":
            table[f.name].add(f"nf_{f.target}")
    names = paper + tuple(e["residual"] for e in extras) + validity
    order = {e["residual"]: k for k, e in enumerate(extras)}
    kal.sort(key=lambda k: order.get(k.residual, -1))
    within = tuple(unresolved_pairs(table, classes_of, across_classes=False))
    across = tuple(unresolved_pairs(table, classes_of, across_classes=True))


    step, init, state_names, aux_names = _build_programs(model, cfg, kal, realign_gain, names,
                                                         tuple(blocks))
    evaluation = _evaluation(model, cfg, names, table)
    return FdiDesign(model, cfg, step, init, evaluation, names, state_names, aux_names,
                     tuple(kal), realign_gain, realign, {f: table[f] for f in faults}, paper,
                     tuple(extras), within, across)


def rk4_amplification(z):
    """Amplification of one classical Runge-Kutta step on ``dx/dt = lambda x``, ``z = lambda h``.

    .. math:: R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24
    """
    return 1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24


def check_parallel_model_step(model: Model, cfg: FdiConfig) -> None:
    """Refuse a design whose RK4 parallel model is numerically unstable at its step.

    The linearisation's eigenvalues ``lambda`` are evaluated at the operating point and at
    each end of every state's declared ``range`` (one state at a time); with
    ``h = sample_time / substeps`` every mode must satisfy
    ``|R(lambda h)| <= max(1, |e^{lambda h}|)`` (:func:`rk4_amplification`), i.e. RK4 may
    not amplify a mode the plant damps. A stiff model (small mass, small dead volume...)
    at a long step otherwise makes the parallel model, and every residual, diverge.

    Raises
    ------
    DesignError
        Naming the mode, the point and the number of sub-steps that would be stable.
    """
    h = cfg.sample_time / cfg.substeps
    points = [{}]
    for s in model.states:
        if s.range:
            points += [{s.name: float(s.range[0])}, {s.name: float(s.range[1])}]
    jac_A = symbolic_jacobians(model).A          # derived once, evaluated at every point
    worst = None
    for point in points:
        try:
            A = numeric(jac_A, operating_point_substitution(model, point))
        except (TypeError, ValueError):   # complex or infinite (zoo) there
            continue
        if not np.all(np.isfinite(A)):
            continue              # not finite there (a range end on a singularity)
        for lam in np.linalg.eigvals(A):
            excess = abs(rk4_amplification(lam * h)) - max(1.0, abs(np.exp(lam * h)))
            if excess > 1e-9 and (worst is None or abs(lam) > abs(worst[0])):
                worst = (lam, point)
    if worst is None:
        return
    lam, point = worst
    need = cfg.substeps
    while need < 100000:
        need += 1
        z = lam * cfg.sample_time / need
        if abs(rk4_amplification(z)) <= max(1.0, abs(np.exp(z))) + 1e-9:
            break
    where = "the operating point" if not point else \
        "the operating point with " + ", ".join(f"{k} = {v:g}" for k, v in point.items())
    raise DesignError(
        f"{model.source}: fdi.substeps: the RK4 parallel model is unstable at step "
        f"{h:g} s: the linearised mode {complex(lam):.4g} 1/s at {where} gives "
        f"|R(lambda h)| = {abs(rk4_amplification(lam * h)):.3g} > 1; "
        f"use substeps >= {need} (or a shorter sample_time), or check the parameters")


def _add_extras(model, cfg, chosen, index, table, kal, blocks, extras, purpose):
    """Design the chosen candidate residuals (Kalman filters or decoupled parallel models)."""
    direct_noise = {o.name: o.noise_std for o in model.outputs}
    for cand in chosen:
        rname = f"R{index}"
        index += 1
        if rname not in cfg.thresholds:
            raise DesignError(f"derived residual {rname} ({cand.label}) needs a threshold: "
                              f"add '{rname} = ...' to [fdi.thresholds]")
        if cand.decoupled:
            blocks.append(parallel_residual(model, model.fault(cand.decoupled), rname,
                                            cfg.process_noise, cfg.sample_time,
                                            max(cfg.realign_noise_scale, 1e-6)))
        else:
            sub = driven_submodel(model, cand.keep, cand.drivers)
            noise = {o: direct_noise[o] for o in cand.drivers.values()}
            kal.append(kalman_residual(sub, rname, (cand.check,), cfg.process_noise,
                                       cfg.sample_time, drivers=cand.drivers,
                                       driver_noise=noise))
        for f, hit in cand.signature.items():
            if hit:
                table[f].add(rname)
        extras.append({"residual": rname, "equations": list(cand.keep),
                       "drivers": dict(cand.drivers), "check": cand.check,
                       "purpose": f"isolate {purpose}", "blind_to": cand.decoupled or None,
                       "description": cand.label})
    return index


def _outputs_in(model: Model, text: str) -> set:
    outs = {o.name: o.symbol for o in model.outputs}
    expr = parse_expression(text, outs, source=model.source, field="fdi")
    return {s.name for s in expr.free_symbols}


def _voter_channel_faults(model: Model, cfg: FdiConfig, channel: str) -> list:
    """Sensor faults that corrupt this voter channel and no other."""
    used = {}
    for ch in cfg.voter.channels:
        if ch in {o.name for o in model.outputs}:
            used[ch] = {ch}
        else:
            spec = next(k for k in cfg.kalman if k.residual == ch)
            used[ch] = set() if spec.update == "voter" else _outputs_in(model, spec.measurement)
    others = set().union(*(used[c] for c in cfg.voter.channels if c != channel))
    return [f.name for f in model.faults
            if f.location == "sensor" and f.target in used[channel] and f.target not in others]


def _realign_gain(model: Model, cfg: FdiConfig):
    """Filter gain ``M`` re-aligning the parallel model on the parity outputs.

    A steady-state Kalman gain of the full linearised model measured by the parity
    outputs, with process noise ``eps^2 Q`` (``eps = realign_noise_scale``): a low
    bandwidth that removes slow drift (the adiabatic model's common-mode pressure, valve
    and friction tolerances) while faults, much faster, still show in the residuals.
    """
    n, p = len(model.states), len(cfg.parity)
    if cfg.realign_noise_scale == 0 or p == 0:
        return np.zeros((n, p)), None
    lin = linearise(model)
    idx = [model.output_index(o) for o in cfg.parity.values()]
    disc = discretise_zoh(lin, cfg.sample_time)
    C = lin.C[idx, :]
    Qc = np.diag([cfg.process_noise[s.name] ** 2 for s in model.states])
    Qd = discretise_noise(lin.A, Qc, cfg.sample_time) * cfg.realign_noise_scale ** 2
    Rd = np.diag([model.outputs[i].noise_std ** 2 for i in idx])
    gain = discrete_kalman_gain(disc.A, C, Qd, Rd, "parallel model realignment")
    return gain.M, gain


def _parallel_block(assign, model, prefix, checks, realign_M, gate, drivers, dt, substeps,
                    residual, derived):
    """A nonlinear parallel model (RK4) of ``model``, compared with measurements.

    ``checks`` lists ``(residual name, measured expression, predicted expression of the
    model's states)``; the residuals are ``measured - predicted`` before the update. The
    state is re-aligned by ``x += gate * M r`` and then propagated by RK4 sub-steps with
    the inputs (and the measured ``drivers``) held, and clamped to its physical limits.
    Each state derivative is evaluated in the form of :func:`rational_form` (one division
    per derivative, parameter-only coefficients from ``derived``).
    Returns the state names and the next-state symbols.
    """
    xs = [_sym(f"{prefix}_{s.name}") for s in model.states]
    state_syms = list(model.x)
    to_block = dict(zip(state_syms, xs))
    to_block.update(drivers)
    res = []
    for rname, measured, predicted in checks:
        res.append(assign(f"r_{rname}", measured - predicted.xreplace(to_block)))
        residual[rname] = res[-1]
    xc = list(xs)
    if np.any(realign_M):
        for i in range(len(xs)):
            corr = sum((_f(realign_M[i, j]) * res[j] for j in range(len(res))
                        if realign_M[i, j] != 0), sp.Integer(0))
            if corr != 0:
                xc[i] = assign(f"{prefix}c_{model.states[i].name}", xs[i] + gate * corr)
    f_expr = [rational_form(e, set(model.p), derived) for e in model.f().xreplace(drivers)]
    h = dt / substeps
    for step in range(substeps):
        xc = _rk4(assign, f_expr, state_syms, xc, h, f"{prefix}{step}_", model)
        xc = _limit(assign, xc, model, f"{prefix}{step}_lim_")
    return [f"{prefix}_{s.name}" for s in model.states], list(xc)


def _build_programs(model, cfg, kal, realign_M, names, parallel_blocks=()):
    dt = cfg.sample_time
    u = [s.symbol for s in model.inputs]
    y = [o.symbol for o in model.outputs]
    y_by_name = {o.name: o.symbol for o in model.outputs}
    p = list(model.p)
    freeze, accommodate = _sym("freeze"), _sym("accommodate")
    asg = []
    residual = {}
    aux = {}

    def assign(name, expr):
        s = _sym(name)
        asg.append((s, _doubles(sp.sympify(expr))))
        return s

    derived = DerivedParameters(assign)

    # -- measurement validity: non-finite or absurd samples never reach the observers ------
    h_expr = model.h()
    raw_u = [_sym(f"{s.name}_raw") for s in model.inputs]
    raw_y = [_sym(f"{o.name}_raw") for o in model.outputs]
    par_of = {s.symbol: _sym(f"par_{s.name}") for s in model.states}
    for s, raw in zip(model.inputs, raw_u):
        bound = _f(validity_bound(model, s))
        assign(s.name, sp.Piecewise((raw, sp.Abs(raw) <= bound),
                                    (_f(model.operating_point[s.name]), True)))
    for k, (o, raw) in enumerate(zip(model.outputs, raw_y)):
        bound = _f(validity_bound(model, o))
        assign(o.name, sp.Piecewise((raw, sp.Abs(raw) <= bound),
                                    (h_expr[k].xreplace(par_of), True)))
        residual[f"nf_{o.name}"] = assign(f"r_nf_{o.name}", sp.Piecewise(
            (sp.Integer(0), sp.Abs(raw) <= bound), (sp.Integer(1), True)))

    # -- parity: parallel model -----------------------------------------------------------
    gate = assign("realign_gate", 1 - freeze)
    checks = [(rname, y_by_name[oname], h_expr[model.output_index(oname)])
              for rname, oname in cfg.parity.items()]
    state_names, z_next = _parallel_block(assign, model, "par", checks, realign_M, gate, {},
                                          dt, cfg.substeps, residual, derived)
    for block in parallel_blocks:
        drivers = {_sym(s.name): y_by_name[s.name] for s in block.model.inputs
                   if s.name in block.drivers.values()}
        checks = [(block.residual, block.measured, block.predicted)]
        names_b, next_b = _parallel_block(assign, block.model, block.residual, checks,
                                          block.realign_gain, gate, drivers, dt,
                                          cfg.substeps, residual, derived)
        state_names += names_b
        z_next += next_b

    # -- Kalman filters: predictions ------------------------------------------------------
    kal_state = {}
    for kr in kal:
        zn = [f"{kr.residual}_{n}" for n in kr.reduction.z_names]
        state_names.extend(zn)
        zs = [_sym(n) for n in zn]
        kal_state[kr.residual] = zs
        yhat = _f(kr.m0[0]) + sum((_f(kr.discrete.C[0, j]) * (zs[j] - _f(kr.z0[j]))
                                   for j in range(len(zs)) if kr.discrete.C[0, j] != 0),
                                  sp.Integer(0))
        aux[f"yhat_{kr.residual}"] = assign(f"yhat_{kr.residual}", yhat)
        m = parse_expression(kr.measurement[0], y_by_name, source=model.source, field="fdi")
        residual[kr.residual] = assign(f"r_{kr.residual}", m - aux[f"yhat_{kr.residual}"])

    # -- voter ----------------------------------------------------------------------------
    fused = None
    vout = None
    if cfg.voter:
        chan = []
        for c in cfg.voter.channels:
            chan.append(y_by_name[c] if c in y_by_name else aux[f"yhat_{c}"])
        a = _f(cfg.voter.tolerance)
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
    signals, shared = None, {}
    if any(kr.schedule == "measured" for kr in kal):
        signals = schedule_signals(assign, model, cfg, y_by_name, vout)
    for kr in kal:
        zs = kal_state[kr.residual]
        if kr.update == "voter":
            e_u = assign(f"eu_{kr.residual}", fused - aux[f"yhat_{kr.residual}"])
        else:
            e_u = residual[kr.residual]
        zplus = [assign(f"{kr.residual}_post{j}", zs[j] + _f(kr.gain.M[j, 0]) * e_u)
                 for j in range(len(zs))]
        u_block = []
        for s in kr.model.inputs:
            u_block.append(y_by_name[s.name] if s.name in kr.drivers.values()
                           else _sym(s.name))
        if kr.schedule == "measured":
            Ad, Bd = scheduled_transition(assign, kr, signals, dt, shared)
        else:
            Ad = sp.Matrix(kr.discrete.A).applyfunc(_f)
            Bd = sp.Matrix(kr.discrete.B).applyfunc(_f)
        for i in range(len(zs)):
            expr = _f(kr.z0[i])
            expr += sum((Ad[i, j] * (zplus[j] - _f(kr.z0[j])) for j in range(len(zs))
                         if Ad[i, j] != 0), sp.Integer(0))
            expr += sum((Bd[i, j] * (u_block[j] - _f(kr.discrete.u0[j]))
                         for j in range(len(u_block)) if Bd[i, j] != 0), sp.Integer(0))
            z_next.append(assign(f"{kr.residual}_next{i}", expr))

    inputs = {"z": tuple(_sym(n) for n in state_names), "u": tuple(raw_u), "y": tuple(raw_y),
              "p": tuple(p), "mode": (freeze, accommodate)}
    aux_names = tuple(k for k in ("voter_out", "position_for_control") if k in aux)
    step = Program(inputs, tuple(asg), {"z_next": tuple(z_next),
                                        "r": tuple(residual[n] for n in names),
                                        "aux": tuple(aux[k] for k in aux_names)})
    step.check_closed()
    init = _init_program(model, cfg, kal, parallel_blocks, state_names)
    return step, init, tuple(state_names), aux_names


def schedule_signals(assign, model: Model, cfg: FdiConfig, y_by_name: dict, voter_out) -> dict:
    """The measured value of each state, for scheduled Kalman predictions.

    A state measured directly by a sensor compared in the voter takes the voter's output
    (which a faulty or lost sensor cannot drag away), another directly measured state its
    (validated) sensor; either is clamped to the state's physical limits. States measured
    by no sensor are absent (their entries stay at the operating point).

    Returns
    -------
    dict of str to (sympy.Symbol, frozenset of str or None)
        State name -> (symbol of the assignment ``sched_<state>``, the sensor it reads, or
        ``None`` for the voter, which no single sensor fault drags away).
    """
    direct = direct_sensors(model)
    voted = set(cfg.voter.channels) if cfg.voter else set()
    out = {}
    for s in model.states:
        sensors = direct.get(s.name, [])
        if not sensors:
            continue
        if voter_out is not None and voted & set(sensors):
            value, reads = voter_out, None
        else:
            value, reads = y_by_name[sensors[0]], frozenset([sensors[0]])
        if s.limits is not None:
            value = sp.Min(sp.Max(value, s.limits[0]), s.limits[1])
        out[s.name] = (assign(f"sched_{s.name}", value), reads)
    return out


def scheduled_transition(assign, kr: KalmanResidual, signals: dict, dt: float,
                         shared: dict | None = None):
    r"""Discrete prediction matrices of a Kalman filter re-evaluated at the measured state.

    The reduced Jacobians ``A_r(s)``, ``B_r(s)`` (symbolic in the states left free by the
    symbolic operating point) are evaluated at the measured states ``s`` and the
    zero-order-hold matrices of the operating point corrected to second order:

    .. math::

        A_d(s) = A_{d,0} + h\,(A_r(s) - A_{r,0}) + \tfrac{h^2}{2}\,(A_r(s)^2 - A_{r,0}^2),

        B_d(s) = B_{d,0} + h\,(B_r(s) - B_{r,0})
                 + \tfrac{h^2}{2}\,(A_r(s) B_r(s) - A_{r,0} B_{r,0})

    exact at the operating point (``A_d(s_0) = A_{d,0} = e^{A_{r,0} h}``), and the Taylor
    expansion of ``e^{A_r(s) h}`` to the same order elsewhere. The gain stays the
    steady-state gain of the operating point. For the pneumatic cylinder the chamber
    stiffness ``A gamma (P_p/V_p + P_n/V_n)`` and the valve gain ``K R T_s gamma
    (1/V_p + 1/V_n)`` vary by tens of per cent over the stroke; a filter fixed at
    mid-stroke mistakes that for a fault near the end stops.

    A filter is scheduled only on the voter and on the sensors its own measurement reads
    (``signals``, see :func:`schedule_signals`), so scheduling adds no sensor fault to its
    signature: the cylinder's position filter R4 follows the voted position only, the
    pressure filter R5 the measured pressures and the voted position. Other states stay
    at their operating values.

    Each scheduled Jacobian entry that is a quotient is evaluated as its numerator times
    the reciprocal of its denominator, one named reciprocal ``sched_inv<k>`` per distinct
    denominator (the cylinder's entries all divide by the same ``V_p V_n`` polynomial: one
    division per sample instead of three). ``shared`` (expression -> symbol, one dict for
    all the filters of a program) makes every distinct expression one assignment: R5's
    valve-gain entry and its ``B_d`` are R4's, computed once.

    Returns
    -------
    (sympy.Matrix, sympy.Matrix)
        ``A_d``, ``B_d``: numbers where nothing is scheduled, else symbols of named
        assignments.

    Raises
    ------
    DesignError
        If the reduced coordinates depend on the state (the filter's state would change
        meaning along the schedule).
    """
    red = kr.reduction
    model = kr.model
    values = model.parameter_values
    state_syms = {s.symbol: s.name for s in model.states}
    if red.T.free_symbols & set(state_syms):
        raise DesignError(f"Kalman filter {kr.residual}: cannot schedule its prediction, the "
                          "reduced coordinates depend on the state "
                          f"({', '.join(sorted(str(s) for s in red.T.free_symbols))})")
    sub = {}
    reads = set().union(*(_outputs_in(model, m) for m in kr.measurement))
    for sym, name in state_syms.items():
        if name in signals and (signals[name][1] is None or signals[name][1] <= reads):
            sub[sym] = signals[name][0]
        else:
            sub[sym] = _f(model.operating_point[name])
    Ar = red.A_r.xreplace(values).xreplace(sub)
    Br = red.B_r.xreplace(values).xreplace(sub)
    n, m = Br.shape
    h = dt
    A0, B0 = red.A_num, red.B_num
    A0sq, AB0 = A0 @ A0, A0 @ B0
    _check_scheduled_filter(kr, [sym for sym in sub if not sub[sym].is_Number],
                            {sym: v for sym, v in sub.items() if v.is_Number}, values, h)
    tag = kr.residual

    shared = {} if shared is None else shared

    def once(name, expr):
        if expr not in shared:
            shared[expr] = assign(name, expr)
        return shared[expr]

    def entry(expr, name):
        expr = sp.sympify(expr)
        if not expr.free_symbols:
            return _f(expr)
        num, den = sp.fraction(expr)
        if den.free_symbols:
            n_inv = sum(1 for v in shared.values() if v.name.startswith("sched_inv"))
            expr = num * once(f"sched_inv{n_inv}", 1 / den)
        return once(name, expr)

    a = sp.Matrix(n, n, lambda i, j: entry(Ar[i, j], f"{tag}_Ar{i}{j}"))
    b = sp.Matrix(n, m, lambda i, j: entry(Br[i, j], f"{tag}_Br{i}{j}"))
    def corrected(name, d0, first, first0, second, second0):
        """``d0 + h (first - first0) + h^2/2 (second - second0)``, or ``d0`` unscheduled."""
        if not (first.free_symbols or second.free_symbols):
            return _f(d0)
        return once(name, _f(d0) + _f(h) * (first - _f(first0))
                    + _f(h * h / 2) * (second - _f(second0)))

    Ad = sp.Matrix(n, n, lambda i, j: corrected(
        f"{tag}_Ad{i}{j}", kr.discrete.A[i, j], a[i, j], A0[i, j],
        sum((a[i, k] * a[k, j] for k in range(n)), sp.Integer(0)), A0sq[i, j]))
    Bd = sp.Matrix(n, m, lambda i, j: corrected(
        f"{tag}_Bd{i}{j}", kr.discrete.B[i, j], b[i, j], B0[i, j],
        sum((a[i, k] * b[k, j] for k in range(n)), sp.Integer(0)), AB0[i, j]))
    return Ad, Bd


def _check_scheduled_filter(kr: KalmanResidual, scheduled: list, fixed: dict, values: dict,
                            h: float, points: int = 7) -> None:
    r"""Refuse a scheduled prediction whose filter is unstable somewhere on its schedule.

    ``scheduled`` lists the state symbols the prediction follows, ``fixed`` maps the others
    to their operating values. Over a grid of ``points`` values per scheduled state
    spanning the clamp of its signal (the state's ``limits``, else its ``range``), the
    frozen-schedule error dynamics of the filter with its fixed gain ``M`` must be stable:

    .. math:: \rho\big(A_d(s)\,(I - M C_r)\big) < 1

    (``A_d(s)`` as in :func:`scheduled_transition`). A stiff corner of the schedule (a
    tiny dead volume at an end stop) otherwise makes the second-order correction, and the
    filter, diverge.

    Raises
    ------
    DesignError
        Naming the filter, the worst point and its spectral radius.
    """
    if not scheduled:
        return
    red, model = kr.reduction, kr.model
    syms = list(scheduled)
    axes = []
    for sym in syms:
        state = next(s for s in model.states if s.symbol == sym)
        box = state.limits if state.limits is not None else state.range
        if box is None:
            raise DesignError(f"Kalman filter {kr.residual}: cannot schedule on state "
                              f"'{state.name}', which has neither limits nor a range")
        lo, hi = (float(sp.sympify(b).xreplace(values)) for b in box)
        axes.append(np.linspace(lo, hi, points))
    A_of = sp.lambdify(syms, red.A_r.xreplace(values).xreplace(fixed), "numpy")
    A0, Ad0 = red.A_num, kr.discrete.A
    A0sq = A0 @ A0
    closed = np.eye(A0.shape[0]) - kr.gain.M @ kr.discrete.C
    worst = (-np.inf, None)
    with np.errstate(all="ignore"):
        for point in np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(syms), -1).T:
            A = np.array(A_of(*point), dtype=float)
            Ad = Ad0 + h * (A - A0) + h * h / 2 * (A @ A - A0sq)
            rho = np.max(np.abs(np.linalg.eigvals(Ad @ closed))) if np.all(
                np.isfinite(Ad)) else np.inf
            if not rho <= worst[0]:       # a NaN radius counts as the worst
                worst = (rho, point)
    rho, point = worst
    if not rho < 1.0:
        at = ", ".join(f"{s} = {v:.4g}" for s, v in zip(syms, point))
        raise DesignError(
            f"{model.source}: fdi.kalman.{kr.residual}.schedule: the scheduled prediction "
            f"is unstable at {at} (spectral radius of A_d(s)(I - M C) {rho:.4g} >= 1; "
            "the model is too stiff there for the sample time); use "
            "schedule = \"operating_point\" or a shorter sample_time")


def validity_bound(model: Model, item) -> float:
    """Largest magnitude a measured input or output may take before it counts as invalid.

    Ten times the physical limits of the state an output measures (or of the item itself),
    else a thousand times its normal range, else 1e12. NaN and Inf always count as invalid.
    """
    target = item
    if hasattr(item, "expr"):
        expr = model.expand(item.expr)
        target = next((s for s in model.states if expr == s.symbol), None)
    values = model.parameter_values
    if target is not None and getattr(target, "limits", None):
        lims = [abs(float(sp.sympify(b).xreplace(values))) for b in target.limits]
        return 10.0 * max(lims)
    span = getattr(target, "range", None) or getattr(item, "range", None)
    if span:
        return 1000.0 * max(abs(span[0]), abs(span[1]))
    return 1e12


class DerivedParameters:
    """Parameter-only coefficients of the step, each one named assignment of the program.

    ``coefficient(c)`` returns ``c`` itself when it is a number or a (negated) parameter,
    else the symbol ``dp<k>`` of an assignment ``dp<k> = c`` added once to the program
    (``-c`` reuses the symbol of ``c``). Every backend evaluates these assignments as any
    other (the same operations, so the same bits); the C compiler computes them once per
    step instead of once per use, and turns no division by a parameter into a repeated one.

    Parameters
    ----------
    assign : callable
        ``assign(name, expr) -> Symbol`` of the program being built.
    """

    def __init__(self, assign):
        self._assign = assign
        self._symbols = {}

    def coefficient(self, c):
        """``c`` (parameter-only) as a number, a signed parameter or a derived symbol."""
        c = sp.sympify(c)
        if c.is_Number:
            return c if c.is_Integer or c.is_Float else _f(c)
        if c.could_extract_minus_sign():
            return -self.coefficient(-c)
        if c.is_Symbol:
            return c
        if c not in self._symbols:
            self._symbols[c] = self._assign(f"dp{len(self._symbols)}", c)
        return self._symbols[c]


def rational_form(expr, params: set, derived: DerivedParameters):
    r"""A right-hand side as one quotient with parameter-only coefficients lifted out.

    .. math::

        f = \frac{\sum_j c_j\, m_j}{\sum_l e_l\, n_l}

    where the monomials ``m_j``, ``n_l`` hold the non-parameter symbols (states, inputs,
    drivers) and the coefficients ``c_j``, ``e_l`` only parameters (each a number, a
    parameter or a :class:`DerivedParameters` symbol; terms with coefficients equal up to
    sign share one product, ``c (m_1 - m_2)``). For the pneumatic chamber,
    ``-A gamma Pp xdot/V + K R Ts gamma v/V`` becomes ``(dp1 v - dp0 Pp xdot)/V``: one
    division instead of two, no product of parameters repeated per RK4 stage. An
    expression with functions (``sqrt``, ``Min``, ``Piecewise``...) is returned as is.

    Parameters
    ----------
    expr : sympy.Expr
    params : set of sympy.Symbol
        The model's parameters.
    derived : DerivedParameters

    Returns
    -------
    sympy.Expr
        Equal to ``expr`` in exact arithmetic.
    """
    if expr.atoms(sp.Function, sp.Piecewise) or not expr.free_symbols - params:
        return expr
    gens = tuple(sorted(expr.free_symbols - params, key=str))
    num, den = sp.fraction(sp.together(expr))
    if not num.atoms(sp.Float):
        num = sp.factor(num)
    if not den.atoms(sp.Float):
        den = sp.factor(den)
    c_num, rest_num = num.as_independent(*gens, as_Add=False)
    c_den, rest_den = den.as_independent(*gens, as_Add=False)
    scale = c_num / c_den
    if rest_num.is_Add:
        top = _collected(rest_num, scale, gens, derived)
    else:
        top = derived.coefficient(scale) * rest_num
    if rest_den == 1:
        return top
    bottom = _collected(rest_den, sp.Integer(1), gens, derived) if rest_den.is_Add else rest_den
    return top / bottom


def _collected(expr, scale, gens, derived):
    """``scale * expr`` as a sum over the monomials of ``expr`` in ``gens``, each with its
    parameter-only coefficient; monomials whose coefficients agree up to sign share one."""
    by_monomial = {}
    for term in sp.Add.make_args(sp.expand(expr)):
        coeff, mono = term.as_independent(*gens, as_Add=False)
        by_monomial[mono] = by_monomial.get(mono, 0) + coeff * scale
    groups = {}
    for mono, coeff in by_monomial.items():
        coeff = sp.factor(coeff) if not coeff.atoms(sp.Float) else coeff
        if coeff == 0:
            continue
        sign = -1 if coeff.could_extract_minus_sign() else 1
        groups.setdefault(sign * coeff, []).append((sign, mono))
    out = sp.Integer(0)
    for coeff, members in groups.items():
        c = derived.coefficient(coeff)
        if len(members) == 1 or c.is_Number:
            out += sum((sign * c * mono for sign, mono in members), sp.Integer(0))
        else:
            out += c * sp.Add(*[sign * mono for sign, mono in members])
    return out


def _limit(assign, x, model, tag):
    """Clamp states with physical limits: ``min(max(x, low), high)``."""
    out = []
    for xi, s in zip(x, model.states):
        if s.limits is None:
            out.append(xi)
        else:
            lo, hi = s.limits
            out.append(assign(f"{tag}{s.name}", sp.Min(sp.Max(xi, lo), hi)))
    return out


def _rk4(assign, f_expr, state_syms, x, h, tag, model):
    """One classical Runge-Kutta step of ``dx/dt = f(x, u)`` as named assignments.

    .. math::

        k_1 = f(x),\\ k_2 = f(x + \\tfrac{h}{2}k_1),\\ k_3 = f(x + \\tfrac{h}{2}k_2),\\
        k_4 = f(x + h k_3),\\ x^+ = x + \\tfrac{h}{6}(k_1 + 2k_2 + 2k_3 + k_4)
    """
    names = [s.name for s in model.states]

    def stage(point, label):
        sub = dict(zip(state_syms, point))
        return [assign(f"{tag}{label}_{names[i]}", f_expr[i].xreplace(sub))
                for i in range(len(point))]

    hh = _f(h)
    half = _f(h / 2)
    k1 = stage(x, "k1")
    x2 = [assign(f"{tag}x2_{names[i]}", x[i] + half * k1[i]) for i in range(len(x))]
    k2 = stage(x2, "k2")
    x3 = [assign(f"{tag}x3_{names[i]}", x[i] + half * k2[i]) for i in range(len(x))]
    k3 = stage(x3, "k3")
    x4 = [assign(f"{tag}x4_{names[i]}", x[i] + hh * k3[i]) for i in range(len(x))]
    k4 = stage(x4, "k4")
    sixth = _f(h / 6)
    # k1 + 2 (k2 + k3) + k4 as named steps: sympy would distribute the numeric factors
    # (h/6 k1 + h/3 k2 + h/3 k3 + h/6 k4: four products where two suffice)
    mid = [assign(f"{tag}k23_{names[i]}", k2[i] + k3[i]) for i in range(len(x))]
    total = [assign(f"{tag}ksum_{names[i]}", k1[i] + 2 * mid[i] + k4[i]) for i in range(len(x))]
    return [assign(f"{tag}next_{names[i]}", x[i] + sixth * total[i]) for i in range(len(x))]


def _init_program(model, cfg, kal, parallel_blocks, state_names):
    """Initial FDI state from the first sample: measured states from their sensors,
    the others at the operating point; Kalman states ``z = T x``. An invalid first sample
    (non-finite or absurd) is replaced by the output at the operating point."""
    direct = direct_measurements(model)
    raw_u = [_sym(f"{s.name}_raw") for s in model.inputs]
    raw_y = [_sym(f"{o.name}_raw") for o in model.outputs]
    point = dict(model.parameter_values)
    point.update({s.symbol: model.operating_point[s.name] for s in (*model.states, *model.inputs)})
    h0 = numeric(model.h(), point).ravel()
    asg = []
    for k, (o, raw) in enumerate(zip(model.outputs, raw_y)):
        bound = _f(validity_bound(model, o))
        asg.append((o.symbol, sp.Piecewise((raw, sp.Abs(raw) <= bound), (_f(h0[k]), True))))
    y_by_name = {o.name: o.symbol for o in model.outputs}
    x0 = []
    for s in model.states:
        prefer = [o for o in cfg.parity.values() if direct.get(s.name) == o or
                  model.expand(model.output(o).expr) == s.symbol]
        if prefer:
            x0.append(y_by_name[prefer[0]])
        elif s.name in direct:
            x0.append(y_by_name[direct[s.name]])
        else:
            x0.append(_f(model.operating_point[s.name]))
    z = list(x0)
    full = {s.name: x0[i] for i, s in enumerate(model.states)}
    for block in parallel_blocks:
        z.extend(block.initial(full, y_by_name))
    for kr in kal:
        xs = [full[s.name] for s in kr.model.states]
        T = kr.reduction.T_num
        for i in range(T.shape[0]):
            z.append(sum((_f(T[i, j]) * xs[j] for j in range(len(xs)) if T[i, j] != 0),
                         sp.Integer(0)))
    inputs = {"u": tuple(raw_u), "y": tuple(raw_y), "p": tuple(model.p)}
    prog = Program(inputs, tuple(asg), {"z0": tuple(z)})
    prog.check_closed()
    return prog


def _evaluation(model, cfg, names, table):
    classes = ("none",) + tuple(sorted({f.fault_class for f in model.faults}))
    actions = ("none",) + tuple(cfg.actions[c] for c in classes[1:])
    pairs = set()
    for f in model.faults:
        mask = sum(1 << names.index(r) for r in table[f.name])
        if mask:
            pairs.add((mask, classes.index(f.fault_class)))
    patterns = tuple(sorted(pairs))
    thresholds = np.array([cfg.thresholds.get(n, 0.0) if not n.startswith("nf_")
                           else 0.0 for n in names], dtype=float)
    return Evaluation(names, cfg.window, thresholds, cfg.confirm, classes, actions, patterns)
