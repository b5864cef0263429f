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
horizon (its flags are always read, as without this rule).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

#: the freeze instants, as fractions of each healthy run (the fault campaign's range)
FREEZE_FRACTIONS = (0.35, 0.65)


def time_to_threshold(design, u, y, k_freeze: int, cfdi=None) -> dict:
    """Per residual, seconds from ``k_freeze`` until ``RMS_r > J_r`` with the realignment
    frozen from sample ``k_freeze`` on (``None``: never within the run).

    The core is the generated C step (``CFdi.core``, mode ``(k >= k_f, 0)``), the RMS the
    moving window of eq 22 (``sqrt(sum_{N} r^2 / N)``).
    """
    from fdigen.backends.c.loader import CFdi
    from fdigen.backends.reference import ReferenceFdi

    ev = design.evaluation
    core = cfdi or CFdi(design)
    ref = ReferenceFdi(design)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref.initialise(u[0], y[0])
    z = ref.z
    K, nr, N = u.shape[0], len(ev.residuals), ev.window
    r = np.empty((K, nr))
    for k in range(K):
        z, r[k], _ = core.core(z, u[k], y[k], (1.0 if k >= k_freeze else 0.0, 0.0))
    sq = np.where(np.isfinite(r), r * r, np.inf)
    csum = np.cumsum(np.vstack([np.zeros((1, nr)), sq]), axis=0)
    lo = np.maximum(np.arange(1, K + 1) - N, 0)
    rms = np.sqrt((csum[1:] - csum[lo]) / N)
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
        ``crossed`` (residual -> runs x instants that crossed), ``trials``.
    """
    from fdigen.backends.c.loader import CFdi

    names = names or [n for n in design.evaluation.residuals if not n.startswith("nf_")]
    cfdi = CFdi(design)
    times = {n: [] for n in names}
    trials = 0
    for u, y in healthy_logs:
        for frac in fractions:
            t = time_to_threshold(design, u, y, int(frac * u.shape[0]), cfdi)
            trials += 1
            for n in names:
                if t[n] is not None:
                    times[n].append(t[n])
    earliest = {n: (min(v) if v else None) for n, v in times.items()}
    return {"horizons": {n: float(f"{e / margin:.3g}") for n, e in earliest.items()
                         if e is not None},
            "earliest": earliest, "crossed": {n: len(v) for n, v in times.items()},
            "trials": trials, "margin": margin, "fractions": list(fractions)}


def healthy_logs(model, cases):
    """The healthy closed-loop logs ``(u, y)`` of tune's ``cases`` (parameter spread,
    references varied as the campaign's)."""
    from fdigen.sim.plant import simulate
    from fdigen.tune.cases import varied_simulation

    centres: dict = {}
    for case in cases:
        sim_model = dataclasses.replace(
            model if case.plant is None else case.plant,
            simulation=varied_simulation(model, case.ref_scale, case.ref_shift, centres))
        sim = simulate(sim_model, case.duration, parameters=case.parameters,
                       seed=case.seed, effects=case.effects)
        yield sim.u, sim.y
