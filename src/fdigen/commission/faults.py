"""Validation and fault campaigns of the commissioned design, with its final thresholds.

The same runs as :func:`fdigen.tune.tune`'s second campaign (:func:`fdigen.tune.make_cases`
from the same seed: fresh healthy runs, then every fault of the model at
``factor * test_size`` for each factor and onset), but evaluated with the thresholds the
commissioning finally writes (the campaign's, raised where the measured healthy log asked
for it). Per run, :func:`fdigen.tune.summarise_case`; per fault,
:func:`fdigen.tune.summarise_faults` (detections, detection and isolation delays, correct
isolations). The false-alarm rate is the share of fresh healthy runs that raised any flag,
with its one-sided 95 % Clopper-Pearson upper bound.
"""

from __future__ import annotations

import dataclasses
import time

from fdigen.tune.campaign import CampaignExecutor
from fdigen.tune.cases import make_cases
from fdigen.tune.extremes import clopper_pearson_upper
from fdigen.tune.fault_summary import summarise_faults
from fdigen.tune.model_update import design_with_thresholds
from fdigen.tune.substep_probe import accurate_campaign


def fault_campaign(model, thresholds: dict, settings, *, workers: int = 2,
                   scheduler: str | None = None, progress: bool = False) -> dict:
    """Run the validation and fault campaigns of ``model`` with ``thresholds``.

    Parameters
    ----------
    model : Model
        The commissioned model (also the simulated plant: it carries the effects).
    thresholds : dict
        Final thresholds.
    settings : fdigen.tune.TuneSettings
        The campaign's settings (runs are drawn from its seed).

    Returns
    -------
    dict
        ``validation_runs``, ``validation_false_alarms``, ``validation_upper_95``,
        ``faults`` (per fault summary), ``timing``.
    """
    t0 = time.perf_counter()
    design = design_with_thresholds(model, thresholds)
    cases = make_cases(model, settings)
    settle = int(round(design.config.window)) if settings.settle is None else \
        int(round(settings.settle / design.config.sample_time))
    with CampaignExecutor(workers, scheduler, progress) as ex:
        cases, accuracy = accurate_campaign(model, cases, ex.map)
        runs = cases["validation"] + cases["fault"]
        ex.warm_up(design)
        res = ex.run(design, runs, settle, "validation + fault runs") if runs else []
    validation = [r for r in res if r["kind"] == "validation"]
    faults = [r for r in res if r["kind"] == "fault"]
    k = sum(r["t_first_flag"] is not None for r in validation)
    return {
        "validation_runs": len(validation),
        "validation_false_alarms": k,
        "validation_upper_95": clopper_pearson_upper(k, len(validation)),
        "validation_flags": sorted({f for r in validation for f in r["flags_raised"]}),
        "faults": summarise_faults(faults),
        "fault_runs": len(faults),
        "substeps_accuracy": accuracy,
        "timing": {"total": time.perf_counter() - t0,
                   "samples": sum(r["samples"] for r in res)},
        "settings": dataclasses.asdict(settings),
    }
