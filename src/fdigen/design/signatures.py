"""Fault signatures derived from the model's structure, and residuals that improve isolation.

A residual generator checks part of the model against part of the measurements. A fault
can move the residual when it reaches the residual's measurement through that part of the
model. With the linearisation ``A = df/dx``, ``E = df/dphi``, ``C_m = dm/dx`` and
``F_m = dm/dphi`` evaluated at random points of the physical range (so that a structural
zero is a zero everywhere, and a nonzero is nonzero generically), fault ``phi_j`` is in the
signature of the residual when any Markov parameter

.. math:: F_m e_j,\\; C_m E e_j,\\; C_m A E e_j,\\; \\dots,\\; C_m A^{n-1} E e_j

is nonzero. For a nonlinear model the powers ``C_m A^k`` are replaced by the gradients
of the Lie derivatives of the measurement along the dynamics,

.. math:: \\frac{\\partial}{\\partial x} L_f^k m, \\qquad L_f^0 m = m, \\;
          L_f^{k+1} m = \\frac{\\partial L_f^k m}{\\partial x} f,

which they equal for a linear model: ``C_m A^k`` at a point away from equilibrium depends
on the coordinates the states are written in (a tank's salt written as a mass ``M`` with
``c = M/(A h)`` lost the leak from its conductivity residual, which the concentration
spelling kept), the Lie derivatives do not (:mod:`fdigen.derive.lie_derivatives`).
Broen's voter weights are the exception: ``w_j`` moves only for faults that corrupt
channel ``j`` alone (a fault seen by all channels moves none of the weights).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import sympy as sp

from fdigen.derive.linearisation import numeric, symbolic_jacobians
from fdigen.model.expression import expression_text, parse_expression
from fdigen.errors import DesignError
from fdigen.model.model import Model
from fdigen.model.sensor_maps import output_preference

_REL_TOL = 1e-9


def random_points(model: Model, n: int, seed: int):
    """``n`` seeded substitutions: states and inputs uniform over their declared ranges
    (or [-1, 1]), parameters at their values, faults at 0."""
    rng = np.random.default_rng(seed)
    pts = []
    for _ in range(n):
        subs = dict(model.parameter_values)
        for s in (*model.states, *model.inputs):
            lo, hi = s.range if s.range else (-1.0, 1.0)
            subs[s.symbol] = float(rng.uniform(lo, hi))
        for f in model.f_sym:
            subs[f] = 0.0
        pts.append(subs)
    return pts


def _real_at(model: Model, mat, subs: dict, rows: str) -> np.ndarray:
    """``numeric(mat, subs)``, or a :class:`DesignError` naming the equation and the point
    where it is not real (a ``sqrt`` or ``log`` of a negative number) and the fix."""
    try:
        return numeric(mat, subs)
    except (TypeError, ValueError):
        pass
    names = ([f"dynamics.{s.name}" for s in model.states] if rows == "dynamics"
             else ["the measured outputs"] * mat.rows)
    bad = next((names[i] for i in range(mat.rows) for j in range(mat.cols)
                if not _is_real(mat[i, j], subs)), names[0])
    point = ", ".join(f"{s.name} = {float(subs[s.symbol]):.6g}"
                      for s in (*model.states, *model.inputs))
    raise DesignError(
        f"{model.source}: {bad} of {model.name}: its derivative is not real at {point} "
        "(a point of the declared ranges, where signatures are derived): a sqrt or log of "
        "a negative number there; guard the argument, e.g. sqrt(max(h, 0)), or narrow the "
        "states' ranges to where the model is defined")


def value_at(expr, subs) -> float | None:
    """``expr`` at the point ``subs`` (17-digit floats), or ``None`` where it is not real
    (a sqrt or log of a negative number)."""
    try:
        return float(sp.sympify(expr).xreplace({k: sp.Float(float(v), 17)
                                                for k, v in subs.items()}).evalf())
    except (TypeError, ValueError):
        return None


def _is_real(expr, subs) -> bool:
    return value_at(expr, subs) is not None


def structural_signature(model: Model, measurement: tuple[str, ...], faults: list[str],
                         points: int = 3, seed: int = 7) -> dict[str, bool]:
    """Which faults of ``model`` reach the measured expressions (see module docstring).

    Parameters
    ----------
    model : Model
        The model (or driven sub-model) the residual generator is built on.
    measurement : tuple of str
        Measured expressions in output names.
    faults : list of str
        Fault names to test (names absent from ``model`` do not respond).
    """
    jac = symbolic_jacobians(model)
    outs = {o.name: o.symbol for o in model.outputs}
    m = sp.Matrix([parse_expression(e, outs, source=model.source, field="fdi.measurement")
                   for e in measurement])
    Jy = m.jacobian(sp.Matrix([o.symbol for o in model.outputs]))
    names = [f.name for f in model.faults]
    result = {name: False for name in faults}
    if not names:
        return result
    E_s, Fm_s = jac.E, Jy * jac.F
    pts = random_points(model, points, seed)
    fast = _fast_gradients(model, m, pts)
    grads_s = None
    for subs, grads in zip(pts, fast):
        E, Fm = (_real_at(model, M, subs, rows)
                 for M, rows in ((E_s, "dynamics"), (Fm_s, "measurement")))
        if grads is None:           # the symbolic path (and its message where not real)
            grads_s = lie_gradients(model, m, jac) if grads_s is None else grads_s
            grads = [_real_at(model, g_s, subs, "measurement") for g_s in grads_s]
        blocks = [(Fm, np.ones(Fm.shape[0]))]
        for Ck in grads:
            blocks.append((Ck @ E, np.linalg.norm(Ck, axis=1)))
        for j, name in enumerate(names):
            if name not in result:
                continue
            for value, scale in blocks:
                col = np.abs(value[:, j])
                ref = scale * max(np.linalg.norm(E[:, j]), np.abs(Fm[:, j]).max(), 1e-300)
                if np.any(col > _REL_TOL * ref) and np.any(col > 0):
                    result[name] = True
    return result


def _fast_gradients(model: Model, measurement, pts: list) -> list:
    """``d/dx L_f^k m`` at each point by CasADi (:mod:`fdigen.derive.lie_numeric`), None
    at a point (or all) where it is not available."""
    from fdigen.derive.lie_numeric import lie_values

    named = [{s.name: float(subs[s.symbol]) for s in (*model.states, *model.inputs)}
             for subs in pts]
    found = lie_values(model, named, len(model.states) - 1, faults=[],
                       measurement=measurement)
    if found is None:
        return [None] * len(pts)
    return [None if v is None else v[0] for v in found]


def lie_gradients(model: Model, measurement, jac) -> list:
    """``[d/dx L_f^k m for k = 0..n-1]`` of the measured expressions ``m`` (in output
    symbols; :func:`fdigen.derive.lie_derivatives.lie_series`). Where a derivative
    outgrows the series' budget, the remaining orders are the linearisation's
    ``(d/dx L_f^k m) A^j`` (symbolic products, evaluated at each point)."""
    from fdigen.derive.lie_derivatives import lie_series

    grads = list(lie_series(model, measurement, with_faults=False).gradients)
    while len(grads) < len(model.states):
        grads.append(grads[-1] * jac.A)
    return grads


@dataclass(frozen=True)
class Candidate:
    """A residual generator over a subset of the equations, driven by measured states."""

    keep: tuple[str, ...]
    drivers: dict
    check: str
    signature: dict
    decoupled: str = ""

    @property
    def label(self) -> str:
        drv = ", ".join(f"{s}<-{o}" for s, o in self.drivers.items())
        if self.decoupled:
            return (f"combination {self.check} of the equations blind to {self.decoupled}, "
                    f"with [{', '.join(self.keep[1:])}], driven by [{drv}]")
        return f"equations [{', '.join(self.keep)}] driven by [{drv}], checked on {self.check}"


#: Sub-models :func:`candidate_residuals` builds at most (smallest subsets first; each is a
#: symbolic derivation): the subsets of the states are 2^n, and a chain of 8 measured
#: states kept a build busy for 146 s (attack round 2). The shipped models build at most 30.
MAX_CANDIDATE_SUBMODELS = 64
#: Subsets of the states :func:`candidate_residuals` looks at, at most (every subset of
#: 15 states): a chain of 24 states with one sensor has 1.7e7 subsets, almost none a
#: sub-model, and kept `inspect` busy past 300 s after the 64 were not reached (attack
#: round 6).
MAX_SUBSETS_EXAMINED = 2 ** 15


def candidate_residuals(model: Model, faults: list[str]) -> list[Candidate]:
    """Every residual generator built from a proper subset of the state equations (at most
    :data:`MAX_CANDIDATE_SUBMODELS` sub-models from at most :data:`MAX_SUBSETS_EXAMINED`
    subsets, smallest subsets first).

    A subset ``E`` qualifies when each state outside ``E`` that its equations use is measured
    directly (it becomes a driver input) and some output depends on ``E``'s states only (it is
    checked). Sensor faults on drivers enter as input faults of the sub-model.
    """
    from fdigen.design.submodel import driven_submodel, driver_reads, measured_states

    direct = measured_states(model)
    f_full = model.f()
    states = [s.name for s in model.states]
    state_syms = {s.symbol: s.name for s in model.states}
    uses = {name: {state_syms[s] for s in f_full[i].free_symbols if s in state_syms}
            for i, name in enumerate(states)}
    out = []
    built = examined = 0
    for size in range(1, len(states)):
        for keep in itertools.combinations(states, size):
            examined += 1
            if built >= MAX_CANDIDATE_SUBMODELS or examined > MAX_SUBSETS_EXAMINED:
                return out
            used = set().union(*(uses[sname] for sname in keep))
            outside = sorted(used - set(keep), key=states.index)
            if any(s not in direct for s in outside):
                continue
            drivers = {s: direct[s] for s in outside}
            for s in outside:    # a compound reading needs the other sensors too, or the
                drivers.update({r: o for r, o in driver_reads(model, s, direct[s]).items()
                                if r not in keep})      # kept states it reads, simulated
            drivers = {s: drivers[s] for s in states if s in drivers}
            built += 1
            try:
                sub = driven_submodel(model, keep, drivers)
            except Exception:
                continue
            rank = output_preference(model)
            kept = {x.symbol for x in sub.states}
            for check in sorted(sub.outputs, key=lambda o: rank[o.name]):
                if not sub.expand(check.expr).free_symbols & kept:
                    continue    # reads no state: a static relation's, not a sub-model's
                sig = structural_signature(sub, (check.name,), faults)
                out.append(Candidate(tuple(keep), drivers, check.name, sig))
    return out


def whole_model_candidates(model: Model, faults: list[str]) -> list[Candidate]:
    """The whole model as a residual generator checked on each output (no driver): what a
    declared parity residual is, for a model that declares none. The last resort of the
    structural selection: a one-state plant has no proper sub-model (a user's vessel read
    by three transmitters derived their static relations only, and its leak went unseen),
    and sensor faults are told apart only by a residual reading one sensor alone (a user's
    boost converter: current-sensor offset and voltage-sensor gain)."""
    from fdigen.model.sensor_maps import output_preference

    keep = tuple(s.name for s in model.states)
    rank = output_preference(model)
    states = {x.symbol for x in model.states}
    return [Candidate(keep, {}, o.name, structural_signature(model, (o.name,), faults))
            for o in sorted(model.outputs, key=lambda o: rank[o.name])
            if model.expand(o.expr).free_symbols & states]


def strongly_isolated(sig_a: set, sig_b: set) -> bool:
    """Two signatures isolate strongly when neither is contained in the other.

    Flags are latched and rise one after the other; a signature contained in another can be
    matched while the larger one is still building up, so containment is weak isolation.
    """
    return bool(sig_a) and bool(sig_b) and not sig_a <= sig_b and not sig_b <= sig_a


def unresolved_pairs(table: dict, classes: dict, across_classes: bool = True):
    """Fault pairs (of different classes, or the same class) not strongly isolated."""
    pairs = []
    names = list(table)
    for a, b in itertools.combinations(names, 2):
        if (classes[a] != classes[b]) != across_classes:
            continue
        if not strongly_isolated(table[a], table[b]):
            pairs.append((a, b))
    return pairs


def decoupling_candidates(model: Model, faults: list[str]) -> list[Candidate]:
    """Candidates blind to one fault each (see :mod:`fdigen.design.decoupling`)."""
    from fdigen.design.decoupling import decoupled_submodel

    out = []
    for fault in model.faults:
        found = decoupled_submodel(model, fault, f"m_{fault.name}")
        if found is None:
            continue
        sub, drivers, measured, _, _, signature = found
        out.append(Candidate(tuple(s.name for s in sub.states), drivers,
                             expression_text(measured),
                             {f: signature.get(f, False) for f in faults}, fault.name))
    return out


def select_extra_residuals(table: dict, classes: dict, candidates: list[Candidate],
                           across_classes: bool = True, limit: int = 8):
    """Greedily choose candidates that make the most unresolved fault pairs isolable.

    A candidate's score counts, over the pairs not yet strongly isolated, the directions
    ``a -> b`` it newly distinguishes (a residual that responds to ``a`` and not to ``b``
    takes ``S(a)`` out of ``S(b)``); strong isolation needs both directions.

    Returns the chosen candidates in order, and the pairs still unresolved.
    """
    table = {k: set(v) for k, v in table.items()}
    chosen = []

    def directions(tab, pairs):
        return sum((bool(tab[a]) and not tab[a] <= tab[b]) + (bool(tab[b]) and not tab[b] <= tab[a])
                   for a, b in pairs)

    while True:
        pairs = unresolved_pairs(table, classes, across_classes)
        base = directions(table, pairs)
        best, best_fixed = None, 0
        for k, cand in enumerate(candidates):
            trial = {f: s | ({f"_c{k}"} if cand.signature.get(f) else set())
                     for f, s in table.items()}
            fixed = directions(trial, pairs) - base
            rank = (fixed, -len(cand.keep), -len(cand.drivers))
            if fixed > 0 and (best is None or rank > best[0]):
                best, best_fixed = (rank, k, cand), fixed
        if best is None or best_fixed == 0 or len(chosen) >= limit:
            return chosen, pairs
        _, k, cand = best
        chosen.append(cand)
        table = {f: s | ({f"_c{k}"} if cand.signature.get(f) else set())
                 for f, s in table.items()}
