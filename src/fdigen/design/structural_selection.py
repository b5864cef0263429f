"""Residuals chosen to reach the isolability the model's structure allows.

:func:`fdigen.design.structure.isolability` gives the ordered fault pairs ``(f_i, f_j)``
that some test can separate (a residual responding to ``f_i`` and not to ``f_j``). The
signature table of the paper's residuals (and of the class-isolating extras) separates
fewer. :func:`select_structural` picks, from fdigen's own candidates (driven sub-models of
:func:`~fdigen.design.signatures.candidate_residuals`, unknown-input decoupled combinations
of :func:`~fdigen.design.signatures.decoupling_candidates`), a few residuals that separate
the rest: a greedy set cover over the ordered pairs still missing, each step taking the
candidate that separates most (ties: fewer driver sensors, since each brings its noise
and its faults into the sub-model; then fewer equations), until the table's isolability
equals the structure's or no candidate helps.

A chosen driven sub-model is realised by :func:`driven_parallel_residual` as a nonlinear
parallel model (RK4, the same block as the parity residuals) driven by the measured
states, compared with its checked sensor and re-aligned by a low-gain steady-state Kalman
correction while no flag is raised. A linear filter of the sub-model would separate the
faults structurally but not numerically: its linearisation error over the stroke is as
large as a leak's effect. A candidate whose parallel model is unstable at the sample time
or whose realignment gain does not exist is refused, with the reason recorded.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from fdigen.derive.kalman import discrete_kalman_gain
from fdigen.derive.linearisation import discretise_noise, discretise_zoh, linearise, numeric
from fdigen.derive.nonsmooth import jacobian
from fdigen.design.decoupling import ParallelResidual
from fdigen.design.parallel_model import check_parallel_model_step
from fdigen.design.structure import table_isolability
from fdigen.design.submodel import driven_submodel
from fdigen.errors import DesignError, FdigenError


def missing_pairs(table: dict, achievable: dict) -> set:
    """Ordered pairs (and ``(f, f)`` for detection) the structure allows and ``table`` misses."""
    got = table_isolability(table)
    return {pair for pair, ok in achievable.items() if ok and not got.get(pair, False)}


def select_structural(table: dict, achievable: dict, candidates, realisable, limit: int = 16):
    """Greedy set cover of the missing ordered pairs by candidate residuals.

    Parameters
    ----------
    table : dict of str to set
        Fault -> residuals responding (the signature table so far).
    achievable : dict
        ``(f_i, f_j) -> bool`` from :func:`fdigen.design.structure.isolability`.
    candidates : list of Candidate
    realisable : callable
        ``realisable(candidate) -> str`` : ``""`` when the candidate can be built, else why
        not (it is then skipped).
    limit : int
        At most this many residuals.

    Returns
    -------
    (list, list, set)
        The chosen candidates in order, the refused ones as ``(candidate, reason)``, and the
        ordered pairs still missing.
    """
    table = {f: set(s) for f, s in table.items()}
    chosen, refused, bad = [], [], set()
    while len(chosen) < limit:
        missing = missing_pairs(table, achievable)
        if not missing:
            break
        best = None
        for k, cand in enumerate(candidates):
            if k in bad:
                continue
            hit = {f for f, on in cand.signature.items() if on and f in table}
            gain = sum(1 for fi, fj in missing if fi in hit and (fi == fj or fj not in hit))
            rank = (gain, -len(cand.drivers), -len(cand.keep), -k)
            if gain > 0 and (best is None or rank > best[0]):
                best = (rank, k, cand, hit)
        if best is None:
            break
        _, k, cand, hit = best
        why = realisable(cand)
        if why:
            bad.add(k)
            refused.append((cand, why))
            continue
        bad.add(k)
        chosen.append(cand)
        for f in hit:
            table[f].add(f"_s{k}")
    return chosen, refused, missing_pairs(table, achievable)


def driven_submodel_parts(model, cand):
    """``(submodel, measured, predicted, initial)`` of a driven-sub-model candidate."""
    sub = driven_submodel(model, cand.keep, cand.drivers)
    out = sub.output(cand.check)
    predicted = sub.expand(out.expr)
    measured = model.output(cand.check).symbol
    initial = tuple(s.symbol for s in sub.states)
    return sub, measured, predicted, initial


def check_driven_parallel(model, cfg, cand) -> str:
    """Why the candidate cannot be realised as a stable parallel model, or ``""``."""
    try:
        sub, *_ = driven_submodel_parts(model, cand)
        check_parallel_model_step(sub, cfg)
        _realign_gain(model, cfg, cand)
    except (FdigenError, ValueError, np.linalg.LinAlgError) as exc:
        return str(exc)
    return ""


def _realign_gain(model, cfg, cand):
    sub, measured, predicted, _ = driven_submodel_parts(model, cand)
    lin = linearise(sub)
    dt = cfg.sample_time
    disc = discretise_zoh(lin, dt)
    n = len(sub.states)
    qs = [cfg.process_noise[s.name] for s in sub.states]
    scale = max(cfg.realign_noise_scale, 1e-6)
    Qd = discretise_noise(lin.A, np.diag(np.square(qs)), dt) * scale ** 2
    point = dict(model.parameter_values)
    point.update({s.symbol: sub.operating_point[s.name] for s in (*sub.states, *sub.inputs)})
    C = numeric(jacobian([predicted], sub.x), point)
    var = model.output(cand.check).noise_std ** 2
    if var <= 0:
        raise DesignError(f"{model.source}: outputs.{cand.check}: a checked sensor needs "
                          "noise_std > 0 for the realignment gain")
    gain = discrete_kalman_gain(disc.A, C, Qd + 1e-300 * np.eye(n), np.array([[var]]),
                                f"realignment of the parallel model of {cand.label}")
    return sub, measured, predicted, gain.M


def driven_parallel_residual(model, cfg, cand, residual: str) -> ParallelResidual:
    """The nonlinear parallel model of a driven sub-model, checked on one sensor.

    .. math:: r = y_c - h_c(\\hat x_E),\\qquad
              \\hat x_E^+ = \\mathrm{RK4}(f_E(\\hat x_E + g M r, u, y_D))

    with ``E`` the kept state equations, ``y_D`` the sensors of the driver states, ``g``
    the realignment gate (0 once a flag is up) and ``M`` the steady-state Kalman gain of
    the linearised sub-model with process noise ``(realign_noise_scale)^2 Q``.
    """
    sub, measured, predicted, M = _realign_gain(model, cfg, cand)
    initial = tuple(s.symbol for s in sub.states)
    return ParallelResidual(residual, sub, dict(cand.drivers), measured, predicted, M,
                            "", initial, dict(cand.signature))
