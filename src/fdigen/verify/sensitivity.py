"""Numeric check of the structural signature table by fault simulation.

For every declared fault with a ``test_size``, the closed loop is simulated with the fault
switched on, the reference FDI core runs over the log, and a residual *responds* when its
RMS exceeds its threshold within ``horizon`` seconds of the fault onset while it stayed
below during a healthy run with the same noise seed. The result is compared with the
structural table: structural zeros that respond numerically contradict the structure
(a bug or a missing structural path); structural ones that stay quiet are faults too
small (at that size) for that residual.

Only responses up to the isolation decision count (or the whole horizon when nothing is
isolated): after it, the closed loop reacts to the fault (a lost position sensor drives the
piston into its end stop, an estimate fed a dead valve diverges) and the frozen parallel
model drifts; those secondary responses are not part of a signature.
"""

from __future__ import annotations

import numpy as np

from fdigen.design.fdi_design import FdiDesign


def numeric_signatures(design: FdiDesign, duration: float = 8.0, t_fault: float = 4.0,
                       horizon: float = 2.0, seed: int = 11, runner=None,
                       stop_at_isolation: bool = True, faults=None) -> dict:
    """Residuals whose RMS crosses the threshold after each fault (see module docstring).

    ``stop_at_isolation=False`` counts responses over the whole horizon (the entries that
    isolate one fault from another of its class often rise after the class decision);
    ``faults`` restricts the campaign to these fault names.

    Returns
    -------
    dict
        ``{"healthy": [...flags of the healthy run...], "faults": {fault: [residuals]}}``.
    """
    from fdigen.detect import fdi_runner
    from fdigen.sim.plant import FaultEvent, simulate

    model = design.model
    runner = runner or fdi_runner(design)
    thr = design.evaluation.thresholds
    names = design.residual_names

    def responding(sim):
        out = runner.run(sim.u, sim.y)
        k0 = int(round(t_fault / design.config.sample_time))
        k1 = int(round((t_fault + horizon) / design.config.sample_time))
        iso = np.flatnonzero(np.asarray(out["fault_class"][k0:k1]) > 0)
        if iso.size and stop_at_isolation:
            k1 = k0 + int(iso[0]) + 1
        rms = out["rms"]
        return [names[i] for i in range(len(names)) if np.any(rms[k0:k1, i] > thr[i])], rms

    healthy = simulate(model, duration, seed=seed)
    out_h = runner.run(healthy.u, healthy.y)
    healthy_flags = [names[i] for i in range(len(names)) if np.any(out_h["rms"][:, i] > thr[i])]
    result = {}
    for f in model.faults:
        if not f.test_size or (faults is not None and f.name not in faults):
            continue
        ramp = f.mode == "additive" and f.location == "sensor"
        size = f.test_size / horizon if ramp else f.test_size
        sim = simulate(model, duration, seed=seed,
                       faults=(FaultEvent(f.name, t_fault, size, ramp=ramp),))
        result[f.name], _ = responding(sim)
    return {"healthy": healthy_flags, "faults": result}


def compare_with_structure(design: FdiDesign, numeric: dict) -> dict:
    """Per fault: residuals that respond against the structure, and quiet ones."""
    out = {}
    for fault, responded in numeric["faults"].items():
        structural = design.signature_table[fault]
        out[fault] = {"unexpected": sorted(set(responded) - structural),
                      "quiet": sorted(structural - set(responded))}
    return out
