"""Validity horizons of frozen residuals, measured on healthy runs (``[fdi.frozen_horizon]``).

The realignment of every parallel model freezes at the first flag; from then on a parallel
model runs open loop and drifts with the plant's tolerances. A flag of residual ``r``
rising later than the time a *healthy* plant's frozen model needs to reach ``r``'s
threshold cannot be told apart from that drift, so the class decision does not read it
(:class:`fdigen.design.evaluation.Evaluation`, ``docs/isolation.md``).

:func:`time_to_threshold` forces the freeze at a given sample of a healthy run and returns,
per residual, the time until its moving RMS first exceeds the threshold;
:func:`frozen_horizons` takes the earliest over runs and freeze instants, divided by a
margin: ``H_r = min_{runs, k_f} T_r / margin``. A residual that never crosses gets no
horizon (its flags are always read, as without this rule). :func:`fault_run_horizons`
adds runs with a fault at its test size, frozen at their own first flag: a residual
outside the fault's signature that crosses later bounds its horizon too (a fault moves
the plant to operating points where a frozen model drifts faster than in healthy runs).
"""

from __future__ import annotations

import warnings

import numpy as np

from fdigen.design.evaluation import moving_rms

#: the freeze instants, as fractions of each healthy run (the fault campaign's range)
FREEZE_FRACTIONS = (0.35, 0.65)


def time_to_threshold(design, u, y, k_freeze: int, cfdi=None, reference=None) -> dict:
    """Per residual, seconds from ``k_freeze`` until ``RMS_r > J_r`` with the realignment
    frozen from sample ``k_freeze`` on (``None``: never within the run).

    The core is the generated C step (``CFdi.core_run``, mode ``(k >= k_f, 0)``), started
    from the state the reference initialises from the first sample (``reference``: a
    :class:`~fdigen.backends.reference.ReferenceFdi` of ``design`` to reuse), the RMS the
    moving window of eq 22 (``sqrt(sum_{N} r^2 / N)``).
    """
    from fdigen.backends.c.loader import CFdi
    from fdigen.backends.reference import ReferenceFdi

    ev = design.evaluation
    core = cfdi or CFdi(design)
    ref = reference or ReferenceFdi(design)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref.initialise(u[0], y[0])
    r = core.core_run(ref.z, u, y, k_freeze)
    rms = moving_rms(r, ev.window)
    dt = design.config.sample_time
    out = {}
    for i, name in enumerate(ev.residuals):
        above = np.flatnonzero(rms[k_freeze:, i] > ev.thresholds[i])
        out[name] = float(above[0] * dt) if above.size else None
    return out


def frozen_horizons(design, healthy_logs, margin: float = 1.25,
                    fractions=FREEZE_FRACTIONS, names=None) -> dict:
    """``H_r = min T_r / margin`` over the healthy logs ``[(u, y), ...]`` and freeze
    instants; residual -> seconds, for the residuals of ``names`` (default: all but the
    validity indicators ``nf_<y>``) that crossed at least once.

    Returns
    -------
    dict
        ``horizons`` (residual -> H_r [s]), ``earliest`` (residual -> min T_r or None),
        ``crossed`` (residual -> runs x instants that crossed), ``trials``, ``runs``
        (healthy logs), ``margin``, ``fractions``.
    """
    from fdigen.backends.c.loader import CFdi

    names = names or [n for n in design.evaluation.residuals if not n.startswith("nf_")]
    from fdigen.backends.reference import ReferenceFdi

    cfdi, ref = CFdi(design), ReferenceFdi(design)
    healthy_logs = list(healthy_logs)
    times = {n: [] for n in names}
    trials = 0
    for u, y in healthy_logs:
        for frac in fractions:
            t = time_to_threshold(design, u, y, int(frac * u.shape[0]), cfdi, ref)
            trials += 1
            for n in names:
                if t[n] is not None:
                    times[n].append(t[n])
    earliest = {n: (min(v) if v else None) for n, v in times.items()}
    return {"horizons": {n: float(f"{e / margin:.3g}") for n, e in earliest.items()
                         if e is not None},
            "earliest": earliest, "crossed": {n: len(v) for n, v in times.items()},
            "trials": trials, "runs": len(healthy_logs), "margin": margin,
            "fractions": list(fractions)}


def fault_run_horizons(design, fault_logs) -> dict:
    """The earliest time, after the design's own first flag, at which a residual outside
    the injected fault's signature crosses its threshold, over ``fault_logs``
    ``[(fault, u, y), ...]``.

    A healthy run's frozen model drifts with the parameter spread at the operating points
    of healthy runs; a fault moves the plant elsewhere (a pump wear empties a tank), where
    a frozen model may drift faster. With ``k_f`` the first flagged sample of the fault
    run (the core's own freeze) and ``T_r`` the time from it until ``RMS_r > J_r``, the
    flags that rise after ``T_r`` in a run of a fault whose signature lacks ``r`` are what
    the horizon must leave out: ``H_r <= min T_r / margin`` over such runs (a crossing at
    the first flag itself, ``T_r = 0``, is a flag outside the signature that no horizon
    can leave out: the campaign counts those).

    Returns
    -------
    dict
        ``earliest`` (residual -> min T_r [s]), ``fault`` (residual -> the fault of that
        run), ``runs`` (fault runs that raised a flag).
    """
    from fdigen.backends.c.loader import CFdi

    from fdigen.backends.reference import ReferenceFdi

    cfdi, ref = CFdi(design), ReferenceFdi(design)
    table = design.signature_table
    earliest, by, runs = {}, {}, 0
    for fault, u, y in fault_logs:
        flags = np.asarray(cfdi.run(u, y)["flags"])
        on = np.flatnonzero(flags)
        if not on.size:
            continue
        runs += 1
        for name, t in time_to_threshold(design, u, y, int(on[0]), cfdi, ref).items():
            if t is None or t <= 0 or name in table[fault] or name.startswith("nf_"):
                continue
            if t < earliest.get(name, np.inf):
                earliest[name], by[name] = t, fault
    return {"earliest": earliest, "fault": by, "runs": runs}


def combined_horizons(healthy: dict, faulty: dict, margin: float) -> dict:
    """``H_r = min(T_r^healthy, T_r^fault) / margin`` (:func:`frozen_horizons`' result
    updated in place with the fault runs': ``set_by_fault`` names the residuals whose
    horizon a fault run set, with the fault and its ``T_r``)."""
    out = dict(healthy)
    earliest = dict(healthy["earliest"])
    set_by = {}
    for name, t in faulty["earliest"].items():
        if earliest.get(name) is None or t < earliest[name]:
            earliest[name] = t
            set_by[name] = {"fault": faulty["fault"][name], "time": t}
    out.update(earliest=earliest, set_by_fault=set_by, fault_runs=faulty["runs"],
               horizons={n: float(f"{e / margin:.3g}") for n, e in earliest.items()
                         if e is not None})
    return out


def fault_logs(model, cases, specs):
    """``(fault, u, y)`` of the closed-loop runs of ``cases`` (their parameter spread and
    references) with each fault of ``specs`` ``[(name, size, ramp), ...]`` switched on at
    half the run."""
    from fdigen.sim.plant import FaultEvent
    from fdigen.tune.cases import simulate_case

    for case in cases:
        for name, size, ramp in specs:
            sim = simulate_case(model, case, (FaultEvent(name, case.duration / 2, size,
                                                         ramp),))
            yield name, sim.u, sim.y


def healthy_logs(model, cases):
    """The healthy closed-loop logs ``(u, y)`` of tune's ``cases`` (parameter spread,
    references varied as the campaign's)."""
    from fdigen.tune.cases import simulate_case

    for case in cases:
        sim = simulate_case(model, case)
        if sim.first_not_real() is None:   # a plant out of its domain bounds nothing
            yield sim.u, sim.y
