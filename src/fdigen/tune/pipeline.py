"""The whole tuning procedure: :func:`tune` (healthy campaign, fit, fault campaign).

Loads the model, draws the cases, runs the healthy campaign with flags off, designs the
thresholds, rebuilds the design with them and runs the validation and fault campaigns,
then assembles the JSON-able report.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from fdigen.errors import FdigenError
from fdigen.tune.campaign import CampaignExecutor
from fdigen.tune.cases import make_cases, test_size_specs
from fdigen.tune.extremes import clopper_pearson_upper
from fdigen.tune.frozen_horizon import (combined_horizons, fault_logs, fault_run_horizons,
                                       frozen_horizons, healthy_logs)
from fdigen.tune.fault_sensitivity import fault_unit, measured_sensitivity
from fdigen.tune.parameter_masking import (calibrated_spread, masking_of_fault_cases,
                                          masking_text)
from fdigen.tune.run_notes import (after_startup, campaign_startup, early_peaks,
                                   growing_residuals, startup_text, substeps_raise)
from fdigen.tune.substep_probe import accurate_campaign
from fdigen.tune.fault_summary import (poorly_isolated, summarise_faults,
                                       unreached_separators,
                                       wrong_isolations_by_class)
from fdigen.design.residual_identity import residual_keys
from fdigen.tune.model_update import (design_with_horizons, design_with_thresholds,
                                      fill_missing_thresholds, flags_off)
from fdigen.sim.run_length import default_duration
from fdigen.tune.run_length import check_run_duration
from fdigen.tune.sensor_span import WIDE_THRESHOLD, thresholds_beyond_span
from fdigen.tune.settings import NO_FLAG, TuneSettings
from fdigen.tune.thresholds import design_thresholds, vertex_maxima, vertex_note


def check_finite_maxima(model, names, maxima) -> None:
    """Refuse (naming the residuals) healthy runs whose RMS is not finite: no threshold
    exists for them. A parallel model of an open-loop unstable plant (a magnetic
    levitation rig) diverges without realignment: the error named only 'threshold inf'."""
    bad = [(n, int(np.sum(~np.isfinite(maxima[:, j])))) for j, n in enumerate(names)
           if not np.all(np.isfinite(maxima[:, j]))]
    if not bad:
        return
    scale = float(model.fdi.get("realign_noise_scale", 0.0))
    hint = (" With [fdi] realign_noise_scale = 0 the parallel models run open loop: on a "
            "plant that is unstable open loop they diverge; a positive scale (0.1) re-aligns "
            "each on its own sensor" if scale <= 0 else
            " (a parallel model or filter that diverges on the healthy plant: check the "
            "model's stability at the operating point and its sensors)")
    raise FdigenError(
        "no threshold can be designed: the healthy RMS of "
        + ", ".join(f"{n} ({k} of {maxima.shape[0]} runs)" for n, k in bad)
        + " is not finite." + hint)


def tune(model=None, settings: TuneSettings | None = None, *, workers: int = 2,
         scheduler: str | None = None, progress: bool = True, log=None, plant=None,
         plant_effects=()) -> dict:
    """Tune the thresholds of a model: healthy campaign, fit, fault campaign.

    Parameters
    ----------
    model : str, Path or None
        Model file or built-in model name (default: the pneumatic cylinder).
    settings : TuneSettings, optional
    workers : int
        Local Dask worker processes (ignored with ``scheduler``).
    scheduler : str, optional
        Address of a running Dask scheduler, or ``"synchronous"`` to run in-process.
    progress : bool
        Progress bars on stderr.
    log : callable, optional
        ``log(message)`` for stage messages.
    plant : str, Path or Model, optional
        The model simulated as the plant (default: ``model`` itself). A design is tuned
        for the plant it will watch: ``fdigen discover``'s augmented model is tuned on the
        plant that carries the effect, and so is the original design it is compared with
        (``scripts/discover_payoff.py``).
    plant_effects : sequence of fdigen.sim.plant.Effect
        Effects switched on in the simulated plant (terms its model file lacks).

    Returns
    -------
    dict
        The report (JSON-able): settings, thresholds (current and tuned, per-residual
        statistics), false-alarm estimates, fault table, per-run summaries, timing.
    """
    from fdigen.design.cache import cached_design
    from fdigen.model.model_file import load_model
    from fdigen.pipeline import resolve_model_path

    settings = settings or TuneSettings()
    say = log or (lambda msg: None)
    t_start = time.perf_counter()
    path = resolve_model_path(model)
    m = load_model(path)
    if not m.faults and settings.faults:
        raise FdigenError("the model has no faults")
    # a parameter's own tolerance in the file (a commissioned model's calibrated spread)
    # is its spread; the settings' own per-parameter spreads win over it
    declared = {q.name: q.tolerance for q in m.parameters if q.tolerance is not None}
    if declared:
        settings = dataclasses.replace(settings, tolerances=tuple(sorted(
            {**declared, **dict(settings.tolerances)}.items())))
    # thresholds the file lacks (a new model, a newly derived residual) are designed here
    written = dict(m.fdi.get("thresholds", {}))
    m, unset = fill_missing_thresholds(m, NO_FLAG)
    stale = [n for n in unset if n in written]    # written for another residual
    if stale:
        say(f"{m.name}: the thresholds of {', '.join(stale)} were written for other "
            "residuals ([fdi.residual_keys]): designed anew from the healthy runs")
    if set(unset) - set(stale):
        say(f"{m.name}: no threshold in the model file for "
            f"{', '.join(n for n in unset if n not in stale)}: designed from the healthy runs")
    design0 = cached_design(m)
    # tuned: the residuals whose thresholds the model file's [fdi.thresholds] sets; others
    # (e.g. measurement-validity indicators) have thresholds fixed by the design
    names = [n for n in design0.residual_names if n in design0.config.thresholds]
    fixed = {n: float(v) for n, v in zip(design0.residual_names,
                                         design0.evaluation.thresholds) if n not in names}
    current = {n: float(design0.config.thresholds[n]) for n in names if n not in unset}
    unknown = sorted(set(settings.keep) - set(names))
    if unknown:
        raise FdigenError(f"--keep names unknown residual(s) {', '.join(unknown)} "
                          f"(residuals: {', '.join(names)})")
    kept_unset = sorted(set(settings.keep) & set(unset))
    if kept_unset:
        raise FdigenError(f"--keep names residual(s) without a threshold in the model file: "
                          f"{', '.join(kept_unset)}")
    dt = design0.config.sample_time
    duration_source = "--duration"
    if settings.duration is None:
        duration, duration_source = default_duration(m)
        settings = dataclasses.replace(settings, duration=duration)
    run_length_notes = check_run_duration(m, settings.duration, dt, design0.config.window)
    from fdigen.design.design_warnings import inputs_outside

    from fdigen.tune.cases import clipped_sizes

    run_length_notes = list(run_length_notes) + [f"warning: {n}" for n in inputs_outside(m)]
    run_length_notes += [f"note: {n}" for n in clipped_sizes(m, settings.fault_factors,
                                                             settings.faults)]
    for note in run_length_notes:
        say(note)
    settle = design0.config.window * dt if settings.settle is None else settings.settle
    # no flag rises during the core's start-up: the thresholds are fitted after it
    settle = max(settle, design0.config.startup)
    settle_samples = int(round(settle / dt))
    if plant is not None and not hasattr(plant, "states"):
        plant = load_model(resolve_model_path(plant))
    raised = substeps_raise(plant or m, settings)
    cases = make_cases(m, settings, plant, plant_effects, raised)
    say(f"{m.name}: {len(names)} residuals, {settings.runs} healthy runs of "
        f"{settings.duration:g} s ({duration_source}), "
        f"{len(cases['validation'])} validation runs, "
        f"{len(cases['fault'])} fault runs")
    healthy_design = flags_off(design0)
    timing = {}
    with CampaignExecutor(workers, scheduler, progress) as ex:
        say(f"executor: {ex.description}")
        cases, accuracy = accurate_campaign(m, cases, ex.map)
        if accuracy:
            say(("" if accuracy["converged"] else "warning: ") + accuracy["text"])
        t0 = time.perf_counter()
        ex.warm_up(healthy_design)
        timing["warm_up"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        healthy = ex.run(healthy_design, cases["healthy"] + cases["vertex"], settle_samples,
                         "healthy runs")
        timing["healthy"] = time.perf_counter() - t0
        vertex_runs = [r for r in healthy if r["kind"] == "vertex" and not r.get("not_real")]
        healthy = [r for r in healthy if r["kind"] == "healthy"]
        fit_runs = in_domain(healthy, say)
        found = None if design0.config.startup else campaign_startup(
            fit_runs, names, early_peaks(fit_runs, names, dt * settle_samples))
        if found:
            found["text"] = startup_text(found, early_peaks(fit_runs, names,
                                                            dt * settle_samples))
            say(found["text"])
            after_startup(fit_runs + vertex_runs, names, found["seconds"], dt * settle_samples)
            m = dataclasses.replace(m, fdi={**m.fdi, "startup": found["seconds"]})
            found.pop("maxima")
        maxima = np.array([[r["max_rms"][n] for n in names] for r in fit_runs])
        startup = np.array([[r["max_rms_startup"][n] for n in names] for r in fit_runs])
        check_finite_maxima(m, names, np.maximum(maxima, startup))
        vertices = vertex_maxima(vertex_runs, names)
        if vertices is not None and vertices.get("diverged"):
            say(vertices["diverged"])
        tuned = design_thresholds(names, maxima, current, settings, startup, vertices)
        note = vertex_note(tuned, names, len(cases["vertex"]), len(vertex_runs),
                           {q.name: q.value for q in (plant or m).parameters})
        if note:
            say(note)
        say("deriving the design with the tuned thresholds")
        t0 = time.perf_counter()
        tuned_design = design_with_thresholds(m, tuned["thresholds"])
        timing["rebuild_design"] = time.perf_counter() - t0
        horizon = None
        if settings.horizon_runs:
            say("measuring the validity horizons of frozen residuals")
            t0 = time.perf_counter()
            horizon = frozen_horizons(tuned_design, healthy_logs(
                plant or m, cases["healthy"][:settings.horizon_runs]), settings.margin)
            if settings.horizon_fault_runs:
                specs = test_size_specs(m, design0.config.window * dt,
                                        settings.duration / 2)
                horizon = combined_horizons(horizon, fault_run_horizons(
                    tuned_design, fault_logs(plant or m,
                                             cases["healthy"][:settings.horizon_fault_runs],
                                             specs)), settings.margin)
            timing["frozen_horizon"] = time.perf_counter() - t0
            # the campaign checks the design as --write would write it
            tuned_design = design_with_horizons(tuned_design, horizon["horizons"])
        t0 = time.perf_counter()
        rest = ex.run(tuned_design, cases["validation"] + cases["fault"], settle_samples,
                      "validation + fault runs") if (cases["validation"] or cases["fault"]) \
            else []
        timing["validation_and_faults"] = time.perf_counter() - t0
        executor = ex.description
    # cases were indexed per kind: split back by kind
    validation = [r for r in rest if r["kind"] == "validation"]
    fault_runs = [r for r in rest if r["kind"] == "fault"]
    k_val = sum(r["t_first_flag"] is not None for r in validation)
    fa = {
        "target_per_run": settings.false_alarm_rate,
        "run_duration": settings.duration,
        "basis": tuned["basis"],
        "fitted": tuned["fitted_false_alarm"],
        "empirical_in_sample": tuned["empirical_false_alarm_in_sample"],
        "validation_runs": len(validation),
        "validation_false_alarms": k_val,
        "validation_upper_95": clopper_pearson_upper(k_val, len(validation)),
        "set_by_startup": [n for n in names
                           if tuned["residuals"][n].get("startup_sets_threshold")],
        "early_peaks": early_peaks(healthy, names, dt * settle_samples),
        "growing": growing_residuals(healthy, names, settings.duration),
        "healthy_runs_current_thresholds_exceeded": int(np.sum(np.any(
            maxima > np.array([current.get(n, np.inf) for n in names]), axis=1))),
    }
    runs = healthy + vertex_runs + validation + fault_runs
    samples = sum(r["samples"] for r in runs)
    sim_s = sum(r["timing"].get("simulate", 0.0) for r in runs)
    fdi_s = sum(r["timing"].get("fdi", 0.0) for r in runs)
    cpu_s = sum(r["timing"].get("simulate_cpu", 0.0) + r["timing"].get("fdi_cpu", 0.0)
                for r in runs)
    timing.update({"total": time.perf_counter() - t_start, "samples": samples,
                   "task_simulate_seconds": sim_s, "task_fdi_seconds": fdi_s,
                   "task_cpu_seconds": cpu_s,
                   "samples_per_second_per_core": samples / (sim_s + fdi_s) if sim_s else None,
                   "samples_per_cpu_second": samples / cpu_s if cpu_s else None})
    faults = summarise_faults(fault_runs)
    class_isolable = class_isolable_faults(design0)
    masking = missed_case_masking(plant or m, settings, fault_runs, design0.config.window)
    return {
        "model": m.name, "model_file": str(path), "residuals": names,
        "plant": None if plant is None else plant.source,
        "plant_effects": [{"effect": e.name, "target": e.target,
                           "parameters": dict(e.parameters)} for e in plant_effects],
        "fixed_residuals": fixed,
        "settings": {**dataclasses.asdict(settings), "settle": settle,
                     "duration_source": duration_source, "warnings": run_length_notes,
                     "settle_samples": settle_samples,
                     "uncertain_parameters": [q.name for q in m.parameters if q.uncertain]},
        "executor": executor,
        "current_thresholds": current,
        "thresholds": tuned["thresholds"],
        "threshold_text": tuned["text"],
        "residual_keys": residual_keys(tuned_design.extra_residuals),
        "threshold_statistics": tuned,
        "false_alarm": fa,
        "frozen_horizon": horizon,
        # a horizon shorter than one RMS window: a flag a fault raises after the first
        # one has no time to build up its RMS before it counts as late (a user's unstable
        # maglev: R1 13 ms against a 50 ms window)
        "short_horizons": {n: h for n, h in ((horizon or {}).get("horizons") or {}).items()
                           if h < design0.config.window * dt},
        "faults": faults,
        "class_isolable": class_isolable,
        "poorly_isolated": (poorly := poorly_isolated(faults, class_isolable)),
        "unreached_separators": unreached_separators(tuned_design, fault_runs, poorly),
        "thresholds_beyond_span": thresholds_beyond_span(tuned_design, tuned["thresholds"]),
        "thresholds_wide": thresholds_beyond_span(tuned_design, tuned["thresholds"],
                                                  WIDE_THRESHOLD),
        "sensitivity": measured_sensitivity(m, faults),
        "parameter_masking": masking,
        "wrong_isolations_by_class": wrong_isolations_by_class(fault_runs),
        "substeps": raised,
        "startup": found,
        "substeps_accuracy": accuracy,
        "left_domain": left_domain({"healthy": healthy, "validation": validation,
                                    "fault": fault_runs}),
        "runs": {"healthy": healthy, "vertex": vertex_runs, "validation": validation,
                 "fault": fault_runs},
        "timing": timing,
    }


def missed_case_masking(model, settings: TuneSettings, fault_runs: list, window: int) -> list:
    """For each fault case at its test size that some run missed (a run without a false
    alarm before its onset: the others never tested the fault): whether the parameter
    spread masks it (:mod:`fdigen.tune.parameter_masking`), i.e. whether a better residual
    could detect it at all at this tolerance. A list of entries with ``fault``, ``kind``,
    ``size`` and the masking's numbers and text."""
    missed = list(dict.fromkeys(
        (r["fault"], float(r["size"]), bool(r["ramp"])) for r in fault_runs
        if r["factor"] == 1.0 and not r["detected"] and not r["false_alarm_before_onset"]))
    if not missed:
        return []
    res = masking_of_fault_cases(model, missed, tolerance=settings.tolerance,
                                 tolerances=dict(settings.tolerances),
                                 duration=settings.duration, window=window)
    out = []
    for (name, size, ramp), entry in res.items():
        unit = fault_unit(model, model.fault(name))
        size_text = f"{size:.3g}{(' ' + unit) if unit and unit != 'x' else unit}" \
            + ("/s" if ramp else "")
        kind = "drift" if ramp else "step"
        out.append({"fault": name, "kind": kind, "size": size, **entry,
                    "text": masking_text(name, kind, size_text, entry,
                                         calibrated=calibrated_spread(model))})
    return out


def in_domain(healthy: list, say) -> list:
    """The healthy runs whose plant stayed in its equations' domain: a run that left it
    (states clamped to limits from then on) says nothing of the plant, and its RMS set a
    written threshold (attack round 3: R1 = 6.09 from five such runs, the fifteen others
    at most 0.68). All of them out: refused."""
    kept = [r for r in healthy if not r.get("not_real")]
    if len(kept) < len(healthy):
        first = next(r["not_real"] for r in healthy if r.get("not_real"))
        say(f"{len(healthy) - len(kept)} of {len(healthy)} healthy runs left the model's "
            f"equations' domain (first: dynamics.{first[1]} at t = {first[0]:g} s): left "
            "out of the thresholds")
    if not kept:
        raise FdigenError("every healthy run left the model's equations' domain (a "
                          "derivative not a number): no threshold can be designed from "
                          "them; narrow the parameter spread (--tolerance, a parameter's "
                          "own tolerance) or guard the model's square roots and logs")
    return kept


def left_domain(runs: dict) -> list:
    """The runs whose plant left its equations' domain (a state's derivative not a number,
    :meth:`fdigen.sim.plant.SimulationResult.first_not_real`): their states were clamped
    to limits from then on, and what the FDI did on them says nothing about the plant."""
    return [{"kind": kind, "index": r.get("index"), "fault": r.get("fault"),
             "size": r.get("size"), "t": r["not_real"][0], "state": r["not_real"][1]}
            for kind, rs in runs.items() for r in rs if r.get("not_real")]


def left_domain_text(gone: list) -> str:
    """One line on the runs of :func:`left_domain` (``gone``, not empty)."""
    first = gone[0]
    return (f"{len(gone)} run(s) left the model's equations' domain (a derivative not a "
            f"number: a sqrt or log of a negative number), e.g. the {first['kind']} run "
            f"{first['index']}"
            + (f" ({first['fault']} at {first['size']:.3g})" if first.get("fault") else "")
            + f": dynamics.{first['state']} at t = {first['t']:g} s; their states were "
            "clamped to limits from then on, so their results say nothing about the plant "
            "(healthy ones are left out of the thresholds): smaller fault sizes, or "
            "arguments guarded as the physics says")


def class_isolable_faults(design) -> list:
    """Faults the class decision can isolate: the class-level signature (the flags the
    class decision reads, without the measurement-validity indicators ``nf_<y>`` that only
    an invalid sample raises) is not empty and lies inside no other class's fault's."""
    from fdigen.design.evaluation import class_level_masks

    masks = class_level_masks(design.evaluation, design.model.outputs)
    cls = {f.name: f.fault_class for f in design.model.faults}
    return [f for f, s in masks.items()
            if s and all(s & ~masks[g] for g in masks if cls[g] != cls[f])]
