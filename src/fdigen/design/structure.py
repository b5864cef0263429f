"""Structural analysis of a model: the best fault isolability its sensors allow.

The model is read as a bipartite graph between equations and unknown variables:

* one dynamic equation per state, ``e_x: dx/dt = f_x(x, u)``, relating the state to the
  states it uses (derivative and state are one variable: mixed causality, the structure
  of Frisk et al.'s Fault Diagnosis Toolbox with differential constraints collapsed);
* one *actuator equation* per input an actuator fault acts on,
  ``a_u: u_eff = u + term(phi)``: the effective input ``u_eff`` is unknown, the commanded
  ``u`` is known, and every equation using ``u`` uses ``u_eff`` instead. The fault then
  enters one equation only (a valve fault does not enter the chamber balances directly,
  so a combination of them can be blind to it);
* one output equation per sensor, ``y = h(x, u)``, ``y`` known.

A fault enters the equations whose right-hand side depends on it (sensor faults their
sensor's, plant faults their targets', actuator faults the actuator equation).

With ``M`` the equations, the structurally overdetermined part ``M+`` of the
Dulmage-Mendelsohn decomposition is the set of equations reachable from an equation left
unmatched by a maximum matching (networkx's Hopcroft-Karp) through alternating paths
(equation -> any of its unknowns -> the equation matched to that unknown). Then
(Krysander and Frisk, 2008):

* fault ``f_i`` is structurally *detectable* when one of its equations lies in ``M+``;
* ``f_i`` is structurally *isolable from* ``f_j`` when one of ``f_i``'s equations lies in
  ``(M \\ E_j)+``, ``E_j`` the equations ``f_j`` enters: some test uses ``f_i``'s equation
  and none of ``f_j``'s.

The minimal structurally overdetermined (MSO) sets are the smallest such tests; each is a
residual generator candidate, and its fault signature is the faults entering it.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import networkx as nx
import sympy as sp

from fdigen.derive.nonsmooth import derivative
from fdigen.model.model import Model
from fdigen.model.sensor_maps import sensor_maps

#: MSO enumeration (exponential in the redundancy) is skipped above this many equations.
MSO_MAX_EQUATIONS = 24

#: Overdetermined parts the MSO enumeration visits at most (the shipped cylinder visits
#: 41; a model of one state and 14 outputs visited 32,752 in 46 s: attack round 2); the
#: list is then reported incomplete (``mso_sets_complete``). Only inspect's report reads
#: it: the design's residuals come from the isolability, which is polynomial.
MSO_MAX_VISITS = 2000


@dataclass(frozen=True)
class Structure:
    """The bipartite equation-variable structure of a model.

    Attributes
    ----------
    equations : dict of str to frozenset of str
        Equation name -> unknown variables it relates.
    faults : dict of str to frozenset of str
        Fault name -> equations it enters.
    known : tuple of str
        Known variables (inputs, measured outputs), for the record.
    """

    equations: dict
    faults: dict
    known: tuple

    def with_sensor(self, variable: str) -> "Structure":
        """The same structure with one more (fault-free) sensor measuring ``variable``."""
        eqs = dict(self.equations)
        eqs[f"y_{variable}_new"] = frozenset({variable})
        return Structure(eqs, dict(self.faults), self.known + (f"{variable}_meas",))

    @property
    def unknowns(self) -> list:
        return sorted(set().union(*self.equations.values())) if self.equations else []


def _on_an_input(model: Model, fault) -> bool:
    """Whether ``fault`` acts on one input through its actuator equation (an actuator
    fault with a term on an input). An actuator fault written inside a definition (a
    valve's ``(1 - block) u`` in a flow) names no input: it enters the equations that use
    the definition, found like a plant fault's."""
    return (fault.location == "actuator" and not fault.multi
            and fault.target in {s.name for s in model.inputs})


def _one_channel(fault, entered: set, eqs: dict) -> set:
    """A fault entering several equations enters them as one unknown signal: its own
    equation ``c_f: z_f = phi`` (the fault's signal, nothing else: healthy it says
    ``z_f = 0``), and the equations it entered use the unknown ``z_f`` with their own
    gains ``df_k/dphi`` (Krysander and Frisk's rewrite of a fault in several equations
    into one, as the actuator equation does for a fault on an input). The fault is one
    scalar, so a combination of two of those equations can always eliminate it: a
    drivetrain's shaft damping in the shaft torque both inertias feel is cancelled by the
    total momentum balance, a quadruple tank's pump loss by the two tanks its flow feeds,
    whether the fault is written in a definition, as terms on the balances or on the
    input they share (the structure saw one fault in two equations: no test without
    both, and said "no residual of any kind separates"). ``eqs`` gains the equation and
    the unknown; returns the equation the fault enters."""
    if len(entered) < 2:
        return entered
    var = f"z_{fault.name}"
    eqs[f"c_{fault.name}"] = frozenset({var})
    for eq in entered:
        eqs[eq] = eqs[eq] | {var}
    return {f"c_{fault.name}"}


def model_structure(model: Model) -> Structure:
    """The structure of ``model`` (see the module docstring)."""
    states = {s.symbol: s.name for s in model.states}
    act_inputs = {f.target for f in model.faults if _on_an_input(model, f)}
    inputs = {s.symbol: s.name for s in model.inputs}

    def unknowns(expr):
        names = set()
        for sym in expr.free_symbols:
            if sym in states:
                names.add(states[sym])
            elif sym in inputs and inputs[sym] in act_inputs:
                names.add(f"{inputs[sym]}_eff")
        return names

    f0 = model.f()
    h0 = model.h()
    eqs = {}
    for k, s in enumerate(model.states):
        eqs[f"e_{s.name}"] = frozenset(unknowns(f0[k]) | {s.name})
    for u in sorted(act_inputs):
        eqs[f"a_{u}"] = frozenset({f"{u}_eff"})
    for k, o in enumerate(model.outputs):
        eqs[f"y_{o.name}"] = frozenset(unknowns(h0[k]))
    fw = model.f(with_faults=True)
    hw = model.h(with_faults=True)
    zero = {f.symbol: 0 for f in model.faults}
    faults = {}
    for flt in model.faults:
        entered = set()
        if _on_an_input(model, flt):
            entered.add(f"a_{flt.target}")
        else:
            for rows, items, tag in ((fw, model.states, "e"), (hw, model.outputs, "y")):
                for k, item in enumerate(items):
                    d = sp.simplify(derivative(rows[k], flt.symbol).xreplace(zero))
                    if d != 0:
                        entered.add(f"{tag}_{item.name}")
                        eqs[f"{tag}_{item.name}"] = eqs[f"{tag}_{item.name}"] | unknowns(d)
            entered = _one_channel(flt, entered, eqs)
        faults[flt.name] = frozenset(entered)
    known = tuple(s.name for s in model.inputs) + tuple(o.name for o in model.outputs)
    return Structure(eqs, faults, known)


def overdetermined_part(structure: Structure, equations=None) -> frozenset:
    """``M+``: the structurally overdetermined part of the equations ``M`` (DM decomposition).

    Equations reachable from an unmatched equation of a maximum matching by alternating
    paths (equation -> unknown -> the equation matched to it).
    """
    eqs = sorted(structure.equations if equations is None else equations)
    graph = nx.Graph()
    graph.add_nodes_from((("e", e) for e in eqs), bipartite=0)
    for e in eqs:
        for v in structure.equations[e]:
            graph.add_edge(("e", e), ("v", v))
    top = [("e", e) for e in eqs]
    matching = nx.bipartite.hopcroft_karp_matching(graph, top_nodes=top)
    todo = [n for n in top if n not in matching]
    seen = set(todo)
    while todo:
        node = todo.pop()
        for var in graph[node]:
            nxt = matching.get(var)
            if nxt is not None and nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return frozenset(name for _, name in seen)


def redundancy(structure: Structure, equations) -> int:
    """Structural redundancy ``|M+| - |vars(M+)|`` of the overdetermined part of ``M``."""
    plus = overdetermined_part(structure, equations)
    used = set().union(*(structure.equations[e] for e in plus)) if plus else set()
    return len(plus) - len(used)


def mso_sets(structure: Structure, limit: int = 2000) -> list:
    """The minimal structurally overdetermined sets (Krysander's algorithm, memoised):
    remove one equation at a time from an overdetermined part of redundancy > 1 and keep
    the overdetermined part of what is left; sets of redundancy 1 are MSO. At most
    ``limit`` sets and :data:`MSO_MAX_VISITS` parts visited (:func:`mso_search` says
    whether the list is complete)."""
    return mso_search(structure, limit)[0]


def mso_search(structure: Structure, limit: int = 2000) -> tuple[list, bool]:
    """:func:`mso_sets` and whether the enumeration finished (no bound reached)."""
    if len(structure.equations) > MSO_MAX_EQUATIONS:
        return [], False
    found, seen = set(), set()
    todo = [overdetermined_part(structure)]
    while todo and len(found) < limit and len(seen) < MSO_MAX_VISITS:
        part = todo.pop()
        if part in seen or not part:
            continue
        seen.add(part)
        phi = redundancy(structure, part)
        if phi == 1:
            found.add(part)
            continue
        if phi < 1:
            continue
        for e in sorted(part):
            todo.append(overdetermined_part(structure, part - {e}))
    return sorted(found, key=lambda s: (len(s), sorted(s))), not todo


def isolability(structure: Structure) -> dict:
    """Structural isolability: ``{(fi, fj): True}`` when ``fi`` is isolable from ``fj``.

    ``(fi, fi)`` is True when ``fi`` is structurally detectable.
    """
    full = overdetermined_part(structure)
    names = list(structure.faults)
    out = {}
    for fi in names:
        out[(fi, fi)] = bool(structure.faults[fi] & full)
        for fj in names:
            if fi == fj:
                continue
            rest = set(structure.equations) - structure.faults[fj]
            out[(fi, fj)] = bool(structure.faults[fi] & overdetermined_part(structure, rest))
    return out


def non_isolable_pairs(isol: dict) -> list:
    """Ordered pairs ``(fi, fj)``, ``fi != fj``, with ``fi`` not isolable from ``fj``."""
    return sorted(pair for pair, ok in isol.items() if pair[0] != pair[1] and not ok)


def table_isolability(table: dict) -> dict:
    """Isolability a signature table achieves: ``fi`` isolable from ``fj`` when a residual
    responds to ``fi`` and not to ``fj`` (``S(fi)`` not contained in ``S(fj)``);
    ``(fi, fi)``: detected by some residual."""
    out = {}
    for fi, fj in itertools.product(table, repeat=2):
        out[(fi, fj)] = bool(table[fi]) if fi == fj else bool(set(table[fi]) - set(table[fj]))
    return out


def sensor_placement(structure: Structure, pairs) -> dict:
    """For each ordered pair not isolable, the unknowns whose measurement would isolate it.

    Each unknown variable in turn gets one more fault-free sensor and the structural
    isolability is recomputed. Returns ``{(fi, fj): [variable, ...]}``.
    """
    result = {tuple(p): [] for p in pairs}
    for var in structure.unknowns:
        isol = isolability(structure.with_sensor(var))
        for pair in result:
            if isol[pair]:
                result[pair].append(var)
    return result


def isolability_report(model: Model, table: dict | None = None, validity=()) -> dict:
    """JSON-able summary: structure, MSO sets, achievable (structural) and achieved (table)
    isolability matrices, the pairs no residual can separate, and sensors that would.

    The achieved isolability reads the residuals of ``table`` but not the measurement
    validity flags ``validity`` (raised only by NaN or far out-of-range samples); the pairs
    only they separate are listed as ``isolable_only_when_the_sensor_dies``, and the
    ordered pairs where achieved and achievable differ are listed both ways."""
    from fdigen.design.analytic_isolability import (achievable_isolability,
                                                    fault_directions, parallel_pairs)

    st = model_structure(model)
    at = fault_directions(model)              # linearised once for both checks
    isol, by_direction = achievable_isolability(model, isolability(st), at=at)
    faults = list(st.faults)
    struct_pairs = non_isolable_pairs(isol)
    parallel = parallel_pairs(model, at=at) if by_direction else set()
    placement = sensor_placement(st, struct_pairs)
    # a fault's own signal (z_f, the unknown of a fault written into several equations)
    # is no quantity a sensor can read (a user's buck converter was told "a sensor on
    # z_cap_deg")
    signals = {f"z_{f.name}" for f in model.faults}
    placement = {pair: [v for v in vs if v not in signals] for pair, vs in placement.items()}
    for pair in placement:
        if frozenset(pair) in parallel:
            # an extra sensor on a state adds rows to C only; one on an input as the
            # actuator delivers it sees the actuator's fault itself
            placement[pair] = [v for v in placement[pair] if v.endswith("_eff")]
    # a sensor on a definition (a heater's power, a flow): a fault written in it enters
    # the sensor's own equation, which separates even a pair acting in one direction
    from fdigen.design.definition_sensors import definition_structures, faults_in

    on_definitions = []
    for name, with_d in definition_structures(model).items() if struct_pairs else ():
        isol_d = isolability(with_d)
        inside = faults_in(model, name)
        for pair in placement:
            if isol_d[pair] and (frozenset(pair) not in parallel
                                 or len(inside & set(pair)) == 1):
                placement[pair].append(name)
                on_definitions.append(name)
    msos, complete = mso_search(st)
    report = {
        "mso_sets_complete": complete,
        "equations": {e: sorted(v) for e, v in st.equations.items()},
        "fault_equations": {f: sorted(v) for f, v in st.faults.items()},
        "mso_sets": [{"equations": sorted(m),
                      "faults": [f for f in faults if st.faults[f] & m]} for m in msos],
        "faults": faults,
        "achievable": [[int(isol[(fi, fj)]) for fj in faults] for fi in faults],
        "achievable_non_isolable": [list(p) for p in struct_pairs],
        # structurally isolable, but the linearised model's rank test refuses them at
        # every point (analytic_isolability); "same direction": their fault columns are
        # parallel everywhere, which no sensor changes
        "not_isolable_by_direction": [
            {"pair": list(p), "same_direction": frozenset(p) in parallel}
            for p in by_direction],
        "sensor_placement": [{"pair": list(p), "sensors": v} for p, v in placement.items()],
        # (a placement on one of these is a second, redundant sensor)
        "measured_states": sorted(sensor_maps(model)),
        "definition_sensors": sorted(set(on_definitions)),
        "states": [x.name for x in model.states],
    }
    if table is not None:
        # validity flags (nf_<y>) rise only on NaN or far out-of-range samples: a pair they
        # alone separate is isolable only when the sensor dies, not by the residuals
        got = table_isolability({f: set(table[f]) - set(validity) for f in faults})
        report["achieved"] = [[int(got[(fi, fj)]) for fj in faults] for fi in faults]
        report["achieved_non_isolable"] = [list(p) for p in non_isolable_pairs(got)]
        full = table_isolability({f: table[f] for f in faults})
        report["isolable_only_when_the_sensor_dies"] = [
            list(p) for p in sorted(p for p, ok in full.items() if ok and not got[p])]
        report["achievable_not_achieved"] = [
            list(p) for p in sorted(p for p, ok in isol.items() if ok and not got[p])]
        report["achieved_not_achievable"] = [
            list(p) for p in sorted(p for p, ok in got.items() if ok and not isol[p])]
    return report
