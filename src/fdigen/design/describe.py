"""A JSON-able description of a design's derived artefacts (``fdigen inspect``)."""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np
import sympy as sp

from fdigen.derive.linearisation import linearise
from fdigen.derive.observability import observability_rank, undetectable_modes
from fdigen.design.fdi_design import FdiDesign
from fdigen.design.residual_identity import residual_keys
from fdigen.design.residual_scale import residual_scales
from fdigen.model.expression import expression_text

#: The observability of every subset of the outputs is listed up to this many outputs
#: (2^n - 1 rank computations); beyond, each output alone and all of them (a model file
#: of 18 outputs of one state kept inspect busy past 600 s: attack round 2).
MAX_SUBSET_OUTPUTS = 10
from fdigen.design.structure import isolability_report


def validity_flags(design: FdiDesign) -> tuple:
    """The measurement validity flags ``nf_<y>`` among the design's residuals."""
    derived = set(design.paper_residuals) | {e["residual"] for e in design.extra_residuals}
    return tuple(n for n in design.residual_names if n not in derived)


def _mat(a) -> list:
    return np.asarray(a, dtype=float).tolist()


def _sym(m: sp.Matrix) -> list:
    """The entries as simplified text; equal entries (most of them: zeros, ones, the
    same coefficient in several filters) are simplified once."""
    return [[_simplified(e) for e in m.row(i)] for i in range(m.rows)]


@lru_cache(maxsize=4096)
def _simplified(expr: sp.Expr) -> str:
    if expr.is_Atom:
        return expression_text(expr)
    from fdigen.design.readable import almost_everywhere  # sign/abs derivatives

    expr = almost_everywhere(expr)
    if _function_depth(expr) > SIMPLIFY_MAX_NESTING or sp.count_ops(expr) > SIMPLIFY_MAX_OPS:
        # sympy's simplify (trigsimp's TR8 on nested sines) took minutes on a 98-character
        # equation (security round 4): a large entry is described as derived
        return expression_text(expr)
    out = sp.simplify(expr)
    # simplify turns sign(v)**2 into a Piecewise guarded by v == 0: the kink again
    return expression_text(almost_everywhere(out) if out.has(sp.Piecewise, sp.DiracDelta)
                           else out)


#: Entries simplified for the description only below these sizes: functions nested this
#: deep (``sin(cos(x))`` is 2) and this many operations.
SIMPLIFY_MAX_NESTING = 3
SIMPLIFY_MAX_OPS = 200


def _function_depth(expr) -> int:
    """How deep functions (``sin``, ``exp``...) are nested in ``expr``."""
    if expr.is_Atom:
        return 0
    inner = max((_function_depth(a) for a in expr.args), default=0)
    return inner + (1 if isinstance(expr, sp.Function) else 0)


def _scheduled_on(design: FdiDesign, residual: str) -> dict:
    """Signals a scheduled filter's prediction reads: ``{state: signal expression}``
    (from the step program: the ``sched_<state>`` assignments its Jacobian entries or its
    nonlinear prediction's reference state use, and the parallel model's states the
    latter reads)."""
    asg = dict(design.step.assignments)
    inv = {s: e for s, e in asg.items() if s.name.startswith("sched_inv")}
    used, estimates = set(), set()
    for s, e in asg.items():
        if s.name.startswith((f"{residual}_Ar", f"{residual}_Br", f"{residual}_nl_base_")):
            used |= {q for q in e.xreplace(inv).free_symbols if q.name.startswith("sched_")}
        if s.name.startswith(f"{residual}_nl_base_"):   # nonlinear prediction's reference
            estimates |= {q for q in e.free_symbols if q.name.startswith("par_")}
    out = {q.name[len("sched_"):]: expression_text(asg[q]) for q in sorted(used, key=str)}
    out.update({q.name[len("par_"):]: f"{q.name} (re-aligned parallel model)"
                for q in sorted(estimates, key=str)})
    return out


def _fault_targets(model, fault) -> list[str]:
    """The equations a fault of several terms enters: its terms' targets, or, for a fault
    written inside [definitions] (no terms of its own), the states and outputs whose
    equations hold it once the definitions are substituted."""
    if fault.terms:
        return [t for t, _ in fault.terms]
    f, h = model.f(with_faults=True), model.h(with_faults=True)
    return ([s.name for k, s in enumerate(model.states) if f[k].has(fault.symbol)]
            + [o.name for k, o in enumerate(model.outputs) if h[k].has(fault.symbol)])


def describe_design(design: FdiDesign) -> dict:
    """Everything derived for a model, at its operating point.

    Returns
    -------
    dict
        ``model``, ``operating_point``, ``linearisation`` (full A, B, C, D, E, F),
        ``kalman`` (per filter: measurement, coordinate change T, reduced A, B, C symbolic
        and numeric, discrete and continuous gains, poles), ``realignment``,
        ``signature_table`` (residuals x faults), ``isolation``, ``extra_residuals``,
        the fault pairs the structure cannot separate, and ``isolability``: the achievable
        (structural) and achieved (signature table) isolability matrices, row ``f_i``
        column ``f_j`` 1 when ``f_i`` is isolable from ``f_j``, the ordered pairs no
        residual can separate and the extra sensors that would
        (:func:`fdigen.design.structure.isolability_report`).
    """
    model = design.model
    lin = linearise(model)
    kal = []
    for k in design.kalman:
        red = k.reduction
        kal.append({
            "residual": k.residual,
            "model": k.model.name,
            "measurement": list(k.measurement),
            "update": k.update,
            "schedule": k.schedule,
            "scheduled_on": _scheduled_on(design, k.residual),
            "drivers": k.drivers,
            "coordinates": list(red.z_names),
            "T": _mat(red.T_num),
            "T_symbolic": _sym(red.T),
            "A_reduced": _mat(red.A_num),
            "B_reduced": _mat(red.B_num),
            "C_reduced": _mat(red.C_num),
            "A_reduced_symbolic": _sym(red.A_r),
            "B_reduced_symbolic": _sym(red.B_r),
            "unobservable_eigenvalues": [complex(e).real for e in red.unobservable_eigenvalues],
            "A_discrete": _mat(k.discrete.A),
            "B_discrete": _mat(k.discrete.B),
            "Q_continuous": _mat(k.Qc),
            "R_discrete": _mat(k.Rd),
            "gain_discrete_predictor_L": _mat(k.gain.L),
            "gain_discrete_filter_M": _mat(k.gain.M),
            "gain_continuous_L": _mat(k.continuous_gain.L),
            "poles_discrete_abs": [abs(complex(p)) for p in k.gain.poles],
        })
    observability = []
    n_out = len(model.outputs)
    sizes = (range(1, n_out + 1) if n_out <= MAX_SUBSET_OUTPUTS   # 2^n ranks: bounded
             else (1, n_out))
    for size in sizes:
        for subset in itertools.combinations(range(n_out), size):
            C = lin.C[list(subset), :]
            rank = observability_rank(lin.A, C)
            observability.append({
                "outputs": [model.outputs[i].name for i in subset], "rank": rank,
                "observable": rank == len(model.states),
                "detectable_continuous": not undetectable_modes(lin.A, C, discrete=False)})
    ev = design.evaluation
    table = {r: {f: int(r in s) for f, s in design.signature_table.items()}
             for r in design.residual_names}
    return {
        "model": model.name,
        "source": model.source.rsplit("/", 1)[-1],
        "states": [s.name for s in model.states],
        "inputs": [s.name for s in model.inputs],
        "outputs": [o.name for o in model.outputs],
        "faults": {f.name: {"location": f.location, "mode": f.mode, "target": f.target,
                            "class": f.fault_class,
                            **({"targets": _fault_targets(model, f)} if f.multi else {})}
                   for f in model.faults},
        "operating_point": dict(model.operating_point),
        "sample_time": design.config.sample_time,
        "linearisation": {"A": _mat(lin.A), "B": _mat(lin.B), "C": _mat(lin.C),
                          "D": _mat(lin.D), "E": _mat(lin.E), "F": _mat(lin.F)},
        "observability": observability,
        "kalman": kal,
        "realignment_gain": _mat(design.realign_gain),
        "residuals": list(design.residual_names),
        "paper_residuals": list(design.paper_residuals),
        "signature_table": table,
        "extra_residuals": [{**e, "key": key} for e, key in zip(
            design.extra_residuals, residual_keys(design.extra_residuals).values())],
        "residual_scales": residual_scales(design),
        "unkeyed_thresholds": list(design.unkeyed_thresholds),
        "unresolved_pairs_across_classes": [list(p) for p in design.unresolved_across_classes],
        "unresolved_pairs_within_class": [list(p) for p in design.unresolved_within_class],
        **({"sensor_maps": maps} if (maps := sensor_map_report(model))["measures"]
           or maps["not_measurements"] else {}),
        "isolability": (iso := {**isolability_report(model, design.signature_table,
                                                     validity_flags(design)),
                                "refused_candidates": [{"candidate": c, "reason": why}
                                                       for c, why in
                                                       design.refused_candidates]})
        | {"not_achieved_reasons": unreached_reasons(model, iso)}
        | _settled(design),
        "isolation": {
            "classes": list(ev.classes),
            "actions": dict(zip(ev.classes, ev.actions)),
            "patterns": [{"residuals": [r for i, r in enumerate(ev.residuals) if m >> i & 1],
                          "class": ev.classes[c]} for m, c in ev.patterns],
            "window": ev.window,
            "confirm": ev.confirm,
            "thresholds": dict(zip(ev.residuals, ev.thresholds.tolist())),
        },
    }


def _settled(design) -> dict:
    """``settled_responses`` (:mod:`fdigen.design.settled_response`: the faults a Kalman
    residual sees only while its filter settles) and ``transient_only_pairs`` (the pairs
    the table isolates only through those a step at the test size does not flag)."""
    from fdigen.design.settled_response import settled_responses, transient_only_pairs

    settled = settled_responses(design)
    return {"settled_responses": settled,
            "transient_only_pairs": [list(p) for p in transient_only_pairs(
                design.signature_table, settled)]}


def sensor_map_report(model) -> dict:
    """How each output reads the states: ``measures`` (output -> the state it measures
    directly and the inverse the derivations substitute, ``h1 = y1/kc``, for maps other
    than ``y = x``) and ``not_measurements`` (outputs of one state not invertible over
    its range, with the reason: they drive no sub-model and initialise no state)."""
    from fdigen.model.sensor_maps import compound_sensor_maps, not_invertible, sensor_maps

    measures = {m.output: {"state": m.state, "gain": m.gain,
                           "inverse": f"{m.state} = {expression_text(m.inverse)}"}
                for maps in sensor_maps(model).values() for m in maps if not m.identity}
    # a sensor of a state over others that are measured (a pressure of moles in a volume)
    measures.update({m.output: {"state": m.state, "gain": m.gain,
                                "inverse": f"{m.state} = {expression_text(m.inverse)}",
                                "with": [s for s, _ in m.reads]}
                     for maps in compound_sensor_maps(model).values() for m in maps})
    return {"measures": measures, "not_measurements": not_invertible(model)}


def unreached_reasons(model, iso: dict) -> dict:
    """For each fault ``g`` that some achievable pair ``f from g`` is not achieved from:
    why none of fdigen's residual constructions is blind to ``g`` (a driven sub-model
    that ``g`` enters, or a decoupling that cannot cancel it), e.g. ``damper enters T_z
    and CO2 in the ratio ..., which depends on those states``."""
    from fdigen.design.decoupling import decoupling_refusal

    out, seen = {}, {}
    for f, g in iso.get("achievable_not_achieved", []):
        seen.setdefault(g, []).append(f)
    for g, fs in seen.items():
        why = decoupling_refusal(model, model.fault(g))
        # a residual blind to g may exist and not see f (a collector loop's R2 is blind
        # to pump wear and to the flow meter: "no residual blind to pump_wear" misread)
        out[g] = (f"no residual blind to {g}: {why}" if why else
                  f"a residual blind to {g} that sees {', '.join(fs)} is allowed by the "
                  "structure, but none of fdigen's constructions realises one here")
    return out

