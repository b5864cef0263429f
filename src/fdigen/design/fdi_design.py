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

This module holds :class:`FdiDesign` and its assembly: the signature table, the paper's and
the structural extra residuals. The parts live beside it: the RK4 parallel model in
:mod:`~fdigen.design.parallel_model`, the scheduled Kalman predictions in
:mod:`~fdigen.design.scheduled_prediction`, the step and initialisation programs in
:mod:`~fdigen.design.step_program`, the residual evaluation in
:mod:`~fdigen.design.evaluation`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp

from fdigen.derive.kalman import KalmanGain
from fdigen.design.analytic_isolability import achievable_isolability
from fdigen.design.config import FdiConfig, read_fdi_config
from fdigen.design.decoupling import parallel_residual
from fdigen.design.evaluation import MAX_RESIDUALS, Evaluation, build_evaluation
from fdigen.design.innovation_filter import filtered_kalman, filtered_realisation
from fdigen.design.measurements import outputs_in
from fdigen.design.observers import KalmanResidual, kalman_residual
from fdigen.design.parallel_model import check_parallel_model_step, parity_realignment
from fdigen.design.program import Program
from fdigen.design.residual_identity import check_residual_keys
from fdigen.design.signatures import (candidate_residuals, decoupling_candidates,
                                      select_extra_residuals, structural_signature,
                                      unresolved_pairs, whole_model_candidates)
from fdigen.design.step_program import build_programs
from fdigen.design.static_relations import static_label, static_relations, static_residual
from fdigen.design.structural_selection import (check_driven_parallel,
                                                driven_parallel_residual, select_structural)
from fdigen.design.structure import isolability, model_structure
from fdigen.design.submodel import driven_submodel
from fdigen.errors import DesignError, FdigenError, ModelFileError
from fdigen.model.expression import expression_text
from fdigen.model.model import Model
from fdigen.model.names import model_names


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
    refused_candidates: tuple = ()   # (label, reason) of structural candidates not realisable
    unkeyed_thresholds: tuple = ()   # derived residuals whose threshold has no residual key

    @property
    def name(self) -> str:
        return self.model.name


def fdi_design(model: Model) -> FdiDesign:
    """Derive the complete FDI design of a model (pure: returns a new object).

    Raises
    ------
    ModelFileError, DesignError
        On a bad configuration, or a design that cannot be built (not detectable, or
        numbers whose derivation overflows double precision: a coefficient of 1e300, a
        power of a large state).
    """
    try:
        return _derive_design(model)
    except OverflowError as exc:
        raise DesignError(
            f"model {model.name}: deriving the FDI design overflows double precision "
            f"({exc}); look for constants, exponents or noise levels of extreme magnitude "
            "(a mode or a gain beyond about 1e150)") from exc


def _derive_design(model: Model) -> FdiDesign:
    cfg = read_fdi_config(model)
    dt = cfg.sample_time
    outputs = {o.name: o for o in model.outputs}
    y_syms = {o.name: o.symbol for o in model.outputs}
    faults = [f.name for f in model.faults]
    classes_of = {f.name: f.fault_class for f in model.faults}

    # -- realignment gain of the parallel model ------------------------------------------
    check_parallel_model_step(model, cfg)
    realignment = parity_realignment(model, cfg)
    # one column per parity residual: the gain of the model that residual checks
    realign_gain = np.hstack([M for _, M, _ in realignment])
    realign = realignment[0][2]

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
            meas_outputs = outputs_in(model, spec.measurement)
            for f in model.faults:
                if f.location == "sensor" and not set(model.outputs_reached(f)) & meas_outputs:
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
    refused = []
    if cfg.extra_residuals:
        cands = candidate_residuals(model, faults)
        chosen, _ = select_extra_residuals(table, classes_of, cands, across_classes=True)
        first = index = 1 + max([int(n[1:]) for n in paper
                                 if n[:1] == "R" and n[1:].isdigit()] or [0])
        index = _add_extras(model, cfg, chosen, index, table, kal, blocks, extras, "classes")
        if cfg.isolate_within_classes:
            # within a class, only residuals blind to a fault by construction: linear
            # sub-model filters separate faults of one class structurally but not
            # numerically (their linearisation error is as large as the faults' effect)
            chosen, _ = select_extra_residuals(table, classes_of,
                                               decoupling_candidates(model, faults),
                                               across_classes=False,
                                               limit=cfg.isolate_within_classes)
            index = _add_extras(model, cfg, chosen, index, table, kal, blocks, extras,
                                "faults")
        if cfg.isolate_structurally:
            refused = _add_structural(model, cfg, faults, index, table, kal, blocks, extras)
        used = [int(e["residual"][1:]) for e in extras if e["residual"][1:].isdigit()]
        _add_static(model, cfg, faults, max(used, default=first - 1) + 1, table, blocks,
                    extras)
    total = len(paper) + len(extras) + len(model.outputs)
    if total > MAX_RESIDUALS:     # before any threshold is asked for: tuning cannot help
        raise DesignError(
            f"{model.source}: the design has {total} residuals ({len(paper)} declared, "
            f"{len(extras)} derived, {len(model.outputs)} sensor validity flags): the flag "
            f"word holds {MAX_RESIDUALS}; declare fewer residuals or outputs, or set [fdi] "
            "extra_residuals = false")
    unkeyed = check_residual_keys(extras, cfg.residual_keys, cfg.thresholds, model.source)
    missing = [e["residual"] for e in extras if e["residual"] not in cfg.thresholds]
    if missing:
        exc = DesignError("derived residuals need thresholds: add " + ", ".join(
            f"'{e['residual']} = ...' ({e['description']})" for e in extras
            if e["residual"] in missing) + " to [fdi.thresholds] (`fdigen tune --model FILE "
            "--write` designs them)")
        exc.missing_thresholds = tuple(missing)     # what `fdigen tune` fills in
        raise exc
    stray = sorted(set(cfg.thresholds) - set(paper) - {e["residual"] for e in extras})
    if stray:
        raise ModelFileError("threshold for a residual this design does not derive "
                             f"(derived: {', '.join(e['residual'] for e in extras) or 'none'})",
                             source=model.source, field="fdi.thresholds", symbol=stray[0])
    validity = tuple(f"nf_{o.name}" for o in model.outputs)
    for f in model.faults:
        if f.location == "sensor":
            table[f.name].update(f"nf_{o}" for o in model.outputs_reached(f))
    names = paper + tuple(e["residual"] for e in extras) + validity
    order = {e["residual"]: k for k, e in enumerate(extras)}
    kal.sort(key=lambda k: order.get(k.residual, -1))
    within = tuple(unresolved_pairs(table, classes_of, across_classes=False))
    across = tuple(unresolved_pairs(table, classes_of, across_classes=True))


    step, init, state_names, aux_names = build_programs(model, cfg, kal, realignment, names,
                                                         tuple(blocks))
    fault_level = () if cfg.structural_classes else class_deciding(
        table, faults, validity, names, tuple(
            e["residual"] for e in extras if e["purpose"].endswith("structural isolability")))
    evaluation = build_evaluation(model, cfg, names, table, fault_level)
    return FdiDesign(model, cfg, step, init, evaluation, names, state_names, aux_names,
                     tuple(kal), realign_gain, realign, {f: table[f] for f in faults}, paper,
                     tuple(extras), within, across,
                     tuple((c.label, why) for c, why in refused), unkeyed)


def _add_structural(model, cfg, faults, index, table, kal, blocks, extras):
    """Add the residuals that bring the table to the structural isolability; returns the
    candidates refused as not realisable, with the reason."""
    # pairs whose faults act in the same direction at every point are not worth a test
    achievable = achievable_isolability(model, isolability(model_structure(model)))[0]
    cands = candidate_residuals(model, faults) + decoupling_candidates(model, faults)

    def realisable(cand):
        if not cand.decoupled:
            return check_driven_parallel(model, cfg, cand)
        try:
            found = parallel_residual(model, model.fault(cand.decoupled), "R", cfg.process_noise,
                                      cfg.sample_time, max(cfg.realign_noise_scale, 1e-6))
        except FdigenError as exc:
            return str(exc)
        return "" if found is not None else "no decoupling direction"

    chosen, refused, missing = select_structural(table, achievable, cands, realisable)
    index = _add_extras(model, cfg, chosen, index, table, kal, blocks, extras,
                        "faults to the structural isolability", parallel=True)
    if missing:
        # the whole model, checked on one sensor, only where no sub-model reaches
        chosen, more, _ = select_structural(table, achievable,
                                            whole_model_candidates(model, faults), realisable)
        _add_extras(model, cfg, chosen, index, table, kal, blocks, extras,
                    "faults to the structural isolability", parallel=True)
        refused = refused + more
    return refused


def derived_name(model, index: int) -> tuple[str, int]:
    """``R<index>``, skipping a name the model already gives a parameter, definition,
    input, output, state or fault (a battery's polarisation resistance ``R1``), and the
    next index."""
    taken = model_names(model)
    while f"R{index}" in taken:
        index += 1
    return f"R{index}", index + 1


def _add_static(model, cfg, faults, index, table, blocks, extras):
    """Add every static relation between the sensors (:mod:`fdigen.design.static_relations`)
    not on the voter's channels (the voter compares those): one subtraction per sample,
    no state to drift, so each is added whether the signature table needs it or not."""
    exclude = set(cfg.voter.channels) if cfg.voter else set()
    for check, drivers, sig in static_relations(model, faults, exclude):
        rname, index = derived_name(model, index)
        blocks.append(static_residual(model, check, drivers, sig, rname))
        for f, hit in sig.items():
            if hit:
                table[f].add(rname)
        extras.append({"residual": rname, "realisation": "static relation",
                       "equations": [], "drivers": dict(drivers), "check": check,
                       "purpose": "compare the sensors without dynamics", "blind_to": None,
                       "description": static_label(check, drivers)})


def _add_extras(model, cfg, chosen, index, table, kal, blocks, extras, purpose,
                parallel=False):
    """Design the chosen candidate residuals (Kalman filters or decoupled parallel models;
    with ``parallel``, driven sub-models as nonlinear parallel models too)."""
    direct_noise = {o.name: o.noise_std for o in model.outputs}
    for cand in chosen:
        rname, index = derived_name(model, index)
        if cand.decoupled:
            blocks.append(parallel_residual(model, model.fault(cand.decoupled), rname,
                                            cfg.process_noise, cfg.sample_time,
                                            max(cfg.realign_noise_scale, 1e-6)))
        elif parallel:
            blocks.append(driven_parallel_residual(model, cfg, cand, rname))
        else:
            sub = driven_submodel(model, cand.keep, cand.drivers)
            noise = {o: direct_noise[o] for o in cand.drivers.values()}
            kal.append(kalman_residual(sub, rname, (cand.check,), cfg.process_noise,
                                       cfg.sample_time, drivers=cand.drivers,
                                       driver_noise=noise,
                                       nonlinear_drivers=cfg.nonlinear_drivers))
        for f, hit in cand.signature.items():
            if hit:
                table[f].add(rname)
        realisation = ("decoupled parallel model" if cand.decoupled else
                       "parallel model" if parallel else
                       filtered_realisation(cfg.innovation_filter)
                       if filtered_kalman(cfg, rname) else "Kalman filter")
        # a combination's checked quantity in expanded form: its key (residual_identity)
        # must not change with how the algebra happened to be factored
        check = (expression_text(sp.expand(blocks[-1].measured)) if cand.decoupled
                 else cand.check)
        extras.append({"residual": rname, "realisation": realisation,
                       "equations": list(cand.keep),
                       "drivers": dict(cand.drivers), "check": check,
                       "purpose": f"isolate {purpose}", "blind_to": cand.decoupled or None,
                       "description": cand.label})
    return index


def _voter_channel_faults(model: Model, cfg: FdiConfig, channel: str) -> list:
    """Sensor faults that corrupt this voter channel and no other."""
    used = {}
    for ch in cfg.voter.channels:
        if ch in {o.name for o in model.outputs}:
            used[ch] = {ch}
        else:
            spec = next(k for k in cfg.kalman if k.residual == ch)
            used[ch] = set() if spec.update == "voter" else outputs_in(model, spec.measurement)
    others = set().union(*(used[c] for c in cfg.voter.channels if c != channel))
    reached = {f.name: set(model.outputs_reached(f)) for f in model.faults
               if f.location == "sensor"}
    return [f for f, outs in reached.items()
            if outs and outs <= used[channel] and not outs & others]


def class_deciding(table: dict, faults, validity, names, fault_level: tuple) -> tuple:
    """The fault-level residuals that stay out of the class decision.

    The structural residuals separate faults within a class and are kept out of the class
    decision (``docs/isolation.md``, section 4), unless a fault has no other residual:
    a fault whose signature holds only fault-level residuals (and validity flags) would be
    detected and never reach the class decision, so never acted on (a user's two tanks
    whose leak and pump loss only a derived structural residual sees). Such residuals
    decide classes too; returns the rest.
    """
    out = set(fault_level)
    class_level = set(names) - out - set(validity)
    needed = {r for f in faults if not set(table[f]) & class_level
              for r in set(table[f]) & out}
    return tuple(r for r in fault_level if r not in needed)

