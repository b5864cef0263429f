"""What a meaning-preserving rewrite must keep: the signature table and isolability up to
renaming, the simulation up to the scaling, the diagnosis of every fault case.

Designs are cached per session (:func:`design_of`); simulations are short.
"""

from __future__ import annotations

import tomllib

from dataclasses import replace

import numpy as np

from fdigen.design.cache import cached_design
from fdigen.errors import FdigenError
from fdigen.model.model_file import load_model, parse_model_text
from fdigen.sim.plant import simulate

from metamorphic.rewrite import Twin, dumps

_DESIGNS: dict = {}
_RUNNERS: dict = {}

#: Relative tolerance of simulations equal up to the scaling: the rewritten expressions
#: round differently (``(h/100)`` in cm), RK4 then carries the rounding (measured: at most
#: about 1e-12 of the range on these plants; 1e-7 leaves room for closed loops).
SIM_RTOL = 1e-7


def model_of(doc: dict, source: str):
    return parse_model_text(dumps(doc), source=source)


def design_of(doc: dict, source: str, path=None):
    """The design of a document (of the file ``path`` when given: the disk cache then
    holds it if another test derived it), through the design cache; thresholds of derived
    residuals the document lacks, or that name residuals it no longer derives, are set
    to 1e300 (never flag: the tables do not depend on them)."""
    text = dumps(doc)
    if text not in _DESIGNS:
        model = load_model(path) if path else parse_model_text(text, source=source)
        try:
            _DESIGNS[text] = cached_design(model)
        except FdigenError:
            _DESIGNS[text] = _design_filling(model)
    return _DESIGNS[text]


def _design_filling(model):
    import dataclasses

    from fdigen.tune.model_update import model_with_thresholds

    fdi = dict(model.fdi)
    paper = set(fdi.get("parity", {})) | set(fdi.get("kalman", {}))
    paper |= set(fdi.get("voter", {}).get("names", []))
    fdi["thresholds"] = {k: v for k, v in fdi.get("thresholds", {}).items() if k in paper}
    fdi.pop("residual_keys", None)    # the derived residuals' thresholds are set below
    model = dataclasses.replace(model, fdi=fdi)
    for _ in range(4):
        try:
            return cached_design(model)
        except FdigenError as exc:
            missing = getattr(exc, "missing_thresholds", ())
            if not missing:
                raise
            model = model_with_thresholds(model, dict.fromkeys(missing, 1e300))
    return cached_design(model)


def canonical_table(design, names: dict | None = None) -> list:
    """The signature table as a sorted multiset of residual columns (each the set of
    faults it responds to, in the original's names): equal up to renaming residuals."""
    back = {v: k for k, v in (names or {}).items()}
    cols = {}
    for fault, residuals in design.signature_table.items():
        for r in residuals:
            cols.setdefault(r, set()).add(back.get(fault, fault))
    return sorted(sorted(c) for c in cols.values())


def paper_table(design, names: dict | None = None) -> dict:
    """Fault -> the paper residuals (named by the file) in its signature."""
    back = {v: k for k, v in (names or {}).items()}
    return {back.get(f, f): sorted(r for r in rs if r in design.paper_residuals)
            for f, rs in design.signature_table.items()}


def unresolved(design, names: dict | None = None) -> set:
    back = {v: k for k, v in (names or {}).items()}
    return {frozenset(back.get(f, f) for f in pair)
            for pair in (*design.unresolved_within_class, *design.unresolved_across_classes)}


def simulate_pair(doc: dict, tw: Twin, samples: int = 300, faults=(), seed: int = 3,
                  noise: bool = True):
    """Simulate the original and its twin (same seed); the twin's outputs mapped back.

    The noise is drawn per output in the file's order: a twin with its outputs reordered
    gets the same numbers on other sensors, so compare those with ``noise=False``."""
    m0 = model_of(doc, "original.toml")
    m1 = model_of(tw.doc, "twin.toml")
    dt = float(doc["fdi"]["sample_time"])
    dur = samples * dt
    r0 = simulate(m0, dur, faults=faults, seed=seed, noise=noise)
    r1 = simulate(m1, dur, faults=[replace(f, name=tw.names.get(f.name, f.name))
                                   for f in faults], seed=seed, noise=noise)
    y1 = np.empty_like(r1.y)
    for j, o in enumerate(m0.outputs):
        name = tw.names.get(o.name, o.name)
        k = m1.output_index(name)
        g, off = tw.output_scale.get(name, (1.0, 0.0))
        y1[:, j] = (r1.y[:, k] - off) / g
    u1 = np.stack([r1.u[:, m1.inputs.index(next(s for s in m1.inputs
                                                 if s.name == tw.names.get(i.name, i.name)))]
                   / tw.input_scale.get(tw.names.get(i.name, i.name), 1.0)
                   for i in m0.inputs], axis=1)
    return r0, (r1, u1, y1)


def close(a: np.ndarray, b: np.ndarray, rtol: float = SIM_RTOL) -> float:
    """Largest difference relative to the signal's span (0 when equal)."""
    span = np.maximum(np.ptp(a, axis=0), np.abs(a).max(axis=0))
    span[span == 0] = 1.0
    return float(np.max(np.abs(a - b) / span))


def diagnose(design, u, y) -> dict:
    """The C core's (else the reference's) decision on a log: isolated class, action, whether any
    flag rose, the faults consistent with the flags (declared names)."""
    from fdigen.detect import fdi_runner, summarise_run

    if id(design) not in _RUNNERS:
        _RUNNERS[id(design)] = (design, fdi_runner(design, "auto"))
    out = _RUNNERS[id(design)][1].run(u, y)
    t = np.arange(len(u)) * design.config.sample_time
    run = summarise_run(design, t, out)
    d = run["diagnosis"]
    return {"fault": d["fault"], "action": d["action"], "detected": run["detected"],
            "candidates": sorted(d["candidates"])}


def doc_of(path) -> dict:
    with open(path, "rb") as fh:
        return tomllib.load(fh)


def extra_key(extra: dict, names: dict | None = None) -> tuple:
    """What a derived residual is, in the original's names: equations, drivers, checked
    output (or the fault it is blind to)."""
    back = {v: k for k, v in (names or {}).items()}
    return (tuple(sorted(back.get(e, e) for e in extra["equations"])),
            tuple(sorted((back.get(s, s), back.get(o, o))
                         for s, o in extra["drivers"].items())),
            back.get(extra["blind_to"] or "", extra["blind_to"] or ""),
            "" if extra["blind_to"] else back.get(extra["check"], extra["check"]))


def with_twin_thresholds(d0, d1, tw: Twin):
    """The twin's design with the original's thresholds, each scaled by the gain of the
    sensor its residual is in the unit of (parity and driven residuals: the checked
    output; a combination blind to a fault: the states' unit, unscaled)."""
    import dataclasses

    th0 = dict(zip(d0.evaluation.residuals, d0.evaluation.thresholds))
    by_key = {extra_key(e): th0[e["residual"]] for e in d0.extra_residuals}
    th1 = dict(zip(d1.evaluation.residuals, d1.evaluation.thresholds))
    for r in d1.paper_residuals:
        th1[r] = th0[r] * _residual_gain(d1, r, None, tw)
    for e in d1.extra_residuals:
        th1[e["residual"]] = by_key[extra_key(e, tw.names)] * _residual_gain(d1, None, e, tw)
    ev = dataclasses.replace(d1.evaluation, thresholds=np.array(
        [th1[r] for r in d1.evaluation.residuals]))
    return dataclasses.replace(d1, evaluation=ev)


def _residual_gain(design, paper, extra, tw):
    cfg = design.config
    if paper is not None:
        out = cfg.parity.get(paper) or next((k.measurement for k in cfg.kalman
                                            if k.residual == paper), None)
    else:
        out = None if extra["blind_to"] else extra["check"]
    return abs(tw.output_scale.get(out, (1.0, 0.0))[0])
